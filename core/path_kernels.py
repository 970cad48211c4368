"""Compiled (numba) kernels of a path's step at a surface: the scattered ray after a BSDF sample, the shadow rays
of next-event estimation with their MIS weights, and the accumulation of contributions into pixels.

Conventions as in core.integrator and core.geometry_kernels: float32 (N, 3) row vectors in the camera-shifted
frame, the shading frame's +z along the shading normal on the face normal's side. Ray origins leave surfaces by
core.geometry_kernels.offset_point.
"""

from __future__ import annotations

import math

import numpy as np

from .geometry_kernels import offset_point, smooth_surface_lift
from .jit_cache import jit as _jit

_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_TINY = np.float32(1e-30)
_FAR = np.float32(3e38)


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
        ox, oy, oz = offset_point(p[k, 0], p[k, 1], p[k, 2], ng[k, 0], ng[k, 1], ng[k, 2], wx, wy, wz, mag[k])
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
                transmits, p, mag, wi, dist, shadow_epsilon, contrib, origin, direction, tmax, out_idx,
                prim, bu, bv, n_view, tri_vertices, corner_normals, terminator_offset):
    """Next-event estimation's contribution (if unoccluded) and shadow ray per light sample.

    contrib = throughput f cos L w / pdf_light, with w the power-heuristic MIS weight (1 for delta lights or
    without MIS); 0 where pdf_light is 0 or where wi crosses the surface of a material that does not transmit.
    The shadow ray leaves p offset to wi's side and is aimed at the sampled light point itself (the offset moves
    the origin; aiming from the new origin keeps a light near a grazing surface from occluding itself); it stops
    shadow_epsilon short of the light. Lights at infinity (dist = inf) get direction wi and tmax 3e38.
    Light sample k belongs to path rows[k] (its throughput and sample id idx). Only samples that would contribute
    get a shadow ray: they are written compacted (contrib, origin, direction, tmax, out_idx rows [0, count));
    returns count.

    Shadow terminator (Cycles' shadow_ray_offset), where terminator_offset (T,) is not empty: on a triangle
    prim[k] whose offset o > 0 (smooth-shaded), with N = n_view (the shading normal on the viewer's side), the
    geometric normal G on N's side of wi, NL = |N . wi| and GL = G . wi, the origin is lifted towards the smooth
    surface (core.geometry_kernels.smooth_surface_lift at barycentrics bu, bv) by the amount
    clamp(2 - (GL + NL) / o, 0, 1) if NL < o else clamp(1 - GL / o, 0, 1). A lifted ray going below the face
    (GL <= 0) may hit the face itself, as in Cycles, instead of being dropped as crossing the surface.
    """
    use_terminator = terminator_offset.shape[0] > 0
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
        lift = _F0
        t = 0
        g_side = _F1
        if use_terminator:
            t = prim[k]
            cutoff = terminator_offset[t]
            if cutoff > _F0:
                nl = wx * n_view[k, 0] + wy * n_view[k, 1] + wz * n_view[k, 2]
                g_side = _F1 if cos_o_geo[k] >= _F0 else -_F1  # G on the viewer's side ...
                if nl < _F0:
                    nl, g_side = -nl, -g_side  # ... or the other one for light through the surface
                gl = g_side * (wx * ng[k, 0] + wy * ng[k, 1] + wz * ng[k, 2])
                if nl < cutoff:
                    lift = min(max(np.float32(2.0) - (gl + nl) / cutoff, _F0), _F1)
                else:
                    lift = min(max(_F1 - gl / cutoff, _F0), _F1)
        if crosses and not transmits[k] and not lift > _F0:
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
        if lift > _F0:
            b1, b2 = bu[k], bv[k]
            lx, ly, lz = smooth_surface_lift(t, _F1 - b1 - b2, b1, b2, ng[k, 0] * g_side, ng[k, 1] * g_side,
                                             ng[k, 2] * g_side, tri_vertices, corner_normals)
            ox, oy, oz = px + lx * lift, py + ly * lift, pz + lz * lift
            if g_side * (wx * ng[k, 0] + wy * ng[k, 1] + wz * ng[k, 2]) > _F0:  # leaves the face: skip it
                ox, oy, oz = offset_point(ox, oy, oz, ng[k, 0], ng[k, 1], ng[k, 2], wx, wy, wz, mag[k])
        else:
            ox, oy, oz = offset_point(px, py, pz, ng[k, 0], ng[k, 1], ng[k, 2], wx, wy, wz, mag[k])
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
        r = rows[k]
        radiance[r, 0], radiance[r, 1], radiance[r, 2] = add_contribution(
            radiance[r, 0], radiance[r, 1], radiance[r, 2], value[k, 0], value[k, 1], value[k, 2], clamp, counters)


@_jit
def add_contribution(r0, r1, r2, v0, v1, v2, clamp, counters):
    """(r0 + v0, r1 + v1, r2 + v2) for one contribution v: a NaN/Inf one dropped (r returned as it is,
    counters[0] += 1), one whose largest component exceeds clamp > 0 scaled down to it (counters[1] += 1).
    accumulate's per-row step and the fused path kernel's (core.fused_path) per-path sum."""
    if not (math.isfinite(v0) and math.isfinite(v1) and math.isfinite(v2)):
        counters[0] += 1
        return r0, r1, r2
    if clamp > 0:
        peak = max(v0, v1, v2)
        if peak > clamp:
            counters[1] += 1
            s = clamp / peak
            v0, v1, v2 = v0 * s, v1 * s, v2 * s
    return r0 + v0, r1 + v1, r2 + v2
