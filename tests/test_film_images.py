"""A tile's images are written once, compiled, into the frame's arrays, and are the bits the film's NumPy form
gives (core.film.TileFilm.write_colour_images / write_aov_images against combined_rgba, variance_of_mean and
aov_images), and the tiles a render shows as they land are the frame's own pixels."""

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import sampling
from monte.core.film import TileFilm
from monte.core.render import render


def _filled_film(kind: str, alpha: bool, passes: list[int], rng) -> TileFilm:
    """A 5x3 film of the sampler `kind` given passes of the listed sample counts (pixel 4 left empty, pixel 7
    constant, pixel 2 never hit, a few pixels a single sample), with AOVs."""
    sampler = sampling.make_sampler(kind, 0, 64, groups=sampling.VARIANCE_GROUPS)
    film = TileFilm(5, 3, True, sampler, alpha=alpha)
    pixels = np.array([p for p in range(15) if p != 4])
    start = 0
    for count in passes:
        pix = np.repeat(pixels, count)
        smp = np.tile(np.arange(start, start + count), len(pixels))
        radiance = (rng.random((len(pix), 3)) * np.exp(rng.normal(size=(len(pix), 3)) * 3)).astype(np.float32)
        radiance[pix == 7] = np.float32([0.1, 2.0, 1e3])
        transparent = rng.random(len(pix)) if alpha else None
        film.add(pix, radiance, smp, transparent)
        depth = np.where(rng.random(len(pix)) < 0.3, np.inf, rng.random(len(pix)) * 40)
        depth[pix == 2] = np.inf
        normal = rng.normal(size=(len(pix), 3))
        normal[pix == 9] = 0.0
        film.add_aovs(pix, rng.random((len(pix), 3)), normal, depth)
        start += count
    return film


@pytest.mark.parametrize("kind", ["sobol", "stratified", "independent"])
@pytest.mark.parametrize("alpha", [False, True])
@pytest.mark.parametrize("passes", [[1], [1, 1, 3], [7, 16]])
def test_compiled_tile_images_equal_the_films_numpy_images_bit_for_bit(kind, alpha, passes):
    film = _filled_film(kind, alpha, passes, np.random.default_rng(len(passes) + 7 * alpha))
    color = np.full((7, 9, 4), -1.0, np.float32)  # a larger frame: the tile goes to rows 2.., columns 3..
    variance = np.full((7, 9, 3), -1.0, np.float32)
    albedo, normal = np.full((7, 9, 3), -1.0, np.float32), np.full((7, 9, 3), -1.0, np.float32)
    depth = np.full((7, 9), -1.0, np.float32)
    film.write_colour_images(color, variance, 2, 3)
    film.write_aov_images(albedo, normal, depth, 2, 3)
    tile = (slice(2, 5), slice(3, 8))
    np.testing.assert_array_equal(color[tile], film.combined_rgba())
    np.testing.assert_array_equal(variance[tile], film.variance_of_mean())
    for got, want in zip((albedo[tile], normal[tile], depth[tile]), film.aov_images()):
        np.testing.assert_array_equal(got, want)
    outside = np.ones((7, 9), bool)
    outside[tile] = False
    assert np.all(color[outside] == -1) and np.all(variance[outside] == -1) and np.all(depth[outside] == -1)
    # the cases the images single out: no sample (black, alpha 1, no variance), a constant pixel, no hit
    assert np.all(color[2, 7] == [0, 0, 0, 1]) and np.all(variance[2, 7] == 0)
    assert np.all(variance[3, 5] == 0) and np.all(color[3, 5, :3] == np.float32([0.1, 2.0, 1e3]))
    assert depth[2, 5] == np.float32(1e10) and np.all(normal[3, 7] == 0)
    assert np.any(variance[tile] > 0) == (sum(passes) > 1)  # one sample: no variance to estimate


def test_the_tiles_shown_as_they_land_are_the_final_images_pixels(fast_settings):
    """At low spp each tile is final after one pass: its images are written into the frame once and shown
    from there (the add-on writes these into Blender's result), not built a second time."""
    shown = []
    result = render(scenes.cornell_box((20, 12)), fast_settings(spp=2, tile_size=8, batch_paths=4096),
                    on_tile=shown.append)
    assert len(shown) == 6 and all(t.samples == 2 for t in shown)
    for t in shown:
        rows, cols = slice(t.y0, t.y0 + t.height), slice(t.x0, t.x0 + t.width)
        np.testing.assert_array_equal(t.color, result.color[rows, cols])
        np.testing.assert_array_equal(t.variance, result.variance[rows, cols])
        np.testing.assert_array_equal(t.depth, result.depth[rows, cols])
    assert result.stats["assembly_seconds"] > 0


@pytest.mark.parametrize("features", [True, False])
def test_at_one_sample_per_pixel_only_the_films_of_tiles_in_flight_exist(fast_settings, monkeypatch, features):
    """Films are made when a tile's first samples arrive and released when its last pass lands, so a 1-spp
    render of 128 tiles (16 per batch of 1024 paths) never holds more than the batches in flight need, where
    making every film up front held all 128 (an 8K frame's 3.2 GB of films at once). Without the denoising
    features (or alpha, light passes, ...) a 1-spp tile needs no film at all (FrameImages.put_one_sample): only
    the one the frame reads its settings from is made."""
    import monte.core.render as render_module

    counts = {"made": 0, "live": 0, "peak": 0}

    class CountedFilm(TileFilm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            counts["made"] += 1
            counts["live"] += 1
            counts["peak"] = max(counts["peak"], counts["live"])

        def release(self):
            super().release()
            counts["live"] -= 1

    monkeypatch.setattr(render_module, "TileFilm", CountedFilm)
    threads = 2
    result = render(scenes.cornell_box((128, 64)), fast_settings(spp=1, tile_size=8, batch_paths=1024,
                                                                 threads=threads, denoising_features=features))
    assert counts["made"] == (128 if features else 1) and counts["live"] == 0
    # batches in flight (threads + 1) and the one being gathered, 16 tiles each
    assert counts["peak"] <= (threads + 2) * 16
    assert int(result.sample_count.sum()) == 128 * 64


@pytest.mark.parametrize("kind", ["sobol", "independent"])
def test_the_compiled_sums_leave_their_scratch_zero_after_partial_passes(kind):
    """film_kernels.add_colour clears only the scratch rows its samples wrote when they are fewer than the tile's
    pixels: after passes over a few pixels of a tile, then an out-of-order pass that is refused, then other
    pixels, the thread's scratch is all zero again, and a film given those samples is the bits of one filled from
    fresh scratch."""
    from monte.core import film as film_module

    rng = np.random.default_rng(3)
    sampler = sampling.make_sampler(kind, 0, 64, groups=sampling.VARIANCE_GROUPS)

    def fill(film, passes):
        for pix, start, count in passes:
            smp = np.tile(np.arange(start, start + count), len(pix))
            pix = np.repeat(pix, count)
            film.add(pix, rng.random((len(pix), 3)).astype(np.float32) * 4, smp)

    subsets = [np.array([3, 40, 41, 63]), np.arange(10, 30), np.array([0, 63])]
    passes = [(subsets[0], 0, 5), (subsets[1], 0, 2), (subsets[0], 5, 3), (subsets[2], 0, 1)]
    film = TileFilm(8, 8, False, sampler)
    fill(film, passes[:2])
    scratch = film_module._SCRATCH.buffers
    assert not scratch.group_sum.any() and not scratch.group_samples.any() and not scratch.sums3.any()
    refused = film.groups > 1  # (a film without variance groups cannot tell the samples' order)
    if refused:
        with pytest.raises(ValueError):  # sample 0 again for pixels that have 5 (whose next sample, 5, lies in
            fill(film, [(subsets[0], 0, 1)])  # another group under any group count): refused, nothing changed
        assert not scratch.group_sum.any() and not scratch.group_samples.any()
    fill(film, passes[2:])
    assert not scratch.group_sum.any() and not scratch.group_samples.any() and not scratch.sums3.any()

    rng = np.random.default_rng(3)  # the same samples into a film whose every call finds fresh zeroed scratch
    fresh = TileFilm(8, 8, False, sampler)
    for one in passes[:2]:
        film_module._SCRATCH.buffers = None
        fill(fresh, [one])
    if refused:
        rng.random((len(subsets[0]) * 1, 3))  # (the refused pass's draws)
    for one in passes[2:]:
        film_module._SCRATCH.buffers = None
        fill(fresh, [one])
    for name in ("shift", "group_dev", "sample_count") + (("dev_sq",) if film.squares else ()):
        assert getattr(film, name).tobytes() == getattr(fresh, name).tobytes(), name
    assert film.sample_count.sum() == 4 * 8 + 20 * 2 + 2 * 1
