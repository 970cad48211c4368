"""Shading-node programs (core.shading): the program format's checks and the node functions against their
definitions (Blender's manual and Cycles' SVM semantics), evaluated through the compiled evaluator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monte.core.shading import evaluator as ev
from monte.core.shading import registry as R
from monte.core.shading.program import N_BIND, WIDTH, ProgramError, ShadingProgram


def program(instructions, registers, lobes=0):
    code = np.full((len(instructions), WIDTH), -1, np.int32)
    for i, (name, ops) in enumerate(instructions):
        spec = R.op(name)
        code[i, 0] = spec.code
        for key, value in ops.items():
            code[i, spec.slot(key)] = value
        for j, (_, kind) in enumerate(spec.operands):
            if kind == "int" and code[i, j + 1] < 0:
                code[i, j + 1] = 0
    regs = np.asarray([np.broadcast_to(np.asarray(r, np.float32), 3) for r in registers], np.float32)
    return ShadingProgram(code, regs, np.full((lobes, N_BIND), -1, np.int32))


def math_node(op, a, b=0.0, c=0.0, clamp=0):
    p = program([("math", dict(out=0, a=1, b=2, c=3, operation=ev.MATH_OPS.index(op), clamp=clamp))],
                [0.0, a, b, c])
    p.validate("test", 0, 0)
    return float(ev.run_single(p)[0, 0])


@pytest.mark.parametrize("op,a,b,c,want", [
    ("ADD", 1.5, 2.25, 0, 3.75), ("DIVIDE", 1.0, 0.0, 0, 0.0), ("DIVIDE", 3.0, 2.0, 0, 1.5),
    ("POWER", -2.0, 0.5, 0, 0.0), ("POWER", -2.0, 3.0, 0, -8.0), ("LOGARITHM", -1.0, 10.0, 0, 0.0),
    ("LOGARITHM", 100.0, 10.0, 0, 2.0), ("SQRT", -4.0, 0, 0, 0.0), ("INVERSE_SQRT", 4.0, 0, 0, 0.5),
    ("COMPARE", 1.0, 1.05, 0.1, 1.0), ("COMPARE", 1.0, 1.2, 0.1, 0.0), ("SMOOTH_MIN", 1.0, 2.0, 0.0, 1.0),
    ("SMOOTH_MIN", 1.0, 1.0, 1.0, 1.0 - 1.0 / 6.0), ("FLOORED_MODULO", -1.0, 3.0, 0, 2.0),
    ("MODULO", -1.0, 3.0, 0, -1.0), ("WRAP", 5.5, 2.0, 1.0, 1.5), ("PINGPONG", 3.5, 2.0, 0, 0.5),
    ("SNAP", 3.7, 0.5, 0, 3.5), ("TRUNC", -1.5, 0, 0, -1.0), ("FRACT", -0.25, 0, 0, 0.75),
    ("ARCSINE", 2.0, 0, 0, math.pi / 2), ("SIGN", -3.0, 0, 0, -1.0), ("ARCTAN2", 1.0, -1.0, 0, 3 * math.pi / 4),
    ("DEGREES", math.pi, 0, 0, 180.0), ("MULTIPLY_ADD", 2.0, 3.0, 4.0, 10.0),
])
def test_math_node_operations(op, a, b, c, want):
    assert math_node(op, a, b, c) == pytest.approx(want, abs=1e-5)


def test_math_clamp_and_every_operation_is_known():
    assert math_node("MULTIPLY", 3.0, 2.0, clamp=1) == 1.0
    assert math_node("SUBTRACT", 0.0, 2.0, clamp=1) == 0.0
    assert len(ev.MATH_OPS) == 41


def test_program_validation_names_the_material_and_the_fault():
    p = program([("math", dict(out=0, a=1, b=2, c=9))], [0, 0, 0])
    with pytest.raises(ProgramError, match=r"material 'M': instruction 0 \(math\): operand 'c' = 9 is not a "
                                           r"register \(0\.\.2\)"):
        p.validate("material 'M'", 0, 0)
    bad = program([("image", dict(color=0, texture=3))], [0])
    with pytest.raises(ProgramError, match=r"operand 'texture' = 3 is not a texture"):
        bad.validate("material 'M'", 0, 2)
    with pytest.raises(ProgramError, match="binds 0 lobes, the material has 1"):
        program([], [0]).validate("material 'M'", 1, 0)


def test_registry_rejects_clashing_opcodes():
    with pytest.raises(ValueError, match="clashes with math"):
        R.register(R.OpSpec("another_math", R.OP_MATH, ()))
    with pytest.raises(ValueError, match="outside"):
        R.register(R.OpSpec("too_far", 600, ()))
