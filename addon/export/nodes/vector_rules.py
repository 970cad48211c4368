"""Compiler rules of the Vector nodes that make shading normals (Normal Map, Bump) and the Normal node.

A BSDF's Normal input driven by these becomes the material program's `normal` binding (shaders.py): the
integrator rebuilds the point's shading frame around it. Bump evaluates its Height input three times, as Cycles
does: at the point and, through copies of the Height subgraph compiled in the builder's bump state, at the point
shifted along the surface by the ray differential's dP.dx and dP.dy times the node's Filter Width (the shading-
context ops of the copies read the shifted position and UVs).
"""

from __future__ import annotations

import numpy as np

from .compiler import FLOAT, RGBA, VECTOR
from .registry import rule

_SPACES = {"TANGENT": 0, "OBJECT": 1, "WORLD": 2, "BLENDER_OBJECT": 3, "BLENDER_WORLD": 4}


@rule("ShaderNodeNormalMap", "Normal Map", "vector", inputs=("Strength", "Color"), outputs=("Normal",),
      notes="Tangent space (MikkTSpace tangents of the named UV map, empty = the active render map, from the "
            "evaluated mesh; a mesh without that map keeps its normal, as Cycles), Object, World, Blender Object / "
            "World; OpenGL and DirectX conventions; Strength. Tangents are taken to world space with the object's "
            "normal matrix (exact for rotation, uniform scale and mirroring; non-uniformly scaled objects differ "
            "slightly from Cycles, which combines them in object space). Base (displacement) has no effect: "
            "Monte has no displacement.")
def _normal_map(c, node, ctx):
    space = _SPACES.get(node.space, 0)
    layer = -1
    if space == 0:
        if c.tangent_layer_index is None:
            c.warn(node, "tangent space needs mesh tangents, which this export does not provide; the normal is "
                         "left unperturbed")
        else:
            layer = c.tangent_layer_index(getattr(node, "uv_map", "") or "")
    flip = int(getattr(node, "convention", "OPENGL") == "DIRECTX")
    out = c.emit("normal_map", color=c.input(node, "Color", RGBA, ctx), strength=c.input(node, "Strength", FLOAT, ctx),
                 space=space, layer=layer, flip_y=flip, varying=True)
    return {"Normal": (out["normal"], VECTOR)}


@rule("ShaderNodeBump", "Bump", "vector", inputs=("Strength", "Distance", "Filter Width", "Height", "Normal"),
      outputs=("Normal",),
      notes="As Cycles: the Height at the point and at the point shifted by the ray differential (camera rays' "
            "pixel footprint, carried along bounces as Cycles' compact differentials) times Filter Width; "
            "Invert; chained bumps through the Normal input. An unlinked Height leaves the input normal.")
def _bump(c, node, ctx):
    normal_in = c.input(node, "Normal", VECTOR, ctx) if c.is_linked(node, "Normal", ctx) else -1
    if not c.is_linked(node, "Height", ctx):
        if normal_in >= 0:
            return {"Normal": (normal_in, VECTOR)}
        return {"Normal": (c.emit("geometry", normal=True)["normal"], VECTOR)}
    width = c.input(node, "Filter Width", FLOAT, ctx) if node.inputs.get("Filter Width") is not None \
        else c.const(1.0)
    height = c.input(node, "Height", FLOAT, ctx)
    with c.bump_copy(1, width):
        height_dx = c.input(node, "Height", FLOAT, ctx)
    with c.bump_copy(2, width):
        height_dy = c.input(node, "Height", FLOAT, ctx)
    out = c.emit("bump", strength=c.input(node, "Strength", FLOAT, ctx), distance=c.input(node, "Distance", FLOAT, ctx),
                 height=height, height_dx=height_dx, height_dy=height_dy, filter_width=width, normal_in=normal_in,
                 invert=int(bool(getattr(node, "invert", False))), varying=True)
    return {"Normal": (out["normal"], VECTOR)}


@rule("ShaderNodeNormal", "Normal", "vector", inputs=("Normal",), outputs=("Normal", "Dot"),
      notes="Normal: the node's direction (normalised); Dot: its dot product with the normalised input.")
def _normal(c, node, ctx):
    d = np.asarray(node.outputs["Normal"].default_value, np.float64)
    length = float(np.linalg.norm(d))
    direction = c.const(d / length if length > 0 else d)
    dot = c.vmath("DOT_PRODUCT", direction, c.vmath("NORMALIZE", c.input(node, "Normal", VECTOR, ctx)))
    return {"Normal": (direction, VECTOR), "Dot": (dot, FLOAT)}


@rule("ShaderNodeTangent", "Tangent", "input", outputs=("Tangent",),
      notes="Radial (about X, Y or Z of the generated coordinates) and UV Map (the map's MikkTSpace tangents, as "
            "Normal Map reads them; zero where a mesh lacks the map), made orthogonal to the normal, as Cycles.")
def _tangent(c, node, ctx):
    if node.direction_type == "UV_MAP":
        if c.tangent_layer_index is None:
            c.warn(node, "UV map tangents need mesh tangents, which this export does not provide; it reads 0")
            return {"Tangent": (c.const(0.0), VECTOR)}
        out = c.emit("tangent", layer=c.tangent_layer_index(getattr(node, "uv_map", "") or ""), axis=0)
    else:
        generated = c.emit("texture_coordinate", generated=True)["generated"]
        out = c.emit("tangent", generated=generated, axis={"X": 0, "Y": 1, "Z": 2}.get(node.axis, 2), layer=-1)
    return {"Tangent": (out["out"], VECTOR)}


_TRANSFORM_TYPES = {"POINT": 0, "VECTOR": 1, "NORMAL": 2}
_TRANSFORM_SPACES = {"WORLD": 0, "OBJECT": 1, "CAMERA": 2}


def _camera_transforms(c, node) -> list[float]:
    """World -> camera and camera -> world (3 x 4 row-major each) in Cycles' camera space (x right, y up, z
    forward: Blender's camera axes with z negated, scale removed); identity with a warning without a camera."""
    m = None if c.camera_matrix is None else np.asarray(c.camera_matrix, np.float64).reshape(4, 4)
    if m is None:
        c.warn(node, "camera space needs the render camera, which this export does not have; using world space")
        eye = np.eye(3, 4).reshape(-1).tolist()
        return eye + eye
    axes = m[:3, :3] / np.maximum(np.linalg.norm(m[:3, :3], axis=0), 1e-30)
    to_world = np.eye(4)
    to_world[:3, :3] = axes * np.array([1.0, 1.0, -1.0])
    to_world[:3, 3] = m[:3, 3]
    to_camera = np.linalg.inv(to_world)
    return to_camera[:3].reshape(-1).tolist() + to_world[:3].reshape(-1).tolist()


@rule("ShaderNodeVectorTransform", "Vector Transform", "vector", inputs=("Vector",), outputs=("Vector",),
      notes="Point, Vector, Normal between World, Object and Camera (Cycles' camera space: +z forward); a Normal "
            "is transformed as a direction and normalised, as Cycles. Camera space in the viewport: world space "
            "(warning).")
def _vector_transform(c, node, ctx):
    cam = c.add_data(_camera_transforms(c, node)) if "CAMERA" in (node.convert_from, node.convert_to) else 0
    out = c.emit("vector_transform", vector=c.input(node, "Vector", VECTOR, ctx),
                 type=_TRANSFORM_TYPES.get(node.vector_type, 0), convert_from=_TRANSFORM_SPACES[node.convert_from],
                 convert_to=_TRANSFORM_SPACES[node.convert_to], camera=cam, varying=node.convert_from != node.convert_to)
    return {"Vector": (out["out"], VECTOR)}


def tangent_uv_maps(materials) -> set[str]:
    """The UV map names ("" = the active render map) whose tangents the tangent-space Normal Map nodes of these
    materials (node groups included) read: what the mesh export computes MikkTSpace tangents for."""
    names: set[str] = set()
    seen: set[int] = set()

    def walk(tree) -> None:
        if tree is None or tree.as_pointer() in seen:
            return
        seen.add(tree.as_pointer())
        for node in tree.nodes:
            if node.bl_idname == "ShaderNodeNormalMap" and node.space == "TANGENT" and not node.mute:
                names.add(getattr(node, "uv_map", "") or "")
            elif node.bl_idname == "ShaderNodeTangent" and node.direction_type == "UV_MAP" and not node.mute:
                names.add(getattr(node, "uv_map", "") or "")
            elif node.bl_idname == "ShaderNodeGroup":
                walk(node.node_tree)

    for mat in materials:
        if mat is not None:
            walk(getattr(mat, "node_tree", None))
    return names
