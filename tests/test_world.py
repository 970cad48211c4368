"""The environment-map world (core.world): its distribution against closed forms and renders against exact
integrals of the map, without Blender (the Cycles cross-checks are in tests/test_world_cycles.py)."""

import math
import re

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import metrics
from monte.core.render import render
from monte.core.scene import SceneError, World
from monte.core.world import EnvironmentDistribution, EnvironmentMap

Z = 4.0  # tolerance in standard errors


def _sun_map(w=64, h=32, seed=0):
    """A smooth random sky, brighter at the zenith, with a small sun 2000x brighter than the sky (row 0 at the
    top)."""
    rng = np.random.default_rng(seed)
    px = (0.2 + 0.8 * rng.random((h, w, 3))).astype(np.float32)
    px[: h // 2] *= 2.0
    px[h // 4, 3 * w // 8] = (3000.0, 2500.0, 2000.0)
    return px


def _fine_grid(nu, nv):
    """Midpoint directions of an nu x nv equirectangular grid over the sphere, and their solid angles."""
    u = (np.arange(nu) + 0.5) / nu
    v = (np.arange(nv) + 0.5) / nv
    uu, vv = np.meshgrid(u, v)
    phi = math.pi - 2 * math.pi * uu
    el = math.pi * (vv - 0.5)
    d = np.stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)], axis=-1).reshape(-1, 3)
    # exact solid angle of each cell
    el0 = math.pi * (np.arange(nv) / nv - 0.5)
    el1 = math.pi * ((np.arange(nv) + 1) / nv - 0.5)
    dw = (2 * math.pi / nu) * (np.sin(el1) - np.sin(el0))
    return d, np.repeat(dw, nu), uu.reshape(-1), vv.reshape(-1)


@pytest.mark.parametrize("projection,rotate", [("EQUIRECTANGULAR", False), ("EQUIRECTANGULAR", True),
                                               ("MIRROR_BALL", False)])
def test_pdf_integrates_to_one_over_the_sphere(projection, rotate):
    m = np.eye(3)
    if rotate:
        c, s = math.cos(0.7), math.sin(0.7)
        m = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    env = EnvironmentMap(_sun_map(), projection=projection, matrix=m, map_resolution=32)
    env.validate([])
    dist = EnvironmentDistribution(env)
    # the pdf is piecewise constant over the 32 x 16 grid divided by cos(elevation): a 16x finer grid of midpoints
    # integrates each cell's cos to 1e-5 (exact would need the cell's sine difference)
    d, dw, _, _ = _fine_grid(512, 256)
    total = float((dist.pdf(d) * dw).sum())
    assert abs(total - 1.0) < 1e-4, total


def test_sampled_directions_follow_the_pdf_chi_square():
    """Pearson's chi-square over 24 x 12 equal-angle bins with 200k samples at the 99.9 % quantile; its power:
    the same samples with 3 % of the upper hemisphere's mirrored below the horizon must be rejected."""
    env = EnvironmentMap(_sun_map(), map_resolution=48)
    env.validate([])
    dist = EnvironmentDistribution(env)
    n = 200_000
    rng = np.random.default_rng(5)
    d, pdf = dist.sample(rng.random((n, 2)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(pdf, dist.pdf(d), rtol=1e-9)  # sample and pdf agree point by point
    bu, bv = 24, 12
    fine_d, fine_dw, fu, fv = _fine_grid(bu * 16, bv * 16)
    cell = (np.minimum((fv * bv).astype(int), bv - 1) * bu + np.minimum((fu * bu).astype(int), bu - 1))
    expected_p = np.bincount(cell, weights=dist.pdf(fine_d) * fine_dw, minlength=bu * bv)

    def chi2(dirs):
        u = 0.5 - np.arctan2(dirs[:, 1], dirs[:, 0]) / (2 * math.pi)
        v = 0.5 + np.arcsin(np.clip(dirs[:, 2], -1, 1)) / math.pi
        b = np.minimum((v * bv).astype(int), bv - 1) * bu + np.minimum((u * bu).astype(int), bu - 1)
        obs = np.bincount(b, minlength=bu * bv)
        exp = expected_p * len(dirs)
        keep = exp > 5
        return float(((obs[keep] - exp[keep]) ** 2 / exp[keep]).sum()), int(keep.sum()) - 1

    stat, dof = chi2(d)
    # 99.9 % quantile of chi-square (Wilson-Hilferty): a correct sampler fails 1 run in 1000
    z = 3.09
    limit = dof * (1 - 2 / (9 * dof) + z * math.sqrt(2 / (9 * dof))) ** 3
    assert stat < limit, (stat, limit)
    # power: 3 % of the upper hemisphere's samples mirrored below the horizon are rejected
    tilt = rng.random(n) < 0.03 * (d[:, 2] > 0)
    wrong = d.copy()
    wrong[tilt, 2] *= -1.0
    assert chi2(wrong)[0] > limit


def test_estimate_of_the_map_integral_is_unbiased():
    """E[L(d) / pdf(d)] over light samples = the integral of L over the sphere (fine-grid quadrature)."""
    env = EnvironmentMap(_sun_map(), interpolation="LINEAR", map_resolution=64)
    env.validate([])
    dist = EnvironmentDistribution(env)
    fine_d, fine_dw, _, _ = _fine_grid(1024, 512)
    exact = (dist.radiance(fine_d) * fine_dw[:, None]).sum(axis=0)
    rng = np.random.default_rng(2)
    d, pdf = dist.sample(rng.random((400_000, 2)))
    est = dist.radiance(d) / pdf[:, None]
    mean, se = est.mean(axis=0), est.std(axis=0) / math.sqrt(len(est))
    assert np.all(np.abs(mean - exact) < Z * se + 2e-3 * exact), (mean, exact, se)
    assert np.all(se < 0.0025 * exact)  # importance sampling: the sun costs little variance (measured 0.14 %)


def _plane_scene(world, resolution=(16, 16)):
    scene = scenes.plane_under_world(resolution, albedo=0.8, world=1.0)
    scene.world = world
    return scene.validate()


def _banded_map(h=16, w=32):
    """Rows of constant radiance (row 0 at the top) and a sun patch: with Closest interpolation the irradiance
    on an upward plane is an exact sum."""
    rows = np.linspace(3.0, 0.5, h)
    px = np.repeat(rows[:, None, None], w, axis=1).repeat(3, axis=2).astype(np.float32)
    px[..., 1] *= 0.8
    px[3, 5] = (400.0, 300.0, 200.0)
    return px


def _upward_irradiance(px):
    """Exact irradiance on an upward surface from a Closest-interpolated equirectangular map: each texel (row r
    from the top) covers elevations [el0, el1], azimuth 2 pi / W, and contributes L x dphi x (sin^2 el1 -
    sin^2 el0) / 2 (cos theta = sin el) above the horizon."""
    h, w = px.shape[:2]
    el1 = math.pi * (0.5 - np.arange(h) / h)
    el0 = math.pi * (0.5 - (np.arange(h) + 1) / h)
    up = el0 >= 0
    wgt = (2 * math.pi / w) * (np.sin(el1) ** 2 - np.sin(el0) ** 2) / 2
    return (px[up] * wgt[up, None, None]).sum(axis=(0, 1))


@pytest.mark.parametrize("mode", ["mis", "light", "bsdf"])
def test_diffuse_plane_under_a_map_matches_the_exact_integral(fast_settings, mode):
    px = _banded_map()
    env = EnvironmentMap(px, interpolation="CLOSEST", map_resolution=32)
    result = render(_plane_scene(World(environment=env)), fast_settings(spp=128, light_sampling=mode, max_bounces=1))
    expected = 0.8 * _upward_irradiance(px) / math.pi
    mean = metrics.channel_means(result.color)
    sigma = metrics.channel_mean_sigma(result.variance)
    tol = Z * sigma
    assert np.all(np.abs(mean - expected) <= tol), (mode, mean, expected, tol)
    if mode != "bsdf":  # the sun makes BSDF sampling alone noisy; the sampled estimators resolve 1 %
        assert np.all(tol < 0.01 * expected), (mode, tol / expected)


@pytest.mark.parametrize("mode", ["mis", "light"])
def test_map_without_importance_sampling_stays_unbiased(fast_settings, mode):
    """Cycles' sampling method None: BSDF sampling alone finds the map (MIS weight 1); the light-sampling-only
    estimator still samples it (nothing else would). Both keep the exact mean."""
    px = _banded_map()
    env = EnvironmentMap(px, interpolation="CLOSEST", importance_sampling=False)
    result = render(_plane_scene(World(environment=env)), fast_settings(spp=512, light_sampling=mode, max_bounces=1))
    expected = 0.8 * _upward_irradiance(px) / math.pi
    mean, sigma = metrics.channel_means(result.color), metrics.channel_mean_sigma(result.variance)
    assert np.all(np.abs(mean - expected) <= Z * sigma), (mode, mean, expected, sigma)
    assert np.all(Z * sigma < 0.05 * expected), Z * sigma / expected  # BSDF sampling finds the sun by chance: 3.5 %


def test_constant_map_renders_the_white_furnace_like_the_uniform_world(fast_settings):
    """A constant map of radiance 1.5 is the uniform world 1.5: same mean (the uniform world's plane is exact,
    0.8 x 1.5, with zero variance), and the map world's own estimate agrees within noise at 1 %."""
    uniform = render(_plane_scene(World(np.full(3, 1.5))), fast_settings(spp=16))
    np.testing.assert_allclose(uniform.color[..., :3], 1.2, rtol=1e-5)
    env = EnvironmentMap(np.full((8, 16, 3), 1.5, np.float32))
    mapped = render(_plane_scene(World(environment=env)), fast_settings(spp=64))
    mean, sigma = metrics.channel_means(mapped.color), metrics.channel_mean_sigma(mapped.variance)
    assert np.all(np.abs(mean - 1.2) <= Z * sigma + 1e-6) and np.all(Z * sigma < 0.012), (mean, sigma)


def test_camera_rays_see_the_map_in_the_lookup_direction(fast_settings):
    """An empty scene: each pixel is the map in its camera ray's direction (box filter, pixel-centre rays
    averaged); looking straight down (-z) a map whose lower half is 2 and upper half 5 gives 2."""
    px = np.full((8, 16, 3), 5.0, np.float32)
    px[4:] = 2.0
    env = EnvironmentMap(px, interpolation="CLOSEST")
    scene = _plane_scene(World(environment=env), resolution=(4, 4))
    scene.meshes = []
    result = render(scene, fast_settings(spp=4))
    np.testing.assert_allclose(result.color[..., :3], 2.0, rtol=1e-6)


def test_bad_texels_are_clamped_with_a_counted_warning(fast_settings):
    px = np.ones((4, 8, 3), np.float32)
    px[0, 0, 0] = np.nan
    px[1, 1] = (-1.0, np.inf, 2.0)
    scene = _plane_scene(World(environment=EnvironmentMap(px, name="W/sky.exr")))
    assert scene.warnings == ["environment 'W/sky.exr': 3 texel channel value(s) NaN, infinite or negative "
                              "clamped to 0"]
    assert np.all(np.isfinite(scene.world.environment.pixels)) and scene.world.environment.pixels.min() == 0
    dist = EnvironmentDistribution(scene.world.environment)
    assert np.all(np.isfinite(dist.tables[2])) and abs(dist.tables[3][-1] - 1.0) < 1e-12


@pytest.mark.parametrize("change,message", [
    (dict(pixels=np.ones((4, 8), np.float32)), "pixels must be (H, W, 3)"),
    (dict(projection="CUBE"), "unknown projection 'CUBE'"),
    (dict(interpolation="Smart"), "unknown interpolation 'Smart'"),
])
def test_bad_maps_raise_scene_errors(change, message):
    kw = dict(pixels=np.ones((4, 8, 3), np.float32), name="W/sky")
    kw.update(change)
    scene = scenes.plane_under_world((4, 4))
    scene.world = World(environment=EnvironmentMap(**kw))
    with pytest.raises(SceneError, match=re.escape(message)):
        scene.validate()


def test_map_memory_is_counted():
    from monte.core.memory import estimate_render_memory
    from monte.core.settings import RenderSettings

    scene = scenes.plane_under_world((8, 8))
    before = estimate_render_memory(scene, RenderSettings(spp=1)).scene
    scene.world = World(environment=EnvironmentMap(np.ones((256, 512, 3), np.float32), map_resolution=128))
    after = estimate_render_memory(scene, RenderSettings(spp=1)).scene
    assert after - before == 256 * 512 * 12 + 2 * 8 * 128 * 64


@pytest.mark.parametrize("projection, map_resolution", [("EQUIRECTANGULAR", 0), ("MIRROR_BALL", 200)])
def test_importance_grid_shared_by_threads_is_the_same_bits(projection, map_resolution):
    """The importance grid's rows split between threads (core.world.importance_luminance): every table the same
    bits as one thread's, for any count (more threads than GRID_ROWS_PER_THREAD allows: fewer parts)."""
    from monte.core.world import GRID_ROWS_PER_THREAD

    env = EnvironmentMap(_sun_map(256, 128, seed=3), projection=projection, map_resolution=map_resolution)
    env.validate([])
    one = EnvironmentDistribution(env)
    assert env.importance_resolution[1] >= 3 * GRID_ROWS_PER_THREAD  # so 2 and 3 threads do split it
    for threads in (2, 3, 64):
        many = EnvironmentDistribution(env, threads=threads)
        assert many.mean_luminance == one.mean_luminance
        for a, b in zip(one.tables, many.tables):
            assert a.tobytes() == b.tobytes()


def test_importance_grid_rows_from_row0():
    """importance_grid(..., row0, out) fills out's rows as rows row0.. of the whole grid."""
    from monte.core import world_kernels
    from monte.core.world import importance_luminance

    env = EnvironmentMap(_sun_map(64, 32, seed=4))
    env.validate([])
    pix, par = EnvironmentDistribution(env).tables[:2]
    whole = importance_luminance(pix, par, 64, 32, 2)
    part = np.full((5, 64), np.nan)
    world_kernels.importance_grid(pix, par, 64, 32, 2, 20, part)
    assert part.tobytes() == whole[20:25].tobytes()
    assert np.all(whole > 0)
