"""The wavefront path tracer: a batch of paths advances one bounce at a time as structure-of-arrays.

Per bounce: intersect all live paths (Embree), add emission seen (MIS-weighted against light sampling), then
for each live path sample a light (next-event estimation with a shadow ray, MIS power heuristic) and the BSDF
for the next direction, apply Russian roulette, and compact away the dead. Bounce counting follows Cycles:
max_bounces B scatters at most B + 1 times (B = 0 still gives direct light at the first hit).

Geometry lives in a frame shifted by the camera position (float64 subtraction, then float32), so precision
is best where the camera looks, wherever the scene sits in the world.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import copy
import threading
import time

import numpy as np

from . import bsdf as bsdf_mod
from . import fused_tracer, geometry_kernels, path_kernels, transparent_shadow
from . import light_passes as lp_mod
from .accel import Accelerator, Hits, MotionTriangles
from .camera import PinholeRays
from .data_passes import DataPath
from .light_groups import LightGroups, LightGroupSamples, emission_shares
from .light_linking import LightLinks, ShadowLinks
from .shader_aovs import AovPath
from .light_shadow import NoShadowLights
from .light_visibility import LightVisibility
from .lights import EmissiveTriangles, LightSample, LightSampler
from .motion import interpolate_corners, resample_steps
from .ray_visibility import DIFFUSE_RAY, GLOSSY_RAY, RAY_KIND_NAMES, bounce_kinds, next_path_state
from .scene import Scene
from .settings import RenderSettings
from .shading import PreparedShading
from .textured_emitters import TexturedEmitters
from .world import environment_radiance
from .shading.program import (ATTRIBUTE_COLUMNS, MESH_ATTRIBUTE_COLUMNS, PATH_COLUMNS, PATH_DEPTH, PATH_FLAGS,
                              PATH_LENGTH, RAY_CAMERA)
from .shading.vector_context import VectorNeeds, vector_context

# Sampler dimension layout: film position first, the lens point (depth of field; its set is read only when the
# camera has an aperture, so a pinhole camera's numbers are unchanged), then a fixed block per bounce. The ray's
# time (motion blur) has a set of its own far past any bounce's, read only when the scene moves, so that a still
# scene's numbers are unchanged (every set is scrambled independently: its index is only a key).
DIM_FILM = 0
DIM_LENS = 1
DIM_BOUNCE_BASE = 2
DIM_STRIDE = 8
DIM_TIME = 0x7FFF0000
# Two sampler calls per bounce: a 4-D set for the vertex (BSDF direction in the stratified pair, whose first number
# also picks the lobe (rescaled within it: core.bsdf_kernels.sample_path), glass reflection vs refraction third,
# Russian roulette fourth) and a 3-D set for the light (point in the pair, which light third).
_D_VERTEX, _D_LIGHT = 1, 4

SHADOW_EPSILON = np.float32(1e-4)  # shadow rays stop this fraction short of the light (its own surface)
# Next-event estimation runs over at most this many paths at a time (its temporaries: see PathTracer._next_event)
NEE_CHUNK = 1 << 15


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _max3(v: np.ndarray) -> np.ndarray:
    """Largest of the 3 components per row (N,3) -> (N,): elementwise maxima, much faster than max(axis=1)."""
    return np.maximum(np.maximum(v[:, 0], v[:, 1]), v[:, 2])


class SurfaceBatch:
    """Surface interactions of M path vertices (see core.geometry_kernels.surface for each array's meaning).

    All of a vertex's values are one row of a single (M, K) float32 array, each field a column view of it, so
    that selecting the vertices that continue (`take`) is one row gather instead of one per field."""

    _VECTORS = ("p", "ng", "ns_raw", "ns", "tangent", "bitangent", "wo", "n_view", "dn")  # (M, 3) views
    _SCALARS = ("mag", "cos_o_geo")  # (M,) views
    _UV = 3 * len(_VECTORS) + len(_SCALARS)  # first uv column

    def __init__(self, data: np.ndarray) -> None:
        self.data = data

    @classmethod
    def empty(cls, m: int, with_uvs: bool) -> "SurfaceBatch":
        return cls(np.empty((m, cls._UV + (2 if with_uvs else 0)), np.float32))

    @property
    def uv_buffer(self) -> np.ndarray:
        """(M, 2) texture coordinates, or (M, 0) when the scene has no UVs."""
        return self.data[:, self._UV:self._UV + 2]

    @property
    def uv(self) -> np.ndarray | None:
        return self.uv_buffer if self.data.shape[1] > self._UV else None

    def take(self, rows: np.ndarray) -> "SurfaceBatch":
        return SurfaceBatch(self.data[rows])


def _column_views() -> None:
    """Give SurfaceBatch one property per field: a view of its columns in the packed array."""
    for i, name in enumerate(SurfaceBatch._VECTORS):
        setattr(SurfaceBatch, name, property(lambda self, c=3 * i: self.data[:, c:c + 3]))
    for i, name in enumerate(SurfaceBatch._SCALARS):
        setattr(SurfaceBatch, name, property(lambda self, c=3 * len(SurfaceBatch._VECTORS) + i: self.data[:, c]))


_column_views()


@dataclass
class PreparedScene:
    """A validated scene flattened for rendering: one triangle soup in the camera-shifted float32 frame."""

    scene: Scene
    shift: np.ndarray
    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (T, 3) int32
    tri_vertices: np.ndarray  # (T, 3, 3) float32
    face_normals: np.ndarray  # (T, 3) float32 unit, from the winding
    tri_magnitude: np.ndarray  # (T,) float32: largest |coordinate| of each triangle (ray offset scale)
    corner_normals: np.ndarray | None  # (T, 3, 3) float32 or None when every triangle is flat
    smooth: np.ndarray | None  # (T,) bool: triangle has shading normals
    uvs: np.ndarray | None  # (T, 3, 2) float32 or None
    material_index: np.ndarray  # (T,) int32
    materials: "bsdf_mod.MaterialTable"
    lights: LightSampler
    emissive: EmissiveTriangles | None
    has_nondelta: np.ndarray  # (M,) bool: material has a lobe that next-event estimation can reach
    radius: float
    specular: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # (M,) has a glossy/glass lobe
    features: dict = field(default_factory=dict)
    shading: PreparedShading | None = None  # the node programs of materials that vary per point, or None
    object_of_triangle: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # (T,) object rows
    # Alpha (Film > Transparent, holdout; see core.scene.Film): kept only when the scene can have alpha < 1.
    alpha: bool = False
    holdout: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))  # (M,) holdout weight
    # (M,) a path that goes through this material's surface (transmission) still counts as transparent
    keeps_transparent: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    # Ray visibility (core.scene.Mesh.visible_*): ray kind ("camera", "shadow", "diffuse", "glossy",
    # "transmission") -> (T,) bool of the triangles those rays see, only for kinds some mesh hides from (the
    # others cast against the whole scene, with no extra ray-casting structure).
    visible_to: dict = field(default_factory=dict)
    no_shadow: "NoShadowLights | None" = None  # lights whose Cast Shadow is off (core.light_shadow)
    has_clear: bool = False  # some material has a Transparent BSDF (a refraction lobe of IOR 1, roughness 0)
    # (T,) float32 Shadow Terminator Geometry Offset of each smooth triangle (0 on flat ones), None when all are 0
    terminator_offset: np.ndarray | None = None
    uv_layers: np.ndarray | None = None  # (T, K, 3, 2) the named UV maps of Scene.uv_layer_names, or None
    # (T,) bool: the triangle belongs to a shadow catcher (core.scene.Mesh.shadow_catcher); None when none does
    catcher: np.ndarray | None = None
    # (M,) bool: shadow rays go on through this material (core.transparent_shadow); None when no material does
    shadow_clear: np.ndarray | None = None
    # (T, A, 3, ATTRIBUTE_COLUMNS) the named attributes of Scene.attribute_names per corner, or None
    attributes: np.ndarray | None = None
    # emitters whose emission a node program drives, light-sampled by their own table (core.textured_emitters)
    textured: TexturedEmitters | None = None
    tangent_layers: np.ndarray | None = None  # (T, K, 3, 4) Scene.tangent_layer_names' tangents, or None
    # per material, which Vector-node inputs its program reads (computed for those points only), None without programs
    vector_needs: VectorNeeds | None = None
    # Motion blur (core.motion): the moving triangles' corners per step (shifted frame), their corner normals per
    # step ((S, M, 3, 3), None when they keep `corner_normals`) and each triangle's row among them (-1: still);
    # all None when nothing moves.
    motion: MotionTriangles | None = None
    motion_normals: np.ndarray | None = None
    motion_slot: np.ndarray | None = None
    moving_emitters: np.ndarray | None = None  # (T,) bool: emissive triangles that move (not light-sampled), or None
    # Light linking and shadow linking (core.light_linking); None when the scene uses none
    links: "LightLinks | None" = None
    shadow_links: "ShadowLinks | None" = None
    light_visibility: "LightVisibility | None" = None  # lights hidden from some bounce rays (core.light_visibility)
    light_groups: "LightGroups | None" = None  # Cycles' light groups (core.light_groups); None: the scene has none
    _subsets: dict = field(default_factory=dict)
    _subsets_lock: threading.Lock = field(default_factory=threading.Lock)

    def visible_subset(self, which: str) -> tuple[Accelerator, np.ndarray]:
        """(ray-casting structure of the triangles `which` rays (a key of visible_to, or "catcher": the rays of
        the shadow catcher's own paths, which see only catchers) see, the scene triangle index of each of its
        triangles), built once on first use."""
        with self._subsets_lock:
            found = self._subsets.get(which)
            if found is None:
                if which == "catcher":
                    mask = self.catcher
                elif which.startswith("blocker "):  # shadow linking: the blockers of set j (core.light_linking)
                    mask = self.shadow_links.blockers[int(which.split()[1])]
                    if "shadow" in self.visible_to:
                        mask = mask & self.visible_to["shadow"]
                else:
                    mask = self.visible_to[which]
                keep = np.flatnonzero(mask)
                motion = None if self.motion is None else self.motion.subset(keep)
                found = self._subsets[which] = (Accelerator(self.vertices, self.triangles[keep], motion=motion),
                                                keep.astype(np.int32))
            return found

    def update_camera(self, camera) -> None:
        """Make the node programs' Camera and Window coordinates follow `camera` (core.scene.Camera), for a
        prepared scene reused after the camera moved (the geometry's frame stays that of the first camera)."""
        if self.shading is not None:
            from .shading.program import camera_row

            self.shading.objects[-1] = camera_row(camera.matrix_world, camera.frame(), camera.kind)

    # The same per-triangle data as the compiled kernels take it: empty arrays instead of None.
    @property
    def kernel_corner_normals(self) -> np.ndarray:
        return self.corner_normals if self.corner_normals is not None else np.zeros((0, 3, 3), np.float32)

    @property
    def kernel_smooth(self) -> np.ndarray:
        return self.smooth if self.smooth is not None else np.zeros(0, bool)

    @property
    def kernel_uvs(self) -> np.ndarray:
        return self.uvs if self.uvs is not None else np.zeros((0, 3, 2), np.float32)

    @classmethod
    def build(cls, scene: Scene, sample_world: bool = False, threads: int = 1) -> "PreparedScene":
        """sample_world: whether light sampling may pick the (uniform) world, see LightSampler; only the
        light-sampling-only estimator needs it (it counts no emission that BSDF sampling finds). threads: how many
        threads may share the preparation's parallel parts (a world map's importance grid)."""
        shift = scene.camera.position.copy()
        verts, tris, mats, normals, uvs, smooth, objs, seen_by, terminator, layers = ([], [], [], [], [], [], [], [],
                                                                              [], [])
        catchers = []
        # per mesh: (triangles, light_sets, receiver_set), (triangles, shadow_sets, blocker_set)
        link_rows, shadow_rows = [], []
        group_index = {name: i for i, name in enumerate(scene.light_groups)}
        group_rows = []  # per mesh: its triangles' light group (core.light_groups), only with light groups
        layer_names = list(scene.uv_layer_names)
        attribute_names, attrs = list(scene.attribute_names), []
        tangent_names = list(scene.tangent_layer_names)
        tangent_parts = []
        offset = 0
        any_smooth = any(m.normals is not None for m in scene.meshes)
        any_uv = any(m.uvs is not None for m in scene.meshes)
        for mesh in scene.meshes:
            if mesh.triangle_count == 0:
                continue
            verts.append((np.asarray(mesh.vertices, np.float64) - shift).astype(np.float32))
            tris.append(mesh.triangles + offset)
            offset += len(mesh.vertices)
            mats.append(mesh.material_index)
            t = mesh.triangle_count
            # object rows: 0 is "no object" (identity), the scene's rows follow
            objs.append(np.zeros(t, np.int32) if mesh.object_index is None
                        else np.broadcast_to(np.asarray(mesh.object_index, np.int32) + 1, (t,)))
            seen_by.append((t, *(bool(getattr(mesh, f"visible_{kind}")) for kind in RAY_KINDS)))
            catchers.append(np.full(t, bool(mesh.shadow_catcher)))
            link_rows.append((t, int(mesh.light_sets), int(mesh.receiver_set)))
            shadow_rows.append((t, int(mesh.shadow_sets), int(mesh.blocker_set)))
            if group_index:
                group_rows.append(np.full(t, group_index.get(mesh.lightgroup, -1), np.int32))
            if layer_names:  # the named UV maps node programs read; (0, 0) where a mesh lacks one
                per = np.zeros((t, len(layer_names), 3, 2), np.float32)
                for j, lname in enumerate(layer_names):
                    if mesh.uv_layers and lname in mesh.uv_layers:
                        per[:, j] = mesh.uv_layers[lname]
                layers.append(per)
            if attribute_names:  # the named attributes Attribute nodes read; 0 where a mesh lacks one (Cycles)
                per = np.zeros((t, len(attribute_names), 3, ATTRIBUTE_COLUMNS), np.float32)
                for j, aname in enumerate(attribute_names):
                    if mesh.attributes and aname in mesh.attributes:
                        per[:, j, :, :MESH_ATTRIBUTE_COLUMNS] = mesh.attributes[aname]
                        per[:, j, :, MESH_ATTRIBUTE_COLUMNS] = 1.0  # found
                attrs.append(per)
            if tangent_names:  # the tangent layers Normal Map nodes read; zeros (no tangent) where a mesh lacks one
                per_t = np.zeros((t, len(tangent_names), 3, 4), np.float32)
                for j, lname in enumerate(tangent_names):
                    if mesh.tangent_layers and lname in mesh.tangent_layers:
                        per_t[:, j] = mesh.tangent_layers[lname]
                tangent_parts.append(per_t)
            if any_smooth:
                normals.append(mesh.normals if mesh.normals is not None else np.zeros((t, 3, 3), np.float32))
                smooth.append(np.full(t, mesh.normals is not None))
                terminator.append(np.full(t, float(mesh.shadow_terminator_offset) if mesh.normals is not None
                                          else 0.0, np.float32))
            if any_uv:
                uvs.append(mesh.uvs if mesh.uvs is not None else np.zeros((t, 3, 2), np.float32))
        vertices = np.concatenate(verts) if verts else np.zeros((0, 3), np.float32)
        triangles = np.concatenate(tris).astype(np.int32) if tris else np.zeros((0, 3), np.int32)
        material_index = np.concatenate(mats).astype(np.int32) if mats else np.zeros(0, np.int32)
        t_count = len(triangles)
        tri_vertices = np.empty((t_count, 3, 3), np.float32)
        face_normals = np.empty((t_count, 3), np.float32)
        tri_magnitude = np.empty(t_count, np.float32)
        # Triangles that became degenerate in float32 (huge coordinates) keep a zero normal and are harmless.
        geometry_kernels.triangle_frames(np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(triangles, np.int64),
                                tri_vertices, face_normals, tri_magnitude)
        corner_normals = np.concatenate(normals).astype(np.float32) if any_smooth and normals else None
        smooth_mask = np.concatenate(smooth) if any_smooth and smooth else None
        terminator_offset = np.concatenate(terminator) if any_smooth and terminator else None
        if terminator_offset is not None and not terminator_offset.any():
            terminator_offset = None  # nothing to do: shadow rays skip the terminator code entirely
        uv_arr = np.concatenate(uvs).astype(np.float32) if any_uv and uvs else None

        materials = bsdf_mod.MaterialTable.build(scene.materials, scene.textures)
        from .shading.program import camera_row, identity_object_row

        object_rows = [identity_object_row()[None]] + ([scene.objects] if scene.objects is not None else [])
        # the render camera last (Texture Coordinate's Camera and Window outputs)
        object_rows.append(camera_row(scene.camera.matrix_world, scene.camera.frame(), scene.camera.kind)[None])
        shading = PreparedShading.build(scene.materials, scene.textures, materials.max_lobes,
                                        np.concatenate(object_rows).astype(np.float32))
        object_of_triangle = np.concatenate(objs).astype(np.int32) if objs else np.zeros(0, np.int32)
        uv_layers = np.concatenate(layers) if layers else None
        attributes = np.concatenate(attrs) if attrs else None
        tangent_layers = np.concatenate(tangent_parts) if tangent_parts else None
        emissive = EmissiveTriangles.from_mesh_arrays(tri_vertices, material_index, materials.emission)
        motion, motion_normals, motion_slot = _motion_geometry(scene.meshes, shift, corner_normals, t_count)
        moving_emitters = None
        if motion is not None and emissive is not None:
            # Moving emitters are not light-sampled (the light table holds still triangles): what BSDF sampling
            # and the camera find counts in full, where the emitter is at the ray's time.
            moving_emitters = (emissive.emitter_of_triangle >= 0) & (motion_slot >= 0)
            if moving_emitters.any():
                still = tri_vertices.copy()
                still[moving_emitters] = 0.0  # zero area: not an emitter of the table
                emissive = EmissiveTriangles.from_mesh_arrays(still, material_index, materials.emission)
            else:
                moving_emitters = None
        if len(vertices):
            lo, hi = vertices.min(axis=0).astype(np.float64), vertices.max(axis=0).astype(np.float64)
            radius = float(np.linalg.norm(hi - lo) / 2) or 1.0
        else:
            radius = 1.0
        lights = LightSampler(scene, shift, emissive, radius, sample_world=sample_world, threads=threads)
        has_nondelta = np.array(
            [any(lobe.kind == "diffuse" or lobe.roughness > 0 for lobe in m.lobes) for m in scene.materials], bool
        )
        features = {
            "lobes": sorted(materials.kinds_present),
            "lights": sorted(lights.kinds_present),
            "textures": bool(scene.textures),
            "smooth_normals": corner_normals is not None,
            "node_programs": 0 if shading is None else int(shading.needs_program.sum()),
        }
        specular = np.array([any(lobe.kind != "diffuse" for lobe in m.lobes) for m in scene.materials], bool)
        alpha = scene.has_alpha
        features["alpha"] = alpha
        holdout = np.array([m.holdout for m in scene.materials], np.float32)
        keeps = np.array([_keeps_transparent(m, scene.film) for m in scene.materials], bool)
        visible_to = {kind: _visibility(seen_by, 1 + i) for i, kind in enumerate(RAY_KINDS)}
        visible_to = {kind: mask for kind, mask in visible_to.items() if mask is not None}
        features["ray_visibility"] = sorted(visible_to)
        no_shadow = NoShadowLights.build(scene.lights, shift)
        features["lights_without_shadow"] = no_shadow is not None
        links = LightLinks.build(scene, shift, emissive, radius, sample_world, link_rows, threads)
        shadow_links = ShadowLinks.build(scene.lights, shift, shadow_rows, emissive, vertices, triangles)
        features["light_linking"] = 0 if links is None else len(links.samplers)
        features["shadow_linking"] = 0 if shadow_links is None else len(shadow_links.sets)
        light_visibility = LightVisibility.build(scene.lights, shift)
        features["light_ray_visibility"] = light_visibility is not None
        catcher = np.concatenate(catchers) if catchers else np.zeros(0, bool)
        catcher = catcher if catcher.any() else None
        features["shadow_catcher"] = catcher is not None
        shadow_clear = transparent_shadow.clear_materials(materials)
        features["transparent_shadows"] = shadow_clear is not None
        features["moving_triangles"] = 0 if motion is None else len(motion.index)
        prepared = cls(scene, shift, vertices, triangles, tri_vertices, face_normals, tri_magnitude, corner_normals,
                   smooth_mask, uv_arr, material_index, materials, lights, emissive, has_nondelta, radius,
                   specular, features, shading, object_of_triangle,
                   alpha, holdout, keeps, visible_to, no_shadow,
                   any(lobe.kind == "refraction" and lobe.ior == 1.0 and lobe.roughness == 0.0
                       for m in scene.materials for lobe in m.lobes),
                   terminator_offset=terminator_offset, uv_layers=uv_layers, catcher=catcher,
                   shadow_clear=shadow_clear, attributes=attributes,
                   tangent_layers=tangent_layers, motion=motion,
                   motion_normals=motion_normals, motion_slot=motion_slot, moving_emitters=moving_emitters,
                   links=links, shadow_links=shadow_links, light_visibility=light_visibility,
                   vector_needs=None if shading is None else VectorNeeds.of(shading))
        if shading is not None and shading.any_emits:
            sampled = shading.emits
            # the estimate sees what light sampling sees: a first bounce's light sample (core.textured_emitters)
            nee_state = np.zeros((1, PATH_COLUMNS), np.float32)
            nee_state[0, PATH_DEPTH] = 1.0
            prepared.textured = TexturedEmitters.build(tri_vertices, material_index, sampled,
                                                       lambda t, b1, b2: emission_at(
                prepared, t, b1, b2, path=np.broadcast_to(nee_state, (len(t), PATH_COLUMNS))))
            features["textured_emitters"] = 0 if prepared.textured is None else prepared.textured.count
        if prepared.textured is not None or moving_emitters is not None:
            _warn_unlinked_emitters(scene, link_rows, shadow_rows, prepared.textured, moving_emitters)
        if group_index:
            emitting = np.zeros(len(triangles), bool)
            for table in (emissive, prepared.textured):
                if table is not None:
                    emitting[table.triangle_id] = True
            prepared.light_groups = LightGroups.build(
                scene, shift, np.concatenate(group_rows) if group_rows else np.zeros(0, np.int32), emitting,
                vertices, triangles)
        features["light_groups"] = 0 if prepared.light_groups is None else prepared.light_groups.count
        return prepared

    def hit_triangles(self, tri: np.ndarray, ray_time: np.ndarray | None) -> tuple:
        """The triangles `tri` (K,) as the rays that hit them at ray_time (K,) see them: (corners (K, 3, 3), face
        normals (K, 3), magnitudes (K,), corner normals (K, 3, 3) or an empty array), moving ones rebuilt at
        their ray's time (core.motion), still ones as prepared."""
        corners, normals, magnitude = self.tri_vertices[tri], self.face_normals[tri], self.tri_magnitude[tri]
        corner_normals = self.kernel_corner_normals
        if len(corner_normals):
            corner_normals = corner_normals[tri]
        slot = self.motion_slot[tri] if self.motion_slot is not None else None
        moving = np.flatnonzero(slot >= 0) if slot is not None and ray_time is not None else np.zeros(0, np.int64)
        if len(moving):
            at = interpolate_corners(self.motion.corners, slot[moving], ray_time[moving])
            frames = (np.empty((len(moving), 3, 3), np.float32), np.empty((len(moving), 3), np.float32),
                      np.empty(len(moving), np.float32))
            geometry_kernels.triangle_frames(np.ascontiguousarray(at.reshape(-1, 3)),
                                             np.arange(3 * len(moving), dtype=np.int64).reshape(-1, 3), *frames)
            corners[moving], normals[moving], magnitude[moving] = frames
            if self.motion_normals is not None:
                corner_normals[moving] = interpolate_corners(self.motion_normals, slot[moving], ray_time[moving])
        return corners, normals, magnitude, corner_normals


def _motion_geometry(meshes, shift: np.ndarray, corner_normals: np.ndarray | None,
                     t_count: int) -> tuple[MotionTriangles | None, np.ndarray | None, np.ndarray | None]:
    """PreparedScene's motion, motion_normals and motion_slot from the meshes' motion steps (all None when
    nothing moves), every mesh's steps resampled onto the largest step count."""
    parts, first = [], 0
    for mesh in meshes:
        if mesh.triangle_count == 0:
            continue
        if mesh.motion_vertices is not None:
            parts.append((first, mesh))
        first += mesh.triangle_count
    if not parts:
        return None, None, None
    steps = max(mesh.motion_vertices.shape[0] for _, mesh in parts)
    with_normals = corner_normals is not None and any(mesh.motion_normals is not None for _, mesh in parts)
    index, corners, normals = [], [], []
    for first, mesh in parts:
        t = mesh.triangle_count
        positions = resample_steps(mesh.motion_vertices, steps)
        corners.append((positions[:, mesh.triangles] - shift).astype(np.float32))
        index.append(np.arange(first, first + t))
        if with_normals:
            normals.append(resample_steps(mesh.motion_normals, steps).astype(np.float32)
                           if mesh.motion_normals is not None
                           else np.broadcast_to(corner_normals[first:first + t], (steps, t, 3, 3)))
    index = np.concatenate(index)
    slot = np.full(t_count, -1, np.int32)
    slot[index] = np.arange(len(index), dtype=np.int32)
    return (MotionTriangles(index, np.ascontiguousarray(np.concatenate(corners, axis=1))),
            np.ascontiguousarray(np.concatenate(normals, axis=1)) if with_normals else None, slot)


RAY_KINDS = ("camera", "shadow", "diffuse", "glossy", "transmission")  # core.scene.Mesh.visible_<kind>


def _warn_unlinked_emitters(scene: Scene, link_rows: list, shadow_rows: list, textured,
                            moving: np.ndarray | None) -> None:
    """Light and shadow linking are not applied to emitters whose emission a node program drives
    (core.textured_emitters) nor to moving ones: name the case in the scene's warnings when such an emitter has a
    receiver or a blocker set."""
    tris = np.concatenate([np.zeros(0, np.int64) if textured is None else np.asarray(textured.triangle_id),
                           np.zeros(0, np.int64) if moving is None else np.flatnonzero(moving)]).astype(np.int64)
    for rows, msg in (
            (link_rows, "light linking: an emissive mesh whose emission a node program drives, or that moves, "
                        "lights every object (its receiver collection is not applied)"),
            (shadow_rows, "shadow linking: an emissive mesh whose emission a node program drives, or that moves, "
                          "is blocked by every object (its blocker collection is not applied)")):
        emitter_set = np.concatenate([np.full(row[0], row[2], np.int64) for row in rows])
        if (emitter_set[tris] > 0).any() and msg not in scene.warnings:
            scene.warnings.append(msg)


def _shares_of_rows(shares: tuple, r: np.ndarray, m: int) -> tuple:
    """The light groups' (rows, (G, K, 3) shares) of M rays (Integrator._group_shares) restricted to the rays `r`,
    renumbered as rows of r."""
    rows, part = shares
    position = np.full(m, -1, np.int64)
    position[r] = np.arange(len(r))
    keep = position[rows] >= 0
    return position[rows[keep]], part[:, keep]


def _rows_of(state: np.ndarray | None, idx: np.ndarray) -> np.ndarray | None:
    """The path-state rows of samples `idx` (None when no state is kept)."""
    return None if state is None else state[idx]


def _visibility(seen_by: list[tuple], column: int) -> np.ndarray | None:
    """(T,) bool per triangle from each mesh's (triangle count, then a flag per RAY_KINDS) entry; None when all
    are seen."""
    if all(entry[column] for entry in seen_by):
        return None
    return np.concatenate([np.full(entry[0], entry[column]) for entry in seen_by])


def _keeps_transparent(material, film) -> bool:
    """Whether a path transmitted through `material` still counts as transparent for the film's alpha (Cycles'
    transparent background flag): every transmitting lobe is a Transparent BSDF (refraction, IOR 1, roughness 0),
    or, with Film > Transparent Glass, a glass/refraction lobe with GGX alpha = roughness^2 at most the threshold.
    A material with no transmitting lobe keeps nothing (nothing goes through it)."""
    through = [lobe for lobe in material.lobes if lobe.kind in ("glass", "refraction")]
    if not through:
        return False
    for lobe in through:
        clear = lobe.kind == "refraction" and lobe.ior == 1.0 and lobe.roughness == 0.0
        glass = film.transparent_glass and lobe.roughness * lobe.roughness <= film.transparent_roughness
        if not (clear or glass):
            return False
    return True


@dataclass
class PathStats:
    """Counters a render reports; seconds_* are thread-seconds per stage of the wavefront."""

    paths: int = 0
    nonfinite: int = 0
    clamped: int = 0
    seconds_camera: float = 0.0  # filter + camera rays
    seconds_intersect: float = 0.0  # Embree closest hits
    seconds_occluded: float = 0.0  # Embree shadow rays
    seconds_emission: float = 0.0  # surface interaction, emission seen (lights, emitters, world) + MIS
    seconds_nee: float = 0.0  # light sampling and BSDF evaluation (shadow rays excluded)
    seconds_scatter: float = 0.0  # BSDF sampling, Russian roulette, compaction, next rays

    STAGES = ("camera", "intersect", "occluded", "emission", "nee", "scatter")

    @classmethod
    def total(cls, parts: list["PathStats"]) -> "PathStats":
        out = cls()
        for part in parts:
            for name in cls.__dataclass_fields__:
                setattr(out, name, getattr(out, name) + getattr(part, name))
        return out

    def stage_seconds(self) -> dict[str, float]:
        return {name: getattr(self, f"seconds_{name}") for name in self.STAGES}


@dataclass
class CatcherSamples:
    """Per camera sample, what Cycles' shadow catcher keeps (core.film forms Combined and the Shadow Catcher pass
    from their pixel sums). A camera path (or one that went on through surfaces counting as transparent) that
    meets a shadow catcher splits there, once: the path itself goes on as usual (its radiance, the Combined sum,
    still sees every object), and a copy shades the catcher seeing only shadow catchers (no occluders, no other
    objects to reflect).

    matte: (N, 3) radiance the path gathered before it split (all of it when it never did): Cycles' Shadow
    Catcher Matte. matte_transparent: (N,) its transparency: the film's, plus the path's mean throughput where it
    split (the catcher leaves the matte). catcher: (N, 3) the copy's radiance (0 where no split). split: (N,) bool.
    background: (N, 3) the world seen along the camera ray where it escaped or met the catcher (Cycles'
    Background pass, which the approximate catcher on an opaque film lays under the matte), None when not
    needed."""

    matte: np.ndarray
    matte_transparent: np.ndarray
    catcher: np.ndarray
    split: np.ndarray
    background: np.ndarray | None

    def take(self, rows: np.ndarray) -> "CatcherSamples":
        return CatcherSamples(self.matte[rows], self.matte_transparent[rows], self.catcher[rows], self.split[rows],
                              None if self.background is None else self.background[rows])

    @classmethod
    def spread(cls, part: "CatcherSamples", rows: np.ndarray, n: int) -> "CatcherSamples":
        """The samples of `part` placed at `rows` of n samples, zero (no split) elsewhere."""
        out = cls(np.zeros((n, 3), np.float32), np.zeros(n, np.float32), np.zeros((n, 3), np.float32),
                  np.zeros(n, bool), None if part.background is None else np.zeros((n, 3), np.float32))
        out.matte[rows], out.matte_transparent[rows], out.catcher[rows] = part.matte, part.matte_transparent, \
            part.catcher
        out.split[rows] = part.split
        if part.background is not None:
            out.background[rows] = part.background
        return out


@dataclass
class _SplitPaths:
    """The state of the paths that split at a shadow catcher at one depth, to trace the catcher's copies from
    (see CatcherSamples): their sample rows and the ray that met the catcher."""

    depth: int
    rows: np.ndarray
    pix: np.ndarray
    smp: np.ndarray
    o: np.ndarray
    d: np.ndarray
    tmax: np.ndarray
    throughput: np.ndarray
    prev_pdf: np.ndarray
    prev_delta: np.ndarray
    prev_normal: np.ndarray | None
    prev_transmits: np.ndarray | None
    origin_class: np.ndarray | None = None  # light linking: the receiver class of each ray's origin
    # the paths' bounces and transparent bounces so far (None: not counted) and the kind of the ray that met the
    # catcher (core.ray_visibility; None: not kept), which the copies go on from
    bounces: np.ndarray | None = None
    transparent_bounces: np.ndarray | None = None
    bounce_kind: np.ndarray | None = None
    came_through: np.ndarray | None = None  # its last scatter went on through a Transparent BSDF


@dataclass
class FirstHit:
    """Per camera sample: the first-hit AOVs (albedo, world-space shading normal, z-depth, inf on a miss; None
    when not asked for), the denoising features (see DenoisingFeatures; None when not asked for) and the shadow
    catcher's samples (CatcherSamples; None when the scene has no shadow catcher)."""

    albedo: np.ndarray | None
    normal: np.ndarray | None
    depth: np.ndarray | None
    features: "DenoisingFeatures | None" = None
    catcher: "CatcherSamples | None" = None
    # The surfaces each path met while it still saw the background (core.data_passes.DataPath), for the data
    # passes; None when not asked for.
    surface: "DataPath | None" = None
    data: dict | None = None  # what each sample adds to the data passes (core.data_passes.DataTables.samples)
    light_passes: "lp_mod.LightPassSamples | None" = None  # Cycles' light passes (settings.light_passes)
    shader_aovs: "AovPath | None" = None  # what AOV Output nodes wrote (core.shader_aovs; Scene.shader_aovs)
    light_groups: "LightGroupSamples | None" = None  # Cycles' light groups (core.light_groups; Scene.light_groups)


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - np.float32(edge0)) / np.float32(edge1 - edge0), 0, 1)
    return (t * t * (3 - 2 * t)).astype(np.float32)


# Below this (max over R, G, B) the albedo a path's features would carry on with counts as none: they close.
FEATURE_DEFER_MIN = np.float32(1e-4)


class DenoisingFeatures:
    """Cycles' (Blender 5.3) Denoising Albedo and Denoising Normal of each camera sample, followed along the path.

    At each surface a path reaches while its features are open, each lobe l has its albedo A_l (core.bsdf.albedo at
    wo: Cycles' bsdf_albedo), weight w_l = mean(A_l) and a diffuse share d_l = smoothstep(0, 0.15, alpha_l)
    (alpha = roughness^2 for glossy/glass/refraction, 1 for diffuse): a mirror or clear glass is specular, a lobe
    with roughness >= 0.39 diffuse, in between a blend. With f = smoothstep(0, 0.5, sum w_l d_l / sum w_l) (0 when
    sum w_l = 0) and T the feature throughput (1 at the camera), the surface adds
        albedo += T f sum_l A_l d_l,      normal += mean(T) f n   (n: the shading normal on the viewer's side)
    and the features go on to the next surface with T *= sum_l A_l (1 - d_l) (1 - f), or close when that is below
    1e-4 (a diffuse surface, a black one, one without lobes). Emission and the world seen while the features are
    open add T x what they add to the image (a lamp seen directly reads its radiance). A path that ends adds
    nothing more (Russian roulette, from the third vertex on, ends a path before its surface is recorded where
    Cycles records it first: a difference only for features still open after two specular bounces). The normal is world space here; the render turns it to camera space. Pixel values are means over
    the samples, not renormalised (as Cycles' passes)."""

    def __init__(self, n: int) -> None:
        self.albedo = np.zeros((n, 3), np.float32)
        self.normal = np.zeros((n, 3), np.float32)
        self.throughput = np.ones((n, 3), np.float32)
        self.open = np.ones(n, bool)

    def add_emission(self, idx: np.ndarray, contribution: np.ndarray) -> None:
        """Emission added to the image for samples idx (their contributions, (M, 3)) while features are open."""
        rows = np.flatnonzero(self.open[idx])
        if len(rows):
            samples = idx[rows]
            value = np.nan_to_num(self.throughput[samples] * contribution[rows], nan=0.0, posinf=0.0)
            np.add.at(self.albedo, samples, value.astype(np.float32))

    def record(self, idx: np.ndarray, lobes: "bsdf_mod.LobeBatch", wo: np.ndarray, n_view: np.ndarray) -> None:
        """Surfaces hit by the paths of samples idx (their lobes, wo in the shading frame, the normal)."""
        rows = np.flatnonzero(self.open[idx])
        if len(rows) == 0:
            return
        lob = lobes.take(rows) if len(rows) < len(idx) else lobes
        samples = idx[rows]
        wo_rows = np.ascontiguousarray(wo[rows])
        m, n_slots = lob.kind.shape
        diffuse_albedo = np.zeros((m, 3), np.float32)
        specular_albedo = np.zeros((m, 3), np.float32)
        weight = np.zeros(m, np.float32)
        weight_diffuse = np.zeros(m, np.float32)
        slot_of = np.arange(n_slots)[None, :]
        for slot in range(n_slots):
            present = lob.kind[:, slot] >= 0
            if not present.any():
                continue
            only = replace(lob, kind=np.where(slot_of == slot, lob.kind, -1).astype(np.int8))
            albedo = bsdf_mod.albedo(only, wo_rows)  # 0 where the slot is empty
            alpha = np.where(lob.kind[:, slot] == bsdf_mod.DIFFUSE, np.float32(1),
                             lob.roughness[:, slot].astype(np.float32) ** 2)
            share = _smoothstep(0.0, 0.15, alpha)[:, None]
            diffuse_albedo += albedo * share
            specular_albedo += albedo * (1 - share)
            w = albedo.mean(axis=1)
            weight += w
            weight_diffuse += w * share[:, 0]
        lit = weight > 0
        f = np.where(lit, _smoothstep(0.0, 0.5, weight_diffuse / np.where(lit, weight, 1)), np.float32(0))
        t = self.throughput[samples]
        self.albedo[samples] += t * diffuse_albedo * f[:, None]
        self.normal[samples] += n_view[rows] * (f * t.mean(axis=1))[:, None]
        deferred = specular_albedo * (1 - f)[:, None]
        go_on = np.abs(deferred).max(axis=1) > FEATURE_DEFER_MIN
        self.throughput[samples[go_on]] = t[go_on] * deferred[go_on]
        self.open[samples[~go_on]] = False


class _CatcherState:
    """A batch's shadow catcher bookkeeping while its paths are traced (see CatcherSamples)."""

    def __init__(self, n: int, background: bool) -> None:
        self.matte = np.zeros((n, 3), np.float32)
        self.matte_transparent = np.zeros(n, np.float32)
        self.split = np.zeros(n, bool)
        self.background = np.zeros((n, 3), np.float32) if background else None
        self.groups: list[_SplitPaths] = []

    def visit(self, tracer: "PathTracer", depth, hit, prim, clear_here, idx, pix, smp, o, d, tm, throughput,
              prev_pdf, prev_delta, prev_normal, prev_transmits, radiance, transparent, origin_class=None,
              bounces=None, transparent_bounces=None, bounce_kind=None, came_through=None) -> None:
        """The live paths' rays at `depth` have been intersected: paths that still count as transparent and meet
        a catcher for the first time split here (before anything at this vertex is added). origin_class: the
        receiver class of each sample's ray origin (light linking) or None; bounces, transparent_bounces,
        bounce_kind, came_through: per sample, the path's bounce counters, its ray's kind and whether it came
        through a Transparent BSDF, or None where not kept."""
        ps = tracer.ps
        if self.background is not None:  # the world along camera rays that escape (Cycles' Background pass)
            gone = np.flatnonzero(~hit & clear_here)
            if len(gone):
                self.background[idx[gone]] += throughput[gone] * self._world(tracer, o[gone], d[gone])
        on = np.flatnonzero(hit & clear_here & ps.catcher[np.where(hit, prim, 0)] & ~self.split[idx])
        if len(on) == 0:
            return
        rows = idx[on]
        self.split[rows] = True
        self.matte[rows] = radiance[rows]
        self.matte_transparent[rows] = (0 if transparent is None else transparent[rows]) + throughput[on].mean(axis=1)
        if self.background is not None:
            self.background[rows] += throughput[on] * self._world(tracer, o[on], d[on])
        self.groups.append(_SplitPaths(depth, rows, pix[on], smp[on], o[on], d[on], tm[on], throughput[on],
                                       prev_pdf[on], prev_delta[on],
                                       None if prev_normal is None else prev_normal[on],
                                       None if prev_transmits is None else prev_transmits[on],
                                       None if origin_class is None else origin_class[rows],
                                       *(None if a is None else a[rows].copy()
                                         for a in (bounces, transparent_bounces, bounce_kind, came_through))))

    @staticmethod
    def _world(tracer: "PathTracer", o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """The world (and lights visible to the camera) along rays, as a camera ray that escapes sees it."""
        m = len(o)
        return tracer.ps.lights.intersect(o, d, np.full(m, np.inf, np.float32), np.zeros(m, np.float32),
                                          np.ones(m, bool), False, camera=True)

    def finish(self, tracer: "PathTracer", radiance: np.ndarray, transparent: np.ndarray | None) -> CatcherSamples:
        """The batch's CatcherSamples once its paths are done: trace the copies, fill the paths that never split."""
        n = len(radiance)
        catcher = np.zeros((n, 3), np.float32)
        for group in self.groups:
            catcher[group.rows] = tracer._trace_copies(group)
        keep = ~self.split
        self.matte[keep] = radiance[keep]
        self.matte_transparent[keep] = 0 if transparent is None else transparent[keep]
        np.clip(self.matte_transparent, 0.0, 1.0, out=self.matte_transparent)
        return CatcherSamples(self.matte, self.matte_transparent, catcher, self.split, self.background)


class PathTracer:
    """Traces batches of camera rays through a prepared scene and returns each sample's radiance."""

    def __init__(self, prepared: PreparedScene, accel: Accelerator, settings: RenderSettings, sampler) -> None:
        self.ps = prepared
        self.accel = accel
        self.settings = settings
        self.sampler = sampler
        self.stats = PathStats()
        self.use_nee = settings.light_sampling in ("mis", "light") and (prepared.lights.has_lights
                                                                       or prepared.textured is not None)
        self.use_bsdf_emission = settings.light_sampling in ("mis", "bsdf")
        self.mis = settings.light_sampling == "mis"
        self._catcher_copies = False  # tracing shadow catcher copies: rays see only catchers (CatcherSamples)
        self._resume: _SplitPaths | None = None  # the copies' state at their split, while _catcher_copies
        # the fused path kernel (core.fused_tracer) where the scene allows it; None: the per-bounce loop below
        self.fused_reason = fused_tracer.supports(self)
        self.fused = fused_tracer.FusedTracer(self, SHADOW_EPSILON) if self.fused_reason is None else None

    def _dim(self, depth: int, k: int) -> int:
        return DIM_BOUNCE_BASE + depth * DIM_STRIDE + k

    def trace(
        self,
        pixel_id: np.ndarray,
        sample_id: np.ndarray,
        origins: np.ndarray | None,
        directions: np.ndarray | None,
        tmax: np.ndarray | None,
        depth_scale: np.ndarray | None,
        t_start: np.ndarray | None,
        want_aovs: bool,
        want_features: bool = False,
        want_surface: bool = False,
        ray_dp: np.ndarray | None = None,
        ray_dd: np.ndarray | None = None,
        ray_time: np.ndarray | None = None,
        camera: PinholeRays | None = None,
    ) -> tuple[np.ndarray, FirstHit | None, np.ndarray | None]:
        """Radiance (N, 3) float32 of N camera paths, their first-hit AOVs (want_aovs; want_features adds the
        denoising features, FirstHit.features; a scene with a shadow catcher adds FirstHit.catcher) and their
        transparency (N,) float32 in [0, 1] (alpha = 1 - transparency; None when the scene has no alpha, see
        core.scene.Film). pixel_id/sample_id (uint32) key the random numbers. While _trace_copies runs, the
        paths are the shadow catcher copies of paths that split (the camera ray arguments are theirs). ray_dp, ray_dd (N,) float32: the camera
        rays' compact differentials (Cycles' ray dP and dD: the spread of a pixel's footprint at the origin and its
        growth per unit distance), which Bump nodes read; None: zero. ray_time: (N,) each path's time in [0, 1]
        over the shutter (motion blur; its bounces and shadow rays keep it), None for a still scene. camera: a pinhole
        camera's rays not made yet, in place of the five camera ray arrays (None each), and of ray_dp and ray_dd
        where the scene's programs read differentials: the fused kernel makes them per path, as needed."""
        ps, s = self.ps, self.settings
        if (self.fused is not None and not (want_features or want_surface or self._catcher_copies)
                and ray_time is None):
            self.stats.paths += len(pixel_id)
            radiance, aovs = self.fused.trace(pixel_id, sample_id, origins, directions, tmax, depth_scale, t_start,
                                              want_aovs, self.stats, ray_dp, ray_dd, camera)
            return radiance, None if aovs is None else FirstHit(*aovs), None
        if camera is not None:  # this loop takes every path's ray, and its differentials where programs read them
            rays = camera.rays()
            if ps.shading is not None and ps.shading.needs_differentials and ray_dp is None:
                ray_dp, ray_dd = camera.footprints(rays)
            origins, directions, tmax, depth_scale, t_start = (rays.origins, rays.directions, rays.tmax,
                                                               rays.depth_scale, rays.t_start)
            rays = camera = None
        n = len(origins)
        radiance = np.zeros((n, 3), np.float32)
        first = None
        if want_aovs:
            first = FirstHit(np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32), np.full(n, np.inf, np.float32))
        features = None
        if want_features:
            features = DenoisingFeatures(n)
            if first is None:
                first = FirstHit(None, None, None)
            first.features = features
        data_path = None
        if want_surface:  # FirstHit.surface records what the data passes need (core.data_passes.DataPath)
            if first is None:
                first = FirstHit(None, None, None)
            data_path = first.surface = DataPath(n, ps)
        lp = None  # the light passes (core.light_passes), only when the render asks for one
        if s.light_passes:
            lp = lp_mod.LightPassSamples(n)
            if first is None:
                first = FirstHit(None, None, None)
            first.light_passes = lp
        lg = None  # the light groups (core.light_groups), only when the scene has some
        if ps.light_groups is not None and not self._catcher_copies:
            lg = LightGroupSamples(n, ps.light_groups.count)
            if first is None:
                first = FirstHit(None, None, None)
            first.light_groups = lg
        aov_path = None  # the shader AOVs (core.shader_aovs), only when some material writes one
        if ps.scene.shader_aovs and ps.shading is not None and ps.shading.writes_aovs and not self._catcher_copies:
            aov_path = AovPath(n, len(ps.scene.shader_aovs), ps)
            if first is None:
                first = FirstHit(None, None, None)
            first.shader_aovs = aov_path
        idx = np.arange(n)  # which sample each live path belongs to
        o, d, tm = origins, directions, tmax
        throughput = np.ones((n, 3), np.float32)
        prev_pdf = np.zeros(n, np.float32)
        prev_delta = np.ones(n, bool)  # camera rays: emission seen directly gets weight 1
        prev_normal = None  # shading normal at each ray's origin (light sampling and MIS use it)
        prev_transmits = None  # whether the material at each ray's origin transmits (weighs light selection)
        pix, smp = pixel_id, sample_id
        self.stats.paths += n
        start_depth = 0
        copies = self._catcher_copies
        if copies:  # resuming the catcher copies (_trace_copies): the paths' state at their split
            sp = self._resume
            start_depth, n = sp.depth, len(sp.rows)
            radiance = np.zeros((n, 3), np.float32)
            idx, o, d, tm, throughput = np.arange(n), sp.o, sp.d, sp.tmax, sp.throughput.copy()
            prev_pdf, prev_delta, prev_normal, prev_transmits = sp.prev_pdf, sp.prev_delta, sp.prev_normal, \
                sp.prev_transmits
            pix, smp = sp.pix, sp.smp
        alpha = ps.alpha and not copies
        transparent = np.zeros(n, np.float32) if alpha else None
        # Ray differentials as Cycles' CPU path keeps them (compact: one spread per ray): at a hit the footprint is
        # dP + t dD; a bounce ray starts with the hit's footprint and keeps the camera ray's dD. Kept per sample,
        # only when some Bump node reads them.
        sample_dp = sample_dd = None
        if ps.shading is not None and ps.shading.needs_differentials:
            sample_dp = np.zeros(n, np.float32) if ray_dp is None else np.asarray(ray_dp, np.float32).copy()
            sample_dd = np.zeros(n, np.float32) if ray_dd is None else np.asarray(ray_dd, np.float32)
        # Per sample: the path still counts as transparent (camera ray, or only through transparent surfaces).
        clear = np.ones(n, bool) if alpha else None
        film_transparent = alpha and ps.scene.film.transparent
        # Per sample: the kind of ray its path casts next (core.ray_visibility), kept only when some mesh hides
        # from diffuse, glossy or transmission rays, or some light does (core.light_visibility).
        # The catcher copies keep it where some light hides from some kind (their rays see only catchers).
        bounce_kind = (np.zeros(n, np.int8) if (not copies and (
            any(k in ps.visible_to for k in ("diffuse", "glossy", "transmission"))
            or ("camera" in ps.visible_to and ps.has_clear))) or ps.light_visibility is not None else None)
        if bounce_kind is not None and copies and self._resume.bounce_kind is not None:
            bounce_kind[:] = self._resume.bounce_kind
        catch = _CatcherState(n, self._needs_background()) if ps.catcher is not None and not copies else None
        # Shadow rays go through Transparent BSDFs: so does MIS (core.transparent_shadow.MisOrigins)
        through = transparent_shadow.MisOrigins.start(o) if ps.shadow_clear is not None else None
        # Per sample: the Light Path node's state of the ray it casts (core.shading.program PATH_*), kept only
        # when some node program reads it.
        # Per sample: the receiver class (core.light_linking) of the object its ray leaves, when linking is used
        origin_class = np.zeros(n, np.int32) if ps.links is not None else None
        if origin_class is not None and copies and self._resume.origin_class is not None:
            origin_class[:] = self._resume.origin_class
        path_state = None
        if ps.shading is not None and ps.shading.uses_light_path:
            path_state = np.zeros((n, PATH_COLUMNS), np.float32)
            path_state[:, PATH_FLAGS] = RAY_CAMERA
        # Per sample: its bounces so far and, apart, its passes straight through Transparent BSDFs, which Cycles
        # counts as transparent bounces up to Transparent Max Bounces and not as bounces (a transparent card does
        # not use up max_bounces). Kept only when some material has a Transparent BSDF lobe (the catcher copies
        # go on from their paths' counts at the split).
        # came_through: per sample, its last scatter went on through a Transparent BSDF (Russian roulette then
        # counts transparent bounces against transparent_rr_depth, as Cycles).
        bounces = transparent_bounces = came_through = None
        transparent_limit = max(int(s.transparent_max_bounces), 1)  # Cycles: the next surface after the limit ends it
        transparent_rr_depth = int(s.transparent_min_bounces) + 2
        last_vertex = s.max_bounces + 1
        if through is not None:
            bounces, transparent_bounces = np.zeros(n, np.int32), np.zeros(n, np.int32)
            came_through = np.zeros(n, bool)
            if copies and self._resume.bounces is not None:
                bounces[:], transparent_bounces[:] = self._resume.bounces, self._resume.transparent_bounces
                came_through[:] = self._resume.came_through
            last_vertex += transparent_limit

        for depth in range(start_depth, last_vertex + 1):
            if len(idx) == 0:
                break
            clock = time.perf_counter()
            # the live paths' times; none where the ray-casting structure has no motion (embreex's fallback renders
            # the frame's pose, and so must the surfaces)
            tr = None if ray_time is None or self.accel.motion is None else ray_time[idx]
            if copies:
                hits = self._intersect_subset("catcher", o, d, tm, tr)
            elif bounce_kind is not None:
                hits = self._intersect_by_kind(bounce_kind[idx], o, d, tm, tr)
            elif depth == 0 and "camera" in ps.visible_to:
                hits = self._intersect_subset("camera", o, d, tm, tr)
            else:
                hits = self.accel.intersect(o, d, tm, tr)
            clock = self._lap("intersect", clock)
            hit = hits.prim >= 0
            if path_state is not None:  # Ray Length: the distance along this ray to the point shaded
                path_state[idx, PATH_LENGTH] = np.where(hit, hits.t, np.float32(0))
            hit_dp = None  # (live paths,) the footprint at each hit (Cycles' sd->dP)
            if sample_dp is not None:
                hit_dp = np.where(hit, sample_dp[idx] + np.where(hit, hits.t, 0) * sample_dd[idx],
                                  0).astype(np.float32)
                sample_dp[idx[hit]] = hit_dp[hit]
            # Emission from analytic lights (area, sphere lights, sun disc) and the world along the ray.
            clear_here = clear[idx] if alpha else None
            if catch is not None:
                catch.visit(self, depth, hit, hits.prim, clear_here, idx, pix, smp, o, d, tm, throughput, prev_pdf,
                            prev_delta, prev_normal, prev_transmits, radiance, transparent, origin_class,
                            bounces, transparent_bounces, bounce_kind, came_through)
            if film_transparent:
                # Rays that still count as transparent and escape: alpha 0 and no world colour.
                gone = np.flatnonzero(~hit & clear_here)
                transparent[idx[gone]] += throughput[gone].mean(axis=1)
            if ps.lights.has_emission or ps.scene.world.camera_color is not None \
                    or ps.scene.world.camera_environment is not None:
                mis_here = self.mis and depth > 0
                t_hit = np.where(hit, hits.t, np.float32(np.inf))
                classes = None if origin_class is None or depth == 0 else origin_class[idx]
                kinds = (None if ps.light_visibility is None or bounce_kind is None or depth == 0
                         else bounce_kind[idx])
                # Camera rays, and as in Cycles camera rays that went on through Transparent BSDFs only (they keep
                # the camera ray's visibility): they see the lights visible to the camera and the camera backdrop.
                camera_rays = depth == 0 if depth == 0 or bounces is None else bounces[idx] == 0
                le = self._light_emission(o, d, t_hit, prev_pdf, prev_delta, mis_here, prev_normal, camera_rays,
                                          prev_transmits, clear_here if film_transparent else None, classes, kinds)
                if through is not None:
                    through.light_emission(self, le, d, t_hit, prev_pdf, prev_delta, mis_here, prev_normal,
                                           prev_transmits, clear_here if film_transparent else None, classes,
                                           kinds, camera_rays)
                backdrop = ps.scene.world.camera_color
                backdrop_map = ps.scene.world.camera_environment
                if np.any(camera_rays) and (backdrop is not None or backdrop_map is not None) \
                        and not film_transparent:
                    # camera rays that escape see the world's camera-only backdrop instead of the background
                    gone = np.flatnonzero(~hit & camera_rays)
                    if len(gone):
                        seen = (environment_radiance(backdrop_map, d[gone]) if backdrop_map is not None
                                else np.asarray(backdrop, np.float32))
                        le[gone] = seen + self.ps.lights.intersect(
                            o[gone], d[gone], np.full(len(gone), np.inf, np.float32), prev_pdf[gone],
                            prev_delta[gone], False, camera=True, world=False)
                if depth > 0 and not self.use_bsdf_emission:
                    # Light sampling only: emission reached by BSDF sampling counts after delta scattering only.
                    le = np.where(prev_delta[:, None], le, np.float32(0))
                shares = None
                if lg is not None:  # each light group's share of it (core.light_groups)
                    shares = self._group_shares(le, o, d, t_hit, prev_pdf, prev_delta, mis_here, prev_normal,
                                                camera_rays, prev_transmits, clear_here if film_transparent else None,
                                                classes, kinds)
                if lp is not None and (depth == 0 or (bounces is not None and not bounces[idx].all())):
                    # seen by the camera, directly or through Transparent BSDFs only: Emission / Environment
                    seen = np.ones(len(idx), bool) if depth == 0 else bounces[idx] == 0
                    r = np.flatnonzero(seen)
                    clean = self._add_camera_light(radiance, lp, idx[r], (throughput * le)[r], o[r], d[r], t_hit[r],
                                                   prev_pdf[r], prev_delta[r])
                    if lg is not None:
                        lg.add(idx[r], clean, _shares_of_rows(shares, r, len(idx)))
                    r = np.flatnonzero(~seen)
                    if len(r):
                        self._add_split(radiance, lp, bounces[idx[r]], idx[r], (throughput * le)[r], lg,
                                        None if lg is None else _shares_of_rows(shares, r, len(idx)))
                else:
                    self._add_split(radiance, lp, depth if bounces is None else bounces[idx], idx, throughput * le,
                                    lg, shares)
                if features is not None:
                    features.add_emission(idx, throughput * le)
            prim = hits.prim
            held = None
            if alpha:
                # Holdout surfaces seen by transparent-counting rays: that share of the throughput becomes
                # transparent; a full holdout ends the path there (no emission, no scattering), as in Cycles.
                h = np.where(hit & clear_here, ps.holdout[ps.material_index[prim]], np.float32(0))
                seen = np.flatnonzero(h > 0)
                if len(seen):
                    transparent[idx[seen]] += h[seen] * throughput[seen].mean(axis=1)
                    held = h >= 1
                    if aov_path is not None and held.any():  # Cycles evaluates the shader before the holdout
                        self._holdout_aovs(aov_path, np.flatnonzero(held), idx, prim, hits, d, tr, path_state, hit_dp)

            # Emission of an emissive triangle hit (two-sided), MIS-weighted against light sampling.
            if ps.emissive is not None:
                em_idx = ps.emissive.emitter_of_triangle[prim]  # prim -1 (a miss) reads a value masked out here
                e = np.flatnonzero(hit & (em_idx >= 0) & (True if held is None else ~held))
                if len(e):
                    em_idx, t_e = em_idx[e], hits.t[e]
                    le = ps.materials.emission[ps.material_index[prim[e]]]
                    if depth == 0 or not self.use_nee:
                        w = np.ones(len(e), np.float32)
                    elif not self.use_bsdf_emission:
                        w = prev_delta[e].astype(np.float32)
                    else:
                        cos_e = np.abs(_dot(d[e], ps.face_normals[prim[e]]))
                        o_e, t_e = (o[e], t_e) if through is None else through.origin_and_distance(e, t_e)
                        if origin_class is None:
                            pdf_l = ps.lights.pdf_triangle(em_idx, o_e, t_e * t_e, cos_e, n=prev_normal[e],
                                                           transmits=prev_transmits[e])
                        else:  # light linking: the selection of the ray's origin's class
                            _, pdf_l = ps.links.triangle_weights(origin_class[idx[e]], em_idx, o_e, t_e * t_e,
                                                                 cos_e, prev_normal[e], prev_transmits[e])
                        pb = prev_pdf[e]
                        w = np.where(prev_delta[e], 1.0, pb * pb / np.maximum(pb * pb + pdf_l * pdf_l, 1e-30))
                    if origin_class is not None and depth > 0:  # an emitter not linked to the ray's origin
                        cls_e = origin_class[idx[e]]
                        w = w * ps.links.emitter_linked[cls_e, em_idx]
                    if (ps.shadow_links is not None and ps.shadow_links.emitter_set is not None and depth > 0
                            and self.mis and self.use_nee):
                        # shadow-linked emitters count from light sampling alone after a non-delta bounce
                        # (core.light_linking)
                        w = w * ~(ps.shadow_links.hides_triangles(prim[e]) & ~prev_delta[e])
                    self._add_split(radiance, lp, depth if bounces is None else bounces[idx[e]], idx[e],
                                    throughput[e] * le * w[:, None].astype(np.float32),
                                    lg, None if lg is None else ps.light_groups.group_of_triangle[prim[e]])
                    if features is not None:
                        features.add_emission(idx[e], throughput[e] * le * w[:, None].astype(np.float32))
            # Moving emitters are not light-sampled: what BSDF sampling (or the camera) finds counts in full.
            if ps.moving_emitters is not None:
                e = np.flatnonzero(hit & ps.moving_emitters[np.maximum(prim, 0)] & (True if held is None else ~held))
                if len(e):
                    le = ps.materials.emission[ps.material_index[prim[e]]]
                    self._add_split(radiance, lp, depth if bounces is None else bounces[idx[e]], idx[e],
                                    throughput[e] * le,
                                    lg, None if lg is None else ps.light_groups.group_of_triangle[prim[e]])
                    if features is not None:
                        features.add_emission(idx[e], throughput[e] * le)
            # Emission that varies per point (a node program drives it): MIS-weighted against the textured
            # emitters' light sampling (core.textured_emitters) where they are in its table, else (programs that
            # read the Light Path node) what BSDF sampling (or the camera) finds counts in full.
            if ps.shading is not None and ps.shading.any_emits:
                e = np.flatnonzero(hit & ps.shading.emits[ps.material_index[prim]] & (True if held is None else ~held))
                if len(e):
                    ge = self._surface(e, prim, hits.u, hits.v, d, tr)
                    mat_e = ps.material_index[prim[e]]
                    le = np.zeros((len(e), 3), np.float32)
                    self._shade(ge, mat_e, prim[e], d[e], ps.materials.gather(mat_e, ge.uv), le,
                                bary=(hits.u[e], hits.v[e]), path=_rows_of(path_state, idx[e]),
                                dp=None if hit_dp is None else hit_dp[e])
                    if ps.textured is not None and depth > 0 and self.use_nee:
                        em = ps.textured.emitter_of_triangle[prim[e]]
                        sampled = em >= 0
                        if not self.use_bsdf_emission:  # light sampling only: BSDF hits count after delta only
                            w = np.where(sampled, prev_delta[e], True).astype(np.float32)
                        else:
                            t_e = hits.t[e] if through is None else through.origin_and_distance(e, hits.t[e])[1]
                            cos_e = np.abs(_dot(d[e], ps.face_normals[prim[e]]))
                            pdf_l = np.where(sampled, ps.textured.pdf(np.maximum(em, 0), t_e * t_e, cos_e), 0)
                            pb = prev_pdf[e]
                            w = np.where(prev_delta[e], 1.0, pb * pb / np.maximum(pb * pb + pdf_l * pdf_l, 1e-30))
                        le = le * w[:, None].astype(np.float32)
                    self._add_split(radiance, lp, depth if bounces is None else bounces[idx[e]], idx[e],
                                    throughput[e] * le,
                                    lg, None if lg is None else ps.light_groups.group_of_triangle[prim[e]])
                    if features is not None:
                        features.add_emission(idx[e], throughput[e] * le)

            # added, and the rays' origins read by nothing below: not held through the surface stage
            le = t_hit = o = tm = origins = tmax = None
            ending = None  # the paths whose vertex here only contributes emission (Cycles' bounce counting)
            if bounces is None:
                if depth == s.max_bounces + 1:
                    self._lap("emission", clock)
                    break
            else:
                ending = (bounces[idx] > s.max_bounces) | (transparent_bounces[idx] >= transparent_limit)
                if ending.all():
                    self._lap("emission", clock)
                    break

            # Russian roulette as Cycles does it (from the third vertex on with the default rr_depth 2; starting
            # at the second cost 4-22 % more MSE at equal samples on the bench scenes and saved only 3-4 % time),
            # before any work at this vertex: survive with probability
            # min(1, sqrt(max throughput)); the square root ends paths later than the throughput itself would
            # (measured on the Cornell box: MSE at equal samples 0.0115 without RR, 0.0201 with q = throughput,
            # 0.0165 with sqrt), and a terminated path casts no shadow ray here. The paths that go on (hit and
            # survived) are selected once, here; random numbers of paths that missed are drawn and unused (they
            # depend only on pixel, sample and dimension).
            survive = hit if held is None else hit & ~held
            if ending is not None:
                survive = survive & ~ending
            rolls = depth >= s.rr_depth
            if bounces is not None:
                # Cycles: a path that arrived through a Transparent BSDF meets the roulette after more than
                # Min Transparent Bounces + 1 transparent bounces, any other after rr_depth bounces
                per_path = np.where(came_through[idx], transparent_bounces[idx] >= transparent_rr_depth,
                                    bounces[idx] >= s.rr_depth)
                rolls = bool(per_path.any())
            if rolls:
                q = np.minimum(np.sqrt(_max3(throughput)), np.float32(1.0))
                if bounces is not None:
                    q = np.where(per_path, q, np.float32(1.0)).astype(np.float32)
                before_roulette = survive
                # the roulette's number, the 4th of the vertex's set (the rest are drawn again for the survivors
                # before the BSDF is sampled: they depend only on pixel, sample and dimension)
                survive = survive & (self.sampler.get_4d(pix, smp, self._dim(depth, _D_VERTEX))[:, 3] < q)
                if aov_path is not None:  # an emitting surface is shaded before the roulette ends the path there
                    self._rouletted_aovs(aov_path, np.flatnonzero(before_roulette & ~survive), idx, prim, hits, d,
                                         tr, path_state, hit_dp)
            rows = np.flatnonzero(survive)
            if want_aovs and depth == 0:
                hit_rows = np.flatnonzero(hit)
                g = self._surface(hit_rows, prim, hits.u, hits.v, d, tr)
                mat_first = ps.material_index[prim[hit_rows]]
                lobes_first = ps.materials.gather(mat_first, g.uv)
                if ps.shading is not None:
                    self._shade(g, mat_first, prim[hit_rows], d[hit_rows], lobes_first,
                                bary=(hits.u[hit_rows], hits.v[hit_rows]), path=_rows_of(path_state, idx[hit_rows]),
                                dp=None if hit_dp is None else hit_dp[hit_rows])
                first.albedo[idx[hit_rows]] = bsdf_mod.albedo(lobes_first)
                first.normal[idx[hit_rows]] = g.ns_raw
                first.depth[idx[hit_rows]] = (t_start[hit_rows] + hits.t[hit_rows]) * depth_scale[hit_rows]
                lobes_first = None
                if len(rows) < len(hit_rows):
                    g = g.take(np.flatnonzero(survive[hit_rows]))
            elif len(rows):
                g = self._surface(rows, prim, hits.u, hits.v, d, tr)
            if len(rows) == 0:
                break
            idx, pix, smp = idx[rows], pix[rows], smp[rows]
            throughput = throughput[rows]
            if rolls:
                throughput /= q[rows][:, None]
            # the camera's arguments are read by nothing below (the direction and the hits still are, until the
            # surface is shaded): not held while the vertex's lobes are gathered
            q = t_start = depth_scale = pixel_id = sample_id = None
            mat = ps.material_index[prim[rows]]
            if origin_class is not None:
                origin_class[idx] = ps.links.class_of_triangle[prim[rows]]
            lobes = ps.materials.gather(mat, g.uv)
            bumped = None  # (rows of g whose program set the normal, their smooth normals)
            aov_rows = aov_out = None
            if aov_path is not None:  # AOV Output nodes write while some path is primary (core.shader_aovs)
                aov_rows = aov_path.writing(idx)
                if aov_rows.any():
                    aov_out = np.zeros((len(idx), aov_path.values.shape[1], 4), np.float32)
            if ps.shading is not None:
                bumped = self._shade(g, mat, prim[rows], d[rows], lobes, bary=(hits.u[rows], hits.v[rows]),
                                     path=_rows_of(path_state, idx), dp=None if hit_dp is None else hit_dp[rows],
                                     aov_out=aov_out)
            if aov_out is not None:
                aov_path.record(idx, aov_rows, aov_out, lobes)
            if ps.specular.any():  # where a specular material's normal was tilted, the diffuse lobes keep it untilted
                lobes.diffuse_normal = np.ascontiguousarray(g.dn)
            # the lobe choice for this view, before anything reads it (core.bsdf.select_for_view)
            bsdf_mod.select_for_view(lobes, g.wo, g.cos_o_geo < 0, mat, ps.materials)
            if features is not None:
                features.record(idx, lobes, g.wo, g.n_view)
            if data_path is not None:
                data_path.record(idx, prim[rows], mat, g.p, g.uv, lobes, throughput)
            if lp is not None and depth == 0:  # the Color passes: the first surface's lobe albedos by kind
                lp.add_colors(idx, lp_mod.colors(lobes, g.wo, g.cos_o_geo < 0), throughput)
            elif lp is not None and bounces is not None:  # and those seen through Transparent BSDFs (Cycles)
                r = np.flatnonzero(bounces[idx] == 0)
                if len(r):
                    lp.add_colors(idx[r], lp_mod.colors(lobes.take(r), g.wo[r], g.cos_o_geo[r] < 0), throughput[r])

            clock = self._lap("emission", clock)
            bary = None
            if self.use_nee and ps.terminator_offset is not None:  # the terminator lift needs the hits' triangles
                bary = (prim[rows], hits.u[rows], hits.v[rows])
                if tr is not None and ps.motion_slot is not None:  # the hits' triangles at their times
                    at = ps.hit_triangles(prim[rows], tr[rows])
                    bary = (np.arange(len(rows), dtype=np.int32), hits.u[rows], hits.v[rows], at[0], at[3],
                            ps.terminator_offset[prim[rows]])
            # Paths in flight hold only what the rest of the vertex reads: the ray that arrived here, its hits and
            # the emission stage's per-path temporaries are dropped before next-event estimation and the scatter
            # allocate theirs (the scatter writes the next rays; the MIS origins keep their own copy).
            # (the rays' origins, the emission temporaries and the camera's arguments went after their last use)
            d = tr = hits = hit = prim = lobes_first = mat_first = survive = em_idx = directions = None
            if through is None:  # the scatter writes the next rays' state afresh; only the MIS origins read these
                prev_pdf = prev_delta = prev_normal = prev_transmits = None
            if self.use_nee:
                # with light passes, which paths' vertex is their first bounce (only Transparent BSDFs before it)
                first_bounce = None if lp is None or bounces is None else bounces[idx] == 0
                if ps.lights.has_lights:
                    self._next_event(depth, idx, pix, smp, g, mat, lobes, throughput, radiance, bary, lp,
                                     first_bounce=first_bounce,
                                     bumped=bumped, ray_time=ray_time,
                                     classes=None if origin_class is None else origin_class[idx],
                                     transparent_bounces=transparent_bounces, lg=lg)
                if ps.textured is not None:
                    self._next_event(depth, idx, pix, smp, g, mat, lobes, throughput, radiance, bary, lp, textured=True,
                                     first_bounce=first_bounce,
                                     bumped=bumped, ray_time=ray_time,
                                     path=_rows_of(path_state, idx), transparent_bounces=transparent_bounces,
                                     lg=lg)
                clock = self._lap("nee", clock)

            # Sample the BSDF for the next direction; the paths that go on are written compacted. The vertex's
            # numbers depend only on pixel, sample and dimension: drawing them again here for the survivors gives
            # the values drawn before the roulette without holding them through the vertex.
            u_vertex = self.sampler.get_4d(pix, smp, self._dim(depth, _D_VERTEX))
            # the direction's first number picks the lobe (core.bsdf_kernels.sample_path); the set's third picks
            # glass reflection vs refraction
            u_dir, u_event = np.ascontiguousarray(u_vertex[:, :2]), np.ascontiguousarray(u_vertex[:, 2])
            u_lobe = np.ascontiguousarray(u_vertex[:, 0])
            u_vertex = None
            bs = bsdf_mod.sample_bsdf(lobes, g.wo, u_event, u_dir, back=g.cos_o_geo < 0)
            if bumped is not None:
                self._bump_shadowing_sampled(bs, lobes, g, bumped)
            if alpha:  # idx is unique among live paths: the flag of each sample that goes on
                clear[idx] &= np.asarray(bs.transmitted, bool) & ps.keeps_transparent[mat]
            if data_path is not None:
                data_path.scattered(idx, bs.transmitted, mat)
            if aov_path is not None:
                aov_path.scattered(idx, bs.transmitted, mat)
            passed = None if through is None else transparent_shadow.clear_passes(lobes, u_lobe, bs.transmitted)
            if bounces is not None:  # idx is unique among live paths
                at_first = bounces[idx] == 0  # (light passes) no bounce before this vertex
                transparent_bounces[idx[passed]] += 1
                bounces[idx[~passed]] += 1
                came_through[idx] = passed
            if bounce_kind is not None:
                kinds = bounce_kind[idx]
                bounce_kinds(lobes.arrays(), u_lobe, bs.transmitted, kinds)
                bounce_kind[idx] = kinds
            if lp is not None and depth == 0:
                self._first_bounce_weights(lp, idx, lobes, g, bs, u_lobe)
            elif lp is not None and bounces is not None:  # a first bounce behind Transparent BSDFs (Cycles)
                r = np.flatnonzero(at_first)
                if len(r):
                    part = bsdf_mod.BsdfSample(*(np.asarray(getattr(bs, f))[r] for f in
                                                 ("wi", "weight", "pdf", "delta", "transmitted", "valid")))
                    self._first_bounce_weights(lp, idx[r], lobes.take(r), g.take(r), part, u_lobe[r])
            if path_state is not None:
                state = path_state[idx]
                next_path_state(lobes.arrays(), u_lobe, bs.transmitted, state)
                path_state[idx] = state
            lobes = u_dir = u_lobe = u_event = state = None  # read by nothing below: not held while the next rays are written
            m = len(idx)
            old_pdf, old_delta, old_normal, old_transmits = prev_pdf, prev_delta, prev_normal, prev_transmits
            o, d = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
            next_throughput, prev_pdf, prev_delta = np.empty((m, 3), np.float32), np.empty(m, np.float32), np.empty(m, bool)
            prev_normal, prev_transmits = np.empty((m, 3), np.float32), np.empty(m, bool)
            next_idx, next_pix, next_smp = np.empty(m, idx.dtype), np.empty(m, pix.dtype), np.empty(m, smp.dtype)
            count = path_kernels.scatter(np.ascontiguousarray(bs.wi, dtype=np.float32), g.tangent, g.bitangent, g.ns,
                                    g.ng, g.cos_o_geo, bs.valid, bs.transmitted,
                                    np.ascontiguousarray(bs.weight, np.float32),
                                    np.ascontiguousarray(throughput, dtype=np.float32), g.p, g.mag,
                                    np.asarray(bs.pdf, np.float32), bs.delta, g.n_view,
                                    ps.materials.has_transmission[mat], idx, pix, smp,
                                    o, d, next_throughput, prev_pdf, prev_delta, prev_normal, prev_transmits,
                                    next_idx, next_pix, next_smp)
            o, d, throughput, prev_pdf, prev_delta = o[:count], d[:count], next_throughput[:count], \
                prev_pdf[:count], prev_delta[:count]
            prev_normal, prev_transmits = prev_normal[:count], prev_transmits[:count]
            if through is not None:
                through = through.advance(depth, rows, idx, passed, next_idx[:count], o, d,
                                          (old_pdf, old_delta, old_normal, old_transmits),
                                          (prev_pdf, prev_delta, prev_normal, prev_transmits))
            idx, pix, smp = next_idx[:count], next_pix[:count], next_smp[:count]
            tm = np.full(count, np.float32(3e38))
            # this vertex's surface, lobes, BSDF sample and the rays' previous state are done with: not held
            # while the next rays are intersected
            g = lobes = bs = mat = u_dir = u_lobe = rows = bumped = bary = passed = None
            old_pdf = old_delta = old_normal = old_transmits = next_throughput = None
            self._lap("scatter", clock)
        if transparent is not None:
            np.clip(transparent, 0.0, 1.0, out=transparent)
        if catch is not None:
            if first is None:
                first = FirstHit(None, None, None)
            first.catcher = catch.finish(self, radiance, transparent)
        return radiance, first, transparent

    def _rouletted_aovs(self, aov_path: AovPath, ended: np.ndarray, idx, prim, hits, d, tr, path_state,
                        hit_dp) -> None:
        """The AOV Output writes (core.shader_aovs) of the surfaces where Russian roulette ends the paths `ended`
        (rows of the live paths idx) and whose material emits: Cycles still shades such a surface (for its
        emission) and its AOV Output nodes write; a path ended on any other surface is never shaded there."""
        ps = self.ps
        mat = ps.material_index[prim[ended]]
        emits = ps.materials.emission[mat].max(axis=1) > 0
        if ps.shading is not None and ps.shading.any_emits:
            emits |= ps.shading.emits[mat]
        ended = ended[emits & aov_path.writing(idx[ended])]
        if len(ended):
            self._shade_aovs(aov_path, ended, np.ones(len(ended), bool), idx, prim, hits, d, tr, path_state, hit_dp)

    def _needs_background(self) -> bool:
        """Whether the shadow catcher needs the world behind it (Cycles' approximate catcher on an opaque film)."""
        film = self.ps.scene.film
        return not film.transparent and not film.shadow_catcher_pass

    def _trace_copies(self, split: "_SplitPaths") -> np.ndarray:
        """Radiance (M, 3) of the shadow catcher copies of paths that split (see CatcherSamples): from the ray that
        met the catcher on, every ray (and shadow ray) sees only the shadow catchers."""
        self._catcher_copies, self._resume = True, split
        try:
            radiance, _, _ = self.trace(split.pix, split.smp, split.o, split.d, split.tmax, None, None, False)
        finally:
            self._catcher_copies, self._resume = False, None
        return radiance

    def _light_emission(self, o, d, tmax, prev_pdf, prev_delta, mis_here, prev_normal, camera, prev_transmits,
                        clear, classes=None, kinds=None, group_hidden: frozenset = frozenset()) -> np.ndarray:
        """Emission of lights and the world along the rays (core.lights.LightSampler.intersect); rays where
        `clear` (None: none) count as transparent and see no world. classes: the receiver class of each ray's
        origin (light linking, core.light_linking; None: camera rays or no linking): each class sees its linked
        emitters; with shadow linking, rays after a non-delta bounce do not see shadow-linked lights (light
        sampling alone counts them). kinds: each ray's kind (core.ray_visibility) where some light hides from
        some kind (core.light_visibility), else None. group_hidden: lights hidden besides (a light group's share,
        core.light_groups). camera: True for camera rays, or (N,) bool where only some rays still are (a camera ray
        that went on through Transparent BSDFs stays one, as in Cycles, and sees only the lights visible to the
        camera)."""
        if not isinstance(camera, (bool, np.bool_)):
            camera = np.asarray(camera, bool)
            if camera.all() or not camera.any():
                camera = bool(camera.all())
            else:
                out = np.empty((len(o), 3), np.float32)
                for flag in (True, False):
                    rows = np.flatnonzero(camera == flag)

                    def sub(a, rows=rows):
                        return None if a is None else a[rows]

                    out[rows] = self._light_emission(o[rows], d[rows], tmax[rows], prev_pdf[rows], prev_delta[rows],
                                                     mis_here, sub(prev_normal), flag, sub(prev_transmits),
                                                     sub(clear), sub(classes), sub(kinds), group_hidden)
                return out
        ps = self.ps
        hide = ps.shadow_links is not None and not camera and mis_here and self.use_nee
        if classes is None and not hide and kinds is None:
            return self._emission_of(ps.lights, o, d, tmax, prev_pdf, prev_delta, mis_here, prev_normal, camera,
                                     prev_transmits, clear, group_hidden)
        # one group per (receiver class, ray kind, shadow-linked lights hidden)
        key = np.zeros(len(o), np.int64) if classes is None else np.asarray(classes, np.int64) * 16
        if kinds is not None:
            key = key + np.asarray(kinds, np.int64) * 2
        if hide:
            key = key + ~np.asarray(prev_delta, bool)
        out = np.empty((len(o), 3), np.float32)
        for k in np.unique(key):
            rows = np.flatnonzero(key == k)
            lights = ps.lights if classes is None else ps.links.samplers[int(k) // 16]
            hidden = (ps.shadow_links.hidden if hide and k % 2 else frozenset()) | group_hidden
            if kinds is not None:
                hidden = hidden | ps.light_visibility.hidden((int(k) % 16) // 2)
            out[rows] = self._emission_of(lights, o[rows], d[rows], tmax[rows], prev_pdf[rows], prev_delta[rows],
                                          mis_here, None if prev_normal is None else prev_normal[rows], camera,
                                          None if prev_transmits is None else prev_transmits[rows],
                                          None if clear is None else clear[rows], hidden)
        return out

    def _group_shares(self, le, o, d, t_hit, prev_pdf, prev_delta, mis_here, prev_normal, camera, prev_transmits,
                      clear, classes, kinds) -> tuple:
        """(rows of `le` that hold light, (G, M, 3) each light group's share there) of the emission of lights and
        world along the rays (core.light_groups): _light_emission with the other groups' lights hidden (and the
        world unless it is in the group), over _light_emission of all."""
        groups = self.ps.light_groups
        rows = np.flatnonzero(le.max(axis=1) > 0)
        if len(rows) == 0:
            return rows, np.zeros((groups.count, 0, 3), np.float32)

        def sub(a):
            return None if a is None else a[rows]

        args = (o[rows], d[rows], t_hit[rows], prev_pdf[rows], prev_delta[rows], mis_here, sub(prev_normal),
                camera if isinstance(camera, (bool, np.bool_)) else camera[rows], sub(prev_transmits))
        no_world = np.ones(len(rows), bool)
        per_group = [self._light_emission(*args, sub(clear) if groups.world_in[g] else no_world, sub(classes),
                                          sub(kinds), groups.hidden[g])
                     if groups.world_in[g] or groups.matchers[g] is not None else np.zeros((len(rows), 3), np.float32)
                     for g in range(groups.count)]
        # every light and the world in a group: the groups' parts sum to the whole look-up
        total = (np.sum(per_group, axis=0) if groups.lights_grouped
                 else self._light_emission(*args, sub(clear), sub(classes), sub(kinds)))
        return rows, emission_shares(per_group, total)

    @staticmethod
    def _emission_of(lights, o, d, tmax, prev_pdf, prev_delta, mis_here, prev_normal, camera, prev_transmits,
                     clear, hidden) -> np.ndarray:
        """_light_emission of one light sampler, `hidden` lights unseen."""
        if clear is None or not clear.any():
            return lights.intersect(o, d, tmax, prev_pdf, prev_delta, mis_here, n=prev_normal, camera=camera,
                                    transmits=prev_transmits, hidden=hidden)
        if clear.all():
            return lights.intersect(o, d, tmax, prev_pdf, prev_delta, mis_here, n=prev_normal, camera=camera,
                                    transmits=prev_transmits, world=False, hidden=hidden)
        out = np.empty((len(o), 3), np.float32)
        for rows, world in ((np.flatnonzero(~clear), True), (np.flatnonzero(clear), False)):
            out[rows] = lights.intersect(o[rows], d[rows], tmax[rows], prev_pdf[rows], prev_delta[rows], mis_here,
                                         n=None if prev_normal is None else prev_normal[rows], camera=camera,
                                         transmits=None if prev_transmits is None else prev_transmits[rows],
                                         world=world, hidden=hidden)
        return out

    def _intersect_by_kind(self, kinds: np.ndarray, o, d, tm, tr=None):
        """Closest hits of rays of several kinds (core.ray_visibility), each against the triangles its kind of ray
        sees. tr: the rays' times (motion blur) or None."""
        ps = self.ps
        groups = [(kind, np.flatnonzero(kinds == code)) for code, kind in RAY_KIND_NAMES.items()
                  if kind in ps.visible_to]
        hidden = np.zeros(len(o), bool)
        for _, rows in groups:
            hidden[rows] = True
        if not hidden.any():
            return self.accel.intersect(o, d, tm, tr)
        hits = Hits(np.full(len(o), -1, np.int32), np.zeros(len(o), np.float32), np.zeros(len(o), np.float32),
                    np.full(len(o), np.inf, np.float32))
        rest = np.flatnonzero(~hidden)
        parts = [(rows, self._intersect_subset(kind, o[rows], d[rows], tm[rows], None if tr is None else tr[rows]))
                 for kind, rows in groups if len(rows)]
        if len(rest):
            parts.append((rest, self.accel.intersect(o[rest], d[rest], tm[rest], None if tr is None else tr[rest])))
        for rows, part in parts:
            hits.prim[rows], hits.u[rows], hits.v[rows], hits.t[rows] = part.prim, part.u, part.v, part.t
        return hits

    def _intersect_subset(self, which: str, o, d, tm, tr=None):
        """Closest hits among the triangles `which` rays see, with the scene's triangle indices."""
        accel, keep = self.ps.visible_subset(which)
        hits = accel.intersect(o, d, tm, tr)
        if len(keep) == 0:
            return hits  # all misses
        found = hits.prim >= 0
        hits.prim = np.where(found, keep[np.where(found, hits.prim, 0)], np.int32(-1)).astype(np.int32)
        return hits

    def _surface(self, rows: np.ndarray, prim, bu, bv, d, tr=None) -> "SurfaceBatch":
        """Surface interactions of the hits `rows` (see core.geometry_kernels.surface); tr: the rays' times
        (motion blur: moving triangles are rebuilt at them) or None."""
        ps = self.ps
        if tr is not None and ps.motion_slot is not None:
            m = len(rows)
            g = SurfaceBatch.empty(m, ps.uvs is not None)
            tri = prim[rows]
            corners, normals, magnitude, corner_normals = ps.hit_triangles(tri, tr[rows])
            local = np.arange(m, dtype=np.int64)
            smooth, uvs = ps.kernel_smooth, ps.kernel_uvs
            geometry_kernels.surface(local, local.astype(np.int32), np.ascontiguousarray(bu[rows]),
                                     np.ascontiguousarray(bv[rows]), np.ascontiguousarray(d[rows], dtype=np.float32),
                                     corners, normals, corner_normals, smooth[tri] if len(smooth) else smooth,
                                     uvs[tri] if len(uvs) else uvs, magnitude, ps.material_index[tri], ps.specular,
                                     g.p, g.ng, g.ns_raw, g.ns, g.tangent, g.bitangent, g.wo, g.n_view, g.dn,
                                     g.mag, g.cos_o_geo, g.uv_buffer)
            return g
        return surface_batch(ps, rows, prim, bu, bv, d)

    def _shade(self, g: "SurfaceBatch", mat: np.ndarray, prim: np.ndarray, dirs: np.ndarray,
               lobes: "bsdf_mod.LobeBatch", emission: np.ndarray | None = None, bary=None,
               path: np.ndarray | None = None, dp=None, aov_out: np.ndarray | None = None):
        """Run the node programs of the points (see `shade_points`); returns its bumped points or None."""
        return shade_points(self.ps, g, mat, prim, dirs, lobes, emission, bary, path, dp, aov_out)

    # Cycles' bump shadowing (closure/bsdf.h, with the material's default Bump Map Correction): where a closure's
    # normal N differs from the smooth normal Ns, directions on opposite sides of the two are rejected
    # (cos(Ns, wi) cos(Ns, N) cos(N, wi) < 0: every lobe when evaluated, diffuse lobes when sampled) and diffuse
    # lobes are softened towards grazing light by a GGX shadowing factor of the normals' deviation.
    @staticmethod
    def _diffuse_only(lobes: "bsdf_mod.LobeBatch", rows: np.ndarray) -> "bsdf_mod.LobeBatch":
        """The lobes with every weight but the diffuse lobes' of `rows` zero, for eval_bsdf(rows=...): the other
        arrays are shared, not copied (only the rows read are filled; the zeros are calloc'd pages)."""
        weight = np.zeros(lobes.weight.shape, lobes.weight.dtype)  # (zeros_like writes every page)
        geometry_kernels.diffuse_lobe_weights(np.asarray(rows, np.int64), lobes.kind, lobes.weight,
                                              bsdf_mod.KIND_CODE["diffuse"], weight)
        return replace(lobes, weight=weight)

    def _bump_shadowing_eval(self, f_cos, lobes, can, gc, wi_local, wi, bumped, n_paths) -> np.ndarray:
        """f cos of next-event light samples with the bump shadowing applied at bumped points."""
        where = np.full(n_paths, -1, np.int64)
        where[bumped[0]] = np.arange(len(bumped[0]))
        sel = np.flatnonzero(where[can] >= 0)
        if len(sel) == 0:
            return f_cos
        ns = bumped[1][where[can[sel]]]
        # each closure's own normal: the specular lobes' is the frame's (tilted), the diffuse lobes' the untilted
        g1, reject, reject_d = _bump_terms(gc, sel, ns, wi[sel], local=False)
        f_d, _ = bsdf_mod.eval_bsdf(self._diffuse_only(lobes, can[sel]), gc.wo[sel], wi_local[sel], rows=can[sel],
                                    back=gc.cos_o_geo[sel] < 0)
        adjusted = (np.where(reject[:, None], np.float32(0), f_cos[sel] - f_d)
                    + np.where(reject_d[:, None], 0.0, g1[:, None] * f_d)).astype(np.float32)
        f_cos = f_cos.copy()
        f_cos[sel] = np.maximum(adjusted, 0.0)
        return f_cos

    def _bump_shadowing_sampled(self, bs, lobes, g, bumped) -> None:
        """The BSDF samples' weights (f cos / pdf) at bumped points with the diffuse lobes' bump shadowing."""
        rows = bumped[0]
        ok = np.flatnonzero(np.asarray(bs.valid, bool)[rows] & ~np.asarray(bs.delta, bool)[rows])
        if len(ok) == 0:
            return
        r = rows[ok]
        wl = np.asarray(bs.wi, np.float32)[r]
        g1, _, reject = _bump_terms(g, r, bumped[1][ok], wl, local=True)
        f_d, _ = bsdf_mod.eval_bsdf(self._diffuse_only(lobes, r), g.wo[r], wl, rows=r, back=g.cos_o_geo[r] < 0)
        loss = np.where(reject, 1.0, 1.0 - g1)[:, None] * f_d / np.maximum(np.asarray(bs.pdf, np.float32)[r], 1e-30)[:, None]
        bs.weight[r] = np.maximum(bs.weight[r] - loss.astype(np.float32), 0.0)

    def _holdout_aovs(self, aov_path: AovPath, rows, idx, prim, hits, d, tr, path_state, hit_dp) -> None:
        """AOV Output nodes of the full holdout surfaces that live paths `rows` hit still write (core.shader_aovs):
        Cycles evaluates a surface's shader, AOV nodes included, before its holdout ends the path."""
        writing = aov_path.writing(idx[rows])
        if writing.any():
            self._shade_aovs(aov_path, rows, writing, idx, prim, hits, d, tr, path_state, hit_dp)

    def _shade_aovs(self, aov_path: AovPath, rows, writing, idx, prim, hits, d, tr, path_state, hit_dp) -> None:
        """Shade the surfaces that live paths `rows` hit only for their AOV Output writes, recorded where
        `writing` (per row) is true."""
        ps = self.ps
        g = self._surface(rows, prim, hits.u, hits.v, d, tr)
        mat = ps.material_index[prim[rows]]
        lobes = ps.materials.gather(mat, g.uv)
        out = np.zeros((len(rows), aov_path.values.shape[1], 4), np.float32)
        self._shade(g, mat, prim[rows], d[rows], lobes, bary=(hits.u[rows], hits.v[rows]),
                    path=_rows_of(path_state, idx[rows]), dp=None if hit_dp is None else hit_dp[rows], aov_out=out)
        aov_path.record(idx[rows], writing, out, lobes)

    def _lap(self, stage: str, since: float) -> float:
        """Add the time since `since` to a stage's counter; returns now."""
        now = time.perf_counter()
        setattr(self.stats, f"seconds_{stage}", getattr(self.stats, f"seconds_{stage}") + now - since)
        return now

    def _next_event(self, depth, idx, pix, smp, g: "SurfaceBatch", mat, lobes, throughput, radiance,
                    bary=None, lp: "lp_mod.LightPassSamples | None" = None, textured: bool = False,
                    path: np.ndarray | None = None, bumped=None, ray_time=None, classes=None,
                    transparent_bounces: np.ndarray | None = None, first_bounce: np.ndarray | None = None,
                    lg: "LightGroupSamples | None" = None, can: np.ndarray | None = None) -> None:
        """Next-event estimation: one light sample per path with a shadow ray, MIS-weighted. bary: (triangle,
        u, v) of each path's hit when some mesh has a shadow terminator offset, else None (with motion blur:
        (row, u, v, corners, corner normals, offsets) of the hits' own triangles at their times); ray_time: each
        sample's time (motion blur: the shadow rays cast at it) or None; lp: the light passes
        to split the contributions into (None: off). transparent_bounces: per sample, the Transparent BSDFs its
        path went through (its shadow rays may pass that many fewer; None: none counted). textured: sample the textured emitters
        (core.textured_emitters) instead of the lights, the emission from their programs; path: the paths' Light
        Path state there (None when no program reads it); classes: the paths' receiver classes (light linking,
        core.light_linking) or None; first_bounce: with light passes, per path, whether its vertex here is its
        first bounce (only Transparent BSDFs passed before it; None: the vertex at depth 0 alone); lg: the light groups
        to attribute the light to (core.light_groups; None: off). can: the rows that take a light sample (None:
        every path whose material next-event estimation can reach, NEE_CHUNK rows at a time)."""
        ps = self.ps
        if can is None:
            can = np.flatnonzero(ps.has_nondelta[mat])
            if len(can) > NEE_CHUNK:
                # The light samples, their BSDF values and shadow rays are ~200 B per path: in chunks they stay a
                # fixed few MB instead of growing with the batch. Each path takes one light sample, keyed by its
                # pixel, sample and depth, and adds it to its own sample: the same numbers in any chunking.
                for a in range(0, len(can), NEE_CHUNK):
                    self._next_event(depth, idx, pix, smp, g, mat, lobes, throughput, radiance, bary, lp, textured,
                                     path, bumped, ray_time, classes, transparent_bounces, first_bounce, lg,
                                     can[a:a + NEE_CHUNK])
                return
        if len(can) == 0:
            return
        gc = g.take(can) if len(can) < len(idx) else g
        u_light = self.sampler.get_3d(pix[can], smp[can], self._dim(depth, _D_LIGHT))
        u_l, u_sel = np.ascontiguousarray(u_light[:, :2]), np.ascontiguousarray(u_light[:, 2])
        u_light = None
        transmits = ps.materials.has_transmission[mat[can]]
        if textured:
            ls = self._sample_textured(gc.p, u_sel, u_l, None if path is None else path[can])
        elif classes is not None:
            ls = ps.links.sample(classes[can], gc.p, gc.n_view, u_sel, u_l, transmits)
        else:
            ls = ps.lights.sample(gc.p, gc.n_view, u_sel, u_l, transmits=transmits)
        wi = np.ascontiguousarray(ls.wi, dtype=np.float32)
        linked_set = None  # shadow linking: which blocker set's light each sample lies on (0: none)
        if ps.shadow_links is not None and not textured:
            linked_set = ps.shadow_links.set_of_samples(gc.p, wi, ls.dist)
        m = len(can)
        wi_local = np.empty((m, 3), np.float32)
        geometry_kernels.to_local(wi, gc.tangent, gc.bitangent, gc.ns, wi_local)
        f_cos, pdf_b = bsdf_mod.eval_bsdf(lobes, gc.wo, wi_local, rows=can, back=gc.cos_o_geo < 0)
        restricted = []  # (rows of can, their lobes) of samples of lights some ray kinds do not see
        if ps.light_visibility is not None and not textured:
            restricted = self._visible_lobes_only(f_cos, lobes, can, gc, wi, wi_local, ls.dist)
        if bumped is not None:
            f_cos = self._bump_shadowing_eval(f_cos, lobes, can, gc, wi_local, wi, bumped, len(idx))
        if linked_set is not None and self.mis:
            # shadow-linked lights count from light sampling alone (core.light_linking): MIS weight 1
            pdf_b = np.where(linked_set > 0, np.float32(0), np.asarray(pdf_b, np.float32))
        contrib, origin, direction = (np.empty((m, 3), np.float32) for _ in range(3))
        tmax, sample_of = np.empty(m, np.float32), np.empty(m, idx.dtype)
        count = path_kernels.shadow_rays(can, np.ascontiguousarray(throughput, np.float32), idx,
                                    np.ascontiguousarray(f_cos, np.float32), np.ascontiguousarray(ls.radiance, np.float32),
                                    np.asarray(ls.pdf, np.float32), np.asarray(pdf_b, np.float32),
                                    np.asarray(ls.delta, bool), self.mis, gc.cos_o_geo, gc.ng, transmits, gc.p, gc.mag,
                                    wi, np.asarray(ls.dist, np.float32), SHADOW_EPSILON, contrib, origin, direction,
                                    tmax, sample_of, *self._terminator_args(bary, can, gc))
        if count == 0:
            return
        if lp is None and lg is None and (ps.no_shadow is None or textured):
            # the light samples, their BSDF values and the vertices' surfaces have been folded into the shadow
            # rays: not held while Embree traces them
            gc = ls = wi = wi_local = f_cos = pdf_b = u_l = u_sel = transmits = restricted = None
        clock = time.perf_counter()
        shadow_time = None if ray_time is None else ray_time[sample_of[:count]]
        if self._catcher_copies:
            occluders = ps.visible_subset("catcher")
        elif "shadow" in ps.visible_to:
            occluders = ps.visible_subset("shadow")
        else:
            occluders = (self.accel, None)
        transmit = None  # shadow rays through transparent surfaces: their transmittance (core.transparent_shadow)
        max_hits = self.settings.transparent_max_bounces
        if ps.shadow_clear is None:
            blocked = occluders[0].occluded(origin[:count], direction[:count], tmax[:count], shadow_time)
        else:
            if transparent_bounces is not None:  # Cycles: the limit less the transparent bounces already made
                max_hits = np.maximum(max_hits - transparent_bounces[sample_of[:count]], 0)
            blocked, transmit = transparent_shadow.trace(self, occluders, origin[:count], direction[:count],
                                                         tmax[:count], max_hits, shadow_time)
        if linked_set is not None and not self._catcher_copies:
            self._shadow_linked(linked_set, idx, can, sample_of[:count], origin[:count], direction[:count],
                                tmax[:count], shadow_time, blocked, transmit, max_hits)
        self.stats.seconds_occluded += time.perf_counter() - clock
        self.stats.seconds_nee -= time.perf_counter() - clock  # counted once, as shadow rays
        if ps.no_shadow is not None and not textured:
            # Samples of lights that cast no shadow are never occluded; one light sample per path, so the
            # sample index names it.
            free = np.zeros(len(radiance), bool)
            free[idx[can][ps.no_shadow.matches(gc.p, wi, ls.dist)]] = True
            blocked &= ~free[sample_of[:count]]
            if transmit is not None:
                transmit[free[sample_of[:count]]] = 1.0
        vis = np.flatnonzero(~blocked)
        shadowed = contrib[vis] if transmit is None else contrib[vis] * transmit[vis]
        if lp is None and lg is None:
            self._add(radiance, sample_of[vis], shadowed)
            return
        value = self._add_clean(radiance, sample_of[vis], shadowed)
        # every path has one light sample: its sample index finds its row in `can`
        row_of = np.zeros(len(radiance), np.int64)
        row_of[idx[can]] = np.arange(m)
        k = row_of[sample_of[:count][vis]]
        if lg is not None:  # each light sample to its emitter's group
            lg.add(sample_of[vis], value, ps.light_groups.of_light_samples(
                gc.p[k], wi[k], np.asarray(ls.dist)[k], origin[:count][vis], direction[:count][vis],
                triangles_only=textured))
        if lp is None:
            return
        if depth > 0 and (first_bounce is None or not first_bounce[can].any()):
            lp.add_split(False, sample_of[vis], value)
            return
        # the first bounce: split by the lobes' shares
        shares = lp_mod.split_ratios(lobes, gc.wo, wi_local, gc.cos_o_geo < 0, rows=can)
        for r, part in restricted:  # lights hidden from some kinds: the shares of the lobes that see them
            for share, sub in zip(shares, lp_mod.split_ratios(part, gc.wo[r], wi_local[r], gc.cos_o_geo[r] < 0)):
                share[r] = sub
        if depth == 0:
            lp.add_split(True, sample_of[vis], value, tuple(share[k] for share in shares))
            return
        # behind Transparent BSDFs only (Cycles: no bounce yet), the light sample is direct light
        first = first_bounce[can][k]
        lp.add_split(True, sample_of[vis][first], value[first], tuple(share[k[first]] for share in shares))
        lp.add_split(False, sample_of[vis][~first], value[~first])

    def _visible_lobes_only(self, f_cos, lobes, can, gc, wi, wi_local, dist) -> list:
        """Re-evaluate (in place in f_cos) the BSDF of light samples of lights hidden from some ray kinds with
        only the lobes of the kinds that see them (core.light_visibility); returns [(rows of can, those lobes)]."""
        group = self.ps.light_visibility.group_of_samples(gc.p, wi, dist)
        restricted = []
        for j in np.unique(group[group > 0]):
            r = np.flatnonzero(group == j)
            part = lobes.take(can[r])
            left_out = np.isin(part.kind, self.ps.light_visibility.groups[int(j) - 1][0])
            part.weight = np.where(left_out[..., None], np.float32(0), part.weight).astype(np.float32)
            f_cos[r] = bsdf_mod.eval_bsdf(part, gc.wo[r], wi_local[r], back=gc.cos_o_geo[r] < 0)[0]
            restricted.append((r, part))
        return restricted

    def _shadow_linked(self, linked_set, idx, can, sample_of, origin, direction, tmax, shadow_time, blocked,
                       transmit, max_hits=None) -> None:
        """Recast (in place in `blocked` and `transmit`) the shadow rays of samples on shadow-linked lights
        against their light's blockers alone (core.light_linking). max_hits: the transparent surfaces each
        shadow ray may pass (a scalar or one per ray; used where `transmit` is kept)."""
        ps = self.ps
        row_of = np.zeros(int(idx.max()) + 1 if len(idx) else 0, np.int64)
        row_of[idx[can]] = np.arange(len(can))
        set_of_ray = linked_set[row_of[sample_of]]
        for j in np.unique(set_of_ray[set_of_ray > 0]):
            r = np.flatnonzero(set_of_ray == j)
            mask = ps.shadow_links.blockers[int(j) - 1]
            if "shadow" in ps.visible_to:
                mask = mask & ps.visible_to["shadow"]
            if not mask.any():  # nothing blocks this light
                blocked[r] = False
                if transmit is not None:
                    transmit[r] = 1.0
                continue
            occluders = ps.visible_subset(f"blocker {int(j) - 1}")
            t = None if shadow_time is None else shadow_time[r]
            if transmit is None:
                blocked[r] = occluders[0].occluded(origin[r], direction[r], tmax[r], t)
            else:
                hits = max_hits[r] if np.ndim(max_hits) else max_hits  # the remaining transparent bounces
                blocked[r], transmit[r] = transparent_shadow.trace(self, occluders, origin[r], direction[r], tmax[r],
                                                                   hits, t)

    def _sample_textured(self, p: np.ndarray, u_select: np.ndarray, u: np.ndarray,
                         path: np.ndarray | None = None) -> LightSample:
        """One light sample of the textured emitters per point p, its radiance from the emitter's program.
        The program sees Cycles' light-sample state: no ray-kind flag set, Ray Depth one more than at p (path: the
        paths' state at p, None when no program reads it)."""
        em, b1, b2, wi, dist, pdf = self.ps.textured.sample(p, u_select, u)
        radiance = np.zeros((len(em), 3), np.float32)
        live = np.flatnonzero(pdf > 0)
        if len(live):
            state = None
            if path is not None:
                state = path[live].copy()
                state[:, PATH_FLAGS] = 0.0
                state[:, PATH_DEPTH] += 1.0
                state[:, PATH_LENGTH] = dist[live]
            radiance[live] = emission_at(self.ps, self.ps.textured.triangle_id[em[live]], b1[live], b2[live],
                                         towards=wi[live], path=state)
        return LightSample(wi=wi, dist=dist, radiance=radiance, pdf=pdf, delta=np.zeros(len(em), bool))

    def _terminator_args(self, bary, can, gc: "SurfaceBatch") -> tuple:
        """shadow_rays' shadow terminator inputs for the light samples of paths `can` (empty arrays: off)."""
        ps = self.ps
        if bary is None:
            e3 = np.zeros((0, 3, 3), np.float32)
            return (np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros(0, np.float32),
                    np.zeros((0, 3), np.float32), e3, e3, np.zeros(0, np.float32))
        prim, bu, bv = bary[:3]
        corners, corner_normals, offsets = bary[3:] if len(bary) > 3 else (ps.tri_vertices, ps.corner_normals,
                                                                           ps.terminator_offset)
        return (np.ascontiguousarray(prim[can]), np.ascontiguousarray(bu[can], np.float32),
                np.ascontiguousarray(bv[can], np.float32), np.ascontiguousarray(gc.n_view), corners,
                corner_normals, offsets)

    def _add_clean(self, radiance: np.ndarray, idx: np.ndarray, value: np.ndarray) -> np.ndarray:
        """_add's work done in two steps, returning the contributions as they were added (non-finite rows 0,
        clamped), so that the light passes split exactly what the image got."""
        clean, nonfinite, clamped = lp_mod.clean_contributions(value, self.settings.clamp)
        self.stats.nonfinite += nonfinite
        self.stats.clamped += clamped
        counters = np.zeros(2, np.int64)
        path_kernels.accumulate(radiance, np.asarray(idx, np.int64), clean, np.float32(0), counters)
        return clean

    def _add_split(self, radiance: np.ndarray, lp: "lp_mod.LightPassSamples | None", depth, idx: np.ndarray,
                   value: np.ndarray, lg: "LightGroupSamples | None" = None, groups=None) -> None:
        """Emission found after `depth` bounces (one count, or (M,) one per row: passes through Transparent BSDFs
        are not bounces, as in Cycles) added to the image and, with light passes, to Emission (seen by the
        camera), the Direct passes (found by the first bounce) or the Indirect ones (later); with light groups
        (lg) to the emitters' groups (`groups`: see core.light_groups.LightGroupSamples.add)."""
        if lp is None and lg is None:
            self._add(radiance, idx, value)
            return
        clean = self._add_clean(radiance, idx, value)
        if lg is not None:
            lg.add(idx, clean, groups)
        if lp is None:
            return
        if np.ndim(depth) == 0:
            if depth == 0:
                lp.add(lp_mod.EMISSION, idx, clean)
            else:
                lp.add_split(depth == 1, idx, clean)
            return
        depth = np.asarray(depth)
        for rows, part in ((np.flatnonzero(depth == 0), None), (np.flatnonzero(depth == 1), True),
                           (np.flatnonzero(depth > 1), False)):
            if len(rows) and part is None:
                lp.add(lp_mod.EMISSION, idx[rows], clean[rows])
            elif len(rows):
                lp.add_split(part, idx[rows], clean[rows])

    def _add_camera_light(self, radiance, lp: "lp_mod.LightPassSamples", idx, value, o, d, t_hit, prev_pdf,
                          prev_delta) -> np.ndarray:
        """Lights and world seen by camera rays (t_hit: the distance to each ray's hit, inf where it escapes),
        with light passes: the lights' share to Emission, the world's to Environment (the lights alone are looked
        up once more, without the world)."""
        clean = self._add_clean(radiance, idx, value)
        lamps = self.ps.lights.intersect(o, d, t_hit, prev_pdf, prev_delta, False, camera=True, world=False)
        total = np.asarray(value, np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            lamp_share = np.where(total > 0, np.clip(lamps / np.where(total > 0, total, 1.0), 0, 1), 0.0)
        em = (clean * lamp_share).astype(np.float32)
        lp.add(lp_mod.EMISSION, idx, em)
        lp.add(lp_mod.ENVIRONMENT, idx, clean - em)
        return clean

    def _first_bounce_weights(self, lp: "lp_mod.LightPassSamples", idx, lobes, g: "SurfaceBatch", bs,
                              u_lobe) -> None:
        """Each sample's diffuse and glossy share of its first bounce (core.light_passes): the lobes' values at
        the sampled direction, or for a delta sample the kind of the lobe it came from."""
        share_d, share_g, share_t = lp_mod.split_ratios(lobes, g.wo, bs.wi, g.cos_o_geo < 0)
        delta = np.flatnonzero(bs.delta)
        if len(delta):
            kinds = np.zeros(len(idx), np.int8)
            bounce_kinds(lobes.arrays(), u_lobe, bs.transmitted, kinds)
            share_d[delta] = (kinds[delta] == DIFFUSE_RAY)[:, None]
            share_g[delta] = (kinds[delta] == GLOSSY_RAY)[:, None]
            # a transmission ray, or a ray through a Transparent BSDF (which stays a camera ray)
            share_t[delta] = ((kinds[delta] != DIFFUSE_RAY) & (kinds[delta] != GLOSSY_RAY))[:, None]
        lp.weight_diffuse[idx] = share_d
        lp.weight_glossy[idx] = share_g
        lp.weight_transmission[idx] = share_t

    def _add(self, radiance: np.ndarray, idx: np.ndarray, value: np.ndarray) -> None:
        """Add contributions to their samples, catching NaN/Inf (counted, dropped) and clamping if asked."""
        counters = np.zeros(2, np.int64)
        path_kernels.accumulate(radiance, np.asarray(idx, np.int64), np.ascontiguousarray(value, dtype=np.float32),
                           np.float32(self.settings.clamp), counters)
        self.stats.nonfinite += int(counters[0])
        self.stats.clamped += int(counters[1])


def _bump_terms(g: "SurfaceBatch", rows: np.ndarray, smooth: np.ndarray, w: np.ndarray,
                local: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cycles' bump shadowing at the points `rows` of g (their node program set the normal), smooth (M, 3) their
    smooth normals, w (M, 3) directions (world space, or in each point's shading frame when `local`):
    (g1 (M,) the diffuse lobes' softening factor, rejected (M,) for the frame's normal (the microfacet lobes'),
    rejected (M,) for the diffuse lobes' normal); geometry_kernels.bump_shadowing_terms."""
    m = len(rows)
    g1, reject, reject_d = np.empty(m, np.float64), np.empty(m, np.bool_), np.empty(m, np.bool_)
    geometry_kernels.bump_shadowing_terms(np.ascontiguousarray(rows, np.int64),
                                          np.ascontiguousarray(smooth, np.float32),
                                          np.ascontiguousarray(w, np.float32), local, g.tangent, g.bitangent,
                                          g.ns, g.n_view, g.dn, g.cos_o_geo, g1, reject, reject_d)
    return g1, reject, reject_d


def surface_batch(ps: PreparedScene, rows: np.ndarray, prim, bu, bv, d) -> "SurfaceBatch":
    """Surface interactions of the hits `rows` (see core.geometry_kernels.surface)."""
    m = len(rows)
    g = SurfaceBatch.empty(m, ps.uvs is not None)
    geometry_kernels.surface(rows.astype(np.int64), prim, bu, bv, np.ascontiguousarray(d, dtype=np.float32),
                    ps.tri_vertices, ps.face_normals, ps.kernel_corner_normals, ps.kernel_smooth,
                    ps.kernel_uvs, ps.tri_magnitude, ps.material_index, ps.specular, g.p, g.ng, g.ns_raw, g.ns, g.tangent, g.bitangent, g.wo,
                    g.n_view, g.dn, g.mag, g.cos_o_geo, g.uv_buffer)
    return g

def shade_points(ps: PreparedScene, g: "SurfaceBatch", mat: np.ndarray, prim: np.ndarray, dirs: np.ndarray,
                 lobes: "bsdf_mod.LobeBatch", emission: np.ndarray | None = None, bary=None,
                 path: np.ndarray | None = None, dp: np.ndarray | None = None, aov_out: np.ndarray | None = None):
    """Run the node programs of the points whose material has one, in place on `lobes` (and `emission`; and
    aov_out (N, K, 4): the AOV Output nodes' writes, core.shader_aovs).
    The shading context as Cycles builds it: world position, N and Ng turned to the viewer's side, I = -dir;
    path: the points' Light Path state (None: camera rays); dp (N,) the footprint of each hit (Cycles' compact
    sd->dP) for Bump nodes. A program that sets the shading normal (Normal Map, Bump) gets the point's shading
    frame rebuilt around it (geometry_kernels.reframe); returns (those rows, their smooth normals) or None."""
    sh = ps.shading
    rows = np.flatnonzero(sh.needs_program[mat])
    if len(rows) == 0:
        return None
    back = g.cos_o_geo < 0
    # the world position; Cycles' sd->N and sd->Ng: the interpolated and the face normal, both negated on a back
    # face (no specular-validity tilt: that belongs to the closures, not to what nodes read); I = -dirs
    m = len(mat)
    if g.p.shape[0] != m:  # the compiled pass writes m rows, one per hit of g
        raise ValueError(f"shade_points: {g.p.shape[0]} hits against {m} materials")
    p_world, ng, n, view = (np.empty((m, 3), np.float32) for _ in range(4))
    geometry_kernels.shading_inputs(g.p, ps.shift.astype(np.float32), g.ng, g.ns_raw, g.cos_o_geo,
                                    np.asarray(dirs, np.float32), p_world, ng, n, view)
    obj = ps.object_of_triangle[prim]
    if ps.motion_slot is not None and bary is not None:
        sh, obj = _objects_at_hit_time(ps, sh, obj, prim, bary, g.p)
    # Differentials, tangents and named UV maps only for the points whose program reads them (each costs more
    # NumPy work per point than a short program's evaluation; the others read zeros they never use)
    needs = ps.vector_needs
    vec = vector_context(ps, prim, bary, ng, dp, g.uv is not None,
                         wants_differentials=None if needs is None else needs.differentials[mat],
                         wants_tangents=None if needs is None else needs.tangents[mat])
    uvx = None
    if ps.uv_layers is not None and bary is not None:  # the named UV maps at the hit points
        want = np.ones(len(prim), bool) if needs is None else needs.uv_layers[mat]
        sel = None if want.all() else np.flatnonzero(want)
        b1, b2 = np.asarray(bary[0], np.float32), np.asarray(bary[1], np.float32)
        corners = ps.uv_layers[prim if sel is None else prim[sel]]  # (N, K, 3, 2)
        if sel is not None:
            b1, b2 = b1[sel], b2[sel]
        uvx = (corners[:, :, 0] * (1 - b1 - b2)[:, None, None] + corners[:, :, 1] * b1[:, None, None]
               + corners[:, :, 2] * b2[:, None, None]).astype(np.float32)
        if vec.db is not None:  # and their derivatives along dP.dx, dP.dy
            db = vec.db if sel is None else vec.db[sel]
            e1, e2 = corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0]  # (N, K, 2)
            full = np.empty((len(b1), uvx.shape[1], 3, 2), np.float32)
            full[:, :, 0] = uvx
            for j in range(2):
                full[:, :, 1 + j] = (e1 * db[:, j, 0, None, None] + e2 * db[:, j, 1, None, None])
            uvx = full
        if sel is not None:
            all_rows = np.zeros((len(prim), *uvx.shape[1:]), np.float32)
            all_rows[sel] = uvx
            uvx = all_rows
    extra = None
    if sh.uses_light_path or sh.uses_attributes:
        attrs = ps.attributes if sh.uses_attributes else None
        n_attr = 0 if attrs is None else attrs.shape[1]
        extra = np.zeros((len(mat), PATH_COLUMNS + ATTRIBUTE_COLUMNS * n_attr), np.float32)
        if path is not None:
            extra[:, :PATH_COLUMNS] = path
        else:
            extra[:, PATH_FLAGS] = RAY_CAMERA
        if n_attr and bary is not None:  # the named attributes at the hit points, as the UV maps
            b1, b2 = np.asarray(bary[0], np.float32), np.asarray(bary[1], np.float32)
            corners = attrs[prim]  # (N, A, 3, ATTRIBUTE_COLUMNS)
            vals = (corners[:, :, 0] * (1 - b1 - b2)[:, None, None] + corners[:, :, 1] * b1[:, None, None]
                    + corners[:, :, 2] * b2[:, None, None])
            extra[:, PATH_COLUMNS:] = vals.reshape(len(mat), -1)
    normal_out = np.zeros((len(mat), 3), np.float32) if sh.any_sets_normal else None
    has_normal = sh.evaluate(rows, mat, p_world, n, ng, view, g.uv, back, obj, lobes,
                             ps.materials.select_scale, emission, uvx, extra, dP=vec.dP, duv=vec.duv,
                             tangents=vec.tangents, mesh_normal=vec.mesh_normal, normal_out=normal_out,
                             aov_out=aov_out)
    if has_normal is not None:
        moved = np.flatnonzero(has_normal)
        if len(moved):
            geometry_kernels.reframe(moved.astype(np.int64), normal_out, np.ascontiguousarray(dirs, np.float32),
                                     g.ng, g.cos_o_geo, ps.specular[mat], g.ns, g.tangent, g.bitangent, g.wo,
                                     g.n_view, g.dn)
            return moved, n[moved].astype(np.float32)
    return None


def emission_at(ps: PreparedScene, triangles: np.ndarray, b1: np.ndarray, b2: np.ndarray,
                towards: np.ndarray | None = None, path: np.ndarray | None = None,
                chunk: int = 1 << 16) -> np.ndarray:
    """(K, 3) float32 emitted radiance of the node programs at points (triangle, barycentrics b1, b2), seen along
    the unit directions `towards` (K, 3) (the ray arriving there; None: head-on from the front), with the Light
    Path state `path` (K, PATH_COLUMNS) (None: a camera ray)."""
    k = len(triangles)
    out = np.zeros((k, 3), np.float32)
    for a in range(0, k, chunk):
        t = np.ascontiguousarray(triangles[a:a + chunk], np.int32)
        u, v = np.ascontiguousarray(b1[a:a + chunk], np.float32), np.ascontiguousarray(b2[a:a + chunk], np.float32)
        d = -ps.face_normals[t] if towards is None else np.ascontiguousarray(towards[a:a + chunk], np.float32)
        g = surface_batch(ps, np.arange(len(t), dtype=np.int64), t, u, v, d)
        mat = ps.material_index[t]
        shade_points(ps, g, mat, t, d, ps.materials.gather(mat, g.uv), out[a:a + chunk], bary=(u, v),
                     path=None if path is None else np.ascontiguousarray(path[a:a + chunk], np.float32))
    return out


def _objects_at_hit_time(ps: PreparedScene, sh: PreparedShading, obj: np.ndarray, prim: np.ndarray, bary,
                         p: np.ndarray):
    """Motion blur: for hits on moving triangles, object rows (appended to a per-call copy of the shading's
    object table) whose world -> object transform takes the hit, where its triangle is at the ray's time, to
    the object-space point it has at the frame: object and generated texture coordinates move with the
    object, as Cycles' motion-interpolated object transforms do (exact for rigid motion). Object Info's
    Location moves with the hit likewise. Returns (shading, object rows per point)."""
    from .shading.program import OBJECT_INVERSE, OBJECT_LOCATION

    moving = np.flatnonzero(ps.motion_slot[prim] >= 0)
    if len(moving) == 0:
        return sh, obj
    b1 = np.asarray(bary[0], np.float64)[moving][:, None]
    b2 = np.asarray(bary[1], np.float64)[moving][:, None]
    corners = ps.tri_vertices[prim[moving]].astype(np.float64)
    at_frame = corners[:, 0] * (1.0 - b1 - b2) + corners[:, 1] * b1 + corners[:, 2] * b2
    delta = at_frame - np.asarray(p, np.float64)[moving]
    rows = sh.objects[obj[moving]].astype(np.float64)
    inverse = rows[:, OBJECT_INVERSE:OBJECT_INVERSE + 12].reshape(-1, 3, 4)
    inverse[:, :, 3] += np.einsum("kij,kj->ki", inverse[:, :, :3], delta)
    rows[:, OBJECT_INVERSE:OBJECT_INVERSE + 12] = inverse.reshape(-1, 12)
    rows[:, OBJECT_LOCATION:OBJECT_LOCATION + 3] -= delta
    moved = copy.copy(sh)  # the table is shared by the render's threads: extend a copy
    moved.objects = np.ascontiguousarray(np.concatenate([sh.objects, rows.astype(np.float32)]))
    obj = obj.copy()
    obj[moving] = len(sh.objects) + np.arange(len(moving), dtype=obj.dtype)
    return moved, obj
