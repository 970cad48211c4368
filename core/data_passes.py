"""Cycles' data passes: Mist, Position, UV, Object Index, Material Index and Cryptomatte Object / Material / Asset.

They read the surfaces a camera sample's path meets while it still sees the background: the camera ray's hit,
and the surfaces behind it while the path goes on through Transparent BSDFs (DataPath; a miss writes nothing).
Each with Cycles' (Blender 5.3) meaning, alpha = 1 - transparency (the summed colour of a surface's Transparent
BSDF lobes):

- Position (world space), Object Index (the object's Pass Index) and Material Index (the material's Pass Index)
  are taken from the pixel's first sample only and not averaged (Cycles overwrites them at sample 0): its first
  surface whose mean alpha is at least 0.5 (Cycles' pass alpha threshold), or the last one it met; 0 where that
  sample saw nothing.
- UV is the mean over the pixel's samples of (u, v, 1) of the active UV map at that same surface (only where it
  is opaque enough; (0, 0, 0) on a miss or on geometry without UVs), Blender's channels U, V, A.
- Mist is 1 - mean over samples of the sum over the surfaces of (1 - m) x mean(throughput x alpha),
  m = clamp((distance - start) / depth, 0, 1) ** falloff exponent (Quadratic 2, Linear 1, Inverse Quadratic
  0.5); distance from the camera position (along the view axis for an orthographic camera), as Cycles'
  camera_distance; the world reads 1.
- Cryptomatte (the OpenEXR Cryptomatte standard): each name (object, material, or asset = the top-most parent
  of the object) is hashed with MurmurHash3_x86_32 (seed 0) and the hash made a float32 (exponent kept in
  [1, 254]); a pixel's coverage of a name is the mean over its samples of mean(throughput) x (1 - mean
  transparency) of the surfaces carrying the name; the `levels` largest (id, coverage) pairs, in decreasing
  coverage, fill layers of 4 channels (id, coverage, id, coverage): CryptoObject00, CryptoObject01, ... The
  manifest ({name: 8 hex digits of the hash}) goes into the file's metadata under cryptomatte/<first 7 hex
  digits of the hash of the layer name>/{name, hash, conversion, manifest}.

Russian roulette may end a path before a surface behind a transparent one is recorded (Monte decides it before
shading a vertex, Cycles after); the survivors' throughput carries 1 / q, so the passes' means are unchanged.
Nothing here runs unless settings.data_passes names a pass: a render without them is unchanged.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass

import numpy as np

from .scene import MIST_FALLOFF, Mist

# Core pass keys, in Cycles' order, and the Blender pass each fills (Cycles' own names).
PASS_NAMES = {
    "mist": "Mist",
    "position": "Position",
    "uv": "UV",
    "object_index": "Object Index",
    "material_index": "Material Index",
    "vector": "Vector",
}
CRYPTO_NAMES = {
    "crypto_object": "CryptoObject",
    "crypto_material": "CryptoMaterial",
    "crypto_asset": "CryptoAsset",
}
DATA_PASSES = tuple(PASS_NAMES) + tuple(CRYPTO_NAMES)
CRYPTOMATTE_MAX_LEVELS = 16  # Blender's View Layer > Cryptomatte > Levels range


# ------------------------------------------------------------------------------------------------- hashing
def murmur3_32(data: bytes, seed: int = 0) -> int:
    """MurmurHash3_x86_32 of `data` (the hash the Cryptomatte standard names), as an unsigned 32-bit int."""
    c1, c2, mask = 0xCC9E2D51, 0x1B873593, 0xFFFFFFFF
    h = seed & mask
    n = len(data) // 4
    for (k,) in struct.iter_unpack("<I", data[:4 * n]):
        k = (k * c1) & mask
        k = ((k << 15) | (k >> 17)) & mask
        k = (k * c2) & mask
        h ^= k
        h = ((h << 13) | (h >> 19)) & mask
        h = (h * 5 + 0xE6546B64) & mask
    tail = data[4 * n:]
    if tail:
        k = int.from_bytes(tail, "little")
        k = (k * c1) & mask
        k = ((k << 15) | (k >> 17)) & mask
        k = (k * c2) & mask
        h ^= k
    h ^= len(data)
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & mask
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & mask
    h ^= h >> 16
    return h


def hash_to_float(h: int) -> np.float32:
    """The Cryptomatte id of a 32-bit hash: its bits read as a float32, the exponent kept in [1, 254] so that
    it is never denormal, infinite or NaN (the standard's uint32_to_float32)."""
    exponent = min(max((h >> 23) & 0xFF, 1), 254)
    bits = (h & 0x807FFFFF) | (exponent << 23)
    return np.frombuffer(struct.pack("<I", bits), np.float32)[0]


def name_hash(name: str) -> int:
    return murmur3_32(name.encode("utf-8"))


def manifest(names) -> dict[str, str]:
    """{name: 8 hex digits of its hash} (the Cryptomatte manifest), names sorted."""
    return {name: f"{name_hash(name):08x}" for name in sorted(set(names))}


def cryptomatte_metadata(layer: str, names) -> dict[str, str]:
    """The EXR header / render-result metadata of one Cryptomatte layer (e.g. "ViewLayer.CryptoObject")."""
    key = f"cryptomatte/{name_hash(layer):08x}"[:len("cryptomatte/") + 7]
    return {f"{key}/name": layer, f"{key}/hash": "MurmurHash3_32", f"{key}/conversion": "uint32_to_float32",
            f"{key}/manifest": json.dumps(manifest(names), separators=(",", ":"))}


# ---------------------------------------------------------------------------------------------- the scene
@dataclass
class DataTables:
    """Per-triangle lookups of a prepared scene for the requested passes: pass indices, and for each
    Cryptomatte kind the triangle's name (an index into names[kind]) and each name's float id."""

    passes: tuple[str, ...]
    levels: int
    object_pass: np.ndarray  # (T,) float32
    material_pass: np.ndarray  # (M,) float32
    name_of_triangle: dict  # kind -> (T,) int32
    names: dict  # kind -> list[str]
    ids: dict  # kind -> (K,) float32
    mist: Mist
    camera_position: np.ndarray  # (3,) float64 world
    camera_forward: np.ndarray | None  # (3,) unit view axis for an orthographic camera, else None
    vector: "VectorTables | None" = None  # the Vector pass's triangles and cameras (its key in passes)

    @classmethod
    def build(cls, scene, prepared, passes: tuple[str, ...], levels: int) -> "DataTables":
        from .shading.program import OBJECT_PASS_INDEX

        t_count = len(prepared.triangles)
        rows = prepared.object_of_triangle if len(prepared.object_of_triangle) == t_count else np.zeros(t_count, int)
        object_table = np.zeros(1, np.float32)
        if scene.objects is not None and len(scene.objects):
            object_table = np.concatenate([[0.0], scene.objects[:, OBJECT_PASS_INDEX]]).astype(np.float32)
        material_pass = np.array([getattr(m, "pass_index", 0) for m in scene.materials], np.float32)
        name_of_triangle, names, ids = {}, {}, {}
        kinds = [k for k in CRYPTO_NAMES if k in passes]
        if kinds:
            mesh_of_triangle = np.concatenate([np.full(m.triangle_count, i, np.int32)
                                               for i, m in enumerate(scene.meshes) if m.triangle_count]
                                              or [np.zeros(0, np.int32)])
            for kind in kinds:
                table, key = _name_table(kind, scene, rows, mesh_of_triangle, prepared.material_index)
                used, key_to_used = np.unique(np.asarray(key, np.int64), return_inverse=True)  # names in use
                uniq, inverse = np.unique(np.array([table[i] for i in used] or [""], dtype=str),
                                          return_inverse=True)
                names[kind] = [str(n) for n in uniq] if len(used) else []
                name_of_triangle[kind] = inverse.reshape(-1).astype(np.int32)[key_to_used.reshape(-1)]
                ids[kind] = np.array([hash_to_float(name_hash(n)) for n in names[kind]], np.float32)
        cam = scene.camera
        matrix = np.asarray(cam.matrix_world, np.float64)
        forward = None
        if cam.kind == "ORTHO":
            forward = -matrix[:3, 2] / max(np.linalg.norm(matrix[:3, 2]), 1e-30)
        vector = VectorTables.build(scene, prepared) if "vector" in passes else None
        return cls(tuple(passes), int(levels), object_table[rows], material_pass, name_of_triangle, names, ids,
                   getattr(scene, "mist", None) or Mist(), matrix[:3, 3].copy(), forward, vector)

    @classmethod
    def for_merge(cls, passes: tuple[str, ...], levels: int, names: dict[str, list[str]]) -> "DataTables":
        """Tables for films that only add up sums made elsewhere (core.render.merge_tile_samples): the passes, the
        Cryptomatte levels and each kind's names (as the renders that took the samples listed them), no scene."""
        kinds = [k for k in CRYPTO_NAMES if k in passes]
        missing = [k for k in kinds if k not in names]
        if missing:
            raise ValueError(f"the Cryptomatte names of {', '.join(missing)} are missing from the film sums")
        names = {kind: list(names[kind]) for kind in kinds}
        ids = {kind: np.array([hash_to_float(name_hash(n)) for n in names[kind]], np.float32) for kind in kinds}
        return cls(tuple(passes), int(levels), np.zeros(0, np.float32), np.zeros(0, np.float32),
                   {kind: np.zeros(0, np.int32) for kind in kinds}, names, ids, Mist(), np.zeros(3), None)

    def samples(self, path: "DataPath") -> dict:
        """What each camera sample of a batch adds to the passes (see the module docstring), from the surfaces
        its path recorded (DataPath). Per-sample arrays, except Cryptomatte: per kind (sample row, name index,
        weight) of every surface that adds to it."""
        n = len(path.prim)
        out: dict = {}
        done = path.prim >= 0
        tri = path.prim[done]
        if "position" in self.passes:
            out["position"] = path.position.astype(np.float32)
        if "uv" in self.passes:
            out["uv"] = path.uv.astype(np.float64)
        if "object_index" in self.passes:
            v = np.zeros(n, np.float32)
            v[done] = self.object_pass[tri]
            out["object_index"] = v
        if "material_index" in self.passes:
            v = np.zeros(n, np.float32)
            v[done] = self.material_pass[path.material[done]]
            out["material_index"] = v
        if self.vector is not None:
            out["vector"], out["vector_weight"] = self.vector.motion(path)
        rows, prim, position, mist_weight, matte_weight = path.surfaces()
        if "mist" in self.passes:
            rel = position - self.camera_position
            dist = rel @ self.camera_forward if self.camera_forward is not None else np.linalg.norm(rel, axis=1)
            inv_depth = 1.0 / self.mist.depth if self.mist.depth > 0 else 0.0
            m = np.clip((dist - self.mist.start) * inv_depth, 0.0, 1.0) ** MIST_FALLOFF[self.mist.falloff]
            out["mist"] = np.bincount(rows, weights=(1.0 - m) * mist_weight, minlength=n)
        keep = matte_weight > 0
        for kind, table in self.name_of_triangle.items():
            out[kind] = (rows[keep], table[prim[keep]], matte_weight[keep])
        return out


def take_samples(values: dict, start: int, stop: int) -> dict:
    """The part of DataTables.samples' values that belongs to samples [start, stop) of the batch, renumbered
    from 0 (a batch spans several tiles)."""
    out = {}
    for key, value in values.items():
        if isinstance(value, tuple):
            rows, idx, weight = value
            sel = (rows >= start) & (rows < stop)
            out[key] = (rows[sel] - start, idx[sel], weight[sel])
        else:
            out[key] = value[start:stop]
    return out


# Cycles' film pass_alpha_threshold: the single-sample passes (Position, the indices, UV) are written at the first
# surface at least this opaque.
PASS_ALPHA_THRESHOLD = 0.5


class DataPath:
    """The surfaces each camera sample's path meets while it still sees the background through Transparent BSDFs
    (Cycles' PATH_RAY_TRANSPARENT_BACKGROUND: the camera ray, and rays that went on through a Transparent BSDF):
    at each, what it adds to Mist ((1 - mist) x mean(throughput x alpha)) and Cryptomatte (mean(throughput) x
    (1 - mean(transparency))), and the surface the single-sample passes read (the first whose mean alpha reaches
    PASS_ALPHA_THRESHOLD; until one does, the latest). alpha = 1 - transparency, transparency the summed colour
    of the surface's Transparent BSDF lobes (refraction of IOR 1, roughness 0)."""

    def __init__(self, n: int, prepared) -> None:
        self.shift = np.asarray(prepared.shift, np.float64)
        self.with_uv = prepared.uvs is not None
        self.clear_only = _clear_only(prepared)
        self.open = np.ones(n, bool)
        self.done = np.zeros(n, bool)
        self.prim = np.full(n, -1, np.int32)
        self.material = np.zeros(n, np.int32)
        self.position = np.zeros((n, 3), np.float64)
        self.uv = np.zeros((n, 3), np.float32)
        self._surfaces: list = []

    def record(self, idx: np.ndarray, prim: np.ndarray, mat: np.ndarray, p: np.ndarray, uv: np.ndarray | None,
               lobes, throughput: np.ndarray) -> None:
        """Surfaces hit by the live paths of samples idx (their triangles, materials, points in the prepared
        frame, UVs, lobes after shading, path throughput)."""
        rows = np.flatnonzero(self.open[idx])
        if len(rows) == 0:
            return
        samples = idx[rows]
        clear = (lobes.kind[rows] == 3) & (lobes.ior[rows] == 1.0) & (lobes.roughness[rows] == 0.0)
        transparency = np.clip((lobes.weight[rows] * clear[:, :, None]).sum(axis=1), 0.0, 1.0)
        alpha = 1.0 - transparency
        t = throughput[rows].astype(np.float64)
        position = p[rows].astype(np.float64) + self.shift
        self._surfaces.append((samples, prim[rows], position, (t * alpha).mean(axis=1),
                               t.mean(axis=1) * (1.0 - transparency.mean(axis=1))))
        single = ~self.done[samples]
        s = samples[single]
        self.prim[s], self.material[s], self.position[s] = prim[rows][single], mat[rows][single], position[single]
        opaque = single & (alpha.mean(axis=1) >= PASS_ALPHA_THRESHOLD)
        self.done[samples[opaque]] = True
        if self.with_uv and uv is not None:
            self.uv[samples[opaque], :2] = uv[rows][opaque]
            self.uv[samples[opaque], 2] = 1.0

    def scattered(self, idx: np.ndarray, transmitted: np.ndarray, mat: np.ndarray) -> None:
        """After BSDF sampling at the surfaces of samples idx: only a path that went through a surface whose
        transmission is all Transparent BSDF still sees the background."""
        self.open[idx] &= np.asarray(transmitted, bool) & self.clear_only[mat]

    def surfaces(self) -> tuple:
        """(sample row, triangle, world position, mist weight, matte weight) of every recorded surface."""
        if not self._surfaces:
            return (np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
        return tuple(np.concatenate(parts) for parts in zip(*self._surfaces))

    def take_live(self, live: np.ndarray, n: int) -> "DataPath":
        """This record (of the live rays `live` of n camera rays) spread back to all n: dead rays recorded
        nothing."""
        out = DataPath.__new__(DataPath)
        out.prim = np.full(n, -1, np.int32)
        out.material = np.zeros(n, np.int32)
        out.position = np.zeros((n, 3), np.float64)
        out.uv = np.zeros((n, 3), np.float32)
        out.prim[live], out.material[live], out.position[live], out.uv[live] = (self.prim, self.material,
                                                                                self.position, self.uv)
        rows, prim, position, mist_w, matte_w = self.surfaces()
        out._surfaces = [(np.asarray(live)[rows], prim, position, mist_w, matte_w)]
        out.done = np.zeros(n, bool)
        out.done[live] = self.done
        return out


class VectorTables:
    """The Vector pass (Cycles' motion vectors, rendered without motion blur): per triangle of the prepared scene
    its corners' world positions at the previous and the next frame (core.scene.Mesh.vector_vertices), and the
    camera there (Camera.vector_matrices; its lens and frame are the frame's).

    A sample's vector is read at the surface the single-sample passes read, where it is at least half opaque (a
    sample that meets none adds nothing, as a miss): the point keeps its barycentric coordinates, is placed at the
    previous and the next frame, and each position is projected to the raster (pixels, x from the left, y from
    the bottom: Cycles' raster) by the camera of its frame: (previous - center, center - next), Blender's Vector
    X, Y and Z, W as Cycles writes them (both pairs point back in time: an object moving right reads negative X
    and Z). The pixel holds the mean over its samples that wrote one."""

    def __init__(self, corners: np.ndarray, camera, matrices: np.ndarray, shift: np.ndarray, now: np.ndarray) -> None:
        self.corners = corners  # (2, T, 3, 3) float64 world
        self.camera = camera
        self.matrices = matrices  # (3, 4, 4) camera-to-world: previous, now, next
        self.shift = shift
        self.now = now  # (T, 3, 3) float64 corners in the prepared frame

    @classmethod
    def build(cls, scene, prepared) -> "VectorTables":
        parts = []
        for mesh in scene.meshes:
            if not mesh.triangle_count:
                continue
            tri = np.asarray(mesh.triangles, np.int64)
            vv = mesh.vector_vertices
            if vv is None:
                vv = np.broadcast_to(np.asarray(mesh.vertices, np.float64), (2,) + np.shape(mesh.vertices))
            parts.append(np.asarray(vv, np.float64)[:, tri])
        corners = np.concatenate(parts, axis=1) if parts else np.zeros((2, 0, 3, 3))
        if corners.shape[1] != len(prepared.tri_vertices):
            raise ValueError(f"the Vector pass: {corners.shape[1]} triangles in the meshes, "
                             f"{len(prepared.tri_vertices)} prepared")
        cam = scene.camera
        now = np.asarray(cam.matrix_world, np.float64)
        vm = cam.vector_matrices if cam.vector_matrices is not None else np.stack([now, now])
        return cls(corners, cam, np.stack([vm[0], now, vm[1]]), np.asarray(prepared.shift, np.float64),
                   np.asarray(prepared.tri_vertices, np.float64))

    def raster(self, points: np.ndarray, which: int) -> np.ndarray:
        """(N, 2) raster positions (pixels, y from the bottom) of world points seen by camera `which` (0 the
        previous frame's, 1 this frame's, 2 the next's)."""
        m = self.matrices[which]
        axes = m[:3, :3] / np.maximum(np.linalg.norm(m[:3, :3], axis=0), 1e-30)
        local = (points - m[:3, 3]) @ axes  # right, up, back
        if self.camera.kind == "ORTHO":
            x, y = local[:, 0], local[:, 1]
        else:
            depth = np.where(local[:, 2] < 0, -local[:, 2], 1e-30)
            x, y = local[:, 0] / depth, local[:, 1] / depth
        xmin, xmax, ymin, ymax = self.camera.frame()
        w, h = self.camera.resolution
        return np.stack([(x - xmin) / (xmax - xmin) * w, (y - ymin) / (ymax - ymin) * h], axis=1)

    def motion(self, path: "DataPath") -> tuple[np.ndarray, np.ndarray]:
        """((N, 4) motion vectors, (N,) weights 1 where the sample wrote one) of a batch's samples."""
        n = len(path.prim)
        out = np.zeros((n, 4), np.float64)
        rows = np.flatnonzero(path.done & (path.prim >= 0))
        if len(rows) == 0:
            return out, np.zeros(n)
        tri = path.prim[rows]
        a, b, c = (self.now[tri, k] for k in range(3))
        d = path.position[rows] - self.shift - a
        e1, e2 = b - a, c - a
        d00, d01, d11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        d20, d21 = (d * e1).sum(1), (d * e2).sum(1)
        denom = np.where(np.abs(d00 * d11 - d01 * d01) > 0, d00 * d11 - d01 * d01, 1.0)
        b1 = (d11 * d20 - d01 * d21) / denom
        b2 = (d00 * d21 - d01 * d20) / denom
        bary = np.stack([1.0 - b1 - b2, b1, b2], axis=1)[:, :, None]
        prev = (self.corners[0, tri] * bary).sum(1)
        nxt = (self.corners[1, tri] * bary).sum(1)
        center = self.raster(path.position[rows], 1)
        out[rows, :2] = self.raster(prev, 0) - center
        out[rows, 2:] = center - self.raster(nxt, 2)
        weight = np.zeros(n)
        weight[rows] = 1.0
        return out, weight


def _clear_only(prepared) -> np.ndarray:
    """(M,) whether every transmitting lobe of a material is a Transparent BSDF (refraction, IOR 1, roughness 0)
    and it has one."""
    out = []
    for material in prepared.scene.materials:
        through = [lobe for lobe in material.lobes if lobe.kind in ("glass", "refraction")]
        out.append(bool(through) and all(lobe.kind == "refraction" and lobe.ior == 1.0 and lobe.roughness == 0.0
                                         for lobe in through))
    return np.array(out, bool)


def _name_table(kind: str, scene, rows: np.ndarray, mesh_of_triangle: np.ndarray,
                material_index: np.ndarray) -> tuple[list[str], np.ndarray]:
    """(names, (T,) index into them) of the name each triangle carries for a Cryptomatte kind: its material's
    name, or its object's (asset's) name from Scene.object_names / asset_names, its mesh's name where the
    triangle has no object or the scene no object names."""
    if kind == "crypto_material":
        return [m.name for m in scene.materials], material_index
    mesh_names = [m.name for m in scene.meshes]
    per_object = scene.asset_names if kind == "crypto_asset" and scene.asset_names else scene.object_names
    if per_object and scene.objects is not None and len(per_object) == len(scene.objects):
        key = np.where(rows > 0, rows - 1, len(per_object) + mesh_of_triangle)
        return list(per_object) + mesh_names, key
    return mesh_names, mesh_of_triangle


# ------------------------------------------------------------------------------------------------ the film
class DataFilm:
    """Accumulators of the data passes for a tile of h x w pixels (see the module docstring for each pass)."""

    def __init__(self, width: int, height: int, tables: DataTables) -> None:
        self.width, self.height, self.tables = width, height, tables
        n = width * height
        self.count = np.zeros(n, np.int64)
        passes = tables.passes
        if "mist" in passes:
            self.mist = np.zeros(n, np.float64)
        if "uv" in passes:
            self.uv = np.zeros((n, 3), np.float64)
        if "position" in passes:
            self.position = np.zeros((n, 3), np.float32)
        if "object_index" in passes:
            self.object_index = np.zeros(n, np.float32)
        if "material_index" in passes:
            self.material_index = np.zeros(n, np.float32)
        if "vector" in passes:
            self.vector = np.zeros((n, 4), np.float64)
            self.vector_weight = np.zeros(n, np.float64)
        # Cryptomatte: sparse sums of coverage, keyed pixel * K + name index, kept sorted
        self.crypto = {kind: (np.zeros(0, np.int64), np.zeros(0, np.float64)) for kind in tables.name_of_triangle}
        self._capture: DataFilm | None = None  # capture_passes(): the current pass's sums, kept apart

    def add(self, pixel: np.ndarray, sample: np.ndarray, values: dict[str, np.ndarray]) -> None:
        """Accumulate samples (tile-local pixel indices, their sample indices, DataTables.samples' values)."""
        if self._capture is not None:
            self._capture.add(pixel, sample, values)
            return
        n = self.width * self.height
        pixel = np.asarray(pixel, np.int64)
        self.count += np.bincount(pixel, minlength=n)
        if "mist" in values:
            self.mist += np.bincount(pixel, weights=values["mist"], minlength=n)
        if "uv" in values:
            for c in range(3):
                self.uv[:, c] += np.bincount(pixel, weights=values["uv"][:, c], minlength=n)
        if "vector" in values:
            for c in range(4):
                self.vector[:, c] += np.bincount(pixel, weights=values["vector"][:, c], minlength=n)
            self.vector_weight += np.bincount(pixel, weights=values["vector_weight"], minlength=n)
        first = np.flatnonzero(np.asarray(sample) == 0)  # the overwritten passes: the pixel's sample 0
        for name in ("position", "object_index", "material_index"):
            if name in values and len(first):
                getattr(self, name)[pixel[first]] = values[name][first]
        for kind in self.crypto:
            rows, idx, weight = values[kind]
            k = len(self.tables.names[kind])
            # The samples' coverage per (pixel, name) is summed first, then added to the film's: a pixel's
            # coverage is its passes' sums added in pass order, which a film merged from passes taken
            # elsewhere (add_sums) repeats bit for bit.
            new_keys, inverse = np.unique(pixel[rows] * k + idx, return_inverse=True)
            self._add_crypto(kind, new_keys, np.bincount(inverse.reshape(-1), weights=weight,
                                                         minlength=len(new_keys)))

    def _add_crypto(self, kind: str, new_keys: np.ndarray, new_sums: np.ndarray) -> None:
        """Add sparse coverage sums (unique keys pixel * K + name index) to the film's Cryptomatte sums."""
        keys, sums = self.crypto[kind]
        all_keys, inverse = np.unique(np.concatenate([keys, new_keys]), return_inverse=True)
        all_sums = np.bincount(inverse.reshape(-1), weights=np.concatenate([sums, new_sums]),
                               minlength=len(all_keys))
        self.crypto[kind] = (all_keys, all_sums)

    # ------------------------------------------------ sums of a render split across machines (core.distributed)
    def _sum_names(self) -> list[str]:
        """The accumulators a pass adds to (the single-sample passes are set by the pixel's sample 0 only)."""
        return [name for name in ("count", "mist", "uv", "vector", "vector_weight") if hasattr(self, name)]

    def state(self) -> dict[str, np.ndarray]:
        """Copies of the film's accumulators by name (Cryptomatte's as "crypto_keys/<kind>" and
        "crypto_sums/<kind>"): set_state() of a film of the same tile and passes makes it this film."""
        names = self._sum_names() + [n for n in ("position", "object_index", "material_index") if hasattr(self, n)]
        out = {name: getattr(self, name).copy() for name in names}
        for kind, (keys, sums) in self.crypto.items():
            out[f"crypto_keys/{kind}"], out[f"crypto_sums/{kind}"] = keys.copy(), sums.copy()
        return out

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Make this film the film whose state() `state` is."""
        mine = self.state()
        self._check(state, mine)
        for name in mine:
            if not name.startswith("crypto_"):
                getattr(self, name)[...] = state[name]
        for kind in self.crypto:
            self.crypto[kind] = (np.asarray(state[f"crypto_keys/{kind}"], np.int64).copy(),
                                 np.asarray(state[f"crypto_sums/{kind}"], np.float64).copy())

    def capture_passes(self) -> None:
        """Keep the sums of the samples added from now on apart, one pass at a time (take_pass), instead of adding
        them to this film: a render split across machines sends them to be added in pass order (add_sums)."""
        self._capture = DataFilm(self.width, self.height, self.tables)

    def take_pass(self) -> dict[str, np.ndarray]:
        """The sums of the samples added since capture_passes() or the last take_pass() (one pass of the
        tile's samples, starting past sample 0); capturing starts over."""
        captured = self._capture
        if captured is None:
            raise ValueError("this data film is not capturing passes (capture_passes())")
        self._capture = DataFilm(self.width, self.height, self.tables)
        return {name: value for name, value in captured.state().items()
                if name not in ("position", "object_index", "material_index")}

    def add_sums(self, sums: dict[str, np.ndarray]) -> None:
        """Add one pass's sums (take_pass() of a film of the same tile and passes): bit for bit what add() of
        that pass's samples gives, since add() adds each pass's per-pixel sums the same way."""
        mine = {name: value for name, value in self.state().items()
                if name not in ("position", "object_index", "material_index")}
        self._check(sums, mine)
        for name in self._sum_names():
            getattr(self, name)[...] += sums[name]
        for kind in self.crypto:
            self._add_crypto(kind, np.asarray(sums[f"crypto_keys/{kind}"], np.int64),
                             np.asarray(sums[f"crypto_sums/{kind}"], np.float64))

    @staticmethod
    def _check(given: dict[str, np.ndarray], mine: dict[str, np.ndarray]) -> None:
        if set(given) != set(mine):
            raise ValueError(f"data pass sums hold {sorted(given)}, this film keeps {sorted(mine)}")
        for name, arr in mine.items():
            if not name.startswith("crypto_") and np.shape(given[name]) != arr.shape:
                raise ValueError(f"data pass sums {name!r} have shape {np.shape(given[name])}, this film "
                                 f"{arr.shape}")

    def images(self) -> dict[str, np.ndarray]:
        """{Blender pass name: (h, w, C) float32} for every pass the film keeps (Cryptomatte as its layers)."""
        h, w = self.height, self.width
        denom = np.maximum(self.count, 1).astype(np.float64)
        out = {}
        if hasattr(self, "mist"):
            out["Mist"] = (1.0 - self.mist / denom).reshape(h, w, 1)
        if hasattr(self, "position"):
            out["Position"] = self.position.reshape(h, w, 3)
        if hasattr(self, "uv"):
            out["UV"] = (self.uv / denom[:, None]).reshape(h, w, 3)
        if hasattr(self, "vector"):
            out["Vector"] = (self.vector / np.maximum(self.vector_weight, 1.0)[:, None]).reshape(h, w, 4)
        if hasattr(self, "object_index"):
            out["Object Index"] = self.object_index.reshape(h, w, 1)
        if hasattr(self, "material_index"):
            out["Material Index"] = self.material_index.reshape(h, w, 1)
        for kind, (keys, sums) in self.crypto.items():
            out.update(self._crypto_layers(kind, keys, sums, denom))
        return {name: np.ascontiguousarray(arr, np.float32) for name, arr in out.items()}

    def _crypto_layers(self, kind: str, keys: np.ndarray, sums: np.ndarray, denom: np.ndarray) -> dict:
        levels = self.tables.levels
        k = len(self.tables.names[kind])
        n = self.width * self.height
        ranked = np.zeros((n, levels, 2), np.float64)
        if len(keys):
            pixel, idx = keys // k, keys % k
            coverage = sums / denom[pixel]
            order = np.lexsort((idx, -coverage, pixel))  # by pixel, then decreasing coverage
            pixel, idx, coverage = pixel[order], idx[order], coverage[order]
            starts = np.searchsorted(pixel, pixel, side="left")
            rank = np.arange(len(pixel)) - starts
            keep = rank < levels
            ranked[pixel[keep], rank[keep], 0] = self.tables.ids[kind][idx[keep]]
            ranked[pixel[keep], rank[keep], 1] = coverage[keep]
        flat = ranked.reshape(self.height, self.width, levels * 2)
        base = CRYPTO_NAMES[kind]
        return {f"{base}{i:02d}": flat[:, :, 4 * i:4 * i + 4] for i in range(levels // 2)}


def assemble(tiles_and_films, region) -> dict[str, np.ndarray]:
    """The region's data passes from (tile rect, DataFilm) pairs."""
    rx, ry, rw, rh = region
    out: dict[str, np.ndarray] = {}
    for tile, film in tiles_and_films:
        tx, ty, tw, th = tile
        for name, img in film.images().items():
            if name not in out:
                out[name] = np.zeros((rh, rw, img.shape[2]), np.float32)
            out[name][ty - ry:ty - ry + th, tx - rx:tx - rx + tw] = img
    return out


def manifests(tables: DataTables) -> dict[str, list[str]]:
    """{"CryptoObject": names, ...} of the requested Cryptomatte kinds."""
    return {CRYPTO_NAMES[kind]: list(names) for kind, names in tables.names.items()}
