"""Cycles' light passes: a path's contribution split by the kind of its FIRST bounce, direct vs indirect.

The passes (Cycles' names and meaning, Blender 5.3):

- Diffuse / Glossy / Transmission Direct: light reaching the camera after exactly one scattering event at the
  first surface (next-event estimation there, and emission that the first bounce's ray finds), the part of it the
  first surface's diffuse / glossy / transmitting lobes scattered;
- ... Indirect: everything after two or more scattering events, attributed to the kind of the FIRST bounce;
- ... Color: the first surface's lobe albedos of that kind (core.bsdf.albedo at the incoming direction; a glass
  lobe counts its Fresnel-reflected share F(cos wo) as glossy and the rest as transmission);
- Emission: emitters (lamps, emissive surfaces) seen directly by the camera;
- Environment: the world seen directly by the camera (0 where Film > Transparent made it transparent).

A pass through a Transparent BSDF is no bounce (Cycles' transparent bounces): what is seen through one counts as
seen directly, the first surface scattered from behind it is the first bounce, and each surface met through
Transparent BSDFs alone adds its colours (times the throughput reaching it); core.integrator classes the
contributions by its per-path bounce counts.

How a first-surface contribution is split (Cycles' bsdf_eval diffuse / glossy / sum): for a direction wi the
lobes' values f_K(wi) are summed per kind K, a glass lobe counting as glossy where wi is on wo's side and as
transmission where it crosses, and the contribution c goes c f_K / f to kind K (per channel; the three shares
sum to 1 up to float rounding). A delta (mirror, clear glass)
sample goes whole to the kind of the lobe it came from. The weights of the first bounce are kept per camera
sample and split everything the path gathers later.

Direct and Indirect are stored as Cycles stores them: divided by their Color pass per pixel (a channel whose
colour is 0 takes the mean of the other channels' ratios, Cycles' even-colour division), so that

    Combined = (Diffuse Direct + Diffuse Indirect) x Diffuse Color
             + (Glossy Direct + Glossy Indirect) x Glossy Color
             + (Transmission Direct + Transmission Indirect) x Transmission Color + Emission + Environment

per pixel (RGB), up to float32 rounding and to pixels where a Color channel is 0 but light came through.

Nothing here runs unless a render asks for a light pass (core.settings.RenderSettings.light_passes); the passes
draw no random numbers, so the image is bit for bit the image rendered without them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from . import bsdf as bsdf_mod

COMPONENTS = ("Diffuse", "Glossy", "Transmission")
# Every light pass, in the order of the accumulation arrays (one (N, 3) slab each).
LIGHT_PASSES = tuple(f"{c} {part}" for c in COMPONENTS for part in ("Direct", "Indirect", "Color")) + (
    "Emission", "Environment")
PASS_INDEX = {name: i for i, name in enumerate(LIGHT_PASSES)}
_DIRECT = {c: PASS_INDEX[f"{c} Direct"] for c in COMPONENTS}
_INDIRECT = {c: PASS_INDEX[f"{c} Indirect"] for c in COMPONENTS}
_COLOR = {c: PASS_INDEX[f"{c} Color"] for c in COMPONENTS}
EMISSION, ENVIRONMENT = PASS_INDEX["Emission"], PASS_INDEX["Environment"]


def check_names(names) -> tuple[str, ...]:
    """The requested light passes as a tuple, ValueError naming any that is not one of LIGHT_PASSES."""
    if isinstance(names, str):
        raise ValueError(f"light passes must be a sequence of pass names, got the string {names!r}")
    names = tuple(names)
    unknown = [n for n in names if n not in PASS_INDEX]
    if unknown:
        raise ValueError(f"unknown light pass(es) {unknown}; Monte's light passes are {list(LIGHT_PASSES)}")
    return names


def _masked(lobes: "bsdf_mod.LobeBatch", kind: int) -> "bsdf_mod.LobeBatch":
    """The lobes with every slot not of `kind` emptied (the layering data of other slots stays readable)."""
    return replace(lobes, kind=np.where(lobes.kind == kind, lobes.kind, np.int8(-1)).astype(np.int8))


def split_ratios(lobes: "bsdf_mod.LobeBatch", wo: np.ndarray, wi: np.ndarray, back: np.ndarray,
                 rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(diffuse, glossy, transmission shares) (M, 3) float32 of the lobes' value f(wo, wi) |cos wi| (local
    frame, as core.bsdf.eval_bsdf takes them, rows/back likewise): f_K / f per channel, 0 where f is 0. Lobes
    of a single kind need no evaluation (kinds absent from the batch are skipped)."""
    m = len(wo)
    present = set(np.unique(lobes.kind).tolist()) - {-1}
    ones, zeros = np.ones((m, 3), np.float32), np.zeros((m, 3), np.float32)
    if present == {bsdf_mod.KIND_CODE["diffuse"]}:
        return ones, zeros, zeros.copy()
    if present == {bsdf_mod.KIND_CODE["glossy"]}:
        return zeros, ones, zeros.copy()
    f = {}
    for name in ("diffuse", "glossy", "glass", "refraction"):
        code = bsdf_mod.KIND_CODE[name]
        f[name] = (bsdf_mod.eval_bsdf(_masked(lobes, code), wo, wi, rows=rows, back=back)[0].astype(np.float64)
                   if code in present else np.zeros((m, 3)))
    total = f["diffuse"] + f["glossy"] + f["glass"] + f["refraction"]
    reflected = ((np.asarray(wi)[:, 2] > 0) != np.asarray(back, bool))[:, None]  # wi on wo's geometric side
    parts = (f["diffuse"], f["glossy"] + np.where(reflected, f["glass"], 0.0),
             f["refraction"] + np.where(reflected, 0.0, f["glass"]))
    with np.errstate(invalid="ignore", divide="ignore"):
        safe = np.where(total > 0, total, 1.0)
        return tuple(np.where(total > 0, np.clip(part / safe, 0, 1), 0.0).astype(np.float32) for part in parts)


def _fresnel_dielectric(cos_i: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a dielectric interface (eta = n_transmitted / n_incident); 1 beyond
    total internal reflection."""
    c = np.abs(cos_i).astype(np.float64)
    g2 = eta.astype(np.float64) ** 2 - 1.0 + c * c
    g = np.sqrt(np.maximum(g2, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        f = 0.5 * a * a * (1.0 + b * b)
    return np.where(g2 > 0, np.nan_to_num(f, nan=1.0), 1.0)


def _multiscatter_darkening(lobes: "bsdf_mod.LobeBatch", slot: int, glossy: np.ndarray, wo: np.ndarray
                            ) -> np.ndarray:
    """(M, 3) factor E + Fms (1 - E) of the rough Fresnel-less glossy lobes in `slot` (Glossy BSDF): Cycles
    folds the multiscatter compensation's darkening and saturation, (1 + Fms (1 - E) / E) / (1 / E) with
    Fms = Fss Eavg / (1 - Fss (1 - Eavg)) and Fss the colour, into the closure's weight, so its Glossy Color
    carries it; 1 for every other lobe."""
    from . import microfacet

    rough = lobes.roughness[:, slot].astype(np.float64)
    apply = glossy & (rough > 0) & (lobes.fresnel[:, slot] == bsdf_mod.FRESNEL_CODE["none"])
    out = np.ones((len(rough), 3), np.float32)
    rows = np.flatnonzero(apply)
    if len(rows) == 0:
        return out
    e = microfacet.ggx_E(rough[rows], np.abs(wo[rows, 2])).astype(np.float64)[:, None]
    e_avg = microfacet.ggx_Eavg(rough[rows]).astype(np.float64)[:, None]
    fss = np.clip(lobes.weight[rows, slot].astype(np.float64), 0.0, 1.0)
    fms = fss * e_avg / np.maximum(1.0 - fss * (1.0 - e_avg), 1e-6)
    out[rows] = (e + fms * (1.0 - e)).astype(np.float32)
    return out


def colors(lobes: "bsdf_mod.LobeBatch", wo: np.ndarray, back: np.ndarray) -> tuple[np.ndarray, ...]:
    """(diffuse, glossy, transmission) colours (M, 3) float32 of first surfaces: per lobe kind the lobe albedos
    at wo (core.bsdf.albedo, Fresnel and layering included; a rough Glossy BSDF lobe with its multiscatter
    darkening, see _multiscatter_darkening), a glass lobe split F(cos wo) : 1 - F between glossy and
    transmission, a Transparent BSDF lobe in none."""
    m, n_slots = lobes.kind.shape
    out = [np.zeros((m, 3), np.float32) for _ in COMPONENTS]
    wo = np.ascontiguousarray(wo, np.float32)
    slot_of = np.arange(n_slots)[None, :]
    for slot in range(n_slots):
        kind = lobes.kind[:, slot]
        if not (kind >= 0).any():
            continue
        only = replace(lobes, kind=np.where(slot_of == slot, lobes.kind, -1).astype(np.int8))
        albedo = bsdf_mod.albedo(only, wo)
        out[0] += np.where((kind == bsdf_mod.KIND_CODE["diffuse"])[:, None], albedo, 0)
        glossy = kind == bsdf_mod.KIND_CODE["glossy"]
        if glossy.any() and lobes.multiscatter:
            albedo = albedo * _multiscatter_darkening(lobes, slot, glossy, wo)
        out[1] += np.where(glossy[:, None], albedo, 0)
        # a Transparent BSDF (refraction of IOR 1, roughness 0) is no transmission colour (Cycles: its closure is
        # not a transmission closure; what is seen through it has a colour of its own)
        clear = (lobes.ior[:, slot] == 1.0) & (lobes.roughness[:, slot] == 0.0)
        out[2] += np.where(((kind == bsdf_mod.KIND_CODE["refraction"]) & ~clear)[:, None], albedo, 0)
        glass = kind == bsdf_mod.KIND_CODE["glass"]
        if glass.any():
            ior = lobes.ior[:, slot].astype(np.float64)
            eta = np.where(back, 1.0 / np.maximum(ior, 1e-6), ior)
            f = _fresnel_dielectric(wo[:, 2], eta)[:, None].astype(np.float32)
            out[1] += np.where(glass[:, None], albedo * f, 0)
            out[2] += np.where(glass[:, None], albedo * (1 - f), 0)
    return tuple(out)


class LightPassSamples:
    """The light passes of N camera samples while their paths are traced: `values` (N, len(LIGHT_PASSES), 3)
    float32 sums (Direct / Indirect not yet divided by their colour), and the first bounce's diffuse and glossy
    weights of each sample (see the module docstring)."""

    def __init__(self, n: int) -> None:
        # pass-major storage: each pass's (N, 3) block is contiguous for the indexed adds
        self._passes = np.zeros((len(LIGHT_PASSES), n, 3), np.float32)
        self.weight_diffuse = np.zeros((n, 3), np.float32)
        self.weight_glossy = np.zeros((n, 3), np.float32)
        self.weight_transmission = np.zeros((n, 3), np.float32)

    def add(self, which: int, idx: np.ndarray, value: np.ndarray) -> None:
        """values[idx, which] += value; idx holds each sample at most once (every caller adds one contribution
        per live path, and a sample has one path), so a plain indexed add is exact."""
        self._passes[which][idx] += np.asarray(value, np.float32)

    @property
    def values(self) -> np.ndarray:
        """(N, len(LIGHT_PASSES), 3) view of the sums (writable)."""
        return self._passes.transpose(1, 0, 2)

    def add_split(self, direct: bool, idx: np.ndarray, value: np.ndarray,
                  shares: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        """Split contributions of samples idx by (diffuse, glossy, transmission) shares (default: each sample's
        first bounce weights) into the Direct or Indirect passes. The shares sum to 1 (to float rounding) where
        the BSDF is not 0, so the parts sum to the contribution."""
        value = np.asarray(value, np.float32)
        if shares is None:
            shares = (self.weight_diffuse[idx], self.weight_glossy[idx], self.weight_transmission[idx])
        table = _DIRECT if direct else _INDIRECT
        for comp, share in zip(COMPONENTS, shares):
            self.add(table[comp], idx, value * share)

    def add_colors(self, idx: np.ndarray, cols: tuple[np.ndarray, ...], throughput: np.ndarray) -> None:
        for comp, col in zip(COMPONENTS, cols):
            self.add(_COLOR[comp], idx, col * throughput)


def clean_contributions(value: np.ndarray, clamp: float) -> tuple[np.ndarray, int, int]:
    """Contributions as core.path_kernels.accumulate adds them: (value with non-finite rows 0 and rows above
    `clamp` > 0 scaled down to it, non-finite row count, clamped row count)."""
    value = np.asarray(value, np.float32)
    finite = np.isfinite(value).all(axis=1)
    out = np.where(finite[:, None], value, np.float32(0)).astype(np.float32)
    clamped = 0
    if clamp > 0:
        peak = out.max(axis=1)
        over = peak > clamp
        clamped = int(over.sum())
        if clamped:
            out[over] *= (np.float32(clamp) / peak[over])[:, None]
    return out, int((~finite).sum()), clamped


def even_divide(value: np.ndarray, color: np.ndarray) -> np.ndarray:
    """value / color per channel where color != 0; a channel of colour 0 takes the mean of the other channels'
    ratios (0 when all are 0): Cycles' division of light passes by their colour."""
    value = np.asarray(value, np.float64)
    color = np.asarray(color, np.float64)
    nz = color != 0
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(nz, value / np.where(nz, color, 1.0), 0.0)
    count = nz.sum(axis=-1, keepdims=True)
    fill = ratio.sum(axis=-1, keepdims=True) / np.maximum(count, 1)
    return np.where(nz, ratio, fill).astype(np.float32)


def finish(means: np.ndarray) -> dict[str, np.ndarray]:
    """The light pass images from the per-pixel means (..., len(LIGHT_PASSES), 3): Direct and Indirect divided by
    their colour (even_divide), the others as they are; name -> (..., 3) float32."""
    out = {}
    for name, i in PASS_INDEX.items():
        arr = means[..., i, :]
        comp, _, part = name.partition(" ")
        if part in ("Direct", "Indirect"):
            arr = even_divide(arr, means[..., _COLOR[comp], :])
        out[name] = np.asarray(arr, np.float32)
    return out


def recombine(passes: dict[str, np.ndarray]) -> np.ndarray:
    """Combined RGB rebuilt from the light passes (Cycles' relation, see the module docstring)."""
    total = passes["Emission"].astype(np.float64) + passes["Environment"]
    for comp in COMPONENTS:
        total = total + (passes[f"{comp} Direct"].astype(np.float64) + passes[f"{comp} Indirect"]) \
            * passes[f"{comp} Color"]
    return total.astype(np.float32)
