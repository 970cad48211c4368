"""Where the shipped fused path kernel's CPU goes, sampled by Linux `perf` (no instrumented copy, no compile).

    python -m monte.lab.fused_sampling [--resolution 256] [--spp 16] [--threads 1] [--frequency 2000]

lab/fused_timing.py (`monte perf --sections fused`) splits the kernel's time with a measurement copy that reads
the cycle counter ~15 times per vertex; those reads, and the code LLVM can no longer move across them, land
mostly in its "rest" and inflate every part that is not Embree. This tool measures the kernel as it ships: it
runs a child process under `perf record -e cpu-clock` (a software clock: no hardware counters needed, so it works
in containers that refuse them), the child logs, per worker thread, when each call of the fused kernel
(core.fused_tracer's `trace_paths`) began and ended (CLOCK_MONOTONIC, the clock perf is told to stamp samples
with), and the samples that fall inside a call of their own thread are the kernel's. Each is charged by the
shared object its instruction pointer lies in: Embree's library; the compiled kernels (numba's JIT code lies in
anonymous memory, which perf names `[anon...]`/`perf-PID.map`/`[unknown]`: with the render's own kernels inlined
into `trace_paths`, that is the kernel's own code); libm (sin/cos/atan2 calls of the light and BSDF samples);
anything else. The whole render window's samples (all threads of the child) are split the same way.

Needs the `perf` tool and perf_event_paranoid <= 2 for one's own processes. Prints numbers only; the sampling is
statistical (at 2000 Hz one second of CPU is ~2000 samples: shares good to ~1-2 %).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

CATEGORIES = ("Embree", "compiled kernels (JIT)", "libm", "other")


def classify(dso: str) -> str:
    """The category of a sample whose instruction pointer lies in shared object `dso` (perf script's dso field,
    with or without its parentheses)."""
    d = dso.strip().strip("()")
    base = os.path.basename(d)
    if "embree" in base:
        return "Embree"
    if base.startswith("libm.") or base.startswith("libm-") or base == "libm.so":
        return "libm"
    if d in ("", "[unknown]") or d.startswith("[anon") or d.startswith("//anon") or base.startswith("perf-") \
            or d.startswith("/memfd:"):
        return "compiled kernels (JIT)"
    return "other"


def parse_samples(lines):
    """(tid, seconds, dso) per sample of `perf script -F tid,time,ip,dso` lines ("  123  4567.890123:  7f..
    (/path/lib.so)"); lines that are not samples are skipped."""
    out = []
    for line in lines:
        parts = line.split()
        if len(parts) < 3 or not parts[1].endswith(":"):
            continue
        try:
            tid = int(parts[0])
            t = float(parts[1][:-1])
        except ValueError:
            continue
        dso = parts[3] if len(parts) > 3 else "[unknown]"
        out.append((tid, t, dso))
    return out


def split(samples, windows, render_window):
    """Counts per category of the samples inside a kernel call of their own thread (windows: {tid: [(t0, t1)]},
    seconds) and of all samples in render_window (t0, t1)."""
    kernel = dict.fromkeys(CATEGORIES, 0)
    render = dict.fromkeys(CATEGORIES, 0)
    r0, r1 = render_window
    for tid, t, dso in samples:
        if not r0 <= t <= r1:
            continue
        cat = classify(dso)
        render[cat] += 1
        if any(a <= t <= b for a, b in windows.get(tid, ())):
            kernel[cat] += 1
    return kernel, render


def _now() -> float:
    return time.clock_gettime(time.CLOCK_MONOTONIC)


def child(resolution: int, spp: int, threads: int, out_path: str) -> None:
    """Render the Cornell box with the shipped kernel, logging each kernel call's thread and time window."""
    from ..core import fused_tracer
    from ..core.builtin_scenes import cornell_box
    from ..core.render import render
    from ..core.settings import RenderSettings

    scene = cornell_box((resolution, resolution))
    render(scene, RenderSettings(spp=1, threads=threads, aovs=False).validate())  # loads the kernels, warms up
    shipped = fused_tracer.trace_paths
    windows: dict[int, list] = {}
    lock = threading.Lock()

    def logged(*args):
        t0 = _now()
        shipped(*args)
        t1 = _now()
        with lock:
            windows.setdefault(threading.get_native_id(), []).append((t0, t1))

    fused_tracer.trace_paths = logged
    try:
        r0, c0 = _now(), time.process_time()
        result = render(scene, RenderSettings(spp=spp, threads=threads, aovs=False).validate())
        r1, c1 = _now(), time.process_time()
    finally:
        fused_tracer.trace_paths = shipped
    assert result.stats.get("fused_kernel"), "the fused kernel did not render the Cornell box"
    with open(out_path, "w") as f:
        json.dump({"windows": {str(k): v for k, v in windows.items()}, "render_window": [r0, r1],
                   "render_cpu": c1 - c0, "seconds": r1 - r0}, f)


def measure(resolution: int = 256, spp: int = 16, threads: int = 1, frequency: int = 2000) -> dict:
    perf = shutil.which("perf")
    if perf is None:
        raise RuntimeError("needs the Linux perf tool, which is not on PATH")
    with tempfile.TemporaryDirectory() as tmp:
        data, log = os.path.join(tmp, "perf.data"), os.path.join(tmp, "windows.json")
        cmd = [perf, "record", "-q", "-e", "cpu-clock", "-F", str(frequency), "-k", "CLOCK_MONOTONIC", "-o", data,
               "--", sys.executable, "-m", __spec__.name if __spec__ else "monte.lab.fused_sampling", "--child", log,
               "--resolution", str(resolution), "--spp", str(spp), "--threads", str(threads)]
        if subprocess.run(cmd).returncode != 0:
            raise RuntimeError("perf record (or the render under it) failed")
        run = subprocess.run([perf, "script", "-i", data, "-F", "tid,time,ip,dso"], capture_output=True, text=True)
        if run.returncode != 0:
            raise RuntimeError(f"perf script failed: {run.stderr.strip()[:200]}")
        script = run.stdout.splitlines()
        with open(log) as f:
            w = json.load(f)
    windows = {int(k): [tuple(x) for x in v] for k, v in w["windows"].items()}
    kernel, render = split(parse_samples(script), windows, tuple(w["render_window"]))
    return {"resolution": resolution, "spp": spp, "threads": threads, "frequency": frequency,
            "render_cpu": w["render_cpu"], "seconds": w["seconds"], "kernel": kernel, "render": render,
            "kernel_calls": sum(len(v) for v in windows.values())}


def report(m: dict) -> None:
    print(f"Cornell box {m['resolution']}x{m['resolution']}, {m['spp']} spp, {m['threads']} thread(s): render "
          f"{m['seconds']:.2f} s, {m['render_cpu']:.2f} CPU s; cpu-clock samples at {m['frequency']} Hz")
    for label, counts in (("inside the fused kernel's calls", m["kernel"]), ("the whole render", m["render"])):
        total = sum(counts.values())
        print(f"  {label}: {total} samples ({total / m['frequency']:.2f} CPU s)")
        for cat in CATEGORIES:
            n = counts[cat]
            print(f"    {cat:26s} {n:7d}  {100 * n / max(total, 1):5.1f} %")
    k = m["kernel"]
    print(f"  Embree's share of the fused kernel's CPU: {100 * k['Embree'] / max(sum(k.values()), 1):.1f} %")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--frequency", type=int, default=2000)
    ap.add_argument("--json", action="store_true", help="print the measurement as JSON too")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        child(a.resolution, a.spp, a.threads, a.child)
        return 0
    m = measure(a.resolution, a.spp, a.threads, a.frequency)
    report(m)
    if a.json:
        print(json.dumps(m))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
