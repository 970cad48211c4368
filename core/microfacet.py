"""GGX microfacet building blocks and the multiscatter energy-compensation tables (Cycles 4.x/5.0 style).

All functions are vectorised over 1-D float32 arrays of direction components in the local shading frame
(normal = +z) and assume the *view* direction `wo` is in the upper hemisphere (callers flip the frame).

Model (what Cycles' `bsdf_microfacet.h` does since Blender 4.0, re-derived from the papers):
  - Isotropic GGX / Trowbridge-Reitz NDF, alpha = roughness^2, height-correlated Smith masking-shadowing
    G2 = 1 / (1 + Lambda(wo) + Lambda(wi)) (Heitz 2014), Walter et al. 2007 BRDF/BTDF.
  - Visible-normal sampling (pdf = G1(wo) D(h) max(0, wo.h) / wo.z) with the spherical-cap formulation of
    Dupuy & Benyoub 2023 (same distribution as Heitz 2018, which Cycles uses; only the sample mapping differs).
  - "Multiscatter GGX": Cycles no longer runs the random-walk multiple-scattering model of Heitz 2016 (removed in
    4.0); it multiplies the single-scatter lobe by 1/E(mu) (`energy_scale`) and, for a coloured lobe, by the
    Kulla-Conty multi-bounce tint (1 + Fms (1 - E)/E) * E with Fms = Fss Eavg / (1 - Fss (1 - Eavg)), where
    E is the single-scatter directional albedo looked up from precomputed tables:
      ggx_E(rough, mu) 32x32 + ggx_Eavg(rough) 32      reflection (Glossy, Principled specular)
      glass_E(rough, mu, z) 16^3 + glass_Eavg(rough, z) 16^2, and an "inv" pair for ior < 1 (Glass)
    with rough = roughness = sqrt(alpha), mu = cos(wo), z = sqrt(|ior - 1| / (ior + 1)), all axes sampled at
    i / (n - 1) and read with (bi/tri)linear interpolation (Cycles' `lookup_table_read_*`).
    The tables here are *our own* numerical integration of our own single-scatter sampler (a deterministic
    midpoint quadrature over the 2-D sample space, see `compute_tables`), generated once into
    core/data/ggx_tables.npz (`python -m monte.core.microfacet` regenerates it).
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

F32 = np.float32
INV_PI = F32(1.0 / math.pi)
TWO_PI = F32(2.0 * math.pi)
# Cycles treats a microfacet lobe as singular (a delta) when alpha_x * alpha_y <= 5e-7.
SINGULAR_ALPHA2 = 5e-7
SINGULAR_ROUGHNESS = SINGULAR_ALPHA2**0.25  # 0.0266: roughness at or below this is a perfect mirror / smooth glass

TABLE_PATH = Path(__file__).resolve().parent / "data" / "ggx_tables.npz"
GGX_N = 32  # ggx_E is GGX_N x GGX_N (mu, rough)
GLASS_N = 16  # glass_E is GLASS_N^3 (z, mu, rough)


# ------------------------------------------------------------------------------------------ GGX primitives
def ggx_D(alpha2: np.ndarray, cos_h: np.ndarray) -> np.ndarray:
    """GGX normal distribution D(h) for cos(theta_h) = cos_h (only cos_h^2 matters)."""
    t = 1.0 + (alpha2 - 1.0) * (cos_h * cos_h)
    return alpha2 * INV_PI / (t * t)


def ggx_lambda(alpha2: np.ndarray, cos_w: np.ndarray) -> np.ndarray:
    """Smith Lambda for GGX; symmetric in the sign of cos_w; +inf at grazing (cos_w = 0)."""
    c2 = cos_w * cos_w
    with np.errstate(divide="ignore", invalid="ignore"):
        tan2 = np.maximum((1.0 - c2) / c2, 0.0)
    return 0.5 * (np.sqrt(1.0 + alpha2 * tan2) - 1.0)


def fresnel_dielectric(cos_i: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Exact unpolarised dielectric Fresnel reflectance.

    cos_i >= 0: cosine of the angle between the incident direction and the (micro)normal on the incident side;
    eta = n_transmitted / n_incident. Returns 1 under total internal reflection."""
    c = np.abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.maximum(g2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        f = 0.5 * a * a * (1.0 + b * b)
    f = np.where(g2 > 0.0, f, 1.0)
    return np.nan_to_num(f, nan=0.0).astype(np.result_type(cos_i, F32), copy=False)


def fresnel_schlick(cos_i: np.ndarray, f0: np.ndarray) -> np.ndarray:
    """Schlick's approximation F0 + (1 - F0)(1 - cos)^5."""
    m = np.clip(1.0 - cos_i, 0.0, 1.0)
    m2 = m * m
    return f0 + (1.0 - f0) * (m2 * m2 * m)


def schlick_f0(ior: np.ndarray) -> np.ndarray:
    r = (ior - 1.0) / (ior + 1.0)
    return r * r


def fresnel_dielectric_avg(eta: np.ndarray) -> np.ndarray:
    """Cosine-weighted hemispherical average 2 int_0^1 F(mu, eta) mu dmu of the exact dielectric Fresnel.

    The numerical fit of Kulla & Conty 2017 ("Revisiting Physically Based Shading at Imageworks"), which is also
    what Cycles uses for the multi-bounce Fresnel tint of a dielectric specular layer (accurate to ~1e-3)."""
    eta = np.asarray(eta, dtype=F32)
    below = 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607))
    above = (eta - 1.0) / (4.08567 + 1.00071 * eta)
    return np.clip(np.where(eta < 1.0, below, above), 0.0, 1.0).astype(F32)


def sample_vndf(ox, oy, oz, alpha, u1, u2):
    """Sample a microfacet normal h from the GGX distribution of normals visible from wo (oz > 0).

    Spherical-cap visible-normal sampling (Dupuy & Benyoub 2023). Returns (hx, hy, hz) with hz >= 0."""
    vx = alpha * ox
    vy = alpha * oy
    inv = 1.0 / np.sqrt(vx * vx + vy * vy + oz * oz)
    vx *= inv
    vy *= inv
    vz = oz * inv
    phi = TWO_PI * u1
    z = (1.0 - u2) * (1.0 + vz) - vz
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    hx = (s * np.cos(phi) + vx) * alpha
    hy = (s * np.sin(phi) + vy) * alpha
    hz = np.maximum(z + vz, 0.0)
    inv = 1.0 / np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-30)
    return hx * inv, hy * inv, hz * inv


def refract(ox, oy, oz, hx, hy, hz, eta):
    """Refract wo (pointing away from the surface, wo.h > 0) through microfacet h; eta = n_t / n_i.

    Returns (ix, iy, iz, tir) with the transmitted direction pointing away on the other side."""
    c = ox * hx + oy * hy + oz * hz
    inv_eta = 1.0 / eta
    s2t = (1.0 - c * c) * (inv_eta * inv_eta)
    tir = s2t >= 1.0
    ct = np.sqrt(np.maximum(1.0 - s2t, 0.0))
    k = c * inv_eta - ct
    return -ox * inv_eta + k * hx, -oy * inv_eta + k * hy, -oz * inv_eta + k * hz, tir


def microfacet_eval(alpha, eta, ox, oy, oz, ix, iy, iz, lobes: str = "both"):
    """Single-scatter GGX terms for a view direction wo (oz > 0) and a light direction wi, without Fresnel.

    Reflection when iz > 0 (h = normalize(wo + wi)); transmission when iz < 0 (generalised half vector
    h = -normalize(wo + eta wi) oriented to +z, eta = n_wi_side / n_wo_side).
    Returns (f_cos, pdf, cos_oh, reflect):
      f_cos = D G2 / (4 oz)                                         (reflection)
            = D G2 eta^2 |wo.h| |wi.h| / (oz (wo.h + eta wi.h)^2)   (transmission), i.e. f |cos(wi)| / Fresnel;
      pdf   = the same with G2 replaced by G1(wo): the solid-angle pdf of VNDF sampling followed by
              reflection/refraction at h (before the reflect/refract choice);
      cos_oh = wo.h (for the Fresnel term); zero f and pdf where the configuration is impossible.
    lobes: "both", "reflect" (transmission configurations give 0) or "transmit" (reflections give 0)."""
    reflect = iz > 0.0
    if lobes == "reflect":
        hx, hy, hz = ox + ix, oy + iy, oz + iz
    else:
        e = eta if lobes == "transmit" else np.where(reflect, F32(1.0), eta)
        hx = e * ix
        hx += ox
        hy = e * iy
        hy += oy
        hz = e * iz
        hz += oz
    hl = hx * hx
    hl += hy * hy
    hl += hz * hz
    np.sqrt(hl, out=hl)
    np.maximum(hl, 1e-30, out=hl)
    if lobes != "reflect":  # orient the generalised half vector to +z
        hl[hz < 0.0] *= -1.0
    hx /= hl
    hy /= hl
    hz /= hl
    cos_oh = ox * hx
    cos_oh += oy * hy
    cos_oh += oz * hz
    cos_ih = ix * hx
    cos_ih += iy * hy
    cos_ih += iz * hz
    alpha2 = alpha * alpha
    d = ggx_D(alpha2, hz)
    lam_o = ggx_lambda(alpha2, oz)
    g1 = lam_o + 1.0
    g2 = ggx_lambda(alpha2, iz)
    g2 += g1
    ok = (oz > 0.0) & (cos_oh > 0.0)
    if lobes == "reflect":
        ok &= reflect & (cos_ih > 0.0)
        d *= 0.25
        d /= oz
    else:
        t = eta * cos_ih
        t += cos_oh
        t *= t
        t *= oz
        tr = d * (eta * eta)
        tr *= np.abs(cos_oh * cos_ih)
        tr /= t
        if lobes == "transmit":
            ok &= (iz < 0.0) & (cos_ih < 0.0)
            d = tr
        else:
            ok &= np.where(reflect, cos_ih > 0.0, (iz < 0.0) & (cos_ih < 0.0))
            d *= 0.25
            d /= oz
            d = np.where(reflect, d, tr)
    ok &= np.isfinite(d)
    common = np.where(ok, d, F32(0.0))
    pdf = common / g1
    common /= g2
    return common.astype(F32, copy=False), pdf.astype(F32, copy=False), cos_oh, reflect


# ------------------------------------------------------------------------------------------------- tables
def _lerp_coords(x, n):
    """Grid index i0 (int32, <= n - 2) and fraction for x in [0, 1] on the grid i / (n - 1)."""
    x = np.clip(x, 0.0, 1.0).astype(F32, copy=False) * F32(n - 1)
    i0 = np.minimum(x.astype(np.int32), n - 2)
    x -= i0
    return i0, x


def _lookup_flat(flat, shape, coords, base=None):
    """Multilinear read of a C-ordered table (flattened) with `shape` at coordinates in [0, 1], one per axis
    (coords[0] along the last axis, as Cycles' lookup_table_read_2D/3D(x, y, z)); grids at i / (n - 1).
    `base` (int array) adds a per-element offset into `flat` (to select one of several stacked tables)."""
    idx = None
    fracs = []
    stride = 1
    strides = []
    for c, n in zip(coords, reversed(shape)):
        i0, f = _lerp_coords(c, n)
        i0 = i0 * np.int32(stride)
        idx = i0 if idx is None else idx + i0
        fracs.append(f)
        strides.append(stride)
        stride *= n
    if base is not None:
        idx = idx + base
    # accumulate the 2^d corners
    out = None
    d = len(coords)
    for corner in range(1 << d):
        off = 0
        w = None
        for a in range(d):
            if corner >> a & 1:
                off += strides[a]
                wa = fracs[a]
            else:
                wa = 1.0 - fracs[a]
            w = wa if w is None else w * wa
        v = flat.take(idx + off if off else idx)
        v *= w
        out = v if out is None else out + v
    return out


@lru_cache(maxsize=1)
def tables() -> dict[str, np.ndarray]:
    """The shipped energy-compensation tables (float32), loaded on first use (~40 KB). The glass tables are also
    stacked as 'glass_E2' (2, 16, 16, 16) and 'glass_Eavg2' (2, 16, 16): [0] entering (ior > 1), [1] leaving."""
    with np.load(TABLE_PATH) as z:
        t = {k: np.ascontiguousarray(z[k], dtype=F32) for k in z.files}
    t["glass_E2"] = np.ascontiguousarray(np.stack([t["glass_E"], t["glass_inv_E"]]))
    t["glass_Eavg2"] = np.ascontiguousarray(np.stack([t["glass_Eavg"], t["glass_inv_Eavg"]]))
    return t


def ior_to_z(ior: np.ndarray) -> np.ndarray:
    """Glass-table IOR axis: z = sqrt(|ior - 1| / (ior + 1)) = F0^(1/4); the same z for ior and 1/ior."""
    return np.sqrt(np.abs((ior - 1.0) / (ior + 1.0)))


def ggx_E(rough, mu):
    """Directional albedo of the white single-scatter GGX reflection lobe, E(roughness, cos(wo))."""
    t = tables()["ggx_E"]
    return _lookup_flat(t.ravel(), t.shape, (rough, mu))


def ggx_Eavg(rough):
    t = tables()["ggx_Eavg"]
    return _lookup_flat(t, t.shape, (rough,))


def glass_E(rough, mu, eta):
    """Directional albedo (R + T) of the white single-scatter GGX glass lobe seen from a medium with relative
    IOR eta = n_other / n_view (eta < 1: leaving the denser medium, Cycles' 'inv' table)."""
    t = tables()["glass_E2"]
    base = np.where(eta < 1.0, np.int32(t[0].size), np.int32(0))
    return _lookup_flat(t.ravel(), t.shape[1:], (rough, mu, ior_to_z(eta)), base)


def glass_Eavg(rough, eta):
    t = tables()["glass_Eavg2"]
    base = np.where(eta < 1.0, np.int32(t[0].size), np.int32(0))
    return _lookup_flat(t.ravel(), t.shape[1:], (rough, ior_to_z(eta)), base)


def multiscatter_factor(E, Eavg, Fss):
    """Cycles' energy preservation as one per-channel multiplier on the single-scatter lobe:
    (1 + Fms (1 - E)/E) with Fms = Fss Eavg / (1 - Fss (1 - Eavg)); for Fss = 1 this is exactly 1/E.
    E, Eavg: (n,); Fss: (n, 3) in [0, 1]. Returns (n, 3)."""
    E = np.maximum(E, F32(1e-4))
    miss = (1.0 - E) / E
    Eavg = Eavg[:, None]
    fms = Fss * Eavg
    den = Fss * (Eavg - 1.0)
    den += 1.0
    np.maximum(den, 1e-6, out=den)
    fms /= den
    fms *= miss[:, None]
    fms += 1.0
    return fms.astype(F32, copy=False)


# ------------------------------------------------------------------------------------- table generation
def _single_scatter_albedo(rough, mu, eta, n_u, glass):
    """Mean of the single-scatter sampling weight over a midpoint n_u x n_u grid of the 2-D sample space
    (for glass the reflect/refract choice with probability F is integrated analytically).
    rough, mu, eta: 1-D float64 arrays of cells. Returns E per cell (float64)."""
    g = (np.arange(n_u) + 0.5) / n_u
    u1, u2 = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    alpha = np.maximum(rough, 1e-4) ** 2
    out = np.empty(len(rough))
    for c in range(len(rough)):
        a, m, e = alpha[c], mu[c], eta[c]
        # singular: a delta lobe, and Cycles makes transmission with |eta - 1| < 1e-4 singular too
        if a * a <= SINGULAR_ALPHA2 or (glass and abs(e - 1.0) < 1e-4):
            out[c] = 1.0
            continue
        ox, oy, oz = math.sqrt(1.0 - m * m), 0.0, m
        hx, hy, hz = sample_vndf(ox, oy, oz, a, u1, u2)
        a2 = a * a
        lam_o = ggx_lambda(a2, oz)
        c_oh = ox * hx + oy * hy + oz * hz
        # reflection
        iz_r = 2.0 * c_oh * hz - oz
        w_r = np.where(iz_r > 0.0, (1.0 + lam_o) / (1.0 + lam_o + ggx_lambda(a2, iz_r)), 0.0)
        if not glass:
            out[c] = w_r.mean()
            continue
        f = fresnel_dielectric(c_oh, e)
        _, _, iz_t, tir = refract(ox, oy, oz, hx, hy, hz, e)
        w_t = np.where((iz_t < 0.0) & ~tir, (1.0 + lam_o) / (1.0 + lam_o + ggx_lambda(a2, iz_t)), 0.0)
        out[c] = (f * w_r + (1.0 - f) * w_t).mean()
    return np.clip(out, 0.0, 1.0)


def compute_tables(n_u: int = 128, n_u_glass: int = 128, n_mu_avg: int = 24, progress: bool = False):
    """Compute all energy-compensation tables with the same axes as Cycles' `cycles_precompute.cpp`:
    rough = clamp(i/(n-1), 1e-4, 1), mu = clamp(j/(n-1), 1e-4, 1), z = clamp(k/(n-1), 1e-4, 0.99) with
    ior = (1 + z^2)/(1 - z^2); Eavg = int_0^1 2 mu E(mu) dmu (Gauss-Legendre in mu). Values clipped to [0, 1]."""
    def axis(n, hi=1.0):
        return np.clip(np.arange(n) / (n - 1), 1e-4, hi)

    xg, wg = np.polynomial.legendre.leggauss(n_mu_avg)
    mu_avg, w_avg = 0.5 * (xg + 1.0), 0.5 * wg

    r32 = axis(GGX_N)
    R, M = np.meshgrid(r32, axis(GGX_N), indexing="xy")  # [mu, rough]
    ggx_e = _single_scatter_albedo(R.ravel(), M.ravel(), np.ones(R.size), n_u, False).reshape(GGX_N, GGX_N)
    R, M = np.meshgrid(r32, mu_avg, indexing="xy")
    e = _single_scatter_albedo(R.ravel(), M.ravel(), np.ones(R.size), n_u, False).reshape(n_mu_avg, GGX_N)
    ggx_eavg = np.clip((2.0 * mu_avg * w_avg) @ e, 0.0, 1.0)
    if progress:
        print("ggx done", flush=True)

    r16, m16 = axis(GLASS_N), axis(GLASS_N)
    zs = axis(GLASS_N, 0.99)
    iors = (1.0 + zs**2) / (1.0 - zs**2)
    out = {"ggx_E": ggx_e, "ggx_Eavg": ggx_eavg}
    for name, etas in (("glass", iors), ("glass_inv", 1.0 / iors)):
        E = np.empty((GLASS_N, GLASS_N, GLASS_N))
        Eavg = np.empty((GLASS_N, GLASS_N))
        for k, eta in enumerate(etas):
            R, M = np.meshgrid(r16, m16, indexing="xy")
            E[k] = _single_scatter_albedo(R.ravel(), M.ravel(), np.full(R.size, eta), n_u_glass, True).reshape(
                GLASS_N, GLASS_N)
            R, M = np.meshgrid(r16, mu_avg, indexing="xy")
            e = _single_scatter_albedo(R.ravel(), M.ravel(), np.full(R.size, eta), n_u_glass, True).reshape(
                n_mu_avg, GLASS_N)
            Eavg[k] = np.clip((2.0 * mu_avg * w_avg) @ e, 0.0, 1.0)
            if progress:
                print(name, k, flush=True)
        out[f"{name}_E"], out[f"{name}_Eavg"] = E, Eavg
    return {k: v.astype(np.float32) for k, v in out.items()}


def main() -> None:  # pragma: no cover - regeneration tool
    import time

    t0 = time.time()
    tabs = compute_tables(progress=True)
    TABLE_PATH.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(TABLE_PATH, **tabs)
    print(f"wrote {TABLE_PATH} in {time.time() - t0:.1f} s")


if __name__ == "__main__":  # pragma: no cover
    main()
