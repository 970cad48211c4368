"""`monte bench --vs cycles --whole-process`: Monte and Cycles timed as whole processes, as a user runs them.

For each scene (a bench scene from bpy_scenes, or a user's .blend), the scene is saved to a temporary .blend
and rendered, after one untimed run of each, alternately by two fresh processes: `python -m monte render
X.blend -o m.exr --file-passes --spp N ...` and a plain bpy process doing what `blender -b X.blend -E CYCLES -f 1`
does (open the file, render with Cycles, write a 32-bit EXR); both render and write the passes the file's view
layer ticks (the bench scenes: the image alone). The time is the process's wall time, start to exit: the Python and bpy imports, opening
the file, Monte's kernel loading and export or Cycles' sync, the render and writing the image, everything the
render-call bench (lab/bench_cycles.py) leaves out. Settings as that bench's: the same samples, seed, bounce
limit, Blackman-Harris 1.5 px filter and threads, Cycles without denoising, adaptive sampling or clamping.
The error is the RMSE against the cached converged Cycles reference (its own noise removed), the efficiency
1/(seconds x MSE) with the whole process's seconds: the best of the repeats (`efficiency`) and their median
(`efficiency_median`: on a shared machine the median is the figure to quote). Each process's CPU seconds (user +
system, its threads included) are reported beside its wall time: on a loaded machine they vary less.

Writes OUTDIR/bench_whole_process.json and returns the report; prints a table.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Callable, Sequence

import bpy
import numpy as np

from ..addon.crosscheck import configure_cycles
from ..core import jit_cache, metrics
from . import bench_cycles
from .bench_math import corrected_rmse, efficiency, format_table, write_json
from .bench_reference import ReferenceCache

# What `blender -b X.blend -E CYCLES -o OUT -f 1` does, in the bpy module (there is no Blender binary here).
_CYCLES_PROCESS = textwrap.dedent("""
    import sys
    import bpy
    blend, out = sys.argv[1], sys.argv[2]
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False)
    scene = bpy.context.scene
    scene.render.filepath = out
    bpy.ops.render.render(write_still=True)
""")


def _run(command: list[str], env: dict) -> tuple[float, float]:
    """(wall seconds, CPU seconds: user + system) of one process from start to exit; a failure raises with its
    output."""
    before = os.times()
    t0 = time.perf_counter()
    proc = subprocess.run(command, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    after = os.times()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:4])} ... failed (exit {proc.returncode}):\n{proc.stdout[-2000:]}\n"
                           f"{proc.stderr[-2000:]}")
    return seconds, (after.children_user - before.children_user) + (after.children_system - before.children_system)


def _process_env(tmp_dir: Path) -> dict:
    """The renderers' environment: this one (its PYTHONPATH too, so that `python -m monte` runs the checkout the
    bench runs from: without it, a checkout on PYTHONPATH benched whatever `monte` the working folder or the
    installed package gave), with Python's bytecode cache on (into a folder of tmp_dir unless PYTHONPYCACHEPREFIX
    names one), as a user's processes have it: with PYTHONDONTWRITEBYTECODE set, every Monte process compiled its
    ~80 modules from source again (~0.3 s of CPU) while bpy's own scripts ship compiled. Without the kernel CPU
    level this process's Monte wrote into its environment (jit_cache.child_environment): each renderer process
    chooses its own, as a user's does, and a Monte started from another checkout is not handed this one's."""
    env = {k: v for k, v in jit_cache.child_environment().items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.setdefault("PYTHONPYCACHEPREFIX", str(tmp_dir / "pycache"))
    return env


def _save_for_cycles(scene, path: Path, spp: int, seed: int, threads: int, max_bounces: int, out: Path) -> None:
    configure_cycles(scene, spp, max_bounces, threads, seed=seed, filter_type="blackman-harris", filter_width=1.5)
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5.0+
        settings.media_type = "IMAGE"
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    scene.render.use_file_extension = False
    scene.render.filepath = str(out)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True, compress=False)


def bench_scene_whole_process(spec: str, *, cache: ReferenceCache, spp: int = 64, repeats: int = 3,
                              threads: int = 2, max_bounces: int = 16, resolution: tuple[int, int] | None = None,
                              reference_spp: int = 1024, reference_seeds: int = 4, seed: int = 1,
                              log: Callable[[str], None] = print) -> dict:
    """Both renderers as whole processes, `repeats` times each, alternating; returns the scene's report (the
    best wall time of each, and the error of its image)."""
    scene, name, version = bench_cycles._load_scene(spec, resolution)
    res = bench_cycles._resolution_of(scene)
    log(f"{name} {res[0]}x{res[1]}, {spp} spp, {threads} threads, whole processes x{repeats}")
    params = bench_cycles.reference_params(name, version, res, max_bounces, reference_spp, reference_seeds)
    ref = bench_cycles.ensure_reference(scene, params, cache, threads, log)
    with tempfile.TemporaryDirectory(prefix="monte-whole-") as tmp:
        tmp_dir = Path(tmp)
        env = _process_env(tmp_dir)
        blend, monte_out, cycles_out = tmp_dir / f"{name}.blend", tmp_dir / "monte.exr", tmp_dir / "cycles.exr"
        _save_for_cycles(scene, blend, spp, seed, threads, max_bounces, cycles_out)
        # --file-passes: the passes the file's view layer ticks (the bench scenes: the image alone), as Cycles'
        # process renders and writes them; without it Monte's layout adds Z, normal and albedo, which cost the
        # render 5-10 % of its CPU and which Cycles' process neither computes nor writes
        monte_cmd = [sys.executable, "-m", "monte", "render", str(blend), "-o", str(monte_out), "--no-png", "-q",
                     "--file-passes",
                     "--spp", str(spp), "--seed", str(seed), "--threads", str(threads), "--max-bounces",
                     str(max_bounces), "--filter", "blackman-harris", "--filter-width", "1.5", "--clamp", "0"]
        cycles_cmd = [sys.executable, "-c", _CYCLES_PROCESS, str(blend), str(cycles_out)]
        for command in (monte_cmd, cycles_cmd):  # untimed: bytecode written, files in the OS's cache
            _run(command, env)
        times: dict[str, list[float]] = {"monte": [], "cycles": []}
        cpu: dict[str, list[float]] = {"monte": [], "cycles": []}
        for _ in range(repeats):
            for renderer, command in (("monte", monte_cmd), ("cycles", cycles_cmd)):
                wall, used = _run(command, env)
                times[renderer].append(wall)
                cpu[renderer].append(used)
        images = {"monte": bench_cycles._read_combined(monte_out), "cycles": bench_cycles._read_combined(cycles_out)}
    report = {"scene": name, "source": spec, "resolution": list(res), "spp": spp, "threads": threads,
              "max_bounces": max_bounces, "repeats": repeats, "renderers": {}}
    for renderer, image in images.items():
        err = corrected_rmse(metrics.rmse(image, ref.image), ref.own_mse)
        best, median = min(times[renderer]), statistics.median(times[renderer])
        report["renderers"][renderer] = {"seconds": best, "seconds_all": times[renderer], "seconds_median": median,
                                         "cpu_seconds_all": cpu[renderer],
                                         "cpu_seconds_median": statistics.median(cpu[renderer]),
                                         "rmse_corrected": err, "efficiency": efficiency(best, err * err),
                                         "efficiency_median": efficiency(median, err * err)}
    m, c = report["renderers"]["monte"], report["renderers"]["cycles"]
    report["monte_over_cycles_efficiency"] = m["efficiency"] / c["efficiency"]
    report["monte_over_cycles_efficiency_median"] = m["efficiency_median"] / c["efficiency_median"]
    log(f"  monte {m['seconds_median']:6.2f} s (median; CPU {m['cpu_seconds_median']:.2f} s) RMSE "
        f"{m['rmse_corrected']:.4f} eff {m['efficiency_median']:8.1f} | cycles {c['seconds_median']:6.2f} s (CPU "
        f"{c['cpu_seconds_median']:.2f} s) RMSE {c['rmse_corrected']:.4f} eff {c['efficiency_median']:8.1f} | "
        f"ratio {report['monte_over_cycles_efficiency_median']:.2f} (best times: "
        f"{report['monte_over_cycles_efficiency']:.2f})")
    return report


def run_whole_process(specs: Sequence[str], reference_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
                      log: Callable[[str], None] = print, **options) -> dict:
    """Every scene of specs as whole processes; writes OUTDIR/bench_whole_process.json, prints a table."""
    out = Path(out_dir).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    cache = ReferenceCache(reference_dir)
    scenes = [bench_scene_whole_process(spec, cache=cache, log=log, **options) for spec in specs]
    report = {"kind": "monte-vs-cycles-whole-process", "blender": bpy.app.version_string,
              "cpu_count": os.cpu_count(), "time": time.strftime("%Y-%m-%d %H:%M:%S"), "scenes": scenes}
    write_json(out / "bench_whole_process.json", report)
    rows = [[s["scene"], s["spp"], s["renderers"]["monte"]["seconds_median"],
             s["renderers"]["monte"]["cpu_seconds_median"], s["renderers"]["monte"]["rmse_corrected"],
             s["renderers"]["monte"]["efficiency_median"], s["renderers"]["cycles"]["seconds_median"],
             s["renderers"]["cycles"]["cpu_seconds_median"], s["renderers"]["cycles"]["rmse_corrected"],
             s["renderers"]["cycles"]["efficiency_median"], s["monte_over_cycles_efficiency_median"]]
            for s in scenes]
    log("")
    log("medians of the repeats (wall seconds, CPU seconds, efficiency with the median wall time)")
    log(format_table(["scene", "spp", "monte s", "monte CPU s", "monte RMSE", "monte eff", "cycles s", "cycles CPU s",
                      "cycles RMSE", "cycles eff", "monte/cycles"], rows))
    log(f"wrote {out / 'bench_whole_process.json'}")
    return report
