"""Build a Blender scene from a core Scene, so that Cycles can render what Monte's core renders (the stress
suite's `--cycles`). The inverse of addon/export, for the parts a core Scene can hold:

- meshes: triangles with per-triangle materials; per-corner shading normals become custom split normals;
- materials: each lobe becomes its Blender node (Diffuse, Glossy (GGX, no Fresnel), Glass, Refraction BSDF),
  summed with Add Shader; emission adds an Emission node of strength 1 (core emission = Blender colour x
  strength). Lobes Blender has no node for (Schlick or dielectric Fresnel on a glossy lobe) fall back to the
  Glossy BSDF, and `unsupported` lists them;
- lights: point, spot, sun and area with their units (watts, W/m^2), colour = power / max(power);
- world: a uniform background of the core world's radiance; camera: the core camera's Blender fields.

Units and frames are Blender's (Z up, metres); the core's camera matrix is Blender's matrix_world.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

from ..core.scene import AreaLight, Lobe, PointLight, Scene, SpotLight, SunLight
from .bpy_scenes import node_tree_of


def _color_and_energy(power) -> tuple[tuple[float, float, float], float]:
    p = np.asarray(power, dtype=np.float64).reshape(-1)
    if p.size == 1:
        p = np.repeat(p, 3)
    peak = float(p.max())
    if peak <= 0:
        return (1.0, 1.0, 1.0), 0.0
    return tuple(float(v) for v in p / peak), peak


def _rotation_to(direction) -> "bpy.types.Matrix":
    """A rotation taking Blender's light axis (-Z) to `direction`."""
    from mathutils import Vector

    return Vector((0.0, 0.0, -1.0)).rotation_difference(Vector([float(v) for v in direction]).normalized()).to_matrix()


def _lobe_node(tree, lobe: Lobe, unsupported: list[str], material_name: str):
    rgba = (*[float(c) for c in lobe.color], 1.0)
    if lobe.kind == "diffuse":
        node = tree.nodes.new("ShaderNodeBsdfDiffuse")
    elif lobe.kind == "glossy":
        node = tree.nodes.new("ShaderNodeBsdfGlossy")
        node.distribution = "GGX"
        node.inputs["Roughness"].default_value = float(lobe.roughness)
        if lobe.fresnel != "none":
            unsupported.append(f"material {material_name!r}: glossy lobe with {lobe.fresnel} Fresnel rendered "
                               "without Fresnel")
    elif lobe.kind in ("glass", "refraction"):
        node = tree.nodes.new("ShaderNodeBsdfGlass" if lobe.kind == "glass" else "ShaderNodeBsdfRefraction")
        node.distribution = "GGX"
        node.inputs["Roughness"].default_value = float(lobe.roughness)
        node.inputs["IOR"].default_value = float(lobe.ior)
    else:
        raise ValueError(f"unknown lobe kind {lobe.kind!r}")
    node.inputs["Color"].default_value = rgba
    if lobe.color_texture >= 0:
        unsupported.append(f"material {material_name!r}: colour texture not converted")
    return node


def _material(core_material, unsupported: list[str]):
    mat = bpy.data.materials.new(core_material.name)
    tree = node_tree_of(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    shaders = [_lobe_node(tree, lobe, unsupported, core_material.name) for lobe in core_material.lobes]
    emission = np.asarray(core_material.emission, dtype=np.float64).reshape(-1)
    if emission.size and emission.max() > 0:
        node = tree.nodes.new("ShaderNodeEmission")
        node.inputs["Color"].default_value = (*[float(c) for c in emission], 1.0)
        node.inputs["Strength"].default_value = 1.0
        shaders.append(node)
    if not shaders:  # a material with nothing: black
        node = tree.nodes.new("ShaderNodeBsdfDiffuse")
        node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        shaders.append(node)
    socket = shaders[0].outputs[0]
    for node in shaders[1:]:
        add = tree.nodes.new("ShaderNodeAddShader")
        tree.links.new(socket, add.inputs[0])
        tree.links.new(node.outputs[0], add.inputs[1])
        socket = add.outputs[0]
    tree.links.new(socket, out.inputs["Surface"])
    return mat


def _mesh_object(core_mesh, materials: list, collection):
    tris = np.asarray(core_mesh.triangles, dtype=np.int64).reshape(-1, 3)
    verts = np.asarray(core_mesh.vertices, dtype=np.float64).reshape(-1, 3)
    mesh = bpy.data.meshes.new(core_mesh.name)
    mesh.from_pydata(verts.tolist(), [], tris.tolist())
    mat_index = np.broadcast_to(np.asarray(core_mesh.material_index, dtype=np.int64), (len(tris),))
    used = sorted(set(int(i) for i in mat_index))
    slot = {m: k for k, m in enumerate(used)}
    for m in used:
        mesh.materials.append(materials[m])
    mesh.polygons.foreach_set("material_index", [slot[int(i)] for i in mat_index])
    if core_mesh.normals is not None:
        mesh.polygons.foreach_set("use_smooth", [True] * len(tris))
        mesh.normals_split_custom_set(np.asarray(core_mesh.normals, dtype=np.float64).reshape(-1, 3).tolist())
    mesh.update()
    obj = bpy.data.objects.new(core_mesh.name, mesh)
    for kind in ("camera", "shadow", "diffuse", "glossy", "transmission"):
        setattr(obj, f"visible_{kind}", bool(getattr(core_mesh, f"visible_{kind}")))
    obj.shadow_terminator_geometry_offset = float(core_mesh.shadow_terminator_offset)
    obj.is_shadow_catcher = bool(getattr(core_mesh, "shadow_catcher", False))
    collection.objects.link(obj)
    return obj


def _light_object(light, collection):
    from mathutils import Matrix

    if isinstance(light, (PointLight, SpotLight)):
        data = bpy.data.lights.new(light.name, "SPOT" if isinstance(light, SpotLight) else "POINT")
        data.shadow_soft_size = float(light.radius)
        data.color, data.energy = _color_and_energy(light.power)
        if isinstance(light, SpotLight):
            data.spot_size = float(light.spot_size)
            data.spot_blend = float(light.spot_blend)
            rot = _rotation_to(light.direction)
        else:
            rot = Matrix.Identity(3)
        matrix = rot.to_4x4()
        matrix.translation = [float(v) for v in light.position]
    elif isinstance(light, SunLight):
        data = bpy.data.lights.new(light.name, "SUN")
        data.color, data.energy = _color_and_energy(light.strength)
        data.angle = float(light.angle)
        matrix = _rotation_to(light.direction).to_4x4()
    elif isinstance(light, AreaLight):
        data = bpy.data.lights.new(light.name, "AREA")
        data.color, data.energy = _color_and_energy(light.power)
        data.shape = light.shape
        data.size, data.size_y = float(light.size_x), float(light.size_y)
        data.spread = float(light.spread)
        matrix = Matrix([[float(v) for v in row] for row in np.asarray(light.matrix_world)])
    else:
        raise ValueError(f"unknown light {type(light).__name__}")
    obj = bpy.data.objects.new(light.name, data)
    obj.matrix_world = matrix
    obj.visible_camera = bool(light.visible_camera)
    data.use_shadow = bool(light.cast_shadow)
    collection.objects.link(obj)
    return obj


def build_bpy_scene(core_scene: Scene) -> tuple[object, list[str]]:
    """Replace Blender's data with `core_scene` (factory settings, empty); returns (bpy scene, notes on what
    could not be converted exactly)."""
    from mathutils import Matrix

    from ..addon import register

    bpy.ops.wm.read_factory_settings(use_empty=True)
    register()
    scene = bpy.context.scene
    unsupported: list[str] = []
    materials = [_material(m, unsupported) for m in core_scene.materials]
    for mesh in core_scene.meshes:
        if mesh.triangle_count:
            _mesh_object(mesh, materials, scene.collection)
    for light in core_scene.lights:
        _light_object(light, scene.collection)
    world = bpy.data.worlds.new("World")
    background = node_tree_of(world).nodes["Background"]
    background.inputs["Color"].default_value = (*[float(c) for c in core_scene.world.color], 1.0)
    background.inputs["Strength"].default_value = 1.0
    if core_scene.world.environment is not None:
        unsupported.append(f"world environment map {core_scene.world.environment.name!r} not converted (uniform "
                           "world colour instead)")
    scene.world = world
    cam = core_scene.camera
    data = bpy.data.cameras.new("Camera")
    data.type = cam.kind
    data.lens = float(cam.lens)
    data.sensor_width, data.sensor_height = float(cam.sensor_width), float(cam.sensor_height)
    data.sensor_fit = cam.sensor_fit
    data.ortho_scale = float(cam.ortho_scale)
    data.shift_x, data.shift_y = float(cam.shift_x), float(cam.shift_y)
    data.clip_start = float(max(cam.clip_start, 1e-6))
    data.clip_end = float(min(cam.clip_end, 1e30))
    dof = data.dof
    dof.use_dof = bool(cam.use_dof)
    dof.aperture_fstop, dof.focus_distance = float(cam.aperture_fstop), float(cam.focus_distance)
    dof.aperture_blades, dof.aperture_rotation = int(cam.aperture_blades), float(cam.aperture_rotation)
    dof.aperture_ratio = float(cam.aperture_ratio)
    if cam.kind == "PANO":
        data.panorama_type = cam.panorama_type
        data.fisheye_fov, data.fisheye_lens = float(cam.fisheye_fov), float(cam.fisheye_lens)
        data.latitude_min, data.latitude_max = float(cam.latitude_min), float(cam.latitude_max)
        data.longitude_min, data.longitude_max = float(cam.longitude_min), float(cam.longitude_max)
    film = core_scene.film
    scene.render.film_transparent = bool(film.transparent)
    scene.cycles.film_transparent_glass = bool(film.transparent_glass)
    scene.cycles.film_transparent_roughness = float(film.transparent_roughness)
    scene.view_layers[0].cycles.use_pass_shadow_catcher = bool(getattr(film, "shadow_catcher_pass", False))
    for mat in core_scene.materials:
        if mat.holdout > 0:
            unsupported.append(f"material {mat.name!r}: holdout weight {mat.holdout:g} not converted")
    obj = bpy.data.objects.new("Camera", data)
    obj.matrix_world = Matrix([[float(v) for v in row] for row in np.asarray(cam.matrix_world)])
    scene.collection.objects.link(obj)
    scene.camera = obj
    scene.render.resolution_x, scene.render.resolution_y = (int(v) for v in cam.resolution)
    scene.render.resolution_percentage = 100
    return scene, unsupported


def cycles_renderer(threads: int = 2):
    """A function (core Scene, RenderSettings) -> dict(mean=[R, G, B], pixel_sigma=[R, G, B], nonfinite=int,
    note=str) that renders the scene with Cycles under Monte's settings (see addon.crosscheck.configure_cycles):
    what `monte stress --cycles` hands to the stress suite. pixel_sigma: the spread of the pixel values / sqrt(n),
    which is the standard error of the mean where every pixel has the same expected value (a furnace)."""
    from ..addon.crosscheck import CYCLES_FILTERS, configure_cycles, render_cycles

    def render(core_scene: Scene, settings) -> dict:
        import tempfile
        from pathlib import Path

        scene, notes = build_bpy_scene(core_scene)
        filter_type = settings.filter_type
        if filter_type not in CYCLES_FILTERS:
            notes.append(f"Cycles has no {filter_type} filter: Blackman-Harris")
            filter_type = "blackman-harris"
        configure_cycles(scene, spp=max(int(settings.spp), 1), max_bounces=int(settings.max_bounces),
                         threads=threads or int(settings.threads), seed=int(settings.seed) + 1,
                         filter_type=filter_type, filter_width=float(settings.filter_width))
        with tempfile.TemporaryDirectory() as tmp:
            rgb, _ = render_cycles(scene, Path(tmp))
        rgb = np.asarray(rgb, dtype=np.float64)[..., :3]
        finite = np.isfinite(rgb)
        mean = [float(rgb[..., c][finite[..., c]].mean()) if finite[..., c].any() else float("nan")
                for c in range(3)]
        pixel_sigma = [float(rgb[..., c][finite[..., c]].std(ddof=1) / np.sqrt(finite[..., c].sum()))
                       if finite[..., c].sum() > 1 else float("nan") for c in range(3)]
        return {"mean": mean, "pixel_sigma": pixel_sigma, "nonfinite": int((~finite).any(axis=-1).sum()),
                "note": "; ".join(notes)}

    return render
