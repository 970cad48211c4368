"""Compiler rules of the colour and converter nodes: Blender node -> core.shading.color instructions.

The nodes' settings become instruction operands and data-pool tables through addon/export/color_nodes.py (ramps
and curves baked with Blender's own evaluation, as Cycles bakes them). The Mix node's rule lives in rules.py; the
blend modes other than Mix come from here (rules.MIX_BLENDS).
"""

from __future__ import annotations

import numpy as np

from ....core.shading import color
from .. import color_nodes
from .compiler import FLOAT, RGBA, VECTOR
from .registry import rule
from .rules import MIX_BLENDS


def _mix_blend(blend: str):
    code = color.BLEND_TYPES[blend]

    def emit(c, node, fac: int, a: int, b: int, ctx) -> int:
        # rules.py has clamped the factor (Clamp Factor, legacy MixRGB) and clamps the result itself
        return c.emit("mix_color", factor=fac, a=a, b=b, blend=code, clamp_factor=0, clamp_result=0)["out"]

    return emit


MIX_BLENDS.update({name: _mix_blend(name) for name in color.BLEND_TYPES if name != "MIX"})


def _warn_working_space(c, node) -> None:
    message = color_nodes.working_space_warning()
    if message:
        c.warn(node, message)


@rule("ShaderNodeValToRGB", "Color Ramp", "converter", inputs=("Fac",), outputs=("Color", "Alpha"),
      notes="Every interpolation and colour mode: Blender's own ramp evaluation baked into a 257-entry table, "
            "as Cycles bakes it.")
def _color_ramp(c, node, ctx):
    k = color_nodes.color_ramp_constants(node)
    fac = c.input(node, 0, FLOAT, ctx)
    outs = c.emit("color_ramp", color=c.output_used(node, "Color", ctx), alpha=c.output_used(node, "Alpha", ctx),
                  fac=fac, table=c.add_data(k.table), rows=k.table.shape[0], interpolate=int(k.interpolate))
    result = {}
    if outs["color"] >= 0:
        result["Color"] = (outs["color"], RGBA)
    if outs["alpha"] >= 0:
        result["Alpha"] = (outs["alpha"], FLOAT)
    return result


def _curve(c, node, ctx, kind: str):
    fac = c.input(node, 0, FLOAT, ctx)
    value = c.input(node, 1, kind, ctx)
    try:
        k = color_nodes.curve_constants(node)
    except ValueError as exc:
        c.warn(node, f"{exc}; the input passes through unchanged")
        return value
    pool = c.add_data(np.concatenate([[k.lo, k.hi], k.table.reshape(-1)]))
    op = "float_curve" if kind == FLOAT else "curves"
    ops = {"value" if kind == FLOAT else "color": value}
    return c.emit(op, fac=fac, table=pool, rows=k.table.shape[0], extrapolate=int(k.extrapolate), **ops)["out"]


@rule("ShaderNodeRGBCurve", "RGB Curves", "color", inputs=("Fac", "Color"), outputs=("Color",),
      notes="Curves baked with Blender's evaluation (C curve first) over the points' x range, as Cycles; "
            "Extend Extrapolated extrapolates linearly. The Tone setting (Film Like) and black/white levels are "
            "ignored, as in Cycles.")
def _rgb_curves(c, node, ctx):
    return {"Color": (_curve(c, node, ctx, RGBA), RGBA)}


@rule("ShaderNodeVectorCurve", "Vector Curves", "vector", inputs=("Fac", "Vector"), outputs=("Vector",),
      notes="As RGB Curves, per component.")
def _vector_curves(c, node, ctx):
    return {"Vector": (_curve(c, node, ctx, VECTOR), VECTOR)}


@rule("ShaderNodeFloatCurve", "Float Curve", "converter", inputs=("Factor", "Value"), outputs=("Value",),
      notes="As RGB Curves, one curve.")
def _float_curve(c, node, ctx):
    return {"Value": (_curve(c, node, ctx, FLOAT), FLOAT)}


@rule("ShaderNodeHueSaturation", "Hue/Saturation/Value", "color",
      inputs=("Hue", "Saturation", "Value", "Fac", "Color"), outputs=("Color",))
def _hsv(c, node, ctx):
    ins = [c.input(node, i, FLOAT, ctx) for i in range(4)]
    r = c.emit("hue_saturation_value", hue=ins[0], saturation=ins[1], value=ins[2], fac=ins[3],
               color=c.input(node, 4, RGBA, ctx))["out"]
    return {"Color": (r, RGBA)}


@rule("ShaderNodeInvert", "Invert Color", "color", inputs=("Fac", "Color"), outputs=("Color",))
def _invert(c, node, ctx):
    r = c.emit("invert", fac=c.input(node, 0, FLOAT, ctx), color=c.input(node, 1, RGBA, ctx))["out"]
    return {"Color": (r, RGBA)}


@rule("ShaderNodeBrightContrast", "Brightness/Contrast", "color", inputs=("Color", "Bright", "Contrast"),
      outputs=("Color",))
def _bright_contrast(c, node, ctx):
    r = c.emit("bright_contrast", color=c.input(node, 0, RGBA, ctx), bright=c.input(node, 1, FLOAT, ctx),
               contrast=c.input(node, 2, FLOAT, ctx))["out"]
    return {"Color": (r, RGBA)}


@rule("ShaderNodeGamma", "Gamma", "color", inputs=("Color", "Gamma"), outputs=("Color",))
def _gamma(c, node, ctx):
    r = c.emit("gamma", color=c.input(node, 0, RGBA, ctx), gamma=c.input(node, 1, FLOAT, ctx))["out"]
    return {"Color": (r, RGBA)}


@rule("ShaderNodeRGBToBW", "RGB to BW", "converter", inputs=("Color",), outputs=("Val",),
      notes="Luminance of scene-linear Rec.709 (another working space warns).")
def _rgb_to_bw(c, node, ctx):
    _warn_working_space(c, node)
    return {"Val": (c.emit("rgb_to_bw", color=c.input(node, 0, RGBA, ctx))["out"], FLOAT)}


@rule("ShaderNodeSeparateColor", "Separate Color", "converter", inputs=("Color",), outputs=("Red", "Green", "Blue"),
      notes="RGB, HSV and HSL.")
def _separate_color(c, node, ctx):
    names = ("Red", "Green", "Blue")
    outs = c.emit("separate_color", color=c.input(node, 0, RGBA, ctx), mode=color_nodes.color_mode(node),
                  **{k: c.output_used(node, n, ctx) for k, n in zip("xyz", names)})
    return {n: (outs[k], FLOAT) for k, n in zip("xyz", names) if outs[k] >= 0}


@rule("ShaderNodeCombineColor", "Combine Color", "converter", inputs=("Red", "Green", "Blue"), outputs=("Color",),
      notes="RGB, HSV and HSL.")
def _combine_color(c, node, ctx):
    x, y, z = (c.input(node, i, FLOAT, ctx) for i in range(3))
    return {"Color": (c.emit("combine_color", x=x, y=y, z=z, mode=color_nodes.color_mode(node))["out"], RGBA)}


@rule("ShaderNodeBlackbody", "Blackbody", "converter", inputs=("Temperature",), outputs=("Color",),
      notes="Cycles' fit (800-12000 K, unit luminance) in scene-linear Rec.709 (another working space warns).")
def _blackbody(c, node, ctx):
    _warn_working_space(c, node)
    return {"Color": (c.emit("blackbody", temperature=c.input(node, 0, FLOAT, ctx))["out"], RGBA)}


@rule("ShaderNodeWavelength", "Wavelength", "converter", inputs=("Wavelength",), outputs=("Color",),
      notes="CIE 1931 matching functions every 5 nm (380-780 nm) to scene-linear Rec.709, as Cycles (another "
            "working space warns).")
def _wavelength(c, node, ctx):
    _warn_working_space(c, node)
    return {"Color": (c.emit("wavelength", wavelength=c.input(node, 0, FLOAT, ctx))["out"], RGBA)}
