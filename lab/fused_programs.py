"""Node programs in the fused path kernel: render CPU of a program scene fused against per-bounce (needs bpy).

The scene is the `textured` bench scene (lab.bpy_scenes.textured) exported through the add-on: --stage 3
(default) as it is (the ball's Bump reads ray differentials), or with what earlier stages of the fused kernel did
not evaluate taken out of its programs: --stage 2 the ball's Bump (its instructions dropped and no normal bound;
the ball's Noise heights still run, unused; the crate keeps its Normal Map), --stage 1 also the crate's Normal
Map. Each repeat renders it once per integrator, interleaved, on one
worker thread in this warm process (one untimed render of each first loads the kernels); printed: each
render's process CPU seconds and the per-bounce / fused ratio of the medians. Prints numbers only.

    python -m monte.lab.fused_programs [--resolution 256] [--spp 64] [--repeat 3] [--stage 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np


def stage1_textured(resolution: int, stage: int = 1):
    """The exported `textured` scene without its normal-setting nodes (stage 1), without its Bump (stage 2) or
    whole (stage 3; see the module docstring)."""
    import bpy

    from ..addon.export import export_scene
    from ..core.shading import registry as R
    from . import bpy_scenes

    scene = bpy_scenes.build("textured", (resolution, resolution))
    scene.render.engine = "MONTE"
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    dropped = (R.OP_BUMP, R.OP_NORMAL_MAP, R.OP_TANGENT) if stage == 1 else (R.OP_BUMP,)
    for m in core_scene.materials if stage < 3 else ():
        p = getattr(m, "program", None)
        if p is None:
            continue
        drop = np.isin(p.code[:, 0], dropped)
        if drop.any():
            p.code = np.ascontiguousarray(p.code[~drop])
            p.normal = -1
    return core_scene


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--stage", type=int, choices=(1, 2, 3), default=3)
    args = ap.parse_args(argv)
    from ..core.fused_tracer import FUSED_ENV
    from ..core.render import render
    from ..core.settings import RenderSettings

    scene = stage1_textured(args.resolution, args.stage)
    settings = RenderSettings(spp=args.spp, threads=1, seed=1, aovs=False).validate()
    cpu: dict[str, list[float]] = {"per-bounce": [], "fused": []}
    images = {}
    for name in cpu:  # loads (or compiles) the kernels
        os.environ[FUSED_ENV] = "0" if name == "per-bounce" else "1"
        images[name] = render(scene, settings.replace(spp=1))
        print(f"{name}: fused kernel {images[name].stats['fused_kernel']}", flush=True)
    for _ in range(args.repeat):
        for name in cpu:
            os.environ[FUSED_ENV] = "0" if name == "per-bounce" else "1"
            t0 = time.process_time()
            images[name] = render(scene, settings)
            cpu[name].append(time.process_time() - t0)
            print(f"  {name}: {cpu[name][-1]:.2f} CPU s", flush=True)
    os.environ.pop(FUSED_ENV, None)
    med = {k: statistics.median(v) for k, v in cpu.items()}
    same = np.array_equal(images["fused"].color, images["per-bounce"].color)
    print(f"{args.resolution}x{args.resolution} {args.spp} spp, 1 thread: per-bounce {med['per-bounce']:.2f} CPU s, "
          f"fused {med['fused']:.2f} CPU s (medians of {args.repeat}), ratio {med['per-bounce'] / med['fused']:.2f}x;"
          f" images bit-identical: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
