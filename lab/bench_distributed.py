"""Benchmark: a render on a local Dask cluster against the same render in one process.

    python -m monte.lab.bench_distributed [--resolution 128x128] [--spp 256] [--workers 2] [--repeats 3]
                                          [--passes mist,crypto_object,...]

Prints the one-process render with `workers` threads and the LocalCluster render with `workers` processes of one
thread, `repeats` times interleaved (one-process, cluster, one-process, cluster, ...: a shared machine's load
then weighs on both alike), after a warm-up of each (so that both run with loaded kernels and the cluster's
workers hold nothing from it but the compiled code). Reports each pair's ratio (one-process seconds / cluster
seconds: 1 means no overhead), their median and spread (min - max), the bytes per frame (the pickled scene,
once to each worker; the film sums back, the data passes' share with --passes), the client's merge time, the
tasks' scheduling overhead (a no-op task's round trip through the scheduler, and per unit: the cluster's wall time
x threads less the units' compute time on the workers, from Dask's task stream) and whether every image (the
data passes' too) is equal bit for bit. No assertion: speed on a shared machine is a number to read, not a test.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from ..core.builtin_scenes import builtin_scene
from ..core.distributed import connect, render_on_cluster
from ..core.render import render
from ..core.settings import RenderSettings

IMAGES = ("color", "variance", "albedo", "normal", "depth", "sample_count")


def run(resolution: tuple[int, int], spp: int, workers: int, scene_name: str = "cornell", repeats: int = 3,
        passes: tuple[str, ...] = ()) -> dict:
    from distributed import get_task_stream

    scene = builtin_scene(scene_name, resolution)
    settings = RenderSettings(spp=spp, seed=1, threads=workers, data_passes=passes)
    render(builtin_scene(scene_name, (16, 16)), settings.replace(spp=1))  # load the kernels
    local_s, cluster_s, same = [], [], True
    reference = None
    with connect(f"local:{workers}") as client:
        render_on_cluster(scene, settings.replace(spp=1), client)  # warm-up: kernels loaded on every worker
        round_trip = _no_op_round_trip(client)
        compute = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            local = render(scene, settings)
            local_s.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            with get_task_stream(client) as stream:
                remote = render_on_cluster(scene, settings, client)
            cluster_s.append(time.perf_counter() - t0)
            compute.append(sum(ss["stop"] - ss["start"] for task in stream.data for ss in task["startstops"]
                               if ss["action"] == "compute" and str(task["key"]).startswith("monte-unit-")))
            reference = local if reference is None else reference
            same = same and all(np.array_equal(getattr(reference, k), getattr(x, k)) for k in IMAGES
                                for x in (local, remote))
            same = same and sorted(remote.data_passes) == sorted(reference.data_passes) and all(
                np.array_equal(reference.data_passes[k], remote.data_passes[k]) for k in reference.data_passes)
    st = remote.stats
    overhead = [(c * st["threads"] - w) / st["units"] for c, w in zip(cluster_s, compute)]
    ratios = [a / b for a, b in zip(local_s, cluster_s)]
    return {"scene": scene_name, "resolution": list(resolution), "spp": spp, "workers": workers,
            "local_seconds": local_s, "cluster_seconds": cluster_s, "ratios": ratios,
            "ratio_median": statistics.median(ratios), "ratio_min": min(ratios), "ratio_max": max(ratios),
            "units": st["units"], "scene_bytes": st["scene_bytes"], "scene_bytes_per_frame": st["scene_bytes"] *
            st["workers"], "film_bytes": st["film_bytes"], "film_bytes_per_unit": st["film_bytes_per_unit"],
            "data_pass_bytes": st["data_pass_bytes"], "passes": list(passes),
            "merge_seconds": st["merge_seconds"], "no_op_round_trip_seconds": round_trip,
            "unit_compute_seconds": [c / st["units"] for c in compute],
            "overhead_seconds_per_unit": overhead, "bit_identical": same}


def _no_op_round_trip(client, tasks: int = 200) -> float:
    """Seconds per task of `tasks` no-op tasks submitted at once and gathered: the scheduler's and the transport's
    own cost of a task, without any work in it."""
    t0 = time.perf_counter()
    client.gather(client.map(_no_op, range(tasks), pure=False))
    return (time.perf_counter() - t0) / tasks


def _no_op(i: int) -> int:
    return i


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m monte.lab.bench_distributed", description=__doc__.split("\n")[0])
    p.add_argument("--resolution", default="128x128")
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--scene", default="cornell")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--passes", default="", help="data passes (core.data_passes keys, comma-separated)")
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.resolution.lower().split("x"))
    r = run((w, h), a.spp, a.workers, a.scene, a.repeats, tuple(k for k in a.passes.split(",") if k))
    for i, (ls, cs, ratio) in enumerate(zip(r["local_seconds"], r["cluster_seconds"], r["ratios"])):
        print(f"run {i + 1}: one process, {r['workers']} threads {ls:.2f} s; LocalCluster of {r['workers']} "
              f"processes {cs:.2f} s; ratio {ratio:.2f}")
    print(f"{r['scene']} {w}x{h} at {r['spp']} spp: ratio median {r['ratio_median']:.2f} (spread "
          f"{r['ratio_min']:.2f} - {r['ratio_max']:.2f} over {len(r['ratios'])} interleaved pairs); "
          f"{r['units']} units; "
          f"per frame: scene {r['scene_bytes'] / 1e3:.0f} kB to each worker ({r['scene_bytes_per_frame'] / 1e3:.0f} kB "
          f"out), film sums back {r['film_bytes'] / 1e6:.2f} MB ({r['film_bytes_per_unit'] / 1e3:.0f} kB per unit), "
          f"merged in {r['merge_seconds'] * 1e3:.0f} ms; bit-identical: {r['bit_identical']}")
    if r["passes"]:
        print(f"data passes {','.join(r['passes'])}: {r['data_pass_bytes'] / 1e6:.2f} MB of the film sums back")
    print(f"scheduling: a no-op task's round trip {r['no_op_round_trip_seconds'] * 1e3:.1f} ms; per unit "
          f"{statistics.median(r['unit_compute_seconds']):.2f} s of compute on a worker and "
          f"{statistics.median(r['overhead_seconds_per_unit']) * 1e3:.0f} ms beyond it (the cluster's wall time x "
          f"threads less the units' compute, per unit: scheduling, transfers, the scene's preparation, idle "
          f"threads at the end; medians over the runs)")
    return 0 if r["bit_identical"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
