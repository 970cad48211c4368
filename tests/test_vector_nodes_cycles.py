"""Normal Map, Bump, Vector Transform and Tangent against Cycles: per pixel on the emission plane (tests/shading_crosscheck.py: the node's
output normal, mapped to 0.5 n + 0.5, is the Emission colour), and a lit scene whose BSDFs use the normals.

The emission-plane images are the nodes' values at the pixel centres in both engines (see
tests/test_shading_crosscheck.py for the filter set-up), so they agree to float rounding: measured max |Monte -
Cycles| 5.8e-3 (bump: a few pixels where the height's finite differences cancel badly in float32), 98th
percentile 2e-4; normal maps 2.9e-3 max (image filtering), Vector Transform 3.6e-3 max; 98th percentiles < 1e-4.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import shading_crosscheck as sc  # noqa: E402

pytestmark = pytest.mark.blender


def _link(tree, out, node, key):
    if isinstance(key, str):
        key = next(i for i, s in enumerate(node.inputs) if s.identifier == key or s.name == key)
    tree.links.new(out, node.inputs[key])


def _math(tree, nodes, op, a, b=None, value=None):
    m = nodes.new("ShaderNodeMath")
    m.operation = op
    _link(tree, a, m, 0)
    if b is not None:
        _link(tree, b, m, 1)
    elif value is not None:
        m.inputs[1].default_value = value
    return m.outputs[0]


def _as_colour(tree, nodes, normal):
    vm = nodes.new("ShaderNodeVectorMath")
    vm.operation = "MULTIPLY_ADD"
    _link(tree, normal, vm, 0)
    vm.inputs[1].default_value = vm.inputs[2].default_value = (0.5, 0.5, 0.5)
    return vm.outputs[0]


def normal_map_image(name: str = "nmap", size: int = 16):
    """A smooth tangent-space normal map (Non-Color): bumps of sines, 2 n - 1 encoded."""
    img = bpy.data.images.new(name, size, size, alpha=False, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    u, v = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size)
    n = np.stack([0.5 * np.sin(2 * np.pi * u), 0.4 * np.cos(2 * np.pi * v), np.ones_like(u)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    px = np.ones((size, size, 4), np.float32)
    px[..., :3] = 0.5 * n + 0.5
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def height_field(tree, nodes):
    """sin(4 x) cos(3 y) of the object coordinates."""
    sep = nodes.new("ShaderNodeSeparateXYZ")
    _link(tree, nodes["Texture Coordinate"].outputs["Object"], sep, 0)
    s = _math(tree, nodes, "SINE", _math(tree, nodes, "MULTIPLY", sep.outputs[0], value=4.0))
    c = _math(tree, nodes, "COSINE", _math(tree, nodes, "MULTIPLY", sep.outputs[1], value=3.0))
    return _math(tree, nodes, "MULTIPLY", s, c)


def chained_bumps(tree, nodes):
    """A bump of object-space heights (strength 0.8), then an inverted bump of sin(7 v) of the UVs on top."""
    first = nodes.new("ShaderNodeBump")
    first.inputs["Distance"].default_value = 0.3
    first.inputs["Strength"].default_value = 0.8
    _link(tree, height_field(tree, nodes), first, "Height")
    sep = nodes.new("ShaderNodeSeparateXYZ")
    _link(tree, nodes["Texture Coordinate"].outputs["UV"], sep, 0)
    second = nodes.new("ShaderNodeBump")
    second.inputs["Distance"].default_value = 0.05
    second.invert = True
    _link(tree, _math(tree, nodes, "SINE", _math(tree, nodes, "MULTIPLY", sep.outputs[1], value=7.0)), second,
          "Height")
    _link(tree, first.outputs[0], second, "Normal")
    return _as_colour(tree, nodes, second.outputs[0])


def normal_map(space: str, convention: str = "OPENGL"):
    def build(tree, nodes):
        nm = nodes.new("ShaderNodeNormalMap")
        nm.space = nm_space = space
        nm.convention = convention
        nm.inputs["Strength"].default_value = 0.7
        if nm_space == "TANGENT":
            tex = nodes.new("ShaderNodeTexImage")
            tex.image = normal_map_image()
            colour = tex.outputs["Color"]
        else:
            sep = nodes.new("ShaderNodeSeparateXYZ")
            _link(tree, nodes["Texture Coordinate"].outputs["UV"], sep, 0)
            comb = nodes.new("ShaderNodeCombineXYZ")
            _link(tree, _math(tree, nodes, "MULTIPLY_ADD", sep.outputs[0], value=0.6), comb, 0)
            _link(tree, _math(tree, nodes, "MULTIPLY_ADD", sep.outputs[1], value=-0.5), comb, 1)
            comb.inputs[2].default_value = 0.85
            colour = comb.outputs[0]
        _link(tree, colour, nm, "Color")
        return _as_colour(tree, nodes, nm.outputs[0])
    return build


def vector_transform(kind: str, src: str, dst: str):
    """Vector Transform of Object coordinates (plus an offset, so that directions and points differ), scaled by
    0.3 into the emission colour (negative values included: the emission is not clamped)."""
    def build(tree, nodes):
        add = nodes.new("ShaderNodeVectorMath")
        add.operation = "ADD"
        _link(tree, nodes["Texture Coordinate"].outputs["Object"], add, 0)
        add.inputs[1].default_value = (0.3, -0.2, 0.5)
        vt = nodes.new("ShaderNodeVectorTransform")
        vt.vector_type, vt.convert_from, vt.convert_to = kind, src, dst
        _link(tree, add.outputs[0], vt, "Vector")
        scale = nodes.new("ShaderNodeVectorMath")
        scale.operation = "SCALE"
        _link(tree, vt.outputs[0], scale, 0)
        scale.inputs["Scale"].default_value = 0.3
        return scale.outputs[0]
    return build


def tangent(direction: str, axis: str = "Z"):
    """The Tangent node (radial about an axis, or the UV map's), or the Geometry node's Tangent for "GEOMETRY"."""
    def build(tree, nodes):
        if direction == "GEOMETRY":
            return _as_colour(tree, nodes, nodes["Geometry"].outputs["Tangent"])
        t = nodes.new("ShaderNodeTangent")
        t.direction_type = direction
        t.axis = axis
        return _as_colour(tree, nodes, t.outputs["Tangent"])
    return build


CASES = {
    "bump-chained": (chained_bumps, 1e-2),
    "normal-map-tangent": (normal_map("TANGENT"), 3e-3),
    "normal-map-tangent-directx": (normal_map("TANGENT", "DIRECTX"), 3e-3),
    "normal-map-object": (normal_map("OBJECT"), 3e-3),
    "normal-map-blender-world": (normal_map("BLENDER_WORLD"), 5e-3),
    "vector-transform-point-object-camera": (vector_transform("POINT", "OBJECT", "CAMERA"), 5e-3),
    "vector-transform-normal-world-object": (vector_transform("NORMAL", "WORLD", "OBJECT"), 5e-3),
    "vector-transform-vector-camera-world": (vector_transform("VECTOR", "CAMERA", "WORLD"), 5e-3),
    "vector-transform-point-camera-object": (vector_transform("POINT", "CAMERA", "OBJECT"), 5e-3),
    # radial about Z (about X or Y the flat plane's radial direction is its normal: degenerate in Cycles too); the
    # tangent turns quickly around the texture space's centre, where a pixel's jitter moves it most
    "tangent-radial-z": (tangent("RADIAL", "Z"), 1e-2),
    "tangent-uv-map": (tangent("UV_MAP"), 5e-3),
    "geometry-tangent": (tangent("GEOMETRY"), 1e-2),
}


@pytest.mark.parametrize("name", list(CASES))
def test_vector_node_normals_match_cycles_per_pixel(name):
    build, worst = CASES[name]
    scene = sc.emission_plane(build, size=32, name=name)
    ob = scene.objects["plane"]
    ob.rotation_euler = (0.0, 0.0, 0.5)  # object and world space differ, tangents are not world axes
    ob.scale = (1.3, 1.3, 1.3)
    uv = ob.data.uv_layers["UVMap"]  # UVs turned a quarter: the tangent runs along the object's y
    uv.data.foreach_set("uv", [1.0, 0.0, 1.0, 1.0, 0.0, 1.0, 0.0, 0.0])
    monte, cycles = sc.compare(scene, spp=2)
    diff = np.abs(monte - cycles)
    print(f"\n{name}: max |Monte - Cycles| {diff.max():.2e}, 98th percentile {np.quantile(diff, 0.98):.2e}")
    assert cycles.std() > 0.02  # the normal varies over the image
    assert np.quantile(diff, 0.98) < 1e-3
    assert diff.max() < worst


def lit_scene(size=(48, 48)):
    """A normal-mapped glossy-diffuse floor (Principled, tangent-space image normal map, repeated UVs) and a
    bump-mapped diffuse sphere (object-space sine heights) under a square area light and a dim world, seen
    from above at an angle."""
    import math

    import blender_fixtures as bf

    scene = bf.reset()
    floor_mat = bf.node_material("floor", "ShaderNodeBsdfPrincipled", Base_Color=(0.7, 0.6, 0.5, 1.0),
                                 Roughness=0.35)
    tree, nodes = floor_mat.node_tree, floor_mat.node_tree.nodes
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = normal_map_image("floor-nmap")
    nm = nodes.new("ShaderNodeNormalMap")
    _link(tree, tex.outputs["Color"], nm, "Color")
    _link(tree, nm.outputs[0], nodes["Principled BSDF"], "Normal")
    s = 3.0
    floor = bf.mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)], floor_mat)
    uv = floor.data.uv_layers.new(name="UVMap")
    uv.data.foreach_set("uv", [0.0, 0.0, 3.0, 0.0, 3.0, 3.0, 0.0, 3.0])

    ball_mat = bf.node_material("ball", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.8, 0.8, 1.0))
    tree, nodes = ball_mat.node_tree, ball_mat.node_tree.nodes
    nodes.new("ShaderNodeTexCoord")
    bump = nodes.new("ShaderNodeBump")
    bump.inputs["Distance"].default_value = 0.2
    _link(tree, height_field(tree, nodes), bump, "Height")
    _link(tree, bump.outputs[0], nodes["Diffuse BSDF"], "Normal")
    ball = bf.icosphere_object("ball", (0, 0, 1.0), 1.0, ball_mat, subdivisions=4)

    bf.add_light(scene, "AREA", (1.0, -1.0, 4.0), (0.2, 0.1, 0.0), energy=400.0, size=1.5)
    bf.camera_object(scene, (0.0, -7.0, 5.0), (math.radians(55), 0.0, 0.0), lens=35.0)
    bf.set_world(scene, (0.05, 0.05, 0.05), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    return scene


@pytest.mark.slow  # ~25 s with compiled kernels: over the default suite's budget for this file
def test_lit_normal_mapped_floor_and_bumped_sphere_match_cycles(tmp_path):
    """The lit scene at 128 spp: the image mean within 1 % of Cycles, the band of rows through the bumped sphere
    within 1.5 % and the side columns (normal-mapped floor) within 1 %. Measured: +0.35 % (image), +0.57 %
    (sphere band), +0.07 % (floor); without Cycles' bump shadowing (Monte before it) the image was +1.5 %, the
    sphere band +2.3 %. Monte's image means over seeds spread by ~0.1 %."""
    from monte.addon import crosscheck as cc

    scene = lit_scene()
    cc.configure_cycles(scene, 128, 8, threads=2, seed=1)
    cyc = cc.render_cycles(scene, tmp_path)[0]
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = 128, 8, 1, 2
    mon = cc.render_monte(scene)[0]
    rel = mon.mean(axis=(0, 1)) / cyc.mean(axis=(0, 1)) - 1
    band = mon[16:32].mean() / cyc[16:32].mean() - 1
    sides = np.r_[mon[:, :12].ravel(), mon[:, 36:].ravel()].mean() / \
        np.r_[cyc[:, :12].ravel(), cyc[:, 36:].ravel()].mean() - 1
    print(f"\nlit vector nodes: Cycles {np.round(cyc.mean(axis=(0, 1)), 4)} Monte "
          f"{np.round(mon.mean(axis=(0, 1)), 4)} rel {np.round(rel, 4)}, sphere band {band:+.4f}, floor {sides:+.4f}")
    assert cyc[16:32, 16:32].mean() > 1.5 * cyc[:, :4].mean()  # the lit sphere stands out
    assert np.all(np.abs(rel) < 0.01)
    assert abs(band) < 0.015 and abs(sides) < 0.01


def _normal_mapped_plane(scale=(1.0, 1.0, 1.0)):
    import blender_fixtures as bf

    scene = bf.reset()
    mat = bf.node_material("nm", "ShaderNodeBsdfDiffuse")
    tree = mat.node_tree
    nm = tree.nodes.new("ShaderNodeNormalMap")
    nm.inputs["Color"].default_value = (0.7, 0.5, 1.0, 1.0)
    _link(tree, nm.outputs[0], tree.nodes["Diffuse BSDF"], "Normal")
    ob = bf.mesh_object("plane", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)], mat)
    ob.data.uv_layers.new(name="UVMap").data.foreach_set("uv", [0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0])
    ob.rotation_euler = (0.0, 0.0, 0.5)
    ob.scale = scale
    bf.camera_object(scene, (0, 0, 3), (0, 0, 0))
    return scene


@pytest.mark.parametrize("mirrored", [False, True])
def test_export_carries_world_space_mikktspace_tangents(mirrored):
    """The plane's UV u runs along its object x: the exported tangent is that axis in world space (rotated by
    0.5 rad about z), sign +1; a mirroring instance (scale x = -1) flips the tangent with x and negates the sign,
    so that sign x (n x t) still gives the world direction of v."""
    from monte.addon.export import export_scene

    scene = _normal_mapped_plane((-1.0, 1.0, 1.0) if mirrored else (1.0, 1.0, 1.0))
    core, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    assert core.tangent_layer_names == [""] and core.warnings == []
    (mesh,) = core.meshes
    t = mesh.tangent_layers[""].reshape(-1, 4)
    x_axis = np.array([np.cos(0.5), np.sin(0.5), 0.0])
    y_axis = np.array([-np.sin(0.5), np.cos(0.5), 0.0])
    assert np.allclose(t[:, :3], -x_axis if mirrored else x_axis, atol=1e-5)
    assert np.allclose(t[:, 3], -1.0 if mirrored else 1.0)
    # the bitangent the normal map builds (sign n x t, n the exported face normal) is the world direction of v
    v0, v1, v2 = (mesh.vertices[i] for i in mesh.triangles[0])
    n = np.cross(v1 - v0, v2 - v0)
    n /= np.linalg.norm(n)
    assert np.allclose(t[0, 3] * np.cross(n, t[0, :3]), y_axis, atol=1e-5)


def test_bsdfs_with_different_normals_warn_and_share_the_first():
    from monte.addon.export import export_scene

    scene = _normal_mapped_plane()
    mat = bpy.data.materials["nm"]
    tree = mat.node_tree
    glossy = tree.nodes.new("ShaderNodeBsdfGlossy")
    mix = tree.nodes.new("ShaderNodeMixShader")
    _link(tree, tree.nodes["Diffuse BSDF"].outputs[0], mix, 1)
    _link(tree, glossy.outputs[0], mix, 2)
    tree.links.new(mix.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    core, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    assert core.warnings == ["material 'nm': node 'Glossy BSDF' (Glossy BSDF): its Normal input is unlinked; Monte "
                             "shades all BSDFs of a material with one normal, that of 'Diffuse BSDF'"]
    assert core.materials[0].program.normal >= 0


def test_diffuse_lobe_of_a_grazing_normal_mapped_principled_keeps_the_mapped_normal(tmp_path):
    """A Principled floor whose constant normal map tilts the normal ~58 degrees away from a camera looking at
    a grazing 20 degrees: the viewer is below the mapped normal, so Cycles tilts the specular closures' normal
    back (ensure_valid_specular_reflection) but keeps the diffuse closure on the mapped normal, which faces away
    from the light. Image mean within 1 % of Cycles at 64 spp (measured -0.4 %); Monte bending the diffuse lobe
    too rendered the image +66 % bright, and with the bump shadowing on the bent normal +2.5 %."""
    import math

    import blender_fixtures as bf
    from monte.addon import crosscheck as cc

    scene = bf.reset()
    mat = bf.node_material("floor", "ShaderNodeBsdfPrincipled", Base_Color=(0.8, 0.8, 0.8, 1.0), Roughness=0.5)
    tree, nodes = mat.node_tree, mat.node_tree.nodes
    nm = nodes.new("ShaderNodeNormalMap")
    nm.inputs["Color"].default_value = (0.92, 0.5, 0.76, 1.0)  # tangent space: towards +u (+x), ~58 degrees
    _link(tree, nm.outputs[0], nodes["Principled BSDF"], "Normal")
    s = 30.0
    floor = bf.mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)], mat)
    floor.data.uv_layers.new(name="UVMap").data.foreach_set("uv", [0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0])
    bf.add_light(scene, "AREA", (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), energy=300.0, size=2.0)
    # from the -x side looking towards +x, 20 degrees down: wo leans to -x, the mapped normal to +x
    bf.camera_object(scene, (-5.0, 0.0, 1.8), (math.radians(70), 0.0, math.radians(-90)), lens=85.0)
    bf.set_world(scene, (0.05, 0.05, 0.05), 1.0)
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.render.resolution_percentage = 100
    cc.configure_cycles(scene, 64, 4, threads=2, seed=1)
    cyc = cc.render_cycles(scene, tmp_path)[0]
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = 64, 4, 1, 2
    mon = cc.render_monte(scene)[0]
    rel = mon.mean() / cyc.mean() - 1
    print(f"\ngrazing normal-mapped Principled: Cycles {cyc.mean():.5f} Monte {mon.mean():.5f} ({rel:+.4f})")
    assert cyc[16:].mean() > 3 * 0.05  # the lit floor fills the lower half
    assert abs(rel) < 0.01
