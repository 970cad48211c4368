"""The fused path kernel: one compiled call traces a batch of camera paths to their end.

The per-bounce integrator (core.integrator.PathTracer.trace) runs ~15 compiled kernels per bounce with NumPy
glue and intermediate arrays between them. For the scenes this module supports (`supports` says which: constant
materials, or node programs that set lobe parameters and the normal (Normal Map, Bump), mesh emitters and analytic
lights, the Sobol sampler, MIS, none of the film's extra outputs; core.fused_tracer decides and calls it) one kernel,
`trace_paths`, does the whole path per camera ray: Embree's closest hit and shadow ray, the emission seen
(MIS-weighted), Russian roulette, the vertex's node program (core.shading.evaluator.run_point), next-event
estimation and the BSDF sample, calling the same device functions (core.bsdf_kernels.eval_path / sample_path,
core.light_kernels.sample_light_path / light_emission_path / triangle_pdf_path) with the same random numbers (the
sampler's dimension sets, evaluated per path by `_sobol`), so the image equals the per-bounce one up to rounding.

Conventions as in core.integrator: float32 rays in the camera-shifted frame; each path's radiance is summed in
float32 in the order the per-bounce integrator adds it (emission of a vertex, then its light sample).
"""

from __future__ import annotations

import math

import numpy as np

from .bsdf_kernels import albedo_batch, eval_path, sample_path, view_select_row
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .camera import pinhole_footprint, pinhole_ray
from .embree import _INVALID_ID, _call_embree, set_ray
from .geometry_kernels import (_valid_reflection_normal, bump_terms_point, differentials_point, offset_point,
                               reframe_point, smooth_normal, smooth_surface_lift)
from .jit_cache import jit_inline as _jit_inline
from .jit_cache import jit_no_nrt as _jit
from .light_kernels import light_emission_path, probabilities_at, sample_light_path, triangle_pdf_path
from .path_kernels import add_contribution as _add
from .sampling import _U, _U0, _U255, _S8, _S16, _S24, _mix32, _owen_rev, _reverse32, _unit_float
from .shading.evaluator import run_point
from .warps import onb_f32


_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_TINY = np.float32(1e-30)
_FAR = np.float32(3e38)
_D_VERTEX, _D_LIGHT = 1, 4  # as core.integrator: a vertex's BSDF/roulette set and its light-sample set
_DIFFUSE = 0  # core.bsdf.KIND_CODE["diffuse"]: the lobes the bump shadowing softens

# Measurement mode (lab/fused_timing.py): with TIMED true at compile time, trace_paths adds the CPU cycles
# (the time-stamp counter) each part of a path takes to counters[TIMING_FIRST:]. The module's kernels are
# compiled and cached with it false: the `if TIMED:` blocks fold away and the shipped kernel pays nothing.
TIMED = False
TIMING_FIRST = 4
TIMING_PARTS = ("closest hit (Embree)", "shadow ray (Embree)", "lights along the ray", "emitter hit MIS",
                "light sample", "BSDF eval", "BSDF sample", "random numbers", "surface", "node program",
                "bump shadowing of the BSDF sample", "whole path loop")
COUNTERS = TIMING_FIRST + len(TIMING_PARTS)  # the length of trace_paths' counters array

# trace_paths' `programs` argument (node programs, core.fused_tracer.FusedTracer.trace builds it): the packed
# programs of core.shading.PreparedShading, what the vertex needs to build their context, and 1-row scratches
PROGRAM_FIELDS = ("needs_program", "prog_of_mat", "code", "code_start", "regs0", "reg_start", "data", "data_start",
                  "bind", "emit_reg", "normal_reg", "tex_pixels", "tex_offset", "tex_h", "tex_w", "objects",
                  "object_of_triangle", "tri_uvs", "shift", "P", "N", "Ng", "I", "uv", "back", "obj", "uvx", "extra",
                  "dP", "duv", "tan", "scratch", "select_scale", "emission", "normal_out", "has_normal", "aov_out",
                  "lobes", "albedo", "tangent_layers", "needs_tangents", "nraw", "diffuse_weight",
                  "needs_differentials", "db", "ray_dp", "ray_dd", "hit_distances")


@intrinsic
def _cycles(typingctx):
    """The CPU's cycle counter (LLVM's readcyclecounter: rdtsc on x86), for the measurement mode."""
    def codegen(context, builder, signature, args):
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.IntType(64), []),
                                            "llvm.readcyclecounter")
        return builder.call(fn, [])

    return types.int64(), codegen


@_jit
def _sobol_set(path_key, s, set_key, group_bits):
    """The hash key and scrambled index of sample s in one dimension set (set_key) of the path whose key is
    path_key = _mix32(p ^ seed_key): the part of core.sampling._sobol_fill that the set's dimensions share, so
    that a path computes it once per set (measured: the random numbers were 16% of the kernel's path loop when
    each dimension recomputed it)."""
    gb = _U(group_bits)
    gmask = _U(_U(_U(1) << gb) - _U(1))
    hk = _mix32(_U(path_key ^ set_key))
    grp = _U(s & gmask)
    if grp != _U0:
        hk = _mix32(_U(hk ^ _U(grp * _U(0x9E3779B9))))
    r = _U(_owen_rev(_reverse32(_U(s >> gb)), hk) ^ _owen_rev(_U0, hk))
    return hk, r


@_jit
def _sobol(hk, r, dim_keys, tables, d):
    """Component d of a dimension set whose (hk, r) `_sobol_set` gave (core.sampling._sobol_fill for one path,
    the same float32 value)."""
    t = tables[d]
    lane = _U(t[0, r & _U255] ^ t[1, (r >> _S8) & _U255] ^ t[2, (r >> _S16) & _U255] ^ t[3, r >> _S24])
    return _unit_float(_reverse32(_owen_rev(lane, _mix32(_U(hk ^ dim_keys[d])))))


@_jit
def _sobol3(hk, r, dim_keys, tables):
    """Components 0, 1 and 2 of a dimension set (a light sample's, or a BSDF sample's)."""
    return _sobol(hk, r, dim_keys, tables, 0), _sobol(hk, r, dim_keys, tables, 1), _sobol(hk, r, dim_keys, tables, 2)


@_jit_inline
def _shade_vertex(programs, lobes, mat, prim, b0, bu, bv, px, py, pz, nx, ny, nz, gx, gy, gz, dx, dy, dz,
                  backface, face_normals, corner_normals, smooth, tri_vertices, hit_dp):
    """Run material mat's node program at a surface vertex into the 1-row lobes of `programs` (PROGRAM_FIELDS,
    "lobes"): row mat of the material lobes, then the program (core.shading.evaluator.run_point) with the
    context core.integrator.shade_points builds: the world position, N (the interpolated normal, nx..) and Ng
    (the face normal) negated on a back face, I = -d, the active UV map (core.geometry_kernels.surface's
    interpolation), the object row, and where the material's program reads them (needs_tangents) the tangent
    layers and the unnormalised mesh normal (core.shading.vector_context._tangents: float64, then float32), and
    where it reads ray differentials (needs_differentials: a Bump node) dP, and the active UV map's duv, of the
    hit's footprint hit_dp (core.geometry_kernels.differentials_point, as the per-bounce vector_context).
    UV Map and Light Path values read zeros: the scenes whose programs read them are not fused
    (core.fused_tracer.supports)."""
    (needs, prog_of_mat, code, code_start, regs0, reg_start, data, data_start, bind, emit_reg, normal_reg,
     tex_pixels, tex_offset, tex_h, tex_w, objects, obj_of_tri, tri_uvs, shift, P, N, Ng, I, uv, side, obj, uvx,
     extra, dP, duv, tan, scratch, t_scale, emission, normal_out, has_normal, aov_out, vl, alb, tangent_layers,
     needs_tangents, nraw, _diffuse_weight, needs_differentials, db, _ray_dp, _ray_dd, _hit_t) = programs
    for l in range(lobes[0].shape[1]):
        vl[0][0, l] = lobes[0][mat, l]
        vl[2][0, l] = lobes[2][mat, l]
        vl[3][0, l] = lobes[3][mat, l]
        vl[4][0, l] = lobes[4][mat, l]
        vl[5][0, l] = lobes[5][mat, l]
        vl[7][0, l] = lobes[7][mat, l]
        for c in range(3):
            vl[1][0, l, c] = lobes[1][mat, l, c]
            vl[6][0, l, c] = lobes[6][mat, l, c]
            vl[8][0, l, 0, c] = lobes[8][mat, l, 0, c]
            vl[8][0, l, 1, c] = lobes[8][mat, l, 1, c]
    P[0, 0], P[0, 1], P[0, 2] = px + shift[0], py + shift[1], pz + shift[2]
    if backface:
        N[0, 0], N[0, 1], N[0, 2] = -nx, -ny, -nz
        Ng[0, 0], Ng[0, 1], Ng[0, 2] = -gx, -gy, -gz
    else:
        N[0, 0], N[0, 1], N[0, 2] = nx, ny, nz
        Ng[0, 0], Ng[0, 1], Ng[0, 2] = gx, gy, gz
    I[0, 0], I[0, 1], I[0, 2] = -dx, -dy, -dz
    has_uv = tri_uvs.shape[0] > 0
    if has_uv:
        for c in range(2):
            uv[0, c] = tri_uvs[prim, 0, c] * b0 + tri_uvs[prim, 1, c] * bu + tri_uvs[prim, 2, c] * bv
    side[0] = backface
    obj[0] = obj_of_tri[prim]
    if tangent_layers.shape[0] == 0:  # no tangent layers: the mesh normal is N (core.shading.evaluator.evaluate)
        nraw[0, 0], nraw[0, 1], nraw[0, 2] = N[0, 0], N[0, 1], N[0, 2]
    elif needs_tangents[mat]:
        f1 = np.float64(bu)
        f2 = np.float64(bv)
        f0 = 1.0 - f1 - f2
        for j in range(tangent_layers.shape[1]):
            for c in range(4):
                tan[0, j, c] = np.float32(tangent_layers[prim, j, 0, c] * f0 + tangent_layers[prim, j, 1, c] * f1
                                          + tangent_layers[prim, j, 2, c] * f2)
        if corner_normals.shape[0] > 0 and smooth[prim]:
            for c in range(3):
                nraw[0, c] = np.float32(np.float64(corner_normals[prim, 0, c]) * f0
                                        + np.float64(corner_normals[prim, 1, c]) * f1
                                        + np.float64(corner_normals[prim, 2, c]) * f2)
        else:
            for c in range(3):
                nraw[0, c] = face_normals[prim, c]
    if needs_differentials[mat]:
        differentials_point(tri_vertices, tri_uvs, prim, Ng[0, 0], Ng[0, 1], Ng[0, 2], hit_dp, 0, dP, db, duv)
    else:  # (vector_context: the points whose program reads no differentials get zeros)
        for j in range(2):
            for c in range(3):
                dP[0, j, c] = _F0
            for c in range(2):
                duv[0, j, c] = _F0
    has_normal[0] = False
    run_point(0, mat, (prog_of_mat, code, code_start, regs0, reg_start, data, data_start, bind, emit_reg,
                       normal_reg, tex_pixels, tex_offset, tex_h, tex_w),
              (P, N, Ng, I, uv, has_uv, side, obj, objects, uvx, extra, dP, duv, tan, nraw, scratch),
              (vl[0], vl[1], vl[2], vl[3], vl[6], vl[8], vl[5], t_scale), (emission, normal_out, has_normal, aov_out))


@_jit
def _bump_adjust(f, f_d, g1, reject, reject_d):
    """One channel of f cos after the bump shadowing (PathTracer._bump_shadowing_eval's NumPy promotion: the
    float32 difference, plus float64 g1 f_d, rounded to float32, clamped at 0)."""
    a = _F0 if reject else f - f_d
    v = np.float32(np.float64(a) + (0.0 if reject_d else g1 * np.float64(f_d)))
    return v if not v < _F0 else _F0


@_jit
def _loss(w, keep, f_d, pdf):
    """One channel of a BSDF sample's weight after the diffuse lobes' bump shadowing loss (PathTracer
    ._bump_shadowing_sampled: keep f_d / pdf in float64, rounded to float32, subtracted, clamped at 0)."""
    v = w - np.float32(keep * np.float64(f_d) / np.float64(pdf))
    return v if not v < _F0 else _F0


@_jit
def trace_paths(pix, smp, origins, directions, tmax, raster_x, raster_y, pinhole, intersect1, occluded1, scene,
                tri_vertices, face_normals, corner_normals, smooth, tri_magnitude, material_index, specular, lobes,
                view_select, select_scale, multiscatter, tabs,
                has_nondelta, has_transmission, emission, emitter_of_triangle, lt, per_point, n_matters,
                has_emission, seed_key, set_keys, dim_keys, tables, group_bits, max_bounces, rr_depth, clamp,
                shadow_epsilon, words, ids, address, buf, radiance, counters, t_start, depth_scale, albedo_of,
                out_albedo, out_normal, out_depth, terminator_offset, programs):
    """Trace camera path k (pixel pix[k], sample smp[k], ray origins[k] + t directions[k], t < tmax[k]) to its
    end and write its radiance (float32) to radiance[k]. Or, where `pinhole` holds a camera (core.camera
    .pinhole_params; else it is empty), the kernel makes path k's camera ray itself, at raster position
    (raster_x[k], raster_y[k]) as core.camera.camera_rays would (origins, directions, tmax, t_start and
    depth_scale are then empty). set_keys: the Sobol set key of every dimension set a
    path reads (index = the set); see core.fused_tracer.supports for what the scene may hold. counters: [non-finite dropped,
    clamped, closest-hit rays, shadow rays, then (TIMED only) the cycles of TIMING_PARTS], added to.
    terminator_offset: (T,) float32, or empty where no triangle has one: the shadow terminator lift of the shadow
    ray's origin, exactly as core.path_kernels.shadow_rays does it. programs: None (no node programs: this code
    compiles without their blocks), or the tuple PROGRAM_FIELDS names: a vertex whose material has a program
    shades and samples a 1-row copy of its lobes that the program rewrote (`_shade_vertex`), and the first hit's
    albedo comes from it. view_select (M,) bool, select_scale (M, L) float32: the materials whose lobe choice
    follows the view, and MaterialTable.select_scale; such a vertex rewrites its row of lobes' `select` (a copy
    per call: the rows are scratch, as the diffuse normals' are) for its wo before anything reads it
    (core.bsdf_kernels.view_select_row, as core.bsdf.select_for_view in the per-bounce integrator)."""
    use_terminator = terminator_offset.shape[0] > 0
    has_normals = corner_normals.shape[0] > 0
    want_aovs = out_depth.shape[0] > 0
    has_emitters = emitter_of_triangle.shape[0] > 0
    make_rays = pinhole.shape[0] > 0
    for k in range(pix.shape[0]):
        p_id = pix[k]
        s_id = smp[k]
        path_key = _mix32(_U(p_id ^ seed_key))
        if make_rays:  # (float64, rounded to float32 as camera_rays stores its rays)
            ox_, oy_, oz_, dx_, dy_, dz_, tm_, scale_, t0_ = pinhole_ray(raster_x[k], raster_y[k], pinhole)
            ox, oy, oz = np.float32(ox_), np.float32(oy_), np.float32(oz_)
            dx, dy, dz = np.float32(dx_), np.float32(dy_), np.float32(dz_)
            tm = np.float32(min(tm_, 3e38))
            cam_t0, cam_scale = np.float32(t0_), np.float32(scale_)
        else:
            ox, oy, oz = origins[k, 0], origins[k, 1], origins[k, 2]
            dx, dy, dz = directions[k, 0], directions[k, 1], directions[k, 2]
            tm = tmax[k]
            cam_t0 = t_start[k] if want_aovs else _F0
            cam_scale = depth_scale[k] if want_aovs else _F0
        cox, coy, coz, cdx, cdy, cdz = ox, oy, oz, dx, dy, dz  # the camera ray
        t0 = t1 = t2 = _F1
        r0 = r1 = r2 = _F0
        prev_pdf = _F0
        prev_delta = True
        pnx = pny = pnz = _F0
        prev_tr = False
        # the path's ray differential, compact as core.integrator keeps it (Bump nodes read it): the footprint
        # fp (Cycles' dP) and its spread per unit distance fd (dD); at a hit fp + t fd (float32), which the
        # bounce ray keeps with the camera ray's fd
        fp = fd = _F0
        # A pinhole camera's are deferred (core.camera.PinholeRays): computed at the path's first vertex that
        # reads them, from its camera ray, then carried over its hit distances so far (nt of them) as above.
        deferred = False
        nt = 0
        if programs is not None:
            if programs[45].shape[0] > 0:
                fp, fd = programs[45][k], programs[46][k]
            elif programs[47].shape[0] > 0:
                deferred = True
        if TIMED:
            cp_ = _cycles()
        for depth in range(max_bounces + 2):
            # ---- closest hit
            if TIMED:
                c0_ = _cycles()
            set_ray(words, ids, ox, oy, oz, dx, dy, dz, tm)
            ids[17] = _INVALID_ID
            ids[18] = _INVALID_ID
            ids[19] = _INVALID_ID
            _call_embree(intersect1, scene, address, 0)
            if TIMED:
                c1_ = _cycles()
                counters[TIMING_FIRST] += c1_ - c0_
            counters[2] += 1
            hit = ids[18] != _INVALID_ID
            prim = np.int32(ids[17]) if hit else np.int32(-1)
            bu = words[15] if hit else _F0
            bv = words[16] if hit else _F0
            t_hit = words[8] if hit else np.float32(np.inf)
            use_mis = depth > 0
            has_n = use_mis and n_matters
            tr_flag = has_n and per_point and prev_tr
            # ---- analytic lights and the world along the ray
            if has_emission:
                if TIMED:
                    c0_ = _cycles()
                er, eg, eb = light_emission_path(
                    np.float64(ox), np.float64(oy), np.float64(oz), np.float64(dx), np.float64(dy), np.float64(dz),
                    np.float64(t_hit), np.float64(prev_pdf) if use_mis else 0.0, prev_delta if use_mis else False,
                    use_mis, np.float64(pnx), np.float64(pny), np.float64(pnz), has_n, tr_flag, depth == 0,
                    per_point, lt, buf)
                if TIMED:
                    counters[TIMING_FIRST + 2] += _cycles() - c0_
                r0, r1, r2 = _add(r0, r1, r2, t0 * np.float32(er), t1 * np.float32(eg), t2 * np.float32(eb), clamp,
                                  counters)
            if not hit:
                break
            if programs is not None:
                if deferred:
                    programs[47][nt] = t_hit
                    nt += 1
                else:
                    fp = fp + t_hit * fd
            # ---- an emissive triangle hit
            mat = material_index[prim]
            if has_emitters and emitter_of_triangle[prim] >= 0:
                e = emitter_of_triangle[prim]
                w = _F1
                if depth > 0 and not prev_delta:
                    cos_e = abs(dx * face_normals[prim, 0] + dy * face_normals[prim, 1] + dz * face_normals[prim, 2])
                    pdf_l = _F0
                    if cos_e > _F0:
                        if TIMED:
                            c0_ = _cycles()
                        pl = triangle_pdf_path(e, np.float64(ox), np.float64(oy), np.float64(oz),
                                               np.float64(np.float32(t_hit * t_hit)), np.float64(cos_e), lt)
                        if per_point:
                            probabilities_at(np.float64(ox), np.float64(oy), np.float64(oz), np.float64(pnx),
                                             np.float64(pny), np.float64(pnz), n_matters, n_matters and prev_tr,
                                             lt[0], lt[1], lt[3], lt[4], buf)
                            unit = lt[20][e]
                            pl *= buf[unit] if unit >= 0 else 0.0
                        pdf_l = np.float32(pl) if math.isfinite(pl) else _F0
                        if TIMED:
                            counters[TIMING_FIRST + 3] += _cycles() - c0_
                    pb = prev_pdf
                    w = pb * pb / max(pb * pb + pdf_l * pdf_l, _TINY)
                r0, r1, r2 = _add(r0, r1, r2, t0 * emission[mat, 0] * w, t1 * emission[mat, 1] * w,
                                  t2 * emission[mat, 2] * w, clamp, counters)
            if depth == 0 and want_aovs:  # the first hit's albedo, normal (as the mesh gives it) and depth
                out_albedo[k, 0], out_albedo[k, 1], out_albedo[k, 2] = albedo_of[mat, 0], albedo_of[mat, 1], \
                    albedo_of[mat, 2]
                ax, ay, az = face_normals[prim, 0], face_normals[prim, 1], face_normals[prim, 2]
                if has_normals and smooth[prim]:
                    ax, ay, az = smooth_normal(corner_normals, prim, _F1 - bu - bv, bu, bv)
                out_normal[k, 0], out_normal[k, 1], out_normal[k, 2] = ax, ay, az
                out_depth[k] = (cam_t0 + t_hit) * cam_scale
            if depth == max_bounces + 1:
                break
            # ---- Russian roulette (the 4th number of the vertex's set)
            if TIMED:
                c0_ = _cycles()
            v_hk, v_r = _sobol_set(path_key, s_id, set_keys[2 + depth * 8 + _D_VERTEX], group_bits)
            if TIMED:
                counters[TIMING_FIRST + 7] += _cycles() - c0_
            if depth >= rr_depth:
                q = min(np.float32(math.sqrt(max(max(t0, t1), t2))), _F1)
                if TIMED:
                    c0_ = _cycles()
                u_rr = _sobol(v_hk, v_r, dim_keys, tables, 3)
                if TIMED:
                    counters[TIMING_FIRST + 7] += _cycles() - c0_
                if not u_rr < q:
                    break
                t0, t1, t2 = t0 / q, t1 / q, t2 / q
            # ---- the surface (core.geometry_kernels.surface for flat triangles)
            if TIMED:
                cs_ = _cycles()
            b0 = _F1 - bu - bv
            mag = tri_magnitude[prim]
            px = tri_vertices[prim, 0, 0] * b0 + tri_vertices[prim, 1, 0] * bu + tri_vertices[prim, 2, 0] * bv
            py = tri_vertices[prim, 0, 1] * b0 + tri_vertices[prim, 1, 1] * bu + tri_vertices[prim, 2, 1] * bv
            pz = tri_vertices[prim, 0, 2] * b0 + tri_vertices[prim, 1, 2] * bu + tri_vertices[prim, 2, 2] * bv
            mag = max(mag, abs(px), abs(py), abs(pz))
            gx, gy, gz = face_normals[prim, 0], face_normals[prim, 1], face_normals[prim, 2]
            wox, woy, woz = -dx, -dy, -dz
            cos_o_geo = wox * gx + woy * gy + woz * gz
            sx, sy, sz = gx, gy, gz
            smooth_here = has_normals and smooth[prim]
            if smooth_here:
                sx, sy, sz = smooth_normal(corner_normals, prim, b0, bu, bv)
            shade_lobes = lobes  # the lobes and row the vertex shades with: its material's, or its program's 1-row copy
            row = mat
            if programs is not None:
                if programs[0][mat]:
                    if TIMED:
                        c0_ = _cycles()
                    if deferred and programs[43][mat]:
                        fp, fd = pinhole_footprint(raster_x[k], raster_y[k], pinhole, cox, coy, coz, cdx, cdy, cdz)
                        for j in range(nt):
                            fp = fp + programs[47][j] * fd
                        deferred = False
                    _shade_vertex(programs, lobes, mat, prim, b0, bu, bv, px, py, pz, sx, sy, sz, gx, gy, gz, dx, dy,
                                  dz, cos_o_geo < _F0, face_normals, corner_normals, smooth, tri_vertices, fp)
                    if TIMED:  # (taken out of the surface's part below)
                        c1_ = _cycles()
                        counters[TIMING_FIRST + 9] += c1_ - c0_
                        cs_ += c1_ - c0_
                    shade_lobes = programs[37]
                    row = 0
                    if depth == 0 and want_aovs:  # (the roulette keeps every camera hit: its throughput is 1)
                        alb = programs[38]
                        albedo_batch(shade_lobes, multiscatter, tabs, alb, False, alb)
                        out_albedo[k, 0], out_albedo[k, 1], out_albedo[k, 2] = alb[0, 0], alb[0, 1], alb[0, 2]
            if sx * gx + sy * gy + sz * gz < _F0:
                sx, sy, sz = -sx, -sy, -sz
            ux, uy, uz = sx, sy, sz  # the normal the diffuse lobes keep
            if smooth_here and specular[mat]:
                side = _F1 if cos_o_geo >= _F0 else -_F1
                vx, vy, vz = _valid_reflection_normal(gx * side, gy * side, gz * side, wox, woy, woz,
                                                      sx * side, sy * side, sz * side)
                sx, sy, sz = np.float32(vx * side), np.float32(vy * side), np.float32(vz * side)
            tx, ty, tz, bx, by, bz = onb_f32(sx, sy, sz)
            # the diffuse lobes' normal (core.geometry_kernels._diffuse_normal), in the row of the vertex's
            # material of the lobes' last array (core.bsdf_kernels.diffuse_axis reads it there)
            dn = shade_lobes[9]
            if ux == sx and uy == sy and uz == sz:
                dn[row, 0], dn[row, 1], dn[row, 2] = _F0, _F0, _F1
            else:
                ax = ux * tx + uy * ty + uz * tz
                ay = ux * bx + uy * by + uz * bz
                az = ux * sx + uy * sy + uz * sz
                alen = max(np.float32(math.sqrt(ax * ax + ay * ay + az * az)), _TINY)
                dn[row, 0], dn[row, 1], dn[row, 2] = ax / alen, ay / alen, az / alen
            lx = wox * tx + woy * ty + woz * tz
            ly = wox * bx + woy * by + woz * bz
            lz = wox * sx + woy * sy + woz * sz
            flip = -_F1 if cos_o_geo < _F0 else _F1
            nvx, nvy, nvz = sx * flip, sy * flip, sz * flip
            bumped = False  # the program set the normal: the frame rebuilt around it, and Cycles' bump shadowing
            if programs is not None:
                if programs[0][mat] and programs[35][0]:
                    bumped = True
                    nrm = programs[34]
                    ok, rsx, rsy, rsz, rtx, rty, rtz, rbx, rby, rbz, rlx, rly, rlz, rvx, rvy, rvz, d0, d1, d2 = \
                        reframe_point(nrm[0, 0], nrm[0, 1], nrm[0, 2], dx, dy, dz, gx, gy, gz, cos_o_geo,
                                      specular[mat])
                    if ok:  # (core.geometry_kernels.reframe: a zero or non-finite normal keeps the frame)
                        sx, sy, sz, tx, ty, tz, bx, by, bz = rsx, rsy, rsz, rtx, rty, rtz, rbx, rby, rbz
                        lx, ly, lz, nvx, nvy, nvz = rlx, rly, rlz, rvx, rvy, rvz
                        dn[row, 0], dn[row, 1], dn[row, 2] = d0, d1, d2
                    # the diffuse-only lobe weights the bump shadowing evaluates (PathTracer._diffuse_only)
                    wd = programs[42]
                    for l in range(wd.shape[1]):
                        dif = shade_lobes[0][row, l] == _DIFFUSE
                        for c in range(3):
                            wd[0, l, c] = shade_lobes[1][row, l, c] if dif else _F0
            back = cos_o_geo < _F0
            sgn = -1.0 if back else 1.0
            if view_select[mat]:
                view_select_row(shade_lobes, row, multiscatter, tabs, np.float64(lz) * sgn, select_scale, mat)
            transmits = has_transmission[mat]
            if TIMED:
                counters[TIMING_FIRST + 8] += _cycles() - cs_
            # ---- next-event estimation: one light sample, MIS-weighted, with a shadow ray
            if has_nondelta[mat]:
                if TIMED:
                    c0_ = _cycles()
                l_hk, l_r = _sobol_set(path_key, s_id, set_keys[2 + depth * 8 + _D_LIGHT], group_bits)
                ua, ub, uc = _sobol3(l_hk, l_r, dim_keys, tables)
                if TIMED:
                    c1_ = _cycles()
                    counters[TIMING_FIRST + 7] += c1_ - c0_
                wx, wy, wz, dist, lr, lg, lb, lpdf, ldelta = sample_light_path(
                    np.float64(px), np.float64(py), np.float64(pz), np.float64(nvx) if n_matters else 0.0,
                    np.float64(nvy) if n_matters else 0.0, np.float64(nvz) if n_matters else 0.0, n_matters,
                    n_matters and per_point and transmits, np.float64(uc), np.float64(ua), np.float64(ub),
                    per_point, lt, buf)
                if TIMED:
                    counters[TIMING_FIRST + 4] += _cycles() - c1_
                wx, wy, wz = np.float32(wx), np.float32(wy), np.float32(wz)
                dist = np.float32(dist)
                pl = np.float32(lpdf)
                if pl > _F0:
                    ix = wx * tx + wy * ty + wz * tz
                    iy = wx * bx + wy * by + wz * bz
                    iz = wx * sx + wy * sy + wz * sz
                    if TIMED:
                        c0_ = _cycles()
                    f0, f1, f2, pb = eval_path(shade_lobes, row, multiscatter, tabs, np.float64(lx), np.float64(ly),
                                               np.float64(lz) * sgn, back, np.float64(ix), np.float64(iy),
                                               np.float64(iz) * sgn)
                    fc0, fc1, fc2 = np.float32(f0), np.float32(f1), np.float32(f2)
                    if programs is not None:
                        if bumped:  # core.integrator.PathTracer._bump_shadowing_eval, its float32/float64 steps
                            g1, rej, rej_d = bump_terms_point(tx, ty, tz, bx, by, bz, sx, sy, sz, nvx, nvy, nvz,
                                                              dn[row, 0], dn[row, 1], dn[row, 2], cos_o_geo,
                                                              programs[20][0, 0], programs[20][0, 1],
                                                              programs[20][0, 2], wx, wy, wz)
                            d_lobes = (shade_lobes[0], programs[42], shade_lobes[2], shade_lobes[3], shade_lobes[4],
                                       shade_lobes[5], shade_lobes[6], shade_lobes[7], shade_lobes[8],
                                       shade_lobes[9])
                            e0, e1, e2, _pd = eval_path(d_lobes, 0, multiscatter, tabs, np.float64(lx),
                                                        np.float64(ly), np.float64(lz) * sgn, back, np.float64(ix),
                                                        np.float64(iy), np.float64(iz) * sgn)
                            fc0 = _bump_adjust(fc0, np.float32(e0), g1, rej, rej_d)
                            fc1 = _bump_adjust(fc1, np.float32(e1), g1, rej, rej_d)
                            fc2 = _bump_adjust(fc2, np.float32(e2), g1, rej, rej_d)
                    if TIMED:
                        counters[TIMING_FIRST + 5] += _cycles() - c0_
                    w = _F1
                    if not ldelta:
                        pbf = np.float32(pb)
                        w = pl * pl / max(pl * pl + pbf * pbf, _TINY)
                    scale = w / max(pl, _TINY)
                    crosses = (cos_o_geo > _F0) != (wx * gx + wy * gy + wz * gz > _F0)
                    lift = _F0
                    g_side = _F1
                    if use_terminator:  # core.path_kernels.shadow_rays' shadow terminator
                        cutoff = terminator_offset[prim]
                        if cutoff > _F0:
                            nl = wx * nvx + wy * nvy + wz * nvz
                            g_side = _F1 if cos_o_geo >= _F0 else -_F1
                            if nl < _F0:
                                nl, g_side = -nl, -g_side
                            gl = g_side * (wx * gx + wy * gy + wz * gz)
                            if nl < cutoff:
                                lift = min(max(np.float32(2.0) - (gl + nl) / cutoff, _F0), _F1)
                            else:
                                lift = min(max(_F1 - gl / cutoff, _F0), _F1)
                    if crosses and not transmits and not lift > _F0:
                        scale = _F0
                    c0 = t0 * fc0 * np.float32(lr) * scale
                    c1 = t1 * fc1 * np.float32(lg) * scale
                    c2 = t2 * fc2 * np.float32(lb) * scale
                    if max(max(max(_F0, c0), c1), c2) > _F0:
                        if lift > _F0:
                            hx, hy, hz = smooth_surface_lift(prim, b0, bu, bv, gx * g_side, gy * g_side, gz * g_side,
                                                             tri_vertices, corner_normals)
                            sox, soy, soz = px + hx * lift, py + hy * lift, pz + hz * lift
                            if g_side * (wx * gx + wy * gy + wz * gz) > _F0:  # leaves the face: skip it
                                sox, soy, soz = offset_point(sox, soy, soz, gx, gy, gz, wx, wy, wz, mag)
                        else:
                            sox, soy, soz = offset_point(px, py, pz, gx, gy, gz, wx, wy, wz, mag)
                        if math.isfinite(dist):
                            vx, vy, vz = px + wx * dist - sox, py + wy * dist - soy, pz + wz * dist - soz
                            length = np.float32(math.sqrt(vx * vx + vy * vy + vz * vz))
                            inv = _F1 / max(length, _TINY)
                            vx, vy, vz = vx * inv, vy * inv, vz * inv
                            stmax = length * (_F1 - shadow_epsilon)
                        else:
                            vx, vy, vz = wx, wy, wz
                            stmax = _FAR
                        if TIMED:
                            c0_ = _cycles()
                        set_ray(words, ids, sox, soy, soz, vx, vy, vz, stmax)
                        _call_embree(occluded1, scene, address, 0)
                        if TIMED:
                            counters[TIMING_FIRST + 1] += _cycles() - c0_
                        counters[3] += 1
                        if not words[8] < 0.0:
                            r0, r1, r2 = _add(r0, r1, r2, c0, c1, c2, clamp, counters)
            # ---- the BSDF sample and the next ray (core.path_kernels.scatter)
            if TIMED:
                c0_ = _cycles()
            u_dir0, u_dir1, u_event = _sobol3(v_hk, v_r, dim_keys, tables)
            if TIMED:
                c1_ = _cycles()
                counters[TIMING_FIRST + 7] += c1_ - c0_
            qx, qy, qz, w0, w1, w2, spdf, sdelta, stransmitted, svalid = sample_path(
                shade_lobes, row, multiscatter, tabs, lx, ly, lz, back, u_event, u_dir0, u_dir1)
            if TIMED:
                counters[TIMING_FIRST + 6] += _cycles() - c1_
            qx, qy, qz = np.float32(qx), np.float32(qy), np.float32(qz)
            sw0, sw1, sw2 = np.float32(w0), np.float32(w1), np.float32(w2)
            if programs is not None:
                if bumped and svalid and not sdelta:  # PathTracer._bump_shadowing_sampled
                    if TIMED:
                        c0_ = _cycles()
                    wlx = tx * qx + bx * qy + sx * qz
                    wly = ty * qx + by * qy + sy * qz
                    wlz = tz * qx + bz * qy + sz * qz
                    g1, _rej, rej_d = bump_terms_point(tx, ty, tz, bx, by, bz, sx, sy, sz, nvx, nvy, nvz,
                                                       dn[row, 0], dn[row, 1], dn[row, 2], cos_o_geo,
                                                       programs[20][0, 0], programs[20][0, 1], programs[20][0, 2],
                                                       wlx, wly, wlz)
                    d_lobes = (shade_lobes[0], programs[42], shade_lobes[2], shade_lobes[3], shade_lobes[4],
                               shade_lobes[5], shade_lobes[6], shade_lobes[7], shade_lobes[8], shade_lobes[9])
                    e0, e1, e2, _pd = eval_path(d_lobes, 0, multiscatter, tabs, np.float64(lx), np.float64(ly),
                                                np.float64(lz) * sgn, back, np.float64(qx), np.float64(qy),
                                                np.float64(qz) * sgn)
                    keep = 1.0 if rej_d else 1.0 - g1
                    pdf_f = max(np.float32(spdf), np.float32(1e-30))
                    sw0 = _loss(sw0, keep, np.float32(e0), pdf_f)
                    sw1 = _loss(sw1, keep, np.float32(e1), pdf_f)
                    sw2 = _loss(sw2, keep, np.float32(e2), pdf_f)
                    if TIMED:
                        counters[TIMING_FIRST + 10] += _cycles() - c0_
            wx = qx * tx + qy * bx + qz * sx
            wy = qx * ty + qy * by + qz * sy
            wz = qx * tz + qy * bz + qz * sz
            side_o = cos_o_geo > _F0
            side_i = wx * gx + wy * gy + wz * gz > _F0
            if not (svalid and ((side_o != side_i) if stransmitted else (side_o == side_i))):
                break
            t0, t1, t2 = t0 * sw0, t1 * sw1, t2 * sw2
            if not max(t0, t1, t2) > _F0:
                break
            ox, oy, oz = offset_point(px, py, pz, gx, gy, gz, wx, wy, wz, mag)
            length = max(np.float32(math.sqrt(wx * wx + wy * wy + wz * wz)), _TINY)
            dx, dy, dz = wx / length, wy / length, wz / length
            prev_pdf = np.float32(spdf)
            prev_delta = sdelta
            pnx, pny, pnz = nvx, nvy, nvz
            prev_tr = transmits
            tm = _FAR
        if TIMED:
            counters[TIMING_FIRST + 11] += _cycles() - cp_
        radiance[k, 0], radiance[k, 1], radiance[k, 2] = r0, r1, r2
