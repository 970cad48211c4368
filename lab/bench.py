"""`monte bench`: render the Cornell box and print throughput, Embree's share, memory and error.

Prints numbers only; nothing here asserts timings (machines are shared and noisy).
"""

from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

import numpy as np

from ..core import metrics
from ..core.exr import read_rgb
from ..core.render import render
from ..core.builtin_scenes import cornell_box
from ..core.settings import CLI_SETTINGS, RenderSettings
from .bench_math import efficiency

REFERENCE_MEANS = (0.39494, 0.33119, 0.39700)  # the bundled Cycles reference (4 x 1024 spp, BH 1.5 px)
REFERENCE_OWN_RMSE = 0.007  # the reference's own noise: RMSE against it is biased up by this in quadrature


def bundled_reference() -> np.ndarray:
    """The converged Cycles 5.0.1 render of the seed's Cornell box (256x256, Blackman-Harris 1.5 px)."""
    with resources.as_file(resources.files(__package__).joinpath("data/cornell_cycles_4096spp.exr")) as path:
        return read_rgb(path)


def run_bench(args: argparse.Namespace) -> dict:
    overrides = {k: getattr(args, k) for k in CLI_SETTINGS if getattr(args, k, None) is not None}
    settings = RenderSettings(**{"spp": 64, "aovs": False, **overrides}).validate()  # Cycles: Combined only
    resolution = getattr(args, "resolution", None) or (256, 256)
    scene = cornell_box(resolution)
    result = render(scene, settings)
    st = result.stats
    image = result.color[..., :3]
    report = {k: st[k] for k in ("spp", "seconds", "samples_per_second", "rays_per_second", "rays_closest",
                                 "rays_shadow", "embree_seconds", "embree_share", "peak_memory_mb", "threads")}
    report["channel_means"] = metrics.channel_means(image).tolist()
    reference = read_rgb(args.reference) if getattr(args, "reference", None) else None
    if reference is None and resolution == (256, 256):
        reference = bundled_reference()
    if reference is not None and reference.shape[:2] == image.shape[:2]:
        err = metrics.rmse(image, reference)
        # Remove the reference's own noise (independent of Monte's) in quadrature.
        err_true = float(np.sqrt(max(err * err - REFERENCE_OWN_RMSE**2, 0.0)))
        report.update(rmse=err, rmse_corrected=err_true,
                      efficiency=efficiency(st["seconds"], err_true * err_true))
    print(f"Cornell box {resolution[0]}x{resolution[1]}, {settings.spp} spp, {settings.sampler}, "
          f"{st['threads']} threads")
    print(f"  time            {st['seconds']:.2f} s (scene prepare {st['prepare_seconds']:.2f} s)")
    print(f"  samples/s       {st['samples_per_second'] / 1e3:.1f} k")
    print(f"  rays/s          {st['rays_per_second'] / 1e6:.2f} M ({st['rays_closest']} closest, "
          f"{st['rays_shadow']} shadow)")
    if st.get("fused_kernel"):
        print("  inside Embree   not timed (the fused path kernel calls Embree inside it: `monte perf --sections "
              "fused` splits its time; MONTE_FUSED=0 times the per-bounce integrator)")
    else:
        print(f"  inside Embree   {100 * st['embree_share']:.0f}% of wall time")
    print(f"  peak memory     {st['peak_memory_mb']:.0f} MB (process max RSS)")
    print(f"  channel means   {' '.join(f'{m:.4f}' for m in report['channel_means'])} "
          f"(Cycles: {' '.join(f'{m:.4f}' for m in REFERENCE_MEANS)})")
    if "rmse" in report:
        print(f"  RMSE vs Cycles  {report['rmse']:.4f} ({report['rmse_corrected']:.4f} without the reference's "
              f"own noise); efficiency 1/(s x MSE) = {report['efficiency']:.1f}")
    return report
