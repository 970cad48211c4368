"""Where the fused path kernel (core.fused_path) renders a scene, and its call.

`supports` decides per PathTracer (a scene-level decision: the scene's features and the render settings) whether
`trace_paths` renders the scene as the per-bounce integrator would; `FusedTracer` holds the kernel's scene-level
arguments and calls it per batch. Kept apart from the kernel module so that edits here recompile no kernel.
"""

from __future__ import annotations

import functools
import os

import numpy as np

from . import bsdf as bsdf_mod
from . import microfacet as mf
from .camera import PinholeRays
from .embree import _RAY_WORDS
from .fused_path import COUNTERS, trace_paths
from .sampling import _TAG_SOBOL_SET, SobolSampler, _U, _key, _sobol_tables

FUSED_ENV = "MONTE_FUSED"  # "0": always the per-bounce integrator (A/B comparisons)


def disabled() -> bool:
    """MONTE_FUSED=0 forces the per-bounce integrator (for A/B comparisons)."""
    return os.environ.get(FUSED_ENV, "1").strip() == "0"


def supports(tracer) -> str | None:
    """None when `trace_paths` renders this tracer's scene with these settings exactly as the per-bounce
    integrator would (its camera paths' radiance and first-hit albedo, normal and depth; PathTracer.trace checks
    per call that no denoising feature, data pass or motion blur is asked for), else the reason it does not (the
    first found)."""
    ps, s = tracer.ps, tracer.settings
    accel = tracer.accel
    if disabled():
        return f"{FUSED_ENV}=0"
    if not isinstance(tracer.sampler, SobolSampler):
        return "the sampler is not Sobol"
    if s.light_sampling != "mis":
        return "light sampling is not MIS"
    if not tracer.use_nee:
        return "nothing to light-sample"
    if getattr(accel, "_scene", None) is None or accel.motion is not None or ps.motion is not None:
        return "no Embree scene, or motion"
    programs = program_reason(ps)
    if programs is not None:
        return programs
    checks = (("textured emitters", ps.textured is not None),
              ("alpha", ps.alpha), ("shadow catcher", ps.catcher is not None),
              ("light groups", ps.light_groups is not None), ("light linking", ps.links is not None),
              ("shadow linking", ps.shadow_links is not None), ("light visibility", ps.light_visibility is not None),
              ("ray visibility", bool(ps.visible_to)), ("transparent BSDF", ps.has_clear),
              ("transparent shadows", ps.shadow_clear is not None), ("lights without shadows", ps.no_shadow is not None),
              ("moving emitters", ps.moving_emitters is not None),
              ("light passes", bool(s.light_passes)), ("shader AOVs", bool(ps.scene.shader_aovs)),
              ("textures", bool(getattr(ps.materials, "_texture_ids", None))),
              ("camera backdrop", ps.scene.world.camera_color is not None
               or ps.scene.world.camera_environment is not None))
    for name, present in checks:
        if present:
            return name
    return None


def program_reason(ps) -> str | None:
    """None when the scene has no node programs or only programs the fused kernel evaluates per vertex (programs
    that read the shading point, its normals, view, tangents, active UV map, object and ray differentials, and
    set lobe parameters and the shading normal: Normal Map, Tangent, Bump; the kernel rebuilds the frame and
    applies the bump shadowing), else why not: a program that reads a named UV map (UV Map), the path state
    (Light Path) or attributes (Attribute), emits (textured emitters) or writes shader AOVs."""
    sh = ps.shading
    if sh is None:
        return None
    needs = ps.vector_needs
    checks = (("node programs reading a named UV map", needs is not None and bool(needs.uv_layers.any())),
              ("node programs reading the light path", sh.uses_light_path),
              ("node programs reading attributes", sh.uses_attributes),
              ("node programs with emission", sh.any_emits),
              ("node programs writing shader AOVs", sh.writes_aovs))
    for name, present in checks:
        if present:
            return name
    return None


@functools.lru_cache(maxsize=16)
def _sobol_set_keys(seed: int, dims: int) -> np.ndarray:
    """The hash keys of the Sobol dimension sets 0 .. dims - 1 for this seed (read-only): the ones the sampler's
    own sets use (SobolSampler), made once per process and seed, since hashing them one Python call at a time
    (~1 ms for 16 bounces) would run on one thread before every render call's first path."""
    keys = np.array([_U(_key(seed, d, _TAG_SOBOL_SET)) for d in range(dims)], np.uint32)
    keys.flags.writeable = False
    return keys


class FusedTracer:
    """The kernel's scene-level arguments, built once per PathTracer whose scene `supports` accepts."""

    def __init__(self, tracer, shadow_epsilon: float) -> None:
        """tracer: the PathTracer whose scene `supports` accepted; shadow_epsilon: the fraction of its length by
        which a shadow ray stops short of the light (core.integrator.SHADOW_EPSILON)."""
        self.shadow_epsilon = np.float32(shadow_epsilon)
        ps, s = tracer.ps, tracer.settings
        sampler = tracer.sampler
        lights = ps.lights
        lib = tracer.accel._library
        self.intersect1, self.occluded1, self.scene = lib.intersect1, lib.occluded1, tracer.accel._scene
        m = ps.materials.kind.shape[0]
        lobes = ps.materials.gather(np.arange(m))
        self.lobes = lobes.arrays()
        self.view_select = np.ascontiguousarray(ps.materials.view_select, np.bool_)
        self.select_scale = np.ascontiguousarray(ps.materials.select_scale, np.float32)
        self.albedo = np.ascontiguousarray(bsdf_mod.albedo(lobes), np.float32)  # (M, 3): the albedo AOV
        self.multiscatter = ps.materials.multiscatter
        self.specular = (np.ascontiguousarray(ps.specular, bool) if len(ps.specular)
                         else np.zeros(m, bool))
        self.tabs = mf.kernel_tables()
        self.emitters = (np.ascontiguousarray(ps.emissive.emitter_of_triangle, np.int64) if ps.emissive is not None
                         else np.zeros(0, np.int64))
        self.lt = lights._tables
        self.per_point = bool(lights._per_point)
        self.n_matters = bool(lights._n_matters)
        self.has_emission = bool(lights.has_emission)
        dims = 2 + (s.max_bounces + 2) * 8
        self.set_keys = _sobol_set_keys(sampler.seed, dims).copy()  # writeable: the kernel's signature types it so
        self.dim_keys = np.ascontiguousarray(sampler._dim_keys, np.uint32)
        self.seed_key = _U(sampler._seed_key)
        self.tables = _sobol_tables()
        self.group_bits = int(sampler._group_bits)
        self.terminator = (ps.terminator_offset if ps.terminator_offset is not None
                           else np.zeros(0, np.float32))  # the shadow terminator offset per triangle (or none)
        self.ps, self.settings, self.accel = ps, s, tracer.accel
        sh = ps.shading
        self.program_tables = None if sh is None else (
            np.ascontiguousarray(sh.needs_program, np.bool_), sh.prog_of_mat, sh.code, sh.code_start, sh.regs0,
            sh.reg_start, sh.data, sh.data_start, sh.bind, sh.emit_reg, sh.normal_reg, *sh.texture_pack,
            sh.objects, np.ascontiguousarray(ps.object_of_triangle, np.int32),
            np.ascontiguousarray(ps.kernel_uvs, np.float32), np.ascontiguousarray(ps.shift, np.float32))
        # the tangent layers Normal Map nodes read (none: an empty table) and which materials' programs read them
        self.tangent_layers = (np.zeros((0, 0, 3, 4), np.float32) if ps.tangent_layers is None
                               else np.ascontiguousarray(ps.tangent_layers, np.float32))
        needs = ps.vector_needs
        self.needs_tangents = (np.ones(m, np.bool_) if needs is None
                               else np.ascontiguousarray(needs.tangents, np.bool_))
        # the materials whose programs read ray differentials (Bump): none where no program has a Bump node (the
        # per-bounce integrator then keeps no differentials: every point reads zeros)
        self.needs_differentials = (np.zeros(m, np.bool_) if sh is None or not sh.needs_differentials
                                    else np.ones(m, np.bool_) if needs is None
                                    else np.ascontiguousarray(needs.differentials, np.bool_))
        self.max_registers = 0 if sh is None else sh.max_registers

    def _programs(self, ray_dp: np.ndarray | None, ray_dd: np.ndarray | None, deferred: bool) -> tuple | None:
        """trace_paths' `programs` argument (core.fused_path.PROGRAM_FIELDS): the scene's program tables, this
        call's 1-row scratches (each call its own: batches may be traced on several threads at once) and the
        camera rays' differentials: computed (ray_dp, ray_dd), or deferred to the paths that read them (a pinhole
        camera's rays, which the kernel makes: a scratch for a path's hit distances), or neither (all empty: the
        paths' footprints are zero)."""
        if self.program_tables is None:
            return None
        f3 = lambda: np.zeros((1, 3), np.float32)  # noqa: E731
        vl = tuple(np.ascontiguousarray(a[:1]).copy() for a in self.lobes[:9]) + (np.zeros((1, 3), np.float32),)
        return (*self.program_tables, f3(), f3(), f3(), f3(), np.zeros((1, 2), np.float32), np.zeros(1, np.bool_),
                np.zeros(1, np.int32), np.zeros((1, 0, 3, 2), np.float32), np.zeros((1, 0), np.float32),
                np.zeros((1, 2, 3), np.float32), np.zeros((1, 2, 2), np.float32),
                np.zeros((1, self.tangent_layers.shape[1], 4), np.float32),
                np.empty((self.max_registers, 3), np.float32),
                np.ascontiguousarray(self.ps.materials.select_scale, np.float32), f3(), f3(), np.zeros(1, np.bool_),
                np.zeros((0, 1, 4), np.float32), vl, f3(), self.tangent_layers, self.needs_tangents, f3(),
                np.zeros(self.lobes[1][:1].shape, np.float32), self.needs_differentials,
                np.zeros((1, 2, 2), np.float32),
                np.zeros(0, np.float32) if ray_dp is None else np.ascontiguousarray(ray_dp, np.float32),
                np.zeros(0, np.float32) if ray_dd is None else np.ascontiguousarray(ray_dd, np.float32),
                np.zeros(int(self.settings.max_bounces) + 2 if deferred else 0, np.float32))

    def trace(self, pixel_id: np.ndarray, sample_id: np.ndarray, origins: np.ndarray | None,
              directions: np.ndarray | None, tmax: np.ndarray | None, depth_scale: np.ndarray | None,
              t_start: np.ndarray | None, want_aovs: bool, stats, ray_dp: np.ndarray | None = None,
              ray_dd: np.ndarray | None = None, camera: PinholeRays | None = None) -> tuple:
        """Radiance (N, 3) float32 of N camera paths and, with want_aovs, their first hits' albedo (N, 3), normal
        (N, 3) and depth (N,) (zeros, zeros and inf where the camera ray missed; else None), as PathTracer.trace's
        FirstHit holds them; adds to stats' counters. ray_dp, ray_dd (N,) float32: the camera rays' compact
        differentials as PathTracer.trace takes them (None: zero), which Bump nodes read. camera: a pinhole camera's
        rays not made yet, in place of the five camera ray arrays (None each): the kernel makes each path's, and
        its differentials where the path reaches a Bump node."""
        ps, s = self.ps, self.settings
        n = len(pixel_id)
        if camera is not None:
            origins = directions = np.zeros((0, 3), np.float32)
            tmax = depth_scale = t_start = np.zeros(0, np.float32)
            raster_x, raster_y, pinhole = camera.raster_x, camera.raster_y, camera.params
        else:
            raster_x = raster_y = pinhole = np.zeros(0)
        radiance = np.empty((n, 3), np.float32)
        counters = np.zeros(COUNTERS, np.int64)  # core.fused_path.TIMED fills the entries past the 4th
        # the kernel allocates nothing (no reference counting in its loop): its scratch comes from here. A
        # 16-byte aligned RTCRayHit (core.embree), the light kernels' per-point probabilities, and the lobes of
        # each material with its own diffuse-normal rows (written per vertex)
        raw = np.zeros(_RAY_WORDS, np.float32)
        pad = ((16 - raw.ctypes.data % 16) % 16) // 4
        words = raw[pad:pad + 32]
        buf = np.empty(max(self.lt[1].shape[0], 1))
        dn = np.zeros((len(self.specular), 3), np.float32)
        dn[:, 2] = 1.0
        # where a material's lobe choice follows the view, the kernel rewrites its select rows: a copy per call
        select = self.lobes[5].copy() if self.view_select.any() else self.lobes[5]
        lobes = (*self.lobes[:5], select, *self.lobes[6:9], dn)
        if want_aovs:
            first = (np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32), np.full(n, np.inf, np.float32))
            aov_args = (np.ascontiguousarray(t_start, np.float32), np.ascontiguousarray(depth_scale, np.float32),
                        self.albedo, *first)
        else:
            first = None
            aov_args = (np.zeros(0, np.float32), np.zeros(0, np.float32), self.albedo, np.zeros((0, 3), np.float32),
                        np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
        trace_paths(np.ascontiguousarray(pixel_id, np.uint32), np.ascontiguousarray(sample_id, np.uint32),
                    np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(directions, np.float32),
                    np.ascontiguousarray(tmax, np.float32), np.ascontiguousarray(raster_x, np.float64),
                    np.ascontiguousarray(raster_y, np.float64), np.ascontiguousarray(pinhole, np.float64),
                    self.intersect1, self.occluded1, self.scene,
                    ps.tri_vertices, ps.face_normals, ps.kernel_corner_normals, ps.kernel_smooth, ps.tri_magnitude,
                    ps.material_index, self.specular, lobes, self.view_select, self.select_scale,
                    self.multiscatter, self.tabs, ps.has_nondelta, ps.materials.has_transmission,
                    np.ascontiguousarray(ps.materials.emission, np.float32), self.emitters, self.lt, self.per_point,
                    self.n_matters, self.has_emission, self.seed_key, self.set_keys, self.dim_keys, self.tables,
                    self.group_bits, int(s.max_bounces), int(s.rr_depth), np.float32(s.clamp),
                    self.shadow_epsilon, words, words.view(np.uint32), words.ctypes.data, buf, radiance, counters,
                    *aov_args, self.terminator, self._programs(ray_dp, ray_dd, camera is not None and ray_dp is None
                                                                   and bool(self.needs_differentials.any())))
        stats.nonfinite += int(counters[0])
        stats.clamped += int(counters[1])
        self.accel.count_rays(int(counters[2]), int(counters[3]))
        return radiance, first
