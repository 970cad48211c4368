"""Monte's settings in Blender: `scene.monte` (render settings) and `view_layer.monte` (extra passes).

Every default is read from `core.settings.RenderSettings()`, so Blender, the CLI and the tests agree by
construction; `render_settings(scene)` turns the properties back into a validated `RenderSettings`.
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from ..core.distributed import DEFAULT_CONNECT_TIMEOUT
from ..core.settings import PREVIEW_SAMPLES, VIEWPORT_SAMPLES, VIEWPORT_START_RESOLUTION, RenderSettings

_DEFAULTS = RenderSettings()

SAMPLER_ITEMS = [
    ("sobol", "Sobol", "Owen-scrambled Sobol sequence: the lowest noise for most scenes"),
    ("stratified", "Stratified", "Jittered strata per pixel (the seed's 2x2 sub-pixel strata)"),
    ("independent", "Independent", "Independent uniform random numbers (for reference and tests)"),
]
FILTER_ITEMS = [
    ("blackman-harris", "Blackman-Harris", "Cycles' default pixel filter (width 1.5 px)"),
    ("gaussian", "Gaussian", "Gaussian pixel filter"),
    ("tent", "Tent", "Triangular pixel filter (the seed's tent-distributed sub-pixel offsets)"),
    ("box", "Box", "Box pixel filter: each sample stays inside its pixel"),
]
DENOISING_QUALITY_ITEMS = [
    ("high", "High", "The best quality, the slowest (Open Image Denoise's high quality; Cycles' default)"),
    ("balanced", "Balanced", "Between high and fast"),
    ("fast", "Fast", "The fastest, lower quality"),
]
LIGHT_SAMPLING_ITEMS = [
    ("mis", "Multiple Importance", "Light and BSDF sampling combined with multiple importance sampling"),
    ("bsdf", "BSDF Only", "BSDF sampling only (reference and tests; noisy with small lights)"),
    ("light", "Lights Only", "Next-event estimation only (reference and tests; misses sharp reflections)"),
]

# scene.monte property name -> RenderSettings field
SETTING_FIELDS = {
    "samples": "spp",
    "seed": "seed",
    "sampler": "sampler",
    "filter_type": "filter_type",
    "filter_width": "filter_width",
    "max_bounces": "max_bounces",
    "rr_depth": "rr_depth",
    "clamp": "clamp",
    "threads": "threads",
    "batch_paths": "batch_paths",
    "tile_size": "tile_size",
    "time_limit": "time_limit",
    "light_sampling": "light_sampling",
    "adaptive_min_samples": "adaptive_min_samples",
}


def _passes_changed(_self, context) -> None:
    # The compositor's Render Layers node lists the passes update_render_passes declares: refresh it.
    view_layer = getattr(context, "view_layer", None)
    if view_layer is not None:
        view_layer.update_render_passes()


class MonteRenderSettings(bpy.types.PropertyGroup):
    """Render settings for Monte, stored per scene (scene.monte)."""

    samples: IntProperty(
        name="Samples", description="Samples per pixel", default=_DEFAULTS.spp, min=1, soft_max=4096,
    )
    seed: IntProperty(
        name="Seed", description="Seed of every random number: the same seed renders the same image",
        default=_DEFAULTS.seed, min=0,
    )
    use_animated_seed: BoolProperty(
        name="Animated Seed",
        description="Add the frame number to the seed, so that the noise pattern changes from frame to frame",
        default=False,
    )
    sampler: EnumProperty(
        name="Sampler", description="How sample positions are generated", items=SAMPLER_ITEMS,
        default=_DEFAULTS.sampler,
    )
    filter_type: EnumProperty(
        name="Pixel Filter", description="Reconstruction filter, importance sampled as Cycles does",
        items=FILTER_ITEMS, default=_DEFAULTS.filter_type,
    )
    filter_width: FloatProperty(
        name="Width", description="Pixel filter width in pixels (Cycles' meaning)",
        default=_DEFAULTS.filter_width, min=0.01, max=64.0, soft_max=10.0, subtype="PIXEL",
    )
    max_bounces: IntProperty(
        name="Max Bounces",
        description="Longest path, Cycles' counting (0 still gives direct light at the first hit)",
        default=_DEFAULTS.max_bounces, min=0, max=1024, soft_max=64,
    )
    rr_depth: IntProperty(
        name="Russian Roulette Depth",
        description="Bounces before paths may be ended at random by their throughput (unbiased)",
        default=_DEFAULTS.rr_depth, min=0, max=1024, soft_max=64,
    )
    clamp: FloatProperty(
        name="Clamp", description="Largest value a sample may add (0 disables clamping; clamping is biased)",
        default=_DEFAULTS.clamp, min=0.0,
    )
    time_limit: FloatProperty(
        name="Time Limit",
        description="Stop after this many seconds, between sample batches (0 = no limit)",
        default=_DEFAULTS.time_limit, min=0.0, subtype="TIME_ABSOLUTE", unit="TIME_ABSOLUTE",
    )
    light_sampling: EnumProperty(
        name="Light Sampling", description="Which light transport estimator to use",
        items=LIGHT_SAMPLING_ITEMS, default=_DEFAULTS.light_sampling,
    )
    use_adaptive_sampling: BoolProperty(
        name="Adaptive Sampling",
        description="Stop sampling pixels whose noise is below the threshold (Cycles' noise metric and scale)",
        default=_DEFAULTS.adaptive_threshold > 0,
    )
    adaptive_threshold: FloatProperty(
        name="Noise Threshold",
        description="Noise level at which a pixel stops taking samples: its standard error summed over R, G, B "
        "divided by the square root of its value (lower is cleaner and slower; Cycles' scale)",
        default=_DEFAULTS.adaptive_threshold or 0.01, min=0.0001, max=0.999, precision=4, step=0.1,
    )
    adaptive_min_samples: IntProperty(
        name="Min Samples",
        description="Samples every pixel takes before it may stop (0 = automatic: 4 / sqrt(threshold), at "
        "least 16)", default=_DEFAULTS.adaptive_min_samples, min=0, max=1 << 24,
    )
    threads: IntProperty(
        name="Threads",
        description="Ray-casting threads (0 = Blender's thread count: all cores, or the fixed number set in "
        "Blender's Performance panel or with blender -t)", default=_DEFAULTS.threads, min=0,
        max=1024,
    )
    batch_paths: IntProperty(
        name="Batch Size",
        description="Paths traced at once: larger is faster up to a point and uses more memory; "
        "Esc takes effect between batches",
        default=_DEFAULTS.batch_paths, min=1024, max=1 << 26,
    )
    tile_size: IntProperty(
        name="Tile Size", description="Edge of the square tiles shown as they finish, in pixels",
        default=_DEFAULTS.tile_size, min=8, max=4096, subtype="PIXEL",
    )
    viewport_samples: IntProperty(
        name="Viewport Samples",
        description="Samples per pixel the Rendered viewport refines to, one sample at a time",
        default=VIEWPORT_SAMPLES, min=1, soft_max=4096,
    )
    viewport_start_resolution: IntProperty(
        name="Start Resolution",
        description="After a change the viewport first shows an image of about this many pixels squared, then "
        "doubles the resolution each pass up to the full view divided by Pixel Size (0 = start at full size)",
        default=VIEWPORT_START_RESOLUTION, min=0, soft_max=1024, subtype="PIXEL",
    )
    preview_samples: IntProperty(
        name="Preview Samples",
        description="Samples per pixel of material, light and world previews (read from the preview scene "
        "Blender builds, so previews normally take the default)", default=PREVIEW_SAMPLES, min=1, soft_max=1024,
    )
    use_denoising: BoolProperty(
        name="Denoise",
        description="Denoise the final render with Intel Open Image Denoise (needs the pyoidn package), guided "
        "by Cycles' Denoising Albedo and Normal passes; the image before denoising stays in the Noisy Image pass",
        default=_DEFAULTS.denoising_features, update=_passes_changed,
    )
    denoising_quality: EnumProperty(
        name="Quality", description="Open Image Denoise's quality", items=DENOISING_QUALITY_ITEMS,
        default="high",
    )
    # Cluster (Render Properties > Cluster): not render settings, they choose where the frame is rendered.
    use_cluster: BoolProperty(
        name="Render on a Dask Cluster",
        description="F12 and command-line renders send the exported frame to a Dask cluster and merge the "
        "workers' results into the same image, bit for bit, as a render on this machine",
        default=False,
    )
    cluster_address: StringProperty(
        name="Scheduler",
        description="The Dask scheduler's address (tcp://host:8786), or local:N to start N worker processes on "
        "this machine", default="tcp://127.0.0.1:8786",
    )
    cluster_timeout: FloatProperty(
        name="Timeout",
        description="Seconds to reach the scheduler and see a worker before the render fails",
        default=DEFAULT_CONNECT_TIMEOUT, min=0.1, soft_max=120.0, subtype="TIME_ABSOLUTE", unit="TIME_ABSOLUTE",
    )
    cluster_status: StringProperty(
        name="Cluster Status", description="What the last Test Connection found", default="",
    )


class MonteViewLayerSettings(bpy.types.PropertyGroup):
    """Monte's passes beyond Blender's own Depth and Normal flags (view_layer.monte)."""

    use_pass_albedo: BoolProperty(
        name="Albedo", description="First-hit surface colour (for denoisers and compositing)", default=False,
        update=_passes_changed,
    )
    use_pass_variance: BoolProperty(
        name="Variance", description="Estimated variance of each pixel's mean (noise map). Its estimate splits "
        "each pixel's samples into 2 independently scrambled sequences, which makes the image's variance about "
        "15 % higher at the same samples", default=False,
        update=_passes_changed,
    )


def render_settings(scene, overrides=None) -> RenderSettings:
    """A validated RenderSettings from scene.monte (plus RenderSettings-named overrides, for one run).
    error_estimate is on only with adaptive sampling or when an override asks for it (the Variance pass)."""
    props = scene.monte
    values = {field: getattr(props, prop) for prop, field in SETTING_FIELDS.items()}
    if props.use_animated_seed:
        values["seed"] = (values["seed"] + scene.frame_current) % (2**32)
    values["adaptive_threshold"] = props.adaptive_threshold if props.use_adaptive_sampling else 0.0
    values["denoising_features"] = bool(props.use_denoising)
    cycles = getattr(scene, "cycles", None)  # Light Paths > Transparent bounces: Cycles' settings, shared
    if cycles is not None and hasattr(cycles, "transparent_max_bounces"):
        values["transparent_max_bounces"] = int(cycles.transparent_max_bounces)
    if cycles is not None and hasattr(cycles, "min_transparent_bounces"):
        values["transparent_min_bounces"] = int(cycles.min_transparent_bounces)
    values.update(overrides or {})
    # The per-pixel error estimate (core's 2 variance groups: ~14-18 % more variance at equal samples) only where
    # something reads it: adaptive sampling here, the Variance pass where the caller asks (engine: the passes).
    values["error_estimate"] = bool(values.get("error_estimate", False)) or values["adaptive_threshold"] > 0
    return RenderSettings(**{**_field_defaults(), **values}).validate()


def _field_defaults() -> dict:
    from dataclasses import fields

    return {f.name: getattr(_DEFAULTS, f.name) for f in fields(_DEFAULTS)}


classes = (MonteRenderSettings, MonteViewLayerSettings)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.monte = PointerProperty(type=MonteRenderSettings, name="Monte Render Settings")
    bpy.types.ViewLayer.monte = PointerProperty(type=MonteViewLayerSettings, name="Monte Passes")


def unregister() -> None:
    del bpy.types.ViewLayer.monte
    del bpy.types.Scene.monte
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
