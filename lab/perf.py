"""`monte perf`: where render time and memory go, measured on the built-in scenes. Prints numbers only.

Sections (each a short run; all in one process, interleaved where two variants are compared):
- stages: thread-seconds per wavefront stage of the per-bounce integrator (camera rays, Embree closest hits, Embree shadow rays, emission and
  surface interaction, next-event estimation, BSDF sampling and compaction, film) and Embree's share of the
  worker thread-time.
- threads: samples/s at 1, 2, ... N worker threads and the speed-up over 1 (alternating runs, best of `repeat`).
- balance: how evenly the batches keep the threads busy, the last batches shrinking or not: measured on this
  machine's threads and projected to 2-64 threads from a per-pixel cost map (lab/schedule_balance.py).
- memory: peak NumPy allocation (tracemalloc) of a batch of paths per batch size, and MB per million paths in
  flight (the slope), of the per-bounce integrator (these two sections set MONTE_FUSED=0: the fused path kernel
  has no stages and no per-bounce arrays).
- skip: the diffuse-only Cornell box with and without an unused glass material (features a scene does not use
  cost nothing: the times should agree within noise).
- adaptive: the Cornell box and the spheres-under-sky scene at a fixed spp with adaptive sampling off and on,
  RMSE against a long render of the same scene, the time saved, and the time at equal error (efficiency ratio).
- nodes: ns per node per shading point of the main shading nodes (Image Texture, Noise (Color; Fac at detail 0,
  2, 8), Voronoi, Wave, Mix, Math, Color Ramp, Bump, Normal Map, Principled), compiled from real Blender
  materials (lab/perf_nodes.py; needs bpy).
- sampled: where the shipped fused path kernel's CPU goes on the Cornell box (Embree, the compiled kernel, libm),
  sampled by Linux `perf` (cpu-clock) without an instrumented copy (lab/fused_sampling.py; needs the perf tool).
- fused (only when named): where the fused path kernel's time goes, Embree's closest hits and shadow rays against
  the rest of a path, from a measurement copy of the kernel that reads the CPU's cycle counter (lab/fused_timing.py).
- textured: the `textured` bench scene on one thread: CPU seconds, stages and the functions with the most own
  time under cProfile (lab/perf_textured.py; needs bpy).
Nothing here asserts a time: machines are shared and noisy; compare ratios within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import tracemalloc

import numpy as np

from ..core.scene import Lobe, Material
from ..core.builtin_scenes import cornell_box, cornell_diffuse, spheres_under_sky
from ..core.settings import RenderSettings
from .bench_math import efficiency

# The command's options live in bench_args (argparse only), so building `monte`'s parser imports none of this.
from .bench_args import PERF_SECTIONS as SECTIONS, add_perf_arguments as add_arguments  # noqa: E402,F401

DEFAULT_SECTIONS = SECTIONS[:-1]  # "fused" compiles a measurement copy of the fused kernel (minutes): asked for only


def render(scene, settings: RenderSettings):
    """core.render.render, imported on the first measurement: `monte render` should not import the renderer's
    kernels before it needs them."""
    from ..core.render import render as core_render

    return core_render(scene, settings)


def _settings(**kw) -> RenderSettings:
    return RenderSettings(**kw).validate()


class _PerBounce:
    """Within it, renders use the per-bounce integrator (MONTE_FUSED=0): the stage split and the memory of the
    paths' arrays are that integrator's (the fused path kernel, core.fused_path, has no stages and holds a batch's
    camera rays and radiance only)."""

    def __enter__(self):
        self._before = os.environ.get("MONTE_FUSED")
        os.environ["MONTE_FUSED"] = "0"

    def __exit__(self, *exc):
        if self._before is None:
            os.environ.pop("MONTE_FUSED", None)
        else:
            os.environ["MONTE_FUSED"] = self._before


def stage_profile(resolution: int, spp: int, threads: int) -> dict:
    """Thread-seconds per stage of one Cornell box render."""
    with _PerBounce():
        result = render(cornell_box((resolution, resolution)), _settings(spp=spp, threads=threads))
    st = result.stats
    stages = st["stage_seconds"]
    total = sum(stages.values())
    return {"seconds": st["seconds"], "samples_per_second": st["samples_per_second"],
            "rays_per_second": st["rays_per_second"], "embree_share": st["embree_share"],
            "stage_seconds": stages, "stage_share": {k: v / max(total, 1e-9) for k, v in stages.items()}}


def thread_scaling(resolution: int, spp: int, max_threads: int, repeat: int) -> dict:
    """Samples/s per worker-thread count, alternating the counts so load changes hit all of them."""
    counts = sorted({1, 2, max_threads} | ({4, 8, 16} & set(range(1, max_threads + 1))))
    best: dict[int, float] = {}
    for _ in range(repeat):
        for n in counts:
            st = render(cornell_box((resolution, resolution)), _settings(spp=spp, threads=n)).stats
            best[n] = max(best.get(n, 0.0), st["samples_per_second"])
    return {"samples_per_second": {str(n): best[n] for n in counts},
            "speedup": {str(n): best[n] / best[1] for n in counts}}


def memory_per_batch(resolution: int, spp: int, batches: list[int]) -> dict:
    """Peak traced allocation (NumPy reports to tracemalloc) of a batch of paths above what was allocated when it
    started: its camera rays, the paths' state, every per-bounce temporary and its results. One worker thread, so
    batches run one at a time on the calling thread; the largest over the render's batches, per batch size. The
    slope against the batch size is the cost per path in flight (fixed costs, e.g. next-event estimation's chunk of
    core.integrator.NEE_CHUNK paths, fall out of it); bytes_per_path: the largest batch's peak over its paths."""
    from ..core import render as render_mod

    traced = render_mod._TileRender._trace_batch
    peaks: list[tuple[int, int]] = []

    def measured(self, segments):
        start = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        out = traced(self, segments)
        peaks.append((tracemalloc.get_traced_memory()[1] - start, sum(len(seg.loc) for seg in segments)))
        return out

    rows = []
    render_mod._TileRender._trace_batch = measured
    per_bounce = _PerBounce()
    per_bounce.__enter__()
    try:
        for batch in batches:
            peaks.clear()
            # enough samples for full batches of this size (core.schedule.batch_target makes at least 8)
            spp_here = max(spp, -(-8 * batch // (resolution * resolution)))
            tracemalloc.start()
            try:
                st = render(cornell_box((resolution, resolution)),
                            _settings(spp=spp_here, threads=1, batch_paths=batch, tile_size=64)).stats
            finally:
                tracemalloc.stop()
            peak, paths = max(peaks)
            rows.append({"batch_paths": batch, "largest_batch": st["largest_batch"], "peak_mb": peak / 2**20,
                         "bytes_per_path": peak / paths})
    finally:
        render_mod._TileRender._trace_batch = traced
        per_bounce.__exit__(None, None, None)
    x = np.array([r["largest_batch"] for r in rows], float)
    y = np.array([r["peak_mb"] for r in rows], float)
    slope = float(np.polyfit(x / 1e6, y, 1)[0]) if len(rows) > 1 else float(y[0] / (x[0] / 1e6))
    return {"rows": rows, "mb_per_million_paths": slope, "bytes_per_path": rows[-1]["bytes_per_path"]}


def _with_unused_glass(scene):
    scene.materials.append(Material("unused_glass", [Lobe("glass", np.full(3, 0.999), roughness=0.0, ior=1.5)]))
    scene.name += "+unused-glass"
    return scene


def feature_skip(resolution: int, spp: int, threads: int, repeat: int) -> dict:
    """Diffuse-only box with and without an unused glass material: best-of times, alternating."""
    times = {"plain": [], "unused_glass": []}
    for _ in range(repeat):
        for key in times:
            scene = cornell_diffuse((resolution, resolution))
            if key == "unused_glass":
                scene = _with_unused_glass(scene)
            times[key].append(render(scene, _settings(spp=spp, threads=threads)).stats["seconds"])
    plain, glass = min(times["plain"]), min(times["unused_glass"])
    return {"seconds_plain": plain, "seconds_unused_glass": glass, "ratio": glass / plain, "all": times}


def adaptive_saving(resolution: int, spp: int, threads: int, threshold: float, builder=cornell_box) -> dict:
    """Adaptive sampling off vs on at the same spp: time, samples taken and RMSE against a 4x longer render;
    the efficiency 1/(seconds x MSE) of each, whose ratio is the time saved at equal error."""
    size = (resolution, resolution)
    reference = render(builder(size), _settings(spp=4 * spp, threads=threads, seed=99, aovs=False)).color[..., :3]
    out = {"scene": builder(size).name}
    for name, thr in (("off", 0.0), ("on", threshold)):
        r = render(builder(size), _settings(spp=spp, threads=threads, adaptive_threshold=thr, aovs=False))
        err = float(np.sqrt(np.mean((r.color[..., :3] - reference) ** 2)))
        out[name] = {"seconds": r.stats["seconds"], "samples": int(r.sample_count.sum()), "rmse": err,
                     "efficiency": efficiency(r.stats["seconds"], err * err)}
    out["threshold"] = threshold
    out["time_saved"] = 1 - out["on"]["seconds"] / out["off"]["seconds"]
    out["efficiency_gain"] = out["on"]["efficiency"] / out["off"]["efficiency"]
    return out


def run_perf(args: argparse.Namespace) -> dict:
    sections = args.sections or list(DEFAULT_SECTIONS)
    res, spp = args.resolution, args.spp
    threads = args.threads or (os.cpu_count() or 1)
    report: dict = {"resolution": res, "spp": spp, "threads": threads}
    if "stages" in sections:
        r = report["stages"] = stage_profile(res, spp, threads)
        print(f"Stages (Cornell box {res}x{res}, {spp} spp, {threads} threads): {r['seconds']:.2f} s, "
              f"{r['samples_per_second'] / 1e3:.0f} k samples/s, {r['rays_per_second'] / 1e6:.2f} M rays/s, "
              f"Embree {100 * r['embree_share']:.0f}% of worker time")
        for k, v in r["stage_seconds"].items():
            print(f"  {k:10s} {v:7.2f} thread-s  {100 * r['stage_share'][k]:5.1f}%")
    if "threads" in sections:
        r = report["threads"] = thread_scaling(res, spp, threads, args.repeat)
        print("Thread scaling (best of %d): " % args.repeat + ", ".join(
            f"{n}: {v / 1e3:.0f} k/s ({r['speedup'][n]:.2f}x)" for n, v in r["samples_per_second"].items()))
    if "balance" in sections:
        from .schedule_balance import balance, print_balance

        report["balance"] = balance(res, spp, threads, max(args.repeat, 3))
        print_balance(report["balance"], res, spp)
    if "memory" in sections:
        r = report["memory"] = memory_per_batch(args.memory_resolution, 1, args.memory_batches)
        print("Peak NumPy memory of a batch by its size: " + ", ".join(
            f"{row['largest_batch']} paths: {row['peak_mb']:.1f} MB" for row in r["rows"])
            + f"; paths in flight {r['mb_per_million_paths']:.0f} MB per million (x worker threads; "
            f"{r['bytes_per_path']:.0f} B per path in the largest batch)")
    if "skip" in sections:
        r = report["skip"] = feature_skip(res, spp, threads, args.repeat)
        print(f"Unused glass material: {r['seconds_plain']:.2f} s without, {r['seconds_unused_glass']:.2f} s with "
              f"(ratio {r['ratio']:.3f})")
    if "adaptive" in sections:
        report["adaptive"] = []
        for builder in (cornell_box, spheres_under_sky):
            r = adaptive_saving(128, args.adaptive_spp, threads, args.adaptive_threshold, builder)
            report["adaptive"].append(r)
            print(f"Adaptive sampling, {r['scene']} (threshold {r['threshold']}): off {r['off']['seconds']:.2f} s, "
                  f"RMSE {r['off']['rmse']:.4f}, efficiency {r['off']['efficiency']:.1f}; on "
                  f"{r['on']['seconds']:.2f} s, RMSE {r['on']['rmse']:.4f}, efficiency {r['on']['efficiency']:.1f}, "
                  f"{r['on']['samples'] / r['off']['samples']:.0%} of the samples; time saved {r['time_saved']:.0%}, "
                  f"time at equal error x{1 / r['efficiency_gain']:.2f}")
    if "nodes" in sections:
        import importlib.util

        if importlib.util.find_spec("bpy") is None:
            # the node programs are compiled from real Blender materials; a core-only install has no bpy
            print("Node costs skipped: the nodes section needs Blender's bpy module (pip install bpy)")
        else:
            from .perf_nodes import node_costs, print_node_costs

            r = report["nodes"] = node_costs(points=args.node_points, repeat=max(args.repeat, 3))
            print_node_costs(r)
    if "textured" in sections:
        import importlib.util

        if importlib.util.find_spec("bpy") is None:
            print("Textured profile skipped: the scene is built in Blender (needs the bpy module)")
        else:
            from .perf_textured import print_textured_profile, textured_profile

            r = report["textured"] = textured_profile(res, spp, args.repeat)
            print_textured_profile(r)
    if "sampled" in sections:
        from .fused_sampling import measure as sample_fused, report as print_sampled

        try:
            r = report["sampled"] = sample_fused(res, spp, max(threads, 1))
        except (OSError, RuntimeError) as e:  # no Linux perf tool, perf refused (perf_event_paranoid), the child failed
            print(f"Sampled split of the fused kernel skipped: {e}")
        else:
            print_sampled(r)
    if "fused" in sections:
        from .fused_timing import measure, report as print_fused

        r = report["fused"] = measure(res, spp, threads)
        print_fused(r)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=2)
    return report
