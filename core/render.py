"""Render orchestration: tiles x sample batches, progress, cancel, and the result images.

Image convention for every array here: row 0 is the TOP of the image, shape (height, width, channels).
(Blender's render result wants row 0 at the bottom: the add-on flips.)
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

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
    batch; should_cancel is polled between batches: when it returns True the render stops and the result
    (cancelled=True) holds every sample taken so far (pixels no batch reached yet are 0).
    tile_order: a permutation of the tile list (for testing that images don't depend on it).
    """
    from .accel import Accelerator
    from .camera import camera_rays
    from .film import TileFilm
    from .filters import PixelFilter
    from .integrator import DIM_FILM, PathTracer, PreparedScene
    from .sampling import make_sampler

    settings.validate()
    t_start = time.perf_counter()
    say = log or (lambda _msg: None)
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
    prepared = PreparedScene.build(scene)
    accel = Accelerator(prepared.vertices, prepared.triangles, settings.thread_count)
    t_prepare = time.perf_counter() - t0
    for w in scene.warnings:
        say(f"warning: {w}")
    say(f"scene {scene.name}: {len(prepared.triangles)} triangles, features {prepared.features}, "
        f"prepared in {t_prepare:.2f} s")

    sampler = make_sampler(settings.sampler, settings.seed, max(settings.spp, 1))
    pixel_filter = PixelFilter(settings.filter_type, settings.filter_width)
    tracer = PathTracer(prepared, accel, settings, sampler)
    tiles = _tiles(rx, ry, rw, rh, settings.tile_size)
    if tile_order is not None:
        if sorted(tile_order) != list(range(len(tiles))):
            raise ValueError("tile_order must be a permutation of the tile indices")
        tiles = [tiles[i] for i in tile_order]
    films = {t: TileFilm(t[2], t[3], settings.aovs) for t in tiles}

    spp = int(settings.spp)
    total_paths = spp * rw * rh
    done_paths = 0
    cancelled = False
    samples_started = np.zeros(len(tiles), np.int64)

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

    try:
        while done_paths < total_paths and not cancelled:
            for ti, tile in enumerate(tiles):
                tx, ty, tw, th = tile
                n_pix = tw * th
                first_sample = int(samples_started[ti])
                if first_sample >= spp:
                    continue
                per_batch = max(1, settings.batch_paths // n_pix)
                count = min(per_batch, spp - first_sample)
                # Pixel chunks keep a batch within batch_paths even when one tile has more pixels than that.
                pix_chunk = max(1, settings.batch_paths // count)
                local = np.arange(n_pix, dtype=np.int64)
                for c0 in range(0, n_pix, pix_chunk):
                    if stop_requested():
                        cancelled = True
                        break
                    loc = np.repeat(local[c0:c0 + pix_chunk], count)
                    smp = np.tile(np.arange(first_sample, first_sample + count, dtype=np.uint32),
                                  min(pix_chunk, n_pix - c0))
                    px = tx + loc % tw
                    py = ty + loc // tw
                    pixel_id = (py * width + px).astype(np.uint32)
                    offsets = pixel_filter.sample(sampler.get_2d(pixel_id, smp, DIM_FILM))
                    rays = camera_rays(scene.camera, px + 0.5 + offsets[:, 0], py + 0.5 + offsets[:, 1])
                    radiance, first = tracer.trace(pixel_id, smp, rays.origins, rays.directions, rays.tmax,
                                                   rays.depth_scale, rays.t_start, settings.aovs)
                    film = films[tile]
                    film.add(loc, radiance)
                    if first is not None:
                        film.add_aovs(loc, first.albedo, first.normal, first.depth)
                    done_paths += len(loc)
                    progress(ti, first_sample + count)
                if cancelled:
                    break
                samples_started[ti] = first_sample + count
                if on_tile is not None:
                    on_tile(tile_result(tile, films[tile], first_sample + count))
    finally:
        accel.close()

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
    st = tracer.stats
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
        "embree_seconds": accel.seconds,
        "embree_share": accel.seconds / max(elapsed, 1e-9),
        "nonfinite_samples": st.nonfinite,
        "clamped_contributions": st.clamped,
        "peak_memory_mb": _peak_memory_mb(),
        "threads": settings.thread_count,
        "features": prepared.features,
    }
    if st.nonfinite:
        msg = f"{st.nonfinite} NaN/Inf path contributions were caught and dropped (not written to the image)"
        scene.warnings.append(msg)
        say(f"warning: {msg}")
    return RenderResult(color, variance, albedo, normal, depth, counts, stats, list(scene.warnings), cancelled)
