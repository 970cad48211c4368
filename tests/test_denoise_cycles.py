"""Denoising against real Cycles (the bpy module): Monte's Denoising Albedo / Denoising Normal passes equal
Cycles' on a scene with diffuse, glossy (smooth, slightly rough, rough) and glass surfaces; the add-on's Denoise
setting fills the Noisy Image pass; on the interior bench scene the denoised 16 spp render is 3x closer to a
converged Cycles reference than the noisy one.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import crosscheck as cc  # noqa: E402
from monte.addon.engine import render_with_operator  # noqa: E402
from monte.core import denoise as dn  # noqa: E402
from monte.core import exr, metrics  # noqa: E402

pytestmark = [pytest.mark.blender]
needs_oidn = pytest.mark.skipif(dn.denoiser_status() is not None, reason="pyoidn has no wheel for this platform")


def feature_scene(resolution=(48, 48)):
    """The Cornell box (diffuse walls, a mirror sphere, a clear glass sphere, a pure-emission lamp) with two
    floating glossy spheres: roughness 0.15 (specular-like for the features) and 0.5 (diffuse-like)."""
    scene = bf.cornell_box(resolution)
    slightly = bf.node_material("slightly_rough", "ShaderNodeBsdfGlossy", Color=(0.8, 0.6, 0.4), Roughness=0.15)
    rough = bf.node_material("rough", "ShaderNodeBsdfGlossy", Color=(0.4, 0.7, 0.5), Roughness=0.5)
    bf.icosphere_object("slightly_rough_sphere", (-0.45, 0.2, 1.35), 0.3, slightly)
    bf.icosphere_object("rough_sphere", (0.45, 0.4, 1.3), 0.3, rough)
    return scene


def cycles_features(scene, spp: int, tmp_path) -> tuple[np.ndarray, np.ndarray]:
    """Cycles' Denoising Albedo and Denoising Normal passes (row 0 at the top; Blender 5.3 defaults: follow
    reflections, albedo roughness weighting). Blender writes them to the file of a still render (they are not in
    the Render Result image that save_render writes)."""
    layer = scene.view_layers[0]
    cc.configure_cycles(scene, spp, 16, threads=2, seed=1)
    layer.cycles.denoising_store_passes = True
    path = tmp_path / "cycles.exr"
    bf.render_still_exr(scene, path)
    ch = exr.read_exr(path)
    albedo = np.stack([ch[f"{layer.name}.Denoising Albedo.{c}"] for c in "RGB"], axis=-1)
    normal = np.stack([ch[f"{layer.name}.Denoising Normal.{c}"] for c in "XYZ"], axis=-1)
    return albedo.astype(np.float64), normal.astype(np.float64)


def monte_result(scene, spp: int):
    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads, m.use_denoising = spp, 16, 1, 2, True
    m.filter_type, m.filter_width = "blackman-harris", 1.5
    return render_with_operator(scene)[0][1]


def test_feature_passes_match_cycles(tmp_path):
    """Means of every channel within 1% (albedo: of the channel's mean; normal: of a unit vector), and the
    per-pixel maps close (mean absolute difference), at 64 spp each."""
    scene = feature_scene()
    cyc_albedo, cyc_normal = cycles_features(scene, 64, tmp_path)
    result = monte_result(scene, 64)
    mon_albedo = result.denoising_albedo.astype(np.float64)
    mon_normal = result.denoising_normal.astype(np.float64)
    ca, ma = cyc_albedo.reshape(-1, 3).mean(0), mon_albedo.reshape(-1, 3).mean(0)
    cn, mn = cyc_normal.reshape(-1, 3).mean(0), mon_normal.reshape(-1, 3).mean(0)
    print(f"\nalbedo means Cycles {np.round(ca, 4)} Monte {np.round(ma, 4)}; normal means Cycles {np.round(cn, 4)} "
          f"Monte {np.round(mn, 4)}; mean |diff| albedo {np.abs(mon_albedo - cyc_albedo).mean():.4f} "
          f"normal {np.abs(mon_normal - cyc_normal).mean():.4f}")
    np.testing.assert_allclose(ma, ca, rtol=0.01)
    np.testing.assert_allclose(mn, cn, atol=0.01)
    # Per pixel: the same surfaces (an error in which surface the features stop at shows as whole regions).
    assert np.abs(mon_albedo - cyc_albedo).mean() < 0.02
    assert np.abs(mon_normal - cyc_normal).mean() < 0.05


@needs_oidn
def test_addon_denoise_writes_cycles_passes(tmp_path):
    """A still rendered with Denoise on: Blender's file holds Combined (denoised), Noisy Image (the render before
    denoising), Denoising Albedo and Denoising Normal. A diffuse plane (albedo 0.5) under a white world, seen
    from straight above: radiance 0.5 everywhere, albedo 0.5, normal facing the camera (0, 0, -1)."""
    scene = bf.plane_under_world(albedo=0.5, world=1.0, resolution=(16, 12))
    scene.monte.samples, scene.monte.threads, scene.monte.use_denoising = 4, 2, True
    scene.monte.denoising_quality = "fast"
    bf.render_still_exr(scene, tmp_path / "still.exr")
    ch = exr.read_exr(tmp_path / "still.exr")

    def layer(name, comps="RGB"):
        return np.stack([ch[f"ViewLayer.{name}.{c}"] for c in comps], axis=-1)

    np.testing.assert_allclose(layer("Noisy Image"), 0.5, atol=1e-4)  # the plane's radiance, noise-free
    combined = layer("Combined")  # denoised: changed, but a flat image stays flat on the whole (tiny images
    assert not np.array_equal(combined, layer("Noisy Image"))  # show OIDN's edge effects at their borders)
    assert combined.mean() == pytest.approx(0.5, rel=0.02)
    np.testing.assert_allclose(layer("Denoising Albedo"), 0.5, atol=1e-5)
    np.testing.assert_allclose(layer("Denoising Normal", "XYZ"), np.broadcast_to((0, 0, -1), (12, 16, 3)),
                               atol=1e-5)


def test_addon_without_oidn_keeps_the_noisy_render(monkeypatch):
    """pyoidn's import fails: the render with Denoise on is the undenoised render (a warning says why), and
    the Denoise panel's check says what is missing."""
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    assert "pyoidn" in dn.denoiser_status()
    scene = feature_scene((16, 16))
    result = monte_result(scene, 2)
    assert result.noisy is None and "denoise_seconds" not in result.stats
    scene.monte.use_denoising = False
    plain = render_with_operator(scene)[0][1]
    np.testing.assert_array_equal(result.color, plain.color)


@needs_oidn
def test_cli_denoises_a_blend_file(tmp_path):
    """`monte render scene.blend --denoise`: the add-on's Denoise setting for that run, Monte's EXR layout with
    the noisy layer and the passes (a plane of albedo 0.5 under a white world: radiance 0.5 exactly)."""
    from monte import cli

    scene = bf.plane_under_world(albedo=0.5, world=1.0, resolution=(12, 10))
    blend = tmp_path / "plane.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "plane.exr"
    assert cli.main(["render", str(blend), "-o", str(out), "--spp", "4", "--threads", "2", "--no-png", "-q",
                     "--denoise", "--denoise-quality", "fast"]) == 0
    ch = exr.read_exr(out)
    np.testing.assert_allclose(ch["noisy.R"], 0.5, atol=1e-4)
    assert ch["R"].mean() == pytest.approx(0.5, rel=0.02) and not np.array_equal(ch["R"], ch["noisy.R"])
    np.testing.assert_allclose(ch["denoising_albedo.G"], 0.5, atol=1e-5)
    np.testing.assert_allclose(ch["denoising_normal.Z"], -1.0, atol=1e-5)


class _Layout:
    """Stands in for a UILayout: records the properties drawn (checked against RNA) and the labels."""

    def __init__(self, log):
        object.__setattr__(self, "log", log)

    def __getattr__(self, name):
        if name in ("column", "row", "box"):
            return lambda *a, **k: _Layout(self.log)
        if name == "prop":
            return self._prop
        if name == "label":
            return lambda text="", **k: self.log.append(("label", text))
        return lambda *a, **k: None

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)

    def _prop(self, data, name, **_kw):
        assert name in data.bl_rna.properties.keys(), f"{type(data).__name__} has no property {name!r}"
        self.log.append(("prop", name))


@pytest.mark.parametrize("installed", [True, False])
def test_denoise_panel_says_whether_oidn_is_there(installed, monkeypatch):
    import types

    from monte.addon.ui import MONTE_RENDER_PT_denoise

    if installed and dn.denoiser_status() is not None:
        pytest.skip("pyoidn has no wheel for this platform")
    if not installed:
        monkeypatch.setitem(sys.modules, "pyoidn", None)
    scene = bf.plane_under_world()
    log = []
    panel = types.SimpleNamespace(layout=_Layout(log))
    ctx = types.SimpleNamespace(scene=scene)
    MONTE_RENDER_PT_denoise.draw_header(panel, ctx)
    MONTE_RENDER_PT_denoise.draw(panel, ctx)
    assert ("prop", "use_denoising") in log and ("prop", "denoising_quality") in log
    assert (("label", "Open Image Denoise is not available:") in log) is not installed


@pytest.mark.slow
@needs_oidn
def test_denoised_interior_is_three_times_closer_to_cycles_reference():
    """The interior bench scene at 96x96: Monte at 16 spp, noisy and denoised, against Cycles 4 x 256 spp (its
    own noise, RMSE about 0.011, removed in quadrature). Measured (against Monte's own 4 x 256 spp): noisy 0.096,
    denoised 0.021-0.025 (3.9-4.5x) for seeds 1 and 2. About 6 minutes on 2 busy cores."""
    from monte.addon.export import export_scene
    from monte.core.render import render
    from monte.core.settings import RenderSettings
    from monte.lab import bpy_scenes
    from monte.lab.bench_cycles import render_cycles
    from monte.lab.bench_math import corrected_rmse, reference_from_seeds

    bf.bpy_module()
    scene = bpy_scenes.build("interior", (96, 96))
    t0 = time.perf_counter()
    reference, own_mse = reference_from_seeds([render_cycles(scene, 256, 1000 + s, 2, 16)[0] for s in range(4)])
    print(f"\nreference: {time.perf_counter() - t0:.0f} s, own RMSE {np.sqrt(own_mse):.4f}")
    scene.render.engine = "MONTE"
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    r = render(core_scene, RenderSettings(spp=16, seed=1, threads=2, aovs=False, denoising_features=True))
    denoised = dn.denoise(r.color, r.denoising_albedo, r.denoising_normal)
    noisy = corrected_rmse(metrics.rmse(r.color[..., :3], reference), own_mse)
    clean = corrected_rmse(metrics.rmse(denoised[..., :3], reference), own_mse)
    print(f"interior 16 spp: RMSE noisy {noisy:.4f}, denoised {clean:.4f} ({noisy / clean:.2f}x)")
    assert noisy / clean >= 3.0
