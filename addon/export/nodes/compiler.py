"""The node-tree compiler: one Blender material node tree -> a core.shading ShadingProgram (or constant lobes).

`ProgramBuilder` owns the register file, the instructions and the data pool of one material. Node rules
(addon/export/nodes/rules.py) read their inputs with `input()` and emit instructions with `emit()`; `emit` folds
an instruction whose inputs are all constant by running it at export through the compiled evaluator
(core.shading.evaluator.run_single), so constant subgraphs cost nothing per shading point and fold with exactly
the kernel's semantics. Links are followed through reroutes, muted links (the input's own value, as Blender),
muted nodes (their internal links pass the matching input through, as Blender), and node groups (inlined, nested:
a Group Input resolves to the group node's input in the enclosing tree).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ....core.shading import evaluator as ev
from ....core.shading import registry as R
from ....core.shading.program import N_BIND, WIDTH, ShadingProgram

MAX_DEPTH = 64
FLOAT, VECTOR, RGBA = "FLOAT", "VECTOR", "RGBA"
# Opcodes that read the shading context (or the -1 "context default" of an "in?" operand): never folded.
CONTEXT_OPS = {"texture_coordinate", "geometry", "object_info", "fresnel", "layer_weight", "attribute", "light_path",
               "normal_map", "bump", "tangent"}


def socket_kind(sock) -> str:
    """FLOAT, VECTOR, RGBA or SHADER for a Blender socket."""
    t = getattr(sock, "type", "VALUE")
    if t in ("VALUE", "INT", "BOOLEAN"):
        return FLOAT
    if t in ("VECTOR", "ROTATION"):
        return VECTOR
    if t == "RGBA":
        return RGBA
    return t


class CompileError(Exception):
    """Raised for a tree the compiler cannot express; the material falls back as documented."""


@dataclass
class Ctx:
    """Where a node sits: the chain of group nodes it was reached through (outermost first)."""

    groups: tuple = ()

    def key(self) -> tuple:
        return tuple(g.as_pointer() for g in self.groups)


@dataclass
class ProgramBuilder:
    owner: str
    warnings: list
    textures: list  # the exporter's Texture list (handles are indices into it)
    image_texture: object  # callable(node, alpha_used) -> (texture index or None, image op flags); warns itself
    material_pass_index: int = 0
    active_uv_names: tuple = ()
    uv_layer_index: object = None  # callable(name) -> index into Scene.uv_layer_names
    attribute_index: object = None  # callable(name) -> index into Scene.attribute_names
    attribute_uses: list = field(default_factory=list)  # (attribute name, "node 'X' (Label)") per read
    tangent_layer_index: object = None  # callable(UV map name, "" = active) -> index into Scene.tangent_layer_names
    # Inside a Bump node's Height subgraph copy: 1 / 2 = evaluated at the point shifted by dP.dx / dP.dy times the
    # filter width (register bump_width); the shading-context ops read it through their bump operands.
    bump: int = 0
    bump_width: int = -1
    camera_matrix: object = None  # the render camera's matrix_world (4 x 4), for Vector Transform's camera space
    registers: list = field(default_factory=list)  # initial values, (3,) float32 each
    varying: list = field(default_factory=list)  # per register: computed per point
    code: list = field(default_factory=list)
    data: list = field(default_factory=list)
    _consts: dict = field(default_factory=dict)
    _outputs: dict = field(default_factory=dict)  # (ctx key, node pointer) -> {output identifier: (reg, kind)}
    _depth: int = 0

    # ---------------------------------------------------------------------------------------- registers
    def const(self, value) -> int:
        v = np.zeros(3, np.float32)
        a = np.asarray(value, np.float64).reshape(-1)
        v[:] = a[0] if a.size == 1 else a[:3]
        if not np.all(np.isfinite(v)):
            v = np.nan_to_num(v, nan=0.0, posinf=3e38, neginf=-3e38).astype(np.float32)
        key = v.tobytes()
        r = self._consts.get(key)
        if r is None:
            r = self._consts[key] = self._new(v, False)
        return r

    def _new(self, value, varying: bool) -> int:
        self.registers.append(np.asarray(value, np.float32).reshape(3).copy())
        self.varying.append(varying)
        return len(self.registers) - 1

    @property
    def writes_aovs(self) -> bool:
        """Whether an AOV Output node was compiled (the material then needs a program, core.shader_aovs)."""
        return any(inst[0] == R.OP_AOV_OUTPUT for inst in self.code)

    def is_const(self, r: int) -> bool:
        return not self.varying[r]

    def value(self, r: int) -> np.ndarray:
        """The constant value of a constant register."""
        return self.registers[r]

    # ------------------------------------------------------------------------------------- instructions
    def emit(self, opname: str, varying: bool = False, **ops) -> dict:
        """Emit `opname` with operands by name (registers, ints; output operands are allocated here: pass
        name=True to want an "out?" output, outputs of kind "out" are always allocated). Returns {output name:
        register} (-1 for an unwanted "out?"). Folds the instruction at export when nothing in it varies."""
        spec = R.op(opname)
        inst = [-1] * WIDTH
        inst[0] = spec.code
        outs: dict = {}
        reads_context = varying or opname in CONTEXT_OPS
        if self.bump and any(name == "bump" for name, _ in spec.operands):
            ops.setdefault("bump", self.bump)
            ops.setdefault("bump_width", self.bump_width)
        for i, (name, kind) in enumerate(spec.operands):
            if name == "bump_width":  # a parameter of the bump copy, not a reason to evaluate per point
                inst[i + 1] = int(ops.get(name, -1))
                continue
            if kind in ("out", "out?"):
                want = kind == "out" or bool(ops.get(name))
                outs[name] = self._new(np.zeros(3), True) if want else -1
                inst[i + 1] = outs[name]
            elif kind in ("in", "in?"):
                r = int(ops.get(name, -1))
                if kind == "in" and r < 0:
                    raise CompileError(f"{opname}: input {name!r} missing")
                if r < 0 or self.varying[r]:
                    reads_context = reads_context or r < 0 or self.varying[r]
                inst[i + 1] = r
            else:
                inst[i + 1] = int(ops.get(name, 0 if kind == "int" else -1))
        if not reads_context:
            self._fold(inst, outs)
        else:
            self.code.append(inst)
        return outs

    def _fold(self, inst: list, outs: dict) -> None:
        """Run one instruction now and turn its outputs into constants."""
        prog = ShadingProgram(np.asarray([inst], np.int32), np.asarray(self.registers, np.float32).reshape(-1, 3),
                              np.zeros((0, N_BIND), np.int32), data=np.asarray(self.data, np.float32))
        regs = ev.run_single(prog, self.textures)
        for r in outs.values():
            if r >= 0:
                self.registers[r] = np.nan_to_num(regs[r], nan=0.0).astype(np.float32)
                self.varying[r] = False

    def add_data(self, values) -> int:
        at = len(self.data)
        self.data.extend(float(v) for v in np.asarray(values, np.float64).reshape(-1))
        return at

    # -------------------------------------------------------------------------------------- conversion
    def convert(self, r: int, src: str, want: str) -> int:
        """Blender's implicit socket conversion of register r from kind `src` to `want`."""
        if src == want or want == "ANY" or (src in (VECTOR, RGBA) and want in (VECTOR, RGBA)):
            return r
        if src == FLOAT:
            return self.emit("float_to_vec", a=r)["out"]
        if src == RGBA and want == FLOAT:
            return self.emit("color_to_float", a=r)["out"]
        if src == VECTOR and want == FLOAT:
            return self.emit("vec_to_float", a=r)["out"]
        raise CompileError(f"cannot convert a {src.lower()} to a {want.lower()}")

    # helpers for shader arithmetic (all fold when constant)
    def _is(self, r: int | None, value: float) -> bool:
        return r is not None and self.is_const(r) and bool(np.all(self.value(r) == value))

    def math(self, operation: str, a: int, b: int | None = None, c: int | None = None, clamp: bool = False) -> int:
        # identities of the shader arithmetic (x 1, + 0) emit nothing, so a plain weight costs no instruction
        if not clamp and operation == "MULTIPLY" and (self._is(a, 1.0) or self._is(b, 1.0)):
            return b if self._is(a, 1.0) else a
        if not clamp and operation == "ADD" and (self._is(a, 0.0) or self._is(b, 0.0)):
            return b if self._is(a, 0.0) else a
        zero = self.const(0.0)
        return self.emit("math", a=a, b=zero if b is None else b, c=zero if c is None else c,
                         operation=ev.MATH_OPS.index(operation), clamp=int(clamp))["out"]

    def vmath(self, operation: str, a: int, b: int | None = None, scale: int | None = None) -> int:
        if operation == "SCALE" and self._is(scale, 1.0):
            return a
        if operation == "ADD" and (self._is(a, 0.0) or self._is(b, 0.0)):
            return b if self._is(a, 0.0) else a
        zero = self.const(0.0)
        out = "value" if operation in ev.VECTOR_MATH_VALUE_OPS else "vector"
        return self.emit("vector_math", a=a, b=zero if b is None else b, c=zero, scale=zero if scale is None else scale,
                         operation=ev.VECTOR_MATH_OPS.index(operation), **{out: True})[out]

    # -------------------------------------------------------------------------------------------- links
    def warn(self, node, what: str) -> None:
        msg = f"{self.owner}: node {node.name!r} ({node.bl_label}): {what}"
        if msg not in self.warnings:
            self.warnings.append(msg)

    def source(self, sock, ctx: Ctx):
        """What feeds input socket `sock` in context `ctx`: ("socket", node, output socket, ctx) for a real node's
        output, or ("default", socket) whose default value applies (unlinked, muted link, dead end)."""
        for _ in range(MAX_DEPTH):
            links = [lk for lk in sock.links] if sock.is_linked else []
            if not links:
                return ("default", sock, ctx)
            link = links[0]
            if getattr(link, "is_muted", False) or not link.is_valid:
                return ("default", sock, ctx)
            node, out = link.from_node, link.from_socket
            found = self._through(node, out, ctx)
            if found[0] == "input":
                sock, ctx = found[1], found[2]
                continue
            return found
        raise CompileError(f"links nest deeper than {MAX_DEPTH} (a cycle?)")

    def _through(self, node, out, ctx: Ctx):
        """Resolve an output socket: reroutes, muted nodes, groups; ("input", sock, ctx) to continue from an input
        socket, else a final ("socket", ...)/("default", ...)."""
        for _ in range(MAX_DEPTH):
            kind = node.bl_idname
            if kind == "NodeReroute":
                return ("input", node.inputs[0], ctx)
            if getattr(node, "mute", False):
                for link in node.internal_links:
                    if link.to_socket == out or link.to_socket.identifier == out.identifier:
                        return ("input", link.from_socket, ctx)
                return ("default", out, ctx)
            if kind == "NodeGroupInput":
                if not ctx.groups:
                    return ("default", out, ctx)
                group_node = ctx.groups[-1]
                outer = Ctx(ctx.groups[:-1])
                sock = _socket_by_identifier(group_node.inputs, out.identifier)
                if sock is None:
                    return ("default", out, ctx)
                return ("input", sock, outer)
            if kind == "ShaderNodeGroup":
                tree = node.node_tree
                if tree is None:
                    return ("default", out, ctx)
                if len(ctx.groups) >= MAX_DEPTH // 4:
                    raise CompileError(f"node groups nest deeper than {MAX_DEPTH // 4}")
                group_out = _active_group_output(tree)
                if group_out is None:
                    return ("default", out, ctx)
                sock = _socket_by_identifier(group_out.inputs, out.identifier)
                if sock is None:
                    return ("default", out, ctx)
                return ("input", sock, Ctx(ctx.groups + (node,)))
            return ("socket", node, out, ctx)
        raise CompileError("too many nested reroutes/groups")

    def input(self, node, key, want: str, ctx: Ctx) -> int:
        """The register of input `key` (index, identifier or name) of `node`, converted to `want`."""
        sock = find_input(node, key)
        if sock is None:
            raise CompileError(f"node {node.name!r} has no input {key!r}")
        return self.socket_value(sock, want, ctx)

    def socket_value(self, sock, want: str, ctx: Ctx) -> int:
        found = self.source(sock, ctx)
        if found[0] == "default":
            return self.convert(self.const(default_value(found[1])), socket_kind(found[1]), want)
        _, node, out, octx = found
        from .registry import RULES

        if node.bl_idname not in RULES:
            # The documented fallback of an unsupported node: the input it drives keeps its own value.
            self.warn(node, f"is not supported by Monte; {sock.name!r} uses its own value "
                            f"{np.round(np.asarray(default_value(sock)), 4).tolist()}")
            return self.convert(self.const(default_value(sock)), socket_kind(sock), want)
        r, kind = self.output(node, out, octx)
        return self.convert(r, kind, want)

    def output_used(self, node, name: str, ctx: Ctx) -> bool:
        """Whether an output socket (by name or identifier) of `node` is linked to anything."""
        return any(s.is_linked for s in node.outputs if (s.name == name or s.identifier == name)
                   and getattr(s, "enabled", True))

    def is_linked(self, node, key, ctx: Ctx) -> bool:
        sock = find_input(node, key)
        return sock is not None and self.source(sock, ctx)[0] == "socket"

    def output(self, node, out, ctx: Ctx) -> tuple[int, str]:
        """(register, kind) of output socket `out` of a real node, compiling the node once per context."""
        from .registry import RULES

        key = (ctx.key(), node.as_pointer(), self.bump, self.bump_width)
        done = self._outputs.get(key)
        if done is None:
            rule = RULES.get(node.bl_idname)
            self._depth += 1
            if self._depth > MAX_DEPTH:
                raise CompileError("the node graph nests too deeply")
            try:
                if rule is None or rule.compile is None:
                    done = {}
                    self.warn(node, "is not supported by Monte; its outputs read as their default values "
                                    "(0 / black unless the socket shows a value)")
                else:
                    done = rule.compile(self, node, ctx)
            finally:
                self._depth -= 1
            self._outputs[key] = done
        ident = out.identifier
        if ident in done:
            return done[ident]
        if out.name in done:
            return done[out.name]
        if out.bl_idname != "NodeSocketShader":
            rule = RULES.get(node.bl_idname)
            if rule is not None and rule.compile is not None:
                self.warn(node, f"output {out.name!r} is not supported; it reads as its default value")
        return self.const(default_value(out)), socket_kind(out)

    # ----------------------------------------------------------------------------------------- finishing
    def finish(self, lobes_bind: np.ndarray, emission: int, normal: int = -1) -> ShadingProgram:
        """The program computing the bound registers: dead instructions removed, registers renumbered."""
        needed = {int(r) for r in lobes_bind.reshape(-1) if r >= 0}
        if emission >= 0:
            needed.add(emission)
        if normal >= 0:
            needed.add(normal)
        keep = []
        for inst in reversed(self.code):
            spec = R.OPS[inst[0]]
            outs = [inst[i + 1] for i, (_, k) in enumerate(spec.operands) if k in ("out", "out?") and inst[i + 1] >= 0]
            if any(o in needed for o in outs) or inst[0] == R.OP_AOV_OUTPUT:  # an AOV write is a sink: kept
                keep.append(inst)
                needed.update(inst[i + 1] for i, (_, k) in enumerate(spec.operands)
                              if k in ("in", "in?") and inst[i + 1] >= 0)
        keep.reverse()
        used = sorted(needed | {inst[i + 1] for inst in keep for i, (_, k) in enumerate(R.OPS[inst[0]].operands)
                                if k in ("out", "out?") and inst[i + 1] >= 0})
        renum = {old: new for new, old in enumerate(used)}
        code = []
        for inst in keep:
            spec = R.OPS[inst[0]]
            row = list(inst)
            for i, (_, k) in enumerate(spec.operands):
                if k in ("in", "in?", "out", "out?") and row[i + 1] >= 0:
                    row[i + 1] = renum[row[i + 1]]
            code.append(row)
        regs = np.asarray([self.registers[r] for r in used], np.float32).reshape(-1, 3)
        bind = np.vectorize(lambda r: renum[int(r)] if r >= 0 else -1, otypes=[np.int32])(lobes_bind) \
            if lobes_bind.size else lobes_bind.astype(np.int32)
        return ShadingProgram(np.asarray(code, np.int32).reshape(-1, WIDTH), regs, bind.reshape(-1, N_BIND),
                              renum[emission] if emission >= 0 else -1, np.asarray(self.data, np.float32),
                              renum[normal] if normal >= 0 else -1)

    def bump_copy(self, which: int, width: int):
        """Context manager: compile inside it as the Bump node's Height copy `which` (1: dP.dx, 2: dP.dy) with
        filter width register `width`."""
        from contextlib import contextmanager

        @contextmanager
        def scope():
            saved = (self.bump, self.bump_width)
            self.bump, self.bump_width = which, width
            try:
                yield
            finally:
                self.bump, self.bump_width = saved

        return scope()


def _socket_by_identifier(sockets, identifier: str):
    for s in sockets:
        if s.identifier == identifier:
            return s
    return None


def _active_group_output(tree):
    outs = [n for n in tree.nodes if n.bl_idname == "NodeGroupOutput"]
    for n in outs:
        if getattr(n, "is_active_output", False):
            return n
    return outs[0] if outs else None


def find_input(node, key):
    """An input socket by index, identifier or name (the first ENABLED socket of that name: Blender keeps
    several sockets of one name on nodes whose data type switches, e.g. Mix's A/B)."""
    if isinstance(key, int):
        return node.inputs[key] if key < len(node.inputs) else None
    for s in node.inputs:
        if s.identifier == key:
            return s
    for s in node.inputs:
        if s.name == key and getattr(s, "enabled", True):
            return s
    return node.inputs.get(key)


def default_value(sock):
    """A socket's own value as floats (a colour's RGB, a vector's XYZ, a float; 0 where it has none)."""
    v = getattr(sock, "default_value", None)
    if v is None:
        return 0.0
    try:
        a = [float(x) for x in v]
        return a[:3] if len(a) >= 3 else (a + [0.0] * 3)[:3]
    except TypeError:
        return float(v)
