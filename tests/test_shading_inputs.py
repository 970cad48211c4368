"""Attribute, Color Attribute and Light Path nodes: the opcodes at one point (analytic), the path state of each
bounce kind (Cycles' path_state_next), and per-pixel / lit cross-checks against Cycles."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from monte.core.shading import evaluator as ev
from monte.core.shading import registry as R
from monte.core.shading.program import (PATH_COLUMNS, RAY_CAMERA, RAY_DIFFUSE, RAY_GLOSSY, RAY_REFLECT,
                                        RAY_SINGULAR, RAY_TRANSMIT, RAY_TRANSPARENT, WIDTH, ShadingProgram)

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _program(opname: str, n_regs: int, **operands) -> ShadingProgram:
    spec = R.op(opname)
    inst = [-1] * WIDTH
    inst[0] = spec.code
    for name, value in operands.items():
        inst[spec.slot(name)] = value
    return ShadingProgram(np.asarray([inst], np.int32), np.zeros((n_regs, 3), np.float32), np.zeros((0, 6), np.int32))


def test_attribute_op_reads_its_columns_and_zero_without_a_table():
    prog = _program("attribute", 3, color=0, alpha=1, fac=2, layer=1, missing_alpha=1)
    extra = np.zeros(PATH_COLUMNS + 12, np.float32)
    extra[PATH_COLUMNS + 6:] = (0.25, 0.5, 0.75, 0.4, 0.5, 1.0)  # the second attribute, found
    regs = ev.run_single(prog, extra=extra)
    assert np.allclose(regs[0], (0.25, 0.5, 0.75)) and regs[1, 0] == np.float32(0.4) and regs[2, 0] == 0.5
    extra[-1] = 0.0  # the mesh lacks it: 0, alpha the node's default
    for e in (extra, ()):  # () : no attribute columns, as a mesh without the attribute
        regs = ev.run_single(prog, extra=e)
        assert not regs[[0, 2]].any() and np.all(regs[1] == 1.0)


def test_light_path_op_reads_flags_and_depths():
    names = ("is_camera", "is_shadow", "is_diffuse", "is_glossy", "is_singular", "is_reflection",
             "is_transmission", "ray_length", "ray_depth", "diffuse_depth", "glossy_depth", "transparent_depth",
             "transmission_depth")
    prog = _program("light_path", 13, **{n: i for i, n in enumerate(names)})
    extra = np.array([RAY_GLOSSY | RAY_SINGULAR | RAY_TRANSMIT, 2.5, 3, 1, 0, 4, 2], np.float32)
    regs = ev.run_single(prog, extra=extra)[:, 0]
    assert regs.tolist() == [0, 0, 0, 1, 1, 0, 1, 2.5, 3, 1, 0, 4, 2]
    regs = ev.run_single(prog)[:, 0]  # no path state: a camera ray
    assert regs.tolist() == [1] + [0] * 12


def test_path_state_follows_cycles_bounce_rules():
    """One lobe per row: diffuse reflection, rough glossy, sharp glossy, rough refraction, Transparent BSDF."""
    from monte.core.bsdf_kernels import DIFFUSE, GLOSSY, REFRACTION
    from monte.core.ray_visibility import next_path_state

    n = 5
    kind = np.array([[DIFFUSE], [GLOSSY], [GLOSSY], [REFRACTION], [REFRACTION]], np.int8)
    rough = np.array([[0.0], [0.3], [0.0], [0.2], [0.0]], np.float32)
    ior = np.array([[1.0], [1.5], [1.5], [1.5], [1.0]], np.float32)
    select = np.ones((n, 1), np.float32)
    arrays = (kind, None, rough, ior, None, select)
    state = np.zeros((n, PATH_COLUMNS), np.float32)
    state[:, 0] = RAY_CAMERA
    transmitted = np.array([False, False, False, True, True])
    next_path_state(arrays, np.full(n, 0.5, np.float32), transmitted, state)
    flags = state[:, 0].astype(int).tolist()
    assert flags == [RAY_REFLECT | RAY_DIFFUSE, RAY_REFLECT | RAY_GLOSSY, RAY_REFLECT | RAY_GLOSSY | RAY_SINGULAR,
                     RAY_TRANSMIT | RAY_GLOSSY, RAY_CAMERA | RAY_TRANSPARENT]
    # depth, diffuse, glossy, transparent, transmission
    assert state[:, 2:].tolist() == [[1, 1, 0, 0, 0], [1, 0, 1, 0, 0], [1, 0, 1, 0, 0], [1, 0, 0, 0, 1],
                                     [0, 0, 0, 1, 0]]


# ------------------------------------------------------------------------------------------- against Cycles
def _bpy():
    return pytest.importorskip("bpy")


def _cross(build, prepare, size=16, name="attr"):
    import shading_crosscheck as sc

    scene = sc.emission_plane(build, size=size, name=name)
    prepare(scene.objects["plane"].data)
    return sc.compare(scene, spp=2)


@pytest.mark.blender
def test_attribute_nodes_match_cycles_per_pixel():
    """Point float, face vector, corner byte colour (with alpha) and the render colour attribute through an
    unnamed Color Attribute node, summed into one colour: each pixel as Cycles shows it."""
    _bpy()

    def build(tree, nodes):
        a_point = nodes.new("ShaderNodeAttribute")
        a_point.attribute_name = "height"
        a_face = nodes.new("ShaderNodeAttribute")
        a_face.attribute_name = "facevec"
        a_corner = nodes.new("ShaderNodeAttribute")
        a_corner.attribute_name = "paint"
        vcol = nodes.new("ShaderNodeVertexColor")  # empty name: the render colour attribute ("paint2")
        add1 = nodes.new("ShaderNodeVectorMath")
        tree.links.new(a_point.outputs["Color"], add1.inputs[0])
        tree.links.new(a_face.outputs["Vector"], add1.inputs[1])
        mul = nodes.new("ShaderNodeVectorMath")
        mul.operation = "SCALE"
        tree.links.new(a_corner.outputs["Color"], mul.inputs[0])
        tree.links.new(a_corner.outputs["Alpha"], mul.inputs["Scale"])
        add2 = nodes.new("ShaderNodeVectorMath")
        tree.links.new(add1.outputs[0], add2.inputs[0])
        tree.links.new(mul.outputs[0], add2.inputs[1])
        add3 = nodes.new("ShaderNodeVectorMath")
        add3.operation = "MULTIPLY_ADD"
        tree.links.new(add2.outputs[0], add3.inputs[0])
        add3.inputs[1].default_value = (1.0, 1.0, 1.0)
        tree.links.new(vcol.outputs["Color"], add3.inputs[2])
        fac = nodes.new("ShaderNodeMath")
        fac.operation = "MULTIPLY_ADD"
        tree.links.new(a_face.outputs["Fac"], fac.inputs[0])
        tree.links.new(vcol.outputs["Alpha"], fac.inputs[1])
        tree.links.new(a_point.outputs["Fac"], fac.inputs[2])
        nodes["Emission"].inputs["Strength"].default_value = 0.5  # outputs of slope <= 3 per metre, as the harness
        final = nodes.new("ShaderNodeVectorMath")
        final.operation = "SCALE"
        tree.links.new(add3.outputs[0], final.inputs[0])
        tree.links.new(fac.outputs[0], final.inputs["Scale"])
        return final.outputs[0]

    def prepare(mesh):
        a = mesh.attributes.new("height", "FLOAT", "POINT")
        a.data.foreach_set("value", [0.1, 0.6, 0.9, 0.3])
        f = mesh.attributes.new("facevec", "FLOAT_VECTOR", "FACE")
        f.data.foreach_set("vector", [0.2, 0.5, 0.8])
        c = mesh.color_attributes.new("paint", "BYTE_COLOR", "CORNER")
        c.data.foreach_set("color", [1.0, 0.2, 0.1, 0.5, 0.3, 0.9, 0.2, 1.0, 0.1, 0.1, 0.8, 0.25, 0.7, 0.7, 0.1, 1.0])
        c2 = mesh.color_attributes.new("paint2", "FLOAT_COLOR", "POINT")
        c2.data.foreach_set("color", [0.4, 0.1, 0.0, 0.2, 0.0, 0.3, 0.6, 0.9, 0.1, 0.1, 0.1, 0.6, 0.9, 0.5, 0.2, 0.4])
        mesh.color_attributes.render_color_index = mesh.color_attributes.find("paint2")

    monte, cycles = _cross(build, prepare)
    diff = np.abs(monte - cycles).max(axis=2)
    print(f"\nattributes: max |Monte - Cycles| {diff.max():.2e}, Cycles range {cycles.min():.3f}..{cycles.max():.3f}")
    assert cycles.std() > 0.05
    assert np.mean(diff > 2e-3) < 0.02 and diff.max() < 2e-2


@pytest.mark.blender
def test_missing_attribute_reads_zero_with_a_warning_as_cycles():
    """An Attribute and a Color Attribute node naming attributes the plane lacks: 0 everywhere but the
    Attribute node's Alpha (1), as Cycles; the export warns naming material, node, mesh and attribute."""
    _bpy()
    from monte.addon.export import export_scene
    import shading_crosscheck as sc

    def build(tree, nodes):
        attr = nodes.new("ShaderNodeAttribute")
        attr.name = "Missing"
        attr.attribute_name = "nothing_here"
        add = nodes.new("ShaderNodeVectorMath")
        tree.links.new(attr.outputs["Color"], add.inputs[0])
        tree.links.new(attr.outputs["Alpha"], add.inputs[1])
        fac = nodes.new("ShaderNodeVectorMath")
        tree.links.new(add.outputs[0], fac.inputs[0])
        tree.links.new(attr.outputs["Fac"], fac.inputs[1])
        fac.inputs[1].default_value = (0.0, 0.0, 0.0)
        vcol = nodes.new("ShaderNodeVertexColor")  # a missing colour attribute: colour and alpha 0
        vcol.layer_name = "no_colours"
        both = nodes.new("ShaderNodeVectorMath")
        tree.links.new(vcol.outputs["Color"], both.inputs[0])
        tree.links.new(vcol.outputs["Alpha"], both.inputs[1])
        sum_ = nodes.new("ShaderNodeVectorMath")
        tree.links.new(fac.outputs[0], sum_.inputs[0])
        tree.links.new(both.outputs[0], sum_.inputs[1])
        shift = nodes.new("ShaderNodeVectorMath")
        tree.links.new(sum_.outputs[0], shift.inputs[0])
        shift.inputs[1].default_value = (0.2, 0.3, 0.4)
        return shift.outputs[0]

    scene = sc.emission_plane(build, size=8, name="missing")
    core, _ = export_scene(_bpy().context.evaluated_depsgraph_get())
    assert ("material 'missing': node 'Missing' (Attribute): mesh 'plane' has no attribute 'nothing_here' (or one "
            "of a type or domain Monte cannot read); it reads 0") in core.warnings
    monte, cycles = sc.compare(scene, spp=2)
    assert np.abs(monte - cycles).max() < 1e-4
    assert np.allclose(monte, (1.2, 1.3, 1.4), atol=1e-5)  # the Attribute node's alpha reads 1, as Cycles


@pytest.mark.blender
def test_light_path_on_camera_rays_matches_cycles_per_pixel():
    """Ray Length of a camera ray (2 m to the plane, orthographic), Is Camera Ray, Ray Depth, as Cycles."""
    _bpy()

    def build(tree, nodes):
        lp = nodes.new("ShaderNodeLightPath")
        comb = nodes.new("ShaderNodeCombineXYZ")
        scale = nodes.new("ShaderNodeMath")
        scale.operation = "MULTIPLY"
        scale.inputs[1].default_value = 0.25
        tree.links.new(lp.outputs["Ray Length"], scale.inputs[0])
        tree.links.new(scale.outputs[0], comb.inputs[0])
        tree.links.new(lp.outputs["Is Camera Ray"], comb.inputs[1])
        add = nodes.new("ShaderNodeMath")
        tree.links.new(lp.outputs["Ray Depth"], add.inputs[0])
        tree.links.new(lp.outputs["Is Diffuse Ray"], add.inputs[1])
        tree.links.new(add.outputs[0], comb.inputs[2])
        return comb.outputs[0]

    monte, cycles = _cross(build, lambda mesh: None, size=8, name="lightpath")
    print(f"\nlight path camera: Monte {monte.mean(axis=(0, 1))} Cycles {cycles.mean(axis=(0, 1))}")
    assert np.abs(monte - cycles).max() < 1e-3
    assert np.allclose(cycles[..., 1], 1.0) and cycles[..., 0].mean() > 0.1


def _textured_emitter_scene():
    """floor_scene's diffuse floor lit by a 3 x 3 m plane 1.5 m above it (hidden from the camera) whose Emission
    colour is a Checker Texture of a warm and a cool colour: the only light."""
    import blender_fixtures as bf

    b = _bpy()
    scene = bf.floor_scene(size=(32, 32))
    mat = b.data.materials.new("checker-light")
    tree = bf.node_tree_of(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 2.0
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = 3.0
    checker.inputs["Color1"].default_value = (4.0, 1.5, 0.3, 1.0)
    checker.inputs["Color2"].default_value = (0.1, 0.4, 1.2, 1.0)
    tree.links.new(checker.outputs["Color"], emission.inputs["Color"])
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    s = 1.5
    light = bf.mesh_object("emitter", [(-s, -s, 1.5), (s, -s, 1.5), (s, s, 1.5), (-s, s, 1.5)], [(0, 1, 2, 3)], mat)
    light.visible_camera = False
    return scene


@pytest.mark.blender
def test_textured_emitter_is_light_sampled_unbiased_and_less_noisy(tmp_path):
    """The floor under a checker-textured emitter: Monte with light sampling + MIS agrees with Cycles' mean within
    1 % (Cycles at 256 spp as the reference, Monte at 64), and its per-pixel error against that reference is
    well below BSDF sampling's at the same sample count."""
    from monte.addon import crosscheck as cc

    scene = _textured_emitter_scene()
    cc.configure_cycles(scene, 256, 2, threads=2, seed=1)
    cyc = cc.render_cycles(scene, tmp_path)[0]
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = 64, 2, 1, 2
    errors, means = {}, {}
    for mode in ("mis", "bsdf"):
        m.light_sampling = mode
        mon = cc.render_monte(scene)[0]
        means[mode] = mon.mean(axis=(0, 1))
        errors[mode] = float(np.sqrt(np.mean((mon - cyc) ** 2)))
    ref = cyc.mean(axis=(0, 1))
    print(f"\ntextured emitter: Cycles {np.round(ref, 4)} Monte MIS {np.round(means['mis'], 4)} "
          f"(rel {np.round(means['mis'] / ref - 1, 4)}), BSDF only {np.round(means['bsdf'], 4)}; RMS error vs "
          f"Cycles: MIS {errors['mis']:.4f}, BSDF only {errors['bsdf']:.4f}")
    assert ref.min() > 0.05
    assert np.allclose(means["mis"], ref, rtol=0.01)
    assert errors["mis"] < 0.5 * errors["bsdf"]


@pytest.mark.blender
def test_light_path_camera_trick_lights_a_floor_as_in_cycles(tmp_path):
    """The common trick: an emitter the camera sees in one colour (Is Camera Ray) that lights the scene in
    another, plus Ray Depth in blue. The emitter, seen from above, hides the floor's middle; the floor mixes a
    Diffuse and a rough Glossy BSDF. The emitter's pixels are exactly the camera colour; the floor's mean within
    2 % of Cycles per channel (128 spp leave ~0.5 % noise in the mean)."""
    import blender_fixtures as bf
    from monte.addon import crosscheck as cc

    b = _bpy()
    scene = _textured_emitter_scene()
    b.data.objects["emitter"].visible_camera = True
    tree = b.data.materials["checker-light"].node_tree
    nodes = tree.nodes
    lp = nodes.new("ShaderNodeLightPath")
    lighting = nodes.new("ShaderNodeCombineXYZ")  # (2, 1, Ray Depth) for the rays that light the floor
    lighting.inputs[0].default_value, lighting.inputs[1].default_value = 2.0, 1.0
    tree.links.new(lp.outputs["Ray Depth"], lighting.inputs[2])
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    tree.links.new(lp.outputs["Is Camera Ray"], mix.inputs["Factor"])
    tree.links.new(lighting.outputs[0], mix.inputs[6])
    mix.inputs[7].default_value = (0.1, 0.2, 0.3, 1.0)  # what the camera sees
    tree.links.new(mix.outputs[2], nodes["Emission"].inputs["Color"])
    floor = b.data.objects["floor"]
    mat = bf.node_material("floor-mix", "ShaderNodeMixShader")
    mt = mat.node_tree
    diffuse = mt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    glossy = mt.nodes.new("ShaderNodeBsdfGlossy")
    glossy.inputs["Roughness"].default_value = 0.4
    mt.links.new(diffuse.outputs[0], mt.nodes["Mix Shader"].inputs[1])
    mt.links.new(glossy.outputs[0], mt.nodes["Mix Shader"].inputs[2])
    floor.data.materials.clear()
    floor.data.materials.append(mat)
    cc.configure_cycles(scene, 128, 3, threads=2, seed=1)
    cyc = cc.render_cycles(scene, tmp_path)[0]
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = 128, 3, 1, 2
    mon = cc.render_monte(scene)[0]
    seen = np.all(np.abs(cyc - (0.2, 0.4, 0.6)) < 1e-3, axis=2)  # the emitter (strength 2)
    assert 0.05 < seen.mean() < 0.15
    # inside the emitter's silhouette (its edge pixels' filter footprints reach the floor in some samples, as
    # many as each renderer's pattern puts there): exactly the camera colour
    inner = seen.copy()
    inner[1:-1, 1:-1] &= seen[:-2, 1:-1] & seen[2:, 1:-1] & seen[1:-1, :-2] & seen[1:-1, 2:]
    assert inner.mean() > 0.02
    assert np.allclose(mon[inner], (0.2, 0.4, 0.6), atol=1e-3)
    c, mm = cyc[~seen].mean(axis=0), mon[~seen].mean(axis=0)
    print(f"\nlight path floor: Cycles {np.round(c, 4)} Monte {np.round(mm, 4)} rel {np.round(mm / c - 1, 4)}")
    assert np.all(c > 0.01)
    assert np.allclose(mm, c, rtol=0.02)


def _image_on(tree, nodes, projection: str, vector_output: str, blend: float = 0.0):
    from test_shading_crosscheck import checker_image

    tex = nodes.new("ShaderNodeTexImage")
    tex.image = checker_image(f"proj-{projection.lower()}")
    tex.interpolation = "Closest"
    tex.projection = projection
    tex.projection_blend = blend
    coords = nodes.get("Texture Coordinate") or nodes.new("ShaderNodeTexCoord")
    tree.links.new(coords.outputs[vector_output], tex.inputs["Vector"])
    return tex.outputs["Color"]


@pytest.mark.blender
@pytest.mark.parametrize("projection", ["SPHERE", "TUBE"])
def test_image_sphere_and_tube_projections_match_cycles_per_pixel(projection):
    """Sphere and Tube projections of Object coordinates (through a Mapping that moves the plane off the
    projection's centre), Closest texels: each pixel's texel as in Cycles (a pixel whose centre is within the
    jitter of a texel edge may differ: at most 5 %)."""
    import shading_crosscheck as sc

    _bpy()

    def build(tree, nodes):
        mapping = nodes.new("ShaderNodeMapping")
        mapping.inputs["Location"].default_value = (0.5, 0.6, 0.3)
        mapping.inputs["Scale"].default_value = (0.4, 0.4, 0.4)
        tree.links.new(nodes["Texture Coordinate"].outputs["Object"], mapping.inputs[0])
        tex = _image_on(tree, nodes, projection, "Object")
        tree.links.new(mapping.outputs[0], tex.node.inputs["Vector"])
        return tex

    monte, cycles = sc.compare(sc.emission_plane(build, size=24, name=f"proj-{projection.lower()}"), spp=2)
    diff = np.abs(monte - cycles).max(axis=2)
    print(f"\n{projection}: pixels differing {np.mean(diff > 1e-3):.3f}")
    assert cycles.std() > 0.05
    assert np.mean(diff > 1e-3) < 0.05


@pytest.mark.blender
def test_image_box_projection_with_blend_matches_cycles_per_pixel():
    """Box projection with Blend 0.3 on a sphere (every normal direction: single faces, two- and three-way
    blends) of Generated coordinates, seen by a camera, each pixel as Cycles (Linear filtering: the blend's
    weights and the three lookups)."""
    import blender_fixtures as bf
    import shading_crosscheck as sc

    b = _bpy()

    def make():
        mat = b.data.materials.new("boxed")
        tree = bf.node_tree_of(mat)
        tree.nodes.clear()
        out = tree.nodes.new("ShaderNodeOutputMaterial")
        emission = tree.nodes.new("ShaderNodeEmission")
        tree.links.new(emission.outputs[0], out.inputs["Surface"])
        color = _image_on(tree, tree.nodes, "BOX", "Generated", blend=0.3)
        color.node.interpolation = "Linear"
        tree.links.new(color, emission.inputs["Color"])
        return mat

    scene = bf.sphere_scene(make, size=(32, 32), world=0.0)
    scene.objects["ball"].rotation_euler = (0.4, 0.3, 0.2)
    monte, cycles = sc.compare(scene, spp=2)
    diff = np.abs(monte - cycles).max(axis=2)
    print(f"\nbox: max |Monte - Cycles| {diff.max():.2e}, pixels > 2e-3: {np.mean(diff > 2e-3):.3f}")
    assert cycles.std() > 0.05
    assert np.mean(diff > 2e-3) < 0.03 and np.median(diff) < 5e-4


@pytest.mark.blender
@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_texture_coordinate_camera_and_window_match_cycles_per_pixel(kind):
    """Camera (scaled) plus Window of a tilted plane seen by a shifted, non-square camera: each pixel as Cycles."""
    import shading_crosscheck as sc

    b = _bpy()

    def build(tree, nodes):
        coords = nodes["Texture Coordinate"]
        scale = nodes.new("ShaderNodeVectorMath")
        scale.operation = "MULTIPLY_ADD"
        scale.inputs[1].default_value = (0.3, 0.3, 0.1)
        tree.links.new(coords.outputs["Camera"], scale.inputs[0])
        tree.links.new(coords.outputs["Window"], scale.inputs[2])
        return scale.outputs[0]

    scene = sc.emission_plane(build, size=16, name=f"camera-{kind.lower()}")
    scene.render.resolution_x = 20
    cam = scene.camera
    cam.location = (0.3, -0.8, 2.2)
    cam.rotation_euler = (0.35, 0.05, 0.1)
    cam.data.type = kind
    cam.data.lens = 35.0
    cam.data.ortho_scale = 2.5
    cam.data.shift_x, cam.data.shift_y = 0.05, -0.1
    b.data.objects["plane"].scale = (3.0, 3.0, 1.0)
    monte, cycles = sc.compare(scene, spp=2)
    diff = np.abs(monte - cycles).max(axis=2)
    print(f"\ncamera/window {kind}: max |Monte - Cycles| {diff.max():.2e}, Cycles {cycles.min():.3f}..{cycles.max():.3f}")
    assert cycles.std() > 0.05
    assert np.mean(diff > 2e-3) < 0.02 and diff.max() < 2e-2


@pytest.mark.blender
def test_world_backdrop_seen_only_by_the_camera_matches_cycles(tmp_path):
    """The world trick: a Mix Shader by Is Camera Ray of a blue Background (lights the scene) and an orange one
    (what the camera sees). The background pixels are the orange exactly; the diffuse sphere, lit by the blue
    world, within 1 % of Cycles per channel (64 spp: ~0.2 % noise in the mean)."""
    import blender_fixtures as bf
    from monte.addon import crosscheck as cc

    b = _bpy()
    scene = bf.sphere_scene(lambda: bf.diffuse("ball", (0.8, 0.8, 0.8)), size=(32, 32))
    tree = scene.world.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputWorld")
    light, seen = tree.nodes.new("ShaderNodeBackground"), tree.nodes.new("ShaderNodeBackground")
    light.inputs["Color"].default_value = (0.2, 0.4, 0.8, 1.0)
    seen.inputs["Color"].default_value = (1.0, 0.5, 0.2, 1.0)
    seen.inputs["Strength"].default_value = 0.5
    mix = tree.nodes.new("ShaderNodeMixShader")
    path = tree.nodes.new("ShaderNodeLightPath")
    tree.links.new(path.outputs["Is Camera Ray"], mix.inputs[0])
    tree.links.new(light.outputs[0], mix.inputs[1])
    tree.links.new(seen.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    cc.configure_cycles(scene, 64, 4, threads=2, seed=1)
    cyc = cc.render_cycles(scene, tmp_path)[0]
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = 64, 4, 1, 2
    mon = cc.render_monte(scene)[0]
    back = np.all(np.abs(cyc - (0.5, 0.25, 0.1)) < 1e-4, axis=2)
    assert 0.6 < back.mean() < 0.9
    off = np.abs(mon[back] - (0.5, 0.25, 0.1)).max(axis=1)
    # (a pixel beside the sphere's silhouette may catch a sphere sample in one engine's filter and not the other's)
    assert np.mean(off > 1e-4) < 0.02 and off.max() < 2e-2
    c, mm = cyc[~back].mean(axis=0), mon[~back].mean(axis=0)
    print(f"\nworld backdrop: sphere Cycles {np.round(c, 4)} Monte {np.round(mm, 4)} rel {np.round(mm / c - 1, 4)}")
    assert np.allclose(mm, c, rtol=0.01)


def test_a_reused_prepared_scene_follows_the_moved_camera():
    """The viewport reuses a prepared scene when only the camera moves: Camera / Window must follow it."""
    from monte.core.integrator import PreparedScene
    from monte.core.scene import Camera, Lobe, Material, Mesh, Scene

    prog = _program("texture_coordinate", 2, camera=0, window=1)
    prog.lobes = np.full((1, 6), -1, np.int32)
    prog.lobes[0, 0] = 0
    mesh = Mesh("quad", np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0]], float), np.array([[0, 1, 2]]))
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), resolution=(8, 8), kind="ORTHO", ortho_scale=4.0)
    scene = Scene(cam, [mesh], [Material("m", [Lobe("diffuse", np.ones(3))], program=prog)]).validate()
    ps = PreparedScene.build(scene)
    row = ps.shading.objects[-1].copy()
    moved = Camera.look_at((1, 0, 5), (1, 0, 0), up=(0, 1, 0), resolution=(8, 8), kind="ORTHO", ortho_scale=4.0)
    ps.update_camera(moved)
    after = ps.shading.objects[-1]
    # world -> camera translation: x shifts by -1 (right axis +x), z (forward) by 5
    assert row[3] == 0.0 and after[3] == -1.0 and row[11] == after[11] == 5.0
