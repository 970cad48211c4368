"""The last batches of a render shrink so that the worker threads finish together (core.schedule.tail_target):
the cut, the batches a render then queues, and images, AOVs and tile callbacks bit-identical to a render whose
batches all keep their size, and to one thread's."""

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import render as render_module
from monte.core.schedule import MIN_BATCH, TAIL_PIECES, tail_piece_overfills, tail_target
from monte.core.settings import RenderSettings

OUTPUTS = ("color", "variance", "albedo", "normal", "depth", "sample_count")


def test_tail_target_keeps_full_batches_until_the_last_rounds():
    target = 1 << 18
    assert TAIL_PIECES == 4
    # enough left to give each of 2 threads four full batches: unchanged
    assert tail_target(target, 8 * target, 2) == target
    assert tail_target(target, 10 * target, 2) == target
    # then the remainder in 4 x workers pieces, rounded up
    assert tail_target(target, 8 * target - 1, 2) == target  # ceil((8t - 1) / 8) = t
    assert tail_target(target, 6 * target, 2) == 3 * target // 4
    assert tail_target(target, 2 * target, 2) == target // 4
    assert tail_target(target, 2 * target + 1, 2) == target // 4 + 1
    assert tail_target(target, 12 * target, 4) == 12 * target // 16
    # never below MIN_BATCH paths, nor above the target itself when that is smaller
    assert tail_target(target, 3 * MIN_BATCH, 2) == MIN_BATCH
    assert tail_target(target, 1, 2) == MIN_BATCH
    assert tail_target(4096, 1, 2) == 4096
    # one worker: nothing runs beside it, every batch keeps the target
    assert tail_target(target, 1, 1) == target
    assert tail_target(target, target, 0) == target


def test_a_tail_piece_never_overfills_a_batch_but_segments_outside_the_tail_do():
    target = 1 << 18
    # in the tail (a pass target below the render's): the batch goes first when the piece would overfill it...
    assert tail_piece_overfills(40_000, target, 30_000, 20_000)
    # ...not when it fits exactly, nor when the batch is still empty (a piece always makes a batch)
    assert not tail_piece_overfills(40_000, target, 20_000, 20_000)
    assert not tail_piece_overfills(40_000, target, 0, 60_000)
    # outside the tail a batch gathers segments until it reaches its target, whatever they overshoot
    assert not tail_piece_overfills(target, target, target - 1, target)


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


@pytest.mark.parametrize("tile_size, expected", [
    # 32x32 tiles (16,384 paths): the first pair of tiles in one full batch; from the third tile on, what is left
    # makes a target below two tiles, and a batch takes no segment that would overfill it: a tile a batch
    (32, [32768] + [MIN_BATCH] * 14),
    # 64x64 tiles (65,536 paths): the first in two full batches, the second in three pieces of 1,366, 1,366 and
    # 1,364 pixels (24,576 paths at most each), the last two in four of 16,384
    (64, [32768, 32768, 21824, 21856, 21856] + [MIN_BATCH] * 8)])
def test_the_last_batches_shrink_and_change_no_bit(monkeypatch, tile_size, expected):
    whole, whole_sizes, whole_calls = _render(monkeypatch, tail=False, tile_size=tile_size)
    cut, cut_sizes, cut_calls = _render(monkeypatch, tail=True, tile_size=tile_size)
    one, _, one_calls = _render(monkeypatch, tail=True, threads=1, tile_size=tile_size)
    assert [p for _, p in whole_sizes] == [32768] * 8
    # 2 threads: full batches while 262,144 paths or more (4 x 2 targets) are left to hand out, then an eighth
    # of what is left at each tile pass, at least MIN_BATCH
    assert [p for _, p in cut_sizes] == expected
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
# ------------------------------------------------------------------ lab.schedule_balance (monte perf --sections balance)
@pytest.mark.parametrize("tile_size, threads", [(32, 2), (64, 2), (64, 4), (32, 1)])
def test_the_balance_plan_cuts_the_batches_the_render_cuts(monkeypatch, tile_size, threads):
    from monte.lab.schedule_balance import plan

    settings = RenderSettings(spp=16, tile_size=tile_size, threads=threads, max_bounces=4, seed=5, aovs=False)
    recorded = []
    run_batch = render_module._TileRender._run_batch

    def record(self, segments):
        recorded.append(sorted((seg.tile, tuple(seg.loc[::seg.sample_end - int(seg.smp[0])])) for seg in segments))
        return run_batch(self, segments)

    monkeypatch.setattr(render_module._TileRender, "_run_batch", record)
    render_module.render(scenes.cornell_box((128, 128)), settings)
    planned = [sorted((t, tuple(loc)) for t, loc, count in batch)
               for batch in plan((128, 128), settings, threads, tail=True)]
    assert sorted(recorded) == sorted(planned)
    whole = plan((128, 128), settings, threads, tail=False)
    assert [sum(len(loc) * count for _, loc, count in b) for b in whole] == [32768] * 8


def test_list_scheduling_and_the_projected_efficiency():
    from monte.lab.schedule_balance import list_schedule, projected_efficiency

    assert list_schedule([3, 1, 1, 1], 2) == 3
    assert list_schedule([1, 1, 1, 3], 2) == 4  # the large batch last: one thread ends alone
    assert list_schedule([2.0] * 8, 4) == 4.0
    # 256x256 at 16 spp in 64x64 tiles: 8 batches of 131,072 paths (two tile passes of 65,536 each)
    settings = RenderSettings(spp=16, tile_size=64, threads=2)
    uniform = np.full((256, 256), 1e-6)
    out = projected_efficiency(uniform, settings, (1, 2, 3))
    assert out["1"]["tail"] == pytest.approx(1.0) and out["1"]["whole"] == pytest.approx(1.0)
    assert out["2"]["whole"] == pytest.approx(1.0)  # 4 rounds of 2 equal batches
    # 8 equal batches on 3 threads take 3 rounds for 8/3 batches' work
    assert out["3"]["whole"] == pytest.approx(8 / 9)
    # the tail's pieces (of what is left at each pass an eighth on 2 threads, a twelfth on 3, at least 16,384
    # paths) are not all of one size, so they cost ~1 % on 2 threads, but end 3 threads within 2 % of each other
    assert 0.98 < out["2"]["tail"] < 1.0
    assert out["3"]["tail"] > 0.98
    assert (out["2"]["batches_tail"], out["3"]["batches_tail"], out["3"]["batches_whole"]) == (26, 34, 8)
    # a frame whose last tile costs 16x the others': the whole batches leave the other thread idle
    skewed = uniform.copy()
    skewed[192:, 192:] *= 16
    out = projected_efficiency(skewed, settings, (2,))
    assert out["2"]["tail"] > out["2"]["whole"]


def test_the_balance_section_prints_its_numbers(capsys):
    from monte.lab.schedule_balance import balance, print_balance

    report = balance(32, 2, 2, 1, scenes=("cornell",), project=(2, 16))
    print_balance(report, 32, 2)
    r = report["cornell"]
    assert set(r["projected"]) == {"2", "16"} and r["threads"] == 2
    assert all(0 < v[k] <= 1 for v in r["projected"].values() for k in ("tail", "whole"))
    assert len(r["measured"]["tail"]["wall"]) == len(r["measured"]["whole"]["idle"]) == 1
    assert r["cpu_seconds"] > 0
    assert "cornell: projected parallel efficiency" in capsys.readouterr().out
