"""Compiled (numba) kernels for the integrator's per-path geometry: one pass over the paths instead of dozens
of NumPy array operations, each of which would stream every array through memory again.

Profiling the NumPy wavefront (`monte perf`, line profiles) showed ~40% of render time in this glue: surface
points and shading frames from barycentrics, ray origins offset off surfaces, shadow-ray set-up and MIS weights.
The sampler (core.sampling), BSDFs (core.bsdf_kernels) and lights (core.light_kernels) are compiled too.

Conventions as in core.integrator: float32 (N, 3) row vectors in the camera-shifted frame; face normals follow
the winding; the shading frame's +z is the shading normal flipped to the face normal's side ("outside").
Kernels release the GIL (render worker threads run them in parallel) and are compiled once, cached on disk.
"""

from __future__ import annotations

import math

import numpy as np

from .jit_cache import jit as _jit


_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_OFFSET_SCALE = np.float32(2.0**-19)  # of the coordinates' magnitude: see _offset
_TINY = np.float32(1e-30)
_FAR = np.float32(3e38)


@_jit
def _offset(px, py, pz, nx, ny, nz, wx, wy, wz, magnitude):
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
            material_index, specular, p, ng, ns_raw, ns, tangent, bitangent, wo, n_view, mag, cos_o_geo, uv):
    """Surface interaction of the hits `rows` (indices into prim/bu/bv/d); writes row k of each output.

    p: point from barycentrics (the triangle's own precision). ng: face normal. ns_raw: interpolated shading
    normal as the mesh gives it (the normal AOV). ns: the same flipped to ng's side; tangent, bitangent: Duff et
    al.'s branchless basis around ns. wo: direction to the viewer (-d) in that frame. n_view: ns on the viewer's
    side. mag: largest |coordinate| of p and its triangle (ray offset scale). cos_o_geo: -d . ng.
    corner_normals/smooth and tri_uvs may be empty arrays (flat shading, no UVs). specular (M,): materials
    with a glossy, glass or refraction lobe, whose smooth shading normals are kept valid for reflection.
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
            sx = corner_normals[t, 0, 0] * b0 + corner_normals[t, 1, 0] * b1 + corner_normals[t, 2, 0] * b2
            sy = corner_normals[t, 0, 1] * b0 + corner_normals[t, 1, 1] * b1 + corner_normals[t, 2, 1] * b2
            sz = corner_normals[t, 0, 2] * b0 + corner_normals[t, 1, 2] * b1 + corner_normals[t, 2, 2] * b2
            length = max(np.float32(math.sqrt(sx * sx + sy * sy + sz * sz)), _TINY)
            sx, sy, sz = sx / length, sy / length, sz / length
        ns_raw[k, 0], ns_raw[k, 1], ns_raw[k, 2] = sx, sy, sz
        if has_uvs:
            for c in range(2):
                uv[k, c] = tri_uvs[t, 0, c] * b0 + tri_uvs[t, 1, c] * b1 + tri_uvs[t, 2, c] * b2
        ox, oy, oz = -d[i, 0], -d[i, 1], -d[i, 2]
        cos_o_geo[k] = ox * gx + oy * gy + oz * gz
        if sx * gx + sy * gy + sz * gz < _F0:
            sx, sy, sz = -sx, -sy, -sz
        if has_normals and smooth[t] and specular[material_index[t]]:
            side = _F1 if cos_o_geo[k] >= _F0 else -_F1  # work on the viewer's side of the surface
            bx, by, bz = _valid_reflection_normal(gx * side, gy * side, gz * side, ox, oy, oz,
                                                  sx * side, sy * side, sz * side)
            sx, sy, sz = np.float32(bx * side), np.float32(by * side), np.float32(bz * side)
        ns[k, 0], ns[k, 1], ns[k, 2] = sx, sy, sz
        sign = _F1 if sz >= _F0 else -_F1
        a = -_F1 / (sign + sz)
        b = sx * sy * a
        tx, ty, tz = _F1 + sign * sx * sx * a, sign * b, -sign * sx
        bx, by, bz = b, sign + sy * sy * a, -sy
        tangent[k, 0], tangent[k, 1], tangent[k, 2] = tx, ty, tz
        bitangent[k, 0], bitangent[k, 1], bitangent[k, 2] = bx, by, bz
        wz = ox * sx + oy * sy + oz * sz
        wo[k, 0] = ox * tx + oy * ty + oz * tz
        wo[k, 1] = ox * bx + oy * by + oz * bz
        wo[k, 2] = wz
        flip = -_F1 if wz < _F0 else _F1
        n_view[k, 0], n_view[k, 1], n_view[k, 2] = sx * flip, sy * flip, sz * flip


@_jit
def to_local(w, tangent, bitangent, normal, out):
    """World directions w (N, 3) in each row's frame: out = (w . t, w . b, w . n)."""
    for k in range(w.shape[0]):
        wx, wy, wz = w[k, 0], w[k, 1], w[k, 2]
        out[k, 0] = wx * tangent[k, 0] + wy * tangent[k, 1] + wz * tangent[k, 2]
        out[k, 1] = wx * bitangent[k, 0] + wy * bitangent[k, 1] + wz * bitangent[k, 2]
        out[k, 2] = wx * normal[k, 0] + wy * normal[k, 1] + wz * normal[k, 2]


@_jit
def scatter(wi_local, tangent, bitangent, ns, ng, cos_o_geo, valid, transmitted, weight, throughput, p, mag,
            pdf, delta, n_view, transmits, idx, pix, smp,
            out_origin, out_direction, out_throughput, out_pdf, out_delta, out_normal, out_transmits, out_idx,
            out_pix, out_smp):
    """Turn sampled BSDF directions into the next rays and write the paths that continue, compacted, to out_*.

    Reflection must stay on wo's side of the true surface and transmission must cross it (else the path ends);
    throughput *= weight (a path whose throughput became 0 ends); origin: p offset off the surface to the new
    direction's side; direction: unit wi. The other per-path values (BSDF pdf and delta flag of the sample, the
    shading normal on the viewer's side, whether the material transmits, sample/pixel/sample ids) are copied
    along. Returns the number of paths written (rows [0, count) of every out_* array).
    """
    count = 0
    for k in range(wi_local.shape[0]):
        lx, ly, lz = wi_local[k, 0], wi_local[k, 1], wi_local[k, 2]
        wx = lx * tangent[k, 0] + ly * bitangent[k, 0] + lz * ns[k, 0]
        wy = lx * tangent[k, 1] + ly * bitangent[k, 1] + lz * ns[k, 1]
        wz = lx * tangent[k, 2] + ly * bitangent[k, 2] + lz * ns[k, 2]
        side_o = cos_o_geo[k] > _F0
        side_i = wx * ng[k, 0] + wy * ng[k, 1] + wz * ng[k, 2] > _F0
        if not (valid[k] and ((side_o != side_i) if transmitted[k] else (side_o == side_i))):
            continue
        t0 = throughput[k, 0] * weight[k, 0]
        t1 = throughput[k, 1] * weight[k, 1]
        t2 = throughput[k, 2] * weight[k, 2]
        if not max(t0, t1, t2) > _F0:
            continue
        j = count
        count += 1
        out_throughput[j, 0], out_throughput[j, 1], out_throughput[j, 2] = t0, t1, t2
        ox, oy, oz = _offset(p[k, 0], p[k, 1], p[k, 2], ng[k, 0], ng[k, 1], ng[k, 2], wx, wy, wz, mag[k])
        out_origin[j, 0], out_origin[j, 1], out_origin[j, 2] = ox, oy, oz
        length = max(np.float32(math.sqrt(wx * wx + wy * wy + wz * wz)), _TINY)
        out_direction[j, 0], out_direction[j, 1], out_direction[j, 2] = wx / length, wy / length, wz / length
        out_pdf[j] = pdf[k]
        out_delta[j] = delta[k]
        out_normal[j, 0], out_normal[j, 1], out_normal[j, 2] = n_view[k, 0], n_view[k, 1], n_view[k, 2]
        out_transmits[j] = transmits[k]
        out_idx[j] = idx[k]
        out_pix[j] = pix[k]
        out_smp[j] = smp[k]
    return count


@_jit
def shadow_rays(rows, throughput, idx, f_cos, radiance, pdf_light, pdf_bsdf, delta, use_mis, cos_o_geo, ng,
                transmits, p, mag, wi, dist, shadow_epsilon, contrib, origin, direction, tmax, out_idx):
    """Next-event estimation's contribution (if unoccluded) and shadow ray per light sample.

    contrib = throughput f cos L w / pdf_light, with w the power-heuristic MIS weight (1 for delta lights or
    without MIS); 0 where pdf_light is 0 or where wi crosses the surface of a material that does not transmit.
    The shadow ray leaves p offset to wi's side and is aimed at the sampled light point itself (the offset moves
    the origin; aiming from the new origin keeps a light near a grazing surface from occluding itself); it stops
    shadow_epsilon short of the light. Lights at infinity (dist = inf) get direction wi and tmax 3e38.
    Light sample k belongs to path rows[k] (its throughput and sample id idx). Only samples that would contribute
    get a shadow ray: they are written compacted (contrib, origin, direction, tmax, out_idx rows [0, count));
    returns count.
    """
    count = 0
    for k in range(rows.shape[0]):
        r = rows[k]
        pl = pdf_light[k]
        scale = _F0
        if pl > _F0:
            w = _F1
            if use_mis and not delta[k]:
                pb = pdf_bsdf[k]
                w = pl * pl / max(pl * pl + pb * pb, _TINY)
            scale = w / max(pl, _TINY)
        wx, wy, wz = wi[k, 0], wi[k, 1], wi[k, 2]
        crosses = (cos_o_geo[k] > _F0) != (wx * ng[k, 0] + wy * ng[k, 1] + wz * ng[k, 2] > _F0)
        if crosses and not transmits[k]:
            scale = _F0
        peak = _F0
        for c in range(3):
            v = throughput[r, c] * f_cos[k, c] * radiance[k, c] * scale
            contrib[count, c] = v
            peak = max(peak, v)
        if not peak > _F0:
            continue
        j = count
        count += 1
        out_idx[j] = idx[r]
        px, py, pz = p[k, 0], p[k, 1], p[k, 2]
        ox, oy, oz = _offset(px, py, pz, ng[k, 0], ng[k, 1], ng[k, 2], wx, wy, wz, mag[k])
        origin[j, 0], origin[j, 1], origin[j, 2] = ox, oy, oz
        dk = dist[k]
        if math.isfinite(dk):
            tx, ty, tz = px + wx * dk - ox, py + wy * dk - oy, pz + wz * dk - oz
            length = np.float32(math.sqrt(tx * tx + ty * ty + tz * tz))
            inv = _F1 / max(length, _TINY)
            direction[j, 0], direction[j, 1], direction[j, 2] = tx * inv, ty * inv, tz * inv
            tmax[j] = length * (_F1 - shadow_epsilon)
        else:
            direction[j, 0], direction[j, 1], direction[j, 2] = wx, wy, wz
            tmax[j] = _FAR
    return count


@_jit
def accumulate(radiance, rows, value, clamp, counters):
    """radiance[rows[k]] += value[k], dropping NaN/Inf rows (counters[0]) and scaling rows whose largest
    component exceeds clamp > 0 down to it (counters[1])."""
    for k in range(rows.shape[0]):
        v0, v1, v2 = value[k, 0], value[k, 1], value[k, 2]
        if not (math.isfinite(v0) and math.isfinite(v1) and math.isfinite(v2)):
            counters[0] += 1
            continue
        if clamp > 0:
            peak = max(v0, v1, v2)
            if peak > clamp:
                counters[1] += 1
                s = clamp / peak
                v0, v1, v2 = v0 * s, v1 * s, v2 * s
        r = rows[k]
        radiance[r, 0] += v0
        radiance[r, 1] += v1
        radiance[r, 2] += v2


# ------------------------------------------------------------------------------------------- scene set-up
@_jit
def triangle_checks(vertices, triangles, finite, area2, edge):
    """Per triangle of float64 vertices (V, 3) and int64 indices (T, 3): finite[t] (all 9 coordinates finite),
    area2[t] = |(b - a) x (c - a)| (twice the area) and edge[t] = the largest |coordinate difference| of b and c
    from a. One pass instead of a (T, 3, 3) gather and a dozen NumPy reductions (scene validation of large
    instanced meshes)."""
    for t in range(triangles.shape[0]):
        i0, i1, i2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        ok = True
        e = 0.0
        for c in range(3):
            a, b, d = vertices[i0, c], vertices[i1, c], vertices[i2, c]
            if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(d)):
                ok = False
            e = max(e, abs(b - a), abs(d - a))
        finite[t] = ok
        edge[t] = e
        ux, uy, uz = vertices[i1, 0] - vertices[i0, 0], vertices[i1, 1] - vertices[i0, 1], vertices[i1, 2] - vertices[i0, 2]
        vx, vy, vz = vertices[i2, 0] - vertices[i0, 0], vertices[i2, 1] - vertices[i0, 1], vertices[i2, 2] - vertices[i0, 2]
        cx, cy, cz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        area2[t] = math.sqrt(cx * cx + cy * cy + cz * cz)


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


@_jit
def camera_rays(raster_x, raster_y, width, height, frame, right, up, back, ortho, clip_start, clip_end,
                origins, directions, tmax, depth_scale, t_start):
    """Camera rays through raster positions (see core.camera.camera_rays), in float64, written as float32.

    frame: (xmin, xmax, ymin, ymax) of the image on the plane at distance 1 (perspective) or in world units
    (orthographic); right, up, back: the camera's unit axes; rays start at clip_start and end at clip_end."""
    xmin, xmax, ymin, ymax = frame[0], frame[1], frame[2], frame[3]
    for k in range(raster_x.shape[0]):
        x = xmin + (raster_x[k] / width) * (xmax - xmin)
        y = ymax - (raster_y[k] / height) * (ymax - ymin)
        if ortho:
            dx, dy, dz = -back[0], -back[1], -back[2]
            ox = x * right[0] + y * up[0] + clip_start * dx
            oy = x * right[1] + y * up[1] + clip_start * dy
            oz = x * right[2] + y * up[2] + clip_start * dz
            tm, scale, t0 = clip_end - clip_start, 1.0, clip_start
        else:
            lx = x * right[0] + y * up[0] - back[0]
            ly = x * right[1] + y * up[1] - back[1]
            lz = x * right[2] + y * up[2] - back[2]
            length = math.sqrt(lx * lx + ly * ly + lz * lz)
            dx, dy, dz = lx / length, ly / length, lz / length
            scale = 1.0 / length  # cos of the angle between the ray and the view axis
            t0 = clip_start / scale
            ox, oy, oz = dx * t0, dy * t0, dz * t0
            tm = clip_end / scale - t0
        origins[k, 0], origins[k, 1], origins[k, 2] = ox, oy, oz
        directions[k, 0], directions[k, 1], directions[k, 2] = dx, dy, dz
        tmax[k] = min(tm, 3e38)
        depth_scale[k] = scale
        t_start[k] = t0
