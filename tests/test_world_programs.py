"""Worlds whose colour a node graph drives (a Gradient or Noise Texture on Texture Coordinate Generated, through a
Color Ramp), compiled as a node program and baked into an environment map (core.world_program), against Cycles:
an equirectangular panoramic camera looking at the world alone (per pixel: at most 1 % of pixels with |z| > 5,
means within max(4 sigma, 0.5 %), see tests/test_crosscheck.py's `check`), and a diffuse floor and sphere lit by
the Gradient world. The Background's own colour is a saturated red no program yields: a world that fell back to
it fails every check by far. Is Camera Ray in the colour graph (or a Mix Shader of Backgrounds by it) gives a
camera-only backdrop map over the light. The Noise panorama is slow: `pytest -m slow tests/test_world_programs.py`.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_crosscheck import check  # noqa: E402

from monte.lab import bpy_scenes as bs  # noqa: E402

pytestmark = pytest.mark.blender
FALLBACK = (0.9, 0.05, 0.05)  # the Background's own colour: what a world falling back would show


def gradient_world(scene, texture: str = "gradient", strength: float = 1.5):
    """Texture Coordinate Generated -> Gradient (Linear) or Noise Texture -> Color Ramp (blue ->
    orange) -> Background Color, strength `strength`."""
    world = bs.set_world(scene, FALLBACK, strength)
    tree = world.node_tree
    coords = tree.nodes.new("ShaderNodeTexCoord")
    if texture == "gradient":
        tex = tree.nodes.new("ShaderNodeTexGradient")
        tex.gradient_type = "LINEAR"
    else:
        tex = tree.nodes.new("ShaderNodeTexNoise")
        tex.inputs["Scale"].default_value = 2.0
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.05, 0.1, 0.4, 1.0)
    ramp.color_ramp.elements[1].color = (1.0, 0.6, 0.2, 1.0)
    tree.links.new(coords.outputs["Generated"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    return world


def _export_world(scene):
    from monte.addon.export.world import export_world

    warnings: list[str] = []
    return export_world(scene.world, warnings), warnings


def test_the_gradient_world_bakes_the_program_in_cycles_background_context():
    """Generated on the world is the ray direction D: a Linear Gradient reads clamp(D.x, 0, 1), so each texel of
    the baked map is the ramp at its centre's x (times the strength), without a warning."""
    from monte.core.sky import equirectangular_directions

    scene = bs.reset()
    gradient_world(scene)
    world, warnings = _export_world(scene)
    assert warnings == [] and world.environment is not None
    pixels = world.environment.pixels
    d = equirectangular_directions(pixels.shape[1])
    fac = np.clip(d[..., 0], 0.0, 1.0)[..., None]
    want = 1.5 * ((1 - fac) * np.array([0.05, 0.1, 0.4]) + fac * np.array([1.0, 0.6, 0.2]))
    np.testing.assert_allclose(pixels, want, atol=2e-5)


def panorama_scene(texture: str):
    scene = bs.reset()
    gradient_world(scene, texture)
    bs.camera_object(scene, (0, 0, 0), (math.pi / 2, 0, 0.3), kind="PANO", panorama_type="EQUIRECTANGULAR")
    # Monte renders no scene without objects: one small triangle the camera does not see.
    hidden = bs.mesh_object("hidden", [(0, 5, 0), (0.01, 5, 0), (0, 5, 0.01)], [(0, 1, 2)])
    hidden.visible_camera = False
    bs._finish(scene, (32, 32))
    return scene


@pytest.mark.parametrize("texture", ["gradient", pytest.param("noise", marks=pytest.mark.slow)])
def test_a_program_world_seen_through_a_panorama_matches_cycles_per_pixel(texture, tmp_path):
    check(panorama_scene(texture), tmp_path, "small")


def test_a_gradient_world_lights_a_diffuse_scene_as_in_cycles(tmp_path):
    scene = bs.reset()
    s = 4.0
    bs.mesh_object("floor", [(-s, -s, -1), (s, -s, -1), (s, s, -1), (-s, s, -1)], [(0, 1, 2, 3)],
                   bs.diffuse("floor", (0.6, 0.6, 0.6)))
    bs.icosphere_object("ball", (0, 0, 0), 1.0, bs.diffuse("ball", (0.7, 0.7, 0.7)))
    bs.camera_object(scene, (0, -5, 0.5), (math.radians(84), 0, 0), lens=35.0)
    gradient_world(scene)
    bs._finish(scene, (32, 32))
    world, warnings = _export_world(scene)
    assert warnings == [] and world.environment is not None
    check(scene, tmp_path, "small", max_bounces=4)


def camera_backdrop_world(scene):
    """Is Camera Ray mixing, inside the colour graph, the Gradient world (what the camera sees) over a uniform
    grey-blue (what lights the scene)."""
    world = gradient_world(scene)
    tree = world.node_tree
    background = tree.nodes["Background"]
    ramp = background.inputs["Color"].links[0].from_node
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    colours = [sk for sk in mix.inputs if sk.type == "RGBA" and sk.enabled]
    colours[0].default_value = (0.3, 0.35, 0.4, 1.0)
    path = tree.nodes.new("ShaderNodeLightPath")
    tree.links.new(path.outputs["Is Camera Ray"], mix.inputs[0])
    tree.links.new(ramp.outputs["Color"], colours[1])
    tree.links.new(mix.outputs["Result"], background.inputs["Color"])
    return world


def test_is_camera_ray_in_the_colour_graph_gives_a_camera_only_backdrop():
    """The program baked twice: with the camera flag (World.camera_environment: the gradient) and without it
    (the light: the uniform colour x strength)."""
    scene = bs.reset()
    camera_backdrop_world(scene)
    world, warnings = _export_world(scene)
    assert warnings == []
    np.testing.assert_allclose(world.environment.pixels, np.broadcast_to(1.5 * np.array([0.3, 0.35, 0.4]),
                                                                         world.environment.pixels.shape), rtol=1e-6)
    seen = world.camera_environment.pixels
    assert seen.shape == (512, 1024, 3) and seen[..., 2].min() < 0.35 * 1.5 < seen[..., 0].max()


def test_a_mix_shader_camera_backdrop_may_be_a_program():
    """Mix Shader (Is Camera Ray) of a uniform Background (the light) and a Gradient one (what the camera sees):
    the camera's Background is baked into World.camera_environment, without a warning."""
    scene = bs.reset()
    world = gradient_world(scene)
    tree = world.node_tree
    seen = tree.nodes["Background"]
    light = tree.nodes.new("ShaderNodeBackground")
    light.inputs["Color"].default_value = (0.2, 0.2, 0.2, 1.0)
    mix = tree.nodes.new("ShaderNodeMixShader")
    path = tree.nodes.new("ShaderNodeLightPath")
    tree.links.new(path.outputs["Is Camera Ray"], mix.inputs[0])
    tree.links.new(light.outputs[0], mix.inputs[1])
    tree.links.new(seen.outputs[0], mix.inputs[2])
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld")
    tree.links.new(mix.outputs[0], output.inputs["Surface"])
    got, warnings = _export_world(scene)
    assert warnings == [] and got.environment is None and got.camera_environment is not None
    np.testing.assert_allclose(got.color, 0.2, rtol=1e-6)


def test_a_camera_only_gradient_backdrop_over_a_uniform_light_as_in_cycles(tmp_path):
    """A diffuse sphere on a floor lit by the uniform colour while the camera sees the gradient behind them."""
    scene = bs.reset()
    s = 4.0
    bs.mesh_object("floor", [(-s, -s, -1), (s, -s, -1), (s, s, -1), (-s, s, -1)], [(0, 1, 2, 3)],
                   bs.diffuse("floor", (0.6, 0.6, 0.6)))
    bs.icosphere_object("ball", (0, 0, 0), 1.0, bs.diffuse("ball", (0.7, 0.7, 0.7)))
    bs.camera_object(scene, (0, -5, 0.5), (math.radians(84), 0, 0.5), lens=25.0)
    camera_backdrop_world(scene)
    bs._finish(scene, (32, 32))
    check(scene, tmp_path, "small", max_bounces=4)


def test_a_mix_shader_of_backgrounds_by_a_texture_is_baked():
    """Mix Shader of two Backgrounds by a Linear Gradient on Generated (D.x clamped): each texel is
    (1 - f) a sa + f b sb, without a warning."""
    from monte.core.sky import equirectangular_directions

    scene = bs.reset()
    world = bs.set_world(scene, (0.8, 0.2, 0.1), 1.0)
    tree = world.node_tree
    first = tree.nodes["Background"]
    second = tree.nodes.new("ShaderNodeBackground")
    second.inputs["Color"].default_value = (0.1, 0.3, 0.9, 1.0)
    second.inputs["Strength"].default_value = 2.0
    mix = tree.nodes.new("ShaderNodeMixShader")
    gradient = tree.nodes.new("ShaderNodeTexGradient")
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["Generated"], gradient.inputs["Vector"])
    tree.links.new(gradient.outputs["Fac"], mix.inputs[0])
    tree.links.new(first.outputs[0], mix.inputs[1])
    tree.links.new(second.outputs[0], mix.inputs[2])
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld")
    tree.links.new(mix.outputs[0], output.inputs["Surface"])
    got, warnings = _export_world(scene)
    assert warnings == [] and got.environment is not None and got.camera_environment is None
    d = equirectangular_directions(1024)
    f = np.clip(d[..., 0], 0.0, 1.0)[..., None]
    want = (1 - f) * np.array([0.8, 0.2, 0.1]) + f * 2.0 * np.array([0.1, 0.3, 0.9])
    np.testing.assert_allclose(got.environment.pixels, want, atol=2e-5)


def test_camera_coordinates_on_the_world_warn_by_name():
    """Texture Coordinate Camera on the world (Cycles: the direction in camera space) is not built: a warning
    naming the world and the outputs; the rest of the graph still renders."""
    scene = bs.reset()
    world = bs.set_world(scene, (0.1, 0.2, 0.3), 1.0)
    tree = world.node_tree
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["Camera"], tree.nodes["Background"].inputs["Color"])
    got, warnings = _export_world(scene)
    assert got.environment is not None
    assert warnings == ["world 'World': Texture Coordinate Camera / Window on the world are not supported; they "
                        "read the ray direction (Camera) and 0 (Window)"]


def test_a_re_export_reuses_the_bake(monkeypatch):
    """The second export of the same world reads the kept bake (the program is not evaluated again): equal
    pixels, its own array."""
    from monte.core import world_program

    scene = bs.reset()
    gradient_world(scene, "noise")
    first, _ = _export_world(scene)

    def no_second_bake(*args, **kwargs):
        raise AssertionError("the world program was baked again")

    monkeypatch.setattr(world_program, "evaluate_world_program", no_second_bake)
    second, _ = _export_world(scene)
    assert second.environment.pixels is not first.environment.pixels
    np.testing.assert_array_equal(second.environment.pixels, first.environment.pixels)
