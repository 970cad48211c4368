"""Tiles whose samples all lie in one segment of one batch (every tile at 1 spp) are summed and written into the
frame's images on the worker thread that traced them (core.render._TileRender._finish_in_worker): the same bits
and the same tile callbacks, in the same order, as when the calling thread adds every batch."""

import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import render as render_module
from monte.core.settings import RenderSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_compare import assert_same_images  # noqa: E402


def _render(monkeypatch, in_worker: bool, sky: bool = False, **kw):
    """(result, tile callbacks, tiles written by the worker path, threads that wrote them, tiles written without a
    film: FrameImages.put_one_sample)."""
    job = render_module._TileRender
    if not in_worker:  # the calling thread adds every segment (tests/test_render_ordered_adds.py: the others)
        monkeypatch.setattr(job, "_whole_tile", lambda self, seg: False)
        monkeypatch.setattr(job, "_adds_in_workers", lambda self: False)
    written, threads = [0], set()
    finish = job._finish_in_worker

    def counted(self, segments, *args):
        done = finish(self, segments, *args)
        written[0] += len(done) - 2  # (the "film" and "assembly" seconds)
        if len(done) > 2:
            threads.add(threading.current_thread().name)
        return done

    monkeypatch.setattr(job, "_finish_in_worker", counted)
    one_sample = [0]
    put_one = render_module.FrameImages.put_one_sample

    def counted_one(self, *args):
        one_sample[0] += 1
        return put_one(self, *args)

    monkeypatch.setattr(render_module.FrameImages, "put_one_sample", counted_one)
    calls = []

    def on_tile(tile):
        calls.append((tile.x0, tile.y0, tile.samples, tile.color.tobytes(), tile.variance.tobytes(),
                      None if tile.albedo is None else tile.albedo.tobytes()))

    settings = RenderSettings(**{**dict(spp=1, tile_size=16, threads=2, max_bounces=4, seed=5, aovs=True,
                                        batch_paths=1024), **kw})
    scene = scenes.spheres_under_sky((80, 48)) if sky else scenes.cornell_box((80, 48))
    result = render_module.render(scene, settings, on_tile=on_tile)
    monkeypatch.undo()
    return result, calls, written[0], threads, one_sample[0]


@pytest.mark.parametrize("kw, whole, film_free", [
    ({}, True, True),  # 1 spp: every tile (15 of 16x16) in one segment, and no film needed
    ({"aovs": False}, True, True),
    ({"spp": 4}, True, False),  # 4 samples of 256 px in a 1024-path batch: one segment each, summed in a film
    ({"spp": 8}, False, False),  # two passes per tile: the workers add them, each tile's in order
    ({"threads": 1}, True, True),  # no worker threads: the same functions on the calling thread
    ({"denoising_features": True}, True, False),  # the features need the film
    ({"sky": True}, True, True),  # pixels that hit nothing: depth 1e10, normal 0
])
def test_whole_tiles_written_by_workers_change_no_bit(monkeypatch, kw, whole, film_free):
    base, base_calls, base_written, _, base_one = _render(monkeypatch, False, **kw)
    fast, fast_calls, fast_written, threads, fast_one = _render(monkeypatch, True, **kw)
    assert base_written == 0 and base_one == 0
    tiles = 5 * 3
    assert fast_written == (tiles if whole else 0)
    assert fast_one == (tiles if film_free else 0)
    if whole and kw.get("threads", 2) > 1:
        assert threads and threading.current_thread().name not in threads  # worker threads wrote them
    assert_same_images(base, fast)
    assert fast_calls == base_calls  # the same tiles reported, in the same order, with the same images
    assert len(base_calls) == tiles * (2 if kw.get("spp") == 8 else 1)
    assert base.color[..., :3].mean() > 0.01
    if kw.get("sky"):
        assert (fast.depth == np.float32(1e10)).any() and (fast.depth < 1e9).any()
    assert int(fast.sample_count.sum()) == 80 * 48 * kw.get("spp", 1)
