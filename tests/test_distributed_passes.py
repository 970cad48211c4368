"""Every pass of a render split into sample ranges (core.render.render_samples, on a Dask cluster through
core.distributed) merges into the one-machine render bit for bit: colour and AOVs, the shader AOVs, Cycles' data
passes (Mist, Position, UV, Object / Material Index, Vector) and Cryptomatte (each name's coverage summed pass by
pass in pass order, so its ranking is the same).

The scene makes the sums inexact: a 70 % transparent veil over a moving quad (Cryptomatte coverage 0.3 and 1
per sample where seen, Mist weights from distances, motion vectors), so adding a tile's passes in another order
changes the last bits of the float64 sums (the control below shows it does).
"""

from __future__ import annotations

import random
import sys
from pathlib import Path

import numpy as np
import pytest
from distributed import Client, LocalCluster

from monte.core.data_passes import CRYPTO_NAMES, DATA_PASSES, DataFilm, hash_to_float, name_hash
from monte.core.distributed import plan_units, render_on_cluster
from monte.core.render import merge_data_tables, merge_tile_samples, render, render_samples
from monte.core.scene import Camera, Lobe, Material, Mesh, Mist, Scene, World
from monte.core.schedule import pass_bounds, tiles
from monte.core.settings import RenderSettings
from monte.core.shading.program import OBJECT_PASS_INDEX, identity_object_row

sys.path.insert(0, str(Path(__file__).resolve().parent))
from node_programs import instruction as _inst, program as _program  # noqa: E402

IMAGES = ("color", "variance", "albedo", "normal", "depth", "sample_count")
SIZE = 16  # pixels; 8x8 tiles: 4 tiles of 3 sample passes each at 48 spp (batch 1024 = 16 samples of 64 px)


def _quad(name: str, z: float, x0: float, x1: float, material: int, obj: int) -> Mesh:
    v = np.array([(x0, -2, z), (x1, -2, z), (x1, 2, z), (x0, 2, z)], np.float64)
    uv = np.array([[(0, 0), (1, 0), (1, 1)], [(0, 0), (1, 1), (0, 1)]], np.float32)
    return Mesh(name, v, np.array([(0, 1, 2), (0, 2, 3)]), material, uvs=uv, object_index=obj)


def passes_scene() -> Scene:
    """An orthographic camera at z = 10 looking down -z over [-1, 1]^2: the left half through a veil at z = 7
    (Transparent BSDF 0.7 + diffuse 0.3) onto a quad at z = 4 that moves 0.1 m along x per frame; the quad's
    program writes the colour AOV "tint" and its x to the value AOV "x", the veil's writes red to "tint"."""
    cam = Camera(np.eye(4), (SIZE, SIZE), kind="ORTHO", ortho_scale=2.0)
    cam.matrix_world[2, 3] = 10.0
    moved = cam.matrix_world.copy()
    moved[1, 3] = 0.05
    cam.vector_matrices = np.stack([moved, cam.matrix_world])
    objects = np.stack([identity_object_row(), identity_object_row()])
    objects[0, OBJECT_PASS_INDEX], objects[1, OBJECT_PASS_INDEX] = 3, 7
    floor = _program([[0.25, 0.5, 0.75], [0, 0, 0]],
                     [_inst("aov_output", value=0, aov=0), _inst("geometry", position=1),
                      _inst("aov_output", value=1, aov=1)])
    red = _program([[1.0, 0.0, 0.0]], [_inst("aov_output", value=0, aov=0)], n_lobes=2)
    mats = [Material("veil", [Lobe("refraction", (0.7, 0.7, 0.7), ior=1.0, roughness=0.0),
                              Lobe("diffuse", (0.3, 0.3, 0.3))], pass_index=2, program=red),
            Material("blue", [Lobe("diffuse", (0.2, 0.3, 0.8))], pass_index=9, program=floor)]
    back = _quad("back mesh", 4.0, -2.0, 2.0, 1, 1)
    back.vector_vertices = np.stack([back.vertices + (0.1, 0, 0), back.vertices - (0.1, 0, 0)])
    return Scene(cam, [_quad("veil mesh", 7.0, -2.0, 0.0, 0, 0), back], mats, world=World(color=(0.5, 0.5, 0.5)),
                 objects=objects, object_names=["Veil", "Back"], asset_names=["Group", "Back"],
                 mist=Mist(2.0, 8.0, "LINEAR"), shader_aovs=[("tint", "COLOR"), ("x", "VALUE")])


def passes_settings(**kw) -> RenderSettings:
    base = dict(spp=48, seed=5, threads=1, batch_paths=1024, tile_size=8, data_passes=DATA_PASSES,
                cryptomatte_levels=4)
    base.update(kw)
    return RenderSettings(**base)


@pytest.fixture(scope="module")
def reference():
    return render(passes_scene(), passes_settings())


def assert_every_pass_equal(a, b) -> None:
    for name in IMAGES:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None) and (x is None or np.array_equal(x, y)), name
    assert sorted(a.shader_aovs) == sorted(b.shader_aovs) == ["tint", "x"]
    for name in a.shader_aovs:
        assert np.array_equal(a.shader_aovs[name], b.shader_aovs[name]), name
    assert sorted(a.data_passes) == sorted(b.data_passes)
    for name in a.data_passes:
        assert a.data_passes[name].dtype == np.float32 and np.array_equal(a.data_passes[name], b.data_passes[name]), \
            name
    assert a.cryptomatte == b.cryptomatte


def test_the_scene_has_every_pass_and_several_passes_per_tile(reference):
    """The tests below prove little unless each pass holds something and each tile takes several sample passes."""
    assert pass_bounds(tiles(0, 0, SIZE, SIZE, 8), 48, passes_settings()) == [[0, 16, 32, 48]] * 4
    p = reference.data_passes
    expected = {"Mist", "Position", "UV", "Object Index", "Material Index", "Vector"} | {
        f"{base}{i:02d}" for base in CRYPTO_NAMES.values() for i in range(2)}
    assert set(p) == expected
    left, right = (slice(2, 14), slice(1, 6)), (slice(2, 14), slice(10, 15))
    veil, back = hash_to_float(name_hash("Veil")), hash_to_float(name_hash("Back"))
    crypto = p["CryptoObject00"][left]
    assert np.all(crypto[..., 0] == back) and np.all(crypto[..., 2] == veil)  # ranked: 0.7 behind, then 0.3
    assert np.allclose(crypto[..., 3], 0.3, atol=1e-6) and 0.5 < crypto[..., 1].mean() < 0.9
    # it moves left (0.1 m of the 2 m view: 0.8 px a frame): previous - now reads +0.8 px
    assert np.allclose(p["Vector"][right][..., 0], 0.8, atol=1e-3)
    assert np.allclose(p["Vector"][right][..., 2], 0.8, atol=1e-3)
    assert 0 < p["Mist"][left].min() and np.all(p["Object Index"][right] == 7)
    assert reference.shader_aovs["tint"][right][..., 2].min() == np.float32(0.75)
    assert np.ptp(reference.shader_aovs["x"][right]) > 0.5


@pytest.mark.parametrize("ranges_per_tile", [1, 2, 3])
def test_sample_ranges_merged_in_any_order_equal_one_render_in_every_pass(reference, ranges_per_tile):
    scene, settings = passes_scene(), passes_settings()
    units = plan_units(scene, settings, 2, ranges_per_tile=ranges_per_tile)
    parts = [part for unit in units for part in render_samples(scene, settings, unit)]
    assert len(parts) == 4 * ranges_per_tile
    random.Random(ranges_per_tile).shuffle(parts)
    assert_every_pass_equal(merge_tile_samples(scene, settings, parts), reference)


def test_the_float64_sums_merged_in_pass_order_equal_one_film_and_in_another_order_do_not():
    """Below the float32 images: a tile's data film folded from its first pass's state and its later passes' sums
    in pass order holds exactly the float64 sums (Mist, UV, Vector, Cryptomatte coverage) of the film that took
    all 48 samples itself; folded as (0 + 2) + 1 it does not (the control: the order is what makes it exact; Mist
    and Vector show it here, while this scene's coverage sums are sums of a few constants, 0.3 and 1, which
    happen to round alike in either order)."""
    scene, settings = passes_scene(), passes_settings()
    whole, = render_samples(scene, settings, {0: (0, 48)})
    first, = render_samples(scene, settings, {0: (0, 16)})
    later, = render_samples(scene, settings, {0: (16, 48)})
    assert len(later.data) == 2  # one sum per sample pass
    tables = merge_data_tables(settings, [first])

    def folded(order):
        film = DataFilm(8, 8, tables)
        film.set_state(first.data[0])
        for sums in order:
            film.add_sums(sums)
        return film.state()

    in_order, swapped = folded(later.data), folded(later.data[::-1])
    assert sorted(in_order) == sorted(whole.data[0])
    for name, value in whole.data[0].items():
        assert value.dtype == in_order[name].dtype and np.array_equal(value, in_order[name]), name
    differ = {name for name, value in whole.data[0].items() if not np.array_equal(value, swapped[name])}
    assert {"mist", "vector"} <= differ


def test_sums_without_the_data_passes_are_refused():
    scene = passes_scene()
    parts = render_samples(scene, passes_settings(data_passes=()), {ti: (0, 48) for ti in range(4)})
    with pytest.raises(ValueError, match=r"tile 0: samples from 0 come without the data passes' sums \(0 for 1 "
                                         r"films\)"):
        merge_tile_samples(scene, passes_settings(data_passes=("mist",)), parts)
    with pytest.raises(ValueError, match="the Cryptomatte names of crypto_object, crypto_material, crypto_asset "
                                         "are missing from the film sums"):
        merge_tile_samples(scene, passes_settings(), parts)


def test_every_pass_on_a_local_cluster_equals_one_render(reference):
    """2 worker processes, 3 units per tile submitted shuffled: the merged frame and each tile shown as it comes
    back (on_tile, which the add-on writes into Blender's result) hold the local render's bits in every pass."""
    scene, settings = passes_scene(), passes_settings()
    shown = []
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as lc, \
            Client(lc) as client:
        remote = render_on_cluster(scene, settings, client, units=plan_units(scene, settings, 2, ranges_per_tile=3),
                                   submit_seed=4, on_tile=shown.append)
    assert_every_pass_equal(remote, reference)
    assert remote.stats["units"] == 12 and len(shown) == 4
    for tile in shown:
        rows, cols = slice(tile.y0, tile.y0 + tile.height), slice(tile.x0, tile.x0 + tile.width)
        assert sorted(tile.data_passes) == sorted(reference.data_passes)
        for name, image in tile.data_passes.items():
            assert np.array_equal(image, reference.data_passes[name][rows, cols]), name
