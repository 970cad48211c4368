"""Film memory: bytes per pixel of core.film.TileFilm (from its arrays) and the peak RSS of a render.

    python -m monte.lab.film_memory                      # bytes per pixel, each film configuration
    python -m monte.lab.film_memory --render 3840x2160   # + the peak RSS of a 1-spp Cornell box at 4K
    python -m monte.lab.film_memory --render 3840x2160 --film OLD_FILM.py   # the same with another film module

--film loads TileFilm from another version of core/film.py (e.g. `git show REV:core/film.py > old.py`) so that
a change to the film can be measured before and after in one checkout. The render runs in this process: run one
render per invocation (peak RSS is per process).
"""

from __future__ import annotations

import argparse
import importlib.util
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m monte.lab.film_memory", description=__doc__.splitlines()[0])
    parser.add_argument("--film", help="a core/film.py to measure instead of this checkout's")
    parser.add_argument("--render", help="WIDTHxHEIGHT: render the Cornell box at 1 spp and report peak RSS")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    film_class = load_film_class(args.film)
    for aovs, features in ((False, False), (True, False), (True, True)):
        print(f"film bytes/pixel aovs={aovs!s:5} features={features!s:5}: "
              f"{film_bytes_per_pixel(film_class, aovs, features):6.1f}")
    if args.render:
        w, h = (int(v) for v in args.render.lower().split("x"))
        render_module.TileFilm = film_class
        scene = scenes.cornell_box((w, h))
        settings = RenderSettings(spp=1, threads=args.threads)
        est = estimate_render_memory(scene, settings)
        r = render_module.render(scene, settings)
        print(f"render {w}x{h} 1 spp: peak RSS {(peak_rss_bytes() or 0) / 2**20:,.0f} MB, estimate "
              f"{est.describe()}, {r.stats['seconds']:.1f} s, image mean {r.color[..., :3].mean():.6f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
