"""Films alive at once: the render's passes go round one window of tiles at a time (core.schedule), so a render
whose tiles need several passes keeps only a window's films, with the same images as going round all tiles."""

import sys
from pathlib import Path

import pytest

from monte.core import builtin_scenes as scenes
from monte.core import render as render_module
from monte.core.film import TileFilm
from monte.core.memory import FILM_BYTES, estimate_render_memory
from monte.core.schedule import FILM_WINDOW_PIXELS, pass_bounds, sample_passes, tile_windows, tiles
from monte.core.settings import RenderSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_compare import assert_same_images  # noqa: E402

# 32x32 in 8x8 tiles (16 tiles of 64 px), 1024-path batches: 16 samples per tile and pass, 3 passes at 48 spp
SIZE, TILE, SPP, BATCH = 32, 8, 48, 1024
WINDOW = 4 * TILE * TILE  # pixels: 4 tiles


def _settings(**kw) -> RenderSettings:
    base = dict(spp=SPP, tile_size=TILE, batch_paths=BATCH, threads=2, max_bounces=4, seed=3, aovs=True)
    base.update(kw)
    return RenderSettings(**base)


def test_windows_cut_the_tiles_by_pixels_and_keep_each_tiles_passes():
    tile_list = tiles(0, 0, 40, 24, 16)  # 3 x 2 tiles of 256, 256, 128 px, then 128, 128, 64 px
    assert tile_windows(tile_list, 640) == [(0, 3), (3, 6)]
    assert tile_windows(tile_list, 639) == [(0, 2), (2, 6)]
    assert tile_windows(tile_list, 100) == [(i, i + 1) for i in range(6)]  # at least one tile each
    assert tile_windows(tile_list, 0) == [(0, 6)]
    settings = _settings(tile_size=16, spp=40)
    whole = list(sample_passes(tile_list, 40, settings, 40, 0))
    windowed = list(sample_passes(tile_list, 40, settings, 40, 640))
    assert sorted(whole) == sorted(windowed)  # every (tile, first sample, count), once
    for ti in range(len(tile_list)):  # each tile's passes in the same order
        assert [p for p in whole if p[0] == ti] == [p for p in windowed if p[0] == ti]
    # the second window starts only when the first holds all its samples
    first_of_second = next(k for k, p in enumerate(windowed) if p[0] >= 3)
    assert all(p[0] < 3 for p in windowed[:first_of_second])
    assert all(p[0] >= 3 for p in windowed[first_of_second:])
    assert len({p[0] for p in windowed[:first_of_second]}) == 3 and first_of_second > 3  # several passes each
    # the control: round all tiles at once (each tile's first pass first)
    assert whole[:6] == [(ti, t, 0, BATCH // (t[2] * t[3])) for ti, t in enumerate(tile_list)]
    assert pass_bounds(tile_list, 40, settings)[0] == [0, 4, 8, 12, 16, 20, 24, 28, 32, 36, 40]


def _render_counting_films(monkeypatch, window: int, **kw):
    """Render the Cornell box with the passes' window set to `window` pixels; (result, most films alive)."""
    alive = {"now": 0, "most": 0}

    class CountedFilm(TileFilm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            alive["now"] += 1
            alive["most"] = max(alive["most"], alive["now"])

        def release(self):
            alive["now"] -= 1
            super().release()

    monkeypatch.setattr(render_module, "TileFilm", CountedFilm)
    monkeypatch.setattr(render_module, "FILM_WINDOW_PIXELS", window)
    result = render_module.render(scenes.cornell_box((SIZE, SIZE)), _settings(**kw))
    return result, alive["most"]


# adaptive at 0.7: some tiles converge whole at 16 or 32 samples (released then, before their last pass)
@pytest.mark.parametrize("extra", [{}, {"adaptive_threshold": 0.7, "adaptive_min_samples": 16}])
def test_a_window_keeps_only_its_films_alive_and_changes_no_bit(monkeypatch, extra):
    whole, most_whole = _render_counting_films(monkeypatch, 0, **extra)
    windowed, most_windowed = _render_counting_films(monkeypatch, WINDOW, **extra)
    tiles_total = (SIZE // TILE) ** 2
    # the control: round all tiles, every film alive until its last pass (with adaptive sampling the first tiles
    # may converge whole before the last film is made)
    assert most_whole == tiles_total if not extra else most_whole >= tiles_total - 4
    assert most_windowed <= 4 + 1  # a window's 4 films (+ the next window's first while the last is folded)
    assert_same_images(whole, windowed)
    assert whole.color[..., :3].mean() > 0.01


def test_a_time_limit_goes_round_the_whole_image(monkeypatch):
    # a time limit that never stops this render: the passes still go round all tiles (the image sharpens evenly)
    _, most = _render_counting_films(monkeypatch, WINDOW, time_limit=1e6)
    assert most == (SIZE // TILE) ** 2


def test_the_memory_estimate_counts_one_window_of_films():
    scene = scenes.cornell_box((7680, 4320))  # 8K: 33 M pixels, 16 windows
    per_pixel = FILM_BYTES  # with the AOVs: their sums live in the frame's AOV images
    assert estimate_render_memory(scene, RenderSettings(spp=128)).film == FILM_WINDOW_PIXELS * per_pixel
    # under a time limit the passes go round the whole image: every film alive
    assert estimate_render_memory(scene, RenderSettings(spp=128, time_limit=60)).film == 7680 * 4320 * per_pixel
    # a tile larger than the window is a window of its own
    big = RenderSettings(spp=128, tile_size=2048)
    assert estimate_render_memory(scene, big).film == 2048 * 2048 * per_pixel
    small = scenes.cornell_box((64, 32))
    assert estimate_render_memory(small, RenderSettings(spp=128)).film == 64 * 32 * per_pixel
