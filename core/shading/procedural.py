"""Blender's procedural texture nodes, computed as Cycles computes them (same hashes, same noise, float32).

Each texture is a scalar device function (numba, callable from other kernels: the shading-node program) that
takes the node's inputs and settings as scalars and returns a tuple, plus a batch function over NumPy arrays
(tests, benchmarks). Coordinates are the node's Vector input (object units, or whatever the node tree feeds
in) and, for 1D and 4D textures, the W input; every texture multiplies them by its Scale input first, as
Blender does.

Matching Cycles pixel for pixel needs its exact integer hashes: Bob Jenkins' lookup3 `final`/`mix` on uint32
(white noise, Perlin gradients, 1D Voronoi, the noise seeds; float inputs hashed through their bit pattern)
and a PCG-style hash on signed int32 (2D-4D Voronoi cells); a hash becomes a float as `(float)h * 2^-32`
(lookup3) or `(float)h * 2^-31` (PCG). Arithmetic feeding a hash or a floor runs in float32 as in Cycles;
other rounding differences stay near float32 precision (about 1e-6 on values of order 1).

Settings that are enums in Blender are small integers here; the `*_TYPES` dictionaries map Blender's enum
identifiers (as bpy spells them) to them. In materials the textures run as shading-program instructions
(opcodes 400-408, registered at the end of this module; `run` is the family's dispatcher called by
core.shading.evaluator; the compiler rules are in addon/export/nodes/textures.py).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..jit_cache import jit_inline
from ..jit_cache import jit_no_nrt as jit  # no function here allocates (the batch wrappers allocate in Python)
from . import registry as R
from .regs import set3, setf

f32 = np.float32
_M32 = 0xFFFFFFFF
_FLT_MAX = np.float32(3.4028234663852886e38)
_TWO_PI = np.float32(2.0 * math.pi)
_HALF_PI = np.float32(0.5 * math.pi)
_I32 = ir.IntType(32)
_TWO23 = np.float32(8388608.0)

# ------------------------------------------------------------------------------------------------ enums
NOISE_FBM, NOISE_MULTIFRACTAL, NOISE_HYBRID_MULTIFRACTAL, NOISE_RIDGED_MULTIFRACTAL, NOISE_HETERO_TERRAIN = range(5)
NOISE_TYPES = {"FBM": NOISE_FBM, "MULTIFRACTAL": NOISE_MULTIFRACTAL, "HYBRID_MULTIFRACTAL": NOISE_HYBRID_MULTIFRACTAL,
               "RIDGED_MULTIFRACTAL": NOISE_RIDGED_MULTIFRACTAL, "HETERO_TERRAIN": NOISE_HETERO_TERRAIN}

(GRADIENT_LINEAR, GRADIENT_QUADRATIC, GRADIENT_EASING, GRADIENT_DIAGONAL, GRADIENT_RADIAL, GRADIENT_QUADRATIC_SPHERE,
 GRADIENT_SPHERICAL) = range(7)
GRADIENT_TYPES = {"LINEAR": GRADIENT_LINEAR, "QUADRATIC": GRADIENT_QUADRATIC, "EASING": GRADIENT_EASING,
                  "DIAGONAL": GRADIENT_DIAGONAL, "RADIAL": GRADIENT_RADIAL,
                  "QUADRATIC_SPHERE": GRADIENT_QUADRATIC_SPHERE, "SPHERICAL": GRADIENT_SPHERICAL}

VORONOI_F1, VORONOI_F2, VORONOI_SMOOTH_F1, VORONOI_DISTANCE_TO_EDGE, VORONOI_N_SPHERE_RADIUS = range(5)
VORONOI_FEATURES = {"F1": VORONOI_F1, "F2": VORONOI_F2, "SMOOTH_F1": VORONOI_SMOOTH_F1,
                    "DISTANCE_TO_EDGE": VORONOI_DISTANCE_TO_EDGE, "N_SPHERE_RADIUS": VORONOI_N_SPHERE_RADIUS}
METRIC_EUCLIDEAN, METRIC_MANHATTAN, METRIC_CHEBYCHEV, METRIC_MINKOWSKI = range(4)
VORONOI_METRICS = {"EUCLIDEAN": METRIC_EUCLIDEAN, "MANHATTAN": METRIC_MANHATTAN, "CHEBYCHEV": METRIC_CHEBYCHEV,
                   "MINKOWSKI": METRIC_MINKOWSKI}

WAVE_BANDS, WAVE_RINGS = range(2)
WAVE_TYPES = {"BANDS": WAVE_BANDS, "RINGS": WAVE_RINGS}
# Bands: X, Y, Z, DIAGONAL; rings: X, Y, Z, SPHERICAL (the same four slots).
WAVE_BANDS_DIRECTIONS = {"X": 0, "Y": 1, "Z": 2, "DIAGONAL": 3}
WAVE_RINGS_DIRECTIONS = {"X": 0, "Y": 1, "Z": 2, "SPHERICAL": 3}
WAVE_SIN, WAVE_SAW, WAVE_TRI = range(3)
WAVE_PROFILES = {"SIN": WAVE_SIN, "SAW": WAVE_SAW, "TRI": WAVE_TRI}


# ------------------------------------------------------------------------------------------------ hashes
@intrinsic
def _float_bits(typingctx, x):
    """The bit pattern of a float32 as a uint32 (C's __float_as_uint)."""
    if x != types.float32:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(32))

    return types.uint32(types.float32), codegen


@jit
def float_bits(x):
    """The bit pattern of float32 x as a non-negative int64 below 2^32."""
    return np.int64(_float_bits(np.float32(x)))


# lookup3 on uint32, carried in int64 and masked after every add, subtract and shift.
@jit
def _rot(x, k):
    return ((x << k) | (x >> (32 - k))) & _M32


@jit
def _final(a, b, c):
    c ^= b
    c = (c - _rot(b, 14)) & _M32
    a ^= c
    a = (a - _rot(c, 11)) & _M32
    b ^= a
    b = (b - _rot(a, 25)) & _M32
    c ^= b
    c = (c - _rot(b, 16)) & _M32
    a ^= c
    a = (a - _rot(c, 4)) & _M32
    b ^= a
    b = (b - _rot(a, 14)) & _M32
    c ^= b
    c = (c - _rot(b, 24)) & _M32
    return c


@jit
def hash_uint(kx):
    """lookup3 of one uint32 (given as an int64; negative values wrap as C's int -> uint)."""
    a = (0xDEADBEEF + (1 << 2) + 13) & _M32
    return _final((a + kx) & _M32, a, a)


@jit
def hash_uint2(kx, ky):
    a = (0xDEADBEEF + (2 << 2) + 13) & _M32
    return _final((a + kx) & _M32, (a + ky) & _M32, a)


@jit
def hash_uint3(kx, ky, kz):
    a = (0xDEADBEEF + (3 << 2) + 13) & _M32
    return _final((a + kx) & _M32, (a + ky) & _M32, (a + kz) & _M32)


@jit
def hash_uint4(kx, ky, kz, kw):
    init = (0xDEADBEEF + (4 << 2) + 13) & _M32
    a = (init + kx) & _M32
    b = (init + ky) & _M32
    c = (init + kz) & _M32
    a = (a - c) & _M32
    a ^= _rot(c, 4)
    c = (c + b) & _M32
    b = (b - a) & _M32
    b ^= _rot(a, 6)
    a = (a + c) & _M32
    c = (c - b) & _M32
    c ^= _rot(b, 8)
    b = (b + a) & _M32
    a = (a - c) & _M32
    a ^= _rot(c, 16)
    c = (c + b) & _M32
    b = (b - a) & _M32
    b ^= _rot(a, 19)
    a = (a + c) & _M32
    c = (c - b) & _M32
    c ^= _rot(b, 4)
    b = (b + a) & _M32
    a = (a + kw) & _M32
    return _final(a, b, c)


@jit
def _uint_to_unit(h):
    """[0, 2^32) -> [0, 1], as Cycles: (float)h * (1 / (float)0xFFFFFFFF), the divisor rounding to 2^32."""
    return np.float32(h) * np.float32(2.0 ** -32)


@jit
def hash_float_to_float(x):
    return _uint_to_unit(hash_uint(float_bits(x)))


@jit
def hash_float2_to_float(x, y):
    return _uint_to_unit(hash_uint2(float_bits(x), float_bits(y)))


@jit
def hash_float3_to_float(x, y, z):
    return _uint_to_unit(hash_uint3(float_bits(x), float_bits(y), float_bits(z)))


@jit
def hash_float4_to_float(x, y, z, w):
    return _uint_to_unit(hash_uint4(float_bits(x), float_bits(y), float_bits(z), float_bits(w)))


# PCG on signed int32 (wrapping), carried in int64.
@jit
def _wrap32(x):
    return ((x + 0x80000000) & _M32) - 0x80000000


@jit
def _pcg2(x, y):
    x = _wrap32(x * 1664525 + 1013904223)
    y = _wrap32(y * 1664525 + 1013904223)
    x = _wrap32(x + y * 1664525)
    y = _wrap32(y + x * 1664525)
    x ^= x >> 16
    y ^= y >> 16
    x = _wrap32(x + y * 1664525)
    y = _wrap32(y + x * 1664525)
    return x & 0x7FFFFFFF, y & 0x7FFFFFFF


@jit
def _pcg3(x, y, z):
    x = _wrap32(x * 1664525 + 1013904223)
    y = _wrap32(y * 1664525 + 1013904223)
    z = _wrap32(z * 1664525 + 1013904223)
    x = _wrap32(x + y * z)
    y = _wrap32(y + z * x)
    z = _wrap32(z + x * y)
    x ^= x >> 16
    y ^= y >> 16
    z ^= z >> 16
    x = _wrap32(x + y * z)
    y = _wrap32(y + z * x)
    z = _wrap32(z + x * y)
    return x & 0x7FFFFFFF, y & 0x7FFFFFFF, z & 0x7FFFFFFF


@jit
def _pcg4(x, y, z, w):
    x = _wrap32(x * 1664525 + 1013904223)
    y = _wrap32(y * 1664525 + 1013904223)
    z = _wrap32(z * 1664525 + 1013904223)
    w = _wrap32(w * 1664525 + 1013904223)
    x = _wrap32(x + y * w)
    y = _wrap32(y + z * x)
    z = _wrap32(z + x * y)
    w = _wrap32(w + y * z)
    x ^= x >> 16
    y ^= y >> 16
    z ^= z >> 16
    w ^= w >> 16
    x = _wrap32(x + y * w)
    y = _wrap32(y + z * x)
    z = _wrap32(z + x * y)
    w = _wrap32(w + y * z)
    return x & 0x7FFFFFFF, y & 0x7FFFFFFF, z & 0x7FFFFFFF, w & 0x7FFFFFFF


@jit
def _int_to_unit(h):
    """[0, 2^31) -> [0, 1]: (float)h * (1 / (float)0x7FFFFFFF), the divisor rounding to 2^31."""
    return np.float32(h) * np.float32(2.0 ** -31)


# ------------------------------------------------------------------------------------------------ Perlin noise
@jit
def _floor(x):
    """np.floor(x), the same value and type, without its libm call: the kernels are compiled for generic x86-64
    (SSE2, no SSE4.1 `roundss`), where LLVM lowers np.floor to a call of floorf, and a call spills the vector
    registers Perlin noise keeps live (~3 ns of 25 per octave). Below 2^23 every float32 and float64 truncates
    to int32 exactly and back; one less where that rounded up (negative non-integers); a zero keeps its sign
    (floor(-0.0) is -0.0). NaN, infinities and magnitudes from 2^23 on take np.floor."""
    if abs(x) < _TWO23:
        f = np.float32(np.int32(x))
        f = f - np.float32(f > x)
        return x if x == 0 else f
    return np.floor(x)


@jit
def _fade(t):
    return t * t * t * (t * (t * np.float32(6.0) - np.float32(15.0)) + np.float32(10.0))


@jit
def _mix(a, b, t):
    return a + t * (b - a)


def _lanes_i32(builder, n, values):
    """An <n x i32> constant."""
    return ir.Constant(ir.VectorType(_I32, n), [ir.Constant(_I32, int(v) & _M32) for v in values])


def _splat(builder, vec_type, scalar):
    """scalar (an LLVM value of vec_type's element type) in every lane of vec_type."""
    undef = ir.Constant(vec_type, ir.Undefined)
    one = builder.insert_element(undef, scalar, ir.Constant(_I32, 0))
    return builder.shuffle_vector(one, undef, _lanes_i32(builder, vec_type.count, [0] * vec_type.count))


def _lookup3_lanes(builder, n, keys):
    """lookup3 (hash_uint .. hash_uint4 above, same operations) of n keys at once: keys are 1-4 <n x i32>."""

    def const(v):
        return _lanes_i32(builder, n, [v] * n)

    def rot(x, k):
        return builder.or_(builder.shl(x, const(k)), builder.lshr(x, const(32 - k)))

    init = const(0xDEADBEEF + (len(keys) << 2) + 13)
    a = builder.add(init, keys[0])
    b = builder.add(init, keys[1]) if len(keys) > 1 else init
    c = builder.add(init, keys[2]) if len(keys) > 2 else init
    if len(keys) == 4:  # lookup3's mix before the last key
        a = builder.xor(builder.sub(a, c), rot(c, 4))
        c = builder.add(c, b)
        b = builder.xor(builder.sub(b, a), rot(a, 6))
        a = builder.add(a, c)
        c = builder.xor(builder.sub(c, b), rot(b, 8))
        b = builder.add(b, a)
        a = builder.xor(builder.sub(a, c), rot(c, 16))
        c = builder.add(c, b)
        b = builder.xor(builder.sub(b, a), rot(a, 19))
        a = builder.add(a, c)
        c = builder.xor(builder.sub(c, b), rot(b, 4))
        b = builder.add(b, a)
        a = builder.add(a, keys[3])
    c = builder.sub(builder.xor(c, b), rot(b, 14))
    a = builder.sub(builder.xor(a, c), rot(c, 11))
    b = builder.sub(builder.xor(b, a), rot(a, 25))
    c = builder.sub(builder.xor(c, b), rot(b, 16))
    a = builder.sub(builder.xor(a, c), rot(c, 4))
    b = builder.sub(builder.xor(b, a), rot(a, 14))
    return builder.sub(builder.xor(c, b), rot(b, 24))


def _perlin_lattice_codegen(dim):
    """LLVM IR of Perlin noise's lattice part in dim dimensions, all 2^dim corners of the cell in one pass of
    vector instructions (SSE2 on the generic x86-64 the kernels are compiled for), as Cycles hashes its corners in
    SIMD. Arguments: the cell's integer corner (dim int64), the fractional position in it (dim float32) and the
    fade weights (dim float32). Corner i has offset (i >> d) & 1 on axis d. Same operations per corner as
    Cycles' scalar definitions, so the same bits:
      hash: lookup3 of the corner's coordinates (uint32);
      gradient: 1D: (1 + (h & 7)), negated if h & 8, times x;
                2D: u = h < 4 ? x : y, v = 2 (h < 4 ? y : x);  u negated if h & 1, v if h & 2;  u + v;
                3D: u = h < 8 ? x : y, v = h < 4 ? y : (h == 12 or 14 ? x : z);  u +- v as 2D;
                4D: u = h < 24 ? x : y, v = h < 16 ? y : z, s = h < 8 ? z : w;  (u +- v) +- s;
      (h masked to 4 bits in 1D and 3D, 3 in 2D, 5 in 4D; a negation is a flip of the sign bit, as -x);
      interpolation: a + w (b - a) between corner pairs along x (weight u), then y, z, w."""
    n = 1 << dim

    def codegen(context, builder, signature, args):
        vi = ir.VectorType(_I32, n)
        f32t = ir.FloatType()
        vf = ir.VectorType(f32t, n)

        def const(v):
            return _lanes_i32(builder, n, [v] * n)

        cells, fracs, weights = args[:dim], args[dim:2 * dim], args[2 * dim:]
        keys = [builder.add(_splat(builder, vi, builder.trunc(cells[d], _I32)),
                            _lanes_i32(builder, n, [(i >> d) & 1 for i in range(n)])) for d in range(dim)]
        h = _lookup3_lanes(builder, n, keys)
        one = ir.Constant(f32t, 1.0)
        # the corner offsets on each axis: f on the near side, f - 1 on the far one
        offs = []
        for d in range(dim):
            near = _splat(builder, vf, fracs[d])
            far = _splat(builder, vf, builder.fsub(fracs[d], one))
            far_lane = builder.icmp_unsigned("!=", _lanes_i32(builder, n, [(i >> d) & 1 for i in range(n)]),
                                             const(0))
            offs.append(builder.select(far_lane, far, near))

        def flip(v, bit, shift):  # negate v where h & bit (the bit moved to the sign)
            sign = builder.shl(builder.and_(h, const(bit)), const(shift))
            return builder.bitcast(builder.xor(builder.bitcast(v, vi), sign), vf)

        if dim == 1:
            hm = builder.and_(h, const(15))
            g = builder.sitofp(builder.add(builder.and_(hm, const(7)), const(1)), vf)
            g = builder.fmul(flip(g, 8, 28), offs[0])
        elif dim == 2:
            low = builder.icmp_unsigned("<", builder.and_(h, const(7)), const(4))
            x, y = offs
            u = builder.select(low, x, y)
            v = builder.fmul(_splat(builder, vf, ir.Constant(f32t, 2.0)), builder.select(low, y, x))
            g = builder.fadd(flip(u, 1, 31), flip(v, 2, 30))
        elif dim == 3:
            hm = builder.and_(h, const(15))
            x, y, z = offs
            u = builder.select(builder.icmp_unsigned("<", hm, const(8)), x, y)
            x_or_z = builder.select(builder.or_(builder.icmp_unsigned("==", hm, const(12)),
                                                builder.icmp_unsigned("==", hm, const(14))), x, z)
            v = builder.select(builder.icmp_unsigned("<", hm, const(4)), y, x_or_z)
            g = builder.fadd(flip(u, 1, 31), flip(v, 2, 30))
        else:
            hm = builder.and_(h, const(31))
            x, y, z, w = offs
            u = builder.select(builder.icmp_unsigned("<", hm, const(24)), x, y)
            v = builder.select(builder.icmp_unsigned("<", hm, const(16)), y, z)
            s = builder.select(builder.icmp_unsigned("<", hm, const(8)), z, w)
            g = builder.fadd(builder.fadd(flip(u, 1, 31), flip(v, 2, 30)), flip(s, 4, 29))
        # interpolate neighbouring lanes (offset 0 and 1 on the current axis) until one is left
        m = n
        for d in range(dim):
            m //= 2
            undef = ir.Constant(ir.VectorType(f32t, 2 * m), ir.Undefined)
            a = builder.shuffle_vector(g, undef, _lanes_i32(builder, m, range(0, 2 * m, 2)))
            b = builder.shuffle_vector(g, undef, _lanes_i32(builder, m, range(1, 2 * m, 2)))
            wv = _splat(builder, ir.VectorType(f32t, m), weights[d])
            g = builder.fadd(a, builder.fmul(wv, builder.fsub(b, a)))
        return builder.extract_element(g, ir.Constant(_I32, 0))

    return codegen


def _lattice_signature(dim):
    return types.float32(*([types.int64] * dim + [types.float32] * (2 * dim)))


# numba's intrinsics take a fixed argument list: one typer per dimension (cells, fractions, fade weights).
@intrinsic
def _perlin_lattice_1d(typingctx, x0, f0, w0):
    return _lattice_signature(1), _perlin_lattice_codegen(1)


@intrinsic
def _perlin_lattice_2d(typingctx, x0, x1, f0, f1, w0, w1):
    return _lattice_signature(2), _perlin_lattice_codegen(2)


@intrinsic
def _perlin_lattice_3d(typingctx, x0, x1, x2, f0, f1, f2, w0, w1, w2):
    return _lattice_signature(3), _perlin_lattice_codegen(3)


@intrinsic
def _perlin_lattice_4d(typingctx, x0, x1, x2, x3, f0, f1, f2, f3, w0, w1, w2, w3):
    return _lattice_signature(4), _perlin_lattice_codegen(4)


@jit
def _perlin_1d(x):
    fl = _floor(x)
    fx = x - fl
    return _perlin_lattice_1d(np.int64(fl), fx, _fade(fx))


@jit
def _perlin_2d(x, y):
    flx = _floor(x)
    fly = _floor(y)
    fx = x - flx
    fy = y - fly
    return _perlin_lattice_2d(np.int64(flx), np.int64(fly), fx, fy, _fade(fx), _fade(fy))


@jit
def _perlin_3d(x, y, z):
    flx = _floor(x)
    fly = _floor(y)
    flz = _floor(z)
    fx = x - flx
    fy = y - fly
    fz = z - flz
    return _perlin_lattice_3d(np.int64(flx), np.int64(fly), np.int64(flz), fx, fy, fz, _fade(fx), _fade(fy),
                              _fade(fz))


@jit
def _perlin_4d(x, y, z, w):
    flx = _floor(x)
    fly = _floor(y)
    flz = _floor(z)
    flw = _floor(w)
    fx = x - flx
    fy = y - fly
    fz = z - flz
    fw = w - flw
    return _perlin_lattice_4d(np.int64(flx), np.int64(fly), np.int64(flz), np.int64(flw), fx, fy, fz, fw,
                              _fade(fx), _fade(fy), _fade(fz), _fade(fw))


@jit
def _wrap_coordinate(p):
    """Cycles repeats Perlin noise every 100000 on each axis (float precision), shifted by half a cell beyond
    1e6 so integer lattice points do not land on exact zeros."""
    a = abs(p)
    if a < np.float32(100000.0):  # fmod would return p itself: skip the libm call
        return p
    corr = np.float32(0.5) if a >= np.float32(1000000.0) else np.float32(0.0)
    return np.fmod(p, np.float32(100000.0)) + corr


@jit
def snoise(dim, x, y, z, w):
    """Signed Perlin noise in about [-1, 1] of dimension dim (1: x only; 2: x, y; 3: x, y, z; 4: all)."""
    if dim == 1:
        return np.float32(0.25) * _perlin_1d(_wrap_coordinate(x))
    if dim == 2:
        return np.float32(0.6616) * _perlin_2d(_wrap_coordinate(x), _wrap_coordinate(y))
    if dim == 3:
        return np.float32(0.9820) * _perlin_3d(_wrap_coordinate(x), _wrap_coordinate(y), _wrap_coordinate(z))
    return np.float32(0.8344) * _perlin_4d(_wrap_coordinate(x), _wrap_coordinate(y), _wrap_coordinate(z),
                                           _wrap_coordinate(w))


# ------------------------------------------------------------------------------------------------ fractal noise
@jit
def noise_fbm(dim, x, y, z, w, detail, roughness, lacunarity, normalize):
    fscale = np.float32(1.0)
    amp = np.float32(1.0)
    maxamp = np.float32(0.0)
    total = np.float32(0.0)
    half = np.float32(0.5)
    for _ in range(int(detail) + 1):
        t = snoise(dim, fscale * x, fscale * y, fscale * z, fscale * w)
        total += t * amp
        maxamp += amp
        amp *= roughness
        fscale *= lacunarity
    rmd = detail - _floor(detail)
    if rmd != np.float32(0.0):
        t = snoise(dim, fscale * x, fscale * y, fscale * z, fscale * w)
        sum2 = total + t * amp
        if normalize:
            return _mix(half * total / maxamp + half, half * sum2 / (maxamp + amp) + half, rmd)
        return _mix(total, sum2, rmd)
    if normalize:
        return half * total / maxamp + half
    return total


@jit
def noise_multi_fractal(dim, x, y, z, w, detail, roughness, lacunarity):
    one = np.float32(1.0)
    value = one
    pwr = one
    for _ in range(int(detail) + 1):
        value *= pwr * snoise(dim, x, y, z, w) + one
        pwr *= roughness
        x *= lacunarity
        y *= lacunarity
        z *= lacunarity
        w *= lacunarity
    rmd = detail - _floor(detail)
    if rmd != np.float32(0.0):
        value *= rmd * pwr * snoise(dim, x, y, z, w) + one
    return value


@jit
def noise_hetero_terrain(dim, x, y, z, w, detail, roughness, lacunarity, offset):
    pwr = roughness
    value = offset + snoise(dim, x, y, z, w)
    x *= lacunarity
    y *= lacunarity
    z *= lacunarity
    w *= lacunarity
    for _ in range(1, int(detail) + 1):
        increment = (snoise(dim, x, y, z, w) + offset) * pwr * value
        value += increment
        pwr *= roughness
        x *= lacunarity
        y *= lacunarity
        z *= lacunarity
        w *= lacunarity
    rmd = detail - _floor(detail)
    if rmd != np.float32(0.0):
        increment = (snoise(dim, x, y, z, w) + offset) * pwr * value
        value += rmd * increment
    return value


@jit
def noise_hybrid_multi_fractal(dim, x, y, z, w, detail, roughness, lacunarity, offset, gain):
    one = np.float32(1.0)
    pwr = one
    value = np.float32(0.0)
    weight = one
    limit = np.float32(0.001)
    i = 0
    n = int(detail)
    while weight > limit and i <= n:
        if weight > one:
            weight = one
        signal = (snoise(dim, x, y, z, w) + offset) * pwr
        pwr *= roughness
        value += weight * signal
        weight *= gain * signal
        x *= lacunarity
        y *= lacunarity
        z *= lacunarity
        w *= lacunarity
        i += 1
    rmd = detail - _floor(detail)
    if rmd != np.float32(0.0) and weight > limit:
        if weight > one:
            weight = one
        signal = (snoise(dim, x, y, z, w) + offset) * pwr
        value += rmd * weight * signal
    return value


@jit
def noise_ridged_multi_fractal(dim, x, y, z, w, detail, roughness, lacunarity, offset, gain):
    pwr = roughness
    signal = offset - abs(snoise(dim, x, y, z, w))
    signal *= signal
    value = signal
    for _ in range(1, int(detail) + 1):
        x *= lacunarity
        y *= lacunarity
        z *= lacunarity
        w *= lacunarity
        weight = min(max(signal * gain, np.float32(0.0)), np.float32(1.0))
        signal = offset - abs(snoise(dim, x, y, z, w))
        signal *= signal
        signal *= weight
        value += signal * pwr
        pwr *= roughness
    return value


@jit
def _noise_select(dim, x, y, z, w, detail, roughness, lacunarity, offset, gain, noise_type, normalize):
    if noise_type == NOISE_MULTIFRACTAL:
        return noise_multi_fractal(dim, x, y, z, w, detail, roughness, lacunarity)
    if noise_type == NOISE_HYBRID_MULTIFRACTAL:
        return noise_hybrid_multi_fractal(dim, x, y, z, w, detail, roughness, lacunarity, offset, gain)
    if noise_type == NOISE_RIDGED_MULTIFRACTAL:
        return noise_ridged_multi_fractal(dim, x, y, z, w, detail, roughness, lacunarity, offset, gain)
    if noise_type == NOISE_HETERO_TERRAIN:
        return noise_hetero_terrain(dim, x, y, z, w, detail, roughness, lacunarity, offset)
    return noise_fbm(dim, x, y, z, w, detail, roughness, lacunarity, normalize)


@jit
def _seed_offset(dim, seed, component):
    """Cycles' per-seed coordinate offsets in [100, 200]: 1D hashes the seed alone, 2D-4D (seed, component)."""
    if dim == 1:
        h = hash_float_to_float(np.float32(seed))
    elif component >= dim:  # a coordinate this dimension ignores
        return np.float32(0.0)
    else:
        h = hash_float2_to_float(np.float32(seed), np.float32(component))
    # Cycles' compiler fuses this multiply-add (one rounding): computed exactly in float64, rounded once.
    return np.float32(np.float64(h) * 100.0 + 100.0)


@jit
def noise_texture(dim, x, y, z, w, scale, detail, roughness, lacunarity, offset, gain, distortion, noise_type,
                  normalize, need_color):
    """The Noise Texture node: (Fac, Color r, g, b). dim 1 reads w only, 2 reads x, y, 3 reads x, y, z,
    4 all four; the others are ignored. need_color False skips Color's two extra noise evaluations (g = b = 0)."""
    detail = min(max(detail, np.float32(0.0)), np.float32(15.0))
    roughness = max(roughness, np.float32(0.0))
    x = x * scale
    y = y * scale
    z = z * scale
    w = w * scale
    if dim == 1:  # the 1D texture lives on W: move it into the first slot
        x = w
    zero = np.float32(0.0)
    if distortion != zero:
        dx = snoise(dim, x + _seed_offset(dim, 0, 0), y + _seed_offset(dim, 0, 1), z + _seed_offset(dim, 0, 2),
                    w + _seed_offset(dim, 0, 3)) * distortion
        dy = zero
        dz = zero
        dw = zero
        if dim >= 2:
            dy = snoise(dim, x + _seed_offset(dim, 1, 0), y + _seed_offset(dim, 1, 1), z + _seed_offset(dim, 1, 2),
                        w + _seed_offset(dim, 1, 3)) * distortion
        if dim >= 3:
            dz = snoise(dim, x + _seed_offset(dim, 2, 0), y + _seed_offset(dim, 2, 1), z + _seed_offset(dim, 2, 2),
                        w + _seed_offset(dim, 2, 3)) * distortion
        if dim >= 4:
            dw = snoise(dim, x + _seed_offset(dim, 3, 0), y + _seed_offset(dim, 3, 1), z + _seed_offset(dim, 3, 2),
                        w + _seed_offset(dim, 3, 3)) * distortion
        x += dx
        y += dy
        z += dz
        w += dw
    value = _noise_select(dim, x, y, z, w, detail, roughness, lacunarity, offset, gain, noise_type, normalize)
    if not need_color:
        return value, value, zero, zero
    # Colour seeds follow the distortion seeds: 1D 1, 2; 2D 2, 3; 3D 3, 4; 4D 4, 5.
    s1 = 1 if dim == 1 else dim
    s2 = s1 + 1
    g = _noise_select(dim, x + _seed_offset(dim, s1, 0), y + _seed_offset(dim, s1, 1), z + _seed_offset(dim, s1, 2),
                      w + _seed_offset(dim, s1, 3), detail, roughness, lacunarity, offset, gain, noise_type, normalize)
    b = _noise_select(dim, x + _seed_offset(dim, s2, 0), y + _seed_offset(dim, s2, 1), z + _seed_offset(dim, s2, 2),
                      w + _seed_offset(dim, s2, 3), detail, roughness, lacunarity, offset, gain, noise_type, normalize)
    return value, value, g, b


# ------------------------------------------------------------------------------------------------ white noise
@jit
def white_noise_texture(dim, x, y, z, w):
    """The White Noise Texture node: (Value, Color r, g, b), hashes of the coordinates' bit patterns."""
    one = np.float32(1.0)
    two = np.float32(2.0)
    if dim == 1:
        return (hash_float_to_float(w), hash_float_to_float(w), hash_float2_to_float(w, one),
                hash_float2_to_float(w, two))
    if dim == 2:
        v = hash_float2_to_float(x, y)
        return v, v, hash_float3_to_float(x, y, one), hash_float3_to_float(x, y, two)
    if dim == 3:
        v = hash_float3_to_float(x, y, z)
        return v, v, hash_float4_to_float(x, y, z, one), hash_float4_to_float(x, y, z, two)
    v = hash_float4_to_float(x, y, z, w)
    return v, v, hash_float4_to_float(z, x, w, y), hash_float4_to_float(w, z, y, x)


# ------------------------------------------------------------------------------------------------ checker, gradient
@jit
def checker_texture(x, y, z, scale):
    """The Checker Texture node's Fac (1: Color1, 0: Color2)."""
    eps = np.float32(0.000001)
    shrink = np.float32(0.999999)
    xi = abs(np.int64(np.floor((x * scale + eps) * shrink)))
    yi = abs(np.int64(np.floor((y * scale + eps) * shrink)))
    zi = abs(np.int64(np.floor((z * scale + eps) * shrink)))
    same_xy = 1 if xi % 2 == yi % 2 else 0
    return np.float32(1.0) if same_xy == zi % 2 else np.float32(0.0)


@jit
def gradient_texture(x, y, z, gradient_type):
    """The Gradient Texture node's Fac in [0, 1] (Color is Fac in all three channels)."""
    zero = np.float32(0.0)
    one = np.float32(1.0)
    if gradient_type == GRADIENT_LINEAR:
        f = x
    elif gradient_type == GRADIENT_QUADRATIC:
        r = max(x, zero)
        f = r * r
    elif gradient_type == GRADIENT_EASING:
        r = min(max(x, zero), one)
        t = r * r
        f = np.float32(3.0) * t - np.float32(2.0) * t * r
    elif gradient_type == GRADIENT_DIAGONAL:
        f = (x + y) * np.float32(0.5)
    elif gradient_type == GRADIENT_RADIAL:
        f = np.arctan2(y, x) / _TWO_PI + np.float32(0.5)
    else:
        # 0.999999: a unit vector gives exactly 0, not a rounding residue
        r = max(np.float32(0.999999) - np.sqrt(x * x + y * y + z * z), zero)
        f = r * r if gradient_type == GRADIENT_QUADRATIC_SPHERE else r
    return min(max(f, zero), one)


# ------------------------------------------------------------------------------------------------ Voronoi
@jit
def _cell_point(dim, cx, cy, cz, cw):
    """The feature point of integer cell (cx, cy, cz, cw) in [0, 1]^dim: 1D hashes the cell's float, 2D-4D
    hash the integers (PCG)."""
    zero = np.float32(0.0)
    if dim == 1:
        return hash_float_to_float(np.float32(cx)), zero, zero, zero
    if dim == 2:
        hx, hy = _pcg2(cx, cy)
        return _int_to_unit(hx), _int_to_unit(hy), zero, zero
    if dim == 3:
        hx, hy, hz = _pcg3(cx, cy, cz)
        return _int_to_unit(hx), _int_to_unit(hy), _int_to_unit(hz), zero
    hx, hy, hz, hw = _pcg4(cx, cy, cz, cw)
    return _int_to_unit(hx), _int_to_unit(hy), _int_to_unit(hz), _int_to_unit(hw)


@jit
def _cell_color(dim, cx, cy, cz, cw):
    if dim == 1:
        c = np.float32(cx)
        return hash_float_to_float(c), hash_float2_to_float(c, np.float32(1.0)), hash_float2_to_float(c, np.float32(2.0))
    if dim == 2:
        hx, hy, hz = _pcg3(cx, cy, 0)
    elif dim == 3:
        hx, hy, hz = _pcg3(cx, cy, cz)
    else:
        hx, hy, hz, _ = _pcg4(cx, cy, cz, cw)
    return _int_to_unit(hx), _int_to_unit(hy), _int_to_unit(hz)


@jit
def _distance(dim, metric, exponent, dx, dy, dz, dw, bound):
    """Voronoi distance of the offset (dx..dw) (only the first dim components count). bound: a monotone stand-in
    (squared Euclidean, Minkowski without the root) for finding the nearest point, as Cycles' F1 does."""
    ax = abs(dx)
    if dim == 1:
        return ax
    ay = abs(dy)
    az = abs(dz) if dim >= 3 else np.float32(0.0)
    aw = abs(dw) if dim >= 4 else np.float32(0.0)
    if metric == METRIC_EUCLIDEAN:
        s = ax * ax + ay * ay
        if dim >= 3:
            s += az * az
        if dim >= 4:
            s += aw * aw
        return s if bound else np.sqrt(s)
    if metric == METRIC_MANHATTAN:
        s = ax + ay
        if dim >= 3:
            s += az
        if dim >= 4:
            s += aw
        return s
    if metric == METRIC_CHEBYCHEV:
        return max(max(ax, ay), max(az, aw))
    if metric == METRIC_MINKOWSKI:
        s = np.power(ax, exponent) + np.power(ay, exponent)
        if dim >= 3:
            s += np.power(az, exponent)
        if dim >= 4:
            s += np.power(aw, exponent)
        return s if bound else np.power(s, np.float32(1.0) / exponent)
    return np.float32(0.0)


@jit
def _ranges(dim, reach):
    """Cell offset ranges (x, y, z, w) for a search of +-reach cells in dim dimensions."""
    ry = reach if dim >= 2 else 0
    rz = reach if dim >= 3 else 0
    rw = reach if dim >= 4 else 0
    return reach, ry, rz, rw


@jit
def _voronoi_f1(dim, metric, exponent, randomness, x, y, z, w):
    fx, fy, fz, fw = _floor(x), _floor(y), _floor(z), _floor(w)
    lx, ly, lz, lw = x - fx, y - fy, z - fz, w - fw
    cx, cy, cz, cw = np.int64(fx), np.int64(fy), np.int64(fz), np.int64(fw)
    rx, ry, rz, rw = _ranges(dim, 1)
    best = _FLT_MAX
    ox = oy = oz = ow = 0
    px = py = pz = pw = np.float32(0.0)
    for u in range(-rw, rw + 1):
        for k in range(-rz, rz + 1):
            for j in range(-ry, ry + 1):
                for i in range(-rx, rx + 1):
                    hx, hy, hz, hw = _cell_point(dim, cx + i, cy + j, cz + k, cw + u)
                    qx = np.float32(i) + hx * randomness
                    qy = np.float32(j) + hy * randomness
                    qz = np.float32(k) + hz * randomness
                    qw = np.float32(u) + hw * randomness
                    d = _distance(dim, metric, exponent, qx - lx, qy - ly, qz - lz, qw - lw, True)
                    if d < best:
                        best = d
                        ox, oy, oz, ow = i, j, k, u
                        px, py, pz, pw = qx, qy, qz, qw
    dist = _distance(dim, metric, exponent, px - lx, py - ly, pz - lz, pw - lw, False)
    r, g, b = _cell_color(dim, cx + ox, cy + oy, cz + oz, cw + ow)
    return dist, r, g, b, px + fx, py + fy, pz + fz, pw + fw


@jit
def _smoothstep01(x):
    if x < np.float32(0.0):
        return np.float32(0.0)
    if x >= np.float32(1.0):
        return np.float32(1.0)
    return (np.float32(3.0) - np.float32(2.0) * x) * (x * x)


@jit
def _voronoi_smooth_f1(dim, metric, exponent, randomness, smoothness, x, y, z, w):
    fx, fy, fz, fw = _floor(x), _floor(y), _floor(z), _floor(w)
    lx, ly, lz, lw = x - fx, y - fy, z - fz, w - fw
    cx, cy, cz, cw = np.int64(fx), np.int64(fy), np.int64(fz), np.int64(fw)
    rx, ry, rz, rw = _ranges(dim, 2)
    zero = np.float32(0.0)
    one = np.float32(1.0)
    half = np.float32(0.5)
    sd = zero
    sr = sg = sb = zero
    spx = spy = spz = spw = zero
    h = -one
    for u in range(-rw, rw + 1):
        for k in range(-rz, rz + 1):
            for j in range(-ry, ry + 1):
                for i in range(-rx, rx + 1):
                    hx, hy, hz, hw = _cell_point(dim, cx + i, cy + j, cz + k, cw + u)
                    qx = np.float32(i) + hx * randomness
                    qy = np.float32(j) + hy * randomness
                    qz = np.float32(k) + hz * randomness
                    qw = np.float32(u) + hw * randomness
                    d = _distance(dim, metric, exponent, qx - lx, qy - ly, qz - lz, qw - lw, False)
                    if h == -one:
                        h = one
                    else:
                        h = _smoothstep01(half + half * (sd - d) / smoothness)
                    corr = smoothness * h * (one - h)
                    sd = _mix(sd, d, h) - corr
                    corr /= one + np.float32(3.0) * smoothness
                    r, g, b = _cell_color(dim, cx + i, cy + j, cz + k, cw + u)
                    sr = _mix(sr, r, h) - corr
                    sg = _mix(sg, g, h) - corr
                    sb = _mix(sb, b, h) - corr
                    spx = _mix(spx, qx, h) - corr
                    spy = _mix(spy, qy, h) - corr
                    spz = _mix(spz, qz, h) - corr
                    spw = _mix(spw, qw, h) - corr
    if dim < 4:
        spw = zero
    if dim < 3:
        spz = zero
    if dim < 2:
        spy = zero
    return sd, sr, sg, sb, fx + spx, fy + spy, fz + spz, fw + spw


@jit
def _voronoi_f2(dim, metric, exponent, randomness, x, y, z, w):
    fx, fy, fz, fw = _floor(x), _floor(y), _floor(z), _floor(w)
    lx, ly, lz, lw = x - fx, y - fy, z - fz, w - fw
    cx, cy, cz, cw = np.int64(fx), np.int64(fy), np.int64(fz), np.int64(fw)
    rx, ry, rz, rw = _ranges(dim, 1)
    d1 = _FLT_MAX
    d2 = _FLT_MAX
    o1x = o1y = o1z = o1w = 0
    o2x = o2y = o2z = o2w = 0
    zero = np.float32(0.0)
    p1x = p1y = p1z = p1w = zero
    p2x = p2y = p2z = p2w = zero
    for u in range(-rw, rw + 1):
        for k in range(-rz, rz + 1):
            for j in range(-ry, ry + 1):
                for i in range(-rx, rx + 1):
                    hx, hy, hz, hw = _cell_point(dim, cx + i, cy + j, cz + k, cw + u)
                    qx = np.float32(i) + hx * randomness
                    qy = np.float32(j) + hy * randomness
                    qz = np.float32(k) + hz * randomness
                    qw = np.float32(u) + hw * randomness
                    d = _distance(dim, metric, exponent, qx - lx, qy - ly, qz - lz, qw - lw, False)
                    if d < d1:
                        d2 = d1
                        d1 = d
                        o2x, o2y, o2z, o2w = o1x, o1y, o1z, o1w
                        o1x, o1y, o1z, o1w = i, j, k, u
                        p2x, p2y, p2z, p2w = p1x, p1y, p1z, p1w
                        p1x, p1y, p1z, p1w = qx, qy, qz, qw
                    elif d < d2:
                        d2 = d
                        o2x, o2y, o2z, o2w = i, j, k, u
                        p2x, p2y, p2z, p2w = qx, qy, qz, qw
    r, g, b = _cell_color(dim, cx + o2x, cy + o2y, cz + o2z, cw + o2w)
    return d2, r, g, b, p2x + fx, p2y + fy, p2z + fz, p2w + fw


@jit
def _voronoi_distance_to_edge(dim, randomness, x, y, z, w):
    fx, fy, fz, fw = _floor(x), _floor(y), _floor(z), _floor(w)
    lx, ly, lz, lw = x - fx, y - fy, z - fz, w - fw
    cx, cy, cz, cw = np.int64(fx), np.int64(fy), np.int64(fz), np.int64(fw)
    if dim == 1:
        mid = hash_float_to_float(fx) * randomness
        left = np.float32(-1.0) + hash_float_to_float(fx - np.float32(1.0)) * randomness
        right = np.float32(1.0) + hash_float_to_float(fx + np.float32(1.0)) * randomness
        two = np.float32(2.0)
        return min(abs((mid + left) / two - lx), abs((mid + right) / two - lx))
    rx, ry, rz, rw = _ranges(dim, 1)
    zero = np.float32(0.0)
    best = _FLT_MAX
    vx = vy = vz = vw = zero
    for u in range(-rw, rw + 1):
        for k in range(-rz, rz + 1):
            for j in range(-ry, ry + 1):
                for i in range(-rx, rx + 1):
                    hx, hy, hz, hw = _cell_point(dim, cx + i, cy + j, cz + k, cw + u)
                    tx = np.float32(i) + hx * randomness - lx
                    ty = np.float32(j) + hy * randomness - ly
                    tz = np.float32(k) + hz * randomness - lz if dim >= 3 else zero
                    tw = np.float32(u) + hw * randomness - lw if dim >= 4 else zero
                    d = tx * tx + ty * ty + tz * tz + tw * tw
                    if d < best:
                        best = d
                        vx, vy, vz, vw = tx, ty, tz, tw
    best = _FLT_MAX
    half = np.float32(0.5)
    for u in range(-rw, rw + 1):
        for k in range(-rz, rz + 1):
            for j in range(-ry, ry + 1):
                for i in range(-rx, rx + 1):
                    hx, hy, hz, hw = _cell_point(dim, cx + i, cy + j, cz + k, cw + u)
                    tx = np.float32(i) + hx * randomness - lx
                    ty = np.float32(j) + hy * randomness - ly
                    tz = np.float32(k) + hz * randomness - lz if dim >= 3 else zero
                    tw = np.float32(u) + hw * randomness - lw if dim >= 4 else zero
                    ex, ey, ez, ew = tx - vx, ty - vy, tz - vz, tw - vw
                    e2 = ex * ex + ey * ey + ez * ez + ew * ew
                    if e2 > np.float32(0.0001):
                        inv = np.float32(1.0) / np.sqrt(e2)
                        d = ((vx + tx) * half * ex + (vy + ty) * half * ey + (vz + tz) * half * ez
                             + (vw + tw) * half * ew) * inv
                        best = min(best, d)
    return best


@jit
def _voronoi_n_sphere_radius(dim, randomness, x, y, z, w):
    fx, fy, fz, fw = _floor(x), _floor(y), _floor(z), _floor(w)
    lx, ly, lz, lw = x - fx, y - fy, z - fz, w - fw
    cx, cy, cz, cw = np.int64(fx), np.int64(fy), np.int64(fz), np.int64(fw)
    rx, ry, rz, rw = _ranges(dim, 1)
    zero = np.float32(0.0)
    best = _FLT_MAX
    ox = oy = oz = ow = 0
    px = py = pz = pw = zero
    for u in range(-rw, rw + 1):
        for k in range(-rz, rz + 1):
            for j in range(-ry, ry + 1):
                for i in range(-rx, rx + 1):
                    hx, hy, hz, hw = _cell_point(dim, cx + i, cy + j, cz + k, cw + u)
                    qx = np.float32(i) + hx * randomness
                    qy = np.float32(j) + hy * randomness if dim >= 2 else zero
                    qz = np.float32(k) + hz * randomness if dim >= 3 else zero
                    qw = np.float32(u) + hw * randomness if dim >= 4 else zero
                    ex, ey = qx - lx, (qy - ly if dim >= 2 else zero)
                    ez, ew = (qz - lz if dim >= 3 else zero), (qw - lw if dim >= 4 else zero)
                    d = ex * ex + ey * ey + ez * ez + ew * ew
                    if d < best:
                        best = d
                        ox, oy, oz, ow = i, j, k, u
                        px, py, pz, pw = qx, qy, qz, qw
    best = _FLT_MAX
    nx = ny = nz = nw = zero
    for u in range(-rw, rw + 1):
        for k in range(-rz, rz + 1):
            for j in range(-ry, ry + 1):
                for i in range(-rx, rx + 1):
                    if i == 0 and j == 0 and k == 0 and u == 0:
                        continue
                    ai, aj, ak, au = i + ox, j + oy, k + oz, u + ow
                    hx, hy, hz, hw = _cell_point(dim, cx + ai, cy + aj, cz + ak, cw + au)
                    qx = np.float32(ai) + hx * randomness
                    qy = np.float32(aj) + hy * randomness if dim >= 2 else zero
                    qz = np.float32(ak) + hz * randomness if dim >= 3 else zero
                    qw = np.float32(au) + hw * randomness if dim >= 4 else zero
                    ex, ey, ez, ew = px - qx, py - qy, pz - qz, pw - qw
                    d = ex * ex + ey * ey + ez * ez + ew * ew
                    if d < best:
                        best = d
                        nx, ny, nz, nw = qx, qy, qz, qw
    ex, ey, ez, ew = nx - px, ny - py, nz - pz, nw - pw
    return np.sqrt(ex * ex + ey * ey + ez * ez + ew * ew) / np.float32(2.0)


@jit
def voronoi_texture(dim, x, y, z, w, scale, detail, roughness, lacunarity, smoothness, exponent, randomness, feature,
                    metric, normalize):
    """The Voronoi Texture node: (Distance, Color r, g, b, Position x, y, z, W, Radius). dim 1 reads w only,
    2 reads x, y, 3 reads x, y, z, 4 all four. Outputs a feature does not produce are 0, as in Blender."""
    zero = np.float32(0.0)
    one = np.float32(1.0)
    half = np.float32(0.5)
    detail = min(max(detail, zero), np.float32(15.0))
    roughness = min(max(roughness, zero), one)
    randomness = min(max(randomness, zero), one)
    smoothness = min(max(smoothness / np.float32(2.0), zero), half)
    x = x * scale
    y = y * scale
    z = z * scale
    w = w * scale
    if dim == 1:  # 1D Voronoi lives on W: move it into the first slot
        x = w
        y = zero
        z = zero
        w = zero
    m = half + half * randomness
    if feature == VORONOI_N_SPHERE_RADIUS:
        radius = _voronoi_n_sphere_radius(dim, randomness, x, y, z, w)
        return zero, zero, zero, zero, zero, zero, zero, zero, radius
    zero_input = detail == zero or roughness == zero
    if feature == VORONOI_DISTANCE_TO_EDGE:
        max_distance = m
        amplitude = one
        max_amplitude = max_distance
        octave_scale = one
        distance = np.float32(8.0)
        for i in range(int(np.ceil(detail)) + 1):
            od = _voronoi_distance_to_edge(dim, randomness, x * octave_scale, y * octave_scale, z * octave_scale,
                                           w * octave_scale)
            if zero_input:
                distance = od
                break
            if np.float32(i) <= detail:
                max_amplitude = _mix(max_amplitude, max_distance / octave_scale, amplitude)
                distance = _mix(distance, min(distance, od / octave_scale), amplitude)
                octave_scale *= lacunarity
                amplitude *= roughness
            else:
                rem = detail - np.floor(detail)
                if rem != zero:
                    lerp_amplitude = _mix(max_amplitude, max_distance / octave_scale, amplitude)
                    max_amplitude = _mix(max_amplitude, lerp_amplitude, rem)
                    lerp_distance = _mix(distance, min(distance, od / octave_scale), amplitude)
                    distance = _mix(distance, min(distance, lerp_distance), rem)
        if normalize:
            distance /= max_amplitude
        return distance, zero, zero, zero, zero, zero, zero, zero, zero
    f2_factor = np.float32(2.0) if feature == VORONOI_F2 else one
    max_distance = _distance(dim, metric, exponent, m, m, m, m, False) * f2_factor
    amplitude = one
    max_amplitude = zero
    octave_scale = one
    od_ = zero
    r_ = g_ = b_ = zero
    px_ = py_ = pz_ = pw_ = zero
    for i in range(int(np.ceil(detail)) + 1):
        sx, sy, sz, sw = x * octave_scale, y * octave_scale, z * octave_scale, w * octave_scale
        if feature == VORONOI_F2:
            d, r, g, b, px, py, pz, pw = _voronoi_f2(dim, metric, exponent, randomness, sx, sy, sz, sw)
        elif feature == VORONOI_SMOOTH_F1 and smoothness != zero:
            d, r, g, b, px, py, pz, pw = _voronoi_smooth_f1(dim, metric, exponent, randomness, smoothness,
                                                            sx, sy, sz, sw)
        else:
            d, r, g, b, px, py, pz, pw = _voronoi_f1(dim, metric, exponent, randomness, sx, sy, sz, sw)
        if zero_input:
            max_amplitude = one
            od_, r_, g_, b_ = d, r, g, b
            px_, py_, pz_, pw_ = px, py, pz, pw
            break
        if np.float32(i) <= detail:
            max_amplitude += amplitude
            od_ += d * amplitude
            r_ += r * amplitude
            g_ += g * amplitude
            b_ += b * amplitude
            px_ = _mix(px_, px / octave_scale, amplitude)
            py_ = _mix(py_, py / octave_scale, amplitude)
            pz_ = _mix(pz_, pz / octave_scale, amplitude)
            pw_ = _mix(pw_, pw / octave_scale, amplitude)
            octave_scale *= lacunarity
            amplitude *= roughness
        else:
            rem = detail - np.floor(detail)
            if rem != zero:
                max_amplitude = _mix(max_amplitude, max_amplitude + amplitude, rem)
                od_ = _mix(od_, od_ + d * amplitude, rem)
                r_ = _mix(r_, r_ + r * amplitude, rem)
                g_ = _mix(g_, g_ + g * amplitude, rem)
                b_ = _mix(b_, b_ + b * amplitude, rem)
                px_ = _mix(px_, _mix(px_, px / octave_scale, amplitude), rem)
                py_ = _mix(py_, _mix(py_, py / octave_scale, amplitude), rem)
                pz_ = _mix(pz_, _mix(pz_, pz / octave_scale, amplitude), rem)
                pw_ = _mix(pw_, _mix(pw_, pw / octave_scale, amplitude), rem)
    if normalize:
        od_ /= max_amplitude * max_distance
        r_ /= max_amplitude
        g_ /= max_amplitude
        b_ /= max_amplitude
    if scale != zero:
        px_ /= scale
        py_ /= scale
        pz_ /= scale
        pw_ /= scale
    else:
        px_ = py_ = pz_ = pw_ = zero
    if dim == 1:  # the 1D position is reported on W
        return od_, r_, g_, b_, zero, zero, zero, px_, zero
    if dim < 4:
        pw_ = zero
    if dim < 3:
        pz_ = zero
    return od_, r_, g_, b_, px_, py_, pz_, pw_, zero


# ------------------------------------------------------------------------------------------------ wave, magic, brick
@jit
def wave_texture(x, y, z, scale, distortion, detail, detail_scale, detail_roughness, phase, wave_type, direction,
                 profile):
    """The Wave Texture node's Fac (Color is Fac in all three channels). direction: 0 X, 1 Y, 2 Z, 3 diagonal
    (bands) or spherical (rings)."""
    eps = np.float32(0.000001)
    shrink = np.float32(0.999999)
    x = (x * scale + eps) * shrink
    y = (y * scale + eps) * shrink
    z = (z * scale + eps) * shrink
    if wave_type == WAVE_BANDS:
        if direction == 0:
            n = x * np.float32(20.0)
        elif direction == 1:
            n = y * np.float32(20.0)
        elif direction == 2:
            n = z * np.float32(20.0)
        else:
            n = (x + y + z) * np.float32(10.0)
    else:
        rx = np.float32(0.0) if direction == 0 else x
        ry = np.float32(0.0) if direction == 1 else y
        rz = np.float32(0.0) if direction == 2 else z
        n = np.sqrt(rx * rx + ry * ry + rz * rz) * np.float32(20.0)
    n += phase
    if distortion != np.float32(0.0):
        fbm = noise_fbm(3, x * detail_scale, y * detail_scale, z * detail_scale, np.float32(0.0), detail,
                        detail_roughness, np.float32(2.0), True)
        n += distortion * (fbm * np.float32(2.0) - np.float32(1.0))
    if profile == WAVE_SIN:
        return np.float32(0.5) + np.float32(0.5) * np.sin(n - _HALF_PI)
    n /= _TWO_PI
    if profile == WAVE_SAW:
        return n - np.floor(n)
    return abs(n - np.floor(n + np.float32(0.5))) * np.float32(2.0)


@jit
def magic_texture(x, y, z, scale, distortion, depth):
    """The Magic Texture node: (Fac, Color r, g, b); depth is the node's turbulence depth (0-10)."""
    # The coordinates wrap at 2 pi before the scale applies (Cycles: no NaN or banding from large values).
    px = np.fmod(x, _TWO_PI)
    py = np.fmod(y, _TWO_PI)
    pz = np.fmod(z, _TWO_PI)
    k = np.float32(5.0) * scale
    a = np.sin((px + py + pz) * k)
    b = np.cos((-px + py - pz) * k)
    c = -np.cos((-px - py + pz) * k)
    if depth > 0:
        a *= distortion
        b *= distortion
        c *= distortion
        b = -np.cos(a - b + c)
        b *= distortion
        if depth > 1:
            a = np.cos(a - b - c)
            a *= distortion
            if depth > 2:
                c = np.sin(-a - b - c)
                c *= distortion
                if depth > 3:
                    a = -np.cos(-a + b - c)
                    a *= distortion
                    if depth > 4:
                        b = -np.sin(-a + b + c)
                        b *= distortion
                        if depth > 5:
                            b = -np.cos(-a + b + c)
                            b *= distortion
                            if depth > 6:
                                a = np.cos(a + b + c)
                                a *= distortion
                                if depth > 7:
                                    c = np.sin(a + b - c)
                                    c *= distortion
                                    if depth > 8:
                                        a = -np.cos(-a - b + c)
                                        a *= distortion
                                        if depth > 9:
                                            b = -np.sin(a - b + c)
                                            b *= distortion
    if distortion != np.float32(0.0):
        d2 = distortion * np.float32(2.0)
        a /= d2
        b /= d2
        c /= d2
    half = np.float32(0.5)
    r, g, bl = half - a, half - b, half - c
    return (r + g + bl) * np.float32(1.0 / 3.0), r, g, bl


@jit
def _brick_noise(n):
    n = (n + 1013) & 0x7FFFFFFF
    n = (n >> 13) ^ n
    t = (n * n) & _M32
    t = (t * 60493 + 19990303) & _M32
    nn = (n * t + 1376312589) & 0x7FFFFFFF
    return np.float32(0.5) * (np.float32(nn) / np.float32(1073741824.0))


@jit
def _smoothstepf(f):
    if f <= np.float32(0.0):
        return np.float32(0.0)
    if f >= np.float32(1.0):
        return np.float32(1.0)
    ff = f * f
    return np.float32(3.0) * ff - np.float32(2.0) * ff * f


@jit
def brick_texture(x, y, scale, mortar_size, mortar_smooth, bias, brick_width, row_height, offset_amount,
                  offset_frequency, squash_amount, squash_frequency):
    """The Brick Texture node: (Fac = mortar amount, tint of the brick in [0, 1]). Color = mix(Color1, Color2,
    tint) where Fac != 1, then mixed with Mortar by Fac (see brick_color)."""
    px = x * scale
    py = y * scale
    rownum = np.int64(np.floor(py / row_height))
    offset = np.float32(0.0)
    if offset_frequency != 0 and squash_frequency != 0:
        if rownum % squash_frequency == 0:
            brick_width *= squash_amount
        if rownum % offset_frequency == 0:
            offset = brick_width * offset_amount
    bricknum = np.int64(np.floor((px + offset) / brick_width))
    bx = (px + offset) - brick_width * np.float32(bricknum)
    by = py - row_height * np.float32(rownum)
    tint = _brick_noise(((rownum << 16) + (bricknum & 0xFFFF)) & _M32) + bias
    tint = min(max(tint, np.float32(0.0)), np.float32(1.0))
    min_dist = min(min(bx, by), min(brick_width - bx, row_height - by))
    if min_dist >= mortar_size:
        mortar = np.float32(0.0)
    elif mortar_smooth == np.float32(0.0):
        mortar = np.float32(1.0)
    else:
        mortar = _smoothstepf((np.float32(1.0) - min_dist / mortar_size) / mortar_smooth)
    return mortar, tint


@jit
def brick_color(fac, tint, c1, c2, mortar):
    """One channel of the Brick Texture's Color from its Fac and tint."""
    if fac != np.float32(1.0):
        c1 = (np.float32(1.0) - tint) * c1 + tint * c2
    return c1 * (np.float32(1.0) - fac) + mortar * fac


@jit
def checker_color(fac, c1, c2):
    """One channel of the Checker Texture's Color."""
    return c1 if fac == np.float32(1.0) else c2


# ------------------------------------------------------------------------------------------------ Gabor
_PI = np.float32(math.pi)
_GABOR_IMPULSES = 8
# Normalisation: 6 x the standard deviation sqrt(impulses x 0.5 x integral of the squared kernel), the integral
# 1/4 in 2D and 1/(4 sqrt 2) in 3D (Cycles' values).
_GABOR_NORM_2D = np.float32(6.0) * np.sqrt(np.float32(_GABOR_IMPULSES * 0.5 * 0.25))
_GABOR_NORM_3D = np.float32(6.0) * np.sqrt(np.float32(_GABOR_IMPULSES * 0.5) * (np.float32(1.0) / (
    np.float32(4.0) * np.float32(math.sqrt(2.0)))))


@jit
def _gabor_kernel(d2, phase_arg):
    """The Hann-windowed Gaussian times the phasor exp(i 2 pi <p, f>): (real, imaginary)."""
    hann = np.float32(0.5) + np.float32(0.5) * np.cos(_PI * d2)
    env = np.exp(-_PI * d2) * hann
    angle = np.float32(2.0) * _PI * phase_arg
    return env * np.cos(angle), env * np.sin(angle)


@jit
def _gabor_2d(x, y, frequency, isotropy, orientation):
    cx, cy = np.floor(x), np.floor(y)
    lx, ly = x - cx, y - cy
    re = np.float32(0.0)
    im = np.float32(0.0)
    for j in range(-1, 2):
        for i in range(-1, 2):
            gx, gy = cx + np.float32(i), cy + np.float32(j)
            px, py = lx - np.float32(i), ly - np.float32(j)
            for n in range(_GABOR_IMPULSES):
                s0, s1, s2 = np.float32(n * 3), np.float32(n * 3 + 1), np.float32(n * 3 + 2)
                rnd = (hash_float3_to_float(gx, gy, s0) - np.float32(0.5)) * _PI
                ori = orientation + rnd * isotropy
                kx = px - hash_float3_to_float(gx, gy, s1)
                ky = py - hash_float3_to_float(s1, gx, gy)
                d2 = kx * kx + ky * ky
                if d2 >= np.float32(1.0):
                    continue
                weight = np.float32(-1.0) if hash_float3_to_float(gx, gy, s2) < np.float32(0.5) else np.float32(1.0)
                fx = frequency * np.cos(ori)
                fy = frequency * np.sin(ori)
                kr, ki = _gabor_kernel(d2, kx * fx + ky * fy)
                re += weight * kr
                im += weight * ki
    return re, im


@jit
def _gabor_3d(x, y, z, frequency, isotropy, ox, oy, oz):
    cx, cy, cz = np.floor(x), np.floor(y), np.floor(z)
    lx, ly, lz = x - cx, y - cy, z - cz
    re = np.float32(0.0)
    im = np.float32(0.0)
    if isotropy != np.float32(0.0):
        inclination0 = np.arccos(oz)
        azimuth0 = (np.float32(-1.0) if oy < np.float32(0.0) else np.float32(1.0)) * np.arccos(
            ox / np.sqrt(ox * ox + oy * oy))
    else:
        inclination0 = np.float32(0.0)
        azimuth0 = np.float32(0.0)
    for k in range(-1, 2):
        for j in range(-1, 2):
            for i in range(-1, 2):
                gx, gy, gz = cx + np.float32(i), cy + np.float32(j), cz + np.float32(k)
                px, py, pz = lx - np.float32(i), ly - np.float32(j), lz - np.float32(k)
                for n in range(_GABOR_IMPULSES):
                    s0, s1, s2 = np.float32(n * 3), np.float32(n * 3 + 1), np.float32(n * 3 + 2)
                    if isotropy == np.float32(0.0):
                        fx, fy, fz = ox, oy, oz
                    else:
                        incl = inclination0 + hash_float4_to_float(gx, gy, gz, s0) * _PI * isotropy
                        azim = azimuth0 + hash_float4_to_float(gz, gx, s0, gy) * _PI * isotropy
                        st = np.sin(incl)
                        fx, fy, fz = st * np.cos(azim), st * np.sin(azim), np.cos(incl)
                    kx = px - hash_float4_to_float(gx, gy, gz, s1)
                    ky = py - hash_float4_to_float(gz, gx, s1, gy)
                    kz = pz - hash_float4_to_float(s1, gz, gy, gx)
                    d2 = kx * kx + ky * ky + kz * kz
                    if d2 >= np.float32(1.0):
                        continue
                    weight = (np.float32(-1.0) if hash_float4_to_float(gx, gy, gz, s2) < np.float32(0.5)
                              else np.float32(1.0))
                    kr, ki = _gabor_kernel(d2, kx * (frequency * fx) + ky * (frequency * fy) + kz * (frequency * fz))
                    re += weight * kr
                    im += weight * ki
    return re, im


@jit
def gabor_texture(gabor_type, x, y, z, scale, frequency, anisotropy, orientation, ox, oy, oz):
    """The Gabor Texture node (Blender 4.3+): (Value, Phase, Intensity). gabor_type 2 or 3 (dimensions);
    orientation: the 2D angle in radians; (ox, oy, oz) the 3D direction (normalized here)."""
    x = x * scale
    y = y * scale
    z = z * scale
    isotropy = np.float32(1.0) - min(max(anisotropy, np.float32(0.0)), np.float32(1.0))
    frequency = max(np.float32(0.001), frequency)
    if gabor_type == 2:
        re, im = _gabor_2d(x, y, frequency, isotropy, orientation)
        norm = _GABOR_NORM_2D
    else:
        inv = np.float32(1.0) / np.sqrt(ox * ox + oy * oy + oz * oz)
        re, im = _gabor_3d(x, y, z, frequency, isotropy, ox * inv, oy * inv, oz * inv)
        norm = _GABOR_NORM_3D
    value = (im / norm) * np.float32(0.5) + np.float32(0.5)
    phase = (np.arctan2(im, re) + _PI) / (np.float32(2.0) * _PI)
    intensity = np.sqrt(re * re + im * im) / norm
    return value, phase, intensity


# ------------------------------------------------------------------------------------------------ batches
@jit
def _white_noise_batch(dim, co, fac, color):
    for n in range(co.shape[0]):
        v, r, g, b = white_noise_texture(dim, co[n, 0], co[n, 1], co[n, 2], co[n, 3])
        fac[n] = v
        color[n, 0] = r
        color[n, 1] = g
        color[n, 2] = b


@jit
def _noise_batch(dim, co, scale, detail, roughness, lacunarity, offset, gain, distortion, noise_type, normalize,
                 fac, color):
    for n in range(co.shape[0]):
        v, r, g, b = noise_texture(dim, co[n, 0], co[n, 1], co[n, 2], co[n, 3], scale, detail, roughness, lacunarity,
                                   offset, gain, distortion, noise_type, normalize, True)
        fac[n] = v
        color[n, 0] = r
        color[n, 1] = g
        color[n, 2] = b


@jit
def _voronoi_batch(dim, co, scale, detail, roughness, lacunarity, smoothness, exponent, randomness, feature, metric,
                   normalize, distance, color, position, w_out, radius):
    for n in range(co.shape[0]):
        d, r, g, b, px, py, pz, pw, rad = voronoi_texture(dim, co[n, 0], co[n, 1], co[n, 2], co[n, 3], scale, detail,
                                                          roughness, lacunarity, smoothness, exponent, randomness,
                                                          feature, metric, normalize)
        distance[n] = d
        color[n, 0] = r
        color[n, 1] = g
        color[n, 2] = b
        position[n, 0] = px
        position[n, 1] = py
        position[n, 2] = pz
        w_out[n] = pw
        radius[n] = rad


@jit
def _checker_batch(co, scale, fac):
    for n in range(co.shape[0]):
        fac[n] = checker_texture(co[n, 0], co[n, 1], co[n, 2], scale)


@jit
def _gradient_batch(co, gradient_type, fac):
    for n in range(co.shape[0]):
        fac[n] = gradient_texture(co[n, 0], co[n, 1], co[n, 2], gradient_type)


@jit
def _wave_batch(co, scale, distortion, detail, detail_scale, detail_roughness, phase, wave_type, direction, profile,
                fac):
    for n in range(co.shape[0]):
        fac[n] = wave_texture(co[n, 0], co[n, 1], co[n, 2], scale, distortion, detail, detail_scale,
                              detail_roughness, phase, wave_type, direction, profile)


@jit
def _magic_batch(co, scale, distortion, depth, fac, color):
    for n in range(co.shape[0]):
        v, r, g, b = magic_texture(co[n, 0], co[n, 1], co[n, 2], scale, distortion, depth)
        fac[n] = v
        color[n, 0] = r
        color[n, 1] = g
        color[n, 2] = b


@jit
def _brick_batch(co, scale, mortar_size, mortar_smooth, bias, brick_width, row_height, offset_amount, offset_frequency,
                 squash_amount, squash_frequency, fac, tint):
    for n in range(co.shape[0]):
        f, t = brick_texture(co[n, 0], co[n, 1], scale, mortar_size, mortar_smooth, bias, brick_width, row_height,
                             offset_amount, offset_frequency, squash_amount, squash_frequency)
        fac[n] = f
        tint[n] = t


@jit
def _gabor_batch(gabor_type, co, scale, frequency, anisotropy, orientation, ox, oy, oz, value, phase, intensity):
    for n in range(co.shape[0]):
        v, p, i = gabor_texture(gabor_type, co[n, 0], co[n, 1], co[n, 2], scale, frequency, anisotropy, orientation,
                                ox, oy, oz)
        value[n] = v
        phase[n] = p
        intensity[n] = i


def _coords(coords: np.ndarray) -> np.ndarray:
    """(N, 3) or (N, 4) coordinates -> contiguous float32 (N, 4), W = 0 where absent."""
    co = np.asarray(coords)
    if co.ndim != 2 or co.shape[1] not in (3, 4):
        raise ValueError(f"texture coordinates must have shape (N, 3) or (N, 4) (x, y, z[, w]), not {co.shape}")
    if not np.issubdtype(co.dtype, np.floating):
        raise ValueError(f"texture coordinates must be floating point, not {co.dtype}")
    out = np.zeros((co.shape[0], 4), np.float32)
    out[:, :co.shape[1]] = co
    return out


def _dimensions(dimensions: int) -> int:
    if dimensions not in (1, 2, 3, 4):
        raise ValueError(f"texture dimensions must be 1, 2, 3 or 4, not {dimensions!r}")
    return int(dimensions)


def _enum(value, table: dict, what: str) -> int:
    if isinstance(value, str):
        if value not in table:
            raise ValueError(f"unknown {what} {value!r}; expected one of {', '.join(table)}")
        return table[value]
    if int(value) not in table.values():
        raise ValueError(f"unknown {what} {value!r}; expected one of {', '.join(table)}")
    return int(value)


def white_noise(coords: np.ndarray, dimensions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """White Noise Texture over (N, 3|4) coordinates (x, y, z[, W]): (Value (N,), Color (N, 3)), float32."""
    co = _coords(coords)
    fac = np.empty(len(co), np.float32)
    color = np.empty((len(co), 3), np.float32)
    _white_noise_batch(_dimensions(dimensions), co, fac, color)
    return fac, color


def noise(coords: np.ndarray, dimensions: int = 3, scale: float = 5.0, detail: float = 2.0, roughness: float = 0.5,
          lacunarity: float = 2.0, offset: float = 0.0, gain: float = 1.0, distortion: float = 0.0,
          noise_type: str | int = "FBM", normalize: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Noise Texture (defaults as Blender's node): (Fac (N,), Color (N, 3)), float32."""
    co = _coords(coords)
    fac = np.empty(len(co), np.float32)
    color = np.empty((len(co), 3), np.float32)
    _noise_batch(_dimensions(dimensions), co, f32(scale), f32(detail), f32(roughness), f32(lacunarity), f32(offset),
                 f32(gain), f32(distortion), _enum(noise_type, NOISE_TYPES, "noise type"), bool(normalize), fac, color)
    return fac, color


def voronoi(coords: np.ndarray, dimensions: int = 3, scale: float = 5.0, detail: float = 0.0, roughness: float = 0.5,
            lacunarity: float = 2.0, smoothness: float = 1.0, exponent: float = 0.5, randomness: float = 1.0,
            feature: str | int = "F1", distance: str | int = "EUCLIDEAN", normalize: bool = False) -> dict:
    """Voronoi Texture (defaults as Blender's node): a dict of float32 outputs "Distance" (N,), "Color" (N, 3),
    "Position" (N, 3), "W" (N,), "Radius" (N,)."""
    co = _coords(coords)
    n = len(co)
    out = {"Distance": np.empty(n, np.float32), "Color": np.empty((n, 3), np.float32),
           "Position": np.empty((n, 3), np.float32), "W": np.empty(n, np.float32), "Radius": np.empty(n, np.float32)}
    _voronoi_batch(_dimensions(dimensions), co, f32(scale), f32(detail), f32(roughness), f32(lacunarity),
                   f32(smoothness), f32(exponent), f32(randomness), _enum(feature, VORONOI_FEATURES, "Voronoi feature"),
                   _enum(distance, VORONOI_METRICS, "Voronoi distance metric"), bool(normalize), out["Distance"],
                   out["Color"], out["Position"], out["W"], out["Radius"])
    return out


GABOR_TYPES = {"2D": 2, "3D": 3}


def gabor(coords: np.ndarray, gabor_type: str | int = "2D", scale: float = 5.0, frequency: float = 2.0,
          anisotropy: float = 1.0, orientation: float = math.pi / 4,
          orientation_3d=(math.sqrt(2.0), math.sqrt(2.0), 0.0)) -> dict:
    """Gabor Texture (defaults as Blender's node): float32 "Value", "Phase", "Intensity" (N,)."""
    co = _coords(coords)
    gt = _enum(gabor_type, GABOR_TYPES, "Gabor type")
    o = np.asarray(orientation_3d, np.float32).reshape(3)
    n = len(co)
    out = {"Value": np.empty(n, np.float32), "Phase": np.empty(n, np.float32), "Intensity": np.empty(n, np.float32)}
    _gabor_batch(gt, co, f32(scale), f32(frequency), f32(anisotropy), f32(orientation), o[0], o[1], o[2],
                 out["Value"], out["Phase"], out["Intensity"])
    return out


def checker(coords: np.ndarray, scale: float = 5.0, color1=(0.8, 0.8, 0.8), color2=(0.2, 0.2, 0.2)
            ) -> tuple[np.ndarray, np.ndarray]:
    """Checker Texture: (Fac (N,), Color (N, 3)), float32."""
    co = _coords(coords)
    fac = np.empty(len(co), np.float32)
    _checker_batch(co, f32(scale), fac)
    color = np.where(fac[:, None] == 1.0, np.asarray(color1, np.float32)[:3], np.asarray(color2, np.float32)[:3])
    return fac, color.astype(np.float32)


def gradient(coords: np.ndarray, gradient_type: str | int = "LINEAR") -> np.ndarray:
    """Gradient Texture's Fac (N,) float32 (its Color is Fac in every channel)."""
    co = _coords(coords)
    fac = np.empty(len(co), np.float32)
    _gradient_batch(co, _enum(gradient_type, GRADIENT_TYPES, "gradient type"), fac)
    return fac


def wave(coords: np.ndarray, scale: float = 5.0, distortion: float = 0.0, detail: float = 2.0,
         detail_scale: float = 1.0, detail_roughness: float = 0.5, phase_offset: float = 0.0,
         wave_type: str | int = "BANDS", direction: str | int = "X", profile: str | int = "SIN") -> np.ndarray:
    """Wave Texture's Fac (N,) float32 (Color is Fac in every channel). direction: bands X/Y/Z/DIAGONAL or
    rings X/Y/Z/SPHERICAL, as the wave type."""
    co = _coords(coords)
    wt = _enum(wave_type, WAVE_TYPES, "wave type")
    directions = WAVE_BANDS_DIRECTIONS if wt == WAVE_BANDS else WAVE_RINGS_DIRECTIONS
    fac = np.empty(len(co), np.float32)
    _wave_batch(co, f32(scale), f32(distortion), f32(detail), f32(detail_scale), f32(detail_roughness),
                f32(phase_offset), wt, _enum(direction, directions, "wave direction"),
                _enum(profile, WAVE_PROFILES, "wave profile"), fac)
    return fac


def magic(coords: np.ndarray, scale: float = 5.0, distortion: float = 1.0, depth: int = 2
          ) -> tuple[np.ndarray, np.ndarray]:
    """Magic Texture: (Fac (N,), Color (N, 3)) float32; depth 0-10 as Blender's turbulence depth."""
    if not 0 <= int(depth) <= 10:
        raise ValueError(f"Magic texture depth must be 0-10, not {depth}")
    co = _coords(coords)
    fac = np.empty(len(co), np.float32)
    color = np.empty((len(co), 3), np.float32)
    _magic_batch(co, f32(scale), f32(distortion), int(depth), fac, color)
    return fac, color


def brick(coords: np.ndarray, scale: float = 5.0, mortar_size: float = 0.02, mortar_smooth: float = 0.1,
          bias: float = 0.0, brick_width: float = 0.5, row_height: float = 0.25, offset: float = 0.5,
          offset_frequency: int = 2, squash: float = 1.0, squash_frequency: int = 2, color1=(0.8, 0.8, 0.8),
          color2=(0.2, 0.2, 0.2), mortar=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Brick Texture (defaults as Blender's node): (Fac (N,), Color (N, 3)) float32."""
    co = _coords(coords)
    fac = np.empty(len(co), np.float32)
    tint = np.empty(len(co), np.float32)
    _brick_batch(co, f32(scale), f32(mortar_size), f32(mortar_smooth), f32(bias), f32(brick_width), f32(row_height),
                 f32(offset), int(offset_frequency), f32(squash), int(squash_frequency), fac, tint)
    c1 = np.asarray(color1, np.float32)[:3]
    c2 = np.asarray(color2, np.float32)[:3]
    m = np.asarray(mortar, np.float32)[:3]
    base = np.where((fac != 1.0)[:, None], (1.0 - tint[:, None]) * c1 + tint[:, None] * c2, c1)
    color = base * (1.0 - fac[:, None]) + m * fac[:, None]
    return fac, color.astype(np.float32)


# ------------------------------------------------------------------------------------------------ shading program
# Opcodes 400..599 (core.shading.registry's procedural family). Float inputs are registers (component 0);
# enums and flags pack into one "int" operand; per-node float settings that are not sockets go in the data pool.
def _ops(kind, *names):
    return tuple((n, kind) for n in names)


def pack_flags(*fields: int) -> int:
    """Several small enums in one int operand, 4 bits each, first field lowest."""
    v = 0
    for i, f in enumerate(fields):
        if not 0 <= int(f) < 16:
            raise ValueError(f"flag field {i} = {f} does not fit in 4 bits")
        v |= int(f) << (4 * i)
    return v


OP_WHITE_NOISE = R.register(R.OpSpec(
    "tex_white_noise", R.PROCEDURAL_BASE + 0, _ops("out?", "value", "color") + _ops("in", "vector", "w")
    + _ops("int", "dimensions"), "White Noise Texture: hashes of the coordinates (1D: W; 4D: vector and W)")).code
OP_CHECKER = R.register(R.OpSpec(
    "tex_checker", R.PROCEDURAL_BASE + 1, _ops("out?", "color", "fac")
    + _ops("in", "vector", "color1", "color2", "scale"), "Checker Texture")).code
OP_GRADIENT = R.register(R.OpSpec(
    "tex_gradient", R.PROCEDURAL_BASE + 2, _ops("out?", "color", "fac") + _ops("in", "vector")
    + _ops("int", "gradient_type"), "Gradient Texture; gradient_type: procedural.GRADIENT_TYPES")).code
OP_NOISE = R.register(R.OpSpec(
    "tex_noise", R.PROCEDURAL_BASE + 3, _ops("out?", "fac", "color")
    + _ops("in", "vector", "w", "scale", "detail", "roughness", "lacunarity", "offset", "gain", "distortion")
    + _ops("int", "flags"), "Noise Texture; flags = pack_flags(dimensions, noise type, normalize)")).code
OP_VORONOI = R.register(R.OpSpec(
    "tex_voronoi", R.PROCEDURAL_BASE + 4, _ops("out?", "distance", "color", "position", "w_out", "radius")
    + _ops("in", "vector", "w", "scale", "detail", "roughness", "lacunarity", "smoothness", "exponent",
           "randomness") + _ops("int", "flags"),
    "Voronoi Texture; flags = pack_flags(dimensions, feature, metric, normalize)")).code
OP_WAVE = R.register(R.OpSpec(
    "tex_wave", R.PROCEDURAL_BASE + 5, _ops("out?", "color", "fac")
    + _ops("in", "vector", "scale", "distortion", "detail", "detail_scale", "detail_roughness", "phase")
    + _ops("int", "flags"), "Wave Texture; flags = pack_flags(wave type, direction, profile)")).code
OP_MAGIC = R.register(R.OpSpec(
    "tex_magic", R.PROCEDURAL_BASE + 6, _ops("out?", "color", "fac") + _ops("in", "vector", "scale", "distortion")
    + _ops("int", "depth"), "Magic Texture; depth 0-10")).code
OP_BRICK = R.register(R.OpSpec(
    "tex_brick", R.PROCEDURAL_BASE + 7, _ops("out?", "color", "fac")
    + _ops("in", "vector", "color1", "color2", "mortar", "scale", "mortar_size", "mortar_smooth", "bias",
           "brick_width", "row_height") + _ops("int", "frequencies") + _ops("data", "params"),
    "Brick Texture; frequencies = pack_flags(offset frequency, squash frequency) (1-15); data: offset, "
    "squash")).code


OP_GABOR = R.register(R.OpSpec(
    "tex_gabor", R.PROCEDURAL_BASE + 8, _ops("out?", "value", "phase", "intensity")
    + _ops("in", "vector", "scale", "frequency", "anisotropy", "orientation", "orientation_3d")
    + _ops("int", "gabor_type"), "Gabor Texture; gabor_type 2 or 3 (dimensions)")).code


@jit_inline
def noise_op(a, regs):
    """The Noise Texture instruction (OP_NOISE). core.shading.evaluator.run_point calls it directly: through
    `run`, whose body holds every texture, the same instruction cost ~20 ns more (~110 against ~90 ns in a
    micro-benchmark on the textured scene's floor points)."""
    flags = a[12]
    v, r, g, b = noise_texture(flags & 15, regs[a[3], 0], regs[a[3], 1], regs[a[3], 2], regs[a[4], 0],
                               regs[a[5], 0], regs[a[6], 0], regs[a[7], 0], regs[a[8], 0], regs[a[9], 0],
                               regs[a[10], 0], regs[a[11], 0], (flags >> 4) & 15, ((flags >> 8) & 15) != 0,
                               a[2] >= 0)
    setf(regs, a[1], v)
    set3(regs, a[2], r, g, b)


@jit
def run(op, a, regs, data):
    """One procedural-texture instruction of a shading program (see the OpSpecs above for the slots)."""
    if op == OP_NOISE:
        noise_op(a, regs)
    elif op == OP_VORONOI:
        flags = a[15]
        d, r, g, b, px, py, pz, pw, rad = voronoi_texture(
            flags & 15, regs[a[6], 0], regs[a[6], 1], regs[a[6], 2], regs[a[7], 0], regs[a[8], 0], regs[a[9], 0],
            regs[a[10], 0], regs[a[11], 0], regs[a[12], 0], regs[a[13], 0], regs[a[14], 0], (flags >> 4) & 15,
            (flags >> 8) & 15, ((flags >> 12) & 15) != 0)
        setf(regs, a[1], d)
        set3(regs, a[2], r, g, b)
        set3(regs, a[3], px, py, pz)
        setf(regs, a[4], pw)
        setf(regs, a[5], rad)
    elif op == OP_WHITE_NOISE:
        v, r, g, b = white_noise_texture(a[5], regs[a[3], 0], regs[a[3], 1], regs[a[3], 2], regs[a[4], 0])
        setf(regs, a[1], v)
        set3(regs, a[2], r, g, b)
    elif op == OP_CHECKER:
        f = checker_texture(regs[a[3], 0], regs[a[3], 1], regs[a[3], 2], regs[a[6], 0])
        set3(regs, a[1], checker_color(f, regs[a[4], 0], regs[a[5], 0]), checker_color(f, regs[a[4], 1], regs[a[5], 1]),
              checker_color(f, regs[a[4], 2], regs[a[5], 2]))
        setf(regs, a[2], f)
    elif op == OP_GRADIENT:
        f = gradient_texture(regs[a[3], 0], regs[a[3], 1], regs[a[3], 2], a[4])
        setf(regs, a[1], f)
        setf(regs, a[2], f)
    elif op == OP_WAVE:
        flags = a[10]
        f = wave_texture(regs[a[3], 0], regs[a[3], 1], regs[a[3], 2], regs[a[4], 0], regs[a[5], 0], regs[a[6], 0],
                         regs[a[7], 0], regs[a[8], 0], regs[a[9], 0], flags & 15, (flags >> 4) & 15,
                         (flags >> 8) & 15)
        setf(regs, a[1], f)
        setf(regs, a[2], f)
    elif op == OP_MAGIC:
        f, r, g, b = magic_texture(regs[a[3], 0], regs[a[3], 1], regs[a[3], 2], regs[a[4], 0], regs[a[5], 0], a[6])
        set3(regs, a[1], r, g, b)
        setf(regs, a[2], f)
    elif op == OP_GABOR:
        v, ph, inten = gabor_texture(a[10], regs[a[4], 0], regs[a[4], 1], regs[a[4], 2], regs[a[5], 0],
                                     regs[a[6], 0], regs[a[7], 0], regs[a[8], 0], regs[a[9], 0], regs[a[9], 1],
                                     regs[a[9], 2])
        setf(regs, a[1], v)
        setf(regs, a[2], ph)
        setf(regs, a[3], inten)
    elif op == OP_BRICK:
        freq = a[13]
        f, tint = brick_texture(regs[a[3], 0], regs[a[3], 1], regs[a[7], 0], regs[a[8], 0], regs[a[9], 0],
                                regs[a[10], 0], regs[a[11], 0], regs[a[12], 0], data[a[14]], freq & 15,
                                data[a[14] + 1], (freq >> 4) & 15)
        set3(regs, a[1], brick_color(f, tint, regs[a[4], 0], regs[a[5], 0], regs[a[6], 0]),
              brick_color(f, tint, regs[a[4], 1], regs[a[5], 1], regs[a[6], 1]),
              brick_color(f, tint, regs[a[4], 2], regs[a[5], 2], regs[a[6], 2]))
        setf(regs, a[2], f)
