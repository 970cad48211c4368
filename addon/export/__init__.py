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

from ...core.motion import densify_transforms, resample_steps
from ...core.scene import Scene, SceneError, World
from .camera import export_camera, render_region, render_resolution  # noqa: F401  (re-exported)
from .film import export_film
from .light import export_light, is_portal, portal_geometry
from .light_linking import LightLinking
from .material import MaterialExporter
from .mesh import LocalMesh, instances_to_mesh, read_mesh
from .motion import (Shutter, deforms, instance_key, object_steps, placed_motion, sample_motion,
                     shutter as motion_shutter, take_steps)
from .nodes.vector_rules import tangent_uv_maps
from .world import export_mist, export_world

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
    instance_info: list = field(default_factory=list)  # per instance: (r, g, b, a, pass index, random id)
    instance_names: list = field(default_factory=list)  # per instance: (object name, asset name) for Cryptomatte
    texspace: tuple | None = None  # (location, size) of the mesh's texture space (Generated coordinates)
    visibility: tuple = (True,) * 5  # Mesh.visible_<kind> for each of MESH_RAY_VISIBILITY
    shadow_terminator_offset: float = 0.0
    shadow_catcher: bool = False  # Object > Visibility > Shadow Catcher (core.scene.Mesh.shadow_catcher)
    # light and shadow linking: Mesh.light_sets, shadow_sets, receiver_set, blocker_set (export/light_linking.py)
    links: tuple = (-1, -1, 0, 0)
    lightgroup: str = ""  # Object > Shading > Light Group (core.scene.Mesh.lightgroup)
    instance_keys: list = field(default_factory=list)  # per instance: its key across subframes (motion blur)
    steps: int = 0  # motion steps (the most of its instances'); 0: no motion blur
    deform_name: str | None = None  # the object whose deforming mesh this is (deformation blur), or None


# Object > Visibility > Ray Visibility flags Monte renders on meshes (core.scene.Mesh.visible_<kind>).
MESH_RAY_VISIBILITY = ("camera", "shadow", "diffuse", "glossy", "transmission")
# Ray Visibility flags Monte does not render (property -> the name Blender's panel shows): on meshes, and on lights.
UNSUPPORTED_RAY_VISIBILITY = {"visible_volume_scatter": "Volume Scatter"}
UNSUPPORTED_LIGHT_VISIBILITY = {"visible_volume_scatter": "Volume Scatter"}
# Ray Visibility flags Monte renders on lights (core.scene lights' visible_<kind>, core.light_visibility).
LIGHT_RAY_VISIBILITY = ("diffuse", "glossy", "transmission")


def _matrix(m) -> np.ndarray:
    return np.array(m, dtype=np.float64).reshape(4, 4)


class ExportCancelled(Exception):
    """should_cancel returned True during the export."""


def _prototype_for(obj, kind, prototypes, materials, warnings, stats, view_layer=None, linking=None):
    """The prototype key for an (object, data) pair seen for the first time, converting its mesh if new;
    None when it has nothing to render. linking: the export's LightLinking (None: none)."""
    original = obj.original
    _warn_object_settings(obj, original, view_layer, warnings)
    links = (-1, -1, 0, 0)
    if linking is not None and linking.active:
        links = (*linking.membership(obj), *linking.emitter(obj))
    held = is_holdout(original, view_layer)
    seen = tuple(bool(getattr(obj, f"visible_{kind}", True)) for kind in MESH_RAY_VISIBILITY)
    if is_indirect_only(original, view_layer):
        seen = (False,) + seen[1:]  # Cycles renders an Indirect Only collection as hidden from camera rays
    slots = tuple(slot.material for slot in obj.material_slots)
    override = getattr(view_layer, "material_override", None) if view_layer is not None else None
    if override is not None:  # View Layer > Material Override: every slot, or the one an object without slots gets
        slots = tuple(override for _ in slots) or (override,)
    catcher = bool(getattr(obj, "is_shadow_catcher", False))
    lightgroup = str(getattr(original, "lightgroup", "") or "")
    slot_key = (tuple(0 if m is None else m.as_pointer() for m in slots) + (("holdout",) if held else ()) + seen
                + (("shadow catcher",) if catcher else ()) + (() if links == (-1, -1, 0, 0) else (("links",) + links))
                + ((("lightgroup", lightgroup),) if lightgroup else ()))
    terminator = _terminator_offset(original)
    if kind == "MESH" and obj.data is not None:
        key = ("mesh", obj.data.as_pointer(), slot_key, terminator)
    else:
        key = ("object", original.as_pointer(), slot_key, terminator)
    proto = prototypes.get(key)
    if proto is not None:
        return key if proto.local is not None else None
    n_slots = max(len(slots), 1)
    lut = np.zeros(n_slots, dtype=np.int32)
    material_of = materials.holdout_index if held else materials.index
    used_materials: list[int] = []

    def attribute_names(tri_slots: np.ndarray) -> list[str]:
        # Only the slots some triangle uses become materials (geometry nodes often leave empty slots); the mesh
        # then reads the attributes their Attribute nodes name.
        for slot in np.unique(np.clip(tri_slots, 0, n_slots - 1)):
            lut[slot] = material_of(slots[slot] if slot < len(slots) else None)
            used_materials.append(int(lut[slot]))
        return materials.attribute_names_of(used_materials)

    local = _read_geometry(obj, warnings, attribute_names, tangent_uv_maps(slots))
    if local is None or local.triangle_count == 0:
        prototypes[key] = _Prototype(None, np.zeros(0, np.int32), original.name)
        return None
    if not used_materials:  # read_mesh asks only for a mesh with triangles
        attribute_names(local.slots)
    materials.warn_missing_attributes(used_materials, local.missing_attributes, original.name)
    prototypes[key] = _Prototype(local, lut, original.name, texspace=_texspace(obj, local), visibility=seen,
                                 shadow_terminator_offset=terminator, shadow_catcher=catcher, links=links,
                                 lightgroup=lightgroup)
    stats.meshes_converted += 1
    return key


def _warn_once(warnings: list[str], msg: str) -> None:
    if msg not in warnings:
        warnings.append(msg)


def _warn_light_settings(obj, warnings: list[str]) -> None:
    """Name each light setting that changes Cycles' image and that Monte does not render."""
    name = obj.original.name
    off = [label for prop, label in UNSUPPORTED_LIGHT_VISIBILITY.items() if not getattr(obj, prop, True)]
    if off:
        _warn_once(warnings, f"light {name!r}: Ray Visibility {', '.join(off)} off is not supported; the light "
                             f"is seen by {', '.join(label.lower() for label in off)} rays")


def _warn_object_settings(obj, original, view_layer, warnings: list[str]) -> None:
    """Name each object setting that changes Cycles' image and that Monte does not render."""
    name = original.name
    off = [label for prop, label in UNSUPPORTED_RAY_VISIBILITY.items() if not getattr(obj, prop, True)]
    if off:
        _warn_once(warnings, f"object {name!r}: Ray Visibility {', '.join(off)} off is not supported; rendered "
                             f"visible to {', '.join(label.lower() for label in off)} rays")
    for system in getattr(obj, "particle_systems", ()):
        settings = system.settings
        if settings.type == "HAIR" and settings.render_type == "PATH":
            _warn_once(warnings, f"object {name!r}: particle hair (particle system {system.name!r}) is not "
                                 "supported and is skipped")


def _warn_simplify(scene, warnings: list[str]) -> None:
    """Render > Simplify: Max Subdivision and Child Particles reach Monte through the render's evaluated depsgraph
    (Blender applies them); the Cycles settings below it that Cycles applies itself, Monte does not."""
    cycles = getattr(scene, "cycles", None)
    if not scene.render.use_simplify or cycles is None:
        return
    limit = getattr(cycles, "texture_limit_render", "OFF")
    if limit != "OFF":
        warnings.append(f"render: Simplify > Texture Limit {limit} is not supported; image textures are read at "
                        "their full size")
    resolution = float(getattr(cycles, "texture_resolution_render", 1.0))
    if resolution != 1.0:
        warnings.append(f"render: Simplify > Texture Resolution {resolution:g} is not supported; image textures are "
                        "read at their full size")
    ao_bounces = int(getattr(cycles, "ao_bounces_render", 0))
    if ao_bounces > 0:
        warnings.append(f"render: Simplify > AO Bounces {ao_bounces} is not supported; every bounce is path traced")


def layer_world(scene, view_layer):
    """The world the view layer renders: its World Override, else the scene's (None: none)."""
    override = getattr(view_layer, "world_override", None) if view_layer is not None else None
    return override if override is not None else scene.world


def export_layer_world(scene, view_layer, warnings: list[str]) -> World:
    """The core World of the view layer's world (layer_world); black, as Cycles renders it, with the view layer's
    Sky (Use Sky) off: the background shader is not evaluated, for camera rays and lighting alike."""
    if view_layer is not None and not getattr(view_layer, "use_sky", True):
        return World(np.zeros(3))
    return export_world(layer_world(scene, view_layer), warnings)


def _warn_view_layer(view_layer, warnings: list[str]) -> None:
    """View layer settings Cycles reads that Monte does not render (Sky off is rendered: the world is black)."""
    if view_layer is None:
        return
    name = view_layer.name
    samples = int(getattr(view_layer, "samples", 0) or 0)
    if samples > 0:
        warnings.append(f"view layer {name!r}: Samples {samples} (the view layer's override) is not supported; Monte "
                        "renders its own Samples setting")
    if not getattr(view_layer, "use_solid", True):
        warnings.append(f"view layer {name!r}: Surfaces (Use Solid) off is not supported; surfaces are rendered")


def is_indirect_only(obj, view_layer) -> bool:
    """Whether an (original) object is in a collection set to Indirect Only in the view layer."""
    if view_layer is None:
        return False
    try:
        return bool(obj.indirect_only_get(view_layer=view_layer))
    except (AttributeError, RuntimeError, TypeError):
        return False


def is_holdout(obj, view_layer) -> bool:
    """Whether an (original) object is held out: its own Holdout setting, or a collection set to Holdout in the
    view layer (Blender's `holdout_get`)."""
    if getattr(obj, "is_holdout", False):
        return True
    if view_layer is None:
        return False
    try:
        return bool(obj.holdout_get(view_layer=view_layer))
    except (AttributeError, RuntimeError, TypeError):
        return False


def _terminator_offset(obj) -> float:
    """The object's Shading > Shadow Terminator > Geometry Offset (Cycles' setting; Blender keeps it in [0, 1],
    default 0.1)."""
    return float(getattr(obj, "shadow_terminator_geometry_offset", 0.1))


def _read_geometry(obj, warnings: list[str], attribute_names=None, tangent_maps=()) -> LocalMesh | None:
    if obj.type == "MESH":
        return read_mesh(obj.data, obj.name, attribute_names, tangent_maps, warnings)
    try:
        mesh = obj.to_mesh()
    except RuntimeError as exc:
        warnings.append(f"object {obj.name!r} ({obj.type.lower()}) could not be converted to a mesh: {exc}")
        return None
    try:
        return None if mesh is None else read_mesh(mesh, obj.name, attribute_names, tangent_maps, warnings)
    finally:
        obj.to_mesh_clear()


def export_scene(
    depsgraph,
    camera_object=None,
    *,
    log: Callable[[str], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
    frame_set: Callable[[int, float], None] | None = None,
    motion_blur: bool = True,
    vector_pass: bool = False,
) -> tuple[Scene, ExportStats]:
    """Build a core Scene from an evaluated depsgraph (the frame's). camera_object defaults to the scene's.

    vector_pass (without motion blur): the objects and the camera are also evaluated at the previous and the next
    frame, for the Vector pass (core.scene.Mesh.vector_vertices, Camera.vector_matrices).

    With Render > Motion Blur on (and motion_blur), the scene is also evaluated at subframes over the shutter
    (addon/export/motion.py) through frame_set(frame, subframe): the render engine's own (RenderEngine.frame_set,
    for its depsgraph), by default the scene's frame_set (the view layer's depsgraph); the frame is set back.

    With the shutter starting or ending on the frame (Position Start or End), objects, lights and the camera are
    exported at the shutter's centre, as Cycles syncs them there; the world at the frame, as Cycles' is.

    Raises SceneError with a clear message for a scene without camera or without anything to render."""
    t0 = time.perf_counter()
    scene = depsgraph.scene
    warnings: list[str] = []
    shutter = motion_shutter(scene, warnings, depsgraph.view_layer) if motion_blur else None
    # The Vector pass without motion blur (Cycles renders it only then): the motion from the previous to the next
    # frame, sampled as a shutter of two frames centred on this one and kept apart from the rays (no blur)
    vector_only = shutter is None and vector_pass
    if vector_only:
        shutter = Shutter(int(scene.frame_current), float(scene.frame_subframe), -1.0, 2.0)
    if shutter is not None and frame_set is None:
        def frame_set(frame: int, subframe: float) -> None:
            scene.frame_set(frame, subframe=subframe)
    moved = shutter is not None and shutter.reference != (shutter.frame, shutter.subframe)
    if moved:
        frame_set(*shutter.reference)
    try:
        out = _export_scene(depsgraph, camera_object, log, should_cancel, frame_set, shutter, warnings, t0)
    finally:
        if moved:
            frame_set(shutter.frame, shutter.subframe)
    if moved:
        portals = out[0].world.portals
        # the world at the frame (its warnings are the centre's, already given)
        out[0].world = export_layer_world(scene, depsgraph.view_layer, [])
        out[0].world.portals = portals
    if vector_only:
        _motion_to_vectors(out[0])
    return out


def _motion_to_vectors(core_scene: Scene) -> None:
    """Move the sampled motion (previous frame, ..., next frame) from motion blur's fields to the Vector pass's:
    Mesh.vector_vertices and Camera.vector_matrices; the render itself stays still."""
    for mesh in core_scene.meshes:
        if mesh.motion_vertices is not None:
            steps = np.asarray(mesh.motion_vertices, np.float64)
            mesh.vector_vertices = np.stack([steps[0], steps[-1]])
            mesh.motion_vertices = mesh.motion_normals = None
    cam = core_scene.camera
    if cam.motion_matrices is not None:
        steps = np.asarray(cam.motion_matrices, np.float64)
        cam.vector_matrices = np.stack([steps[0], steps[-1]])
    cam.motion_matrices = cam.motion_lens = cam.shutter_curve = cam.rolling_shutter = None


def _export_scene(depsgraph, camera_object, log, should_cancel, frame_set, shutter, warnings: list[str],
                  t0: float) -> tuple[Scene, ExportStats]:
    """export_scene's work, with the scene at the shutter's reference time (see export_scene)."""
    scene = depsgraph.scene
    stats = ExportStats()
    if camera_object is None:
        camera_object = scene.camera
    if camera_object is not None:
        camera_object = camera_object.evaluated_get(depsgraph)
    camera = export_camera(camera_object, scene, warnings)
    _warn_simplify(scene, warnings)

    _warn_view_layer(depsgraph.view_layer, warnings)
    shader_aovs = view_layer_aovs(depsgraph.view_layer, layer_world(scene, depsgraph.view_layer), warnings)
    materials = MaterialExporter(warnings, None if camera is None else camera.matrix_world, shader_aovs)
    prototypes: dict[tuple, _Prototype] = {}
    # (object pointer, data pointer) -> prototype key or None (skip). Blender reuses one temporary object
    # for many geometry-node instances, so this keeps the per-instance work to a few attribute reads.
    resolved: dict[tuple[int, int], tuple | None] = {}
    lights = []
    portals = []  # light portals (core.scene.World.portals)
    unsupported: dict[str, int] = {}
    linking = LightLinking(depsgraph.objects, warnings)
    for i, inst in enumerate(depsgraph.object_instances):
        if should_cancel is not None and i % 1024 == 1023 and should_cancel():
            raise ExportCancelled()
        obj = inst.object
        kind = obj.type
        if kind == "LIGHT":
            if inst.show_self and is_portal(obj.data):
                portals.append(portal_geometry(obj.data, _matrix(inst.matrix_world)))
            elif inst.show_self:
                light = export_light(obj.name, obj.data, _matrix(inst.matrix_world), warnings)
                if light is not None:
                    light.visible_camera = bool(getattr(obj, "visible_camera", False))
                    light.cast_shadow = bool(getattr(obj.data, "use_shadow", True))
                    light.receiver_set, light.blocker_set = linking.emitter(obj)
                    light.lightgroup = str(getattr(obj.original, "lightgroup", "") or "")
                    for ray in LIGHT_RAY_VISIBILITY:
                        setattr(light, f"visible_{ray}", bool(getattr(obj, f"visible_{ray}", True)))
                    _warn_light_settings(obj, warnings)
                    lights.append(light)
            continue
        if kind not in GEOMETRY_TYPES:
            if kind in ("CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"):
                unsupported[kind] = unsupported.get(kind, 0) + 1
            continue
        if not inst.show_self:
            continue
        data = obj.data
        rkey = (obj.as_pointer(), 0 if data is None else data.as_pointer())
        if rkey in resolved:
            key = resolved[rkey]
        else:
            key = resolved[rkey] = _prototype_for(obj, kind, prototypes, materials, warnings, stats,
                                                  depsgraph.view_layer, linking)
        if key is not None:
            proto = prototypes[key]
            proto.matrices.append(inst.matrix_world.copy())
            proto.instance_info.append((*obj.color, obj.pass_index, inst.random_id))
            proto.instance_names.append((obj.name, _asset_name(inst, obj)))
            if shutter is not None:
                parent = inst.parent.original if inst.is_instance and inst.parent is not None else None
                steps = object_steps(obj.original, parent)
                proto.instance_keys.append(instance_key(inst))
                proto.steps = max(proto.steps, steps)
                if steps and not inst.is_instance and deforms(obj.original, scene):
                    proto.deform_name = obj.original.name

    for kind, count in unsupported.items():
        warnings.append(f"{count} {kind.lower()} object(s) are not supported by Monte and are skipped")

    motion = None
    if shutter is not None:
        motion = _sample_motion(depsgraph, frame_set, shutter, prototypes, camera_object, camera, warnings)
        camera.shutter_curve = shutter.curve
        camera.rolling_shutter = shutter.rolling

    meshes = []
    object_rows = []
    object_names: list[str] = []
    asset_names: list[str] = []
    for proto in prototypes.values():
        if proto.local is None or not proto.matrices:
            continue
        k = len(proto.matrices)
        stats.instances += k
        name = proto.name if k == 1 else f"{proto.name} (x{k} instances)"
        if proto.local.uvs is None and any(int(m) in materials.textured for m in proto.slot_materials):
            warnings.append(f"mesh {proto.name!r} has an image-textured material but no UV map; the texture is "
                            "sampled at UV (0, 0)")
        matrices = np.array(proto.matrices, dtype=np.float64).reshape(k, 4, 4)
        mesh = instances_to_mesh(proto.local, matrices, proto.slot_materials, name,
                                 proto.shadow_terminator_offset)
        start = sum(len(r) for r in object_rows)
        object_rows.append(_object_rows(matrices, np.array(proto.instance_info, np.float64).reshape(k, 6),
                                        proto.texspace))
        mesh.object_index = np.repeat(np.arange(start, start + k, dtype=np.int32), proto.local.triangle_count)
        object_names += [names[0] for names in proto.instance_names]
        asset_names += [names[1] for names in proto.instance_names]
        for kind, seen in zip(MESH_RAY_VISIBILITY, proto.visibility):
            setattr(mesh, f"visible_{kind}", seen)
        mesh.shadow_catcher = proto.shadow_catcher
        mesh.light_sets, mesh.shadow_sets, mesh.receiver_set, mesh.blocker_set = proto.links
        mesh.lightgroup = proto.lightgroup
        if motion is not None and proto.steps:
            _attach_motion(mesh, proto, matrices, motion, warnings)
        meshes.append(mesh)

    if not materials.materials:
        materials.index(None)  # core needs at least one material
    world = export_layer_world(scene, depsgraph.view_layer, warnings)
    world_object = layer_world(scene, depsgraph.view_layer)
    world.portals = np.stack(portals) if portals else None
    world.lightgroup = str(getattr(world_object, "lightgroup", "") or "") if world_object is not None else ""
    lights = lights + world.lights  # a Sky Texture's sun disc
    out = Scene(camera=camera, meshes=meshes, materials=materials.materials, lights=lights, world=world,
                textures=materials.textures, name=scene.name, warnings=warnings,
                film=export_film(scene, depsgraph.view_layer),
                objects=np.concatenate(object_rows).astype(np.float32) if object_rows else None,
                uv_layer_names=list(materials.uv_names), mist=export_mist(world_object),
                object_names=object_names, asset_names=asset_names,
                attribute_names=list(materials.attribute_names),
                tangent_layer_names=list(materials.tangent_names), shader_aovs=shader_aovs,
                light_groups=view_layer_light_groups(depsgraph.view_layer))
    if out.light_groups and out.has_shadow_catcher:
        from ..core.light_groups import SHADOW_CATCHER_WARNING

        warnings.append(SHADOW_CATCHER_WARNING)
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


def view_layer_aovs(view_layer, world, warnings: list[str]) -> list[tuple[str, str]]:
    """The view layer's shader AOVs (View Layer Properties > Shader AOV) as core.scene.Scene.shader_aovs: (name,
    "COLOR" | "VALUE") in their order, the invalid ones (a repeated name, or one of a built-in pass: Blender
    marks them) left out as Cycles does, with a warning; a warning too for AOV Output nodes in the world, which
    Monte does not evaluate."""
    out: list[tuple[str, str]] = []
    for aov in getattr(view_layer, "aovs", ()):
        if not getattr(aov, "is_valid", True):
            warnings.append(f"view layer {view_layer.name!r}: shader AOV {aov.name!r} is invalid (a repeated name or "
                            "the name of a built-in pass) and is not written")
            continue
        out.append((str(aov.name), "VALUE" if aov.type == "VALUE" else "COLOR"))
    tree = getattr(world, "node_tree", None) if out and world is not None else None
    if tree is not None and any(n.bl_idname == "ShaderNodeOutputAOV" for n in tree.nodes):
        warnings.append(f"world {world.name!r}: AOV Output nodes in the world are not evaluated by Monte; the "
                        "AOVs stay 0 where the camera sees the world")
    return out


def view_layer_light_groups(view_layer) -> list[str]:
    """The view layer's light groups (View Layer Properties > Light Groups) as core.scene.Scene.light_groups: their
    names in order (Blender keeps them unique). Emitters naming another group light none, as in Cycles."""
    return [str(group.name) for group in getattr(view_layer, "lightgroups", ()) if group.name]


def _asset_name(inst, obj) -> str:
    """Cryptomatte Asset's name of an object instance, as Cycles names it: the top-most parent of the object (of
    its instancer, for an instance), the object itself when it has no parent."""
    top = inst.parent if getattr(inst, "is_instance", False) and inst.parent is not None else obj
    seen = 0
    while top.parent is not None and seen < 1000:  # Blender forbids parent loops; the bound is a guard
        top, seen = top.parent, seen + 1
    return top.name


def _sample_motion(depsgraph, frame_set, shutter, prototypes, camera_object, camera, warnings):
    """Evaluate the subframes motion blur needs (none when nothing asks for steps); the camera's motion goes
    straight onto `camera`. Returns the samples (addon/export/motion.MotionSamples) or None."""
    moving = [p for p in prototypes.values() if p.local is not None and p.matrices and p.steps]
    camera_steps = object_steps(camera_object.original) if camera_object is not None else 0
    steps = max([p.steps for p in moving] + [camera_steps])
    if steps < 2:
        return None
    def read(obj):
        try:
            local = _read_geometry(obj, [])
        except (RuntimeError, ValueError):
            return None
        return None if local is None else (local.vertices, local.normals, local.triangle_count)

    keys = {key for p in moving for key in p.instance_keys}
    deforming = {p.deform_name for p in moving if p.deform_name is not None and len(p.matrices) == 1}
    samples = sample_motion(depsgraph, frame_set, shutter, keys, deforming,
                            camera_object.original.name if camera_steps else None, steps, read)
    if samples.camera is not None:
        camera.motion_matrices = take_steps(samples.camera, camera_steps)
    lenses = samples.camera_lenses
    if lenses and camera.kind == "PERSP" and (lenses[0] != camera.lens or lenses[1] != camera.lens):
        if camera.use_dof and camera.aperture_fstop > 0:
            warnings.append(f"camera {camera_object.original.name!r}: a focal length (zoom) changing during the "
                            "shutter together with depth of field is not motion-blurred; rendered with the frame's")
        else:
            camera.motion_lens = lenses
    return samples


def _attach_motion(mesh, proto: _Prototype, matrices: np.ndarray, motion, warnings: list[str]) -> None:
    """Set mesh.motion_vertices (and motion_normals) from the subframes' samples, when the mesh moves."""
    steps = proto.steps
    per_step = []
    for key, frame_matrix in zip(proto.instance_keys, matrices):
        found = motion.matrices.get(key)
        per_step.append(take_steps(found, steps) if found is not None else np.broadcast_to(frame_matrix,
                                                                                            (steps, 4, 4)))
    step_matrices = np.stack(per_step, axis=1)  # (S, K, 4, 4)
    local = proto.local
    local_steps = [local.vertices] * steps
    normal_steps = None if local.normals is None else [local.normals] * steps
    deformed = False
    if proto.deform_name is not None and proto.deform_name in motion.deformed:
        read = motion.deformed[proto.deform_name]
        read = read[::(len(read) - 1) // (steps - 1)][:steps]  # this object's steps among the common ones
        if all(r is not None and r[0].shape == local.vertices.shape and r[2] == local.triangle_count
               for r in read):
            local_steps = [r[0] for r in read]
            if normal_steps is not None:
                normal_steps = [r[1] if r[1] is not None else local.normals for r in read]
            deformed = any(not np.array_equal(v, local.vertices) for v in local_steps)
        else:
            warnings.append(f"object {proto.deform_name!r}: its mesh changes topology during the shutter; rendered "
                            "without deformation blur")
    if not deformed and np.all(step_matrices == matrices[None]):
        return  # still
    # Rotation: more baked steps, so that vertices (linear between steps) follow their arcs.
    step_matrices = densify_transforms(step_matrices)
    if len(step_matrices) != steps:
        local_steps = list(resample_steps(np.stack(local_steps), len(step_matrices)))
        if normal_steps is not None:
            normal_steps = list(resample_steps(np.stack(normal_steps), len(step_matrices)))
    mirrored = np.linalg.det(matrices[:, :3, :3]) < 0
    mesh.motion_vertices, mesh.motion_normals = placed_motion(local_steps, normal_steps, step_matrices, mirrored)


def _texspace(obj, local: LocalMesh) -> tuple[np.ndarray, np.ndarray]:
    """(location, size) of the texture space Generated coordinates map to [0, 1]^3: the mesh's own (auto: its
    bounding box), or the bounding box of the converted geometry for curves, text and metaballs."""
    data = obj.data
    if obj.type == "MESH" and data is not None and hasattr(data, "texspace_location"):
        return np.array(data.texspace_location, np.float64), np.array(data.texspace_size, np.float64)
    if local.vertices.size:
        lo, hi = local.vertices.min(axis=0).astype(np.float64), local.vertices.max(axis=0).astype(np.float64)
        return (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-30)
    return np.zeros(3), np.ones(3)


def _object_rows(matrices: np.ndarray, info: np.ndarray, texspace) -> np.ndarray:
    """The core.shading object-table rows of K instances: world -> object transform, location, colour, pass index,
    random value (Monte's hash of the instance's random id, uniform in [0, 1)), texture-space box."""
    from ...core.shading.program import (OBJECT_BOX_MIN, OBJECT_BOX_SIZE, OBJECT_COLOR, OBJECT_COLUMNS,
                                         OBJECT_INVERSE, OBJECT_LOCATION, OBJECT_PASS_INDEX, OBJECT_RANDOM)

    k = matrices.shape[0]
    rows = np.zeros((k, OBJECT_COLUMNS), np.float64)
    det = np.linalg.det(matrices)
    safe = np.where(np.abs(det)[:, None, None] > 1e-300, matrices, np.eye(4))
    inv = np.linalg.inv(safe)
    rows[:, OBJECT_INVERSE:OBJECT_INVERSE + 12] = inv[:, :3, :4].reshape(k, 12)
    rows[:, OBJECT_LOCATION:OBJECT_LOCATION + 3] = matrices[:, :3, 3]
    rows[:, OBJECT_COLOR:OBJECT_COLOR + 4] = info[:, :4]
    rows[:, OBJECT_PASS_INDEX] = info[:, 4]
    rid = info[:, 5].astype(np.int64) & 0xFFFFFFFF
    rows[:, OBJECT_RANDOM] = ((rid * 2654435761 + 0x9E3779B9) & 0xFFFFFFFF) / 2.0**32
    loc, size = texspace
    rows[:, OBJECT_BOX_MIN:OBJECT_BOX_MIN + 3] = loc - size
    rows[:, OBJECT_BOX_SIZE:OBJECT_BOX_SIZE + 3] = 2.0 * size
    return rows
