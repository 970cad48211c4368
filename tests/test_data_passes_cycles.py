"""The data passes in Blender (the real bpy module) against Cycles: the same scene rendered by both, each pass
compared; Cryptomatte mattes pulled by Blender's own compositor Cryptomatte node equal the object masks; the
passes reach the render result and its multilayer EXR with Cycles' names and manifests; the Vector pass, which
Cycles renders only without motion blur, is named in a warning and not registered with motion blur on.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.lab.bpy_scenes import box_object  # noqa: E402

from monte.addon import crosscheck as cc  # noqa: E402
from monte.addon.engine import data_pass_names, requested_passes, unavailable_pass_warnings  # noqa: E402
from monte.core import exr  # noqa: E402
from monte.core.data_passes import hash_to_float, name_hash  # noqa: E402

pytestmark = [pytest.mark.blender]

SIZE = (40, 32)
SPP = 16
FLAGS = ("use_pass_mist", "use_pass_position", "use_pass_uv", "use_pass_object_index", "use_pass_material_index",
         "use_pass_cryptomatte_object", "use_pass_cryptomatte_material", "use_pass_cryptomatte_asset")


def data_scene():
    """A floor, a ball and a box (the box parented to an empty "Rig": its Cryptomatte asset), each with its own
    pass index and material (with pass indices), UV maps, linear mist from 2 to 12 m, under a grey world."""
    scene = bf.reset()
    s = 4.0
    floor = bf.mesh_object("Floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                           bf.diffuse("FloorMat", (0.6, 0.6, 0.6)))
    ball = bf.icosphere_object("Ball", (-0.7, 0.3, 0.6), 0.6, bf.diffuse("BallMat", (0.8, 0.2, 0.2)),
                               subdivisions=3)
    box = box_object("Box", (0.2, -0.6, 0.0), (1.2, 0.4, 1.0), bf.diffuse("BoxMat", (0.2, 0.3, 0.8)))
    rig = bpy.data.objects.new("Rig", None)
    scene.collection.objects.link(rig)
    box.parent = rig
    for obj, index in ((floor, 1), (ball, 2), (box, 3)):
        obj.pass_index = index
        obj.data.uv_layers.new(name="UVMap")
        obj.active_material.pass_index = 10 + index
    bf.camera_object(scene, (0.0, -5.0, 3.0), (np.radians(60), 0.0, 0.0), lens=35.0)
    bf.set_world(scene, (0.3, 0.3, 0.3), 1.0)
    mist = scene.world.mist_settings
    mist.start, mist.depth, mist.falloff = 2.0, 10.0, "LINEAR"
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    layer = scene.view_layers[0]
    for flag in FLAGS:
        setattr(layer, flag, True)
    layer.pass_cryptomatte_depth = 4
    return scene


def render_exr(scene, path: Path) -> tuple[dict, dict]:
    """F12 with the scene's engine, saved as Blender's multilayer EXR: (channels, header)."""
    scene.render.use_compositing = False
    bf.render_still_exr(scene, path)
    return exr.read_exr(path), exr.read_header(path)


def passes_of(channels: dict, layer: str) -> dict[str, np.ndarray]:
    """{pass: (H, W, C)} from "<layer>.<pass>.<channel>" channels (Blender's order of the channel letters;
    Cryptomatte's in lower case, as Blender writes Cycles' layers)."""
    out: dict[str, list] = {}
    for pass_name, letters in (("Mist", "Z"), ("Position", "XYZ"), ("UV", "UVA"), ("Object Index", "X"),
                               ("Material Index", "X"),
                               *((f"Crypto{k}{i:02d}", "rgba") for k in ("Object", "Material", "Asset")
                                 for i in range(2))):
        out[pass_name] = np.stack([channels[f"{layer}.{pass_name}.{c}"] for c in letters], axis=-1)
    return out


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("data_passes")
    scene = data_scene()
    layer = scene.view_layers[0].name
    cc.configure_cycles(scene, SPP, 4, threads=2, seed=1, filter_type="blackman-harris", filter_width=1.5)
    cycles_channels, cycles_header = render_exr(scene, tmp / "cycles.exr")
    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = SPP, 4, 1, 2
    m.filter_type, m.filter_width = "blackman-harris", 1.5
    monte_channels, monte_header = render_exr(scene, tmp / "monte.exr")
    return (scene, passes_of(cycles_channels, layer), cycles_header, passes_of(monte_channels, layer),
            monte_header)


def interior(index_image: np.ndarray) -> np.ndarray:
    """Pixels whose 3x3 neighbourhood shows one object (no edge inside: the sample-0 passes agree there)."""
    img = index_image[..., 0]
    pad = np.pad(img, 1, mode="edge")
    same = np.ones(img.shape, bool)
    for dy in range(3):
        for dx in range(3):
            same &= pad[dy:dy + img.shape[0], dx:dx + img.shape[1]] == img
    return same


def test_index_and_position_passes_equal_cycles_per_pixel(renders):
    _, cyc, _, mon, _ = renders
    inside = interior(mon["Object Index"]) & interior(cyc["Object Index"])
    assert inside.mean() > 0.6
    for name in ("Object Index", "Material Index"):
        assert np.array_equal(mon[name][inside], cyc[name][inside]), name
    assert set(np.unique(mon["Object Index"])) == {0.0, 1.0, 2.0, 3.0}
    assert set(np.unique(mon["Material Index"])) == {0.0, 11.0, 12.0, 13.0}
    # Position: one sample's hit within the filter's 1.5 pixels in each: at most 1.5 pixels' change apart
    diff = np.abs(mon["Position"] - cyc["Position"])[inside]
    bound = 1.5 * bf.footprint(cyc["Position"])[inside] + 1e-4
    print(f"\nPosition: mean |Monte - Cycles| {diff.mean():.4f} m, max {diff.max():.4f} m, largest share of "
          f"the bound {(diff / bound).max():.2f}")
    assert np.all(diff <= bound)
    # the means (each pixel one sample: its jitter does not average out per pixel) within 1% of the scene's size
    cm, mm = cyc["Position"].reshape(-1, 3).mean(0), mon["Position"].reshape(-1, 3).mean(0)
    size = np.ptp(cyc["Position"].reshape(-1, 3), axis=0).max()
    print(f"Position means: Cycles {np.round(cm, 4)}, Monte {np.round(mm, 4)} (scene size {size:.2f} m)")
    assert np.all(np.abs(mm - cm) <= 0.01 * size), (mm, cm)


def test_mist_and_uv_match_cycles(renders):
    _, cyc, _, mon, _ = renders
    for name in ("Mist", "UV"):
        cm, mm = cyc[name].reshape(-1, cyc[name].shape[2]).mean(0), mon[name].reshape(-1, mon[name].shape[2]).mean(0)
        print(f"\n{name}: means Cycles {np.round(cm, 5)} Monte {np.round(mm, 5)}; mean |diff| per pixel "
              f"{np.abs(mon[name] - cyc[name]).mean():.5f}")
        assert np.all(np.abs(mm - cm) <= 0.01 * np.maximum(np.abs(cm), 1e-3)), name
    inside = interior(mon["Object Index"]) & interior(cyc["Object Index"])
    # per pixel: means of 16 samples over the same footprint, apart by far less than the pass changes per pixel
    diff = np.abs(mon["Mist"] - cyc["Mist"])[inside]
    assert np.all(diff <= 0.5 * bf.footprint(cyc["Mist"])[inside] + 2e-3), diff.max()
    world = inside & (mon["Object Index"][..., 0] == 0)
    assert world.sum() > 10 and np.all(mon["Mist"][world] == 1.0)  # the world: no mist written, 1


def test_cryptomatte_matches_cycles(renders):
    _, cyc, cyc_header, mon, mon_header = renders
    layer = renders[0].view_layers[0].name
    for kind in ("Object", "Material", "Asset"):
        c0, m0 = cyc[f"Crypto{kind}00"], mon[f"Crypto{kind}00"]
        inside = interior(mon["Object Index"]) & interior(cyc["Object Index"])
        assert np.array_equal(m0[inside][:, 0], c0[inside][:, 0]), kind  # the same top-ranked id
        cov_c = sum(cyc[f"Crypto{kind}{i:02d}"][..., c].mean() for i in range(2) for c in (1, 3))
        cov_m = sum(mon[f"Crypto{kind}{i:02d}"][..., c].mean() for i in range(2) for c in (1, 3))
        assert abs(cov_m - cov_c) <= 0.01 * cov_c, (kind, cov_m, cov_c)
    # the manifests in the file's metadata: Cycles' keys and names
    for kind, names in (("Object", {"Floor", "Ball", "Box"}), ("Material", {"FloorMat", "BallMat", "BoxMat"}),
                        ("Asset", {"Floor", "Ball", "Rig"})):
        key = f"cryptomatte/{name_hash(f'{layer}.Crypto{kind}'):08x}"[:19]
        assert str(mon_header[f"{key}/name"]) == f"{layer}.Crypto{kind}"
        assert str(cyc_header[f"{key}/name"]) == f"{layer}.Crypto{kind}"
        manifest = json.loads(str(mon_header[f"{key}/manifest"]))
        assert set(manifest) == names
        assert all(int(v, 16) == name_hash(n) for n, v in manifest.items())
        cycles_manifest = json.loads(str(cyc_header[f"{key}/manifest"]))
        assert all(cycles_manifest[n] == v for n, v in manifest.items())


def test_compositor_cryptomatte_node_picks_each_object(renders, tmp_path):
    """Blender's compositor (Cryptomatte node, source Render, matte by name) on Monte's render: each object's
    matte equals its mask (the Object Index pass's coverage: 1 inside, partial only on edges)."""
    scene, _, _, mon, _ = renders
    scene.render.engine = "MONTE"
    node = bf.composite_to_exr(scene, "CompositorNodeCryptomatteV2", "Matte", "crypto comp")
    node.source = "RENDER"
    node.layer_name = f"{scene.view_layers[0].name}.CryptoObject"
    scene.view_settings.view_transform = "Standard"
    crypto = mon["CryptoObject00"]
    for name in ("Ball", "Box", "Floor"):
        node.matte_id = name
        path = tmp_path / f"matte_{name}.exr"
        scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True, scene=scene.name)
        matte = exr.read_exr(path)["R"]
        fid = hash_to_float(name_hash(name))
        expected = np.where(crypto[..., 0] == fid, crypto[..., 1], 0) + np.where(crypto[..., 2] == fid,
                                                                                  crypto[..., 3], 0)
        inside = interior(mon["Object Index"])
        mask = (mon["Object Index"][..., 0] == {"Floor": 1, "Ball": 2, "Box": 3}[name]) & inside
        print(f"\n{name}: matte sum {matte.sum():.2f}, coverage sum {expected.sum():.2f}, "
              f"max |diff| {np.abs(matte - expected).max():.5f}")
        assert mask.sum() > 10
        assert np.allclose(matte, expected, atol=1e-4), name  # a different render, the same seed: equal
        assert np.all(matte[mask] == 1.0) and np.all(matte[inside & ~mask] == 0.0)
    scene.render.use_compositing = False


def test_pass_registration_and_unavailable_pass_warning():
    scene = data_scene()
    layer = scene.view_layers[0]
    assert data_pass_names(layer, scene) == ["Mist", "Position", "UV", "Object Index", "Material Index", "CryptoObject00",
                                             "CryptoObject01", "CryptoMaterial00", "CryptoMaterial01",
                                             "CryptoAsset00", "CryptoAsset01"]
    layer.use_pass_vector = True  # produced without motion blur (tests/test_vector_pass_cycles.py)
    assert "Vector" in requested_passes(layer, scene) and unavailable_pass_warnings(layer, scene) == []
    scene.render.use_motion_blur = True  # as in Cycles, not with motion blur: named, not registered
    assert "Vector" not in requested_passes(layer, scene)
    assert unavailable_pass_warnings(layer, scene) == [
        f"view layer {layer.name!r}: the Vector pass is not available with motion blur on (as in Cycles); it is "
        "not produced"]
    scene.render.use_motion_blur = False
    layer.use_pass_vector = False
    local_names = data_pass_names(layer, scene)
    scene.monte.use_cluster = True  # a cluster render carries them as a local one (tests/test_cluster_ui.py)
    assert data_pass_names(layer, scene) == local_names and unavailable_pass_warnings(layer, scene) == []
    scene.monte.use_cluster = False
    for flag in FLAGS:
        setattr(layer, flag, False)
    assert requested_passes(layer, scene) == ["Combined"]  # nothing selected: nothing registered or computed


def veil_material(transparency: float):
    """Mix Shader: a diffuse and a Transparent BSDF, the latter with weight `transparency`."""
    mat = bpy.data.materials.new("VeilMat")
    tree = bf.node_tree_of(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = transparency
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.9, 0.8, 0.2, 1.0)
    clear = tree.nodes.new("ShaderNodeBsdfTransparent")
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(clear.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def test_passes_through_a_transparent_veil_match_cycles(tmp_path):
    """A 70 % transparent veil over half the view: Mist, UV and each Cryptomatte name's total coverage as Cycles
    (their means within 1 %); the veil and what is behind it share the coverage."""
    scene = data_scene()
    veil = bf.mesh_object("Veil", [(-3, -3, 1.4), (0.3, -3, 1.4), (0.3, 3, 1.4), (-3, 3, 1.4)], [(0, 1, 2, 3)],
                          veil_material(0.7))
    veil.data.uv_layers.new(name="UVMap")
    layer = scene.view_layers[0].name
    cc.configure_cycles(scene, 64, 4, threads=2, seed=1, filter_type="blackman-harris", filter_width=1.5)
    cyc = passes_of(render_exr(scene, tmp_path / "cycles.exr")[0], layer)
    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = 64, 4, 1, 2
    m.filter_type, m.filter_width = "blackman-harris", 1.5
    mon = passes_of(render_exr(scene, tmp_path / "monte.exr")[0], layer)
    for name in ("Mist", "UV"):
        cm, mm = cyc[name].reshape(-1, cyc[name].shape[2]).mean(0), mon[name].reshape(-1, mon[name].shape[2]).mean(0)
        print(f"\n{name} with the veil: means Cycles {np.round(cm, 5)} Monte {np.round(mm, 5)}")
        assert np.all(np.abs(mm - cm) <= 0.01 * np.maximum(np.abs(cm), 1e-3)), name

    def coverage(passes, name):
        """(H, W) the coverage of a name in every pixel."""
        fid = hash_to_float(name_hash(name))
        return sum(np.where(passes[f"CryptoObject{i:02d}"][..., c] == fid,
                            passes[f"CryptoObject{i:02d}"][..., c + 1], 0) for i in range(2) for c in (0, 2))

    for name in ("Veil", "Floor", "Ball"):
        cyc_cov, mon_cov = coverage(cyc, name), coverage(mon, name)
        # noise: pixels partly covered (behind the veil, on edges) are Bernoulli means of 64 samples in each
        partial = ((cyc_cov > 0) & (cyc_cov < 1)) | ((mon_cov > 0) & (mon_cov < 1))
        sigma = np.sqrt(2 * 0.25 / 64 * partial.sum())
        print(f"{name}: coverage Cycles {cyc_cov.sum():.2f} Monte {mon_cov.sum():.2f} pixels (sigma {sigma:.2f})")
        assert abs(mon_cov.sum() - cyc_cov.sum()) <= max(0.01 * cyc_cov.sum(), 4 * sigma), name
    veil_cov = coverage(mon, "Veil")
    assert (veil_cov > 0).sum() > 200 and np.median(veil_cov[veil_cov > 0]) == np.float32(0.3)  # opacity 0.3


def test_headless_exr_carries_the_data_passes_and_manifests(tmp_path):
    """`monte render scene.blend -o out.exr` (addon.headless): the data passes as <pass>.<channel> channels, the
    Cryptomatte layers as the standard names them (CryptoObject00.R ...) with their manifests in the header.
    Last in this module: it opens the saved file in place of the current one."""
    from monte.addon.headless import render_blend_file

    scene = data_scene()
    scene.render.engine = "MONTE"
    scene.monte.threads = 2
    blend = tmp_path / "data.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "out.exr"
    render_blend_file(blend, out, {"spp": 4}, log=lambda _msg: None)
    channels, header = exr.read_exr(out), exr.read_header(out)
    for name in ("Mist.Z", "Position.X", "Position.Z", "UV.U", "UV.A", "Object Index.X", "Material Index.X",
                 "CryptoObject00.R", "CryptoObject01.A", "CryptoMaterial00.G", "CryptoAsset01.B"):
        assert name in channels, name
    assert set(np.unique(channels["Object Index.X"])) == {0.0, 1.0, 2.0, 3.0}
    assert np.all(channels["Mist.Z"] >= 0) and np.all(channels["Mist.Z"] <= 1)
    ids = set(np.unique(channels["CryptoObject00.R"])) - {0.0}
    assert ids == {hash_to_float(name_hash(n)) for n in ("Floor", "Ball", "Box")}
    key = f"cryptomatte/{name_hash('CryptoObject'):08x}"[:19]
    assert str(header[f"{key}/name"]) == "CryptoObject"
    assert set(json.loads(str(header[f"{key}/manifest"]))) == {"Floor", "Ball", "Box"}
