"""core/shading/color.py without Blender: identities the colour nodes must keep and the errors of their batch
forms for bad input. The per-pixel agreement with Cycles is tests/test_color_nodes.py."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.shading import color


@pytest.fixture(scope="module")
def colours() -> np.ndarray:
    return np.random.default_rng(7).uniform(0.0, 1.0, (500, 3))


@pytest.mark.parametrize("mode", ["HSV", "HSL"])
def test_separate_then_combine_gives_the_colour_back(colours, mode):
    back = color.combine_color_many(mode, color.separate_color_many(mode, colours))
    np.testing.assert_allclose(back, colours, atol=1e-12)


def test_hsv_of_primaries():
    hsv = color.separate_color_many("HSV", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0.5]])
    np.testing.assert_allclose(hsv, [[0, 1, 1], [1 / 3, 1, 1], [2 / 3, 1, 1], [0, 0, 0.5]], atol=1e-15)


def test_mix_factor_ends_and_clamping(colours):
    a, b = colours[:250], colours[250:]
    np.testing.assert_allclose(color.mix_color_many("MIX", 0.0, a, b), a, atol=1e-15)
    np.testing.assert_allclose(color.mix_color_many("MIX", 1.0, a, b), b, atol=1e-15)
    # factor 2 extrapolates unless clamped; the result clamp keeps [0, 1]
    np.testing.assert_allclose(color.mix_color_many("MIX", 2.0, a, b), 2 * b - a, atol=1e-12)
    np.testing.assert_allclose(color.mix_color_many("MIX", 2.0, a, b, clamp_factor=True), b, atol=1e-15)
    clamped = color.mix_color_many("MIX", 2.0, a, b, clamp_result=True)
    np.testing.assert_allclose(clamped, np.clip(2 * b - a, 0, 1), atol=1e-12)


def test_value_and_luminance():
    np.testing.assert_allclose(color.rgb_to_bw_many([[1, 1, 1]]), [1.0], atol=1e-12)  # white has luminance 1
    np.testing.assert_allclose(color.gamma_many([[0.25, -0.5, 4.0]], 0.5), [[0.5, -0.5, 2.0]], atol=1e-15)
    np.testing.assert_allclose(color.gamma_many([[0.25, -0.5, 4.0]], 0.0), [[1, 1, 1]])


def test_table_lookup_interpolates_and_extrapolates_a_line():
    """A table of the line 2x - 0.5 over [0, 1]: linear lookup gives the line inside, the end values outside,
    and the line itself with extrapolation."""
    x = np.linspace(0.0, 1.0, color.TABLE_SIZE)
    table = np.repeat((2 * x - 0.5)[:, None], 3, axis=1)
    f = np.array([-0.5, 0.123, 0.5, 0.987, 1.75])
    inside = color.curves_many(table, 0.0, 1.0, False, 1.0, np.repeat(f[:, None], 3, axis=1))[:, 0]
    np.testing.assert_allclose(inside, np.clip(2 * f - 0.5, -0.5, 1.5), atol=1e-6)
    line = color.curves_many(table, 0.0, 1.0, True, 1.0, np.repeat(f[:, None], 3, axis=1))[:, 0]
    np.testing.assert_allclose(line, 2 * f - 0.5, atol=1e-5)


def test_blackbody_ends_and_wavelength_outside_the_visible():
    np.testing.assert_allclose(color.blackbody_many([100.0, 20000.0]),
                               [[5.413294490189271, 0, 0], [0.8262954810464208, 0.9945080501520986,
                                                            1.566307710274283]], rtol=1e-12)
    assert np.all(color.wavelength_many([300.0, 374.9, 780.0, 900.0]) == 0.0)


@pytest.mark.parametrize("call, message", [
    (lambda: color.mix_color_many("PLUS", 0.5, [0, 0, 0], [1, 1, 1]),
     "unknown blend type 'PLUS'; expected one of MIX, ADD, MULTIPLY"),
    (lambda: color.mix_color_many("MIX", [0.5, 0.5], np.zeros((3, 3)), [1, 1, 1]),
     "fac: expected a scalar or 3 values, got shape (2,)"),
    (lambda: color.mix_color_many("MIX", 0.5, np.zeros((2, 2)), [1, 1, 1]),
     "a: expected one colour or 2 colours of 3 (or 4) channels, got shape (2, 2)"),
    (lambda: color.color_ramp_many(np.zeros((10, 3)), True, 0.5),
     "ramp table: expected a table of shape (rows >= 2, 4), got (10, 3)"),
    (lambda: color.float_curve_many(np.full(8, np.nan), 0.0, 1.0, False, 1.0, 0.5),
     "curve table: the table holds non-finite values"),
    (lambda: color.curves_many(np.zeros((8, 3)), 1.0, 1.0, False, 1.0, [0, 0, 0]), "curve range [1.0, 1.0] is empty"),
    (lambda: color.separate_color_many("CMYK", [0, 0, 0]),
     "unknown colour mode 'CMYK'; expected one of RGB, HSV, HSL"),
])
def test_bad_input_is_named(call, message):
    with pytest.raises(ValueError) as info:
        call()
    assert str(info.value).startswith(message)


# --------------------------------------------------------------------------- through the node program's evaluator
def _run(name: str, registers, data=(), **operands) -> np.ndarray:
    """One instruction of the colour family run by the compiled evaluator; the final register file."""
    from monte.core.shading import evaluator as ev
    from monte.core.shading import registry as R
    from monte.core.shading.program import N_BIND, WIDTH, ShadingProgram

    spec = R.op(name)
    code = np.full((1, WIDTH), -1, np.int32)
    code[0, 0] = spec.code
    for key, value in operands.items():
        code[0, spec.slot(key)] = value
    regs = np.asarray([np.broadcast_to(np.asarray(r, np.float32), 3) for r in registers], np.float32)
    program = ShadingProgram(code, regs, np.zeros((0, N_BIND), np.int32), data=np.asarray(data, np.float32))
    program.validate("test", 0, 0)
    return ev.run_single(program)


def test_every_colour_opcode_runs_in_the_evaluator_as_its_batch_form():
    """Each opcode's operand slots reach the right device function (checked against the batch forms)."""
    c1, c2 = np.array([0.2, 0.7, 0.4]), np.array([0.9, 0.3, 0.5])
    x = np.linspace(0.0, 1.0, color.TABLE_SIZE)
    ramp = np.stack([x, x ** 2, 1 - x, 0.5 + 0.5 * x], axis=1)
    curve = np.stack([np.sqrt(x), x ** 2, 1 - x], axis=1)
    near = dict(atol=2e-7)
    regs = _run("mix_color", [0, 0.3, c1, c2], out=0, factor=1, a=2, b=3, blend=color.MIX_OVERLAY,
                clamp_factor=0, clamp_result=0)
    np.testing.assert_allclose(regs[0], color.mix_color_many("OVERLAY", 0.3, c1, c2)[0], **near)
    regs = _run("color_ramp", [0, 0, 0.37], ramp.reshape(-1), color=0, alpha=1, fac=2, table=0,
                rows=color.TABLE_SIZE, interpolate=1)
    want = color.color_ramp_many(ramp, True, 0.37)[0]
    np.testing.assert_allclose(np.r_[regs[0], regs[1, 0]], want, **near)
    pool = np.r_[-0.5, 1.5, curve.reshape(-1)]
    regs = _run("curves", [0, 0.8, c1], pool, out=0, fac=1, color=2, table=0, rows=color.TABLE_SIZE, extrapolate=1)
    np.testing.assert_allclose(regs[0], color.curves_many(curve, -0.5, 1.5, True, 0.8, c1)[0], **near)
    pool = np.r_[0.0, 2.0, curve[:, 0]]
    regs = _run("float_curve", [0, 0.9, 2.5], pool, out=0, fac=1, value=2, table=0, rows=color.TABLE_SIZE,
                extrapolate=1)
    np.testing.assert_allclose(regs[0, 0], color.float_curve_many(curve[:, 0], 0.0, 2.0, True, 0.9, 2.5)[0], **near)
    regs = _run("hue_saturation_value", [0, 0.6, 1.3, 0.8, 0.9, c1], out=0, hue=1, saturation=2, value=3, fac=4,
                color=5)
    np.testing.assert_allclose(regs[0], color.hue_saturation_value_many(0.6, 1.3, 0.8, 0.9, c1)[0], **near)
    regs = _run("invert", [0, 0.7, c1], out=0, fac=1, color=2)
    np.testing.assert_allclose(regs[0], color.invert_many(0.7, c1)[0], **near)
    regs = _run("bright_contrast", [0, c1, 0.1, 0.6], out=0, color=1, bright=2, contrast=3)
    np.testing.assert_allclose(regs[0], color.bright_contrast_many(c1, 0.1, 0.6)[0], **near)
    regs = _run("gamma", [0, c1, 2.2], out=0, color=1, gamma=2)
    np.testing.assert_allclose(regs[0], color.gamma_many(c1, 2.2)[0], **near)
    regs = _run("rgb_to_bw", [0, c1], out=0, color=1)
    np.testing.assert_allclose(regs[0], color.rgb_to_bw_many(c1)[0], **near)
    regs = _run("separate_color", [0, 0, 0, c1], x=0, y=1, z=2, color=3, mode=color.COLOR_HSL)
    np.testing.assert_allclose(regs[:3, 0], color.separate_color_many("HSL", c1)[0], **near)
    regs = _run("combine_color", [0, 0.3, 0.6, 0.8], out=0, x=1, y=2, z=3, mode=color.COLOR_HSV)
    np.testing.assert_allclose(regs[0], color.combine_color_many("HSV", [0.3, 0.6, 0.8])[0], **near)
    regs = _run("blackbody", [0, 3300.0], out=0, temperature=1)
    np.testing.assert_allclose(regs[0], color.blackbody_many(3300.0)[0], rtol=2e-7)
    regs = _run("wavelength", [0, 512.5], out=0, wavelength=1)
    np.testing.assert_allclose(regs[0], color.wavelength_many(512.5)[0], **near)
