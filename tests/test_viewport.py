"""The interactive viewport and material previews with the real bpy module: what each kind of depsgraph change
re-exports, the progressive restart (reduced resolution first, then sample by sample, converging), the camera
made from a 3D view's matrices, cancellation, errors, drawing through Blender's gpu module, and the preview path."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402
from monte.lab import bpy_scenes  # noqa: E402

from monte.addon import engine as engine_mod  # noqa: E402
from monte.addon import viewport as vp  # noqa: E402
from monte.addon.export.camera import export_camera  # noqa: E402
from monte.core.render import render as core_render  # noqa: E402
from monte.core.settings import RenderSettings  # noqa: E402

pytestmark = pytest.mark.blender

# Few bounces and a box filter keep the renders small; the scene is lit directly.
SETTINGS = RenderSettings(threads=2, seed=3, max_bounces=2, filter_type="box", filter_width=1.0)


def block_scene():
    """A grey floor, a red box ("block", material "paint") on it, a point lamp and a dim world; camera above."""
    scene = bf.reset()
    s = 4.0
    bf.mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                   bf.diffuse("grey", (0.5, 0.5, 0.5)))
    bpy_scenes.box_object("block", (-0.5, -0.5, 0.0), (0.5, 0.5, 1.0), bf.diffuse("paint", (0.8, 0.1, 0.1)))
    bpy_scenes.light_object(scene, "POINT", (1.0, -1.0, 3.0), energy=300.0, shadow_soft_size=0.0)
    bf.set_world(scene, (0.2, 0.2, 0.2), 1.0)
    bf.camera_object(scene, (0.0, -5.0, 4.0), (math.radians(50), 0.0, 0.0), lens=35.0)
    scene.render.resolution_x, scene.render.resolution_y = 40, 30
    scene.render.resolution_percentage = 100
    return scene


@pytest.fixture
def changes():
    """Applies a change in Blender and returns (depsgraph, the changes its depsgraph.updates reported), read
    inside a depsgraph handler as Blender's view_update sees them."""
    captured: list = []

    @bpy.app.handlers.persistent  # the tests reset Blender to factory settings after this fixture
    def handler(_scene, depsgraph):
        captured.append(vp.depsgraph_changes(depsgraph))

    bpy.app.handlers.depsgraph_update_post.append(handler)

    def apply(change):
        captured.clear()
        change()
        depsgraph = bpy.context.evaluated_depsgraph_get()
        depsgraph.update()
        return depsgraph, vp.merged_changes(captured)

    yield apply
    bpy.app.handlers.depsgraph_update_post.remove(handler)


def mesh_named(scene, name):
    return next(m for m in scene.meshes if m.name == name)


# ------------------------------------------------------------------------------------------- the view
@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_camera_from_view_matches_the_exported_camera(kind):
    """A 3D view looking through a camera: its view and projection matrices give core's camera the same frame,
    position, direction and clipping as the camera's own export (shift included)."""
    scene = block_scene()
    cam = scene.camera
    cam.data.type = kind
    cam.data.shift_x, cam.data.shift_y = 0.1, -0.05
    cam.data.ortho_scale = 6.0
    cam.data.clip_start, cam.data.clip_end = 0.5, 40.0
    depsgraph = bpy.context.evaluated_depsgraph_get()
    w, h = 40, 30
    window = cam.calc_matrix_camera(depsgraph, x=w, y=h)
    view = cam.matrix_world.inverted()
    got = vp.camera_from_view(view, window, (w, h))
    want = export_camera(cam.evaluated_get(depsgraph), scene, [])
    assert got.kind == kind
    assert np.allclose(got.frame(), want.frame(), atol=1e-5)
    assert np.allclose(got.matrix_world[:3, :3], want.matrix_world[:3, :3], atol=1e-6)
    assert np.allclose(got.matrix_world[:3, 3], want.matrix_world[:3, 3], atol=1e-5)
    assert got.clip_start == pytest.approx(0.5, rel=1e-4) and got.clip_end == pytest.approx(40.0, rel=1e-4)


def test_camera_view_keeps_the_cameras_depth_of_field():
    """In the camera view the scene camera's depth of field applies, with its own aperture (focal length)."""
    scene = block_scene()
    cam = scene.camera
    cam.data.dof.use_dof, cam.data.dof.aperture_fstop, cam.data.dof.focus_distance = True, 1.4, 4.0
    cam.data.dof.aperture_blades = 6
    depsgraph = bpy.context.evaluated_depsgraph_get()
    want = export_camera(cam.evaluated_get(depsgraph), scene, [])
    got = vp.camera_from_view(cam.matrix_world.inverted(), cam.calc_matrix_camera(depsgraph, x=40, y=30), (40, 30),
                              lens=replace(want, resolution=(40, 30)))
    assert got.aperture_radius() == pytest.approx(want.aperture_radius()) and want.aperture_radius() > 0
    assert (got.focus_distance, got.aperture_blades, got.lens) == (4.0, 6, pytest.approx(35.0))
    assert np.allclose(got.frame(), replace(want, resolution=(40, 30)).frame(), atol=1e-5)


def test_orthographic_view_with_negative_near_plane_moves_the_origin_back():
    """Blender's orthographic viewports clip from -far/2: rays start that far behind the view point instead."""
    proj = np.diag([0.5, 0.375, -2.0 / 30.0, 1.0])  # 4 m wide, near -15, far 15 (proj[2, 3] = 0)
    got = vp.camera_from_view(np.eye(4), proj, (30, 40))
    assert got.clip_start == 0.0 and got.clip_end == pytest.approx(30.0)
    assert np.allclose(got.matrix_world[:3, 3], [0.0, 0.0, 15.0])
    assert np.allclose(got.frame(), (-2.0, 2.0, -2.0 * 4 / 3, 2.0 * 4 / 3))


def test_pixel_size_reads_blenders_setting():
    scene = bf.reset()
    scene.render.preview_pixel_size = "4"
    assert vp.pixel_size(scene) == 4
    scene.render.preview_pixel_size = "AUTO"  # the interface's pixel size: 1 without a high-density display
    assert vp.pixel_size(scene) == max(1, round(bpy.context.preferences.system.pixel_size))


def test_resolution_dividers_follow_start_resolution_and_pixel_size():
    assert vp.resolution_dividers(1280, 720, 1, 64) == [16, 8, 4, 2, 1]  # 80x45 first
    assert vp.resolution_dividers(1280, 720, 2, 64) == [16, 8, 4, 2]
    assert vp.resolution_dividers(1280, 720, 1, 0) == [1]
    assert vp.resolution_dividers(40, 30, 1, 8) == [8, 4, 2, 1]
    assert vp.resolution_dividers(16, 16, 4, 64) == [4]


# ------------------------------------------------------------------------------------------- the export
def test_the_viewport_scene_carries_what_a_full_export_carries():
    """The object table node programs read (object space, texture space, colour, pass index, random), each
    triangle's row, the film settings and the ray visibility: the viewport's scene holds the same as F12's
    export, so Object/Generated coordinates, Object Info, Film > Transparent and visibility render alike."""
    from monte.addon.export import export_scene

    scene = block_scene()
    block = bpy.data.objects["block"]
    block.location, block.rotation_euler, block.scale = (0.3, -0.2, 0.1), (0.2, 0.0, 0.7), (1.0, 2.0, 0.5)
    block.color, block.pass_index = (0.2, 0.4, 0.6, 1.0), 7
    block.visible_shadow = False
    scene.render.film_transparent = True
    depsgraph = bpy.context.evaluated_depsgraph_get()
    sync = vp.SceneSync()
    sync.sync(depsgraph)
    got = sync.scene(vp.scene_camera_view(depsgraph, (40, 30)))
    want, _ = export_scene(depsgraph)
    assert got.film == want.film and got.film.transparent
    for name in ("block", "floor"):
        g, w = mesh_named(got, name), mesh_named(want, name)
        assert [getattr(g, f"visible_{k}") for k in vp.MESH_RAY_VISIBILITY] == \
            [getattr(w, f"visible_{k}") for k in vp.MESH_RAY_VISIBILITY]
        assert np.allclose(got.objects[np.asarray(g.object_index)], want.objects[np.asarray(w.object_index)])
    assert mesh_named(got, "block").visible_shadow is False
    assert got.uv_layer_names == want.uv_layer_names


def test_each_kind_of_change_reexports_only_what_changed(changes):
    scene = block_scene()
    sync = vp.SceneSync()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    first = sync.sync(depsgraph)
    assert sorted(first.meshes_read) == ["block", "floor"] and sorted(first.materials_compiled) == ["grey", "paint"]
    assert first.lights_exported == 1 and first.world_exported and first.rebuild == "geometry"
    camera = vp.scene_camera_view(depsgraph, (40, 30))
    before = sync.scene(camera)
    block_before = mesh_named(before, "block").vertices.copy()

    block = bpy.data.objects["block"]
    report = sync.sync(*changes(lambda: setattr(block, "location", (0.5, 0.0, 0.0))))
    assert (report.moved, report.meshes_read, report.materials_compiled) == (["block"], [], [])
    assert (report.lights_exported, report.world_exported, report.removed) == (0, False, [])
    assert report.rebuild == "geometry"
    after = sync.scene(camera)
    assert np.allclose(mesh_named(after, "block").vertices - block_before, [0.5, 0.0, 0.0])
    assert mesh_named(after, "floor") is mesh_named(before, "floor")  # untouched: the same placed mesh

    paint = bpy.data.materials["paint"]
    node = paint.node_tree.nodes["Diffuse BSDF"]
    report = sync.sync(*changes(lambda: node.inputs["Color"].__setattr__("default_value", (0.1, 0.7, 0.2, 1))))
    assert (report.materials_compiled, report.meshes_read, report.moved) == (["paint"], [], [])
    assert report.lights_exported == 0 and report.rebuild == "shading"
    mat = next(m for m in sync.scene(camera).materials if m.name == "paint")
    assert np.allclose(mat.lobes[0].color, (0.1, 0.7, 0.2), atol=1e-6)

    lamp = bpy.data.objects["point"]
    report = sync.sync(*changes(lambda: setattr(lamp.data, "energy", 600.0)))
    assert report.lights_exported == 1 and report.rebuild == "shading"
    assert (report.meshes_read, report.moved, report.materials_compiled) == ([], [], [])
    light = sync.scene(camera).lights[0]
    assert np.allclose(light.power, 600.0)

    report = sync.sync(*changes(lambda: setattr(scene.camera, "location", (0.0, -6.0, 4.0))))
    assert report.line() == "nothing changed" and report.rebuild == "none"

    report = sync.sync(*changes(lambda: bpy_scenes.box_object("extra", (1, 1, 0), (1.5, 1.5, 0.5), paint)))
    assert (report.meshes_read, report.moved, report.removed) == (["extra"], [], [])
    assert report.materials_compiled == [] and report.rebuild == "geometry"
    assert len(sync.scene(camera).meshes) == 3

    report = sync.sync(*changes(lambda: bpy.data.objects.remove(bpy.data.objects["extra"])))
    assert (report.removed, report.meshes_read, report.moved) == (["extra"], [], [])
    assert sorted(m.name for m in sync.scene(camera).meshes) == ["block", "floor"]

    def edit_geometry():
        block.data.vertices[0].co.z -= 0.25
        block.data.update()

    report = sync.sync(*changes(edit_geometry))
    assert (report.meshes_read, report.moved, report.materials_compiled) == (["block"], [], [])
    assert mesh_named(sync.scene(camera), "block").vertices[:, 2].min() == pytest.approx(-0.25)

    world_bg = scene.world.node_tree.nodes["Background"]
    report = sync.sync(*changes(lambda: world_bg.inputs["Color"].__setattr__("default_value", (0.5, 0, 0, 1))))
    assert report.world_exported and report.rebuild == "shading" and report.meshes_read == []
    assert np.allclose(sync.scene(camera).world.color, (0.5, 0.0, 0.0))


# ------------------------------------------------------------------------------------------- rendering
def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a)[..., :3] - np.asarray(b)[..., :3]) ** 2)))


def session_images(session):
    """Record every image the session publishes: (samples, divider, rgba copy)."""
    seen: list = []

    def on_image():
        img = session.image()
        if img is not None:
            seen.append((img.samples, img.divider, img.rgba.copy()))

    session._on_image = on_image
    return seen


def test_progressive_restart_starts_small_and_converges(changes):
    block_scene()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    session = vp.ViewportSession(SETTINGS, samples=16, pixel_size=1, start_resolution=8)
    seen = session_images(session)
    try:
        session.sync(depsgraph)
        camera = vp.scene_camera_view(depsgraph, (40, 30))
        session.set_view(camera)
        final = session.wait(timeout=300)
        assert final.samples == 16 and final.rgba.shape == (30, 40, 4) and session.done
        # Reduced resolutions first (Start Resolution 8: 5x3, then 10x7, 20x15), then 16 full-size samples.
        assert [(s, d, img.shape[:2]) for s, d, img in seen[:4]] == [
            (1, 8, (3, 5)), (1, 4, (7, 10)), (1, 2, (15, 20)), (1, 1, (30, 40))]
        assert [s for s, d, _ in seen[3:]] == list(range(1, 17))
        # Converges to a 512-sample reference: the error falls about as 1/sqrt(samples).
        reference = core_render(session.sync_state.scene(camera), SETTINGS.replace(spp=512, seed=99)).color
        full = {s: img for s, d, img in seen if d == 1}
        errors = [rmse(full[n], reference) for n in (1, 4, 16)]
        assert errors[0] > errors[1] > errors[2] and errors[2] < 0.6 * errors[0], errors

        # A camera move re-prepares nothing; the image matches a session prepared for that camera.
        prepared_before = dict(session.prepare_count)
        moved = replace(camera, matrix_world=camera.matrix_world @ _translation(0.3, 0.2, 0.0))
        assert session.set_view(moved)
        moved_image = session.wait(timeout=300)
        assert session.prepare_count == prepared_before
        fresh = vp.ViewportSession(SETTINGS, samples=16, pixel_size=1, start_resolution=8)
        try:
            fresh.sync(depsgraph)
            fresh.set_view(moved)
            fresh_image = fresh.wait(timeout=300)
        finally:
            fresh.stop()
        assert rmse(moved_image.rgba, fresh_image.rgba) < 0.01 * float(fresh_image.rgba[..., :3].mean())

        # A material edit rebuilds the shading tables only; an object move the geometry.
        paint = bpy.data.materials["paint"].node_tree.nodes["Diffuse BSDF"]
        session.sync(*changes(lambda: paint.inputs["Color"].__setattr__("default_value", (0.1, 0.1, 0.8, 1))))
        session.wait(samples=1, timeout=300)
        assert session.prepare_count == {"geometry": prepared_before["geometry"],
                                         "shading": prepared_before["shading"] + 1}
        block = bpy.data.objects["block"]
        session.sync(*changes(lambda: setattr(block, "location", (0.3, 0.0, 0.0))))
        session.wait(samples=1, timeout=300)
        assert session.prepare_count["geometry"] == prepared_before["geometry"] + 1
    finally:
        session.stop()
    session.join(30)
    assert not session._thread.is_alive()


def test_an_added_or_deleted_object_renders_as_a_fresh_session_does(changes, monkeypatch):
    """After an object is added, and after another is deleted (the meshes after it move to other object rows),
    the session's image equals bit for bit that of a fresh session of the changed scene; the preparation checked
    the triangles of the added mesh alone (the kept meshes were checked when they came)."""
    from monte.core import scene as core_scene

    block_scene()
    camera = vp.scene_camera_view(bpy.context.evaluated_depsgraph_get(), (40, 30))
    validated: list[str] = []
    validate = core_scene.Mesh.validate

    def counting(mesh, *args, **kwargs):
        validated.append(mesh.name)
        return validate(mesh, *args, **kwargs)

    monkeypatch.setattr(core_scene.Mesh, "validate", counting)

    def fresh_image(depsgraph):
        fresh = vp.ViewportSession(SETTINGS, samples=4, pixel_size=1, start_resolution=0)
        try:
            fresh.sync(depsgraph)
            fresh.set_view(camera)
            return fresh.wait(timeout=300).rgba
        finally:
            fresh.stop()

    session = vp.ViewportSession(SETTINGS, samples=4, pixel_size=1, start_resolution=0)
    try:
        session.sync(bpy.context.evaluated_depsgraph_get())
        session.set_view(camera)
        before = session.wait(timeout=300).rgba
        assert sorted(validated) == ["block", "floor"]

        validated.clear()
        green = bf.diffuse("green", (0.1, 0.7, 0.1))
        depsgraph, flagged = changes(lambda: bpy_scenes.box_object("extra", (1.0, 0.0, 0.0), (1.8, 0.8, 0.8), green))
        assert session.sync(depsgraph, flagged).meshes_read == ["extra"]
        added = session.wait(timeout=300).rgba
        assert validated == ["extra"]
        assert not np.allclose(added, before, atol=0.05)  # the new box is in view
        np.testing.assert_array_equal(added, fresh_image(depsgraph))

        validated.clear()
        depsgraph, flagged = changes(lambda: bpy.data.objects.remove(bpy.data.objects["block"]))
        assert session.sync(depsgraph, flagged).removed == ["block"]
        deleted = session.wait(timeout=300).rgba
        assert validated == []
        np.testing.assert_array_equal(deleted, fresh_image(depsgraph))
    finally:
        session.stop()


def test_a_mesh_with_a_dropped_triangle_renders_after_later_updates(changes):
    """A mesh whose preparation drops a degenerate triangle keeps rendering after a material edit and an object
    add (its instances' object rows were recomputed from the prototype's triangle count, which no longer fit the
    validated mesh: the viewport showed a broadcast error); the image equals a fresh session's."""
    block_scene()
    # a quad plus a zero-area triangle (three collinear points) in one mesh
    bf.mesh_object("sliver", [(1.0, -1.0, 0.01), (2.0, -1.0, 0.01), (2.0, 0.0, 0.01), (1.0, 0.0, 0.01),
                              (1.2, -0.5, 0.01), (1.5, -0.5, 0.01), (1.8, -0.5, 0.01)],
                   [(0, 1, 2, 3), (4, 5, 6)], bf.diffuse("sliver", (0.1, 0.1, 0.9)))
    camera = vp.scene_camera_view(bpy.context.evaluated_depsgraph_get(), (40, 30))
    session = vp.ViewportSession(SETTINGS, samples=2, pixel_size=1, start_resolution=0)
    try:
        session.sync(bpy.context.evaluated_depsgraph_get())
        session.set_view(camera)
        session.wait(timeout=300)
        sliver = [m for m in session.sync_state.meshes.values() if "sliver" in m.name]
        assert [len(m.triangles) for m in sliver] == [2]  # the quad's two; the zero-area triangle dropped
        paint = bpy.data.materials["paint"].node_tree.nodes["Diffuse BSDF"]
        session.sync(*changes(lambda: paint.inputs["Color"].__setattr__("default_value", (0.1, 0.8, 0.1, 1))))
        session.wait(timeout=300)
        green = bf.diffuse("green", (0.1, 0.7, 0.1))
        depsgraph, flagged = changes(lambda: bpy_scenes.box_object("extra", (-2.0, 0.0, 0.0), (-1.5, 0.5, 0.5),
                                                                   green))
        session.sync(depsgraph, flagged)
        image = session.wait(timeout=300).rgba
    finally:
        session.stop()
    fresh = vp.ViewportSession(SETTINGS, samples=2, pixel_size=1, start_resolution=0)
    try:
        fresh.sync(depsgraph)
        fresh.set_view(camera)
        np.testing.assert_array_equal(image, fresh.wait(timeout=300).rgba)
    finally:
        fresh.stop()


def _translation(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def test_a_change_cancels_the_render_in_flight(changes):
    """With a sample count the session would take hours to reach, only cancelling the pass in flight lets the
    changed scene's first full-size image appear."""
    block_scene()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    session = vp.ViewportSession(SETTINGS, samples=1_000_000, pixel_size=2, start_resolution=0)
    try:
        session.sync(depsgraph)
        session.set_view(vp.scene_camera_view(depsgraph, (48, 36)))
        before = session.wait(samples=2, timeout=300)
        assert before.rgba.shape == (18, 24, 4)  # Pixel Size 2
        block = bpy.data.objects["block"]
        session.sync(*changes(lambda: setattr(block, "location", (3.0, 3.0, 0.0))))
        assert session.image() is not None  # the view keeps showing the last image until the new one comes
        after = session.wait(samples=1, timeout=300)
        assert after.version > before.version and not session.done
        # The moved block is gone from the middle of the image, the floor seen instead.
        assert not np.allclose(after.rgba, before.rgba, atol=0.05)
    finally:
        session.stop()
    session.join(30)
    assert not session._thread.is_alive()


def test_the_viewport_computes_no_pass_beside_combined(monkeypatch):
    """A view layer asking for shader AOVs (with an AOV Output node), data passes, light passes, a light group and
    denoising: the viewport session, which shows Combined alone, renders none of them (the scene it renders lists
    no AOV and no light group, its materials write no AOV, its settings ask for no pass) -- while F12's export and
    settings do ask for them, so the test would see them if the session let them through."""
    from monte.addon.engine import render_settings
    from monte.addon.export import export_scene
    from monte.core import render as render_mod
    from monte.core.shading.registry import OP_AOV_OUTPUT

    scene = block_scene()
    tree = bpy.data.materials["paint"].node_tree
    aov = tree.nodes.new("ShaderNodeOutputAOV")
    aov.aov_name = "tint"
    aov.inputs["Color"].default_value = (0.0, 1.0, 0.0, 1.0)
    bpy.ops.scene.view_layer_add_aov()
    layer = scene.view_layers[0]
    layer.active_aov.name = "tint"
    layer.use_pass_mist = layer.use_pass_diffuse_direct = layer.use_pass_cryptomatte_object = True
    bpy.ops.scene.view_layer_add_lightgroup(name="lamps")
    for obj in bpy.data.objects:
        if obj.type == "LIGHT":
            obj.lightgroup = "lamps"
    scene.monte.use_denoising = True
    depsgraph = bpy.context.evaluated_depsgraph_get()
    full, _ = export_scene(depsgraph)
    assert full.shader_aovs == [("tint", "COLOR")] and full.light_groups == ["lamps"]
    settings = render_settings(scene, {"data_passes": ("mist", "crypto_object"), "light_passes": ("Diffuse Direct",)})
    assert settings.denoising_features
    seen = []
    real = render_mod.render

    def spy(core_scene, core_settings, **kw):
        result = real(core_scene, core_settings, **kw)
        seen.append((core_scene, core_settings, result))
        return result

    monkeypatch.setattr(render_mod, "render", spy)
    session = vp.ViewportSession(settings.replace(threads=2), samples=2, start_resolution=0)
    try:
        session.sync(depsgraph)
        session.set_view(vp.scene_camera_view(depsgraph, (40, 30)))
        assert session.wait(timeout=300).samples == 2
    finally:
        session.stop()
    assert seen
    for core_scene, core_settings, result in seen:
        assert core_scene.shader_aovs == [] and core_scene.light_groups == []
        assert not any(getattr(m, "program", None) is not None and np.any(m.program.code[:, 0] == OP_AOV_OUTPUT)
                       for m in core_scene.materials)
        assert (core_settings.data_passes, core_settings.light_passes, core_settings.denoising_features,
                core_settings.aovs) == ((), (), False, False)
        assert result.shader_aovs is None and result.light_groups is None and result.light_passes is None
        assert result.data_passes == {} and result.denoising_albedo is None


def test_a_scene_monte_cannot_render_shows_the_error_and_recovers(changes):
    scene = bf.reset()
    bf.camera_object(scene, (0.0, -5.0, 1.0), (math.radians(90), 0.0, 0.0))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    session = vp.ViewportSession(SETTINGS, samples=2, start_resolution=0)
    try:
        session.sync(depsgraph)
        session.set_view(vp.scene_camera_view(depsgraph, (16, 12)))
        assert session.error == ("nothing to render in the viewport: no visible meshes, curves, text or "
                                 "metaballs")
        with pytest.raises(Exception, match="nothing to render in the viewport"):
            session.wait(timeout=5)
        session.sync(*changes(lambda: bpy_scenes.box_object("box", (-1, -1, -1), (1, 1, 1), None)))
        assert session.error is None
        assert session.wait(timeout=300).samples == 2
    finally:
        session.stop()


# ------------------------------------------------------------------------------------------- drawing
def gpu_context() -> None:
    """One tiny Workbench render creates the GPU context the bpy module otherwise lacks (about 3 s here; EEVEE
    compiles its shaders for minutes in software GL); skips with the reason when none can be made here."""
    import gpu

    try:
        gpu.types.GPUOffScreen(4, 4).free()
        return
    except Exception:  # noqa: BLE001 - "GPU functions for drawing are not available in background mode"
        pass
    scene = bf.reset()
    scene.render.engine = "BLENDER_WORKBENCH"
    bf.camera_object(scene, (0, 0, 1), (0, 0, 0))
    scene.render.resolution_x = scene.render.resolution_y = 8
    try:
        bpy.ops.render.render()
        gpu.types.GPUOffScreen(4, 4).free()
    except Exception as exc:  # noqa: BLE001
        pytest.skip(f"no GPU context can be made here (a Workbench render did not create one: {exc})")


def draw_offscreen(width, height, draw) -> np.ndarray:
    """Run draw() into an offscreen framebuffer in pixel coordinates; the pixels, row 0 at the top."""
    import gpu
    from mathutils import Matrix

    offscreen = gpu.types.GPUOffScreen(width, height, format="RGBA32F")
    try:
        with offscreen.bind():
            fb = gpu.state.active_framebuffer_get()
            fb.clear(color=(0.0, 0.0, 0.0, 0.0))
            with gpu.matrix.push_pop():
                gpu.matrix.load_matrix(Matrix.Identity(4))
                pixel_space = Matrix.Identity(4)
                pixel_space[0][0], pixel_space[1][1] = 2.0 / width, 2.0 / height
                pixel_space[0][3] = pixel_space[1][3] = -1.0
                gpu.matrix.load_projection_matrix(pixel_space)
                draw()
            buffer = fb.read_color(0, 0, width, height, 4, 0, "FLOAT")
        buffer.dimensions = width * height * 4
        return np.array(buffer.to_list(), np.float32).reshape(height, width, 4)[::-1]
    finally:
        offscreen.free()


def test_draw_uploads_the_image_and_stretches_it_over_the_view():
    gpu_context()
    rng = np.random.default_rng(5)
    image = np.concatenate([rng.uniform(0.0, 1.0, (6, 8, 3)), np.ones((6, 8, 1))], axis=2).astype(np.float32)
    got = draw_offscreen(8, 6, lambda: vp.draw_texture(vp.image_texture(image), 8, 6))
    assert np.allclose(got, image, atol=1e-5)  # same orientation (row 0 at the top), float precision
    # Pixel Size 2: a half-size image covers the whole view.
    flat = np.full((6, 8, 4), 0.3, np.float32)
    flat[..., 3] = 1.0
    got = draw_offscreen(16, 12, lambda: vp.draw_texture(vp.image_texture(flat), 16, 12))
    assert np.allclose(got, flat.repeat(2, axis=0).repeat(2, axis=1), atol=1e-5)


def test_engine_draws_inside_the_display_space_shader_bracket(tmp_path):
    """The engine's own drawing (bind_display_space_shader, the texture, unbind) inside a real engine instance.
    Blender 4.x/5.x's bind_display_space_shader binds the image shader and its draw manager applies the view
    transform to what view_draw drew, afterwards: so the drawn pixels must stay scene-linear (0.2, not the 0.48
    of an sRGB transform applied twice), whatever the view transform."""
    gpu_context()
    scene = bf.plane_under_world(albedo=0.5, world=1.0, resolution=(4, 4))
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
    linear = np.full((4, 4, 4), 0.2, np.float32)
    linear[..., 3] = 1.0
    drawn = {}

    def draw_inside_render(self, depsgraph):
        image = vp.ViewImage(linear, 1, 1, (8, 8), 1, 0.0)
        drawn["pixels"] = draw_offscreen(8, 8, lambda: self._draw_viewport_image(depsgraph.scene, image, 8, 8))
        self._write_black(depsgraph)

    original = engine_mod.MonteRenderEngine._render
    engine_mod.MonteRenderEngine._render = draw_inside_render
    try:
        bpy.ops.render.render()
    finally:
        engine_mod.MonteRenderEngine._render = original
    assert np.allclose(drawn["pixels"][..., :3], 0.2, atol=1e-5), drawn["pixels"][0, 0]
    assert np.allclose(drawn["pixels"][..., 3], 1.0)


def test_engine_view_update_and_view_draw(tmp_path):
    """The engine's view_update and view_draw in a real engine instance (taken inside an F12 render, as the bpy
    module opens no 3D view): the context carries what Blender's would, a region's size and a view whose matrices
    are the scene camera's. view_update starts the session, view_draw sets the view and, once the samples are in,
    draws exactly the session's image."""
    import types

    gpu_context()
    scene = block_scene()
    scene.monte.viewport_samples, scene.monte.viewport_start_resolution = 4, 0
    scene.monte.max_bounces, scene.monte.threads, scene.monte.filter_type = 2, 2, "box"
    scene.render.preview_pixel_size = "1"
    depsgraph = bpy.context.evaluated_depsgraph_get()
    w, h = 40, 30
    view = types.SimpleNamespace(view_matrix=scene.camera.matrix_world.inverted(), view_perspective="CAMERA",
                                 window_matrix=scene.camera.calc_matrix_camera(depsgraph, x=w, y=h))
    context = types.SimpleNamespace(region=types.SimpleNamespace(width=w, height=h), region_data=view)
    seen = {}

    def viewport_inside_render(self, depsgraph):
        try:
            self.view_update(context, depsgraph)
            session = self._viewport
            self.view_draw(context, depsgraph)  # sets the view; draws once an image exists
            assert session.camera is not None, getattr(self, "_viewport_error", None)
            seen["image"] = session.wait(timeout=300)
            seen["pixels"] = draw_offscreen(w, h, lambda: self.view_draw(context, depsgraph))
            seen["samples"] = session.samples
        finally:
            if getattr(self, "_viewport", None) is not None:
                self._viewport.stop()
        self._write_black(depsgraph)

    original = engine_mod.MonteRenderEngine._render
    engine_mod.MonteRenderEngine._render = viewport_inside_render
    try:
        bpy.ops.render.render()
    finally:
        engine_mod.MonteRenderEngine._render = original
    image = seen["image"]
    assert seen["samples"] == 4 and image.samples == 4 and image.rgba.shape == (h, w, 4)
    assert image.rgba[..., :3].std() > 0.05  # a real picture: floor, block, world
    assert np.allclose(seen["pixels"], image.rgba, rtol=1e-5, atol=1e-5)


# ------------------------------------------------------------------------------------------- previews
def preview_like_scene():
    """Blender's material preview in miniature: a sphere on a floor under an area light, 64x64."""
    scene = bf.reset()
    bf.mesh_object("floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                   bf.diffuse("checker", (0.6, 0.6, 0.6)))
    bf.icosphere_object("preview", (0, 0, 1), 1.0, bf.diffuse("material", (0.2, 0.4, 0.8)), subdivisions=3)
    bpy_scenes.light_object(scene, "AREA", (2, -2, 4), energy=400.0, size=2.0)
    bf.set_world(scene, (0.05, 0.05, 0.05))
    bf.camera_object(scene, (0, -6, 2.5), (math.radians(78), 0, 0), lens=50.0)
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.resolution_percentage = 100
    m = scene.monte
    m.preview_samples, m.seed, m.threads, m.max_bounces = 16, 2, 2, 3
    return scene


def render_preview(scene, cancel_after: int | None = None) -> list[int]:
    """F12 through the engine's preview path (is_preview answered True); the sample counts of the passes it wrote.
    cancel_after: test_break answers True once that many passes were written (the user moved on)."""
    passes: list[int] = []
    original_pp = vp.progressive_passes

    def counting(*args, **kwargs):
        on_image = args[4]

        def record(rgba, taken):
            passes.append(taken)
            on_image(rgba, taken)

        return original_pp(*args[:4], record, *args[5:], **kwargs)

    engine = engine_mod.MonteRenderEngine
    originals = (engine._preview_requested, engine._cancel_requested)
    engine._preview_requested = lambda self: True
    if cancel_after is not None:
        engine._cancel_requested = lambda self: len(passes) >= cancel_after
    vp.progressive_passes = counting
    try:
        assert bpy.ops.render.render() == {"FINISHED"}
    finally:
        engine._preview_requested, engine._cancel_requested = originals
        vp.progressive_passes = original_pp
    return passes


def test_preview_path_renders_progressively_and_agrees_with_a_full_render(tmp_path):
    """Blender's preview jobs need a window, so the engine's preview path renders a preview-like scene through
    F12 with is_preview answered True; the image it leaves must agree with a plain render of the same samples,
    and its passes grow 1, 2, 4, ... up to Preview Samples."""
    scene = preview_like_scene()
    passes = render_preview(scene)
    assert passes == [1, 3, 7, 15, 16]
    ch = bf.save_render_exr(scene, tmp_path / "preview.exr")
    got = np.stack([ch[f"ViewLayer.Combined.{c}"] for c in "RGB"], axis=-1)
    assert got.shape == (64, 64, 3)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    from monte.addon.export import export_scene
    from monte.addon.properties import render_settings

    core_scene, _ = export_scene(depsgraph)
    reference = core_render(core_scene, render_settings(scene, {"aovs": False}).replace(spp=256, seed=7)).color
    # Blender's EXR holds the top row first, as core's images do.
    err = rmse(got, reference[..., :3])
    noise16 = rmse(core_render(core_scene, render_settings(scene, {"aovs": False}).replace(spp=16, seed=11)).color,
                   reference)
    assert err < 1.5 * noise16 + 1e-3, (err, noise16)
    assert abs(float(got.mean()) - float(reference[..., :3].mean())) < 0.03 * float(reference[..., :3].mean())


def test_preview_stops_when_the_user_moves_on(tmp_path):
    scene = preview_like_scene()
    assert render_preview(scene, cancel_after=2) == [1, 3]  # the third pass is cancelled, not written
    ch = bf.save_render_exr(scene, tmp_path / "stopped.exr")
    got = np.stack([ch[f"ViewLayer.Combined.{c}"] for c in "RGB"], axis=-1)
    assert got.shape == (64, 64, 3) and got.mean() > 0.01  # the 3-sample image stays


def test_engine_declares_previews():
    assert engine_mod.MonteRenderEngine.bl_use_preview is True


def test_viewport_session_keeps_no_error_estimate():
    """The viewport draws Combined alone, so nothing reads the per-pixel error estimate: one Sobol scramble per
    pixel even where the scene's settings (adaptive sampling, which the viewport turns off) asked for it."""
    asked = SETTINGS.replace(adaptive_threshold=0.01, error_estimate=True)
    session = vp.ViewportSession(asked, samples=4, pixel_size=1, start_resolution=0)
    assert session.settings.error_estimate is False and session.settings.adaptive_threshold == 0.0
    assert session.settings.variance_groups == 1
