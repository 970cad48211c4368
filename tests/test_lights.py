"""Tests of core/lights.py: sampling pdfs against closed forms, MIS consistency, and units against Cycles.

Every irradiance check compares a Monte Carlo estimate sum(radiance cos / pdf) / N with a closed form (or a
Gauss-Legendre quadrature of the light's surface where no closed form is at hand), within 4 standard errors of
the estimate plus a small relative floor for float32 rounding, and proves its power on its own numbers: the closed
form 1 % too high and 1 % too low must fail (assert_close's built-in control; where sampling is noisier the
sample count is raised until it does, and the one exception, a 3-degree spread, states 5 %).

The sampled directions follow each light kind's pdf: Pearson's chi-square over 64 cells of the light, with a
built-in control (the pdf 5 % too high over half its mass and 5 % too low over the rest must fail).

The Cycles checks render a white diffuse plane (or a mirror) under each light kind with Blender 5.0's Cycles in a
subprocess (bpy), and compare with Monte's own sampler at the same pixels: a units check that detects 2 % (its
control: Monte's mean 2 % off fails); the 1 % agreement of every light kind with Cycles is test_crosscheck.py's.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from monte.core import lights
from monte.core.scene import (AreaLight, Camera, Material, PointLight, Scene, SpotLight, SunLight, World)

SHIFT = np.array([1000.5, -2000.25, 30.0])  # the integrator's world offset: every position below is shifted
UP = np.array([0.0, 0.0, 1.0])


# --------------------------------------------------------------------------------------------------- helpers
def make_scene(light_list=(), world=0.0) -> Scene:
    cam = Camera.look_at((0, -5, 1), (0, 0, 0))
    wc = np.broadcast_to(np.asarray(world, dtype=np.float64), (3,)).copy()
    return Scene(camera=cam, materials=[Material("m")], lights=list(light_list), world=World(wc)).validate()


def make_sampler(light_list=(), world=0.0, tris=None, radius=10.0) -> lights.LightSampler:
    return lights.LightSampler(make_scene(light_list, world), SHIFT, tris, radius)


def W(p):
    """World position of a point given relative to the shift (what the integrator passes)."""
    return SHIFT + np.asarray(p, dtype=np.float64)


def estimate(sampler, p, n=UP, count=200_000, seed=0, use_n=True):
    """MC irradiance at shifted point p with normal n: (mean, standard error) of radiance cos / pdf (red)."""
    rng = np.random.default_rng(seed)
    P = np.tile(np.asarray(p, np.float32), (count, 1))
    Nn = np.tile(np.asarray(n, np.float32), (count, 1))
    s = sampler.sample(P, Nn if use_n else None, rng.random(count, dtype=np.float32),
                       rng.random((count, 2), dtype=np.float32))
    assert s.wi.shape == (count, 3) and s.radiance.shape == (count, 3)
    assert s.pdf.dtype == np.float32 and s.wi.dtype == np.float32
    cos = np.maximum(np.einsum("ij,ij->i", s.wi.astype(np.float64), Nn), 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(s.pdf > 0, s.radiance[:, 0] * cos / s.pdf, 0.0)
    return f.mean(), f.std() / math.sqrt(count)


DETECT = 0.01  # the error every closed-form check here detects: its closed form 1 % off must fail


def assert_close(est, se, expected, rel_floor=2e-4, sigmas=4.0, detect=DETECT):
    """est within sigmas x se (+ rel_floor relative) of the closed form, and the built-in control: the closed
    form `detect` (1 %) too high or too low must fail at this sample count (else the check is too noisy to see
    a 1 % error: raise its sample count)."""
    tol = sigmas * se + rel_floor * abs(expected) + 1e-12
    assert abs(est - expected) <= tol, f"estimate {est:.6g} +- {se:.3g}, expected {expected:.6g}"
    if expected != 0 and detect:
        for wrong in (1 + detect, 1 - detect):
            assert abs(est - wrong * expected) > tol, (f"the control: {expected * wrong:.6g} ({100 * detect:g} % off) "
                                                       f"passes too (tolerance {100 * tol / abs(expected):.2f} %)")


def gl(n, a, b):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (b - a) * x + 0.5 * (a + b), 0.5 * (b - a) * w


def spread_factor(cos_a, spread):
    if spread >= math.pi:
        return np.ones_like(cos_a)
    h = spread / 2
    th = math.tan(h)
    tan_a = np.sqrt(np.clip(1 - cos_a ** 2, 0, None)) / np.maximum(cos_a, 1e-300)
    return np.maximum((th - tan_a) / (th - h), 0)


def quad_irradiance(p, n, points, weights, light_normal, L, two_sided=False, spread=math.pi, weight_fn=None):
    """Irradiance at p (normal n) from emitting surface samples (K, 3) with area weights (K,)."""
    dv = points - p
    d2 = (dv ** 2).sum(-1)
    w = dv / np.sqrt(d2)[:, None]
    cr = np.clip(w @ n, 0, None)
    cl = -(w @ light_normal) if light_normal.ndim == 1 else -(w * light_normal).sum(-1)
    cl = np.abs(cl) if two_sided else np.clip(cl, 0, None)
    f = L * spread_factor(cl, spread) * cr * cl / d2 * weights
    if weight_fn is not None:
        f = f * weight_fn(-w)
    return float(f.sum())


def rect_quadrature(c, ax, ay, lx, ly, n=96):
    s, ws = gl(n, -lx / 2, lx / 2)
    t, wt = gl(n, -ly / 2, ly / 2)
    S, T = np.meshgrid(s, t, indexing="ij")
    pts = c + S.reshape(-1, 1) * ax + T.reshape(-1, 1) * ay
    return pts, np.outer(ws, wt).reshape(-1)


def ellipse_quadrature(c, ax, ay, rx, ry, n=96):
    r, wr = gl(n, 0, 1)
    ph, wp = gl(2 * n, 0, 2 * math.pi)
    R, PH = np.meshgrid(r, ph, indexing="ij")
    pts = c + (R * np.cos(PH)).reshape(-1, 1) * ax * rx + (R * np.sin(PH)).reshape(-1, 1) * ay * ry
    return pts, (np.outer(wr, wp) * R).reshape(-1) * rx * ry


def disc_facing(c, p, r, n=64):
    """A disc of radius r centred at c and facing p (the soft-falloff point light): points, weights, normal."""
    nd = (p - c) / np.linalg.norm(p - c)
    a = np.cross(nd, [0.3, 0.5, 0.8])
    a /= np.linalg.norm(a)
    b = np.cross(nd, a)
    pts, w = ellipse_quadrature(c, a, b, r, r, n)
    return pts, w, nd


def corner_form_factor(a, b, h):
    """Form factor from a differential area to a parallel rectangle [0, a] x [0, b] at height h whose corner is
    straight above it (signed in a and b, so rectangles add by inclusion-exclusion)."""
    sa, sb = math.copysign(1, a), math.copysign(1, b)
    A, B = abs(a) / h, abs(b) / h
    f = (A / math.sqrt(1 + A * A) * math.atan(B / math.sqrt(1 + A * A))
         + B / math.sqrt(1 + B * B) * math.atan(A / math.sqrt(1 + B * B))) / (2 * math.pi)
    return sa * sb * f


def parallel_rect_irradiance(L, x0, x1, y0, y1, h):
    """Irradiance at the origin (normal +z) from a Lambertian rectangle [x0,x1]x[y0,y1] at height h."""
    F = (corner_form_factor(x1, y1, h) - corner_form_factor(x0, y1, h) - corner_form_factor(x1, y0, h)
         + corner_form_factor(x0, y0, h))
    return math.pi * L * F


def smoothstep(x):
    x = np.clip(x, 0, 1)
    return x * x * (3 - 2 * x)


def area_matrix(center, normal, x_hint=(1.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    """Light-to-world matrix whose local -Z is `normal`."""
    z = -np.asarray(normal, float) / np.linalg.norm(normal)
    x = np.asarray(x_hint, float) - z * (np.dot(x_hint, z))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x * scale[0], y * scale[1], z * scale[2], center
    return m


def spot_light(pos, target, power, radius=0.0, size=math.radians(40), blend=0.3):
    d = np.asarray(target, float) - pos
    return SpotLight("spot", position=W(pos), direction=d / np.linalg.norm(d), power=np.full(3, power),
                     radius=radius, spot_size=size, spot_blend=blend)


# --------------------------------------------------------------------------------------------- irradiance
P = 100.0


def test_point_light_intensity_is_power_over_4pi():
    s = make_sampler([PointLight("p", W([0.3, -0.2, 2.0]), np.full(3, P))])
    p = np.array([0.0, 0.0, 0.0])
    v = np.array([0.3, -0.2, 2.0]) - p
    d2 = v @ v
    est, se = estimate(s, p)
    assert_close(est, se, P / (4 * math.pi) * (v[2] / math.sqrt(d2)) / d2, rel_floor=1e-5)
    assert s.kinds_present == {"point"} and s.has_lights


def test_point_light_sample_fields():
    s = make_sampler([PointLight("p", W([0, 0, 2.0]), np.full(3, P))])
    ls = s.sample(np.zeros((4, 3), np.float32), None, np.full(4, 0.5, np.float32), np.full((4, 2), 0.5, np.float32))
    assert ls.delta.all()
    np.testing.assert_allclose(ls.wi, [[0, 0, 1]] * 4, atol=1e-6)
    np.testing.assert_allclose(ls.dist, 2.0, rtol=1e-6)
    np.testing.assert_allclose(ls.pdf, 1.0)  # selection probability only
    np.testing.assert_allclose(ls.radiance, P / (4 * math.pi) / 4, rtol=1e-5)  # I / d^2


def test_spot_light_smoothstep_cone():
    pos = np.array([0.6, 0.3, 1.5])
    size, blend = math.radians(50), 0.4
    sl = spot_light(pos, [0.0, 0.0, 0.0], P, size=size, blend=blend)
    s = make_sampler([sl])
    cos_half = math.cos(size / 2)
    for p in ([0.0, 0.0, 0.0], [0.35, 0.25, 0.0], [0.5, -0.3, 0.0], [-0.5, 0.5, 0.0]):
        p = np.asarray(p)
        w = p - pos
        d = np.linalg.norm(w)
        w /= d
        att = smoothstep((w @ sl.direction - cos_half) / ((1 - cos_half) * blend))
        exp = P / (4 * math.pi) * att * (-w[2]) / d ** 2
        est, se = estimate(s, p, count=2000)
        assert_close(est, se, exp, rel_floor=1e-5)
    assert s.kinds_present == {"spot"}


def test_soft_falloff_point_light_is_a_disc_facing_the_point():
    # Blender's default (use_soft_falloff): perpendicular irradiance P / (4 pi (d^2 + r^2))
    r, d = 0.5, 2.0
    s = make_sampler([PointLight("p", W([0, 0, d]), np.full(3, P), radius=r)])
    est, se = estimate(s, np.zeros(3))
    assert_close(est, se, P / (4 * math.pi * (d * d + r * r)))
    # oblique: quadrature over the disc facing the shading point
    c, p, n = np.array([0.0, 0.0, d]), np.array([1.2, 0.4, 0.0]), np.array([0.0, 0.6, 0.8])
    pts, wts, ln = disc_facing(c, p, r)
    exp = quad_irradiance(p, n, pts, wts, ln, P / (4 * math.pi ** 2 * r * r))
    est, se = estimate(s, p, n)
    assert_close(est, se, exp)


def test_sphere_point_light_without_soft_falloff():
    r, c = 0.5, np.array([0.2, 0.1, 2.0])
    pl = PointLight("p", W(c), np.full(3, P), radius=r)
    pl.soft_falloff = False  # Blender's use_soft_falloff = False: a true sphere
    s = make_sampler([pl])
    n = np.array([0.0, 0.6, 0.8])
    v = c
    d2 = v @ v
    est, se = estimate(s, np.zeros(3), n)
    assert_close(est, se, P / (4 * math.pi) * (v @ n) / math.sqrt(d2) / d2)  # exact while above the horizon
    # inside the sphere every direction sees radiance L: irradiance pi L (cosine about n, or uniform)
    L = P / (4 * math.pi ** 2 * r * r)
    est, se = estimate(s, c + [0.1, 0, 0], n)
    assert_close(est, se, math.pi * L)
    est, se = estimate(s, c + [0.1, 0, 0], n, use_n=False, count=2_000_000)  # uniform: 2M for the 1 % control
    assert_close(est, se, math.pi * L)


def test_spot_light_with_radius():
    pos, r = np.array([0.5, 0.2, 1.2]), 0.15
    size, blend = math.radians(60), 0.5
    sl = spot_light(pos, [0.0, 0.0, 0.0], P, radius=r, size=size, blend=blend)
    s = make_sampler([sl])
    cos_half = math.cos(size / 2)

    def cone(w_from_light):
        return smoothstep((w_from_light @ sl.direction - cos_half) / ((1 - cos_half) * blend))

    for p in ([0.0, 0.0, 0.0], [-0.3, -0.2, 0.0]):
        p = np.asarray(p)
        pts, wts, ln = disc_facing(pos, p, r)
        exp = quad_irradiance(p, UP, pts, wts, ln, P / (4 * math.pi ** 2 * r * r), weight_fn=cone)
        est, se = estimate(s, p)
        assert_close(est, se, exp)


def test_square_area_light_parallel_closed_form():
    side, h = 0.8, 1.0
    m = area_matrix([0.3, -0.1, h], [0, 0, -1])
    m[:3, 3] = W(m[:3, 3])
    s = make_sampler([AreaLight("a", m, np.full(3, P), "SQUARE", side)])
    L = P / (math.pi * side * side)
    exp = parallel_rect_irradiance(L, 0.3 - side / 2, 0.3 + side / 2, -0.1 - side / 2, -0.1 + side / 2, h)
    est, se = estimate(s, np.zeros(3))
    assert_close(est, se, exp)
    # far away and tiny: the solid angle is still right (float64 spherical rectangle)
    m2 = area_matrix([0.0, 0.0, 50.0], [0, 0, -1])
    m2[:3, 3] = W(m2[:3, 3])
    s2 = make_sampler([AreaLight("a", m2, np.full(3, P), "SQUARE", 0.01)])
    est, se = estimate(s2, np.zeros(3), count=20_000)
    assert_close(est, se, parallel_rect_irradiance(P / (math.pi * 1e-4), -0.005, 0.005, -0.005, 0.005, 50.0),
                 rel_floor=1e-4)


@pytest.mark.parametrize("shape", ["RECTANGLE", "ELLIPSE"])
def test_rotated_scaled_area_light(shape):
    c = np.array([0.4, 0.2, 0.9])
    m = area_matrix(c, [-0.3, -0.1, -1.0], x_hint=(1, 0.3, 0), scale=(1.5, 0.5, 1.0))
    m[:3, 3] = W(c)
    sx, sy = 0.6, 0.9
    s = make_sampler([AreaLight("a", m, np.full(3, P), shape, sx, sy)])
    ax, ay = m[:3, 0] / np.linalg.norm(m[:3, 0]), m[:3, 1] / np.linalg.norm(m[:3, 1])
    lx, ly = 1.5 * sx, 0.5 * sy
    ng = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    if shape == "RECTANGLE":
        pts, wts = rect_quadrature(c, ax, ay, lx, ly)
        area = lx * ly
    else:
        pts, wts = ellipse_quadrature(c, ax, ay, lx / 2, ly / 2)
        area = math.pi * lx * ly / 4
    for p, n in (([0.0, 0.0, 0.0], UP), ([0.9, -0.4, 0.2], np.array([-0.6, 0.0, 0.8]))):
        p = np.asarray(p)
        exp = quad_irradiance(p, n, pts, wts, ng, P / (math.pi * area))
        est, se = estimate(s, p, n)
        assert_close(est, se, exp)


def test_disk_area_light_on_axis():
    side, h = 0.8, 1.0
    m = area_matrix([0, 0, h], [0, 0, -1])
    m[:3, 3] = W(m[:3, 3])
    s = make_sampler([AreaLight("a", m, np.full(3, P), "DISK", side)])
    L = P / (math.pi * math.pi * side * side / 4)
    r2 = (side / 2) ** 2
    est, se = estimate(s, np.zeros(3))
    assert_close(est, se, math.pi * L * r2 / (h * h + r2))


def test_area_light_is_one_sided():
    m = area_matrix([0, 0, 1.0], [0, 0, 1.0])  # emits upwards, away from the point below
    m[:3, 3] = W(m[:3, 3])
    s = make_sampler([AreaLight("a", m, np.full(3, P), "SQUARE", 1.0)])
    rng = np.random.default_rng(0)
    ls = s.sample(np.zeros((1000, 3), np.float32), None, rng.random(1000), rng.random((1000, 2)))
    assert np.all(ls.pdf == 0) and np.all(ls.radiance == 0)


@pytest.mark.parametrize("spread_deg", [120.0, 60.0, 3.0])
def test_area_light_spread(spread_deg):
    """A narrow spread is a noisy light to sample (the whole square is sampled, a small part of it shines at the
    point): at 3 deg, 2M samples resolve a 5 % error, not 1 % (the wider spreads: 1 %)."""
    spread = math.radians(spread_deg)
    c = np.array([0.1, 0.05, 1.0])
    m = area_matrix(c, [0, 0, -1])
    m[:3, 3] = W(c)
    side = 0.5
    s = make_sampler([AreaLight("a", m, np.full(3, P), "SQUARE", side, spread=spread)])
    pts, wts = rect_quadrature(c, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), side, side, n=300)
    for p in ([0.0, 0.0, 0.0], [0.12, 0.1, 0.0], [0.6, 0.0, 0.0]):
        p = np.asarray(p)
        exp = quad_irradiance(p, UP, pts, wts, np.array([0, 0, -1.0]), P / (math.pi * side * side), spread=spread)
        est, se = estimate(s, p, count={3.0: 2_000_000, 60.0: 1_000_000}.get(spread_deg, 200_000))
        assert_close(est, se, exp, rel_floor=2e-3, detect=0.05 if spread_deg < 10 else DETECT)


@pytest.mark.parametrize("angle_deg", [0.0, 0.526, 20.0])
def test_sun_strength_is_irradiance(angle_deg):
    d = np.array([0.3, -0.4, -0.8])
    d /= np.linalg.norm(d)
    s = make_sampler([SunLight("sun", d, np.full(3, 3.0), angle=math.radians(angle_deg))])
    n = np.array([0.0, -0.6, 0.8])
    est, se = estimate(s, np.zeros(3), n)
    assert_close(est, se, 3.0 * float(-d @ n), rel_floor=1e-5)
    rng = np.random.default_rng(1)
    ls = s.sample(np.zeros((10, 3), np.float32), None, rng.random(10), rng.random((10, 2)))
    assert np.all(np.isinf(ls.dist)) and np.all(ls.delta == (angle_deg == 0))


def test_world_constant_radiance():
    s = make_sampler([], world=(0.5, 0.25, 0.125))
    est, se = estimate(s, np.zeros(3))  # cosine sampling about n: no variance
    assert_close(est, se, math.pi * 0.5, rel_floor=1e-5)
    est, se = estimate(s, np.zeros(3), use_n=False, count=2_000_000)  # uniform sphere: 2M for the 1 % control
    assert_close(est, se, math.pi * 0.5)
    assert s.kinds_present == {"world"}


def two_triangle_quad(c, half, normal_up=False):
    x0, x1, y0, y1 = c[0] - half, c[0] + half, c[1] - half, c[1] + half
    z = c[2]
    a, b, cc, d = [x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]
    tris = np.array([[a, b, cc], [a, cc, d]] if normal_up else [[a, cc, b], [a, d, cc]], np.float32)
    return tris


@pytest.mark.parametrize("normal_up", [False, True])
def test_emissive_triangles_both_faces(normal_up):
    c, half, Le = np.array([0.2, -0.1, 1.0]), 0.4, 2.0
    dark = np.array([[[0, 0, 5], [1, 0, 5], [0, 1, 5]]], np.float32)  # a triangle of a non-emitting material
    tris = np.concatenate([two_triangle_quad(c, half, normal_up), dark])
    mats = np.array([1, 1, 0])
    et = lights.EmissiveTriangles.from_mesh_arrays(tris, mats, np.array([[0, 0, 0], [Le, Le, Le]]))
    assert et.count == 2 and list(et.emitter_of_triangle) == [0, 1, -1]
    s = make_sampler([], tris=et)
    exp = parallel_rect_irradiance(Le, c[0] - half, c[0] + half, c[1] - half, c[1] + half, c[2])
    est, se = estimate(s, np.zeros(3))
    assert_close(est, se, exp)
    assert s.kinds_present == {"triangle"}


def test_no_emitters():
    assert lights.EmissiveTriangles.from_mesh_arrays(np.zeros((2, 3, 3), np.float32), np.zeros(2, int),
                                                      np.zeros((1, 3))) is None
    s = make_sampler([], world=0.0, tris=None)
    assert not s.has_lights and s.kinds_present == frozenset()
    ls = s.sample(np.zeros((3, 3), np.float32), None, np.zeros(3), np.zeros((3, 2)))
    assert np.all(ls.pdf == 0)
    out = s.intersect(np.zeros((3, 3)), np.tile(UP, (3, 1)), np.full(3, np.inf), np.ones(3), np.zeros(3, bool), True)
    assert np.all(out == 0)


def test_pdf_triangle_matches_sample():
    tris = np.array([[[0, 0, 1], [1, 0, 1.2], [0, 1, 0.9]], [[2, 2, 2], [3, 2, 2], [2, 3, 2.5]]], np.float32)
    et = lights.EmissiveTriangles.from_mesh_arrays(tris, np.array([0, 1]), np.array([[1.0, 2.0, 3.0], [5.0, 0.5, 0.1]]))
    s = make_sampler([PointLight("p", W([0, 0, 3]), np.full(3, 50.0))], tris=et)
    rng = np.random.default_rng(3)
    N = 5000
    p = rng.normal(size=(N, 3)).astype(np.float32) * 0.3
    us = rng.random(N, dtype=np.float32)
    ls = s.sample(p, None, us, rng.random((N, 2), dtype=np.float32))
    # which emitter each sample picked: recover it from the hit point
    q = p + ls.wi * ls.dist[:, None]
    on_first = np.abs((q - tris[0, 0]) @ et.normal[0]) < 1e-3
    is_tri = ~ls.delta & (ls.pdf > 0)
    emitter = np.where(on_first, 0, 1)
    cos = np.abs(np.einsum("ij,ij->i", ls.wi, et.normal[emitter]))
    pdf = s.pdf_triangle(emitter[is_tri], p[is_tri], ls.dist[is_tri] ** 2, cos[is_tri])
    np.testing.assert_allclose(pdf, ls.pdf[is_tri], rtol=2e-4)
    assert s.pdf_triangle(np.array([-1]), np.zeros((1, 3)), np.ones(1), np.ones(1))[0] == 0


def test_selection_floor_and_mixture():
    m = area_matrix([0.5, 0, 1.5], [0, 0, -1])
    m[:3, 3] = W(m[:3, 3])
    tris = two_triangle_quad(np.array([-0.5, 0.3, 1.2]), 0.2)
    et = lights.EmissiveTriangles.from_mesh_arrays(tris, np.zeros(2, int), np.array([[3.0, 3.0, 3.0]]))
    sun_d = np.array([0.0, 0.0, -1.0])
    light_list = [PointLight("p", W([0, 0, 2.0]), np.full(3, 30.0)),
                  AreaLight("a", m, np.array([80.0, 20.0, 5.0]), "SQUARE", 0.5),
                  SunLight("s", sun_d, np.full(3, 2.0), angle=math.radians(5)),
                  PointLight("zero", W([0, 0, 1.0]), np.zeros(3))]
    scene = make_scene(light_list, world=0.1)
    # the zero-power light is dropped by validation; put it back to check that it is never selected
    scene.lights.append(PointLight("zero", W([0, 0, 1.0]), np.zeros(3)))
    R = 3.0
    s = lights.LightSampler(scene, SHIFT, et, R)
    assert s.kinds_present == {"triangle", "point", "area", "sun", "world"}
    lum = lights.luminance
    powers = np.array([lum([3.0] * 3) * 0.08 * 2 * math.pi] * 2 + [lum([30.0] * 3), lum([80.0, 20.0, 5.0]),
                                                                   lum([2.0] * 3) * math.pi * R * R,
                                                                   lum([0.1] * 3) * math.pi ** 2 * R * R])
    rng = np.random.default_rng(5)
    N = 400_000
    ls = s.sample(np.zeros((N, 3), np.float32), np.tile(UP, (N, 1)), rng.random(N), rng.random((N, 2)))
    probs = s.selection_probabilities(np.zeros((1, 3), np.float32), UP[None])
    assert set(probs) == {"triangles 0", "point 0", "area 0", "sun 0", "world"}  # the zero-power light: no unit
    assert abs(sum(float(v[0]) for v in probs.values()) - 1.0) < 1e-9
    # the power floor: every unit lit at the point keeps at least its share of SELECTION_POWER_FLOOR by power
    floor = lights.SELECTION_POWER_FLOOR * np.array([2 * powers[0]] + list(powers[2:])) / powers.sum()
    assert np.all(np.array([probs[k][0] for k in ("triangles 0", "point 0", "area 0", "sun 0", "world")]) >= floor)
    # the selection probability of the point light shows in its pdf and in how often it is picked
    p_point = float(probs["point 0"][0])
    frac_point = np.mean(ls.delta)
    assert abs(frac_point - p_point) < 4 * math.sqrt(p_point * (1 - p_point) / N)
    np.testing.assert_allclose(ls.pdf[ls.delta], p_point, rtol=1e-5)
    # the mixture estimate is the sum of the parts' closed forms
    expected = (30.0 / (4 * math.pi) / 4  # point at distance 2 overhead
                + parallel_rect_irradiance(80.0 / (math.pi * 0.25), 0.25, 0.75, -0.25, 0.25, 1.5)  # area light
                + 2.0  # sun from straight above
                + parallel_rect_irradiance(3.0, -0.7, -0.3, 0.1, 0.5, 1.2)  # the emissive quad
                + math.pi * 0.1)  # world
    est, se = estimate(s, np.zeros(3), count=400_000, seed=11)
    assert_close(est, se, expected)


# ------------------------------------------------------------------------------------- per-point selection
def selection(s, p, n=None, transmits=None):
    return {k: float(v[0]) for k, v in s.selection_probabilities(np.asarray([p], np.float32),
                                                                 None if n is None else np.asarray([n], np.float32),
                                                                 None if transmits is None else [transmits]).items()}


def test_selection_weighs_distance_orientation_and_cuts_what_cannot_contribute():
    a = lights.SELECTION_POWER_FLOOR
    near, far = PointLight("near", W([0, 0, 1.0]), np.full(3, P)), PointLight("far", W([0, 0, 3.0]), np.full(3, P))
    s = make_sampler([near, far])
    # equal powers straight above: importance I / d^2 -> 9 : 1, then the power floor
    got = selection(s, [0, 0, 0], UP, False)
    np.testing.assert_allclose([got["point 0"], got["point 1"]], [(1 - a) * 0.9 + a / 2, (1 - a) * 0.1 + a / 2],
                               rtol=1e-9)
    # a receiver cosine: the far light moved sideways to 45 degrees (distance 3) counts cos 45 as much
    side = make_sampler([near, PointLight("far", W([3 / math.sqrt(2), 0, 3 / math.sqrt(2)]), np.full(3, P))])
    got = selection(side, [0, 0, 0], UP, False)
    share = (1 / 9 * math.sqrt(0.5)) / (1 + 1 / 9 * math.sqrt(0.5))
    assert got["point 1"] == pytest.approx((1 - a) * share + a / 2, rel=1e-6)
    # both below a surface that only reflects: nothing can arrive; fall back to the power shares
    got = selection(s, [0, 0, 0], -UP, False)
    assert got["point 0"] == pytest.approx(0.5) and got["point 1"] == pytest.approx(0.5)
    # one above, one below: the one below is never picked; a transmitting surface sees both
    below = make_sampler([near, PointLight("below", W([0, 0, -3.0]), np.full(3, P))])
    assert selection(below, [0, 0, 0], UP, False) == {"point 0": 1.0, "point 1": 0.0}
    got = selection(below, [0, 0, 0], UP, True)
    assert got["point 1"] == pytest.approx((1 - a) * 0.1 + a / 2, rel=1e-6)
    # without a normal there is no hemisphere cut either
    assert selection(below, [0, 0, 0])["point 1"] == pytest.approx((1 - a) * 0.1 + a / 2, rel=1e-6)
    # a one-sided area light seen from behind, a spot seen from outside its cone: never picked
    m = area_matrix([0, 0, 1.0], [0, 0, 1])  # faces up, the point is below it
    m[:3, 3] = W(m[:3, 3])
    spot = spot_light(np.array([2.0, 0, 1.0]), [4.0, 0, 0], P, size=math.radians(40))
    s = make_sampler([near, AreaLight("a", m, np.full(3, P), "SQUARE", 0.5), spot])
    got = selection(s, [0, 0, 0])
    assert got["area 0"] == 0.0 and got["spot 1"] == 0.0 and got["point 0"] == 1.0
    assert selection(s, [0, 0, 2.0])["area 0"] > 0.5  # above the area light it is the nearest
    assert selection(s, [4.0, 0, 0])["spot 1"] > 0.5  # inside the cone


def test_one_unit_needs_no_per_point_work():
    s = make_sampler([PointLight("p", W([0, 0, 2.0]), np.full(3, P))])
    assert not s._per_point
    ls = s.sample(np.zeros((4, 3), np.float32), np.tile(-UP, (4, 1)), np.zeros(4), np.zeros((4, 2)),
                  transmits=np.zeros(4, bool))
    np.testing.assert_array_equal(ls.pdf, 1.0)  # even below the surface: probability 1, no importance computed
    tris = two_triangle_quad(np.array([0.0, 0.0, 1.0]), 0.3)
    et = lights.EmissiveTriangles.from_mesh_arrays(tris, np.zeros(2, int), np.array([[2.0] * 3]))
    assert not make_sampler([], tris=et)._per_point  # a quad lamp: one group of two triangles


def test_emissive_triangles_form_a_few_spatial_groups():
    verts, faces = lights_icosphere(4)
    tri = np.concatenate([verts[faces] * 0.2 + [-2.0, 0, 1], verts[faces] * 0.2 + [2.0, 0, 1]]).astype(np.float32)
    et = lights.EmissiveTriangles.from_mesh_arrays(tri, np.zeros(len(tri), int), np.array([[1.0] * 3]))
    s = make_sampler([], tris=et)
    groups = np.unique(s._tri_table.unit)
    assert 2 <= groups.size <= lights._MAX_TRIANGLE_GROUPS
    # no group straddles the two spheres, and the shares inside each group add up to 1
    for g in groups:
        x = tri[s._tri_table.unit == g][:, :, 0]
        assert np.all(x < 0) or np.all(x > 0)
        assert s._tri_table.sel[s._tri_table.unit == g].sum() == pytest.approx(1.0)
    # next to the left sphere its groups are picked far more often than the right sphere's
    probs = s.selection_probabilities(np.array([[-1.5, 0, 1]], np.float32), np.array([[-1.0, 0, 0]], np.float32),
                                      [False])
    left = sum(float(v[0]) for k, v in probs.items() if np.all(tri[s._tri_table.unit == int(k.split()[1])][:, :, 0] < 0))
    assert left > 0.9


def lights_icosphere(subdivisions):
    """A unit icosphere (vertices, faces) by subdividing an icosahedron."""
    t = (1 + math.sqrt(5)) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    verts = [np.array(x, float) / np.linalg.norm(x) for x in v]
    for _ in range(subdivisions):
        cache, nf = {}, []
        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return np.array(verts), np.array(f)


def one_light_of_each_kind(height: float, r: float, area: tuple) -> dict:
    """One light of each kind, keyed by name ("world": no light, the caller adds the world): the disc and sphere
    point lights `height` m up with radius r, the rectangle or square area light AreaLight(shape, sizes...) of
    `area`, an ellipse with spread, a sun."""
    sphere = PointLight("sphere", W([0.2, 0.1, height]), np.full(3, P), radius=r)
    sphere.soft_falloff = False
    inside = PointLight("inside", W([0.1, 0, 0.1]), np.full(3, P), radius=r)
    inside.soft_falloff = False
    m = area_matrix([0.3, -0.1, 1.0], [0, 0, -1])
    m[:3, 3] = W(m[:3, 3])
    me = area_matrix([-0.2, 0.1, 0.8], [0.3, 0, -1], scale=(1.0, 0.6, 1.0))
    me[:3, 3] = W(me[:3, 3])
    sun_d = np.array([0.2, 0.1, -1.0]) / np.linalg.norm([0.2, 0.1, -1.0])
    return {
        "disc point": [PointLight("p", W([0.3, 0, height]), np.full(3, P), radius=r)],
        "sphere point": [sphere],
        "inside sphere": [inside],
        "spot disc": [spot_light(np.array([0.4, 0.2, 1.2]), [0, 0, 0], P, radius=0.3, size=math.radians(70))],
        f"area {area[0].lower()}": [AreaLight("a", m, np.full(3, P), *area)],
        "area ellipse spread": [AreaLight("a", me, np.full(3, P), "ELLIPSE", 0.9, 0.7, spread=math.radians(90))],
        "sun": [SunLight("s", sun_d, np.full(3, 3.0), angle=math.radians(30))],
        "world": [],
    }


def consistency_cases():
    """Each light kind beside a delta point light (so that the selection is per point): (lights, world)."""
    return one_light_of_each_kind(1.5, 0.4, ("RECTANGLE", 0.8, 0.5))


def random_shading_points(rng, n, extent, offset):
    """n float32 points uniform in the box [-offset, extent - offset), unit normals uniform on the sphere
    (float32), and transmission flags (30% True), drawn from rng in that order."""
    p = (rng.random((n, 3)) * extent - offset).astype(np.float32)
    nn = rng.normal(size=(n, 3))
    nn = (nn / np.linalg.norm(nn, axis=1)[:, None]).astype(np.float32)
    return p, nn, rng.random(n) < 0.3


@pytest.mark.parametrize("case", list(consistency_cases()))
def test_intersect_pdf_is_the_sample_pdf_at_every_point(case):
    """MIS needs the light pdf of a direction twice: from `sample` and, when a BSDF ray hits the light, from
    `intersect`. With per-point selection both must use the same point, normal and transmission flag. Weighing
    each hit against a BSDF pdf equal to the sample's own pdf must give exactly 1/2."""
    delta = PointLight("delta", W([-0.6, 0.3, 0.7]), np.full(3, 2 * P))
    s = make_sampler(consistency_cases()[case] + [delta], world=0.5 if case == "world" else 0.0)
    assert s._per_point
    rng = np.random.default_rng(8)
    N = 40_000
    p, nn, tr = random_shading_points(rng, N, [2.0, 2.0, 1.0], [1.0, 1.0, 0.5])
    ls = s.sample(p, nn, rng.random(N, dtype=np.float32), rng.random((N, 2), dtype=np.float32), transmits=tr)
    rows = np.nonzero(~ls.delta & (ls.pdf > 0) & (ls.radiance[:, 0] > 0))[0]
    assert rows.size > N // 10
    tmax = np.where(np.isinf(ls.dist[rows]), np.inf, ls.dist[rows] * 1.001).astype(np.float32)
    le = s.intersect(p[rows], ls.wi[rows], tmax, ls.pdf[rows], np.zeros(rows.size, bool), True, n=nn[rows],
                     transmits=tr[rows])
    w = le[:, 0].astype(np.float64) / ls.radiance[rows, 0]
    np.testing.assert_allclose(np.median(w), 0.5, rtol=1e-6)
    assert np.mean(np.abs(w - 0.5) < 1e-3) > 0.999, np.sort(w)[[0, -1]]
    # the selection really varies from point to point (else this test would not test it)
    punctual = case in ("disc point", "sphere point", "inside sphere", "spot disc")
    pick = s.selection_probabilities(p[:2000], nn[:2000], tr[:2000])["point 1" if punctual else "point 0"]
    assert pick.max() - pick.min() > 0.3
    # and leaving the flags out where `sample` had them is an error, not a silent bias
    with pytest.raises(ValueError, match="transmission flags"):
        s.intersect(p[rows], ls.wi[rows], tmax, ls.pdf[rows], np.zeros(rows.size, bool), True, n=nn[rows])


def test_pdf_triangle_is_the_sample_pdf_at_every_point():
    verts, faces = lights_icosphere(3)
    tri = np.concatenate([verts[faces] * 0.3 + [-1.0, 0, 1], verts[faces] * 0.3 + [1.0, 0.5, 1.2]]).astype(np.float32)
    et = lights.EmissiveTriangles.from_mesh_arrays(tri, np.zeros(len(tri), int), np.array([[1.0, 2.0, 3.0]]))
    s = make_sampler([PointLight("delta", W([0, 0, 2.0]), np.full(3, P))], tris=et)
    assert s._per_point and np.unique(s._tri_table.unit).size > 2
    rng = np.random.default_rng(9)
    N = 20_000
    p, nn, tr = random_shading_points(rng, N, [4.0, 2.0, 0.5], [2.0, 1.0, 0.5])
    ls = s.sample(p, nn, rng.random(N), rng.random((N, 2)), transmits=tr)
    rows = np.nonzero(~ls.delta & (ls.pdf > 0))[0]
    q = p[rows].astype(np.float64) + ls.wi[rows] * ls.dist[rows, None]
    # the emitter each sample landed on: the triangle whose plane holds q and whose corners enclose it
    v = tri.astype(np.float64)
    nrm = et.normal.astype(np.float64)
    emitter = np.full(rows.size, -1)
    for e in range(len(tri)):
        a, b, c = v[e]
        on = np.abs((q - a) @ nrm[e]) < 1e-4
        if not on.any():
            continue
        w0 = np.cross(b - a, q[on] - a) @ nrm[e]
        w1 = np.cross(c - b, q[on] - b) @ nrm[e]
        w2 = np.cross(a - c, q[on] - c) @ nrm[e]
        inside = (w0 >= -1e-7) & (w1 >= -1e-7) & (w2 >= -1e-7)
        idx = np.nonzero(on)[0][inside]
        emitter[idx] = e
    found = emitter >= 0
    assert found.mean() > 0.99
    r = rows[found]
    cos = np.abs(np.einsum("ij,ij->i", ls.wi[r], et.normal[emitter[found]]))
    pdf = s.pdf_triangle(emitter[found], p[r], ls.dist[r] ** 2, cos, n=nn[r], transmits=tr[r])
    # (a point on a shared edge may be credited to the neighbour, which can differ in group or sampling mode)
    assert np.mean(np.abs(pdf / ls.pdf[r] - 1) < 1e-3) > 0.999


def test_per_point_selection_is_unbiased_where_it_changes_strongly():
    """Two area lights far apart over a floor: next to each, the selection favours it ~10:1. Light sampling,
    and MIS of light sampling with cosine-sampled BSDF rays, both give the closed-form irradiance at every point.
    Power: the smallest error it detects is 1 % (60k samples per point resolve it): assert_close's control, the
    closed form 1 % high and 1 % low must fail, runs at each point for both estimators."""
    La, Lb = 40.0, 10.0
    ma = area_matrix([-1.5, 0, 0.5], [0, 0, -1])
    ma[:3, 3] = W(ma[:3, 3])
    mb = area_matrix([1.5, 0, 1.5], [0, 0, -1])
    mb[:3, 3] = W(mb[:3, 3])
    s = make_sampler([AreaLight("a", ma, np.full(3, La * math.pi * 0.16), "SQUARE", 0.4),
                      AreaLight("b", mb, np.full(3, Lb * math.pi * 0.64), "SQUARE", 0.8)])
    rng = np.random.default_rng(12)
    N = 60_000
    picks = []
    for x in (-1.5, -0.5, 0.5, 1.5):
        expected = (parallel_rect_irradiance(La, -1.7 - x, -1.3 - x, -0.2, 0.2, 0.5)
                    + parallel_rect_irradiance(Lb, 1.1 - x, 1.9 - x, -0.4, 0.4, 1.5))
        p = np.tile(np.float32([x, 0, 0]), (N, 1))
        nn = np.tile(UP.astype(np.float32), (N, 1))
        tr = np.zeros(N, bool)
        picks.append(selection(s, [x, 0, 0], UP, False)["area 0"])
        ls = s.sample(p, nn, rng.random(N), rng.random((N, 2)), transmits=tr)
        cos_l = np.maximum(ls.wi[:, 2].astype(np.float64), 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            f_l = np.where(ls.pdf > 0, ls.radiance[:, 0] * cos_l / ls.pdf, 0)
        assert_close(f_l.mean(), f_l.std() / math.sqrt(N), expected)
        pl, pb = ls.pdf.astype(np.float64), cos_l / math.pi
        f_l *= np.where(pl > 0, pl * pl / (pl * pl + pb * pb), 0)
        d, pdf_b = cosine_directions(UP, N, rng)
        le = s.intersect(p, d, np.full(N, np.inf, np.float32), pdf_b, np.zeros(N, bool), True, n=nn, transmits=tr)
        f_b = le[:, 0].astype(np.float64) * math.pi
        assert_close(f_l.mean() + f_b.mean(), math.hypot(f_l.std(), f_b.std()) / math.sqrt(N), expected)
    assert picks[0] > 0.8 and picks[-1] < 0.3  # the selection does change strongly across the floor


def test_single_emitter_beside_zero_power_lights():
    scene = make_scene([PointLight("on", W([0, 0, 2.0]), np.full(3, P))])
    scene.lights.insert(0, PointLight("off", W([5, 5, 5.0]), np.zeros(3)))  # as if not validated
    s = lights.LightSampler(scene, SHIFT, None, 10.0)
    est, se = estimate(s, np.zeros(3), count=100)
    assert_close(est, se, P / (4 * math.pi) / 4, rel_floor=1e-5)


def test_mirrored_area_light_matrix():
    # a negative scale flips the light's handedness (the other branch of the spherical-rectangle frame)
    c = np.array([0.2, 0.1, 1.0])
    m = area_matrix(c, [0, 0, -1], scale=(-1.0, 1.0, 1.0))
    m[:3, 3] = W(c)
    s = make_sampler([AreaLight("a", m, np.full(3, P), "RECTANGLE", 0.6, 0.3)])
    L = P / (math.pi * 0.18)
    est, se = estimate(s, np.zeros(3))
    assert_close(est, se, parallel_rect_irradiance(L, c[0] - 0.3, c[0] + 0.3, c[1] - 0.15, c[1] + 0.15, c[2]))


def test_positions_are_relative_to_the_shift():
    m = area_matrix([0.3, 0, 1.0], [0, 0, -1])
    pl = PointLight("p", [1.0, 2.0, 3.0], np.full(3, P), radius=0.2)
    m0 = m.copy()
    a0 = AreaLight("a", m0, np.full(3, P), "SQUARE", 0.5)
    s0 = lights.LightSampler(make_scene([pl, a0]), np.zeros(3), None, 10.0)
    shift = np.array([1e5, -3e4, 7e3])
    m1 = m.copy()
    m1[:3, 3] += shift
    s1 = lights.LightSampler(make_scene([PointLight("p", np.array([1.0, 2.0, 3.0]) + shift, np.full(3, P), radius=0.2),
                                         AreaLight("a", m1, np.full(3, P), "SQUARE", 0.5)]), shift, None, 10.0)
    rng = np.random.default_rng(2)
    p = rng.normal(size=(1000, 3)).astype(np.float32)
    us, u = rng.random(1000), rng.random((1000, 2))
    a, b = s0.sample(p, None, us, u), s1.sample(p, None, us, u)
    np.testing.assert_allclose(a.wi, b.wi, atol=1e-4)
    np.testing.assert_allclose(a.pdf, b.pdf, rtol=1e-3)


# ---------------------------------------------------------------------------------------------------- MIS
def cosine_directions(n, count, rng):
    u1, u2 = rng.random(count), rng.random(count)
    r, phi = np.sqrt(u1), 2 * math.pi * u2
    t = np.cross(n, [0.3, 0.5, 0.8])
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    d = np.outer(r * np.cos(phi), t) + np.outer(r * np.sin(phi), b) + np.outer(np.sqrt(1 - u1), n)
    return d.astype(np.float32), (np.sqrt(1 - u1) / math.pi).astype(np.float32)


def mis_cases():
    """Each light kind alone (the world at 0.7), and a point, a square and a sun together under a 0.2 world:
    (lights, world)."""
    kinds = one_light_of_each_kind(2.0, 0.5, ("SQUARE", 0.8))
    cases = {name: (lights, 0.7 if name == "world" else 0.0) for name, lights in kinds.items()}
    cases["all"] = (kinds["disc point"] + kinds["area square"] + kinds["sun"], 0.2)
    return cases


@pytest.mark.parametrize("case", list(mis_cases()))
def test_intersect_agrees_with_sample_and_mis_sums(case):
    light_list, world = mis_cases()[case]
    s = make_sampler(light_list, world=world)
    rng = np.random.default_rng(7)
    N = 300_000
    n = np.array([0.1, -0.2, 1.0])
    n /= np.linalg.norm(n)
    p = np.zeros((N, 3), np.float32)
    nn = np.tile(n.astype(np.float32), (N, 1))
    # light sampling, no MIS: the reference value
    ls = s.sample(p, nn, rng.random(N, dtype=np.float32), rng.random((N, 2), dtype=np.float32))
    cos_l = np.maximum(np.einsum("ij,ij->i", ls.wi.astype(np.float64), nn), 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        f_light = np.where(ls.pdf > 0, ls.radiance[:, 0] * cos_l / ls.pdf, 0)
    ref, ref_se = f_light.mean(), f_light.std() / math.sqrt(N)
    # BSDF (cosine) sampling with intersect, no MIS
    d, pdf_b = cosine_directions(n, N, rng)
    tinf = np.full(N, np.inf, np.float32)
    le = s.intersect(p, d, tinf, pdf_b, np.zeros(N, bool), False, n=nn)
    f_bsdf = le[:, 0].astype(np.float64) * math.pi
    est, se = f_bsdf.mean(), f_bsdf.std() / math.sqrt(N)
    assert abs(est - ref) <= 4 * math.hypot(se, ref_se) + 1e-4 * abs(ref), (est, se, ref, ref_se)
    # MIS: the two weighted estimators add up to the same value
    le_mis = s.intersect(p, d, tinf, pdf_b, np.zeros(N, bool), True, n=nn)
    f_b = le_mis[:, 0].astype(np.float64) * math.pi
    pdf_b_l = cos_l / math.pi
    pl = ls.pdf.astype(np.float64)
    w_l = np.where(ls.delta, 1.0, np.where(pl > 0, pl * pl / (pl * pl + pdf_b_l * pdf_b_l), 0))
    f_l = f_light * w_l
    tot = f_b.mean() + f_l.mean()
    tot_se = math.hypot(f_b.std(), f_l.std()) / math.sqrt(N)
    assert abs(tot - ref) <= 4 * math.hypot(tot_se, ref_se) + 1e-4 * abs(ref), (tot, tot_se, ref, ref_se)
    # MIS must lower the variance against either strategy alone on these smooth cases
    assert tot_se <= 1.05 * max(se, ref_se)
    # a delta BSDF (mirror) or mis=False takes the emission unweighted
    le_delta = s.intersect(p, d, tinf, pdf_b, np.ones(N, bool), True, n=nn)
    np.testing.assert_allclose(le_delta, le, rtol=1e-6)


def ray_triangles(o, d, tris):
    """Closest hit of rays (N, 3) over a few triangles (Moller-Trumbore, float64): (t, index), inf / -1 if none."""
    best, idx = np.full(o.shape[0], np.inf), np.full(o.shape[0], -1)
    for k, (a, b, c) in enumerate(np.asarray(tris, np.float64)):
        e1, e2 = b - a, c - a
        pv = np.cross(d, e2)
        inv = 1.0 / (pv @ e1)
        tv = o - a
        qv = np.cross(tv, e1)
        u, v, t = (tv * pv).sum(1) * inv, (d * qv).sum(1) * inv, (qv @ e2) * inv
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < best)
        best, idx = np.where(hit, t, best), np.where(hit, k, idx)
    return best, idx


@pytest.mark.parametrize("height", [1.0, 0.05])
def test_triangle_mis_with_pdf_triangle_sums_to_the_closed_form(height):
    """What the integrator does for an emissive triangle hit by a BSDF ray, against light sampling. At height
    1.0 the quad is sampled by area, at 0.05 (edges longer than the distance) by solid angle."""
    c, half, Le = np.array([0.2, -0.1, height]), 0.4, 2.0
    tris = two_triangle_quad(c, half)
    et = lights.EmissiveTriangles.from_mesh_arrays(tris, np.zeros(2, int), np.array([[Le] * 3]))
    s = make_sampler([PointLight("p", W([0, 0, 2.0]), np.full(3, 30.0))], tris=et)
    expected = (parallel_rect_irradiance(Le, c[0] - half, c[0] + half, c[1] - half, c[1] + half, c[2])
                + 30 / (4 * math.pi) / 4)
    rng = np.random.default_rng(4)
    N = 300_000
    p, nn = np.zeros((N, 3), np.float32), np.tile(UP.astype(np.float32), (N, 1))
    ls = s.sample(p, nn, rng.random(N), rng.random((N, 2)))
    cos_l = np.maximum(ls.wi[:, 2].astype(np.float64), 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        f_l = np.where(ls.pdf > 0, ls.radiance[:, 0] * cos_l / ls.pdf, 0)
    pl, pb = ls.pdf.astype(np.float64), cos_l / math.pi
    f_l *= np.where(ls.delta, 1.0, pl * pl / (pl * pl + pb * pb))
    d, pdf_b = cosine_directions(UP, N, rng)
    t, k = ray_triangles(np.zeros((N, 3)), d.astype(np.float64), tris)
    hit = k >= 0
    pdf_t = s.pdf_triangle(np.where(hit, et.emitter_of_triangle[np.maximum(k, 0)], -1), np.zeros((N, 3)), t * t,
                           np.abs(d[:, 2]), n=nn)
    pb2 = pdf_b.astype(np.float64) ** 2
    f_b = np.where(hit, Le * math.pi * pb2 / (pb2 + pdf_t.astype(np.float64) ** 2), 0)
    est = f_l.mean() + f_b.mean()
    se = math.hypot(f_l.std(), f_b.std()) / math.sqrt(N)
    assert_close(est, se, expected)


def test_intersect_needs_the_normal_that_sample_got():
    s = make_sampler([], world=1.0)
    p, nn = np.zeros((2, 3), np.float32), np.tile(UP.astype(np.float32), (2, 1))
    d, tinf, pdf = nn, np.full(2, np.inf, np.float32), np.ones(2, np.float32)
    s.intersect(p, d, tinf, pdf, np.zeros(2, bool), True)  # nothing sampled about a normal yet: uniform pdf
    s.sample(p, nn, np.zeros(2), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="pass the same normal"):
        s.intersect(p, d, tinf, pdf, np.zeros(2, bool), True)
    out = s.intersect(p, d, tinf, pdf, np.zeros(2, bool), True, n=nn)
    np.testing.assert_allclose(out, 1 / (1 + 1 / math.pi ** 2), rtol=1e-6)  # BSDF pdf 1 vs light pdf 1 / pi
    s.intersect(p, d, tinf, pdf, np.zeros(2, bool), False)  # without MIS n is not needed


def test_intersect_respects_tmax_and_camera_visibility():
    m = area_matrix([0, 0, 1.0], [0, 0, -1])
    m[:3, 3] = W(m[:3, 3])
    s = make_sampler([AreaLight("a", m, np.full(3, P), "SQUARE", 1.0),
                      PointLight("p", W([0, 0, 2.0]), np.full(3, P), radius=0.3),
                      SunLight("s", [0, 0, -1.0], np.full(3, 1.0), angle=0.2)], world=0.5)
    o = np.zeros((4, 3), np.float32)
    d = np.tile(np.float32([0, 0, 1]), (4, 1))
    tmax = np.array([0.5, 1.5, 2.5, np.inf], np.float32)
    out = s.intersect(o, d, tmax, np.ones(4), np.zeros(4, bool), False)
    La, Lp = P / math.pi, P / (4 * math.pi ** 2 * 0.09)
    Ls = 1.0 / (math.pi * math.sin(0.1) ** 2)
    np.testing.assert_allclose(out[:, 0], [0, La, La + Lp, La + Lp + Ls + 0.5], rtol=1e-5)
    cam = s.intersect(o, d, tmax, np.ones(4), np.zeros(4, bool), False, camera=True)
    np.testing.assert_allclose(cam[:, 0], [0, 0, 0, 0.5], rtol=1e-6)  # Cycles: lights invisible to the camera
    down = s.intersect(o, -d, np.full(4, np.inf), np.ones(4), np.zeros(4, bool), False)
    np.testing.assert_allclose(down[:, 0], 0.5, rtol=1e-6)  # nothing but the world below
    back = s.intersect(np.tile(np.float32([0, 0, 3]), (1, 1)), -d[:1], np.full(1, 2.5, np.float32), np.ones(1),
                       np.zeros(1, bool), False)
    np.testing.assert_allclose(back[:, 0], Lp, rtol=1e-5)  # the area light's back face emits nothing


# --------------------------------------------------------------------------------------------------- Cycles
HAVE_BPY = importlib.util.find_spec("bpy") is not None

_BPY_SCRIPT = r'''
import json, math, sys
import bpy, mathutils
specs = json.loads(open(sys.argv[1]).read())
out_dir = sys.argv[2]
def track(d):
    return mathutils.Vector(d).normalized().to_track_quat('-Z', 'Y').to_matrix().to_4x4()
for spec in specs:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = 'CYCLES'
    c = sc.cycles
    c.device = 'CPU'; c.samples = spec['spp']; c.use_adaptive_sampling = False; c.use_denoising = False
    c.max_bounces = 0; c.diffuse_bounces = 0; c.glossy_bounces = 0; c.transmission_bounces = 0
    c.pixel_filter_type = 'BOX'; c.filter_width = 1.0; c.seed = 1
    c.sample_clamp_direct = 0.0; c.sample_clamp_indirect = 0.0
    sc.render.resolution_x = sc.render.resolution_y = spec['res']; sc.render.resolution_percentage = 100
    sc.render.threads_mode = 'FIXED'; sc.render.threads = 2
    sc.render.image_settings.file_format = 'OPEN_EXR'; sc.render.image_settings.color_depth = '32'
    sc.world = bpy.data.worlds.new('W')
    sc.world.use_nodes = True
    bg = sc.world.node_tree.nodes['Background']
    bg.inputs['Color'].default_value = (*spec['world'], 1.0); bg.inputs['Strength'].default_value = 1.0
    if spec['surface'] != 'none':
        me = bpy.data.meshes.new('plane'); h = 50.0
        me.from_pydata([(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [], [(0, 1, 2, 3)])
        ob = bpy.data.objects.new('plane', me); sc.collection.objects.link(ob)
        mat = bpy.data.materials.new('m'); mat.use_nodes = True; nt = mat.node_tree; nt.nodes.clear()
        out = nt.nodes.new('ShaderNodeOutputMaterial')
        if spec['surface'] == 'diffuse':
            b = nt.nodes.new('ShaderNodeBsdfDiffuse'); b.inputs['Color'].default_value = (spec['albedo'],) * 3 + (1,)
        else:
            b = nt.nodes.new('ShaderNodeBsdfGlossy'); b.inputs['Roughness'].default_value = 0.0
            b.inputs['Color'].default_value = (1, 1, 1, 1)
        nt.links.new(b.outputs[0], out.inputs['Surface']); me.materials.append(mat)
    for i, q in enumerate(spec.get('emitters', [])):
        me = bpy.data.meshes.new('e%d' % i)
        me.from_pydata([tuple(v) for v in q['verts']], [], [(0, 1, 2, 3)])
        ob = bpy.data.objects.new('e%d' % i, me); sc.collection.objects.link(ob)
        mat = bpy.data.materials.new('e%d' % i); mat.use_nodes = True; nt = mat.node_tree; nt.nodes.clear()
        out = nt.nodes.new('ShaderNodeOutputMaterial'); e = nt.nodes.new('ShaderNodeEmission')
        e.inputs['Color'].default_value = (1, 1, 1, 1); e.inputs['Strength'].default_value = q['strength']
        nt.links.new(e.outputs[0], out.inputs['Surface']); me.materials.append(mat)
    for i, L in enumerate(spec['lights']):
        ld = bpy.data.lights.new('l%d' % i, L['type'])
        if L['type'] == 'SUN':
            ld.energy = L['strength']; ld.angle = L['angle']
            mw = track(L['dir'])
        elif L['type'] == 'AREA':
            ld.energy = L['power']; ld.shape = L['shape']; ld.size = L['size_x']; ld.size_y = L['size_y']
            ld.spread = L['spread']
            mw = mathutils.Matrix(L['matrix'])
        else:
            ld.energy = L['power']; ld.shadow_soft_size = L['radius']; ld.use_soft_falloff = L['soft_falloff']
            mw = track(L['dir']) if L['type'] == 'SPOT' else mathutils.Matrix.Identity(4)
            if L['type'] == 'SPOT':
                ld.spot_size = L['size']; ld.spot_blend = L['blend']
            mw.translation = mathutils.Vector(L['loc'])
        ob = bpy.data.objects.new('l%d' % i, ld); sc.collection.objects.link(ob)
        ob.matrix_world = mw
    cd = bpy.data.cameras.new('cam'); cd.type = 'ORTHO'; cd.ortho_scale = spec['view'][2]
    cd.clip_start = 0.01; cd.clip_end = 1000.0
    cam = bpy.data.objects.new('cam', cd); cam.location = (spec['view'][0], spec['view'][1], spec['cam_z'])
    sc.collection.objects.link(cam); sc.camera = cam
    sc.render.filepath = out_dir + '/' + spec['name'] + '.exr'
    bpy.ops.render.render(write_still=True)
'''


def render_with_cycles(specs, tmp_path):
    spec_file = tmp_path / "specs.json"
    spec_file.write_text(json.dumps(specs))
    script = tmp_path / "render.py"
    script.write_text(_BPY_SCRIPT)
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, str(script), str(spec_file), str(tmp_path)], capture_output=True,
                          text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    import OpenEXR
    images = {}
    for spec in specs:
        ch = OpenEXR.File(str(tmp_path / f"{spec['name']}.exr")).channels()
        img = ch["RGBA"].pixels if "RGBA" in ch else ch["RGB"].pixels
        images[spec["name"]] = np.asarray(img, dtype=np.float64)[..., :3]
    return images


def spec_to_sampler(spec) -> lights.LightSampler:
    """The same lights as Monte scene objects (positions in world space; the sampler gets SHIFT)."""
    out = []
    for L in spec["lights"]:
        if L["type"] == "POINT":
            pl = PointLight("p", W(L["loc"]), np.full(3, L["power"]), radius=L["radius"])
            pl.soft_falloff = L["soft_falloff"]
            out.append(pl)
        elif L["type"] == "SPOT":
            sl = SpotLight("s", W(L["loc"]), np.asarray(L["dir"]), np.full(3, L["power"]), radius=L["radius"],
                           spot_size=L["size"], spot_blend=L["blend"])
            sl.soft_falloff = L["soft_falloff"]
            out.append(sl)
        elif L["type"] == "SUN":
            out.append(SunLight("sun", np.asarray(L["dir"]), np.full(3, L["strength"]), angle=L["angle"]))
        else:
            m = np.array(L["matrix"], dtype=np.float64)
            m[:3, 3] = W(m[:3, 3])
            out.append(AreaLight("a", m, np.full(3, L["power"]), L["shape"], L["size_x"], L["size_y"],
                                 spread=L["spread"]))
    tris = None
    if spec.get("emitters"):
        quads = np.array([q["verts"] for q in spec["emitters"]], np.float32)  # (Q, 4, 3)
        t = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        strength = np.array([q["strength"] for q in spec["emitters"]] * 2)
        tris = lights.EmissiveTriangles.from_mesh_arrays(t, np.arange(t.shape[0]), np.repeat(strength[:, None], 3, 1))
    return make_sampler(out, world=spec["world"], tris=tris)


def monte_image(spec, per_pixel=2048, seed=0):
    """Monte's expected pixel values for the Cycles setup: jittered points over each pixel's footprint, light
    sampling for the diffuse plane (rho / pi x irradiance), `intersect` of the reflected ray for the mirror."""
    s = spec_to_sampler(spec)
    res, (cx, cy, size) = spec["res"], spec["view"]
    rng = np.random.default_rng(seed)
    iy, ix = np.divmod(np.repeat(np.arange(res * res), per_pixel), res)
    x = cx - size / 2 + (ix + rng.random(ix.size)) * size / res
    y = cy + size / 2 - (iy + rng.random(iy.size)) * size / res  # row 0 at the top
    p = np.stack([x, y, np.zeros_like(x)], 1).astype(np.float32)
    N = p.shape[0]
    nn = np.tile(UP.astype(np.float32), (N, 1))
    if spec["surface"] == "diffuse":
        ls = s.sample(p, nn, rng.random(N, dtype=np.float32), rng.random((N, 2), dtype=np.float32))
        cos = np.maximum(ls.wi[:, 2], 0).astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(ls.pdf > 0, ls.radiance[:, 0] * cos / ls.pdf, 0) * spec["albedo"] / math.pi
    elif spec["surface"] == "mirror":
        f = s.intersect(p, nn, np.full(N, np.inf), np.ones(N), np.ones(N, bool), False, n=nn)[:, 0]
    else:  # camera rays from the orthographic camera straight down, through the lights, into the world
        o = p + np.float32([0, 0, spec["cam_z"]])
        f = s.intersect(o, -nn, np.full(N, np.inf), np.ones(N), np.ones(N, bool), False, camera=True)[:, 0]
    f = f.reshape(res, res, per_pixel).astype(np.float64)
    return f.mean(-1), f.std(-1) / math.sqrt(per_pixel)


def base_spec(name, lights_, surface="diffuse", world=(0.0, 0.0, 0.0), spp=256, res=16, view=(0.0, 0.0, 0.4),
              emitters=()):
    return dict(name=name, lights=lights_, surface=surface, world=list(world), spp=spp, res=res, view=list(view),
                albedo=0.8, cam_z=5.0, emitters=list(emitters))


def point_spec(**kw):
    d = dict(type="POINT", loc=[1.0, 0.5, 1.0], power=100.0, radius=0.0, soft_falloff=True, dir=[0, 0, -1.0])
    d.update(kw)
    return d


def cycles_specs():
    area_m = area_matrix([0.3, -0.2, 1.0], [0.2, 0.1, -1.0], x_hint=(1, 0.4, 0), scale=(1.2, 0.8, 1.0))
    sun_dir = [0.3, -0.2, -1.0]
    spot_dir = (np.array([0.05, 0.0, 0.0]) - [0.6, 0.3, 0.8]).tolist()
    return [
        base_spec("point_soft_disc", [point_spec(radius=0.3)]),
        base_spec("point_sphere", [point_spec(radius=0.3, soft_falloff=False, loc=[0.5, 0.3, 0.6])]),
        base_spec("spot", [point_spec(type="SPOT", loc=[0.6, 0.3, 0.8], dir=spot_dir, size=math.radians(20),
                                      blend=0.4)]),
        base_spec("spot_disc", [point_spec(type="SPOT", loc=[0.6, 0.3, 0.8], dir=spot_dir, radius=0.1,
                                           size=math.radians(20), blend=0.4)]),
        base_spec("spot_sphere", [point_spec(type="SPOT", loc=[0.6, 0.3, 0.8], dir=spot_dir, radius=0.1,
                                             soft_falloff=False, size=math.radians(20), blend=0.4)]),
        base_spec("sun", [dict(type="SUN", dir=sun_dir, strength=3.0, angle=math.radians(10))]),
        base_spec("area_rect", [dict(type="AREA", matrix=area_m.tolist(), power=100.0, shape="RECTANGLE",
                                     size_x=0.5, size_y=0.2, spread=math.pi)]),
        base_spec("area_disk_spread", [dict(type="AREA", matrix=area_matrix([0.1, 0.05, 0.8], [0, 0, -1]).tolist(),
                                            power=100.0, shape="DISK", size_x=0.5, size_y=0.5,
                                            spread=math.radians(60))]),
        base_spec("world", [], world=(0.5, 0.25, 0.1)),
        # the quad's normal points up: the plane below sees its back face
        base_spec("mesh_back_face", [], emitters=[dict(strength=2.0, verts=[[0.65, 0.2, 0.5], [0.25, 0.2, 0.6],
                                                                            [0.25, -0.2, 0.6], [0.65, -0.2, 0.5]])]),
        # a mirror: what BSDF rays see of each light kind; the camera rays pass through the lights first
        base_spec("mirror", [point_spec(loc=[-0.1, -0.1, 1.0], radius=0.08),
                             point_spec(loc=[0.1, 0.1, 1.5], radius=0.07, soft_falloff=False),
                             dict(type="AREA", matrix=area_matrix([0.1, -0.1, 2.0], [0, 0, -1]).tolist(),
                                  power=10.0, shape="SQUARE", size_x=0.1, size_y=0.1, spread=math.pi),
                             dict(type="SUN", dir=[0.0, 0.01, -1.0], strength=1.0, angle=math.radians(3))],
                  surface="mirror", spp=64),
        base_spec("camera_world", [point_spec(loc=[0.0, 0.0, 1.0], radius=0.5)], surface="none",
                  world=(0.3, 0.3, 0.3), spp=4),
    ]


def compare(name, img, spec, tol=0.01):
    mean, se = monte_image(spec)
    cyc = img[..., 0]
    assert cyc.shape == mean.shape
    c_mean, m_mean = cyc.mean(), mean.mean()
    m_se = math.sqrt((se ** 2).sum()) / se.size
    assert abs(c_mean - m_mean) <= tol * abs(m_mean) + 4 * m_se, f"{name}: Cycles {c_mean:.6g} Monte {m_mean:.6g}"
    # The control: these unit checks (tolerance `tol` for Cycles' own noise, + 4 sigma of Monte's) detect 2 tol;
    # Monte's mean off by that must fail. (The 1 % check of every light kind: test_crosscheck.py's test_light.)
    for wrong in (1 + 2 * tol, 1 - 2 * tol):
        assert abs(c_mean - wrong * m_mean) > tol * abs(wrong * m_mean) + 4 * m_se, f"{name}: {wrong} x Monte passes"
    # 4 x 4 blocks: the light is where Cycles has it
    r = spec["res"] // 4
    cb = cyc.reshape(4, r, 4, r).mean((1, 3))
    mb = mean.reshape(4, r, 4, r).mean((1, 3))
    scale = max(abs(m_mean), 1e-6)
    assert np.all(np.abs(cb - mb) <= 0.03 * np.abs(mb) + 0.01 * scale), f"{name}: blocks\n{cb}\n{mb}"
    print(f"{name}: Cycles {c_mean:.6g}, Monte {m_mean:.6g} +- {m_se:.2g}, ratio {c_mean / m_mean:.5f}")
    return c_mean, m_mean


@pytest.mark.blender
@pytest.mark.skipif(not HAVE_BPY, reason="needs the bpy module")
def test_cycles_point_light_units(tmp_path):
    """Fast cross-check: Cycles' diffuse plane under a 100 W point light equals rho / pi x P / (4 pi) cos / d^2."""
    spec = base_spec("point", [point_spec()])
    img = render_with_cycles([spec], tmp_path)["point"]
    c_mean, m_mean = compare("point", img, spec, tol=0.003)
    # and the closed form at the view's centre pixel region
    v = np.array([1.0, 0.5, 1.0])
    assert abs(c_mean - 0.8 / math.pi * 100 / (4 * math.pi) * v[2] / np.linalg.norm(v) ** 3) < 0.01 * c_mean


@pytest.fixture(scope="module")
def cycles_images(tmp_path_factory):
    specs = cycles_specs()
    return specs, render_with_cycles(specs, tmp_path_factory.mktemp("cycles"))


@pytest.mark.blender
@pytest.mark.skipif(not HAVE_BPY, reason="needs the bpy module")
@pytest.mark.parametrize("name", [s["name"] for s in cycles_specs()])
def test_cycles_units(cycles_images, name):
    specs, images = cycles_images
    spec = next(s for s in specs if s["name"] == name)
    compare(name, images[name], spec)


def test_near_triangles_are_sampled_by_solid_angle_without_fireflies():
    """A quad 1 cm above the shading point: light sampling alone gives the closed-form irradiance, and every
    sample has the same weight (uniform in solid angle: radiance / pdf = Le x solid angle / selection)."""
    c, half, Le = np.array([0.0, 0.0, 0.01]), 0.3, 1.5
    tris = two_triangle_quad(c, half)
    et = lights.EmissiveTriangles.from_mesh_arrays(tris, np.zeros(2, int), np.array([[Le] * 3]))
    s = make_sampler([], tris=et)
    rng = np.random.default_rng(5)
    N = 200_000
    p = np.zeros((N, 3), np.float32)
    ls = s.sample(p, np.tile(UP.astype(np.float32), (N, 1)), rng.random(N), rng.random((N, 2)))
    assert np.all(ls.pdf > 0) and np.all(np.isfinite(ls.dist)) and np.all(ls.dist > 0)
    q = ls.wi * ls.dist[:, None]
    np.testing.assert_allclose(q[:, 2], 0.01, atol=1e-5)  # the sampled points lie on the quad
    assert np.all(np.abs(q[:, :2]) <= half + 1e-4)
    weight = ls.radiance[:, 0] / ls.pdf
    for side in (q[:, 0] > q[:, 1] + 1e-3, q[:, 0] < q[:, 1] - 1e-3):  # the two triangles of the quad
        assert np.ptp(weight[side]) < 1e-3 * weight[side].mean()  # constant weight within a triangle
    f = weight * np.maximum(ls.wi[:, 2], 0)
    expected = parallel_rect_irradiance(Le, -half, half, -half, half, 0.01)
    assert_close(f.mean(), f.std() / math.sqrt(N), expected)


def test_spherical_triangle_sampler_is_arvos_map():
    """The solid-angle sampler of near triangles (given the solid angle and corner distances that the near test
    computed) is Arvo's map, checked by its two defining properties in float64: u0 picks the corner c' on arc ac
    whose sub-triangle (a, b, c') has solid angle u0 x omega (measured independently, Van Oosterom-Strackee), and
    u1 picks the point on arc bc' with 1 - cos(angle to b) = u1 (1 - cos(angle from b to c'))."""
    from monte.core.light_kernels import _solid_angle, _spherical_triangle_direction
    rng = np.random.default_rng(11)
    for _ in range(300):
        a, b, c = rng.normal(size=(3, 3)) + rng.normal(size=3) * rng.uniform(0, 3)
        omega, la, lb, lc = _solid_angle(*a, *b, *c)
        np.testing.assert_allclose([la, lb, lc], np.linalg.norm([a, b, c], axis=1), rtol=1e-15)
        if omega < 1e-3:
            continue
        u0 = rng.uniform(0.02, 1.0)
        c1 = np.array(_spherical_triangle_direction(*a, *b, *c, la, lb, lc, omega, u0, 1.0))
        assert math.isclose(np.linalg.norm(c1), 1.0, abs_tol=1e-12)
        # c' lies on the great circle through a and c, between them
        assert abs(np.dot(c1, np.cross(a, c))) < 1e-9 * np.linalg.norm(np.cross(a, c))
        ua, uc = a / la, c / lc
        assert np.dot(c1, ua) >= np.dot(uc, ua) - 1e-9 and np.dot(c1, uc) >= np.dot(ua, uc) - 1e-9
        assert math.isclose(_solid_angle(*a, *b, *c1)[0], u0 * omega, rel_tol=1e-7, abs_tol=1e-9)
        u1 = rng.uniform()
        w = np.array(_spherical_triangle_direction(*a, *b, *c, la, lb, lc, omega, u0, u1))
        ub = b / lb
        assert math.isclose(1.0 - np.dot(w, ub), u1 * (1.0 - np.dot(c1, ub)), rel_tol=1e-6, abs_tol=1e-12)
        assert abs(np.dot(w, np.cross(ub, c1))) < 1e-9  # on arc b c'
    # u0 = 1 is corner c itself: the whole triangle
    a, b, c = np.array([0.3, -0.2, 1.0]), np.array([-0.4, 0.1, 0.9]), np.array([0.1, 0.5, 1.2])
    omega, la, lb, lc = _solid_angle(*a, *b, *c)
    np.testing.assert_allclose(_spherical_triangle_direction(*a, *b, *c, la, lb, lc, omega, 1.0, 1.0), c / lc,
                               atol=1e-9)



# ------------------------------------------------------------------------------------ chi-square of sampling
# Each light kind alone, sampled from one shading point: the directions `sample` draws, binned on the light
# (equal-area cells of its surface, or equal-solid-angle cells of its cone), against the counts its own pdf
# predicts (the pdf `intersect` weighs MIS with, which `test_intersect_pdf_is_the_sample_pdf_at_every_point`
# ties to `sample`'s; for emissive triangles `pdf_triangle`), integrated over each cell by Gauss-Legendre
# quadrature. Pearson's statistic over 64 cells at the 99.9 % quantile: a correct sampler fails 1 run in 1000
# (the seeds are fixed, so a run either passes or not). Power: with N = 200k samples, a pdf 5 % too high over
# the cells holding half the mass and 5 % too low over the rest adds N x 0.05^2 = 500 to the statistic (critical
# value ~106): the built-in control below must fail, in every case.
CHI2_SAMPLES = 200_000
CHI2_CELLS = 8  # per axis: 64 cells
CHI2_QUAD = 4  # Gauss-Legendre points per cell and axis


def direction_pdf(s, p, n, d):
    """Solid-angle pdf (selection included) of `s.sample` at point p (3,) with normal n (3,) for directions d
    (M, 3), recovered from `intersect`: a BSDF ray of pdf b gets the power-heuristic weight w = b^2 / (b^2 + pl^2),
    so pl = b sqrt((1 - w) / w); a second pass with b = pl keeps w near 1/2 (float32 precision)."""
    M = d.shape[0]
    P0 = np.tile(np.float32(p), (M, 1))
    Nn = np.tile(np.float32(n), (M, 1))
    tinf = np.full(M, np.inf, np.float32)
    d = d.astype(np.float32)
    le = s.intersect(P0, d, tinf, np.ones(M), np.zeros(M, bool), False, n=Nn)[:, 0].astype(np.float64)
    b = np.ones(M)
    seen = le > 0
    for _ in range(2):
        w = s.intersect(P0, d, tinf, b, np.zeros(M, bool), True, n=Nn)[:, 0].astype(np.float64)
        w = np.where(seen, w / np.where(seen, le, 1.0), 0.0)
        b = np.where(seen & (w > 0), b * np.sqrt(np.maximum(1 - w, 0) / np.maximum(w, 1e-300)), 1.0)
    return np.where(seen, b, 0.0)


def frame(axis):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.cross(axis, [0.3, 0.5, 0.8])
    a /= np.linalg.norm(a)
    return a, np.cross(axis, a), axis


def cell_grid(lo0, hi0, lo1, hi1):
    """Quadrature over CHI2_CELLS^2 equal cells of [lo0, hi0] x [lo1, hi1]: (x0, x1, weight, cell) flat."""
    x, w = np.polynomial.legendre.leggauss(CHI2_QUAD)
    e0, e1 = np.linspace(lo0, hi0, CHI2_CELLS + 1), np.linspace(lo1, hi1, CHI2_CELLS + 1)
    h0, h1 = np.diff(e0)[0] / 2, np.diff(e1)[0] / 2
    c0 = (e0[:-1, None] + h0 * (1 + x)).reshape(-1)  # (cells * quad,)
    c1 = (e1[:-1, None] + h1 * (1 + x)).reshape(-1)
    w0, w1 = np.tile(w * h0, CHI2_CELLS), np.tile(w * h1, CHI2_CELLS)
    i0, i1 = np.repeat(np.arange(CHI2_CELLS), CHI2_QUAD), np.repeat(np.arange(CHI2_CELLS), CHI2_QUAD)
    X0, X1 = np.meshgrid(c0, c1, indexing="ij")
    W0, W1 = np.meshgrid(w0, w1, indexing="ij")
    I0, I1 = np.meshgrid(i0, i1, indexing="ij")
    return X0.ravel(), X1.ravel(), (W0 * W1).ravel(), (I0 * CHI2_CELLS + I1).ravel()


def cell_of(v0, v1, lo0, hi0, lo1, hi1):
    i0 = np.clip(((v0 - lo0) / (hi0 - lo0) * CHI2_CELLS).astype(int), 0, CHI2_CELLS - 1)
    i1 = np.clip(((v1 - lo1) / (hi1 - lo1) * CHI2_CELLS).astype(int), 0, CHI2_CELLS - 1)
    return i0 * CHI2_CELLS + i1


def chi2_case(name):
    """(sampler, point, normal, cells of the samples' (wi, dist) (N,), expected probability per cell (64,))."""
    p, n = np.zeros(3), UP
    if name in ("area rectangle", "area ellipse spread"):
        c = np.array([0.3, -0.1, 1.0])
        if name == "area rectangle":
            m, lx, ly = area_matrix(c, [0.2, 0, -1]), 0.8, 0.5
            light = AreaLight("a", m.copy(), np.full(3, P), "RECTANGLE", lx, ly)
        else:
            m, lx, ly = area_matrix(c, [0, 0.3, -1], scale=(1.0, 0.6, 1.0)), 0.9, 0.7 * 0.6
            light = AreaLight("a", m.copy(), np.full(3, P), "ELLIPSE", 0.9, 0.7, spread=math.radians(90))
        light.matrix_world[:3, 3] = W(c)
        ax, ay = m[:3, 0] / np.linalg.norm(m[:3, 0]), m[:3, 1] / np.linalg.norm(m[:3, 1])
        nl = -m[:3, 2] / np.linalg.norm(m[:3, 2])
        if name == "area rectangle":  # cells of the rectangle
            box = (-lx / 2, lx / 2, -ly / 2, ly / 2)
            to_point = lambda s, t: c + s[:, None] * ax + t[:, None] * ay  # noqa: E731
            jac = lambda s, t: np.ones_like(s)  # noqa: E731
            coords = lambda q: ((q - c) @ ax, (q - c) @ ay)  # noqa: E731
        else:  # equal-area cells of the ellipse: (r^2, phi)
            rx, ry = lx / 2, ly / 2
            box = (0.0, 1.0, -math.pi, math.pi)
            to_point = lambda u, f: c + np.sqrt(u)[:, None] * (rx * np.cos(f)[:, None] * ax  # noqa: E731
                                                               + ry * np.sin(f)[:, None] * ay)
            jac = lambda u, f: np.full_like(u, rx * ry / 2)  # noqa: E731
            coords = lambda q: ((((q - c) @ ax) / rx) ** 2 + (((q - c) @ ay) / ry) ** 2,  # noqa: E731
                                np.arctan2(((q - c) @ ay) / ry, ((q - c) @ ax) / rx))
        s = make_sampler([light])
        surface = (to_point, jac, coords, nl)
    elif name == "emissive quad":
        # a quad whose edges are longer than its height (sampled by solid angle, each triangle its own pdf): cells
        # (s, t) of each triangle ABC, x = A + s (B - A) + s t (C - B), area element 2 area(ABC) s ds dt; the
        # first coordinate runs over [0, 2): triangle int(.), s = frac(.)
        c, half = np.array([0.2, -0.1, 0.3]), 0.4
        tris = two_triangle_quad(c, half).astype(np.float64)
        et = lights.EmissiveTriangles.from_mesh_arrays(tris.astype(np.float32), np.zeros(2, int),
                                                       np.array([[2.0] * 3]))
        s = make_sampler([], tris=et)
        box = (0.0, 2.0, 0.0, 1.0)
        A, B, C = tris[:, 0], tris[:, 1], tris[:, 2]
        area2 = np.linalg.norm(np.cross(B - A, C - A), axis=1)

        def to_point(u, t):
            k, sv = np.minimum(u.astype(int), 1), u - np.minimum(u.astype(int), 1)
            return A[k] + sv[:, None] * (B[k] - A[k]) + (sv * t)[:, None] * (C[k] - B[k])

        def jac(u, t):
            k = np.minimum(u.astype(int), 1)
            return area2[k] * (u - k)

        def coords(q):
            out_u, out_t = np.full(len(q), -1.0), np.zeros(len(q))
            for k in range(2):  # barycentric weights (1 - s, s (1 - t), s t) of q in triangle k
                e1, e2, dq = B[k] - A[k], C[k] - A[k], q - A[k]
                d11, d12, d22 = e1 @ e1, e1 @ e2, e2 @ e2
                den = d11 * d22 - d12 * d12
                lb, lc = (d22 * (dq @ e1) - d12 * (dq @ e2)) / den, (d11 * (dq @ e2) - d12 * (dq @ e1)) / den
                inside = (lb >= -1e-6) & (lc >= -1e-6) & (lb + lc <= 1 + 1e-6)
                sv = np.clip(lb + lc, 1e-12, 1)
                out_u = np.where(inside, k + np.minimum(sv, 1 - 1e-9), out_u)
                out_t = np.where(inside, np.clip(lc / sv, 0, 1), out_t)
            assert np.all(out_u >= 0)
            return out_u, out_t

        surface = (to_point, jac, coords, np.array([0, 0, -1.0]))
    else:  # cone cells (cos theta, phi) about the direction of the light: sphere light, sun, world
        if name == "sphere light":
            centre, r = np.array([0.4, 0.2, 1.2]), 0.5
            light = PointLight("sphere", W(centre), np.full(3, P), radius=r)
            light.soft_falloff = False
            axis, cos_max = centre, math.sqrt(1 - r * r / (centre @ centre))
            s = make_sampler([light])
        elif name == "sun":
            sun_d = np.array([0.2, 0.1, -1.0]) / np.linalg.norm([0.2, 0.1, -1.0])
            s = make_sampler([SunLight("s", sun_d, np.full(3, 3.0), angle=math.radians(30))])
            axis, cos_max = -sun_d, math.cos(math.radians(15))
        else:  # the uniform world, cosine-sampled about the normal
            s = make_sampler([], world=0.7)
            axis, cos_max = UP, 0.0
        box = (cos_max, 1.0, -math.pi, math.pi)
        surface = None
        a, b, z = frame(axis)
    rng = np.random.default_rng(21)
    N = CHI2_SAMPLES
    ls = s.sample(np.tile(np.float32(p), (N, 1)), np.tile(np.float32(n), (N, 1)), rng.random(N), rng.random((N, 2)))
    assert np.all(ls.pdf > 0) and not np.any(ls.delta)
    x0, x1, wq, cell = cell_grid(*box)
    if surface is None:
        wi = ls.wi.astype(np.float64)
        got = cell_of(wi @ z, np.arctan2(wi @ b, wi @ a), *box)
        st = np.sqrt(np.clip(1 - x0 * x0, 0, None))
        d = st[:, None] * (np.cos(x1)[:, None] * a + np.sin(x1)[:, None] * b) + x0[:, None] * z
        dens = direction_pdf(s, p, n, d)  # cells in (cos theta, phi) measure solid angle
    else:
        to_point, jac, coords, nl = surface
        q = ls.wi.astype(np.float64) * ls.dist[:, None]
        got = cell_of(*coords(q), *box)
        x = to_point(x0, x1)
        dist = np.linalg.norm(x - p, axis=1)
        d = (x - p) / dist[:, None]
        if name == "emissive quad":
            k = np.minimum(x0.astype(int), 1)
            pdf = s.pdf_triangle(et.emitter_of_triangle[k], np.tile(p, (len(k), 1)), dist ** 2, np.abs(d @ nl),
                                 n=np.tile(n, (len(k), 1))).astype(np.float64)
        else:
            pdf = direction_pdf(s, p, n, d)
        dens = pdf * np.abs(d @ nl) / dist ** 2 * jac(x0, x1)  # solid-angle pdf -> the cells' area measure
    expected = np.bincount(cell, weights=dens * wq, minlength=CHI2_CELLS ** 2)
    counts = np.bincount(got, minlength=CHI2_CELLS ** 2)
    return counts, expected


def pearson(counts, expected):
    """Pearson's statistic of counts against probabilities `expected` (renormalised over the cells), and the
    99.9 % quantile of its distribution under the null hypothesis."""
    from scipy import stats

    e = counts.sum() * expected / expected.sum()
    assert e.min() > 5, e.min()  # every cell expects enough samples for the chi-square approximation
    return float(((counts - e) ** 2 / e).sum()), float(stats.chi2.isf(1e-3, len(e) - 1))


@pytest.mark.parametrize("name", ["area rectangle", "area ellipse spread", "emissive quad", "sphere light", "sun",
                                  "world"])
def test_light_sampling_follows_its_pdf_chi_square(name):
    counts, expected = chi2_case(name)
    # the pdf integrates to 1 over the light (the quadrature of the pdf is a probability)
    assert expected.sum() == pytest.approx(1.0, rel=2e-3), expected.sum()
    stat, limit = pearson(counts, expected)
    assert stat < limit, f"{name}: chi-square {stat:.1f} >= {limit:.1f}"
    # built-in control: the same pdf 5 % too high over the cells holding the first half of its mass and 5 % too
    # low over the rest must fail
    half = np.cumsum(expected) <= 0.5 * expected.sum()
    for sign in (1, -1):
        wrong = expected * np.where(half, 1 + 0.05 * sign, 1 - 0.05 * sign)
        assert pearson(counts, wrong)[0] > limit, f"{name}: a 5%-wrong pdf passes"
