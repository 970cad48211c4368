"""Benchmark scenes built in bpy, so that Monte (through the add-on's export) and Cycles render the same data.

Each builder resets Blender to an empty factory scene with Monte registered, builds the scene and returns it.
All render at 256x256 by default with Blackman-Harris 1.5 px, the default of both Monte and Cycles.

- `cornell_box`: the seed's Cornell box (the same triangles as core.builtin_scenes.cornell_box).
- `interior`: a diffuse-only room with furniture-like boxes, lit by one ceiling area light and a small lamp.
- `glass`: glass and rough-glass objects on a floor under a tilted area light (caustics on the floor).
- `instances`: 4096 small spheres scattered by geometry nodes (Instance on Points) on a ground plane.
- `hdri`: gold Suzanne, a rough glossy and a diffuse sphere on a diffuse floor lit only by Blender's bundled
  `sunrise.exr` studio HDRI (a small sun holding half of the map's light), rotated through a Mapping node.
- `textured`: shading-node programs: a UV-mapped crate with image textures on base colour, roughness and a
  tangent-space normal map, a bump-mapped sphere (Noise heights), on a procedural floor (Noise -> Color Ramp).

`SCENES` maps the names `monte bench --scene` accepts to the builders. `scene_version(name)` is part of the
reference cache key: bump the scene's entry in `SCENE_VERSIONS` (or `SCENES_VERSION` for all of them) whenever
a builder changes what it renders, so that only that scene's cached Cycles reference is re-rendered.
"""

from __future__ import annotations

import math
from typing import Callable

import bpy
import numpy as np

SCENES_VERSION = 1
# glass 2: the cube and the slab lifted 1 mm off the floor (coplanar faces made the image depend on how each
# renderer breaks ties between coincident surfaces: Monte 0.22, Cycles 0.06 in red under the cube's top face).
SCENE_VERSIONS = {"glass": 2, "textured": 2}  # textured 2: the crate colour 8-bit sRGB (a float sRGB image changed on reload)


def scene_version(name: str) -> int:
    """The version of one bench scene's builder (part of its reference cache key)."""
    return SCENE_VERSIONS.get(name, SCENES_VERSION)


def reset():
    """Empty factory scene, Monte registered and selected; returns the scene."""
    from ..addon import register

    register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "MONTE"
    return scene


# --------------------------------------------------------------------------------------------- materials
def node_tree_of(idblock):
    """The node tree of a material or world, created first where Blender has none: before 5.0 a new material
    or world has use_nodes False and node_tree None (5.x gives every new one a tree)."""
    if idblock.node_tree is None:
        idblock.use_nodes = True
    return idblock.node_tree


def node_material(name: str, shader: str, **inputs):
    """A material whose Material Output is fed by one shader node with the given input values
    (keyword names with '_' for spaces: Base_Color -> 'Base Color')."""
    mat = bpy.data.materials.new(name)
    tree = node_tree_of(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    node = tree.nodes.new(shader)
    for key, value in inputs.items():
        sock = node.inputs[key.replace("_", " ")]
        if sock.type == "RGBA" and len(value) == 3:
            value = (*value, 1.0)
        sock.default_value = value
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    return mat


def diffuse(name: str, rgb) -> object:
    return node_material(name, "ShaderNodeBsdfDiffuse", Color=tuple(rgb))


def set_world(scene, rgb, strength: float = 1.0):
    world = bpy.data.worlds.new("World")
    scene.world = world
    tree = node_tree_of(world)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputWorld")
    bg = tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = (*rgb, 1.0)
    bg.inputs["Strength"].default_value = strength
    tree.links.new(bg.outputs[0], out.inputs["Surface"])
    return world


def studio_hdri(name: str) -> str:
    """Path of one of the studio HDRIs shipped with Blender (`datafiles/studiolights/world/`: forest, city,
    courtyard, interior, night, studio, sunrise, sunset, each 1024 x 512); FileNotFoundError if absent."""
    import os

    folder = bpy.utils.system_resource("DATAFILES", path="studiolights/world")
    path = os.path.join(folder, f"{name}.exr") if folder else ""
    if not path or not os.path.isfile(path):
        raise FileNotFoundError(f"studio HDRI {name!r} not found in Blender's datafiles ({folder!r})")
    return path


def set_environment_world(scene, path: str, strength: float = 1.0, rotation=None, scale=None,
                          projection: str = "EQUIRECTANGULAR", interpolation: str = "Linear"):
    """A world whose Background colour is an Environment Texture of the image at path; with rotation (Euler
    XYZ, radians) or scale, through Texture Coordinate Generated -> Mapping (Point)."""
    world = bpy.data.worlds.new("World")
    scene.world = world
    tree = node_tree_of(world)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputWorld")
    bg = tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = strength
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(path, check_existing=True)
    env.projection = projection
    env.interpolation = interpolation
    tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    tree.links.new(bg.outputs[0], out.inputs["Surface"])
    if rotation is not None or scale is not None:
        coord = tree.nodes.new("ShaderNodeTexCoord")
        mapping = tree.nodes.new("ShaderNodeMapping")
        if rotation is not None:
            mapping.inputs["Rotation"].default_value = rotation
        if scale is not None:
            mapping.inputs["Scale"].default_value = scale
        tree.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
        tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    return world


# --------------------------------------------------------------------------------------------- objects
def mesh_object(name: str, vertices, faces, material=None, collection=None, smooth=False):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in vertices], [], [tuple(f) for f in faces])
    if material is not None:
        me.materials.append(material)
    if smooth:
        me.shade_smooth()
    ob = bpy.data.objects.new(name, me)
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def grid_object(name: str, corner0, corner1, quads_per_side: int, material=None):
    """A flat grid of quads_per_side^2 quads (twice as many triangles) at height corner0[2], spanning corner0 to
    corner1 in x and y; built with foreach_set, so a million triangles take a fraction of a second."""
    n = int(quads_per_side)
    xs = np.linspace(corner0[0], corner1[0], n + 1)
    ys = np.linspace(corner0[1], corner1[1], n + 1)
    gx, gy = np.meshgrid(xs, ys)
    vertices = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, float(corner0[2]))], 1)
    index = np.arange((n + 1) * (n + 1)).reshape(n + 1, n + 1)
    quads = np.stack([index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]], -1).reshape(-1, 4)
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(vertices))
    me.vertices.foreach_set("co", vertices.astype(np.float32).ravel())
    me.loops.add(quads.size)
    me.loops.foreach_set("vertex_index", quads.astype(np.int32).ravel())
    me.polygons.add(len(quads))
    me.polygons.foreach_set("loop_start", np.arange(0, quads.size, 4, dtype=np.int32))
    me.update()
    if material is not None:
        me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def icosphere_object(name: str, center, radius: float, material=None, subdivisions: int = 5):
    import bmesh

    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=subdivisions, radius=radius)
    bm.to_mesh(me)
    bm.free()
    if material is not None:
        me.materials.append(material)
    me.shade_smooth()
    ob = bpy.data.objects.new(name, me)
    ob.location = center
    bpy.context.scene.collection.objects.link(ob)
    return ob


def box_object(name: str, lo, hi, material=None, inward: bool = False):
    """An axis-aligned box from corner lo to corner hi (6 quads, outward normals; inward=True for a room)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
         (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    if inward:
        faces = [tuple(reversed(f)) for f in faces]
    return mesh_object(name, v, faces, material)


def camera_object(scene, location, rotation_euler, lens=50.0, sensor_fit="AUTO", kind="PERSP", **data):
    cam = bpy.data.cameras.new("Camera")
    cam.type = kind
    cam.lens = lens
    cam.sensor_fit = sensor_fit
    for key, value in data.items():
        setattr(cam, key, value)
    ob = bpy.data.objects.new("Camera", cam)
    ob.location = location
    ob.rotation_euler = rotation_euler
    scene.collection.objects.link(ob)
    scene.camera = ob
    return ob


def light_object(scene, kind: str, location, rotation=(0.0, 0.0, 0.0), **props):
    data = bpy.data.lights.new(kind.lower(), kind)
    for key, value in props.items():
        setattr(data, key, value)
    ob = bpy.data.objects.new(kind.lower(), data)
    ob.location = location
    ob.rotation_euler = rotation
    scene.collection.objects.link(ob)
    return ob


def _finish(scene, resolution) -> None:
    scene.render.resolution_x, scene.render.resolution_y = (int(v) for v in resolution)
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    # Blackman-Harris 1.5 px: Monte's and Cycles' default, set explicitly so a changed default shows.
    scene.monte.filter_type, scene.monte.filter_width = "blackman-harris", 1.5
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = "BLACKMAN_HARRIS", 1.5


# --------------------------------------------------------------------------------------------- scenes
def cornell_box(resolution=(256, 256)):
    """The seed's Cornell box as core.builtin_scenes.cornell_box builds it, in bpy:
    the same triangles (quads split along 0-2), materials and camera."""
    scene = reset()
    white = diffuse("white", (0.75, 0.75, 0.75))
    red = diffuse("red", (0.75, 0.25, 0.25))
    blue = diffuse("blue", (0.25, 0.25, 0.75))
    lamp = node_material("lamp", "ShaderNodeEmission", Color=(1.0, 1.0, 1.0), Strength=12.0)
    mirror = node_material("mirror", "ShaderNodeBsdfGlossy", Color=(0.999, 0.999, 0.999), Roughness=0.0)
    glass = node_material("glass", "ShaderNodeBsdfGlass", Color=(0.999, 0.999, 0.999), Roughness=0.0, IOR=1.5)
    quads = [
        ("floor", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], white),
        ("ceiling", [(-1, -1, 2), (-1, 1, 2), (1, 1, 2), (1, -1, 2)], white),
        ("back", [(-1, 1, 0), (1, 1, 0), (1, 1, 2), (-1, 1, 2)], white),
        ("left", [(-1, -1, 0), (-1, 1, 0), (-1, 1, 2), (-1, -1, 2)], red),
        ("right", [(1, -1, 0), (1, -1, 2), (1, 1, 2), (1, 1, 0)], blue),
        ("lamp", [(-0.3, -0.3, 1.98), (-0.3, 0.3, 1.98), (0.3, 0.3, 1.98), (0.3, -0.3, 1.98)], lamp),
    ]
    for name, verts, mat in quads:
        mesh_object(name, verts, [(0, 1, 2), (0, 2, 3)], mat)
    icosphere_object("mirror_sphere", (-0.45, 0.35, 0.35), 0.35, mirror)
    icosphere_object("glass_sphere", (0.45, -0.2, 0.35), 0.35, glass)
    lens = 36.0 / (2.0 * math.tan(math.radians(39.0) / 2.0))
    camera_object(scene, (0, -3.9, 1), (math.pi / 2, 0, 0), lens=lens, sensor_fit="HORIZONTAL", sensor_width=36.0)
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    set_world(scene, (0.0, 0.0, 0.0), 0.0)
    return scene


def interior(resolution=(256, 256)):
    """A closed diffuse room (6 x 4 x 2.8 m) with furniture-like boxes: a table, a cabinet, a sofa and a shelf.
    Lit only from inside: a 1.2 x 0.8 m ceiling area light (60 W) and a small warm point lamp (15 W) on the
    shelf; every surface Lambertian, so most light arrives after several diffuse bounces."""
    scene = reset()
    wall = diffuse("wall", (0.8, 0.78, 0.72))
    floor = diffuse("floor", (0.45, 0.3, 0.2))
    wood = diffuse("wood", (0.55, 0.35, 0.2))
    fabric = diffuse("fabric", (0.2, 0.35, 0.6))
    pale = diffuse("pale", (0.85, 0.85, 0.85))
    box_object("room", (-3, -2, 0), (3, 2, 2.8), wall, inward=True)
    mesh_object("floor", [(-3, -2, 0.001), (3, -2, 0.001), (3, 2, 0.001), (-3, 2, 0.001)], [(0, 1, 2, 3)], floor)
    box_object("table_top", (-0.9, -0.3, 0.72), (0.5, 0.5, 0.77), wood)
    for i, (x, y) in enumerate([(-0.85, -0.25), (0.45, -0.25), (-0.85, 0.45), (0.45, 0.45)]):
        box_object(f"table_leg{i}", (x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, 0.72), wood)
    box_object("cabinet", (2.2, 0.8, 0.0), (2.95, 1.95, 1.9), pale)
    box_object("sofa_seat", (-2.9, -1.2, 0.0), (-2.1, 1.0, 0.45), fabric)
    box_object("sofa_back", (-2.95, -1.2, 0.0), (-2.7, 1.0, 0.9), fabric)
    box_object("shelf", (-1.0, 1.75, 1.2), (1.0, 1.98, 1.25), wood)
    for i in range(5):
        x = -0.9 + 0.38 * i
        box_object(f"book{i}", (x, 1.8, 1.25), (x + 0.25, 1.95, 1.25 + 0.18 + 0.04 * (i % 3)),
                   (pale if i % 2 else fabric))
    light_object(scene, "AREA", (0.5, 0.0, 2.78), energy=60.0, shape="RECTANGLE", size=1.2, size_y=0.8)
    light_object(scene, "POINT", (0.8, 1.85, 1.5), energy=15.0, color=(1.0, 0.8, 0.6), shadow_soft_size=0.05)
    camera_object(scene, (2.7, -1.8, 1.5), (math.radians(82), 0, math.radians(52)), lens=18.0)
    set_world(scene, (0.0, 0.0, 0.0), 0.0)
    _finish(scene, resolution)
    return scene


def glass(resolution=(256, 256)):
    """Glass-heavy: a smooth glass sphere, a rough glass sphere (roughness 0.2), a smooth glass cube, a rough
    glass slab and a small glass sphere cluster on a white floor against a grey backdrop, under a tilted 0.5 m
    square area light (60 W) and a dim grey world: the floor shows caustics through every object."""
    scene = reset()
    floor = diffuse("floor", (0.8, 0.8, 0.8))
    backdrop = diffuse("backdrop", (0.5, 0.5, 0.55))
    clear = node_material("glass", "ShaderNodeBsdfGlass", Color=(1.0, 1.0, 1.0), Roughness=0.0, IOR=1.5)
    rough = node_material("rough_glass", "ShaderNodeBsdfGlass", Color=(0.9, 0.95, 1.0), Roughness=0.2, IOR=1.5)
    tinted = node_material("tinted_glass", "ShaderNodeBsdfGlass", Color=(1.0, 0.75, 0.5), Roughness=0.0, IOR=1.45)
    mesh_object("floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)], floor)
    mesh_object("backdrop", [(-4, 2, 0), (4, 2, 0), (4, 2, 3), (-4, 2, 3)], [(0, 1, 2, 3)], backdrop)
    icosphere_object("glass_sphere", (-0.8, 0.2, 0.45), 0.45, clear)
    icosphere_object("rough_sphere", (0.5, 0.6, 0.4), 0.4, rough)
    # 1 mm above the floor: faces coplanar with it would make the result depend on tie-breaking (see
    # SCENE_VERSIONS).
    box_object("glass_cube", (0.9, -0.6, 0.001), (1.5, 0.0, 0.601), tinted)
    box_object("rough_slab", (-0.3, -0.9, 0.001), (0.3, -0.8, 0.801), rough)
    for i in range(5):
        a = 2 * math.pi * i / 5
        icosphere_object(f"bead{i}", (-0.1 + 0.35 * math.cos(a), -0.2 + 0.35 * math.sin(a), 0.12), 0.12, clear,
                         subdivisions=3)
    light_object(scene, "AREA", (-1.5, -1.0, 3.0), (math.radians(30), math.radians(-25), 0), energy=60.0,
                 shape="SQUARE", size=0.5)
    camera_object(scene, (0.0, -4.2, 2.0), (math.radians(68), 0, 0), lens=35.0)
    set_world(scene, (0.05, 0.05, 0.06), 1.0)
    _finish(scene, resolution)
    return scene


def _scatter_node_group(count_side: int, radius: float, material):
    """Geometry nodes: a count_side^2 grid of points, each an instance of one small icosphere with a random
    scale in [0.5, 1.5] x radius (Instance on Points keeps them instances, not realized geometry)."""
    ng = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = ng.nodes, ng.links
    gin = nodes.new("NodeGroupInput")
    gout = nodes.new("NodeGroupOutput")
    grid = nodes.new("GeometryNodeMeshGrid")
    grid.inputs["Size X"].default_value = grid.inputs["Size Y"].default_value = 7.0
    grid.inputs["Vertices X"].default_value = grid.inputs["Vertices Y"].default_value = count_side
    sphere = nodes.new("GeometryNodeMeshIcoSphere")
    sphere.inputs["Radius"].default_value = radius
    sphere.inputs["Subdivisions"].default_value = 2
    set_mat = nodes.new("GeometryNodeSetMaterial")
    set_mat.inputs["Material"].default_value = material
    rand = nodes.new("FunctionNodeRandomValue")
    rand.data_type = "FLOAT"
    rand.inputs["Min"].default_value = 0.5
    rand.inputs["Max"].default_value = 1.5
    rand.inputs["Seed"].default_value = 7
    inst = nodes.new("GeometryNodeInstanceOnPoints")
    join = nodes.new("GeometryNodeJoinGeometry")
    links.new(sphere.outputs["Mesh"], set_mat.inputs["Geometry"])
    links.new(grid.outputs["Mesh"], inst.inputs["Points"])
    links.new(set_mat.outputs["Geometry"], inst.inputs["Instance"])
    links.new(rand.outputs["Value"], inst.inputs["Scale"])
    links.new(inst.outputs["Instances"], join.inputs["Geometry"])
    links.new(gin.outputs[0], join.inputs["Geometry"])
    links.new(join.outputs["Geometry"], gout.inputs[0])
    return ng


def instances(resolution=(256, 256)):
    """An instanced scene: 64 x 64 = 4096 instances of a 320-triangle icosphere (random scale) over a 7 m square,
    made by a geometry-nodes modifier on the ground plane; a sun (3 W/m^2, 3 degrees) and a blue-grey sky."""
    scene = reset()
    ground = diffuse("ground", (0.6, 0.55, 0.5))
    balls = node_material("balls", "ShaderNodeBsdfPrincipled", Base_Color=(0.7, 0.2, 0.15), Roughness=0.5)
    plane = mesh_object("ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)], ground)
    mod = plane.modifiers.new("Scatter", "NODES")
    mod.node_group = _scatter_node_group(64, 0.03, balls)
    light_object(scene, "SUN", (0, 0, 5), (math.radians(40), math.radians(20), 0), energy=3.0,
                 angle=math.radians(3.0))
    camera_object(scene, (0.0, -5.5, 3.0), (math.radians(62), 0, 0), lens=30.0)
    set_world(scene, (0.35, 0.45, 0.6), 1.0)
    _finish(scene, resolution)
    return scene


def monkey_object(name: str, location, size: float, material=None, rotation=(0.0, 0.0, 0.0)):
    """Suzanne (bmesh's monkey, subdivided once, smooth shaded)."""
    import bmesh

    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_monkey(bm)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=1, use_grid_fill=True)
    bmesh.ops.scale(bm, vec=(size, size, size), verts=bm.verts[:])
    bm.to_mesh(me)
    bm.free()
    if material is not None:
        me.materials.append(material)
    me.shade_smooth()
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    ob.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(ob)
    return ob


def hdri(resolution=(256, 256)):
    """Image-based lighting: a gold metal Suzanne (Principled, metallic 1, roughness 0.25), a rough glossy grey
    sphere and a diffuse sphere on a 10 m diffuse floor, lit only by Blender's `sunrise.exr` (a small sun low
    over the horizon, half of the map's light, casts long shadows) rotated 60 degrees about Z through a Mapping
    node."""
    scene = reset()
    floor = diffuse("floor", (0.6, 0.6, 0.6))
    gold = node_material("gold", "ShaderNodeBsdfPrincipled", Base_Color=(1.0, 0.77, 0.34), Metallic=1.0,
                         Roughness=0.25)
    glossy = node_material("glossy", "ShaderNodeBsdfGlossy", Color=(0.8, 0.8, 0.8), Roughness=0.15)
    white = diffuse("white", (0.8, 0.8, 0.8))
    mesh_object("floor", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [(0, 1, 2, 3)], floor)
    monkey_object("suzanne", (0.0, 0.0, 0.75), 0.7, gold, rotation=(math.radians(-10), 0, math.radians(15)))
    icosphere_object("glossy_sphere", (-1.3, 0.6, 0.45), 0.45, glossy)
    icosphere_object("diffuse_sphere", (1.3, 0.5, 0.4), 0.4, white)
    camera_object(scene, (0.0, -5.0, 2.2), (math.radians(72), 0, 0), lens=40.0)
    set_environment_world(scene, studio_hdri("sunrise"), 1.0, rotation=(0.0, 0.0, math.radians(60.0)))
    _finish(scene, resolution)
    return scene


def _image(name: str, pixels, colorspace: str, float_buffer: bool = True):
    """A packed image from (H, W, 4) pixels (row 0 at the bottom, as Blender stores them): float (packed as
    OpenEXR) or 8-bit (packed as PNG). Both read back from a saved .blend as they were made (what the whole-process
    bench renders), as long as a float image is Non-Color: a float sRGB image is kept linear in memory but read
    back through the sRGB transform, so a colour image is 8-bit sRGB, as users' colour textures are."""
    import numpy as np

    h, w = pixels.shape[:2]
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=float_buffer)
    img.colorspace_settings.name = colorspace
    if float_buffer:
        img.file_format = "OPEN_EXR"
    img.pixels.foreach_set(np.ascontiguousarray(pixels, np.float32).ravel())
    img.pack()
    return img


def _crate_images(size: int = 64):
    """(colour, roughness, normal map) images of a crate: planks with a darker frame."""
    import numpy as np

    u, v = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size)
    frame = (np.minimum(np.minimum(u, 1 - u), np.minimum(v, 1 - v)) < 0.1).astype(np.float32)
    plank = 0.5 + 0.5 * np.sin(2 * np.pi * 4 * v) ** 2
    colour = np.ones((size, size, 4), np.float32)
    colour[..., 0] = 0.55 * plank * (1 - 0.5 * frame) + 0.1
    colour[..., 1] = 0.35 * plank * (1 - 0.5 * frame) + 0.06
    colour[..., 2] = 0.15 * plank * (1 - 0.5 * frame) + 0.03
    rough = np.ones((size, size, 4), np.float32)
    rough[..., :3] = (0.35 + 0.4 * plank * (1 - frame) + 0.1 * frame)[..., None]
    n = np.stack([np.zeros_like(u), 0.6 * np.sin(2 * np.pi * 4 * v) * np.cos(2 * np.pi * 4 * v), np.ones_like(u)],
                 axis=-1)
    n[..., 0] += 0.4 * frame * np.sign(0.5 - u)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    nmap = np.ones((size, size, 4), np.float32)
    nmap[..., :3] = 0.5 * n + 0.5
    return (_image("crate-colour", colour, "sRGB", float_buffer=False), _image("crate-roughness", rough, "Non-Color"),
            _image("crate-normal", nmap, "Non-Color"))


def textured(resolution=(256, 256)):
    """Shading-node programs under an area light and a dim sky: a UV-mapped crate (image textures on Base Color
    and Roughness, a tangent-space normal map), a sphere bumped by a Noise Texture, a floor whose colour is a
    Noise Texture through a Color Ramp."""
    import bmesh

    scene = reset()
    floor = node_material("floor", "ShaderNodeBsdfPrincipled", Roughness=0.6)
    tree = floor.node_tree
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 3.0
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.15, 0.2, 0.12, 1.0)
    ramp.color_ramp.elements[1].color = (0.6, 0.55, 0.45, 1.0)
    tree.links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    mesh_object("floor", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [(0, 1, 2, 3)], floor)

    crate = node_material("crate", "ShaderNodeBsdfPrincipled")
    tree = crate.node_tree
    principled = tree.nodes["Principled BSDF"]
    colour_img, rough_img, normal_img = _crate_images()
    for image, socket in ((colour_img, "Base Color"), (rough_img, "Roughness")):
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
        tree.links.new(tex.outputs["Color"], principled.inputs[socket])
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = normal_img
    nmap = tree.nodes.new("ShaderNodeNormalMap")
    tree.links.new(tex.outputs["Color"], nmap.inputs["Color"])
    tree.links.new(nmap.outputs["Normal"], principled.inputs["Normal"])
    me = bpy.data.meshes.new("crate")
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")  # create_cube's calc_uvs fills an existing UV layer
    bmesh.ops.create_cube(bm, size=1.2, calc_uvs=True)
    bm.to_mesh(me)
    bm.free()
    me.materials.append(crate)
    ob = bpy.data.objects.new("crate", me)
    ob.location = (-0.9, 0.3, 0.6)
    ob.rotation_euler = (0.0, 0.0, math.radians(25))
    bpy.context.scene.collection.objects.link(ob)

    ball = node_material("ball", "ShaderNodeBsdfPrincipled", Base_Color=(0.7, 0.25, 0.2), Roughness=0.4)
    tree = ball.node_tree
    heights = tree.nodes.new("ShaderNodeTexNoise")
    heights.inputs["Scale"].default_value = 6.0
    bump = tree.nodes.new("ShaderNodeBump")
    bump.inputs["Distance"].default_value = 0.05
    tree.links.new(heights.outputs["Fac"], bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], tree.nodes["Principled BSDF"].inputs["Normal"])
    icosphere_object("ball", (1.0, 0.0, 0.7), 0.7, ball, subdivisions=4)

    light_object(scene, "AREA", (1.5, -2.0, 4.0), (math.radians(30), math.radians(15), 0), energy=500.0, size=2.0)
    camera_object(scene, (0.0, -5.5, 2.6), (math.radians(70), 0, 0), lens=35.0)
    set_world(scene, (0.08, 0.09, 0.1), 1.0)
    _finish(scene, resolution)
    return scene


SCENES: dict[str, Callable] = {
    "cornell": cornell_box,
    "interior": interior,
    "glass": glass,
    "instances": instances,
    "hdri": hdri,
    "textured": textured,
}


def build(name: str, resolution=(256, 256)):
    """Build the named benchmark scene; ValueError for an unknown name."""
    try:
        builder = SCENES[name]
    except KeyError:
        raise ValueError(f"unknown benchmark scene {name!r}; choose one of {', '.join(SCENES)}") from None
    return builder(resolution)
