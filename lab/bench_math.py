"""The arithmetic of run time against error: noise-corrected RMSE, the seed's efficiency, equal-error ratios.

Conventions: times in seconds, errors as RMSE over all pixels and the R, G, B channels of linear images.
A converged reference still carries noise of its own (mean squared error `reference_mse` against the true
image); since that noise is independent of the image measured, MSE(image, reference) = MSE(image, truth) +
reference_mse in expectation, so it is subtracted in quadrature. The seed's efficiency is 1 / (T x V)
with the corrected MSE standing in for V. At equal error e, efficiency 1/(t e^2) of two renderers compares
as their times: ratio(e) = t_other(e) / t_this(e), read off each renderer's piecewise-linear log-log line.

Also: the JSON/PNG writers and the compact table the bench commands print. No bpy here.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..core.atomic_file import write_atomically, write_text_atomically


def corrected_rmse(rmse: float, reference_mse: float) -> float:
    """RMSE against the truth, estimated from RMSE against a noisy reference with mean squared error
    reference_mse (independent noise subtracts in quadrature; clipped at 0)."""
    return float(math.sqrt(max(rmse * rmse - reference_mse, 0.0)))


def efficiency(seconds: float, mse: float) -> float:
    """The seed's efficiency 1 / (T x V): T the time (seconds, or another cost), V the variance of the estimate,
    for which the MSE against a reference stands in; inf when either is 0 (a point to leave off a log plot).
    The project's one meaning of efficiency (bench, perf, the MC study)."""
    return 1.0 / (seconds * mse) if seconds > 0 and mse > 0 else float("inf")


def reference_from_seeds(images: Sequence[np.ndarray]) -> tuple[np.ndarray, float]:
    """The mean of K >= 2 independent renders (different seeds) and its own mean squared error: per pixel
    and channel, the variance of the mean is s^2 / K with s^2 the unbiased spread over the seeds; averaged
    over the image that is the expected MSE of the mean against the truth."""
    if len(images) < 2:
        raise ValueError("a reference needs at least 2 independent renders to estimate its own noise")
    stack = np.stack([np.asarray(im[..., :3], np.float64) for im in images])
    mean = stack.mean(axis=0)
    own_mse = float(stack.var(axis=0, ddof=1).mean() / len(images))
    return mean.astype(np.float32), own_mse


def _valid_points(seconds: Iterable[float], rmse: Iterable[float]) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(list(seconds), np.float64)
    e = np.asarray(list(rmse), np.float64)
    keep = np.isfinite(t) & np.isfinite(e) & (t > 0) & (e > 0)
    return t[keep], e[keep]


def loglog_fit(seconds: Iterable[float], rmse: Iterable[float]) -> tuple[float, float]:
    """Least-squares line log(rmse) = a + b log(seconds); returns (a, b). b = -0.5 for a pure Monte Carlo
    estimator whose time grows with its sample count."""
    t, e = _valid_points(seconds, rmse)
    if len(t) < 2:
        raise ValueError("a log-log fit needs at least 2 points with positive time and error")
    b, a = np.polyfit(np.log(t), np.log(e), 1)
    return float(a), float(b)


def seconds_at_rmse(seconds: Iterable[float], rmse: Iterable[float], levels: Iterable[float]) -> np.ndarray:
    """Time to reach each RMSE level on the renderer's log-log line: piecewise-linear interpolation of
    log(seconds) against log(rmse) through the measured points (sorted by error); NaN outside their range."""
    t, e = _valid_points(seconds, rmse)
    levels = np.asarray(list(levels), np.float64)
    out = np.full(levels.shape, np.nan)
    if len(t) == 0:
        return out
    order = np.argsort(e)
    le, lt = np.log(e[order]), np.log(t[order])
    inside = (levels >= e.min()) & (levels <= e.max())
    out[inside] = np.exp(np.interp(np.log(levels[inside]), le, lt))
    return out


def equal_error_ratio(this: tuple[Sequence[float], Sequence[float]],
                      other: tuple[Sequence[float], Sequence[float]], n_levels: int = 5) -> dict:
    """Efficiency of `this` over `other` at equal error, each given as (seconds, rmse) point lists.

    Levels: n_levels RMSE values spaced evenly in log between the largest of the two smallest errors and
    the smallest of the two largest (the errors both reached). At each level the ratio of efficiencies
    1/(t e^2) is t_other(e) / t_this(e). When the ranges do not overlap, both log-log least-squares lines
    are extended to the geometric middle of all errors and `extrapolated` is True.
    Returns levels, seconds_this, seconds_other, ratios, ratio (geometric mean over the levels) and
    extrapolated; ratio is NaN when either side has fewer than 2 usable points (and no overlap).
    """
    t1, e1 = _valid_points(*this)
    t2, e2 = _valid_points(*other)
    nan = {"levels": [], "seconds_this": [], "seconds_other": [], "ratios": [], "ratio": float("nan"),
           "extrapolated": False}
    if len(t1) == 0 or len(t2) == 0:
        return nan
    lo, hi = max(e1.min(), e2.min()), min(e1.max(), e2.max())
    if lo <= hi:
        levels = np.exp(np.linspace(math.log(lo), math.log(hi), n_levels)) if hi > lo else np.array([lo])
        levels = np.clip(levels, lo, hi)  # exp(log(x)) may round just outside the measured range
        s1, s2 = seconds_at_rmse(t1, e1, levels), seconds_at_rmse(t2, e2, levels)
        extrapolated = False
    else:
        if len(t1) < 2 or len(t2) < 2:
            return nan
        (a1, b1), (a2, b2) = loglog_fit(t1, e1), loglog_fit(t2, e2)
        if b1 >= 0 or b2 >= 0:  # error not falling with time: no meaningful extension
            return nan
        levels = np.array([math.exp(np.log(np.concatenate([e1, e2])).mean())])
        s1 = np.exp((np.log(levels) - a1) / b1)
        s2 = np.exp((np.log(levels) - a2) / b2)
        extrapolated = True
    ratios = s2 / s1
    return {"levels": levels.tolist(), "seconds_this": s1.tolist(), "seconds_other": s2.tolist(),
            "ratios": ratios.tolist(), "ratio": float(np.exp(np.mean(np.log(ratios)))),
            "extrapolated": extrapolated}


# --------------------------------------------------------------------------------------------- output
def write_json(path: str | os.PathLike, data) -> Path:
    """Write JSON atomically (core.atomic_file)."""
    return write_text_atomically(path, json.dumps(data, indent=2, default=_json_default) + "\n", ".json")


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def format_table(headers: Sequence[str], rows: Sequence[Sequence], markdown: bool = False) -> str:
    """A fixed-width text table (or a Markdown table); floats keep 4 significant digits."""
    def cell(v) -> str:
        if isinstance(v, float):
            if not math.isfinite(v):
                return "-"
            return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}"
        return str(v)

    body = [[cell(v) for v in row] for row in rows]
    if markdown:
        lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
        lines += ["| " + " | ".join(r) + " |" for r in body]
        return "\n".join(lines)
    widths = [max(len(h), *(len(r[i]) for r in body)) if body else len(h) for i, h in enumerate(headers)]
    fmt = "  ".join(f"{{:>{w}}}" for w in widths)
    return "\n".join([fmt.format(*headers)] + [fmt.format(*r) for r in body])


def plot_rmse_vs_seconds(panels: Sequence[dict], path: str | os.PathLike) -> Path:
    """A log-log plot of RMSE against seconds, one panel per scene. Each panel: {"title": str, "series":
    [{"label": str, "seconds": [...], "rmse": [...], "spp": [...] (optional, annotated)}]}; also draws the
    slope -1/2 guide through each series' first point. Written atomically (matplotlib, Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(len(panels), 1)
    cols = min(n, 2)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 4.2 * rows), squeeze=False)
    for ax, panel in zip(axes.ravel(), panels):
        for k, series in enumerate(panel["series"]):
            t, e = _valid_points(series["seconds"], series["rmse"])
            if len(t) == 0:
                continue
            line, = ax.loglog(t, e, "o-", label=series["label"])
            guide = np.array([t.min(), t.max()])
            ax.loglog(guide, e[np.argmin(t)] * np.sqrt(guide.min() / guide), ":", color=line.get_color(),
                      alpha=0.5, label="slope -1/2" if k == 0 else None)
            for ti, ei, s in zip(series["seconds"], series["rmse"], series.get("spp") or []):
                if ti > 0 and ei > 0:
                    ax.annotate(str(s), (ti, ei), textcoords="offset points", xytext=(4, 4), fontsize=7,
                                color=line.get_color())
        ax.set_title(panel["title"], fontsize=10)
        ax.set_xlabel("seconds")
        ax.set_ylabel("RMSE vs reference (its own noise removed)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    fig.tight_layout()
    try:
        return write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"), ".png")
    finally:
        plt.close(fig)
