"""Light portals against Cycles: a room lit only through a window by an HDRI world, with an area light marked
as a portal in the window.

In Cycles a portal emits nothing, is seen by no ray and casts no shadow; it only makes the world's light samples
of points inside go through the window (less noise, the same image). Monte does the same (core.world_kernels'
portal sampling, MIS with the map and the BSDF): Monte with and without the portal must agree, the portal
lowering the noise (the ratio printed). Against Cycles (with its portal) compared by
monte.addon.crosscheck (tests/test_crosscheck.py's `check`: channel means within max(4 sigma, 0.5 %), at most
1 % of per-pixel |z| > 5, and the power to see a 1 % error). The control: the same area light as an ordinary
light (what Monte rendered before it knew portals) must disagree. About 6 minutes on the shared 2 cores:
`pytest -m slow tests/test_light_portals.py` (the core's portal tests, tests/test_light_portal_sampling.py, run
by default).
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

# The window: x in [-W, W], z in [Z0, Z1] in the wall y = 1 of the room [-1, 1] x [-1, 1] x [0, 2].
W, Z0, Z1 = 0.8, 0.3, 1.7


def set_portal(light, on: bool) -> None:
    """Light > Portal: on the light itself where Blender has it there, else on its Cycles settings."""
    if hasattr(light, "is_portal"):
        light.is_portal = on
    else:
        light.cycles.is_portal = on


def window_room():
    """A closed 2 m room (diffuse walls, albedo 0.6) with a window in its north wall under Blender's forest HDRI,
    seen from inside near the south wall; an area light the size of the window in it, facing in, as a portal."""
    bf.bpy_module()
    scene = bf.reset()
    grey = bf.diffuse("wall", (0.6, 0.6, 0.6))
    quads = {"floor": [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)],
             "ceiling": [(-1, -1, 2), (-1, 1, 2), (1, 1, 2), (1, -1, 2)],
             "south": [(-1, -1, 0), (-1, -1, 2), (1, -1, 2), (1, -1, 0)],
             "east": [(1, -1, 0), (1, -1, 2), (1, 1, 2), (1, 1, 0)],
             "west": [(-1, -1, 0), (-1, 1, 0), (-1, 1, 2), (-1, -1, 2)],
             # the north wall around the window: below, above, left, right of it
             "sill": [(-1, 1, 0), (1, 1, 0), (1, 1, Z0), (-1, 1, Z0)],
             "lintel": [(-1, 1, Z1), (1, 1, Z1), (1, 1, 2), (-1, 1, 2)],
             "left": [(-1, 1, Z0), (-W, 1, Z0), (-W, 1, Z1), (-1, 1, Z1)],
             "right": [(W, 1, Z0), (1, 1, Z0), (1, 1, Z1), (W, 1, Z1)]}
    for name, quad in quads.items():
        bs.mesh_object(name, quad, [(0, 1, 2, 3)], grey)
    bs.set_environment_world(scene, bs.studio_hdri("forest"), 1.0)
    bf.camera_object(scene, (0.0, -0.9, 1.2), (math.radians(75), 0, math.radians(10)), lens=16.0)
    portal = bf.add_light(scene, "AREA", (0.0, 1.0, 0.5 * (Z0 + Z1)), (-math.pi / 2, 0, 0), name="window",
                          energy=40.0, shape="RECTANGLE", size=2 * W, size_y=Z1 - Z0)
    set_portal(portal.data, True)
    scene.render.resolution_x, scene.render.resolution_y = SIZES["small"][0], SIZES["small"][0]
    scene.render.resolution_percentage = 100
    return scene


SAMPLES = 5  # x the small cross-check's sample counts: 4 sigma of the means' difference below 0.6 %


@pytest.mark.slow
def test_a_window_portal_renders_as_cycles(tmp_path):
    from monte.addon import crosscheck as cc
    from monte.core import compare as cmp
    from monte.core.exr import read_exr

    scene = window_room()
    check(scene, tmp_path, "small", max_bounces=2, samples=SAMPLES)

    def image(name):
        ch = read_exr(tmp_path / "cc" / f"{name}.exr")
        return np.stack([ch[c] for c in "RGB"], -1), np.stack([ch[f"variance.{c}"] for c in "RGB"], -1)

    (guided, guided_var), (cycles, cycles_var) = image("monte"), image("cycles")
    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.threads, m.seed = SIZES["small"][1], 2, 2, 1
    # Monte without the portal: the same image within noise; the portal only lowers the noise.
    bpy.data.objects["window"].hide_render = True
    plain, plain_var = cc.render_monte(scene)
    same = cmp.compare(guided, guided_var, plain, plain_var, rel_floor=0.005)
    assert same.verdict()[0], same.verdict()[1]
    # per-sample variance (the pixel means' variance x their samples): the guided image has SAMPLES x more
    ratio = float(plain_var.mean() / (SAMPLES * guided_var.mean()))
    print(f"\nportal: mean pixel variance per sample, without / with the portal {ratio:.2f}")
    assert ratio > 1.5
    # The control: the window's area light as an ordinary light (the portal flag ignored) is far off.
    bpy.data.objects["window"].hide_render = False
    set_portal(bpy.data.lights["window"], False)
    wrong, wrong_var = cc.render_monte(scene)
    assert not cmp.compare(wrong, wrong_var, cycles, cycles_var, rel_floor=0.005).verdict()[0]
