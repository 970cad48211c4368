"""Shadow catcher (core.scene.Mesh.shadow_catcher) in the core renderer against closed forms.

A catcher plane fills the frame, a black square hidden from the camera hangs between it and a sun that shines
straight down the view, so its shadow is a sharp square in the middle of the image; the world is black. With
nothing but the sun and black surfaces there is no indirect light: in the umbra the catcher receives nothing,
elsewhere exactly what it receives without the square. So the Shadow Catcher pass is 0 in the umbra and 1
elsewhere, and Cycles' approximate catcher on a transparent film gives Combined black with alpha 1 in the umbra
and alpha 0 elsewhere (the catcher itself gone). With the Shadow Catcher pass asked for, Combined is the matte:
the catcher transparent everywhere. On an opaque film with a lit world and nothing shadowing, the catcher
vanishes into the world behind it. A scene without catcher keeps none of the catcher's sums.
"""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.render import render
from monte.core.scene import AreaLight, Camera, Film, Lobe, Material, Mesh, Scene, SunLight, World
from monte.core.settings import RenderSettings

RES = (24, 24)
SETTINGS = RenderSettings(spp=16, max_bounces=3, seed=5, filter_type="box", filter_width=1.0, threads=1)
# The camera at the origin looks down -z and sees +-0.5 at distance 1 (24 pixels); the shadow of the square of
# half-size 0.2 covers pixels 8..15: rows and columns 9..14 are deep inside, 0..4 and 19..23 far outside.
UMBRA = (slice(9, 15), slice(9, 15))
LIT = np.ones(RES[::-1], bool)
LIT[5:19, 5:19] = False


def _square(name: str, half: float, z: float, material: int) -> Mesh:
    quad = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float64)
    return Mesh(name, quad, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material_index=material)


def _scene(film: Film, occluder: bool = True, world: float = 0.0, catcher: bool = True) -> Scene:
    cam = Camera(np.eye(4), resolution=RES, lens=36.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    materials = [Material("ground", [Lobe("diffuse", np.full(3, 0.5))]),
                 Material("black", [Lobe("diffuse", np.zeros(3))])]
    plane = _square("catcher", 2.0, -1.0, 0)
    plane.shadow_catcher = catcher
    meshes = [plane]
    if occluder:
        square = _square("occluder", 0.2, -0.5, 1)
        square.visible_camera = False
        meshes.append(square)
    sun = SunLight("sun", np.array([0.0, 0.0, -1.0]), np.full(3, 3.0), angle=0.0)
    return Scene(camera=cam, meshes=meshes, materials=materials, lights=[sun],
                 world=World(color=np.full(3, world)), film=film)


def test_shadow_catcher_pass_is_the_shadow():
    result = render(_scene(Film(transparent=True)), SETTINGS)
    shadow = result.shadow_catcher
    assert shadow.shape == (RES[1], RES[0], 3)
    np.testing.assert_array_equal(shadow[UMBRA], 0.0)
    np.testing.assert_allclose(shadow[LIT], 1.0, atol=1e-5)
    assert result.stats["features"]["shadow_catcher"]


def test_approximate_catcher_on_transparent_film_puts_the_shadow_in_alpha():
    result = render(_scene(Film(transparent=True)), SETTINGS)
    rgba = result.color
    np.testing.assert_array_equal(rgba[..., :3], 0.0)  # the catcher adds no colour, the world is transparent
    np.testing.assert_allclose(rgba[UMBRA][..., 3], 1.0, atol=1e-6)
    np.testing.assert_allclose(rgba[LIT][..., 3], 0.0, atol=1e-5)
    # The matte (Cycles' Shadow Catcher Matte) is the catcher cut out: transparent everywhere.
    np.testing.assert_array_equal(result.shadow_catcher_matte[..., 3], 0.0)


def test_with_the_shadow_catcher_pass_combined_is_the_matte():
    result = render(_scene(Film(transparent=True, shadow_catcher_pass=True)), SETTINGS)
    np.testing.assert_array_equal(result.color, 0.0)  # black and transparent: the shadow is only in the pass
    np.testing.assert_array_equal(result.shadow_catcher[UMBRA], 0.0)
    np.testing.assert_allclose(result.shadow_catcher[LIT], 1.0, atol=1e-5)


def test_opaque_film_shows_the_world_through_an_unshadowed_catcher():
    world = 0.7
    result = render(_scene(Film(), occluder=False, world=world), SETTINGS)
    np.testing.assert_allclose(result.color[..., :3], world, rtol=1e-5)
    np.testing.assert_array_equal(result.color[..., 3], 1.0)
    np.testing.assert_allclose(result.shadow_catcher, 1.0, atol=1e-5)


def test_opaque_film_darkens_the_world_by_the_shadow():
    # A lit world adds indirect light to the catcher, so the umbra's shadow is not 0: the approximate catcher
    # lays the world under it scaled by the shadow's mean, Combined = world x mean(shadow).
    world = 0.7
    result = render(_scene(Film(), world=world), SETTINGS)
    expected = world * np.clip(result.shadow_catcher.mean(axis=2), 0, 1)
    np.testing.assert_allclose(result.color[..., 0], expected, rtol=1e-4, atol=1e-6)
    assert result.shadow_catcher[UMBRA].max() < 0.5 < result.shadow_catcher[LIT].min()


def test_no_catcher_costs_nothing():
    result = render(_scene(Film(transparent=True), catcher=False), SETTINGS)
    assert result.shadow_catcher is None and result.shadow_catcher_matte is None
    assert not result.stats["features"]["shadow_catcher"]
    # The plane is an ordinary object again: lit by the sun outside the shadow (0.5 x 3 / pi), opaque.
    np.testing.assert_allclose(result.color[LIT][..., :3], 0.5 * 3.0 / np.pi, rtol=1e-4)
    np.testing.assert_array_equal(result.color[..., 3], 1.0)


@pytest.mark.parametrize("transparent", [True, False])
def test_objects_in_front_of_the_catcher_stay_in_combined(transparent):
    # The square seen by the camera covers the umbra: there Combined is the square itself, opaque, as without
    # a catcher.
    with_catcher = _scene(Film(transparent=transparent))
    with_catcher.meshes[1].visible_camera = True
    plain = _scene(Film(transparent=transparent), catcher=False)
    plain.meshes[1].visible_camera = True
    a, b = render(with_catcher, SETTINGS), render(plain, SETTINGS)
    np.testing.assert_allclose(a.color[UMBRA], b.color[UMBRA], atol=1e-6)


def test_memory_estimate_and_exr_carry_the_catcher(tmp_path):
    from monte.core import exr
    from monte.core.film import CatcherOutput, TileFilm
    from monte.core.memory import FILM_CATCHER_BYTES, estimate_render_memory

    scene, plain = _scene(Film(transparent=True)), _scene(Film(transparent=True), catcher=False)
    pixels = RES[0] * RES[1]
    assert (estimate_render_memory(scene, SETTINGS).film - estimate_render_memory(plain, SETTINGS).film
            == pixels * FILM_CATCHER_BYTES)
    with_catcher = TileFilm(RES[0], RES[1], False, alpha=True, catcher=CatcherOutput.of(scene))
    assert with_catcher.nbytes - TileFilm(RES[0], RES[1], False, alpha=True).nbytes == pixels * FILM_CATCHER_BYTES
    result = render(scene, SETTINGS)
    path = exr.write_exr(tmp_path / "c.exr", exr.image_channels(result.color, result.variance,
                                                               shadow_catcher=result.shadow_catcher))
    back = exr.read_exr(path)
    np.testing.assert_array_equal(back["shadow_catcher.G"], result.shadow_catcher[..., 1])


def test_split_render_merges_to_the_same_catcher_images():
    from monte.core.render import merge_tile_samples, render_samples
    from monte.core.schedule import tiles

    scene = _scene(Film(transparent=True))
    settings = SETTINGS.replace(tile_size=12)
    whole = render(scene, settings)
    n_tiles = len(tiles(0, 0, RES[0], RES[1], settings.tile_size))
    parts = render_samples(scene, settings, {ti: (0, settings.spp) for ti in range(n_tiles)})
    merged = merge_tile_samples(scene, settings, parts)
    np.testing.assert_array_equal(merged.color, whole.color)
    np.testing.assert_array_equal(merged.shadow_catcher, whole.shadow_catcher)


def test_catcher_seen_through_a_transparent_bsdf_still_splits():
    # A Transparent BSDF sheet (white, IOR 1) in front of everything: paths through it still count as
    # transparent, so they split at the catcher behind it and the closed forms hold unchanged.
    scene = _scene(Film(transparent=True))
    scene.materials.append(Material("clear", [Lobe("refraction", np.ones(3), roughness=0.0, ior=1.0)]))
    sheet = _square("sheet", 1.0, -0.3, 2)
    sheet.visible_shadow = False  # light passes it (the sun's shadow rays would otherwise stop at the sheet)
    scene.meshes.append(sheet)
    result = render(scene, SETTINGS)
    np.testing.assert_allclose(result.color[UMBRA][..., 3], 1.0, atol=1e-6)
    np.testing.assert_allclose(result.color[LIT][..., 3], 0.0, atol=1e-5)
    np.testing.assert_array_equal(result.shadow_catcher[UMBRA], 0.0)


def test_catcher_copies_keep_the_transparent_bounces_apart():
    # Max Bounces 0 behind the Transparent BSDF sheet: the pass through the sheet is a transparent bounce, not a
    # bounce, so the catcher behind it gets its direct light, in the path and in its shadow-free copy alike
    # (a copy counting the sheet as a bounce would end there unlit: the umbra's pass would read 1, alpha 0).
    scene = _scene(Film(transparent=True))
    scene.materials.append(Material("clear", [Lobe("refraction", np.ones(3), roughness=0.0, ior=1.0)]))
    sheet = _square("sheet", 1.0, -0.3, 2)
    sheet.visible_shadow = False
    scene.meshes.append(sheet)
    result = render(scene, SETTINGS.replace(max_bounces=0))
    np.testing.assert_array_equal(result.shadow_catcher[UMBRA], 0.0)
    np.testing.assert_allclose(result.shadow_catcher[LIT], 1.0, atol=1e-5)
    np.testing.assert_allclose(result.color[UMBRA][..., 3], 1.0, atol=1e-6)
    np.testing.assert_allclose(result.color[LIT][..., 3], 0.0, atol=1e-5)


def test_catcher_copies_honour_a_lights_ray_visibility():
    # An area light hidden from diffuse rays over the diffuse catcher (no sun): the catcher gets nothing from it,
    # by light sampling or by BSDF rays, in the path and in its copy, so there is no shadow to catch: the pass is
    # 1 and the film transparent everywhere. A copy whose BSDF rays saw the light would read a shadow (pass 0,
    # alpha > 0) wherever one found it. Control: with the light visible, the square's shadow is in the pass.
    def scene(hidden: bool) -> Scene:
        sc = _scene(Film(transparent=True))
        m = np.eye(4)
        m[:3, 3] = (0.0, 0.0, -0.2)  # above the square (unseen by the camera, as the square)
        sc.lights = [AreaLight("lamp", m, np.full(3, 5.0), size_x=0.3, size_y=0.3, visible_diffuse=not hidden)]
        return sc

    result = render(scene(True), SETTINGS)
    assert result.stats["features"]["light_ray_visibility"]
    np.testing.assert_array_equal(result.shadow_catcher, 1.0)
    np.testing.assert_array_equal(result.color, 0.0)
    lit = render(scene(False), SETTINGS)
    assert lit.shadow_catcher[UMBRA].mean() < 0.5


def _mirror_scene(catcher: bool) -> Scene:
    """The camera sees a mirror filling the frame (z = -1) that reflects a catcher plane behind the camera
    (z = +1, facing the mirror) lit from below by the sun; the mirror lets the light through."""
    cam = Camera(np.eye(4), resolution=RES, lens=36.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    materials = [Material("ground", [Lobe("diffuse", np.full(3, 0.5))]),
                 Material("mirror", [Lobe("glossy", np.full(3, 0.9), roughness=0.0)])]
    mirror = _square("mirror", 2.0, -1.0, 1)
    mirror.visible_shadow = False
    plane = _square("catcher", 4.0, 1.0, 0)
    plane.triangles = plane.triangles[:, ::-1].copy()  # facing -z, towards the mirror
    plane.shadow_catcher = catcher
    sun = SunLight("sun", np.array([0.0, 0.0, 1.0]), np.full(3, 3.0), angle=0.0)
    return Scene(camera=cam, meshes=[mirror, plane], materials=materials, lights=[sun],
                 world=World(color=np.zeros(3)), film=Film(transparent=True))


def test_catcher_seen_in_a_mirror_is_an_ordinary_object():
    # Cycles splits only paths that still count as transparent: a reflection shows the catcher as it is.
    with_catcher, plain = render(_mirror_scene(True), SETTINGS), render(_mirror_scene(False), SETTINGS)
    # at least the sun's light on the plane seen in the mirror (and more: the mirror sends it back to the plane)
    assert (plain.color[..., :3] >= 0.9 * 0.5 * 3.0 / np.pi * (1 - 1e-4)).all()
    np.testing.assert_array_equal(plain.color[..., 3], 1.0)
    np.testing.assert_array_equal(with_catcher.color, plain.color)
    np.testing.assert_array_equal(with_catcher.shadow_catcher, 1.0)
