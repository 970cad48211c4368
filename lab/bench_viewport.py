"""Viewport and preview timings: how long after each kind of change the Rendered viewport shows its first image
and its 16th sample, and how long a material preview takes. Prints numbers; asserts nothing.

    python -m monte.lab.bench_viewport [--width 1280 --height 720 --threads 2 --samples 16 --repeats 5
                                        --extra-triangles 500000]

The scene is the bench's `interior` room (lab/bpy_scenes.py) seen through its camera at the view size. Each
change goes through Blender's depsgraph (a depsgraph handler reads the updates as view_update does) into a real
ViewportSession; the times are measured from the change reaching the session (after the main-thread export,
printed separately) to the image being published by the worker.
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import threading
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..addon import viewport as vp
from ..core.settings import RenderSettings
from . import bpy_scenes


class _Recorder:
    """Times of the images a session publishes, relative to the last mark()."""

    def __init__(self, session: vp.ViewportSession) -> None:
        self.session = session
        self.t0 = time.perf_counter()
        self.events: list[tuple[float, int, int]] = []
        session._on_image = self._on_image

    def _on_image(self) -> None:
        img = self.session.image()
        if img is not None:
            self.events.append((time.perf_counter() - self.t0, img.samples, img.divider))

    def mark(self) -> None:
        self.events = []
        self.t0 = time.perf_counter()

    def first_and_full(self, samples: int, timeout: float = 600.0) -> tuple[float, float, int]:
        self.session.wait(samples=samples, timeout=timeout)
        first = self.events[0]
        full = next(t for t, s, d in self.events if d == self.session.pixel_size and s >= samples)
        return first[0], full, first[2]


class _CollectorPauses:
    """Seconds the garbage collector held the interpreter (any thread, any generation) since the last mark():
    a full collection stops every Python thread, the viewport's worker included."""

    def __init__(self) -> None:
        self.total = 0.0
        self.full = 0
        self._started: dict[int, float] = {}

    def __call__(self, phase: str, info: dict) -> None:
        key = threading.get_ident()
        if phase == "start":
            self._started[key] = time.perf_counter()
        elif key in self._started:
            self.total += time.perf_counter() - self._started.pop(key)
            self.full += info["generation"] == 2

    def mark(self) -> None:
        self.total, self.full = 0.0, 0


def _changes_handler(captured: list):
    @bpy.app.handlers.persistent
    def handler(_scene, depsgraph):
        captured.append(vp.depsgraph_changes(depsgraph))

    return handler


def _apply(change, captured: list):
    captured.clear()
    change()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    return depsgraph, vp.merged_changes(captured)


@dataclass
class _Row:
    """One kind of change measured `repeats` times: seconds per repeat."""

    label: str
    rebuild: str = ""
    export: list[float] = field(default_factory=list)
    first: list[float] = field(default_factory=list)
    full: list[float] = field(default_factory=list)
    collector: list[float] = field(default_factory=list)
    full_collections: int = 0
    size: str = ""


def bench_viewport(width: int, height: int, threads: int, samples: int, start_resolution: int,
                   pixel_size: int, repeats: int = 1, extra_triangles: int = 0) -> dict[str, _Row]:
    """Print (and return) each kind of change's times over `repeats` repeats: the median, and the range when
    repeated. Each repeat of a change is a real change (object and camera moves alternate between two places,
    edits between two values, an added object is deleted by the next "object delete"). extra_triangles: a rug
    of about that many triangles on the floor, which no change touches (what an update costs in a big scene)."""
    repeats = max(1, int(repeats))
    bpy_scenes.interior((width, height))
    if extra_triangles > 0:
        bpy_scenes.grid_object("rug", (-1.5, -1.5, 0.005), (1.5, 1.5, 0.005),
                               max(1, round(math.sqrt(extra_triangles / 2))), bpy.data.materials["fabric"])
    settings = RenderSettings(threads=threads, seed=1)
    captured: list = []
    handler = _changes_handler(captured)
    bpy.app.handlers.depsgraph_update_post.append(handler)
    pauses = _CollectorPauses()
    gc.callbacks.append(pauses)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    camera = vp.scene_camera_view(depsgraph, (width, height))

    # Warm the kernels (numba's cache is loaded on first use) so the first row is not a one-off.
    warm = vp.ViewportSession(settings, samples=1, start_resolution=0)
    warm.sync(depsgraph)
    warm.set_view(vp.scene_camera_view(depsgraph, (64, 36)))
    warm.wait(timeout=900)
    warm.stop()

    session = vp.ViewportSession(settings, samples=samples, pixel_size=pixel_size, start_resolution=start_resolution)
    rec = _Recorder(session)
    quads = sum(len(o.data.polygons) for o in bpy.data.objects if o.type == "MESH")
    print(f"viewport {width}x{height}, {threads} threads, {samples} samples, start resolution {start_resolution}, "
          f"pixel size {pixel_size}, {repeats} repeats; interior scene ({quads} quads)")
    rows: dict[str, _Row] = {}

    def measure(label: str, report: vp.SyncReport | None, export_s: float) -> None:
        first, full, divider = rec.first_and_full(samples)
        row = rows.setdefault(label, _Row(label))
        row.rebuild = report.rebuild if report is not None else "camera"
        row.export.append(export_s)
        row.first.append(first)
        row.full.append(full)
        row.collector.append(pauses.total)
        row.full_collections += pauses.full
        row.size = f"{width // divider}x{height // divider}"

    def timed_sync(label, change):
        dg, changes = _apply(change, captured)
        t = time.perf_counter()
        rec.mark()
        pauses.mark()
        report = session.sync(dg, changes)
        export_s = time.perf_counter() - t
        measure(label, report, export_s)

    table = bpy.data.objects["table_top"]
    node = bpy.data.materials["fabric"].node_tree.nodes["Diffuse BSDF"]
    lamp = next(o for o in bpy.data.objects if o.type == "LIGHT" and o.data.type == "AREA")
    wood = bpy.data.materials["wood"]
    for i in range(repeats):
        if i == 0:
            t = time.perf_counter()
            rec.mark()
            pauses.mark()
            report = session.sync(depsgraph)
            export_s = time.perf_counter() - t
            session.set_view(camera)
            measure("initial", report, export_s)
        rec.mark()
        pauses.mark()
        turn = _rotation_z(0.05 if i % 2 == 0 else -0.05)
        moved = vp.camera_from_view(np.linalg.inv(camera.matrix_world @ turn), _projection(camera), (width, height))
        session.set_view(moved)
        measure("camera move", None, 0.0)
        odd = i % 2
        timed_sync("object move", lambda: setattr(table, "location", (0.2, 0.1 + 0.1 * odd, 0.0)))
        colour = (0.6, 0.2, 0.2, 1) if odd == 0 else (0.5, 0.3, 0.2, 1)
        timed_sync("material edit", lambda: node.inputs["Color"].__setattr__("default_value", colour))
        timed_sync("light edit", lambda: setattr(lamp.data, "energy", 90.0 if odd == 0 else 80.0))
        timed_sync("object add", lambda: bpy_scenes.box_object("crate", (1.0, -1.0, 0.0), (1.4, -0.6, 0.4), wood))
        timed_sync("object delete", lambda: bpy.data.objects.remove(bpy.data.objects["crate"]))
    session.stop()
    gc.callbacks.remove(pauses)
    bpy.app.handlers.depsgraph_update_post.remove(handler)

    def ms(values: list[float]) -> str:
        mid = statistics.median(values) * 1e3
        return f"{mid:.1f}" if len(values) == 1 else f"{mid:.1f} ({min(values) * 1e3:.0f}-{max(values) * 1e3:.0f})"

    print("medians (range) in ms; gc: the garbage collector's pauses inside the row (full collections)")
    print(f"{'change':<14} {'export ms':>16} {'first image ms':>18} {'(size)':>7} {f'{samples} samples s':>12} "
          f"{'gc ms':>16}  rebuild")
    for row in rows.values():
        print(f"{row.label:<14} {ms(row.export):>16} {ms(row.first):>18} {row.size:>7} "
              f"{statistics.median(row.full):12.2f} {ms(row.collector):>12} ({row.full_collections})  {row.rebuild}")
    return rows


def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _projection(camera) -> np.ndarray:
    """An OpenGL projection reproducing a core perspective camera's frame (for the camera-move row)."""
    xmin, xmax, ymin, ymax = camera.frame()
    n, f = camera.clip_start, min(camera.clip_end, 1e4)
    p = np.zeros((4, 4))
    p[0, 0], p[0, 2] = 2 / (xmax - xmin), (xmax + xmin) / (xmax - xmin)
    p[1, 1], p[1, 2] = 2 / (ymax - ymin), (ymax + ymin) / (ymax - ymin)
    p[2, 2], p[2, 3] = -(f + n) / (f - n), -2 * f * n / (f - n)
    p[3, 2] = -1.0
    return p


def bench_preview(size: int, threads: int, samples: int) -> None:
    """A material preview's work: export a sphere-on-floor preview-like scene and render it in passes."""
    from ..addon.export import export_scene
    from ..core.render import prepare_scene

    scene = bpy_scenes.reset()
    bpy_scenes.mesh_object("floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                           bpy_scenes.diffuse("checker", (0.6, 0.6, 0.6)))
    bpy_scenes.icosphere_object("preview", (0, 0, 1), 1.0,
                                bpy_scenes.node_material("material", "ShaderNodeBsdfPrincipled",
                                                         Base_Color=(0.2, 0.4, 0.8), Roughness=0.3))
    bpy_scenes.light_object(scene, "AREA", (2, -2, 4), energy=400.0, size=2.0)
    bpy_scenes.set_world(scene, (0.05, 0.05, 0.05))
    bpy_scenes.camera_object(scene, (0, -6, 2.5), (math.radians(78), 0, 0), lens=50.0)
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    settings = RenderSettings(threads=threads, seed=1, aovs=False)
    for attempt in ("cold", "warm"):
        times = []
        t0 = time.perf_counter()
        core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
        prepared = prepare_scene(core_scene, settings)
        t_ready = time.perf_counter() - t0
        vp.progressive_passes(core_scene, settings, samples, prepared,
                              lambda rgba, n: times.append((n, time.perf_counter() - t0)), lambda: False)
        passes = ", ".join(f"{n} spp {t * 1e3:.0f} ms" for n, t in times)
        print(f"preview {size}x{size} ({attempt}): export+prepare {t_ready * 1e3:.0f} ms; {passes}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--start-resolution", type=int, default=64)
    parser.add_argument("--pixel-size", type=int, default=1)
    parser.add_argument("--preview-size", type=int, default=128)
    parser.add_argument("--preview-samples", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=1, help="measure each kind of change this many times "
                        "and print medians")
    parser.add_argument("--extra-triangles", type=int, default=0, help="add a rug of about this many triangles "
                        "that no change touches (an update's cost in a big scene)")
    args = parser.parse_args(argv)
    bench_viewport(args.width, args.height, args.threads, args.samples, args.start_resolution, args.pixel_size,
                   args.repeats, args.extra_triangles)
    bench_preview(args.preview_size, args.threads, args.preview_samples)


if __name__ == "__main__":
    main()
