"""Blender materials (node trees) -> core Materials (sums of lobes plus emission, optionally a node program).

The surface shader tree is compiled by addon/export/nodes (see docs/shading-nodes.md for every supported node):
every input of every shader may be driven by nodes, evaluated per shading point by a core.shading program; a
material whose tree folds to constants is plain constant lobes (no per-point cost). Shaders map to lobes as:

- Principled BSDF, approximated by a sum of Monte lobes (all multiplied by Alpha):
    specular  glossy GGX, weight (1 - metallic)(1 - transmission), Cycles' generalized-Schlick Fresnel: the
              exact dielectric Fresnel of eta remapped from [F0(eta), 1] to [f0 x Specular Tint, 1], with
              f0 = F0(IOR) x 2 x Specular IOR Level and eta the IOR of that f0 (eta = IOR at the default 0.5);
              absent when f0 = 0 (eta = 1), as in Cycles
    diffuse   base colour x (1 - metallic)(1 - transmission), lying `under` the specular lobe: scaled per hit
              by 1 - max_c of the specular layer's albedo estimate at the view angle (Cycles 4.x/5.0 layering)
    metal     Schlick's Fresnel on the base colour (what Blender's F82 model reduces to with a white tint):
              a glossy GGX lobe of base colour x metallic without Fresnel plus one with Schlick F0 = 0 tinted
              (1 - base colour) x metallic (both per point when the base colour is textured)
    glass     glass GGX with IOR, weight (1 - metallic) x transmission, as Cycles' glass closure: reflection
              with the generalized-Schlick Fresnel of F0(IOR) x Specular Tint (no Specular IOR Level),
              transmission (1 - F) x sqrt(base colour)
    alpha     refraction with IOR 1 (a straight pass-through) weighted 1 - alpha
    emission  Emission Color x Emission Strength
  Coat, sheen, subsurface (rendered as diffuse), anisotropy, thin film and normal/bump maps are not
  supported: a warning names each one that is in use.
- Diffuse, Glossy (no Fresnel), Glass, Refraction, Transparent and Emission shaders; Mix Shader (its factor may
  vary per point) and Add Shader of those: weights multiply down the tree.

Anything else gives a warning naming the material and the node, and a documented fallback: an unsupported
shader makes the whole material a diffuse of the material's viewport colour (Viewport Display > Color); an
unsupported node driving an input uses that socket's own value. No node tree: the viewport colour as
diffuse. An empty material slot: a default grey (0.8) diffuse, as Cycles renders it. Images are read once
each (RGBA, as Cycles holds them: associated alpha, 8-bit sRGB decoded after filtering); a missing image reads
Cycles' missing-texture magenta, NaN/Inf texels read 0 (counted warning).
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
    px = _pixels_top_down(image)
    if px.shape[2] >= 3:
        rgb = px[..., :3]
    else:
        rgb = np.repeat(px[..., :1], 3, axis=2)
    if _srgb_encoded(image, warnings):
        rgb = srgb_to_linear(rgb)
    return np.ascontiguousarray(rgb, dtype=np.float32)


def _pixels_top_down(image) -> np.ndarray:
    """An image's pixels as they are stored, (H, W, channels) float32, row 0 at the TOP (Blender stores row 0 at
    the bottom): one foreach_get call (image_pixels and image_rgba read them so)."""
    w, h = int(image.size[0]), int(image.size[1])
    if w == 0 or h == 0:
        raise ValueError(f"image {image.name!r} has no pixels (missing file {image.filepath!r}?)")
    ch = int(image.channels)
    buf = np.empty(w * h * ch, dtype=np.float32)
    image.pixels.foreach_get(buf)
    return buf.reshape(h, w, ch)[::-1]


def _srgb_encoded(image, warnings: list[str] | None) -> bool:
    """Whether an image's pixels are sRGB-encoded: an 8-bit image in a colour space that is not linear (one other
    than sRGB is treated as sRGB, with a warning)."""
    space = image.colorspace_settings.name.lower()
    encoded = not image.is_float and space not in _LINEAR_SPACES
    if encoded and space != "srgb" and warnings is not None:
        warnings.append(f"image {image.name!r}: colour space {image.colorspace_settings.name!r} is treated as sRGB")
    return encoded


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


class MaterialExporter:
    """Converts each Blender material once; `index(material)` gives its position in `materials`.

    A material's node tree is compiled by addon/export/nodes (a ShaderWalk over a ProgramBuilder): when every lobe
    parameter and the emission fold to constants the material is plain constant lobes (rendered as before, at no
    per-point cost); otherwise it carries a core.shading ShadingProgram that drives them per shading point."""

    def __init__(self, warnings: list[str], camera_matrix=None, shader_aovs=()) -> None:
        self.warnings = warnings
        # the view layer's shader AOVs (core.scene.Scene.shader_aovs): name -> (index, kind) for AOV Output nodes
        self.shader_aovs = {name: (i, kind) for i, (name, kind) in enumerate(shader_aovs)}
        self.camera_matrix = camera_matrix  # the render camera's matrix_world (Vector Transform's camera space)
        self.materials: list[Material] = []
        self.textures: list[Texture] = []
        self.textured: set[int] = set()  # material indices that read UVs (image textures, UV coordinates)
        self.nonfinite_texels = 0
        self.uv_names: list[str] = []  # UV maps UV Map nodes name (core Scene.uv_layer_names)
        self.attribute_names: list[str] = []  # attributes Attribute nodes name (core Scene.attribute_names)
        # material index -> [(attribute name, "node 'X' (Label)")] its Attribute / Color Attribute nodes read
        self.attribute_uses: dict[int, list] = {}
        self._converted_uses: list = []
        self.tangent_names: list[str] = []  # UV maps Normal Map nodes take tangents of (Scene.tangent_layer_names)
        self._by_key: dict[int | tuple, int] = {}
        self._tex_by_key: dict[tuple, int] = {}
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
            mat = self.convert(material)
            mat.pass_index = int(getattr(material, "pass_index", 0))  # the Material Index pass
            found = self._add(mat)
            self.attribute_uses[found] = self._converted_uses
            if mat.program is not None and _reads_uv(mat.program):
                self.textured.add(found)
            self._by_key[key] = found
        return found

    def refresh(self, material) -> bool:
        """Convert an edited material again in place (its index stays); False if it was never converted."""
        key = material.original.as_pointer() if getattr(material, "original", None) else material.as_pointer()
        found = self._by_key.get(key)
        if found is None:
            return False
        textures_before = len(self.textures)
        mat = self.convert(material)
        mat.pass_index = int(getattr(material, "pass_index", 0))
        self.materials[found] = mat
        self.attribute_uses[found] = self._converted_uses
        if any(lobe.color_texture >= 0 for lobe in mat.lobes) or len(self.textures) > textures_before:
            self.textured.add(found)
        return True

    def convert(self, material) -> Material:
        from .nodes.compiler import CompileError, ProgramBuilder
        from .nodes.shaders import UnsupportedShader, compile_aov_outputs, compile_surface

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
        builder = ProgramBuilder(owner, self.warnings, self.textures,
                                 lambda node, alpha_used: self._image_texture(node, owner, alpha_used),
                                 material_pass_index=int(getattr(material, "pass_index", 0)),
                                 uv_layer_index=self._uv_layer_index, attribute_index=self._attribute_index,
                                 tangent_layer_index=self._tangent_layer_index,
                                 camera_matrix=self.camera_matrix)
        self._converted_uses = builder.attribute_uses
        try:
            lobes, bind, emission, holdout, normal = compile_surface(builder, output)
            if self.shader_aovs:
                compile_aov_outputs(builder, tree, self.shader_aovs)
        except (UnsupportedShader, CompileError) as exc:
            self.warnings.append(f"{owner}: {exc}; falling back to a diffuse of the material's viewport colour "
                                 f"{np.round(viewport, 4).tolist()}")
            return Material(name, [Lobe("diffuse", viewport)])
        emit_const = builder.is_const(emission)
        constant_emission = np.maximum(builder.value(emission).astype(np.float64), 0.0) if emit_const else np.zeros(3)
        if not np.any(bind >= 0) and emit_const and normal < 0 and not builder.writes_aovs:
            return Material(name, lobes, emission=constant_emission, holdout=holdout)
        program = builder.finish(bind, -1 if emit_const else emission, normal)
        return Material(name, lobes, emission=constant_emission, program=program, holdout=holdout)

    def holdout_index(self, material) -> int:
        """Index of `material` held out (an object or collection set to holdout): its lobes and emission for
        the rays that see it normally, holdout weight 1 for camera rays (core.scene.Material.holdout)."""
        base = self.index(material)
        key = ("holdout", base)
        found = self._by_key.get(key)
        if found is None:
            src = self.materials[base]
            found = self._by_key[key] = self._add(Material(f"{src.name} (holdout)", list(src.lobes),
                                                           emission=src.emission.copy(), program=src.program,
                                                           holdout=1.0))
            if base in self.textured:
                self.textured.add(found)
            self.attribute_uses[found] = self.attribute_uses.get(base, [])
        return found

    # ----------------------------------------------------------------------------------------- internals
    def _tangent_layer_index(self, name: str) -> int:
        if name not in self.tangent_names:
            self.tangent_names.append(name)
        return self.tangent_names.index(name)

    def _uv_layer_index(self, name: str) -> int:
        if name not in self.uv_names:
            self.uv_names.append(name)
        return self.uv_names.index(name)

    def _attribute_index(self, name: str) -> int:
        if name not in self.attribute_names:
            self.attribute_names.append(name)
        return self.attribute_names.index(name)

    def attribute_names_of(self, material_indices) -> list[str]:
        """The attribute names the Attribute / Color Attribute nodes of these materials read."""
        return sorted({name for m in material_indices for name, _ in self.attribute_uses.get(m, ())})

    def warn_missing_attributes(self, material_indices, missing, mesh_name: str) -> None:
        """Warn, naming material, node and attribute, for each attribute a mesh lacks (it reads 0, as Blender)."""
        for m in sorted(set(material_indices)):
            for name, node in self.attribute_uses.get(m, ()):
                if name in missing:
                    what = f"attribute {name!r}" if name else "an active render colour attribute"
                    msg = (f"material {self.materials[m].name!r}: {node}: mesh {mesh_name!r} has no {what} (or "
                           "one of a type or domain Monte cannot read); it reads 0")
                    if msg not in self.warnings:
                        self.warnings.append(msg)

    def _add(self, mat: Material) -> int:
        self.materials.append(mat)
        return len(self.materials) - 1

    def _image_texture(self, node, owner: str, alpha_used: bool) -> tuple[int | None, int]:
        """(texture index, image-op flags) of an Image Texture node, Cycles' alpha association applied through
        the flags; (None, 0) with a warning naming material, node and path when the image is missing."""
        image = node.image
        if image is None:
            self.warnings.append(f"{owner}: image texture {node.name!r} has no image; using Cycles' missing-"
                                 "texture colour (magenta)")
            return None, 0
        if image.source not in ("FILE", "GENERATED"):
            self.warnings.append(f"{owner}: image {image.name!r} is a {image.source.lower()} image; Monte reads its "
                                 "first frame/tile only")
        key = image.original.as_pointer() if getattr(image, "original", None) else image.as_pointer()
        if key not in self._tex_by_key:
            try:
                pixels, encoded = image_rgba(image, self.warnings)
            except Exception as exc:  # missing file, unreadable image
                self.warnings.append(f"{owner}: node {node.name!r}: image {image.name!r} ({_image_path(image)!r}) "
                                     f"could not be read ({exc}); using Cycles' missing-texture colour (magenta)")
                return None, 0
            bad = ~np.isfinite(pixels)
            if bad.any():
                count = int(bad.sum())
                self.nonfinite_texels += count
                self.warnings.append(f"{owner}: node {node.name!r}: image {image.name!r} has {count} NaN/Inf "
                                     "texel values; they read as 0")
                pixels = np.where(bad, np.float32(0), pixels)
            self.textures.append(Texture(image.name, pixels))
            self._tex_by_key[key] = len(self.textures) - 1
            self._tex_by_key[(key, "srgb")] = int(encoded)
        idx = self._tex_by_key[key]
        flags = 2 if self._tex_by_key[(key, "srgb")] else 0
        if alpha_used and _associates_alpha(image):
            flags |= 4  # the Alpha output in use: Cycles unassociates the (associated) colour
        return idx, flags


def _reads_uv(program) -> bool:
    from ...core.shading import registry as R

    for inst in program.code:
        if inst[0] == R.OP_IMAGE and inst[R.op("image").slot("vector")] < 0:
            return True
        if inst[0] == R.OP_TEXCOORD and inst[R.op("texture_coordinate").slot("uv")] >= 0:
            return True
    return False


def _image_path(image) -> str:
    """The image's file as an absolute path (Blender stores '//'-relative ones)."""
    try:
        import bpy

        return bpy.path.abspath(image.filepath, library=image.library)
    except Exception:  # not a file image, or no bpy path helpers
        return image.filepath


def _associates_alpha(image) -> bool:
    """Whether Cycles holds the image with associated (premultiplied) alpha: not for data (Non-Color) images and
    not for the Channel Packed and None alpha modes."""
    data = image.colorspace_settings.name.lower() in ("non-color", "raw")
    return not data and getattr(image, "alpha_mode", "STRAIGHT") not in ("CHANNEL_PACKED", "NONE")


def image_rgba(image, warnings: list[str] | None = None) -> tuple[np.ndarray, bool]:
    """An image's pixels as (H, W, 4) float32 RGBA, row 0 at the TOP, and whether the colour is sRGB-encoded
    (8-bit images in an sRGB colour space, decoded by the image opcode after filtering as Cycles does); other
    images are linear as Blender holds them. As Cycles loads them, straight alpha is associated (colour times
    alpha; 8-bit images in integer arithmetic on the bytes, so the image opcode's unassociation for the Alpha
    output sees the same rounding); alpha mode None reads alpha 1. One foreach_get call."""
    px = _pixels_top_down(image)
    h, w, ch = px.shape
    rgba = np.ones((h, w, 4), np.float32)
    if ch >= 3:
        rgba[..., :3] = px[..., :3]
    else:
        rgba[..., :3] = px[..., :1]
    if ch == 4 or ch == 2:
        rgba[..., 3] = px[..., ch - 1]
    if getattr(image, "alpha_mode", "STRAIGHT") == "NONE":
        rgba[..., 3] = 1.0
    if (ch == 4 or ch == 2) and _associates_alpha(image) and getattr(image, "alpha_mode", "STRAIGHT") == "STRAIGHT":
        if image.is_float:
            rgba[..., :3] *= rgba[..., 3:4]
        else:
            b = np.rint(rgba * 255.0).astype(np.int32)
            rgba[..., :3] = ((b[..., :3] * b[..., 3:4]) // 255).astype(np.float32) / 255.0
    return np.ascontiguousarray(rgba), _srgb_encoded(image, warnings)
