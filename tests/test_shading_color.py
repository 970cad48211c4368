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
