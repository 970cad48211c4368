"""Compiled (numba) kernels of the environment-map world: the map's radiance in a direction (Cycles' Environment
Texture through a Mapping node) and the importance sampling of directions by its 2D distribution.

Conventions (Cycles'): world directions are unit (x, y, z) with z up. The lookup vector is m = M d (M the Mapping
node's linear part, 3x3 row-major in `par`); an equirectangular map reads u = 0.5 - atan2(m.y, m.x) / (2 pi),
v = 0.5 + asin(m.z / |m|) / pi (v = 0 at the bottom row); a mirror ball reads the point of a ball seen from -y
that reflects m. The map `pix` is (H, W, 3) float32 with row 0 at the TOP (core.texture's convention), wrapped in
both axes (Repeat) for Linear (bilinear, texel centres at (i + 0.5) / W) and Closest.

The importance distribution lives on an equirectangular grid over WORLD directions (after the Mapping node, as
Cycles evaluates the whole background shader into its map): `func` (Hr, Wr) float64 holds the piecewise-constant
density in (u, v) (mean 1 over the grid), row 0 at v = 0 (the bottom, elevation -pi/2); `marg` (Hr + 1,) the cdf
over rows; `cond` (Hr, Wr + 1) each row's cdf over columns. The solid-angle pdf of a direction is
func / (2 pi^2 cos(elevation)).
"""

from __future__ import annotations

import math

import numpy as np

from .jit_cache import jit_inline as _inline
from .jit_cache import jit_no_nrt as _jit

# `par` columns: M (row-major 3x3), strength (r, g, b), mirror-ball projection (else equirectangular), Closest
# interpolation (else Linear)
(E_M00, E_M01, E_M02, E_M10, E_M11, E_M12, E_M20, E_M21, E_M22, E_SR, E_SG, E_SB, E_MIRROR_BALL,
 E_CLOSEST) = range(14)
E_FIELDS = 14

_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / (2.0 * math.pi)
_INV_PI = 1.0 / math.pi
_INV_2PI2 = 1.0 / (2.0 * math.pi * math.pi)


@_jit
def equirect_uv(x, y, z):
    """(u, v) in [0, 1] of the equirectangular parametrisation of a direction (need not be unit)."""
    u = 0.5 - math.atan2(y, x) * _INV_TWO_PI
    r = math.sqrt(x * x + y * y + z * z)
    if not r > 0.0:
        return 0.5, 0.5
    v = 0.5 + math.asin(min(max(z / r, -1.0), 1.0)) * _INV_PI
    return u, v


@_jit
def equirect_direction(u, v):
    """The unit direction at (u, v) of the equirectangular parametrisation, and cos(elevation)."""
    phi = math.pi - _TWO_PI * u
    el = math.pi * (v - 0.5)
    ce = math.cos(el)
    return ce * math.cos(phi), ce * math.sin(phi), math.sin(el), ce


@_jit
def mirror_ball_uv(x, y, z):
    """(u, v) of a mirror ball photographed from -y that reflects direction (x, y, z) (Cycles'
    direction_to_mirrorball)."""
    r = math.sqrt(x * x + y * y + z * z)
    if not r > 0.0:
        return 0.5, 0.5
    x, y, z = x / r, y / r - 1.0, z / r
    div = 2.0 * math.sqrt(max(-0.5 * y, 0.0))
    if div > 0.0:
        x, z = x / div, z / div
    return 0.5 * (x + 1.0), 0.5 * (z + 1.0)


@_inline
def _texel(pix, row_from_bottom, col):
    H = pix.shape[0]
    t = H - 1 - row_from_bottom
    return np.float64(pix[t, col, 0]), np.float64(pix[t, col, 1]), np.float64(pix[t, col, 2])


@_inline
def image_lookup(pix, u, v, closest):
    """The map at (u, v) (v = 0 at the bottom), Repeat extension; bilinear unless closest."""
    H, W = pix.shape[0], pix.shape[1]
    if closest:
        i = int(math.floor(u * W)) % W
        j = int(math.floor(v * H)) % H
        return _texel(pix, j, i)
    x = u * W - 0.5
    y = v * H - 0.5
    fx0 = math.floor(x)
    fy0 = math.floor(y)
    tx = x - fx0
    ty = y - fy0
    x0 = int(fx0) % W
    y0 = int(fy0) % H
    x1 = (x0 + 1) % W
    y1 = (y0 + 1) % H
    ar, ag, ab = _texel(pix, y0, x0)
    br, bg, bb = _texel(pix, y0, x1)
    cr, cg, cb = _texel(pix, y1, x0)
    dr, dg, db = _texel(pix, y1, x1)
    w00, w10, w01, w11 = (1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty
    return (w00 * ar + w10 * br + w01 * cr + w11 * dr, w00 * ag + w10 * bg + w01 * cg + w11 * dg,
            w00 * ab + w10 * bb + w01 * cb + w11 * db)


@_inline
def env_radiance(pix, par, dx, dy, dz):
    """Radiance (r, g, b) of the map world in world direction d (float64)."""
    mx = par[E_M00] * dx + par[E_M01] * dy + par[E_M02] * dz
    my = par[E_M10] * dx + par[E_M11] * dy + par[E_M12] * dz
    mz = par[E_M20] * dx + par[E_M21] * dy + par[E_M22] * dz
    if par[E_MIRROR_BALL] != 0.0:
        u, v = mirror_ball_uv(mx, my, mz)
    else:
        u, v = equirect_uv(mx, my, mz)
    r, g, b = image_lookup(pix, u, v, par[E_CLOSEST] != 0.0)
    return r * par[E_SR], g * par[E_SG], b * par[E_SB]


@_inline
def _find_interval(cdf, start, n, x):
    """The index i in [0, n) with cdf[start + i] <= x < cdf[start + i + 1] (binary search; cdf non-decreasing,
    cdf[start] = 0, cdf[start + n] = 1), skipping zero-width intervals."""
    lo, hi = 0, n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if cdf[start + mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo


@_inline
def env_sample(par, func, marg, cond, u0, u1):
    """A world direction by the map's distribution from uniform u0, u1 in [0, 1): (x, y, z, solid-angle pdf)."""
    Wr, Hr = func.shape[1], func.shape[0]
    i = _find_interval(marg, 0, Hr, u1)
    w = marg[i + 1] - marg[i]
    dv = (u1 - marg[i]) / w if w > 0.0 else 0.5
    row = cond[i]
    j = _find_interval(row, 0, Wr, u0)
    w = row[j + 1] - row[j]
    du = (u0 - row[j]) / w if w > 0.0 else 0.5
    u = (j + min(max(du, 0.0), 1.0)) / Wr
    v = (i + min(max(dv, 0.0), 1.0)) / Hr
    x, y, z, ce = equirect_direction(u, v)
    if not ce > 0.0:
        return x, y, z, 0.0
    return x, y, z, func[i, j] * _INV_2PI2 / ce


@_inline
def env_pdf(func, dx, dy, dz):
    """Solid-angle pdf with which env_sample produces unit world direction d."""
    Wr, Hr = func.shape[1], func.shape[0]
    u, v = equirect_uv(dx, dy, dz)
    j = min(max(int(u * Wr), 0), Wr - 1)
    i = min(max(int(v * Hr), 0), Hr - 1)
    ce = math.sqrt(max(dx * dx + dy * dy, 0.0))
    if not ce > 0.0:
        return 0.0
    return func[i, j] * _INV_2PI2 / ce


# ------------------------------------------------------------------------------- batch forms (tests, set-up)
@_jit
def radiance_batch(pix, par, d, out):
    """out[i] = env_radiance of direction d[i] ((N, 3) float64) into (N, 3) float64."""
    for k in range(d.shape[0]):
        r, g, b = env_radiance(pix, par, d[k, 0], d[k, 1], d[k, 2])
        out[k, 0], out[k, 1], out[k, 2] = r, g, b


@_jit
def importance_grid(pix, par, Wr, Hr, k, out):
    """out (Hr, Wr): luminance of the map world averaged over k x k points spread evenly inside each cell of an
    equirectangular grid over world directions (row 0 at the bottom); k = 1 is Cycles' background map (the cell
    centre)."""
    inv = 1.0 / (k * k)
    for i in range(Hr):
        for j in range(Wr):
            acc = 0.0
            for a in range(k):
                v = (i + (a + 0.5) / k) / Hr
                for b in range(k):
                    x, y, z, _ = equirect_direction((j + (b + 0.5) / k) / Wr, v)
                    r, g, bb = env_radiance(pix, par, x, y, z)
                    acc += 0.2126 * r + 0.7152 * g + 0.0722 * bb
            out[i, j] = acc * inv


@_jit
def sample_batch(par, func, marg, cond, u, d, pdf):
    """env_sample for every row of u ((N, 2) float64): d (N, 3), pdf (N,) float64."""
    for k in range(u.shape[0]):
        x, y, z, p = env_sample(par, func, marg, cond, u[k, 0], u[k, 1])
        d[k, 0], d[k, 1], d[k, 2] = x, y, z
        pdf[k] = p


@_jit
def pdf_batch(func, d, pdf):
    """env_pdf for every unit direction d[k] ((N, 3) float64) into pdf (N,)."""
    for k in range(d.shape[0]):
        pdf[k] = env_pdf(func, d[k, 0], d[k, 1], d[k, 2])
