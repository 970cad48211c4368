"""The node compiler on Blender materials: folding, fallbacks and bad input (named warnings, documented
fallbacks, never a crash). The per-node values are cross-checked against Cycles in test_shading_crosscheck.py."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon.export import export_scene  # noqa: E402
from monte.core.shading import evaluator as ev  # noqa: E402
from monte.core.shading.program import BIND_WEIGHT  # noqa: E402

pytestmark = pytest.mark.blender


@pytest.fixture
def scene():
    bf.bpy_module()
    s = bf.reset()
    bf.camera_object(s, (0, -5, 0), (1.5708, 0, 0))
    return s


def plane(material):
    ob = bf.mesh_object("plane", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)], material)
    ob.data.uv_layers.new(name="UVMap")
    return ob


def export():
    return export_scene(bpy.context.evaluated_depsgraph_get())[0]


def diffuse_with(build):
    mat = bf.node_material("M", "ShaderNodeBsdfDiffuse")
    tree = mat.node_tree
    sock = build(tree, tree.nodes)
    if sock is not None:
        tree.links.new(sock, tree.nodes["Diffuse BSDF"].inputs["Color"])
    plane(mat)
    return export()


def test_constant_subgraphs_fold_to_plain_lobes(scene):
    """Value -> Math -> Combine XYZ -> colour: no program, the folded colour on the lobe (today's path)."""
    def build(tree, nodes):
        value = nodes.new("ShaderNodeValue")
        value.outputs[0].default_value = 0.25
        math = nodes.new("ShaderNodeMath")
        math.operation = "SQRT"
        tree.links.new(value.outputs[0], math.inputs[0])
        comb = nodes.new("ShaderNodeCombineXYZ")
        tree.links.new(math.outputs[0], comb.inputs[0])
        comb.inputs[1].default_value = 0.2
        return comb.outputs[0]

    got = diffuse_with(build)
    mat = got.materials[0]
    assert mat.program is None
    assert np.allclose(mat.lobes[0].color, (0.5, 0.2, 0.0), atol=1e-6)


def test_varying_colour_gets_a_program_with_only_live_instructions(scene):
    def build(tree, nodes):
        coords = nodes.new("ShaderNodeTexCoord")
        dead = nodes.new("ShaderNodeMath")  # linked from the UV but feeding nothing: removed
        tree.links.new(coords.outputs["UV"], dead.inputs[0])
        return coords.outputs["UV"]

    got = diffuse_with(build)
    prog = got.materials[0].program
    assert prog is not None and prog.code.shape[0] == 1  # texture_coordinate only
    w = prog.lobes[0, BIND_WEIGHT]
    regs = ev.run_single(prog, uv=(0.25, 0.75))
    assert np.allclose(regs[w], (0.25, 0.75, 0.0))


def test_missing_image_warns_with_material_node_and_path(scene):
    def build(tree, nodes):
        tex = nodes.new("ShaderNodeTexImage")
        tex.name = "Albedo map"
        img = bpy.data.images.new("albedo", 4, 4)
        img.source = "FILE"
        img.filepath = "/nonexistent/albedo.png"  # a file that is gone since the .blend was saved
        tex.image = img
        return tex.outputs["Color"]

    got = diffuse_with(build)
    msg = [w for w in got.warnings if "Albedo map" in w]
    assert msg and "material 'M'" in msg[0] and "/nonexistent/albedo.png" in msg[0] and "magenta" in msg[0]
    assert got.materials[0].program is None
    assert np.allclose(got.materials[0].lobes[0].color, (1.0, 0.0, 1.0))


def test_nonfinite_texels_read_as_zero_with_a_counted_warning(scene):
    img = bpy.data.images.new("hdr", 2, 1, alpha=True, float_buffer=True)
    img.pixels.foreach_set(np.array([np.nan, 0.5, np.inf, 1.0, 0.2, 0.3, 0.4, 1.0], np.float32))

    def build(tree, nodes):
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = img
        tex.interpolation = "Closest"
        return tex.outputs["Color"]

    got = diffuse_with(build)
    assert any("material 'M'" in w and "'hdr' has 2 NaN/Inf texel values; they read as 0" in w for w in got.warnings)
    assert np.all(np.isfinite(got.textures[0].pixels))
    prog = got.materials[0].program
    regs = ev.run_single(prog, got.textures, uv=(0.25, 0.5))
    assert np.allclose(regs[prog.lobes[0, BIND_WEIGHT]], (0.0, 0.5, 0.0))


def test_unsupported_shader_in_a_mix_warns_by_name(scene):
    """A Toon BSDF beside a Diffuse in a Mix Shader: the documented fallback (the material's viewport colour as
    a diffuse), named. (A Script node's sockets exist only once its OSL script compiles, which needs OSL; its
    shader output then takes this same path.)"""
    mixed = bf.node_material("Mixed", "ShaderNodeMixShader")
    mt = mixed.node_tree
    toon = mt.nodes.new("ShaderNodeBsdfToon")
    diffuse = mt.nodes.new("ShaderNodeBsdfDiffuse")
    mt.links.new(toon.outputs[0], mt.nodes["Mix Shader"].inputs[1])
    mt.links.new(diffuse.outputs[0], mt.nodes["Mix Shader"].inputs[2])
    mixed.diffuse_color = (0.1, 0.2, 0.3, 1.0)
    plane(mixed)
    got = export()
    by = {m.name: m for m in got.materials}
    assert [l.kind for l in by["Mixed"].lobes] == ["diffuse"]
    assert np.allclose(by["Mixed"].lobes[0].color, (0.1, 0.2, 0.3), atol=1e-6)
    assert any("material 'Mixed'" in w and "Toon BSDF" in w and "viewport colour" in w for w in got.warnings)


def test_unsupported_node_keeps_the_socket_value_and_names_itself(scene):
    def build(tree, nodes):
        tree.nodes["Diffuse BSDF"].inputs["Color"].default_value = (0.2, 0.6, 0.4, 1.0)
        occlusion = nodes.new("ShaderNodeAmbientOcclusion")
        occlusion.name = "Occlusion"
        return occlusion.outputs["Color"]

    got = diffuse_with(build)
    assert np.allclose(got.materials[0].lobes[0].color, (0.2, 0.6, 0.4), atol=1e-6)
    assert any("material 'M'" in w and "Occlusion" in w and "uses its own value" in w for w in got.warnings)


def test_node_group_muted_node_and_reroute_are_followed(scene):
    group = bpy.data.node_groups.new("double", "ShaderNodeTree")
    group.interface.new_socket("x", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("y", in_out="OUTPUT", socket_type="NodeSocketFloat")
    gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    mul = group.nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = 2.0
    group.links.new(gin.outputs[0], mul.inputs[0])
    group.links.new(mul.outputs[0], gout.inputs[0])

    def build(tree, nodes):
        coords = nodes.new("ShaderNodeTexCoord")
        sep = nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(coords.outputs["UV"], sep.inputs[0])
        g = nodes.new("ShaderNodeGroup")
        g.node_tree = group
        tree.links.new(sep.outputs["X"], g.inputs[0])
        muted = nodes.new("ShaderNodeMath")
        muted.operation = "SINE"
        muted.mute = True
        tree.links.new(g.outputs[0], muted.inputs[0])
        reroute = nodes.new("NodeReroute")
        tree.links.new(muted.outputs[0], reroute.inputs[0])
        return reroute.outputs[0]

    got = diffuse_with(build)
    prog = got.materials[0].program
    regs = ev.run_single(prog, uv=(0.3, 0.9))
    assert np.allclose(regs[prog.lobes[0, BIND_WEIGHT]], 0.6, atol=1e-6)  # 2 x u, the muted sine passed through
