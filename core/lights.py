"""Light selection and sampling for next-event estimation with MIS, vectorised over N shading points.

Coordinates: every position given to this module and returned by it is (world position - shift) in float32,
`shift` being the integrator's float64 world offset; the light tables subtract it in float64 before the cast.

Units, as Cycles 5.0 converts Blender's (each checked against a Cycles render in tests/test_lights.py):
- point light, radius 0: intensity P / (4 pi) W/sr; radius r > 0: radiance P / (4 pi^2 r^2), a disc facing the
  shading point (soft falloff, Blender's default) or a sphere (`soft_falloff` False);
- spot light: the point light times Cycles' smoothstep of the cone (size, blend);
- sun: strength S W/m^2 is the irradiance; angle a > 0 gives a disc of radiance S / (pi sin^2(a / 2));
- area light: one-sided (local -Z), radiance P / (pi A), A the world area; spread < pi attenuates as Cycles;
- mesh emission: radiance colour x strength from both faces; world: constant radiance colour x strength, or an
  environment map (core.world: the image through the Mapping node, x strength).
Visibility as Cycles' defaults: camera rays see the world but no light (unless `visible_camera`), BSDF rays see
every light with a surface and the world; lights never block rays.

Sampling: rectangles by solid angle, discs/ellipses and emissive triangles by area (near, large triangles by
solid angle), sphere lights in the cone they subtend, the sun in its cone, the uniform world cosine-weighted
about n, an environment map by its 2D distribution (core.world_kernels).
`intersect` and `pdf_triangle` compute the light pdf of a BSDF-sampled direction with the same formulas and the
same per-point selection (they need the n and transmission flags `sample` got), so MIS weights match. Delta
lights (radius 0, sun angle 0): `pdf` is the selection probability and `radiance` the value to divide by it.

Selection: one unit per shading point (each analytic light, the world, up to 8 spatial groups of emissive
triangles picked inside by power), with probability 0.9 x importance share + 0.1 x power share over the units
not provably dark there; importance estimates each unit's irradiance at the point and normal.

The kernels are in core.light_kernels. docs/lights.md has the full contract: the Cycles function each unit
follows, the selection heuristic's formulas, and the measurements behind its constants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import light_kernels as lk
from .scene import AreaLight, PointLight, Scene, SpotLight, SunLight
from .world import EnvironmentDistribution, portal_table

__all__ = ["EmissiveTriangles", "LightSample", "LightSampler", "luminance"]

_F32 = np.float32
_TWO_PI = 2.0 * math.pi
_INV_PI = 1.0 / math.pi
_INV_4PI = 1.0 / (4.0 * math.pi)
_LUM = np.array([0.2126, 0.7152, 0.0722])

# The one light-kind enumeration is core.light_kernels' (the kernels branch on it); its names here:
_KIND_NAMES = {lk.TRI_GROUP: "triangle", lk.POINT: "point", lk.SPOT: "spot", lk.AREA: "area", lk.SUN: "sun",
               lk.WORLD: "world"}
# Share of the per-point selection given by power alone (among the units not provably dark at the point): keeps
# a light that the importance estimate underrates (its rival occluded there) from being sampled too rarely.
SELECTION_POWER_FLOOR = 0.1
# The uniform world's importance is this fraction of the irradiance pi L it gives: its light samples are cosine
# distributed about n, as a diffuse BSDF's own samples (which MIS counts too), so they add little beside them
# (measurements in docs/lights.md). Renders leave the world out of selection; this serves light_sampling="light".
_WORLD_IMPORTANCE = 0.1
# An environment map's importance is this multiple of the irradiance pi L_mean it gives: its light samples follow
# the map's brightness (a sun in it), which BSDF sampling finds poorly (measurements in docs/lights.md).
_WORLD_MAP_IMPORTANCE = 3.0


def luminance(rgb) -> np.ndarray:
    """Rec. 709 luminance of (..., 3) linear RGB."""
    return np.asarray(rgb, dtype=np.float64) @ _LUM


# -------------------------------------------------------------------------------------------- array helpers
def _cm(a, dtype=_F32) -> np.ndarray:
    """(N, k) -> contiguous (k, N) (the triangle tables are component-major)."""
    return np.ascontiguousarray(np.asarray(a, dtype=dtype).T)


def _rows(a, N: int | None = None) -> np.ndarray:
    """(N, 3) contiguous float32, as the kernels take points, normals and directions."""
    a = np.asarray(a, dtype=_F32).reshape(-1, 3)
    if N is not None and a.shape[0] != N:
        a = np.broadcast_to(a, (N, 3))
    return np.ascontiguousarray(a)


def _vec(a, N: int) -> np.ndarray:
    """(N,) contiguous float32 (scalars broadcast)."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=_F32).reshape(-1), (N,)))


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
        cand, cr, area2 = nondegenerate_triangles(tri, cand)
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


# ------------------------------------------------------------------------------------ one table per light kind
# Each kind's lights as arrays, one row per light, in the shifted frame; `kernel_table` writes the flat table
# core.light_kernels reads. `sel` (the probability of a light once its unit is chosen) and `unit` (its
# selection unit, -1: never selected) are filled in when the units are built.
def nondegenerate_triangles(tri_vertices: np.ndarray, candidates: np.ndarray) -> tuple:
    """The candidate triangles (indices into tri_vertices (T, 3, 3)) whose area is finite and nonzero: (their
    indices, the cross products of their edges (K, 3) float64, twice their areas (K,) float64)."""
    v = tri_vertices[candidates].astype(np.float64)
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    ok = np.isfinite(area2) & (area2 > 0)
    return candidates[ok], cross[ok], area2[ok]


def _f32(a) -> np.ndarray:
    """Values as the float32 code held them, in float64."""
    return np.asarray(a, _F32).astype(np.float64)


@dataclass
class _PunctualLights:
    """Point and spot lights. pos (P, 3) float32; power (P, 3) the lights' colour x Power (W); rad (P, 3) float32
    radiance of the disc/sphere, or the intensity P / (4 pi) for radius 0; radius (P,); sphere (P,) sphere mode
    (no soft falloff, radius > 0); spot (P,); direction (P, 3) float32 spot axis; cos_half (P,) cos(size / 2)
    (-1 for points); width (P,) (1 - cos_half) x blend; camera (P,) visible to camera rays; selection_power
    (P,) luminance x the cone's share of the sphere."""

    pos: np.ndarray
    power: np.ndarray
    rad: np.ndarray
    radius: np.ndarray
    sphere: np.ndarray
    spot: np.ndarray
    direction: np.ndarray
    cos_half: np.ndarray
    width: np.ndarray
    camera: np.ndarray
    selection_power: np.ndarray
    sel: np.ndarray | None = None
    unit: np.ndarray | None = None

    @classmethod
    def from_lights(cls, lights: list, shift: np.ndarray) -> "_PunctualLights":
        n = len(lights)
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
        cone_fraction = np.where(spot, 0.5 * (1.0 - cos_half), 1.0)
        return cls(pos=pos.astype(_F32), power=power, rad=(power * scale[:, None]).astype(_F32), radius=radius,
                   sphere=sphere & (radius > 0), spot=spot, direction=sdir.astype(_F32), cos_half=cos_half,
                   width=width, camera=cam,
                   selection_power=luminance(power) * cone_fraction if n else np.zeros(0))

    def kernel_table(self) -> np.ndarray:
        pt = np.zeros((len(self.radius), lk.PT_FIELDS))
        if len(self.radius):
            pt[:, lk.PT_X:lk.PT_Z + 1] = self.pos
            pt[:, lk.PT_R:lk.PT_B + 1] = self.rad
            pt[:, lk.PT_RADIUS] = self.radius
            pt[:, lk.PT_SPHERE] = self.sphere
            pt[:, lk.PT_SPOT] = self.spot
            pt[:, lk.PT_DX:lk.PT_DZ + 1] = self.direction
            pt[:, lk.PT_COS_HALF] = _f32(self.cos_half)
            safe_w = np.where(self.width > 0, self.width, 1.0)
            pt[:, lk.PT_INV_WIDTH] = np.where(self.width > 0, _f32(1.0 / safe_w), 0.0)
            pt[:, lk.PT_SEL] = self.sel
            pt[:, lk.PT_UNIT] = self.unit
            pt[:, lk.PT_CAM] = self.camera
            pt[:, lk.PT_LIT] = np.any(self.rad > 0, axis=1)
        return np.ascontiguousarray(pt)


@dataclass
class _AreaLights:
    """Area lights. centre (A, 3); axis_x, axis_y (A, 3) an orthonormal frame of the light's plane; normal (A, 3)
    the emitting side (Cycles: the -Z column); axis_z = axis_x x axis_y; size_x, size_y (A,) world sizes;
    ellipse (A,) disc/ellipse; area (A,) world area; rad (A, 3) float32 radiance P / (pi A); tan_half (A,)
    tan(spread / 2) (inf: Lambertian); norm_spread (A,) 1 / (tan(h) - h) (0: Lambertian); camera (A,);
    selection_power (A,) luminance(P)."""

    centre: np.ndarray
    axis_x: np.ndarray
    axis_y: np.ndarray
    normal: np.ndarray
    axis_z: np.ndarray
    size_x: np.ndarray
    size_y: np.ndarray
    ellipse: np.ndarray
    area: np.ndarray
    rad: np.ndarray
    tan_half: np.ndarray
    norm_spread: np.ndarray
    camera: np.ndarray
    selection_power: np.ndarray
    sel: np.ndarray | None = None
    unit: np.ndarray | None = None

    @classmethod
    def from_lights(cls, lights: list, shift: np.ndarray) -> "_AreaLights":
        n = len(lights)
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
        area = lx * ly * np.where(ellipse, math.pi / 4.0, 1.0)
        return cls(centre=c, axis_x=ax, axis_y=ay, normal=ng, axis_z=np.cross(ax, ay), size_x=lx, size_y=ly,
                   ellipse=ellipse, area=area, rad=(power / (math.pi * area[:, None])).astype(_F32),  # L = P/(pi A)
                   tan_half=tan_half, norm_spread=norm_spread, camera=cam,
                   selection_power=luminance(power) if n else np.zeros(0))

    def kernel_table(self) -> np.ndarray:
        ar = np.zeros((len(self.area), lk.AR_FIELDS))
        if len(self.area):
            for col, v in ((lk.AR_CX, self.centre), (lk.AR_AXX, self.axis_x), (lk.AR_AYX, self.axis_y),
                           (lk.AR_ZX, self.axis_z), (lk.AR_NX, self.normal), (lk.AR_R, self.rad),
                           (lk.AR_CX32, _f32(self.centre)), (lk.AR_AXX32, _f32(self.axis_x)),
                           (lk.AR_AYX32, _f32(self.axis_y)), (lk.AR_NX32, _f32(self.normal))):
                ar[:, col:col + 3] = v
            ar[:, lk.AR_LX], ar[:, lk.AR_LY] = self.size_x, self.size_y
            ar[:, lk.AR_ELLIPSE] = self.ellipse
            ar[:, lk.AR_AREA] = self.area
            ar[:, lk.AR_TAN_HALF] = np.where(self.norm_spread > 0, self.tan_half, 0.0)
            ar[:, lk.AR_NORM_SPREAD] = self.norm_spread
            ar[:, lk.AR_SEL] = self.sel
            ar[:, lk.AR_UNIT] = self.unit
            ar[:, lk.AR_CAM] = self.camera
            ar[:, lk.AR_LIT] = np.any(self.rad > 0, axis=1)
            ar[:, lk.AR_SU32] = _f32(2.0 / self.size_x)
            ar[:, lk.AR_SV32] = _f32(2.0 / self.size_y)
        return np.ascontiguousarray(ar)


@dataclass
class _SunLights:
    """Suns. to_sun (S, 3) float32 unit direction towards the sun; rad (S, 3) float32 radiance of the disc (the
    irradiance for angle 0); one_minus_cos (S,) 1 - cos(angle / 2) (0: a delta light); camera (S,);
    selection_power (S,) luminance(S) x pi R^2 (what crosses the scene's bounding disc)."""

    to_sun: np.ndarray
    rad: np.ndarray
    one_minus_cos: np.ndarray
    camera: np.ndarray
    selection_power: np.ndarray
    sel: np.ndarray | None = None
    unit: np.ndarray | None = None

    @classmethod
    def from_lights(cls, lights: list, R: float) -> "_SunLights":
        n = len(lights)
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
        return cls(to_sun=to_sun.astype(_F32), rad=rad.astype(_F32), one_minus_cos=omc, camera=cam,
                   selection_power=power)

    def kernel_table(self) -> np.ndarray:
        su = np.zeros((len(self.one_minus_cos), lk.SU_FIELDS))
        if len(self.one_minus_cos):
            su[:, lk.SU_DX:lk.SU_DZ + 1] = self.to_sun
            su[:, lk.SU_R:lk.SU_B + 1] = self.rad
            su[:, lk.SU_OMC] = self.one_minus_cos
            su[:, lk.SU_COS_HALF] = _f32(1.0 - self.one_minus_cos)
            su[:, lk.SU_SEL] = self.sel
            su[:, lk.SU_UNIT] = self.unit
            su[:, lk.SU_CAM] = self.camera
        return np.ascontiguousarray(su)


@dataclass
class _TriangleTable:
    """The emissive triangles as core.light_kernels reads them: v0, e1, e2, normal, rad (3, E) float32
    component-major; pdf_area (E,) float32 selection x 1 / area; sel (E,) share of the group's power; edge2 (E,)
    longest edge squared; unit (E,) the group's unit; order, cdf, start: the spatial groups (group j's
    triangles are order[start[j]:start[j + 1]], picked by power with the cdf values in [j, j + 1))."""

    v0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    rad: np.ndarray
    pdf_area: np.ndarray
    sel: np.ndarray
    edge2: np.ndarray
    unit: np.ndarray
    order: np.ndarray
    cdf: np.ndarray
    start: np.ndarray

    @classmethod
    def empty(cls) -> "_TriangleTable":
        e3 = np.zeros((3, 0), _F32)
        return cls(e3, e3, e3, e3, e3, np.zeros(0, _F32), np.zeros(0), np.zeros(0), np.zeros(0, np.int64),
                   np.zeros(0, np.int64), np.zeros(0), np.zeros(1, np.int64))

    def kernel_tables(self) -> tuple:
        return (self.v0, self.e1, self.e2, self.normal, self.rad, self.pdf_area, np.ascontiguousarray(self.sel),
                np.ascontiguousarray(self.edge2, np.float64), self.order, self.cdf, self.start)


@dataclass
class _Units:
    """The selectable units of the per-point light selection (docs/lights.md): table (K, UNIT_FIELDS)
    float64 (core.light_kernels' columns), kind (K,) the light kind (core.light_kernels: TRI_GROUP, POINT, SPOT,
    AREA, SUN, WORLD), local (K,) the light's row in its kind's table (the group for TRI_GROUP), fallback (K,)
    the power shares."""

    table: np.ndarray
    kind: np.ndarray
    local: np.ndarray
    fallback: np.ndarray


class _UnitBuilder:
    """Collects the units one light (or triangle group) at a time."""

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.kinds: list[int] = []
        self.local: list[int] = []

    def add(self, kind: int, index: int, power: float, **fields) -> int:
        row = np.zeros(lk.UNIT_FIELDS)
        row[lk.C_COS_O], row[lk.C_COS_E], row[lk.C_COS_U] = 1.0, -2.0, 1.0
        for name, value in fields.items():
            if name == "centre":
                row[lk.C_X:lk.C_Z + 1] = value
            elif name == "axis":
                row[lk.C_AX:lk.C_AZ + 1] = value
            else:
                row[getattr(lk, "C_" + name.upper())] = value
        row[lk.C_POWER] = power
        self.rows.append(row)
        self.kinds.append(kind)
        self.local.append(index)
        return len(self.rows) - 1

    def units(self) -> _Units:
        K = len(self.rows)
        table = np.ascontiguousarray(np.asarray(self.rows, np.float64).reshape(K, lk.UNIT_FIELDS))
        pw = table[:, lk.C_POWER].copy()
        total = float(pw.sum()) if K else 0.0
        lit = bool(K and total > 0 and np.isfinite(total))
        return _Units(table, np.asarray(self.kinds, np.int64), np.asarray(self.local, np.int64),
                      np.ascontiguousarray(pw / total if lit else pw, np.float64))


def _selectable(power) -> bool:
    return bool(np.isfinite(power) and power > 0)


# ------------------------------------------------------------------------------------------------ the sampler
class LightSampler:
    """Selects one emitter per shading point by power and samples it; evaluates the lights BSDF rays pass.

    See the module docstring for the units and docs/lights.md for the selection heuristic. Public attributes:
    `has_lights`, `kinds_present` (subset of {"triangle", "point", "spot", "sun", "area", "world"}), `triangles`
    (EmissiveTriangles or None), `world_radiance` ((3,) float32, zeros when black or replaced by a map),
    `environment` (core.world.EnvironmentDistribution; `has_environment`: a lit map), `shift`, `scene_radius`.
    `has_emission` (has_lights, or a lit world that `intersect` returns).
    sample_world=False leaves the uniform world out of light selection, as Cycles does for a world without spatial
    variation (`test_enabled_lights`: background MIS off without portals or a varying shader; an environment map
    is selectable whatever sample_world, unless its importance_sampling is off): BSDF sampling
    then finds it alone, with MIS weight 1, and `intersect` still returns it. A uniform world's
    light samples (cosine-distributed about n) only duplicate a diffuse BSDF's own samples while taking
    selections, and shadow rays, from the other lights.
    Work scales with N times the number of analytic lights in `intersect`, and with N in `sample`. threads: how
    many threads fill an environment map's importance grid (core.world.importance_luminance)."""

    def __init__(self, scene: Scene, shift: np.ndarray, emissive_triangles: EmissiveTriangles | None,
                 scene_radius: float, sample_world: bool = True, threads: int = 1):
        shift = np.asarray(shift, dtype=np.float64).reshape(3)
        R = float(scene_radius) if np.isfinite(scene_radius) and scene_radius > 0 else 1.0
        self.shift = shift
        self.scene_radius = R
        tris = emissive_triangles if (emissive_triangles is not None and emissive_triangles.count) else None
        self.triangles = tris

        self._punctual = _PunctualLights.from_lights(
            [lt for lt in scene.lights if isinstance(lt, (PointLight, SpotLight))], shift)
        self._areas = _AreaLights.from_lights([lt for lt in scene.lights if isinstance(lt, AreaLight)], shift)
        self._suns = _SunLights.from_lights([lt for lt in scene.lights if isinstance(lt, SunLight)], R)
        # the scene lights behind each kind's table rows (`intersect`'s hidden= names lights by identity)
        self._row_lights = ([lt for lt in scene.lights if isinstance(lt, (PointLight, SpotLight))],
                            [lt for lt in scene.lights if isinstance(lt, AreaLight)],
                            [lt for lt in scene.lights if isinstance(lt, SunLight)])
        self._hiding: dict = {}
        env = scene.world.environment
        self._portals = portal_table(scene.world.portals, shift)  # world sampling through them (core.world)
        if len(self._portals):
            sample_world = True  # Cycles samples a world with portals whatever its variation
        self.environment = EnvironmentDistribution(env if env is not None and not scene.world.is_black else None,
                                                   threads)
        self.has_environment = self.environment.mean_luminance > 0
        if env is not None:
            wc = np.zeros(3)  # the map replaces the uniform colour
            world_lum = self.environment.mean_luminance
            # Cycles samples a world that varies (background MIS) unless its sampling method is None (the
            # light-sampling-only estimator samples it always: nothing else would find it)
            sample_world = self.has_environment and (env.importance_sampling or sample_world)
        else:
            wc = np.asarray(scene.world.color, dtype=np.float64).reshape(-1)
            wc = np.repeat(wc, 3) if wc.size == 1 else wc
            world_lum = float(luminance(wc))
        self.world_radiance = wc.astype(_F32)
        # Flux through the scene's cross-section disc, as for the sun: irradiance pi L on a disc of area pi R^2
        # (not into the whole bounding sphere: that picked the world 4x too often, see docs/lights.md).
        world_power = world_lum * math.pi ** 2 * R * R
        world_importance = _WORLD_MAP_IMPORTANCE if self.has_environment else _WORLD_IMPORTANCE

        # The selectable units (docs/lights.md): a few spatial groups of emissive triangles, each
        # analytic light, the world. Zero power is left out (never selected).
        builder = _UnitBuilder()
        self._tri_table = self._triangle_units(builder, tris)
        self._punctual_units(builder)
        self._area_units(builder)
        self._sun_units(builder, R)
        self._world_sel, self._world_unit = 0.0, -1
        if _selectable(world_power) and sample_world:
            self._world_unit = builder.add(lk.WORLD, 0, world_power,
                                           intensity=world_importance * world_power / (math.pi * R * R))
            self._world_sel = 1.0
        self._units = builder.units()
        pw = self._units.table[:, lk.C_POWER]
        self.has_lights = bool(pw.size and pw.sum() > 0 and np.isfinite(pw.sum()))
        # one unit: probability 1 everywhere, no per-point work
        self._per_point = pw.size > 1

        self.kinds_present = frozenset(_KIND_NAMES[int(k)] for k in np.unique(self._units.kind))
        # Something a ray can reach: a selectable light, or a lit world that is not sampled (MIS weight 1).
        self.has_emission = bool(self.has_lights or np.any(self.world_radiance > 0) or self.has_environment)
        # The world and the inside of sphere lights are sampled about the normal given to `sample`; `intersect`
        # then needs the same normal for MIS (checked, since a mismatch would bias silently).
        # With more than one unit the selection itself depends on n and on the transmission flag.
        self._n_matters = bool(self._world_sel > 0 or np.any(self._punctual.sphere & (self._punctual.sel > 0))
                               or self._per_point)
        self._sampled_about_n = False
        self._sampled_with_transmits = False
        self._tables = self._kernel_tables()

    # ---------------------------------------------------------------------------------------- construction
    def _triangle_units(self, builder: _UnitBuilder, tris: EmissiveTriangles | None) -> _TriangleTable:
        """A unit per spatial group of emissive triangles; inside a group a triangle is picked by power."""
        if tris is None:
            return _TriangleTable.empty()
        E = tris.count
        sel = np.zeros(E)
        unit = np.full(E, -1, np.int64)
        t_power = tris.power
        order, cdf, starts = [], [], [0]
        for members in _cluster_emitters(tris):
            members = members[np.isfinite(t_power[members]) & (t_power[members] > 0)]
            gp = float(t_power[members].sum())
            if not _selectable(gp):
                continue
            v = tris.vertices[members].astype(np.float64).reshape(-1, 3)
            lo, hi = v.min(axis=0), v.max(axis=0)
            nrm = tris.normal[members].astype(np.float64)
            # normal cone of a two-sided group: the principal normal direction and the widest deviation
            axis = np.linalg.eigh(nrm.T @ nrm)[1][:, -1]
            cos_o = float(np.clip(np.abs(nrm @ axis).min(), 0.0, 1.0))
            u = builder.add(lk.TRI_GROUP, len(order), gp, centre=0.5 * (lo + hi),
                            radius=0.5 * float(np.linalg.norm(hi - lo)), axis=axis, cos_o=cos_o,
                            sin_o=math.sqrt(max(1.0 - cos_o * cos_o, 0.0)), intensity=gp / _TWO_PI)
            share = t_power[members] / gp
            sel[members] = share
            unit[members] = u
            c = np.cumsum(share)
            c[-1] = 1.0
            order.append(members)
            cdf.append(len(order) - 1 + c)  # group j occupies [j, j + 1)
            starts.append(starts[-1] + members.size)
        # component-major copies for gathers, and selection x area pdf
        v = tris.vertices.astype(np.float32)
        edges = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 1], v[:, 0] - v[:, 2]], axis=1).astype(np.float64)
        empty = _TriangleTable.empty()
        return _TriangleTable(
            v0=_cm(v[:, 0]), e1=_cm(v[:, 1] - v[:, 0]), e2=_cm(v[:, 2] - v[:, 0]), normal=_cm(tris.normal),
            rad=_cm(tris.emission), pdf_area=(sel / tris.area).astype(_F32), sel=sel,
            edge2=(edges * edges).sum(axis=2).max(axis=1), unit=unit,
            order=np.concatenate(order).astype(np.int64) if order else empty.order,
            cdf=np.concatenate(cdf) if order else empty.cdf,
            start=np.asarray(starts, np.int64) if order else empty.start)

    def _punctual_units(self, builder: _UnitBuilder) -> None:
        lights = self._punctual
        n = len(lights.radius)
        lights.sel, lights.unit = np.zeros(n), np.full(n, -1, np.int64)
        for i in range(n):
            if not _selectable(lights.selection_power[i]):
                continue
            spot = bool(lights.spot[i])
            lights.unit[i] = builder.add(lk.SPOT if spot else lk.POINT, i, float(lights.selection_power[i]),
                                         centre=lights.pos[i].astype(np.float64), radius=float(lights.radius[i]),
                                         axis=lights.direction[i].astype(np.float64),
                                         cos_e=float(lights.cos_half[i]) if spot else -2.0,
                                         intensity=float(luminance(lights.power[i])) * _INV_4PI)
            lights.sel[i] = 1.0

    def _area_units(self, builder: _UnitBuilder) -> None:
        lights = self._areas
        n = len(lights.area)
        lights.sel, lights.unit = np.zeros(n), np.full(n, -1, np.int64)
        for i in range(n):
            if not _selectable(lights.selection_power[i]):
                continue
            half = 0.5 * math.hypot(lights.size_x[i], lights.size_y[i]) if not lights.ellipse[i] else \
                0.5 * max(lights.size_x[i], lights.size_y[i])
            lambert = lights.norm_spread[i] <= 0
            lights.unit[i] = builder.add(lk.AREA, i, float(lights.selection_power[i]), centre=lights.centre[i],
                                         radius=half, axis=lights.normal[i],
                                         cos_e=0.0 if lambert else 1.0 / math.sqrt(1.0 + lights.tan_half[i] ** 2),
                                         tan_half=0.0 if lambert else float(lights.tan_half[i]),
                                         norm_spread=float(lights.norm_spread[i]),
                                         intensity=float(lights.selection_power[i]) * _INV_PI)
            lights.sel[i] = 1.0

    def _sun_units(self, builder: _UnitBuilder, R: float) -> None:
        lights = self._suns
        n = len(lights.one_minus_cos)
        lights.sel, lights.unit = np.zeros(n), np.full(n, -1, np.int64)
        for i in range(n):
            if not _selectable(lights.selection_power[i]):
                continue
            cos_u = 1.0 - float(lights.one_minus_cos[i])
            lights.unit[i] = builder.add(lk.SUN, i, float(lights.selection_power[i]),
                                         axis=lights.to_sun[i].astype(np.float64), cos_u=cos_u,
                                         sin_u=math.sqrt(max(1.0 - cos_u * cos_u, 0.0)),
                                         intensity=float(lights.selection_power[i]) / (math.pi * R * R))
            lights.sel[i] = 1.0

    def _kernel_tables(self) -> tuple:
        """The tuple core.light_kernels reads (see its layout comment), built once."""
        world = np.zeros(lk.W_FIELDS)
        world[lk.W_R:lk.W_B + 1] = self.world_radiance
        world[lk.W_SEL], world[lk.W_UNIT] = self._world_sel, self._world_unit
        world[lk.W_LIT] = bool(np.any(self.world_radiance > 0) or self.has_environment)
        world[lk.W_MAP] = self.has_environment
        u = self._units
        return (u.table, u.kind, u.local, u.fallback, float(SELECTION_POWER_FLOOR),
                self._punctual.kernel_table(), self._areas.kernel_table(), self._suns.kernel_table(), world,
                *self._tri_table.kernel_tables(), np.ascontiguousarray(self._tri_table.unit, np.int64),
                *self.environment.tables, self._portals)

    def _tables_without_world(self) -> tuple:
        """The kernel tables with the world row unlit (for `intersect(world=False)`); sampling never uses them."""
        cached = getattr(self, "_no_world", None)
        if cached is None:
            world = self._tables[8].copy()
            world[lk.W_LIT] = 0.0
            cached = self._no_world = (*self._tables[:8], world, *self._tables[9:])
        return cached

    def _tables_hiding(self, world: bool, hidden: frozenset) -> tuple:
        """The kernel tables with the lights in `hidden` (ids of scene lights) unlit for `intersect` (their
        selection, and so every MIS weight, unchanged); cached per (world, hidden)."""
        key = (world, hidden)
        cached = self._hiding.get(key)
        if cached is None:
            base = self._tables if world else self._tables_without_world()
            punctual, areas, suns = base[5].copy(), base[6].copy(), base[7].copy()
            for table, rows, lit in ((punctual, self._row_lights[0], [lk.PT_LIT]),
                                     (areas, self._row_lights[1], [lk.AR_LIT]),
                                     (suns, self._row_lights[2], [lk.SU_R, lk.SU_G, lk.SU_B])):
                for i, lt in enumerate(rows):
                    if id(lt) in hidden:
                        table[i, lit] = 0.0
            cached = self._hiding[key] = (*base[:5], punctual, areas, suns, *base[8:])
        return cached

    def _scratch(self) -> np.ndarray:
        """Per-call scratch for the kernels' per-point selection probabilities (K,) (calls may run in threads)."""
        return np.empty(max(self._units.kind.size, 1))

    # -------------------------------------------------------------------------------------------- sampling
    def sample(self, p: np.ndarray, n: np.ndarray | None, u_select: np.ndarray, u: np.ndarray,
               transmits: np.ndarray | None = None) -> LightSample:
        """Pick an emitter for each shading point p (N, 3) and sample a direction towards it.

        n: (N, 3) shading-side unit normal or None: weighs the per-point selection (see the module docstring),
        cosine-samples the world (else uniform sphere) and the inside of a sphere light. transmits: (N,) bool,
        whether the material at p transmits (its BSDF is not zero below n), or None (treated as True: no
        hemisphere cut). Pass the same n and transmits to `intersect` and `pdf_triangle` at the same point, so
        that MIS sees the same pdfs. u_select: (N,) and u: (N, 2) uniform numbers in [0, 1)."""
        p = _rows(p)
        N = p.shape[0]
        if not self.has_lights or N == 0:
            return LightSample.empty(N)
        # n matters to the selection, the world and the inside of sphere lights
        need_n = n is not None and self._n_matters
        nr = _rows(n, N) if need_n else None
        self._sampled_about_n |= need_n
        tc = self._transmits(transmits, N, nr)
        self._sampled_with_transmits |= tc is not None
        u = np.ascontiguousarray(np.broadcast_to(np.asarray(u, dtype=_F32).reshape(-1, 2), (N, 2)))
        u_sel = np.ascontiguousarray(np.broadcast_to(np.asarray(u_select, dtype=np.float64).reshape(-1), (N,)))
        out = LightSample(wi=np.empty((N, 3), _F32), dist=np.empty(N, _F32), radiance=np.empty((N, 3), _F32),
                          pdf=np.empty(N, _F32), delta=np.empty(N, bool))
        lk.sample_batch(p, *self._n_t_args(nr, tc), u_sel, u, self._per_point, self._tables, self._scratch(),
                        out.wi, out.dist, out.radiance, out.pdf, out.delta)
        return out

    # per-point selection ----------------------------------------------------------------------------------
    def _transmits(self, transmits, N, nc):
        """The transmission flags (N,) bool as the kernels take them, or None when they cannot matter (one unit,
        or no normal) or were not given."""
        if transmits is None or nc is None or not self._per_point:
            return None
        return np.ascontiguousarray(np.broadcast_to(np.asarray(transmits, dtype=bool).reshape(-1), (N,)))

    @staticmethod
    def _n_t_args(nr, tc):
        return (np.zeros((0, 3), _F32) if nr is None else nr, nr is not None,
                np.ones(0, bool) if tc is None else tc, tc is not None)

    def _unit_probability(self, which, pr, nr, tc) -> np.ndarray:
        """(M,) float64: the probability with which `sample` picks unit which (scalar or (M,); -1: never) at the
        points pr (M, 3) with the normals nr (M, 3) or None and the flags tc (M,) or None."""
        M = pr.shape[0]
        which = np.broadcast_to(np.asarray(which, np.int64).reshape(-1), (M,))
        if not self._per_point:
            return (which >= 0).astype(np.float64)
        out = np.empty(M)
        lk.probability(pr, *self._n_t_args(nr, tc), np.ascontiguousarray(which), self._units.table,
                       self._units.kind, self._units.fallback, SELECTION_POWER_FLOOR, self._scratch(), out)
        return out

    def selection_probabilities(self, p: np.ndarray, n: np.ndarray | None = None,
                                transmits: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Per-point probability (N,) of each selectable unit, keyed "point 0", "area 1", "sun 0", "world",
        "triangles 2" (a group), ... (index within its kind): what `sample` uses; for tests and diagnostics."""
        pr = _rows(p)
        N = pr.shape[0]
        nr = _rows(n, N) if n is not None and self._n_matters else None
        tc = self._transmits(transmits, N, nr)
        out = {}
        for k in range(self._units.kind.size):
            kind, i = int(self._units.kind[k]), int(self._units.local[k])
            name = "world" if kind == lk.WORLD else "triangles" if kind == lk.TRI_GROUP else _KIND_NAMES[kind]
            if kind != lk.WORLD:
                name = f"{name} {i}"
            out[name] = self._unit_probability(k, pr, nr, tc)
        return out

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
        N = emitter.shape[0]
        if self.triangles is None or N == 0:
            return np.zeros(N, _F32)
        emitter = np.ascontiguousarray(emitter, np.int64)
        o = _rows(origin, N)
        cos_l = _vec(abs_cos_light, N)
        d2 = _vec(dist2, N)
        nr = self._check_normal(n, N, transmits, "pdf_triangle") if self._per_point else None
        tc = self._transmits(transmits, N, nr)
        out = np.empty(N, _F32)
        lk.triangle_pdf_batch(emitter, o, d2, cos_l, *self._n_t_args(nr, tc), self._per_point, self._tables,
                              self._scratch(), out)
        return out

    def _check_normal(self, n, N, transmits, caller):
        """n as (N, 3) float32 for the selection (None when it does not matter); raises where `sample` got normals
        or transmission flags that this MIS evaluation lacks (the pdfs would silently differ)."""
        if n is None and self._sampled_about_n:
            raise ValueError(f"LightSampler.{caller}: `sample` was given normals, so the world, sphere lights or "
                             "the per-point light selection depend on them; pass the same normal of the ray's "
                             "origin as n= for MIS")
        if transmits is None and self._sampled_with_transmits:
            raise ValueError(f"LightSampler.{caller}: `sample` was given transmission flags, which weigh the "
                             "per-point light selection; pass the same flags of the ray's origin as transmits=")
        return _rows(n, N) if n is not None and self._n_matters else None

    def intersect(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, bsdf_pdf: np.ndarray,
                  bsdf_delta: np.ndarray, mis: bool, n: np.ndarray | None = None,
                  camera: bool = False, transmits: np.ndarray | None = None, world: bool = True,
                  hidden: frozenset = frozenset()) -> np.ndarray:
        """Emission (N, 3) of every analytic light surface the rays o + t d (unit d, (N, 3)) pass for
        0 < t < tmax, summed (lights are transparent), each MIS-weighted by the power heuristic against
        bsdf_pdf (N,) (solid angle), weight 1 where bsdf_delta (N,) or when mis is False.

        Seen: area lights (front face), point/spot lights with radius > 0 (the disc facing o, or the sphere),
        and, where tmax is inf, the sun's disc (angle > 0) and the world. n: the normal given to `sample` at o
        (the selection, the world and the inside of sphere lights depend on it), None if `sample` got None;
        transmits: the flags given to `sample` there (None likewise).
        camera=True: camera rays, which see the world but no light unless the light has
        `visible_camera = True` (Blender's default is False); no MIS weighting.
        world=False: the world is not seen (rays that count as transparent under Film > Transparent).
        hidden: ids of scene lights these rays do not see (light linking, a light's ray visibility)."""
        o = _rows(o)
        N = o.shape[0]
        if N == 0:
            return np.zeros((0, 3), _F32)
        dr = _rows(d, N)
        tmax = _vec(tmax, N)
        use_mis = bool(mis) and not camera
        if use_mis:
            bsdf_pdf = _vec(bsdf_pdf, N)
            no_mis = np.ascontiguousarray(np.broadcast_to(np.asarray(bsdf_delta, dtype=bool).reshape(-1), (N,)))
            nr = self._check_normal(n, N, transmits, "intersect")
        else:
            bsdf_pdf, no_mis = np.zeros(0, _F32), np.zeros(0, bool)
            nr = _rows(n, N) if n is not None and self._n_matters else None
        tc = self._transmits(transmits, N, nr)
        out = np.empty((N, 3), _F32)
        if hidden:
            tables = self._tables_hiding(world, hidden)
        else:
            tables = self._tables if world else self._tables_without_world()
        lk.emission_batch(o, dr, tmax, bsdf_pdf, no_mis, use_mis, *self._n_t_args(nr, tc), bool(camera),
                          self._per_point, tables, self._scratch(), out)
        return out
