"""The shading-node coverage table (docs/shading-nodes.md), generated from the node registry.

    .venv/bin/python -m monte.addon.export.nodes.coverage --write   # regenerate the committed table
    .venv/bin/python -m monte.addon.export.nodes.coverage --check   # exit 1 when it differs (tests do this)
"""

from __future__ import annotations

import sys
from pathlib import Path

from .registry import RULES

DOC = Path(__file__).resolve().parents[3] / "docs" / "shading-nodes.md"
CATEGORIES = (("output", "Output"), ("shader", "Shaders"), ("input", "Input"), ("texture", "Textures"),
              ("color", "Colour"), ("vector", "Vector"), ("converter", "Converter"), ("layout", "Layout"))

HEADER = """# Shading nodes Monte supports

Generated from the node registry (`addon/export/nodes/`) by
`.venv/bin/python -m monte.addon.export.nodes.coverage --write`; a test fails when this file and the registry
disagree. A material's node tree is compiled at export into a program evaluated per shading point; constant
parts fold at export, and a material that folds to constants costs nothing per point. What each main node costs
per shading point: `monte perf --sections nodes` (measurements in docs/performance.md).

Anything not listed is unsupported and never silent: the export warns, naming the material and the node, and
uses the documented fallback:

- an unsupported node driving an input: the input keeps its own value (the value shown on the socket);
- an unsupported output of a supported node: its default value (0 or black), with a warning;
- an unsupported shader (e.g. Toon, Translucent, Subsurface Scattering, Hair, Holdout, Script/OSL) anywhere in
  the surface tree: the whole material renders as a diffuse of its viewport colour (Viewport Display > Color);
- a missing or unreadable image: Cycles' missing-texture magenta; NaN/Inf texels read as 0 (counted warning).
"""


def table() -> str:
    lines = [HEADER]
    for category, title in CATEGORIES:
        rules = sorted((r for r in RULES.values() if r.category == category), key=lambda r: r.label)
        if not rules:
            continue
        lines += [f"## {title}", "", "| Node | bl_idname | Inputs | Outputs | Known differences |",
                  "|---|---|---|---|---|"]
        for r in rules:
            cells = [r.label, f"`{r.bl_idname}`", ", ".join(r.inputs) or "-", ", ".join(r.outputs) or "-",
                     r.notes.replace("|", "/") or "-"]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    text = table()
    if argv == ["--write"]:
        DOC.write_text(text)
        print(f"wrote {DOC}")
        return 0
    if argv == ["--check"]:
        if not DOC.exists() or DOC.read_text() != text:
            print(f"{DOC} is out of date: run with --write", file=sys.stderr)
            return 1
        return 0
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
