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
    tangent_layers: dict = None  # UV map name ("" = active render) -> (T, 3, 4) MikkTSpace tangent xyz + sign

    @property
    def triangle_count(self) -> int:
        return int(self.triangles.shape[0])


def read_mesh(mesh, name: str, tangent_maps=(), warnings: list | None = None) -> LocalMesh:
    """Triangles, positions, shading normals, UVs and material slots of an evaluated Blender mesh; tangent_maps:
    the UV map names ("" = the active render map) whose MikkTSpace tangents Normal Map nodes read."""
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
    tangents = _tangents(mesh, name, tangent_maps, loops, warnings) if n_tri and tangent_maps else {}
    return LocalMesh(name, vertices, tri_verts, slots, normals, uvs, layers, tangents)


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
        tangent_layers={name: np.ascontiguousarray(tl.reshape(-1, 3, 4)) for name, tl in tangents.items()} or None,
    )
