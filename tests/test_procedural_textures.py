"""Monte's procedural textures (core/shading/procedural.py) against Cycles, pixel by pixel.

Each case is one tile of a Cycles render: a unit square of an emission plane seen by an orthographic camera
(32 x 32 pixels a tile, no lights, black world), its material Texture Coordinate (Object) -> Vector Math
(multiply-add: the tile's square onto the wanted texture domain) -> the texture -> Emission (strength 1).
One sample per pixel, Gaussian pixel filter 0.01 pixel wide (Blender forces the box filter to 1 pixel). A
second render with the same sample pattern, whose planes emit their own object coordinates, gives the exact
point each pixel's sample hit; the batch functions evaluate the texture there, so the comparison holds no
sampling error at all, only the difference between the two implementations. Values must agree to 1e-4
absolute (relative for outputs that grow beyond 1, such as the multifractal noises); measured, they agree to
float32 rounding (at most 2.4e-6, most exactly), Magic at depth 5 aside (1e-4, see its case). Textures with
steps (checker, brick, Voronoi cell colours, white noise of floored coordinates) may differ where a rounding
difference moves a sample across a step: those cases allow 2% of the tile's pixels to differ (none do today).

All default cases share one pair of Cycles renders and one pair of Monte renders (module fixtures, ~20 s in
all once the kernels are compiled); the wider sweeps (186 cases, 4 more pairs of Cycles renders, ~20 s) are
marked slow: `pytest -m slow tests/test_procedural_textures.py`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import crosscheck as cc  # noqa: E402
from monte.core.shading import procedural as tex  # noqa: E402

pytestmark = pytest.mark.blender

TILE = 32  # pixels per unit tile
COLUMNS = 8
SPP = 1
TOLERANCE = 1e-4
STEP_FRACTION = 0.02  # pixels allowed to differ on textures with steps (see the module docstring)
MAX_SAMPLE_OFFSET = 0.5  # pixels: leave out the few pixels Cycles sampled far from their centre


@dataclass
class Case:
    """One tile: the texture node, its settings and input values, the output compared, and the domain the
    tile's unit square maps to (vector = local * span + origin; W from the vector's x or a constant)."""
    name: str
    node: str
    output: str
    expect: object  # callable(coords (N, 4) float32) -> (N,) or (N, 3)
    props: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)
    span: tuple = (1.0, 1.0, 1.0)
    origin: tuple = (0.0, 0.0, 0.0)
    w: object = None  # None: W unlinked (0 or its default), "x": the vector's x, a number: that constant
    floor: bool = False  # floor the vector (and W) first: white noise then gives whole cells
    bias: float = 0.0  # added to the output before the Emission (keeps negative values out of the film)
    steps: bool = False
    relative: bool = False
    tolerance: float = TOLERANCE

    @property
    def id(self):
        return self.name


def _socket(sockets, name):
    """A socket by name or identifier ("Fac" is named "Factor" since Blender 5.0); None when the node's
    settings leave it out (the Vector input of a 1D texture)."""
    for sock in sockets:
        if (sock.name == name or sock.identifier == name) and getattr(sock, "enabled", True):
            return sock
    return None


def _feed(node, inputs):
    for key, value in inputs.items():
        sock = _socket(node.inputs, key)
        if sock is None:  # unused with these settings (Offset and Gain of fBM noise, Exponent of Euclidean, ...)
            continue
        if sock.type == "RGBA" and len(value) == 3:
            value = (*value, 1.0)
        sock.default_value = value


def _material(case: Case, tile_origin):
    mat = bpy.data.materials.new(case.name)
    tree = bf.node_tree_of(mat)
    tree.nodes.clear()
    nodes, links = tree.nodes, tree.links
    out = nodes.new("ShaderNodeOutputMaterial")
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    links.new(emission.outputs[0], out.inputs["Surface"])
    coord = nodes.new("ShaderNodeTexCoord")
    mad = nodes.new("ShaderNodeVectorMath")
    mad.operation = "MULTIPLY_ADD"
    span = np.asarray(case.span, np.float64)
    mad.inputs[1].default_value = tuple(span)
    mad.inputs[2].default_value = tuple(np.asarray(case.origin) - np.asarray(tile_origin) * span)
    links.new(coord.outputs["Object"], mad.inputs[0])
    vector = mad.outputs[0]
    if case.floor:
        fl = nodes.new("ShaderNodeVectorMath")
        fl.operation = "FLOOR"
        links.new(vector, fl.inputs[0])
        vector = fl.outputs[0]
    node = nodes.new(case.node)
    for key, value in case.props.items():
        setattr(node, key, value)
    _feed(node, case.inputs)
    if _socket(node.inputs, "Vector") is not None:
        links.new(vector, _socket(node.inputs, "Vector"))
    if case.w == "x":
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(vector, sep.inputs[0])
        links.new(sep.outputs[0], _socket(node.inputs, "W"))
    elif case.w is not None:
        _socket(node.inputs, "W").default_value = float(case.w)
    result = _socket(node.outputs, case.output)
    if case.bias:
        if result.type == "VALUE":
            add = nodes.new("ShaderNodeMath")
            add.operation = "ADD"
            add.inputs[1].default_value = case.bias
        else:
            add = nodes.new("ShaderNodeVectorMath")
            add.operation = "ADD"
            add.inputs[1].default_value = (case.bias,) * 3
        links.new(result, add.inputs[0])
        result = add.outputs[0]
    links.new(result, emission.inputs["Color"])
    return mat


def _tile_origin(index: int, rows: int):
    col, row = index % COLUMNS, index // COLUMNS
    return np.array([col, rows - 1 - row, 0.0])


def _calibration_material():
    """Emission = the object coordinates themselves: the image then holds where each pixel's samples landed."""
    mat = bpy.data.materials.new("calibration")
    tree = bf.node_tree_of(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    emission = tree.nodes.new("ShaderNodeEmission")
    coord = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(coord.outputs["Object"], emission.inputs["Color"])
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    return mat


def render_cases(cases: list[Case], tmp_dir: Path, engine: str = "CYCLES") -> tuple:
    """One render of every case's tile by `engine` (CYCLES or MONTE): (image (rows * TILE, COLUMNS * TILE, 3),
    row 0 at the top; each pixel's distance from its sample to its centre, in pixels (H, W); the world (x, y)
    its sample hit (H, W, 2), from a second render with the same sample pattern whose planes emit their own
    object coordinates)."""
    rows = -(-len(cases) // COLUMNS)
    scene = bf.reset()
    planes = []
    for i, case in enumerate(cases):
        o = _tile_origin(i, rows)
        verts = [tuple(o + d) for d in ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0))]
        planes.append(bf.mesh_object(case.name, verts, [(0, 1, 2, 3)], _material(case, o)))
    scale = max(COLUMNS, rows)
    bf.camera_object(scene, (COLUMNS / 2, rows / 2, 5.0), (0, 0, 0), kind="ORTHO", ortho_scale=float(scale))
    bf.set_world(scene, (0.0, 0.0, 0.0), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = COLUMNS * TILE, rows * TILE
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    if engine == "CYCLES":
        # Blender gives Cycles' box filter a width of 1 pixel whatever the setting; the Gaussian keeps 0.01.
        cc.configure_cycles(scene, SPP, 1, threads=2, seed=1, filter_type="gaussian", filter_width=0.01)
        render = lambda: cc.render_cycles(scene, tmp_dir)[0]  # noqa: E731
    else:
        m = scene.monte
        m.samples, m.seed, m.threads, m.filter_type, m.filter_width, m.max_bounces = SPP, 1, 2, "box", 0.01, 1
        render = lambda: cc.render_monte(scene)[0]  # noqa: E731
    image = render()
    calibration = _calibration_material()
    for ob in planes:
        ob.data.materials[0] = calibration
    where = render()
    h, w = image.shape[:2]
    cx = (np.arange(w) + 0.5) / TILE
    cy = rows - (np.arange(h) + 0.5) / TILE
    offset = np.hypot(where[..., 0] - cx[None, :], where[..., 1] - cy[:, None]) * TILE
    return image, offset, where[..., :2].astype(np.float32)


def tile_coords(case: Case, where: np.ndarray, tile_origin) -> np.ndarray:
    """The texture coordinates (x, y, z, W) the material computes at the tile's pixels (N, 4) float32, taken
    at the mean position of each pixel's samples (`where`, world x, y), row 0 at the top."""
    pos = np.zeros((where.shape[0] * where.shape[1], 3), np.float32)
    pos[:, :2] = where.reshape(-1, 2)
    # The material's multiply-add, with the constants Blender stores (float32): position * span + shift
    span = np.float32(case.span)
    shift = np.float32(np.asarray(case.origin) - np.asarray(tile_origin) * np.asarray(case.span))
    vec = pos * span + shift
    if case.floor:
        vec = np.floor(vec)
    w = np.zeros((len(vec), 1), np.float32)
    if case.w == "x":
        w[:, 0] = vec[:, 0]
    elif case.w is not None:
        w[:, 0] = case.w
    return np.concatenate([vec, w], axis=1).astype(np.float32)


def check(case: Case, rendered, index: int, rows: int, slack: float = 1.0) -> None:
    image, offset, where = rendered
    col, row = index % COLUMNS, index // COLUMNS
    tile = (slice(row * TILE, (row + 1) * TILE), slice(col * TILE, (col + 1) * TILE))
    got = image[tile].reshape(-1, 3) - case.bias
    centred = offset[tile].ravel() <= MAX_SAMPLE_OFFSET
    want = np.asarray(case.expect(tile_coords(case, where[tile], _tile_origin(index, rows))), np.float64)
    if want.ndim == 1:
        want = np.repeat(want[:, None], 3, axis=1)
    err = np.abs(got - want)
    if case.relative:
        err = err / np.maximum(1.0, np.abs(want))
    tolerance = case.tolerance * slack
    bad = np.any(err > tolerance, axis=1) & centred
    if case.steps:
        assert bad.sum() <= STEP_FRACTION * centred.sum(), (
            f"{case.name}: {bad.sum()} of {centred.sum()} pixels differ by more than {tolerance} "
            f"(allowed {STEP_FRACTION:.0%} at steps); worst {err[centred].max():.3g}")
        assert np.median(err[centred]) < TOLERANCE
    else:
        assert not bad.any(), (f"{case.name}: {bad.sum()} of {centred.sum()} pixels differ by more "
                               f"than {tolerance}; worst {err[centred].max():.3g}")


# --------------------------------------------------------------------------------------------- cases
def _noise(dim, output="Fac", **kw):
    def f(co):
        fac, color = tex.noise(co, dim, **kw)
        return fac if output == "Fac" else color
    return f


def _voronoi(dim, output, **kw):
    return lambda co: tex.voronoi(co, dim, **kw)[output]


NOISE_INPUTS = dict(Scale=3.0, Detail=2.5, Roughness=0.6, Lacunarity=2.1, Offset=0.3, Gain=1.2, Distortion=0.0)


def _noise_case(name, dim, noise_type="FBM", output="Fac", normalize=True, relative=False, bias=0.0, **over):
    inputs = dict(NOISE_INPUTS, **over)
    kw = dict(scale=inputs["Scale"], detail=inputs["Detail"], roughness=inputs["Roughness"],
              lacunarity=inputs["Lacunarity"], offset=inputs["Offset"], gain=inputs["Gain"],
              distortion=inputs["Distortion"], noise_type=noise_type, normalize=normalize)
    return Case(name, "ShaderNodeTexNoise", output, _noise(dim, output, **kw),
                props=dict(noise_dimensions=f"{dim}D", noise_type=noise_type, normalize=normalize), inputs=inputs,
                span=(2.0, 2.0, 2.0), origin=(-1.3, 0.4, 0.7), w="x" if dim in (1, 4) else None, bias=bias,
                relative=relative)


VORONOI_INPUTS = dict(Scale=2.5, Detail=0.0, Roughness=0.5, Lacunarity=2.0, Smoothness=1.0, Exponent=1.5,
                      Randomness=0.9)


def _voronoi_case(name, dim, feature="F1", metric="EUCLIDEAN", output="Distance", normalize=False, steps=None,
                  bias=0.0, **over):
    inputs = dict(VORONOI_INPUTS, **over)
    kw = dict(scale=inputs["Scale"], detail=inputs["Detail"], roughness=inputs["Roughness"],
              lacunarity=inputs["Lacunarity"], smoothness=inputs["Smoothness"], exponent=inputs["Exponent"],
              randomness=inputs["Randomness"], feature=feature, distance=metric, normalize=normalize)
    if steps is None:  # colours and positions jump from cell to cell; F2 distances and edges have kinks only
        steps = output in ("Color", "Position", "W", "Radius") and feature != "SMOOTH_F1"
    return Case(name, "ShaderNodeTexVoronoi", output, _voronoi(dim, output, **kw),
                props=dict(voronoi_dimensions=f"{dim}D", feature=feature, distance=metric, normalize=normalize),
                inputs=inputs, span=(2.0, 2.0, 2.0), origin=(-0.7, 0.3, 0.45), w="x" if dim in (1, 4) else None,
                steps=steps, bias=bias)


def default_cases() -> list[Case]:
    cases = []
    for gt in tex.GRADIENT_TYPES:
        cases.append(Case(f"gradient-{gt}", "ShaderNodeTexGradient", "Fac",
                          lambda co, gt=gt: tex.gradient(co, gt), props=dict(gradient_type=gt),
                          span=(2.4, 2.4, 0.0), origin=(-1.2, -1.2, 0.3)))
    cases.append(Case("checker", "ShaderNodeTexChecker", "Color",
                      lambda co: tex.checker(co, 3.0, (0.9, 0.5, 0.1), (0.1, 0.3, 0.7))[1],
                      inputs={"Scale": 3.0, "Color1": (0.9, 0.5, 0.1), "Color2": (0.1, 0.3, 0.7)},
                      span=(1.7, 1.3, 0.0), origin=(-0.45, 0.2, 0.25), steps=True))
    for dim in (1, 2, 3, 4):
        cases.append(Case(f"white-noise-{dim}d", "ShaderNodeTexWhiteNoise", "Color",
                          lambda co, dim=dim: tex.white_noise(co, dim)[1], props=dict(noise_dimensions=f"{dim}D"),
                          span=(6.0, 6.0, 0.0), origin=(-3.0, -2.0, 1.0), w="x" if dim in (1, 4) else None,
                          floor=True, steps=True))
    cases.append(Case("white-noise-3d-value", "ShaderNodeTexWhiteNoise", "Value",
                      lambda co: tex.white_noise(co, 3)[0], props=dict(noise_dimensions="3D"),
                      span=(6.0, 6.0, 0.0), origin=(-3.0, -2.0, 1.0), floor=True, steps=True))
    for dim in (1, 2, 3, 4):
        cases.append(_noise_case(f"noise-fbm-{dim}d", dim, output="Color"))
    cases.append(_noise_case("noise-fbm-3d-distorted-raw", 3, normalize=False, bias=1.0, relative=True,
                             Distortion=0.8))
    cases.append(_noise_case("noise-multifractal-3d", 3, "MULTIFRACTAL", relative=True, bias=1.0))
    cases.append(_noise_case("noise-hybrid-3d", 3, "HYBRID_MULTIFRACTAL", relative=True, bias=1.0))
    cases.append(_noise_case("noise-ridged-3d", 3, "RIDGED_MULTIFRACTAL", relative=True, Offset=1.0))
    cases.append(_noise_case("noise-hetero-3d", 3, "HETERO_TERRAIN", relative=True, bias=2.0))
    cases.append(_voronoi_case("voronoi-f1-3d-distance", 3))
    cases.append(_voronoi_case("voronoi-f1-3d-color", 3, output="Color"))
    cases.append(_voronoi_case("voronoi-f1-2d-position", 2, output="Position", bias=1.0))
    cases.append(_voronoi_case("voronoi-f2-2d-manhattan", 2, "F2", "MANHATTAN"))
    cases.append(_voronoi_case("voronoi-smooth-f1-3d-color", 3, "SMOOTH_F1", output="Color"))
    cases.append(_voronoi_case("voronoi-edge-2d", 2, "DISTANCE_TO_EDGE"))
    cases.append(_voronoi_case("voronoi-radius-3d", 3, "N_SPHERE_RADIUS", output="Radius"))
    cases.append(_voronoi_case("voronoi-f1-4d-chebychev", 4, metric="CHEBYCHEV"))
    cases.append(_voronoi_case("voronoi-f1-3d-minkowski", 3, metric="MINKOWSKI"))
    cases.append(_voronoi_case("voronoi-f1-1d-w", 1, output="W", bias=1.0))
    cases.append(_voronoi_case("voronoi-fractal-2d-normalized", 2, normalize=True, Detail=2.5, Roughness=0.6))
    for name, kind, direction, profile, extra in (
            ("wave-bands-x-sin", "BANDS", "X", "SIN", {}),
            ("wave-rings-spherical-saw", "RINGS", "SPHERICAL", "SAW", {}),
            ("wave-bands-diagonal-tri-distorted", "BANDS", "DIAGONAL", "TRI",
             {"Distortion": 3.0, "Detail": 2.5, "Detail Scale": 1.5, "Detail Roughness": 0.6, "Phase Offset": 0.7})):
        inputs = {"Scale": 1.3, **extra}
        kw = dict(scale=1.3, distortion=extra.get("Distortion", 0.0), detail=extra.get("Detail", 2.0),
                  detail_scale=extra.get("Detail Scale", 1.0), detail_roughness=extra.get("Detail Roughness", 0.5),
                  phase_offset=extra.get("Phase Offset", 0.0))
        dir_prop = "bands_direction" if kind == "BANDS" else "rings_direction"
        cases.append(Case(name, "ShaderNodeTexWave", "Fac",
                          lambda co, kind=kind, direction=direction, profile=profile, kw=kw:
                          tex.wave(co, wave_type=kind, direction=direction, profile=profile, **kw),
                          props={"wave_type": kind, dir_prop: direction, "wave_profile": profile}, inputs=inputs,
                          span=(1.5, 1.5, 0.0), origin=(-0.75, -0.6, 0.2), steps=profile != "SIN"))
    # Each level of the Magic texture multiplies float32 rounding differences (sinf/cosf of Cycles' libm
    # against LLVM's) by up to Distortion: depth 5 at distortion 2.3 differs by up to 1e-4 and gets 5e-4.
    for depth, dist, tol in ((2, 1.0, TOLERANCE), (5, 2.3, 5e-4)):
        cases.append(Case(f"magic-depth{depth}", "ShaderNodeTexMagic", "Color",
                          lambda co, depth=depth, dist=dist: tex.magic(co, 1.7, dist, depth)[1],
                          props=dict(turbulence_depth=depth), inputs={"Scale": 1.7, "Distortion": dist},
                          span=(1.2, 1.2, 0.0), origin=(-0.2, 0.1, 0.3), bias=1.0, tolerance=tol))
    for gt, output in (("2D", "Value"), ("2D", "Phase"), ("3D", "Value"), ("3D", "Intensity")):
        cases.append(Case(f"gabor-{gt.lower()}-{output.lower()}", "ShaderNodeTexGabor", output,
                          lambda co, gt=gt, output=output: tex.gabor(co, gt, 2.0, 2.5, 0.6, 0.7,
                                                                     (0.3, -0.5, 0.8))[output],
                          props=dict(gabor_type=gt), inputs={"Scale": 2.0, "Frequency": 2.5, "Anisotropy": 0.6,
                                                             "Orientation": 0.7 if gt == "2D" else (0.3, -0.5, 0.8)},
                          span=(1.5, 1.5, 0.0), origin=(-0.6, 0.3, 0.4), steps=output == "Phase"))
    cases.append(Case("brick", "ShaderNodeTexBrick", "Color",
                      lambda co: tex.brick(co, 2.0, 0.05, 0.3, 0.1, 0.6, 0.3, 0.4, 3, 0.8, 2,
                                           (0.9, 0.4, 0.2), (0.3, 0.6, 0.2), (0.05, 0.05, 0.1))[1],
                      props=dict(offset=0.4, offset_frequency=3, squash=0.8, squash_frequency=2),
                      inputs={"Scale": 2.0, "Mortar Size": 0.05, "Mortar Smooth": 0.3, "Bias": 0.1,
                              "Brick Width": 0.6, "Row Height": 0.3, "Color1": (0.9, 0.4, 0.2),
                              "Color2": (0.3, 0.6, 0.2), "Mortar": (0.05, 0.05, 0.1)},
                      span=(1.5, 1.5, 0.0), origin=(-0.3, -0.2, 0.0), steps=True))
    return cases


DEFAULT_CASES = default_cases()


@pytest.fixture(scope="module")
def default_render(tmp_path_factory):
    return render_cases(DEFAULT_CASES, tmp_path_factory.mktemp("procedural"))


def test_calibration_keeps_most_pixels(default_render):
    """The calibration render saw the planes (sample positions near the pixel centres), and the comparison
    leaves out at most a few pixels where Cycles drew a sample far from the centre."""
    offset = default_render[1]
    rows = -(-len(DEFAULT_CASES) // COLUMNS)
    covered = np.concatenate([offset[(i // COLUMNS) * TILE:(i // COLUMNS + 1) * TILE,
                                     (i % COLUMNS) * TILE:(i % COLUMNS + 1) * TILE].ravel()
                              for i in range(len(DEFAULT_CASES))])
    assert rows * COLUMNS >= len(DEFAULT_CASES)
    assert np.median(covered) < 0.01  # the Gaussian filter 0.01 pixel wide: samples near the centres
    assert (covered > MAX_SAMPLE_OFFSET).mean() < 0.03


@pytest.mark.parametrize("index", range(len(DEFAULT_CASES)), ids=[c.name for c in DEFAULT_CASES])
def test_texture_matches_cycles(default_render, index):
    rows = -(-len(DEFAULT_CASES) // COLUMNS)
    check(DEFAULT_CASES[index], default_render, index, rows)


@pytest.fixture(scope="module")
def monte_render(tmp_path_factory):
    return render_cases(DEFAULT_CASES, tmp_path_factory.mktemp("procedural-monte"), engine="MONTE")


@pytest.mark.parametrize("index", range(len(DEFAULT_CASES)), ids=[c.name for c in DEFAULT_CASES])
def test_monte_renders_the_texture_node(monte_render, index):
    """The same materials rendered by Monte: the add-on compiles each texture node into the shading program,
    whose emission must equal the batch function at every pixel's sample (so, by the test above, Cycles).
    Twice the tolerance: Monte's Vector Math rounds its multiply-add once, Cycles twice, and the one-ulp
    coordinate difference grows through the distorted noise to 1.04e-4 at one pixel."""
    rows = -(-len(DEFAULT_CASES) // COLUMNS)
    check(DEFAULT_CASES[index], monte_render, index, rows, slack=2.0)


# --------------------------------------------------------------------------------------------- slow: wider sweeps
def slow_cases() -> list[Case]:
    cases = []
    for dim in (1, 2, 3, 4):
        cases.append(Case(f"white-noise-{dim}d-unfloored", "ShaderNodeTexWhiteNoise", "Color",
                          lambda co, dim=dim: tex.white_noise(co, dim)[1], props=dict(noise_dimensions=f"{dim}D"),
                          origin=(0.25, -0.5, 0.125), w="x" if dim in (1, 4) else None))
    for scale in (0.5, 7.0):
        cases.append(Case(f"checker-scale{scale}", "ShaderNodeTexChecker", "Factor",
                          lambda co, scale=scale: tex.checker(co, scale)[0], inputs={"Scale": scale},
                          span=(2.0, 2.0, 0.0), origin=(-1.0, -1.0, -0.3), steps=True))
    for noise_type in tex.NOISE_TYPES:
        for dim in (1, 2, 3, 4):
            relative = noise_type != "FBM"
            bias = 0.0 if noise_type in ("FBM", "MULTIFRACTAL", "RIDGED_MULTIFRACTAL") else 2.0
            cases.append(_noise_case(f"noise-{noise_type.lower()}-{dim}d", dim, noise_type, output="Color",
                                     relative=relative, bias=bias))
            cases.append(_noise_case(f"noise-{noise_type.lower()}-{dim}d-distorted", dim, noise_type,
                                     relative=relative, bias=bias + 1.0, Distortion=1.5, Detail=4.3))
    cases.append(_noise_case("noise-fbm-3d-raw-detail0", 3, normalize=False, bias=1.0, Detail=0.0))
    cases.append(_noise_case("noise-fbm-2d-detail15-rough", 2, Detail=15.0, Roughness=0.9))
    for dim in (1, 2, 3, 4):
        for feature in tex.VORONOI_FEATURES:
            outputs = {"F1": ("Distance", "Color", "Position" if dim > 1 else "W"),
                       "F2": ("Distance", "Color", "W" if dim in (1, 4) else "Position"),
                       "SMOOTH_F1": ("Distance", "Color", "Position" if dim > 1 else "W"),
                       "DISTANCE_TO_EDGE": ("Distance",), "N_SPHERE_RADIUS": ("Radius",)}[feature]
            for output in outputs:
                cases.append(_voronoi_case(f"voronoi-{feature.lower()}-{dim}d-{output.lower()}", dim, feature,
                                           output=output, bias=1.0 if output in ("Position", "W") else 0.0))
        if dim > 1:
            for metric in ("MANHATTAN", "CHEBYCHEV", "MINKOWSKI"):
                for feature in ("F1", "F2", "SMOOTH_F1"):
                    cases.append(_voronoi_case(f"voronoi-{feature.lower()}-{dim}d-{metric.lower()}", dim, feature,
                                               metric))
        for feature in ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE"):
            cases.append(_voronoi_case(f"voronoi-{feature.lower()}-{dim}d-fractal", dim, feature, normalize=True,
                                       Detail=1.7, Roughness=0.7, Lacunarity=2.3, Randomness=0.6))
    for kind, directions in (("BANDS", tex.WAVE_BANDS_DIRECTIONS), ("RINGS", tex.WAVE_RINGS_DIRECTIONS)):
        for direction in directions:
            for profile in tex.WAVE_PROFILES:
                dir_prop = "bands_direction" if kind == "BANDS" else "rings_direction"
                cases.append(Case(f"wave-{kind.lower()}-{direction.lower()}-{profile.lower()}", "ShaderNodeTexWave",
                                  "Factor", lambda co, kind=kind, direction=direction, profile=profile:
                                  tex.wave(co, 1.1, 1.2, 3.0, 2.0, 0.55, 0.3, kind, direction, profile),
                                  props={"wave_type": kind, dir_prop: direction, "wave_profile": profile},
                                  inputs={"Scale": 1.1, "Distortion": 1.2, "Detail": 3.0, "Detail Scale": 2.0,
                                          "Detail Roughness": 0.55, "Phase Offset": 0.3},
                                  span=(1.5, 1.5, 0.0), origin=(-0.75, -0.6, 0.2), steps=profile != "SIN"))
    for gt in ("2D", "3D"):
        for aniso in (0.0, 1.0):
            for output in ("Value", "Phase", "Intensity"):
                cases.append(Case(f"gabor-{gt.lower()}-aniso{aniso:g}-{output.lower()}", "ShaderNodeTexGabor", output,
                                  lambda co, gt=gt, output=output, aniso=aniso:
                                  tex.gabor(co, gt, 3.0, 1.5, aniso, -0.4, (-0.2, 0.9, 0.3))[output],
                                  props=dict(gabor_type=gt),
                                  inputs={"Scale": 3.0, "Frequency": 1.5, "Anisotropy": aniso,
                                          "Orientation": -0.4 if gt == "2D" else (-0.2, 0.9, 0.3)},
                                  span=(1.5, 1.5, 0.0), origin=(-0.6, 0.3, 0.4), steps=output == "Phase"))
    for depth in range(11):
        cases.append(Case(f"magic-depth{depth}-slow", "ShaderNodeTexMagic", "Color",
                          lambda co, depth=depth: tex.magic(co, 1.3, 1.1, depth)[1],
                          props=dict(turbulence_depth=depth), inputs={"Scale": 1.3, "Distortion": 1.1},
                          span=(1.2, 1.2, 0.0), origin=(-0.4, 0.2, 0.1), bias=1.0, tolerance=5e-4))
    for name, props, inputs in (
            ("brick-defaults", {}, {}),
            ("brick-no-offset", dict(offset_frequency=1, offset=0.0), {"Mortar Smooth": 0.0}),
            ("brick-squash", dict(offset=0.7, offset_frequency=2, squash=1.6, squash_frequency=3),
             {"Bias": -0.3, "Mortar Size": 0.1}),
            ("brick-every-row", dict(offset_frequency=1, squash=2.0, squash_frequency=1), {"Row Height": 0.4})):
        kw = dict(scale=5.0, mortar_size=0.02, mortar_smooth=0.1, bias=0.0, brick_width=0.5, row_height=0.25,
                  offset=0.5, offset_frequency=2, squash=1.0, squash_frequency=2)
        kw.update({k: v for k, v in props.items()})
        kw.update({k.lower().replace(" ", "_"): v for k, v in inputs.items()})
        cases.append(Case(name, "ShaderNodeTexBrick", "Color", lambda co, kw=kw: tex.brick(co, **kw)[1],
                          props=props, inputs=inputs, span=(1.3, 1.3, 0.0), origin=(-0.6, -0.4, 0.0), steps=True))
    return cases


SLOW_CASES = slow_cases()
SLOW_GROUP = 48  # tiles per Cycles render


@pytest.fixture(scope="module")
def slow_renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("procedural-slow")
    return [render_cases(SLOW_CASES[i:i + SLOW_GROUP], tmp) for i in range(0, len(SLOW_CASES), SLOW_GROUP)]


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(SLOW_CASES)), ids=[c.name for c in SLOW_CASES])
def test_texture_sweep_matches_cycles(slow_renders, index):
    group, local = divmod(index, SLOW_GROUP)
    count = len(SLOW_CASES[group * SLOW_GROUP:(group + 1) * SLOW_GROUP])
    check(SLOW_CASES[index], slow_renders[group], local, -(-count // COLUMNS))


@pytest.fixture(scope="module")
def slow_monte_renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("procedural-slow-monte")
    return [render_cases(SLOW_CASES[i:i + SLOW_GROUP], tmp, engine="MONTE")
            for i in range(0, len(SLOW_CASES), SLOW_GROUP)]


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(SLOW_CASES)), ids=[c.name for c in SLOW_CASES])
def test_monte_texture_sweep(slow_monte_renders, index):
    """The sweep through Monte's shading program. Monte's Vector Math rounds the tile's multiply-add once (Cycles
    twice), so a coordinate may differ by one float32 ulp: white noise of unfloored coordinates hashes those bits
    and is left out; every case may differ at 2% of its pixels (a cell boundary of Voronoi's 5^4-cell Smooth F1
    window crossed), and values by 3x the tolerance (ulp differences grown by distortion)."""
    case = SLOW_CASES[index]
    if "unfloored" in case.name:
        pytest.skip("white noise hashes the coordinates' bits; Monte's differ from Cycles' by an ulp at some pixels")
    group, local = divmod(index, SLOW_GROUP)
    count = len(SLOW_CASES[group * SLOW_GROUP:(group + 1) * SLOW_GROUP])
    check(replace(case, steps=True), slow_monte_renders[group], local, -(-count // COLUMNS), slack=3.0)


# --------------------------------------------------------------------------------------------- unlinked Vector
def test_unlinked_vector_reads_generated_coordinates():
    """Textures with nothing in their Vector input read Generated coordinates in Blender: a Noise, a Voronoi and
    a Brick texture side by side in one material (summed into the Emission colour) on the shared emission-plane
    harness, Monte against Cycles. Both put samples within 0.005 px of the pixel centres (different jitters):
    at these scales the sum's slope is below 0.1 per pixel, so pixels must agree to 1e-3, except at most 2% near
    the brick's and the cells' steps."""
    import shading_crosscheck as sc

    def build(tree, nodes):
        noise = nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = 2.0
        vor = nodes.new("ShaderNodeTexVoronoi")
        vor.inputs["Scale"].default_value = 3.0
        brick = nodes.new("ShaderNodeTexBrick")
        add = nodes.new("ShaderNodeVectorMath")
        add.operation = "ADD"
        tree.links.new(noise.outputs["Color"], add.inputs[0])
        tree.links.new(vor.outputs["Color"], add.inputs[1])
        add2 = nodes.new("ShaderNodeVectorMath")
        add2.operation = "ADD"
        tree.links.new(add.outputs[0], add2.inputs[0])
        tree.links.new(brick.outputs["Color"], add2.inputs[1])
        return add2.outputs[0]

    monte, cycles = sc.compare(sc.emission_plane(build, size=48))
    err = np.abs(monte - cycles).max(axis=2)
    assert cycles.max() > 0.5 and np.ptp(cycles) > 0.5  # the textures are there
    assert (err > 1e-3).mean() <= 0.02, f"{(err > 1e-3).sum()} pixels differ by more than 1e-3; worst {err.max()}"
    assert np.median(err) < 1e-4
