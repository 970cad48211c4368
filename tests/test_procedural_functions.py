"""The procedural textures' analytic values and bad-input errors (no Blender; the per-pixel agreement with Cycles
is tests/test_procedural_textures.py)."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.shading import procedural as tex


def grid(n=9, lo=-2.0, hi=2.0, z=0.0, w=0.0):
    x, y = np.meshgrid(np.linspace(lo, hi, n), np.linspace(lo, hi, n))
    return np.stack([x.ravel(), y.ravel(), np.full(n * n, z), np.full(n * n, w)], axis=1).astype(np.float32)


def test_gradient_types_follow_their_formulas():
    co = grid(11, -1.5, 1.5, z=0.25)
    x, y, z = co[:, 0].astype(np.float64), co[:, 1].astype(np.float64), co[:, 2].astype(np.float64)
    r = np.maximum(0.999999 - np.sqrt(x * x + y * y + z * z), 0.0)
    expected = {"LINEAR": x, "QUADRATIC": np.maximum(x, 0) ** 2,
                "EASING": 3 * np.clip(x, 0, 1) ** 2 - 2 * np.clip(x, 0, 1) ** 3, "DIAGONAL": (x + y) / 2,
                "RADIAL": np.arctan2(y, x) / (2 * np.pi) + 0.5, "SPHERICAL": r, "QUADRATIC_SPHERE": r * r}
    for name, want in expected.items():
        np.testing.assert_allclose(tex.gradient(co, name), np.clip(want, 0, 1), atol=2e-7, err_msg=name)


def test_checker_alternates_between_cells():
    co = grid(8, 0.05, 3.95)  # two points a cell of a 4 x 4 checker at scale 1, z in cell 0
    fac, color = tex.checker(co, 1.0, (1, 0, 0), (0, 0, 1))
    parity = (np.floor(co[:, 0]) + np.floor(co[:, 1])) % 2 == 1  # Color1 where x and y cells differ in parity
    np.testing.assert_array_equal(fac, parity.astype(np.float32))
    np.testing.assert_array_equal(color[parity], np.tile([1, 0, 0], (parity.sum(), 1)))


def test_noise_vanishes_on_the_lattice():
    """Perlin noise is 0 at integer points, so one octave of normalized fBM is exactly 0.5 there, in every
    dimension; between lattice points it is not."""
    co = grid(5, -2.0, 2.0, z=3.0, w=-1.0)
    for dim in (1, 2, 3, 4):
        fac, _ = tex.noise(co, dim, scale=1.0, detail=0.0)
        np.testing.assert_array_equal(fac, 0.5)
        fac, _ = tex.noise(co + np.float32(0.37), dim, scale=1.0, detail=0.0)
        assert np.abs(fac - 0.5).max() > 0.01


def test_noise_fbm_normalized_stays_in_unit_range():
    co = (np.random.default_rng(3).random((4000, 4)) * 20 - 10).astype(np.float32)
    for dim in (1, 2, 3, 4):
        fac, color = tex.noise(co, dim, detail=6.5, roughness=0.7, distortion=0.8)
        assert 0.0 <= fac.min() and fac.max() <= 1.0 and 0.0 <= color.min() and color.max() <= 1.0
        np.testing.assert_array_equal(fac, color[:, 0])


def test_white_noise_is_a_function_of_the_coordinates_only():
    co = grid(7)
    v1, c1 = tex.white_noise(co, 3)
    v2, c2 = tex.white_noise(co[::-1].copy(), 3)
    np.testing.assert_array_equal(v1, v2[::-1])
    np.testing.assert_array_equal(v1, c1[:, 0])
    assert len(np.unique(v1)) == len(v1) and 0.0 <= v1.min() and v1.max() <= 1.0
    # 1D reads W only
    v_a, _ = tex.white_noise(np.array([[1, 2, 3, 0.5]], np.float32), 1)
    v_b, _ = tex.white_noise(np.array([[7, 8, 9, 0.5]], np.float32), 1)
    assert v_a[0] == v_b[0]


def test_voronoi_without_randomness_is_the_integer_lattice():
    """Randomness 0 puts every feature point on its cell's corner: F1 is the distance to the nearest integer
    point, the cell colour that point's, and the edge distance 0.5 minus the largest offset from it."""
    co = (np.random.default_rng(5).random((500, 4)) * 6 - 3).astype(np.float32)
    co[:, 2:] = 0.0
    out = tex.voronoi(co, 2, scale=1.0, randomness=0.0)
    nearest = np.round(co[:, :2].astype(np.float64))
    np.testing.assert_allclose(out["Distance"], np.linalg.norm(co[:, :2] - nearest, axis=1), atol=1e-6)
    np.testing.assert_allclose(out["Position"][:, :2], nearest, atol=1e-6)
    edge = tex.voronoi(co, 2, scale=1.0, randomness=0.0, feature="DISTANCE_TO_EDGE")["Distance"]
    np.testing.assert_allclose(edge, 0.5 - np.abs(co[:, :2] - nearest).max(axis=1), atol=1e-6)
    radius = tex.voronoi(co, 3, scale=1.0, randomness=0.0, feature="N_SPHERE_RADIUS")["Radius"]
    np.testing.assert_allclose(radius, 0.5, atol=1e-6)
    manhattan = tex.voronoi(co, 2, scale=1.0, randomness=0.0, distance="MANHATTAN")["Distance"]
    np.testing.assert_allclose(manhattan, np.abs(co[:, :2] - nearest).sum(axis=1), atol=1e-6)


def test_wave_bands_and_magic_follow_their_formulas():
    co = grid(9, -1.0, 1.0, z=0.3)
    p = (co[:, :3].astype(np.float64) * 1.5 + 1e-6) * 0.999999
    want = 0.5 + 0.5 * np.sin(p[:, 0] * 20 + 0.4 - np.pi / 2)
    np.testing.assert_allclose(tex.wave(co, 1.5, phase_offset=0.4), want, atol=2e-5)
    fac, color = tex.magic(co, 2.0, 0.0, 0)  # depth 0, no distortion: the three base waves
    x, y, z = (np.fmod(co[:, i].astype(np.float64), 2 * np.pi) for i in range(3))
    want = 0.5 - np.stack([np.sin((x + y + z) * 10), np.cos((-x + y - z) * 10), -np.cos((-x - y + z) * 10)], 1)
    np.testing.assert_allclose(color, want, atol=2e-5)
    np.testing.assert_allclose(fac, want.mean(axis=1), atol=2e-5)


def test_brick_corners_are_mortar_and_centres_are_brick():
    # scale 1, brick 0.5 x 0.25, no offset: the brick with corner (0, 0) has its centre at (0.25, 0.125)
    co = np.array([[0.001, 0.001, 0, 0], [0.25, 0.125, 0, 0]], np.float32)
    fac, color = tex.brick(co, 1.0, mortar_size=0.02, mortar_smooth=0.0, offset=0.0, color1=(1, 1, 1),
                           color2=(1, 1, 1), mortar=(0, 0, 0))
    np.testing.assert_array_equal(fac, [1.0, 0.0])
    np.testing.assert_array_equal(color[0], [0, 0, 0])
    np.testing.assert_allclose(color[1], [1, 1, 1], atol=1e-6)


@pytest.mark.parametrize("call, message", [
    (lambda: tex.noise(np.zeros((4, 2), np.float32)),
     r"texture coordinates must have shape \(N, 3\) or \(N, 4\) \(x, y, z\[, w\]\), not \(4, 2\)"),
    (lambda: tex.white_noise(np.zeros((4, 3), np.int32)), "texture coordinates must be floating point, not int32"),
    (lambda: tex.voronoi(np.zeros((1, 3), np.float32), dimensions=5),
     "texture dimensions must be 1, 2, 3 or 4, not 5"),
    (lambda: tex.noise(np.zeros((1, 3), np.float32), noise_type="PERLIN"),
     "unknown noise type 'PERLIN'; expected one of FBM, MULTIFRACTAL, HYBRID_MULTIFRACTAL, RIDGED_MULTIFRACTAL, "
     "HETERO_TERRAIN"),
    (lambda: tex.voronoi(np.zeros((1, 3), np.float32), distance="EUCLID"),
     "unknown Voronoi distance metric 'EUCLID'"),
    (lambda: tex.wave(np.zeros((1, 3), np.float32), wave_type="RINGS", direction="DIAGONAL"),
     "unknown wave direction 'DIAGONAL'; expected one of X, Y, Z, SPHERICAL"),
    (lambda: tex.magic(np.zeros((1, 3), np.float32), depth=11), "Magic texture depth must be 0-10, not 11"),
])
def test_bad_input_is_refused_with_a_clear_message(call, message):
    with pytest.raises(ValueError, match=message):
        call()
