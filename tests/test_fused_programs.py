"""Node programs in the fused path kernel (core.fused_path): a scene whose programs set lobe parameters from the
shading point (Image Texture, Noise, Color Ramp, Object Info, Texture Coordinate, Mix), and one whose programs
set the shading normal (Normal Map in tangent, object and world space: the frame rebuilt, the bump shadowing) are
rendered by one compiled call per batch that evaluates each vertex's program (core.shading.evaluator.run_point,
the body the per-bounce integrator's run_programs loops over) on the same inputs, so their images and first-hit
passes equal the per-bounce integrator's bit for bit; so does one whose Bump nodes read the ray differentials
each path carries (stage 3); programs that need what the kernel does not carry yet (UV Map, Light Path, ...)
keep the per-bounce integrator, with the reason named."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from monte.core.fused_tracer import FUSED_ENV, supports
from monte.core.integrator import PathTracer
from monte.core.precompile import _program, fused_program_scene
from monte.core.render import prepare_scene
from monte.core.sampling import make_sampler
from monte.core.shading import registry as R
from monte.core.shading.program import WIDTH

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fused_compare import (assert_fused_bit_identical_across_thread_counts,  # noqa: E402
                           assert_fused_equals_per_bounce, render_with as _render)


def _tracer(scene, settings):
    ps, accel = prepare_scene(scene, settings)
    return PathTracer(ps, accel, settings, make_sampler(settings.sampler, settings.seed, settings.spp, 4))


def test_the_fused_kernel_evaluates_node_programs_as_the_per_bounce_integrator(fast_settings, monkeypatch):
    scene = fused_program_scene((32, 24))
    settings = fast_settings(spp=8, threads=1)
    monkeypatch.setenv(FUSED_ENV, "1")
    assert supports(_tracer(scene, settings)) is None  # the fused kernel renders this scene
    # same random numbers, same device functions, same program inputs: the same bits (as the constant-material
    # scenes of tests/test_fused_path.py)
    old, new = assert_fused_equals_per_bounce(scene, settings, monkeypatch)
    assert old.color[..., :3].mean() > 0.01  # lit: not two black images
    # the programs ran: the floor's and the balls' albedo vary per pixel (the constant materials' would not), and
    # the two balls (same material, other objects: Object Info Random, Object coordinates) differ
    albedo = new.albedo.reshape(-1, 3)
    hit = np.isfinite(new.depth.reshape(-1))
    assert len(np.unique(albedo[hit].round(4), axis=0)) > 20


def test_without_its_programs_the_scene_renders_another_image(fast_settings, monkeypatch):
    """The comparison above is not one of two renders that ignore the programs: dropping them changes the image."""
    settings = fast_settings(spp=4, threads=1)
    with_programs = _render(fused_program_scene((16, 12)), settings, monkeypatch, fused=True)
    scene = fused_program_scene((16, 12))
    for m in scene.materials:
        m.program = None
    plain = _render(scene, settings, monkeypatch, fused=True)
    assert with_programs.stats["fused_kernel"] and plain.stats["fused_kernel"]
    assert not np.allclose(with_programs.color, plain.color, rtol=1e-2)
    assert not np.allclose(with_programs.albedo, plain.albedo, rtol=1e-2)


def test_node_programs_in_the_fused_kernel_are_bit_identical_across_thread_counts(fast_settings, monkeypatch):
    scene = fused_program_scene((32, 32))  # 8 batches of 1024 paths, traced on one thread or two
    assert_fused_bit_identical_across_thread_counts(scene, fast_settings, monkeypatch)


def test_the_russian_roulette_from_the_camera_hit_on_keeps_the_images_equal(fast_settings, monkeypatch):
    """rr_depth 0: the roulette runs at every vertex (at the camera hit it keeps every path, whose throughput is
    1: the albedo pass, written there from the program-shaded lobes, is never cut short)."""
    scene = fused_program_scene((16, 12))
    settings = fast_settings(spp=4, threads=1, rr_depth=0)
    assert_fused_equals_per_bounce(scene, settings, monkeypatch)


def _inst(opname, **operands):
    spec = R.op(opname)
    row = np.full(WIDTH, -1, np.int32)
    row[0] = spec.code
    for j, (_, kind) in enumerate(spec.operands):
        if kind == "int":
            row[j + 1] = 0
    for name, value in operands.items():
        row[spec.slot(name)] = value
    return row


def _with(program, *rows, registers: int = 0):
    """The program with the instruction rows appended (and registers more constant registers)."""
    program.code = np.concatenate([program.code, np.asarray(rows, np.int32).reshape(-1, WIDTH)])
    if registers:
        program.registers = np.concatenate([program.registers, np.zeros((registers, 3), np.float32)])
    return program


# each edit of the floor's program (registers 0-15, see fused_program_scene; 16+ are added; and of the scene)
# and the reason supports gives
EDITS = {
    "light path": (lambda p, scene: _with(p, _inst("light_path", is_camera=16), registers=1),
                   "node programs reading the light path"),
    "uv map": (lambda p, scene: _with(p, _inst("uv_layer", out=16), registers=1),
               "node programs reading a named UV map"),
    "attribute": (lambda p, scene: _with(p, _inst("attribute", fac=16), registers=1),
                  "node programs reading attributes"),
    "aov output": (lambda p, scene: (_with(p, _inst("aov_output", value=4)),
                                     setattr(scene, "shader_aovs", [("noise", "VALUE")])),
                   "node programs writing shader AOVs"),
    "emission": (lambda p, scene: setattr(p, "emission", 5), "node programs with emission"),
}


# edits the fused kernel evaluates since stage 2 (programs that set the normal, read tangents) and stage 3 (Bump)
FUSED_EDITS = {
    "bump": lambda p: (_with(p, _inst("bump", normal=16, strength=15, distance=15, height=4, height_dx=4,
                                      height_dy=4, filter_width=15), registers=1), setattr(p, "normal", 16)),
    "normal": lambda p: setattr(p, "normal", 2),
    "tangent": lambda p: _with(p, _inst("tangent", out=16), registers=1),
    "normal map": lambda p: (_with(p, _inst("normal_map", normal=16, color=3, strength=15), registers=1),
                             setattr(p, "normal", 16)),
}


@pytest.mark.parametrize("edit", list(FUSED_EDITS))
def test_programs_that_set_the_normal_or_read_tangents_are_fused(edit, fast_settings, monkeypatch):
    scene = fused_program_scene()
    FUSED_EDITS[edit](scene.materials[0].program)
    monkeypatch.setenv(FUSED_ENV, "1")
    tracer = _tracer(scene, fast_settings(spp=2))
    assert supports(tracer) is None
    assert tracer.fused is not None


@pytest.mark.parametrize("edit", list(EDITS))
def test_node_programs_the_fused_kernel_does_not_evaluate_keep_the_per_bounce_integrator(edit, fast_settings,
                                                                                        monkeypatch):
    change, reason = EDITS[edit]
    scene = fused_program_scene()
    change(scene.materials[0].program, scene)
    monkeypatch.setenv(FUSED_ENV, "1")
    tracer = _tracer(scene, fast_settings(spp=2))
    assert supports(tracer) == reason
    assert tracer.fused is None


def normal_mapped_scene(resolution: tuple[int, int] = (32, 24), specular_floor: bool = True):
    """Normal Map nodes in the three spaces on smooth meshes, seen at a grazing 20 degrees (the case of
    tests/test_vector_nodes_cycles.py that exposed the diffuse lobes' normal): a Principled-like floor (glossy
    over diffuse: the specular tilt of the mapped normal is active where the viewer is below it) with a
    tangent-space map leaning ~58 degrees towards +x (its colour varying with the UV u), smooth corner normals
    that differ from the face's (the mesh normal the map reads is their interpolation) and one tangent layer;
    a glossy + diffuse ball (an object) with an object-space map, and a diffuse ball with a world-space one.
    specular_floor False: the floor is diffuse only (no tilt)."""
    from monte.core.builtin_scenes import icosphere, quad
    from monte.core.scene import Camera, Lobe, Material, PointLight, Scene, World
    from monte.core.shading.program import OBJECT_INVERSE, OBJECT_LOCATION, identity_object_row

    grey = np.full(3, 0.7)
    # floor: 0 uv, 1 colour a, 2 colour b, 3 colour, 4 normal, 5 strength 1
    floor = _program([("texture_coordinate", {"uv": 0}), ("mix", {"out": 3, "factor": 0, "a": 1, "b": 2}),
                      ("normal_map", {"normal": 4, "color": 3, "strength": 5, "space": 0, "layer": 0})],
                     [0.0, (0.92, 0.5, 0.76), (0.3, 0.62, 0.9), 0.0, 0.0, 1.0], 2 if specular_floor else 1, {})
    floor.normal = 4
    ball = _program([("normal_map", {"normal": 1, "color": 0, "strength": 2, "space": 1})],
                    [(0.75, 0.4, 0.8), 0.0, 1.0], 2, {})
    ball.normal = 1
    matte = _program([("normal_map", {"normal": 1, "color": 0, "strength": 2, "space": 2})],
                     [(0.3, 0.7, 0.85), 0.0, 0.8], 1, {})
    matte.normal = 1
    floor_lobes = ([Lobe("glossy", np.ones(3), roughness=0.5, fresnel="generalized_schlick", f0=np.full(3, 0.04)),
                    Lobe("diffuse", grey, under=0)] if specular_floor else [Lobe("diffuse", grey)])
    materials = [Material("floor", floor_lobes, program=floor),
                 Material("ball", [Lobe("glossy", np.ones(3), roughness=0.3, fresnel="dielectric"),
                                   Lobe("diffuse", grey)], program=ball),
                 Material("matte", [Lobe("diffuse", grey)], program=matte)]
    s = 6.0
    ground = quad("ground", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], 0)
    ground.uvs = np.array([[(0, 0), (1, 0), (1, 1)], [(0, 0), (1, 1), (0, 1)]], np.float64)
    corner = np.array([(0.15, 0.0, 1.0), (0.0, 0.1, 1.0), (-0.1, 0.05, 1.0), (0.05, -0.1, 1.0)])
    corner /= np.linalg.norm(corner, axis=1)[:, None]
    ground.normals = corner[[[0, 1, 2], [0, 2, 3]]]
    ground.tangent_layers = {"": np.tile(np.array([1.0, 0.0, 0.0, 1.0]), (2, 3, 1))}
    meshes = [ground, icosphere("ball", (0.8, -0.6, 0.5), 0.5, 1), icosphere("matte", (1.2, 0.9, 0.4), 0.4, 2)]
    row = identity_object_row()  # the ball, turned 90 degrees about z: its object space is not the world's
    row[OBJECT_INVERSE:OBJECT_INVERSE + 12] = [0, 1, 0, 0.6, -1, 0, 0, 0.8, 0, 0, 1, -0.5]
    row[OBJECT_LOCATION:OBJECT_LOCATION + 3] = (0.8, -0.6, 0.5)
    meshes[1].object_index = 0
    camera = Camera.look_at((-5.0, 0.0, 1.8), (0.0, 0.0, 0.0), horizontal_fov=math.radians(40.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=meshes, materials=materials, tangent_layer_names=[""],
                 lights=[PointLight("point", np.array((0.5, -1.0, 3.0)), np.full(3, 60.0))],
                 world=World(np.array((0.05, 0.05, 0.05))), name="fused-normal-maps",
                 objects=np.asarray([row], np.float32))


@pytest.mark.parametrize("specular_floor", [True, False])
def test_normal_mapped_programs_render_in_the_fused_kernel_as_per_bounce(specular_floor, fast_settings,
                                                                         monkeypatch):
    """The frame rebuilt around the mapped normal (core.geometry_kernels.reframe_point, the specular tilt where
    the material has glossy lobes), the diffuse lobes' untilted normal, the tangents and mesh normal the map
    reads, and the bump shadowing of light samples and BSDF samples: the same bits as the per-bounce integrator."""
    scene = normal_mapped_scene(specular_floor=specular_floor)
    settings = fast_settings(spp=8, threads=1)
    monkeypatch.setenv(FUSED_ENV, "1")
    tracer = _tracer(scene, settings)
    assert supports(tracer) is None
    assert tracer.ps.specular[0] == specular_floor
    old, new = assert_fused_equals_per_bounce(scene, settings, monkeypatch)
    assert old.color[..., :3].mean() > 0.01
    # the maps matter: without them (the smooth normals) the fused image is another one
    plain = normal_mapped_scene(specular_floor=specular_floor)
    for m in plain.materials:
        m.program.normal = -1
    flat = _render(plain, settings, monkeypatch, fused=True)
    assert flat.stats["fused_kernel"]
    assert not np.allclose(flat.color, new.color, rtol=1e-2)


def test_normal_mapped_programs_in_the_fused_kernel_are_bit_identical_across_thread_counts(fast_settings,
                                                                                          monkeypatch):
    scene = normal_mapped_scene((32, 32))
    assert_fused_bit_identical_across_thread_counts(scene, fast_settings, monkeypatch)


def bump_mapped_scene(resolution: tuple[int, int] = (32, 24)):
    """Bump nodes (stage 3: ray differentials): a smooth Principled-like ball (glossy over diffuse) whose normal a
    Bump of Noise heights sets (the Noise of the Object coordinates at the point and shifted along dP.dx / dP.dy by
    the filter width: the Height subgraph's bump copies), a UV-mapped floor with those bumps chained into an
    inverted Bump of Image Texture heights (the image read at the UV map shifted by the bump offsets: duv), and a
    grey ball without a program."""
    from monte.core.builtin_scenes import icosphere, quad
    from monte.core.scene import Camera, Lobe, Material, PointLight, Scene, Texture, World
    from monte.core.shading.procedural import pack_flags
    from monte.core.shading.program import BIND_ROUGHNESS

    grey = np.full(3, 0.6)
    # registers: 0-2 object coordinates at P, P + w dP.dx, P + w dP.dy; 3-5 their noise; 6 the bumped normal;
    # 7-9 the image at the UV map and shifted; 10 the chained normal; 11 strength 0.8, 12 distance 0.3,
    # 13 filter width 0.5, 14 scale 4, 15 detail 2, 16 roughness 0.5, 17 lacunarity 2, 18 0, 19 1, 20 distance 0.05
    noise = {"w": 18, "scale": 14, "detail": 15, "roughness": 16, "lacunarity": 17, "offset": 18, "gain": 19,
             "distortion": 18, "flags": pack_flags(3, 0, 1)}
    code = [("texture_coordinate", {"object": 0}),
            ("texture_coordinate", {"object": 1, "bump": 1, "bump_width": 13}),
            ("texture_coordinate", {"object": 2, "bump": 2, "bump_width": 13}),
            ("tex_noise", {**noise, "fac": 3, "vector": 0}),
            ("tex_noise", {**noise, "fac": 4, "vector": 1}),
            ("tex_noise", {**noise, "fac": 5, "vector": 2}),
            ("bump", {"normal": 6, "strength": 11, "distance": 12, "height": 3, "height_dx": 4, "height_dy": 5,
                      "filter_width": 13})]
    chained = code + [("image", {"color": 7, "texture": 0}),
                      ("image", {"color": 8, "texture": 0, "bump": 1, "bump_width": 13}),
                      ("image", {"color": 9, "texture": 0, "bump": 2, "bump_width": 13}),
                      ("bump", {"normal": 10, "strength": 19, "distance": 20, "height": 7, "height_dx": 8,
                                "height_dy": 9, "filter_width": 13, "normal_in": 6, "invert": 1})]
    regs = [0.0] * 11 + [0.8, 0.3, 0.5, 4.0, 2.0, 0.5, 2.0, 0.0, 1.0, 0.05]
    ball = _program(code, regs, 2, {(0, BIND_ROUGHNESS): 3})
    ball.normal = 6
    floor = _program(chained, regs, 2, {})
    floor.normal = 10
    materials = [
        Material("floor", [Lobe("glossy", np.ones(3), roughness=0.4, fresnel="generalized_schlick",
                                f0=np.full(3, 0.04)), Lobe("diffuse", grey, under=0)], program=floor),
        Material("ball", [Lobe("glossy", np.ones(3), roughness=0.3, fresnel="dielectric"),
                          Lobe("diffuse", np.array((0.8, 0.3, 0.2)))], program=ball),
        Material("grey", [Lobe("diffuse", grey)]),
    ]
    ground = quad("ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], 0)
    ground.uvs = np.array([[(0, 0), (8, 0), (8, 8)], [(0, 0), (8, 8), (0, 8)]], np.float64)
    meshes = [ground, icosphere("ball", (-0.4, 0.0, 0.6), 0.6, 1), icosphere("plain", (0.9, 0.6, 0.35), 0.35, 2)]
    texels = np.random.default_rng(5).uniform(0.0, 1.0, (8, 8, 3)).astype(np.float32)
    camera = Camera.look_at((0.0, -4.0, 1.8), (0.0, 0.0, 0.4), horizontal_fov=math.radians(50.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=meshes, materials=materials,
                 lights=[PointLight("point", np.array((1.0, -1.5, 3.0)), np.full(3, 40.0))],
                 world=World(np.array((0.1, 0.12, 0.15))), textures=[Texture("heights", texels)], name="fused-bumps")


def test_bump_mapped_programs_render_in_the_fused_kernel_as_per_bounce(fast_settings, monkeypatch):
    """Stage 3: each path carries its ray differential (footprint and spread, float32, as the per-bounce
    integrator), each vertex spreads it along the surface (core.geometry_kernels.differentials_point, the function
    the per-bounce vector_context calls) into dP and the UV map's duv, which the Bump nodes and their shifted
    Height inputs (Texture Coordinate, Image Texture) read: the same bits as the per-bounce integrator, chained and
    inverted bumps included, with the bump shadowing of the normal they set."""
    scene = bump_mapped_scene()
    settings = fast_settings(spp=8, threads=1)
    monkeypatch.setenv(FUSED_ENV, "1")
    tracer = _tracer(scene, settings)
    assert supports(tracer) is None
    assert tracer.ps.shading.needs_differentials
    assert list(tracer.fused.needs_differentials) == [True, True, False]
    old, new = assert_fused_equals_per_bounce(scene, settings, monkeypatch)
    assert old.color[..., :3].mean() > 0.01
    # the bumps matter: without the normal they set the image is another one
    plain = bump_mapped_scene()
    for m in plain.materials[:2]:
        m.program.normal = -1
    flat = _render(plain, settings, monkeypatch, fused=True)
    assert flat.stats["fused_kernel"]
    assert not np.allclose(flat.color, new.color, rtol=1e-2)


def test_the_fused_kernel_reads_the_ray_differentials(fast_settings, monkeypatch):
    """The differentials reach the Bump nodes: with the camera rays' differentials zero (every footprint zero: no
    height difference, the Bump keeps the normal) the image changes, in both integrators alike; with them twice
    as wide (the shifted heights further apart) it changes too."""
    from monte.core import render as render_mod

    scene = bump_mapped_scene((24, 16))
    settings = fast_settings(spp=4, threads=1)
    real = _render(scene, settings, monkeypatch, fused=True)
    original = render_mod.camera_differentials
    # the differentials computed for every ray up front, as other cameras' are (not deferred: scaled below)
    monkeypatch.setattr(render_mod, "pinhole_params", lambda camera: None)

    def scaled(factor):
        def differentials(*args, **kwargs):
            dp, dd = original(*args, **kwargs)
            return dp * np.float32(factor), dd * np.float32(factor)
        return differentials

    out = {}
    for factor in (0.0, 2.0):
        monkeypatch.setattr(render_mod, "camera_differentials", scaled(factor))
        fused = _render(scene, settings, monkeypatch, fused=True)
        per_bounce = _render(scene, settings, monkeypatch, fused=False)
        assert fused.stats["fused_kernel"] and not per_bounce.stats["fused_kernel"]
        assert np.array_equal(fused.color, per_bounce.color), factor
        assert not np.allclose(fused.color, real.color, rtol=1e-3), factor
        out[factor] = fused.color
    assert not np.allclose(out[0.0], out[2.0], rtol=1e-3)


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_a_pinhole_cameras_differentials_computed_where_a_path_reads_them_are_the_same_bits(kind, fast_settings,
                                                                                          monkeypatch):
    """A still pinhole camera's rays are made per path by the fused kernel (core.camera.PinholeRays), and their
    differentials only when the path reaches a material with a Bump node, from its camera ray, carried over the
    hit distances so far (paths that meet the bump-free third material first, then a bumped one). The image and
    the first-hit passes are those of camera rays and differentials made for every ray before the kernel ran
    (compiled or in NumPy)."""
    from monte.core import render as render_mod
    from monte.core.camera import PinholeRays

    scene = bump_mapped_scene((24, 16))
    if kind == "ORTHO":
        scene.camera.kind, scene.camera.ortho_scale = "ORTHO", 5.0
    settings = fast_settings(spp=8, threads=1, max_bounces=6)
    made = []
    real_init = PinholeRays.__init__

    def counted(self, *args):
        made.append(1)
        real_init(self, *args)

    monkeypatch.setattr(PinholeRays, "__init__", counted)
    original = render_mod.camera_differentials

    def refused(*args, **kwargs):
        raise AssertionError("a pinhole camera's differentials were computed up front")

    monkeypatch.setattr(render_mod, "camera_differentials", refused)
    deferred = _render(scene, settings, monkeypatch, fused=True)
    assert deferred.stats["fused_kernel"] and made
    monkeypatch.setattr(render_mod, "pinhole_params", lambda camera: None)
    for compiled in (True, False):
        monkeypatch.setattr(render_mod, "camera_differentials",
                            lambda *a, _c=compiled, **k: original(*a, **{**k, "compiled": _c and k["compiled"]}))
        up_front = _render(scene, settings, monkeypatch, fused=True)
        assert up_front.stats["fused_kernel"]
        for name in ("color", "variance", "albedo", "normal", "depth"):
            assert np.array_equal(getattr(deferred, name), getattr(up_front, name)), (compiled, name)
    assert deferred.color[..., :3].mean() > 0.01


def test_bump_mapped_programs_in_the_fused_kernel_are_bit_identical_across_thread_counts(fast_settings,
                                                                                        monkeypatch):
    scene = bump_mapped_scene((32, 32))
    assert_fused_bit_identical_across_thread_counts(scene, fast_settings, monkeypatch)


@pytest.mark.parametrize("kind", ["ORTHO", "PANO", "LENS"])
def test_bump_mapped_programs_through_other_cameras_render_fused_as_per_bounce(kind, fast_settings, monkeypatch):
    """The kernel takes whatever differentials the camera rays carry (an orthographic camera's: a constant
    footprint, no spread; a panoramic camera's and a thin lens's (depth of field), computed in NumPy, the
    panoramic one with dead rays): the same image as the per-bounce integrator."""
    scene = bump_mapped_scene((24, 16))
    if kind == "LENS":
        scene.camera.use_dof, scene.camera.aperture_fstop, scene.camera.focus_distance = True, 0.5, 4.0
    else:
        scene.camera.kind = kind
    if kind == "ORTHO":
        scene.camera.ortho_scale = 5.0
    elif kind == "PANO":
        scene.camera.panorama_type = "FISHEYE_EQUIDISTANT"
    settings = fast_settings(spp=4, threads=1)
    old, _ = assert_fused_equals_per_bounce(scene, settings, monkeypatch)
    assert old.color[..., :3].mean() > 0.005
