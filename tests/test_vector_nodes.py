"""The Vector nodes' device functions (Normal Map, Bump) against their analytic values, and the ray-differential
helpers they read (core.shading.vector_context). No Blender: programs are run through evaluator.run_single."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monte.core.scene import Camera
from monte.core.camera import PinholeRays, camera_rays, pinhole_params
from monte.core.shading import evaluator as ev
from monte.core.shading import registry as R
from monte.core.shading.program import WIDTH, ShadingProgram
from monte.core.shading.vector_context import camera_differentials, orthonormals


def _inst(name: str, **ops) -> list[int]:
    spec = R.op(name)
    row = [-1] * WIDTH
    row[0] = spec.code
    for i, (operand, kind) in enumerate(spec.operands):
        row[i + 1] = ops.get(operand, 0 if kind == "int" else -1)
    return row


def _run(code, registers, **context) -> np.ndarray:
    prog = ShadingProgram(np.asarray(code, np.int32), np.asarray(registers, np.float32), np.zeros((0, 6), np.int32))
    return ev.run_single(prog, **context)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _normal_map(colour, strength=1.0, space=0, flip_y=0, **context) -> np.ndarray:
    regs = [[0, 0, 0], colour, [strength] * 3]
    return _run([_inst("normal_map", normal=0, color=1, strength=2, space=space, layer=0, flip_y=flip_y)], regs,
                **context)[0]


def test_normal_map_world_space_is_the_colour_as_a_direction_negated_on_back_faces():
    n = _unit([0.3, -0.5, 0.8])
    colour = 0.5 * n + 0.5
    assert np.allclose(_normal_map(colour, space=2), n, atol=1e-6)
    assert np.allclose(_normal_map(colour, space=2, back=True), -n, atol=1e-6)
    # Blender world space: y and z negated
    assert np.allclose(_normal_map(colour, space=4), n * [1, -1, -1], atol=1e-6)
    # strength blends linearly from N outside tangent space
    half = _normal_map(colour, strength=0.5, space=2, N=(0, 0, 1))
    assert np.allclose(half, _unit(np.array([0, 0, 1]) + 0.5 * (n - [0, 0, 1])), atol=1e-6)


def test_normal_map_tangent_space_uses_tangent_sign_and_strength_in_tangent_space():
    # tangent +x, sign -1: the bitangent is -(z x x) = -y, so a green-up colour points along -y
    tangents = [[1.0, 0.0, 0.0, -1.0]]
    assert np.allclose(_normal_map([0.5, 1.0, 0.5], tangents=tangents), [0, -1, 0], atol=1e-6)
    c = np.array([0.8, 0.35, 0.9])
    t = 2 * c - 1
    expect = _unit([0.6 * t[0], -0.6 * t[1], 1 + (t[2] - 1) * 0.6])
    assert np.allclose(_normal_map(c, strength=0.6, tangents=tangents), expect, atol=1e-6)
    # DirectX: green points down
    assert np.allclose(_normal_map([0.5, 1.0, 0.5], flip_y=1, tangents=tangents), [0, 1, 0], atol=1e-6)
    # a mesh without the map (zero tangent) keeps N
    assert np.allclose(_normal_map(c, tangents=[[0, 0, 0, 0]], N=(0, 0.6, 0.8)), [0, 0.6, 0.8], atol=1e-6)


@pytest.mark.parametrize("invert, strength", [(False, 1.0), (True, 1.0), (False, 0.4)])
def test_bump_of_a_linear_height_tilts_the_normal_by_its_gradient(invert, strength):
    """h = a x + b y at the point and at the points shifted by the differential (via Geometry Position in the
    bump copies): the bumped normal is normalize(N - distance grad h), whatever the differential's size,
    orientation or the filter width."""
    a, b, distance, width = 0.7, -0.3, 0.5, 0.1
    regs = np.zeros((16, 3), np.float32)
    regs[1], regs[2], regs[6], regs[10] = strength, distance, width, (a, b, 0.0)
    code = [_inst("geometry", position=3), _inst("geometry", position=4, bump=1, bump_width=6),
            _inst("geometry", position=5, bump=2, bump_width=6)]
    for src, dst in ((3, 7), (4, 8), (5, 9)):
        code.append(_inst("vector_math", value=dst, a=src, b=10, c=11, scale=11, operation=10))  # dot
    code.append(_inst("bump", normal=0, strength=1, distance=2, height=7, height_dx=8, height_dy=9, filter_width=6,
                      invert=int(invert)))
    dp = ((0.004, 0.003, 0.0), (-0.003, 0.004, 0.0))  # rotated, 5 mm footprint
    out = _run(code, regs, P=(0.3, 0.2, 0.0), dP=dp)[0]
    sign = -1.0 if invert else 1.0
    bumped = _unit([-sign * distance * a, -sign * distance * b, 1.0])
    expect = _unit(strength * bumped + (1 - strength) * np.array([0, 0, 1]))
    assert np.allclose(out, expect, atol=2e-5)


def test_orthonormals_are_cycles_make_orthonormals():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n = np.vstack([n, np.full((1, 3), 1 / math.sqrt(3))])  # the (1, 1, 1) special case
    a, b = orthonormals(n)
    assert np.allclose(np.linalg.norm(a, axis=1), 1) and np.allclose(np.linalg.norm(b, axis=1), 1)
    assert np.allclose(np.einsum("ij,ij->i", a, n), 0, atol=1e-12)
    assert np.allclose(b, np.cross(n, a))
    # the first tangent is along (1, 1, 1) x n
    assert np.allclose(a[0], _unit(np.cross([1, 1, 1], n[0])))
    assert np.allclose(a[-1], _unit([0, 2 / math.sqrt(3), -2 / math.sqrt(3)]))


def _numpy_differentials(tri_vertices, uvs, prim, ng_view, dp):
    """The per-bounce differentials as NumPy computed them before the compiled per-point function
    (core.geometry_kernels.differentials_point) took over: einsum dot products, whose summation order is NumPy's."""
    ta, tb = orthonormals(ng_view)
    size = np.asarray(dp, np.float64)[:, None]
    d = np.stack([ta * size, tb * size], axis=1)
    v = tri_vertices[prim].astype(np.float64)
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    a11, a12, a22 = (np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e1, e2),
                     np.einsum("ij,ij->i", e2, e2))
    det = a11 * a22 - a12 * a12
    inv = np.where(det != 0, 1.0 / np.where(det != 0, det, 1.0), 0.0)
    db = np.empty((len(prim), 2, 2))
    for j in range(2):
        r1, r2 = np.einsum("ij,ij->i", e1, d[:, j]), np.einsum("ij,ij->i", e2, d[:, j])
        db[:, j, 0] = (a22 * r1 - a12 * r2) * inv
        db[:, j, 1] = (a11 * r2 - a12 * r1) * inv
    c = uvs[prim].astype(np.float64)
    u1, u2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    duv = u1[:, None] * db[:, :, 0, None] + u2[:, None] * db[:, :, 1, None]
    return d.astype(np.float32), db.astype(np.float32), duv.astype(np.float32)


def test_compiled_differentials_match_numpy():
    """The per-bounce ray differentials (vector_context._differentials, now one compiled function per point that
    the fused kernel shares) equal the NumPy statement of them up to float32 rounding, on random triangles and
    normals, with the (1, 1, 1) normal and a degenerate triangle (no barycentric derivative)."""
    from types import SimpleNamespace

    from monte.core.shading.vector_context import _differentials

    rng = np.random.default_rng(11)
    t = 64
    tri = rng.normal(size=(t, 3, 3)).astype(np.float32) * 3
    tri[-1, 2] = tri[-1, 1]  # degenerate
    uvs = rng.uniform(size=(t, 3, 2)).astype(np.float32)
    n = 400
    prim = rng.integers(0, t, n)
    prim[:3] = t - 1
    ng = rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    ng[3] = 1 / math.sqrt(3)
    ng = ng.astype(np.float32)
    dp = rng.uniform(1e-3, 0.1, n).astype(np.float32)
    ps = SimpleNamespace(tri_vertices=tri, uvs=uvs)
    got = _differentials(ps, prim, ng, dp, True)
    want = _numpy_differentials(tri, uvs, prim, ng, dp)
    for g, w in zip(got, want):
        assert g.dtype == np.float32 and g.shape == w.shape
        assert np.allclose(g, w, rtol=1e-6, atol=1e-7 * float(np.abs(w).max()))
    assert np.array_equal(got[1][prim == t - 1], np.zeros((int(np.sum(prim == t - 1)), 2, 2), np.float32))
    assert np.abs(got[1]).max() > 0 and np.abs(got[2]).max() > 0
    # the footprint scales dP: along two unit tangents of the normal, orthogonal to it
    assert np.allclose(np.linalg.norm(got[0], axis=2), dp[:, None], rtol=1e-5)
    assert np.allclose(np.einsum("nij,nj->ni", got[0], ng), 0, atol=1e-6)
    # no UV map: no duv
    assert _differentials(SimpleNamespace(tri_vertices=tri, uvs=None), prim, ng, dp, True)[2] is None


def test_camera_differentials_are_the_pixel_footprint():
    ortho = Camera(matrix_world=np.eye(4), kind="ORTHO", ortho_scale=2.0, resolution=(40, 20))
    x, y = np.array([3.5, 20.0]), np.array([7.5, 10.0])
    dp, dd = camera_differentials(ortho, x, y, camera_rays(ortho, x, y))
    assert np.allclose(dp, 2.0 / 40) and np.allclose(dd, 0.0)
    persp = Camera(matrix_world=np.eye(4), kind="PERSP", resolution=(64, 64))
    x, y = np.array([32.0]), np.array([32.0])
    rays = camera_rays(persp, x, y)
    dp, dd = camera_differentials(persp, x, y, rays)
    width = persp.frame()[1] - persp.frame()[0]  # of the image plane at distance 1
    assert np.allclose(dd, width / 64, rtol=1e-3)
    assert np.allclose(dp, rays.t_start * dd, rtol=1e-3)


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_compiled_camera_differentials_are_the_numpy_ones_bit_for_bit(kind):
    # a rotated, scaled, shifted camera and jittered raster positions: the compiled pass (the render's) must
    # give the bits of the NumPy form (two more ray batches), which the images were made with
    rng = np.random.default_rng(3)
    c, s = math.cos(0.7), math.sin(0.7)
    m = np.array([[c, 0, s, 1.5], [0, 1, 0, -2.0], [-s, 0, c, 4.0], [0, 0, 0, 1]]) @ np.diag([1.3, 0.8, 2.0, 1.0])
    cam = Camera(matrix_world=m, kind=kind, ortho_scale=3.0, resolution=(97, 61))
    x, y = rng.uniform(0, 97, 5000), rng.uniform(0, 61, 5000)
    rays = camera_rays(cam, x, y)
    dp, dd = camera_differentials(cam, x, y, rays)
    dp_np, dd_np = camera_differentials(cam, x, y, rays, compiled=False)
    assert dp.dtype == np.float32 and dd.dtype == np.float32
    assert np.array_equal(dp, dp_np) and np.array_equal(dd, dd_np)
    # deferred (the fused kernel makes a path's ray, and its differentials where it reads them, with the same
    # per-ray functions; PinholeRays makes them all for the per-bounce integrator)
    deferred = PinholeRays(x, y, pinhole_params(cam))
    made = deferred.rays()
    for name in ("origins", "directions", "tmax", "depth_scale", "t_start"):
        assert np.array_equal(getattr(made, name), getattr(rays, name)), name
    dp_d, dd_d = deferred.footprints(made)
    assert np.array_equal(dp_d, dp_np) and np.array_equal(dd_d, dd_np)
    assert np.all(dp > 0) and (np.all(dd > 0) if kind == "PERSP" else np.all(dd == 0))


def test_only_a_pinhole_camera_has_deferred_differentials():
    # panoramic rays and a thin lens's need their neighbours' lens points: computed up front, in NumPy
    persp = Camera(matrix_world=np.eye(4), kind="PERSP", resolution=(64, 48))
    p = pinhole_params(persp)
    assert p.shape == (18,) and p.dtype == np.float64 and tuple(p[:2]) == (64.0, 48.0) and p[15] == 0.0
    assert pinhole_params(Camera(matrix_world=np.eye(4), kind="ORTHO", resolution=(8, 8)))[15] == 1.0
    assert pinhole_params(Camera(matrix_world=np.eye(4), kind="PANO", resolution=(8, 8))) is None
    lens = Camera(matrix_world=np.eye(4), kind="PERSP", resolution=(8, 8), use_dof=True, aperture_fstop=1.0,
                  focus_distance=2.0)
    assert lens.aperture_radius() > 0 and pinhole_params(lens) is None


def _bump_term_reference(n, s, w):
    """Cycles' bump shadowing (closure/bsdf.h) in float64 NumPy: (g1, rejected, |the sign test's product|)."""
    cos_si, cos_sn, cos_ni = (np.einsum("ij,ij->i", a, b) for a, b in ((s, w), (s, n), (n, w)))
    cos_i, cos_d = np.abs(cos_si), np.minimum(np.abs(cos_sn), 1.0)
    alpha2 = np.clip(0.125 * (1.0 / np.maximum(cos_d ** 2, 1e-30) - 1.0), 0.0, 1.0)
    g1 = 2.0 / (1.0 + np.sqrt(1.0 + alpha2 * (1.0 / np.maximum(cos_i ** 2, 1e-30) - 1.0)))
    g1 = np.where((cos_d >= 1.0) | (cos_i >= 1.0), 1.0, np.where(cos_i < 1e-6, 0.0, g1))
    return g1, cos_si * cos_sn * cos_ni < 0, np.abs(cos_si * cos_sn * cos_ni)


def test_bump_shadowing_terms_are_cycles_terms_for_both_normals_in_world_and_local_directions():
    """The compiled bump shadowing (one pass per point) against Cycles' formula: the frame's normal decides the
    rejection of every lobe, the diffuse normal (dn in the frame, negated on back faces) the diffuse softening;
    directions given in world space and in the shading frame agree."""
    from monte.core.integrator import SurfaceBatch, _bump_terms

    rng = np.random.default_rng(7)
    m = 400
    g = SurfaceBatch.empty(m, False)
    g.data[:] = 0.0

    def units(k):
        v = rng.normal(size=(k, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    ns = units(m)
    t = np.cross(ns, units(m))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(ns, t)
    g.ns[:], g.tangent[:], g.bitangent[:] = ns, t, b
    back = rng.random(m) < 0.3
    g.cos_o_geo[:] = np.where(back, -0.5, 0.5)
    g.n_view[:] = np.where(back[:, None], -ns, ns)
    dn = units(m) * [0.3, 0.3, 1.0]
    dn /= np.linalg.norm(dn, axis=1, keepdims=True)
    dn[::4] = (0.0, 0.0, 1.0)  # untilted points: the diffuse normal is the frame's
    g.dn[:] = dn
    smooth = units(m)
    smooth[::5] = g.n_view[::5]  # the node left the normal as it was: no softening
    w_world = units(m)
    grazing = np.zeros(m, bool)
    grazing[3::7] = True  # perpendicular to the smooth normal: fully shadowed diffuse lobes
    w_world[grazing] = np.cross(smooth[grazing], w_world[grazing])
    w_world[grazing] /= np.linalg.norm(w_world[grazing], axis=1, keepdims=True)
    w_local = np.stack([np.einsum("ij,ij->i", w_world, a) for a in (t, b, ns)], axis=1)
    rows = rng.permutation(m)[: m - 50]

    f64 = lambda a: np.asarray(a, np.float32).astype(np.float64)  # what the kernel reads (float32)
    t, b, ns, smooth, w_world = f64(g.tangent), f64(g.bitangent), f64(g.ns), f64(smooth), f64(w_world)
    diffuse_normal = t * dn[:, :1] + b * dn[:, 1:2] + ns * dn[:, 2:3]
    diffuse_normal = np.where(back[:, None], -diffuse_normal, diffuse_normal)
    want_g1, want_reject_d, size_d = _bump_term_reference(diffuse_normal[rows], smooth[rows], w_world[rows])
    _, want_reject, size = _bump_term_reference(f64(g.n_view)[rows], smooth[rows], w_world[rows])
    clear, clear_d = size > 1e-4, size_d > 1e-4  # sign tests float32 rounding cannot flip
    for w in (w_world, w_local):
        g1, reject, reject_d = _bump_terms(g, rows, smooth[rows], w[rows], local=w is w_local)
        np.testing.assert_allclose(g1, want_g1, atol=1e-4)
        assert np.array_equal(reject[clear], want_reject[clear])
        assert np.array_equal(reject_d[clear_d], want_reject_d[clear_d])
    assert want_reject.sum() > 50 and ((want_g1 > 0.01) & (want_g1 < 0.99)).sum() > 50  # the cases meant
    same = ((rows % 20) == 0) & ~grazing[rows]  # untilted and the node's normal the smooth one: no softening
    assert np.all(g1[same] > 1.0 - 1e-5)
    assert np.all(g1[grazing[rows]] < 1e-3)


def test_shading_inputs_and_diffuse_weights_are_the_numpy_expressions():
    """The compiled passes shade_points and the bump shadowing use give what their NumPy forms gave: the world
    position, the normals negated on back faces, I = -d; the diffuse lobes' weights of the given rows only."""
    from monte.core import geometry_kernels as gk
    from monte.core.integrator import SurfaceBatch

    rng = np.random.default_rng(11)
    m = 300
    g = SurfaceBatch.empty(m, True)
    g.data[:] = rng.normal(size=g.data.shape).astype(np.float32)
    d = rng.normal(size=(m, 3)).astype(np.float32)
    shift = np.array([1e3 / 3, -7.1, 0.25], np.float32)
    out = [np.empty((m, 3), np.float32) for _ in range(4)]
    gk.shading_inputs(g.p, shift, g.ng, g.ns_raw, g.cos_o_geo, d, *out)
    back = g.cos_o_geo < 0
    assert back.any() and (~back).any()
    for got, want in zip(out, ((g.p + shift).astype(np.float32), np.where(back[:, None], -g.ng, g.ng),
                               np.where(back[:, None], -g.ns_raw, g.ns_raw), -d)):
        assert np.array_equal(got, want)

    kind = rng.integers(0, 4, size=(m, 4)).astype(np.int8)
    weight = rng.random((m, 4, 3)).astype(np.float32)
    rows = rng.permutation(m)[:120]
    got = np.zeros_like(weight)
    gk.diffuse_lobe_weights(rows.astype(np.int64), kind, weight, 0, got)
    want = np.zeros_like(weight)
    want[rows] = np.where((kind[rows] == 0)[..., None], weight[rows], np.float32(0))
    assert np.array_equal(got, want) and got[rows].any() and not np.delete(got, rows, axis=0).any()
