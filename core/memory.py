"""How much memory a render will need, estimated before anything is allocated, against what the machine has.

The estimate (bytes), measured on this renderer (see docs/stress.md for the calibration):

    total = film pixels x (FILM_BYTES [+ FILM_SQUARES_BYTES] [+ FILM_FEATURE_BYTES])
          + pixels x (RESULT_BYTES [+ RESULT_AOV_BYTES] [+ RESULT_FEATURE_BYTES])
          + threads x min(batch, pixels x spp) x PATH_BYTES      (batch: core.schedule.batch_target)
          + triangles x TRIANGLE_BYTES + texels x TEXEL_BYTES

- film pixels: the films alive at once, one window of tiles (core.schedule.FILM_WINDOW_PIXELS, or one tile
  where a tile is larger) when the region is larger, every pixel under a time limit (its passes go round the
  whole image); the data passes' films are all alive until the end (every pixel);
- film (core.film, float32 storage): per pixel a float32 RGB shift (12 B), for each of the 2 variance groups a
  float32 RGB deviation sum (2 x 12 B), an int32 sample count (4 B) (40 B); for samplers other than Sobol a
  float32 RGB sum of squared deviations (FILM_SQUARES_BYTES, 12 B; the independent sampler's film keeps one group
  and the squares: FILM_INDEPENDENT_BYTES, 40 B); without an error estimate (RenderSettings.error_estimate off)
  one group and no squares for every sampler: K, one deviation sum and the count (FILM_NO_ESTIMATE_BYTES, 28 B),
  and the result keeps no variance image (12 B less); the AOVs' float32 albedo, normal and depth sums are kept in
  the result's own AOV images until each tile is final, their depth hit count in its sample-count image
  (core.render.FrameImages.add_aovs), so they add nothing to a render's films (render_samples()' films, which are
  handed on, keep them: FILM_AOV_BYTES, 32 B); with the denoising
  features float32 albedo and normal sums (24 B); with a shadow catcher float32 matte, catcher and world sums
  (36 B), the matte's transparency (4 B) and an int32 count of samples that met the catcher (4 B) (+ 44 B, and
  28 B more in the result: the Shadow Catcher pass and its matte); with light passes float32 RGB sums of all 11
  (132 B); with shader AOVs (Scene.shader_aovs) a float32 RGB sum and write count per AOV (16 B; the result
  16 B per colour AOV, 4 B per value AOV); with light groups (Scene.light_groups) a float32 RGB sum per group
  (12 B, and 12 B in the result). Each pass is summed in float64 over the batch's samples
  (counted in the path batch) before it is folded in;
- result: the assembled float32 colour RGBA (16 B), variance (12 B; none without an error estimate), int32
  sample count (4 B); with AOVs
  albedo, normal (24 B) and depth (4 B); with the denoising features their albedo and normal (24 B); 12 B per
  light pass asked for;
- data passes (core.data_passes), each requested one: per pixel a sample count (8 B) and film / result bytes of
  DATA_PASS_BYTES (Mist float64 sum / float32; UV float64 RGB sums / float32; Position and the indices float32);
  a Cryptomatte kind keeps sparse (key, coverage) pairs, about 2 per pixel (32 B), and levels x 8 B of layers;
- batch: the integrator's float32 structure-of-arrays for every path in flight, ray buffers and temporaries
  (measured by `monte perf --sections memory`: a batch of 2^18 Cornell box paths with AOVs peaks at about 320 B
  per path; PATH_BYTES keeps a margin for materials with more lobes, whose per-path lobe arrays are 63 B a lobe);
- scene: the camera-shifted float32 triangle soup, face and corner normals, UVs, material indices and the Embree
  BVH (about 400 B per triangle), textures (float32 RGB, kept twice during preparation), and the world's
  environment map (float32 RGB, held once) with its importance tables (two float64 per grid cell).

The interpreter, NumPy and Embree themselves (about 70 MB) are not counted: they are there before a render.
`check_render_memory` raises RenderMemoryError when the estimate exceeds the memory available to this process
(MemAvailable, or a cgroup limit if lower), instead of letting the kernel kill the process halfway.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from .scene import Scene
from .schedule import FILM_WINDOW_PIXELS, batch_target
from .settings import RenderSettings

FILM_BYTES = 40  # 2 variance groups (core.sampling.VARIANCE_GROUPS)
FILM_SQUARES_BYTES = 12  # the sum of squared deviations: kept for all samplers but Sobol (core.film)
FILM_INDEPENDENT_BYTES = 40  # independent samples: one group (no variance groups) and the squares
FILM_NO_ESTIMATE_BYTES = 28  # settings.error_estimate off: one group, no squares, for every sampler
FILM_AOV_BYTES = 32  # AOV sums in a film render_samples() hands on (a render's films keep none)
FILM_LIGHT_PASS_BYTES = 132  # float32 RGB sums of the 11 light passes (core.light_passes)
RESULT_LIGHT_PASS_BYTES = 12  # per light pass asked for: float32 RGB
FILM_SHADER_AOV_BYTES = 16  # per shader AOV: float32 RGB sum and write count (core.shader_aovs)
LIGHT_GROUP_BYTES = 12  # per light group, in the film and in the result: float32 RGB (core.light_groups)
RESULT_BYTES = 32
RESULT_VARIANCE_BYTES = 12  # of RESULT_BYTES: the variance image (none without an error estimate)
RESULT_AOV_BYTES = 28
FILM_FEATURE_BYTES = 24
RESULT_FEATURE_BYTES = 24
FILM_CATCHER_BYTES = 44
RESULT_CATCHER_BYTES = 28
PATH_BYTES = 400
TRIANGLE_BYTES = 400
TEXEL_BYTES = 24
# Data passes: key -> (film bytes, result bytes) per pixel; Cryptomatte kinds add levels x 8 B of result layers.
DATA_PASS_BYTES = {"mist": (8, 4), "uv": (24, 12), "position": (12, 12), "object_index": (4, 4),
                   "material_index": (4, 4), "crypto_object": (32, 0), "crypto_material": (32, 0),
                   "crypto_asset": (32, 0), "vector": (40, 16)}
# Refuse when the estimate exceeds this share of the available memory (the rest: fragmentation, the EXR writer).
SAFETY_SHARE = 0.9


class RenderMemoryError(MemoryError):
    """The render would need more memory than the machine has; the message gives both numbers and what to
    change."""


@dataclass
class MemoryEstimate:
    """Bytes a render needs, by part (see the module docstring for the formula)."""

    film: int
    result: int
    batch: int
    scene: int

    @property
    def total(self) -> int:
        return self.film + self.result + self.batch + self.scene

    def describe(self) -> str:
        mb = 2**20
        return (f"{self.total / mb:,.0f} MB (film {self.film / mb:,.0f} MB, result {self.result / mb:,.0f} MB, "
                f"path batch {self.batch / mb:,.0f} MB, scene {self.scene / mb:,.0f} MB)")


def estimate_render_memory(scene: Scene, settings: RenderSettings, pixels: int | None = None) -> MemoryEstimate:
    """Estimate the bytes `render(scene, settings)` allocates; pixels: the region's pixel count (default: the
    whole frame)."""
    if pixels is None:
        w, h = scene.camera.resolution
        pixels = int(w) * int(h)
    aovs = bool(settings.aovs)
    features = bool(settings.denoising_features)
    colour = {"sobol": FILM_BYTES, "stratified": FILM_BYTES + FILM_SQUARES_BYTES}.get(settings.sampler,
                                                                                     FILM_INDEPENDENT_BYTES)
    if not getattr(settings, "error_estimate", True):
        colour = FILM_NO_ESTIMATE_BYTES
    light = bool(getattr(settings, "light_passes", ()))
    # the tiles' films alive at once (core.render: one window of tiles at a time, but round all under a time limit)
    film_pixels = pixels if settings.time_limit > 0 else min(pixels, max(FILM_WINDOW_PIXELS,
                                                                         int(settings.tile_size) ** 2))
    film = film_pixels * (colour + (FILM_FEATURE_BYTES if features else 0)
                          + (FILM_LIGHT_PASS_BYTES if light else 0))
    result = pixels * (RESULT_BYTES - (0 if getattr(settings, "error_estimate", True) else RESULT_VARIANCE_BYTES)
                       + (RESULT_AOV_BYTES if aovs else 0) + (RESULT_FEATURE_BYTES if features else 0)
                       + RESULT_LIGHT_PASS_BYTES * len(getattr(settings, "light_passes", ())))
    aov_list = list(getattr(scene, "shader_aovs", ()))
    film += film_pixels * FILM_SHADER_AOV_BYTES * len(aov_list)
    result += pixels * sum(16 if kind == "COLOR" else 4 for _, kind in aov_list)
    groups = len(getattr(scene, "light_groups", ()))
    film += film_pixels * LIGHT_GROUP_BYTES * groups
    result += pixels * LIGHT_GROUP_BYTES * groups
    if scene.has_shadow_catcher:
        film += film_pixels * FILM_CATCHER_BYTES
        result += pixels * RESULT_CATCHER_BYTES
    passes = tuple(getattr(settings, "data_passes", ()))
    if passes:
        levels = 2 * ((int(settings.cryptomatte_levels) + 1) // 2)
        film += pixels * (8 + sum(DATA_PASS_BYTES[p][0] for p in passes))
        result += pixels * sum(DATA_PASS_BYTES[p][1] + (8 * levels if p.startswith("crypto") else 0)
                               for p in passes)
    # every worker thread traces one batch at a time (see core.schedule.batch_target)
    total_paths = pixels * max(int(settings.spp), 0)
    paths = min(batch_target(settings, total_paths), total_paths) * settings.thread_count
    # RGB texels as TEXEL_BYTES; RGBA ones (node-program images, packed RGBA once more for the evaluator) 4/3 of it
    texels = sum(int(t.pixels.shape[0]) * int(t.pixels.shape[1]) * (4 if t.pixels.shape[2] == 4 else 3) // 3
                 for t in scene.textures)
    scene_bytes = scene.triangle_count * TRIANGLE_BYTES + texels * TEXEL_BYTES
    if scene.world.environment is not None:  # the world's map (held once) and its importance tables
        scene_bytes += scene.world.environment.nbytes
    # with light passes each path carries their float32 sums and its first bounce's weights (156 B)
    path_bytes = PATH_BYTES + (156 if light else 0)
    return MemoryEstimate(film, result, paths * path_bytes, scene_bytes)


def available_memory() -> int | None:
    """Bytes this process can still allocate: the smaller of /proc/meminfo's MemAvailable and the cgroup's
    remaining limit; None where neither can be read (then no check is made)."""
    candidates = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                candidates.append(int(line.split()[1]) * 1024)
                break
    except (OSError, ValueError, IndexError):
        pass
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            limit = Path(limit_file).read_text().strip()
            if limit != "max" and int(limit) < 2**60:
                candidates.append(int(limit) - int(Path(usage_file).read_text().strip()))
            break
        except (OSError, ValueError):
            continue
    if not candidates and hasattr(os, "sysconf"):
        try:
            candidates.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError):
            pass
    return max(min(candidates), 0) if candidates else None


def peak_rss_bytes() -> int | None:
    """This process's peak resident set size: VmHWM from /proc/self/status (reset by exec, unlike
    getrusage's ru_maxrss, which a child process inherits from its parent on Linux); None where unavailable."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    except (ImportError, OSError):
        return None


def check_render_memory(scene: Scene, settings: RenderSettings, pixels: int | None = None,
                        available: int | None = None) -> MemoryEstimate:
    """Raise RenderMemoryError if the render's estimate exceeds SAFETY_SHARE of the available memory
    (`available` bytes, default: measured now). Returns the estimate."""
    est = estimate_render_memory(scene, settings, pixels)
    avail = available_memory() if available is None else available
    if avail is not None and est.total > SAFETY_SHARE * avail:
        w, h = scene.camera.resolution
        raise RenderMemoryError(
            f"scene {scene.name!r} at {w}x{h} needs about {est.describe()}, but only "
            f"{avail / 2**20:,.0f} MB of memory is available: lower the resolution, render a region, turn off "
            f"the AOV passes, or lower the batch size (--batch)")
    return est
