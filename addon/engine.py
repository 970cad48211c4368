"""MonteRenderEngine: Blender's render engine entry point. Thin on purpose: export, call core.render, copy
tiles into Blender's render result, forward progress and cancel.

Blender facts this relies on (see docs/addon.md and the project's notes): an exception escaping render()
is swallowed and can crash Blender when the still is saved, so render() catches everything and reports it
with self.report({'ERROR'}) (the render operator then fails cleanly); a render() that writes no result also
crashes at save time, so a cancelled export still writes a (black) result; render results are row 0 at the
bottom, core's tiles row 0 at the top.
"""

from __future__ import annotations

import time
import traceback

import bpy
import numpy as np

from ..core.distributed import ClusterError
from ..core.scene import SceneError
from .export import ExportCancelled, export_camera, export_scene, render_region, render_resolution
from .export.film import uses_shadow_catcher_pass
from .properties import render_settings

# The one table of passes Monte registers: pass name -> (channels, chanid, type), Cycles' names and layouts.
# Combined is always there; the others when the view layer asks (requested_passes).
PASSES = {
    "Combined": (4, "RGBA", "COLOR"),
    "Depth": (1, "Z", "VALUE"),
    "Normal": (3, "XYZ", "VECTOR"),
    "Albedo": (3, "RGB", "COLOR"),
    "Variance": (3, "RGB", "COLOR"),
    # With denoising on (Cycles' names): the image before denoising and the passes the denoiser read.
    "Noisy Image": (4, "RGBA", "COLOR"),
    "Denoising Normal": (3, "XYZ", "VECTOR"),
    "Denoising Albedo": (3, "RGB", "COLOR"),
    # Cycles' Passes > Light > Shadow Catcher (the view layer's Cycles property): 1 where nothing shadows a
    # shadow catcher, below 1 in its shadows (core.film).
    "Shadow Catcher": (3, "RGB", "COLOR"),
    # Cycles' data passes (core.data_passes); Cryptomatte's layers are CRYPTO_LAYER below.
    "Mist": (1, "Z", "VALUE"),
    "Position": (3, "XYZ", "VECTOR"),
    "UV": (3, "UVA", "VECTOR"),
    "Object Index": (1, "X", "VALUE"),
    "Material Index": (1, "X", "VALUE"),
    "Vector": (4, "XYZW", "VECTOR"),
}
# Blender before 5.0 names the index passes as Cycles did then.
LEGACY_PASS_NAMES = {"Object Index": "IndexOB", "Material Index": "IndexMA"}
if bpy.app.version < (5, 0, 0):
    PASSES.update({old: PASSES.pop(new) for new, old in LEGACY_PASS_NAMES.items()})
CRYPTO_LAYER = (4, "rgba", "COLOR")  # CryptoObject00, CryptoObject01, ... (two (id, coverage) pairs each)
DENOISING_PASSES = ("Noisy Image", "Denoising Normal", "Denoising Albedo")
# Blender's view layer flags of the data passes (View Layer Properties > Passes > Data, Cryptomatte) -> core key.
DATA_PASS_FLAGS = {
    "use_pass_mist": "mist",
    "use_pass_position": "position",
    "use_pass_uv": "uv",
    "use_pass_object_index": "object_index",
    "use_pass_material_index": "material_index",
    "use_pass_cryptomatte_object": "crypto_object",
    "use_pass_cryptomatte_material": "crypto_material",
    "use_pass_cryptomatte_asset": "crypto_asset",
    "use_pass_vector": "vector",
}
# Passes Blender offers that Monte cannot produce: flag -> the warning's reason (never registered: no black pass).
UNAVAILABLE_PASSES: dict[str, str] = {}


def vector_unavailable(view_layer, scene) -> str:
    """Why the Vector pass is not produced for this render ('' when it is): as Cycles, not with motion blur on;
    not for a panoramic camera."""
    if scene is None or not getattr(view_layer, "use_pass_vector", False):
        return ""
    if (scene.render.use_motion_blur and scene.render.motion_blur_shutter > 0
            and getattr(view_layer, "use_motion_blur", True)):
        return "the Vector pass is not available with motion blur on (as in Cycles); it is not produced"
    camera = scene.camera
    if camera is not None and camera.type == "CAMERA" and camera.data.type == "PANO":
        return "Monte does not write motion vectors for a panoramic camera: the Vector pass is not produced"
    return ""


def data_passes(view_layer, scene=None) -> tuple[str, ...]:
    """The core data pass keys (core.data_passes) this view layer asks for (a cluster render carries them as a
    local one does)."""
    if view_layer is None:
        return ()
    skip_vector = bool(vector_unavailable(view_layer, scene))
    return tuple(key for flag, key in DATA_PASS_FLAGS.items() if getattr(view_layer, flag, False)
                 and not (key == "vector" and skip_vector))


def cryptomatte_layers(view_layer) -> int:
    """Cryptomatte layers per kind, as Cycles: Levels (1-16) in pairs, one layer per two levels."""
    return (min(16, max(1, int(getattr(view_layer, "pass_cryptomatte_depth", 6)))) + 1) // 2


def data_pass_names(view_layer, scene=None) -> list[str]:
    """The Blender passes of the requested data passes, Cryptomatte's layers included."""
    from ..core.data_passes import CRYPTO_NAMES, PASS_NAMES

    names = []
    for key in data_passes(view_layer, scene):
        if key in PASS_NAMES:
            name = PASS_NAMES[key]
            names.append(name if name in PASSES else LEGACY_PASS_NAMES[name])
        else:
            names += [f"{CRYPTO_NAMES[key]}{i:02d}" for i in range(cryptomatte_layers(view_layer))]
    return names


def unavailable_pass_warnings(view_layer, scene=None) -> list[str]:
    """Warnings naming the selected passes Monte does not produce."""
    if view_layer is None:
        return []
    out = [f"view layer {view_layer.name!r}: {reason}" for flag, reason in UNAVAILABLE_PASSES.items()
           if getattr(view_layer, flag, False)]
    vector = vector_unavailable(view_layer, scene)
    if vector:
        out.append(f"view layer {view_layer.name!r}: {vector}")
    return out

# Cycles' light passes (core.light_passes): Blender's pass name -> the view layer property that asks for it
# (Cycles' own checkboxes, View Layer Properties > Passes > Light). One table: register, fill and write from it.
LIGHT_PASS_PROPERTIES = {
    "Diffuse Direct": "use_pass_diffuse_direct",
    "Diffuse Indirect": "use_pass_diffuse_indirect",
    "Diffuse Color": "use_pass_diffuse_color",
    "Glossy Direct": "use_pass_glossy_direct",
    "Glossy Indirect": "use_pass_glossy_indirect",
    "Glossy Color": "use_pass_glossy_color",
    "Transmission Direct": "use_pass_transmission_direct",
    "Transmission Indirect": "use_pass_transmission_indirect",
    "Transmission Color": "use_pass_transmission_color",
    "Emission": "use_pass_emit",
    "Environment": "use_pass_environment",
}
PASSES.update({name: (3, "RGB", "COLOR") for name in LIGHT_PASS_PROPERTIES})
# Light passes Cycles has and Monte cannot produce (no ambient occlusion pass, no volumes): when one is ticked the
# render says so by name and the pass is not registered (never a black pass that looks real). (owner, property,
# pass name); owner "cycles" is view_layer.cycles (present while the Cycles add-on is enabled).
UNSUPPORTED_PASSES = (
    ("view_layer", "use_pass_ambient_occlusion", "Ambient Occlusion"),
    ("cycles", "use_pass_volume_direct", "Volume Direct"),
    ("cycles", "use_pass_volume_indirect", "Volume Indirect"),
)


def unsupported_passes(view_layer) -> list[str]:
    """Names of the passes ticked on `view_layer` that Monte does not produce (UNSUPPORTED_PASSES)."""
    if view_layer is None:
        return []
    names = []
    for owner, prop, name in UNSUPPORTED_PASSES:
        holder = view_layer if owner == "view_layer" else getattr(view_layer, owner, None)
        if holder is not None and bool(getattr(holder, prop, False)):
            names.append(name)
    return names


def light_group_passes(view_layer) -> list[str]:
    """The view layer's light group passes (View Layer Properties > Light Groups), Cycles' names "Combined_<group>"
    (core.light_groups), registered as RGB colour passes as Cycles registers them."""
    from ..core.light_groups import pass_name

    if view_layer is None:
        return []
    return [pass_name(str(group.name)) for group in getattr(view_layer, "lightgroups", ()) if group.name]


def shader_aov_passes(view_layer) -> dict[str, tuple[int, str, str]]:
    """The view layer's valid shader AOVs as passes, Cycles' layouts: name -> (4, "RGBA", "COLOR") for a COLOR
    AOV (alpha: the share of samples that wrote it), (1, "X", "VALUE") for a VALUE one (core.shader_aovs)."""
    out = {}
    for aov in getattr(view_layer, "aovs", ()) if view_layer is not None else ():
        if getattr(aov, "is_valid", True):
            out[aov.name] = (1, "X", "VALUE") if aov.type == "VALUE" else (4, "RGBA", "COLOR")
    return out


def requested_passes(view_layer, scene=None) -> list[str]:
    """The passes Monte fills for this view layer (of `scene`, whose denoise setting adds the denoising
    passes)."""
    names = ["Combined"]
    monte_scene = getattr(scene, "monte", None)
    if monte_scene is not None and monte_scene.use_denoising:
        names += DENOISING_PASSES
    if view_layer is None:
        return names
    if view_layer.use_pass_z:
        names.append("Depth")
    if view_layer.use_pass_normal:
        names.append("Normal")
    monte = getattr(view_layer, "monte", None)
    if monte is not None and monte.use_pass_albedo:
        names.append("Albedo")
    if monte is not None and monte.use_pass_variance:
        names.append("Variance")
    if uses_shadow_catcher_pass(view_layer):
        names.append("Shadow Catcher")
    names += [name for name, prop in LIGHT_PASS_PROPERTIES.items() if getattr(view_layer, prop, False)]
    return (names + data_pass_names(view_layer, scene) + list(shader_aov_passes(view_layer))
            + light_group_passes(view_layer))


def requested_light_passes(passes: list[str]) -> tuple[str, ...]:
    """The light passes among `passes` (core.settings.RenderSettings.light_passes)."""
    return tuple(name for name in passes if name in LIGHT_PASS_PROPERTIES)


# Extra progress callbacks (core.render.Progress -> None), e.g. the headless command's progress bar.
progress_listeners: list = []
# A headless cluster export (addon/headless.py export_blend_frames) listens here: while one is set, F12 exports
# the scene through its render depsgraph (render subdivision levels, the render's motion-blur subframes) and hands
# it over, (core scene, export stats), rendering nothing itself.
export_listeners: list = []
# Callbacks for each finished view layer: (view_layer_name, core RenderResult, region, (width, height)),
# region = (x0, y0 from the top, w, h) or None; used by the headless entry point to write Monte's EXR layout.
result_listeners: list = []


def render_with_operator(scene, on_progress=None) -> list:
    """Run Blender's render operator on `scene` (F12, without saving) and return what Monte rendered:
    [(view_layer_name, core RenderResult, region, (width, height)), ...] (empty for other engines).
    Raises RuntimeError with Blender's message (without its "Error: " prefix) when the render fails."""
    captured: list = []

    def capture(layer_name, result, region, size) -> None:
        captured.append((layer_name, result, region, size))

    result_listeners.append(capture)
    if on_progress is not None:
        progress_listeners.append(on_progress)
    try:
        bpy.ops.render.render(write_still=False, scene=scene.name)
    except RuntimeError as exc:
        message = str(exc).strip()
        raise RuntimeError(message[len("Error: "):] if message.startswith("Error: ") else message) from exc
    finally:
        result_listeners.remove(capture)
        if on_progress is not None:
            progress_listeners.remove(on_progress)
    return captured


class MonteRenderEngine(bpy.types.RenderEngine):
    bl_idname = "MONTE"
    bl_label = "Monte"
    bl_use_preview = True  # material/light/world previews: small, progressive (see _render_preview)
    bl_use_postprocess = True  # compositing and sequencer stay available
    bl_use_shading_nodes_custom = False  # Blender's own material/light/world node panels
    bl_use_eevee_viewport = True  # Material Preview shading in the viewport uses EEVEE; Rendered uses Monte

    # ------------------------------------------------------------------------------------------ passes
    def update_render_passes(self, scene=None, renderlayer=None):
        aovs = shader_aov_passes(renderlayer)
        groups = set(light_group_passes(renderlayer))
        for name in requested_passes(renderlayer, scene):
            channels, chanid, kind = PASSES.get(name) or aovs.get(name) or (
                (3, "RGB", "COLOR") if name in groups else CRYPTO_LAYER)
            self.register_pass(scene, renderlayer, name, channels, chanid, kind)

    # ------------------------------------------------------------------------------------------ render
    def _cancel_requested(self) -> bool:
        """Polled between sample batches (and during export). Tests replace this to simulate Esc."""
        return bool(self.test_break())

    def _preview_requested(self) -> bool:
        """Blender renders a material/light/world preview. Tests replace this to render a preview-like scene
        through the preview path (the bpy module cannot start Blender's preview jobs without a window)."""
        return bool(self.is_preview)

    def _progress(self, p) -> None:
        """After every sample batch: status bar stats line (sample, rays/s, time left) and progress."""
        self.update_stats("", f"Monte | {p.stats_line()}")
        self.update_progress(min(max(p.fraction, 0.0), 1.0))
        for listener in list(progress_listeners):
            listener(p)

    def _log(self, message: str) -> None:
        print(f"Monte: {message}", flush=True)
        if message.startswith("compiling"):  # the one long silent step: show it in the status bar too
            self.update_stats("", f"Monte | {message}")

    def render(self, depsgraph):
        try:
            if self._preview_requested():
                self._render_preview(depsgraph)
                return
            from ..core.precompile import loader_paused

            with loader_paused():  # the render loads what it calls; the loader goes on afterwards
                self._render(depsgraph)
        except ExportCancelled:
            self._log("cancelled during export")
            self._write_black(depsgraph)
        except ClusterError as exc:
            # Never a silent local render instead: the user asked for the cluster.
            self._log(f"cluster render failed: {exc}")
            self._write_black(depsgraph)
            self.report({"ERROR"}, f"Monte: cluster render failed: {exc}")
        except Exception as exc:  # noqa: BLE001 - anything escaping would crash Blender at save time
            self._log("render failed:\n" + traceback.format_exc())
            message = str(exc) if isinstance(exc, (SceneError, ValueError, OSError)) else \
                f"{type(exc).__name__}: {exc}"
            self.report({"ERROR"}, f"Monte: {message}")

    def _render(self, depsgraph) -> None:
        from ..core.render import render as core_render

        scene = depsgraph.scene
        view_layer = depsgraph.view_layer
        passes = requested_passes(view_layer, scene)
        self.update_stats("", "Monte | Exporting scene")

        # Motion blur evaluates subframes through the engine's frame_set (its own depsgraph), as Cycles does.
        core_scene, stats = export_scene(depsgraph, self.camera_override,
                                         should_cancel=self._cancel_requested,
                                         vector_pass="vector" in data_passes(view_layer, scene),
                                         frame_set=lambda frame, subframe: self.frame_set(frame, subframe=subframe))
        for w in core_scene.warnings + unavailable_pass_warnings(view_layer, scene):
            self.report({"WARNING"}, f"Monte: {w}")
        self.report({"INFO"}, f"Monte: {stats.line()}")
        if export_listeners:  # a headless cluster export: the scene as F12 exports it, rendered elsewhere
            for listener in list(export_listeners):
                listener(core_scene, stats)
            return
        settings = render_settings(scene, {"aovs": any(p in passes for p in ("Depth", "Normal", "Albedo")),
                                           "data_passes": data_passes(view_layer, scene),
                                           "cryptomatte_levels": 2 * cryptomatte_layers(view_layer),
                                           "light_passes": requested_light_passes(passes),
                                           "error_estimate": "Variance" in passes})
        for name in unsupported_passes(view_layer):
            self.report({"WARNING"}, f"Monte: the {name} pass (view layer {view_layer.name!r}) is not produced "
                        "by Monte; it is left out of the render result")
        if settings.threads == 0:
            # Blender's own thread count: all cores, or Performance > Threads > Fixed, or `blender -t N`.
            settings = settings.replace(threads=max(1, int(scene.render.threads)))

        width, height = render_resolution(scene)
        region = render_region(scene)
        rx, ry, rw, rh = region if region is not None else (0, 0, width, height)
        layer_name = view_layer.name
        t0 = time.perf_counter()

        def on_tile(tile) -> None:
            lx, ly = tile.x0 - rx, tile.y0 - ry
            self._write(lx, rh - (ly + tile.height), tile.width, tile.height, tile, passes, layer_name)

        if scene.monte.use_cluster:
            result = self._render_on_cluster(depsgraph, core_scene, settings, region, on_tile)
            if result is None:  # cancelled: the tiles already back stay written, the rest black
                return
        else:
            result = core_render(core_scene, settings, region=region, on_tile=on_tile, on_progress=self._progress,
                                 should_cancel=self._cancel_requested, log=self._log)
        if scene.monte.use_denoising:
            self._denoise(result, scene.monte.denoising_quality)
        for w in result.warnings:  # what the render found (e.g. data passes behind transparent surfaces)
            if w not in core_scene.warnings:
                self.report({"WARNING"}, f"Monte: {w}")
        # The whole region once more, all passes from the final accumulation: consistent even after a cancel.
        self._write(0, 0, rw, rh, result, passes, layer_name, cryptomatte_metadata_of(result, layer_name))
        for listener in list(result_listeners):
            listener(layer_name, result, region, (width, height))
        seconds = time.perf_counter() - t0
        samples = int(np.asarray(result.sample_count).sum())
        if scene.monte.use_cluster:
            st = result.stats
            summary = (f"{samples:,} samples in {seconds:.2f} s on the cluster ({st['units']} units, "
                       f"{st['workers']} workers, {st['threads']} threads)")
        else:
            summary = (f"{'cancelled, ' if result.cancelled else ''}{samples:,} samples in {seconds:.2f} s, "
                       f"{result.stats.get('rays_per_second', 0.0) / 1e6:.2f} M rays/s")
        self.update_stats("", f"Monte | {summary}")
        self._log(summary)
        if result.cancelled:
            self.report({"WARNING"}, f"Monte: render stopped early ({summary}); the image holds the samples taken")

    def _render_on_cluster(self, depsgraph, core_scene, settings, region, on_tile):
        """The exported frame (its render region only, when one is set) rendered on the Dask cluster of Render
        Properties > Cluster (addon/cluster.py; one connection for all the frames of an animation): tiles
        written as their units come back; the result equals a local render bit for bit. Returns None
        when Esc cancelled it (its units cancelled on the cluster). ClusterError when the scheduler cannot be
        reached, has no worker or runs another Monte: the render fails, nothing is rendered here instead."""
        from ..core.distributed import render_on_cluster
        from .cluster import cluster_address, cluster_client, expose_core_to_workers

        address, timeout = cluster_address(depsgraph.scene)
        expose_core_to_workers()
        cancelled = []

        def should_cancel() -> bool:
            if self._cancel_requested():
                cancelled.append(True)
                return True
            return False

        tiles_done = []

        def on_cluster_tile(tile) -> None:
            tiles_done.append(tile)
            on_tile(tile)

        self.update_stats("", f"Monte | Connecting to the Dask scheduler at {address}")
        self._log(f"connecting to the Dask scheduler at {address}")
        try:
            with cluster_client(address, timeout, self._log) as client:
                return render_on_cluster(core_scene, settings, client, on_progress=self._progress,
                                         should_cancel=should_cancel, log=self._log, on_tile=on_cluster_tile,
                                         region=region)
        except KeyboardInterrupt:
            if not cancelled:
                raise
        self._log(f"cluster render cancelled with {len(tiles_done)} tiles done; its units were cancelled")
        if not tiles_done:
            self._write_black(depsgraph)
        self.update_stats("", f"Monte | cancelled: {len(tiles_done)} tiles came back from the cluster")
        self.report({"WARNING"}, f"Monte: cluster render cancelled; the image holds the {len(tiles_done)} tiles "
                    "that were done, the rest is black")
        return None

    def _render_preview(self, depsgraph) -> None:
        """A material/light/world preview: Blender's preview scene at its small size, in passes of growing
        sample counts (1, 2, 4, ...) up to the scene's Preview Samples, each written as it finishes; moving on
        (test_break) stops it between batches."""
        from ..core.render import prepare_scene
        from .viewport import progressive_passes

        scene = depsgraph.scene
        core_scene, _ = export_scene(depsgraph, self.camera_override, should_cancel=self._cancel_requested,
                                     motion_blur=False)  # previews are still, as Cycles'
        samples = int(getattr(scene.monte, "preview_samples", 16))
        settings = render_settings(scene, {"aovs": False, "time_limit": 0.0, "adaptive_threshold": 0.0})
        if settings.threads == 0:
            settings = settings.replace(threads=max(1, int(scene.render.threads)))
        width, height = render_resolution(scene)
        layer_name = depsgraph.view_layer.name
        prepared = prepare_scene(core_scene, settings)
        written = []

        def on_image(rgba, taken) -> None:
            result = self.begin_result(0, 0, width, height, layer=layer_name)
            try:
                result.layers[0].passes["Combined"].rect.foreach_set(np.ascontiguousarray(rgba[::-1]).ravel())
            finally:
                self.end_result(result)
            written.append(taken)
            self.update_progress(taken / samples)

        progressive_passes(core_scene, settings, samples, prepared, on_image, self._cancel_requested)
        if not written:
            self._write_black(depsgraph)

    # ------------------------------------------------------------------------------------------ viewport
    def view_update(self, context, depsgraph):
        """Blender's main thread, after depsgraph changes in a Rendered viewport: export what changed (the
        worker thread renders)."""
        try:
            session = self._viewport_session(depsgraph.scene)
            session.sync(depsgraph)
            self._viewport_error = None
        except Exception as exc:  # noqa: BLE001 - a viewport error is shown, never raised into Blender
            self._log("viewport update failed:\n" + traceback.format_exc())
            self._viewport_error = f"{type(exc).__name__}: {exc}"
        self.tag_redraw()

    def view_draw(self, context, depsgraph):
        """Draw the newest image of the view, with the view's colour management; tells the view the sample count
        or the error."""
        from .viewport import camera_from_view

        region, rv3d = context.region, context.region_data
        session = getattr(self, "_viewport", None)
        if session is None:
            return
        view_error = None
        try:
            lens = None
            scene = depsgraph.scene
            if rv3d.view_perspective == "CAMERA" and scene.camera is not None and scene.camera.type == "CAMERA":
                lens = export_camera(scene.camera.evaluated_get(depsgraph), scene, [])  # depth of field
            session.set_view(camera_from_view(rv3d.view_matrix, rv3d.window_matrix, (region.width, region.height),
                                              lens))
        except Exception as exc:  # noqa: BLE001 - e.g. a zero-size region: shown, the next draw retries
            view_error = str(exc)
        error = view_error or session.error or getattr(self, "_viewport_error", None)
        if error:
            self.update_stats("", f"Monte: {error}")
            return
        image = session.image()
        if image is None:
            self.update_stats("", "Monte | Preparing")
            return
        self._draw_viewport_image(depsgraph.scene, image, region.width, region.height)
        status = "Done" if session.done and image.samples >= session.samples else "Rendering"
        self.update_stats("", f"Monte | Sample {image.samples}/{session.samples} | {status}")

    def _draw_viewport_image(self, scene, image, width: int, height: int) -> None:
        import gpu

        from .viewport import draw_texture, image_texture

        cached = getattr(self, "_viewport_texture", None)
        if cached is None or cached[0] != image.version:
            cached = self._viewport_texture = (image.version, image_texture(image.rgba))
        gpu.state.blend_set("ALPHA_PREMULT")
        self.bind_display_space_shader(scene)
        try:
            draw_texture(cached[1], width, height)
        finally:
            self.unbind_display_space_shader()
            gpu.state.blend_set("NONE")

    def _viewport_session(self, scene):
        from ..core.settings import VIEWPORT_SAMPLES, VIEWPORT_START_RESOLUTION
        from .viewport import ViewportSession, pixel_size

        monte = scene.monte
        settings = render_settings(scene)
        if settings.threads == 0:
            settings = settings.replace(threads=max(1, int(scene.render.threads)))
        key = (settings, int(getattr(monte, "viewport_samples", VIEWPORT_SAMPLES)), pixel_size(scene),
               int(getattr(monte, "viewport_start_resolution", VIEWPORT_START_RESOLUTION)))
        session = getattr(self, "_viewport", None)
        if session is not None and getattr(self, "_viewport_key", None) != key:
            # A render setting changed: start a new session (a full export), as Cycles resets.
            session.stop()
            session = None
        if session is None:
            self._viewport_key = key
            self._viewport_error = None
            session = self._viewport = ViewportSession(key[0], key[1], key[2], key[3], on_image=self.tag_redraw)
        return session

    def __del__(self):
        try:
            session = getattr(self, "_viewport", None)
        except ReferenceError:  # Blender freed the engine before Python collected it: it had no viewport
            return
        if session is not None:
            session.stop()

    def _denoise(self, result, quality: str) -> None:
        """Denoise result.color with Open Image Denoise, keeping the image before it as result.noisy (the Noisy
        Image pass); without the denoiser a warning says why and the render stays as it is (noisy, result.noisy
        None; the Noisy Image pass then holds the same image as Combined)."""
        from ..core.denoise import DenoiserUnavailable, denoise

        self.update_stats("", "Monte | Denoising")
        try:
            t0 = time.perf_counter()
            denoised = denoise(result.color, result.denoising_albedo, result.denoising_normal, quality=quality)
        except DenoiserUnavailable as exc:
            self.report({"WARNING"}, f"Monte: the render was not denoised: {exc}")
            return
        result.noisy, result.color = result.color, denoised
        result.stats["denoise_seconds"] = time.perf_counter() - t0
        self._log(f"denoised ({quality}) in {result.stats['denoise_seconds']:.2f} s")

    # ------------------------------------------------------------------------------------------ results
    def _write(self, x: int, y: int, w: int, h: int, src, passes: list[str], layer_name: str,
               metadata: dict | None = None) -> None:
        """Copy a tile/result (row 0 at the top) into Blender's render result at region-local (x, y) with
        y from the bottom; every declared pass in one result so none is reset. metadata: fields added to the
        render result's metadata (Cryptomatte's manifests, as Cycles adds them)."""
        if metadata:
            full = self.get_result()  # the render's own result holds the metadata (Cycles writes it there too)
            for key, value in metadata.items():
                full.stamp_data_add_field(key, value)
        result = self.begin_result(x, y, w, h, layer=layer_name)
        try:
            layer = result.layers[0]
            for rpass in layer.passes:
                data = _pass_pixels(rpass.name, src, h, w, rpass.channels)
                rpass.rect.foreach_set(data)
        finally:
            self.end_result(result)

    def _write_black(self, depsgraph) -> None:
        scene = depsgraph.scene
        width, height = render_resolution(scene)
        region = render_region(scene)
        rw, rh = (region[2], region[3]) if region is not None else (width, height)
        result = self.begin_result(0, 0, rw, rh, layer=depsgraph.view_layer.name)
        self.end_result(result)


def cryptomatte_metadata_of(result, layer_name: str) -> dict[str, str]:
    """The render result metadata of a result's Cryptomatte layers, as Cycles writes it (layer
    "<view layer>.CryptoObject", ...)."""
    from ..core.data_passes import cryptomatte_metadata

    out: dict[str, str] = {}
    for base, names in getattr(result, "cryptomatte", {}).items():
        out.update(cryptomatte_metadata(f"{layer_name}.{base}", names))
    return out


def _pass_pixels(name: str, src, h: int, w: int, channels: int) -> np.ndarray:
    """Flattened float32 pixels of one pass, flipped to Blender's bottom-up rows."""
    arr = None
    if name == "Combined":
        arr = src.color
    elif name == "Depth":
        arr = src.depth
    elif name == "Normal":
        arr = src.normal
    elif name == "Albedo":
        arr = src.albedo
    elif name == "Variance":
        arr = src.variance
    elif name == "Noisy Image":
        # A tile in progress is not denoised yet: its colour is the noisy image.
        noisy = getattr(src, "noisy", None)
        arr = noisy if noisy is not None else src.color
    elif name == "Denoising Normal":
        arr = src.denoising_normal
    elif name == "Denoising Albedo":
        arr = src.denoising_albedo
    elif name == "Shadow Catcher":
        arr = getattr(src, "shadow_catcher", None)
    elif name in LIGHT_PASS_PROPERTIES:
        arr = (getattr(src, "light_passes", None) or {}).get(name)
    elif name in (getattr(src, "shader_aovs", None) or {}):
        arr = src.shader_aovs[name]
    elif name in (getattr(src, "light_groups", None) or {}):
        arr = src.light_groups[name]
    else:
        data = getattr(src, "data_passes", {})
        arr = data.get(name)
        if arr is None:  # a legacy index pass name (Blender < 5.0)
            arr = data.get(next((new for new, old in LEGACY_PASS_NAMES.items() if old == name), ""))
    if arr is None:
        fill = 1e10 if name == "Depth" else 1.0 if name == "Shadow Catcher" else 0.0
        return np.full(h * w * channels, fill, dtype=np.float32)
    arr = np.asarray(arr, dtype=np.float32).reshape(h, w, -1)
    if arr.shape[2] != channels:
        out = np.zeros((h, w, channels), np.float32)
        c = min(channels, arr.shape[2])
        out[..., :c] = arr[..., :c]
        arr = out
    return np.ascontiguousarray(arr[::-1]).ravel()
