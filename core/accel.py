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

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, backend: str | None = None) -> None:
        """vertices: (V, 3) float32; triangles: (T, 3) int32 indices into vertices (validated by the caller)."""
        if backend not in (None, "embree", "embreex"):
            raise ValueError(f"unknown ray-casting backend {backend!r} (expected 'embree' or 'embreex')")
        self.triangle_count = int(len(triangles))
        self.rays_closest = 0
        self.rays_shadow = 0
        self._count_lock = threading.Lock()
        self._library = None
        self._scene = None
        library, why_not = embree.load() if backend != "embreex" else (None, None)
        if library is None and backend == "embree":
            raise RuntimeError(f"the Embree backend is not available: {why_not}")
        if library is None and why_not:
            warnings.warn(f"{why_not}; casting rays through embreex's wrapper (slower)", RuntimeWarning, stacklevel=2)
        self.backend = "embree" if library is not None else "embreex"
        if not self.triangle_count:
            return
        if library is not None:
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

    def __del__(self) -> None:
        if getattr(self, "_scene", None) is not None:
            self._library.release_scene(self._scene)
            self._scene = None

    def intersect(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | None = None) -> Hits:
        """Closest hit along each ray within (0, tmax]. origins, directions: (N, 3) float32 (unit directions)."""
        n = len(origins)
        if n == 0 or self.triangle_count == 0:
            return Hits(np.full(n, -1, np.int32), np.zeros(n, np.float32), np.zeros(n, np.float32),
                        np.full(n, np.inf, np.float32))
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        if self._scene is not None:
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

    def occluded(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        """True where something lies along the ray within (0, tmax). (N,) bool."""
        n = len(origins)
        result = np.zeros(n, bool)
        if n == 0 or self.triangle_count == 0:
            return result
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        if self._scene is not None:
            embree.trace_occluded(self._library.occluded1, self._scene, origins, directions,
                                  np.ascontiguousarray(tmax, dtype=np.float32), result)
        else:
            tmax = np.ascontiguousarray(np.minimum(tmax, 3.0e38), dtype=np.float32)
            r = self._wrapper.run(origins, directions, dists=tmax, query="OCCLUDED")  # overwrites dists
            result[:] = r != -1
        with self._count_lock:
            self.rays_shadow += n
        return result
