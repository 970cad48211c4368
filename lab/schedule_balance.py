"""`monte perf --sections balance`: how evenly a render's batches keep its threads busy, with and without the
shrinking last batches (core.schedule.tail_target), measured here and projected to more threads than this
machine has.

- **Cost map.** One render on one thread, in 16x16 tiles of one batch each (every batch one tile's samples),
  after an untimed one, gives each pixel's CPU seconds per sample (the batch's thread time spread over its
  paths).
- **Projection.** For each thread count, the batches a render with the default tiles and batch size hands out
  (`plan`: the same cuts as core.render's pass loop, tail or not), each costed from the map, run in order by
  threads that each take the next batch when free (list scheduling, as the pool does). Printed: the parallel
  efficiency, total CPU / (threads x the last thread's finish). It leaves out what costs the same either way
  (camera rays, film sums per path) and the calling thread's share (a few per cent of one thread).
- **Measured** (this machine's thread count): real renders alternating tail and no tail in one process; the idle
  thread-seconds (threads x wall minus the batches' wall time summed) and the wall times.

Prints numbers only: no timing is asserted. Scenes: the built-in `cornell` (every tile costs about the same) and
`spheres-sky` (a sky that costs little above a ground and spheres that cost much).
"""

from __future__ import annotations

import heapq
import statistics
import time
from contextlib import contextmanager
from dataclasses import replace
from typing import Iterator

import numpy as np

from ..core import render as render_module
from ..core.builtin_scenes import builtin_scene
from ..core.schedule import (FILM_WINDOW_PIXELS, MIN_BATCH, batch_target, pass_segments, sample_passes,
                             tail_piece_overfills, tail_target, tiles)
from ..core.scene import Scene
from ..core.settings import RenderSettings

SCENES = ("cornell", "spheres-sky")
THREADS = (2, 4, 8, 16, 32, 64)
COST_TILE = 16  # pixels: the cost map's tiles, one batch each


@contextmanager
def _tail(on: bool) -> Iterator[None]:
    """Renders inside shrink their last batches (on) or keep every batch at the target (off)."""
    real = render_module.tail_target
    if not on:
        render_module.tail_target = lambda target, paths_left, workers: target
    try:
        yield
    finally:
        render_module.tail_target = real


@contextmanager
def _batches_timed(out: list) -> Iterator[None]:
    """Appends (segments, wall seconds, thread CPU seconds) of every batch a render inside runs."""
    job = render_module._TileRender
    run_batch = job._run_batch

    def timed(self, segments):
        t0, c0 = time.perf_counter(), time.thread_time()
        result = run_batch(self, segments)
        out.append((segments, time.perf_counter() - t0, time.thread_time() - c0))
        return result

    job._run_batch = timed
    try:
        yield
    finally:
        job._run_batch = run_batch


def cost_map(scene: Scene, settings: RenderSettings) -> np.ndarray:
    """(height, width) CPU seconds per sample of each pixel, from one render on one thread in COST_TILE-pixel
    tiles whose batches hold one tile each, after one untimed render (a process's first batch of a scene also
    loads, or compiles, the kernels it calls: that is no cost of its pixels)."""
    w, h = scene.camera.resolution
    fine = replace(settings, threads=1, tile_size=COST_TILE,
                   batch_paths=max(1024, COST_TILE * COST_TILE * settings.spp))
    render_module.render(scene, fine)
    batches: list = []
    with _batches_timed(batches):
        render_module.render(scene, fine)
    cost = np.zeros(w * h)
    for segments, _wall, cpu in batches:
        paths = sum(len(seg.loc) for seg in segments)
        for seg in segments:
            x, y, tw, _th = seg.tile
            pixel = (y + seg.loc // tw) * w + x + seg.loc % tw
            np.add.at(cost, pixel, cpu / paths)
    return (cost / settings.spp).reshape(h, w)


def plan(resolution: tuple[int, int], settings: RenderSettings, workers: int, tail: bool) -> list[list[tuple]]:
    """The batches, in order, that a render of the whole frame with these settings hands to `workers` threads
    (no adaptive sampling): each a list of (tile, tile-local pixels, samples). The cuts are core.render's pass
    loop's, made with its functions (sample_passes, tail_target, pass_segments, tail_piece_overfills); a test
    checks them against a real render's batches."""
    w, h = resolution
    tile_list = tiles(0, 0, w, h, settings.tile_size)
    target = batch_target(settings, settings.spp * w * h)
    passes = list(sample_passes(tile_list, settings.spp, settings, settings.spp, FILM_WINDOW_PIXELS))
    left = sum(t[2] * t[3] * count for _, t, _, count in passes)
    batches, group, gathered = [], [], 0
    for ti, tile, first_sample, count in passes:
        pixels = np.arange(tile[2] * tile[3], dtype=np.int64)
        here = tail_target(target, left + gathered, workers) if tail and workers > 1 else target
        left -= len(pixels) * count
        for seg in pass_segments(ti, tile, pixels, first_sample, count, here):
            if tail_piece_overfills(here, target, gathered, len(seg.loc)):
                batches.append(group)
                group, gathered = [], 0
            group.append((seg.tile, seg.loc[::count], count))
            gathered += len(seg.loc)
            if gathered >= here:
                batches.append(group)
                group, gathered = [], 0
    if group:
        batches.append(group)
    return batches


def list_schedule(costs: list[float], workers: int) -> float:
    """When the last of `workers` threads finishes, each taking the next batch in order as soon as it is free."""
    free = [0.0] * workers
    for c in costs:
        heapq.heappush(free, heapq.heappop(free) + c)
    return max(free)


def projected_efficiency(costs_per_sample: np.ndarray, settings: RenderSettings, threads: tuple[int, ...]
                         ) -> dict[str, dict[str, float]]:
    """{threads: {"tail": efficiency, "whole": efficiency, "batches_tail": n, "batches_whole": n}} of the frame's
    batches run by list scheduling, from the cost map."""
    h, w = costs_per_sample.shape
    flat = costs_per_sample.reshape(-1)
    out: dict[str, dict[str, float]] = {}
    for n in threads:
        row: dict[str, float] = {}
        for tail in (True, False):
            costs = [sum(float(flat[(t[1] + loc // t[2]) * w + t[0] + loc % t[2]].sum()) * count
                         for t, loc, count in batch) for batch in plan((w, h), settings, n, tail)]
            key = "tail" if tail else "whole"
            row[key] = sum(costs) / (n * list_schedule(costs, n))
            row["batches_" + key] = len(costs)
        out[str(n)] = row
    return out


def measured_idle(scene: Scene, settings: RenderSettings, repeat: int) -> dict[str, dict[str, list[float]]]:
    """Real renders at settings.threads alternating tail and no tail (after one untimed render): per render its
    wall seconds and the idle thread-seconds, threads x wall minus its batches' wall seconds."""
    render_module.render(scene, settings)
    out: dict[str, dict[str, list[float]]] = {m: {"wall": [], "idle": []} for m in ("tail", "whole")}
    workers = settings.thread_count
    for i in range(repeat):
        for mode in (("tail", "whole") if i % 2 == 0 else ("whole", "tail")):
            batches: list = []
            with _tail(mode == "tail"), _batches_timed(batches):
                t0 = time.perf_counter()
                render_module.render(scene, settings)
                wall = time.perf_counter() - t0
            out[mode]["wall"].append(wall)
            out[mode]["idle"].append(workers * wall - sum(b[1] for b in batches))
    return out


def balance(resolution: int, spp: int, threads: int, repeat: int, scenes: tuple[str, ...] = SCENES,
            project: tuple[int, ...] = THREADS) -> dict:
    """The section's numbers for each scene (see the module's docstring)."""
    report: dict = {}
    for name in scenes:
        scene = builtin_scene(name, (resolution, resolution))
        settings = RenderSettings(spp=spp, seed=1, threads=threads, aovs=False).validate()
        costs = cost_map(scene, settings)
        report[name] = {"projected": projected_efficiency(costs, settings, project),
                        "cpu_seconds": float(costs.sum() * spp)}
        if settings.thread_count > 1:
            report[name]["measured"] = measured_idle(scene, settings, repeat)
            report[name]["threads"] = settings.thread_count
    return report


def print_balance(report: dict, resolution: int, spp: int) -> None:
    print(f"Batch balance ({resolution}x{resolution}, {spp} spp; tail: the last batches shrink, whole: they keep "
          f"their size; at least {MIN_BATCH} paths a batch):")
    for name, r in report.items():
        cells = ", ".join(f"{n}: {v['tail']:.1%} / {v['whole']:.1%} ({v['batches_tail']} / {v['batches_whole']} "
                          f"batches)" for n, v in r["projected"].items())
        print(f"  {name}: projected parallel efficiency, tail / whole, by threads: {cells}")
        if "measured" in r:
            m = r["measured"]
            print(f"  {name}: measured on {r['threads']} threads (median of {len(m['tail']['wall'])}): idle "
                  f"{statistics.median(m['tail']['idle']):.3f} / {statistics.median(m['whole']['idle']):.3f} "
                  f"thread-s, wall {statistics.median(m['tail']['wall']):.3f} / "
                  f"{statistics.median(m['whole']['wall']):.3f} s, of {r['cpu_seconds']:.2f} CPU s on one thread")
