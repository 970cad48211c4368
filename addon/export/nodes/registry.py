"""The registry of supported nodes: Blender node bl_idname -> compiler rule, supported sockets, known differences.

Rules register themselves with the `rule` decorator (rules.py for value nodes, shaders.py for shader nodes); the
coverage table docs/shading-nodes.md is generated from RULES (coverage.py), so the documentation cannot drift.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class Rule:
    bl_idname: str
    label: str
    category: str  # "input", "shader", "texture", "converter", "vector", "color", "output", "layout"
    compile: Callable | None  # (builder, node, ctx) -> {output identifier: (register, kind)}; None for shaders
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    notes: str = ""


RULES: dict[str, Rule] = {}


def rule(bl_idname: str, label: str, category: str, inputs=(), outputs=(), notes: str = ""):
    """Decorator registering a node's compiler rule (the function may be None-returning for documentation-only
    entries such as shaders, which shaders.py walks itself)."""

    def register(fn):
        if bl_idname in RULES:
            raise ValueError(f"node {bl_idname} registered twice")
        RULES[bl_idname] = Rule(bl_idname, label, category, fn, tuple(inputs), tuple(outputs), notes)
        return fn

    return register


def document(bl_idname: str, label: str, category: str, inputs=(), outputs=(), notes: str = "") -> None:
    """A registry entry for a node handled outside the value-node rules (shaders, layout nodes)."""
    if bl_idname in RULES:
        raise ValueError(f"node {bl_idname} registered twice")
    RULES[bl_idname] = Rule(bl_idname, label, category, None, tuple(inputs), tuple(outputs), notes)


def _load() -> None:
    from . import color_rules, rules, shaders, textures, vector_rules  # noqa: F401  (registration side effects)


_load()
