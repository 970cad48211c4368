"""Not a test module: the per-node cross-check harness against Cycles, for every shading-node family.

`emission_plane(build, ...)` builds a 2 x 2 plane (UVs spanning [0, 1]^2, Generated = Object/2 + 1/2) filling
an orthographic camera's view, under a black world, whose material is an Emission shader of strength 1 with its
Color driven by the socket `build(tree, nodes)` returns: so each pixel shows the node's output at the point under
the pixel centre. A tiny pixel filter puts every sample at the pixel centre, making each pixel deterministic up
to float rounding in both engines: Monte's box of width 0.01 px and Cycles' Gaussian of width 0.01 px (Cycles'
Box filter ignores its width and spreads samples over the whole pixel; measured). `compare` renders both.

Usage in a test (tests/test_shading_crosscheck.py):

    def build(tree, nodes):
        math = nodes.new("ShaderNodeMath"); math.operation = "SINE"
        tree.links.new(nodes["Texture Coordinate"].outputs["Object"], math.inputs[0])
        return math.outputs[0]
    monte, cycles = compare(emission_plane(build))
    assert np.abs(monte - cycles).max() < 1e-3
"""

from __future__ import annotations

import math

import numpy as np

import blender_fixtures as bf


def emission_plane(build, size: int = 32, name: str = "node"):
    """A scene whose image is the output of `build(tree, nodes) -> output socket` on a plane, seen straight on.
    The tree already holds "Texture Coordinate" and "Geometry" nodes for inputs."""
    bpy = bf.bpy_module()
    scene = bf.reset()
    mat = bpy.data.materials.new(name)
    tree = bf.node_tree_of(mat)
    tree.nodes.clear()
    nodes = tree.nodes
    out = nodes.new("ShaderNodeOutputMaterial")
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    nodes.new("ShaderNodeTexCoord")
    nodes.new("ShaderNodeNewGeometry")
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    socket = build(tree, nodes)
    if socket is not None:
        tree.links.new(socket, emission.inputs["Color"])
    ob = bf.mesh_object("plane", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)], mat)
    uv = ob.data.uv_layers.new(name="UVMap")
    uv.data.foreach_set("uv", [0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0])
    bf.camera_object(scene, (0, 0, 2), (0, 0, 0), kind="ORTHO", ortho_scale=2.0)
    bf.set_world(scene, (0.0, 0.0, 0.0), 0.0)
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    return scene


def compare(scene, spp: int = 2, tmp_dir=None):
    """(Monte image, Cycles image), (H, W, 3) float64 each, rendered with every sample at the pixel centre."""
    import tempfile
    from pathlib import Path

    from monte.addon import crosscheck as cc

    m = scene.monte
    m.samples, m.max_bounces, m.seed, m.threads = spp, 0, 1, 2
    m.filter_type, m.filter_width = "box", 0.01
    monte = cc.render_monte(scene)[0]
    cc.configure_cycles(scene, spp, 0, threads=2, seed=1, filter_type="gaussian", filter_width=0.01)
    if hasattr(scene.render, "filter_size"):
        scene.render.filter_size = 0.01
    with tempfile.TemporaryDirectory() as tmp:
        cycles = cc.render_cycles(scene, Path(tmp_dir or tmp))[0]
    scene.render.engine = "MONTE"
    return monte, cycles


def pixel_centres(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Object-space x, y of each pixel centre (row 0 at the top) of emission_plane's camera."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    return np.meshgrid(c, -c)


__all__ = ["emission_plane", "compare", "pixel_centres", "math"]
