"""Random numbers, samplers and sample warps for the wavefront path tracer.

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

Warps take ``u`` of shape (N, 2) in [0, 1) and return float32 points; every warp has a
matching ``pdf_*`` (solid angle for directions, area for disks, barycentric/area for
triangles).  Local shading frames have the normal along +z.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from functools import lru_cache
from itertools import permutations
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "uniform",
    "hash_u32",
    "Sampler",
    "IndependentSampler",
    "StratifiedSampler",
    "SobolSampler",
    "SAMPLER_KINDS",
    "DEFAULT_SAMPLER",
    "make_sampler",
    "sobol_matrices",
    "sample_cosine_hemisphere",
    "sample_cosine_hemisphere_concentric",
    "pdf_cosine_hemisphere",
    "sample_uniform_hemisphere",
    "pdf_uniform_hemisphere",
    "sample_uniform_sphere",
    "pdf_uniform_sphere",
    "sample_uniform_cone",
    "pdf_uniform_cone",
    "sample_concentric_disk",
    "pdf_concentric_disk",
    "sample_uniform_triangle",
    "pdf_uniform_triangle",
    "sample_sphere_cap",
    "pdf_sphere_cap",
    "build_onb",
    "to_local",
    "to_world",
]

U32 = NDArray[np.uint32]
F32 = NDArray[np.float32]

_M32 = 0xFFFFFFFF
_INV_2_24 = np.float32(2.0**-24)
_PI = np.float32(math.pi)
_TWO_PI = np.float32(2.0 * math.pi)
_INV_PI = np.float32(1.0 / math.pi)
_INV_2PI = np.float32(0.5 / math.pi)
_INV_4PI = np.float32(0.25 / math.pi)

# ---------------------------------------------------------------------------------------
# Integer hashing (uint32 only)
# ---------------------------------------------------------------------------------------

# Mixer: C. Wellons' "lowbias32" (xorshift-multiply, two rounds), a bijection on uint32
# with near-ideal avalanche.  Array and Python-int versions must agree bit for bit.
# Hot paths work in place with one scratch buffer: fresh 4 MB temporaries cost ~3x an
# in-place pass over the same data.
_MIX_M1 = 0x7FEB352D
_MIX_M2 = 0x846CA68B
_U1, _U16, _U15 = np.uint32(1), np.uint32(16), np.uint32(15)
_UM1, _UM2 = np.uint32(_MIX_M1), np.uint32(_MIX_M2)


def _mix(h: U32, tmp: U32 | None = None) -> U32:
    """Avalanche a *fresh* uint32 array in place and return it (bijective).

    ``tmp`` is an optional scratch array of the same shape (clobbered).
    """
    t = np.empty_like(h) if tmp is None else tmp
    np.right_shift(h, _U16, out=t)
    h ^= t
    h *= _UM1
    np.right_shift(h, _U15, out=t)
    h ^= t
    h *= _UM2
    np.right_shift(h, _U16, out=t)
    h ^= t
    return h


def _mix_int(h: int) -> int:
    """Python-int twin of :func:`_mix` (for scalar keys)."""
    h &= _M32
    h ^= h >> 16
    h = (h * _MIX_M1) & _M32
    h ^= h >> 15
    h = (h * _MIX_M2) & _M32
    h ^= h >> 16
    return h


def _key(*values: int) -> int:
    """Fold arbitrary Python ints (64 bits each, negatives wrap) into one uint32 key."""
    h = 0x9E3779B9
    for v in values:
        v = int(v) & 0xFFFFFFFFFFFFFFFF
        h = _mix_int(h ^ (v & _M32))
        h = _mix_int((h + (v >> 32) + 0x632BE5AB) & _M32)
    return h


def hash_u32(*values: ArrayLike) -> U32:
    """Hash integer arrays (broadcast together, each reduced mod 2**32) to uint32.

    A general-purpose, well-avalanched combination for callers that need random integers
    (e.g. to pick a light).  Pure: the output depends only on the input values.
    """
    arrs = np.broadcast_arrays(*[np.atleast_1d(_as_u32(v)) for v in values])
    h = np.full(arrs[0].shape, 0x9E3779B9, dtype=np.uint32)
    for a in arrs:
        h = _mix(h ^ a)
    return h


def _as_u32(a: ArrayLike) -> U32:
    arr = np.asarray(a)
    if arr.dtype == np.uint32:
        return arr
    if arr.dtype.kind not in "iub" and arr.size:
        raise TypeError(f"pixel/sample indices must be integers, got dtype {arr.dtype}")
    return arr.astype(np.uint32)  # wraps mod 2**32, like C


def _prep(pixel: ArrayLike, sample: ArrayLike) -> tuple[U32, U32]:
    p, s = np.broadcast_arrays(np.atleast_1d(_as_u32(pixel)), np.atleast_1d(_as_u32(sample)))
    return p, s


# Work is done in chunks of this many paths with preallocated scratch buffers reused
# across chunks, so the ~100 elementwise passes stay in cache and never page-fault on
# fresh temporaries (about 2x faster than whole-array NumPy expressions at 1M paths).
# Every result is elementwise, so chunking never changes a value.
_CHUNK = 1 << 16


class _Work:
    """Scratch buffers for one chunk: ``u`` uint32 arrays, ``i`` intp arrays, ``q`` uint64."""

    __slots__ = ("u", "i", "q")

    def __init__(self, m: int, n_u: int = 8, n_i: int = 2, n_q: int = 2) -> None:
        self.u = [np.empty(m, dtype=np.uint32) for _ in range(n_u)]
        self.i = [np.empty(m, dtype=np.intp) for _ in range(n_i)]
        self.q = [np.empty(m, dtype=np.uint64) for _ in range(n_q)]

    def head(self, m: int) -> "_Work":
        w = _Work.__new__(_Work)
        w.u = [a[:m] for a in self.u]
        w.i = [a[:m] for a in self.i]
        w.q = [a[:m] for a in self.q]
        return w


def _chunked(kernel, pixel: ArrayLike, sample: ArrayLike, n: int) -> F32:
    """Run ``kernel(p, s, out, work)`` chunkwise; it fills ``out`` (m, n). Returns (..., n)."""
    p, s = _prep(pixel, sample)
    shape = p.shape
    p, s = p.reshape(-1), s.reshape(-1)
    total = p.shape[0]
    out = np.empty((total, n), dtype=np.float32)
    work = _Work(min(total, _CHUNK))
    for a in range(0, total, _CHUNK):
        b = min(a + _CHUNK, total)
        kernel(p[a:b], s[a:b], out[a:b], work if b - a == _CHUNK else work.head(b - a))
    return out.reshape(shape + (n,))


def _write_float(h: U32, dst: F32) -> None:
    """``dst = top 24 bits of h * 2**-24``: float32 in [0, 1 - 2**-24], exact. Clobbers h."""
    h >>= np.uint32(8)
    np.copyto(dst, h, casting="unsafe")  # < 2**24: exact in float32
    dst *= _INV_2_24


def _to_float(h: U32) -> F32:
    """Top 24 bits of a *fresh* ``h`` (clobbered) as float32 in [0, 1 - 2**-24], exact."""
    f = np.empty(h.shape, dtype=np.float32)
    _write_float(h, f)
    return f


# Domain tags so that the same (seed, dim) never yields the same key in two roles.
_TAG_UNIFORM = 0x55A1
_TAG_STRAT_PERM = 0x5EA7
_TAG_SOBOL_SET = 0x50B0
_TAG_SOBOL_DIM = 0x5C4A


class _PathHash:
    """Per-path hash state shared by all dims of one (seed, pixel, sample) chunk.

    Uses ``work.u[0:3]`` (ph, g, scratch).
    """

    __slots__ = ("ph", "g", "tmp")

    def __init__(self, seed_key: int, pixel: U32, sample: U32, work: _Work) -> None:
        self.ph, self.g, self.tmp = work.u[0], work.u[1], work.u[2]
        np.bitwise_xor(pixel, np.uint32(seed_key), out=self.ph)
        _mix(self.ph, self.tmp)  # bijective in pixel
        np.bitwise_xor(self.ph, sample, out=self.g)
        _mix(self.g, self.tmp)  # bijective in sample for a fixed pixel

    def bits(self, key: int, out: U32) -> U32:
        """Well-mixed uint32 per path for the scalar ``key``, written to ``out``."""
        np.bitwise_xor(self.g, np.uint32(key), out=out)
        out += self.ph  # two paths whose `g` collide still differ in every key
        return _mix(out, self.tmp)


def uniform(seed: int, pixel: ArrayLike, sample: ArrayLike, dim: int) -> F32:
    """Counter-based hash RNG: float32 in [0, 1) from (seed, pixel, sample, dim).

    ``pixel`` and ``sample`` are uint32 arrays (broadcast); ``seed`` and ``dim`` are ints.
    Output values are ``k * 2**-24`` for a 24-bit integer ``k``, so strictly < 1.
    """
    seed_key, dim_key = _key(seed), _key(seed, dim, _TAG_UNIFORM)

    def kernel(p: U32, s: U32, out: F32, work: _Work) -> None:
        h = _PathHash(seed_key, p, s, work).bits(dim_key, work.u[3])
        _write_float(h, out[:, 0])

    return _chunked(kernel, pixel, sample, 1)[..., 0]


# ---------------------------------------------------------------------------------------
# Samplers
# ---------------------------------------------------------------------------------------


class Sampler(ABC):
    """Common interface: ``get_1d/2d/3d/4d(pixel, sample, dim)`` -> float32 in [0, 1).

    ``spp`` is informational (validated, reported); values never depend on it, so a render
    with more samples extends, rather than replaces, a render with fewer.
    """

    kind: ClassVar[str] = ""

    def __init__(self, seed: int = 0, spp: int = 1) -> None:
        if int(spp) < 1:
            raise ValueError(f"samples per pixel (spp) must be >= 1, got {spp!r}")
        self.seed = int(seed)
        self.spp = int(spp)
        self._seed_key = _key(self.seed)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(seed={self.seed}, spp={self.spp})"

    @abstractmethod
    def _fill(self, p: U32, s: U32, dim: int, out: F32, work: _Work) -> None:
        """Write the ``out.shape[1]`` components of dimension set ``dim`` into ``out``."""

    def get(self, pixel: ArrayLike, sample: ArrayLike, dim: int, n: int) -> F32:
        """``n`` (1-4) components of dimension set ``dim``: float32 of shape (..., n)."""
        if not 1 <= int(n) <= 4:
            raise ValueError(f"a dimension set has 1 to 4 components, got n={n}")
        d, k = int(dim), int(n)
        return _chunked(lambda p, s, out, work: self._fill(p, s, d, out, work), pixel, sample, k)

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
    """Plain hash RNG: component ``c`` of set ``dim`` is ``uniform(seed, p, s, 4*dim + c)``."""

    kind = "independent"

    def _fill(self, p: U32, s: U32, dim: int, out: F32, work: _Work) -> None:
        st = _PathHash(self._seed_key, p, s, work)
        for c in range(out.shape[1]):
            _write_float(st.bits(_key(self.seed, 4 * dim + c, _TAG_UNIFORM), work.u[3]), out[:, c])


# All 24 permutations of the 4 strata, flattened: PERM[4 * k + j].
_PERM4 = np.array(list(permutations(range(4))), dtype=np.uint32).ravel()


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

    def _fill(self, p: U32, s: U32, dim: int, out: F32, work: _Work) -> None:
        n = out.shape[1]
        st = _PathHash(self._seed_key, p, s, work)
        tmp = st.tmp
        hb, hp, jx, jy = work.u[3], work.u[4], work.u[5], work.u[6]
        lane, idx = work.i[0], work.i[1]
        np.right_shift(s, np.uint32(2), out=hb)
        hb ^= st.ph
        _mix(hb, tmp)  # per (pixel, block of 4 samples)
        np.bitwise_and(s, np.uint32(3), out=lane)
        for q in range(0, n, 2):
            np.bitwise_xor(hb, np.uint32(_key(self.seed, dim, q, _TAG_STRAT_PERM)), out=hp)
            _mix(hp, tmp)
            # 24 * (top 24 bits) >> 24: uniform permutation index in [0, 24)
            hp >>= np.uint32(8)
            hp *= np.uint32(24)
            hp >>= np.uint32(24)
            np.left_shift(hp, np.uint32(2), out=idx)
            idx += lane
            stratum = np.take(_PERM4, idx, mode="clip", out=hp)
            st.bits(_key(self.seed, 4 * dim + q, _TAG_UNIFORM), jx)
            if q + 1 < n:  # 2-D pair: quadrant + 23 jitter bits per axis
                st.bits(_key(self.seed, 4 * dim + q + 1, _TAG_UNIFORM), jy)
                jx >>= np.uint32(9)
                jy >>= np.uint32(9)
                np.bitwise_and(stratum, _U1, out=tmp)
                tmp <<= np.uint32(23)
                jx |= tmp
                stratum >>= _U1
                stratum <<= np.uint32(23)
                jy |= stratum
                for c, k in ((q, jx), (q + 1, jy)):
                    np.copyto(out[:, c], k, casting="unsafe")
                    out[:, c] *= _INV_2_24
            else:  # lone 1-D component: quarter + 22 jitter bits
                jx >>= np.uint32(10)
                stratum <<= np.uint32(22)
                jx |= stratum
                np.copyto(out[:, q], jx, casting="unsafe")
                out[:, q] *= _INV_2_24


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


_REV_STEPS = tuple(
    (np.uint32(sh), np.uint32(mask)) for sh, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F))
)


def _reverse_bits(x: U32, tmp: U32) -> U32:
    """Reverse the 32 bits of each element of ``x`` in place; returns ``x``."""
    for sh, mask in _REV_STEPS:  # swap bits, pairs, nibbles within each byte ...
        np.right_shift(x, sh, out=tmp)
        tmp &= mask
        x &= mask
        x <<= sh
        x |= tmp
    x.byteswap(inplace=True)  # ... then the bytes
    return x

def _reverse_int(x: int) -> int:
    return int(f"{x & _M32:032b}"[::-1], 2)


@lru_cache(maxsize=None)
def _sobol_tables() -> NDArray[np.uint64]:
    """Gather tables in the bit-reversed domain, two dims packed per uint64 lane.

    ``T[pair, chunk, b]``: chunk 0 takes the top 16 bits of the reversed index ``ri``
    (natural index bits 0..15), chunk 1 the low 16 bits (natural bits 16..31); the value
    is the XOR of the bit-reversed direction numbers of dims (2*pair, 2*pair + 1), packed
    as ``lo | hi << 32``.
    """
    v = sobol_matrices()
    vr = np.array([[_reverse_int(int(x)) for x in row] for row in v], dtype=np.uint64)
    b = np.arange(1 << 16, dtype=np.uint64)
    tables = np.zeros((2, 2, 1 << 16), dtype=np.uint64)
    for pair in range(2):
        packed = vr[2 * pair] | (vr[2 * pair + 1] << np.uint64(32))  # (32,)
        for chunk, nat_bit in ((0, lambda t: 15 - t), (1, lambda t: 31 - t)):
            acc = np.zeros(1 << 16, dtype=np.uint64)
            for t in range(16):
                sel = (b >> np.uint64(t)) & np.uint64(1)
                acc ^= sel * packed[nat_bit(t)]
            tables[pair, chunk] = acc
    return tables


# Nested uniform (Owen) scramble in the bit-reversed domain, after Burley 2020 /
# Vegdahl's improved Laine-Karras permutation: each output bit depends only on the same
# and lower bits, i.e. (reversed) on the same and more significant digits.
_OW1, _OW2, _OW3 = np.uint32(0x3D20ADEA), np.uint32(0x05526C56), np.uint32(0x53A22864)


def _owen_rev(x: U32, seed: U32, tmp: U32) -> U32:
    """Scramble ``x`` in place (bit-reversed domain) with per-path ``seed``; returns ``x``."""
    np.multiply(x, _OW1, out=tmp)
    x ^= tmp
    x += seed
    np.right_shift(seed, _U16, out=tmp)
    tmp |= _U1
    x *= tmp
    np.multiply(x, _OW2, out=tmp)
    x ^= tmp
    np.multiply(x, _OW3, out=tmp)
    x ^= tmp
    return x


def _owen_rev_zero(seed: U32, out: U32, tmp: U32) -> U32:
    """``_owen_rev(0, seed)`` into ``out``, without materialising zeros."""
    np.right_shift(seed, _U16, out=out)
    out |= _U1
    out *= seed
    np.multiply(out, _OW2, out=tmp)
    out ^= tmp
    np.multiply(out, _OW3, out=tmp)
    out ^= tmp
    return out

class SobolSampler(Sampler):
    """Owen-scrambled 4-D Sobol (Burley 2020, Cycles' "Sobol-Burley"), the default.

    For dimension set ``dim`` and pixel ``p`` a seed ``h = H(seed, p, dim)`` drives

    1. a hash shuffle of the sample index: ``i' = owen(i) xor owen(0)`` -- a nested
       uniform scramble of the index bits that maps ``[0, 2**k)`` onto itself for every k
       (so the first ``2**k`` samples use exactly the first ``2**k`` Sobol points, and
       rendering more samples never changes earlier ones), decorrelating dimension sets
       (padding beyond 4 dims);
    2. Sobol dims 0..3 of index ``i'`` (dim 0 van der Corput, then the Joe-Kuo
       polynomials x+1, x^2+x+1, x^3+x+1), evaluated by 16-bit table gathers;
    3. an independent nested uniform scramble of each output dim.
    """

    kind = "sobol"

    def _fill(self, p: U32, s: U32, dim: int, out: F32, work: _Work) -> None:
        n = out.shape[1]
        h, tmp, ri, r0, lane, sd = work.u[:6]
        i0, i1 = work.i
        x, x1 = work.q
        np.bitwise_xor(p, np.uint32(self._seed_key), out=h)
        _mix(h, tmp)
        h ^= np.uint32(_key(self.seed, dim, _TAG_SOBOL_SET))
        _mix(h, tmp)  # per (seed, pixel, dim set)
        np.copyto(ri, s)
        _owen_rev(_reverse_bits(ri, tmp), h, tmp)
        ri ^= _owen_rev_zero(h, r0, tmp)  # bit-reversed shuffled index; natural value < 2**bitlen(s)
        hi_chunk = bool(s.size) and int(s.max()) >= (1 << 16)
        if hi_chunk:
            np.bitwise_and(ri, np.uint32(0xFFFF), out=i1)
        np.right_shift(ri, _U16, out=i0)
        tables = _sobol_tables()
        for pair in range((n + 1) // 2):
            np.take(tables[pair, 0], i0, mode="clip", out=x)
            if hi_chunk:
                x ^= np.take(tables[pair, 1], i1, mode="clip", out=x1)
            for j in range(min(2, n - 2 * pair)):
                d = 2 * pair + j
                if j:
                    x >>= np.uint64(32)
                np.copyto(lane, x, casting="unsafe")  # low 32 bits: dim d (bit-reversed)
                np.bitwise_xor(h, np.uint32(_key(d, _TAG_SOBOL_DIM)), out=sd)
                _mix(sd, tmp)
                _owen_rev(lane, sd, tmp)
                _write_float(_reverse_bits(lane, tmp), out[:, d])


SAMPLER_KINDS: tuple[str, ...] = ("independent", "stratified", "sobol")
DEFAULT_SAMPLER = "sobol"
_SAMPLERS: dict[str, type[Sampler]] = {
    "independent": IndependentSampler,
    "stratified": StratifiedSampler,
    "sobol": SobolSampler,
}


def make_sampler(kind: str = DEFAULT_SAMPLER, seed: int = 0, spp: int = 1) -> Sampler:
    """Create a sampler by name: "independent", "stratified" or "sobol" (default).

    Accepts Cycles-style aliases "sobol_burley"/"sobol-burley" and "random" for independent.
    Raises ValueError for an unknown kind or ``spp < 1``.
    """
    name = str(kind).strip().lower().replace("_", "-")
    name = {"sobol-burley": "sobol", "random": "independent"}.get(name, name)
    if name not in _SAMPLERS:
        raise ValueError(f"unknown sampler kind (sampling pattern) {kind!r}; expected one of {SAMPLER_KINDS}")
    return _SAMPLERS[name](seed=seed, spp=spp)


# ---------------------------------------------------------------------------------------
# Warps (u: (N, 2) in [0, 1); outputs float32)
# ---------------------------------------------------------------------------------------


def _uv(u: ArrayLike) -> tuple[F32, F32]:
    a = np.asarray(u, dtype=np.float32)
    if a.ndim != 2 or a.shape[1] < 2:
        raise ValueError(f"expected u of shape (N, 2), got {a.shape}")
    return a[:, 0], a[:, 1]


def _dir(cos_t: F32, sin_t: F32, phi: F32) -> F32:
    out = np.empty(cos_t.shape + (3,), dtype=np.float32)
    out[:, 0] = sin_t * np.cos(phi)
    out[:, 1] = sin_t * np.sin(phi)
    out[:, 2] = cos_t
    return out


def sample_cosine_hemisphere(u: ArrayLike) -> F32:
    """Cosine-weighted direction about +z, the thesis' map.

    ``phi = 2 pi u0``, ``theta = arccos(sqrt(1 - u1))`` (so ``cos = sqrt(1 - u1) > 0``,
    ``sin = sqrt(u1)``).  pdf: :func:`pdf_cosine_hemisphere` = cos(theta) / pi.
    """
    u0, u1 = _uv(u)
    return _dir(np.sqrt(np.float32(1) - u1), np.sqrt(u1), _TWO_PI * u0)


def sample_cosine_hemisphere_concentric(u: ArrayLike) -> F32:
    """Cosine-weighted direction about +z via Malley's method on the concentric disk.

    Better preserves stratification than the polar map.  Same pdf, cos(theta) / pi.
    """
    d = sample_concentric_disk(u)
    out = np.empty((d.shape[0], 3), dtype=np.float32)
    out[:, :2] = d
    out[:, 2] = np.sqrt(np.maximum(np.float32(0), np.float32(1) - d[:, 0] ** 2 - d[:, 1] ** 2))
    return out


def pdf_cosine_hemisphere(w: ArrayLike) -> F32:
    """Solid-angle pdf ``max(w.z, 0) / pi`` of the cosine-weighted hemisphere warps."""
    z = np.asarray(w, dtype=np.float32)[..., 2]
    return np.maximum(z, np.float32(0)) * _INV_PI


def sample_uniform_hemisphere(u: ArrayLike) -> F32:
    """Uniform direction on the +z hemisphere: ``z = u0``, ``phi = 2 pi u1``; pdf 1/(2 pi)."""
    u0, u1 = _uv(u)
    return _dir(u0, np.sqrt(np.maximum(np.float32(0), np.float32(1) - u0 * u0)), _TWO_PI * u1)


def pdf_uniform_hemisphere(w: ArrayLike) -> F32:
    """1/(2 pi) for ``w.z >= 0``, else 0."""
    z = np.asarray(w, dtype=np.float32)[..., 2]
    return np.where(z >= 0, _INV_2PI, np.float32(0)).astype(np.float32)


def sample_uniform_sphere(u: ArrayLike) -> F32:
    """Uniform direction on the unit sphere: ``z = 1 - 2 u0``, ``phi = 2 pi u1``; pdf 1/(4 pi)."""
    u0, u1 = _uv(u)
    z = np.float32(1) - np.float32(2) * u0
    return _dir(z, np.sqrt(np.maximum(np.float32(0), np.float32(1) - z * z)), _TWO_PI * u1)


def pdf_uniform_sphere(w: ArrayLike) -> F32:
    """1/(4 pi) everywhere (shape of ``w[..., 0]``)."""
    return np.full(np.asarray(w).shape[:-1], _INV_4PI, dtype=np.float32)


def sample_uniform_cone(u: ArrayLike, cos_max: ArrayLike) -> F32:
    """Uniform direction in the cone about +z with ``cos(theta) >= cos_max``.

    ``cos_max`` is a scalar or (N,) array.  ``cos = 1 - u0 (1 - cos_max)``,
    ``phi = 2 pi u1``; pdf ``1 / (2 pi (1 - cos_max))`` (see :func:`pdf_uniform_cone`).
    """
    u0, u1 = _uv(u)
    one_minus = np.float32(1) - np.asarray(cos_max, dtype=np.float32)
    t = u0 * one_minus  # 1 - cos(theta), kept separate for precision in narrow cones
    sin_t = np.sqrt(np.maximum(np.float32(0), t * (np.float32(2) - t)))
    return _dir(np.float32(1) - t, sin_t, _TWO_PI * u1)


def pdf_uniform_cone(w: ArrayLike, cos_max: ArrayLike) -> F32:
    """``1 / (2 pi (1 - cos_max))`` inside the cone (``w.z >= cos_max``), 0 outside."""
    z = np.asarray(w, dtype=np.float32)[..., 2]
    cm = np.asarray(cos_max, dtype=np.float32)
    with np.errstate(divide="ignore"):
        val = _INV_2PI / (np.float32(1) - cm)
    return np.where(z >= cm, val, np.float32(0)).astype(np.float32)


def sample_concentric_disk(u: ArrayLike) -> F32:
    """Shirley-Chiu concentric map of [0,1)^2 onto the unit disk; (N, 2), pdf 1/pi."""
    u0, u1 = _uv(u)
    a = np.float32(2) * u0 - np.float32(1)
    b = np.float32(2) * u1 - np.float32(1)
    use_a = np.abs(a) > np.abs(b)
    r = np.where(use_a, a, b)
    num = np.where(use_a, b, a)
    safe = np.where(r == 0, np.float32(1), r)
    ratio = num / safe
    quarter = np.float32(math.pi / 4)
    theta = np.where(use_a, quarter * ratio, np.float32(math.pi / 2) - quarter * ratio)
    out = np.empty((u0.shape[0], 2), dtype=np.float32)
    out[:, 0] = r * np.cos(theta)
    out[:, 1] = r * np.sin(theta)
    return out


def pdf_concentric_disk(p: ArrayLike) -> F32:
    """Area pdf 1/pi inside the unit disk, 0 outside."""
    q = np.asarray(p, dtype=np.float32)
    return np.where((q[..., 0] ** 2 + q[..., 1] ** 2) <= 1, _INV_PI, np.float32(0)).astype(np.float32)


def sample_uniform_triangle(u: ArrayLike, method: str = "heitz") -> F32:
    """Uniform barycentrics ``(b0, b1, b2)``, shape (N, 3), summing to 1.

    ``method="heitz"``: Heitz 2019 low-distortion square-to-triangle map (default);
    ``method="sqrt"``: the classic ``b0 = 1 - sqrt(u0), b1 = u1 sqrt(u0)`` map.
    The point ``b0 A + b1 B + b2 C`` is uniform on the triangle: pdf 2 in (b0, b1), i.e.
    ``1 / area`` in area measure (see :func:`pdf_uniform_triangle`).
    """
    u0, u1 = _uv(u)
    if method == "heitz":
        half0, half1 = np.float32(0.5) * u0, np.float32(0.5) * u1
        lower = u0 < u1
        b0 = np.where(lower, half0, u0 - half1)
        b1 = np.where(lower, u1 - half0, half1)
    elif method == "sqrt":
        su = np.sqrt(u0)
        b0 = np.float32(1) - su
        b1 = u1 * su
    else:
        raise ValueError(f"unknown triangle sampling method {method!r}; expected 'heitz' or 'sqrt'")
    out = np.empty((u0.shape[0], 3), dtype=np.float32)
    out[:, 0] = b0
    out[:, 1] = b1
    out[:, 2] = np.maximum(np.float32(0), np.float32(1) - b0 - b1)
    return out


def pdf_uniform_triangle(area: ArrayLike) -> F32:
    """Area-measure pdf ``1 / area`` of :func:`sample_uniform_triangle` points."""
    return (np.float32(1) / np.asarray(area, dtype=np.float32)).astype(np.float32)


def _cap_geometry(p: ArrayLike, center: ArrayLike, radius: ArrayLike):
    """Axis to the sphere (float64), ``1 - cos(theta_max)`` (stable), and an inside mask."""
    d = np.asarray(center, dtype=np.float64) - np.asarray(p, dtype=np.float64)
    d = np.atleast_2d(d)
    dist2 = np.einsum("ij,ij->i", d, d)
    r2 = np.asarray(radius, dtype=np.float64) ** 2
    inside = dist2 <= r2
    sin2 = np.where(inside, 1.0, r2 / np.where(dist2 > 0, dist2, 1.0))
    one_minus_cos = sin2 / (1.0 + np.sqrt(np.maximum(0.0, 1.0 - sin2)))
    axis = d / np.sqrt(np.where(dist2 > 0, dist2, 1.0))[:, None]
    return axis, one_minus_cos, inside


def sample_sphere_cap(
    u: ArrayLike, p: ArrayLike, center: ArrayLike, radius: ArrayLike
) -> tuple[F32, F32]:
    """Uniform direction within the cone subtended by a sphere (for sphere lights).

    ``p``: (N, 3) shading points; ``center``: (3,) or (N, 3); ``radius``: scalar or (N,).
    Returns ``(wi, pdf)``: world-space unit directions (N, 3) and the solid-angle pdf
    ``1 / (2 pi (1 - cos_max))`` with ``sin^2(theta_max) = r^2 / |c - p|^2`` (computed as
    ``1 - cos_max = sin^2 / (1 + cos_max)`` for precision with small or distant spheres).
    A point inside the sphere gets a uniform sphere direction with pdf 1/(4 pi).
    """
    u0, u1 = _uv(u)
    axis, omc, inside = _cap_geometry(p, center, radius)
    omc = np.broadcast_to(omc, u0.shape)
    inside = np.broadcast_to(inside, u0.shape)
    t = u0.astype(np.float64) * np.where(inside, 2.0, omc)  # inside: z = 1 - 2 u0 (sphere)
    cos_t = 1.0 - t
    sin_t = np.sqrt(np.maximum(0.0, t * (2.0 - t)))
    phi = 2.0 * math.pi * u1.astype(np.float64)
    local = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)
    tb, bb = build_onb(axis)
    axis_b = np.broadcast_to(axis, local.shape)
    wi = to_world(local, tb.astype(np.float64), bb.astype(np.float64), axis_b)
    pdf = np.where(inside, 0.25 / math.pi, 1.0 / (2.0 * math.pi * np.where(inside, 1.0, omc)))
    return wi.astype(np.float32), pdf.astype(np.float32)


def pdf_sphere_cap(wi: ArrayLike | None, p: ArrayLike, center: ArrayLike, radius: ArrayLike) -> F32:
    """Solid-angle pdf of :func:`sample_sphere_cap` (1/(4 pi) for points inside the sphere).

    With ``wi`` (N, 3), directions outside the cone get 0; the cone test allows for
    float32 rounding of ``wi`` (a few ulps of cos(theta) around 1), so the directions
    :func:`sample_sphere_cap` returns always get their own pdf back.  Pass ``wi=None`` when
    the caller already knows the direction hits the sphere (e.g. MIS after a BSDF ray hit
    the light): that skips the test.
    """
    axis, omc, inside = _cap_geometry(p, center, radius)
    cone = np.where(inside, 0.25 / math.pi, 1.0 / (2.0 * math.pi * np.where(inside, 1.0, omc)))
    if wi is None:
        return cone.astype(np.float32)
    w = np.atleast_2d(np.asarray(wi, dtype=np.float64))
    cos_t = np.einsum("ij,ij->i", w, np.broadcast_to(axis, w.shape))
    in_cone = (1.0 - cos_t) <= omc * (1.0 + 1e-4) + 2.5e-7
    return np.where(inside | in_cone, cone, 0.0).astype(np.float32)


# ---------------------------------------------------------------------------------------
# Frames
# ---------------------------------------------------------------------------------------


def build_onb(n: ArrayLike) -> tuple[NDArray, NDArray]:
    """Orthonormal basis ``(t, b)`` around unit normals ``n`` (N, 3), branchless.

    Duff et al. 2017, "Building an Orthonormal Basis, Revisited".  ``(t, b, n)`` is
    right-handed (``t x b = n``).  Keeps the input float dtype (float32 by default).
    """
    nn = np.asarray(n)
    if nn.dtype != np.float64:
        nn = nn.astype(np.float32)
    one = nn.dtype.type(1)
    x, y, z = nn[..., 0], nn[..., 1], nn[..., 2]
    sign = np.copysign(one, z)
    a = -one / (sign + z)
    bxy = x * y * a
    t = np.stack([one + sign * x * x * a, sign * bxy, -sign * x], axis=-1)
    b = np.stack([bxy, sign + y * y * a, -y], axis=-1)
    return t, b


def to_local(v: ArrayLike, t: ArrayLike, b: ArrayLike, n: ArrayLike) -> NDArray:
    """World vector(s) -> local frame: ``(v.t, v.b, v.n)``."""
    v, t, b, n = (np.asarray(a) for a in (v, t, b, n))
    return np.stack([(v * t).sum(-1), (v * b).sum(-1), (v * n).sum(-1)], axis=-1)


def to_world(v: ArrayLike, t: ArrayLike, b: ArrayLike, n: ArrayLike) -> NDArray:
    """Local vector(s) -> world: ``v.x t + v.y b + v.z n``."""
    v = np.asarray(v)
    return v[..., 0:1] * np.asarray(t) + v[..., 1:2] * np.asarray(b) + v[..., 2:3] * np.asarray(n)
