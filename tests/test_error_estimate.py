"""RenderSettings.error_estimate: a render keeps 2 variance groups per pixel (independently scrambled Sobol
sequences, whose spread is the unbiased estimate of each pixel's error: RenderResult.variance) only when
something reads that estimate; otherwise one scrambled sequence per pixel, as Cycles, which is less noisy at the
same samples. The calibration of the estimate itself (the 2-group path) is tests/test_variance.py's."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import memory, sampling
from monte.core.distributed import plan_units
from monte.core.film import TileFilm
from monte.core.render import merge_tile_samples, render, render_samples
from monte.core.settings import RenderSettings


def _settings(**kw) -> RenderSettings:
    base = dict(spp=16, seed=1, threads=1, tile_size=16, batch_paths=1024, filter_type="box", filter_width=1.0)
    base.update(kw)
    return RenderSettings(**base)


# ------------------------------------------------------------------------------------------ the group choice
def test_which_settings_keep_one_group_and_which_two():
    assert sampling.VARIANCE_GROUPS == 2
    assert RenderSettings().error_estimate is True and RenderSettings().variance_groups == 2  # core's default
    assert RenderSettings(error_estimate=False).variance_groups == 1
    for sampler in ("sobol", "stratified", "independent"):
        assert RenderSettings(sampler=sampler, error_estimate=False).validate().variance_groups == 1
    # adaptive sampling reads the estimate: refused without it, named in the message
    with pytest.raises(ValueError, match="adaptive sampling.*error_estimate=True"):
        RenderSettings(adaptive_threshold=0.01, error_estimate=False).validate()
    RenderSettings(adaptive_threshold=0.01, error_estimate=True).validate()
    with pytest.raises(ValueError, match="error_estimate must be True or False"):
        RenderSettings(error_estimate=1).validate()


def test_a_film_without_the_estimate_keeps_one_group_no_squares_and_refuses_a_variance():
    for kind in ("sobol", "stratified", "independent"):
        sampler = sampling.make_sampler(kind, 0, 16, groups=1)
        film = TileFilm(4, 2, aovs=False, sampler=sampler, error_estimate=False)
        assert film.groups == 1 and not film.squares
        assert film.nbytes == memory.FILM_NO_ESTIMATE_BYTES * 8
        rng = np.random.default_rng(3)
        values = rng.random((8 * 16, 3))
        pixel = np.repeat(np.arange(8), 16)
        film.add(pixel, values, np.tile(np.arange(16), 8))
        np.testing.assert_allclose(film.mean()[..., :3].reshape(8, 3), values.reshape(8, 16, 3).mean(axis=1),
                                   rtol=1e-5)
        with pytest.raises(ValueError, match="no error estimate"):
            film.variance_of_mean()
        with pytest.raises(ValueError, match="no error estimate"):
            film.active_pixels(0.01)
        with pytest.raises(ValueError, match="variance=None"):
            film.write_colour_images(np.zeros((2, 4, 4), np.float32), np.zeros((2, 4, 3), np.float32), 0, 0)
        # the colour written without a variance is the compiled write's, bit for bit, into a larger frame
        frame = np.zeros((5, 7, 4), np.float32)
        film.write_colour_images(frame, None, 2, 3)
        assert np.array_equal(frame[2:4, 3:7], film.combined_rgba())
        assert not frame[:2].any() and not frame[:, :3].any()


def test_memory_estimate_without_the_estimate():
    scene = scenes.cornell_box((64, 64))
    with_est = memory.estimate_render_memory(scene, _settings())
    without = memory.estimate_render_memory(scene, _settings(error_estimate=False))
    pixels = 64 * 64
    assert with_est.film == pixels * memory.FILM_BYTES and without.film == pixels * memory.FILM_NO_ESTIMATE_BYTES
    assert with_est.result - without.result == pixels * memory.RESULT_VARIANCE_BYTES


# ------------------------------------------------------------------------------------------------- renders
def test_a_render_without_the_estimate_has_no_variance_and_the_same_bits_on_any_thread_count():
    scene = scenes.cornell_box((40, 24))
    tiles = []
    one = render(scene, _settings(error_estimate=False), on_tile=tiles.append)
    assert one.variance is None and tiles and all(t.variance is None for t in tiles)
    two_threads = render(scene, _settings(error_estimate=False, threads=2))
    assert np.array_equal(one.color, two_threads.color) and np.array_equal(one.albedo, two_threads.albedo)
    # one sample per pixel (the film-less tile writer) too
    assert render(scene, _settings(error_estimate=False, spp=1)).variance is None
    # and the sequence really is another one than the grouped render's: sample i is point i of the one scramble
    grouped = render(scene, _settings())
    assert grouped.variance is not None and not np.array_equal(one.color, grouped.color)


def test_a_split_render_merges_to_the_same_bits_without_the_estimate():
    scene = scenes.cornell_box((32, 24))
    settings = _settings(spp=12, seed=7, error_estimate=False)
    whole = render(scene, settings)
    units = plan_units(scene, settings, 2, ranges_per_tile=3)
    assert len(units) > 4  # several sample ranges per tile
    parts = [part for unit in units for part in render_samples(scene, settings, unit)]
    merged = merge_tile_samples(scene, settings, parts)
    assert merged.variance is None
    for name in ("color", "albedo", "normal", "depth", "sample_count"):
        assert np.array_equal(getattr(merged, name), getattr(whole, name)), name
    # a film of the other setting cannot take these sums
    with pytest.raises(ValueError):
        merge_tile_samples(scene, settings.replace(error_estimate=True), parts)


def _seed_images(scene, seeds, **kw) -> np.ndarray:
    return np.stack([render(scene, _settings(seed=s, **kw)).color[..., :3].astype(np.float64) for s in seeds])


def test_one_group_matches_two_groups_mean_within_noise_and_is_less_noisy():
    # 24 seeds of a 24x24 Cornell box at 16 spp each way. The image means must agree within 4 standard errors
    # (from the seeds' spread: no bias from the single scramble), and the per-pixel variance over seeds, averaged
    # over the 576 pixels (relative standard error ~2 % each), must be lower with one group: the 2 groups' half-
    # size point sets measured 1.14x at 16 spp on a 16x16 Cornell box (docs/performance.md).
    scene = scenes.cornell_box((24, 24))
    seeds = range(100, 124)
    one = _seed_images(scene, seeds, error_estimate=False)
    two = _seed_images(scene, seeds, error_estimate=True)
    m1, m2 = one.mean(axis=(1, 2)), two.mean(axis=(1, 2))  # (seeds, 3) image means
    se = np.sqrt(m1.var(axis=0, ddof=1) / len(seeds) + m2.var(axis=0, ddof=1) / len(seeds))
    diff = m1.mean(axis=0) - m2.mean(axis=0)
    print(f"\nimage mean 1 group {m1.mean(axis=0)}, 2 groups {m2.mean(axis=0)}, z {diff / se}")
    assert np.all(np.abs(diff) < 4 * se)
    v1 = one.var(axis=0, ddof=1).mean()
    v2 = two.var(axis=0, ddof=1).mean()
    print(f"mean pixel variance over seeds: 1 group {v1:.4e}, 2 groups {v2:.4e}, ratio {v2 / v1:.3f}")
    assert v2 / v1 > 1.04
