"""Motion blur: positions over the shutter, as Cycles samples them.

Every camera ray gets a time u in [0, 1) (a sampler dimension of its own, read only when the scene moves), 0 at
shutter open and 1 at close; the ray's bounces and shadow rays keep it. What moves is given at S >= 2 steps
evenly spaced over the shutter (step s at u = s / (S - 1)):

- meshes: `core.scene.Mesh.motion_vertices` (and `motion_normals`), linear between steps (Embree's motion-blur
  triangles interpolate the same way; the hit point is rebuilt here at the ray's time);
- the camera: `core.scene.Camera.motion_matrices`, its rotation interpolated by quaternion slerp and its position
  linearly between steps (Cycles' decomposed camera motion).

Steps of different counts (Cycles' 2^(n-1) + 1 per object) are resampled onto one common grid, exactly where the
grids nest.
"""

from __future__ import annotations

import numpy as np

from .scene import MAX_MOTION_STEPS  # noqa: F401  (re-exported: the steps' limit, Embree's)


def resample_steps(values: np.ndarray, steps: int) -> np.ndarray:
    """(S, ...) values at times s / (S - 1) -> (steps, ...) at j / (steps - 1), linear in between (float64)."""
    values = np.asarray(values, np.float64)
    count = values.shape[0]
    if count == steps:
        return values
    where = np.linspace(0.0, 1.0, steps) * (count - 1)
    lo = np.minimum(np.floor(where).astype(np.int64), count - 2)
    frac = (where - lo).reshape((steps,) + (1,) * (values.ndim - 1))
    return values[lo] * (1.0 - frac) + values[lo + 1] * frac


def _bracket(time: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """For ray times in [0, 1]: the step before each (0 .. steps - 2) and the fraction of the way to the next."""
    where = np.clip(np.asarray(time, np.float64), 0.0, 1.0) * (steps - 1)
    lo = np.minimum(np.floor(where).astype(np.int64), steps - 2)
    return lo, where - lo


def interpolate_corners(step_values: np.ndarray, which: np.ndarray, time: np.ndarray) -> np.ndarray:
    """step_values (S, M, 3, 3) float32 (triangle corners or corner normals at each step); which (K,) rows of M;
    time (K,) ray times -> (K, 3, 3) float32 at those times, linear between steps as Embree interpolates."""
    lo, frac = _bracket(time, step_values.shape[0])
    f = frac.astype(np.float32)[:, None, None]
    a = step_values[lo, which]
    b = step_values[lo + 1, which]
    return (a + (b - a) * f).astype(np.float32)


def _quaternions(rotations: np.ndarray) -> np.ndarray:
    """(S, 3, 3) rotation matrices -> (S, 4) unit quaternions (w, x, y, z)."""
    out = np.empty((len(rotations), 4))
    for i, m in enumerate(rotations):  # a handful of steps: no need to vectorise
        trace = m[0, 0] + m[1, 1] + m[2, 2]
        if trace > 0:
            s = 2.0 * np.sqrt(trace + 1.0)
            q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
        elif m[1, 1] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
        out[i] = q
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    # Consecutive steps on the same hemisphere: slerp takes the short way round.
    for i in range(1, len(out)):
        if np.dot(out[i - 1], out[i]) < 0:
            out[i] = -out[i]
    return out


def _rotation_matrices(q: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) -> (N, 3, 3)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def camera_transforms(matrices: np.ndarray, time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera at each ray's time: (N, 3, 3) rotation (the camera's axes normalised, scale dropped as the
    renderer's camera rays drop it) and (N, 3) position, both float64, from its (S, 4, 4) camera-to-world
    matrices at the shutter's steps (rotation slerped, position linear)."""
    m = np.asarray(matrices, np.float64)
    basis = m[:, :3, :3] / np.linalg.norm(m[:, :3, :3], axis=1, keepdims=True)
    q = _quaternions(basis)
    lo, frac = _bracket(time, len(m))
    a, b = q[lo], q[lo + 1]
    cos = np.clip(np.sum(a * b, axis=1), -1.0, 1.0)
    angle = np.arccos(cos)
    sin = np.sin(angle)
    near = sin < 1e-6  # nearly the same rotation: linear, then normalised
    safe = np.where(near, 1.0, sin)
    wa = np.where(near, 1.0 - frac, np.sin((1.0 - frac) * angle) / safe)
    wb = np.where(near, frac, np.sin(frac * angle) / safe)
    q_t = a * wa[:, None] + b * wb[:, None]
    q_t /= np.linalg.norm(q_t, axis=1, keepdims=True)
    position = m[lo, :3, 3] * (1.0 - frac)[:, None] + m[lo + 1, :3, 3] * frac[:, None]
    return _rotation_matrices(q_t), position


def moving_camera_rays(camera, raster_x: np.ndarray, raster_y: np.ndarray, lens_u: np.ndarray | None,
                       ray_time: np.ndarray):
    """core.camera.camera_rays for a camera with motion_matrices: each ray leaves the camera where it is at the
    ray's time. Origins stay relative to camera.position (the frame's), as camera_rays' are."""
    from dataclasses import replace

    from .camera import camera_rays

    rays = camera_rays(replace(camera, matrix_world=np.eye(4), motion_matrices=None), raster_x, raster_y, lens_u)
    rotation, position = camera_transforms(camera.motion_matrices, ray_time)
    offset = position - np.asarray(camera.position, np.float64)
    origins = np.einsum("nij,nj->ni", rotation, rays.origins.astype(np.float64)) + offset
    directions = np.einsum("nij,nj->ni", rotation, rays.directions.astype(np.float64))
    rays.origins = origins.astype(np.float32)
    rays.directions = directions.astype(np.float32)
    return rays
