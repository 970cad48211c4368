"""A render on a Dask cluster (the `distributed` package), merged bit for bit into what one machine makes.

Every random number is a pure function of (seed, pixel, sample, dimension) and a tile's film adds its samples
one sample pass at a time (core.schedule.pass_bounds), so the work splits into units of whole tiles or of
whole sample passes of a tile. Workers run core.render.render_samples on their units and send back raw film
sums; the client adds them tile by tile in pass order (core.render.merge_tile_samples), which is the order one
render() adds them in: the image is the same bit for bit for any worker count, unit split or completion order.

The scene goes to the workers once per frame (scattered with broadcast=True); each worker prepares it (Embree
scene, flattened triangles) once and keeps it for the frame's units. Workers need Monte's core with NumPy,
numba and Embree, never bpy or a .blend. `distributed` is imported when a cluster is used, so the rest of
Monte runs without it.
"""

from __future__ import annotations

import math
import os
import pickle
import random
import threading
import time
import uuid
from collections import OrderedDict
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

from .data_passes import DataFilm
from .film import CatcherOutput, TileFilm
from .render import (CancelCallback, RenderResult, SampleRanges, TileCallback, TileSamples, fold_tile_part,
                     merge_data_tables, merge_tile_samples, render_samples, tile_result, world_to_camera)
from .sampling import make_sampler
from .scene import Scene
from .schedule import TileRect, pass_bounds, tiles
from .settings import RenderSettings

DEFAULT_CONNECT_TIMEOUT = 10.0  # seconds to reach a scheduler and see a worker before giving up
UNITS_PER_WORKER = 4  # enough units that a slow or lost worker's share is small, few enough to keep sums small


class ClusterError(RuntimeError):
    """The cluster cannot do the render: unreachable, no workers, a worker that differs, a failed unit."""


@dataclass
class ClusterProgress:
    """Progress of a cluster render: fraction of paths done, units done, the cluster's samples per second."""

    fraction: float
    units_done: int
    units_total: int
    workers: int
    samples_done: int
    elapsed: float
    samples_per_second: float
    eta_seconds: float

    def stats_line(self) -> str:
        return (f"Unit {self.units_done}/{self.units_total} | {self.workers} workers | "
                f"{self.samples_per_second / 1e3:.0f} k samples/s | Elapsed {self.elapsed:.1f} s | "
                f"Remaining {self.eta_seconds:.1f} s")


# ----------------------------------------------------------------------------------------------- work units
def plan_units(scene: Scene, settings: RenderSettings, workers: int, *, region: TileRect | None = None,
               ranges_per_tile: int | None = None, units_per_worker: int = UNITS_PER_WORKER) -> list[SampleRanges]:
    """Cut a frame (or its region: only the region's tiles, indexed as render_samples indexes them) into work
    units (each a dict tile index -> samples [start, end), whole sample passes) for a cluster of `workers`
    worker threads (a unit runs on one thread).

    With at least units_per_worker x workers tiles, units are groups of whole tiles (the film comes back once
    per tile); with fewer, each tile's passes are split into ranges_per_tile ranges (default: enough for that
    many units), since a unit that starts past sample 0 sends one film per pass back. With a time limit each
    unit is one sample pass of one tile, listed pass by pass over the tiles (all tiles' first pass, then their
    second, ...), so that a render stopped by the limit has refined the whole image evenly, as a local one.
    Adaptive sampling keeps tiles whole (a pass depends on the ones before).
    """
    tile_list = _tile_list(scene, settings, region)
    bounds = pass_bounds(tile_list, int(settings.spp), settings)
    target = max(1, workers * units_per_worker)
    progressive = settings.time_limit > 0 and ranges_per_tile is None and settings.adaptive_threshold <= 0
    if progressive:
        ranges_per_tile = max(len(b) - 1 for b in bounds)
    if ranges_per_tile is None:
        ranges_per_tile = 1 if len(tile_list) >= target else -(-target // len(tile_list))
    if settings.adaptive_threshold > 0:
        ranges_per_tile = 1
    if ranges_per_tile < 1:
        raise ValueError(f"ranges per tile must be at least 1, got {ranges_per_tile}")
    if ranges_per_tile == 1:
        per_unit = -(-len(tile_list) // target)
        return [{ti: (0, int(settings.spp)) for ti in range(t0, min(t0 + per_unit, len(tile_list)))}
                for t0 in range(0, len(tile_list), per_unit)]
    units: list[SampleRanges] = []
    for ti, b in enumerate(bounds):
        passes = len(b) - 1
        k = max(1, min(ranges_per_tile, passes))
        cuts = [b[round(i * passes / k)] for i in range(k + 1)]
        units += [{ti: (cuts[i], cuts[i + 1])} for i in range(k)]
    if progressive:
        units.sort(key=lambda u: next(iter(u.values()))[0])  # stable: tile order within each pass
    return units


def _tile_list(scene: Scene, settings: RenderSettings, region: TileRect | None) -> list[TileRect]:
    """The tiles render() cuts the region (the whole frame when None) into."""
    width, height = scene.camera.resolution
    rx, ry, rw, rh = (0, 0, width, height) if region is None else (int(v) for v in region)
    return tiles(rx, ry, rw, rh, settings.tile_size)


# ---------------------------------------------------------------------------------------- on the workers
_PREPARED: OrderedDict = OrderedDict()  # frame key -> (PreparedScene, Accelerator), the latest frames only
_PREPARED_LOCK = threading.Lock()
_PREPARED_KEEP = 2


def _prepared_for(frame_key: str, scene: Scene, settings: RenderSettings):
    """This worker's prepared scene for the frame, built by its first unit (units of a frame share it)."""
    from .accel import Accelerator
    from .integrator import PreparedScene

    with _PREPARED_LOCK:
        if frame_key in _PREPARED:
            _PREPARED.move_to_end(frame_key)
            return _PREPARED[frame_key]
        scene.validate()  # also puts its arrays in the forms PreparedScene expects
        prepared = PreparedScene.build(scene, sample_world=settings.light_sampling == "light",
                                       threads=settings.thread_count)
        entry = (prepared, Accelerator(prepared.vertices, prepared.triangles, motion=prepared.motion))
        _PREPARED[frame_key] = entry
        while len(_PREPARED) > _PREPARED_KEEP:
            _PREPARED.popitem(last=False)
        return entry


def render_unit(scene: Scene, settings: RenderSettings, unit: SampleRanges, frame_key: str,
                region: TileRect | None = None) -> list[TileSamples]:
    """A worker's task: the unit's film sums (tile indices of the region's tiles, the frame's when None). One
    thread per task (a worker runs as many tasks as it has threads); the image does not depend on it. A unit
    always runs to its end: the client applies a time limit by handing out no more units."""
    prepared = _prepared_for(frame_key, scene, settings)
    return render_samples(scene, settings.replace(threads=1, time_limit=0.0), unit, region=region,
                          prepared=prepared)


def worker_versions() -> dict[str, str]:
    """What must match between the client and every worker for the image to be the same."""
    import numba
    import numpy

    try:
        from importlib.metadata import version

        monte_version = version("monte")
    except Exception:  # not installed as a distribution: the source tree's files are what counts
        monte_version = "unknown"
    return {"monte": monte_version, "numpy": numpy.__version__, "numba": numba.__version__,
            "core sources": _source_digest()}


def _source_digest() -> str:
    """A digest of the core's sources: two installs of the same version number may still differ."""
    import hashlib

    digest = hashlib.sha256()
    folder = os.path.dirname(os.path.abspath(__file__))
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py"):
            with open(os.path.join(folder, name), "rb") as f:
                digest.update(name.encode() + b"\0" + f.read())
    return digest.hexdigest()[:16]


# --------------------------------------------------------------------------------------------- the client
@contextmanager
def connect(address: str, timeout: float = DEFAULT_CONNECT_TIMEOUT, log: Callable[[str], None] | None = None
            ) -> Iterator:
    """A distributed.Client for `address`: "tcp://host:8786" (a running scheduler) or "local:N" (a LocalCluster
    of N worker processes with one thread each, on this machine). Raises ClusterError when the scheduler
    cannot be reached or shows no worker within `timeout` seconds, or a worker's Monte differs from ours."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:
        raise ClusterError(f"a cluster render needs the 'distributed' package (pip install monte[cluster]): "
                           f"{exc}") from None
    say = log or (lambda _m: None)
    cluster = None
    if address.startswith("local:"):
        try:
            n = int(address[len("local:"):])
        except ValueError:
            n = 0
        if n < 1:
            raise ClusterError(f"--dask local:N needs a worker count N >= 1, got {address!r}")
        say(f"starting a local Dask cluster of {n} worker processes")
        # ":0": its HTTP server (health, metrics; the dashboard when bokeh is installed) on a free port
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0")
        client = Client(cluster, timeout=timeout)
    else:
        if "://" not in address:
            raise ClusterError(f"a Dask scheduler address looks like tcp://host:8786, got {address!r}")
        try:
            client = Client(address, timeout=timeout)
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s: {exc}") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except (OSError, TimeoutError):
            raise ClusterError(f"the Dask scheduler at {address} has no worker (waited {timeout:g} s)") from None
        check_workers(client)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def check_workers(client, expected: dict[str, str] | None = None) -> None:
    """Refuse workers whose Monte sources, NumPy or numba differ from `expected` (this client's worker_versions()
    when None): their images would differ. The ClusterError names each such worker and what differs."""
    mine = worker_versions() if expected is None else expected
    theirs = client.run(worker_versions)
    wrong = []
    for worker, versions in sorted(theirs.items()):
        diffs = [f"{k} {versions.get(k)} (client {mine.get(k)})" for k in sorted(set(mine) | set(versions))
                 if versions.get(k) != mine.get(k)]
        if diffs:
            wrong.append(f"{worker}: {', '.join(diffs)}")
    if wrong:
        raise ClusterError("workers run a different Monte than this client (install the same Monte, NumPy and "
                           "numba on every worker): " + "; ".join(wrong))


def render_on_cluster(scene: Scene, settings: RenderSettings, client, *,
                      units: list[SampleRanges] | None = None,
                      on_progress: Callable[[ClusterProgress], None] | None = None,
                      should_cancel: CancelCallback | None = None,
                      log: Callable[[str], None] | None = None,
                      submit_seed: int | None = None,
                      on_tile: TileCallback | None = None,
                      region: TileRect | None = None) -> RenderResult:
    """Render the frame (or its region) on the cluster behind `client`; the images equal render()'s bit for bit.

    units: the work split (plan_units for the cluster's worker threads when None). submit_seed: submit the units
    in a shuffled order (for showing that the image does not depend on it). should_cancel is polled while units
    run: when it returns True every unit is cancelled and KeyboardInterrupt is raised (a cluster render keeps
    no partial image: a frame is all or nothing).
    region: (x0, y0, width, height) of the frame, y0 from the top, as render()'s: only the region's tiles are
    rendered and the result covers the region, equal to render(region=...) bit for bit.
    settings.time_limit > 0: the units (one sample pass of one tile each, pass by pass over the tiles) are
    handed out a few per worker thread at a time, and none after the limit has passed (counted from this
    call); the units already out finish and count. The image then holds, per tile, the samples of its passes
    from 0 up to where its units stopped (the result is marked cancelled, as a local render stopped by its
    time limit): each tile is exactly what one machine makes of those samples, which passes got done
    depends on the cluster's speed.
    on_tile: called on this thread with each tile (core.render.Tile, all its samples) as soon as the units
    holding its samples are back, so a viewer can show the frame filling in; its images equal the final ones.
    stats: seconds, samples/s, units, workers, threads, scene_bytes (the pickled scene sent once per worker),
    film_bytes (all film sums sent back; data_pass_bytes of them the data passes') and film_bytes_per_unit.
    """
    job = _FrameJob(client, scene, settings, units, submit_seed, log, on_tile=on_tile, region=region)
    _run_jobs([job], on_progress, should_cancel)
    return job.result()


def render_frames_on_cluster(client, frames: Iterable[tuple],
                             on_frame: Callable[[object, RenderResult], None], *, frames_in_flight: int = 2,
                             on_progress: Callable[[ClusterProgress], None] | None = None,
                             should_cancel: CancelCallback | None = None,
                             log: Callable[[str], None] | None = None) -> int:
    """Render a sequence of frames ((key, scene, settings) or (key, scene, settings, region), e.g. a .blend's
    exported frames; region as render_on_cluster's, None the whole frame) on the cluster,
    with up to frames_in_flight frames' units queued at once, so that workers keep busy while the client
    takes the next frame from `frames` (an export) and merges the last. on_frame(key, result) is called on this
    thread as each frame completes (in completion order), with images bit-identical to render()'s of that
    frame. Cancel as render_on_cluster (the frames already passed to on_frame stay done). Returns frames done.
    A frame with a time limit is rendered alone (no other frame's units queued beside it), so that its limit
    is spent on it.
    """
    if frames_in_flight < 1:
        raise ValueError(f"frames in flight must be at least 1, got {frames_in_flight}")
    source = iter(frames)
    jobs: list[_FrameJob] = []
    finished = 0

    def refill() -> None:
        nonlocal source
        while (source is not None and sum(not j.done for j in jobs) < frames_in_flight
               and not any(j.settings.time_limit > 0 and not j.done for j in jobs)):
            try:
                key, scene, settings, *rest = next(source)
            except StopIteration:
                source = None
                return
            jobs.append(_FrameJob(client, scene, settings, None, None, log, key, region=rest[0] if rest else None))

    def deliver() -> None:
        nonlocal finished
        for job in [j for j in jobs if j.done]:
            jobs.remove(job)
            on_frame(job.key, job.result())
            finished += 1

    refill()
    while jobs:
        _run_jobs(jobs, on_progress, should_cancel, until_one_done=True)
        deliver()
        refill()
    return finished


class _FrameJob:
    """One frame's units on the cluster: submitted when made, their film sums collected as they finish."""

    def __init__(self, client, scene: Scene, settings: RenderSettings, units: list[SampleRanges] | None,
                 submit_seed: int | None, log: Callable[[str], None] | None, key: object = None,
                 on_tile: TileCallback | None = None, region: TileRect | None = None) -> None:
        say = log or (lambda _m: None)
        settings.validate()
        scene.validate()
        width, height = scene.camera.resolution
        if region is not None:
            region = tuple(int(v) for v in region)
            rx, ry, rw, rh = region
            if rw < 1 or rh < 1 or rx < 0 or ry < 0 or rx + rw > width or ry + rh > height:
                raise ValueError(f"render region {region} is not inside the {width}x{height} frame")
        self.region = region
        self.key, self.scene, self.settings = key, scene, settings
        self.t_start = time.perf_counter()
        worker_info = client.scheduler_info(n_workers=-1)["workers"]
        self.workers = max(1, len(worker_info))
        self.threads = max(1, sum(int(w.get("nthreads", 1)) for w in worker_info.values()))
        if units is None:  # a unit runs on one thread: a worker with 8 threads runs 8 at once
            units = plan_units(scene, settings, self.threads, region=region)
        self.units = units
        order = list(range(len(units)))
        if submit_seed is not None:
            random.Random(submit_seed).shuffle(order)
        self.frame_key = frame_key = uuid.uuid4().hex
        self.scene_bytes = len(pickle.dumps(scene, protocol=pickle.HIGHEST_PROTOCOL))
        say(f"{len(units)} units on {self.workers} workers; scene {self.scene_bytes / 1e3:.0f} kB to each worker")
        self.client = client
        self.shared = [client.scatter(scene, broadcast=True, hash=False),
                       client.scatter(settings, broadcast=True, hash=False)]
        tile_list = _tile_list(scene, settings, region)
        self.tile_list, self.on_tile = tile_list, on_tile
        self.tile_parts: dict[int, list[TileSamples]] = {}
        self.unit_paths = {self._unit_key(i): _unit_paths(tile_list, units[i]) for i in order}
        self.total_paths = sum(self.unit_paths.values())
        # With a time limit units go out a few per thread at a time (none once it has passed); else all at once.
        self.to_submit = order
        self.window = 2 * self.threads if settings.time_limit > 0 else len(units)
        self.stopped = False  # the time limit passed with units not handed out
        self.futures: list = []
        self.pending: set = set()
        self.parts: list[TileSamples] = []
        self.done_paths = 0
        self.film_bytes = 0
        self.data_bytes = 0  # of film_bytes, the data passes' sums
        self._hand_out()

    def _unit_key(self, i: int) -> str:
        return f"monte-unit-{self.frame_key}-{i}"

    def _hand_out(self) -> None:
        """Submit units while fewer than `window` are out; none after the time limit (the rest is dropped)."""
        limit = self.settings.time_limit
        while self.to_submit and len(self.pending) < self.window:
            if limit > 0 and self.futures and time.perf_counter() - self.t_start > limit:
                self.stopped = True
                self.to_submit = []
                break
            i = self.to_submit.pop(0)
            future = self.client.submit(render_unit, *self.shared, self.units[i], self.frame_key, self.region,
                                        pure=False, key=self._unit_key(i))
            self.futures.append(future)
            self.pending.add(future)

    @property
    def done(self) -> bool:
        return not self.pending and not self.to_submit

    def poll(self) -> int:
        """Collect the units finished since the last call; returns how many. ClusterError for a failed unit."""
        from distributed import CancelledError

        finished = [f for f in self.pending if f.done()]
        for f in finished:
            self.pending.discard(f)
            try:
                result = f.result()
            except CancelledError:
                raise ClusterError(f"unit {f.key} was cancelled by the cluster") from None
            except Exception as exc:
                raise ClusterError(f"unit {f.key} failed on its worker: {type(exc).__name__}: {exc}") from exc
            # the scheduler may forget the unit now that its result is here (not when this job is collected, which
            # a reference cycle can put off until the garbage collector runs: the finished unit's film stayed in a
            # worker's memory until then)
            f.release()
            self.parts += result
            if self.on_tile is not None:
                self._show_finished_tiles(result)
            self.film_bytes += sum(part.nbytes() for part in result)
            self.data_bytes += sum(a.nbytes for part in result for sums in part.data for a in sums.values())
            self.done_paths += self.unit_paths[f.key]
        if finished or self.settings.time_limit > 0:
            self._hand_out()
        if self.done:
            self.release()
        return len(finished)

    def _show_finished_tiles(self, result: list[TileSamples]) -> None:
        """Pass each tile whose samples are now all back to on_tile (its film added in pass order, as the final
        merge adds it, so the tile shown is the tile of the final image)."""
        spp = int(self.settings.spp)
        for part in result:
            self.tile_parts.setdefault(part.tile_index, []).append(part)
        for ti in sorted({part.tile_index for part in result}):
            parts = sorted(self.tile_parts[ti], key=lambda p: p.sample_start)
            if sum(p.sample_end - p.sample_start for p in parts) != spp:
                continue
            tile = self.tile_list[ti]
            sampler = make_sampler(self.settings.sampler, self.settings.seed, max(spp, 1), groups=self.settings.variance_groups)
            film = TileFilm(tile[2], tile[3], self.settings.aovs, sampler, self.settings.denoising_features,
                            alpha=self.scene.has_alpha, catcher=CatcherOutput.of(self.scene),
                            light_passes=self.settings.light_passes, shader_aovs=self.scene.shader_aovs,
                            light_groups=self.scene.light_groups, error_estimate=self.settings.error_estimate)
            tables = merge_data_tables(self.settings, parts)
            data_film = DataFilm(tile[2], tile[3], tables) if tables is not None else None
            for p in parts:
                fold_tile_part(film, data_film, p)
            del self.tile_parts[ti]
            rot = world_to_camera(self.scene) if self.settings.denoising_features else None
            shown = tile_result(tile, film, spp, self.settings.aovs, rot)
            if data_film is not None:
                shown.data_passes = data_film.images()
            self.on_tile(shown)

    def cancel(self) -> None:
        running = bool(self.pending)  # units out and not back (a finished job has none to forget)
        self.to_submit = []
        self.client.cancel(self.futures, force=True)
        # and the futures released now, not when this job is collected (a raised exception's traceback holds it
        # until the garbage collector runs), so that the scheduler forgets every unit at once
        for future in self.futures:
            future.release()
        self.release()
        if running and self.client.status == "running":  # (a lost scheduler forgot them: no call to wait on)
            self._forget_units()

    def _forget_units(self, seconds: float = 5.0) -> None:
        """Cancel again, on the scheduler itself, any of this frame's units it still holds: a cancel sent while the
        units were being registered was seen to leave them running and wanted by this client (about one cancelled
        render in ten on the loaded 2-core machine). Polls until none is wanted twice in a row, or `seconds`. Best
        effort: a scheduler that cannot be reached keeps nothing of this frame's anyway."""
        prefix = f"monte-unit-{self.frame_key}-"

        def cancel_left(dask_scheduler, prefix: str, client: str) -> int:
            import inspect

            # only units some client still wants (stimulus_cancel asserts that); an unwanted one is being forgotten
            keys = [k for k, ts in dask_scheduler.tasks.items() if isinstance(k, str) and k.startswith(prefix)
                    and ts.who_wants]
            if keys:  # (reason and msg: distributed 2024.4 and later)
                extra = ({"reason": "Monte render cancelled", "msg": ""}
                         if "reason" in inspect.signature(dask_scheduler.stimulus_cancel).parameters else {})
                dask_scheduler.stimulus_cancel(keys, client=client, force=True, **extra)
            return len(keys)

        deadline = time.monotonic() + seconds
        clear = 0
        try:
            while clear < 2 and time.monotonic() < deadline:
                left = self.client.run_on_scheduler(cancel_left, prefix=prefix, client=self.client.id)
                clear = clear + 1 if left == 0 else 0
                time.sleep(0.02)
        except Exception:  # noqa: BLE001 (the cancel's own exception is the one to report)
            pass

    def release(self) -> None:
        """Let the workers drop this frame's scene and settings."""
        if self.shared:
            self.client.cancel(self.shared)
            self.shared = []

    def result(self) -> RenderResult:
        """The merged frame (after every unit is done)."""
        t_merge = time.perf_counter()
        result = merge_tile_samples(self.scene, self.settings, self.parts, region=self.region, partial=self.stopped)
        elapsed = time.perf_counter() - self.t_start
        result.stats.update({
            "seconds": elapsed,
            "merge_seconds": time.perf_counter() - t_merge,
            "samples_per_second": result.stats["samples"] / max(elapsed, 1e-9),
            "units": len(self.units),
            "workers": self.workers,
            "threads": self.threads,
            "scene_bytes": self.scene_bytes,
            "film_bytes": self.film_bytes,
            "data_pass_bytes": self.data_bytes,
            "film_bytes_per_unit": self.film_bytes / max(len(self.futures), 1),
            "units_done": len(self.futures),
            "stopped_by_time_limit": self.stopped,
        })
        return result


def _run_jobs(jobs: list[_FrameJob], on_progress: Callable[[ClusterProgress], None] | None,
              should_cancel: CancelCallback | None, until_one_done: bool = False) -> None:
    """Wait for the jobs' units (until every job is done, or one is), reporting progress over all of them;
    on a cancel, an error or Ctrl-C every job's units are cancelled and the exception goes on."""
    t_start = min(j.t_start for j in jobs)
    try:
        while any(not j.done for j in jobs):
            if should_cancel is not None and should_cancel():
                raise KeyboardInterrupt
            newly = sum(j.poll() for j in jobs if not j.done)
            if not newly:
                time.sleep(0.05)
                continue
            if on_progress is not None:
                done_paths = sum(j.done_paths for j in jobs)
                total = sum(j.total_paths for j in jobs)
                elapsed = time.perf_counter() - t_start
                frac = done_paths / total if total else 1.0
                on_progress(ClusterProgress(frac, sum(len(j.futures) - len(j.pending) for j in jobs),
                                            sum(len(j.units) for j in jobs), jobs[0].workers, done_paths,
                                            elapsed, done_paths / max(elapsed, 1e-9),
                                            elapsed * (1 - frac) / frac if frac > 0 else math.inf))
            if until_one_done and any(j.done for j in jobs):
                return
    except BaseException:
        for j in jobs:
            j.cancel()
        raise


def _unit_paths(tile_list: list, unit: SampleRanges) -> int:
    """Paths (pixel samples) a unit traces, for progress."""
    return sum((end - start) * tile_list[ti][2] * tile_list[ti][3] for ti, (start, end) in unit.items())
