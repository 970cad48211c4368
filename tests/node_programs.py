"""Hand-built node programs for core tests: instructions by opcode name and operand names (core.shading.registry),
and a ShadingProgram of them over constant registers, no lobes bound."""

from __future__ import annotations

import numpy as np

from monte.core.shading import registry as R
from monte.core.shading.program import WIDTH, ShadingProgram


def instruction(opname: str, **operands) -> list[int]:
    """One instruction row: the opcode, then each named operand in its slot; unnamed slots -1."""
    spec = R.op(opname)
    inst = [-1] * WIDTH
    inst[0] = spec.code
    for name, value in operands.items():
        inst[spec.slot(name)] = value
    return inst


def program(registers, code, n_lobes: int = 1) -> ShadingProgram:
    """A program of the instruction rows `code` over the constant `registers`, with n_lobes unbound lobes."""
    return ShadingProgram(np.asarray(code, np.int32).reshape(-1, WIDTH), np.asarray(registers, np.float32),
                          np.full((n_lobes, 6), -1, np.int32))
