"""`monte bench` command-line options beyond the render options (argparse only: cheap to import).

--vs cycles (lab/bench_cycles.py, needs bpy), --vs mitsuba (lab/bench_mitsuba.py, needs bpy and mitsuba), --samplers, --batch-sizes and --seed-table
(lab/bench_ladders.py, no bpy).
"""

from __future__ import annotations

import argparse

SEED_TABLE_COUNTS = (8, 40, 200, 1000)  # samples per stratum in the seed's tables (also 5000, 25000)
BENCH_SCENES = ("cornell", "interior", "glass", "instances", "hdri", "textured")


def _int_list(text: str) -> list[int]:
    try:
        values = [int(float(v)) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return values


def _float_list(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not values or min(values) <= 0:
        raise argparse.ArgumentTypeError(f"expected positive numbers of seconds, got {text!r}")
    return values


def add_bench_arguments(p: argparse.ArgumentParser) -> None:
    """`monte bench` options beyond the render options: --vs cycles, the ladders, the seed table."""
    p.add_argument("blend", nargs="*", help="with --vs cycles: .blend files to bench as well")
    p.add_argument("--vs", choices=("cycles", "mitsuba"),
                   help="Monte against Cycles, run time against error (needs bpy); mitsuba: Monte against "
                        "Mitsuba 3 and Cycles on the Cornell box, box filter (needs bpy and mitsuba: "
                        "pip install -r requirements/rivals.txt)")
    p.add_argument("--mitsuba-variant", choices=("llvm_ad_rgb", "scalar_rgb"), default="llvm_ad_rgb",
                   help="with --vs mitsuba: Mitsuba's variant (default llvm_ad_rgb, its fastest on CPUs)")
    p.add_argument("--mitsuba-sampler", choices=("independent", "stratified", "multijitter", "orthogonal",
                                                 "ldsampler"), default="independent",
                   help="with --vs mitsuba: Mitsuba's sampler (default independent, Mitsuba's default)")
    p.add_argument("--scene", choices=(*BENCH_SCENES, "all", "none"),
                   help="with --vs cycles: which built-in bench scene(s) (default cornell; none = only .blend)")
    p.add_argument("--reference-dir", help="folder of cached converged references (created if missing)")
    p.add_argument("-o", "--output-dir", help="folder for bench.json and the plot (--vs, ladders, seed table)")
    p.add_argument("--ladder", type=_int_list, help="sample counts, e.g. 16,32,64,128,256")
    p.add_argument("--time-ladder", type=_float_list, help="with --vs cycles: time budgets in seconds instead")
    p.add_argument("--whole-process", action="store_true",
                   help="with --vs cycles: time each renderer as a whole process (monte render X.blend against "
                        "Blender rendering it with Cycles), at --spp (default 64)")
    p.add_argument("--repeats", type=int, default=3,
                   help="with --whole-process: processes per renderer, the best time counts (default 3)")
    p.add_argument("--reference-spp", type=int, default=1024, help="reference samples per seed (default 1024)")
    p.add_argument("--reference-seeds", type=int, default=4, help="reference seeds averaged (default 4)")
    p.add_argument("--samplers", action="store_true", help="Monte's samplers against each other (no bpy)")
    p.add_argument("--batch-sizes", type=_int_list, nargs="?", const=[1 << k for k in range(14, 21)],
                   help="batch sizes to compare (default 2^14..2^20) at --spp (default 16)")
    p.add_argument("--seed-table", action="store_true", help="the seed's variance tables (Markdown)")
    p.add_argument("--strata-samples", type=_int_list, default=list(SEED_TABLE_COUNTS),
                   help="with --seed-table: samples per stratum (default 8,40,200,1000; the seed also 5000,25000)")
