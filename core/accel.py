"""Ray casting with Embree (embreex): closest hits and occlusion.

embreex releases the GIL inside `run`, so render worker threads cast their batches' rays in parallel through
one shared scene. Embree's tnear is fixed at 0 here: callers offset ray origins off surfaces themselves (see
core.kernels._offset). All coordinates are float32 in the integrator's shifted frame (world minus the camera
position).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from embreex import mesh_construction, rtcore_scene


@dataclass
class Hits:
    """Closest hits of N rays. prim: triangle index (-1 = miss); u, v: barycentrics of vertices 1 and 2;
    t: distance along the (unit) direction; valid only where prim >= 0."""

    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    t: np.ndarray


class Accelerator:
    """An Embree scene over one triangle soup, shared by the render's worker threads, plus ray counters."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        """vertices: (V, 3) float32; triangles: (T, 3) int32 indices."""
        self.triangle_count = int(len(triangles))
        self._scene = rtcore_scene.EmbreeScene()
        if self.triangle_count:
            mesh_construction.TriangleMesh(
                self._scene,
                np.ascontiguousarray(vertices, dtype=np.float32),
                np.ascontiguousarray(triangles, dtype=np.int32),
            )
            # The scene commits on its first run; do it here, before threads share it.
            self._scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self.rays_closest = 0
        self.rays_shadow = 0
        self._count_lock = threading.Lock()

    def intersect(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | None = None) -> Hits:
        """Closest hit along each ray within (0, tmax]. origins, directions: (N, 3) float32 (unit directions)."""
        n = len(origins)
        if n == 0 or self.triangle_count == 0:
            return Hits(np.full(n, -1, np.int32), np.zeros(n, np.float32), np.zeros(n, np.float32),
                        np.full(n, np.inf, np.float32))
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        # embreex overwrites dists in place: always hand it a fresh array
        dists = np.full(n, 3.0e38, np.float32) if tmax is None else np.minimum(tmax, np.float32(3.0e38), dtype=np.float32)
        r = self._scene.run(origins, directions, dists=dists, output=1)
        with self._count_lock:
            self.rays_closest += n
        prim, t = r["primID"], r["tfar"]  # fresh arrays of this call
        t[prim < 0] = np.inf
        return Hits(prim, r["u"], r["v"], t)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        """True where something lies along the ray within (0, tmax). (N,) bool."""
        n = len(origins)
        result = np.zeros(n, bool)
        if n == 0 or self.triangle_count == 0:
            return result
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        tmax = np.ascontiguousarray(np.minimum(tmax, 3.0e38), dtype=np.float32)

        r = self._scene.run(origins, directions, dists=tmax, query="OCCLUDED")  # overwrites dists
        result[:] = r != -1
        with self._count_lock:
            self.rays_shadow += n
        return result
