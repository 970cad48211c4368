"""Light linking and shadow linking against real Cycles (bpy ships it), 48x48 pixels, black world.

Scenes (diffuse quads on the ground seen from above by an orthographic camera):
- receivers: three quads (left, middle, right). A square area light over the left quad lights the receiver
  collection {left: Include}; a sphere point light over the middle lights {middle: Exclude} (every object but
  the middle one); an emissive quad over the right lights {right: Include}. Each object is lit by some emitters
  only, through light sampling and BSDF hits (MIS with the class's light selection).
- visibility (32x32): diffuse, mixed and glossy quads under an area light and a sphere light, both with one
  Ray Visibility flag turned: Diffuse off, Glossy off, Camera on (the sphere light seen; `-m slow`); and a
  rough glass sheet over a floor under an area light with Transmission off.
- a light with Camera visibility off (32x32) behind a Transparent BSDF card: camera rays stay camera rays through
  the card and do not see it (control: the light seen, as Monte rendered it when such a ray was a bounce ray).
- blockers: a floor and a square hovering over it under an area light whose blocker collection holds only a
  small cube off to the side: the square casts no shadow from that light (Cycles' shadow linking); the square
  itself is lit. The same with an emissive quad in place of the area light (shadow linking of an emissive mesh).

Each is compared by its mean (within max(4 sigma, 1 %) capped at 1 %) and per-pixel z-scores (core.compare:
at most 1 % of pixels beyond 5 sigma), Cycles' per-pixel variance from 4 seeds at half Monte's samples, Monte's
from its film. Control: the same scene with its linking removed, rendered by Monte, must fail the same check
against Cycles' linked image (it differs by 17-120 %). About 35 s on 2 cores with compiled kernels cached.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import crosscheck as cc  # noqa: E402
from monte.addon.export import export_scene  # noqa: E402
from monte.core import compare as cmp  # noqa: E402

pytestmark = [pytest.mark.blender]

CYCLES_RUNS = 4
SPP, BOUNCES = 64, 3


def _quad(name, x0, x1, y0, y1, z, material, collection=None):
    return bf.mesh_object(name, [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)], [(0, 1, 2, 3)], material,
                          collection=collection)


def _linking_collection(name: str, states: dict) -> object:
    """A collection holding the objects `states` names, each with its link state (INCLUDE / EXCLUDE)."""
    coll = bpy.data.collections.new(name)
    for obj_name, state in states.items():
        coll.objects.link(bpy.data.objects[obj_name])
    for entry, obj in zip(coll.collection_objects, coll.objects):
        entry.light_linking.link_state = states[obj.name]
    return coll


def _base(size=(48, 48)):
    scene = bf.reset()
    bf.camera_object(scene, (0, 0, 6), (0, 0, 0), kind="ORTHO", ortho_scale=7.0)
    bf.set_world(scene, (0.0, 0.0, 0.0), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    return scene


def receivers_scene(linked: bool = True):
    scene = _base()
    grey = bf.diffuse("grey", (0.8, 0.8, 0.8))
    _quad("left", -3.4, -1.2, -3, 3, 0, grey)
    _quad("middle", -1.0, 1.0, -3, 3, 0, grey)
    _quad("right", 1.2, 3.4, -3, 3, 0, grey)
    area = bf.add_light(scene, "AREA", (-2.0, 0.0, 1.5), name="area", energy=60.0, size=1.0)
    point = bf.add_light(scene, "POINT", (0.0, 0.5, 1.2), name="point", energy=80.0, shadow_soft_size=0.3)
    glow = bf.node_material("glow", "ShaderNodeEmission", Strength=6.0)
    lamp = _quad("lamp", 1.8, 2.6, -0.4, 0.4, 1.0, glow)
    if linked:
        area.light_linking.receiver_collection = _linking_collection("area receivers", {"left": "INCLUDE"})
        point.light_linking.receiver_collection = _linking_collection("point receivers", {"middle": "EXCLUDE"})
        lamp.light_linking.receiver_collection = _linking_collection("lamp receivers", {"right": "INCLUDE"})
    return scene


def blockers_scene(linked: bool = True):
    scene = _base()
    _quad("floor", -3.5, 3.5, -3.5, 3.5, 0, bf.diffuse("floor", (0.8, 0.8, 0.8)))
    _quad("square", -1.0, 1.0, -1.0, 1.0, 0.8, bf.diffuse("square", (0.2, 0.5, 0.8)))
    _quad("cube", 2.4, 3.0, 2.4, 3.0, 0.4, bf.diffuse("cube", (0.8, 0.3, 0.2)))
    area = bf.add_light(scene, "AREA", (0.0, 0.0, 2.5), name="area", energy=150.0, size=1.5)
    if linked:
        area.light_linking.blocker_collection = _linking_collection("area blockers", {"cube": "INCLUDE"})
    return scene


def emissive_blockers_scene(linked: bool = True):
    """blockers_scene lit by an emissive quad (its blocker collection: the cube) instead of the area light."""
    scene = _base()
    _quad("floor", -3.5, 3.5, -3.5, 3.5, 0, bf.diffuse("floor", (0.8, 0.8, 0.8)))
    _quad("square", -1.0, 1.0, -1.0, 1.0, 0.8, bf.diffuse("square", (0.2, 0.5, 0.8)))
    _quad("cube", 2.4, 3.0, 2.4, 3.0, 0.4, bf.diffuse("cube", (0.8, 0.3, 0.2)))
    glow = bf.node_material("glow", "ShaderNodeEmission", Strength=30.0)
    lamp = _quad("lamp", -0.75, 0.75, -0.75, 0.75, 2.5, glow)
    if linked:
        lamp.light_linking.blocker_collection = _linking_collection("lamp blockers", {"cube": "INCLUDE"})
    return scene


def visibility_scene(flag: str | None):
    """Diffuse, half diffuse / half glossy (a Mix Shader) and glossy quads under a square area light and a sphere
    light, both with Ray Visibility `flag` turned (None: defaults)."""
    scene = _base(size=(32, 32))
    _quad("diffuse", -3.4, -1.2, -3, 3, 0, bf.diffuse("grey", (0.8, 0.8, 0.8)))
    mix = bf.diffuse("mix", (0.8, 0.8, 0.8))
    tree = mix.node_tree
    glossy = tree.nodes.new("ShaderNodeBsdfGlossy")
    glossy.inputs["Roughness"].default_value = 0.3
    shader = tree.nodes.new("ShaderNodeMixShader")
    out = tree.nodes["Material Output"]
    diffuse = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfDiffuse")
    tree.links.new(diffuse.outputs[0], shader.inputs[1])
    tree.links.new(glossy.outputs[0], shader.inputs[2])
    tree.links.new(shader.outputs[0], out.inputs["Surface"])
    _quad("mix", -1.0, 1.0, -3, 3, 0, mix)
    _quad("glossy", 1.2, 3.4, -3, 3, 0, bf.node_material("glossy", "ShaderNodeBsdfGlossy", Roughness=0.3))
    lights = [bf.add_light(scene, "AREA", (-0.8, -1.0, 2.0), name="area", energy=120.0, size=1.5),
              bf.add_light(scene, "POINT", (1.0, 1.2, 1.5), name="sphere", energy=80.0, shadow_soft_size=0.3)]
    if flag is not None:
        for light in lights:
            setattr(light, flag, flag == "visible_camera")  # the camera's default is off, the others' on
    return scene


def transmission_scene(flag_off: bool):
    """A rough glass sheet over half of a diffuse floor under an area light (Transmission off: no light through
    the sheet, none refracted by it in next-event estimation)."""
    scene = _base(size=(32, 32))
    _quad("floor", -3.5, 3.5, -3.5, 3.5, 0, bf.diffuse("floor", (0.8, 0.8, 0.8)))
    _quad("sheet", -3.5, 0.0, -3.5, 3.5, 0.6, bf.node_material("glass", "ShaderNodeBsdfGlass", Roughness=0.2))
    light = bf.add_light(scene, "AREA", (-0.5, 0.0, 2.0), name="area", energy=150.0, size=2.0)
    light.visible_transmission = not flag_off
    return scene


def lamp_behind_card_scene(camera_off: bool):
    """A floor lit from above by an area light, under a Transparent BSDF card over its left half, with a second
    area light between card and floor facing the camera: Camera visibility off (Blender's default), Cycles' camera
    rays keep their visibility through the card and do not see it; on (the control, which is also what Monte
    rendered when a ray past a Transparent BSDF counted as a bounce ray), it is seen through the card."""
    scene = _base(size=(32, 32))
    _quad("floor", -3.5, 3.5, -3.5, 3.5, 0, bf.diffuse("floor", (0.8, 0.8, 0.8)))
    _quad("card", -3.5, 0.0, -3.5, 3.5, 1.6,
          bf.node_material("card", "ShaderNodeBsdfTransparent", Color=(0.5, 0.6, 0.4, 1.0)))
    bf.add_light(scene, "AREA", (0.5, 0.0, 3.0), name="key", energy=150.0, size=2.0)
    face = bf.add_light(scene, "AREA", (-1.5, 0.0, 1.0), rotation=(np.pi, 0, 0), name="face", energy=40.0, size=1.0)
    face.visible_camera = not camera_off
    return scene


def monte(scene, spp: int = SPP):
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = spp, BOUNCES, 1, 2
    return cc.render_monte(scene)


def cycles(scene, tmp_path, spp: int = SPP):
    runs = []
    for seed in range(1, CYCLES_RUNS + 1):
        cc.configure_cycles(scene, spp // 2, BOUNCES, threads=2, seed=seed)
        runs.append(cc.render_cycles(scene, tmp_path)[0])
    return cmp.runs_mean_and_variance(np.stack(runs))


def comparison(mon, mon_var, cyc, cyc_var) -> cmp.Comparison:
    return cmp.compare(mon, mon_var, cyc, cyc_var, rel_cap=0.01)


def check(name: str, build, tmp_path, control=False, spp: int = SPP) -> None:
    scene = build(True)
    mon, mon_var = monte(scene, spp)
    cyc, cyc_var = cycles(scene, tmp_path, spp)
    c = comparison(mon, mon_var, cyc, cyc_var)
    # the 1 % cap must be above what the noise resolves, or the noise alone could fail the check
    assert np.all(c.resolvable <= 0.01), f"{name}: the noise resolves only {np.round(100 * c.resolvable, 2)} %"
    ok, reasons = c.verdict()
    print(f"\n{name}: Monte {np.round(c.mean_a, 4)} Cycles {np.round(c.mean_b, 4)} "
          f"rel {np.round(100 * c.relative_difference, 2)} % z {c.z_stats()}")
    assert ok, f"{name}: {reasons}"
    plain, plain_var = monte(build(control), spp)  # control: linking (the flag) ignored
    c = comparison(plain, plain_var, cyc, cyc_var)
    print(f"{name} without it (control): rel {np.round(100 * c.relative_difference, 2)} %")
    assert not c.verdict()[0], f"{name}: the unlinked scene passes the same check (a control that cannot fail)"


def test_receiver_collections_match_cycles(tmp_path):
    check("light linking", receivers_scene, tmp_path)


def test_blocker_collection_matches_cycles(tmp_path):
    check("shadow linking", blockers_scene, tmp_path)


def test_emissive_mesh_blocker_collection_matches_cycles(tmp_path):
    check("shadow linking of an emissive mesh", emissive_blockers_scene, tmp_path)


@pytest.mark.parametrize("flag", ["visible_diffuse", "visible_glossy",
                                  pytest.param("visible_camera", marks=pytest.mark.slow)])
def test_light_ray_visibility_matches_cycles(flag, tmp_path):
    # 1024 samples: the glossy quad's noise at 64 resolved only ~3.4 % of the mean, over the 1 % cap
    check(f"light {flag}", lambda on: visibility_scene(flag if on else None), tmp_path, control=False, spp=1024)


def test_collections_become_light_sets_as_blenders_manual_states():
    """Include and Exclude: included minus excluded (a child collection's state applies to all inside it), only
    excluded: everything else; emitters sharing a collection share its set; instances keep their object's
    sets; an emissive mesh's Blocker Collection gives it a blocker set of its own."""
    scene = _base()
    grey = bf.diffuse("grey", (0.8, 0.8, 0.8))
    for i, name in enumerate("abcd"):
        _quad(name, i, i + 0.5, 0, 1, 0, grey)
    child = bpy.data.collections.new("child")
    child.objects.link(bpy.data.objects["b"])
    child.objects.link(bpy.data.objects["c"])
    mixed = _linking_collection("mixed", {"a": "INCLUDE", "c": "EXCLUDE"})
    mixed.children.link(child)
    only_excluded = _linking_collection("only excluded", {"d": "EXCLUDE"})
    lights = [bf.add_light(scene, "POINT", (0, 0, 2), name=f"lamp{i}", energy=10.0) for i in range(3)]
    lights[0].light_linking.receiver_collection = mixed
    lights[1].light_linking.receiver_collection = mixed
    lights[2].light_linking.receiver_collection = only_excluded
    lights[2].light_linking.blocker_collection = mixed
    bpy.data.objects["d"].light_linking.blocker_collection = only_excluded
    core = export_scene(bpy.context.evaluated_depsgraph_get())[0]
    sets = {lt.name: (lt.receiver_set, lt.blocker_set) for lt in core.lights}
    assert sets["lamp0"] == sets["lamp1"] != sets["lamp2"] and sets["lamp0"][1] == 0 and sets["lamp2"][1] > 0
    mixed_set, excluded_set, blocker_set = sets["lamp0"][0], sets["lamp2"][0], sets["lamp2"][1]
    masks = {m.name: m for m in core.meshes}
    receives = {name: (bool(masks[name].light_sets >> mixed_set & 1), bool(masks[name].light_sets >> excluded_set & 1))
                for name in "abcd"}
    assert receives == {"a": (True, True), "b": (True, True), "c": (False, True), "d": (False, False)}
    assert [bool(masks[name].shadow_sets >> blocker_set & 1) for name in "abcd"] == [True, True, False, False]
    assert masks["d"].blocker_set > 0 and masks["d"].blocker_set != blocker_set and masks["a"].blocker_set == 0
    assert not any("Shadow Linking" in w for w in core.warnings)


def test_light_transmission_visibility_matches_cycles(tmp_path):
    check("light visible_transmission", transmission_scene, tmp_path, control=False, spp=512)  # noise: see above


def test_light_hidden_from_the_camera_stays_hidden_through_a_transparent_card(tmp_path):
    check("light camera visibility through a Transparent BSDF", lamp_behind_card_scene, tmp_path)
