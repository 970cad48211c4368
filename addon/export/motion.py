"""Motion blur: Render Properties > Motion Blur and each object's Object > Motion Blur, sampled as Cycles' sync
samples them (core.motion says how the renderer uses the steps).

The shutter spans `motion_blur_shutter` frames placed by Position (Start on Frame: [frame, frame + shutter];
Center: [frame - shutter / 2, frame + shutter / 2]; End: [frame - shutter, frame]). The scene is evaluated at
evenly spaced subframes over it (frame_set with a subframe, as Cycles does). An object with Motion Blur on takes
Cycles' (2 << (Steps - 1)) + 1 steps (3 for Steps 1): its transforms (every instance's world matrix) and, with
Deformation on and a mesh that deforming modifiers or shape keys change (Blender's is_deform_modified, Cycles'
test), its evaluated vertex positions and normals. The camera object's steps give the camera's motion. A shutter
of 0 or Motion Blur off: no blur, nothing sampled (Cycles' behaviour).

The Shutter Curve (how open the shutter is over its time) is read at CURVE_POINTS times; ray times follow it.
Rolling Shutter (Top, with its duration) times each image row as Cycles does; a perspective camera zooming
during the shutter blurs as Cycles' perspective motion does. Not rendered, warned by name: a zoom together with
depth of field (the frame's focal length). Transform motion is baked into
vertex steps (linear between steps); rotation is decomposed and slerped as Cycles interpolates it, and baked at
enough steps (core.motion.densify_transforms) that the vertices follow their arcs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...core.motion import MAX_MOTION_STEPS


@dataclass
class Shutter:
    """The shutter in frames: it opens `start` frames from the frame (frame + subframe) and stays open `length`."""

    frame: int
    subframe: float
    start: float
    length: float
    curve: np.ndarray | None = None  # the Shutter Curve at CURVE_POINTS times over the shutter; None: flat
    rolling: float | None = None  # Rolling Shutter (Top) duration, None: off

    @property
    def reference(self) -> tuple[int, float]:
        """(frame, subframe) of the shutter's centre, where what does not blur is exported (as Cycles syncs it)."""
        t = self.frame + self.subframe + self.start + 0.5 * self.length
        if self.start == -0.5 * self.length:
            return self.frame, self.subframe
        whole = math.floor(t)
        return int(whole), float(t - whole)

    def step_times(self, steps: int) -> list[tuple[int, float]]:
        """(frame, subframe) of `steps` evenly spaced times from shutter open to close."""
        out = []
        for s in range(steps):
            t = self.frame + self.subframe + self.start + self.length * s / (steps - 1)
            whole = math.floor(t)
            out.append((int(whole), float(t - whole)))
        return out


def shutter(scene, warnings: list[str], view_layer=None) -> Shutter | None:
    """The render's shutter, or None without motion blur (off, off in the view layer as Cycles reads it, or a
    shutter of 0 frames, which Cycles renders sharp); warns for the shutter settings Monte does not render."""
    r = scene.render
    if not r.use_motion_blur or not getattr(view_layer, "use_motion_blur", True):
        return None
    length = float(r.motion_blur_shutter)
    if not length > 0:
        return None
    position = getattr(r, "motion_blur_position", "CENTER")
    start = {"START": 0.0, "CENTER": -0.5 * length, "END": -length}.get(position, -0.5 * length)
    cycles = getattr(scene, "cycles", None)
    rolling = None
    if getattr(cycles, "rolling_shutter_type", "NONE") == "TOP":
        rolling = min(max(float(cycles.rolling_shutter_duration), 0.0), 1.0)
    elif getattr(cycles, "rolling_shutter_type", "NONE") != "NONE":
        warnings.append(f"render: Motion Blur > Rolling Shutter {cycles.rolling_shutter_type!r} is not supported; "
                        "rendered with a global shutter (every row exposed over the same time)")
    mapping = getattr(r, "motion_blur_shutter_curve", None)
    curve = None if _flat_curve(mapping) else _curve_values(mapping, warnings)
    return Shutter(int(scene.frame_current), float(scene.frame_subframe), start, length, curve, rolling)


CURVE_POINTS = 256  # where the Shutter Curve is read (Cycles tabulates it likewise)


def _curve_values(mapping, warnings: list[str]) -> np.ndarray | None:
    """The Shutter Curve read at CURVE_POINTS evenly spaced times, clamped to >= 0; None (flat, warned) when
    unreadable or zero everywhere."""
    try:
        mapping.initialize()
        values = np.array([mapping.evaluate(mapping.curves[0], x) for x in np.linspace(0.0, 1.0, CURVE_POINTS)])
    except (AttributeError, RuntimeError, TypeError, IndexError):
        values = None
    if values is not None:
        values = np.clip(np.nan_to_num(values, nan=0.0), 0.0, None)
    if values is None or not values.sum() > 0:
        warnings.append("render: Motion Blur > Shutter Curve is unreadable or zero everywhere; rendered with the "
                        "shutter fully open (a flat curve)")
        return None
    return values


def _flat_curve(mapping) -> bool:
    """Whether a shutter CurveMapping is the constant 1 (Blender's default), read at its control points."""
    if mapping is None:
        return True
    try:
        points = [p.location[1] for curve in mapping.curves for p in curve.points]
    except (AttributeError, TypeError):
        return True
    return all(abs(y - 1.0) < 1e-6 for y in points)


def object_steps(obj, parent=None) -> int:
    """Cycles' motion steps of an (original) object: 0 with its Motion Blur off (or its instancer's), else
    (2 << (Steps - 1)) + 1, the larger of the object's and its instancer's."""
    settings = getattr(obj, "cycles", None)
    if settings is None:
        return 3
    if not settings.use_motion_blur:
        return 0
    steps = max(1, int(settings.motion_steps))
    parent_settings = getattr(parent, "cycles", None) if parent is not None else None
    if parent_settings is not None:
        if not parent_settings.use_motion_blur:
            return 0
        steps = max(steps, int(parent_settings.motion_steps))
    return min((2 << (steps - 1)) + 1, MAX_MOTION_STEPS)


def deforms(obj, scene) -> bool:
    """Whether an (original) mesh object asks for deformation blur (Object > Motion Blur > Deformation) and
    deforming modifiers or shape keys may change its vertices (Blender's is_deform_modified, the test Cycles
    makes): only those meshes are read again at each step."""
    settings = getattr(obj, "cycles", None)
    if settings is not None and not settings.use_deform_motion:
        return False
    if obj.type != "MESH":
        return False
    try:
        return bool(obj.is_deform_modified(scene, "RENDER"))
    except (AttributeError, TypeError, RuntimeError):
        return bool(obj.modifiers) or getattr(obj.data, "shape_keys", None) is not None


def instance_key(inst) -> tuple:
    """A key naming one depsgraph instance across subframes (the object and, for an instance, its instancer and
    persistent id)."""
    obj = inst.object.original
    if inst.is_instance:
        parent = inst.parent.original.name if inst.parent is not None else ""
        return (obj.name, parent, tuple(inst.persistent_id))
    return (obj.name, "", ())


@dataclass
class MotionSamples:
    """What the subframes saw: per instance key its world matrices (S, 4, 4) at the common steps, per deforming
    object name the (vertices (V, 3), normals (T, 3, 3) or None) of its evaluated mesh at each step (None where
    unreadable), and the camera's matrices (S, 4, 4) or None."""

    steps: int
    matrices: dict
    deformed: dict
    camera: np.ndarray | None
    camera_lenses: tuple = ()  # the camera's focal length (mm) at shutter open and close


def sample_motion(depsgraph, frame_set: Callable[[int, float], None], shutter_: Shutter, keys: set,
                  deforming: set, camera_name: str | None, steps: int, read: Callable) -> MotionSamples:
    """Evaluate the scene at `steps` subframes over the shutter; keep the matrices of instances `keys`, the
    meshes of objects `deforming` (read(obj) -> (vertices, normals) or None) and the camera's matrix; the scene is
    set back to the shutter's reference time afterwards."""
    matrices = {key: np.zeros((steps, 4, 4)) for key in keys}
    seen = {key: np.zeros(steps, bool) for key in keys}
    deformed = {name: [None] * steps for name in deforming}
    camera = np.zeros((steps, 4, 4)) if camera_name is not None else None
    lenses = [0.0] * steps
    try:
        for s, (frame, subframe) in enumerate(shutter_.step_times(steps)):
            frame_set(frame, subframe)
            for inst in depsgraph.object_instances:
                obj = inst.object
                if camera is not None and not inst.is_instance and obj.original.name == camera_name:
                    camera[s] = np.array(obj.matrix_world, np.float64).reshape(4, 4)
                    lenses[s] = float(getattr(obj.data, "lens", 0.0))
                if not inst.show_self:
                    continue
                key = instance_key(inst)
                if key in seen:
                    matrices[key][s] = np.array(inst.matrix_world, np.float64).reshape(4, 4)
                    seen[key][s] = True
                    if not inst.is_instance and obj.original.name in deformed:
                        deformed[obj.original.name][s] = read(obj)
    finally:
        frame_set(*shutter_.reference)
    # An instance missing at some step (it appears or vanishes during the shutter): no motion for it.
    matrices = {key: m for key, m in matrices.items() if seen[key].all()}
    return MotionSamples(steps, matrices, deformed, camera, (lenses[0], lenses[-1]) if camera is not None else ())


def take_steps(values: np.ndarray, steps: int) -> np.ndarray:
    """Every k-th of (S, ...) values sampled on the common grid, for an object of fewer steps (grids nest:
    (2 << n) + 1 points)."""
    total = values.shape[0]
    if steps >= total:
        return values
    stride = (total - 1) // (steps - 1)
    return values[::stride][:steps]


def placed_motion(local_steps: list, normals_steps: list | None, matrices: np.ndarray,
                  mirrored: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The world positions (S, K * V, 3) and corner normals (S, K * T, 3, 3) or None of a mesh placed at K
    instances, per step: local_steps (S, V, 3) object-space vertices, normals_steps (S, T, 3, 3) or None,
    matrices (S, K, 4, 4); mirrored (K,) instances whose winding the export flipped (their corner order)."""
    steps = matrices.shape[0]
    k = matrices.shape[1]
    positions = []
    normals = [] if normals_steps is not None else None
    for s in range(steps):
        lin = matrices[s, :, :3, :3]
        v = np.asarray(local_steps[s], np.float64)
        positions.append((np.matmul(v[None], lin.transpose(0, 2, 1)) + matrices[s, :, None, :3, 3]).reshape(-1, 3))
        if normals is not None:
            det = np.linalg.det(lin)
            inv = np.linalg.inv(np.where(np.abs(det)[:, None, None] > 1e-300, lin, np.eye(3)))
            n = np.matmul(np.asarray(normals_steps[s], np.float32).reshape(1, -1, 3), inv.astype(np.float32))
            n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
            n = n.reshape(k, -1, 3, 3)
            if mirrored.any():
                n[mirrored] = n[mirrored][:, :, [0, 2, 1]]
            normals.append(n.reshape(-1, 3, 3))
    return np.stack(positions), None if normals is None else np.stack(normals).astype(np.float32)
