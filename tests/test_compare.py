"""core.compare: the cross-check's statistics on synthetic noisy images with known truth (no Blender)."""

from __future__ import annotations

import numpy as np

from monte.core import compare as cmp


def noisy_pair(rng, bias: float = 0.0, shape=(48, 48, 3), k: int = 4):
    """Image a: truth + noise with its known variance; image b: mean of k noisy runs of truth * (1 + bias)."""
    # A smooth image (noise levels vary slowly, as in renders; the pooling assumes it).
    y, x = np.meshgrid(np.linspace(0, 1, shape[0]), np.linspace(0, 1, shape[1]), indexing="ij")
    truth = (0.2 + 0.8 * (0.5 + 0.5 * np.sin(3 * x + 2 * y)))[..., None] * np.array([1.0, 0.8, 0.6])
    sd_a = 0.05 * truth
    a = truth + rng.normal(size=shape) * sd_a
    runs = truth * (1 + bias) + rng.normal(size=(k,) + shape) * (0.1 * truth)
    b, var_b = cmp.runs_mean_and_variance(runs)
    return a, sd_a**2, b, var_b


def test_agreeing_images_agree_and_z_is_standard_normal():
    rng = np.random.default_rng(1)
    a, va, b, vb = noisy_pair(rng)
    c = cmp.compare(a, va, b, vb)
    agree, reasons = c.verdict()
    assert agree, reasons
    zs = c.z_stats()
    # Pooled variance (27+ degrees of freedom): close to a unit normal.
    assert abs(zs["mean"]) < 0.05 and 0.9 < zs["std"] < 1.1
    assert zs["frac_gt5"] == 0.0 and zs["frac_gt3"] < 0.01
    assert np.all(np.abs(c.difference) < 4 * c.sigma)


def test_unpooled_k4_variance_has_heavy_tails():
    """Why the pooling: z on the 3-degrees-of-freedom per-pixel estimate exceeds 3 far more often."""
    rng = np.random.default_rng(2)
    a, va, b, vb = noisy_pair(rng, shape=(64, 64, 3))
    y, x = np.meshgrid(np.linspace(0, 1, 64), np.linspace(0, 1, 64), indexing="ij")
    exact = (0.2 + 0.8 * (0.5 + 0.5 * np.sin(3 * x + 2 * y)))[..., None] * np.array([1.0, 0.8, 0.6])
    zero = np.zeros_like(exact)
    raw = cmp.compare(exact, zero, b, vb, pool=1).z_stats()  # b against the truth, its own variance only
    pooled = cmp.compare(exact, zero, b, vb, pool=3).z_stats()
    assert raw["frac_gt3"] > 0.03  # Student's t with 3 degrees of freedom: 5.8 %
    assert pooled["frac_gt3"] < 0.01 and pooled["frac_gt5"] < 1e-3  # t with ~27 degrees of freedom


def test_a_one_percent_bias_is_found():
    rng = np.random.default_rng(3)
    a, va, b, vb = noisy_pair(rng, bias=0.01, shape=(128, 128, 3))
    c = cmp.compare(a, va, b, vb)
    agree, reasons = c.verdict()
    assert not agree and any("mean differs" in r for r in reasons)
    assert np.allclose(c.relative_difference, -0.01, atol=0.003)


def test_a_local_difference_is_found_by_the_z_tail():
    rng = np.random.default_rng(4)
    a, va, b, vb = noisy_pair(rng, shape=(64, 64, 3))
    a[:8, :8] += 1.0  # 1.6 % of the pixels, far beyond noise; image mean +1.6 % x ~1 / 0.6
    c = cmp.compare(a, va, b, vb, rel_floor=0.5)  # a huge mean floor: only the z tail can catch it
    agree, reasons = c.verdict()
    assert not agree and any("5 sigma" in r for r in reasons)
    labels = np.zeros(a.shape[:2], int)
    labels[:8, :8] = 7
    rows = cmp.region_attribution(c, labels, {0: "rest", 7: "patch"}, a, b)
    assert rows[0]["name"] == "patch" and rows[0]["excess_chi2"] > 10 * abs(rows[1]["excess_chi2"])
    assert rows[0]["luma_difference_share"] > 0.3


def test_noise_free_equal_pixels_are_not_differences():
    img = np.full((8, 8, 3), 0.5)
    c = cmp.compare(img, np.zeros_like(img), img * (1 + 1e-7), np.zeros_like(img))
    assert c.verdict()[0] and np.all(np.isfinite(c.z))


def test_noise_cannot_hide_a_difference_above_the_cap():
    """Channel means 3 % apart with noise so large that 4 sigma is ~12 %: without the cap that would pass; the 1 %
    cap fails it, and says the noise only resolves ~12 %. A 0.8 % difference in the same noise passes."""
    truth = np.full((8, 8, 3), 0.5)
    big = np.full_like(truth, (0.03 * 0.5 * 8) ** 2)  # per-pixel variance: sigma of the mean 3 % of 0.5
    loose = cmp.compare(truth * 1.03, big, truth, np.zeros_like(truth), rel_cap=1.0)
    assert loose.verdict()[0] and np.allclose(loose.resolvable, 0.12)
    capped = cmp.compare(truth * 1.03, big, truth, np.zeros_like(truth))
    agree, reasons = capped.verdict()
    assert not agree and "capped at 1 %" in reasons[0] and "12.00 %" in reasons[0]
    assert cmp.compare(truth * 1.008, big, truth, np.zeros_like(truth)).verdict()[0]
    # a stated model gap (rel_floor) wins over the cap
    assert cmp.compare(truth * 1.015, big, truth, np.zeros_like(truth), rel_floor=0.02).verdict()[0]
