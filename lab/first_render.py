"""The first render after installing the extension zip, timed as a user meets it (issue 20's first target).

    python -m monte.lab.first_render dist/monte-<version>-linux_x64.zip [--resolution 256x256] [--spp 64]

Saves the Cornell bench scene (lab/bpy_scenes.py) as a .blend set to render with Monte, installs the zip into an
empty Blender user folder (Blender's extension machinery, as tests/test_addon_install.py does; the preferences
saved, as Blender saves them on quit), then runs fresh processes that each start the bpy module, read the saved
preferences (which enables the installed extension: Blender does so as it starts, the bpy module when asked), open
the .blend and press F12 twice (render with write_still): the first is the *cold* process (the first ever after installing: Python's bytecode for the
extension is written then), the next ones *warm*. `--kernel-cpu generic` plays a CPU without AVX2 (the kernel
level such a CPU loads or compiles). Prints, per process, the seconds from the process's start to
the end of its first render, and each of its two render calls; nothing is asserted (a benchmark, not a test).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

_SAVE = textwrap.dedent("""
    import sys
    import bpy
    import monte
    from monte.lab import bpy_scenes
    blend, out, w, h, spp, threads = sys.argv[1], sys.argv[2], *map(int, sys.argv[3:7])
    monte.register()
    scene = bpy_scenes.build("cornell", (w, h))
    scene.render.engine = "MONTE"
    scene.monte.samples, scene.monte.threads = spp, threads
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5.0+
        settings.media_type = "IMAGE"
    settings.file_format, settings.color_depth = "OPEN_EXR", "32"
    scene.render.use_file_extension = False
    scene.render.filepath = out
    bpy.ops.wm.save_as_mainfile(filepath=blend, copy=True, compress=False)
    monte.unregister()
""")

_INSTALL = textwrap.dedent("""
    import sys
    import bpy  # BLENDER_USER_RESOURCES (an empty folder) is set in the environment
    bpy.ops.wm.read_factory_settings(use_empty=True)
    res = bpy.ops.extensions.package_install_files(repo="user_default", filepath=sys.argv[1], enable_on_install=True)
    assert res == {"FINISHED"}, res
    bpy.ops.wm.save_userpref()
""")

# A user's F12, twice: the process's first render call and its second.
_RENDER = textwrap.dedent("""
    import json, sys, time
    t_start = float(sys.argv[2])
    import bpy
    # What Blender does as it starts: read the saved preferences and enable their add-ons (the bpy module does not
    # on its import)
    bpy.ops.wm.read_userpref()
    t_bpy = time.time()
    assert "bl_ext.user_default.monte" in sys.modules, "the installed extension was not enabled at start-up"
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False)
    t_open = time.time()
    calls = []
    for _ in range(2):
        t0 = time.time()
        assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
        calls.append(time.time() - t0)
    precompile = sys.modules["bl_ext.user_default.monte.core.precompile"]
    print("RESULT " + json.dumps({"bpy_import": t_bpy - t_start, "open": t_open - t_bpy, "calls": calls,
                                  "first_render_done": t_open + calls[0] - t_start,
                                  "kernels": precompile.kernel_cache_counts()}))
""")


def _child(code: str, *args: str, env: dict) -> dict | None:
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    return json.loads(lines[-1][len("RESULT "):]) if lines else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("zip", help="the extension zip (tools/build_extension.py)")
    parser.add_argument("--resolution", default="256x256", help="WxH (default the bench scene's 256x256)")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--processes", type=int, default=3, help="render processes after installing (default 3)")
    parser.add_argument("--kernel-cpu", choices=("auto", "generic", "x86-64-v3"), default="auto",
                        help="MONTE_KERNEL_CPU of the processes after installing: generic plays a CPU without "
                             "AVX2 (default auto: this machine's level)")
    args = parser.parse_args(argv)
    w, h = (int(v) for v in args.resolution.lower().split("x"))
    with tempfile.TemporaryDirectory(prefix="monte-first-render-") as tmp:
        tmp_dir = Path(tmp)
        user = tmp_dir / "user"
        user.mkdir()
        blend = tmp_dir / "cornell.blend"
        base = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONDONTWRITEBYTECODE")
                and not k.startswith("NUMBA_") and k != "MONTE_KERNEL_CPU"}
        _child(_SAVE, str(blend), str(tmp_dir / "out.exr"), str(w), str(h), str(args.spp), str(args.threads),
               env=dict(base, PYTHONDONTWRITEBYTECODE="1", **({"PYTHONPATH": os.environ["PYTHONPATH"]}
                                                           if "PYTHONPATH" in os.environ else {})))
        env = dict(base, BLENDER_USER_RESOURCES=str(user), MONTE_KERNEL_CPU=args.kernel_cpu)  # (writes bytecode)
        t0 = time.perf_counter()
        _child(_INSTALL, str(Path(args.zip).resolve()), env=env)
        print(f"install (unzip, wheels, enable, save preferences): {time.perf_counter() - t0:.2f} s")
        for i in range(args.processes):
            r = _child(_RENDER, str(blend), repr(time.time()), env=env)
            kind = "cold (first process after install)" if i == 0 else "warm"
            print(f"process {i + 1} {kind}: first render done {r['first_render_done']:.2f} s after the process "
                  f"started (bpy + extension {r['bpy_import']:.2f} s, open {r['open']:.2f} s); F12 #1 "
                  f"{r['calls'][0]:.2f} s, F12 #2 {r['calls'][1]:.2f} s; kernels {r['kernels']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
