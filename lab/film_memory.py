"""Film memory: bytes per pixel of core.film.TileFilm (from its arrays) and the peak RSS of a render.

    python -m monte.lab.film_memory                      # bytes per pixel, each film configuration
    python -m monte.lab.film_memory --render 3840x2160   # + the peak RSS of a 1-spp Cornell box at 4K
    python -m monte.lab.film_memory --render 3840x2160 --film OLD_FILM.py   # the same with another film module
    python -m monte.lab.film_memory --render 3840x2160 --spp 2 --tile-size 512 [--whole-image]
        # tiles that need several passes (512x512 tiles take 1 sample per pass at the default batch): the passes
        # going round one window of tiles at a time (core.schedule.FILM_WINDOW_PIXELS), or with --whole-image
        # round all tiles at once (every film alive until the last pass), as a time limit makes them
    python -m monte.lab.film_memory --table             # samples/s and peak RSS: 256x256 at 256 spp, 1080p, 4K
                                                         # and 8K at 1 spp, one process each, in one run
    python -m monte.lab.film_memory --table --package-root DIR   # the same for another checkout's `monte`
                                                         # (DIR holds its `monte` folder, e.g. from git archive)
    python -m monte.lab.film_memory --table --warm --package-root DIR --repeat 2
        # the same rows after a warm-up render in each process (no per-process first-render cost), this checkout
        # and DIR's alternating, with each render's process CPU per sample

    python -m monte.lab.film_memory --storage-study      # the 52 B/px colour storage (float32 running mean and three
                                                         # group excess sums) and float16 AOV running means against
                                                         # the film's storage and float64, a million samples per pixel

    python -m monte.lab.film_memory --render-films 1920x1080 --spp 2 --tile-size 512 [--package-root DIR]
        # the films a render makes (bytes per pixel, the most alive at once) and the process's peak RSS, in a
        # fresh process; with --package-root also that checkout's `monte`, in the same run

--film loads TileFilm from another version of core/film.py (e.g. `git show REV:core/film.py > old.py`) so that
a change to the film can be measured before and after in one checkout. The render runs in this process: run one
render per invocation (peak RSS is per process).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys

import numpy as np

from ..core import builtin_scenes as scenes
from ..core import render as render_module
from ..core.memory import estimate_render_memory, peak_rss_bytes
from ..core.sampling import VARIANCE_GROUPS, make_sampler
from ..core.settings import RenderSettings


def load_film_class(path: str | None):
    """TileFilm from core.film, or from the module file at `path` (loaded inside monte.core)."""
    if path is None:
        from ..core.film import TileFilm

        return TileFilm
    spec = importlib.util.spec_from_file_location("monte.core._film_measured", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    if not hasattr(module.TileFilm, "release"):  # a film from before the frame's assembly released films
        module.TileFilm.release = lambda self: None
    return module.TileFilm


def film_bytes_per_pixel(film_class, aovs: bool, features: bool) -> float:
    """Bytes per pixel of a 64x64 film's arrays (every ndarray attribute the film holds)."""
    sampler = make_sampler("sobol", 0, 16, groups=VARIANCE_GROUPS)
    film = film_class(64, 64, aovs, sampler, features)
    total = sum(v.nbytes for v in vars(film).values() if isinstance(v, np.ndarray))
    return total / (64 * 64)


# (width, height, spp) of the throughput table: the shape of the work, from many samples of few pixels to one
# sample of many
TABLE = ((256, 256, 256), (1920, 1080, 1), (3840, 2160, 1), (7680, 4320, 1))

# One render in a fresh process (peak RSS is per process), through the API every version of the core has.
_ONE_RENDER = """
import json, resource, sys
from monte.core import builtin_scenes
from monte.core.render import render
from monte.core.settings import RenderSettings
w, h, spp, threads = (int(v) for v in sys.argv[1:5])
r = render(builtin_scenes.cornell_box((w, h)), RenderSettings(spp=spp, threads=threads))
st = r.stats
print(json.dumps({"samples_per_second": st["samples_per_second"], "seconds": st["seconds"],
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                  "film_seconds": st["stage_seconds"].get("film", 0.0),
                  "assembly_seconds": st.get("assembly_seconds", float("nan"))}))
"""


def throughput_table(threads: int, package_root: str | None, sizes=TABLE) -> list[dict]:
    """Samples/s (the whole render: preparation, paths, film, the frame's assembly) and peak RSS of the Cornell
    box at each (width, height, spp), each in its own process; package_root: a folder whose `monte` is imported
    instead of this one (to measure another version in the same run)."""
    env = dict(os.environ)
    if package_root:
        env["PYTHONPATH"] = os.pathsep.join([package_root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    rows = []
    for w, h, spp in sizes:
        out = subprocess.run([sys.executable, "-c", _ONE_RENDER, str(w), str(h), str(spp), str(threads)],
                             env=env, check=True, capture_output=True, text=True).stdout
        row = {"width": w, "height": h, "spp": spp, **json.loads(out.strip().splitlines()[-1])}
        print(f"{w}x{h} {spp:4d} spp: {row['samples_per_second'] / 1e3:7.0f} k samples/s, {row['seconds']:7.1f} s, "
              f"peak RSS {row['peak_rss_mb']:7,.0f} MB, film {row['film_seconds']:.2f} s, "
              f"assembly {row['assembly_seconds']:.2f} s", flush=True)
        rows.append(row)
    return rows


# The table's renders in one process after a warm-up render (kernels loaded, tracers' tables built: the per-process
# first-render cost out, as in Blender, which keeps the add-on loaded): samples/s of each render, its process CPU
# seconds (all threads) and the process's peak RSS after it.
_WARM_RENDERS = """
import json, resource, sys, time
from monte.core import builtin_scenes
from monte.core.render import render
from monte.core.settings import RenderSettings
threads = int(sys.argv[1])
sizes = [tuple(int(v) for v in a.split(",")) for a in sys.argv[2:]]
render(builtin_scenes.cornell_box((64, 64)), RenderSettings(spp=1, threads=threads))  # the warm-up
render(builtin_scenes.cornell_box((64, 64)), RenderSettings(spp=4, threads=threads))
for w, h, spp in sizes:
    c0 = time.process_time()
    r = render(builtin_scenes.cornell_box((w, h)), RenderSettings(spp=spp, threads=threads))
    cpu = time.process_time() - c0
    st = r.stats
    print(json.dumps({"width": w, "height": h, "spp": spp, "samples_per_second": st["samples_per_second"],
                      "seconds": st["seconds"], "cpu_us_per_sample": cpu / st["samples"] * 1e6,
                      "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}), flush=True)
"""


def warm_table(threads: int, package_root: str | None, repeat: int, sizes=TABLE) -> list[dict]:
    """The throughput table measured in warm processes (_WARM_RENDERS: every row but the largest in one process,
    the largest, whose peak RSS is reported, in one of its own), this checkout's `monte` and, with package_root,
    that folder's alternating in one run (the order swapped every repeat); rows tagged "version"."""
    versions = [("this", None)] + ([("other", package_root)] if package_root else [])
    groups = [sizes[:-1], sizes[-1:]]
    rows = []
    for k in range(repeat):
        for name, root in (versions if k % 2 == 0 else versions[::-1]):
            env = dict(os.environ)
            if root:
                env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
            for group in groups:
                args = [",".join(str(v) for v in size) for size in group]
                out = subprocess.run([sys.executable, "-c", _WARM_RENDERS, str(threads), *args], env=env, check=True,
                                     capture_output=True, text=True).stdout
                for line in out.strip().splitlines():
                    row = {"version": name, "repeat": k, **json.loads(line)}
                    print(f"{name:5} #{k} {row['width']}x{row['height']} {row['spp']:4d} spp: "
                          f"{row['samples_per_second'] / 1e3:7.0f} k samples/s, {row['seconds']:6.1f} s, CPU "
                          f"{row['cpu_us_per_sample']:.3f} us/sample, peak RSS {row['peak_rss_mb']:7,.0f} MB",
                          flush=True)
                    rows.append(row)
    return rows


# One render in a fresh process, counting the films it makes (their arrays' bytes, the most alive at once).
_FILM_RENDER = """
import gc, json, resource, sys, weakref
import numpy as np
from monte.core import builtin_scenes
from monte.core import render as render_module
from monte.core.settings import RenderSettings
w, h, spp, tile, threads = (int(v) for v in sys.argv[1:6])
made, alive = [], weakref.WeakSet()
most = [0]
class CountedFilm(render_module.TileFilm):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        made.append(sum(v.nbytes for v in vars(self).values() if isinstance(v, np.ndarray)) / max(self.pixels, 1))
        alive.add(self)
        most[0] = max(most[0], sum(f.pixels for f in alive))
render_module.TileFilm = CountedFilm
r = render_module.render(builtin_scenes.cornell_box((w, h)), RenderSettings(spp=spp, threads=threads, tile_size=tile,
                                                                           aovs=True))
print(json.dumps({"film_bytes_per_pixel": max(made), "film_pixels_alive_max": most[0],
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                  "seconds": r.stats["seconds"], "image_mean": float(r.color[..., :3].mean()),
                  "albedo_mean": float(r.albedo.mean()), "depth_mean": float(r.depth.mean())}))
"""


def render_films(width: int, height: int, spp: int, tile: int, threads: int, package_root: str | None) -> dict:
    """The films a Cornell box render with AOVs makes (bytes per pixel of their arrays, the most pixels of film
    alive at once) and the process's peak RSS, in a fresh process; package_root as throughput_table's."""
    env = dict(os.environ)
    if package_root:
        env["PYTHONPATH"] = os.pathsep.join([package_root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    out = subprocess.run([sys.executable, "-c", _FILM_RENDER, str(width), str(height), str(spp), str(tile),
                          str(threads)], env=env, check=True, capture_output=True, text=True).stdout
    row = json.loads(out.strip().splitlines()[-1])
    print(f"{package_root or 'this checkout'}: {width}x{height} {spp} spp, {tile}-px tiles: film "
          f"{row['film_bytes_per_pixel']:.1f} B/px, at most {row['film_pixels_alive_max']:,} px of film alive, peak RSS "
          f"{row['peak_rss_mb']:,.0f} MB, {row['seconds']:.1f} s, image mean {row['image_mean']:.6f}, albedo mean "
          f"{row['albedo_mean']:.6f}, depth mean {row['depth_mean']:.6f}", flush=True)
    return row


def _grouped_variance(dev: np.ndarray, group_n: np.ndarray, mean_dev: np.ndarray) -> np.ndarray:
    """core.film's grouped variance of the mean from per-group sums of deviations dev (p, G, 3) from a common
    value, group_n (G,) samples per group and mean_dev (p, 3) the mean's deviation from that value."""
    d = dev / group_n[None, :, None] - mean_dev[:, None]
    return (group_n[None, :, None] * d * d).sum(axis=1) / ((len(group_n) - 1) * group_n.sum())


def storage_study(samples: int = 1_000_000, groups: int = 4, seed: int = 7) -> list[dict]:
    """Errors of the mean and of the grouped variance of the mean after `samples` samples per pixel, against
    float64, for the film's colour storage (float32 shift and `groups` float32 deviation sums: 16 + 12 G B/px with the
    count) and the 12-number one (float32 running mean, groups - 1 float32 excess sums, the last one implied by
    their sum being 0: 52 B/px), each pass folded as core.film folds it; and of a float16 running mean of an AOV
    (an edge pixel: albedo 0.2 or 0.8 at random). Pixels: uniform noise on a level (the tests' 1000 + U(0, 1), a
    pixel as noisy as it is bright, a quiet one). (groups=4: the study as recorded in docs/performance.md, made when renders used 4 groups.)"""
    rng = np.random.default_rng(seed)
    rows = []
    group = np.arange(samples) % groups
    for level, noise in ((1000.0, 1.0), (1.0, 1.0), (0.5, 0.01)):
        values = (np.float32(level) + np.float32(noise) * rng.random((2, samples, 3), dtype=np.float32))
        v64 = values.astype(np.float64)
        mean = v64.mean(axis=1)
        group_n = np.bincount(group, minlength=groups)
        reference = _grouped_variance(np.stack([(v64[:, group == g] - mean[:, None]).sum(axis=1)
                                                for g in range(groups)], axis=1), group_n, np.zeros_like(mean))
        for pass_size in (4096, 64):
            shift = running = None
            dev = np.zeros((2, groups, 3), np.float32)
            excess = np.zeros((2, groups - 1, 3), np.float32)
            before = np.zeros(groups, np.int64)
            for s0 in range(0, samples, pass_size):
                chunk, g = v64[:, s0:s0 + pass_size], group[s0:s0 + pass_size]
                sums = np.stack([chunk[:, g == k].sum(axis=1) for k in range(groups)], axis=1)
                counts = np.bincount(g, minlength=groups)
                if shift is None:
                    shift = running = (sums.sum(axis=1) / chunk.shape[1]).astype(np.float32)
                k = shift.astype(np.float64)[:, None]
                dev = (dev.astype(np.float64) + sums - counts[None, :, None] * k).astype(np.float32)
                old = running.astype(np.float64)
                after = before + counts
                new = (old + (sums.sum(axis=1) - counts.sum() * old) / after.sum()).astype(np.float32)
                m = new.astype(np.float64)[:, None]
                excess = (excess.astype(np.float64) - before[None, :-1, None] * (m - old[:, None])
                          + sums[:, :-1] - counts[None, :-1, None] * m).astype(np.float32)
                running, before = new, after
            d64 = dev.astype(np.float64)
            film_mean = shift.astype(np.float64) + d64.sum(axis=1) / samples
            film_var = _grouped_variance(d64, group_n, d64.sum(axis=1) / samples)
            e64 = excess.astype(np.float64)
            all_excess = np.concatenate([e64, -e64.sum(axis=1, keepdims=True)], axis=1)
            compact_var = _grouped_variance(all_excess, group_n, np.zeros_like(mean))
            rel = lambda a, b: float(np.max(np.abs(a - b) / np.abs(b)))
            row = {"pixel": f"{level:g} + {noise:g} U(0,1)", "pass": pass_size,
                   "mean_err_film": rel(film_mean, mean), "mean_err_52B": rel(running.astype(np.float64), mean),
                   "var_err_film": rel(film_var, reference), "var_err_52B": rel(compact_var, reference)}
            print(f"{row['pixel']:>18}, {pass_size:4d} samples/pass: mean rel. error film {row['mean_err_film']:.1e},"
                  f" 52 B {row['mean_err_52B']:.1e}; grouped variance rel. error film {row['var_err_film']:.1e},"
                  f" 52 B {row['var_err_52B']:.1e}", flush=True)
            rows.append(row)
    albedo = np.where(rng.random(samples) < 0.5, 0.2, 0.8)
    for pass_size in (64, 1):
        half, n = np.float16(0.0), 0
        for s0 in range(0, samples, pass_size):
            chunk = albedo[s0:s0 + pass_size]
            n += len(chunk)
            half = np.float16(np.float64(half) + (chunk.sum() - len(chunk) * np.float64(half)) / n)
        err = abs(float(half) - albedo.mean())
        print(f"AOV edge pixel (albedo 0.2 or 0.8), {pass_size:2d} samples/pass: float16 running mean off by {err:.1e}"
              f" (float32 sums: {abs(float(np.float32(albedo.sum())) / samples - albedo.mean()):.1e})", flush=True)
        rows.append({"pixel": "albedo 0.2/0.8", "pass": pass_size, "float16_running_mean_err": err})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m monte.lab.film_memory", description=__doc__.splitlines()[0])
    parser.add_argument("--film", help="a core/film.py to measure instead of this checkout's")
    parser.add_argument("--render", help="WIDTHxHEIGHT: render the Cornell box at 1 spp and report peak RSS")
    parser.add_argument("--spp", type=int, default=1, help="with --render: samples per pixel")
    parser.add_argument("--tile-size", type=int, default=64, help="with --render: tile edge in pixels")
    parser.add_argument("--whole-image", action="store_true",
                        help="with --render: the passes go round all tiles at once (no window of tiles)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--table", action="store_true", help="the throughput table (see the module docstring)")
    parser.add_argument("--package-root", help="with --table or --render-films: measure the `monte` package in this "
                                               "folder")
    parser.add_argument("--warm", action="store_true", help="with --table: after a warm-up render in each process "
                                                             "(see warm_table)")
    parser.add_argument("--repeat", type=int, default=1, help="with --table --warm: rounds, the order alternating")
    parser.add_argument("--json", help="with --table: write the rows to this file")
    parser.add_argument("--render-films", metavar="WIDTHxHEIGHT",
                        help="the films a render makes and its peak RSS (see the module docstring)")
    parser.add_argument("--storage-study", action="store_true",
                        help="the compact storages' errors at a million samples (see the module docstring)")
    args = parser.parse_args(argv)
    if args.render_films:
        w, h = (int(v) for v in args.render_films.lower().split("x"))
        for root in ([args.package_root] if args.package_root else []) + [None]:
            render_films(w, h, args.spp, args.tile_size, args.threads, root)
        return 0
    if args.storage_study:
        storage_study()
        return 0
    if args.table:
        rows = (warm_table(args.threads, args.package_root, args.repeat) if args.warm
                else throughput_table(args.threads, args.package_root))
        if args.json:
            with open(args.json, "w") as f:
                json.dump(rows, f, indent=1)
        return 0
    film_class = load_film_class(args.film)
    for aovs, features in ((False, False), (True, False), (True, True)):
        print(f"film bytes/pixel aovs={aovs!s:5} features={features!s:5}: "
              f"{film_bytes_per_pixel(film_class, aovs, features):6.1f}")
    if args.render:
        w, h = (int(v) for v in args.render.lower().split("x"))
        render_module.TileFilm = film_class
        if args.whole_image:
            render_module.FILM_WINDOW_PIXELS = 0
        scene = scenes.cornell_box((w, h))
        settings = RenderSettings(spp=args.spp, threads=args.threads, tile_size=args.tile_size)
        est = estimate_render_memory(scene, settings)
        r = render_module.render(scene, settings)
        order = "round all tiles" if args.whole_image else f"windows of {render_module.FILM_WINDOW_PIXELS:,} px"
        print(f"render {w}x{h} {args.spp} spp, {args.tile_size}-px tiles, {order}: peak RSS "
              f"{(peak_rss_bytes() or 0) / 2**20:,.0f} MB, estimate {est.describe()}, {r.stats['seconds']:.1f} s, "
              f"image mean {r.color[..., :3].mean():.6f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
