"""The per-point inputs of the Vector nodes (Normal Map, Bump) that the integrator hands the evaluator: ray
differentials spread along the surface, the UV maps' derivatives along them, tangent layers and the mesh normal.

Cycles keeps a ray's differential in compact form, one footprint size dP per shading point
(differential_transfer_compact: the ray's dP plus distance x its dD); where a node needs vectors it spreads that
size along two orthonormal tangents of the viewer-side true normal Ng (differential_from_compact, with the
tangents of make_orthonormals). A mesh attribute's derivative follows from the barycentric derivatives that move
the point by those vectors within its triangle (differential_dudv). NumPy over a batch of points, but for the
differentials: one compiled function per point (core.geometry_kernels.differentials_point), shared with the fused
path kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class VectorContext:
    """dP (N, 2, 3): dP.dx, dP.dy (world units); db (N, 2, 2): for each, the change of the barycentric weights
    (b1, b2) of corners 1 and 2; duv (N, 2, 2): the active UV map's change; tangents (N, K, 4): the tangent
    layers interpolated (xyz, sign); mesh_normal (N, 3): the interpolated mesh normal, unnormalised, outside.
    Each None when not needed."""

    dP: np.ndarray | None = None
    db: np.ndarray | None = None
    duv: np.ndarray | None = None
    tangents: np.ndarray | None = None
    mesh_normal: np.ndarray | None = None


def row_lengths(v: np.ndarray) -> np.ndarray:
    """Euclidean length of each row of v (N, 3), bit for bit np.linalg.norm(v, axis=1) (the same float64
    sum, (x^2 + y^2) + z^2) at about a third of its cost: the norm reduces along the short axis, which NumPy
    runs as a slow strided reduction."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return np.sqrt(x * x + y * y + z * z)


def orthonormals(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (a, b) of unit normals n (N, 3) with b = n x a, chosen as Cycles' make_orthonormals:
    a along (1, 1, 1) x n, or (-1, 1, 1) x n when n is along (1, 1, 1)."""
    n = np.asarray(n, np.float64)
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    diagonal = (x == y) & (x == z)
    a = np.stack([z - y, np.where(diagonal, x + z, x - z), np.where(diagonal, -y - x, y - x)], axis=1)
    a /= np.maximum(row_lengths(a), 1e-300)[:, None]
    # b = n x a component by component: np.cross's own arithmetic (the same products and differences, the same
    # bits) without its axis bookkeeping, which costs more than the products for these short rows
    ax, ay, az = a[:, 0], a[:, 1], a[:, 2]
    b = np.empty_like(a)
    b[:, 0] = y * az - z * ay
    b[:, 1] = z * ax - x * az
    b[:, 2] = x * ay - y * ax
    return a, b


@dataclass
class VectorNeeds:
    """Per material (M,) bool: what its node program reads beyond the basic shading context. differentials: ray
    differentials (dP, the UV maps' derivatives; a Bump node), tangents: tangent layers and the mesh normal
    (Normal Map, Tangent), uv_layers: the named UV maps (UV Map node). A point whose material reads none of them
    gets zeros there: the evaluator's reads of them are multiplied by 0 (an unbumped point's zero offset)."""

    differentials: np.ndarray
    tangents: np.ndarray
    uv_layers: np.ndarray

    @classmethod
    def of(cls, shading) -> "VectorNeeds":
        """From a core.shading.PreparedShading's packed programs."""
        from . import registry as R

        m = len(shading.prog_of_mat)
        out = cls(np.zeros(m, bool), np.zeros(m, bool), np.zeros(m, bool))
        for mat, p in enumerate(shading.prog_of_mat):
            if p < 0:
                continue
            ops = shading.code[shading.code_start[p]:shading.code_start[p + 1], 0]
            out.differentials[mat] = bool(np.any(ops == R.OP_BUMP))
            out.tangents[mat] = bool(np.any((ops == R.OP_NORMAL_MAP) | (ops == R.OP_TANGENT)))
            out.uv_layers[mat] = bool(np.any(ops == R.OP_UV_LAYER))
        return out


def _subset(want: np.ndarray | None, n: int) -> np.ndarray | None:
    """Row indices where `want` (N,) bool holds, or None for all rows (also when want is None)."""
    if want is None or want.all():
        return None
    return np.flatnonzero(want)


def _scatter(values: np.ndarray, rows: np.ndarray | None, n: int) -> np.ndarray:
    """values computed for `rows` (None: all n rows) as an (n, ...) array, zeros elsewhere."""
    if rows is None:
        return values
    full = np.zeros((n, *values.shape[1:]), values.dtype)
    full[rows] = values
    return full


def vector_context(ps, prim: np.ndarray, bary, ng_view: np.ndarray, dp: np.ndarray | None,
                   has_uv: bool, wants_differentials: np.ndarray | None = None,
                   wants_tangents: np.ndarray | None = None) -> VectorContext:
    """The Vector-node inputs of hits on triangles `prim` at barycentrics bary = (b1, b2) (None: none), with
    viewer-side true normals ng_view and footprints dp (None: no differentials). ps: the PreparedScene
    (tri_vertices, uvs, tangent_layers, corner_normals, smooth, face_normals). wants_differentials /
    wants_tangents (N,) bool: the points whose program reads them (VectorNeeds); the others get zeros (None:
    every point). Each point's values do not depend on the others'."""
    out = VectorContext()
    if bary is None:
        return out
    n = len(prim)
    if dp is not None:
        rows = _subset(wants_differentials, n)
        if rows is None or len(rows):
            d, db, duv = _differentials(ps, prim if rows is None else prim[rows],
                                        ng_view if rows is None else ng_view[rows],
                                        dp if rows is None else np.asarray(dp)[rows], has_uv)
            out.dP, out.db = _scatter(d, rows, n), _scatter(db, rows, n)
            out.duv = None if duv is None else _scatter(duv, rows, n)
        else:
            out.dP, out.db = np.zeros((n, 2, 3), np.float32), np.zeros((n, 2, 2), np.float32)
            out.duv = np.zeros((n, 2, 2), np.float32) if has_uv and ps.uvs is not None else None
    if ps.tangent_layers is not None:
        rows = _subset(wants_tangents, n)
        if rows is None or len(rows):
            t, normal = _tangents(ps, prim if rows is None else prim[rows],
                                  bary if rows is None else (np.asarray(bary[0])[rows], np.asarray(bary[1])[rows]))
            out.tangents, out.mesh_normal = _scatter(t, rows, n), _scatter(normal, rows, n)
        else:
            out.tangents = np.zeros((n, ps.tangent_layers.shape[1], 4), np.float32)
            out.mesh_normal = np.zeros((n, 3), np.float32)
    return out


def _differentials(ps, prim, ng_view, dp, has_uv):
    """(dP (N, 2, 3), db (N, 2, 2), duv (N, 2, 2) or None) float32 of VectorContext for these points: the
    compiled per-point function (core.geometry_kernels.differentials_point) that the fused path kernel calls
    too, so both give the same bits (orthonormals above is its NumPy statement of the tangents)."""
    from ..geometry_kernels import differentials

    n = len(prim)
    dP, db = np.empty((n, 2, 3), np.float32), np.empty((n, 2, 2), np.float32)
    with_uv = has_uv and ps.uvs is not None
    duv = np.empty((n, 2, 2), np.float32) if with_uv else np.empty((0, 2, 2), np.float32)
    uvs = ps.uvs if with_uv else np.zeros((0, 3, 2), np.float32)
    differentials(np.ascontiguousarray(prim, np.int64), np.ascontiguousarray(ng_view, np.float32),
                  np.ascontiguousarray(dp, np.float32), np.ascontiguousarray(ps.tri_vertices, np.float32),
                  np.ascontiguousarray(uvs, np.float32),
                  dP, db, duv)
    return dP, db, (duv if with_uv else None)


def _tangents(ps, prim, bary):
    """(tangents (N, K, 4), mesh normal (N, 3)) float32 of VectorContext for these points."""
    b1 = np.asarray(bary[0], np.float64)
    b2 = np.asarray(bary[1], np.float64)
    b0 = 1.0 - b1 - b2
    t = ps.tangent_layers[prim]  # (N, K, 3, 4)
    tangents = (t[:, :, 0] * b0[:, None, None] + t[:, :, 1] * b1[:, None, None]
                + t[:, :, 2] * b2[:, None, None]).astype(np.float32)
    normal = ps.face_normals[prim].astype(np.float64)
    if ps.corner_normals is not None:
        cn = ps.corner_normals[prim].astype(np.float64)
        smooth_n = cn[:, 0] * b0[:, None] + cn[:, 1] * b1[:, None] + cn[:, 2] * b2[:, None]
        normal = np.where(ps.smooth[prim][:, None], smooth_n, normal)
    return tangents, normal.astype(np.float32)


def camera_differentials(camera, raster_x: np.ndarray, raster_y: np.ndarray, rays,
                         lens_u: np.ndarray | None = None, compiled: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Cycles' compact differentials of camera rays (dP, dD), (N,) float32 each: the mean length of the change of
    the ray's origin (dP) and of its unit direction (dD) when the raster position moves by one pixel in x and in
    y (differential_make_compact). Orthographic: dP = the pixel's size, dD = 0; perspective: the origin sits on
    the near clipping plane, so dP = its distance x dD, as Cycles' camera rays. `rays` are camera_rays' rays
    at (raster_x, raster_y); compiled: a pinhole camera's in one compiled pass (camera.pinhole_differentials,
    the same bits as the NumPy below); False (or another camera): in NumPy, from two more ray batches."""
    from ..camera import camera_rays, pinhole_differentials

    if compiled:
        out = pinhole_differentials(camera, raster_x, raster_y, rays)
        if out is not None:
            return out
    x = np.asarray(raster_x, np.float64)
    y = np.asarray(raster_y, np.float64)
    rx = camera_rays(camera, x + 1.0, y, lens_u)
    ry = camera_rays(camera, x, y + 1.0, lens_u)
    o, d = rays.origins.astype(np.float64), rays.directions.astype(np.float64)
    dp = 0.5 * (row_lengths(rx.origins - o) + row_lengths(ry.origins - o))
    dd = 0.5 * (row_lengths(rx.directions - d) + row_lengths(ry.directions - d))
    return dp.astype(np.float32), dd.astype(np.float32)
