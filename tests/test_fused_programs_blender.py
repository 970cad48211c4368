"""Node programs in the fused path kernel on scenes built in Blender and exported by the add-on: the cases the
core-built scenes of tests/test_fused_programs.py do not reach. Back faces (Geometry Backfacing, the viewer-side
normals), a mesh without UV maps under an Image Texture and Texture Coordinate UV, Texture Coordinate Camera and
Window, Vector Transform, a box-projected image, and instances of a collection (Object Info Random and Object
coordinates per instance). Each scene must render in the fused kernel with the per-bounce integrator's bits."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from fused_compare import (assert_fused_bit_identical_across_thread_counts,  # noqa: E402
                           assert_fused_equals_per_bounce)
from monte.addon.export import export_scene  # noqa: E402

pytestmark = pytest.mark.blender


def _principled(name: str):
    mat = bf.node_material(name, "ShaderNodeBsdfPrincipled", Roughness=0.45)
    return mat, mat.node_tree, mat.node_tree.nodes, mat.node_tree.nodes["Principled BSDF"]


def _noise(tree, nodes, vector, scale: float = 3.0):
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = scale
    tree.links.new(vector, noise.inputs["Vector"])
    return noise


def _grid_image(name: str = "grid"):
    image = bpy.data.images.new(name, 32, 32)
    image.generated_type = "COLOR_GRID"
    return image


def _walls_seen_from_both_sides():
    """Two single-sided walls of one material, one facing the camera and one facing away (its back faces are
    seen): Base Color mixes red into a Noise of the Camera coordinates by Geometry Backfacing; Roughness from the
    Window coordinates' x."""
    mat, tree, nodes, bsdf = _principled("walls")
    coords = nodes.new("ShaderNodeTexCoord")
    geometry = nodes.new("ShaderNodeNewGeometry")
    noise = _noise(tree, nodes, coords.outputs["Camera"])
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    tree.links.new(geometry.outputs["Backfacing"], mix.inputs["Factor"])
    tree.links.new(noise.outputs["Color"], mix.inputs["A"])
    mix.inputs["B"].default_value = (0.8, 0.1, 0.1, 1.0)
    tree.links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    window = nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(coords.outputs["Window"], window.inputs[0])
    tree.links.new(window.outputs["X"], bsdf.inputs["Roughness"])
    # the winding gives the front wall a -y normal (towards the camera) and the back wall a +y one
    bf.mesh_object("front", [(-2, 0, 0), (-0.1, 0, 0), (-0.1, 0, 1.5), (-2, 0, 1.5)], [(0, 1, 2, 3)], mat)
    bf.mesh_object("back", [(0.1, 0, 0), (0.1, 0, 1.5), (2, 0, 1.5), (2, 0, 0)], [(0, 1, 2, 3)], mat)


def _transformed_ball():
    """A rotated, scaled ball whose Base Color is a Noise of its Object coordinates taken to world space by a
    Vector Transform, and a box-projected colour grid on a cube without UV maps (blend 0.3) beside it."""
    mat, tree, nodes, bsdf = _principled("transformed")
    coords = nodes.new("ShaderNodeTexCoord")
    transform = nodes.new("ShaderNodeVectorTransform")
    transform.vector_type, transform.convert_from, transform.convert_to = "POINT", "OBJECT", "WORLD"
    tree.links.new(coords.outputs["Object"], transform.inputs["Vector"])
    noise = _noise(tree, nodes, transform.outputs["Vector"], scale=4.0)
    tree.links.new(noise.outputs["Color"], bsdf.inputs["Base Color"])
    ball = bf.icosphere_object("ball", (0.6, -1.2, 0.5), 0.5, mat, subdivisions=2)
    ball.rotation_euler = (0.3, 0.0, 0.7)
    ball.scale = (1.0, 0.7, 1.2)

    box, tree, nodes, bsdf = _principled("boxed")
    coords = nodes.new("ShaderNodeTexCoord")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = _grid_image()
    tex.projection, tex.projection_blend = "BOX", 0.3
    tree.links.new(coords.outputs["Object"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    s = 0.35
    v = [(-s, -s, -s), (s, -s, -s), (s, s, -s), (-s, s, -s), (-s, -s, s), (s, -s, s), (s, s, s), (-s, s, s)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    cube = bf.mesh_object("cube", v, f, box)
    cube.location, cube.rotation_euler = (-0.8, -1.3, 0.4), (0.4, 0.2, 0.6)


def _without_uvs():
    """A ball with no UV map under an Image Texture on its (missing) UVs and a Noise of Texture Coordinate UV."""
    mat, tree, nodes, bsdf = _principled("no-uv")
    coords = nodes.new("ShaderNodeTexCoord")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = _grid_image("grid-no-uv")
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    noise = _noise(tree, nodes, coords.outputs["UV"])
    tree.links.new(noise.outputs["Fac"], bsdf.inputs["Roughness"])
    ball = bf.icosphere_object("no-uv", (-0.2, -1.6, 0.35), 0.35, mat, subdivisions=2)
    while ball.data.uv_layers:
        ball.data.uv_layers.remove(ball.data.uv_layers[0])


def _instanced_balls():
    """Three instances of a collection (a ball) whose colour is Object Info Random through a Color Ramp and whose
    roughness is a Noise of the Object coordinates: each instance its own random number and object space."""
    mat, tree, nodes, bsdf = _principled("instanced")
    info = nodes.new("ShaderNodeObjectInfo")
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.9, 0.2, 0.1, 1.0)
    ramp.color_ramp.elements[1].color = (0.1, 0.3, 0.9, 1.0)
    tree.links.new(info.outputs["Random"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    coords = nodes.new("ShaderNodeTexCoord")
    noise = _noise(tree, nodes, coords.outputs["Object"], scale=5.0)
    tree.links.new(noise.outputs["Fac"], bsdf.inputs["Roughness"])
    source = bpy.data.collections.new("ball source")
    ball = bf.icosphere_object("source ball", (0, 0, 0), 0.25, mat, subdivisions=2)
    for c in list(ball.users_collection):
        c.objects.unlink(ball)
    source.objects.link(ball)
    for i, location in enumerate(((-1.7, -0.8, 0.25), (1.6, -1.6, 0.25), (0.3, -2.5, 0.2))):
        empty = bpy.data.objects.new(f"instance {i}", None)
        empty.instance_type, empty.instance_collection = "COLLECTION", source
        empty.location, empty.rotation_euler = location, (0.0, 0.0, 0.8 * i)
        bpy.context.scene.collection.objects.link(empty)


def blender_program_scene(resolution=(40, 30)):
    scene = bf.reset()
    floor = bf.diffuse("floor", (0.5, 0.5, 0.5))
    bf.mesh_object("floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)], floor)
    _walls_seen_from_both_sides()
    _transformed_ball()
    _without_uvs()
    _instanced_balls()
    bf.add_light(scene, "AREA", (0.5, -2.5, 3.0), (math.radians(35), 0.0, 0.0), energy=300.0, size=1.5)
    bf.camera_object(scene, (0.0, -5.0, 1.6), (math.radians(80), 0.0, 0.0), lens=28.0)
    bf.set_world(scene, (0.1, 0.12, 0.15), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    return scene


def test_exported_node_programs_render_in_the_fused_kernel_as_per_bounce(fast_settings, monkeypatch):
    blender_program_scene()
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    names = {m.name for m in core_scene.materials if m.program is not None}
    assert {"walls", "transformed", "boxed", "no-uv", "instanced"} <= names  # all five are node programs
    old, new = assert_fused_equals_per_bounce(core_scene, fast_settings(spp=8, threads=1, max_bounces=4),
                                              monkeypatch)
    # the programs ran: many distinct albedos (the constant floor alone would give one)
    hit = np.isfinite(new.depth.reshape(-1))
    assert len(np.unique(new.albedo.reshape(-1, 3)[hit].round(4), axis=0)) > 50
    assert old.color[..., :3].mean() > 0.01


def test_exported_node_programs_in_the_fused_kernel_are_bit_identical_across_thread_counts(fast_settings,
                                                                                         monkeypatch):
    blender_program_scene((32, 32))
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    assert_fused_bit_identical_across_thread_counts(core_scene, fast_settings, monkeypatch, spp=4, max_bounces=4)
