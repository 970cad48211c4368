"""`monte mc-study`: the seed's Monte Carlo experiments, reproduced and extended.

Runs the estimators, variance-reduction methods and samplers of ``lab/montecarlo.py`` over many
independent repetitions, then writes PNG plots, ``summary.json`` and ``summary.md`` into one folder.
Every random stream derives from (seed, experiment name, n), so the numbers of a run are a pure
function of the seed and the ``quick`` flag; only keys containing "second" (timings and the
efficiencies 1/(T·V) built from them) vary between runs.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core.atomic_file import write_bytes_atomically
from . import montecarlo as mc
from .bench_math import efficiency

# The trapezoidal rule: np.trapezoid since NumPy 2.0 (np.trapz was removed), np.trapz on NumPy 1.x (Blender 4.x).
trapezoid = getattr(np, "trapezoid", None) or np.trapz

CONFIDENCE = 0.999
"""Confidence level of every interval and band in the study (normal approximation)."""

ESTIMATE_SPREAD = 0.95
"""Share of single estimates inside the plotted spread band: a quantile of the estimates themselves,
not a confidence interval, so a level the repetitions can resolve (R = 1000 leaves 25 per tail)."""


@dataclass(frozen=True)
class StudyConfig:
    """Problem sizes: the default run computes for seconds, ``quick`` (what CI runs) for well under one;
    drawing the ten plots adds a few seconds to either."""

    sample_counts: tuple[int, ...]
    repetitions: int
    importance_segments: int
    two_d_samples: int
    two_d_repetitions: int
    splits: int
    weight_threshold: float
    survival_probability: float
    splitting_sweep: tuple[int, ...]
    survival_sweep: tuple[float, ...]
    sampler_samples: int
    histogram_bins: int
    metropolis_steps: int
    metropolis_step_size: float

    @classmethod
    def for_run(cls, quick: bool) -> StudyConfig:
        return cls(
            sample_counts=tuple(2**k for k in range(1, 9 if quick else 13)),
            repetitions=200 if quick else 1000,
            importance_segments=4,
            two_d_samples=64 if quick else 256,
            two_d_repetitions=400 if quick else 2000,
            splits=8,
            weight_threshold=0.5,
            survival_probability=0.1,
            splitting_sweep=(1, 2, 4, 8, 16, 32),
            survival_sweep=(1.0, 0.5, 0.25, 0.1, 0.05, 0.02),
            sampler_samples=10_000 if quick else 100_000,
            histogram_bins=30 if quick else 50,
            metropolis_steps=100,
            metropolis_step_size=3.0,
        )


def _rng(seed: int, experiment: str, n: int = 0) -> np.random.Generator:
    """An independent stream per (seed, experiment, n): results do not depend on run order."""
    return np.random.default_rng([seed, zlib.crc32(experiment.encode()), n])


# --------------------------------------------------------------------------------------------
# Experiments
# --------------------------------------------------------------------------------------------

Estimator = Callable[[int, int, np.random.Generator], np.ndarray]


STATISTICS = ("mean", "mean_half_width", "variance", "variance_half_width", "bias", "mse", "mse_half_width")


def _sweep_over_n(
    name: str, estimator: Estimator, config: StudyConfig, seed: int, fit_variance_slope: bool = True
) -> dict[str, Any]:
    """Run ``estimator`` for every n with R repetitions; statistics, timings and 1/(T·V) per n."""
    rows: dict[str, list] = {key: [] for key in STATISTICS}
    rows |= {"exact_in_interval": [], "single_estimate_spread": [], "seconds_per_estimate": [],
             "efficiency_per_second": []}
    tail = (1.0 - ESTIMATE_SPREAD) / 2.0 * 100.0
    for n in config.sample_counts:
        start = time.perf_counter()
        estimates = mc.run_repetitions(estimator, n, config.repetitions, _rng(seed, name, n))
        seconds = (time.perf_counter() - start) / config.repetitions
        stats = mc.summarize_repetitions(estimates, mc.SEED_EXACT, CONFIDENCE)
        for key in STATISTICS:
            rows[key].append(getattr(stats, key))
        rows["exact_in_interval"].append(stats.contains(mc.SEED_EXACT))
        # Where single estimates fall (not their mean): the spread one run of n samples has.
        rows["single_estimate_spread"].append(np.percentile(estimates, [tail, 100.0 - tail]).tolist())
        rows["seconds_per_estimate"].append(seconds)
        rows["efficiency_per_second"].append(efficiency(seconds, stats.variance))
    result: dict[str, Any] = {"n": list(config.sample_counts), "repetitions": config.repetitions,
                              "single_estimate_spread_level": ESTIMATE_SPREAD, **rows}
    if fit_variance_slope:
        standard_errors = np.array(rows["variance_half_width"]) / mc.normal_quantile(CONFIDENCE)
        slope, slope_error = mc.loglog_slope(np.array(config.sample_counts), np.array(rows["variance"]),
                                             standard_errors)
        result["variance_loglog_slope"] = slope
        result["variance_slope_standard_error"] = slope_error
    return result


def _single_sample_variance(f: mc.Integrand, a: float, b: float, points: int = 400_001) -> float:
    """V[(b − a) f(X)] for X ~ U(a, b) by fine quadrature: the theory line σ²/n of the plots."""
    x = np.linspace(a, b, points)
    values = f(x)
    mean = trapezoid(values, x) / (b - a)
    mean_square = trapezoid(values**2, x) / (b - a)
    return float((b - a) ** 2 * (mean_square - mean**2))


def _estimator_experiments(config: StudyConfig, seed: int, log: Callable[[str], None]) -> dict[str, Any]:
    f = mc.seed_integrand
    a, b = mc.SEED_INTERVAL
    pdf = mc.PiecewiseLinearPdf.fit(f, a, b, config.importance_segments)
    estimators: dict[str, Estimator] = {
        "uniform": lambda n, r, rng: mc.uniform_estimates(f, a, b, n, r, rng),
        "stratified": lambda n, r, rng: mc.stratified_estimates(f, a, b, n, r, rng),
        "importance": lambda n, r, rng: mc.importance_estimates(f, pdf, n, r, rng),
        "biased_max": lambda n, r, rng: mc.biased_max_estimates(f, a, b, n, r, rng),
    }
    results = {}
    for name, estimator in estimators.items():
        log(f"mc-study: {name} estimator, n = {config.sample_counts[0]}..{config.sample_counts[-1]}, "
            f"{config.repetitions} repetitions")
        # The biased estimator's variance is no power law of n (it collapses onto max f): no slope.
        results[name] = _sweep_over_n(name, estimator, config, seed, fit_variance_slope=name != "biased_max")
    results["importance"]["pdf"] = {
        "kind": "piecewise linear through f at equally spaced nodes",
        "nodes": pdf.nodes.tolist(),
        "values": pdf.values.tolist(),
    }
    results["biased_max"]["limit"] = 0.5 * float(f(np.linspace(a, b, 400_001)).max())
    return results


def _variance_reduction_1d(estimators: dict[str, Any]) -> dict[str, Any]:
    """Variance and measured efficiency of each unbiased method relative to uniform, at the largest n."""
    uniform = estimators["uniform"]
    methods = {}
    for name in ("uniform", "stratified", "importance"):
        sweep = estimators[name]
        methods[name] = {
            "variance": sweep["variance"][-1],
            "variance_ratio_vs_uniform": uniform["variance"][-1] / sweep["variance"][-1],
            "efficiency_per_second": sweep["efficiency_per_second"][-1],
            "efficiency_per_second_ratio_vs_uniform":
                sweep["efficiency_per_second"][-1] / uniform["efficiency_per_second"][-1],
            "variance_loglog_slope": sweep.get("variance_loglog_slope"),
        }
    return {"n": uniform["n"][-1], "methods": methods}


def _costed_summary(result: mc.CostedEstimates, exact: float) -> dict[str, Any]:
    stats = mc.summarize_repetitions(result.estimates, exact, CONFIDENCE)
    return {
        "mean": stats.mean,
        "mean_half_width": stats.mean_half_width,
        "exact_in_interval": stats.contains(exact),
        "variance": stats.variance,
        "variance_half_width": stats.variance_half_width,
        "cost_per_estimate": result.cost_per_estimate,
        "efficiency_per_cost_unit": efficiency(result.cost_per_estimate, stats.variance),
    }


def _variance_reduction_2d(config: StudyConfig, seed: int, log: Callable[[str], None]) -> dict[str, Any]:
    """Russian roulette and splitting on the expensive/cheap 2-D integrand, with parameter sweeps."""
    g = mc.ExpensiveCheapIntegrand()
    n, repetitions = config.two_d_samples, config.two_d_repetitions
    log(f"mc-study: Russian roulette and splitting, n = {n}, {repetitions} repetitions")

    def roulette(q: float) -> mc.CostedEstimates:
        return mc.russian_roulette_estimates(
            g, n, repetitions, _rng(seed, f"roulette q={q}", n),
            weight_threshold=config.weight_threshold, survival_probability=q)

    def splitting(m: int) -> mc.CostedEstimates:
        return mc.splitting_estimates(g, n, repetitions, _rng(seed, f"splitting m={m}", n), splits=m)

    methods = {
        "uniform": _costed_summary(
            mc.uniform_2d_estimates(g, n, repetitions, _rng(seed, "uniform 2d", n)), g.exact),
        "russian_roulette": _costed_summary(roulette(config.survival_probability), g.exact),
        "splitting": _costed_summary(splitting(config.splits), g.exact),
    }
    uniform_efficiency = methods["uniform"]["efficiency_per_cost_unit"]
    for summary in methods.values():
        summary["variance_ratio_vs_uniform"] = methods["uniform"]["variance"] / summary["variance"]
        summary["efficiency_ratio_vs_uniform"] = summary["efficiency_per_cost_unit"] / uniform_efficiency
    methods["russian_roulette"].update(
        weight_threshold=config.weight_threshold, survival_probability=config.survival_probability)
    methods["splitting"]["splits"] = config.splits

    def sweep(results: list[dict[str, Any]]) -> dict[str, list[float]]:
        columns = {key: [r[key] for r in results] for key in ("variance", "cost_per_estimate")}
        ratios = [r["efficiency_per_cost_unit"] / uniform_efficiency for r in results]
        return columns | {"efficiency_ratio_vs_uniform": ratios}

    return {
        "integrand": "g(x, y) = (pi/2) sin(pi y) * (k+1) frac(x + y)^k, k = "
                     f"{g.lobe_exponent}, on [0, 1]^2; exact value {g.exact}",
        "cheap_cost": g.cheap_cost,
        "expensive_cost": g.expensive_cost,
        "n": n,
        "repetitions": repetitions,
        "methods": methods,
        "splitting_sweep": {"splits": list(config.splitting_sweep)}
        | sweep([_costed_summary(splitting(m), g.exact) for m in config.splitting_sweep]),
        "russian_roulette_sweep": {"survival_probability": list(config.survival_sweep)}
        | sweep([_costed_summary(roulette(q), g.exact) for q in config.survival_sweep]),
    }


@dataclass(frozen=True)
class SamplerRun:
    """One sampler's samples and what they are tested against (kept for the plots)."""

    name: str
    method: str
    target: str
    samples: np.ndarray
    pdf: mc.Integrand
    cdf: Callable[[np.ndarray], np.ndarray]
    domain: tuple[float, float]
    extra: dict[str, Any]


def _sampler_experiments(
    config: StudyConfig, seed: int, log: Callable[[str], None]
) -> tuple[dict[str, Any], list[SamplerRun], np.ndarray]:
    """Draw from each sampler and chi-square test it against its target pdf."""
    n = config.sampler_samples
    a, b = mc.SEED_INTERVAL
    log(f"mc-study: samplers, {n} samples each")
    pdf = mc.PiecewiseLinearPdf.fit(mc.seed_integrand, a, b, config.importance_segments)

    theta, phi = mc.sample_cosine_hemisphere(_rng(seed, "cosine hemisphere"), n)
    hemisphere = {
        "method": "inverse transform: phi = 2 pi xi1, theta = arccos(sqrt(1 - xi2))",
        "target": "cosine-weighted hemisphere, p(theta, phi) = sin(2 theta) / (2 pi)",
        "samples": n,
        "test": "joint (theta, phi) histogram, 10 x 8 bins",
        **asdict(mc.cosine_hemisphere_chi_square(theta, phi)),
    }
    # The same samples against the uniform-hemisphere pdf: shows the test can tell them apart.
    wrong_pdf_control = {
        "method": "the cosine-hemisphere samples above",
        "target": "WRONG on purpose: uniform hemisphere, p(theta) = sin(theta)",
        "samples": n,
        **asdict(mc.cosine_hemisphere_chi_square(theta, phi, mc.uniform_hemisphere_theta_cdf)),
    }

    envelope = mc.envelope_constant(mc.seed_density, pdf.pdf, a, b)
    rejection = mc.rejection_sample(
        mc.seed_density, pdf.sample, pdf.pdf, envelope, n, _rng(seed, "rejection"))
    mh_rng = _rng(seed, "metropolis")
    metropolis = mc.metropolis_hastings(mc.seed_density, mh_rng.uniform(a, b, n),
                                        config.metropolis_step_size, config.metropolis_steps, mh_rng)

    runs = [
        SamplerRun("inverse_transform_piecewise_linear", "inverse transform (quadratic CDF inverse)",
                   f"piecewise-linear pdf through f at {config.importance_segments + 1} nodes "
                   "(the importance-sampling pdf)",
                   pdf.sample(_rng(seed, "piecewise linear"), n), pdf.pdf, pdf.cdf, (a, b), {}),
        SamplerRun("acceptance_rejection", "acceptance-rejection, proposal = the piecewise-linear pdf",
                   "the seed's integrand as a pdf, f(x)/F on [0, 10]", rejection.samples,
                   mc.seed_density, mc.seed_integrand_cdf, (a, b),
                   {"envelope_constant": envelope, "acceptance_rate": rejection.acceptance_rate}),
        SamplerRun("metropolis_hastings",
                   f"random-walk Metropolis-Hastings, {n} independent chains, final state after "
                   f"{config.metropolis_steps} steps of N(0, {config.metropolis_step_size}^2)",
                   "the seed's integrand as a pdf, f(x)/F on [0, 10]", metropolis.samples,
                   mc.seed_density, mc.seed_integrand_cdf, (a, b),
                   {"acceptance_rate": metropolis.acceptance_rate, "steps": config.metropolis_steps,
                    "step_size": config.metropolis_step_size}),
    ]
    summary: dict[str, Any] = {
        "cosine_hemisphere": hemisphere, "cosine_hemisphere_vs_wrong_pdf": wrong_pdf_control}
    for run in runs:
        edges = np.linspace(*run.domain, config.histogram_bins + 1)
        summary[run.name] = {
            "method": run.method, "target": run.target, "samples": n,
            "test": f"histogram, {config.histogram_bins} equal bins",
            **asdict(mc.histogram_chi_square(run.samples, run.cdf, edges)), **run.extra,
        }
    return summary, runs, np.stack([theta, phi])


# --------------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------------


def _band(ax, x, centre, half_width, label: str, **style) -> None:
    """A line with a shaded confidence band, clipped above zero so log axes can show it."""
    centre = np.asarray(centre, dtype=float)
    half_width = np.asarray(half_width, dtype=float)
    (line,) = ax.plot(x, centre, marker="o", markersize=3, label=label, **style)
    low = np.maximum(centre - half_width, centre * 1e-3)
    ax.fill_between(x, low, centre + half_width, color=line.get_color(), alpha=0.2, linewidth=0)


def _confidence_label() -> str:
    return f"{CONFIDENCE:.1%} band"


def _spread_label() -> str:
    return f"central {ESTIMATE_SPREAD:.0%} of single estimates"


def _plot_error(
    ax_mean, ax_rmse, sweep: dict[str, Any], single_sample_variance: float | None, title: str
) -> None:
    n = np.array(sweep["n"])
    band = np.array(sweep["single_estimate_spread"])
    ax_mean.fill_between(n, band[:, 0], band[:, 1], color="0.85", label=_spread_label())
    _band(ax_mean, n, sweep["mean"], sweep["mean_half_width"], f"mean of estimates ({_confidence_label()})")
    ax_mean.axhline(mc.SEED_EXACT, color="k", linestyle="--", linewidth=1, label=f"exact {mc.SEED_EXACT:.6f}")
    ax_mean.set(xscale="log", xlabel="n (samples per estimate)", ylabel="estimate",
                title=f"{title}: estimates")
    ax_mean.legend(fontsize=7)

    mse = np.array(sweep["mse"])
    mse_hw = np.array(sweep["mse_half_width"])
    rmse = np.sqrt(mse)
    (line,) = ax_rmse.plot(n, rmse, marker="o", markersize=3, label="RMSE = sqrt(MSE)")
    ax_rmse.fill_between(n, np.sqrt(np.maximum(mse - mse_hw, mse * 1e-6)), np.sqrt(mse + mse_hw),
                         color=line.get_color(), alpha=0.2, linewidth=0, label=_confidence_label())
    if single_sample_variance is not None:
        ax_rmse.plot(n, np.sqrt(single_sample_variance / n), "k--", linewidth=1, label="theory sigma/sqrt(n)")
    ax_rmse.set(xscale="log", yscale="log", xlabel="n", ylabel="|error|", title=f"{title}: error")
    ax_rmse.legend(fontsize=7)


def _new_figure(plt, columns: int):
    """A figure of 1 or 2 panels with fixed margins: tight_layout would double this machine-bound
    cost (it measures every tick label), and these layouts never change."""
    fig, axes = plt.subplots(1, columns, figsize=(5.5 * columns, 4.2))
    left = 0.12 / columns
    fig.subplots_adjust(left=left, right=1 - left / 3, bottom=0.12, top=0.92, wspace=0.28)
    return fig, axes


def _figures(summary: dict[str, Any], samplers: list[SamplerRun], hemisphere: np.ndarray) -> dict[str, Any]:
    """Build every figure; returns file name -> matplotlib Figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    est = summary["estimators"]
    sigma2 = summary["integrand"]["single_sample_variance"]
    figures: dict[str, Any] = {}

    fig, (ax1, ax2) = _new_figure(plt, 2)
    _plot_error(ax1, ax2, est["uniform"], sigma2, "uniform F_n")
    figures["error_vs_n.png"] = fig

    fig, ax = _new_figure(plt, 1)
    uniform = est["uniform"]
    n = np.array(uniform["n"])
    efficiency = np.array(uniform["efficiency_per_second"])
    relative = np.array(uniform["variance_half_width"]) / np.array(uniform["variance"])
    # 1/(T V): the band propagates V's interval only (T is one measurement, not a sample mean).
    (line,) = ax.plot(n, efficiency, marker="o", markersize=3, label="1 / (T V), uniform F_n")
    ax.fill_between(n, efficiency / (1 + relative), efficiency / np.maximum(1 - relative, 1e-3),
                    color=line.get_color(), alpha=0.2, linewidth=0, label=_confidence_label() + " (from V)")
    ax.set(xscale="log", yscale="log", xlabel="n", ylabel="efficiency [1/(s * variance)]",
           title="efficiency of the uniform estimator (T measured)")
    ax.legend(fontsize=7)
    figures["efficiency_vs_n.png"] = fig

    fig, ax = _new_figure(plt, 1)
    _band(ax, n, uniform["mse"], uniform["mse_half_width"], f"MSE ({_confidence_label()})")
    ax.plot(n, uniform["variance"], "x", label="V (plug-in)")
    ax.plot(n, np.maximum(np.square(uniform["bias"]), 1e-12), "+", label="bias^2 (statistical noise)")
    ax.plot(n, sigma2 / n, "k--", linewidth=1, label="theory sigma^2/n")
    ax.set(xscale="log", yscale="log", xlabel="n", ylabel="MSE",
           title="MSE of the unbiased uniform estimator")
    ax.legend(fontsize=7)
    figures["mse_vs_n.png"] = fig

    biased = est["biased_max"]
    fig, (ax1, ax2) = _new_figure(plt, 2)
    _band(ax1, n, biased["mean"], biased["mean_half_width"],
          f"mean of (1/2) max f(X_i) ({_confidence_label()})")
    band = np.array(biased["single_estimate_spread"])
    ax1.fill_between(n, band[:, 0], band[:, 1], color="0.85", label=_spread_label())
    ax1.axhline(biased["limit"], color="C3", linestyle=":",
                label=f"limit (1/2) max f = {biased['limit']:.4f}")
    ax1.set(xscale="log", xlabel="n", ylabel="estimate",
            title=f"biased estimator (exact value {mc.SEED_EXACT:.2f} is far above)")
    ax1.legend(fontsize=7)
    _band(ax2, n, biased["mse"], biased["mse_half_width"], f"MSE ({_confidence_label()})")
    ax2.plot(n, np.square(biased["bias"]), "--", label="bias^2")
    ax2.plot(n, biased["variance"], marker="x", label="V")
    ax2.plot(n, np.array(biased["variance"]) + np.square(biased["bias"]), ":", color="k", label="V + bias^2")
    ax2.set(xscale="log", yscale="log", xlabel="n", ylabel="squared error", title="MSE = V + bias^2")
    ax2.legend(fontsize=7)
    figures["biased_estimator.png"] = fig

    fig, (ax1, ax2) = _new_figure(plt, 2)
    for name in ("uniform", "stratified", "importance"):
        sweep = est[name]
        slope = sweep.get("variance_loglog_slope")
        label = name + (f" (slope {slope:.2f})" if slope is not None else "")
        _band(ax1, n, sweep["variance"], sweep["variance_half_width"], label)
        ax2.plot(n, sweep["efficiency_per_second"], marker="o", markersize=3, label=name)
    ax1.set(xscale="log", yscale="log", xlabel="n", ylabel="variance",
            title=f"variance ({_confidence_label()})")
    ax2.set(xscale="log", yscale="log", xlabel="n", ylabel="1 / (T V)", title="efficiency (T measured)")
    ax1.legend(fontsize=7)
    ax2.legend(fontsize=7)
    figures["variance_reduction.png"] = fig

    two_d = summary["variance_reduction_2d"]
    fig, (ax1, ax2) = _new_figure(plt, 2)
    names = list(two_d["methods"])
    positions = np.arange(len(names))
    uniform_2d = two_d["methods"]["uniform"]
    for offset, (key, label) in enumerate([
        ("variance", "variance / uniform"), ("cost_per_estimate", "cost / uniform"),
        ("efficiency_per_cost_unit", "efficiency / uniform")]):
        ratios = [two_d["methods"][m][key] / uniform_2d[key] for m in names]
        ax1.bar(positions + (offset - 1) * 0.27, ratios, width=0.27, label=label)
    ax1.axhline(1.0, color="k", linewidth=0.8)
    ax1.set_xticks(positions, [m.replace("_", " ") for m in names])
    ax1.set(ylabel="ratio to uniform",
            title=f"2-D integrand, n = {two_d['n']} (costs: cheap {two_d['cheap_cost']:g}, "
                  f"expensive {two_d['expensive_cost']:g})")
    ax1.legend(fontsize=7)
    ax2.plot(two_d["splitting_sweep"]["splits"], two_d["splitting_sweep"]["efficiency_ratio_vs_uniform"],
             marker="o", label="splitting: m cheap samples per expensive one (x axis: m)")
    ax2.plot(1.0 / np.array(two_d["russian_roulette_sweep"]["survival_probability"]),
             two_d["russian_roulette_sweep"]["efficiency_ratio_vs_uniform"],
             marker="s", label="Russian roulette: survival q (x axis: 1/q)")
    ax2.axhline(1.0, color="k", linewidth=0.8)
    ax2.set(xscale="log", xlabel="m or 1/q", ylabel="efficiency / uniform", title="parameter sweeps")
    ax2.legend(fontsize=7)
    figures["variance_reduction_2d.png"] = fig

    tests = summary["samplers"]
    theta, phi = hemisphere
    fig, (ax1, ax2) = _new_figure(plt, 2)
    grid = np.linspace(0.0, math.pi / 2.0, 200)
    ax1.hist(theta, bins=40, range=(0, math.pi / 2), density=True, histtype="stepfilled", color="0.75",
             label="samples")
    ax1.plot(grid, mc.cosine_hemisphere_theta_pdf(grid), "C0", label="target sin(2 theta)")
    ax1.plot(grid, mc.uniform_hemisphere_theta_pdf(grid), "C3--",
             label=f"wrong pdf sin(theta): p = {tests['cosine_hemisphere_vs_wrong_pdf']['p_value']:.2g}")
    ax1.set(xlabel="theta", ylabel="density",
            title="cosine hemisphere theta; joint (theta, phi) "
                  f"chi2 = {tests['cosine_hemisphere']['statistic']:.1f}, "
                  f"p = {tests['cosine_hemisphere']['p_value']:.3f}")
    ax1.legend(fontsize=7)
    ax2.hist(phi, bins=40, range=(0, 2 * math.pi), density=True, histtype="stepfilled", color="0.75",
             label="samples")
    ax2.axhline(1.0 / (2.0 * math.pi), color="C0", label="target 1/(2 pi)")
    ax2.set(xlabel="phi", ylabel="density", title="cosine hemisphere phi")
    ax2.legend(fontsize=7)
    figures["sampler_cosine_hemisphere.png"] = fig

    for run in samplers:
        fig, ax = _new_figure(plt, 1)
        grid = np.linspace(*run.domain, 400)
        ax.hist(run.samples, bins=50, range=run.domain, density=True, histtype="stepfilled", color="0.75",
                label="samples")
        ax.plot(grid, run.pdf(grid), "C0", label="target pdf")
        result = tests[run.name]
        ax.set(xlabel="x", ylabel="density",
               title=f"{run.name.replace('_', ' ')}: chi2 = {result['statistic']:.1f}, "
                     f"dof = {result['degrees_of_freedom']}, p = {result['p_value']:.3f}")
        ax.legend(fontsize=7)
        figures[f"sampler_{run.name}.png"] = fig

    return figures


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------


def _write_atomically(path: Path, data: bytes) -> None:
    """Readers never see a partial file (core.atomic_file)."""
    write_bytes_atomically(path, data)


def _write_plots(
    out_dir: Path, summary: dict[str, Any], sampler_runs: list[SamplerRun], hemisphere: np.ndarray,
    log: Callable[[str], None],
) -> list[str]:
    log(f"mc-study: writing plots to {out_dir}")
    figures = _figures(summary, sampler_runs, hemisphere)
    import matplotlib.pyplot as plt

    for name, fig in figures.items():
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=100)
        plt.close(fig)
        _write_atomically(out_dir / name, buffer.getvalue())
    return sorted(figures)


def _markdown(summary: dict[str, Any]) -> str:
    est = summary["estimators"]
    uniform = est["uniform"]
    lines = [
        "# Monte Carlo study",
        "",
        f"Seed {summary['seed']}{', quick run' if summary['quick'] else ''}; every interval is at "
        f"{CONFIDENCE:.1%} confidence. Integrand: {summary['integrand']['formula']}, exact value "
        f"{summary['integrand']['exact']:.14f}. Timings (keys with \"second\") vary between runs; "
        "everything else is a function of the seed.",
        "",
        f"## Uniform estimator ({uniform['repetitions']} repetitions per n)",
        "",
        "| n | mean ± half-width | variance | MSE | efficiency 1/(T V) [1/s] |",
        "|---:|---:|---:|---:|---:|",
    ]
    for i, n in enumerate(uniform["n"]):
        lines.append(f"| {n} | {uniform['mean'][i]:.5f} ± {uniform['mean_half_width'][i]:.5f} | "
                     f"{uniform['variance'][i]:.4g} | {uniform['mse'][i]:.4g} | "
                     f"{uniform['efficiency_per_second'][i]:.3g} |")
    biased = est["biased_max"]
    lines += [
        "",
        f"Variance log-log slope: {uniform['variance_loglog_slope']:.3f} ± "
        f"{uniform['variance_slope_standard_error']:.3f} (theory -1).",
        "",
        "## Biased estimator (1/2) max f(X_i)",
        "",
        f"Converges to (1/2) max f = {biased['limit']:.5f}, not to the integral.",
        "",
        "| n | mean | bias | variance | MSE = V + bias^2 |",
        "|---:|---:|---:|---:|---:|",
    ]
    for i, n in enumerate(biased["n"]):
        lines.append(f"| {n} | {biased['mean'][i]:.5f} | {biased['bias'][i]:.4f} | "
                     f"{biased['variance'][i]:.3g} | {biased['mse'][i]:.6g} |")
    one_d = summary["variance_reduction_1d"]
    lines += [
        "",
        f"## Variance reduction on the seed's integral (n = {one_d['n']})",
        "",
        "| method | variance | variance ratio vs uniform | variance slope "
        "| efficiency ratio vs uniform (measured T) |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, m in one_d["methods"].items():
        lines.append(f"| {name} | {m['variance']:.4g} | {m['variance_ratio_vs_uniform']:.4g} | "
                     f"{m['variance_loglog_slope']:.3f} | "
                     f"{m['efficiency_per_second_ratio_vs_uniform']:.4g} |")
    two_d = summary["variance_reduction_2d"]
    lines += [
        "",
        f"## Russian roulette and splitting (n = {two_d['n']}, {two_d['repetitions']} repetitions)",
        "",
        f"{two_d['integrand']}. Cost units: cheap factor {two_d['cheap_cost']:g}, expensive factor "
        f"{two_d['expensive_cost']:g}; efficiency = 1/(cost V).",
        "",
        "| method | mean ± half-width | variance | cost per estimate | efficiency ratio vs uniform |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, m in two_d["methods"].items():
        lines.append(f"| {name} | {m['mean']:.5f} ± {m['mean_half_width']:.5f} | {m['variance']:.4g} | "
                     f"{m['cost_per_estimate']:.1f} | {m['efficiency_ratio_vs_uniform']:.3f} |")
    lines += [
        "",
        "## Samplers (chi-square against the target pdf)",
        "",
        "| sampler | target | samples | chi2 | dof | p-value |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for name, s in summary["samplers"].items():
        lines.append(f"| {name} | {s['target']} | {s['samples']} | {s['statistic']:.1f} | "
                     f"{s['degrees_of_freedom']} | {s['p_value']:.3g} |")
    lines += ["", "Files: " + ", ".join(summary["files"]), ""]
    return "\n".join(lines)


def run_mc_study(
    out_dir: Path,
    seed: int = 0,
    quick: bool = False,
    log: Callable[[str], None] = print,
    *,
    plots: bool = True,
) -> dict:
    """Run every experiment, write the PNG plots, ``summary.json`` and ``summary.md`` into
    ``out_dir`` (created if missing), and return the summary dict.

    ``plots=False`` skips the PNGs (most of a quick run's time on a slow machine); the numbers are
    the same either way.
    """
    started = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    config = StudyConfig.for_run(quick)
    a, b = mc.SEED_INTERVAL

    estimators = _estimator_experiments(config, seed, log)
    samplers_summary, sampler_runs, hemisphere = _sampler_experiments(config, seed, log)
    summary: dict[str, Any] = {
        "seed": seed,
        "quick": quick,
        "confidence": CONFIDENCE,
        "integrand": {
            "formula": "f(x) = sin(u)/u * e^u, u = sqrt(pi^2 x / 10), on [0, 10]",
            "interval": [a, b],
            "exact": mc.SEED_EXACT,
            "single_sample_variance": _single_sample_variance(mc.seed_integrand, a, b),
        },
        "estimators": estimators,
        "variance_reduction_1d": _variance_reduction_1d(estimators),
        "variance_reduction_2d": _variance_reduction_2d(config, seed, log),
        "samplers": samplers_summary,
    }

    written = _write_plots(out_dir, summary, sampler_runs, hemisphere, log) if plots else []
    summary["files"] = written + ["summary.json", "summary.md"]
    summary["runtime_seconds"] = time.perf_counter() - started
    _write_atomically(out_dir / "summary.json", json.dumps(summary, indent=2).encode())
    _write_atomically(out_dir / "summary.md", _markdown(summary).encode())
    log(f"mc-study: done in {summary['runtime_seconds']:.1f} s")
    return summary


# --------------------------------------------------------------------------------------------
# CLI glue: `monte mc-study`
# --------------------------------------------------------------------------------------------


from .bench_args import add_mc_study_arguments as add_arguments  # noqa: E402,F401 - argparse only


def main(args: argparse.Namespace) -> int:
    """Entry point for `monte mc-study`; returns the process exit status."""
    summary = run_mc_study(args.output, seed=args.seed, quick=args.quick)
    print(f"wrote {len(summary['files'])} files to {args.output}")
    return 0
