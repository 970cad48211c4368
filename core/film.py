"""Film: per-pixel accumulation of samples and first-hit AOVs for one tile, and the error of each pixel's mean.

Pixel filters are importance-sampled (core.filters), as Cycles does: each sample lands in the pixel it was
generated for with weight 1, so a pixel's value is a plain mean.

The variance of that mean depends on how the samples were drawn. For independent samples s^2 / n is unbiased.
For stratified or quasi-random (Sobol) samples it is not: the samples of a pixel are negatively correlated, and
s^2 / n overstates the error several-fold (a 16x16 Cornell box at 16 spp with Owen-scrambled Sobol: the
seed-to-seed variance of the image mean is about a quarter of it). So the film sums each pixel's samples in
G variance groups (core.sampling.Sampler.variance_group: independently scrambled Sobol sequences, or groups of
whole stratified blocks) whose means are independent estimates of the pixel, and estimates

    var(mean) = sum_g n_g (m_g - m)^2 / ((G' - 1) n)

over the G' groups holding samples (n_g samples with mean m_g; m the pixel mean, n = sum n_g). With equal
n_g this is the textbook var(group means) / G', unbiased whatever the correlation inside a group; it has only
G' - 1 degrees of freedom per pixel, but summed over many pixels (an image or region mean) it is precise.
With fewer than 2 groups holding samples (the first block of 4 stratified samples) it falls back to s^2 / n,
which overstates the error there rather than claiming none.

Only a render that reads the estimate keeps the groups (core.settings.RenderSettings.error_estimate: the
variance pass, adaptive sampling, the Cycles cross-checks): each group is a 1/G-size point set, which costs the
image itself noise (2 groups: 1.14-1.18x the variance per sample of one Sobol sequence on the `instances` bench
scene). A film made without the estimate sums one group (sample i is point i of the pixel's single scramble, as
Cycles) and no squares: 28 B per pixel, and variance_of_mean() / active_pixels() refuse.

Storage: float32, shifted. Each pixel keeps a shift K (per channel, float32: the mean of its first pass of
samples) and float32 sums of the samples' deviations from K: per variance group, and their squares. Every
pass of samples (one add() call per pixel and pass) is first summed exactly enough in float64, then folded
into the float32 sums once. Deviations from K are small next to the pixel's value wherever the pixel is not
noisy, so float32 rounding of their sums costs the mean almost nothing (mean = K + sum / n in float64), and a
constant pixel keeps sums of exactly 0: its mean is exact and its variance exactly 0 at any sample count. For a
noisy pixel the rounding of each fold (2^-24 of a deviation sum) stays orders of magnitude below the noise
the sums measure (tests/test_film_memory.py: 1e6 samples against float64 references).

A pixel's samples arrive in order (sample 0 first, each pass continuing where the last ended: the render's passes,
adaptive sampling and a split render's merge all do so), so its samples per variance group follow from its
sample count and the sampler's group rule (periodic in the sample index): the film keeps one int32 count per
pixel and derives the group counts, checking on every fold that the samples it was given are the ones it derives.

The sum of squared deviations serves only s^2 / n: for independent samples, and for a pixel with fewer than 2
groups holding samples. Under the Sobol sampler's rule (group i mod G) 2 samples already fill 2 groups, and
with fewer there is no variance to estimate, so a film for it keeps no squares.

Memory per pixel (core.memory): K 12 B, group deviation sums 24 B (G = 2), the sample count 4 B = 40 B, and
the sum of squared deviations 12 B more where the estimate reads it (stratified, independent samples); a film made
with aovs keeps 32 B more (float32 albedo, normal and depth sums, int32 depth count), but a render's films are
made without: it sums the AOVs straight into the frame's AOV images with the same operations
(core.render.FrameImages.add_aovs), so only the films render_samples() hands on keep them; the denoising
features add 24 B, alpha (Film > Transparent, holdout) 4 B, a shadow catcher 44 B, the light passes
(core.light_passes) 132 B, the shader AOVs (core.shader_aovs) 16 B each. (It was 136 + 64 + 48 B in float64,
and 88 B with stored group counts.)

The sums and the fold of a render's add() calls run compiled (core.film_kernels: the same operations in the
same order, one pass over the samples and one over the tile, where NumPy's form made some thirty passes over
the tile per call and cost more per sample than the path itself at 1 sample per pixel and pass); the raw sums
of a film in capture mode (below) and their fold stay in NumPy. So do the image methods (mean, variance_of_mean,
aov_images, ...), the reference for write_colour_images / write_aov_images, which the frame's assembly uses:
the same bits, compiled, written straight into the frame's arrays.

Shadow catcher (core.scene.Mesh.shadow_catcher; core.integrator.CatcherSamples): the film also sums each
pixel's matte M (the radiance gathered before paths met a catcher) with its transparency T_m, the catcher
copies' radiance K, the count of samples that split S, and the world behind (B), and forms the images as
Cycles' film does (C: the Combined sum, T_c its transparency, per pixel):

    shadow catcher   = 1 where S = 0, else (1 - a) + a (C - M) / K per channel (1 where K = 0), a = 1 - T_c / n
    Combined         = with the Shadow Catcher pass (Film.shadow_catcher_pass): (M / n, 1 - T_m / n);
                       without it (Cycles' approximate catcher), with a = 1 - T_m / n and
                       a_m = a + (1 - a) (1 - clamp(mean(shadow catcher), 0, 1)):
                       transparent film: (M / n, a_m); opaque film: (M / n + (1 - a_m) B / n, 1)
    Shadow Catcher Matte = (M / n, 1 - T_m / n)

A render split across machines (core.distributed) moves films two ways: a film's state (state() /
set_state()), and the raw float64 sums of one pass of samples (a film in capture mode, capture_passes() /
take_pass(); folded by add_sums() exactly as add() folds them), so merged films equal one render bit for bit.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from . import film_kernels
from .light_groups import images as light_group_images
from .light_passes import LIGHT_PASSES, finish
from .shader_aovs import CHANNELS as AOV_CHANNELS
from .shader_aovs import images as aov_images
from .sampling import Sampler

_OUT_OF_ORDER = ("film: each pixel's samples must arrive in order, sample 0 first and each pass continuing where "
                 "the pixel's last pass ended")
_NO_SQUARES = np.zeros((0, 3), np.float32)  # dev_sq of a film that keeps no squares (never read)
_NO_SUMS = np.zeros((0, 3), np.float64)
_NO_ALPHA = np.zeros(0, np.float32)  # transparent_sum of a film without alpha (never read)
_SCRATCH = threading.local()  # per thread: films may be filled on several threads (a cluster worker's units)


class _Scratch:
    """Zeroed float64 / int64 buffers for the compiled accumulation of a tile of n pixels: kept from call to call
    (the kernels leave them zeroed), since fresh zeroed pages cost a page fault each on every call."""

    def __init__(self, n: int, groups: int) -> None:
        self.n, self.groups = n, groups
        self.group_sum = np.zeros((n, groups, 3))
        self.group_samples = np.zeros((n, groups), np.int64)
        self.sums3 = np.zeros((n, 3))
        self.sums1 = np.zeros(n)
        self.counts = np.zeros(n, np.int64)
        self.counts32 = np.zeros(n, np.int32)  # (the alpha sums' counts, not kept)


def _scratch(n: int, groups: int) -> _Scratch:
    """This thread's scratch for a tile of n pixels and `groups` variance groups (the last size asked is kept)."""
    scratch = getattr(_SCRATCH, "buffers", None)
    if scratch is None or scratch.n != n or scratch.groups != groups:
        scratch = _SCRATCH.buffers = _Scratch(n, groups)
    return scratch

_COLOUR_RAW = ("group_sum", "group_count", "dev_sq")
_AOV_RAW = ("albedo", "normal", "depth_sum", "depth_count")
_FEATURE_RAW = ("feature_albedo", "feature_normal")
_ALPHA_RAW = ("transparent_sum",)
_LIGHT_RAW = ("light_pass_sum",)
_SHADER_AOV_RAW = ("shader_aov_sum",)
_LIGHT_GROUP_RAW = ("light_group_sum",)
_CATCHER_RAW = ("matte_sum", "matte_transparent_sum", "catcher_sum", "catcher_count", "background_sum")


@dataclass(frozen=True)
class CatcherOutput:
    """How a film with a shadow catcher forms Combined (core.scene.Film: shadow_catcher_pass, transparent)."""

    shadow_catcher_pass: bool
    transparent: bool

    @classmethod
    def of(cls, scene) -> "CatcherOutput | None":
        """The scene's (a core.scene.Scene), None when no mesh is a shadow catcher (the film keeps nothing more)."""
        if not scene.has_shadow_catcher:
            return None
        return cls(bool(scene.film.shadow_catcher_pass), bool(scene.film.transparent))


class TileFilm:
    """Accumulators for a tile of h x w pixels. Samples arrive with their tile-local pixel index (row-major,
    row 0 at the top) and their sample index (which picks their variance group, see the module docstring).
    Each add() call must hold at most one pass of a pixel's samples (the render's batches do: a pass over a
    tile is cut into chunks of whole pixels)."""

    def __init__(self, width: int, height: int, aovs: bool, sampler: Sampler | None = None,
                 features: bool = False, alpha: bool = False, catcher: CatcherOutput | None = None,
                 light_passes: tuple[str, ...] = (), shader_aovs=(), light_groups=(),
                 error_estimate: bool = True) -> None:
        """features: keep the denoising features' sums; alpha: keep each pixel's summed transparency
        (core.scene.Film); without it alpha is 1; catcher: keep the shadow catcher's sums and form Combined
        from them (see the module docstring), None without a shadow catcher; light_passes: the light passes asked
        for (the film keeps the sums of all of core.light_passes.LIGHT_PASSES when any is asked for: Direct and
        Indirect need their Color); shader_aovs: core.scene.Scene.shader_aovs, (name, kind) pairs, whose sums
        (core.shader_aovs.AovPath.values, 16 B per AOV and pixel) the film keeps; light_groups:
        core.scene.Scene.light_groups, whose float32 RGB sums (core.light_groups, 12 B per group and pixel) it keeps;
        error_estimate: keep what the estimate of each pixel's error needs (core.settings.RenderSettings.
        error_estimate); without it the film keeps one group and no squares (the sampler's groups are not read:
        give it a sampler with groups=1, whose values are the ones a render without the estimate takes) and
        variance_of_mean() and active_pixels() refuse."""
        self.width, self.height = width, height
        n = width * height
        self.error_estimate = bool(error_estimate)
        # Independent samples need no groups: s^2 / n is exact for them and has the most degrees of freedom.
        self._sampler = sampler if (error_estimate and sampler is not None and not sampler.iid
                                    and sampler.groups > 1) else None
        self.groups = self._sampler.groups if self._sampler is not None else 1
        self.shift = np.zeros((n, 3), np.float32)
        self.group_dev = np.zeros((n, self.groups, 3), np.float32)
        self.sample_count = np.zeros(n, np.int32)
        # not an array attribute of the film (what the film holds per pixel is counted from those)
        self._group_prefix = (_group_prefix_counts(self._sampler, self.groups),)
        # s^2 / n is read only while fewer than 2 groups hold samples: never past 1 sample when 2 fill 2 groups
        prefix = self._group_prefix[0]
        self.squares = self.error_estimate and (self.groups == 1
                                                or np.count_nonzero(prefix[min(2, len(prefix) - 1)]) < 2)
        if self.squares:
            self.dev_sq = np.zeros((n, 3), np.float32)
        self.aovs = aovs
        self.alpha = alpha
        if alpha:
            self.transparent_sum = np.zeros(n, np.float32)
        if aovs:
            self.albedo = np.zeros((n, 3), np.float32)
            self.normal = np.zeros((n, 3), np.float32)
            self.depth_sum = np.zeros(n, np.float32)
            self.depth_count = np.zeros(n, np.int32)
        self.features = features  # the denoising albedo and normal (core.integrator.DenoisingFeatures)
        if features:
            self.feature_albedo = np.zeros((n, 3), np.float32)
            self.feature_normal = np.zeros((n, 3), np.float32)
        self.catcher = catcher
        if catcher is not None:
            self.matte_sum = np.zeros((n, 3), np.float32)
            self.matte_transparent_sum = np.zeros(n, np.float32)
            self.catcher_sum = np.zeros((n, 3), np.float32)
            self.catcher_count = np.zeros(n, np.int32)
            self.background_sum = np.zeros((n, 3), np.float32)
        self.light_passes = tuple(light_passes)
        if self.light_passes:
            self.light_pass_sum = np.zeros((n, len(LIGHT_PASSES), 3), np.float32)
        self.shader_aovs = tuple(tuple(a) for a in shader_aovs)
        if self.shader_aovs:
            self.shader_aov_sum = np.zeros((n, len(self.shader_aovs), AOV_CHANNELS), np.float32)
        self.light_groups = tuple(light_groups)
        if self.light_groups:
            self.light_group_sum = np.zeros((n, len(self.light_groups), 3), np.float32)
        self._capture: dict[str, np.ndarray] | None = None

    # ------------------------------------------------------------------------------------------ totals
    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def count(self) -> np.ndarray:
        """(n,) samples each pixel has taken."""
        return self.sample_count.astype(np.int64)

    def group_counts(self, count: np.ndarray | None = None) -> np.ndarray:
        """(n, G) int64 samples per variance group of pixels holding `count` (n,) samples (default: their
        own): samples 0 .. count - 1, grouped by the sampler's rule (periodic, see _group_prefix_counts)."""
        count = self.count if count is None else np.asarray(count, np.int64)
        prefix = self._group_prefix[0]
        period = len(prefix) - 1
        full, rest = np.divmod(count, period)
        return full[:, None] * prefix[period] + prefix[rest]

    def _mean64(self) -> np.ndarray:
        """(n, 3) float64 pixel means (the shift where no sample has landed: 0)."""
        n = np.maximum(self.count, 1).astype(np.float64)[:, None]
        return self.shift.astype(np.float64) + self.group_dev.astype(np.float64).sum(axis=1) / n

    @property
    def nbytes(self) -> int:
        """Bytes the film's arrays hold."""
        return sum(arr.nbytes for arr in self.state().values())

    # ------------------------------------------------------------------------------------- accumulation
    def add(self, pixel: np.ndarray, radiance: np.ndarray, sample: np.ndarray | None = None,
            transparent: np.ndarray | None = None) -> None:
        """Accumulate samples: pixel (N,) tile-local index, radiance (N, 3) finite values, sample (N,) their
        sample indices (needed when the film has variance groups), transparent (N,) their transparency in
        [0, 1] (needed when the film keeps alpha)."""
        n = self.pixels
        pixel = self._pixels(pixel)
        slot = pixel
        if self.groups > 1:
            if sample is None:
                raise ValueError("this film keeps variance groups: pass the samples' indices")
            group = np.asarray(self._sampler.variance_group(sample), np.int64)
            slot = pixel * self.groups + group
        if self.alpha and transparent is None:
            raise ValueError("this film keeps alpha: pass the samples' transparency")
        if self._capture is None:  # compiled: the same sums and fold as below, in one pass (core.film_kernels)
            # float32 radiance (the integrators') goes in as it is: the kernel reads each value as float64, the
            # same values as a float64 copy's (4 M samples: ~75 ms and 100 MB less per 256x256 64-spp render)
            r = (radiance if isinstance(radiance, np.ndarray) and radiance.dtype == np.float32
                 and radiance.ndim == 2 and radiance.flags.c_contiguous else np.ascontiguousarray(radiance, np.float64))
            group = group if self.groups > 1 else np.zeros(len(pixel), np.int64)
            scratch = _scratch(n, self.groups)
            bad = film_kernels.add_colour(pixel, np.ascontiguousarray(group), r, self._group_prefix[0],
                                          self.squares, self.shift, self.group_dev, self.sample_count,
                                          self.dev_sq if self.squares else _NO_SQUARES, scratch.group_sum,
                                          scratch.group_samples, scratch.sums3 if self.squares else _NO_SUMS)
            if bad >= 0:
                raise ValueError(_OUT_OF_ORDER)
            if self.alpha:
                film_kernels.add_sums1(pixel, np.ascontiguousarray(transparent, np.float64), False,
                                       self.transparent_sum, scratch.counts32, scratch.sums1, scratch.counts)
            return
        r = np.ascontiguousarray(radiance, np.float64)
        slots = n * self.groups
        count = np.bincount(pixel, minlength=n)
        group_sum = np.empty((n, self.groups, 3), np.float64)
        for c in range(3):
            group_sum[:, :, c] = np.bincount(slot, weights=r[:, c], minlength=slots).reshape(n, self.groups)
        raw = {"group_sum": group_sum,
               "group_count": np.bincount(slot, minlength=slots).reshape(n, self.groups).astype(np.int32)}
        if self.squares:
            # squared deviations from this pass's own mean: exactly 0 for a constant pixel (no cancellation)
            pass_mean = group_sum.sum(axis=1) / np.maximum(count, 1)[:, None]
            dev = r - pass_mean[pixel]
            dev_sq = raw["dev_sq"] = np.empty((n, 3), np.float64)
            for c in range(3):
                dev_sq[:, c] = np.bincount(pixel, weights=dev[:, c] * dev[:, c], minlength=n)
        if self.alpha:
            raw["transparent_sum"] = np.bincount(pixel, weights=np.asarray(transparent, np.float64), minlength=n)
        self._take(raw)

    def add_aovs(self, pixel: np.ndarray, albedo: np.ndarray, normal: np.ndarray, depth: np.ndarray) -> None:
        """Accumulate first-hit AOVs (averaged over the pixel's samples); depth only where finite (a hit)."""
        n = self.pixels
        pixel = self._pixels(pixel)
        if self._capture is None:  # compiled (core.film_kernels): the sums and fold below
            scratch = _scratch(n, self.groups)
            film_kernels.add_sums3(pixel, np.ascontiguousarray(albedo, np.float64), self.albedo, scratch.sums3)
            film_kernels.add_sums3(pixel, np.ascontiguousarray(normal, np.float64), self.normal, scratch.sums3)
            film_kernels.add_sums1(pixel, np.ascontiguousarray(depth, np.float64), True, self.depth_sum,
                                   self.depth_count, scratch.sums1, scratch.counts)
            return
        hit = np.isfinite(depth)
        raw = {"albedo": _bincount3(pixel, albedo, n), "normal": _bincount3(pixel, normal, n),
               "depth_sum": np.bincount(pixel[hit], weights=depth[hit], minlength=n),
               "depth_count": np.bincount(pixel[hit], minlength=n).astype(np.int32)}
        self._take(raw)

    def add_features(self, pixel: np.ndarray, albedo: np.ndarray, normal: np.ndarray) -> None:
        """Accumulate the denoising features of samples (averaged over the pixel's samples)."""
        n = self.pixels
        pixel = self._pixels(pixel)
        if self._capture is None:  # compiled (core.film_kernels): the sums and fold of _take
            scratch = _scratch(n, self.groups)
            film_kernels.add_sums3(pixel, np.ascontiguousarray(albedo, np.float64), self.feature_albedo,
                                   scratch.sums3)
            film_kernels.add_sums3(pixel, np.ascontiguousarray(normal, np.float64), self.feature_normal,
                                   scratch.sums3)
            return
        self._take({"feature_albedo": _bincount3(pixel, albedo, n),
                    "feature_normal": _bincount3(pixel, normal, n)})

    def add_catcher(self, pixel: np.ndarray, samples) -> None:
        """Accumulate the shadow catcher's samples (core.integrator.CatcherSamples) of the samples at `pixel`."""
        n = self.pixels
        pixel = np.asarray(pixel, np.int64)
        raw = {"matte_sum": _bincount3(pixel, samples.matte, n),
               "matte_transparent_sum": np.bincount(pixel, weights=np.asarray(samples.matte_transparent, np.float64),
                                                    minlength=n),
               "catcher_sum": _bincount3(pixel, samples.catcher, n),
               "catcher_count": np.bincount(pixel[samples.split], minlength=n).astype(np.int32),
               "background_sum": (np.zeros((n, 3)) if samples.background is None
                                  else _bincount3(pixel, samples.background, n))}
        self._take(raw)

    def add_light_passes(self, pixel: np.ndarray, values: np.ndarray) -> None:
        """Accumulate the light passes of samples: values (N, len(LIGHT_PASSES), 3) (see core.light_passes)."""
        n, k = self.pixels, len(LIGHT_PASSES) * 3
        pixel = np.asarray(pixel, np.int64)
        slot = (pixel[:, None] * k + np.arange(k)[None, :]).ravel()
        sums = np.bincount(slot, weights=np.asarray(values, np.float64).reshape(-1), minlength=n * k)
        self._take({"light_pass_sum": sums.reshape(n, len(LIGHT_PASSES), 3)})

    def add_shader_aovs(self, pixel: np.ndarray, values: np.ndarray) -> None:
        """Accumulate the shader AOVs of samples: values (N, K, 4) (core.shader_aovs.AovPath.values)."""
        self._take({"shader_aov_sum": self._per_pixel_sums(pixel, values)})

    def add_light_groups(self, pixel: np.ndarray, values: np.ndarray) -> None:
        """Accumulate the light groups of samples: values (N, G, 3) (core.light_groups.LightGroupSamples.values)."""
        self._take({"light_group_sum": self._per_pixel_sums(pixel, values)})

    def _per_pixel_sums(self, pixel: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(pixels, *values' row shape) float64 sums of the samples' values (N, ...) into their pixels."""
        values = np.asarray(values, np.float64)
        k = int(np.prod(values.shape[1:]))
        slot = (np.asarray(pixel, np.int64)[:, None] * k + np.arange(k)[None, :]).ravel()
        sums = np.bincount(slot, weights=values.reshape(-1), minlength=self.pixels * k)
        return sums.reshape(self.pixels, *values.shape[1:])

    def _pixels(self, pixel: np.ndarray) -> np.ndarray:
        """The samples' tile-local pixel indices as contiguous int64, checked to lie in the tile (the compiled
        accumulation does not check its indices)."""
        pixel = np.ascontiguousarray(pixel, np.int64).reshape(-1)
        if len(pixel) and (pixel.min() < 0 or pixel.max() >= self.pixels):
            raise ValueError(f"film: pixel index out of range [0, {self.pixels}) for a {self.width}x{self.height} "
                             "tile")
        return pixel

    def _take(self, raw: dict[str, np.ndarray]) -> None:
        if self._capture is not None:
            _add_raw(self._capture, raw)
        else:
            self._fold(raw)

    def _fold(self, raw: dict[str, np.ndarray]) -> None:
        """Fold one pass's float64 sums (see _raw_names) into the float32 storage, once per pixel."""
        if "group_sum" in raw:
            group_sum, group_count = raw["group_sum"], raw["group_count"]
            count = group_count.sum(axis=1, dtype=np.int64)
            took = np.flatnonzero(count > 0)
            if len(took):
                before = self.sample_count[took].astype(np.int64)
                after = before + count[took]
                if not np.array_equal(self.group_counts(after) - self.group_counts(before), group_count[took]):
                    raise ValueError(_OUT_OF_ORDER)
                gs, gc, c = group_sum[took], group_count[took].astype(np.float64), count[took].astype(np.float64)
                pass_mean = gs.sum(axis=1) / c[:, None]
                first = before == 0
                if np.any(first):
                    self.shift[took[first]] = pass_mean[first].astype(np.float32)
                k = self.shift[took].astype(np.float64)
                # deviations of this pass from K: its sums minus their counts times K (exactly 0 when constant)
                self.group_dev[took] = (self.group_dev[took].astype(np.float64)
                                        + (gs - gc[:, :, None] * k[:, None, :])).astype(np.float32)
                if self.squares:
                    d = pass_mean - k  # sum (x - K)^2 = sum (x - pass mean)^2 + c (pass mean - K)^2
                    self.dev_sq[took] = (self.dev_sq[took].astype(np.float64) + raw["dev_sq"][took]
                                         + c[:, None] * d * d).astype(np.float32)
                self.sample_count[took] = after
        for name in _AOV_RAW + _FEATURE_RAW + _ALPHA_RAW + _CATCHER_RAW + _LIGHT_RAW + _SHADER_AOV_RAW + _LIGHT_GROUP_RAW:
            if name in raw:
                arr = getattr(self, name)
                if arr.dtype == np.float32:
                    arr[...] = (arr.astype(np.float64) + raw[name]).astype(np.float32)
                else:
                    arr += raw[name]

    # ------------------------------------------------------------------------------- moving films around
    def _raw_names(self) -> list[str]:
        names = [name for name in _COLOUR_RAW if name != "dev_sq" or self.squares]
        if self.alpha:
            names += _ALPHA_RAW
        if self.aovs:
            names += _AOV_RAW
        if self.features:
            names += _FEATURE_RAW
        if self.catcher is not None:
            names += _CATCHER_RAW
        if self.light_passes:
            names += _LIGHT_RAW
        if self.shader_aovs:
            names += _SHADER_AOV_RAW
        if self.light_groups:
            names += _LIGHT_GROUP_RAW
        return names

    def state(self) -> dict[str, np.ndarray]:
        """The film's accumulators by name (the arrays themselves, not copies): set_state() of a film of the
        same tile and settings makes it this film."""
        names = ["shift", "group_dev", "sample_count"] + (["dev_sq"] if self.squares else [])
        if self.alpha:
            names += list(_ALPHA_RAW)
        if self.aovs:
            names += list(_AOV_RAW)
        if self.features:
            names += list(_FEATURE_RAW)
        if self.catcher is not None:
            names += list(_CATCHER_RAW)
        if self.light_passes:
            names += list(_LIGHT_RAW)
        if self.shader_aovs:
            names += list(_SHADER_AOV_RAW)
        if self.light_groups:
            names += list(_LIGHT_GROUP_RAW)
        return {name: getattr(self, name) for name in names}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Make this film a copy of the film whose state() `state` is."""
        self._check(state, self.state())
        for name, arr in self.state().items():
            arr[...] = state[name]

    def capture_passes(self) -> None:
        """Keep the raw float64 sums of the samples added from now on instead of folding them in, until
        take_pass() (a render split across machines sends one pass at a time, see add_sums)."""
        self._capture = self._zero_raw()

    def take_pass(self) -> dict[str, np.ndarray]:
        """The raw sums captured since capture_passes() or the last take_pass(); capturing starts over."""
        if self._capture is None:
            raise ValueError("this film is not capturing passes (capture_passes())")
        out, self._capture = self._capture, self._zero_raw()
        return out

    def add_sums(self, sums: dict[str, np.ndarray]) -> None:
        """Fold in the raw sums of one pass of samples (take_pass() of a film of the same tile and settings):
        bit for bit what add() of that pass's samples gives, so films merged pass by pass, in pass order, equal
        one render."""
        self._check(sums, self._zero_raw())
        self._fold(sums)

    def _zero_raw(self) -> dict[str, np.ndarray]:
        out = {}
        for name in self._raw_names():
            if name == "group_count":  # the pass's samples per group (the film itself derives them)
                out[name] = np.zeros((self.pixels, self.groups), np.int32)
                continue
            like = getattr(self, "group_dev" if name == "group_sum" else name)
            out[name] = np.zeros(like.shape, np.int32 if like.dtype == np.int32 else np.float64)
        return out

    @staticmethod
    def _check(given: dict[str, np.ndarray], mine: dict[str, np.ndarray]) -> None:
        if set(given) != set(mine):
            raise ValueError(f"film sums hold {sorted(given)}, this film keeps {sorted(mine)}")
        for name, arr in mine.items():
            if np.shape(given[name]) != arr.shape:
                raise ValueError(f"film sums {name!r} have shape {np.shape(given[name])}, this film {arr.shape}")

    def release(self) -> None:
        """Drop the accumulators' memory once the film's images are taken (the frame's assembly): the film is
        empty afterwards and takes no more samples."""
        for name in self.state():
            setattr(self, name, getattr(self, name)[:0].copy())
        self.width = self.height = 0
        self._capture = None

    def clear(self) -> None:
        """Set every accumulator back to zero."""
        for arr in self.state().values():
            arr[...] = 0

    # ---------------------------------------------------------------------------------------- images
    def feature_images(self) -> tuple[np.ndarray, np.ndarray]:
        """(denoising albedo (h,w,3), denoising normal (h,w,3), world space): plain means over the pixel's
        samples, the normal not renormalised (as Cycles' passes)."""
        n = np.maximum(self.count, 1)[:, None]
        return self._image(self.feature_albedo / n), self._image(self.feature_normal / n)

    def light_pass_images(self) -> dict[str, np.ndarray]:
        """The light passes asked for: name -> (h, w, 3) float32, Direct and Indirect divided by their Color
        (core.light_passes.finish)."""
        n = np.maximum(self.count, 1).astype(np.float64)[:, None, None]
        passes = finish(self.light_pass_sum.astype(np.float64) / n)
        return {name: self._image(passes[name]) for name in self.light_passes}

    def shader_aov_images(self) -> dict[str, np.ndarray]:
        """The shader AOVs: name -> (h, w, 4) RGBA (COLOR) or (h, w, 1) (VALUE), means over the pixel's samples
        (core.shader_aovs.images)."""
        n = np.maximum(self.count, 1).astype(np.float64)[:, None, None]
        return {name: self._image(arr) for name, arr in
                aov_images(self.shader_aov_sum.astype(np.float64) / n, self.shader_aovs).items()}

    def light_group_images(self) -> dict[str, np.ndarray]:
        """The light groups: pass name (Combined_<group>) -> (h, w, 3), means over the pixel's samples
        (core.light_groups.images)."""
        n = np.maximum(self.count, 1).astype(np.float64)[:, None, None]
        return {name: self._image(arr) for name, arr in
                light_group_images(self.light_group_sum.astype(np.float64) / n, self.light_groups).items()}

    def _image(self, arr: np.ndarray) -> np.ndarray:
        return arr.reshape(self.height, self.width, *arr.shape[1:]).astype(np.float32)

    def mean(self) -> np.ndarray:
        """(h, w, 3) pixel means (0 where no sample has landed yet)."""
        return self._image(self._mean64())

    def alpha_image(self) -> np.ndarray:
        """(h, w) alpha: 1 minus each pixel's mean transparency (1 everywhere for a film without alpha and where
        no sample has landed yet)."""
        if not self.alpha:
            return np.ones((self.height, self.width), np.float32)
        return self._image(1.0 - self.transparent_sum.astype(np.float64) / np.maximum(self.count, 1))

    def combined_rgba(self) -> np.ndarray:
        """(h, w, 4) the image's Combined: the colour means with alpha_image(), or with a shadow catcher as
        Cycles forms it (see the module docstring)."""
        if self.catcher is None:
            return np.concatenate([self.mean(), self.alpha_image()[:, :, None]], axis=2)
        n = np.maximum(self.count, 1).astype(np.float64)
        matte = self.matte_sum.astype(np.float64) / n[:, None]
        alpha = np.clip(1.0 - self.matte_transparent_sum.astype(np.float64) / n, 0.0, 1.0)
        if not self.catcher.shadow_catcher_pass:  # Cycles' approximate shadow catcher
            shadow = np.clip(self._shadow_catcher64().mean(axis=1), 0.0, 1.0)
            alpha = alpha + (1.0 - alpha) * (1.0 - shadow)
            if not self.catcher.transparent:
                matte = matte + (1.0 - alpha)[:, None] * self.background_sum.astype(np.float64) / n[:, None]
                alpha = np.ones_like(alpha)
        return self._image(np.concatenate([matte, alpha[:, None]], axis=1))

    def shadow_catcher_images(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Shadow Catcher (h, w, 3), Shadow Catcher Matte (h, w, 4), Shadow Catcher Sample Count (h, w): the
        share of the pixel's samples that met a catcher) of a film with a shadow catcher."""
        n = np.maximum(self.count, 1).astype(np.float64)
        matte = np.concatenate([self.matte_sum.astype(np.float64) / n[:, None],
                                np.clip(1.0 - self.matte_transparent_sum / n, 0.0, 1.0)[:, None]], axis=1)
        return (self._image(self._shadow_catcher64()), self._image(matte),
                self._image(self.catcher_count / n))

    def _shadow_catcher64(self) -> np.ndarray:
        """(n, 3) the Shadow Catcher pass: the catcher's light with the other objects over its light without
        them (see the module docstring)."""
        count = self.count.astype(np.float64)
        combined = self._mean64() * count[:, None]
        catcher = self.catcher_sum.astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(catcher != 0, (combined - self.matte_sum) / np.where(catcher != 0, catcher, 1), 1.0)
        alpha = np.clip(1.0 - self.transparent_sum / np.maximum(count, 1), 0.0, 1.0)[:, None]
        out = (1.0 - alpha) + alpha * ratio
        return np.where((self.catcher_count > 0)[:, None], out, 1.0)

    def _variance_of_mean(self) -> np.ndarray:
        """(n, 3) estimated variance of each pixel's mean (see the module docstring); 0 with fewer than 2
        samples. ValueError for a film without the error estimate (its sums cannot give it)."""
        if not self.error_estimate:
            raise ValueError("this film keeps no error estimate (RenderSettings.error_estimate is off): the variance "
                             "of its pixels' means is unknown")
        n = self.count.astype(np.float64)[:, None]
        group_dev = self.group_dev.astype(np.float64)
        total = group_dev.sum(axis=1)  # deviations from K: the variance does not see K
        if self.squares:
            with np.errstate(invalid="ignore", divide="ignore"):
                naive = (self.dev_sq.astype(np.float64) - total * total / n) / (n - 1) / n
            var = np.where(n > 1, naive, 0.0)
        else:  # (the grouped estimate below covers every pixel with 2 or more samples)
            var = np.zeros_like(total)
        if self.groups > 1:
            group_count = self.group_counts()
            ng = group_count.astype(np.float64)[:, :, None]
            filled = (group_count > 0).sum(axis=1)[:, None].astype(np.float64)
            with np.errstate(invalid="ignore", divide="ignore"):
                dev = group_dev / np.maximum(ng, 1) - (total / np.maximum(n, 1))[:, None, :]
                dev = np.where(ng > 0, dev, 0.0)
                grouped = (ng * dev * dev).sum(axis=1) / ((filled - 1) * n)
            var = np.where(filled >= 2, grouped, var)
        return np.maximum(var, 0.0)

    def write_colour_images(self, color: np.ndarray, variance: np.ndarray | None, y0: int, x0: int) -> None:
        """Write combined_rgba() and variance_of_mean() into color (H, W, 4) and variance (H, W, 3) float32
        (C-contiguous) at rows y0.., columns x0..: the same bits, compiled where there is no shadow catcher
        (core.film_kernels.colour_images; one pass over the tile instead of some forty float64 passes).
        variance None: the colour only (a film without the error estimate has none to write)."""
        if variance is not None and not self.error_estimate:
            raise ValueError("this film keeps no error estimate: pass variance=None")
        if self.catcher is not None:
            color[y0:y0 + self.height, x0:x0 + self.width] = self.combined_rgba()
            if variance is not None:
                variance[y0:y0 + self.height, x0:x0 + self.width] = self.variance_of_mean()
            return
        if variance is None:  # the kernel writes a variance too: into the tile's own arrays, its colour copied
            tile_color = np.empty((self.height, self.width, 4), np.float32)
            self._colour_kernel(tile_color, np.empty((self.height, self.width, 3), np.float32), 0, 0)
            color[y0:y0 + self.height, x0:x0 + self.width] = tile_color
            return
        self._colour_kernel(color, variance, y0, x0)

    def _colour_kernel(self, color: np.ndarray, variance: np.ndarray, y0: int, x0: int) -> None:
        film_kernels.colour_images(self.shift, self.group_dev, self.sample_count, self._group_prefix[0],
                                   self.squares, self.dev_sq if self.squares else _NO_SQUARES, self.alpha,
                                   self.transparent_sum if self.alpha else _NO_ALPHA, y0, x0, self.width,
                                   color, variance)

    def write_aov_images(self, albedo: np.ndarray, normal: np.ndarray, depth: np.ndarray, y0: int, x0: int
                         ) -> None:
        """Write aov_images() into albedo, normal (H, W, 3) and depth (H, W) float32 (C-contiguous) at rows y0..,
        columns x0.. (compiled: core.film_kernels.aov_images, the same bits)."""
        film_kernels.aov_images(self.albedo, self.normal, self.depth_sum, self.depth_count, self.sample_count,
                                y0, x0, self.width, albedo, normal, depth)

    def variance_of_mean(self) -> np.ndarray:
        """(h, w, 3) estimated variance of each pixel's mean (see the module docstring; 0 with fewer than 2
        samples)."""
        return self._image(self._variance_of_mean())

    def active_pixels(self, threshold: float) -> np.ndarray:
        """Tile-local indices of pixels that still need samples under adaptive sampling.

        A pixel's error is the sum over R, G, B of the standard error of its mean, divided by the square root of
        its summed mean (Cycles' metric: relative to sqrt(intensity), so dark pixels are judged as a display
        transform would show them). A pixel is converged when its error is below `threshold`, and stays active
        while any of its 8 neighbours in the tile is active (Cycles dilates the same way), so noise at the edge
        of a converged region keeps being sampled.
        """
        n = self.count.astype(np.float64)
        mean = self._mean64()
        var = np.where(n[:, None] > 1, self._variance_of_mean(), np.inf)
        err = np.sqrt(var).sum(axis=1) / (1e-4 + np.sqrt(np.maximum(mean.sum(axis=1), 0.0)))
        active = (err >= threshold).reshape(self.height, self.width)
        grown = np.pad(active, 1)
        dilated = np.zeros_like(active)
        for dy in range(3):
            for dx in range(3):
                dilated |= grown[dy:dy + self.height, dx:dx + self.width]
        return np.flatnonzero(dilated.reshape(-1))

    def aov_images(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(albedo (h,w,3), normal (h,w,3) unit where hit, depth (h,w) with 1e10 where nothing was hit)."""
        n = np.maximum(self.count, 1)[:, None]
        albedo = self.albedo / n
        normal = self.normal.astype(np.float64) / n
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.where(length > 0, normal / np.maximum(length, 1e-30), 0.0)
        depth = np.where(self.depth_count > 0, self.depth_sum / np.maximum(self.depth_count, 1), 1e10)
        return self._image(albedo), self._image(normal), self._image(depth)


def _group_prefix_counts(sampler: Sampler | None, groups: int) -> np.ndarray:
    """(P + 1, G) int64: row r holds how many of the samples 0 .. r - 1 fall in each variance group, over one
    period P of the sampler's group rule (4 G covers every sampler's rule: i mod G, and (i // 4) mod G); a rule
    that is not periodic there is refused (the film could not derive its group counts)."""
    if sampler is None:
        return np.array([[0], [1]], np.int64)  # one group, period 1
    period = 4 * groups
    group = np.asarray(sampler.variance_group(np.arange(2 * period)), np.int64)
    if not np.array_equal(group[:period], group[period:]):
        raise ValueError(f"{type(sampler).__name__}'s variance groups do not repeat every {period} samples")
    prefix = np.zeros((period + 1, groups), np.int64)
    for r in range(period):
        prefix[r + 1] = prefix[r]
        prefix[r + 1, group[r]] += 1
    return prefix


def _bincount3(pixel: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n, 3) float64 per-pixel sums of (N, 3) values."""
    out = np.empty((n, 3), np.float64)
    for c in range(3):
        out[:, c] = np.bincount(pixel, weights=values[:, c], minlength=n)
    return out


def _add_raw(into: dict[str, np.ndarray], raw: dict[str, np.ndarray]) -> None:
    """Add one add() call's raw sums into a pass's. The chunks of a pass hold disjoint pixels, so each pixel's
    pass total is its one chunk's value (adding exact zeros elsewhere): the pass folds as its chunks do."""
    for name, arr in raw.items():
        into[name] += arr
