"""Light groups against real Cycles (the bpy module): View Layer > Light Groups with Object > Shading > Light Group
on lights and an emissive mesh and World > Settings > Light Group: each group's "Combined_<name>" pass reaches
Blender's render result (the multilayer EXR) and the compositor's Render Layers node, with Cycles' mean; a
wrong group assignment fails the same comparison (the control)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon.engine import render_with_operator  # noqa: E402
from monte.core import exr  # noqa: E402

pytestmark = [pytest.mark.blender]

GROUPS = ("key", "fill", "panel", "sky")


def group_scene(size=(32, 32)):
    """Diffuse floor and wall, a diffuse and a glossy (roughness 0.3) sphere; a square area light ("key"), a sphere
    light of radius 0.1 ("fill"), an emissive panel ("panel") and a blue-grey world ("sky") seen above the wall."""
    scene = bf.reset()
    s = 3.0
    bf.mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                   bf.diffuse("floor", (0.6, 0.55, 0.5)))
    bf.mesh_object("wall", [(-s, 1.5, 0), (s, 1.5, 0), (s, 1.5, 2.2), (-s, 1.5, 2.2)], [(0, 1, 2, 3)],
                   bf.diffuse("wall", (0.8, 0.8, 0.8)))
    bf.icosphere_object("clay", (-0.8, 0.2, 0.45), 0.45, bf.diffuse("clay", (0.7, 0.2, 0.1)), subdivisions=4)
    bf.icosphere_object("metal", (0.5, 0.4, 0.45), 0.45,
                        bf.node_material("metal", "ShaderNodeBsdfGlossy", Color=(0.9, 0.8, 0.5, 1), Roughness=0.3),
                        subdivisions=4)
    panel = bf.mesh_object("panel", [(-1.6, 1.45, 1.3), (-0.8, 1.45, 1.3), (-0.8, 1.45, 1.8), (-1.6, 1.45, 1.8)],
                           [(0, 1, 2, 3)], bf.node_material("panel", "ShaderNodeEmission", Color=(1, 0.8, 0.5, 1),
                                                            Strength=4.0))
    key = bf.add_light(scene, "AREA", (1.2, -1.0, 2.6), (0.4, 0.0, 0.6), name="key", energy=300.0,
                       shape="SQUARE", size=1.5)
    fill = bf.add_light(scene, "POINT", (-1.5, -1.0, 1.2), name="fill", energy=150.0, shadow_soft_size=0.1)
    fill.data.color = (0.6, 0.8, 1.0)
    bf.camera_object(scene, (0, -4.5, 1.6), (math.radians(82), 0, 0), lens=30.0)
    bf.set_world(scene, (0.3, 0.4, 0.6), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    for name in GROUPS:
        bpy.ops.scene.view_layer_add_lightgroup(name=name)
    key.lightgroup, fill.lightgroup, panel.lightgroup = "key", "fill", "panel"
    scene.world.lightgroup = "sky"
    return scene


def group_passes(path: Path, layer: str) -> dict[str, np.ndarray]:
    ch = exr.read_exr(path)
    return {g: np.stack([ch[f"{layer}.Combined_{g}.{c}"] for c in "RGB"], axis=-1).astype(np.float64)
            for g in GROUPS}


# Measured (32x32, 1024 samples, one seed each): see test_light_groups_match_cycles's printout; each group's mean
# within 1 % of Cycles', the control (key and fill swapped) tens of % off.


def test_light_groups_match_cycles(tmp_path):
    scene = group_scene()
    layer = scene.view_layers[0].name
    cycles_exr, monte_exr = bf.cycles_and_monte_exrs(scene, tmp_path, 1024, 8)
    cycles, monte = group_passes(cycles_exr, layer), group_passes(monte_exr, layer)
    combined = exr.read_exr(monte_exr)
    monte_combined = np.stack([combined[f"{layer}.Combined.{c}"] for c in "RGB"], axis=-1)
    lines, errors = [], {}
    for g in GROUPS:
        cm, mm = cycles[g].mean(), monte[g].mean()
        errors[g] = mm / cm - 1
        lines.append(f"Combined_{g:6s} Cycles {cm:.5f} Monte {mm:.5f} ({100 * errors[g]:+.2f} %)")
    print("\n" + "\n".join(lines))
    # every emitter is in a group: the groups sum to Combined in Blender's render result too
    np.testing.assert_allclose(sum(monte.values()), monte_combined, rtol=1e-4, atol=1e-5)
    for g, err in errors.items():
        assert abs(err) < 0.01, f"Combined_{g}: Monte's mean is {100 * err:+.2f} % off Cycles'"
    # the control: the key and the fill light in each other's group (128 samples: the error sought is large)
    bpy.data.objects["key"].lightgroup, bpy.data.objects["fill"].lightgroup = "fill", "key"
    scene.monte.samples = 128
    wrong = render_with_operator(scene)[0][1].light_groups
    swapped = abs(wrong["Combined_key"].mean() / cycles["key"].mean() - 1)
    print(f"control: Combined_key with the key and fill lights swapped {100 * swapped:.1f} % off Cycles'")
    assert swapped > 0.1


def test_light_group_reaches_the_compositor_and_skips_unknown_groups(tmp_path, capfd):
    """The Render Layers node offers Combined_<group>; what it composites is Monte's pass. An emitter naming a
    group the view layer lacks lights no group (as Cycles): its light is in Combined only."""
    scene = bf.plane_under_world(albedo=0.5, world=2.0, resolution=(8, 8))
    scene.render.engine = "MONTE"
    scene.monte.samples = 4
    bpy.ops.scene.view_layer_add_lightgroup(name="sky")
    bpy.ops.scene.view_layer_add_lightgroup(name="lamps")
    scene.world.lightgroup = "sky"
    lamp = bf.add_light(scene, "POINT", (0.3, 0.3, 0.5), name="lamp", energy=10.0, shadow_soft_size=0.0)
    lamp.lightgroup = "nowhere"  # not a group of the view layer
    node = bf.composite_to_exr(scene, "CompositorNodeRLayers", "Combined_sky")
    assert node.outputs["Combined_sky"].enabled and node.outputs["Combined_lamps"].enabled
    try:
        path = tmp_path / "comp.exr"
        scene.render.filepath = str(path)
        scene.render.use_file_extension = False
        result = render_with_operator(scene)[0][1]
        bpy.ops.render.render(write_still=True, scene=scene.name)
    finally:
        scene.render.use_compositing = False
    sky, lamps = result.light_groups["Combined_sky"], result.light_groups["Combined_lamps"]
    assert np.all(lamps == 0)  # no emitter is in "lamps"
    # the plane lit by a uniform world of 2 with albedo 0.5: 1 (a zero-variance estimator), the lamp not in it
    np.testing.assert_allclose(sky, 1.0, rtol=1e-4)
    assert result.color[..., :3].mean() > 1.05
    composited = exr.read_exr(path)
    np.testing.assert_allclose(np.stack([composited[c] for c in "RGB"], axis=-1), sky, rtol=1e-5, atol=1e-6)


def test_headless_blend_writes_the_light_groups(tmp_path):
    """`monte render scene.blend` (addon.headless) writes each group as Combined_<name>.R/G/B into Monte's EXR
    layout, padded to the frame outside a render border like the other passes."""
    from monte.addon.headless import render_blend_file

    scene = bf.plane_under_world(albedo=0.5, world=2.0, resolution=(12, 10))
    bpy.ops.scene.view_layer_add_lightgroup(name="sky")
    scene.world.lightgroup = "sky"
    scene.render.use_border = True
    scene.render.border_max_x = 0.5
    blend = tmp_path / "plane.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "plane.exr"
    render_blend_file(blend, out, {"spp": 4}, log=lambda _m: None)
    channels = exr.read_exr(out)
    # albedo 0.5 x world 2: 1 where the border rendered (a zero-variance estimator), 0 outside
    np.testing.assert_allclose(channels["Combined_sky.G"][:, :6], 1.0, rtol=1e-4)
    assert np.all(channels["Combined_sky.R"][:, 6:] == 0)
    np.testing.assert_allclose(channels["Combined_sky.B"][:, :6], channels["B"][:, :6], rtol=1e-5)
