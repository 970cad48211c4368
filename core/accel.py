"""Ray casting with Embree (embreex): closest hits and occlusion, in chunks across threads.

embreex releases the GIL inside `run`, so a thread pool over ray chunks scales across cores. Embree's tnear is
fixed at 0 here: callers offset ray origins off surfaces themselves (see `offset_ray_origin`).
All coordinates are float32 in the integrator's shifted frame (world minus the camera position).
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from embreex import mesh_construction, rtcore_scene

# Rays per Embree call: large enough to amortise the call, small enough to balance across threads.
_CHUNK = 1 << 15


@dataclass
class Hits:
    """Closest hits of N rays. prim: triangle index (-1 = miss); u, v: barycentrics of vertices 1 and 2;
    t: distance along the (unit) direction; valid only where prim >= 0."""

    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    t: np.ndarray


class Accelerator:
    """An Embree scene over one triangle soup, plus counters for benchmarks (rays cast, seconds inside Embree)."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, threads: int = 1) -> None:
        """vertices: (V, 3) float32; triangles: (T, 3) int32 indices. threads: worker threads for ray chunks."""
        self.threads = max(1, int(threads))
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
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        self.rays_closest = 0
        self.rays_shadow = 0
        self.seconds = 0.0
        self._count_lock = threading.Lock()  # render workers share this accelerator

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def _chunks(self, n: int) -> list[slice]:
        per = max(min(_CHUNK, -(-n // self.threads)), 1024)
        return [slice(i, min(i + per, n)) for i in range(0, n, per)]

    def _map(self, fn, n: int) -> None:
        chunks = self._chunks(n)
        if self._pool is None or len(chunks) == 1:
            for c in chunks:
                fn(c)
        else:
            list(self._pool.map(fn, chunks))

    def intersect(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | None = None) -> Hits:
        """Closest hit along each ray within (0, tmax]. origins, directions: (N, 3) float32 (unit directions)."""
        n = len(origins)
        prim = np.full(n, -1, np.int32)
        u = np.zeros(n, np.float32)
        v = np.zeros(n, np.float32)
        t = np.full(n, np.inf, np.float32)
        if n == 0 or self.triangle_count == 0:
            return Hits(prim, u, v, t)
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        if tmax is not None:
            tmax = np.ascontiguousarray(np.minimum(tmax, 3.0e38), dtype=np.float32)

        def work(c: slice) -> None:
            dists = None if tmax is None else tmax[c].copy()  # embreex overwrites dists in place
            r = self._scene.run(origins[c], directions[c], dists=dists, output=1)
            prim[c] = r["primID"]
            u[c] = r["u"]
            v[c] = r["v"]
            t[c] = r["tfar"]

        start = time.perf_counter()
        self._map(work, n)
        with self._count_lock:
            self.seconds += time.perf_counter() - start
            self.rays_closest += n
        t[prim < 0] = np.inf
        return Hits(prim, u, v, t)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        """True where something lies along the ray within (0, tmax). (N,) bool."""
        n = len(origins)
        result = np.zeros(n, bool)
        if n == 0 or self.triangle_count == 0:
            return result
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        tmax = np.ascontiguousarray(np.minimum(tmax, 3.0e38), dtype=np.float32)

        def work(c: slice) -> None:
            r = self._scene.run(origins[c], directions[c], dists=tmax[c].copy(), query="OCCLUDED")
            result[c] = r != -1

        start = time.perf_counter()
        self._map(work, n)
        with self._count_lock:
            self.seconds += time.perf_counter() - start
            self.rays_shadow += n
        return result


def offset_ray_origin(p: np.ndarray, ng: np.ndarray, toward: np.ndarray, magnitude: np.ndarray) -> np.ndarray:
    """Move points `p` off their surface along the geometric normal `ng` (unit, (N,3)) to the side of `toward`
    (the new ray's direction), by an amount proportional to the coordinates' float32 rounding error.

    magnitude: (N,) the largest absolute coordinate involved in computing p (of p itself and of the hit
    triangle's vertices). A point interpolated from float32 vertices is wrong by a few ulps of that magnitude
    (pbrt-v4's error bounds; Wachter & Binder, Ray Tracing Gems ch. 6). An offset of 2^-19 (~64 ulps) of it
    clears the error with margin at any scale; the floor keeps points at the origin from a zero offset.
    """
    eps = np.maximum(magnitude * np.float32(2.0**-19), np.float32(1e-30))
    side = np.where(np.einsum("ij,ij->i", ng, toward) >= 0, eps, -eps).astype(np.float32)
    return p + ng * side[:, None]
