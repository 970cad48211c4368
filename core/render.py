"""Render orchestration: tiles x sample batches, progress, cancel, and the result images.

Image convention for every array here: row 0 is the TOP of the image, shape (height, width, channels).
(Blender's render result wants row 0 at the bottom: the add-on flips.)
"""

from __future__ import annotations

import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .kernels import compile_cache_is_cold
from .scene import Scene
from .settings import RenderSettings


@dataclass
class Tile:
    """A finished tile. x0, y0: its top-left pixel in the full frame (y0 counted from the top).

    color: (h, w, 4) RGBA float32 linear radiance (alpha 1 where a surface or the world was seen; Monte
    renders an opaque world, so alpha is 1 everywhere). variance: (h, w, 3) variance of each pixel's mean.
    albedo, normal: (h, w, 3) first-hit AOVs (normal in world space); depth: (h, w) distance along the camera
    axis to the first hit (Blender's Z pass; 1e10 where nothing was hit). samples: samples taken per pixel.
    """

    x0: int
    y0: int
    color: np.ndarray
    variance: np.ndarray
    albedo: np.ndarray | None = None
    normal: np.ndarray | None = None
    depth: np.ndarray | None = None
    samples: int = 0

    @property
    def width(self) -> int:
        return int(self.color.shape[1])

    @property
    def height(self) -> int:
        return int(self.color.shape[0])


@dataclass
class Progress:
    """Progress of a render: fraction in [0, 1], the sample being worked on, rays cast so far, rates."""

    fraction: float
    tiles_done: int
    tiles_total: int
    samples_done: int
    spp: int
    rays: int
    elapsed: float
    rays_per_second: float
    eta_seconds: float

    def stats_line(self) -> str:
        """A Blender status-bar style line: sample, rays/s, time left."""
        return (f"Tile {min(self.tiles_done + 1, self.tiles_total)}/{self.tiles_total} | "
                f"Sample {self.samples_done}/{self.spp} | {self.rays_per_second / 1e6:.2f} M rays/s | "
                f"Elapsed {self.elapsed:.1f} s | Remaining {self.eta_seconds:.1f} s")


@dataclass
class RenderResult:
    """The full frame (same arrays as Tile, whole image), statistics and what went wrong on the way."""

    color: np.ndarray
    variance: np.ndarray
    albedo: np.ndarray | None
    normal: np.ndarray | None
    depth: np.ndarray | None
    sample_count: np.ndarray
    stats: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    cancelled: bool = False


ProgressCallback = Callable[[Progress], None]
TileCallback = Callable[[Tile], None]
CancelCallback = Callable[[], bool]


def _tiles(x0: int, y0: int, w: int, h: int, size: int) -> list[tuple[int, int, int, int]]:
    """Tiles (x, y, w, h) covering the region, row by row from the top."""
    return [(x, y, min(size, x0 + w - x), min(size, y0 + h - y))
            for y in range(y0, y0 + h, size) for x in range(x0, x0 + w, size)]


_MIN_BATCH = 1 << 14  # paths: below this NumPy's per-call overhead dominates a batch


def batch_target(settings: RenderSettings, total_paths: int) -> int:
    """Paths per batch for a render of total_paths paths: settings.batch_paths, or fewer so that a small render
    still makes 8 batches for the worker threads to share (but never fewer than _MIN_BATCH paths)."""
    return max(1, min(settings.batch_paths, max(_MIN_BATCH, -(-total_paths // 8))))


@dataclass
class Segment:
    """Part of a batch: samples [sample_end - count, sample_end) of some pixels of one tile. loc: tile-local
    pixel index per path; smp: sample index per path; last_chunk: the last segment of this tile's pass."""

    tile_index: int
    tile: tuple[int, int, int, int]
    loc: np.ndarray
    smp: np.ndarray
    sample_end: int
    last_chunk: bool


def _peak_memory_mb() -> float:
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    except (ImportError, OSError):  # not on Windows
        return float("nan")


def render(
    scene: Scene,
    settings: RenderSettings,
    *,
    region: tuple[int, int, int, int] | None = None,
    on_tile: TileCallback | None = None,
    on_progress: ProgressCallback | None = None,
    should_cancel: CancelCallback | None = None,
    log: Callable[[str], None] | None = None,
    tile_order: list[int] | None = None,
) -> RenderResult:
    """Render `scene` with `settings`.

    region: (x0, y0, width, height) in pixels of the full resolution, y0 from the top (render border/crop);
    None renders the whole frame. The result arrays cover the region only.

    Work is split into tiles x sample batches: each batch traces at most settings.batch_paths paths, so
    memory is bounded by the batch, not by the image or the sample count. Samples are taken in passes over
    the tiles (a pass gives every tile as many samples as fit in one batch), so long renders refine the whole
    image progressively and a time limit or cancel leaves a complete, noisier image.
    on_tile is called with each tile after each pass over it (its current state); on_progress after every
    batch; should_cancel is polled before each batch is queued: when it returns True the render stops and the
    result (cancelled=True) holds every sample taken so far (pixels no batch reached yet are 0); batches
    running on other threads at that moment finish and count, silently (no callback after the cancel).
    Batches run on settings.thread_count worker threads and are accumulated in the order they were queued, so
    the image does not depend on the thread count. adaptive_threshold > 0 turns on adaptive sampling.
    tile_order: a permutation of the tile list (for testing that images don't depend on it).
    """
    from .accel import Accelerator
    from .camera import camera_rays
    from .film import TileFilm
    from .filters import PixelFilter
    from .integrator import DIM_FILM, PathStats, PathTracer, PreparedScene
    from .sampling import VARIANCE_GROUPS, make_sampler

    settings.validate()
    t_start = time.perf_counter()
    say = log or (lambda _msg: None)
    if compile_cache_is_cold():
        say("compiling the render kernels (first render after an install or update, about a minute; cached after)")
    scene.validate()
    width, height = scene.camera.resolution
    if region is None:
        region = (0, 0, width, height)
    rx, ry, rw, rh = (int(v) for v in region)
    if rw < 1 or rh < 1 or rx < 0 or ry < 0 or rx + rw > width or ry + rh > height:
        raise ValueError(f"render region {region} is not inside the {width}x{height} frame")
    # Issue 6: estimate memory before allocating anything; a clear error instead of an out-of-memory kill.
    from .memory import check_render_memory
    check_render_memory(scene, settings, rw * rh)

    t0 = time.perf_counter()
    prepared = PreparedScene.build(scene, sample_world=settings.light_sampling == "light")
    # Parallelism is across batches (see below), so each Embree call runs on the worker that makes it.
    accel = Accelerator(prepared.vertices, prepared.triangles)
    t_prepare = time.perf_counter() - t0
    for w in scene.warnings:
        say(f"warning: {w}")
    say(f"scene {scene.name}: {len(prepared.triangles)} triangles, features {prepared.features}, "
        f"prepared in {t_prepare:.2f} s")

    sampler = make_sampler(settings.sampler, settings.seed, max(settings.spp, 1), groups=VARIANCE_GROUPS)
    pixel_filter = PixelFilter(settings.filter_type, settings.filter_width)
    tiles = _tiles(rx, ry, rw, rh, settings.tile_size)
    if tile_order is not None:
        if sorted(tile_order) != list(range(len(tiles))):
            raise ValueError("tile_order must be a permutation of the tile indices")
        tiles = [tiles[i] for i in tile_order]
    films = {t: TileFilm(t[2], t[3], settings.aovs, sampler) for t in tiles}

    spp = int(settings.spp)
    total_paths = spp * rw * rh
    done_paths = 0
    cancelled = False
    samples_started = np.zeros(len(tiles), np.int64)
    pixels_converged = np.zeros(len(tiles), np.int64)  # adaptive sampling: pixels that stopped early
    largest_batch = 0  # paths in the largest batch traced (memory scales with it, times the worker threads)

    def progress(tiles_done: int, sample: int) -> None:
        if on_progress is None:
            return
        elapsed = time.perf_counter() - t_start
        rays = accel.rays_closest + accel.rays_shadow
        frac = done_paths / total_paths if total_paths else 1.0
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("inf")
        on_progress(Progress(frac, tiles_done, len(tiles), sample, spp, rays, elapsed,
                             rays / max(elapsed, 1e-9), eta))

    def stop_requested() -> bool:
        if should_cancel is not None and should_cancel():
            return True
        return settings.time_limit > 0 and time.perf_counter() - t_start > settings.time_limit

    def tile_result(tile, film: TileFilm, samples: int) -> Tile:
        color = np.concatenate([film.mean(), np.ones((tile[3], tile[2], 1), np.float32)], axis=2)
        albedo = normal = depth = None
        if settings.aovs:
            albedo, normal, depth = film.aov_images()
        return Tile(tile[0], tile[1], color, film.variance_of_mean(), albedo, normal, depth, samples)

    adaptive = settings.adaptive_threshold > 0
    min_samples = settings.adaptive_min_samples_for(spp) if adaptive else spp

    def passes():
        """(tile index, tile, first sample, sample count) in pass order: a pass gives every tile as many samples
        as fit in one batch (with adaptive sampling: at most min_samples, then half of that, so convergence is
        checked often)."""
        started = samples_started.copy()
        while True:
            any_left = False
            for ti, tile in enumerate(tiles):
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

    tracers: list[PathTracer] = []
    local_state = threading.local()
    tracers_lock = threading.Lock()

    def trace_batch(segments: list[Segment]):
        """Camera rays and paths of one batch, which may span several tiles (runs on a worker thread; touches no
        shared mutable state but the counters, which are locked)."""
        tracer = getattr(local_state, "tracer", None)
        if tracer is None:
            tracer = local_state.tracer = PathTracer(prepared, accel, settings, sampler)
            with tracers_lock:
                tracers.append(tracer)
        t0 = time.perf_counter()
        px = np.concatenate([seg.tile[0] + seg.loc % seg.tile[2] for seg in segments])
        py = np.concatenate([seg.tile[1] + seg.loc // seg.tile[2] for seg in segments])
        smp = np.concatenate([seg.smp for seg in segments])
        pixel_id = (py * width + px).astype(np.uint32)
        offsets = pixel_filter.sample(sampler.get_2d(pixel_id, smp, DIM_FILM))
        rays = camera_rays(scene.camera, px + 0.5 + offsets[:, 0], py + 0.5 + offsets[:, 1])
        tracer.stats.seconds_camera += time.perf_counter() - t0
        return tracer.trace(pixel_id, smp, rays.origins, rays.directions, rays.tmax, rays.depth_scale,
                            rays.t_start, settings.aovs)

    # Batches run on `workers` threads (NumPy, numba and Embree release the GIL), at most `workers + 1` in
    # flight, and are accumulated in submission order on this thread: the image does not depend on timing.
    # A batch holds about `target` paths, gathered from as many tile passes as it takes (at 1 spp a 64x64 tile is
    # only 4096 paths, far too few to amortise NumPy's per-call cost); small images are split into at least 8
    # batches (of at least _MIN_BATCH paths) so that threads share them. None of this depends on the thread count.
    workers = settings.thread_count
    target = batch_target(settings, total_paths)
    if adaptive:
        # A pass's convergence test waits for the tile's previous pass: keep each pass in >= 8 batches so that
        # the threads still share it.
        step = max(16, min_samples // 2)
        target = min(target, max(_MIN_BATCH, -(-rw * rh * step // 8)))
    pool = ThreadPoolExecutor(workers) if workers > 1 else None
    in_flight: deque = deque()  # (segments, job)
    group: list[Segment] = []
    group_paths = 0
    film_seconds = 0.0

    def submit() -> None:
        nonlocal group, group_paths, largest_batch
        if not group:
            return
        segments, group = group, []
        largest_batch = max(largest_batch, group_paths)
        group_paths = 0
        job = pool.submit(trace_batch, segments) if pool is not None else (lambda: trace_batch(segments))
        in_flight.append((segments, job))
        if len(in_flight) > (workers if pool is not None else 0):
            finish_one()

    def finish_one(quiet: bool = False) -> None:
        nonlocal done_paths, film_seconds
        segments, job = in_flight.popleft()
        radiance, first = job.result() if pool is not None else job()
        start = 0
        for seg in segments:
            rows = slice(start, start + len(seg.loc))
            start = rows.stop
            t0 = time.perf_counter()
            film = films[seg.tile]
            film.add(seg.loc, radiance[rows], seg.smp)
            if first is not None:
                film.add_aovs(seg.loc, first.albedo[rows], first.normal[rows], first.depth[rows])
            film_seconds += time.perf_counter() - t0
            done_paths += len(seg.loc)
            if not quiet:
                progress(seg.tile_index, seg.sample_end)
            if seg.last_chunk:
                samples_started[seg.tile_index] = seg.sample_end
                if on_tile is not None and not quiet:
                    on_tile(tile_result(seg.tile, film, seg.sample_end))

    def tile_busy(ti: int) -> bool:
        return any(seg.tile_index == ti for segments, _ in in_flight for seg in segments)

    try:
        for ti, tile, first_sample, count in passes():
            n_pix = tile[2] * tile[3]
            pixels = np.arange(n_pix, dtype=np.int64)
            if adaptive and first_sample >= min_samples:
                if any(seg.tile_index == ti for seg in group):
                    submit()
                while tile_busy(ti):  # the convergence test needs this tile's earlier samples
                    finish_one()
                pixels = films[tile].active_pixels(settings.adaptive_threshold)
                pixels_converged[ti] = n_pix - len(pixels)
                done_paths += (n_pix - len(pixels)) * count  # samples converged pixels no longer need
                if len(pixels) == 0:
                    samples_started[ti] = first_sample + count
                    progress(ti, first_sample + count)
                    if on_tile is not None:
                        on_tile(tile_result(tile, films[tile], first_sample + count))
                    continue
            pix_chunk = max(1, target // count)
            chunks = [pixels[c0:c0 + pix_chunk] for c0 in range(0, len(pixels), pix_chunk)]
            for k, chunk in enumerate(chunks):
                if stop_requested():
                    cancelled = True
                    break
                loc = np.repeat(chunk, count)
                smp = np.tile(np.arange(first_sample, first_sample + count, dtype=np.uint32), len(chunk))
                group.append(Segment(ti, tile, loc, smp, first_sample + count, k == len(chunks) - 1))
                group_paths += len(loc)
                if group_paths >= target:
                    submit()
            if cancelled:
                break
        if cancelled:
            # Batches still queued never start; ones already running finish (a path batch cannot stop halfway
            # without bias) and their samples are kept, but no callback reports anything after the cancel.
            group, group_paths = [], 0
            while in_flight:
                job = in_flight[0][-1]
                if pool is not None and job.cancel():
                    in_flight.popleft()
                else:
                    finish_one(quiet=True)
        submit()
        while in_flight:
            finish_one()
    finally:
        if pool is not None:
            for _, job in in_flight:
                job.cancel()
            pool.shutdown(wait=True)

    # Assemble the region's image from the tiles.
    color = np.zeros((rh, rw, 4), np.float32)
    variance = np.zeros((rh, rw, 3), np.float32)
    albedo = np.zeros((rh, rw, 3), np.float32) if settings.aovs else None
    normal = np.zeros((rh, rw, 3), np.float32) if settings.aovs else None
    depth = np.full((rh, rw), 1e10, np.float32) if settings.aovs else None
    counts = np.zeros((rh, rw), np.int32)
    for tile in tiles:
        tx, ty, tw, th = tile
        film = films[tile]
        sl = (slice(ty - ry, ty - ry + th), slice(tx - rx, tx - rx + tw))
        tr = tile_result(tile, film, 0)
        color[sl], variance[sl] = tr.color, tr.variance
        counts[sl] = film.count.reshape(th, tw)
        if settings.aovs:
            albedo[sl], normal[sl], depth[sl] = tr.albedo, tr.normal, tr.depth
    elapsed = time.perf_counter() - t_start
    st = PathStats.total([t.stats for t in tracers])
    rays = accel.rays_closest + accel.rays_shadow
    stats = {
        "scene": scene.name,
        "resolution": [width, height],
        "region": [rx, ry, rw, rh],
        "spp": spp,
        "samples": int(counts.sum()),
        "seconds": elapsed,
        "prepare_seconds": t_prepare,
        "samples_per_second": counts.sum() / max(elapsed, 1e-9),
        "rays_closest": accel.rays_closest,
        "rays_shadow": accel.rays_shadow,
        "rays_per_second": rays / max(elapsed, 1e-9),
        "embree_seconds": st.seconds_intersect + st.seconds_occluded,
        # Share of all worker thread-time (wall time x workers) spent inside Embree.
        "embree_share": (st.seconds_intersect + st.seconds_occluded) / max(elapsed * workers, 1e-9),
        "stage_seconds": {**st.stage_seconds(), "film": film_seconds},
        "nonfinite_samples": st.nonfinite,
        "clamped_contributions": st.clamped,
        "peak_memory_mb": _peak_memory_mb(),
        "threads": settings.thread_count,
        "largest_batch": largest_batch,
        "adaptive_pixels_converged": int(pixels_converged.sum()) if adaptive else 0,
        "features": prepared.features,
    }
    if st.nonfinite:
        msg = f"{st.nonfinite} NaN/Inf path contributions were caught and dropped (not written to the image)"
        scene.warnings.append(msg)
        say(f"warning: {msg}")
    return RenderResult(color, variance, albedo, normal, depth, counts, stats, list(scene.warnings), cancelled)
