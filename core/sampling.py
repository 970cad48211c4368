"""Random numbers and samplers for the wavefront path tracer.

Everything here is vectorised over arrays of N paths and is a *pure function* of
``(seed, pixel index, sample index, dimension)``: the same inputs give the same bits
whatever the batch, tile order or thread count, and rendering more samples only appends
samples (sample ``i`` never changes when ``spp`` grows), so more samples refine the same image.

Conventions
-----------
* ``pixel`` and ``sample`` are integer arrays (any integer dtype; reduced mod 2**32 to
  ``uint32``) that broadcast against each other; outputs have their broadcast shape
  (at least 1-D), with a trailing axis of 2/3/4 for ``get_2d``/``get_3d``/``get_4d``.
* Every float output is ``float32`` in ``[0, 1)``: it is built from 24 integer bits as
  ``k * 2**-24`` with ``k < 2**24``, so it is exact and strictly below 1 after rounding.
* ``dim`` (a non-negative Python int) names a *dimension set*: one call's worth of 1-4
  correlated random numbers, like Cycles' ``PRNG_*`` ids.  Distinct ``dim`` ids give
  decorrelated streams.  Use each id with one arity only: ``get_1d(p, s, d)`` equals
  ``get_2d(p, s, d)[:, 0]`` for "independent" and "sobol" (not for "stratified").
  The integrator numbers them ``dim = base + bounce * stride``; any int works.
* Where the stratification lives (per ``dim`` id):

  - ``sobol``: ``get_2d`` gives Sobol dims (0, 1) -- every aligned block of ``2**k``
    consecutive samples of a pixel (in particular the first ``2**k``) is a (0, k, 2)-net;
    ``get_1d`` is Sobol dim 0 (1-D stratified at every power of two); ``get_3d``/``get_4d``
    add Sobol dims 2 and 3 (a 4-D Sobol point).  Beyond 4 components: use another ``dim``
    id (padding by a per-(pixel, dim) hash-shuffled sample index, as Burley 2020).
  - ``stratified``: in each aligned block of 4 consecutive samples ``4j .. 4j+3`` every one
    of the 2x2 strata of a ``get_2d`` pair (or the 4 strata of ``get_1d``) gets exactly one
    sample: sample ``i`` goes to stratum ``perm[i mod 4]`` with ``perm`` one of the 24
    permutations picked by a hash of (pixel, dim, block j); jitter inside the stratum is
    random.  ``get_3d``/``get_4d`` stratify components (0, 1) and (2, 3)/(2,) separately.
  - ``independent``: no structure; ``uniform(seed, pixel, sample, 4 * dim + c)`` for
    component ``c``.

Implementation: the samplers, :func:`uniform` and :func:`hash_u32` are compiled numba
kernels (``nogil``, cached on disk) over blocks of paths, written so that LLVM vectorises
them in uint32 arithmetic; they give exactly the bits of the former NumPy implementation
(pinned by tests), about 6x faster per path.  The warps that turn these numbers into
directions and points are in core.warps.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from functools import lru_cache
from itertools import permutations
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .jit_cache import jit as _jit

__all__ = [
    "uniform",
    "hash_u32",
    "Sampler",
    "IndependentSampler",
    "StratifiedSampler",
    "SobolSampler",
    "SAMPLER_KINDS",
    "DEFAULT_SAMPLER",
    "VARIANCE_GROUPS",
    "make_sampler",
    "sobol_matrices",
]

U32 = NDArray[np.uint32]
F32 = NDArray[np.float32]


# ---------------------------------------------------------------------------------------
# Integer hashing and bit tricks: compiled kernels
# ---------------------------------------------------------------------------------------

# Every sampler value is a short chain of uint32 operations per path (hash mixing, bit
# reversal, Owen scrambles, Sobol table lookups).  As NumPy that was ~100 elementwise
# passes per call, each streaming the arrays through memory again; here each kernel walks
# the paths in blocks of _BLOCK (scratch stays in L1) with one simple loop per stage, so
# LLVM vectorises the loops (8 uint32 lanes on AVX2), and releases the GIL (render worker
# threads run in parallel).
#
# Typing rule (numba): uint32 op uint32 computes in uint64 and uint64 op int64 -- a bare
# int literal included -- in float64.  So every constant is an np.uint32 and every
# expression is truncated back with _U(...): LLVM then narrows the arithmetic to i32,
# which AVX2 can vectorise (it has no 64-bit multiply), and the bits equal C uint32
# arithmetic.  Floats are converted from int32 (< 2**24), which also vectorises.
_U = np.uint32
_M32 = 0xFFFFFFFF
_S1, _S2, _S4, _S8, _S9, _S10 = (_U(k) for k in (1, 2, 4, 8, 9, 10))
_S15, _S16, _S22, _S23, _S24 = (_U(k) for k in (15, 16, 22, 23, 24))
_U0, _U1, _U3, _U24, _U255 = _U(0), _U(1), _U(3), _U(24), _U(255)
_INV_2_24 = np.float32(2.0**-24)
_BLOCK = 512

# Mixer: C. Wellons' "lowbias32" (xorshift-multiply, two rounds), a bijection on uint32
# with near-ideal avalanche.
_MIX_M1 = _U(0x7FEB352D)
_MIX_M2 = _U(0x846CA68B)


@_jit
def _mix32(h):
    """lowbias32 of a uint32 (bijective)."""
    h = _U(h ^ (h >> _S16))
    h = _U(h * _MIX_M1)
    h = _U(h ^ (h >> _S15))
    h = _U(h * _MIX_M2)
    return _U(h ^ (h >> _S16))


@_jit
def _reverse32(x):
    """Reverse the 32 bits of a uint32 (LLVM turns this into its bitreverse intrinsic)."""
    x = _U(((x >> _S1) & _U(0x55555555)) | _U((x & _U(0x55555555)) << _S1))
    x = _U(((x >> _S2) & _U(0x33333333)) | _U((x & _U(0x33333333)) << _S2))
    x = _U(((x >> _S4) & _U(0x0F0F0F0F)) | _U((x & _U(0x0F0F0F0F)) << _S4))
    x = _U(((x >> _S8) & _U(0x00FF00FF)) | _U((x & _U(0x00FF00FF)) << _S8))
    return _U((x >> _S16) | _U((x & _U(0xFFFF)) << _S16))


# Nested uniform (Owen) scramble in the bit-reversed domain, after Burley 2020 /
# Vegdahl's improved Laine-Karras permutation: each output bit depends only on the same
# and lower bits, i.e. (reversed) on the same and more significant digits.
_OW1, _OW2, _OW3 = _U(0x3D20ADEA), _U(0x05526C56), _U(0x53A22864)


@_jit
def _owen_rev(x, seed):
    """Scramble uint32 ``x`` (bit-reversed domain) with the uint32 ``seed``."""
    x = _U(x ^ _U(x * _OW1))
    x = _U(x + seed)
    x = _U(x * ((seed >> _S16) | _U1))
    x = _U(x ^ _U(x * _OW2))
    return _U(x ^ _U(x * _OW3))


@_jit
def _unit_float(h):
    """Top 24 bits of uint32 ``h`` as float32 ``k * 2**-24`` in [0, 1 - 2**-24], exact."""
    return np.float32(np.int32(h >> _S8)) * _INV_2_24


@_jit
def _store_block(out, a, m, rows):
    """``out[a + k, c] = rows[c, k]`` for ``k < m``; one unrolled loop per width (vectorises)."""
    n = out.shape[1]
    o = out[a : a + m]
    if n == 4:
        r0, r1, r2, r3 = rows[0], rows[1], rows[2], rows[3]
        for k in range(m):
            o[k, 0] = r0[k]
            o[k, 1] = r1[k]
            o[k, 2] = r2[k]
            o[k, 3] = r3[k]
    elif n == 3:
        r0, r1, r2 = rows[0], rows[1], rows[2]
        for k in range(m):
            o[k, 0] = r0[k]
            o[k, 1] = r1[k]
            o[k, 2] = r2[k]
    elif n == 2:
        r0, r1 = rows[0], rows[1]
        for k in range(m):
            o[k, 0] = r0[k]
            o[k, 1] = r1[k]
    else:
        r0 = rows[0]
        for k in range(m):
            o[k, 0] = r0[k]


@_jit
def _to_float_kernel(h, out):
    for i in range(h.shape[0]):
        out[i] = _unit_float(h[i])


@_jit
def _fold_mix_kernel(h, a):
    """``h = mix(h xor a)`` elementwise, in place (one :func:`hash_u32` round)."""
    for i in range(h.shape[0]):
        h[i] = _mix32(_U(h[i] ^ a[i]))


def _mix_int(h: int) -> int:
    """:func:`_mix32` of a Python int (reduced mod 2**32), for scalar keys."""
    return int(_mix32(_U(int(h) & _M32)))


def _key(*values: int) -> int:
    """Fold arbitrary Python ints (64 bits each, negatives wrap) into one uint32 key."""
    h = 0x9E3779B9
    for v in values:
        v = int(v) & 0xFFFFFFFFFFFFFFFF
        h = _mix_int(h ^ (v & _M32))
        h = _mix_int((h + (v >> 32) + 0x632BE5AB) & _M32)
    return h


def _keys(values: list[int]) -> U32:
    return np.array(values, dtype=np.uint32)


def _as_u32(a: ArrayLike) -> U32:
    arr = np.asarray(a)
    if arr.dtype == np.uint32:
        return arr
    if arr.dtype.kind not in "iub" and arr.size:
        raise TypeError(f"pixel/sample indices must be integers, got dtype {arr.dtype}")
    return arr.astype(np.uint32)  # wraps mod 2**32, like C


def _flat_u32(*values: ArrayLike) -> tuple[tuple[int, ...], list[U32]]:
    """Broadcast integer arrays; return the shape and each as 1-D C-contiguous writeable uint32.

    That is the one array type the kernels are compiled for (a read-only array would be
    another numba type, compiled again), so read-only inputs are copied.  np.broadcast_to
    rather than np.broadcast_arrays: the latter's views warn when numba reads their flags.
    """
    arrs = [np.atleast_1d(_as_u32(v)) for v in values]
    shape = np.broadcast_shapes(*(a.shape for a in arrs))
    flat = []
    for a in arrs:
        a = np.ascontiguousarray((a if a.shape == shape else np.broadcast_to(a, shape)).reshape(-1))
        flat.append(a if a.flags.writeable else a.copy())
    return shape, flat


def hash_u32(*values: ArrayLike) -> U32:
    """Hash integer arrays (broadcast together, each reduced mod 2**32) to uint32.

    A general-purpose, well-avalanched combination for callers that need random integers
    (e.g. to pick a light).  Pure: the output depends only on the input values.
    """
    shape, flat = _flat_u32(*values)
    h = np.full(math.prod(shape), 0x9E3779B9, dtype=np.uint32)
    for a in flat:
        _fold_mix_kernel(h, a)
    return h.reshape(shape)


def _to_float(h: ArrayLike) -> F32:
    """Top 24 bits of uint32 ``h`` as float32 in [0, 1 - 2**-24], exact."""
    shape, (flat,) = _flat_u32(np.asarray(h, dtype=np.uint32))
    out = np.empty(flat.shape, dtype=np.float32)
    _to_float_kernel(flat, out)
    return out.reshape(shape)


# Domain tags so that the same (seed, dim) never yields the same key in two roles.
_TAG_UNIFORM = 0x55A1
_TAG_STRAT_PERM = 0x5EA7
_TAG_SOBOL_SET = 0x50B0
_TAG_SOBOL_DIM = 0x5C4A


# Per-path hash state shared by all components of one (seed, pixel, sample):
# ``ph = mix(pixel ^ seed_key)`` (bijective in pixel), ``g = mix(ph ^ sample)`` (bijective
# in sample for a fixed pixel); the bits for a scalar key are ``mix((g ^ key) + ph)`` --
# adding ``ph`` keeps two paths whose ``g`` collide different in every key.


@_jit
def _path_hash_block(p, s, a, m, seed_key, ph, g):
    for k in range(m):
        h = _mix32(_U(p[a + k] ^ seed_key))
        ph[k] = h
        g[k] = _mix32(_U(h ^ s[a + k]))


@_jit
def _path_bits(ph, g, key):
    return _mix32(_U(_U(g ^ key) + ph))


@_jit
def _hash_fill(p, s, seed_key, keys, out):
    """``out[i, c]`` = float of the path bits for ``keys[c]`` (uniform / independent)."""
    n = out.shape[1]
    ph, g = np.empty(_BLOCK, np.uint32), np.empty(_BLOCK, np.uint32)
    rows = np.empty((n, _BLOCK), np.float32)
    for a in range(0, p.shape[0], _BLOCK):
        m = min(_BLOCK, p.shape[0] - a)
        _path_hash_block(p, s, a, m, seed_key, ph, g)
        for c in range(n):
            key, row = keys[c], rows[c]
            for k in range(m):
                row[k] = _unit_float(_path_bits(ph[k], g[k], key))
        _store_block(out, a, m, rows)


def _run(fill, pixel: ArrayLike, sample: ArrayLike, n: int, *args) -> F32:
    """Broadcast ``pixel``/``sample``, run ``fill(p, s, *args, out)`` into out (paths, n)."""
    shape, (p, s) = _flat_u32(pixel, sample)
    out = np.empty((p.shape[0], n), dtype=np.float32)
    if p.shape[0]:
        fill(p, s, *args, out)
    return out.reshape(shape + (n,))


def uniform(seed: int, pixel: ArrayLike, sample: ArrayLike, dim: int) -> F32:
    """Counter-based hash RNG: float32 in [0, 1) from (seed, pixel, sample, dim).

    ``pixel`` and ``sample`` are uint32 arrays (broadcast); ``seed`` and ``dim`` are ints.
    Output values are ``k * 2**-24`` for a 24-bit integer ``k``, so strictly < 1.
    """
    keys = _keys([_key(seed, dim, _TAG_UNIFORM)])
    return _run(_hash_fill, pixel, sample, 1, _U(_key(seed)), keys)[..., 0]


# ---------------------------------------------------------------------------------------
# Samplers
# ---------------------------------------------------------------------------------------


class Sampler(ABC):
    """Common interface: ``get_1d/2d/3d/4d(pixel, sample, dim)`` -> float32 in [0, 1).

    ``spp`` is informational (validated, reported); values never depend on it, so a render
    with more samples extends, rather than replaces, a render with fewer.
    """

    kind: ClassVar[str] = ""
    # True when a pixel's samples are independent draws, so that s^2 / n estimates the variance of
    # their mean; otherwise the spread of the variance groups' means does (see variance_group).
    iid: ClassVar[bool] = False

    def __init__(self, seed: int = 0, spp: int = 1, groups: int = 1) -> None:
        if int(spp) < 1:
            raise ValueError(f"samples per pixel (spp) must be >= 1, got {spp!r}")
        groups = int(groups)
        if groups < 1 or groups > 256 or groups & (groups - 1):
            raise ValueError(f"variance groups must be a power of two in [1, 256], got {groups!r}")
        self.seed = int(seed)
        self.spp = int(spp)
        self.groups = groups
        self._group_bits = groups.bit_length() - 1
        self._seed_key = _U(_key(self.seed))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(seed={self.seed}, spp={self.spp}, groups={self.groups})"

    def variance_group(self, sample: ArrayLike) -> NDArray[np.int64]:
        """The variance group (0 .. groups - 1) of each sample index: the means of a pixel's groups are
        independent, identically distributed estimates of the pixel (up to their sample counts), so their
        spread estimates the error of the pixel's mean honestly even where the samples within a group are
        correlated (stratified, quasi-random). Default: ``i mod groups``."""
        return (np.asarray(sample).astype(np.int64) & (self.groups - 1)).astype(np.int64)

    @abstractmethod
    def _fill(self, p: U32, s: U32, dim: int, out: F32) -> None:
        """Write the ``out.shape[1]`` components of dimension set ``dim`` into ``out``.

        ``p``, ``s``: 1-D C-contiguous uint32, one entry per row of ``out`` (>= 1 row).
        """

    def get(self, pixel: ArrayLike, sample: ArrayLike, dim: int, n: int) -> F32:
        """``n`` (1-4) components of dimension set ``dim``: float32 of shape (..., n)."""
        if not 1 <= int(n) <= 4:
            raise ValueError(f"a dimension set has 1 to 4 components, got n={n}")
        d = int(dim)
        return _run(lambda p, s, out: self._fill(p, s, d, out), pixel, sample, int(n))

    def get_1d(self, pixel: ArrayLike, sample: ArrayLike, dim: int) -> F32:
        """One float32 per path, shape ``broadcast(pixel, sample).shape``."""
        return self.get(pixel, sample, dim, 1)[..., 0]

    def get_2d(self, pixel: ArrayLike, sample: ArrayLike, dim: int) -> F32:
        """A 2-D point per path, shape ``(..., 2)``; the stratified/Sobol 2-D structure."""
        return self.get(pixel, sample, dim, 2)

    def get_3d(self, pixel: ArrayLike, sample: ArrayLike, dim: int) -> F32:
        """A 3-D point per path, shape ``(..., 3)``."""
        return self.get(pixel, sample, dim, 3)

    def get_4d(self, pixel: ArrayLike, sample: ArrayLike, dim: int) -> F32:
        """A 4-D point per path, shape ``(..., 4)``."""
        return self.get(pixel, sample, dim, 4)


class IndependentSampler(Sampler):
    """Plain hash RNG: component ``c`` of set ``dim`` is ``uniform(seed, p, s, 4*dim + c)``.

    Samples are independent, so ``groups`` changes no value (the film uses s^2 / n)."""

    kind = "independent"
    iid = True

    def _fill(self, p: U32, s: U32, dim: int, out: F32) -> None:
        keys = _keys([_key(self.seed, 4 * dim + c, _TAG_UNIFORM) for c in range(out.shape[1])])
        _hash_fill(p, s, self._seed_key, keys, out)


# All 24 permutations of the 4 strata, flattened: PERM[4 * k + j].
_PERM4 = np.array(list(permutations(range(4))), dtype=np.uint32).ravel()


@_jit
def _stratified_fill(p, s, seed_key, perm_keys, jitter_keys, perm4, out):
    """See :class:`StratifiedSampler`: ``perm_keys[q // 2]`` per pair, ``jitter_keys[c]``."""
    n = out.shape[1]
    ph, g = np.empty(_BLOCK, np.uint32), np.empty(_BLOCK, np.uint32)
    hb = np.empty(_BLOCK, np.uint32)
    rows = np.empty((n, _BLOCK), np.float32)
    for a in range(0, p.shape[0], _BLOCK):
        m = min(_BLOCK, p.shape[0] - a)
        _path_hash_block(p, s, a, m, seed_key, ph, g)
        for k in range(m):
            hb[k] = _mix32(_U((s[a + k] >> _S2) ^ ph[k]))  # per (pixel, block of 4 samples)
        for q in range(0, n, 2):
            pkey, kx = perm_keys[q // 2], jitter_keys[q]
            rx = rows[q]
            if q + 1 < n:  # 2-D pair: quadrant + 23 jitter bits per axis
                ky, ry = jitter_keys[q + 1], rows[q + 1]
                for k in range(m):
                    # 24 * (top 24 bits) >> 24: uniform permutation index in [0, 24)
                    perm = _U(_U(_U(_mix32(_U(hb[k] ^ pkey)) >> _S8) * _U24) >> _S24)
                    stratum = perm4[_U(_U(perm << _S2) + (s[a + k] & _U3))]
                    jx = _U(_path_bits(ph[k], g[k], kx) >> _S9) | _U((stratum & _U1) << _S23)
                    jy = _U(_path_bits(ph[k], g[k], ky) >> _S9) | _U((stratum >> _S1) << _S23)
                    rx[k] = np.float32(np.int32(jx)) * _INV_2_24
                    ry[k] = np.float32(np.int32(jy)) * _INV_2_24
            else:  # lone 1-D component: quarter + 22 jitter bits
                for k in range(m):
                    perm = _U(_U(_U(_mix32(_U(hb[k] ^ pkey)) >> _S8) * _U24) >> _S24)
                    stratum = perm4[_U(_U(perm << _S2) + (s[a + k] & _U3))]
                    jx = _U(_path_bits(ph[k], g[k], kx) >> _S10) | _U(stratum << _S22)
                    rx[k] = np.float32(np.int32(jx)) * _INV_2_24
        _store_block(out, a, m, rows)


class StratifiedSampler(Sampler):
    """2x2 jittered strata per pixel, stratum order shuffled per (pixel, dim, block of 4).

    Sample ``i`` of a pixel falls in stratum ``perm[i mod 4]`` where ``perm`` is one of the
    24 orderings chosen by hashing (seed, pixel, dim, i // 4): every aligned run of 4
    samples covers the 4 strata once, and strata are decorrelated across dims and blocks.
    For ``get_2d`` the strata are the quadrants (stratum k -> x half ``k & 1``, y half
    ``k >> 1``); for ``get_1d`` they are the quarters [k/4, (k+1)/4).  The position inside
    a stratum is uniform random.
    """

    kind = "stratified"

    def variance_group(self, sample: ArrayLike) -> NDArray[np.int64]:
        """Group ``(i // 4) mod groups``: blocks of 4 are stratified together but drawn independently of
        other blocks, so groups of whole blocks have independent means; ``groups`` changes no value."""
        return ((np.asarray(sample).astype(np.int64) >> 2) & (self.groups - 1)).astype(np.int64)

    def _fill(self, p: U32, s: U32, dim: int, out: F32) -> None:
        n = out.shape[1]
        perm_keys = _keys([_key(self.seed, dim, q, _TAG_STRAT_PERM) for q in range(0, n, 2)])
        jitter_keys = _keys([_key(self.seed, 4 * dim + c, _TAG_UNIFORM) for c in range(n)])
        _stratified_fill(p, s, self._seed_key, perm_keys, jitter_keys, _PERM4, out)


# ---------------------------------------------------------------------------------------
# Sobol generator matrices (computed, not tabulated)
# ---------------------------------------------------------------------------------------

# Primitive polynomials and initial direction numbers (Joe & Kuo 2008, "new-joe-kuo-6"):
# (degree s, interior-coefficient bits a, initial m_1..m_s).  Dim 0 is van der Corput.
_SOBOL_INIT = [
    (1, 0, (1,)),  # x + 1
    (2, 1, (1, 3)),  # x^2 + x + 1
    (3, 1, (1, 3, 1)),  # x^3 + x + 1
]


@lru_cache(maxsize=None)
def sobol_matrices() -> NDArray[np.uint32]:
    """Direction numbers ``V[d, k]`` (uint32, MSB = first binary digit) of 4 Sobol dims.

    Sobol point ``d`` of index ``i`` is ``XOR_k (bit k of i) * V[d, k]`` / 2**32.
    """
    v = np.zeros((4, 32), dtype=np.uint32)
    v[0] = [1 << (31 - k) for k in range(32)]
    for d, (deg, a, m_init) in enumerate(_SOBOL_INIT, start=1):
        m = list(m_init)
        for k in range(deg, 32):
            new = m[k - deg] ^ (m[k - deg] << deg)
            for ell in range(1, deg):
                if (a >> (deg - 1 - ell)) & 1:
                    new ^= m[k - ell] << ell
            m.append(new)
        v[d] = [m[k] << (31 - k) for k in range(32)]
    return v


@lru_cache(maxsize=None)
def _sobol_tables() -> U32:
    """Byte lookup tables of Sobol dims 0..3 in the bit-reversed domain.

    ``T[d, j, b]``: byte ``j`` (bits ``8j .. 8j+7``) of the bit-reversed index ``ri`` holds
    natural index bits ``31-8j .. 24-8j``; the value is the XOR of the bit-reversed
    direction numbers of dim ``d`` that the set bits of ``b`` select.  16 KiB in all.
    """
    vr = np.array([[_reverse32(x) for x in row] for row in sobol_matrices()], dtype=np.uint32)
    tables = np.zeros((4, 4, 256), dtype=np.uint32)
    b = np.arange(256, dtype=np.uint32)
    for j in range(4):
        for t in range(8):
            sel = ((b >> np.uint32(t)) & np.uint32(1)).astype(bool)
            tables[:, j, sel] ^= vr[:, 31 - 8 * j - t, None]
    return tables


@_jit
def _sobol_fill(p, s, seed_key, set_key, dim_keys, tables, group_bits, out):
    """See :class:`SobolSampler`: ``set_key`` per (seed, dim set), ``dim_keys[d]`` per Sobol dim;
    ``2**group_bits`` independently scrambled groups (sample ``i`` is point ``i >> group_bits`` of
    group ``i & (2**group_bits - 1)``)."""
    n = out.shape[1]
    h, ri, lane = np.empty(_BLOCK, np.uint32), np.empty(_BLOCK, np.uint32), np.empty(_BLOCK, np.uint32)
    rows = np.empty((n, _BLOCK), np.float32)
    gb = _U(group_bits)
    gmask = _U(_U(_U1 << gb) - _U1)
    for a in range(0, p.shape[0], _BLOCK):
        m = min(_BLOCK, p.shape[0] - a)
        s_or = _U0
        for k in range(m):
            s_or = _U(s_or | _U(s[a + k] >> gb))
        for k in range(m):
            hk = _mix32(_U(_mix32(_U(p[a + k] ^ seed_key)) ^ set_key))  # per (seed, pixel, dim set)
            grp = _U(s[a + k] & gmask)
            # group 0 keeps the ungrouped scramble; others get their own (independent) one
            hk = hk if grp == _U0 else _mix32(_U(hk ^ _U(grp * _U(0x9E3779B9))))
            h[k] = hk
            # bit-reversed shuffled index owen(i) xor owen(0): natural value < 2**bitlen(i),
            # so bytes 0-1 (0-2) of ri are zero when every index of the block is < 2**16 (2**8)
            ri[k] = _U(_owen_rev(_reverse32(_U(s[a + k] >> gb)), hk) ^ _owen_rev(_U0, hk))
        for d in range(n):
            t0, t1, t2, t3 = tables[d, 0], tables[d, 1], tables[d, 2], tables[d, 3]
            if s_or < _U(1 << 8):
                for k in range(m):
                    lane[k] = t3[ri[k] >> _S24]
            elif s_or < _U(1 << 16):
                for k in range(m):
                    lane[k] = _U(t2[(ri[k] >> _S16) & _U255] ^ t3[ri[k] >> _S24])
            else:
                for k in range(m):
                    r = ri[k]
                    lane[k] = _U(t0[r & _U255] ^ t1[(r >> _S8) & _U255] ^ t2[(r >> _S16) & _U255] ^ t3[r >> _S24])
            dkey, row = dim_keys[d], rows[d]
            for k in range(m):
                row[k] = _unit_float(_reverse32(_owen_rev(lane[k], _mix32(_U(h[k] ^ dkey)))))
        _store_block(out, a, m, rows)


class SobolSampler(Sampler):
    """Owen-scrambled 4-D Sobol (Burley 2020, Cycles' "Sobol-Burley"), the default.

    For dimension set ``dim`` and pixel ``p`` a seed ``h = H(seed, p, dim)`` drives

    1. a hash shuffle of the sample index: ``i' = owen(i) xor owen(0)`` -- a nested
       uniform scramble of the index bits that maps ``[0, 2**k)`` onto itself for every k
       (so the first ``2**k`` samples use exactly the first ``2**k`` Sobol points, and
       rendering more samples never changes earlier ones), decorrelating dimension sets
       (padding beyond 4 dims);
    2. Sobol dims 0..3 of index ``i'`` (dim 0 van der Corput, then the Joe-Kuo
       polynomials x+1, x^2+x+1, x^3+x+1), evaluated by byte-table lookups in the
       bit-reversed domain (one lookup per dim while the indices are < 256);
    3. an independent nested uniform scramble of each output dim.

    All three run in one compiled kernel (:func:`_sobol_fill`).

    With ``groups = G > 1`` (randomised QMC with G replicates) sample ``i`` of a pixel is point
    ``i // G`` of group ``i mod G``, and each group has its own seed ``h`` (group 0 keeps the
    ungrouped one): G independent Owen-scrambled sequences, whose means are independent estimates
    of the pixel. Everything said above about the first ``2**k`` samples then holds per group.
    """

    kind = "sobol"

    def __init__(self, seed: int = 0, spp: int = 1, groups: int = 1) -> None:
        super().__init__(seed, spp, groups)
        self._dim_keys = _keys([_key(d, _TAG_SOBOL_DIM) for d in range(4)])

    def _fill(self, p: U32, s: U32, dim: int, out: F32) -> None:
        set_key = _U(_key(self.seed, dim, _TAG_SOBOL_SET))
        _sobol_fill(p, s, self._seed_key, set_key, self._dim_keys, _sobol_tables(), self._group_bits, out)


SAMPLER_KINDS: tuple[str, ...] = ("independent", "stratified", "sobol")
# Variance groups a render uses (see Sampler.variance_group and core.film): the fewest that still give an unbiased
# estimate of each pixel's error (the spread of independent group means; 1 degree of freedom per pixel, as Cycles'
# own estimate from two halves of the samples), so that the image stays as close as it can to one Owen-scrambled
# Sobol sequence per pixel. Splitting Sobol into G independently scrambled sequences costs the single scramble's
# quality: on a 16x16 Cornell box the mean pixel variance rose 1.14x (2 groups), 1.29x (4), 2.5x (8) at 16 spp;
# on the `instances` bench scene (256x256, against one scramble) 1.18x / 1.14x of Cycles' with 2 groups at
# 16 / 64 spp, 1.43x / 1.32x with the 4 groups used before (docs/performance.md, "The instances scene: the variance groups").
VARIANCE_GROUPS = 2
DEFAULT_SAMPLER = "sobol"
_SAMPLERS: dict[str, type[Sampler]] = {
    "independent": IndependentSampler,
    "stratified": StratifiedSampler,
    "sobol": SobolSampler,
}


def make_sampler(kind: str = DEFAULT_SAMPLER, seed: int = 0, spp: int = 1, groups: int = 1) -> Sampler:
    """Create a sampler by name: "independent", "stratified" or "sobol" (default).

    ``groups``: variance groups (a power of two; see :meth:`Sampler.variance_group`). For "sobol" each
    group is an independently scrambled sequence (sample ``i`` is point ``i // groups`` of group
    ``i mod groups``), so it changes the values; groups=1 is the single scramble. The other kinds'
    values do not depend on it.
    Accepts Cycles-style aliases "sobol_burley"/"sobol-burley" and "random" for independent.
    Raises ValueError for an unknown kind, ``spp < 1`` or bad ``groups``.
    """
    name = str(kind).strip().lower().replace("_", "-")
    name = {"sobol-burley": "sobol", "random": "independent"}.get(name, name)
    if name not in _SAMPLERS:
        raise ValueError(f"unknown sampler kind (sampling pattern) {kind!r}; expected one of {SAMPLER_KINDS}")
    return _SAMPLERS[name](seed=seed, spp=spp, groups=groups)

