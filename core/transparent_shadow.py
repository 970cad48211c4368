"""Shadow rays through transparent surfaces, as Cycles' transparent shadows.

A shadow ray that meets a surface whose material can be transparent (it has a Transparent BSDF lobe: a
"refraction" lobe of IOR 1 and roughness 0, which is also how a Principled BSDF's Alpha < 1 and a Mix with a
Transparent BSDF are exported) goes on through it, its light multiplied by the surface's transparency there: the
summed colour of those lobes at the hit, after the material's node program ran (node-driven alpha, alpha
textures). A surface of any other material blocks the light, as does the transparent surface after
`max_hits` = Render Settings > Light Paths > Transparent bounces (Cycles' transparent_max_bounce) less the
transparent bounces the ray's path already made (core.integrator counts them apart from bounces, as Cycles).

Only scenes with such a material pay for it (`clear_materials` is None otherwise, and shadow rays stay one
occlusion query each); even then only the shadow rays an occlusion query finds blocked are traced again, hit by
hit (closest hits, a batch per layer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .accel import Accelerator
from .bsdf import REFRACTION, LobeBatch, MaterialTable
from .ray_visibility import bounce_kinds

_OFFSET_SCALE = np.float32(2.0**-19)  # the ray-origin offset of core.geometry_kernels.offset_point
_TINY = np.float32(1e-30)


def clear_materials(materials: MaterialTable) -> np.ndarray | None:
    """(M,) bool: the materials with a Transparent BSDF lobe (shadow rays go on through them); None when none."""
    clear = ((materials.kind == REFRACTION) & (materials.ior == 1.0) & (materials.roughness == 0.0)).any(axis=1)
    return clear if clear.any() else None


def transparency(lobes: LobeBatch) -> np.ndarray:
    """(N, 3) float32 transparency of N surface points: the summed colour of their Transparent BSDF lobes
    (Cycles' shader_bsdf_transparency), clipped to [0, 1]."""
    clear = (lobes.kind == REFRACTION) & (lobes.ior == 1.0) & (lobes.roughness == 0.0)
    out = np.einsum("nl,nlc->nc", clear.astype(np.float32), np.asarray(lobes.weight, np.float32))
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def trace(tracer, occluders: tuple[Accelerator, np.ndarray | None], origin: np.ndarray, direction: np.ndarray,
          tmax: np.ndarray, max_hits: "int | np.ndarray",
          time: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(blocked (N,) bool, transmittance (N, 3) float32) of N shadow rays through the scene of
    `tracer` (a core.integrator.PathTracer: its prepared scene, surface interactions and node programs).

    occluders: the ray-casting structure the shadow rays see and the scene triangle index of each of its
    triangles (None: the whole scene, same indices). A ray is blocked at its first surface whose material is
    not in the scene's clear materials, whose transparency is black, or that would be its (max_hits + 1)-th
    (max_hits: one limit for all, or (N,) one per ray). time: (N,) the rays' times over the shutter (motion blur:
    moving surfaces are met, and shaded, where they are at each ray's time), None for a still scene."""
    ps = tracer.ps
    clear = ps.shadow_clear
    accel, keep = occluders
    n = len(origin)
    limit = np.broadcast_to(np.asarray(max_hits, np.int64), (n,))
    # the times only where the structure has motion (without, surfaces are shaded at the frame's pose too)
    time = None if time is None or getattr(accel, "motion", None) is None else np.asarray(time, np.float32)
    blocked = accel.occluded(origin, direction, tmax, time)
    transmit = np.ones((n, 3), np.float32)
    rows = np.flatnonzero(blocked)
    o, d, tm = origin[rows], np.ascontiguousarray(direction[rows]), tmax[rows].copy()
    tr = None if time is None else time[rows]
    layer = 0
    while len(rows):
        hits = accel.intersect(o, d, tm, tr)
        prim = hits.prim
        if keep is not None and len(keep):
            prim = np.where(prim >= 0, keep[np.maximum(prim, 0)], np.int32(-1)).astype(np.int32)
        found = prim >= 0
        blocked[rows[~found]] = False  # nothing more in the way (an occlusion query and a closest hit may differ
        # by a grazing hit; the closest-hit query decides)
        at = np.flatnonzero(found)
        at = at[layer < limit[rows[at]]]  # the others meet one transparent surface too many: blocked
        mat = ps.material_index[prim[at]]
        at, mat = at[clear[mat]], mat[clear[mat]]  # the others meet an opaque surface: blocked
        if len(at) == 0:
            break
        g = tracer._surface(at, prim, hits.u, hits.v, d, tr)
        lobes = ps.materials.gather(mat, g.uv)
        if ps.shading is not None:
            tracer._shade(g, mat, prim[at], d[at], lobes, bary=(hits.u[at], hits.v[at]))
        transmit[rows[at]] *= transparency(lobes)
        go = transmit[rows[at]].max(axis=1) > 0  # a black surface blocks
        at, g = at[go], g.take(np.flatnonzero(go))
        # go on from just beyond the surface, on the ray's side of it, for the rest of the distance
        eps = np.maximum(g.mag * _OFFSET_SCALE, _TINY)
        side = np.where(np.einsum("ij,ij->i", g.ng, d[at]) < 0, -eps, eps)
        o = (g.p + g.ng * side[:, None]).astype(np.float32)
        tm = (tm[at] - hits.t[at]).astype(np.float32)
        rows, d = rows[at], d[at]
        passed = tm <= 0
        blocked[rows[passed]] = False
        rows, o, d, tm = rows[~passed], o[~passed], np.ascontiguousarray(d[~passed]), tm[~passed]
        tr = None if time is None else time[rows]
        layer += 1
    return blocked, transmit


def clear_passes(lobes: LobeBatch, u_lobe: np.ndarray, transmitted: np.ndarray) -> np.ndarray:
    """(N,) bool: the BSDF samples (drawn by core.bsdf.sample_bsdf from `lobes` with lobe-selection numbers
    `u_lobe`, the u[:, 0] it was given; `transmitted` their flags) that went straight on through a Transparent BSDF lobe. The lobe choice
    is repeated exactly by core.ray_visibility.bounce_kinds, which leaves such samples' ray kind unchanged."""
    untouched = np.int8(127)  # no ray kind has this code
    kinds = np.full(len(u_lobe), untouched, np.int8)
    bounce_kinds(lobes.arrays(), u_lobe, transmitted, kinds)
    return (kinds == untouched) & np.asarray(transmitted, bool)


@dataclass
class MisOrigins:
    """Where the paths' multiple importance sampling stands when shadow rays go through transparent surfaces.

    As in Cycles, a path that goes on through a Transparent BSDF keeps the BSDF pdf, normal and origin of the
    vertex before it: emission it then reaches is weighted against the light sample that vertex's shadow ray
    (which passed through the same surfaces) drew, so the two strategies' weights still sum to one. o (N, 3):
    each live ray's MIS origin (its own origin unless it went on through transparent surfaces); t (N,): the
    distance along the ray from o to the ray's origin (0 unless it did)."""

    o: np.ndarray
    t: np.ndarray

    @classmethod
    def start(cls, origins: np.ndarray) -> "MisOrigins":
        return cls(np.asarray(origins, np.float32), np.zeros(len(origins), np.float32))

    def light_emission(self, tracer, le: np.ndarray, d, t_hit, prev_pdf, prev_delta, mis, prev_normal,
                       prev_transmits, clear, classes=None, kinds=None, camera=False) -> None:
        """Replace in `le` the light emission (PathTracer._light_emission) of the rays that went on through
        transparent surfaces: what lies beyond their origin on the line from the MIS origin, weighted from
        there. camera: bool or (N,) bool, the rays that are still camera rays (through Transparent BSDFs only)."""
        r = np.flatnonzero(self.t > 0)
        if len(r) == 0:
            return
        camera_r = camera if isinstance(camera, (bool, np.bool_)) else np.asarray(camera, bool)[r]

        def seen(tmax):
            return tracer._light_emission(self.o[r], d[r], tmax, prev_pdf[r], prev_delta[r], mis,
                                          None if prev_normal is None else prev_normal[r], camera_r,
                                          None if prev_transmits is None else prev_transmits[r],
                                          None if clear is None else clear[r],
                                          None if classes is None else classes[r],
                                          None if kinds is None else kinds[r])

        le[r] = seen(self.t[r] + t_hit[r]) - seen(self.t[r])

    def origin_and_distance(self, rows: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(MIS origins, distances from them) of the hits at distance t along the rays `rows`."""
        return self.o[rows], self.t[rows] + t

    def advance(self, depth: int, rows: np.ndarray, idx: np.ndarray, passed: np.ndarray, next_idx: np.ndarray,
                o: np.ndarray, d: np.ndarray, old: tuple, new: tuple) -> "MisOrigins":
        """The MIS origins of the next rays o, d (of samples next_idx) after the vertex at `depth` of the paths
        idx (rows `rows` of the arrays before it); `passed`: per path idx, its sample went on through a
        Transparent BSDF. old: the (prev_pdf, prev_delta, prev_normal, prev_transmits) before the vertex (indexed
        like `rows`' source), written into `new` (the next rays' arrays, in place) where a path passed. A camera
        ray (depth 0) keeps what the Transparent BSDF sample gave it, as before."""
        mis_o, mis_t = np.array(o, np.float32), np.zeros(len(o), np.float32)
        if depth == 0 or not passed.any() or len(next_idx) == 0:
            return MisOrigins(mis_o, mis_t)
        row_of = np.full(int(max(idx.max(), next_idx.max())) + 1, -1, np.int64)
        row_of[idx] = np.arange(len(idx))
        k = row_of[next_idx]
        p = np.flatnonzero(passed[k])
        src = rows[k[p]]
        for before, after in zip(old, new):
            if before is not None:
                after[p] = before[src]
        mis_o[p] = self.o[src]
        mis_t[p] = np.einsum("ij,ij->i", o[p] - mis_o[p], d[p])
        return MisOrigins(mis_o, mis_t)
