"""Cycles' light passes (core.light_passes): they sum to Combined, have their analytic values where there is
one, and cost nothing when not asked for (the image is bit for bit the same)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monte.core.builtin_scenes import furnace, icosphere, plane_under_world, quad
from monte.core.light_passes import LIGHT_PASSES, even_divide, recombine
from monte.core.render import render
from monte.core.scene import AreaLight, Camera, Lobe, Material, Scene, World
from monte.core.settings import RenderSettings


def every_kind_scene(resolution=(32, 32)) -> Scene:
    """Diffuse ground and wall, a diffuse, a rough glossy, a clear glass, a rough glass and a diffuse + glossy
    sphere, a rough glass pane, a square area light seen by the camera, an emissive quad, and a coloured world
    above the wall."""
    materials = [
        Material("ground", [Lobe("diffuse", np.array((0.6, 0.55, 0.5)))]),
        Material("clay", [Lobe("diffuse", np.array((0.7, 0.2, 0.1)))]),
        Material("metal", [Lobe("glossy", np.array((0.9, 0.8, 0.5)), roughness=0.3)]),
        Material("glass", [Lobe("glass", np.ones(3), roughness=0.0, ior=1.45)]),
        Material("frosted", [Lobe("glass", np.array((0.8, 0.9, 1.0)), roughness=0.3, ior=1.5)]),
        Material("plastic", [Lobe("diffuse", np.array((0.2, 0.4, 0.6))),
                             Lobe("glossy", np.full(3, 0.3), roughness=0.15)]),
        Material("panel", [Lobe("diffuse", np.zeros(3))], emission=np.array((2.0, 1.5, 1.0))),
    ]
    meshes = [
        quad("ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], 0),
        quad("wall", [(-4, 1.5, 0), (4, 1.5, 0), (4, 1.5, 2.2), (-4, 1.5, 2.2)], 0),
        icosphere("clay", (-1.2, 0.2, 0.4), 0.4, 1),
        icosphere("metal", (-0.3, 0.5, 0.4), 0.4, 2),
        icosphere("glass", (0.5, -0.3, 0.4), 0.4, 3),
        icosphere("frosted", (1.3, 0.4, 0.4), 0.4, 4),
        icosphere("plastic", (0.0, -0.8, 0.9), 0.3, 5),
        quad("panel", [(-1.6, 1.45, 1.4), (-0.8, 1.45, 1.4), (-0.8, 1.45, 1.9), (-1.6, 1.45, 1.9)], 6),
        # a frosted pane under the lamp, seen from below: light through one transmission (Transmission Direct)
        quad("pane", [(0.4, -1.0, 1.9), (0.4, 0.0, 1.9), (1.6, 0.0, 1.9), (1.6, -1.0, 1.9)], 4),
    ]
    m = np.eye(4)
    m[:3, 3] = (1.0, -0.5, 2.5)
    lights = [AreaLight("lamp", m, np.full(3, 300.0), size_x=0.8, size_y=0.8, visible_camera=True)]
    camera = Camera.look_at((0, -4.5, 1.6), (0, 0.5, 1.0), horizontal_fov=math.radians(55.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=lights,
                 world=World(np.array((0.3, 0.4, 0.6))), name="every-kind")


@pytest.mark.parametrize("clamp", [0.0, 1.0])
def test_light_passes_sum_to_combined_and_cost_nothing_when_off(clamp):
    """Cycles' relation (DiffDir + DiffInd) DiffCol + ... + Emission + Environment = Combined per pixel, on a
    scene with every kind of surface and light, also with clamped contributions; every pass holds light
    somewhere; the image is bit for bit the image rendered without light passes."""
    scene = every_kind_scene()
    settings = RenderSettings(spp=8, threads=2, clamp=clamp, light_passes=LIGHT_PASSES)
    result = render(scene, settings)
    combined = result.color[..., :3].astype(np.float64)
    rebuilt = recombine(result.light_passes).astype(np.float64)
    assert np.abs(rebuilt - combined).max() <= 1e-4 * max(1.0, combined.max())
    for name in LIGHT_PASSES:
        assert result.light_passes[name].max() > 0, f"{name} is black on a scene that has it"
    plain = render(every_kind_scene(), settings.replace(light_passes=()))
    assert plain.light_passes is None
    assert np.array_equal(plain.color, result.color)


def test_only_the_passes_asked_for_come_back():
    result = render(plane_under_world((8, 8)), RenderSettings(spp=4, threads=1,
                                                             light_passes=("Emission", "Diffuse Color")))
    assert sorted(result.light_passes) == ["Diffuse Color", "Emission"]


def test_plane_under_world_analytic():
    """A plane of albedo 0.8 seeing only a world of radiance 1: Diffuse Color 0.8, Diffuse Direct 1 (the light
    after one bounce, divided by the colour), no indirect light, no emission or environment seen directly."""
    result = render(plane_under_world((8, 8), albedo=0.8, world=1.0),
                    RenderSettings(spp=64, threads=1, light_passes=LIGHT_PASSES))
    lp = result.light_passes
    np.testing.assert_allclose(lp["Diffuse Color"], 0.8, rtol=1e-6)
    assert abs(lp["Diffuse Direct"].mean() - 1.0) < 0.01
    for name in ("Diffuse Indirect", "Glossy Direct", "Glossy Color", "Transmission Direct", "Emission",
                 "Environment"):
        assert lp[name].max() == 0.0, name


def test_furnace_analytic():
    """A closed sphere of albedo a = 0.5 and emission 1 seen from inside, max_bounces B = 3: Emission 1,
    Diffuse Color a, Diffuse Direct (a Le) / a = 1 (image mean), Diffuse Indirect (Le (a^2 + ... + a^(B+1))) / a = 0.875."""
    result = render(furnace((8, 8)), RenderSettings(spp=256, threads=1, max_bounces=3,
                                                    light_passes=LIGHT_PASSES))
    lp = result.light_passes
    np.testing.assert_allclose(lp["Emission"], 1.0, rtol=1e-6)
    np.testing.assert_allclose(lp["Diffuse Color"], 0.5, rtol=1e-6)
    assert abs(lp["Diffuse Direct"].mean() - 1.0) < 0.01  # light sampling + MIS: noisy per pixel
    # Russian roulette (from the third vertex) makes the indirect light noisy: its image mean within 2 %
    assert abs(lp["Diffuse Indirect"].mean() / 0.875 - 1) < 0.02


def test_even_divide_fills_zero_colour_channels():
    out = even_divide(np.array([[0.5, 1.0, 0.0], [0.0, 0.0, 0.0]]), np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(out, [[1.0, 2.0, 1.5], [0.0, 0.0, 0.0]])


def test_unknown_light_pass_is_refused():
    with pytest.raises(ValueError, match=r"unknown light pass\(es\) \['Shadow'\]"):
        RenderSettings(light_passes=("Emission", "Shadow")).validate()


def test_light_passes_in_the_exr_and_merged_renders_equal_one(tmp_path):
    """`monte render --light-passes` writes them as diffuse_direct.R ... environment.B; a render split into
    sample ranges and merged (core.distributed's way) has the same light passes bit for bit."""
    import subprocess
    import sys

    from monte.core import exr
    from monte.core.render import merge_tile_samples, render_samples
    from monte.core.schedule import pass_bounds, tiles

    out = tmp_path / "a.exr"
    proc = subprocess.run([sys.executable, "-m", "monte", "render", "plane-world", "-o", str(out), "--spp", "4",
                           "--resolution", "8x8", "--light-passes", "--no-png"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    channels = exr.read_exr(out)
    for name in LIGHT_PASSES:
        for c in "RGB":
            assert f"{name.lower().replace(' ', '_')}.{c}" in channels
    np.testing.assert_allclose(channels["diffuse_color.G"], 0.8, rtol=1e-6)

    scene = plane_under_world((8, 8))
    settings = RenderSettings(spp=64, threads=1, batch_paths=1024, light_passes=("Diffuse Direct", "Diffuse Color"))
    whole = render(scene, settings)
    bounds = pass_bounds(tiles(0, 0, 8, 8, settings.tile_size), settings.spp, settings)[0]
    assert len(bounds) > 2, bounds
    cut = bounds[1]
    parts = render_samples(scene, settings, {0: (0, cut)}) + render_samples(scene, settings, {0: (cut, 64)})
    merged = merge_tile_samples(scene, settings, parts)
    for name in settings.light_passes:
        assert np.array_equal(merged.light_passes[name], whole.light_passes[name]), name
