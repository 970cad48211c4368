"""Compiled (numba) BSDF evaluation and sampling, material gathering and texture lookup.

Profiling the Cornell box showed ~20% of render time in the NumPy BSDF code: dozens of small array operations
per lobe kind, each streaming every path's arrays through memory again, plus fancy-index copies of the lobe
arrays. Here each path is one pass of scalar code.

Layout: scalar per-path device functions (`eval_path`, `sample_path`, the GGX and Fresnel helpers, the table
lookups) that a fused per-bounce kernel can call, and batch kernels looping over paths (`eval_batch`,
`sample_batch`, `albedo_batch`, `gather_batch`, `texture_batch`, `selection_batch`). The model, the frame and
weight conventions are documented in core.bsdf and core.microfacet; this module only implements them.

Arguments shared by the kernels:
  lobes = (kind (N, L) int8, weight (N, L, 3) float32, roughness (N, L) float32, ior (N, L) float32,
           fresnel (N, L) int8, select (N, L) float32, f0 (N, L, 3) float32, under (N, L) int8,
           tint (N, L, 2, 3) float32, diffuse_normal (N, 3) or (0, 3) float32)  -- a LobeBatch's arrays,
           C-contiguous. f0: reflectance at normal incidence
           of a generalized-Schlick glossy or glass lobe; under: slot of the generalized-Schlick glossy lobe this
           lobe lies beneath (-1: none), see `layer_factor`; tint: reflection [0] and transmission [1] tints of a
           glass lobe, see `glass_fresnel`.
  diffuse_normal: the diffuse lobes' normal in the hit's local frame (see `diffuse_axis`); (0, 3): +z for all.
  tabs = (ggx_E (32, 32), ggx_Eavg (32,), glass_E2 (2, 16, 16, 16), glass_Eavg2 (2, 16, 16),
          gen_schlick_s (16, 16, 16)) float32: the tables of core.microfacet.tables().
  row: which hit of `lobes` a path reads (lets callers evaluate a subset without copying the lobe arrays).
Arithmetic is float64 (inputs and outputs are float32), so results agree with the former float32 NumPy code to its
rounding; lobe selection and texture filtering stay float32 (bit-identical selection probabilities, cdf and
texels), and a sampled direction is rounded to float32 before the mixture is evaluated there, so a sample's pdf is
the pdf `eval_path` gives for the direction returned.
"""

from __future__ import annotations

import math

import numpy as np

# No NRT reference counting (these kernels never allocate), device functions taking arrays inlined: core.jit_cache.
from .jit_cache import jit_inline as _inline
from .jit_cache import jit_no_nrt as _jit
from .warps import sample_cos_hemisphere_local

# lobe kinds and glossy Fresnel modes (core.bsdf re-exports these)
EMPTY, DIFFUSE, GLOSSY, GLASS, REFRACTION = -1, 0, 1, 2, 3
F_NONE, F_SCHLICK, F_DIELECTRIC, F_GEN_SCHLICK = 0, 1, 2, 3
# microfacet configurations a lobe admits
_REFLECT, _TRANSMIT, _BOTH = 0, 1, 2

_INV_PI = 1.0 / math.pi
_F32_0 = np.float32(0.0)
_F32_1 = np.float32(1.0)
_F32_HALF = np.float32(0.5)
_F32_TINY = np.float32(1e-30)
_F32_BELOW_1 = np.float32(0.99999994)  # largest float32 below 1


# ------------------------------------------------------------------------------------------------ Fresnel
@_jit
def fresnel_dielectric(cos_i, eta):
    """Exact unpolarised dielectric Fresnel reflectance; cos_i on the incident side (its sign is ignored),
    eta = n_transmitted / n_incident. 1 under total internal reflection."""
    c = abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    if not g2 > 0.0:
        return 1.0
    g = math.sqrt(g2)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    f = 0.5 * a * a * (1.0 + b * b)
    return f if f == f else 0.0


@_jit
def schlick_f0(ior):
    r = (ior - 1.0) / (ior + 1.0)
    return r * r


@_jit
def fresnel_schlick(cos_i, f0):
    """Schlick's approximation F0 + (1 - F0)(1 - cos)^5."""
    m = min(max(1.0 - cos_i, 0.0), 1.0)
    m2 = m * m
    return f0 + (1.0 - f0) * (m2 * m2 * m)


@_jit
def fresnel_dielectric_avg(eta):
    """Cosine-weighted hemispherical average of the dielectric Fresnel, Kulla & Conty 2017's fit (as Cycles)."""
    if eta < 1.0:
        v = 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607))
    else:
        v = (eta - 1.0) / (4.08567 + 1.00071 * eta)
    return min(max(v, 0.0), 1.0)


@_jit
def glossy_fresnel(mode, ior, cos_oh):
    """Fresnel factor of a glossy lobe at wo.h."""
    if mode == F_SCHLICK:
        return fresnel_schlick(cos_oh, schlick_f0(ior))
    if mode == F_DIELECTRIC:
        return fresnel_dielectric(cos_oh, ior)
    return 1.0


@_jit
def glossy_fresnel_avg(mode, ior):
    """wo-independent albedo estimate of a glossy lobe relative to its colour: 1, the Schlick average
    F0 + (1 - F0)/21 (2 int_0^1 mu (1 - mu)^5 dmu = 1/21) or the dielectric average. Used for lobe selection,
    the multiscatter Fss and the albedo AOV."""
    if mode == F_SCHLICK:
        f0 = schlick_f0(ior)
        return f0 + (1.0 - f0) / 21.0
    if mode == F_DIELECTRIC:
        return fresnel_dielectric_avg(ior)
    return 1.0


@_jit
def gen_schlick_s(cos_i, eta):
    """Cycles' generalized Schlick with a negative exponent: the real dielectric Fresnel at cos_i remapped from
    [F0(eta), 1] to [0, 1]; the lobe's Fresnel is then f0 + (1 - f0) s per channel (f90 = 1)."""
    f0r = schlick_f0(eta)
    if not f0r < 1.0:
        return 1.0
    return min(max((fresnel_dielectric(cos_i, eta) - f0r) / (1.0 - f0r), 0.0), 1.0)


@_jit
def gen_schlick_s_avg(eta):
    """The remap factor of the Kulla-Conty dielectric Fresnel average: Cycles' Fss = f0 + (1 - f0) s_avg of a
    generalized-Schlick lobe (multiscatter tint, lobe selection)."""
    f0r = schlick_f0(eta)
    if not f0r < 1.0:
        return 1.0
    return min(max((fresnel_dielectric_avg(eta) - f0r) / (1.0 - f0r), 0.0), 1.0)


# -------------------------------------------------------------------------------------------------- GGX
@_jit
def ggx_lambda(alpha2, cos_w):
    """Smith Lambda for GGX; +inf at grazing (cos_w = 0)."""
    c2 = cos_w * cos_w
    tan2 = max((1.0 - c2) / c2, 0.0) if c2 > 0.0 else math.inf
    return 0.5 * (math.sqrt(1.0 + alpha2 * tan2) - 1.0)


@_jit
def sample_vndf(ox, oy, oz, alpha, u1, u2):
    """GGX visible-normal sample h (hz >= 0) for wo (oz > 0): the spherical-cap mapping of Dupuy & Benyoub 2023."""
    vx = alpha * ox
    vy = alpha * oy
    inv = 1.0 / math.sqrt(vx * vx + vy * vy + oz * oz)
    vx *= inv
    vy *= inv
    vz = oz * inv
    phi = 2.0 * math.pi * u1
    z = (1.0 - u2) * (1.0 + vz) - vz
    s = math.sqrt(min(max(1.0 - z * z, 0.0), 1.0))
    hx = (s * math.cos(phi) + vx) * alpha
    hy = (s * math.sin(phi) + vy) * alpha
    hz = max(z + vz, 0.0)
    inv = 1.0 / max(math.sqrt(hx * hx + hy * hy + hz * hz), 1e-30)
    return hx * inv, hy * inv, hz * inv


@_jit
def refract(ox, oy, oz, hx, hy, hz, eta):
    """Refract wo (wo.h > 0) through microfacet h, eta = n_t / n_i: (ix, iy, iz, total internal reflection)."""
    c = ox * hx + oy * hy + oz * hz
    inv_eta = 1.0 / eta
    s2t = (1.0 - c * c) * (inv_eta * inv_eta)
    tir = s2t >= 1.0
    ct = math.sqrt(max(1.0 - s2t, 0.0))
    k = c * inv_eta - ct
    return -ox * inv_eta + k * hx, -oy * inv_eta + k * hy, -oz * inv_eta + k * hz, tir


@_jit
def microfacet_eval(alpha, eta, ox, oy, oz, ix, iy, iz, which):
    """Single-scatter GGX terms without Fresnel for wo (oz > 0) and wi: (f |cos wi| / Fresnel, pdf of VNDF
    sampling + reflection/refraction at h, wo.h, wi is a reflection). Reflection when iz > 0
    (h = normalize(wo + wi)), transmission when iz < 0 (h = -normalize(wo + eta wi) oriented to +z);
    which: _REFLECT / _TRANSMIT (the other configuration gives 0) or _BOTH. See core.microfacet.
    A transmission pair is evaluated as Cycles' bsdf_microfacet_eval does: without checking that it is a physical
    refraction (wo and wi on the two sides of the microfacet h, which also bounds the angle between wi and the
    straight-through direction); wo.h and wi.h enter as absolute values. Sampling never produces such pairs, so
    only next-event estimation sees them (and, as in Cycles, its MIS weight uses the pdf given here); where h
    makes wo.h total internal reflection the caller zeroes the pair (glass: its Fresnel; refraction: `eval_path`)."""
    reflect = iz > 0.0
    if which == _REFLECT:
        hx, hy, hz = ox + ix, oy + iy, oz + iz
    else:
        e = eta if (which == _TRANSMIT or not reflect) else 1.0
        hx, hy, hz = e * ix + ox, e * iy + oy, e * iz + oz
    hl = max(math.sqrt(hx * hx + hy * hy + hz * hz), 1e-30)
    if which != _REFLECT and hz < 0.0:
        hl = -hl
    hx, hy, hz = hx / hl, hy / hl, hz / hl
    cos_oh = ox * hx + oy * hy + oz * hz
    cos_ih = ix * hx + iy * hy + iz * hz
    transmission = which == _TRANSMIT or (which == _BOTH and not reflect)
    ok = oz > 0.0 and (cos_oh > 0.0 or (transmission and cos_oh != 0.0))
    if not ok:
        return 0.0, 0.0, cos_oh, reflect
    cos_oh = abs(cos_oh)  # Cycles' Fresnel takes |wo.h|; equal to wo.h for every physical pair
    alpha2 = alpha * alpha
    t = 1.0 + (alpha2 - 1.0) * (hz * hz)
    d = alpha2 * _INV_PI / (t * t)
    g1 = ggx_lambda(alpha2, oz) + 1.0
    g2 = ggx_lambda(alpha2, iz) + g1
    if which == _REFLECT or (which == _BOTH and reflect):
        ok = reflect and cos_ih > 0.0
        d = d * 0.25 / oz
    else:
        ok = iz < 0.0
        den = eta * cos_ih + ox * hx + oy * hy + oz * hz  # (eta wi + wo).h = +-|eta wi + wo|
        d = d * (eta * eta) * abs(cos_oh * cos_ih) / (den * den * oz)
    if not (ok and math.isfinite(d)):
        return 0.0, 0.0, cos_oh, reflect
    return d / g2, d / g1, cos_oh, reflect


# --------------------------------------------------------------------------------- multiscatter tables
@_jit
def _grid(x, n):
    """Cell index (<= n - 2) and fraction of x in [0, 1] on the grid i / (n - 1)."""
    x = min(max(x, 0.0), 1.0) * (n - 1)
    i = min(int(x), n - 2)
    return i, x - i


@_inline
def ggx_E(tabs, rough, mu):
    """Directional albedo of the white single-scatter GGX reflection lobe, bilinear in (roughness, cos wo)."""
    t = tabs[0]
    n = t.shape[0]
    ir, fr = _grid(rough, n)
    im, fm = _grid(mu, n)
    a = t[im, ir] * (1.0 - fr) + t[im, ir + 1] * fr
    b = t[im + 1, ir] * (1.0 - fr) + t[im + 1, ir + 1] * fr
    return a * (1.0 - fm) + b * fm


@_inline
def ggx_Eavg(tabs, rough):
    t = tabs[1]
    ir, fr = _grid(rough, t.shape[0])
    return t[ir] * (1.0 - fr) + t[ir + 1] * fr


@_jit
def _glass_axes(eta):
    """Stacked-table index (0: entering, eta > 1; 1: leaving) and the IOR axis z = sqrt(|eta - 1| / (eta + 1))."""
    return (1 if eta < 1.0 else 0), math.sqrt(abs((eta - 1.0) / (eta + 1.0)))


@_inline
def _read3(t, rough, mu, z):
    """Trilinear read of a (z, mu, rough) table on the grid i / (n - 1) (Cycles' lookup_table_read_3D)."""
    n = t.shape[0]
    ir, fr = _grid(rough, t.shape[2])
    im, fm = _grid(mu, t.shape[1])
    iz, fz = _grid(z, n)
    out = 0.0
    for cz in range(2):
        wz = fz if cz else 1.0 - fz
        for cm in range(2):
            wm = fm if cm else 1.0 - fm
            row = t[iz + cz, im + cm]
            out += wz * wm * (row[ir] * (1.0 - fr) + row[ir + 1] * fr)
    return out


@_inline
def glass_E(tabs, rough, mu, eta):
    """Directional albedo (R + T) of the white single-scatter GGX glass lobe, trilinear in (roughness, cos, z)."""
    s, z = _glass_axes(eta)
    return _read3(tabs[2][s], rough, mu, z)


@_inline
def gen_schlick_table_s(tabs, rough, mu, eta):
    """Cycles' ggx_gen_schlick_ior_s(roughness, cos wo, z = F0(eta)^(1/4)): the VNDF average of `gen_schlick_s`
    at h.wo over valid reflections, trilinear."""
    return _read3(tabs[4], rough, mu, math.sqrt(abs((eta - 1.0) / (eta + 1.0))))


@_inline
def glass_Eavg(tabs, rough, eta):
    t = tabs[3]
    n = t.shape[1]
    s, z = _glass_axes(eta)
    ir, fr = _grid(rough, n)
    iz, fz = _grid(z, n)
    a = t[s, iz, ir] * (1.0 - fr) + t[s, iz, ir + 1] * fr
    b = t[s, iz + 1, ir] * (1.0 - fr) + t[s, iz + 1, ir + 1] * fr
    return a * (1.0 - fz) + b * fz


@_jit
def ggx_E_batch(tabs, rough, mu, out):
    for k in range(out.shape[0]):
        out[k] = ggx_E(tabs, rough[k], mu[k])


@_jit
def ggx_Eavg_batch(tabs, rough, out):
    for k in range(out.shape[0]):
        out[k] = ggx_Eavg(tabs, rough[k])


@_jit
def multiscatter_tint(E, Eavg, fss):
    """Cycles' energy preservation for one channel: 1 + Fms (1 - E)/E, Fms = Fss Eavg / (1 - Fss (1 - Eavg));
    1/E for Fss = 1."""
    E = max(E, 1e-4)
    fss = min(max(fss, 0.0), 1.0)
    fms = fss * Eavg / max(fss * (Eavg - 1.0) + 1.0, 1e-6)
    return 1.0 + fms * ((1.0 - E) / E)


@_inline
def _layer_terms(lobes, row, j, multiscatter, tabs, mu):
    """Channel-independent terms of the generalized-Schlick lobe j's albedo estimate at cos wo = mu:
    (s from the table, E, Eavg, s_avg of Fss)."""
    r = np.float64(lobes[2][row, j])
    eta = np.float64(lobes[3][row, j])
    s = gen_schlick_table_s(tabs, r, mu, eta)
    if not multiscatter:
        return s, 1.0, 1.0, 1.0
    return s, max(ggx_E(tabs, r, mu), 1e-4), ggx_Eavg(tabs, r), gen_schlick_s_avg(eta)


@_jit
def _layer_albedo(f0c, s, E, Eavg, sa, multiscatter):
    """One channel of the layer's albedo estimate relative to its colour: (E + Fms (1 - E)) (f0 + (1 - f0) s)
    with the multiscatter darkening (Fss = f0 + (1 - f0) s_avg; none when Fss = 1), f0 + (1 - f0) s without."""
    est = f0c + (1.0 - f0c) * s
    if not multiscatter:
        return est
    fss = f0c + (1.0 - f0c) * sa
    if fss >= 1.0:
        return est
    return E * multiscatter_tint(E, Eavg, fss) * est


@_inline
def gen_schlick_albedo(lobes, row, j, multiscatter, tabs, mu, c):
    """Cycles' albedo estimate of the generalized-Schlick glossy lobe in slot j, channel c, relative to its colour,
    seen from cos wo = mu (bsdf_microfacet_estimate_albedo x microfacet_ggx_preserve_energy's weight)."""
    s, E, Eavg, sa = _layer_terms(lobes, row, j, multiscatter, tabs, mu)
    return _layer_albedo(np.float64(lobes[6][row, j, c]), s, E, Eavg, sa, multiscatter)


@_inline
def layer_factor(lobes, row, j, multiscatter, tabs, mu):
    """Weight factor of a lobe lying under the generalized-Schlick glossy lobe in slot j, seen from cos wo = mu:
    saturate(1 - max_c albedo_c / colour_c) (Cycles' closure_layering_weight; channels of zero colour count 0)."""
    weight = lobes[1]
    f0 = lobes[6]
    s, E, Eavg, sa = _layer_terms(lobes, row, j, multiscatter, tabs, mu)
    m = 0.0
    for c in range(3):
        if weight[row, j, c] > 0.0:
            m = max(m, _layer_albedo(np.float64(f0[row, j, c]), s, E, Eavg, sa, multiscatter))
    return min(max(1.0 - m, 0.0), 1.0)


# ------------------------------------------------------------------------------------------------ lobes
@_jit
def _relative_ior(ior_f32, back):
    """eta = n_other_side / n_wo_side of a glass / refraction lobe: ior entering, 1/ior leaving (rounded to
    float32, as the lobe arrays are)."""
    return np.float64(np.float32(_F32_1 / ior_f32) if back else ior_f32)


@_inline
def glass_tinted(lobes, row, l):
    """Whether glass lobe l takes the tinted path (`glass_fresnel`): generalized-Schlick Fresnel or a reflection or
    transmission tint other than white. A plain white-tinted glass keeps the untinted arithmetic (bit-identical
    to the Glass BSDF before tints existed)."""
    if lobes[4][row, l] == F_GEN_SCHLICK:
        return True
    tint = lobes[8]
    for i in range(2):
        for c in range(3):
            if tint[row, l, i, c] != _F32_1:
                return True
    return False


@_inline
def glass_fresnel(lobes, row, l, cos_oh, eta):
    """Reflectance R_c and transmittance T_c per channel of glass lobe l at wo.h = cos_oh (eta: relative IOR):
    R_c = F_c x reflection tint_c, T_c = (1 - F_c) x transmission tint_c, with F_c = f0_c + (1 - f0_c) s
    (generalized Schlick, s the dielectric Fresnel of eta remapped from [F0(eta), 1] to [0, 1]; 1 under total
    internal reflection) or the exact dielectric Fresnel. Cycles' glass closure (bsdf_microfacet.h); the lobe
    colour multiplies both on top. Returns (R0, R1, R2, T0, T1, T2)."""
    tint = lobes[8]
    f0s = lobes[6]
    if lobes[4][row, l] == F_GEN_SCHLICK:
        sv = gen_schlick_s(cos_oh, eta)
        g0 = np.float64(f0s[row, l, 0])
        g1 = np.float64(f0s[row, l, 1])
        g2 = np.float64(f0s[row, l, 2])
        F0 = g0 + (1.0 - g0) * sv
        F1 = g1 + (1.0 - g1) * sv
        F2 = g2 + (1.0 - g2) * sv
    else:
        F0 = F1 = F2 = fresnel_dielectric(cos_oh, eta)
    return (F0 * tint[row, l, 0, 0], F1 * tint[row, l, 0, 1], F2 * tint[row, l, 0, 2],
            (1.0 - F0) * tint[row, l, 1, 0], (1.0 - F1) * tint[row, l, 1, 1], (1.0 - F2) * tint[row, l, 1, 2])


@_jit
def _reflect_probability(R0, R1, R2, T0, T1, T2):
    """Probability of choosing reflection at a tinted glass microfacet: mean R / mean (R + T) (Cycles'
    pdf_reflect); -1 when both vanish (no valid sample)."""
    r = R0 + R1 + R2
    t = T0 + T1 + T2
    return r / (r + t) if r + t > 0.0 else -1.0


@_inline
def glass_fss(lobes, row, l, eta):
    """Multiscatter Fss of a tinted glass lobe per channel (Cycles' setup_fresnel_generalized_schlick: the
    transmission tint when it is not black, else the reflection tint x the Fresnel average). For a plain glass the
    lobe colour is part of the tint (the Glass BSDF's colour is its tint in Cycles); a generalized-Schlick lobe's
    colour is the closure weight and is not."""
    tint = lobes[8]
    weight = lobes[1]
    gen = lobes[4][row, l] == F_GEN_SCHLICK
    t0 = np.float64(tint[row, l, 1, 0])
    t1 = np.float64(tint[row, l, 1, 1])
    t2 = np.float64(tint[row, l, 1, 2])
    if not gen:
        t0 *= weight[row, l, 0]
        t1 *= weight[row, l, 1]
        t2 *= weight[row, l, 2]
    if t0 > 0.0 or t1 > 0.0 or t2 > 0.0:
        return t0, t1, t2
    r0 = np.float64(tint[row, l, 0, 0])
    r1 = np.float64(tint[row, l, 0, 1])
    r2 = np.float64(tint[row, l, 0, 2])
    if gen:
        sa = gen_schlick_s_avg(eta)
        f0s = lobes[6]
        g0 = np.float64(f0s[row, l, 0])
        g1 = np.float64(f0s[row, l, 1])
        g2 = np.float64(f0s[row, l, 2])
        return r0 * (g0 + (1.0 - g0) * sa), r1 * (g1 + (1.0 - g1) * sa), r2 * (g2 + (1.0 - g2) * sa)
    fa = fresnel_dielectric_avg(eta)
    return r0 * weight[row, l, 0] * fa, r1 * weight[row, l, 1] * fa, r2 * weight[row, l, 2] * fa


@_inline
def diffuse_axis(lobes, row, back):
    """The diffuse lobes' normal of hit `row` in the frame flipped to wo's geometric side (`back`): the shading
    normal before Cycles' specular-validity tilt, which only the microfacet lobes get (the frame's z is the tilted
    normal); (0, 0, 1) where the hit has none or nothing was tilted."""
    dn = lobes[9]
    if dn.shape[0] == 0:
        return 0.0, 0.0, 1.0
    dx = np.float64(dn[row, 0])
    dy = np.float64(dn[row, 1])
    dz = np.float64(dn[row, 2])
    if back:  # the flip z -> -z of the frame turns the normal on the viewer's side into (-x, -y, z)
        return -dx, -dy, dz
    return dx, dy, dz


@_inline
def eval_path(lobes, row, multiscatter, tabs, ox, oy, oz, back, ix, iy, iz):
    """f |cos wi| (3 channels) and the mixture pdf over the non-delta lobes of hit `row`, in the frame flipped to
    wo's geometric side (`back`: wo was below the surface); (f0, f1, f2, pdf). oz < 0 (wo below a smooth shading
    normal on that side) leaves the diffuse lobe as it is (Cycles' max(N.wi, 0) / pi) and the microfacet lobes
    zero. A lobe with under >= 0 is scaled by
    `layer_factor` at cos wo (its value only: the pdf stays select x lobe pdf). Diffuse lobes take their cosine
    about `diffuse_axis`."""
    kind, weight, rough, ior, fresnel, select, f0s, under, tint, dnorm = lobes
    dx, dy, dz = diffuse_axis(lobes, row, back)
    cos_d = ix * dx + iy * dy + iz * dz  # = iz exactly for the axis (0, 0, 1)
    f0 = f1 = f2 = pdf = 0.0
    for l in range(kind.shape[1]):
        k = kind[row, l]
        if k == DIFFUSE:
            c = max(cos_d, 0.0) * _INV_PI
            pdf += select[row, l] * c
            j = under[row, l]
            if j >= 0:
                c *= layer_factor(lobes, row, j, multiscatter, tabs, oz)
            f0 += weight[row, l, 0] * c
            f1 += weight[row, l, 1] * c
            f2 += weight[row, l, 2] * c
            continue
        r = np.float64(rough[row, l])
        if k < GLOSSY or not r > 0.0:  # empty slot or delta lobe
            continue
        lobe_ior = np.float64(ior[row, l])
        if k == GLOSSY:
            eta = 1.0
            which = _REFLECT
        else:
            eta = _relative_ior(ior[row, l], back)
            which = _BOTH if k == GLASS else _TRANSMIT
        fc, p, cos_oh, refl = microfacet_eval(r * r, eta, ox, oy, oz, ix, iy, iz, which)
        if p == 0.0 and fc == 0.0:
            continue
        mode = fresnel[row, l]
        c0 = np.float64(weight[row, l, 0])
        c1 = np.float64(weight[row, l, 1])
        c2 = np.float64(weight[row, l, 2])
        # per-channel Fresnel (generalized Schlick) and multiscatter Fss
        fr0 = fr1 = fr2 = 1.0
        if k == GLOSSY and mode == F_GEN_SCHLICK:
            sv = gen_schlick_s(cos_oh, lobe_ior)
            g0 = np.float64(f0s[row, l, 0])
            g1 = np.float64(f0s[row, l, 1])
            g2 = np.float64(f0s[row, l, 2])
            fr0, fr1, fr2 = g0 + (1.0 - g0) * sv, g1 + (1.0 - g1) * sv, g2 + (1.0 - g2) * sv
            sa = gen_schlick_s_avg(lobe_ior)
            fss0, fss1, fss2 = g0 + (1.0 - g0) * sa, g1 + (1.0 - g1) * sa, g2 + (1.0 - g2) * sa
        elif k == GLOSSY:
            fc *= glossy_fresnel(mode, lobe_ior, cos_oh)
            scale = glossy_fresnel_avg(mode, lobe_ior)  # Fss: colour x Fresnel average
            fss0, fss1, fss2 = c0 * scale, c1 * scale, c2 * scale
        elif k == GLASS and glass_tinted(lobes, row, l):
            R0, R1, R2, T0, T1, T2 = glass_fresnel(lobes, row, l, cos_oh, eta)
            pr = _reflect_probability(R0, R1, R2, T0, T1, T2)
            if not pr >= 0.0:
                continue
            if refl:
                fr0, fr1, fr2 = R0, R1, R2
                p *= pr
            else:
                fr0, fr1, fr2 = T0, T1, T2
                p *= 1.0 - pr
            fss0, fss1, fss2 = glass_fss(lobes, row, l, eta)
        else:
            if k == GLASS:
                F = fresnel_dielectric(cos_oh, eta)
                fr = F if refl else 1.0 - F
                fc *= fr
                p *= fr
            elif fresnel_dielectric(cos_oh, eta) >= 1.0:
                continue  # refraction: a pair whose microfacet totally reflects wo transmits nothing (Cycles)
            # glass: Fss is the transmission tint (the colour); refraction: transmission only, no Fresnel factor
            # and no compensation (Cycles' Refraction BSDF)
            fss0, fss1, fss2 = c0, c1, c2
        j = under[row, l]
        if j >= 0:
            fc *= layer_factor(lobes, row, j, multiscatter, tabs, oz)
        if multiscatter and k != REFRACTION:
            if k == GLOSSY:
                E = ggx_E(tabs, r, oz)
                Eavg = ggx_Eavg(tabs, r)
            else:
                E = glass_E(tabs, r, oz, eta)
                Eavg = glass_Eavg(tabs, r, eta)
            f0 += c0 * fr0 * multiscatter_tint(E, Eavg, fss0) * fc
            f1 += c1 * fr1 * multiscatter_tint(E, Eavg, fss1) * fc
            f2 += c2 * fr2 * multiscatter_tint(E, Eavg, fss2) * fc
        else:
            f0 += c0 * fr0 * fc
            f1 += c1 * fr1 * fc
            f2 += c2 * fr2 * fc
        pdf += select[row, l] * p
    return f0, f1, f2, pdf


@_inline
def _choose_lobe(kind, select, row, u_lobe):
    """Lobe slot picked by u_lobe with the select probabilities (-1: none), its probability and the remainder of
    u_lobe rescaled to [0, 1) (float32 arithmetic, as the NumPy cumsum selection it replaces)."""
    L = kind.shape[1]
    if L == 1:
        s = select[row, 0]
        return (0 if s > _F32_0 else -1), s, u_lobe
    cdf = _F32_0
    chosen = 0
    last = -1
    for l in range(L):
        s = select[row, l]
        cdf = np.float32(cdf + s)
        if cdf <= u_lobe:
            chosen += 1
        if s > _F32_0:
            last = l
    if last < 0:
        return -1, _F32_0, u_lobe
    chosen = min(chosen, last)
    cdf = _F32_0
    for l in range(chosen + 1):
        cdf = np.float32(cdf + select[row, l])
    s = select[row, chosen]
    u_rem = np.float32(np.float32(u_lobe - np.float32(cdf - s)) / max(s, _F32_TINY))
    return chosen, s, min(max(u_rem, _F32_0), _F32_BELOW_1)


@_inline
def sample_path(lobes, row, multiscatter, tabs, wox, woy, woz, back, u_event, u1, u2):
    """Sample wi for hit `row` seen from wo (local frame, unflipped): pick a lobe with `select` by u1, rescale u1
    within the chosen lobe's interval and sample its direction with (u1 rescaled, u2); u_event chooses reflection
    vs refraction for glass. (The lobe choice takes the direction's own number, as Cycles 3.x did, so each lobe's
    directions keep the 2-D stratification of (u1, u2): picked with a third number, the samples that land in one
    lobe's interval are a coarsely stratified subset of the pairs, and a multi-lobe material's variance per sample
    fell more slowly with the sample count. A single-lobe material gets u1 unchanged.)
    back: wo is on the -z side of the surface as the geometric normal decides it (core.bsdf: the lobes act in
    the frame flipped to that side even where wo is below the shading normal there).
    Returns (wix, wiy, wiz, weight0, weight1, weight2, pdf, delta, transmitted, valid); wi is rounded to float32
    before the mixture is evaluated there. Invalid samples have wi = +z, zero weight and pdf."""
    kind, weight, rough, ior, fresnel, select, f0s, under, tint, dnorm = lobes
    s = -1.0 if back else 1.0
    ox = np.float64(wox)
    oy = np.float64(woy)
    oz = np.float64(woz) * s  # < 0: wo below the shading normal on the geometric side it is on
    c, sel_c, u1 = _choose_lobe(kind, select, row, u1)
    k = kind[row, c] if c >= 0 else EMPTY
    if k == EMPTY:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False, False, False
    is_delta = False
    p_event = 1.0
    gw0 = gw1 = gw2 = 1.0  # a delta glass sample's value / event probability per channel (1 untinted)
    dx, dy, dz = diffuse_axis(lobes, row, back)
    if k == DIFFUSE:
        x, y, z = sample_cos_hemisphere_local(np.float64(u1), np.float64(u2))
        ok = z > 0.0
        if not (dx == 0.0 and dy == 0.0):  # about the diffuse axis (Duff et al.'s basis around it)
            sg = math.copysign(1.0, dz)
            a = -1.0 / (sg + dz)
            b = dx * dy * a
            tx, ty, tz = 1.0 + sg * dx * dx * a, sg * b, -sg * dx
            bx, by, bz = b, sg + dy * dy * a, -dy
            x, y, z = x * tx + y * bx + z * dx, x * ty + y * by + z * dy, x * tz + y * bz + z * dz
    else:
        rough_c = np.float64(rough[row, c])
        is_delta = not rough_c > 0.0
        if is_delta:
            hx, hy, hz = 0.0, 0.0, 1.0
        else:
            hx, hy, hz = sample_vndf(ox, oy, oz, rough_c * rough_c, np.float64(u1), np.float64(u2))
        cos_oh = ox * hx + oy * hy + oz * hz
        ok = oz > 0.0 and cos_oh > 0.0
        if k == GLOSSY:
            c2 = 2.0 * cos_oh
            x, y, z = c2 * hx - ox, c2 * hy - oy, c2 * hz - oz
            ok = ok and z > 0.0
        else:
            eta = _relative_ior(ior[row, c], back)
            x, y, z, tir = refract(ox, oy, oz, hx, hy, hz, eta)
            reflect = False
            if k == GLASS and glass_tinted(lobes, row, c):
                R0, R1, R2, T0, T1, T2 = glass_fresnel(lobes, row, c, cos_oh, eta)
                pr = _reflect_probability(R0, R1, R2, T0, T1, T2)
                ok = ok and pr >= 0.0
                reflect = u_event < pr
                p_event = pr if reflect else 1.0 - pr
                if ok and p_event > 0.0:
                    inv_ev = 1.0 / p_event
                    if reflect:
                        gw0, gw1, gw2 = R0 * inv_ev, R1 * inv_ev, R2 * inv_ev
                    else:
                        gw0, gw1, gw2 = T0 * inv_ev, T1 * inv_ev, T2 * inv_ev
                if reflect:
                    c2 = 2.0 * cos_oh
                    x, y, z = c2 * hx - ox, c2 * hy - oy, c2 * hz - oz
            elif k == GLASS:
                F = fresnel_dielectric(cos_oh, eta)
                reflect = u_event < F
                p_event = F if reflect else 1.0 - F
                if reflect:
                    c2 = 2.0 * cos_oh
                    x, y, z = c2 * hx - ox, c2 * hy - oy, c2 * hz - oz
            ok = ok and (z > 0.0 if reflect else (z < 0.0 and not tir))
    # the direction as it is returned (float32), flipped back below
    x = np.float64(np.float32(x))
    y = np.float64(np.float32(y))
    z = np.float64(np.float32(z))
    if not ok:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False, False, False
    if is_delta:
        # weight = value / (select x event probability) x event probability
        inv = 1.0 / np.float64(sel_c)
        fr0 = fr1 = fr2 = 1.0
        if k == GLOSSY and fresnel[row, c] == F_GEN_SCHLICK:
            sv = gen_schlick_s(oz, np.float64(ior[row, c]))
            fr0 = f0s[row, c, 0] + (1.0 - f0s[row, c, 0]) * sv
            fr1 = f0s[row, c, 1] + (1.0 - f0s[row, c, 1]) * sv
            fr2 = f0s[row, c, 2] + (1.0 - f0s[row, c, 2]) * sv
        elif k == GLOSSY:
            fr0 = fr1 = fr2 = glossy_fresnel(fresnel[row, c], np.float64(ior[row, c]), oz)
        elif k == GLASS:
            fr0, fr1, fr2 = gw0, gw1, gw2
        j = under[row, c]
        if j >= 0:
            inv *= layer_factor(lobes, row, j, multiscatter, tabs, oz)
        w0 = weight[row, c, 0] * inv * fr0
        w1 = weight[row, c, 1] * inv * fr1
        w2 = weight[row, c, 2] * inv * fr2
        pdf = sel_c * p_event
    elif kind.shape[1] == 1 and k == DIFFUSE and under[row, c] < 0:
        # a lone diffuse lobe needs no mixture sum: f cos / pdf = colour / select, pdf = select cos / pi
        pdf = sel_c * (max(x * dx + y * dy + z * dz, 0.0) * _INV_PI)
        inv = 1.0 / max(np.float64(sel_c), 1e-30)
        w0, w1, w2 = weight[row, c, 0] * inv, weight[row, c, 1] * inv, weight[row, c, 2] * inv
    else:
        # MIS-consistent: f and pdf summed over all non-delta lobes at the sampled direction
        f0, f1, f2, pdf = eval_path(lobes, row, multiscatter, tabs, ox, oy, oz, back, x, y, z)
        if pdf > 0.0:
            w0, w1, w2 = f0 / pdf, f1 / pdf, f2 / pdf
        else:
            w0 = w1 = w2 = 0.0
    if not (pdf > 0.0 and (w0 > 0.0 or w1 > 0.0 or w2 > 0.0)):
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, False, False, False
    # a diffuse sample is a reflection even where it lies below the tilted normal (scatter checks the true side)
    return x, y, z * s, w0, w1, w2, pdf, is_delta, z < 0.0 and k != DIFFUSE, True


# ------------------------------------------------------------------------------------------ batch kernels
@_jit
def eval_batch(lobes, rows, use_rows, multiscatter, tabs, wo, wi, back, f_out, pdf_out):
    """eval_path for each direction pair k (hit rows[k] if use_rows else k); wo, wi (n, 3) local frame; back (n,):
    the geometric side of wo (see sample_path)."""
    for k in range(wo.shape[0]):
        row = rows[k] if use_rows else k
        b = back[k]
        s = -1.0 if b else 1.0
        f0, f1, f2, pdf = eval_path(lobes, row, multiscatter, tabs, np.float64(wo[k, 0]), np.float64(wo[k, 1]),
                                    np.float64(wo[k, 2]) * s, b, np.float64(wi[k, 0]), np.float64(wi[k, 1]),
                                    np.float64(wi[k, 2]) * s)
        f_out[k, 0] = f0
        f_out[k, 1] = f1
        f_out[k, 2] = f2
        pdf_out[k] = pdf


@_jit
def sample_batch(lobes, multiscatter, tabs, wo, back, u_event, u, wi, weight, pdf, delta, transmitted, valid):
    """sample_path for every hit; back (n,): the geometric side of each wo."""
    for k in range(wo.shape[0]):
        x, y, z, w0, w1, w2, p, d, t, v = sample_path(lobes, k, multiscatter, tabs, wo[k, 0], wo[k, 1], wo[k, 2],
                                                      back[k], u_event[k], u[k, 0], u[k, 1])
        wi[k, 0] = x
        wi[k, 1] = y
        wi[k, 2] = z
        weight[k, 0] = w0
        weight[k, 1] = w1
        weight[k, 2] = w2
        pdf[k] = p
        delta[k] = d
        transmitted[k] = t
        valid[k] = v


@_jit
def albedo_batch(lobes, multiscatter, tabs, wo, use_wo, out):
    """Albedo AOV: sum of lobe colours; Fresnel-weighted glossy lobes scaled by F(|wo.z|) (use_wo) or their
    hemispherical average; generalized-Schlick lobes by their albedo estimate at |wo.z| (`gen_schlick_albedo`) or
    their Fss; lobes under a layer by its `layer_factor` at |wo.z| or 1 - max_c Fss_c of the layer. Glass counts
    R + T = 1, a tinted glass F_c rt_c + (1 - F_c) tt_c with F_c = f0_c + (1 - f0_c) s, s from the
    generalized-Schlick table at |wo.z| or its average (f0 = F0(ior) for a plain glass; Cycles'
    bsdf_microfacet_estimate_albedo without the multiscatter darkening)."""
    kind, weight, rough, ior, fresnel, select, f0s, under, tint, dnorm = lobes
    for k in range(kind.shape[0]):
        mu = abs(np.float64(wo[k, 2])) if use_wo else 1.0
        a0 = a1 = a2 = 0.0
        for l in range(kind.shape[1]):
            kl = kind[k, l]
            if kl < 0:
                continue
            s0 = s1 = s2 = 1.0
            if kl == GLOSSY and fresnel[k, l] == F_GEN_SCHLICK:
                if use_wo:
                    s0 = gen_schlick_albedo(lobes, k, l, multiscatter, tabs, mu, 0)
                    s1 = gen_schlick_albedo(lobes, k, l, multiscatter, tabs, mu, 1)
                    s2 = gen_schlick_albedo(lobes, k, l, multiscatter, tabs, mu, 2)
                else:
                    sa = gen_schlick_s_avg(np.float64(ior[k, l]))
                    s0 = f0s[k, l, 0] + (1.0 - f0s[k, l, 0]) * sa
                    s1 = f0s[k, l, 1] + (1.0 - f0s[k, l, 1]) * sa
                    s2 = f0s[k, l, 2] + (1.0 - f0s[k, l, 2]) * sa
            elif kl == GLOSSY and fresnel[k, l] != F_NONE:
                if use_wo:
                    s0 = glossy_fresnel(fresnel[k, l], np.float64(ior[k, l]), mu)
                else:
                    s0 = glossy_fresnel_avg(fresnel[k, l], np.float64(ior[k, l]))
                s1 = s2 = s0
            elif kl == GLASS and glass_tinted(lobes, k, l):
                lior = np.float64(ior[k, l])
                if use_wo:
                    sv = gen_schlick_table_s(tabs, np.float64(rough[k, l]), mu, lior)
                else:
                    sv = gen_schlick_s_avg(lior)
                gen = fresnel[k, l] == F_GEN_SCHLICK
                for c in range(3):
                    g = np.float64(f0s[k, l, c]) if gen else schlick_f0(lior)
                    F = g + (1.0 - g) * sv
                    a = F * tint[k, l, 0, c] + (1.0 - F) * tint[k, l, 1, c]
                    if c == 0:
                        s0 = a
                    elif c == 1:
                        s1 = a
                    else:
                        s2 = a
            j = under[k, l]
            if j >= 0:
                if use_wo:
                    lf = layer_factor(lobes, k, j, multiscatter, tabs, mu)
                else:
                    sa = gen_schlick_s_avg(np.float64(ior[k, j]))
                    m = 0.0
                    for c in range(3):
                        m = max(m, f0s[k, j, c] + (1.0 - f0s[k, j, c]) * sa)
                    lf = min(max(1.0 - m, 0.0), 1.0)
                s0 *= lf
                s1 *= lf
                s2 *= lf
            a0 += weight[k, l, 0] * s0
            a1 += weight[k, l, 1] * s1
            a2 += weight[k, l, 2] * s2
        out[k, 0] = a0
        out[k, 1] = a1
        out[k, 2] = a2


@_inline
def _normalise_select(kind, select, k, tot):
    """Divide row k's lobe weights (float32, summing to tot) by their sum; a black material (tot 0) picks among
    its present lobes uniformly (their weights are 0 anyway)."""
    L = kind.shape[1]
    if not tot > _F32_0:
        tot = _F32_0
        for l in range(L):
            select[k, l] = _F32_1 if kind[k, l] >= 0 else _F32_0
            tot = np.float32(tot + select[k, l])
        tot = max(tot, _F32_1)
    for l in range(L):
        select[k, l] = np.float32(select[k, l] / tot)


@_inline
def _select_row(kind, weight, scale, m, k, select):
    """Lobe-choice probabilities of hit k (float32): mean colour x albedo estimate (scale[m, l]), normalised over
    the present lobes; a black material picks among its lobes uniformly (their weights are 0 anyway)."""
    L = kind.shape[1]
    tot = _F32_0
    for l in range(L):
        s = np.float32(np.float32(weight[k, l, 0] + weight[k, l, 1]) + weight[k, l, 2]) * scale[m, l]
        select[k, l] = s
        tot = np.float32(tot + s)
    _normalise_select(kind, select, k, tot)


@_inline
def view_select_row(lobes, row, multiscatter, tabs, mu, scale, m):
    """Rewrite hit `row`'s lobe-choice probabilities for the view cos wo = mu (float64, the frame flipped to wo's
    geometric side, as eval_path's oz): mean colour x each lobe's albedo estimate at mu, normalised, as Cycles sets
    a closure's sample weight from its albedo at the view direction (bsdf_microfacet_estimate_albedo), the layers
    below a coat attenuated by what the coat reflects there (closure_layering_weight). A diffuse lobe counts 1; a
    generalized-Schlick glossy lobe its single-scatter albedo f0 + (1 - f0) s(mu) (the `gen_schlick_table_s`
    read that gen_schlick_albedo also makes, without its multiscatter factor: a few % from 1, and three more table
    reads and six divisions a vertex); another glossy lobe its Fresnel at mu (`glossy_fresnel`); a lobe under a
    layer also 1 - max_c of that layer's albedo (under another lobe than the last coat seen: `layer_factor`);
    glass and refraction lobes keep their view-independent estimate scale[m, l] (material m's row of
    MaterialTable.select_scale). So a coated surface seen at grazing angles, where its coat reflects most, picks the
    coat more often, and less often where it is seen head-on: the material-wide averages (`_select_row`)
    over-picked the coat head-on and under-picked it at grazing angles, where paths from a floor arrive at an
    object's base. The probabilities only shape the variance (every reader of `select` at the vertex, the light
    sample's MIS, the BSDF sample and the ray kinds, sees these), so the estimate need not be exact. The caller
    decides that material m's choice follows the view (MaterialTable.view_select)."""
    kind, weight, rough, ior, fresnel, select, f0s, under, tint, dnorm = lobes
    mu = min(max(mu, 1e-4), 1.0)  # (wo below the shading normal: the tables' grazing end)
    tot = _F32_0
    layer = -1  # the last generalized-Schlick lobe seen, and 1 - max_c of its albedo (its layer_factor)
    layer_keep = 1.0
    for l in range(kind.shape[1]):
        k = kind[row, l]
        if k < 0:
            select[row, l] = _F32_0
            continue
        if k == DIFFUSE:
            a = 1.0
        elif k == GLOSSY and fresnel[row, l] == F_GEN_SCHLICK:
            # the layer's single-scatter albedo f0 + (1 - f0) s(mu) (gen_schlick_albedo without the multiscatter
            # factor, which is within a few % of 1 and costs three table reads and six divisions a vertex): linear
            # in f0, so the mean colour's is the channels' mean, and the largest f0 gives the largest albedo
            s = gen_schlick_table_s(tabs, np.float64(rough[row, l]), mu, np.float64(ior[row, l]))
            fmean = 0.0
            fmax = 0.0
            for c in range(3):
                fc = np.float64(f0s[row, l, c])
                fmean += fc
                if weight[row, l, c] > 0.0:
                    fmax = max(fmax, fc)
            fmean /= 3.0
            a = fmean + (1.0 - fmean) * s
            layer = l
            layer_keep = min(max(1.0 - (fmax + (1.0 - fmax) * s), 0.0), 1.0)
        elif k == GLOSSY:
            a = glossy_fresnel(fresnel[row, l], np.float64(ior[row, l]), mu)
        else:
            a = np.float64(scale[m, l])
        j = under[row, l]
        if j >= 0 and k <= GLOSSY:
            a *= layer_keep if j == layer else layer_factor(lobes, row, j, multiscatter, tabs, mu)
        sv = np.float32(np.float32(np.float32(weight[row, l, 0] + weight[row, l, 1]) + weight[row, l, 2])
                        * np.float32(a))
        select[row, l] = sv
        tot = np.float32(tot + sv)
    _normalise_select(kind, select, row, tot)


@_jit
def view_selection_batch(lobes, multiscatter, tabs, wo, back, mat, view_select, scale):
    """view_select_row for every hit k whose material mat[k] has a view-dependent choice (view_select[mat[k]]),
    seen from the local wo[k] (flipped to its geometric side where back[k], as sample_batch does)."""
    for k in range(wo.shape[0]):
        m = mat[k]
        if view_select[m]:
            mu = np.float64(wo[k, 2]) * (-1.0 if back[k] else 1.0)
            view_select_row(lobes, k, multiscatter, tabs, mu, scale, m)


@_jit
def selection_batch(kind, weight, scale, select):
    for k in range(kind.shape[0]):
        _select_row(kind, weight, scale, k, k, select)


@_inline
def texel_bilinear(pixels, offset, h, w, u, v, channel):
    """Bilinear, repeat-wrapped lookup of one channel of an H x W x 3 image stored flat from `offset`, in
    Blender's UV convention (texel (r, c) centred at ((c + 0.5)/W, 1 - (r + 0.5)/H)); float32 arithmetic.
    Non-finite coordinates read as 0."""
    if not math.isfinite(u):
        u = _F32_0
    if not math.isfinite(v):
        v = _F32_0
    x = np.float32(u * np.float32(w)) - _F32_HALF
    y = np.float32(np.float32(_F32_1 - v) * np.float32(h)) - _F32_HALF
    xf = np.float32(math.floor(x))
    yf = np.float32(math.floor(y))
    fx = np.float32(x - xf)
    fy = np.float32(y - yf)
    xi0 = np.int64(xf) % w
    yi0 = np.int64(yf) % h
    xi1 = xi0 + 1 if xi0 + 1 < w else 0
    yi1 = yi0 + 1 if yi0 + 1 < h else 0
    gx = np.float32(_F32_1 - fx)
    p00 = pixels[offset + (yi0 * w + xi0) * 3 + channel]
    p01 = pixels[offset + (yi0 * w + xi1) * 3 + channel]
    p10 = pixels[offset + (yi1 * w + xi0) * 3 + channel]
    p11 = pixels[offset + (yi1 * w + xi1) * 3 + channel]
    top = np.float32(np.float32(p00 * gx) + np.float32(p01 * fx))
    bot = np.float32(np.float32(p10 * gx) + np.float32(p11 * fx))
    return np.float32(top + np.float32(np.float32(bot - top) * fy))


@_jit
def texture_batch(pixels, h, w, uv, out):
    """texel_bilinear of an (H, W, 3) image (flattened) at (n, 2) UVs into out (n, 3)."""
    for k in range(uv.shape[0]):
        for c in range(3):
            out[k, c] = texel_bilinear(pixels, 0, h, w, uv[k, 0], uv[k, 1], c)


@_jit
def gather_batch(mi, uv, has_uv, t_kind, t_color, t_rough, t_ior, t_fresnel, t_f0, t_under, t_tint, t_texture,
                 t_select, t_scale, tex_pixels, tex_offset, tex_h, tex_w, kind, weight, rough, ior, fresnel, select,
                 f0, under, tint):
    """Per-hit lobe arrays of material indices mi from the (M, L) material tables. Lobes with a colour texture
    (t_texture >= 0) are tinted by it at the hit's uv (missing UVs read (0, 0)) and the hit's selection
    probabilities recomputed; otherwise they are copied from t_select. A generalized-Schlick glass lobe's texture
    multiplies its transmission tint by sqrt(saturate(texel)) (Cycles' Principled transmission) instead of its
    colour."""
    L = t_kind.shape[1]
    for k in range(mi.shape[0]):
        m = mi[k]
        textured = False
        for l in range(L):
            kind[k, l] = t_kind[m, l]
            rough[k, l] = t_rough[m, l]
            ior[k, l] = t_ior[m, l]
            fresnel[k, l] = t_fresnel[m, l]
            select[k, l] = t_select[m, l]
            under[k, l] = t_under[m, l]
            for c in range(3):
                f0[k, l, c] = t_f0[m, l, c]
                tint[k, l, 0, c] = t_tint[m, l, 0, c]
                tint[k, l, 1, c] = t_tint[m, l, 1, c]
            t = t_texture[m, l]
            if t >= 0:
                textured = True
                u = uv[k, 0] if has_uv else _F32_0
                v = uv[k, 1] if has_uv else _F32_0
                to_tint = t_kind[m, l] == GLASS and t_fresnel[m, l] == F_GEN_SCHLICK
                for c in range(3):
                    texel = texel_bilinear(tex_pixels, tex_offset[t], tex_h[t], tex_w[t], u, v, c)
                    if to_tint:
                        weight[k, l, c] = t_color[m, l, c]
                        tint[k, l, 1, c] = t_tint[m, l, 1, c] * np.float32(math.sqrt(min(max(texel, _F32_0),
                                                                                          _F32_1)))
                    else:
                        weight[k, l, c] = t_color[m, l, c] * texel
            else:
                for c in range(3):
                    weight[k, l, c] = t_color[m, l, c]
        if textured:
            _select_row(kind, weight, t_scale, m, k, select)
