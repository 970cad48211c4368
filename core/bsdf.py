"""BSDFs: materials as weighted sums of lobes, evaluated and sampled for N hits at once.

This module is the API (LobeBatch, MaterialTable, eval_bsdf, sample_bsdf, albedo) and the model's documentation;
the per-path work runs in compiled numba kernels (core.bsdf_kernels), which a fused per-bounce kernel can also call.

Frame and direction conventions
-------------------------------
Everything is in the LOCAL shading frame (normal = +z), float32 (N, 3), unit vectors. `wo` points from the
surface towards where the path came from, `wi` towards the next vertex / light. +z is the outside.
- The side of the surface wo is on is `back` (N,) bool, decided by the GEOMETRIC normal as Cycles does (it flips
  N and Ng together when the ray hits the back face); default wo.z < 0, right when the frame's normal is the
  geometric one. A smooth shading normal may put wo.z < 0 in front of the surface (or > 0 behind it): the lobes
  still act on wo's geometric side, so the diffuse lobe stays max(N.wi, 0) / pi around the shading normal turned
  to that side (Cycles' diffuse closure) instead of being mirrored under the surface, and microfacet lobes seen
  from below their normal give nothing (Cycles' cos_NI <= 0; the integrator tilts the normal of specular
  materials so that this is rare, Cycles' ensure_valid_specular_reflection).
- diffuse, glossy: two-sided like Cycles (which flips N towards the viewer): on the back they act in the
  flipped frame and reflect into wo's hemisphere.
- glass, refraction: the front enters (eta = ior), the back leaves (eta = 1/ior). No 1/eta^2 radiance
  scaling (Cycles has none).

Lobes (Cycles 5.0 closures they mirror)
---------------------------------------
- diffuse: Lambert, f = colour / pi.
- glossy (Glossy BSDF, Multiscatter GGX; or a specular layer): GGX reflection with alpha = roughness^2,
  height-correlated Smith G2 = 1/(1 + Lambda_o + Lambda_i), Fresnel "none" (colour at every angle),
  "schlick" (F0 = ((ior-1)/(ior+1))^2, F = F0 + (1-F0)(1-cos)^5), "dielectric" (exact, from ior) or
  "generalized_schlick" (Cycles' Principled specular: per channel f0 + (1 - f0) s with s the exact dielectric
  Fresnel remapped from [F0(ior), 1] to [0, 1]), all times colour, evaluated at wo.h.
- layering (Cycles' Principled, `closure_layering_weight`): a lobe whose `under` names a generalized-Schlick
  glossy lobe j is scaled by saturate(1 - max_c A_c(wo)), A_c = (E + Fms_c (1 - E)) (f0_c + (1 - f0_c) s(wo)) the
  layer's albedo estimate relative to its colour (without multiscatter: f0_c + (1 - f0_c) s), s read from the
  ggx_gen_schlick_ior_s table at (roughness_j, |cos wo|, sqrt(|ior_j - 1| / (ior_j + 1))). The factor scales
  the lobe's value in eval and sample and its albedo, never its pdf or selection probability, so the estimator
  stays unbiased; it depends on wo only (not reciprocal, as in Cycles).
- glass (Glass BSDF, Multiscatter GGX): exact dielectric Fresnel at wo.h, reflection tinted and transmission
  tinted by colour, total internal reflection; reflection/refraction chosen with probability F (as Cycles 4+).
  Tinted glass (Cycles' glass closure with separate tints; the Principled BSDF's transmission): reflection
  R_c = F_c rt_c and transmission T_c = (1 - F_c) tt_c times the colour, F_c the exact Fresnel or, with
  fresnel "generalized_schlick", f0_c + (1 - f0_c) s as for the glossy lobe (total internal reflection: 1);
  reflection is chosen with probability mean(R) / mean(R + T) (Cycles' pdf_reflect) and the multiscatter Fss
  is the transmission tint (x colour for a plain glass), or rt x the Fresnel average when that is black.
- refraction (Refraction BSDF): GGX transmission only and, as in Cycles 4+/5.0, *no* Fresnel factor
  (`fresnel_type = NONE`: the transmitted weight is the colour at every angle); under total internal
  reflection the sample is invalid (the path ends), as Cycles' `valid = ... fresnel != 1`.
- roughness with roughness^4 <= 5e-7 (Cycles' alpha_x alpha_y <= 5e-7, i.e. roughness <= 0.0266) is a delta
  lobe (mirror / smooth glass / smooth refraction); so is rough glass/refraction with |ior - 1| < 1e-4.

Multiscatter GGX (what Cycles 4.0+ does and what is matched here)
-----------------------------------------------------------------
Cycles' "Multiscatter GGX" is no longer Heitz's random walk (removed in Blender 4.0): `microfacet_ggx_preserve_energy`
scales the single-scatter GGX lobe by 1/E(roughness, cos wo) (`energy_scale`) and tints it by
(1 + Fms (1-E)/E) E with Fms = Fss Eavg / (1 - Fss (1 - Eavg)) (Kulla & Conty 2017), E and Eavg being tabulated
single-scatter albedos (reflection: 32x32 + 32; glass: 16^3 + 16^2 over (roughness, cos, z = sqrt(|ior-1|/(ior+1)))
for entering and a second set for leaving). Fss is the lobe colour for Glossy (Cycles passes the colour) and for
Glass (the transmission tint), colour x the Schlick average for "schlick", colour x the Kulla-Conty dielectric
Fresnel average for "dielectric". The Refraction BSDF gets no compensation (Cycles applies none).
Implemented exactly that way; the per-lobe factor multiplies both eval and the sampled weight, never the pdf.
Approximations: our tables are our own deterministic quadrature of our own sampler, with Cycles' axes (they agree
with Cycles' shipped tables to ~1e-4 typically, 2e-3 at worst, e.g. E(rough 1, mu 1) = 0.30686 vs 0.30685); the
VNDF sample mapping is the spherical-cap one (same distribution as Cycles' Heitz 2018); transmission samples that
leave on wo's side (and reflections below the horizon) are invalid here, whereas Cycles keeps the former. As in
Cycles, the tables are read with linear interpolation, so a white compensated lobe has albedo 1 at grid points and
up to ~1% off between them near grazing. Like Cycles' scaling, the compensated lobe depends on cos(wo) only, so it
is *not* reciprocal (the single-scatter lobes are; `LobeBatch.multiscatter=False` gives them).

Unphysical refraction pairs (Cycles' behaviour, kept on purpose): `eval_bsdf` answers a glass / refraction pair
on the two sides of the surface with Walter's formula even where it is no physical refraction through any
microfacet (h = eta wi + wo with wo.h and wi.h of one sign; |wo.h| then enters the Fresnel), as Cycles'
bsdf_microfacet_eval does (it has no check for it). Sampling never produces such pairs, so the two estimators of
light through rough glass differ: next-event estimation finds more than BSDF sampling alone, and the MIS image lies
between them. Measured (Blender 5.3 Cycles, Glass r0.8 IOR 1.45 seen from inside at 40 deg, 2 x 2 area light 1 m
away): Cycles 2.97 with light sampling, 1.76 vs 1.77 (ours) with BSDF sampling only on an emissive quad; ours was
2.82 with MIS before answering those pairs. A rough frosted pane between an area light and a floor: ours was 11 %
darker at roughness 0.8, 1 % at 0.4. So `light_sampling` "bsdf" and "light" no longer agree through rough glass
(neither do Cycles' equivalents); "mis" is what Cycles renders.

Measured against Blender 5.0.1 Cycles (plane under a white world, ortho camera; pixel = directional albedo; ours
by 2M-sample MC): Glossy r1 colour 0.5 at 60 deg 0.30507 vs 0.30498; Glossy r0.5 colour 0.5 at 30 deg 0.47481
vs 0.47467; white Glossy r1 1.0002 vs 0.9995; Glass r0.5 ior 1.5 at 30 deg 1.0002 vs 0.9995, from inside 1.0018
vs 1.0014; Glass r1 from inside at 60 deg 0.9997 vs 0.9968 (+-0.0008); Glass r0.5 colour 0.5 0.4970 vs 0.4965;
Refraction r0.5 at 60 deg 0.98684 vs 0.98656, from inside at 30 deg 0.7912 vs 0.7913 (Cycles' errors 1e-4..8e-4).

Sampling (pbrt-style one-sample MIS over lobes)
-----------------------------------------------
A lobe is picked with probability `select` (Cycles' closure `sample_weight`: the mean of the lobe colour, times a
hemispherical Fresnel average for Fresnel-weighted glossy). A delta lobe returns weight = value / (select x event
probability), e.g. colour / select for smooth glass whichever of R (probability F) or T was chosen; its `pdf` is
select x event probability. A non-delta sample returns f_sum |cos| / pdf_sum, both summed over
all non-delta lobes at the sampled direction (the same quantities `eval_bsdf` returns), so BSDF samples and light
samples combine with MIS consistently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from . import bsdf_kernels as bk
from . import microfacet as mf
from .bsdf_kernels import (DIFFUSE, EMPTY, F_DIELECTRIC, F_GEN_SCHLICK, F_NONE, F_SCHLICK, GLASS,  # noqa: F401
                           GLOSSY, REFRACTION)
from .scene import Material, SceneError, Texture

F32 = np.float32

KINDS = ("diffuse", "glossy", "glass", "refraction")
KIND_CODE = {k: i for i, k in enumerate(KINDS)}
FRESNEL_CODE = {"none": 0, "schlick": 1, "dielectric": 2, "generalized_schlick": 3}


# --------------------------------------------------------------------------------------------------- batches
@dataclass
class LobeBatch:
    """Structure of arrays for N hits x L lobe slots (slots of a hit are filled from 0; empty slots have kind -1).

    kind (N, L) int8: -1 empty, 0 diffuse, 1 glossy, 2 glass, 3 refraction.
    weight (N, L, 3) float32: lobe colour with textures applied.
    roughness, ior (N, L) float32 (roughness already snapped to 0 where the lobe is a delta).
    fresnel (N, L) int8: 0 none, 1 schlick, 2 dielectric (glossy only).
    select (N, L) float32: lobe-choice probabilities, summing to 1 over the present lobes of a hit.
    multiscatter: apply Cycles' multiscatter-GGX energy compensation to glossy and glass lobes.
    f0 (N, L, 3) float32: reflectance at normal incidence of generalized-Schlick glossy lobes (else unused).
    under (N, L) int8: slot of the generalized-Schlick glossy lobe this lobe lies beneath, or -1 (see `Lobe.under`).
    tint (N, L, 2, 3) float32: reflection [:, :, 0] and transmission [:, :, 1] tints of glass lobes (else unused).
    f0, under and tint default to F0(ior), -1 and white.
    diffuse_normal (N, 3) float32 or None: the diffuse lobes' normal in each hit's local frame, where the frame's
    z (the microfacet lobes' normal) was tilted for valid specular reflection and the diffuse lobes keep the
    untilted one (Cycles' valid_reflection_N is a specular closure's only); None: +z for every hit.
    """

    kind: np.ndarray
    weight: np.ndarray
    roughness: np.ndarray
    ior: np.ndarray
    fresnel: np.ndarray
    select: np.ndarray
    multiscatter: bool = True
    f0: np.ndarray | None = None
    under: np.ndarray | None = None
    tint: np.ndarray | None = None
    diffuse_normal: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.f0 is None:
            r = (np.asarray(self.ior, F32) - 1.0) / (np.asarray(self.ior, F32) + 1.0)
            self.f0 = np.repeat((r * r)[..., None], 3, axis=-1).astype(F32)
        if self.under is None:
            self.under = np.full(np.shape(self.kind), -1, np.int8)
        if self.tint is None:
            self.tint = np.ones(np.shape(self.kind) + (2, 3), F32)

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    def arrays(self) -> tuple:
        """The lobe arrays as the compiled kernels take them (core.bsdf_kernels), C-contiguous."""
        return (np.ascontiguousarray(self.kind, np.int8), np.ascontiguousarray(self.weight, F32),
                np.ascontiguousarray(self.roughness, F32), np.ascontiguousarray(self.ior, F32),
                np.ascontiguousarray(self.fresnel, np.int8), np.ascontiguousarray(self.select, F32),
                np.ascontiguousarray(self.f0, F32), np.ascontiguousarray(self.under, np.int8),
                np.ascontiguousarray(self.tint, F32),
                np.zeros((0, 3), F32) if self.diffuse_normal is None
                else np.ascontiguousarray(self.diffuse_normal, F32).reshape(-1, 3))

    def take(self, rows: np.ndarray) -> "LobeBatch":
        """The sub-batch of the given hit rows (copies)."""
        return replace(
            self,
            kind=self.kind[rows],
            weight=self.weight[rows],
            roughness=self.roughness[rows],
            ior=self.ior[rows],
            fresnel=self.fresnel[rows],
            select=self.select[rows],
            f0=self.f0[rows],
            under=self.under[rows],
            tint=self.tint[rows],
            diffuse_normal=None if self.diffuse_normal is None else self.diffuse_normal[rows],
        )


@dataclass
class BsdfSample:
    """Result of `sample_bsdf` for N hits.

    wi (N, 3): sampled direction (local frame). weight (N, 3): f |cos wi| / pdf, lobe selection included.
    pdf (N,): solid-angle pdf of the non-delta mixture at wi (for delta samples: the discrete probability of the
    chosen event, for Russian roulette / logging only). delta (N,): a delta lobe was sampled (no MIS).
    transmitted (N,): wi is on the other side of the surface from wo. valid (N,): False ends the path."""

    wi: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray
    delta: np.ndarray
    transmitted: np.ndarray
    valid: np.ndarray


def select_for_view(lobes: LobeBatch, wo: np.ndarray, back: np.ndarray, material_index: np.ndarray,
                    table: "MaterialTable") -> None:
    """Rewrite, in place, the lobe-choice probabilities of the hits whose material chooses by the view
    (MaterialTable.view_select) for their local wo (N, 3; `back`: wo below the geometric surface), as the fused
    path kernel does at each vertex (core.bsdf_kernels.view_select_row). Every reader of lobes.select after this
    (eval_bsdf's pdf, sample_bsdf, the ray kinds) sees the same probabilities."""
    if not table.view_select.any() or len(lobes) == 0:
        return
    lobes.select = np.ascontiguousarray(lobes.select, F32)  # the array the kernel rewrites is the batch's own
    bk.view_selection_batch(lobes.arrays(), lobes.multiscatter, mf.kernel_tables(),
                            np.ascontiguousarray(wo, F32), np.ascontiguousarray(back, np.bool_),
                            np.ascontiguousarray(material_index, np.int64), table.view_select,
                            np.ascontiguousarray(table.select_scale, F32))


# -------------------------------------------------------------------------------------------------- materials
def _gen_schlick_fss(f0: np.ndarray, ior: float) -> np.ndarray:
    """Per-channel hemispherical Fresnel average of a generalized-Schlick lobe: f0 + (1 - f0) s_avg (Cycles' Fss)."""
    sa = float(bk.gen_schlick_s_avg(float(ior)))
    return np.asarray(f0, np.float64) + (1.0 - np.asarray(f0, np.float64)) * sa


def _lobe_select_scale(kind: int, fresnel: int, ior: float, f0: np.ndarray, layer: tuple | None,
                       tint: np.ndarray | None = None) -> float:
    """wo-independent estimate of a lobe's albedo relative to its colour (for lobe selection): the Fresnel average
    of a glossy lobe; for a lobe under a layer (layer = (f0, ior) of that layer) 1 - max_c Fss_c of the layer; for a
    tinted glass lobe (tint (2, 3): reflection, transmission) the mean of F rt + (1 - F) tt, F the Fresnel
    average (white glass: 1)."""
    scale = 1.0
    gen = fresnel == F_GEN_SCHLICK
    if kind == GLASS and tint is not None and (gen or np.any(np.asarray(tint) != 1.0)):
        fa = _gen_schlick_fss(f0 if gen else np.full(3, float(bk.schlick_f0(float(ior)))), ior)
        scale = float(np.mean(fa * tint[0] + (1.0 - fa) * tint[1]))
    elif kind == GLOSSY and fresnel == F_GEN_SCHLICK:
        scale = float(np.mean(_gen_schlick_fss(f0, ior)))
    elif kind == GLOSSY:
        scale = float(bk.glossy_fresnel_avg(fresnel, float(ior)))
    if layer is not None:
        scale *= min(max(1.0 - float(np.max(_gen_schlick_fss(*layer))), 0.0), 1.0)
    return scale


class MaterialTable:
    """All scene materials packed into (M, L) arrays; `gather` expands them per hit with textures applied."""

    def __init__(self, kind, color, roughness, ior, fresnel, texture, textures, emission, multiscatter=True,
                 f0=None, under=None, tint=None):
        self.kind = np.ascontiguousarray(kind, dtype=np.int8)
        self.color = np.ascontiguousarray(color, dtype=F32)
        self.roughness = np.ascontiguousarray(roughness, dtype=F32)
        self.ior = np.ascontiguousarray(ior, dtype=F32)
        self.fresnel = np.ascontiguousarray(fresnel, dtype=np.int8)
        defaults = LobeBatch(self.kind, self.color, self.roughness, self.ior, self.fresnel, self.roughness,
                             f0=f0, under=under, tint=tint)
        self.f0 = np.ascontiguousarray(defaults.f0, dtype=F32)
        self.under = np.ascontiguousarray(defaults.under, dtype=np.int8)
        self.tint = np.ascontiguousarray(defaults.tint, dtype=F32)
        self.texture = np.ascontiguousarray(texture, dtype=np.int32)
        self.textures = [np.ascontiguousarray(getattr(t, "pixels", t), dtype=F32)[..., :3] for t in textures]
        self.emission = np.ascontiguousarray(emission, dtype=F32).reshape(-1, 3)
        self.multiscatter = bool(multiscatter)
        m, l = self.kind.shape
        scale = np.ones((m, l), F32)
        for i in range(m):
            for j in range(l):
                u = int(self.under[i, j])
                layer = (self.f0[i, u], float(self.ior[i, u])) if u >= 0 else None
                scale[i, j] = _lobe_select_scale(int(self.kind[i, j]), int(self.fresnel[i, j]), float(self.ior[i, j]),
                                                 self.f0[i, j], layer, self.tint[i, j])
        self._select_scale = scale
        self._select = self._selection(self.kind, self.color, scale)
        # materials whose lobe choice follows the view (core.bsdf_kernels.view_select_row): more than one lobe, one
        # of them a glossy lobe with a Fresnel term or a lobe under a layer; the others keep the choice above
        present = self.kind >= 0
        follows_view = ((self.kind == GLOSSY) & (self.fresnel != F_NONE)) | (present & (self.under >= 0))
        self.view_select: np.ndarray = np.ascontiguousarray((present.sum(axis=1) > 1) & follows_view.any(axis=1))
        self.kinds_present: frozenset[str] = frozenset(KINDS[k] for k in np.unique(self.kind) if k >= 0)
        self.has_transmission: np.ndarray = np.any((self.kind == GLASS) | (self.kind == REFRACTION), axis=1)
        self._texture_ids = sorted(int(t) for t in np.unique(self.texture) if t >= 0)
        # Only images a lobe reads are packed here (node programs hold theirs in core.shading): each once.
        used = set(self._texture_ids)
        self._texture_pack = self._pack_textures([t if i in used else np.zeros((1, 1, 3), F32)
                                                  for i, t in enumerate(self.textures)])

    @staticmethod
    def _pack_textures(textures: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """All texture images in one flat float32 buffer for the gather kernel: (pixels, offset, height, width)."""
        sizes = [t.shape[0] * t.shape[1] * 3 for t in textures]
        offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if textures else np.zeros(0, np.int64)
        pixels = (np.concatenate([np.ascontiguousarray(t).reshape(-1) for t in textures]) if textures
                  else np.zeros(0, F32)).astype(F32)
        h = np.array([t.shape[0] for t in textures], np.int64)
        w = np.array([t.shape[1] for t in textures], np.int64)
        return pixels, offset, h, w

    @property
    def select_scale(self) -> np.ndarray:
        """(M, L) float32 albedo estimates relative to lobe colour, used for lobe selection (also by node programs,
        which keep a material's constant estimate: selection only shapes the variance, never the expectation)."""
        return self._select_scale

    @property
    def max_lobes(self) -> int:
        return int(self.kind.shape[1])

    @classmethod
    def build(
        cls, materials: Sequence[Material], textures: Sequence[Texture] = (), multiscatter: bool = True
    ) -> "MaterialTable":
        """Pack validated materials. Roughness <= 0.0266 (Cycles' singular threshold) becomes 0 (delta), as does
        rough glass/refraction with |ior - 1| < 1e-4 (Cycles treats that transmission as singular).
        Raises SceneError when a lobe's `under` is not another lobe of its material with Fresnel
        "generalized_schlick"."""
        m = len(materials)
        l = max([1] + [len(mat.lobes) for mat in materials])
        kind = np.full((m, l), EMPTY, np.int8)
        color = np.zeros((m, l, 3), F32)
        rough = np.zeros((m, l), F32)
        ior = np.ones((m, l), F32)
        fres = np.zeros((m, l), np.int8)
        tex = np.full((m, l), -1, np.int32)
        f0 = np.zeros((m, l, 3), F32)
        under = np.full((m, l), -1, np.int8)
        tint = np.ones((m, l, 2, 3), F32)
        emission = np.zeros((m, 3), F32)
        for i, mat in enumerate(materials):
            emission[i] = np.broadcast_to(np.asarray(mat.emission, dtype=F32).reshape(-1), (3,))
            for j, lobe in enumerate(mat.lobes):
                k = KIND_CODE[lobe.kind]
                kind[i, j] = k
                color[i, j] = np.broadcast_to(np.asarray(lobe.color, dtype=F32).reshape(-1), (3,))
                r = float(lobe.roughness)
                if r <= mf.SINGULAR_ROUGHNESS or (k in (GLASS, REFRACTION) and abs(lobe.ior - 1.0) < 1e-4):
                    r = 0.0
                rough[i, j] = min(r, 1.0)
                ior[i, j] = max(float(lobe.ior), 1e-5)
                fres[i, j] = FRESNEL_CODE[lobe.fresnel]
                tex[i, j] = int(lobe.color_texture)
                r0 = (ior[i, j] - 1.0) / (ior[i, j] + 1.0)
                lf0 = r0 * r0 if lobe.f0 is None else lobe.f0
                f0[i, j] = np.clip(np.broadcast_to(np.asarray(lf0, dtype=F32).reshape(-1), (3,)), 0.0, 1.0)
                for t, value in enumerate((lobe.reflection_tint, lobe.transmission_tint)):
                    if value is not None:
                        tint[i, j, t] = np.broadcast_to(np.asarray(value, dtype=F32).reshape(-1), (3,))
                u = int(lobe.under)
                if u >= 0:
                    if u >= len(mat.lobes) or u == j or mat.lobes[u].kind != "glossy" or \
                            mat.lobes[u].fresnel != "generalized_schlick":
                        raise SceneError(f"material {mat.name!r}: lobe {j} lies under lobe {u}, which is not a "
                                         "generalized-Schlick glossy lobe of the same material")
                    under[i, j] = u
        return cls(kind, color, rough, ior, fres, tex, list(textures), emission, multiscatter, f0, under, tint)

    def gather(self, material_index: np.ndarray, uv: np.ndarray | None = None) -> LobeBatch:
        """Per-hit lobes for (N,) material indices; `uv` (N, 2) for colour textures (missing UVs read (0, 0))."""
        mi = np.ascontiguousarray(np.asarray(material_index).reshape(-1), dtype=np.int64)
        n, l = len(mi), self.max_lobes
        if n and (mi.min() < 0 or mi.max() >= self.kind.shape[0]):  # the kernel does not bounds-check
            raise IndexError(f"material index out of range [0, {self.kind.shape[0]}): {mi.min()}..{mi.max()}")
        kind = np.empty((n, l), np.int8)
        weight = np.empty((n, l, 3), F32)
        rough = np.empty((n, l), F32)
        ior = np.empty((n, l), F32)
        fres = np.empty((n, l), np.int8)
        sel = np.empty((n, l), F32)
        f0 = np.empty((n, l, 3), F32)
        under = np.empty((n, l), np.int8)
        tint = np.empty((n, l, 2, 3), F32)
        has_uv = uv is not None and bool(self._texture_ids)
        uvs = np.ascontiguousarray(np.asarray(uv).reshape(-1, 2), dtype=F32) if has_uv else np.zeros((0, 2), F32)
        bk.gather_batch(mi, uvs, has_uv, self.kind, self.color, self.roughness, self.ior, self.fresnel, self.f0,
                        self.under, self.tint, self.texture, self._select, self._select_scale, *self._texture_pack,
                        kind, weight, rough, ior, fres, sel, f0, under, tint)
        return LobeBatch(kind, weight, rough, ior, fres, sel, self.multiscatter, f0, under, tint)

    @staticmethod
    def _selection(kind: np.ndarray, weight: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """Lobe-choice probabilities: mean colour x albedo estimate, normalised over the present lobes."""
        sel = np.empty(kind.shape, F32)
        bk.selection_batch(np.ascontiguousarray(kind, np.int8), np.ascontiguousarray(weight, F32),
                           np.ascontiguousarray(scale, F32), sel)
        return sel


# --------------------------------------------------------------------------------- evaluation and sampling
def _f32_rows(a: np.ndarray, cols: int) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=F32).reshape(-1, cols))


def _back_side(back: np.ndarray | None, wo: np.ndarray, caller: str) -> np.ndarray:
    """The (N,) bool side flags the kernels take: `back` as given, or wo.z < 0 (see the module docstring)."""
    if back is None:
        return np.ascontiguousarray(wo[:, 2] < 0)
    b = np.ascontiguousarray(np.asarray(back, dtype=bool).reshape(-1))
    if b.shape[0] != wo.shape[0]:
        raise ValueError(f"{caller}: back has {b.shape[0]} rows, wo {wo.shape[0]}")
    return b


def eval_bsdf(lobes: LobeBatch, wo: np.ndarray, wi: np.ndarray, rows: np.ndarray | None = None,
              back: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """f(wo, wi) |cos wi| summed over the non-delta lobes (N, 3) and the pdf of `sample_bsdf` producing wi through a
    non-delta lobe (N,): sum_l select_l pdf_l (solid angle).

    rows: optional (N,) indices into `lobes` giving the hit of each direction pair (same as `lobes.take(rows)`,
    without the copy); else wo and wi have one row per hit. back: optional (N,) bool, wo is behind the surface
    by its geometric normal (default wo.z < 0; see the module docstring)."""
    wo = _f32_rows(wo, 3)
    wi = _f32_rows(wi, 3)
    n = wo.shape[0]
    if wi.shape[0] != n:
        raise ValueError(f"eval_bsdf: wo has {n} rows, wi {wi.shape[0]}")
    side = _back_side(back, wo, "eval_bsdf")
    if rows is None:
        if len(lobes) != n:
            raise ValueError(f"eval_bsdf: {len(lobes)} hits but {n} directions")
        idx = np.zeros(0, np.int64)
    else:
        idx = np.ascontiguousarray(rows, dtype=np.int64).reshape(-1)
        if idx.shape[0] != n:
            raise ValueError(f"eval_bsdf: {idx.shape[0]} rows but {n} directions")
        if n and (idx.min() < 0 or idx.max() >= len(lobes)):
            raise IndexError(f"eval_bsdf: rows out of range for {len(lobes)} hits")
    f = np.empty((n, 3), F32)
    pdf = np.empty(n, F32)
    bk.eval_batch(lobes.arrays(), idx, rows is not None, lobes.multiscatter, mf.kernel_tables(), wo, wi, side, f,
                  pdf)
    return f, pdf


def sample_bsdf(lobes: LobeBatch, wo: np.ndarray, u_event: np.ndarray, u: np.ndarray,
                back: np.ndarray | None = None) -> BsdfSample:
    """Sample wi for each hit: u[:, 0] picks a lobe with `select` and, rescaled within the chosen lobe's
    interval, samples its direction with u[:, 1] (core.bsdf_kernels.sample_path: each lobe's directions keep the
    pair's stratification); u_event (N,) picks reflection vs refraction for glass. back: optional (N,) bool, wo is
    behind the surface by its geometric normal (default wo.z < 0). See the module docstring for the side and
    weight conventions."""
    n = len(lobes)
    wo = _f32_rows(wo, 3)
    u_event = np.ascontiguousarray(np.asarray(u_event, dtype=F32).reshape(-1))
    u = _f32_rows(u, 2)
    if not (wo.shape[0] == u_event.shape[0] == u.shape[0] == n):
        raise ValueError(f"sample_bsdf: {n} hits, wo {wo.shape[0]}, u_event {u_event.shape[0]}, u {u.shape[0]} rows")
    side = _back_side(back, wo, "sample_bsdf")
    wi = np.empty((n, 3), F32)
    weight = np.empty((n, 3), F32)
    pdf = np.empty(n, F32)
    delta = np.empty(n, bool)
    transmitted = np.empty(n, bool)
    valid = np.empty(n, bool)
    bk.sample_batch(lobes.arrays(), lobes.multiscatter, mf.kernel_tables(), wo, side, u_event, u, wi, weight, pdf,
                    delta, transmitted, valid)
    return BsdfSample(wi=wi, weight=weight, pdf=pdf, delta=delta, transmitted=transmitted, valid=valid)


def albedo(lobes: LobeBatch, wo: np.ndarray | None = None) -> np.ndarray:
    """Albedo AOV (N, 3): sum of lobe colours, Fresnel-weighted glossy lobes scaled by their Fresnel estimate --
    F(cos wo) when `wo` is given (as Cycles' `bsdf_microfacet_estimate_fresnel` at the shading normal), else the
    hemispherical average; generalized-Schlick lobes by their albedo estimate A(wo) (else their Fss) and lobes
    under them by the layering factor (else 1 - max Fss). Glass counts R + T = 1 (tinted glass its estimate
    F rt + (1 - F) tt), refraction its colour."""
    n = len(lobes)
    out = np.empty((n, 3), F32)
    w = _f32_rows(wo, 3) if wo is not None else np.zeros((0, 3), F32)
    bk.albedo_batch(lobes.arrays(), lobes.multiscatter, mf.kernel_tables(), w, wo is not None, out)
    return out
