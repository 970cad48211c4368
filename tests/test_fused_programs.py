"""Node programs in the fused path kernel (core.fused_path, stage 1): a scene whose programs set lobe parameters
from the shading point (Image Texture, Noise, Color Ramp, Object Info, Texture Coordinate, Mix) is rendered by
one compiled call per batch that evaluates each vertex's program (core.shading.evaluator.run_point, the body the
per-bounce integrator's run_programs loops over) on the same inputs, so its image and first-hit passes equal the
per-bounce integrator's bit for bit; programs that need what the kernel does not carry yet keep the per-bounce
integrator, with the reason named."""

import numpy as np
import pytest

from monte.core.fused_tracer import FUSED_ENV, supports
from monte.core.integrator import PathTracer
from monte.core.precompile import fused_program_scene
from monte.core.render import prepare_scene, render
from monte.core.sampling import make_sampler
from monte.core.shading import registry as R
from monte.core.shading.program import WIDTH


def _tracer(scene, settings):
    ps, accel = prepare_scene(scene, settings)
    return PathTracer(ps, accel, settings, make_sampler(settings.sampler, settings.seed, settings.spp, 4))


def _render(scene, settings, monkeypatch, fused: bool):
    monkeypatch.setenv(FUSED_ENV, "1" if fused else "0")
    return render(scene, settings)


def test_the_fused_kernel_evaluates_node_programs_as_the_per_bounce_integrator(fast_settings, monkeypatch):
    scene = fused_program_scene((32, 24))
    settings = fast_settings(spp=8, threads=1)
    monkeypatch.setenv(FUSED_ENV, "1")
    assert supports(_tracer(scene, settings)) is None  # the fused kernel renders this scene
    old = _render(scene, settings, monkeypatch, fused=False)
    new = _render(scene, settings, monkeypatch, fused=True)
    assert new.stats["fused_kernel"] and not old.stats["fused_kernel"]
    # same random numbers, same device functions, same program inputs: the same bits (as the constant-material
    # scenes of tests/test_fused_path.py)
    assert np.array_equal(new.color, old.color)
    assert np.array_equal(new.variance, old.variance)
    for aov in ("albedo", "normal", "depth"):
        assert np.array_equal(getattr(new, aov), getattr(old, aov)), aov
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
    one = _render(scene, fast_settings(spp=8, threads=1, batch_paths=1024), monkeypatch, fused=True)
    two = _render(scene, fast_settings(spp=8, threads=2, batch_paths=1024), monkeypatch, fused=True)
    assert one.stats["fused_kernel"]
    assert np.array_equal(one.color, two.color)
    assert np.array_equal(one.variance, two.variance)
    assert np.array_equal(one.albedo, two.albedo)


def test_the_russian_roulette_from_the_camera_hit_on_keeps_the_images_equal(fast_settings, monkeypatch):
    """rr_depth 0: the roulette runs at every vertex (at the camera hit it keeps every path, whose throughput is
    1: the albedo pass, written there from the program-shaded lobes, is never cut short)."""
    scene = fused_program_scene((16, 12))
    settings = fast_settings(spp=4, threads=1, rr_depth=0)
    old = _render(scene, settings, monkeypatch, fused=False)
    new = _render(scene, settings, monkeypatch, fused=True)
    assert new.stats["fused_kernel"]
    assert np.array_equal(new.color, old.color)
    assert np.array_equal(new.albedo, old.albedo)


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
    "normal": (lambda p, scene: setattr(p, "normal", 2), "node programs that set the normal"),
    "bump": (lambda p, scene: _with(p, _inst("bump", normal=16, strength=15, distance=15, height=4, height_dx=4,
                                      height_dy=4, filter_width=15), registers=1),
             "node programs with Bump nodes"),
    "tangent": (lambda p, scene: _with(p, _inst("tangent", out=16), registers=1), "node programs reading tangents"),
    "light path": (lambda p, scene: _with(p, _inst("light_path", is_camera=16), registers=1),
                   "node programs reading the light path"),
    "normal map": (lambda p, scene: _with(p, _inst("normal_map", normal=16, color=3, strength=15), registers=1),
                   "node programs reading tangents"),
    "uv map": (lambda p, scene: _with(p, _inst("uv_layer", out=16), registers=1),
               "node programs reading a named UV map"),
    "attribute": (lambda p, scene: _with(p, _inst("attribute", fac=16), registers=1),
                  "node programs reading attributes"),
    "aov output": (lambda p, scene: (_with(p, _inst("aov_output", value=4)),
                                     setattr(scene, "shader_aovs", [("noise", "VALUE")])),
                   "node programs writing shader AOVs"),
    "emission": (lambda p, scene: setattr(p, "emission", 5), "node programs with emission"),
}


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
