"""Light sampling of textured emitters: triangles whose emission a node program drives per point.

Their emission is unknown until a program runs at a point, so the light sampler of core.lights (one constant
radiance per emitting triangle) cannot hold them. `TexturedEmitters` is a second, separate light-sampling
strategy for them, combined with BSDF sampling by the power heuristic (each of the two light-sampling strategies
covers its own emitters, so their sum stays unbiased):

- selection: triangle i with probability proportional to area_i x (a_i + FLOOR x mean(a)), a_i the average of
  the emission's largest absolute channel over SAMPLES_PER_TRIANGLE stratified points of the triangle, estimated
  once per render by running the programs there (`build`'s `emission_at`). The floor keeps the pdf positive on
  every triangle, so a triangle whose estimate is 0 but which emits somewhere is still found: unbiased whatever
  the estimate; a good estimate only lowers the noise.
- a point uniformly on the triangle (area measure), converted to solid angle at the shading point:
  pdf = p_select x dist^2 / (area x |cos_light|); both faces emit (as the constant emitters).
- the radiance there comes from running the program at the sampled point (the integrator's `emission_at`).

A program that reads the Light Path node is light-sampled as Cycles samples it: a light sample runs the program
with no ray-kind flag set (Is Diffuse Ray, Is Camera Ray, ... read 0) and Ray Depth one more than at the
shading point, while a BSDF ray that hits the emitter runs it with that ray's flags, MIS-weighted: so an
emitter that shines only for diffuse rays lights a diffuse surface by the BSDF-sampled share alone, as in
Cycles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lights import nondegenerate_triangles

SAMPLES_PER_TRIANGLE = 16  # stratified points per triangle for the emission estimate (4 x 4 over the square)
FLOOR = 0.05  # share of the mean estimate every triangle's selection weight gets (unbiasedness, see above)
MAX_ESTIMATE_POINTS = 1 << 21  # beyond this many emitting triangles x points, fewer points per triangle


def _square_to_triangle(u1: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barycentrics (b1, b2) of a uniform point on a triangle (P = (1 - b1 - b2) v0 + b1 v1 + b2 v2)."""
    su = np.sqrt(u1)
    return (u2 * su).astype(np.float32), (1.0 - su).astype(np.float32)


@dataclass
class TexturedEmitters:
    """triangle_id (E,) global triangle index; vertices (E, 3, 3) float32 (the integrator's shifted frame);
    normal (E, 3) float32 unit; area (E,) float64; select_pdf (E,) float64 (sums to 1); cdf (E,) float64;
    emitter_of_triangle (T,) int32 (-1: not a textured emitter); average (E,) the emission estimate."""

    triangle_id: np.ndarray
    vertices: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    select_pdf: np.ndarray
    cdf: np.ndarray
    emitter_of_triangle: np.ndarray
    average: np.ndarray

    @classmethod
    def build(cls, tri_vertices: np.ndarray, material_index: np.ndarray, sampled_materials: np.ndarray,
              emission_at) -> "TexturedEmitters | None":
        """The table of the triangles whose material is in `sampled_materials` ((M,) bool), or None when there
        are none. emission_at(triangles (K,), b1 (K,), b2 (K,)) -> (K, 3) emitted radiance seen from the front."""
        tris = np.flatnonzero(sampled_materials[material_index]) if len(material_index) else np.zeros(0, np.int64)
        if tris.size == 0:
            return None
        tris, cross, area2 = nondegenerate_triangles(tri_vertices, tris)
        if tris.size == 0:
            return None
        e = tris.size
        side = 4 if e * SAMPLES_PER_TRIANGLE <= MAX_ESTIMATE_POINTS else 1
        s = (np.arange(side) + 0.5) / side
        u1, u2 = (a.reshape(-1) for a in np.meshgrid(s, s))
        b1, b2 = _square_to_triangle(u1, u2)
        k = b1.size
        radiance = emission_at(np.repeat(tris, k), np.tile(b1, e), np.tile(b2, e))
        average = np.abs(np.asarray(radiance, np.float64)).max(axis=1).reshape(e, k).mean(axis=1)
        average = np.where(np.isfinite(average), average, 0.0)
        area = 0.5 * area2
        mean = float((average * area).sum() / area.sum())
        weight = area * (average + (FLOOR * mean if mean > 0 else 1.0))
        select = weight / weight.sum()
        cdf = np.cumsum(select)
        cdf[-1] = 1.0
        of_triangle = np.full(len(material_index), -1, np.int32)
        of_triangle[tris] = np.arange(e, dtype=np.int32)
        return cls(tris.astype(np.int64), np.ascontiguousarray(tri_vertices[tris], np.float32),
                   (cross / area2[:, None]).astype(np.float32), area, select, cdf, of_triangle, average)

    @property
    def count(self) -> int:
        return int(self.triangle_id.shape[0])

    def sample(self, p: np.ndarray, u_select: np.ndarray, u: np.ndarray):
        """One point per shading point p (N, 3): (emitter (N,), b1, b2 (N,) barycentrics, wi (N, 3) unit towards
        it, dist (N,), pdf (N,) solid angle incl. selection, 0 where the point is seen edge-on)."""
        e = np.minimum(np.searchsorted(self.cdf, np.asarray(u_select, np.float64), side="right"), self.count - 1)
        b1, b2 = _square_to_triangle(np.asarray(u[:, 0], np.float64), np.asarray(u[:, 1], np.float64))
        v = self.vertices[e].astype(np.float64)
        point = v[:, 0] * (1.0 - b1 - b2)[:, None] + v[:, 1] * b1[:, None] + v[:, 2] * b2[:, None]
        d = point - np.asarray(p, np.float64)
        dist2 = np.einsum("ij,ij->i", d, d)
        dist = np.sqrt(dist2)
        wi = d / np.maximum(dist, 1e-30)[:, None]
        cos_l = np.abs(np.einsum("ij,ij->i", wi, self.normal[e].astype(np.float64)))
        pdf = self.pdf(e, dist2, cos_l)
        return e, b1, b2, wi.astype(np.float32), dist.astype(np.float32), pdf

    def pdf(self, emitter: np.ndarray, dist2: np.ndarray, abs_cos_light: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (selection included) of sampling the point of `emitter` at squared distance dist2
        seen at |cos| abs_cos_light; 0 edge-on."""
        cos_l = np.asarray(abs_cos_light, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = self.select_pdf[emitter] * np.asarray(dist2, np.float64) / (self.area[emitter] * cos_l)
        return np.where((cos_l > 1e-7) & np.isfinite(pdf), pdf, 0.0).astype(np.float32)
