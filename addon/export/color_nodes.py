"""The settings of Blender's colour and converter nodes -> the constants their device functions read
(core/shading/color.py).

Ramps and curves are baked exactly as Cycles bakes them: Blender's own evaluation (ColorRamp.evaluate,
CurveMapping.evaluate) at core.shading.color.TABLE_SIZE evenly spaced positions, so every interpolation mode
(Linear, Ease, Constant, Cardinal, B-Spline; RGB, HSV and HSL ramps) and every curve handle type comes out as
Blender draws it. Curves are baked over the x range of their points (all channels together) and their Extend
setting picks clamping (Extend Horizontal) or linear extrapolation (Extend Extrapolated) beyond it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.shading import color

# Blender's working colour spaces the colour-space constants of core.shading.color hold for.
_REC709_NAMES = ("Linear Rec.709", "Linear", "Linear BT.709", "Linear sRGB")


@dataclass(frozen=True)
class RampConstants:
    """A Color Ramp: its RGBA table (TABLE_SIZE, 4) float32 over factors [0, 1]; interpolate is False for
    Constant interpolation (the entry below the factor is used)."""

    table: np.ndarray
    interpolate: bool


@dataclass(frozen=True)
class CurveConstants:
    """A curve node: the table (TABLE_SIZE, channels) float32 baked over inputs [lo, hi] (columns r, g, b for RGB
    Curves with the C curve applied first; x, y, z for Vector Curves; one column for Float Curve) and whether
    values beyond [lo, hi] extrapolate linearly."""

    table: np.ndarray
    lo: float
    hi: float
    extrapolate: bool


@dataclass(frozen=True)
class MixConstants:
    """A Mix node in Color mode (or a legacy MixRGB node): blend mode code (core.shading.color.MIX_*), factor and
    result clamping."""

    blend: int
    clamp_factor: bool
    clamp_result: bool


def color_ramp_constants(node) -> RampConstants:
    """The constants of a Color Ramp node (ShaderNodeValToRGB)."""
    ramp = node.color_ramp
    n = color.TABLE_SIZE
    table = np.array([tuple(ramp.evaluate(i / (n - 1))) for i in range(n)], dtype=np.float32)
    return RampConstants(table, ramp.interpolation != "CONSTANT")


def _prepared(mapping):
    """The curve mapping with its evaluation tables built from the current points (as Cycles does before
    reading it)."""
    mapping.update()
    mapping.initialize()
    return mapping


def _x_range(mapping, count: int, owner: str) -> tuple[float, float]:
    lo, hi = np.inf, -np.inf
    for curve in list(mapping.curves)[:count]:
        points = curve.points
        if len(points):
            lo = min(lo, points[0].location[0])
            hi = max(hi, points[-1].location[0])
    if not hi > lo:
        raise ValueError(f"{owner}: the curve's points span no x range ([{lo}, {hi}])")
    return float(lo), float(hi)


def curve_constants(node) -> CurveConstants:
    """The constants of an RGB Curves, Vector Curves or Float Curve node (ShaderNodeRGBCurve, ShaderNodeVectorCurve,
    ShaderNodeFloatCurve). Raises ValueError naming the node when its curve has no x range (all points at one x)."""
    owner = f"node {node.name!r} ({node.bl_label})"
    mapping = _prepared(node.mapping)
    curves = list(mapping.curves)
    n = color.TABLE_SIZE
    kind = node.bl_idname
    if kind == "ShaderNodeFloatCurve":
        lo, hi = _x_range(mapping, 1, owner)
        xs = lo + np.arange(n, dtype=np.float64) / (n - 1) * (hi - lo)
        table = np.array([[mapping.evaluate(curves[0], float(x))] for x in np.float32(xs)], dtype=np.float32)
    elif kind == "ShaderNodeRGBCurve":
        lo, hi = _x_range(mapping, 4, owner)
        xs = lo + np.arange(n, dtype=np.float64) / (n - 1) * (hi - lo)
        rows = []
        for x in np.float32(xs):
            c = mapping.evaluate(curves[3], float(x))
            rows.append([mapping.evaluate(curves[k], c) for k in range(3)])
        table = np.array(rows, dtype=np.float32)
    elif kind == "ShaderNodeVectorCurve":
        lo, hi = _x_range(mapping, 3, owner)
        xs = lo + np.arange(n, dtype=np.float64) / (n - 1) * (hi - lo)
        table = np.array([[mapping.evaluate(curves[k], float(x)) for k in range(3)] for x in np.float32(xs)],
                         dtype=np.float32)
    else:
        raise ValueError(f"{owner} is not a curve node")
    return CurveConstants(table, lo, hi, mapping.extend == "EXTRAPOLATED")


def mix_constants(node) -> MixConstants:
    """The constants of a Mix node in Color mode (ShaderNodeMix, data_type 'RGBA') or a legacy MixRGB node.
    Raises ValueError naming the node for another Mix data type (Float and Vector mixes are not colour nodes)."""
    if node.bl_idname == "ShaderNodeMixRGB":
        return MixConstants(color.BLEND_TYPES[node.blend_type], True, bool(node.use_clamp))
    if node.bl_idname != "ShaderNodeMix" or node.data_type != "RGBA":
        raise ValueError(f"node {node.name!r} ({node.bl_label}) is not a Mix node in Color mode")
    return MixConstants(color.BLEND_TYPES[node.blend_type], bool(node.clamp_factor), bool(node.clamp_result))


def color_mode(node) -> int:
    """The mode code (core.shading.color.COLOR_RGB / HSV / HSL) of a Separate Color or Combine Color node."""
    return color.COLOR_MODES[node.mode]


def working_space_warning() -> str | None:
    """A warning when the blend file's scene-linear working space is not Rec.709: RGB to BW, Blackbody and
    Wavelength then use Rec.709's constants (their colours are off by the gamut difference). None when it is
    Rec.709 or Blender has no per-file working space (before 5.0: Rec.709 with the default configuration)."""
    import bpy

    space = getattr(getattr(bpy.data, "colorspace", None), "working_space", None)
    if space is None or space in _REC709_NAMES:
        return None
    return (f"the working colour space {space!r} is not Linear Rec.709; this node uses Rec.709's luminance and "
            f"primaries")
