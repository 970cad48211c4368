"""Throughput of the procedural textures' batch functions (core.shading.procedural), one thread.

Run: `.venv/bin/python -m monte.lab.bench_procedural [points]`; prints million points per second for each
texture at typical settings (the first call of each compiles or loads its kernels and is not timed).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from ..core.shading import procedural as tex

CASES = {
    "white noise 3D": lambda co: tex.white_noise(co, 3),
    "checker": lambda co: tex.checker(co),
    "gradient spherical": lambda co: tex.gradient(co, "SPHERICAL"),
    "noise fBM 3D detail 2": lambda co: tex.noise(co, 3),
    "noise fBM 4D detail 2": lambda co: tex.noise(co, 4),
    "noise ridged 3D detail 8": lambda co: tex.noise(co, 3, detail=8.0, noise_type="RIDGED_MULTIFRACTAL"),
    "voronoi F1 3D": lambda co: tex.voronoi(co, 3),
    "voronoi smooth F1 3D": lambda co: tex.voronoi(co, 3, feature="SMOOTH_F1"),
    "voronoi F1 4D": lambda co: tex.voronoi(co, 4),
    "voronoi edge 3D": lambda co: tex.voronoi(co, 3, feature="DISTANCE_TO_EDGE"),
    "wave bands distorted": lambda co: tex.wave(co, distortion=2.0),
    "magic depth 2": lambda co: tex.magic(co),
    "brick": lambda co: tex.brick(co),
}


def run(points: int = 200_000) -> dict[str, float]:
    """Million points per second of each texture on `points` random coordinates in [-5, 5]^4."""
    co = (np.random.default_rng(1).random((points, 4)) * 10 - 5).astype(np.float32)
    rates = {}
    for name, fn in CASES.items():
        fn(co[:16])
        t = time.perf_counter()
        fn(co)
        rates[name] = points / (time.perf_counter() - t) / 1e6
    return rates


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200_000
    for name, rate in run(n).items():
        print(f"{name:28s} {rate:8.2f} Mpoints/s")
