"""Film > Transparent, holdout and panoramic cameras against real Cycles (bpy ships it): the same Blender scene
rendered by both engines, colour and alpha compared by their means and per-pixel z-scores (core.compare).

Cycles' per-pixel variance comes from K renders with different seeds (core.compare.runs_mean_and_variance),
Monte's from its film. Small images (32x32 or 48x32) at sample counts where a 1 % difference of the means is
several sigma. The default suite runs transparent film, object holdout and a fisheye with depth of field
(about 25 s); the rest (holdout by
shader and collection, transparent glass, every panorama type, every ray visibility flag, Cast Shadow) is
`@pytest.mark.slow` (about 30 s on 2 cores with compiled kernels cached):
`.venv/bin/python -m pytest -m slow tests/test_film_camera_cycles.py`.
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

from monte.addon import crosscheck as cc  # noqa: E402
from monte.addon.engine import render_with_operator  # noqa: E402
from monte.core import compare as cmp  # noqa: E402

pytestmark = [pytest.mark.blender]

CYCLES_RUNS = 4


def monte_rgba(scene, spp: int, bounces: int) -> tuple[np.ndarray, np.ndarray]:
    """Monte's (RGBA (H, W, 4), variance of RGB (H, W, 3)) through Blender's render operator."""
    scene.render.engine = "MONTE"
    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = spp, bounces, 1, 2
    scene.view_layers[0].monte.use_pass_variance = True  # the comparison reads Monte's error estimate
    result = render_with_operator(scene)[0][1]
    return np.asarray(result.color, np.float64), np.asarray(result.variance, np.float64)


def cycles_rgba(scene, tmp_path, spp: int, bounces: int) -> tuple[np.ndarray, np.ndarray]:
    """Cycles' mean RGBA over CYCLES_RUNS seeds (H, W, 4) and the per-pixel variance of that mean (H, W, 4)."""
    runs = []
    layer = scene.view_layers[0].name
    for seed in range(1, CYCLES_RUNS + 1):
        cc.configure_cycles(scene, spp, bounces, threads=2, seed=seed)
        render_with_operator(scene)
        ch = bf.save_render_exr(scene, tmp_path / f"cycles{seed}.exr")
        runs.append(np.stack([ch[f"{layer}.Combined.{c}"] for c in "RGBA"], axis=-1))
    return cmp.runs_mean_and_variance(np.stack(runs))


def alpha_variance(alpha: np.ndarray, spp: int) -> np.ndarray:
    """Variance of a pixel's mean transparency from its samples, each 0 or 1 (a binomial; exact where a pixel
    is fully covered or uncovered, where it is 0)."""
    return alpha * (1.0 - alpha) / spp


def check(name: str, mon: np.ndarray, mon_var: np.ndarray, cyc: np.ndarray, cyc_var: np.ndarray, spp: int,
          rel: float = 0.01) -> None:
    """Colour (RGB) and alpha (as a grey image) agree: channel means within max(4 sigma, rel) of Cycles' (capped
    at rel as core.compare does) and at most 1 % of pixels beyond 5 sigma."""
    colour = cmp.compare(mon[..., :3], mon_var, cyc[..., :3], cyc_var[..., :3], rel_cap=rel)
    a_m, a_c = np.repeat(mon[..., 3:4], 3, axis=2), np.repeat(cyc[..., 3:4], 3, axis=2)
    alpha = cmp.compare(a_m, np.repeat(alpha_variance(mon[..., 3], spp)[..., None], 3, axis=2),
                        a_c, np.repeat(cyc_var[..., 3:4], 3, axis=2), rel_cap=rel)
    for what, c in (("colour", colour), ("alpha", alpha)):
        ok, reasons = c.verdict()
        print(f"\n{name} {what}: Monte {np.round(c.mean_a, 4)} Cycles {np.round(c.mean_b, 4)} "
              f"rel {np.round(100 * c.relative_difference, 2)} % z {c.z_stats()}")
        assert ok, f"{name} {what}: {reasons}"


def ball_on_floor(make_material, size=(32, 32), world: float = 1.0):
    """A ball (material from make_material()) on a grey floor that ends inside the frame, under a uniform
    world: the world shows around the floor, the floor shows the ball's shadow and bounce light."""
    scene = bf.reset()
    s = 1.6
    bf.mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                   bf.diffuse("floor", (0.6, 0.6, 0.6)))
    bf.icosphere_object("ball", (0, 0, 0.7), 0.7, make_material(), subdivisions=3)
    bf.camera_object(scene, (0, -5.5, 3.0), (math.radians(62), 0, 0), lens=40.0)
    bf.set_world(scene, (world, world, world), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    return scene


def _diffuse_ball():
    return bf.diffuse("ball", (0.8, 0.3, 0.2))


def _holdout_ball():
    mat = bpy.data.materials.new("holdout")
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    hold = tree.nodes.new("ShaderNodeHoldout")
    tree.links.new(hold.outputs[0], out.inputs["Surface"])
    return mat


SPP, BOUNCES = 64, 4


def test_transparent_film_matches_cycles(tmp_path):
    scene = ball_on_floor(_diffuse_ball)
    scene.render.film_transparent = True
    mon, mon_var = monte_rgba(scene, SPP, BOUNCES)
    # Blender's render result holds the alpha (saved as an EXR, row 0 at the top as Monte's).
    saved = bf.save_render_exr(scene, tmp_path / "monte.exr")
    np.testing.assert_allclose(saved[f"{scene.view_layers[0].name}.Combined.A"], mon[..., 3], atol=1e-6)
    cyc, cyc_var = cycles_rgba(scene, tmp_path, SPP // 2, BOUNCES)
    assert mon[..., 3].min() == 0.0 and mon[..., 3].max() == 1.0  # both the world and the floor are seen
    check("transparent film", mon, mon_var, cyc, cyc_var, SPP)


@pytest.mark.parametrize("how", [pytest.param("shader", marks=pytest.mark.slow), "object",
                                 pytest.param("collection", marks=pytest.mark.slow)])
def test_holdout_matches_cycles(how, tmp_path):
    scene = ball_on_floor(_holdout_ball if how == "shader" else _diffuse_ball)
    ball = bpy.data.objects["ball"]
    if how == "object":
        ball.is_holdout = True
    elif how == "collection":
        coll = bpy.data.collections.new("held")
        scene.collection.children.link(coll)
        scene.collection.objects.unlink(ball)
        coll.objects.link(ball)
        scene.view_layers[0].layer_collection.children["held"].holdout = True
    mon, mon_var = monte_rgba(scene, SPP, BOUNCES)
    cyc, cyc_var = cycles_rgba(scene, tmp_path, SPP // 2, BOUNCES)
    assert mon[..., 3].min() == 0.0  # the ball is cut out
    check(f"holdout ({how})", mon, mon_var, cyc, cyc_var, SPP)


@pytest.mark.slow
def test_transparent_glass_matches_cycles(tmp_path):
    def glass():
        mat = bpy.data.materials.new("glass")
        mat.use_nodes = True
        tree = mat.node_tree
        tree.nodes.clear()
        out = tree.nodes.new("ShaderNodeOutputMaterial")
        node = tree.nodes.new("ShaderNodeBsdfGlass")
        node.inputs["Roughness"].default_value = 0.0
        tree.links.new(node.outputs[0], out.inputs["Surface"])
        return mat

    scene = ball_on_floor(glass)
    scene.render.film_transparent = True
    scene.cycles.film_transparent_glass = True
    scene.cycles.film_transparent_roughness = 0.1
    mon, mon_var = monte_rgba(scene, SPP, 8)
    cyc, cyc_var = cycles_rgba(scene, tmp_path, SPP // 2, 8)
    check("transparent glass", mon, mon_var, cyc, cyc_var, SPP)


PANORAMAS = {
    "equirectangular": dict(panorama_type="EQUIRECTANGULAR"),
    "equirectangular-range": dict(panorama_type="EQUIRECTANGULAR", latitude_min=-0.3, latitude_max=1.1,
                                  longitude_min=-1.9, longitude_max=0.6),
    "fisheye-equidistant": dict(panorama_type="FISHEYE_EQUIDISTANT", fisheye_fov=math.radians(160)),
    "fisheye-equisolid": dict(panorama_type="FISHEYE_EQUISOLID", fisheye_lens=8.0, fisheye_fov=math.radians(170)),
    "mirrorball": dict(panorama_type="MIRRORBALL"),
    # Blender's default polynomial (a 10.5 mm-like lens) on its 36 mm sensor, and a steeper one.
    "fisheye-lens-polynomial": dict(panorama_type="FISHEYE_LENS_POLYNOMIAL", fisheye_fov=math.radians(170)),
    "fisheye-lens-polynomial-steep": dict(panorama_type="FISHEYE_LENS_POLYNOMIAL", fisheye_fov=math.radians(120),
                                          fisheye_polynomial_k1=-0.05, fisheye_polynomial_k2=0.0003),
    "central-cylindrical": dict(panorama_type="CENTRAL_CYLINDRICAL", central_cylindrical_range_u_min=-2.2,
                                central_cylindrical_range_u_max=0.9, central_cylindrical_range_v_min=-0.6,
                                central_cylindrical_range_v_max=1.4, central_cylindrical_radius=1.3),
}


def panorama_room():
    """Inside a box with differently coloured walls (and a white ceiling lit by a point light) so that every
    direction a panorama looks has its own colour: a wrong direction shows as a wrong colour."""
    scene = bf.reset()
    s = 2.0
    walls = {"north": ((-s, s, -s), (s, s, -s), (s, s, s), (-s, s, s), (0.8, 0.2, 0.2)),
             "south": ((s, -s, -s), (-s, -s, -s), (-s, -s, s), (s, -s, s), (0.2, 0.8, 0.2)),
             "east": ((s, s, -s), (s, -s, -s), (s, -s, s), (s, s, s), (0.2, 0.2, 0.8)),
             "west": ((-s, -s, -s), (-s, s, -s), (-s, s, s), (-s, -s, s), (0.8, 0.8, 0.2)),
             "floor": ((-s, -s, -s), (s, -s, -s), (s, s, -s), (-s, s, -s), (0.5, 0.5, 0.5)),
             "ceiling": ((-s, s, s), (s, s, s), (s, -s, s), (-s, -s, s), (0.9, 0.9, 0.9))}
    for name, (a, b, c, d, colour) in walls.items():
        bf.mesh_object(name, [a, b, c, d], [(0, 1, 2, 3)], bf.diffuse(name, colour))
    bf.icosphere_object("ball", (0.8, 1.0, -0.6), 0.5, bf.diffuse("ball", (0.9, 0.5, 0.1)), subdivisions=2)
    bf.add_light(scene, "POINT", (0.3, -0.4, 1.2), energy=300.0, shadow_soft_size=0.2)
    bf.set_world(scene, (0, 0, 0), 1.0)
    return scene


@pytest.mark.slow
@pytest.mark.parametrize("name", list(PANORAMAS))
def test_panoramic_cameras_match_cycles(name, tmp_path):
    scene = panorama_room()
    bf.camera_object(scene, (0.2, -0.3, 0.1), (math.radians(80), 0, math.radians(20)), kind="PANO",
                     **PANORAMAS[name])
    scene.render.resolution_x, scene.render.resolution_y = 48, 32
    scene.render.resolution_percentage = 100
    spp = 32
    mon, mon_var = monte_rgba(scene, spp, 2)
    cyc, cyc_var = cycles_rgba(scene, tmp_path, spp // 2, 2)
    check(f"panorama {name}", mon, mon_var, cyc, cyc_var, spp)


def test_panoramic_depth_of_field_matches_cycles(tmp_path):
    """A fisheye with depth of field (a wide aperture focused 1 m away, the walls 1.5-2.5 m off: blurred) against
    Cycles. The control: the same camera without depth of field (the pinhole, sharp) must disagree."""
    scene = panorama_room()
    cam = bf.camera_object(scene, (0.2, -0.3, 0.1), (math.radians(80), 0, math.radians(20)), kind="PANO",
                           **PANORAMAS["fisheye-equidistant"])
    cam.data.dof.use_dof = True
    cam.data.dof.aperture_fstop = 0.1  # radius 50 mm / (2 x 0.1) = 0.25 m
    cam.data.dof.focus_distance = 1.0
    scene.render.resolution_x, scene.render.resolution_y = 48, 32
    scene.render.resolution_percentage = 100
    # 256 spp: the blur changes the room's few edges, not its means, so the control below needs the noise well
    # under that difference (at 64 spp the sharp image failed to disagree under some sampling patterns: 0.3 %
    # of pixels beyond 5 sigma, against 2 % here; the blurred one none).
    spp = 256
    mon, mon_var = monte_rgba(scene, spp, 2)
    cyc, cyc_var = cycles_rgba(scene, tmp_path, spp // 2, 2)
    check("panorama depth of field", mon, mon_var, cyc, cyc_var, spp)
    cam.data.dof.use_dof = False
    sharp, sharp_var = monte_rgba(scene, spp, 2)
    assert not cmp.compare(sharp[..., :3], sharp_var, cyc[..., :3], cyc_var[..., :3], rel_cap=0.01).verdict()[0]


VISIBILITY = {
    "object-camera-off": lambda scene: setattr(bpy.data.objects["ball"], "visible_camera", False),
    "collection-indirect-only": lambda scene: _collection_of_ball(scene, "indirect_only"),
    "object-shadow-off": lambda scene: setattr(bpy.data.objects["ball"], "visible_shadow", False),
    "light-camera-on": lambda scene: setattr(bpy.data.objects["lamp"], "visible_camera", True),
    "light-cast-shadow-off": lambda scene: setattr(bpy.data.objects["lamp"].data, "use_shadow", False),
    "object-diffuse-off": lambda scene: setattr(bpy.data.objects["ball"], "visible_diffuse", False),
    "object-glossy-off": lambda scene: (_glossy_floor(), setattr(bpy.data.objects["ball"], "visible_glossy", False)),
    "object-transmission-off": lambda scene: (_glass_pane(scene),
                                              setattr(bpy.data.objects["ball"], "visible_transmission", False)),
}


def _collection_of_ball(scene, flag: str) -> None:
    coll = bpy.data.collections.new(flag)
    scene.collection.children.link(coll)
    ball = bpy.data.objects["ball"]
    scene.collection.objects.unlink(ball)
    coll.objects.link(ball)
    setattr(scene.view_layers[0].layer_collection.children[flag], flag, True)


def _glossy_floor():
    """The floor half glossy (a mix of Diffuse and Glossy BSDFs): it reflects the ball by glossy rays."""
    floor = bpy.data.objects["floor"]
    mat = floor.material_slots[0].material
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    diffuse = out.inputs["Surface"].links[0].from_node
    glossy = tree.nodes.new("ShaderNodeBsdfGlossy")
    glossy.inputs["Roughness"].default_value = 0.2
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.5
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(glossy.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])


def _glass_pane(scene):
    """A smooth refracting pane between the camera and the ball: the ball is seen through it by transmission rays
    (refraction only: a reflecting pane would mirror the lamp onto the floor, caustics too noisy to compare; the
    lamp turned to face down, so that the pane does not show its bright face)."""
    bpy.data.objects["lamp"].rotation_euler = (0.0, 0.0, 0.0)
    mat = bpy.data.materials.new("pane")
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    node = tree.nodes.new("ShaderNodeBsdfRefraction")
    node.inputs["Roughness"].default_value = 0.0
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    bf.mesh_object("pane", [(-1.2, -1.6, 0.0), (1.2, -1.6, 0.0), (1.2, -1.6, 1.6), (-1.2, -1.6, 1.6)],
                   [(0, 1, 2, 3)], mat)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(VISIBILITY))
def test_ray_visibility_matches_cycles(name, tmp_path):
    """Object > Visibility > Ray Visibility: a ball hidden from camera rays (its shadow and bounce light stay), or
    from shadow rays (seen, casting no shadow); an area light in view made visible to the camera; the light's
    Cast Shadow off (its light samples pass the ball; BSDF rays towards it are still blocked)."""
    scene = ball_on_floor(_diffuse_ball, world=0.2)
    # Tilted towards the camera, so that its emitting side is in view.
    bf.add_light(scene, "AREA", (0.6, -0.2, 2.2), (-1.0, 0.1, 0), name="lamp", energy=150.0, shape="SQUARE",
                 size=0.8)
    before, _ = monte_rgba(scene, SPP, BOUNCES)
    VISIBILITY[name](scene)
    mon, mon_var = monte_rgba(scene, SPP, BOUNCES)
    changed = np.abs(mon - before)[..., :3].max(axis=2) > 0.03
    assert changed.mean() > 0.01, "the setting must change the image for this test to see anything"
    cyc, cyc_var = cycles_rgba(scene, tmp_path, SPP // 2, BOUNCES)
    check(f"visibility {name}", mon, mon_var, cyc, cyc_var, SPP)
