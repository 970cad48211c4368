"""Viewport and preview timings: how long after each kind of change the Rendered viewport shows its first image
and its 16th sample, and how long a material preview takes. Prints numbers; asserts nothing.

    python -m monte.lab.bench_viewport [--width 1280 --height 720 --threads 2 --samples 16]

The scene is the bench's `interior` room (lab/bpy_scenes.py) seen through its camera at the view size. Each
change goes through Blender's depsgraph (a depsgraph handler reads the updates as view_update does) into a real
ViewportSession; the times are measured from the change reaching the session (after the main-thread export,
printed separately) to the image being published by the worker.
"""

from __future__ import annotations

import argparse
import math
import time

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


def bench_viewport(width: int, height: int, threads: int, samples: int, start_resolution: int,
                   pixel_size: int) -> None:
    bpy_scenes.interior((width, height))
    settings = RenderSettings(threads=threads, seed=1)
    captured: list = []
    handler = _changes_handler(captured)
    bpy.app.handlers.depsgraph_update_post.append(handler)
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
          f"pixel size {pixel_size}; interior scene ({quads} quads)")
    print(f"{'change':<16} {'export ms':>9} {'first image ms':>15} {'(size)':>10} {f'{samples} samples s':>12}  "
          "rebuild")

    def row(label: str, report: vp.SyncReport | None, export_s: float) -> None:
        first, full, divider = rec.first_and_full(samples)
        size = f"{width // divider}x{height // divider}"
        rebuild = report.rebuild if report is not None else "camera"
        print(f"{label:<16} {export_s * 1e3:9.1f} {first * 1e3:15.1f} {size:>10} {full:12.2f}  {rebuild}")

    t = time.perf_counter()
    report = session.sync(depsgraph)
    export_s = time.perf_counter() - t
    rec.mark()
    session.set_view(camera)
    row("initial", report, export_s)

    rec.mark()
    moved = vp.camera_from_view(np.linalg.inv(camera.matrix_world @ _rotation_z(0.05)), _projection(camera),
                                (width, height))
    session.set_view(moved)
    row("camera move", None, 0.0)

    def timed_sync(label, change):
        dg, changes = _apply(change, captured)
        t = time.perf_counter()
        rec.mark()
        report = session.sync(dg, changes)
        export_s = time.perf_counter() - t
        row(label, report, export_s)

    table = bpy.data.objects["table_top"]
    timed_sync("object move", lambda: setattr(table, "location", (0.2, 0.1, 0.0)))
    node = bpy.data.materials["fabric"].node_tree.nodes["Diffuse BSDF"]
    timed_sync("material edit", lambda: node.inputs["Color"].__setattr__("default_value", (0.6, 0.2, 0.2, 1)))
    lamp = next(o for o in bpy.data.objects if o.type == "LIGHT" and o.data.type == "AREA")
    timed_sync("light edit", lambda: setattr(lamp.data, "energy", 90.0))
    timed_sync("object add", lambda: bpy_scenes.box_object("crate", (1.0, -1.0, 0.0), (1.4, -0.6, 0.4),
                                                           bpy.data.materials["wood"]))
    timed_sync("object delete", lambda: bpy.data.objects.remove(bpy.data.objects["crate"]))
    session.stop()
    bpy.app.handlers.depsgraph_update_post.remove(handler)


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
    args = parser.parse_args(argv)
    bench_viewport(args.width, args.height, args.threads, args.samples, args.start_resolution, args.pixel_size)
    bench_preview(args.preview_size, args.threads, args.preview_samples)


if __name__ == "__main__":
    main()
