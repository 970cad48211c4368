"""The variance Monte reports for each pixel's mean (RenderResult.variance, the `variance` pass) is the variance of
its estimate: checked against the measured seed-to-seed variance of many renders, for each sampler.

A 16x16 Cornell box at 16 spp is rendered with SEEDS seeds. For the image mean (per channel) and for the pixel
means (averaged over pixels) the test compares

    ratio = measured seed-to-seed variance / mean over seeds of the reported variance

with 1. The measured variance s^2 from S seeds has, for normal data, Var(s^2) = 2 sigma^4 / (S - 1); with heavy
tails (a rare bright path) it is (mu4 - sigma^4 (S - 3) / (S - 1)) / S, which the test estimates from the
renders themselves (fourth central moment), so a relative standard error of sqrt(2 / (S - 1)) = 0.10 at
S = 200 for the image mean, and far less for the pixel means (averaged over 256 nearly independent pixels).
The reported variance's own sampling error (mean over S seeds) is added in quadrature. The ratio must be within
Z = 4 standard errors of 1: for the image mean about +-0.4, so a variance estimate off by more than ~40 % (a
standard error off by ~20 %) fails; for the pixel means it is tighter (+-0.15-0.3).

The control: the same renders with the former estimate (one Sobol scramble per pixel, s^2 / n over its samples,
which treats quasi-random samples as independent) must fail: its ratio is about 0.25.
"""

from __future__ import annotations

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import sampling
from monte.core.render import render
from monte.core.settings import RenderSettings

SEEDS = 200
SPP = 16
Z = 4.0


def render_seeds(sampler: str, seeds: int = SEEDS) -> tuple[np.ndarray, np.ndarray]:
    """(images, reported variances), each (seeds, 16, 16, 3) float64."""
    images, variances = [], []
    for seed in range(seeds):
        settings = RenderSettings(spp=SPP, seed=seed, sampler=sampler, threads=2, filter_type="box",
                                  filter_width=1.0, aovs=False)
        result = render(scenes.cornell_box((16, 16)), settings)
        images.append(result.color[..., :3])
        variances.append(result.variance)
    return np.asarray(images, np.float64), np.asarray(variances, np.float64)


def variance_and_its_variance(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample variance over axis 0 and the estimated variance of that sample variance: the fourth-moment
    formula (any distribution with a finite fourth moment), at least the normal 2 sigma^4 / (S - 1)."""
    s = x.shape[0]
    dev = x - x.mean(axis=0)
    var = (dev**2).sum(axis=0) / (s - 1)
    m4 = (dev**4).mean(axis=0)
    return var, np.maximum((m4 - var**2 * (s - 3) / (s - 1)) / s, 2 * var**2 / (s - 1))


def calibration(images: np.ndarray, variances: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{"image": (ratio (3,), standard error (3,)), "pixels": (ratio (3,), standard error (3,))}."""
    s = images.shape[0]
    pixels = images.shape[1] * images.shape[2]
    # image mean, per channel
    measured, measured_var = variance_and_its_variance(images.mean(axis=(1, 2)))
    reported_each = variances.sum(axis=(1, 2)) / pixels**2  # (S, 3)
    reported = reported_each.mean(axis=0)
    rel_se = np.sqrt(measured_var / measured**2 + reported_each.var(axis=0, ddof=1) / s / reported**2)
    out = {"image": (measured / reported, measured / reported * rel_se)}
    # pixel means: measured per-pixel variances averaged over pixels (pixels are independent estimates)
    pix_measured, pix_measured_var = variance_and_its_variance(images.reshape(s, pixels, 3))
    measured = pix_measured.mean(axis=0)
    measured_var = pix_measured_var.sum(axis=0) / pixels**2
    reported_each = variances.reshape(s, pixels, 3).mean(axis=1)
    reported = reported_each.mean(axis=0)
    rel_se = np.sqrt(measured_var / measured**2 + reported_each.var(axis=0, ddof=1) / s / reported**2)
    out["pixels"] = (measured / reported, measured / reported * rel_se)
    return out


def calibrated(ratio: np.ndarray, se: np.ndarray) -> bool:
    return bool(np.all(np.abs(ratio - 1.0) <= Z * se))


@pytest.mark.parametrize("sampler", ["sobol", "stratified", "independent"])
def test_reported_variance_matches_seed_to_seed_variance(sampler):
    cal = calibration(*render_seeds(sampler))
    for what, (ratio, se) in cal.items():
        print(f"{sampler} {what}: measured/reported {np.round(ratio, 3)} +- {np.round(se, 3)}")
        # the tolerance is what says which error this test detects: it must stay well below the naive error
        assert np.all(Z * se < 0.5), f"{what}: too few seeds to resolve a 2x error ({se})"
        assert calibrated(ratio, se), f"{sampler} {what}: measured/reported variance {ratio} (+- {se}) is not 1"


def test_naive_variance_fails_the_calibration_for_sobol(monkeypatch):
    # One Sobol scramble per pixel and s^2 / n, as before the variance groups: overstates the error ~4x.
    # 60 seeds are plenty here: the ratio is ~0.25 +- 0.05, its 4-sigma band reaches ~0.45, far from 1.
    import monte.core.render as render_module

    monkeypatch.setattr(sampling, "VARIANCE_GROUPS", 1)
    monkeypatch.setattr(render_module, "VARIANCE_GROUPS", 1, raising=False)  # where render imports it by name
    cal = calibration(*render_seeds("sobol", seeds=60))
    ratio, se = cal["image"]
    print(f"naive sobol image: measured/reported {np.round(ratio, 3)} +- {np.round(se, 3)}")
    assert not calibrated(ratio, se)
    assert np.all(ratio < 0.5)


def test_film_group_estimate_is_the_spread_of_group_means():
    from monte.core.film import TileFilm

    film = TileFilm(2, 1, aovs=False, sampler=sampling.make_sampler("sobol", 0, 8, groups=4))
    # pixel 0: 8 samples, groups 0..3 get (1, 3), (2, 2), (5, 7), (0, 0); pixel 1: a single sample
    values = np.array([1, 2, 5, 0, 3, 2, 7, 0], np.float64)
    film.add(np.zeros(8, np.int64), np.repeat(values[:, None], 3, axis=1), np.arange(8))
    film.add(np.array([1]), np.ones((1, 3)), np.array([0]))
    group_means = np.array([2.0, 2.0, 6.0, 0.0])
    expected = group_means.var(ddof=1) / 4
    var = film.variance_of_mean()
    np.testing.assert_allclose(var[0, 0], expected, rtol=1e-6)
    assert np.all(var[0, 1] == 0.0)  # one sample: no estimate
    np.testing.assert_allclose(film.mean()[0, 0], values.mean(), rtol=1e-6)
    assert film.count.tolist() == [8, 1]
    # fewer than 2 groups with samples (the first stratified block): s^2 / n, not zero
    strat = TileFilm(1, 1, aovs=False, sampler=sampling.make_sampler("stratified", 0, 4, groups=4))
    strat.add(np.zeros(4, np.int64), np.repeat(values[:4, None], 3, axis=1), np.arange(4))
    np.testing.assert_allclose(strat.variance_of_mean()[0, 0], values[:4].var(ddof=1) / 4, rtol=1e-6)
    with pytest.raises(ValueError, match="sample"):
        film.add(np.zeros(1, np.int64), np.ones((1, 3)))
