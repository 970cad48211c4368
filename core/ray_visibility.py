"""Per-object ray visibility for bounce rays (Blender's Object > Visibility > Ray Visibility > Diffuse, Glossy,
Transmission; core.scene.Mesh.visible_diffuse / visible_glossy / visible_transmission), with Cycles' ray kinds:
a ray that a transmitting lobe sent through the surface is a transmission ray, else a diffuse lobe's a diffuse
ray and any other (glossy, glass or refraction reflection) a glossy ray; a ray that went on through a
Transparent BSDF (a refraction lobe of IOR 1 and roughness 0) stays the kind it was (a camera ray stays a camera
ray, as Cycles' transparent bounces keep the ray's visibility).

Which lobe a BSDF sample came from is the choice core.bsdf_kernels.sample_path makes from the same lobe-selection
number (the first of the two direction numbers given to core.bsdf.sample_bsdf, u[:, 0]), so `bounce_kinds`
repeats that choice exactly. Only scenes where some mesh hides from one of these kinds
pay for it (the integrator asks only then).
"""

from __future__ import annotations

import numpy as np

from .bsdf_kernels import DIFFUSE, REFRACTION, _choose_lobe
from .jit_cache import jit
from .shading.program import (PATH_DEPTH, PATH_DIFFUSE_DEPTH, PATH_FLAGS, PATH_GLOSSY_DEPTH, PATH_TRANSMISSION_DEPTH,
                              PATH_TRANSPARENT_DEPTH, RAY_DIFFUSE, RAY_GLOSSY, RAY_REFLECT, RAY_SINGULAR,
                              RAY_TRANSMIT, RAY_TRANSPARENT)

CAMERA_RAY, DIFFUSE_RAY, GLOSSY_RAY, TRANSMISSION_RAY = 0, 1, 2, 3
RAY_KIND_NAMES = {CAMERA_RAY: "camera", DIFFUSE_RAY: "diffuse", GLOSSY_RAY: "glossy", TRANSMISSION_RAY: "transmission"}


@jit
def _bounce_kinds(kind, select, rough, ior, u_lobe, transmitted, out):
    for k in range(u_lobe.shape[0]):
        c, _, _ = _choose_lobe(kind, select, k, u_lobe[k])
        if c < 0:
            continue
        if transmitted[k]:
            clear = kind[k, c] == REFRACTION and ior[k, c] == 1.0 and rough[k, c] == 0.0
            if not clear:
                out[k] = TRANSMISSION_RAY
        else:
            out[k] = DIFFUSE_RAY if kind[k, c] == DIFFUSE else GLOSSY_RAY


def bounce_kinds(lobe_arrays: tuple, u_lobe: np.ndarray, transmitted: np.ndarray, kinds: np.ndarray) -> None:
    """Update `kinds` (N,) int8, each path's current ray kind, to the kind of the ray each BSDF sample starts
    (see the module docstring), from the lobe arrays (core.bsdf.LobeBatch.arrays()), the lobe-selection numbers
    (u[:, 0] given to sample_bsdf) and its `transmitted` flags."""
    _bounce_kinds(lobe_arrays[0], lobe_arrays[5], lobe_arrays[2], lobe_arrays[3],
                  np.ascontiguousarray(u_lobe, np.float32), np.ascontiguousarray(transmitted, bool), kinds)


@jit
def _next_path_state(kind, select, rough, ior, u_lobe, transmitted, state):
    for k in range(u_lobe.shape[0]):
        c, _, _ = _choose_lobe(kind, select, k, u_lobe[k])
        if c < 0:
            continue
        flags = np.int64(state[k, PATH_FLAGS])
        singular = rough[k, c] == 0.0
        if transmitted[k] and kind[k, c] == REFRACTION and ior[k, c] == 1.0 and singular:
            # a transparent bounce: the ray keeps its kind (and its depth)
            state[k, PATH_FLAGS] = flags | RAY_TRANSPARENT
            state[k, PATH_TRANSPARENT_DEPTH] += 1.0
            continue
        state[k, PATH_DEPTH] += 1.0
        if transmitted[k]:
            flags = RAY_TRANSMIT
            state[k, PATH_TRANSMISSION_DEPTH] += 1.0
        else:
            flags = RAY_REFLECT
            if kind[k, c] == DIFFUSE:
                state[k, PATH_DIFFUSE_DEPTH] += 1.0
            else:
                state[k, PATH_GLOSSY_DEPTH] += 1.0
        if kind[k, c] == DIFFUSE:
            flags |= RAY_DIFFUSE
        elif singular:
            flags |= RAY_GLOSSY | RAY_SINGULAR
        else:
            flags |= RAY_GLOSSY
        state[k, PATH_FLAGS] = flags


def next_path_state(lobe_arrays: tuple, u_lobe: np.ndarray, transmitted: np.ndarray, state: np.ndarray) -> None:
    """Update `state` (N, core.shading.program.PATH_COLUMNS) float32, each path's Light Path state, for the ray
    each BSDF sample starts, as Cycles' path_state_next: a transparent bounce (Transparent BSDF) sets the
    transparent flag and counts a transparent bounce, keeping the ray's kind; any other bounce counts one (Ray
    Depth) and sets reflection or transmission, and diffuse, glossy or glossy + singular (a lobe of roughness
    0), counting a diffuse, glossy (reflections) or transmission bounce. The length column is the caller's."""
    _next_path_state(lobe_arrays[0], lobe_arrays[5], lobe_arrays[2], lobe_arrays[3],
                     np.ascontiguousarray(u_lobe, np.float32), np.ascontiguousarray(transmitted, bool), state)
