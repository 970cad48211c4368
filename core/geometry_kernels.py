"""Compiled (numba) kernels of surface geometry: surface interactions from ray hits (points, normals, shading
frames from barycentrics), ray origins offset off surfaces, and the per-triangle frames the hits read.

One pass over the paths instead of dozens of NumPy array operations, each of which would stream every array
through memory again: profiling the NumPy wavefront (`monte perf`, line profiles) showed ~40% of render time in
this glue. What paths do at a surface (scatter, shadow rays, accumulation) is in core.path_kernels.

Conventions as in core.integrator: float32 (N, 3) row vectors in the camera-shifted frame; face normals follow
the winding; the shading frame's +z is the shading normal flipped to the face normal's side ("outside").
Kernels release the GIL (render worker threads run them in parallel) and are compiled once, cached on disk.
"""

from __future__ import annotations

import math

import numpy as np

from .jit_cache import jit as _jit
from .jit_cache import jit_inline as _jit_inline
from .warps import onb_f32


_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_OFFSET_SCALE = np.float32(2.0**-19)  # of the coordinates' magnitude: see offset_point
_TINY = np.float32(1e-30)


@_jit
def offset_point(px, py, pz, nx, ny, nz, wx, wy, wz, magnitude):
    """Move point p off its surface along the unit geometric normal n to the side of direction w, by an amount
    proportional to the coordinates' float32 rounding error.

    magnitude: the largest absolute coordinate involved in computing p (of p itself and of the hit triangle's
    vertices). A point interpolated from float32 vertices is wrong by a few ulps of that magnitude (pbrt-v4's
    error bounds; Wachter & Binder, Ray Tracing Gems ch. 6). An offset of 2^-19 (~64 ulps) of it clears the error
    with margin at any scale; the floor keeps points at the origin from a zero offset."""
    eps = max(magnitude * _OFFSET_SCALE, _TINY)
    if nx * wx + ny * wy + nz * wz < _F0:
        eps = -eps
    return px + nx * eps, py + ny * eps, pz + nz * eps


@_jit
def smooth_normal(corner_normals, t, b0, b1, b2):
    """The unit smooth-shading normal of triangle t at barycentrics (b0, b1, b2): its corner normals
    interpolated in float32, normalised (a zero length kept finite by a tiny floor)."""
    sx = corner_normals[t, 0, 0] * b0 + corner_normals[t, 1, 0] * b1 + corner_normals[t, 2, 0] * b2
    sy = corner_normals[t, 0, 1] * b0 + corner_normals[t, 1, 1] * b1 + corner_normals[t, 2, 1] * b2
    sz = corner_normals[t, 0, 2] * b0 + corner_normals[t, 1, 2] * b1 + corner_normals[t, 2, 2] * b2
    length = max(np.float32(math.sqrt(sx * sx + sy * sy + sz * sz)), _TINY)
    return sx / length, sy / length, sz / length


@_jit
def _valid_reflection_normal(gx, gy, gz, ix, iy, iz, nx, ny, nz):
    """Cycles' ensure_valid_specular_reflection: the shading normal N (unit, on the viewer's side of the face
    normal G) tilted towards G just enough that the mirror reflection of the viewer direction I about it leaves
    the true surface at least min(0.9 I.G, 0.01) above the tangent plane. Else, at silhouettes of smooth-shaded
    meshes, mirror and glass paths would be sent below the surface and lost."""
    i_z = ix * gx + iy * gy + iz * gz
    n_z = nx * gx + ny * gy + nz * gz
    n_i = nx * ix + ny * iy + nz * iz
    threshold = min(0.9 * i_z, 0.01)
    if 2.0 * n_i * n_z - i_z >= threshold:
        return nx, ny, nz
    xx, xy, xz = nx - n_z * gx, ny - n_z * gy, nz - n_z * gz  # N's part in the tangent plane
    length = math.sqrt(xx * xx + xy * xy + xz * xz)
    if length <= 0.0:
        return nx, ny, nz
    xx, xy, xz = xx / length, xy / length, xz / length
    i_x = ix * xx + iy * xy + iz * xz
    # N' = sin(t) X + cos(t) G reflects I to height i_x sin(2t) + i_z cos(2t): solve for that = threshold.
    rho = math.sqrt(i_x * i_x + i_z * i_z)
    if rho <= 0.0:
        return nx, ny, nz
    psi = math.atan2(i_x, i_z)
    delta = math.acos(min(max(threshold / rho, -1.0), 1.0))
    theta0 = math.atan2(length, n_z)
    best = 0.0
    best_gap = 1e30
    for phi in (psi - delta, psi + delta):
        theta = 0.5 * phi
        if abs(theta) < 0.5 * math.pi and abs(theta - theta0) < best_gap:
            best, best_gap = theta, abs(theta - theta0)
    st, ct = math.sin(best), math.cos(best)
    return st * xx + ct * gx, st * xy + ct * gy, st * xz + ct * gz


@_jit
def surface(rows, prim, bu, bv, d, tri_vertices, face_normals, corner_normals, smooth, tri_uvs, tri_magnitude,
            material_index, specular, p, ng, ns_raw, ns, tangent, bitangent, wo, n_view, dn, mag, cos_o_geo, uv):
    """Surface interaction of the hits `rows` (indices into prim/bu/bv/d); writes row k of each output.

    p: point from barycentrics (the triangle's own precision). ng: face normal. ns_raw: interpolated shading
    normal as the mesh gives it (the normal AOV). ns: the same flipped to ng's side; tangent, bitangent: Duff et
    al.'s branchless basis around ns. wo: direction to the viewer (-d) in that frame. n_view: ns turned to the
    viewer's side of the surface as the geometric normal decides it (Cycles flips N with Ng), even where the viewer
    is below ns itself: the side the BSDF acts on (core.bsdf), light selection and MIS must agree on. mag: largest |coordinate| of p and its triangle (ray offset scale). cos_o_geo: -d . ng.
    corner_normals/smooth and tri_uvs may be empty arrays (flat shading, no UVs). specular (M,): materials
    with a glossy, glass or refraction lobe, whose smooth shading normals are kept valid for reflection.
    dn: the diffuse lobes' normal in the local frame (tangent, bitangent, ns): the shading normal before that
    validity tilt (Cycles tilts only the specular closures' normal), exactly (0, 0, 1) where nothing was tilted.
    """
    has_normals = corner_normals.shape[0] > 0
    has_uvs = tri_uvs.shape[0] > 0
    for k in range(rows.shape[0]):
        i = rows[k]
        t = prim[i]
        b1 = bu[i]
        b2 = bv[i]
        b0 = _F1 - b1 - b2
        m = tri_magnitude[t]
        for c in range(3):
            pc = tri_vertices[t, 0, c] * b0 + tri_vertices[t, 1, c] * b1 + tri_vertices[t, 2, c] * b2
            p[k, c] = pc
            m = max(m, abs(pc))
            ng[k, c] = face_normals[t, c]
        mag[k] = m
        gx, gy, gz = face_normals[t, 0], face_normals[t, 1], face_normals[t, 2]
        sx, sy, sz = gx, gy, gz
        if has_normals and smooth[t]:
            sx, sy, sz = smooth_normal(corner_normals, t, b0, b1, b2)
        ns_raw[k, 0], ns_raw[k, 1], ns_raw[k, 2] = sx, sy, sz
        if has_uvs:
            for c in range(2):
                uv[k, c] = tri_uvs[t, 0, c] * b0 + tri_uvs[t, 1, c] * b1 + tri_uvs[t, 2, c] * b2
        ox, oy, oz = -d[i, 0], -d[i, 1], -d[i, 2]
        cos_o_geo[k] = ox * gx + oy * gy + oz * gz
        if sx * gx + sy * gy + sz * gz < _F0:
            sx, sy, sz = -sx, -sy, -sz
        ux, uy, uz = sx, sy, sz  # the normal the diffuse lobes keep
        if has_normals and smooth[t] and specular[material_index[t]]:
            side = _F1 if cos_o_geo[k] >= _F0 else -_F1  # work on the viewer's side of the surface
            bx, by, bz = _valid_reflection_normal(gx * side, gy * side, gz * side, ox, oy, oz,
                                                  sx * side, sy * side, sz * side)
            sx, sy, sz = np.float32(bx * side), np.float32(by * side), np.float32(bz * side)
        ns[k, 0], ns[k, 1], ns[k, 2] = sx, sy, sz
        tx, ty, tz, bx, by, bz = onb_f32(sx, sy, sz)
        tangent[k, 0], tangent[k, 1], tangent[k, 2] = tx, ty, tz
        bitangent[k, 0], bitangent[k, 1], bitangent[k, 2] = bx, by, bz
        _diffuse_normal(dn, k, ux, uy, uz, sx, sy, sz, tx, ty, tz, bx, by, bz)
        wo[k, 0] = ox * tx + oy * ty + oz * tz
        wo[k, 1] = ox * bx + oy * by + oz * bz
        wo[k, 2] = ox * sx + oy * sy + oz * sz
        flip = -_F1 if cos_o_geo[k] < _F0 else _F1
        n_view[k, 0], n_view[k, 1], n_view[k, 2] = sx * flip, sy * flip, sz * flip


@_jit
def reframe(rows, normal, d, ng, cos_o_geo, correct, ns, tangent, bitangent, wo, n_view, dn):
    """Shading frames of the points `rows` rebuilt around a node-set shading normal (a Normal Map or Bump node
    driving the BSDFs' Normal input): normal (N, 3) world space on the viewer's side (Cycles' closure N), d the
    incoming ray directions, ng the face normals, cos_o_geo = -d . ng; correct (N,) bool: tilt the normal so
    that the mirror reflection of the viewer stays above the surface (Cycles' bump-map correction, applied where
    the material has specular lobes, as `surface` does for smooth normals). Writes ns (the normal on ng's side
    of the viewer, Monte's "outside" convention of `surface`), the tangent frame, wo, n_view and dn (the node's
    normal, untilted, for the diffuse lobes: see `surface`); a zero or non-finite normal keeps the point's frame."""
    for j in range(rows.shape[0]):
        k = rows[j]
        ok, sx, sy, sz, tx, ty, tz, bx, by, bz, lx, ly, lz, vx, vy, vz, d0, d1, d2 = reframe_point(
            normal[k, 0], normal[k, 1], normal[k, 2], d[k, 0], d[k, 1], d[k, 2], ng[k, 0], ng[k, 1], ng[k, 2],
            cos_o_geo[k], correct[k])
        if not ok:
            continue
        n_view[k, 0], n_view[k, 1], n_view[k, 2] = vx, vy, vz
        ns[k, 0], ns[k, 1], ns[k, 2] = sx, sy, sz
        tangent[k, 0], tangent[k, 1], tangent[k, 2] = tx, ty, tz
        bitangent[k, 0], bitangent[k, 1], bitangent[k, 2] = bx, by, bz
        wo[k, 0], wo[k, 1], wo[k, 2] = lx, ly, lz
        dn[k, 0], dn[k, 1], dn[k, 2] = d0, d1, d2


@_jit
def reframe_point(nx, ny, nz, dx, dy, dz, gx, gy, gz, cos_o_geo, correct):
    """`reframe` at one point (the fused path kernel calls it per vertex, `reframe` per row: the same bits): the
    node-set normal n (world space, the viewer's side), the incoming direction d, the face normal g, cos_o_geo =
    -d . g, correct: the specular tilt. Returns (ok, ns (3), tangent (3), bitangent (3), wo (3), n_view (3), dn
    (3)); ok false (the rest zeros) where n is zero or not finite: the point keeps its frame."""
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not (length > 0.0 and math.isfinite(length)):
        return (False, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0, _F0,
                _F0)
    nx, ny, nz = nx / length, ny / length, nz / length
    side = _F1 if cos_o_geo >= _F0 else -_F1
    ox, oy, oz = -dx, -dy, -dz
    ux, uy, uz = np.float32(nx * side), np.float32(ny * side), np.float32(nz * side)
    if correct:
        bx, by, bz = _valid_reflection_normal(gx * side, gy * side, gz * side, ox, oy, oz, nx, ny, nz)
        nx, ny, nz = bx, by, bz
    vx, vy, vz = np.float32(nx), np.float32(ny), np.float32(nz)
    sx, sy, sz = vx * side, vy * side, vz * side
    tx, ty, tz, bx2, by2, bz2 = onb_f32(sx, sy, sz)
    lx = ox * tx + oy * ty + oz * tz
    ly = ox * bx2 + oy * by2 + oz * bz2
    lz = ox * sx + oy * sy + oz * sz
    d0, d1, d2 = _diffuse_normal_point(ux, uy, uz, sx, sy, sz, tx, ty, tz, bx2, by2, bz2)
    return True, sx, sy, sz, tx, ty, tz, bx2, by2, bz2, lx, ly, lz, vx, vy, vz, d0, d1, d2


@_jit
def _diffuse_normal(dn, k, ux, uy, uz, sx, sy, sz, tx, ty, tz, bx, by, bz):
    """Row k of dn: the untilted normal u in the frame (t, b, s) of the tilted one, (0, 0, 1) exactly where
    the tilt left the normal as it was (so that the diffuse lobes compute what they did without one)."""
    dn[k, 0], dn[k, 1], dn[k, 2] = _diffuse_normal_point(ux, uy, uz, sx, sy, sz, tx, ty, tz, bx, by, bz)


@_jit
def _diffuse_normal_point(ux, uy, uz, sx, sy, sz, tx, ty, tz, bx, by, bz):
    """`_diffuse_normal`'s row as three values."""
    if ux == sx and uy == sy and uz == sz:
        return _F0, _F0, _F1
    x = ux * tx + uy * ty + uz * tz
    y = ux * bx + uy * by + uz * bz
    z = ux * sx + uy * sy + uz * sz
    length = max(np.float32(math.sqrt(x * x + y * y + z * z)), _TINY)
    return x / length, y / length, z / length


@_jit
def _bump_term(nx, ny, nz, sx, sy, sz, wx, wy, wz):
    """(diffuse softening factor, rejected) of Cycles' bump shadowing for a closure normal n, the smooth normal
    s and a direction w: rejected where w lies on opposite sides of s and n (cos(s, w) cos(s, n) cos(n, w) < 0);
    the factor is the GGX shadowing G1 at w of a roughness alpha^2 = tan^2(s, n) / 8 (Chiang et al.'s terminator
    softening), 1 where s and n agree, 0 at grazing w."""
    cos_si = np.float64(sx * wx + sy * wy + sz * wz)
    cos_sn = np.float64(sx * nx + sy * ny + sz * nz)
    cos_ni = np.float64(nx * wx + ny * wy + nz * wz)
    reject = cos_si * cos_sn * cos_ni < 0.0
    cos_i = abs(cos_si)
    cos_d = min(abs(cos_sn), 1.0)
    if cos_d >= 1.0 or cos_i >= 1.0:
        return 1.0, reject
    if cos_i < 1e-6:
        return 0.0, reject
    tan2_d = 1.0 / max(cos_d * cos_d, 1e-30) - 1.0
    alpha2 = min(max(0.125 * tan2_d, 0.0), 1.0)
    tan2_i = 1.0 / max(cos_i * cos_i, 1e-30) - 1.0
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha2 * tan2_i)), reject


@_jit
def bump_shadowing_terms(rows, smooth, w, local, tangent, bitangent, ns, n_view, dn, cos_o_geo, g1, reject,
                         reject_d):
    """Cycles' bump shadowing of directions w (M, 3) leaving the points rows (M,) (rows of the surface arrays)
    whose node program set the normal, with smooth (M, 3) their smooth normals on the viewer's side; w in world
    space, or in each point's shading frame when `local`. Writes reject (M,) for the frame's (possibly tilted)
    normal n_view (the microfacet lobes'), and g1 (M,) float64 and reject_d (M,) for the diffuse lobes' normal
    (dn in the frame, on the viewer's side: see `surface`). One pass instead of ~40 NumPy passes over the rows."""
    for j in range(rows.shape[0]):
        k = rows[j]
        tx, ty, tz = tangent[k, 0], tangent[k, 1], tangent[k, 2]
        bx, by, bz = bitangent[k, 0], bitangent[k, 1], bitangent[k, 2]
        zx, zy, zz = ns[k, 0], ns[k, 1], ns[k, 2]
        wx, wy, wz = w[j, 0], w[j, 1], w[j, 2]
        if local:
            wx, wy, wz = tx * wx + bx * wy + zx * wz, ty * wx + by * wy + zy * wz, tz * wx + bz * wy + zz * wz
        g1[j], reject[j], reject_d[j] = bump_terms_point(
            tx, ty, tz, bx, by, bz, zx, zy, zz, n_view[k, 0], n_view[k, 1], n_view[k, 2], dn[k, 0], dn[k, 1],
            dn[k, 2], cos_o_geo[k], smooth[j, 0], smooth[j, 1], smooth[j, 2], wx, wy, wz)


@_jit
def bump_terms_point(tx, ty, tz, bx, by, bz, zx, zy, zz, vx, vy, vz, d0, d1, d2, cos_o_geo, sx, sy, sz, wx, wy, wz):
    """`bump_shadowing_terms` at one point (the fused path kernel calls it per vertex: the same bits): the frame
    (t, b, z = ns), its normal n_view v, the diffuse normal dn d in it, cos_o_geo, the smooth normal s and the
    world direction w. Returns (g1, reject, reject_d)."""
    _, reject = _bump_term(vx, vy, vz, sx, sy, sz, wx, wy, wz)
    ux = tx * d0 + bx * d1 + zx * d2
    uy = ty * d0 + by * d1 + zy * d2
    uz = tz * d0 + bz * d1 + zz * d2
    if cos_o_geo < _F0:
        ux, uy, uz = -ux, -uy, -uz
    g1, reject_d = _bump_term(ux, uy, uz, sx, sy, sz, wx, wy, wz)
    return g1, reject, reject_d


@_jit
def diffuse_lobe_weights(rows, kind, weight, diffuse, out):
    """out[r] (zeros on entry) = weight[r] of the lobes of kind `diffuse`, for each row r in rows: the
    diffuse-only lobe weights the bump shadowing evaluates (integrator.PathTracer._diffuse_only)."""
    for j in range(rows.shape[0]):
        r = rows[j]
        for s in range(kind.shape[1]):
            if kind[r, s] == diffuse:
                out[r, s, 0], out[r, s, 1], out[r, s, 2] = weight[r, s, 0], weight[r, s, 1], weight[r, s, 2]


@_jit
def to_local(w, tangent, bitangent, normal, out):
    """World directions w (N, 3) in each row's frame: out = (w . t, w . b, w . n)."""
    for k in range(w.shape[0]):
        wx, wy, wz = w[k, 0], w[k, 1], w[k, 2]
        out[k, 0] = wx * tangent[k, 0] + wy * tangent[k, 1] + wz * tangent[k, 2]
        out[k, 1] = wx * bitangent[k, 0] + wy * bitangent[k, 1] + wz * bitangent[k, 2]
        out[k, 2] = wx * normal[k, 0] + wy * normal[k, 1] + wz * normal[k, 2]


@_jit
def shading_inputs(p, shift, ng, ns_raw, cos_o_geo, d, p_world, ng_out, n_out, i_out):
    """What node programs read of a batch of surface points (integrator.shade_points), in one pass: the world
    position p + shift (float32), Cycles' sd->Ng and sd->N (the face and the interpolated normal, negated where
    cos_o_geo < 0: a back face) and I = -d. The same bits as the NumPy expressions it replaces."""
    sx, sy, sz = shift[0], shift[1], shift[2]
    for k in range(p.shape[0]):
        p_world[k, 0], p_world[k, 1], p_world[k, 2] = p[k, 0] + sx, p[k, 1] + sy, p[k, 2] + sz
        if cos_o_geo[k] < 0:
            ng_out[k, 0], ng_out[k, 1], ng_out[k, 2] = -ng[k, 0], -ng[k, 1], -ng[k, 2]
            n_out[k, 0], n_out[k, 1], n_out[k, 2] = -ns_raw[k, 0], -ns_raw[k, 1], -ns_raw[k, 2]
        else:
            ng_out[k, 0], ng_out[k, 1], ng_out[k, 2] = ng[k, 0], ng[k, 1], ng[k, 2]
            n_out[k, 0], n_out[k, 1], n_out[k, 2] = ns_raw[k, 0], ns_raw[k, 1], ns_raw[k, 2]
        i_out[k, 0], i_out[k, 1], i_out[k, 2] = -d[k, 0], -d[k, 1], -d[k, 2]


# ------------------------------------------------------------------------------------------- scene set-up
@_jit
def triangle_frames(vertices, triangles, tri_vertices, face_normals, magnitude):
    """Per triangle of float32 vertices (V, 3): its corners (T, 3, 3), unit face normal from the winding (cross
    product in float64; a triangle degenerate in float32 gets (0, 0, 0)) and largest |coordinate| (the scale of
    its ray offsets)."""
    for t in range(triangles.shape[0]):
        m = np.float32(0.0)
        for k in range(3):
            for c in range(3):
                x = vertices[triangles[t, k], c]
                tri_vertices[t, k, c] = x
                m = max(m, abs(x))
        magnitude[t] = m
        # edges in float32 (the precision the renderer's triangles have), their cross product in float64
        ux = np.float64(tri_vertices[t, 1, 0] - tri_vertices[t, 0, 0])
        uy = np.float64(tri_vertices[t, 1, 1] - tri_vertices[t, 0, 1])
        uz = np.float64(tri_vertices[t, 1, 2] - tri_vertices[t, 0, 2])
        vx = np.float64(tri_vertices[t, 2, 0] - tri_vertices[t, 0, 0])
        vy = np.float64(tri_vertices[t, 2, 1] - tri_vertices[t, 0, 1])
        vz = np.float64(tri_vertices[t, 2, 2] - tri_vertices[t, 0, 2])
        cx, cy, cz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        length = max(math.sqrt(cx * cx + cy * cy + cz * cz), 1e-300)
        face_normals[t, 0], face_normals[t, 1], face_normals[t, 2] = cx / length, cy / length, cz / length


# ------------------------------------------------------------------------------------------- shadow terminator
@_jit
def _dot_vn(tri_vertices, corner_normals, t, a, b, i):
    """(V_a - V_b) . N_i of triangle t."""
    s = np.float32(0.0)
    for c in range(3):
        s += (tri_vertices[t, a, c] - tri_vertices[t, b, c]) * corner_normals[t, i, c]
    return s


@_jit
def _dot_nv(tri_vertices, corner_normals, t, i, j, a, b):
    """(N_i - N_j) . (V_a - V_b) of triangle t."""
    s = np.float32(0.0)
    for c in range(3):
        s += (corner_normals[t, i, c] - corner_normals[t, j, c]) * (tri_vertices[t, a, c] - tri_vertices[t, b, c])
    return s


@_jit
def smooth_surface_lift(t, w0, w1, w2, gx, gy, gz, tri_vertices, corner_normals):
    """Cycles' shadow_ray_smooth_surface_offset: the vector that lifts the point with barycentric weights
    (w0, w1, w2) of triangle t towards the smooth surface its corner normals describe, on the side of the unit
    geometric normal g (the side the shadow ray leaves from).

    The lift is h along the interpolated (unnormalised) normal n: h from the parabola through the corners with
    the corner normals' slopes, kept at least half of it and bounded by the tangent planes at the corners (the
    local linear envelope); with n on g's side h >= 0, else h <= 0, so the point always moves to g's side."""
    v, n = tri_vertices, corner_normals
    px = v[t, 0, 0] * w0 + v[t, 1, 0] * w1 + v[t, 2, 0] * w2
    py = v[t, 0, 1] * w0 + v[t, 1, 1] * w1 + v[t, 2, 1] * w2
    pz = v[t, 0, 2] * w0 + v[t, 1, 2] * w1 + v[t, 2, 2] * w2
    nx = n[t, 0, 0] * w0 + n[t, 1, 0] * w1 + n[t, 2, 0] * w2  # unnormalised, as Cycles
    ny = n[t, 0, 1] * w0 + n[t, 1, 1] * w1 + n[t, 2, 1] * w2
    nz = n[t, 0, 2] * w0 + n[t, 1, 2] * w1 + n[t, 2, 2] * w2

    # parabolic approximation over the triangle (weights of corners 0 and 1 as the free parameters)
    a = _dot_nv(tri_vertices, corner_normals, t, 2, 0, 0, 2)
    b = _dot_nv(tri_vertices, corner_normals, t, 2, 1, 1, 2)
    c = _dot_nv(tri_vertices, corner_normals, t, 1, 0, 1, 0)
    h = a * w0 * (w0 - 1) + (a + b + c) * w0 * w1 + b * w1 * (w1 - 1)
    front = nx * gx + ny * gy + nz * gz > 0
    env = np.float32(3.4e38)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        pv = (tri_vertices[t, i, 0] - px) * corner_normals[t, i, 0] + (tri_vertices[t, i, 1] - py) * \
            corner_normals[t, i, 1] + (tri_vertices[t, i, 2] - pz) * corner_normals[t, i, 2]
        if front:
            hi = max(max(_dot_vn(tri_vertices, corner_normals, t, j, i, i), _dot_vn(tri_vertices, corner_normals, t, k, i, i)), np.float32(0.0))
            hi = max(pv + hi, np.float32(0.0))  # (V_i - P) . N_i + ...
        else:
            hi = max(max(_dot_vn(tri_vertices, corner_normals, t, i, j, i), _dot_vn(tri_vertices, corner_normals, t, i, k, i)), np.float32(0.0))
            hi = max(-pv + hi, np.float32(0.0))  # (P - V_i) . N_i + ...
        env = min(env, hi)
    if front:
        h = max(env, h * np.float32(0.5))
    else:
        h = min(-env, h * np.float32(0.5))
    return nx * h, ny * h, nz * h


@_jit_inline
def differentials_point(tri_vertices, tri_uvs, prim, ngx, ngy, ngz, dp, k, dP, db, duv):
    """Row k of core.shading.vector_context.VectorContext's dP (N, 2, 3), db (N, 2, 2) and, where tri_uvs is not
    empty, duv (N, 2, 2) (float32) of a hit on triangle prim with viewer-side true normal ng and footprint dp
    (Cycles' compact sd->dP): dP.dx, dP.dy = dp along the two unit tangents of Cycles' make_orthonormals (a along
    (1, 1, 1) x n, or (-1, 1, 1) x n when n lies along (1, 1, 1); b = n x a), the barycentric derivatives
    (b1, b2) that move the point by them within the triangle (the normal equations of the edges e1, e2) and the
    active UV map's change along them. Float64 inside, in one written order (each dot product (x + y) + z), so
    the per-bounce batch (`differentials`) and the fused kernel (core.fused_path) give the same bits."""
    x, y, z = np.float64(ngx), np.float64(ngy), np.float64(ngz)
    ax = z - y
    if x == y and x == z:
        ay, az = x + z, -y - x
    else:
        ay, az = x - z, y - x
    alen = max(math.sqrt(ax * ax + ay * ay + az * az), 1e-300)
    ax, ay, az = ax / alen, ay / alen, az / alen
    bx = y * az - z * ay
    by = z * ax - x * az
    bz = x * ay - y * ax
    size = np.float64(dp)
    d0x, d0y, d0z = ax * size, ay * size, az * size
    d1x, d1y, d1z = bx * size, by * size, bz * size
    vx, vy, vz = (np.float64(tri_vertices[prim, 0, 0]), np.float64(tri_vertices[prim, 0, 1]),
                  np.float64(tri_vertices[prim, 0, 2]))
    e1x = np.float64(tri_vertices[prim, 1, 0]) - vx
    e1y = np.float64(tri_vertices[prim, 1, 1]) - vy
    e1z = np.float64(tri_vertices[prim, 1, 2]) - vz
    e2x = np.float64(tri_vertices[prim, 2, 0]) - vx
    e2y = np.float64(tri_vertices[prim, 2, 1]) - vy
    e2z = np.float64(tri_vertices[prim, 2, 2]) - vz
    a11 = e1x * e1x + e1y * e1y + e1z * e1z
    a12 = e1x * e2x + e1y * e2y + e1z * e2z
    a22 = e2x * e2x + e2y * e2y + e2z * e2z
    det = a11 * a22 - a12 * a12
    inv = 1.0 / det if det != 0.0 else 0.0
    r10 = e1x * d0x + e1y * d0y + e1z * d0z
    r20 = e2x * d0x + e2y * d0y + e2z * d0z
    r11 = e1x * d1x + e1y * d1y + e1z * d1z
    r21 = e2x * d1x + e2y * d1y + e2z * d1z
    b00 = (a22 * r10 - a12 * r20) * inv
    b01 = (a11 * r20 - a12 * r10) * inv
    b10 = (a22 * r11 - a12 * r21) * inv
    b11 = (a11 * r21 - a12 * r11) * inv
    dP[k, 0, 0], dP[k, 0, 1], dP[k, 0, 2] = np.float32(d0x), np.float32(d0y), np.float32(d0z)
    dP[k, 1, 0], dP[k, 1, 1], dP[k, 1, 2] = np.float32(d1x), np.float32(d1y), np.float32(d1z)
    db[k, 0, 0], db[k, 0, 1] = np.float32(b00), np.float32(b01)
    db[k, 1, 0], db[k, 1, 1] = np.float32(b10), np.float32(b11)
    if tri_uvs.shape[0] > 0:
        for c in range(2):
            u0 = np.float64(tri_uvs[prim, 0, c])
            u1 = np.float64(tri_uvs[prim, 1, c]) - u0
            u2 = np.float64(tri_uvs[prim, 2, c]) - u0
            duv[k, 0, c] = np.float32(u1 * b00 + u2 * b01)
            duv[k, 1, c] = np.float32(u1 * b10 + u2 * b11)


@_jit
def differentials(prim, ng, dp, tri_vertices, tri_uvs, dP, db, duv):
    """`differentials_point` for every row k of hits on triangles prim (N,) with viewer-side true normals ng
    (N, 3) float32 and footprints dp (N,) float32, into dP (N, 2, 3), db (N, 2, 2) and duv (N, 2, 2) (float32;
    duv untouched where tri_uvs is empty)."""
    for k in range(prim.shape[0]):
        differentials_point(tri_vertices, tri_uvs, prim[k], ng[k, 0], ng[k, 1], ng[k, 2], dp[k], k, dP, db, duv)
