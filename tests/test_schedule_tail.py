"""The last batches of a render shrink so that the worker threads finish together (core.schedule.tail_target):
the cut, the batches a render then queues, and images, AOVs and tile callbacks bit-identical to a render whose
batches all keep their size, and to one thread's."""

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import render as render_module
from monte.core.schedule import MIN_BATCH, tail_target
from monte.core.settings import RenderSettings

OUTPUTS = ("color", "variance", "albedo", "normal", "depth", "sample_count")


def test_tail_target_keeps_full_batches_until_the_last_two_rounds():
    target = 1 << 18
    # enough left to give each of 2 threads two full batches: unchanged
    assert tail_target(target, 4 * target, 2) == target
    assert tail_target(target, 10 * target, 2) == target
    # then the remainder in 2 x workers pieces, rounded up
    assert tail_target(target, 4 * target - 1, 2) == target - 0  # ceil((4t - 1) / 4) = t
    assert tail_target(target, 3 * target, 2) == 3 * target // 4
    assert tail_target(target, target, 2) == target // 4
    assert tail_target(target, target + 1, 2) == target // 4 + 1
    assert tail_target(target, 6 * target, 4) == 6 * target // 8
    # never below MIN_BATCH paths, nor above the target itself when that is smaller
    assert tail_target(target, 3 * MIN_BATCH, 2) == MIN_BATCH
    assert tail_target(target, 1, 2) == MIN_BATCH
    assert tail_target(4096, 1, 2) == 4096
    # one worker: nothing runs beside it, every batch keeps the target
    assert tail_target(target, 1, 1) == target
    assert tail_target(target, target, 0) == target


def _render(monkeypatch, tail: bool, threads: int = 2, **kw):
    """(result, the paths of each batch in submission order, the tile callbacks)."""
    job = render_module._TileRender
    if not tail:
        monkeypatch.setattr(render_module, "tail_target", lambda target, left, workers: target)
    sizes = []
    run_batch = job._run_batch

    def counted(self, segments):
        out = run_batch(self, segments)
        sizes.append((segments[0].tile_index, sum(len(seg.loc) for seg in segments)))
        return out

    monkeypatch.setattr(job, "_run_batch", counted)
    calls = []

    def on_tile(tile):
        calls.append((tile.x0, tile.y0, tile.samples, tile.color.tobytes(), tile.variance.tobytes(),
                      tile.albedo.tobytes()))

    # 128x128 at 16 spp: 262,144 paths, a batch target of 32,768 (core.schedule.batch_target's 8 batches)
    settings = RenderSettings(**{**dict(spp=16, tile_size=32, threads=threads, max_bounces=4, seed=5, aovs=True),
                                 **kw})
    result = render_module.render(scenes.cornell_box((128, 128)), settings, on_tile=on_tile)
    monkeypatch.undo()
    sizes.sort()  # (first tile, paths): the order they were handed out in, whichever thread ran them
    return result, sizes, calls


@pytest.mark.parametrize("tile_size", [32, 64])
def test_the_last_batches_shrink_and_change_no_bit(monkeypatch, tile_size):
    whole, whole_sizes, whole_calls = _render(monkeypatch, tail=False, tile_size=tile_size)
    cut, cut_sizes, cut_calls = _render(monkeypatch, tail=True, tile_size=tile_size)
    one, _, one_calls = _render(monkeypatch, tail=True, threads=1, tile_size=tile_size)
    assert [p for _, p in whole_sizes] == [32768] * 8
    # 2 threads: full batches while 131,072 paths or more are left to hand out, then a quarter of what is left
    # at each tile pass, at least MIN_BATCH. 32x32 tiles (16,384 paths, two a batch): tiles 10-11 go at 24,576
    # (their pair makes one batch of 32,768), 12-15 at 16,384 each. 64x64 tiles (65,536 paths, two segments a
    # batch each): the last tile in four pieces of 16,384 paths.
    assert [p for _, p in cut_sizes] == [32768] * 6 + [MIN_BATCH] * 4
    for name in OUTPUTS:
        a, b, c = getattr(whole, name), getattr(cut, name), getattr(one, name)
        assert a.tobytes() == b.tobytes() == c.tobytes(), name
    assert cut_calls == whole_calls == one_calls


@pytest.mark.parametrize("kw", [{"spp": 40, "batch_paths": 1 << 15},  # 3 passes a tile (16, 16, 8 samples)
                                {"spp": 1}])  # whole tiles, written by the worker threads without a film
def test_shrinking_batches_over_several_passes_and_at_one_sample(monkeypatch, kw):
    whole, _, whole_calls = _render(monkeypatch, tail=False, **kw)
    cut, cut_sizes, cut_calls = _render(monkeypatch, tail=True, **kw)
    assert sum(p for _, p in cut_sizes) == 128 * 128 * kw["spp"]
    for name in OUTPUTS:
        assert getattr(whole, name).tobytes() == getattr(cut, name).tobytes(), name
    assert cut_calls == whole_calls
    np.testing.assert_array_equal(cut.sample_count, kw["spp"])
