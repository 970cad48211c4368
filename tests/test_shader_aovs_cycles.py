"""Shader AOVs in Blender (the real bpy module) against Cycles: View Layer Properties > Shader AOV lists a COLOR
and a VALUE AOV written by AOV Output nodes (a texture's colour and value, no lights needed), seen directly,
through a Transparent BSDF sheet (the writes add up) and behind clear glass (nothing written); both engines'
multilayer EXRs compared per pixel, with a control that a one-pixel shift fails the same comparison; the passes
are registered with Cycles' names and layouts and reach the compositor's Render Layers node. Russian roulette among
stacked Transparent BSDF veils ends AOV writes as in Cycles (only an emitting surface it ends a path on writes)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon.engine import requested_passes, shader_aov_passes, unsupported_passes  # noqa: E402
from monte.core import exr  # noqa: E402

pytestmark = [pytest.mark.blender]

SIZE = (40, 40)
SPP = 32
HALF = 2.0  # the orthographic view spans 4 m


def _aov_node(tree, name: str, socket: str, source) -> None:
    node = tree.nodes.new("ShaderNodeOutputAOV")
    node.aov_name = name
    tree.links.new(source, node.inputs[socket])


def aov_scene():
    """Seen from above (orthographic): a floor whose AOV Output nodes write the Object texture coordinate
    ("coords", COLOR) and a Noise Texture's Fac ("noise", VALUE); a Transparent BSDF sheet over x < -1 writing
    (1, 0, 0) to "coords"; a clear glass sheet over x > 1 writing nothing; no lamps, a grey world."""
    scene = bf.reset()
    floor_mat = bf.diffuse("Floor", (0.5, 0.5, 0.5))
    tree = floor_mat.node_tree
    coords = tree.nodes.new("ShaderNodeTexCoord")
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 1.5
    noise.inputs["Detail"].default_value = 0.0
    tree.links.new(coords.outputs["Object"], noise.inputs["Vector"])
    _aov_node(tree, "coords", "Color", coords.outputs["Object"])
    _aov_node(tree, "noise", "Value", noise.outputs["Fac"])
    veil_mat = bpy.data.materials.new("Veil")
    tree = bf.node_tree_of(veil_mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    transparent = tree.nodes.new("ShaderNodeBsdfTransparent")
    tree.links.new(transparent.outputs[0], out.inputs["Surface"])
    aov = tree.nodes.new("ShaderNodeOutputAOV")
    aov.aov_name = "coords"
    aov.inputs["Color"].default_value = (1.0, 0.0, 0.0, 1.0)
    glass = bf.node_material("Glass", "ShaderNodeBsdfGlass", IOR=1.5, Roughness=0.0)
    s = 3.0
    bf.mesh_object("Floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)], floor_mat)
    bf.mesh_object("Veil", [(-s, -s, 0.5), (-1, -s, 0.5), (-1, s, 0.5), (-s, s, 0.5)], [(0, 1, 2, 3)], veil_mat)
    bf.mesh_object("Pane", [(1, -s, 0.5), (s, -s, 0.5), (s, s, 0.5), (1, s, 0.5)], [(0, 1, 2, 3)], glass)
    bf.camera_object(scene, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), kind="ORTHO", ortho_scale=2 * HALF)
    bf.set_world(scene, (0.5, 0.5, 0.5), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    layer = scene.view_layers[0]
    for name, kind in (("coords", "COLOR"), ("noise", "VALUE")):
        bpy.ops.scene.view_layer_add_aov()
        layer.active_aov.name, layer.active_aov.type = name, kind
    return scene


def passes_of(channels: dict, layer: str) -> dict[str, np.ndarray]:
    return {"coords": np.stack([channels[f"{layer}.coords.{c}"] for c in "RGBA"], axis=-1),
            "noise": channels[f"{layer}.noise.X"][..., None]}


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("shader_aovs")
    scene = aov_scene()
    layer = scene.view_layers[0].name
    cycles_exr, monte_exr = bf.cycles_and_monte_exrs(scene, tmp, SPP, 4)
    return scene, passes_of(exr.read_exr(cycles_exr), layer), passes_of(exr.read_exr(monte_exr), layer)


def _columns() -> np.ndarray:
    """(W,) x of each pixel column's centre (EXR rows from the top; x grows to the right)."""
    return -HALF + (np.arange(SIZE[0]) + 0.5) * (2 * HALF / SIZE[0])


def _within(a: np.ndarray, b: np.ndarray, tol: np.ndarray) -> np.ndarray:
    return np.abs(a - b) <= tol


def test_aovs_match_cycles_per_pixel(renders):
    """A pixel's value is the mean of its samples' values, each taken at a filter-jittered point: Monte and Cycles
    differ by that jitter's mean, a small share of the value's change across one pixel (measured at 32 spp: rms
    0.018 of it, largest 0.08); the bound is 0.15 of the change across the pixel, so a one-pixel error fails
    (the control below), and the mean difference must be below 0.005 of a pixel's change (a bias)."""
    _, cyc, mon = renders
    x = _columns()
    pixel = 2 * HALF / SIZE[0]
    away = np.abs(np.abs(x) - 1) > 2 * pixel  # columns not straddling a sheet's edge
    for name, c in (("coords", 0), ("coords", 1), ("noise", 0)):
        ref, got = cyc[name][..., c], mon[name][..., c]
        reach = bf.footprint(ref)[:, away]
        signed = (got - ref)[:, away]
        live = reach > 0
        print(f"\n{name}[{c}]: |Monte - Cycles| / change across a pixel: largest "
              f"{(np.abs(signed[live]) / reach[live]).max():.3f}, rms {np.sqrt((signed ** 2).mean()):.5f}, "
              f"mean {signed.mean():+.6f}")
        assert np.all(np.abs(signed) <= 0.15 * reach + 1e-6), (name, c)
        assert abs(signed.mean()) <= 0.005 * np.median(reach[live]), (name, c)
    # z, and the alpha (the share of samples writing, two writes through the veil): equal in both
    for c in (2, 3):
        assert np.allclose(mon["coords"][..., c][:, away], cyc["coords"][..., c][:, away], atol=1e-5), c
    assert np.allclose(cyc["coords"][:, x < -1 - 2 * pixel, 3], 2.0)
    # behind the glass nothing writes, in both
    for img in (cyc, mon):
        assert np.all(img["coords"][:, x > 1 + 2 * pixel] == 0) and np.all(img["noise"][:, x > 1 + 2 * pixel] == 0)


def test_control_a_one_pixel_shift_fails_the_comparison(renders):
    """The comparison above detects an AOV one pixel off."""
    _, cyc, mon = renders
    x = _columns()
    pixel = 2 * HALF / SIZE[0]
    away = np.abs(np.abs(x) - 1) > 2 * pixel
    ref = cyc["coords"][..., 0]
    shifted = np.roll(mon["coords"][..., 0], 1, axis=1)
    assert not np.all(np.abs(shifted - ref)[:, away] <= 0.15 * bf.footprint(ref)[:, away] + 1e-6)


def test_aov_passes_are_registered_and_reach_the_compositor(renders, tmp_path):
    """The passes have Cycles' names and layouts, and the compositor's Render Layers node gives Monte's AOV."""
    scene, _, mon = renders
    layer = scene.view_layers[0]
    assert shader_aov_passes(layer) == {"coords": (4, "RGBA", "COLOR"), "noise": (1, "X", "VALUE")}
    assert requested_passes(layer, scene)[-2:] == ["coords", "noise"]
    assert unsupported_passes(layer) == []
    scene.render.engine = "MONTE"
    bf.composite_to_exr(scene, "CompositorNodeRLayers", "coords", "aov comp")
    path = tmp_path / "composited.exr"
    scene.render.filepath = str(path)
    try:
        bpy.ops.render.render(write_still=True, scene=scene.name)
    finally:
        scene.render.use_compositing = False
    image = exr.read_exr(path)
    got = np.stack([image[c] for c in "RGB"], axis=-1)
    assert np.allclose(got, mon["coords"][..., :3], atol=1e-4)  # a new render, the same seed: equal


def test_export_keeps_listed_aovs_and_warns_for_what_it_skips(tmp_path):
    """An AOV Output node of an AOV the view layer does not list compiles to nothing (as Cycles ignores it); an
    AOV named like a built-in pass is invalid (Blender marks it) and left out with a warning; AOV Output nodes in a
    node group or the world are named in warnings; `monte render scene.blend` writes the AOVs into its EXR."""
    from monte.addon.export import export_scene
    from monte.addon.headless import render_blend_file
    from monte.core.shading import registry as R

    scene = aov_scene()
    layer = scene.view_layers[0]
    floor = bpy.data.materials["Floor"].node_tree
    _aov_node(floor, "unlisted", "Value", floor.nodes["Noise Texture"].outputs["Fac"])
    group = bpy.data.node_groups.new("Hidden AOV", "ShaderNodeTree")
    group.nodes.new("ShaderNodeOutputAOV").aov_name = "coords"
    floor.nodes.new("ShaderNodeGroup").node_tree = group
    world_aov = scene.world.node_tree.nodes.new("ShaderNodeOutputAOV")
    world_aov.aov_name = "coords"
    veil = bpy.data.materials["Veil"].node_tree  # a shader into Value: an invalid link, the default is written
    _aov_node(veil, "noise", "Value", veil.nodes["Transparent BSDF"].outputs[0])
    veil.nodes["AOV Output.001"].inputs["Value"].default_value = 0.25
    bpy.ops.scene.view_layer_add_aov()
    layer.active_aov.name = "Combined"  # a built-in pass's name: invalid
    core_scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    assert core_scene.shader_aovs == [("coords", "COLOR"), ("noise", "VALUE")]
    floor_program = next(m for m in core_scene.materials if m.name == "Floor").program
    writes = floor_program.code[floor_program.code[:, 0] == R.OP_AOV_OUTPUT]
    assert sorted(writes[:, 2].tolist()) == [0, 1]  # coords and noise; "unlisted" left out
    veil_material = next(m for m in core_scene.materials if m.name == "Veil")
    assert [lobe.kind for lobe in veil_material.lobes] == ["refraction"]
    program = veil_material.program
    veil_writes = program.code[program.code[:, 0] == R.OP_AOV_OUTPUT]
    assert veil_writes[:, 2].tolist() == [0, 1]
    assert program.registers[veil_writes[1, 1], 0] == 0.25  # the Value input's own value, as Blender and Cycles
    warnings = "\n".join(core_scene.warnings)
    assert "shader AOV 'Combined' is invalid (a repeated name or the name of a built-in pass) and is not written" in \
        warnings
    assert "AOV Output nodes inside node groups are not evaluated by Monte" in warnings
    assert "world 'World': AOV Output nodes in the world are not evaluated by Monte" in warnings
    layer.aovs.remove(layer.aovs[-1])
    scene.monte.samples, scene.monte.threads = 4, 2
    blend = tmp_path / "aovs.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "aovs.exr"
    render_blend_file(blend, out)
    channels = exr.read_exr(out)
    assert {"coords.R", "coords.G", "coords.B", "coords.A", "noise.X"} <= set(channels)
    x = _columns()
    assert np.allclose(channels["coords.A"][:, np.abs(x) < 0.8], 1.0)


def _veils_scene(emits: bool):
    """Six stacked Transparent BSDF sheets (colour 0.6), each writing 1 to the VALUE AOV "layers" (with `emits`, a
    faint Emission added to their shader), over a black world, seen from above (16x16)."""
    scene = bf.reset()
    mat = bpy.data.materials.new("Veil")
    tree = bf.node_tree_of(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    transparent = tree.nodes.new("ShaderNodeBsdfTransparent")
    transparent.inputs["Color"].default_value = (0.6, 0.6, 0.6, 1.0)
    surface = transparent.outputs[0]
    if emits:
        glow = tree.nodes.new("ShaderNodeEmission")
        glow.inputs["Strength"].default_value = 0.01
        add = tree.nodes.new("ShaderNodeAddShader")
        tree.links.new(surface, add.inputs[0])
        tree.links.new(glow.outputs[0], add.inputs[1])
        surface = add.outputs[0]
    tree.links.new(surface, out.inputs["Surface"])
    aov = tree.nodes.new("ShaderNodeOutputAOV")
    aov.aov_name = "layers"
    aov.inputs["Value"].default_value = 1.0
    s = 3.0
    for k in range(6):
        bf.mesh_object(f"Veil{k}", [(-s, -s, k), (s, -s, k), (s, s, k), (-s, s, k)], [(0, 1, 2, 3)], mat)
    bf.camera_object(scene, (0.0, 0.0, 10.0), (0.0, 0.0, 0.0), kind="ORTHO", ortho_scale=2 * HALF)
    bf.set_world(scene, (0.0, 0.0, 0.0), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = 16, 16
    scene.render.resolution_percentage = 100
    layer = scene.view_layers[0]
    bpy.ops.scene.view_layer_add_aov()
    layer.active_aov.name, layer.active_aov.type = "layers", "VALUE"
    return scene


@pytest.mark.parametrize("emits", [False, True])
def test_russian_roulette_ends_aov_writes_as_in_cycles(emits, tmp_path):
    """Cycles decides Russian roulette before shading and shades a surface it ends a path on only when the shader
    emits: through six 0.6-transparent veils the AOV sums to 3.31 (no emission) or 4.18 (emission) per sample.
    Monte's mean within 1 % of Cycles' (256 spp each: standard error about 0.1 %); control: the other rule's
    value (21 % away) is rejected by the same bound."""
    scene = _veils_scene(emits)
    layer = scene.view_layers[0].name
    cycles_exr, monte_exr = bf.cycles_and_monte_exrs(scene, tmp_path, 256, 4)
    cyc = float(exr.read_exr(cycles_exr)[f"{layer}.layers.X"].mean())
    mon = float(exr.read_exr(monte_exr)[f"{layer}.layers.X"].mean())
    print(f"\nveils (emission {emits}): Monte {mon:.4f} Cycles {cyc:.4f} ({100 * (mon / cyc - 1):+.2f} %)")
    assert abs(mon / cyc - 1) < 0.01
    other = 2 + 0.6 * 2.176 if emits else 2 + 2.176
    assert abs(other / cyc - 1) > 0.01


def test_a_held_out_floor_writes_its_aovs_as_in_cycles(tmp_path):
    """The floor set to holdout (Object > Visibility > Holdout): Cycles evaluates its shader, AOV Output nodes
    included, before the holdout ends the path, so the AOVs hold the floor's values where the camera sees it; so
    do Monte's (the same per-pixel bound as above; the colour alpha, the share of samples writing, equal)."""
    scene = aov_scene()
    bpy.data.objects["Floor"].is_holdout = True
    layer = scene.view_layers[0].name
    cycles_exr, monte_exr = bf.cycles_and_monte_exrs(scene, tmp_path, SPP, 4)
    cyc, mon = passes_of(exr.read_exr(cycles_exr), layer), passes_of(exr.read_exr(monte_exr), layer)
    x = _columns()
    open_floor = np.abs(x) < 1 - 2 * 2 * HALF / SIZE[0]  # the floor seen directly, between the sheets
    assert np.allclose(cyc["coords"][:, open_floor, 3], 1.0)  # Cycles writes there
    for name, c in (("coords", 0), ("coords", 1), ("noise", 0)):
        ref, got = cyc[name][..., c][:, open_floor], mon[name][..., c][:, open_floor]
        assert np.all(np.abs(got - ref) <= 0.15 * bf.footprint(cyc[name][..., c])[:, open_floor] + 1e-6), (name, c)
    assert np.allclose(mon["coords"][:, open_floor, 3], cyc["coords"][:, open_floor, 3], atol=1e-5)
