"""Monte's scene model: plain, validated dataclasses of NumPy arrays.

Conventions (Blender's): right-handed world, Z up, metres. Colours are linear Rec.709 RGB. Angles are radians.
Triangles are wound counter-clockwise seen from the side their geometric normal points to ("outside"): the
face normal is normalize(cross(v1 - v0, v2 - v0)). Shading normals are per triangle corner.

Units follow Blender/Cycles (see each light's docstring): mesh emission is radiance (colour x strength, emitted
from both faces); point/spot/area light power is in watts; sun strength is irradiance in W/m^2; the world
background is radiance (colour x strength).

`Scene.validate()` turns bad input into either a clear `SceneError` naming the object, or a dropped element
counted in `Scene.warnings` -- never a crash deep inside NumPy or Embree.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from .world import EnvironmentMap, EnvironmentMapError

if TYPE_CHECKING:
    from .shading.program import ShadingProgram

LobeKind = Literal["diffuse", "glossy", "glass", "refraction"]
FresnelMode = Literal["none", "schlick", "dielectric", "generalized_schlick"]
AreaShape = Literal["SQUARE", "RECTANGLE", "DISK", "ELLIPSE"]
PanoramaType = Literal["EQUIRECTANGULAR", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID", "MIRRORBALL",
                       "FISHEYE_LENS_POLYNOMIAL", "CENTRAL_CYLINDRICAL"]
PANORAMA_TYPES = ("EQUIRECTANGULAR", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID", "MIRRORBALL",
                  "FISHEYE_LENS_POLYNOMIAL", "CENTRAL_CYLINDRICAL")


MAX_MOTION_STEPS = 129  # motion-blur steps a mesh or camera may have (Embree's RTC_MAX_TIME_STEP_COUNT)


SHADER_AOV_KINDS = ("COLOR", "VALUE")  # Scene.shader_aovs' types (core.shader_aovs)


class SceneError(ValueError):
    """Invalid scene input that cannot be rendered; the message names the offending element."""


def _as_rgb(value, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.size == 1:
        arr = np.repeat(arr, 3)
    if arr.size != 3:
        raise SceneError(f"{what}: expected an RGB triple, got {arr.size} values")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{what}: colour has NaN or Inf components {arr.tolist()}")
    if np.any(arr < 0):
        raise SceneError(f"{what}: negative colour/radiance {arr.tolist()} is not physical")
    return arr


def _as_vec3(value, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.size != 3 or not np.all(np.isfinite(arr)):
        raise SceneError(f"{what}: expected a finite 3-vector, got {np.asarray(value).tolist()}")
    return arr


def _as_matrix(value, what: str) -> np.ndarray:
    m = np.asarray(value, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise SceneError(f"{what}: expected a finite 4x4 matrix")
    return m


# --------------------------------------------------------------------------------------------------- materials
@dataclass
class Lobe:
    """One BSDF lobe of a material (a Cycles closure), weighted by `color`.

    kind:
      - "diffuse": Lambertian, reflectance `color`.
      - "glossy": GGX microfacet reflection (alpha = roughness^2, Cycles' mapping); roughness 0 is a perfect
        mirror. `fresnel` chooses the reflectance: "none" = `color` at every angle (Blender's Glossy BSDF),
        "schlick" = Schlick's F0 = ((ior-1)/(ior+1))^2 times `color` (the seed's mirror), "dielectric" = exact
        dielectric Fresnel from `ior` times `color`, reflection only; "generalized_schlick" = Cycles' Principled
        specular layer: the exact dielectric Fresnel of `ior` remapped from [F0(ior), 1] to [`f0`, 1] per
        channel, times `color` (the layer weight), with Cycles' Fss = f0 + (1 - f0) s_avg for multiscatter.
      - "glass": smooth or GGX-rough dielectric with exact Fresnel and total internal reflection (Blender's
        Glass BSDF); `ior` is inside/outside, outside is where the geometric normal points. Reflection is
        `color` x F x `reflection_tint`, transmission `color` x (1 - F) x `transmission_tint`. With fresnel
        "generalized_schlick" F is per channel f0 + (1 - f0) s (s as for the glossy lobe; Cycles' Principled
        transmission: f0 = F0(ior) x Specular Tint), else the exact dielectric Fresnel.
      - "refraction": the transmission part of "glass" only (Blender's Refraction BSDF).
    color_texture: index into `Scene.textures` that multiplies `color` at the hit's UV, or -1. On a "glass" lobe
      with fresnel "generalized_schlick" it multiplies `transmission_tint` by the square root of the texel
      clamped to [0, 1] instead (Cycles' Principled transmission tint sqrt(base colour)).
    f0: RGB reflectance at normal incidence of a "generalized_schlick" lobe (clamped to [0, 1]); None = F0(ior).
    reflection_tint, transmission_tint: RGB tints of a "glass" lobe's reflection and transmission (None = white,
      the Glass BSDF); other kinds reject them.
    under: index, in the material's lobe list, of a "generalized_schlick" glossy lobe this lobe lies beneath
      (a Principled base under its specular layer), or -1. The lobe's weight is then scaled per hit by
      saturate(1 - max_c A_c(wo) / color_c of that layer), A its albedo estimate at cos(wo) (Cycles'
      closure_layering_weight); see core.bsdf.
    """

    kind: LobeKind
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    roughness: float = 0.0
    ior: float = 1.5
    fresnel: FresnelMode = "none"
    color_texture: int = -1
    f0: np.ndarray | None = None
    under: int = -1
    reflection_tint: np.ndarray | None = None
    transmission_tint: np.ndarray | None = None

    def validate(self, owner: str) -> None:
        if self.kind not in ("diffuse", "glossy", "glass", "refraction"):
            raise SceneError(f"{owner}: unknown lobe kind {self.kind!r}")
        self.color = _as_rgb(self.color, f"{owner} {self.kind} colour")
        if not (math.isfinite(self.roughness) and 0.0 <= self.roughness <= 1.0):
            raise SceneError(f"{owner}: roughness {self.roughness} outside [0, 1]")
        if not (math.isfinite(self.ior) and self.ior > 0.0):
            raise SceneError(f"{owner}: IOR {self.ior} must be a positive number")
        if self.fresnel not in ("none", "schlick", "dielectric", "generalized_schlick"):
            raise SceneError(f"{owner}: unknown Fresnel mode {self.fresnel!r}")
        if self.f0 is not None:
            self.f0 = _as_rgb(self.f0, f"{owner} {self.kind} f0")
        for name in ("reflection_tint", "transmission_tint"):
            value = getattr(self, name)
            if value is not None:
                if self.kind != "glass":
                    raise SceneError(f"{owner}: {name} applies to glass lobes only, not {self.kind!r}")
                setattr(self, name, _as_rgb(value, f"{owner} glass {name.replace('_', ' ')}"))
        if not (isinstance(self.under, (int, np.integer)) and -1 <= self.under < 127):
            raise SceneError(f"{owner}: `under` must be a lobe index or -1, got {self.under!r}")


@dataclass
class Material:
    """A surface: a sum of BSDF lobes plus two-sided emission.

    emission: emitted radiance in W/(sr m^2) per colour unit (Blender's Emission colour x strength),
    emitted from both faces of the triangle, as Cycles' mesh emission is.
    program: optional core.shading ShadingProgram (a compiled node tree) that overrides lobe parameters and the
    emission per shading point (see core.shading.program); `lobes` then give the lobe kinds and constant values.
    holdout: weight in [0, 1] of a holdout (Blender's Holdout shader, or an object or collection set to
    holdout): where a camera ray (or a ray that went on through transparent surfaces, see `Film`) meets the
    surface, that fraction of the path's throughput is made transparent in the alpha channel and adds no colour;
    at 1 the path ends there. Other rays see only the lobes and emission (a Holdout shader alone absorbs), as
    Cycles does.
    pass_index: the material's Pass Index (Blender's Material > Settings > Pass Index), read by the Material Index
    pass (core.data_passes).
    """

    name: str
    lobes: list[Lobe] = field(default_factory=list)
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    program: "ShadingProgram | None" = None
    holdout: float = 0.0
    pass_index: int = 0

    def validate(self, n_textures: int) -> None:
        owner = f"material {self.name!r}"
        self.emission = _as_rgb(self.emission, f"{owner} emission")
        if not (math.isfinite(self.holdout) and 0.0 <= self.holdout <= 1.0):
            raise SceneError(f"{owner}: holdout weight {self.holdout} outside [0, 1]")
        for lobe in self.lobes:
            lobe.validate(owner)
            if not (-1 <= lobe.color_texture < n_textures):
                raise SceneError(f"{owner}: texture index {lobe.color_texture} out of range")
        if self.program is not None:
            from .shading.program import ProgramError

            try:
                self.program.validate(owner, len(self.lobes), n_textures)
            except ProgramError as exc:
                raise SceneError(str(exc)) from None

    @property
    def is_emissive(self) -> bool:
        return bool(np.any(np.asarray(self.emission) > 0))


@dataclass
class Texture:
    """An RGB or RGBA image, (H, W, 3 or 4) float32, row 0 at the top; sampled with UV in [0, 1] (v = 0 at the
    bottom, Blender's convention). A lobe's `color_texture` reads its RGB as linear colour with repeat wrapping
    and bilinear filtering; a shading program's image opcode chooses filtering, extension, alpha association
    and sRGB decoding itself (core.shading.registry, "image")."""

    name: str
    pixels: np.ndarray

    def validate(self) -> None:
        px = np.asarray(self.pixels, dtype=np.float32)
        if px.ndim != 3 or px.shape[2] not in (3, 4) or px.shape[0] < 1 or px.shape[1] < 1:
            raise SceneError(f"texture {self.name!r}: expected an (H, W, 3) or (H, W, 4) image, got shape "
                             f"{px.shape}")
        px = np.ascontiguousarray(px)
        bad = ~np.isfinite(px)
        if bad.any():
            raise SceneError(f"texture {self.name!r}: {int(bad.sum())} NaN/Inf texel values")
        self.pixels = px


# ------------------------------------------------------------------------------------------------------ meshes
@dataclass
class Mesh:
    """A triangle mesh in world space.

    vertices: (V, 3) float32/float64 world positions. triangles: (T, 3) int vertex indices.
    normals: optional (T, 3, 3) per-corner shading normals (smooth/flat/sharp edges already resolved);
      None means flat shading (the geometric normal).
    uvs: optional (T, 3, 2) per-corner texture coordinates.
    material_index: (T,) int index into `Scene.materials` (a single int broadcasts).
    object_index: optional (T,) int (or one int) row of `Scene.objects` each triangle belongs to: the object data
      shading nodes read (object space, texture space, Object Info); None = no object (identity space).
    visible_camera: False hides the mesh from camera rays (Blender's Object > Visibility > Ray Visibility >
      Camera); visible_shadow: False lets shadow rays pass through it (Ray Visibility > Shadow);
      visible_diffuse / visible_glossy / visible_transmission: False hides it from rays that a diffuse lobe,
      a glossy lobe (or a glass's reflection), or a transmission started (core.ray_visibility). Other rays see it.
    shadow_terminator_offset: Cycles' object setting Shading > Shadow Terminator > Geometry Offset, >= 0 (the
      UI's range is [0, 1]; larger values act as 1 on almost every ray):
      on smooth-shaded triangles, shadow rays towards lights at grazing angles leave from the point lifted
      towards the smooth surface the shading normals describe (Cycles' shadow_ray_offset). 0 = off (the core's
      default); Blender objects default to 0.1 and the add-on exports their value.
    uv_layers: optional {name: (T, 3, 2)} every UV map of the mesh by name (UV Map nodes naming a map read
      these through `Scene.uv_layer_names`; a mesh without the named map reads (0, 0), as Blender does).
    shadow_catcher: Cycles' Object > Visibility > Shadow Catcher: the mesh leaves the image (Combined) and only
      the shadows and light other objects add to it remain, as alpha or the Shadow Catcher pass (see `Film`).
    attributes: optional {name: (T, 3, 5)} the mesh attributes Attribute / Color Attribute nodes read, per
      triangle corner (point and face attributes spread to the corners), interpolated linearly over the
      triangle: the Color / Vector output (3 floats), Alpha and Fac (core.shading.program
      MESH_ATTRIBUTE_COLUMNS); read through `Scene.attribute_names`; a mesh without the named attribute reads 0
      (Alpha: 1 for the Attribute node, 0 for Color Attribute), as Cycles.
    tangent_layers: optional {name: (T, 3, 4)} per corner the MikkTSpace tangent of a UV map (world space, xyz)
      and the bitangent sign (w, +-1), for Normal Map nodes in tangent space (`Scene.tangent_layer_names`;
      the name "" is the active render UV map). A mesh without the named layer renders the unperturbed normal
      there, as Cycles.
    light_sets / shadow_sets: bitmasks of the light sets (core.light_linking, bit k: set k, 0..63) the object
      receives light from / blocks the light of; -1 (every bit, the default): every set. receiver_set: as an
      emitter (an emissive mesh), the light set it lights; 0: every object. blocker_set: as an emitter, the light
      set whose members alone block its light (Shadow Linking); 0: every object.
    motion_vertices: optional (S, V, 3) world positions of the vertices at S >= 2 times evenly spaced over the
      camera's shutter (step 0 at shutter open, S - 1 at close; core.motion): motion blur of a moving or
      deforming mesh. `vertices` stays the frame's pose (light sampling of emitters reads it). None: still.
    motion_normals: optional (S, T, 3, 3) the corner normals at those steps (a rotating or deforming smooth
      mesh); None keeps `normals` at every step.
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    material_index: np.ndarray | int = 0
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    object_index: np.ndarray | int | None = None
    visible_camera: bool = True
    visible_shadow: bool = True
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    shadow_terminator_offset: float = 0.0
    uv_layers: dict | None = None
    shadow_catcher: bool = False
    attributes: dict | None = None
    tangent_layers: dict | None = None
    motion_vertices: np.ndarray | None = None
    motion_normals: np.ndarray | None = None
    light_sets: int = -1
    shadow_sets: int = -1
    receiver_set: int = 0
    blocker_set: int = 0
    lightgroup: str = ""  # as an emitter, Cycles' light group it lights (core.light_groups); "": none
    # The Vector pass (core.data_passes): (2, V, 3) world positions of the vertices at the previous and the next
    # frame; None: where it is now at both.
    vector_vertices: np.ndarray | None = None

    @property
    def triangle_count(self) -> int:
        return int(np.asarray(self.triangles).shape[0])

    def validate(self, n_materials: int, warnings: list[str], n_objects: int = 0) -> None:
        """Check shapes and indices; drop degenerate or non-finite triangles with a counted warning."""
        owner = f"mesh {self.name!r}"
        v = np.asarray(self.vertices)
        if v.ndim != 2 or v.shape[1] != 3:
            raise SceneError(f"{owner}: vertices must have shape (V, 3), got {v.shape}")
        v = v.astype(np.float64, copy=False)
        tri = np.asarray(self.triangles)
        if tri.size == 0:
            tri = tri.reshape(0, 3)
        if tri.ndim != 2 or tri.shape[1] != 3:
            raise SceneError(f"{owner}: triangles must have shape (T, 3), got {tri.shape}")
        if not np.issubdtype(tri.dtype, np.integer):
            raise SceneError(f"{owner}: triangle indices must be integers, got {tri.dtype}")
        tri = tri.astype(np.int64, copy=False)
        if tri.size and (tri.min() < 0 or tri.max() >= len(v)):
            raise SceneError(
                f"{owner}: triangle vertex index out of range [0, {len(v) - 1}]: "
                f"min {int(tri.min())}, max {int(tri.max())}"
            )
        n_tri = tri.shape[0]
        mat = np.broadcast_to(np.asarray(self.material_index), (n_tri,)).astype(np.int64)
        if n_tri and (mat.min() < 0 or mat.max() >= n_materials):
            raise SceneError(
                f"{owner}: material index out of range [0, {n_materials - 1}]: "
                f"min {int(mat.min())}, max {int(mat.max())}"
            )
        objs = None
        if self.object_index is not None:
            objs = np.broadcast_to(np.asarray(self.object_index), (n_tri,)).astype(np.int64)
            if n_tri and (objs.min() < 0 or objs.max() >= n_objects):
                raise SceneError(f"{owner}: object index out of range [0, {n_objects - 1}]: "
                                 f"min {int(objs.min())}, max {int(objs.max())}")
        normals = None if self.normals is None else np.asarray(self.normals, dtype=np.float32)
        if normals is not None and normals.shape != (n_tri, 3, 3):
            raise SceneError(f"{owner}: normals must have shape (T, 3, 3) = ({n_tri}, 3, 3), got {normals.shape}")
        offset = self.shadow_terminator_offset
        if not (isinstance(offset, (int, float, np.floating, np.integer)) and 0.0 <= float(offset) < math.inf):
            raise SceneError(f"{owner}: shadow_terminator_offset (Shadow Terminator > Geometry Offset) must be a "
                             f"finite number >= 0, got {offset!r}")
        uvs = None if self.uvs is None else np.asarray(self.uvs, dtype=np.float32)
        if uvs is not None and uvs.shape != (n_tri, 3, 2):
            raise SceneError(f"{owner}: uvs must have shape (T, 3, 2) = ({n_tri}, 3, 2), got {uvs.shape}")

        motion, motion_normals = self._checked_motion(owner, v.shape[0], n_tri, warnings)
        if self.vector_vertices is not None:
            vv = np.asarray(self.vector_vertices, np.float64)
            if vv.shape != (2, v.shape[0], 3):
                raise SceneError(f"{owner}: vector_vertices must have shape (2, V, 3) with V = {v.shape[0]}, got "
                                 f"{vv.shape}")
            self.vector_vertices = np.nan_to_num(vv, nan=0.0, posinf=0.0, neginf=0.0)
        # Drop triangles with non-finite or degenerate (zero-area) geometry: counted, never fatal.
        finite = np.empty(n_tri, bool)
        area2 = np.empty(n_tri)
        edge = np.empty(n_tri)
        from .mesh_checks import triangle_checks  # numba: imported when a mesh is checked, not with the data types

        triangle_checks(np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(tri), finite, area2, edge)
        with np.errstate(invalid="ignore", over="ignore"):
            # zero area relative to the triangle's own size: collinear or repeated vertices
            degenerate = ~(area2 > 1e-12 * np.maximum(edge, 1e-300) ** 2) | (area2 == 0)
        keep = finite & ~degenerate
        if normals is not None:
            bad_n = ~np.all(np.isfinite(normals), axis=(1, 2)) | np.any(np.linalg.norm(normals, axis=2) < 1e-12, axis=1)
            if bad_n.any():
                warnings.append(f"{owner}: {int(bad_n.sum())} triangles with invalid shading normals use flat shading")
                normals = normals.copy()
                p = v[tri[bad_n]]
                with np.errstate(invalid="ignore", over="ignore"):
                    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
                flat = (cross / np.maximum(area2[bad_n], 1e-300)[:, None]).astype(np.float32)
                normals[bad_n] = flat[:, None, :]
        layers = {}
        for lname, luv in (self.uv_layers or {}).items():
            luv = np.asarray(luv, dtype=np.float32)
            if luv.shape != (n_tri, 3, 2):
                raise SceneError(f"{owner}: UV map {lname!r} must have shape (T, 3, 2) = ({n_tri}, 3, 2), got "
                                 f"{luv.shape}")
            layers[lname] = np.nan_to_num(luv, nan=0.0, posinf=0.0, neginf=0.0)
        attributes = {}
        for aname, values in (self.attributes or {}).items():
            values = np.asarray(values, dtype=np.float32)
            if values.shape != (n_tri, 3, 5):
                raise SceneError(f"{owner}: attribute {aname!r} must have shape (T, 3, 5) = ({n_tri}, 3, 5), got "
                                 f"{values.shape}")
            if not np.all(np.isfinite(values)):
                warnings.append(f"{owner}: attribute {aname!r}: non-finite values replaced by 0")
                values = np.nan_to_num(values, nan=0.0, posinf=0.0, neginf=0.0)
            attributes[aname] = values
        tangents = {}
        for lname, lt in (self.tangent_layers or {}).items():
            lt = np.asarray(lt, dtype=np.float32)
            if lt.shape != (n_tri, 3, 4):
                raise SceneError(f"{owner}: tangent layer {lname!r} must have shape (T, 3, 4) = ({n_tri}, 3, 4), "
                                 f"got {lt.shape}")
            tangents[lname] = np.nan_to_num(lt, nan=0.0, posinf=0.0, neginf=0.0)
        if uvs is not None and not np.all(np.isfinite(uvs)):
            warnings.append(f"{owner}: non-finite UVs replaced by 0")
            uvs = np.nan_to_num(uvs, nan=0.0, posinf=0.0, neginf=0.0)
        n_nonfinite = int((~finite).sum())
        n_degenerate = int((finite & degenerate).sum())
        if n_nonfinite:
            warnings.append(f"{owner}: dropped {n_nonfinite} triangles with NaN/Inf vertex coordinates")
        if n_degenerate:
            warnings.append(f"{owner}: dropped {n_degenerate} zero-area (degenerate) triangles")
        if not keep.all():
            tri, mat = tri[keep], mat[keep]
            normals = None if normals is None else normals[keep]
            uvs = None if uvs is None else uvs[keep]
            objs = None if objs is None else objs[keep]
            layers = {lname: luv[keep] for lname, luv in layers.items()}
            attributes = {aname: values[keep] for aname, values in attributes.items()}
            tangents = {lname: lt[keep] for lname, lt in tangents.items()}
            motion_normals = None if motion_normals is None else motion_normals[:, keep]
        # Non-finite vertices that no kept triangle uses are harmless; replace them so later arithmetic is clean.
        if not np.all(np.isfinite(v)):
            v = np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)
        self.vertices, self.triangles, self.material_index = v, tri.astype(np.int32), mat.astype(np.int32)
        self.normals, self.uvs = normals, uvs
        self.object_index = None if objs is None else objs.astype(np.int32)
        self.uv_layers = layers or None
        self.attributes = attributes or None
        self.tangent_layers = tangents or None
        self.motion_vertices, self.motion_normals = motion, motion_normals

    def _checked_motion(self, owner: str, n_vertices: int, n_tri: int,
                        warnings: list[str]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """motion_vertices / motion_normals as float64 / float32 arrays, or None (still, or with a warning when
        unusable: the mesh then renders without motion blur, at its frame pose)."""
        if self.motion_vertices is None:
            return None, None
        steps = np.asarray(self.motion_vertices, np.float64)
        if steps.ndim != 3 or steps.shape[1:] != (n_vertices, 3) or not 2 <= steps.shape[0] <= MAX_MOTION_STEPS:
            raise SceneError(f"{owner}: motion_vertices must have shape (S, V, 3) with 2 <= S <= "
                             f"{MAX_MOTION_STEPS} and V = {n_vertices}, got {steps.shape}")
        if not np.all(np.isfinite(steps)):
            warnings.append(f"{owner}: NaN/Inf in its motion-blur positions; rendered without motion blur")
            return None, None
        if np.all(steps == steps[:1]):
            return None, None  # nothing moves
        normals = None
        if self.motion_normals is not None:
            normals = np.asarray(self.motion_normals, np.float32)
            if normals.shape != (steps.shape[0], n_tri, 3, 3):
                raise SceneError(f"{owner}: motion_normals must have shape (S, T, 3, 3) = ({steps.shape[0]}, "
                                 f"{n_tri}, 3, 3), got {normals.shape}")
            if not np.all(np.isfinite(normals)):
                warnings.append(f"{owner}: NaN/Inf in its motion-blur normals; its normals do not move")
                normals = None
        return steps, normals


# ------------------------------------------------------------------------------------------------------ lights
@dataclass
class PointLight:
    """Blender point light. power: watts x colour (RGB). radius: sphere radius in metres (soft falloff).

    Radiant intensity I = power / (4 pi) W/sr; with radius r > 0 it is a sphere light (see notes)."""

    name: str
    position: np.ndarray
    power: np.ndarray
    radius: float = 0.0
    visible_camera: bool = False
    cast_shadow: bool = True
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    receiver_set: int = 0
    blocker_set: int = 0
    lightgroup: str = ""  # Cycles' light group (core.light_groups); "": none


@dataclass
class SpotLight:
    """Blender spot light: a point light restricted to a cone around `direction` (the light's local -Z).

    spot_size: full cone angle (radians); spot_blend: fraction of the cone edge smoothed (0..1)."""

    name: str
    position: np.ndarray
    direction: np.ndarray
    power: np.ndarray
    radius: float = 0.0
    spot_size: float = math.radians(45.0)
    spot_blend: float = 0.15
    visible_camera: bool = False
    cast_shadow: bool = True
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    receiver_set: int = 0
    blocker_set: int = 0
    lightgroup: str = ""  # Cycles' light group (core.light_groups); "": none


@dataclass
class SunLight:
    """Blender sun: strength is irradiance in W/m^2 x colour on a surface facing the sun.

    direction: the way the light travels (the light's local -Z in world space). angle: angular diameter."""

    name: str
    direction: np.ndarray
    strength: np.ndarray
    angle: float = math.radians(0.526)
    visible_camera: bool = False
    cast_shadow: bool = True
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    receiver_set: int = 0
    blocker_set: int = 0
    lightgroup: str = ""  # Cycles' light group (core.light_groups); "": none


@dataclass
class AreaLight:
    """Blender area light, one-sided, emitting along its local -Z.

    matrix_world: 4x4 light-to-world (scale included, as Blender's). size_x/size_y: extent in local units
    (SQUARE and DISK use size_x for both). power: watts x colour; radiance L = power / (pi A) with A the world
    area. spread: radians, pi is Lambertian."""

    name: str
    matrix_world: np.ndarray
    power: np.ndarray
    shape: AreaShape = "SQUARE"
    size_x: float = 1.0
    size_y: float = 1.0
    spread: float = math.pi
    visible_camera: bool = False
    cast_shadow: bool = True
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    receiver_set: int = 0
    blocker_set: int = 0
    lightgroup: str = ""  # Cycles' light group (core.light_groups); "": none


Light = PointLight | SpotLight | SunLight | AreaLight
# Every light has visible_camera: camera rays see its surface (a sphere light's, an area light's, the sun's disc;
# Blender's Object > Visibility > Ray Visibility > Camera on the light, off by default), and cast_shadow: False
# (Blender's Cast Shadow off) lets its light samples through every object (core.light_shadow).
# visible_diffuse / visible_glossy / visible_transmission: False hides it from bounce rays of that kind and from
# those lobes in next-event estimation (core.light_visibility).
# receiver_set / blocker_set (Light Linking / Shadow Linking, core.light_linking): the light set (1..63) whose
# members the light lights / whose members alone block it; 0: every object (no linking).


@dataclass
class World:
    """The background, seen by every ray that escapes: uniform radiance `color` (Blender's Background colour x
    strength), or, when `environment` is set, that image (core.world.EnvironmentMap, its Background strength
    folded into its `strength`) in place of the colour. camera_color: optional (3,) radiance that camera rays see
    where they escape, instead of the background (Blender's Light Path > Is Camera Ray mixing two Backgrounds: a
    backdrop that differs from the light); None: the background. camera_environment: optional map
    (core.world.EnvironmentMap, its strength folded in) that camera rays see in its place, taking precedence over
    camera_color (the same trick with a direction-varying backdrop); it lights nothing.
    portals: (P, 4, 3) float64 light portals (Cycles' area lights marked Portal), each a parallelogram: its
    centre, its two full edge vectors (world units) and the unit normal pointing to the side it lets the world
    in (the area light's emission direction); None: none. They emit nothing and no ray sees them: shading
    points on their inner side sample the world through them as well as by its map (core.world.portal_table)."""

    color: np.ndarray = field(default_factory=lambda: np.zeros(3))
    environment: EnvironmentMap | None = None
    camera_color: np.ndarray | None = None
    camera_environment: EnvironmentMap | None = None
    portals: np.ndarray | None = None
    # Lights that belong to the world (a Sky Texture's sun disc, core.sky): the exporters add them to the
    # scene's lights; the world itself does not render them.
    lights: list = field(default_factory=list)
    lightgroup: str = ""  # Cycles' light group of the world's light (core.light_groups); "": none

    @property
    def is_black(self) -> bool:
        if self.environment is not None:
            return not (np.any(np.asarray(self.environment.strength) > 0)
                        and np.any(np.asarray(self.environment.pixels) > 0))
        return not bool(np.any(np.asarray(self.color) > 0))


# ------------------------------------------------------------------------------------------------------ camera
@dataclass
class Camera:
    """Blender camera. matrix_world: camera-to-world 4x4; the camera looks along its local -Z with +Y up.

    kind "PERSP": lens (focal length, mm) and sensor (mm) with Blender's sensor fit: "AUTO" applies
    sensor_width to the larger image side, "HORIZONTAL" sensor_width to the width, "VERTICAL" sensor_height
    to the height. kind "ORTHO": ortho_scale is the extent of the fitted side in metres. shift_x/shift_y move
    the frame in units of the fitted side. clip_start/clip_end bound the visible depth along the ray.

    Depth of field (a thin lens, Cycles' conventions), on when use_dof: the aperture's radius is
    lens x 1e-3 / (2 aperture_fstop) metres for "PERSP" and "PANO" (the focal length in mm read as metres, whatever the
    scene's unit scale, as Cycles does) and 1 / (2 aperture_fstop) for "ORTHO"; focus_distance (m) is the
    distance of the plane in focus along the view axis. aperture_blades >= 3 makes the aperture a regular
    polygon of that many sides inscribed in the aperture's circle, turned by aperture_rotation (radians);
    0 (or 1, 2) keeps it round. aperture_ratio squeezes the aperture horizontally by 1 / ratio (anamorphic
    bokeh). An f-stop or focus distance of 0 renders as a pinhole (see `aperture_radius`).

    kind "PANO" (Cycles' panoramic camera; depth of field as Cycles: the focus is a sphere of radius
    focus_distance around the camera, see core.camera._panorama_rays): rays leave the camera position in the directions
    panorama_type maps the image to, u = x / width + shift_x and v = y / height + shift_y (from the bottom),
    each in [0, 1] across the image. "EQUIRECTANGULAR": longitude from longitude_min at the left edge to
    longitude_max at the right (0 straight ahead, positive to the left), latitude from latitude_min at the
    bottom to latitude_max at the top (radians). "FISHEYE_EQUIDISTANT": the angle off the view axis is
    r x fisheye_fov / 2 with r the distance from the image centre in units of half the image (the circle of
    radius 1 stretches with the image's aspect). "FISHEYE_EQUISOLID": a lens of fisheye_lens mm on the fitted
    sensor (sensor_fit; the other side by the aspect) at angle theta from the axis images at radius
    2 lens sin(theta / 2), up to fisheye_fov. "MIRRORBALL": the image is a mirror ball seen from afar along
    the view axis. "FISHEYE_LENS_POLYNOMIAL": the angle off the axis is -(k0 + k1 r + ... + k4 r^4)
    (fisheye_polynomial) at radius r mm on the fitted sensor, up to fisheye_fov / 2. "CENTRAL_CYLINDRICAL": a
    cylinder of cylinder_radius around the camera's up axis, longitude from longitude_min (left) to
    longitude_max (right), height from cylinder_height_min (bottom) to cylinder_height_max (top).
    Rays outside the fisheye circle or the ball are dead (black and opaque). Clipping: rays
    start clip_start from the camera and end at clip_end; the depth pass is the distance along the ray.

    motion_matrices: optional (S, 4, 4) camera-to-world matrices at S >= 2 times evenly spaced over the shutter
    (motion blur of a moving camera, core.motion); matrix_world stays the frame's. None: a still camera.
    shutter_curve: optional (K >= 2,) how open the shutter is at K times evenly spaced from open to close
    (Blender's Shutter Curve, >= 0, linear in between): ray times follow it (core.motion.shutter_times). None:
    fully open throughout (a flat curve).
    motion_lens: optional (lens at shutter open, lens at close) in mm: a perspective camera zooming during the
    shutter (Cycles' perspective motion: the image-plane point of each ray moves linearly from open to the frame's
    lens to close, by the ray's time); ignored by other camera types, as Cycles does. None: no zoom.
    rolling_shutter: optional duration in [0, 1] of Cycles' rolling shutter (Top): image rows are exposed one
    after the other, the top first; each ray's time is (u - 1/2) d + (r - 1/2)(1 - d) + 1/2 with u its shutter
    time, d the duration and r = (row + 1) / height (rows from the top), as Cycles times its rows. None: off.
    """

    matrix_world: np.ndarray
    resolution: tuple[int, int] = (256, 256)
    kind: Literal["PERSP", "ORTHO", "PANO"] = "PERSP"
    lens: float = 50.0
    sensor_width: float = 36.0
    sensor_height: float = 24.0
    sensor_fit: Literal["AUTO", "HORIZONTAL", "VERTICAL"] = "AUTO"
    ortho_scale: float = 7.0
    shift_x: float = 0.0
    shift_y: float = 0.0
    clip_start: float = 1e-6
    clip_end: float = 1e30
    use_dof: bool = False
    aperture_fstop: float = 2.8
    focus_distance: float = 10.0
    aperture_blades: int = 0
    aperture_rotation: float = 0.0
    aperture_ratio: float = 1.0
    panorama_type: PanoramaType = "EQUIRECTANGULAR"
    fisheye_fov: float = math.pi
    fisheye_lens: float = 10.5
    latitude_min: float = -0.5 * math.pi
    latitude_max: float = 0.5 * math.pi
    longitude_min: float = -math.pi
    longitude_max: float = math.pi
    fisheye_polynomial: tuple[float, float, float, float, float] = (
        -1.1735143712967577e-05, -0.019988736953434998, -3.3525322965709175e-06, 3.099275275886036e-06,
        -2.6064646454854524e-08)
    cylinder_height_min: float = -1.0
    cylinder_height_max: float = 1.0
    cylinder_radius: float = 1.0
    motion_matrices: np.ndarray | None = None
    shutter_curve: np.ndarray | None = None
    rolling_shutter: float | None = None
    motion_lens: tuple[float, float] | None = None
    vector_matrices: np.ndarray | None = None  # (2, 4, 4) camera-to-world at the previous and next frame (Vector)

    @classmethod
    def look_at(
        cls,
        eye,
        target,
        up=(0.0, 0.0, 1.0),
        horizontal_fov: float = math.radians(39.0),
        resolution: tuple[int, int] = (256, 256),
        **kwargs,
    ) -> "Camera":
        """A perspective camera at `eye` looking at `target`, with the given horizontal field of view."""
        eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
        forward = target - eye
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, true_up, -forward, eye
        sensor_width = kwargs.pop("sensor_width", 36.0)
        lens = sensor_width / (2.0 * math.tan(horizontal_fov / 2.0))
        return cls(matrix_world=m, resolution=resolution, lens=lens, sensor_width=sensor_width,
                   sensor_fit="HORIZONTAL", **kwargs)

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.matrix_world, dtype=np.float64)[:3, 3]

    def aperture_radius(self) -> float:
        """The lens aperture's radius in metres; 0 renders a pinhole camera (depth of field off, an f-stop of
        0 or a focus distance of 0: Blender lets both be typed in, and a pinhole is what they mean)."""
        if not self.use_dof or self.aperture_fstop == 0 or self.focus_distance == 0:
            return 0.0
        numerator = 1.0 if self.kind == "ORTHO" else self.lens * 1e-3
        return numerator / (2.0 * self.aperture_fstop)

    def frame(self) -> tuple[float, float, float, float]:
        """The image frame on the plane at distance 1 in front of the camera (perspective) or at the camera
        (orthographic), in camera-local units: (xmin, xmax, ymin, ymax). Follows Blender's
        BKE_camera_params_compute_viewplane: the fitted side spans the sensor, shift is in fitted-side units."""
        w, h = self.resolution
        fit = self.sensor_fit
        if fit == "AUTO":
            fit = "HORIZONTAL" if w >= h else "VERTICAL"
            sensor = self.sensor_width
        else:
            sensor = self.sensor_width if fit == "HORIZONTAL" else self.sensor_height
        extent = self.ortho_scale if self.kind == "ORTHO" else sensor / self.lens
        view = w if fit == "HORIZONTAL" else h
        pixel = extent / view
        dx, dy = self.shift_x * view, self.shift_y * view
        return ((-0.5 * w + dx) * pixel, (0.5 * w + dx) * pixel, (-0.5 * h + dy) * pixel, (0.5 * h + dy) * pixel)

    def _validate_panorama(self) -> None:
        if self.panorama_type not in PANORAMA_TYPES:
            raise SceneError(f"camera: unknown panorama type {self.panorama_type!r} ({', '.join(PANORAMA_TYPES)})")
        for name in ("fisheye_fov", "fisheye_lens", "latitude_min", "latitude_max", "longitude_min",
                     "longitude_max", "cylinder_height_min", "cylinder_height_max", "cylinder_radius"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise SceneError(f"camera: panorama {name} is {value}, it must be a finite number")
            setattr(self, name, value)
        if self.panorama_type.startswith("FISHEYE") and not self.fisheye_fov > 0:
            raise SceneError(f"camera: fisheye field of view {self.fisheye_fov} must be positive")
        if self.panorama_type == "FISHEYE_EQUISOLID" and not self.fisheye_lens > 0:
            raise SceneError(f"camera: fisheye lens {self.fisheye_lens} mm must be positive")
        coefficients = tuple(float(k) for k in np.asarray(self.fisheye_polynomial, np.float64).reshape(-1))
        if len(coefficients) != 5 or not all(math.isfinite(k) for k in coefficients):
            raise SceneError(f"camera: fisheye polynomial needs 5 finite coefficients, got {self.fisheye_polynomial!r}")
        self.fisheye_polynomial = coefficients
        if self.panorama_type == "CENTRAL_CYLINDRICAL" and not self.cylinder_radius > 0:
            raise SceneError(f"camera: central cylindrical radius {self.cylinder_radius} must be positive")

    def validate(self) -> None:
        self.matrix_world = _as_matrix(self.matrix_world, "camera matrix")
        w, h = self.resolution
        if int(w) != w or int(h) != h or w < 1 or h < 1:
            raise SceneError(f"camera: resolution must be at least 1x1 pixels, got {w}x{h}")
        self.resolution = (int(w), int(h))
        if w * h > 2**31 - 1:
            raise SceneError(f"camera: resolution {w}x{h} has too many pixels")
        if self.kind not in ("PERSP", "ORTHO", "PANO"):
            raise SceneError(f"camera: unknown camera type {self.kind!r} (PERSP, ORTHO or PANO)")
        if self.kind == "PANO":
            self._validate_panorama()
        for name in ("lens", "sensor_width", "sensor_height", "ortho_scale", "shift_x", "shift_y", "clip_start"):
            if not math.isfinite(float(getattr(self, name))):
                raise SceneError(f"camera: {name} is {getattr(self, name)}, it must be a finite number")
        if math.isnan(float(self.clip_end)):
            raise SceneError("camera: clip_end is NaN")
        if self.kind == "PERSP" and not (self.lens > 0 and self.sensor_width > 0 and self.sensor_height > 0):
            raise SceneError(f"camera: lens {self.lens} mm and sensor size must be positive")
        if self.kind == "ORTHO" and not self.ortho_scale > 0:
            raise SceneError(f"camera: orthographic scale {self.ortho_scale} must be positive")
        if self.sensor_fit not in ("AUTO", "HORIZONTAL", "VERTICAL"):
            raise SceneError(f"camera: unknown sensor fit {self.sensor_fit!r}")
        if not (0 <= self.clip_start < self.clip_end):
            raise SceneError(f"camera: clipping range [{self.clip_start}, {self.clip_end}] is empty")
        basis = self.matrix_world[:3, :3]
        if abs(np.linalg.det(basis)) < 1e-12:
            raise SceneError("camera: matrix is singular (zero scale)")
        self.use_dof = bool(self.use_dof)
        for name in ("aperture_fstop", "focus_distance", "aperture_rotation", "aperture_ratio"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise SceneError(f"camera: depth of field {name} is {value}, it must be a finite number")
            setattr(self, name, value)
        for name in ("aperture_fstop", "focus_distance"):
            if getattr(self, name) < 0:
                raise SceneError(f"camera: depth of field {name} is {getattr(self, name)}, it must be >= 0")
        if not self.aperture_ratio > 0:
            raise SceneError(f"camera: depth of field aperture_ratio is {self.aperture_ratio}, it must be > 0")
        blades = self.aperture_blades
        try:
            whole = not isinstance(blades, bool) and float(blades).is_integer()
        except (TypeError, ValueError):
            whole = False
        if not whole or blades < 0:
            raise SceneError(f"camera: depth of field aperture_blades is {blades!r}, it must be a whole number >= 0")
        self.aperture_blades = int(blades)
        if self.motion_matrices is not None:
            steps = np.asarray(self.motion_matrices, np.float64)
            if steps.ndim != 3 or steps.shape[1:] != (4, 4) or not 2 <= steps.shape[0] <= MAX_MOTION_STEPS:
                raise SceneError(f"camera: motion_matrices must have shape (S, 4, 4) with 2 <= S <= "
                                 f"{MAX_MOTION_STEPS}, got {steps.shape}")
            if not np.all(np.isfinite(steps)):
                raise SceneError("camera: NaN/Inf in its motion-blur matrices")
            if np.any(np.abs(np.linalg.det(steps[:, :3, :3])) < 1e-12):
                raise SceneError("camera: a motion-blur matrix is singular (zero scale)")
            self.motion_matrices = None if np.all(steps == steps[:1]) else steps
        if self.vector_matrices is not None:
            vm = np.asarray(self.vector_matrices, np.float64)
            if vm.shape != (2, 4, 4) or not np.all(np.isfinite(vm)):
                raise SceneError(f"camera: vector_matrices must be two finite 4x4 matrices, got shape {vm.shape}")
            self.vector_matrices = vm
        if self.shutter_curve is not None:
            curve = np.asarray(self.shutter_curve, np.float64)
            if curve.ndim != 1 or len(curve) < 2 or not np.all(np.isfinite(curve)) or np.any(curve < 0) \
                    or not curve.sum() > 0:
                raise SceneError("camera: shutter_curve must be 2 or more finite values >= 0, not all 0 (how open "
                                 f"the shutter is over its time), got {np.array2string(curve, threshold=8)}")
            self.shutter_curve = None if np.all(curve == curve[0]) else curve
        if self.motion_lens is not None:
            lenses = tuple(float(x) for x in self.motion_lens)
            if len(lenses) != 2 or not all(math.isfinite(x) and x > 0 for x in lenses):
                raise SceneError(f"camera: motion_lens must be two focal lengths > 0 (shutter open, close), got "
                                 f"{self.motion_lens!r}")
            self.motion_lens = None if lenses == (self.lens, self.lens) else lenses
        if self.rolling_shutter is not None:
            duration = float(self.rolling_shutter)
            if not 0.0 <= duration <= 1.0:
                raise SceneError(f"camera: rolling_shutter duration {self.rolling_shutter} must be in [0, 1]")
            self.rolling_shutter = duration


# -------------------------------------------------------------------------------------------------------- film
@dataclass
class Film:
    """Blender's Film > Transparent settings (Cycles' conventions).

    transparent: camera rays that escape to the world add no world colour and count as transparent (alpha 0),
    as do rays that went on through a Transparent BSDF (a "refraction" lobe of IOR 1 and roughness 0).
    transparent_glass: rays that went on through glass or refraction lobes whose GGX alpha (roughness^2) is at
    most `transparent_roughness` count likewise (Film > Transparent Glass and its Roughness Threshold).
    Without `transparent` the world is opaque; holdout surfaces (`Material.holdout`) are transparent either way.

    shadow_catcher_pass: the view layer asks for Cycles' Shadow Catcher pass. With a shadow catcher mesh
    (`Mesh.shadow_catcher`) in the scene this picks how Combined is formed, as Cycles does: with the pass,
    Combined is the shadow catcher matte (the catchers transparent and black, their shadows only in the pass);
    without it, Cycles' approximate shadow catcher puts the shadows into Combined (as alpha with a transparent
    film, over the world otherwise).
    """

    transparent: bool = False
    transparent_glass: bool = False
    transparent_roughness: float = 0.1
    shadow_catcher_pass: bool = False

    def validate(self) -> None:
        if not (math.isfinite(self.transparent_roughness) and 0.0 <= self.transparent_roughness <= 1.0):
            raise SceneError(f"film: transparent glass roughness threshold {self.transparent_roughness} outside "
                             "[0, 1]")


MIST_FALLOFF = {"QUADRATIC": 2.0, "LINEAR": 1.0, "INVERSE_QUADRATIC": 0.5}  # Blender's falloff -> exponent


@dataclass
class Mist:
    """World > Mist Pass (Cycles' meaning, core.data_passes): start and depth in metres from the camera, falloff
    one of MIST_FALLOFF. Blender's defaults."""

    start: float = 5.0
    depth: float = 25.0
    falloff: str = "QUADRATIC"

    def validate(self) -> None:
        for name in ("start", "depth"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise SceneError(f"world mist {name} is {value!r}, it must be a finite number")
        if self.depth < 0:
            raise SceneError(f"world mist depth is {self.depth}, it must be >= 0")
        if self.falloff not in MIST_FALLOFF:
            raise SceneError(f"world mist falloff {self.falloff!r} is not one of {', '.join(MIST_FALLOFF)}")


# ------------------------------------------------------------------------------------------------------- scene
@dataclass
class Scene:
    """Everything a render needs. Build it, then call `validate()` (render does it for you)."""

    camera: Camera
    meshes: list[Mesh] = field(default_factory=list)
    materials: list[Material] = field(default_factory=list)
    lights: list[Light] = field(default_factory=list)
    world: World = field(default_factory=World)
    textures: list[Texture] = field(default_factory=list)
    name: str = "scene"
    warnings: list[str] = field(default_factory=list)
    objects: np.ndarray | None = None  # (O, core.shading.program.OBJECT_COLUMNS) float32 rows, see Mesh.object_index
    film: Film = field(default_factory=Film)
    uv_layer_names: list[str] = field(default_factory=list)  # the UV maps node programs name (uv_layer operand)
    # The data passes (core.data_passes): World > Mist Pass, and per row of `objects` the object's name and its
    # asset's (its top-most parent's) name, which Cryptomatte hashes; empty: the meshes' names stand in.
    mist: Mist = field(default_factory=lambda: Mist())
    object_names: list[str] = field(default_factory=list)
    asset_names: list[str] = field(default_factory=list)
    attribute_names: list[str] = field(default_factory=list)  # the attributes node programs name (attribute op)
    tangent_layer_names: list[str] = field(default_factory=list)  # Mesh.tangent_layers normal_map ops name ("" active)
    # Cycles' shader AOVs (core.shader_aovs): (name, "COLOR" | "VALUE") in the view layer's order; the node
    # programs' aov_output instructions index this list. Empty: no AOV pass, nothing kept.
    shader_aovs: list[tuple[str, str]] = field(default_factory=list)
    # Cycles' light groups (View Layer > Light Groups, core.light_groups): their names in the view layer's order;
    # emitters name theirs in `lightgroup`. Empty: no light group pass, nothing kept.
    light_groups: list[str] = field(default_factory=list)

    @property
    def has_alpha(self) -> bool:
        """Whether the image can have alpha below 1 (transparent film or a holdout material); otherwise the
        renderer keeps no transparency and alpha is 1 everywhere."""
        return (bool(self.film.transparent) or any(m.holdout > 0 for m in self.materials)
                or self.has_shadow_catcher)

    @property
    def has_shadow_catcher(self) -> bool:
        """Whether some mesh with triangles is a shadow catcher (Mesh.shadow_catcher): the render then keeps the
        shadow catcher's sums (core.film) and forms Combined as Cycles does with a catcher."""
        return any(m.shadow_catcher and m.triangle_count > 0 for m in self.meshes)

    @property
    def triangle_count(self) -> int:
        return sum(m.triangle_count for m in self.meshes)

    @property
    def has_motion(self) -> bool:
        """Whether anything moves over the shutter (motion blur): rays then carry a time (core.motion)."""
        return (self.camera.motion_matrices is not None or self.camera.motion_lens is not None
                or any(m.motion_vertices is not None for m in self.meshes))

    def validate(self, checked_meshes: Collection[int] = ()) -> "Scene":
        """Validate in place; raise SceneError for what cannot be rendered, drop and count what can be.

        checked_meshes: ids (id()) of meshes of this scene that an earlier validate() passed and that nobody has
        changed since, whose material and object indices the caller keeps in range (the viewport: a mesh kept
        across an update, with the material list only growing and the object table rebuilt around it); their
        per-triangle checks are skipped (a fraction of a second per million triangles) as long as their object
        indices fit the object table (else they are checked in full). Their light sets are checked as every
        mesh's."""
        self.camera.validate()
        self.film.validate()
        self.mist.validate()
        for tex in self.textures:
            tex.validate()
        if not self.materials:
            raise SceneError("scene has no materials: add at least one (meshes index into the material list)")
        for mat in self.materials:
            mat.validate(len(self.textures))
        self._validate_shader_aovs()
        self._validate_light_groups()
        n_objects = 0
        if self.objects is not None:
            from .shading.program import OBJECT_COLUMNS

            self.objects = np.ascontiguousarray(np.asarray(self.objects, np.float32).reshape(-1, OBJECT_COLUMNS))
            if not np.all(np.isfinite(self.objects)):
                raise SceneError("scene objects: NaN/Inf in the object table (a degenerate object transform?)")
            n_objects = len(self.objects)
        for mesh in self.meshes:
            if id(mesh) not in checked_meshes or not _object_index_fits(mesh, n_objects):
                mesh.validate(len(self.materials), self.warnings, n_objects)
            _validate_light_sets(mesh, f"mesh {mesh.name!r}")
        self.world.color = _as_rgb(self.world.color, "world background")
        if self.world.camera_color is not None:
            self.world.camera_color = _as_rgb(self.world.camera_color, "world background seen by the camera")
        if self.world.camera_environment is not None:
            try:
                self.world.camera_environment.validate(self.warnings)
            except EnvironmentMapError as exc:
                raise SceneError(str(exc)) from None
        if self.world.environment is not None:
            try:
                self.world.environment.validate(self.warnings)
            except EnvironmentMapError as exc:
                raise SceneError(str(exc)) from None
        if self.world.portals is not None:
            portals = np.asarray(self.world.portals, dtype=np.float64)
            if portals.ndim != 3 or portals.shape[1:] != (4, 3) or not np.isfinite(portals).all():
                raise SceneError(f"world portals must be a finite (P, 4, 3) array, got shape {portals.shape}")
            flat = np.linalg.norm(np.cross(portals[:, 1], portals[:, 2]), axis=1) <= 0
            if flat.any():
                self.warnings.append(f"{int(flat.sum())} light portal(s) of zero area are ignored")
            self.world.portals = portals[~flat] if len(portals[~flat]) else None
        kept: list[Light] = []
        for light in self.lights:
            _validate_light_sets(light, f"{type(light).__name__} {light.name!r}")
            if _validate_light(light, self.warnings):
                kept.append(light)
        self.lights = kept
        return self


    def _validate_shader_aovs(self) -> None:
        """Normalise Scene.shader_aovs to [(name, kind)]; SceneError for a bad entry (an empty or repeated name, an
        unknown type) or an AOV Output instruction naming no listed AOV."""
        from .shading.registry import OP_AOV_OUTPUT

        if isinstance(self.shader_aovs, str):
            raise SceneError(f"shader AOVs must be a list of (name, kind) pairs, got the string {self.shader_aovs!r}")
        checked: list[tuple[str, str]] = []
        for entry in self.shader_aovs:
            try:
                name, kind = entry
            except (TypeError, ValueError):
                raise SceneError(f"shader AOV {entry!r}: expected a (name, kind) pair") from None
            if not isinstance(name, str) or not name:
                raise SceneError(f"shader AOV {tuple(entry)!r}: the name must be a non-empty string")
            if kind not in SHADER_AOV_KINDS:
                raise SceneError(f"shader AOV {name!r}: unknown type {kind!r}; choose COLOR or VALUE")
            if any(name == n for n, _ in checked):
                raise SceneError(f"shader AOV {name!r} is listed twice")
            checked.append((name, kind))
        self.shader_aovs = checked
        for mat in self.materials:
            program = getattr(mat, "program", None)
            if program is None:
                continue
            code = program.code  # (I, WIDTH) int32 once Material.validate has run
            slots = code[code[:, 0] == OP_AOV_OUTPUT, 2]
            if len(slots) and (slots.min() < 0 or slots.max() >= len(self.shader_aovs)):
                raise SceneError(f"material {mat.name!r}: an AOV Output instruction names AOV {int(slots.max())}, "
                                 f"the scene lists {len(self.shader_aovs)} shader AOV(s)")


    def _validate_light_groups(self) -> None:
        """Normalise Scene.light_groups to a list of names; SceneError for an empty or repeated name or a non-string.
        An emitter naming a group not listed lights no group (as Cycles)."""
        if isinstance(self.light_groups, str):
            raise SceneError(f"light groups must be a list of names, got the string {self.light_groups!r}")
        checked: list[str] = []
        for name in self.light_groups:
            if not isinstance(name, str) or not name:
                raise SceneError(f"light group {name!r}: the name must be a non-empty string")
            if name in checked:
                raise SceneError(f"light group {name!r} is listed twice")
            checked.append(name)
        self.light_groups = checked


MAX_LIGHT_SETS = 64  # light sets 0..63, as Cycles' 64-bit membership masks


def _object_index_fits(mesh: Mesh, n_objects: int) -> bool:
    """Whether a validated mesh's object indices (None, or one int32 per triangle) lie in [0, n_objects)."""
    objs = mesh.object_index
    if objs is None:
        return True
    if not isinstance(objs, np.ndarray) or objs.dtype != np.int32 or objs.shape != (len(mesh.triangles),):
        return False
    return not objs.size or (int(objs.min()) >= 0 and int(objs.max()) < n_objects)


def _validate_light_sets(item, owner: str) -> None:
    """Light and shadow linking fields (see Mesh and Light): sets in [0, 63], masks of 64 bits."""
    for name in ("receiver_set", "blocker_set"):
        if not hasattr(item, name):
            continue
        value = getattr(item, name)
        if not isinstance(value, (int, np.integer)) or not 0 <= int(value) < MAX_LIGHT_SETS:
            raise SceneError(f"{owner}: {name} {value!r} must be an integer light set in [0, {MAX_LIGHT_SETS - 1}]")
    for name in ("light_sets", "shadow_sets"):
        value = getattr(item, name, -1)
        if not isinstance(value, (int, np.integer)) or not -(2 ** 63) <= int(value) < 2 ** MAX_LIGHT_SETS:
            raise SceneError(f"{owner}: {name} {value!r} must be an integer bitmask of light sets (-1: all)")


def _validate_light(light: Light, warnings: list[str]) -> bool:
    """Normalise a light's fields; return False (with a warning) for a light that emits nothing."""
    owner = f"{type(light).__name__} {light.name!r}"
    if isinstance(light, SunLight):
        light.strength = _as_rgb(light.strength, f"{owner} strength")
        d = _as_vec3(light.direction, f"{owner} direction")
        if np.linalg.norm(d) == 0:
            raise SceneError(f"{owner}: direction is the zero vector")
        light.direction = d / np.linalg.norm(d)
        if not (0.0 <= light.angle < math.pi):
            raise SceneError(f"{owner}: angle {light.angle} rad must be in [0, pi)")
        emits = np.any(light.strength > 0)
    else:
        light.power = _as_rgb(light.power, f"{owner} power")
        emits = np.any(light.power > 0)
        if isinstance(light, (PointLight, SpotLight)):
            light.position = _as_vec3(light.position, f"{owner} position")
            if not (light.radius >= 0 and math.isfinite(light.radius)):
                raise SceneError(f"{owner}: radius {light.radius} must be >= 0")
        if isinstance(light, SpotLight):
            d = _as_vec3(light.direction, f"{owner} direction")
            if np.linalg.norm(d) == 0:
                raise SceneError(f"{owner}: direction is the zero vector")
            light.direction = d / np.linalg.norm(d)
            if not (0.0 < light.spot_size <= math.pi):
                raise SceneError(f"{owner}: spot size {light.spot_size} rad must be in (0, pi]")
            if not (0.0 <= light.spot_blend <= 1.0):
                raise SceneError(f"{owner}: spot blend {light.spot_blend} must be in [0, 1]")
        if isinstance(light, AreaLight):
            light.matrix_world = _as_matrix(light.matrix_world, f"{owner} matrix")
            if light.shape not in ("SQUARE", "RECTANGLE", "DISK", "ELLIPSE"):
                raise SceneError(f"{owner}: unknown area shape {light.shape!r}")
            if light.shape in ("SQUARE", "DISK"):
                light.size_y = light.size_x
            if not (light.size_x > 0 and light.size_y > 0):
                warnings.append(f"{owner}: zero size, dropped")
                return False
            if not (0.0 < light.spread <= math.pi):
                raise SceneError(f"{owner}: spread {light.spread} rad must be in (0, pi]")
    if not emits:
        warnings.append(f"{owner}: emits nothing (zero power), dropped from light selection")
        return False
    return True
