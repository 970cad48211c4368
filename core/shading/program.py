"""The shading-node program format: what the add-on's compiler writes and `core.shading.evaluator` runs.

A material whose node tree does not fold to constants carries one `ShadingProgram`:

- `registers` (R, 3) float32: the register file's initial values. Every register holds 3 floats: a vector or a
  colour uses all three, a float (scalar socket) uses component 0 (the compiler converts between socket types
  with explicit instructions, as Blender converts implicitly). Unconnected inputs and folded constants are
  registers initialised here; instructions overwrite the others.
- `code` (I, WIDTH) int32: one instruction per row: code[i, 0] is the opcode (see core.shading.registry), the
  other WIDTH - 1 slots are operands: register indices, enum values, texture handles (indices into
  `Scene.textures`) or offsets into `data`, as the opcode's `OpSpec.operands` names them. Unused slots are -1.
  Instructions run in order, once per shading point; they read and write registers only.
- `data` float32: a pool for variable-length operands (colour-ramp stops, curve tables), read by offset.
- `lobes` (L, N_BIND) int32: for lobe slot l of the material (its `Material.lobes`, in order) and each lobe
  parameter (`BIND_*`), the register holding the per-point value, or -1 to keep the lobe's constant value.
  Weights and tints are colours, roughness and ior floats (component 0), f0 a colour.
- `emission`: the register holding the emitted radiance (colour x strength, W/(sr m^2)), or -1 for the
  material's constant `Material.emission`.
- `normal`: the register holding the shading normal the BSDFs use (a Normal Map or Bump node's output driving a
  shader's Normal input; world space, on the viewer's side like N), or -1 for the interpolated normal. The
  integrator rebuilds the point's shading frame around it (core.geometry_kernels.reframe).

The evaluator writes the bound values over the lobe parameters `MaterialTable.gather` produced (the layout of
core.bsdf.LobeBatch), clamping as `MaterialTable.build` does (roughness to [0, 1] and to 0 at or below Cycles'
singular threshold, ior >= 1e-5, f0 and tints to [0, 1] / >= 0), and recomputes the lobe-choice probabilities.

Per-point inputs (the "shading context", world space, float32): P position, N shading normal and Ng true normal
both turned to the viewer's side (Cycles flips N and Ng on a back face), I unit direction towards the viewer,
UV (the mesh's active UV map), backfacing, the object row (`OBJECT_*` columns of `PreparedShading.objects`), and
the per-point extras (`PATH_*` and attribute columns below): the path state and the named mesh attributes; for the
Vector nodes also the ray differential dP.dx / dP.dy (Cycles' compact differential spread along two orthonormal
tangents of Ng), the UV maps' derivatives along them, the tangent layers (MikkTSpace tangent + bitangent sign per
UV map, Scene.tangent_layer_names) and the interpolated, unnormalised mesh normal (outside).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

WIDTH = 16  # int32 slots per instruction: the opcode and 15 operands

# Lobe parameters a program may drive (columns of ShadingProgram.lobes).
BIND_WEIGHT, BIND_ROUGHNESS, BIND_IOR, BIND_F0, BIND_TINT_R, BIND_TINT_T = range(6)
N_BIND = 6
BIND_NAMES = ("weight", "roughness", "ior", "f0", "reflection_tint", "transmission_tint")

# Columns of the per-object table (float32 rows): the world -> object transform (3x4, row-major), the object's
# location, its Object Info colour (RGB) and alpha, pass index, random value, and the generated-coordinate box
# (texture space location and size, in object space).
OBJECT_INVERSE = 0  # 12 floats
OBJECT_LOCATION = 12  # 3
OBJECT_COLOR = 15  # 4
OBJECT_PASS_INDEX = 19
OBJECT_RANDOM = 20
OBJECT_BOX_MIN = 21  # 3
OBJECT_BOX_SIZE = 24  # 3
OBJECT_COLUMNS = 27
# The last row of the object table the evaluator gets is the render camera's (Texture Coordinate's Camera and
# Window outputs; no triangle names it): world -> camera space (x right, y up, z forward: Cycles' camera space)
# as 3x4 in the OBJECT_INVERSE columns, the image frame (core.scene.Camera.frame: xmin, xmax, ymin, ymax) and the
# projection (CAMERA_PERSP, CAMERA_ORTHO, CAMERA_PANO).
CAMERA_FRAME = 12  # 4
CAMERA_KIND = 16
CAMERA_PERSP, CAMERA_ORTHO, CAMERA_PANO = 0, 1, 2

# Columns of the per-point extras (`PreparedShading.evaluate`'s `extra`, float32 (N, PATH_COLUMNS + 5 A)): the
# path state the Light Path node reads (Cycles' ray flags and bounce counts of the ray that reached the point,
# the ray's length in metres), then ATTRIBUTE_COLUMNS per named attribute of Scene.attribute_names.
PATH_FLAGS, PATH_LENGTH, PATH_DEPTH, PATH_DIFFUSE_DEPTH, PATH_GLOSSY_DEPTH, PATH_TRANSPARENT_DEPTH, \
    PATH_TRANSMISSION_DEPTH = range(7)
PATH_COLUMNS = 7
# Bits of the PATH_FLAGS column (stored as an exact float), Cycles' PATH_RAY_* meaning: the kind of the last
# non-transparent bounce (a camera ray stays one through transparent surfaces).
RAY_CAMERA, RAY_SHADOW, RAY_DIFFUSE, RAY_GLOSSY, RAY_SINGULAR, RAY_REFLECT, RAY_TRANSMIT, RAY_TRANSPARENT = (
    1, 2, 4, 8, 16, 32, 64, 128)
# Per attribute: the Color / Vector output (3 floats), Alpha, and Fac (Cycles' float output: the value of a
# float attribute, x of a 2D one, the average of a vector or colour): core.scene.Mesh.attributes' 5 columns;
# then 1 where the mesh has the attribute, 0 where it lacks it (all outputs read 0 there, Alpha the node's own
# default: 1 for the Attribute node, 0 for Color Attribute, as Cycles).
MESH_ATTRIBUTE_COLUMNS = 5
ATTRIBUTE_COLUMNS = 6


def camera_row(matrix_world, frame, kind: str) -> np.ndarray:
    """The object-table row of the render camera (see CAMERA_FRAME): matrix_world camera -> world 4x4 (Blender's,
    looking along -Z), frame (xmin, xmax, ymin, ymax), kind "PERSP", "ORTHO" or "PANO"."""
    m = np.asarray(matrix_world, np.float64)
    axes = m[:3, :3] / np.maximum(np.linalg.norm(m[:3, :3], axis=0), 1e-30)
    rot = np.stack([axes[:, 0], axes[:, 1], -axes[:, 2]])  # rows: right, up, forward
    row = np.zeros(OBJECT_COLUMNS, np.float32)
    row[OBJECT_INVERSE:OBJECT_INVERSE + 12] = np.concatenate([rot, (-rot @ m[:3, 3])[:, None]], axis=1).reshape(-1)
    row[CAMERA_FRAME:CAMERA_FRAME + 4] = frame
    row[CAMERA_KIND] = {"PERSP": CAMERA_PERSP, "ORTHO": CAMERA_ORTHO}.get(kind, CAMERA_PANO)
    return row


def identity_object_row() -> np.ndarray:
    """The object row of geometry without an object: identity transform, white, index 0, box [0, 1]^3."""
    row = np.zeros(OBJECT_COLUMNS, np.float32)
    row[OBJECT_INVERSE:OBJECT_INVERSE + 12] = np.eye(3, 4, dtype=np.float32).reshape(-1)
    row[OBJECT_COLOR:OBJECT_COLOR + 4] = 1.0
    row[OBJECT_BOX_SIZE:OBJECT_BOX_SIZE + 3] = 1.0
    return row


class ProgramError(ValueError):
    """A malformed program (the compiler's bug or a hand-written program's): raised by `validate`."""


@dataclass
class ShadingProgram:
    """One material's node program; see the module docstring for each field's meaning."""

    code: np.ndarray
    registers: np.ndarray
    lobes: np.ndarray
    emission: int = -1
    data: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    normal: int = -1

    def validate(self, owner: str, n_lobes: int, n_textures: int) -> None:
        """Normalise dtypes and check every operand the registry declares; raise ProgramError naming `owner`."""
        from .registry import OPS, check_instruction

        self.code = np.ascontiguousarray(np.asarray(self.code, np.int32).reshape(-1, WIDTH))
        self.registers = np.ascontiguousarray(np.asarray(self.registers, np.float32).reshape(-1, 3))
        self.data = np.ascontiguousarray(np.asarray(self.data, np.float32).reshape(-1))
        self.lobes = np.ascontiguousarray(np.asarray(self.lobes, np.int32).reshape(-1, N_BIND))
        r = self.registers.shape[0]
        if self.lobes.shape[0] != n_lobes:
            raise ProgramError(f"{owner}: program binds {self.lobes.shape[0]} lobes, the material has {n_lobes}")
        if not np.all(np.isfinite(self.registers)):
            raise ProgramError(f"{owner}: program constants contain NaN/Inf")
        bound = np.concatenate([self.lobes.reshape(-1), [self.emission, self.normal]])
        if np.any((bound < -1) | (bound >= r)):
            raise ProgramError(f"{owner}: an output binding names a register outside [0, {r})")
        for i, inst in enumerate(self.code):
            op = int(inst[0])
            if op not in OPS:
                raise ProgramError(f"{owner}: instruction {i}: unknown opcode {op}")
            why = check_instruction(OPS[op], inst, r, len(self.data), n_textures)
            if why:
                raise ProgramError(f"{owner}: instruction {i} ({OPS[op].name}): {why}")

    @property
    def is_constant(self) -> bool:
        """No instruction and no binding: the material is its constant lobes."""
        return self.code.shape[0] == 0 and not np.any(self.lobes >= 0) and self.emission < 0 and self.normal < 0
