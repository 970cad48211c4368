"""Benchmark: a render on a local Dask cluster against the same render in one process.

    python -m monte.lab.bench_distributed [--resolution 128x128] [--spp 256] [--workers 2]

Prints the one-process render with `workers` threads, the LocalCluster render with `workers` processes of one
thread (a warm-up render first, so that both run with loaded kernels and the cluster's workers hold nothing
from it but the compiled code), their ratio (one-process seconds / cluster seconds: 1 means no overhead), the
bytes sent (the pickled scene, once to each worker; film sums back, per unit) and whether the images are equal
bit for bit. No assertion: speed on a shared machine is a number to read, not a test.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ..core.builtin_scenes import builtin_scene
from ..core.distributed import connect, render_on_cluster
from ..core.render import render
from ..core.settings import RenderSettings


def run(resolution: tuple[int, int], spp: int, workers: int, scene_name: str = "cornell") -> dict:
    scene = builtin_scene(scene_name, resolution)
    settings = RenderSettings(spp=spp, seed=1, threads=workers)
    render(builtin_scene(scene_name, (16, 16)), settings.replace(spp=1))  # load the kernels
    t0 = time.perf_counter()
    local = render(scene, settings)
    local_s = time.perf_counter() - t0
    with connect(f"local:{workers}") as client:
        render_on_cluster(scene, settings.replace(spp=1), client)  # warm-up: kernels loaded on every worker
        t0 = time.perf_counter()
        remote = render_on_cluster(scene, settings, client)
        cluster_s = time.perf_counter() - t0
    same = all(np.array_equal(getattr(local, k), getattr(remote, k))
               for k in ("color", "variance", "albedo", "normal", "depth", "sample_count"))
    st = remote.stats
    return {"scene": scene_name, "resolution": list(resolution), "spp": spp, "workers": workers,
            "local_seconds": local_s, "cluster_seconds": cluster_s, "ratio": local_s / cluster_s,
            "units": st["units"], "scene_bytes": st["scene_bytes"], "film_bytes": st["film_bytes"],
            "film_bytes_per_unit": st["film_bytes_per_unit"], "merge_seconds": st["merge_seconds"],
            "bit_identical": same}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m monte.lab.bench_distributed", description=__doc__.split("\n")[0])
    p.add_argument("--resolution", default="128x128")
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--scene", default="cornell")
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.resolution.lower().split("x"))
    r = run((w, h), a.spp, a.workers, a.scene)
    print(f"{r['scene']} {w}x{h} at {r['spp']} spp: one process, {r['workers']} threads {r['local_seconds']:.2f} s; "
          f"LocalCluster of {r['workers']} processes {r['cluster_seconds']:.2f} s (ratio {r['ratio']:.2f}); "
          f"{r['units']} units; scene {r['scene_bytes'] / 1e3:.0f} kB to each worker; film sums back "
          f"{r['film_bytes'] / 1e6:.2f} MB ({r['film_bytes_per_unit'] / 1e3:.0f} kB per unit), merged in "
          f"{r['merge_seconds'] * 1e3:.0f} ms; bit-identical: {r['bit_identical']}")
    return 0 if r["bit_identical"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
