"""The first render call of a process against its later ones (issue 20: "the first render call within 0.05 s of
later ones"), timed as in Blender: one bpy process registers the add-on (which starts the background kernel
loader), opens a .blend set to render with Monte and presses F12 several times.

    python -m monte.lab.first_call /tmp/cornell64.blend [more.blend ...] [--processes 3] [--calls 4]

Each .blend is rendered by --processes fresh processes in each of two modes, alternating: `now` presses F12 right
after the file opened (the loader still at work), `after` waits for the loader to finish first. Prints, per
process, each call's wall and CPU seconds (the process's CPU, all threads), the loader's state when the first
call began (alive, signatures loaded) and the first call's excess over the median of the later ones; `uptime`'s
load before each .blend. Nothing is asserted (a benchmark, not a test). The .blend must render with Monte (the
bench files: `monte bench --whole-process` saves them).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import textwrap
from pathlib import Path

_CHILD = textwrap.dedent("""
    import json, sys, time
    blend, mode, calls, spp = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    import bpy
    import monte
    from monte.core import precompile
    monte.register()
    from monte.addon import engine
    renders, real_render = [], engine.MonteRenderEngine._render

    def counted(self, depsgraph):
        real_render(self, depsgraph)
        renders.append(1)

    engine.MonteRenderEngine._render = counted
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False)
    scene = bpy.context.scene
    scene.render.engine = "MONTE"  # the bench files are saved for either renderer
    if spp:
        scene.monte.samples = spp
    if mode == "after":
        loader = precompile._loader
        if loader is not None:
            loader.join()

    def loaded():
        return sum(len(d.overloads) for d in precompile._dispatchers())

    out = {"calls": []}
    for i in range(calls):
        alive = precompile._loader is not None and precompile._loader.is_alive()
        n = loaded()
        t, c = time.perf_counter(), time.process_time()
        bpy.ops.render.render(write_still=False)
        assert renders == [1] * (i + 1), "Monte did not render"
        out["calls"].append({"wall": time.perf_counter() - t, "cpu": time.process_time() - c,
                             "loader_alive": alive, "loaded_before": n})
    monte.unregister()
    print("RESULT " + json.dumps(out), flush=True)
""")


def _run(blend: str, mode: str, calls: int, spp: int) -> dict:
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as a user's Blender: bytecode cached
    proc = subprocess.run([sys.executable, "-c", _CHILD, blend, mode, str(calls), str(spp)], env=env,
                          capture_output=True, text=True, timeout=600)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise RuntimeError(f"no result (rc {proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("blends", nargs="+")
    parser.add_argument("--processes", type=int, default=3)
    parser.add_argument("--calls", type=int, default=4)
    parser.add_argument("--modes", default="now,after")
    parser.add_argument("--spp", type=int, default=1, help="Monte's samples (0: the file's)")
    args = parser.parse_args(argv)
    for blend in args.blends:
        blend = str(Path(blend).resolve())
        print(f"{Path(blend).name}: uptime {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
        for p in range(args.processes):
            for mode in args.modes.split(","):
                calls = _run(blend, mode, args.calls, args.spp)["calls"]
                later = statistics.median(c["wall"] for c in calls[1:]) if len(calls) > 1 else 0.0
                first = calls[0]
                print(f"  {mode:5s} #{p}: " + " ".join(f"{c['wall']:.3f}/{c['cpu']:.3f}" for c in calls)
                      + f"  first-later {first['wall'] - later:+.3f} s  loader "
                      + f"{'alive' if first['loader_alive'] else 'done'} ({first['loaded_before']} loaded)",
                      flush=True)


if __name__ == "__main__":
    main()
