"""A .blend animation on a Dask cluster (`monte render scene.blend --dask local:2 --frames 1-2`): each frame is
exported once here through the add-on, rendered on a real LocalCluster and written as OUTPUT_####.exr, equal bit
for bit to the core render of the same exported frame; --resume renders only the frames whose file is missing.
The export is F12's (its render depsgraph: render subdivision levels)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon.headless import export_blend_frames  # noqa: E402
from monte.cli import main  # noqa: E402
from monte.core.distributed import plan_units  # noqa: E402
from monte.core.exr import read_exr  # noqa: E402
from monte.core.render import render  # noqa: E402

pytestmark = pytest.mark.blender

OPTIONS = ["--spp", "8", "--seed", "3", "--batch", "1024", "--tile", "16", "--resolution", "24x16", "--no-png", "-q"]


@pytest.fixture()
def animated_blend(tmp_path):
    """The Cornell box with its camera moving between frames 1 and 2, saved as a .blend."""
    bf.cornell_box((24, 16))
    scene = bpy.context.scene
    cam = scene.camera
    cam.keyframe_insert("location", frame=1)
    cam.location.x += 0.3
    cam.keyframe_insert("location", frame=2)
    scene.frame_set(1)
    blend = tmp_path / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    return blend


def test_frames_on_a_cluster_equal_the_core_render_of_each_frame(animated_blend, tmp_path):
    out = tmp_path / "frames" / "shot.exr"
    out.parent.mkdir()
    assert main(["render", str(animated_blend), "-o", str(out), "--dask", "local:2", "--frames", "1-2",
                 "--variance"] + OPTIONS) == 0
    assert sorted(p.name for p in out.parent.iterdir()) == ["shot_0001.exr", "shot_0002.exr"]
    overrides = {"spp": 8, "seed": 3, "batch_paths": 1024, "tile_size": 16, "resolution": (24, 16),
                 "variance": True}
    colors = []
    for frame, scene, settings, region, _size, _cropped in export_blend_frames(animated_blend, overrides, [1, 2],
                                                                             log=lambda _m: None):
        assert region is None
        assert settings.error_estimate  # --variance: the 2 variance groups, on the cluster as here
        local = render(scene, settings)
        written = read_exr(out.parent / f"shot_{frame:04d}.exr")
        assert np.array_equal(written["R"], local.color[..., 0]) and np.array_equal(written["B"], local.color[..., 2])
        assert np.array_equal(written["variance.G"], local.variance[..., 1])
        assert np.array_equal(written["Z"], local.depth)
        colors.append(local.color)
    assert not np.array_equal(colors[0], colors[1])  # the camera did move: two different frames

    # --resume: frame 1 stays as it is, the missing frame 2 is rendered again, identically.
    first = (out.parent / "shot_0001.exr").stat().st_mtime_ns
    second = (out.parent / "shot_0002.exr").read_bytes()
    (out.parent / "shot_0002.exr").unlink()
    assert main(["render", str(animated_blend), "-o", str(out), "--dask", "local:2", "--frames", "1,2",
                 "--resume", "--variance"] + OPTIONS) == 0
    assert (out.parent / "shot_0001.exr").stat().st_mtime_ns == first
    assert (out.parent / "shot_0002.exr").read_bytes() == second


def test_frames_without_a_cluster_are_refused(animated_blend, tmp_path, capsys):
    assert main(["render", str(animated_blend), "-o", str(tmp_path / "x.exr"), "--frames", "1-2"] + OPTIONS) == 2
    assert "--frames and --resume render a .blend's frames on a cluster" in capsys.readouterr().err


def test_a_cluster_export_sees_the_scene_as_f12_does(tmp_path):
    """A cube with a Subdivision Surface modifier of 1 level in the viewport and 3 for renders: the frames
    exported for a cluster hold the render levels, 6 x 4^3 quads = 768 triangles, as F12's own render does
    (control: the viewport depsgraph the export used before holds 6 x 4 quads = 48)."""
    from monte.addon.export import export_scene

    bf.cornell_box((8, 8))
    for obj in list(bpy.data.objects):
        if obj.type == "MESH":
            bpy.data.objects.remove(obj)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 0.0))
    modifier = bpy.context.active_object.modifiers.new("Subdivision", "SUBSURF")
    modifier.levels, modifier.render_levels = 1, 3
    blend = tmp_path / "subdivided.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    exported = list(export_blend_frames(blend, {"spp": 1}, None, log=lambda _m: None))
    assert len(exported) == 1
    assert sum(m.triangle_count for m in exported[0].scene.meshes) == 6 * 4 ** 3 * 2
    viewport, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    assert sum(m.triangle_count for m in viewport.meshes) == 6 * 4 * 2


def test_a_cluster_export_takes_one_view_layer_its_passes_and_its_overrides_together(tmp_path):
    """Two view layers: "Override" (a Material Override, no passes) and "Mist" (the Mist pass). The cluster renders
    one layer: the scene it exports and the passes it asks for come from that same layer (the log names it), and
    the export runs once; with "Mist" the only layer that renders, it is that one. (Before, F12 exported every
    layer, the first was kept and the passes came from the active one.)"""
    bf.cornell_box((8, 8))
    scene = bpy.context.scene
    first = scene.view_layers[0]
    first.name = "Override"
    first.material_override = bpy.data.materials.new("override material")
    second = scene.view_layers.new("Mist")
    second.use_pass_mist = True

    def exported_layer(blend):
        said: list[str] = []
        item, = export_blend_frames(blend, {"spp": 1}, None, log=said.append)
        names = {m.name for m in item.scene.materials}
        overridden = any("override material" in name for name in names)
        return overridden, "mist" in item.settings.data_passes, said

    blend = tmp_path / "layers.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    overridden, mist, said = exported_layer(blend)
    assert overridden != mist  # the override and the passes of one layer, whichever it is
    chosen = "Mist" if mist else "Override"
    assert f"Monte: 2 view layers render; the cluster renders view layer {chosen!r}" in said

    bpy.context.scene.view_layers["Override"].use = False  # (the file loaded above)
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    overridden, mist, said = exported_layer(blend)
    assert mist and not overridden
    assert not any("view layers render" in line for line in said)


def test_a_render_region_sends_out_only_its_tiles_and_equals_the_local_region_render(tmp_path, capsys):
    """Render Region x 0.25-0.75 of 24x16 (pixels 6-18, y 4-12 from the top): only the region's tiles go out (the
    units plan_units cuts for the region, fewer paths than the frame's), the EXR is padded to the frame as
    `monte render scene.blend` writes a region, and it equals that local render's file bit for bit, the view
    layer's data passes (Mist, Cryptomatte) included."""
    bf.cornell_box((24, 16))
    scene = bpy.context.scene
    scene.render.use_border, scene.render.use_crop_to_border = True, False
    scene.render.border_min_x, scene.render.border_max_x = 0.25, 0.75
    scene.render.border_min_y, scene.render.border_max_y = 0.25, 0.75
    layer = scene.view_layers[0]  # the view layer's data passes go to the cluster too
    layer.use_pass_mist, layer.use_pass_cryptomatte_object = True, True
    blend = tmp_path / "region.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    options = [o for o in OPTIONS if o != "-q"]
    assert main(["render", str(blend), "-o", str(tmp_path / "cluster.exr"), "--dask", "local:2"] + options) == 0
    log = capsys.readouterr().err
    assert main(["render", str(blend), "-o", str(tmp_path / "local.exr")] + OPTIONS) == 0

    overrides = {"spp": 8, "seed": 3, "batch_paths": 1024, "tile_size": 16, "resolution": (24, 16)}
    item, = export_blend_frames(blend, overrides, None, log=lambda _m: None)
    assert item.region == (6, 4, 12, 8) and item.size == (24, 16) and not item.cropped
    units = plan_units(item.scene, item.settings, 2, region=item.region)
    assert {ti for u in units for ti in u} == {0}  # the region is one 12x8 tile of 16x16 tiles
    assert f"{len(units)} units on 2 workers" in log
    local = render(item.scene, item.settings, region=item.region)
    written = read_exr(tmp_path / "cluster.exr")
    assert written["R"].shape == (16, 24)
    assert np.array_equal(written["R"][4:12, 6:18], local.color[..., 0]) and local.color[..., 0].max() > 0
    outside = np.ones((16, 24), bool)
    outside[4:12, 6:18] = False
    assert np.all(written["R"][outside] == 0) and np.all(written["Z"][outside] == 1e10)
    assert np.array_equal(written["Mist.Z"][4:12, 6:18], local.data_passes["Mist"][..., 0])
    from_blender = read_exr(tmp_path / "local.exr")
    common = set(written) & set(from_blender)
    assert {"R", "A", "Mist.Z", "CryptoObject00.R", "CryptoObject00.G"} <= common
    assert not item.settings.error_estimate and "variance.R" not in set(written) | set(from_blender)  # no --variance
    for name in common:
        assert np.array_equal(written[name], from_blender[name]), name
