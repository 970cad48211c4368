"""Cross-check: render one Blender scene with Monte and with Cycles and say whether they agree within noise.

`crosscheck_scene(scene, out_dir, options)` renders the scene (the current bpy scene, or one opened by
`crosscheck_blend_file`) twice through Blender's own render operator, so both engines see the same evaluated
scene (render-time modifiers, instances, the frame's camera):
- Monte through the add-on's engine, with the per-pixel variance of each pixel's mean that Monte estimates;
- Cycles on the CPU as an unbiased reference (`configure_cycles`): same resolution, camera, thread count,
  bounce limit (every per-kind limit set to it), pixel filter type and width; no denoising, adaptive
  sampling or clamping; blur_glossy 0; caustics on. Cycles gives no variance, so it renders K times with
  different seeds and the variance comes from the spread of the K images (core.compare explains the
  estimator and its 3x3 pooling).
Then it writes monte.exr and cycles.exr (with variance channels), difference.png (per-pixel z-scores in false
colour), monte.png, cycles.png, report.json and report.txt (core.compare's statistics, the verdict and, when
they disagree, which materials and which lights hold the difference).

Every scene, render and material setting it changes is restored afterwards, also on error.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import bpy
import numpy as np

from ..core import compare as cmp
from ..core.atomic_file import write_text_atomically
from ..core import exr

CYCLES_FILTERS = {"blackman-harris": "BLACKMAN_HARRIS", "gaussian": "GAUSSIAN", "box": "BOX"}
MAX_ATTRIBUTED_LIGHTS = 8


class CrosscheckError(RuntimeError):
    """The cross-check could not run; the message says why."""


@dataclass
class CrosscheckOptions:
    """What to render. None means "the scene's own setting".

    spp: Monte's samples per pixel (default scene.monte.samples). cycles_spp: Cycles' samples per pixel in
    total, split over cycles_runs renders with seeds 1..K (default: the same as Monte's). resolution:
    (width, height) in pixels at 100 %. threads: for both renderers (0 = all cores). max_bounces: for both
    (default scene.monte.max_bounces). rel_floor: the relative tolerance floor on channel means (0.5 %;
    larger where Monte approximates on purpose). attribute: when they disagree, find which materials and
    lights hold the difference (costs two more renders per light)."""

    spp: int | None = None
    cycles_spp: int | None = None
    cycles_runs: int = 4
    resolution: tuple[int, int] | None = None
    threads: int = 0
    max_bounces: int | None = None
    rel_floor: float = cmp.REL_FLOOR
    attribute: bool = True

    def validate(self) -> "CrosscheckOptions":
        for name in ("spp", "cycles_spp"):
            v = getattr(self, name)
            if v is not None and (int(v) != v or v < 1):
                raise ValueError(f"{name} must be a positive integer, got {v}")
        if int(self.cycles_runs) != self.cycles_runs or self.cycles_runs < 2:
            raise ValueError(f"cycles_runs must be at least 2 (the variance needs two renders), got {self.cycles_runs}")
        if self.threads < 0:
            raise ValueError(f"threads must be >= 0 (0 = all cores), got {self.threads}")
        if self.max_bounces is not None and self.max_bounces < 0:
            raise ValueError(f"max_bounces must be >= 0, got {self.max_bounces}")
        if self.resolution is not None and (len(self.resolution) != 2 or min(self.resolution) < 1):
            raise ValueError(f"resolution must be (width, height) >= 1, got {self.resolution}")
        if not (0 <= self.rel_floor < 1):
            raise ValueError(f"rel_floor must be in [0, 1), got {self.rel_floor}")
        return self


# ------------------------------------------------------------------------------------------ settings
class _Overrides:
    """Set attributes and remember the old values; restore() puts them back in reverse order."""

    def __init__(self) -> None:
        self._saved: list[tuple[Any, str, Any]] = []

    def set(self, owner, attr: str, value) -> None:
        self._saved.append((owner, attr, getattr(owner, attr)))
        setattr(owner, attr, value)

    def restore(self) -> None:
        while self._saved:
            owner, attr, value = self._saved.pop()
            try:
                setattr(owner, attr, value)
            except (ReferenceError, AttributeError, TypeError):  # a datablock removed meanwhile
                pass


def configure_cycles(scene, spp: int, max_bounces: int, threads: int, seed: int = 1,
                     filter_type: str | None = None, filter_width: float | None = None,
                     overrides: _Overrides | None = None, time_limit: float = 0.0) -> None:
    """Make Cycles an unbiased CPU reference for Monte: spp samples, every bounce limit max_bounces (Cycles'
    counting, as Monte's), no denoising/adaptive sampling/clamping, blur_glossy 0, caustics on, a fixed
    seed and thread count (0 = all cores), and Monte's pixel filter (type and width, Cycles' meaning).
    time_limit: seconds (0 = none; the bench's time-budget rungs). The one Cycles set-up of the project: the
    cross-check, the bench (lab.bench_cycles) and the stress suite's Cycles column (lab.core_to_bpy) use it."""
    o = overrides or _Overrides()
    c = scene.cycles
    o.set(scene.render, "engine", "CYCLES")
    o.set(c, "device", "CPU")
    o.set(c, "samples", int(spp))
    o.set(c, "use_adaptive_sampling", False)
    o.set(c, "use_denoising", False)
    o.set(c, "sample_clamp_direct", 0.0)
    o.set(c, "sample_clamp_indirect", 0.0)
    o.set(c, "blur_glossy", 0.0)
    o.set(c, "caustics_reflective", True)
    o.set(c, "caustics_refractive", True)
    for attr in ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces"):
        o.set(c, attr, int(max_bounces))
    o.set(c, "volume_bounces", 0)  # Monte renders no volumes
    o.set(c, "transparent_max_bounces", max(int(max_bounces), 8))
    o.set(c, "seed", int(seed))
    o.set(c, "use_animated_seed", False)
    o.set(c, "time_limit", float(time_limit))
    if filter_type is not None:
        if filter_type not in CYCLES_FILTERS:
            raise ValueError(f"Cycles has no {filter_type!r} pixel filter; use one of {', '.join(CYCLES_FILTERS)}")
        o.set(c, "pixel_filter_type", CYCLES_FILTERS[filter_type])
    if filter_width is not None:
        o.set(c, "filter_width", float(filter_width))
    o.set(scene.render, "threads_mode", "FIXED")
    o.set(scene.render, "threads", int(threads) or (os.cpu_count() or 1))
    for layer in scene.view_layers:  # no denoising data passes: time spent on nothing compared
        if hasattr(layer, "cycles"):
            o.set(layer.cycles, "denoising_store_passes", False)


def _render_layer(scene):
    layers = [vl for vl in scene.view_layers if vl.use]
    if not layers:
        raise CrosscheckError(f"scene {scene.name!r} has no view layer enabled for rendering")
    return layers[0]


def _render(scene, what: str) -> list:
    from .engine import render_with_operator

    try:
        return render_with_operator(scene)
    except RuntimeError as exc:
        raise CrosscheckError(f"{what} render of scene {scene.name!r} failed: {exc}") from exc


def render_monte(scene) -> tuple[np.ndarray, np.ndarray]:
    """Render the scene with Monte as F12 does: (colour (H, W, 3), variance of each pixel's mean (H, W, 3)),
    row 0 at the top. scene.monte and scene.render must already hold the wanted settings; the rendered view
    layer's Variance pass is ticked for the render (the engine then keeps the error estimate,
    core.settings.RenderSettings.error_estimate) and restored after it."""
    scene.render.engine = "MONTE"
    o = _Overrides()
    for layer in scene.view_layers:  # every layer that may render first (captured[0]), not only the one compared
        if layer.use:
            o.set(layer.monte, "use_pass_variance", True)
    o.set(_render_layer(scene).monte, "use_pass_variance", True)
    try:
        captured = _render(scene, "Monte")
    finally:
        o.restore()
    if not captured:
        raise CrosscheckError(f"Monte produced no image for scene {scene.name!r}")
    result = captured[0][1]
    if result.variance is None:
        raise CrosscheckError("Monte's render kept no error estimate (its variance): the comparison needs it")
    return (np.asarray(result.color, np.float64)[..., :3].copy(),
            np.asarray(result.variance, np.float64)[..., :3].copy())


def render_cycles(scene, tmp_dir: Path, with_material_index: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Render the scene with Cycles (already configured) and read the Render Result back through a
    multilayer EXR: (colour (H, W, 3), material index (H, W) or None), row 0 at the top."""
    layer = _render_layer(scene)
    _render(scene, "Cycles")
    image = bpy.data.images.get("Render Result")
    if image is None:
        raise CrosscheckError("Cycles produced no Render Result")
    o = _Overrides()
    settings = scene.render.image_settings
    try:
        if hasattr(settings, "media_type"):  # Blender 5.0+
            o.set(settings, "media_type", "MULTI_LAYER_IMAGE")
        o.set(settings, "file_format", "OPEN_EXR_MULTILAYER")
        o.set(settings, "color_depth", "32")
        path = tmp_dir / f"cycles-{time.perf_counter_ns()}.exr"
        image.save_render(str(path), scene=scene)
    finally:
        o.restore()
    channels = exr.read_exr(path)
    path.unlink()
    prefix = f"{layer.name}.Combined."
    try:
        rgb = np.stack([channels[prefix + c] for c in "RGB"], axis=-1).astype(np.float64)
    except KeyError:
        raise CrosscheckError(f"Cycles' render has no {prefix}R/G/B (channels: {', '.join(sorted(channels))})") from None
    # The material index pass is "Material Index" since Blender 5.0, "IndexMA" before.
    index = (channels.get(f"{layer.name}.Material Index.X", channels.get(f"{layer.name}.IndexMA.X"))
             if with_material_index else None)
    return rgb, (None if index is None else np.rint(index).astype(np.int64))


# ------------------------------------------------------------------------------------------ the check
class _Session:
    """One cross-check: the scene with its settings overridden, rendering both engines on demand."""

    def __init__(self, scene, options: CrosscheckOptions, tmp_dir: Path, log: Callable[[str], None]):
        self.scene, self.options, self.tmp_dir, self.log = scene, options, tmp_dir, log
        self.notes: list[str] = []
        self.o = _Overrides()
        monte = scene.monte
        self.spp = int(options.spp or monte.samples)
        total = int(options.cycles_spp or self.spp)
        self.runs = int(options.cycles_runs)
        self.cycles_spp_per_run = max(1, math.ceil(total / self.runs))
        self.bounces = int(options.max_bounces if options.max_bounces is not None else monte.max_bounces)
        self.threads = int(options.threads) or (os.cpu_count() or 1)
        self.filter_type = monte.filter_type
        self.filter_width = float(monte.filter_width)
        if self.filter_type not in CYCLES_FILTERS:
            self.notes.append(f"Cycles has no {self.filter_type} filter: both render with Blackman-Harris "
                              f"{self.filter_width:g} px")
            self.filter_type = "blackman-harris"

    def apply_common(self) -> None:
        scene, o = self.scene, self.o
        r = scene.render
        if self.options.resolution is not None:
            o.set(r, "resolution_x", int(self.options.resolution[0]))
            o.set(r, "resolution_y", int(self.options.resolution[1]))
            o.set(r, "resolution_percentage", 100)
        o.set(r, "use_border", False)
        layer = _render_layer(scene)
        for vl in scene.view_layers:  # one view layer is compared; the others need not render
            if vl != layer:
                o.set(vl, "use", False)
        m = scene.monte
        o.set(m, "samples", self.spp)
        o.set(m, "max_bounces", self.bounces)
        o.set(m, "threads", self.threads)
        o.set(m, "filter_type", self.filter_type)
        o.set(m, "filter_width", self.filter_width)
        o.set(m, "time_limit", 0.0)
        o.set(m, "clamp", 0.0)
        o.set(scene.render, "engine", scene.render.engine)  # restored at the end whatever ran last

    def monte(self) -> tuple[np.ndarray, np.ndarray, float]:
        t0 = time.perf_counter()
        rgb, var = render_monte(self.scene)
        return rgb, var, time.perf_counter() - t0

    def cycles(self, material_index: bool = False):
        """K Cycles renders: (mean, per-pixel variance of the mean, material index, seconds)."""
        o = _Overrides()
        layer = _render_layer(self.scene)
        t0 = time.perf_counter()
        try:
            if material_index:
                o.set(layer, "use_pass_material_index", True)
            runs, index = [], None
            for k in range(self.runs):
                configure_cycles(self.scene, self.cycles_spp_per_run, self.bounces, self.threads, seed=k + 1,
                                 filter_type=self.filter_type, filter_width=self.filter_width, overrides=o)
                rgb, idx = render_cycles(self.scene, self.tmp_dir, material_index and k == 0)
                runs.append(rgb)
                index = idx if idx is not None else index
        finally:
            o.restore()
        mean, var = cmp.runs_mean_and_variance(np.stack(runs))
        return mean, var, index, time.perf_counter() - t0


def crosscheck_scene(scene, out_dir: str | os.PathLike, options: CrosscheckOptions | None = None,
                     log: Callable[[str], None] | None = None) -> dict:
    """Render `scene` with Monte and Cycles, write the images and reports into out_dir (created if missing;
    its parent must exist) and return the report (what report.json holds)."""
    say = log or (lambda msg: print(msg, flush=True))
    options = (options or CrosscheckOptions()).validate()
    out = Path(out_dir).expanduser().resolve()
    if out.exists() and not out.is_dir():
        raise CrosscheckError(f"cannot write the cross-check into {out}: it is a file")
    if not out.parent.is_dir():
        raise CrosscheckError(f"cannot write the cross-check into {out}: folder {out.parent} does not exist")
    out.mkdir(exist_ok=True)
    if scene.camera is None:
        raise CrosscheckError(f"scene {scene.name!r} has no camera")
    from . import register

    register()
    with tempfile.TemporaryDirectory(prefix="monte-crosscheck-") as tmp:
        session = _Session(scene, options, Path(tmp), say)
        material_names: dict[int, str] = {0: "(background / world)"}
        try:
            session.apply_common()
            # Temporary material pass indices so Cycles' Material Index pass names each material.
            materials = [m for m in bpy.data.materials]
            for i, mat in enumerate(materials, start=1):
                session.o.set(mat, "pass_index", i)
                material_names[i] = mat.name
            say(f"Cross-check: Monte, {session.spp} spp ...")
            monte_rgb, monte_var, monte_s = session.monte()
            say(f"Cross-check: Cycles, {session.runs} x {session.cycles_spp_per_run} spp ...")
            cyc_rgb, cyc_var, index, cyc_s = session.cycles(material_index=True)
            result = cmp.compare(monte_rgb, monte_var, cyc_rgb, cyc_var, rel_floor=options.rel_floor)
            agree, reasons = result.verdict()
            attribution: dict[str, Any] = {}
            if options.attribute and not agree:
                if index is not None:
                    attribution["materials"] = cmp.region_attribution(result, index, material_names,
                                                                      monte_rgb, cyc_rgb)
                say("Cross-check: they disagree; rendering each light source alone ...")
                attribution["lights"] = _light_attribution(session)
        finally:
            session.o.restore()
        report = _report(scene, session, result, agree, reasons, attribution, monte_s, cyc_s)
    _write_outputs(out, report, result, monte_rgb, monte_var, cyc_rgb, cyc_var)
    say(report_text(report))
    return report


def _light_sources(scene) -> list[tuple[str, Any]]:
    """(name, light object or None for the world/emitting surfaces) for the sources to isolate."""
    lights = [ob for ob in scene.objects if ob.type == "LIGHT" and not ob.hide_render]
    lights.sort(key=lambda ob: -float(ob.data.energy))
    return [(f"light {ob.name!r}", ob) for ob in lights]


def _light_attribution(session: _Session) -> list[dict]:
    """Render each light alone, then the world alone, then emitting surfaces alone, with both engines; for
    each: channel means, relative difference and the difference in sigmas. Sorted by |sigmas|, largest first."""
    scene = session.scene
    lights = _light_sources(scene)
    skipped = lights[MAX_ATTRIBUTED_LIGHTS:]
    lights = lights[:MAX_ATTRIBUTED_LIGHTS]
    cases: list[tuple[str, Any]] = [*lights, ("world", "world"), ("emitting surfaces", "surfaces")]
    rows = []
    for name, source in cases:
        o = _Overrides()
        try:
            for other_name, ob in lights + skipped:
                if ob is not source:
                    o.set(ob, "hide_render", True)
            if source != "world":
                o.set(scene, "world", None)
            elif scene.world is None:
                continue
            monte_rgb, monte_var, _ = session.monte()
            cyc_rgb, cyc_var, _, _ = session.cycles()
        finally:
            o.restore()
        if max(monte_rgb.max(), cyc_rgb.max()) <= 0.0:
            continue  # nothing emits in this case (no emitting surfaces, a black world)
        c = cmp.compare(monte_rgb, monte_var, cyc_rgb, cyc_var, rel_floor=session.options.rel_floor)
        sig = c.difference / np.maximum(c.sigma, 1e-30)
        rows.append({"source": name, "monte_mean": c.mean_a.tolist(), "cycles_mean": c.mean_b.tolist(),
                     "relative_difference": c.relative_difference.tolist(), "sigmas": sig.tolist(),
                     "agree": bool(c.means_agree.all())})
    rows.sort(key=lambda r: -max(abs(s) for s in r["sigmas"]))
    if skipped:
        rows.append({"source": f"{len(skipped)} weaker lights not isolated", "skipped": [n for n, _ in skipped]})
    return rows


# ------------------------------------------------------------------------------------------ outputs
def _report(scene, session: _Session, c: cmp.Comparison, agree: bool, reasons: list[str],
            attribution: dict, monte_s: float, cyc_s: float) -> dict:
    h, w = c.z.shape[:2]
    sig = c.difference / np.maximum(c.sigma, 1e-30)

    def per_channel(values) -> dict:
        return {ch: float(v) for ch, v in zip(cmp.CHANNELS, values)}

    return {
        "scene": scene.name,
        "blend_file": bpy.data.filepath or None,
        "resolution": [w, h],
        "settings": {"monte_spp": session.spp, "cycles_spp": session.cycles_spp_per_run * session.runs,
                     "cycles_runs": session.runs, "cycles_spp_per_run": session.cycles_spp_per_run,
                     "max_bounces": session.bounces, "threads": session.threads,
                     "filter_type": session.filter_type, "filter_width": session.filter_width},
        "seconds": {"monte": monte_s, "cycles": cyc_s},
        "means": {
            "monte": {ch: {"mean": float(m), "sigma": float(s), "ci95": [float(m - 1.96 * s), float(m + 1.96 * s)]}
                      for ch, m, s in zip(cmp.CHANNELS, c.mean_a, c.sigma_a)},
            "cycles": {ch: {"mean": float(m), "sigma": float(s), "ci95": [float(m - 1.96 * s), float(m + 1.96 * s)]}
                       for ch, m, s in zip(cmp.CHANNELS, c.mean_b, c.sigma_b)},
        },
        "relative_difference": per_channel(c.relative_difference),
        "difference_sigmas": per_channel(sig),
        "tolerance": {"absolute": per_channel(c.tolerance), "sigmas": c.sigmas, "rel_floor": c.rel_floor},
        "rmse": c.rmse,
        "rmse_expected_from_noise": c.rmse_noise,
        "zscores": c.z_stats() | {"gaussian_frac_gt3": 0.0027, "limit_frac_gt5": cmp.Z5_FRACTION},
        "verdict": {"agree": bool(agree), "reasons": reasons},
        "attribution": attribution,
        "notes": session.notes,
    }


def report_text(report: dict) -> str:
    """The short human-readable report (report.txt)."""
    s, z = report["settings"], report["zscores"]
    lines = [
        f"Monte vs Cycles: scene {report['scene']!r}, {report['resolution'][0]}x{report['resolution'][1]}, "
        f"Monte {s['monte_spp']} spp ({report['seconds']['monte']:.1f} s), Cycles {s['cycles_runs']} x "
        f"{s['cycles_spp_per_run']} spp ({report['seconds']['cycles']:.1f} s), {s['max_bounces']} bounces, "
        f"{s['filter_type']} {s['filter_width']:g} px",
        "channel   Monte (95% CI)                 Cycles (95% CI)                diff      sigmas",
    ]
    for ch in cmp.CHANNELS:
        m, cy = report["means"]["monte"][ch], report["means"]["cycles"][ch]
        lines.append(f"  {ch}     {m['mean']:.5f} +- {1.96 * m['sigma']:.5f}          "
                     f"{cy['mean']:.5f} +- {1.96 * cy['sigma']:.5f}          "
                     f"{100 * report['relative_difference'][ch]:+6.2f} %  {report['difference_sigmas'][ch]:+6.1f}")
    lines.append(f"RMSE {report['rmse']:.4g} (noise alone would give {report['rmse_expected_from_noise']:.4g})")
    lines.append(f"per-pixel z: mean {z['mean']:+.2f}, std {z['std']:.2f}, |z|>3 {100 * z['frac_gt3']:.2f} % "
                 f"(Gaussian 0.27 %), |z|>5 {100 * z['frac_gt5']:.2f} % (allowed {100 * z['limit_frac_gt5']:.0f} %)")
    v = report["verdict"]
    lines.append("VERDICT: " + ("they agree within noise" if v["agree"] else "they DISAGREE"))
    lines += [f"  - {r}" for r in v["reasons"]]
    att = report.get("attribution") or {}
    if att.get("materials"):
        lines.append("where (by material, most disagreement first):")
        for row in att["materials"][:5]:
            lines.append(f"  {row['name']}: {row['pixels']} px, mean z {row['mean_z']:+.1f}, |z|>3 "
                         f"{100 * row['frac_gt3']:.0f} %, share of luma difference "
                         f"{100 * row['luma_difference_share']:+.0f} %")
    if att.get("lights"):
        lines.append("which light (each rendered alone):")
        for row in att["lights"]:
            if "sigmas" in row:
                rel = ", ".join(f"{100 * x:+.2f}" for x in row["relative_difference"])
                lines.append(f"  {row['source']}: relative difference R,G,B {rel} %, "
                             f"{max(row['sigmas'], key=abs):+.1f} sigma{'' if not row['agree'] else ' (agrees)'}")
            else:
                lines.append(f"  {row['source']}")
    lines += [f"note: {n}" for n in report.get("notes", [])]
    return "\n".join(lines)


def _write_outputs(out: Path, report: dict, c: cmp.Comparison, monte_rgb, monte_var, cyc_rgb, cyc_var) -> None:
    f32 = np.float32
    exr.write_exr(out / "monte.exr", exr.image_channels(monte_rgb.astype(f32), monte_var.astype(f32)))
    exr.write_exr(out / "cycles.exr", exr.image_channels(cyc_rgb.astype(f32), cyc_var.astype(f32)))
    exr.write_png(out / "difference.png", cmp.srgb_to_linear(cmp.upscale(cmp.zscore_colors(c.z))))
    exr.write_png(out / "monte.png", cmp.upscale(monte_rgb))
    exr.write_png(out / "cycles.png", cmp.upscale(cyc_rgb))
    write_text_atomically(out / "report.json", json.dumps(report, indent=2), ".json")
    write_text_atomically(out / "report.txt", report_text(report) + "\n", ".txt")


# ------------------------------------------------------------------------------------------ .blend files
def crosscheck_blend_file(blend_path: str | os.PathLike, out_dir: str | os.PathLike,
                          options: CrosscheckOptions | None = None,
                          log: Callable[[str], None] | None = None) -> dict:
    """Open a .blend (never saved back) and cross-check its active scene; see crosscheck_scene.
    Raises FileNotFoundError / HeadlessError for a missing or unreadable file."""
    from .headless import _check_blend, open_blend

    options = (options or CrosscheckOptions()).validate()
    blend = Path(blend_path).expanduser().resolve()
    _check_blend(blend)
    open_blend(blend)
    return crosscheck_scene(bpy.context.scene, out_dir, options, log)
