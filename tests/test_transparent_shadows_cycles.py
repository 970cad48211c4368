"""Transparent shadows against Cycles: a sheet hidden from the camera over the left half of a diffuse floor
(tests/blender_fixtures.floor_scene, seen from above), between the light and the floor, exported by the add-on
and compared by monte.addon.crosscheck (channel means within max(4 sigma, 0.5 %), at most 1 % of per-pixel
|z| > 5, and the power to see a 1 % error: tests/test_crosscheck.py's `check`). The sheet is a Transparent BSDF
under an area light (default suite; the control: Monte with Transparent bounces 0, every transparent surface
blocking shadow rays as before, must disagree; and two camera-visible sheets at Max Bounces 1: a pass through a
Transparent BSDF is a transparent bounce, not a bounce), a Principled BSDF of Alpha 0.5 under a sun, a Principled BSDF
whose Alpha is a Checker texture under a point light, and a Transparent BSDF under an HDRI world (those three
are slow: `pytest -m slow tests/test_transparent_shadows_cycles.py`).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402
from test_crosscheck import SIZES, check  # noqa: E402

from monte.lab import bpy_scenes as bs  # noqa: E402

pytestmark = pytest.mark.blender


def sheet_scene(make_material, light: dict | None, world: float = 0.0):
    """The floor under a 5 x 10 sheet at z = 1.5 over its left half (x < 0), hidden from camera rays."""
    bf.bpy_module()
    scene = bf.floor_scene(size=(32, 32), world=world)
    sheet = bs.mesh_object("sheet", [(-5, -5, 1.5), (0, -5, 1.5), (0, 5, 1.5), (-5, 5, 1.5)], [(0, 1, 2, 3)],
                           make_material())
    sheet.visible_camera = False
    if light is not None:
        light = dict(light)
        bf.add_light(scene, light.pop("kind"), light.pop("location"), light.pop("rotation", (0, 0, 0)), **light)
    return scene


def transparent_bsdf():
    return bs.node_material("clear", "ShaderNodeBsdfTransparent", Color=(0.5, 0.6, 0.4))


def half_alpha():
    return bs.node_material("half", "ShaderNodeBsdfPrincipled", Base_Color=(0.8, 0.8, 0.8), Alpha=0.5)


def checker_alpha():
    """A Principled BSDF whose Alpha is a Checker texture's Fac (1 on its first colour's squares, 0 elsewhere):
    a lace of holes, as an alpha-mapped card."""
    mat = bs.node_material("lace", "ShaderNodeBsdfPrincipled", Base_Color=(0.8, 0.8, 0.8))
    tree = mat.node_tree
    coords = tree.nodes.new("ShaderNodeTexCoord")
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = 1.5
    tree.links.new(coords.outputs["Object"], checker.inputs["Vector"])
    principled = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    tree.links.new(checker.outputs["Fac"], principled.inputs["Alpha"])
    return mat


AREA = dict(kind="AREA", location=(-1.0, 0.0, 3.0), energy=300.0, shape="SQUARE", size=1.0)
SUN = dict(kind="SUN", location=(0, 0, 5), rotation=(0.3, 0.2, 0), energy=2.0, angle=math.radians(10))
POINT = dict(kind="POINT", location=(-1.0, 0.5, 3.0), energy=600.0, shadow_soft_size=0.3)


def _control_disagrees(scene, tmp_path, max_bounces: int):
    """Monte's render of `scene` with a setting changed (the control) at check()'s small size, and Cycles' image
    that check() rendered; asserts that the two disagree (per-pixel comparison). Returns (control, Cycles) RGB."""
    from monte.addon import crosscheck as cc
    from monte.core import compare as cmp
    from monte.core.exr import read_exr

    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.threads, m.seed = SIZES["small"][1], max_bounces, 2, 1
    wrong, wrong_var = cc.render_monte(scene)
    ch = read_exr(tmp_path / "cc" / "cycles.exr")
    cycles = np.stack([ch[c] for c in "RGB"], -1)
    cycles_var = np.stack([ch[f"variance.{c}"] for c in "RGB"], -1)
    assert not cmp.compare(wrong, wrong_var, cycles, cycles_var, rel_floor=0.005).verdict()[0]
    return wrong, cycles


def test_transparent_bsdf_sheet_under_an_area_light(tmp_path):
    scene = sheet_scene(transparent_bsdf, AREA)
    check(scene, tmp_path, "small", max_bounces=2)
    # The control: shadow rays blocked by the sheet (Transparent bounces 0: Monte before transparent shadows)
    scene.cycles.transparent_max_bounces = 0
    wrong, cycles = _control_disagrees(scene, tmp_path, max_bounces=2)
    left = np.s_[:, :14]  # under the sheet
    assert wrong[left].mean() < 0.9 * cycles[left].mean()


def test_transparent_surfaces_are_not_bounces(tmp_path):
    """Two Transparent BSDF sheets over the whole floor, seen by the camera, at Max Bounces 1: Cycles counts a
    pass through them as a transparent bounce (up to Transparent Max Bounces), not as a bounce, so the floor
    behind them still gets its direct light (Monte counting them as bounces left it black). The control: Monte
    with Transparent Max Bounces 1, whose paths end at the second sheet, must disagree."""
    scene = sheet_scene(transparent_bsdf, AREA)
    sheet = bpy.data.objects["sheet"]
    sheet.visible_camera = True
    sheet.scale.x = 2.0  # its x from -5..0 stretched to -10..0, then moved to -5..5: over the whole floor
    sheet.location.x = 5.0
    second = bs.mesh_object("sheet2", [(-5, -5, 1.0), (5, -5, 1.0), (5, 5, 1.0), (-5, 5, 1.0)], [(0, 1, 2, 3)],
                            bs.node_material("clear2", "ShaderNodeBsdfTransparent", Color=(0.9, 0.8, 0.9)))
    assert second.visible_camera
    check(scene, tmp_path, "small", max_bounces=1)
    scene.cycles.transparent_max_bounces = 1
    wrong, cycles = _control_disagrees(scene, tmp_path, max_bounces=1)
    assert wrong.mean() < 0.1 * cycles.mean()


@pytest.mark.slow
@pytest.mark.parametrize("make_material, light, bounces", [
    pytest.param(half_alpha, SUN, 4, id="alpha-0.5-sun"),
    pytest.param(checker_alpha, POINT, 4, id="checker-alpha-point"),
])
def test_alpha_sheets(make_material, light, bounces, tmp_path):
    check(sheet_scene(make_material, light), tmp_path, "small", max_bounces=bounces)


@pytest.mark.slow
def test_transparent_sheet_under_an_hdri(tmp_path):
    """Shadow rays towards the world (an environment map is light-sampled; a uniform world is not, in either
    renderer)."""
    scene = sheet_scene(transparent_bsdf, None)
    bs.set_environment_world(scene, bs.studio_hdri("forest"), 1.0)
    check(scene, tmp_path, "small", max_bounces=2)
