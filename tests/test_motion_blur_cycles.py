"""Motion blur from Blender against real Cycles (bpy ships it), and the export of Render > Motion Blur.

A dark cube moving sideways in front of a bright uniform world (object motion), the cube turning about its
vertical axis (rotation), the same cube still with the camera moving (camera motion) and a cube deformed by an animated shape key (deformation blur): both engines
render the same Blender scene, compared by their means and per-pixel z-scores (core.compare; Cycles' variance
from CYCLES_RUNS seeds), and the blurred edge must really be blurred (its column profile far from the sharp
render's, on Cycles' side of it). The export tests check the shutter's placement (Position), Shutter 0 and the
named warnings. About 20 s on 2 cores with compiled kernels cached (the images are 48 x 24).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import crosscheck as cc  # noqa: E402
from monte.addon.engine import render_with_operator  # noqa: E402
from monte.addon.export import export_scene  # noqa: E402
from monte.core import compare as cmp  # noqa: E402

pytestmark = [pytest.mark.blender]

CYCLES_RUNS = 4
SPP, BOUNCES = 64, 2
CUBE = [(-0.5, -0.5, -0.5), (0.5, -0.5, -0.5), (0.5, 0.5, -0.5), (-0.5, 0.5, -0.5),
        (-0.5, -0.5, 0.5), (0.5, -0.5, 0.5), (0.5, 0.5, 0.5), (-0.5, 0.5, 0.5)]
FACES = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]


def _linear_keys(obj, path: str, frames_values) -> None:
    """Keyframes of obj.path with linear interpolation, so that the motion is uniform."""
    for frame, value in frames_values:
        setattr(obj, path, value)
        obj.keyframe_insert(path, frame=frame)
    owner = obj.id_data
    animation = owner.animation_data
    action = animation.action
    if hasattr(action, "fcurves"):  # Blender 4.x
        curves = action.fcurves
    else:  # layered actions (Blender 5)
        from bpy_extras import anim_utils

        curves = anim_utils.action_get_channelbag_for_slot(action, animation.action_slot).fcurves
    for curve in curves:
        for point in curve.keyframe_points:
            point.interpolation = "LINEAR"


def cube_scene(move: str, shutter: float = 1.0):
    """A dark diffuse cube (0.1) under a white world seen from -y, at frame 2 with a shutter of `shutter`
    frames centred on it. move: "object" (the cube goes 1 m/frame along +x), "rotate" (it turns a quarter turn
    per frame about z), "camera" (the camera goes 0.6
    m/frame along +x), "deform" (a shape key stretches the cube's +x side 1.2 m/frame) or "none"."""
    scene = bf.reset()
    cube = bf.mesh_object("cube", CUBE, FACES, bf.diffuse("dark", (0.1, 0.1, 0.1)))
    cam = bf.camera_object(scene, (0, -6, 0), (math.pi / 2, 0, 0), lens=50.0)
    bf.set_world(scene, (1.0, 1.0, 1.0), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = 48, 24
    scene.render.resolution_percentage = 100
    if move == "object":
        _linear_keys(cube, "location", [(1, (-1.0, 0, 0)), (3, (1.0, 0, 0))])
    elif move == "rotate":
        _linear_keys(cube, "rotation_euler", [(1, (0, 0, 0.0)), (3, (0, 0, math.pi))])
    elif move == "camera":
        _linear_keys(cam, "location", [(1, (-0.6, -6, 0)), (3, (0.6, -6, 0))])
    elif move == "deform":
        cube.shape_key_add(name="Basis")
        key = cube.shape_key_add(name="stretch", from_mix=False)
        for i, v in enumerate(CUBE):
            if v[0] > 0:
                key.data[i].co = (v[0] + 2.4, v[1], v[2])
        _linear_keys(key, "value", [(1, 0.0), (3, 1.0)])
    scene.frame_set(2)
    scene.render.use_motion_blur = move != "none"
    scene.render.motion_blur_shutter = shutter
    return scene


def monte_image(scene) -> tuple[np.ndarray, np.ndarray]:
    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = SPP, BOUNCES, 1, 2
    scene.view_layers[0].monte.use_pass_variance = True  # the comparison reads Monte's error estimate
    result = render_with_operator(scene)[0][1]
    return np.asarray(result.color, np.float64)[..., :3], np.asarray(result.variance, np.float64)


def cycles_image(scene, tmp_path) -> tuple[np.ndarray, np.ndarray]:
    runs = []
    layer = scene.view_layers[0].name
    for seed in range(1, CYCLES_RUNS + 1):
        cc.configure_cycles(scene, SPP // 2, BOUNCES, threads=2, seed=seed)
        render_with_operator(scene)
        ch = bf.save_render_exr(scene, tmp_path / f"cycles{seed}.exr")
        runs.append(np.stack([ch[f"{layer}.Combined.{c}"] for c in "RGB"], axis=-1))
    return cmp.runs_mean_and_variance(np.stack(runs))


def check_blur(name: str, scene, tmp_path) -> None:
    """Monte and Cycles agree (means within 1 %, per-pixel z-scores), and the edge really is blurred: the column
    profile of the grey level moves far (beyond 10 of its standard errors) from the sharp image's, and Monte's
    profile lies within 5 standard errors of Cycles' in every column."""
    mon, mon_var = monte_image(scene)
    cyc, cyc_var = cycles_image(scene, tmp_path)
    c = cmp.compare(mon, mon_var, cyc, cyc_var, rel_cap=0.01)
    ok, reasons = c.verdict()
    print(f"\n{name}: Monte {np.round(c.mean_a, 4)} Cycles {np.round(c.mean_b, 4)} rel "
          f"{np.round(100 * c.relative_difference, 2)} % z {c.z_stats()}")
    assert ok, f"{name}: {reasons}"
    scene.render.use_motion_blur = False
    sharp, _ = monte_image(scene)
    profile = lambda img: img.mean(axis=(0, 2))  # noqa: E731
    h = mon.shape[0]
    se_mon = np.sqrt(mon_var.mean(axis=2).sum(axis=0) / 3) / h
    se_cyc = np.sqrt(cyc_var.mean(axis=2).sum(axis=0) / 3) / h
    # floored at 0.001: at the ends of a ramp few samples see the cube and the variance estimates fall short
    se = np.sqrt(se_mon ** 2 + se_cyc ** 2) + 1e-3
    moved = np.abs(profile(mon) - profile(sharp)) / se
    assert moved.max() > 10, f"{name}: the blurred image is not blurred ({moved.max():.1f} standard errors)"
    gap = np.abs(profile(mon) - profile(cyc)) / se
    print(f"{name}: edge profile Monte {np.round(profile(mon), 3)}\n Cycles {np.round(profile(cyc), 3)}\n"
          f" sharp {np.round(profile(sharp), 3)}; largest gap {gap.max():.2f} standard errors")
    assert gap.max() < 5, f"{name}: the blurred edge profile differs from Cycles' ({gap.max():.1f} std. errors)"


def test_moving_object_matches_cycles(tmp_path):
    check_blur("object motion", cube_scene("object"), tmp_path)


def test_moving_textured_object_matches_cycles(tmp_path):
    """A checker texture in Generated coordinates moves with the cube (its coordinates follow the object over
    the shutter), where texture coordinates taken at the frame would hold the pattern still."""
    scene = cube_scene("object")
    mat = bpy.data.materials["dark"]
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfDiffuse")
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = 3.0
    checker.inputs["Color1"].default_value = (0.9, 0.9, 0.9, 1.0)
    checker.inputs["Color2"].default_value = (0.02, 0.02, 0.02, 1.0)
    tree.links.new(checker.outputs["Color"], bsdf.inputs["Color"])
    check_blur("textured object motion", scene, tmp_path)


def test_rotating_object_matches_cycles(tmp_path):
    """A quarter turn over the shutter in Cycles' 3 steps: the vertices are baked at more steps (their arcs)."""
    scene = cube_scene("rotate")
    assert _export(scene).meshes[0].motion_vertices.shape[0] > 3
    check_blur("rotation", scene, tmp_path)


def test_moving_camera_matches_cycles(tmp_path):
    check_blur("camera motion", cube_scene("camera"), tmp_path)


def test_deforming_mesh_matches_cycles(tmp_path):
    check_blur("deformation", cube_scene("deform"), tmp_path)


# ------------------------------------------------------------------------------------------- the export
def _export(scene):
    return export_scene(bpy.context.evaluated_depsgraph_get())[0]


@pytest.mark.parametrize("position, first_x, last_x", [("START", 0.0, 0.5), ("CENTER", -0.25, 0.25),
                                                        ("END", -0.5, 0.0)])
def test_shutter_position_places_the_steps(position, first_x, last_x):
    """The cube's centre at shutter open and close (1 m/frame, shutter 0.5 frames, frame 2 at x = 0); what does
    not blur is exported at the shutter's centre (Cycles syncs there); the frame is set back after the export."""
    scene = cube_scene("object", shutter=0.5)
    scene.render.motion_blur_position = position
    core = _export(scene)
    steps = core.meshes[0].motion_vertices
    assert steps.shape == (3, 8, 3)  # Steps 1: Cycles' 3 steps
    np.testing.assert_allclose(steps[[0, -1]].mean(axis=1)[:, 0], [first_x, last_x], atol=1e-5)
    np.testing.assert_allclose(core.meshes[0].vertices.mean(axis=0)[0], (first_x + last_x) / 2, atol=1e-5)
    assert scene.frame_current == 2 and scene.frame_subframe == 0.0
    assert bpy.data.objects["cube"].location.x == pytest.approx(0.0, abs=1e-6)


def test_start_on_frame_matches_cycles(tmp_path):
    """Position Start on Frame: the blur runs from the frame's pose onwards."""
    scene = cube_scene("object")
    scene.render.motion_blur_position = "START"
    check_blur("start on frame", scene, tmp_path)


def test_object_motion_steps_and_camera_motion_are_exported():
    scene = cube_scene("camera")
    bpy.data.objects["cube"].cycles.motion_steps = 3  # (2 << 2) + 1 = 9 steps; the camera keeps 3
    core = _export(scene)
    cam = core.camera.motion_matrices
    assert cam.shape == (3, 4, 4)
    np.testing.assert_allclose(cam[:, 0, 3], [-0.3, 0.0, 0.3], atol=1e-5)
    assert core.meshes[0].motion_vertices is None  # the cube does not move
    bpy.data.objects["Camera"].cycles.use_motion_blur = False
    assert _export(scene).camera.motion_matrices is None


def test_shutter_zero_or_motion_blur_off_renders_sharp():
    scene = cube_scene("object")
    scene.render.motion_blur_shutter = 0.0
    core = _export(scene)
    assert core.meshes[0].motion_vertices is None and not core.has_motion
    scene.render.motion_blur_shutter = 1.0
    bpy.data.objects["cube"].cycles.use_motion_blur = False
    assert _export(scene).meshes[0].motion_vertices is None


def test_deformation_is_sampled_and_can_be_turned_off():
    scene = cube_scene("deform", shutter=0.5)
    steps = _export(scene).meshes[0].motion_vertices
    assert steps is not None
    # frame 2 is halfway (value 0.5: +1.2 m on the +x side); +-0.25 frames moves that side -+0.3 m
    np.testing.assert_allclose(steps[[0, 2], 1, 0], [0.5 + 0.9, 0.5 + 1.5], atol=1e-5)
    bpy.data.objects["cube"].cycles.use_deform_motion = False
    assert _export(scene).meshes[0].motion_vertices is None


def test_zoom_matches_cycles(tmp_path):
    """A still cube, the camera zooming 20 -> 80 mm over frames 1-3 (35 -> 65 over the shutter): a radial blur."""
    scene = cube_scene("none")
    _linear_keys(bpy.data.objects["Camera"].data, "lens", [(1, 20.0), (3, 80.0)])
    scene.frame_set(2)
    scene.render.use_motion_blur = True
    core = _export(scene)
    assert core.camera.motion_lens == pytest.approx((35.0, 65.0)) and core.camera.lens == pytest.approx(50.0)
    check_blur("zoom", scene, tmp_path)
    scene.render.use_motion_blur = True
    bpy.data.objects["Camera"].data.dof.use_dof = True
    warnings = _export(scene).warnings
    assert any("camera 'Camera'" in w and "zoom" in w and "depth of field" in w for w in warnings), warnings


def test_rolling_shutter_is_exported():
    scene = cube_scene("object")
    assert _export(scene).camera.rolling_shutter is None
    scene.cycles.rolling_shutter_type = "TOP"
    scene.cycles.rolling_shutter_duration = 0.25
    assert _export(scene).camera.rolling_shutter == pytest.approx(0.25)


def test_rolling_shutter_matches_cycles(tmp_path):
    """Rolling Shutter (Top, duration 0.2): rows exposed in turn, the cube sheared as well as blurred."""
    scene = cube_scene("object")
    scene.cycles.rolling_shutter_type = "TOP"
    scene.cycles.rolling_shutter_duration = 0.2
    check_blur("rolling shutter", scene, tmp_path)


def _bend_shutter_curve(scene) -> None:
    curve = scene.render.motion_blur_shutter_curve
    curve.curves[0].points[1].location = (0.5, 0.2)
    curve.update()


def test_shutter_curve_is_exported():
    scene = cube_scene("object")
    assert _export(scene).camera.shutter_curve is None  # flat: nothing to do
    _bend_shutter_curve(scene)
    curve = _export(scene).camera.shutter_curve
    assert curve.shape == (256,)
    np.testing.assert_allclose(curve[[0, 128, -1]], [1.0, 0.2, 1.0], atol=0.01)


def test_shutter_curve_matches_cycles(tmp_path):
    """A shutter mostly open at its ends (Shutter Curve 1, 0.2, 1): the blurred cube weighs its end positions."""
    scene = cube_scene("object")
    _bend_shutter_curve(scene)
    check_blur("shutter curve", scene, tmp_path)
