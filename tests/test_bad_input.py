"""Bad input never loses work: clear errors naming the setting, file or object, checked before rendering where
possible; outputs written atomically; memory estimated before allocation; cancel leaves a valid image.

(Complements tests/test_io_cli.py, tests/test_render.py and tests/test_addon_engine.py, which cover the
EXR round trip, a failing EXR write, negative spp, zero resolution, junk geometry and engine cancel.)
"""

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from monte import cli
from monte.core import builtin_scenes as scenes
from monte.core import exr, memory
from monte.core.render import render
from monte.core.scene import SceneError
from monte.core.settings import RenderSettings

READ_ONLY_DIR = Path("/proc")  # writable by nobody, root included (tests may run as root)


# ----------------------------------------------------------------------------------------- absurd settings
@pytest.mark.parametrize("change, message", [
    (dict(spp=float("nan")), r"samples per pixel \(spp\) must be a whole number, got nan"),
    (dict(spp=2.5), "samples per pixel"),
    (dict(spp="8"), "samples per pixel"),
    (dict(filter_width=float("nan")), "filter width"),
    (dict(filter_width=float("inf")), "filter width"),
    (dict(rr_depth=float("nan")), "Russian roulette depth"),
    (dict(batch_paths=float("inf")), "batch size"),
    (dict(tile_size=0), "tile size"),
    (dict(time_limit=float("nan")), "time limit"),
    (dict(threads=-1), "threads"),
    (dict(seed=-5), "seed"),
])
def test_absurd_settings_name_the_setting(fast_settings, change, message):
    with pytest.raises(ValueError, match=message):
        render(scenes.furnace((4, 4)), fast_settings(**change))


@pytest.mark.parametrize("field, value", [("lens", float("nan")), ("shift_x", float("inf")),
                                          ("clip_start", float("nan")), ("sensor_width", float("nan"))])
def test_nan_camera_values_name_the_field(fast_settings, field, value):
    scene = scenes.furnace((4, 4))
    setattr(scene.camera, field, value)
    with pytest.raises(SceneError, match=f"camera: {field}"):
        render(scene, fast_settings())


def test_cli_rejects_absurd_values_before_writing(tmp_path, capsys):
    out = tmp_path / "x.exr"
    for argv, message in ((["--filter-width", "0"], "filter width"), (["--spp", "-2"], "samples per pixel"),
                          (["--filter-width", "nan"], "filter width"), (["--clamp", "-1"], "clamp")):
        assert cli.main(["render", "furnace", "-o", str(out), "--quiet", *argv]) == 1
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse: exit status 2 with the message
        cli.main(["render", "furnace", "-o", str(out), "--resolution", "0x4"])
    assert "resolution must be at least 1x1" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------- output paths
@pytest.mark.parametrize("where", ["missing folder", "a folder", "read-only", "parent is a file"])
def test_unwritable_output_fails_before_rendering(tmp_path, capsys, monkeypatch, where):
    target = {"missing folder": tmp_path / "nope" / "a.exr", "a folder": tmp_path / "d.exr",
              "read-only": READ_ONLY_DIR / "monte-test.exr", "parent is a file": tmp_path / "f.txt" / "a.exr"}[where]
    (tmp_path / "f.txt").write_text("a file")
    (tmp_path / "d.exr").mkdir()
    rendered = []
    monkeypatch.setattr("monte.core.render.render", lambda *a, **k: rendered.append(1))
    assert cli.main(["render", "furnace", "-o", str(target), "--quiet", "--spp", "1"]) == 1
    err = capsys.readouterr().err
    assert "cannot write" in err and str(target) in err
    assert rendered == []  # the error came before any rendering
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.exr", "f.txt"]
    assert list((tmp_path / "d.exr").iterdir()) == []


def test_png_write_is_atomic_and_keeps_the_existing_file(tmp_path, monkeypatch):
    target = tmp_path / "keep.png"
    target.write_bytes(b"precious preview")
    import builtins

    real_open = builtins.open

    def failing_open(path, mode="r", *a, **k):
        f = real_open(path, mode, *a, **k)
        if "w" in mode and str(path).endswith(".png"):
            f.write(b"\x89PNG half")
            f.close()
            raise OSError(28, "No space left on device")
        return f

    monkeypatch.setattr(builtins, "open", failing_open)
    with pytest.raises(exr.OutputError, match="No space left"):
        exr.write_png(target, np.zeros((4, 4, 3), np.float32))
    monkeypatch.undo()
    assert target.read_bytes() == b"precious preview"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.png"]


def test_exr_write_replaces_a_file_only_with_a_complete_one(tmp_path):
    target = tmp_path / "img.exr"
    target.write_bytes(b"old")
    exr.write_exr(target, {"R": np.full((3, 2), 2.0, np.float32)})
    assert exr.read_exr(target)["R"].shape == (3, 2)
    with pytest.raises(exr.OutputError, match="it is a folder"):
        exr.write_exr(tmp_path, {"R": np.zeros((2, 2), np.float32)})
    with pytest.raises(ValueError, match="2-D"):  # bad data fails before the target is touched
        exr.write_exr(target, {"R": np.zeros((2, 2), np.float32), "G": np.zeros((3, 2), np.float32)})
    assert exr.read_exr(target)["R"][0, 0] == 2.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["img.exr"]


def test_corrupt_exr_reads_as_a_clear_error(tmp_path):
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"v/1\x01" + os.urandom(200))
    with pytest.raises(ValueError, match="bad.exr is not a readable OpenEXR"):
        exr.read_exr(bad)


# ----------------------------------------------------------------------------------------- memory
def test_memory_estimate_follows_the_documented_formula():
    scene = scenes.cornell_box((100, 50))
    s = RenderSettings(spp=4, batch_paths=1 << 14, threads=3)
    est = memory.estimate_render_memory(scene, s)
    pixels = 100 * 50
    assert est.film == pixels * memory.FILM_BYTES  # the AOV sums live in the result's AOV images
    assert est.result == pixels * (memory.RESULT_BYTES + memory.RESULT_AOV_BYTES)
    # each of the 3 worker threads traces one batch of min(batch_paths, all paths) paths at a time
    assert est.batch == 3 * min(1 << 14, pixels * 4) * memory.PATH_BYTES
    assert memory.estimate_render_memory(scene, s.replace(spp=1)).batch == 3 * pixels * memory.PATH_BYTES
    assert est.scene == scene.triangle_count * memory.TRIANGLE_BYTES
    no_aov = memory.estimate_render_memory(scene, s.replace(aovs=False))
    assert no_aov.total < est.total


def test_too_large_a_render_is_refused_before_allocation(fast_settings):
    scene = scenes.cornell_box((40000, 40000))  # 1.6 G pixels: hundreds of GB of film
    with pytest.raises(memory.RenderMemoryError, match=r"40000x40000 needs about [\d,]+ MB.*available"):
        render(scene, fast_settings(spp=1))


def test_memory_check_uses_the_available_amount():
    scene = scenes.cornell_box((64, 64))
    s = RenderSettings(spp=4)
    est = memory.check_render_memory(scene, s, available=10 * 2**30)
    with pytest.raises(memory.RenderMemoryError, match="lower the resolution"):
        memory.check_render_memory(scene, s, available=est.total)
    avail = memory.available_memory()
    assert avail is None or avail > 0


def test_cli_reports_a_too_large_render(tmp_path, capsys):
    out = tmp_path / "big.exr"
    assert cli.main(["render", "cornell", "-o", str(out), "--quiet", "--resolution", "40000x40000"]) == 1
    assert "memory is available" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_memory_estimate_bounds_a_measured_render():
    """The estimate is not wildly off: a 512x512 render's peak RSS growth (child process) lies within
    [0.3, 2] x the estimate plus the interpreter/Embree baseline."""
    import json
    import subprocess

    code = ("import json; from monte.core import builtin_scenes as scenes, memory; from monte.core.render import render; "
            "from monte.core.settings import RenderSettings as R; import monte.core.accel, monte.core.integrator; "
            "s = scenes.cornell_box((512, 512)); st = R(spp=1, threads=2); "
            "base = memory.peak_rss_bytes(); "
            "e = memory.estimate_render_memory(s, st).total; render(s, st); "
            "peak = memory.peak_rss_bytes(); "
            "print(json.dumps([base, peak, e]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    base, peak, est = json.loads(proc.stdout.strip().splitlines()[-1])
    assert 0.3 * est <= peak - base <= 2.0 * est, (base, peak, est)


# ----------------------------------------------------------------------------------------- cancel
@pytest.mark.parametrize("cancel_at", [1, 2, 3, 5, 8, 13])
def test_cancel_at_any_batch_leaves_a_valid_image(fast_settings, cancel_at):
    calls = {"n": 0}

    def cancel() -> bool:
        calls["n"] += 1
        return calls["n"] > cancel_at

    tiles = []
    result = render(scenes.cornell_box((24, 16)), fast_settings(spp=40, tile_size=8, batch_paths=1024),
                    should_cancel=cancel, on_tile=tiles.append)
    assert result.cancelled
    for arr in (result.color, result.variance, result.albedo, result.normal, result.depth):
        assert np.all(np.isfinite(arr))
    counts = result.sample_count
    assert int(counts.sum()) == result.stats["samples"]
    # 16 samples per batch (1024 paths / 64 tile pixels): a pixel holds whole passes, 0, 16, 32 or 40
    assert set(np.unique(counts)) <= {0, 16, 32, 40}
    unsampled = counts == 0
    assert np.all(result.color[unsampled][:, :3] == 0) and np.all(result.variance[unsampled] == 0)
    assert np.all(result.depth[unsampled] == 1e10)
    assert np.all(result.color[..., 3] == 1)
    # every tile reported to on_tile was complete for the samples it claims
    for t in tiles:
        assert t.samples >= 1 and np.all(np.isfinite(t.color))


def test_cancel_before_the_first_batch_is_a_black_valid_image(fast_settings):
    result = render(scenes.cornell_box((8, 8)), fast_settings(spp=4), should_cancel=lambda: True)
    assert result.cancelled and int(result.sample_count.sum()) == 0
    assert np.all(result.color[..., :3] == 0) and np.all(np.isfinite(result.color))


# ----------------------------------------------------------------------------------------- .blend input
def test_cli_missing_and_corrupt_blend_are_clear_errors(tmp_path, capsys):
    pytest.importorskip("bpy")
    out = tmp_path / "out.exr"
    out.write_bytes(b"previous")
    assert cli.main(["render", str(tmp_path / "missing.blend"), "-o", str(out)]) == 1
    assert "no such .blend file" in capsys.readouterr().err
    corrupt = tmp_path / "corrupt.blend"
    corrupt.write_bytes(b"BLENDER-v500" + os.urandom(100))
    assert cli.main(["render", str(corrupt), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "corrupt.blend" in err and "Traceback" not in err
    junk = tmp_path / "junk.blend"
    junk.write_text("not a blend")
    assert cli.main(["render", str(junk), "-o", str(out)]) == 1
    assert "is not a Blender file" in capsys.readouterr().err
    assert out.read_bytes() == b"previous"


@pytest.mark.blender
@pytest.mark.parametrize("problem", ["missing file", "not an image"])
def test_bad_texture_file_warns_falls_back_and_renders(tmp_path, capfd, problem):
    """A texture whose file is missing or not an image: a warning naming material, node, image and path, the
    Image Texture node's fallback colour (Cycles' missing-texture magenta), and the render proceeds (the plane
    under the white world shows albedo (1, 0, 1))."""
    bpy = pytest.importorskip("bpy")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import blender_fixtures as bf
    from monte.addon.headless import render_blend_file

    scene = bf.plane_under_world(albedo=0.5, world=1.0, resolution=(8, 8))
    path = tmp_path / "tex.png"
    if problem == "not an image":
        path.write_text("this is a text file, not a PNG")
    mat = bf.node_material("Textured", "ShaderNodeBsdfDiffuse")
    nodes = mat.node_tree.nodes
    shader = nodes["Diffuse BSDF"]
    shader.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    tex = nodes.new("ShaderNodeTexImage")
    image = bpy.data.images.new("Broken", 4, 4)
    image.source = "FILE"
    image.filepath = str(path)
    tex.image = image
    mat.node_tree.links.new(tex.outputs["Color"], shader.inputs["Color"])
    plane = bpy.data.objects["plane"]
    plane.data.materials.clear()
    plane.data.materials.append(mat)
    plane.data.uv_layers.new(name="UVMap")
    blend = tmp_path / "broken_texture.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    log: list[str] = []
    out = tmp_path / "out.exr"
    render_blend_file(blend, out, {"spp": 4}, log=log.append)
    text = "\n".join(log) + capfd.readouterr().out  # the engine reports export warnings to Blender's log
    assert f"warning: material 'Textured': node 'Image Texture': image 'Broken' ({str(path)!r}) could not be " \
           "read" in text, text
    assert "missing-texture colour (magenta)" in text, text
    rgb = exr.read_rgb(out)
    assert np.all(np.isfinite(rgb))
    assert np.allclose(rgb.reshape(-1, 3).mean(axis=0), (1.0, 0.0, 1.0), atol=0.02)
