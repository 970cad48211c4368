"""Monte's interactive viewport (Rendered shading) and the progressive renders of material previews.

Three parts, each testable without a window:

- `SceneSync` keeps a core scene up to date from depsgraph updates, re-exporting only what changed: a moved object
  gets its instances re-placed (its mesh is not read again), an edited material is recompiled alone, a light edit
  re-exports the lights, a geometry edit or a new object reads that mesh, a deleted object is dropped. Every
  `sync()` says what it did in a `SyncReport`. It runs on Blender's main thread (bpy is not thread-safe).
- `ViewportSession` renders on a worker thread: the first image at a reduced resolution (Cycles' Start Resolution
  and Pixel Size), then one sample at a time up to the viewport sample count, each image a float RGBA array. A
  new change cancels the pass in flight and restarts; a camera (view) move re-prepares nothing (the prepared
  triangles and Embree scene are reused, rays start from the new position), a shading change rebuilds the
  shading tables and keeps the Embree scene, only a geometry change rebuilds both. Either way only the meshes
  the update brought are checked again (triangle by triangle); the kept ones were checked when they came.
- `camera_from_view` turns a 3D view's view and projection matrices into core's Camera; `draw_image` draws an
  image with Blender's `gpu` module (the engine brackets it with the view's colour management).

Images are row 0 at the TOP (core's convention); `draw_image` flips them for the GPU.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..core.scene import Camera, Scene, SceneError
from ..core.settings import RenderSettings
from .export import (GEOMETRY_TYPES, MESH_RAY_VISIBILITY, ExportStats, _object_rows, _prototype_for, _Prototype,
                     export_layer_world)
from .export.camera import export_camera
from .export.film import export_film
from .export.light import export_light
from .export.material import MaterialExporter
from .export.mesh import instances_to_mesh

# ------------------------------------------------------------------------------------------------ the view


def camera_from_view(view_matrix, window_matrix, size: tuple[int, int], lens: Camera | None = None) -> Camera:
    """core's Camera for a 3D view: view_matrix (world -> view) and window_matrix (OpenGL projection) as
    `RegionView3D` holds them, size = the region in pixels. Perspective and orthographic views; the projection's
    off-centre terms (camera shift, the camera view's zoom and pan) become the camera's shift. The near and far
    planes become the clipping range (an orthographic view's negative near plane moves the ray origins back).

    lens: in the camera view, the scene camera's export: its depth of field is applied (a perspective view keeps
    the camera's focal length, with the sensor scaled to the view's frame, so the aperture is the camera's)."""
    view = np.array(view_matrix, dtype=np.float64).reshape(4, 4)
    proj = np.array(window_matrix, dtype=np.float64).reshape(4, 4)
    w, h = int(size[0]), int(size[1])
    if w < 1 or h < 1:
        raise SceneError(f"viewport: the view is {w}x{h} pixels; nothing to render")
    try:
        cam_to_world = np.linalg.inv(view)
    except np.linalg.LinAlgError as exc:
        raise SceneError("viewport: the view matrix is singular") from exc
    ortho = abs(proj[3, 3] - 1.0) < 1e-9 and abs(proj[3, 2]) < 1e-9
    p00, p11 = proj[0, 0], proj[1, 1]
    if not (p00 > 0 and p11 > 0 and math.isfinite(p00) and math.isfinite(p11)):
        raise SceneError(f"viewport: unusable projection (scale {p00:g}, {p11:g})")
    if ortho:
        # x_ndc = p00 x + p03: the frame spans 2 / p00 metres, centred at -p03 / p00.
        extent = 2.0 / p00
        shift_x = -proj[0, 3] / 2.0
        shift_y = -proj[1, 3] / p11 / extent
        near = (proj[2, 3] + 1.0) / proj[2, 2]
        far = (proj[2, 3] - 1.0) / proj[2, 2]
        if near < 0:  # Blender's orthographic views see behind the view point: start the rays further back
            cam_to_world = cam_to_world.copy()
            cam_to_world[:3, 3] += cam_to_world[:3, 2] * (-near)
            far, near = far - near, 0.0
        return Camera(matrix_world=cam_to_world, resolution=(w, h), kind="ORTHO", ortho_scale=extent,
                      sensor_fit="HORIZONTAL", shift_x=shift_x, shift_y=shift_y, clip_start=near,
                      clip_end=far)
    # Perspective: x_ndc = (p00 x + p02 z) / -z; at distance 1 the frame spans 2 / p00, centred at p02 / p00.
    extent = 2.0 / p00
    focal = float(lens.lens) if lens is not None and lens.kind == "PERSP" else 50.0
    shift_x = proj[0, 2] / 2.0
    shift_y = proj[1, 2] / p11 / extent
    near = proj[2, 3] / (proj[2, 2] - 1.0)
    far = proj[2, 3] / (proj[2, 2] + 1.0)
    if not (0 <= near < far):
        near, far = 1e-3, 1e30
    camera = Camera(matrix_world=cam_to_world, resolution=(w, h), kind="PERSP", lens=focal,
                    sensor_width=extent * focal, sensor_height=extent * focal * h / w, sensor_fit="HORIZONTAL",
                    shift_x=shift_x, shift_y=shift_y, clip_start=near, clip_end=far)
    if lens is not None and lens.use_dof:
        camera = replace(camera, use_dof=True, aperture_fstop=lens.aperture_fstop,
                         focus_distance=lens.focus_distance, aperture_blades=lens.aperture_blades,
                         aperture_rotation=lens.aperture_rotation, aperture_ratio=lens.aperture_ratio)
    return camera


def pixel_size(scene) -> int:
    """The viewport's Pixel Size (Render Properties > Performance in Cycles): 1, 2, 4 or 8, or for "Automatic"
    Blender's interface pixel size (2 on high-density displays)."""
    value = scene.render.preview_pixel_size
    if value == "AUTO":
        import bpy

        return max(1, int(round(bpy.context.preferences.system.pixel_size)))
    return int(value)


def resolution_dividers(width: int, height: int, pixel_size: int, start_resolution: int) -> list[int]:
    """The reduced resolutions a restart goes through, as pixel dividers, largest first, ending at pixel_size:
    the first divider is pixel_size times the power of two that brings the image to about start_resolution^2
    pixels (Cycles' Start Resolution); each next pass halves it. start_resolution 0 starts at pixel_size."""
    pixel_size = max(1, int(pixel_size))
    divider = pixel_size
    if start_resolution > 0:
        w, h = width / pixel_size, height / pixel_size
        while w * h > start_resolution * start_resolution and min(w, h) >= 2:
            w, h, divider = w / 2, h / 2, divider * 2
    out = [divider]
    while divider > pixel_size:
        divider = max(pixel_size, divider // 2)
        out.append(divider)
    return out


# ---------------------------------------------------------------------------------------------- the export


@dataclass
class SyncReport:
    """What one SceneSync.sync() re-exported. Names are Blender object / material names.

    meshes_read: objects whose mesh was read (new, or geometry edited); moved: objects whose instances were only
    re-placed; removed: objects no longer in the scene; materials_compiled: materials converted (new or edited);
    lights_exported: lights exported (0 when the lights were kept); world_exported: the world was re-exported.
    rebuild: what the renderer must redo: "none", "shading" (materials, lights, world) or "geometry"."""

    meshes_read: list[str] = field(default_factory=list)
    moved: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    materials_compiled: list[str] = field(default_factory=list)
    lights_exported: int = 0
    world_exported: bool = False
    rebuild: str = "none"

    def line(self) -> str:
        parts = [f"{label} {', '.join(sorted(names))}" for label, names in
                 (("read", self.meshes_read), ("moved", self.moved), ("removed", self.removed),
                  ("compiled", self.materials_compiled)) if names]
        if self.lights_exported:
            parts.append(f"{self.lights_exported} lights")
        if self.world_exported:
            parts.append("world")
        return "; ".join(parts) or "nothing changed"


@dataclass
class DepsgraphChanges:
    """What depsgraph.updates flagged (pointers of original data-blocks)."""

    full: bool = False
    geometry: set = field(default_factory=set)  # object or mesh pointers whose geometry changed
    materials: dict = field(default_factory=dict)  # pointer -> material
    lights: bool = False
    world: bool = False


def merged_changes(parts: list[DepsgraphChanges]) -> DepsgraphChanges:
    """Several batches of updates (e.g. one per depsgraph handler call) as one."""
    merged = DepsgraphChanges()
    for part in parts:
        merged.full |= part.full
        merged.geometry |= part.geometry
        merged.materials.update(part.materials)
        merged.lights |= part.lights
        merged.world |= part.world
    return merged


def depsgraph_changes(depsgraph) -> DepsgraphChanges:
    """Read depsgraph.updates (valid inside view_update and depsgraph handlers) into plain sets."""
    import bpy

    changes = DepsgraphChanges()
    # A material edit also flags the objects using it as "geometry" updated, with their mesh flagged for
    # shading only: such an object's mesh is kept unless modifiers (or a non-mesh type) make it depend on more.
    mesh_shading_only = set()
    objects = []
    for update in depsgraph.updates:
        data = update.id
        original = getattr(data, "original", None) or data
        if isinstance(data, bpy.types.Object):
            if data.type == "LIGHT":
                changes.lights = True
            elif update.is_updated_geometry:
                objects.append(data)
        elif isinstance(data, bpy.types.Mesh) and not update.is_updated_geometry:
            mesh_shading_only.add(original.as_pointer())
        elif isinstance(data, bpy.types.Mesh) and update.is_updated_geometry:
            changes.geometry.add(original.as_pointer())
        elif isinstance(data, bpy.types.Material):
            changes.materials[original.as_pointer()] = data
        elif isinstance(data, bpy.types.Light):
            changes.lights = True
        elif isinstance(data, bpy.types.World):
            changes.world = True
        elif isinstance(data, bpy.types.Scene) and update.is_updated_shading:
            changes.world = True  # the scene's world was replaced
    for obj in objects:
        original = obj.original
        mesh = original.data if original.type == "MESH" else None
        if mesh is not None and not len(original.modifiers) and mesh.as_pointer() in mesh_shading_only:
            continue
        changes.geometry.add(original.as_pointer())
    return changes


class SceneSync:
    """An incrementally updated export of one depsgraph (see the module docstring). Main thread only."""

    def __init__(self) -> None:
        self.warnings: list[str] = []
        self.materials = MaterialExporter(self.warnings)
        self.prototypes: dict[tuple, _Prototype] = {}
        self.owners: dict[tuple, set] = {}  # prototype key -> original object/mesh pointers it came from
        self.meshes: dict[tuple, object] = {}  # prototype key -> placed core Mesh
        self.placed: dict[tuple, np.ndarray] = {}  # prototype key -> the matrices its mesh was placed with
        # prototype key -> per instance (r, g, b, a, pass index, random id): the object data node programs read
        self.instance_info: dict[tuple, np.ndarray] = {}
        # prototype key -> (its placed Mesh, the first object row scene() gave its instances)
        self.row_starts: dict[tuple, tuple] = {}
        self.film = None  # core.scene.Film of the scene (Film > Transparent...), exported on each sync
        self.light_matrices: list = []
        self.lights: list = []
        self.world = None
        self.synced = False
        self.geometry_version = 0
        self.shading_version = 0

    def sync(self, depsgraph, changes: DepsgraphChanges | None = None) -> SyncReport:
        """Bring the export up to date. changes: from depsgraph_changes(); None re-reads depsgraph.updates (a
        first sync exports everything)."""
        if changes is None:
            changes = DepsgraphChanges(full=True) if not self.synced else depsgraph_changes(depsgraph)
        if not self.synced:
            changes.full = True
        report = SyncReport()
        names = {}
        for key in list(self.prototypes):
            if changes.full or self.owners.get(key, set()) & changes.geometry:
                self._drop(key)
        for pointer, material in changes.materials.items():
            if self.materials.refresh(material):
                report.materials_compiled.append(material.name)
        materials_before = len(self.materials.materials)

        stats = ExportStats()
        resolved: dict[tuple[int, int], tuple | None] = {}
        matrices: dict[tuple, list] = {}
        infos: dict[tuple, list] = {}
        light_items = []
        for inst in depsgraph.object_instances:
            obj = inst.object
            kind = obj.type
            if kind == "LIGHT":
                if inst.show_self:
                    light_items.append((obj.name, obj.data, np.array(inst.matrix_world, np.float64)))
                continue
            if kind not in GEOMETRY_TYPES or not inst.show_self:
                continue
            data = obj.data
            rkey = (obj.as_pointer(), 0 if data is None else data.as_pointer())
            if rkey in resolved:
                key = resolved[rkey]
            else:
                new = stats.meshes_converted
                known = set(self.prototypes)
                key = resolved[rkey] = _prototype_for(obj, kind, self.prototypes, self.materials, self.warnings,
                                                      stats, depsgraph.view_layer)
                for k in set(self.prototypes) - known:
                    self.owners[k] = {obj.original.as_pointer()}
                    if data is not None and getattr(obj.original, "data", None) is not None:
                        self.owners[k].add(obj.original.data.as_pointer())
                if stats.meshes_converted > new:
                    report.meshes_read.append(obj.original.name)
            if key is not None:
                matrices.setdefault(key, []).append(np.array(inst.matrix_world, np.float64))
                infos.setdefault(key, []).append((*obj.color, obj.pass_index, inst.random_id))
                names.setdefault(key, obj.original.name)

        for key in list(self.meshes):
            if key not in matrices:
                report.removed.append(self.prototypes[key].name if key in self.prototypes else str(key))
                self._drop(key)
        read = set(report.meshes_read)
        for key, mats in matrices.items():
            stacked = np.array(mats, np.float64).reshape(-1, 4, 4)
            self.instance_info[key] = np.array(infos[key], np.float64).reshape(-1, 6)
            old = self.placed.get(key)
            if old is not None and old.shape == stacked.shape and np.array_equal(old, stacked):
                continue
            proto = self.prototypes[key]
            k = len(stacked)
            label = proto.name if k == 1 else f"{proto.name} (x{k} instances)"
            mesh = self.meshes[key] = instances_to_mesh(proto.local, stacked, proto.slot_materials, label,
                                                        proto.shadow_terminator_offset)
            for ray_kind, seen in zip(MESH_RAY_VISIBILITY, proto.visibility):
                setattr(mesh, f"visible_{ray_kind}", seen)
            mesh.shadow_catcher = proto.shadow_catcher  # the viewport forms Cycles' approximate catcher
            self.placed[key] = stacked
            if old is not None and names[key] not in read:
                report.moved.append(names[key])
        report.removed = [n for n in report.removed if n not in read]  # re-read under a new key: not removed

        report.materials_compiled += [m.name for m in self.materials.materials[materials_before:]]
        light_matrices = [(name, m) for name, _, m in light_items]
        same_lights = (len(light_matrices) == len(self.light_matrices) and all(
            a[0] == b[0] and np.array_equal(a[1], b[1]) for a, b in zip(light_matrices, self.light_matrices)))
        if changes.full or changes.lights or not same_lights:
            lights = [export_light(name, data, m, self.warnings) for name, data, m in light_items]
            self.lights = [light for light in lights if light is not None]
            self.light_matrices = light_matrices
            report.lights_exported = len(light_items)
        if changes.full or changes.world or self.world is None:
            self.world = export_layer_world(depsgraph.scene, depsgraph.view_layer, self.warnings)
            report.world_exported = True

        self.film = export_film(depsgraph.scene)
        if not self.materials.materials:
            self.materials.index(None)
        if report.meshes_read or report.moved or report.removed or changes.full:
            report.rebuild = "geometry"
            self.geometry_version += 1
        elif report.materials_compiled or report.lights_exported or report.world_exported:
            report.rebuild = "shading"
            self.shading_version += 1
        self.synced = True
        return report

    def _drop(self, key) -> None:
        for table in (self.prototypes, self.owners, self.meshes, self.placed, self.instance_info, self.row_starts):
            table.pop(key, None)

    def scene(self, camera: Camera, name: str = "viewport") -> Scene:
        """The current export as a core Scene seen through `camera` (raises SceneError when nothing is visible).
        It lists no shader AOV and no light group (the viewport shows Combined alone): nothing computes them."""
        if not self.meshes:
            raise SceneError("nothing to render in the viewport: no visible meshes, curves, text or metaballs")
        # The object table node programs read (object space, texture space, Object Info), as the exporter
        # builds it: one row per instance, each mesh's triangles pointing at their instance's row.
        meshes, rows, start = [], [], 0
        for key, mesh in self.meshes.items():
            proto, placed = self.prototypes[key], self.placed[key]
            k = placed.shape[0]
            rows.append(_object_rows(placed, self.instance_info[key], proto.texspace))
            previous_mesh, previous = self.row_starts.get(key, (None, 0))
            if (previous_mesh is mesh and isinstance(mesh.object_index, np.ndarray)
                    and len(mesh.object_index) == len(mesh.triangles)):
                # rows set before (and filtered with the triangles a preparation dropped, so the prototype's
                # count no longer fits): shifted to the instances' new first row
                mesh.object_index = (mesh.object_index - np.int32(previous) + np.int32(start)).astype(np.int32)
            else:
                mesh.object_index = np.repeat(np.arange(start, start + k, dtype=np.int32),
                                              proto.local.triangle_count)
            self.row_starts[key] = (mesh, start)
            start += k
            meshes.append(mesh)
        extra = {} if self.film is None else {"film": self.film}
        lights = list(self.lights) + list(self.world.lights)  # a Sky Texture's sun disc
        return Scene(camera=camera, meshes=meshes, materials=list(self.materials.materials), lights=lights,
                     world=self.world, textures=list(self.materials.textures), name=name,
                     warnings=list(self.warnings), objects=np.concatenate(rows).astype(np.float32),
                     uv_layer_names=list(self.materials.uv_names),
                     attribute_names=list(self.materials.attribute_names),
                     tangent_layer_names=list(self.materials.tangent_names), **extra)


def scene_camera_view(depsgraph, size: tuple[int, int]) -> Camera:
    """The scene camera as a view of `size` pixels (Blender's camera view fitted to the region), for callers
    without a 3D view (tests, benchmarks)."""
    scene = depsgraph.scene
    if scene.camera is None:
        raise SceneError("scene has no camera: add a camera and make it the scene's active camera")
    camera = export_camera(scene.camera.evaluated_get(depsgraph), scene, [])
    return replace(camera, resolution=(int(size[0]), int(size[1])))


# ---------------------------------------------------------------------------------------------- rendering


@dataclass
class ViewImage:
    """One published viewport image: rgba (h, w, 4) float32 linear, row 0 at the top, at the view's size divided
    by `divider`; samples per pixel in it; the view size it is drawn at; `version` grows with each image."""

    rgba: np.ndarray
    samples: int
    divider: int
    view_size: tuple[int, int]
    version: int
    seconds: float  # since the change that started this image's restart


class Accumulator:
    """The running mean of images of independent sample passes (each weighted by its sample count)."""

    def __init__(self) -> None:
        self.sum: np.ndarray | None = None
        self.samples = 0

    def add(self, color: np.ndarray, samples: int) -> np.ndarray:
        if self.sum is None or self.sum.shape != color.shape:
            self.sum, self.samples = np.zeros_like(color, dtype=np.float64), 0
        self.sum += np.asarray(color, np.float64) * samples
        self.samples += samples
        return (self.sum / self.samples).astype(np.float32)


def progressive_passes(scene: Scene, settings: RenderSettings, total_samples: int, prepared,
                       on_image: Callable[[np.ndarray, int], None], should_cancel: Callable[[], bool],
                       first_samples: int = 1) -> int:
    """Render `scene` in passes of growing sample counts (first_samples, then doubling) with independent seeds,
    calling on_image(mean RGBA image, samples so far) after each; stops early when should_cancel() turns true
    (a cancelled pass is dropped). Returns the samples taken. Used by material previews."""
    from ..core.render import render as core_render

    acc = Accumulator()
    count = max(1, int(first_samples))
    while acc.samples < total_samples:
        count = min(count, total_samples - acc.samples)
        result = core_render(scene, settings.replace(spp=count, seed=(settings.seed + acc.samples) % 2**32),
                             prepared=prepared, should_cancel=should_cancel)
        if result.cancelled:
            break
        on_image(acc.add(result.color, count), acc.samples)
        count *= 2
    return acc.samples


class ViewportSession:
    """A progressive viewport render on a worker thread (see the module docstring).

    Main thread: `sync(depsgraph)` after depsgraph updates, `set_view(camera)` before each draw, `image()` to
    draw. The worker restarts whenever either brings a change. samples: the viewport sample count; pixel_size
    and start_resolution: Cycles' meanings. on_image is called (from the worker) after each new image."""

    def __init__(self, settings: RenderSettings, samples: int, pixel_size: int = 1, start_resolution: int = 64,
                 on_image: Callable[[], None] | None = None) -> None:
        if samples < 1:
            raise ValueError(f"viewport samples must be at least 1, got {samples}")
        # The viewport shows Combined alone: no pass beside it is computed (the data passes, the light passes, the
        # denoising features; its scene lists no shader AOV and no light group, see SceneSync.scene).
        self.settings = settings.replace(aovs=False, denoising_features=False, data_passes=(), light_passes=(),
                                         time_limit=0.0, adaptive_threshold=0.0,
                                         error_estimate=False).validate()  # nothing reads it: one scramble
        self.samples = int(samples)
        self.pixel_size = max(1, int(pixel_size))
        self.start_resolution = max(0, int(start_resolution))
        self.sync_state = SceneSync()
        self.camera: Camera | None = None
        self.error: str | None = None
        self.last_report: SyncReport | None = None
        self.prepare_count = {"geometry": 0, "shading": 0}  # how often the worker rebuilt each (for tests)
        self._checked_meshes: dict[int, object] = {}  # (worker) id -> the meshes the last preparation validated
        self._on_image = on_image
        self._cond = threading.Condition()
        self._callback_lock = threading.Lock()
        self._generation = 0
        self._changed_at = time.perf_counter()
        self._scene_parts: Scene | None = None
        self._versions = (0, 0)
        self._image: ViewImage | None = None
        self._image_version = 0
        self._image_generation = -1
        self._done_generation = -1
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="monte-viewport", daemon=True)
        self._thread.start()

    # --------------------------------------------------------------------------------------- main thread
    def sync(self, depsgraph, changes: DepsgraphChanges | None = None) -> SyncReport:
        """Export what changed (see SceneSync.sync) and restart the render if anything did. A scene Monte cannot
        export sets `error` (shown in the viewport) instead of raising."""
        try:
            report = self.sync_state.sync(depsgraph, changes)
            scene = self.sync_state.scene(self.camera or Camera(matrix_world=np.eye(4)),
                                          name=depsgraph.scene.name)
        except SceneError as exc:
            with self._cond:
                self.error = str(exc)
                self._scene_parts = None
                self._restart()
            self.last_report = None
            return SyncReport()
        self.last_report = report
        versions = (self.sync_state.geometry_version, self.sync_state.shading_version)
        with self._cond:
            if self.error is not None or versions != self._versions or self._scene_parts is None:
                self.error = None
                self._scene_parts, self._versions = scene, versions
                self._restart()
        return report

    def set_view(self, camera: Camera) -> bool:
        """The view to render; restarts (camera only: nothing is re-exported or rebuilt) when it changed.
        Returns whether it changed."""
        camera.validate()
        with self._cond:
            if self.camera is not None and _same_camera(self.camera, camera):
                return False
            self.camera = camera
            self._restart()
        return True

    def image(self) -> ViewImage | None:
        """The newest image (None before the first one); right after a change, the previous state's until the
        first image of the new one arrives."""
        with self._cond:
            return self._image

    @property
    def done(self) -> bool:
        """All viewport samples of the current state are in the image."""
        with self._cond:
            return self._done_generation == self._generation

    def wait(self, samples: int | None = None, timeout: float = 120.0) -> ViewImage:
        """Block until the image holds `samples` (default: all) samples of the current state or an error is set;
        for tests and benchmarks. Raises TimeoutError or SceneError (the session's error)."""
        target = self.samples if samples is None else samples
        deadline = time.perf_counter() + timeout
        with self._cond:
            generation = self._generation
            while True:
                if self.error is not None:
                    raise SceneError(self.error)
                img = self._image
                if img is not None and self._image_generation == generation and img.samples >= target \
                        and img.divider == self.pixel_size:
                    return img
                left = deadline - time.perf_counter()
                if left <= 0:
                    raise TimeoutError(f"viewport: no image with {target} samples after {timeout} s")
                self._cond.wait(left)

    def stop(self) -> None:
        """End the worker (the pass in flight is cancelled); no on_image call after this returns."""
        with self._callback_lock:
            self._on_image = None
        with self._cond:
            self._stopped = True
            self._generation += 1
            self._cond.notify_all()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def _restart(self) -> None:
        """(lock held) A change: the worker drops what it renders and starts over. The last image stays
        available to draw until the first one of the new state replaces it (no blank frame while orbiting)."""
        self._generation += 1
        self._changed_at = time.perf_counter()
        self._cond.notify_all()

    # --------------------------------------------------------------------------------------- worker
    def _run(self) -> None:
        prepared = None  # (PreparedScene, Accelerator)
        built = (-1, -1)
        geometry_camera: Camera | None = None
        while True:
            with self._cond:
                while not self._stopped and (self._scene_parts is None or self.camera is None
                                             or self._done_generation == self._generation or self.error):
                    self._cond.wait()
                if self._stopped:
                    return
                generation, parts, camera = self._generation, self._scene_parts, self.camera
                versions, changed_at = self._versions, self._changed_at
            try:
                if prepared is None or versions[0] != built[0]:
                    # The geometry's frame is centred on the camera of the time; later camera moves keep it.
                    geometry_camera = camera
                    prepared = self._prepare(replace(parts, camera=camera), None)
                    self.prepare_count["geometry"] += 1
                    built = versions
                elif versions[1] != built[1]:
                    prepared = self._prepare(replace(parts, camera=geometry_camera), prepared[1])
                    self.prepare_count["shading"] += 1
                    built = versions
                self._render_passes(generation, replace(parts, camera=camera), prepared, changed_at)
            except Exception as exc:  # noqa: BLE001 - shown in the viewport; Blender keeps running
                import traceback

                print("Monte: viewport render failed:\n" + traceback.format_exc(), flush=True)
                with self._cond:
                    if generation == self._generation:
                        self.error = f"{type(exc).__name__}: {exc}" if not isinstance(exc, SceneError) else str(exc)
                        self._cond.notify_all()
                prepared = None

    def _prepare(self, scene: Scene, accel):
        """(worker) core.render.prepare_scene's work, with the Embree scene `accel` kept when given (a shading
        change). Meshes the previous preparation validated and the update kept (the same Mesh objects: SceneSync
        replaces a mesh it re-places or re-reads) skip their per-triangle checks, which on a big scene cost more
        than the update itself (core.scene.Scene.validate's checked_meshes)."""
        from ..core.accel import Accelerator
        from ..core.integrator import PreparedScene

        scene.validate(checked_meshes=self._checked_meshes.keys())
        # Holding the meshes keeps their ids from being reused by new ones while they are trusted.
        self._checked_meshes = {id(mesh): mesh for mesh in scene.meshes}
        prepared = PreparedScene.build(scene, sample_world=self.settings.light_sampling == "light",
                                       threads=self.settings.thread_count)
        if accel is None:
            accel = Accelerator(prepared.vertices, prepared.triangles, motion=prepared.motion)
        return prepared, accel

    def _render_passes(self, generation: int, scene: Scene, prepared, changed_at: float) -> None:
        from ..core.render import render as core_render

        def cancelled() -> bool:
            return self._generation != generation

        w, h = scene.camera.resolution
        acc = Accumulator()
        for divider in resolution_dividers(w, h, self.pixel_size, self.start_resolution):
            size = (max(1, w // divider), max(1, h // divider))
            small = replace(scene, camera=replace(scene.camera, resolution=size))
            final = divider == self.pixel_size
            while True:
                seed = (self.settings.seed + acc.samples) % 2**32
                result = core_render(small, self.settings.replace(spp=1, seed=seed), prepared=prepared,
                                     should_cancel=cancelled)
                if result.cancelled or cancelled():
                    return
                rgba = acc.add(result.color, 1) if final else result.color
                finished = final and acc.samples >= self.samples
                self._publish(generation, rgba, acc.samples if final else 1, divider, (w, h), changed_at, finished)
                if not final or finished:
                    break

    def _publish(self, generation, rgba, samples, divider, size, changed_at, finished: bool) -> None:
        with self._cond:
            if generation != self._generation:
                return
            if finished:
                self._done_generation = generation
            self._image_version += 1
            self._image = ViewImage(rgba, samples, divider, size, self._image_version,
                                    time.perf_counter() - changed_at)
            self._image_generation = generation
        with self._callback_lock:  # outside the state lock: the callback may read image()
            if self._on_image is not None:
                self._on_image()
        with self._cond:  # waiters wake after the callback saw the image
            self._cond.notify_all()


def _same_camera(a: Camera, b: Camera) -> bool:
    return (a.resolution == b.resolution and np.array_equal(np.asarray(a.matrix_world), np.asarray(b.matrix_world))
            and (a.kind, a.lens, a.sensor_width, a.ortho_scale, a.shift_x, a.shift_y, a.clip_start, a.clip_end)
            == (b.kind, b.lens, b.sensor_width, b.ortho_scale, b.shift_x, b.shift_y, b.clip_start, b.clip_end))


# ---------------------------------------------------------------------------------------------- drawing


def image_texture(rgba: np.ndarray):
    """A GPUTexture (RGBA32F) of an image with row 0 at the top (flipped: GPU textures start at the bottom).

    The Buffer wraps the array without a copy; RGBA32F uploads it as it is (RGBA16F would convert every value
    on the CPU first: 30-50 ms instead of 10-20 ms for 1280x720 here)."""
    import gpu

    h, w = rgba.shape[:2]
    flat = np.ascontiguousarray(rgba[::-1], dtype=np.float32).reshape(-1)
    buffer = gpu.types.Buffer("FLOAT", flat.size, flat)
    return gpu.types.GPUTexture((w, h), format="RGBA32F", data=buffer)


def draw_texture(texture, width: int, height: int) -> None:
    """Draw `texture` stretched over (0, 0)-(width, height) of the current region (pixel space)."""
    from gpu_extras.presets import draw_texture_2d

    draw_texture_2d(texture, (0, 0), width, height)
