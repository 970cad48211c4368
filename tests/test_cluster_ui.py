"""F12 on a Dask cluster from Blender (Render Properties > Cluster): the engine exports the frame, renders it on a
real distributed.LocalCluster (2 worker processes, one thread each) and writes the same image bits as a local
render, tile by tile as units come back; Esc cancels the units; an unreachable scheduler fails the render with
core.distributed's message and renders nothing locally; Test Connection reports the workers or the error."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
distributed = pytest.importorskip("distributed")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import engine as engine_mod  # noqa: E402
from monte.addon.engine import render_with_operator  # noqa: E402
from monte.core.distributed import ClusterProgress  # noqa: E402

pytestmark = pytest.mark.blender
Engine = engine_mod.MonteRenderEngine
UNREACHABLE = "tcp://127.0.0.1:9"  # the discard port: nothing listens there


@pytest.fixture(scope="module")
def scheduler():
    """A LocalCluster's scheduler address (tcp://127.0.0.1:PORT) with 2 worker processes of one thread."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster:
        with distributed.Client(cluster) as client:
            yield cluster.scheduler_address, client


def small_cornell(resolution=(24, 16), spp=8):
    """The Cornell box cut into 8x8 tiles (6 at 24x16), one sample pass per tile: 6 units of one tile each."""
    scene = bf.cornell_box(resolution)
    monte = scene.monte
    monte.samples, monte.seed, monte.batch_paths, monte.tile_size, monte.threads = spp, 3, 1024, 8, 1
    return scene


def render_still(scene, tmp_path, name):
    """F12 written as a float multilayer EXR; its channels."""
    bf.render_still_exr(scene, tmp_path / f"{name}.exr")
    return bf.read_exr_layers(tmp_path / f"{name}.exr")


def test_f12_on_the_cluster_writes_the_local_image_bits_tile_by_tile(scheduler, tmp_path, patch_engine):
    address, _ = scheduler
    scene = small_cornell()
    scene.view_layers[0].use_pass_z = True
    local = render_still(scene, tmp_path, "local")

    writes = []
    original_write = Engine._write

    def record_write(self, x, y, w, h, *rest):
        writes.append((x, y, w, h))
        original_write(self, x, y, w, h, *rest)

    patch_engine("_write", record_write)
    scene.monte.use_cluster = True
    scene.monte.cluster_address = address
    progress = []
    captured = render_with_operator(scene, on_progress=progress.append)
    on_cluster = render_still(scene, tmp_path, "cluster")
    assert sorted(local) == sorted(on_cluster)
    for name in local:
        assert np.array_equal(local[name], on_cluster[name]), name
    assert local["ViewLayer.Combined.R"].max() > 0

    # Each of the 6 tiles was written as its unit came back, then the whole frame once (per render).
    tile_writes = [wr for wr in writes[:len(writes) // 2] if wr[2:] != (24, 16)]
    assert sorted(tile_writes) == sorted((x, y, 8, 8) for x in (0, 8, 16) for y in (0, 8))
    assert writes[len(writes) // 2 - 1] == (0, 0, 24, 16)
    # Progress: units done up to all 6, the 2 workers seen.
    assert progress and all(isinstance(p, ClusterProgress) for p in progress)
    assert [p.units_total for p in progress] == [6] * len(progress)
    assert progress[-1].units_done == 6 and progress[-1].fraction == 1.0 and progress[-1].workers == 2
    assert "Unit 6/6 | 2 workers" in progress[-1].stats_line()
    (layer, result, region, size), = captured
    assert result.stats["units"] == 6 and result.stats["workers"] == 2 and region is None and size == (24, 16)


def test_esc_cancels_the_units_and_keeps_the_tiles_done(scheduler, tmp_path, patch_engine):
    address, client = scheduler
    # 12 tiles of 16x16 at 96 spp: 6 units of 2 tiles (3 per worker thread, one after another), each long
    # enough that the client sees the first back well before the last could be done.
    scene = small_cornell((64, 48), spp=96)
    scene.monte.tile_size = 16
    scene.monte.use_cluster = True
    scene.monte.cluster_address = address
    events = []
    original_progress = Engine._progress

    def progress(self, p):
        events.append(p)
        original_progress(self, p)

    patch_engine("_progress", progress)
    patch_engine("_cancel_requested", lambda self: bool(events))  # Esc once the first unit is back
    image = render_still(scene, tmp_path, "cancelled")["ViewLayer.Combined.R"]
    assert len(events) == 1 and events[0].units_done < events[0].units_total == 6
    tiles_lit = sum(bool(image[y:y + 16, x:x + 16].max() > 0) for y in range(0, 48, 16) for x in range(0, 64, 16))
    assert 2 <= tiles_lit < 12 and tiles_lit == 2 * events[0].units_done
    # The scheduler forgets every unit: the ones not started never run.
    deadline = time.monotonic() + 60
    while _scheduler_units(client) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _scheduler_units(client) == []


def _scheduler_units(client) -> list[str]:
    return client.run_on_scheduler(
        lambda dask_scheduler: [str(k) for k in dask_scheduler.tasks if "monte-unit" in str(k)])


def test_a_blend_saved_with_the_cluster_on_renders_there_headless(scheduler, tmp_path):
    """`monte render scene.blend` / `blender -b -E MONTE` go through the engine: the saved Cluster settings
    apply, and the EXR holds the local render's bits."""
    from monte.addon.headless import render_blend_file
    from monte.core.exr import read_exr

    scene = small_cornell()
    local = render_with_operator(scene)[0][1]
    scene.monte.use_cluster = True
    scene.monte.cluster_address = scheduler[0]
    blend = tmp_path / "on_cluster.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    progress = []
    render_blend_file(blend, tmp_path / "out.exr", log=lambda _m: None, on_progress=progress.append)
    written = read_exr(tmp_path / "out.exr")
    for c, name in enumerate("RGB"):
        assert np.array_equal(written[name], local.color[..., c]), name
    assert progress[-1].units_done == progress[-1].units_total == 6


def test_unreachable_scheduler_fails_the_render_and_renders_nothing_here(monkeypatch):
    import monte.core.render

    def no_local_render(*_a, **_k):
        raise AssertionError("a local render ran instead of the cluster")

    monkeypatch.setattr(monte.core.render, "render", no_local_render)
    scene = small_cornell()
    scene.monte.use_cluster = True
    scene.monte.cluster_address = UNREACHABLE
    scene.monte.cluster_timeout = 1.0
    with pytest.raises(RuntimeError) as err:
        render_with_operator(scene)
    assert str(err.value).startswith(f"Monte: cluster render failed: cannot reach the Dask scheduler at "
                                     f"{UNREACHABLE} within 1 s: ")


@pytest.mark.parametrize("setting, message", [
    ("empty address", "Monte: cluster render failed: Render on a Dask cluster is on but the scheduler address is "
                      "empty (tcp://host:8786, or local:N for N worker processes on this machine)"),
    ("no scheme", "Monte: cluster render failed: a Dask scheduler address looks like tcp://host:8786, "
                  "got 'localhost:8786'"),
])
def test_bad_cluster_settings_are_exact_errors(setting, message, scheduler):
    scene = small_cornell()
    scene.monte.use_cluster = True
    scene.monte.cluster_address = scheduler[0]
    if setting == "empty address":
        scene.monte.cluster_address = "  "
    elif setting == "no scheme":
        scene.monte.cluster_address = "localhost:8786"
    with pytest.raises(RuntimeError) as err:
        render_with_operator(scene)
    assert str(err.value) == message


def test_a_render_region_goes_to_the_cluster_alone_and_equals_the_local_region(scheduler):
    """Render Region x 0.25-0.75 of 24x16: pixels 6-18, 4 of the frame's 6 tiles of 8x8 (8+4 wide, 2 rows), one
    unit each; the region's image is the local region render's bit for bit."""
    scene = small_cornell()
    scene.view_layers[0].monte.use_pass_variance = True  # the error estimate's groups cross the cluster too
    scene.render.use_border = True
    scene.render.border_min_x, scene.render.border_max_x = 0.25, 0.75
    (_, local, local_region, _), = render_with_operator(scene)
    scene.monte.use_cluster = True
    scene.monte.cluster_address = scheduler[0]
    (_, remote, region, _), = render_with_operator(scene)
    assert region == local_region == (6, 0, 12, 16) and remote.color.shape == (16, 12, 4)
    assert remote.stats["units"] == 4 and remote.stats["region"] == [6, 0, 12, 16]
    assert local.variance is not None and remote.variance is not None
    for name in ("color", "variance", "sample_count"):
        assert np.array_equal(getattr(remote, name), getattr(local, name)), name
    assert local.color[..., :3].max() > 0


def test_data_passes_arrive_from_the_cluster_with_the_local_bits(scheduler, tmp_path):
    """Mist, Position, UV, the indices and Cryptomatte (View Layer > Passes > Data) on F12 on the cluster: every
    layer of Blender's EXR, the Cryptomatte manifest included, equals the local render's; 32 spp is 2 sample
    passes per 8x8 tile, so each tile is merged from 2 units (one from sample 0, one past it)."""
    scene = small_cornell(spp=32)
    layer = scene.view_layers[0]
    for flag in ("use_pass_mist", "use_pass_position", "use_pass_uv", "use_pass_object_index",
                 "use_pass_material_index", "use_pass_cryptomatte_object", "use_pass_cryptomatte_material"):
        setattr(layer, flag, True)
    local = render_still(scene, tmp_path, "local")
    scene.monte.use_cluster = True
    scene.monte.cluster_address = scheduler[0]
    captured = []
    engine_mod.result_listeners.append(lambda *args: captured.append(args))
    try:
        on_cluster = render_still(scene, tmp_path, "cluster")
    finally:
        engine_mod.result_listeners.pop()
    (_, result, _, _), = captured
    assert result.stats["units"] == 12 and result.stats["workers"] == 2
    assert {"ViewLayer.Mist.Z", "ViewLayer.Position.X", "ViewLayer.UV.U", "ViewLayer.Object Index.X",
            "ViewLayer.Material Index.X", "ViewLayer.CryptoObject00.r",
            "ViewLayer.CryptoMaterial00.g"} <= set(on_cluster)
    assert sorted(local) == sorted(on_cluster)
    for name in local:
        assert np.array_equal(local[name], on_cluster[name]), name
    assert np.ptp(on_cluster["ViewLayer.Mist.Z"]) > 0 and on_cluster["ViewLayer.CryptoObject00.g"].max() > 0
    assert set(result.cryptomatte) == {"CryptoObject", "CryptoMaterial"} and result.cryptomatte["CryptoObject"]


def test_an_animation_keeps_one_connection_for_all_its_frames(scheduler, tmp_path):
    """An animation rendered from Blender (render_init .. render_complete) connects once; every frame equals the
    local render of that frame bit for bit; the connection is closed when the animation ends."""
    from monte.addon import cluster as cluster_mod

    scene = small_cornell()
    scene.frame_start, scene.frame_end = 1, 3
    scene.monte.use_animated_seed = True  # frames differ: a frame cannot pass for another
    scene.render.image_settings.file_format = "OPEN_EXR"
    frames = {}

    def capture(name, result, region, size):
        frames.setdefault(name, []).append(result)

    engine_mod.result_listeners.append(capture)
    try:
        scene.render.filepath = str(tmp_path / "local_")
        bpy.ops.render.render(animation=True, scene=scene.name)
        local = frames.pop("ViewLayer")
        scene.monte.use_cluster = True
        scene.monte.cluster_address = scheduler[0]
        scene.render.filepath = str(tmp_path / "cluster_")
        before = cluster_mod._job.connects
        bpy.ops.render.render(animation=True, scene=scene.name)
        remote = frames.pop("ViewLayer")
    finally:
        engine_mod.result_listeners.remove(capture)
    assert cluster_mod._job.connects - before == 1
    assert cluster_mod._job.client is None and not cluster_mod._job.in_job
    assert len(local) == len(remote) == 3
    for a, b in zip(local, remote):
        assert np.array_equal(a.color, b.color) and b.stats["units"] == 6
    assert not np.array_equal(local[0].color, local[1].color)
    assert sorted(p.name for p in tmp_path.glob("cluster_*.exr")) == [f"cluster_{f:04d}.exr" for f in (1, 2, 3)]


def test_test_connection_reports_the_workers_or_the_exact_error(scheduler):
    address, _ = scheduler
    scene = small_cornell()
    scene.monte.cluster_address = address
    assert bpy.ops.monte.cluster_test() == {"FINISHED"}
    assert scene.monte.cluster_status == f"Connected to {address}: 2 workers, 2 threads"
    scene.monte.cluster_address = UNREACHABLE
    scene.monte.cluster_timeout = 1.0
    with pytest.raises(RuntimeError, match=f"Monte: cannot reach the Dask scheduler at {UNREACHABLE} within 1 s"):
        bpy.ops.monte.cluster_test()
    assert scene.monte.cluster_status.startswith(f"Failed: cannot reach the Dask scheduler at {UNREACHABLE}")


_F12_AS_AN_EXTENSION = """
import importlib, sys
sys.path.insert(0, {path!r})
sys.modules["monte"] = None  # as in Blender, where the extension is importable only as bl_ext.<repository>.monte
import bpy
import numpy as np
ext = importlib.import_module("fakeext.monte")
ext.register()
scene = importlib.import_module("fakeext.monte.lab.bpy_scenes").cornell_box((24, 16))
m = scene.monte
m.samples, m.seed, m.batch_paths, m.tile_size, m.threads = 8, 3, 1024, 8, 1
m.use_cluster, m.cluster_address = True, {address!r}
(_, result, _, _), = ext.addon.engine.render_with_operator(scene)
np.save({out!r}, result.color)
print("UNITS", result.stats["units"], type(result).__module__)
"""


def test_f12_on_the_cluster_from_monte_loaded_as_a_blender_extension(scheduler, tmp_path):
    """Blender imports the extension as bl_ext.<repository>.monte, which the workers cannot import: the scene
    and units still reach them (as monte.core.*, the name they import) and the image is the local one."""
    import subprocess

    import monte

    address, _ = scheduler
    (tmp_path / "fakeext").mkdir()
    (tmp_path / "fakeext" / "__init__.py").write_text("")
    (tmp_path / "fakeext" / "monte").symlink_to(Path(monte.__file__).resolve().parent, target_is_directory=True)
    out = tmp_path / "color.npy"
    script = _F12_AS_AN_EXTENSION.format(path=str(tmp_path), address=address, out=str(out))
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "UNITS 6 monte.core.render" in run.stdout
    local = render_with_operator(small_cornell())[0][1]
    assert np.array_equal(np.load(out), local.color)
