"""Where the floor's variance per sample on `textured` differs from Cycles': by bounce limit, Russian roulette and
what a floor pixel sees.

`python -m monte.lab.floor_variance --spp 64,256 --seeds 6 --configs b0,b1,b2,full,norr` renders the `textured`
bench scene (lab.bpy_scenes) with Monte and with Cycles, seeds 1..K each (`--first-seed`), at each sample count,
for each variant:

- `bN`: every bounce limit N (Cycles' counting, as Monte's: b0 is direct light only, b1 adds one indirect bounce);
- `full`: the bench's limit (16);
- `norr`: the bench's limit with Russian roulette off in both renderers (Monte `rr_depth` 1000, Cycles
  `min_light_bounces` 1000).

Per variant, sample count and region it prints the per-pixel variance of one render across the seeds (mean over
the region's pixels and the three channels), Monte's, Cycles' and their ratio, and that variance x spp (flat
while a renderer's error falls as 1/N). Regions: the floor, split by what it sees: `lit` (direct light above half
the floor's 95th percentile, from a direct-only Monte render), `shadow` (under 5 % of it), `penumbra` (between),
`near` (within `--near` m of the crate's or the ball's footprint on the floor); and the crate, the ball, the whole
image. No reference needed: variance only. `--objects flat` unlinks the crate's and the ball's Normal Map / Bump,
`--objects matte` gives them a Diffuse BSDF instead of their Principled BSDF (the same colour and normal inputs),
`--objects metal` Metallic 1 (one specular lobe); `--glossy-select F` scales Monte's lobe-choice estimate of every
glossy lobe by F (a diagnostic);
`--save DIR` writes the per-pixel variance maps and the region masks (npz). Numbers only. The findings:
docs/performance.md, "The floor's excess at 256 spp: the objects' glossy reflections".
"""

from __future__ import annotations

import argparse
import time
from typing import Sequence

import numpy as np

VARIANTS = {"full": (16, False), "norr": (16, True)}


def variant(name: str) -> tuple[int, bool]:
    """(max_bounces, Russian roulette off) of a variant name: full, norr or bN."""
    if name in VARIANTS:
        return VARIANTS[name]
    if name.startswith("b") and name[1:].isdigit():
        return int(name[1:]), False
    raise ValueError(f"unknown variant {name!r}: full, norr or bN (every bounce limit N)")


def floor_regions(position: np.ndarray, direct: np.ndarray, floor: np.ndarray,
                  footprints: Sequence[tuple[np.ndarray, np.ndarray]], near: float) -> dict[str, np.ndarray]:
    """Split the floor mask (H, W) by its direct light (H, W, 3: lit / penumbra / shadow, against the floor's 95th
    percentile of luminance) and by the distance in x, y of its position (H, W, 3) to any (lo, hi) footprint."""
    lum = np.asarray(direct, np.float64)[..., :3].mean(axis=-1)
    top = float(np.percentile(lum[floor], 95))
    lit, shadow = floor & (lum > 0.5 * top), floor & (lum < 0.05 * top)
    pos = np.asarray(position, np.float64)[..., :2]
    dist = np.full(floor.shape, np.inf)
    for lo, hi in footprints:
        d = np.maximum(np.maximum(lo[:2] - pos, pos - hi[:2]), 0.0)
        dist = np.minimum(dist, np.hypot(d[..., 0], d[..., 1]))
    return {"floor": floor, "lit": lit, "penumbra": floor & ~lit & ~shadow, "shadow": shadow,
            "near": floor & (dist < near), "far": floor & (dist >= near)}


def scale_glossy_selection(factor: float) -> None:
    """Make Monte's lobe choice (for the rest of this process) pick glossy lobes as if their albedo estimate were
    `factor` x what core.bsdf estimates: a diagnostic of the choice probabilities, unbiased by construction."""
    from ..core import bsdf

    original = bsdf._lobe_select_scale

    def scaled(kind, fresnel, ior, f0, layer, tint=None):
        s = original(kind, fresnel, ior, f0, layer, tint)
        return s * factor if kind == bsdf.GLOSSY else s

    bsdf._lobe_select_scale = scaled


def edit_material(material, how: str) -> None:
    """The `--objects` variants on a bench material whose output is a Principled BSDF: "as-is" leaves it, "flat"
    unlinks its Normal input, "metal" sets its Metallic to 1, "matte" puts a Diffuse BSDF with the same Color (Base
    Color) and Normal inputs in its place (one diffuse lobe: no lobe choice)."""
    if how == "as-is":
        return
    tree = material.node_tree
    principled = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    if how == "metal":
        principled.inputs["Metallic"].default_value = 1.0
        return
    if how == "flat":
        for link in list(principled.inputs["Normal"].links):
            tree.links.remove(link)
        return
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    for src, dst in (("Base Color", "Color"), ("Normal", "Normal")):
        socket = principled.inputs[src]
        if socket.links:
            tree.links.new(socket.links[0].from_socket, diffuse.inputs[dst])
        elif src == "Base Color":
            diffuse.inputs[dst].default_value = socket.default_value
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    tree.links.new(diffuse.outputs["BSDF"], output.inputs["Surface"])


def main(argv: Sequence[str] | None = None) -> int:
    import bpy

    from ..addon.export import export_scene
    from ..core.render import render
    from . import bpy_scenes
    from .bench_cycles import monte_settings, render_cycles
    from .error_split import pixel_variance, regions_by_box

    p = argparse.ArgumentParser(prog="python -m monte.lab.floor_variance", description=__doc__.split("\n\n")[0])
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--spp", default="64,256", help="comma-separated sample counts")
    p.add_argument("--seeds", type=int, default=6)
    p.add_argument("--first-seed", type=int, default=1, help="seeds first-seed .. first-seed + seeds - 1")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--configs", default="b0,b1,full,norr", help="comma-separated variants: full, norr, bN")
    p.add_argument("--near", type=float, default=0.5, help="metres from an object's footprint that count as near")
    p.add_argument("--objects", default="as-is", choices=("as-is", "flat", "matte", "metal"),
                   help="the crate's and the ball's materials: as built; flat: their Normal Map / Bump unlinked; "
                        "matte: a Diffuse BSDF (same colour and normal inputs) instead of the Principled BSDF; "
                        "metal: the Principled BSDF with Metallic 1 (one specular lobe, no lobe choice)")
    p.add_argument("--glossy-select", type=float, default=1.0,
                   help="Monte only, a diagnostic: scale every glossy lobe's lobe-choice estimate by this factor "
                        "(core.bsdf._lobe_select_scale; unbiased: the choice shapes the variance, not the mean)")
    p.add_argument("--save", default="", help="folder for the per-pixel variance maps (npz)")
    args = p.parse_args(argv)
    counts = [int(x) for x in args.spp.split(",")]
    configs = [(c, *variant(c)) for c in args.configs.split(",")]

    if args.glossy_select != 1.0:
        scale_glossy_selection(args.glossy_select)
    scene = bpy_scenes.build("textured", (args.resolution, args.resolution))
    for name in ("crate", "ball"):
        edit_material(bpy.data.materials[name], args.objects)
    scene.render.engine = "MONTE"
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    first = render(core_scene, monte_settings(4, 1, args.threads, 16, data_passes=("position",)))
    position = next(v for k, v in first.data_passes.items() if k.lower() == "position")
    boxes = {}
    for mesh in core_scene.meshes:
        v = np.asarray(mesh.vertices, np.float64)
        boxes[mesh.name] = (v.min(axis=0), v.max(axis=0))
    objects = regions_by_box(position, boxes)
    direct = render(core_scene, monte_settings(64, 1, args.threads, 0)).color
    footprints = [boxes[n] for n in boxes if n != "floor"]
    regions = {**floor_regions(position, direct, objects["floor"], footprints, args.near),
               **{n: objects[n] for n in ("crate", "ball") if n in objects},
               "all": np.ones(position.shape[:2], bool)}
    cyc = scene.cycles
    min_light = cyc.min_light_bounces
    print(f"textured ({args.objects} objects) {args.resolution}x{args.resolution}, seeds {args.first_seed}.."
          f"{args.first_seed + args.seeds - 1} per renderer; pixels: "
          + ", ".join(f"{n} {int(m.sum())}" for n, m in regions.items()), flush=True)
    print(f"{'variant':8s} {'spp':>5s} {'region':9s} {'var Monte':>10s} {'var Cycles':>10s} {'ratio':>6s} "
          f"{'Monte x spp':>11s} {'Cycles x spp':>12s}", flush=True)
    maps = {}
    for name, bounces, rr_off in configs:
        for spp in counts:
            t0 = time.perf_counter()
            seeds = range(args.first_seed, args.first_seed + args.seeds)
            extra = {"rr_depth": 1000} if rr_off else {}
            monte = [render(core_scene, monte_settings(spp, s, args.threads, bounces, **extra)).color for s in seeds]
            cyc.min_light_bounces = 1000 if rr_off else min_light
            cycles = [render_cycles(scene, spp, s, args.threads, bounces)[0] for s in seeds]
            cyc.min_light_bounces = min_light
            vm, vc = pixel_variance(monte), pixel_variance(cycles)
            maps[f"{name}_{spp}_monte"], maps[f"{name}_{spp}_cycles"] = vm.astype(np.float32), vc.astype(np.float32)
            for region, mask in regions.items():
                if not mask.any():
                    continue
                a, b = float(vm[mask].mean()), float(vc[mask].mean())
                print(f"{name:8s} {spp:5d} {region:9s} {a:10.3e} {b:10.3e} {a / b:6.3f} {a * spp:11.3e} "
                      f"{b * spp:12.3e}", flush=True)
            print(f"# {name} {spp} spp: {time.perf_counter() - t0:.0f} s", flush=True)
    if args.save:
        import os
        os.makedirs(args.save, exist_ok=True)
        np.savez_compressed(os.path.join(args.save, "floor_variance.npz"),
                            **maps, **{f"mask_{n}": m for n, m in regions.items()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
