"""Motion blur in the core (core.motion, Embree's motion-blur triangles through core.accel) against closed forms:
rays at a time hit a moving triangle where it is at that time, a square moving across an orthographic camera
blurs into its box-convolved profile, a moving camera gives the same image as the object moving the other way,
a still scene is untouched (bit for bit), and bad motion data gets a named error or warning."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monte.core.accel import Accelerator, MotionTriangles
from monte.core.motion import camera_transforms, interpolate_corners, resample_steps, shutter_times
from monte.core.render import render
from monte.core.scene import Camera, Material, Mesh, Scene, SceneError, World
from monte.core.settings import RenderSettings


def test_rays_hit_moving_triangles_where_they_are_at_the_ray_time():
    """A unit quad moving +2 along x over the shutter and a still triangle: rays straight down at x = 2.5
    find the quad only late in the shutter, at x = 0.5 only early; the still triangle at every time."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [10, 10, 0], [11, 10, 0], [10, 11, 0]], np.float32)
    tri = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]], np.int32)
    start = v[tri[:2]]
    # three steps, the middle one halfway: linear motion
    corners = np.stack([start, start + [1, 0, 0], start + [2, 0, 0]]).astype(np.float32)
    accel = Accelerator(v, tri, motion=MotionTriangles(np.array([0, 1]), corners))
    x = np.array([2.5, 2.5, 0.5, 0.5, 10.2, 10.2, 1.4], np.float32)
    y = np.array([0.7, 0.7, 0.6, 0.6, 10.2, 10.2, 0.2], np.float32)
    times = np.array([0.1, 0.9, 0.1, 0.9, 0.0, 1.0, 0.5], np.float32)
    origins = np.stack([x, y, np.ones_like(x)], axis=1)
    down = np.tile(np.array([[0, 0, -1]], np.float32), (len(x), 1))
    hits = accel.intersect(origins, down, time=times)
    # at time u the quad spans x in [2u, 2u + 1]; triangle 0 is the lower-right half (y < x - 2u)
    np.testing.assert_array_equal(hits.prim, [-1, 0, 1, -1, 2, 2, 0])
    np.testing.assert_allclose(hits.t[hits.prim >= 0], 1.0, rtol=1e-6)
    blocked = accel.occluded(origins, down, np.full(len(x), 2.0, np.float32), time=times)
    np.testing.assert_array_equal(blocked, hits.prim >= 0)
    with pytest.raises(ValueError, match="every ray needs a time"):
        accel.intersect(origins, down)


def test_step_resampling_and_interpolation_are_linear():
    three = np.array([0.0, 1.0, 4.0])[:, None]
    np.testing.assert_allclose(resample_steps(three, 5)[:, 0], [0.0, 0.5, 1.0, 2.5, 4.0])
    corners = np.arange(2 * 1 * 9, dtype=np.float32).reshape(2, 1, 3, 3)
    mid = interpolate_corners(corners, np.array([0, 0]), np.array([0.25, 1.0]))
    np.testing.assert_allclose(mid[0], corners[0, 0] + 0.25 * 9)
    np.testing.assert_allclose(mid[1], corners[1, 0])


def test_camera_rotation_is_slerped_and_position_linear():
    """Halfway between a camera and the same turned 90 degrees about z and moved 2 m: turned 45, moved 1."""
    a = np.eye(4)
    b = np.eye(4)
    b[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    b[:3, 3] = (2, 0, 0)
    rotation, position = camera_transforms(np.stack([a, b]), np.array([0.0, 0.5, 1.0]))
    c = math.sqrt(0.5)
    np.testing.assert_allclose(rotation[1], [[c, -c, 0], [c, c, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(rotation[2], b[:3, :3], atol=1e-12)
    np.testing.assert_allclose(position[:, 0], [0, 1, 2])


# A 64 x 16 orthographic view 4 m wide looking down at an emitting bar 1 m wide (x in [-0.5, 0.5]) that fills the
# image's height; over the shutter it moves SHIFT metres along +x (or the camera moves -SHIFT).
WIDTH, HEIGHT, SCALE, SHIFT, SPP = 64, 16, 4.0, 0.75, 256


def _camera(dx: float = 0.0) -> Camera:
    m = np.eye(4)
    m[:3, 3] = (dx, 0.0, 5.0)
    return Camera(matrix_world=m, resolution=(WIDTH, HEIGHT), kind="ORTHO", ortho_scale=SCALE)


def _bar(dx: float = 0.0) -> np.ndarray:
    return np.array([[-0.5, -1, 0], [0.5, -1, 0], [0.5, 1, 0], [-0.5, 1, 0]], np.float64) + [dx, 0, 0]


def _scene(moving_bar: bool, moving_camera: bool) -> Scene:
    bar = Mesh("bar", _bar(), np.array([[0, 1, 2], [0, 2, 3]]))
    if moving_bar:
        bar.motion_vertices = np.stack([_bar(0.0), _bar(SHIFT / 2), _bar(SHIFT)])
    camera = _camera()
    if moving_camera:
        camera.motion_matrices = np.stack([_camera(0.0).matrix_world, _camera(-SHIFT).matrix_world])
    glow = Material("glow", lobes=[], emission=np.ones(3))
    return Scene(camera=camera, meshes=[bar], materials=[glow], world=World(color=np.zeros(3)))


def _settings(**kw) -> RenderSettings:
    options = dict(spp=SPP, max_bounces=0, filter_type="box", filter_width=1.0, seed=3, threads=1)
    return RenderSettings(**{**options, **kw})


def expected_profile(weight=lambda u: np.ones_like(u)) -> np.ndarray:
    """Each column's mean coverage by the bar over the shutter: the pixel's box [x0, x1] against the bar's
    [-0.5 + SHIFT u, 0.5 + SHIFT u], u in [0, 1] with density proportional to weight(u) (integrated on a fine
    grid)."""
    u = (np.arange(20000) + 0.5) / 20000
    w = weight(u) / weight(u).mean()
    edges = -SCALE / 2 + SCALE * np.arange(WIDTH + 1) / WIDTH
    lo, hi = -0.5 + SHIFT * u, 0.5 + SHIFT * u
    cover = np.clip(np.minimum(hi[:, None], edges[None, 1:]) - np.maximum(lo[:, None], edges[None, :-1]), 0, None)
    return (cover / (SCALE / WIDTH) * w[:, None]).mean(axis=0)


@pytest.mark.parametrize("what", ["object", "camera"])
def test_moving_bar_blurs_into_its_box_convolved_profile(what):
    """Each pixel's value is the fraction of its (pixel x shutter) samples that see the bar: a binomial mean, so
    within 5 of its standard errors of the closed form (Sobol samples do better); and the image really is blurred:
    each edge ramps over the motion (SHIFT = 12 pixels), where a still bar has sharp edges."""
    scene = _scene(moving_bar=what == "object", moving_camera=what == "camera")
    result = render(scene, _settings())
    columns = result.color[..., 0].astype(np.float64).mean(axis=0)
    expected = expected_profile()
    sigma = np.sqrt(np.maximum(expected * (1 - expected), 1 / SPP) / (SPP * HEIGHT))
    assert np.all(np.abs(columns - expected) < 5 * sigma + 1e-6), np.c_[columns, expected]
    ramp = np.flatnonzero((columns > 0.02) & (columns < 0.98))
    assert len(ramp) >= 20  # two ramps of about 12 pixels each; a still bar has no partly covered column
    assert abs(columns.sum() * SCALE / WIDTH - 1.0) < 0.01  # the bar's area is kept: blur only moves light


def test_shutter_curve_maps_uniform_numbers_to_its_distribution():
    u = np.linspace(0, 1, 101)
    np.testing.assert_allclose(shutter_times(u, np.array([2.0, 2.0])), u, atol=1e-6)
    np.testing.assert_allclose(shutter_times(u, np.array([0.0, 1.0])), np.sqrt(u), atol=1e-6)  # density 2t
    np.testing.assert_allclose(shutter_times(u, np.array([1.0, 0.0])), 1 - np.sqrt(1 - u), atol=1e-6)
    # a triangle over 3 points: density 4t then 4(1 - t)
    tri = shutter_times(u, np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(tri, np.where(u < 0.5, np.sqrt(u / 2), 1 - np.sqrt((1 - u) / 2)), atol=1e-6)


def test_shutter_curve_weights_the_blur():
    """A shutter opening linearly (curve 0 -> 1): the bar's later positions weigh more (density 2u)."""
    scene = _scene(moving_bar=True, moving_camera=False)
    scene.camera.shutter_curve = np.array([0.0, 1.0])
    columns = render(scene, _settings()).color[..., 0].astype(np.float64).mean(axis=0)
    expected = expected_profile(lambda u: 2 * u)
    sigma = np.sqrt(np.maximum(expected * (1 - expected), 1 / SPP) / (SPP * HEIGHT))
    assert np.all(np.abs(columns - expected) < 5 * sigma + 1e-6), np.c_[columns, expected]
    flat = expected_profile()
    assert np.abs(columns - flat).max() > 0.1  # not the flat shutter's profile


def test_rolling_shutter_times_each_row():
    """Rolling shutter of duration 0: row r (from the top) sees the bar at time (r + 1) / HEIGHT only, so each
    row shows a sharp bar whose centre moves SHIFT (r + 1) / HEIGHT; duration 1 is the global shutter."""
    scene = _scene(moving_bar=True, moving_camera=False)
    scene.camera.rolling_shutter = 0.0
    image = render(scene, _settings(spp=16)).color[..., 0].astype(np.float64)
    x = -SCALE / 2 + SCALE * (np.arange(WIDTH) + 0.5) / WIDTH
    centre = (image * x).sum(axis=1) / image.sum(axis=1)
    np.testing.assert_allclose(centre, SHIFT * (np.arange(HEIGHT) + 1) / HEIGHT, atol=0.01)
    np.testing.assert_allclose(image.sum(axis=1) * SCALE / WIDTH, 1.0, atol=0.02)  # each row: the whole bar
    times = np.linspace(0, 1, 5)
    from monte.core.motion import rolling_shutter_times

    np.testing.assert_allclose(rolling_shutter_times(times, np.full(5, 3), 8, 1.0), times, atol=1e-7)
    np.testing.assert_allclose(rolling_shutter_times(times, np.full(5, 3), 8, 0.5), 0.5 * times + 0.25, atol=1e-7)


def test_camera_motion_matches_the_object_moving_the_other_way():
    """The same rays (film position and time) see the bar at the same place relative to the camera."""
    obj = render(_scene(True, False), _settings()).color
    cam = render(_scene(False, True), _settings()).color
    differ = np.abs(obj - cam) > 1e-6
    assert differ.mean() < 0.01  # a sample exactly on an edge may round either way


def test_a_still_scene_renders_bit_identically_and_reads_no_time():
    """Motion steps that do not move are dropped at validation: the image is the still one, bit for bit."""
    still = render(_scene(False, False), _settings(spp=16)).color
    scene = _scene(False, False)
    scene.meshes[0].motion_vertices = np.stack([_bar(), _bar()])
    scene.camera.motion_matrices = np.stack([_camera().matrix_world] * 3)
    same = render(scene, _settings(spp=16)).color
    assert scene.meshes[0].motion_vertices is None and scene.camera.motion_matrices is None
    np.testing.assert_array_equal(still, same)


def test_moving_emitter_lights_as_the_time_average_of_still_ones():
    """A small emitting square moving 1 m above a diffuse floor: the floor's light is the average over the
    shutter of what the square gives at each place. Moving emitters are not light-sampled (BSDF sampling finds
    them), still ones are; both estimates are unbiased, so the moving render's mean matches the mean of 9 still
    renders along the path (midpoint rule, its error far below the 2 % allowed)."""
    def lamp(x: float) -> np.ndarray:
        return np.array([[-0.2, -0.2, 1.0], [-0.2, 0.2, 1.0], [0.2, 0.2, 1.0], [0.2, -0.2, 1.0]]) + [x, 0, 0]

    def floor_scene(x: float, moving: bool) -> Scene:
        floor = Mesh("floor", np.array([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], np.float64),
                     np.array([[0, 1, 2], [0, 2, 3]]), material_index=0)
        square = Mesh("lamp", lamp(x), np.array([[0, 1, 2], [0, 2, 3]]), material_index=1)  # facing down
        if moving:
            square.motion_vertices = np.stack([lamp(-0.5), lamp(0.5)])
        m = np.eye(4)
        m[:3, 3] = (0, 0, 4)
        camera = Camera(matrix_world=m, resolution=(16, 16), kind="ORTHO", ortho_scale=4.0)
        from monte.core.scene import Lobe

        grey = Material("grey", lobes=[Lobe("diffuse", color=np.array([0.8, 0.8, 0.8]))])
        glow = Material("glow", lobes=[], emission=np.full(3, 10.0))
        return Scene(camera=camera, meshes=[floor, square], materials=[grey, glow], world=World(color=np.zeros(3)))

    settings = RenderSettings(spp=256, max_bounces=1, seed=5, threads=1)
    moving = render(floor_scene(0.0, True), settings).color.astype(np.float64)
    still = np.mean([render(floor_scene(x, False), RenderSettings(spp=32, max_bounces=1, seed=5, threads=1))
                     .color.astype(np.float64) for x in (np.arange(9) + 0.5) / 9 - 0.5], axis=0)
    seen = np.ones((16, 16), bool)
    seen[6:10, 4:12] = False  # the lamp's own pixels (its back faces the camera: black) differ in where it is
    np.testing.assert_allclose(moving[seen].mean(), still[seen].mean(), rtol=0.02)


def test_bad_motion_data_gets_named_errors_and_warnings():
    scene = _scene(False, False)
    scene.meshes[0].motion_vertices = np.zeros((3, 5, 3))
    with pytest.raises(SceneError, match=r"mesh 'bar': motion_vertices must have shape \(S, V, 3\) with 2 <= S <= "
                                         r"129 and V = 4, got \(3, 5, 3\)"):
        scene.validate()
    scene = _scene(False, False)
    scene.meshes[0].motion_vertices = np.stack([_bar(), _bar(np.nan)])
    scene.validate()
    assert scene.meshes[0].motion_vertices is None
    assert "mesh 'bar': NaN/Inf in its motion-blur positions; rendered without motion blur" in scene.warnings
    scene = _scene(False, False)
    scene.camera.motion_matrices = np.zeros((1, 4, 4))
    with pytest.raises(SceneError, match=r"camera: motion_matrices must have shape \(S, 4, 4\) with 2 <= S <= 129, "
                                         r"got \(1, 4, 4\)"):
        scene.validate()
    scene = _scene(False, False)
    scene.camera.motion_matrices = np.stack([np.eye(4), np.zeros((4, 4))])
    with pytest.raises(SceneError, match="camera: a motion-blur matrix is singular"):
        scene.validate()
    scene = _scene(False, False)
    scene.camera.motion_lens = (35.0, 0.0)
    with pytest.raises(SceneError, match=r"camera: motion_lens must be two focal lengths > 0 \(shutter open, "
                                         r"close\), got \(35.0, 0.0\)"):
        scene.validate()
    scene = _scene(False, False)
    scene.camera.rolling_shutter = 1.5
    with pytest.raises(SceneError, match=r"camera: rolling_shutter duration 1.5 must be in \[0, 1\]"):
        scene.validate()
    scene = _scene(False, False)
    scene.camera.shutter_curve = np.array([1.0, -0.5])
    with pytest.raises(SceneError, match=r"camera: shutter_curve must be 2 or more finite values >= 0, not all 0 "
                                         r"\(how open the shutter is over its time\), got \[ 1.  -0.5\]"):
        scene.validate()


def test_rotation_is_baked_into_enough_steps_to_follow_the_arc():
    """A quarter turn about z over 3 steps, at scale 2: the dense steps keep the original ones, keep the scale,
    and a vertex at radius 2 stays on its circle between baked steps (within 1 - cos(MAX_STEP_ANGLE / 2))."""
    from monte.core.motion import MAX_STEP_ANGLE, densify_transforms

    def turn(angle):
        m = np.eye(4)
        c, s = math.cos(angle), math.sin(angle)
        m[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) * 2.0
        m[:3, 3] = (angle, 0, 0)
        return m

    coarse = np.stack([turn(0.0), turn(math.pi / 4), turn(math.pi / 2)])[:, None]
    dense = densify_transforms(coarse)
    sub = (len(dense) - 1) // 2
    assert len(dense) == 2 * sub + 1 and sub >= math.ceil((math.pi / 4) / MAX_STEP_ANGLE)
    np.testing.assert_allclose(dense[::sub], coarse, atol=1e-12)
    point = dense[:, 0, :3, :3] @ np.array([1.0, 0, 0])  # radius 2 at every baked step
    np.testing.assert_allclose(np.linalg.norm(point, axis=1), 2.0, rtol=1e-12)
    halfway = (point[1:] + point[:-1]) / 2  # what linear interpolation between baked steps gives
    assert np.linalg.norm(halfway, axis=1).min() > 2.0 * math.cos(MAX_STEP_ANGLE / 2) - 1e-12
    np.testing.assert_allclose(dense[:, 0, 0, 3], np.linspace(0, math.pi / 2, len(dense)), atol=1e-12)
    still = np.stack([turn(0.3)] * 3)[:, None]
    assert densify_transforms(still).shape == still.shape


def test_moving_mesh_hidden_from_camera_rays_is_not_seen():
    """Ray visibility with motion: the camera's own ray-casting structure (a subset of the triangles) keeps the
    visible bar's motion and leaves the hidden one out."""
    scene = _scene(moving_bar=True, moving_camera=False)
    hidden = Mesh("hidden", _bar(-1.5), np.array([[0, 1, 2], [0, 2, 3]]), visible_camera=False)
    hidden.motion_vertices = np.stack([_bar(-1.5), _bar(-1.0)])
    scene.meshes.append(hidden)
    columns = render(scene, _settings()).color[..., 0].astype(np.float64).mean(axis=0)
    expected = expected_profile()
    sigma = np.sqrt(np.maximum(expected * (1 - expected), 1 / SPP) / (SPP * HEIGHT))
    assert np.all(np.abs(columns - expected) < 5 * sigma + 1e-6)


def test_moving_smooth_sphere_with_terminator_offset_under_the_sun():
    """The shadow terminator offset lifts shadow-ray origins from the hit triangle's corners and normals: with
    motion they must be the triangle's at the ray's time. A sphere and the camera moving 2 m together under a
    sun (lighting that does not change with position) render as the still pair does, pixel by pixel."""
    from monte.core.builtin_scenes import icosphere
    from monte.core.scene import SunLight

    def sphere_scene(moving: bool) -> Scene:
        ball = icosphere("ball", (0, 0, 0), 1.0, 0)
        ball.shadow_terminator_offset = 0.5
        camera = Camera.look_at((0, -5, 0), (0, 0, 0), resolution=(32, 32))
        if moving:
            v = np.asarray(ball.vertices, np.float64)
            ball.motion_vertices = np.stack([v, v + [2.0, 0, 0]])
            later = np.array(camera.matrix_world, np.float64)
            later[0, 3] += 2.0
            camera.motion_matrices = np.stack([camera.matrix_world, later])
        sun = SunLight("sun", np.array([-0.6, 0.5, -0.6]), np.array([3.0, 3.0, 3.0]))
        return Scene(camera=camera, meshes=[ball], materials=[Material("grey", lobes=[_diffuse()])],
                     lights=[sun], world=World(color=np.zeros(3)))

    settings = RenderSettings(spp=32, max_bounces=1, seed=2, threads=1)
    still = render(sphere_scene(False), settings).color
    moving = render(sphere_scene(True), settings).color
    assert np.all(np.isfinite(moving))
    np.testing.assert_allclose(moving.mean(axis=(0, 1)), still.mean(axis=(0, 1)), rtol=0.01)
    # The same sampler numbers trace the same relative paths: pixel by pixel equal up to float rounding (6e-8
    # measured; shadow rays lifted from another triangle's corners differ by 8e-4).
    np.testing.assert_allclose(moving, still, rtol=0, atol=1e-5)


def _diffuse():
    from monte.core.scene import Lobe

    return Lobe("diffuse", color=np.array([0.8, 0.8, 0.8]))


def test_a_moving_transparent_card_casts_its_shadow_where_it_is_at_each_rays_time():
    """A Transparent BSDF card (transparency 0.5, unseen by the camera; x in [-0.5, 0.5] at the frame) moving
    from x = -1 to x = +1 over the shutter between a sun shining straight down and a grey floor: the shadow rays
    pass it where it is at their time, so each column reads L0 (1 - 0.5 c) with c its mean coverage by the card
    over pixel and shutter (0.5 in the middle: 0.75 L0, where the frame's pose would give 0.5 L0), each sample
    0.5 L0 or L0: within 5 standard errors of that mean."""
    from monte.core.scene import Lobe, SunLight

    def card(dx: float) -> np.ndarray:
        return np.array([[-0.5, -3, 0.5], [0.5, -3, 0.5], [0.5, 3, 0.5], [-0.5, 3, 0.5]], np.float64) + [dx, 0, 0]

    floor = Mesh("floor", np.array([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], np.float64),
                 np.array([[0, 1, 2], [0, 2, 3]]), material_index=0)
    veil = Mesh("veil", card(0.0), np.array([[0, 1, 2], [0, 2, 3]]), material_index=1, visible_camera=False)
    veil.motion_vertices = np.stack([card(-1.0), card(1.0)])
    materials = [Material("grey", [Lobe("diffuse", np.full(3, 0.5))]),
                 Material("veil", [Lobe("refraction", np.full(3, 0.5), roughness=0.0, ior=1.0)])]
    sun = SunLight("sun", np.array([0.0, 0.0, -1.0]), np.full(3, 3.0), angle=0.0)
    scene = Scene(camera=_camera(), meshes=[floor, veil], materials=materials, lights=[sun],
                  world=World(color=np.zeros(3)))
    result = render(scene, _settings(spp=64))
    assert result.stats["features"]["transparent_shadows"] and result.stats["features"]["moving_triangles"] == 2
    lit = 0.5 * 3.0 / math.pi
    columns = result.color[..., 0].astype(np.float64).mean(axis=0) / lit
    u = (np.arange(20000) + 0.5) / 20000
    edges = -SCALE / 2 + SCALE * np.arange(WIDTH + 1) / WIDTH
    lo, hi = -1.5 + 2 * u, -0.5 + 2 * u
    cover = np.clip(np.minimum(hi[:, None], edges[None, 1:]) - np.maximum(lo[:, None], edges[None, :-1]), 0, None)
    expected = 1 - 0.5 * (cover / (SCALE / WIDTH)).mean(axis=0)
    sigma = 0.5 * np.sqrt(np.maximum((1 - expected) * 2 * (1 - 2 * (1 - expected)), 1 / 64) / (64 * HEIGHT))
    assert np.all(np.abs(columns - expected) < 5 * sigma + 1e-5), np.c_[columns, expected]
    assert abs(columns[WIDTH // 2 - 4:WIDTH // 2 + 4].mean() - 0.75) < 0.02
