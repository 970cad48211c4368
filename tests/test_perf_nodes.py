"""`monte perf --sections nodes`: a row per main shading node with its cost per shading point (lab/perf_nodes.py).

No timing is asserted (shared machines): the section must compile each node from a real Blender material into a
program that does per-point work, and print one positive ns figure per node."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("bpy")

NODES = ("Image Texture", "Noise Texture", "Voronoi Texture", "Mix (Color)", "Math", "Color Ramp", "Bump",
         "Normal Map", "Principled BSDF")


def test_node_costs_have_a_positive_row_per_main_node(capsys):
    from monte.lab.perf_nodes import node_costs, print_node_costs

    r = node_costs(points=1 << 14, repeat=3)
    assert tuple(r["ns_per_point"]) == NODES
    for name, ns in r["ns_per_point"].items():
        assert math.isfinite(ns) and ns > 0, (name, ns)
    assert r["baseline_ns_per_point"]["uv"] > 0
    print_node_costs(r)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("Shading nodes, ns per node per shading point")
    for name in NODES:
        row = [line for line in lines if line.strip().startswith(name)]
        assert len(row) == 1, name
        assert float(row[0].split()[-2]) > 0
