"""`monte perf --sections nodes`: a row per main shading node with its cost per shading point (lab/perf_nodes.py).

No timing is asserted (shared machines): the section must compile each node from a real Blender material into a
program that does per-point work (a positive time per point), and print one finite ns figure per node. A node's
figure is a difference of two timings, so a cheap node (Normal Map over its image baseline, ~10-40 ns) can come out
negative under load: its sign is not asserted."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("bpy")

NODES = ("Image Texture", "Noise Texture", "Noise Fac detail 0", "Noise Fac detail 2", "Noise Fac detail 8",
         "Voronoi Texture", "Wave Texture", "Mix (Color)", "Math", "Color Ramp", "Bump",
         "Normal Map", "Principled BSDF")


def test_node_costs_have_a_row_per_main_node(capsys):
    from monte.lab.perf_nodes import node_costs, print_node_costs

    r = node_costs(points=1 << 14, repeat=3)
    assert tuple(r["ns_per_point"]) == NODES
    for name, ns in r["ns_per_point"].items():
        assert math.isfinite(ns), (name, ns)
        assert r["program_ns_per_point"][name] > 0, name
    assert r["baseline_ns_per_point"]["uv"] > 0
    print_node_costs(r)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("Shading nodes, ns per node per shading point")
    for name in NODES:
        row = [line for line in lines if line.strip().startswith(name)]
        assert len(row) == 1, name
        assert math.isfinite(float(row[0].split()[-2])), row


def test_textured_profile_names_the_node_interpreter_and_accounts_for_the_render(capsys):
    """`monte perf --sections textured` at a tiny size: the profile's functions are sorted by own time, their
    shares are of the profiled total, and the scene's node programs show up as the interpreter's calls (one per
    vertex batch: at least one per bounce that hits a textured material)."""
    from monte.lab.perf_textured import print_textured_profile, textured_profile

    r = textured_profile(resolution=16, spp=2, repeat=1, top=200)
    assert r["cpu_seconds_best"] > 0 and r["profiled_seconds"] > 0
    seconds = [f["seconds"] for f in r["functions"]]
    assert seconds == sorted(seconds, reverse=True)
    assert 0 < sum(f["share"] for f in r["functions"]) <= 1 + 1e-9
    interpreter = [f for f in r["functions"] if f["function"] == "shading/evaluator.py:evaluate"]
    assert len(interpreter) == 1 and interpreter[0]["calls"] >= 1
    assert set(r["stage_seconds"]) >= {"camera", "intersect", "emission", "nee", "scatter"}
    print_textured_profile(r)
    out = capsys.readouterr().out
    assert out.startswith("Textured scene 16x16, 2 spp, 1 thread: ")
    assert "shading/evaluator.py:evaluate" in out
