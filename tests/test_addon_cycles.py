"""Cross-checks of the add-on against Cycles (bpy ships it): the same Blender scene rendered by both engines.

Lights exercise the export's unit conversions end to end (power, exposure, temperature, spot cone and blend,
area shapes and Normalize, sun angle) with direct light only; materials measure how far Monte's Principled
BSDF approximation is from Cycles' (the tolerances below are what docs/addon.md reports). Slow: run with
`pytest -m slow tests/test_addon_cycles.py`.
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

from monte.addon import crosscheck as cc  # noqa: E402

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def render(scene, engine: str, tmp_path, spp: int, bounces: int) -> np.ndarray:
    """The scene rendered by one engine, (H, W, 3) linear RGB; Cycles as the cross-check's unbiased reference."""
    if engine == "CYCLES":
        cc.configure_cycles(scene, spp, bounces, threads=2, seed=1)
        return cc.render_cycles(scene, tmp_path)[0]
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = spp, bounces, 1, 2
    return cc.render_monte(scene)[0]


def blocks(img: np.ndarray, n: int = 4) -> np.ndarray:
    h, w, _ = img.shape
    return img[: h - h % n, : w - w % n].reshape(n, h // n, n, w // n, 3).mean(axis=(1, 3))


floor_scene = bf.floor_scene
add_light = bf.add_light


LIGHTS = {k: bf.LIGHTS[k] for k in ("point", "spot", "sun", "area-square", "area-ellipse", "area-unnormalized",
                                   "temperature")}


@pytest.mark.parametrize("name", list(LIGHTS))
def test_lights_match_cycles(name, tmp_path):
    scene = floor_scene()
    props = dict(LIGHTS[name])
    kind, location = props.pop("kind"), props.pop("location")
    rotation = props.pop("rotation", (0, 0, 0))
    add_light(scene, kind, location, rotation, **props)
    cyc = blocks(render(scene, "CYCLES", tmp_path, 256, 0))
    mon = blocks(render(scene, "MONTE", tmp_path, 256, 0))
    lit = cyc.max(axis=2) > 0.02 * cyc.max()
    rel = np.abs(mon - cyc)[lit] / np.maximum(cyc[lit], 1e-3)
    print(f"\n{name}: mean Cycles {cyc.mean():.4f} Monte {mon.mean():.4f}, block rel. diff median "
          f"{np.median(rel):.3f} max {rel.max():.3f}")
    assert mon.mean() == pytest.approx(cyc.mean(), rel=0.03)
    assert np.median(rel) < 0.04


sphere_scene = bf.sphere_scene


# name: (inputs, relative tolerance on the sphere's mean colour): see blender_fixtures.PRINCIPLED.
PRINCIPLED = bf.PRINCIPLED


def sphere_mask(shape: tuple[int, int], margin_px: float = 1.5) -> np.ndarray:
    """Pixels whose centre sees the unit sphere of sphere_scene (camera 5 units away, 50 mm lens, 36 mm sensor)
    at least margin_px pixels inside its outline: a geometric mask, so that noise cannot select pixels (a mask
    thresholded on one render's values biases the mean of nearly white materials)."""
    h, w = shape
    half = 18.0 / 50.0  # tan of the half field of view
    px = 2.0 * half / w
    x = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * half
    y = ((np.arange(h) + 0.5) / h * 2.0 - 1.0) * half * h / w
    r = np.hypot(x[None, :], y[:, None])
    return r < math.tan(math.asin(1.0 / 5.0)) - margin_px * px


@pytest.mark.parametrize("name", list(PRINCIPLED))
def test_principled_bsdf_approximation_against_cycles(name, tmp_path):
    inputs, tolerance = PRINCIPLED[name]

    def make():
        mat = bf.node_material(name, "ShaderNodeBsdfPrincipled")
        node = mat.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            node.inputs[key].default_value = value
        return mat

    scene = sphere_scene(make)
    cyc = render(scene, "CYCLES", tmp_path, 128, 16)
    mon = render(scene, "MONTE", tmp_path, 128, 16)
    mask = sphere_mask(cyc.shape[:2])
    assert 0.15 * mask.size < mask.sum() < 0.25 * mask.size  # the inner disc covers ~20 % of the frame
    c, m = cyc[mask].mean(axis=0), mon[mask].mean(axis=0)
    print(f"\n{name}: sphere mean Cycles {np.round(c, 4)} Monte {np.round(m, 4)} rel {np.round(m / c - 1, 4)}")
    assert np.allclose(m, c, rtol=tolerance)


def rough_pane_scene(shader: str, th_deg: float, size: int = 8):
    """A 2000 x 2000 rough dielectric plane (roughness 0.8, IOR 1.45; Glass BSDF or Principled with Transmission
    1) at z = 0 with a 2 x 2 area light of 100 W 1 m above it, seen through the plane by an orthographic camera
    below at th_deg from the normal (black world): each pixel is the light's radiance transmitted by the rough
    interface from inside, i.e. next-event estimation (and BSDF-sampled hits) through rough glass."""
    scene = bf.reset()
    s = 1000.0
    inputs = {"Roughness": 0.8, "IOR": 1.45}
    if shader == "ShaderNodeBsdfPrincipled":
        inputs["Transmission Weight"] = 1.0
    mat = bf.node_material("pane", shader)
    node = next(n for n in mat.node_tree.nodes if n.bl_idname == shader)
    for key, value in inputs.items():
        node.inputs[key].default_value = value
    bf.mesh_object("pane", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)], mat)
    add_light(scene, "AREA", (0, 0, 1), energy=100.0, size=2.0)
    th = math.radians(th_deg)
    bf.camera_object(scene, (0, -3 * math.sin(th), -3 * math.cos(th)), (math.pi - th, 0, 0), kind="ORTHO",
                     ortho_scale=0.1)
    bf.set_world(scene, (0.0, 0.0, 0.0), 0.0)
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    return scene


@pytest.mark.parametrize("shader,th", [("ShaderNodeBsdfGlass", 40.0), ("ShaderNodeBsdfGlass", 0.0),
                                       ("ShaderNodeBsdfPrincipled", 40.0)])
def test_light_through_rough_glass_matches_cycles(shader, th, tmp_path):
    """Light reaching a viewer through a rough dielectric: Cycles' next-event estimation evaluates refraction
    pairs that are no physical refraction (its eval has no such check), so the light it finds through a rough
    pane exceeds what BSDF sampling alone finds; ours does the same. Before, ours was 5 % darker at 40 degrees
    (Glass BSDF: 2.82 vs 2.97), matching Cycles only with the light's emission sampling off."""
    scene = rough_pane_scene(shader, th)
    cyc = render(scene, "CYCLES", tmp_path, 2048, 1).mean(axis=(0, 1))
    mon = render(scene, "MONTE", tmp_path, 2048, 1).mean(axis=(0, 1))
    print(f"\n{shader} {th} deg: Cycles {np.round(cyc, 4)} Monte {np.round(mon, 4)} rel {np.round(mon / cyc - 1, 4)}")
    assert np.allclose(mon, cyc, rtol=0.01)
