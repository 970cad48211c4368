"""The audit: never silently different from Cycles.

A small scene (a glossy-and-diffuse cube on a floor, a point light, a world, a camera) is exported once with
Blender's defaults (no warning), then with one setting that changes Cycles' image turned away from its default.
For each such setting Monte either renders it -- the exported core scene carries it, checked by a predicate on
the scene (and the cross-checks in tests/test_film_camera_cycles.py, test_depth_of_field.py and
test_addon_cycles.py compare those renders with Cycles) -- with no warning, or names it in a warning (the words
listed). A setting that changed nothing in the export and warned about nothing would be silently different.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon.export import export_scene  # noqa: E402

pytestmark = [pytest.mark.blender]


def build_scene():
    scene = bf.reset()
    s = 4.0
    bf.mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                   bf.diffuse("floor", (0.5, 0.5, 0.5)))
    v = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), (-1, -1, 2), (1, -1, 2), (1, 1, 2), (-1, 1, 2)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    bf.mesh_object("cube", v, f, bf.node_material("cube", "ShaderNodeBsdfPrincipled", Roughness=0.3))
    bf.add_light(scene, "POINT", (2, -2, 4), name="lamp", energy=500.0)
    bf.camera_object(scene, (0, -9, 4), (math.radians(70), 0, 0), lens=35.0)
    bf.set_world(scene, (0.2, 0.3, 0.4), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    scene.render.resolution_percentage = 100
    return scene


def export():
    return export_scene(bpy.context.evaluated_depsgraph_get())[0]


def obj(name):
    return bpy.data.objects[name]


def _set(owner, **values):
    for key, value in values.items():
        setattr(owner, key, value)


def _sky(scene, sky_type: str) -> None:
    """A Sky Texture of `sky_type` on the world's Background colour (skipped where this Blender has no such type:
    4.x has Nishita in place of the two scattering types)."""
    if sky_type not in {e.identifier for e in bpy.types.ShaderNodeTexSky.bl_rna.properties["sky_type"].enum_items}:
        pytest.skip(f"this Blender has no {sky_type} sky")
    tree = scene.world.node_tree
    node = tree.nodes.new("ShaderNodeTexSky")
    node.sky_type = sky_type
    tree.links.new(node.outputs["Color"], tree.nodes["Background"].inputs["Color"])


def _gradient_world(scene) -> None:
    """Texture Coordinate Generated -> Gradient Texture -> the world's Background colour (a node program)."""
    tree = scene.world.node_tree
    gradient = tree.nodes.new("ShaderNodeTexGradient")
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs["Generated"], gradient.inputs["Vector"])
    tree.links.new(gradient.outputs["Color"], tree.nodes["Background"].inputs["Color"])


def _cycles_output(material_or_world):
    tree = material_or_world.node_tree
    return tree, next(n for n in tree.nodes if n.bl_idname in ("ShaderNodeOutputMaterial", "ShaderNodeOutputWorld"))


def _volume(target):
    """A Principled Volume on the Volume socket of a material (or the world)."""
    tree, out = _cycles_output(target)
    vol = tree.nodes.new("ShaderNodeVolumePrincipled")
    tree.links.new(vol.outputs[0], out.inputs["Volume"])


def _displacement(mat):
    tree, out = _cycles_output(mat)
    disp = tree.nodes.new("ShaderNodeDisplacement")
    tree.links.new(disp.outputs[0], out.inputs["Displacement"])


def _moving_cube(scene):
    """Render > Motion Blur on, with the cube moving over the shutter (a keyframe either side of the frame)."""
    cube = obj("cube")
    for frame, x in ((0, -0.5), (2, 0.5)):
        cube.location.x = x
        cube.keyframe_insert("location", frame=frame)
    scene.frame_set(1)
    scene.render.use_motion_blur = True


def _bent_shutter_curve(scene):
    curve = scene.render.motion_blur_shutter_curve
    curve.curves[0].points[1].location = (0.5, 0.3)
    curve.update()


def _holdout_shader(mat):
    tree, out = _cycles_output(mat)
    hold = tree.nodes.new("ShaderNodeHoldout")
    tree.links.new(hold.outputs[0], out.inputs["Surface"])


def _collection_flag(flag):
    def apply(scene):
        coll = bpy.data.collections.new("set")
        scene.collection.children.link(coll)
        cube = obj("cube")
        scene.collection.objects.unlink(cube)
        coll.objects.link(cube)
        setattr(scene.view_layers[0].layer_collection.children["set"], flag, True)
    return apply


def _particle_hair(scene):
    floor = obj("floor")
    mod = floor.modifiers.new("hair", "PARTICLE_SYSTEM")
    settings = mod.particle_system.settings
    settings.type = "HAIR"
    settings.count = 10


def _light_linking(scene):
    coll = bpy.data.collections.new("lit")
    coll.objects.link(obj("cube"))
    obj("lamp").light_linking.receiver_collection = coll


def _shadow_linking(scene):
    coll = bpy.data.collections.new("blockers")
    coll.objects.link(obj("floor"))
    obj("lamp").light_linking.blocker_collection = coll


def _material_override(scene):
    scene.view_layers[0].material_override = bf.diffuse("override", (0.1, 0.8, 0.1))


def _world_override(scene):
    own = scene.world
    scene.view_layers[0].world_override = bf.set_world(scene, (0.9, 0.1, 0.1), 1.0)
    scene.world = own


def _pano(kind, **extra):
    def apply(scene):
        cam = scene.camera.data
        cam.type = "PANO"
        cam.panorama_type = kind
        _set(cam, **extra)
    return apply


def _material(scene, name="cube"):
    return bpy.data.materials[name]


def _mesh(core, name):
    return next(m for m in core.meshes if m.name == name)


def _material_of(core, name):
    mesh = _mesh(core, name)
    return core.materials[int(np.asarray(mesh.material_index).reshape(-1)[0])]


# name -> (turn the setting on, ("renders", predicate on the exported core scene) or ("warns", words)).
AUDIT = {
    # camera
    "camera lens": (lambda s: _set(s.camera.data, lens=80.0), ("renders", lambda c: c.camera.lens == 80.0)),
    "camera orthographic": (lambda s: _set(s.camera.data, type="ORTHO"),
                            ("renders", lambda c: c.camera.kind == "ORTHO")),
    "camera shift": (lambda s: _set(s.camera.data, shift_x=0.25), ("renders", lambda c: c.camera.shift_x == 0.25)),
    "camera clip start": (lambda s: _set(s.camera.data, clip_start=3.0),
                          ("renders", lambda c: c.camera.clip_start == 3.0)),
    "camera sensor fit": (lambda s: _set(s.camera.data, sensor_fit="VERTICAL"),
                          ("renders", lambda c: c.camera.sensor_fit == "VERTICAL")),
    "depth of field": (lambda s: (_set(s.camera.data.dof, use_dof=True, aperture_fstop=2.0)),
                       ("renders", lambda c: c.camera.aperture_radius() > 0)),
    "panorama equirectangular": (_pano("EQUIRECTANGULAR", latitude_min=-0.5),
                                 ("renders", lambda c: c.camera.kind == "PANO" and c.camera.latitude_min == -0.5)),
    "panorama fisheye equidistant": (_pano("FISHEYE_EQUIDISTANT"),
                                     ("renders", lambda c: c.camera.panorama_type == "FISHEYE_EQUIDISTANT")),
    "panorama fisheye equisolid": (_pano("FISHEYE_EQUISOLID", fisheye_lens=8.0),
                                   ("renders", lambda c: c.camera.fisheye_lens == 8.0)),
    "panorama mirror ball": (_pano("MIRRORBALL"), ("renders", lambda c: c.camera.panorama_type == "MIRRORBALL")),
    "panorama central cylindrical": (_pano("CENTRAL_CYLINDRICAL", central_cylindrical_radius=2.0),
                                     ("renders", lambda c: c.camera.cylinder_radius == 2.0)),
    "panorama lens polynomial": (_pano("FISHEYE_LENS_POLYNOMIAL", fisheye_polynomial_k1=-0.5),
                                 ("renders", lambda c: c.camera.fisheye_polynomial[1] == -0.5)),
    "panorama cubemap face": (_pano("EQUIANGULAR_CUBEMAP_FACE"), ("warns", ["Equiangular Cubemap Face"])),
    "panorama depth of field": (lambda s: (_pano("FISHEYE_EQUIDISTANT")(s),
                                           _set(s.camera.data.dof, use_dof=True, aperture_fstop=2.0)),
                                ("renders", lambda c: c.camera.kind == "PANO" and c.camera.aperture_radius() > 0)),
    # render and film
    "resolution percentage": (lambda s: _set(s.render, resolution_percentage=50),
                              ("renders", lambda c: c.camera.resolution == (16, 12))),
    "motion blur": (_moving_cube, ("renders", lambda c: any(m.motion_vertices is not None for m in c.meshes))),
    "rolling shutter": (lambda s: (_moving_cube(s), _set(s.cycles, rolling_shutter_type="TOP")),
                        ("renders", lambda c: c.camera.rolling_shutter is not None)),
    "shutter curve": (lambda s: (_moving_cube(s), _bent_shutter_curve(s)),
                      ("renders", lambda c: c.camera.shutter_curve is not None)),
    "pixel aspect": (lambda s: _set(s.render, pixel_aspect_x=2.0), ("warns", ["pixel aspect"])),
    "simplify texture limit": (lambda s: (_set(s.render, use_simplify=True), _set(s.cycles, texture_limit_render="256")),
                               ("warns", ["Simplify > Texture Limit 256"])),
    "simplify AO bounces": (lambda s: (_set(s.render, use_simplify=True), _set(s.cycles, ao_bounces_render=2)),
                            ("warns", ["Simplify > AO Bounces 2"])),
    "film transparent": (lambda s: _set(s.render, film_transparent=True),
                         ("renders", lambda c: c.film.transparent)),
    "film transparent glass": (lambda s: (_set(s.render, film_transparent=True),
                                          _set(s.cycles, film_transparent_glass=True,
                                               film_transparent_roughness=0.25)),
                               ("renders", lambda c: c.film.transparent_glass and c.film.transparent_roughness == 0.25)),
    # lights
    "light power": (lambda s: _set(obj("lamp").data, energy=1000.0),
                    ("renders", lambda c: np.allclose(c.lights[0].power, 1000.0))),
    "light cast shadow": (lambda s: _set(obj("lamp").data, use_shadow=False),
                          ("renders", lambda c: not c.lights[0].cast_shadow)),
    "light camera visibility": (lambda s: _set(obj("lamp"), visible_camera=True),
                                ("renders", lambda c: c.lights[0].visible_camera)),
    "light diffuse visibility": (lambda s: _set(obj("lamp"), visible_diffuse=False),
                                 ("renders", lambda c: not c.lights[0].visible_diffuse)),
    "light glossy visibility": (lambda s: _set(obj("lamp"), visible_glossy=False),
                                ("renders", lambda c: not c.lights[0].visible_glossy)),
    "light transmission visibility": (lambda s: _set(obj("lamp"), visible_transmission=False),
                                      ("renders", lambda c: not c.lights[0].visible_transmission)),
    "light volume scatter visibility": (lambda s: _set(obj("lamp"), visible_volume_scatter=False),
                                        ("warns", ["light 'lamp'", "Volume Scatter"])),
    "light linking": (_light_linking, ("renders", lambda c: c.lights[0].receiver_set == 1
                                       and _mesh(c, "cube").light_sets & 2 and not _mesh(c, "floor").light_sets & 2)),
    "shadow linking": (_shadow_linking, ("renders", lambda c: c.lights[0].blocker_set == 1
                                         and _mesh(c, "floor").shadow_sets & 2
                                         and not _mesh(c, "cube").shadow_sets & 2)),
    # objects
    "object camera visibility": (lambda s: _set(obj("cube"), visible_camera=False),
                                 ("renders", lambda c: not _mesh(c, "cube").visible_camera)),
    "object shadow visibility": (lambda s: _set(obj("cube"), visible_shadow=False),
                                 ("renders", lambda c: not _mesh(c, "cube").visible_shadow)),
    "object diffuse visibility": (lambda s: _set(obj("cube"), visible_diffuse=False),
                                  ("renders", lambda c: not _mesh(c, "cube").visible_diffuse)),
    "object glossy visibility": (lambda s: _set(obj("cube"), visible_glossy=False),
                                 ("renders", lambda c: not _mesh(c, "cube").visible_glossy)),
    "object transmission visibility": (lambda s: _set(obj("cube"), visible_transmission=False),
                                       ("renders", lambda c: not _mesh(c, "cube").visible_transmission)),
    "object volume scatter visibility": (lambda s: _set(obj("cube"), visible_volume_scatter=False),
                                         ("warns", ["Volume Scatter"])),
    "object holdout": (lambda s: _set(obj("cube"), is_holdout=True),
                       ("renders", lambda c: _material_of(c, "cube").holdout == 1.0)),
    "shadow catcher": (lambda s: _set(obj("floor"), is_shadow_catcher=True),
                       ("renders", lambda c: _mesh(c, "floor").shadow_catcher and c.has_shadow_catcher)),
    "shadow catcher pass": (lambda s: (_set(obj("floor"), is_shadow_catcher=True),
                                       _set(s.view_layers[0].cycles, use_pass_shadow_catcher=True)),
                            ("renders", lambda c: c.film.shadow_catcher_pass)),
    "collection holdout": (_collection_flag("holdout"),
                           ("renders", lambda c: _material_of(c, "cube").holdout == 1.0)),
    "collection indirect only": (_collection_flag("indirect_only"),  # Cycles: the same image as camera-hidden
                                 ("renders", lambda c: not _mesh(c, "cube").visible_camera)),
    "collection exclude": (_collection_flag("exclude"),
                           ("renders", lambda c: "cube" not in [m.name for m in c.meshes])),
    # view layer (Cycles reads these from it)
    "view layer material override": (_material_override,
                                     ("renders", lambda c: _material_of(c, "cube").name == "override"
                                      and _material_of(c, "floor").name == "override")),
    "view layer world override": (_world_override,
                                  ("renders", lambda c: np.allclose(c.world.color, (0.9, 0.1, 0.1)))),
    "view layer sky off": (lambda s: _set(s.view_layers[0], use_sky=False),
                           ("renders", lambda c: np.allclose(c.world.color, 0) and c.world.environment is None)),
    "view layer samples": (lambda s: _set(s.view_layers[0], samples=16), ("warns", ["Samples 16"])),
    "view layer surfaces off": (lambda s: _set(s.view_layers[0], use_solid=False), ("warns", ["Use Solid"])),
    "particle hair": (_particle_hair, ("warns", ["particle hair", "'floor'"])),
    # materials and world
    "holdout shader": (lambda s: _holdout_shader(_material(s)),
                       ("renders", lambda c: _material_of(c, "cube").holdout == 1.0)),
    "principled volume": (lambda s: _volume(_material(s)), ("warns", ["volumes", "Principled Volume"])),
    "displacement": (lambda s: _displacement(_material(s)), ("warns", ["displacement"])),
    "world strength": (lambda s: _set(s.world.node_tree.nodes["Background"].inputs["Strength"], default_value=3.0),
                       ("renders", lambda c: np.allclose(c.world.color, (0.6, 0.9, 1.2)))),
    "world volume": (lambda s: _volume(s.world), ("warns", ["world volumes"])),
    "world camera visibility": (lambda s: _set(s.world.cycles_visibility, camera=False),
                                ("warns", ["world", "Camera"])),
    "world gradient texture": (_gradient_world,
                               ("renders", lambda c: c.world.environment is not None
                                and c.world.environment.name == "World/program")),
    "sky texture preetham": (lambda s: _sky(s, "PREETHAM"),
                             ("renders", lambda c: c.world.environment is not None
                              and c.world.environment.pixels.shape == (512, 1024, 3))),
    "sky texture hosek-wilkie": (lambda s: _sky(s, "HOSEK_WILKIE"),
                                 ("renders", lambda c: c.world.environment is not None
                                  and c.world.environment.pixels.shape == (512, 1024, 3) and c.lights[1:] == [])),
    "sky texture single scattering": (lambda s: _sky(s, "SINGLE_SCATTERING"),
                                      ("renders", lambda c: c.world.environment is not None
                                       and [light.name for light in c.lights] == ["lamp", "World/Sky Texture sun"])),
    "sky texture multiple scattering": (lambda s: _sky(s, "MULTIPLE_SCATTERING"),
                                        ("renders", lambda c: c.world.environment is not None
                                         and c.world.environment.pixels.shape == (1024, 2048, 3)
                                         and [light.name for light in c.lights] == ["lamp",
                                                                                    "World/Sky Texture sun"])),
}


def test_the_audit_covers_enough_settings():
    assert len(AUDIT) >= 25


def test_defaults_warn_about_nothing():
    build_scene()
    assert export().warnings == []


@pytest.mark.parametrize("name", list(AUDIT))
def test_each_setting_is_rendered_or_named(name):
    scene = build_scene()
    before = export()
    turn_on, (verdict, expect) = AUDIT[name]
    turn_on(scene)
    got = export()
    if verdict == "renders":
        assert got.warnings == [], got.warnings
        assert expect(got) and not expect(before), f"{name}: the export does not carry the setting"
    else:
        assert any(all(word in w for word in expect) for w in got.warnings), got.warnings


def test_a_light_portal_is_no_light():
    """An area light marked as a portal (Cycles: no emission, unseen, unshadowing; it only guides the world's
    sampling, which changes noise) leaves the lights for the world's portals, with no warning."""
    scene = build_scene()
    bf.add_light(scene, "AREA", (0, 0, 3), name="window", energy=50.0, size=2.0)
    assert sorted(light.name for light in export().lights) == ["lamp", "window"]
    light = obj("window").data
    if hasattr(light, "is_portal"):
        light.is_portal = True
    else:
        light.cycles.is_portal = True
    got = export()
    assert got.warnings == [] and [light.name for light in got.lights] == ["lamp"]
    portal = got.world.portals
    assert portal.shape == (1, 4, 3)
    assert np.allclose(portal[0, 0], (0, 0, 3)) and np.allclose(np.abs(portal[0, 1:3]).sum(axis=0), (2, 2, 0))
    assert np.allclose(portal[0, 3], (0, 0, -1))  # the light's -Z: where it lets the world in


def test_view_layer_motion_blur_off_renders_sharp():
    """Render > Motion Blur on with a moving cube, the view layer's Motion Blur off: Cycles renders the layer
    sharp, and so does Monte (no motion exported, no warning); on, the cube carries its motion."""
    scene = build_scene()
    _moving_cube(scene)
    assert any(m.motion_vertices is not None for m in export().meshes)
    scene.view_layers[0].use_motion_blur = False
    got = export()
    assert got.warnings == [] and all(m.motion_vertices is None for m in got.meshes)
