"""A camera ray that goes on through Transparent BSDFs stays a camera ray, as in Cycles (its transparent bounces
keep the ray's visibility flags): it sees only the lights visible to the camera and the world's camera backdrop
(Light Path > Is Camera Ray), not what bounce rays see.

Scenes: a camera looking down at an area light that faces it, under a Transparent BSDF card of colour c that
fills the view; black world. Every render uses the same random numbers, so the image through the card is
exactly c times the image without it (float rounding)."""

from __future__ import annotations

import numpy as np

from monte.core.render import render
from monte.core.scene import AreaLight, Camera, Lobe, Material, Mesh, Scene, World
from monte.core.settings import RenderSettings

SETTINGS = RenderSettings(spp=4, max_bounces=2, seed=5, threads=1)
CARD = np.array([0.5, 0.25, 1.0])


def _scene(card: bool, lamp_seen_by_camera: bool, world: World | None = None, lamp: bool = True) -> Scene:
    cam = Camera(np.eye(4), resolution=(24, 24), lens=20.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    cam.matrix_world[:3, 3] = (0.0, 0.0, 3.0)
    face_up = np.diag([1.0, -1.0, -1.0, 1.0])  # turned about X: the light emits along +Z, towards the camera
    face_up[:3, 3] = (0.0, 0.0, -0.5)
    lights = [AreaLight("lamp", face_up, np.full(3, 50.0), size_x=1.0, size_y=1.0,
                        visible_camera=lamp_seen_by_camera)] if lamp else []
    materials = [Material("card", [Lobe("refraction", CARD, roughness=0.0, ior=1.0)])]
    meshes = []
    if card:
        v = np.array([[-8, -8, 0.5], [8, -8, 0.5], [8, 8, 0.5], [-8, 8, 0.5]], np.float64)
        meshes.append(Mesh("card", v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material_index=0))
    return Scene(camera=cam, meshes=meshes, materials=materials, lights=lights,
                 world=world if world is not None else World(np.zeros(3)))


def _image(scene: Scene) -> np.ndarray:
    return render(scene, SETTINGS).color[..., :3]


def test_a_light_hidden_from_the_camera_stays_hidden_through_a_transparent_card():
    seen = _image(_scene(card=False, lamp_seen_by_camera=True))
    assert (seen > 1.0).mean() > 0.02  # the lamp covers some pixels
    assert _image(_scene(card=False, lamp_seen_by_camera=False)).max() == 0.0
    # through the card (before: a ray past a Transparent BSDF counted as a bounce ray, which sees every light)
    assert _image(_scene(card=True, lamp_seen_by_camera=False)).max() == 0.0
    # control: a light visible to the camera is seen through the card, times its colour
    np.testing.assert_allclose(_image(_scene(card=True, lamp_seen_by_camera=True)), seen * CARD, rtol=1e-5,
                               atol=1e-7)


def test_the_camera_backdrop_is_seen_through_a_transparent_card():
    """A world whose camera rays see a backdrop (camera_color) other than its light (color): through the card,
    the backdrop times the card's colour (before: the light's colour)."""
    world = World(np.full(3, 0.2), camera_color=np.array([1.0, 0.5, 0.25]))
    got = _image(_scene(card=True, lamp_seen_by_camera=False, world=world, lamp=False))
    np.testing.assert_allclose(got, np.broadcast_to(world.camera_color * CARD, got.shape), rtol=1e-5)
