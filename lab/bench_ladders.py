"""Monte-only benchmark ladders on the seed's Cornell box (no bpy): samplers, batch sizes, the seed's tables.

- `samplers`: sobol, stratified (the seed's 2x2 strata) and independent at a ladder of sample counts,
  interleaved; RMSE and efficiency at equal spp, and each sampler's efficiency relative to Sobol at equal error.
- `batch_sizes`: one sample count at several batch sizes (paths in flight); time, samples/s, RMSE, efficiency
  and the process's peak memory so far (run in ascending order, so the peak belongs to the largest batch yet).
- `seed_table`: the seed's variance tables. The seed rendered its Cornell box with 2x2 strata per pixel and
  tent-distributed sub-pixel offsets at 8, 40, 200, 1000, 5000 and 25000 samples per stratum (4x that per
  pixel) and reported, for R, G, B and BT.709 luma, the variance of the pixel values over the image of its
  output (smallpt writes values clamped to [0, 1] and gamma-encoded with 1/2.2). That number mixes the
  image's own contrast with noise and levels off at the contrast, not at 0; next to it the table gives the
  quantities that measure the noise: the mean per-pixel variance of the estimate (RenderResult.variance)
  and the RMSE against the converged Cycles reference.

Errors are RMSE against a reference with its own noise removed in quadrature (bench_math.corrected_rmse).
Every function prints nothing; the `run_*` entry points used by `monte bench` print tables and write JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..core import metrics
from ..core.render import render
from ..core.builtin_scenes import cornell_box
from ..core.settings import RenderSettings
from .bench_args import SEED_TABLE_COUNTS
from .bench_math import corrected_rmse, efficiency, equal_error_ratio, format_table, write_json
from .bench_reference import BUNDLED_OWN_RMSE, Reference, read_reference_file
SEED_GAMMA = 2.2  # smallpt's output encoding: (clamp(x, 0, 1)) ** (1 / 2.2)


# --------------------------------------------------------------------------------------------- references
def find_cornell_reference(resolution: tuple[int, int], max_bounces: int = 16,
                           reference: str | os.PathLike | None = None,
                           reference_dir: str | os.PathLike | None = None) -> Reference | None:
    """The reference for the Cornell box at this resolution: the file given; else the best cached one in
    reference_dir (Blackman-Harris 1.5 px, same bounces, most samples); else the bundled one at 256x256 and
    16 bounces; else None."""
    if reference:
        return read_reference_file(reference)
    w, h = resolution
    if reference_dir and Path(reference_dir).is_dir():
        best, best_n = None, -1
        for meta_path in Path(reference_dir).glob(f"cornell-{w}x{h}-*.json"):
            try:
                meta = json.loads(meta_path.read_text())
                p = meta["params"]
            except (OSError, ValueError, KeyError):
                continue
            exr_path = meta_path.with_suffix(".exr")
            ok = (p.get("max_bounces") == max_bounces and p.get("filter_type") == "blackman-harris"
                  and p.get("filter_width") == 1.5 and exr_path.is_file())
            n = int(p.get("spp_per_seed", 0)) * int(p.get("seeds", 0))
            if ok and n > best_n:
                best, best_n = (exr_path, meta), n
        if best is not None:
            from ..core.exr import read_rgb

            return Reference(read_rgb(best[0]), float(best[1]["own_mse"]), best[1]["params"], best[0], "cache")
    if (w, h) == (256, 256) and max_bounces == 16:
        from .bench import bundled_reference

        return Reference(bundled_reference(), BUNDLED_OWN_RMSE**2, {"scene": "cornell"}, None, "bundled")
    return None


def _peak_memory_mb() -> float:
    """The process's peak resident memory so far in MB (NaN where the resource module is missing)."""
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    except (ImportError, OSError):
        return float("nan")


def _errors(image: np.ndarray, ref: Reference | None) -> tuple[float, float]:
    if ref is None or ref.image.shape[:2] != image.shape[:2]:
        return float("nan"), float("nan")
    err = metrics.rmse(image, ref.image)
    return err, corrected_rmse(err, ref.own_mse)


def _settings(args_overrides: dict, **fixed) -> RenderSettings:
    return RenderSettings(**{**args_overrides, "aovs": False, **fixed}).validate()


# --------------------------------------------------------------------------------------------- ladders
def sampler_ladder(ladder: Sequence[int], samplers: Sequence[str] = ("sobol", "stratified", "independent"),
                   resolution: tuple[int, int] = (256, 256), reference: Reference | None = None,
                   overrides: dict | None = None, log: Callable[[str], None] = lambda m: None) -> dict:
    """Each sampler at each spp (interleaved: all samplers at 16, then at 32, ...): seconds, RMSE,
    efficiency; and each sampler's efficiency over Sobol's at equal error."""
    scene = cornell_box(resolution)
    overrides = dict(overrides or {})
    render(scene, _settings(overrides, spp=1))  # warm-up: tables, caches
    points = []
    for spp in ladder:
        for sampler in samplers:
            result = render(scene, _settings(overrides, spp=int(spp), sampler=sampler))
            sec = result.stats["seconds"]
            err, err_c = _errors(result.color[..., :3], reference)
            points.append({"sampler": sampler, "spp": int(spp), "seconds": sec, "rmse": err,
                           "rmse_corrected": err_c, "efficiency": efficiency(sec, err_c * err_c),
                           "mean_pixel_variance": float(np.mean(result.variance))})
            log(f"  {sampler:12s} {spp:5d} spp  {sec:7.2f} s  RMSE {err_c:.4f}  eff {points[-1]['efficiency']:.1f}")
    base = [p for p in points if p["sampler"] == samplers[0]]
    ratios = {}
    for s in samplers:
        mine = [p for p in points if p["sampler"] == s]
        ratios[s] = equal_error_ratio(([p["seconds"] for p in mine], [p["rmse_corrected"] for p in mine]),
                                      ([p["seconds"] for p in base], [p["rmse_corrected"] for p in base]))
    return {"kind": "samplers", "resolution": list(resolution), "points": points,
            "efficiency_over_first_at_equal_error": {s: r["ratio"] for s, r in ratios.items()},
            "equal_error": ratios}


def batch_ladder(batch_sizes: Sequence[int], spp: int = 16, resolution: tuple[int, int] = (256, 256),
                 reference: Reference | None = None, overrides: dict | None = None,
                 log: Callable[[str], None] = lambda m: None) -> dict:
    """One spp at each batch size in ascending order: seconds, samples/s, RMSE, efficiency, peak RSS so far."""
    scene = cornell_box(resolution)
    overrides = dict(overrides or {})
    render(scene, _settings(overrides, spp=1))
    points = []
    for batch in sorted(int(b) for b in batch_sizes):
        result = render(scene, _settings(overrides, spp=int(spp), batch_paths=batch))
        st = result.stats
        err, err_c = _errors(result.color[..., :3], reference)
        points.append({"batch_paths": batch, "spp": int(spp), "seconds": st["seconds"],
                       "samples_per_second": st["samples_per_second"], "rmse": err, "rmse_corrected": err_c,
                       "efficiency": efficiency(st["seconds"], err_c * err_c), "peak_memory_mb": _peak_memory_mb()})
        log(f"  batch {batch:8d}  {st['seconds']:7.2f} s  {st['samples_per_second'] / 1e3:6.1f} k samples/s  "
            f"peak {points[-1]['peak_memory_mb']:.0f} MB")
    return {"kind": "batch-sizes", "resolution": list(resolution), "spp": int(spp), "points": points}


def seed_display_values(image: np.ndarray) -> np.ndarray:
    """What the seed's program wrote: linear values clamped to [0, 1], encoded with gamma 1/2.2."""
    return np.clip(np.asarray(image[..., :3], np.float64), 0.0, 1.0) ** (1.0 / SEED_GAMMA)


def seed_table(counts_per_stratum: Sequence[int] = SEED_TABLE_COUNTS, resolution: tuple[int, int] = (256, 256),
               reference: Reference | None = None, overrides: dict | None = None, filter_width: float = 1.0,
               log: Callable[[str], None] = lambda m: None) -> dict:
    """The seed's variance table: the Cornell box with 2x2 strata per pixel (sampler 'stratified') and a tent
    filter of filter_width px, at 4 x count samples per pixel for each count. Per row: the seed's variance of
    pixel values over the image (display values, R, G, B, BT.709 luma; also for linear values), the mean
    per-pixel variance of the estimate (linear) and the RMSE against the reference."""
    scene = cornell_box(resolution)
    overrides = dict(overrides or {})
    rows = []
    for count in counts_per_stratum:
        if int(count) < 1:
            raise ValueError(f"samples per stratum must be >= 1, got {count}")
        settings = _settings(overrides, spp=4 * int(count), sampler="stratified", filter_type="tent",
                             filter_width=filter_width)
        result = render(scene, settings)
        image = result.color[..., :3]
        err, err_c = _errors(image, reference)
        row = {"samples_per_stratum": int(count), "spp": 4 * int(count), "seconds": result.stats["seconds"],
               "seed_variance": metrics.seed_variance_table(seed_display_values(image)),
               "seed_variance_linear": metrics.seed_variance_table(image),
               "mean_pixel_variance": metrics.mean_pixel_variance(result.variance),
               "rmse": err, "rmse_corrected": err_c}
        rows.append(row)
        log(f"  {count:6d} per stratum ({4 * count} spp): {row['seconds']:.1f} s, luma variance "
            f"{row['seed_variance']['luma']:.5f}, mean pixel variance {row['mean_pixel_variance']['luma']:.3g}")
    return {"kind": "seed-table", "resolution": list(resolution), "sampler": "stratified (2x2 per pixel)",
            "filter": f"tent {filter_width} px", "display_encoding": f"clamp [0, 1], gamma 1/{SEED_GAMMA}",
            "reference": None if reference is None else
            {"source": reference.source, "path": str(reference.path) if reference.path else None,
             "own_rmse": float(np.sqrt(reference.own_mse))}, "rows": rows}


SEED_PUBLISHED = {  # the seed's numbers (its slides), samples per stratum -> R, G, B, luma
    8: (0.07344142, 0.06190188, 0.07339846, 0.06380390),
    40: (0.05132978, 0.04714374, 0.05175589, 0.04621717),
    200: (0.02482136, 0.02453323, 0.02517796, 0.02276842),
    1000: (0.02023584, 0.02019825, 0.02031221, 0.01840096),
    5000: (0.01904086, 0.01936775, 0.01930308, 0.01754279),
    25000: (0.01885027, 0.01919554, 0.01911878, 0.01737635),
}


def seed_table_markdown(table: dict) -> str:
    """The seed-table report as Markdown: the seed's quantity (and its published numbers) beside the noise."""
    w, h = table["resolution"]
    headers = ["per stratum", "spp", "s", "var R", "var G", "var B", "var luma", "seed's luma",
               "pixel var (luma)", "RMSE"]
    rows = []
    for r in table["rows"]:
        sv, pv = r["seed_variance"], r["mean_pixel_variance"]
        published = SEED_PUBLISHED.get(r["samples_per_stratum"])
        rows.append([r["samples_per_stratum"], r["spp"], round(r["seconds"], 1), sv["R"], sv["G"], sv["B"],
                     sv["luma"], published[3] if published else float("nan"), pv["luma"], r["rmse_corrected"]])
    ref = table.get("reference")
    note = (f"Cornell box {w}x{h}, {table['sampler']}, {table['filter']}. var R/G/B/luma: variance of pixel "
            f"values over the image as the seed computed it (display values: {table['display_encoding']}); "
            "seed's luma: the seed's published number at that count (its own scene and renderer). pixel var: mean "
            "per-pixel variance of the estimate (linear, BT.709 luma weights squared). RMSE: "
            + (f"linear, against the {ref['source']} Cycles reference (Blackman-Harris 1.5 px, its own noise "
               f"{ref['own_rmse']:.4f} removed; the filter difference adds a small floor)" if ref else
               "left out (no reference at this resolution)") + ".")
    return format_table(headers, rows, markdown=True) + "\n\n" + note + "\n"


# --------------------------------------------------------------------------------------------- command line
def _out_dir(args) -> Path | None:
    if not args.output_dir:
        return None
    out = Path(args.output_dir).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    return out


def run_ladders(args: argparse.Namespace, overrides: dict,
                make_reference: Callable[[tuple[int, int]], Reference | None] | None = None) -> dict:
    """`monte bench --samplers / --batch-sizes / --seed-table`: print tables, write JSON (and seed_table.md)."""
    resolution = tuple(args.resolution) if args.resolution else (256, 256)
    max_bounces = overrides.get("max_bounces", 16)
    reference = find_cornell_reference(resolution, max_bounces, args.reference, args.reference_dir)
    if reference is None and make_reference is not None:
        reference = make_reference(resolution)
    if reference is None:
        print(f"note: no reference for the Cornell box at {resolution[0]}x{resolution[1]}: RMSE left out "
              "(give --reference-dir DIR with bpy installed to render one, or --reference FILE)")
    log = print
    out = _out_dir(args)
    report: dict = {"time": time.strftime("%Y-%m-%d %H:%M:%S"), "cpu_count": os.cpu_count()}
    base = {k: v for k, v in overrides.items() if k not in ("spp", "sampler", "batch_paths")}
    if args.samplers:
        ladder = args.ladder or [16, 32, 64]
        print(f"Samplers on the Cornell box {resolution[0]}x{resolution[1]}, spp {ladder}")
        r = sampler_ladder(ladder, resolution=resolution, reference=reference, overrides=base, log=log)
        rows = [[p["sampler"], p["spp"], p["seconds"], p["rmse_corrected"], p["efficiency"]] for p in r["points"]]
        print(format_table(["sampler", "spp", "seconds", "RMSE", "efficiency"], rows))
        for s, ratio in r["efficiency_over_first_at_equal_error"].items():
            print(f"  {s}: efficiency relative to sobol at equal error {ratio:.3g}")
        report["samplers"] = r
    if args.batch_sizes:
        spp = overrides.get("spp", 16)
        print(f"Batch sizes on the Cornell box {resolution[0]}x{resolution[1]}, {spp} spp")
        r = batch_ladder(args.batch_sizes, spp, resolution, reference, {**base, "sampler": overrides.get(
            "sampler", "sobol")}, log=log)
        rows = [[p["batch_paths"], p["seconds"], p["samples_per_second"], p["rmse_corrected"], p["efficiency"],
                 p["peak_memory_mb"]] for p in r["points"]]
        print(format_table(["batch", "seconds", "samples/s", "RMSE", "efficiency", "peak MB"], rows))
        report["batch_sizes"] = r
    if args.seed_table:
        print(f"The seed's variance table, Cornell box {resolution[0]}x{resolution[1]}, "
              f"{args.strata_samples} samples per stratum")
        width = base.pop("filter_width", 1.0)
        base.pop("filter_type", None)
        r = seed_table(args.strata_samples, resolution, reference, base, filter_width=width, log=log)
        md = seed_table_markdown(r)
        print(md)
        report["seed_table"] = r
        if out is not None:
            (out / "seed_table.md").write_text(md)
    if out is not None:
        write_json(out / "bench.json", report)
        print(f"wrote {out / 'bench.json'}")
    return report
