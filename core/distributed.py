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
from typing import Callable, Iterator

from .render import CancelCallback, RenderResult, SampleRanges, TileSamples, merge_tile_samples, render_samples
from .scene import Scene
from .schedule import pass_bounds, tiles
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
def plan_units(scene: Scene, settings: RenderSettings, workers: int, *, ranges_per_tile: int | None = None,
               units_per_worker: int = UNITS_PER_WORKER) -> list[SampleRanges]:
    """Cut a frame into work units (each a dict tile index -> samples [start, end), whole sample passes) for a
    cluster of `workers` worker threads (a unit runs on one thread).

    With at least units_per_worker x workers tiles, units are groups of whole tiles (the film comes back once
    per tile); with fewer, each tile's passes are split into ranges_per_tile ranges (default: enough for that
    many units), since a unit that starts past sample 0 sends one film per pass back. Adaptive sampling keeps
    tiles whole (a pass depends on the ones before).
    """
    width, height = scene.camera.resolution
    tile_list = tiles(0, 0, width, height, settings.tile_size)
    bounds = pass_bounds(tile_list, int(settings.spp), settings)
    target = max(1, workers * units_per_worker)
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
    return units


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
        prepared = PreparedScene.build(scene, sample_world=settings.light_sampling == "light")
        entry = (prepared, Accelerator(prepared.vertices, prepared.triangles))
        _PREPARED[frame_key] = entry
        while len(_PREPARED) > _PREPARED_KEEP:
            _PREPARED.popitem(last=False)
        return entry


def render_unit(scene: Scene, settings: RenderSettings, unit: SampleRanges, frame_key: str) -> list[TileSamples]:
    """A worker's task: the unit's film sums. One thread per task (a worker runs as many tasks as it has
    threads); the image does not depend on it."""
    prepared = _prepared_for(frame_key, scene, settings)
    return render_samples(scene, settings.replace(threads=1), unit, prepared=prepared)


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
                      submit_seed: int | None = None) -> RenderResult:
    """Render the whole frame on the cluster behind `client`; the images equal render()'s bit for bit.

    units: the work split (plan_units for the cluster's worker count when None). submit_seed: submit the units
    in a shuffled order (for showing that the image does not depend on it). should_cancel is polled while units
    run: when it returns True every unit is cancelled and KeyboardInterrupt is raised (a cluster render keeps
    no partial image: a frame is all or nothing). A time limit does not apply (refused).
    stats: seconds, samples/s, units, workers, scene_bytes (the pickled scene sent once per worker),
    film_bytes (all film sums sent back) and film_bytes_per_unit.
    """
    from distributed import CancelledError

    say = log or (lambda _m: None)
    settings.validate()
    if settings.time_limit > 0:
        raise ValueError("a time limit does not apply to a cluster render (its units are not stopped halfway)")
    scene.validate()
    t_start = time.perf_counter()
    worker_info = client.scheduler_info(n_workers=-1)["workers"]
    workers = max(1, len(worker_info))
    threads = max(1, sum(int(w.get("nthreads", 1)) for w in worker_info.values()))
    if units is None:  # a unit runs on one thread: a worker with 8 threads runs 8 at once
        units = plan_units(scene, settings, threads)
    order = list(range(len(units)))
    if submit_seed is not None:
        random.Random(submit_seed).shuffle(order)
    frame_key = uuid.uuid4().hex
    scene_bytes = len(pickle.dumps(scene, protocol=pickle.HIGHEST_PROTOCOL))
    say(f"{len(units)} units on {workers} workers; scene {scene_bytes / 1e3:.0f} kB to each worker")
    scene_future = client.scatter(scene, broadcast=True, hash=False)
    settings_future = client.scatter(settings, broadcast=True, hash=False)
    futures = [client.submit(render_unit, scene_future, settings_future, units[i], frame_key, pure=False,
                             key=f"monte-unit-{frame_key}-{i}") for i in order]
    width, height = scene.camera.resolution
    tile_list = tiles(0, 0, width, height, settings.tile_size)
    unit_paths = {f.key: _unit_paths(tile_list, units[i]) for f, i in zip(futures, order)}
    total_paths = sum(unit_paths.values())
    parts: list[TileSamples] = []
    pending = set(futures)
    done_paths = 0
    film_bytes = 0
    try:
        while pending:
            if should_cancel is not None and should_cancel():
                raise KeyboardInterrupt
            finished = [f for f in pending if f.done()]
            if not finished:
                time.sleep(0.05)
                continue
            for f in finished:
                pending.discard(f)
                try:
                    result = f.result()
                except CancelledError:
                    raise ClusterError(f"unit {f.key} was cancelled by the cluster") from None
                except Exception as exc:
                    raise ClusterError(f"unit {f.key} failed on its worker: {type(exc).__name__}: {exc}") from exc
                parts += result
                film_bytes += sum(a.nbytes for part in result for sums in part.films for a in sums.values())
                done_paths += unit_paths[f.key]
                if on_progress is not None:
                    elapsed = time.perf_counter() - t_start
                    frac = done_paths / total_paths if total_paths else 1.0
                    on_progress(ClusterProgress(frac, len(futures) - len(pending), len(futures), workers,
                                                done_paths, elapsed, done_paths / max(elapsed, 1e-9),
                                                elapsed * (1 - frac) / frac if frac > 0 else math.inf))
    except BaseException:
        client.cancel(futures, force=True)
        raise
    finally:
        client.cancel([scene_future, settings_future])
    t_merge = time.perf_counter()
    result = merge_tile_samples(scene, settings, parts)
    elapsed = time.perf_counter() - t_start
    result.stats.update({
        "seconds": elapsed,
        "merge_seconds": time.perf_counter() - t_merge,
        "samples_per_second": result.stats["samples"] / max(elapsed, 1e-9),
        "units": len(units),
        "workers": workers,
        "threads": threads,
        "scene_bytes": scene_bytes,
        "film_bytes": film_bytes,
        "film_bytes_per_unit": film_bytes / max(len(units), 1),
    })
    return result


def _unit_paths(tile_list: list, unit: SampleRanges) -> int:
    """Paths (pixel samples) a unit traces, for progress."""
    return sum((end - start) * tile_list[ti][2] * tile_list[ti][3] for ti, (start, end) in unit.items())
