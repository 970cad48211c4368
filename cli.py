"""The `monte` command: render built-in scenes through the core, .blend files through the add-on (bpy).

Examples:
  monte render cornell -o cornell.exr --spp 64
  monte render --list
  monte render scene.blend -o out.exr --spp 128      (needs the bpy module)
  monte bench
  monte mc-study -o study/
  monte crosscheck scene.blend -o check/ --spp 256   (needs the bpy module)
  monte render cornell -o out.exr --spp 1024 --dask tcp://host:8786    (a Dask cluster: see `monte worker`)
  monte worker tcp://host:8786
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Callable
from pathlib import Path

from .core.settings import CLI_SETTINGS, FILTERS, SAMPLERS, RenderSettings

# What to install for the commands that use Blender (any version of the README's support table works).
BPY_HINT = "pip install bpy==5.3.0 on Python 3.13, or bpy 4.2 / 4.5 / 5.0 on Python 3.11"


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 256x256, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"resolution must be at least 1x1, got {text!r}")
    return w, h


def _add_render_options(p: argparse.ArgumentParser) -> None:
    """Options shared by render and bench; defaults None mean 'the scene's or RenderSettings' default'."""
    p.add_argument("--spp", type=int, help="samples per pixel (default 64)")
    p.add_argument("--seed", type=int, help="random seed; the same seed gives the same image bit for bit")
    p.add_argument("--sampler", choices=SAMPLERS, help="sample generator (default sobol)")
    p.add_argument("--filter", dest="filter_type", choices=FILTERS, help="pixel filter (default blackman-harris)")
    p.add_argument("--filter-width", type=float, help="pixel filter width in pixels, Cycles' meaning (default 1.5)")
    p.add_argument("--max-bounces", type=int, help="maximum bounces, Cycles' counting (default 16)")
    p.add_argument("--rr-depth", type=int, help="bounces before Russian roulette starts (default 2, as Cycles)")
    p.add_argument("--clamp", type=float, help="clamp sample values above this (0 = off, unbiased; default 0)")
    p.add_argument("--threads", type=int, help="ray-casting threads (0 = all cores)")
    p.add_argument("--batch", dest="batch_paths", type=int, help="paths traced at once; bounds memory")
    p.add_argument("--tile", dest="tile_size", type=int, help="tile edge in pixels (default 64)")
    p.add_argument("--time-limit", type=float, help="stop after this many seconds (0 = no limit)")
    p.add_argument("--adaptive-threshold", type=float,
                   help="adaptive sampling noise threshold, Cycles' scale (0 = off, default; try 0.01)")
    p.add_argument("--adaptive-min-samples", type=int,
                   help="samples before adaptive sampling may stop a pixel (0 = automatic)")
    p.add_argument("--resolution", type=_resolution, help="image size WxH (built-in scenes)")
    p.add_argument("--denoise", action="store_true",
                   help="denoise with Intel Open Image Denoise (needs pyoidn) on Cycles' Denoising Albedo and "
                        "Normal passes; the EXR keeps the image before denoising as the noisy.* layer")
    p.add_argument("--denoise-quality", choices=("high", "balanced", "fast"), default="high",
                   help="Open Image Denoise's quality (default high, as Cycles)")
    p.add_argument("--light-passes", action="store_true",
                   help="built-in scenes: also write Cycles' light passes (diffuse_direct.*, ..., emission.*, "
                        "environment.*); a .blend writes the passes its view layer ticks")


def _settings_from(args: argparse.Namespace) -> dict:
    out = {k: getattr(args, k) for k in CLI_SETTINGS if getattr(args, k, None) is not None}
    if getattr(args, "denoise", False):
        out["denoising_features"] = True
    if getattr(args, "light_passes", False):
        from .core.light_passes import LIGHT_PASSES

        out["light_passes"] = LIGHT_PASSES
    return out


class DenoiseFailed(Exception):
    """The render was saved undenoised (the message says why and where)."""


def _denoise_result(result, quality: str, log) -> None:
    """Denoise result.color in place (Open Image Denoise on its denoising passes), keeping the noisy image as
    result.noisy; raises DenoiseFailed when the denoiser is unavailable (result left noisy, noisy None)."""
    from .core.denoise import DenoiserUnavailable, denoise

    try:
        t0 = time.perf_counter()
        denoised = denoise(result.color, result.denoising_albedo, result.denoising_normal, quality=quality)
    except DenoiserUnavailable as exc:
        raise DenoiseFailed(str(exc)) from None
    seconds = time.perf_counter() - t0
    h, w = result.color.shape[:2]
    log(f"denoised ({quality}) in {seconds:.2f} s ({seconds / (w * h / 1e6):.2f} s per megapixel)")
    result.noisy = result.color
    result.color = denoised
    result.stats["denoise_seconds"] = seconds


class ProgressBar:
    """A one-line progress bar on stderr (no dependency); silent when stderr is not a terminal unless forced."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.last = 0.0

    def __call__(self, p) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.last < 0.2 and p.fraction < 1:
            return
        self.last = now
        bar = "#" * int(30 * p.fraction)
        sys.stderr.write(f"\r[{bar:<30}] {100 * p.fraction:5.1f}%  {p.stats_line()}   ")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def cmd_render(args: argparse.Namespace) -> int:
    if args.list:
        from .core.builtin_scenes import BUILTIN_SCENES

        for name, (_, description) in BUILTIN_SCENES.items():
            print(f"{name:18s} {description}")
        return 0
    if not args.scene:
        print("monte render: name a built-in scene (see --list) or a .blend file", file=sys.stderr)
        return 2
    overrides = _settings_from(args)
    output = Path(args.output)
    # --variance: the per-pixel error estimate (core.settings.RenderSettings.error_estimate) and its variance.*
    # channels; without it one Sobol sequence per pixel (~15 % less variance), unless adaptive sampling needs it
    variance = bool(args.variance) or float(overrides.get("adaptive_threshold") or 0.0) > 0
    is_blend = args.scene.endswith(".blend") or Path(args.scene).suffix == ".blend"
    if (args.frames is not None or args.resume) and not (args.dask and is_blend):
        print("monte render: --frames and --resume render a .blend's frames on a cluster (with --dask); "
              "built-in scenes are still images", file=sys.stderr)
        return 2
    if args.file_passes and not is_blend:
        print("monte render: --file-passes is for a .blend (a built-in scene writes the passes asked with "
              "--passes)", file=sys.stderr)
        return 2
    if is_blend and overrides.pop("light_passes", None):
        print("monte render: --light-passes is for built-in scenes; a .blend writes the light passes its view "
              "layer ticks (View Layer Properties > Passes > Light)", file=sys.stderr)
        return 2
    if is_blend:
        if args.passes:
            print("monte render: --passes is for built-in scenes; a .blend renders the passes its view layers "
                  "select (View Layer Properties > Passes)", file=sys.stderr)
            return 2
        if args.dask:
            return _render_blend_on_cluster(args, overrides, output)
        try:
            from .addon.headless import render_blend_file
        except ImportError as exc:
            print(f"monte render: rendering a .blend needs the bpy module ({BPY_HINT}): {exc}",
                  file=sys.stderr)
            return 2
        from .addon.headless import HeadlessError

        _blend_overrides(args, overrides)
        try:
            render_blend_file(args.scene, output, overrides)  # reports what it wrote
        except HeadlessError as exc:
            print(f"monte render: error: {exc}", file=sys.stderr)
            return 1
        if args.denoise:
            from .core.denoise import denoiser_status

            reason = denoiser_status()
            if reason is not None:
                print(f"monte render: error: {reason}. The image was saved without denoising to {output}",
                      file=sys.stderr)
                return 1
        return 0

    from .core import exr
    from .core.render import render
    from .core.builtin_scenes import builtin_scene

    scene = builtin_scene(args.scene, args.resolution)
    if args.passes:
        overrides["data_passes"] = args.passes
    settings = RenderSettings(**overrides, error_estimate=variance).validate()
    if output.suffix.lower() != ".exr":
        print(f"monte render: output must be an .exr file, got {output}", file=sys.stderr)
        return 2
    exr.check_writable(output)  # fail now, not after the render
    if not args.no_png:
        exr.check_writable(output.with_suffix(".png"))
    bar = ProgressBar(not args.quiet)
    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    if args.dask:
        from .core.distributed import ClusterError, connect, render_on_cluster

        try:
            with connect(args.dask, args.dask_timeout, log) as client:
                try:
                    result = render_on_cluster(scene, settings, client, on_progress=bar, log=log)
                finally:
                    bar.close()
        except ClusterError as exc:
            print(f"monte render: error: {exc}", file=sys.stderr)
            return 1
        st = result.stats
        log(f"cluster: {st['units']} units on {st['workers']} workers, scene {st['scene_bytes'] / 1e3:.0f} kB "
            f"to each worker, film sums back {st['film_bytes'] / 1e6:.2f} MB "
            f"({st['film_bytes_per_unit'] / 1e3:.0f} kB per unit)")
    else:
        result = render(scene, settings, on_progress=bar, log=log)
        bar.close()
    failed = None
    if args.denoise:
        try:
            _denoise_result(result, args.denoise_quality, log)
        except DenoiseFailed as exc:
            failed = str(exc)
    _write_outputs(result, output, args.no_png)
    if failed is not None:
        print(f"monte render: error: {failed}. The image was saved without denoising to {output}",
              file=sys.stderr)
        return 1
    if result.cancelled:
        print("render stopped early (time limit or cancel): the image holds the samples taken", file=sys.stderr)
    return 0


def _data_passes(text: str) -> tuple[str, ...]:
    """--passes: comma-separated keys of core.data_passes.DATA_PASSES."""
    from .core.data_passes import DATA_PASSES

    names = tuple(name.strip() for name in text.split(",") if name.strip())
    unknown = [name for name in names if name not in DATA_PASSES]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown data pass {unknown[0]!r}; choose from {', '.join(DATA_PASSES)}")
    return names


def _frames(text: str) -> list[int]:
    """--frames: "A-B" (inclusive) or "A,B,C" (frame numbers >= 0)."""
    try:
        if "-" in text and "," not in text:
            first, last = (int(v) for v in text.split("-"))
            frames = list(range(first, last + 1))
        else:
            frames = [int(v) for v in text.split(",")]
        if not frames or min(frames) < 0 or len(set(frames)) != len(frames):
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(f"frames look like 1-250 or 1,5,9, got {text!r}") from None
    return frames


def frame_output(output: Path, frame: int) -> Path:
    """The output file of one frame of an animation: render.exr -> render_0007.exr."""
    return output.with_name(f"{output.stem}_{frame:04d}{output.suffix}")


def _blend_overrides(args: argparse.Namespace, overrides: dict) -> None:
    """The options a .blend's render takes over its own settings (here or on a cluster): --resolution,
    --variance, and the denoising features asked for as the denoiser at --denoise-quality."""
    if args.resolution:
        overrides["resolution"] = args.resolution
    if getattr(args, "variance", False):
        overrides["variance"] = True
    if getattr(args, "file_passes", False):
        overrides["file_passes"] = True
    if overrides.pop("denoising_features", False):
        overrides["denoise"] = True
        overrides["denoise_quality"] = args.denoise_quality


def _render_blend_on_cluster(args: argparse.Namespace, overrides: dict, output: Path) -> int:
    """A .blend's frames exported here (through the add-on) and rendered on a Dask cluster, each frame written
    atomically as it completes (a cancelled or failed animation keeps its finished frames)."""
    try:
        from .addon.headless import HeadlessError, export_blend_frames, write_monte_exr
    except ImportError as exc:
        print(f"monte render: rendering a .blend needs the bpy module ({BPY_HINT}): {exc}", file=sys.stderr)
        return 2
    from .core import exr
    from .core.distributed import ClusterError, connect, render_frames_on_cluster

    if output.suffix.lower() != ".exr":
        print(f"monte render: output must be an .exr file, got {output}", file=sys.stderr)
        return 2
    _blend_overrides(args, overrides)
    frames = args.frames
    outputs = {f: frame_output(output, f) for f in frames} if frames is not None else {None: output}
    if args.resume:
        done = [f for f, path in outputs.items() if path.exists()]
        outputs = {f: path for f, path in outputs.items() if f not in done}
        if done:
            print(f"monte render: --resume: {len(done)} frames already written, {len(outputs)} to render",
                  file=sys.stderr)
        if not outputs:
            return 0
    for path in outputs.values():
        exr.check_writable(path)
    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    todo = None if frames is None else list(outputs)
    bar = ProgressBar(not args.quiet)

    undenoised = []
    exported = {}  # frame -> its BlendFrame (the render region and the frame's size, for the output)

    def frames_to_render():
        for item in export_blend_frames(args.scene, overrides, todo, log=log):
            exported[item.frame] = item
            yield item.frame, item.scene, item.settings, item.region  # a render region: only its tiles go out

    def write_frame(frame, result) -> None:
        bar.close()
        if args.denoise:
            try:
                _denoise_result(result, args.denoise_quality, log)
            except DenoiseFailed as exc:
                undenoised.append(str(exc))
        item = exported.pop(frame)
        # the layout `monte render scene.blend` writes (shader AOVs too; a render region padded to the frame)
        _write_outputs(result, outputs[frame if frames is not None else None], args.no_png,
                       write=lambda out: write_monte_exr(out, result, item.region, item.size, item.cropped))

    try:
        with connect(args.dask, args.dask_timeout, log) as client:
            try:  # two frames in flight: the workers render one while this process exports the next
                render_frames_on_cluster(client, frames_to_render(), write_frame, frames_in_flight=2,
                                         on_progress=bar, log=log)
            finally:
                bar.close()
    except (ClusterError, HeadlessError) as exc:
        print(f"monte render: error: {exc}", file=sys.stderr)
        return 1
    if undenoised:
        print(f"monte render: error: {undenoised[0]}. {len(undenoised)} frames were saved without denoising",
              file=sys.stderr)
        return 1
    return 0


def _write_outputs(result, output: Path, no_png: bool, write: Callable[[Path], None] | None = None) -> list[str]:
    """The EXR (and PNG preview) of a render, each written atomically; reports what it wrote. write(output):
    writes the EXR instead of the core layout below (a .blend's render region, padded to its frame)."""
    from .core import exr

    from .core.data_passes import cryptomatte_metadata

    if write is not None:
        write(output)
    else:
        channels = exr.image_channels(result.color, result.variance, result.albedo, result.normal, result.depth,
                                      noisy=result.noisy, denoising_albedo=result.denoising_albedo,
                                      denoising_normal=result.denoising_normal,
                                      shadow_catcher=result.shadow_catcher,
                                      light_passes=result.light_passes)
        data = getattr(result, "data_passes", {})
        channels.update(exr.data_pass_channels(data, {"Mist": "Z", "Position": "XYZ", "UV": "UVA",
                                                      "Object Index": "X", "Material Index": "X",
                                                      "Vector": "XYZW"}))
        metadata = {k: v for base, names in getattr(result, "cryptomatte", {}).items()
                    for k, v in cryptomatte_metadata(base, names).items()}
        exr.write_exr(output, channels, metadata)
    written = [str(output)]
    if not no_png:
        png = output.with_suffix(".png")
        exr.write_png(png, result.color)
        written.append(str(png))
    st = result.stats
    mean = result.color[..., :3].reshape(-1, 3).mean(axis=0)
    rays = f", {st['rays_per_second'] / 1e6:.2f} M rays/s" if "rays_per_second" in st else ""
    print(f"wrote {', '.join(written)}: {st['samples']} samples in {st['seconds']:.2f} s "
          f"({st['samples_per_second'] / 1e3:.0f} k samples/s{rays}); "
          f"mean RGB {mean[0]:.4f} {mean[1]:.4f} {mean[2]:.4f}")
    return written


def cmd_worker(args: argparse.Namespace) -> int:
    """Load (the first time: compile and cache) the render kernels, then become a Dask worker of the scheduler at
    args.address (`dask worker`, same process id), so that the first render's units do not each wait for a
    compile."""
    from .core.builtin_scenes import builtin_scene
    from .core.render import render

    print("monte worker: loading the render kernels (compiled and cached the first time, about a minute)",
          file=sys.stderr, flush=True)
    render(builtin_scene("cornell", (8, 8)), RenderSettings(spp=1, threads=1))
    command = [sys.executable, "-m", "distributed.cli.dask_worker", args.address,
               "--nthreads", str(args.nthreads), "--nworkers", str(args.nworkers)]
    if args.name:
        command += ["--name", args.name]
    print(f"monte worker: {' '.join(command[3:])}", file=sys.stderr, flush=True)
    sys.stderr.flush()
    sys.stdout.flush()
    os.execv(sys.executable, command)
    return 0  # not reached


def cmd_bench(args: argparse.Namespace) -> int:
    if args.denoise and not args.vs:
        print("monte bench: --denoise compares denoised renders with --vs cycles only", file=sys.stderr)
        return 2
    if args.vs:
        try:
            if args.vs == "mitsuba":
                from .lab.bench_mitsuba import run_from_args
            else:
                from .lab.bench_cycles import run_from_args
        except ImportError as exc:
            print(f"monte bench --vs {args.vs} needs the bpy module ({BPY_HINT}): {exc}", file=sys.stderr)
            return 2
        if args.vs == "mitsuba":
            from .lab.bench_mitsuba import MitsubaUnavailable

            try:
                report = run_from_args(args, _settings_from(args))
            except MitsubaUnavailable as exc:
                print(f"monte bench --vs mitsuba: {exc}", file=sys.stderr)
                return 2
        else:
            report = run_from_args(args, _settings_from(args))
    elif args.samplers or args.batch_sizes or args.seed_table:
        from .lab.bench_ladders import run_ladders

        report = run_ladders(args, _settings_from(args), make_reference=_cycles_reference_maker(args))
    else:
        from .lab.bench import run_bench

        report = run_bench(args)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
    return 0


def cmd_perf(args: argparse.Namespace) -> int:
    from .lab.perf import run_perf

    run_perf(args)
    return 0


def _cycles_reference_maker(args: argparse.Namespace):
    """With --reference-dir and the bpy module: a function rendering a missing Cornell reference with Cycles."""
    if not args.reference_dir:
        return None
    try:
        from .lab.bench_cycles import cornell_reference_maker
    except ImportError:
        return None
    return cornell_reference_maker(args)


def cmd_mc_study(args: argparse.Namespace) -> int:
    from .lab.mc_study import main

    return main(args)


def cmd_crosscheck(args: argparse.Namespace) -> int:
    """Exit status 0 when Monte and Cycles agree within noise, 3 when they do not (see report.txt)."""
    try:
        from .addon.crosscheck import CrosscheckError, CrosscheckOptions, crosscheck_blend_file
        from .addon.headless import HeadlessError
    except ImportError as exc:
        print(f"monte crosscheck: needs the bpy module ({BPY_HINT}): {exc}", file=sys.stderr)
        return 2
    options = CrosscheckOptions(spp=args.spp, cycles_spp=args.cycles_spp, resolution=args.resolution,
                                threads=args.threads or 0, max_bounces=args.max_bounces)
    try:
        report = crosscheck_blend_file(args.blend, args.output, options)
    except (CrosscheckError, HeadlessError) as exc:
        print(f"monte crosscheck: error: {exc}", file=sys.stderr)
        return 1
    return 0 if report["verdict"]["agree"] else 3

def cmd_stress(args: argparse.Namespace) -> int:
    from .lab.stress import StressConfig, run_suite, write_report

    cfg = StressConfig.quick_run() if args.quick else StressConfig.full()
    if args.threads is not None:
        cfg.threads = args.threads
    if args.cycles:
        try:
            from .lab.core_to_bpy import cycles_renderer
        except ImportError as exc:
            print(f"monte stress --cycles needs the bpy module ({BPY_HINT}): {exc}", file=sys.stderr)
            return 2
        cfg.cycles = cycles_renderer(cfg.threads)
    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    results = run_suite(cfg, only=args.only, log=log)
    json_path, md_path = write_report(results, args.output, cfg)
    failed = [c.name for c in results if c.required and not c.passed]
    print(f"wrote {json_path}, {md_path}: {sum(c.passed for c in results if c.required)}/"
          f"{sum(c.required for c in results)} required cases pass"
          + (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


class _Subcommand(argparse.ArgumentParser):
    """A subcommand's parser whose arguments are added when it is first used: when it parses (the command named
    on the command line) or prints its help or usage. Building every subcommand's arguments took ~1 ms of CPU of
    every `monte render` process (6.2 -> 5.2 ms for building the parser and parsing, the rest being argparse's
    own first use), for one subcommand's use; `monte --help` lists every subcommand from its help line as
    before."""

    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None

    def _complete(self) -> None:
        add, self.add_arguments = self.add_arguments, None
        if add is not None:
            add(self)

    def parse_known_args(self, args=None, namespace=None):
        self._complete()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:
        self._complete()
        return super().format_usage()

    def format_help(self) -> str:
        self._complete()
        return super().format_help()


def _render_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", nargs="?", help="built-in scene name (see --list) or path to a .blend file")
    p.add_argument("-o", "--output", default="render.exr", help="output EXR path (default render.exr)")
    p.add_argument("--list", action="store_true", help="list the built-in scenes and exit")
    p.add_argument("--no-png", action="store_true", help="don't write the sRGB PNG preview next to the EXR")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or log")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="render on a Dask cluster: a scheduler's address (tcp://host:8786) or local:N (N worker "
                        "processes on this machine); the image is the same bit for bit")
    p.add_argument("--dask-timeout", type=float, default=10.0,
                   help="seconds to reach the Dask scheduler and see a worker (default 10)")
    p.add_argument("--frames", type=_frames,
                   help="with --dask and a .blend: frames A-B or A,B,C, each written as OUTPUT_####.exr when done")
    p.add_argument("--resume", action="store_true",
                   help="with --frames: skip frames whose output file exists")
    p.add_argument("--variance", action="store_true",
                   help="also estimate each pixel's error and write it as variance.R/G/B (2 independently scrambled "
                        "sequences per pixel: the image's variance is ~15%% higher at the same samples; adaptive sampling "
                        "keeps the estimate anyway; a .blend's view layer with the Variance pass ticked too)")
    p.add_argument("--file-passes", action="store_true",
                   help="a .blend: write the passes its view layers tick, not every pass Monte has (Z, normal "
                        "and albedo, computed together, only where one is ticked: ~5-10%% of a render's CPU; the "
                        "image is the same bit for bit)")
    p.add_argument("--passes", type=_data_passes, default=(),
                   help="built-in scenes: Cycles' data passes to add to the EXR, comma-separated: mist, position, "
                        "uv, object_index, material_index, crypto_object, crypto_material, crypto_asset (a .blend "
                        "uses its view layer's pass checkboxes)")
    _add_render_options(p)
    p.set_defaults(func=cmd_render)


def _worker_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("address", help="the Dask scheduler's address, tcp://host:8786")
    p.add_argument("--nthreads", type=int, default=os.cpu_count() or 1,
                   help="units rendered at once, one thread each (default: all cores)")
    p.add_argument("--nworkers", type=int, default=1, help="worker processes (default 1)")
    p.add_argument("--name", help="the worker's name on the scheduler")
    p.set_defaults(func=cmd_worker)


def _bench_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", help="also write the numbers to this JSON file")
    from .lab.bench_args import add_bench_arguments

    add_bench_arguments(p)
    p.add_argument("--reference", help="reference EXR for RMSE (default: the bundled converged Cycles render)")
    _add_render_options(p)
    p.set_defaults(func=cmd_bench)


def _perf_arguments(p: argparse.ArgumentParser) -> None:
    from .lab.bench_args import add_perf_arguments

    add_perf_arguments(p)
    p.set_defaults(func=cmd_perf)


def _crosscheck_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("blend", help="path to a .blend file (its active scene and camera)")
    p.add_argument("-o", "--output", required=True, help="folder for the EXRs, difference PNG and reports")
    p.add_argument("--spp", type=int, help="Monte's samples per pixel (default: the scene's)")
    p.add_argument("--cycles-spp", type=int, help="Cycles' samples per pixel over its 4 seeds (default: --spp)")
    p.add_argument("--resolution", type=_resolution, help="image size WxH (default: the scene's)")
    p.add_argument("--threads", type=int, help="threads for both renderers (default: all cores)")
    p.add_argument("--max-bounces", type=int, help="bounce limit for both (default: the scene's Monte setting)")
    p.set_defaults(func=cmd_crosscheck)


def _stress_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", required=True, help="folder for report.json and report.md")
    p.add_argument("--quick", action="store_true", help="smaller images and fewer samples (about a minute)")
    p.add_argument("--only", nargs="+", metavar="GROUP", help="run only these case groups (e.g. scale dielectric)")
    p.add_argument("--threads", type=int, help="ray-casting threads (0 = all cores)")
    p.add_argument("--cycles", action="store_true",
                   help="also render each case with Cycles (needs bpy) and report its means beside Monte's")
    p.add_argument("-q", "--quiet", action="store_true", help="no per-case log")
    p.set_defaults(func=cmd_stress)


def _mc_study_arguments(p: argparse.ArgumentParser) -> None:
    from .lab.bench_args import add_mc_study_arguments

    add_mc_study_arguments(p)
    p.set_defaults(func=cmd_mc_study)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="monte", description="Monte: a physically based Monte Carlo path tracer.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Subcommand)

    for name, help_line, add_arguments in (
            ("render", "render a built-in scene or a .blend file to an EXR (+ PNG preview)", _render_arguments),
            ("worker", "serve as a Dask worker for `monte render --dask` (kernels loaded first)", _worker_arguments),
            ("bench", "benchmark the Cornell box: samples/s, rays/s, Embree share, memory, RMSE; --vs cycles, "
                      "--samplers, --batch-sizes, --seed-table: run time against error", _bench_arguments),
            ("perf", "where time and memory go: stage profile, thread scaling, memory per batch, unused-feature "
                     "cost, adaptive sampling savings", _perf_arguments),
            ("crosscheck", "render a .blend with Monte and Cycles and compare them within noise",
             _crosscheck_arguments),
            ("stress", "the numerical stress suite: scale, grazing, degenerate geometry, glass, fireflies, extreme "
                       "resolutions; writes report.json and report.md", _stress_arguments),
            ("mc-study", "the seed's Monte Carlo study: estimators, error, efficiency, MSE", _mc_study_arguments)):
        sub.add_parser(name, help=help_line).add_arguments = add_arguments
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from .core.atomic_file import OutputError  # not core.exr: OpenEXR is imported where a file is written
    from .core.scene import SceneError

    try:
        return int(args.func(args) or 0)
    except (SceneError, OutputError, ValueError, FileNotFoundError, MemoryError) as exc:
        print(f"monte {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"\nmonte {args.command}: interrupted", file=sys.stderr)
        return 130


def run() -> None:
    """The `monte` executable (console script and `python -m monte`): main(), then the process's end.

    After a command that loaded the bpy module, Monte is unregistered and the process ends here with main()'s
    status, once every output is written and the exit handlers ran, without the interpreter's teardown (which
    crashes or hangs with the bpy module of 4.2 and 4.5, and costs ~0.5 s with numba's kernels loaded; where a
    non-daemon thread still runs on 5.0 and newer, Python exits normally): addon.headless.end_bpy_process.
    main() itself never ends the process, so tests and scripts can call it."""
    status = main()
    if "bpy" in sys.modules:
        from .addon.headless import end_bpy_process

        end_bpy_process(status, quick_exit=True)  # the interpreter's teardown skipped: ~0.5 s
    sys.exit(status)


if __name__ == "__main__":
    run()
