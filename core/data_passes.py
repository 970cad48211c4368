"""Cycles' data passes: Mist, Position, UV, Object Index, Material Index and Cryptomatte Object / Material / Asset.

All of them read the surface a camera ray hits first (a miss writes nothing), with Cycles' (Blender 5.3) meaning:

- Position (world space), Object Index (the object's Pass Index) and Material Index (the
  material's Pass Index) are taken from the pixel's first sample only and not averaged (Cycles
  overwrites them at sample 0): no blend of two indices at an edge, 0 where that sample saw nothing.
- UV is the mean over the pixel's samples of (u, v, 1) of the active UV map at the hit ((0, 0, 0) on a miss or
  on geometry without UVs), Blender's channels U, V, A.
- Mist is 1 - mean over samples of (1 - m), m = clamp((distance - start) / depth, 0, 1) ** falloff exponent
  (Quadratic 2, Linear 1, Inverse Quadratic 0.5); distance from the camera position (along the view axis for
  an orthographic camera), as Cycles' camera_distance; a miss adds 0, so the world reads 1.
- Cryptomatte (the OpenEXR Cryptomatte standard): each name (object, material, or asset = the top-most parent
  of the object) is hashed with MurmurHash3_x86_32 (seed 0) and the hash made a float32 (exponent kept in
  [1, 254]); a pixel's coverage of a name is the fraction of its samples whose first hit carries the name;
  the `levels` largest (id, coverage) pairs, in decreasing coverage, fill layers of 4 channels
  (id, coverage, id, coverage): CryptoObject00, CryptoObject01, ... The manifest ({name: 8 hex digits of
  the hash}) goes into the file's metadata under cryptomatte/<first 7 hex digits of the hash of the layer
  name>/{name, hash, conversion, manifest}.

Cycles looks through surfaces that are (partly) transparent (a Transparent BSDF) for UV (the first surface at
least half opaque), Mist and Cryptomatte (weighted by each surface's opacity); Monte's passes stop at the
first surface, so a scene where such a material is seen gets a warning naming the passes (see
`transparency_warning`).

Nothing here runs unless settings.data_passes names a pass: a render without them is unchanged.
"""

from __future__ import annotations

import json
import math
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
        return cls(tuple(passes), int(levels), object_table[rows], material_pass, name_of_triangle, names, ids,
                   getattr(scene, "mist", None) or Mist(), matrix[:3, 3].copy(), forward)

    def samples(self, prepared, prim: np.ndarray, bu: np.ndarray, bv: np.ndarray, t: np.ndarray,
                origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
        """Per camera sample, what it adds to each pass (see the module docstring): prim (-1 on a miss), the
        hit's barycentrics and distance along the ray, the rays in the prepared (camera-shifted) frame."""
        n = len(prim)
        hit = prim >= 0
        p = np.flatnonzero(hit)
        tri = prim[p]
        out: dict[str, np.ndarray] = {"hit": hit}
        position = np.zeros((n, 3), np.float64)
        position[p] = (origins[p].astype(np.float64) + directions[p].astype(np.float64) * t[p, None].astype(np.float64)
                       + np.asarray(prepared.shift, np.float64))
        if "position" in self.passes:
            out["position"] = position.astype(np.float32)
        if "mist" in self.passes:
            rel = position[p] - self.camera_position
            dist = rel @ self.camera_forward if self.camera_forward is not None else np.linalg.norm(rel, axis=1)
            inv_depth = 1.0 / self.mist.depth if self.mist.depth > 0 else 0.0
            m = np.clip((dist - self.mist.start) * inv_depth, 0.0, 1.0) ** MIST_FALLOFF[self.mist.falloff]
            mist = np.zeros(n, np.float64)
            mist[p] = 1.0 - m
            out["mist"] = mist
        if "uv" in self.passes:
            uv = np.zeros((n, 3), np.float64)
            if prepared.uvs is not None:
                corners = prepared.uvs[tri].astype(np.float64)  # (m, 3, 2)
                b1, b2 = bu[p].astype(np.float64), bv[p].astype(np.float64)
                uv[p, :2] = corners[:, 0] * (1 - b1 - b2)[:, None] + corners[:, 1] * b1[:, None] \
                    + corners[:, 2] * b2[:, None]
                uv[p, 2] = 1.0
            out["uv"] = uv
        if "object_index" in self.passes:
            v = np.zeros(n, np.float32)
            v[p] = self.object_pass[tri]
            out["object_index"] = v
        if "material_index" in self.passes:
            v = np.zeros(n, np.float32)
            v[p] = self.material_pass[prepared.material_index[tri]]
            out["material_index"] = v
        for kind, table in self.name_of_triangle.items():
            v = np.full(n, -1, np.int32)
            v[p] = table[tri]
            out[kind] = v
        return out


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


def transparency_warning(prepared, passes: tuple[str, ...]) -> str | None:
    """The warning for a scene with a Transparent BSDF when passes Cycles defines through transparency are on."""
    affected = [PASS_NAMES.get(k, CRYPTO_NAMES.get(k)) for k in passes if k in ("mist", "uv") or k in CRYPTO_NAMES]
    if not affected or not prepared.has_clear:
        return None
    return (f"data passes {', '.join(affected)}: a material has a Transparent BSDF; Monte's data passes read the "
            "first surface a camera ray hits, where Cycles looks through transparent surfaces, so these passes "
            "differ from Cycles' behind them")


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
        # Cryptomatte: sparse sums of coverage, keyed pixel * K + name index, kept sorted
        self.crypto = {kind: (np.zeros(0, np.int64), np.zeros(0, np.float64)) for kind in tables.name_of_triangle}

    def add(self, pixel: np.ndarray, sample: np.ndarray, values: dict[str, np.ndarray]) -> None:
        """Accumulate samples (tile-local pixel indices, their sample indices, DataTables.samples' values)."""
        n = self.width * self.height
        pixel = np.asarray(pixel, np.int64)
        self.count += np.bincount(pixel, minlength=n)
        if "mist" in values:
            self.mist += np.bincount(pixel, weights=values["mist"], minlength=n)
        if "uv" in values:
            for c in range(3):
                self.uv[:, c] += np.bincount(pixel, weights=values["uv"][:, c], minlength=n)
        first = np.flatnonzero(np.asarray(sample) == 0)  # the overwritten passes: the pixel's sample 0
        for name in ("position", "object_index", "material_index"):
            if name in values and len(first):
                getattr(self, name)[pixel[first]] = values[name][first]
        for kind, (keys, sums) in self.crypto.items():
            idx = values[kind]
            hit = idx >= 0
            k = len(self.tables.names[kind])
            new_keys = pixel[hit] * k + idx[hit]
            all_keys, inverse = np.unique(np.concatenate([keys, new_keys]), return_inverse=True)
            all_sums = np.bincount(inverse, weights=np.concatenate([sums, np.ones(len(new_keys))]),
                                   minlength=len(all_keys))
            self.crypto[kind] = (all_keys, all_sums)

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
