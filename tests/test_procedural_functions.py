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


# --------------------------------------------------------------------------------------------- shading program
def run_op(name, registers, data=(), **ops):
    """One instruction of a shading program through the compiled evaluator; returns the register file."""
    from monte.core.shading import evaluator as ev
    from monte.core.shading import registry as R
    from monte.core.shading.program import N_BIND, WIDTH, ShadingProgram

    spec = R.op(name)
    code = np.full((1, WIDTH), -1, np.int32)
    code[0, 0] = spec.code
    for key, value in ops.items():
        code[0, spec.slot(key)] = value
    regs = np.asarray([np.broadcast_to(np.asarray(r, np.float32), 3) for r in registers], np.float32)
    prog = ShadingProgram(code, regs, np.zeros((0, N_BIND), np.int32), data=np.asarray(data, np.float32))
    prog.validate("test", 0, 0)
    return ev.run_single(prog)


def test_program_opcodes_equal_the_batch_functions():
    p = np.array([[0.31, -1.7, 2.2, 0.45]], np.float32)
    vec, w = p[0, :3], p[0, 3]
    # noise: out fac 0, color 1; vector 2, w 3, scale..distortion 4..10
    regs = run_op("tex_noise", [0, 0, vec, w, 2.5, 3.5, 0.6, 2.1, 0.3, 1.2, 0.4], fac=0, color=1, vector=2, w=3,
                  scale=4, detail=5, roughness=6, lacunarity=7, offset=8, gain=9, distortion=10,
                  flags=tex.pack_flags(4, tex.NOISE_HETERO_TERRAIN, 0))
    fac, color = tex.noise(p, 4, 2.5, 3.5, 0.6, 2.1, 0.3, 1.2, 0.4, "HETERO_TERRAIN", False)
    np.testing.assert_allclose(regs[0, 0], fac[0], rtol=1e-6)
    np.testing.assert_allclose(regs[1], color[0], rtol=1e-6)
    regs = run_op("tex_voronoi", [0, 0, 0, 0, 0, vec, w, 1.5, 1.5, 0.6, 2.0, 0.8, 1.5, 0.7],
                  distance=0, color=1, position=2, w_out=3, radius=4, vector=5, w=6, scale=7, detail=8, roughness=9,
                  lacunarity=10, smoothness=11, exponent=12, randomness=13,
                  flags=tex.pack_flags(3, tex.VORONOI_SMOOTH_F1, tex.METRIC_MINKOWSKI, 1))
    out = tex.voronoi(p, 3, 1.5, 1.5, 0.6, 2.0, 0.8, 1.5, 0.7, "SMOOTH_F1", "MINKOWSKI", True)
    np.testing.assert_allclose(regs[0, 0], out["Distance"][0], rtol=1e-6)
    np.testing.assert_allclose(regs[1], out["Color"][0], rtol=1e-6)
    np.testing.assert_allclose(regs[2], out["Position"][0], rtol=1e-6)
    regs = run_op("tex_brick", [0, 0, vec, (1, 0, 0), (0, 1, 0), (0, 0, 1), 3.0, 0.05, 0.2, 0.1, 0.5, 0.25],
                  data=(0.3, 1.4), color=0, fac=1, vector=2, color1=3, color2=4, mortar=5, scale=6, mortar_size=7,
                  mortar_smooth=8, bias=9, brick_width=10, row_height=11, frequencies=tex.pack_flags(3, 2), params=0)
    fac, color = tex.brick(p, 3.0, 0.05, 0.2, 0.1, 0.5, 0.25, 0.3, 3, 1.4, 2, (1, 0, 0), (0, 1, 0), (0, 0, 1))
    np.testing.assert_allclose(regs[1, 0], fac[0], rtol=1e-6)
    np.testing.assert_allclose(regs[0], color[0], rtol=1e-6)
    regs = run_op("tex_wave", [0, vec, 1.3, 2.0, 2.5, 1.5, 0.6, 0.7], fac=0, vector=1, scale=2, distortion=3,
                  detail=4, detail_scale=5, detail_roughness=6, phase=7, flags=tex.pack_flags(1, 3, 2))
    np.testing.assert_allclose(regs[0, 0], tex.wave(p, 1.3, 2.0, 2.5, 1.5, 0.6, 0.7, "RINGS", "SPHERICAL",
                                                    "TRI")[0], rtol=1e-6)


def test_pack_flags_refuses_fields_beyond_4_bits():
    with pytest.raises(ValueError, match="flag field 1 = 16 does not fit in 4 bits"):
        tex.pack_flags(3, 16)


def test_gabor_is_zero_mean_with_unit_range_and_refuses_unknown_types():
    co = (np.random.default_rng(7).random((3000, 4)) * 8 - 4).astype(np.float32)
    for gt in ("2D", "3D"):
        out = tex.gabor(co, gt)
        assert abs(float(out["Value"].mean()) - 0.5) < 0.02
        assert 0.0 <= out["Phase"].min() and out["Phase"].max() <= 1.0 and out["Intensity"].min() >= 0.0
    with pytest.raises(ValueError, match="unknown Gabor type '4D'; expected one of 2D, 3D"):
        tex.gabor(co, "4D")
