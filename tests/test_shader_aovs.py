"""Shader AOVs in the core (core.shader_aovs): exact values of the AOV Output instruction where camera paths are
primary (the camera ray's hit and the surfaces behind Transparent BSDFs, summed), nothing behind glass or where
nothing was hit, the film's means, the render unchanged by them, a split render merged equal, and the errors
for bad AOV lists. Blender and Cycles: tests/test_shader_aovs_cycles.py."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from monte.core.render import render, render_samples, merge_tile_samples
from monte.core.scene import Camera, Lobe, Material, Mesh, Scene, SceneError
from monte.core.settings import RenderSettings
from monte.core.shading import registry as R

sys.path.insert(0, str(Path(__file__).resolve().parent))
from node_programs import instruction as _inst, program as _program  # noqa: E402

SIZE = 16
SPP = 8
HALF = 2.0  # the orthographic view spans [-2, 2] in x and y


def _quad(name: str, x0: float, x1: float, z: float, material: int) -> Mesh:
    v = np.array([[x0, -3, z], [x1, -3, z], [x1, 3, z], [x0, 3, z]], float)
    return Mesh(name, v, np.array([[0, 1, 2], [0, 2, 3]]), material_index=material)


def aov_scene(aovs=(("tint", "COLOR"), ("x", "VALUE"))) -> Scene:
    """Looking down -z (orthographic, 4 m across): a floor at z = 0 whose program writes the colour
    (0.25, 0.5, 0.75) to AOV 0 and the point's x to AOV 1; over x < -1 a Transparent BSDF sheet writing
    (1, 0, 0) to AOV 0; over x > 1 a clear glass sheet writing nothing; a lamp-less grey world."""
    floor = _program([[0.25, 0.5, 0.75], [0, 0, 0]],
                     [_inst("aov_output", value=0, aov=0), _inst("geometry", position=1),
                      _inst("aov_output", value=1, aov=1)])
    sheet = _program([[1.0, 0.0, 0.0]], [_inst("aov_output", value=0, aov=0)])
    materials = [Material("floor", [Lobe("diffuse", np.full(3, 0.5))], program=floor),
                 Material("transparent", [Lobe("refraction", np.ones(3), ior=1.0)], program=sheet),
                 Material("glass", [Lobe("glass", np.ones(3), ior=1.5)])]
    meshes = [_quad("floor", -3, 3, 0.0, 0), _quad("veil", -3, -1, 1.0, 1), _quad("pane", 1, 3, 1.0, 2)]
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), resolution=(SIZE, SIZE), kind="ORTHO",
                         ortho_scale=2 * HALF)
    scene = Scene(cam, meshes, materials, shader_aovs=list(aovs))
    scene.world.color = np.full(3, 0.5)
    return scene


def settings(**kw) -> RenderSettings:
    return RenderSettings(spp=SPP, seed=3, threads=1, max_bounces=4, **kw)


@pytest.fixture(scope="module")
def result():
    return render(aov_scene(), settings())


def _columns() -> np.ndarray:
    """(SIZE,) x of each pixel column's centre."""
    return -HALF + (np.arange(SIZE) + 0.5) * (2 * HALF / SIZE)


def test_colour_aov_is_written_at_primary_surfaces_and_summed_through_transparency(result):
    tint = result.shader_aovs["tint"]
    assert tint.shape == (SIZE, SIZE, 4)
    x = _columns()
    open_floor = (np.abs(x) < 1 - 2 * HALF / SIZE)  # columns whose samples all see the bare floor
    veiled = x < -1 - 2 * HALF / SIZE  # ... all through the Transparent BSDF sheet
    glazed = x > 1 + 2 * HALF / SIZE  # ... all behind the glass
    np.testing.assert_allclose(tint[:, open_floor], np.broadcast_to([0.25, 0.5, 0.75, 1.0], tint[:, open_floor].shape),
                               rtol=0, atol=1e-6)
    # the sheet writes (1, 0, 0) and the floor seen through it writes too: alpha counts both writes
    np.testing.assert_allclose(tint[:, veiled], np.broadcast_to([1.25, 0.5, 0.75, 2.0], tint[:, veiled].shape),
                               rtol=0, atol=1e-6)
    # behind glass the path is no longer primary: nothing is written (the glass itself writes nothing)
    assert np.all(tint[:, glazed] == 0.0)


def test_value_aov_holds_the_program_value_per_pixel(result):
    xs = result.shader_aovs["x"]
    assert xs.shape == (SIZE, SIZE, 1)
    x = _columns()
    open_floor = np.abs(x) < 1 - 2 * HALF / SIZE
    # each sample writes its hit's x: the pixel mean lies within the filter's reach (1.5 pixels) of the centre
    got = xs[:, open_floor, 0]
    assert np.all(np.abs(got - x[open_floor]) < 0.75 * 2 * HALF / SIZE)
    # and averaged over a column the filter's jitter cancels to a small fraction of a pixel
    assert np.all(np.abs(got.mean(axis=0) - x[open_floor]) < 0.1 * 2 * HALF / SIZE)
    assert np.all(xs[:, x > 1 + 2 * HALF / SIZE] == 0.0)


def test_aovs_change_nothing_else_and_cost_nothing_when_not_listed(result):
    plain = aov_scene(aovs=())
    for m in plain.materials:  # the compiler drops AOV Output nodes of AOVs the view layer does not list
        if m.program is not None:
            keep = m.program.code[:, 0] != R.OP_AOV_OUTPUT
            m.program = _program(m.program.registers, m.program.code[keep])
    without = render(plain, settings())
    assert without.shader_aovs is None
    assert np.array_equal(without.color, result.color)  # the AOV writes draw no random numbers


def test_a_full_holdout_still_writes_its_aovs():
    """Cycles evaluates a surface's shader (its AOV Output nodes) before a holdout ends the path: the floor made a
    full holdout still writes its colour and x where the camera sees it, while the image is transparent there."""
    scene = aov_scene()
    scene.meshes = scene.meshes[:1]  # the floor alone
    scene.materials[0].holdout = 1.0
    out = render(scene, settings())
    np.testing.assert_allclose(out.color[..., 3], 0.0, atol=1e-6)  # held out: alpha 0 everywhere
    tint = out.shader_aovs["tint"]
    np.testing.assert_allclose(tint, np.broadcast_to([0.25, 0.5, 0.75, 1.0], tint.shape), atol=1e-6)
    x = out.shader_aovs["x"][..., 0]
    np.testing.assert_allclose(x.mean(axis=0), _columns(), atol=0.5 * 2 * HALF / SIZE)


def test_misses_write_nothing():
    scene = aov_scene()
    scene.meshes = scene.meshes[1:]  # no floor: the veil's samples go on to the world
    out = render(scene, settings())
    tint = out.shader_aovs["tint"]
    x = _columns()
    np.testing.assert_allclose(tint[:, x < -1 - 2 * HALF / SIZE], np.broadcast_to(
        [1.0, 0.0, 0.0, 1.0], tint[:, x < -1 - 2 * HALF / SIZE].shape), atol=1e-6)
    assert np.all(tint[:, np.abs(x) < 1 - 2 * HALF / SIZE] == 0.0)


def test_split_render_merges_to_the_same_aovs(result):
    scene, s = aov_scene(), settings(tile_size=8)
    whole = render(aov_scene(), s)
    work = {ti: (0, SPP) for ti in range(4)}
    parts = render_samples(scene, s, work)
    merged = merge_tile_samples(aov_scene(), s, parts)
    for name in ("tint", "x"):
        assert np.array_equal(merged.shader_aovs[name], whole.shader_aovs[name]), name


@pytest.mark.parametrize("aovs, message", [
    ([("a", "COLOR"), ("a", "VALUE")], "shader AOV 'a' is listed twice"),
    ([("a", "VECTOR")], "shader AOV 'a': unknown type 'VECTOR'; choose COLOR or VALUE"),
    ([("", "COLOR")], "shader AOV ('', 'COLOR'): the name must be a non-empty string"),
    ([("tint", "COLOR")], "material 'floor': an AOV Output instruction names AOV 1, the scene lists 1 shader AOV(s)"),
])
def test_bad_aov_lists_are_refused_by_name(aovs, message):
    with pytest.raises(SceneError) as info:
        aov_scene(aovs=aovs).validate()
    assert str(info.value) == message


@pytest.mark.parametrize("emits, expected", [(False, 2 + 0.6 * (1 + 0.6 + 0.36 + 0.216)),
                                              (True, 2 + 1 + 0.6 + 0.36 + 0.216)])
def test_a_path_ended_by_russian_roulette_writes_aovs_only_on_an_emitting_surface(emits, expected):
    """Six Transparent BSDF sheets (transparency 0.6: alpha 0.4, so the path stays primary through all of them)
    each write 1 to a VALUE AOV over a black world. Russian roulette (from the third vertex: survival
    q = sqrt(max throughput) = 0.6 there and at each sheet after) ends paths among the sheets. As in Cycles, which
    decides the roulette before shading and shades a surface it ends a path on only for its emission, the sheet
    where a path ends writes only when its material emits: the mean is 2 + 0.6 x 2.176 = 3.31 (Cycles at 256 spp:
    3.307), with a faint emission 2 + 2.176 = 4.176 (Cycles: 4.175); within 1 % at 64 spp, the two 21 % apart."""
    out = render(_six_veils(emits), RenderSettings(spp=64, seed=3, threads=1, max_bounces=4))
    np.testing.assert_allclose(out.shader_aovs["layers"].mean(), expected, rtol=0.01)


def test_min_transparent_bounces_spare_the_paths_from_russian_roulette():
    """Cycles' Min Transparent Bounces 4: a path coming through Transparent BSDFs meets the roulette only after
    more than 5 transparent bounces, so every path crosses the six veils and each pixel reads exactly 6."""
    out = render(_six_veils(), RenderSettings(spp=8, seed=3, threads=1, max_bounces=4, transparent_min_bounces=4))
    np.testing.assert_allclose(out.shader_aovs["layers"], 6.0, rtol=1e-6)


def _six_veils(emits: bool = False) -> Scene:
    sheet = _program([[1.0, 0.0, 0.0]], [_inst("aov_output", value=0, aov=0)])
    materials = [Material("veil", [Lobe("refraction", np.full(3, 0.6), ior=1.0)], program=sheet,
                          emission=np.full(3, 0.01 if emits else 0.0))]
    meshes = [_quad(f"veil{k}", -3, 3, float(k), 0) for k in range(6)]
    cam = Camera.look_at((0, 0, 10), (0, 0, 0), up=(0, 1, 0), resolution=(SIZE, SIZE), kind="ORTHO",
                         ortho_scale=2 * HALF)
    scene = Scene(cam, meshes, materials, shader_aovs=[("layers", "VALUE")])
    scene.world.color = np.zeros(3)
    return scene
