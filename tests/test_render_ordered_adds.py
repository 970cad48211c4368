"""Tiles that take several passes get their segments added to their films by the worker threads, each tile's in
the order the render queued them (core.render._TileRender._add_in_order), instead of all by the calling thread:
the same bits and the same tile callbacks, in the same order, as when the calling thread adds every segment."""

import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import render as render_module
from monte.core.render import _SKIPPED, _TileRender
from monte.core.schedule import Segment

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_compare import assert_same_images, tile_recorder  # noqa: E402


def _render(monkeypatch, in_workers: bool, **kw):
    """(result, tile callbacks, {thread name: segments it added to films})."""
    job = render_module._TileRender
    if not in_workers:
        monkeypatch.setattr(job, "_adds_in_workers", lambda self: False)
    adders: dict[str, int] = {}
    add_segment = job._add_segment

    def counted(self, *args):
        name = threading.current_thread().name
        adders[name] = adders.get(name, 0) + 1
        return add_segment(self, *args)

    monkeypatch.setattr(job, "_add_segment", counted)
    calls, on_tile = tile_recorder()

    # 48x40 in 9 tiles of 16x16 or 16x8 pixels: 16 or 32 samples a pass in a 4096-path batch, so every tile
    # takes several passes
    settings = dict(spp=40, tile_size=16, threads=2, max_bounces=4, seed=5, aovs=True, batch_paths=4096)
    settings.update(kw)
    result = render_module.render(scenes.cornell_box((48, 40)), render_module.RenderSettings(**settings),
                                  on_tile=on_tile)
    monkeypatch.undo()
    return result, calls, adders


@pytest.mark.parametrize("kw", [
    {},
    {"threads": 3},
    {"error_estimate": False},  # the frame's AOV sums (FrameImages.add_aovs) from the workers
    {"aovs": False, "spp": 33},  # a last pass of one sample
    {"denoising_features": True},
    {"batch_paths": 1024, "spp": 16},  # 4 or 8 samples a pass
    {"tile_size": 64, "batch_paths": 1024, "spp": 3},  # one tile, each pass of 1920 paths cut into 2 segments
])
def test_segments_added_by_the_workers_change_no_bit(monkeypatch, kw):
    base, base_calls, base_adders = _render(monkeypatch, False, **kw)
    fast, fast_calls, fast_adders = _render(monkeypatch, True, **kw)
    main = threading.main_thread().name
    size = kw.get("tile_size", 16)
    tiles = -(-48 // size) * -(-40 // size)
    assert set(base_adders) == {main}  # the calling thread added every segment
    assert fast_adders and main not in fast_adders  # the workers did
    assert sum(fast_adders.values()) == sum(base_adders.values()) >= 2 * tiles  # several segments a tile
    assert_same_images(base, fast)
    assert fast_calls == base_calls  # the same tiles reported, in the same order, with the same images
    assert len(base_calls) >= 2 * tiles  # every pass of every tile
    assert fast.stats["samples"] == base.stats["samples"] == 48 * 40 * kw.get("spp", 40)


def test_one_thread_adds_on_the_calling_thread(monkeypatch):
    result, calls, adders = _render(monkeypatch, True, threads=1)
    assert set(adders) == {threading.main_thread().name}
    # 6 tiles of 16x16 in passes of 16, 16 and 8 samples, 3 of 16x8 in passes of 32 and 8
    assert int(result.sample_count.sum()) == 48 * 40 * 40 and len(calls) == 6 * 3 + 3 * 2


class _Orders:
    """A _TileRender reduced to its ordered adds: _add_segment_in_worker records (tile, order, thread)."""

    def __init__(self, monkeypatch):
        self.job = job = object.__new__(_TileRender)
        job._tile_adds, job._adds, job._adds_failed = {}, threading.Condition(), None
        self.added = []

        def add(seg, done):
            self.added.append((seg.tile_index, seg.order, threading.current_thread().name))
            return seg.last_chunk, f"tile {seg.tile_index} pass {seg.order}"

        monkeypatch.setattr(job, "_add_segment_in_worker", add, raising=False)

    @staticmethod
    def segment(tile: int, order: int) -> Segment:
        seg = Segment(tile, (0, 0, 1, 1), np.zeros(1, np.int64), np.zeros(1, np.uint32), order + 1, True)
        seg.order = order
        return seg

    def deposit(self, tile: int, order: int, skipped: bool = False) -> None:
        seg = self.segment(tile, order)
        self.job._add_in_order(seg, _SKIPPED if skipped else (seg,), {"film": 0.0, "assembly": 0.0})


def test_a_tile_adds_its_segments_in_queue_order_whoever_brings_them(monkeypatch):
    orders = _Orders(monkeypatch)
    orders.deposit(0, 2)  # early: nothing added, nobody waits
    orders.deposit(1, 0)
    orders.deposit(0, 1)
    assert orders.added == [(1, 0, threading.main_thread().name)]
    arrived = threading.Event()

    def late_first():
        orders.deposit(0, 0)  # the one missing: this thread adds it and the two that waited
        arrived.set()

    worker = threading.Thread(target=late_first, name="late")
    worker.start()
    worker.join(10)
    assert arrived.is_set()
    assert [(t, o) for t, o, _ in orders.added] == [(1, 0), (0, 0), (0, 1), (0, 2)]
    assert {name for t, o, name in orders.added if t == 0} == {"late"}
    assert orders.job._report_in_order(orders.segment(0, 1)) == (True, "tile 0 pass 1")
    assert orders.job._report_in_order(orders.segment(0, 0)) == (True, "tile 0 pass 0")


def test_a_segment_a_cancel_dropped_lets_its_tiles_later_ones_through(monkeypatch):
    orders = _Orders(monkeypatch)
    orders.deposit(0, 0)
    orders.deposit(0, 2)  # a later batch, already running when the cancel came
    orders.deposit(0, 1, skipped=True)  # its batch never started
    assert [(t, o) for t, o, _ in orders.added] == [(0, 0), (0, 2)]
    assert orders.job._report_in_order(orders.segment(0, 1)) == (False, None)
    assert orders.job._report_in_order(orders.segment(0, 2)) == (True, "tile 0 pass 2")


def test_the_calling_thread_waits_for_a_report_another_worker_is_adding(monkeypatch):
    orders = _Orders(monkeypatch)
    got = []
    waiter = threading.Thread(target=lambda: got.append(orders.job._report_in_order(orders.segment(3, 0))))
    waiter.start()
    waiter.join(0.2)
    assert waiter.is_alive() and not got  # not added yet: it waits
    orders.deposit(3, 0)
    waiter.join(10)
    assert got == [(True, "tile 3 pass 0")]


def test_a_failed_add_is_raised_to_the_calling_thread_not_waited_for(monkeypatch):
    orders = _Orders(monkeypatch)

    def broken(seg, done):
        raise ValueError("film refused the samples")

    monkeypatch.setattr(orders.job, "_add_segment_in_worker", broken, raising=False)
    with pytest.raises(ValueError, match="film refused"):
        orders.deposit(0, 0)
    with pytest.raises(ValueError, match="film refused"):  # the same error, whichever thread added
        orders.job._report_in_order(orders.segment(0, 1))


def test_the_calling_thread_is_handed_no_batch_arrays_to_hold(monkeypatch):
    """With the workers adding, a finished batch hands the calling thread none of its arrays: they go as soon as
    its segments are added, not when the calling thread reaches the batch."""
    job = render_module._TileRender
    run_batch = job._run_batch
    returned = []

    def spy(self, segments):
        out = run_batch(self, segments)
        returned.append(out[:3])
        return out

    monkeypatch.setattr(job, "_run_batch", spy)
    result = render_module.render(scenes.cornell_box((48, 40)), render_module.RenderSettings(
        spp=40, tile_size=16, threads=2, max_bounces=4, batch_paths=4096))
    assert int(result.sample_count.sum()) == 48 * 40 * 40
    assert len(returned) >= 9 and all(array is None for arrays in returned for array in arrays)


def test_after_a_cancel_no_tile_images_are_made_for_callbacks_that_will_not_come(monkeypatch):
    job = render_module._TileRender
    tile_result = job._tile_result
    made = []

    def spy(self, *args):
        made.append(self.cancelled)
        return tile_result(self, *args)

    monkeypatch.setattr(job, "_tile_result", spy)
    polls = [0]

    def cancel():
        polls[0] += 1
        return polls[0] > 8

    result = render_module.render(scenes.cornell_box((48, 40)), render_module.RenderSettings(
        spp=40, tile_size=16, threads=2, max_bounces=4, batch_paths=4096), on_tile=lambda tile: None,
        should_cancel=cancel)
    assert result.cancelled and made and not any(made)  # intermediate passes' images, all before the cancel
