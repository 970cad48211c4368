"""Shading-node programs: Blender material node trees evaluated per shading point.

The add-on's compiler (addon/export/nodes/) translates each material's node tree into a `ShadingProgram`
(core.shading.program: flat int32 instructions over a float32 register file, float32 data, texture handles),
folding constant subgraphs at export. A material whose tree folds to constants gets no program and renders
through `MaterialTable.gather` alone, at no extra cost. For the others `PreparedShading` (core.shading.evaluator)
runs all programs of a batch of shading points in one compiled kernel and writes the per-point lobe parameters
(weights, roughness, ior, f0, tints) and emission over what `gather` produced, in core.bsdf.LobeBatch's layout.

Modules
-------
- program.py    the program format (instructions, registers, output bindings, the object table's columns)
- registry.py   every opcode: number, operand layout (`OpSpec`), documentation; opcode ranges per family
- evaluator.py  the compiled interpreter (`run_programs`), core node functions, image lookup, `PreparedShading`
- color.py      colour and converter nodes (opcodes 200..399)          [another engineer's module]
- procedural.py procedural textures (opcodes 400..599)                  [another engineer's module]

How a new node is added (five steps, each in its own place)
-------------------------------------------------------------
1. Opcode: in the family's module (core ops: registry.py; colour: color.py; procedural: procedural.py) call
   `registry.register(OpSpec(name, code, operands, doc))` with a number in the family's range and the operand
   layout in slot order: outputs first ("out", or "out?" when the output may be unused = -1), then register
   inputs ("in"; "in?" when -1 means a context default such as the normal), then "int" enums/flags, "tex"
   texture handles, "data" offsets into the program's float pool. The family module must be imported by
   registry.py's last line(s) (`from . import color  # noqa` style) so its opcodes exist when programs are
   validated.
2. Device function: the node's maths as a numba function decorated with core.jit_cache's `jit_no_nrt`
   (scalar arguments) or `jit_inline` (arguments that are arrays), following Blender's definition and Cycles'
   SVM kernel. The family module exposes ONE dispatcher decorated `jit_inline`:
       def run(op, a, regs, data):  # a: the instruction's int32 slots (a[0] = op, a[1..] operands)
   reading inputs with `evaluator.get3(regs, a[i])` / `regs[a[i], 0]` (floats live in component 0) and
   writing outputs with `evaluator.set3(regs, a[i], x, y, z)` / `evaluator.setf(regs, a[i], x)` (both skip
   a -1 operand). `data[a[i] + j]` reads the pool. To avoid an import cycle, put get3/set3/setf-style helpers
   in the family module itself or import them from evaluator inside `run`'s module only (evaluator imports the
   family module, never the reverse at import time).
   Then add the family's branch to `evaluator._execute` (its comment shows the line) and add the module's
   name to core.jit_cache.KERNEL_MODULES ("shading/color", "shading/procedural").
3. Compiler rule: in addon/export/nodes/rules.py, a function decorated
       @rule("ShaderNodeXxx", inputs=(...), outputs=(...), notes="known differences from Cycles")
       def _xxx(c, node): ...
   that reads the node's settings, gets its input registers with `c.input(node, "Socket", "FLOAT"|"VECTOR"|
   "RGBA")` and emits the instruction with `c.emit("opname", operand=..., ...)`, returning
   {"Output socket name": register}. Unsupported settings call `c.warn(node, "what; fallback")`.
   Constant inputs fold automatically: `emit` evaluates an instruction whose inputs are all constant at export
   (through `evaluator.run_single`, so the semantics are the kernel's) unless the opcode reads the shading
   context (set `varying=True` in emit for such ops).
4. Registry entry: the @rule decorator IS the registry entry (addon/export/nodes/registry.py collects them);
   `inputs`/`outputs` list the supported sockets and `notes` the known differences. Regenerate the coverage
   table with `.venv/bin/python -m monte.addon.export.nodes.coverage --write` (docs/shading-nodes.md);
   tests/test_shading_coverage.py fails while the committed table differs from the generated one.
5. Test: an analytic test of the device function through `evaluator.run_single` (tests/test_shading_nodes.py
   style), and a cross-check against Cycles with tests/shading_crosscheck.py's `emission_plane_case` (the node's
   output drives the Emission colour of a plane seen by an orthographic camera; Monte and Cycles images compared
   per pixel).
"""

from .program import ShadingProgram, ProgramError  # noqa: F401
from .evaluator import PreparedShading  # noqa: F401
