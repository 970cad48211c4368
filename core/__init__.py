"""The renderer core: NumPy arrays in, NumPy arrays out. Never imports bpy."""

from . import dataclass_code as _dataclass_code

# Before any of Monte's dataclasses is defined: their generated methods come compiled from the last process.
_dataclass_code.install()
