"""Ray casting with Embree: closest hits and occlusion, over one triangle soup shared by the render's threads.

Embree 4 is the library the embreex wheel ships. core.embree calls it directly (shared buffers, compiled trace
loops): building is ~5x faster than through embreex's Python wrapper (no element-wise copy), tracing the same
or a little faster, hits bit-identical. The wrapper stays as the fallback where that library cannot be found
(`backend` says which one runs). Both release the GIL while tracing, so worker threads cast their batches'
rays in parallel. Embree's tnear is fixed at 0: callers offset ray origins off surfaces themselves (see
core.geometry_kernels.offset_point). All coordinates are float32 in the integrator's shifted frame (world minus
the camera position).
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass

import numpy as np

from . import embree


@dataclass
class MotionTriangles:
    """Triangles that move during the shutter (motion blur): index (M,) int, which of the Accelerator's
    triangles move; corners (S, M, 3, 3) float32, their corners at S >= 2 times evenly spaced from shutter open
    (step 0) to close (step S - 1), in the same frame as the vertices. A ray's time is in [0, 1] over the
    shutter; between steps positions are linear."""

    index: np.ndarray
    corners: np.ndarray

    def subset(self, keep: np.ndarray) -> "MotionTriangles | None":
        """The moving triangles among triangles[keep], renumbered as positions in keep (None if none move)."""
        position = np.full(int(max(keep.max(initial=-1), self.index.max(initial=-1))) + 1, -1, np.int64)
        position[keep] = np.arange(len(keep))
        where = position[self.index]
        chosen = np.flatnonzero(where >= 0)
        if not len(chosen):
            return None
        return MotionTriangles(where[chosen], self.corners[:, chosen])


@dataclass
class Hits:
    """Closest hits of N rays. prim: triangle index (-1 = miss); u, v: barycentrics of vertices 1 and 2;
    t: distance along the (unit) direction; valid only where prim >= 0."""

    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    t: np.ndarray


class Accelerator:
    """An Embree scene over one triangle soup, shared by the render's worker threads, plus ray counters.

    backend: "embree" (direct calls, the default when the library loads), "embreex" (its Python wrapper; the
    fallback, with a warning) or None to choose."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, backend: str | None = None,
                 motion: MotionTriangles | None = None) -> None:
        """vertices: (V, 3) float32; triangles: (T, 3) int32 indices into vertices (validated by the caller).
        motion: the triangles that move over the shutter (motion blur); rays then carry a time (intersect's and
        occluded's `time`). None: a static scene, traced exactly as without motion blur."""
        if backend not in (None, "embree", "embreex"):
            raise ValueError(f"unknown ray-casting backend {backend!r} (expected 'embree' or 'embreex')")
        self.triangle_count = int(len(triangles))
        self.rays_closest = 0
        self.rays_shadow = 0
        self._count_lock = threading.Lock()
        self._library = None
        self._scene = None
        self.motion = motion
        library, why_not = embree.load() if backend != "embreex" else (None, None)
        if library is None and backend == "embree":
            raise RuntimeError(f"the Embree backend is not available: {why_not}")
        if library is None and why_not:
            warnings.warn(f"{why_not}; casting rays through embreex's wrapper (slower)", RuntimeWarning, stacklevel=2)
        self.backend = "embree" if library is not None else "embreex"
        if motion is not None and library is None:
            warnings.warn("motion blur needs Embree's own library (embreex's wrapper has no motion-blur geometry); "
                          "rendering without motion blur", RuntimeWarning, stacklevel=2)
            self.motion = motion = None
        if not self.triangle_count:
            return
        if motion is not None:
            self._build_motion(library, vertices, triangles, motion)
        elif library is not None:
            # Embree reads these in place for the scene's lifetime: keep them. One spare vertex row: Embree may
            # read up to 16 bytes from the last vertex's start.
            self._vertices = np.zeros((len(vertices) + 1, 3), np.float32)
            self._vertices[:-1] = vertices
            self._triangles = np.ascontiguousarray(triangles, dtype=np.int32).view(np.uint32)
            self._scene = library.new_triangle_scene(self._vertices, self._triangles)
            self._library = library
        else:
            from embreex import mesh_construction, rtcore_scene

            self._wrapper = rtcore_scene.EmbreeScene()
            mesh_construction.TriangleMesh(self._wrapper, np.ascontiguousarray(vertices, dtype=np.float32),
                                           np.ascontiguousarray(triangles, dtype=np.int32))
            # The wrapper commits on its first run; do it here, before threads share it.
            self._wrapper.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))

    def _build_motion(self, library, vertices: np.ndarray, triangles: np.ndarray, motion: MotionTriangles) -> None:
        """Two Embree geometries: the static triangles over the shared vertices, the moving ones as a triangle
        soup with one vertex buffer per time step; `_order`/`_first` turn (geomID, primID) back into indices."""
        moving = np.asarray(motion.index, np.int64)
        still = np.ones(self.triangle_count, bool)
        still[moving] = False
        static = np.flatnonzero(still)
        self._vertices = np.zeros((len(vertices) + 1, 3), np.float32)
        self._vertices[:-1] = vertices
        self._triangles = np.ascontiguousarray(np.asarray(triangles, np.int32)[static]).view(np.uint32)
        m = len(moving)
        self._steps = []
        for corners in motion.corners:  # (M, 3, 3) per step, + one padding row
            soup = np.zeros((3 * m + 1, 3), np.float32)
            soup[:-1] = corners.reshape(3 * m, 3)
            self._steps.append(soup)
        self._moving = np.arange(3 * m, dtype=np.uint32).reshape(m, 3)
        self._scene, ids = library.new_motion_scene(self._vertices, self._triangles, self._steps, self._moving)
        self._library = library
        self._order = np.concatenate([static, moving]).astype(np.int32)
        self._first = np.zeros(max(ids) + 1, np.int64)
        offsets = ([0] if len(static) else []) + [len(static)]
        for geom, offset in zip(ids, offsets):
            self._first[geom] = offset

    def _times(self, time: np.ndarray | None, n: int) -> np.ndarray:
        if time is None:
            raise ValueError("this scene has motion blur: every ray needs a time in [0, 1] (shutter open to close)")
        time = np.ascontiguousarray(time, dtype=np.float32)
        if time.shape != (n,):
            raise ValueError(f"{len(time)} ray times for {n} rays")
        return time

    def __del__(self) -> None:
        if getattr(self, "_scene", None) is not None:
            self._library.release_scene(self._scene)
            self._scene = None

    def count_rays(self, closest: int, shadow: int) -> None:
        """Count rays traced outside `intersect` / `occluded` (the fused path kernel, core.fused_path)."""
        with self._count_lock:
            self.rays_closest += closest
            self.rays_shadow += shadow

    def intersect(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | None = None,
                  time: np.ndarray | None = None) -> Hits:
        """Closest hit along each ray within (0, tmax]. origins, directions: (N, 3) float32 (unit directions).
        time: (N,) ray times in [0, 1] over the shutter, needed only by a scene with motion (ignored otherwise)."""
        n = len(origins)
        if n == 0 or self.triangle_count == 0:
            return Hits(np.full(n, -1, np.int32), np.zeros(n, np.float32), np.zeros(n, np.float32),
                        np.full(n, np.inf, np.float32))
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        if self.motion is not None:
            hits = Hits(np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32))
            bounds = np.empty(0, np.float32) if tmax is None else np.ascontiguousarray(tmax, dtype=np.float32)
            embree.trace_closest_timed(self._library.intersect1, self._scene, origins, directions, bounds,
                                       self._times(time, n), self._order, self._first, hits.prim, hits.u, hits.v,
                                       hits.t)
        elif self._scene is not None:
            hits = Hits(np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32))
            bounds = np.empty(0, np.float32) if tmax is None else np.ascontiguousarray(tmax, dtype=np.float32)
            embree.trace_closest(self._library.intersect1, self._scene, origins, directions, bounds,
                                 hits.prim, hits.u, hits.v, hits.t)
        else:
            # embreex overwrites dists in place: always hand it a fresh array
            dists = np.full(n, 3.0e38, np.float32) if tmax is None else np.minimum(tmax, np.float32(3.0e38), dtype=np.float32)
            r = self._wrapper.run(origins, directions, dists=dists, output=1)
            hits = Hits(r["primID"], r["u"], r["v"], r["tfar"])  # fresh arrays of this call
            hits.t[hits.prim < 0] = np.inf
        with self._count_lock:
            self.rays_closest += n
        return hits

    def occluded(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray,
                 time: np.ndarray | None = None) -> np.ndarray:
        """True where something lies along the ray within (0, tmax). (N,) bool. time: as for intersect."""
        n = len(origins)
        result = np.zeros(n, bool)
        if n == 0 or self.triangle_count == 0:
            return result
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        if self.motion is not None:
            embree.trace_occluded_timed(self._library.occluded1, self._scene, origins, directions,
                                        np.ascontiguousarray(tmax, dtype=np.float32), self._times(time, n), result)
        elif self._scene is not None:
            embree.trace_occluded(self._library.occluded1, self._scene, origins, directions,
                                  np.ascontiguousarray(tmax, dtype=np.float32), result)
        else:
            tmax = np.ascontiguousarray(np.minimum(tmax, 3.0e38), dtype=np.float32)
            r = self._wrapper.run(origins, directions, dists=tmax, query="OCCLUDED")  # overwrites dists
            result[:] = r != -1
        with self._count_lock:
            self.rays_shadow += n
        return result
