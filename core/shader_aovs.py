"""Cycles' shader AOVs: values that materials' AOV Output nodes write into passes of their own.

A view layer lists its AOVs (Blender's View Layer Properties > Shader AOV: a name and a type, COLOR or VALUE);
core.scene.Scene.shader_aovs holds them in that order, and a material's node program writes one with the
`aov_output` opcode (core.shading.registry: the value's register and the AOV's index into Scene.shader_aovs).
What the passes hold, with Cycles' (Blender 5.3) meaning:

- An AOV Output node writes where the camera sample's path is still primary: the camera ray's hit, and the
  surfaces behind it while the path goes on through Transparent BSDFs (Cycles' PATH_RAY_TRANSPARENT_BACKGROUND),
  until the first surface whose mean alpha reaches core.data_passes.PASS_ALPHA_THRESHOLD (that surface writes,
  then the path is done: Cycles' PATH_RAY_SINGLE_PASS_DONE). Never after a bounce of another kind (no AOV through
  glass, in reflections or from light bounces).
- The value is written as the node computes it, not weighted by the path's throughput, and the writes of a
  sample's surfaces add up (two transparent layers with AOV nodes write twice, as in Cycles). Russian roulette
  ends a path before its surface is shaded, so that surface writes nothing, unless its material emits (Cycles
  decides the roulette before shading and still shades an emitting surface, whose AOV Output nodes then write).
- A pixel holds the mean over its samples (a sample that wrote nothing adds 0): a COLOR AOV is RGBA whose alpha
  is the share of the pixel's samples that wrote it (Cycles writes alpha 1 with each colour); a VALUE AOV is
  one channel. Pixels no sample wrote are 0.

- A full holdout surface (a Holdout material, or an object or collection held out) still writes: Cycles evaluates
  the surface's shader, AOV Output nodes included, before the holdout ends the path (core.integrator shades it
  for its AOVs alone).

Differences: AOV Output nodes of the world are not evaluated (the add-on warns).

Nothing here runs unless the scene lists AOVs and some material writes one: the compiler keeps AOV Output
nodes only for AOVs the view layer lists, so other renders carry no AOV instruction, film channel or state.
"""

from __future__ import annotations

import numpy as np

from .data_passes import PASS_ALPHA_THRESHOLD, _clear_only
from .scene import SHADER_AOV_KINDS as AOV_KINDS  # noqa: F401  (the list itself is checked by Scene.validate)
CHANNELS = 4  # per AOV and sample: the summed value (RGB; a VALUE AOV uses the first) and the count of writes


class AovPath:
    """Which camera samples' paths may still write AOVs (see the module docstring), and their sums:
    `values` (N, K, CHANNELS) float32."""

    def __init__(self, n: int, n_aovs: int, prepared) -> None:
        self.values = np.zeros((n, n_aovs, CHANNELS), np.float32)
        self.open = np.ones(n, bool)  # primary: the camera ray, or rays on through Transparent BSDFs
        self.done = np.zeros(n, bool)  # a surface at least PASS_ALPHA_THRESHOLD opaque was met
        self.clear_only = _clear_only(prepared)

    def writing(self, idx: np.ndarray) -> np.ndarray:
        """(M,) bool: which of the live paths of samples idx write the AOVs of the surfaces they hit now."""
        return self.open[idx] & ~self.done[idx]

    def any_writing(self, idx: np.ndarray) -> bool:
        return bool(self.writing(idx).any())

    def record(self, idx: np.ndarray, wrote: np.ndarray, written: np.ndarray, lobes) -> None:
        """After shading the surfaces of samples idx: add the AOV writes (written (M, K, CHANNELS)) of the rows
        that may write (wrote (M,) bool), then mark done those whose surface is opaque enough."""
        rows = np.flatnonzero(wrote)
        if len(rows) == 0:
            return
        self.values[idx[rows]] += written[rows]
        clear = (lobes.kind[rows] == 3) & (lobes.ior[rows] == 1.0) & (lobes.roughness[rows] == 0.0)
        transparency = np.clip((lobes.weight[rows] * clear[:, :, None]).sum(axis=1), 0.0, 1.0)
        opaque = (1.0 - transparency).mean(axis=1) >= PASS_ALPHA_THRESHOLD
        self.done[idx[rows[opaque]]] = True

    def scattered(self, idx: np.ndarray, transmitted: np.ndarray, mat: np.ndarray) -> None:
        """After BSDF sampling: only a path that went through a surface whose transmission is all Transparent
        BSDF stays primary."""
        self.open[idx] &= np.asarray(transmitted, bool) & self.clear_only[mat]


    def spread(self, live: np.ndarray, n: int) -> "AovPath":
        """These sums (of the live rays `live` of n camera rays) spread back to all n: dead rays wrote nothing."""
        out = AovPath.__new__(AovPath)
        out.values = np.zeros((n,) + self.values.shape[1:], np.float32)
        out.values[live] = self.values
        return out


def images(means: np.ndarray, aovs) -> dict[str, np.ndarray]:
    """{AOV name: (..., 4) RGBA for COLOR (alpha: the share of samples that wrote it), (..., 1) for VALUE} from
    per-pixel means (..., K, CHANNELS) of AovPath.values."""
    out = {}
    for k, (name, kind) in enumerate(aovs):
        m = np.asarray(means[..., k, :], np.float32)
        out[name] = np.ascontiguousarray(m if kind == "COLOR" else m[..., :1], np.float32)
    return out
