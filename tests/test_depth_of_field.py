"""The thin-lens camera (core.camera with Camera.use_dof) against closed forms: points in the plane in focus stay
sharp, points off it spread into the thin lens's circle of confusion, the blade polygon's shape and area, a
pinhole when depth of field is off (bit for bit) or degenerate, and errors naming each bad setting."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monte.core.camera import aperture_point, camera_rays
from monte.core.render import render
from monte.core.sampling import make_sampler
from monte.core.scene import Camera, Material, Mesh, Scene, SceneError, World
from monte.core.settings import RenderSettings

N = 1 << 14  # lens samples per test: sampling errors below are stated in standard errors of this N


def lens_samples(n: int = N, seed: int = 7) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 2), dtype=np.float32)


def dof_camera(kind: str = "PERSP", **kwargs) -> Camera:
    eye, target = (0.3, -6.0, 1.2), (0.0, 0.0, 0.5)
    settings = {"use_dof": True, "aperture_fstop": 1.4, "focus_distance": 4.0, **kwargs}
    cam = Camera.look_at(eye, target, resolution=(64, 48), kind=kind, **settings)
    cam.validate()
    return cam


def view_axis(cam: Camera) -> np.ndarray:
    m = np.asarray(cam.matrix_world, np.float64)
    return -m[:3, 2] / np.linalg.norm(m[:3, 2])


def at_depth(cam: Camera, rays, depth: float) -> np.ndarray:
    """Where each ray (camera-relative) crosses the plane `depth` metres ahead along the view axis."""
    o, d = rays.origins.astype(np.float64), rays.directions.astype(np.float64)
    fwd = view_axis(cam)
    t = (depth - o @ fwd) / (d @ fwd)
    return o + t[:, None] * d


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_aperture_radius_follows_cycles(kind):
    cam = dof_camera(kind)
    expected = (1.0 if kind == "ORTHO" else cam.lens * 1e-3) / (2 * 1.4)
    assert cam.aperture_radius() == pytest.approx(expected, rel=1e-12)
    for off in (dict(use_dof=False), dict(aperture_fstop=0.0), dict(focus_distance=0.0)):
        assert Camera(cam.matrix_world, kind=kind, **{**dict(use_dof=True), **off}).aperture_radius() == 0.0


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
@pytest.mark.parametrize("blades", [0, 6])
def test_points_in_the_plane_in_focus_stay_sharp(kind, blades):
    """Every lens point's ray through a raster position meets the pinhole ray where it crosses the plane in
    focus: that plane images sharply."""
    cam = dof_camera(kind, aperture_blades=blades, aperture_rotation=0.4, aperture_ratio=1.7)
    pinhole = Camera(**{**cam.__dict__, "use_dof": False})
    rx, ry = np.full(N, 13.25), np.full(N, 40.5)
    lens = at_depth(cam, camera_rays(cam, rx, ry, lens_samples()), cam.focus_distance)
    sharp = at_depth(pinhole, camera_rays(pinhole, rx[:1], ry[:1]), cam.focus_distance)[0]
    assert np.abs(lens - sharp).max() < 2e-6 * cam.focus_distance  # float32 rays


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
@pytest.mark.parametrize("depth", [1.5, 9.0])
def test_points_off_focus_spread_into_the_thin_lens_circle(kind, depth):
    """Rays through one raster position cross a plane at `depth` in a uniform disk about the pinhole ray of
    radius R |depth - focus| / focus (the thin lens's circle of confusion, in object space; the orthographic
    lens's rays all leave parallel to the view axis of the pixel, so the same similar triangles hold)."""
    cam = dof_camera(kind)
    pinhole = Camera(**{**cam.__dict__, "use_dof": False})
    rx, ry = np.full(N, 20.5), np.full(N, 10.5)
    spread = at_depth(cam, camera_rays(cam, rx, ry, lens_samples()), depth)
    centre = at_depth(pinhole, camera_rays(pinhole, rx[:1], ry[:1]), depth)[0]
    radius = cam.aperture_radius() * abs(depth - cam.focus_distance) / cam.focus_distance
    r2 = ((spread - centre) ** 2).sum(axis=1) / radius**2
    # r^2 / radius^2 of a uniform disk point is uniform on [0, 1]: mean 1/2, standard error sqrt(1/12 / N).
    assert r2.max() <= 1 + 1e-4 and r2.max() > 1 - 1e-2
    assert abs(r2.mean() - 0.5) < 5 * math.sqrt(1 / 12 / N)
    assert np.abs((spread - centre).mean(axis=0)).max() < 5 * radius * math.sqrt(0.25 / N)


@pytest.mark.parametrize("blades, rotation", [(3, 0.0), (5, 0.3), (8, -1.0)])
def test_blade_polygon_shape_and_area(blades, rotation):
    """The aperture with n blades: uniform in the regular n-gon inscribed in the unit circle with its corners
    at rotation + (2k + 1) pi / n (Cycles' polygon). Checked: the reach towards each corner (1) and each edge's
    normal (the apothem cos(pi/n)), the area through the density at the centre (fraction of points in a small
    central square = square's area / polygon's area) and the second moment of a uniform n-gon."""
    u = lens_samples(1 << 16, seed=blades)
    p = np.array([aperture_point(float(a), float(b), blades, rotation, 1.0) for a, b in u])
    half = math.pi / blades
    corners = rotation + (2 * np.arange(blades) + 1) * half
    edges = rotation + 2 * np.arange(blades) * half
    reach = lambda angles: (p @ np.stack([np.cos(angles), np.sin(angles)])).max(axis=0)  # noqa: E731
    assert np.allclose(reach(corners), 1.0, atol=0.02) and reach(corners).max() <= 1 + 1e-9
    assert np.allclose(reach(edges), math.cos(half), atol=1e-3) and reach(edges).max() <= math.cos(half) + 1e-9
    area = 0.5 * blades * math.sin(2 * half)
    side = 0.3
    inside = float(np.mean((np.abs(p[:, 0]) < side / 2) & (np.abs(p[:, 1]) < side / 2)))
    expected = side**2 / area
    assert abs(inside - expected) < 5 * math.sqrt(expected * (1 - expected) / len(p))
    r2 = (p**2).sum(axis=1)
    second = math.cos(half) ** 2 / 2 + math.sin(half) ** 2 / 6
    assert abs(r2.mean() - second) < 5 * r2.std() / math.sqrt(len(p))


def test_round_aperture_and_anamorphic_ratio():
    """Fewer than 3 blades: the unit disk; aperture_ratio 2 halves it along x (Cycles divides x by the ratio)."""
    u = lens_samples(1 << 15)
    for blades in (0, 1, 2):
        p = np.array([aperture_point(float(a), float(b), blades, 0.0, 1.0) for a, b in u[:4096]])
        assert (p**2).sum(axis=1).max() <= 1 + 1e-9
    p = np.array([aperture_point(float(a), float(b), 0, 0.0, 0.5) for a, b in u])
    se = lambda v: 5 * v.std() / math.sqrt(len(v))  # noqa: E731
    assert abs((p[:, 0] ** 2).mean() - 0.25 / 4) < se(p[:, 0] ** 2)  # E[x^2] of the unit disk is 1/4
    assert abs((p[:, 1] ** 2).mean() - 0.25) < se(p[:, 1] ** 2)


@pytest.mark.parametrize("off", [dict(use_dof=False), dict(aperture_fstop=0.0), dict(focus_distance=0.0)])
def test_pinhole_when_off_or_degenerate_is_bit_identical(off):
    """Depth of field off, an f-stop of 0 or a focus distance of 0: exactly the pinhole camera's rays, whatever
    lens samples are passed (and none are needed)."""
    cam = dof_camera(**{k: v for k, v in off.items() if k != "use_dof"})
    if "use_dof" in off:
        cam.use_dof = False
    pinhole = Camera(**{**cam.__dict__, "use_dof": False})
    rx, ry = np.random.default_rng(1).random((2, 500)) * 48
    a, b = camera_rays(cam, rx, ry, lens_samples(500)), camera_rays(pinhole, rx, ry)
    for name in ("origins", "directions", "tmax", "depth_scale", "t_start"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert np.isfinite(getattr(a, name)).all()


def test_lens_samples_are_required_with_an_aperture():
    cam = dof_camera()
    with pytest.raises(ValueError, match="lens samples"):
        camera_rays(cam, np.zeros(3), np.zeros(3))


@pytest.mark.parametrize("setting, value", [
    ("aperture_fstop", -1.0), ("aperture_fstop", float("nan")), ("focus_distance", -0.5),
    ("focus_distance", float("inf")), ("aperture_rotation", float("nan")), ("aperture_ratio", 0.0),
    ("aperture_ratio", float("nan")), ("aperture_blades", -3), ("aperture_blades", 4.5),
])
def test_bad_settings_name_themselves(setting, value):
    cam = Camera(np.eye(4), use_dof=True, **{setting: value})
    with pytest.raises(SceneError, match=setting):
        cam.validate()


def _emitter_scene(cam: Camera) -> Scene:
    """A small emitting square 6 m ahead, facing the camera, on black."""
    s, z = 0.25, -6.0
    quad = np.array([[-s, -s, z], [s, -s, z], [s, s, z], [-s, s, z]], np.float32)
    mesh = Mesh("glow", quad, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material_index=0)
    return Scene(camera=cam, meshes=[mesh], materials=[Material("glow", emission=np.ones(3))],
                 world=World(color=np.zeros(3)))


def test_render_spreads_an_emitter_by_the_circle_of_confusion():
    """A rendered emitter off focus: its image keeps its power (the total over the film) and is the sharp image
    convolved with the circle of confusion, a uniform disk of radius R |z - f| / (f z) on the plane at distance
    1: its variance along each image axis grows by radius^2 / 4 (the disk's), whatever the square and the pixel
    filter add to both."""
    res, spp = (48, 48), 256
    base = dict(resolution=res, lens=50.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    m = np.eye(4)
    sharp = Camera(m, **base)
    blurred = Camera(m, use_dof=True, aperture_fstop=0.1, focus_distance=1.5, **base)
    settings = RenderSettings(spp=spp, max_bounces=1, seed=4)
    results = [render(_emitter_scene(c), settings) for c in (sharp, blurred)]
    images = [r.color[..., 0].astype(np.float64) for r in results]
    assert np.isfinite(images[1]).all()
    # Power: the same total within 4 sigma of the renders' noise (pixels are independent: the variance of a sum
    # is the sum of the pixels' variances): 4 sigma is ~2.1 % of the total at 256 spp (the blurred image's noise),
    # so the smallest error it detects is 5 % (1 % would take ~20x the samples); the control: a total 5 % off fails.
    sigma = math.sqrt(sum(float(r.variance[..., 0].astype(np.float64).sum()) for r in results))
    tol = 4 * sigma + 1e-5 * images[0].sum()
    assert abs(images[1].sum() - images[0].sum()) <= tol, (images[1].sum(), images[0].sum(), sigma)
    for wrong in (1.05, 0.95):
        assert abs(images[1].sum() - wrong * images[0].sum()) > tol, (wrong, tol / images[0].sum())
    pixel = (36.0 / 50.0) / res[0]  # pixel size on the plane at distance 1
    coc = blurred.aperture_radius() * (6.0 - 1.5) / (1.5 * 6.0) / pixel  # circle of confusion radius, pixels
    centres = np.arange(res[0]) + 0.5

    def variance(image, axis):
        w = image.sum(axis=axis)
        mean = (w * centres).sum() / w.sum()
        return (w * (centres - mean) ** 2).sum() / w.sum()

    for axis in (0, 1):
        grown = variance(images[1], axis) - variance(images[0], axis)
        print(f"axis {axis}: variance grew by {grown:.3f} px^2, circle of confusion {coc:.2f} px: {coc**2 / 4:.3f}")
        assert grown == pytest.approx(coc**2 / 4, rel=0.05)


@pytest.mark.parametrize("panorama", ["EQUIRECTANGULAR", "FISHEYE_EQUIDISTANT", "MIRRORBALL"])
def test_panoramic_depth_of_field_focuses_on_a_sphere(panorama):
    """Cycles' depth of field on a panorama: every lens ray through a raster position passes through the point
    at focus_distance along that position's pinhole ray (a sphere in focus about the camera, not a plane), from
    a lens point in the plane perpendicular to the pinhole ray, uniform in the disk of the aperture's radius;
    the ray starts clip_start beyond its lens point."""
    cam = dof_camera("PANO", panorama_type=panorama, aperture_fstop=0.5, focus_distance=3.0, clip_start=0.25)
    pinhole = Camera(**{**cam.__dict__, "use_dof": False})
    rx, ry = np.full(N, 20.5), np.full(N, 16.5)
    rays = camera_rays(cam, rx, ry, lens_samples())
    centre = camera_rays(pinhole, rx[:1], ry[:1]).directions[0].astype(np.float64)
    o, d = rays.origins.astype(np.float64), rays.directions.astype(np.float64)
    lens_point = o - cam.clip_start * d
    in_focus = centre * cam.focus_distance
    miss = np.cross(in_focus - lens_point, d)  # distance of the point in focus from each ray's line
    assert np.linalg.norm(miss, axis=1).max() < 1e-5 * cam.focus_distance
    radius = cam.aperture_radius()
    assert radius == pytest.approx(cam.lens * 1e-3 / (2 * 0.5))
    assert np.abs(lens_point @ centre).max() < 1e-6
    r2 = (lens_point**2).sum(axis=1) / radius**2
    assert r2.max() <= 1 + 1e-4 and r2.max() > 1 - 1e-2
    assert abs(r2.mean() - 0.5) < 5 * math.sqrt(1 / 12 / N)
    # off the sphere in focus the rays spread: at twice the focus distance, by the aperture's radius again
    far = o + ((2 * cam.focus_distance - cam.clip_start) * d)
    spread = np.linalg.norm(far - 2 * in_focus, axis=1) / radius
    assert 0.95 < spread.max() < 1.05
