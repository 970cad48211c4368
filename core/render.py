"""Render orchestration: a scene and settings in, tiles, progress and the finished image out.

`render()` checks its inputs, prepares the scene (flattened triangles, the Embree scene), then runs the batches of
paths core.schedule cuts the work into on worker threads, accumulating each batch into its tiles' films in the
order the batches were queued, and assembles the result. Image convention for every array here: row 0 is the TOP
of the image, shape (height, width, channels). (Blender's render result wants row 0 at the bottom: the add-on
flips.)
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from typing import Callable

import numpy as np

from .accel import Accelerator
from .camera import PinholeRays, camera_rays, pinhole_params
from .data_passes import DataFilm, DataTables, manifests, take_samples
from .data_passes import assemble as assemble_data
from . import film_kernels
from .film import CatcherOutput, TileFilm
from .filters import PixelFilter
from .integrator import (DIM_FILM, DIM_LENS, DIM_TIME, CatcherSamples, DenoisingFeatures, FirstHit, PathStats,
                         PathTracer, PreparedScene)
from .motion import moving_camera_rays, rolling_shutter_times, shutter_times
from .shading.vector_context import camera_differentials
from .jit_cache import compile_cache_is_cold, compile_notices
from .light_groups import LightGroupSamples, pass_name
from .light_passes import LightPassSamples
from .memory import check_render_memory
from .sampling import make_sampler
from .scene import Scene
from .schedule import (FILM_WINDOW_PIXELS, Segment, TileRect, adaptive_batch_target, batch_target, pass_bounds,
                       pass_segments, sample_passes, tail_piece_overfills, tail_target, tiles)

SampleRanges = dict[int, tuple[int, int]]  # tile index -> samples [start, end) to take of it
from .settings import RenderSettings

try:
    import resource
except ImportError:  # not on Windows
    resource = None


@dataclass
class Tile:
    """A finished tile. x0, y0: its top-left pixel in the full frame (y0 counted from the top).

    color: (h, w, 4) RGBA float32 linear radiance, premultiplied by alpha: alpha is 1 where surfaces or an
    opaque world were seen, lower where the pixel's samples escaped to the world under Film > Transparent or
    met a holdout (core.scene.Film, Material.holdout), which add no colour. variance: (h, w, 3) variance of each pixel's mean
    (its unbiased estimate), None when settings.error_estimate is off (no render of those settings has one).
    albedo, normal: (h, w, 3) first-hit AOVs (normal in world space); depth: (h, w) distance along the camera
    axis to the first hit (Blender's Z pass; 1e10 where nothing was hit). samples: samples taken per pixel.
    denoising_albedo, denoising_normal: (h, w, 3) Cycles' Denoising Albedo and Denoising Normal passes (normal in
    camera space: +x right, +y up, +z along the view, so a surface facing the camera reads (0, 0, -1); means
    over the pixel's samples, not renormalised), None unless settings.denoising_features.
    With a shadow catcher (core.scene.Mesh.shadow_catcher) color is Combined as Cycles forms it (core.film) and
    shadow_catcher (h, w, 3) is Cycles' Shadow Catcher pass, shadow_catcher_matte (h, w, 4) its Shadow Catcher
    Matte (both None without a catcher); variance stays that of the paths' radiance (the catcher seen).
    data_passes: {Blender pass name: (h, w, C)} Cycles' data passes of settings.data_passes (core.data_passes:
    Mist, Position, UV, Object Index, Material Index, CryptoObject00, ...); empty when none are asked for.
    """

    x0: int
    y0: int
    color: np.ndarray
    variance: np.ndarray | None
    albedo: np.ndarray | None = None
    normal: np.ndarray | None = None
    depth: np.ndarray | None = None
    samples: int = 0
    denoising_albedo: np.ndarray | None = None
    denoising_normal: np.ndarray | None = None
    shadow_catcher: np.ndarray | None = None
    shadow_catcher_matte: np.ndarray | None = None
    data_passes: dict = field(default_factory=dict)
    light_passes: dict[str, np.ndarray] | None = None  # Cycles' light passes asked for (core.light_passes)
    # Scene.shader_aovs: name -> (h, w, 4) RGBA (COLOR) or (h, w, 1) (VALUE) (core.shader_aovs)
    shader_aovs: dict[str, np.ndarray] | None = None
    # Scene.light_groups: pass name (Combined_<group>) -> (h, w, 3) (core.light_groups)
    light_groups: dict[str, np.ndarray] | None = None

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
    variance: np.ndarray | None  # None without settings.error_estimate
    albedo: np.ndarray | None
    normal: np.ndarray | None
    depth: np.ndarray | None
    sample_count: np.ndarray
    stats: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    cancelled: bool = False
    denoising_albedo: np.ndarray | None = None
    denoising_normal: np.ndarray | None = None
    noisy: np.ndarray | None = None  # the colour before denoising, when a caller denoised `color` (core.denoise)
    shadow_catcher: np.ndarray | None = None  # (h, w, 3) Cycles' Shadow Catcher pass (see Tile), or None
    shadow_catcher_matte: np.ndarray | None = None  # (h, w, 4) its Shadow Catcher Matte, or None
    data_passes: dict = field(default_factory=dict)  # see Tile.data_passes
    # {"CryptoObject": [names], ...}: the names each requested Cryptomatte layer hashes (its manifest,
    # core.data_passes.cryptomatte_metadata)
    cryptomatte: dict = field(default_factory=dict)
    # settings.light_passes: name -> (h, w, 3) float32 (core.light_passes: Direct/Indirect divided by Color)
    light_passes: dict[str, np.ndarray] | None = None
    shader_aovs: dict[str, np.ndarray] | None = None  # see Tile.shader_aovs
    light_groups: dict[str, np.ndarray] | None = None  # see Tile.light_groups


ProgressCallback = Callable[[Progress], None]
TileCallback = Callable[[Tile], None]
CancelCallback = Callable[[], bool]


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
    prepared: tuple[PreparedScene, Accelerator] | None = None,
) -> RenderResult:
    """Render `scene` with `settings`.

    region: (x0, y0, width, height) in pixels of the full resolution, y0 from the top (render border/crop);
    None renders the whole frame. The result arrays cover the region only.

    Work is split into tiles x sample batches: each batch traces at most settings.batch_paths paths, so
    memory is bounded by the batch, not by the image or the sample count. Samples are taken in passes over
    the tiles (a pass gives every tile as many samples as fit in one batch), so long renders refine the image
    progressively. The passes go round one window of tiles at a time (core.schedule.FILM_WINDOW_PIXELS, 2^21
    pixels: a 1080p frame is one window), so that only that window's films are alive when tiles need several
    passes; with a time limit they go round the whole image, which a time limit then leaves complete and
    evenly noisier. A cancel leaves the windows not yet reached without their samples.
    on_tile is called with each tile after each pass over it (its current state); on_progress after every
    batch; should_cancel is polled before each batch is queued: when it returns True the render stops and the
    result (cancelled=True) holds every sample taken so far (pixels no batch reached yet are 0); batches
    running on other threads at that moment finish and count, silently (no callback after the cancel).
    Batches run on settings.thread_count worker threads and are accumulated in the order they were queued, so
    the image does not depend on the thread count. adaptive_threshold > 0 turns on adaptive sampling.
    tile_order: a permutation of the tile list (for testing that images don't depend on it).
    prepared: the scene's (PreparedScene, Accelerator) from prepare_scene() when the caller keeps them between
    renders (the viewport): they must come from a scene with the same geometry, materials, lights and world;
    only the camera may differ (rays then start from the new camera position in the prepared frame).
    """
    t_start = time.perf_counter()
    say = log or _silent
    region = _check_inputs(scene, settings, region, camera_only=prepared is not None)
    # A cold cache is said before the work; otherwise the first kernel this scene needs that the cache lacks says
    # so when it starts compiling (a worker thread calls `say` then), rather than leaving the render silent.
    with compile_notices(None if say is _silent or _said_cache_cold(scene, say) else say):
        if prepared is None:
            prepared, accel, t_prepare = _prepare(scene, settings, say)
        else:
            (prepared, accel), t_prepare = prepared, 0.0
            prepared.update_camera(scene.camera)  # a moved camera (the viewport's): what Camera / Window nodes read
        job = _TileRender(scene, settings, prepared, accel, region, tile_order, t_start,
                          on_tile, on_progress, should_cancel)
        job.run()
    return job.result(t_prepare, say)


@dataclass
class TileSamples:
    """Raw film sums of samples [sample_start, sample_end) of one tile (index into the frame's tile list).

    films: with sample_start 0 there is one, the tile's film state (TileFilm.state()) after those samples exactly
    as render() holds it; otherwise one per sample pass, in pass order, each the pass's raw float64 sums
    (TileFilm.take_pass()), to be folded into the film holding the earlier samples pass by pass
    (TileFilm.add_sums), which is what render() does with them: the merge is bit-identical to one render()
    whatever machine took which range.
    """

    tile_index: int
    sample_start: int
    sample_end: int
    films: list[dict[str, np.ndarray]]
    # Cycles' data passes (settings.data_passes), as `films`: the DataFilm's state() from sample 0, else one
    # take_pass() per sample pass; crypto_names: each Cryptomatte kind's names, which its sums index.
    data: list[dict[str, np.ndarray]] = field(default_factory=list)
    crypto_names: dict[str, list[str]] = field(default_factory=dict)

    def nbytes(self) -> int:
        """Bytes of the sums (what a cluster worker sends back for this range)."""
        return sum(a.nbytes for sums in self.films + self.data for a in sums.values())


def render_samples(scene: Scene, settings: RenderSettings, work: SampleRanges, *,
                   region: tuple[int, int, int, int] | None = None,
                   prepared: tuple[PreparedScene, Accelerator] | None = None) -> list[TileSamples]:
    """Take samples [start, end) of some tiles of the frame (work: tile index -> (start, end); tiles as
    core.schedule.tiles cuts the region, the whole frame when None, with settings.tile_size, as render() with
    that region cuts it) and return their raw film sums, for a render split across processes or machines
    (core.distributed) and merged with merge_tile_samples.

    Each range must start and end on one of the tile's sample-pass boundaries (core.schedule.pass_bounds); with
    adaptive sampling only whole tiles (0, spp), since which pixels a pass samples depends on the passes before.
    prepared: the scene's (PreparedScene, Accelerator) when the caller keeps them between calls (built here
    otherwise). No time limit, progress or cancel: a range is the unit of work a scheduler cancels.
    """
    region = _check_inputs(scene, settings, region)
    if settings.time_limit > 0:  # a range always runs to its end (a time limit is the caller's to apply)
        settings = settings.replace(time_limit=0.0)
    if prepared is None:
        prepared = _prepare(scene, settings, _silent)[:2]
    job = _TileRender(scene, settings, prepared[0], prepared[1], region, None, time.perf_counter(),
                      None, None, None, work=work)
    job.run()
    return job.tile_samples()


def merge_tile_samples(scene: Scene, settings: RenderSettings, parts: list[TileSamples], *,
                       region: tuple[int, int, int, int] | None = None, partial: bool = False) -> RenderResult:
    """The frame (or the region, as render_samples() was given it) from the film sums of render_samples() calls
    that together cover every sample of every tile: the result's images equal render()'s bit for bit (stats
    hold only what the merge knows).

    partial: the parts may stop short of settings.spp (a time limit stopped handing out ranges): each tile holds
    the samples of its parts from 0 up to the first missing range (later parts are left out), a tile without any
    stays black with count 0, and the result is marked cancelled, as a local render stopped by its time limit.
    Each tile's pixels are then what render() makes of exactly those samples."""
    width, height = scene.camera.resolution
    region = (0, 0, width, height) if region is None else tuple(int(v) for v in region)
    tile_list = tiles(*region, settings.tile_size)
    sampler = make_sampler(settings.sampler, settings.seed, max(settings.spp, 1), groups=settings.variance_groups)

    def make_film(t: TileRect) -> TileFilm:
        return TileFilm(t[2], t[3], settings.aovs, sampler, settings.denoising_features, alpha=scene.has_alpha,
                        catcher=CatcherOutput.of(scene), light_passes=settings.light_passes,
                        shader_aovs=scene.shader_aovs, light_groups=scene.light_groups,
                        error_estimate=settings.error_estimate)

    tables = merge_data_tables(settings, parts)
    data_films = [DataFilm(t[2], t[3], tables) for t in tile_list] if tables is not None else None
    by_tile: dict[int, list[TileSamples]] = {}
    for part in parts:
        if not 0 <= part.tile_index < len(tile_list):
            raise ValueError(f"tile index {part.tile_index} is not one of the frame's {len(tile_list)} tiles")
        by_tile.setdefault(part.tile_index, []).append(part)
    # One tile at a time: its parts folded into its film, its images written into the frame and the film
    # released, so only one film is alive beside the parts and the frame (as render()'s FrameImages does).
    first = make_film(tile_list[0]) if tile_list else None
    frame = FrameImages(region, settings.aovs, first,
                        world_to_camera(scene) if first is not None and first.features else None)
    reached = [0] * len(tile_list)
    for ti, tile in enumerate(tile_list):
        film = first if ti == 0 else make_film(tile)
        for part in sorted(by_tile.get(ti, []), key=lambda p: p.sample_start):
            if part.sample_start != reached[ti]:
                if partial and part.sample_start > reached[ti]:
                    continue  # past a missing range: its samples cannot be added without those before them
                raise ValueError(f"tile {ti}: samples from {part.sample_start} follow samples up to {reached[ti]}")
            if part.sample_start == 0 and len(part.films) != 1:
                raise ValueError(f"tile {ti}: samples from 0 come as one film state, not {len(part.films)}")
            fold_tile_part(film, None if data_films is None else data_films[ti], part)
            reached[ti] = part.sample_end
        frame.put(tile, film)
        film.release()
    missing = [ti for ti, r in enumerate(reached) if r != settings.spp]
    if missing and not partial:
        raise ValueError(f"tiles {missing[:8]} do not hold all {settings.spp} samples")
    color, variance, albedo, normal, depth, counts, features, extras = frame.images()
    stats = {"scene": scene.name, "resolution": [width, height], "region": list(region), "spp": settings.spp,
             "samples": int(counts.sum())}
    result = RenderResult(color, variance, albedo, normal, depth, counts, stats, list(scene.warnings),
                          bool(missing))
    if features is not None:
        result.denoising_albedo, result.denoising_normal = features
    for name, value in extras.items():
        setattr(result, name, value)
    if data_films is not None:
        result.data_passes = assemble_data(list(zip(tile_list, data_films)), region)
        result.cryptomatte = manifests(tables)
    return result


def merge_data_tables(settings: RenderSettings, parts: list[TileSamples]) -> DataTables | None:
    """The data passes' tables for films merged from `parts` (None without data passes): the Cryptomatte names
    come with the parts (each unit's render listed them from the same scene)."""
    if not settings.data_passes:
        return None
    names = next((p.crypto_names for p in parts if p.crypto_names), {})
    return DataTables.for_merge(tuple(settings.data_passes), 2 * math.ceil(settings.cryptomatte_levels / 2), names)


def fold_tile_part(film: TileFilm, data_film: DataFilm | None, part: TileSamples) -> None:
    """Add one range's sums to its tile's films (those holding the tile's samples before part.sample_start): its
    film state from sample 0, else its passes' sums one by one in pass order, as render() adds them."""
    if data_film is not None and len(part.data) != len(part.films):
        raise ValueError(f"tile {part.tile_index}: samples from {part.sample_start} come without the data passes' "
                         f"sums ({len(part.data)} for {len(part.films)} films)")
    if part.sample_start == 0:
        film.set_state(part.films[0])
        if data_film is not None:
            data_film.set_state(part.data[0])
        return
    for sums in part.films:
        film.add_sums(sums)
    for sums in part.data if data_film is not None else ():
        data_film.add_sums(sums)


class FrameImages:
    """A region's images (see Tile for the arrays), filled tile by tile from the tiles' films as each is final.

    The arrays are allocated at once but zeroed lazily (np.zeros), so their memory is committed as tiles are
    written, while each tile's film is released (TileFilm.release) as soon as it is read: films and images are
    never all held at once, and at low sample counts, where each tile is final after one pass, only the films
    of the tiles in flight are held. put() returns the tile's images as views of the region's arrays, so a
    tile shown as it lands (Render callbacks) is not built a second time for the frame."""

    def __init__(self, region: TileRect, aovs: bool, film: TileFilm | None,
                 world_to_camera: np.ndarray | None = None) -> None:
        """film: any of the region's tile films (they share their settings), None for an empty region;
        world_to_camera: the rotation that turns the denoising normal to camera space (the denoising features are
        written only with it, where the films keep them)."""
        self.region, self.aovs = region, aovs
        rx, ry, rw, rh = region
        self.color = np.zeros((rh, rw, 4), np.float32)
        # none without the error estimate (core.settings.RenderSettings.error_estimate): Tile / RenderResult.variance None
        self.variance = np.zeros((rh, rw, 3), np.float32) if film is None or film.error_estimate else None
        self.albedo = np.zeros((rh, rw, 3), np.float32) if aovs else None
        self.normal = np.zeros((rh, rw, 3), np.float32) if aovs else None
        # (0 until a tile's images are written: put() writes 1e10 where nothing was hit, and every tile is put)
        self.depth = np.zeros((rh, rw), np.float32) if aovs else None
        self.counts = np.zeros((rh, rw), np.int32)
        # add_aovs(): float64 / int64 sums for one tile's pixels, one set per thread (worker threads write tiles
        # that are final within their batch, core.render._TileRender._finish_in_worker)
        self._aov_scratch = threading.local()
        # put_one_sample() without AOVs: empty stand-ins for its kernel's AOV arrays
        self._no_aov1, self._no_aov2 = np.zeros(0, np.float32), np.zeros((0, 3), np.float32)
        self._no_aov3 = np.zeros((0, 0, 3), np.float32)
        self.extras: dict = {}
        if film is not None and film.catcher is not None:
            self.extras["shadow_catcher"] = np.ones((rh, rw, 3), np.float32)
            self.extras["shadow_catcher_matte"] = np.zeros((rh, rw, 4), np.float32)
        if film is not None and film.light_passes:
            self.extras["light_passes"] = {name: np.zeros((rh, rw, 3), np.float32) for name in film.light_passes}
        if film is not None and film.shader_aovs:
            self.extras["shader_aovs"] = {name: np.zeros((rh, rw, 4 if kind == "COLOR" else 1), np.float32)
                                          for name, kind in film.shader_aovs}
        if film is not None and film.light_groups:
            self.extras["light_groups"] = {pass_name(name): np.zeros((rh, rw, 3), np.float32)
                                           for name in film.light_groups}
        self.features = None
        self.rot = world_to_camera
        if film is not None and film.features and world_to_camera is not None:
            self.features = (np.zeros((rh, rw, 3), np.float32), np.zeros((rh, rw, 3), np.float32))

    def add_aovs(self, tile: TileRect, pixel: np.ndarray, albedo: np.ndarray, normal: np.ndarray,
                 depth: np.ndarray) -> None:
        """Sum a local render's first-hit AOVs of samples at the tile's `pixel` (tile-local) straight into the
        region's albedo, normal and depth images, instead of into the tile's film (whose memory per pixel that
        halves: the images exist anyway). The depth hits are counted in the sample-count image until the tile is
        put(), which makes the sums the AOV images (core.film_kernels.add_aovs_to_frame / finish_frame_aovs: the
        operations of the film's AOV sums and images, so the same bits). A tile's film then keeps no AOVs."""
        tw, th = tile[2:]
        n = tw * th
        pixel = np.ascontiguousarray(pixel, np.int64).reshape(-1)
        if len(pixel) and (pixel.min() < 0 or pixel.max() >= n):
            raise ValueError(f"frame: pixel index out of range [0, {n}) for a {tw}x{th} tile")
        scratch = getattr(self._aov_scratch, "buffers", None)
        if scratch is None or len(scratch[1]) != n:
            scratch = self._aov_scratch.buffers = (np.zeros((n, 6)), np.zeros(n), np.zeros(n, np.int64))
        f64 = lambda a: np.ascontiguousarray(a, np.float64)
        rows, columns = self.slice(tile)
        film_kernels.add_aovs_to_frame(pixel, f64(albedo), f64(normal), f64(depth).reshape(-1), rows.start,
                                       columns.start, tw, self.albedo, self.normal, self.depth, self.counts,
                                       *scratch)

    def slice(self, tile: TileRect) -> tuple[slice, slice]:
        """The (rows, columns) slices of a tile (inside the region) in the region's images."""
        tx, ty, tw, th = tile
        oy, ox = ty - self.region[1], tx - self.region[0]
        return slice(oy, oy + th), slice(ox, ox + tw)

    def put(self, tile: TileRect, film: TileFilm, samples: int = 0) -> Tile:
        """Write a tile's images from its film (and, where the film keeps no AOVs, from the AOV sums add_aovs()
        left in the region's images); returns them as a Tile of views into the region's arrays (samples: what
        Tile.samples reports). The film is left as it is (the caller releases it)."""
        tx, ty, tw, th = tile
        sl = self.slice(tile)
        oy, ox = sl[0].start, sl[1].start  # the tile's first row and column in the region's images
        film.write_colour_images(self.color, self.variance, oy, ox)
        out = Tile(tx, ty, self.color[sl], self._variance(sl), samples=samples)
        if self.aovs:
            if film.aovs:
                film.write_aov_images(self.albedo, self.normal, self.depth, oy, ox)
            else:  # the sums are in the images (and the depth hits in the counts, read before they are written)
                film_kernels.finish_frame_aovs(film.sample_count, oy, ox, tw, self.albedo, self.normal, self.depth,
                                               self.counts)
            out.albedo, out.normal, out.depth = self.albedo[sl], self.normal[sl], self.depth[sl]
        self.counts[sl] = film.count.reshape(th, tw)
        if self.features is not None:
            feature_albedo, feature_normal = film.feature_images()
            self.features[0][sl] = feature_albedo
            self.features[1][sl] = feature_normal @ self.rot.T
            out.denoising_albedo, out.denoising_normal = self.features[0][sl], self.features[1][sl]
        if "shadow_catcher" in self.extras:
            catcher, matte = film.shadow_catcher_images()[:2]
            self.extras["shadow_catcher"][sl], self.extras["shadow_catcher_matte"][sl] = catcher, matte
            out.shadow_catcher = self.extras["shadow_catcher"][sl]
            out.shadow_catcher_matte = self.extras["shadow_catcher_matte"][sl]
        # the named images of the light passes, shader AOVs and light groups: Tile attribute -> the film's images
        for key, images in (("light_passes", film.light_pass_images), ("shader_aovs", film.shader_aov_images),
                            ("light_groups", film.light_group_images)):
            if key in self.extras:
                frame, tile_images = self.extras[key], images()
                for name, arr in tile_images.items():
                    frame[name][sl] = arr
                setattr(out, key, {name: frame[name][sl] for name in tile_images})
        return out

    def put_one_sample(self, tile: TileRect, radiance: np.ndarray, albedo: np.ndarray | None,
                       normal: np.ndarray | None, depth: np.ndarray | None) -> Tile:
        """Write a tile that takes exactly one sample per pixel (pixel p's in row p of each array, float32) without
        a film: the bits a film and put() would write (core.film_kernels add_colour, colour_images,
        add_aovs_to_frame and finish_frame_aovs at one sample: the film's shift is the sample and its deviations 0,
        so the colour is `sample + 0.0`; one filled variance group, so the variance is 0, which the frame's
        zeroed image already holds; alpha 1; the AOV sums `0 + value` divided by 1, the normal made unit, depth
        1e10 where nothing was hit) in one compiled pass over the tile
        (core.film_kernels.one_sample_images) instead of four compiled walks over a film. Only for
        films with nothing but colour (no alpha, shadow catcher, denoising features, light passes, shader AOVs
        or light groups): _TileRender._one_sample decides. `tests/test_render_whole_tiles.py` compares it with
        the film's path bit for bit."""
        tx, ty, tw, th = tile
        sl = self.slice(tile)
        f32 = lambda a: np.ascontiguousarray(a, np.float32)
        if self.aovs:
            aov_in = (f32(albedo), f32(normal), f32(depth).reshape(-1))
            aov_out = (self.albedo, self.normal, self.depth)
        else:  # (not read: arrays of the kernel's types, so that it has one signature)
            aov_in = (self._no_aov2, self._no_aov2, self._no_aov1)
            aov_out = (self._no_aov3, self._no_aov3, self._no_aov1.reshape(0, 0))
        film_kernels.one_sample_images(f32(radiance), *aov_in, bool(self.aovs), sl[0].start, sl[1].start, tw,
                                       self.color, *aov_out, self.counts)
        out = Tile(tx, ty, self.color[sl], self._variance(sl), samples=1)
        if self.aovs:
            out.albedo, out.normal, out.depth = self.albedo[sl], self.normal[sl], self.depth[sl]
        return out

    def _variance(self, sl: tuple[slice, slice]) -> np.ndarray | None:
        return None if self.variance is None else self.variance[sl]

    def images(self) -> tuple:
        """(color, variance, albedo, normal, depth, sample counts, denoising features, extras): the region's images
        (AOVs None when settings.aovs is off; the features (albedo, normal in camera space) None unless the films
        keep them), and the extras: {RenderResult attribute: image} of the shadow catcher's, the light passes',
        the shader AOVs' and the light groups' images where the films keep them."""
        return (self.color, self.variance, self.albedo, self.normal, self.depth, self.counts, self.features,
                self.extras)


def tile_result(tile: TileRect, film: TileFilm, samples: int, aovs: bool,
                world_to_camera: np.ndarray | None = None, frame: FrameImages | None = None) -> Tile:
    """A tile's images from its film, in arrays of its own (samples: what Tile.samples reports;
    world_to_camera: the rotation that turns the denoising normal to camera space, needed for the denoising
    features when the film keeps them; frame: the render's FrameImages, which hold the AOV sums of a local
    render's films (FrameImages.add_aovs): they are copied, so the frame's running sums are left as they are)."""
    images = FrameImages(tile, aovs, film, world_to_camera)
    if aovs and not film.aovs:
        if frame is None:
            raise ValueError("tile_result: a film without AOV sums needs the frame that holds them")
        sl = frame.slice(tile)
        images.albedo[...] = frame.albedo[sl]
        images.normal[...] = frame.normal[sl]
        images.depth[...] = frame.depth[sl]
        images.counts[...] = frame.counts[sl]  # the depth hits, borrowed until the tile is final
    return images.put(tile, film, samples)


def world_to_camera(scene: Scene) -> np.ndarray:
    """(3, 3) rotation from world to Cycles' camera space (+x right, +y up, +z the view direction) of the
    scene's camera: the rows are the camera's local X, Y and -Z axes, normalised (a scaled camera keeps its
    directions)."""
    axes = np.asarray(scene.camera.matrix_world, np.float64)[:3, :3].T.copy()
    axes[2] *= -1
    return axes / np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-30)


def _silent(_msg: str) -> None:
    pass


def _said_cache_cold(scene: Scene, say: Callable[[str], None]) -> bool:
    """Say that the render compiles the kernels first when the kernel cache is cold (reads the cache folder, so
    only when there is someone to tell); True when said."""
    if say is _silent:
        return False
    programs = any(getattr(m, "program", None) is not None for m in scene.materials)
    if not compile_cache_is_cold(programs):
        return False
    say("compiling the render kernels (first render after an install or update, about a minute; cached after)")
    return True


def _check_inputs(scene: Scene, settings: RenderSettings, region, camera_only: bool = False) -> TileRect:
    """Validate the settings, the scene (camera_only: its camera; the rest was validated when it was prepared)
    and the region (the whole frame when None), and refuse a render that would not fit in memory (a clear error
    instead of an out-of-memory kill). Returns the region."""
    settings.validate()
    if camera_only:
        scene.camera.validate()
    else:
        scene.validate()
    width, height = scene.camera.resolution
    if region is None:
        region = (0, 0, width, height)
    rx, ry, rw, rh = (int(v) for v in region)
    if rw < 1 or rh < 1 or rx < 0 or ry < 0 or rx + rw > width or ry + rh > height:
        raise ValueError(f"render region {region} is not inside the {width}x{height} frame")
    check_render_memory(scene, settings, rw * rh)
    return rx, ry, rw, rh


def _prepare(scene: Scene, settings: RenderSettings, say) -> tuple[PreparedScene, Accelerator, float]:
    """The scene flattened for rendering and its ray-casting structure; (prepared, accel, seconds taken)."""
    t0 = time.perf_counter()
    prepared = PreparedScene.build(scene, sample_world=settings.light_sampling == "light",
                                   threads=settings.thread_count)
    # Parallelism is across batches (see _TileRender), so each Embree call runs on the worker that makes it.
    accel = Accelerator(prepared.vertices, prepared.triangles, motion=prepared.motion)
    t_prepare = time.perf_counter() - t0
    for w in scene.warnings:
        say(f"warning: {w}")
    say(f"scene {scene.name}: {len(prepared.triangles)} triangles, features {prepared.features}, "
        f"prepared in {t_prepare:.2f} s")
    return prepared, accel, t_prepare


def prepare_scene(scene: Scene, settings: RenderSettings) -> tuple[PreparedScene, Accelerator]:
    """The scene flattened for rendering and its Embree scene, for callers that render it many times with
    render(prepared=...) (the viewport's progressive passes, camera moves)."""
    scene.validate()
    prepared, accel, _ = _prepare(scene, settings, _silent)
    return prepared, accel


def _peak_memory_mb() -> float:
    if resource is None:
        return float("nan")
    try:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    except OSError:
        return math.nan


class _LazyFilms(dict):
    """tile -> TileFilm, each made by `make(tile)` on its first lookup (`make` itself: a film not kept here)."""

    def __init__(self, make: Callable[[TileRect], TileFilm]) -> None:
        super().__init__()
        self.make = make

    def __missing__(self, tile: TileRect) -> TileFilm:
        film = self[tile] = self.make(tile)
        return film


_SKIPPED = object()  # _add_in_order: a segment a cancel dropped (its tile's later segments go on without it)
_NO_REPORT: tuple[bool, None] = (False, None)


class _TileAdds:
    """One tile's segments on their way into its film (_TileRender._add_in_order): those that arrived before their
    turn (Segment.order -> the item to add), the next to add, whether a thread is adding, and the reports of those
    added for the calling thread."""

    __slots__ = ("pending", "next", "draining", "reports")

    def __init__(self) -> None:
        self.pending: dict[int, object] = {}
        self.next = 0
        self.draining = False
        self.reports: dict[int, tuple[bool, Tile | None]] = {}


class _TileRender:
    """One render while its batches run: the tiles' films, the batches in flight, the counters.

    Batches run on `workers` threads (NumPy, numba and Embree release the GIL), about `workers + 1` batches' paths
    in flight (the last, smaller batches of core.schedule.tail_target more of them). Each tile's film sums its
    segments in the order they were queued, so the image does not depend on timing. A tile whose samples all lie
    in one segment of one batch (every tile at 1 spp) is summed into a film of its own and written into the
    frame's images by the worker thread that traced it (nothing else feeds that film, so the bits are the same);
    a tile of several segments gets them from whichever worker holds its next one (_add_in_order). The calling
    thread then only reports them (progress, on_tile) in submission order; one thread alone, sample ranges, data
    passes and adaptive sampling have it add the segments itself. A batch
    holds about `target` paths, gathered from as many tile passes as it takes (at 1 spp a 64x64 tile is only
    4096 paths, far too few to amortise NumPy's per-call cost); small images are split into at least 8 batches
    (core.schedule.batch_target) so that threads share them, and the last ones shrink so that the threads finish
    together (core.schedule.tail_target, which alone depends on the thread count: it cuts a tile's pass at pixel
    boundaries, which changes no sum). The image depends on none of this.
    """

    def __init__(self, scene: Scene, settings: RenderSettings, prepared: PreparedScene, accel: Accelerator,
                 region: TileRect, tile_order: list[int] | None, t_start: float,
                 on_tile: TileCallback | None, on_progress: ProgressCallback | None,
                 should_cancel: CancelCallback | None, work: SampleRanges | None = None) -> None:
        self.scene, self.settings, self.prepared, self.accel = scene, settings, prepared, accel
        self.region, self.t_start = region, t_start
        # Rays start relative to the camera; the prepared frame is relative to prepared.shift.
        offset = np.asarray(scene.camera.position, np.float64) - np.asarray(prepared.shift, np.float64)
        self.camera_offset = offset.astype(np.float32) if np.any(offset != 0) else None
        # Motion blur: rays carry a time only when something moves (a still scene reads no time at all).
        self.motion = (prepared.motion is not None or scene.camera.motion_matrices is not None
                       or scene.camera.motion_lens is not None)
        self.on_tile, self.on_progress, self.should_cancel = on_tile, on_progress, should_cancel
        self.sampler = make_sampler(settings.sampler, settings.seed, max(settings.spp, 1), groups=settings.variance_groups)
        self.pixel_filter = PixelFilter(settings.filter_type, settings.filter_width)
        rx, ry, rw, rh = region
        self.tiles = tiles(rx, ry, rw, rh, settings.tile_size)
        if tile_order is not None:
            if sorted(tile_order) != list(range(len(self.tiles))):
                raise ValueError("tile_order must be a permutation of the tile indices")
            self.tiles = [self.tiles[i] for i in tile_order]
        alpha = scene.has_alpha
        catcher = CatcherOutput.of(scene)
        # Each tile's film is made when first asked for (its first samples): at low spp, where tiles are final
        # after one pass and released then, films are made and freed a few at a time, and memory freed by one
        # is reused by the next instead of all films' small arrays staying resident in the heap.
        # A local render sums the AOVs into its frame's images (FrameImages.add_aovs), render_samples() into the films
        # it hands on.
        film_aovs = settings.aovs and work is not None
        self.films = _LazyFilms(lambda t: TileFilm(t[2], t[3], film_aovs, self.sampler,
                                                   settings.denoising_features, alpha=alpha, catcher=catcher,
                                                   light_passes=settings.light_passes,
                                                   shader_aovs=scene.shader_aovs,
                                                   light_groups=scene.light_groups,
                                                   error_estimate=settings.error_estimate))
        # Cycles' data passes (core.data_passes); render_samples() hands their sums on beside the films'
        self.data_tables = None
        self.data_films: dict = {}
        if settings.data_passes:
            self.data_tables = DataTables.build(scene, prepared, tuple(settings.data_passes),
                                                2 * math.ceil(settings.cryptomatte_levels / 2))
            wanted = self.tiles if work is None else [self.tiles[int(ti)] for ti in work
                                                      if 0 <= int(ti) < len(self.tiles)]
            self.data_films = {t: DataFilm(t[2], t[3], self.data_tables) for t in wanted}

        self.spp = int(settings.spp)
        self.total_paths = self.spp * rw * rh
        self.done_paths = 0
        self.cancelled = False
        self.samples_started = np.zeros(len(self.tiles), np.int64)
        self.pixels_converged = np.zeros(len(self.tiles), np.int64)  # adaptive sampling: pixels that stopped early
        self.largest_batch = 0  # paths in the largest batch traced (memory scales with it, times the threads)
        self.film_seconds = 0.0  # film sums, on whichever thread did them (whole tiles: the workers), summed
        self.assembly_seconds = 0.0  # the tiles' images written into the frame's, summed over the threads
        self.adaptive = settings.adaptive_threshold > 0
        self.min_samples = settings.adaptive_min_samples_for(self.spp) if self.adaptive else self.spp
        # render_samples(): only these sample ranges are taken; tiles whose range starts past 0 keep each pass's
        # sums apart (the merge adds them to the earlier passes' film one pass at a time, as render() does).
        self.work = self._check_work(work) if work is not None else None
        self.pass_sums: dict[int, list[dict[str, np.ndarray]]] = {}
        self.data_pass_sums: dict[int, list[dict[str, np.ndarray]]] = {}
        for ti, (start, _end) in (self.work or {}).items():
            if start > 0:  # these tiles' films keep each pass's raw sums apart (TileFilm.capture_passes)
                self.films[self.tiles[ti]].capture_passes()
                if self.data_tables is not None:
                    self.data_films[self.tiles[ti]].capture_passes()

        # The region's images, each tile's written (and its film released) as soon as its last pass lands
        # (FrameImages); render_samples() hands films on instead.
        self.frame: FrameImages | None = None
        self.final: set[int] = set()  # tiles already in self.frame
        if work is None:
            self.frame = FrameImages(region, settings.aovs, self.films[self.tiles[0]] if self.tiles else None,
                                     world_to_camera(scene) if settings.denoising_features else None)

        # tiles of one sample per pixel whose films would hold nothing but colour are written without a film
        # (FrameImages.put_one_sample: the same bits)
        self._one_sample = (self.spp == 1 and self.frame is not None and not alpha and catcher is None
                            and not settings.light_passes and not scene.shader_aovs and not scene.light_groups
                            and not settings.denoising_features and self.data_tables is None)
        self.workers = settings.thread_count
        self.target = batch_target(settings, self.total_paths)
        if self.adaptive:
            self.target = adaptive_batch_target(self.target, rw * rh, self.min_samples)
        self.pool: ThreadPoolExecutor | None = None
        self.in_flight: deque = deque()  # (segments, job)
        self.in_flight_paths = 0  # their paths
        self.group: list[Segment] = []  # segments of the batch being gathered
        self.group_paths = 0
        self.tracers: list[PathTracer] = []  # one per worker thread
        self.local_state = threading.local()
        self.tracers_lock = threading.Lock()
        # Segments of tiles that take several passes are added to their films by the worker threads, each tile's
        # in the order they were queued (_add_in_order), not all by the calling thread: with many threads, one
        # thread summing every sample would be the render's limit. Not for a local render's sample ranges, data
        # passes or adaptive sampling, whose passes the calling thread reads as they land.
        self._ordered_adds = self._adds_in_workers()  # decided once: a tile's segments must all go one way
        self._queued_segments: dict[int, int] = {}  # tile index -> its segments queued so far (Segment.order)
        self._tile_adds: dict[int, _TileAdds] = {}
        self._adds = threading.Condition()  # guards _tile_adds and _adds_failed; notified as segments land
        self._adds_failed: BaseException | None = None

    # ----------------------------------------------------------------------------------------- the pass loop
    def run(self) -> None:
        """Queue every pass's segments in batches until all samples are taken or the render is stopped."""
        self.pool = ThreadPoolExecutor(self.workers) if self.workers > 1 else None
        try:
            # One window of tiles at a time (their films alone alive when tiles need several passes), except
            # under a time limit, where every pass goes round the whole image so that it sharpens evenly.
            window = FILM_WINDOW_PIXELS if self.settings.time_limit <= 0 else 0
            # the paths still to hand out, for the shrinking last batches (tail_target); adaptive sampling's
            # passes skip converged pixels, so their count is not known ahead: its batches keep their size
            left = None if self.adaptive or self.pool is None else self._paths_to_trace(window)
            for ti, tile, first_sample, count in sample_passes(self.tiles, self.spp, self.settings,
                                                               self.min_samples, window):
                if self.work is not None and not self._in_work(ti, first_sample, count):
                    continue
                pixels = np.arange(tile[2] * tile[3], dtype=np.int64)
                if self.adaptive and first_sample >= self.min_samples:
                    pixels = self._unconverged_pixels(ti, tile, first_sample, count)
                    if len(pixels) == 0:
                        continue
                target = self.target
                if left is not None:
                    target = tail_target(self.target, left + self.group_paths, self.workers)
                    left -= len(pixels) * count
                for seg in pass_segments(ti, tile, pixels, first_sample, count, target):
                    if self._stop_requested():
                        self.cancelled = True
                        break
                    if tail_piece_overfills(target, self.target, self.group_paths, len(seg.loc)):
                        self._submit()  # the batch goes first, alone
                    self.group.append(seg)
                    self.group_paths += len(seg.loc)
                    if self.group_paths >= target:
                        self._submit()
                if self.cancelled:
                    break
            if self.cancelled:
                self._drop_queued_batches()
            self._submit()
            while self.in_flight:
                self._finish_one()
        finally:
            if self.pool is not None:
                for _, job in self.in_flight:
                    job.cancel()
                self.pool.shutdown(wait=True)

    def _paths_to_trace(self, window: int) -> int:
        """Paths of every pass the run will queue (the sample ranges' alone under render_samples())."""
        return sum(tile[2] * tile[3] * count
                   for ti, tile, first_sample, count in sample_passes(self.tiles, self.spp, self.settings,
                                                                      self.min_samples, window)
                   if self.work is None or self._in_work(ti, first_sample, count))

    def _unconverged_pixels(self, ti: int, tile: TileRect, first_sample: int, count: int) -> np.ndarray:
        """Adaptive sampling: the tile's pixels still above the noise threshold, once its earlier samples are all
        in; a tile with none left is reported done for this pass."""
        n_pix = tile[2] * tile[3]
        if ti in self.final:  # converged whole at an earlier pass: its images are in the frame, its film released
            self.done_paths += n_pix * count
            self.samples_started[ti] = first_sample + count
            self._progress(ti, first_sample + count)
            return np.zeros(0, np.int64)
        if any(seg.tile_index == ti for seg in self.group):
            self._submit()
        while self._tile_busy(ti):  # the convergence test needs this tile's earlier samples
            self._finish_one()
        pixels = self.films[tile].active_pixels(self.settings.adaptive_threshold)
        self.pixels_converged[ti] = n_pix - len(pixels)
        self.done_paths += (n_pix - len(pixels)) * count  # samples converged pixels no longer need
        if len(pixels) == 0:
            self.samples_started[ti] = first_sample + count
            self._progress(ti, first_sample + count)
            if self.frame is not None:  # final now (no pixel takes more samples): its images once, film released
                out = self._final_tile(ti, tile, self.films[tile], first_sample + count)
            else:
                out = self._tile_result(tile, self.films[tile], first_sample + count)
            if self.on_tile is not None:
                self.on_tile(out)
        return pixels

    def _drop_queued_batches(self) -> None:
        """After a cancel: batches still queued never start; ones already running finish (a path batch cannot
        stop halfway without bias) and their samples are kept, but no callback reports anything any more."""
        self.group, self.group_paths = [], 0
        while self.in_flight:
            job = self.in_flight[0][-1]
            if self.pool is not None and job.cancel():
                segments, _ = self._pop_oldest()
                done = {"film": 0.0, "assembly": 0.0}
                for seg in segments:  # later segments of their tiles, already running, are added without them
                    if self._ordered_adds and not self._whole_tile(seg):
                        self._add_in_order(seg, _SKIPPED, done)
                self.film_seconds += done["film"]
                self.assembly_seconds += done["assembly"]
            else:
                self._finish_one(quiet=True)

    def _stop_requested(self) -> bool:
        if self.should_cancel is not None and self.should_cancel():
            return True
        return self.settings.time_limit > 0 and time.perf_counter() - self.t_start > self.settings.time_limit

    def _tile_busy(self, ti: int) -> bool:
        return any(seg.tile_index == ti for segments, _ in self.in_flight for seg in segments)

    # ------------------------------------------------------------------------------------------- batches
    def _submit(self) -> None:
        """Queue the gathered segments as one batch; beyond `workers` batches in flight that hold more than
        `workers` full batches' paths, finish the oldest. (The paths bound lets the small last batches of
        tail_target queue up behind a large one still running: a thread that is done with its own takes the
        next instead of waiting for the calling thread, which waits for the oldest. Queued batches hold only
        their pixel and sample indices; the threads trace one at a time each, so the paths alive are bounded as
        before.)"""
        if not self.group:
            return
        segments, self.group = self.group, []
        for seg in segments:  # each tile's segments in queue order: the order its film sums them in
            seg.order = self._queued_segments.get(seg.tile_index, 0)
            self._queued_segments[seg.tile_index] = seg.order + 1
        self.largest_batch = max(self.largest_batch, self.group_paths)
        self.in_flight_paths += self.group_paths
        self.group_paths = 0
        if self.pool is not None:
            job = self.pool.submit(self._run_batch, segments)
        else:  # no worker threads: the batch runs on this thread when it is finished
            job = partial(self._run_batch, segments)
        self.in_flight.append((segments, job))
        if self.pool is None:
            self._finish_one()
        elif len(self.in_flight) > self.workers and self.in_flight_paths > self.workers * self.target:
            self._finish_one()

    def _pop_oldest(self) -> tuple[list[Segment], object]:
        """The oldest batch in flight (segments, job), taken off the queue and its paths off the count."""
        segments, job = self.in_flight.popleft()
        self.in_flight_paths -= sum(len(seg.loc) for seg in segments)
        return segments, job

    def _run_batch(self, segments: list[Segment]):
        """A batch's paths (_trace_batch) and, for its segments that hold a whole tile's samples (every pixel, all
        spp: at low spp nearly every tile), their films, summed and written into the frame's images here on the
        worker thread (_finish_in_worker); the other segments are added to their tiles' films in each tile's
        queue order, by the workers (_add_in_order) or, where _adds_in_workers says not, by the calling thread
        in submission order."""
        radiance, first, transparent = self._trace_batch(segments)
        finished = self._finish_in_worker(segments, radiance, first, transparent)
        if self._ordered_adds:  # every segment is added here or waits in its tile's queue: none for the calling
            radiance = first = transparent = None  # thread, so the batch's arrays go as soon as they are added
        return radiance, first, transparent, finished

    def _whole_tile(self, seg: Segment) -> bool:
        """Whether seg holds all of its tile's samples (every pixel, samples 0 .. spp) and nothing else feeds the
        tile's film: its film can be made, summed, written into the frame and released by itself, on any thread,
        with the bits the calling thread would write (a tile's film depends only on its own samples, in order)."""
        return (self.frame is not None and self.work is None and not self.adaptive and self.data_tables is None
                and seg.last_chunk and len(seg.loc) == seg.tile[2] * seg.tile[3] * self.spp)

    def _adds_in_workers(self) -> bool:
        """Whether this render's segments that are not whole tiles are added to their films by the worker threads
        (_add_in_order) rather than by the calling thread (read once, as _ordered_adds: were one tile's segments
        split between the two ways, its later ones would wait for a number never handed in)."""
        return (self.workers > 1 and self.frame is not None and self.work is None and not self.adaptive
                and self.data_tables is None)

    def _finish_in_worker(self, segments: list[Segment], radiance, first, transparent) -> dict:
        """Write the batch's whole tiles (_whole_tile) into the frame's images from films of their own, on the
        worker thread: the frame's tiles are disjoint, so threads write them side by side; their order does not
        matter. The other segments go to _add_in_order where _ordered_adds says so. Returns {segment index: the tile's
        images (Tile)} for the whole tiles, plus the film and assembly seconds (keys "film", "assembly"), which
        the calling thread adds up."""
        done: dict = {"film": 0.0, "assembly": 0.0}
        # without a film: the settings allow it (_one_sample, decided once per render) and, once per batch, the
        # tracer returned nothing a film would keep beyond colour and the frame's AOVs
        aov = first is not None and first.albedo is not None
        one_sample = (self._one_sample and transparent is None and aov == self.frame.aovs and (first is None or (
            first.features is None and first.catcher is None and first.light_passes is None
            and first.shader_aovs is None and first.light_groups is None)))
        start = 0
        for k, seg in enumerate(segments):
            rows = slice(start, start + len(seg.loc))
            start = rows.stop
            if not self._whole_tile(seg):
                if self._ordered_adds:
                    self._add_in_order(seg, (seg, rows, radiance, first, transparent), done)
                continue
            t0 = time.perf_counter()
            if one_sample:
                # (a whole tile at 1 spp holds its pixels in order: its segment's loc is 0 .. n - 1)
                done[k] = self.frame.put_one_sample(seg.tile, radiance[rows], first.albedo[rows] if aov else None,
                                                    first.normal[rows] if aov else None,
                                                    first.depth[rows] if aov else None)
                unused = self.films.pop(seg.tile, None)  # (tile 0's, made for the frame's settings)
                if unused is not None:
                    unused.release()
                done["assembly"] += time.perf_counter() - t0
                continue
            # a film of its own (tile 0's was made before the render started, for the frame: taken, still empty)
            film = self.films.pop(seg.tile, None)
            if film is None:
                film = self.films.make(seg.tile)
            self._add_segment(film, seg, rows, radiance, first, transparent)
            t1 = time.perf_counter()
            done[k] = self.frame.put(seg.tile, film, self.spp)
            film.release()
            done["film"] += t1 - t0
            done["assembly"] += time.perf_counter() - t1
        return done

    def _add_in_order(self, seg: Segment, item, done: dict) -> None:
        """Add a segment (item: its rows of the batch's results, or _SKIPPED for one a cancel dropped) to its tile's
        film after the tile's segments queued before it (Segment.order). The thread that holds a tile's next
        segment adds it and any that queued up behind it, so no thread waits for another; the others leave theirs
        in the tile's queue. Each segment's report (_add_segment_in_worker) is kept for the calling thread's
        callbacks (_report_in_order). A tile's segments are then summed in queue order, as the calling thread
        sums them, so the film holds the same bits."""
        with self._adds:
            adds = self._tile_adds.get(seg.tile_index)
            if adds is None:
                adds = self._tile_adds[seg.tile_index] = _TileAdds()
            adds.pending[seg.order] = item
            if adds.draining:
                return
            adds.draining = True
        try:
            while True:
                with self._adds:
                    order = adds.next
                    item = adds.pending.pop(order, None)
                    if item is None:
                        adds.draining = False
                        return
                    adds.next += 1
                report = _NO_REPORT if item is _SKIPPED else self._add_segment_in_worker(*item, done)
                with self._adds:
                    adds.reports[order] = report
                    self._adds.notify_all()
        except BaseException as exc:  # the calling thread must not wait for reports that will never come
            with self._adds:
                self._adds_failed = exc
                self._adds.notify_all()
            raise

    def _add_segment_in_worker(self, seg: Segment, rows: slice, radiance, first, transparent,
                               done: dict) -> tuple[bool, Tile | None]:
        """_add_segment, and where the segment ends its tile's pass what the calling thread would then do with the
        film: its images written into the frame and the film released when the tile is final, or the tile's
        images so far for on_tile. Returns (final, Tile or None)."""
        t0 = time.perf_counter()
        film = self.films[seg.tile]
        self._add_segment(film, seg, rows, radiance, first, transparent)
        t1 = time.perf_counter()
        done["film"] += t1 - t0
        if not seg.last_chunk:
            return _NO_REPORT
        if seg.sample_end == self.spp:  # final: its images once, the film released
            tile = self.frame.put(seg.tile, film, self.spp)
            film.release()
            done["assembly"] += time.perf_counter() - t1
            return True, tile
        # (after a cancel nothing more is reported: no images to make)
        return False, (None if self.on_tile is None or self.cancelled
                       else self._tile_result(seg.tile, film, seg.sample_end))

    def _report_in_order(self, seg: Segment) -> tuple[bool, Tile | None]:
        """The report of a segment _add_in_order added (waiting until it is added: a later batch's worker may be
        adding it)."""
        with self._adds:
            while True:
                adds = self._tile_adds.get(seg.tile_index)
                if adds is not None and seg.order in adds.reports:
                    return adds.reports.pop(seg.order)
                if self._adds_failed is not None:  # what the worker raised (its batch's result raises it too)
                    raise self._adds_failed
                self._adds.wait()

    def _trace_batch(self, segments: list[Segment]):
        """Camera rays and paths of one batch, which may span several tiles (runs on a worker thread; touches no
        shared mutable state but the tracer list, which is locked; _finish_in_worker then writes the batch's whole
        tiles, which no other thread touches)."""
        tracer = getattr(self.local_state, "tracer", None)
        if tracer is None:
            tracer = self.local_state.tracer = PathTracer(self.prepared, self.accel, self.settings, self.sampler)
            with self.tracers_lock:
                self.tracers.append(tracer)
        t0 = time.perf_counter()
        px = np.concatenate([seg.tile[0] + seg.loc % seg.tile[2] for seg in segments])
        py = np.concatenate([seg.tile[1] + seg.loc // seg.tile[2] for seg in segments])
        smp = np.concatenate([seg.smp for seg in segments])
        pixel_id = (py * self.scene.camera.resolution[0] + px).astype(np.uint32)
        offsets = self.pixel_filter.sample(self.sampler.get_2d(pixel_id, smp, DIM_FILM))
        camera = self.scene.camera
        lens_u = self.sampler.get_2d(pixel_id, smp, DIM_LENS) if camera.aperture_radius() > 0 else None
        raster_x, raster_y = px + 0.5 + offsets[:, 0], py + 0.5 + offsets[:, 1]
        ray_time = self.sampler.get_1d(pixel_id, smp, DIM_TIME) if self.motion else None
        if ray_time is not None and camera.shutter_curve is not None:
            ray_time = shutter_times(ray_time, camera.shutter_curve)
        if ray_time is not None and camera.rolling_shutter is not None:
            ray_time = rolling_shutter_times(ray_time, py, camera.resolution[1], camera.rolling_shutter)
        moving = (camera.motion_matrices is not None or camera.motion_lens is not None) and ray_time is not None
        # A still pinhole camera's rays (and their differentials, where a path reaches a Bump node) are made per
        # path where they are traced: the fused kernel makes each path's (PinholeRays), with the same bits.
        pinhole = None if moving or self.camera_offset is not None else pinhole_params(camera)
        differentials = (None, None)
        rays = deferred = None
        if pinhole is not None:
            deferred = PinholeRays(np.ascontiguousarray(raster_x, np.float64),
                                   np.ascontiguousarray(raster_y, np.float64), pinhole)
        else:
            if moving:
                rays = moving_camera_rays(camera, raster_x, raster_y, lens_u, ray_time)
            else:
                rays = camera_rays(camera, raster_x, raster_y, lens_u)
            if self.prepared.shading is not None and self.prepared.shading.needs_differentials:  # Bump nodes
                # (compiled only from camera_rays' own rays: the NumPy form serves the moving camera's)
                differentials = camera_differentials(camera, raster_x, raster_y, rays, lens_u, compiled=not moving)
            if self.camera_offset is not None:  # prepared for another camera position (render(prepared=...))
                rays.origins += self.camera_offset
        tracer.stats.seconds_camera += time.perf_counter() - t0
        # the pixel coordinates and film offsets are in the rays now: not held while the paths are traced
        px = py = offsets = raster_x = raster_y = lens_u = None
        if rays is not None and rays.alive is not None:  # a panoramic camera's dead rays: nothing traced or added
            out = self._trace_alive(tracer, pixel_id, smp, rays, differentials, ray_time)
        else:
            # Handed over, not kept here: CPython moves a call's arguments into the function's variables, so once
            # the tracer is past the camera rays' first hits (it drops them there) nothing holds them.
            camera_arrays = [pixel_id, smp]
            if rays is not None:
                camera_arrays += [rays.origins, rays.directions, rays.tmax, rays.depth_scale, rays.t_start]
            else:
                camera_arrays += [None] * 5
            camera_arrays.append(deferred)
            pixel_id = smp = rays = deferred = None
            take = camera_arrays.pop
            out = tracer.trace(take(0), take(0), take(0), take(0), take(0), take(0), take(0), self.settings.aovs,
                               self.settings.denoising_features, self.data_tables is not None, differentials[0],
                               differentials[1], ray_time, take(0))  # (no *args: a call keeps its arguments)
        if self.data_tables is not None:
            first = out[1]
            first.data = self.data_tables.samples(first.surface)
        return out

    def _trace_alive(self, tracer: PathTracer, pixel_id, smp, rays, differentials=(None, None), ray_time=None):
        """Trace only the rays that are alive; dead ones get radiance 0, no transparency and no first hit."""
        live = np.flatnonzero(rays.alive)
        n = len(rays.alive)
        dp, dd = (None if a is None else a[live] for a in differentials)
        radiance_l, first_l, transparent_l = tracer.trace(
            pixel_id[live], smp[live], rays.origins[live], rays.directions[live], rays.tmax[live],
            rays.depth_scale[live], rays.t_start[live], self.settings.aovs, self.settings.denoising_features,
            self.data_tables is not None, dp, dd, None if ray_time is None else ray_time[live])
        radiance = np.zeros((n, 3), np.float32)
        radiance[live] = radiance_l
        transparent = None
        if transparent_l is not None:
            transparent = np.zeros(n, np.float32)
            transparent[live] = transparent_l
        first = None
        if first_l is not None:
            first = FirstHit(None, None, None)
            if first_l.albedo is not None:
                first = FirstHit(np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32),
                                 np.full(n, np.inf, np.float32))
                first.albedo[live], first.normal[live], first.depth[live] = (first_l.albedo, first_l.normal,
                                                                             first_l.depth)
            if first_l.features is not None:
                first.features = DenoisingFeatures(n)
                first.features.albedo[live], first.features.normal[live] = (first_l.features.albedo,
                                                                            first_l.features.normal)
            if first_l.catcher is not None:  # dead rays: no split, no matte, no transparency
                first.catcher = CatcherSamples.spread(first_l.catcher, live, n)
            if first_l.surface is not None:  # dead rays saw nothing
                first.surface = first_l.surface.take_live(live, n)
            if first_l.light_passes is not None:
                first.light_passes = LightPassSamples(n)
                first.light_passes.values[live] = first_l.light_passes.values
            if first_l.shader_aovs is not None:  # dead rays wrote nothing
                first.shader_aovs = first_l.shader_aovs.spread(live, n)
            if first_l.light_groups is not None:  # dead rays gathered no light
                first.light_groups = LightGroupSamples(n, first_l.light_groups.values.shape[1])
                first.light_groups.values[live] = first_l.light_groups.values
        return radiance, first, transparent

    def _finish_one(self, quiet: bool = False) -> None:
        """Wait for the oldest batch in flight, add what its worker did not to its tiles' films, and report its
        segments (quiet: no callbacks)."""
        segments, job = self._pop_oldest()
        radiance, first, transparent, finished = job.result() if self.pool is not None else job()
        self.film_seconds += finished["film"]
        self.assembly_seconds += finished["assembly"]
        start = 0
        for k, seg in enumerate(segments):
            rows = slice(start, start + len(seg.loc))
            start = rows.stop
            if k in finished or self._ordered_adds:  # added by a worker: its callbacks only
                # a whole tile, already in the frame (_finish_in_worker), or a segment of _add_in_order
                final, tile = (True, finished[k]) if k in finished else self._report_in_order(seg)
                self.done_paths += len(seg.loc)
                if not quiet:
                    self._progress(seg.tile_index, seg.sample_end)
                if seg.last_chunk:  # (every whole tile's is)
                    self.samples_started[seg.tile_index] = seg.sample_end
                    if final:
                        self.final.add(seg.tile_index)
                    if self.on_tile is not None and not quiet and tile is not None:
                        self.on_tile(tile)
                continue
            t0 = time.perf_counter()
            film = self.films[seg.tile]
            self._add_segment(film, seg, rows, radiance, first, transparent)
            self.film_seconds += time.perf_counter() - t0
            self.done_paths += len(seg.loc)
            if not quiet:
                self._progress(seg.tile_index, seg.sample_end)
            if seg.last_chunk:
                self.samples_started[seg.tile_index] = seg.sample_end
                if self.work is not None and self.work[seg.tile_index][0] > 0:
                    self.pass_sums.setdefault(seg.tile_index, []).append(film.take_pass())
                    if self.data_tables is not None:
                        self.data_pass_sums.setdefault(seg.tile_index, []).append(
                            self.data_films[seg.tile].take_pass())
                if self.frame is not None and seg.sample_end == self.spp:  # the tile is final: its images once
                    tile = self._final_tile(seg.tile_index, seg.tile, film)
                    if self.on_tile is not None and not quiet:
                        self.on_tile(tile)
                elif self.on_tile is not None and not quiet:
                    self.on_tile(self._tile_result(seg.tile, film, seg.sample_end))

    def _add_segment(self, film: TileFilm, seg: Segment, rows: slice, radiance, first, transparent) -> None:
        """Add a segment's samples (rows of the batch's results) to its tile's film (the local render's AOV sums
        to the frame's images, its data passes to the tile's data film)."""
        film.add(seg.loc, radiance[rows], seg.smp, None if transparent is None else transparent[rows])
        if first is not None and first.albedo is not None:
            if film.aovs:
                film.add_aovs(seg.loc, first.albedo[rows], first.normal[rows], first.depth[rows])
            else:
                self.frame.add_aovs(seg.tile, seg.loc, first.albedo[rows], first.normal[rows], first.depth[rows])
        if first is not None and first.features is not None:
            film.add_features(seg.loc, first.features.albedo[rows], first.features.normal[rows])
        if first is not None and first.catcher is not None:
            film.add_catcher(seg.loc, first.catcher.take(rows))
        if self.data_tables is not None:
            self.data_films[seg.tile].add(seg.loc, seg.smp, take_samples(first.data, rows.start, rows.stop))
        if first is not None and first.light_passes is not None:
            film.add_light_passes(seg.loc, first.light_passes.values[rows])
        if first is not None and first.shader_aovs is not None:
            film.add_shader_aovs(seg.loc, first.shader_aovs.values[rows])
        if first is not None and first.light_groups is not None:
            film.add_light_groups(seg.loc, first.light_groups.values[rows])

    # ----------------------------------------------------------------------- sample ranges (render_samples)
    def _check_work(self, work: SampleRanges) -> SampleRanges:
        """Refuse ranges that are not whole sample passes of existing tiles (they could not merge exactly)."""
        checked: SampleRanges = {}
        bounds = pass_bounds(self.tiles, self.spp, self.settings)
        for ti, (start, end) in work.items():
            ti, start, end = int(ti), int(start), int(end)
            if not 0 <= ti < len(self.tiles):
                raise ValueError(f"tile index {ti} is not one of the frame's {len(self.tiles)} tiles")
            if start not in bounds[ti] or end not in bounds[ti] or end <= start:
                raise ValueError(f"samples [{start}, {end}) of tile {ti} are not whole sample passes "
                                 f"(pass boundaries {bounds[ti]})")
            if self.adaptive and (start, end) != (0, self.spp):
                raise ValueError("with adaptive sampling a tile's samples cannot be split: each pass depends on "
                                 "the ones before")
            checked[ti] = (start, end)
        return checked

    def _in_work(self, ti: int, first_sample: int, count: int) -> bool:
        rng = self.work.get(ti)
        return rng is not None and rng[0] <= first_sample and first_sample + count <= rng[1]

    def tile_samples(self) -> list[TileSamples]:
        """After run() with work: each tile range's film sums (see TileSamples)."""
        out = []
        names = {} if self.data_tables is None else {kind: list(n) for kind, n in self.data_tables.names.items()}
        for ti, (start, end) in sorted(self.work.items()):
            data = []
            if start > 0:
                films = self.pass_sums.get(ti, [])
                if self.data_tables is not None:
                    data = self.data_pass_sums.get(ti, [])
            else:
                films = [{name: arr.copy() for name, arr in self.films[self.tiles[ti]].state().items()}]
                if self.data_tables is not None:
                    data = [self.data_films[self.tiles[ti]].state()]
            out.append(TileSamples(ti, start, end, films, data, names))
        return out

    # ------------------------------------------------------------------------------------------ reporting
    def _progress(self, tiles_done: int, sample: int) -> None:
        if self.on_progress is None:
            return
        elapsed = time.perf_counter() - self.t_start
        rays = sum(self._ray_counts())
        frac = self.done_paths / self.total_paths if self.total_paths else 1.0
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("inf")
        self.on_progress(Progress(frac, tiles_done, len(self.tiles), sample, self.spp, rays, elapsed,
                                  rays / max(elapsed, 1e-9), eta))

    def _ray_counts(self) -> tuple[int, int]:
        """(closest-hit rays, shadow rays) cast so far, those cast against the ray-visibility structures included."""
        structures = [self.accel] + [accel for accel, _ in list(self.prepared._subsets.values())]
        return (sum(a.rays_closest for a in structures), sum(a.rays_shadow for a in structures))

    def _final_tile(self, ti: int, tile: TileRect, film: TileFilm, samples: int | None = None) -> Tile:
        """Write a tile that holds all its samples (or whose pixels all converged, at `samples`) into the frame's
        images and release its film; the tile's images (views of the frame's) for on_tile."""
        t0 = time.perf_counter()
        out = self.frame.put(tile, film, self.spp if samples is None else samples)
        film.release()
        self.final.add(ti)
        if self.data_tables is not None:
            out.data_passes = self.data_films[tile].images()
        self.assembly_seconds += time.perf_counter() - t0
        return out

    def _tile_result(self, tile: TileRect, film: TileFilm, samples: int) -> Tile:
        rot = world_to_camera(self.scene) if self.settings.denoising_features else None
        out = tile_result(tile, film, samples, self.settings.aovs, rot, self.frame)
        if self.data_tables is not None:
            out.data_passes = self.data_films[tile].images()
        return out

    def result(self, t_prepare: float, say) -> RenderResult:
        """The region's image assembled from the tiles, with the render's statistics."""
        settings, scene, accel = self.settings, self.scene, self.accel
        rx, ry, rw, rh = self.region
        t0 = time.perf_counter()
        for ti, tile in enumerate(self.tiles):  # tiles a cancel, a time limit or adaptive sampling left open
            if ti not in self.final:
                self.frame.put(tile, self.films[tile])
                self.films[tile].release()
        color, variance, albedo, normal, depth, counts, features, extras = self.frame.images()
        self.assembly_seconds += time.perf_counter() - t0
        elapsed = time.perf_counter() - self.t_start
        st = PathStats.total([t.stats for t in self.tracers])
        rays_closest, rays_shadow = self._ray_counts()
        rays = rays_closest + rays_shadow
        stats = {
            "scene": scene.name,
            "resolution": list(scene.camera.resolution),
            "region": [rx, ry, rw, rh],
            "spp": self.spp,
            "samples": int(counts.sum()),
            "seconds": elapsed,
            "prepare_seconds": t_prepare,
            "samples_per_second": counts.sum() / max(elapsed, 1e-9),
            "rays_closest": rays_closest,
            "rays_shadow": rays_shadow,
            "rays_per_second": rays / max(elapsed, 1e-9),
            "embree_seconds": st.seconds_intersect + st.seconds_occluded,
            # Share of all worker thread-time (wall time x workers) spent inside Embree.
            "embree_share": (st.seconds_intersect + st.seconds_occluded) / max(elapsed * self.workers, 1e-9),
            # the fused path kernel (core.fused_tracer) traced the paths: Embree is called inside it, untimed
            "fused_kernel": any(t.fused is not None for t in self.tracers),
            "stage_seconds": {**st.stage_seconds(), "film": self.film_seconds},
            # the writing of the tiles' images into the frame's (beside the film sums), summed over the threads
            "assembly_seconds": self.assembly_seconds,
            "nonfinite_samples": st.nonfinite,
            "clamped_contributions": st.clamped,
            "peak_memory_mb": _peak_memory_mb(),
            "threads": settings.thread_count,
            "largest_batch": self.largest_batch,
            "adaptive_pixels_converged": int(self.pixels_converged.sum()) if self.adaptive else 0,
            "features": self.prepared.features,
        }
        if st.nonfinite:
            msg = f"{st.nonfinite} NaN/Inf path contributions were caught and dropped (not written to the image)"
            scene.warnings.append(msg)
            say(f"warning: {msg}")
        out = RenderResult(color, variance, albedo, normal, depth, counts, stats, list(scene.warnings),
                           self.cancelled)
        if features is not None:
            out.denoising_albedo, out.denoising_normal = features
        for name, value in extras.items():
            setattr(out, name, value)
        if self.data_tables is not None:
            out.data_passes = assemble_data([(t, self.data_films[t]) for t in self.tiles], self.region)
            out.cryptomatte = manifests(self.data_tables)
        return out
