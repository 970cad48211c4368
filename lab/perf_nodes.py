"""`monte perf --sections nodes`: what each main shading node costs per shading point (needs bpy).

Each node is built in a real Blender material (the add-on's compiler turns it into a node program, as for a
render) whose Emission colour (or, for Principled, Base Color) is the node's output, fed by the UV coordinates.
The programs run through `core.shading.PreparedShading.evaluate` on a batch of random shading points (position,
normal, UV, ray differentials, a tangent layer), best of `repeat` alternating runs, in thread CPU time (the
machine may be shared). The baseline is the same material with the UV coordinates driving the output directly;
a node's cost is (its program - the baseline) per point, divided by the number of copies chained in its program
(several, so that cheap nodes stand out of the timer's noise). Noise's row reads its Color output (three fBM
evaluations of 3 octaves, Blender's default detail 2); the Noise Fac rows one fBM at detail 0, 2, 8 (1, 3, 9
octaves of 3D Perlin noise); Wave is distorted (its distortion is a 3-octave Noise). Bump's row includes the two
extra evaluations of its Height input (Cycles' way: the height at P + dP.dx and P + dP.dy), here a Separate XYZ of
the coordinates. Prints numbers only: no timing is asserted.
"""

from __future__ import annotations

import time

import numpy as np

CHAIN = 8  # copies of a node chained in one program (cheap nodes then stand out of the timer's noise)


def _link(tree, out, inp):
    tree.links.new(out, inp)


def _material(name: str, build):
    """A material whose Emission colour is build(tree, colour_socket_in)'s output socket; returns the material."""
    import bpy

    from .bpy_scenes import node_tree_of

    mat = bpy.data.materials.new(name)
    tree = node_tree_of(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    texco = tree.nodes.new("ShaderNodeTexCoord")
    shader = build(tree, texco.outputs["UV"], out)
    if shader is None:
        emit = tree.nodes.new("ShaderNodeEmission")
        _link(tree, texco.outputs["UV"], emit.inputs["Color"])
        shader = emit.outputs[0]
    _link(tree, shader, out.inputs["Surface"])
    return mat


def _emit(tree, socket):
    emit = tree.nodes.new("ShaderNodeEmission")
    _link(tree, socket, emit.inputs["Color"])
    return emit.outputs[0]


def _chain(tree, uv, make, out_name: str):
    """CHAIN copies of the node made by make(tree), each fed by the previous one's output (the first by uv)."""
    sock = uv
    for _ in range(CHAIN):
        node = make(tree)
        _link(tree, sock, node.inputs[0] if node.bl_idname != "ShaderNodeMix" else node.inputs["A"])
        sock = node.outputs[out_name]
    return _emit(tree, sock)


def _image_node(image):
    def make(tree):
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        return node
    return make


def _noise(tree):
    node = tree.nodes.new("ShaderNodeTexNoise")
    node.inputs["Scale"].default_value = 3.0
    return node


def _noise_detail(detail: float):
    def make(tree):
        node = _noise(tree)
        node.inputs["Detail"].default_value = detail
        return node
    return make


def _wave(tree):
    node = tree.nodes.new("ShaderNodeTexWave")
    node.inputs["Scale"].default_value = 3.0
    node.inputs["Distortion"].default_value = 2.0  # Blender's default detail 2: three octaves of distortion noise
    return node


def _voronoi(tree):
    node = tree.nodes.new("ShaderNodeTexVoronoi")
    node.inputs["Scale"].default_value = 4.0
    return node


def _mix(tree):
    node = tree.nodes.new("ShaderNodeMix")
    node.data_type = "RGBA"
    node.inputs["Factor"].default_value = 0.3
    node.inputs["B"].default_value = (0.2, 0.5, 0.8, 1.0)
    return node


def _math(tree):
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = "MULTIPLY_ADD"
    node.inputs[1].default_value = 0.9
    node.inputs[2].default_value = 0.05
    return node


def _ramp(tree):
    node = tree.nodes.new("ShaderNodeValToRGB")
    node.color_ramp.elements.new(0.4).color = (0.8, 0.2, 0.1, 1.0)
    return node


def _bump(tree, uv, out):
    sep = tree.nodes.new("ShaderNodeSeparateXYZ")
    _link(tree, uv, sep.inputs[0])
    bump = tree.nodes.new("ShaderNodeBump")
    _link(tree, sep.outputs["X"], bump.inputs["Height"])
    return _emit(tree, bump.outputs["Normal"])


def _normal_map(image):
    def build(tree, uv, out):
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
        _link(tree, uv, tex.inputs["Vector"])
        nmap = tree.nodes.new("ShaderNodeNormalMap")
        nmap.uv_map = "UVMap"
        _link(tree, tex.outputs["Color"], nmap.inputs["Color"])
        return _emit(tree, nmap.outputs["Normal"])
    return build


def _image_only(image):
    def build(tree, uv, out):
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
        _link(tree, uv, tex.inputs["Vector"])
        return _emit(tree, tex.outputs["Color"])
    return build


def _principled(tree, uv, out):
    """Principled BSDF with Base Color, Metallic and Roughness driven (the UV's colour, its average for the
    floats): what a textured Principled adds per point (conversions, the metallic split, lobe writes and the
    lobe-choice probabilities)."""
    node = tree.nodes.new("ShaderNodeBsdfPrincipled")
    for socket in ("Base Color", "Metallic", "Roughness"):
        _link(tree, uv, node.inputs[socket])
    return node.outputs[0]


def _test_image(name: str, size: int = 256):
    """A float colour image with every texel different (bpy), as a user's texture."""
    import bpy

    image = bpy.data.images.new(name, size, size, alpha=True, float_buffer=True)
    rng = np.random.default_rng(3)
    px = rng.random((size, size, 4), dtype=np.float32)
    px[..., 3] = 1.0
    image.pixels.foreach_set(px.reshape(-1))
    image.colorspace_settings.name = "Non-Color"
    return image


def node_cases():
    """(row name, builder of the material's output, copies of the node in the program, the program's base)."""
    image = _test_image("perf-image")
    return [
        ("Image Texture", lambda t, uv, o: _chain(t, uv, _image_node(image), "Color"), CHAIN, "uv"),
        ("Noise Texture", lambda t, uv, o: _chain(t, uv, _noise, "Color"), CHAIN, "uv"),
        ("Noise Fac detail 0", lambda t, uv, o: _chain(t, uv, _noise_detail(0.0), "Fac"), CHAIN, "uv"),
        ("Noise Fac detail 2", lambda t, uv, o: _chain(t, uv, _noise_detail(2.0), "Fac"), CHAIN, "uv"),
        ("Noise Fac detail 8", lambda t, uv, o: _chain(t, uv, _noise_detail(8.0), "Fac"), CHAIN, "uv"),
        ("Voronoi Texture", lambda t, uv, o: _chain(t, uv, _voronoi, "Color"), CHAIN, "uv"),
        ("Wave Texture", lambda t, uv, o: _chain(t, uv, _wave, "Fac"), CHAIN, "uv"),
        ("Mix (Color)", lambda t, uv, o: _chain(t, uv, _mix, "Result"), CHAIN, "uv"),
        ("Math", lambda t, uv, o: _chain(t, uv, _math, "Value"), CHAIN, "uv"),
        ("Color Ramp", lambda t, uv, o: _chain(t, uv, _ramp, "Color"), CHAIN, "uv"),
        ("Bump", _bump, 1, "uv"),
        ("Normal Map", _normal_map(image), 1, "image"),
        ("Principled BSDF", _principled, 1, "uv"),  # Base Color, Metallic, Roughness driven
    ], image


def _points(n: int, seed: int = 7) -> dict:
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=(n, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    tangent = np.cross(normal, np.array([0.3, 0.5, 0.8], np.float32))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    tangents = np.concatenate([tangent, np.ones((n, 1), np.float32)], axis=1)[:, None, :].astype(np.float32)
    return {"P": rng.random((n, 3), dtype=np.float32) * 4 - 2, "N": normal, "Ng": normal.copy(),
            "I": normal.copy(), "uv": rng.random((n, 2), dtype=np.float32),
            "back": np.zeros(n, bool), "obj": np.zeros(n, np.int32),
            "dP": (rng.normal(size=(n, 2, 3)) * 1e-3).astype(np.float32),
            "duv": (rng.normal(size=(n, 2, 2)) * 1e-3).astype(np.float32), "tangents": tangents}


def _runner(material, textures, pts: dict):
    """A callable that runs the material's program over all points once (fresh lobe arrays each call)."""
    from ..core.bsdf import MaterialTable
    from ..core.shading import PreparedShading

    table = MaterialTable.build([material], textures)
    shading = PreparedShading([material.program], textures, table.max_lobes)
    n = len(pts["uv"])
    mat = np.zeros(n, np.int32)
    rows = np.arange(n, dtype=np.int64)
    emission = np.zeros((n, 3), np.float32)

    def run() -> float:
        lobes = table.gather(mat, pts["uv"])
        t0 = time.thread_time()
        shading.evaluate(rows, mat, pts["P"], pts["N"], pts["Ng"], pts["I"], pts["uv"], pts["back"], pts["obj"],
                         lobes, table.select_scale, emission, dP=pts["dP"], duv=pts["duv"],
                         tangents=pts["tangents"], mesh_normal=pts["N"])
        return time.thread_time() - t0
    return run


def node_costs(points: int = 1 << 16, repeat: int = 5) -> dict:
    """ns per shading point of each main node (its program minus the baseline, per copy), and the baseline's."""
    from ..addon.export.material import MaterialExporter
    from .bpy_scenes import reset

    reset()
    cases, image = node_cases()
    pts = _points(points)
    warnings: list[str] = []
    exporter = MaterialExporter(warnings)
    runners = {}
    for name, build, copies, base in cases:
        mat = exporter.convert(_material(name, build))
        if mat.program is None:
            raise RuntimeError(f"perf nodes: {name!r} folded to constants (warnings: {warnings})")
        runners[name] = (_runner(mat, exporter.textures, pts), copies, base)
    base_uv = exporter.convert(_material("baseline", lambda t, uv, o: None))
    base_image = exporter.convert(_material("baseline-image", _image_only(image)))
    bases = {"uv": _runner(base_uv, exporter.textures, pts), "image": _runner(base_image, exporter.textures, pts)}
    best = {k: np.inf for k in [*runners, *(f"base:{b}" for b in bases)]}
    for fn in [*(r[0] for r in runners.values()), *bases.values()]:
        fn()  # first calls load the kernels
    for _ in range(repeat):
        for key, fn in bases.items():
            best[f"base:{key}"] = min(best[f"base:{key}"], fn())
        for name, (fn, _, _) in runners.items():
            best[name] = min(best[name], fn())
    rows = {}
    for name, (_, copies, base) in runners.items():
        rows[name] = 1e9 * (best[name] - best[f"base:{base}"]) / (copies * points)
    return {"points": points, "ns_per_point": rows,
            "program_ns_per_point": {name: 1e9 * best[name] / points for name in runners},
            "baseline_ns_per_point": {k: 1e9 * best[f"base:{k}"] / points for k in bases}}


def print_node_costs(r: dict) -> None:
    print(f"Shading nodes, ns per node per shading point ({r['points']} points, program evaluation only; "
          f"baseline program {r['baseline_ns_per_point']['uv']:.0f} ns/point):")
    for name, ns in r["ns_per_point"].items():
        print(f"  {name:18s} {ns:8.1f} ns")
