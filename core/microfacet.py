"""GGX microfacet model and the multiscatter energy-compensation tables (Cycles 4.x/5.0 style).

Rendering evaluates and samples the model in compiled scalar code (core.bsdf_kernels: `microfacet_eval`,
`sample_vndf`, `refract`, the Fresnel terms, the table lookups). This module holds the tables (`tables`,
`ggx_E`, `ggx_Eavg`) and their generator, which integrates in float64 with the same compiled functions the
renderer runs; `fresnel_dielectric` and `sample_vndf` here are those functions over arrays (local shading frame:
normal = +z, view direction wo in the upper hemisphere).

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
  - Principled BSDF layering (Cycles' `closure_layering_weight`): the diffuse base under the specular layer is
    scaled by 1 - max_c albedo_c(wo) of that layer, estimated from a third table
      gen_schlick_s(rough, mu, z) 16^3 (Cycles' ggx_gen_schlick_ior_s)
    = the VNDF average, over reflections that stay above the horizon (others count 0), of the generalized-Schlick
    remap s = saturate((F_dielectric(h.wo, ior) - F0(ior)) / (1 - F0(ior))), so the layer's Fresnel albedo
    estimate is f0 + (1 - f0) s (the lobe energy E is not included; the multiscatter weight adds it).
    The tables here are *our own* numerical integration of our own single-scatter sampler (a deterministic
    midpoint quadrature over the 2-D sample space, see `compute_tables`), generated once into
    core/data/ggx_tables.npz (`python -m monte.core.microfacet` regenerates it).
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from . import bsdf_kernels as bk
from .jit_cache import jit

F32 = np.float32
# Cycles treats a microfacet lobe as singular (a delta) when alpha_x * alpha_y <= 5e-7.
SINGULAR_ALPHA2 = 5e-7
SINGULAR_ROUGHNESS = SINGULAR_ALPHA2**0.25  # 0.0266: roughness at or below this is a perfect mirror / smooth glass

TABLE_PATH = Path(__file__).resolve().parent / "data" / "ggx_tables.npz"
GGX_N = 32  # ggx_E is GGX_N x GGX_N (mu, rough)
GLASS_N = 16  # glass_E is GLASS_N^3 (z, mu, rough)


# ------------------------------------------------------------------- the compiled GGX and Fresnel, batched
# The model's functions exist once, compiled, in core.bsdf_kernels (what the renderer runs); these batch forms let
# the table generator, tools and tests call that same code on arrays.
@jit
def _fresnel_dielectric_batch(cos_i, eta, out):
    for k in range(out.shape[0]):
        out[k] = bk.fresnel_dielectric(cos_i[k], eta[k])


@jit
def _sample_vndf_batch(ox, oy, oz, alpha, u1, u2, out):
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = bk.sample_vndf(ox[k], oy[k], oz[k], alpha[k], u1[k], u2[k])


def _columns(*values) -> list[np.ndarray]:
    """The arguments broadcast against each other as contiguous float64 1-D arrays."""
    arrays = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, np.float64)) for v in values))
    return [np.array(a, np.float64).ravel() for a in arrays]  # copies: numba wants writeable arrays


def fresnel_dielectric(cos_i, eta) -> np.ndarray:
    """core.bsdf_kernels.fresnel_dielectric (exact unpolarised dielectric Fresnel; eta = n_t / n_i, 1 under total
    internal reflection) of each element of the broadcast arguments: float64 (n,)."""
    c, e = _columns(cos_i, eta)
    out = np.empty(len(c))
    _fresnel_dielectric_batch(c, e, out)
    return out


def sample_vndf(ox, oy, oz, alpha, u1, u2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """core.bsdf_kernels.sample_vndf (a GGX visible normal h for wo, hz >= 0) of each element of the broadcast
    arguments: (hx, hy, hz), float64 (n,) each."""
    cols = _columns(ox, oy, oz, alpha, u1, u2)
    out = np.empty((len(cols[0]), 3))
    _sample_vndf_batch(*cols, out)
    return out[:, 0], out[:, 1], out[:, 2]


# ------------------------------------------------------------------------------------------------- tables
@lru_cache(maxsize=1)
def tables() -> dict[str, np.ndarray]:
    """The shipped tables (float32), loaded on first use (~60 KB). The glass tables are also
    stacked as 'glass_E2' (2, 16, 16, 16) and 'glass_Eavg2' (2, 16, 16): [0] entering (ior > 1), [1] leaving."""
    with np.load(TABLE_PATH) as z:
        t = {k: np.ascontiguousarray(z[k], dtype=F32) for k in z.files}
    t["glass_E2"] = np.ascontiguousarray(np.stack([t["glass_E"], t["glass_inv_E"]]))
    t["glass_Eavg2"] = np.ascontiguousarray(np.stack([t["glass_Eavg"], t["glass_inv_Eavg"]]))
    return t


@lru_cache(maxsize=1)
def kernel_tables() -> tuple[np.ndarray, ...]:
    """The tables as core.bsdf_kernels takes them: (ggx_E, ggx_Eavg, glass_E2, glass_Eavg2, gen_schlick_s)."""
    t = tables()
    return t["ggx_E"], t["ggx_Eavg"], t["glass_E2"], t["glass_Eavg2"], t["gen_schlick_s"]


def ggx_E(rough: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Directional albedo of the white single-scatter GGX reflection lobe, E(roughness, cos(wo)), read from the
    table with bilinear interpolation (what the compiled BSDF uses; float32 (n,))."""
    rough, mu = np.broadcast_arrays(np.asarray(rough, np.float64).ravel(), np.asarray(mu, np.float64).ravel())
    out = np.empty(rough.shape, F32)
    bk.ggx_E_batch(kernel_tables(), np.ascontiguousarray(rough), np.ascontiguousarray(mu), out)
    return out


def ggx_Eavg(rough: np.ndarray) -> np.ndarray:
    """Cosine-weighted average of ggx_E over cos(wo), linear in roughness (float32 (n,))."""
    rough = np.ascontiguousarray(np.asarray(rough, np.float64).ravel())
    out = np.empty(rough.shape, F32)
    bk.ggx_Eavg_batch(kernel_tables(), rough, out)
    return out


# ------------------------------------------------------------------------------------- table generation
def _quadrature_grid(rough, n_u):
    """The midpoint n_u x n_u grid (u1, u2) of the 2-D VNDF sample space the table generators average over, and
    GGX alpha = roughness^2 (at least 1e-8) per cell."""
    g = (np.arange(n_u) + 0.5) / n_u
    u1, u2 = (np.ascontiguousarray(a.ravel()) for a in np.meshgrid(g, g, indexing="ij"))
    return u1, u2, np.maximum(rough, 1e-4) ** 2


@jit
def _single_scatter_albedo_cells(alpha, mu, eta, u1, u2, glass, out):
    """out[c] = the mean single-scatter sampling weight of cell c over the sample grid (u1, u2); for glass the
    reflect/refract choice with probability F is integrated analytically."""
    for c in range(out.shape[0]):
        a, m, e = alpha[c], mu[c], eta[c]
        # singular: a delta lobe, and Cycles makes transmission with |eta - 1| < 1e-4 singular too
        if a * a <= SINGULAR_ALPHA2 or (glass and abs(e - 1.0) < 1e-4):
            out[c] = 1.0
            continue
        ox, oy, oz = math.sqrt(1.0 - m * m), 0.0, m
        a2 = a * a
        lam_o = bk.ggx_lambda(a2, oz)
        total = 0.0
        for k in range(u1.shape[0]):
            hx, hy, hz = bk.sample_vndf(ox, oy, oz, a, u1[k], u2[k])
            c_oh = ox * hx + oy * hy + oz * hz
            iz_r = 2.0 * c_oh * hz - oz
            w_r = (1.0 + lam_o) / (1.0 + lam_o + bk.ggx_lambda(a2, iz_r)) if iz_r > 0.0 else 0.0
            if not glass:
                total += w_r
                continue
            f = bk.fresnel_dielectric(c_oh, e)
            _, _, iz_t, tir = bk.refract(ox, oy, oz, hx, hy, hz, e)
            w_t = (1.0 + lam_o) / (1.0 + lam_o + bk.ggx_lambda(a2, iz_t)) if iz_t < 0.0 and not tir else 0.0
            total += f * w_r + (1.0 - f) * w_t
        out[c] = min(max(total / u1.shape[0], 0.0), 1.0)


@jit
def _gen_schlick_s_cells(alpha, mu, eta, u1, u2, out):
    """out[c] = the mean over the sample grid of the generalized-Schlick remap of cell c (0 below the horizon)."""
    for c in range(out.shape[0]):
        a, m, e = alpha[c], mu[c], eta[c]
        ox, oy, oz = math.sqrt(1.0 - m * m), 0.0, m
        f0 = ((e - 1.0) / (e + 1.0)) ** 2
        singular = a * a <= SINGULAR_ALPHA2  # a mirror: h = n for every sample
        total = 0.0
        for k in range(u1.shape[0]):
            hx, hy, hz = (0.0, 0.0, 1.0) if singular else bk.sample_vndf(ox, oy, oz, a, u1[k], u2[k])
            c_oh = ox * hx + oy * hy + oz * hz
            if 2.0 * c_oh * hz - oz > 0.0:
                total += min(max((bk.fresnel_dielectric(c_oh, e) - f0) / (1.0 - f0), 0.0), 1.0)
        out[c] = min(max(total / u1.shape[0], 0.0), 1.0)


def _single_scatter_albedo(rough, mu, eta, n_u, glass):
    """Mean of the single-scatter sampling weight over a midpoint n_u x n_u grid of the 2-D sample space, the
    compiled GGX sampler and weights (core.bsdf_kernels) per cell. rough, mu, eta: 1-D float64 arrays of cells.
    Returns E per cell (float64)."""
    u1, u2, alpha = _quadrature_grid(rough, n_u)
    alpha, mu, eta = _columns(alpha, mu, eta)
    out = np.empty(len(alpha))
    _single_scatter_albedo_cells(alpha, mu, eta, u1, u2, bool(glass), out)
    return out


def _gen_schlick_s(rough, mu, eta, n_u):
    """Mean over a midpoint n_u x n_u grid of the VNDF sample space of the generalized-Schlick remap factor
    saturate((F(h.wo, eta) - F0(eta)) / (1 - F0(eta))), 0 where the reflection leaves below the horizon (Cycles'
    `precompute_ggx_gen_schlick_s` with exponent -1: the eval ratio of an f0 = 0 and an f0 = 1 lobe, so neither the
    masking weight nor the lobe energy enters). rough, mu, eta: 1-D float64 arrays of cells."""
    u1, u2, alpha = _quadrature_grid(rough, n_u)
    alpha, mu, eta = _columns(alpha, mu, eta)
    out = np.empty(len(alpha))
    _gen_schlick_s_cells(alpha, mu, eta, u1, u2, out)
    return out


def compute_gen_schlick_table(n_u: int = 128) -> np.ndarray:
    """ggx_gen_schlick_ior_s on Cycles' axes: [z, mu, rough] 16^3 with rough = clamp(i/15, 1e-4, 1),
    mu = clamp(j/15, 1e-4, 1), z = clamp(k/15, 1e-4, 0.99), ior = (1 + z^2)/(1 - z^2) (F0 = z^4). float32."""
    def axis(n, hi=1.0):
        return np.clip(np.arange(n) / (n - 1), 1e-4, hi)

    zs = axis(GLASS_N, 0.99)
    iors = (1.0 + zs**2) / (1.0 - zs**2)
    R, M = np.meshgrid(axis(GLASS_N), axis(GLASS_N), indexing="xy")  # [mu, rough]
    out = np.empty((GLASS_N, GLASS_N, GLASS_N))
    for k, eta in enumerate(iors):
        out[k] = _gen_schlick_s(R.ravel(), M.ravel(), np.full(R.size, eta), n_u).reshape(GLASS_N, GLASS_N)
    return out.astype(np.float32)


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
    out["gen_schlick_s"] = compute_gen_schlick_table(n_u_glass)
    return {k: v.astype(np.float32) for k, v in out.items()}


def main() -> None:  # pragma: no cover - regeneration tool
    """`python -m monte.core.microfacet` regenerates every table; `... gen_schlick` only the Principled one."""
    import sys
    import time

    t0 = time.time()
    if sys.argv[1:] == ["gen_schlick"]:
        with np.load(TABLE_PATH) as z:
            tabs = {k: z[k] for k in z.files}
        tabs["gen_schlick_s"] = compute_gen_schlick_table()
    else:
        tabs = compute_tables(progress=True)
    TABLE_PATH.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(TABLE_PATH, **tabs)
    print(f"wrote {TABLE_PATH} in {time.time() - t0:.1f} s")


if __name__ == "__main__":  # pragma: no cover
    main()
