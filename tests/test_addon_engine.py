"""The MONTE render engine inside Blender (bpy module): F12-style renders, passes, border, cancel, errors,
the headless entry point, and the panels."""

from __future__ import annotations

import math
import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import engine as engine_mod  # noqa: E402
from monte.addon.headless import HeadlessError, render_blend_file  # noqa: E402

pytestmark = pytest.mark.blender
Engine = engine_mod.MonteRenderEngine


def render_still(scene, tmp_path, name="out"):
    """bpy.ops.render.render(write_still=True) into a multilayer EXR; returns its channels."""
    path = tmp_path / f"{name}.exr"  # a still has no frame number
    bf.render_still_exr(scene, path)
    assert path.is_file()
    return bf.read_exr_layers(path)


def rgb(ch, layer="ViewLayer", name="Combined"):
    return np.stack([ch[f"{layer}.{name}.{c}"] for c in "RGB"], axis=-1)


# ---------------------------------------------------------------------------------------------- rendering
def test_plane_under_world_radiance_and_passes(tmp_path):
    scene = bf.plane_under_world(albedo=0.5, world=1.0, resolution=(16, 12))
    vl = scene.view_layers[0]
    vl.use_pass_z = vl.use_pass_normal = True
    vl.monte.use_pass_albedo = vl.monte.use_pass_variance = True
    ch = render_still(scene, tmp_path)
    combined = rgb(ch)
    assert combined.shape == (12, 16, 3)
    assert np.all(np.isfinite(combined)) and np.allclose(ch["ViewLayer.Combined.A"], 1.0)
    var = rgb(ch, name="Variance")
    # radiance = albedo x world. The uniform world is found by cosine-weighted BSDF sampling alone (as Cycles
    # does; it is not light-sampled), so over an unbounded diffuse plane every sample is exactly albedo x world:
    # a zero-variance estimator, which the Variance pass must report (float rounding aside).
    assert np.all(var >= 0) and var.max() < 1e-10
    assert np.allclose(combined, 0.5, atol=1e-5)
    assert np.allclose(ch["ViewLayer.Depth.Z"], 1.0, atol=1e-4)  # camera 1 m above, looking straight down
    normal = np.stack([ch[f"ViewLayer.Normal.{c}"] for c in "XYZ"], axis=-1)
    assert np.allclose(normal, (0, 0, 1), atol=1e-4)
    assert np.allclose(rgb(ch, name="Albedo"), 0.5, atol=1e-4)


def test_only_requested_passes_are_declared(tmp_path):
    scene = bf.plane_under_world(resolution=(8, 8))
    scene.monte.samples = 2
    ch = render_still(scene, tmp_path)
    assert {k.split(".")[1] for k in ch} == {"Combined"}


def test_the_error_estimate_is_kept_only_for_the_variance_pass_or_adaptive_sampling():
    # The Variance pass and adaptive sampling read each pixel's error estimate (2 variance groups); any other
    # render takes one Sobol sequence per pixel (core.settings.RenderSettings.error_estimate).
    from monte.addon.properties import render_settings
    from monte.core.render import render as core_render

    scene = bf.cornell_box((16, 12))
    scene.monte.samples = 8
    vl = scene.view_layers[0]
    vl.monte.use_pass_variance = False
    scene.monte.use_adaptive_sampling = False
    plain = engine_mod.render_with_operator(scene)[0][1]
    assert plain.variance is None
    assert render_settings(scene).error_estimate is False
    vl.monte.use_pass_variance = True
    with_pass = engine_mod.render_with_operator(scene)[0][1]
    assert with_pass.variance is not None and with_pass.variance.shape == (12, 16, 3)
    assert np.all(with_pass.variance >= 0) and with_pass.variance.max() > 0
    assert not np.array_equal(plain.color, with_pass.color)  # other sample sequences
    # the same images as core renders of the exported scene with each setting
    core_scene, _ = engine_mod.export_scene(bpy.context.evaluated_depsgraph_get())
    base = render_settings(scene, {"aovs": False, "threads": 1})
    for setting, result in ((False, plain), (True, with_pass)):
        again = core_render(core_scene, base.replace(error_estimate=setting, threads=int(scene.render.threads)))
        assert np.array_equal(again.color, result.color), setting
    # adaptive sampling turns the estimate on, with or without the pass
    vl.monte.use_pass_variance = False
    scene.monte.use_adaptive_sampling = True
    assert render_settings(scene).error_estimate is True
    adaptive = engine_mod.render_with_operator(scene)[0][1]
    assert adaptive.variance is not None


def test_resolution_percentage_and_border(tmp_path):
    scene = bf.plane_under_world(resolution=(40, 30))
    scene.monte.samples = 4
    scene.render.resolution_percentage = 50  # 20 x 15
    r = scene.render
    r.use_border = True
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.25, 0.75, 0.1, 0.5
    r.use_crop_to_border = False
    full = rgb(render_still(scene, tmp_path, "uncropped"))
    assert full.shape == (15, 20, 3)
    # Blender's border in pixels: x 5..15, y 1..7 from the bottom -> rows 8..13 from the top
    inside = np.zeros(full.shape[:2], bool)
    inside[8:14, 5:15] = True
    assert np.all(full[~inside] == 0)
    assert np.all(full[inside] > 0.2)
    r.use_crop_to_border = True
    crop = rgb(render_still(scene, tmp_path, "cropped"))
    assert crop.shape == (6, 10, 3)
    assert np.allclose(crop, full[8:14, 5:15], atol=1e-6)  # same pixels, same samples: same values


def test_exported_cornell_box_renders_like_core(fast_settings):
    from monte.addon.export import export_scene
    from monte.core.render import render
    from monte.core.builtin_scenes import cornell_box

    bf.cornell_box((24, 24))
    exported, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    settings = fast_settings(spp=16)
    a = render(exported, settings)
    b = render(cornell_box((24, 24)), settings)
    # Same seed and sampling: the sigma of the difference of the two means comes from the per-pixel differences
    # (common random numbers), far below either render's own; a 1 % error must fail (the control).
    from monte.core import metrics
    from monte.lab.stress import paired_sigma

    diff = metrics.channel_means(a.color) - metrics.channel_means(b.color)
    sigma = paired_sigma(a, b)
    assert np.all(np.abs(diff) < 5 * sigma + 1e-6), (diff, sigma)
    for wrong in (1.01, 0.99):
        a.color[..., :3] *= wrong
        assert np.any(np.abs(metrics.channel_means(a.color) - metrics.channel_means(b.color))
                      >= 5 * paired_sigma(a, b) + 1e-6), wrong
        a.color[..., :3] /= wrong


# ---------------------------------------------------------------------------------------------- cancel, errors
def test_cancel_stops_within_a_batch_and_keeps_a_valid_partial_image(tmp_path, patch_engine):
    scene = bf.plane_under_world(resolution=(32, 32))
    scene.monte.samples = 64
    scene.monte.batch_paths = 4096  # 16 batches for this image
    scene.monte.tile_size = 32
    events = []

    def cancel(self):
        polls = sum(1 for e in events if e == "poll")
        events.append("poll")
        return polls >= 6  # Esc after a few batches

    original_progress = Engine._progress

    def progress(self, p):
        events.append(("progress", p.fraction))
        original_progress(self, p)

    patch_engine("_cancel_requested", cancel)
    patch_engine("_progress", progress)
    ch = render_still(scene, tmp_path)
    first_true = [i for i, e in enumerate(events) if e == "poll"][6]
    assert not any(isinstance(e, tuple) for e in events[first_true + 1:]), "a batch ran after the cancel"
    fractions = [e[1] for e in events if isinstance(e, tuple)]
    assert 0 < max(fractions) < 0.6
    img = rgb(ch)
    assert np.all(np.isfinite(img)) and np.all(img >= 0)
    # Every pixel has samples (progressive passes over the tiles): the partial image is a noisier version of
    # the full render, not a half-black one.
    patch_engine("_cancel_requested", lambda self: False)
    full = rgb(render_still(scene, tmp_path, "full"))
    assert img[..., 0].min() > 0
    assert abs(img[..., 0].mean() - full[..., 0].mean()) < 0.05 * full[..., 0].mean()


def test_a_kernel_compile_during_a_render_reaches_the_status_bar(tmp_path, patch_engine):
    """A render whose scene needs a kernel the cache lacks says so when the compile starts (numba's
    "numba:compile" event, fired by a worker thread, as a render's worker compiles): the engine's log prints it and
    shows it in the status bar (update_stats), from that thread, without an error, and the render completes."""
    import threading

    from numba.core import event as numba_events

    from monte.core import embree

    scene = bf.plane_under_world(resolution=(16, 16))
    scene.monte.samples = 4
    logged, failed, fired = [], [], []
    original_progress, original_log = Engine._progress, Engine._log

    def compile_on_a_worker() -> None:
        with numba_events.trigger_event("numba:compile", data={"dispatcher": embree.trace_closest, "args": (),
                                                               "return_type": None}):
            pass

    def progress(self, p):
        if not fired:
            worker = threading.Thread(target=compile_on_a_worker)
            worker.start()
            worker.join()
            fired.append(True)
        original_progress(self, p)

    def log(self, message):
        try:
            original_log(self, message)  # prints, and for a compile notice calls update_stats
        except BaseException as exc:  # (the notice's caller swallows errors: record them here)
            failed.append(repr(exc))
            raise
        logged.append((message, threading.current_thread() is threading.main_thread()))

    patch_engine("_progress", progress)
    patch_engine("_log", log)
    ch = render_still(scene, tmp_path)
    notices = [entry for entry in logged if "kernel cache does not hold" in entry[0]]
    assert notices == [("compiling the render kernels this scene needs that the kernel cache does not hold yet "
                        "(embree.trace_closest first; once, cached after)", False)], logged
    assert failed == []
    assert np.allclose(rgb(ch), 0.5, atol=1e-5)


def test_cancel_during_export_leaves_a_black_image_and_no_crash(tmp_path, patch_engine):
    scene = bf.plane_under_world(resolution=(8, 8))
    for i in range(1100):  # enough instances that the export polls for cancel
        bf.mesh_object(f"tri{i}", [(0, 0, i), (1, 0, i), (0, 1, i)], [(0, 1, 2)])
    patch_engine("_cancel_requested", lambda self: True)
    img = rgb(render_still(scene, tmp_path))
    assert img.shape == (8, 8, 3) and np.all(img == 0)


def test_errors_are_reported_and_nothing_is_saved(tmp_path, patch_engine, monkeypatch):
    scene = bf.plane_under_world(resolution=(8, 8))
    bpy.data.objects.remove(bpy.data.objects["plane"])
    scene.render.filepath = str(tmp_path / "err_")
    scene.render.image_settings.file_format = "OPEN_EXR"
    with pytest.raises(RuntimeError, match="no visible objects"):
        bpy.ops.render.render(write_still=True)
    assert not list(tmp_path.iterdir())

    bf.plane_under_world(resolution=(8, 8))
    import monte.core.render as core_render

    def boom(*args, **kwargs):
        raise ZeroDivisionError("simulated failure deep in the core")

    monkeypatch.setattr(core_render, "render", boom)
    bpy.context.scene.render.filepath = str(tmp_path / "err_")
    with pytest.raises(RuntimeError, match="ZeroDivisionError: simulated failure"):
        bpy.ops.render.render(write_still=True)
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------------------------------- headless
def test_headless_render_blend_file(tmp_path):
    scene = bf.plane_under_world(albedo=0.5, world=2.0, resolution=(12, 10))
    scene.monte.samples = 16
    blend = tmp_path / "plane.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "plane.exr"
    progress = []
    render_blend_file(blend, out, {"spp": 8, "seed": 7, "filter": "tent", "max_bounces": 2, "threads": None},
                      log=lambda _m: None, on_progress=progress.append)
    assert progress and progress[-1].fraction == pytest.approx(1.0) and progress[-1].spp == 8
    from monte.core.exr import read_exr, read_rgb

    img = read_rgb(out)
    assert img.shape == (10, 12, 3)
    # albedo 0.5 x world 2: a zero-variance estimator (see test_plane_under_world_radiance_and_passes), so every
    # pixel is 1 to float rounding, whatever the filter
    assert np.allclose(img, 1.0, atol=1e-5)
    # Monte's channel layout, as `monte render` writes for built-in scenes
    channels = read_exr(out)
    assert {"R", "G", "B", "A", "albedo.G", "normal.Z", "Z"} <= set(channels)
    assert np.allclose(channels["Z"], 1.0, atol=1e-4) and np.allclose(channels["albedo.R"], 0.5, atol=1e-4)
    assert "variance.R" not in channels  # only when asked: the override (`monte render --variance`)
    render_blend_file(blend, out, {"spp": 8, "seed": 7, "variance": True}, log=lambda _m: None)
    channels = read_exr(out)
    assert {"variance.R", "variance.G", "variance.B"} <= set(channels)
    assert np.all(np.stack([channels[f"variance.{c}"] for c in "RGB"]) < 1e-10)  # the zero-variance estimator
    # The overrides were for that run only: the file on disk is untouched.
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    assert bpy.context.scene.monte.samples == 16 and bpy.context.scene.monte.filter_type == "box"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plane.blend", "plane.exr"]
    # Blender's multilayer file instead, with a cropped border
    bpy.context.scene.render.use_border = bpy.context.scene.render.use_crop_to_border = True
    bpy.context.scene.render.border_max_x = 0.5
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    render_blend_file(blend, out, {"spp": 2, "multilayer": True, "variance": True}, log=lambda _m: None)
    layers = bf.read_exr_layers(out)
    assert {"ViewLayer.Combined.R", "ViewLayer.Depth.Z", "ViewLayer.Albedo.R", "ViewLayer.Variance.R"} <= set(layers)
    assert layers["ViewLayer.Combined.R"].shape == (10, 6)


def test_headless_file_passes_writes_only_what_the_view_layer_ticks_and_the_same_image(tmp_path):
    """file_passes (`monte render X.blend --file-passes`): Z, normal and albedo are neither forced on nor computed
    unless the view layer ticks them; the image is the same bits as the default render's, which carries them all."""
    scene = bf.plane_under_world(albedo=0.5, world=2.0, resolution=(12, 10))
    for layer in scene.view_layers:
        layer.use_pass_z = layer.use_pass_normal = False
        layer.monte.use_pass_albedo = False
    blend = tmp_path / "plane.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    from monte.core.exr import read_exr

    settings = {"spp": 4, "seed": 3, "max_bounces": 3}
    every, only = tmp_path / "every.exr", tmp_path / "only.exr"
    render_blend_file(blend, every, settings, log=lambda _m: None)
    render_blend_file(blend, only, {**settings, "file_passes": True}, log=lambda _m: None)
    every_channels, only_channels = read_exr(every), read_exr(only)
    assert {"Z", "albedo.R", "normal.Z"} <= set(every_channels)
    assert sorted(only_channels) == ["A", "B", "G", "R"]
    for c in "RGBA":
        assert np.array_equal(only_channels[c], every_channels[c])
    # a ticked pass is still written (the core computes Z, normal and albedo together: all three come with it)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    bpy.context.scene.view_layers[0].use_pass_z = True
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    render_blend_file(blend, only, {**settings, "file_passes": True}, log=lambda _m: None)
    only_channels = read_exr(only)
    assert "Z" in only_channels and np.array_equal(only_channels["Z"], every_channels["Z"])
    with pytest.raises(ValueError, match="file_passes must be True or False"):
        render_blend_file(blend, only, {"file_passes": "yes"}, log=lambda _m: None)


def test_headless_errors_name_the_file_and_never_clobber_output(tmp_path):
    out = tmp_path / "keep.exr"
    out.write_bytes(b"previous image")
    with pytest.raises(FileNotFoundError, match="missing.blend"):
        render_blend_file(tmp_path / "missing.blend", out, {})
    junk = tmp_path / "junk.blend"
    junk.write_bytes(b"this is not a blend file")
    with pytest.raises(HeadlessError, match="junk.blend"):
        render_blend_file(junk, out, {})
    corrupt = tmp_path / "corrupt.blend"
    corrupt.write_bytes(b"BLENDER-v500" + os.urandom(64))
    with pytest.raises(HeadlessError, match="corrupt.blend"):
        render_blend_file(corrupt, out, {})
    scene = bf.plane_under_world(resolution=(8, 8))
    bpy.data.objects.remove(bpy.data.objects["plane"])
    empty = tmp_path / "empty.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(empty))
    with pytest.raises(HeadlessError, match="empty.blend.*no visible objects"):
        render_blend_file(empty, out, {}, log=lambda _m: None)
    with pytest.raises(ValueError, match="unknown render override"):
        render_blend_file(empty, out, {"sppp": 3})
    bf.plane_under_world(resolution=(8, 8))
    bpy.data.objects.remove(bpy.data.objects["Camera"])
    nocam = tmp_path / "nocam.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(nocam))
    with pytest.raises(HeadlessError, match="nocam.blend.*has no camera"):
        render_blend_file(nocam, out, {}, log=lambda _m: None)
    assert out.read_bytes() == b"previous image"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["corrupt.blend", "empty.blend", "junk.blend", "keep.exr",
                                                          "nocam.blend"]
    del scene


# ---------------------------------------------------------------------------------------------- UI
class _Recorder:
    """Stands in for a UILayout: checks that every prop() names a real RNA property."""

    def __init__(self, log):
        self._log = log

    def __getattr__(self, name):
        if name in ("column", "row", "split", "box"):
            return lambda *a, **k: _Recorder(self._log)
        if name in ("prop", "prop_search"):
            return self._prop
        return lambda *a, **k: None

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)

    def _prop(self, data, name, *_search, **_kw):  # prop_search also names the collection to search
        assert name in data.bl_rna.properties.keys(), f"{type(data).__name__} has no property {name!r}"
        self._log.append(name)


def test_panels_draw_real_properties_and_blender_panels_are_opted_in():
    from monte.addon import ui

    scene = bf.reset()
    mat = bf.diffuse("m", (0.5, 0.5, 0.5))
    light = bpy.data.lights.new("L", "AREA")
    world = bf.set_world(scene, (0.1, 0.1, 0.1))
    cam = bpy.data.cameras.new("C")
    cam.type = "PANO"
    ob = bpy.data.objects.new("O", None)
    scene.view_layers[0].use_pass_mist = True  # World > Mist Pass shows with the Mist pass on, as in Cycles
    ctx = types.SimpleNamespace(scene=scene, view_layer=scene.view_layers[0], material=mat, world=world,
                                light=light, camera=cam, object=ob, engine="MONTE")
    drawn = []
    for cls in ui.classes:
        assert cls.poll(ctx)
        panel = types.SimpleNamespace(layout=_Recorder(drawn), bl_space_type="PROPERTIES",
                                      SCENE_PROPS=cls.SCENE_PROPS)
        cls.draw(panel, ctx)
    assert {"samples", "seed", "sampler", "clamp", "time_limit", "max_bounces", "rr_depth", "filter_type",
            "filter_width", "threads", "batch_paths", "use_pass_z", "use_pass_albedo", "energy", "film_transparent",
            "film_transparent_glass", "panorama_type", "visible_diffuse", "is_holdout", "use_pass_mist",
            "use_pass_object_index", "use_pass_cryptomatte_asset", "pass_cryptomatte_depth", "falloff",
            "transparent_max_bounces", "motion_blur_shutter",
            "motion_blur_position", "motion_steps", "is_portal", "lightgroup"} <= set(drawn)
    for kind in ("FISHEYE_EQUISOLID", "FISHEYE_LENS_POLYNOMIAL", "CENTRAL_CYLINDRICAL", "EQUIRECTANGULAR"):
        cam.panorama_type = kind
        ui.MONTE_CAMERA_PT_panorama.draw(types.SimpleNamespace(layout=_Recorder(drawn)), ctx)
    assert {"fisheye_lens", "fisheye_polynomial_k4", "central_cylindrical_radius", "latitude_min"} <= set(drawn)
    for name in ("RENDER_PT_format", "RENDER_PT_output", "DATA_PT_lens", "DATA_PT_camera",
                 "EEVEE_MATERIAL_PT_context_material", "DATA_PT_spot", "RENDER_PT_color_management"):
        assert "MONTE" in getattr(bpy.types, name).COMPAT_ENGINES, name
    assert "MONTE" not in bpy.types.DATA_PT_camera_dof.COMPAT_ENGINES
    engines = {getattr(c, "bl_idname", None) for c in bpy.types.RenderEngine.__subclasses__()}
    assert "MONTE" in engines


def test_each_view_layer_renders_with_its_own_passes(tmp_path):
    scene = bf.plane_under_world(resolution=(8, 8))
    scene.monte.samples = 4
    second = scene.view_layers.new("Second")
    second.use_pass_z = True
    ch = render_still(scene, tmp_path)
    layers = {k.rsplit(".", 2)[0] + "." + k.rsplit(".", 2)[1] for k in ch}
    assert layers == {"ViewLayer.Combined", "Second.Combined", "Second.Depth"}
    assert np.allclose(rgb(ch), rgb(ch, layer="Second"))  # same scene, same seed: same pixels


def test_image_texture_orientation_end_to_end(tmp_path):
    """An image whose top half is red and bottom half green, UV-mapped onto a plane seen from above with the
    image's up along +y, renders red at the top of the frame: rows and UVs are flipped exactly once."""
    scene = bf.reset()
    img = bpy.data.images.new("TopRed", 8, 8, float_buffer=True)
    px = np.zeros((8, 8, 4), np.float32)
    px[:4] = (0.0, 1.0, 0.0, 1.0)  # Blender's rows 0-3 are the bottom half
    px[4:] = (1.0, 0.0, 0.0, 1.0)
    img.pixels.foreach_set(px.ravel())
    mat = bf.node_material("tex", "ShaderNodeBsdfDiffuse")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    tex.interpolation = "Closest"
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Diffuse BSDF"].inputs["Color"])
    ob = bf.mesh_object("plane", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)], mat)
    uv = ob.data.uv_layers.new(name="UVMap")
    uv.uv.foreach_set("vector", np.array([0, 0, 1, 0, 1, 1, 0, 1], np.float32))
    bf.camera_object(scene, (0, 0, 2), (0, 0, 0), kind="ORTHO", ortho_scale=2.0)
    bf.set_world(scene, (1.0, 1.0, 1.0))
    scene.render.resolution_x = scene.render.resolution_y = 8
    scene.monte.samples, scene.monte.filter_type, scene.monte.filter_width = 8, "box", 1.0
    out = rgb(render_still(scene, tmp_path))
    top, bottom = out[:3].mean(axis=(0, 1)), out[-3:].mean(axis=(0, 1))
    assert top[0] > 5 * top[1] and bottom[1] > 5 * bottom[0], (top, bottom)


def test_adaptive_sampling_settings_reach_the_renderer(tmp_path):
    """Blender's Noise Threshold checkbox and value map to RenderSettings; off means threshold 0."""
    from monte.addon.properties import render_settings

    scene = bf.plane_under_world(albedo=0.5, world=1.0, resolution=(16, 12))
    assert render_settings(scene).adaptive_threshold == 0.0
    scene.monte.use_adaptive_sampling = True
    scene.monte.adaptive_threshold = 0.05
    scene.monte.adaptive_min_samples = 8
    settings = render_settings(scene)
    assert settings.adaptive_threshold == pytest.approx(0.05) and settings.adaptive_min_samples == 8
    scene.monte.samples = 64
    ch = render_still(scene, tmp_path)  # renders (the sky-lit plane converges early) and stays right
    assert np.allclose(rgb(ch), 0.5, atol=1e-5)  # a zero-variance estimator: exact to float rounding
    blend = tmp_path / "adaptive.blend"
    scene.monte.use_adaptive_sampling = False
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "adaptive.exr"
    render_blend_file(blend, out, {"spp": 32, "adaptive_threshold": 0.05, "adaptive_min_samples": 8},
                      log=lambda _m: None)
    assert out.exists()
    with pytest.raises(ValueError, match="adaptive threshold"):
        render_blend_file(blend, out, {"adaptive_threshold": -1.0}, log=lambda _m: None)
