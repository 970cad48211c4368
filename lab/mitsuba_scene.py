"""A core Scene rendered by Mitsuba 3 through its Python API: the same triangles, camera, pixel filter and samples.

Only what the bench scenes' rival comparison needs is translated, and anything else is refused with the object
named (never a silently different image):
- meshes: every triangle, unrolled to three vertices each so that Monte's per-corner shading normals travel as
  Mitsuba vertex normals (flat meshes keep face normals); one PLY file per (mesh, material) pair;
- materials: one lobe of kind diffuse (Mitsuba `diffuse`), glossy at roughness 0 without Fresnel (`conductor`
  with material "none", Blender's Glossy BSDF at roughness 0), glass at roughness 0 (`dielectric`, exterior
  IOR 1), or no lobe at all (black); Blender's BSDFs shade both faces, so diffuse and conductor are wrapped in
  `twosided`; emission becomes an `area` emitter. Mitsuba's area emitter is one-sided where Blender's emission
  shader lights both faces, so an emitter gets a flipped duplicate moved 1e-4 of the scene's size along its
  own normal (coincident triangles would leave which face a ray meets to the traversal's tie-breaking);
- camera: a perspective camera without shift, depth of field or motion, its field of view from Blender's
  sensor fit; Mitsuba's camera looks along its local +z with +x to the left, Blender's along -z with +x right;
- the world must be black (the Cornell box is lit by its lamp only);
- integrator `path` with max_depth = max_bounces + 2 (Mitsuba counts the camera segment and the segment to the
  light, Cycles' max_bounces 0 is direct light only, Mitsuba's max_depth 2), hidden emitters off.

No bpy here; mitsuba is imported by the caller (an optional development dependency: requirements/rivals.txt).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..core.scene import Scene

MITSUBA_FILTERS = {"box": {"type": "box"}}  # Monte/Cycles box of width 1 px = Mitsuba box of radius 0.5 px
EMITTER_DUPLICATE_OFFSET = 1e-4  # of the scene's bounding-box diagonal


class MitsubaSceneError(ValueError):
    """The scene uses something the Mitsuba translation does not carry over (the message names it)."""


def _rgb(value) -> dict:
    return {"type": "rgb", "value": [float(v) for v in np.asarray(value, np.float64).reshape(3)]}


def _bsdf(material) -> dict:
    name = material.name
    if material.program is not None:
        raise MitsubaSceneError(f"material {name!r}: node programs are not translated to Mitsuba")
    if material.holdout:
        raise MitsubaSceneError(f"material {name!r}: holdout is not translated to Mitsuba")
    if len(material.lobes) > 1:
        raise MitsubaSceneError(f"material {name!r}: {len(material.lobes)} lobes; Mitsuba gets one-lobe materials only")
    if not material.lobes:
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(np.zeros(3))}}
    lobe = material.lobes[0]
    if lobe.color_texture >= 0:
        raise MitsubaSceneError(f"material {name!r}: textured lobes are not translated to Mitsuba")
    if lobe.kind == "diffuse":
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(lobe.color)}}
    if lobe.kind == "glossy" and lobe.roughness == 0.0 and lobe.fresnel == "none":
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                             "specular_reflectance": _rgb(lobe.color)}}
    if lobe.kind == "glass" and lobe.roughness == 0.0:
        return {"type": "dielectric", "int_ior": float(lobe.ior), "ext_ior": 1.0,
                "specular_reflectance": _rgb(lobe.color), "specular_transmittance": _rgb(lobe.color)}
    raise MitsubaSceneError(f"material {name!r}: a {lobe.kind!r} lobe (roughness {lobe.roughness}, fresnel "
                            f"{lobe.fresnel!r}) is not translated to Mitsuba")


def write_ply(path: Path, positions: np.ndarray, normals: np.ndarray | None) -> None:
    """A binary little-endian PLY of unrolled triangles: positions (3T, 3), optional normals (3T, 3); face i is
    vertices 3i, 3i+1, 3i+2."""
    n_vert = positions.shape[0]
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    vert = np.empty(n_vert, dtype=fields)
    vert["x"], vert["y"], vert["z"] = positions.T
    if normals is not None:
        vert["nx"], vert["ny"], vert["nz"] = normals.T
    faces = np.empty(n_vert // 3, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = np.arange(n_vert, dtype=np.int32).reshape(-1, 3)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n_vert}"]
    header += [f"property float {f}" for f, _ in fields]
    header += [f"element face {n_vert // 3}", "property list uchar int vertex_indices", "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vert.tobytes())
        f.write(faces.tobytes())


def _sensor(scene: Scene, spp: int, sampler: str, filter_type: str) -> dict:
    cam = scene.camera
    name = "the camera"
    if cam.kind != "PERSP":
        raise MitsubaSceneError(f"{name}: a {cam.kind} camera is not translated to Mitsuba (perspective only)")
    if cam.use_dof or cam.shift_x or cam.shift_y or cam.motion_matrices is not None or cam.rolling_shutter:
        raise MitsubaSceneError(f"{name}: depth of field, lens shift and motion are not translated to Mitsuba")
    if filter_type not in MITSUBA_FILTERS:
        raise MitsubaSceneError(f"pixel filter {filter_type!r}: Mitsuba gets {', '.join(MITSUBA_FILTERS)}")
    w, h = cam.resolution
    fit = cam.sensor_fit if cam.sensor_fit != "AUTO" else ("HORIZONTAL" if w >= h else "VERTICAL")
    if fit == "HORIZONTAL":
        axis, size = "x", cam.sensor_width
    elif cam.sensor_fit == "AUTO":
        axis, size = "y", cam.sensor_width  # Blender's AUTO fits the sensor width to the larger side
    else:
        axis, size = "y", cam.sensor_height
    fov = math.degrees(2.0 * math.atan(0.5 * size / cam.lens))
    # Blender's camera looks along its local -z with +x right; Mitsuba's along +z with +x left.
    to_world = np.asarray(cam.matrix_world, np.float64) @ np.diag([-1.0, 1.0, -1.0, 1.0])
    import mitsuba as mi

    return {"type": "perspective", "fov_axis": axis, "fov": fov,
            "near_clip": float(max(cam.clip_start, 1e-4)), "far_clip": float(min(cam.clip_end, 1e7)),
            "to_world": mi.ScalarTransform4f(to_world.tolist()),
            "film": {"type": "hdrfilm", "width": int(w), "height": int(h), "pixel_format": "rgb",
                     "rfilter": dict(MITSUBA_FILTERS[filter_type]), "sample_border": False},
            "sampler": {"type": sampler, "sample_count": int(spp)}}


def mitsuba_scene_dict(scene: Scene, folder: str | Path, *, spp: int, max_bounces: int,
                       filter_type: str = "box", sampler: str = "independent",
                       two_sided_emitters: bool = True) -> dict:
    """The Mitsuba scene description (for mi.load_dict) of a core Scene; writes its PLY files into folder.
    mitsuba must be imported with a variant set. Raises MitsubaSceneError for anything not translated.
    two_sided_emitters=False leaves out the emitters' flipped duplicates (Mitsuba's own one-sided emitters:
    a different image, the tests' control)."""
    folder = Path(folder)
    if scene.lights or (scene.world is not None and (np.any(np.asarray(scene.world.color) != 0)
                                                     or scene.world.environment is not None or scene.world.lights)):
        raise MitsubaSceneError("the Mitsuba translation takes mesh emitters under a black world only "
                                f"({len(scene.lights)} lights, world {scene.world})")
    all_v = np.concatenate([np.asarray(m.vertices, np.float64) for m in scene.meshes])
    offset = EMITTER_DUPLICATE_OFFSET * float(np.linalg.norm(all_v.max(axis=0) - all_v.min(axis=0)))
    bsdfs = {}
    desc: dict = {"type": "scene",
                  "integrator": {"type": "path", "max_depth": int(max_bounces) + 2, "hide_emitters": False}}
    for mi_index, mesh in enumerate(scene.meshes):
        if mesh.motion_vertices is not None or not mesh.visible_camera or mesh.shadow_catcher:
            raise MitsubaSceneError(f"mesh {mesh.name!r}: motion, ray visibility and shadow catchers are not "
                                    "translated to Mitsuba")
        tris = np.asarray(mesh.triangles, np.int64)
        mats = np.broadcast_to(np.asarray(mesh.material_index), (tris.shape[0],))
        verts = np.asarray(mesh.vertices, np.float64)
        for mat_index in np.unique(mats):
            sel = mats == mat_index
            material = scene.materials[int(mat_index)]
            if material.name not in bsdfs:
                bsdfs[material.name] = _bsdf(material)
            positions = verts[tris[sel]]  # (T, 3, 3)
            normals = None if mesh.normals is None else np.asarray(mesh.normals, np.float64)[sel]
            emission = np.asarray(material.emission, np.float64)
            copies = [(positions, normals, "")]
            if np.any(emission > 0) and two_sided_emitters:
                flipped = positions[:, ::-1]
                face_n = np.cross(flipped[:, 1] - flipped[:, 0], flipped[:, 2] - flipped[:, 0])
                face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-30)
                copies.append((flipped + offset * face_n[:, None, :],
                               None if normals is None else -normals[:, ::-1], "_back"))
            for pos, nrm, suffix in copies:
                key = f"mesh{mi_index}_{int(mat_index)}{suffix}"
                path = folder / f"{key}.ply"
                write_ply(path, pos.reshape(-1, 3), None if nrm is None else nrm.reshape(-1, 3))
                shape = {"type": "ply", "filename": str(path), "bsdf": bsdfs[material.name],
                         "face_normals": nrm is None}
                if np.any(emission > 0):
                    shape["emitter"] = {"type": "area", "radiance": _rgb(emission)}
                desc[key] = shape
    desc["sensor"] = _sensor(scene, spp, sampler, filter_type)
    return desc
