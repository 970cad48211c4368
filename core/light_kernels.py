"""Compiled (numba) kernels of per-shading-point light selection: the importance of each selectable light unit at
a point, the selection probabilities they give, and the pick itself (see core.lights' module docstring for the
heuristic and its conventions).

The unit table is one float64 array (K, UNIT_FIELDS) plus an int64 kind per unit; positions are in the
integrator's shifted frame (as every position core.lights handles). Points p and normals n arrive component-major
(3, N) float32, as core.lights keeps them. One function, `_probabilities`, computes a point's probabilities for
both `select` (light sampling) and `probability` (the light pdf of a BSDF-sampled direction, for MIS): the two must
agree exactly, or MIS weights are biased.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy", boundscheck=False)

# unit kinds
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


@numba.njit(cache=True, nogil=True, error_model="numpy", boundscheck=False, inline="always")
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


@_jit
def _probabilities(i, p, n, has_n, transmits, has_t, table, kinds, fallback, floor_weight, out):
    """Selection probability of every unit at point i into out (K,): (1 - floor_weight) x importance share +
    floor_weight x power share among the units that are not provably zero there; `fallback` (the power shares)
    where no unit is alive."""
    K = kinds.shape[0]
    px, py, pz = np.float64(p[0, i]), np.float64(p[1, i]), np.float64(p[2, i])
    nx = ny = nz = 0.0
    if has_n:
        nx, ny, nz = np.float64(n[0, i]), np.float64(n[1, i]), np.float64(n[2, i])
    tr = has_t and transmits[i]
    total_imp = 0.0
    total_pow = 0.0
    for k in range(K):
        imp, alive = _importance(table, k, kinds[k], px, py, pz, nx, ny, nz, has_n, tr)
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


@_jit
def select(p, n, has_n, transmits, has_t, u, table, kinds, fallback, floor_weight, unit, prob, u_rest):
    """Pick a unit for each point p[:, i] with probability from `_probabilities`, by u[i] in [0, 1).

    unit[i]: the unit; prob[i]: its probability; u_rest[i]: u rescaled to [0, 1) within the unit's share (for a
    second choice inside the unit, e.g. a triangle of a group)."""
    K = kinds.shape[0]
    buf = np.empty(K)
    for i in range(p.shape[1]):
        _probabilities(i, p, n, has_n, transmits, has_t, table, kinds, fallback, floor_weight, buf)
        x = np.float64(u[i])
        acc = 0.0
        before = 0.0
        chosen = -1
        for k in range(K):
            pk = buf[k]
            if pk <= 0.0:
                continue
            chosen = k
            before = acc
            acc += pk
            if x < acc:
                break
        if chosen < 0:
            unit[i] = 0
            prob[i] = 0.0
            u_rest[i] = 0.0
            continue
        pk = buf[chosen]
        unit[i] = chosen
        prob[i] = pk
        u_rest[i] = min(max((x - before) / pk, 0.0), 0.99999994)


@_jit
def probability(p, n, has_n, transmits, has_t, which, table, kinds, fallback, floor_weight, prob):
    """prob[i] = the probability with which `select` picks unit which[i] at point p[:, i] (0 where which < 0)."""
    K = kinds.shape[0]
    buf = np.empty(K)
    for i in range(p.shape[1]):
        k = which[i]
        if k < 0:
            prob[i] = 0.0
            continue
        _probabilities(i, p, n, has_n, transmits, has_t, table, kinds, fallback, floor_weight, buf)
        prob[i] = buf[k]
