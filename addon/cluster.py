"""Rendering from Blender on a Dask cluster: the "Test connection" operator, the engine's cluster render and the
render job's connection (one for all the frames of an animation, closed when the job ends).

The engine exports the frame as for a local render, then hands the core scene to core.distributed: the frame is
cut into work units, rendered on the cluster's workers and merged bit for bit into the image one machine makes.
Tiles are written into Blender's render result as the units holding them come back. A scheduler that cannot be
reached is an error (the render fails with core.distributed's message); it never falls back to a local render.
"""

from __future__ import annotations

from contextlib import ExitStack, contextmanager
from typing import Callable, Iterator

import bpy

from ..core.distributed import DEFAULT_CONNECT_TIMEOUT, ClusterError, connect

# Cluster workers unpickle the scene, the settings and the unit function by their module path, and they
# import Monte as `monte` (pip install monte[cluster]); Blender imports the extension as bl_ext.<repository>.monte.
WORKER_PACKAGE = "monte"


def cluster_address(scene) -> tuple[str, float]:
    """(address, timeout in seconds) of scene.monte's cluster settings; ClusterError for an empty address."""
    monte = scene.monte
    address = monte.cluster_address.strip()
    if not address:
        raise ClusterError("Render on a Dask cluster is on but the scheduler address is empty "
                           "(tcp://host:8786, or local:N for N worker processes on this machine)")
    return address, float(monte.cluster_timeout)


def expose_core_to_workers() -> None:
    """Make the core's objects travel to the workers as `monte.core.*`, the name the workers import them by.

    Where Blender imports Monte under another name (bl_ext.<repository>.monte), each core module is also
    registered as monte.core.<name> and its classes and functions take that module name, so pickles name
    them as a worker (and, for what comes back, this process) finds them. ClusterError when another package
    is already importable here as `monte`."""
    import sys

    package = __name__.rpartition(".addon.")[0]
    if package == WORKER_PACKAGE:
        return
    existing = sys.modules.get(WORKER_PACKAGE)
    if existing is not None and existing is not sys.modules[package]:
        raise ClusterError(f"Monte is loaded as {package!r} but another {WORKER_PACKAGE!r} package "
                           f"({getattr(existing, '__file__', '?')}) is loaded too: cluster units would be "
                           "unpickled against it; remove one of them")
    _expose_core_as(package, WORKER_PACKAGE)


def _expose_core_as(package: str, alias: str) -> None:
    import importlib
    import pkgutil
    import sys
    import types

    core = importlib.import_module(f"{package}.core")
    sys.modules[alias] = sys.modules[package]
    sys.modules[f"{alias}.core"] = core
    for info in pkgutil.iter_modules(core.__path__):
        module = importlib.import_module(f"{package}.core.{info.name}")
        sys.modules[f"{alias}.core.{info.name}"] = module
        for obj in list(vars(module).values()):
            if isinstance(obj, (type, types.FunctionType)) and obj.__module__ == module.__name__:
                obj.__module__ = f"{alias}.core.{info.name}"


def describe_workers(client) -> str:
    """"N workers, T threads" of the cluster behind a distributed.Client."""
    workers = client.scheduler_info(n_workers=-1)["workers"]
    threads = sum(int(w.get("nthreads", 1)) for w in workers.values())
    return f"{len(workers)} worker{'s' if len(workers) != 1 else ''}, {threads} thread{'s' if threads != 1 else ''}"


def probe_cluster(address: str, timeout: float = DEFAULT_CONNECT_TIMEOUT,
                    log: Callable[[str], None] | None = None) -> str:
    """Connect to the cluster as a render would (workers checked for the same Monte) and return the line
    "Connected to ADDRESS: N workers, T threads"; ClusterError with the reason otherwise."""
    expose_core_to_workers()
    with connect(address, timeout, log) as client:
        return f"Connected to {address}: {describe_workers(client)}"


class _RenderJobConnection:
    """The connection of a render job (Blender's render_init .. render_complete / render_cancel: one still, or
    every frame of an animation): opened by its first cluster frame and kept for the next ones, so that an
    animation connects (and a local:N cluster starts its workers) once, not once per frame."""

    def __init__(self) -> None:
        self.in_job = False
        self.key: tuple[str, float] | None = None
        self.client = None
        self.stack: ExitStack | None = None
        self.connects = 0  # connections opened since the add-on was loaded (reported by tests)

    def close(self) -> None:
        stack, self.stack, self.client, self.key = self.stack, None, None, None
        if stack is not None:
            stack.close()


_job = _RenderJobConnection()


@contextmanager
def cluster_client(address: str, timeout: float, log: Callable[[str], None] | None = None) -> Iterator:
    """A distributed.Client for a frame's cluster render (core.distributed.connect's checks and errors). Inside
    a render job the client stays open for the job's next frames (the same address and timeout, still
    running); a frame that fails closes it. Outside a job (no render_init seen) the connection is the frame's."""
    say = log or (lambda _m: None)
    if not _job.in_job:
        _job.connects += 1
        with connect(address, timeout, log) as client:
            yield client
        return
    client = _job.client
    if client is not None and (_job.key != (address, timeout) or client.status != "running"):
        _job.close()
        client = None
    if client is None:
        stack = ExitStack()
        client = stack.enter_context(connect(address, timeout, log))
        _job.connects += 1
        _job.stack, _job.client, _job.key = stack, client, (address, timeout)
    else:
        say(f"using the render job's connection to {address}")
    try:
        yield client
    except KeyboardInterrupt:  # a cancelled frame: its units are cancelled, the connection is still good
        raise
    except BaseException:
        _job.close()
        raise


@bpy.app.handlers.persistent
def _on_render_init(*_args) -> None:
    _job.close()
    _job.in_job = True


@bpy.app.handlers.persistent
def _on_render_end(*_args) -> None:
    _job.in_job = False
    _job.close()


_HANDLERS = (("render_init", _on_render_init), ("render_complete", _on_render_end),
             ("render_cancel", _on_render_end))


class MONTE_OT_cluster_test(bpy.types.Operator):
    """Connect to the Dask scheduler in the Cluster panel and report the workers found, or why it failed"""

    bl_idname = "monte.cluster_test"
    bl_label = "Test Connection"

    def execute(self, context):
        scene = context.scene
        try:
            address, timeout = cluster_address(scene)
            line = probe_cluster(address, timeout)
        except ClusterError as exc:
            scene.monte.cluster_status = f"Failed: {exc}"
            self.report({"ERROR"}, f"Monte: {exc}")
            return {"CANCELLED"}
        except Exception as exc:  # noqa: BLE001 - shown to the user, never raised into Blender
            scene.monte.cluster_status = f"Failed: {type(exc).__name__}: {exc}"
            self.report({"ERROR"}, f"Monte: {type(exc).__name__}: {exc}")
            return {"CANCELLED"}
        scene.monte.cluster_status = line
        self.report({"INFO"}, f"Monte: {line}")
        return {"FINISHED"}


classes = (MONTE_OT_cluster_test,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    for name, handler in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if handler not in handlers:
            handlers.append(handler)


def unregister() -> None:
    for name, handler in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if handler in handlers:
            handlers.remove(handler)
    _job.in_job = False
    _job.close()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
