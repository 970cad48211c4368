"""Colour and converter shading nodes as compiled device functions, defined as Cycles' shader kernel defines them
(the per-pixel cross-check against Cycles is tests/test_color_nodes.py).

Each node is a scalar device function (colours as (r, g, b) tuples of float64; float32 inputs are promoted) that
a node program calls per shading point, plus a batch form at the bottom (NumPy arrays in and out) that tests and
benchmarks call, so what is tested is what renders. Colours are scene-linear Rec.709 (Blender's default working
space); the nodes that need a colour space (RGB to BW, Blackbody, Wavelength) say so.

Nodes whose settings are curves or ramps read a baked lookup table, as Cycles does: the exporter
(addon/export/color_nodes.py) evaluates Blender's own Color Ramp / Curve Mapping at `TABLE_SIZE` evenly spaced
positions and the device functions interpolate linearly between the entries (with Cycles' linear extrapolation
beyond the curve's range when the curve's Extend is Extrapolated). Tables are float32 arrays of shape
(TABLE_SIZE, channels); the device functions read them row-major from a flat float array at an offset (a node
program's data pool), the batch forms take them whole.

Factors: the Mix node clamps its factor to [0, 1] only with Clamp Factor, the legacy MixRGB node always; the other
nodes blend with the factor as given (Cycles does not clamp them either).
"""

from __future__ import annotations

import math

import numpy as np

from ..jit_cache import jit_no_nrt as jit  # device functions never allocate
from . import registry as R
from .regs import get3, getf, set3, setf

# Lookup tables hold the ramp or curve at TABLE_SIZE positions t_i = lo + i / (TABLE_SIZE - 1) (hi - lo).
TABLE_SIZE = 257

# ------------------------------------------------------------------------------------------------ enumerations
# Mix blend modes (the Mix node's and the legacy MixRGB node's `blend_type`).
MIX_BLEND, MIX_ADD, MIX_MUL, MIX_SUB, MIX_SCREEN, MIX_DIV, MIX_DIFF, MIX_DARK, MIX_LIGHT, MIX_OVERLAY, \
    MIX_DODGE, MIX_BURN, MIX_HUE, MIX_SAT, MIX_VAL, MIX_COLOR, MIX_SOFT, MIX_LINEAR, MIX_EXCLUSION = range(19)
BLEND_TYPES = {
    "MIX": MIX_BLEND, "ADD": MIX_ADD, "MULTIPLY": MIX_MUL, "SUBTRACT": MIX_SUB, "SCREEN": MIX_SCREEN,
    "DIVIDE": MIX_DIV, "DIFFERENCE": MIX_DIFF, "DARKEN": MIX_DARK, "LIGHTEN": MIX_LIGHT, "OVERLAY": MIX_OVERLAY,
    "DODGE": MIX_DODGE, "BURN": MIX_BURN, "HUE": MIX_HUE, "SATURATION": MIX_SAT, "VALUE": MIX_VAL,
    "COLOR": MIX_COLOR, "SOFT_LIGHT": MIX_SOFT, "LINEAR_LIGHT": MIX_LINEAR, "EXCLUSION": MIX_EXCLUSION,
}

# Separate / Combine Color modes.
COLOR_RGB, COLOR_HSV, COLOR_HSL = 0, 1, 2
COLOR_MODES = {"RGB": COLOR_RGB, "HSV": COLOR_HSV, "HSL": COLOR_HSL}

# ------------------------------------------------------------------------------------------- colour-space data
def _rec709_to_xyz() -> np.ndarray:
    """The RGB -> CIE XYZ matrix of Rec.709 (primaries r (0.64, 0.33), g (0.30, 0.60), b (0.15, 0.06); white D65
    (0.3127, 0.3290) at Y = 1): the columns are the primaries' XYZ, scaled so that RGB (1, 1, 1) is the white."""
    xy = np.array([[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]])
    primaries = np.stack([xy[:, 0] / xy[:, 1], np.ones(3), (1.0 - xy[:, 0] - xy[:, 1]) / xy[:, 1]])
    wx, wy = 0.3127, 0.3290
    white = np.array([wx / wy, 1.0, (1.0 - wx - wy) / wy])
    return primaries * np.linalg.solve(primaries, white)[None, :]


_RGB_TO_XYZ = _rec709_to_xyz()
# Luminance weights of scene-linear Rec.709 (the Y row of RGB -> XYZ): RGB to BW's output.
RGB_TO_Y = tuple(float(x) for x in _RGB_TO_XYZ[1])
# CIE XYZ -> scene-linear Rec.709, rows r, g, b: the Wavelength node's conversion.
XYZ_TO_RGB = tuple(tuple(float(x) for x in row) for row in np.linalg.inv(_RGB_TO_XYZ))

# Blackbody: Cycles' piecewise fit of the Planckian locus in Rec.709 with unit luminance, 800 K .. 12000 K
# (red and green a / T + b T + c, blue a cubic in T), seven segments starting at these temperatures.
_BB_STARTS = (965.0, 1167.0, 1449.0, 1902.0, 3315.0, 6365.0)
_BB_R = np.array([[1.61919106e+03, -2.05010916e-03, 5.02995757e+00],
                  [2.48845471e+03, -1.11330907e-03, 3.22621544e+00],
                  [3.34143193e+03, -4.86551192e-04, 1.76486769e+00],
                  [4.09461742e+03, -1.27446582e-04, 7.25731635e-01],
                  [4.67028036e+03, 2.91258199e-05, 1.26703442e-01],
                  [4.59509185e+03, 2.87495649e-05, 1.50345020e-01],
                  [3.78717450e+03, 9.35907826e-06, 3.99075871e-01]])
_BB_G = np.array([[-4.88999748e+02, 6.04330754e-04, -7.55807526e-02],
                  [-7.55994277e+02, 3.16730098e-04, 4.78306139e-01],
                  [-1.02363977e+03, 1.20223470e-04, 9.36662319e-01],
                  [-1.26571316e+03, 4.87340896e-06, 1.27054498e+00],
                  [-1.42529332e+03, -4.01150431e-05, 1.43972784e+00],
                  [-1.17554822e+03, -2.16378048e-05, 1.30408023e+00],
                  [-5.00799571e+02, -4.59832026e-06, 1.09098763e+00]])
_BB_B = np.array([[5.96945309e-11, -4.85742887e-08, -9.70622247e-05, -4.07936148e-03],
                  [2.40430366e-11, 5.55021075e-08, -1.98503712e-04, 2.89312858e-02],
                  [-1.40949732e-11, 1.89878968e-07, -3.56632824e-04, 9.10767778e-02],
                  [-3.61460868e-11, 2.84822009e-07, -4.93211319e-04, 1.56723440e-01],
                  [-1.97075738e-11, 1.75359352e-07, -2.50542825e-04, -2.22783266e-02],
                  [-1.61997957e-13, -1.64216008e-08, 3.86216271e-04, -7.38077418e-01],
                  [6.72650283e-13, -2.73078809e-08, 4.24098264e-04, -7.52335691e-01]])
# The fit's values at its ends: 12000 K and above, and below 800 K (where the light is very dim).
_BB_HOT = (0.8262954810464208, 0.9945080501520986, 1.566307710274283)
_BB_COLD = (5.413294490189271, -0.20319390035873933, -0.0822535242887164)

# CIE 1931 2-degree colour matching functions (x, y, z) at 380, 385, ..., 780 nm, as Cycles tabulates them.
_CIE_XYZ = np.array([
    [0.0014, 0.0000, 0.0065], [0.0022, 0.0001, 0.0105], [0.0042, 0.0001, 0.0201], [0.0076, 0.0002, 0.0362],
    [0.0143, 0.0004, 0.0679], [0.0232, 0.0006, 0.1102], [0.0435, 0.0012, 0.2074], [0.0776, 0.0022, 0.3713],
    [0.1344, 0.0040, 0.6456], [0.2148, 0.0073, 1.0391], [0.2839, 0.0116, 1.3856], [0.3285, 0.0168, 1.6230],
    [0.3483, 0.0230, 1.7471], [0.3481, 0.0298, 1.7826], [0.3362, 0.0380, 1.7721], [0.3187, 0.0480, 1.7441],
    [0.2908, 0.0600, 1.6692], [0.2511, 0.0739, 1.5281], [0.1954, 0.0910, 1.2876], [0.1421, 0.1126, 1.0419],
    [0.0956, 0.1390, 0.8130], [0.0580, 0.1693, 0.6162], [0.0320, 0.2080, 0.4652], [0.0147, 0.2586, 0.3533],
    [0.0049, 0.3230, 0.2720], [0.0024, 0.4073, 0.2123], [0.0093, 0.5030, 0.1582], [0.0291, 0.6082, 0.1117],
    [0.0633, 0.7100, 0.0782], [0.1096, 0.7932, 0.0573], [0.1655, 0.8620, 0.0422], [0.2257, 0.9149, 0.0298],
    [0.2904, 0.9540, 0.0203], [0.3597, 0.9803, 0.0134], [0.4334, 0.9950, 0.0087], [0.5121, 1.0000, 0.0057],
    [0.5945, 0.9950, 0.0039], [0.6784, 0.9786, 0.0027], [0.7621, 0.9520, 0.0021], [0.8425, 0.9154, 0.0018],
    [0.9163, 0.8700, 0.0017], [0.9786, 0.8163, 0.0014], [1.0263, 0.7570, 0.0011], [1.0567, 0.6949, 0.0010],
    [1.0622, 0.6310, 0.0008], [1.0456, 0.5668, 0.0006], [1.0026, 0.5030, 0.0003], [0.9384, 0.4412, 0.0002],
    [0.8544, 0.3810, 0.0002], [0.7514, 0.3210, 0.0001], [0.6424, 0.2650, 0.0000], [0.5419, 0.2170, 0.0000],
    [0.4479, 0.1750, 0.0000], [0.3608, 0.1382, 0.0000], [0.2835, 0.1070, 0.0000], [0.2187, 0.0816, 0.0000],
    [0.1649, 0.0610, 0.0000], [0.1212, 0.0446, 0.0000], [0.0874, 0.0320, 0.0000], [0.0636, 0.0232, 0.0000],
    [0.0468, 0.0170, 0.0000], [0.0329, 0.0119, 0.0000], [0.0227, 0.0082, 0.0000], [0.0158, 0.0057, 0.0000],
    [0.0114, 0.0041, 0.0000], [0.0081, 0.0029, 0.0000], [0.0058, 0.0021, 0.0000], [0.0041, 0.0015, 0.0000],
    [0.0029, 0.0010, 0.0000], [0.0020, 0.0007, 0.0000], [0.0014, 0.0005, 0.0000], [0.0010, 0.0004, 0.0000],
    [0.0007, 0.0002, 0.0000], [0.0005, 0.0002, 0.0000], [0.0003, 0.0001, 0.0000], [0.0002, 0.0001, 0.0000],
    [0.0002, 0.0001, 0.0000], [0.0001, 0.0000, 0.0000], [0.0001, 0.0000, 0.0000], [0.0001, 0.0000, 0.0000],
    [0.0000, 0.0000, 0.0000]])
# Cycles' empirical scale that keeps every Wavelength channel <= 1.
_WAVELENGTH_SCALE = 1.0 / 2.52


# --------------------------------------------------------------------------------------------- colour models
@jit
def _clamp01(x):
    """x clamped to [0, 1], NaN to 0 (as Cycles' saturatef)."""
    if not x > 0.0:
        return 0.0
    return 1.0 if x > 1.0 else x


@jit
def rgb_to_hsv(r, g, b):
    """(h, s, v), h in [0, 1): hexcone HSV; a grey (or black) has h = s = 0."""
    cmax = max(r, max(g, b))
    cmin = min(r, min(g, b))
    delta = cmax - cmin
    s = delta / cmax if cmax != 0.0 else 0.0
    h = 0.0
    if s != 0.0:
        cr, cg, cb = (cmax - r) / delta, (cmax - g) / delta, (cmax - b) / delta
        if r == cmax:
            h = cb - cg
        elif g == cmax:
            h = 2.0 + cr - cb
        else:
            h = 4.0 + cg - cr
        h /= 6.0
        if h < 0.0:
            h += 1.0
    return h, s, cmax


@jit
def hsv_to_rgb(h, s, v):
    """(r, g, b) of hexcone HSV; h = 1 is h = 0; h outside [0, 1] falls in the last sextant, as in Cycles."""
    if s == 0.0:
        return v, v, v
    if h == 1.0:
        h = 0.0
    h *= 6.0
    i = math.floor(h)
    f = h - i
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    if i == 0.0:
        return v, t, p
    if i == 1.0:
        return q, v, p
    if i == 2.0:
        return p, v, t
    if i == 3.0:
        return p, q, v
    if i == 4.0:
        return t, p, v
    return v, p, q


@jit
def rgb_to_hsl(r, g, b):
    """(h, s, l), h in [0, 1), l capped at 1."""
    cmax = max(r, max(g, b))
    cmin = min(r, min(g, b))
    lum = min(1.0, (cmax + cmin) / 2.0)
    if cmax == cmin:
        return 0.0, 0.0, lum
    delta = cmax - cmin
    s = delta / (2.0 - cmax - cmin) if lum > 0.5 else delta / (cmax + cmin)
    if cmax == r:
        h = (g - b) / delta + (6.0 if g < b else 0.0)
    elif cmax == g:
        h = (b - r) / delta + 2.0
    else:
        h = (r - g) / delta + 4.0
    return h / 6.0, s, lum


@jit
def hsl_to_rgb(h, s, lum):
    """(r, g, b) of HSL (the hue as three clamped triangle waves)."""
    nr = min(max(abs(h * 6.0 - 3.0) - 1.0, 0.0), 1.0)
    ng = min(max(2.0 - abs(h * 6.0 - 2.0), 0.0), 1.0)
    nb = min(max(2.0 - abs(h * 6.0 - 4.0), 0.0), 1.0)
    chroma = (1.0 - abs(2.0 * lum - 1.0)) * s
    return (nr - 0.5) * chroma + lum, (ng - 0.5) * chroma + lum, (nb - 0.5) * chroma + lum


# ------------------------------------------------------------------------------------------------------- Mix
@jit
def _lerp(a, b, t):
    return (1.0 - t) * a + t * b


@jit
def _overlay1(t, a, b):
    if a < 0.5:
        return a * (1.0 - t + 2.0 * t * b)
    return 1.0 - (1.0 - t + 2.0 * t * (1.0 - b)) * (1.0 - a)


@jit
def _divide1(t, a, b):
    if b != 0.0:
        return (1.0 - t) * a + t * a / b
    return a


@jit
def _dodge1(t, a, b):
    if a == 0.0:
        return a
    d = 1.0 - t * b
    if d <= 0.0:
        return 1.0
    q = a / d
    return 1.0 if q > 1.0 else q


@jit
def _burn1(t, a, b):
    d = 1.0 - t + t * b
    if d <= 0.0:
        return 0.0
    q = 1.0 - (1.0 - a) / d
    if q < 0.0:
        return 0.0
    return 1.0 if q > 1.0 else q


@jit
def _soft1(t, a, b):
    screen = 1.0 - (1.0 - b) * (1.0 - a)
    return (1.0 - t) * a + t * ((1.0 - a) * b * a + a * screen)


@jit
def _hsv_blend(mode, t, r1, g1, b1, r2, g2, b2):
    """Hue, Saturation, Value and Color: blends in HSV (Hue and Color only where colour 2 has a hue)."""
    if mode == MIX_HUE or mode == MIX_COLOR:
        h2, s2, _ = rgb_to_hsv(r2, g2, b2)
        if s2 == 0.0:
            return r1, g1, b1
        h, s, v = rgb_to_hsv(r1, g1, b1)
        if mode == MIX_COLOR:
            s = s2
        r, g, b = hsv_to_rgb(h2, s, v)
        return _lerp(r1, r, t), _lerp(g1, g, t), _lerp(b1, b, t)
    h, s, v = rgb_to_hsv(r1, g1, b1)
    if mode == MIX_SAT:
        if s == 0.0:
            return r1, g1, b1
        _, s2, _ = rgb_to_hsv(r2, g2, b2)
        return hsv_to_rgb(h, (1.0 - t) * s + t * s2, v)
    _, _, v2 = rgb_to_hsv(r2, g2, b2)  # MIX_VAL
    return hsv_to_rgb(h, s, (1.0 - t) * v + t * v2)


@jit
def mix_blend(mode, t, r1, g1, b1, r2, g2, b2):
    """Colour 1 blended with colour 2 by factor t (not clamped here) in blend mode `mode` (a MIX_* value)."""
    if mode == MIX_BLEND:
        return _lerp(r1, r2, t), _lerp(g1, g2, t), _lerp(b1, b2, t)
    if mode == MIX_ADD:
        return _lerp(r1, r1 + r2, t), _lerp(g1, g1 + g2, t), _lerp(b1, b1 + b2, t)
    if mode == MIX_MUL:
        return _lerp(r1, r1 * r2, t), _lerp(g1, g1 * g2, t), _lerp(b1, b1 * b2, t)
    if mode == MIX_SUB:
        return _lerp(r1, r1 - r2, t), _lerp(g1, g1 - g2, t), _lerp(b1, b1 - b2, t)
    if mode == MIX_SCREEN:
        tm = 1.0 - t
        return (1.0 - (tm + t * (1.0 - r2)) * (1.0 - r1), 1.0 - (tm + t * (1.0 - g2)) * (1.0 - g1),
                1.0 - (tm + t * (1.0 - b2)) * (1.0 - b1))
    if mode == MIX_DIV:
        return _divide1(t, r1, r2), _divide1(t, g1, g2), _divide1(t, b1, b2)
    if mode == MIX_DIFF:
        return _lerp(r1, abs(r1 - r2), t), _lerp(g1, abs(g1 - g2), t), _lerp(b1, abs(b1 - b2), t)
    if mode == MIX_EXCLUSION:
        return (max(_lerp(r1, r1 + r2 - 2.0 * r1 * r2, t), 0.0), max(_lerp(g1, g1 + g2 - 2.0 * g1 * g2, t), 0.0),
                max(_lerp(b1, b1 + b2 - 2.0 * b1 * b2, t), 0.0))
    if mode == MIX_DARK:
        return _lerp(r1, min(r1, r2), t), _lerp(g1, min(g1, g2), t), _lerp(b1, min(b1, b2), t)
    if mode == MIX_LIGHT:
        return _lerp(r1, max(r1, r2), t), _lerp(g1, max(g1, g2), t), _lerp(b1, max(b1, b2), t)
    if mode == MIX_OVERLAY:
        return _overlay1(t, r1, r2), _overlay1(t, g1, g2), _overlay1(t, b1, b2)
    if mode == MIX_DODGE:
        return _dodge1(t, r1, r2), _dodge1(t, g1, g2), _dodge1(t, b1, b2)
    if mode == MIX_BURN:
        return _burn1(t, r1, r2), _burn1(t, g1, g2), _burn1(t, b1, b2)
    if mode == MIX_SOFT:
        return _soft1(t, r1, r2), _soft1(t, g1, g2), _soft1(t, b1, b2)
    if mode == MIX_LINEAR:
        return r1 + t * (2.0 * r2 - 1.0), g1 + t * (2.0 * g2 - 1.0), b1 + t * (2.0 * b2 - 1.0)
    if mode == MIX_HUE or mode == MIX_SAT or mode == MIX_VAL or mode == MIX_COLOR:
        return _hsv_blend(mode, t, r1, g1, b1, r2, g2, b2)
    return 0.0, 0.0, 0.0


@jit
def mix_color(mode, fac, r1, g1, b1, r2, g2, b2, clamp_factor, clamp_result):
    """The Mix node in Color mode: factor clamped to [0, 1] with Clamp Factor, result with Clamp Result.
    The legacy MixRGB node is mix_color(mode, fac, ..., True, use_clamp)."""
    t = _clamp01(fac) if clamp_factor else fac
    r, g, b = mix_blend(mode, t, r1, g1, b1, r2, g2, b2)
    if clamp_result:
        return _clamp01(r), _clamp01(g), _clamp01(b)
    return r, g, b


# ------------------------------------------------------------------------------------------ ramps and curves
@jit
def table_lookup(data, offset, rows, width, c, f, interpolate, extrapolate):
    """Channel c of a lookup table spanning f in [0, 1], stored row-major in data[offset:] as `rows` rows of
    `width` floats (a program's data pool, or one table flattened): linear between rows (the row below with
    interpolate False), the end rows outside [0, 1], or with extrapolate the line through the two end rows."""
    base = offset + c
    if extrapolate and (f < 0.0 or f > 1.0):
        if f < 0.0:
            t0 = float(data[base])
            return t0 + (t0 - float(data[base + width])) * -f * (rows - 1)
        last = base + (rows - 1) * width
        t0 = float(data[last])
        return t0 + (t0 - float(data[last - width])) * (f - 1.0) * (rows - 1)
    x = _clamp01(f) * (rows - 1)
    i = min(int(x), rows - 1)
    t = x - i
    a = float(data[base + i * width])
    if interpolate and t > 0.0:
        a = (1.0 - t) * a + t * float(data[base + (i + 1) * width])
    return a


@jit
def color_ramp(data, offset, rows, interpolate, fac):
    """Color Ramp: (r, g, b, alpha) at fac from its baked RGBA table (rows x 4 floats at data[offset:]);
    interpolate False for Constant interpolation."""
    return (table_lookup(data, offset, rows, 4, 0, fac, interpolate, False),
            table_lookup(data, offset, rows, 4, 1, fac, interpolate, False),
            table_lookup(data, offset, rows, 4, 2, fac, interpolate, False),
            table_lookup(data, offset, rows, 4, 3, fac, interpolate, False))


@jit
def curves_rgb(data, offset, rows, lo, hi, extrapolate, fac, r, g, b):
    """RGB Curves and Vector Curves: each channel through its column of the table (rows x 3 floats at
    data[offset:]) baked over [lo, hi], blended with the input by fac."""
    span = hi - lo
    cr = table_lookup(data, offset, rows, 3, 0, (r - lo) / span, True, extrapolate)
    cg = table_lookup(data, offset, rows, 3, 1, (g - lo) / span, True, extrapolate)
    cb = table_lookup(data, offset, rows, 3, 2, (b - lo) / span, True, extrapolate)
    return (1.0 - fac) * r + fac * cr, (1.0 - fac) * g + fac * cg, (1.0 - fac) * b + fac * cb


@jit
def float_curve(data, offset, rows, lo, hi, extrapolate, fac, value):
    """Float Curve: value through the table (rows floats at data[offset:]) baked over [lo, hi], blended with the
    input by fac."""
    v = table_lookup(data, offset, rows, 1, 0, (value - lo) / (hi - lo), True, extrapolate)
    return (1.0 - fac) * value + fac * v


# -------------------------------------------------------------------------------------------- colour adjustments
@jit
def hue_saturation_value(hue, saturation, value, fac, r, g, b):
    """Hue/Saturation/Value: hue shifted by hue - 0.5 (wrapped), saturation scaled (clamped to [0, 1]), value
    scaled; blended with the input by fac; negative channels to 0."""
    h, s, v = rgb_to_hsv(r, g, b)
    h = h + hue + 0.5
    h = h - math.floor(h)
    s = _clamp01(s * saturation)
    v *= value
    hr, hg, hb = hsv_to_rgb(h, s, v)
    return (max(fac * hr + (1.0 - fac) * r, 0.0), max(fac * hg + (1.0 - fac) * g, 0.0),
            max(fac * hb + (1.0 - fac) * b, 0.0))


@jit
def invert(fac, r, g, b):
    """Invert: 1 - colour, blended with the input by fac."""
    return (fac * (1.0 - r) + (1.0 - fac) * r, fac * (1.0 - g) + (1.0 - fac) * g,
            fac * (1.0 - b) + (1.0 - fac) * b)


@jit
def bright_contrast(r, g, b, bright, contrast):
    """Bright/Contrast: (1 + contrast) c + bright - contrast / 2 per channel, negative values to 0."""
    a = 1.0 + contrast
    off = bright - contrast * 0.5
    return max(a * r + off, 0.0), max(a * g + off, 0.0), max(a * b + off, 0.0)


@jit
def _pow_positive(c, gamma):
    return c ** gamma if c > 0.0 else c


@jit
def gamma_correct(r, g, b, gamma):
    """Gamma: positive channels raised to gamma (others unchanged); gamma 0 gives white."""
    if gamma == 0.0:
        return 1.0, 1.0, 1.0
    return _pow_positive(r, gamma), _pow_positive(g, gamma), _pow_positive(b, gamma)


@jit
def rgb_to_bw(r, g, b):
    """RGB to BW: the luminance of scene-linear Rec.709."""
    return RGB_TO_Y[0] * r + RGB_TO_Y[1] * g + RGB_TO_Y[2] * b


@jit
def separate_color(mode, r, g, b):
    """Separate Color: the colour's (r, g, b), (h, s, v) or (h, s, l) for mode COLOR_RGB / HSV / HSL."""
    if mode == COLOR_HSV:
        return rgb_to_hsv(r, g, b)
    if mode == COLOR_HSL:
        return rgb_to_hsl(r, g, b)
    return r, g, b


@jit
def combine_color(mode, x, y, z):
    """Combine Color: the colour of (r, g, b), (h, s, v) or (h, s, l) for mode COLOR_RGB / HSV / HSL."""
    if mode == COLOR_HSV:
        return hsv_to_rgb(x, y, z)
    if mode == COLOR_HSL:
        return hsl_to_rgb(x, y, z)
    return x, y, z


# ------------------------------------------------------------------------------------------- light colours
@jit
def blackbody(temperature):
    """Blackbody: the colour of a black body at `temperature` kelvin with unit luminance (Cycles' fit, 800 K to
    12000 K; the end colours beyond), negative channels (outside the Rec.709 gamut) to 0."""
    t = temperature
    if t >= 12000.0:
        r, g, b = _BB_HOT
    elif t < 800.0:
        r, g, b = _BB_COLD
    else:
        i = 0
        while i < 6 and t >= _BB_STARTS[i]:
            i += 1
        inv = 1.0 / t
        r = _BB_R[i, 0] * inv + _BB_R[i, 1] * t + _BB_R[i, 2]
        g = _BB_G[i, 0] * inv + _BB_G[i, 1] * t + _BB_G[i, 2]
        b = ((_BB_B[i, 0] * t + _BB_B[i, 1]) * t + _BB_B[i, 2]) * t + _BB_B[i, 3]
    return max(r, 0.0), max(g, 0.0), max(b, 0.0)


@jit
def wavelength(nanometres):
    """Wavelength: the colour of monochromatic light (CIE 1931 matching functions interpolated every 5 nm,
    380-780 nm, black outside; to Rec.709, scaled by 1 / 2.52, negative channels to 0)."""
    x = (nanometres - 380.0) * 0.2
    if not (x > -1.0 and x < 80.0):  # Cycles truncates towards 0, so (-1, 0) still reads the first interval
        return 0.0, 0.0, 0.0
    i = int(x)
    f = x - i
    cx = (1.0 - f) * _CIE_XYZ[i, 0] + f * _CIE_XYZ[i + 1, 0]
    cy = (1.0 - f) * _CIE_XYZ[i, 1] + f * _CIE_XYZ[i + 1, 1]
    cz = (1.0 - f) * _CIE_XYZ[i, 2] + f * _CIE_XYZ[i + 1, 2]
    r = (XYZ_TO_RGB[0][0] * cx + XYZ_TO_RGB[0][1] * cy + XYZ_TO_RGB[0][2] * cz) * _WAVELENGTH_SCALE
    g = (XYZ_TO_RGB[1][0] * cx + XYZ_TO_RGB[1][1] * cy + XYZ_TO_RGB[1][2] * cz) * _WAVELENGTH_SCALE
    b = (XYZ_TO_RGB[2][0] * cx + XYZ_TO_RGB[2][1] * cy + XYZ_TO_RGB[2][2] * cz) * _WAVELENGTH_SCALE
    return max(r, 0.0), max(g, 0.0), max(b, 0.0)


# ---------------------------------------------------------------------- opcodes and the program's dispatcher
def _ops(*pairs: str) -> tuple[tuple[str, str], ...]:
    """Operands from "name:kind" strings, in slot order."""
    return tuple(tuple(p.split(":")) for p in pairs)


# Tables in a program's data pool: curves store lo, hi, then the table (rows x width floats, row-major); ramps the
# table alone.
OP_MIX_COLOR = R.register(R.OpSpec(
    "mix_color", R.COLOR_BASE + 0, _ops("out:out", "factor:in", "a:in", "b:in", "blend:int", "clamp_factor:int",
                                        "clamp_result:int"),
    "Mix node (Color), every blend mode: blend = core.shading.color.MIX_* code")).code
OP_COLOR_RAMP = R.register(R.OpSpec(
    "color_ramp", R.COLOR_BASE + 1, _ops("color:out?", "alpha:out?", "fac:in", "table:data", "rows:int",
                                         "interpolate:int"),
    "Color Ramp: RGBA table of `rows` rows at data[table]; interpolate 0 for Constant")).code
OP_CURVES = R.register(R.OpSpec(
    "curves", R.COLOR_BASE + 2, _ops("out:out", "fac:in", "color:in", "table:data", "rows:int", "extrapolate:int"),
    "RGB Curves / Vector Curves: data[table] = lo, hi, then the rows x 3 table")).code
OP_FLOAT_CURVE = R.register(R.OpSpec(
    "float_curve", R.COLOR_BASE + 3, _ops("out:out", "fac:in", "value:in", "table:data", "rows:int",
                                          "extrapolate:int"),
    "Float Curve: data[table] = lo, hi, then the rows x 1 table")).code
OP_HSV = R.register(R.OpSpec(
    "hue_saturation_value", R.COLOR_BASE + 4, _ops("out:out", "hue:in", "saturation:in", "value:in", "fac:in",
                                                   "color:in"), "Hue/Saturation/Value node")).code
OP_INVERT = R.register(R.OpSpec("invert", R.COLOR_BASE + 5, _ops("out:out", "fac:in", "color:in"),
                                "Invert node")).code
OP_BRIGHT_CONTRAST = R.register(R.OpSpec(
    "bright_contrast", R.COLOR_BASE + 6, _ops("out:out", "color:in", "bright:in", "contrast:in"),
    "Bright/Contrast node")).code
OP_GAMMA = R.register(R.OpSpec("gamma", R.COLOR_BASE + 7, _ops("out:out", "color:in", "gamma:in"),
                               "Gamma node")).code
OP_RGB_TO_BW = R.register(R.OpSpec("rgb_to_bw", R.COLOR_BASE + 8, _ops("out:out", "color:in"),
                                   "RGB to BW node: Rec.709 luminance (float)")).code
OP_SEPARATE_COLOR = R.register(R.OpSpec(
    "separate_color", R.COLOR_BASE + 9, _ops("x:out?", "y:out?", "z:out?", "color:in", "mode:int"),
    "Separate Color node: mode COLOR_RGB / HSV / HSL")).code
OP_COMBINE_COLOR = R.register(R.OpSpec(
    "combine_color", R.COLOR_BASE + 10, _ops("out:out", "x:in", "y:in", "z:in", "mode:int"),
    "Combine Color node: mode COLOR_RGB / HSV / HSL")).code
OP_BLACKBODY = R.register(R.OpSpec("blackbody", R.COLOR_BASE + 11, _ops("out:out", "temperature:in"),
                                   "Blackbody node (kelvin)")).code
OP_WAVELENGTH = R.register(R.OpSpec("wavelength", R.COLOR_BASE + 12, _ops("out:out", "wavelength:in"),
                                    "Wavelength node (nm)")).code


@jit
def run(op, a, regs, data):
    """One colour-family instruction: `a` its int32 slots (a[0] = op), registers (R, 3) float32, the program's
    float data pool. Operand slots follow the OpSpecs above."""
    if op == OP_MIX_COLOR:
        r1, g1, b1 = get3(regs, a[3])
        r2, g2, b2 = get3(regs, a[4])
        r, g, b = mix_color(a[5], getf(regs, a[2]), r1, g1, b1, r2, g2, b2, a[6] != 0, a[7] != 0)
        set3(regs, a[1], r, g, b)
    elif op == OP_COLOR_RAMP:
        r, g, b, alpha = color_ramp(data, a[4], a[5], a[6] != 0, getf(regs, a[3]))
        set3(regs, a[1], r, g, b)
        setf(regs, a[2], alpha)
    elif op == OP_CURVES:
        r, g, b = get3(regs, a[3])
        o = a[4]
        r, g, b = curves_rgb(data, o + 2, a[5], float(data[o]), float(data[o + 1]), a[6] != 0, getf(regs, a[2]),
                             r, g, b)
        set3(regs, a[1], r, g, b)
    elif op == OP_FLOAT_CURVE:
        o = a[4]
        setf(regs, a[1], float_curve(data, o + 2, a[5], float(data[o]), float(data[o + 1]), a[6] != 0,
                                     getf(regs, a[2]), getf(regs, a[3])))
    elif op == OP_HSV:
        r, g, b = get3(regs, a[6])
        r, g, b = hue_saturation_value(getf(regs, a[2]), getf(regs, a[3]), getf(regs, a[4]), getf(regs, a[5]),
                                       r, g, b)
        set3(regs, a[1], r, g, b)
    elif op == OP_INVERT:
        r, g, b = get3(regs, a[3])
        r, g, b = invert(getf(regs, a[2]), r, g, b)
        set3(regs, a[1], r, g, b)
    elif op == OP_BRIGHT_CONTRAST:
        r, g, b = get3(regs, a[2])
        r, g, b = bright_contrast(r, g, b, getf(regs, a[3]), getf(regs, a[4]))
        set3(regs, a[1], r, g, b)
    elif op == OP_GAMMA:
        r, g, b = get3(regs, a[2])
        r, g, b = gamma_correct(r, g, b, getf(regs, a[3]))
        set3(regs, a[1], r, g, b)
    elif op == OP_RGB_TO_BW:
        r, g, b = get3(regs, a[2])
        setf(regs, a[1], rgb_to_bw(r, g, b))
    elif op == OP_SEPARATE_COLOR:
        r, g, b = get3(regs, a[4])
        x, y, z = separate_color(a[5], r, g, b)
        setf(regs, a[1], x)
        setf(regs, a[2], y)
        setf(regs, a[3], z)
    elif op == OP_COMBINE_COLOR:
        r, g, b = combine_color(a[5], getf(regs, a[2]), getf(regs, a[3]), getf(regs, a[4]))
        set3(regs, a[1], r, g, b)
    elif op == OP_BLACKBODY:
        r, g, b = blackbody(getf(regs, a[2]))
        set3(regs, a[1], r, g, b)
    elif op == OP_WAVELENGTH:
        r, g, b = wavelength(getf(regs, a[2]))
        set3(regs, a[1], r, g, b)


# ------------------------------------------------------------------------- batch forms (tests and benchmarks)
@jit
def _mix_batch(mode, fac, a, b, clamp_factor, clamp_result, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = mix_color(mode, fac[k], a[k, 0], a[k, 1], a[k, 2], b[k, 0], b[k, 1],
                                                    b[k, 2], clamp_factor, clamp_result)


@jit
def _ramp_batch(table, rows, interpolate, fac, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = color_ramp(table, 0, rows, interpolate, fac[k])


@jit
def _curves_batch(table, rows, lo, hi, extrapolate, fac, c, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = curves_rgb(table, 0, rows, lo, hi, extrapolate, fac[k], c[k, 0], c[k, 1],
                                                     c[k, 2])


@jit
def _float_curve_batch(table, rows, lo, hi, extrapolate, fac, value, out):
    for k in range(out.shape[0]):
        out[k] = float_curve(table, 0, rows, lo, hi, extrapolate, fac[k], value[k])


@jit
def _hsv_batch(hue, sat, val, fac, c, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = hue_saturation_value(hue[k], sat[k], val[k], fac[k], c[k, 0], c[k, 1],
                                                                c[k, 2])


@jit
def _invert_batch(fac, c, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = invert(fac[k], c[k, 0], c[k, 1], c[k, 2])


@jit
def _bright_contrast_batch(c, bright, contrast, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = bright_contrast(c[k, 0], c[k, 1], c[k, 2], bright[k], contrast[k])


@jit
def _gamma_batch(c, gamma, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = gamma_correct(c[k, 0], c[k, 1], c[k, 2], gamma[k])


@jit
def _bw_batch(c, out):
    for k in range(out.shape[0]):
        out[k] = rgb_to_bw(c[k, 0], c[k, 1], c[k, 2])


@jit
def _separate_batch(mode, c, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = separate_color(mode, c[k, 0], c[k, 1], c[k, 2])


@jit
def _combine_batch(mode, c, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = combine_color(mode, c[k, 0], c[k, 1], c[k, 2])


@jit
def _blackbody_batch(t, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = blackbody(t[k])


@jit
def _wavelength_batch(nm, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = wavelength(nm[k])


def _values(v, n: int, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.ndim > 1 or (a.ndim == 1 and a.shape[0] not in (1, n)):
        raise ValueError(f"{name}: expected a scalar or {n} values, got shape {a.shape}")
    return np.ascontiguousarray(np.broadcast_to(a.reshape(-1) if a.ndim else a, (n,)))


def _colors(c, n: int, name: str) -> np.ndarray:
    a = np.asarray(c, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] < 3 or a.shape[0] not in (1, n):
        raise ValueError(f"{name}: expected one colour or {n} colours of 3 (or 4) channels, got shape "
                         f"{np.asarray(c).shape}")
    return np.ascontiguousarray(np.broadcast_to(a[:, :3], (n, 3)))


def _length(scalars=(), colors=()) -> int:
    n = 1
    for v in scalars:
        a = np.asarray(v)
        if a.ndim == 1:
            n = max(n, a.shape[0])
    for c in colors:
        a = np.asarray(c)
        if a.ndim == 2:
            n = max(n, a.shape[0])
    return n


def _table(table, channels: int, name: str) -> np.ndarray:
    t = np.asarray(table, dtype=np.float32)
    if t.ndim == 1 and channels == 1:
        t = t[:, None]
    if t.ndim != 2 or t.shape[1] != channels or t.shape[0] < 2:
        raise ValueError(f"{name}: expected a table of shape (rows >= 2, {channels}), got {np.asarray(table).shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name}: the table holds non-finite values")
    return np.ascontiguousarray(t)


def _blend_code(blend_type) -> int:
    if isinstance(blend_type, str):
        try:
            return BLEND_TYPES[blend_type]
        except KeyError:
            raise ValueError(f"unknown blend type {blend_type!r}; expected one of {', '.join(BLEND_TYPES)}") from None
    code = int(blend_type)
    if code not in BLEND_TYPES.values():
        raise ValueError(f"unknown blend type code {code}")
    return code


def _mode_code(mode) -> int:
    if isinstance(mode, str):
        try:
            return COLOR_MODES[mode]
        except KeyError:
            raise ValueError(f"unknown colour mode {mode!r}; expected one of {', '.join(COLOR_MODES)}") from None
    code = int(mode)
    if code not in COLOR_MODES.values():
        raise ValueError(f"unknown colour mode code {code}")
    return code


def mix_color_many(blend_type, fac, a, b, clamp_factor: bool = False, clamp_result: bool = False) -> np.ndarray:
    """The Mix node (Color) for N points: blend_type a Blender identifier ("MULTIPLY", ...) or MIX_* code; fac
    (N,) or scalar; a, b (N, 3) or one colour. Returns (N, 3) float64. Legacy MixRGB: clamp_factor=True."""
    code = _blend_code(blend_type)
    n = _length((fac,), (a, b))
    out = np.empty((n, 3))
    _mix_batch(code, _values(fac, n, "fac"), _colors(a, n, "a"), _colors(b, n, "b"), bool(clamp_factor),
               bool(clamp_result), out)
    return out


def color_ramp_many(table, interpolate: bool, fac) -> np.ndarray:
    """Color Ramp for N factors from its baked (rows, 4) RGBA table. Returns (N, 4): colour and alpha."""
    t = _table(table, 4, "ramp table")
    n = _length((fac,))
    out = np.empty((n, 4))
    _ramp_batch(t.ravel(), t.shape[0], bool(interpolate), _values(fac, n, "fac"), out)
    return out


def curves_many(table, lo: float, hi: float, extrapolate: bool, fac, color) -> np.ndarray:
    """RGB Curves / Vector Curves for N colours (or vectors) from the (rows, 3) table baked over [lo, hi]."""
    t = _table(table, 3, "curve table")
    if not hi > lo:
        raise ValueError(f"curve range [{lo}, {hi}] is empty")
    n = _length((fac,), (color,))
    out = np.empty((n, 3))
    _curves_batch(t.ravel(), t.shape[0], float(lo), float(hi), bool(extrapolate), _values(fac, n, "fac"),
                  _colors(color, n, "color"), out)
    return out


def float_curve_many(table, lo: float, hi: float, extrapolate: bool, fac, value) -> np.ndarray:
    """Float Curve for N values from the (rows,) table baked over [lo, hi]."""
    t = _table(table, 1, "curve table")
    if not hi > lo:
        raise ValueError(f"curve range [{lo}, {hi}] is empty")
    n = _length((fac, value))
    out = np.empty(n)
    _float_curve_batch(t.ravel(), t.shape[0], float(lo), float(hi), bool(extrapolate), _values(fac, n, "fac"),
                       _values(value, n, "value"), out)
    return out


def hue_saturation_value_many(hue, saturation, value, fac, color) -> np.ndarray:
    """Hue/Saturation/Value for N colours."""
    n = _length((hue, saturation, value, fac), (color,))
    out = np.empty((n, 3))
    _hsv_batch(_values(hue, n, "hue"), _values(saturation, n, "saturation"), _values(value, n, "value"),
               _values(fac, n, "fac"), _colors(color, n, "color"), out)
    return out


def invert_many(fac, color) -> np.ndarray:
    """Invert for N colours."""
    n = _length((fac,), (color,))
    out = np.empty((n, 3))
    _invert_batch(_values(fac, n, "fac"), _colors(color, n, "color"), out)
    return out


def bright_contrast_many(color, bright, contrast) -> np.ndarray:
    """Bright/Contrast for N colours."""
    n = _length((bright, contrast), (color,))
    out = np.empty((n, 3))
    _bright_contrast_batch(_colors(color, n, "color"), _values(bright, n, "bright"),
                           _values(contrast, n, "contrast"), out)
    return out


def gamma_many(color, gamma) -> np.ndarray:
    """Gamma for N colours."""
    n = _length((gamma,), (color,))
    out = np.empty((n, 3))
    _gamma_batch(_colors(color, n, "color"), _values(gamma, n, "gamma"), out)
    return out


def rgb_to_bw_many(color) -> np.ndarray:
    """RGB to BW for N colours: (N,) luminances."""
    n = _length((), (color,))
    out = np.empty(n)
    _bw_batch(_colors(color, n, "color"), out)
    return out


def separate_color_many(mode, color) -> np.ndarray:
    """Separate Color ("RGB", "HSV", "HSL") for N colours: (N, 3)."""
    n = _length((), (color,))
    out = np.empty((n, 3))
    _separate_batch(_mode_code(mode), _colors(color, n, "color"), out)
    return out


def combine_color_many(mode, channels) -> np.ndarray:
    """Combine Color ("RGB", "HSV", "HSL") for N channel triples (N, 3): (N, 3) colours."""
    n = _length((), (channels,))
    out = np.empty((n, 3))
    _combine_batch(_mode_code(mode), _colors(channels, n, "channels"), out)
    return out


def blackbody_many(temperature) -> np.ndarray:
    """Blackbody for N temperatures (kelvin): (N, 3)."""
    n = _length((temperature,))
    out = np.empty((n, 3))
    _blackbody_batch(_values(temperature, n, "temperature"), out)
    return out


def wavelength_many(nanometres) -> np.ndarray:
    """Wavelength for N wavelengths (nm): (N, 3)."""
    n = _length((nanometres,))
    out = np.empty((n, 3))
    _wavelength_batch(_values(nanometres, n, "wavelength"), out)
    return out
