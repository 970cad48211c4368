"""The opcode registry: every instruction a shading program may hold, its number and its operand layout.

Opcode numbers are grouped by the module whose device functions implement them, so that engineers adding node
families never collide (see core.shading's docstring for the whole procedure of adding a node):

    0..199    core nodes          core.shading.evaluator (inputs, maths, vectors, mapping, images, shader helpers)
    200..399  colour/converters   core.shading.color
    400..599  procedural textures core.shading.procedural

An `OpSpec` names the operand in each instruction slot (slot 1 is operand 0; slot 0 is the opcode) and its kind:
  "in"    a register read (must exist)
  "in?"   a register read or -1, meaning the shading context's default (e.g. the normal N when unlinked)
  "out"   a register written (must exist); "out?" may be -1 (output unused, not computed or discarded)
  "int"   an integer parameter (an enum of the node, a flag)
  "tex"   a texture handle: an index into Scene.textures
  "data"  an offset into the program's float data pool
Operands past the listed ones are -1.
"""

from __future__ import annotations

from dataclasses import dataclass

from .program import WIDTH

CORE_BASE, COLOR_BASE, PROCEDURAL_BASE, OPCODE_END = 0, 200, 400, 600
FAMILY_OF = (("core", CORE_BASE, COLOR_BASE), ("color", COLOR_BASE, PROCEDURAL_BASE),
             ("procedural", PROCEDURAL_BASE, OPCODE_END))
OPERAND_KINDS = ("in", "in?", "out", "out?", "int", "tex", "data")


@dataclass(frozen=True)
class OpSpec:
    """One instruction: `name`, opcode `code`, operands ((name, kind), ...) in slot order, and a line of
    documentation (the semantics, Blender's/Cycles' where they differ from the obvious)."""

    name: str
    code: int
    operands: tuple[tuple[str, str], ...]
    doc: str = ""

    def __post_init__(self) -> None:
        if len(self.operands) > WIDTH - 1:
            raise ValueError(f"opcode {self.name}: {len(self.operands)} operands, at most {WIDTH - 1}")
        for name, kind in self.operands:
            if kind not in OPERAND_KINDS:
                raise ValueError(f"opcode {self.name}: operand {name!r} has unknown kind {kind!r}")

    def slot(self, operand: str) -> int:
        """The instruction slot (1-based, after the opcode) of a named operand."""
        for i, (name, _) in enumerate(self.operands):
            if name == operand:
                return i + 1
        raise KeyError(f"opcode {self.name} has no operand {operand!r}")

    @property
    def family(self) -> str:
        return next(f for f, lo, hi in FAMILY_OF if lo <= self.code < hi)


OPS: dict[int, OpSpec] = {}
OPS_BY_NAME: dict[str, OpSpec] = {}


def register(spec: OpSpec) -> OpSpec:
    """Add an opcode to the registry; raises ValueError on a clash of number or name."""
    if not CORE_BASE <= spec.code < OPCODE_END:
        raise ValueError(f"opcode {spec.name}: {spec.code} outside [{CORE_BASE}, {OPCODE_END})")
    if spec.code in OPS or spec.name in OPS_BY_NAME:
        other = OPS.get(spec.code) or OPS_BY_NAME[spec.name]
        raise ValueError(f"opcode {spec.name} ({spec.code}) clashes with {other.name} ({other.code})")
    OPS[spec.code] = spec
    OPS_BY_NAME[spec.name] = spec
    return spec


def op(name: str) -> OpSpec:
    return OPS_BY_NAME[name]


def check_instruction(spec: OpSpec, inst, n_registers: int, n_data: int, n_textures: int) -> str:
    """Why the instruction's operands are invalid for `spec`, or '' when they are valid."""
    for i, (name, kind) in enumerate(spec.operands):
        v = int(inst[i + 1])
        if kind in ("in", "out") and not 0 <= v < n_registers:
            return f"operand {name!r} = {v} is not a register (0..{n_registers - 1})"
        if kind in ("in?", "out?") and not -1 <= v < n_registers:
            return f"operand {name!r} = {v} is not a register or -1"
        if kind == "tex" and not 0 <= v < n_textures:
            return f"operand {name!r} = {v} is not a texture (0..{n_textures - 1})"
        if kind == "data" and not 0 <= v <= n_data:
            return f"operand {name!r} = {v} is outside the data pool (0..{n_data})"
    for j in range(len(spec.operands) + 1, WIDTH):
        if int(inst[j]) != -1:
            return f"slot {j} is unused by {spec.name} but holds {int(inst[j])}"
    return ""


def _r(*names: str, kind: str) -> tuple[tuple[str, str], ...]:
    return tuple((n, kind) for n in names)


# ------------------------------------------------------------------------------------------------ core opcodes
# Conversions and helpers the compiler emits between sockets.
OP_COPY = register(OpSpec("copy", 1, _r("out", kind="out") + _r("a", kind="in"), "out = a")).code
OP_FLOAT_TO_VEC = register(OpSpec("float_to_vec", 2, _r("out", kind="out") + _r("a", kind="in"),
                                  "out = (a.x, a.x, a.x): Blender's float -> vector/colour")).code
OP_COLOR_TO_FLOAT = register(OpSpec("color_to_float", 3, _r("out", kind="out") + _r("a", kind="in"),
                                    "out.x = 0.2126 r + 0.7152 g + 0.0722 b: colour -> float (Rec.709 luminance)")).code
OP_VEC_TO_FLOAT = register(OpSpec("vec_to_float", 4, _r("out", kind="out") + _r("a", kind="in"),
                                  "out.x = (x + y + z) / 3: vector -> float")).code
# Maths (Cycles' svm_math / svm_vector_math semantics, safe divisions, logarithms and roots).
OP_MATH = register(OpSpec("math", 10, _r("out", kind="out") + _r("a", "b", "c", kind="in")
                          + _r("operation", "clamp", kind="int"),
                          "Math node: operation = core.shading.evaluator.MATH_OPS index; clamp to [0, 1]")).code
OP_VECTOR_MATH = register(OpSpec("vector_math", 11, _r("vector", "value", kind="out?") + _r("a", "b", "c", "scale", kind="in")
                                 + _r("operation", kind="int"),
                                 "Vector Math node: operation = core.shading.evaluator.VECTOR_MATH_OPS index")).code
OP_MAP_RANGE = register(OpSpec("map_range", 12, _r("out", kind="out") + _r("value", "from_min", "from_max", "to_min",
                                                                          "to_max", "steps", kind="in")
                               + _r("interpolation", "clamp", "vector", kind="int"),
                               "Map Range node: interpolation 0 linear 1 stepped 2 smoothstep 3 smootherstep; "
                               "vector = 1 maps each component")).code
OP_CLAMP = register(OpSpec("clamp", 13, _r("out", kind="out") + _r("value", "min", "max", kind="in")
                           + _r("range", kind="int"), "Clamp node: range = 1 swaps min and max when min > max")).code
OP_SEPARATE_XYZ = register(OpSpec("separate_xyz", 14, _r("x", "y", "z", kind="out?") + _r("vector", kind="in"))).code
OP_COMBINE_XYZ = register(OpSpec("combine_xyz", 15, _r("out", kind="out") + _r("x", "y", "z", kind="in"))).code
OP_MAPPING = register(OpSpec("mapping", 16, _r("out", kind="out") + _r("vector", "location", "rotation", "scale",
                                                                      kind="in") + _r("type", kind="int"),
                             "Mapping node: type 0 point 1 texture 2 vector 3 normal; rotation XYZ Euler")).code
OP_MIX = register(OpSpec("mix", 17, _r("out", kind="out") + _r("factor", "a", "b", kind="in")
                         + _r("clamp", "per_component", kind="int"),
                         "Mix node (float, vector, colour blend Mix): out = a + f (b - a); per_component: the "
                         "factor is a vector")).code
OP_FRESNEL = register(OpSpec("fresnel", 18, _r("out", kind="out") + _r("ior", kind="in") + _r("normal", kind="in?"),
                             "Fresnel node: dielectric Fresnel of I.N, eta inverted on a back face")).code
OP_LAYER_WEIGHT = register(OpSpec("layer_weight", 19, _r("fresnel", "facing", kind="out?") + _r("blend", kind="in")
                                  + _r("normal", kind="in?"), "Layer Weight node")).code
# Shading-context inputs.
# bump / bump_width on the shading-context ops: the copy of a Bump node's Height subgraph that reads the point
# shifted along the surface by the ray differential (bump 1: dP.dx, 2: dP.dy) times the Bump's filter width
# (register bump_width), as Cycles' *_bump_dx/_bump_dy nodes; bump 0 reads the point itself.
_BUMP = (("bump", "int"), ("bump_width", "in?"))
OP_TEXCOORD = register(OpSpec("texture_coordinate", 30, _r("generated", "normal", "uv", "object", "camera", "window",
                                                          "reflection", kind="out?") + _BUMP,
                              "Texture Coordinate node outputs (object space: the hit object's)")).code
OP_GEOMETRY = register(OpSpec("geometry", 31, _r("position", "normal", "true_normal", "incoming", "backfacing",
                                                 "parametric", kind="out?") + _BUMP, "Geometry node outputs")).code
OP_OBJECT_INFO = register(OpSpec("object_info", 32, _r("location", "color", "alpha", "object_index", "random",
                                                       kind="out?"), "Object Info node outputs")).code
OP_UV_LAYER = register(OpSpec("uv_layer", 33, _r("out", kind="out") + _r("layer", kind="int") + _BUMP,
                              "UV Map node naming a map: layer = index into Scene.uv_layer_names")).code
OP_ATTRIBUTE = register(OpSpec("attribute", 34, _r("color", "alpha", "fac", kind="out?")
                                + _r("layer", "missing_alpha", kind="int"),
                                "Attribute / Color Attribute node: layer = index into Scene.attribute_names "
                                "(the per-point extras' attribute columns); a mesh without it reads 0, alpha "
                                "missing_alpha")).code
OP_LIGHT_PATH = register(OpSpec("light_path", 35, _r("is_camera", "is_shadow", "is_diffuse", "is_glossy",
                                                     "is_singular", "is_reflection", "is_transmission", "ray_length",
                                                     "ray_depth", "diffuse_depth", "glossy_depth",
                                                     "transparent_depth", "transmission_depth", kind="out?"),
                                 "Light Path node outputs from the per-point path state (core.shading.program "
                                 "PATH_*); without one: a camera ray of length 0")).code
# Images.
OP_IMAGE = register(OpSpec("image", 40, _r("color", "alpha", kind="out?") + _r("vector", kind="in?")
                           + _r("texture", kind="tex") + _r("interpolation", "extension", "flags", "projection",
                                                             kind="int") + _r("blend", kind="in?")
                           + _BUMP,
                           "Image Texture node: interpolation 0 linear 1 closest 2 cubic; "
                           "extension 0 repeat 1 extend 2 clip 3 mirror; flags bit 0: colour times alpha "
                           "(associate), bit 2: colour divided by alpha where 0 < alpha < 1 (unassociate; after "
                           "the weighted sum for box), bit 1: sRGB-decode the colour after filtering (and "
                           "association). vector -1: the UV map. projection 0 flat 1 box (Cycles' weights from "
                           "the object-space normal, blend: the Blend register, -1 = 0) 2 sphere 3 tube")).code
# Shader helpers (the Principled BSDF's derived lobe parameters).
OP_SPECULAR_LAYER = register(OpSpec("specular_layer", 50, _r("f0", "eta", kind="out") + _r("ior", "level", "tint",
                                                                                          kind="in"),
                                    "Principled specular layer: f0 = F0(IOR) 2 level tint (clamped), eta from f0 "
                                    "(Cycles' closure adjustment)")).code
OP_GLASS_F0 = register(OpSpec("glass_f0", 51, _r("out", kind="out") + _r("ior", "tint", kind="in"),
                              "Principled glass reflection f0 = F0(IOR) x tint, clamped to [0, 1]")).code
OP_SQRT_SATURATE = register(OpSpec("sqrt_saturate", 52, _r("out", kind="out") + _r("a", kind="in"),
                                   "per component sqrt(clamp(a, 0, 1)) (Principled transmission tint)")).code
OP_ONE_MINUS_SATURATE = register(OpSpec("one_minus_saturate", 53, _r("out", kind="out") + _r("a", kind="in"),
                                        "per component clamp(1 - a, 0, 1) (Principled metal Schlick tint)")).code
# Vector nodes: the shading normal (world space, on the viewer's side like the context's N).
OP_NORMAL_MAP = register(OpSpec("normal_map", 60, _r("normal", kind="out") + _r("color", "strength", kind="in")
                                + _r("space", "layer", "flip_y", kind="int"),
                                "Normal Map node (Cycles' svm_node_normal_map): colour 2 c - 1; space 0 tangent "
                                "(layer: index into Scene.tangent_layer_names, -1 or a mesh without it: N), 1 "
                                "object, 2 world, 3 / 4 Blender object / world (y and z negated); flip_y: DirectX "
                                "green channel; negated on a back face; strength scales the tangent-space offset "
                                "(other spaces: blends from N)")).code
OP_BUMP = register(OpSpec("bump", 61, _r("normal", kind="out") + _r("strength", "distance", "height", "height_dx",
                                                                     "height_dy", "filter_width", kind="in")
                          + _r("normal_in", kind="in?") + _r("invert", kind="int"),
                          "Bump node (Cycles' svm_node_set_bump): the heights at the point and shifted by the ray "
                          "differential's dP.dx / dP.dy times filter_width give the surface gradient; normal_in -1: "
                          "N")).code
OP_VECTOR_TRANSFORM = register(OpSpec("vector_transform", 62, _r("out", kind="out") + _r("vector", kind="in")
                                      + _r("type", "convert_from", "convert_to", kind="int")
                                      + _r("camera", kind="data"),
                                      "Vector Transform node (Cycles' svm_node_vector_transform): type 0 point 1 "
                                      "vector 2 normal (a direction, normalised); spaces 0 world 1 object 2 camera; "
                                      "camera: 24 floats in the data pool, world -> camera then camera -> world "
                                      "(3 x 4 row-major each, Cycles' camera space: +z forward)")).code
OP_TANGENT = register(OpSpec("tangent", 63, _r("out", kind="out") + _r("generated", kind="in?")
                             + _r("axis", "layer", kind="int"),
                             "Tangent node / Geometry's Tangent (Cycles' svm_node_tangent, primitive_tangent): layer "
                             ">= 0: the UV map's tangent layer (zero where a mesh lacks it); else radial about axis "
                             "0 x 1 y 2 z of the generated coordinates, taken to world space as a normal; then made "
                             "orthogonal to N")).code
# Output to a pass (core.shader_aovs): no register written, so the compiler keeps it as a sink and never folds it.
OP_AOV_OUTPUT = register(OpSpec("aov_output", 70, _r("value", kind="in") + _r("aov", kind="int"),
                                "AOV Output node (Cycles' svm_node_aov_color / _value): adds the value (a colour, or "
                                "a float in component 0) and a count of 1 to the point's AOV `aov` (an index into "
                                "Scene.shader_aovs) where the integrator asks for AOVs; nothing elsewhere")).code
