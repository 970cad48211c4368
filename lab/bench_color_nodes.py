"""Throughput of the colour and converter nodes (core/shading/color.py) through their batch forms: millions of
shading points per second per node, one thread, after the first compile.

    python -m monte.lab.bench_color_nodes [--points 1000000] [--repeats 5]

Prints one line per node (best of the repeats). The batch loop is what a node program's per-point call costs
plus the loop itself; no Blender needed.
"""

from __future__ import annotations

import argparse
import time
from typing import Callable

import numpy as np

from ..core.shading import color


def cases(n: int) -> dict[str, Callable[[], object]]:
    """Node name -> a call evaluating it on n random points (colours and factors in [0, 1], a 9-stop ramp,
    smooth curves)."""
    rng = np.random.default_rng(1)
    a, b, fac = rng.uniform(0, 1, (n, 3)), rng.uniform(0, 1, (n, 3)), rng.uniform(0, 1, n)
    x = np.linspace(0.0, 1.0, color.TABLE_SIZE)
    ramp = np.stack([x, x ** 2, np.sqrt(x), np.ones_like(x)], axis=1).astype(np.float32)
    curve = ramp[:, :3].copy()
    out = {f"Mix {mode}": (lambda mode=mode: color.mix_color_many(mode, fac, a, b))
           for mode in ("MIX", "MULTIPLY", "OVERLAY", "HUE", "SOFT_LIGHT")}
    out.update({
        "Color Ramp": lambda: color.color_ramp_many(ramp, True, fac),
        "RGB Curves": lambda: color.curves_many(curve, 0.0, 1.0, True, 1.0, a),
        "Float Curve": lambda: color.float_curve_many(curve[:, 0], 0.0, 1.0, False, 1.0, fac),
        "Hue/Saturation/Value": lambda: color.hue_saturation_value_many(0.6, 1.2, 0.9, 1.0, a),
        "Invert": lambda: color.invert_many(fac, a),
        "Bright/Contrast": lambda: color.bright_contrast_many(a, 0.1, 0.2),
        "Gamma": lambda: color.gamma_many(a, 2.2),
        "RGB to BW": lambda: color.rgb_to_bw_many(a),
        "Separate HSV": lambda: color.separate_color_many("HSV", a),
        "Combine HSL": lambda: color.combine_color_many("HSL", a),
        "Blackbody": lambda: color.blackbody_many(800.0 + 11000.0 * fac),
        "Wavelength": lambda: color.wavelength_many(380.0 + 400.0 * fac),
    })
    return out


def run(points: int = 1_000_000, repeats: int = 5) -> dict[str, float]:
    """Millions of points per second per node (best of `repeats`)."""
    rates = {}
    for name, call in cases(points).items():
        call()  # compile (or load from the cache) first
        best = min(_timed(call) for _ in range(repeats))
        rates[name] = points / best / 1e6
    return rates


def _timed(call: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    call()
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    if args.points < 1 or args.repeats < 1:
        parser.error("--points and --repeats must be at least 1")
    for name, rate in run(args.points, args.repeats).items():
        print(f"{name:22s} {rate:8.1f} M points/s")


if __name__ == "__main__":
    main()
