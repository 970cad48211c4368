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
    assert main(["render", str(animated_blend), "-o", str(out), "--dask", "local:2", "--frames", "1-2"]
                + OPTIONS) == 0
    assert sorted(p.name for p in out.parent.iterdir()) == ["shot_0001.exr", "shot_0002.exr"]
    overrides = {"spp": 8, "seed": 3, "batch_paths": 1024, "tile_size": 16, "resolution": (24, 16)}
    colors = []
    for frame, scene, settings in export_blend_frames(animated_blend, overrides, [1, 2], log=lambda _m: None):
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
                 "--resume"] + OPTIONS) == 0
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
    assert sum(m.triangle_count for m in exported[0][1].meshes) == 6 * 4 ** 3 * 2
    viewport, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    assert sum(m.triangle_count for m in viewport.meshes) == 6 * 4 * 2
