"""Compiler rules of the procedural texture nodes (core.shading.procedural's opcodes): Blender node -> one
instruction each. An unlinked Vector input reads the Generated coordinates, as in Blender; the node's own
Texture Mapping panel (hidden in the sidebar) is not applied (warning when it is not the identity)."""

from __future__ import annotations

from ....core.shading import procedural as tex
from .compiler import FLOAT, RGBA, VECTOR
from .registry import rule


def _vector(c, node, ctx) -> int:
    if c.is_linked(node, "Vector", ctx):
        return c.input(node, "Vector", VECTOR, ctx)
    return c.emit("texture_coordinate", generated=True)["generated"]


def _mapping_check(c, node) -> None:
    m = getattr(node, "texture_mapping", None)
    if m is None:
        return
    moved = any(abs(v) > 1e-9 for v in (*m.translation, *m.rotation)) or any(abs(v - 1) > 1e-9 for v in m.scale)
    if moved or getattr(m, "mapping_x", "X") != "X" or getattr(m, "mapping_y", "Y") != "Y" \
            or getattr(m, "mapping_z", "Z") != "Z" or getattr(m, "use_min", False) or getattr(m, "use_max", False):
        c.warn(node, "the node's own Texture Mapping settings are not supported; they are ignored (use a "
                     "Mapping node)")


def _dims(node, prop: str) -> int:
    return int(getattr(node, prop, "3D")[0])


def _float(c, node, name, ctx) -> int:
    return c.input(node, name, FLOAT, ctx)


def _w(c, node, dims: int, ctx) -> int:
    return _float(c, node, "W", ctx) if dims in (1, 4) else c.const(0.0)


@rule("ShaderNodeTexWhiteNoise", "White Noise Texture", "texture", inputs=("Vector", "W"),
      outputs=("Value", "Color"), notes="1D-4D, as Cycles (same hash of the coordinates' bits).")
def _white_noise(c, node, ctx):
    dims = _dims(node, "noise_dimensions")
    outs = c.emit("tex_white_noise", value=c.output_used(node, "Value", ctx), color=c.output_used(node, "Color", ctx),
                  vector=_vector(c, node, ctx) if dims > 1 else c.const(0.0), w=_w(c, node, dims, ctx),
                  dimensions=dims)
    return {"Value": (outs["value"], FLOAT), "Color": (outs["color"], RGBA)}


@rule("ShaderNodeTexChecker", "Checker Texture", "texture", inputs=("Vector", "Color1", "Color2", "Scale"),
      outputs=("Color", "Fac"))
def _checker(c, node, ctx):
    _mapping_check(c, node)
    outs = c.emit("tex_checker", color=True, fac=True, vector=_vector(c, node, ctx),
                  color1=c.input(node, "Color1", RGBA, ctx), color2=c.input(node, "Color2", RGBA, ctx),
                  scale=_float(c, node, "Scale", ctx))
    return {"Color": (outs["color"], RGBA), "Fac": (outs["fac"], FLOAT)}


@rule("ShaderNodeTexGradient", "Gradient Texture", "texture", inputs=("Vector",), outputs=("Color", "Fac"),
      notes="All seven types.")
def _gradient(c, node, ctx):
    _mapping_check(c, node)
    outs = c.emit("tex_gradient", color=True, fac=True, vector=_vector(c, node, ctx),
                  gradient_type=tex.GRADIENT_TYPES[node.gradient_type])
    return {"Color": (outs["color"], RGBA), "Fac": (outs["fac"], FLOAT)}


@rule("ShaderNodeTexNoise", "Noise Texture", "texture",
      inputs=("Vector", "W", "Scale", "Detail", "Roughness", "Lacunarity", "Offset", "Gain", "Distortion"),
      outputs=("Fac", "Color"), notes="fBM, Multifractal, Hybrid/Ridged Multifractal, Hetero Terrain; 1D-4D; "
                                      "Normalize.")
def _noise(c, node, ctx):
    _mapping_check(c, node)
    dims = _dims(node, "noise_dimensions")
    names = ("Scale", "Detail", "Roughness", "Lacunarity", "Offset", "Gain", "Distortion")
    ins = {n.lower(): _float(c, node, n, ctx) for n in names}
    flags = tex.pack_flags(dims, tex.NOISE_TYPES[getattr(node, "noise_type", "FBM")],
                           int(getattr(node, "normalize", True)))
    outs = c.emit("tex_noise", fac=True, color=c.output_used(node, "Color", ctx),
                  vector=_vector(c, node, ctx) if dims > 1 else c.const(0.0), w=_w(c, node, dims, ctx), flags=flags,
                  **ins)
    return {"Fac": (outs["fac"], FLOAT), "Color": (outs["color"], RGBA)}


@rule("ShaderNodeTexVoronoi", "Voronoi Texture", "texture",
      inputs=("Vector", "W", "Scale", "Detail", "Roughness", "Lacunarity", "Smoothness", "Exponent", "Randomness"),
      outputs=("Distance", "Color", "Position", "W", "Radius"),
      notes="F1, F2, Smooth F1, Distance to Edge, N-Sphere Radius; all four metrics; 1D-4D; fractal Detail and "
            "Normalize.")
def _voronoi(c, node, ctx):
    _mapping_check(c, node)
    dims = _dims(node, "voronoi_dimensions")
    names = ("Scale", "Detail", "Roughness", "Lacunarity", "Smoothness", "Exponent", "Randomness")
    ins = {n.lower(): _float(c, node, n, ctx) for n in names}
    flags = tex.pack_flags(dims, tex.VORONOI_FEATURES[node.feature], tex.VORONOI_METRICS[node.distance],
                           int(getattr(node, "normalize", False)))
    used = {k: c.output_used(node, n, ctx) for k, n in (("distance", "Distance"), ("color", "Color"),
                                                           ("position", "Position"), ("w_out", "W"),
                                                           ("radius", "Radius"))}
    outs = c.emit("tex_voronoi", vector=_vector(c, node, ctx) if dims > 1 else c.const(0.0),
                  w=_w(c, node, dims, ctx), flags=flags, **used, **ins)
    return {"Distance": (outs["distance"], FLOAT), "Color": (outs["color"], RGBA),
            "Position": (outs["position"], VECTOR), "W": (outs["w_out"], FLOAT), "Radius": (outs["radius"], FLOAT)}


@rule("ShaderNodeTexWave", "Wave Texture", "texture",
      inputs=("Vector", "Scale", "Distortion", "Detail", "Detail Scale", "Detail Roughness", "Phase Offset"),
      outputs=("Color", "Fac"), notes="Bands and rings, every direction and profile.")
def _wave(c, node, ctx):
    _mapping_check(c, node)
    kind = tex.WAVE_TYPES[node.wave_type]
    direction = (tex.WAVE_BANDS_DIRECTIONS[node.bands_direction] if kind == tex.WAVE_BANDS
                 else tex.WAVE_RINGS_DIRECTIONS[node.rings_direction])
    ins = {k: _float(c, node, n, ctx) for k, n in (
        ("scale", "Scale"), ("distortion", "Distortion"), ("detail", "Detail"), ("detail_scale", "Detail Scale"),
        ("detail_roughness", "Detail Roughness"), ("phase", "Phase Offset"))}
    outs = c.emit("tex_wave", color=True, fac=True, vector=_vector(c, node, ctx),
                  flags=tex.pack_flags(kind, direction, tex.WAVE_PROFILES[node.wave_profile]), **ins)
    return {"Color": (outs["color"], RGBA), "Fac": (outs["fac"], FLOAT)}


@rule("ShaderNodeTexMagic", "Magic Texture", "texture", inputs=("Vector", "Scale", "Distortion"),
      outputs=("Color", "Fac"))
def _magic(c, node, ctx):
    _mapping_check(c, node)
    outs = c.emit("tex_magic", color=True, fac=True, vector=_vector(c, node, ctx),
                  scale=_float(c, node, "Scale", ctx), distortion=_float(c, node, "Distortion", ctx),
                  depth=min(max(int(node.turbulence_depth), 0), 10))
    return {"Color": (outs["color"], RGBA), "Fac": (outs["fac"], FLOAT)}


@rule("ShaderNodeTexBrick", "Brick Texture", "texture",
      inputs=("Vector", "Color1", "Color2", "Mortar", "Scale", "Mortar Size", "Mortar Smooth", "Bias",
              "Brick Width", "Row Height"), outputs=("Color", "Fac"),
      notes="Offset and squash frequencies above 15 are clamped to 15 (warning).")
def _brick(c, node, ctx):
    _mapping_check(c, node)
    freqs = []
    for name in ("offset_frequency", "squash_frequency"):
        f = int(getattr(node, name))
        if f > 15:
            c.warn(node, f"{name.replace('_', ' ')} {f} is above Monte's limit of 15; using 15")
            f = 15
        freqs.append(f)
    ins = {k: c.input(node, n, RGBA, ctx) for k, n in (("color1", "Color1"), ("color2", "Color2"),
                                                       ("mortar", "Mortar"))}
    ins.update({k: _float(c, node, n, ctx) for k, n in (
        ("scale", "Scale"), ("mortar_size", "Mortar Size"), ("mortar_smooth", "Mortar Smooth"), ("bias", "Bias"),
        ("brick_width", "Brick Width"), ("row_height", "Row Height"))})
    params = c.add_data([float(node.offset), float(node.squash)])
    outs = c.emit("tex_brick", color=True, fac=True, vector=_vector(c, node, ctx),
                  frequencies=tex.pack_flags(*freqs), params=params, **ins)
    return {"Color": (outs["color"], RGBA), "Fac": (outs["fac"], FLOAT)}


@rule("ShaderNodeTexGabor", "Gabor Texture", "texture",
      inputs=("Vector", "Scale", "Frequency", "Anisotropy", "Orientation 2D", "Orientation 3D"),
      outputs=("Value", "Phase", "Intensity"), notes="2D and 3D.")
def _gabor(c, node, ctx):
    _mapping_check(c, node)
    gt = tex.GABOR_TYPES[node.gabor_type]
    orient = [s for s in node.inputs if s.name == "Orientation"]
    o2 = c.socket_value(orient[0], FLOAT, ctx) if gt == 2 else c.const(0.0)
    o3 = c.socket_value(orient[1], VECTOR, ctx) if gt == 3 else c.const([0.0, 0.0, 1.0])
    used = {k.lower(): c.output_used(node, k, ctx) for k in ("Value", "Phase", "Intensity")}
    outs = c.emit("tex_gabor", vector=_vector(c, node, ctx), scale=_float(c, node, "Scale", ctx),
                  frequency=_float(c, node, "Frequency", ctx), anisotropy=_float(c, node, "Anisotropy", ctx),
                  orientation=o2, orientation_3d=o3, gabor_type=gt, **used)
    return {"Value": (outs["value"], FLOAT), "Phase": (outs["phase"], FLOAT),
            "Intensity": (outs["intensity"], FLOAT)}
