"""A render split into work units on a Dask cluster (core.distributed) equals the one-machine render bit for bit.

The cluster tests run a real distributed.LocalCluster of 2 worker processes (one thread each) on tiny Cornell
boxes; the split is forced into several tiles and sample passes (small tiles and batches) so that a unit that
starts past sample 0 and a merge across units really happen.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from distributed import Client, LocalCluster

from monte.cli import main
from monte.core.builtin_scenes import builtin_scene
from monte.core.exr import read_exr
from monte.core.distributed import (ClusterError, check_workers, connect, plan_units, render_frames_on_cluster,
                                    render_on_cluster, render_unit, worker_versions)
from monte.core.render import merge_tile_samples, render, render_samples
from monte.core.schedule import pass_bounds, tiles
from monte.core.settings import RenderSettings

IMAGES = ("color", "variance", "albedo", "normal", "depth", "sample_count")


def _settings(**kw) -> RenderSettings:
    # 16x16 tiles and 1024-path batches: 4 samples per pass, so 12 spp is 3 passes per tile.
    base = dict(spp=12, seed=7, threads=1, batch_paths=1024, tile_size=16, filter_type="box", filter_width=1.0)
    base.update(kw)
    return RenderSettings(**base)


def _scene():
    return builtin_scene("cornell", (32, 24))  # tiles 16x16, 16x16, 16x8, 16x8


def _assert_same_images(a, b) -> None:
    for name in IMAGES:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), f"{name} differs"


@pytest.fixture(scope="module")
def reference():
    return render(_scene(), _settings())


@pytest.fixture(scope="module")
def cluster():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as lc:
        with Client(lc) as client:
            yield lc, client


def test_the_split_has_several_passes_per_tile():
    """The tests below would prove little if every tile were one pass: check the split they rely on."""
    scene, settings = _scene(), _settings()
    bounds = pass_bounds(tiles(0, 0, 32, 24, 16), 12, settings)
    assert bounds == [[0, 4, 8, 12], [0, 4, 8, 12], [0, 8, 12], [0, 8, 12]]
    units = plan_units(scene, settings, 2, ranges_per_tile=3)
    assert sorted(u[ti] for u in units for ti in u) == sorted(
        [(0, 4), (4, 8), (8, 12)] * 2 + [(0, 8), (8, 12)] * 2)


@pytest.mark.parametrize("ranges_per_tile", [1, 2, 3])
def test_sample_ranges_merged_in_any_order_equal_one_render(reference, ranges_per_tile):
    scene, settings = _scene(), _settings()
    units = plan_units(scene, settings, 2, ranges_per_tile=ranges_per_tile)
    parts = [part for unit in units for part in render_samples(scene, settings, unit)]
    random.Random(ranges_per_tile).shuffle(parts)
    _assert_same_images(merge_tile_samples(scene, settings, parts), reference)


def test_ranges_off_the_pass_boundaries_are_refused():
    with pytest.raises(ValueError, match=r"samples \[0, 6\) of tile 0 are not whole sample passes"):
        render_samples(_scene(), _settings(), {0: (0, 6)})
    with pytest.raises(ValueError, match="tile index 9 is not one of the frame's 4 tiles"):
        render_samples(_scene(), _settings(), {9: (0, 12)})
    with pytest.raises(ValueError, match="adaptive sampling a tile's samples cannot be split"):
        render_samples(_scene(), _settings(adaptive_threshold=0.05), {0: (0, 4)})


def test_a_merge_with_a_missing_range_is_refused():
    scene, settings = _scene(), _settings()
    parts = render_samples(scene, settings, {ti: (0, 12) for ti in range(4)})
    parts += render_samples(scene, settings, {0: (8, 12)})  # tile 0 twice: samples 8.. after samples up to 12
    with pytest.raises(ValueError, match="tile 0: samples from 8 follow samples up to 12"):
        merge_tile_samples(scene, settings, parts)
    with pytest.raises(ValueError, match=r"tiles \[3\] do not hold all 12 samples"):
        merge_tile_samples(scene, settings, parts[:3])


@pytest.mark.parametrize("ranges_per_tile, submit_seed", [(None, None), (1, 3), (3, 11)])
def test_cluster_render_equals_one_render(cluster, reference, ranges_per_tile, submit_seed):
    _, client = cluster
    scene, settings = _scene(), _settings()
    units = plan_units(scene, settings, 2, ranges_per_tile=ranges_per_tile) if ranges_per_tile else None
    seen = []
    result = render_on_cluster(scene, settings, client, units=units, submit_seed=submit_seed,
                               on_progress=seen.append)
    _assert_same_images(result, reference)
    assert result.stats["workers"] == 2 and result.stats["samples"] == 32 * 24 * 12
    done = [p.units_done for p in seen]  # one report per poll, which may collect several units
    assert done == sorted(set(done)) and done[-1] == result.stats["units"]
    assert seen[-1].fraction == 1.0 and seen[-1].samples_done == 32 * 24 * 12


@pytest.mark.parametrize("ranges_per_tile", [1, 3])
def test_each_tile_is_shown_once_its_units_are_back_as_the_final_image_holds_it(cluster, reference,
                                                                                ranges_per_tile):
    """on_tile (the add-on writes these into Blender's render result as they come): every tile once, after its
    last sample range, with images equal to the final frame's (3 ranges per tile: merged from 3 units)."""
    _, client = cluster
    scene, settings = _scene(), _settings(aovs=True)
    units = plan_units(scene, settings, 2, ranges_per_tile=ranges_per_tile)
    shown = []
    result = render_on_cluster(scene, settings, client, units=units, submit_seed=5, on_tile=shown.append)
    assert sorted((t.x0, t.y0, t.width, t.height) for t in shown) == sorted(tiles(0, 0, 32, 24, 16))
    for t in shown:
        window = (slice(t.y0, t.y0 + t.height), slice(t.x0, t.x0 + t.width))
        assert t.samples == 12
        for name in ("color", "variance", "albedo", "normal", "depth"):
            assert np.array_equal(getattr(t, name), getattr(result, name)[window]), name
    _assert_same_images(result, render(scene, settings))


def test_frames_in_flight_each_equal_their_own_render(cluster):
    """Three 'frames' (the seed changes, as Blender's animated seed does) with two in flight at once: each
    delivered frame equals render() of that frame, and the second frame's units were queued before the first
    was done."""
    _, client = cluster
    scene = _scene()
    frames = [(seed, _scene(), _settings(seed=seed)) for seed in (1, 2, 3)]
    delivered = {}
    seen = []
    n = render_frames_on_cluster(client, iter(frames), lambda key, result: delivered.__setitem__(key, result),
                                 frames_in_flight=2, on_progress=seen.append)
    assert n == 3 and sorted(delivered) == [1, 2, 3]
    for seed in (1, 2, 3):
        _assert_same_images(delivered[seed], render(scene, _settings(seed=seed)))
    units_per_frame = len(plan_units(scene, _settings(), 2))
    assert max(p.units_total for p in seen) == 2 * units_per_frame
    with pytest.raises(ValueError, match="frames in flight must be at least 1"):
        render_frames_on_cluster(client, iter(frames), lambda *_: None, frames_in_flight=0)


def test_frames_with_a_time_limit_go_one_at_a_time(cluster, reference):
    """Frames with a time limit are not queued beside each other (each limit is spent on its own frame): the
    progress never counts more than one frame's 10 units; a limit that does not pass changes no bit."""
    _, client = cluster
    frames = [(seed, _scene(), _settings(seed=seed, time_limit=3600.0)) for seed in (7, 8)]
    delivered, seen = {}, []
    n = render_frames_on_cluster(client, iter(frames), lambda key, result: delivered.__setitem__(key, result),
                                 frames_in_flight=2, on_progress=seen.append)
    assert n == 2 and {p.units_total for p in seen} == {10}
    _assert_same_images(delivered[7], reference)
    _assert_same_images(delivered[8], render(_scene(), _settings(seed=8)))


def test_adaptive_render_on_the_cluster_equals_one_render(cluster):
    _, client = cluster
    scene, settings = _scene(), _settings(spp=24, adaptive_threshold=0.2, adaptive_min_samples=8)
    local = render(scene, settings)
    assert local.sample_count.min() < 24  # adaptive sampling did stop some pixels early
    _assert_same_images(render_on_cluster(scene, settings, client), local)


def test_cancel_cancels_the_units_and_the_cluster_renders_on(cluster, reference):
    _, client = cluster
    scene, settings = _scene(), _settings()
    units = plan_units(scene, settings, 2, ranges_per_tile=3)
    with pytest.raises(KeyboardInterrupt):
        render_on_cluster(scene, settings, client, units=units, should_cancel=lambda: True)
    # Units already running finish on their thread (Python cannot stop one halfway); the rest never start and
    # the scheduler forgets them all.
    deadline = time.monotonic() + 60
    while _scheduler_units(client) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _scheduler_units(client) == []
    _assert_same_images(render_on_cluster(scene, settings, client), reference)


def _scheduler_units(client) -> list[str]:
    return client.run_on_scheduler(
        lambda dask_scheduler: [str(k) for k in dask_scheduler.tasks if "monte-unit" in str(k)])


def test_a_worker_killed_mid_render_loses_nothing(cluster, reference):
    """Kill one worker process (SIGKILL) as soon as the first unit is back: the scheduler runs its units again
    on the other worker (LocalCluster starts a new one), and the image is still bit-identical."""
    lc, client = cluster
    scene, settings = _scene(), _settings()
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    killed = []

    def kill_once(_progress):
        if not killed:
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

    units = plan_units(scene, settings, 2, ranges_per_tile=3)
    result = render_on_cluster(scene, settings, client, units=units, on_progress=kill_once)
    assert killed
    _assert_same_images(result, reference)
    # The nanny restarts it: later tests must see 2 live workers. wait_for_workers alone can return while the
    # scheduler still lists the killed one (the units may all finish on the other before it notices), and the next
    # test's broadcast then reached the dead worker (CommClosedError); so wait until it is gone and 2 answer.
    deadline = time.monotonic() + 120
    while True:
        alive = client.run(os.getpid, on_error="ignore")
        listed = client.scheduler_info(n_workers=-1)["workers"]
        if len(alive) == 2 == len(listed) and victim not in alive.values():
            break
        assert time.monotonic() < deadline, f"the cluster did not get back to 2 live workers: {alive}, {list(listed)}"
        time.sleep(0.2)


def test_workers_with_another_monte_are_refused(cluster):
    """The workers report their real versions; a client expecting another Monte release or other core sources
    refuses them, naming what differs (the same check connect() makes against this client's own versions)."""
    _, client = cluster
    mine = worker_versions()
    check_workers(client)  # the same install: accepted
    other = {**mine, "monte": "0.0.1", "core sources": "0123456789abcdef"}
    with pytest.raises(ClusterError, match=r"different Monte than this client.*core sources "
                                           + mine["core sources"] + r" \(client 0123456789abcdef\)"):
        check_workers(client, other)


def test_monte_worker_joins_a_scheduler_and_renders_the_same_image(reference, tmp_path):
    """`monte worker ADDRESS` (kernels loaded, then `dask worker` in the same process) against a scheduler with
    no worker of its own: a still and two frames on this one worker, each equal to its own render."""
    with LocalCluster(n_workers=0, processes=True, dashboard_address=":0") as lc, Client(lc) as client:
        with open(tmp_path / "worker.log", "wb") as log:
            proc = subprocess.Popen([sys.executable, "-m", "monte", "worker", lc.scheduler_address,
                                     "--nthreads", "1", "--name", "monte-test-worker"],
                                    stdout=log, stderr=subprocess.STDOUT)
        try:
            client.wait_for_workers(1, timeout=120)
            names = [w["name"] for w in client.scheduler_info(n_workers=-1)["workers"].values()]
            assert names == ["monte-test-worker"]
            _assert_same_images(render_on_cluster(_scene(), _settings(), client), reference)
            delivered = {}
            frames = [(seed, _scene(), _settings(seed=seed)) for seed in (7, 8)]
            assert render_frames_on_cluster(client, iter(frames), delivered.__setitem__) == 2
            _assert_same_images(delivered[7], reference)
            _assert_same_images(delivered[8], render(_scene(), _settings(seed=8)))
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    assert "loading the render kernels" in (tmp_path / "worker.log").read_text()


REGION = (8, 4, 20, 17)  # x0, y0 from the top, width, height: tiles 16x16, 4x16, 16x1, 4x1 of the region


def test_a_region_sends_out_only_its_tiles():
    """plan_units cuts the region as render(region=...) does: only its 4 tiles go out (each in up to 2 ranges
    of whole passes, for 2 worker threads' 8 units), and the ranges cover each region pixel's 12 samples."""
    scene, settings = _scene(), _settings()
    region_tiles = tiles(*REGION, 16)
    units = plan_units(scene, settings, 2, region=REGION)
    assert {ti for u in units for ti in u} == set(range(len(region_tiles))) == {0, 1, 2, 3}
    covered = sum((e - s) * region_tiles[ti][2] * region_tiles[ti][3] for u in units for ti, (s, e) in u.items())
    assert covered == 20 * 17 * 12


def test_region_on_the_cluster_equals_the_local_region_render(cluster):
    scene, settings = _scene(), _settings()
    local = render(scene, settings, region=REGION)
    remote = render_on_cluster(scene, settings, cluster[1], region=REGION, submit_seed=3)
    assert remote.color.shape == (17, 20, 4) and remote.stats["region"] == list(REGION)
    _assert_same_images(remote, local)
    assert int(remote.sample_count.sum()) == 20 * 17 * 12
    with pytest.raises(ValueError, match=r"render region \(30, 0, 8, 8\) is not inside the 32x24 frame"):
        render_on_cluster(scene, settings, cluster[1], region=(30, 0, 8, 8))


def test_a_time_limit_that_never_passes_hands_units_out_progressively_and_changes_nothing(cluster, reference):
    """With a time limit the units are single passes handed out a few at a time (the 16x16 tiles' 3 passes and
    the 16x8 tiles' 2: 10 units, 4 out at once for 2 threads); a limit that does not pass gives the full image,
    bit for bit."""
    units = plan_units(_scene(), _settings(time_limit=3600.0), 2)
    assert [sorted(u.items()) for u in units] == [[(0, (0, 4))], [(1, (0, 4))], [(2, (0, 8))], [(3, (0, 8))],
                                                  [(0, (4, 8))], [(1, (4, 8))], [(0, (8, 12))], [(1, (8, 12))],
                                                  [(2, (8, 12))], [(3, (8, 12))]]
    remote = render_on_cluster(_scene(), _settings(time_limit=3600.0), cluster[1])
    assert remote.stats["units"] == 10 and not remote.stats["stopped_by_time_limit"] and not remote.cancelled
    _assert_same_images(remote, reference)


def test_a_passed_time_limit_stops_handing_out_units_and_keeps_the_ones_done(cluster, reference):
    """A limit of 1 us has passed once the first unit (tile 0's first pass) is out: nothing more goes out, that
    unit finishes and counts. The image holds its 4 samples per pixel of tile 0 and nothing else, bit for bit
    what one process makes of those samples, and is marked cancelled as a local render stopped by its limit."""
    scene, settings = _scene(), _settings(time_limit=1e-6)
    remote = render_on_cluster(scene, settings, cluster[1])
    assert remote.cancelled and remote.stats["stopped_by_time_limit"] and remote.stats["units_done"] == 1
    counts = remote.sample_count
    assert (counts[:16, :16] == 4).all() and counts.sum() == 16 * 16 * 4
    assert not remote.color[:, 16:, :3].any() and not remote.color[16:, :, :3].any()  # black (alpha 1: opaque film)
    here = merge_tile_samples(scene, settings, render_samples(scene, settings, {0: (0, 4)}), partial=True)
    _assert_same_images(remote, here)
    assert not np.array_equal(remote.color[:16, :16], reference.color[:16, :16])  # 4 of 12 samples: not the full
    with pytest.raises(ValueError, match=r"tiles \[0, 1, 2, 3\] do not hold all 12 samples"):
        merge_tile_samples(scene, settings, render_samples(scene, settings, {0: (0, 4)}))


def test_light_passes_on_the_cluster_equal_one_render(cluster):
    """The light passes' sums travel in the film sums like the colour's: bit-identical to one render."""
    from monte.core.light_passes import LIGHT_PASSES

    scene, settings = _scene(), _settings(light_passes=tuple(LIGHT_PASSES))
    local = render(scene, settings)
    remote = render_on_cluster(scene, settings, cluster[1], units=plan_units(scene, settings, 2,
                                                                             ranges_per_tile=3))
    _assert_same_images(remote, local)
    assert set(remote.light_passes) == set(LIGHT_PASSES)
    for name in LIGHT_PASSES:
        assert np.array_equal(remote.light_passes[name], local.light_passes[name]), name
    assert local.light_passes["Diffuse Direct"].max() > 0


def test_light_groups_on_the_cluster_equal_one_render(cluster):
    """The light groups' sums travel in the film sums too (core.light_groups): bit-identical to one render."""
    scene, settings = _scene(), _settings()
    for emitter in [*scene.lights, *scene.meshes, scene.world]:
        emitter.lightgroup = "all"
    scene.light_groups = ["all", "none"]
    local = render(scene, settings)
    remote = render_on_cluster(scene, settings, cluster[1], units=plan_units(scene, settings, 2, ranges_per_tile=3))
    _assert_same_images(remote, local)
    assert list(remote.light_groups) == ["Combined_all", "Combined_none"]
    for name, arr in local.light_groups.items():
        assert np.array_equal(remote.light_groups[name], arr), name
    assert local.light_groups["Combined_all"].max() > 0 and not local.light_groups["Combined_none"].any()


def test_a_unit_runs_without_a_cluster_too(reference):
    """render_unit is the workers' task: plain core, callable anywhere (what a worker imports)."""
    scene, settings = _scene(), _settings()
    parts = render_unit(scene, settings, {ti: (0, 12) for ti in range(4)}, "frame-a")
    _assert_same_images(merge_tile_samples(scene, settings, parts), reference)


def test_unreachable_scheduler_is_a_clear_error():
    with pytest.raises(ClusterError, match=r"cannot reach the Dask scheduler at tcp://127.0.0.1:9 within 1 s"):
        with connect("tcp://127.0.0.1:9", timeout=1):
            pass


@pytest.mark.parametrize("address, message", [("localhost:8786", "looks like tcp://host:8786"),
                                               ("local:0", "worker count N >= 1"),
                                               ("local:two", "worker count N >= 1")])
def test_malformed_addresses_are_refused(address, message):
    with pytest.raises(ClusterError, match=message):
        with connect(address, timeout=1):
            pass


def test_cli_dask_local_writes_the_same_exr_as_a_local_render(tmp_path, capsys):
    """With data passes too (--passes): the EXR's bytes, Mist and Cryptomatte with its manifest included."""
    common = ["render", "cornell", "--resolution", "32x24", "--spp", "12", "--seed", "7", "--batch", "1024",
              "--tile", "16", "--no-png", "-q", "--passes", "mist,object_index,crypto_material"]
    assert main(common + ["-o", str(tmp_path / "local.exr")]) == 0
    assert main(common + ["-o", str(tmp_path / "cluster.exr"), "--dask", "local:1"]) == 0
    assert (tmp_path / "local.exr").read_bytes() == (tmp_path / "cluster.exr").read_bytes()
    assert {"Mist.Z", "CryptoMaterial00.R"} <= set(read_exr(tmp_path / "cluster.exr"))


def test_ctrl_c_stops_a_cluster_render_writes_nothing_and_leaves_no_worker(tmp_path):
    """SIGINT to `monte render --dask local:2` once its units are queued: exit status 130, no file, and the
    LocalCluster's worker processes are gone (the units cancelled, the cluster closed)."""
    out = tmp_path / "big.exr"
    proc = subprocess.Popen([sys.executable, "-m", "monte", "render", "cornell", "--resolution", "128x128",
                             "--spp", "1024", "-o", str(out), "--dask", "local:2"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines = []
    try:
        for line in proc.stderr:
            lines.append(line)
            if "units on 2 workers" in line:
                break
        workers = _child_pids(proc.pid)
        proc.send_signal(signal.SIGINT)
        _, rest = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, "".join(lines) + rest
    assert "interrupted" in rest
    assert list(tmp_path.iterdir()) == []
    # The workers (and multiprocessing's helper processes) end with the cluster; give them a moment to exit.
    deadline = time.monotonic() + 30
    while [pid for pid in workers if _alive(pid)] and time.monotonic() < deadline:
        time.sleep(0.1)
    left = {pid: _cmdline(pid) for pid in workers if _alive(pid)}
    assert len(workers) >= 2 and not left, left


def _child_pids(pid: int) -> list[int]:
    """Every process below `pid` (Linux /proc)."""
    children = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            if ppid == pid:
                children += [int(entry)] + _child_pids(int(entry))
    return children


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_cli_unreachable_scheduler_writes_nothing(tmp_path, capsys):
    out = tmp_path / "x.exr"
    status = main(["render", "cornell", "--resolution", "8x8", "--spp", "1", "-o", str(out), "-q",
                   "--dask", "tcp://127.0.0.1:9", "--dask-timeout", "1"])
    assert status == 1
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
