"""Helpers for the add-on tests (tests/test_addon_*.py): scene builders in bpy and EXR reading.

Not a test module. Import it with `from blender_fixtures import ...` after putting this folder on sys.path
(pytest runs with --import-mode=importlib, so tests do that explicitly). bpy is imported once per process;
`reset()` returns Blender to an empty factory scene with Monte registered.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent


def bpy_module():
    import bpy

    from monte.addon import register

    register()
    return bpy


# The scene-building helpers the benchmark scenes use too (one implementation, in the add-on).
from monte.lab.bpy_scenes import (  # noqa: E402
    camera_object,
    diffuse,
    icosphere_object,
    mesh_object,
    node_tree_of,
    node_material,
    reset,
    set_world,
)


# --------------------------------------------------------------------------------------------- scenes
def cornell_box(resolution=(256, 256)):
    """The seed's Cornell box in bpy (built by monte.lab.bpy_scenes.cornell_box, which the benchmark uses too):
    the same triangles as core.builtin_scenes.cornell_box (quads split along 0-2), materials and camera."""
    bpy_module()
    from monte.lab import bpy_scenes

    return bpy_scenes.cornell_box(resolution)


def plane_under_world(albedo: float = 0.5, world: float = 1.0, resolution=(16, 16), height: float = 1.0):
    """A large diffuse plane at z = 0 under a uniform world, seen from straight above (radiance albedo x world)."""
    scene = reset()
    s = 1000.0
    mesh_object("plane", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                diffuse("plane", (albedo,) * 3))
    camera_object(scene, (0, 0, height), (0, 0, 0), lens=50.0)
    set_world(scene, (world, world, world), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    m = scene.monte
    m.samples, m.seed, m.threads, m.filter_type, m.filter_width = 16, 1, 2, "box", 1.0
    return scene


# --------------------------------------------------------------------------------------------- images
def read_exr_layers(path) -> dict[str, np.ndarray]:
    """Every channel of every part of an EXR (Blender's multilayer files are multi-part), name -> (H, W)."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {name: np.asarray(ch.pixels, dtype=np.float32) for part in f.parts
                for name, ch in part.channels.items()}


def use_float_exr(scene, multilayer: bool = True) -> None:
    """Set the scene's output to a 32-bit EXR, multilayer (every pass) or single-layer (Blender 5.x names the
    multilayer choice by media type too)."""
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "MULTI_LAYER_IMAGE" if multilayer else "IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER" if multilayer else "OPEN_EXR"
    settings.color_depth = "32"


def render_still_exr(scene, path) -> None:
    """F12 with the scene's engine, written (write_still) as a 32-bit multilayer EXR at `path` (a still's name
    gets no frame number; give it the .exr extension)."""
    bpy = bpy_module()
    use_float_exr(scene)
    scene.render.filepath = str(path)
    scene.render.use_file_extension = False
    assert bpy.ops.render.render(write_still=True, scene=scene.name) == {"FINISHED"}


def composite_to_exr(scene, node_type: str, output: str, name: str = "test comp"):
    """Composite a node of `node_type` (its `output` socket) as the scene's image, written as a single-layer
    32-bit EXR on F12 (compositing switched on: the caller switches it off after rendering). Returns the node
    for the caller to set up (its scene, layer, matte)."""
    bpy = bpy_module()
    tree = bpy.data.node_groups.new(name, "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    node = tree.nodes.new(node_type)
    node.scene = scene
    out = tree.nodes.new("NodeGroupOutput")
    tree.links.new(node.outputs[output], out.inputs[0])
    scene.compositing_node_group = tree
    use_float_exr(scene, multilayer=False)
    scene.render.use_compositing = True
    return node


def cycles_and_monte_exrs(scene, folder: Path, spp: int, bounces: int) -> tuple[Path, Path]:
    """F12 with Cycles, then with Monte (the scene's engine left on Monte): the same samples and bounces, seed 1,
    2 threads, a 1.5-pixel Blackman-Harris filter, no compositing; returns the two multilayer EXRs' paths."""
    from monte.addon import crosscheck as cc

    scene.render.use_compositing = False
    cc.configure_cycles(scene, spp, bounces, threads=2, seed=1, filter_type="blackman-harris", filter_width=1.5)
    render_still_exr(scene, folder / "cycles.exr")
    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = spp, bounces, 1, 2
    m.filter_type, m.filter_width = "blackman-harris", 1.5
    render_still_exr(scene, folder / "monte.exr")
    return folder / "cycles.exr", folder / "monte.exr"


def footprint(image: np.ndarray) -> np.ndarray:
    """How much a pass changes across one pixel: per pixel (and channel, for an (H, W, C) image) the largest
    difference to a 4-neighbour; the shape of `image`."""
    pad = np.pad(image, ((1, 1), (1, 1)) + ((0, 0),) * (image.ndim - 2), mode="edge")
    h, w = image.shape[:2]
    return np.max([np.abs(pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] - image)
                   for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1))], axis=0)


def save_render_exr(scene, path, multilayer: bool = True) -> dict[str, np.ndarray]:
    """Save Blender's Render Result as a 32-bit EXR and read it back."""
    bpy = bpy_module()
    use_float_exr(scene, multilayer)
    bpy.data.images["Render Result"].save_render(str(path), scene=scene)
    return read_exr_layers(path)


# --------------------------------------------------------------------------------------------- cross-check scenes
# Light set-ups (add_light keyword arguments) the Cycles cross-check tests share.
LIGHTS = {
    "point": dict(kind="POINT", location=(0.5, 0, 2), energy=200.0, shadow_soft_size=0.3, color=(1.0, 0.7, 0.4)),
    "spot": dict(kind="SPOT", location=(0, 0, 3), rotation=(0.3, 0, 0), energy=500.0, spot_size=math.radians(50),
                 spot_blend=0.4, shadow_soft_size=0.1, exposure=1.0),
    "sun": dict(kind="SUN", location=(0, 0, 5), rotation=(0.5, 0.2, 0), energy=2.0, angle=math.radians(10)),
    "area-square": dict(kind="AREA", location=(0, 0, 1.5), energy=100.0, shape="SQUARE", size=1.0),
    "area-rectangle": dict(kind="AREA", location=(0, 0, 1.5), rotation=(0.3, 0, 0), energy=80.0,
                           shape="RECTANGLE", size=1.5, size_y=0.5),
    "area-disk": dict(kind="AREA", location=(0.3, 0, 1.2), energy=60.0, shape="DISK", size=1.2),
    "area-ellipse": dict(kind="AREA", location=(0, 0, 1.5), rotation=(0.4, 0, 0), energy=100.0, shape="ELLIPSE",
                         size=2.0, size_y=0.5),
    "area-unnormalized": dict(kind="AREA", location=(0, 0, 1.5), energy=40.0, shape="RECTANGLE", size=1.5,
                              size_y=0.5, normalize=False),
    "temperature": dict(kind="POINT", location=(0, 0, 2), energy=200.0, use_temperature=True, temperature=3000.0),
}


# Principled BSDF variations: name -> (node inputs, relative tolerance). Monte layers the Principled dielectric as
# Cycles 4.x/5.0 does (docs/addon.md). Sphere under a white sky, 48x48, 128 spp, interior pixels
# (tests/test_addon_cycles.py): every gap <= 0.1 % (before the layering: rough -4.2 %, smooth -3.6 %, alpha
# 0.5 -3.4 %). One render's mean has a relative spread up to 0.15 % between seeds, so a Monte - Cycles difference
# has sigma <= 0.15 %: 0.6 % is 4 sigma; metal keeps a real ~-0.15 % (Schlick in place of Cycles' F82) inside its
# 0.5 %; white glass under a white sky is 1 in both. Coloured glass (Cycles' glass closure: transmission tinted
# sqrt(base), reflection by Specular Tint only; Specular IOR Level does not touch it): over 12 seeds smooth
# -0.03/-0.02/-0.01 % (sigma 0.02-0.03 %; one render's spread <= 0.08 %, so 0.5 % is > 4 sigma); rough 0.3 with
# a coloured Specular Tint over 4 seeds +0.12/+0.05/+0.03 % (sigma 0.09 %), one render's spread up to 0.16 % in
# Cycles and 0.11 % in Monte: a single-seed gap has sigma <= 0.2 %, 0.8 % is 4 sigma. Transmission 0.5 (glass
# beside the layered dielectric) over 16 seeds -0.11/-0.04/-0.02 % (sigma 0.05-0.06 %), one render's spread up to
# 0.21 % (Cycles) and 0.15 % (Monte): 1 % is 4 sigma of a single-seed gap. Before (base colour on reflection and
# on each transmission) -21/-71/-81 %, -24/-71/-79 % and -11/-27/-31 %. The cross-check
# (tests/test_crosscheck.py) uses these as floors under its own 4 sigma.
PRINCIPLED = {
    "dielectric-rough": ({"Base Color": (0.8, 0.3, 0.2, 1), "Roughness": 0.5}, 0.006),
    "dielectric-smooth": ({"Base Color": (0.2, 0.5, 0.8, 1), "Roughness": 0.05}, 0.006),
    "metal": ({"Base Color": (0.9, 0.6, 0.3, 1), "Metallic": 1.0, "Roughness": 0.3}, 0.005),
    "glass": ({"Base Color": (1, 1, 1, 1), "Transmission Weight": 1.0, "Roughness": 0.0}, 0.005),
    "glass-coloured": ({"Base Color": (0.8, 0.3, 0.2, 1), "Transmission Weight": 1.0, "Roughness": 0.0}, 0.005),
    "glass-coloured-tinted": ({"Base Color": (0.8, 0.3, 0.2, 1), "Transmission Weight": 1.0, "Roughness": 0.3,
                               "Specular Tint": (1.0, 0.5, 0.2, 1), "Specular IOR Level": 1.0}, 0.008),
    "transmission-half": ({"Base Color": (0.8, 0.3, 0.2, 1), "Transmission Weight": 0.5, "Roughness": 0.2}, 0.01),
    "half-alpha": ({"Base Color": (0.8, 0.8, 0.8, 1), "Alpha": 0.5, "Roughness": 0.5}, 0.006),
}


def set_light_props(data, props: dict) -> None:
    """Set light-data properties, on every Blender of the support table: Blender 4.2 lights have no Exposure
    (it multiplies the power by 2^exposure, so the energy carries it there) and no Temperature (a test of it
    is skipped there, saying so)."""
    import pytest

    import bpy

    props = dict(props)
    if "exposure" in props and "exposure" not in data.bl_rna.properties:
        props["energy"] = props.get("energy", data.energy) * 2.0 ** props.pop("exposure")
    for key, value in props.items():
        if key not in data.bl_rna.properties:
            pytest.skip(f"Blender {bpy.app.version_string} lights have no {key!r} setting")
        setattr(data, key, value)


def add_light(scene, kind: str, location, rotation=(0, 0, 0), name: str | None = None, **props):
    """A light object of Blender type `kind` (POINT, SPOT, SUN, AREA) with light-data properties `props`."""
    bpy = bpy_module()
    data = bpy.data.lights.new(name or kind.lower(), kind)
    set_light_props(data, props)
    ob = bpy.data.objects.new(name or kind.lower(), data)
    ob.location = location
    ob.rotation_euler = rotation
    scene.collection.objects.link(ob)
    return ob


def floor_scene(size=(48, 48), world: float = 0.0):
    """A 10 x 10 diffuse floor (albedo 0.8) at z = 0 seen by an orthographic camera from above; world
    radiance `world` (0 = black). For direct-light checks of each light kind."""
    scene = reset()
    s = 5.0
    mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                diffuse("floor", (0.8, 0.8, 0.8)))
    camera_object(scene, (0, 0, 6), (0, 0, 0), kind="ORTHO", ortho_scale=10.0)
    set_world(scene, (world, world, world), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    return scene


def sphere_scene(make_material, size=(48, 48), world: float = 1.0):
    """A unit icosphere with the material make_material() returns (made after the reset) at the origin under
    a uniform white world, seen from -y."""
    scene = reset()
    icosphere_object("ball", (0, 0, 0), 1.0, make_material(), subdivisions=5)
    camera_object(scene, (0, -5, 0), (math.pi / 2, 0, 0), lens=50.0)
    set_world(scene, (world, world, world), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    return scene


def stage_scene(make_material, size=(32, 32), world: float = 0.1):
    """A sphere with the material make_material() returns (made after the reset) on a two-coloured floor (red and green halves) in front of a white wall, lit
    by a tilted square area light and a dim world: reflections and refractions have something to show."""
    scene = reset()
    s = 3.0
    mesh_object("floor_red", [(-s, -s, 0), (0, -s, 0), (0, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                diffuse("red", (0.7, 0.15, 0.1)))
    mesh_object("floor_green", [(0, -s, 0), (s, -s, 0), (s, s, 0), (0, s, 0)], [(0, 1, 2, 3)],
                diffuse("green", (0.15, 0.6, 0.2)))
    mesh_object("wall", [(-s, 1.5, 0), (s, 1.5, 0), (s, 1.5, 3), (-s, 1.5, 3)], [(0, 1, 2, 3)],
                diffuse("wall", (0.8, 0.8, 0.8)))
    icosphere_object("ball", (0, 0, 0.8), 0.8, make_material(), subdivisions=4)
    # A large light: caustics through the sphere (found only by BSDF sampling) stay moderately noisy.
    add_light(scene, "AREA", (1.5, -1.5, 3.0), (0.6, 0.0, 0.8), energy=600.0, shape="SQUARE", size=2.5)
    camera_object(scene, (0, -4.5, 1.6), (math.radians(80), 0, 0), lens=35.0)
    set_world(scene, (world, world, world), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    return scene
