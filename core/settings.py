"""Render settings shared by the CLI, the Blender add-on and the tests (defaults match both)."""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass, fields
from typing import Literal

SAMPLERS = ("sobol", "stratified", "independent")
FILTERS = ("blackman-harris", "gaussian", "tent", "box")
# Settings a user overrides from the command line (`monte render`, `monte bench`).
CLI_SETTINGS = ("spp", "seed", "sampler", "filter_type", "filter_width", "max_bounces", "rr_depth", "clamp",
                "threads", "batch_paths", "tile_size", "time_limit", "adaptive_threshold", "adaptive_min_samples")

# The interactive viewport and material previews (Blender add-on): samples the viewport refines to, the image
# size (about START^2 pixels) a restart shows first, and the samples of a material preview.
VIEWPORT_SAMPLES = 32
VIEWPORT_START_RESOLUTION = 64
PREVIEW_SAMPLES = 16

_LABELS = {"spp": "samples per pixel (spp)", "max_bounces": "max bounces", "rr_depth": "Russian roulette depth",
           "batch_paths": "batch size (batch_paths)", "tile_size": "tile size", "filter_width": "filter width",
           "time_limit": "time limit", "adaptive_threshold": "adaptive threshold",
           "adaptive_min_samples": "adaptive min samples", "transparent_max_bounces": "transparent max bounces",
           "transparent_min_bounces": "transparent min bounces"}


@dataclass
class RenderSettings:
    """How to render. Bounce counting follows Cycles: max_bounces = 0 still gives direct light at the first hit.

    spp: samples per pixel. seed: every random number is a pure function of (seed, pixel, sample, dimension).
    sampler: "sobol" (Owen-scrambled Sobol), "stratified" (the seed's 2x2 strata per pixel), "independent".
    filter_type/filter_width: pixel filter importance-sampled as Cycles does (width in pixels, Cycles' meaning).
    rr_depth: Russian roulette starts after this many bounces (2, as Cycles: its min_bounce is the UI's
    minimum light bounces 0 + 1, and a path's bounce count must exceed it). clamp: max sample value (0 = off, unbiased).
    threads: ray-casting threads (0 = all cores). batch_paths: paths alive at once (bounds memory).
    tile_size: square tile edge in pixels. time_limit: seconds, 0 = none (stops between sample batches).
    light_sampling: "mis" (default), "bsdf" (BSDF sampling only) or "light" (next-event estimation only; for
    the unbiasedness tests). aovs: also produce albedo, normal and depth passes.
    adaptive_threshold: adaptive sampling's noise threshold, Cycles' meaning and scale (0 = off, the default;
    Cycles suggests 0.01): a pixel stops taking samples once the sum of its channels' standard errors divided by
    sqrt of its summed value is below it. adaptive_min_samples: samples every pixel gets before the test
    (0 = automatic: 4 / sqrt(threshold), at least 16, at most spp).
    denoising_features: also produce Cycles' Denoising Albedo and Denoising Normal passes (what the denoiser of
    core.denoise reads; see core.integrator.DenoisingFeatures); off costs nothing.
    data_passes: Cycles' data passes to produce, keys of core.data_passes.DATA_PASSES ("mist", "position", "uv",
    "object_index", "material_index", "crypto_object", "crypto_material", "crypto_asset"); empty (the default)
    costs nothing. cryptomatte_levels: (id, coverage) pairs kept per pixel (Blender's Cryptomatte Levels,
    1-16, rounded up to even: two pairs per 4-channel layer).
    light_passes: Cycles' light passes to produce, by name (core.light_passes.LIGHT_PASSES: "Diffuse Direct",
    ..., "Emission", "Environment"); empty (the default) costs nothing.
    transparent_max_bounces: transparent surfaces a shadow ray goes through before it counts as blocked (Cycles'
    Light Paths > Transparent bounces, default 8; see core.transparent_shadow).
    transparent_min_bounces: Cycles' Min Transparent Bounces (scene.cycles.min_transparent_bounces, default 0): a
    path that arrives at a surface through a Transparent BSDF meets Russian roulette only once it has made more
    than this + 1 transparent bounces (Cycles' transparent_min_bounce); any other path once its bounces (passes
    through Transparent BSDFs not counted) reach rr_depth.
    error_estimate: keep an unbiased estimate of each pixel's error (RenderResult.variance: the Variance pass,
    `monte render --variance`). It needs the pixel's samples split into core.sampling.VARIANCE_GROUPS (2)
    independently scrambled Sobol sequences, whose spread measures the error; each is a half-size point set, so the
    image itself is noisier: on the `instances` bench scene 1.14-1.18x the variance per sample of one sequence (the
    MSE a render pays at equal samples; docs/performance.md), and the film keeps 12 B more per pixel. Off: one
    Owen-scrambled Sobol sequence per pixel (as Cycles), and RenderResult.variance is None. Adaptive sampling reads
    the estimate: a threshold > 0 with error_estimate False is refused (validate()). Core's default keeps it (core
    users read result.variance); the add-on and `monte render` turn it on only where something reads it.
    """

    spp: int = 64
    seed: int = 0
    sampler: Literal["sobol", "stratified", "independent"] = "sobol"
    filter_type: Literal["blackman-harris", "gaussian", "tent", "box"] = "blackman-harris"
    filter_width: float = 1.5
    max_bounces: int = 16
    rr_depth: int = 2
    clamp: float = 0.0
    threads: int = 0
    batch_paths: int = 1 << 18
    tile_size: int = 64
    time_limit: float = 0.0
    light_sampling: Literal["mis", "bsdf", "light"] = "mis"
    aovs: bool = True
    adaptive_threshold: float = 0.0
    adaptive_min_samples: int = 0
    denoising_features: bool = False
    data_passes: tuple[str, ...] = ()
    cryptomatte_levels: int = 6
    light_passes: tuple[str, ...] = ()
    transparent_max_bounces: int = 8
    transparent_min_bounces: int = 0
    error_estimate: bool = True

    def validate(self) -> "RenderSettings":
        """Raise ValueError naming the setting for absurd values (NaN, Inf and non-numbers included)."""
        for name in ("spp", "seed", "max_bounces", "rr_depth", "threads", "batch_paths", "tile_size",
                     "adaptive_min_samples", "transparent_max_bounces", "transparent_min_bounces"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) \
                    or int(value) != value:
                raise ValueError(f"{_LABELS.get(name, name)} must be a whole number, got {value!r}")
        for name in ("filter_width", "clamp", "time_limit", "adaptive_threshold"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise ValueError(f"{_LABELS.get(name, name)} must be a finite number, got {value!r}")
        if int(self.spp) != self.spp or self.spp < 0:
            raise ValueError(f"samples per pixel must be a non-negative integer, got {self.spp}")
        if self.sampler not in SAMPLERS:
            raise ValueError(f"unknown sampler {self.sampler!r}; choose one of {', '.join(SAMPLERS)}")
        if self.filter_type not in FILTERS:
            raise ValueError(f"unknown filter {self.filter_type!r}; choose one of {', '.join(FILTERS)}")
        if not (math.isfinite(self.filter_width) and self.filter_width > 0):
            raise ValueError(f"filter width must be a positive number of pixels, got {self.filter_width}")
        if self.filter_width > 64:
            raise ValueError(f"filter width {self.filter_width} px is absurd (at most 64)")
        if int(self.max_bounces) != self.max_bounces or self.max_bounces < 0:
            raise ValueError(f"max bounces must be a non-negative integer, got {self.max_bounces}")
        if self.transparent_max_bounces < 0:
            raise ValueError(f"transparent max bounces must be >= 0, got {self.transparent_max_bounces}")
        if self.transparent_min_bounces < 0:
            raise ValueError(f"transparent min bounces must be >= 0, got {self.transparent_min_bounces}")
        if self.rr_depth < 0:
            raise ValueError(f"Russian roulette depth must be >= 0, got {self.rr_depth}")
        if not (math.isfinite(self.clamp) and self.clamp >= 0):
            raise ValueError(f"clamp must be >= 0 (0 = off), got {self.clamp}")
        if self.threads < 0:
            raise ValueError(f"threads must be >= 0 (0 = all cores), got {self.threads}")
        if self.batch_paths < 1024:
            raise ValueError(f"batch size must be at least 1024 paths, got {self.batch_paths}")
        if self.tile_size < 1:
            raise ValueError(f"tile size must be at least 1 pixel, got {self.tile_size}")
        if not (math.isfinite(self.time_limit) and self.time_limit >= 0):
            raise ValueError(f"time limit must be >= 0 seconds, got {self.time_limit}")
        if self.light_sampling not in ("mis", "bsdf", "light"):
            raise ValueError(f"unknown light sampling {self.light_sampling!r}")
        if not (math.isfinite(self.adaptive_threshold) and 0 <= self.adaptive_threshold < 1):
            raise ValueError(f"adaptive threshold must be in [0, 1) (0 = off), got {self.adaptive_threshold}")
        if int(self.adaptive_min_samples) != self.adaptive_min_samples or self.adaptive_min_samples < 0:
            raise ValueError(f"adaptive min samples must be a non-negative integer (0 = automatic), "
                             f"got {self.adaptive_min_samples}")
        from .data_passes import DATA_PASSES

        unknown = [p for p in self.data_passes if p not in DATA_PASSES]
        if isinstance(self.data_passes, str) or unknown:
            raise ValueError(f"unknown data pass {unknown[0] if unknown else self.data_passes!r}; choose from "
                             f"{', '.join(DATA_PASSES)}")
        if isinstance(self.cryptomatte_levels, bool) or not isinstance(self.cryptomatte_levels, numbers.Integral) \
                or not 1 <= self.cryptomatte_levels <= 16:
            raise ValueError(f"cryptomatte levels must be a whole number in [1, 16], got {self.cryptomatte_levels!r}")
        from .light_passes import check_names

        check_names(self.light_passes)
        if not isinstance(self.error_estimate, bool):
            raise ValueError(f"error_estimate must be True or False, got {self.error_estimate!r}")
        if self.adaptive_threshold > 0 and not self.error_estimate:
            raise ValueError("adaptive sampling (adaptive threshold > 0) reads each pixel's error estimate: "
                             "set error_estimate=True")
        if not (0 <= self.seed < 2**32):
            raise ValueError(f"seed must be in [0, 2^32), got {self.seed}")
        return self

    def adaptive_min_samples_for(self, spp: int) -> int:
        """Samples every pixel takes before adaptive sampling may stop it."""
        if self.adaptive_min_samples > 0:
            return min(int(self.adaptive_min_samples), spp)
        return min(max(16, math.ceil(4 / math.sqrt(self.adaptive_threshold))), spp)

    @property
    def variance_groups(self) -> int:
        """The variance groups a render with these settings keeps per pixel (core.sampling.Sampler.variance_group):
        core.sampling.VARIANCE_GROUPS with an error estimate, else 1 (one scrambled sequence per pixel)."""
        from .sampling import VARIANCE_GROUPS

        return VARIANCE_GROUPS if self.error_estimate else 1

    @property
    def thread_count(self) -> int:
        return self.threads or (os.cpu_count() or 1)

    def replace(self, **changes) -> "RenderSettings":
        known = {f.name for f in fields(self)}
        unknown = set(changes) - known
        if unknown:
            raise ValueError(f"unknown render settings: {', '.join(sorted(unknown))}")
        return RenderSettings(**{**{f.name: getattr(self, f.name) for f in fields(self)}, **changes})
