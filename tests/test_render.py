"""End-to-end renderer tests against closed forms, with tolerances from the renderer's own variance estimate."""

import math

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import metrics
from monte.core.render import render
from monte.core.scene import Lobe, Material, Mesh, SceneError
from monte.core.shading.program import OBJECT_COLUMNS

Z = 4.0  # tolerance in standard errors of the image mean


def image_mean_and_sigma(result):
    return metrics.channel_means(result.color), metrics.channel_mean_sigma(result.variance)


DETECT = 0.01  # every closed-form mean check must see a 1 % error (its own control, in assert_mean)


def assert_mean(result, expected, rel_floor=0.0):
    mean, sigma = image_mean_and_sigma(result)
    tol = np.maximum(Z * sigma, rel_floor * np.abs(expected)) + 1e-6
    assert np.all(np.abs(mean - expected) <= tol), f"mean {mean} vs expected {expected} (tolerance {tol})"
    # The control: an expectation 1 % off must fail, both ways (so the render has the samples to resolve 1 %).
    for wrong in (1 + DETECT, 1 - DETECT):
        assert np.any(np.abs(mean - wrong * np.asarray(expected)) > tol), (
            f"a {100 * DETECT:g} % error would pass: tolerance {tol / np.abs(expected)} (relative)")
    return mean, sigma


@pytest.mark.parametrize("bounces", [0, 3, 16])
def test_furnace_matches_bounce_limited_closed_form(fast_settings, bounces):
    a, le = 0.5, 1.0
    result = render(scenes.furnace((16, 16), albedo=a, emission=le), fast_settings(spp=32, max_bounces=bounces))
    expected = le * (1 - a ** (bounces + 2)) / (1 - a)
    mean, sigma = assert_mean(result, np.full(3, expected))
    assert result.stats["nonfinite_samples"] == 0


def test_furnace_high_albedo_converges_to_le_over_one_minus_albedo(fast_settings):
    a = 0.8
    # 512 spp: long paths (mean length 5 bounces) are noisy; 4 sigma is then ~0.5 %, so a 1 % error fails
    result = render(scenes.furnace((16, 16), albedo=a, emission=1.0), fast_settings(spp=512, max_bounces=64))
    expected = (1 - a**66) / (1 - a)
    assert_mean(result, np.full(3, expected))


def test_directly_seen_emitter_is_exact(fast_settings):
    # Albedo 0: every camera ray sees the emitter and nothing else, so every sample is exactly Le.
    result = render(scenes.furnace((8, 8), albedo=0.0, emission=3.0), fast_settings(spp=4))
    np.testing.assert_allclose(result.color[..., :3], 3.0, rtol=0, atol=1e-6)
    np.testing.assert_allclose(result.variance, 0.0, atol=1e-12)
    np.testing.assert_allclose(result.color[..., 3], 1.0)


def test_diffuse_plane_under_uniform_world(fast_settings):
    result = render(scenes.plane_under_world((16, 16), albedo=0.8, world=1.5), fast_settings(spp=32))
    assert_mean(result, np.full(3, 0.8 * 1.5))


def test_point_light_in_diffuse_sphere(fast_settings):
    rho, power = 0.5, 100.0
    # 128 spp: 4 sigma ~0.6 %, so a 1 % error fails
    result = render(scenes.point_in_sphere((16, 16), albedo=rho, power=power), fast_settings(spp=128, max_bounces=64))
    expected = rho * power / (4 * math.pi**2 * (1 - rho))
    # The icosphere's flat faces sit up to 0.1% inside the unit sphere: allow 0.5% beside the noise.
    assert_mean(result, np.full(3, expected), rel_floor=0.005)


MIS_DETECT = 0.06  # the smallest difference between two estimators that the agreement test below must see


def test_mis_light_only_and_bsdf_only_agree(fast_settings):
    """BSDF-sampling-only, light-sampling-only and MIS estimators are all unbiased: same mean within noise."""
    scene_res = (24, 24)
    means, sigmas = {}, {}
    # 128 spp: light-only NEE is heavy-tailed near the lamp, and at 64 spp its sample sigma under-estimates the spread.
    for mode in ("mis", "light", "bsdf"):
        r = render(scenes.cornell_diffuse(scene_res), fast_settings(spp=128, light_sampling=mode, max_bounces=4))
        means[mode], sigmas[mode] = image_mean_and_sigma(r)
    for a, b in (("mis", "light"), ("mis", "bsdf"), ("light", "bsdf")):
        tol = Z * np.hypot(sigmas[a], sigmas[b])
        assert np.all(np.abs(means[a] - means[b]) <= tol), f"{a} {means[a]} vs {b} {means[b]} (tol {tol})"
        # Its power: BSDF-only sampling of a small lamp is noisy, so this resolves MIS_DETECT (measured 4 sigma:
        # 2.5 % mis/light, 4.5-5 % with bsdf); an estimator that far off must fail.
        for wrong in (1 + MIS_DETECT, 1 - MIS_DETECT):
            assert np.any(np.abs(wrong * means[a] - means[b]) > tol), f"{a} vs {b}: a {MIS_DETECT:.0%} error passes"
    # MIS should not be noisier than BSDF sampling alone on a scene lit by a small lamp.
    assert np.all(sigmas["mis"] < sigmas["bsdf"])


def _two_corner_lights_scene(resolution):
    """A floor seen from above with an area light low over its left side, a sphere light over its right side,
    a small emissive ball (many triangles: several selection groups) at the back, a rough glass ball (a
    transmitting material) and a sky: the per-point light selection changes strongly across the image."""
    from monte.core.scene import AreaLight, Camera, PointLight, Scene, World

    materials = [Material("floor", [Lobe("diffuse", np.full(3, 0.7))]),
                 Material("glow", [Lobe("diffuse", np.zeros(3))], emission=np.full(3, 4.0)),
                 Material("rough glass", [Lobe("glass", np.full(3, 0.95), roughness=0.4, ior=1.5)])]
    meshes = [scenes.quad("floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], 0),
              scenes.icosphere("glow", (0.0, 1.3, 0.25), 0.2, 1),
              scenes.icosphere("glass", (0.0, -0.6, 0.35), 0.35, 2)]
    m = np.eye(4)
    m[:3, 3] = (-1.3, 0.0, 0.4)  # faces down (-Z)
    area = AreaLight("low", m, np.full(3, 15.0), "SQUARE", 0.5)
    lamp = PointLight("lamp", np.array([1.3, 0.0, 0.6]), np.full(3, 25.0), radius=0.25)
    camera = Camera.look_at((0, 0, 4.5), (0, 0, 0), up=(0, 1, 0), horizontal_fov=math.radians(50.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=[area, lamp],
                 world=World(np.full(3, 0.05)), name="two-lights")


def test_per_point_light_selection_is_unbiased_across_the_image(fast_settings):
    """MIS, light-only and BSDF-only estimators agree on each half of an image whose light selection changes
    strongly from the left half (area light) to the right (sphere light); MIS must use the same per-point
    selection probability when a BSDF ray hits a light as when the light was sampled."""
    scene = _two_corner_lights_scene((24, 24))
    from monte.core.integrator import PreparedScene

    ps = PreparedScene.build(scene.validate())
    probs = ps.lights.selection_probabilities(np.array([[-1.3, 0, 0], [1.3, 0, 0]]) - ps.shift,
                                              np.array([[0, 0, 1.0], [0, 0, 1.0]]), [False, False])
    assert probs["area 0"][0] > 0.6 and probs["area 0"][1] < 0.2  # the selection does change across the image
    halves = {}
    for mode in ("mis", "light", "bsdf"):
        r = render(scene, fast_settings(spp=128, light_sampling=mode, max_bounces=3))
        halves[mode] = [image_mean_and_sigma_of(r, cols) for cols in (slice(0, 12), slice(12, 24))]
    for a, b in (("mis", "light"), ("mis", "bsdf"), ("light", "bsdf")):
        for h in range(2):
            (ma, sa), (mb, sb) = halves[a][h], halves[b][h]
            tol = Z * np.hypot(sa, sb)
            assert np.all(np.abs(ma - mb) <= tol), f"half {h}: {a} {ma} vs {b} {mb} (tol {tol})"
            # the control: what this comparison can see (see SELECTION_SCENE_LIGHTS' comment) must fail
            error = 0.15 if "bsdf" in (a, b) else 0.04
            for wrong in (1 + error, 1 - error):
                assert np.any(np.abs(wrong * ma - mb) > Z * np.hypot(wrong * sa, sb)), (a, b, h, wrong)


# The estimator comparison above resolves what the noise of its weakest estimator allows (BSDF-only, ~1.8 % per
# half at 128 spp): its control below shows 4 % between MIS and light-only and 15 % against BSDF-only. The 1 %
# check of the per-point selection in a render is against a closed form: a floor lit directly by two square
# lights whose selection changes from ~9:1 to ~1:4 across the image.
SELECTION_SCENE_LIGHTS = ((-1.0, 0.5, 0.4, 40.0), (1.0, 1.5, 0.8, 10.0))  # (x, height, side, radiance)


def _selection_floor_scene(resolution):
    """A 1e4 m diffuse floor (albedo 0.5) seen straight down from 3 m (50 degrees), lit only by two square area
    lights facing down (lights are invisible to camera rays and cast no shadow), world black."""
    from monte.core.scene import AreaLight, Camera, Scene, World

    lights = []
    for k, (x, h, side, radiance) in enumerate(SELECTION_SCENE_LIGHTS):
        m = np.eye(4)
        m[:3, 3] = (x, 0.0, h)  # local -Z (the emitting side) points down
        lights.append(AreaLight(f"l{k}", m, np.full(3, radiance * math.pi * side * side), "SQUARE", side))
    floor = scenes.quad("floor", [(-5e3, -5e3, 0), (5e3, -5e3, 0), (5e3, 5e3, 0), (-5e3, 5e3, 0)], 0)
    camera = Camera.look_at((0, 0, 3.0), (0, 0, 0), up=(0, 1, 0), horizontal_fov=math.radians(50.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=[floor], materials=[Material("floor", [Lobe("diffuse", np.full(3, 0.5))])],
                 lights=lights, world=World(np.zeros(3)), name="selection-floor")


def _selection_floor_half_means(n_quad=48):
    """Closed form of the two image halves' means (box filter: pixels tile the frame, and the frame maps affinely
    onto the floor): albedo / pi x irradiance (the form factors of parallel rectangles) averaged over each half
    of the floor's visible square, by Gauss-Legendre quadrature."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_lights import parallel_rect_irradiance

    half = 3.0 * math.tan(math.radians(25.0))
    g, w = np.polynomial.legendre.leggauss(n_quad)
    means = []
    for x0, x1 in ((-half, 0.0), (0.0, half)):
        xs, wx = 0.5 * (x1 - x0) * g + 0.5 * (x0 + x1), 0.5 * (x1 - x0) * w
        ys, wy = half * g, half * w
        total = 0.0
        for xi, wxi in zip(xs, wx):
            for yi, wyi in zip(ys, wy):
                e = sum(parallel_rect_irradiance(L, cx - s / 2 - xi, cx + s / 2 - xi, -s / 2 - yi, s / 2 - yi, h)
                        for cx, h, s, L in SELECTION_SCENE_LIGHTS)
                total += wxi * wyi * e
        means.append(0.5 / math.pi * total / ((x1 - x0) * 2 * half))
    return means


def test_per_point_light_selection_against_the_closed_form(fast_settings):
    """The per-point selection in a render: each half of the image against its closed form, with MIS and with
    light sampling alone, within 4 sigma; 1 % off must fail (the control; at 64 spp 4 sigma is 0.25-0.35 %)."""
    scene = _selection_floor_scene((24, 24))
    from monte.core.integrator import PreparedScene

    ps = PreparedScene.build(scene.validate())
    probs = ps.lights.selection_probabilities(np.array([[-1.0, 0, 0], [1.0, 0, 0]]) - ps.shift,
                                              np.array([[0, 0, 1.0], [0, 0, 1.0]]), [False, False])
    assert probs["area 0"][0] > 0.8 and probs["area 0"][1] < 0.3  # the selection changes strongly across it
    expected = _selection_floor_half_means()
    for mode in ("mis", "light"):
        r = render(scene, fast_settings(spp=64, light_sampling=mode, max_bounces=0))
        for h, cols in enumerate((slice(0, 12), slice(12, 24))):
            mean, sigma = image_mean_and_sigma_of(r, cols)
            tol = Z * sigma + 1e-5 * expected[h]
            print(f"{mode} half {h}: {mean[0]:.5f} vs {expected[h]:.5f} (tolerance {100 * tol[0] / expected[h]:.2f} %)")
            assert np.all(np.abs(mean - expected[h]) <= tol), (mode, h, mean, expected[h], tol)
            for wrong in (1 + DETECT, 1 - DETECT):
                assert np.any(np.abs(mean - wrong * expected[h]) > tol), (mode, h, wrong)


def image_mean_and_sigma_of(result, cols):
    return metrics.channel_means(result.color[:, cols]), metrics.channel_mean_sigma(result.variance[:, cols])


def test_same_seed_same_image_in_any_tile_order_or_thread_count(fast_settings):
    scene = scenes.cornell_box((24, 20))
    base = render(scene, fast_settings(spp=8, tile_size=8, threads=1))
    n_tiles = 3 * 3
    other = render(scenes.cornell_box((24, 20)), fast_settings(spp=8, tile_size=8, threads=2),
                   tile_order=list(reversed(range(n_tiles))))
    assert np.array_equal(base.color, other.color)
    assert np.array_equal(base.variance, other.variance)
    different = render(scenes.cornell_box((24, 20)), fast_settings(spp=8, tile_size=8, seed=2))
    assert not np.array_equal(base.color, different.color)


def test_more_samples_refine_the_same_image(fast_settings):
    """Samples are a pure function of their index: a render in several batches equals one in a single batch."""
    one = render(scenes.cornell_box((16, 16)), fast_settings(spp=8, batch_paths=1 << 16))
    many = render(scenes.cornell_box((16, 16)), fast_settings(spp=8, batch_paths=1024))
    np.testing.assert_allclose(one.color, many.color, rtol=1e-5, atol=1e-6)


def test_region_renders_the_same_pixels_as_the_full_frame(fast_settings):
    full = render(scenes.cornell_box((24, 24)), fast_settings(spp=4))
    part = render(scenes.cornell_box((24, 24)), fast_settings(spp=4), region=(5, 7, 10, 9))
    np.testing.assert_allclose(part.color, full.color[7:16, 5:15], rtol=1e-5, atol=1e-6)


def test_cancel_returns_a_valid_partial_image(fast_settings):
    calls = {"n": 0}

    def cancel_after_two():
        calls["n"] += 1
        return calls["n"] > 2

    # batch_paths 1024: 8 batches, so that a cancel after two polls leaves some and misses others
    result = render(scenes.cornell_box((32, 32)), fast_settings(spp=8, tile_size=8, batch_paths=1024),
                    should_cancel=cancel_after_two)
    assert result.cancelled
    assert np.all(np.isfinite(result.color))
    done = result.sample_count > 0
    assert 0 < done.sum() < done.size
    assert np.all(result.color[~done][..., :3] == 0)


def test_tiles_and_progress_are_reported(fast_settings):
    tiles, progress = [], []
    render(scenes.cornell_box((20, 12)), fast_settings(spp=2, tile_size=8), on_tile=tiles.append,
           on_progress=progress.append)
    assert len(tiles) == 3 * 2
    assert sum(t.width * t.height for t in tiles) == 20 * 12
    assert progress[-1].fraction == pytest.approx(1.0)
    assert all(b.fraction >= a.fraction for a, b in zip(progress, progress[1:]))


def test_zero_samples_gives_a_black_valid_image(fast_settings):
    result = render(scenes.cornell_box((4, 4)), fast_settings(spp=0))
    assert result.color.shape == (4, 4, 4)
    assert np.all(result.color[..., :3] == 0)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(spp=-1), "samples per pixel"),
        (dict(filter_width=0.0), "filter width"),
        (dict(sampler="magic"), "unknown sampler"),
        (dict(max_bounces=-2), "max bounces"),
        (dict(clamp=float("nan")), "clamp"),
    ],
)
def test_absurd_settings_raise_clear_errors(fast_settings, change, message):
    with pytest.raises(ValueError, match=message):
        render(scenes.cornell_box((4, 4)), fast_settings(**change))


def test_zero_resolution_is_rejected(fast_settings):
    with pytest.raises(SceneError, match="resolution"):
        render(scenes.cornell_box((0, 4)), fast_settings())


def test_bad_geometry_is_dropped_with_counted_warnings(fast_settings):
    scene = scenes.plane_under_world((8, 8))
    v = np.array([[0, 0, 0.5], [1, 0, 0.5], [np.nan, 1, 0.5], [2, 0, 0.5], [3, 0, 0.5], [4, 0, 0.5]])
    scene.meshes.append(Mesh("junk", v, np.array([[0, 1, 2], [3, 4, 5], [0, 0, 1]]), 0))
    result = render(scene, fast_settings(spp=4))
    text = " ".join(result.warnings)
    assert "mesh 'junk': dropped 1 triangles with NaN/Inf" in text
    assert "mesh 'junk': dropped 2 zero-area (degenerate) triangles" in text
    assert np.all(np.isfinite(result.color))


def test_checked_meshes_skip_their_triangle_checks_unless_their_object_indices_do_not_fit():
    """Scene.validate(checked_meshes): a mesh named there keeps what a check would drop (its triangles are not
    examined again), the other meshes are checked; a named mesh whose object indices leave the object table is
    checked in full and refused with the usual error."""
    def scene_with_junk():
        scene = scenes.plane_under_world((8, 8))
        v = np.array([[0, 0, 0.5], [1, 0, 0.5], [0, 1, 0.5]], np.float64)
        junk = Mesh("junk", v, np.array([[0, 1, 2], [0, 0, 1]], np.int32), 0)  # the second is degenerate
        scene.meshes.append(junk)
        scene.objects = np.zeros((2, OBJECT_COLUMNS), np.float32)
        for mesh in scene.meshes:
            mesh.object_index = np.zeros(len(mesh.triangles), np.int32)
        return scene, junk

    scene, junk = scene_with_junk()
    scene.validate(checked_meshes={id(junk)})
    assert len(junk.triangles) == 2 and not any("junk" in w for w in scene.warnings)
    scene, junk = scene_with_junk()
    scene.validate()  # the control: unnamed, the degenerate triangle is dropped
    assert len(junk.triangles) == 1 and "mesh 'junk': dropped 1 zero-area (degenerate) triangles" in scene.warnings

    scene, junk = scene_with_junk()
    junk.object_index = np.array([0, 2], np.int32)  # row 2 of a 2-row object table
    with pytest.raises(SceneError, match=r"mesh 'junk': object index out of range \[0, 1\]: min 0, max 2"):
        scene.validate(checked_meshes={id(junk)})


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda s: setattr(s.meshes[0], "triangles", np.array([[0, 1, 9]])), "vertex index out of range"),
        (lambda s: setattr(s.meshes[0], "material_index", 5), "material index out of range"),
        (lambda s: setattr(s.materials[0], "emission", np.array([-1.0, 0, 0])), "negative colour"),
        (lambda s: s.materials.clear(), "no materials"),
        (lambda s: s.materials[0].lobes.append(Lobe("glossy", np.ones(3), roughness=2.0)), "roughness"),
        (lambda s: setattr(s.camera, "lens", 0.0), "lens"),
    ],
)
def test_invalid_scene_raises_scene_error(fast_settings, mutate, message):
    scene = scenes.plane_under_world((4, 4))
    mutate(scene)
    with pytest.raises(SceneError, match=message):
        render(scene, fast_settings(spp=1))


def test_aovs_first_hit(fast_settings):
    result = render(scenes.plane_under_world((8, 8), albedo=0.8), fast_settings(spp=4))
    np.testing.assert_allclose(result.albedo, 0.8, atol=1e-5)
    np.testing.assert_allclose(result.normal, np.broadcast_to([0, 0, 1], result.normal.shape), atol=1e-5)
    # The camera looks straight down from height 1: z-depth 1 everywhere.
    np.testing.assert_allclose(result.depth, 1.0, atol=1e-4)


def test_cornell_box_matches_cycles_channel_means():
    """The seed's Cornell box against the converged Cycles reference (0.3949, 0.3312, 0.3970), BH 1.5 px."""
    from monte.core.settings import RenderSettings

    settings = RenderSettings(spp=128, seed=3, threads=2, filter_type="blackman-harris", filter_width=1.5,
                              max_bounces=16)
    result = render(scenes.cornell_box((96, 96)), settings)
    expected = np.array([0.39494, 0.33119, 0.39700])
    mean, sigma = image_mean_and_sigma(result)
    # 128 spp: 4 sigma + 0.2 % (the reference's own precision, float32 film) ~0.7 %, so a 1 % error fails
    tol = Z * sigma + 0.002 * expected
    print(f"tolerance {np.round(100 * tol / expected, 2)} %")
    assert np.all(np.abs(mean - expected) <= tol), f"{mean} vs Cycles {expected} (sigma {sigma})"
    for wrong in (1 + DETECT, 1 - DETECT):
        assert np.any(np.abs(mean - wrong * expected) > tol)
    assert result.stats["nonfinite_samples"] == 0


def test_adaptive_sampling_stops_converged_pixels_and_keeps_the_mean(fast_settings):
    """A plane under a uniform sky: sky pixels have zero variance and stop at the minimum sample count; the
    image mean stays within the noise of a full render; threshold 0 keeps every pixel at spp."""
    scene = scenes.plane_under_world((24, 24))
    full = render(scene, fast_settings(spp=64, tile_size=8))
    assert (full.sample_count == 64).all()
    adaptive = render(scenes.plane_under_world((24, 24)),
                      fast_settings(spp=64, tile_size=8, adaptive_threshold=0.05, adaptive_min_samples=8))
    counts = adaptive.sample_count
    assert counts.min() == 8 and counts.max() <= 64
    assert adaptive.stats["adaptive_pixels_converged"] > 0
    assert counts.sum() < full.sample_count.sum()
    # Pixels that stopped early: their estimated error is below the threshold (Cycles' metric).
    stopped = counts < 64
    mean = adaptive.color[..., :3]
    err = np.sqrt(adaptive.variance).sum(-1) / (1e-4 + np.sqrt(mean.sum(-1)))
    assert (err[stopped] < 0.05).mean() > 0.95  # dilation keeps a few below-threshold pixels running
    sigma = np.sqrt(full.variance.sum() + adaptive.variance.sum()) / full.variance[..., 0].size
    tol = 5 * sigma + 1e-6
    assert abs(full.color[..., :3].mean() - mean.mean()) < tol
    for wrong in (1 + DETECT, 1 - DETECT):  # a zero-variance scene: a 1 % error in the adaptive mean must fail
        assert abs(full.color[..., :3].mean() - wrong * mean.mean()) > tol


def test_adaptive_sampling_spends_samples_where_the_noise_is(fast_settings):
    """spheres-sky: the top rows see only the uniform sky and stop at the minimum; the ground under the spheres
    (shadows, indirect light) keeps sampling, so the mean count there is well above the sky's."""
    result = render(scenes.spheres_under_sky((48, 32)),
                    fast_settings(spp=64, tile_size=16, adaptive_threshold=0.1, adaptive_min_samples=8))
    counts = result.sample_count
    assert (counts[:4] == 8).all(), counts[:4]
    assert counts[20:].mean() > 2 * 8, counts[20:].mean()
    assert counts.max() == 64


def test_adaptive_settings_are_validated():
    from monte.core.settings import RenderSettings

    with pytest.raises(ValueError, match="adaptive threshold"):
        RenderSettings(adaptive_threshold=-0.1).validate()
    with pytest.raises(ValueError, match="adaptive min samples"):
        RenderSettings(adaptive_min_samples=-1).validate()
    assert RenderSettings(adaptive_threshold=0.01).adaptive_min_samples_for(1024) == 40
    assert RenderSettings(adaptive_threshold=0.01).adaptive_min_samples_for(20) == 20


def test_stats_break_time_into_stages_and_bound_batches(fast_settings, monkeypatch):
    monkeypatch.setenv("MONTE_FUSED", "0")  # the per-bounce integrator's stages (the fused kernel has none)
    result = render(scenes.cornell_box((32, 32)), fast_settings(spp=8, batch_paths=4096, threads=2))
    st = result.stats
    stages = st["stage_seconds"]
    assert set(stages) == {"camera", "intersect", "occluded", "emission", "nee", "scatter", "film"}
    assert all(v > 0 for v in stages.values())
    # Embree's share is of all worker thread-time, so it is a fraction whatever the thread count.
    assert 0 < st["embree_share"] < 1
    assert 0 < st["largest_batch"] <= 4096


def test_perf_command_reports_stages_and_unused_feature_cost(tmp_path):
    import json

    from monte.cli import main

    out = tmp_path / "perf.json"
    assert main(["perf", "--sections", "stages", "skip", "--resolution", "16", "--spp", "2", "--repeat", "1",
                 "--threads", "1", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert sum(report["stages"]["stage_share"].values()) == pytest.approx(1.0)
    assert report["skip"]["seconds_plain"] > 0 and report["skip"]["seconds_unused_glass"] > 0


_TRACE_ONE_RAY = """
import sys
sys.path.insert(0, {path!r})
if {package!r} != "monte":
    sys.modules["monte"] = None  # as in Blender, where a linked checkout is importable only as bl_ext.<repo>.monte
import numpy as np
from {package}.core import jit_cache
from {package}.core.accel import Accelerator
accel = Accelerator(np.array([[0, 0, 1], [2, 0, 1], [0, 2, 1]], np.float32), np.array([[0, 1, 2]], np.int32))
hits = accel.intersect(np.array([[0.5, 0.5, 0]], np.float32), np.array([[0, 0, 1]], np.float32))
print("HIT", int(hits.prim[0]), float(hits.t[0]), jit_cache.cache_dir())
"""


def test_kernel_caches_are_kept_apart_per_import_name(tmp_path):
    """numba's cache records the kernel module's import name: a cache written while the package was imported
    as monte and read under another name where monte is not importable (an alias here, as Blender's
    bl_ext.<repo>.monte for a checkout linked into its extensions folder) used to fail with ModuleNotFoundError.
    Each name now has its own folder (core.jit_cache)."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    import monte

    root = Path(monte.__file__).resolve().parent
    (tmp_path / "montealias").symlink_to(root, target_is_directory=True)
    alias_cache = root / "core" / "__pycache__" / "numba-montealias.core"
    try:
        runs = {}
        for package in ("monte", "montealias"):  # monte's cache exists (written now if not before), then the alias
            code = _TRACE_ONE_RAY.format(path=str(tmp_path), package=package)
            proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                                  cwd=str(tmp_path))
            assert proc.returncode == 0, proc.stderr[-3000:]
            runs[package] = proc.stdout.split("HIT ")[-1].split()
        for prim, t, _ in runs.values():
            assert prim == "0" and abs(float(t) - 1.0) < 1e-6
        assert runs["montealias"][2].endswith("numba-montealias.core") and runs["monte"][2].endswith("numba-monte.core")
        assert list(alias_cache.glob("embree.trace_closest-*.nbi"))
    finally:
        shutil.rmtree(alias_cache, ignore_errors=True)


def test_kernel_cache_is_warm_after_a_render(fast_settings):
    """After any render the compiled kernels are cached on disk, so the 'compiling' notice is not shown again."""
    from monte.core.jit_cache import compile_cache_is_cold

    messages = []
    render(scenes.plane_under_world((8, 8)), fast_settings(spp=1), log=messages.append)
    assert not compile_cache_is_cold()
    messages.clear()
    render(scenes.plane_under_world((8, 8)), fast_settings(spp=1), log=messages.append)
    assert not any(m.startswith("compiling") for m in messages), messages
