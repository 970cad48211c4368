"""Tests for core.sampling (RNG, samplers, warps, frames) and core.filters (pixel filters).

Statistical tests use fixed seeds, so they are deterministic; thresholds are loose enough
(p > 1e-4) that a correct implementation passes with a wide margin, and every warp/filter
check is paired with a deliberately wrong pdf that must fail (p < 1e-6).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import trapezoid
import pytest
from scipy import stats

from monte.core import filters, sampling, warps

KINDS = sampling.SAMPLER_KINDS
P_OK = 1e-4
P_BAD = 1e-6


# ---------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------


def chi2_pvalue(observed: np.ndarray, expected: np.ndarray, n_total: int, min_expected: float = 5.0) -> float:
    """Chi-square p-value of histogram counts against expected counts.

    Bins with small expectation are pooled; the mass outside the histogram (samples that
    fell outside, and pdf mass the bins do not cover) is one more bin, so a pdf with the
    wrong normalisation fails too.
    """
    obs = np.asarray(observed, dtype=np.float64).ravel()
    exp = np.asarray(expected, dtype=np.float64).ravel()
    small = exp < min_expected
    o = list(obs[~small])
    e = list(exp[~small])
    if small.any():
        o.append(obs[small].sum())
        e.append(exp[small].sum())
    o_out = n_total - obs.sum()
    e_out = n_total - exp.sum()
    o.append(o_out)
    e.append(max(e_out, 1e-12))
    o, e = np.array(o), np.array(e)
    keep = ~((o == 0) & (e <= 1e-9))
    o, e = o[keep], np.maximum(e[keep], 1e-12)
    stat = float(np.sum((o - e) ** 2 / e))
    return float(stats.chi2.sf(stat, max(len(o) - 1, 1)))


def expected_2d(density, n_bins: int, n: int, sub: int = 8) -> np.ndarray:
    """Expected counts on an n_bins^2 grid over [0,1]^2 for a density on the square."""
    m = n_bins * sub
    c = (np.arange(m) + 0.5) / m
    s, t = np.meshgrid(c, c, indexing="ij")
    d = density(s.ravel(), t.ravel()).reshape(m, m)
    return d.reshape(n_bins, sub, n_bins, sub).mean(axis=(1, 3)) * (n / n_bins**2)


def hist_2d(s: np.ndarray, t: np.ndarray, n_bins: int) -> np.ndarray:
    ok = (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    h, _, _ = np.histogram2d(s[ok], t[ok], bins=n_bins, range=[[0, 1], [0, 1]])
    return h


def rand_u(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 2), dtype=np.float32)


def phi01(w: np.ndarray) -> np.ndarray:
    return (np.arctan2(w[:, 1], w[:, 0]) / (2 * np.pi)) % 1.0


def dir_from(z: np.ndarray, phi: np.ndarray) -> np.ndarray:
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


# ---------------------------------------------------------------------------------------
# hash RNG
# ---------------------------------------------------------------------------------------


def test_uniform_range_dtype_and_strictly_below_one():
    pix = np.arange(200_000, dtype=np.uint32)
    u = sampling.uniform(3, pix, np.uint32(5), 2)
    assert u.dtype == np.float32 and u.shape == (200_000,)
    assert u.min() >= 0.0 and u.max() < 1.0
    # the largest representable output is 1 - 2**-24 (never rounds to 1)
    top = sampling._to_float(np.array([0xFFFFFFFF], dtype=np.uint32))
    assert top[0] == np.float32(1 - 2**-24) and top[0] < 1.0


def test_uniform_is_pure_and_batch_independent():
    rng = np.random.default_rng(0)
    pix = rng.integers(0, 2**32, 100_000, dtype=np.uint64).astype(np.uint32)
    smp = rng.integers(0, 4096, 100_000).astype(np.uint32)
    a = sampling.uniform(11, pix, smp, 7)
    b = sampling.uniform(11, pix.copy(), smp.copy(), 7)
    assert np.array_equal(a, b)
    perm = rng.permutation(pix.size)
    assert np.array_equal(sampling.uniform(11, pix[perm], smp[perm], 7), a[perm])
    parts = np.concatenate([sampling.uniform(11, pix[i : i + 777], smp[i : i + 777], 7) for i in range(0, pix.size, 777)])
    assert np.array_equal(parts, a)
    # any integer dtype, same values
    assert np.array_equal(sampling.uniform(11, pix.astype(np.int64), smp.astype(np.int32), 7), a)
    # every input matters
    assert not np.array_equal(sampling.uniform(12, pix, smp, 7), a)
    assert not np.array_equal(sampling.uniform(11, pix, smp, 8), a)
    assert not np.array_equal(sampling.uniform(11, pix, smp + 1, 7), a)
    assert not np.array_equal(sampling.uniform(11, pix + 1, smp, 7), a)


def test_uniform_uniformity_and_decorrelation():
    n = 200_000
    pix = np.arange(n, dtype=np.uint32)
    u = sampling.uniform(1, pix, 0, 0)
    obs, _ = np.histogram(u, bins=100, range=(0, 1))
    assert chi2_pvalue(obs, np.full(100, n / 100), n) > P_OK
    # consecutive pixels, consecutive samples and consecutive dims look independent
    for a, b in (
        (u[:-1], u[1:]),
        (u, sampling.uniform(1, pix, 1, 0)),
        (u, sampling.uniform(1, pix, 0, 1)),
        (u, sampling.uniform(2, pix, 0, 0)),
    ):
        h = hist_2d(a.astype(np.float64), b.astype(np.float64), 20)
        assert chi2_pvalue(h, np.full((20, 20), a.size / 400), a.size) > P_OK


def test_hash_avalanche():
    rng = np.random.default_rng(5)
    x = rng.integers(0, 2**32, 20_000, dtype=np.uint64).astype(np.uint32)
    base = sampling.hash_u32(x, 17)
    for bit in (0, 7, 16, 31):
        flipped = sampling.hash_u32(x ^ np.uint32(1 << bit), 17)
        changed = np.unpackbits((base ^ flipped).view(np.uint8)).reshape(-1, 32).mean(axis=0)
        assert np.all(np.abs(changed - 0.5) < 0.03), (bit, changed)


# ---------------------------------------------------------------------------------------
# samplers: purity, determinism, refinement
# ---------------------------------------------------------------------------------------


def test_make_sampler_kinds_and_errors():
    assert sampling.DEFAULT_SAMPLER == "sobol"
    assert isinstance(sampling.make_sampler(), sampling.SobolSampler)
    assert isinstance(sampling.make_sampler("SOBOL_BURLEY", 1, 4), sampling.SobolSampler)
    assert isinstance(sampling.make_sampler("independent"), sampling.IndependentSampler)
    assert isinstance(sampling.make_sampler("stratified"), sampling.StratifiedSampler)
    with pytest.raises(ValueError, match="sampler kind"):
        sampling.make_sampler("halton")
    with pytest.raises(ValueError, match="spp"):
        sampling.make_sampler("sobol", 0, 0)


@pytest.mark.parametrize("kind", KINDS)
def test_sampler_pure_permutation_and_batch_independent(kind):
    rng = np.random.default_rng(1)
    n = 70_000  # more than one internal chunk
    pix = rng.integers(0, 1 << 22, n).astype(np.uint32)
    smp = rng.integers(0, 1 << 18, n).astype(np.uint32)  # also exercises the >= 2**16 path
    s1 = sampling.make_sampler(kind, seed=9, spp=64)
    s2 = sampling.make_sampler(kind, seed=9, spp=4096)  # spp never changes values
    for get in ("get_1d", "get_2d", "get_3d", "get_4d"):
        a = getattr(s1, get)(pix, smp, 5)
        assert a.dtype == np.float32
        assert a.min() >= 0.0 and a.max() < 1.0
        assert np.array_equal(a, getattr(s2, get)(pix, smp, 5))
        perm = rng.permutation(n)
        assert np.array_equal(getattr(s1, get)(pix[perm], smp[perm], 5), a[perm])
        cuts = [0, 1, 1000, 65_535, 65_536, 65_537, n]
        parts = [getattr(s1, get)(pix[i:j], smp[i:j], 5) for i, j in zip(cuts[:-1], cuts[1:])]
        assert np.array_equal(np.concatenate(parts), a)
    assert not np.array_equal(sampling.make_sampler(kind, seed=10).get_2d(pix, smp, 5), s1.get_2d(pix, smp, 5))
    assert not np.array_equal(s1.get_2d(pix, smp, 6), s1.get_2d(pix, smp, 5))


@pytest.mark.parametrize("kind", KINDS)
def test_sampler_shapes_and_broadcasting(kind):
    s = sampling.make_sampler(kind, 3, 16)
    pix = np.arange(12, dtype=np.uint32).reshape(3, 4)
    assert s.get_1d(pix, 2, 0).shape == (3, 4)
    assert s.get_2d(pix, 2, 0).shape == (3, 4, 2)
    assert s.get_2d(7, np.arange(16), 0).shape == (16, 2)
    row = s.get_2d(7, np.arange(16), 0)
    assert np.array_equal(row, s.get_2d(np.full(16, 7), np.arange(16, dtype=np.int64), 0))
    # more samples refine: the first 8 samples are the same whatever else is asked for
    assert np.array_equal(s.get_2d(7, np.arange(8), 0), row[:8])
    if kind != "stratified":
        assert np.array_equal(s.get_1d(pix, 2, 4), s.get_2d(pix, 2, 4)[..., 0])
    assert s.get_2d([], [], 0).shape == (0, 2)
    with pytest.raises(TypeError):
        s.get_1d(np.array([0.5]), 0, 0)


def test_independent_sampler_is_the_hash_rng():
    s = sampling.make_sampler("independent", 5)
    pix = np.arange(1000)
    u = s.get_4d(pix, 7, 2)
    for c in range(4):
        assert np.array_equal(u[:, c], sampling.uniform(5, pix, 7, 4 * 2 + c))


# ---------------------------------------------------------------------------------------
# samplers: uniformity, decorrelation, stratification
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_sampler_uniformity_chi2(kind):
    s = sampling.make_sampler(kind, 4, 16)
    pix = np.repeat(np.arange(4096, dtype=np.uint32), 16)
    smp = np.tile(np.arange(16, dtype=np.uint32), 4096)
    n = pix.size
    for dim in (0, 13):
        u = s.get_2d(pix, smp, dim).astype(np.float64)
        h = hist_2d(u[:, 0], u[:, 1], 32)
        assert chi2_pvalue(h, np.full((32, 32), n / 1024), n) > P_OK
        u1 = s.get_1d(pix, smp, dim + 100)
        obs, _ = np.histogram(u1, bins=64, range=(0, 1))
        assert chi2_pvalue(obs, np.full(64, n / 64), n) > P_OK
    # 3rd/4th components
    u4 = s.get_4d(pix, smp, 3).astype(np.float64)
    h = hist_2d(u4[:, 2], u4[:, 3], 32)
    assert chi2_pvalue(h, np.full((32, 32), n / 1024), n) > P_OK


@pytest.mark.parametrize("kind", KINDS)
def test_sampler_dims_and_pixels_decorrelated(kind):
    """Different dim ids (padding), components, and neighbouring pixels look independent."""
    s = sampling.make_sampler(kind, 4, 16)
    pix = np.repeat(np.arange(4096, dtype=np.uint32), 16)
    smp = np.tile(np.arange(16, dtype=np.uint32), 4096)
    n = pix.size
    a = s.get_2d(pix, smp, 2).astype(np.float64)
    b = s.get_2d(pix, smp, 3).astype(np.float64)
    c = s.get_2d(pix + 1, smp, 2).astype(np.float64)
    d = s.get_4d(pix, smp, 2).astype(np.float64)
    for x, y in ((a[:, 0], b[:, 0]), (a[:, 1], b[:, 0]), (a[:, 0], c[:, 0]), (d[:, 0], d[:, 2]), (d[:, 1], d[:, 3])):
        h = hist_2d(x, y, 16)
        assert chi2_pvalue(h, np.full((16, 16), n / 256), n) > P_OK


def test_stratified_each_block_of_four_covers_all_strata():
    s = sampling.make_sampler("stratified", 2, 64)
    pix = np.repeat(np.arange(500, dtype=np.uint32), 64)
    smp = np.tile(np.arange(64, dtype=np.uint32), 500)
    for dim in (0, 1, 9):
        u = s.get_2d(pix, smp, dim)
        stratum = (u[:, 0] >= 0.5).astype(int) + 2 * (u[:, 1] >= 0.5).astype(int)
        blocks = np.sort(stratum.reshape(-1, 4), axis=1)
        assert np.all(blocks == np.arange(4))
        q = np.floor(s.get_1d(pix, smp, dim + 50) * 4).astype(int)
        assert np.all(np.sort(q.reshape(-1, 4), axis=1) == np.arange(4))
    # the stratum order is not the same in every pixel/block/dim (decorrelation)
    u0 = s.get_2d(pix, smp, 0)
    u1 = s.get_2d(pix, smp, 1)
    st0 = (u0[:, 0] >= 0.5) + 2 * (u0[:, 1] >= 0.5)
    st1 = (u1[:, 0] >= 0.5) + 2 * (u1[:, 1] >= 0.5)
    assert len(np.unique(st0.reshape(-1, 4), axis=0)) == 24
    assert 0.2 < np.mean(st0 == st1) < 0.3  # independent strata: ~1/4 agree


def _is_net(pts: np.ndarray, k: int) -> bool:
    """Exactly one point in every elementary interval of volume 2**-k (dims 0-1)."""
    q = (pts.astype(np.float64) * 2**24).astype(np.int64)
    for a in range(k + 1):
        b = k - a
        cell = (q[:, 0] >> (24 - a)) * (1 << b) + (q[:, 1] >> (24 - b))
        if np.unique(cell).size != (1 << k):
            return False
    return True


def test_sobol_first_2k_samples_are_nets():
    s = sampling.make_sampler("sobol", 5, 1024)
    for pixel in (0, 1, 77, 123_456):
        for dim in (0, 1, 6, 40):
            for k in range(0, 11):
                assert _is_net(s.get_2d(pixel, np.arange(1 << k), dim), k), (pixel, dim, k)
            # any aligned block of 2**k samples is a net too
            assert _is_net(s.get_2d(pixel, np.arange(3 << 6, 4 << 6), dim), 6)
            # 1-D: one point per interval of length 2**-k
            x = s.get_1d(pixel, np.arange(256), dim + 1000)
            assert np.unique(np.floor(x * 256).astype(int)).size == 256
    # beyond the 16-bit fast path
    assert _is_net(s.get_2d(3, np.arange(1 << 17), 2), 17)
    # independent is (almost surely) not a net
    ind = sampling.make_sampler("independent", 5)
    assert not _is_net(ind.get_2d(0, np.arange(256), 0), 8)


def test_sobol_variance_groups_are_independent_scrambled_sequences():
    # groups=G: sample i is point i // G of group i mod G; group 0 is the single-scramble sequence itself, the
    # others are scrambled differently, and each group's first 2**k points are a net.
    single = sampling.make_sampler("sobol", 5, 1024)
    grouped = sampling.make_sampler("sobol", 5, 1024, groups=4)
    for pixel in (0, 77, 123_456):
        for dim in (0, 6):
            i = np.arange(4 * 256)
            pts = grouped.get_2d(pixel, i, dim)
            assert np.array_equal(pts[0::4], single.get_2d(pixel, np.arange(256), dim))
            for g in range(4):
                for k in range(0, 9):
                    assert _is_net(pts[g::4][: 1 << k], k), (pixel, dim, g, k)
            assert not np.array_equal(pts[1::4], pts[0::4]) and not np.array_equal(pts[2::4], pts[1::4])
            assert not _is_net(pts[:256], 8)  # the groups together are not one net: they are independent
    assert np.array_equal(grouped.variance_group(np.arange(10)), np.arange(10) % 4)
    strat = sampling.make_sampler("stratified", 5, 64, groups=4)
    assert np.array_equal(strat.variance_group(np.arange(20)), (np.arange(20) // 4) % 4)
    assert np.array_equal(strat.get_2d(3, np.arange(64), 2), sampling.make_sampler("stratified", 5).get_2d(
        3, np.arange(64), 2))  # groups of whole blocks change no value
    ind = sampling.make_sampler("independent", 5, 64, groups=4)
    assert ind.iid and np.array_equal(ind.get_2d(3, np.arange(64), 2),
                                      sampling.make_sampler("independent", 5).get_2d(3, np.arange(64), 2))
    for bad in (0, 3, 512):
        with pytest.raises(ValueError, match="variance groups"):
            sampling.make_sampler("sobol", 0, 1, groups=bad)


# Exact outputs (as 24-bit integers k, value = k * 2**-24) of get_4d for fixed inputs,
# computed by the NumPy implementation that preceded the compiled kernels: any change of
# bits (which would change every rendered image) fails here.  Sample indices cover the
# one-byte, 17-bit and 32-bit Sobol table paths; pixels the full uint32 range.
_PIN_PIX = [0, 1, 12345, 2**32 - 1]
_PIN_SMP = [0, 1, 70000, 2**31 + 5]
_PINNED = {
    ("sobol", 0, 0): [[9716246, 9202080, 3421760, 16597025], [11487410, 13995584, 10732916, 1650613],
                      [15608323, 16306805, 10496111, 13976333], [2841833, 10146559, 14058097, 9385288]],
    ("sobol", 7, 13): [[16698001, 5577791, 659912, 13605886], [1750658, 8624143, 13344401, 11552603],
                       [15478837, 8307377, 53198, 8253968], [5643409, 15940699, 3775786, 15338419]],
    ("stratified", 7, 13): [[5740685, 9101119, 13965648, 9581711], [8261025, 5153083, 3257263, 9097521],
                            [2454587, 224350, 1856239, 7279092], [7217532, 12130586, 4278192, 7168330]],
    ("independent", 7, 13): [[11481370, 1425023, 11154081, 2386207], [16522051, 10306167, 6514526, 1417827],
                             [4909175, 448700, 3712479, 14558184], [14435065, 7483956, 8556385, 14336661]],
}


@pytest.mark.parametrize("kind, seed, dim", list(_PINNED))
def test_sampler_bits_are_pinned(kind, seed, dim):
    s = sampling.make_sampler(kind, seed)
    u = s.get_4d(np.array(_PIN_PIX, dtype=np.uint32), np.array(_PIN_SMP, dtype=np.uint32), dim)
    expected = np.array(_PINNED[kind, seed, dim], dtype=np.float64) * 2.0**-24
    assert u.dtype == np.float32
    assert np.array_equal(u.astype(np.float64), expected), (u * 2**24).astype(np.int64).tolist()
    # the same rows come back one path at a time and inside a long batch (several kernel blocks)
    for i in range(4):
        assert np.array_equal(s.get_4d(_PIN_PIX[i], _PIN_SMP[i], dim)[0], u[i])
    long_pix = np.repeat(np.array(_PIN_PIX, dtype=np.uint32), 700)
    long_smp = np.repeat(np.array(_PIN_SMP, dtype=np.uint32), 700)
    assert np.array_equal(s.get_4d(long_pix, long_smp, dim)[::700], u)


def test_sobol_matrices_match_joe_kuo_reference():
    from scipy.stats import qmc

    v = sampling.sobol_matrices()
    m = 10
    idx = np.arange(1 << m, dtype=np.uint64)
    pts = np.zeros((1 << m, 4))
    for d in range(4):
        acc = np.zeros(1 << m, dtype=np.uint64)
        for k in range(m):
            acc ^= ((idx >> np.uint64(k)) & np.uint64(1)) * np.uint64(v[d, k])
        pts[:, d] = acc / 2.0**32
    ref = qmc.Sobol(4, scramble=False).random_base2(m)  # Gray-code order: compare as sets
    key = lambda p: p[np.lexsort(p.T[::-1])]  # noqa: E731
    assert np.array_equal(key(pts), key(ref))


def test_sobol_beats_independent_on_smooth_integrand():
    def f(x, y):
        return np.exp(-4 * ((x - 0.3) ** 2 + (y - 0.6) ** 2)) + x * y

    g = lambda a: math.sqrt(math.pi) / 4 * (math.erf(2 * (1 - a)) + math.erf(2 * a))  # noqa: E731
    exact = g(0.3) * g(0.6) + 0.25
    n_pix, spp = 1024, 64
    pix = np.repeat(np.arange(n_pix, dtype=np.uint32), spp)
    smp = np.tile(np.arange(spp, dtype=np.uint32), n_pix)
    rmse = {}
    for kind in KINDS:
        u = sampling.make_sampler(kind, 8, spp).get_2d(pix, smp, 3).astype(np.float64)
        est = f(u[:, 0], u[:, 1]).reshape(n_pix, spp).mean(axis=1)
        rmse[kind] = float(np.sqrt(np.mean((est - exact) ** 2)))
    assert rmse["sobol"] < 0.25 * rmse["independent"], rmse
    assert rmse["stratified"] < 0.9 * rmse["independent"], rmse


# ---------------------------------------------------------------------------------------
# warps: the compiled ones the light and BSDF kernels run (core.warps), through their batch forms
# ---------------------------------------------------------------------------------------

N_WARP = 200_000
BINS = 20
UP = np.array([0.0, 0.0, 1.0])


def pdf_cos_hemisphere(w):
    return np.maximum(w[..., 2], 0.0) / np.pi


def pdf_uniform_hemisphere(w):
    return np.where(w[..., 2] >= 0, 1 / (2 * np.pi), 0.0)


def in_frame(w, normal):
    """Directions w (N, 3) in the frame warps.onb builds about the unit normal: (w.t, w.b, w.n)."""
    t, b = warps.onb_many(np.broadcast_to(normal, w.shape))
    return np.stack([(w * t).sum(1), (w * b).sum(1), w @ normal], axis=-1)


def _hemisphere_p(samples, pdf_fn):
    w = samples.astype(np.float64)
    obs = hist_2d(w[:, 2], phi01(w), BINS)
    exp = expected_2d(lambda s, t: pdf_fn(dir_from(s, 2 * np.pi * t)) * 2 * np.pi, BINS, len(w))
    return chi2_pvalue(obs, exp, len(w))


TILTED = np.array([0.48, -0.6, 0.64])  # unit


@pytest.mark.parametrize("frame", ["local (BSDF)", "about +z (lights)", "about a tilted normal (lights)"])
def test_cosine_hemisphere_warps(frame):
    u = rand_u(N_WARP, 1)
    if frame == "local (BSDF)":
        w = warps.cos_hemisphere_local_many(u)
    elif frame == "about +z (lights)":
        w = warps.cos_hemisphere_many(UP, u)
    else:
        w = in_frame(warps.cos_hemisphere_many(TILTED, u), TILTED)
    assert w.shape == (N_WARP, 3)
    assert np.allclose(np.linalg.norm(w, axis=1), 1, atol=1e-12) and w[:, 2].min() >= 0
    assert _hemisphere_p(w, pdf_cos_hemisphere) > P_OK
    assert _hemisphere_p(w, pdf_uniform_hemisphere) < P_BAD
    cos_t = w[:10, 2]
    assert np.allclose([warps.cos_hemisphere_pdf(c) for c in cos_t], pdf_cos_hemisphere(w[:10]), rtol=1e-15)


def test_cosine_hemisphere_is_the_thesis_formula():
    u = rand_u(1000, 2).astype(np.float64)
    w = warps.cos_hemisphere_local_many(u)
    theta = np.arccos(np.sqrt(1 - u[:, 0]))
    assert np.allclose(w[:, 2], np.cos(theta), atol=1e-12)
    assert np.allclose(phi01(w), u[:, 1], atol=1e-9)
    # the lights' warp about +z is the same map (the frame about +z is the identity)
    assert np.array_equal(warps.cos_hemisphere_many(UP, u), w)


def test_uniform_sphere():
    ws = warps.sphere_many(rand_u(N_WARP, 4))
    assert np.allclose(np.linalg.norm(ws, axis=1), 1, atol=1e-12)

    def p_sphere(pdf_fn):
        obs = hist_2d((ws[:, 2] + 1) / 2, phi01(ws), BINS)
        exp = expected_2d(lambda s, t: pdf_fn(dir_from(2 * s - 1, 2 * np.pi * t)) * 4 * np.pi, BINS, N_WARP)
        return chi2_pvalue(obs, exp, N_WARP)

    assert p_sphere(lambda w: np.full(w.shape[:-1], warps.sphere_pdf())) > P_OK
    assert p_sphere(pdf_uniform_hemisphere) < P_BAD


@pytest.mark.parametrize("cos_max", [0.7, -0.3, 0.999])
def test_uniform_cone(cos_max):
    w = warps.cone_many(UP, 1 - cos_max, rand_u(N_WARP, 5))
    assert w[:, 2].min() >= cos_max - 1e-12
    assert np.allclose(np.linalg.norm(w, axis=1), 1, atol=1e-12)

    def p(cos_pdf):
        obs = hist_2d((w[:, 2] - cos_max) / (1 - cos_max), phi01(w), BINS)
        jac = (1 - cos_max) * 2 * np.pi
        exp = expected_2d(lambda s, t: np.where(cos_max + s * (1 - cos_max) >= cos_pdf,
                                                warps.cone_pdf(1 - cos_pdf), 0.0) * jac, BINS, N_WARP)
        return chi2_pvalue(obs, exp, N_WARP)

    assert p(cos_max) > P_OK
    assert p(cos_max - 0.01 * (1 - cos_max)) < P_BAD  # pdf of a slightly wider cone
    assert warps.cone_pdf(1 - cos_max) == pytest.approx(1 / (2 * np.pi * (1 - cos_max)), rel=1e-15)


def test_uniform_cone_per_path_cos_max():
    cm = np.linspace(-0.5, 0.9, 1000)
    w = warps.cone_many(UP, 1 - cm, rand_u(1000, 6))
    assert np.all(w[:, 2] >= cm - 1e-12)


@pytest.mark.parametrize("radius", [1.0, 0.05])
def test_uniform_disk(radius):
    d = warps.disk_many(radius, rand_u(N_WARP, 7)) / radius
    r2 = (d**2).sum(axis=1)
    assert r2.max() <= 1 + 1e-12

    def p(pdf_fn):
        obs = hist_2d(r2, phi01(d), BINS)

        def density(s, t):  # (r^2, phi / 2 pi) -> area element pi ds dt
            r, phi = np.sqrt(s), 2 * np.pi * t
            return pdf_fn(np.stack([r * np.cos(phi), r * np.sin(phi)], -1)) * np.pi

        exp = expected_2d(density, BINS, N_WARP)
        return chi2_pvalue(obs, exp, N_WARP)

    assert p(lambda q: np.where((q**2).sum(-1) <= 1, 1 / np.pi, 0.0)) > P_OK
    assert p(lambda q: (1 - (q**2).sum(-1)) * 2 / np.pi) < P_BAD
    assert np.array_equal(warps.disk_many(radius, np.zeros((1, 2))), np.zeros((1, 2)))  # centre, no NaN


def test_uniform_triangle():
    b = warps.triangle_many(rand_u(N_WARP, 9))
    assert b.shape == (N_WARP, 2) and b.min() >= 0 and b.sum(axis=1).max() <= 1 + 1e-12
    n = 16
    obs = hist_2d(b[:, 0], b[:, 1], n)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    inside_frac = np.where(i + j < n - 1, 1.0, np.where(i + j == n - 1, 0.5, 0.0))
    cell = 1.0 / n**2
    # uniform on the triangle b1, b2 >= 0, b1 + b2 <= 1 of area 1/2: density 2
    exp = inside_frac * cell * 2.0 * N_WARP
    assert chi2_pvalue(obs, exp, N_WARP) > P_OK
    wrong = inside_frac * cell * 2 * (1 - (i + 0.5) / n) * 1.5 * N_WARP  # a non-uniform "pdf"
    assert chi2_pvalue(obs, wrong, N_WARP) < P_BAD


@pytest.mark.parametrize("dist", [3.0, 50.0, 1e4])
def test_sphere_cap(dist):
    """A sphere light seen from outside: the cone the lights sample (sample_cone with
    one_minus_cos_from_sin2(r^2 / d^2)) holds exactly the directions that hit the sphere, uniformly."""
    rng = np.random.default_rng(10)
    center = np.array([0.3, -1.0, 2.0])
    radius = 1.0
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    p = center - dist * axis
    omc = warps.one_minus_cos_from_sin2(radius**2 / dist**2)
    wi = warps.cone_many(axis, omc, rand_u(N_WARP, 11))
    assert np.allclose(np.linalg.norm(wi, axis=1), 1, atol=1e-12)
    assert warps.cone_pdf(omc) == pytest.approx(1 / (2 * np.pi * (1 - math.sqrt(1 - radius**2 / dist**2))),
                                                rel=1e-6 if dist < 100 else 1e-3)
    miss = np.linalg.norm(np.cross(wi, center - p), axis=1)  # ray-to-centre distance
    assert np.all(miss <= radius * (1 + 1e-9))
    assert np.all(wi @ (center - p) > 0)
    assert miss.max() > radius * (1 - 1e-3)  # and the cone is not narrower than the sphere
    if dist < 10:  # the histogram is meaningful where the cone is resolved finely
        loc = in_frame(wi, axis)
        s = (1 - loc[:, 2]) / omc
        obs = hist_2d(1 - s, phi01(loc), BINS)
        exp = expected_2d(lambda s_, t_: np.full(s_.shape, 1.0), BINS, N_WARP)
        assert chi2_pvalue(obs, exp, N_WARP) > P_OK
        # the pdf of a cone 2% wider is rejected
        assert chi2_pvalue(obs, exp * (omc / (1.02 * omc)), N_WARP) < P_BAD


@pytest.mark.parametrize("sin2", [0.5, 1e-4, 1e-12, 1e-30])
def test_one_minus_cos_keeps_tiny_cones(sin2):
    # 1 - sqrt(1 - s) = s/2 + s^2/8 + s^3/16 + ...: the naive form is 0 below s ~ 1e-16 (a star's cone)
    series = sin2 / 2 + sin2**2 / 8 + sin2**3 / 16 + 5 * sin2**4 / 128
    want = 1 - math.sqrt(1 - sin2) if sin2 > 0.1 else series
    assert warps.one_minus_cos_from_sin2(sin2) == pytest.approx(want, rel=1e-14)


# ---------------------------------------------------------------------------------------
# frames
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 2e-6)])
def test_onb_orthonormal_right_handed(dtype, tol):
    """onb (lights, float64) and onb_f32 (the shading frames of surface hits, float32)."""
    rng = np.random.default_rng(13)
    n = rng.normal(size=(10_000, 3))
    n = np.concatenate([n, [[0, 0, 1], [0, 0, -1], [-0.0, -0.0, -1], [1, 0, 0], [0, -1, 0], [1e-8, 0, -1]]])
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(dtype)
    t, b = warps.onb_many(n)
    assert t.dtype == dtype and b.dtype == dtype
    for v in (t, b):
        assert np.allclose(np.linalg.norm(v, axis=1), 1, atol=tol)
    assert np.allclose((t * b).sum(1), 0, atol=tol)
    assert np.allclose((t * n).sum(1), 0, atol=tol)
    assert np.allclose((b * n).sum(1), 0, atol=tol)
    assert np.allclose(np.cross(t, b), n, atol=tol)
    if dtype == np.float32:
        return
    # around(): polar angle measured from the axis, azimuth from t towards b
    for k in (0, 5, 10_003):
        w = warps.around(*n[k], math.cos(0.3), math.sin(0.3), 1.1)
        assert np.dot(w, n[k]) == pytest.approx(math.cos(0.3), abs=1e-12)
        assert math.atan2(np.dot(w, b[k]), np.dot(w, t[k])) == pytest.approx(1.1, abs=1e-12)


# ---------------------------------------------------------------------------------------
# pixel filters
# ---------------------------------------------------------------------------------------

FILTER_CASES = [
    ("box", 1.0),
    ("box", 1.5),
    ("tent", 1.0),
    ("gaussian", 1.5),
    ("gaussian", 0.5),
    ("blackman-harris", 1.5),
    ("blackman-harris", 3.0),
]


def _filter_p(x: np.ndarray, radius: float, pdf_1d, n_bins: int = 64, sub: int = 32) -> float:
    edges = np.linspace(-radius, radius, n_bins + 1)
    obs, _ = np.histogram(x, bins=edges)
    xs = (np.arange(n_bins * sub) + 0.5) / (n_bins * sub) * 2 * radius - radius
    mass = pdf_1d(xs).astype(np.float64).reshape(n_bins, sub).mean(axis=1) * (2 * radius / n_bins)
    return chi2_pvalue(obs, mass * x.size, x.size)


@pytest.mark.parametrize("kind,width", FILTER_CASES)
def test_filter_samples_match_pdf_and_support(kind, width):
    f = filters.PixelFilter(kind, width)
    n = 300_000
    off = f.sample(rand_u(n, 14))
    assert off.dtype == np.float32 and off.shape == (n, 2)
    assert np.all(np.abs(off) <= f.radius)
    for axis in (0, 1):
        assert _filter_p(off[:, axis].astype(np.float64), f.radius, f.pdf_1d) > P_OK
    # x and y independent (separable)
    h, _, _ = np.histogram2d(off[:, 0], off[:, 1], bins=8, range=[[-f.radius, f.radius]] * 2)
    mx = h.sum(1) / n
    my = h.sum(0) / n
    assert chi2_pvalue(h, np.outer(mx, my) * n, n) > P_OK
    # extreme u stay inside the support, and the pdf integrates to 1
    ext = f.sample(np.array([[0, 1 - 2**-24], [2**-24, 0.5]], dtype=np.float32))
    assert np.all(np.abs(ext) <= f.radius) and np.isclose(abs(ext[0, 0]), f.radius, rtol=1e-6)
    xs = np.linspace(-f.radius, f.radius, 200_001)
    assert np.isclose(trapezoid(f.pdf_1d(xs), xs), 1, atol=2e-3 if kind == "box" else 1e-5)
    assert f.pdf_1d(np.array([f.radius * 1.001]))[0] == 0


def test_filter_wrong_pdf_fails():
    n = 300_000
    g = filters.PixelFilter("gaussian", 1.0)  # radius 1.5
    bh = filters.PixelFilter("blackman-harris", 1.5)  # radius 1.5, different shape
    x = g.sample(rand_u(n, 15))[:, 0].astype(np.float64)
    assert _filter_p(x, 1.5, g.pdf_1d) > P_OK
    assert _filter_p(x, 1.5, bh.pdf_1d) < P_BAD
    tent = filters.PixelFilter("tent", 1.0)
    box = filters.PixelFilter("box", 2.0)  # same radius 1
    xt = tent.sample(rand_u(n, 16))[:, 0].astype(np.float64)
    assert _filter_p(xt, 1.0, box.pdf_1d) < P_BAD


def test_filter_width_conventions():
    assert filters.PixelFilter("box", 1.5).radius == 0.75
    assert filters.PixelFilter("gaussian", 1.5).radius == 2.25
    assert filters.PixelFilter("blackman-harris", 1.5).radius == 1.5
    assert filters.PixelFilter("tent", 1.5).radius == 1.5
    assert filters.PixelFilter("BLACKMAN_HARRIS", 2).kind == "blackman-harris"
    assert filters.PixelFilter("Gaussian", 2).kind == "gaussian"
    assert filters.PixelFilter("triangle", 2).kind == "tent"
    # Gaussian: sigma = width / 4 (Cycles: exp(-2 (x * 6 / (3 w))^2))
    g = filters.PixelFilter("gaussian", 2.0)
    x = g.sample(rand_u(400_000, 17)).astype(np.float64)
    assert abs(x.std() - 0.5) < 0.003
    # Blackman-Harris peak 1 at 0, ~0 at +-width
    bh = filters.PixelFilter("blackman-harris", 2.0)
    assert np.isclose(bh.evaluate(np.array([0.0]))[0], 1.0, atol=1e-5)
    assert bh.evaluate(np.array([2.0]))[0] < 1e-4


def _cycles_filter_table(kind: str, width: float, size: int = 1024) -> np.ndarray:
    """Re-derivation of Cycles' film filter table (scene/film.cpp + util/math_cdf.cpp)."""
    if kind == "box":
        func = lambda v, w: np.ones_like(v)  # noqa: E731
    elif kind == "gaussian":
        width *= 3.0
        func = lambda v, w: np.exp(-2.0 * (v * 6.0 / w) ** 2)  # noqa: E731
    else:
        width *= 2.0

        def func(v, w):
            v = 2 * np.pi * (v / w + 0.5)
            return 0.35875 - 0.48829 * np.cos(v) + 0.14128 * np.cos(2 * v) - 0.01168 * np.cos(3 * v)

    res_cdf = size - 1  # util_cdf_inverted evaluates the CDF with resolution - 1 samples
    rng_ = width * 0.5
    xs = rng_ * np.arange(res_cdf) / (res_cdf - 1)
    cdf = np.concatenate([[0.0], np.cumsum(np.abs(func(xs, width)))])
    cdf /= cdf[-1]
    half = (size - 1) // 2
    table = np.zeros(size)
    for i in range(half + 1):
        x = i / half
        index = int(np.searchsorted(cdf, x, side="right"))  # upper_bound
        if index < len(cdf) - 1:
            t = (x - cdf[index]) / (cdf[index + 1] - cdf[index])
        else:
            t, index = 0.0, len(cdf) - 1
        y = (index + t) / (size - 1) * (2 * rng_)
        table[half + i] = 0.5 * (1 + y)
        table[half - i] = 0.5 * (1 - y)
    return table


@pytest.mark.parametrize(
    "kind,width", [("box", 1.0), ("box", 2.0), ("gaussian", 1.5), ("blackman-harris", 1.5), ("blackman-harris", 2.5)]
)
def test_filter_matches_cycles_table(kind, width):
    table = _cycles_filter_table(kind, width)
    u = np.linspace(0.01, 0.99, 197)
    j = u * (len(table) - 1)  # kernel/util/lookup_table.h: lookup_table_read
    i0 = np.floor(j).astype(int)
    cyc = table[i0] + (table[i0 + 1] - table[i0]) * (j - i0) - 0.5  # offset from pixel centre
    ours = filters.PixelFilter(kind, width).sample_1d(u.astype(np.float32))
    assert np.max(np.abs(ours - cyc)) < 0.01 * max(width, 1.0), np.max(np.abs(ours - cyc))


def test_filter_tables_are_built_once_per_kind_and_width():
    """Every render call makes its PixelFilter; the inverse CDF tables are built once per process for each kind and
    width (filters._inverse_tables), read-only, and are the tables that kind and width build."""
    a, b = filters.PixelFilter("blackman-harris", 1.5), filters.PixelFilter("BLACKMAN_HARRIS", 1.5)
    assert a._inv is b._inv and a._tails[0] is b._tails[0] and a._tails[1] is b._tails[1]
    assert not a._inv.flags.writeable
    for kind, width in (("blackman-harris", 1.5), ("blackman-harris", 2.0), ("gaussian", 1.5), ("gaussian", 0.5)):
        f = filters.PixelFilter(kind, width)
        built = filters._inverse_tables.__wrapped__(kind, width)
        for got, want in zip((f._inv, *f._tails), built):
            np.testing.assert_array_equal(got, want)
        assert abs(float(f._inv[0]) + f.radius) < 1e-3 * f.radius  # u = 0 and 1: the support's ends
        assert abs(float(f._inv[-1]) - f.radius) < 1e-3 * f.radius
    assert not np.array_equal(filters.PixelFilter("blackman-harris", 2.0)._inv, a._inv)
    assert not np.array_equal(filters.PixelFilter("gaussian", 1.0)._inv, a._inv)


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "wide"])
def test_filter_bad_width_raises(bad):
    with pytest.raises(ValueError, match="filter width"):
        filters.PixelFilter("box", bad)


def test_filter_bad_kind_raises():
    with pytest.raises(ValueError, match="pixel filter type"):
        filters.PixelFilter("mitchell", 1.0)
    with pytest.raises(ValueError):
        filters.PixelFilter("box", 1.0).sample(np.zeros((4, 3), np.float32))
