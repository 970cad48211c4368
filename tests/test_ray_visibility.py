"""Per-object ray visibility in the core renderer (core.scene.Mesh.visible_camera / visible_shadow): a red
square between a point light and a grey floor, hidden from camera rays, from shadow rays, or both, against the
floor rendered alone (the same random numbers, so equal images are equal bit for bit)."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.render import render
from monte.core.scene import Camera, Lobe, Material, Mesh, PointLight, Scene, World
from monte.core.settings import RenderSettings

SETTINGS = RenderSettings(spp=8, max_bounces=0, seed=2, threads=1)  # direct light only


def _quad(name: str, half: float, z: float, material: int, **flags) -> Mesh:
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float64)
    return Mesh(name, v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material_index=material, **flags)


def _scene(square_flags: dict | None, **light) -> Scene:
    cam = Camera(np.eye(4), resolution=(24, 24), lens=20.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    cam.matrix_world[:3, 3] = (0.0, 0.0, 3.0)
    meshes = [_quad("floor", 3.0, -1.0, 0)]
    if square_flags is not None:
        meshes.append(_quad("square", 0.4, 0.5, 1, **square_flags))
    mats = [Material("grey", [Lobe("diffuse", np.full(3, 0.5))]), Material("red", [Lobe("diffuse", (0.9, 0.1, 0.1))])]
    light = PointLight("lamp", np.array([0.0, 0.0, 2.0]), np.full(3, 200.0), **light)
    return Scene(camera=cam, meshes=meshes, materials=mats, lights=[light], world=World(np.zeros(3)))


@pytest.fixture(scope="module")
def alone() -> np.ndarray:
    return render(_scene(None), SETTINGS).color


def test_hidden_from_camera_and_shadow_rays_is_as_if_absent(alone):
    got = render(_scene(dict(visible_camera=False, visible_shadow=False)), SETTINGS)
    np.testing.assert_array_equal(got.color, alone)
    assert got.stats["features"]["ray_visibility"] == ["camera", "shadow"]
    # Rays cast against the camera's and the shadow rays' own structures are counted too.
    assert got.stats["rays_closest"] >= 24 * 24 * SETTINGS.spp
    assert got.stats["rays_shadow"] == render(_scene(None), SETTINGS).stats["rays_shadow"]


def test_hidden_from_camera_still_casts_its_shadow(alone):
    got = render(_scene(dict(visible_camera=False)), SETTINGS).color
    rgb = got[..., :3]
    assert np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 1], rgb[..., 2])  # no red seen
    shadow = got[..., 0] < 0.5 * alone[..., 0]
    assert 0.05 < shadow.mean() < 0.5  # the square's shadow on the floor
    assert (got[..., 0] <= alone[..., 0]).all()


def test_hidden_from_shadow_rays_is_seen_but_casts_no_shadow(alone):
    got = render(_scene(dict(visible_shadow=False)), SETTINGS).color
    red = got[..., 0] != got[..., 1]  # pixels the square covers, even in part (the floor is grey)
    assert red.mean() > 0.02 and (got[red][:, 0] > got[red][:, 1]).all()  # the square is seen
    np.testing.assert_array_equal(got[~red], alone[~red])  # and the floor around it is fully lit


@pytest.mark.parametrize("radius", [0.0, 0.3])
def test_a_light_that_casts_no_shadow_lights_through_the_square(radius):
    """Cast Shadow off: next-event estimation ignores the square (with max_bounces 0 and a point light no BSDF
    sample reaches the light: the floor is lit as if the square were absent, while the square is still seen)."""
    alone_r = render(_scene(None, radius=radius), SETTINGS).color
    got = render(_scene({}, radius=radius, cast_shadow=False), SETTINGS)
    shadowed = render(_scene({}, radius=radius), SETTINGS).color
    red = got.color[..., 0] != got.color[..., 1]
    assert red.mean() > 0.02
    if radius == 0:
        np.testing.assert_array_equal(got.color[~red], alone_r[~red])
    else:  # a sphere light is also reached by BSDF samples, which the square still blocks (as in Cycles)
        assert (got.color[~red][:, 0] >= shadowed[~red][:, 0]).all()
        np.testing.assert_allclose(got.color[~red].mean(), alone_r[~red].mean(), rtol=0.05)
    assert got.stats["features"]["lights_without_shadow"]


def test_default_visibility_builds_no_extra_structure():
    assert not render(_scene({}), SETTINGS).stats["features"]["ray_visibility"]
