"""Statistics for comparing two noisy renders of the same scene (Monte against Cycles), without Blender.

Conventions: images are (H, W, 3) linear RGB, row 0 at the top; a "variance" image holds the estimated
variance of each pixel's *mean* (not of single samples). Pixels are independent estimates (each sample lands
in one pixel, as Cycles and Monte importance-sample their pixel filters), so the variance of an image mean
is sum(var) / n^2.

Cycles reports no variance, so it is estimated from K independent renders (different seeds):
`runs_mean_and_variance` returns their mean and the per-pixel variance of that mean, s^2 / K with K - 1
degrees of freedom. With K = 4 a z-score built on it follows Student's t with 3 degrees of freedom, whose
tails are far heavier than a Gaussian's (P(|t3| > 3) = 5.8 %, P(|t3| > 5) = 1.5 %), so agreeing images would
look like disagreeing ones. For the per-pixel z-scores both renderers' variance estimates are therefore
pooled over a 3x3 neighbourhood (noise varies slowly across most of an image): about 9 (K - 1) = 27 degrees
of freedom for Cycles with K = 4, which brings P(|t| > 3) to 0.6 % and P(|t| > 5) to 3e-5. Monte's own
estimate comes from its 2 variance groups (core.film): 1 degree of freedom per pixel (9 pooled), and
heavy-tailed where paths are (caustics, light seen through glass): most pixels miss the rare bright paths and
underestimate their variance while a few overestimate it; pooling averages that too. Where the variance changes sharply (a light's edge) pooling spreads it over
neighbours, erring by at most a factor ~2 either way on a few pixels. The image means' sigmas use the
unpooled per-pixel estimates (unbiased, and summing n of them leaves many degrees of freedom).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .metrics import BT709

CHANNELS = ("R", "G", "B")
# Verdict thresholds (docs/crosscheck.md explains them).
MEAN_SIGMAS = 4.0  # channel means agree within max(min(4 sigma, REL_CAP x mean), REL_FLOOR x mean)
REL_FLOOR = 0.005
# Whatever the noise, channel means more than 1 % apart disagree: a noisy render cannot pass a 3 % error.
# (Where Monte approximates on purpose, a larger rel_floor states the gap and wins over the cap.)
REL_CAP = 0.01
Z5_FRACTION = 0.01  # at most 1 % of per-pixel z-scores beyond 5 (Gaussian: 6e-7; pooled t27: 3e-5)


def runs_mean_and_variance(runs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From K >= 2 independent renders (K, H, W, 3): (mean image, per-pixel variance of the mean)."""
    runs = np.asarray(runs, np.float64)
    if runs.ndim != 4 or runs.shape[0] < 2:
        raise ValueError(f"need K >= 2 renders shaped (K, H, W, C), got {runs.shape}")
    k = runs.shape[0]
    mean = runs.mean(axis=0)
    return mean, runs.var(axis=0, ddof=1) / k


def box_smooth(image: np.ndarray, size: int = 3) -> np.ndarray:
    """Mean over a size x size neighbourhood (edges replicated); size 1 returns the image unchanged."""
    if size <= 1:
        return np.asarray(image, np.float64)
    r = size // 2
    padded = np.pad(np.asarray(image, np.float64), ((r, r), (r, r)) + ((0, 0),) * (np.ndim(image) - 2),
                    mode="edge")
    h, w = image.shape[:2]
    out = np.zeros(np.shape(image), np.float64)
    for dy in range(size):  # size^2 shifted adds: vectorised over the image
        for dx in range(size):
            out += padded[dy:dy + h, dx:dx + w]
    return out / (size * size)


@dataclass
class Comparison:
    """Monte against a reference renderer (Cycles) on one image; every number is per channel R, G, B."""

    mean_a: np.ndarray  # Monte's channel means
    mean_b: np.ndarray  # Cycles' channel means
    sigma_a: np.ndarray  # standard error of Monte's channel means
    sigma_b: np.ndarray
    tolerance: np.ndarray  # allowed |mean_a - mean_b|
    z: np.ndarray  # (H, W, 3) per-pixel z-scores
    rmse: float  # between the two images (includes both renders' noise)
    rmse_noise: float  # what the RMSE would be from the estimated noise alone
    pixels: int
    rel_floor: float = REL_FLOOR
    sigmas: float = MEAN_SIGMAS
    rel_cap: float = REL_CAP
    notes: list[str] = field(default_factory=list)

    @property
    def resolvable(self) -> np.ndarray:
        """(3,) the smallest relative difference of the channel means the noise lets this comparison see:
        sigmas x sigma / |mean_b|. Above rel_cap the cap sets the tolerance and noise alone can fail it."""
        return self.sigmas * self.sigma / np.maximum(np.abs(self.mean_b), 1e-12)

    @property
    def sigma(self) -> np.ndarray:
        return np.hypot(self.sigma_a, self.sigma_b)

    @property
    def difference(self) -> np.ndarray:
        return self.mean_a - self.mean_b

    @property
    def relative_difference(self) -> np.ndarray:
        return self.difference / np.maximum(np.abs(self.mean_b), 1e-12)

    @property
    def means_agree(self) -> np.ndarray:
        return np.abs(self.difference) <= self.tolerance

    def z_stats(self) -> dict[str, float]:
        z = self.z[np.isfinite(self.z)]
        if z.size == 0:
            return {"mean": 0.0, "std": 0.0, "frac_gt3": 0.0, "frac_gt5": 0.0, "max_abs": 0.0, "count": 0}
        a = np.abs(z)
        return {"mean": float(z.mean()), "std": float(z.std()), "frac_gt3": float((a > 3).mean()),
                "frac_gt5": float((a > 5).mean()), "max_abs": float(a.max()), "count": int(z.size)}

    def verdict(self) -> tuple[bool, list[str]]:
        """(agree, reasons it does not): channel means within tolerance and no excess of |z| > 5 pixels."""
        reasons = []
        for i, c in enumerate(CHANNELS):
            if not self.means_agree[i]:
                reasons.append(f"channel {c}: mean differs by {100 * self.relative_difference[i]:+.2f} % "
                               f"({self.difference[i] / max(self.sigma[i], 1e-30):+.1f} sigma; allowed "
                               f"{self.tolerance[i]:.3g}" + (f", capped at {100 * self.rel_cap:g} %: the noise "
                               f"alone resolves only {100 * self.resolvable[i]:.2f} %"
                               if self.resolvable[i] > max(self.rel_cap, self.rel_floor) else "") + ")")
        zs = self.z_stats()
        if zs["frac_gt5"] > Z5_FRACTION:
            reasons.append(f"{100 * zs['frac_gt5']:.2f} % of pixel values differ by more than 5 sigma "
                           f"(allowed {100 * Z5_FRACTION:.0f} %): a local difference")
        return not reasons, reasons


def compare(
    image_a: np.ndarray,
    var_a: np.ndarray,
    image_b: np.ndarray,
    var_b: np.ndarray,
    *,
    rel_floor: float = REL_FLOOR,
    sigmas: float = MEAN_SIGMAS,
    rel_cap: float = REL_CAP,
    pool: int = 3,
) -> Comparison:
    """Compare image_a with image_b, given the per-pixel variances of their means. Channel means agree when
    |difference| <= max(min(sigmas x sigma, rel_cap x |mean_b|), rel_floor x |mean_b|): within the noise, never
    more than rel_cap apart unless rel_floor (a stated model gap) allows it; per-pixel z-scores use both
    variances pooled over pool x pool pixels (1 = no pooling)."""
    a = np.asarray(image_a, np.float64)[..., :3]
    b = np.asarray(image_b, np.float64)[..., :3]
    va = np.maximum(np.asarray(var_a, np.float64)[..., :3], 0.0)
    vb = np.maximum(np.asarray(var_b, np.float64)[..., :3], 0.0)
    if a.shape != b.shape or va.shape != a.shape or vb.shape != a.shape:
        raise ValueError(f"image shapes differ: {a.shape}, {va.shape}, {b.shape}, {vb.shape}")
    n = a.shape[0] * a.shape[1]
    mean_a = a.reshape(-1, 3).mean(axis=0)
    mean_b = b.reshape(-1, 3).mean(axis=0)
    sigma_a = np.sqrt(va.reshape(-1, 3).sum(axis=0)) / n
    sigma_b = np.sqrt(vb.reshape(-1, 3).sum(axis=0)) / n
    tolerance = np.maximum(np.minimum(sigmas * np.hypot(sigma_a, sigma_b), rel_cap * np.abs(mean_b)),
                           rel_floor * np.abs(mean_b))
    diff = a - b
    # float32 rounding of noise-free pixels (a plain background) is not a difference: floor the error scale
    # at 1e-5 of the value (float32 carries ~6e-8), and at 1e-12 absolute.
    floor = (1e-5 * np.maximum(np.abs(a), np.abs(b))) ** 2 + 1e-24
    pooled = box_smooth(va + vb, pool)
    z = diff / np.sqrt(pooled + floor)
    return Comparison(mean_a, mean_b, sigma_a, sigma_b, tolerance, z,
                      rmse=float(np.sqrt(np.mean(diff * diff))),
                      rmse_noise=float(np.sqrt(np.mean(va + vb))), pixels=n, rel_floor=rel_floor, sigmas=sigmas,
                      rel_cap=rel_cap)


def region_attribution(comparison: Comparison, labels: np.ndarray, names: dict[int, str],
                       image_a: np.ndarray, image_b: np.ndarray) -> list[dict]:
    """Split the difference by region (labels: (H, W) ints, e.g. Cycles' material index pass).

    For each label: its pixel count, the signed luma difference summed over its pixels as a share of the whole
    image's absolute luma difference, the mean z and the excess chi-square sum(z^2 - 1) over its values (how
    much disagreement beyond noise it holds). Sorted by excess chi-square, largest first."""
    labels = np.asarray(labels).astype(np.int64)
    z = np.where(np.isfinite(comparison.z), comparison.z, 0.0)
    luma_diff = (np.asarray(image_a, np.float64)[..., :3] - np.asarray(image_b, np.float64)[..., :3]) @ BT709
    total_abs = max(float(np.abs(luma_diff).sum()), 1e-30)
    rows = []
    for label in np.unique(labels):
        mask = labels == label
        zm = z[mask]
        rows.append({
            "label": int(label),
            "name": names.get(int(label), f"index {int(label)}"),
            "pixels": int(mask.sum()),
            "luma_difference_share": float(luma_diff[mask].sum() / total_abs),
            "mean_z": float(zm.mean()),
            "frac_gt3": float((np.abs(zm) > 3).mean()),
            "excess_chi2": float((zm * zm - 1.0).sum()),
        })
    rows.sort(key=lambda r: -r["excess_chi2"])
    return rows


def zscore_colors(z: np.ndarray, limit: float = 5.0) -> np.ndarray:
    """False colour (H, W, 3) in [0, 1] (display values, not linear) for per-pixel z-scores (H, W, 3):
    each pixel shows its channel of largest |z|; black = agreement, red = Monte brighter, blue = Monte darker,
    full brightness at |z| >= limit; |z| > limit is drawn yellow (brighter) or cyan (darker)."""
    z = np.where(np.isfinite(z), z, np.sign(np.nan_to_num(z)) * 1e9)
    idx = np.abs(z).argmax(axis=-1)
    zmax = np.take_along_axis(z, idx[..., None], axis=-1)[..., 0]
    t = np.clip(np.abs(zmax) / limit, 0.0, 1.0)
    out = np.zeros(zmax.shape + (3,))
    pos, neg = zmax > 0, zmax < 0
    out[pos, 0] = t[pos]
    out[neg, 2] = t[neg]
    out[neg, 0] = 0.25 * t[neg]
    out[neg, 1] = 0.35 * t[neg]
    over = np.abs(zmax) > limit
    out[over & pos] = (1.0, 1.0, 0.0)
    out[over & neg] = (0.0, 1.0, 1.0)
    return out


def srgb_to_linear(display: np.ndarray) -> np.ndarray:
    """Inverse of the sRGB transfer curve, so display colours survive core.exr.write_png's encoding."""
    s = np.clip(np.asarray(display, np.float64), 0.0, 1.0)
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def upscale(image: np.ndarray, min_size: int = 256) -> np.ndarray:
    """Nearest-neighbour upscale by an integer factor so the longer side is at least min_size pixels."""
    factor = max(1, -(-min_size // max(image.shape[:2])))
    return np.repeat(np.repeat(image, factor, axis=0), factor, axis=1)
