"""The view layer's Material Override, World Override and Sky (Use Sky) against real Cycles (bpy ships it).

A red diffuse ball on a grey floor seen from above under a grey world, 32x32. With the view layer's Material
Override (a glossy blue Principled BSDF) and World Override (a warm world) Cycles renders every surface with the
override material under the override world; Monte must match (channel means within max(4 sigma, 1 %) capped at
1 %, at most 1 % of pixels beyond 5 sigma; Cycles' variance from 4 seeds at half Monte's samples). Control: the
scene without the overrides (what Monte rendered before it read them) is rejected against the same Cycles image.
With Sky off Cycles renders the world black for every ray (the image is 0): so must Monte. About 15 s on 2 cores.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import crosscheck as cc  # noqa: E402
from monte.core import compare as cmp  # noqa: E402

pytestmark = [pytest.mark.blender]

CYCLES_RUNS = 4
SPP, BOUNCES = 64, 3


def ball_scene():
    scene = bf.floor_scene(size=(32, 32), world=0.5)
    bf.icosphere_object("ball", (0, 0, 1.5), 1.5, bf.diffuse("ball", (0.8, 0.2, 0.1)), subdivisions=3)
    return scene


def override(scene, on: bool) -> None:
    layer = scene.view_layers[0]
    own = scene.world
    warm = bf.set_world(scene, (0.9, 0.6, 0.3), 1.0)
    scene.world = own
    layer.world_override = warm if on else None
    layer.material_override = (bf.node_material("override", "ShaderNodeBsdfPrincipled",
                                                **{"Base Color": (0.1, 0.3, 0.8, 1.0), "Roughness": 0.4})
                               if on else None)


def monte(scene):
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = SPP, BOUNCES, 1, 2
    return cc.render_monte(scene)


def cycles(scene, tmp_path, runs: int = CYCLES_RUNS, spp: int = SPP // 2):
    images = []
    for seed in range(1, runs + 1):
        cc.configure_cycles(scene, spp, BOUNCES, threads=2, seed=seed)
        images.append(cc.render_cycles(scene, tmp_path)[0])
    return cmp.runs_mean_and_variance(np.stack(images))


def test_material_and_world_override_match_cycles(tmp_path):
    scene = ball_scene()
    override(scene, True)
    mon, mon_var = monte(scene)
    cyc, cyc_var = cycles(scene, tmp_path)
    c = cmp.compare(mon, mon_var, cyc, cyc_var, rel_cap=0.01)
    ok, reasons = c.verdict()
    print(f"\noverrides: Monte {np.round(c.mean_a, 4)} Cycles {np.round(c.mean_b, 4)} "
          f"rel {np.round(100 * c.relative_difference, 2)} % z {c.z_stats()}")
    assert ok, reasons
    override(scene, False)  # control: the overrides ignored
    plain, plain_var = monte(scene)
    c = cmp.compare(plain, plain_var, cyc, cyc_var, rel_cap=0.01)
    print(f"overrides ignored (control): rel {np.round(100 * c.relative_difference, 2)} %")
    assert not c.verdict()[0], "the scene without its overrides passes the same check (a control that cannot fail)"


def test_sky_off_renders_the_world_black_as_cycles(tmp_path):
    scene = ball_scene()
    scene.view_layers[0].use_sky = False
    cyc, _ = cycles(scene, tmp_path, runs=2, spp=4)
    mon, _ = monte(scene)
    assert cyc.max() == 0.0 and mon.max() == 0.0
    scene.view_layers[0].use_sky = True  # control: the world lights the scene
    assert monte(scene)[0].mean() > 0.1
