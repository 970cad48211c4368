"""Light linking, shadow linking and a light's ray visibility in the core renderer (core.light_linking,
core.light_visibility): direct light only (max_bounces 0, so light sampling and the BSDF hits of lights, MIS
between them, and nothing else), where a linked scene must equal, bit for bit, the scene it reduces to (the same
random numbers: a receiver class's light selection is the selection of its linked emitters alone)."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.render import render as render_rgba
from monte.core.scene import AreaLight, Camera, Lobe, Material, Mesh, PointLight, Scene, SceneError, World
from monte.core.settings import RenderSettings

SETTINGS = RenderSettings(spp=8, max_bounces=0, seed=2, threads=1)
W = 24


def render(scene: Scene, settings: RenderSettings):
    """core.render.render with the colour as RGB (alpha is 1 here)."""
    result = render_rgba(scene, settings)
    result.color = result.color[..., :3]
    return result


def _quad(name: str, half: float, z: float, material: int, x: float = 0.0, **fields) -> Mesh:
    v = np.array([[x - half, -half, z], [x + half, -half, z], [x + half, half, z], [x - half, half, z]], np.float64)
    return Mesh(name, v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material_index=material, **fields)


MATERIALS = [Material("grey", [Lobe("diffuse", np.full(3, 0.5))]),
             Material("glow", [Lobe("diffuse", np.zeros(3))], emission=np.full(3, 4.0)),
             Material("mirrorish", [Lobe("glossy", np.full(3, 0.8), roughness=0.3)]),
             Material("red", [Lobe("diffuse", (0.9, 0.1, 0.1))])]


def _camera() -> Camera:
    cam = Camera(np.eye(4), resolution=(W, W), lens=20.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    cam.matrix_world[:3, 3] = (0.0, 0.0, 3.0)
    return cam


def _area(name: str, x: float, **fields) -> AreaLight:
    m = np.eye(4)
    m[:3, 3] = (x, 0.0, 0.2)
    return AreaLight(name, m, np.full(3, 60.0), size_x=0.6, size_y=0.6, **fields)


def _two_floors(left: dict, right: dict, lights: list, lamp: dict | None = None) -> Scene:
    """A left and a right floor (x < 0, x > 0) at z = -1, lit by `lights` and (lamp given) an emissive quad."""
    meshes = [_quad("left", 1.2, -1.0, 0, x=-1.25, **left), _quad("right", 1.2, -1.0, 0, x=1.25, **right)]
    if lamp is not None:
        meshes.append(_quad("lamp", 0.25, 0.0, 1, x=1.25, **lamp))
    return Scene(camera=_camera(), meshes=meshes, materials=MATERIALS, lights=lights, world=World(np.zeros(3)))


def _halves(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return img[:, : W // 2 - 1], img[:, W // 2 + 1:]


@pytest.mark.parametrize("estimator", ["mis", "bsdf", "light"])
def test_each_floor_is_lit_by_its_linked_light_alone(estimator):
    """Light a lights set 1 (the left floor), light b set 2 (the right floor): each half equals the scene with its
    light alone, with MIS, BSDF sampling alone and light sampling alone; the unlinked scene (control) differs on
    both halves."""
    settings = RenderSettings(spp=8, max_bounces=0, seed=2, threads=1, light_sampling=estimator)
    linked = render(_two_floors(dict(light_sets=0b011), dict(light_sets=0b101),
                                [_area("a", -1.25, receiver_set=1), _area("b", 1.25, receiver_set=2)]), settings)
    only_a = render(_two_floors({}, {}, [_area("a", -1.25)]), settings).color
    only_b = render(_two_floors({}, {}, [_area("b", 1.25)]), settings).color
    both = render(_two_floors({}, {}, [_area("a", -1.25), _area("b", 1.25)]), settings).color
    assert linked.stats["features"]["light_linking"] == 2
    left, right = _halves(linked.color)
    np.testing.assert_array_equal(left, _halves(only_a)[0])
    np.testing.assert_array_equal(right, _halves(only_b)[1])
    assert not np.array_equal(_halves(both)[0], left)
    if estimator != "bsdf":  # (BSDF rays from the right floor find light a too rarely at 8 spp)
        assert not np.array_equal(_halves(both)[1], right)
        assert _halves(both)[0].mean() > 1.02 * left.mean()  # b's light on the left floor, gone when linked


def test_an_emissive_mesh_lights_only_its_receivers():
    """An emissive quad over the right floor lighting set 1 (the right floor only): the left floor is black, the
    right one as with the quad unlinked."""
    linked = render(_two_floors(dict(light_sets=0b001), dict(light_sets=0b011), [], lamp=dict(receiver_set=1)),
                    SETTINGS)
    plain = render(_two_floors({}, {}, [], lamp={}), SETTINGS).color
    left, right = _halves(linked.color)
    assert _halves(plain)[0].mean() > 1e-4  # the control: unlinked, the quad lights the left floor
    assert left.max() == 0.0
    # pixels that see the quad itself (camera rays see every emitter; radiance 4), at least in part: the lit floor
    # stays at or below 1 (at 8 spp no pixel need be covered by the quad alone)
    lamp = _halves(plain)[1].max(axis=-1) > 1.5  # from the unlinked render: a linking bug cannot hide its pixels
    assert lamp.any()
    np.testing.assert_array_equal(right[~lamp], _halves(plain)[1][~lamp])


def _square_scene(square: dict, radius: float, **light) -> Scene:
    meshes = [_quad("floor", 3.0, -1.0, 0), _quad("square", 0.4, 0.5, 3, **square)]
    lamp = PointLight("lamp", np.array([1.2, 0.0, 2.0]), np.full(3, 200.0), radius=radius, **light)
    return Scene(camera=_camera(), meshes=meshes, materials=MATERIALS, lights=[lamp], world=World(np.zeros(3)))


@pytest.mark.parametrize("radius", [0.0, 0.3])
def test_a_blocker_collection_without_the_square_lets_its_light_through(radius):
    """Shadow linking: the lamp's blockers (set 1) hold the floor but not the square, so the floor is lit as with
    the square hidden from shadow rays (a point light: bit for bit; a sphere light, counted by light sampling
    alone, within its noise) while the square is still seen; unlinked (control) the square's shadow is there."""
    got = render(_square_scene(dict(shadow_sets=-1 & ~0b10), radius, blocker_set=1), SETTINGS)
    free = render(_square_scene(dict(visible_shadow=False), radius), SETTINGS).color
    shadowed = render(_square_scene({}, radius), SETTINGS).color
    assert got.stats["features"]["shadow_linking"] == 1
    red = got.color[..., 0] != got.color[..., 1]
    assert red.mean() > 0.02
    if radius == 0:
        np.testing.assert_array_equal(got.color[~red], free[~red])
    else:
        np.testing.assert_allclose(got.color[~red].mean(), free[~red].mean(), rtol=0.03)
    assert (shadowed[~red][:, 0] < 0.5 * got.color[~red][:, 0]).mean() > 0.02  # the square's shadow


def test_a_blocker_collection_with_the_square_keeps_its_shadow():
    got = render(_square_scene({}, 0.0, blocker_set=1), SETTINGS).color  # every object is in set 1 by default
    np.testing.assert_array_equal(got, render(_square_scene({}, 0.0), SETTINGS).color)


def _under_a_glowing_quad(square: dict, **lamp) -> Scene:
    """The floor and the hovering square of _square_scene lit by an emissive quad (facing both ways) instead."""
    meshes = [_quad("floor", 3.0, -1.0, 0), _quad("square", 0.4, 0.5, 3, **square),
              _quad("lamp", 0.4, 1.5, 1, x=0.6, **lamp)]
    return Scene(camera=_camera(), meshes=meshes, materials=MATERIALS, lights=[], world=World(np.zeros(3)))


def test_an_emissive_mesh_with_a_blocker_collection_without_the_square_lights_through_it():
    """Shadow linking of an emissive mesh: its blockers (set 1) leave the square out, so the floor is lit as with
    the square hidden from shadow rays (light sampling alone counts it: equal within the noise, 2 % over the floor and 5 % in the shadow at 32
    spp);
    unlinked (control) the square's shadow is there; a blocker set holding the square keeps it (within the noise)."""
    settings = SETTINGS.replace(spp=32)
    got = render(_under_a_glowing_quad(dict(shadow_sets=-1 & ~0b10), blocker_set=1), settings)
    free = render(_under_a_glowing_quad(dict(visible_shadow=False)), settings).color
    shadowed = render(_under_a_glowing_quad({}), settings).color
    assert got.stats["features"]["shadow_linking"] == 1
    floor = (got.color[..., 0] == got.color[..., 1]) & (got.color.max(axis=-1) < 3.9)  # grey: not square, lamp
    shadow = floor & (shadowed[..., 0] < 0.5 * free[..., 0])  # the square's shadow (control: it is there)
    assert floor.mean() > 0.5 and shadow.mean() > 0.02
    np.testing.assert_allclose(got.color[floor].mean(), free[floor].mean(), rtol=0.02)
    np.testing.assert_allclose(got.color[shadow].mean(), free[shadow].mean(), rtol=0.05)
    kept = render(_under_a_glowing_quad({}, blocker_set=1), settings).color  # every object is in set 1
    np.testing.assert_allclose(kept[shadow].mean(), shadowed[shadow].mean(), rtol=0.05, atol=1e-3)


def _behind_a_clear_card(**light) -> Scene:
    """The floor seen through a clear card (a Transparent BSDF above the lamp, so only camera rays cross it) with
    two stacked clear squares between the floor and the point lamp."""
    clear = Material("clear", [Lobe("refraction", np.full(3, 0.8), roughness=0.0, ior=1.0)])
    meshes = [_quad("floor", 3.0, -1.0, 0, shadow_sets=-1 & ~0b10), _quad("square", 0.4, 0.5, 4),
              _quad("square2", 0.4, 0.8, 4), _quad("card", 3.0, 2.5, 4)]
    lamp = PointLight("lamp", np.array([1.2, 0.0, 2.0]), np.full(3, 200.0), **light)
    return Scene(camera=_camera(), meshes=meshes, materials=MATERIALS + [clear], lights=[lamp],
                 world=World(np.zeros(3)))


def test_shadow_linked_rays_pass_only_the_transparent_bounces_left():
    """Transparent Bounces 2, one spent by the camera ray on the card: a shadow ray may pass one more clear
    surface, not the two squares, so they shadow the floor; with a blocker collection holding the squares (the
    floor left out) the lamp's shadow rays, recast against its blockers, keep that limit and the image is the
    unlinked one, bit for bit. Control: with Transparent Bounces 3 the squares let light through."""
    settings = SETTINGS.replace(transparent_max_bounces=2)
    linked = render(_behind_a_clear_card(blocker_set=1), settings)
    unlinked = render(_behind_a_clear_card(), settings).color
    assert linked.stats["features"]["shadow_linking"] == 1
    np.testing.assert_array_equal(linked.color, unlinked)
    passing = render(_behind_a_clear_card(), SETTINGS.replace(transparent_max_bounces=3)).color
    assert (unlinked[..., 0] < 0.5 * passing[..., 0]).mean() > 0.02  # the squares' shadow at the limit


def _lit_floor(material: int, **light) -> Scene:
    return Scene(camera=_camera(), meshes=[_quad("floor", 3.0, -1.0, material)], materials=MATERIALS,
                 lights=[_area("lamp", 0.0, **light)], world=World(np.zeros(3)))


@pytest.mark.parametrize("flag, material, dark", [("visible_diffuse", 0, True), ("visible_glossy", 2, True),
                                                  ("visible_glossy", 0, False), ("visible_diffuse", 2, False),
                                                  ("visible_transmission", 0, False)])
def test_a_light_hidden_from_a_ray_kind_lights_only_the_other_lobes(flag, material, dark):
    """Diffuse (Glossy) off: a diffuse (glossy) floor gets nothing from the light, by light sampling or by BSDF
    rays; the other kind of floor is lit exactly as before (control: the default render is lit)."""
    got = render(_lit_floor(material, **{flag: False}), SETTINGS)
    plain = render(_lit_floor(material), SETTINGS).color
    assert got.stats["features"]["light_ray_visibility"]
    assert plain.mean() > 0.01
    if dark:
        assert got.color.max() == 0.0
    else:
        np.testing.assert_array_equal(got.color, plain)


def test_default_scene_builds_no_linking():
    stats = render(_lit_floor(0), SETTINGS).stats["features"]
    assert stats["light_linking"] == 0 and stats["shadow_linking"] == 0 and not stats["light_ray_visibility"]


@pytest.mark.parametrize("field, value, message", [
    ("receiver_set", 64, "AreaLight 'lamp': receiver_set 64 must be an integer light set in [0, 63]"),
    ("blocker_set", -1, "AreaLight 'lamp': blocker_set -1 must be an integer light set in [0, 63]"),
])
def test_bad_light_sets_are_named(field, value, message):
    with pytest.raises(SceneError, match=message.replace("[", r"\[").replace("]", r"\]")):
        render(_lit_floor(0, **{field: value}), SETTINGS)


def test_a_bad_membership_mask_is_named():
    scene = _lit_floor(0)
    scene.meshes[0].light_sets = 2.5
    with pytest.raises(SceneError, match=r"mesh 'floor': light_sets 2.5 must be an integer bitmask of light sets \(-1: all\)"):
        render(scene, SETTINGS)


def test_light_passes_keep_a_hidden_lights_direct_light_out_of_its_kind():
    """A diffuse + glossy floor under a light with Glossy off, light sampling alone: Glossy Direct is black,
    Diffuse Direct holds the direct light (control: with Glossy on, Glossy Direct is lit). (With MIS, a BSDF ray
    that the diffuse lobe sent still carries the glossy lobe's share of its value into Glossy Direct, as in
    Cycles.)"""
    mixed = Material("mix", [Lobe("diffuse", np.full(3, 0.4)), Lobe("glossy", np.full(3, 0.4), roughness=0.3)])
    names = ("Diffuse Direct", "Glossy Direct")
    settings = RenderSettings(spp=8, max_bounces=0, seed=2, threads=1, light_passes=names, light_sampling="light")

    def floor(**flags) -> Scene:
        scene = _lit_floor(0, **flags)
        scene.materials = [mixed]
        return scene

    hidden = render_rgba(floor(visible_glossy=False), settings).light_passes
    shown = render_rgba(floor(), settings).light_passes
    assert shown["Glossy Direct"].max() > 0.01
    assert hidden["Glossy Direct"].max() == 0.0
    assert hidden["Diffuse Direct"].max() > 0.01
