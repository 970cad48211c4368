"""`monte bench --vs mitsuba`: Monte against Mitsuba 3 and Cycles, run time against error, on the Cornell box.

The scene is built in bpy (lab/bpy_scenes.py) and exported to a core Scene once through the add-on's export;
Monte renders that Scene, Mitsuba 3 renders the same triangles through its Python API (lab/mitsuba_scene.py:
the emitter made two-sided by a flipped duplicate, as Blender's emission shader is), and Cycles renders the bpy
scene, interleaved at each rung of a sample-count ladder (Monte 64, Mitsuba 64, Cycles 64, Monte 256, ...),
in this one process, with the same resolution, bounce limit, thread count and pixel filter: a box of width
1 px, the one filter all three share exactly (Mitsuba has no Blackman-Harris; its Gaussian is truncated at
2 sigma, Cycles' at 6). Times as lab/bench_cycles.py takes them: Monte's render call (Embree build + render),
Cycles' render operator (sync + render), Mitsuba's mi.render call (its scene, a few ms of PLY parsing and BVH
build, is loaded once per rung outside the timer, which favours Mitsuba slightly). Errors are RMSE against a
converged Cycles reference rendered with the same box filter (cached in --reference-dir), its own noise
removed in quadrature; efficiency is 1/(seconds x MSE); the ratios at equal error come from
bench_math.equal_error_ratio.

Mitsuba's variant: llvm_ad_rgb by default, the fastest CPU variant (Dr.Jit compiles the whole path tracer into
one vectorised megakernel per render; the compiled kernel is cached, and the untimed warm-up render compiles
it); scalar_rgb (one ray at a time, no compiler) with --mitsuba-variant scalar_rgb. Its sampler: independent
(Mitsuba's default) unless --mitsuba-sampler names another.

Writes OUTDIR/bench_vs_mitsuba.json and bench_vs_mitsuba.png and returns the report.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Callable, Sequence

import bpy
import numpy as np

from ..addon.export import export_scene
from ..core.render import render as monte_render
from . import bpy_scenes
from .bench_cycles import _point, ensure_reference, monte_settings, reference_params, render_cycles, _resolution_of
from .bench_math import equal_error_ratio, format_table, plot_rmse_vs_seconds, write_json
from .bench_reference import ReferenceCache
from .mitsuba_scene import mitsuba_scene_dict

MITSUBA_VARIANTS = ("llvm_ad_rgb", "scalar_rgb")
MITSUBA_SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
FILTER = ("box", 1.0)  # type and width (Cycles' meaning) shared by the three renderers
DEFAULT_LADDER = (64, 256)
RENDERERS = ("monte", "mitsuba", "cycles")


class MitsubaUnavailable(RuntimeError):
    """mitsuba is not installed, or lacks the variant asked for (the message says how to get it)."""


LLVM_SEARCH = ("/usr/lib/x86_64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib")
MIN_LLVM = 16  # Dr.Jit 1.5's kernels abort the process in LLVM 15's instruction selection (fminimum)


def find_libllvm() -> str | None:
    """The newest shared libLLVM of version >= MIN_LLVM in the usual library folders, or None."""
    import glob
    import re

    best: tuple[int, str] | None = None
    for folder in LLVM_SEARCH:
        for path in glob.glob(os.path.join(folder, "libLLVM*.so*")):
            m = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
            if m and int(m.group(1)) >= MIN_LLVM and (best is None or int(m.group(1)) > best[0]):
                best = (int(m.group(1)), path)
    return None if best is None else best[1]


def import_mitsuba(variant: str):
    """(mitsuba, drjit) with the variant set; MitsubaUnavailable when missing. An llvm variant runs on the newest
    libLLVM >= 16 found (DRJIT_LIBLLVM_PATH, when set, wins): Dr.Jit would load an older one and abort."""
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        lib = find_libllvm()
        if lib is None:
            raise MitsubaUnavailable(f"Mitsuba's {variant} needs a shared libLLVM >= {MIN_LLVM} (Debian/Ubuntu: "
                                     "apt install libllvm19, or point DRJIT_LIBLLVM_PATH at one); "
                                     "--mitsuba-variant scalar_rgb needs none")
        os.environ["DRJIT_LIBLLVM_PATH"] = lib
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:
        raise MitsubaUnavailable(f"Mitsuba 3 is not installed ({exc}); install the optional development "
                                 "dependency: pip install -r requirements/rivals.txt") from None
    if variant not in mi.variants():
        raise MitsubaUnavailable(f"this Mitsuba build has no variant {variant!r} (it has {', '.join(mi.variants())})")
    try:
        mi.set_variant(variant)
    except Exception as exc:  # llvm variants need a shared libLLVM at run time
        raise MitsubaUnavailable(f"Mitsuba's {variant} variant cannot start here: {exc}") from None
    return mi, dr


class MitsubaRenderer:
    """Renders a core Scene with Mitsuba 3: PLY files in a temporary folder, one loaded scene per spp."""

    def __init__(self, core_scene, *, variant: str = "llvm_ad_rgb", threads: int = 2, max_bounces: int = 16,
                 sampler: str = "independent", filter_type: str = "box"):
        self.mi, self.dr = import_mitsuba(variant)
        self.variant, self.sampler, self.filter_type = variant, sampler, filter_type
        self.core_scene, self.max_bounces = core_scene, int(max_bounces)
        self.dr.set_thread_count(int(threads) or (os.cpu_count() or 1))
        self._folder = tempfile.TemporaryDirectory(prefix="monte-mitsuba-")
        self._scenes: dict[int, object] = {}

    def scene(self, spp: int):
        if spp not in self._scenes:
            desc = mitsuba_scene_dict(self.core_scene, self._folder.name, spp=spp, max_bounces=self.max_bounces,
                                      filter_type=self.filter_type, sampler=self.sampler)
            self._scenes[spp] = self.mi.load_dict(desc)
        return self._scenes[spp]

    def render(self, spp: int, seed: int) -> tuple[np.ndarray, float]:
        """(linear RGB (H, W, 3) float32, row 0 at the top; seconds of the mi.render call)."""
        scene = self.scene(int(spp))
        t0 = time.perf_counter()
        image = self.mi.render(scene, spp=int(spp), seed=int(seed))
        image = np.array(image, dtype=np.float32)  # evaluates the llvm variant's kernel (inside the timer)
        seconds = time.perf_counter() - t0
        return image[..., :3], seconds

    def close(self) -> None:
        self._scenes.clear()
        self._folder.cleanup()


def bench_cornell(*, cache: ReferenceCache, ladder: Sequence[int] = DEFAULT_LADDER, threads: int = 2,
                  max_bounces: int = 16, resolution: tuple[int, int] = (256, 256), reference_spp: int = 1024,
                  reference_seeds: int = 4, seed: int = 1, variant: str = "llvm_ad_rgb",
                  sampler: str = "independent", log: Callable[[str], None] = print) -> dict:
    """Monte, Mitsuba and Cycles on the Cornell box at each rung, interleaved; returns the report."""
    scene = bpy_scenes.build("cornell", tuple(resolution))
    filter_type, filter_width = FILTER
    res = _resolution_of(scene)
    log(f"cornell {res[0]}x{res[1]}, {threads} threads, max bounces {max_bounces}, box filter 1 px; "
        f"Mitsuba {variant}, {sampler} sampler")
    params = reference_params("cornell", f"bpy_scenes:{bpy_scenes.scene_version('cornell')}", res, max_bounces,
                              reference_spp, reference_seeds, filter_type=filter_type, filter_width=filter_width)
    ref = ensure_reference(scene, params, cache, threads, log, filter_type=filter_type, filter_width=filter_width)

    scene.render.engine = "MONTE"
    core_scene, stats = export_scene(bpy.context.evaluated_depsgraph_get())
    log(f"  monte export: {stats.line()}")
    mitsuba = MitsubaRenderer(core_scene, variant=variant, threads=threads, max_bounces=max_bounces,
                              sampler=sampler, filter_type=filter_type)

    def m_settings(spp: int):
        return monte_settings(spp, seed, threads, max_bounces, filter_type=filter_type, filter_width=filter_width)

    try:
        # Warm-up, untimed: kernels, tables and caches of all three (Mitsuba's llvm kernel compiles here).
        monte_render(core_scene, m_settings(1))
        for spp in ladder:
            mitsuba.render(int(spp), seed)
        render_cycles(scene, 1, seed, threads, max_bounces, filter_type=filter_type, filter_width=filter_width)
        points = []
        n_pix = res[0] * res[1]
        for spp in ladder:
            spp = int(spp)
            t0 = time.perf_counter()
            result = monte_render(core_scene, m_settings(spp))
            m_sec = time.perf_counter() - t0
            points.append(_point("monte", spp, result.color[..., :3], m_sec, ref, int(result.sample_count.sum())))
            mi_img, mi_sec = mitsuba.render(spp, seed)
            points.append(_point("mitsuba", spp, mi_img, mi_sec, ref, spp * n_pix))
            c_img, c_sec = render_cycles(scene, spp, seed, threads, max_bounces, filter_type=filter_type,
                                         filter_width=filter_width)
            points.append(_point("cycles", spp, c_img, c_sec, ref, spp * n_pix))
            m, s, c = points[-3:]
            log(f"  {spp:>6} spp: " + " | ".join(
                f"{p['renderer']} {p['seconds']:6.2f} s RMSE {p['rmse_corrected']:.4f} eff {p['efficiency']:6.1f}"
                for p in (m, s, c)) + f" | monte/mitsuba {m['efficiency'] / s['efficiency']:.2f}, "
                f"monte/cycles {m['efficiency'] / c['efficiency']:.2f}")
    finally:
        mitsuba.close()
    series = {r: [p for p in points if p["renderer"] == r] for r in RENDERERS}

    def ratio(other: str) -> dict:
        return equal_error_ratio(([p["seconds"] for p in series["monte"]],
                                  [p["rmse_corrected"] for p in series["monte"]]),
                                 ([p["seconds"] for p in series[other]],
                                  [p["rmse_corrected"] for p in series[other]]))

    return {"scene": "cornell", "resolution": list(res), "threads": threads, "max_bounces": max_bounces,
            "filter": {"type": filter_type, "width": filter_width},
            "mitsuba": {"version": mitsuba.mi.__version__, "variant": variant, "sampler": sampler},
            "reference": {"path": str(ref.path) if ref.path else None, "source": ref.source,
                          "own_rmse": float(np.sqrt(ref.own_mse)), "params": ref.params},
            "points": points,
            "per_rung_efficiency_ratio": {
                other: {str(m["rung"]): m["efficiency"] / o["efficiency"]
                        for m, o in zip(series["monte"], series[other])} for other in ("mitsuba", "cycles")},
            "equal_error": {"mitsuba": ratio("mitsuba"), "cycles": ratio("cycles")},
            "monte_over_mitsuba_efficiency": ratio("mitsuba")["ratio"],
            "monte_over_cycles_efficiency": ratio("cycles")["ratio"]}


def run_vs_mitsuba(reference_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
                   log: Callable[[str], None] = print, **options) -> dict:
    """Bench the Cornell box against Mitsuba 3 and Cycles; write OUTDIR/bench_vs_mitsuba.json and .png."""
    out = Path(out_dir).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    s = bench_cornell(cache=ReferenceCache(reference_dir), log=log, **options)
    report = {"kind": "monte-vs-mitsuba", "blender": bpy.app.version_string, "cpu_count": os.cpu_count(),
              "time": time.strftime("%Y-%m-%d %H:%M:%S"), "scenes": [s]}
    write_json(out / "bench_vs_mitsuba.json", report)
    panel = {"title": f"cornell {s['resolution'][0]}x{s['resolution'][1]}, {s['threads']} threads, box 1 px "
                      f"(Monte/Mitsuba {s['monte_over_mitsuba_efficiency']:.2g}, "
                      f"Monte/Cycles {s['monte_over_cycles_efficiency']:.2g})",
             "series": [{"label": r if r != "mitsuba" else f"mitsuba {s['mitsuba']['variant']}",
                         "seconds": [p["seconds"] for p in s["points"] if p["renderer"] == r],
                         "rmse": [p["rmse_corrected"] for p in s["points"] if p["renderer"] == r],
                         "spp": [p["rung"] for p in s["points"] if p["renderer"] == r]} for r in RENDERERS]}
    plot_rmse_vs_seconds([panel], out / "bench_vs_mitsuba.png")
    rows = [[p["rung"], p["renderer"], p["seconds"], p["samples_per_second"] / 1e3, p["rmse_corrected"],
             p["efficiency"]] for p in s["points"]]
    log("")
    log(format_table(["spp", "renderer", "s", "k samples/s", "RMSE", "eff"], rows))
    for other in ("mitsuba", "cycles"):
        r = s["equal_error"][other]
        log(f"Monte/{other} efficiency at equal error = {r['ratio']:.3g}"
            f"{' (extrapolated)' if r['extrapolated'] else ''}")
    log(f"wrote {out / 'bench_vs_mitsuba.json'}, {out / 'bench_vs_mitsuba.png'}")
    return report


def run_from_args(args, overrides: dict) -> dict:
    """`monte bench --vs mitsuba ...` (cli.py): check the arguments, then run_vs_mitsuba."""
    if args.blend or (args.scene not in (None, "cornell")):
        raise ValueError("--vs mitsuba benches the Cornell box only (the scene the Mitsuba translation covers)")
    if not args.reference_dir:
        raise ValueError("--vs mitsuba needs --reference-dir DIR (the box-filtered Cycles reference is cached there)")
    if not args.output_dir:
        raise ValueError("--vs mitsuba needs -o OUTDIR (bench_vs_mitsuba.json and the plot go there)")
    if args.time_ladder or args.whole_process or getattr(args, "denoise", False):
        raise ValueError("--vs mitsuba takes a sample-count --ladder only (no --time-ladder, --whole-process "
                         "or --denoise)")
    if args.reference_seeds < 2 or args.reference_spp < 1:
        raise ValueError("the reference needs --reference-seeds >= 2 (to estimate its own noise) and "
                         "--reference-spp >= 1")
    unsupported = sorted(set(overrides) - {"threads", "max_bounces", "seed"})
    if unsupported:
        raise ValueError(f"--vs mitsuba fixes these settings for a fair comparison: {', '.join(unsupported)}")
    return run_vs_mitsuba(args.reference_dir, args.output_dir, ladder=args.ladder or DEFAULT_LADDER,
                          threads=overrides.get("threads") or 2, max_bounces=overrides.get("max_bounces", 16),
                          resolution=tuple(args.resolution) if args.resolution else (256, 256),
                          reference_spp=args.reference_spp, reference_seeds=args.reference_seeds,
                          seed=overrides.get("seed", 1), variant=args.mitsuba_variant,
                          sampler=args.mitsuba_sampler)
