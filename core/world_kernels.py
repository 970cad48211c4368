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

# Light portals (core.world.portal_table): a corner, the two edges, the unit normal towards the inside, the area,
# and the inverse of the edges' Gram matrix (a point's edge coordinates from its dot products with the edges).
(P_CX, P_CY, P_CZ, P_UX, P_UY, P_UZ, P_VX, P_VY, P_VZ, P_NX, P_NY, P_NZ, P_AREA, P_G00, P_G01, P_G11) = range(16)
P_FIELDS = 16
# Share of a world light sample that goes through the portals when a shading point is inside some (the rest
# follows the map, or the cosine about n for a uniform world), as Cycles splits its background samples.
PORTAL_SHARE = 0.5
_BELOW_ONE = 0.9999999403953552  # the largest float32 below 1

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
def importance_grid(pix, par, Wr, Hr, k, row0, out):
    """out (rows, Wr): rows row0 .. row0 + rows of the luminance of the map world averaged over k x k points spread
    evenly inside each cell of an equirectangular grid of Hr x Wr cells over world directions (row 0 at the
    bottom); k = 1 is Cycles' background map (the cell centre). Each cell depends on nothing else, so threads may
    fill disjoint rows at once (the kernel releases the GIL)."""
    inv = 1.0 / (k * k)
    for row in range(out.shape[0]):
        i = row0 + row
        for j in range(Wr):
            acc = 0.0
            for a in range(k):
                v = (i + (a + 0.5) / k) / Hr
                for b in range(k):
                    x, y, z, _ = equirect_direction((j + (b + 0.5) / k) / Wr, v)
                    r, g, bb = env_radiance(pix, par, x, y, z)
                    acc += 0.2126 * r + 0.7152 * g + 0.0722 * bb
            out[row, j] = acc * inv


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


@_inline
def _inside_portal(portals, i, px, py, pz):
    return ((px - portals[i, P_CX]) * portals[i, P_NX] + (py - portals[i, P_CY]) * portals[i, P_NY]
            + (pz - portals[i, P_CZ]) * portals[i, P_NZ]) > 0.0


@_inline
def portals_facing(portals, px, py, pz):
    """How many portals have p on their inner side (0: the world is sampled without them at p)."""
    count = 0
    for i in range(portals.shape[0]):
        if _inside_portal(portals, i, px, py, pz):
            count += 1
    return count


@_inline
def portal_direction(portals, count, px, py, pz, u0, u1):
    """A unit direction from p towards a point uniform (by area) on one of the `count` portals facing p, each
    picked with probability 1 / count (u0 picks it and, rescaled, places the point with u1)."""
    x = u0 * count
    pick = min(int(x), count - 1)
    s = min(x - pick, _BELOW_ONE)
    seen = 0
    for i in range(portals.shape[0]):
        if not _inside_portal(portals, i, px, py, pz):
            continue
        if seen == pick:
            qx = portals[i, P_CX] + s * portals[i, P_UX] + u1 * portals[i, P_VX] - px
            qy = portals[i, P_CY] + s * portals[i, P_UY] + u1 * portals[i, P_VY] - py
            qz = portals[i, P_CZ] + s * portals[i, P_UZ] + u1 * portals[i, P_VZ] - pz
            length = math.sqrt(qx * qx + qy * qy + qz * qz)
            if length > 0.0:
                return qx / length, qy / length, qz / length
            return 0.0, 0.0, 1.0
        seen += 1
    return 0.0, 0.0, 1.0


@_inline
def portal_pdf(portals, count, px, py, pz, dx, dy, dz):
    """The solid-angle pdf of portal_direction at p (count portals facing it) in unit direction d: the mean over
    the facing portals of dist^2 / (|cos| area) for each one the ray from p along d passes through."""
    total = 0.0
    for i in range(portals.shape[0]):
        if not _inside_portal(portals, i, px, py, pz):
            continue
        dn = dx * portals[i, P_NX] + dy * portals[i, P_NY] + dz * portals[i, P_NZ]
        if dn >= 0.0:
            continue  # away from the portal's plane
        t = ((portals[i, P_CX] - px) * portals[i, P_NX] + (portals[i, P_CY] - py) * portals[i, P_NY]
             + (portals[i, P_CZ] - pz) * portals[i, P_NZ]) / dn
        hx, hy, hz = px + t * dx - portals[i, P_CX], py + t * dy - portals[i, P_CY], pz + t * dz - portals[i, P_CZ]
        hu = hx * portals[i, P_UX] + hy * portals[i, P_UY] + hz * portals[i, P_UZ]
        hv = hx * portals[i, P_VX] + hy * portals[i, P_VY] + hz * portals[i, P_VZ]
        a = portals[i, P_G00] * hu + portals[i, P_G01] * hv
        b = portals[i, P_G01] * hu + portals[i, P_G11] * hv
        if 0.0 <= a <= 1.0 and 0.0 <= b <= 1.0:
            total += t * t / (-dn * portals[i, P_AREA])
    return total / count


@_jit
def portal_sample_batch(portals, p, u, d, pdf):
    """portal_direction and portal_pdf for each point p (N, 3) with numbers u (N, 2): d (N, 3), pdf (N,) (pdf 0
    and d (0, 0, 1) where no portal faces the point). For tests."""
    for k in range(p.shape[0]):
        count = portals_facing(portals, p[k, 0], p[k, 1], p[k, 2])
        if count == 0:
            d[k, 0], d[k, 1], d[k, 2], pdf[k] = 0.0, 0.0, 1.0, 0.0
            continue
        x, y, z = portal_direction(portals, count, p[k, 0], p[k, 1], p[k, 2], u[k, 0], u[k, 1])
        d[k, 0], d[k, 1], d[k, 2] = x, y, z
        pdf[k] = portal_pdf(portals, count, p[k, 0], p[k, 1], p[k, 2], x, y, z)
