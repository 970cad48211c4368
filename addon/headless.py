"""Render a .blend file with Monte from plain Python (the `bpy` module), as `monte render scene.blend -o out.exr`.

`render_blend_file(blend_path, output_path, overrides)` loads the file, registers the engine in this process,
applies the overrides to the loaded scene (the file on disk is never saved, so they last for this run only),
renders through the engine exactly as F12 does, and writes the EXR atomically: to a temporary file beside
the target, then os.replace, so an existing file is either kept whole or replaced whole.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Callable, Iterator, NamedTuple

import bpy  # at import time, so that callers without the bpy module get an ImportError up front
import numpy as np

from ..core.settings import RenderSettings
from .properties import SETTING_FIELDS

# override key -> scene.monte property: the property's own name, the RenderSettings field it maps to
# (properties.SETTING_FIELDS), and "filter" as the CLI spells it.
_MONTE_KEYS = {**{prop: prop for prop in SETTING_FIELDS},
               **{field: prop for prop, field in SETTING_FIELDS.items()},
               "filter": "filter_type"}
# override key -> what it sets outside scene.monte
_OTHER_KEYS = {
    "resolution": "(width, height) in pixels",
    "resolution_percentage": "resolution scale in percent",
    "frame": "frame number to render",
    "camera": "name of the camera object to render from",
    "scene": "name of the scene to render (default: the file's active scene)",
    "adaptive_threshold": "adaptive sampling's noise threshold (0 turns adaptive sampling off)",
    "denoise": "denoise with Open Image Denoise (True/False; the scene's Denoise setting)",
    "denoise_quality": "Open Image Denoise's quality: high, balanced or fast",
    "variance": "also estimate each pixel's error and write it (variance.R/G/B; the Variance pass): 2 "
                "variance groups per pixel, ~15 % more variance at the same samples (True/False, default False "
                "unless the view layer ticks the Variance pass)",
    "file_passes": "write the passes the view layers tick, not every pass Monte has: Z, normal and albedo "
                   "(computed together) only where the view layer ticks one of them (True/False, default False; "
                   "the image itself is the same bits)",
    "multilayer": "write Blender's multilayer EXR (every view layer and pass, after compositing) instead of "
                  "Monte's channel layout",
}

_BLEND_MAGIC = (b"BLENDER", b"\x1f\x8b", b"\x28\xb5\x2f\xfd")  # plain, gzip, zstd


def end_bpy_process(status: int, quick_exit: bool = False) -> None:
    """Unregister Monte, and on Blender versions whose bpy module cannot shut down end the process now.

    Call it last, once every output is written and closed: the bpy module of Blender 4.2 crashes (SIGSEGV,
    status 139) at interpreter exit and 4.5's hangs, so a finished headless render would report a failure or
    never return. There the process ends with os._exit(status) after removing Blender's temporary folder and
    flushing stdout and stderr; on 5.0 and newer, after unregistering, this returns and Python exits normally.

    quick_exit (the `monte` command): on 5.0 and newer too, end the process here once the exit handlers ran
    (Python's atexit functions, among them bpy's), Blender's temporary folder is removed and stdout and stderr
    are flushed, skipping the interpreter's teardown of every module and object: with numba's compiled kernels
    loaded that teardown took 0.5-0.7 s of a 1-spp render's process (all of Cycles' process exit: 0.25 s).
    Only when no other non-daemon thread is running (a normal exit waits for those); else Python exits
    normally.
    """
    from . import unregister

    unregister()
    if bpy.app.version < (5, 0, 0):
        _remove_session_temp_folder()
        _flush_output()
        os._exit(int(status))
    if quick_exit and _only_daemon_threads_left():
        import atexit

        atexit._run_exitfuncs()
        _remove_session_temp_folder()
        _flush_output()
        os._exit(int(status))


def _flush_output() -> None:
    """Flush Python's stdout and stderr and the C library's streams (Blender's own printf lines, e.g. "Read
    blend", sit in a full buffer when stdout is a pipe): os._exit() flushes neither. A closed pipe is ignored."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    try:
        import ctypes

        libc = ctypes.CDLL(None) if os.name != "nt" else ctypes.CDLL("ucrtbase")
        libc.fflush(None)
    except (OSError, AttributeError):
        pass


def _remove_session_temp_folder() -> None:
    """Remove the temporary folder Blender made for this process (bpy.app.tempdir, /tmp/blender_XXXXXX/), as
    Blender's own teardown does; the quick exit skips that teardown."""
    import shutil

    folder = os.path.normpath(bpy.app.tempdir or "")
    if os.path.basename(folder).startswith("blender_") and os.path.isdir(folder):
        shutil.rmtree(folder, ignore_errors=True)


def _only_daemon_threads_left() -> bool:
    """True when every running thread but this one is a daemon thread (which a normal exit does not wait for)."""
    import threading

    current = threading.current_thread()
    return all(t is current or t.daemon or not t.is_alive() for t in threading.enumerate())


class HeadlessError(RuntimeError):
    """A headless render failed; the message names the file and the reason."""


def known_overrides() -> dict[str, str]:
    out = {k: f"Monte setting {v}" for k, v in _MONTE_KEYS.items()}
    out.update(_OTHER_KEYS)
    return out


def _check_blend(path: Path) -> None:
    if not path.exists():
        raise FileNotFoundError(f"no such .blend file: {path}")
    if not path.is_file():
        raise HeadlessError(f"{path} is not a file")
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError as exc:
        raise HeadlessError(f"cannot read {path}: {exc}") from exc
    if not any(head.startswith(m) for m in _BLEND_MAGIC):
        raise HeadlessError(f"{path} is not a Blender file (it does not start with a .blend header)")


def open_blend(blend: Path) -> None:
    """Open a checked .blend as Blender's main file with Monte registered; HeadlessError if Blender cannot."""
    from . import register

    register()
    try:
        result = bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False)
    except RuntimeError as exc:
        raise HeadlessError(f"could not open {blend}: {str(exc).strip()}") from exc
    if "FINISHED" not in result:
        raise HeadlessError(f"could not open {blend}")


def _validate_overrides(overrides: dict[str, Any]) -> dict[str, Any]:
    clean = {k: v for k, v in (overrides or {}).items() if v is not None}
    unknown = sorted(set(clean) - set(_MONTE_KEYS) - set(_OTHER_KEYS))
    if unknown:
        raise ValueError(f"unknown render override(s) {', '.join(unknown)}; known: "
                         f"{', '.join(sorted(set(_MONTE_KEYS) | set(_OTHER_KEYS)))}")
    # Check the Monte settings with core's own validation before touching Blender.
    fields = {}
    for key, prop in _MONTE_KEYS.items():
        if key in clean:
            fields[SETTING_FIELDS[prop]] = clean[key]
    if "adaptive_threshold" in clean:
        fields["adaptive_threshold"] = clean["adaptive_threshold"]
    for key in ("variance", "file_passes"):
        if key in clean and not isinstance(clean[key], bool):
            raise ValueError(f"override {key} must be True or False, got {clean[key]!r}")
    RenderSettings().replace(**fields).validate()
    return clean


def _apply_overrides(bpy, scene, overrides: dict[str, Any]) -> None:
    monte = scene.monte
    for key, value in overrides.items():
        if key in _MONTE_KEYS:
            prop = _MONTE_KEYS[key]
            try:
                setattr(monte, prop, value)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"override {key}={value!r}: {exc}") from exc
    if "denoise" in overrides:
        monte.use_denoising = bool(overrides["denoise"])
    if "denoise_quality" in overrides:
        try:
            monte.denoising_quality = overrides["denoise_quality"]
        except (TypeError, ValueError) as exc:
            raise ValueError(f"override denoise_quality={overrides['denoise_quality']!r}: {exc}") from exc
    if "adaptive_threshold" in overrides:
        threshold = float(overrides["adaptive_threshold"])
        monte.use_adaptive_sampling = threshold > 0
        if threshold > 0:
            monte.adaptive_threshold = threshold
    r = scene.render
    if "resolution" in overrides:
        w, h = overrides["resolution"]
        r.resolution_x, r.resolution_y = int(w), int(h)
        if "resolution_percentage" not in overrides:
            r.resolution_percentage = 100
    if "resolution_percentage" in overrides:
        r.resolution_percentage = int(overrides["resolution_percentage"])
    if "camera" in overrides:
        cam = bpy.data.objects.get(overrides["camera"])
        if cam is None or cam.type != "CAMERA":
            raise ValueError(f"override camera={overrides['camera']!r}: no camera object of that name")
        scene.camera = cam
    if "frame" in overrides:
        scene.frame_set(int(overrides["frame"]))


def _configure_output(scene, multilayer: bool, variance: bool = False, file_passes: bool = False) -> None:
    for layer in scene.view_layers:
        if not file_passes:  # every pass Monte has: Monte's layout carries them all
            layer.use_pass_z = layer.use_pass_normal = True
            layer.monte.use_pass_albedo = True
        # but the Variance pass only when asked (or ticked): its estimate costs the image ~15 % more variance
        layer.monte.use_pass_variance = layer.monte.use_pass_variance or variance
    if not multilayer:
        return
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5.0+
        settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"


def _monte_channels(result, region, size) -> dict:
    """core.exr's channel layout (R G B A, variance.*, albedo.*, normal.*, Z; with denoising noisy.*,
    denoising_albedo.*, denoising_normal.*; with a shadow catcher shadow_catcher.*; with light passes
    diffuse_direct.* ...), the same as `monte render` of a built-in scene; with a region, padded to the full frame (black, depth 1e10, shadow catcher 1) as an
    uncropped border."""
    from ..core.exr import image_channels

    light = getattr(result, "light_passes", None) or {}
    arrays = [result.color, result.variance, result.albedo, result.normal, result.depth, result.noisy,
              result.denoising_albedo, result.denoising_normal, getattr(result, "shadow_catcher", None),
              *light.values()]
    if region is not None:
        x0, y0, w, h = region
        width, height = size
        padded = []
        for arr, fill in zip(arrays, (0.0, 0.0, 0.0, 0.0, 1e10, 0.0, 0.0, 0.0, 1.0) + (0.0,) * (len(arrays) - 9)):
            if arr is None:
                padded.append(None)
                continue
            full = np.full((height, width) + arr.shape[2:], fill, dtype=np.float32)
            full[y0:y0 + h, x0:x0 + w] = arr
            padded.append(full)
        arrays = padded
    channels = image_channels(*arrays[:5], noisy=arrays[5], denoising_albedo=arrays[6], denoising_normal=arrays[7],
                              shadow_catcher=arrays[8], light_passes=dict(zip(light, arrays[9:])))
    data = dict(getattr(result, "data_passes", {}))
    if region is not None and data:
        x0, y0, w, h = region
        width, height = size
        for name, arr in data.items():
            full = np.zeros((height, width, arr.shape[2]), np.float32)
            if name == "Mist":
                full[...] = 1.0  # outside the region: nothing seen, as a miss
            full[y0:y0 + h, x0:x0 + w] = arr
            data[name] = full
    from ..core.exr import data_pass_channels
    from .engine import PASSES

    letters = {name: spec[1] for name, spec in PASSES.items()} | {"Object Index": "X", "Material Index": "X"}
    channels.update(data_pass_channels(data, letters))
    # shader AOVs (core.shader_aovs): "<name>.R/G/B/A" for a COLOR AOV, "<name>.X" for a VALUE one, as Blender
    aovs = dict(getattr(result, "shader_aovs", None) or {})
    if region is not None:
        x0, y0, w, h = region
        for name, arr in aovs.items():
            full = np.zeros((size[1], size[0], arr.shape[2]), np.float32)
            full[y0:y0 + h, x0:x0 + w] = arr
            aovs[name] = full
    channels.update(data_pass_channels(aovs, {name: "RGBA" if arr.shape[2] == 4 else "X"
                                              for name, arr in aovs.items()}))
    # light groups (core.light_groups): "Combined_<group>.R/G/B", as Blender names the passes
    groups = dict(getattr(result, "light_groups", None) or {})
    if region is not None:
        x0, y0, w, h = region
        for name, arr in groups.items():
            full = np.zeros((size[1], size[0], 3), np.float32)
            full[y0:y0 + h, x0:x0 + w] = arr
            groups[name] = full
    channels.update(data_pass_channels(groups, {name: "RGB" for name in groups}))
    return channels


def render_blend_file(
    blend_path: str | os.PathLike,
    output_path: str | os.PathLike,
    overrides: dict[str, Any] | None = None,
    *,
    log: Callable[[str], None] | None = None,
    on_progress: Callable[[Any], None] | None = None,
) -> None:
    """Render `blend_path` with Monte and write the image to `output_path` (OpenEXR, 32-bit float, linear).

    overrides: Monte settings for this run (spp, seed, sampler, filter/filter_type, filter_width, max_bounces,
    rr_depth, clamp, threads, batch_paths, tile_size, time_limit, light_sampling) and resolution,
    resolution_percentage, frame, camera, scene, variance, file_passes, multilayer; None values are ignored. The
    Monte layout holds variance.R/G/B only with variance=True or where the view layer ticks the Variance pass, and
    Z, normal.* and albedo.* always, unless file_passes=True (then only where the view layer ticks one of them).
    on_progress: called with core.render.Progress after every sample batch (e.g. a progress bar).
    Raises FileNotFoundError / HeadlessError naming the file, ValueError for bad overrides.
    """
    say = log or (lambda msg: print(msg, flush=True))
    blend = Path(blend_path).expanduser().resolve()
    out = Path(output_path).expanduser().resolve()
    _check_blend(blend)
    clean = _validate_overrides(dict(overrides or {}))
    if not out.parent.is_dir():
        raise HeadlessError(f"cannot write {out}: folder {out.parent} does not exist")
    if out.suffix.lower() != ".exr":
        raise HeadlessError(f"cannot write {out}: Monte writes OpenEXR; use a .exr file name")
    from ..core.exr import OutputError, check_writable

    try:  # before loading and rendering: a read-only folder must not cost a whole render
        check_writable(out)
    except OutputError as exc:
        raise HeadlessError(str(exc)) from exc

    open_blend(blend)
    scene = bpy.context.scene
    if "scene" in clean:
        scene = bpy.data.scenes.get(clean["scene"])
        if scene is None:
            raise ValueError(f"{blend} has no scene named {clean['scene']!r}; scenes: "
                             f"{', '.join(s.name for s in bpy.data.scenes)}")
    scene.render.engine = "MONTE"
    _apply_overrides(bpy, scene, clean)
    if scene.camera is None:
        raise HeadlessError(f"cannot render {blend}: scene {scene.name!r} has no camera")
    _configure_output(scene, bool(clean.get("multilayer", False)), bool(clean.get("variance", False)),
                      bool(clean.get("file_passes", False)))
    say(f"Monte: rendering {blend.name} (scene {scene.name!r}, frame {scene.frame_current}) to {out}")
    from ..core.precompile import stop_loading_kernels
    from .engine import render_with_operator

    # One render in this process: the background loader (paused while a render runs) would go on after it with
    # the list's other features' kernels, which nothing here calls, until the exit stops it. Stopped now, after
    # the signature it is loading; the render loads what it calls, as it does while the loader is paused.
    stop_loading_kernels(wait=False)
    try:
        captured = render_with_operator(scene, on_progress)
    except RuntimeError as exc:
        raise HeadlessError(f"rendering {blend} failed: {exc}") from exc
    if clean.get("multilayer"):
        _save_blender_multilayer(bpy, scene, blend, out)
    else:
        if not captured:
            raise HeadlessError(f"rendering {blend} produced no image (no view layer is enabled for rendering)")
        from ..core.exr import write_exr

        layer_name, result, region, size = captured[0]
        if len(captured) > 1:
            say(f"Monte: {len(captured)} view layers rendered; writing {layer_name!r} (multilayer=True writes all)")
        if result.cancelled:
            say("Monte: the render stopped early (time limit); the image holds the samples taken")
        write_monte_exr(out, result, region, size, scene.render.use_crop_to_border)
    say(f"Monte: wrote {out}")


def write_monte_exr(out: Path, result, region, size: tuple[int, int], cropped: bool) -> None:
    """A render of a .blend in Monte's channel layout (_monte_channels), written atomically: a render region
    (x0, y0 from the top, width, height) padded to the full frame of `size`, or alone when `cropped` (Blender's
    Crop to Render Region); the Cryptomatte manifests in the header."""
    from ..core.data_passes import cryptomatte_metadata
    from ..core.exr import write_exr

    # Cryptomatte layers are named by their pass (CryptoObject00.R, ...): the metadata names "CryptoObject"
    metadata = {k: v for base, names in getattr(result, "cryptomatte", {}).items()
                for k, v in cryptomatte_metadata(base, names).items()}
    write_exr(out, _monte_channels(result, None if cropped else region, size), metadata)


class BlendFrame(NamedTuple):
    """One frame of a .blend exported for a render elsewhere (export_blend_frames)."""

    frame: int
    scene: Any  # core.scene.Scene
    settings: RenderSettings
    region: tuple[int, int, int, int] | None  # the render region (x0, y0 from the top, w, h), None: the frame
    size: tuple[int, int]  # the frame's (width, height) in pixels
    cropped: bool  # Crop to Render Region: the output is the region alone


def export_blend_frames(blend_path: str | os.PathLike, overrides: dict[str, Any] | None, frames: list[int] | None,
                        *, log: Callable[[str], None] | None = None) -> Iterator[BlendFrame]:
    """Open a .blend once and export each frame's core Scene and RenderSettings (with AOVs, and the data passes,
    light passes and Cryptomatte levels its active view layer selects, as the engine's F12 render), for a render
    of the core scene elsewhere (a Dask cluster: core.distributed); yields a BlendFrame one frame at a time, so a
    caller that stops early exports no more. frames None: the scene's current frame. A render border
    (Render Region) is the frame's region: render only it (render(region=...) or render_on_cluster's).

    overrides as render_blend_file's (but "scene" and "multilayer" do not apply).
    Raises FileNotFoundError / HeadlessError / ValueError."""
    from .engine import (cryptomatte_layers, data_passes, export_listeners, requested_light_passes,
                         requested_passes, unavailable_pass_warnings)
    from .export import render_region, render_resolution
    from .properties import render_settings

    say = log or (lambda msg: print(msg, flush=True))
    blend = Path(blend_path).expanduser().resolve()
    _check_blend(blend)
    clean = _validate_overrides(dict(overrides or {}))
    for key in ("scene", "multilayer", "file_passes"):
        if key in clean:
            raise ValueError(f"override {key} does not apply to a scene exported for a cluster render")
    open_blend(blend)
    scene = bpy.context.scene
    scene.render.engine = "MONTE"
    _apply_overrides(bpy, scene, clean)
    if scene.camera is None:
        raise HeadlessError(f"cannot render {blend}: scene {scene.name!r} has no camera")
    # One view layer goes to the cluster: the active one when it renders, else the first that does; F12 renders
    # only it (the others are off while it runs), so its passes, overrides and export are the same layer's.
    rendered = [layer for layer in scene.view_layers if layer.use]
    if not rendered:
        raise HeadlessError(f"{blend}: no view layer of scene {scene.name!r} is enabled for rendering")
    active = bpy.context.view_layer
    view_layer = active if active.use else rendered[0]
    if len(rendered) > 1:
        say(f"Monte: {len(rendered)} view layers render; the cluster renders view layer {view_layer.name!r}")
    for warning in unavailable_pass_warnings(view_layer, scene):
        say(f"Monte: warning: {warning}")
    keys = data_passes(view_layer, scene)
    region, size = render_region(scene), render_resolution(scene)
    for frame in (frames if frames is not None else [scene.frame_current]):
        scene.frame_set(int(frame))
        # F12's own export (its render depsgraph: render subdivision levels and the like, as a local render
        # sees the scene), handed over by the engine instead of rendered there
        exported: list = []

        def listener(core, stats) -> None:
            exported.append((core, stats))

        export_listeners.append(listener)
        others = [layer for layer in rendered if layer != view_layer]
        for layer in others:
            layer.use = False
        try:
            bpy.ops.render.render(write_still=False, scene=scene.name)
        except RuntimeError as exc:
            message = str(exc).strip()
            message = message[len("Error: "):] if message.startswith("Error: ") else message
            raise HeadlessError(f"{blend}, frame {frame}: {message}") from exc
        finally:
            export_listeners.remove(listener)
            for layer in others:
                layer.use = True
        if len(exported) != 1:
            raise HeadlessError(f"{blend}, frame {frame}: view layer {view_layer.name!r} exported "
                                f"{len(exported)} times (expected once)")
        core_scene, stats = exported[0]
        passes = requested_passes(view_layer, scene)
        settings = render_settings(scene, {"aovs": True, "data_passes": keys,
                                           "cryptomatte_levels": 2 * cryptomatte_layers(view_layer),
                                           "light_passes": requested_light_passes(passes),
                                           "error_estimate": bool(clean.get("variance")) or "Variance" in passes})
        say(f"Monte: exported {blend.name} frame {frame}: {stats.line()}"
            + (f"; render region {region}" if region is not None else ""))
        yield BlendFrame(int(frame), core_scene, settings, region, size, bool(scene.render.use_crop_to_border))


def _save_blender_multilayer(bpy, scene, blend: Path, out: Path) -> None:
    """Blender's own multilayer EXR of the Render Result, written beside the target and renamed onto it."""
    from ..core.atomic_file import OutputError, write_atomically

    image = bpy.data.images.get("Render Result")
    if image is None:
        raise HeadlessError(f"rendering {blend} produced no image")

    def save(tmp: str) -> None:
        image.save_render(tmp, scene=scene)
        if not os.path.getsize(tmp):  # mkstemp made it empty: Blender wrote nothing
            raise HeadlessError(f"Blender did not write {out}")

    try:
        write_atomically(out, save, suffix=".exr")
    except HeadlessError:
        raise
    except (RuntimeError, OutputError) as exc:  # Blender's save_render raises RuntimeError
        raise HeadlessError(f"could not write {out}: {str(exc).strip()}") from exc
