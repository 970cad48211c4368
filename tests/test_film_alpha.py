"""Film > Transparent, Transparent Glass and holdout in the core renderer against closed forms: a diffuse square
seen by the camera in front of a lit world, where the alpha is the square's coverage and the world adds no
colour; surfaces seen through a Transparent BSDF or smooth glass; the holdout weight as alpha."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.render import render
from monte.core.scene import Camera, Film, Lobe, Material, Mesh, Scene, SceneError, World
from monte.core.settings import RenderSettings

RES = (24, 24)
WORLD = np.array([0.8, 0.6, 0.4])


def _square(name: str, half: float, z: float, material: int) -> Mesh:
    quad = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float64)
    return Mesh(name, quad, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material_index=material)


def _scene(materials: list[Material], meshes: list[Mesh], film: Film | None = None) -> Scene:
    # The camera at the origin looks down -z; a 36 mm sensor with a 36 mm lens sees +-0.5 at distance 1.
    cam = Camera(np.eye(4), resolution=RES, lens=36.0, sensor_width=36.0, sensor_fit="HORIZONTAL")
    return Scene(camera=cam, meshes=meshes, materials=materials, world=World(color=WORLD), film=film or Film())


SETTINGS = RenderSettings(spp=16, max_bounces=4, seed=3, filter_type="box", filter_width=1.0, threads=1)
# The centre 12x12 pixels see the square (half-size 0.25 at distance 1, the frame spans +-0.5).
INSIDE = (slice(7, 17), slice(7, 17))
OUTSIDE = np.ones(RES[::-1], bool)
OUTSIDE[5:19, 5:19] = False


def _diffuse_square_scene(film: Film | None = None, holdout: float = 0.0) -> Scene:
    mat = Material("grey", [Lobe("diffuse", np.full(3, 0.5))], holdout=holdout)
    return _scene([mat], [_square("square", 0.25, -1.0, 0)], film)


def test_opaque_film_keeps_alpha_one_and_the_world():
    result = render(_diffuse_square_scene(), SETTINGS)
    assert (result.color[..., 3] == 1.0).all()
    np.testing.assert_allclose(result.color[OUTSIDE][:, :3], np.broadcast_to(WORLD, (OUTSIDE.sum(), 3)), rtol=1e-5)
    assert not result.stats["features"]["alpha"]


def test_transparent_film_alpha_is_coverage_and_drops_the_world():
    opaque = render(_diffuse_square_scene(), SETTINGS)
    result = render(_diffuse_square_scene(Film(transparent=True)), SETTINGS)
    alpha = result.color[..., 3]
    assert (alpha[OUTSIDE] == 0).all() and (result.color[OUTSIDE][:, :3] == 0).all()
    assert (alpha[INSIDE] == 1).all()
    # The square's own colour is unchanged: the world still lights it (only camera rays lose it).
    np.testing.assert_array_equal(result.color[INSIDE][..., :3], opaque.color[INSIDE][..., :3])
    # Edge pixels: alpha is the covered fraction, so the mean alpha is the square's share of the frame.
    assert alpha.mean() == pytest.approx(0.25, abs=0.01)


def test_holdout_material_is_black_and_transparent_even_on_opaque_film():
    result = render(_diffuse_square_scene(holdout=1.0), SETTINGS)
    assert (result.color[INSIDE] == 0).all()
    assert (result.color[..., 3][OUTSIDE] == 1).all()
    np.testing.assert_allclose(result.color[OUTSIDE][:, :3], np.broadcast_to(WORLD, (OUTSIDE.sum(), 3)), rtol=1e-5)


def test_partial_holdout_weight_is_the_alpha():
    result = render(_diffuse_square_scene(holdout=0.3), SETTINGS)
    np.testing.assert_allclose(result.color[INSIDE][..., 3], 0.7, atol=1e-6)


def test_transparent_bsdf_passes_transparency_and_glass_only_with_transparent_glass():
    """A Transparent BSDF square (refraction, IOR 1) of colour 0.5 in front of the diffuse one: where only the
    world is behind it, alpha = 1 - 0.5 (half the throughput escapes), where the diffuse square is behind it,
    alpha 1. Smooth glass counts as transparent only with Film > Transparent Glass."""
    grey = Material("grey", [Lobe("diffuse", np.full(3, 0.5))])
    clear = Material("clear", [Lobe("refraction", np.full(3, 0.5), roughness=0.0, ior=1.0)])
    glass = Material("glass", [Lobe("glass", np.ones(3), roughness=0.0, ior=1.5)])
    behind = _square("behind", 0.2, -2.0, 0)  # covers the centre +-2.4 pixels seen through the front square
    centre = (slice(11, 13), slice(11, 13))
    ring = np.zeros(RES[::-1], bool)
    ring[8:16, 8:16] = True
    ring[9:15, 9:15] = False
    film = Film(transparent=True)
    result = render(_scene([grey, clear], [behind, _square("front", 0.25, -1.0, 1)], film), SETTINGS)
    np.testing.assert_allclose(result.color[ring][:, 3], 0.5, atol=1e-6)
    np.testing.assert_allclose(result.color[centre][..., 3], 1.0, atol=1e-6)
    # Glass: opaque without Transparent Glass; with it, the escaping part of smooth glass is transparent.
    front = _square("front", 0.25, -1.0, 1)
    opaque = render(_scene([grey, glass], [behind, front], film), SETTINGS)
    assert (opaque.color[ring][:, 3] == 1).all()
    see_through = render(_scene([grey, glass], [behind, front], Film(True, True, 0.1)), SETTINGS)
    # At normal incidence a 1.5 slab reflects about 8% back (not transparent) and passes the rest.
    assert 0.02 < see_through.color[ring][:, 3].mean() < 0.2
    assert see_through.color[ring][:, 3].min() >= 0.0
    # A glass rougher than the threshold (alpha 0.25 > 0.1) stays opaque.
    rough = Material("rough", [Lobe("glass", np.ones(3), roughness=0.5, ior=1.5)])
    kept = render(_scene([grey, rough], [behind, front], Film(True, True, 0.1)), SETTINGS)
    assert (kept.color[ring][:, 3] == 1).all()


def test_bad_film_and_holdout_settings_name_themselves():
    with pytest.raises(SceneError, match=r"film: transparent glass roughness threshold 1.5 outside \[0, 1\]"):
        _diffuse_square_scene(Film(True, True, 1.5)).validate()
    with pytest.raises(SceneError, match=r"material 'grey': holdout weight 2.0 outside \[0, 1\]"):
        _diffuse_square_scene(holdout=2.0).validate()


def test_alpha_reaches_the_exr_and_the_png(tmp_path):
    """The EXR holds the alpha as channel A; the PNG preview becomes RGBA (straight alpha, colour divided by
    alpha), while an opaque image keeps its RGB PNG."""
    import struct
    import zlib

    from monte.core import exr

    result = render(_diffuse_square_scene(Film(transparent=True)), SETTINGS)
    exr.write_exr(tmp_path / "a.exr", exr.image_channels(result.color, result.variance))
    np.testing.assert_array_equal(exr.read_exr(tmp_path / "a.exr")["A"], result.color[..., 3])

    def png_pixels(path):
        data = path.read_bytes()
        width, height, _, colour_type = struct.unpack(">IIBB", data[16:26])
        idat = data.index(b"IDAT")
        size = struct.unpack(">I", data[idat - 4:idat])[0]
        raw = np.frombuffer(zlib.decompress(data[idat + 4:idat + 4 + size]), np.uint8)
        channels = 4 if colour_type == 6 else 3
        return colour_type, raw.reshape(height, width * channels + 1)[:, 1:].reshape(height, width, channels)

    exr.write_png(tmp_path / "a.png", result.color)
    kind, px = png_pixels(tmp_path / "a.png")
    assert kind == 6
    np.testing.assert_array_equal(px[..., 3], (np.clip(result.color[..., 3], 0, 1) * 255 + 0.5).astype(np.uint8))
    inside = result.color[INSIDE]
    np.testing.assert_array_equal(px[INSIDE][..., :3], exr.linear_to_srgb8(inside[..., :3] / inside[..., 3:4]))
    opaque = render(_diffuse_square_scene(), SETTINGS)
    exr.write_png(tmp_path / "b.png", opaque.color)
    assert png_pixels(tmp_path / "b.png")[0] == 2


def test_alpha_of_sample_ranges_merged_equals_one_render():
    """A render split into sample ranges (core.distributed's unit of work) carries the transparency in its film
    sums: merged, colour and alpha equal one render's bit for bit."""
    from monte.core.render import merge_tile_samples, render_samples
    from monte.core.schedule import pass_bounds, tiles

    scene = _diffuse_square_scene(Film(transparent=True))
    settings = SETTINGS.replace(tile_size=16, batch_paths=1024)
    whole = render(scene, settings)
    bounds = pass_bounds(tiles(0, 0, RES[0], RES[1], 16), settings.spp, settings)
    parts = []
    for ti, b in enumerate(bounds):
        for start, end in zip(b[:-1], b[1:]):
            parts += render_samples(scene, settings, {ti: (start, end)})
    assert len(parts) > len(bounds)  # some tile was split
    merged = merge_tile_samples(scene, settings, parts)
    np.testing.assert_array_equal(merged.color, whole.color)
    assert 0 < merged.color[..., 3].mean() < 1
