"""The film's float32 storage: memory per pixel and exact-enough sums at any sample count.

The film keeps float32 sums of deviations from a per-pixel shift, each pass of samples summed in float64 and
folded in once (core.film). These tests feed it a million samples per pixel, in passes as a render does, and
compare its mean and variance estimates with the same quantities computed from the samples in float64.
"""

import numpy as np
import pytest

from monte.core import sampling
from monte.core.film import TileFilm
from monte.core.builtin_scenes import cornell_box, spheres_under_sky
from monte.core.memory import FILM_AOV_BYTES, FILM_BYTES, FILM_FEATURE_BYTES, estimate_render_memory
from monte.core.settings import SAMPLERS, RenderSettings

SAMPLES = 1_000_000
PASS = 4096  # samples per pixel and pass: 244 folds, the order of a long render's passes per tile


def _film_bytes(film: TileFilm) -> int:
    return sum(v.nbytes for v in vars(film).values() if isinstance(v, np.ndarray))


@pytest.mark.parametrize("aovs, features", [(False, False), (True, False), (True, True)])
@pytest.mark.parametrize("kind", SAMPLERS)
def test_film_bytes_per_pixel_match_the_memory_estimate(aovs, features, kind):
    sampler = sampling.make_sampler(kind, 0, 16, groups=sampling.VARIANCE_GROUPS)
    # a render's film keeps no AOVs (their sums live in the frame's AOV images); render_samples()' films do
    film, handed_on = TileFilm(16, 8, False, sampler, features), TileFilm(16, 8, aovs, sampler, features)
    scene = cornell_box((16, 8))
    estimate = estimate_render_memory(scene, RenderSettings(spp=16, sampler=kind, aovs=aovs,
                                                            denoising_features=features))
    assert _film_bytes(film) == film.nbytes == estimate.film
    colour = {"sobol": 12 + 2 * 12 + 4, "stratified": 12 + 2 * 12 + 4 + 12, "independent": 12 + 12 + 4 + 12}[kind]
    assert film.nbytes == (colour + (FILM_FEATURE_BYTES if features else 0)) * 16 * 8
    assert handed_on.nbytes == film.nbytes + (FILM_AOV_BYTES if aovs else 0) * 16 * 8
    # shift, 2 group sums, the count: with the AOVs and the variance (float64 sums took 200 B per pixel with the
    # AOVs, stored group counts and squares 120, the AOV sums in the film 96, 4 variance groups 64); Sobol's film
    # keeps no squares
    assert FILM_BYTES == 40 and FILM_AOV_BYTES == 32


def test_a_render_sums_its_aovs_in_the_frame_and_its_films_keep_40_bytes_per_pixel(monkeypatch):
    """The films a render makes (counted as they are made) keep the colour only, with AOVs on; the AOV images are
    the bits a film's own AOV sums give: those of render_samples() (films that keep the AOVs) merged."""
    from monte.core import render as render_module

    made = []

    class CountedFilm(TileFilm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append((self.pixels, self.nbytes))

    monkeypatch.setattr(render_module, "TileFilm", CountedFilm)
    scene = spheres_under_sky((24, 16))  # sky above the horizon: pixels that hit nothing (depth 1e10)
    settings = RenderSettings(spp=8, tile_size=8, batch_paths=1 << 10, threads=1, aovs=True,
                              adaptive_threshold=0.05, adaptive_min_samples=4)
    local = render_module.render(scene, settings)
    assert len(made) == 6 and all(nbytes == FILM_BYTES * pixels for pixels, nbytes in made)
    made.clear()
    parts = render_module.render_samples(scene, settings, {ti: (0, 8) for ti in range(6)})
    assert len(made) == 6 and all(nbytes == (FILM_BYTES + FILM_AOV_BYTES) * pixels for pixels, nbytes in made)
    merged = render_module.merge_tile_samples(scene, settings, parts)
    assert (local.depth == 1e10).any() and (local.depth < 1e10).any()
    for name in ("color", "variance", "albedo", "normal", "depth", "sample_count"):
        assert getattr(local, name).tobytes() == getattr(merged, name).tobytes(), name
    assert local.sample_count.min() < 8  # adaptive sampling stopped some tiles early (their AOVs finished then)


def _feed(film: TileFilm, values: np.ndarray, pass_size: int) -> None:
    """values (pixels, samples, 3): each pixel's samples in order, pass_size of each pixel's per add()."""
    pixels, samples, _ = values.shape
    for s0 in range(0, samples, pass_size):
        chunk = values[:, s0:s0 + pass_size]
        k = chunk.shape[1]
        film.add(np.repeat(np.arange(pixels), k), chunk.reshape(-1, 3),
                 np.tile(np.arange(s0, s0 + k), pixels))


@pytest.mark.parametrize("sampler_kind", ["sobol", "independent"])
def test_a_constant_pixel_has_an_exact_mean_and_zero_variance_after_a_million_samples(sampler_kind):
    sampler = sampling.make_sampler(sampler_kind, 0, SAMPLES, groups=sampling.VARIANCE_GROUPS)
    film = TileFilm(3, 1, aovs=False, sampler=sampler)
    value = np.array([0.1, 3.7e-3, 1234.567], np.float32)  # none exact in binary: float32 sums would drift
    levels = np.stack([value, value * np.float32(0.3), np.full(3, np.float32(7.0))])
    per_pass = np.broadcast_to(levels[:, None, :], (3, PASS, 3))
    for s0 in range(0, SAMPLES, PASS):
        k = min(PASS, SAMPLES - s0)
        film.add(np.repeat(np.arange(3), k), per_pass[:, :k].reshape(-1, 3), np.tile(np.arange(s0, s0 + k), 3))
    assert film.count.tolist() == [SAMPLES] * 3
    np.testing.assert_array_equal(film.mean()[0], levels)
    assert np.all(film.variance_of_mean() == 0.0)


def _grouped_reference(values: np.ndarray, groups: np.ndarray, g: int) -> np.ndarray:
    """float64 grouped variance of the mean (core.film's formula) of values (pixels, n, 3)."""
    n = values.shape[1]
    m = values.mean(axis=1)
    out = np.zeros((values.shape[0], 3))
    for k in range(g):
        sel = values[:, groups == k]
        out += sel.shape[1] * (sel.mean(axis=1) - m) ** 2
    return out / ((g - 1) * n)


def test_a_noisy_pixel_keeps_its_mean_and_variance_after_a_million_samples():
    """Uniform noise of known variance on a large mean (1000 + U(0, 1): variance 1/12), where float32 sums of
    the samples themselves, or of their squares, would lose the variance entirely."""
    rng = np.random.default_rng(7)
    pixels, g = 2, sampling.VARIANCE_GROUPS
    values = (np.float32(1000.0) + rng.random((pixels, SAMPLES, 3), dtype=np.float32)).astype(np.float32)
    v64 = values.astype(np.float64)
    sobol = TileFilm(pixels, 1, aovs=False, sampler=sampling.make_sampler("sobol", 0, SAMPLES, groups=g))
    iid = TileFilm(pixels, 1, aovs=False, sampler=sampling.make_sampler("independent", 0, SAMPLES, groups=g))
    _feed(sobol, values, PASS)
    _feed(iid, values, PASS)
    mean = v64.mean(axis=1)
    # the mean to float32 rounding (2^-24 relative: 6e-5 at 1000)
    np.testing.assert_allclose(sobol.mean()[0], mean, rtol=1.2e-7, atol=0)
    np.testing.assert_allclose(iid.mean()[0], mean, rtol=1.2e-7, atol=0)
    # s^2 / n against float64, and against the known variance 1/12: the relative sd of s^2 for uniform noise is
    # sqrt(0.8 / 1e6) = 0.09 %, so 0.5 % is over 5 sigma
    naive = v64.var(axis=1, ddof=1) / SAMPLES
    np.testing.assert_allclose(iid.variance_of_mean()[0], naive, rtol=1e-4)
    np.testing.assert_allclose(iid.variance_of_mean()[0] * SAMPLES, 1 / 12, rtol=5e-3)
    # the grouped estimate against float64 from the same samples: its group means differ by ~3e-4, which the
    # float32 deviation sums must resolve
    grouped = _grouped_reference(v64, np.arange(SAMPLES) % g, g)
    np.testing.assert_allclose(sobol.variance_of_mean()[0], grouped, rtol=1e-3)


def test_adding_a_pass_in_chunks_or_whole_gives_the_same_bits():
    """A pass reaches the film in chunks of whole pixels (a render's segments) or as one pass's raw sums (a
    split render's merge): both fold the same values."""
    rng = np.random.default_rng(3)
    sampler = sampling.make_sampler("sobol", 0, 64, groups=4)
    whole, merged = TileFilm(4, 2, True, sampler, True), TileFilm(4, 2, True, sampler, True)
    capture = TileFilm(4, 2, True, sampler, True)
    for s0 in (0, 16, 32):
        if s0:
            capture.capture_passes()
        for chunk in (np.arange(0, 3), np.arange(3, 8)):
            pix = np.repeat(chunk, 16)
            smp = np.tile(np.arange(s0, s0 + 16), len(chunk))
            rad = rng.random((len(pix), 3)).astype(np.float32) * 5
            alb, nor = rng.random((len(pix), 3)), rng.random((len(pix), 3)) - 0.5
            depth = np.where(rng.random(len(pix)) < 0.2, np.inf, rng.random(len(pix)) * 10)
            for film in (whole, capture):
                film.add(pix, rad, smp)
                film.add_aovs(pix, alb, nor, depth)
                film.add_features(pix, alb, nor)
        if s0 == 0:
            merged.set_state({k: v.copy() for k, v in capture.state().items()})
        else:
            merged.add_sums(capture.take_pass())
    for name, arr in whole.state().items():
        np.testing.assert_array_equal(merged.state()[name], arr, err_msg=name)
    with pytest.raises(ValueError, match="film sums hold"):
        merged.add_sums({"group_sum": np.zeros((8, 4, 3))})
    with pytest.raises(ValueError, match="not capturing passes"):
        whole.take_pass()


@pytest.mark.parametrize("kind", ["sobol", "stratified"])
def test_group_counts_follow_from_the_sample_count_and_samples_out_of_order_are_refused(kind):
    """The film keeps one count per pixel and derives its samples per variance group; a pass that does not
    continue where the pixel's samples ended would make those wrong, so it is refused."""
    sampler = sampling.make_sampler(kind, 0, 64, groups=sampling.VARIANCE_GROUPS)
    film = TileFilm(2, 1, aovs=False, sampler=sampler)
    film.add(np.repeat([0, 1], [7, 3]), np.ones((10, 3)), np.concatenate([np.arange(7), np.arange(3)]))
    groups = sampler.variance_group(np.arange(7))
    g = sampling.VARIANCE_GROUPS
    assert film.group_counts().tolist() == [np.bincount(groups, minlength=g).tolist(),
                                            np.bincount(groups[:3], minlength=g).tolist()]
    with pytest.raises(ValueError, match="each pixel's samples must arrive in order, sample 0 first"):
        film.add(np.array([1]), np.ones((1, 3)), np.array([4]))  # sample 3 skipped: sample 4 is in another group
    assert film.count.tolist() == [7, 3]


def test_a_pixel_outside_the_tile_is_refused_before_the_compiled_sums_touch_memory():
    film = TileFilm(2, 1, aovs=True, sampler=sampling.make_sampler("sobol", 0, 4, groups=4))
    with pytest.raises(ValueError, match=r"film: pixel index out of range \[0, 2\) for a 2x1 tile"):
        film.add(np.array([0, 2]), np.ones((2, 3)), np.array([0, 0]))
    with pytest.raises(ValueError, match=r"out of range \[0, 2\)"):
        film.add_aovs(np.array([-1]), np.ones((1, 3)), np.ones((1, 3)), np.ones(1))
    assert film.count.tolist() == [0, 0] and not film.albedo.any()


def test_a_tile_shown_before_it_is_final_carries_the_aovs_of_its_samples_so_far():
    """on_tile gets each tile after every pass; its AOVs (summed in the frame, not the film) are those of the
    samples so far: equal, bit for bit, to the final AOVs of a render that stops at that sample count (the same
    passes over the tile), and the frame's running sums are left intact (the final images equal render_samples()
    merged)."""
    from monte.core import render as render_module

    scene = spheres_under_sky((64, 64))
    kwargs = dict(tile_size=32, batch_paths=2048, threads=1, aovs=True)  # 2 samples per pass over a 32x32 tile
    shown: list = []

    def keep(tile):
        if tile.samples == 4:
            shown.append((tile.x0, tile.y0, tile.albedo.copy(), tile.normal.copy(), tile.depth.copy()))

    full = render_module.render(scene, RenderSettings(spp=8, **kwargs), on_tile=keep)
    half = render_module.render(scene, RenderSettings(spp=4, **kwargs))
    assert len(shown) == 4
    for x, y, albedo, normal, depth in shown:
        sl = (slice(y, y + 32), slice(x, x + 32))
        assert albedo.tobytes() == half.albedo[sl].tobytes()
        assert normal.tobytes() == half.normal[sl].tobytes()
        assert depth.tobytes() == half.depth[sl].tobytes()
        assert (albedo > 0).any() and (depth < 1e10).any()
    parts = render_module.render_samples(scene, RenderSettings(spp=8, **kwargs), {ti: (0, 8) for ti in range(4)})
    merged = render_module.merge_tile_samples(scene, RenderSettings(spp=8, **kwargs), parts)
    for name in ("albedo", "normal", "depth"):
        assert getattr(full, name).tobytes() == getattr(merged, name).tobytes(), name
