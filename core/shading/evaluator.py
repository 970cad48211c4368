"""The compiled evaluator of shading programs (core.shading.program) and its Python face, `PreparedShading`.

`run_programs` runs each shading point's material program: it loads the program's initial registers into a
scratch register file, executes the instructions in order (`_execute` dispatches on the opcode family: core
opcodes here, colour nodes in core.shading.color, procedural textures in core.shading.procedural), then writes
the bound registers over the point's lobe parameters and emission. Arithmetic of the node functions is float64
(registers are float32), following Cycles' SVM semantics (safe division, roots, logarithms, as named per op).
"""

from __future__ import annotations

import math

import numpy as np

from .. import bsdf_kernels as bk
from .. import microfacet as mf
from ..jit_cache import jit_inline as _jit_inline
from ..jit_cache import jit_no_nrt as _jit
from . import color
from . import registry as R
from . import procedural
from .regs import get3, set3, setf  # noqa: F401  (re-exported for node modules)
from .program import (BIND_F0, BIND_IOR, BIND_ROUGHNESS, BIND_TINT_R, BIND_TINT_T, BIND_WEIGHT, N_BIND,
                      OBJECT_BOX_MIN, OBJECT_BOX_SIZE, OBJECT_COLOR, OBJECT_INVERSE, OBJECT_LOCATION,
                      OBJECT_PASS_INDEX, OBJECT_RANDOM, WIDTH, ShadingProgram, identity_object_row,
                      ATTRIBUTE_COLUMNS, PATH_COLUMNS, RAY_CAMERA, RAY_SHADOW, RAY_DIFFUSE, RAY_GLOSSY, RAY_SINGULAR,
                      RAY_REFLECT, RAY_TRANSMIT, CAMERA_FRAME, CAMERA_KIND, CAMERA_ORTHO, CAMERA_PANO)

# Blender's enum identifiers in the order of the evaluator's operation numbers (the compiler maps names to these).
MATH_OPS = ("ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "MULTIPLY_ADD", "POWER", "LOGARITHM", "SQRT", "INVERSE_SQRT",
            "ABSOLUTE", "EXPONENT", "MINIMUM", "MAXIMUM", "LESS_THAN", "GREATER_THAN", "SIGN", "COMPARE",
            "SMOOTH_MIN", "SMOOTH_MAX", "ROUND", "FLOOR", "CEIL", "TRUNC", "FRACT", "MODULO", "FLOORED_MODULO",
            "WRAP", "SNAP", "PINGPONG", "SINE", "COSINE", "TANGENT", "ARCSINE", "ARCCOSINE", "ARCTANGENT",
            "ARCTAN2", "SINH", "COSH", "TANH", "RADIANS", "DEGREES")
VECTOR_MATH_OPS = ("ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "MULTIPLY_ADD", "CROSS_PRODUCT", "PROJECT", "REFLECT",
                   "REFRACT", "FACEFORWARD", "DOT_PRODUCT", "DISTANCE", "LENGTH", "SCALE", "NORMALIZE", "SNAP",
                   "FLOOR", "CEIL", "MODULO", "WRAP", "FRACTION", "ABSOLUTE", "MINIMUM", "MAXIMUM", "SINE",
                   "COSINE", "TANGENT", "POWER", "SIGN")
# Vector Math operations whose result is the Value output (the Vector output is then 0).
VECTOR_MATH_VALUE_OPS = ("DOT_PRODUCT", "DISTANCE", "LENGTH")

_OP_CONST = {name: spec.code for name, spec in R.OPS_BY_NAME.items()}
_COPY, _F2V, _C2F, _V2F = R.OP_COPY, R.OP_FLOAT_TO_VEC, R.OP_COLOR_TO_FLOAT, R.OP_VEC_TO_FLOAT
_MATH, _VMATH, _MAPRANGE, _CLAMP = R.OP_MATH, R.OP_VECTOR_MATH, R.OP_MAP_RANGE, R.OP_CLAMP
_SEPXYZ, _COMBXYZ, _MAPPING, _MIX = R.OP_SEPARATE_XYZ, R.OP_COMBINE_XYZ, R.OP_MAPPING, R.OP_MIX
_FRESNEL, _LAYER = R.OP_FRESNEL, R.OP_LAYER_WEIGHT
_TEXCO, _GEOM, _OBJINFO, _IMAGE = R.OP_TEXCOORD, R.OP_GEOMETRY, R.OP_OBJECT_INFO, R.OP_IMAGE
_UVLAYER, _ATTR, _LIGHTPATH = R.OP_UV_LAYER, R.OP_ATTRIBUTE, R.OP_LIGHT_PATH
_NORMAL_MAP, _BUMP_OP, _VTRANSFORM, _TANGENT = R.OP_NORMAL_MAP, R.OP_BUMP, R.OP_VECTOR_TRANSFORM, R.OP_TANGENT
_SPEC, _GLASSF0, _SQRTSAT, _OMS = R.OP_SPECULAR_LAYER, R.OP_GLASS_F0, R.OP_SQRT_SATURATE, R.OP_ONE_MINUS_SATURATE
_AOV_OUT = R.OP_AOV_OUTPUT  # run by run_programs itself (it writes a pass, not a register); a no-op elsewhere
_COLOR_BASE, _PROC_BASE = R.COLOR_BASE, R.PROCEDURAL_BASE
_NOISE = procedural.OP_NOISE
_SINGULAR = np.float32(mf.SINGULAR_ROUGHNESS)
_F32_0 = np.float32(0.0)
_F32_1 = np.float32(1.0)


# --------------------------------------------------------------------------------------- scalar node functions
@_jit
def safe_divide(a, b):
    return a / b if b != 0.0 else 0.0


@_jit
def _fract(a):
    return a - math.floor(a)


@_jit
def _smoothmin(a, b, c):
    if c != 0.0:
        h = max(c - abs(a - b), 0.0) / c
        return min(a, b) - h * h * h * c * (1.0 / 6.0)
    return min(a, b)


@_jit
def _wrap(a, hi, lo):
    rng = hi - lo
    return a - rng * math.floor((a - lo) / rng) if rng != 0.0 else lo


@_jit
def _pingpong(a, b):
    return abs(_fract((a - b) / (b * 2.0)) * b * 2.0 - b) if b != 0.0 else 0.0


@_jit
def _safe_pow(a, b):
    if a < 0.0 and b != math.floor(b):
        return 0.0
    if a == 0.0 and b < 0.0:
        return 0.0
    return a ** b


@_jit
def math_op(op, a, b, c):
    """Blender's Math node operation `op` (index into MATH_OPS) with Cycles' safe semantics."""
    if op == 0:
        return a + b
    if op == 1:
        return a - b
    if op == 2:
        return a * b
    if op == 3:
        return safe_divide(a, b)
    if op == 4:
        return a * b + c
    if op == 5:
        return _safe_pow(a, b)
    if op == 6:
        return math.log(a) / math.log(b) if a > 0.0 and b > 0.0 and b != 1.0 else 0.0
    if op == 7:
        return math.sqrt(a) if a > 0.0 else 0.0
    if op == 8:
        return 1.0 / math.sqrt(a) if a > 0.0 else 0.0
    if op == 9:
        return abs(a)
    if op == 10:
        return math.exp(min(a, 709.0))
    if op == 11:
        return min(a, b)
    if op == 12:
        return max(a, b)
    if op == 13:
        return 1.0 if a < b else 0.0
    if op == 14:
        return 1.0 if a > b else 0.0
    if op == 15:
        return 1.0 if a > 0.0 else (-1.0 if a < 0.0 else 0.0)
    if op == 16:
        return 1.0 if abs(a - b) <= max(c, 1e-5) else 0.0
    if op == 17:
        return _smoothmin(a, b, c)
    if op == 18:
        return -_smoothmin(-a, -b, c)
    if op == 19:
        return math.floor(a + 0.5)
    if op == 20:
        return math.floor(a)
    if op == 21:
        return math.ceil(a)
    if op == 22:
        return float(math.trunc(a)) if math.isfinite(a) else a
    if op == 23:
        return _fract(a)
    if op == 24:
        return np.fmod(a, b) if b != 0.0 else 0.0
    if op == 25:
        return a - math.floor(a / b) * b if b != 0.0 else 0.0
    if op == 26:
        return _wrap(a, b, c)
    if op == 27:
        return math.floor(safe_divide(a, b)) * b
    if op == 28:
        return _pingpong(a, b)
    if op == 29:
        return math.sin(a)
    if op == 30:
        return math.cos(a)
    if op == 31:
        return math.tan(a)
    if op == 32:
        return math.asin(min(max(a, -1.0), 1.0))
    if op == 33:
        return math.acos(min(max(a, -1.0), 1.0))
    if op == 34:
        return math.atan(a)
    if op == 35:
        return math.atan2(a, b)
    if op == 36:
        return math.sinh(a)
    if op == 37:
        return math.cosh(a)
    if op == 38:
        return math.tanh(a)
    if op == 39:
        return a * (math.pi / 180.0)
    if op == 40:
        return a * (180.0 / math.pi)
    return 0.0


@_jit
def _smoothstep(e0, e1, x):
    if x < e0:
        return 0.0
    if x >= e1:
        return 1.0
    t = (x - e0) / (e1 - e0)
    return t * t * (3.0 - 2.0 * t)


@_jit
def _smootherstep(e0, e1, x):
    t = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@_jit
def map_range(value, fmin, fmax, tmin, tmax, steps, interp, clamp):
    """Blender's Map Range node for one component (Cycles' svm_map_range): 0 when from_min == from_max."""
    if fmax == fmin:
        return 0.0
    if interp == 0 or interp == 1:
        f = (value - fmin) / (fmax - fmin)
        if interp == 1:
            f = math.floor(f * (steps + 1.0)) / steps if steps > 0.0 else 0.0
    elif interp == 2:
        f = 1.0 - _smoothstep(fmax, fmin, value) if fmin > fmax else _smoothstep(fmin, fmax, value)
    else:
        f = 1.0 - _smootherstep(fmax, fmin, value) if fmin > fmax else _smootherstep(fmin, fmax, value)
    r = tmin + f * (tmax - tmin)
    if clamp != 0 and interp <= 1:
        r = min(max(r, tmax), tmin) if tmin > tmax else min(max(r, tmin), tmax)
    return r


@_jit
def fresnel_dielectric_cos(cosi, eta):
    """Cycles' fresnel_dielectric_cos (1 under total internal reflection)."""
    c = abs(cosi)
    g = eta * eta - 1.0 + c * c
    if g > 0.0:
        g = math.sqrt(g)
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        return 0.5 * a * a * (1.0 + b * b)
    return 1.0


@_jit
def euler_matrix(rx, ry, rz):
    """Rows of the XYZ-Euler rotation Rz Ry Rx (Cycles' euler_to_transform)."""
    cx, cy, cz = math.cos(rx), math.cos(ry), math.cos(rz)
    sx, sy, sz = math.sin(rx), math.sin(ry), math.sin(rz)
    return (cy * cz, sy * sx * cz - cx * sz, sy * cx * cz + sx * sz,
            cy * sz, sy * sx * sz + cx * cz, sy * cx * sz - sx * cz,
            -sy, cy * sx, cy * cx)


@_jit
def srgb_to_linear(c):
    """The sRGB transfer function's inverse (Cycles' color_srgb_to_linear)."""
    if c < 0.04045:
        return 0.0 if c < 0.0 else c * (1.0 / 12.92)
    return ((c + 0.055) * (1.0 / 1.055)) ** 2.4


# -------------------------------------------------------------------------------------------------- vectors
@_jit
def _vector_math(a, regs, o):
    """Vector Math: a = instruction operand slots, o = operation index (VECTOR_MATH_OPS)."""
    ax, ay, az = get3(regs, a[3])
    bx, by, bz = get3(regs, a[4])
    cx, cy, cz = get3(regs, a[5])
    s = float(regs[a[6], 0])
    x = y = z = 0.0
    v = 0.0
    if o == 0:
        x, y, z = ax + bx, ay + by, az + bz
    elif o == 1:
        x, y, z = ax - bx, ay - by, az - bz
    elif o == 2:
        x, y, z = ax * bx, ay * by, az * bz
    elif o == 3:
        x, y, z = safe_divide(ax, bx), safe_divide(ay, by), safe_divide(az, bz)
    elif o == 4:
        x, y, z = ax * bx + cx, ay * by + cy, az * bz + cz
    elif o == 5:
        x, y, z = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    elif o == 6:
        ll = bx * bx + by * by + bz * bz
        t = (ax * bx + ay * by + az * bz) / ll if ll != 0.0 else 0.0
        x, y, z = bx * t, by * t, bz * t
    elif o == 7 or o == 8:
        ll = math.sqrt(bx * bx + by * by + bz * bz)
        nx, ny, nz = (bx / ll, by / ll, bz / ll) if ll != 0.0 else (bx, by, bz)
        d = nx * ax + ny * ay + nz * az
        if o == 7:
            x, y, z = ax - 2.0 * d * nx, ay - 2.0 * d * ny, az - 2.0 * d * nz
        else:
            k = 1.0 - s * s * (1.0 - d * d)
            if k >= 0.0:
                q = s * d + math.sqrt(k)
                x, y, z = s * ax - q * nx, s * ay - q * ny, s * az - q * nz
    elif o == 9:
        if cx * bx + cy * by + cz * bz < 0.0:
            x, y, z = ax, ay, az
        else:
            x, y, z = -ax, -ay, -az
    elif o == 10:
        v = ax * bx + ay * by + az * bz
    elif o == 11:
        v = math.sqrt((ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2)
    elif o == 12:
        v = math.sqrt(ax * ax + ay * ay + az * az)
    elif o == 13:
        x, y, z = ax * s, ay * s, az * s
    elif o == 14:
        ll = math.sqrt(ax * ax + ay * ay + az * az)
        x, y, z = (ax / ll, ay / ll, az / ll) if ll != 0.0 else (ax, ay, az)
    elif o == 15:
        x, y, z = math_op(27, ax, bx, 0.0), math_op(27, ay, by, 0.0), math_op(27, az, bz, 0.0)
    elif o == 16:
        x, y, z = math.floor(ax), math.floor(ay), math.floor(az)
    elif o == 17:
        x, y, z = math.ceil(ax), math.ceil(ay), math.ceil(az)
    elif o == 18:
        x, y, z = math_op(24, ax, bx, 0.0), math_op(24, ay, by, 0.0), math_op(24, az, bz, 0.0)
    elif o == 19:
        x, y, z = _wrap(ax, bx, cx), _wrap(ay, by, cy), _wrap(az, bz, cz)
    elif o == 20:
        x, y, z = _fract(ax), _fract(ay), _fract(az)
    elif o == 21:
        x, y, z = abs(ax), abs(ay), abs(az)
    elif o == 22:
        x, y, z = min(ax, bx), min(ay, by), min(az, bz)
    elif o == 23:
        x, y, z = max(ax, bx), max(ay, by), max(az, bz)
    elif o == 24:
        x, y, z = math.sin(ax), math.sin(ay), math.sin(az)
    elif o == 25:
        x, y, z = math.cos(ax), math.cos(ay), math.cos(az)
    elif o == 26:
        x, y, z = math.tan(ax), math.tan(ay), math.tan(az)
    elif o == 27:
        x, y, z = _safe_pow(ax, bx), _safe_pow(ay, by), _safe_pow(az, bz)
    elif o == 28:
        x, y, z = math_op(15, ax, 0.0, 0.0), math_op(15, ay, 0.0, 0.0), math_op(15, az, 0.0, 0.0)
    set3(regs, a[1], x, y, z)
    setf(regs, a[2], v)


@_jit
def _mapping(a, regs):
    vx, vy, vz = get3(regs, a[2])
    lx, ly, lz = get3(regs, a[3])
    rx, ry, rz = get3(regs, a[4])
    sx, sy, sz = get3(regs, a[5])
    t = a[6]
    m = euler_matrix(rx, ry, rz)
    if t == 1:  # texture: the inverse of point
        px, py, pz = vx - lx, vy - ly, vz - lz
        x = m[0] * px + m[3] * py + m[6] * pz
        y = m[1] * px + m[4] * py + m[7] * pz
        z = m[2] * px + m[5] * py + m[8] * pz
        set3(regs, a[1], safe_divide(x, sx), safe_divide(y, sy), safe_divide(z, sz))
        return
    if t == 3:
        px, py, pz = safe_divide(vx, sx), safe_divide(vy, sy), safe_divide(vz, sz)
    else:
        px, py, pz = vx * sx, vy * sy, vz * sz
    x = m[0] * px + m[1] * py + m[2] * pz
    y = m[3] * px + m[4] * py + m[5] * pz
    z = m[6] * px + m[7] * py + m[8] * pz
    if t == 0:
        x, y, z = x + lx, y + ly, z + lz
    elif t == 3:
        ll = math.sqrt(x * x + y * y + z * z)
        if ll != 0.0:
            x, y, z = x / ll, y / ll, z / ll
    set3(regs, a[1], x, y, z)


# --------------------------------------------------------------------------------------------------- images
@_jit
def _bspline(t):
    """Cubic B-spline weights of the 4 texels around a fractional position t (Cycles' bicubic)."""
    t2 = t * t
    t3 = t2 * t
    w0 = (1.0 / 6.0) * (-t3 + 3.0 * t2 - 3.0 * t + 1.0)
    w1 = (1.0 / 6.0) * (3.0 * t3 - 6.0 * t2 + 4.0)
    w2 = (1.0 / 6.0) * (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0)
    w3 = (1.0 / 6.0) * t3
    return w0, w1, w2, w3


@_jit
def _texel_at(h, w, ix, iy, ext):
    """Index of texel (ix, iy) (iy counted from the BOTTOM row, Blender's v) in an image stored row 0 at the
    top, with the extension mode ext: 0 repeat, 1 extend, 2 clip (-1 outside the image: the texel reads 0),
    3 mirror."""
    if ext == 0:
        ix = ix % w
        iy = iy % h
    elif ext == 1:
        ix = min(max(ix, 0), w - 1)
        iy = min(max(iy, 0), h - 1)
    elif ext == 2:
        if ix < 0 or iy < 0 or ix >= w or iy >= h:
            return -1
    else:
        mx = abs(ix + (1 if ix < 0 else 0)) % (2 * w)
        ix = 2 * w - mx - 1 if mx >= w else mx
        my = abs(iy + (1 if iy < 0 else 0)) % (2 * h)
        iy = 2 * h - my - 1 if my >= h else my
    return (h - 1 - iy) * w + ix


@_jit
def _rgba_at(tex_pixels, off, i):
    """The four channels of texel index i (from `_texel_at`) as float64; zeros for -1."""
    if i < 0:
        return 0.0, 0.0, 0.0, 0.0
    j = off + i * 4
    return float(tex_pixels[j]), float(tex_pixels[j + 1]), float(tex_pixels[j + 2]), float(tex_pixels[j + 3])


@_jit
def _image_rgba(tex_pixels, off, h, w, u, v, interp, ext, flags):
    """An RGBA image (stored flat from `off`, row 0 at the top) filtered at (u, v) as Cycles interpolates images:
    linear = bilinear between texel centres, closest = the texel containing (u, v), cubic = cubic B-spline;
    extension as in `_texel_at`; non-finite coordinates read as 0. Returns (r, g, b, alpha) with the Image
    Texture op's flags applied (associate, unassociate, then the sRGB decode). The four channels share each
    texel's address (found once, not once per channel: ~3x fewer integer divisions per lookup), each channel's
    arithmetic in the order of the former per-channel lookup, so the values are the same bits."""
    if not math.isfinite(u):
        u = 0.0
    if not math.isfinite(v):
        v = 0.0
    if interp == 1:
        r, g, b, alpha = _rgba_at(tex_pixels, off, _texel_at(h, w, np.int64(math.floor(u * w)),
                                                             np.int64(math.floor(v * h)), ext))
    else:
        x = u * w - 0.5
        y = v * h - 0.5
        fx0 = math.floor(x)
        fy0 = math.floor(y)
        ix = np.int64(fx0)
        iy = np.int64(fy0)
        tx = x - fx0
        ty = y - fy0
        if interp == 0:
            r00, g00, b00, a00 = _rgba_at(tex_pixels, off, _texel_at(h, w, ix, iy, ext))
            r10, g10, b10, a10 = _rgba_at(tex_pixels, off, _texel_at(h, w, ix + 1, iy, ext))
            r01, g01, b01, a01 = _rgba_at(tex_pixels, off, _texel_at(h, w, ix, iy + 1, ext))
            r11, g11, b11, a11 = _rgba_at(tex_pixels, off, _texel_at(h, w, ix + 1, iy + 1, ext))
            sx = 1.0 - tx
            sy = 1.0 - ty
            alpha = sy * (sx * a00 + tx * a10) + ty * (sx * a01 + tx * a11)
            r = sy * (sx * r00 + tx * r10) + ty * (sx * r01 + tx * r11)
            g = sy * (sx * g00 + tx * g10) + ty * (sx * g01 + tx * g11)
            b = sy * (sx * b00 + tx * b10) + ty * (sx * b01 + tx * b11)
        else:
            wx = _bspline(tx)
            wy = _bspline(ty)
            r = g = b = alpha = 0.0
            for j in range(4):
                rr = rg = rb = ra = 0.0
                for i in range(4):
                    cr, cg, cb, ca = _rgba_at(tex_pixels, off, _texel_at(h, w, ix - 1 + i, iy - 1 + j, ext))
                    rr += wx[i] * cr
                    rg += wx[i] * cg
                    rb += wx[i] * cb
                    ra += wx[i] * ca
                r += wy[j] * rr
                g += wy[j] * rg
                b += wy[j] * rb
                alpha += wy[j] * ra
    if flags & 1:
        r, g, b = r * alpha, g * alpha, b * alpha
    elif flags & 4 and alpha != 0.0 and alpha != 1.0:
        r, g, b = r / alpha, g / alpha, b / alpha
    if flags & 2:
        r, g, b = srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b)
    return r, g, b, alpha


@_jit
def _map_to_sphere(x, y, z):
    """Cycles' map_to_sphere: (u, v) of a direction about the origin, u from atan2(x, y), v from the pole."""
    ll = math.sqrt(x * x + y * y + z * z)
    if ll <= 0.0:
        return 0.0, 0.0
    u = 0.0 if (x == 0.0 and y == 0.0) else (1.0 - math.atan2(x, y) / math.pi) / 2.0
    return u, 1.0 - math.acos(min(max(z / ll, -1.0), 1.0)) / math.pi


@_jit
def _map_to_tube(x, y, z):
    """Cycles' map_to_tube: u around the z axis, v = (z + 1) / 2."""
    ll = math.sqrt(x * x + y * y)
    if ll <= 0.0:
        return 0.0, 0.0
    return (1.0 - math.atan2(x / ll, y / ll) / math.pi) * 0.5, (z + 1.0) * 0.5


@_jit
def _box_weights(N, k, obj, objects, blend):
    """Cycles' box-projection weights of the x, y and z faces from the object-space shading normal (a corner
    of one face where it dominates, blends between two or three within `blend`), and that normal's signs."""
    m = objects[obj[k]]
    nx, ny, nz = float(N[k, 0]), float(N[k, 1]), float(N[k, 2])
    sx = m[OBJECT_INVERSE + 0] * nx + m[OBJECT_INVERSE + 1] * ny + m[OBJECT_INVERSE + 2] * nz
    sy = m[OBJECT_INVERSE + 4] * nx + m[OBJECT_INVERSE + 5] * ny + m[OBJECT_INVERSE + 6] * nz
    sz = m[OBJECT_INVERSE + 8] * nx + m[OBJECT_INVERSE + 9] * ny + m[OBJECT_INVERSE + 10] * nz
    ax, ay, az = abs(sx), abs(sy), abs(sz)
    total = ax + ay + az
    if total > 0.0:
        ax, ay, az = ax / total, ay / total, az / total
    wx = wy = wz = 0.0
    limit = 0.5 * (1.0 + blend)
    if ax > limit * (ax + ay) and ax > limit * (ax + az):
        wx = 1.0
    elif ay > limit * (ax + ay) and ay > limit * (ay + az):
        wy = 1.0
    elif az > limit * (ax + az) and az > limit * (ay + az):
        wz = 1.0
    elif blend > 0.0:
        if az < (1.0 - limit) * (ay + ax):
            wx = min(max((ax / (ax + ay) - 0.5 * (1.0 - blend)) / blend, 0.0), 1.0)
            wy = 1.0 - wx
        elif ax < (1.0 - limit) * (ay + az):
            wy = min(max((ay / (ay + az) - 0.5 * (1.0 - blend)) / blend, 0.0), 1.0)
            wz = 1.0 - wy
        elif ay < (1.0 - limit) * (ax + az):
            wx = min(max((ax / (ax + az) - 0.5 * (1.0 - blend)) / blend, 0.0), 1.0)
            wz = 1.0 - wx
        else:
            wx = ((2.0 - limit) * ax + (limit - 1.0)) / (2.0 * limit - 1.0)
            wy = ((2.0 - limit) * ay + (limit - 1.0)) / (2.0 * limit - 1.0)
            wz = ((2.0 - limit) * az + (limit - 1.0)) / (2.0 * limit - 1.0)
    else:
        wx = 1.0  # no blend and no dominant face: one side, as Cycles
    return wx, wy, wz, sx, sy, sz
# ------------------------------------------------------------------------------------------- vector nodes
@_jit
def _bump_shift(regs, b, wreg):
    """(which differential, its scale) of a shading-context op's bump operands: b 0 none, 1 dP.dx, 2 dP.dy;
    the scale is the Bump node's filter width (register wreg)."""
    if b <= 0:
        return 0, 0.0
    return b - 1, float(regs[wreg, 0]) if wreg >= 0 else 1.0


@_jit
def _point(k, P, dP, b, w):
    """The shading position, shifted by w dP.dx or w dP.dy when b > 0 (_bump_shift)."""
    if w == 0.0:
        return float(P[k, 0]), float(P[k, 1]), float(P[k, 2])
    return (float(P[k, 0]) + w * dP[k, b, 0], float(P[k, 1]) + w * dP[k, b, 1],
            float(P[k, 2]) + w * dP[k, b, 2])


@_jit
def _normalize3(x, y, z):
    ll = math.sqrt(x * x + y * y + z * z)
    if ll > 0.0 and math.isfinite(ll):
        return x / ll, y / ll, z / ll
    return 0.0, 0.0, 0.0


@_jit_inline
def _normal_map(a, regs, k, N, back, obj, objects, tan, nraw):
    """Cycles' svm_node_normal_map: the colour as 2 c - 1 in tangent, object or world space; world-space result
    on the viewer's side (negated on a back face). Strength scales the tangent-space offset (x, y times it, z
    from 1 towards the colour's) in tangent space, and blends from N linearly in the other spaces."""
    cx, cy, cz = get3(regs, a[2])
    cx, cy, cz = 2.0 * (cx - 0.5), 2.0 * (cy - 0.5), 2.0 * (cz - 0.5)
    if a[6] != 0:  # DirectX: green points down
        cy = -cy
    space = a[4]
    strength = float(regs[a[3], 0])
    layer = a[5]
    nx, ny, nz = float(N[k, 0]), float(N[k, 1]), float(N[k, 2])
    ox, oy, oz = nx, ny, nz
    fallback = False
    if space == 0:
        tx = ty = tz = sgn = 0.0
        if 0 <= layer < tan.shape[1]:
            tx, ty, tz, sgn = float(tan[k, layer, 0]), float(tan[k, layer, 1]), float(tan[k, layer, 2]), \
                float(tan[k, layer, 3])
        if tx == 0.0 and ty == 0.0 and tz == 0.0:
            fallback = True  # no tangents for this map (the mesh lacks it): the unperturbed normal, as Cycles
        else:
            mx, my, mz = float(nraw[k, 0]), float(nraw[k, 1]), float(nraw[k, 2])
            cx, cy = cx * strength, cy * strength
            cz = 1.0 + (cz - 1.0) * min(max(strength, 0.0), 1.0)
            bx, by, bz = sgn * (my * tz - mz * ty), sgn * (mz * tx - mx * tz), sgn * (mx * ty - my * tx)
            ox, oy, oz = _normalize3(cx * tx + cy * bx + cz * mx, cx * ty + cy * by + cz * my,
                                     cx * tz + cy * bz + cz * mz)
    else:
        if space == 3 or space == 4:
            cy, cz = -cy, -cz
        if space == 1 or space == 3:
            m = objects[obj[k]]  # object -> world for normals: the transpose of the world -> object matrix
            ox = m[OBJECT_INVERSE + 0] * cx + m[OBJECT_INVERSE + 4] * cy + m[OBJECT_INVERSE + 8] * cz
            oy = m[OBJECT_INVERSE + 1] * cx + m[OBJECT_INVERSE + 5] * cy + m[OBJECT_INVERSE + 9] * cz
            oz = m[OBJECT_INVERSE + 2] * cx + m[OBJECT_INVERSE + 6] * cy + m[OBJECT_INVERSE + 10] * cz
            ox, oy, oz = _normalize3(ox, oy, oz)
        else:
            ox, oy, oz = _normalize3(cx, cy, cz)
    if fallback:
        set3(regs, a[1], nx, ny, nz)
        return
    if back[k]:
        ox, oy, oz = -ox, -oy, -oz
    if space != 0 and strength != 1.0:
        strength = max(strength, 0.0)
        ox, oy, oz = _normalize3(nx + (ox - nx) * strength, ny + (oy - ny) * strength, nz + (oz - nz) * strength)
    if ox == 0.0 and oy == 0.0 and oz == 0.0:
        ox, oy, oz = nx, ny, nz
    set3(regs, a[1], ox, oy, oz)


@_jit_inline
def _bump(a, regs, k, N, dP):
    """Cycles' svm_node_set_bump: the heights h_c, h_x, h_y at P, P + w dP.dx, P + w dP.dy (w: filter width)
    tilt the normal by the surface gradient, strength blends from the input normal."""
    if a[8] >= 0:
        nx, ny, nz = get3(regs, a[8])
    else:
        nx, ny, nz = float(N[k, 0]), float(N[k, 1]), float(N[k, 2])
    xx, xy, xz = float(dP[k, 0, 0]), float(dP[k, 0, 1]), float(dP[k, 0, 2])
    yx, yy, yz = float(dP[k, 1, 0]), float(dP[k, 1, 1]), float(dP[k, 1, 2])
    rxx, rxy, rxz = yy * nz - yz * ny, yz * nx - yx * nz, yx * ny - yy * nx  # Rx = dPdy x N
    ryx, ryy, ryz = ny * xz - nz * xy, nz * xx - nx * xz, nx * xy - ny * xx  # Ry = N x dPdx
    hc, hx, hy = float(regs[a[4], 0]), float(regs[a[5], 0]), float(regs[a[6], 0])
    det = xx * rxx + xy * rxy + xz * rxz
    gx = (hx - hc) * rxx + (hy - hc) * ryx
    gy = (hx - hc) * rxy + (hy - hc) * ryy
    gz = (hx - hc) * rxz + (hy - hc) * ryz
    strength = max(float(regs[a[2], 0]), 0.0)
    scale = float(regs[a[3], 0])
    if a[9] != 0:
        scale = -scale
    width = float(regs[a[7], 0])
    sd = 1.0 if det > 0.0 else (-1.0 if det < 0.0 else 0.0)
    ad = abs(det) * width
    ox, oy, oz = _normalize3(ad * nx - scale * sd * gx, ad * ny - scale * sd * gy, ad * nz - scale * sd * gz)
    if ox == 0.0 and oy == 0.0 and oz == 0.0:
        ox, oy, oz = nx, ny, nz
    else:
        ox, oy, oz = _normalize3(strength * ox + (1.0 - strength) * nx, strength * oy + (1.0 - strength) * ny,
                                 strength * oz + (1.0 - strength) * nz)
    set3(regs, a[1], ox, oy, oz)


@_jit
def _tangent(a, regs, k, N, obj, objects, tan):
    """Cycles' tangent: a UV map's tangent or the radial tangent of the generated coordinates (object -> world
    as a normal, normalised), then cross(N, normalize(cross(t, N)))."""
    layer = a[4]
    if layer >= 0:
        tx = ty = tz = 0.0
        if layer < tan.shape[1]:
            tx, ty, tz = float(tan[k, layer, 0]), float(tan[k, layer, 1]), float(tan[k, layer, 2])
        if tx == 0.0 and ty == 0.0 and tz == 0.0:
            set3(regs, a[1], 0.0, 0.0, 0.0)
            return
    else:
        gx, gy, gz = get3(regs, a[2])
        axis = a[3]
        if axis == 0:
            dx, dy, dz = 0.0, -(gz - 0.5), gy - 0.5
        elif axis == 1:
            dx, dy, dz = -(gz - 0.5), 0.0, gx - 0.5
        else:
            dx, dy, dz = -(gy - 0.5), gx - 0.5, 0.0
        m = objects[obj[k]]
        tx = m[OBJECT_INVERSE + 0] * dx + m[OBJECT_INVERSE + 4] * dy + m[OBJECT_INVERSE + 8] * dz
        ty = m[OBJECT_INVERSE + 1] * dx + m[OBJECT_INVERSE + 5] * dy + m[OBJECT_INVERSE + 9] * dz
        tz = m[OBJECT_INVERSE + 2] * dx + m[OBJECT_INVERSE + 6] * dy + m[OBJECT_INVERSE + 10] * dz
        tx, ty, tz = _normalize3(tx, ty, tz)
    nx, ny, nz = float(N[k, 0]), float(N[k, 1]), float(N[k, 2])
    cx, cy, cz = _normalize3(ty * nz - tz * ny, tz * nx - tx * nz, tx * ny - ty * nx)
    set3(regs, a[1], ny * cz - nz * cy, nz * cx - nx * cz, nx * cy - ny * cx)


@_jit
def _affine(m, off, x, y, z, point):
    """Rows off..off+11 of m (a 3 x 4 row-major transform) applied to a point (point) or a direction."""
    w = 1.0 if point else 0.0
    return (m[off] * x + m[off + 1] * y + m[off + 2] * z + m[off + 3] * w,
            m[off + 4] * x + m[off + 5] * y + m[off + 6] * z + m[off + 7] * w,
            m[off + 8] * x + m[off + 9] * y + m[off + 10] * z + m[off + 11] * w)


@_jit
def _object_forward(m, x, y, z, point):
    """Object -> world for the object row m: the inverse of its world -> object transform (OBJECT_INVERSE)."""
    a, b, c = m[OBJECT_INVERSE + 0], m[OBJECT_INVERSE + 1], m[OBJECT_INVERSE + 2]
    d, e, f = m[OBJECT_INVERSE + 4], m[OBJECT_INVERSE + 5], m[OBJECT_INVERSE + 6]
    g, h, i = m[OBJECT_INVERSE + 8], m[OBJECT_INVERSE + 9], m[OBJECT_INVERSE + 10]
    if point:
        x, y, z = x - m[OBJECT_INVERSE + 3], y - m[OBJECT_INVERSE + 7], z - m[OBJECT_INVERSE + 11]
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if det == 0.0:
        return x, y, z
    r = 1.0 / det
    return ((e * i - f * h) * r * x + (c * h - b * i) * r * y + (b * f - c * e) * r * z,
            (f * g - d * i) * r * x + (a * i - c * g) * r * y + (c * d - a * f) * r * z,
            (d * h - e * g) * r * x + (b * g - a * h) * r * y + (a * e - b * d) * r * z)


@_jit
def _vector_transform(a, regs, data, k, obj, objects):
    x, y, z = get3(regs, a[2])
    kind, src, dst, cam = a[3], a[4], a[5], a[6]
    point = kind == 0
    m = objects[obj[k]]
    if src == 0:
        if dst == 2:
            x, y, z = _affine(data, cam, x, y, z, point)
        elif dst == 1:
            x, y, z = _affine(m, OBJECT_INVERSE, x, y, z, point)
    elif src == 2:
        if dst == 0 or dst == 1:
            x, y, z = _affine(data, cam + 12, x, y, z, point)
        if dst == 1:
            x, y, z = _affine(m, OBJECT_INVERSE, x, y, z, point)
    else:
        if dst == 0 or dst == 2:
            x, y, z = _object_forward(m, x, y, z, point)
        if dst == 2:
            x, y, z = _affine(data, cam, x, y, z, point)
    if kind == 2:
        ll = math.sqrt(x * x + y * y + z * z)
        if ll > 0.0:
            x, y, z = x / ll, y / ll, z / ll
    set3(regs, a[1], x, y, z)


# ------------------------------------------------------------------------------------------------- dispatch
@_jit
def _register_op(op, a, regs):
    """Execute core opcode `op` when it reads and writes registers only (no shading context): returns False for
    the others (`_core_op`). The interpreter calls this with 3 arguments instead of the context's two dozen
    arrays, which made an instruction's call cost more than its arithmetic."""
    if op == _COPY:
        x, y, z = get3(regs, a[2])
        set3(regs, a[1], x, y, z)
    elif op == _F2V:
        setf(regs, a[1], float(regs[a[2], 0]))
    elif op == _C2F:
        setf(regs, a[1], 0.2126 * regs[a[2], 0] + 0.7152 * regs[a[2], 1] + 0.0722 * regs[a[2], 2])
    elif op == _V2F:
        setf(regs, a[1], (float(regs[a[2], 0]) + regs[a[2], 1] + regs[a[2], 2]) / 3.0)
    elif op == _MATH:
        r = math_op(a[5], float(regs[a[2], 0]), float(regs[a[3], 0]), float(regs[a[4], 0]))
        if a[6] != 0:
            r = min(max(r, 0.0), 1.0)
        setf(regs, a[1], r)
    elif op == _VMATH:
        _vector_math(a, regs, a[7])
    elif op == _MAPRANGE:
        if a[10] != 0:
            x = map_range(regs[a[2], 0], regs[a[3], 0], regs[a[4], 0], regs[a[5], 0], regs[a[6], 0], regs[a[7], 0],
                          a[8], a[9])
            y = map_range(regs[a[2], 1], regs[a[3], 1], regs[a[4], 1], regs[a[5], 1], regs[a[6], 1], regs[a[7], 1],
                          a[8], a[9])
            z = map_range(regs[a[2], 2], regs[a[3], 2], regs[a[4], 2], regs[a[5], 2], regs[a[6], 2], regs[a[7], 2],
                          a[8], a[9])
            set3(regs, a[1], x, y, z)
        else:
            setf(regs, a[1], map_range(float(regs[a[2], 0]), float(regs[a[3], 0]), float(regs[a[4], 0]),
                                       float(regs[a[5], 0]), float(regs[a[6], 0]), float(regs[a[7], 0]), a[8], a[9]))
    elif op == _CLAMP:
        v, lo, hi = float(regs[a[2], 0]), float(regs[a[3], 0]), float(regs[a[4], 0])
        if a[5] != 0 and lo > hi:
            lo, hi = hi, lo
        setf(regs, a[1], min(max(v, lo), hi))
    elif op == _SEPXYZ:
        x, y, z = get3(regs, a[4])
        setf(regs, a[1], x)
        setf(regs, a[2], y)
        setf(regs, a[3], z)
    elif op == _COMBXYZ:
        set3(regs, a[1], regs[a[2], 0], regs[a[3], 0], regs[a[4], 0])
    elif op == _MAPPING:
        _mapping(a, regs)
    elif op == _MIX:
        fx = float(regs[a[2], 0])
        fy = float(regs[a[2], 1]) if a[6] != 0 else fx
        fz = float(regs[a[2], 2]) if a[6] != 0 else fx
        if a[5] != 0:
            fx, fy, fz = min(max(fx, 0.0), 1.0), min(max(fy, 0.0), 1.0), min(max(fz, 0.0), 1.0)
        ax, ay, az = get3(regs, a[3])
        bx, by, bz = get3(regs, a[4])
        set3(regs, a[1], ax + fx * (bx - ax), ay + fy * (by - ay), az + fz * (bz - az))
    elif op == _SPEC:
        ior = float(regs[a[3], 0])
        level = float(regs[a[4], 0])
        rr = (ior - 1.0) / (ior + 1.0)
        f0 = rr * rr
        eta = ior
        if level != 0.5:
            f0 *= 2.0 * level
            c = math.sqrt(min(max(f0, 0.0), 0.99))
            eta = (1.0 + c) / (1.0 - c)
            if ior < 1.0:
                eta = 1.0 / eta
        tx, ty, tz = get3(regs, a[5])
        set3(regs, a[1], min(max(f0 * tx, 0.0), 1.0), min(max(f0 * ty, 0.0), 1.0), min(max(f0 * tz, 0.0), 1.0))
        setf(regs, a[2], eta)
    elif op == _GLASSF0:
        ior = float(regs[a[2], 0])
        rr = (ior - 1.0) / (ior + 1.0)
        f0 = rr * rr
        tx, ty, tz = get3(regs, a[3])
        set3(regs, a[1], min(max(f0 * tx, 0.0), 1.0), min(max(f0 * ty, 0.0), 1.0), min(max(f0 * tz, 0.0), 1.0))
    elif op == _SQRTSAT:
        x, y, z = get3(regs, a[2])
        set3(regs, a[1], math.sqrt(min(max(x, 0.0), 1.0)), math.sqrt(min(max(y, 0.0), 1.0)),
             math.sqrt(min(max(z, 0.0), 1.0)))
    elif op == _OMS:
        x, y, z = get3(regs, a[2])
        set3(regs, a[1], min(max(1.0 - x, 0.0), 1.0), min(max(1.0 - y, 0.0), 1.0), min(max(1.0 - z, 0.0), 1.0))
    else:
        return False
    return True


@_jit
def _core_op(op, a, regs, data, k, P, N, Ng, I, uv, has_uv, back, obj, objects, tex_pixels, tex_offset, tex_h,
             tex_w, uvx, extra, dP, duv, tan, nraw):
    """Execute core opcode `op` with operand slots `a` (a[1..]) for shading point k."""
    if _register_op(op, a, regs) or _context_op(op, a, regs, k, P, N, I, uv, has_uv, back, obj, objects, tex_pixels,
                                                tex_offset, tex_h, tex_w, dP, duv, tan, nraw):
        return
    if op == _FRESNEL:
        n0, n1, n2 = (float(N[k, 0]), float(N[k, 1]), float(N[k, 2])) if a[3] < 0 else get3(regs, a[3])
        eta = max(float(regs[a[2], 0]), 1e-5)
        if back[k]:
            eta = 1.0 / eta
        setf(regs, a[1], fresnel_dielectric_cos(I[k, 0] * n0 + I[k, 1] * n1 + I[k, 2] * n2, eta))
    elif op == _LAYER:
        n0, n1, n2 = (float(N[k, 0]), float(N[k, 1]), float(N[k, 2])) if a[4] < 0 else get3(regs, a[4])
        blend = min(max(float(regs[a[3], 0]), 0.0), 1.0 - 1e-5)
        cosi = I[k, 0] * n0 + I[k, 1] * n1 + I[k, 2] * n2
        eta = max(1.0 - blend, 1e-5)
        eta = eta if back[k] else 1.0 / eta
        setf(regs, a[1], fresnel_dielectric_cos(cosi, eta))
        f = abs(cosi)
        if blend != 0.5:
            f = f ** (2.0 * blend if blend < 0.5 else 0.5 / (1.0 - blend))
        setf(regs, a[2], 1.0 - f)
    elif op == _GEOM:
        b, w = _bump_shift(regs, a[7], a[8])
        px, py, pz = _point(k, P, dP, b, w)
        set3(regs, a[1], px, py, pz)
        set3(regs, a[2], N[k, 0], N[k, 1], N[k, 2])
        set3(regs, a[3], Ng[k, 0], Ng[k, 1], Ng[k, 2])
        set3(regs, a[4], I[k, 0], I[k, 1], I[k, 2])
        setf(regs, a[5], 1.0 if back[k] else 0.0)
        set3(regs, a[6], 0.0, 0.0, 0.0)  # parametric: not computed (the compiler warns when it is used)
    elif op == _UVLAYER:
        layer = a[2]
        b, w = _bump_shift(regs, a[3], a[4])
        if layer < uvx.shape[1]:
            set3(regs, a[1], uvx[k, layer, 0, 0] + w * uvx[k, layer, 1 + b, 0],
                 uvx[k, layer, 0, 1] + w * uvx[k, layer, 1 + b, 1], 0.0)
        else:
            set3(regs, a[1], 0.0, 0.0, 0.0)
    elif op == _ATTR:
        col = PATH_COLUMNS + a[4] * ATTRIBUTE_COLUMNS
        if col + ATTRIBUTE_COLUMNS <= extra.shape[1] and extra[k, col + 5] > 0.5:
            set3(regs, a[1], extra[k, col], extra[k, col + 1], extra[k, col + 2])
            setf(regs, a[2], extra[k, col + 3])
            setf(regs, a[3], extra[k, col + 4])
        else:  # a mesh without the attribute (or no attribute table: a program run outside a render)
            set3(regs, a[1], 0.0, 0.0, 0.0)
            setf(regs, a[2], float(a[5]))
            setf(regs, a[3], 0.0)
    elif op == _LIGHTPATH:
        _light_path(a, regs, k, extra)
    elif op == _OBJINFO:
        o = obj[k]
        set3(regs, a[1], objects[o, OBJECT_LOCATION], objects[o, OBJECT_LOCATION + 1], objects[o, OBJECT_LOCATION + 2])
        set3(regs, a[2], objects[o, OBJECT_COLOR], objects[o, OBJECT_COLOR + 1], objects[o, OBJECT_COLOR + 2])
        setf(regs, a[3], objects[o, OBJECT_COLOR + 3])
        setf(regs, a[4], objects[o, OBJECT_PASS_INDEX])
        setf(regs, a[5], objects[o, OBJECT_RANDOM])
    elif op == _VTRANSFORM:
        _vector_transform(a, regs, data, k, obj, objects)
    elif op == _TANGENT:
        _tangent(a, regs, k, N, obj, objects, tan)


@_jit_inline
def _image_op(a, regs, k, N, uv, has_uv, obj, objects, tex_pixels, tex_offset, tex_h, tex_w, duv):
    """The Image Texture instruction (Color into a[1], Alpha into a[2]) for shading point k."""
    if a[3] >= 0:
        x, y, z = get3(regs, a[3])
    elif has_uv:
        b, w = _bump_shift(regs, a[10], a[11])
        x, y, z = float(uv[k, 0]) + w * duv[k, b, 0], float(uv[k, 1]) + w * duv[k, b, 1], 0.0
    else:
        x, y, z = 0.0, 0.0, 0.0
    t = a[4]
    proj = a[8]
    if proj == 1:  # box: up to three lookups, unassociated after the sum (Cycles, against fringes)
        blend = float(regs[a[9], 0]) if a[9] >= 0 else 0.0
        wx, wy, wz, sx, sy, sz = _box_weights(N, k, obj, objects, blend)
        r = g = b = alpha = 0.0
        for face in range(3):
            wf = wx if face == 0 else (wy if face == 1 else wz)
            if wf <= 0.0:
                continue
            if face == 0:
                u, v = (1.0 - y if sx < 0.0 else y), z
            elif face == 1:
                u, v = (1.0 - x if sy > 0.0 else x), z
            else:
                u, v = (1.0 - y if sz > 0.0 else y), x
            fr, fg, fb, fa = _image_rgba(tex_pixels, tex_offset[t], tex_h[t], tex_w[t], u, v, a[5], a[6],
                                         a[7] & 3)
            r, g, b, alpha = r + wf * fr, g + wf * fg, b + wf * fb, alpha + wf * fa
        if a[7] & 4 and alpha != 0.0 and alpha != 1.0:
            r, g, b = r / alpha, g / alpha, b / alpha
    else:
        if proj == 2 or proj == 3:  # sphere / tube about the centre of the [0, 1] cube (Cycles' map_to_*)
            cx, cy, cz = 2.0 * x - 1.0, 2.0 * y - 1.0, 2.0 * z - 1.0
            u, v = _map_to_sphere(cx, cy, cz) if proj == 2 else _map_to_tube(cx, cy, cz)
        else:
            u, v = x, y
        r, g, b, alpha = _image_rgba(tex_pixels, tex_offset[t], tex_h[t], tex_w[t], u, v, a[5], a[6], a[7])
    set3(regs, a[1], r, g, b)
    setf(regs, a[2], alpha)


@_jit
def _flag(flags, bit):
    return 1.0 if flags & bit else 0.0


@_jit
def _light_path(a, regs, k, extra):
    """Light Path node: the ray kind flags and bounce counts of the path state (Cycles' svm_node_light_path)."""
    if extra.shape[1] >= PATH_COLUMNS:
        flags = np.int64(extra[k, 0])
        vals = (float(extra[k, 1]), float(extra[k, 2]), float(extra[k, 3]), float(extra[k, 4]),
                float(extra[k, 5]), float(extra[k, 6]))
    else:  # no path state: a camera ray
        flags = np.int64(RAY_CAMERA)
        vals = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    setf(regs, a[1], _flag(flags, RAY_CAMERA))
    setf(regs, a[2], _flag(flags, RAY_SHADOW))
    setf(regs, a[3], _flag(flags, RAY_DIFFUSE))
    setf(regs, a[4], _flag(flags, RAY_GLOSSY))
    setf(regs, a[5], _flag(flags, RAY_SINGULAR))
    setf(regs, a[6], _flag(flags, RAY_REFLECT))
    setf(regs, a[7], _flag(flags, RAY_TRANSMIT))
    for j in range(6):
        setf(regs, a[8 + j], vals[j])


@_jit_inline
def _texture_coordinate(a, regs, k, P, N, I, uv, has_uv, obj, objects, dP, duv):
    o = obj[k]
    b, w = _bump_shift(regs, a[8], a[9])
    px, py, pz = _point(k, P, dP, b, w)
    m = objects[o]
    ox = m[OBJECT_INVERSE + 0] * px + m[OBJECT_INVERSE + 1] * py + m[OBJECT_INVERSE + 2] * pz + m[OBJECT_INVERSE + 3]
    oy = m[OBJECT_INVERSE + 4] * px + m[OBJECT_INVERSE + 5] * py + m[OBJECT_INVERSE + 6] * pz + m[OBJECT_INVERSE + 7]
    oz = m[OBJECT_INVERSE + 8] * px + m[OBJECT_INVERSE + 9] * py + m[OBJECT_INVERSE + 10] * pz + m[OBJECT_INVERSE + 11]
    set3(regs, a[1], safe_divide(ox - m[OBJECT_BOX_MIN], m[OBJECT_BOX_SIZE]),
         safe_divide(oy - m[OBJECT_BOX_MIN + 1], m[OBJECT_BOX_SIZE + 1]),
         safe_divide(oz - m[OBJECT_BOX_MIN + 2], m[OBJECT_BOX_SIZE + 2]))
    # Object-space normal: the inverse transform's transpose inverse is the forward matrix's rotation part;
    # for the rigid and uniformly scaled objects this uses, world -> object rotates N by the inverse's 3x3.
    nx, ny, nz = float(N[k, 0]), float(N[k, 1]), float(N[k, 2])
    qx = m[OBJECT_INVERSE + 0] * nx + m[OBJECT_INVERSE + 1] * ny + m[OBJECT_INVERSE + 2] * nz
    qy = m[OBJECT_INVERSE + 4] * nx + m[OBJECT_INVERSE + 5] * ny + m[OBJECT_INVERSE + 6] * nz
    qz = m[OBJECT_INVERSE + 8] * nx + m[OBJECT_INVERSE + 9] * ny + m[OBJECT_INVERSE + 10] * nz
    ll = math.sqrt(qx * qx + qy * qy + qz * qz)
    if ll > 0.0:
        qx, qy, qz = qx / ll, qy / ll, qz / ll
    set3(regs, a[2], qx, qy, qz)
    if has_uv:
        set3(regs, a[3], uv[k, 0] + w * duv[k, b, 0], uv[k, 1] + w * duv[k, b, 1], 0.0)
    else:
        set3(regs, a[3], 0.0, 0.0, 0.0)
    set3(regs, a[4], ox, oy, oz)
    if a[5] >= 0 or a[6] >= 0:  # Camera and Window: the camera is the object table's last row
        c = objects[objects.shape[0] - 1]
        cx = c[OBJECT_INVERSE + 0] * px + c[OBJECT_INVERSE + 1] * py + c[OBJECT_INVERSE + 2] * pz + c[OBJECT_INVERSE + 3]
        cy = c[OBJECT_INVERSE + 4] * px + c[OBJECT_INVERSE + 5] * py + c[OBJECT_INVERSE + 6] * pz + c[OBJECT_INVERSE + 7]
        cz = c[OBJECT_INVERSE + 8] * px + c[OBJECT_INVERSE + 9] * py + c[OBJECT_INVERSE + 10] * pz + c[OBJECT_INVERSE + 11]
        set3(regs, a[5], cx, cy, cz)
        kind = c[CAMERA_KIND]
        if kind == CAMERA_PANO:
            set3(regs, a[6], 0.0, 0.0, 0.0)  # not computed for panoramic cameras (the export warns)
        else:
            sx, sy = (cx, cy) if kind == CAMERA_ORTHO else (safe_divide(cx, cz), safe_divide(cy, cz))
            set3(regs, a[6], safe_divide(sx - c[CAMERA_FRAME], c[CAMERA_FRAME + 1] - c[CAMERA_FRAME]),
                 safe_divide(sy - c[CAMERA_FRAME + 2], c[CAMERA_FRAME + 3] - c[CAMERA_FRAME + 2]), 0.0)
    d = I[k, 0] * nx + I[k, 1] * ny + I[k, 2] * nz
    set3(regs, a[7], 2.0 * d * nx - I[k, 0], 2.0 * d * ny - I[k, 1], 2.0 * d * nz - I[k, 2])


@_jit_inline
def _context_op(op, a, regs, k, P, N, I, uv, has_uv, back, obj, objects, tex_pixels, tex_offset, tex_h, tex_w, dP,
                duv, tan, nraw):
    """The context ops of textured materials (Texture Coordinate, Image Texture, Normal Map, Bump) for shading
    point k, given only the arrays they read; False (nothing done) for any other op. Inlined into both
    run_programs, which runs them straight from its loop, and _core_op (run_single's path)."""
    if op == _TEXCO:
        _texture_coordinate(a, regs, k, P, N, I, uv, has_uv, obj, objects, dP, duv)
    elif op == _IMAGE:
        _image_op(a, regs, k, N, uv, has_uv, obj, objects, tex_pixels, tex_offset, tex_h, tex_w, duv)
    elif op == _NORMAL_MAP:
        _normal_map(a, regs, k, N, back, obj, objects, tan, nraw)
    elif op == _BUMP_OP:
        _bump(a, regs, k, N, dP)
    else:
        return False
    return True


@_jit
def _execute(op, a, regs, data, k, P, N, Ng, I, uv, has_uv, back, obj, objects, tex_pixels, tex_offset, tex_h,
             tex_w, uvx, extra, dP, duv, tan, nraw):
    """One instruction (`run_single`'s path; `run_programs` dispatches the same way inline). A new opcode family
    hooks in here and in run_programs: `elif op < NEXT_BASE: family.run(op, a, regs, data)`."""
    if op < _COLOR_BASE:
        _core_op(op, a, regs, data, k, P, N, Ng, I, uv, has_uv, back, obj, objects, tex_pixels, tex_offset, tex_h,
                 tex_w, uvx, extra, dP, duv, tan, nraw)
    elif op < _PROC_BASE:
        color.run(op, a, regs, data)
    else:
        procedural.run(op, a, regs, data)


@_jit_inline
def run_point(k, m, prog, ctx, lob, out):
    """Evaluate the program of material m at shading point k (row k of the per-point arrays; see run_programs):
    the body of run_programs' loop, also inlined into the fused path kernel (core.fused_path), which runs it on
    1-row arrays (k = 0) at each surface vertex. run_programs' arguments in four tuples (a call of more than 30
    arguments compiles to CALL_FUNCTION_EX, which numba cannot inline): prog = (prog_of_mat .. tex_w), ctx =
    (P .. scratch), lob = (kind .. t_scale), out = (emission, normal_out, has_normal, aov_out)."""
    (prog_of_mat, code, code_start, regs0, reg_start, data, data_start, bind, emit_reg, normal_reg, tex_pixels,
     tex_offset, tex_h, tex_w) = prog
    P, N, Ng, I, uv, has_uv, back, obj, objects, uvx, extra, dP, duv, tan, nraw, scratch = ctx
    kind, weight, rough, ior, f0, tint, select, t_scale = lob
    emission, normal_out, has_normal, aov_out = out
    p = prog_of_mat[m]
    if p < 0:
        return
    r0, r1 = reg_start[p], reg_start[p + 1]
    for r in range(r1 - r0):
        scratch[r, 0] = regs0[r0 + r, 0]
        scratch[r, 1] = regs0[r0 + r, 1]
        scratch[r, 2] = regs0[r0 + r, 2]
    pdata = data[data_start[p]:data_start[p + 1]]
    for i in range(code_start[p], code_start[p + 1]):
        a = code[i]
        if a[0] == _AOV_OUT:
            if aov_out.shape[0] > 0:
                for c in range(3):
                    aov_out[k, a[2], c] += scratch[a[1], c]
                aov_out[k, a[2], 3] += _F32_1
            continue
        op = a[0]
        # the families straight from here (not through _execute): register-only ops take 3-4 arguments,
        # only the ops that read the shading context get its arrays
        if op < _COLOR_BASE:
            if _register_op(op, a, scratch):
                pass
            # the context ops of textured materials inlined here with the arrays they read: through
            # _core_op each call passed the whole context (two dozen arrays) twice, ~120 ns per instruction
            elif _context_op(op, a, scratch, k, P, N, I, uv, has_uv, back, obj, objects, tex_pixels, tex_offset,
                             tex_h, tex_w, dP, duv, tan, nraw):
                pass
            else:
                _core_op(op, a, scratch, pdata, k, P, N, Ng, I, uv, has_uv, back, obj, objects, tex_pixels,
                         tex_offset, tex_h, tex_w, uvx, extra, dP, duv, tan, nraw)
        elif op < _PROC_BASE:
            color.run(op, a, scratch, pdata)
        elif op == _NOISE:  # the commonest texture, outside procedural.run's many-texture body (noise_op)
            procedural.noise_op(a, scratch)
        else:
            procedural.run(op, a, scratch, pdata)
    L = bind.shape[1]
    changed = False
    for l in range(L):
        if kind[k, l] < 0:
            continue
        b = bind[p, l, BIND_WEIGHT]
        if b >= 0:
            changed = True
            for c in range(3):
                wv = scratch[b, c]
                weight[k, l, c] = wv if wv > _F32_0 else _F32_0
        b = bind[p, l, BIND_ROUGHNESS]
        if b >= 0:
            rv = min(max(scratch[b, 0], _F32_0), _F32_1)
            if not rv > _SINGULAR:
                rv = _F32_0
            rough[k, l] = rv
        b = bind[p, l, BIND_IOR]
        if b >= 0:
            iv = scratch[b, 0]
            ior[k, l] = iv if iv > np.float32(1e-5) else np.float32(1e-5)
        b = bind[p, l, BIND_F0]
        if b >= 0:
            for c in range(3):
                f0[k, l, c] = min(max(scratch[b, c], _F32_0), _F32_1)
        for t in range(2):
            b = bind[p, l, BIND_TINT_R + t]
            if b >= 0:
                changed = True
                for c in range(3):
                    tv = scratch[b, c]
                    tint[k, l, t, c] = tv if tv > _F32_0 else _F32_0
    if changed:
        bk._select_row(kind, weight, t_scale, m, k, select)
    e = emit_reg[p]
    if e >= 0:  # not clamped: Cycles renders a negative emission colour as negative radiance
        for c in range(3):
            emission[k, c] = scratch[e, c]
    nr = normal_reg[p]
    if nr >= 0:
        has_normal[k] = True
        for c in range(3):
            normal_out[k, c] = scratch[nr, c]


@_jit
def run_programs(rows, mat, prog_of_mat, code, code_start, regs0, reg_start, data, data_start, bind, emit_reg,
                 normal_reg, tex_pixels, tex_offset, tex_h, tex_w, P, N, Ng, I, uv, has_uv, back, obj, objects, uvx,
                 extra, dP, duv, tan, nraw, scratch, kind, weight, rough, ior, f0, tint, select, t_scale, emission,
                 normal_out, has_normal, aov_out):
    """Evaluate the programs of the points `rows` (indices into the per-point arrays); write the bound lobe
    parameters of point k into row k of the LobeBatch arrays (kind .. select), `emission` (N, 3) likewise (rows
    whose program binds no emission are left as they are), and the bound shading normal into normal_out[k] with
    has_normal[k] = True. aov_out (N, K, 4): each aov_output instruction adds its value and a count of 1 to
    aov_out[k, aov]; with no rows (0, K, 4) the instructions write nothing. scratch (R_max, 3) float32 is the
    register file."""
    prog = (prog_of_mat, code, code_start, regs0, reg_start, data, data_start, bind, emit_reg, normal_reg,
            tex_pixels, tex_offset, tex_h, tex_w)
    ctx = (P, N, Ng, I, uv, has_uv, back, obj, objects, uvx, extra, dP, duv, tan, nraw, scratch)
    lob = (kind, weight, rough, ior, f0, tint, select, t_scale)
    out = (emission, normal_out, has_normal, aov_out)
    for j in range(rows.shape[0]):
        k = rows[j]
        run_point(k, mat[k], prog, ctx, lob, out)


# ----------------------------------------------------------------------------------------------- Python face
class PreparedShading:
    """The scene's programs packed for `run_programs`, and the textures they read (RGBA float32, once per image).

    Built by `build(materials, textures, max_lobes)`; None when no material has a program (renders then pay
    nothing). `needs_program` (M,) bool marks the materials whose lobes vary per point, `emits` (M,) bool those
    whose emission does."""

    def __init__(self, programs: list[ShadingProgram | None], textures, max_lobes: int,
                 objects: np.ndarray | None = None) -> None:
        m = len(programs)
        self.prog_of_mat = np.full(m, -1, np.int32)
        live = [(i, p) for i, p in enumerate(programs) if p is not None]
        code, regs, data, binds, emits, normals = [], [], [], [], [], []
        for n, (i, p) in enumerate(live):
            self.prog_of_mat[i] = n
            code.append(p.code)
            regs.append(p.registers)
            data.append(p.data)
            b = np.full((max_lobes, N_BIND), -1, np.int32)
            b[:p.lobes.shape[0]] = p.lobes
            binds.append(b)
            emits.append(p.emission)
            normals.append(getattr(p, "normal", -1))
        self.code = np.ascontiguousarray(np.concatenate(code) if code else np.zeros((0, WIDTH), np.int32), np.int32)
        self.code_start = np.concatenate([[0], np.cumsum([len(c) for c in code])]).astype(np.int64)
        self.regs0 = np.ascontiguousarray(np.concatenate(regs) if regs else np.zeros((0, 3), np.float32), np.float32)
        self.reg_start = np.concatenate([[0], np.cumsum([len(r) for r in regs])]).astype(np.int64)
        self.data = np.ascontiguousarray(np.concatenate(data) if data else np.zeros(0, np.float32), np.float32)
        self.data_start = np.concatenate([[0], np.cumsum([len(d) for d in data])]).astype(np.int64)
        self.bind = np.ascontiguousarray(np.stack(binds) if binds else np.zeros((0, max_lobes, N_BIND), np.int32))
        self.emit_reg = np.asarray(emits, np.int32).reshape(-1)
        self.normal_reg = np.asarray(normals, np.int32).reshape(-1)
        # Programs that set the shading normal, and those whose Bump nodes read ray differentials.
        self.sets_normal = np.zeros(m, bool)
        for i, p in live:
            self.sets_normal[i] = getattr(p, "normal", -1) >= 0
        self.any_sets_normal = bool(self.sets_normal.any())
        self.needs_differentials = bool(len(self.code) and np.any(self.code[:, 0] == R.OP_BUMP))
        self.max_registers = max([1] + [len(r) for r in regs])
        self.needs_program = self.prog_of_mat >= 0
        self.emits = np.zeros(m, bool)
        for i, p in live:
            self.emits[i] = p.emission >= 0
        self.any_emits = bool(self.emits.any())
        ops = self.code[:, 0] if len(self.code) else np.zeros(0, np.int32)
        # Which per-point extras the programs read: the integrator tracks the path state and interpolates the
        # named attributes only then.
        self.uses_light_path = bool(np.any(ops == _LIGHTPATH))
        self.uses_attributes = bool(np.any(ops == _ATTR))
        self.writes_aovs = bool(np.any(ops == _AOV_OUT))  # some AOV Output node (core.shader_aovs)
        self.objects = np.ascontiguousarray(objects if objects is not None else identity_object_row()[None], np.float32)
        self.texture_pack = pack_textures_rgba(textures)

    @classmethod
    def build(cls, materials, textures, max_lobes: int, objects: np.ndarray | None = None) -> "PreparedShading | None":
        programs = [getattr(mat, "program", None) for mat in materials]
        if all(p is None for p in programs):
            return None
        return cls(programs, textures, max_lobes, objects)

    def evaluate(self, rows: np.ndarray, mat: np.ndarray, P, N, Ng, I, uv, back, obj, lobes, select_scale,
                 emission: np.ndarray | None = None, uv_layers: np.ndarray | None = None,
                 extra: np.ndarray | None = None, dP=None, duv=None,
                 tangents=None, mesh_normal=None, normal_out: np.ndarray | None = None,
                 aov_out: np.ndarray | None = None) -> np.ndarray | None:
        """Run the programs of points `rows` in place on `lobes` (a LobeBatch with one row per point) and
        `emission` ((N, 3), optional). P, N, Ng, I (N, 3) float32 world space, uv (N, 2) or None, back (N,)
        bool, obj (N,) int32 object rows, uv_layers (N, K, 2) the named UV maps (Scene.uv_layer_names) or
        (N, K, 3, 2) with their derivatives along dP.dx and dP.dy, or None; extra (N, PATH_COLUMNS + 5 A) float32
        the path state and attributes (core.shading.program) or None.

        Vector nodes: dP (N, 2, 3) the ray differential's dP.dx and dP.dy (world units), duv (N, 2, 2) the active
        UV map's derivatives along them, tangents (N, T, 4) the tangent layers (Scene.tangent_layer_names:
        tangent xyz, bitangent sign; zeros where a mesh lacks the map), mesh_normal (N, 3) the interpolated,
        unnormalised mesh normal (outside); None reads zeros. aov_out (N, K, 4) float32: where the AOV Output
        nodes add their values (core.shader_aovs), None: they write nothing. Returns has_normal (N,) bool, the
        points whose program set the shading normal (written into normal_out (N, 3)), or None when no program
        sets one."""
        n = len(mat)
        if emission is None:
            emission = np.zeros((n, 3), np.float32)
        has_uv = uv is not None
        uvs = np.ascontiguousarray(uv, np.float32) if has_uv else np.zeros((0, 2), np.float32)
        scratch = np.empty((self.max_registers, 3), np.float32)
        if uv_layers is None:
            uvx = np.zeros((n, 0, 3, 2), np.float32)
        else:
            uvx = np.asarray(uv_layers, np.float32)
            if uvx.ndim == 3:  # values only: zero derivatives
                full = np.zeros((n, uvx.shape[1], 3, 2), np.float32)
                full[:, :, 0] = uvx
                uvx = full
            uvx = np.ascontiguousarray(uvx)
        ext = np.zeros((n, 0), np.float32) if extra is None else np.ascontiguousarray(extra, np.float32)
        dP = np.zeros((n, 2, 3), np.float32) if dP is None else np.ascontiguousarray(dP, np.float32)
        duv = np.zeros((n, 2, 2), np.float32) if duv is None else np.ascontiguousarray(duv, np.float32)
        tan = np.zeros((n, 0, 4), np.float32) if tangents is None else np.ascontiguousarray(tangents, np.float32)
        nraw = _f3(N) if mesh_normal is None else _f3(mesh_normal)
        has_normal = np.zeros(n, np.bool_)
        if normal_out is None:
            normal_out = np.zeros((n, 3), np.float32)
        if aov_out is None:
            aov_out = _NO_AOVS
        run_programs(np.ascontiguousarray(rows, np.int64), np.ascontiguousarray(mat, np.int64), self.prog_of_mat,
                     self.code, self.code_start, self.regs0, self.reg_start, self.data, self.data_start, self.bind,
                     self.emit_reg, self.normal_reg, *self.texture_pack, _f3(P), _f3(N), _f3(Ng), _f3(I), uvs,
                     has_uv, np.ascontiguousarray(back, np.bool_), np.ascontiguousarray(obj, np.int32), self.objects,
                     uvx, ext, dP, duv, tan, nraw, scratch, lobes.kind, lobes.weight, lobes.roughness, lobes.ior,
                     lobes.f0, lobes.tint, lobes.select, select_scale, emission, normal_out, has_normal, aov_out)
        return has_normal if self.any_sets_normal else None


_NO_AOVS = np.zeros((0, 1, 4), np.float32)


def _f3(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, np.float32).reshape(-1, 3))


def pack_textures_rgba(textures) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Images as one flat RGBA float32 buffer (row 0 at the top): (pixels, offset, height, width). An RGB image
    gets alpha 1."""
    parts, offsets, hs, ws = [], [], [], []
    at = 0
    for t in textures:
        px = np.asarray(getattr(t, "pixels", t), np.float32)
        h, w, ch = px.shape
        rgba = np.ones((h, w, 4), np.float32)
        rgba[..., :min(ch, 4)] = px[..., :4]
        parts.append(rgba.reshape(-1))
        offsets.append(at)
        at += rgba.size
        hs.append(h)
        ws.append(w)
    pixels = np.concatenate(parts) if parts else np.zeros(4, np.float32)
    return (np.ascontiguousarray(pixels, np.float32), np.asarray(offsets, np.int64), np.asarray(hs, np.int64),
            np.asarray(ws, np.int64))


def run_single(program: ShadingProgram, textures=(), P=(0, 0, 0), N=(0, 0, 1), Ng=None, I=(0, 0, 1), uv=(0.0, 0.0),
               back=False, objects: np.ndarray | None = None, uv_layers=(), extra=(), dP=((0, 0, 0), (0, 0, 0)),
               duv=((0, 0), (0, 0)), tangents=(), mesh_normal=None) -> np.ndarray:
    """The program's final register file at one shading point (tests, and the compiler's constant folding).
    uv_layers: K (u, v) pairs, or K x 3 x 2 (value, d/dx, d/dy); dP: dP.dx, dP.dy; tangents: T x 4 (tangent xyz,
    bitangent sign); mesh_normal: the unnormalised mesh normal (default N); extra: the
    point's path state and attributes (core.shading.program PATH_* columns), empty for none."""
    n_regs = max(program.registers.shape[0], 1)
    code = np.ascontiguousarray(program.code, np.int32).reshape(-1, WIDTH)
    P3, N3, I3 = (np.asarray(v, np.float32).reshape(1, 3) for v in (P, N, I))
    Ng3 = N3 if Ng is None else np.asarray(Ng, np.float32).reshape(1, 3)
    regs = np.array(program.registers, np.float32).reshape(-1, 3).copy()
    pack = pack_textures_rgba(textures)
    objs = np.ascontiguousarray(objects if objects is not None else identity_object_row()[None], np.float32)
    layers = np.asarray(uv_layers, np.float32)
    uvx = np.zeros((1, 0, 3, 2), np.float32)
    if layers.size:
        if layers.size % 6 == 0 and layers.ndim == 3:
            uvx = np.ascontiguousarray(layers.reshape(1, -1, 3, 2))
        else:
            flat = layers.reshape(-1, 2)
            uvx = np.zeros((1, flat.shape[0], 3, 2), np.float32)
            uvx[0, :, 0] = flat
    tan = np.asarray(tangents, np.float32).reshape(1, -1, 4)
    nraw = N3 if mesh_normal is None else np.asarray(mesh_normal, np.float32).reshape(1, 3)
    _run_one(code, regs, np.ascontiguousarray(program.data, np.float32), *pack, P3, N3, Ng3, I3,
             np.asarray(uv, np.float32).reshape(1, 2), np.array([bool(back)]), np.zeros(1, np.int32), objs,
             uvx, np.asarray(extra, np.float32).reshape(1, -1), np.asarray(dP, np.float32).reshape(1, 2, 3), np.asarray(duv, np.float32).reshape(1, 2, 2),
             np.ascontiguousarray(tan), np.ascontiguousarray(nraw))
    return regs[:n_regs]


@_jit
def _run_one(code, regs, data, tex_pixels, tex_offset, tex_h, tex_w, P, N, Ng, I, uv, back, obj, objects, uvx, extra,
             dP, duv, tan, nraw):
    for i in range(code.shape[0]):
        a = code[i]
        _execute(a[0], a, regs, data, 0, P, N, Ng, I, uv, True, back, obj, objects, tex_pixels, tex_offset, tex_h,
                 tex_w, uvx, extra, dP, duv, tan, nraw)
