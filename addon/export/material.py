"""Blender materials (node trees) -> core Materials (sums of lobes plus emission) and Textures.

What is read, starting from the active Material Output (target Cycles/All) Surface socket:

- Principled BSDF, approximated by a sum of Monte lobes (all multiplied by Alpha):
    specular  glossy GGX, weight (1 - metallic)(1 - transmission), Cycles' generalized-Schlick Fresnel: the
              exact dielectric Fresnel of eta remapped from [F0(eta), 1] to [f0 x Specular Tint, 1], with
              f0 = F0(IOR) x 2 x Specular IOR Level and eta the IOR of that f0 (eta = IOR at the default 0.5);
              absent when f0 = 0 (eta = 1), as in Cycles
    diffuse   base colour x (1 - metallic)(1 - transmission), lying `under` the specular lobe: scaled per hit
              by 1 - max_c of the specular layer's albedo estimate at the view angle (Cycles 4.x/5.0 layering)
    metal     Schlick's Fresnel on the base colour (what Blender's F82 model reduces to with a white tint):
              a glossy GGX lobe of base colour x metallic without Fresnel plus one with Schlick F0 = 0 tinted
              (1 - base colour) x metallic; with a textured base colour only the first (darker at grazing)
    glass     glass GGX with IOR, weight (1 - metallic) x transmission, as Cycles' glass closure: reflection
              with the generalized-Schlick Fresnel of F0(IOR) x Specular Tint (no Specular IOR Level),
              transmission (1 - F) x sqrt(base colour)
    alpha     refraction with IOR 1 (a straight pass-through) weighted 1 - alpha
    emission  Emission Color x Emission Strength
  Coat, sheen, subsurface (rendered as diffuse), anisotropy, thin film and normal/bump maps are not
  supported: a warning names each one that is in use.
- Diffuse, Glossy (no Fresnel), Glass, Refraction, Transparent and Emission shaders.
- Mix Shader (constant factor) and Add Shader of those: weights multiply down the tree.
- Colour inputs: a constant, an RGB node, or an Image Texture on the active UV map (pixels loaded with
  foreach_get, converted to linear; image alpha ignored). Scalar inputs: a constant or a Value node.
- Reroutes are followed.

Anything else gives a warning naming the material and the node, and a documented fallback: an unsupported
shader makes the whole material a diffuse of the material's viewport colour (Viewport Display > Color); an
unsupported node driving an input uses that socket's own value. No node tree: the viewport colour as
diffuse. An empty material slot: a default grey (0.8) diffuse, as Cycles renders it.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.scene import Lobe, Material, Texture

DEFAULT_GREY = 0.8


def node_tree(idblock):
    """The node tree Blender renders with: in Blender < 5 only when "Use Nodes" is on (5.0 deprecates the
    flag: node trees are always used)."""
    tree = getattr(idblock, "node_tree", None)
    if tree is None:
        return None
    import bpy

    if bpy.app.version < (5, 0, 0) and not getattr(idblock, "use_nodes", True):
        return None
    return tree
_MAX_DEPTH = 64


class UnsupportedShader(Exception):
    """Raised inside the tree walk: the material falls back to its viewport colour."""

    def __init__(self, node, why: str = "is not supported by Monte") -> None:
        super().__init__(f"node {node.name!r} ({node.bl_label}) {why}")


def follow_link(socket):
    """The node feeding `socket` (through reroutes and muted-free links), or None if unlinked."""
    seen = 0
    while socket is not None and socket.is_linked and seen < _MAX_DEPTH:
        link = socket.links[0]
        if not link.is_valid or link.is_muted:
            return None
        node = link.from_node
        if node.bl_idname == "NodeReroute":
            socket = node.inputs[0]
            seen += 1
            continue
        if node.mute:
            # A muted node passes its first matching input through; treat as unlinked.
            return None
        return node
    return None


def _from_socket(socket):
    """The output socket feeding `socket` (through reroutes), or None."""
    seen = 0
    while socket is not None and socket.is_linked and seen < _MAX_DEPTH:
        link = socket.links[0]
        if link.from_node.bl_idname == "NodeReroute":
            socket = link.from_node.inputs[0]
            seen += 1
            continue
        return link.from_socket
    return None


def socket_value(sock, owner: str, warnings: list[str]):
    """A scalar input: its own value, or a Value node's; anything else warns and uses the socket's value."""
    if sock is None:
        return 0.0
    src = follow_link(sock)
    if src is None:
        return float(sock.default_value)
    if src.bl_idname == "ShaderNodeValue":
        return float(src.outputs[0].default_value)
    warnings.append(f"{owner}: node {src.name!r} ({src.bl_label}) driving {sock.name!r} is not supported; "
                    f"using the socket's value {float(sock.default_value):g}")
    return float(sock.default_value)


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


_LINEAR_SPACES = {"linear", "linear rec.709", "non-color", "raw", "linear rec.2020", "linear cie-xyz e",
                  "linear cie-xyz d65", "scene linear", "linear srgb"}


def image_pixels(image, warnings: list[str] | None = None) -> np.ndarray:
    """An image's pixels as (H, W, 3) float32 linear RGB, row 0 at the TOP (Blender stores row 0 at the
    bottom). One foreach_get call; 8-bit sRGB images are converted to linear."""
    w, h = int(image.size[0]), int(image.size[1])
    if w == 0 or h == 0:
        raise ValueError(f"image {image.name!r} has no pixels (missing file {image.filepath!r}?)")
    ch = int(image.channels)
    buf = np.empty(w * h * ch, dtype=np.float32)
    image.pixels.foreach_get(buf)
    px = buf.reshape(h, w, ch)[::-1]
    if ch >= 3:
        rgb = px[..., :3]
    else:
        rgb = np.repeat(px[..., :1], 3, axis=2)
    space = image.colorspace_settings.name.lower()
    if not image.is_float and space not in _LINEAR_SPACES:
        if space != "srgb" and warnings is not None:
            warnings.append(f"image {image.name!r}: colour space {image.colorspace_settings.name!r} is treated "
                            "as sRGB")
        rgb = srgb_to_linear(rgb)
    return np.ascontiguousarray(rgb, dtype=np.float32)


def image_average_color(image) -> np.ndarray:
    try:
        return image_pixels(image).reshape(-1, 3).mean(axis=0).astype(np.float64)
    except ValueError:
        return np.zeros(3)


def specular_layer(ior: float, level: float) -> tuple[float, float]:
    """(f0, eta) of the Principled specular layer, as Cycles' closure.h adjusts them: f0 = F0(IOR) x 2 x Specular
    IOR Level and, when the level is not 0.5, eta re-derived from that f0 (clamped to 0.99), inverted for IOR < 1.
    eta = 1 means there is no specular layer."""
    r = (ior - 1.0) / (ior + 1.0)
    f0 = r * r
    eta = ior
    if level != 0.5:
        f0 *= 2.0 * level
        c = math.sqrt(min(max(f0, 0.0), 0.99))
        eta = (1.0 + c) / (1.0 - c)
        if ior < 1.0:
            eta = 1.0 / eta
    return f0, eta


def _drop_black_lobes(lobes: list[Lobe]) -> list[Lobe]:
    """The lobes with some non-zero colour, their `under` indices renumbered (a lobe under a dropped layer keeps
    its full weight, as it would with a black layer above)."""
    keep = [i for i, lobe in enumerate(lobes) if np.any(lobe.color > 0)]
    new_index = {old: new for new, old in enumerate(keep)}
    out = []
    for i in keep:
        lobe = lobes[i]
        if lobe.under >= 0:
            lobe.under = new_index.get(lobe.under, -1)
        out.append(lobe)
    return out


class MaterialExporter:
    """Converts each Blender material once; `index(material)` gives its position in `materials`."""

    def __init__(self, warnings: list[str]) -> None:
        self.warnings = warnings
        self.materials: list[Material] = []
        self.textures: list[Texture] = []
        self.textured: set[int] = set()  # material indices that sample a texture (need UVs)
        self._by_key: dict[int | tuple, int] = {}
        self._tex_by_key: dict[int, int] = {}
        self._default: int | None = None

    # ----------------------------------------------------------------------------------------- public
    def index(self, material) -> int:
        if material is None:
            if self._default is None:
                self._default = self._add(Material("Monte default (no material)",
                                                   [Lobe("diffuse", np.full(3, DEFAULT_GREY))]))
            return self._default
        key = material.original.as_pointer() if getattr(material, "original", None) else material.as_pointer()
        found = self._by_key.get(key)
        if found is None:
            textures_before = len(self.textures)
            mat = self.convert(material)
            found = self._add(mat)
            if any(lobe.color_texture >= 0 for lobe in mat.lobes) or len(self.textures) > textures_before:
                self.textured.add(found)
            self._by_key[key] = found
        return found

    def convert(self, material) -> Material:
        name = material.name
        owner = f"material {name!r}"
        viewport = np.array(material.diffuse_color[:3], dtype=np.float64)
        tree = node_tree(material)
        if tree is None:
            return Material(name, [Lobe("diffuse", viewport)])
        output = tree.get_output_node("CYCLES")
        if output is None:
            self.warnings.append(f"{owner}: no active Material Output node; using the viewport colour as diffuse")
            return Material(name, [Lobe("diffuse", viewport)])
        if output.inputs.get("Volume") is not None and output.inputs["Volume"].is_linked:
            vol = follow_link(output.inputs["Volume"])
            label = f" {vol.name!r} ({vol.bl_label})" if vol is not None else ""
            self.warnings.append(f"{owner}: volumes are not supported; the volume shader{label} is ignored")
        if output.inputs.get("Displacement") is not None and output.inputs["Displacement"].is_linked:
            self.warnings.append(f"{owner}: displacement is not supported and is ignored")
        node = follow_link(output.inputs["Surface"])
        if node is None:
            # Cycles renders an unlinked surface black.
            return Material(name, [])
        lobes: list[Lobe] = []
        emission = np.zeros(3)
        self._holdout = 0.0
        try:
            emission = self._shader(node, 1.0, lobes, owner, 0)
        except UnsupportedShader as exc:
            self.warnings.append(f"{owner}: {exc}; falling back to a diffuse of the material's viewport colour "
                                 f"{np.round(viewport, 4).tolist()}")
            return Material(name, [Lobe("diffuse", viewport)])
        return Material(name, _drop_black_lobes(lobes), emission=np.maximum(emission, 0.0),
                        holdout=min(max(self._holdout, 0.0), 1.0))

    def holdout_index(self, material) -> int:
        """Index of `material` held out (an object or collection set to holdout): its lobes and emission for
        the rays that see it normally, holdout weight 1 for camera rays (core.scene.Material.holdout)."""
        base = self.index(material)
        key = ("holdout", base)
        found = self._by_key.get(key)
        if found is None:
            src = self.materials[base]
            found = self._by_key[key] = self._add(Material(f"{src.name} (holdout)", list(src.lobes),
                                                           emission=src.emission.copy(), holdout=1.0))
            if base in self.textured:
                self.textured.add(found)
        return found

    # ----------------------------------------------------------------------------------------- internals
    def _add(self, mat: Material) -> int:
        self.materials.append(mat)
        return len(self.materials) - 1

    def _shader(self, node, weight: float, lobes: list[Lobe], owner: str, depth: int) -> np.ndarray:
        """Append the lobes of the shader `node` scaled by `weight`; return its emission."""
        if depth > _MAX_DEPTH:
            raise UnsupportedShader(node, "nests too deeply")
        kind = node.bl_idname
        zero = np.zeros(3)
        if weight == 0.0:
            return zero
        if kind == "ShaderNodeMixShader":
            fac = min(max(socket_value(node.inputs[0], owner, self.warnings), 0.0), 1.0)
            e = zero
            for sock, w in ((node.inputs[1], 1.0 - fac), (node.inputs[2], fac)):
                child = follow_link(sock)
                if child is not None and w > 0:
                    e = e + self._shader(child, weight * w, lobes, owner, depth + 1)
            return e
        if kind == "ShaderNodeAddShader":
            e = zero
            for sock in (node.inputs[0], node.inputs[1]):
                child = follow_link(sock)
                if child is not None:
                    e = e + self._shader(child, weight, lobes, owner, depth + 1)
            return e
        if kind == "ShaderNodeEmission":
            color, _ = self._color(node.inputs["Color"], owner, allow_texture=False)
            strength = socket_value(node.inputs["Strength"], owner, self.warnings)
            return weight * color * strength
        if kind == "ShaderNodeBsdfDiffuse":
            color, tex = self._color(node.inputs["Color"], owner)
            if socket_value(node.inputs["Roughness"], owner, self.warnings) > 0:
                self.warnings.append(f"{owner}: node {node.name!r}: Oren-Nayar roughness is not supported; "
                                     "rendered as Lambertian")
            self._check_normal(node, owner)
            lobes.append(Lobe("diffuse", weight * color, color_texture=tex))
            return zero
        if kind in ("ShaderNodeBsdfAnisotropic", "ShaderNodeBsdfGlossy"):
            color, tex = self._color(node.inputs["Color"], owner)
            rough = self._roughness(node.inputs["Roughness"], owner)
            aniso = node.inputs.get("Anisotropy")
            if aniso is not None and socket_value(aniso, owner, self.warnings) != 0:
                self.warnings.append(f"{owner}: node {node.name!r}: anisotropy is not supported; rendered isotropic")
            self._check_normal(node, owner)
            lobes.append(Lobe("glossy", weight * color, roughness=rough, fresnel="none", color_texture=tex))
            return zero
        if kind in ("ShaderNodeBsdfGlass", "ShaderNodeBsdfRefraction"):
            color, tex = self._color(node.inputs["Color"], owner)
            rough = self._roughness(node.inputs["Roughness"], owner)
            ior = self._ior(node.inputs["IOR"], owner)
            self._check_normal(node, owner)
            lobe_kind = "glass" if kind == "ShaderNodeBsdfGlass" else "refraction"
            lobes.append(Lobe(lobe_kind, weight * color, roughness=rough, ior=ior, color_texture=tex))
            return zero
        if kind == "ShaderNodeHoldout":
            self._holdout += weight
            return zero
        if kind == "ShaderNodeBsdfTransparent":
            color, _ = self._color(node.inputs["Color"], owner, allow_texture=False)
            lobes.append(Lobe("refraction", weight * color, roughness=0.0, ior=1.0))
            return zero
        if kind == "ShaderNodeBsdfPrincipled":
            return self._principled(node, weight, lobes, owner)
        raise UnsupportedShader(node)

    def _principled(self, node, weight: float, lobes: list[Lobe], owner: str) -> np.ndarray:
        inp = node.inputs
        w = self.warnings

        def val(name: str, default: float = 0.0) -> float:
            sock = inp.get(name)
            return default if sock is None else socket_value(sock, owner, w)

        base, tex = self._color(inp["Base Color"], owner)
        metallic = min(max(val("Metallic"), 0.0), 1.0)
        rough = self._roughness(inp["Roughness"], owner)
        ior = self._ior(inp["IOR"], owner)
        transmission = min(max(val("Transmission Weight", val("Transmission")), 0.0), 1.0)
        alpha = min(max(val("Alpha", 1.0), 0.0), 1.0)
        level = max(val("Specular IOR Level", 0.5), 0.0)
        tint_sock = inp.get("Specular Tint")
        tint = np.ones(3)
        if tint_sock is not None and tint_sock.type == "RGBA":
            tint, _ = self._color(tint_sock, owner, allow_texture=False)
        for name, what in (("Coat Weight", "coat"), ("Sheen Weight", "sheen"), ("Anisotropic", "anisotropy"),
                           ("Thin Film Thickness", "thin film")):
            if val(name) > 0:
                w.append(f"{owner}: node {node.name!r}: {what} is not supported and is ignored")
        if val("Subsurface Weight") > 0:
            w.append(f"{owner}: node {node.name!r}: subsurface scattering is not supported; rendered as diffuse")
        self._check_normal(node, owner)

        a = weight * alpha
        dielectric = (1.0 - metallic) * (1.0 - transmission)
        if a * dielectric > 0:
            f0, eta = specular_layer(ior, level)
            spec = -1
            if eta != 1.0:
                spec = len(lobes)
                lobes.append(Lobe("glossy", np.full(3, a * dielectric), roughness=rough, ior=eta,
                                  fresnel="generalized_schlick", f0=np.clip(f0 * tint, 0.0, 1.0)))
            lobes.append(Lobe("diffuse", a * dielectric * base, color_texture=tex, under=spec))
        if a * metallic > 0:
            # Schlick on the base colour, F = base + (1 - base)(1 - cos)^5, as the sum of a Fresnel-free lobe
            # (base) and a Schlick lobe with F0 = 0 (IOR 1) tinted 1 - base. A textured base colour cannot
            # tint by 1 - texture: it keeps the first lobe only (darker near grazing angles).
            lobes.append(Lobe("glossy", a * metallic * base, roughness=rough, fresnel="none", color_texture=tex))
            if tex < 0 and np.any(base < 1):
                lobes.append(Lobe("glossy", a * metallic * np.clip(1.0 - base, 0.0, 1.0), roughness=rough,
                                  ior=1.0, fresnel="schlick"))
        if a * (1.0 - metallic) * transmission > 0:
            # Cycles' Principled glass closure: the real IOR (Specular IOR Level does not apply), reflection
            # f0 = F0(IOR) x Specular Tint remapped as for the specular layer and untinted otherwise,
            # transmission tinted by sqrt(base colour) (light crosses two interfaces through a closed object);
            # a textured base colour tints the transmission by the texel's square root (see core.scene.Lobe).
            r0 = (ior - 1.0) / (ior + 1.0)
            lobes.append(Lobe("glass", np.full(3, a * (1.0 - metallic) * transmission), roughness=rough, ior=ior,
                              fresnel="generalized_schlick", f0=np.clip(r0 * r0 * tint, 0.0, 1.0),
                              transmission_tint=np.sqrt(np.clip(base, 0.0, 1.0)), color_texture=tex))
        if alpha < 1.0:
            lobes.append(Lobe("refraction", np.full(3, weight * (1.0 - alpha)), roughness=0.0, ior=1.0))
        emission = np.zeros(3)
        strength_sock = inp.get("Emission Strength")
        strength = 1.0 if strength_sock is None else socket_value(strength_sock, owner, w)
        if strength != 0:
            ecolor, _ = self._color(inp.get("Emission Color") or inp["Emission"], owner, allow_texture=False)
            emission = weight * alpha * ecolor * strength
        return emission

    def _roughness(self, sock, owner: str) -> float:
        return min(max(socket_value(sock, owner, self.warnings), 0.0), 1.0)

    def _ior(self, sock, owner: str) -> float:
        ior = socket_value(sock, owner, self.warnings)
        if not (math.isfinite(ior) and ior > 0):
            self.warnings.append(f"{owner}: IOR {ior:g} is not physical; using 1.5")
            return 1.5
        return ior

    def _check_normal(self, node, owner: str) -> None:
        sock = node.inputs.get("Normal")
        if sock is not None and sock.is_linked:
            src = follow_link(sock)
            if src is not None:
                self.warnings.append(f"{owner}: node {src.name!r} ({src.bl_label}) on {node.name!r}'s Normal: "
                                     "bump and normal maps are not supported and are ignored")

    def _color(self, sock, owner: str, allow_texture: bool = True) -> tuple[np.ndarray, int]:
        """(linear RGB weight, texture index or -1) of a colour input."""
        default = np.array(sock.default_value[:3], dtype=np.float64)
        src = follow_link(sock)
        if src is None:
            return default, -1
        if src.bl_idname == "ShaderNodeRGB":
            return np.array(src.outputs[0].default_value[:3], dtype=np.float64), -1
        if src.bl_idname == "ShaderNodeTexImage" and allow_texture:
            out = _from_socket(sock)
            if out is not None and out.name != "Color":
                self.warnings.append(f"{owner}: the {out.name!r} output of {src.name!r} is not supported as a "
                                     "colour; using the image's colour")
            tex = self._texture(src, owner)
            if tex is not None:
                return np.ones(3), tex
            return default, -1
        why = "is not supported" if allow_texture or src.bl_idname != "ShaderNodeTexImage" else \
            "is not supported on this input"
        self.warnings.append(f"{owner}: node {src.name!r} ({src.bl_label}) driving {sock.name!r} {why}; using "
                             f"the socket's colour {np.round(default, 4).tolist()}")
        return default, -1

    def _texture(self, node, owner: str) -> int | None:
        image = node.image
        if image is None:
            self.warnings.append(f"{owner}: image texture {node.name!r} has no image; using the socket's colour")
            return None
        vec = follow_link(node.inputs["Vector"])
        if vec is not None:
            ok = vec.bl_idname == "ShaderNodeTexCoord" and _from_socket(node.inputs["Vector"]).name == "UV"
            ok = ok or vec.bl_idname == "ShaderNodeUVMap"
            if not ok:
                self.warnings.append(f"{owner}: node {vec.name!r} ({vec.bl_label}) mapping {node.name!r} is not "
                                     "supported; the texture uses the active UV map")
            elif vec.bl_idname == "ShaderNodeUVMap" and vec.uv_map:
                self.warnings.append(f"{owner}: {node.name!r} asks for UV map {vec.uv_map!r}; Monte uses the "
                                     "active (render) UV map")
        if node.projection != "FLAT":
            self.warnings.append(f"{owner}: {node.name!r}: {node.projection.lower()} projection is not supported; "
                                 "using UV mapping")
        if image.source not in ("FILE", "GENERATED"):
            self.warnings.append(f"{owner}: image {image.name!r} is a {image.source.lower()} image; Monte reads its "
                                 "first frame/tile only")
        key = image.original.as_pointer() if getattr(image, "original", None) else image.as_pointer()
        if key in self._tex_by_key:
            return self._tex_by_key[key]
        try:
            pixels = image_pixels(image, self.warnings)
        except Exception as exc:  # missing file, unreadable image
            self.warnings.append(f"{owner}: image {image.name!r} could not be read ({exc}); using the socket's "
                                 "colour")
            return None
        self.textures.append(Texture(image.name, pixels))
        idx = len(self.textures) - 1
        self._tex_by_key[key] = idx
        return idx
