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

Memory per pixel: G x (3 float64 sums + an int32 count) + 3 float64 sums of squares = 136 B with G = 4
(core.memory.FILM_BYTES), against 56 B for a sum, a sum of squares and a count alone.
"""

from __future__ import annotations

import numpy as np

from .sampling import Sampler


class TileFilm:
    """Accumulators for a tile of h x w pixels. Samples arrive with their tile-local pixel index (row-major,
    row 0 at the top) and their sample index (which picks their variance group, see the module docstring)."""

    def __init__(self, width: int, height: int, aovs: bool, sampler: Sampler | None = None,
                 features: bool = False, alpha: bool = False) -> None:
        """features: keep the denoising features' sums; alpha: keep each pixel's summed transparency
        (core.scene.Film); without it alpha is 1."""
        self.width, self.height = width, height
        n = width * height
        # Independent samples need no groups: s^2 / n is exact for them and has the most degrees of freedom.
        self._sampler = sampler if sampler is not None and not sampler.iid and sampler.groups > 1 else None
        self.groups = self._sampler.groups if self._sampler is not None else 1
        self.group_sum = np.zeros((n, self.groups, 3), np.float64)
        self.group_count = np.zeros((n, self.groups), np.int32)
        self.sum_sq = np.zeros((n, 3), np.float64)
        self.aovs = aovs
        self.alpha = alpha
        if alpha:
            self.transparent_sum = np.zeros(n, np.float64)
        if aovs:
            self.albedo = np.zeros((n, 3), np.float64)
            self.normal = np.zeros((n, 3), np.float64)
            self.depth_sum = np.zeros(n, np.float64)
            self.depth_count = np.zeros(n, np.int64)
        self.features = features  # the denoising albedo and normal (core.integrator.DenoisingFeatures)
        if features:
            self.feature_albedo = np.zeros((n, 3), np.float64)
            self.feature_normal = np.zeros((n, 3), np.float64)

    @property
    def sum(self) -> np.ndarray:
        """(n, 3) sum of each pixel's samples."""
        return self.group_sum.sum(axis=1)

    @property
    def count(self) -> np.ndarray:
        """(n,) samples each pixel has taken."""
        return self.group_count.sum(axis=1, dtype=np.int64)

    def add(self, pixel: np.ndarray, radiance: np.ndarray, sample: np.ndarray | None = None,
            transparent: np.ndarray | None = None) -> None:
        """Accumulate samples: pixel (N,) tile-local index, radiance (N, 3) finite values, sample (N,) their
        sample indices (needed when the film has variance groups), transparent (N,) their transparency in
        [0, 1] (needed when the film keeps alpha)."""
        n = self.group_count.shape[0]
        slot = np.asarray(pixel, np.int64)
        if self.groups > 1:
            if sample is None:
                raise ValueError("this film keeps variance groups: pass the samples' indices")
            slot = slot * self.groups + self._sampler.variance_group(sample)
        slots = n * self.groups
        self.group_count += np.bincount(slot, minlength=slots).reshape(n, self.groups).astype(np.int32)
        r = radiance.astype(np.float64)
        for c in range(3):
            self.group_sum[:, :, c] += np.bincount(slot, weights=r[:, c], minlength=slots).reshape(n, self.groups)
            self.sum_sq[:, c] += np.bincount(pixel, weights=r[:, c] * r[:, c], minlength=n)
        if self.alpha:
            if transparent is None:
                raise ValueError("this film keeps alpha: pass the samples' transparency")
            self.transparent_sum += np.bincount(pixel, weights=np.asarray(transparent, np.float64), minlength=n)

    def sums(self) -> dict[str, np.ndarray]:
        """The film's raw accumulators by name (the arrays themselves, not copies): what a render split across
        machines sends back and merges with add_sums."""
        names = ["group_sum", "group_count", "sum_sq"]
        if self.alpha:
            names.append("transparent_sum")
        if self.aovs:
            names += ["albedo", "normal", "depth_sum", "depth_count"]
        if self.features:
            names += ["feature_albedo", "feature_normal"]
        return {name: getattr(self, name) for name in names}

    def add_sums(self, sums: dict[str, np.ndarray]) -> None:
        """Add another film's raw accumulators (same tile, same groups, same AOV setting) into this one.

        Adding the accumulators of a film that holds one pass of samples, started from zero, gives bit for bit
        what add() of that pass's samples gives: each pixel's pass total is summed in the same order either way,
        then added once to the running total. So films merged pass by pass, in pass order, equal one render."""
        mine = self.sums()
        if set(sums) != set(mine):
            raise ValueError(f"film sums hold {sorted(sums)}, this film keeps {sorted(mine)}")
        for name, arr in mine.items():
            if sums[name].shape != arr.shape:
                raise ValueError(f"film sums {name!r} have shape {sums[name].shape}, this film {arr.shape}")
            arr += sums[name]

    def clear(self) -> None:
        """Set every accumulator back to zero."""
        for arr in self.sums().values():
            arr[...] = 0

    def add_aovs(self, pixel: np.ndarray, albedo: np.ndarray, normal: np.ndarray, depth: np.ndarray) -> None:
        """Accumulate first-hit AOVs (averaged over the pixel's samples); depth only where finite (a hit)."""
        n = self.group_count.shape[0]
        for c in range(3):
            self.albedo[:, c] += np.bincount(pixel, weights=albedo[:, c], minlength=n)
            self.normal[:, c] += np.bincount(pixel, weights=normal[:, c], minlength=n)
        hit = np.isfinite(depth)
        self.depth_sum += np.bincount(pixel[hit], weights=depth[hit], minlength=n)
        self.depth_count += np.bincount(pixel[hit], minlength=n)

    def add_features(self, pixel: np.ndarray, albedo: np.ndarray, normal: np.ndarray) -> None:
        """Accumulate the denoising features of samples (averaged over the pixel's samples)."""
        n = self.group_count.shape[0]
        for c in range(3):
            self.feature_albedo[:, c] += np.bincount(pixel, weights=albedo[:, c], minlength=n)
            self.feature_normal[:, c] += np.bincount(pixel, weights=normal[:, c], minlength=n)

    def feature_images(self) -> tuple[np.ndarray, np.ndarray]:
        """(denoising albedo (h,w,3), denoising normal (h,w,3), world space): plain means over the pixel's
        samples, the normal not renormalised (as Cycles' passes)."""
        n = np.maximum(self.count, 1)[:, None]
        return self._image(self.feature_albedo / n), self._image(self.feature_normal / n)

    def _image(self, arr: np.ndarray) -> np.ndarray:
        return arr.reshape(self.height, self.width, *arr.shape[1:]).astype(np.float32)

    def mean(self) -> np.ndarray:
        """(h, w, 3) pixel means (0 where no sample has landed yet)."""
        return self._image(self.sum / np.maximum(self.count, 1)[:, None])

    def alpha_image(self) -> np.ndarray:
        """(h, w) alpha: 1 minus each pixel's mean transparency (1 everywhere for a film without alpha and where
        no sample has landed yet)."""
        if not self.alpha:
            return np.ones((self.height, self.width), np.float32)
        return self._image(1.0 - self.transparent_sum / np.maximum(self.count, 1))

    def _variance_of_mean(self) -> np.ndarray:
        """(n, 3) estimated variance of each pixel's mean (see the module docstring); 0 with fewer than 2
        samples."""
        n = self.count.astype(np.float64)[:, None]
        total = self.sum
        with np.errstate(invalid="ignore", divide="ignore"):
            naive = (self.sum_sq - total * total / n) / (n - 1) / n
        var = np.where(n > 1, naive, 0.0)
        if self.groups > 1:
            ng = self.group_count.astype(np.float64)[:, :, None]
            filled = (self.group_count > 0).sum(axis=1)[:, None].astype(np.float64)
            with np.errstate(invalid="ignore", divide="ignore"):
                dev = self.group_sum / np.maximum(ng, 1) - (total / np.maximum(n, 1))[:, None, :]
                grouped = (ng * dev * dev).sum(axis=1) / ((filled - 1) * n)
            var = np.where(filled >= 2, grouped, var)
        return np.maximum(var, 0.0)

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
        mean = self.sum / np.maximum(n, 1)[:, None]
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
        normal = self.normal / n
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.where(length > 0, normal / np.maximum(length, 1e-30), 0.0)
        depth = np.where(self.depth_count > 0, self.depth_sum / np.maximum(self.depth_count, 1), 1e10)
        return self._image(albedo), self._image(normal), self._image(depth)
