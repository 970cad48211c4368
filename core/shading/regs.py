"""Register-file access for the node device functions (core.shading.evaluator and the node-family modules).

A register is a row of the (R, 3) float32 scratch array: a vector or colour uses the three components, a float
component 0 (setf mirrors it into all three so that a float read as a colour is grey). Operand -1 means "output
unused": set3/setf then write nothing.
"""

from __future__ import annotations

from ..jit_cache import jit_no_nrt as _jit


@_jit
def get3(regs, r):
    """(x, y, z) of register r as float64."""
    return float(regs[r, 0]), float(regs[r, 1]), float(regs[r, 2])


@_jit
def getf(regs, r):
    """The float in register r (component 0) as float64."""
    return float(regs[r, 0])


@_jit
def set3(regs, r, x, y, z):
    if r >= 0:
        regs[r, 0] = x
        regs[r, 1] = y
        regs[r, 2] = z


@_jit
def setf(regs, r, x):
    if r >= 0:
        regs[r, 0] = x
        regs[r, 1] = x
        regs[r, 2] = x
