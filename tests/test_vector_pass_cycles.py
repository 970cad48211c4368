"""The Vector pass (Cycles' motion vectors, rendered without motion blur) in Blender against Cycles: a ball
moving across a floor while the camera moves, both engines' Vector passes compared per pixel inside the objects;
with motion blur on it is not produced (as in Cycles) and a warning says so."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon.engine import data_passes, requested_passes, unavailable_pass_warnings  # noqa: E402
from monte.core import exr  # noqa: E402

pytestmark = [pytest.mark.blender]

SIZE = (48, 36)
SPP = 16


def moving_scene():
    """Frame 2 of a linear animation: a ball going 1 m per frame along x (and 0.25 m up), the camera 0.2 m per
    frame along x, over a still floor (pass index 1; the ball 2)."""
    scene = bf.reset()
    bpy.context.preferences.edit.keyframe_new_interpolation_type = "LINEAR"
    s = 6.0
    floor = bf.mesh_object("Floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                           bf.diffuse("FloorMat", (0.5, 0.5, 0.5)))
    ball = bf.icosphere_object("Ball", (0.0, 0.0, 0.8), 0.8, bf.diffuse("BallMat", (0.8, 0.3, 0.2)),
                               subdivisions=3)
    floor.pass_index, ball.pass_index = 1, 2
    for frame, x in ((1, -1.0), (3, 1.0)):
        ball.location = (x, 0.0, 0.8 + 0.25 * (frame - 2))
        ball.keyframe_insert("location", frame=frame)
    cam = bf.camera_object(scene, (0.0, -6.0, 3.5), (np.radians(62), 0.0, 0.0), lens=35.0)
    for frame, x in ((1, -0.2), (3, 0.2)):
        cam.location = (x, -6.0, 3.5)
        cam.keyframe_insert("location", frame=frame)
    scene.frame_set(2)
    bf.set_world(scene, (0.3, 0.3, 0.3), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.use_motion_blur = False
    layer = scene.view_layers[0]
    layer.use_pass_vector = True
    layer.use_pass_object_index = True
    return scene


def passes_of(channels: dict, layer: str) -> tuple[np.ndarray, np.ndarray]:
    return (np.stack([channels[f"{layer}.Vector.{c}"] for c in "XYZW"], axis=-1),
            channels[f"{layer}.Object Index.X"])


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("vector")
    scene = moving_scene()
    layer = scene.view_layers[0].name
    scene.render.use_motion_blur = False  # Cycles renders the Vector pass only without motion blur
    cycles_exr, monte_exr = bf.cycles_and_monte_exrs(scene, tmp, SPP, 2)
    return scene, passes_of(exr.read_exr(cycles_exr), layer), passes_of(exr.read_exr(monte_exr), layer)


def interior(index: np.ndarray) -> np.ndarray:
    pad = np.pad(index, 2, mode="edge")
    same = np.ones(index.shape, bool)
    for dy in range(5):
        for dx in range(5):
            same &= pad[dy:dy + index.shape[0], dx:dx + index.shape[1]] == index
    return same


def test_vector_pass_matches_cycles_per_pixel(renders):
    _, (cyc, cyc_index), (mon, mon_index) = renders
    inside = interior(cyc_index) & interior(mon_index) & (cyc_index > 0)
    assert inside.sum() > 200 and (inside & (cyc_index == 2)).sum() > 20
    for c, axis in enumerate("XYZW"):
        ref, got = cyc[..., c], mon[..., c]
        tol = 0.15 * bf.footprint(ref) + 0.02
        diff = np.abs(got - ref)[inside]
        print(f"\nVector.{axis}: Cycles mean {ref[inside].mean():+.3f} px (ball {ref[inside & (cyc_index == 2)].mean():+.3f}),"
              f" max |Monte - Cycles| {diff.max():.4f} px")
        assert np.all(diff <= tol[inside]), axis
    # the ball moves about 1 m per frame: several pixels; the control: a vector of the wrong sign fails
    ball = inside & (cyc_index == 2)
    assert np.abs(cyc[ball][:, 0]).mean() > 3.0
    assert not np.all(np.abs(-mon[..., 0] - cyc[..., 0])[ball] <= 0.15 * bf.footprint(cyc[..., 0])[ball] + 0.02)


def test_vector_pass_needs_motion_blur_off(renders):
    scene, _, _ = renders
    layer = scene.view_layers[0]
    assert "Vector" in requested_passes(layer, scene)
    scene.render.use_motion_blur = True
    try:
        assert "vector" not in data_passes(layer, scene) and "Vector" not in requested_passes(layer, scene)
        assert unavailable_pass_warnings(layer, scene) == [
            f"view layer {layer.name!r}: the Vector pass is not available with motion blur on (as in Cycles); it is "
            "not produced"]
    finally:
        scene.render.use_motion_blur = False
