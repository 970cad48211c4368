"""`monte bench --vs cycles` end to end with the real bpy and Cycles at a tiny size, and the bench scenes."""

from __future__ import annotations

import json

import pytest

bpy = pytest.importorskip("bpy")

from monte.cli import main  # noqa: E402

pytestmark = pytest.mark.blender


@pytest.mark.parametrize("name, triangles, instances, lights", [
    ("cornell", 10252, 8, 0), ("interior", 182, 16, 2), ("glass", 11868, 11, 1), ("instances", 327682, 4097, 1),
    ("hdri", 14114, 4, 0), ("textured", 1294, 3, 1)])
def test_bench_scenes_export(name, triangles, instances, lights):
    from monte.lab import bpy_scenes
    from monte.addon.export import export_scene

    scene = bpy_scenes.build(name, (24, 16))
    assert (scene.render.resolution_x, scene.render.resolution_y) == (24, 16)
    core_scene, stats = export_scene(bpy.context.evaluated_depsgraph_get())
    assert (stats.triangles, stats.instances, stats.lights) == (triangles, instances, lights)
    assert core_scene.warnings == []


def test_the_textured_bench_scene_renders_in_the_fused_kernel():
    """Its floor (Noise into a Color Ramp), crate (Image Textures, Normal Map) and ball (Noise into Bump: ray
    differentials) are all node programs the fused path kernel evaluates (core.fused_tracer.supports)."""
    from monte.addon.export import export_scene
    from monte.core.fused_tracer import supports
    from monte.core.integrator import PathTracer
    from monte.core.render import prepare_scene
    from monte.core.sampling import make_sampler
    from monte.core.settings import RenderSettings
    from monte.lab import bpy_scenes

    bpy_scenes.build("textured", (24, 16))
    core_scene, _stats = export_scene(bpy.context.evaluated_depsgraph_get())
    settings = RenderSettings(spp=4, threads=1).validate()
    ps, accel = prepare_scene(core_scene, settings)
    tracer = PathTracer(ps, accel, settings, make_sampler(settings.sampler, settings.seed, settings.spp, 4))
    assert ps.shading is not None and ps.shading.needs_differentials  # the ball's Bump
    assert ps.vector_needs.tangents.any()  # the crate's Normal Map
    assert supports(tracer) is None and tracer.fused is not None
    bpy_scenes.reset()


@pytest.mark.parametrize("name", ["textured", "hdri"])
def test_bench_scene_images_survive_a_saved_blend(name, tmp_path):
    """`--whole-process` renders the bench scene saved as a .blend against a reference rendered in memory: every
    image must read back as it was made (a float sRGB image did not: the crate's colour moved by up to 0.29, so
    Monte's and Cycles' whole processes were both 0.073 RMSE from the textured reference, on top of their noise)."""
    import numpy as np
    from monte.lab import bpy_scenes

    bpy_scenes.build(name, (24, 16))
    made = {}
    for image in bpy.data.images:
        if image.size[0] and image.users:
            pixels = np.empty(len(image.pixels), np.float32)
            image.pixels.foreach_get(pixels)
            made[image.name] = pixels
    assert made or name == "hdri"
    path = tmp_path / f"{name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    for image_name, pixels in made.items():
        image = bpy.data.images[image_name]
        read = np.empty(len(image.pixels), np.float32)
        image.pixels.foreach_get(read)
        assert np.array_equal(read, pixels), (image_name, float(np.abs(read - pixels).max()))
    bpy_scenes.reset()


def test_bench_vs_cycles_tiny_end_to_end(tmp_path, capsys):
    refs, out = tmp_path / "refs", tmp_path / "out"
    args = ["bench", "--vs", "cycles", "--scene", "cornell", "--resolution", "32x32", "--ladder", "2,4",
            "--reference-dir", str(refs), "-o", str(out), "--reference-spp", "8", "--reference-seeds", "2",
            "--threads", "2"]
    assert main(args) == 0
    report = json.loads((out / "bench.json").read_text())
    (scene,) = report["scenes"]
    assert scene["scene"] == "cornell" and scene["resolution"] == [32, 32] and scene["threads"] == 2
    assert scene["reference"]["source"] == "rendered" and scene["reference"]["own_rmse"] > 0
    # Interleaved: Monte 2, Cycles 2, Monte 4, Cycles 4.
    assert [(p["renderer"], p["rung"]) for p in scene["points"]] == [
        ("monte", 2), ("cycles", 2), ("monte", 4), ("cycles", 4)]
    for p in scene["points"]:
        assert p["seconds"] > 0 and p["rmse"] > p["rmse_corrected"] > 0
        assert p["efficiency"] == pytest.approx(1 / (p["seconds"] * p["rmse_corrected"] ** 2))
    # Same scene, both unbiased, similar per-sample noise: equal-spp errors are close (a flipped or
    # mismatched image would be far off). Both renderers are deterministic at a fixed seed.
    for m, c in zip(scene["points"][0::2], scene["points"][1::2]):
        assert 0.6 < m["rmse_corrected"] / c["rmse_corrected"] < 1.6
    assert scene["equal_error"]["ratio"] > 0
    png = out / "bench_vs_cycles.png"
    assert png.read_bytes()[:4] == b"\x89PNG"
    (ref_file,) = refs.glob("cornell-32x32-*.exr")
    stamp = ref_file.stat().st_mtime_ns
    assert "rendering with Cycles" in capsys.readouterr().out

    assert main([*args[:8], "2", *args[9:]]) == 0  # ladder 2 only; the reference is reused
    report = json.loads((out / "bench.json").read_text())
    assert report["scenes"][0]["reference"]["source"] == "cache"
    assert ref_file.stat().st_mtime_ns == stamp
    assert "rendering with Cycles" not in capsys.readouterr().out


def test_bench_vs_cycles_errors(tmp_path):
    with pytest.raises(ValueError, match="reference-dir"):
        from monte.lab.bench_cycles import run_from_args
        from monte.cli import build_parser

        run_from_args(build_parser().parse_args(["bench", "--vs", "cycles", "-o", str(tmp_path)]), {})
    assert main(["bench", "--vs", "cycles", "--reference-dir", str(tmp_path), "-o", str(tmp_path),
                 "--spp", "8"]) == 1  # --spp is the ladder's job: a clear error, not a silent override


def test_bench_vs_cycles_time_ladder(tmp_path):
    out = tmp_path / "out"
    assert main(["bench", "--vs", "cycles", "--resolution", "16x16", "--time-ladder", "0.3",
                 "--reference-dir", str(tmp_path / "refs"), "-o", str(out), "--reference-spp", "8",
                 "--reference-seeds", "2", "--threads", "2"]) == 0
    (scene,) = json.loads((out / "bench.json").read_text())["scenes"]
    assert scene["ladder_kind"] == "seconds"
    monte, cycles = scene["points"]
    # Each renderer stopped at its budget, not at the 65536 spp asked for (16x16 pixels).
    assert 0 < monte["samples"] < 65536 * 256
    assert monte["rmse"] > 0 and cycles["rmse"] > 0  # (corrected may be 0: the tiny reference is noisier)

@pytest.mark.skipif(__import__("monte.core.denoise", fromlist=["x"]).denoiser_status() is not None,
                    reason="pyoidn has no wheel for this platform")
def test_bench_vs_cycles_denoised(tmp_path, capsys):
    """--denoise: both renderers denoised (errors below the noisy ones of the same rung), and the report holds
    the denoising cost and the times for target errors."""
    refs, out = tmp_path / "refs", tmp_path / "out"
    common = ["bench", "--vs", "cycles", "--scene", "cornell", "--resolution", "32x32", "--ladder", "4,16",
              "--reference-dir", str(refs), "--reference-spp", "64", "--reference-seeds", "2", "--threads", "2"]
    assert main([*common, "-o", str(out / "noisy")]) == 0
    assert main([*common, "-o", str(out / "denoised"), "--denoise", "--denoise-quality", "fast"]) == 0
    noisy = json.loads((out / "noisy" / "bench.json").read_text())["scenes"][0]
    denoised = json.loads((out / "denoised" / "bench.json").read_text())["scenes"][0]
    # Both renderers are deterministic at a fixed seed, so an undenoised image would give the same error; at
    # 4 spp denoising cuts it (measured: Monte 0.45 -> 0.31, Cycles 0.37 -> 0.30); at 16 spp, 32x32, the
    # reference's own noise (2 x 64 spp) dominates.
    for n, d in zip(noisy["points"], denoised["points"]):
        assert (n["renderer"], n["rung"]) == (d["renderer"], d["rung"])
        assert d["rmse"] != n["rmse"]
        if n["rung"] == 4:
            assert d["rmse"] < 0.9 * n["rmse"]
    report = denoised["denoise"]
    assert report["quality"] == "fast" and report["monte_seconds_per_megapixel"] > 0
    assert len(report["target_rmse"]) == 3 and set(report["seconds_for_target"]) == {"monte", "cycles"}
    assert "denoising (fast): Monte" in capsys.readouterr().out

def test_bench_whole_process_tiny_end_to_end(tmp_path):
    """Both renderers as whole processes on the same saved .blend: a fair pair (same samples, filter, bounces),
    so their errors against the reference are alike, and the efficiency is taken with the process's time."""
    out = tmp_path / "out"
    assert main(["bench", "--vs", "cycles", "--whole-process", "--scene", "cornell", "--resolution", "16x16",
                 "--spp", "8", "--repeats", "1", "--reference-dir", str(tmp_path / "refs"), "-o", str(out),
                 "--reference-spp", "16", "--reference-seeds", "2", "--threads", "2"]) == 0
    (scene,) = json.loads((out / "bench_whole_process.json").read_text())["scenes"]
    assert scene["spp"] == 8 and scene["resolution"] == [16, 16] and scene["repeats"] == 1
    monte, cycles = scene["renderers"]["monte"], scene["renderers"]["cycles"]
    for r in (monte, cycles):
        assert r["seconds"] == min(r["seconds_all"]) > 0 and len(r["seconds_all"]) == 1
        assert r["efficiency"] == pytest.approx(1 / (r["seconds"] * r["rmse_corrected"] ** 2))
        assert r["seconds_median"] == r["seconds_all"][0] and len(r["cpu_seconds_all"]) == 1
        assert 0 < r["cpu_seconds_median"] == r["cpu_seconds_all"][0]  # the child's own CPU time was counted
        assert r["efficiency_median"] == pytest.approx(1 / (r["seconds_median"] * r["rmse_corrected"] ** 2))
    assert 0.5 < monte["rmse_corrected"] / cycles["rmse_corrected"] < 2.0  # same scene, same samples
    assert scene["monte_over_cycles_efficiency"] == pytest.approx(monte["efficiency"] / cycles["efficiency"])


def test_bench_whole_process_renderers_choose_their_own_kernel_level(tmp_path, monkeypatch):
    """The renderer processes do not inherit the NUMBA_* values this process's Monte wrote into its environment
    (a Monte of another checkout would run this one's kernel CPU level), but keep the user's own."""
    from monte.core import jit_cache
    from monte.lab.bench_whole_process import _process_env

    monkeypatch.setattr(jit_cache, "NUMBA_ENVIRONMENT_WRITTEN", {"MONTE_TEST_WRITTEN": "by-monte"})
    monkeypatch.setenv("MONTE_TEST_WRITTEN", "by-monte")
    monkeypatch.delenv("PYTHONPYCACHEPREFIX", raising=False)
    env = _process_env(tmp_path)
    assert "MONTE_TEST_WRITTEN" not in env and env["PYTHONPYCACHEPREFIX"] == str(tmp_path / "pycache")
    monkeypatch.setenv("MONTE_TEST_WRITTEN", "by-the-user")
    assert _process_env(tmp_path)["MONTE_TEST_WRITTEN"] == "by-the-user"


def test_bench_whole_process_errors(tmp_path):
    base = ["bench", "--vs", "cycles", "--whole-process", "--reference-dir", str(tmp_path), "-o", str(tmp_path)]
    assert main([*base, "--ladder", "8,16"]) == 1  # renders at --spp: a ladder is refused, not ignored
    assert main([*base, "--repeats", "0"]) == 1
    assert main([*base, "--filter", "box"]) == 1  # the filter is fixed for a fair comparison
