"""The fused path kernel (core.fused_path, dispatched by core.fused_tracer): where a scene allows it, one compiled call traces each camera path to
its end. It reads the same random numbers per dimension and calls the same device functions as the per-bounce
integrator, so its images must equal that integrator's up to float32 rounding (on this machine: bit for bit),
whatever the thread count; scenes it does not support keep the per-bounce integrator, with the reason named."""

import sys
from pathlib import Path

import numpy as np
import pytest

from monte.core import builtin_scenes
from monte.core.fused_tracer import FUSED_ENV, supports
from monte.core.integrator import PathTracer
from monte.core.render import prepare_scene, render
from monte.core.sampling import _TAG_SOBOL_SET, _U, _key, make_sampler

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fused_compare import assert_fused_bit_identical_across_thread_counts  # noqa: E402

SCENES = ("cornell", "point_in_sphere", "spheres_under_sky")


def _scene(name, res=16):
    if name == "cornell":
        return builtin_scenes.cornell_box((res, res))
    return getattr(builtin_scenes, name)((res, res))


def _tracer(scene, settings):
    ps, accel = prepare_scene(scene, settings)
    return PathTracer(ps, accel, settings, make_sampler(settings.sampler, settings.seed, settings.spp, 4))


def _render(scene, settings, monkeypatch, fused: bool):
    monkeypatch.setenv(FUSED_ENV, "1" if fused else "0")
    return render(scene, settings)


@pytest.mark.parametrize("name", SCENES)
def test_the_fused_kernel_renders_what_the_per_bounce_integrator_does(name, fast_settings, monkeypatch):
    settings = fast_settings(spp=8, threads=1)
    scene = _scene(name)
    monkeypatch.setenv(FUSED_ENV, "1")
    assert supports(_tracer(scene, settings)) is None  # the fused kernel does render this scene
    old = _render(scene, settings, monkeypatch, fused=False)
    new = _render(scene, settings, monkeypatch, fused=True)
    a, b = old.color[..., :3].astype(np.float64), new.color[..., :3].astype(np.float64)
    # Channel means within 3 sigma of their standard error (from the film's per-pixel variance): a kernel that
    # drew other random numbers would still pass this, so the pixels must also agree to float32 rounding.
    se = np.sqrt(np.sum(old.variance[..., :3], axis=(0, 1))) / a.shape[0] / a.shape[1]
    assert np.all(np.abs(a.mean(axis=(0, 1)) - b.mean(axis=(0, 1))) <= 3 * se + 1e-7)
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-6)
    assert a.mean() > 0.01  # the scene is lit: the comparison is not one of two black images
    # the stats say which traced (the bench prints Embree's share only where it was timed)
    assert new.stats["fused_kernel"] and not old.stats["fused_kernel"]
    assert old.stats["embree_share"] > 0 and new.stats["embree_share"] == 0
    for aov in ("albedo", "normal", "depth"):  # the first hit's passes come from the kernel too
        np.testing.assert_allclose(getattr(new, aov), getattr(old, aov), rtol=1e-6, atol=1e-7)


def test_the_fused_kernel_is_bit_identical_across_thread_counts(fast_settings, monkeypatch):
    scene = _scene("cornell", 24)
    assert_fused_bit_identical_across_thread_counts(scene, fast_settings, monkeypatch)


@pytest.mark.parametrize("change, reason", [
    (dict(sampler="independent"), "the sampler is not Sobol"),
    (dict(light_sampling="bsdf"), "light sampling is not MIS"),
    (dict(light_passes=("Diffuse Direct",)), "light passes"),
])
def test_scenes_or_settings_it_does_not_support_keep_the_per_bounce_integrator(change, reason, fast_settings,
                                                                                monkeypatch):
    monkeypatch.setenv(FUSED_ENV, "1")
    tracer = _tracer(_scene("cornell"), fast_settings(spp=4, **change))
    assert supports(tracer) == reason
    assert tracer.fused is None


def test_a_scene_lit_by_an_unsampled_world_alone_keeps_the_per_bounce_integrator(fast_settings, monkeypatch):
    monkeypatch.setenv(FUSED_ENV, "1")
    assert supports(_tracer(_scene("plane_under_world"), fast_settings(spp=4))) == "nothing to light-sample"


def test_the_environment_variable_forces_the_per_bounce_integrator(fast_settings, monkeypatch):
    monkeypatch.setenv(FUSED_ENV, "0")
    tracer = _tracer(_scene("cornell"), fast_settings(spp=4))
    assert supports(tracer) == f"{FUSED_ENV}=0"
    assert tracer.fused is None


def test_each_tracer_gets_its_own_seeds_sobol_set_keys(fast_settings, monkeypatch):
    """The kernel's Sobol set keys are hashed once per process and seed (fused_tracer._sobol_set_keys): a tracer
    gets its own seed's, the sampler's own keys, in a writeable array (a read-only one is another kernel
    signature, which would be compiled anew on the render's first batch)."""
    monkeypatch.setenv(FUSED_ENV, "1")
    for seed in (1, 2, 1, 2**40 + 5):
        keys = _tracer(_scene("cornell"), fast_settings(spp=1, seed=seed)).fused.set_keys
        assert keys.dtype == np.uint32 and keys.flags.writeable and len(keys) == 2 + (16 + 2) * 8
        np.testing.assert_array_equal(keys, [_U(_key(seed, d, _TAG_SOBOL_SET)) for d in range(len(keys))])


def test_the_shipped_kernel_has_no_timing_code(fast_settings, monkeypatch):
    """The measurement mode (core.fused_path.TIMED, lab/fused_timing.py) is compiled out of the shipped kernel: the
    counters past the 4th, where it would add cycles, stay zero while the ray counts before them grow."""
    from monte.core import fused_path, fused_tracer

    assert fused_path.TIMED is False
    seen = []
    shipped = fused_tracer.trace_paths

    def spy(*args):
        shipped(*args)
        seen.append(args[list(fused_path.trace_paths.py_func.__code__.co_varnames).index("counters")].copy())

    monkeypatch.setattr(fused_tracer, "trace_paths", spy)
    _render(_scene("cornell"), fast_settings(spp=2, threads=1), monkeypatch, fused=True)
    assert seen and all(len(c) == fused_path.COUNTERS for c in seen)
    total = np.sum(seen, axis=0)
    assert total[2] > 0 and total[3] > 0  # closest-hit and shadow rays were traced and counted
    assert not np.any(total[fused_path.TIMING_FIRST:])


def test_the_fused_kernel_applies_the_shadow_terminator_offset_as_the_per_bounce_integrator(fast_settings,
                                                                                           monkeypatch):
    """Blender's objects carry a shadow terminator offset (Geometry Offset, 0.1 by default), so every exported
    scene with smooth-shaded meshes has one: the fused kernel lifts shadow-ray origins as
    core.path_kernels.shadow_rays does, and the image equals the per-bounce integrator's."""
    # 48x48: the lift changes only the few pixels whose shadow rays leave a facet near the terminator (at 24x24 and
    # 8 spp the 2-group Sobol pattern happens to put no sample on one)
    scene = _scene("spheres_under_sky", 48)
    smooth = [m for m in scene.meshes if m.normals is not None]
    assert smooth  # the spheres are smooth-shaded (and not only delta-scattering): the offset applies to them
    settings = fast_settings(spp=8, threads=1)
    plain = _render(scene, settings, monkeypatch, fused=True)
    for m in smooth:
        m.shadow_terminator_offset = 0.5
    monkeypatch.setenv(FUSED_ENV, "1")
    assert supports(_tracer(scene, settings)) is None
    old = _render(scene, settings, monkeypatch, fused=False)
    new = _render(scene, settings, monkeypatch, fused=True)
    assert new.stats["fused_kernel"] and not old.stats["fused_kernel"]
    np.testing.assert_allclose(new.color[..., :3], old.color[..., :3], rtol=1e-4, atol=1e-6)
    assert not np.array_equal(new.color, plain.color)  # the offset changed the image: the lift ran
