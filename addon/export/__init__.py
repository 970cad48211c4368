"""Export of Blender's evaluated depsgraph into a core Scene.

`export_scene(depsgraph)` walks `depsgraph.object_instances` once: every mesh-like object (meshes, and curves,
surfaces, text and metaballs through to_mesh), every instance (collection instances, geometry-node instances,
particles, array modifiers are already in the evaluated mesh) and every light, with their world matrices.
Each distinct mesh is converted once and placed at all its instances in one vectorised step.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ...core.scene import Scene, SceneError
from .camera import export_camera, render_region, render_resolution  # noqa: F401  (re-exported)
from .light import export_light
from .material import MaterialExporter
from .mesh import LocalMesh, instances_to_mesh, read_mesh
from .world import export_world

GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "META"}


@dataclass
class ExportStats:
    seconds: float = 0.0
    objects: int = 0
    instances: int = 0
    meshes_converted: int = 0
    triangles: int = 0
    lights: int = 0
    materials: int = 0
    textures: int = 0

    def line(self) -> str:
        return (f"Exported {self.triangles:,} triangles ({self.meshes_converted} meshes, {self.instances} "
                f"instances), {self.lights} lights, {self.materials} materials, {self.textures} textures "
                f"in {self.seconds:.2f} s")


@dataclass
class _Prototype:
    local: LocalMesh
    slot_materials: np.ndarray
    name: str
    matrices: list = field(default_factory=list)


def _matrix(m) -> np.ndarray:
    return np.array(m, dtype=np.float64).reshape(4, 4)


def _special_visibility(obj) -> bool:
    flags = ("visible_camera", "visible_shadow", "visible_diffuse", "visible_glossy", "visible_transmission")
    return not all(getattr(obj, f, True) for f in flags) or bool(getattr(obj, "is_holdout", False))


def _read_geometry(obj, warnings: list[str]) -> LocalMesh | None:
    if obj.type == "MESH":
        return read_mesh(obj.data, obj.name)
    try:
        mesh = obj.to_mesh()
    except RuntimeError as exc:
        warnings.append(f"object {obj.name!r} ({obj.type.lower()}) could not be converted to a mesh: {exc}")
        return None
    try:
        return None if mesh is None else read_mesh(mesh, obj.name)
    finally:
        obj.to_mesh_clear()


def export_scene(
    depsgraph,
    camera_object=None,
    *,
    log: Callable[[str], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> tuple[Scene, ExportStats]:
    """Build a core Scene from an evaluated depsgraph (the frame's). camera_object defaults to the scene's.

    Raises SceneError with a clear message for a scene without camera or without anything to render."""
    t0 = time.perf_counter()
    scene = depsgraph.scene
    warnings: list[str] = []
    stats = ExportStats()
    if camera_object is None:
        camera_object = scene.camera
    if camera_object is not None:
        camera_object = camera_object.evaluated_get(depsgraph)
    camera = export_camera(camera_object, scene, warnings)

    materials = MaterialExporter(warnings)
    prototypes: dict[tuple, _Prototype] = {}
    lights = []
    unsupported: dict[str, int] = {}
    visibility_warned: set[str] = set()
    for i, inst in enumerate(depsgraph.object_instances):
        if should_cancel is not None and i % 1024 == 1023 and should_cancel():
            raise KeyboardInterrupt("export cancelled")
        obj = inst.object
        kind = obj.type
        if kind == "LIGHT":
            if not inst.show_self:
                continue
            light = export_light(obj.name, obj.data, _matrix(inst.matrix_world), warnings)
            if light is not None:
                lights.append(light)
            continue
        if kind not in GEOMETRY_TYPES:
            if kind in ("CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"):
                unsupported[kind] = unsupported.get(kind, 0) + 1
            continue
        if not inst.show_self:
            continue
        original = obj.original
        if original.name not in visibility_warned and _special_visibility(obj):
            visibility_warned.add(original.name)
            warnings.append(f"object {original.name!r}: ray visibility and holdout settings are not supported; "
                            "rendered fully visible")
        slots = tuple(slot.material for slot in obj.material_slots)
        slot_key = tuple(0 if m is None else m.as_pointer() for m in slots)
        if kind == "MESH" and obj.data is not None:
            key = ("mesh", obj.data.as_pointer(), slot_key)
        else:
            key = ("object", original.as_pointer(), slot_key)
        proto = prototypes.get(key)
        if proto is None:
            local = _read_geometry(obj, warnings)
            if local is None or local.triangle_count == 0:
                prototypes[key] = proto = _Prototype(None, np.zeros(0, np.int32), obj.name)
            else:
                lut = [materials.index(m) for m in slots] or [materials.index(None)]
                proto = _Prototype(local, np.asarray(lut, dtype=np.int32), original.name)
                prototypes[key] = proto
                stats.meshes_converted += 1
        if proto.local is not None:
            proto.matrices.append(_matrix(inst.matrix_world))

    for kind, count in unsupported.items():
        warnings.append(f"{count} {kind.lower()} object(s) are not supported by Monte and are skipped")

    meshes = []
    for proto in prototypes.values():
        if proto.local is None or not proto.matrices:
            continue
        k = len(proto.matrices)
        stats.instances += k
        name = proto.name if k == 1 else f"{proto.name} (x{k} instances)"
        if proto.local.uvs is None and any(int(m) in materials.textured for m in proto.slot_materials):
            warnings.append(f"mesh {proto.name!r} has an image-textured material but no UV map; the texture is "
                            "sampled at UV (0, 0)")
        meshes.append(instances_to_mesh(proto.local, np.stack(proto.matrices), proto.slot_materials, name))

    if not materials.materials:
        materials.index(None)  # core needs at least one material
    world = export_world(scene.world, warnings)
    out = Scene(camera=camera, meshes=meshes, materials=materials.materials, lights=lights, world=world,
                textures=materials.textures, name=scene.name, warnings=warnings)
    if not meshes:
        raise SceneError(f"scene {scene.name!r} has no visible objects to render (meshes, curves, text, "
                         "metaballs); check the objects' render visibility and the view layer's collections")
    stats.seconds = time.perf_counter() - t0
    stats.objects = len(prototypes)
    stats.triangles = sum(m.triangle_count for m in meshes)
    stats.lights = len(lights)
    stats.materials = len(materials.materials)
    stats.textures = len(materials.textures)
    if log is not None:
        log(stats.line())
    return out, stats
