"""Blender camera -> core Camera (perspective, orthographic and panoramic, Blender's sensor fit, shift and
clipping, depth of field), and a warning naming each camera setting Monte does not render yet.

core.Camera.frame() reproduces BKE_camera_params_compute_viewplane, so the fields are copied as they are;
tests compare the frame with `camera.data.view_frame(scene=scene)`.
"""

from __future__ import annotations

import numpy as np

from ...core.scene import PANORAMA_TYPES, Camera, SceneError


def render_resolution(scene) -> tuple[int, int]:
    """The rendered size in pixels: resolution x percentage, as Blender rounds it (integer division)."""
    r = scene.render
    pct = int(r.resolution_percentage)
    return max(1, (int(r.resolution_x) * pct) // 100), max(1, (int(r.resolution_y) * pct) // 100)


def render_region(scene) -> tuple[int, int, int, int] | None:
    """The render border as core's region (x0, y0 from the TOP, width, height), None for the full frame.

    Blender truncates the border's fractions times the resolution (checked against its render result)."""
    r = scene.render
    if not r.use_border:
        return None
    w, h = render_resolution(scene)
    xmin, xmax = int(r.border_min_x * w), int(r.border_max_x * w)
    ymin, ymax = int(r.border_min_y * h), int(r.border_max_y * h)  # from the bottom
    xmin, xmax = max(0, min(xmin, w)), max(0, min(xmax, w))
    ymin, ymax = max(0, min(ymin, h)), max(0, min(ymax, h))
    if xmax - xmin < 1 or ymax - ymin < 1:
        # Blender renders the whole frame when the border is empty.
        return None
    if (xmin, ymin, xmax, ymax) == (0, 0, w, h):
        return None
    return xmin, h - ymax, xmax - xmin, ymax - ymin


def _normalized(matrix) -> np.ndarray:
    """Camera-to-world 4x4 with the scale removed (Blender renders cameras without their object scale)."""
    m = np.array(matrix, dtype=np.float64).reshape(4, 4)
    for axis in range(3):
        n = np.linalg.norm(m[:3, axis])
        if n > 0:
            m[:3, axis] /= n
    return m


def focus_distance(camera_object, dof) -> float:
    """The distance in focus (m): the Focus Object's distance along the camera's view axis (its bone's head
    when a Focus Bone is set on an armature) or, without one, Focus Distance; as Cycles' Blender sync reads it."""
    target = dof.focus_object
    if target is None:
        return float(dof.focus_distance)
    where = np.array(target.matrix_world, dtype=np.float64).reshape(4, 4)
    bone_name = getattr(dof, "focus_subtarget", "")
    if target.pose is not None and bone_name:
        bone = target.pose.bones.get(bone_name)
        if bone is not None:
            where = where @ np.array(bone.matrix, dtype=np.float64).reshape(4, 4)
    m = _normalized(camera_object.matrix_world)
    return float(abs(np.dot(m[:3, 2], m[:3, 3] - where[:3, 3])))


def export_camera(camera_object, scene, warnings: list[str]) -> Camera:
    """Build core's Camera from an evaluated camera object and the scene's render settings."""
    if camera_object is None:
        raise SceneError("scene has no camera: add a camera and make it the scene's active camera")
    if camera_object.type != "CAMERA":
        raise SceneError(f"the scene camera {camera_object.name!r} is a {camera_object.type.lower()}, not a camera")
    cam = camera_object.data
    name = camera_object.name
    kind = cam.type
    panorama = {}
    if kind == "PANO":
        panorama = _panorama(cam, name, warnings)
        if not panorama:
            kind = "PERSP"
    elif kind not in ("PERSP", "ORTHO"):
        raise SceneError(f"camera {name!r}: camera type {kind} is not supported by Monte")
    r = scene.render
    if abs(r.pixel_aspect_x - r.pixel_aspect_y) > 1e-6:
        warnings.append(f"render: non-square pixel aspect {r.pixel_aspect_x:g}:{r.pixel_aspect_y:g} is not "
                        "supported; rendering square pixels")
    dof = cam.dof
    focus = focus_distance(camera_object, dof) if dof.use_dof else float(dof.focus_distance)
    if dof.use_dof and dof.aperture_fstop == 0:
        # Cycles clamps the f-stop to 1e-5: an aperture kilometres wide that blurs everything into one colour.
        warnings.append(f"camera {name!r}: depth of field F-Stop 0 is rendered as a pinhole (in focus); Cycles "
                        "renders an unbounded aperture, blurring the whole image")
    elif dof.use_dof and focus == 0:
        # Cycles aims every lens ray at the lens centre, sideways: its image shows only what is beside the lens.
        what = "the Focus Object's distance" if dof.focus_object is not None else "Focus Distance"
        warnings.append(f"camera {name!r}: depth of field with {what} 0 is rendered as a pinhole (in focus); "
                        "Cycles sends its rays sideways and renders only the world")
    return Camera(
        matrix_world=_normalized(camera_object.matrix_world),
        resolution=render_resolution(scene),
        kind=kind,
        lens=float(cam.lens),
        sensor_width=float(cam.sensor_width),
        sensor_height=float(cam.sensor_height),
        sensor_fit=cam.sensor_fit,
        ortho_scale=float(cam.ortho_scale),
        shift_x=float(cam.shift_x),
        shift_y=float(cam.shift_y),
        clip_start=float(cam.clip_start),
        clip_end=float(cam.clip_end),
        use_dof=bool(dof.use_dof),
        aperture_fstop=float(dof.aperture_fstop),
        focus_distance=focus,
        aperture_blades=int(dof.aperture_blades),
        aperture_rotation=float(dof.aperture_rotation),
        aperture_ratio=float(dof.aperture_ratio),
        **panorama,
    )


def _panorama(cam, name: str, warnings: list[str]) -> dict:
    """core Camera fields of a panoramic camera, or {} (with a warning naming the type) for a panorama type
    Monte does not render, which then renders as a perspective camera with the camera's lens."""
    kind = str(getattr(cam, "panorama_type", ""))
    if kind not in PANORAMA_TYPES:
        pretty = kind.replace("_", " ").title() or "unknown"
        warnings.append(f"camera {name!r}: panoramic camera type {pretty} is not supported; rendering it as a "
                        f"perspective camera with its {cam.lens:g} mm lens")
        return {}
    fields = {"panorama_type": kind, "fisheye_fov": float(cam.fisheye_fov), "fisheye_lens": float(cam.fisheye_lens),
              "latitude_min": float(cam.latitude_min), "latitude_max": float(cam.latitude_max),
              "longitude_min": float(cam.longitude_min), "longitude_max": float(cam.longitude_max),
              "fisheye_polynomial": tuple(float(getattr(cam, f"fisheye_polynomial_k{i}")) for i in range(5))}
    if kind == "CENTRAL_CYLINDRICAL":
        fields.update(longitude_min=float(cam.central_cylindrical_range_u_min),
                      longitude_max=float(cam.central_cylindrical_range_u_max),
                      cylinder_height_min=float(cam.central_cylindrical_range_v_min),
                      cylinder_height_max=float(cam.central_cylindrical_range_v_max),
                      cylinder_radius=float(cam.central_cylindrical_radius))
    return fields
