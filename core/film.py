"""Film: per-pixel accumulation of samples (sum, sum of squares, count) and first-hit AOVs for one tile.

Pixel filters are importance-sampled (core.filters), as Cycles does: each sample lands in the pixel it was
generated for with weight 1, so a pixel's value is a plain mean and its variance estimate is exact.
"""

from __future__ import annotations

import numpy as np


class TileFilm:
    """Accumulators for a tile of h x w pixels. Samples arrive with their tile-local pixel index (row-major,
    row 0 at the top)."""

    def __init__(self, width: int, height: int, aovs: bool) -> None:
        self.width, self.height = width, height
        n = width * height
        self.sum = np.zeros((n, 3), np.float64)
        self.sum_sq = np.zeros((n, 3), np.float64)
        self.count = np.zeros(n, np.int64)
        self.aovs = aovs
        if aovs:
            self.albedo = np.zeros((n, 3), np.float64)
            self.normal = np.zeros((n, 3), np.float64)
            self.depth_sum = np.zeros(n, np.float64)
            self.depth_count = np.zeros(n, np.int64)

    def add(self, pixel: np.ndarray, radiance: np.ndarray) -> None:
        """Accumulate samples: pixel (N,) tile-local index, radiance (N, 3) finite values."""
        n = self.count.shape[0]
        self.count += np.bincount(pixel, minlength=n)
        r = radiance.astype(np.float64)
        for c in range(3):
            self.sum[:, c] += np.bincount(pixel, weights=r[:, c], minlength=n)
            self.sum_sq[:, c] += np.bincount(pixel, weights=r[:, c] * r[:, c], minlength=n)

    def add_aovs(self, pixel: np.ndarray, albedo: np.ndarray, normal: np.ndarray, depth: np.ndarray) -> None:
        """Accumulate first-hit AOVs (averaged over the pixel's samples); depth only where finite (a hit)."""
        n = self.count.shape[0]
        for c in range(3):
            self.albedo[:, c] += np.bincount(pixel, weights=albedo[:, c], minlength=n)
            self.normal[:, c] += np.bincount(pixel, weights=normal[:, c], minlength=n)
        hit = np.isfinite(depth)
        self.depth_sum += np.bincount(pixel[hit], weights=depth[hit], minlength=n)
        self.depth_count += np.bincount(pixel[hit], minlength=n)

    def _image(self, arr: np.ndarray) -> np.ndarray:
        return arr.reshape(self.height, self.width, *arr.shape[1:]).astype(np.float32)

    def mean(self) -> np.ndarray:
        """(h, w, 3) pixel means (0 where no sample has landed yet)."""
        return self._image(self.sum / np.maximum(self.count, 1)[:, None])

    def variance_of_mean(self) -> np.ndarray:
        """(h, w, 3) unbiased estimate of the variance of each pixel's mean: s^2 / n (0 with fewer than 2)."""
        n = self.count[:, None].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            var = (self.sum_sq - self.sum * self.sum / n) / (n - 1) / n
        var = np.where(n > 1, np.maximum(var, 0.0), 0.0)
        return self._image(var)

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
        with np.errstate(invalid="ignore", divide="ignore"):
            var = np.where(n[:, None] > 1, (self.sum_sq - self.sum * mean) / (n[:, None] - 1) / n[:, None], np.inf)
        err = np.sqrt(np.maximum(var, 0.0)).sum(axis=1) / (1e-4 + np.sqrt(np.maximum(mean.sum(axis=1), 0.0)))
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
