"""Where the fused path kernel's time goes: Embree's closest hits and shadow rays against the rest of a path.

    python -m monte.lab.fused_timing [--resolution 256] [--spp 16] [--threads 1] [--scene cornell|textured]

Compiles a measurement copy of core.fused_path.trace_paths with the module's TIMED flag on (not cached; about
as long as the shipped kernel's compile, minutes), which reads the CPU's cycle counter around each part of a
path and sums the cycles per part in its counters array (core.fused_path.TIMING_PARTS), renders the Cornell box
(--scene textured: the node-program bench scene lab.bpy_scenes.textured, which needs bpy; its programs are the
"node program" part) with it (the image is the shipped kernel's: the flag adds reads of the counter and nothing else), and prints each
part's share of the kernel's path loop, its nanoseconds per call where it has a call count, and the rest. The
cycles become seconds by the counter's rate measured against time.perf_counter. The shipped kernel, compiled
with the flag off, has none of this code.

The counter reads cost some tens of cycles each and LLVM may move cheap arithmetic across them: the split is
good to a few percent of the loop, not to the cycle. The counter counts wall cycles: on a loaded machine a
descheduled thread charges the part it was in, so read the shares (preemption falls on each part in proportion
to its time), not the seconds.
The reads are not free either: on the Cornell box they roughly double the time of the parts that are not Embree
(docs/performance.md, "The path loop's glue, round one"); lab/fused_sampling.py samples the shipped kernel with
Linux perf instead, without a copy.
"""

from __future__ import annotations

import argparse
import inspect
import threading
import time

import numba
import numpy as np

from ..core import fused_path  # first: core.jit_cache picks the CPU numba compiles for before any kernel here


def _timed_kernel():
    """A non-cached copy of trace_paths; it reads TIMED as a global when it compiles (its first call)."""
    return numba.njit(nogil=True, error_model="numpy", boundscheck=False, _nrt=False)(fused_path.trace_paths.py_func)


@numba.njit(nogil=True)
def _spin(n):
    acc = 0.0
    for i in range(n):
        acc += np.sqrt(np.float64(i))
    return acc


def cycles_per_second() -> float:
    """The cycle counter's rate, against time.perf_counter over ~0.3 s."""
    _cycles = fused_path._cycles

    @numba.njit
    def read():
        return _cycles()

    read()
    _spin(10)
    c0, t0 = read(), time.perf_counter()
    _spin(60_000_000)
    c1, t1 = read(), time.perf_counter()
    return (c1 - c0) / (t1 - t0)


def measure(resolution: int, spp: int, threads: int, compile_only: bool = False, scene_name: str = "cornell") -> dict:
    """Render the Cornell box (or, scene_name "textured", the node-program bench scene lab.bpy_scenes.textured,
    which needs bpy) with the timed kernel; the cycles per part, summed over all worker threads."""
    from ..core import fused_tracer
    from ..core.builtin_scenes import cornell_box
    from ..core.render import render
    from ..core.settings import RenderSettings

    t0 = time.perf_counter()
    kernel = _timed_kernel()
    position = list(inspect.signature(fused_path.trace_paths.py_func).parameters).index("counters")
    totals = np.zeros(fused_path.COUNTERS, np.int64)
    lock = threading.Lock()

    def traced(*args):
        kernel(*args)
        with lock:
            totals[:] += args[position]

    if scene_name == "textured":
        from .fused_programs import stage1_textured

        scene = stage1_textured(resolution, 3)
    else:
        scene = cornell_box((resolution, resolution))
    shipped = fused_tracer.trace_paths
    fused_tracer.trace_paths = traced
    try:
        fused_path.TIMED = True
        try:
            render(scene, RenderSettings(spp=1, threads=1, aovs=False).validate())  # compiles the timed copy
        finally:
            fused_path.TIMED = False
        compile_seconds = time.perf_counter() - t0
        if compile_only:
            return {"compile_seconds": compile_seconds}
        totals[:] = 0
        t1 = time.process_time()
        result = render(scene, RenderSettings(spp=spp, threads=threads, aovs=False).validate())
        render_cpu = time.process_time() - t1
    finally:
        fused_tracer.trace_paths = shipped
    assert result.stats.get("fused_kernel"), f"the fused kernel did not render {scene_name}"
    rate = cycles_per_second()
    first = fused_path.TIMING_FIRST
    parts = {name: totals[first + i] / rate for i, name in enumerate(fused_path.TIMING_PARTS)}
    loop = parts.pop("whole path loop")
    calls = {"closest hit (Embree)": int(totals[2]), "shadow ray (Embree)": int(totals[3])}
    return {"scene": scene_name, "render_cpu": render_cpu, "resolution": resolution, "spp": spp, "threads": threads,
            "seconds": result.stats["seconds"],
            "cycles_per_second": rate, "loop_seconds": loop, "parts_seconds": parts,
            "rest_seconds": loop - sum(parts.values()), "calls": calls, "compile_seconds": compile_seconds}


def report(m: dict) -> None:
    loop = m["loop_seconds"]
    print(f"{m['scene']} {m['resolution']}x{m['resolution']}, {m['spp']} spp, {m['threads']} thread(s): render "
          f"{m['seconds']:.2f} s ({m['render_cpu']:.2f} CPU s), path loop {loop:.2f} thread-s "
          f"(counter {m['cycles_per_second'] / 1e9:.2f} GHz)")
    rows = list(m["parts_seconds"].items()) + [("rest (branching, MIS, film sums, ray set-up)", m["rest_seconds"])]
    for name, sec in rows:
        n = m["calls"].get(name)
        per = f"  {1e9 * sec / n:6.0f} ns/ray (wall)" if n else ""
        print(f"  {name:46s} {sec:7.2f} s  {100 * sec / loop:5.1f} %{per}")
    embree = m["parts_seconds"]["closest hit (Embree)"] + m["parts_seconds"]["shadow ray (Embree)"]
    print(f"  Embree's share of the path loop: {100 * embree / loop:.1f} %")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--scene", choices=("cornell", "textured"), default="cornell")
    a = ap.parse_args(argv)
    report(measure(a.resolution, a.spp, a.threads, scene_name=a.scene))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
