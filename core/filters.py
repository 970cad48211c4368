"""Pixel reconstruction filters, importance-sampled the way Cycles does it.

Cycles never weights film samples by the filter: each camera sample belongs to exactly one
pixel, and its film position is offset from the pixel centre by an amount drawn from the
filter's normalised 1-D profile, independently in x and y, with weight 1
(``camera_sample()`` in ``intern/cycles/kernel/camera/camera.h`` adds
``lookup_table_read(filter_u)`` to the pixel's corner).  The resulting image is the
(separable) filter convolved with the radiance, normalised per pixel.

Width conventions, read from ``intern/cycles/scene/film.cpp`` (``filter_func_box``,
``filter_func_gaussian``, ``filter_func_blackman_harris``, ``filter_table``) where the
table spans ``x`` in ``[0, width_eff / 2]`` and is mirrored:

* ``box``: ``width_eff = width``; uniform on ``[-width/2, +width/2]``.
* ``gaussian``: ``width_eff = 3 * width`` and ``f(x) = exp(-2 (x * 6 / width_eff)^2)``
  ``= exp(-8 x^2 / width^2)``, i.e. a Gaussian with sigma = ``width / 4``, truncated at
  ``+-1.5 * width`` (= +-6 sigma).
* ``blackman-harris``: ``width_eff = 2 * width``; the 4-term Blackman-Harris window
  (0.35875, 0.48829, 0.14128, 0.01168) spanning ``[-width, +width]``, peak at 0.
* ``tent`` (not in Cycles): triangle ``1 - |x| / width`` on ``[-width, +width]``, the same
  "width = half-span" convention as Cycles' Blackman-Harris.

Cycles tabulates the inverse CDF in 1024 entries (``FILTER_TABLE_SIZE``) read with linear
interpolation; we build a finer table (box and tent use exact closed forms), so the
sample density equals the filter to within the table's resolution.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PixelFilter", "FILTER_KINDS"]

F32 = NDArray[np.float32]

FILTER_KINDS: tuple[str, ...] = ("box", "tent", "gaussian", "blackman-harris")
_ALIASES = {"triangle": "tent", "blackman_harris": "blackman-harris", "blackmanharris": "blackman-harris"}
_BH = (0.35875, 0.48829, 0.14128, 0.01168)
_RADIUS_PER_WIDTH = {"box": 0.5, "tent": 1.0, "gaussian": 1.5, "blackman-harris": 1.0}  # support half-extent / width

_CDF_CELLS = 1 << 14  # x-grid cells for the CDF (Simpson per cell)
_INV_CELLS = 1 << 16  # uniform-u inverse table entries (lerped), cf. Cycles' 1024
# The outermost u-cells ([0, 2**-16) and [1 - 2**-16, 1)) hold the filter's long tails;
# each gets its own 256-cell table, which exhausts float32 u's 24 bits of resolution.
_TAIL_CELLS = 1 << 8
_CHUNK = 1 << 16  # samples per vectorised pass (keeps temporaries in cache)


def _largest_f32_at_most(x: float) -> np.float32:
    r = np.float32(x)
    return np.nextafter(r, np.float32(0)) if float(r) > x else r


def _lerp(table: F32, i: NDArray[np.intp], frac: F32) -> F32:
    a = np.take(table, i, mode="clip")
    b = np.take(table, i + 1, mode="clip")
    b -= a
    b *= frac
    b += a
    return b


def _profile(kind: str, width: float, radius: float, x: ArrayLike) -> NDArray[np.float64]:
    """The unnormalised profile of a filter of this kind and width (PixelFilter.evaluate)."""
    x = np.asarray(x, dtype=np.float64)
    w, r = width, radius
    inside = np.abs(x) <= r
    if kind == "box":
        f = np.ones_like(x)
    elif kind == "tent":
        f = 1.0 - np.abs(x) / w
    elif kind == "gaussian":
        f = np.exp(-8.0 * (x / w) ** 2)  # sigma = w / 4
    else:  # Cycles: v = 2 pi (x / width_eff + 1/2), width_eff = 2 w
        v = 2.0 * math.pi * (x / (2.0 * w) + 0.5)
        a0, a1, a2, a3 = _BH
        f = a0 - a1 * np.cos(v) + a2 * np.cos(2.0 * v) - a3 * np.cos(3.0 * v)
    return np.where(inside, f, 0.0)


class PixelFilter:
    """Separable pixel filter with Cycles' width conventions (see module docstring).

    Parameters
    ----------
    kind:
        "box", "tent" (alias "triangle"), "gaussian" or "blackman-harris" (case and
        ``_``/``-`` insensitive, so Blender's enum names such as "BLACKMAN_HARRIS" work).
    width:
        Blender's "Filter Width" / Cycles ``filter_width`` in pixels; must be > 0.

    Attributes
    ----------
    radius:
        Half-extent of the support in pixels: every offset satisfies ``|x| <= radius``.
    """

    def __init__(self, kind: str = "blackman-harris", width: float = 1.5) -> None:
        name = str(kind).strip().lower().replace(" ", "-")
        name = _ALIASES.get(name, name.replace("_", "-"))
        if name not in FILTER_KINDS:
            raise ValueError(f"unknown pixel filter type (filter_type) {kind!r}; expected one of {FILTER_KINDS}")
        try:
            w = float(width)
        except (TypeError, ValueError):
            raise ValueError(f"pixel filter width (filter_width) must be a number > 0, got {width!r}") from None
        if not (math.isfinite(w) and w > 0.0):
            raise ValueError(f"pixel filter width (filter_width) must be a finite number > 0 pixels, got {width!r}")
        self.kind: str = name
        self.width: float = w
        self.radius: float = _RADIUS_PER_WIDTH[name] * w
        self._r32 = _largest_f32_at_most(self.radius)
        self._norm = self._integral()
        self._inv: F32 | None = None
        self._tails: tuple[F32, F32] | None = None
        if name in ("gaussian", "blackman-harris"):
            self._build_inverse_tables()

    def __repr__(self) -> str:
        return f"PixelFilter(kind={self.kind!r}, width={self.width!r})"

    # -- profile -------------------------------------------------------------------------

    def evaluate(self, x: ArrayLike) -> NDArray[np.float64]:
        """Unnormalised filter profile ``f(x)`` (1 at the centre), 0 outside ``+-radius``."""
        return _profile(self.kind, self.width, self.radius, x)

    def _integral(self) -> float:
        w = self.width
        if self.kind == "box":
            return w
        if self.kind == "tent":
            return w
        if self.kind == "gaussian":
            sigma = 0.25 * w
            return sigma * math.sqrt(2.0 * math.pi) * math.erf(6.0 / math.sqrt(2.0))
        return _BH[0] * 2.0 * w  # cosine terms integrate to 0 over the full window

    def pdf_1d(self, x: ArrayLike) -> F32:
        """Normalised density of one offset coordinate: ``f(x) / integral(f)`` (float32)."""
        return (self.evaluate(x) / self._norm).astype(np.float32)

    def pdf(self, offsets: ArrayLike) -> F32:
        """Density of a 2-D offset (N, 2): the product of the two 1-D densities."""
        o = np.asarray(offsets, dtype=np.float64)
        return (self.pdf_1d(o[..., 0]) * self.pdf_1d(o[..., 1])).astype(np.float32)

    # -- sampling ------------------------------------------------------------------------

    def _build_inverse_tables(self) -> None:
        """The inverse CDF tables of this kind and width, built once per process (_inverse_tables): every render
        call makes its filter, and building them (~2 ms) would run on one thread before any path starts."""
        self._inv, low, high = _inverse_tables(self.kind, self.width)
        self._tails = (low, high)

    def sample_1d(self, u: ArrayLike) -> F32:
        """Offsets (float32, pixels from the pixel centre) for u in [0, 1), any shape."""
        uu = np.asarray(u, dtype=np.float32)
        flat = uu.reshape(-1)
        out = np.empty(flat.shape, dtype=np.float32)
        for a in range(0, flat.size, _CHUNK):  # cache-sized chunks; values are elementwise
            out[a : a + _CHUNK] = self._sample_chunk(flat[a : a + _CHUNK])
        return out.reshape(uu.shape)

    def _sample_chunk(self, uu: F32) -> F32:
        if self.kind == "box":
            x = uu - np.float32(0.5)
            x *= np.float32(self.width)
        elif self.kind == "tent":
            # inverse CDF of the triangle on [-w, w], mirrored about u = 1/2
            lo = uu < np.float32(0.5)
            v = np.where(lo, uu, np.float32(1) - uu)
            v *= np.float32(2)
            mag = np.float32(1) - np.sqrt(v, out=v)
            mag *= np.float32(self.width)
            x = np.where(lo, -mag, mag)
        else:
            t = uu * np.float32(_INV_CELLS)  # exact: power-of-two scaling
            i = t.astype(np.intp)
            np.minimum(i, _INV_CELLS - 1, out=i)
            x = _lerp(self._inv, i, t - i.astype(np.float32))
            assert self._tails is not None
            for cell, tail in ((0, self._tails[0]), (_INV_CELLS - 1, self._tails[1])):
                sel = np.flatnonzero(i == cell)
                if sel.size:
                    t2 = (t[sel] - np.float32(cell)) * np.float32(_TAIL_CELLS)
                    j = np.minimum(t2.astype(np.intp), _TAIL_CELLS - 1)
                    x[sel] = _lerp(tail, j, t2 - j.astype(np.float32))
        return np.clip(x, -self._r32, self._r32, out=x)

    def sample(self, u: ArrayLike) -> F32:
        """Film offsets (N, 2) float32 in pixels relative to the pixel centre.

        x and y are drawn independently from the 1-D profile with ``u[:, 0]`` and
        ``u[:, 1]`` (u in [0, 1)); weight 1.  The raster position is
        ``pixel_xy + 0.5 + offset``.
        """
        uu = np.asarray(u, dtype=np.float32)
        if uu.ndim != 2 or uu.shape[1] != 2:
            raise ValueError(f"expected u of shape (N, 2), got {uu.shape}")
        return self.sample_1d(uu)


@functools.lru_cache(maxsize=8)
def _inverse_tables(kind: str, width: float) -> tuple[F32, F32, F32]:
    """Inverse CDF on uniform grids of u, from a Simpson-integrated CDF on [-r, r]: the whole table and the tables
    of its first and last cells, read-only (shared by every PixelFilter of this kind and width)."""
    r = _RADIUS_PER_WIDTH[kind] * width
    r32 = _largest_f32_at_most(r)
    edges = np.linspace(-r, r, _CDF_CELLS + 1)
    mids = 0.5 * (edges[:-1] + edges[1:])
    fe, fm = _profile(kind, width, r, edges), _profile(kind, width, r, mids)
    mass = (fe[:-1] + 4.0 * fm + fe[1:]) * ((2.0 * r / _CDF_CELLS) / 6.0)
    cdf = np.concatenate([[0.0], np.cumsum(mass)])
    cdf /= cdf[-1]

    def table(u_lo: float, u_hi: float, cells: int) -> F32:
        inv = np.interp(np.linspace(u_lo, u_hi, cells + 1), cdf, edges)
        out = np.clip(inv, -r, r).astype(np.float32).clip(-r32, r32)
        out.flags.writeable = False
        return out

    du = 1.0 / _INV_CELLS
    return table(0.0, 1.0, _INV_CELLS), table(0.0, du, _TAIL_CELLS), table(1.0 - du, 1.0, _TAIL_CELLS)
