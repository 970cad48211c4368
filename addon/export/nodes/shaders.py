"""Shader nodes -> Monte lobes whose parameters may vary per shading point.

The closure tree's SHAPE (which lobes a material has) is fixed at export; every lobe parameter is a register of
the material's program (a constant when it folds). Mix Shader factors, Principled inputs and colours may all be
driven by nodes: the lobe weights are products down the tree evaluated per point.

Principled BSDF (as the constant mapping it generalises, see addon/export/material.py's docstring): specular
layer (generalized Schlick, f0 and eta per point through the specular_layer opcode), diffuse under it, metal as
base + (1 - base) Schlick (both lobes per point, so a textured base colour keeps the full Schlick tint), glass
with sqrt(base) transmission tint, alpha as a straight pass-through, emission colour x strength x alpha.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ....core.shading.program import (BIND_F0, BIND_IOR, BIND_ROUGHNESS, BIND_TINT_R, BIND_TINT_T, BIND_WEIGHT,
                                      N_BIND)
from ....core.scene import Lobe
from .compiler import FLOAT, RGBA, VECTOR, MAX_DEPTH, CompileError, Ctx
from .registry import document

SHADERS = {
    "ShaderNodeBsdfDiffuse": ("Diffuse BSDF", ("Color", "Roughness (0 only)", "Normal"),
                              "Lambertian: Oren-Nayar roughness > 0 warns and is ignored."),
    "ShaderNodeBsdfGlossy": ("Glossy BSDF", ("Color", "Roughness", "Normal"),
                             "Multiscatter GGX for every distribution; anisotropy warns and is ignored."),
    "ShaderNodeBsdfAnisotropic": ("Anisotropic BSDF", ("Color", "Roughness", "Normal"), "As Glossy (isotropic)."),
    "ShaderNodeBsdfGlass": ("Glass BSDF", ("Color", "Roughness", "IOR", "Normal"), ""),
    "ShaderNodeBsdfRefraction": ("Refraction BSDF", ("Color", "Roughness", "IOR", "Normal"), ""),
    "ShaderNodeBsdfTransparent": ("Transparent BSDF", ("Color",), ""),
    "ShaderNodeEmission": ("Emission", ("Color", "Strength"),
                           "A varying emission is light-sampled by its own table (triangles chosen by area x "
                           "an emission estimate, the emission evaluated per point) with MIS; a light sample runs the "
                           "program as Cycles does (Light Path: no ray-kind flag, Ray Depth + 1)."),
    "ShaderNodeMixShader": ("Mix Shader", ("Fac", "Shader", "Shader"), "The factor may vary per point."),
    "ShaderNodeAddShader": ("Add Shader", ("Shader", "Shader"), ""),
    "ShaderNodeHoldout": ("Holdout", (), "Camera rays (and rays through transparent surfaces) see zero colour and "
                          "zero alpha; other rays see nothing. A weight that varies per point warns and is ignored."),
    "ShaderNodeBsdfPrincipled": ("Principled BSDF",
                                 ("Base Color", "Metallic", "Roughness", "IOR", "Alpha", "Transmission Weight",
                                  "Specular IOR Level", "Specular Tint", "Emission Color", "Emission Strength",
                                  "Normal"),
                                 "Coat, sheen, anisotropy and thin film are ignored (warning when used); "
                                 "subsurface renders as diffuse (warning)."),
}
_NORMAL_NOTE = ("Normal (Normal Map, Bump, ...): one shading normal per material point, the first BSDF's linked "
                "Normal (a warning names a BSDF whose Normal differs); Cycles' bump-map correction of the "
                "reflection applies where the material has glossy or glass lobes.")
for _idname, (_label, _inputs, _notes) in SHADERS.items():
    if "Normal" in _inputs:
        _notes = f"{_notes} {_NORMAL_NOTE}".strip()
    document(_idname, _label, "shader", inputs=_inputs, outputs=("BSDF",), notes=_notes)
document("ShaderNodeOutputMaterial", "Material Output", "output", inputs=("Surface",),
         notes="The active output for Cycles (target Cycles or All). Volume and Displacement warn and are ignored.")
document("ShaderNodeOutputAOV", "AOV Output", "output", inputs=("Color", "Value"),
         notes="Writes the view layer's shader AOV of its name (Color for a COLOR AOV, Value for a VALUE one) where "
               "camera paths are primary (core.shader_aovs); nodes in node groups and in the world are not "
               "evaluated (warning); an AOV the view layer does not list is not written, as in Cycles.")


class UnsupportedShader(Exception):
    """Raised inside the shader walk: the whole material falls back to its viewport colour (documented)."""

    def __init__(self, node, why: str = "is not supported by Monte") -> None:
        super().__init__(f"node {node.name!r} ({node.bl_label}) {why}")


@dataclass
class LobeSpec:
    kind: str
    weight: int  # RGBA register
    fresnel: str = "none"
    roughness: int | None = None
    ior: int | None = None
    f0: int | None = None
    reflection_tint: int | None = None
    transmission_tint: int | None = None
    under: int = -1


class ShaderWalk:
    """Collects the lobes and emission of a material's surface shader tree into a ProgramBuilder."""

    def __init__(self, c) -> None:
        self.c = c
        self.lobes: list[LobeSpec] = []
        self.emission = c.const(0.0)
        self.holdout = 0.0  # Holdout shader weight (core.scene.Material.holdout); constant weights only
        self.normals: list = []  # (BSDF node, its Normal input's register or -1 when unlinked), in walk order

    # ---------------------------------------------------------------------------------------------- walk
    def surface(self, sock, ctx: Ctx) -> None:
        self._socket(sock, ctx, self.c.const(1.0), 0)

    def _socket(self, sock, ctx: Ctx, w: int, depth: int) -> None:
        found = self.c.source(sock, ctx)
        if found[0] == "default":
            return  # an unlinked shader socket: nothing (Cycles renders it black)
        self.shader(found[1], found[3], w, depth)

    def shader(self, node, ctx: Ctx, w: int, depth: int) -> None:
        c = self.c
        if depth > MAX_DEPTH:
            raise UnsupportedShader(node, "nests too deeply")
        if c.is_const(w) and not np.any(c.value(w) != 0):
            return
        kind = node.bl_idname
        if kind == "ShaderNodeMixShader":
            fac = c.math("MINIMUM", c.math("MAXIMUM", c.input(node, 0, FLOAT, ctx), c.const(0.0)), c.const(1.0))
            self._socket(node.inputs[1], ctx, c.math("MULTIPLY", w, c.math("SUBTRACT", c.const(1.0), fac)), depth + 1)
            self._socket(node.inputs[2], ctx, c.math("MULTIPLY", w, fac), depth + 1)
            return
        if kind == "ShaderNodeAddShader":
            self._socket(node.inputs[0], ctx, w, depth + 1)
            self._socket(node.inputs[1], ctx, w, depth + 1)
            return
        if kind == "ShaderNodeHoldout":
            if c.is_const(w):
                self.holdout += float(np.mean(c.value(w)))
            else:
                c.warn(node, "a Holdout weighted by a factor that varies per point is not supported; ignored")
            return
        if kind == "ShaderNodeEmission":
            e = c.vmath("SCALE", c.input(node, "Color", RGBA, ctx), scale=c.math(
                "MULTIPLY", w, c.input(node, "Strength", FLOAT, ctx)))
            self.emission = c.vmath("ADD", self.emission, e)
            return
        self._check_normal(node, ctx)
        if kind == "ShaderNodeBsdfDiffuse":
            rough = c.input(node, "Roughness", FLOAT, ctx)
            if not c.is_const(rough) or c.value(rough)[0] > 0:
                c.warn(node, "Oren-Nayar roughness is not supported; rendered as Lambertian")
            self.lobes.append(LobeSpec("diffuse", self._weighted(node, "Color", w, ctx)))
            return
        if kind in ("ShaderNodeBsdfAnisotropic", "ShaderNodeBsdfGlossy"):
            aniso = node.inputs.get("Anisotropy")
            if aniso is not None:
                a = c.input(node, "Anisotropy", FLOAT, ctx)
                if not c.is_const(a) or c.value(a)[0] != 0:
                    c.warn(node, "anisotropy is not supported; rendered isotropic")
            self.lobes.append(LobeSpec("glossy", self._weighted(node, "Color", w, ctx),
                                       roughness=c.input(node, "Roughness", FLOAT, ctx)))
            return
        if kind in ("ShaderNodeBsdfGlass", "ShaderNodeBsdfRefraction"):
            self.lobes.append(LobeSpec("glass" if kind == "ShaderNodeBsdfGlass" else "refraction",
                                       self._weighted(node, "Color", w, ctx),
                                       roughness=c.input(node, "Roughness", FLOAT, ctx),
                                       ior=c.input(node, "IOR", FLOAT, ctx)))
            return
        if kind == "ShaderNodeBsdfTransparent":
            self.lobes.append(LobeSpec("refraction", self._weighted(node, "Color", w, ctx), roughness=c.const(0.0),
                                       ior=c.const(1.0)))
            return
        if kind == "ShaderNodeBsdfPrincipled":
            self._principled(node, ctx, w)
            return
        raise UnsupportedShader(node)

    def _weighted(self, node, colour: str, w: int, ctx: Ctx) -> int:
        return self.c.vmath("SCALE", self.c.input(node, colour, RGBA, ctx), scale=w)

    def _check_normal(self, node, ctx: Ctx) -> None:
        """Record the BSDF's Normal input (a Normal Map, Bump, ... output): the material's shading normal."""
        if node.inputs.get("Normal") is None:
            return
        reg = -1
        if self.c.is_linked(node, "Normal", ctx):
            reg = self.c.input(node, "Normal", VECTOR, ctx)
        self.normals.append((node, reg))

    def shading_normal(self) -> int:
        """The register of the material's shading normal, or -1. Monte shades all BSDFs of a point in one frame:
        the first linked Normal input drives them all (a warning names a BSDF whose Normal differs)."""
        linked = [(node, r) for node, r in self.normals if r >= 0]
        if not linked:
            return -1
        first_node, first = linked[0]
        for node, r in self.normals:
            if r != first:
                what = "is unlinked" if r < 0 else "differs"
                self.c.warn(node, f"its Normal input {what}; Monte shades all BSDFs of a material with one normal, "
                                  f"that of {first_node.name!r}")
        return first

    def _principled(self, node, ctx: Ctx, w: int) -> None:
        c = self.c

        def val(name: str, default: float = 0.0) -> int:
            return c.input(node, name, FLOAT, ctx) if node.inputs.get(name) is not None else c.const(default)

        def sat(r: int) -> int:
            return c.math("MINIMUM", c.math("MAXIMUM", r, c.const(0.0)), c.const(1.0))

        def one_minus(r: int) -> int:
            return c.math("SUBTRACT", c.const(1.0), r)

        def used(name: str) -> bool:
            if node.inputs.get(name) is None:
                return False
            r = val(name)
            return not c.is_const(r) or c.value(r)[0] > 0

        base = c.input(node, "Base Color", RGBA, ctx)
        metallic = sat(val("Metallic"))
        rough = val("Roughness", 0.5)
        ior = c.input(node, "IOR", FLOAT, ctx)
        if c.is_const(ior) and not (np.isfinite(c.value(ior)[0]) and c.value(ior)[0] > 0):
            c.warn(node, f"IOR {c.value(ior)[0]:g} is not physical; using 1.5")
            ior = c.const(1.5)
        transmission = sat(val("Transmission Weight") if node.inputs.get("Transmission Weight") is not None
                           else val("Transmission"))
        alpha = sat(val("Alpha", 1.0))
        level = c.math("MAXIMUM", val("Specular IOR Level", 0.5), c.const(0.0))
        tint_sock = node.inputs.get("Specular Tint")
        tint = c.input(node, "Specular Tint", RGBA, ctx) if tint_sock is not None and tint_sock.type == "RGBA" \
            else c.const(1.0)
        for name, what in (("Coat Weight", "coat"), ("Sheen Weight", "sheen"), ("Anisotropic", "anisotropy"),
                           ("Thin Film Thickness", "thin film")):
            if used(name):
                c.warn(node, f"{what} is not supported and is ignored")
        if used("Subsurface Weight"):
            c.warn(node, "subsurface scattering is not supported; rendered as diffuse")

        a = c.math("MULTIPLY", w, alpha)
        dielectric = c.math("MULTIPLY", one_minus(metallic), one_minus(transmission))
        ad = c.math("MULTIPLY", a, dielectric)
        if not self._zero(ad):
            spec = c.emit("specular_layer", ior=ior, level=level, tint=tint)
            eta = spec["eta"]
            under = -1
            if not (c.is_const(eta) and c.value(eta)[0] == 1.0):
                under = len(self.lobes)
                self.lobes.append(LobeSpec("glossy", c.convert(ad, FLOAT, RGBA), fresnel="generalized_schlick",
                                           roughness=rough, ior=eta, f0=spec["f0"]))
            self.lobes.append(LobeSpec("diffuse", c.vmath("SCALE", base, scale=ad), under=under))
        am = c.math("MULTIPLY", a, metallic)
        if not self._zero(am):
            self.lobes.append(LobeSpec("glossy", c.vmath("SCALE", base, scale=am), roughness=rough))
            schlick = c.vmath("SCALE", c.emit("one_minus_saturate", a=base)["out"], scale=am)
            self.lobes.append(LobeSpec("glossy", schlick, fresnel="schlick", roughness=rough, ior=c.const(1.0)))
        at = c.math("MULTIPLY", c.math("MULTIPLY", a, one_minus(metallic)), transmission)
        if not self._zero(at):
            self.lobes.append(LobeSpec("glass", c.convert(at, FLOAT, RGBA), fresnel="generalized_schlick",
                                       roughness=rough, ior=ior, f0=c.emit("glass_f0", ior=ior, tint=tint)["out"],
                                       transmission_tint=c.emit("sqrt_saturate", a=base)["out"]))
        clear = c.math("MULTIPLY", w, one_minus(alpha))
        if not self._zero(clear):
            self.lobes.append(LobeSpec("refraction", c.convert(clear, FLOAT, RGBA), roughness=c.const(0.0),
                                       ior=c.const(1.0)))
        strength = val("Emission Strength", 1.0) if node.inputs.get("Emission Strength") is not None \
            else c.const(1.0)
        if not self._zero(strength):
            ecol = c.input(node, "Emission Color" if node.inputs.get("Emission Color") is not None else "Emission",
                           RGBA, ctx)
            e = c.vmath("SCALE", ecol, scale=c.math("MULTIPLY", a, strength))
            self.emission = c.vmath("ADD", self.emission, e)

    def _zero(self, r: int) -> bool:
        return self.c.is_const(r) and not np.any(self.c.value(r) != 0)

    # ------------------------------------------------------------------------------------------- result
    def lobes_and_bindings(self) -> tuple[list[Lobe], np.ndarray]:
        """Template lobes (constant values, or placeholders where a register varies) and the (L, N_BIND)
        binding table; lobes whose weight is constant black are dropped (`under` renumbered)."""
        c = self.c
        keep = [i for i, s in enumerate(self.lobes) if not self._zero(s.weight)]
        new_index = {old: new for new, old in enumerate(keep)}
        lobes, bind = [], np.full((len(keep), N_BIND), -1, np.int32)
        for j, i in enumerate(keep):
            s = self.lobes[i]
            kw: dict = {"fresnel": s.fresnel, "under": new_index.get(s.under, -1)}
            for field_name, slot, reg, placeholder in (
                    ("color", BIND_WEIGHT, s.weight, np.ones(3)),
                    ("roughness", BIND_ROUGHNESS, s.roughness, 0.5),
                    ("ior", BIND_IOR, s.ior, 1.5),
                    ("f0", BIND_F0, s.f0, None),
                    ("reflection_tint", BIND_TINT_R, s.reflection_tint, None),
                    ("transmission_tint", BIND_TINT_T, s.transmission_tint, np.ones(3))):
                if reg is None:
                    continue
                if c.is_const(reg):
                    v = c.value(reg).astype(np.float64)
                    if field_name == "roughness":
                        kw[field_name] = float(min(max(v[0], 0.0), 1.0))
                    elif field_name == "ior":
                        kw[field_name] = float(max(v[0], 1e-5))
                    elif field_name in ("color", "reflection_tint", "transmission_tint"):
                        kw[field_name] = np.maximum(v, 0.0)
                    else:
                        kw[field_name] = np.clip(v, 0.0, 1.0)
                else:
                    bind[j, slot] = reg
                    if placeholder is not None:
                        kw[field_name] = placeholder
                    elif field_name == "f0":
                        kw[field_name] = np.full(3, 0.04)
            lobes.append(Lobe(s.kind, **kw))
        return lobes, bind


def compile_surface(c, output_node) -> tuple[list[Lobe], np.ndarray, int, float, int]:
    """(template lobes, bindings, emission register, holdout weight in [0, 1], shading-normal register or -1) of
    a Material Output's Surface input."""
    walk = ShaderWalk(c)
    sock = output_node.inputs["Surface"]
    walk.surface(sock, Ctx())
    lobes, bind = walk.lobes_and_bindings()
    normal = walk.shading_normal() if lobes else -1
    return lobes, bind, walk.emission, min(max(walk.holdout, 0.0), 1.0), normal


def compile_aov_outputs(c, tree, aovs: dict) -> int:
    """Emit an aov_output instruction for each AOV Output node of the material's tree (its top level, target
    Cycles or All, not muted) whose name the view layer lists: aovs {name: (index into Scene.shader_aovs,
    "COLOR" | "VALUE")}; the node's Color or Value input by the AOV's type, as Cycles. Returns how many."""
    count = 0
    for node in tree.nodes:
        if node.bl_idname == "ShaderNodeGroup" and _group_has_aov_output(node.node_tree):
            c.warn(node, "AOV Output nodes inside node groups are not evaluated by Monte; their AOVs are not "
                         "written")
        if node.bl_idname != "ShaderNodeOutputAOV" or node.mute or getattr(node, "target", "ALL") == "EEVEE":
            continue
        found = aovs.get(node.aov_name)
        if found is None:
            continue
        index, kind = found
        try:
            value = c.input(node, "Color", RGBA, Ctx()) if kind == "COLOR" else c.input(node, "Value", FLOAT, Ctx())
        except (CompileError, UnsupportedShader) as exc:  # the node's AOV only; the material renders as it is
            c.warn(node, f"{exc}; its AOV {node.aov_name!r} is not written")
            continue
        c.emit("aov_output", value=value, aov=index, varying=True)
        count += 1
    return count


def _group_has_aov_output(tree, depth: int = 0) -> bool:
    if tree is None or depth > 16:
        return False
    return any(n.bl_idname == "ShaderNodeOutputAOV" or (n.bl_idname == "ShaderNodeGroup"
                                                       and _group_has_aov_output(n.node_tree, depth + 1))
               for n in tree.nodes)


__all__ = ["compile_surface", "compile_aov_outputs", "UnsupportedShader", "CompileError"]
