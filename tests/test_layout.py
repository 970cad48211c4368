"""The three layers hold: core/ imports neither bpy, the add-on nor the lab; addon/ never imports the lab; the
extension's build excludes lab/. Read from the source (every import statement, module level or inside a
function), so an import hidden in a function body is caught too."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _imports(path: Path) -> list[str]:
    """Every module an import statement in `path` names, relative imports resolved against the package root
    (`monte`), e.g. 'monte.core.scene', 'bpy', 'numpy'."""
    package = ["monte", *path.relative_to(ROOT).parent.parts]
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            names += [module, *(f"{module}.{a.name}" for a in node.names)]
    return names


def _sources(folder: str) -> list[Path]:
    return sorted((ROOT / folder).rglob("*.py"))


@pytest.mark.parametrize("folder, forbidden", [
    ("core", ("bpy", "mathutils", "monte.addon", "monte.lab")),
    ("addon", ("monte.lab",)),
])
def test_layer_imports(folder, forbidden):
    bad = [f"{p.relative_to(ROOT)} imports {name}" for p in _sources(folder) for name in _imports(p)
           if any(name == f or name.startswith(f + ".") for f in forbidden)]
    assert not bad, "\n".join(bad)


def test_import_resolution_sees_relative_imports():
    # The check above is only as good as its resolver: a relative import from lab/ must resolve into monte.
    names = _imports(ROOT / "lab" / "stress.py")
    assert "monte.core.render" in names and "monte.core.metrics" in names


def test_extension_excludes_the_lab():
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert "/lab/" in manifest["build"]["paths_exclude_pattern"]


def test_every_cli_subcommand_is_there():
    from monte.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert sorted(sub.choices) == ["bench", "crosscheck", "mc-study", "perf", "render", "stress", "worker"]


def test_core_has_no_import_cycles():
    """No core module reaches itself through imports (function-level ones included: a cycle hidden in a
    function body is still a cycle, only deferred)."""
    modules = {p.stem: p for p in _sources("core") if p.parent == ROOT / "core"}
    graph = {name: {n.split(".")[2] for n in _imports(path) if n.startswith("monte.core.") and
                    n.split(".")[2] in modules and n.split(".")[2] != name}
             for name, path in modules.items()}
    cycles = []

    def visit(node, stack):
        for nxt in sorted(graph[node]):
            if nxt in stack:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif len(stack) < len(graph):
                visit(nxt, stack + [nxt])

    for name in graph:
        visit(name, [name])
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles[:5])
