"""The environment-map world: an HDRI (Blender's Environment Texture on the Background) as a light that every
escaping ray sees and that next-event estimation samples by its brightness.

`EnvironmentMap` is the data (core.scene.World holds it); `EnvironmentDistribution` builds, once per render, the
tables the compiled kernels (core.world_kernels) read: the map itself, the Mapping matrix, and a piecewise-constant
2D distribution over an equirectangular grid of world directions, as Cycles builds its background map:
- the grid is Cycles' world "Map Resolution" (width x width / 2) or, with Auto (`map_resolution` 0), the
  image's own size, capped at MAX_IMPORTANCE_WIDTH x half of it;
- each cell holds the luminance of the world (the map seen through the Mapping node and the projection)
  averaged over 2 x 2 directions in it (the centre alone, as Cycles, beyond 2^20 cells) plus IMPORTANCE_FLOOR x
  the mean, times cos(elevation) (the cell's solid angle); the floor keeps the pdf positive wherever the map may
  be lit, so light sampling alone stays unbiased;
- a direction's solid-angle pdf is p(u, v) / (2 pi^2 cos(elevation)), p the density over the (u, v) square.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np


def _kernels():
    """core.world_kernels, imported on first use: core.scene imports this module, and what only builds or checks
    a scene (the `monte` command's parser, `monte render --list`) should not import numba."""
    from . import world_kernels

    return world_kernels


__all__ = ["EnvironmentMap", "EnvironmentMapError", "EnvironmentDistribution", "IMPORTANCE_FLOOR",
           "MAX_IMPORTANCE_WIDTH", "environment_radiance", "importance_luminance", "portal_table"]

# Share of the mean luminance added to every cell of the importance grid: where a cell's centre is black but its
# texels are not (a small light between grid centres), light sampling keeps a chance to find it.
IMPORTANCE_FLOOR = 1e-3
# Each importance cell averages the world over this many points squared: a small sun between cell centres (the
# bilinear footprint of a bright texel reaches into the neighbouring cells) is still found by light sampling
# (one point, Cycles' choice, left 1.8 % relative noise on a one-texel sun where 2 x 2 leaves 0.14 %).
IMPORTANCE_SUBSAMPLES = 2
_SUBSAMPLED_CELLS = 1 << 20  # larger grids (finer than a 1024 x 512 map) take the centre alone: 4x less set-up
# Auto resolution follows the image; beyond this width the grid (two float64 tables) costs more than it gains.
MAX_IMPORTANCE_WIDTH = 4096
GRID_ROWS_PER_THREAD = 32  # importance_luminance: fewer rows a thread cost less than starting it
_LUM = np.array([0.2126, 0.7152, 0.0722])


class EnvironmentMapError(ValueError):
    """An environment map that cannot be rendered (bad shape, unknown projection)."""


@dataclass
class EnvironmentMap:
    """An image lighting the world from every direction (Blender's Environment Texture on the Background).

    pixels: (H, W, 3) float32 linear RGB radiance, row 0 at the TOP (core.texture's convention), held once.
    projection: "EQUIRECTANGULAR" (u along -azimuth from -x, v = elevation) or "MIRROR_BALL" (a mirror sphere
    photographed from -y), Cycles' conventions (core.world_kernels). interpolation: "LINEAR" (bilinear) or
    "CLOSEST". matrix: (3, 3), the Mapping node's linear part: the map is read in direction matrix @ d for the
    world direction d (a rotation; a scale stretches it; location is ignored as for any direction).
    strength: (3,) multiplies the texels (Background Strength x a constant colour factor).
    map_resolution: width of the importance grid (height width / 2), Cycles' world Map Resolution; 0 is Auto
    (the image's own size). importance_sampling False: Cycles' sampling method None, the world is found by BSDF
    sampling alone. name: for warnings (the world and image)."""

    pixels: np.ndarray
    projection: Literal["EQUIRECTANGULAR", "MIRROR_BALL"] = "EQUIRECTANGULAR"
    interpolation: Literal["LINEAR", "CLOSEST"] = "LINEAR"
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    strength: np.ndarray = field(default_factory=lambda: np.ones(3))
    map_resolution: int = 0
    importance_sampling: bool = True
    name: str = "environment"

    def validate(self, warnings: list[str]) -> None:
        """Check the shape and settings (EnvironmentMapError); clamp NaN, Inf and negative texels to 0 with one
        warning counting them."""
        px = np.asarray(self.pixels)
        if px.ndim != 3 or px.shape[2] != 3 or px.shape[0] < 1 or px.shape[1] < 1:
            raise EnvironmentMapError(f"environment {self.name!r}: pixels must be (H, W, 3), got {px.shape}")
        if self.projection not in ("EQUIRECTANGULAR", "MIRROR_BALL"):
            raise EnvironmentMapError(f"environment {self.name!r}: unknown projection {self.projection!r}")
        if self.interpolation not in ("LINEAR", "CLOSEST"):
            raise EnvironmentMapError(f"environment {self.name!r}: unknown interpolation {self.interpolation!r}")
        px = np.ascontiguousarray(px, dtype=np.float32)
        bad = ~(np.isfinite(px) & (px >= 0))
        count = int(np.count_nonzero(bad))
        if count:
            px = px.copy() if px is self.pixels else px
            px[bad] = 0.0
            warnings.append(f"environment {self.name!r}: {count} texel channel value(s) NaN, infinite or negative "
                            "clamped to 0")
        self.pixels = px
        m = np.asarray(self.matrix, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise EnvironmentMapError(f"environment {self.name!r}: matrix must be a finite 3x3, got {m.shape}")
        self.matrix = m
        s = np.broadcast_to(np.asarray(self.strength, dtype=np.float64).reshape(-1), (3,)).copy()
        if not np.all(np.isfinite(s)):
            raise EnvironmentMapError(f"environment {self.name!r}: strength {s.tolist()} is not finite")
        self.strength = np.maximum(s, 0.0)
        self.map_resolution = max(int(self.map_resolution), 0)

    @property
    def nbytes(self) -> int:
        """Bytes the render holds for it: the map and the importance tables (func and the column cdfs, float64)."""
        w, h = self.importance_resolution
        return int(np.asarray(self.pixels).nbytes) + 2 * 8 * w * h

    @property
    def importance_resolution(self) -> tuple[int, int]:
        """(width, height) of the importance grid: Map Resolution x half of it, or Auto: the image's size (both
        capped at MAX_IMPORTANCE_WIDTH x half)."""
        h, w = np.asarray(self.pixels).shape[:2]
        if self.map_resolution > 0:
            w, h = self.map_resolution, max(self.map_resolution // 2, 1)
        if w > MAX_IMPORTANCE_WIDTH:
            h = max(int(round(h * MAX_IMPORTANCE_WIDTH / w)), 1)
            w = MAX_IMPORTANCE_WIDTH
        return max(int(w), 1), max(int(h), 1)


class EnvironmentDistribution:
    """The kernel tables of a map world: `tables` = (pix, par, func, marg, cond) (see core.world_kernels), and
    `mean_luminance`, the luminance of the world averaged over the sphere (estimated on the grid), for the light
    selection's power. `sample`, `pdf` and `radiance` are the batch forms (float64), for tests and tools."""

    def __init__(self, env: EnvironmentMap | None, threads: int = 1):
        """threads: how many threads fill the importance grid (rows split between them; the same values)."""
        if env is None:
            self.tables = empty_tables()
            self.mean_luminance = 0.0
            return
        par = np.zeros(_kernels().E_FIELDS)
        par[_kernels().E_M00:_kernels().E_M22 + 1] = np.asarray(env.matrix, np.float64).reshape(9)
        par[_kernels().E_SR:_kernels().E_SB + 1] = env.strength
        par[_kernels().E_MIRROR_BALL] = env.projection == "MIRROR_BALL"
        par[_kernels().E_CLOSEST] = env.interpolation == "CLOSEST"
        pix = np.ascontiguousarray(env.pixels, dtype=np.float32)
        w, h = env.importance_resolution
        lum = importance_luminance(pix, par, w, h, IMPORTANCE_SUBSAMPLES if w * h <= _SUBSAMPLED_CELLS else 1,
                                   threads)
        lum = np.where(np.isfinite(lum) & (lum > 0), lum, 0.0)
        cos_el = np.cos(math.pi * ((np.arange(h) + 0.5) / h - 0.5))
        weighted = lum * cos_el[:, None]
        self.mean_luminance = float(weighted.sum() / (cos_el.sum() * w))
        func = (lum + IMPORTANCE_FLOOR * self.mean_luminance) * cos_el[:, None] if self.mean_luminance > 0 else \
            np.broadcast_to(cos_el[:, None], (h, w)).copy()
        row_sum = func.sum(axis=1)
        cond = np.zeros((h, w + 1))
        cond[:, 1:] = np.cumsum(func, axis=1) / np.where(row_sum > 0, row_sum, 1.0)[:, None]
        cond[:, -1] = 1.0
        marg = np.zeros(h + 1)
        marg[1:] = np.cumsum(row_sum) / row_sum.sum()
        marg[-1] = 1.0
        func = func * (w * h / func.sum())  # density over the (u, v) square: mean 1
        self.tables = (pix, par, np.ascontiguousarray(func), marg, np.ascontiguousarray(cond))

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Directions (N, 3) and their solid-angle pdfs (N,) from uniform numbers u (N, 2) in [0, 1)."""
        u = np.ascontiguousarray(np.asarray(u, np.float64).reshape(-1, 2))
        d, pdf = np.empty((u.shape[0], 3)), np.empty(u.shape[0])
        _, par, func, marg, cond = self.tables
        _kernels().sample_batch(par, func, marg, cond, u, d, pdf)
        return d, pdf

    def pdf(self, d: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (N,) of unit world directions d (N, 3)."""
        d = np.ascontiguousarray(np.asarray(d, np.float64).reshape(-1, 3))
        out = np.empty(d.shape[0])
        _kernels().pdf_batch(self.tables[2], d, out)
        return out

    def radiance(self, d: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) of the world in directions d (N, 3)."""
        d = np.ascontiguousarray(np.asarray(d, np.float64).reshape(-1, 3))
        out = np.empty((d.shape[0], 3))
        _kernels().radiance_batch(self.tables[0], self.tables[1], d, out)
        return out


def importance_luminance(pix: np.ndarray, par: np.ndarray, w: int, h: int, k: int, threads: int = 1) -> np.ndarray:
    """(h, w) float64: core.world_kernels.importance_grid over the whole grid, its rows shared by up to `threads`
    threads (this one included; at least GRID_ROWS_PER_THREAD rows each). A render's world map is filled before
    its first batch, while the other cores have nothing to do: 0.20-0.27 s on one core for a 1024 x 512 grid at
    2 x 2 lookups a cell."""
    lum = np.empty((h, w))
    parts = max(1, min(int(threads), h // GRID_ROWS_PER_THREAD))
    bounds = [h * p // parts for p in range(parts + 1)]
    if parts == 1:
        _kernels().importance_grid(pix, par, w, h, k, 0, lum)
        return lum
    from concurrent.futures import ThreadPoolExecutor  # (core.scene imports this module: kept off its imports)

    with ThreadPoolExecutor(parts - 1) as pool:
        jobs = [pool.submit(_kernels().importance_grid, pix, par, w, h, k, lo, lum[lo:hi])
                for lo, hi in zip(bounds[1:-1], bounds[2:])]
        _kernels().importance_grid(pix, par, w, h, k, 0, lum[:bounds[1]])
        for job in jobs:
            job.result()
    return lum


def environment_radiance(env: EnvironmentMap, d: np.ndarray) -> np.ndarray:
    """Radiance (N, 3) float32 of the map `env` (its matrix, projection, interpolation and strength) in unit world
    directions d (N, 3): the lookup alone, no importance tables (the world's camera-only backdrop)."""
    par = np.zeros(_kernels().E_FIELDS)
    par[_kernels().E_M00:_kernels().E_M22 + 1] = np.asarray(env.matrix, np.float64).reshape(9)
    par[_kernels().E_SR:_kernels().E_SB + 1] = env.strength
    par[_kernels().E_MIRROR_BALL] = env.projection == "MIRROR_BALL"
    par[_kernels().E_CLOSEST] = env.interpolation == "CLOSEST"
    d = np.ascontiguousarray(np.asarray(d, np.float64).reshape(-1, 3))
    out = np.empty((d.shape[0], 3))
    _kernels().radiance_batch(np.ascontiguousarray(env.pixels, np.float32), par, d, out)
    return out.astype(np.float32)


def empty_tables() -> tuple:
    """The kernel tables of a world without a map (same types, so the kernels compile once)."""
    return (np.zeros((1, 1, 3), np.float32), np.zeros(_kernels().E_FIELDS), np.ones((1, 1)), np.array([0.0, 1.0]),
            np.array([[0.0, 1.0]]))


def portal_table(portals: np.ndarray | None, shift: np.ndarray) -> np.ndarray:
    """The kernels' table of light portals (core.world_kernels' P_* columns) from core.scene.World.portals,
    positions made relative to the integrator's `shift`: (P, P_FIELDS) float64, (0, P_FIELDS) when none."""
    if portals is None or len(portals) == 0:
        return np.zeros((0, _kernels().P_FIELDS))
    portals = np.asarray(portals, dtype=np.float64)
    u, v = portals[:, 1], portals[:, 2]
    table = np.zeros((len(portals), _kernels().P_FIELDS))
    table[:, _kernels().P_CX:_kernels().P_CX + 3] = portals[:, 0] - 0.5 * (u + v) - np.asarray(shift, np.float64).reshape(3)
    table[:, _kernels().P_UX:_kernels().P_UX + 3] = u
    table[:, _kernels().P_VX:_kernels().P_VX + 3] = v
    n = portals[:, 3] / np.linalg.norm(portals[:, 3], axis=1, keepdims=True)
    table[:, _kernels().P_NX:_kernels().P_NX + 3] = n
    uu, vv, uv = (u * u).sum(axis=1), (v * v).sum(axis=1), (u * v).sum(axis=1)
    table[:, _kernels().P_AREA] = np.linalg.norm(np.cross(u, v), axis=1)
    det = uu * vv - uv * uv
    table[:, _kernels().P_G00], table[:, _kernels().P_G01], table[:, _kernels().P_G11] = vv / det, -uv / det, uu / det  # Gram inverse
    return np.ascontiguousarray(table)
