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
- regs.py       register access for device functions (get3, getf, set3, setf)
- evaluator.py  the compiled interpreter (`run_programs`), core node functions, image lookup, `PreparedShading`
- color.py      colour and converter nodes (opcodes 200..399)          [another engineer's module]
- procedural.py procedural textures (opcodes 400..599)                  [another engineer's module]

How a new node is added (five steps, each in its own place)
-------------------------------------------------------------
1. Opcode: in the family's module (core ops: registry.py; colour: color.py; procedural: procedural.py) call
   `registry.register(OpSpec(name, code, operands, doc))` with a number in the family's range and the operand
   layout in slot order: outputs first ("out", or "out?" when the output may be unused = -1), then register
   inputs ("in"; "in?" when -1 means a context default such as the normal), then "int" enums/flags, "tex"
   texture handles, "data" offsets into the program's float pool. The family module registers its opcodes
   when imported; evaluator.py imports it (and this package imports evaluator), so they exist whenever
   core.shading is used.
2. Device function: the node's maths as a numba function decorated with core.jit_cache's `jit_no_nrt`
   (compiled once, cached on disk; never allocate inside), following Blender's definition and Cycles' SVM
   kernel. The family module exposes ONE dispatcher, also `jit_no_nrt`:
       def run(op, a, regs, data):  # a: the instruction's int32 slots (a[0] = op, a[1..] operands)
   reading inputs with core.shading.regs' `get3(regs, a[i])` / `getf(regs, a[i])` (floats live in component
   0) and writing outputs with `set3(regs, a[i], x, y, z)` / `setf(regs, a[i], x)` (both skip a -1 operand);
   `data[a[i] + j]` reads the program's float pool. The family module imports core.shading.regs and
   core.shading.registry only (evaluator imports the family module, never the reverse).
   Then add the family's branch to `evaluator._execute` and to the loop of `evaluator.run_programs` (their
   comments show the line), import the module in
   evaluator.py, and add "shading/<module>" to core.jit_cache.KERNEL_MODULES.
3. Compiler rule: in addon/export/nodes/ (rules.py, or a module of the family imported by nodes/registry.py's
   `_load`), a function decorated
       @rule("ShaderNodeXxx", "Label", "texture", inputs=(...), outputs=(...), notes="known differences")
       def _xxx(c, node, ctx): ...
   that reads the node's settings (warning with `c.warn(node, "what; the fallback")` for unsupported ones),
   gets input registers with `c.input(node, key, FLOAT | VECTOR | RGBA, ctx)` (key: socket index, identifier
   or name; Blender's implicit conversions are applied), emits instructions with
   `c.emit("opname", operand=register_or_int, ..., output_name=True)` (returns {output name: register}) and
   returns {"Output socket name or identifier": (register, FLOAT | VECTOR | RGBA)}. Float data (ramp stops)
   goes in with `c.add_data(values)` (returns the offset for a "data" operand). An unlinked texture Vector
   input reads Generated coordinates: `c.emit("texture_coordinate", generated=True)["generated"]`.
   Constant inputs fold automatically: `emit` runs an instruction whose inputs are all constant at export
   (through `evaluator.run_single`, so with the kernel's semantics), unless the opcode reads the shading
   context (compiler.CONTEXT_OPS, or `emit(..., varying=True)`).
4. Registry entry: the @rule decorator IS the registry entry (addon/export/nodes/registry.py collects them);
   `inputs`/`outputs` list the supported sockets and `notes` the known differences. Regenerate the coverage
   table with `.venv/bin/python -m monte.addon.export.nodes.coverage --write` (docs/shading-nodes.md);
   tests/test_shading_coverage.py fails while the committed table differs from the generated one.
5. Test: an analytic test of the device function through `evaluator.run_single` (tests/test_shading_nodes.py
   style), and a cross-check against Cycles with tests/shading_crosscheck.py: `emission_plane(build)` (the
   node's output drives the Emission colour of a plane filling an orthographic camera's view) and
   `compare(scene)` (Monte's and Cycles' images, compared per pixel; see tests/test_shading_crosscheck.py).
"""

from .program import ShadingProgram, ProgramError  # noqa: F401
from .evaluator import PreparedShading  # noqa: F401
