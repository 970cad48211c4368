"""The colour and converter nodes (core/shading/color.py, baked by addon/export/color_nodes.py) against Cycles,
per pixel.

Each material is Texture Coordinate (Generated) -> Separate XYZ -> Math nodes (affine functions of the plane's
(u, v)) -> the node under test -> Emission (strength 1) on a 2 x 2 plane; several planes sit side by side in one
render, each filling a BLOCK x BLOCK block of an orthographic camera's image, no lights, a black world. One
sample per pixel with a 0.01 px Gaussian pixel filter puts that sample on the pixel centre (measured: within
3e-6 px; more samples spread over about +-0.3 px whatever the filter width, so they would blur the inputs), and
with nothing but emission in view the image is the node's value at the pixel centres, which the batch
functions evaluate here from the same (u, v). Tolerances: 1e-4 absolute where values
lie in about [0, 1]; 1e-4 relative to max(1, |value|) for HDR outputs (Blackbody). Cycles computes in float32
and this in float64: the measured gaps are ~1e-6 (printed with -s).

Inputs are chosen away from the nodes' discontinuities (a Constant ramp's steps, hue's wrap at red), where a
sample 0.005 px off the centre could fall on the other side.

The last test renders the same nodes with Monte, through its node program (compiler rules, opcodes, evaluator),
and checks each pixel against the range the node takes over the square Monte's samples cover.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import crosscheck as cc  # noqa: E402
from monte.addon.export import color_nodes as export  # noqa: E402
from monte.core.shading import color  # noqa: E402

pytestmark = pytest.mark.blender

BLOCK = 32  # pixels per plane side
SPP = 1  # the one sample at the pixel centre (see above)
MONTE_SPP = 4  # the range check below holds for any count; a few samples average the jitter
ABS_TOL = 1e-4


# ------------------------------------------------------------------------------------------ scene and inputs
def pixel_uv() -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of the Generated coordinates at the pixel centres of one block, row 0 at the top, as float32."""
    j = (np.arange(BLOCK) + 0.5) / BLOCK
    u = np.broadcast_to(j[None, :], (BLOCK, BLOCK))
    v = np.broadcast_to(1.0 - j[:, None], (BLOCK, BLOCK))
    return u.astype(np.float32).ravel(), v.astype(np.float32).ravel()


def affine(coeffs, u, v) -> np.ndarray:
    """a u + b v + c in float32, as the Math nodes compute it (Multiply Add twice)."""
    a, b, c = (np.float32(x) for x in coeffs)
    return (u * a + (v * b + c)).astype(np.float64)


def affine_color(rows, u, v) -> np.ndarray:
    return np.stack([affine(r, u, v) for r in rows], axis=-1)


@pytest.fixture(autouse=True)
def fresh_scene():
    """An empty factory scene for each test (made before its materials)."""
    return bf.reset()


class Material:
    """An emission material for one plane: scalar((a, b, c)) and color(rows) give affine functions a u + b v + c
    of the plane's (u, v) as node sockets, node() adds a node, emit(socket) drives the Emission colour."""

    def __init__(self, name: str, at_x: float | None = None):
        """(u, v) are the Generated coordinates; with at_x, the same values from the world position of the plane
        render_blocks centres at x = at_x (u = (x - at_x + 1) / 2, v = (y + 1) / 2)."""
        self.mat = bpy.data.materials.new(name)
        tree = self.tree = bf.node_tree_of(self.mat)
        tree.nodes.clear()
        out = tree.nodes.new("ShaderNodeOutputMaterial")
        self.emission = tree.nodes.new("ShaderNodeEmission")
        self.emission.inputs["Strength"].default_value = 1.0
        tree.links.new(self.emission.outputs[0], out.inputs["Surface"])
        self.sep = tree.nodes.new("ShaderNodeSeparateXYZ")
        if at_x is None:
            coords = tree.nodes.new("ShaderNodeTexCoord")
            tree.links.new(coords.outputs["Generated"], self.sep.inputs[0])
        else:
            geometry = tree.nodes.new("ShaderNodeNewGeometry")
            to_uv = self.node("ShaderNodeVectorMath", operation="MULTIPLY_ADD")
            to_uv.inputs[1].default_value = (0.5, 0.5, 0.0)
            to_uv.inputs[2].default_value = (0.5 - 0.5 * at_x, 0.5, 0.5)
            tree.links.new(geometry.outputs["Position"], to_uv.inputs[0])
            tree.links.new(to_uv.outputs[0], self.sep.inputs[0])

    def node(self, kind: str, **props):
        n = self.tree.nodes.new(kind)
        for key, value in props.items():
            setattr(n, key, value)
        return n

    def link(self, socket, target) -> None:
        self.tree.links.new(socket, target)

    def scalar(self, coeffs):
        a, b, c = coeffs
        inner = self.node("ShaderNodeMath", operation="MULTIPLY_ADD")
        self.link(self.sep.outputs["Y"], inner.inputs[0])
        inner.inputs[1].default_value, inner.inputs[2].default_value = b, c
        outer = self.node("ShaderNodeMath", operation="MULTIPLY_ADD")
        self.link(self.sep.outputs["X"], outer.inputs[0])
        outer.inputs[1].default_value = a
        self.link(inner.outputs[0], outer.inputs[2])
        return outer.outputs[0]

    def color(self, rows):
        comb = self.node("ShaderNodeCombineXYZ")
        for k, r in enumerate(rows):
            self.link(self.scalar(r), comb.inputs[k])
        return comb.outputs[0]

    def emit(self, socket) -> None:
        self.link(socket, self.emission.inputs["Color"])


def plane_x(i: int, k: int) -> float:
    """The x of the centre of plane i of k in render_blocks' row."""
    return float(-k + 1 + 2 * i)


def render_blocks(materials: list[Material], tmp_path, engine: str = "CYCLES") -> list[np.ndarray]:
    """One render (Cycles, or Monte through its node program) of a row of planes, one per material; each block
    (BLOCK * BLOCK, 3), row-major from the top. The materials are made after `fresh_scene` reset Blender; a
    second call renders the same planes again."""
    scene = bpy.context.scene
    k = len(materials)
    if scene.camera is None:
        for i, m in enumerate(materials):
            x = plane_x(i, k)
            bf.mesh_object(f"plane{i}", [(x - 1, -1, 0), (x + 1, -1, 0), (x + 1, 1, 0), (x - 1, 1, 0)],
                           [(0, 1, 2, 3)], m.mat)
        bf.camera_object(scene, (0, 0, 2), (0, 0, 0), kind="ORTHO", ortho_scale=2.0 * k)
        bf.set_world(scene, (0.0, 0.0, 0.0), 1.0)
        scene.render.resolution_x, scene.render.resolution_y = BLOCK * k, BLOCK
        scene.render.resolution_percentage = 100
        scene.render.film_transparent = False
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
    if engine == "MONTE":
        # Monte's samples spread over its narrowest box (0.01 px: the inputs move by up to 1.6e-4 across it)
        m = scene.monte
        m.samples, m.max_bounces, m.seed, m.threads = MONTE_SPP, 0, 1, 2
        m.filter_type, m.filter_width = "box", 0.01
        rgb = cc.render_monte(scene)[0]
    else:
        cc.configure_cycles(scene, SPP, 0, threads=2, seed=1, filter_type="gaussian", filter_width=0.01)
        rgb = cc.render_cycles(scene, tmp_path)[0]
        scene.render.engine = "MONTE"
    assert rgb.shape == (BLOCK, BLOCK * k, 3)
    return [rgb[:, i * BLOCK:(i + 1) * BLOCK].reshape(-1, 3) for i in range(k)]


def check(name: str, got: np.ndarray, want: np.ndarray, rel: bool = False) -> float:
    """Assert a rendered block `got` equals `want` per pixel (absolute ABS_TOL, or relative to max(1, |want|))."""
    want = np.broadcast_to(np.asarray(want, np.float64).reshape(len(got), -1), got.shape)
    scale = np.maximum(1.0, np.abs(want)) if rel else 1.0
    err = np.abs(got - want) / scale
    worst = float(err.max())
    print(f"{name}: max {'relative ' if rel else ''}error {worst:.2e}")
    if worst > ABS_TOL:
        i = int(np.argmax(err.max(axis=-1)))
        raise AssertionError(f"{name}: pixel {divmod(i, BLOCK)} Cycles {got[i]} vs {want[i]} (error {worst:.2e})")
    return worst


# ------------------------------------------------------------------------------------------------------- Mix
# Colours A and B and the factor as affine functions (a u + b v + c) of the plane's coordinates: A and B vary
# in different directions, B stays away from 0 (Divide's special case) and the factor inside (0, 1) (Dodge and
# Burn jump where t B reaches 1 and beyond).
MIX_A = ((0.9, 0.0, 0.05), (0.0, 0.9, 0.05), (0.5, -0.4, 0.5))
MIX_B = ((0.0, 0.8, 0.1), (-0.7, 0.0, 0.8), (0.3, 0.3, 0.2))
MIX_FAC = (0.3, 0.5, 0.1)


def mix_material(name: str, blend_type: str, fac=MIX_FAC, a=MIX_A, b=MIX_B, clamp_factor=False,
                 clamp_result=False, legacy=False, at_x=None) -> Material:
    m = Material(name, at_x)
    if legacy:
        node = m.node("ShaderNodeMixRGB", blend_type=blend_type, use_clamp=clamp_result)
        fac_in, a_in, b_in, out = node.inputs[0], node.inputs[1], node.inputs[2], node.outputs[0]
    else:
        node = m.node("ShaderNodeMix", data_type="RGBA", blend_type=blend_type, clamp_factor=clamp_factor,
                      clamp_result=clamp_result)
        by_id = {s.identifier: s for s in node.inputs}
        fac_in, a_in, b_in = by_id["Factor_Float"], by_id["A_Color"], by_id["B_Color"]
        out = next(s for s in node.outputs if s.identifier == "Result_Color")
    m.link(m.scalar(fac), fac_in)
    m.link(m.color(a), a_in)
    m.link(m.color(b), b_in)
    m.emit(out)
    m.constants = export.mix_constants(node)
    return m


def test_mix_every_blend_mode_matches_cycles(tmp_path):
    u, v = pixel_uv()
    modes = list(color.BLEND_TYPES)
    mats = [mix_material(f"mix-{mode}", mode) for mode in modes]
    blocks = render_blocks(mats, tmp_path)
    fac, a, b = affine(MIX_FAC, u, v), affine_color(MIX_A, u, v), affine_color(MIX_B, u, v)
    for mode, m, got in zip(modes, mats, blocks):
        k = m.constants
        assert k.blend == color.BLEND_TYPES[mode] and not k.clamp_factor and not k.clamp_result
        check(f"Mix {mode}", got, color.mix_color_many(mode, fac, a, b, k.clamp_factor, k.clamp_result))


def test_mix_clamping_and_legacy_mixrgb_match_cycles(tmp_path):
    """Clamp Factor and Clamp Result on the Mix node, the legacy MixRGB node (factor always clamped, Clamp on the
    result), with a factor from -0.3 to 1.3 and colours outside [0, 1]."""
    u, v = pixel_uv()
    fac_rows = (1.6, 0.0, -0.3)
    a_rows = ((1.5, 0.0, -0.2), (0.0, 1.2, 0.1), (0.4, 0.4, 0.3))
    b_rows = ((0.0, 0.9, 0.3), (-1.0, 0.0, 1.1), (0.2, 0.0, 0.9))
    cases = [(mode, cf, cr, legacy) for mode in ("MIX", "LINEAR_LIGHT", "ADD")
             for cf, cr, legacy in ((False, False, False), (True, False, False), (False, True, False),
                                    (True, True, False), (True, False, True), (True, True, True))]
    mats = [mix_material(f"clamp-{i}", mode, fac_rows, a_rows, b_rows, cf, cr, legacy)
            for i, (mode, cf, cr, legacy) in enumerate(cases)]
    blocks = render_blocks(mats, tmp_path)
    fac, a, b = affine(fac_rows, u, v), affine_color(a_rows, u, v), affine_color(b_rows, u, v)
    for (mode, cf, cr, legacy), m, got in zip(cases, mats, blocks):
        k = m.constants
        assert (k.clamp_factor, k.clamp_result) == (cf, cr)
        want = color.mix_color_many(mode, fac, a, b, k.clamp_factor, k.clamp_result)
        check(f"{'MixRGB' if legacy else 'Mix'} {mode} clamp factor {cf} result {cr}", got, want)
    # the cases differ: clamping is visible in this image (a check that could not fail would prove nothing)
    assert np.abs(blocks[0] - blocks[3]).max() > 0.1


# ------------------------------------------------------------------------------------------------ Color Ramp
RAMP_STOPS = ((0.1, (0.9, 0.1, 0.05, 1.0)), (0.35, (0.1, 0.7, 0.2, 0.6)), (0.7, (0.2, 0.3, 0.95, 0.2)),
              (0.9, (1.0, 0.9, 0.3, 0.9)))
# The factor runs from -0.04 to 1.06 across a block, its pixel centres at least 0.07 table steps from a step of
# a Constant ramp's table.
RAMP_FAC = (1.1, 0.0, -0.037)


def ramp_material(name: str, interpolation: str, mode: str = "RGB", hue: str = "NEAR",
                  alpha: bool = False, at_x=None) -> Material:
    m = Material(name, at_x)
    node = m.node("ShaderNodeValToRGB")
    ramp = node.color_ramp
    ramp.interpolation, ramp.color_mode, ramp.hue_interpolation = interpolation, mode, hue
    (pos0, col0), (pos1, col1) = RAMP_STOPS[0], RAMP_STOPS[-1]
    ramp.elements[0].position, ramp.elements[0].color = pos0, col0
    ramp.elements[1].position, ramp.elements[1].color = pos1, col1
    for pos, col in RAMP_STOPS[1:-1]:
        ramp.elements.new(pos).color = col
    m.link(m.scalar(RAMP_FAC), node.inputs["Fac"])
    m.emit(node.outputs["Alpha" if alpha else "Color"])
    m.constants = export.color_ramp_constants(node)
    m.alpha = alpha
    return m


def test_color_ramp_matches_cycles(tmp_path):
    """Every interpolation (Linear, Ease, Constant, Cardinal, B-Spline) in RGB, HSV with each hue
    interpolation, and HSL; the Alpha output."""
    u, v = pixel_uv()
    cases = [(i, "RGB", "NEAR", False) for i in ("LINEAR", "EASE", "CONSTANT", "CARDINAL", "B_SPLINE")]
    cases += [("LINEAR", "HSV", h, False) for h in ("NEAR", "FAR", "CW", "CCW")]
    cases += [("EASE", "HSL", "NEAR", False), ("LINEAR", "RGB", "NEAR", True)]
    mats = [ramp_material(f"ramp-{k}", *case) for k, case in enumerate(cases)]
    blocks = render_blocks(mats, tmp_path)
    fac = affine(RAMP_FAC, u, v)
    for case, m, got in zip(cases, mats, blocks):
        k = m.constants
        assert k.table.shape == (color.TABLE_SIZE, 4) and k.interpolate == (case[0] != "CONSTANT")
        rgba = color.color_ramp_many(k.table, k.interpolate, fac)
        want = rgba[:, 3:4] if m.alpha else rgba[:, :3]
        check(f"Color Ramp {case}", got, want)
    # Constant really steps: its image differs from Linear's
    assert np.abs(blocks[2] - blocks[0]).max() > 0.05


# -------------------------------------------------------------------------------------------------- curves
def set_points(curve, points, handles=None) -> None:
    """Replace a curve map's points by `points` [(x, y), ...] (handle types by index where given)."""
    while len(curve.points) > 2:
        curve.points.remove(curve.points[-1])
    curve.points[0].location, curve.points[1].location = points[0], points[-1]
    for x, y in points[1:-1]:
        curve.points.new(x, y)
    for i, h in (handles or {}).items():
        curve.points[i].handle_type = h


def curve_material(name: str, kind: str, extend: str, value_rows, fac_rows, shape: str, at_x=None) -> Material:
    m = Material(name, at_x)
    node = m.node(kind)
    mapping = node.mapping
    mapping.extend = extend
    mapping.use_clip = False
    curves = mapping.curves
    if kind == "ShaderNodeRGBCurve":
        set_points(curves[3], [(0.0, 0.05), (0.3, 0.45), (1.0, 0.9)])                      # C
        set_points(curves[0], [(0.0, 0.1), (0.5, 0.3), (1.0, 1.0)], {1: "VECTOR"})          # R
        set_points(curves[1], [(0.0, 0.0), (0.25, 0.6), (0.6, 0.4), (1.0, 0.8)], {2: "AUTO_CLAMPED"})  # G
        if shape == "wide":  # B spans x beyond [0, 1]: the table covers every curve's x range
            set_points(curves[2], [(-0.2, 0.3), (0.4, 0.1), (1.3, 0.7)])
    elif kind == "ShaderNodeVectorCurve":
        set_points(curves[0], [(-1.0, -0.8), (0.0, 0.3), (1.0, 0.6)])
        set_points(curves[1], [(-1.0, 0.5), (-0.2, -0.4), (0.5, 0.2), (1.0, -0.6)], {1: "VECTOR"})
        if shape == "wide":
            set_points(curves[2], [(-1.3, 0.0), (0.7, 0.9), (1.2, 0.2)])
    else:
        points = [(0.0, 0.2), (0.4, 0.9), (1.0, 0.5)] if shape != "wide" else [(0.2, 0.1), (0.5, 0.8), (0.8, 0.3)]
        set_points(curves[0], points, {1: "AUTO_CLAMPED"})
    mapping.update()
    value_in = node.inputs[1]
    if kind == "ShaderNodeFloatCurve":
        m.link(m.scalar(value_rows), value_in)
    else:
        m.link(m.color(value_rows), value_in)
    m.link(m.scalar(fac_rows), node.inputs[0])
    m.emit(node.outputs[0])
    m.constants = export.curve_constants(node)
    return m


def test_curves_match_cycles(tmp_path):
    """RGB Curves (C curve applied first, Vector and Auto Clamped handles), Vector Curves and Float Curve, Extend
    Horizontal and Extrapolated, inputs beyond the curves' x range, curves whose points span other ranges than
    [0, 1] (and, for Float Curve, less than [0, 1])."""
    u, v = pixel_uv()
    rgb_in = ((1.4, 0.0, -0.2), (0.0, 1.4, -0.2), (0.5, 0.3, 0.1))
    vec_in = ((2.6, 0.0, -1.3), (0.0, 2.4, -1.2), (1.0, -1.0, 0.1))
    float_in = (1.4, 0.1, -0.25)
    fac = (0.3, 0.0, 0.8)
    cases = []
    for kind, rows in (("ShaderNodeRGBCurve", rgb_in), ("ShaderNodeVectorCurve", vec_in),
                       ("ShaderNodeFloatCurve", float_in)):
        for extend in ("HORIZONTAL", "EXTRAPOLATED"):
            for shape in ("unit", "wide"):
                cases.append((kind, extend, rows, shape))
    mats = [curve_material(f"curve-{i}", kind, extend, rows, fac, shape)
            for i, (kind, extend, rows, shape) in enumerate(cases)]
    blocks = render_blocks(mats, tmp_path)
    f = affine(fac, u, v)
    for (kind, extend, rows, shape), m, got in zip(cases, mats, blocks):
        k = m.constants
        assert k.extrapolate == (extend == "EXTRAPOLATED")
        if kind == "ShaderNodeFloatCurve":
            want = color.float_curve_many(k.table, k.lo, k.hi, k.extrapolate, f, affine(rows, u, v))[:, None]
        else:
            want = color.curves_many(k.table, k.lo, k.hi, k.extrapolate, f, affine_color(rows, u, v))
        check(f"{kind[10:]} {extend} {shape} [{k.lo:g}, {k.hi:g}]", got, want)
    # extrapolation shows in these images
    assert np.abs(blocks[0] - blocks[2]).max() > 0.05


# ------------------------------------------------------------------------------- adjustments and converters
COLOR_IN = ((0.9, 0.0, 0.05), (0.0, 0.8, 0.1), (0.4, -0.3, 0.5))
# Separate Color's input: green - blue = (0.2 (3 i + j) - 7.184) / 32 at pixel (i, j) is never within 5e-4 of 0,
# so hue never wraps at red (green crossing blue while red is largest) within a sample's reach of a pixel centre.
HSV_IN = ((0.9, 0.0, 0.05), (0.0, 0.9, 0.05), (0.2, 0.3, 0.413))


def _node_material(name: str, kind: str, props: dict, inputs: dict, output: str | int = 0,
                   combine_outputs: bool = False, at_x=None) -> Material:
    """A material with one node of `kind`: inputs maps input index -> ("s", coeffs) for a scalar or
    ("c", rows) for a colour; with combine_outputs its three float outputs go to the emission as (x, y, z)."""
    m = Material(name, at_x)
    node = m.node(kind, **props)
    for index, (what, coeffs) in inputs.items():
        m.link(m.scalar(coeffs) if what == "s" else m.color(coeffs), node.inputs[index])
    if combine_outputs:
        comb = m.node("ShaderNodeCombineXYZ")
        for k in range(3):
            m.link(node.outputs[k], comb.inputs[k])
        m.emit(comb.outputs[0])
    else:
        m.emit(node.outputs[output])
    m.node_ref = node
    return m


def _converter_cases() -> dict:
    """The adjustment and converter nodes: name -> (_node_material arguments, reference(u, v) -> (N, channels))."""
    s = affine
    hsv_in = HSV_IN
    comb_in = ((1.0, 0.0, 0.0), (0.0, 1.1, -0.05), (0.3, 0.3, 0.3))
    out = {
        "hsv": (("ShaderNodeHueSaturation", {}, {0: ("s", (0.6, 0.0, 0.2)), 1: ("s", (0.0, 1.6, 0.2)),
                                                 2: ("s", (0.5, 0.5, 0.5)), 3: ("s", (0.0, 0.4, 0.6)),
                                                 4: ("c", COLOR_IN)}),
                lambda u, v: color.hue_saturation_value_many(s((0.6, 0.0, 0.2), u, v), s((0.0, 1.6, 0.2), u, v),
                                                             s((0.5, 0.5, 0.5), u, v), s((0.0, 0.4, 0.6), u, v),
                                                             affine_color(COLOR_IN, u, v))),
        "invert": (("ShaderNodeInvert", {}, {0: ("s", (0.0, 1.2, -0.1)), 1: ("c", COLOR_IN)}),
                   lambda u, v: color.invert_many(s((0.0, 1.2, -0.1), u, v), affine_color(COLOR_IN, u, v))),
        "bright-contrast": (("ShaderNodeBrightContrast", {}, {0: ("c", COLOR_IN), 1: ("s", (0.4, 0.0, -0.2)),
                                                             2: ("s", (0.0, 1.5, -0.5))}),
                            lambda u, v: color.bright_contrast_many(affine_color(COLOR_IN, u, v),
                                                                    s((0.4, 0.0, -0.2), u, v),
                                                                    s((0.0, 1.5, -0.5), u, v))),
        "gamma": (("ShaderNodeGamma", {}, {0: ("c", COLOR_IN), 1: ("s", (2.0, 0.5, 0.1))}),
                  lambda u, v: color.gamma_many(affine_color(COLOR_IN, u, v), s((2.0, 0.5, 0.1), u, v))),
        "rgb-to-bw": (("ShaderNodeRGBToBW", {}, {0: ("c", COLOR_IN)}),
                      lambda u, v: color.rgb_to_bw_many(affine_color(COLOR_IN, u, v))[:, None]),
        "blackbody": (("ShaderNodeBlackbody", {}, {0: ("s", (12000.0, 200.0, 600.0))}),
                      lambda u, v: color.blackbody_many(s((12000.0, 200.0, 600.0), u, v))),
        "wavelength": (("ShaderNodeWavelength", {}, {0: ("s", (420.0, 3.0, 370.0))}),
                       lambda u, v: color.wavelength_many(s((420.0, 3.0, 370.0), u, v))),
    }
    for mode in ("RGB", "HSV", "HSL"):
        out[f"separate-{mode}"] = (("ShaderNodeSeparateColor", {"mode": mode}, {0: ("c", hsv_in)}, 0, True),
                                   lambda u, v, mode=mode: color.separate_color_many(mode, affine_color(hsv_in, u, v)))
        out[f"combine-{mode}"] = (("ShaderNodeCombineColor", {"mode": mode},
                                   {k: ("s", r) for k, r in enumerate(comb_in)}),
                                  lambda u, v, mode=mode: color.combine_color_many(mode, affine_color(comb_in, u, v)))
    return out


def test_adjustment_and_converter_nodes_match_cycles(tmp_path):
    """Hue/Saturation/Value, Invert, Bright/Contrast, Gamma, RGB to BW, Separate and Combine Color (RGB, HSV,
    HSL; Separate's input keeps hue off its wrap at red, HSV_IN), Blackbody over 600-12800 K (every segment of the
    fit and both ends; HDR: relative tolerance) and Wavelength over 370-790 nm (both ends black)."""
    u, v = pixel_uv()
    cases = _converter_cases()
    names = list(cases)
    blocks = render_blocks([_node_material(name, *cases[name][0]) for name in names], tmp_path)
    for name, got in zip(names, blocks):
        check(name, got, cases[name][1](u, v), rel=name == "blackbody")


# ------------------------------------------------------------------------------------------------ bad input
def test_export_names_the_node_it_cannot_use():
    mat = bpy.data.materials.new("bad")
    tree = bf.node_tree_of(mat)
    curve = tree.nodes.new("ShaderNodeFloatCurve")
    curve.name = "Flat"
    points = curve.mapping.curves[0].points
    points[0].location, points[1].location = (0.5, 0.0), (0.5, 1.0)
    with pytest.raises(ValueError, match=r"^node 'Flat' \(Float Curve\): the curve's points span no x range "
                                         r"\(\[0.5, 0.5\]\)$"):
        export.curve_constants(curve)
    mix = tree.nodes.new("ShaderNodeMix")
    mix.name, mix.data_type = "Floats", "FLOAT"
    with pytest.raises(ValueError, match=r"^node 'Floats' \(Mix\) is not a Mix node in Color mode$"):
        export.mix_constants(mix)
    assert export.working_space_warning() is None  # the factory default is Linear Rec.709


# ------------------------------------------------------------------------ through Monte's node program
JITTER = 0.005 / BLOCK  # how far in u or v Monte's samples stray from the pixel centre (its 0.01 px box)


def _monte_cases() -> list:
    """(name, build(material name, plane x) -> Material, reference(material, u, v) -> (N, channels))."""
    def mix_ref(mode, fac, a, b, cf, cr):
        return lambda m, u, v: color.mix_color_many(mode, affine(fac, u, v), affine_color(a, u, v),
                                                    affine_color(b, u, v), cf, cr)

    cases = [(f"Mix {mode}", lambda name, x, mode=mode: mix_material(name, mode, at_x=x),
              mix_ref(mode, MIX_FAC, MIX_A, MIX_B, False, False)) for mode in color.BLEND_TYPES]
    rows = ((1.6, 0.0, -0.3), ((1.5, 0.0, -0.2), (0.0, 1.2, 0.1), (0.4, 0.4, 0.3)),
            ((0.0, 0.9, 0.3), (-1.0, 0.0, 1.1), (0.2, 0.0, 0.9)))
    for cf, cr, legacy in ((True, False, False), (False, True, False), (True, True, True)):
        cases.append((f"Mix LINEAR_LIGHT clamp {cf} {cr} legacy {legacy}",
                      lambda name, x, cf=cf, cr=cr, legacy=legacy: mix_material(name, "LINEAR_LIGHT", *rows, cf, cr,
                                                                                legacy, at_x=x),
                      mix_ref("LINEAR_LIGHT", *rows, cf, cr)))
    ramps = [(i, "RGB", "NEAR", False) for i in ("LINEAR", "EASE", "CONSTANT", "CARDINAL", "B_SPLINE")]
    for args in ramps + [("LINEAR", "HSV", "FAR", False), ("EASE", "HSL", "NEAR", False),
                         ("LINEAR", "RGB", "NEAR", True)]:
        cases.append((f"Color Ramp {' '.join(map(str, args))}",
                      lambda name, x, args=args: ramp_material(name, *args, at_x=x),
                      lambda m, u, v: (lambda rgba: rgba[:, 3:] if m.alpha else rgba[:, :3])(
                          color.color_ramp_many(m.constants.table, m.constants.interpolate, affine(RAMP_FAC, u, v)))))
    fac = (0.3, 0.0, 0.8)
    for kind, value in (("ShaderNodeRGBCurve", ((1.4, 0.0, -0.2), (0.0, 1.4, -0.2), (0.5, 0.3, 0.1))),
                        ("ShaderNodeVectorCurve", ((2.6, 0.0, -1.3), (0.0, 2.4, -1.2), (1.0, -1.0, 0.1))),
                        ("ShaderNodeFloatCurve", (1.4, 0.1, -0.25))):
        for extend, shape in (("HORIZONTAL", "unit"), ("EXTRAPOLATED", "wide")):
            def ref(m, u, v, value=value, is_float=kind == "ShaderNodeFloatCurve"):
                k = m.constants
                if is_float:
                    return color.float_curve_many(k.table, k.lo, k.hi, k.extrapolate, affine(fac, u, v),
                                                  affine(value, u, v))[:, None]
                return color.curves_many(k.table, k.lo, k.hi, k.extrapolate, affine(fac, u, v),
                                         affine_color(value, u, v))
            cases.append((f"{kind[10:]} {extend} {shape}",
                          lambda name, x, a=(kind, extend, value, fac, shape): curve_material(name, *a, at_x=x), ref))
    for name, (node_args, ref) in _converter_cases().items():
        cases.append((name, lambda n, x, node_args=node_args: _node_material(n, *node_args, at_x=x),
                      lambda m, u, v, ref=ref: ref(u, v)))
    return cases


def test_monte_renders_the_colour_nodes_as_cycles(tmp_path):
    """The planes rendered by Monte (compiler rules -> opcodes -> evaluator -> emission) and by Cycles.

    Every blend mode, the clamps and the legacy node, every ramp interpolation and colour mode, the curve nodes
    (both Extend modes, wide ranges), the adjustments and converters, Blackbody and Wavelength. Inputs come from
    the world position (the same (u, v) as Generated). Monte's samples stray up to 0.005 px from the pixel
    centre (its narrowest box), so each Monte pixel, an average of MONTE_SPP samples, must lie within the range
    the node takes over that square (its reference at the centre, corners and edge midpoints), widened by 1e-4
    (relative above 1, for Divide and Blackbody); negative colours (Subtract, Linear Light) render negative in
    both. Cycles' own image is checked against the same references at the centre (1e-4)."""
    cases = _monte_cases()
    k = len(cases)
    mats = [build(f"monte-{i}", plane_x(i, k)) for i, (_, build, _) in enumerate(cases)]
    monte = render_blocks(mats, tmp_path, engine="MONTE")
    cycles = render_blocks(mats, tmp_path)
    u, v = pixel_uv()
    offsets = [(du, dv) for du in (-JITTER, 0.0, JITTER) for dv in (-JITTER, 0.0, JITTER)]
    for (name, _, ref), m, got, cyc in zip(cases, mats, monte, cycles):
        centre = ref(m, u, v)
        check(f"Cycles {name}", cyc, centre, rel=True)
        around = np.stack([ref(m, (u + du).astype(np.float32), (v + dv).astype(np.float32)) for du, dv in offsets])
        lo, hi = around.min(axis=0), around.max(axis=0)
        tol = ABS_TOL * np.maximum(1.0, np.abs(hi))
        below, above = (lo - tol) - got, got - (hi + tol)
        worst = float(max(below.max(), above.max()))
        print(f"Monte {name}: {float(np.max(np.abs(got - centre))):.2e} from the centre value, "
              f"{'inside' if worst <= 0 else 'OUTSIDE'} the range over the sample square")
        if worst > 0:
            i = int(np.argmax(np.maximum(below, above).max(axis=-1)))
            raise AssertionError(f"Monte {name}: pixel {divmod(i, BLOCK)} {got[i]} outside [{lo[i]}, {hi[i]}]")
