"""Environment-map worlds against Cycles: Blender's bundled studio HDRIs on the Background, through the add-on's
export, a gold metal Suzanne on a diffuse floor, compared by monte.addon.crosscheck (channel means within
max(4 sigma, 0.5 %), at most 1 % of per-pixel |z| > 5, and the power to see a 1 % error: see
tests/test_crosscheck.py's `check`). The forest map runs in the default suite; the rotated map (Mapping node),
the mirror-ball projection and the larger image are slow: `pytest -m slow tests/test_world_cycles.py`.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_crosscheck import SIZES, check  # noqa: E402

from monte.lab import bpy_scenes as bs  # noqa: E402

pytestmark = pytest.mark.blender
SAMPLES = 3  # x test_crosscheck's sample counts: 2 left 4 sigma at 0.69 % (the sun in the gold), above 0.6 %


def gold_suzanne_scene(world_setup) -> object:
    """Gold metal Suzanne (Principled, metallic, roughness 0.3) on a 8 m diffuse floor; world_setup(scene) sets
    the world."""
    scene = bs.reset()
    gold = bs.node_material("gold", "ShaderNodeBsdfPrincipled", Base_Color=(1.0, 0.77, 0.34), Metallic=1.0,
                            Roughness=0.3)
    bs.mesh_object("floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                   bs.diffuse("floor", (0.6, 0.6, 0.6)))
    bs.monkey_object("suzanne", (0, 0, 0.8), 0.8, gold)
    bs.camera_object(scene, (0, -4.5, 2.0), (math.radians(72), 0, 0), lens=40.0)
    world_setup(scene)
    bs._finish(scene, (32, 32))
    return scene


@pytest.mark.parametrize("size", [pytest.param("small"), pytest.param("large", marks=pytest.mark.slow)])
def test_forest_hdri_gold_suzanne(size, tmp_path):
    """The issue's scene: without the map (its average colour as a uniform world) it was -14/-11/-5 %."""
    scene = gold_suzanne_scene(lambda s: bs.set_environment_world(s, bs.studio_hdri("forest"), 1.0))
    check(scene, tmp_path, size, max_bounces=4, samples=SAMPLES)



@pytest.mark.slow
def test_rotated_hdri_through_a_mapping_node(tmp_path):
    """forest.exr turned by Euler XYZ (0.4, -0.3, 60 deg) and scaled along z through a Mapping node; the control:
    Monte with the tilt's signs flipped (the sun, its highlight and the shadows moved) must disagree with the
    same Cycles images."""
    from monte.addon import crosscheck as cc
    from monte.core import compare as cmp
    from monte.core.exr import read_exr

    scene = gold_suzanne_scene(lambda s: bs.set_environment_world(
        s, bs.studio_hdri("forest"), 1.0, rotation=(0.4, -0.3, math.radians(60.0)), scale=(1.0, 1.0, 1.3)))
    check(scene, tmp_path, "small", max_bounces=4, samples=SAMPLES)
    scene.world.node_tree.nodes["Mapping"].inputs["Rotation"].default_value = (-0.4, 0.3, math.radians(60.0))
    m = scene.monte
    m.samples, m.max_bounces, m.threads, m.seed = SIZES["small"][1] * SAMPLES, 4, 2, 1
    scene.render.resolution_x = scene.render.resolution_y = SIZES["small"][0]
    wrong, wrong_var = cc.render_monte(scene)
    ch = read_exr(tmp_path / "cc" / "cycles.exr")
    cycles = np.stack([ch[c] for c in "RGB"], -1)
    cycles_var = np.stack([ch[f"variance.{c}"] for c in "RGB"], -1)
    assert not cmp.compare(wrong, wrong_var, cycles, cycles_var, rel_floor=0.005).verdict()[0]


def mirror_ball_exr(src_path: str, out_path: Path, n: int = 256) -> Path:
    """An n x n mirror-ball image of the equirectangular map at src_path (Cycles' mirrorball_to_direction: a
    mirror sphere seen from -y), black outside the ball."""
    from monte.addon.export.material import image_pixels
    from monte.core.exr import write_exr
    from monte.core.world import EnvironmentDistribution, EnvironmentMap

    img = bpy.data.images.load(src_path, check_existing=True)
    dist = EnvironmentDistribution(EnvironmentMap(image_pixels(img)))
    v, u = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n, indexing="ij")  # v: row from bottom
    x, z = 2 * u - 1, 2 * v - 1
    inside = x * x + z * z <= 1
    y = -np.sqrt(np.maximum(1 - x * x - z * z, 0))
    d = -2 * y[..., None] * np.stack([x, y, z], -1) + np.array([0.0, 1.0, 0.0])  # reflection of (0, 1, 0)
    rgb = (dist.radiance(d.reshape(-1, 3)).reshape(n, n, 3) * inside[..., None])[::-1]  # row 0 at the top
    return write_exr(out_path, {c: rgb[..., i] for i, c in enumerate("RGB")})


@pytest.mark.slow
def test_mirror_ball_hdri(tmp_path):
    path = mirror_ball_exr(bs.studio_hdri("forest"), tmp_path / "ball.exr")
    scene = gold_suzanne_scene(lambda s: bs.set_environment_world(s, str(path), 1.0, projection="MIRROR_BALL"))
    check(scene, tmp_path, "small", max_bounces=4, samples=SAMPLES)


# ------------------------------------------------------------------------------------------ export (no render)
def _export_world(scene):
    from monte.addon.export.world import export_world

    warnings: list[str] = []
    return export_world(scene.world, warnings), warnings


def test_export_reads_the_map_mapping_and_sampling_settings():
    scene = bs.reset()
    world = bs.set_environment_world(scene, bs.studio_hdri("forest"), 2.5, rotation=(0.0, 0.0, math.pi / 2),
                                     scale=(1.0, 1.0, 2.0), interpolation="Closest")
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = 256
    got, warnings = _export_world(scene)
    env = got.environment
    assert warnings == [] and env.pixels.shape == (512, 1024, 3) and env.pixels.dtype == np.float32
    assert env.interpolation == "CLOSEST" and env.projection == "EQUIRECTANGULAR"
    np.testing.assert_allclose(env.strength, 2.5)
    # Point mapping: rotate (90 degrees about Z) after scaling (z by 2): x -> y, y -> -x, z -> 2z
    np.testing.assert_allclose(env.matrix, [[0, -1, 0], [1, 0, 0], [0, 0, 2]], atol=1e-7)
    assert env.map_resolution == 256 and env.importance_resolution == (256, 128) and env.importance_sampling
    world.cycles.sampling_method = "AUTOMATIC"
    assert _export_world(scene)[0].environment.importance_resolution == (1024, 512)
    world.cycles.sampling_method = "NONE"
    assert not _export_world(scene)[0].environment.importance_sampling


def test_missing_hdri_warns_with_world_and_path_and_renders_the_background_colour(tmp_path):
    scene = bs.reset()
    world = bs.set_environment_world(scene, bs.studio_hdri("forest"), 2.0)
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1.0)
    image = world.node_tree.nodes["Environment Texture"].image
    missing = tmp_path / "gone.exr"
    image.filepath = str(missing)
    image.reload()
    got, warnings = _export_world(scene)
    assert got.environment is None
    np.testing.assert_allclose(got.color, (0.4, 0.6, 0.8), rtol=1e-6)
    assert len(warnings) == 1 and warnings[0].startswith(f"world 'World': environment image 'forest.exr' ({missing})")
    assert "using the Background's own colour" in warnings[0]


def test_unreadable_hdri_warns_with_world_and_path_and_renders_the_background_colour(tmp_path):
    """A file that is there but is no image (garbage bytes named .exr): the same warning and fallback as a
    missing one, never an exception or a black world."""
    scene = bs.reset()
    world = bs.set_environment_world(scene, bs.studio_hdri("forest"), 2.0)
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.2, 0.3, 0.4, 1.0)
    image = world.node_tree.nodes["Environment Texture"].image
    broken = tmp_path / "broken.exr"
    broken.write_bytes(b"not an image at all " * 64)
    image.filepath = str(broken)
    image.reload()
    got, warnings = _export_world(scene)
    assert got.environment is None
    np.testing.assert_allclose(got.color, (0.4, 0.6, 0.8), rtol=1e-6)
    assert len(warnings) == 1 and warnings[0].startswith(f"world 'World': environment image 'forest.exr' ({broken})")
    assert "using the Background's own colour" in warnings[0]


def test_a_direction_varying_node_renders_through_a_baked_program():
    """A world colour that varies with direction through other nodes (a Gradient Texture on Generated
    coordinates) is compiled as a node program and baked into an equirectangular map, without a warning
    (tests/test_world_programs.py compares it with Cycles)."""
    scene = bs.reset()
    world = bs.set_world(scene, (0.1, 0.2, 0.3), 1.0)
    tree = world.node_tree
    gradient = tree.nodes.new("ShaderNodeTexGradient")
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["Generated"], gradient.inputs["Vector"])
    tree.links.new(gradient.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    got, warnings = _export_world(scene)
    assert warnings == [] and got.environment is not None
    assert got.environment.pixels.shape == (512, 1024, 3) and np.allclose(got.color, 0.0)


def test_an_environment_texture_inside_a_world_graph_warns_and_keeps_the_socket_colour():
    """The control: an Environment Texture mixed with a colour by a Layer Weight (a graph a world program cannot
    express) warns naming the world and the node, and renders the socket's own colour."""
    scene = bs.reset()
    world = bs.set_environment_world(scene, bs.studio_hdri("forest"), 1.0)
    tree = world.node_tree
    background = tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    weight = tree.nodes.new("ShaderNodeLayerWeight")
    colours = [sk for sk in mix.inputs if sk.type == "RGBA" and sk.enabled]
    tree.links.new(weight.outputs["Facing"], mix.inputs[0])
    tree.links.new(tree.nodes["Environment Texture"].outputs["Color"], colours[0])
    tree.links.new(mix.outputs["Result"], background.inputs["Color"])
    got, warnings = _export_world(scene)
    assert got.environment is None
    np.testing.assert_allclose(got.color, (0.1, 0.2, 0.3), rtol=1e-6)
    assert warnings[0] == ("world 'World': node 'Environment Texture' (Environment Texture) inside a world node "
                           "graph is not supported (only directly on the Background, or times a constant colour)")


@pytest.mark.parametrize("factor", [1.0, 0.5])
def test_a_constant_colour_multiply_scales_the_map(factor):
    """Background <- Mix (Color, Multiply, factor f) of the map and a constant colour c: the map x ((1 - f) + f c)."""
    scene = bs.reset()
    world = bs.set_environment_world(scene, bs.studio_hdri("forest"), 2.0)
    tree = world.node_tree
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type, mix.blend_type = "RGBA", "MULTIPLY"
    mix.inputs[0].default_value = factor
    colours = [sk for sk in mix.inputs if sk.type == "RGBA" and sk.enabled]
    colours[1].default_value = (0.2, 0.5, 1.5, 1.0)
    tree.links.new(tree.nodes["Environment Texture"].outputs["Color"], colours[0])
    tree.links.new(mix.outputs["Result"], tree.nodes["Background"].inputs["Color"])
    got, warnings = _export_world(scene)
    assert warnings == [] and got.environment is not None
    np.testing.assert_allclose(got.environment.strength, 2.0 * ((1 - factor) + factor * np.array([0.2, 0.5, 1.5])),
                               rtol=1e-6)
