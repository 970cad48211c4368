"""Files, the command line, the camera and scale invariance."""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from monte import cli
from monte.core import builtin_scenes as scenes
from monte.core import exr, metrics
from monte.core.camera import camera_rays
from monte.core.render import render
from monte.core.scene import Camera


def test_exr_round_trip_with_named_channels(tmp_path):
    color = np.random.default_rng(0).random((5, 7, 4)).astype(np.float32)
    path = exr.write_exr(tmp_path / "a.exr", exr.image_channels(color, variance=color[..., :3],
                                                                 depth=color[..., 0]))
    channels = exr.read_exr(path)
    assert set(channels) == {"R", "G", "B", "A", "variance.R", "variance.G", "variance.B", "Z"}
    np.testing.assert_array_equal(channels["G"], color[..., 1])
    np.testing.assert_array_equal(exr.read_rgb(path), color[..., :3])
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's 0600


def test_multipart_exr_reads_every_part(tmp_path):
    import OpenEXR

    def header():  # one dict per part: Part stores its name in the header it is given
        return {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    parts = [OpenEXR.Part(header(), {"R": np.zeros((2, 3), np.float32)}, "ViewLayer.Combined"),
             OpenEXR.Part(header(), {"Z": np.full((2, 3), 7.0, np.float32)}, "ViewLayer.Depth"),
             OpenEXR.Part(header(), {"R": np.ones((2, 3), np.float32)}, "ViewLayer.Albedo")]
    OpenEXR.File(parts).write(str(tmp_path / "mp.exr"))
    channels = exr.read_exr(tmp_path / "mp.exr")
    assert sorted(channels) == ["R", "ViewLayer.Albedo.R", "Z"]
    assert channels["Z"][0, 0] == 7.0 and channels["ViewLayer.Albedo.R"][0, 0] == 1.0


def test_failed_write_keeps_the_existing_file_and_leaves_no_temp(tmp_path, monkeypatch):
    target = tmp_path / "keep.exr"
    target.write_bytes(b"precious")

    def explode(self, path):
        with open(path, "wb") as f:
            f.write(b"half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(exr.OpenEXR.File, "write", explode)
    with pytest.raises(exr.OutputError, match="No space left"):
        exr.write_exr(target, {"R": np.zeros((2, 2), np.float32)})
    assert target.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.exr"]


def test_write_into_missing_folder_is_a_clear_error(tmp_path):
    with pytest.raises(exr.OutputError, match="does not exist"):
        exr.write_exr(tmp_path / "nope" / "a.exr", {"R": np.zeros((2, 2), np.float32)})


def test_png_preview_is_a_valid_png(tmp_path):
    path = exr.write_png(tmp_path / "p.png", np.full((3, 4, 3), 0.5, np.float32))
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    assert int.from_bytes(data[16:20], "big") == 4 and int.from_bytes(data[20:24], "big") == 3


def test_cli_renders_a_builtin_scene(tmp_path, capsys):
    out = tmp_path / "c.exr"
    code = cli.main(["render", "furnace", "-o", str(out), "--spp", "16", "--resolution", "8x6", "--quiet",
                     "--filter", "box", "--filter-width", "1", "--max-bounces", "0", "--variance"])
    assert code == 0
    rgb = exr.read_rgb(out)
    assert rgb.shape == (6, 8, 3)
    # furnace: albedo 0.5, Le 1, max_bounces 0 -> Le (1 + a) = 1.5 per pixel on average, within 4 standard errors
    # of the image mean (from the file's variance channels); at 16 spp that is ~0.6 %, so a 1 % error fails
    channels = exr.read_exr(out)
    sigma = np.array([np.sqrt(channels[f"variance.{c}"].astype(np.float64).sum()) / rgb[..., 0].size for c in "RGB"])
    assert np.all(4 * sigma < 0.01 * 1.5)
    mean = rgb.reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(mean - 1.5) <= 4 * sigma)
    for wrong in (1.01, 0.99):  # the control: the closed form 1 % off fails
        assert np.any(np.abs(mean - wrong * 1.5) > 4 * sigma), (wrong, mean, sigma)
    assert (tmp_path / "c.png").is_file()
    assert "wrote" in capsys.readouterr().out
    # without --variance: one Sobol sequence per pixel, and no variance channels (the image is another one)
    plain = tmp_path / "plain.exr"
    assert cli.main(["render", "furnace", "-o", str(plain), "--spp", "16", "--resolution", "8x6", "--quiet",
                     "--filter", "box", "--filter-width", "1", "--max-bounces", "0", "--no-png"]) == 0
    plain_channels = exr.read_exr(plain)
    assert set(plain_channels) == set(channels) - {"variance.R", "variance.G", "variance.B"}
    assert not np.array_equal(plain_channels["R"], channels["R"])
    assert np.all(np.abs(exr.read_rgb(plain).reshape(-1, 3).mean(axis=0) - 1.5) <= 4 * sigma)


def test_cli_list_and_errors(tmp_path, capsys):
    assert cli.main(["render", "--list"]) == 0
    assert "cornell" in capsys.readouterr().out
    assert cli.main(["render", "nosuchscene", "-o", str(tmp_path / "x.exr")]) == 1
    assert "unknown built-in scene 'nosuchscene'" in capsys.readouterr().err
    assert cli.main(["render", "furnace", "-o", str(tmp_path / "x.exr"), "--spp", "-3"]) == 1
    assert "samples per pixel" in capsys.readouterr().err
    assert cli.main(["render", "furnace", "-o", str(tmp_path / "x.exr"), "--file-passes"]) == 2
    assert "--file-passes is for a .blend" in capsys.readouterr().err
    assert not (tmp_path / "x.exr").exists()


def test_python_dash_m_monte_works():
    proc = subprocess.run([sys.executable, "-m", "monte", "render", "--list"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "cornell" in proc.stdout


def test_camera_frame_follows_blender_sensor_fit_and_shift():
    cam = Camera(np.eye(4), resolution=(200, 100), lens=50.0, sensor_width=36.0, shift_x=0.1)
    xmin, xmax, ymin, ymax = cam.frame()
    # AUTO fit on a landscape image: the width spans the 36 mm sensor at 50 mm, shift in units of the width.
    assert xmax - xmin == pytest.approx(36 / 50)
    assert ymax - ymin == pytest.approx(18 / 50)
    assert (xmin + xmax) / 2 == pytest.approx(0.1 * 36 / 50)
    portrait = Camera(np.eye(4), resolution=(100, 200), lens=50.0, sensor_width=36.0)
    _, _, ymin, ymax = portrait.frame()
    assert ymax - ymin == pytest.approx(36 / 50)
    ortho = Camera(np.eye(4), resolution=(100, 50), kind="ORTHO", ortho_scale=4.0)
    xmin, xmax, ymin, ymax = ortho.frame()
    assert (xmax - xmin, ymax - ymin) == pytest.approx((4.0, 2.0))


def test_camera_centre_ray_looks_down_minus_z_and_fov_is_exact():
    cam = Camera.look_at((0, 0, 0), (0, 1, 0), horizontal_fov=math.radians(60), resolution=(64, 64))
    rays = camera_rays(cam, np.array([32.0, 0.0]), np.array([32.0, 32.0]))
    np.testing.assert_allclose(rays.directions[0], [0, 1, 0], atol=1e-6)
    # The left edge of the frame is at half the horizontal field of view.
    assert math.degrees(math.acos(rays.directions[1] @ np.array([0, 1, 0]))) == pytest.approx(30.0, abs=1e-4)


def _transformed_cornell(scale: float, offset: float):
    scene = scenes.cornell_box((24, 24))
    for mesh in scene.meshes:
        mesh.vertices = mesh.vertices * scale + offset
    scene.camera.matrix_world = scene.camera.matrix_world.copy()
    scene.camera.matrix_world[:3, 3] = scene.camera.matrix_world[:3, 3] * scale + offset
    return scene


@pytest.mark.parametrize("scale, offset", [(1e-3, 0.0), (1e4, 0.0), (1.0, 1e5)])
def test_cornell_box_renders_the_same_at_any_scale_and_far_from_the_origin(fast_settings, scale, offset):
    settings = fast_settings(spp=16, filter_type="blackman-harris", filter_width=1.5)
    canonical = render(scenes.cornell_box((24, 24)), settings)
    moved = render(_transformed_cornell(scale, offset), settings)
    assert moved.stats["nonfinite_samples"] == 0
    # Same random numbers, same paths: the images agree to far below the noise (no self-intersection speckle).
    diff = np.abs(moved.color[..., :3] - canonical.color[..., :3])
    assert np.median(diff) < 1e-3
    m, c = metrics.channel_means(moved.color), metrics.channel_means(canonical.color)
    sigma = metrics.channel_mean_sigma(canonical.variance)
    assert np.all(np.abs(m - c) < 4 * sigma + 1e-3), (m, c)


def test_a_subcommands_arguments_are_built_when_it_is_used(capsys):
    """Each subcommand's arguments are added when that subcommand parses or prints its help (a `monte render`
    process built every subcommand's before, the lab's options too): parsing `render` builds render's alone,
    and every other subcommand still parses and prints its help with its own options."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    args = parser.parse_args(["render", "scene.blend", "-o", "out.exr", "--spp", "1"])
    assert args.func is cli.cmd_render and args.spp == 1 and args.output == "out.exr"
    built = {name for name, p in sub.choices.items() if p.add_arguments is None}
    assert built == {"render"}
    assert any("--max-bounces" in a.option_strings for a in sub.choices["render"]._actions)
    assert not any("--reference" in a.option_strings for a in sub.choices["bench"]._actions)

    args = parser.parse_args(["crosscheck", "x.blend", "-o", "out", "--spp", "4"])
    assert args.func is cli.cmd_crosscheck and args.spp == 4
    with pytest.raises(SystemExit):
        parser.parse_args(["bench", "--help"])
    assert "--reference" in capsys.readouterr().out
    assert "stress" in parser.format_help() and sub.choices["stress"].add_arguments is not None
    assert "--quick" in sub.choices["stress"].format_help()
