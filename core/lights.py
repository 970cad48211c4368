"""Light selection and sampling for next-event estimation with MIS, vectorised over N shading points.

Coordinates: the integrator renders relative to a world offset `shift` (float64 (3,)) for precision. Every
position given to this module and returned by it is (world position - shift) in float32; the light tables are
built by subtracting `shift` in float64 before the cast.

Units, exactly as Cycles 5.0 converts them (read from the kernel, and each one checked here against a Cycles
5.0.1 render of a white diffuse plane, see tests/test_lights.py). Blender's `strength` of a light is
colour x Power (W) or colour x Strength (sun, W/m^2) (`intern/cycles/blender/light.cpp`, `sync_light`), and
`normalize` is on by default, so Cycles divides it by `Light::area()` (`intern/cycles/scene/light.cpp`):

- Point light, radius r = 0: radiant intensity I = P / (4 pi) W/sr. (`device_update_lights`:
  eval_fac = invarea / pi with `Light::area()` = 4 when the radius is 0; `point_light_sample` then divides by
  the distance squared through its pdf.)
- Point light, radius r > 0: radiance L = P / (4 pi^2 r^2) (eval_fac = 1 / (pi * 4 pi r^2), `Light::area()` =
  4 pi r^2). Its shape depends on Blender's `use_soft_falloff` (default True; `is_sphere = !use_soft_falloff`
  in `blender/light.cpp`):
    * soft falloff (default): a disc of radius r centred on the light and facing the shading point
      (`point_light_sample`, "ad-hoc radius based on oriented disk"): irradiance at distance d, perpendicular
      incidence, P / (4 pi (d^2 + r^2));
    * no soft falloff: a sphere of radius r, sampled by the cone it subtends: irradiance P / (4 pi d^2), exactly
      a point light's, while the sphere is above the horizon.
  Monte reads the mode from `getattr(light, "soft_falloff", True)` (scene.PointLight has no field for it yet).
- Spot light: the point light above (same I or L, no renormalisation to the cone) times
  smoothstep((cos_a - cos(size / 2)) / ((1 - cos(size / 2)) x blend)) with cos_a the cosine between the spot axis
  and the direction from the emitting point to the shading point (`spot.h` `spot_light_attenuation`,
  `spot_smooth` set in `scene/light.cpp`). Blend 0 is a hard edge. Inside a sphere-mode spot the attenuation
  is not applied (as Cycles). Non-uniformly scaled spot cones (elliptic) are not modelled.
- Sun: strength S is the irradiance on a surface facing it; with angular diameter a > 0 the disc has radiance
  S / (pi sin^2(a / 2)) (`Light::area()` for LIGHT_DISTANT = pi sin^2(a / 2), eval_fac = 1 / area), sampled
  uniformly in the cone of half-angle a / 2 (`distant.h`). a = 0 is a delta light.
- Area light: one-sided, emitting towards the light's local -Z, radiance L = P / (pi A) with A the world area
  (|X column| size_x x |Y column| size_y, x pi / 4 for DISK/ELLIPSE) (`area.h` `area_light_eval`:
  eval_fac = invarea / pi, "Convert radiant flux to radiance"). Spread s < pi multiplies L by
  max((tan(s/2) - tan(theta)) / (tan(s/2) - s/2), 0), theta the angle to the light's normal
  (`area_light_spread_attenuation`, normalised so the cosine-weighted integral is pi as for a Lambertian
  emitter); s = pi is Lambertian. Rectangles are sampled by solid angle (Urena et al. 2013, spherical
  rectangles, as Cycles), discs/ellipses uniformly by area. With s < pi the sampling is not narrowed to the lit
  region as Cycles' `area_light_spread_clamp_light` does: unbiased, only noisier for narrow spreads.
- Mesh emission: radiance = Emission colour x strength, from both faces (`emissive_simple_eval` uses |cos|).
- World: constant radiance colour x strength in every direction.

Visibility, Cycles' defaults (Blender creates light objects with `visible_camera` False and diffuse, glossy
and transmission visibility True; checked with renders): camera rays see the world but no light
(`intersect(..., camera=True)`); BSDF rays see every light that has a surface (area lights' front face,
point/spot discs or spheres with r > 0, the sun disc with a > 0) and the world. Lights never block rays. A
light that carries `visible_camera = True` (no such field in scene.py yet) is seen by camera rays too.

Sampling and MIS: rectangles by solid angle, discs/ellipses and emissive triangles uniformly by area, point
lights as Cycles (uniform in the cone a sphere subtends; uniformly over the disc for soft falloff), the sun
uniformly in its cone, the world cosine-weighted about the normal n given to `sample` (uniform sphere without
n); the inside of a sphere light likewise. `intersect` returns each light's emission weighted by the power
heuristic against the BSDF pdf, with the light pdf of that same direction (selection included) computed by the
same formulas `sample` uses; it needs the same n for the world (it raises if `sample` got normals and
`intersect` none). Delta lights (r = 0, sun angle 0): `pdf` is the selection probability and `radiance` the
value to divide by it (I / d^2, S).

Cost (2-core machine here, per million shading points): `sample` about 30 ms for a point light, 50-100 ms
for discs, suns, the world and ellipses, 250-300 ms for rectangles (float64 spherical rectangles, for accuracy
on tiny or distant lights); `intersect` about N x (number of analytic lights) of similar work.

Emissive triangles are sampled uniformly in area, or uniformly in the solid angle they subtend (Arvo's spherical
triangle sampling) where the triangle is near and large (longest edge longer than the distance to its plane,
Cycles' rule): the seed's lamp hangs 2 cm under the ceiling, where area sampling's 1/d^2 makes fireflies.
`pdf_triangle` applies the same rule from the ray origin.

Light selection (one emitter per shading point, chosen per point, like Cycles' light tree for a handful of
lights). The selectable units are each analytic light (point, spot, area, sun), the world, and the emissive
triangles in up to 8 spatial groups (split at centroid medians; groups under 16 triangles, such as a quad lamp,
are not split); inside a group a triangle is picked by power (luminance(emission) x area). At a shading point p
with shading normal n (the viewer's side) each unit gets an importance, an estimate of the irradiance it gives
(W/m^2, Rec. 709 luminance):
  finite units (bounding sphere centre c, radius r; d = |c - p|):
    intensity x emitter-cone factor x receiver factor / max(d^2, r^2)
    intensity: point and spot P / (4 pi); area P / pi (Lambertian peak); triangle group L A (its power / 2 pi).
    emitter cone, with theta_u = asin(r / d) the angle the bounds subtend (no cone test when p is inside them):
    spot 1 inside its cone widened by theta_u, else 0; area cos(theta') x its spread attenuation, theta' =
    max(angle(normal, p - c) - theta_u, 0), and 0 behind its plane or outside its spread; triangle group
    the same about its two-sided normal cone (widened by the group's normal spread), never 0.
  sun: S x receiver factor (theta_u its half-angle); world: 0.1 pi L (_WORLD_IMPORTANCE: a uniform world's
  light samples duplicate what BSDF sampling already finds, so it is weighted down).
  receiver factor: cos(max(angle(n, c - p) - theta_u, 0)), or its |cos| version where the material transmits
  (the `transmits` flag) or 1 without n; a unit entirely below a surface that only reflects gets 0.
Probability of a unit: 0.9 x importance / sum of importances + 0.1 (SELECTION_POWER_FLOOR) x power / sum of
powers, both over the units that are not provably dark at p (importance 0: one-sided area light from behind,
outside a spot cone or area spread, wholly below a reflect-only surface; 0.06 degree margin), so every unit that
can contribute keeps a probability > 0 and the estimator stays unbiased; the power shares alone where no unit
is lit. Powers: emissive triangle L x area x 2 pi (both faces), point P, spot P (1 - cos(size / 2)) / 2 (the
fraction of the sphere inside the cone), area P, sun S x pi R^2 (what crosses the scene's bounding disc), world
L x pi^2 R^2 (irradiance pi L through the scene's cross-section disc, like the sun), R = scene_radius. Emitters
with zero power are never selected. One unit (a single lamp) has probability 1 and costs nothing per point;
otherwise the selection is a compiled pass over points x units (core.light_kernels), about 50-100 ns per point
for two units. `intersect` and `pdf_triangle` evaluate the same probability at the ray origin with the normal
and transmission flag `sample` got there (they raise if those are missing), so MIS weights match.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import kernels
from . import light_kernels as lk
from .scene import AreaLight, PointLight, Scene, SpotLight, SunLight

__all__ = ["EmissiveTriangles", "LightSample", "LightSampler", "luminance"]

_F32 = np.float32
_TWO_PI = 2.0 * math.pi
_INV_PI = 1.0 / math.pi
_INV_4PI = 1.0 / (4.0 * math.pi)
_LUM = np.array([0.2126, 0.7152, 0.0722])
_RECT_MIN_SOLID_ANGLE = 1e-9  # below this a rectangle's solid angle is unreliable even in float64: sample by area

_KIND_TRI, _KIND_PUNCT, _KIND_AREA, _KIND_SUN, _KIND_WORLD = range(5)
# Share of the per-point selection given by power alone (among the units not provably dark at the point): keeps
# a light that the importance estimate underrates (its rival occluded there) from being sampled too rarely.
SELECTION_POWER_FLOOR = 0.1
# The uniform world's importance is this fraction of the irradiance pi L it gives: its light samples are cosine
# distributed about n, as a diffuse BSDF's own samples (which MIS counts too), so they add little beside them.
# Instances bench (sun + sky), MSE at equal samples: 4.99e-4 at 1, 4.03e-4 at 0.5, 3.17e-4 at 0.1, 3.05e-4 at
# 0.03 (fixed selection by power: 4.14e-4); the glass bench (dim sky + area light) is unchanged.
_WORLD_IMPORTANCE = 0.1


def luminance(rgb) -> np.ndarray:
    """Rec. 709 luminance of (..., 3) linear RGB."""
    return np.asarray(rgb, dtype=np.float64) @ _LUM


# -------------------------------------------------------------------------------------------- vector helpers
# Internally vectors are component-major, (3, N): NumPy broadcasts (3, N) against (3, 1) with an inner loop of
# length N, about ten times faster than (N, 3) against (3,) (inner loop of length 3). The public API is (N, 3).
def _cm(a, dtype=_F32) -> np.ndarray:
    """(N, k) -> contiguous (k, N)."""
    return np.ascontiguousarray(np.asarray(a, dtype=dtype).T)


def _rm(a) -> np.ndarray:
    """(k, N) (or (k, 1), broadcast) -> contiguous (N, k) float32 (column copies are faster than a transpose)."""
    out = np.empty((a.shape[1], a.shape[0]), _F32)
    for i in range(a.shape[0]):
        out[:, i] = a[i]
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


_MIN_SPHERICAL_OMEGA = 1e-6  # sr: below this a spherical triangle is numerically flat; sample by area instead


def _basis(nz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit vectors nz (3, N) to orthonormal frames (Duff et al. 2017)."""
    x, y, z = nz
    s = np.where(z >= 0, 1.0, -1.0).astype(nz.dtype)
    a = -1.0 / (s + z)
    b = x * y * a
    t = np.stack([1.0 + s * x * x * a, s * b, -s * x])
    bb = np.stack([b, s + y * y * a, -y])
    return t, bb


def _sample_cone(axis: np.ndarray, one_minus_cos_max, u: np.ndarray):
    """Uniform directions in the cones about unit axis (3, N) whose 1 - cos(half-angle) is given; u (2, N).

    Returns (wi (3, N), cos_theta). Works in 1 - cos so that tiny cones (the sun, far spheres) keep their
    precision in float32."""
    x = u[0] * one_minus_cos_max
    cos_t = 1.0 - x
    sin_t = np.sqrt(np.maximum(x * (2.0 - x), 0.0))
    phi = _TWO_PI * u[1]
    t, b = _basis(axis)
    wi = axis * cos_t + t * (sin_t * np.cos(phi)) + b * (sin_t * np.sin(phi))
    return wi.astype(_F32, copy=False), cos_t


def _sample_cos_hemisphere(n: np.ndarray, u: np.ndarray):
    """Cosine-weighted directions about unit n (3, N); returns (wi, cos_theta)."""
    r = np.sqrt(u[0])
    phi = _TWO_PI * u[1]
    cos_t = np.sqrt(np.maximum(1.0 - u[0], 0.0))
    t, b = _basis(n)
    wi = n * cos_t + t * (r * np.cos(phi)) + b * (r * np.sin(phi))
    return wi.astype(_F32, copy=False), cos_t


def _sample_sphere(u: np.ndarray) -> np.ndarray:
    z = 1.0 - 2.0 * u[0]
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = _TWO_PI * u[1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z]).astype(_F32)


def _one_minus_cos_from_sin2(sin2):
    """1 - sqrt(1 - sin2) without cancellation."""
    return sin2 / (1.0 + np.sqrt(np.maximum(1.0 - sin2, 0.0)))


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _mis_power(pdf_a: np.ndarray, pdf_b: np.ndarray) -> np.ndarray:
    """Power-heuristic weight of strategy a against b (solid-angle pdfs); 1 where b is 0, 0 where only b."""
    a2 = np.square(pdf_a.astype(np.float64))
    b2 = np.square(pdf_b.astype(np.float64))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        w = a2 / (a2 + b2)
    w = np.where(b2 > 0, w, 1.0)
    return np.where(np.isfinite(w), w, np.where(np.isinf(a2), 1.0, 0.0)).astype(_F32)


# ---------------------------------------------------------------------------------------- spherical rectangle
def _rect_frame(o, c, ax, ay, z, lx, ly):
    """One rectangle (centre c, unit axes ax, ay, z = ax x ay, side lengths lx, ly; (3,) float64) seen from the
    points o (3, N), in the frame of Urena et al. 2013, "An Area-Preserving Parametrization for Spherical
    Rectangles" (float64).

    Returns the rectangle's extent (x0, x1, y0, y1) along (ax, ay) relative to o, the distance z0 <= 0 along
    the normal zs (z flipped away from o), the constants b0, b1, the solid angle S and the offset a2 + a3 used
    by the sampler. The paper's internal angles g_i = acos(-n_i . n_i+1) are written as pi/2 - a_i with
    a_i = asin(-n_i . n_i+1), so that S = sum(g) - 2 pi = -(a0 + a1 + a2 + a3) has no cancellation for small
    rectangles."""
    dvec = c[:, None] - o.astype(np.float64)
    z0 = z @ dvec
    flip = z0 > 0
    z0 = -np.abs(z0)
    xc = ax @ dvec
    yc = ay @ dvec
    x0, x1 = xc - 0.5 * lx, xc + 0.5 * lx
    y0, y1 = yc - 0.5 * ly, yc + 0.5 * ly
    z2 = z0 * z0
    with np.errstate(invalid="ignore", divide="ignore"):
        r_y0, r_x1 = np.sqrt(z2 + y0 * y0), np.sqrt(z2 + x1 * x1)
        r_y1, r_x0 = np.sqrt(z2 + y1 * y1), np.sqrt(z2 + x0 * x0)
        # edge-plane normals n0..n3: (0, z0, -y0)/r_y0, (-z0, 0, x1)/r_x1, (0, -z0, y1)/r_y1, (z0, 0, -x0)/r_x0
        a0 = np.arcsin(np.clip(y0 * x1 / (r_y0 * r_x1), -1, 1))
        a1 = np.arcsin(np.clip(-x1 * y1 / (r_x1 * r_y1), -1, 1))
        a2 = np.arcsin(np.clip(x0 * y1 / (r_y1 * r_x0), -1, 1))
        a3 = np.arcsin(np.clip(-x0 * y0 / (r_x0 * r_y0), -1, 1))
        b0 = -y0 / r_y0
        b1 = y1 / r_y1
    S = -(a0 + a1 + a2 + a3)
    S = np.where(np.isfinite(S), S, 0.0)
    return dict(x0=x0, x1=x1, y0=y0, y1=y1, z0=z0, flip=flip, b0=b0, b1=b1, S=S, a23=a2 + a3)


def _rect_sample(o, f, ax, ay, z, u):
    """Points (3, N) float64 on the rectangle of frame f (from _rect_frame), uniform in solid angle from o.

    The paper's au = u S + k with k = 2 pi - g2 - g3 is pi + (u S + a2 + a3) here; the pi flips the signs of
    cos(au) and sin(au), which is folded into fu."""
    S, z0, b0, b1 = f["S"], f["z0"], f["b0"], f["b1"]
    phi = u[0].astype(np.float64) * S + f["a23"]
    with np.errstate(invalid="ignore", divide="ignore"):
        fu = (np.cos(phi) * b0 + b1) / np.sin(phi)
        cu = np.clip(np.copysign(1.0, fu) / np.sqrt(fu * fu + b0 * b0), -1.0, 1.0)
        xu = -(cu * z0) / np.maximum(np.sqrt(1.0 - cu * cu), 1e-12)
    xu = np.clip(np.nan_to_num(xu), f["x0"], f["x1"])
    d2 = xu * xu + z0 * z0
    y0, y1 = f["y0"], f["y1"]
    h0 = y0 / np.sqrt(d2 + y0 * y0)
    h1 = y1 / np.sqrt(d2 + y1 * y1)
    hv = h0 + u[1].astype(np.float64) * (h1 - h0)
    hv2 = hv * hv
    with np.errstate(invalid="ignore", divide="ignore"):
        yv = np.where(hv2 < 1.0 - 1e-12, hv * np.sqrt(d2 / np.maximum(1.0 - hv2, 1e-300)), y1)
    yv = np.clip(yv, y0, y1)
    zc = np.where(f["flip"], -z0, z0)  # z0 along z itself
    return o.astype(np.float64) + ax[:, None] * xu + ay[:, None] * yv + z[:, None] * zc


# ---------------------------------------------------------------------------------------------- row grouping
def _groups(li: np.ndarray, count: int):
    """(k, rows) for every light k that occurs in li; rows is slice(None) when k is the only one."""
    if li.size == 0:
        return
    lo, hi = int(li.min()), int(li.max())
    if lo == hi:
        yield lo, slice(None)
        return
    order = np.argsort(li, kind="stable")
    bounds = np.searchsorted(li[order], np.arange(count + 1))
    for k in range(count):
        if bounds[k + 1] > bounds[k]:
            yield k, order[bounds[k]:bounds[k + 1]]


def _split(mask: np.ndarray):
    """Row selectors (True rows, False rows), each slice(None) for everything or None for nothing."""
    if mask.all():
        return slice(None), None
    if not mask.any():
        return None, slice(None)
    return np.nonzero(mask)[0], np.nonzero(~mask)[0]


def _per_light(li, count, p, n, u, fn):
    """Run fn(k, p, n, u) on the columns of each light k in li; gather (wi, dist, rad, pdf, delta)."""
    out = None
    for k, rows in _groups(li, count):
        res = fn(k, p[:, rows], None if n is None else n[:, rows], u[:, rows])
        if isinstance(rows, slice):
            return res
        if out is None:
            N = p.shape[1]
            out = (np.empty((3, N), _F32), np.empty(N, _F32), np.empty((3, N), _F32), np.empty(N, _F32),
                   np.empty(N, bool))
        for dst, src in zip(out, res):
            dst[..., rows] = src
    return out


def _clean(wi, dist, rad, pdf, delta):
    """Zero the samples that carry no contribution or are not finite (a shading point at a light's centre)."""
    pdf = np.asarray(pdf, dtype=_F32)
    rad = np.broadcast_to(rad, wi.shape)
    with np.errstate(invalid="ignore"):
        ok = (pdf > 0) & np.isfinite(pdf) & np.isfinite(rad[0] + rad[1] + rad[2]) & np.isfinite(wi[0] + wi[1] + wi[2])
    if not ok.all():
        pdf = np.where(ok, pdf, 0)
        rad = np.where(ok, rad, 0)
        wi = np.where(ok, wi, 0)
    return wi, dist, rad, pdf, delta


# ------------------------------------------------------------------------------------ emissive triangle groups
_MAX_TRIANGLE_GROUPS = 8  # units per point cost O(units): a few spatial groups, a power CDF inside each
_MIN_GROUP_SPLIT = 16  # groups of fewer triangles (a quad lamp) are not split


def _cluster_emitters(tris: "EmissiveTriangles") -> list[np.ndarray]:
    """Spatial groups of emitter indices: split the group with the largest bounding box at the median of its
    triangle centroids along their widest axis, until _MAX_TRIANGLE_GROUPS or no group has _MIN_GROUP_SPLIT
    triangles with distinct centroids."""
    v = tris.vertices.astype(np.float64)
    lo_t, hi_t = v.min(axis=1), v.max(axis=1)
    centroid = v.mean(axis=1)
    groups = [np.arange(tris.count)]
    final: list[np.ndarray] = []
    while groups and len(groups) + len(final) < _MAX_TRIANGLE_GROUPS:
        size = [float(np.linalg.norm(hi_t[g].max(axis=0) - lo_t[g].min(axis=0))) if g.size >= _MIN_GROUP_SPLIT
                else -1.0 for g in groups]
        j = int(np.argmax(size))
        if size[j] < 0:
            break
        g = groups.pop(j)
        c = centroid[g]
        ext = c.max(axis=0) - c.min(axis=0)
        axis = int(np.argmax(ext))
        if not ext[axis] > 0:
            final.append(g)
            continue
        order = np.argsort(c[:, axis], kind="stable")
        half = g.size // 2
        groups += [g[order[:half]], g[order[half:]]]
    return final + groups


# ---------------------------------------------------------------------------------------------- data classes
@dataclass
class LightSample:
    """One light sample per shading point (float32, (N, 3) and (N,) arrays).

    wi: (N, 3) unit direction from p towards the light; dist: (N,) distance to the sampled point (np.inf for the
    sun and the world): cast the shadow ray to dist x (1 - eps). radiance: (N, 3) radiance arriving along -wi,
    before the BSDF and the cosine. pdf: (N,) solid-angle pdf including the selection probability; 0 means no
    contribution (radiance is 0 there as well). delta: (N,) bool, a point/spot light with radius 0 or a sun with
    angle 0: there `pdf` is the selection probability alone, `radiance` is already I / d^2 (times the spot
    cone) or S, `radiance / pdf` is the estimate, and the MIS weight is 1."""

    wi: np.ndarray
    dist: np.ndarray
    radiance: np.ndarray
    pdf: np.ndarray
    delta: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "LightSample":
        return cls(wi=np.zeros((n, 3), _F32), dist=np.full(n, np.inf, _F32), radiance=np.zeros((n, 3), _F32),
                   pdf=np.zeros(n, _F32), delta=np.zeros(n, bool))


@dataclass
class EmissiveTriangles:
    """The emitting triangles of the prepared geometry (in the integrator's shifted float32 coordinates).

    vertices: (E, 3, 3) float32; emission: (E, 3) float32 radiance (both faces); triangle_id: (E,) global
    triangle index; area: (E,) float64; normal: (E, 3) float32 unit geometric normal; emitter_of_triangle: (T,)
    int32, the emitter index of each global triangle or -1 (maps an Embree hit to an emitter)."""

    vertices: np.ndarray
    emission: np.ndarray
    triangle_id: np.ndarray
    area: np.ndarray
    normal: np.ndarray
    emitter_of_triangle: np.ndarray

    @property
    def count(self) -> int:
        return int(self.triangle_id.shape[0])

    @property
    def power(self) -> np.ndarray:
        """Selection power: luminance(emission) x area x 2 pi (a Lambertian face radiates pi L A)."""
        return luminance(self.emission) * self.area * _TWO_PI

    @classmethod
    def from_mesh_arrays(cls, tri_vertices: np.ndarray, material_index: np.ndarray,
                         emission_per_material: np.ndarray) -> "EmissiveTriangles | None":
        """Emitters from all triangles (T, 3, 3) (shifted float32), their material indices (T,) and the
        per-material emission (M, 3). Triangles whose material emits nothing, or of zero area, are not emitters.
        None when nothing emits."""
        tri = np.asarray(tri_vertices)
        T = tri.shape[0]
        emission_per_material = np.asarray(emission_per_material, dtype=np.float64).reshape(-1, 3)
        if T == 0 or emission_per_material.size == 0:
            return None
        mat = np.asarray(material_index, dtype=np.int64).reshape(-1)
        mat = np.broadcast_to(mat, (T,)) if mat.size == 1 else mat
        emissive_mat = np.any(emission_per_material > 0, axis=1)
        cand = np.nonzero(emissive_mat[mat])[0]
        if cand.size == 0:
            return None
        v = tri[cand].astype(np.float64)
        cr = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        area2 = np.linalg.norm(cr, axis=1)
        ok = np.isfinite(area2) & (area2 > 0)
        cand, cr, area2 = cand[ok], cr[ok], area2[ok]
        if cand.size == 0:
            return None
        emitter_of_triangle = np.full(T, -1, np.int32)
        emitter_of_triangle[cand] = np.arange(cand.size, dtype=np.int32)
        return cls(
            vertices=np.ascontiguousarray(tri[cand], dtype=_F32),
            emission=emission_per_material[mat[cand]].astype(_F32),
            triangle_id=cand.astype(np.int64),
            area=0.5 * area2,
            normal=(cr / area2[:, None]).astype(_F32),
            emitter_of_triangle=emitter_of_triangle,
        )


# ------------------------------------------------------------------------------------------------ the sampler
class LightSampler:
    """Selects one emitter per shading point by power and samples it; evaluates the lights BSDF rays pass.

    See the module docstring for the units and the selection heuristic. Public attributes: `has_lights`,
    `kinds_present` (subset of {"triangle", "point", "spot", "sun", "area", "world"}), `triangles`
    (EmissiveTriangles or None), `world_radiance` ((3,) float32, zeros when black), `shift`, `scene_radius`.
    Work scales with N times the number of analytic lights in `intersect`, and with N in `sample`."""

    def __init__(self, scene: Scene, shift: np.ndarray, emissive_triangles: EmissiveTriangles | None,
                 scene_radius: float):
        shift = np.asarray(shift, dtype=np.float64).reshape(3)
        R = float(scene_radius) if np.isfinite(scene_radius) and scene_radius > 0 else 1.0
        self.shift = shift
        self.scene_radius = R
        tris = emissive_triangles if (emissive_triangles is not None and emissive_triangles.count) else None
        self.triangles = tris

        punct = [lt for lt in scene.lights if isinstance(lt, (PointLight, SpotLight))]
        areas = [lt for lt in scene.lights if isinstance(lt, AreaLight)]
        suns = [lt for lt in scene.lights if isinstance(lt, SunLight)]
        self._build_punctual(punct, shift)
        self._build_areas(areas, shift)
        self._build_suns(suns, R)
        wc = np.asarray(scene.world.color, dtype=np.float64).reshape(-1)
        wc = np.repeat(wc, 3) if wc.size == 1 else wc
        self.world_radiance = wc.astype(_F32)
        # Flux through the scene's cross-section disc, as for the sun: irradiance pi L on a disc of area pi R^2.
        # (Counting the flux into the whole bounding sphere, 4 pi^2 L R^2, picked the world 4x too often next to
        # a sun: on the instanced bench scene that was 2.2x the MSE at equal samples.)
        world_power = float(luminance(wc)) * math.pi ** 2 * R * R

        # The selectable units (see the module docstring): a few spatial groups of emissive triangles, each
        # analytic light, the world. Zero power is left out (never selected).
        self._build_units(tris, world_power, R)
        if tris is not None:
            # component-major copies for gathers, and selection x area pdf
            v = tris.vertices.astype(np.float32)
            self._t_v0 = _cm(v[:, 0])
            self._t_e1 = _cm(v[:, 1] - v[:, 0])
            self._t_e2 = _cm(v[:, 2] - v[:, 0])
            self._t_n = _cm(tris.normal)
            self._t_L = _cm(tris.emission)
            self._t_pdf_area = (self._t_sel / tris.area).astype(_F32)
            edges = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 1], v[:, 0] - v[:, 2]], axis=1).astype(np.float64)
            self._t_edge2 = (edges * edges).sum(axis=2).max(axis=1)  # longest edge squared

        present = set()
        if np.any(self._t_sel > 0):
            present.add("triangle")
        for i in np.nonzero(self._p_sel > 0)[0]:
            present.add("spot" if self._p_is_spot[i] else "point")
        if np.any(self._a_sel > 0):
            present.add("area")
        if np.any(self._s_sel > 0):
            present.add("sun")
        if self._w_sel > 0:
            present.add("world")
        self.kinds_present = frozenset(present)
        # The world and the inside of sphere lights are sampled about the normal given to `sample`; `intersect`
        # then needs the same normal for MIS (checked, since a mismatch would bias silently).
        # With more than one unit the selection itself depends on n and on the transmission flag.
        self._n_matters = bool(self._w_sel > 0 or np.any(self._p_sphere & (self._p_sel > 0)) or self._per_point)
        self._sampled_about_n = False
        self._sampled_with_transmits = False

    # ---------------------------------------------------------------------------------------- construction
    def _build_units(self, tris, world_power, R):
        """The unit table of the per-point selection (core.light_kernels) and, per light kind, each light's unit
        (-1: never selected) and its probability once its unit is chosen (`_x_sel`: 1, or a triangle's share of
        its group's power)."""
        rows, kinds, kind5, local, power = [], [], [], [], []

        def add(kind, k5, index, pw, **fields):
            row = np.zeros(lk.UNIT_FIELDS)
            row[lk.C_COS_O], row[lk.C_COS_E], row[lk.C_COS_U] = 1.0, -2.0, 1.0
            for name, value in fields.items():
                if name == "centre":
                    row[lk.C_X:lk.C_Z + 1] = value
                elif name == "axis":
                    row[lk.C_AX:lk.C_AZ + 1] = value
                else:
                    row[getattr(lk, "C_" + name.upper())] = value
            row[lk.C_POWER] = pw
            rows.append(row)
            kinds.append(kind)
            kind5.append(k5)
            local.append(index)
            power.append(pw)
            return len(rows) - 1

        def ok(pw):
            return bool(np.isfinite(pw) and pw > 0)

        E = tris.count if tris is not None else 0
        self._t_sel = np.zeros(E)
        self._t_unit = np.full(E, -1, np.int64)
        if tris is not None:
            t_power = tris.power
            groups = _cluster_emitters(tris)
            order, cdf, starts = [], [], [0]
            for g, members in enumerate(groups):
                members = members[np.isfinite(t_power[members]) & (t_power[members] > 0)]
                gp = float(t_power[members].sum())
                if not ok(gp):
                    continue
                v = tris.vertices[members].astype(np.float64).reshape(-1, 3)
                lo, hi = v.min(axis=0), v.max(axis=0)
                nrm = tris.normal[members].astype(np.float64)
                # normal cone of a two-sided group: the principal normal direction and the widest deviation
                axis = np.linalg.eigh(nrm.T @ nrm)[1][:, -1]
                cos_o = float(np.clip(np.abs(nrm @ axis).min(), 0.0, 1.0))
                u = add(lk.TRI_GROUP, _KIND_TRI, len(order), gp, centre=0.5 * (lo + hi),
                        radius=0.5 * float(np.linalg.norm(hi - lo)), axis=axis, cos_o=cos_o,
                        sin_o=math.sqrt(max(1.0 - cos_o * cos_o, 0.0)), intensity=gp / _TWO_PI)
                share = t_power[members] / gp
                self._t_sel[members] = share
                self._t_unit[members] = u
                c = np.cumsum(share)
                c[-1] = 1.0
                order.append(members)
                cdf.append(len(order) - 1 + c)  # group j occupies [j, j + 1)
                starts.append(starts[-1] + members.size)
            if order:
                self._g_order = np.concatenate(order).astype(np.int64)
                self._g_cdf = np.concatenate(cdf)
                self._g_start = np.asarray(starts, np.int64)
        self._p_sel = np.zeros(self._p_count)
        self._p_unit = np.full(self._p_count, -1, np.int64)
        for i in range(self._p_count):
            if not ok(self._p_power[i]):
                continue
            spot = bool(self._p_is_spot[i])
            self._p_unit[i] = add(lk.SPOT if spot else lk.POINT, _KIND_PUNCT, i, float(self._p_power[i]),
                                  centre=self._p_pos[i].astype(np.float64), radius=float(self._p_radius[i]),
                                  axis=self._p_dir[i].astype(np.float64),
                                  cos_e=float(self._p_cos_half[i]) if spot else -2.0,
                                  intensity=float(luminance(self._p_rad_power[i])) * _INV_4PI)
            self._p_sel[i] = 1.0
        self._a_sel = np.zeros(self._a_count)
        self._a_unit = np.full(self._a_count, -1, np.int64)
        for i in range(self._a_count):
            if not ok(self._a_power[i]):
                continue
            half = 0.5 * math.hypot(self._a_lx[i], self._a_ly[i]) if not self._a_ellipse[i] else \
                0.5 * max(self._a_lx[i], self._a_ly[i])
            lambert = self._a_norm_spread[i] <= 0
            self._a_unit[i] = add(lk.AREA, _KIND_AREA, i, float(self._a_power[i]), centre=self._a_c[i],
                                  radius=half, axis=self._a_ng[i],
                                  cos_e=0.0 if lambert else 1.0 / math.sqrt(1.0 + self._a_tan_half[i] ** 2),
                                  tan_half=0.0 if lambert else float(self._a_tan_half[i]),
                                  norm_spread=float(self._a_norm_spread[i]),
                                  intensity=float(self._a_power[i]) * _INV_PI)
            self._a_sel[i] = 1.0
        self._s_sel = np.zeros(self._s_count)
        self._s_unit = np.full(self._s_count, -1, np.int64)
        for i in range(self._s_count):
            if not ok(self._s_power[i]):
                continue
            cos_u = 1.0 - float(self._s_omc[i])
            self._s_unit[i] = add(lk.SUN, _KIND_SUN, i, float(self._s_power[i]), axis=self._s_dir[i].astype(np.float64),
                                  cos_u=cos_u, sin_u=math.sqrt(max(1.0 - cos_u * cos_u, 0.0)),
                                  intensity=float(self._s_power[i]) / (math.pi * R * R))
            self._s_sel[i] = 1.0
        self._w_sel, self._w_unit = 0.0, -1
        if ok(world_power):
            self._w_unit = add(lk.WORLD, _KIND_WORLD, 0, world_power,
                               intensity=_WORLD_IMPORTANCE * world_power / (math.pi * R * R))
            self._w_sel = 1.0

        K = len(rows)
        pw = np.asarray(power, np.float64)
        total = float(pw.sum()) if K else 0.0
        self.has_lights = bool(K and total > 0 and np.isfinite(total))
        self._u_table = np.ascontiguousarray(np.asarray(rows, np.float64).reshape(K, lk.UNIT_FIELDS))
        self._u_kind = np.asarray(kinds, np.int64)
        self._u_kind5 = np.asarray(kind5, np.int8)
        self._u_local = np.asarray(local, np.int64)
        self._u_fallback = pw / total if self.has_lights else pw
        # one unit: probability 1 everywhere, no per-point work
        self._per_point = K > 1

    def _build_punctual(self, lights, shift):
        n = len(lights)
        self._p_count = n
        pos = np.zeros((n, 3))
        power = np.zeros((n, 3))
        radius = np.zeros(n)
        sphere = np.zeros(n, bool)
        spot = np.zeros(n, bool)
        sdir = np.tile([0.0, 0.0, -1.0], (n, 1))
        cos_half = np.full(n, -1.0)
        width = np.zeros(n)
        cam = np.zeros(n, bool)
        for i, lt in enumerate(lights):
            pos[i] = np.asarray(lt.position, dtype=np.float64).reshape(3) - shift
            power[i] = np.broadcast_to(np.asarray(lt.power, dtype=np.float64).reshape(-1), (3,))
            radius[i] = max(float(lt.radius), 0.0)
            sphere[i] = not bool(getattr(lt, "soft_falloff", True))
            cam[i] = bool(getattr(lt, "visible_camera", False))
            if isinstance(lt, SpotLight):
                spot[i] = True
                d = np.asarray(lt.direction, dtype=np.float64).reshape(3)
                sdir[i] = d / np.linalg.norm(d)
                cos_half[i] = math.cos(0.5 * float(lt.spot_size))
                width[i] = (1.0 - cos_half[i]) * float(lt.spot_blend)
        # Cycles: eval_fac = 1 / (pi Light::area()), area 4 pi r^2 (4 when r = 0): radiance of the disc/sphere,
        # or the intensity P / (4 pi) for r = 0.
        safe_r = np.where(radius > 0, radius, 1.0)
        scale = np.where(radius > 0, 1.0 / (4.0 * math.pi ** 2 * safe_r ** 2), _INV_4PI)
        self._p_pos = pos.astype(_F32)
        self._p_rad_power = power
        self._p_rad = (power * scale[:, None]).astype(_F32)
        self._p_radius = radius
        self._p_sphere = sphere & (radius > 0)
        self._p_is_spot = spot
        self._p_dir = sdir.astype(_F32)
        self._p_cos_half = cos_half
        self._p_width = width
        self._p_cam = cam
        cone_fraction = np.where(spot, 0.5 * (1.0 - cos_half), 1.0)
        self._p_power = luminance(power) * cone_fraction if n else np.zeros(0)

    def _build_areas(self, lights, shift):
        n = len(lights)
        self._a_count = n
        c = np.zeros((n, 3))
        ax = np.tile([1.0, 0, 0], (n, 1))
        ay = np.tile([0, 1.0, 0], (n, 1))
        ng = np.tile([0, 0, -1.0], (n, 1))
        lx = np.ones(n)
        ly = np.ones(n)
        ellipse = np.zeros(n, bool)
        power = np.zeros((n, 3))
        tan_half = np.full(n, np.inf)
        norm_spread = np.zeros(n)
        cam = np.zeros(n, bool)
        for i, lt in enumerate(lights):
            m = np.asarray(lt.matrix_world, dtype=np.float64)
            c[i] = m[:3, 3] - shift
            sx = float(lt.size_x)
            sy = sx if lt.shape in ("SQUARE", "DISK") else float(lt.size_y)
            ux, uy = m[:3, 0] * sx, m[:3, 1] * sy
            lx[i], ly[i] = np.linalg.norm(ux), np.linalg.norm(uy)
            ax[i] = ux / lx[i]
            v = uy - ax[i] * (ax[i] @ uy)  # orthogonalised against shear: an orthonormal rectangle frame
            ay[i] = v / np.linalg.norm(v)
            ng[i] = -m[:3, 2] / np.linalg.norm(m[:3, 2])  # Cycles: dir = -Z column
            ellipse[i] = lt.shape in ("DISK", "ELLIPSE")
            power[i] = np.broadcast_to(np.asarray(lt.power, dtype=np.float64).reshape(-1), (3,))
            spread = float(lt.spread)
            if spread < math.pi:
                half = 0.5 * max(spread, 0.0)
                tan_half[i] = math.tan(half)
                # 1 / (tan(h) - h), by its series 3 / h^3 where the difference cancels (as scene/light.cpp)
                norm_spread[i] = 1.0 / (tan_half[i] - half) if half > 0.05 else 3.0 / half ** 3
            cam[i] = bool(getattr(lt, "visible_camera", False))
        self._a_c = c
        self._a_ax, self._a_ay, self._a_ng = ax, ay, ng
        self._a_z = np.cross(ax, ay)
        self._a_lx, self._a_ly = lx, ly
        self._a_ellipse = ellipse
        self._a_area = lx * ly * np.where(ellipse, math.pi / 4.0, 1.0)
        self._a_rad = (power / (math.pi * self._a_area[:, None])).astype(_F32)  # L = P / (pi A)
        self._a_tan_half = tan_half
        self._a_norm_spread = norm_spread
        self._a_cam = cam
        self._a_power = luminance(power) if n else np.zeros(0)

    def _build_suns(self, lights, R):
        n = len(lights)
        self._s_count = n
        to_sun = np.zeros((n, 3))
        rad = np.zeros((n, 3))
        omc = np.zeros(n)
        power = np.zeros(n)
        cam = np.zeros(n, bool)
        for i, lt in enumerate(lights):
            d = np.asarray(lt.direction, dtype=np.float64).reshape(3)
            to_sun[i] = -d / np.linalg.norm(d)
            s = np.broadcast_to(np.asarray(lt.strength, dtype=np.float64).reshape(-1), (3,))
            half = 0.5 * float(lt.angle)
            if half > 0:
                omc[i] = 2.0 * math.sin(0.5 * half) ** 2  # 1 - cos(half)
                rad[i] = s / (math.pi * math.sin(half) ** 2)
            else:
                rad[i] = s
            power[i] = luminance(s) * math.pi * R * R
            cam[i] = bool(getattr(lt, "visible_camera", False))
        self._s_dir = to_sun.astype(_F32)
        self._s_rad = rad.astype(_F32)
        self._s_omc = omc
        self._s_cos_half = 1.0 - omc
        self._s_cam = cam
        self._s_power = power

    # -------------------------------------------------------------------------------------------- sampling
    def sample(self, p: np.ndarray, n: np.ndarray | None, u_select: np.ndarray, u: np.ndarray,
               transmits: np.ndarray | None = None) -> LightSample:
        """Pick an emitter for each shading point p (N, 3) and sample a direction towards it.

        n: (N, 3) shading-side unit normal or None: weighs the per-point selection (see the module docstring),
        cosine-samples the world (else uniform sphere) and the inside of a sphere light. transmits: (N,) bool,
        whether the material at p transmits (its BSDF is not zero below n), or None (treated as True: no
        hemisphere cut). Pass the same n and transmits to `intersect` and `pdf_triangle` at the same point, so
        that MIS sees the same pdfs. u_select: (N,) and u: (N, 2) uniform numbers in [0, 1)."""
        p = np.asarray(p).reshape(-1, 3)
        N = p.shape[0]
        if not self.has_lights or N == 0:
            return LightSample.empty(N)
        pc = _cm(p)
        # n matters to the selection, the world and the inside of sphere lights
        need_n = n is not None and self._n_matters
        nc = _cm(np.asarray(n).reshape(-1, 3)) if need_n else None
        self._sampled_about_n |= need_n
        tc = self._transmits(transmits, N, nc)
        self._sampled_with_transmits |= tc is not None
        uc = _cm(np.asarray(u).reshape(-1, 2))
        u_sel = np.asarray(u_select, dtype=np.float64).reshape(-1)
        if not self._per_point:
            unit_prob, u_rest = None, u_sel
            kind, only = None, int(self._u_kind5[0])
            local = np.full(N, self._u_local[0], np.int64)
            if only == _KIND_TRI:
                local = self._pick_in_group(local, u_rest)
        else:
            unit = np.empty(N, np.int64)
            unit_prob = np.empty(N)
            u_rest = np.empty(N)
            lk.select(pc, *self._n_t_args(nc, tc), np.ascontiguousarray(u_sel), self._u_table, self._u_kind,
                      self._u_fallback, SELECTION_POWER_FLOOR, unit, unit_prob, u_rest)
            kind = self._u_kind5[unit]
            local = self._u_local[unit]
            tri = kind == _KIND_TRI
            if tri.any():
                local[tri] = self._pick_in_group(local[tri], u_rest[tri])
            counts = np.bincount(kind, minlength=5)
            only = int(np.argmax(counts)) if counts.max() == N else -1
        out = None
        for k, fn in ((_KIND_TRI, self._sample_triangles), (_KIND_PUNCT, self._sample_punctual),
                      (_KIND_AREA, self._sample_areas), (_KIND_SUN, self._sample_suns),
                      (_KIND_WORLD, self._sample_world)):
            if only >= 0:
                if k != only:
                    continue
                rows = slice(None)
            else:
                rows = np.nonzero(kind == k)[0]
                if rows.size == 0:
                    continue
            wi, dist, rad, pdf, delta = fn(pc[:, rows], None if nc is None else nc[:, rows], uc[:, rows],
                                           local[rows])
            if unit_prob is not None:
                pdf = pdf * unit_prob[rows]
            wi, dist, rad, pdf, delta = _clean(wi, dist, rad, pdf, delta)
            if only >= 0:
                return LightSample(wi=_rm(wi), dist=np.asarray(dist, _F32), radiance=_rm(rad),
                                   pdf=np.asarray(pdf, _F32), delta=np.asarray(delta, bool))
            if out is None:
                out = (np.zeros((3, N), _F32), np.full(N, np.inf, _F32), np.zeros((3, N), _F32),
                       np.zeros(N, _F32), np.zeros(N, bool))
            for dst, src in zip(out, (wi, dist, rad, pdf, delta)):
                dst[..., rows] = src
        return LightSample(wi=_rm(out[0]), dist=out[1], radiance=_rm(out[2]), pdf=out[3], delta=out[4])

    # per-point selection ----------------------------------------------------------------------------------
    def _transmits(self, transmits, N, nc):
        """The transmission flags (N,) bool as the kernels take them, or None when they cannot matter (one unit,
        or no normal) or were not given."""
        if transmits is None or nc is None or not self._per_point:
            return None
        return np.ascontiguousarray(np.broadcast_to(np.asarray(transmits, dtype=bool).reshape(-1), (N,)))

    @staticmethod
    def _n_t_args(nc, tc):
        return (np.zeros((3, 0), _F32) if nc is None else np.ascontiguousarray(nc, dtype=_F32), nc is not None,
                np.ones(0, bool) if tc is None else tc, tc is not None)

    def _unit_probability(self, which, oc, nc, tc) -> np.ndarray:
        """(M,) float64: the probability with which `sample` picks unit which (scalar or (M,); -1: never) at the
        points oc (3, M) with the normals nc (3, M) or None and the flags tc (M,) or None."""
        M = oc.shape[1]
        which = np.broadcast_to(np.asarray(which, np.int64).reshape(-1), (M,))
        if not self._per_point:
            return (which >= 0).astype(np.float64)
        out = np.empty(M)
        lk.probability(np.ascontiguousarray(oc, dtype=_F32), *self._n_t_args(nc, tc), np.ascontiguousarray(which),
                       self._u_table, self._u_kind, self._u_fallback, SELECTION_POWER_FLOOR, out)
        return out

    def _pick_in_group(self, group: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Emitter indices picked by power inside the triangle groups `group` (M,) with uniform numbers u (M,)."""
        idx = np.searchsorted(self._g_cdf, group + np.asarray(u, np.float64), side="right")
        idx = np.clip(idx, self._g_start[group], self._g_start[group + 1] - 1)
        return self._g_order[idx]

    def selection_probabilities(self, p: np.ndarray, n: np.ndarray | None = None,
                                transmits: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Per-point probability (N,) of each selectable unit, keyed "point 0", "area 1", "sun 0", "world",
        "triangles 2" (a group), ... (index within its kind): what `sample` uses; for tests and diagnostics."""
        p = np.asarray(p).reshape(-1, 3)
        N = p.shape[0]
        pc = _cm(p)
        nc = _cm(np.asarray(n).reshape(-1, 3)) if n is not None and self._n_matters else None
        tc = self._transmits(transmits, N, nc)
        names = {_KIND_TRI: "triangles", _KIND_AREA: "area", _KIND_SUN: "sun"}
        out = {}
        for k in range(self._u_kind.size):
            k5, i = int(self._u_kind5[k]), int(self._u_local[k])
            if k5 == _KIND_WORLD:
                name = "world"
            elif k5 == _KIND_PUNCT:
                name = f"{'spot' if self._p_is_spot[i] else 'point'} {i}"
            else:
                name = f"{names[k5]} {i}"
            out[name] = self._unit_probability(k, pc, nc, tc)
        return out

    # triangles --------------------------------------------------------------------------------------------
    def _near_args(self, p, li):
        return (np.ascontiguousarray(p, dtype=np.float32), np.ascontiguousarray(li, dtype=np.int64), self._t_v0,
                self._t_e1, self._t_e2, self._t_n, self._t_edge2, _MIN_SPHERICAL_OMEGA)

    def _sample_triangles(self, p, n, u, li):
        """Area sampling, or (near and large triangles, Cycles' rule) uniform solid-angle sampling: the seed's
        lamp hangs 2 cm under the ceiling, where area sampling's 1/d^2 weight makes fireflies."""
        su = np.sqrt(u[0])
        b1 = 1.0 - su
        b2 = u[1] * su
        q = (np.take(self._t_v0, li, axis=1) + np.take(self._t_e1, li, axis=1) * b1
             + np.take(self._t_e2, li, axis=1) * b2)
        w = q - p
        d2 = _dot(w, w)
        dist = np.sqrt(d2)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = w / dist
            cos_l = np.abs(_dot(np.take(self._t_n, li, axis=1), wi))
            pdf = np.where(cos_l > 0, self._t_pdf_area[li] * d2 / cos_l, 0.0)
        wi, dist = np.ascontiguousarray(wi, np.float32), np.ascontiguousarray(dist, np.float32)
        omega = np.empty(li.shape[0])
        kernels.sample_near_triangles(*self._near_args(p, li), np.ascontiguousarray(u[0], np.float64),
                                      np.ascontiguousarray(u[1], np.float64), wi, dist, omega)
        near = omega != 0
        if near.any():
            pdf = np.where(near, np.where(omega > 0, self._t_sel[li] / np.where(near, omega, 1.0), 0.0), pdf)
        return wi, dist, np.take(self._t_L, li, axis=1), pdf, np.zeros(p.shape[1], bool)

    # point and spot lights --------------------------------------------------------------------------------
    def _spot_att(self, k: int, w_from_light: np.ndarray):
        """Spot cone smoothstep of light k for unit directions leaving it (3, N); None for a point light."""
        if not self._p_is_spot[k]:
            return None
        sd = self._p_dir[k]
        x = (sd[0] * w_from_light[0] + sd[1] * w_from_light[1] + sd[2] * w_from_light[2]) - _F32(self._p_cos_half[k])
        width = float(self._p_width[k])
        if width > 0:
            return _smoothstep(x * _F32(1.0 / width))
        return (x > 0).astype(_F32)

    def _sample_punctual(self, p, n, u, li):
        return _per_light(li, self._p_count, p, n, u, self._sample_one_punctual)

    def _sample_one_punctual(self, k, p, n, u):
        N = p.shape[1]
        r = float(self._p_radius[k])
        sel = float(self._p_sel[k])
        L = self._p_rad[k][:, None]
        v = self._p_pos[k][:, None] - p
        d2 = _dot(v, v)
        d = np.sqrt(d2)
        with np.errstate(invalid="ignore", divide="ignore"):
            axis = v / d
        delta = np.full(N, r <= 0)
        if r <= 0:  # a point: intensity / d^2
            att = self._spot_att(k, -axis)
            with np.errstate(divide="ignore"):
                scale = (1.0 / d2) if att is None else att / d2
            return axis, d, L * scale, np.full(N, sel, _F32), delta
        if not self._p_sphere[k]:  # disc of radius r on the light, facing p, sampled uniformly by area
            t, b = _basis(axis)
            rr = _F32(r) * np.sqrt(u[0])
            phi = _TWO_PI * u[1]
            w = v + t * (rr * np.cos(phi)) + b * (rr * np.sin(phi))
            t2 = _dot(w, w)
            dist = np.sqrt(t2)
            with np.errstate(invalid="ignore", divide="ignore"):
                wi = w / dist
                cos_l = np.abs(_dot(axis, wi))
                pdf = np.where(cos_l > 0, t2 * _F32(sel / (math.pi * r * r)) / cos_l, 0)
            att = self._spot_att(k, -wi)
            return wi, dist, (L if att is None else L * att), pdf, delta
        # a sphere of radius r
        wi = np.empty((3, N), _F32)
        dist = np.empty(N, _F32)
        pdf = np.empty(N, _F32)
        outside, inside = _split(d > r)
        if outside is not None:  # uniform in the cone the sphere subtends
            do, d2o = d[outside], d2[outside]
            omc = _one_minus_cos_from_sin2(_F32(r * r) / d2o)
            wo, cos_t = _sample_cone(axis[:, outside], omc, u[:, outside])
            sin2 = np.maximum(1.0 - cos_t * cos_t, 0)
            wi[:, outside] = wo
            dist[outside] = do * cos_t - np.sqrt(np.maximum(_F32(r * r) - d2o * sin2, 0))
            pdf[outside] = sel / (_TWO_PI * omc)
        if inside is not None:  # inside: every direction meets the sphere; cosine about n, or uniform
            if n is not None:
                wn, cos_t = _sample_cos_hemisphere(n[:, inside], u[:, inside])
                pdf[inside] = (sel * _INV_PI) * cos_t
            else:
                wn = _sample_sphere(u[:, inside])
                pdf[inside] = sel * _INV_4PI
            bb = _dot(v[:, inside], wn)
            dist[inside] = bb + np.sqrt(np.maximum(_F32(r * r) - d2[inside] + bb * bb, 0))
            wi[:, inside] = wn
        att = self._spot_att(k, -wi)
        if att is None:
            return wi, dist, L, pdf, delta
        if inside is not None:
            att[inside] = 1.0  # Cycles applies no cone inside the sphere
        return wi, dist, L * att, pdf, delta

    # area lights ------------------------------------------------------------------------------------------
    def _area_spread(self, k: int, cos_a: np.ndarray):
        """Spread attenuation of area light k for cosines to its normal (N,); None when Lambertian."""
        ns = float(self._a_norm_spread[k])
        if ns <= 0:
            return None
        with np.errstate(invalid="ignore", divide="ignore"):
            tan_a = np.sqrt(np.maximum(1.0 - cos_a * cos_a, 0.0)) / cos_a
            att = np.where(cos_a > 0, np.maximum((self._a_tan_half[k] - tan_a) * ns, 0.0), 0.0)
        return att.astype(_F32)

    def _area_points(self, k: int, u: np.ndarray) -> np.ndarray:
        """Points (3, N) float64 uniformly distributed by area on area light k."""
        uu = u.astype(np.float64)
        if self._a_ellipse[k]:
            rr = np.sqrt(uu[0])
            sx, sy = rr * np.cos(_TWO_PI * uu[1]), rr * np.sin(_TWO_PI * uu[1])
        else:
            sx, sy = 2.0 * uu[0] - 1.0, 2.0 * uu[1] - 1.0
        return (self._a_c[k][:, None] + self._a_ax[k][:, None] * (0.5 * self._a_lx[k] * sx)
                + self._a_ay[k][:, None] * (0.5 * self._a_ly[k] * sy))

    def _rect_frame_of(self, k: int, o: np.ndarray):
        return _rect_frame(o, self._a_c[k], self._a_ax[k], self._a_ay[k], self._a_z[k], self._a_lx[k],
                           self._a_ly[k])

    def _sample_areas(self, p, n, u, li):
        return _per_light(li, self._a_count, p, n, u, self._sample_one_area)

    def _sample_one_area(self, k, p, n, u):
        N = p.shape[1]
        p64 = p.astype(np.float64)
        ng = self._a_ng[k]
        front = ng @ (p64 - self._a_c[k][:, None]) > 0
        if self._a_ellipse[k]:
            by_area = np.ones(N, bool)
            q = self._area_points(k, u)
            pdf = np.zeros(N)
        else:
            f = self._rect_frame_of(k, p64)
            ok = f["S"] > _RECT_MIN_SOLID_ANGLE
            q = _rect_sample(p64, f, self._a_ax[k], self._a_ay[k], self._a_z[k], u)
            with np.errstate(divide="ignore"):
                pdf = np.where(ok, 1.0 / np.where(ok, f["S"], 1.0), 0.0)
            by_area = ~ok
            if by_area.any():
                q[:, by_area] = self._area_points(k, u[:, by_area])
        w = q - p64
        t2 = _dot(w, w)
        dist = np.sqrt(t2)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = w / dist
            cos_a = -(ng @ wi)
            if by_area.any():
                pdf = np.where(by_area, np.where(cos_a > 0, t2 / (self._a_area[k] * cos_a), 0.0), pdf)
        pdf = np.where(front, pdf * self._a_sel[k], 0.0)
        att = self._area_spread(k, cos_a)
        L = self._a_rad[k][:, None]
        return wi.astype(_F32), dist.astype(_F32), (L if att is None else L * att), pdf, np.zeros(N, bool)

    # sun and world ----------------------------------------------------------------------------------------
    def _sample_suns(self, p, n, u, li):
        return _per_light(li, self._s_count, p, n, u, self._sample_one_sun)

    def _sample_one_sun(self, k, p, n, u):
        N = p.shape[1]
        axis = self._s_dir[k][:, None]
        omc = float(self._s_omc[k])
        sel = float(self._s_sel[k])
        dist = np.full(N, np.inf, _F32)
        L = self._s_rad[k][:, None]
        if omc <= 0:
            return np.broadcast_to(axis, (3, N)), dist, L, np.full(N, sel, _F32), np.ones(N, bool)
        wi, _ = _sample_cone(np.broadcast_to(axis, (3, N)), _F32(omc), u)
        return wi, dist, L, np.full(N, sel / (_TWO_PI * omc), _F32), np.zeros(N, bool)

    def _sample_world(self, p, n, u, li):
        N = p.shape[1]
        if n is not None:
            wi, cos_t = _sample_cos_hemisphere(n, u)
            pdf = _F32(self._w_sel * _INV_PI) * cos_t
        else:
            wi = _sample_sphere(u)
            pdf = np.full(N, self._w_sel * _INV_4PI, _F32)
        return wi, np.full(N, np.inf, _F32), self.world_radiance[:, None], pdf, np.zeros(N, bool)

    # ------------------------------------------------------------------------------------------ evaluation
    def pdf_triangle(self, emitter: np.ndarray, origin: np.ndarray, dist2: np.ndarray,
                     abs_cos_light: np.ndarray, n: np.ndarray | None = None,
                     transmits: np.ndarray | None = None) -> np.ndarray:
        """Solid-angle pdf (selection included) with which `sample` produces the emissive-triangle point that a
        BSDF ray hit: emitter (N,) index into `triangles` (from `emitter_of_triangle`), origin (N, 3) the ray
        origins (the shading points `sample` would get, same frame), dist2 (N,) squared distance from the origin,
        abs_cos_light (N,) |cos| at the triangle; n (N, 3) and transmits (N,): what `sample` got at the origin.
        0 where the cosine is 0 or the emitter is -1."""
        emitter = np.asarray(emitter).reshape(-1)
        if self.triangles is None or emitter.size == 0:
            return np.zeros(emitter.shape[0], _F32)
        ok = emitter >= 0
        li = np.where(ok, emitter, 0)
        cos_l = np.asarray(abs_cos_light, dtype=_F32).reshape(-1)
        oc = _cm(np.asarray(origin).reshape(-1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            pdf = self._t_pdf_area[li] * np.asarray(dist2, dtype=_F32).reshape(-1) / cos_l
            omega = np.empty(li.shape[0])
            kernels.triangle_solid_angles(*self._near_args(oc, li), omega)
            near = omega > 0
            pdf = np.where(near, self._t_sel[li] / np.where(near, omega, 1.0), pdf)
        if self._per_point:
            nc = self._check_normal(n, li.shape[0], transmits, "pdf_triangle")
            pdf = pdf * self._unit_probability(np.where(ok, self._t_unit[li], -1), oc, nc,
                                               self._transmits(transmits, li.shape[0], nc))
        return np.where(ok & (cos_l > 0) & np.isfinite(pdf), pdf, 0).astype(_F32)

    def _check_normal(self, n, N, transmits, caller):
        """n as (3, N) for the selection (None when it does not matter); raises where `sample` got normals or
        transmission flags that this MIS evaluation lacks (the pdfs would silently differ)."""
        if n is None and self._sampled_about_n:
            raise ValueError(f"LightSampler.{caller}: `sample` was given normals, so the world, sphere lights or "
                             "the per-point light selection depend on them; pass the same normal of the ray's "
                             "origin as n= for MIS")
        if transmits is None and self._sampled_with_transmits:
            raise ValueError(f"LightSampler.{caller}: `sample` was given transmission flags, which weigh the "
                             "per-point light selection; pass the same flags of the ray's origin as transmits=")
        return _cm(np.asarray(n).reshape(-1, 3)) if n is not None and self._n_matters else None

    def intersect(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, bsdf_pdf: np.ndarray,
                  bsdf_delta: np.ndarray, mis: bool, n: np.ndarray | None = None,
                  camera: bool = False, transmits: np.ndarray | None = None) -> np.ndarray:
        """Emission (N, 3) of every analytic light surface the rays o + t d (unit d, (N, 3)) pass for
        0 < t < tmax, summed (lights are transparent), each MIS-weighted by the power heuristic against
        bsdf_pdf (N,) (solid angle), weight 1 where bsdf_delta (N,) or when mis is False.

        Seen: area lights (front face), point/spot lights with radius > 0 (the disc facing o, or the sphere),
        and, where tmax is inf, the sun's disc (angle > 0) and the world. n: the normal given to `sample` at o
        (the selection, the world and the inside of sphere lights depend on it), None if `sample` got None;
        transmits: the flags given to `sample` there (None likewise).
        camera=True: camera rays, which see the world but no light unless the light has
        `visible_camera = True` (Blender's default is False); no MIS weighting."""
        o = np.asarray(o).reshape(-1, 3)
        N = o.shape[0]
        if N == 0:
            return np.zeros((0, 3), _F32)
        oc = _cm(o)
        dc = _cm(np.asarray(d).reshape(-1, 3))
        tmax = np.broadcast_to(np.asarray(tmax, dtype=_F32).reshape(-1), (N,))
        use_mis = bool(mis) and not camera
        if use_mis:
            bsdf_pdf = np.broadcast_to(np.asarray(bsdf_pdf, dtype=_F32).reshape(-1), (N,))
            no_mis = np.broadcast_to(np.asarray(bsdf_delta, dtype=bool).reshape(-1), (N,))
        if use_mis:
            nc = self._check_normal(n, N, transmits, "intersect")
        else:
            nc = _cm(np.asarray(n).reshape(-1, 3)) if n is not None and self._n_matters else None
        tc = self._transmits(transmits, N, nc)
        out = np.zeros((3, N), _F32)

        def accumulate(rows, rad, light_pdf, unit):
            """Add rad (3, n) (or (3, 1)) at rows, weighted against the BSDF strategy; light_pdf: the pdf given
            that unit `unit` is selected."""
            if use_mis:
                if self._per_point:
                    light_pdf = light_pdf * self._unit_probability(
                        unit, oc[:, rows], None if nc is None else nc[:, rows], None if tc is None else tc[rows])
                w = np.where(no_mis[rows], _F32(1.0), _mis_power(bsdf_pdf[rows], light_pdf))
                rad = rad * w
            out[:, rows] += rad

        for i in range(self._p_count):
            if self._p_radius[i] > 0 and (self._p_cam[i] or not camera) and np.any(self._p_rad[i] > 0):
                self._intersect_punctual(i, oc, dc, tmax, nc, accumulate)
        for i in range(self._a_count):
            if (self._a_cam[i] or not camera) and np.any(self._a_rad[i] > 0):
                self._intersect_area(i, oc, dc, tmax, accumulate)
        escaped = np.isinf(tmax)
        if escaped.any():
            rows = slice(None) if escaped.all() else np.nonzero(escaped)[0]
            de = dc[:, rows]
            for i in range(self._s_count):
                if self._s_omc[i] <= 0 or not (self._s_cam[i] or not camera):
                    continue
                hit = self._s_dir[i] @ de >= _F32(self._s_cos_half[i])
                if hit.any():
                    r = np.arange(N)[rows][hit]
                    pdf = np.full(r.size, self._s_sel[i] / (_TWO_PI * self._s_omc[i]), _F32)
                    accumulate(r, self._s_rad[i][:, None], pdf, self._s_unit[i])
            if np.any(self.world_radiance > 0):
                if not use_mis:
                    out[:, rows] += self.world_radiance[:, None]
                else:
                    if nc is not None:
                        pdf = _F32(self._w_sel * _INV_PI) * np.maximum(_dot(de, nc[:, rows]), 0)
                    else:
                        pdf = np.full(de.shape[1], self._w_sel * _INV_4PI, _F32)
                    accumulate(rows, self.world_radiance[:, None], pdf, self._w_unit)
        return _rm(out)

    def _intersect_punctual(self, i, o, d, tmax, n, accumulate):
        r = float(self._p_radius[i])
        r2 = _F32(r * r)
        v = self._p_pos[i][:, None] - o  # towards the light
        d2 = _dot(v, v)
        b = _dot(v, d)  # distance along the ray to the point nearest the centre
        sel = float(self._p_sel[i])
        L = self._p_rad[i][:, None]
        if not self._p_sphere[i]:
            # the disc through the centre facing o: the ray meets its plane at t = d2 / b, at squared
            # distance t^2 - d2 from the centre
            with np.errstate(invalid="ignore", divide="ignore"):
                t = d2 / b
                hit = (b > 0) & (t < tmax) & (t * t - d2 <= r2)
            rows = np.nonzero(hit)[0]
            if rows.size == 0:
                return
            tl = t[rows]
            cos_l = b[rows] / np.sqrt(d2[rows])
            pdf = tl * tl * _F32(sel / (math.pi * r * r)) / cos_l
            att = self._spot_att(i, -d[:, rows])
            accumulate(rows, L if att is None else L * att, pdf, self._p_unit[i])
            return
        inside = d2 <= r2
        with np.errstate(invalid="ignore"):
            disc = b * b - d2 + r2
            sq = np.sqrt(np.maximum(disc, 0))
            t = np.where(inside, b + sq, b - sq)
            hit = (disc >= 0) & (t > 0) & (t < tmax) & (inside | (b > 0))
        rows = np.nonzero(hit)[0]
        if rows.size == 0:
            return
        ins = inside[rows]
        omc = _one_minus_cos_from_sin2(np.minimum(r2 / d2[rows], 1.0))
        with np.errstate(divide="ignore"):
            pdf = np.where(ins, 0.0, sel / (_TWO_PI * np.where(ins, 1.0, omc)))
        if ins.any():
            if n is not None:
                pin = (sel * _INV_PI) * np.maximum(_dot(d[:, rows], n[:, rows]), 0)
            else:
                pin = np.full(rows.size, sel * _INV_4PI)
            pdf = np.where(ins, pin, pdf)
        att = self._spot_att(i, -d[:, rows])
        rad = L if att is None else L * np.where(ins, _F32(1.0), att)
        accumulate(rows, rad, pdf.astype(_F32), self._p_unit[i])

    def _intersect_area(self, i, o, d, tmax, accumulate):
        ng = self._a_ng[i].astype(_F32)
        dn = ng @ d
        c = self._a_c[i].astype(_F32)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (ng @ (c[:, None] - o)) / dn
        cand = np.nonzero((dn < 0) & (t > 0) & (t < tmax))[0]
        if cand.size == 0:
            return
        rel = o[:, cand] + d[:, cand] * t[cand] - c[:, None]
        su = (self._a_ax[i].astype(_F32) @ rel) * _F32(2.0 / self._a_lx[i])
        sv = (self._a_ay[i].astype(_F32) @ rel) * _F32(2.0 / self._a_ly[i])
        if self._a_ellipse[i]:
            inside = su * su + sv * sv <= 1.0
        else:
            inside = (np.abs(su) <= 1.0) & (np.abs(sv) <= 1.0)
        rows = cand[inside]
        if rows.size == 0:
            return
        cos_a = -dn[rows].astype(np.float64)
        att = self._area_spread(i, cos_a)
        L = self._a_rad[i][:, None]
        # the pdf with which `sample` produces this direction from o: same code path, same inputs
        with np.errstate(divide="ignore", invalid="ignore"):
            tl = t[rows].astype(np.float64)
            pdf = tl * tl / (self._a_area[i] * cos_a)
            if not self._a_ellipse[i]:
                S = self._rect_frame_of(i, o[:, rows])["S"]
                solid = S > _RECT_MIN_SOLID_ANGLE
                pdf = np.where(solid, 1.0 / np.where(solid, S, 1.0), pdf)
        accumulate(rows, L if att is None else L * att, (self._a_sel[i] * pdf).astype(_F32), self._a_unit[i])
