"""Where one renderer's error against a converged reference comes from: per object, noise or bias.

`python -m monte.lab.error_split --scene textured --spp 16 --seeds 8` renders a bench scene (lab.bpy_scenes)
with Monte and with Cycles at the same sample count, seeds 1..K each, and splits each renderer's mean squared
error against the bench's cached Cycles reference (`--reference-dir`, as `monte bench --vs cycles`) per region:
the pixels whose first hit lies in each mesh's bounding box (smallest box first; "background" where the
camera ray hit nothing), from Monte's Position pass. Per region and renderer it prints the variance of one
render (across the seeds) and the squared bias of the mean (the mean image's squared error minus its own
variance / K and the reference's own noise): a variance ratio above 1 is a sampling weakness, a bias that
Cycles does not have is a disagreement in the model. Prints numbers only.
"""

from __future__ import annotations

import argparse
from typing import Sequence

import numpy as np


def _rgb_stack(images: Sequence[np.ndarray]) -> np.ndarray:
    """(K, H, W, 3) float64: the renders' RGB, K >= 2."""
    stack = np.stack([np.asarray(i, np.float64)[..., :3] for i in images])
    if len(stack) < 2:
        raise ValueError(f"a variance needs at least 2 images (seeds), got {len(stack)}")
    return stack


def pixel_variance(images: Sequence[np.ndarray]) -> np.ndarray:
    """(H, W) variance of one image across K >= 2 renders ((H, W, >= 3) each, different seeds; ddof 1), averaged
    over the RGB channels."""
    return _rgb_stack(images).var(axis=0, ddof=1).mean(axis=-1)


def split_error(images: Sequence[np.ndarray], reference: np.ndarray, reference_mse: float,
                regions: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Per region (name -> (H, W) bool mask): `variance`, the mean over its pixels and channels of the variance of
    one image across `images` (K >= 2 renders with different seeds, (H, W, >= 3)), and `bias2`, the squared error
    of their mean against `reference` minus the part of it the noise explains (variance / K, and the reference's
    own per-pixel mse): an unbiased estimate of the squared bias, which may come out slightly negative."""
    stack = _rgb_stack(images)  # (converted once: the variance and the mean both read it)
    variance = stack.var(axis=0, ddof=1).mean(axis=-1)
    k = len(stack)
    ref = np.asarray(reference, np.float64)[..., :3]
    if variance.shape != ref.shape[:2]:
        raise ValueError(f"images are {variance.shape}, the reference {ref.shape[:2]}")
    stack_mean = stack.mean(axis=0)
    bias2 = ((stack_mean - ref) ** 2).mean(axis=-1) - variance / k - reference_mse
    out = {}
    for name, mask in regions.items():
        mask = np.asarray(mask, bool)
        if mask.any():
            out[name] = {"pixels": int(mask.sum()), "variance": float(variance[mask].mean()),
                         "bias2": float(bias2[mask].mean())}
    return out


def regions_by_box(position: np.ndarray, boxes: dict[str, tuple[np.ndarray, np.ndarray]],
                   margin: float = 1e-3) -> dict[str, np.ndarray]:
    """Masks of the pixels whose world position (H, W, 3) lies in each named box (lo, hi), grown by `margin` x the
    box's diagonal; a pixel in several boxes goes to the smallest. Pixels in none, or with a non-finite or all-zero
    position (no hit), are "background"."""
    pos = np.asarray(position, np.float64)[..., :3]
    hit = np.isfinite(pos).all(axis=-1) & (np.abs(pos).sum(axis=-1) > 0)
    owner = np.full(pos.shape[:2], -1)
    best = np.full(pos.shape[:2], np.inf)
    names = list(boxes)
    for i, name in enumerate(names):
        lo, hi = (np.asarray(b, np.float64) for b in boxes[name])
        pad = margin * float(np.linalg.norm(hi - lo)) + 1e-6
        inside = hit & ((pos >= lo - pad) & (pos <= hi + pad)).all(axis=-1)
        size = float(np.prod(np.maximum(hi - lo, 1e-6)))
        take = inside & (size < best)
        owner[take], best[take] = i, size
    out = {name: owner == i for i, name in enumerate(names)}
    out["background"] = owner < 0
    return out


def main(argv: Sequence[str] | None = None) -> int:
    import glob

    import bpy

    from ..addon.export import export_scene
    from ..core.render import render
    from . import bpy_scenes
    from .bench_cycles import monte_settings, render_cycles
    from .bench_reference import read_reference_file

    p = argparse.ArgumentParser(prog="python -m monte.lab.error_split", description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="textured", choices=sorted(bpy_scenes.SCENES))
    p.add_argument("--resolution", type=int, default=128, help="square image size (the reference's)")
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--max-bounces", type=int, default=16)
    p.add_argument("--reference-dir", required=True, help="the bench's reference cache (monte bench --vs cycles)")
    p.add_argument("--error-estimate", action="store_true",
                   help="render Monte with the per-pixel error estimate (2 variance groups, as the Variance pass "
                        "does); default: one Sobol sequence per pixel, as a render that reads no variance")
    args = p.parse_args(argv)
    found = sorted(glob.glob(f"{args.reference_dir}/{args.scene}-{args.resolution}x{args.resolution}-*.exr"))
    if not found:
        p.error(f"no {args.scene} {args.resolution}x{args.resolution} reference in {args.reference_dir}: "
                "run monte bench --vs cycles for it first")
    ref = read_reference_file(found[0])
    scene = bpy_scenes.build(args.scene, (args.resolution, args.resolution))
    scene.render.engine = "MONTE"
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    first = render(core_scene, monte_settings(4, 1, args.threads, args.max_bounces, data_passes=("position",)))
    position = next(v for k, v in first.data_passes.items() if k.lower() == "position")
    boxes = {}
    for mesh in core_scene.meshes:
        v = np.asarray(mesh.vertices, np.float64)
        boxes[mesh.name] = (v.min(axis=0), v.max(axis=0))
    regions = {"all": np.ones(position.shape[:2], bool), **regions_by_box(position, boxes)}
    seeds = range(1, args.seeds + 1)
    monte = [render(core_scene, monte_settings(args.spp, s, args.threads, args.max_bounces,
                                               error_estimate=args.error_estimate)).color for s in seeds]
    cycles = [render_cycles(scene, args.spp, s, args.threads, args.max_bounces)[0] for s in seeds]
    m = split_error(monte, ref.image, ref.own_mse, regions)
    c = split_error(cycles, ref.image, ref.own_mse, regions)
    print(f"{args.scene} {args.resolution}x{args.resolution}, {args.spp} spp, {args.seeds} seeds each; Monte "
          f"{'with' if args.error_estimate else 'without'} the error estimate")
    print(f"{'region':12s} {'pixels':>6s} {'var Monte':>10s} {'var Cycles':>10s} {'ratio':>6s} "
          f"{'bias2 Monte':>11s} {'bias2 Cycles':>12s}")
    for name in m:
        a, b = m[name], c[name]
        print(f"{name:12s} {a['pixels']:6d} {a['variance']:10.3e} {b['variance']:10.3e} "
              f"{a['variance'] / b['variance']:6.2f} {a['bias2']:11.2e} {b['bias2']:12.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
