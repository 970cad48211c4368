"""Evaluated Blender meshes -> core Meshes, with bulk foreach_get into NumPy (no per-vertex Python).

A mesh is read once in its local space (`read_mesh`) and then placed at every instance's world matrix in
one vectorised step (`instances_to_mesh`): collection instances, geometry-node instances, particles and
linked duplicates of one mesh cost one conversion however many times they appear.

Shading normals follow Blender: `normals_domain` FACE (all flat) -> no per-corner normals (the geometric
normal), POINT (smooth, no sharp edges) -> vertex normals, CORNER (sharp edges, custom normals, mixed) ->
corner normals. Normals go to world space with the inverse transpose; a mirroring matrix (negative
determinant) flips the winding so that the geometric normal still points outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.scene import Mesh


@dataclass
class LocalMesh:
    """One evaluated mesh in object space."""

    name: str
    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (T, 3) int32
    slots: np.ndarray  # (T,) int32 material slot per triangle
    normals: np.ndarray | None  # (T, 3, 3) float32 or None (flat)
    uvs: np.ndarray | None  # (T, 3, 2) float32 or None
    uv_layers: dict = None  # every UV map by name: (T, 3, 2) float32 (what UV Map nodes name)
    attributes: dict = None  # the attributes Attribute nodes name: (T, 3, 5) float32 (core.scene.Mesh.attributes)
    missing_attributes: tuple = ()  # names asked for that the mesh does not have (they read 0)
    tangent_layers: dict = None  # UV map name ("" = active render) -> (T, 3, 4) MikkTSpace tangent xyz + sign

    @property
    def triangle_count(self) -> int:
        return int(self.triangles.shape[0])


def read_mesh(mesh, name: str, attribute_names=None, tangent_maps=(), warnings: list | None = None) -> LocalMesh:
    """Triangles, positions, shading normals, UVs and material slots of an evaluated Blender mesh, the named
    attributes `attribute_names(slots)` asks for (a callable given the (T,) material slots, or None), and
    tangent_maps: the UV map names ("" = the active render map) whose MikkTSpace tangents Normal Map nodes read."""
    mesh.calc_loop_triangles()
    tris = mesh.loop_triangles
    n_tri = len(tris)
    n_vert = len(mesh.vertices)
    vertices = np.empty(n_vert * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", vertices)
    vertices = vertices.reshape(n_vert, 3)
    tri_verts = np.empty(n_tri * 3, dtype=np.int32)
    tris.foreach_get("vertices", tri_verts)
    tri_verts = tri_verts.reshape(n_tri, 3)
    slots = np.empty(n_tri, dtype=np.int32)
    tris.foreach_get("material_index", slots)

    tri_loops = None

    def loops() -> np.ndarray:
        nonlocal tri_loops
        if tri_loops is None:
            tri_loops = np.empty(n_tri * 3, dtype=np.int32)
            tris.foreach_get("loops", tri_loops)
        return tri_loops

    normals = None
    domain = getattr(mesh, "normals_domain", "CORNER")
    if n_tri and domain == "POINT":
        vn = np.empty(n_vert * 3, dtype=np.float32)
        mesh.vertex_normals.foreach_get("vector", vn)
        normals = vn.reshape(n_vert, 3)[tri_verts]
    elif n_tri and domain == "CORNER":
        n_loop = len(mesh.loops)
        cn = np.empty(n_loop * 3, dtype=np.float32)
        mesh.corner_normals.foreach_get("vector", cn)
        normals = cn.reshape(n_loop, 3)[loops()].reshape(n_tri, 3, 3)

    uvs = None
    layers = {}
    active = mesh.uv_layers.active
    if n_tri and len(mesh.uv_layers):
        n_loop = len(mesh.loops)
        for layer in mesh.uv_layers:
            uv = np.empty(n_loop * 2, dtype=np.float32)
            layer.uv.foreach_get("vector", uv)
            layers[layer.name] = uv.reshape(n_loop, 2)[loops()].reshape(n_tri, 3, 2)
        if active is not None:
            uvs = layers[active.name]
    attributes, missing = {}, []
    for aname in (attribute_names(slots) if attribute_names is not None and n_tri else ()):
        values = _read_attribute(mesh, aname, layers, tri_verts, loops, tris)
        if values is None:
            missing.append(aname)
        else:
            attributes[aname] = values
    tangents = _tangents(mesh, name, tangent_maps, loops, warnings) if n_tri and tangent_maps else {}
    return LocalMesh(name, vertices, tri_verts, slots, normals, uvs, layers, attributes, tuple(missing),
                     tangents)


# Blender attribute data types Monte reads, by how many components they have (1: a float, 2: a 2D vector, 3: a
# vector, 4: a colour with alpha); the integer and boolean types read as floats, as Cycles converts them.
_ATTRIBUTE_TYPES = {"FLOAT": ("value", 1), "INT": ("value", 1), "INT8": ("value", 1), "BOOLEAN": ("value", 1),
                    "FLOAT2": ("vector", 2), "INT32_2D": ("vector", 2), "FLOAT_VECTOR": ("vector", 3),
                    "FLOAT_COLOR": ("color", 4), "BYTE_COLOR": ("color", 4)}


def render_color_name(mesh) -> str | None:
    """The mesh's active render colour attribute (what an unnamed Color Attribute node reads), or None."""
    colors = getattr(mesh, "color_attributes", None)
    if colors is None or not len(colors):
        return None
    i = getattr(colors, "render_color_index", -1)
    if 0 <= i < len(colors):
        return colors[i].name
    return getattr(mesh.attributes, "default_color_name", None) or None


def _read_attribute(mesh, aname: str, uv_layers: dict, tri_verts: np.ndarray, loops, tris) -> np.ndarray | None:
    """(T, 3, 5) float32 per triangle corner of the attribute `aname` ("" = the render colour attribute):
    colour/vector xyz, alpha, fac as Cycles' Attribute node outputs them; None when the mesh has no such
    attribute (or one of a domain or type Cycles does not render on a surface)."""
    n_tri = tri_verts.shape[0]
    real = render_color_name(mesh) if aname == "" else aname
    if real is None:
        return None
    attr = mesh.attributes.get(real)
    if attr is None or real.startswith("."):
        if real in uv_layers:  # a UV map read by name: a 2D vector
            uv = uv_layers[real]
            out = np.zeros((n_tri, 3, 5), np.float32)
            out[..., :2], out[..., 3], out[..., 4] = uv, 1.0, uv[..., 0]
            return out
        return None
    kind = _ATTRIBUTE_TYPES.get(attr.data_type)
    if kind is None or attr.domain not in ("POINT", "CORNER", "FACE"):
        return None
    prop, width = kind
    n = len(attr.data)
    flat = np.empty(n * width, np.float32) if prop != "value" else np.empty(n, np.float32)
    if attr.data_type in ("INT", "INT8", "BOOLEAN", "INT32_2D"):
        raw = np.empty(flat.size, np.int32 if attr.data_type != "BOOLEAN" else bool)
        attr.data.foreach_get(prop, raw)
        flat = raw.astype(np.float32)
    else:
        attr.data.foreach_get(prop, flat)
    values = flat.reshape(n, width)
    if attr.domain == "POINT":
        corner = values[tri_verts]
    elif attr.domain == "CORNER":
        corner = values[loops()].reshape(n_tri, 3, width)
    else:
        faces = np.empty(n_tri, np.int32)
        tris.foreach_get("polygon_index", faces)
        corner = np.broadcast_to(values[faces][:, None, :], (n_tri, 3, width))
    out = np.zeros((n_tri, 3, 5), np.float32)
    if width == 1:
        out[..., :3] = corner
        out[..., 3] = 1.0
        out[..., 4] = corner[..., 0]
    elif width == 2:
        out[..., :2] = corner
        out[..., 3] = 1.0
        out[..., 4] = corner[..., 0]
    else:
        out[..., :3] = corner[..., :3]
        out[..., 3] = corner[..., 3] if width == 4 else 1.0
        out[..., 4] = corner[..., :3].mean(axis=-1)
    return out


def _tangents(mesh, name: str, maps, loops, warnings) -> dict:
    """Blender's MikkTSpace tangents (Mesh.calc_tangents) per triangle corner for each UV map in `maps` the mesh
    has: (T, 3, 4) float32, xyz the tangent, w the bitangent sign. A mesh without the map gets none (Cycles then
    leaves the normal unperturbed); a failure is a warning naming the mesh."""
    out = {}
    render = next((layer for layer in mesh.uv_layers if getattr(layer, "active_render", False)), None)
    render = render or mesh.uv_layers.active
    n_loop = len(mesh.loops)
    for key in sorted(maps):
        uv_name = key or (render.name if render is not None else "")
        if not uv_name or uv_name not in mesh.uv_layers:
            continue
        try:
            mesh.calc_tangents(uvmap=uv_name)
        except RuntimeError as exc:
            if warnings is not None:
                warnings.append(f"mesh {name!r}: tangents of UV map {uv_name!r} could not be computed ({exc}); "
                                "normal maps there leave the normal unperturbed")
            continue
        t = np.empty(n_loop * 3, dtype=np.float32)
        sign = np.empty(n_loop, dtype=np.float32)
        mesh.loops.foreach_get("tangent", t)
        mesh.loops.foreach_get("bitangent_sign", sign)
        mesh.free_tangents()
        both = np.concatenate([t.reshape(n_loop, 3), sign[:, None]], axis=1)
        out[key] = both[loops()].reshape(-1, 3, 4)
    return out


def instances_to_mesh(local: LocalMesh, matrices: np.ndarray, slot_materials: np.ndarray, name: str,
                      shadow_terminator_offset: float = 0.0) -> Mesh:
    """Place `local` at each of the (K, 4, 4) world matrices; slot_materials maps slot -> scene material.
    shadow_terminator_offset: the object's Shadow Terminator Geometry Offset (see core.scene.Mesh)."""
    k = matrices.shape[0]
    v = local.vertices.astype(np.float64)
    n_vert, n_tri = v.shape[0], local.triangle_count
    lin = matrices[:, :3, :3]
    # (K, V, 3) world positions
    world = np.matmul(v[None], lin.transpose(0, 2, 1)) + matrices[:, None, :3, 3]
    tri = local.triangles[None, :, :] + (np.arange(k, dtype=np.int64) * n_vert)[:, None, None]
    det = np.linalg.det(lin)
    mirrored = det < 0

    normals = None
    if local.normals is not None:
        inv = np.linalg.inv(np.where(np.abs(det)[:, None, None] > 1e-300, lin, np.eye(3)))
        # n' = inv(M)^T n; as row vectors: n @ inv(M). float32 is plenty for unit vectors.
        n = np.matmul(local.normals.reshape(1, -1, 3), inv.astype(np.float32))
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
        normals = n.reshape(k, n_tri, 3, 3)
    uvs = None if local.uvs is None else np.broadcast_to(local.uvs, (k, n_tri, 3, 2))
    layers = {name: np.broadcast_to(uv, (k, n_tri, 3, 2)) for name, uv in (local.uv_layers or {}).items()}
    attrs = {name: np.broadcast_to(a, (k, n_tri, 3, 5)) for name, a in (local.attributes or {}).items()}
    tangents = {}
    if local.tangent_layers:
        # Tangents go to world space as normals do (the normal matrix), keeping their length; a mirroring
        # instance negates the bitangent sign (the cross product of mirrored vectors turns around).
        inv = np.linalg.inv(np.where(np.abs(det)[:, None, None] > 1e-300, lin, np.eye(3))).astype(np.float32)
        for lname, tl in local.tangent_layers.items():
            t = tl[None, :, :, :3].reshape(1, -1, 3)
            length = np.linalg.norm(t, axis=-1, keepdims=True)
            w = np.matmul(t, inv)  # (K, T*3, 3)
            w *= length / np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-30)
            sign = np.broadcast_to(tl[None, :, :, 3], (k, n_tri, 3)) * np.where(mirrored, -1.0, 1.0)[:, None, None]
            tangents[lname] = np.concatenate([w.reshape(k, n_tri, 3, 3), sign[..., None]], axis=-1).astype(np.float32)

    if mirrored.any():
        tri = tri.copy()
        tri[mirrored] = tri[mirrored][:, :, [0, 2, 1]]
        if normals is not None:
            normals[mirrored] = normals[mirrored][:, :, [0, 2, 1]]
        if uvs is not None:
            uvs = uvs.copy()
            uvs[mirrored] = uvs[mirrored][:, :, [0, 2, 1]]
        for name, uv in layers.items():
            uv = uv.copy()
            uv[mirrored] = uv[mirrored][:, :, [0, 2, 1]]
            layers[name] = uv
        for name, a in attrs.items():
            a = a.copy()
            a[mirrored] = a[mirrored][:, :, [0, 2, 1]]
            attrs[name] = a
        for name, tl in tangents.items():
            tl[mirrored] = tl[mirrored][:, :, [0, 2, 1]]

    slots = np.clip(local.slots, 0, len(slot_materials) - 1)
    mat = np.broadcast_to(slot_materials[slots], (k, n_tri)).reshape(-1)
    return Mesh(
        name=name,
        vertices=world.reshape(-1, 3),
        triangles=tri.reshape(-1, 3).astype(np.int32 if k * n_vert < 2**31 else np.int64),
        material_index=np.ascontiguousarray(mat, dtype=np.int32),
        normals=None if normals is None else normals.reshape(-1, 3, 3),
        uvs=None if uvs is None else np.ascontiguousarray(uvs.reshape(-1, 3, 2), dtype=np.float32),
        shadow_terminator_offset=float(shadow_terminator_offset),
        uv_layers={name: np.ascontiguousarray(uv.reshape(-1, 3, 2), dtype=np.float32) for name, uv in layers.items()}
        or None,
        attributes={name: np.ascontiguousarray(a.reshape(-1, 3, 5), dtype=np.float32) for name, a in attrs.items()}
        or None,
        tangent_layers={name: np.ascontiguousarray(tl.reshape(-1, 3, 4)) for name, tl in tangents.items()} or None,
    )
