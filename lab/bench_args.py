"""`monte bench` command-line options beyond the render options, and `monte perf`'s and `monte mc-study`'s
(argparse only: cheap to import).

--vs cycles (lab/bench_cycles.py, needs bpy), --vs mitsuba (lab/bench_mitsuba.py, needs bpy and mitsuba), --samplers, --batch-sizes and --seed-table
(lab/bench_ladders.py, no bpy).
"""

from __future__ import annotations

import argparse
import pathlib

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


# `monte perf` (lab/perf.py) and `monte mc-study` (lab/mc_study.py): their options here, so that building the
# command line's parser imports neither module (NumPy, the Monte Carlo study: 0.08-0.12 s of every `monte` process
# on the loaded 2-core machine).
PERF_SECTIONS = ("stages", "threads", "balance", "memory", "skip", "adaptive", "nodes", "textured", "sampled",
                 "fused")


def add_perf_arguments(p: argparse.ArgumentParser) -> None:
    """Options of `monte perf`."""
    p.add_argument("--sections", nargs="*", choices=PERF_SECTIONS,
                   help="which measurements (default: all but fused, which compiles a measurement copy of the fused "
                        "path kernel first, minutes)")
    p.add_argument("--resolution", type=int, default=128, help="square image size (default 128)")
    p.add_argument("--spp", type=int, default=16, help="samples per pixel per run (default 16)")
    p.add_argument("--threads", type=int, default=0, help="most worker threads (0 = all cores)")
    p.add_argument("--repeat", type=int, default=2, help="alternating repeats for timing comparisons")
    p.add_argument("--adaptive-threshold", type=float, default=0.1,
                   help="adaptive threshold to measure (default 0.1: Cornell box pixels reach it near 256 spp)")
    p.add_argument("--adaptive-spp", type=int, default=256, help="spp of the adaptive comparison (128x128 image)")
    p.add_argument("--node-points", type=int, default=1 << 16,
                   help="shading points per program run in the nodes section (default 65536)")
    p.add_argument("--memory-batches", type=int, nargs="+", default=[1 << 15, 1 << 16, 1 << 17, 1 << 18],
                   help="batch sizes (paths) of the memory section (default 32768 65536 131072 262144)")
    p.add_argument("--memory-resolution", type=int, default=256,
                   help="square image size of the memory section (default 256)")
    p.add_argument("--json", help="also write the numbers to this JSON file")


def add_mc_study_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `monte mc-study`."""
    parser.add_argument("-o", "--output", type=pathlib.Path, required=True,
                        help="folder for the plots and summaries")
    parser.add_argument("--seed", type=int, default=0,
                        help="random seed (default 0); every number but the timings is a function of it")
    parser.add_argument("--quick", action="store_true",
                        help="reduced sizes, as CI runs (well under a second of computing, plus the plots)")
