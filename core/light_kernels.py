"""Compiled (numba) kernels of per-shading-point light selection: the importance of each selectable light unit at
a point, the selection probabilities they give, and the pick itself (the heuristic and its conventions:
docs/lights.md; core.lights builds the tables).

The unit table is one float64 array (K, UNIT_FIELDS) plus an int64 kind per unit; positions are in the
integrator's shifted frame (as every position core.lights handles). Points p and normals n arrive component-major
(3, N) float32, as core.lights keeps them. One function, `_probabilities`, computes a point's probabilities for
both `select` (light sampling) and `probability` (the light pdf of a BSDF-sampled direction, for MIS): the two must
agree exactly, or MIS weights are biased.
"""

from __future__ import annotations

import math

import numpy as np

# No NRT reference counting (these kernels never allocate), device functions taking arrays inlined: core.jit_cache.
from .jit_cache import jit_inline as _inline
from .jit_cache import jit_no_nrt as _jit
from .world_kernels import (PORTAL_SHARE, env_pdf, env_radiance, env_sample, portal_direction, portal_pdf,
                            portals_facing)
from .warps import (cone_pdf, cos_hemisphere_pdf, onb, one_minus_cos_from_sin2, sample_cone, sample_cos_hemisphere,
                    sample_disk, sample_sphere, sample_triangle, sphere_pdf)

# The light kinds, the one enumeration of them (core.lights names them): a selectable unit's kind says how its
# importance is estimated and which table (pt: POINT and SPOT, ar, su, the triangles, the world row) samples it.
TRI_GROUP, POINT, SPOT, AREA, SUN, WORLD = range(6)

# unit table columns
(C_X, C_Y, C_Z, C_RADIUS, C_AX, C_AY, C_AZ, C_COS_O, C_SIN_O, C_COS_E, C_TAN_HALF, C_NORM_SPREAD, C_INTENSITY,
 C_POWER, C_COS_U, C_SIN_U) = range(16)
UNIT_FIELDS = 16

# Cosine margin for "provably zero": a unit is dropped only when its bounds lie beyond a cut by more than this
# (about 0.06 degrees), so that float32 rounding of p, n and the ray origin offset never drops a unit whose
# contribution is not zero.
_DEAD_MARGIN = 1e-3


@_jit
def _cos_minus(cos_a, cos_b, sin_b):
    """cos(max(a - b, 0)) for angles a, b in [0, pi] given by cos a and by cos b, sin b (sin a only computed
    where needed: the square root is most of the cost)."""
    if cos_a >= cos_b:
        return 1.0
    return cos_a * cos_b + math.sqrt(max(1.0 - cos_a * cos_a, 0.0)) * sin_b


@_inline
def _importance(t, k, kind, px, py, pz, nx, ny, nz, has_n, transmits):
    """(importance, alive) of one unit at point p with shading normal n (has_n False: no normal known).

    importance: an estimate of the irradiance the unit gives at p (W/m^2 up to a constant): intensity x emitter
    orientation bound / squared distance to the bounding sphere (clamped to its radius) x receiver cosine bound.
    alive False only where the unit's contribution is provably zero (one-sided area light seen from behind, p
    outside a spot cone or an area light's spread, the whole light below a reflect-only surface)."""
    intensity = t[k, C_INTENSITY]
    if kind == WORLD:
        return intensity, True
    inside = False
    if kind == SUN:
        vx, vy, vz = t[k, C_AX], t[k, C_AY], t[k, C_AZ]
        cos_u, sin_u = t[k, C_COS_U], t[k, C_SIN_U]
        dist2 = 1.0
    else:
        vx = t[k, C_X] - px
        vy = t[k, C_Y] - py
        vz = t[k, C_Z] - pz
        d2 = vx * vx + vy * vy + vz * vz
        r = t[k, C_RADIUS]
        r2 = r * r
        dist2 = max(d2, r2, 1e-30)
        cos_u, sin_u = 1.0, 0.0
        if d2 <= r2 * 1.000001 or d2 <= 0.0:
            inside = True  # p within the light's bounds: no direction-based bound holds
        else:
            inv_d = 1.0 / math.sqrt(d2)
            vx, vy, vz = vx * inv_d, vy * inv_d, vz * inv_d
            if r > 0.0:
                sin_u = r * inv_d
                cos_u = math.sqrt(max(1.0 - sin_u * sin_u, 0.0))
        if kind == AREA:
            # one-sided: nothing reaches points behind the plane (the same test `sample` applies)
            if t[k, C_AX] * (px - t[k, C_X]) + t[k, C_AY] * (py - t[k, C_Y]) + t[k, C_AZ] * (pz - t[k, C_Z]) <= 0.0:
                return 0.0, False
        if kind != POINT and not inside:
            # the emitter's cone (axis, spread theta_o) against the direction light -> p (-v), widened by the
            # bounding sphere's half-angle theta_u
            cos_t = -(t[k, C_AX] * vx + t[k, C_AY] * vy + t[k, C_AZ] * vz)
            if kind == TRI_GROUP:
                cos_t = abs(cos_t)  # emits from both faces
            cos_t = min(max(cos_t, -1.0), 1.0)
            cos_o, sin_o = t[k, C_COS_O], t[k, C_SIN_O]
            cos_ou = cos_o * cos_u - sin_o * sin_u  # theta_o + theta_u (both <= pi / 2)
            sin_ou = sin_o * cos_u + cos_o * sin_u
            cos_tp = _cos_minus(cos_t, cos_ou, sin_ou)
            if cos_tp < t[k, C_COS_E] - _DEAD_MARGIN:
                return 0.0, False  # outside the spot cone / the area light's spread
            if kind == SPOT:
                pass  # constant intensity inside the cone
            else:  # Lambertian (area, triangles): intensity ~ cos
                intensity *= max(cos_tp, 0.0)
                ns = t[k, C_NORM_SPREAD]
                if ns > 0.0 and cos_tp > 0.0:
                    tan_tp = math.sqrt(max(1.0 - cos_tp * cos_tp, 0.0)) / cos_tp
                    intensity *= max((t[k, C_TAN_HALF] - tan_tp) * ns, 0.0)
    if has_n and not inside:
        cos_i = nx * vx + ny * vy + nz * vz
        if transmits:
            cos_i = abs(cos_i)
        cos_i = min(max(cos_i, -1.0), 1.0)
        cos_ip = _cos_minus(cos_i, cos_u, sin_u)
        if cos_ip < -_DEAD_MARGIN and not transmits:
            return 0.0, False  # the whole light is below the surface, which only reflects
        intensity *= max(cos_ip, 0.0)
    return intensity / dist2, True


@_jit  # not inlined: seven call sites, each a loop over the units (a call costs little beside it; inlining
# each copy tripled the first compile time)
def probabilities_at(px, py, pz, nx, ny, nz, has_n, transmits, table, kinds, fallback, floor_weight, out):
    """Selection probability of every unit at point p (float64 of the float32 point; n likewise, has_n False: no
    normal; transmits: the material there transmits) into out (K,): (1 - floor_weight) x importance share +
    floor_weight x power share among the units that are not provably zero there; `fallback` (the power shares)
    where no unit is alive."""
    K = kinds.shape[0]
    total_imp = 0.0
    total_pow = 0.0
    for k in range(K):
        imp, alive = _importance(table, k, kinds[k], px, py, pz, nx, ny, nz, has_n, transmits)
        if alive:
            if not (imp >= 0.0 and imp < 1e300):
                imp = 0.0
            out[k] = imp
            total_imp += imp
            total_pow += table[k, C_POWER]
        else:
            out[k] = -1.0
    if total_pow <= 0.0:
        for k in range(K):
            out[k] = fallback[k]
        return
    w_imp = (1.0 - floor_weight) / total_imp if total_imp > 0.0 else 0.0
    w_pow = (floor_weight if total_imp > 0.0 else 1.0) / total_pow
    for k in range(K):
        if out[k] < 0.0:
            out[k] = 0.0
        else:
            out[k] = out[k] * w_imp + table[k, C_POWER] * w_pow


@_inline
def select_path(px, py, pz, nx, ny, nz, has_n, transmits, x, table, kinds, fallback, floor_weight, buf):
    """Pick a unit at one point with probability from `probabilities_at`, by x in [0, 1) (float64).

    Returns (unit, its probability, x rescaled to [0, 1) within the unit's share, for a second choice inside the
    unit such as a triangle of a group); (0, 0, 0) where no unit can be chosen."""
    probabilities_at(px, py, pz, nx, ny, nz, has_n, transmits, table, kinds, fallback, floor_weight, buf)
    acc = 0.0
    before = 0.0
    chosen = -1
    for k in range(kinds.shape[0]):
        pk = buf[k]
        if pk <= 0.0:
            continue
        chosen = k
        before = acc
        acc += pk
        if x < acc:
            break
    if chosen < 0:
        return 0, 0.0, 0.0
    pk = buf[chosen]
    return chosen, pk, min(max((x - before) / pk, 0.0), 0.99999994)


@_jit
def probability(p, n, has_n, transmits, has_t, which, table, kinds, fallback, floor_weight, buf, prob):
    """prob[i] = the probability with which the selection picks unit which[i] at point p[i] (0 where
    which < 0). p, n (N, 3) float32; buf: scratch (K,) float64."""
    for i in range(p.shape[0]):
        k = which[i]
        if k < 0:
            prob[i] = 0.0
            continue
        nx = ny = nz = 0.0
        if has_n:
            nx, ny, nz = np.float64(n[i, 0]), np.float64(n[i, 1]), np.float64(n[i, 2])
        probabilities_at(np.float64(p[i, 0]), np.float64(p[i, 1]), np.float64(p[i, 2]), nx, ny, nz, has_n,
                         has_t and transmits[i], table, kinds, fallback, floor_weight, buf)
        prob[i] = buf[k]


# ====================================================================================== light sampling kernels
# Everything below samples and evaluates the lights themselves (core.lights builds the tables once per scene).
# Arithmetic is float64 on the float32 inputs; outputs are rounded to float32 where the public API is float32.
# Spherical rectangles and near triangles need float64; elsewhere it costs nothing in scalar code.

# point/spot light table columns (float64; positions, directions, radiance hold float32-rounded values)
(PT_X, PT_Y, PT_Z, PT_R, PT_G, PT_B, PT_RADIUS, PT_SPHERE, PT_SPOT, PT_DX, PT_DY, PT_DZ, PT_COS_HALF, PT_INV_WIDTH,
 PT_SEL, PT_UNIT, PT_CAM, PT_LIT) = range(18)
PT_FIELDS = 18
# area light table columns: centre, unit axes (float64), their float32 roundings for the ray-plane test
(AR_CX, AR_CY, AR_CZ, AR_AXX, AR_AXY, AR_AXZ, AR_AYX, AR_AYY, AR_AYZ, AR_ZX, AR_ZY, AR_ZZ, AR_NX, AR_NY, AR_NZ,
 AR_LX, AR_LY, AR_ELLIPSE, AR_AREA, AR_R, AR_G, AR_B, AR_TAN_HALF, AR_NORM_SPREAD, AR_SEL, AR_UNIT, AR_CAM, AR_LIT,
 AR_CX32, AR_CY32, AR_CZ32, AR_AXX32, AR_AXY32, AR_AXZ32, AR_AYX32, AR_AYY32, AR_AYZ32, AR_NX32, AR_NY32, AR_NZ32,
 AR_SU32, AR_SV32) = range(42)
AR_FIELDS = 42
# sun table columns: direction to the sun (float32-rounded), radiance, 1 - cos(half-angle), cos(half-angle)
(SU_DX, SU_DY, SU_DZ, SU_R, SU_G, SU_B, SU_OMC, SU_COS_HALF, SU_SEL, SU_UNIT, SU_CAM) = range(11)
SU_FIELDS = 11
# world row: uniform radiance, selection, unit, lit, and whether an environment map (tables 21-25) replaces
# the radiance
(W_R, W_G, W_B, W_SEL, W_UNIT, W_LIT, W_MAP) = range(7)
W_FIELDS = 7

# The light tables, one tuple (see core.lights.LightSampler._kernel_tables):
#   (u_table, u_kind, u_local, u_fallback, floor_weight,        -- per-point selection units
#    pt (P, PT_FIELDS), ar (A, AR_FIELDS), su (S, SU_FIELDS), world (W_FIELDS,),
#    t_v0, t_e1, t_e2, t_n, t_L (3, E) float32, t_pdf_area (E,) float32, t_sel (E,), t_edge2 (E,) float64,
#    g_order (E,) int64, g_cdf (E,) float64, g_start (G + 1,) int64, t_unit (E,) int64,
#    env_pix (H, W, 3) float32, env_par (E_FIELDS,), env_func (Hr, Wr), env_marg (Hr + 1,), env_cond (Hr, Wr + 1),
#    portals (P, P_FIELDS))
#    -- indices 9-20: the emissive triangles (component-major), their spatial groups and units; 21-25: the world's
#    environment map and its distribution (core.world_kernels; placeholders when the world is uniform); 26: the
#    light portals (core.world.portal_table; no rows when none)

_TWO_PI = 2.0 * math.pi
_INV_PI = 1.0 / math.pi
_INV_4PI = 1.0 / (4.0 * math.pi)
_RECT_MIN_SOLID_ANGLE = 1e-9  # below this a rectangle's solid angle is unreliable even in float64: sample by area
MIN_SPHERICAL_OMEGA = 1e-6  # sr: below this a spherical triangle is numerically flat; sample by area instead
_TWO_PI_SA = 2.0 * math.pi


@_jit
def _f32(x):
    return np.float64(np.float32(x))


@_jit
def _clip(x, lo, hi):
    """np.clip for scalars, NaN passing through."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@_jit
def _smoothstep(x):
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@_jit
def _mis_power(pdf_a, pdf_b):
    """Power-heuristic weight (float32) of strategy a against b (solid-angle pdfs); 1 where b is 0 (or NaN), 0
    where only b is infinite."""
    a2 = pdf_a * pdf_a
    b2 = pdf_b * pdf_b
    if not b2 > 0.0:
        return 1.0
    w = a2 / (a2 + b2)
    if math.isfinite(w):
        return _f32(w)
    return 1.0 if math.isinf(a2) else 0.0


# ------------------------------------------------------------------ emissive triangles sampled by solid angle
@_jit
def _solid_angle(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Solid angle (sr) of a triangle with corners a, b, c relative to the viewer (Van Oosterom-Strackee), and the
    corners' distances |a|, |b|, |c| (the spherical sampler's normalisations)."""
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    num = abs(ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx))
    den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb \
        + (bx * cx + by * cy + bz * cz) * la
    # 2 atan2 lies in [0, 2 pi] (num >= 0); the one value outside [0, 2 pi), a viewer on the triangle itself, is 0
    # (what `% (2 pi)` gave, without its floor and sign fix-ups)
    omega = 2.0 * math.atan2(num, den)
    if not omega < _TWO_PI_SA:
        omega -= _TWO_PI_SA
    return omega, la, lb, lc


@_inline
def _near_triangle(px, py, pz, t, v0, e1, e2, normal, edge2):
    """Corners of triangle t relative to p (float64), and its solid angle if it is sampled by solid angle
    there (Cycles' rule: longest edge longer than the distance to its plane), else 0; then the corners' distances
    from p where the solid angle is computed (else 0)."""
    ax = np.float64(v0[0, t]) - px
    ay = np.float64(v0[1, t]) - py
    az = np.float64(v0[2, t]) - pz
    bx, by, bz = ax + e1[0, t], ay + e1[1, t], az + e1[2, t]
    cx, cy, cz = ax + e2[0, t], ay + e2[1, t], az + e2[2, t]
    plane = abs(normal[0, t] * ax + normal[1, t] * ay + normal[2, t] * az)
    omega = la = lb = lc = 0.0
    if edge2[t] > plane * plane:
        omega, la, lb, lc = _solid_angle(ax, ay, az, bx, by, bz, cx, cy, cz)
        if omega <= MIN_SPHERICAL_OMEGA:
            omega = 0.0
    return ax, ay, az, bx, by, bz, cx, cy, cz, omega, la, lb, lc


@_jit
def _unit3(x, y, z):
    length = math.sqrt(x * x + y * y + z * z)
    if length > 0.0:
        return x / length, y / length, z / length
    return 0.0, 0.0, 0.0


@_jit
def _spherical_triangle_direction(ax, ay, az, bx, by, bz, cx, cy, cz, la, lb, lc, omega, u0, u1):
    """A direction uniform in the solid angle of the triangle with corners a, b, c relative to the viewer (Arvo
    1995, "Stratified sampling of spherical triangles", as pbrt-v4 writes it), given the corners' distances la,
    lb, lc and the solid angle omega (as _solid_angle computes them).

    Arvo's sub-triangle area is u0 * omega, the triangle's area alpha + beta + gamma - pi being its solid angle:
    so only the interior angle alpha at a is needed, and only through its cosine and sine, which are the dot and
    the length of the cross product of the unit edge-plane normals n_ab = a x b / |a x b| and -n_ca: with |a| = 1,
    (a x b) x (c x a) = -det(a, b, c) a, so sin(alpha) = |det(a, b, c)| / (|a x b| |c x a|). And Arvo's
    sin/cos(pi + u0 omega) are -sin/-cos(u0 omega)."""
    ia, ib, ic = 1.0 / la, 1.0 / lb, 1.0 / lc
    ax, ay, az = ax * ia, ay * ia, az * ia
    bx, by, bz = bx * ib, by * ib, bz * ib
    cx, cy, cz = cx * ic, cy * ic, cz * ic
    abx, aby, abz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx  # a x b
    cax, cay, caz = cy * az - cz * ay, cz * ax - cx * az, cx * ay - cy * ax  # c x a
    inv = 1.0 / math.sqrt((abx * abx + aby * aby + abz * abz) * (cax * cax + cay * cay + caz * caz))
    cos_alpha = -(abx * cax + aby * cay + abz * caz) * inv
    sin_alpha = abs(abx * cx + aby * cy + abz * cz) * inv
    area = u0 * omega  # the sub-triangle's area
    s_a, c_a = math.sin(area), math.cos(area)
    sin_phi = c_a * sin_alpha - s_a * cos_alpha
    cos_phi = -(c_a * cos_alpha + s_a * sin_alpha)
    k1 = cos_phi + cos_alpha
    k2 = sin_phi - sin_alpha * (ax * bx + ay * by + az * bz)
    den = (k2 * sin_phi + k1 * cos_phi) * sin_alpha
    cos_bp = (k2 + (k2 * cos_phi - k1 * sin_phi) * cos_alpha) / den if den != 0.0 else 1.0
    cos_bp = min(max(cos_bp, -1.0), 1.0)
    sin_bp = math.sqrt(1.0 - cos_bp * cos_bp)
    ca = cx * ax + cy * ay + cz * az
    qx, qy, qz = _unit3(cx - ca * ax, cy - ca * ay, cz - ca * az)
    px, py, pz = cos_bp * ax + sin_bp * qx, cos_bp * ay + sin_bp * qy, cos_bp * az + sin_bp * qz  # c'
    pb = px * bx + py * by + pz * bz
    cos_t = 1.0 - u1 * (1.0 - pb)
    sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0))
    rx, ry, rz = _unit3(px - pb * bx, py - pb * by, pz - pb * bz)
    return cos_t * bx + sin_t * rx, cos_t * by + sin_t * ry, cos_t * bz + sin_t * rz


@_inline
def _sample_triangle(px, py, pz, t, u0, u1, lt):
    """Emitter t from p: uniform by area, or (near and large, Cycles' rule) uniform in its solid angle: the
    seed's lamp hangs 2 cm under the ceiling, where area sampling's 1/d^2 weight makes fireflies.
    Returns (wi, dist, radiance, pdf given the unit), pdf 0 for no contribution."""
    t_v0, t_e1, t_e2, t_n, t_L, t_pdf_area, t_sel, t_edge2 = lt[9], lt[10], lt[11], lt[12], lt[13], lt[14], \
        lt[15], lt[16]
    ax, ay, az, bx, by, bz, cx, cy, cz, omega, la, lb, lc = _near_triangle(px, py, pz, t, t_v0, t_e1, t_e2, t_n,
                                                                           t_edge2)
    nx, ny, nz = np.float64(t_n[0, t]), np.float64(t_n[1, t]), np.float64(t_n[2, t])
    rr, rg, rb = np.float64(t_L[0, t]), np.float64(t_L[1, t]), np.float64(t_L[2, t])
    if omega > 0.0:
        wx, wy, wz = _spherical_triangle_direction(ax, ay, az, bx, by, bz, cx, cy, cz, la, lb, lc, omega, u0, u1)
        # distance to the plane: (n . (v0 - p)) / (n . w), v0 - p = the unnormalised corner a
        den = nx * wx + ny * wy + nz * wz
        d = (nx * ax + ny * ay + nz * az) / den if den != 0.0 else 0.0
        if not (d > 0.0 and math.isfinite(d)):
            return 0.0, 0.0, 0.0, 0.0, rr, rg, rb, 0.0  # sampled direction missed the plane (numerically)
        return wx, wy, wz, d, rr, rg, rb, t_sel[t] / omega
    b1, b2 = sample_triangle(u0, u1)
    # the point rounded to float32, as the triangle's own precision
    qx = _f32(t_v0[0, t] + t_e1[0, t] * b1 + t_e2[0, t] * b2)
    qy = _f32(t_v0[1, t] + t_e1[1, t] * b1 + t_e2[1, t] * b2)
    qz = _f32(t_v0[2, t] + t_e1[2, t] * b1 + t_e2[2, t] * b2)
    wx, wy, wz = qx - px, qy - py, qz - pz
    d2 = wx * wx + wy * wy + wz * wz
    d = math.sqrt(d2)
    wx, wy, wz = wx / d, wy / d, wz / d
    cos_l = abs(nx * wx + ny * wy + nz * wz)
    pdf = t_pdf_area[t] * d2 / cos_l if cos_l > 0.0 else 0.0
    return wx, wy, wz, d, rr, rg, rb, pdf


@_inline
def _pick_in_group(group, x, g_order, g_cdf, g_start):
    """Emitter picked by power inside triangle group `group` by x in [0, 1): the first entry of the group whose
    cumulative share (offset by the group index) exceeds group + x."""
    lo = g_start[group]
    hi = g_start[group + 1] - 1
    key = group + x
    a, b = lo, hi
    while a < b:  # first index in [lo, hi] with cdf > key (hi if none)
        m = (a + b) >> 1
        if g_cdf[m] > key:
            b = m
        else:
            a = m + 1
    return g_order[a]


@_inline
def triangle_pdf_path(e, ox, oy, oz, dist2, cos_l, lt):
    """Solid-angle pdf, given its unit, with which the sampler produces the point of emitter e that a ray from o
    hit at squared distance dist2 and |cos| cos_l (float32 values): the area pdf, or 1 / solid angle where the
    triangle is near."""
    omega = _near_triangle(ox, oy, oz, e, lt[9], lt[10], lt[11], lt[12], lt[16])[9]
    if omega > 0.0:
        return lt[15][e] / omega
    return _f32(np.float64(lt[14][e]) * dist2 / cos_l)


# ------------------------------------------------------------------------------------------ point and spot
@_jit
def _spot_att(pt, k, wx, wy, wz):
    """Spot cone smoothstep of light k for the unit direction w leaving it (1 for point lights)."""
    if pt[k, PT_SPOT] == 0.0:
        return 1.0
    x = _f32(pt[k, PT_DX] * wx + pt[k, PT_DY] * wy + pt[k, PT_DZ] * wz - pt[k, PT_COS_HALF])
    if pt[k, PT_INV_WIDTH] > 0.0:
        return _smoothstep(_f32(x * pt[k, PT_INV_WIDTH]))
    return 1.0 if x > 0.0 else 0.0


@_inline
def _sample_punctual(px, py, pz, nx, ny, nz, has_n, k, u0, u1, pt):
    """Point/spot light k: a point (delta), the disc of radius r facing p (uniform by area), or the sphere
    (uniform in the cone it subtends; from inside, cosine about n or uniform). Returns (wi, dist, radiance, pdf
    given the unit, delta)."""
    r = pt[k, PT_RADIUS]
    rr, rg, rb = pt[k, PT_R], pt[k, PT_G], pt[k, PT_B]
    vx, vy, vz = pt[k, PT_X] - px, pt[k, PT_Y] - py, pt[k, PT_Z] - pz
    d2 = vx * vx + vy * vy + vz * vz
    d = math.sqrt(d2)
    axx, axy, axz = vx / d, vy / d, vz / d
    if r <= 0.0:  # a point: intensity / d^2
        s = _spot_att(pt, k, -axx, -axy, -axz) / d2
        return axx, axy, axz, d, rr * s, rg * s, rb * s, 1.0, True
    if pt[k, PT_SPHERE] == 0.0:  # disc of radius r on the light, facing p, sampled uniformly by area
        tx, ty, tz, bx, by, bz = onb(axx, axy, axz)
        c, s = sample_disk(r, u0, u1)
        wx, wy, wz = vx + tx * c + bx * s, vy + ty * c + by * s, vz + tz * c + bz * s
        t2 = wx * wx + wy * wy + wz * wz
        dist = math.sqrt(t2)
        wx, wy, wz = wx / dist, wy / dist, wz / dist
        cos_l = abs(axx * wx + axy * wy + axz * wz)
        pdf = t2 / (math.pi * r * r) / cos_l if cos_l > 0.0 else 0.0
        att = _spot_att(pt, k, -wx, -wy, -wz)
        return wx, wy, wz, dist, rr * att, rg * att, rb * att, pdf, False
    r2 = _f32(r * r)
    if d > r:  # uniform in the cone the sphere subtends
        omc = one_minus_cos_from_sin2(r2 / d2)
        wx, wy, wz, cos_t = sample_cone(axx, axy, axz, omc, u0, u1)
        sin2 = max(1.0 - cos_t * cos_t, 0.0)
        dist = d * cos_t - math.sqrt(max(r2 - d2 * sin2, 0.0))
        att = _spot_att(pt, k, -wx, -wy, -wz)
        return wx, wy, wz, dist, rr * att, rg * att, rb * att, cone_pdf(omc), False
    # inside: every direction meets the sphere; cosine about n, or uniform (no spot cone inside, as Cycles)
    if has_n:
        wx, wy, wz, cos_t = sample_cos_hemisphere(nx, ny, nz, u0, u1)
        pdf = cos_hemisphere_pdf(cos_t)
    else:
        wx, wy, wz = sample_sphere(u0, u1)
        pdf = sphere_pdf()
    bb = vx * wx + vy * wy + vz * wz
    dist = bb + math.sqrt(max(r2 - d2 + bb * bb, 0.0))
    return wx, wy, wz, dist, rr, rg, rb, pdf, False


# ------------------------------------------------------------------------------------------------ area lights
@_jit
def _area_spread(ar, k, cos_a):
    """Spread attenuation of area light k for the cosine to its normal (1 when Lambertian)."""
    ns = ar[k, AR_NORM_SPREAD]
    if ns <= 0.0:
        return 1.0
    if not cos_a > 0.0:
        return 0.0
    tan_a = math.sqrt(max(1.0 - cos_a * cos_a, 0.0)) / cos_a
    return _f32(max((ar[k, AR_TAN_HALF] - tan_a) * ns, 0.0))


@_inline
def _rect_frame(ar, k, ox, oy, oz):
    """Rectangle k seen from o, in the frame of Urena et al. 2013, "An Area-Preserving Parametrization for
    Spherical Rectangles" (float64): its extent (x0, x1, y0, y1) along its axes relative to o, the distance
    z0 <= 0 along the normal flipped away from o, flip, the constants b0, b1, the solid angle S and the offset
    a2 + a3 of the sampler. The paper's internal angles g_i = acos(-n_i . n_i+1) are written as pi/2 - a_i with
    a_i = asin(-n_i . n_i+1), so that S = sum(g) - 2 pi = -(a0 + a1 + a2 + a3) has no cancellation for small
    rectangles."""
    dx, dy, dz = ar[k, AR_CX] - ox, ar[k, AR_CY] - oy, ar[k, AR_CZ] - oz
    z0 = ar[k, AR_ZX] * dx + ar[k, AR_ZY] * dy + ar[k, AR_ZZ] * dz
    flip = z0 > 0.0
    z0 = -abs(z0)
    xc = ar[k, AR_AXX] * dx + ar[k, AR_AXY] * dy + ar[k, AR_AXZ] * dz
    yc = ar[k, AR_AYX] * dx + ar[k, AR_AYY] * dy + ar[k, AR_AYZ] * dz
    hx, hy = 0.5 * ar[k, AR_LX], 0.5 * ar[k, AR_LY]
    x0, x1 = xc - hx, xc + hx
    y0, y1 = yc - hy, yc + hy
    z2 = z0 * z0
    r_y0, r_x1 = math.sqrt(z2 + y0 * y0), math.sqrt(z2 + x1 * x1)
    r_y1, r_x0 = math.sqrt(z2 + y1 * y1), math.sqrt(z2 + x0 * x0)
    # edge-plane normals n0..n3: (0, z0, -y0)/r_y0, (-z0, 0, x1)/r_x1, (0, -z0, y1)/r_y1, (z0, 0, -x0)/r_x0
    a0 = math.asin(_clip(y0 * x1 / (r_y0 * r_x1), -1.0, 1.0))
    a1 = math.asin(_clip(-x1 * y1 / (r_x1 * r_y1), -1.0, 1.0))
    a2 = math.asin(_clip(x0 * y1 / (r_y1 * r_x0), -1.0, 1.0))
    a3 = math.asin(_clip(-x0 * y0 / (r_x0 * r_y0), -1.0, 1.0))
    b0 = -y0 / r_y0
    b1 = y1 / r_y1
    S = -(a0 + a1 + a2 + a3)
    if not math.isfinite(S):
        S = 0.0
    return x0, x1, y0, y1, z0, flip, b0, b1, S, a2 + a3


@_inline
def _rect_sample(ar, k, ox, oy, oz, x0, x1, y0, y1, z0, flip, b0, b1, S, a23, u0, u1):
    """Point on rectangle k uniform in solid angle from o (frame from _rect_frame). The paper's
    au = u S + k with k = 2 pi - g2 - g3 is pi + (u S + a2 + a3) here; the pi flips the signs of cos(au) and
    sin(au), which is folded into fu."""
    phi = u0 * S + a23
    fu = (math.cos(phi) * b0 + b1) / math.sin(phi)
    cu = _clip(math.copysign(1.0, fu) / math.sqrt(fu * fu + b0 * b0), -1.0, 1.0)
    sq = math.sqrt(1.0 - cu * cu)
    xu = -(cu * z0) / (sq if sq > 1e-12 or sq != sq else 1e-12)
    if xu != xu:
        xu = 0.0
    xu = _clip(xu, x0, x1)
    d2 = xu * xu + z0 * z0
    h0 = y0 / math.sqrt(d2 + y0 * y0)
    h1 = y1 / math.sqrt(d2 + y1 * y1)
    hv = h0 + u1 * (h1 - h0)
    hv2 = hv * hv
    yv = hv * math.sqrt(d2 / max(1.0 - hv2, 1e-300)) if hv2 < 1.0 - 1e-12 else y1
    yv = _clip(yv, y0, y1)
    zc = -z0 if flip else z0  # z0 along z itself
    return (ox + ar[k, AR_AXX] * xu + ar[k, AR_AYX] * yv + ar[k, AR_ZX] * zc,
            oy + ar[k, AR_AXY] * xu + ar[k, AR_AYY] * yv + ar[k, AR_ZY] * zc,
            oz + ar[k, AR_AXZ] * xu + ar[k, AR_AYZ] * yv + ar[k, AR_ZZ] * zc)


@_inline
def _area_point(ar, k, u0, u1):
    """Point uniformly distributed by area on area light k."""
    if ar[k, AR_ELLIPSE] != 0.0:
        sx, sy = sample_disk(1.0, u0, u1)
    else:
        sx, sy = 2.0 * u0 - 1.0, 2.0 * u1 - 1.0
    hx, hy = 0.5 * ar[k, AR_LX] * sx, 0.5 * ar[k, AR_LY] * sy
    return (ar[k, AR_CX] + ar[k, AR_AXX] * hx + ar[k, AR_AYX] * hy,
            ar[k, AR_CY] + ar[k, AR_AXY] * hx + ar[k, AR_AYY] * hy,
            ar[k, AR_CZ] + ar[k, AR_AXZ] * hx + ar[k, AR_AYZ] * hy)


@_inline
def _sample_area(px, py, pz, k, u0, u1, ar):
    """Area light k: rectangles uniform in solid angle (by area where that is below _RECT_MIN_SOLID_ANGLE),
    discs/ellipses uniform by area; nothing behind its plane. Returns (wi, dist, radiance, pdf given the unit)."""
    front = ar[k, AR_NX] * (px - ar[k, AR_CX]) + ar[k, AR_NY] * (py - ar[k, AR_CY]) + \
        ar[k, AR_NZ] * (pz - ar[k, AR_CZ]) > 0.0
    by_area = True
    pdf = 0.0
    qx = qy = qz = 0.0
    if ar[k, AR_ELLIPSE] == 0.0:
        x0, x1, y0, y1, z0, flip, b0, b1, S, a23 = _rect_frame(ar, k, px, py, pz)
        if S > _RECT_MIN_SOLID_ANGLE:
            by_area = False
            qx, qy, qz = _rect_sample(ar, k, px, py, pz, x0, x1, y0, y1, z0, flip, b0, b1, S, a23, u0, u1)
            pdf = 1.0 / S
    if by_area:
        qx, qy, qz = _area_point(ar, k, u0, u1)
    wx, wy, wz = qx - px, qy - py, qz - pz
    t2 = wx * wx + wy * wy + wz * wz
    dist = math.sqrt(t2)
    wx, wy, wz = wx / dist, wy / dist, wz / dist
    cos_a = -(ar[k, AR_NX] * wx + ar[k, AR_NY] * wy + ar[k, AR_NZ] * wz)
    if by_area:
        pdf = t2 / (ar[k, AR_AREA] * cos_a) if cos_a > 0.0 else 0.0
    if not front:
        pdf = 0.0
    att = _area_spread(ar, k, cos_a)
    return wx, wy, wz, dist, ar[k, AR_R] * att, ar[k, AR_G] * att, ar[k, AR_B] * att, pdf


# ----------------------------------------------------------------------------------------------- sampling
@_inline
def sample_light_path(px, py, pz, nx, ny, nz, has_n, transmits, u_sel, u0, u1, per_point, lt, buf):
    """One light sample at shading point p (float64 of float32 values; n the shading-side normal where has_n;
    transmits: the material transmits), with uniform numbers u_sel (selection) and u0, u1 (the light's own).

    Picks a unit (per point, or the only one), an emitter in it, samples it. Returns (wx, wy, wz, dist, r, g, b,
    pdf, delta) rounded to float32 values: the solid-angle pdf includes the selection probability; pdf 0 (with
    wi and radiance 0) means no contribution. buf: scratch (K,) float64."""
    u_table, u_kind, u_local, fallback, floor_weight = lt[0], lt[1], lt[2], lt[3], lt[4]
    prob = 1.0
    unit = 0
    x = u_sel
    if per_point:
        unit, prob, x = select_path(px, py, pz, nx, ny, nz, has_n, transmits, u_sel, u_table, u_kind, fallback,
                                    floor_weight, buf)
    kind = u_kind[unit]
    local = u_local[unit]
    delta = False
    if kind == TRI_GROUP:
        e = _pick_in_group(local, x, lt[17], lt[18], lt[19])
        wx, wy, wz, dist, rr, rg, rb, pdf = _sample_triangle(px, py, pz, e, u0, u1, lt)
    elif kind == POINT or kind == SPOT:
        wx, wy, wz, dist, rr, rg, rb, pdf, delta = _sample_punctual(px, py, pz, nx, ny, nz, has_n, local, u0, u1,
                                                                     lt[5])
        pdf *= lt[5][local, PT_SEL]
    elif kind == AREA:
        ar = lt[6]
        wx, wy, wz, dist, rr, rg, rb, pdf = _sample_area(px, py, pz, local, u0, u1, ar)
        pdf *= ar[local, AR_SEL]
    elif kind == SUN:
        su = lt[7]
        dist = math.inf
        rr, rg, rb = su[local, SU_R], su[local, SU_G], su[local, SU_B]
        omc = su[local, SU_OMC]
        wx, wy, wz = su[local, SU_DX], su[local, SU_DY], su[local, SU_DZ]
        if omc <= 0.0:
            pdf = su[local, SU_SEL]
            delta = True
        else:
            wx, wy, wz, _ = sample_cone(wx, wy, wz, _f32(omc), u0, u1)
            pdf = su[local, SU_SEL] / (_TWO_PI * omc)
    elif lt[26].shape[0] > 0 and portals_facing(lt[26], px, py, pz) > 0:
        dist = math.inf
        wx, wy, wz, rr, rg, rb, pdf = _world_through_portals(px, py, pz, nx, ny, nz, has_n, u0, u1, lt)
    elif lt[8][W_MAP] != 0.0:
        dist = math.inf
        wx, wy, wz, pdf = env_sample(lt[22], lt[23], lt[24], lt[25], u0, u1)
        rr, rg, rb = env_radiance(lt[21], lt[22], wx, wy, wz)
        pdf *= lt[8][W_SEL]
    else:
        w = lt[8]
        dist = math.inf
        rr, rg, rb = w[W_R], w[W_G], w[W_B]
        if has_n:
            wx, wy, wz, cos_t = sample_cos_hemisphere(nx, ny, nz, u0, u1)
            pdf = _f32(w[W_SEL] * _INV_PI) * cos_t
        else:
            wx, wy, wz = sample_sphere(u0, u1)
            pdf = w[W_SEL] * _INV_4PI
    if per_point:
        pdf *= prob
    # zero the samples that carry no contribution or are not finite (a shading point at a light's centre)
    pdf32 = np.float32(pdf)
    r32, g32, b32 = np.float32(rr), np.float32(rg), np.float32(rb)
    x32, y32, z32 = np.float32(wx), np.float32(wy), np.float32(wz)
    if not (pdf32 > 0 and math.isfinite(pdf32) and math.isfinite(r32 + g32 + b32) and math.isfinite(x32 + y32 + z32)):
        pdf32 = np.float32(0.0)
        r32 = g32 = b32 = x32 = y32 = z32 = np.float32(0.0)
    return x32, y32, z32, np.float32(dist), r32, g32, b32, pdf32, delta


@_inline
def _world_pdf(px, py, pz, nx, ny, nz, has_n, dx, dy, dz, lt):
    """The world's light-sample solid-angle pdf (before selection) at p, inside some light portal, in direction d:
    PORTAL_SHARE through the portals facing p, the rest by the map (or the cosine about n, or the sphere)."""
    w = lt[8]
    if w[W_MAP] != 0.0:
        base = env_pdf(lt[23], dx, dy, dz)
    elif has_n:
        base = max(dx * nx + dy * ny + dz * nz, 0.0) * _INV_PI
    else:
        base = _INV_4PI
    count = portals_facing(lt[26], px, py, pz)
    return (1.0 - PORTAL_SHARE) * base + PORTAL_SHARE * portal_pdf(lt[26], count, px, py, pz, dx, dy, dz)


@_inline
def _world_through_portals(px, py, pz, nx, ny, nz, has_n, u0, u1, lt):
    """A world light sample at p inside some light portal (Cycles' portals): with probability PORTAL_SHARE a
    direction through a portal, else as without portals; the pdf (times the world's selection) is the mixture's
    (_world_pdf), so either kind of sample is weighted against both. Returns (wx, wy, wz, r, g, b, pdf)."""
    w = lt[8]
    if u0 < PORTAL_SHARE:
        count = portals_facing(lt[26], px, py, pz)
        wx, wy, wz = portal_direction(lt[26], count, px, py, pz, u0 / PORTAL_SHARE, u1)
    else:
        v0 = min((u0 - PORTAL_SHARE) / (1.0 - PORTAL_SHARE), 0.9999999403953552)
        if w[W_MAP] != 0.0:
            wx, wy, wz, _ = env_sample(lt[22], lt[23], lt[24], lt[25], v0, u1)
        elif has_n:
            wx, wy, wz, _ = sample_cos_hemisphere(nx, ny, nz, v0, u1)
        else:
            wx, wy, wz = sample_sphere(v0, u1)
    if w[W_MAP] != 0.0:
        rr, rg, rb = env_radiance(lt[21], lt[22], wx, wy, wz)
    else:
        rr, rg, rb = w[W_R], w[W_G], w[W_B]
    pdf = w[W_SEL] * _world_pdf(px, py, pz, nx, ny, nz, has_n, wx, wy, wz, lt)
    return wx, wy, wz, rr, rg, rb, pdf


@_jit
def sample_batch(p, n, has_n, transmits, has_t, u_sel, u, per_point, lt, buf, wi, dist, radiance, pdf, delta):
    """sample_light_path for every point: p, n (N, 3) float32 (n unused unless has_n), transmits (N,) bool
    (unused unless has_t), u_sel (N,) float64, u (N, 2) float32; writes wi, radiance (N, 3), dist, pdf (N,)
    float32 and delta (N,) bool."""
    for i in range(p.shape[0]):
        nx = ny = nz = 0.0
        if has_n:
            nx, ny, nz = np.float64(n[i, 0]), np.float64(n[i, 1]), np.float64(n[i, 2])
        wx, wy, wz, d, rr, rg, rb, pd, de = sample_light_path(
            np.float64(p[i, 0]), np.float64(p[i, 1]), np.float64(p[i, 2]), nx, ny, nz, has_n,
            has_t and transmits[i], u_sel[i], np.float64(u[i, 0]), np.float64(u[i, 1]), per_point, lt, buf)
        wi[i, 0], wi[i, 1], wi[i, 2] = wx, wy, wz
        dist[i] = d
        radiance[i, 0], radiance[i, 1], radiance[i, 2] = rr, rg, rb
        pdf[i] = pd
        delta[i] = de


# ------------------------------------------------------------------------------------ emission along rays
@_jit
def _times_selection(pl, unit, have_prob, ox, oy, oz, nx, ny, nz, has_n, transmits, lt, buf):
    """pl times the per-point selection probability of `unit` (-1: never selected) at the ray origin o; the
    probabilities of all units go into buf on a ray's first light hit (have_prob False) and are reused after.
    Returns (pl x probability, True)."""
    if not have_prob:
        probabilities_at(ox, oy, oz, nx, ny, nz, has_n, transmits, lt[0], lt[1], lt[3], lt[4], buf)
    return pl * (buf[unit] if unit >= 0 else 0.0), True


@_inline
def light_emission_path(ox, oy, oz, dx, dy, dz, tmax, bsdf_pdf, bsdf_delta, use_mis, nx, ny, nz, has_n,
                        transmits, camera, per_point, lt, buf):
    """Emission (r, g, b) of every analytic light surface the ray o + t d (unit d) passes for 0 < t < tmax,
    summed (lights are transparent), each weighted by the power heuristic against bsdf_pdf (unless bsdf_delta
    or not use_mis) with the light pdf `sample_light_path` gives that direction (selection included); where tmax
    is inf also the sun discs and the world. camera: camera rays see the world and only lights marked visible
    to the camera. Inputs are float64 of float32 values; buf: scratch (K,) float64."""
    pt, ar, su, w = lt[5], lt[6], lt[7], lt[8]
    er = eg = eb = 0.0
    need_prob = use_mis and per_point
    have_prob = False
    # ---- point/spot lights with a surface: the disc facing o, or the sphere
    for k in range(pt.shape[0]):
        r = pt[k, PT_RADIUS]
        if not (r > 0.0 and (pt[k, PT_CAM] != 0.0 or not camera) and pt[k, PT_LIT] != 0.0):
            continue
        r2 = _f32(r * r)
        vx, vy, vz = pt[k, PT_X] - ox, pt[k, PT_Y] - oy, pt[k, PT_Z] - oz  # towards the light
        d2 = vx * vx + vy * vy + vz * vz
        b = vx * dx + vy * dy + vz * dz  # distance along the ray to the point nearest the centre
        sel = pt[k, PT_SEL]
        att = 1.0
        if pt[k, PT_SPHERE] == 0.0:
            # the ray meets the disc's plane at t = d2 / b, at squared distance t^2 - d2 from the centre
            t = d2 / b
            if not (b > 0.0 and t < tmax and t * t - d2 <= r2):
                continue
            cos_l = b / math.sqrt(d2)
            pdf = t * t * (sel / (math.pi * r * r)) / cos_l
            att = _spot_att(pt, k, -dx, -dy, -dz)
        else:
            inside = d2 <= r2
            disc = b * b - d2 + r2
            sq = math.sqrt(max(disc, 0.0))
            t = b + sq if inside else b - sq
            if not (disc >= 0.0 and t > 0.0 and t < tmax and (inside or b > 0.0)):
                continue
            if inside:
                if has_n:
                    pdf = (sel * _INV_PI) * max(dx * nx + dy * ny + dz * nz, 0.0)
                else:
                    pdf = sel * _INV_4PI
            else:
                pdf = sel / (_TWO_PI * one_minus_cos_from_sin2(min(r2 / d2, 1.0)))
                att = _spot_att(pt, k, -dx, -dy, -dz)
        wgt = 1.0
        if use_mis and not bsdf_delta:
            pl = _f32(pdf)
            if need_prob:
                pl, have_prob = _times_selection(pl, np.int64(pt[k, PT_UNIT]), have_prob, ox, oy, oz, nx, ny, nz,
                                                 has_n, transmits, lt, buf)
            wgt = _mis_power(bsdf_pdf, pl)
        er += _f32(_f32(pt[k, PT_R] * att) * wgt)
        eg += _f32(_f32(pt[k, PT_G] * att) * wgt)
        eb += _f32(_f32(pt[k, PT_B] * att) * wgt)
    # ---- area lights (front face)
    for k in range(ar.shape[0]):
        if not ((ar[k, AR_CAM] != 0.0 or not camera) and ar[k, AR_LIT] != 0.0):
            continue
        gx, gy, gz = ar[k, AR_NX32], ar[k, AR_NY32], ar[k, AR_NZ32]
        dn = _f32(gx * dx + gy * dy + gz * dz)
        cx, cy, cz = ar[k, AR_CX32], ar[k, AR_CY32], ar[k, AR_CZ32]
        t = _f32(_f32(gx * (cx - ox) + gy * (cy - oy) + gz * (cz - oz)) / dn)
        if not (dn < 0.0 and t > 0.0 and t < tmax):
            continue
        rx, ry, rz = ox + dx * t - cx, oy + dy * t - cy, oz + dz * t - cz
        su_ = (ar[k, AR_AXX32] * rx + ar[k, AR_AXY32] * ry + ar[k, AR_AXZ32] * rz) * ar[k, AR_SU32]
        sv_ = (ar[k, AR_AYX32] * rx + ar[k, AR_AYY32] * ry + ar[k, AR_AYZ32] * rz) * ar[k, AR_SV32]
        if ar[k, AR_ELLIPSE] != 0.0:
            if not su_ * su_ + sv_ * sv_ <= 1.0:
                continue
        elif not (abs(su_) <= 1.0 and abs(sv_) <= 1.0):
            continue
        cos_a = -dn
        att = _area_spread(ar, k, cos_a)
        wgt = 1.0
        if use_mis and not bsdf_delta:
            # the pdf with which the sampler produces this direction from o: same formulas, same inputs
            pdf = t * t / (ar[k, AR_AREA] * cos_a)
            if ar[k, AR_ELLIPSE] == 0.0:
                S = _rect_frame(ar, k, ox, oy, oz)[8]
                if S > _RECT_MIN_SOLID_ANGLE:
                    pdf = 1.0 / S
            pl = _f32(ar[k, AR_SEL] * pdf)
            if need_prob:
                pl, have_prob = _times_selection(pl, np.int64(ar[k, AR_UNIT]), have_prob, ox, oy, oz, nx, ny, nz,
                                                 has_n, transmits, lt, buf)
            wgt = _mis_power(bsdf_pdf, pl)
        er += _f32(_f32(ar[k, AR_R] * att) * wgt)
        eg += _f32(_f32(ar[k, AR_G] * att) * wgt)
        eb += _f32(_f32(ar[k, AR_B] * att) * wgt)
    if not math.isinf(tmax):
        return er, eg, eb
    # ---- escaped: sun discs and the world
    for k in range(su.shape[0]):
        omc = su[k, SU_OMC]
        if omc <= 0.0 or not (su[k, SU_CAM] != 0.0 or not camera):
            continue
        if not _f32(su[k, SU_DX] * dx + su[k, SU_DY] * dy + su[k, SU_DZ] * dz) >= su[k, SU_COS_HALF]:
            continue
        wgt = 1.0
        if use_mis and not bsdf_delta:
            pl = _f32(su[k, SU_SEL] / (_TWO_PI * omc))
            if need_prob:
                pl, have_prob = _times_selection(pl, np.int64(su[k, SU_UNIT]), have_prob, ox, oy, oz, nx, ny, nz,
                                                 has_n, transmits, lt, buf)
            wgt = _mis_power(bsdf_pdf, pl)
        er += _f32(su[k, SU_R] * wgt)
        eg += _f32(su[k, SU_G] * wgt)
        eb += _f32(su[k, SU_B] * wgt)
    if w[W_LIT] != 0.0:
        has_map = w[W_MAP] != 0.0
        if has_map:
            wr, wg, wb = env_radiance(lt[21], lt[22], dx, dy, dz)
        else:
            wr, wg, wb = w[W_R], w[W_G], w[W_B]
        wgt = 1.0
        if use_mis and not bsdf_delta:
            if lt[26].shape[0] > 0 and portals_facing(lt[26], ox, oy, oz) > 0:
                pl = _f32(w[W_SEL] * _world_pdf(ox, oy, oz, nx, ny, nz, has_n, dx, dy, dz, lt))
            elif has_map:
                pl = _f32(w[W_SEL] * env_pdf(lt[23], dx, dy, dz))
            elif has_n:
                pl = _f32(_f32(w[W_SEL] * _INV_PI) * _f32(max(dx * nx + dy * ny + dz * nz, 0.0)))
            else:
                pl = _f32(w[W_SEL] * _INV_4PI)
            if need_prob:
                pl, have_prob = _times_selection(pl, np.int64(w[W_UNIT]), have_prob, ox, oy, oz, nx, ny, nz,
                                                 has_n, transmits, lt, buf)
            wgt = _mis_power(bsdf_pdf, pl)
        er += _f32(wr * wgt)
        eg += _f32(wg * wgt)
        eb += _f32(wb * wgt)
    return er, eg, eb


@_jit
def emission_batch(o, d, tmax, bsdf_pdf, bsdf_delta, use_mis, n, has_n, transmits, has_t, camera, per_point, lt,
                   buf, out):
    """light_emission_path for every ray: o, d, n (N, 3) float32, tmax, bsdf_pdf (N,) float32, bsdf_delta (N,)
    bool (both unused unless use_mis); out (N, 3) float32."""
    for i in range(o.shape[0]):
        nx = ny = nz = 0.0
        if has_n:
            nx, ny, nz = np.float64(n[i, 0]), np.float64(n[i, 1]), np.float64(n[i, 2])
        pb = 0.0
        de = False
        if use_mis:
            pb = np.float64(bsdf_pdf[i])
            de = bsdf_delta[i]
        er, eg, eb = light_emission_path(
            np.float64(o[i, 0]), np.float64(o[i, 1]), np.float64(o[i, 2]), np.float64(d[i, 0]),
            np.float64(d[i, 1]), np.float64(d[i, 2]), np.float64(tmax[i]), pb, de, use_mis, nx, ny, nz, has_n,
            has_t and transmits[i], camera, per_point, lt, buf)
        out[i, 0], out[i, 1], out[i, 2] = er, eg, eb


@_jit
def triangle_pdf_batch(emitter, o, dist2, cos_l, n, has_n, transmits, has_t, per_point, lt, buf, out):
    """out[i]: the solid-angle pdf (selection included) with which the sampler produces the point of emitter
    emitter[i] hit by a ray from o[i] at squared distance dist2[i] with |cos| cos_l[i]; 0 where the emitter is
    -1, the cosine 0 or the pdf not finite."""
    for i in range(o.shape[0]):
        e = emitter[i]
        cl = np.float64(cos_l[i])
        if e < 0 or not cl > 0.0:
            out[i] = 0.0
            continue
        ox, oy, oz = np.float64(o[i, 0]), np.float64(o[i, 1]), np.float64(o[i, 2])
        pdf = triangle_pdf_path(e, ox, oy, oz, np.float64(dist2[i]), cl, lt)
        if per_point:
            nx = ny = nz = 0.0
            if has_n:
                nx, ny, nz = np.float64(n[i, 0]), np.float64(n[i, 1]), np.float64(n[i, 2])
            probabilities_at(ox, oy, oz, nx, ny, nz, has_n, has_t and transmits[i], lt[0], lt[1], lt[3], lt[4],
                             buf)
            unit = lt[20][e]
            pdf *= buf[unit] if unit >= 0 else 0.0
        out[i] = pdf if math.isfinite(pdf) else 0.0
