"""Sixteen worker threads (more than this machine's cores, so they interleave at random) give the same bits, the
same tile callbacks in the same order and the same sample counts as one thread: whole tiles, tiles that take
several passes (their segments added by the workers in queue order), adaptive sampling, and the per-bounce
integrator. A render is designed to scale past two threads; this checks that nothing in it depends on how
many threads there are or which one gets which batch."""

import sys
import threading
from pathlib import Path

import pytest

from monte.core import builtin_scenes as scenes
from monte.core import render as render_module

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_compare import assert_same_images, tile_recorder  # noqa: E402


def _render(monkeypatch, threads: int, scene, **kw):
    """(result, tile callbacks, names of the threads that traced batches)."""
    job = render_module._TileRender
    tracers: set[str] = set()
    run_batch = job._run_batch

    def recorded(self, segments):
        tracers.add(threading.current_thread().name)
        return run_batch(self, segments)

    monkeypatch.setattr(job, "_run_batch", recorded)
    calls, on_tile = tile_recorder()

    settings = render_module.RenderSettings(**{"seed": 3, "max_bounces": 4, "threads": threads, **kw})
    result = render_module.render(scene, settings, on_tile=on_tile)
    monkeypatch.setattr(job, "_run_batch", run_batch)
    return result, calls, tracers


CASES = {
    # 48x40 in 9 tiles, 4 or 8 samples a pass in 1024-path batches: ~70 batches, each tile's segments added by
    # whichever worker holds its next one
    "several passes a tile": (lambda: scenes.cornell_box((48, 40)),
                              dict(spp=24, tile_size=16, batch_paths=1024, aovs=True)),
    "several passes, no error estimate": (lambda: scenes.cornell_box((48, 40)),
                                          dict(spp=24, tile_size=16, batch_paths=1024, error_estimate=False)),
    # 1 spp: whole tiles written by the worker that traced them (192 tiles of 8x8, 16 to a batch)
    "whole tiles at 1 spp": (lambda: scenes.cornell_box((128, 96)), dict(spp=1, tile_size=8, batch_paths=1024)),
    "adaptive": (lambda: scenes.cornell_box((48, 40)),
                 dict(spp=32, tile_size=16, batch_paths=1024, adaptive_threshold=0.05, adaptive_min_samples=8)),
    # light passes keep the per-bounce integrator (a batch is many kernel calls, not one)
    "per-bounce integrator": (lambda: scenes.cornell_box((48, 40)),
                              dict(spp=8, tile_size=8, batch_paths=1024, light_passes=("Diffuse Direct",
                                                                                        "Diffuse Indirect"))),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_sixteen_threads_give_one_threads_bits(monkeypatch, case):
    build, kw = CASES[case]
    one, one_calls, one_tracers = _render(monkeypatch, 1, build(), **kw)
    many, many_calls, many_tracers = _render(monkeypatch, 16, build(), **kw)
    assert len(one_tracers) == 1
    assert len(many_tracers) >= 3, many_tracers  # batches really ran on several of the sixteen
    assert_same_images(one, many)
    if one.light_passes is not None:
        assert sorted(one.light_passes) == sorted(many.light_passes)
        for name, image in one.light_passes.items():
            assert image.tobytes() == many.light_passes[name].tobytes(), name
    assert many_calls == one_calls  # the same tiles reported, in the same order, with the same images
    assert many.stats["samples"] == one.stats["samples"] > 0
    assert (many.sample_count == one.sample_count).all()
