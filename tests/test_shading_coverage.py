"""docs/shading-nodes.md is the registry's table: the committed file must equal the generated one."""

from __future__ import annotations

import pytest

pytest.importorskip("bpy")


def test_committed_coverage_table_equals_the_generated_one():
    from monte.addon.export.nodes import coverage

    assert coverage.DOC.read_text() == coverage.table(), \
        "docs/shading-nodes.md is out of date: run .venv/bin/python -m monte.addon.export.nodes.coverage --write"


def test_every_rule_names_a_category_the_table_shows():
    from monte.addon.export.nodes import coverage
    from monte.addon.export.nodes.registry import RULES

    shown = {c for c, _ in coverage.CATEGORIES}
    assert {r.category for r in RULES.values()} <= shown
    assert "ShaderNodeMath" in coverage.table() and "ShaderNodeTexImage" in coverage.table()
