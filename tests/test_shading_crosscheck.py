"""Shading nodes against Cycles, per node family: a plane's Emission colour is the node's output, rendered by
Monte and by Cycles (tests/shading_crosscheck.py) and compared per pixel.

Every sample lands within 0.005 px of its pixel centre in both engines (Cycles' Gaussian filter of width 0.01
px, Monte's box of the same width), so each pixel is the node's output at the pixel centre up to float rounding
(measured: Monte equals the analytic value of the math chain to 6e-6; Cycles agrees with Monte to <= 5e-4, the
float32 differences of Cycles' fast sin/pow approximations). A sample jittered by 0.005 px moves an output
of slope 3/UV-unit by 6e-4: outputs must agree to 1e-3 per pixel, allowing 2 % of the pixels (a rare sample
farther out, a kink within the jitter) up to 2e-2.
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
SMOOTH_TOL = 1e-3


def link(tree, out, node, key):
    """Link `out` to the input of `node` given by index, identifier or name."""
    if isinstance(key, str):
        key = next(i for i, sock in enumerate(node.inputs) if sock.identifier == key or sock.name == key)
    tree.links.new(out, node.inputs[key])


def math_chain(tree, nodes):
    """sin(3 u) * v + pingpong(u, 0.3), smooth-min'ed against 0.6, through a node group and a muted node."""
    uv = nodes["Texture Coordinate"].outputs["UV"]
    sep = nodes.new("ShaderNodeSeparateXYZ")
    link(tree, uv, sep, 0)
    sine = nodes.new("ShaderNodeMath")
    sine.operation = "MULTIPLY"
    sine.inputs[1].default_value = 3.0
    link(tree, sep.outputs["X"], sine, 0)
    s2 = nodes.new("ShaderNodeMath")
    s2.operation = "SINE"
    link(tree, sine.outputs[0], s2, 0)
    muted = nodes.new("ShaderNodeMath")  # muted: passes its first input through
    muted.operation = "POWER"
    muted.mute = True
    link(tree, s2.outputs[0], muted, 0)
    mul = nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    link(tree, muted.outputs[0], mul, 0)
    link(tree, sep.outputs["Y"], mul, 1)
    # a node group computing pingpong(x, 0.3)
    group = bpy.data.node_groups.new("pp", "ShaderNodeTree")
    group.interface.new_socket("x", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("y", in_out="OUTPUT", socket_type="NodeSocketFloat")
    gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    pp = group.nodes.new("ShaderNodeMath")
    pp.operation = "PINGPONG"
    pp.inputs[1].default_value = 0.3
    group.links.new(gin.outputs[0], pp.inputs[0])
    reroute = group.nodes.new("NodeReroute")
    group.links.new(pp.outputs[0], reroute.inputs[0])
    group.links.new(reroute.outputs[0], gout.inputs[0])
    gnode = nodes.new("ShaderNodeGroup")
    gnode.node_tree = group
    link(tree, sep.outputs["X"], gnode, 0)
    add = nodes.new("ShaderNodeMath")
    add.operation = "ADD"
    link(tree, mul.outputs[0], add, 0)
    link(tree, gnode.outputs[0], add, 1)
    smin = nodes.new("ShaderNodeMath")
    smin.operation = "SMOOTH_MIN"
    smin.inputs[1].default_value = 0.6
    smin.inputs[2].default_value = 0.2
    link(tree, add.outputs[0], smin, 0)
    comb = nodes.new("ShaderNodeCombineXYZ")
    link(tree, smin.outputs[0], comb, 0)
    link(tree, add.outputs[0], comb, 1)
    link(tree, s2.outputs[0], comb, 2)
    return comb.outputs[0]


def vectors(tree, nodes):
    """Object coordinates -> Mapping (point, rotated and scaled) -> Vector Math cross/normalize/reflect ->
    Map Range (smootherstep, vector) -> Mix (non-uniform vector factor)."""
    obj = nodes["Texture Coordinate"].outputs["Object"]
    mapping = nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Location"].default_value = (0.1, -0.2, 0.3)
    mapping.inputs["Rotation"].default_value = (0.3, 0.5, 0.7)
    mapping.inputs["Scale"].default_value = (1.5, 0.7, 1.0)
    link(tree, obj, mapping, 0)
    cross = nodes.new("ShaderNodeVectorMath")
    cross.operation = "CROSS_PRODUCT"
    cross.inputs[1].default_value = (0.2, 0.9, 0.4)
    link(tree, mapping.outputs[0], cross, 0)
    refl = nodes.new("ShaderNodeVectorMath")
    refl.operation = "REFLECT"
    link(tree, cross.outputs[0], refl, 0)
    link(tree, nodes["Geometry"].outputs["Normal"], refl, 1)
    maprange = nodes.new("ShaderNodeMapRange")
    maprange.data_type = "FLOAT_VECTOR"
    maprange.interpolation_type = "SMOOTHERSTEP"
    link(tree, refl.outputs[0], maprange, "Vector")
    maprange.inputs[7].default_value = (-1.0, -1.0, -1.0)
    maprange.inputs[8].default_value = (1.0, 1.0, 1.0)
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "VECTOR"
    mix.factor_mode = "NON_UNIFORM"
    link(tree, nodes["Texture Coordinate"].outputs["UV"], mix, "Factor_Vector")
    link(tree, next(o for o in maprange.outputs if o.identifier == "Vector"), mix, "A_Vector")
    link(tree, mapping.outputs[0], mix, "B_Vector")
    return next(sock for sock in mix.outputs if sock.identifier == "Result_Vector")


def inputs_and_fresnel(tree, nodes):
    """Generated, Layer Weight and Fresnel with a varying Normal input, Geometry Position / Incoming."""
    gen = nodes["Texture Coordinate"].outputs["Generated"]
    normal = nodes.new("ShaderNodeVectorMath")
    normal.operation = "NORMALIZE"
    comb = nodes.new("ShaderNodeVectorMath")
    comb.operation = "ADD"
    comb.inputs[1].default_value = (-0.5, -0.5, 0.8)
    link(tree, gen, comb, 0)
    link(tree, comb.outputs[0], normal, 0)
    fres = nodes.new("ShaderNodeFresnel")
    fres.inputs["IOR"].default_value = 1.8
    link(tree, normal.outputs[0], fres, "Normal")
    lw = nodes.new("ShaderNodeLayerWeight")
    lw.inputs["Blend"].default_value = 0.3
    link(tree, normal.outputs[0], lw, "Normal")
    dot = nodes.new("ShaderNodeVectorMath")
    dot.operation = "DOT_PRODUCT"
    link(tree, nodes["Geometry"].outputs["Position"], dot, 0)
    link(tree, nodes["Geometry"].outputs["Incoming"], dot, 1)
    comb2 = nodes.new("ShaderNodeCombineXYZ")
    link(tree, fres.outputs[0], comb2, 0)
    link(tree, lw.outputs["Facing"], comb2, 1)
    clamp = nodes.new("ShaderNodeClamp")
    clamp.clamp_type = "RANGE"
    clamp.inputs["Min"].default_value = 0.9
    clamp.inputs["Max"].default_value = -0.2
    link(tree, dot.outputs["Value"], clamp, 0)
    add = nodes.new("ShaderNodeMath")
    add.operation = "ADD"
    link(tree, clamp.outputs[0], add, 0)
    link(tree, lw.outputs["Fresnel"], add, 1)
    link(tree, add.outputs[0], comb2, 2)
    return comb2.outputs[0]


def object_info(tree, nodes):
    """Object Info (location, colour, pass index, material index) mixed by a stepped Map Range and Clamp of the
    UV Map node's coordinates; the plane is moved, coloured and given a pass index by the test."""
    info = nodes.new("ShaderNodeObjectInfo")
    uvmap = nodes.new("ShaderNodeUVMap")
    sep = nodes.new("ShaderNodeSeparateXYZ")
    link(tree, uvmap.outputs["UV"], sep, 0)
    steps = nodes.new("ShaderNodeMapRange")
    steps.interpolation_type = "STEPPED"
    steps.inputs["Steps"].default_value = 3.0
    link(tree, sep.outputs["X"], steps, "Value")
    scale = nodes.new("ShaderNodeVectorMath")
    scale.operation = "SCALE"
    link(tree, info.outputs["Color"], scale, 0)
    link(tree, steps.outputs["Result"], scale, "Scale")
    index = nodes.new("ShaderNodeMath")
    index.operation = "MULTIPLY_ADD"
    link(tree, info.outputs["Object Index"], index, 0)
    index.inputs[1].default_value = 0.1
    link(tree, info.outputs["Material Index"], index, 2)
    loc = nodes.new("ShaderNodeVectorMath")
    loc.operation = "ADD"
    link(tree, info.outputs["Location"], loc, 0)
    link(tree, sep.outputs["Y"], loc, 1)
    clamp = nodes.new("ShaderNodeClamp")
    link(tree, loc.outputs["Vector"], clamp, 0)  # vector -> float: the average
    clamp.inputs["Max"].default_value = 0.7
    comb = nodes.new("ShaderNodeCombineXYZ")
    link(tree, index.outputs[0], comb, 0)
    link(tree, clamp.outputs[0], comb, 1)
    add = nodes.new("ShaderNodeVectorMath")
    add.operation = "ADD"
    link(tree, comb.outputs[0], add, 0)
    link(tree, scale.outputs["Vector"], add, 1)
    return add.outputs["Vector"]


CASES = {"math": math_chain, "vectors": vectors, "inputs-fresnel": inputs_and_fresnel, "object-info": object_info}


@pytest.mark.parametrize("name", list(CASES))
def test_smooth_node_outputs_match_cycles_per_pixel(name):
    scene = sc.emission_plane(CASES[name], size=24, name=name)
    ob = scene.objects["plane"]
    ob.location, ob.scale, ob.pass_index, ob.color = (0.1, -0.05, 0.3), (1.2, 1.1, 1.0), 3, (0.9, 0.4, 0.2, 1.0)
    bpy.data.materials[name].pass_index = 2
    monte, cycles = sc.compare(scene, spp=2)
    diff = np.abs(monte - cycles)
    print(f"\n{name}: max |Monte - Cycles| {diff.max():.2e}, mean {diff.mean():.2e}, "
          f"image mean {cycles.mean():.4f}")
    assert cycles.std() > 0.02  # the output varies over the plane: the comparison has power
    assert np.mean(diff.max(axis=2) > SMOOTH_TOL) < 0.02
    assert diff.max() < 2e-2


def checker_image(name: str = "tex"):
    """A 4 x 3 8-bit sRGB RGBA image with distinct texels and alphas 0.25..1 (straight alpha)."""
    img = bpy.data.images.new(name, 4, 3, alpha=True)
    rng = np.random.default_rng(7)
    px = rng.uniform(0.05, 1.0, (3, 4, 4)).astype(np.float32)
    px[..., 3] = rng.choice([0.25, 0.5, 1.0], (3, 4))
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


IMAGE_CASES = {  # (interpolation, extension, use the Alpha output)
    "linear-repeat": ("Linear", "REPEAT", False),
    "closest-extend": ("Closest", "EXTEND", True),
    "cubic-clip": ("Cubic", "CLIP", False),
    "linear-mirror-alpha": ("Linear", "MIRROR", True),
}


@pytest.mark.parametrize("name", list(IMAGE_CASES))
def test_image_texture_matches_cycles_per_pixel(name):
    interpolation, extension, use_alpha = IMAGE_CASES[name]

    def build(tree, nodes):
        mapping = nodes.new("ShaderNodeMapping")
        mapping.inputs["Location"].default_value = (-0.613, -0.587, 0.0)
        mapping.inputs["Scale"].default_value = (2.2, 2.2, 1.0)
        link(tree, nodes["Texture Coordinate"].outputs["UV"], mapping, 0)
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = checker_image()
        tex.interpolation, tex.extension = interpolation, extension
        link(tree, mapping.outputs[0], tex, "Vector")
        if not use_alpha:
            return tex.outputs["Color"]
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        link(tree, tex.outputs["Alpha"], mix, "Factor_Float")
        mix.inputs[6].default_value = (0.0, 0.2, 1.0, 1.0)  # A: blue where transparent
        link(tree, tex.outputs["Color"], mix, "B_Color")
        return next(o for o in mix.outputs if o.identifier == "Result_Color")

    scene = sc.emission_plane(build, size=24, name=name)
    monte, cycles = sc.compare(scene, spp=2)
    diff = np.abs(monte - cycles).max(axis=2)
    print(f"\n{name}: max |Monte - Cycles| {diff.max():.2e}, share > 2e-3 {np.mean(diff > 2e-3):.3f}, "
          f"std {cycles.std():.3f}")
    assert cycles.std() > 0.02
    # Measured: closest 3e-7, cubic 8e-4, linear 6e-3 at a few pixels (the 0.005 px jitter across a texel step
    # of up to 0.9 in 1/9 px of texture), the rest to float rounding (8-bit sRGB texels associated in bytes and
    # decoded after filtering, as Cycles).
    assert np.mean(diff > 2e-3) < 0.03
    assert np.median(diff) < 5e-4


@pytest.mark.slow
def test_lit_textured_principled_mixed_by_layer_weight_matches_cycles(tmp_path):
    """A sphere under a white sky whose Principled BSDF has an image-textured Base Color (object coordinates
    through a Mapping), a Roughness from a Math node and Metallic from a Map Range of the position, mixed with
    a Glossy BSDF by Layer Weight's Facing: per-point lobe weights, roughness and Mix factor. The sphere's mean
    colour must match Cycles within 1 % (one render's mean spreads by ~0.15 % at 128 spp, as the Principled
    cross-checks in tests/test_addon_cycles.py measure). Measured: -0.28/-0.31/-0.19 %."""
    import blender_fixtures as bf
    from monte.addon import crosscheck as cc

    def make():
        mat = bf.node_material("textured", "ShaderNodeBsdfPrincipled")
        tree = mat.node_tree
        nodes = tree.nodes
        principled = nodes["Principled BSDF"]
        coords = nodes.new("ShaderNodeTexCoord")
        mapping = nodes.new("ShaderNodeMapping")
        mapping.inputs["Scale"].default_value = (1.3, 1.3, 1.3)
        link(tree, coords.outputs["Object"], mapping, 0)
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = checker_image("sphere-tex")
        link(tree, mapping.outputs[0], tex, "Vector")
        link(tree, tex.outputs["Color"], principled, "Base Color")
        sep = nodes.new("ShaderNodeSeparateXYZ")
        link(tree, coords.outputs["Object"], sep, 0)
        rough = nodes.new("ShaderNodeMath")
        rough.operation = "MULTIPLY_ADD"
        rough.inputs[1].default_value = 0.3
        rough.inputs[2].default_value = 0.5
        link(tree, sep.outputs["Z"], rough, 0)
        link(tree, rough.outputs[0], principled, "Roughness")
        metal = nodes.new("ShaderNodeMapRange")
        metal.inputs["From Min"].default_value = -0.5
        metal.inputs["From Max"].default_value = 0.8
        link(tree, sep.outputs["X"], metal, "Value")
        link(tree, metal.outputs["Result"], principled, "Metallic")
        glossy = nodes.new("ShaderNodeBsdfGlossy")
        glossy.inputs["Color"].default_value = (0.9, 0.7, 0.3, 1.0)
        glossy.inputs["Roughness"].default_value = 0.2
        weight = nodes.new("ShaderNodeLayerWeight")
        weight.inputs["Blend"].default_value = 0.4
        mix = nodes.new("ShaderNodeMixShader")
        link(tree, weight.outputs["Facing"], mix, 0)
        link(tree, principled.outputs[0], mix, 1)
        link(tree, glossy.outputs[0], mix, 2)
        out = nodes["Material Output"]
        tree.links.new(mix.outputs[0], out.inputs["Surface"])
        return mat

    scene = bf.sphere_scene(make)
    cc.configure_cycles(scene, 128, 8, threads=2, seed=1)
    cyc = cc.render_cycles(scene, tmp_path)[0]
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = 128, 8, 1, 2
    mon = cc.render_monte(scene)[0]
    mask = ~np.all(np.abs(cyc - 1.0) < 1e-4, axis=2)  # everything but the white sky: the sphere's pixels
    c, mm = cyc[mask].mean(axis=0), mon[mask].mean(axis=0)
    print(f"\nlit textured sphere: Cycles {np.round(c, 4)} Monte {np.round(mm, 4)} rel {np.round(mm / c - 1, 4)}")
    assert 0.1 * mask.size < mask.sum() < 0.4 * mask.size  # the sphere covers ~20 % of the frame
    assert np.allclose(mm, c, rtol=0.01)


def test_uv_map_node_reads_a_named_non_active_uv_map():
    """Two UV maps on the plane; a UV Map node names the second (not active for rendering), the Texture
    Coordinate UV output reads the active one: both as Cycles shows them."""
    def build(tree, nodes):
        uvmap = nodes.new("ShaderNodeUVMap")
        uvmap.uv_map = "Second"
        add = nodes.new("ShaderNodeVectorMath")
        add.operation = "MULTIPLY_ADD"
        link(tree, uvmap.outputs["UV"], add, 0)
        add.inputs[1].default_value = (1.0, 1.0, 0.0)
        link(tree, nodes["Texture Coordinate"].outputs["UV"], add, 2)
        return add.outputs[0]

    scene = sc.emission_plane(build, size=16, name="uvmaps")
    second = scene.objects["plane"].data.uv_layers.new(name="Second")
    second.data.foreach_set("uv", [0.3, 0.9, 0.1, 0.2, 0.8, 0.0, 0.6, 0.7])
    scene.objects["plane"].data.uv_layers["UVMap"].active_render = True
    monte, cycles = sc.compare(scene, spp=2)
    diff = np.abs(monte - cycles).max(axis=2)
    print(f"\nuv maps: max |Monte - Cycles| {diff.max():.2e}")
    assert cycles.std() > 0.05
    assert np.mean(diff > SMOOTH_TOL) < 0.02 and diff.max() < 2e-2
