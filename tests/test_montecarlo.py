"""Monte Carlo estimators, variance reduction, samplers and the `mc-study` command.

Everything runs at fixed seeds, so each statistical assertion is deterministic; the confidence
levels are stated so that a change of seed would still pass with the stated probability.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from scipy.integrate import trapezoid
import pytest

from monte.lab import mc_study
from monte.lab import montecarlo as mc

CONFIDENCE = 0.999
Z = mc.normal_quantile(CONFIDENCE)  # 3.29
P_VALUE_FLOOR = 1e-3  # a correct sampler fails this at a random seed with probability 0.1%
f = mc.seed_integrand
A, B = mc.SEED_INTERVAL
FITTED_PDF = mc.PiecewiseLinearPdf.fit(f, A, B, 4)


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


# ---------------------------------------------------------------- the seed's integrand


def _cumulative_trapezoid(pdf, x: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.diff(x) * (pdf(x[1:]) + pdf(x[:-1])) / 2)])


def test_seed_integrand_integrates_to_the_seeds_exact_value():
    assert mc.SEED_EXACT == pytest.approx(24.45963551499059, abs=1e-12)
    x = np.linspace(A, B, 200_001)
    assert trapezoid(f(x), x) == pytest.approx(mc.SEED_EXACT, rel=1e-8)
    assert f(np.array([0.0]))[0] == pytest.approx(1.0)


def test_seed_cdf_is_the_integral_of_the_density():
    x = np.linspace(A, B, 100_001)
    np.testing.assert_allclose(mc.seed_integrand_cdf(x), _cumulative_trapezoid(mc.seed_density, x), atol=1e-8)
    assert mc.seed_density(np.array([-1.0, 11.0])).tolist() == [0.0, 0.0]


# ---------------------------------------------------------------- unbiased estimators

UNBIASED_1D = {
    "uniform": lambda n, r, g: mc.uniform_estimates(f, A, B, n, r, g),
    "stratified": lambda n, r, g: mc.stratified_estimates(f, A, B, n, r, g),
    "importance": lambda n, r, g: mc.importance_estimates(f, FITTED_PDF, n, r, g),
}


@pytest.mark.parametrize("name", UNBIASED_1D)
def test_unbiased_estimator_mean_contains_exact_value_at_99_9_percent(name):
    estimates = UNBIASED_1D[name](64, 400, rng(1))
    stats = mc.summarize_repetitions(estimates, mc.SEED_EXACT, CONFIDENCE)
    assert stats.contains(mc.SEED_EXACT), (stats.mean, stats.mean_half_width)


@pytest.mark.parametrize(
    "method", [mc.uniform_2d_estimates, mc.russian_roulette_estimates, mc.splitting_estimates])
def test_roulette_and_splitting_are_unbiased_at_99_9_percent(method):
    g = mc.ExpensiveCheapIntegrand()
    result = method(g, 64, 400, rng(2))
    stats = mc.summarize_repetitions(result.estimates, g.exact, CONFIDENCE)
    assert stats.contains(g.exact), (stats.mean, stats.mean_half_width)


def test_uniform_variance_falls_as_one_over_n():
    ns = np.array([4, 16, 64, 256])
    stats = [mc.summarize_repetitions(UNBIASED_1D["uniform"](n, 400, rng(n)), mc.SEED_EXACT, CONFIDENCE)
             for n in ns]
    variances = np.array([s.variance for s in stats])
    # Standard error of each variance from its own repetitions; the slope's tolerance follows.
    standard_errors = np.array([s.variance_half_width for s in stats]) / Z
    slope, slope_error = mc.loglog_slope(ns, variances, standard_errors)
    assert abs(slope + 1.0) <= Z * slope_error, (slope, slope_error)
    assert slope_error < 0.05  # the tolerance is tight enough to mean something


def test_stratified_and_importance_sampling_have_lower_variance_than_uniform():
    variance = {name: mc.summarize_repetitions(est(64, 400, rng(3)), mc.SEED_EXACT).variance
                for name, est in UNBIASED_1D.items()}
    assert variance["stratified"] < variance["uniform"] / 10
    assert variance["importance"] < variance["uniform"] / 10


def test_roulette_and_splitting_are_more_efficient_than_uniform_in_cost_units():
    g = mc.ExpensiveCheapIntegrand()

    def efficiency(result: mc.CostedEstimates) -> float:
        return 1.0 / (result.cost_per_estimate * result.estimates.var())

    uniform = efficiency(mc.uniform_2d_estimates(g, 64, 1000, rng(4)))
    assert efficiency(mc.russian_roulette_estimates(g, 64, 1000, rng(5))) > 1.3 * uniform
    assert efficiency(mc.splitting_estimates(g, 64, 1000, rng(6))) > 2.0 * uniform


def test_biased_estimator_mse_is_variance_plus_bias_squared():
    estimates = mc.biased_max_estimates(f, A, B, 16, 500, rng(7))
    stats = mc.summarize_repetitions(estimates, mc.SEED_EXACT, CONFIDENCE)
    # An identity of the plug-in sample statistics, not an approximation.
    assert stats.mse == pytest.approx(stats.variance + stats.bias**2, rel=1e-12)
    assert abs(stats.bias) > 100 * stats.mean_half_width  # bias is not noise
    assert stats.mean < 0.5 * 3.3626  # never above half the integrand's maximum


def test_run_repetitions_batches_without_changing_the_count():
    estimates = mc.run_repetitions(UNBIASED_1D["uniform"], 1000, 37, rng(8), max_elements=4000)
    assert estimates.shape == (37,)


# ---------------------------------------------------------------- samplers against their pdfs


def test_piecewise_linear_pdf_is_normalised_and_its_cdf_matches():
    pdf = mc.PiecewiseLinearPdf(np.array([0.0, 1.0, 2.0, 4.0]), np.array([0.0, 2.0, 2.0, 1.0]))
    x = np.linspace(0.0, 4.0, 40_001)
    assert trapezoid(pdf.pdf(x), x) == pytest.approx(1.0, rel=1e-8)
    np.testing.assert_allclose(pdf.cdf(x), _cumulative_trapezoid(pdf.pdf, x), atol=1e-8)
    samples = pdf.sample(rng(9), 20_000)  # zero start value and a flat segment: the edge cases
    assert samples.min() >= 0.0 and samples.max() <= 4.0
    assert mc.histogram_chi_square(samples, pdf.cdf, np.linspace(0, 4, 41)).p_value > P_VALUE_FLOOR


def test_piecewise_linear_pdf_rejects_bad_input():
    with pytest.raises(ValueError):
        mc.PiecewiseLinearPdf(np.array([0.0, 1.0]), np.array([-1.0, 1.0]))
    with pytest.raises(ValueError):
        mc.PiecewiseLinearPdf(np.array([1.0, 0.0]), np.array([1.0, 1.0]))


def _rejection_samples(n: int) -> np.ndarray:
    envelope = mc.envelope_constant(mc.seed_density, FITTED_PDF.pdf, A, B)
    result = mc.rejection_sample(mc.seed_density, FITTED_PDF.sample, FITTED_PDF.pdf, envelope, n, rng(10))
    return result.samples


def _metropolis_samples(n: int) -> np.ndarray:
    generator = rng(11)
    return mc.metropolis_hastings(mc.seed_density, generator.uniform(A, B, n), 3.0, 100, generator).samples


ONE_D_SAMPLERS = {
    "inverse transform, piecewise linear": (lambda n: FITTED_PDF.sample(rng(12), n), FITTED_PDF.cdf),
    "acceptance-rejection": (_rejection_samples, mc.seed_integrand_cdf),
    "metropolis-hastings": (_metropolis_samples, mc.seed_integrand_cdf),
}
EDGES = np.linspace(A, B, 31)


# The chi-square tests' resolving power. A pdf "5 % wrong" is 5 % too high over the lower half of the probability
# mass and 5 % too low over the upper half (wrong_cdf). Binned, that adds a noncentrality of about
# N x 0.05^2 = 250 at N = 100 000 samples to a statistic with ~29 degrees of freedom: its mean ~280 against
# a 0.1 % critical value of 58, so the 5 %-wrong pdf fails with certainty (> 6 standard deviations) while a
# right one fails with probability 0.1 % (P_VALUE_FLOOR). At the former 20 000 samples the noncentrality was
# 50, and a 5 %-wrong pdf passed about 1 time in 10.
CHI_SQUARE_SAMPLES = 100_000
WRONG_BY = 0.05


def wrong_cdf(cdf, eps: float = WRONG_BY):
    """The cdf of a density eps too high (relative) where cdf < 1/2 and eps too low above: still normalised."""
    def wrong(x):
        c = np.asarray(cdf(x), dtype=float)
        return np.where(c <= 0.5, (1 + eps) * c, 0.5 * (1 + eps) + (1 - eps) * (c - 0.5))
    return wrong


@pytest.mark.parametrize("name", ONE_D_SAMPLERS)
def test_sampler_passes_chi_square_against_its_pdf(name):
    draw, cdf = ONE_D_SAMPLERS[name]
    samples = draw(CHI_SQUARE_SAMPLES)
    assert samples.shape == (CHI_SQUARE_SAMPLES,)
    assert mc.histogram_chi_square(samples, cdf, EDGES).p_value > P_VALUE_FLOOR


@pytest.mark.parametrize("name", ONE_D_SAMPLERS)
def test_sampler_fails_chi_square_against_a_5_percent_wrong_pdf(name):
    draw, cdf = ONE_D_SAMPLERS[name]
    assert mc.histogram_chi_square(draw(CHI_SQUARE_SAMPLES), wrong_cdf(cdf), EDGES).p_value < P_VALUE_FLOOR


def test_cosine_hemisphere_passes_against_its_pdf_and_fails_against_a_5_percent_wrong_one():
    theta, phi = mc.sample_cosine_hemisphere(rng(13), CHI_SQUARE_SAMPLES)
    assert mc.cosine_hemisphere_chi_square(theta, phi).p_value > P_VALUE_FLOOR
    wrong = wrong_cdf(mc.cosine_hemisphere_theta_cdf)
    assert mc.cosine_hemisphere_chi_square(theta, phi, wrong).p_value < P_VALUE_FLOOR
    assert mc.cosine_hemisphere_chi_square(theta, phi, mc.uniform_hemisphere_theta_cdf).p_value < 1e-6
    directions = mc.directions_from_angles(theta, phi)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    assert directions[:, 2].min() >= 0.0
    # E[cos θ] over the cosine-weighted hemisphere is 2/3.
    cosines = directions[:, 2]
    assert cosines.mean() == pytest.approx(2.0 / 3.0, abs=Z * cosines.std() / math.sqrt(cosines.size))


def test_rejection_sampler_refuses_an_envelope_that_does_not_bound_the_target():
    with pytest.raises(ValueError, match="envelope"):
        mc.rejection_sample(mc.seed_density, FITTED_PDF.sample, FITTED_PDF.pdf, 0.5, 1000, rng(14))


def test_metropolis_hastings_refuses_a_start_outside_the_support():
    with pytest.raises(ValueError):
        mc.metropolis_hastings(mc.seed_density, np.array([-1.0, 5.0]), 1.0, 10, rng(15))


def test_chi_square_refuses_bins_that_miss_part_of_the_support():
    with pytest.raises(ValueError):
        mc.chi_square_test(np.array([10, 10]), np.array([0.3, 0.3]))


# ---------------------------------------------------------------- the study command


def _without_timings(value):
    """Drop every key that holds a timing or a number derived from one (they all contain 'second')."""
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if "second" not in k}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def test_quick_study_writes_its_files_with_sane_numbers(tmp_path):
    summary = mc_study.run_mc_study(tmp_path, seed=0, quick=True, log=lambda message: None)

    for name in summary["files"]:
        assert (tmp_path / name).stat().st_size > 0, name
    pngs = [name for name in summary["files"] if name.endswith(".png")]
    assert len(pngs) >= 10
    assert all((tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for name in pngs)
    assert not list(tmp_path.glob(".*.tmp"))  # atomic writes leave no temporaries
    assert json.loads((tmp_path / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert "| uniform |" in (tmp_path / "summary.md").read_text()

    estimators = summary["estimators"]
    for name in ("uniform", "stratified", "importance"):
        assert all(estimators[name]["exact_in_interval"]), name
    uniform = estimators["uniform"]
    assert abs(uniform["variance_loglog_slope"] + 1) <= Z * uniform["variance_slope_standard_error"]
    assert estimators["stratified"]["variance_loglog_slope"] < -2.5
    biased = estimators["biased_max"]
    np.testing.assert_allclose(
        biased["mse"], np.array(biased["variance"]) + np.square(biased["bias"]), rtol=1e-12)
    assert biased["mean"][-1] == pytest.approx(biased["limit"], rel=1e-3)

    one_d = summary["variance_reduction_1d"]["methods"]
    assert one_d["stratified"]["variance_ratio_vs_uniform"] > 10
    assert one_d["importance"]["variance_ratio_vs_uniform"] > 10
    two_d = summary["variance_reduction_2d"]["methods"]
    assert all(method["exact_in_interval"] for method in two_d.values())
    assert two_d["russian_roulette"]["efficiency_ratio_vs_uniform"] > 1
    assert two_d["splitting"]["efficiency_ratio_vs_uniform"] > 1

    samplers = summary["samplers"]
    for name, result in samplers.items():
        if name.endswith("wrong_pdf"):
            assert result["p_value"] < 1e-6
        else:
            assert result["p_value"] > P_VALUE_FLOOR, name


def test_study_is_deterministic_for_a_seed(tmp_path):
    def numbers(folder: str, seed: int):
        mc_study.run_mc_study(tmp_path / folder, seed=seed, quick=True, log=lambda message: None, plots=False)
        return _without_timings(json.loads((tmp_path / folder / "summary.json").read_text()))

    first = numbers("first", 0)
    assert numbers("second", 0) == first
    assert numbers("other", 1)["estimators"]["uniform"]["mean"] != first["estimators"]["uniform"]["mean"]


def test_cli_arguments_and_main(tmp_path, monkeypatch):
    parser = argparse.ArgumentParser()
    mc_study.add_arguments(parser)
    args = parser.parse_args(["-o", str(tmp_path), "--seed", "3", "--quick"])
    assert (args.output, args.seed, args.quick) == (tmp_path, 3, True)
    assert parser.parse_args(["--output", "x"]).seed == 0
    with pytest.raises(SystemExit):
        parser.parse_args([])

    calls = []
    def fake_run(out_dir, seed, quick):
        calls.append((out_dir, seed, quick))
        return {"files": []}

    monkeypatch.setattr(mc_study, "run_mc_study", fake_run)
    assert mc_study.main(args) == 0
    assert calls == [(tmp_path, 3, True)]
