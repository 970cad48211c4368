"""Denoising: Cycles' Denoising Albedo / Normal passes (core.integrator.DenoisingFeatures), Open Image Denoise
through core.denoise, `monte render --denoise`, and what happens without the denoiser (pyoidn's import failing).

The Cycles comparisons of the passes and the interior bench scene are in tests/test_denoise_cycles.py (slow).
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from monte import cli
from monte.core import denoise as dn
from monte.core import exr, metrics
from monte.core.builtin_scenes import cornell_box
from monte.core.render import render
from monte.core.scene import Lobe, Material
from monte.core.settings import RenderSettings
from monte.lab.bench import REFERENCE_OWN_RMSE, bundled_reference

HAVE_OIDN = dn.denoiser_status() is None
needs_oidn = pytest.mark.skipif(not HAVE_OIDN, reason="pyoidn has no wheel for this platform")


@pytest.fixture
def no_oidn(monkeypatch):
    """pyoidn's import fails, as on a machine without it (a None entry in sys.modules makes `import` raise
    ImportError)."""
    monkeypatch.setitem(sys.modules, "pyoidn", None)


def _settings(**kw) -> RenderSettings:
    return RenderSettings(**{"threads": 2, "aovs": False, **kw})


# ------------------------------------------------------------------------------------------ the passes
def test_features_leave_the_image_unchanged_and_cost_nothing_when_off():
    scene = cornell_box((24, 24))
    off = render(scene, _settings(spp=4))
    on = render(scene, _settings(spp=4, denoising_features=True))
    assert off.denoising_albedo is None and off.denoising_normal is None
    np.testing.assert_array_equal(on.color, off.color)  # the features draw no random numbers
    assert on.denoising_albedo.shape == on.denoising_normal.shape == (24, 24, 3)


def _pixel(img: np.ndarray, row: int, col: int) -> np.ndarray:
    return img[row - 1:row + 2, col - 1:col + 2].reshape(-1, 3).mean(axis=0)


# Pixels of the 64x64 Cornell box (camera at (0, -3.9, 1) along +y, 39 degrees): the back wall, and the
# centres of the mirror sphere (-0.45, 0.35, 0.35) and the glass sphere, projected by hand.
BACK_WALL = (25, 32)
MIRROR_CENTRE = (45, 22)


def _smoothstep(e0, e1, x):
    t = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return t * t * (3 - 2 * t)


@pytest.mark.parametrize("roughness", [0.0, 0.25, 0.4])
def test_feature_passes_blend_by_roughness_as_cycles(roughness):
    """A glossy lobe (colour 0.9, no Fresnel) is diffuse by the share d = smoothstep(0, 0.15, roughness^2) and the
    surface writes its features with f = smoothstep(0, 0.5, d): albedo 0.9 d f, normal f x (towards the camera).
    The rest goes on to what the sphere reflects near its centre: the open front of the box, the black world (0).
    Roughness 0: a mirror (0, 0); 0.25: d = 0.376, f = 0.846; 0.4: diffuse (0.9, 1)."""
    scene = cornell_box((64, 64))
    scene.materials[4] = Material("metal", [Lobe("glossy", np.full(3, 0.9), roughness=roughness)])
    r = render(scene, _settings(spp=16, denoising_features=True))
    wall_albedo, wall_normal = _pixel(r.denoising_albedo, *BACK_WALL), _pixel(r.denoising_normal, *BACK_WALL)
    np.testing.assert_allclose(wall_albedo, 0.75, atol=1e-5)  # diffuse white, every sample
    np.testing.assert_allclose(wall_normal, (0, 0, -1), atol=1e-5)  # facing the camera, camera space
    d = _smoothstep(0, 0.15, roughness ** 2)
    f = _smoothstep(0, 0.5, d)
    albedo = _pixel(r.denoising_albedo, *MIRROR_CENTRE)
    normal = _pixel(r.denoising_normal, *MIRROR_CENTRE)
    # What the deferred share 0.9 (1 - d) (1 - f) reaches (a white wall at most) may add to the albedo.
    deferred = 0.9 * (1 - d) * (1 - f)
    assert 0.9 * d * f - 0.01 <= albedo.min() and albedo.max() <= 0.9 * d * f + 0.75 * deferred + 0.01
    # The normals of the sphere's centre pixels are within 20 degrees of the view axis (cos 20 = 0.94).
    assert -f - 0.01 <= normal[2] <= -0.94 * f + deferred  # the normal near the sphere's centre faces the camera


def test_feature_passes_through_a_mirror_multiply_its_albedo():
    """The mirror sphere (colour 0.999) shows the scene: wherever it reflects a white wall the albedo is
    0.999 x 0.75, never the sphere's own colour."""
    scene = cornell_box((64, 64))
    r = render(scene, _settings(spp=16, denoising_features=True))
    albedo = r.denoising_albedo.reshape(-1, 3)
    assert np.isclose(albedo, 0.999 * 0.75, atol=2e-5).all(axis=1).sum() > 10
    # No pixel reads the mirror's colour (it would be the first-hit AOV's value) but the lamp, seen directly or
    # in the mirror, reads its radiance (12).
    assert not np.isclose(albedo, 0.999, atol=1e-3).all(axis=1).any()
    assert albedo.max() == pytest.approx(12.0, rel=1e-4)


# ------------------------------------------------------------------------------------------ OIDN
@needs_oidn
def test_denoised_cornell_box_is_three_times_closer_to_the_converged_reference():
    """16 spp, 256x256 against the bundled converged Cycles render (its own noise removed in quadrature): the
    denoised image's RMSE is at least 3x lower than the noisy one's (measured: 0.120 -> 0.034)."""
    reference = bundled_reference()
    r = render(cornell_box((256, 256)), _settings(spp=16, denoising_features=True))
    denoised = dn.denoise(r.color, r.denoising_albedo, r.denoising_normal)
    assert denoised.shape == r.color.shape
    np.testing.assert_array_equal(denoised[..., 3], r.color[..., 3])  # alpha passes through

    def err(img):
        e = metrics.rmse(img[..., :3], reference)
        return np.sqrt(e * e - REFERENCE_OWN_RMSE ** 2)

    noisy, clean = err(r.color), err(denoised)
    print(f"\nCornell 16 spp: RMSE noisy {noisy:.4f}, denoised {clean:.4f} ({noisy / clean:.2f}x)")
    assert noisy / clean >= 3.0


@needs_oidn
def test_cli_denoise_keeps_the_noisy_image_as_its_own_layer(tmp_path, capsys):
    out = tmp_path / "d.exr"
    args = ["render", "cornell", "--resolution", "32x32", "--spp", "4", "--threads", "2", "-q", "--no-png"]
    assert cli.main(args + ["-o", str(out), "--denoise", "--denoise-quality", "fast"]) == 0
    ch = exr.read_exr(out)
    for name in ("noisy.R", "noisy.A", "denoising_albedo.R", "denoising_normal.Z"):
        assert name in ch
    plain = tmp_path / "p.exr"
    assert cli.main(args + ["-o", str(plain)]) == 0
    undenoised = exr.read_exr(plain)
    np.testing.assert_array_equal(ch["noisy.R"], undenoised["R"])  # the noisy layer is the render as it was
    assert not np.array_equal(ch["R"], undenoised["R"])
    assert "noisy.R" not in undenoised and "denoising_albedo.R" not in undenoised


# ------------------------------------------------------------------------------------------ bad input
def test_without_oidn_the_error_says_what_to_install(no_oidn):
    reason = dn.denoiser_status()
    assert reason.startswith("denoising needs Intel Open Image Denoise through the pyoidn package, which could "
                             "not be loaded (ModuleNotFoundError: import of pyoidn halted")
    assert reason.endswith(dn.INSTALL_HINT)
    with pytest.raises(dn.DenoiserUnavailable, match="pip install pyoidn"):
        dn.denoise(np.zeros((4, 4, 3), np.float32))


def test_cli_without_oidn_saves_the_noisy_image_and_fails(no_oidn, tmp_path, capsys):
    out = tmp_path / "n.exr"
    status = cli.main(["render", "cornell", "--resolution", "16x16", "--spp", "2", "--threads", "2", "-q",
                       "--no-png", "-o", str(out), "--denoise"])
    assert status == 1
    err = capsys.readouterr().err
    assert "monte render: error: denoising needs Intel Open Image Denoise through the pyoidn package" in err
    assert f"The image was saved without denoising to {out}" in err
    ch = exr.read_exr(out)
    assert "R" in ch and "denoising_albedo.R" in ch and "noisy.R" not in ch
    # the render itself, undenoised (the CLI keeps no error estimate unless asked: one Sobol scramble per pixel)
    direct = render(cornell_box((16, 16)), _settings(spp=2, error_estimate=False))
    np.testing.assert_array_equal(ch["R"], direct.color[..., 0])


@pytest.mark.parametrize("call, message", [
    (lambda: dn.denoise(np.zeros((4, 4, 3)), quality="ultra"),
     "unknown denoising quality 'ultra'; choose one of high, balanced, fast"),
    (lambda: dn.denoise(np.zeros((4, 4))), r"denoise: the colour image has shape \(4, 4\), expected"),
    (lambda: dn.denoise(np.zeros((4, 4, 3)), np.zeros((4, 5, 3))),
     r"denoise: the albedo image has shape \(4, 5, 3\), expected \(4, 4, 3\)"),
    (lambda: dn.denoise(np.zeros((4, 4, 3)), None, np.zeros((4, 4, 3))),
     "denoise: a normal image needs an albedo image as well"),
    (lambda: dn.denoise(np.full((4, 4, 3), np.nan)), "denoise: the colour image holds NaN or Inf values"),
])
def test_bad_input_is_refused_by_name(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_bench_denoise_needs_vs_cycles(capsys):
    assert cli.main(["bench", "--denoise"]) == 2
    assert "monte bench: --denoise compares denoised renders with --vs cycles only" in capsys.readouterr().err


def test_feature_passes_merge_bit_for_bit_from_sample_ranges():
    """A render split into sample ranges (core.distributed's units) and merged has the same denoising passes
    as one render: the film's feature sums travel with its other sums."""
    from monte.core.render import merge_tile_samples, render_samples
    from monte.core.schedule import pass_bounds, tiles

    scene = cornell_box((32, 24))
    settings = _settings(spp=12, tile_size=16, batch_paths=1024, denoising_features=True)
    whole = render(scene, settings)
    bounds = pass_bounds(tiles(0, 0, 32, 24, 16), 12, settings)
    parts = [part for ti, b in enumerate(bounds) for lo, hi in zip(b[:-1], b[1:])
             for part in render_samples(scene, settings, {ti: (lo, hi)})]
    merged = merge_tile_samples(scene, settings, parts[::-1])
    np.testing.assert_array_equal(merged.denoising_albedo, whole.denoising_albedo)
    np.testing.assert_array_equal(merged.denoising_normal, whole.denoising_normal)
    assert np.abs(whole.denoising_normal).max() > 0.5
