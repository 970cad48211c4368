"""`monte bench --vs cycles`: Monte against Cycles, run time against error, on the same bpy scenes.

For each scene (a builder from bpy_scenes, or a user's .blend): the scene is exported to a core Scene once
through the add-on's export, then Monte (core.render.render) and Cycles (bpy.ops.render.render, CPU) render
it at each rung of a ladder of sample counts (or time budgets), interleaved (Monte 16, Cycles 16, Monte 32,
...), in this one process, with the same resolution, bounce limit, pixel filter and thread count; Cycles
with no denoising, no adaptive sampling, no clamping, blur_glossy 0 and caustics on. The time measured is
the render call itself (for Monte: Embree build + render, not the export; for Cycles: its sync + render,
not saving the image). Errors are RMSE against a converged Cycles reference from a ReferenceCache (rendered
here when missing), with the reference's own noise removed in quadrature.

With denoise=True (`--denoise`), both renderers' images are denoised with Open Image Denoise on their own
Denoising Albedo / Normal passes (Cycles: its OIDN, accurate prefilter; Monte: core.denoise, the same prefilter),
the times include the denoising, and the report adds each renderer's time to reach target errors and the
denoising seconds per megapixel (Monte's measured around its denoise call; Cycles' as the difference between a
denoised and an undenoised render of the lowest rung, an estimate).

Writes OUTDIR/bench.json and one log-log PNG (bench_vs_cycles.png, a panel per scene), and returns the report.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Callable, Sequence

import bpy
import numpy as np

from ..addon.crosscheck import configure_cycles
from ..addon.export import export_scene
from ..core import exr, metrics
from ..core.render import render as monte_render
from ..core.settings import RenderSettings
from . import bpy_scenes
from .bench_math import (corrected_rmse, efficiency, equal_error_ratio, format_table, plot_rmse_vs_seconds,
                         reference_from_seeds, seconds_at_rmse, write_json)
from .bench_reference import Reference, ReferenceCache, file_digest

DEFAULT_LADDER = (16, 32, 64, 128, 256)
BIG_SPP = 1 << 16  # sample count for time-budget rungs (the budget stops the render first)


def _read_combined(path: Path) -> np.ndarray:
    ch = exr.read_exr(path)
    for prefix in ("ViewLayer.Combined.", "Combined.", ""):
        if all(prefix + c in ch for c in "RGB"):
            return np.stack([ch[prefix + c] for c in "RGB"], axis=-1)
    combined = sorted(k for k in ch if k.endswith("Combined.R"))
    if combined:
        p = combined[0][:-1]
        return np.stack([ch[p + c] for c in "RGB"], axis=-1)
    raise RuntimeError(f"Cycles' render result has no Combined pass (channels: {', '.join(sorted(ch))})")


def render_cycles(scene, spp: int, seed: int, threads: int, max_bounces: int, time_limit: float = 0.0,
                  denoise: str | None = None, filter_type: str | None = None,
                  filter_width: float | None = None) -> tuple[np.ndarray, float]:
    """One Cycles render: (linear RGB (H, W, 3) with row 0 at the top, seconds of the render call).
    denoise: None, or the Open Image Denoise quality ("high", "balanced", "fast") Cycles denoises with (CPU,
    albedo and normal, accurate prefilter). filter_type / filter_width: the pixel filter (None: the scene's)."""
    configure_cycles(scene, spp, max_bounces, threads, seed=seed, time_limit=time_limit, filter_type=filter_type,
                     filter_width=filter_width)
    if denoise is not None:
        c = scene.cycles
        c.use_denoising = True
        c.denoiser = "OPENIMAGEDENOISE"
        c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        c.denoising_prefilter = "ACCURATE"
        c.denoising_quality = denoise.upper()
        if hasattr(c, "denoising_use_gpu"):
            c.denoising_use_gpu = False
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False, scene=scene.name)
    seconds = time.perf_counter() - t0
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    fd, tmp = tempfile.mkstemp(suffix=".exr", prefix="monte-bench-")
    os.close(fd)
    try:
        bpy.data.images["Render Result"].save_render(tmp, scene=scene)
        image = _read_combined(Path(tmp))
    finally:
        os.unlink(tmp)
    # OpenEXR stores the top row first; Blender writes the image upright, so no flip is needed.
    return image, seconds


def monte_settings(spp: int, seed: int, threads: int, max_bounces: int, time_limit: float = 0.0,
                   filter_type: str = "blackman-harris", filter_width: float = 1.5, **extra) -> RenderSettings:
    """Monte's settings matching addon.crosscheck.configure_cycles as the bench calls it: Blackman-Harris 1.5 px
    (unless given), no clamp, no AOV passes, no per-pixel error estimate (nothing the bench reads: one Sobol
    sequence per pixel, as Cycles and as a `monte render` without --variance; error_estimate=True gives 2)."""
    extra.setdefault("error_estimate", False)
    return RenderSettings(spp=int(spp), seed=int(seed), threads=int(threads), max_bounces=int(max_bounces),
                          filter_type=filter_type, filter_width=filter_width, clamp=0.0, time_limit=time_limit,
                          aovs=False, **extra).validate()


def _load_scene(spec: str, resolution: tuple[int, int] | None) -> tuple[object, str, str]:
    """Build a named bench scene or open a .blend; returns (bpy scene, name, version string for the key)."""
    if spec.endswith(".blend") or os.path.sep in spec:
        path = Path(spec).expanduser().resolve()
        if not path.is_file():
            raise FileNotFoundError(f"no such .blend file: {path}")
        bpy_scenes.reset()
        bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
        scene = bpy.context.scene
        if scene.camera is None:
            raise ValueError(f"{path} has no camera in scene {scene.name!r}")
        if resolution is not None:
            scene.render.resolution_x, scene.render.resolution_y = resolution
            scene.render.resolution_percentage = 100
        return scene, path.stem, "blend:" + file_digest(path)
    scene = bpy_scenes.build(spec, resolution or (256, 256))
    return scene, spec, f"bpy_scenes:{bpy_scenes.scene_version(spec)}"


def _resolution_of(scene) -> tuple[int, int]:
    r = scene.render
    return (r.resolution_x * r.resolution_percentage // 100, r.resolution_y * r.resolution_percentage // 100)


def reference_params(name: str, version: str, resolution, max_bounces: int, spp: int, seeds: int,
                     filter_type: str = "blackman-harris", filter_width: float = 1.5) -> dict:
    return {"scene": name, "scene_version": version, "resolution": [int(resolution[0]), int(resolution[1])],
            "max_bounces": int(max_bounces), "filter_type": filter_type, "filter_width": float(filter_width),
            "spp_per_seed": int(spp), "seeds": int(seeds), "renderer": f"cycles {bpy.app.version_string}"}


def ensure_reference(scene, params: dict, cache: ReferenceCache, threads: int,
                     log: Callable[[str], None], filter_type: str | None = None,
                     filter_width: float | None = None) -> Reference:
    """The cached reference for params, or render it now with Cycles (seeds 1..K) and cache it. filter_type /
    filter_width: the pixel filter to render it with (None: the scene's, which params must name)."""
    ref = cache.load(params)
    if ref is not None:
        log(f"  reference: {ref.source} {ref.path} (own RMSE {np.sqrt(ref.own_mse):.4g})")
        return ref
    k, n = params["seeds"], params["spp_per_seed"]
    log(f"  reference: rendering with Cycles, {k} seeds x {n} spp (cached for next time) ...")
    t0 = time.perf_counter()
    images = [render_cycles(scene, n, 1000 + s, threads, params["max_bounces"], filter_type=filter_type,
                            filter_width=filter_width)[0] for s in range(k)]
    mean, own_mse = reference_from_seeds(images)
    path = cache.store(mean, own_mse, params, note=f"Cycles, {k} seeds x {n} spp, "
                                                   f"{time.perf_counter() - t0:.0f} s")
    log(f"  reference: wrote {path} (own RMSE {np.sqrt(own_mse):.4g}, {time.perf_counter() - t0:.0f} s)")
    return Reference(mean, own_mse, params, path, "rendered")


def _point(renderer: str, rung, image: np.ndarray, seconds: float, ref: Reference, samples: int) -> dict:
    err = metrics.rmse(image, ref.image)
    err_c = corrected_rmse(err, ref.own_mse)
    return {"renderer": renderer, "rung": rung, "seconds": seconds, "samples": samples,
            "samples_per_second": samples / seconds if seconds > 0 else float("nan"),
            "rmse": err, "rmse_corrected": err_c, "efficiency": efficiency(seconds, err_c * err_c)}


def _monte_point(core_scene, settings: RenderSettings, denoise: str | None) -> tuple[np.ndarray, float, int, float]:
    """One timed Monte render (denoised when denoise names a quality): (RGB, seconds, samples, denoise seconds)."""
    from ..core.denoise import denoise as oidn_denoise

    if denoise is not None:
        settings = settings.replace(denoising_features=True)
    t0 = time.perf_counter()
    result = monte_render(core_scene, settings)
    t_denoise = 0.0
    image = result.color[..., :3]
    if denoise is not None:
        t1 = time.perf_counter()
        image = oidn_denoise(image, result.denoising_albedo, result.denoising_normal, quality=denoise)
        t_denoise = time.perf_counter() - t1
    return image, time.perf_counter() - t0, int(result.sample_count.sum()), t_denoise


def bench_scene(spec: str, *, cache: ReferenceCache, ladder: Sequence[int] = DEFAULT_LADDER,
                time_ladder: Sequence[float] | None = None, threads: int = 2, max_bounces: int = 16,
                resolution: tuple[int, int] | None = None, reference_spp: int = 1024, reference_seeds: int = 4,
                seed: int = 1, denoise: str | None = None, log: Callable[[str], None] = print) -> dict:
    """Monte and Cycles on one scene at each rung, interleaved; returns the scene's report. denoise: None, or
    the Open Image Denoise quality both renderers denoise with (see the module docstring)."""
    scene, name, version = _load_scene(spec, resolution)
    res = _resolution_of(scene)
    log(f"{name} {res[0]}x{res[1]}, {threads} threads, max bounces {max_bounces}")
    params = reference_params(name, version, res, max_bounces, reference_spp, reference_seeds)
    ref = ensure_reference(scene, params, cache, threads, log)

    scene.render.engine = "MONTE"
    core_scene, stats = export_scene(bpy.context.evaluated_depsgraph_get())
    log(f"  monte export: {stats.line()}")
    # Warm-up, untimed: first calls load kernels, tables and caches in both renderers (and the denoisers).
    _monte_point(core_scene, monte_settings(1, seed, threads, max_bounces), denoise)
    render_cycles(scene, 1, seed, threads, max_bounces, denoise=denoise)

    points = []
    monte_denoise_seconds = []
    rungs = list(time_ladder) if time_ladder else list(ladder)
    n_pix = res[0] * res[1]
    for rung in rungs:
        if time_ladder:
            m_set = monte_settings(BIG_SPP, seed, threads, max_bounces, time_limit=float(rung))
        else:
            m_set = monte_settings(int(rung), seed, threads, max_bounces)
        m_img, m_sec, m_samples, m_denoise = _monte_point(core_scene, m_set, denoise)
        monte_denoise_seconds.append(m_denoise)
        points.append(_point("monte", rung, m_img, m_sec, ref, m_samples))
        if time_ladder:
            c_img, c_sec = render_cycles(scene, BIG_SPP, seed, threads, max_bounces, time_limit=float(rung),
                                         denoise=denoise)
            c_samples = -1  # Cycles does not report how many samples fit in the budget
        else:
            c_img, c_sec = render_cycles(scene, int(rung), seed, threads, max_bounces, denoise=denoise)
            c_samples = int(rung) * n_pix
        points.append(_point("cycles", rung, c_img, c_sec, ref, c_samples))
        m, c = points[-2], points[-1]
        log(f"  {rung:>6} {'s' if time_ladder else 'spp'}: monte {m['seconds']:7.2f} s RMSE "
            f"{m['rmse_corrected']:.4f} eff {m['efficiency']:7.1f} | cycles {c['seconds']:7.2f} s RMSE "
            f"{c['rmse_corrected']:.4f} eff {c['efficiency']:7.1f}")
    mon = [p for p in points if p["renderer"] == "monte"]
    cyc = [p for p in points if p["renderer"] == "cycles"]
    ratio = equal_error_ratio(([p["seconds"] for p in mon], [p["rmse_corrected"] for p in mon]),
                              ([p["seconds"] for p in cyc], [p["rmse_corrected"] for p in cyc]))
    report = {}
    if denoise is not None:
        report["denoise"] = _denoise_report(scene, rungs, time_ladder, seed, threads, max_bounces, denoise,
                                            points, monte_denoise_seconds, n_pix, log)
    return {**report, "scene": name, "source": spec, "resolution": list(res), "threads": threads,
            "max_bounces": max_bounces, "ladder_kind": "seconds" if time_ladder else "spp",
            "triangles": stats.triangles, "instances": stats.instances,
            "reference": {"path": str(ref.path) if ref.path else None, "source": ref.source,
                          "own_rmse": float(np.sqrt(ref.own_mse)), "params": ref.params},
            "points": points, "equal_error": ratio,
            "monte_over_cycles_efficiency": ratio["ratio"]}


def _denoise_report(scene, rungs, time_ladder, seed, threads, max_bounces, quality: str, points: list[dict],
                    monte_denoise_seconds: list[float], n_pix: int, log) -> dict:
    """Denoising seconds per megapixel (Monte measured; Cycles estimated as a denoised minus an undenoised
    render of the lowest rung) and the seconds each renderer needs for target errors (log-log interpolation of
    its points; None outside the errors it reached)."""
    megapixels = n_pix / 1e6
    monte_s_per_mp = float(np.median(monte_denoise_seconds)) / megapixels
    rung = rungs[0]
    spp, limit = (BIG_SPP, float(rung)) if time_ladder else (int(rung), 0.0)
    plain = render_cycles(scene, spp, seed, threads, max_bounces, time_limit=limit)[1]
    denoised = render_cycles(scene, spp, seed, threads, max_bounces, time_limit=limit, denoise=quality)[1]
    cycles_s_per_mp = max(denoised - plain, 0.0) / megapixels
    targets = {}
    for renderer in ("monte", "cycles"):
        pts = [p for p in points if p["renderer"] == renderer]
        t = np.array([p["seconds"] for p in pts])
        e = np.array([p["rmse_corrected"] for p in pts])
        targets[renderer] = e, t
    all_errors = np.concatenate([targets[r][0] for r in targets])
    levels = sorted({float(v) for v in np.quantile(all_errors[all_errors > 0], (0.25, 0.5, 0.75))}) \
        if (all_errors > 0).any() else []
    seconds_for = {}
    for renderer, (e, t) in targets.items():
        ok = (e > 0) & (t > 0)
        seconds_for[renderer] = []
        for level in levels:
            inside = ok.any() and e[ok].min() <= level <= e[ok].max()
            seconds_for[renderer].append(float(seconds_at_rmse(t[ok], e[ok], np.array([level]))[0])
                                         if inside else None)
    log(f"  denoising ({quality}): Monte {monte_s_per_mp:.2f} s/MP, Cycles about {cycles_s_per_mp:.2f} s/MP")
    for i, level in enumerate(levels):
        m, c = seconds_for["monte"][i], seconds_for["cycles"][i]
        log(f"  time for RMSE {level:.4f}: Monte {'-' if m is None else f'{m:.2f} s'}, "
            f"Cycles {'-' if c is None else f'{c:.2f} s'}")
    return {"quality": quality, "monte_seconds_per_megapixel": monte_s_per_mp,
            "cycles_seconds_per_megapixel_estimate": cycles_s_per_mp, "target_rmse": levels,
            "seconds_for_target": seconds_for}


def summary_table(scenes: list[dict]) -> str:
    headers = ["scene", "rung", "monte s", "monte RMSE", "monte eff", "cycles s", "cycles RMSE", "cycles eff"]
    rows = []
    for s in scenes:
        mon = [p for p in s["points"] if p["renderer"] == "monte"]
        cyc = [p for p in s["points"] if p["renderer"] == "cycles"]
        for m, c in zip(mon, cyc):
            rows.append([s["scene"], m["rung"], m["seconds"], m["rmse_corrected"], m["efficiency"],
                         c["seconds"], c["rmse_corrected"], c["efficiency"]])
    return format_table(headers, rows)


def ratio_lines(scenes: list[dict]) -> list[str]:
    out = []
    for s in scenes:
        r = s["equal_error"]
        where = "extrapolated" if r["extrapolated"] else \
            (f"RMSE {min(r['levels']):.4f}..{max(r['levels']):.4f}" if r["levels"] else "no common error")
        out.append(f"{s['scene']}: Monte/Cycles efficiency at equal error = {r['ratio']:.3g} ({where})")
    return out


def run_vs_cycles(specs: Sequence[str], reference_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
                  log: Callable[[str], None] = print, **options) -> dict:
    """Bench every scene in specs (names from bpy_scenes.SCENES or .blend paths); write OUTDIR/bench.json
    and OUTDIR/bench_vs_cycles.png; print a table. options: see bench_scene."""
    out = Path(out_dir).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    cache = ReferenceCache(reference_dir)
    scenes = [bench_scene(spec, cache=cache, log=log, **options) for spec in specs]
    report = {"kind": "monte-vs-cycles", "blender": bpy.app.version_string, "cpu_count": os.cpu_count(),
              "time": time.strftime("%Y-%m-%d %H:%M:%S"), "scenes": scenes}
    write_json(out / "bench.json", report)
    panels = [{"title": f"{s['scene']} {s['resolution'][0]}x{s['resolution'][1]}, {s['threads']} threads "
                        f"(Monte/Cycles eff. {s['monte_over_cycles_efficiency']:.2g})",
               "series": [{"label": r, "seconds": [p["seconds"] for p in s["points"] if p["renderer"] == r],
                           "rmse": [p["rmse_corrected"] for p in s["points"] if p["renderer"] == r],
                           "spp": [p["rung"] for p in s["points"] if p["renderer"] == r]}
                          for r in ("monte", "cycles")]} for s in scenes]
    plot_rmse_vs_seconds(panels, out / "bench_vs_cycles.png")
    log("")
    log(summary_table(scenes))
    for line in ratio_lines(scenes):
        log(line)
    log(f"wrote {out / 'bench.json'}, {out / 'bench_vs_cycles.png'}")
    return report


def _scene_specs(args) -> list[str]:
    from .bench_args import BENCH_SCENES

    choice = args.scene or ("none" if args.blend else "cornell")
    names = list(BENCH_SCENES) if choice == "all" else [] if choice == "none" else [choice]
    return names + list(args.blend)


def run_from_args(args, overrides: dict) -> dict:
    """`monte bench --vs cycles ...` (cli.py): check the arguments, then run_vs_cycles."""
    specs = _scene_specs(args)
    if not specs:
        raise ValueError("nothing to bench: name --scene or give .blend files")
    if not args.reference_dir:
        raise ValueError("--vs cycles needs --reference-dir DIR (converged references are cached there)")
    if not args.output_dir:
        raise ValueError("--vs cycles needs -o OUTDIR (bench.json and the plot go there)")
    if args.ladder and args.time_ladder:
        raise ValueError("give either --ladder (sample counts) or --time-ladder (seconds), not both")
    if args.reference_seeds < 2 or args.reference_spp < 1:
        raise ValueError("the reference needs --reference-seeds >= 2 (to estimate its own noise) and "
                         "--reference-spp >= 1")
    if getattr(args, "whole_process", False):
        unsupported = sorted(set(overrides) - {"threads", "max_bounces", "seed", "spp"})
        if unsupported:
            raise ValueError(f"--whole-process fixes these settings for a fair comparison: {', '.join(unsupported)}")
        if args.ladder or args.time_ladder:
            raise ValueError("--whole-process renders at --spp (default 64), not a ladder")
        if args.repeats < 1:
            raise ValueError(f"--repeats must be at least 1, got {args.repeats}")
        from .bench_whole_process import run_whole_process

        return run_whole_process(specs, args.reference_dir, args.output_dir, spp=overrides.get("spp", 64),
                                 repeats=args.repeats, threads=overrides.get("threads") or 2,
                                 max_bounces=overrides.get("max_bounces", 16),
                                 resolution=tuple(args.resolution) if args.resolution else None,
                                 reference_spp=args.reference_spp, reference_seeds=args.reference_seeds,
                                 seed=overrides.get("seed", 1))
    unsupported = sorted(set(overrides) - {"threads", "max_bounces", "seed", "denoising_features"})
    if unsupported:
        raise ValueError(f"--vs cycles fixes these settings for a fair comparison: {', '.join(unsupported)}")
    return run_vs_cycles(specs, args.reference_dir, args.output_dir,
                         ladder=args.ladder or DEFAULT_LADDER, time_ladder=args.time_ladder,
                         threads=overrides.get("threads") or 2, max_bounces=overrides.get("max_bounces", 16),
                         resolution=tuple(args.resolution) if args.resolution else None,
                         reference_spp=args.reference_spp, reference_seeds=args.reference_seeds,
                         seed=overrides.get("seed", 1),
                         denoise=args.denoise_quality if getattr(args, "denoise", False) else None)


def cornell_reference_maker(args) -> Callable[[tuple[int, int]], Reference]:
    """For the Monte-only ladders: render (or load) the Cornell reference at a resolution into
    --reference-dir with Cycles."""
    def make(resolution: tuple[int, int]) -> Reference:
        threads = args.threads or 2
        max_bounces = args.max_bounces if args.max_bounces is not None else 16
        scene, name, version = _load_scene("cornell", tuple(resolution))
        params = reference_params(name, version, _resolution_of(scene), max_bounces, args.reference_spp,
                                  args.reference_seeds)
        return ensure_reference(scene, params, ReferenceCache(args.reference_dir), threads, print)

    return make
