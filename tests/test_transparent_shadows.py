"""Shadow rays through transparent surfaces in the core renderer (core.transparent_shadow): sheets with a
Transparent BSDF lobe (a "refraction" lobe of IOR 1, roughness 0) between a point light and a grey floor, hidden
from camera rays so that each pixel is the floor's direct light only (max_bounces 0). Every render uses the same
random numbers, so the floor under a sheet of transparency c is exactly c times the floor rendered alone (float
rounding), and its shadow is black where the light is blocked."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.render import render
from monte.core.scene import Camera, Lobe, Material, Mesh, PointLight, Scene, World
from monte.core.settings import RenderSettings

SETTINGS = RenderSettings(spp=4, max_bounces=0, seed=3, threads=1)  # direct light only


def _quad(name: str, half: float, z: float, material: int, **flags) -> Mesh:
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float64)
    return Mesh(name, v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material_index=material, **flags)


def _scene(sheet: list[Lobe] | None, layers: int = 1, world: float = 0.0, light: bool = True,
           half: float = 8.0) -> Scene:
    cam = Camera(np.eye(4), resolution=(24, 24), lens=20.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    cam.matrix_world[:3, 3] = (0.0, 0.0, 3.0)
    meshes = [_quad("floor", 6.0, -1.0, 0)]
    mats = [Material("grey", [Lobe("diffuse", np.full(3, 0.5))])]
    if sheet is not None:
        mats.append(Material("sheet", sheet))
        meshes += [_quad(f"sheet{i}", half, 0.5 + 0.2 * i, 1, visible_camera=False) for i in range(layers)]
    lights = [PointLight("lamp", np.array([0.0, 0.0, 2.0]), np.full(3, 200.0))] if light else []
    return Scene(camera=cam, meshes=meshes, materials=mats, lights=lights, world=World(np.full(3, world)))


def _clear(color) -> Lobe:
    return Lobe("refraction", np.asarray(color, np.float64), roughness=0.0, ior=1.0)


@pytest.fixture(scope="module")
def alone() -> np.ndarray:
    img = render(_scene(None), SETTINGS).color[..., :3]
    assert img.min() > 0.01  # the whole floor is lit
    return img


def test_a_transparent_sheet_passes_its_colour(alone):
    got = render(_scene([_clear((0.5, 0.25, 1.0))]), SETTINGS)
    np.testing.assert_allclose(got.color[..., :3], alone * np.array([0.5, 0.25, 1.0]), rtol=1e-5, atol=1e-7)
    assert got.stats["features"]["transparent_shadows"]


def test_a_mix_of_transparent_and_diffuse_passes_the_transparent_weight(alone):
    """A Mix Shader of factor 0.3 (Transparent 0.3, Diffuse 0.7) lets 0.3 through, as Cycles' shadow rays."""
    got = render(_scene([Lobe("diffuse", np.full(3, 0.7 * 0.8)), _clear(np.full(3, 0.3))]), SETTINGS)
    np.testing.assert_allclose(got.color[..., :3], 0.3 * alone, rtol=1e-5, atol=1e-7)


def test_layers_multiply_up_to_the_transparent_bounce_limit(alone):
    three = render(_scene([_clear(np.full(3, 0.5))], layers=3), SETTINGS).color[..., :3]
    np.testing.assert_allclose(three, 0.125 * alone, rtol=1e-5, atol=1e-7)
    limited = SETTINGS.replace(transparent_max_bounces=2)  # the third sheet blocks, as in Cycles
    assert render(_scene([_clear(np.full(3, 0.5))], layers=3), limited).color[..., :3].max() == 0.0
    exact = SETTINGS.replace(transparent_max_bounces=3)
    np.testing.assert_allclose(render(_scene([_clear(np.full(3, 0.5))], layers=3), exact).color[..., :3],
                               three, rtol=1e-6)


def test_opaque_and_refracting_sheets_still_block():
    """The old behaviour stays for everything but the Transparent BSDF: a diffuse sheet and a Refraction BSDF
    of IOR 1.45 cast black shadows (no caustics reach the floor with max_bounces 0), and a scene without a
    transparent material keeps the plain occlusion query."""
    for lobes in ([Lobe("diffuse", np.full(3, 0.8))], [Lobe("refraction", np.ones(3), roughness=0.0, ior=1.45)]):
        got = render(_scene(lobes), SETTINGS)
        assert got.color[..., :3].max() == 0.0
        assert not got.stats["features"]["transparent_shadows"]


def test_the_world_is_seen_through_the_sheet():
    """Shadow rays towards a uniform world (no lamp): the floor's direct world light through a sheet of
    transparency 0.4 is 0.4 of the floor's under the open sky (same light samples)."""
    # Light samples only (a uniform world is light-sampled by this estimator alone); the sheet reaches far
    # enough that every sample towards the sky crosses it
    light_only = SETTINGS.replace(spp=16, light_sampling="light")
    a = render(_scene(None, world=1.0, light=False), light_only).color[..., :3]
    b = render(_scene([_clear(np.full(3, 0.4))], world=1.0, light=False, half=1e4), light_only).color[..., :3]
    assert a.min() > 0.1
    np.testing.assert_allclose(b, 0.4 * a, rtol=1e-5, atol=1e-7)


def test_mis_through_the_sheet_is_unbiased():
    """An area light behind a sheet of transparency 0.5: light sampling alone (shadow rays through the sheet),
    BSDF sampling alone (paths through the sheet) and their MIS combination (BSDF rays through the sheet weighted
    from the floor, as Cycles) agree on the floor's mean within their noise (max_bounces 2: the floor, the
    sheet, the light). Counting the light both ways would add up to the light-sampled share (tens of %)."""
    from monte.core.scene import AreaLight

    def scene():
        sc = _scene([_clear(np.full(3, 0.5))], light=False)
        m = np.eye(4)
        m[:3, 3] = (0.0, 0.0, 2.0)
        sc.lights.append(AreaLight("panel", m, np.full(3, 400.0), size_x=2.0))
        return sc

    base = SETTINGS.replace(spp=256, max_bounces=2)
    means = {kind: float(render(scene(), base.replace(light_sampling=kind)).color[..., :3].mean())
             for kind in ("mis", "light", "bsdf")}
    assert means["light"] > 0.05
    assert means["mis"] == pytest.approx(means["light"], rel=0.02), means
    assert means["mis"] == pytest.approx(means["bsdf"], rel=0.03), means


@pytest.mark.parametrize("field, value, message", [
    ("transparent_max_bounces", -1, "transparent max bounces must be >= 0, got -1"),
    ("transparent_max_bounces", 2.5, "transparent max bounces must be a whole number, got 2.5"),
    ("transparent_min_bounces", -1, "transparent min bounces must be >= 0, got -1"),
    ("transparent_min_bounces", 2.5, "transparent min bounces must be a whole number, got 2.5")])
def test_bad_transparent_bounce_limits_are_named(field, value, message):
    with pytest.raises(ValueError, match=message.replace(".", r"\.")):
        SETTINGS.replace(**{field: value}).validate()


def test_a_sheet_hidden_from_shadow_rays_is_skipped(alone):
    """An opaque sheet hidden from shadow rays (Ray Visibility > Shadow off) under the transparent one: shadow
    rays cast against the shadow-visible triangles only (their own structure, scene triangle indices mapped back)
    still see the transparent sheet's material."""
    sc = _scene([_clear(np.full(3, 0.5))])
    sc.materials.append(Material("opaque", [Lobe("diffuse", np.full(3, 0.8))]))
    sc.meshes.append(_quad("hidden", 8.0, 0.0, 2, visible_camera=False, visible_shadow=False))
    got = render(sc, SETTINGS)
    assert got.stats["features"]["ray_visibility"] == ["camera", "shadow"]
    np.testing.assert_allclose(got.color[..., :3], 0.5 * alone, rtol=1e-5, atol=1e-7)
