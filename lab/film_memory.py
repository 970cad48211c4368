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
    parser.add_argument("--package-root", help="with --table: measure the `monte` package in this folder")
    parser.add_argument("--json", help="with --table: write the rows to this file")
    args = parser.parse_args(argv)
    if args.table:
        rows = throughput_table(args.threads, args.package_root)
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
