"""Cycles' data passes in the core (core.data_passes): hashing, and each pass on a scene whose values are known
exactly (two quads at known depths seen by an orthographic camera)."""

import json

import numpy as np
import pytest

from monte.core.data_passes import cryptomatte_metadata, hash_to_float, manifest, murmur3_32, name_hash
from monte.core.render import render
from monte.core.scene import Camera, Lobe, Material, Mesh, Mist, Scene, SceneError, World
from monte.core.settings import RenderSettings
from monte.core.shading.program import OBJECT_PASS_INDEX, identity_object_row

ALL = ("mist", "position", "uv", "object_index", "material_index", "crypto_object", "crypto_material",
       "crypto_asset")


def test_murmur3_matches_the_reference_test_vectors():
    # MurmurHash3_x86_32's published test vectors (data, seed) -> hash
    assert murmur3_32(b"", 0) == 0
    assert murmur3_32(b"", 1) == 0x514E28B7
    assert murmur3_32(b"", 0xFFFFFFFF) == 0x81F16F39
    assert murmur3_32(b"\x00\x00\x00\x00", 0) == 0x2362F9DE
    assert murmur3_32(b"aaaa", 0x9747B28C) == 0x5A97808A
    assert murmur3_32(b"aaa", 0x9747B28C) == 0x283E0130
    assert murmur3_32(b"aa", 0x9747B28C) == 0x5D211726
    assert murmur3_32(b"a", 0x9747B28C) == 0x7FA09EA6
    assert murmur3_32(b"Hello, world!", 0x9747B28C) == 0x24884CBA
    assert murmur3_32(b"The quick brown fox jumps over the lazy dog", 0x9747B28C) == 0x2FA826CD


def test_hash_to_float_keeps_the_exponent_finite_and_normal():
    assert hash_to_float(0x3F800000) == np.float32(1.0)  # an ordinary exponent: the bits as they are
    assert np.frombuffer(hash_to_float(0x00000001).tobytes(), np.uint32)[0] == 0x00800001  # exponent 0 -> 1
    inf_bits = np.frombuffer(hash_to_float(0xFF800000).tobytes(), np.uint32)[0]
    assert inf_bits == 0xFF000000  # exponent 255 -> 254, sign kept
    assert np.isfinite(hash_to_float(0x7FFFFFFF))


def test_manifest_and_metadata_follow_the_cryptomatte_layout():
    assert manifest(["b", "a", "a"]) == {"a": f"{name_hash('a'):08x}", "b": f"{name_hash('b'):08x}"}
    meta = cryptomatte_metadata("ViewLayer.CryptoObject", ["Cube"])
    key = f"cryptomatte/{name_hash('ViewLayer.CryptoObject'):08x}"[:19]
    assert meta[f"{key}/name"] == "ViewLayer.CryptoObject"
    assert meta[f"{key}/hash"] == "MurmurHash3_32"
    assert meta[f"{key}/conversion"] == "uint32_to_float32"
    assert meta[f"{key}/manifest"] == '{"Cube":"%08x"}' % name_hash("Cube")


def _quad(name, z, x0, x1, material, obj):
    v = np.array([(x0, -2, z), (x1, -2, z), (x1, 2, z), (x0, 2, z)], np.float64)
    uv = np.array([[(0, 0), (1, 0), (1, 1)], [(0, 0), (1, 1), (0, 1)]], np.float32)
    return Mesh(name, v, np.array([(0, 1, 2), (0, 2, 3)]), material, uvs=uv, object_index=obj)


def _scene(mist=Mist(2.0, 4.0, "LINEAR")) -> Scene:
    """An orthographic camera at z = 10 looking down -z over [-1, 1]^2 (16x16 pixels): the left half sees quad
    "left" at z = 7 (distance 3), the right half quad "right" at z = 4 (distance 6); both reach beyond the frame
    (the pixel filter's samples at the border land outside it)."""
    cam = Camera(np.eye(4), (16, 16), kind="ORTHO", ortho_scale=2.0)
    cam.matrix_world[2, 3] = 10.0
    objects = np.stack([identity_object_row(), identity_object_row()])
    objects[0, OBJECT_PASS_INDEX], objects[1, OBJECT_PASS_INDEX] = 3, 7
    mats = [Material("red", [Lobe("diffuse", (0.8, 0.2, 0.2))], pass_index=5),
            Material("blue", [Lobe("diffuse", (0.2, 0.2, 0.8))], pass_index=9)]
    return Scene(cam, [_quad("left mesh", 7.0, -2.0, 0.0, 0, 0), _quad("right mesh", 4.0, 0.0, 2.0, 1, 1)], mats,
                 world=World(color=(0.5, 0.5, 0.5)), objects=objects, object_names=["Left", "Right"],
                 asset_names=["Group", "Group"], mist=mist)


def _render(scene, passes=ALL, spp=16, **kw):
    return render(scene, RenderSettings(spp=spp, threads=1, data_passes=passes, tile_size=8, **kw))


def test_each_data_pass_on_a_scene_with_known_values():
    result = _render(_scene())
    p = result.data_passes
    left, right = (slice(2, 14), slice(1, 7)), (slice(2, 14), slice(9, 15))  # away from the middle edge
    assert np.allclose(p["Position"][left][..., 2], 7.0) and np.allclose(p["Position"][right][..., 2], 4.0)
    assert np.all(p["Position"][left][..., 0] < 0) and np.all(p["Position"][right][..., 0] > 0)
    assert np.all(p["Object Index"][left] == 3) and np.all(p["Object Index"][right] == 7)
    assert np.all(p["Material Index"][left] == 5) and np.all(p["Material Index"][right] == 9)
    # linear mist from 2 to 6: distance 3 reads 0.25, distance 6 reads 1
    assert np.allclose(p["Mist"][left], 0.25, atol=1e-6) and np.allclose(p["Mist"][right], 1.0, atol=1e-6)
    # UV: the quad's (0..1) map; the A channel 1 wherever the pixel's samples all hit
    assert np.allclose(p["UV"][..., 2], 1.0)
    assert np.all(np.diff(p["UV"][left][..., 0], axis=1) > 0)
    # Cryptomatte: 3 layers of 2 ranks (levels 6); coverage 1 of the right name inside, shared at the edge
    assert sorted(n for n in p if n.startswith("Crypto")) == sorted(
        f"Crypto{k}{i:02d}" for k in ("Object", "Material", "Asset") for i in range(3))
    obj = p["CryptoObject00"]
    assert np.all(obj[left][..., 0] == hash_to_float(name_hash("Left")))
    assert np.all(obj[right][..., 0] == hash_to_float(name_hash("Right")))
    assert np.allclose(obj[..., 1] + obj[..., 3], 1.0)  # every sample hits one of the two
    assert np.all(obj[..., 1] >= obj[..., 3])  # ranks in decreasing coverage
    edge = obj[:, 7:9]
    assert (edge[..., 3] > 0).mean() > 0.8  # pixels on the edge see both quads (the filter reaches 1.5 px)
    assert np.all(p["CryptoMaterial00"][left][..., 0] == hash_to_float(name_hash("red")))
    asset = p["CryptoAsset00"]
    assert np.all(asset[..., 0] == hash_to_float(name_hash("Group"))) and np.allclose(asset[..., 1], 1.0)
    assert np.all(p["CryptoObject01"] == 0)  # nothing beyond two names per pixel
    assert result.cryptomatte == {"CryptoObject": ["Left", "Right"], "CryptoMaterial": ["blue", "red"],
                                  "CryptoAsset": ["Group"]}


def test_mist_falloffs_and_the_world():
    scene = _scene()
    scene.camera.resolution = (16, 16)
    scene.meshes = scene.meshes[:1]  # the right half sees the world
    for falloff, expected in (("QUADRATIC", 0.25 ** 2), ("INVERSE_QUADRATIC", 0.25 ** 0.5), ("LINEAR", 0.25)):
        scene.mist = Mist(2.0, 4.0, falloff)
        mist = _render(scene, ("mist",), spp=4).data_passes["Mist"]
        assert np.allclose(mist[2:14, 1:7], expected, atol=1e-6), falloff
        assert np.all(mist[:, 9:] == 1.0)  # a miss adds nothing: the world reads 1


def test_data_passes_change_nothing_else_and_cost_nothing_off():
    plain = _render(_scene(), ())
    with_passes = _render(_scene())
    assert plain.data_passes == {} and plain.cryptomatte == {}
    assert np.array_equal(plain.color, with_passes.color)  # they draw no random numbers


def test_bad_data_pass_input_is_named():
    with pytest.raises(ValueError, match="unknown data pass 'shadow'"):
        RenderSettings(data_passes=("mist", "shadow")).validate()
    with pytest.raises(ValueError, match=r"cryptomatte levels must be a whole number in \[1, 16\], got 0"):
        RenderSettings(cryptomatte_levels=0).validate()
    with pytest.raises(SceneError, match="world mist falloff 'CUBIC' is not one of"):
        _render(_scene(Mist(0.0, 1.0, "CUBIC")), ("mist",), spp=1)
    with pytest.raises(SceneError, match="world mist depth is -1.0, it must be >= 0"):
        _render(_scene(Mist(0.0, -1.0)), ("mist",), spp=1)


def test_passes_look_through_a_transparent_bsdf_as_cycles():
    """The left quad 70 % transparent (Transparent BSDF 0.7 + diffuse 0.3) over a third quad at z = 1
    (distance 9): Mist and Cryptomatte add both surfaces weighted by opacity and throughput; Position, the indices
    and UV read the back one where the path went on through the front (whose alpha 0.3 is below Cycles' threshold
    0.5), as Cycles' paths do with the Transparent BSDF's share of the lobe choice."""
    scene = _scene(Mist(2.0, 8.0, "LINEAR"))
    scene.materials.append(Material("veil", [Lobe("refraction", (0.7, 0.7, 0.7), ior=1.0, roughness=0.0),
                                             Lobe("diffuse", (0.3, 0.3, 0.3))], pass_index=2))
    scene.meshes[0].material_index = 2
    back = _quad("back mesh", 1.0, -2.0, 0.0, 0, 0)
    back.object_index = None  # no object: Cryptomatte names it by its mesh, Object Index 0
    scene.meshes.append(back)
    spp = 256
    p = _render(scene, ("mist", "position", "object_index", "material_index", "uv", "crypto_object"),
                spp=spp).data_passes
    left = (slice(2, 14), slice(1, 6))
    # mist: 1 - (0.3 (1 - m(3)) + 0.7 (1 - m(9))), m(3) = 1/8, m(9) = 7/8; each sample adds the back with 0 or 1
    expected = 1 - (0.3 * (1 - 1 / 8) + 0.7 * (1 - 7 / 8))
    mist = p["Mist"][left]
    sigma = np.sqrt(0.7 * 0.3 / spp) * (1 - 7 / 8)  # per pixel: the back's share is a binomial mean
    assert abs(mist.mean() - expected) < 4 * sigma / np.sqrt(mist.size) + 1e-4, (mist.mean(), expected)
    obj = p["CryptoObject00"][left], p["CryptoObject01"][left]
    cov = {}
    for layer in obj:
        for c in (0, 2):
            for fid in np.unique(layer[..., c]):
                cov[fid] = cov.get(fid, 0.0) + layer[..., c + 1][layer[..., c] == fid].sum() / (mist.size)
    front, behind = hash_to_float(name_hash("Left")), hash_to_float(name_hash("back mesh"))
    assert abs(cov[front] - 0.3) < 1e-6  # the front: opacity 0.3 at throughput 1, every sample
    assert abs(cov[behind] - 0.7) < 4 * np.sqrt(0.21 / spp / mist.size) + 1e-4
    # the single-sample passes: the back surface where sample 0 went through (probability 0.7), else the front
    z = p["Position"][left][..., 2]
    back = np.abs(z - 1.0) < 1e-5  # (the hit's t, rounded by Embree, puts a point an ulp or so off the plane)
    assert np.all(back | (np.abs(z - 7.0) < 1e-5)) and abs(back.mean() - 0.7) < 4 * np.sqrt(0.21 / z.size)
    assert np.all(p["Object Index"][left][..., 0] == np.where(back, 0, 3))
    assert np.all(p["Material Index"][left][..., 0] == np.where(back, 5, 2))
    # UV only where a sample reached an opaque enough surface: the back one, 0.7 of the samples
    assert abs(p["UV"][left][..., 2].mean() - 0.7) < 4 * np.sqrt(0.21 / spp / z.size) + 1e-4


def test_a_region_holds_the_full_frames_pixels_and_dead_rays_add_nothing():
    scene = _scene()
    full = _render(scene, ALL, spp=4).data_passes
    part = render(scene, RenderSettings(spp=4, threads=1, data_passes=ALL, tile_size=8), region=(3, 5, 9, 7))
    for name, img in part.data_passes.items():  # every sample of a pixel is the same in both renders
        assert np.array_equal(img, full[name][5:12, 3:12]), name
    # a fisheye's rays outside its circle are dead: nothing seen, Mist 1, no index, no Cryptomatte
    fisheye = _scene()
    fisheye.camera = Camera(fisheye.camera.matrix_world, (16, 16), kind="PANO",
                            panorama_type="FISHEYE_EQUIDISTANT", fisheye_fov=np.pi)
    p = _render(fisheye, ALL, spp=4).data_passes
    assert p["Mist"][0, 0, 0] == 1.0 and p["Object Index"][0, 0, 0] == 0 and np.all(p["CryptoObject00"][0, 0] == 0)
    assert p["Object Index"][8, 6, 0] == 3 and p["Object Index"][8, 8, 0] == 7  # near the axis: both quads


def test_the_command_line_writes_the_passes_and_manifests(tmp_path, capsys):
    from monte.cli import main
    from monte.core import exr

    out = tmp_path / "out.exr"
    assert main(["render", "cornell", "-o", str(out), "--spp", "2", "--resolution", "16x16", "--threads", "1",
                 "--passes", "mist,object_index,crypto_material", "--no-png", "-q"]) == 0
    channels, header = exr.read_exr(out), exr.read_header(out)
    assert {"Mist.Z", "Object Index.X", "CryptoMaterial00.R", "CryptoMaterial02.A"} <= set(channels)
    key = f"cryptomatte/{name_hash('CryptoMaterial'):08x}"[:19]
    assert header[f"{key}/name"] == "CryptoMaterial"
    assert set(json.loads(header[f"{key}/manifest"])) <= {"white", "red", "blue", "mirror", "glass", "lamp"}
    with pytest.raises(SystemExit):
        main(["render", "cornell", "--passes", "mist,shadow"])
    assert "unknown data pass 'shadow'" in capsys.readouterr().err


def test_memory_estimate_counts_the_data_passes():
    from monte.core.memory import estimate_render_memory

    scene = _scene()
    plain = estimate_render_memory(scene, RenderSettings())
    some = estimate_render_memory(scene, RenderSettings(data_passes=("mist", "crypto_object"), cryptomatte_levels=6))
    assert some.film - plain.film == 256 * (8 + 8 + 32)  # count, mist sum, Cryptomatte pairs
    assert some.result - plain.result == 256 * (4 + 6 * 8)  # Mist, 3 layers of 4 float32
