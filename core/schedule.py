"""How a render's work is cut up: tiles, sample passes over the tiles, and batches of paths.

Pure arithmetic on the render's size and settings (no arrays but index lists), shared by core.render, which runs
the batches, and core.memory, which estimates what a batch costs before anything is allocated. Nothing here
depends on the thread count, so neither does the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .settings import RenderSettings

MIN_BATCH = 1 << 14  # paths: below this NumPy's per-call overhead dominates a batch
# tail_target's pieces per thread of the work left: 4 kept 88-99 % of 16 threads busy in the projections of
# lab/schedule_balance (eight scenes and sizes), 2 kept 87-98 % and did worse on 2 threads (73-98 % while tail
# pieces could still regroup into one batch); 8 only added batches (docs/performance.md, "Threads that finish
# together")
TAIL_PIECES = 4
# Pixels whose films a render keeps alive at once when its tiles need several passes (core.render: the passes go
# round one window of tiles at a time): 2^21 pixels, ~150 MB of film at 72 B/px, a 1080p frame in one window
# (no change there), 1/16 of an 8K frame. Not tied to the thread count: 512 tiles of 64x64 keep 16+ threads fed.
FILM_WINDOW_PIXELS = 1 << 21

TileRect = tuple[int, int, int, int]  # (x, y, width, height) in pixels, y from the top


def tiles(x0: int, y0: int, w: int, h: int, size: int) -> list[TileRect]:
    """Tiles (x, y, w, h) covering the region, row by row from the top."""
    return [(x, y, min(size, x0 + w - x), min(size, y0 + h - y))
            for y in range(y0, y0 + h, size) for x in range(x0, x0 + w, size)]


def batch_target(settings: RenderSettings, total_paths: int) -> int:
    """Paths per batch for a render of total_paths paths: settings.batch_paths, or fewer so that a small render
    still makes 8 batches for the worker threads to share (but never fewer than MIN_BATCH paths)."""
    return max(1, min(settings.batch_paths, max(MIN_BATCH, -(-total_paths // 8))))


def tail_target(target: int, paths_left: int, workers: int) -> int:
    """Paths per batch for the next tile pass, while `paths_left` paths (that pass's included) are still to be
    handed to `workers` threads: `target` as long as that fills every thread TAIL_PIECES times over; then the
    remainder in TAIL_PIECES x workers pieces, never below MIN_BATCH paths (nor above target). Batches of one
    size can cost very different times (a tile of sky beside one of textured floor: 0.05 s against 0.7 s on the
    bench's `textured`), and with the last ones whole a thread could finish alone for most of a batch's time;
    the shrinking tail ends the threads together instead. One worker gets `target`: nothing runs beside it to
    wait for.

    Batches are cut at pixel boundaries within a pass (pass_segments), so where they fall never changes an
    image; only how many threads there are decides the cut."""
    if workers <= 1:
        return target
    share = -(-paths_left // (TAIL_PIECES * workers))
    return max(min(target, share), min(target, MIN_BATCH))


def tail_piece_overfills(pass_target: int, target: int, gathered: int, piece: int) -> bool:
    """Whether the batch gathered so far (`gathered` paths) goes out before a pass's next segment (`piece` paths)
    joins it: in the tail (the pass's target from tail_target below the render's `target`) a piece never
    overfills a batch, so that two tail pieces do not make one batch again. Outside the tail a batch gathers
    segments until it reaches its target."""
    return pass_target < target and gathered > 0 and gathered + piece > pass_target


def adaptive_batch_target(target: int, region_pixels: int, min_samples: int) -> int:
    """With adaptive sampling a pass's convergence test waits for the tile's previous pass: keep each pass in
    >= 8 batches so that the threads still share it."""
    step = max(16, min_samples // 2)
    return min(target, max(MIN_BATCH, -(-region_pixels * step // 8)))


@dataclass
class Segment:
    """Part of a batch: samples [sample_end - count, sample_end) of some pixels of one tile. loc: tile-local
    pixel index per path; smp: sample index per path; last_chunk: the last segment of this tile's pass; order:
    the segment's place among its tile's segments as the render queues them (the order its film sums them in)."""

    tile_index: int
    tile: TileRect
    loc: np.ndarray
    smp: np.ndarray
    sample_end: int
    last_chunk: bool
    order: int = 0  # its place among its tile's segments in the order they are queued (set when queued)


def sample_passes(tile_list: list[TileRect], spp: int, settings: RenderSettings, min_samples: int,
                  window_pixels: int = 0) -> Iterator[tuple[int, TileRect, int, int]]:
    """(tile index, tile, first sample, sample count) in pass order: a pass gives every tile as many samples as
    fit in one batch (with adaptive sampling: at most min_samples, then half of that, so convergence is checked
    often).

    window_pixels > 0: the passes go round the tiles of one window (consecutive tiles of about that many pixels,
    see tile_windows) until the window's tiles hold all their samples, then on to the next window, so only one
    window's films are alive at a time when a tile needs several passes; 0: round all tiles at once (every
    film alive until the last pass, the whole image sharpening evenly, as a time limit wants). Each tile's own
    passes (first sample, count) are the same either way, and so are the images (core.film sums a tile's
    passes in their order, whatever comes between them)."""
    for lo, hi in tile_windows(tile_list, window_pixels):
        for ti, tile, first_sample, count in _round_robin(tile_list[lo:hi], spp, settings, min_samples):
            yield lo + ti, tile, first_sample, count


def tile_windows(tile_list: list[TileRect], window_pixels: int) -> list[tuple[int, int]]:
    """[lo, hi) index ranges cutting tile_list into consecutive windows of at most window_pixels pixels (at
    least one tile each); one window of all tiles when window_pixels <= 0."""
    if window_pixels <= 0:
        return [(0, len(tile_list))] if tile_list else []
    out, lo, pixels = [], 0, 0
    for ti, tile in enumerate(tile_list):
        n_pix = tile[2] * tile[3]
        if ti > lo and pixels + n_pix > window_pixels:
            out.append((lo, ti))
            lo, pixels = ti, 0
        pixels += n_pix
    if lo < len(tile_list):
        out.append((lo, len(tile_list)))
    return out


def _round_robin(tile_list: list[TileRect], spp: int, settings: RenderSettings, min_samples: int
                 ) -> Iterator[tuple[int, TileRect, int, int]]:
    adaptive = settings.adaptive_threshold > 0
    started = np.zeros(len(tile_list), np.int64)
    while True:
        any_left = False
        for ti, tile in enumerate(tile_list):
            first_sample = int(started[ti])
            if first_sample >= spp:
                continue
            any_left = True
            n_pix = tile[2] * tile[3]
            count = min(max(1, settings.batch_paths // n_pix), spp - first_sample)
            if adaptive:
                count = min(count, min_samples if first_sample < min_samples else max(16, min_samples // 2))
            yield ti, tile, first_sample, count
            started[ti] = first_sample + count
        if not any_left:
            return


def pass_bounds(tile_list: list[TileRect], spp: int, settings: RenderSettings) -> list[list[int]]:
    """Each tile's sample-pass boundaries [0, ..., spp]: the first sample of each of its passes, then spp. A split
    of a tile's samples that merges bit for bit with the rest cuts only there (core.render.render_samples)."""
    min_samples = settings.adaptive_min_samples_for(spp) if settings.adaptive_threshold > 0 else spp
    bounds: list[list[int]] = [[] for _ in tile_list]
    for ti, _tile, first_sample, _count in sample_passes(tile_list, spp, settings, min_samples):
        bounds[ti].append(first_sample)
    for b in bounds:
        b.append(spp)
    return bounds


def pass_segments(ti: int, tile: TileRect, pixels: np.ndarray, first_sample: int, count: int, target: int
                  ) -> Iterator[Segment]:
    """One tile's pass over `pixels` (tile-local indices), samples [first_sample, first_sample + count), cut
    into as few segments of at most about `target` paths as it takes, of equal pixel counts (made one at a time:
    a cancelled render stops making them)."""
    pieces = max(1, -(-len(pixels) // max(1, target // count)))
    pix_chunk = max(1, -(-len(pixels) // pieces))
    chunks = [pixels[c0:c0 + pix_chunk] for c0 in range(0, len(pixels), pix_chunk)]
    for k, chunk in enumerate(chunks):
        yield Segment(ti, tile, np.repeat(chunk, count),
                      np.tile(np.arange(first_sample, first_sample + count, dtype=np.uint32), len(chunk)),
                      first_sample + count, k == len(chunks) - 1)
