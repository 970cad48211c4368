"""The stress suite: scenes where renderers usually break, each measured against a known answer.

Every case renders a scene whose image is known: the seed's Cornell box under a transformation that must not
change the image (scale, translation, re-tessellation, junk geometry, flipped winding), or an analytic scene
(a white furnace: a closed or lossless scene in a uniform radiance field, where every pixel has a closed-form
value). Each case reports numbers, never pictures:

- nonfinite: NaN/Inf values in the image (must be 0), and NaN/Inf path contributions caught and dropped;
- mean: the image's channel means against the reference's, with a tolerance derived from the sample count:
  tol = K_SIGMA x sqrt(sigma_case^2 + sigma_ref^2) + floor, the sigmas being standard errors of the means
  estimated from the per-pixel variance of each render, and floor a float32 precision term (1e-5 relative)
  for zero-variance answers. Cases compared with the canonical Cornell render use the same seed and sampling
  (common random numbers) at `paired_spp`: their noise largely cancels pixel by pixel, so sigma is that of the
  paired per-pixel differences (paired_sigma), and a 2 % change of the image fails (tests/test_stress.py
  proves it on the noisiest case);
- wall (Cornell cases): a flat region of the back wall, picked from the canonical render's first-hit normal and
  depth; self-intersection shows up there as dark speckle, so the wall's mean and its pixel spread are
  compared with the same region of the canonical render. The spread is a robust variance (scaled median
  absolute deviation): at a few samples per pixel single caustic outliers rule the plain variance (its ratio
  between two seeds of the same scene ranged 0.35-7 on a 73-pixel wall). Its ratio limit follows from the
  number of wall pixels n: exp(K_SIGMA x sqrt(2 x 5.4 / n)) (log of a MAD^2 has variance ~5.4 / n);
- case-specific checks (warning counts, sample counts, bias and variance under clamping, peak memory).

A case is "required" when Monte promises the answer; "probe" cases push past the promise to find where things
degrade, and report without failing the suite. `run_suite` returns the results; `write_report` writes
report.json and report.md. See docs/stress.md for the measured table.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..core import builtin_scenes as scenes
from ..core import metrics
from ..core.compare import box_smooth
from ..core.render import RenderResult, render
from ..core.scene import Camera, Lobe, Material, Mesh, Scene, SunLight, World
from ..core.settings import RenderSettings

K_SIGMA = 5.0  # tolerance in standard errors: ~40 cases, so a false alarm at 5 sigma is negligible
FLOOR_REL = 1e-5  # float32 accumulation precision, for references with zero variance


@dataclass
class StressConfig:
    """Sizes of a suite run: Cornell cases render `resolution` squared at `spp`; the canonical Cornell box and the
    cases compared with it pixel by pixel at `paired_spp` (default: spp), enough for a 2 % change to show."""

    resolution: int = 64
    spp: int = 64
    paired_spp: int | None = None
    quick: bool = False
    threads: int = 0
    seed: int = 1
    big_resolution: tuple[int, int] = (7680, 4320)
    huge_spp: int = 65536
    # (core Scene, RenderSettings) -> {"mean": [R, G, B], "nonfinite": int, "note": str}: renders the same case
    # with Cycles (lab.core_to_bpy.cycles_renderer, passed in by `monte stress --cycles`); None: Monte only.
    cycles: Callable | None = None

    @classmethod
    def full(cls) -> "StressConfig":
        return cls()

    @classmethod
    def quick_run(cls) -> "StressConfig":
        return cls(resolution=32, spp=16, quick=True, big_resolution=(1920, 1080), huge_spp=4096)

    @classmethod
    def test_run(cls) -> "StressConfig":
        """The reduced suite the default tests run (tiny images, few samples; the cases compared with the
        canonical box pixel by pixel at 1024 spp, where their 5-sigma tolerances are <= 1.3 %: a 2 % change fails)."""
        return cls(resolution=20, spp=8, paired_spp=1024, quick=True, threads=2, big_resolution=(480, 270),
                   huge_spp=1024)


@dataclass
class CaseResult:
    """The numbers of one case. mean/reference: channel means; tolerance: absolute, per channel."""

    name: str
    group: str
    description: str
    reference_kind: str
    required: bool = True
    passed: bool = False
    nonfinite_pixels: int = 0
    caught_samples: int = 0
    mean: list[float] = field(default_factory=list)
    reference: list[float] = field(default_factory=list)
    tolerance: list[float] = field(default_factory=list)
    sigma: list[float] = field(default_factory=list)  # the standard error the tolerance was built on
    rel_error: float = 0.0
    wall_mean_ratio: float | None = None
    wall_variance_ratio: float | None = None
    wall_variance_limit: float | None = None
    checks: dict = field(default_factory=dict)
    notes: str = ""
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    peak_memory_mb: float | None = None
    cycles: dict | None = None

    @property
    def status(self) -> str:
        if self.passed:
            return "pass"
        return "FAIL" if self.required else "degrades"


# ------------------------------------------------------------------------------------------- scene helpers
def transform_scene(scene: Scene, scale: float = 1.0, offset=(0.0, 0.0, 0.0)) -> Scene:
    """Scale the whole scene (camera and clipping included) about the origin, then translate it. Radiance
    does not depend on scale, so the image must not change."""
    offset = np.asarray(offset, np.float64)
    for mesh in scene.meshes:
        mesh.vertices = np.asarray(mesh.vertices, np.float64) * scale + offset
    cam = scene.camera
    cam.matrix_world = np.asarray(cam.matrix_world, np.float64).copy()
    cam.matrix_world[:3, 3] = cam.matrix_world[:3, 3] * scale + offset
    cam.clip_start *= scale
    return scene


def box_mesh(name: str, lo, hi, material: int, inward: bool = False) -> Mesh:
    """An axis-aligned box of 12 triangles, normals outward (inward=True reverses them)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    v = np.array([[lo[0] if i & 1 == 0 else hi[0], lo[1] if i & 2 == 0 else hi[1], lo[2] if i & 4 == 0 else hi[2]]
                  for i in range(8)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.int32)
    if inward:
        tris = tris[:, ::-1].copy()
    return Mesh(name, v, tris, material)


def uv_sphere(name: str, center, radius: float, material: int, segments: int, rings: int,
              smooth: bool = True) -> Mesh:
    """A UV sphere with few faces and exact smooth normals: the shading normal is far from the geometric one
    near the silhouette of each facet (the shadow terminator problem)."""
    theta = np.linspace(0, math.pi, rings + 1)
    phi = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    tris = []
    for r in range(rings):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            c, d = a + segments, b + segments
            if r > 0:
                tris.append((a, c, b))
            if r < rings - 1:
                tris.append((b, c, d))
    tris = np.array(tris, np.int32)
    normals = unit[tris].astype(np.float32) if smooth else None
    return Mesh(name, unit * radius + np.asarray(center, np.float64), tris, material, normals=normals)


def _white_furnace(meshes: list[Mesh], materials: list[Material], resolution: int, world: float = 1.0) -> Scene:
    """Objects near the origin inside a uniform world of radiance `world`, seen from (0, -4, 0.3). With
    lossless (colour 1) dielectrics and black emitters of radiance equal to the world, every pixel is `world`."""
    cam = Camera.look_at((0, -4.0, 0.3), (0, 0, 0), horizontal_fov=math.radians(28.0),
                         resolution=(resolution, resolution))
    return Scene(camera=cam, meshes=meshes, materials=materials, world=World(np.full(3, world)), name="furnace")


def _glass(ior: float, roughness: float = 0.0, name: str = "glass") -> Material:
    return Material(name, [Lobe("glass", np.ones(3), roughness=roughness, ior=ior)])


def _plane_scene(resolution: int, eye, target, fov_deg: float, size: float = 1e6, albedo: float = 0.8,
                 world: float = 1.0, lights=None, up=(0, 0, 1), strips: int = 0) -> Scene:
    """A huge diffuse plane z = 0 of albedo rho under a uniform sky Lw: its radiance is rho x Lw everywhere
    (one bounce, it sees only the sky). strips > 0 cuts it into that many long, thin triangles pairs."""
    s = size
    if strips:
        xs = np.linspace(-s, s, strips + 1)
        v = np.concatenate([np.stack([xs, np.full_like(xs, -s), np.zeros_like(xs)], 1),
                            np.stack([xs, np.full_like(xs, s), np.zeros_like(xs)], 1)])
        n = strips + 1
        tris = np.array([t for i in range(strips) for t in ((i, i + 1, n + i + 1), (i, n + i + 1, n + i))], np.int32)
        mesh = Mesh("plane", v, tris, 0)
    else:
        mesh = scenes.quad("plane", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], 0)
    cam = Camera.look_at(eye, target, up=up, horizontal_fov=math.radians(fov_deg), resolution=(resolution, resolution))
    return Scene(camera=cam, meshes=[mesh], materials=[Material("plane", [Lobe("diffuse", np.full(3, albedo))])],
                 lights=list(lights or []), world=World(np.full(3, world)), name="plane")


def _replace_mesh(scene: Scene, name: str, mesh: Mesh) -> Scene:
    scene.meshes = [mesh if m.name == name else m for m in scene.meshes]
    return scene


def _back_wall_strips(n: int) -> Mesh:
    """The Cornell back wall (x in [-1, 1], z in [0, 2] at y = 1) as n horizontal strips: 2n triangles with
    aspect ratio n : 1."""
    z = np.linspace(0, 2, n + 1)
    v = np.concatenate([np.stack([np.full_like(z, -1), np.ones_like(z), z], 1),
                        np.stack([np.full_like(z, 1), np.ones_like(z), z], 1)])
    tris = np.array([t for i in range(n) for t in ((i, n + 1 + i, n + 2 + i), (i, n + 2 + i, i + 1))], np.int32)
    return Mesh("back", v, tris, 0)


def _back_wall_fan(n: int) -> Mesh:
    """The back wall as a fan of n needles from the corner (-1, 1, 0) to points along the two far edges."""
    s = np.linspace(0, 1, n // 2 + 1)
    rim = np.concatenate([np.stack([np.ones_like(s), np.ones_like(s), 2 * s], 1),       # right edge, upwards
                          np.stack([1 - 2 * s[1:], np.ones_like(s[1:]), np.full_like(s[1:], 2)], 1)])  # top edge
    v = np.concatenate([[(-1.0, 1.0, 0.0)], rim])
    tris = np.array([(0, i + 2, i + 1) for i in range(len(rim) - 1)], np.int32)
    return Mesh("back", v, tris, 0)


# ------------------------------------------------------------------------------------------------ measuring
class Context:
    """Renders shared between cases (the canonical Cornell box) and the settings of this run."""

    def __init__(self, cfg: StressConfig, log: Callable[[str], None]) -> None:
        self.cfg = cfg
        self.log = log
        self._canonical: RenderResult | None = None
        self._wall: np.ndarray | None = None

    def settings(self, **kw) -> RenderSettings:
        base = dict(spp=self.cfg.spp, seed=self.cfg.seed, threads=self.cfg.threads)
        base.update(kw)
        return RenderSettings(**base)

    def paired_settings(self, **kw) -> RenderSettings:
        """Settings of the canonical render and of the cases compared with it pixel by pixel (same seed)."""
        return self.settings(**{"spp": self.cfg.paired_spp or self.cfg.spp, **kw})

    def cornell(self, **kw) -> Scene:
        return scenes.cornell_box((self.cfg.resolution, self.cfg.resolution), **kw)

    def render(self, scene: Scene, settings: RenderSettings, **kw) -> RenderResult:
        """Monte's render of a case; with a Cycles renderer configured, Cycles' too (as result.cycles) where
        Cycles gives a meaningful answer (at least one sample, at most 4 M pixels, no cancel or time limit)."""
        result = render(scene, settings, **kw)
        w, h = scene.camera.resolution
        if (self.cfg.cycles is not None and settings.spp >= 1 and w * h <= 4_000_000 and not kw
                and settings.time_limit == 0):
            try:
                result.cycles = self.cfg.cycles(scene, settings)
            except Exception as exc:  # a case Cycles cannot take is reported, not fatal to the suite
                result.cycles = {"mean": [], "nonfinite": 0, "note": f"Cycles failed: {exc}"}
        return result

    @property
    def canonical(self) -> RenderResult:
        if self._canonical is None:
            self._canonical = self.render(self.cornell(), self.paired_settings())
        return self._canonical

    @property
    def wall(self) -> np.ndarray:
        """(H, W) bool: pixels whose first hit is the flat back wall (normal -y, depth 4.9) in every sample."""
        if self._wall is None:
            c = self.canonical
            self._wall = (c.normal[..., 1] < -0.9999) & (np.abs(c.depth - 4.9) < 0.01)
        return self._wall


def _sigma(result: RenderResult) -> np.ndarray:
    return metrics.channel_mean_sigma(result.variance)


def paired_sigma(result: RenderResult, reference: RenderResult) -> np.ndarray:
    """(3,) standard error of the difference of two renders' channel means, from their per-pixel differences d.
    Meant for two renders with the same seed and sampling (common random numbers), whose noise largely cancels
    pixel by pixel. Pixels are independent, so Var(mean d) = sum Var(d_p) / n^2; where the expected images are
    equal E[d_p] = 0 and sum d_p^2 estimates it. A change of the image (a brighter lamp: E[d_p] = c ref_p) would
    inflate that sum by c^2 sum ref_p^2 and hide itself, so the residuals r = d - c ref, with c = sum d / sum ref
    the change the two images show, are used instead: sqrt(sum r^2 / (n - 1)) / sqrt(n)."""
    a = np.nan_to_num(result.color[..., :3].astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0).reshape(-1, 3)
    b = np.asarray(reference.color[..., :3], np.float64).reshape(-1, 3)
    d = a - b
    c = d.sum(axis=0) / np.where(b.sum(axis=0) != 0, b.sum(axis=0), 1.0)
    r = d - c * b
    n = d.shape[0]
    return np.sqrt((r * r).sum(axis=0) / max(n - 1, 1) / n)


def measure(ctx: Context, name: str, group: str, description: str, result: RenderResult, reference_mean,
            reference_sigma=None, *, reference_kind: str, wall_reference: RenderResult | None = None,
            paired: RenderResult | None = None, required: bool = True, extra_tolerance: float = 0.0,
            notes: str = "", checks: dict | None = None, seconds: float = 0.0) -> CaseResult:
    """Compare a render with a reference mean (and optionally the canonical wall), into a CaseResult.
    paired: the reference render itself, when it was rendered with the same seed, resolution and sampling: the
    tolerance then uses the paired sigma (paired_sigma), far smaller than the two renders' own sigmas.
    extra_tolerance: a relative allowance for a known, documented model difference (0 for exact answers)."""
    color = result.color[..., :3]
    nonfinite = int((~np.isfinite(result.color)).sum() + (~np.isfinite(result.variance)).sum())
    mean = metrics.channel_means(np.nan_to_num(color, nan=0.0, posinf=0.0, neginf=0.0))
    ref = np.broadcast_to(np.asarray(reference_mean, np.float64), (3,))
    ref_sigma = np.zeros(3) if reference_sigma is None else np.broadcast_to(np.asarray(reference_sigma), (3,))
    sigma = np.sqrt(_sigma(result) ** 2 + ref_sigma ** 2)
    if paired is not None and paired.color.shape == result.color.shape:
        sigma = paired_sigma(result, paired)
    tol = K_SIGMA * sigma + FLOOR_REL * np.abs(ref) + extra_tolerance * np.abs(ref)
    rel = float(np.max(np.abs(mean - ref) / np.maximum(np.abs(ref), 1e-12)))
    ok_mean = bool(np.all(np.abs(mean - ref) <= tol))
    case = CaseResult(name, group, description, reference_kind, required=required, nonfinite_pixels=nonfinite,
                      caught_samples=int(result.stats.get("nonfinite_samples", 0)), mean=mean.tolist(),
                      reference=ref.tolist(), tolerance=tol.tolist(), sigma=sigma.tolist(), rel_error=rel, notes=notes,
                      warnings=list(result.warnings), checks=dict(checks or {}),
                      seconds=seconds or float(result.stats.get("seconds", 0.0)),
                      peak_memory_mb=result.stats.get("peak_memory_mb"))
    cycles = getattr(result, "cycles", None)
    if cycles is not None:
        case.cycles = dict(cycles)
        if cycles.get("mean") and case.mean:
            ref = np.maximum(np.abs(np.asarray(case.mean, float)), 1e-9)
            rel = (np.asarray(cycles["mean"], float) - np.asarray(case.mean, float)) / ref
            case.cycles["relative_to_monte"] = rel.tolist()
            extra = f"Cycles/Monte {1 + float(np.mean(rel)):.3f}"
            if cycles.get("nonfinite"):
                extra += f", Cycles NaN/Inf px {cycles['nonfinite']}"
            case.cycles["note"] = "; ".join(v for v in (extra, cycles.get("note", "")) if v)
    ok_wall = True
    if wall_reference is not None and result.color.shape == wall_reference.color.shape:
        mask = ctx.wall
        n = int(mask.sum())
        if n >= 4:
            lum_case = color[mask] @ metrics.BT709
            lum_ref = wall_reference.color[..., :3][mask] @ metrics.BT709
            case.wall_mean_ratio = float(lum_case.mean() / lum_ref.mean())
            case.wall_variance_ratio = float(_robust_variance(lum_case) / max(_robust_variance(lum_ref), 1e-30))
            case.wall_variance_limit = float(math.exp(K_SIGMA * math.sqrt(2 * _LOG_MAD2_VARIANCE / n)))
            mean_tol = K_SIGMA * math.sqrt((lum_case.var(ddof=1) + lum_ref.var(ddof=1)) / n) / lum_ref.mean()
            # Acne blackens single pixels: count wall pixels darker than the canonical one by > 4 sigma of
            # their own difference (expected: almost none; allowed: 5% + 1 for heavy-tailed noise).
            # each pixel's variance pooled over its 3x3 neighbours (core.compare's reason: a pixel's own estimate
            # has 1 degree of freedom, from the film's 2 variance groups, and a z-score on it is heavy-tailed)
            v_case = box_smooth(result.variance)[mask] @ (metrics.BT709 ** 2)
            v_ref = box_smooth(wall_reference.variance)[mask] @ (metrics.BT709 ** 2)
            z = (lum_case - lum_ref) / np.sqrt(np.maximum(v_case + v_ref, 1e-12))
            dark = int((z < -4).sum())
            case.checks["wall_dark_outliers"] = dark
            ok_wall = (abs(case.wall_mean_ratio - 1) <= mean_tol + extra_tolerance
                       and case.wall_variance_ratio <= case.wall_variance_limit and dark <= 0.05 * n + 1)
            case.checks["wall_pixels"] = n
    ok_checks = all(bool(v) for k, v in case.checks.items() if k.startswith("ok_"))
    case.passed = nonfinite == 0 and ok_mean and ok_wall and ok_checks
    return case


# Variance of log(MAD^2) for n normal samples is about 5.4 / n (the MAD's asymptotic efficiency is 37%).
_LOG_MAD2_VARIANCE = 5.4


def _robust_variance(x: np.ndarray) -> float:
    """(1.4826 x median absolute deviation)^2: the variance for normal data, but not ruled by the few
    heavy-tailed Monte Carlo outliers (caustic paths) that a handful of samples per pixel produce."""
    return float((1.4826 * np.median(np.abs(x - np.median(x)))) ** 2)


def _timed(fn, *a, **kw):
    t = time.perf_counter()
    out = fn(*a, **kw)
    return out, time.perf_counter() - t


# -------------------------------------------------------------------------------------------------- cases
def case_scale(ctx: Context) -> list[CaseResult]:
    out = []
    scales = [1e-4, 1e-2, 1e2, 1e5] + ([] if ctx.cfg.quick else [1e-7, 1e8])
    for s in scales:
        probe = not (1e-4 <= s <= 1e5)
        r = ctx.render(transform_scene(ctx.cornell(), scale=s), ctx.paired_settings())
        out.append(measure(ctx, f"scale {s:g}", "scale", f"whole Cornell box (camera incl.) scaled by {s:g}", r,
                           metrics.channel_means(ctx.canonical.color), _sigma(ctx.canonical),
                           reference_kind="canonical Cornell", wall_reference=ctx.canonical, paired=ctx.canonical, required=not probe))
    return out


def case_translate(ctx: Context) -> list[CaseResult]:
    out = []
    offsets = [1e3, 1e4, 1e5] + ([1e8] if ctx.cfg.quick else [1e7, 1e9, 1e11, 1e13, 1e15])
    for t in offsets:
        probe = t > 1e5
        r = ctx.render(transform_scene(ctx.cornell(), offset=(t, -t, t)), ctx.paired_settings())
        out.append(measure(ctx, f"translate {t:g}", "translate", f"whole Cornell box moved to ({t:g}, -{t:g}, {t:g})",
                           r, metrics.channel_means(ctx.canonical.color), _sigma(ctx.canonical),
                           reference_kind="canonical Cornell", wall_reference=ctx.canonical, paired=ctx.canonical, required=not probe))
    return out


def case_grazing_view(ctx: Context) -> list[CaseResult]:
    out = []
    res = ctx.cfg.resolution
    for pitch, fov in ((2.0, 2.0), (0.05, 0.04), (0.002, 0.0016)):
        rad = math.radians(pitch)
        scene = _plane_scene(res, (0, 0, 1), (0, math.cos(rad), 1 - math.sin(rad)), fov)
        r = ctx.render(scene, ctx.settings())
        lo, hi = pitch - fov / 2, pitch + fov / 2
        out.append(measure(ctx, f"grazing view {pitch:g} deg", "grazing",
                           f"diffuse plane seen at {lo:g}..{hi:g} deg from its surface (hits up to "
                           f"{1 / math.tan(math.radians(lo)):.3g} m away)", r, 0.8, reference_kind="analytic rho Lw"))
    return out


def case_grazing_light(ctx: Context) -> list[CaseResult]:
    out = []
    res = ctx.cfg.resolution
    for elev in (5.0, 1.0, 0.1, 0.01, -1.0):
        e = math.radians(elev)
        strength = math.pi / (0.8 * max(math.sin(abs(e)), 1e-9))  # makes the lit answer 1
        sun = SunLight("sun", np.array([0.0, -math.cos(e), -math.sin(e)]), np.full(3, strength), angle=0.0)
        scene = _plane_scene(res, (0, 0, 1), (0, 0, 0), 40.0, world=0.0, lights=[sun], up=(0, 1, 0))
        r = ctx.render(scene, ctx.settings())
        expected = 1.0 if elev > 0 else 0.0
        out.append(measure(ctx, f"grazing sun {elev:g} deg", "grazing",
                           f"delta sun {elev:g} deg above the plane (strength x sin(elev) x rho / pi = {expected:g})",
                           r, expected, reference_kind="analytic", notes="below the horizon: no light may leak"
                           if elev < 0 else ""))
    return out


def case_thin_triangles(ctx: Context) -> list[CaseResult]:
    out = []
    ref_m, ref_s = metrics.channel_means(ctx.canonical.color), _sigma(ctx.canonical)
    for label, mesh in (("back wall as 1000 strips (2000:1)", _back_wall_strips(1000)),
                        ("back wall as a fan of 2000 needles", _back_wall_fan(2000))):
        r = ctx.render(_replace_mesh(ctx.cornell(), "back", mesh), ctx.paired_settings())
        out.append(measure(ctx, "thin: " + label.split(" as ")[1].split(" (")[0], "thin/long", label, r, ref_m, ref_s,
                           reference_kind="canonical Cornell", wall_reference=ctx.canonical, paired=ctx.canonical))
    res = ctx.cfg.resolution
    scene = _plane_scene(res, (0, 0, 1), (0, 0, 0), 40.0, size=1e6, strips=400, up=(0, 1, 0))
    r = ctx.render(scene, ctx.settings())
    out.append(measure(ctx, "long: 2e6 x 5e3 triangles", "thin/long",
                       "sky-lit plane cut into 800 triangles 2e6 m long, seen from 1 m", r, 0.8,
                       reference_kind="analytic rho Lw"))
    return out


def case_degenerate(ctx: Context) -> CaseResult:
    v = np.array([
        [0, 0, 1], [0.5, 0, 1], [1, 0, 1],                 # 0-2 collinear
        [np.nan, 0, 1], [0, np.inf, 1], [0, 0, -np.inf],   # 3-5 non-finite
        [-0.5, 0, 0.5], [0.5, 0, 0.5], [0, 0, 1.5],        # 6-8 a proper triangle's corners, reused below
        [0.2, 0.0, 0.8], [0.6, 0.0, 0.8 + 1e-9], [1.0, 0.0, 0.8],  # 9-11 nearly collinear (kept, ~zero area)
    ], np.float64)
    tris = np.array([[0, 1, 2], [0, 0, 1], [6, 6, 6], [3, 6, 7], [4, 5, 8], [9, 10, 11]], np.int32)
    scene = ctx.cornell()
    scene.meshes.append(Mesh("junk", v, tris, 0))
    r = ctx.render(scene, ctx.paired_settings())
    text = " ".join(r.warnings)
    checks = {"ok_nonfinite_dropped": "dropped 2 triangles with NaN/Inf" in text,
              "ok_degenerate_dropped": "dropped 3 zero-area" in text}
    return measure(ctx, "degenerate + NaN/Inf triangles", "degenerate",
                   "zero-area, collinear, repeated-vertex, NaN and Inf triangles and a 1e-9-thin sliver added "
                   "in the middle of the box", r, metrics.channel_means(ctx.canonical.color), _sigma(ctx.canonical),
                   reference_kind="canonical Cornell", wall_reference=ctx.canonical, paired=ctx.canonical, checks=checks)


def case_coplanar(ctx: Context) -> list[CaseResult]:
    out = []
    ref_m, ref_s = metrics.channel_means(ctx.canonical.color), _sigma(ctx.canonical)
    scene = ctx.cornell()
    extra = [m for m in scene.meshes if m.name in ("back", "floor")]
    for m in extra:
        scene.meshes.append(Mesh(m.name + "_dup", m.vertices.copy(), m.triangles.copy(), m.material_index))
        scene.meshes.append(Mesh(m.name + "_flip", m.vertices.copy(), m.triangles[:, ::-1].copy(), m.material_index))
    r = ctx.render(scene, ctx.paired_settings())
    out.append(measure(ctx, "coplanar duplicates", "coplanar", "back wall and floor each present three times "
                       "(same material; one copy wound the other way)", r, ref_m, ref_s,
                       reference_kind="canonical Cornell", wall_reference=ctx.canonical, paired=ctx.canonical))
    scene = ctx.cornell()
    back = next(m for m in scene.meshes if m.name == "back")
    scene.meshes.append(Mesh("back_red", back.vertices.copy(), back.triangles.copy(), 1))
    r = ctx.render(scene, ctx.settings())
    wall = ctx.wall
    lum = r.color[..., :3][wall].mean(axis=0)
    out.append(measure(ctx, "coplanar, two materials", "coplanar", "back wall duplicated in red (z-fighting): which "
                       "face wins is arbitrary, the image must stay finite", r, metrics.channel_means(r.color),
                       reference_kind="finite only", required=True,
                       notes=f"wall RGB {lum[0]:.3f} {lum[1]:.3f} {lum[2]:.3f}"))
    return out


def case_normals(ctx: Context) -> list[CaseResult]:
    out = []
    ref_m, ref_s = metrics.channel_means(ctx.canonical.color), _sigma(ctx.canonical)
    scene = ctx.cornell()
    for m in scene.meshes:
        if m.name not in ("mirror_sphere", "glass_sphere"):
            m.triangles = m.triangles[:, ::-1].copy()
    r = ctx.render(scene, ctx.paired_settings())
    out.append(measure(ctx, "flipped winding (walls)", "normals", "every wall and the lamp wound the other way "
                       "(geometric normals outward)", r, ref_m, ref_s, reference_kind="canonical Cornell",
                       wall_reference=ctx.canonical, paired=ctx.canonical))
    scene = ctx.cornell()
    for m in scene.meshes:
        m.normals = None
    r = ctx.render(scene, ctx.paired_settings())
    out.append(measure(ctx, "missing shading normals", "normals", "spheres without shading normals (flat facets)",
                       r, ref_m, ref_s, reference_kind="canonical Cornell", extra_tolerance=0.005,
                       notes="0.5% allowance: facets of a 5120-triangle sphere may change the image slightly "
                             "(measured -0.07 +- 0.12 %)",
                       wall_reference=ctx.canonical, paired=ctx.canonical))
    scene = ctx.cornell()
    for m in scene.meshes:
        if m.normals is not None:
            m.normals = -m.normals
    r = ctx.render(scene, ctx.paired_settings())
    out.append(measure(ctx, "inverted shading normals", "normals", "sphere shading normals point inward, "
                       "against the winding", r, ref_m, ref_s, reference_kind="canonical Cornell",
                       extra_tolerance=0.005, wall_reference=ctx.canonical, paired=ctx.canonical,
                       notes="the shading normal is flipped to the geometric side, so the image barely changes"))
    return out


def _tilted_furnace(res: int, tilt_deg: float, albedo: float = 0.5) -> Scene:
    scene = scenes.furnace((res, res), albedo=albedo)
    mesh = scene.meshes[0]
    p = mesh.vertices[mesh.triangles]
    ng = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    # tilt each corner's normal by the angle about a tangent that changes from corner to corner
    tangent = np.cross(ng, np.array([0.3, 0.5, 0.8]))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    bit = np.cross(ng, tangent)
    a = math.radians(tilt_deg)
    normals = np.empty((len(ng), 3, 3))
    for k, phi in enumerate((0.0, 2.1, 4.2)):
        axis = math.cos(phi) * tangent + math.sin(phi) * bit
        normals[:, k] = math.cos(a) * ng + math.sin(a) * axis
    mesh.normals = normals.astype(np.float32)
    return scene


def case_shading_normals(ctx: Context) -> list[CaseResult]:
    out = []
    res = max(ctx.cfg.resolution // 2, 8)
    for tilt in (30.0, 60.0, 85.0):
        r = ctx.render(_tilted_furnace(res, tilt), ctx.settings())
        m = metrics.channel_means(r.color)
        checks = {"ok_no_energy_gain": bool(np.all(m <= 2.0 + K_SIGMA * _sigma(r) + 2.0 * FLOOR_REL)),
                  "ratio_to_analytic": float(m.mean() / 2.0)}
        out.append(measure(ctx, f"shading normals tilted {tilt:g} deg", "shading normals",
                           f"furnace (albedo 0.5, Le 1) whose shading normals are {tilt:g} deg off the geometric "
                           "normal: energy may be lost, never gained", r, m, reference_kind="no gain over Le/(1-a)=2",
                           checks=checks))
    # shadow terminator: a 12 x 6 smooth UV sphere against the 5120-triangle icosphere, both diffuse white
    base = scenes.cornell_diffuse((ctx.cfg.resolution, ctx.cfg.resolution))
    ref = ctx.render(base, ctx.settings())
    low = scenes.cornell_diffuse((ctx.cfg.resolution, ctx.cfg.resolution))
    low = _replace_mesh(low, "mirror_sphere", uv_sphere("mirror_sphere", (-0.45, 0.35, 0.35), 0.35, 4, 12, 6))
    r = ctx.render(low, ctx.settings())
    out.append(measure(ctx, "shadow terminator (12x6 sphere)", "shading normals",
                       "a 12 x 6 smooth-shaded UV sphere instead of the icosphere (diffuse Cornell box)", r,
                       metrics.channel_means(ref.color), _sigma(ref), reference_kind="5120-triangle sphere",
                       extra_tolerance=0.02, required=False,
                       notes="2% allowance: a 72-facet sphere is a different shape; dark facet bands are the artefact"))
    return out


def case_dielectrics(ctx: Context) -> list[CaseResult]:
    """White furnace for glass: a lossless dielectric in a uniform radiance field is invisible."""
    out = []
    res = ctx.cfg.resolution
    # Flat-shaded spheres: a polyhedron traps light by total internal reflection for hundreds of bounces
    # (measured at IOR 1.5, 256x256: 0.3% of paths still inside after 64 bounces, 0.05% after 512, none after
    # 4096; at IOR 4, critical angle 14.5 deg, some survive 4096 and none 16384), so these cases allow 16384
    # bounces and expect exactly the world radiance.
    sphere = lambda name, c, r, m: scenes.icosphere(name, c, r, m, smooth=False)  # noqa: E731
    deep = 16384
    for ior in (1.0001, 1.5, 4.0):
        scene = _white_furnace([sphere("ball", (0, 0, 0), 1.0, 0)], [_glass(ior)], res)
        r = ctx.render(scene, ctx.settings(max_bounces=deep))
        out.append(measure(ctx, f"glass IOR {ior:g}", "dielectric", f"flat-shaded glass sphere, IOR {ior:g}, in a "
                           "uniform world: every pixel = world radiance", r, 1.0, reference_kind="analytic (furnace)"))
    scene = _white_furnace([scenes.icosphere("ball", (0, 0, 0), 1.0, 0)], [_glass(1.5)], res)
    r = ctx.render(scene, ctx.settings(max_bounces=deep))
    out.append(measure(ctx, "smooth glass IOR 1.5", "dielectric", "the same sphere smooth-shaded", r, 1.0,
                       reference_kind="analytic (furnace)", required=False,
                       notes="smooth shading normals are kept valid for reflection (Cycles' rule); ~3e-5 of "
                             "paths still end at the silhouette by refraction through a tilted normal"))
    scene = _white_furnace([sphere("outer", (0, 0, 0), 1.0, 0), sphere("inner", (0, 0, 0.1), 0.5, 1)],
                           [_glass(1.5), _glass(1.33, name="water")], res)
    r = ctx.render(scene, ctx.settings(max_bounces=deep))
    out.append(measure(ctx, "nested glass", "dielectric", "IOR 1.33 sphere inside an IOR 1.5 sphere (each surface "
                       "its own air interface)", r, 1.0, reference_kind="analytic (furnace)"))
    scene = _white_furnace([box_mesh("a", (-1, -0.5, -0.5), (0, 0.5, 0.5), 0), box_mesh("b", (0, -0.5, -0.5),
                            (1, 0.5, 0.5), 0), sphere("s1", (-0.4, -1.0, 0.6), 0.4, 0), sphere("s2", (0.4, -1.0, 0.6),
                                                                                               0.4, 0)],
                           [_glass(1.5)], res)
    r = ctx.render(scene, ctx.settings(max_bounces=deep))
    out.append(measure(ctx, "touching glass", "dielectric", "two glass cubes sharing a face, two glass spheres "
                       "touching at a point", r, 1.0, reference_kind="analytic (furnace)",
                       notes="shared faces are two interfaces with a zero-thickness air gap"))
    rod = box_mesh("rod", (-0.3, -1.5, -0.3), (0.3, 1.5, 0.3), 0)
    rod.vertices = rod.vertices @ np.array([[1, 0, 0], [0, 0.8, 0.6], [0, -0.6, 0.8]])
    for bounces in (4, 16, 256):
        scene = _white_furnace([rod], [_glass(1.5)], res)
        r = ctx.render(scene, ctx.settings(max_bounces=bounces))
        m = metrics.channel_means(r.color)
        exact = bounces >= 256
        checks = {"ok_no_gain": bool(np.all(m <= 1.0 + K_SIGMA * _sigma(r) + 1e-5))}
        out.append(measure(ctx, f"TIR rod, max bounces {bounces}", "dielectric",
                           "glass rod (light pipe) in a uniform world: total internal reflection chains hit the "
                           "bounce limit", r, 1.0 if exact else m, reference_kind="analytic (furnace)" if exact else
                           "no gain over 1", checks=checks, notes="" if exact else
                           f"dark by {100 * (1 - m.mean()):.2f}%: paths cut at the bounce limit"))
    # closed glass box with an emitter inside, at thermal equilibrium with the world
    emit = Material("emitter", [Lobe("diffuse", np.zeros(3))], emission=np.ones(3))
    inner = scenes.icosphere("emitter", (0, 0, 0), 0.4, 1)
    scene = _white_furnace([box_mesh("box", (-0.7, -0.7, -0.7), (0.7, 0.7, 0.7), 0), inner], [_glass(1.5), emit], res)
    r = ctx.render(scene, ctx.settings(max_bounces=64))
    out.append(measure(ctx, "emitter in closed glass box", "dielectric", "black emitter of radiance 1 inside a closed "
                       "glass box, world radiance 1 (equilibrium): every pixel 1; its light leaves only by caustic "
                       "paths", r, 1.0, reference_kind="analytic (furnace)"))
    # Linearity splits that answer into two non-trivial halves: the emitter's light escaping the box (caustic
    # paths only) plus the world's light around and through it must add up to 1 in every pixel.
    lit = {}
    for world, le in ((0.0, 1.0), (1.0, 0.0)):
        emit = Material("emitter", [Lobe("diffuse", np.zeros(3))], emission=np.full(3, le))
        scene = _white_furnace([box_mesh("box", (-0.7, -0.7, -0.7), (0.7, 0.7, 0.7), 0),
                                scenes.icosphere("emitter", (0, 0, 0), 0.4, 1)], [_glass(1.5), emit], res, world=world)
        lit[world] = ctx.render(scene, ctx.settings(max_bounces=64, seed=ctx.cfg.seed + int(world) * 7))
    r = lit[0.0]
    m_world = metrics.channel_means(lit[1.0].color)
    out.append(measure(ctx, "emitter in glass box, world 0", "dielectric", "the emitter alone (world black): its "
                       "light + the world-alone image = 1", r, 1.0 - m_world, _sigma(lit[1.0]),
                       reference_kind="1 - (world-alone render)",
                       notes=f"emitter part {metrics.channel_means(r.color).mean():.4f}, world part {m_world.mean():.4f}"))
    return out


def clamp_closed_form_scenes(res: int) -> list[tuple[str, Scene, np.ndarray, float]]:
    """Scenes whose every sample contribution is one known RGB value v, so that a clamp c has a closed form: each
    contribution whose largest component exceeds c is scaled down to it, so the image is v min(1, c / max(v)).
    (name, scene, v, c): a sky-lit plane (the uniform world, found by cosine-sampled BSDF rays: every sample
    rho x Lw) and a plane under a delta sun (found by light sampling only: every sample strength x sin(elev) x
    rho / pi), both coloured so that the scaling (one factor for all channels) shows."""
    sky = scenes.plane_under_world((res, res), albedo=0.8)
    sky.world = World(np.array([10.0, 5.0, 2.5]))
    e = math.radians(30.0)
    colour = np.array([1.0, 0.5, 0.25])
    sun = SunLight("sun", np.array([0.0, -math.cos(e), -math.sin(e)]), colour * math.pi / (0.8 * math.sin(e)),
                   angle=0.0)
    sunlit = _plane_scene(res, (0, 0, 1), (0, 0, 0), 40.0, world=0.0, lights=[sun], up=(0, 1, 0))
    return [("sky-lit plane", sky, 0.8 * np.array([10.0, 5.0, 2.5]), 2.0),
            ("sun-lit plane", sunlit, colour, 0.5)]


def case_clamp_closed_form(ctx: Context) -> list[CaseResult]:
    """Clamping against its closed form (clamp_closed_form_scenes): exact, zero-variance answers."""
    out = []
    res = max(ctx.cfg.resolution // 2, 8)
    for name, scene, value, clamp in clamp_closed_form_scenes(res):
        r = ctx.render(scene, ctx.settings(clamp=clamp))
        expected = value * min(1.0, clamp / float(value.max()))
        out.append(measure(ctx, f"clamp {clamp:g}, {name}", "fireflies", f"{name}: every sample "
                           f"{_fmt(value.tolist(), 3)}, clamp {clamp:g} scales it to {_fmt(expected.tolist(), 3)}", r, expected,
                           reference_kind="analytic (clamped)",
                           checks={"clamped_contributions": int(r.stats["clamped_contributions"]),
                                   "ok_every_sample_clamped": int(r.stats["clamped_contributions"]) > 0}))
    return out


def case_fireflies(ctx: Context) -> list[CaseResult]:
    """A lamp 1/400 of the area at 400x the radiance (same power) in the Cornell box: light reaching the floor
    through the glass sphere and off the mirror is found only by BSDF sampling, as rare huge samples. The clamped
    renders have no closed form (clamp_closed_form_scenes has those): they are held to the unclamped render with
    the same seed, pixel by pixel (clamping only scales contributions down, it never changes a path: no pixel
    may brighten), and to the independent unclamped reference (darker, with less variance)."""
    def tiny() -> Scene:
        scene = ctx.cornell()
        k = 0.015
        scene = _replace_mesh(scene, "lamp", scenes.quad("lamp", [(-k, -k, 1.98), (-k, k, 1.98), (k, k, 1.98),
                                                                   (k, -k, 1.98)], 3))
        scene.materials[3] = Material("lamp", [Lobe("diffuse", np.zeros(3))], emission=np.full(3, 12.0 * 400))
        return scene

    ref = ctx.render(tiny(), ctx.settings(spp=ctx.cfg.spp * 4, seed=ctx.cfg.seed + 1000))
    ref_m, ref_s = metrics.channel_means(ref.color), _sigma(ref)
    out = []
    unclamped_var = unclamped = None
    for clamp in (0.0, 10.0, 1.0):
        r = ctx.render(tiny(), ctx.settings(clamp=clamp))
        m = metrics.channel_means(r.color)
        var = metrics.mean_pixel_variance(r.variance)["luma"]
        bias = float(((m - ref_m) @ metrics.BT709) / (ref_m @ metrics.BT709))
        checks = {"mean_pixel_variance": var, "bias_rel": bias, "clamped_contributions":
                  int(r.stats["clamped_contributions"])}
        if clamp == 0:
            unclamped_var, unclamped = var, r
            out.append(measure(ctx, "tiny bright lamp, unbiased", "fireflies", "lamp 1/400 the area, 400x radiance "
                               "(12 x 400); default estimator", r, ref_m, ref_s, checks=checks,
                               reference_kind="same scene, 4x spp, other seed"))
        else:
            checks["ok_variance_reduced"] = var < unclamped_var
            checks["ok_biased_down"] = bias <= K_SIGMA * float((ref_s @ metrics.BT709) / (ref_m @ metrics.BT709))
            # Same seed, same paths (clamping scales contributions, it never changes a path): against the unclamped
            # render every pixel is at most as bright, and only pixels that received a clamped contribution differ
            # at all (each contribution lands in one pixel), so the rest of the image is the unclamped one exactly
            # (a black or otherwise wrong image fails here).
            gap = unclamped.color[..., :3].astype(np.float64) - r.color[..., :3]
            changed = int(np.any(np.abs(gap) > 1e-6 * np.abs(unclamped.color[..., :3]) + 1e-9, axis=-1).sum())
            checks["changed_pixels"] = changed
            checks["ok_no_pixel_brighter"] = bool(np.all(gap >= -1e-6 * np.abs(unclamped.color[..., :3]) - 1e-9))
            checks["ok_only_pixels_with_clamped_samples_change"] = 0 < changed <= checks["clamped_contributions"]
            checks["ok_darker_than_unclamped"] = bool(np.all(m < metrics.channel_means(unclamped.color)))
            out.append(measure(ctx, f"tiny bright lamp, clamp {clamp:g}", "fireflies", f"the same with clamp "
                               f"{clamp:g}: less variance, darker (bias)", r, m, checks=checks,
                               reference_kind="unclamped render, same seed: equal but where clamped",
                               notes=f"bias {100 * bias:+.1f}%, pixel variance x{var / unclamped_var:.2g}"))
    return out


def case_albedo_extremes(ctx: Context) -> list[CaseResult]:
    out = []
    res = max(ctx.cfg.resolution // 2, 8)
    for albedo, bounces in ((1.0, 16), (1.0, 3), (0.0, 16)):
        expected = (bounces + 2) if albedo == 1.0 else 1.0  # Le sum_{k=0}^{B+1} a^k
        # 8x the samples: light sampling and MIS make the albedo-1 furnace noisy (not zero-variance), and a
        # 1 % error must lie outside its 5 sigma
        r = ctx.render(scenes.furnace((res, res), albedo=albedo), ctx.settings(spp=8 * ctx.cfg.spp,
                                                                               max_bounces=bounces))
        checks = {"max_pixel_variance": float(r.variance.max())}
        out.append(measure(ctx, f"furnace albedo {albedo:g}, {bounces} bounces", "albedo",
                           f"closed sphere, albedo exactly {albedo:g}, Le 1, max bounces {bounces}: "
                           f"Le x (B + 2) = {expected:g}" if albedo else "albedo 0: Le exactly", r, expected,
                           reference_kind="analytic"))
    for albedo in (1.0, 0.0):
        r = ctx.render(scenes.plane_under_world((res, res), albedo=albedo), ctx.settings())
        out.append(measure(ctx, f"sky-lit plane albedo {albedo:g}", "albedo", f"plane of albedo {albedo:g} under "
                           f"a sky of radiance 1", r, albedo, reference_kind="analytic"))
    return out


def _render_peak_child(width: int, height: int, spp: int, threads: int) -> dict:
    """Runs in a child process: render the Cornell box at width x height, return finiteness and peak RSS."""
    from ..core.memory import estimate_render_memory, peak_rss_bytes

    scene = scenes.cornell_box((width, height))
    settings = RenderSettings(spp=spp, threads=threads)
    est = estimate_render_memory(scene, settings)
    r = render(scene, settings)
    return {"nonfinite": int((~np.isfinite(r.color)).sum()), "samples": int(r.sample_count.sum()),
            "unsampled": int((r.sample_count == 0).sum()), "mean": metrics.channel_means(r.color).tolist(),
            "peak_memory_mb": (peak_rss_bytes() or 0) / 2**20, "estimate_mb": est.total / 2**20,
            "seconds": r.stats["seconds"]}


def horizon_scene(width: int, height: int) -> Scene:
    """The camera 1 m above the sky-lit plane (albedo 0.8, sky 1) looking at the horizon (39 deg horizontal field
    of view): the horizon halves the frame, below it every sample is 0.8 (cosine-sampled sky), above it 1, so
    the frame's mean is exactly 0.9 at any resolution (box filter: pixels tile the frame) and any aspect ratio
    (the frame is symmetric about the horizon; the 1e9 m plane misses only rays within 1e-9 rad of it, 1e-5 of
    a 4096x1 frame's height: a 1e6 m plane shifted that frame's mean by 0.12 %)."""
    scene = _plane_scene(1, (0, 0, 1), (0, 1, 1), 39.0, size=1e9)
    scene.camera = Camera.look_at((0, 0, 1), (0, 1, 1), horizontal_fov=math.radians(39.0), resolution=(width, height))
    return scene


def case_resolutions(ctx: Context) -> list[CaseResult]:
    """Extreme resolutions on the horizon scene (analytic: the mean of any frame is 0.9; the Cornell box's mean
    would need millions of paths at one pixel to resolve a 2 % error)."""
    out = []
    box = dict(filter_type="box", filter_width=1.0)
    for w, h, spp in ((1, 1, 4096), (1, 4096, ctx.cfg.spp), (4096, 1, ctx.cfg.spp)):
        r = ctx.render(horizon_scene(w, h), ctx.settings(spp=spp, **box))
        checks = {"ok_every_pixel_sampled": bool(np.all(r.sample_count > 0))}
        what = ("one pixel covering the whole frame (box filter): its value is the frame's mean" if w * h == 1 else
                f"a one-pixel line (the other side spans {'~180 deg' if w == 1 else '39 deg'})")
        out.append(measure(ctx, f"{w}x{h}", "resolution", f"{what}: half sky, half plane", r, 0.9,
                           reference_kind="analytic (horizon: 0.5 x 0.8 + 0.5 x 1)", checks=checks))
    w, h = ctx.cfg.big_resolution
    if w * h <= 1 << 20:  # small enough to render here; a child process gives the large frame its own peak RSS
        info = _render_peak_child(w, h, 1, ctx.cfg.threads)
        ok = info["nonfinite"] == 0 and info["unsampled"] == 0 and info["samples"] == w * h
        out.append(CaseResult(f"{w}x{h} 1 spp", "resolution", f"{w}x{h} Cornell box at 1 sample per pixel",
                              "finite, every pixel sampled", passed=ok, nonfinite_pixels=info["nonfinite"],
                              mean=info["mean"], seconds=info["seconds"], checks={"estimate_mb": info["estimate_mb"]}))
        return out
    code = ("import json, sys; from monte.lab.stress import _render_peak_child; "
            f"print(json.dumps(_render_peak_child({w}, {h}, 1, {ctx.cfg.threads})))")
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=os.environ.copy())
    seconds = time.perf_counter() - t
    if proc.returncode != 0:
        case = CaseResult(f"{w}x{h} 1 spp", "resolution", "large frame in a child process", "finite",
                          notes=f"child failed: {proc.stderr.strip()[-300:]}")
        out.append(case)
        return out
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    ok = info["nonfinite"] == 0 and info["unsampled"] == 0 and info["samples"] == w * h
    case = CaseResult(f"{w}x{h} 1 spp", "resolution", f"{w}x{h} Cornell box at 1 sample per pixel (child process)",
                      "finite, every pixel sampled, peak memory near the estimate", passed=ok,
                      nonfinite_pixels=info["nonfinite"], mean=info["mean"], seconds=seconds,
                      peak_memory_mb=info["peak_memory_mb"],
                      checks={"estimate_mb": round(info["estimate_mb"], 1), "peak_rss_mb": round(info["peak_memory_mb"], 1),
                              "bytes_per_pixel_peak": round(info["peak_memory_mb"] * 2**20 / (w * h), 1)},
                      notes=f"peak RSS {info['peak_memory_mb']:.0f} MB, estimate {info['estimate_mb']:.0f} MB")
    out.append(case)
    return out


def case_sample_counts(ctx: Context) -> list[CaseResult]:
    out = []
    r = ctx.render(ctx.cornell(), ctx.settings(spp=0))
    checks = {"ok_black": bool(np.all(r.color[..., :3] == 0)), "ok_count_zero": int(r.sample_count.sum()) == 0}
    out.append(measure(ctx, "0 spp", "samples", "zero samples: a black, valid image", r, 0.0, reference_kind="black",
                       checks=checks))
    # the horizon scene: a mean at one sample per pixel that is exact (the Cornell box's would need millions of
    # pixels to resolve 2 %); an even height puts the horizon between two rows, so every pixel is 0.8 or 1
    res = 2 * max(ctx.cfg.resolution // 2, 4)
    r = ctx.render(horizon_scene(res, res), ctx.settings(spp=1, filter_type="box", filter_width=1.0))
    checks = {"ok_count_one": bool(np.all(r.sample_count == 1)), "ok_variance_zero": bool(np.all(r.variance == 0))}
    out.append(measure(ctx, "1 spp", "samples", "one sample per pixel: no variance estimate (0), the horizon "
                       "scene's mean 0.9", r, 0.9, reference_kind="analytic (horizon: 0.5 x 0.8 + 0.5 x 1)",
                       checks=checks))
    spp = ctx.cfg.huge_spp
    r = render(scenes.furnace((4, 4), albedo=0.5), ctx.settings(spp=spp, batch_paths=4096, max_bounces=64))
    pix = r.color[..., :3].reshape(-1, 3)
    # the spread of the 16 pixel means must agree with their estimated variance (chi-square, 15 dof)
    spread = float(pix.var(axis=0, ddof=1).mean() / r.variance.reshape(-1, 3).mean())
    checks = {"ok_all_samples": bool(np.all(r.sample_count == spp)), "passes": spp * 16 // 4096,
              "pixel_spread_over_estimate": spread, "ok_variance_estimate": 0.1 < spread < 3.0}
    out.append(measure(ctx, f"{spp} spp progressive", "samples", f"furnace 4x4 at {spp} spp in 4096-path batches: "
                       "every sample counted, mean Le/(1-a) (64 bounces)", r, 2.0 * (1 - 0.5 ** 66),
                       reference_kind="analytic", checks=checks))
    return out


def case_cancel(ctx: Context) -> CaseResult:
    calls = {"n": 0}

    def cancel() -> bool:
        calls["n"] += 1
        return calls["n"] > 3

    r = ctx.render(ctx.cornell(), ctx.settings(tile_size=8, batch_paths=1024), should_cancel=cancel)  # many batches
    done = r.sample_count > 0
    checks = {"ok_cancelled": r.cancelled, "ok_unsampled_black": bool(np.all(r.color[~done][:, :3] == 0)),
              "ok_partial": bool(0 < done.sum() < done.size),
              "ok_counts_consistent": int(r.sample_count.sum()) == int(r.stats["samples"])}
    return measure(ctx, "cancel mid-render", "samples", "cancel after 3 batches: finite partial image, unsampled "
                   "pixels black, sample counts consistent", r, metrics.channel_means(r.color),
                   reference_kind="finite", checks=checks)


CASES: list[tuple[str, Callable[[Context], CaseResult | list[CaseResult]]]] = [
    ("scale", case_scale),
    ("translate", case_translate),
    ("grazing-view", case_grazing_view),
    ("grazing-light", case_grazing_light),
    ("thin", case_thin_triangles),
    ("degenerate", case_degenerate),
    ("coplanar", case_coplanar),
    ("normals", case_normals),
    ("shading-normals", case_shading_normals),
    ("dielectric", case_dielectrics),
    ("fireflies", case_fireflies),
    ("clamp", case_clamp_closed_form),
    ("albedo", case_albedo_extremes),
    ("resolution", case_resolutions),
    ("samples", case_sample_counts),
    ("cancel", case_cancel),
]


def run_suite(cfg: StressConfig, only: list[str] | None = None,
              log: Callable[[str], None] | None = None) -> list[CaseResult]:
    """Run every case group (or those named in `only`) and return the results in order."""
    say = log or (lambda _m: None)
    ctx = Context(cfg, say)
    results: list[CaseResult] = []
    for group, fn in CASES:
        if only and group not in only:
            continue
        t = time.perf_counter()
        got = fn(ctx)
        got = got if isinstance(got, list) else [got]
        for case in got:
            say(f"{case.status:8s} {case.name}: mean {_fmt(case.mean)} ref {_fmt(case.reference)} {case.notes}")
        say(f"-- {group}: {time.perf_counter() - t:.1f} s")
        results.extend(got)
    return results


def _fmt(values, digits: int = 4) -> str:
    return " ".join(f"{v:.{digits}g}" for v in values) if values else "-"


def write_report(results: list[CaseResult], out_dir: str | os.PathLike, cfg: StressConfig,
                 extra: dict | None = None) -> tuple[Path, Path]:
    """report.json (every number) and report.md (one table row per case) in out_dir."""
    from ..core.atomic_file import write_text_atomically

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    payload = {"config": asdict(cfg) | {"cycles": cfg.cycles is not None}, "k_sigma": K_SIGMA,
               "cases": [asdict(c) | {"status": c.status} for c in results]}
    payload.update(extra or {})
    text = json.dumps(payload, indent=2, default=float)
    json_path = write_text_atomically(out / "report.json", text, ".json")
    md_path = write_text_atomically(out / "report.md", report_markdown(results, cfg), ".md")
    return json_path, md_path


def report_markdown(results: list[CaseResult], cfg: StressConfig) -> str:
    with_cycles = any(c.cycles for c in results)
    n_req = sum(c.required for c in results)
    n_pass = sum(c.passed for c in results if c.required)
    lines = [f"Cornell cases at {cfg.resolution}x{cfg.resolution}, {cfg.spp} spp, seed {cfg.seed}; tolerance "
             f"{K_SIGMA:g} sigma of the means (+1e-5 relative). Required cases passed: {n_pass}/{n_req}.", "",
             "| case | status | NaN/Inf px | mean (R G B) | reference | rel. error | tolerance (rel.) | wall mean "
             "ratio | wall var ratio (limit) | notes |" + (" Cycles mean |" if with_cycles else ""),
             "|---|---|---|---|---|---|---|---|---|---|" + ("---|" if with_cycles else "")]
    for c in results:
        ref = max(abs(c.reference[i]) for i in range(3)) if c.reference else 0
        tol_rel = (max(c.tolerance) / ref) if c.tolerance and ref > 0 else float("nan")
        wall_m = f"{c.wall_mean_ratio:.4f}" if c.wall_mean_ratio is not None else ""
        wall_v = (f"{c.wall_variance_ratio:.3f} ({c.wall_variance_limit:.2f})" if c.wall_variance_ratio is not None
                  else "")
        notes = c.notes
        failed = [k[3:] for k, v in c.checks.items() if k.startswith("ok_") and not v]
        if failed:
            notes = (notes + "; " if notes else "") + "failed: " + ", ".join(failed)
        if c.caught_samples:
            notes = (notes + "; " if notes else "") + f"{c.caught_samples} NaN samples caught"
        row = (f"| {c.name} | {c.status} | {c.nonfinite_pixels} | {_fmt(c.mean)} | {_fmt(c.reference)} | "
               f"{c.rel_error:.2e} | {tol_rel:.1e} | {wall_m} | {wall_v} | {notes} |")
        if with_cycles:
            row += f" {_fmt(c.cycles.get('mean', [])) if c.cycles else ''} {c.cycles.get('note', '') if c.cycles else ''} |"
        lines.append(row)
    return "\n".join(lines) + "\n"
