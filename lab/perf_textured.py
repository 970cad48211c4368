"""`monte perf --sections textured`: where a render of the `textured` bench scene spends its time (needs bpy).

The scene (lab.bpy_scenes.textured: an image-textured, normal-mapped crate, a Noise-bumped sphere, a Noise ->
Color Ramp floor) is exported through the add-on once, rendered once untimed (kernels load), then rendered on
one worker thread under cProfile. Printed: the render's process CPU seconds without the profiler (best of
`repeat`), the stage thread-seconds, and the functions with the most own time under the profiler (a numba
kernel's time counts as its Python caller's: `evaluate` is the node-program interpreter, `sample` of lights.py
the light-sampling kernel, and so on). The profiler roughly doubles the per-call Python overhead, so read its
column as shares. Prints numbers only: no timing is asserted.

It profiles the per-bounce integrator (MONTE_FUSED=0 while it renders), whose stages and kernels the profile can
tell apart: the scene's default renderer, the fused path kernel (core.fused_path), is one compiled call per
batch (`python -m monte.lab.fused_programs` times the two against each other).
"""

from __future__ import annotations

import cProfile
import os
import pstats
import time

TOP = 20  # functions listed


def _scene(resolution: int):
    import bpy

    from ..addon.export import export_scene
    from . import bpy_scenes

    scene = bpy_scenes.build("textured", (resolution, resolution))
    scene.render.engine = "MONTE"
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    return core_scene


def textured_profile(resolution: int, spp: int, repeat: int, top: int = TOP) -> dict:
    """CPU seconds, stage seconds and the top functions by own time of a 1-thread per-bounce render of
    `textured`."""
    from ..core.fused_tracer import FUSED_ENV
    from ..core.render import render
    from ..core.settings import RenderSettings

    before = os.environ.get(FUSED_ENV)
    os.environ[FUSED_ENV] = "0"
    try:
        return _profile(render, RenderSettings, resolution, spp, repeat, top)
    finally:
        if before is None:
            os.environ.pop(FUSED_ENV, None)
        else:
            os.environ[FUSED_ENV] = before


def _profile(render, RenderSettings, resolution: int, spp: int, repeat: int, top: int) -> dict:

    scene = _scene(resolution)
    settings = RenderSettings(spp=spp, threads=1, seed=1, aovs=False).validate()
    render(scene, settings.replace(spp=1))  # loads the kernels
    cpu = []
    for _ in range(max(repeat, 1)):
        t0 = time.process_time()
        result = render(scene, settings)
        cpu.append(time.process_time() - t0)
    profiler = cProfile.Profile()
    profiler.enable()
    render(scene, settings)
    profiler.disable()
    stats = pstats.Stats(profiler)
    total = stats.total_tt
    rows = sorted(((tt, cc, func) for func, (cc, _nc, tt, _ct, _callers) in stats.stats.items()), reverse=True)
    functions = [{"function": f"{func[0].rsplit('/', 2)[-2]}/{func[0].rsplit('/', 1)[-1]}:{func[2]}"
                  if "/" in func[0] else func[2], "seconds": tt, "calls": cc, "share": tt / total}
                 for tt, cc, func in rows[:top]]
    return {"resolution": resolution, "spp": spp, "cpu_seconds_best": min(cpu), "cpu_seconds": cpu,
            "stage_seconds": result.stats["stage_seconds"], "profiled_seconds": total, "functions": functions}


def print_textured_profile(r: dict) -> None:
    print(f"Textured scene {r['resolution']}x{r['resolution']}, {r['spp']} spp, 1 thread: "
          f"{r['cpu_seconds_best']:.2f} CPU s (best of {len(r['cpu_seconds'])}); under cProfile "
          f"{r['profiled_seconds']:.2f} s")
    print("  stages: " + ", ".join(f"{k} {v:.2f}" for k, v in r["stage_seconds"].items()))
    for f in r["functions"]:
        print(f"  {f['seconds']:7.3f} s {100 * f['share']:5.1f}%  {f['calls']:6d} calls  {f['function']}")
