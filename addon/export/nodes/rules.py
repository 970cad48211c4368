"""Compiler rules of the value nodes (inputs, maths, vectors, mapping, images): Blender node -> instructions.

Each rule is `fn(c, node, ctx) -> {output identifier or name: (register, kind)}` registered with `@rule`, which
is also the node's entry in the coverage table (docs/shading-nodes.md). `c` is the material's ProgramBuilder.
"""

from __future__ import annotations

import numpy as np

from ....core.shading import evaluator as ev
from .compiler import FLOAT, RGBA, VECTOR, CompileError
from .registry import document, rule

# Blend modes of the Mix (colour) node other than MIX: filled by the colour-node module's rules
# (blend_type -> fn(c, node, fac_reg, a_reg, b_reg, ctx) -> colour register).
MIX_BLENDS: dict = {}


def _out(r: int, kind: str):
    return (r, kind)


# ------------------------------------------------------------------------------------------------- inputs
@rule("ShaderNodeValue", "Value", "input", outputs=("Value",))
def _value(c, node, ctx):
    return {"Value": _out(c.const(float(node.outputs[0].default_value)), FLOAT)}


@rule("ShaderNodeRGB", "RGB", "input", outputs=("Color",))
def _rgb(c, node, ctx):
    return {"Color": _out(c.const(list(node.outputs[0].default_value)[:3]), RGBA)}


@rule("ShaderNodeTexCoord", "Texture Coordinate", "input",
      outputs=("Generated", "Normal", "UV", "Object", "Camera", "Window", "Reflection"),
      notes="Camera: camera space of the render camera (x right, y up, z forward, as Cycles); Window: the "
            "position in the full camera frame in [0, 1] (x from the left, y from the bottom, z 0; a render "
            "border does not change it), 0 under a panoramic camera. The Object field (another object's space) and From Instancer "
            "are not supported (warning; the hit object's space is used). Generated is the object's texture "
            "space (its bounding box) of the evaluated mesh, not of the undeformed original.")
def _texcoord(c, node, ctx):
    if getattr(node, "object", None) is not None:
        c.warn(node, f"coordinates of another object ({node.object.name!r}) are not supported; using the hit "
                     "object's")
    if getattr(node, "from_instancer", False):
        c.warn(node, "From Instancer is not supported; using the instance's own coordinates")
    names = ("Generated", "Normal", "UV", "Object", "Camera", "Window", "Reflection")
    used = {n: c.output_used(node, n, ctx) for n in names}
    outs = c.emit("texture_coordinate", **{n.lower(): used[n] for n in names})
    return {n: _out(outs[n.lower()], VECTOR) for n in names if outs[n.lower()] >= 0}


@rule("ShaderNodeUVMap", "UV Map", "input", outputs=("UV",),
      notes="Any UV map by name (a mesh without it reads (0, 0), as Blender); empty name: the active render map. "
            "From Instancer is not supported (warning).")
def _uvmap(c, node, ctx):
    name = getattr(node, "uv_map", "")
    if getattr(node, "from_instancer", False):
        c.warn(node, "From Instancer is not supported; using the instance's own UVs")
    if name and c.uv_layer_index is not None:
        return {"UV": _out(c.emit("uv_layer", layer=c.uv_layer_index(name), varying=True)["out"], VECTOR)}
    return {"UV": _out(c.emit("texture_coordinate", uv=True)["uv"], VECTOR)}


def _read_attribute(c, node, name: str, missing_alpha: float) -> dict:
    """{"color", "alpha", "fac"} registers of the named attribute ("" = the render colour attribute); a mesh
    without it reads 0 and alpha `missing_alpha` (Cycles: 1 for Attribute, 0 for Color Attribute)."""
    if c.attribute_index is None:  # compiled outside a scene export: as a mesh without the attribute
        return {"color": c.const(0.0), "alpha": c.const(missing_alpha), "fac": c.const(0.0)}
    c.attribute_uses.append((name, f"node {node.name!r} ({node.bl_label})"))
    return c.emit("attribute", layer=c.attribute_index(name), missing_alpha=int(missing_alpha), color=True,
                  alpha=True, fac=True)


@rule("ShaderNodeAttribute", "Attribute", "input", outputs=("Color", "Vector", "Fac", "Alpha"),
      notes="Geometry type: float, 2D vector, vector, colour (float and byte), integer and boolean attributes of "
            "the evaluated mesh by name (UV maps too), on points, faces and face corners, interpolated over each "
            "triangle as Cycles; a mesh without it reads 0, Alpha 1 (warning naming material, node, mesh and "
            "attribute). "
            "Object, Instancer and View Layer types read 0 (warning).")
def _attribute(c, node, ctx):
    kind = getattr(node, "attribute_type", "GEOMETRY")
    if kind != "GEOMETRY":
        c.warn(node, f"attribute type {kind} is not supported; the outputs read 0")
        zero = c.const(0.0)
        return {"Color": _out(zero, RGBA), "Vector": _out(zero, VECTOR), "Fac": _out(zero, FLOAT),
                "Alpha": _out(zero, FLOAT)}
    outs = _read_attribute(c, node, node.attribute_name, 1.0)
    return {"Color": _out(outs["color"], RGBA), "Vector": _out(outs["color"], VECTOR),
            "Fac": _out(outs["fac"], FLOAT), "Alpha": _out(outs["alpha"], FLOAT)}


@rule("ShaderNodeVertexColor", "Color Attribute", "input", outputs=("Color", "Alpha"),
      notes="Any colour attribute by name; empty name: the mesh's active render colour attribute. A mesh "
            "without it reads 0 (warning).")
def _color_attribute(c, node, ctx):
    outs = _read_attribute(c, node, getattr(node, "layer_name", ""), 0.0)
    return {"Color": _out(outs["color"], RGBA), "Alpha": _out(outs["alpha"], FLOAT)}


_LIGHT_PATH_OUTPUTS = {"Is Camera Ray": "is_camera", "Is Shadow Ray": "is_shadow", "Is Diffuse Ray": "is_diffuse",
                       "Is Glossy Ray": "is_glossy", "Is Singular Ray": "is_singular",
                       "Is Reflection Ray": "is_reflection", "Is Transmission Ray": "is_transmission",
                       "Ray Length": "ray_length", "Ray Depth": "ray_depth", "Diffuse Depth": "diffuse_depth",
                       "Glossy Depth": "glossy_depth", "Transparent Depth": "transparent_depth",
                       "Transmission Depth": "transmission_depth"}


@rule("ShaderNodeLightPath", "Light Path", "input", outputs=tuple(_LIGHT_PATH_OUTPUTS),
      notes="Cycles' ray flags and bounce counts of the path that reached the point; a light sample of a "
            "textured emitter sees no ray-kind flag and Ray Depth + 1, as Cycles. An emission driven by Is "
            "Diffuse/Glossy/... Ray splits between light and BSDF sampling by MIS weights that depend on the "
            "sampling strategy (Monte samples a triangle's area, Cycles its solid angle): such emitters differ "
            "from Cycles (Is Camera Ray and the depths agree). Is Shadow Ray reads 0: Monte's shadow rays do not "
            "run materials (every surface blocks them; warning). Is Volume Scatter Ray and Portal Depth read 0.")
def _light_path(c, node, ctx):
    if c.output_used(node, "Is Shadow Ray", ctx):
        c.warn(node, "Is Shadow Ray reads 0: shadow rays do not evaluate materials in Monte (every surface casts "
                     "a shadow)")
    for n in ("Is Volume Scatter Ray", "Portal Depth"):
        if c.output_used(node, n, ctx):
            c.warn(node, f"the {n} output is not supported; it reads 0")
    outs = c.emit("light_path", **{v: c.output_used(node, k, ctx) for k, v in _LIGHT_PATH_OUTPUTS.items()})
    res = {k: _out(outs[v], FLOAT) for k, v in _LIGHT_PATH_OUTPUTS.items() if outs[v] >= 0}
    zero = c.const(0.0)
    for n in ("Is Volume Scatter Ray", "Portal Depth"):
        res[n] = _out(zero, FLOAT)
    return res


@rule("ShaderNodeNewGeometry", "Geometry", "input",
      outputs=("Position", "Normal", "Tangent", "True Normal", "Incoming", "Backfacing"),
      notes="Tangent: Cycles' radial tangent about Z of the generated coordinates. Parametric, Pointiness and "
            "Random Per Island read 0 (warning).")
def _geometry(c, node, ctx):
    names = {"Position": "position", "Normal": "normal", "True Normal": "true_normal", "Incoming": "incoming",
             "Backfacing": "backfacing", "Parametric": "parametric"}
    for n in ("Parametric", "Pointiness", "Random Per Island"):
        if c.output_used(node, n, ctx):
            c.warn(node, f"the {n} output is not supported; it reads 0")
    outs = c.emit("geometry", **{v: c.output_used(node, k, ctx) for k, v in names.items()})
    res = {k: _out(outs[v], FLOAT if k == "Backfacing" else VECTOR) for k, v in names.items() if outs[v] >= 0}
    if c.output_used(node, "Tangent", ctx):
        generated = c.emit("texture_coordinate", generated=True)["generated"]
        res["Tangent"] = _out(c.emit("tangent", generated=generated, axis=2, layer=-1)["out"], VECTOR)
    return res


@rule("ShaderNodeObjectInfo", "Object Info", "input",
      outputs=("Location", "Color", "Alpha", "Object Index", "Material Index", "Random"),
      notes="Random is Monte's own hash of the object's name and instance (a uniform number in [0, 1) per "
            "object, not Cycles' value).")
def _object_info(c, node, ctx):
    names = {"Location": "location", "Color": "color", "Alpha": "alpha", "Object Index": "object_index",
             "Random": "random"}
    outs = c.emit("object_info", **{v: c.output_used(node, k, ctx) for k, v in names.items()})
    res = {k: _out(outs[v], RGBA if k == "Color" else (VECTOR if k == "Location" else FLOAT))
           for k, v in names.items() if outs[v] >= 0}
    res["Material Index"] = _out(c.const(float(c.material_pass_index)), FLOAT)
    return res


@rule("ShaderNodeFresnel", "Fresnel", "input", inputs=("IOR", "Normal"), outputs=("Fac",))
def _fresnel(c, node, ctx):
    n = c.input(node, "Normal", VECTOR, ctx) if c.is_linked(node, "Normal", ctx) else -1
    return {"Fac": _out(c.emit("fresnel", ior=c.input(node, "IOR", FLOAT, ctx), normal=n)["out"], FLOAT)}


@rule("ShaderNodeLayerWeight", "Layer Weight", "input", inputs=("Blend", "Normal"), outputs=("Fresnel", "Facing"))
def _layer_weight(c, node, ctx):
    n = c.input(node, "Normal", VECTOR, ctx) if c.is_linked(node, "Normal", ctx) else -1
    outs = c.emit("layer_weight", fresnel=True, facing=True, blend=c.input(node, "Blend", FLOAT, ctx), normal=n)
    return {"Fresnel": _out(outs["fresnel"], FLOAT), "Facing": _out(outs["facing"], FLOAT)}


# -------------------------------------------------------------------------------------------------- maths
@rule("ShaderNodeMath", "Math", "converter", inputs=("Value", "Value_001", "Value_002"), outputs=("Value",),
      notes="Every operation, with Cycles' safe semantics (division by 0, roots and logarithms of negatives "
            "give 0) and Clamp.")
def _math(c, node, ctx):
    op = node.operation
    if op not in ev.MATH_OPS:
        c.warn(node, f"operation {op} is not supported; the output reads 0")
        return {"Value": _out(c.const(0.0), FLOAT)}
    a, b, d = (c.input(node, i, FLOAT, ctx) for i in range(3))
    r = c.emit("math", a=a, b=b, c=d, operation=ev.MATH_OPS.index(op), clamp=int(node.use_clamp))["out"]
    return {"Value": _out(r, FLOAT)}


@rule("ShaderNodeVectorMath", "Vector Math", "vector", inputs=("Vector", "Vector_001", "Vector_002", "Scale"),
      outputs=("Vector", "Value"), notes="Every operation (Cycles' safe division, normalisation, projection).")
def _vector_math(c, node, ctx):
    op = node.operation
    if op not in ev.VECTOR_MATH_OPS:
        c.warn(node, f"operation {op} is not supported; the outputs read 0")
        return {"Vector": _out(c.const(0.0), VECTOR), "Value": _out(c.const(0.0), FLOAT)}
    a, b, d = (c.input(node, i, VECTOR, ctx) for i in range(3))
    s = c.input(node, 3, FLOAT, ctx)
    outs = c.emit("vector_math", vector=True, value=True, a=a, b=b, c=d, scale=s,
                  operation=ev.VECTOR_MATH_OPS.index(op))
    return {"Vector": _out(outs["vector"], VECTOR), "Value": _out(outs["value"], FLOAT)}


_MAP_RANGE_INTERP = ("LINEAR", "STEPPED", "SMOOTHSTEP", "SMOOTHERSTEP")


@rule("ShaderNodeMapRange", "Map Range", "converter",
      inputs=("Value", "From Min", "From Max", "To Min", "To Max", "Steps", "Vector"), outputs=("Result", "Vector"),
      notes="Float and Vector, all four interpolation types, Clamp (linear and stepped, as Cycles).")
def _map_range(c, node, ctx):
    vector = node.data_type == "FLOAT_VECTOR"
    interp = _MAP_RANGE_INTERP.index(node.interpolation_type)
    if vector:
        ins = [c.input(node, i, VECTOR, ctx) for i in range(6, 12)]
    else:
        ins = [c.input(node, i, FLOAT, ctx) for i in range(0, 6)]
    r = c.emit("map_range", value=ins[0], from_min=ins[1], from_max=ins[2], to_min=ins[3], to_max=ins[4],
               steps=ins[5], interpolation=interp, clamp=int(node.clamp), vector=int(vector))["out"]
    return {"Vector": _out(r, VECTOR)} if vector else {"Result": _out(r, FLOAT)}


@rule("ShaderNodeClamp", "Clamp", "converter", inputs=("Value", "Min", "Max"), outputs=("Result",),
      notes="Min Max and Range.")
def _clamp(c, node, ctx):
    ins = [c.input(node, i, FLOAT, ctx) for i in range(3)]
    r = c.emit("clamp", value=ins[0], min=ins[1], max=ins[2], range=int(node.clamp_type == "RANGE"))["out"]
    return {"Result": _out(r, FLOAT)}


@rule("ShaderNodeSeparateXYZ", "Separate XYZ", "converter", inputs=("Vector",), outputs=("X", "Y", "Z"))
def _separate_xyz(c, node, ctx):
    outs = c.emit("separate_xyz", x=True, y=True, z=True, vector=c.input(node, 0, VECTOR, ctx))
    return {"X": _out(outs["x"], FLOAT), "Y": _out(outs["y"], FLOAT), "Z": _out(outs["z"], FLOAT)}


@rule("ShaderNodeCombineXYZ", "Combine XYZ", "converter", inputs=("X", "Y", "Z"), outputs=("Vector",))
def _combine_xyz(c, node, ctx):
    x, y, z = (c.input(node, i, FLOAT, ctx) for i in range(3))
    return {"Vector": _out(c.emit("combine_xyz", x=x, y=y, z=z)["out"], VECTOR)}


_MAPPING_TYPES = ("POINT", "TEXTURE", "VECTOR", "NORMAL")


@rule("ShaderNodeMapping", "Mapping", "vector", inputs=("Vector", "Location", "Rotation", "Scale"),
      outputs=("Vector",), notes="Point, Texture, Vector and Normal; rotation as XYZ Euler.")
def _mapping(c, node, ctx):
    t = _MAPPING_TYPES.index(node.vector_type)
    v = c.input(node, "Vector", VECTOR, ctx)
    loc = c.input(node, "Location", VECTOR, ctx) if t < 2 else c.const(0.0)
    rot = c.input(node, "Rotation", VECTOR, ctx)
    scale = c.input(node, "Scale", VECTOR, ctx)
    return {"Vector": _out(c.emit("mapping", vector=v, location=loc, rotation=rot, scale=scale, type=t)["out"],
                           VECTOR)}


def _mix_colors(c, node, ctx, blend: str, fac: int, a: int, b: int, clamp_result: bool) -> int:
    if blend != "MIX":
        fn = MIX_BLENDS.get(blend)
        if fn is None:
            c.warn(node, f"blend mode {blend} is not supported yet; mixing as Mix")
        else:
            r = fn(c, node, fac, a, b, ctx)
            return _saturate(c, r) if clamp_result else r
    r = c.emit("mix", factor=fac, a=a, b=b, clamp=0, per_component=0)["out"]
    return _saturate(c, r) if clamp_result else r


def _saturate(c, r: int) -> int:
    lo = c.vmath("MAXIMUM", r, c.const(0.0))
    return c.vmath("MINIMUM", lo, c.const(1.0))


@rule("ShaderNodeMix", "Mix", "color", inputs=("Factor", "A", "B"), outputs=("Result",),
      notes="Float, Vector (uniform and non-uniform factor) and Color; Clamp Factor and Clamp Result. Colour "
            "in all 19 blend modes (those other than Mix: core.shading.color, as Cycles' kernel).")
def _mix(c, node, ctx):
    dt = node.data_type
    clamp_fac = bool(getattr(node, "clamp_factor", True))
    if dt == "FLOAT":
        fac = c.input(node, "Factor_Float", FLOAT, ctx)
        a, b = c.input(node, "A_Float", FLOAT, ctx), c.input(node, "B_Float", FLOAT, ctx)
        r = c.emit("mix", factor=fac, a=a, b=b, clamp=int(clamp_fac), per_component=0)["out"]
        return {"Result_Float": _out(r, FLOAT), "Result": _out(r, FLOAT)}
    if dt == "VECTOR":
        nonuniform = getattr(node, "factor_mode", "UNIFORM") == "NON_UNIFORM"
        fac = c.input(node, "Factor_Vector", VECTOR, ctx) if nonuniform else c.input(node, "Factor_Float", FLOAT, ctx)
        a, b = c.input(node, "A_Vector", VECTOR, ctx), c.input(node, "B_Vector", VECTOR, ctx)
        r = c.emit("mix", factor=fac, a=a, b=b, clamp=int(clamp_fac), per_component=int(nonuniform))["out"]
        return {"Result_Vector": _out(r, VECTOR), "Result": _out(r, VECTOR)}
    if dt == "RGBA":
        fac = c.input(node, "Factor_Float", FLOAT, ctx)
        if clamp_fac:
            fac = c.math("MINIMUM", c.math("MAXIMUM", fac, c.const(0.0)), c.const(1.0))
        a, b = c.input(node, "A_Color", RGBA, ctx), c.input(node, "B_Color", RGBA, ctx)
        r = _mix_colors(c, node, ctx, node.blend_type, fac, a, b, bool(getattr(node, "clamp_result", False)))
        return {"Result_Color": _out(r, RGBA), "Result": _out(r, RGBA)}
    raise CompileError(f"Mix node data type {dt} is not supported")


@rule("ShaderNodeMixRGB", "Mix (Legacy)", "color", inputs=("Fac", "Color1", "Color2"), outputs=("Color",),
      notes="As Mix (colour); the factor is clamped to [0, 1] as Cycles' legacy node.")
def _mix_rgb(c, node, ctx):
    fac = c.input(node, 0, FLOAT, ctx)
    fac = c.math("MINIMUM", c.math("MAXIMUM", fac, c.const(0.0)), c.const(1.0))
    a, b = c.input(node, 1, RGBA, ctx), c.input(node, 2, RGBA, ctx)
    return {"Color": _out(_mix_colors(c, node, ctx, node.blend_type, fac, a, b, bool(node.use_clamp)), RGBA)}


# ------------------------------------------------------------------------------------------------- images
_INTERP = {"Linear": 0, "Closest": 1, "Cubic": 2, "Smart": 2}
_EXTENSION = {"REPEAT": 0, "EXTEND": 1, "CLIP": 2, "MIRROR": 3}
_PROJECTION = {"FLAT": 0, "BOX": 1, "SPHERE": 2, "TUBE": 3}


@rule("ShaderNodeTexImage", "Image Texture", "texture", inputs=("Vector",), outputs=("Color", "Alpha"),
      notes="Flat, Box (Cycles' weights from the object-space normal, with Blend), Sphere and Tube projections; "
            "Linear, Closest, Cubic (Smart = Cubic, as Cycles on the CPU); Repeat, Extend, Clip, Mirror; colour "
            "spaces sRGB (decoded after filtering, as Cycles), Non-Color / Linear / Raw, others treated as sRGB "
            "(warning); alpha modes Straight, Premultiplied, Channel Packed, None with Cycles' association (the "
            "Color output is premultiplied unless the Alpha output is used). First frame / tile only. Missing or unreadable image: warning, magenta "
            "(Cycles' missing-texture colour).")
def _image(c, node, ctx):
    alpha_used = c.output_used(node, "Alpha", ctx)
    tex, flags = c.image_texture(node, alpha_used)
    if tex is None:  # missing: Cycles' TEX_IMAGE_MISSING colour
        return {"Color": _out(c.const([1.0, 0.0, 1.0]), RGBA), "Alpha": _out(c.const(1.0), FLOAT)}
    projection = _PROJECTION.get(node.projection)
    if projection is None:
        c.warn(node, f"{node.projection.lower()} projection is not supported; using flat")
        projection = 0
    vec = c.input(node, "Vector", VECTOR, ctx) if c.is_linked(node, "Vector", ctx) else -1
    interp = _INTERP.get(node.interpolation, 0)
    ext = _EXTENSION.get(node.extension, 0)
    blend = c.const(float(node.projection_blend)) if projection == 1 else -1
    outs = c.emit("image", color=True, alpha=True, vector=vec, texture=tex, interpolation=interp, extension=ext,
                  flags=flags, projection=projection, blend=blend, varying=vec < 0 or projection == 1)
    return {"Color": _out(outs["color"], RGBA), "Alpha": _out(outs["alpha"], FLOAT)}


# ---------------------------------------------------------------------------------------- layout / output
document("NodeReroute", "Reroute", "layout", notes="Followed (removed at export).")
document("NodeFrame", "Frame", "layout", notes="Ignored (layout only).")
document("ShaderNodeGroup", "Group", "layout",
         notes="Inlined, nested groups included; Group Input reads the group node's inputs.")
document("NodeGroupInput", "Group Input", "layout")
document("NodeGroupOutput", "Group Output", "layout", notes="The active Group Output is used.")
