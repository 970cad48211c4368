"""Image error metrics: RMSE, relMSE, channel means with confidence intervals, the seed's variance tables.

Images are (H, W, 3) linear RGB. BT.709 luma weights (0.2126, 0.7152, 0.0722) as in the seed's tables.
"""

from __future__ import annotations

import math

import numpy as np

BT709 = np.array([0.2126, 0.7152, 0.0722])


def rmse(image: np.ndarray, reference: np.ndarray) -> float:
    """Root mean squared error over all pixels and the R, G, B channels."""
    diff = np.asarray(image[..., :3], np.float64) - np.asarray(reference[..., :3], np.float64)
    return float(np.sqrt(np.mean(diff * diff)))


def relmse(image: np.ndarray, reference: np.ndarray, eps: float = 1e-2) -> float:
    """Relative MSE: mean of (x - ref)^2 / (ref^2 + eps), robust to dark pixels."""
    x = np.asarray(image[..., :3], np.float64)
    r = np.asarray(reference[..., :3], np.float64)
    return float(np.mean((x - r) ** 2 / (r * r + eps)))


def channel_means(image: np.ndarray) -> np.ndarray:
    """(3,) mean of each channel over the image."""
    return np.asarray(image[..., :3], np.float64).reshape(-1, 3).mean(axis=0)


def channel_mean_sigma(variance_of_mean: np.ndarray) -> np.ndarray:
    """(3,) standard error of the channel means, from per-pixel variances of the pixel means (pixels are
    independent estimates, so the variance of their average is sum(var) / n^2)."""
    v = np.asarray(variance_of_mean[..., :3], np.float64).reshape(-1, 3)
    return np.sqrt(v.sum(axis=0)) / v.shape[0]


def mean_confidence_interval(values: np.ndarray, z: float = 3.29) -> tuple[float, float]:
    """(mean, half-width) of the z-sigma confidence interval of the mean of i.i.d. values (3.29 = 99.9%)."""
    values = np.asarray(values, np.float64).ravel()
    half = z * values.std(ddof=1) / math.sqrt(len(values)) if len(values) > 1 else float("inf")
    return float(values.mean()), float(half)


def seed_variance_table(image: np.ndarray) -> dict[str, float]:
    """The seed's tables: variance of pixel values over the image for R, G, B and BT.709 luma.
    (This measures image contrast plus noise; `mean_pixel_variance` measures the noise alone.)"""
    rgb = np.asarray(image[..., :3], np.float64).reshape(-1, 3)
    luma = rgb @ BT709
    return {"R": float(rgb[:, 0].var()), "G": float(rgb[:, 1].var()), "B": float(rgb[:, 2].var()),
            "luma": float(luma.var())}


def mean_pixel_variance(variance_of_mean: np.ndarray) -> dict[str, float]:
    """Mean over pixels of the estimated variance of each pixel's mean, per channel and for luma (assuming
    independent channels for luma, an upper-bound-free approximation used for reporting)."""
    v = np.asarray(variance_of_mean[..., :3], np.float64).reshape(-1, 3)
    return {"R": float(v[:, 0].mean()), "G": float(v[:, 1].mean()), "B": float(v[:, 2].mean()),
            "luma": float((v @ (BT709 * BT709)).mean())}

