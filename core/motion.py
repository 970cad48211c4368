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


def quaternions(rotations: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions (w, x, y, z), each with w >= 0 where possible."""
    m = np.asarray(rotations, np.float64)
    out = np.empty((len(m), 4))
    for i, r in enumerate(m):  # a handful of steps per object: no need to vectorise
        trace = r[0, 0] + r[1, 1] + r[2, 2]
        if trace > 0:
            s = 2.0 * np.sqrt(trace + 1.0)
            q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
        elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
            s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
            q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
        elif r[1, 1] > r[2, 2]:
            s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
            q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
        else:
            s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
            q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
        out[i] = q
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def same_hemisphere(q: np.ndarray) -> np.ndarray:
    """(S, ..., 4) quaternions of consecutive steps, each flipped onto its predecessor's side (slerp between
    neighbours then takes the short way round)."""
    q = np.array(q, np.float64)
    for i in range(1, len(q)):
        flip = np.sum(q[i - 1] * q[i], axis=-1) < 0
        q[i][flip] = -q[i][flip]
    return q


def slerp(a: np.ndarray, b: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions a, b and (N,) fractions -> (N, 4) spherical interpolation (linear, normalised,
    where a and b nearly agree)."""
    cos = np.clip(np.sum(a * b, axis=1), -1.0, 1.0)
    angle = np.arccos(cos)
    sin = np.sin(angle)
    near = sin < 1e-6
    safe = np.where(near, 1.0, sin)
    wa = np.where(near, 1.0 - frac, np.sin((1.0 - frac) * angle) / safe)
    wb = np.where(near, frac, np.sin(frac * angle) / safe)
    q = a * wa[:, None] + b * wb[:, None]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def rotation_matrices(q: np.ndarray) -> np.ndarray:
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
    q = same_hemisphere(quaternions(basis))
    lo, frac = _bracket(time, len(m))
    position = m[lo, :3, 3] * (1.0 - frac)[:, None] + m[lo + 1, :3, 3] * frac[:, None]
    return rotation_matrices(slerp(q[lo], q[lo + 1], frac)), position


# Baked steps of a rotating object lie at most this angle (radians) apart: a point moving linearly between two of
# them strays from its arc by at most 1 - cos(angle / 2) of its radius, 1.1e-4 here.
MAX_STEP_ANGLE = 0.03


def densify_transforms(matrices: np.ndarray, max_steps: int = MAX_MOTION_STEPS) -> np.ndarray:
    """(S, K, 4, 4) object-to-world matrices of K instances at S steps over the shutter -> (D, K, 4, 4) at
    D = (S - 1) k + 1 steps, k the fewest subdivisions of each step that keep the rotation between baked steps
    within MAX_STEP_ANGLE (D <= max_steps). Each matrix is split into translation, rotation and stretch (polar
    decomposition); in between, translation and stretch are linear and rotation slerped, as Cycles interpolates
    decomposed motion transforms. Vertices baked at the dense steps then follow the arcs of rotating objects."""
    m = np.asarray(matrices, np.float64)
    steps, k = m.shape[:2]
    lin = m[..., :3, :3]
    u, _, vt = np.linalg.svd(lin)
    rot = u @ vt
    flip = np.linalg.det(rot) < 0  # mirrored: the rotation keeps det +1, the stretch takes the sign
    u[flip, :, 2] *= -1
    rot = u @ vt
    stretch = np.swapaxes(rot, -1, -2) @ lin
    q = same_hemisphere(quaternions(rot.reshape(-1, 3, 3)).reshape(steps, k, 4))
    angle = 2.0 * np.arccos(np.clip(np.abs(np.sum(q[1:] * q[:-1], axis=-1)), 0.0, 1.0))
    sub = max(1, int(np.ceil(angle.max() / MAX_STEP_ANGLE)))
    sub = min(sub, max(1, (max_steps - 1) // (steps - 1)))
    if sub == 1:
        return m
    dense = (steps - 1) * sub + 1
    where = np.arange(dense) / sub
    lo = np.minimum(np.floor(where).astype(np.int64), steps - 2)
    frac = where - lo
    out = np.zeros((dense, k, 4, 4))
    out[..., 3, 3] = 1.0
    for j in range(dense):
        f = frac[j]
        r = rotation_matrices(slerp(q[lo[j]], q[lo[j] + 1], np.full(k, f)))
        s = stretch[lo[j]] * (1.0 - f) + stretch[lo[j] + 1] * f
        out[j, :, :3, :3] = r @ s
        out[j, :, :3, 3] = m[lo[j], :, :3, 3] * (1.0 - f) + m[lo[j] + 1, :, :3, 3] * f
    return out


def shutter_times(u: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Uniform numbers u in [0, 1) -> ray times in [0, 1] distributed as the shutter curve says ((K,) openness
    at K evenly spaced times, linear in between): the inverse of the curve's cumulative integral (within a
    segment the integral is quadratic, solved exactly), as Cycles' shutter table maps them. float32."""
    curve = np.asarray(curve, np.float64)
    width = 1.0 / (len(curve) - 1)
    areas = (curve[1:] + curve[:-1]) * 0.5 * width
    cdf = np.concatenate([[0.0], np.cumsum(areas)])
    target = np.asarray(u, np.float64) * cdf[-1]
    seg = np.clip(np.searchsorted(cdf, target, side="right") - 1, 0, len(curve) - 2)
    a = curve[seg]
    slope = (curve[seg + 1] - a) / width
    area = target - cdf[seg]
    # a s + slope s^2 / 2 = area, the stable root
    denom = a + np.sqrt(np.maximum(a * a + 2.0 * slope * area, 0.0))
    s = np.where(denom > 0, 2.0 * area / np.where(denom > 0, denom, 1.0), 0.0)
    return np.clip((seg + np.clip(s / width, 0.0, 1.0)) * width, 0.0, 1.0).astype(np.float32)


def rolling_shutter_times(time: np.ndarray, row: np.ndarray, height: int, duration: float) -> np.ndarray:
    """Cycles' rolling shutter (Top): rows (0 at the top of the image) are exposed in turn, each over `duration`
    of the shutter; ray times (N,) in [0, 1] -> (time - 1/2) d + (r - 1/2)(1 - d) + 1/2, r = (row + 1) / height.
    float32."""
    r = (np.asarray(row, np.float64) + 1.0) / float(height)
    t = (np.asarray(time, np.float64) - 0.5) * duration + (r - 0.5) * (1.0 - duration) + 0.5
    return np.clip(t, 0.0, 1.0).astype(np.float32)


def moving_camera_rays(camera, raster_x: np.ndarray, raster_y: np.ndarray, lens_u: np.ndarray | None,
                       ray_time: np.ndarray):
    """core.camera.camera_rays for a camera with motion_matrices and/or motion_lens: each ray leaves the camera
    where it is at the ray's time, and a zooming perspective camera's image-plane point moves from the shutter-
    open lens to the frame's to the shutter-close lens (Cycles' perspective motion, without depth of field).
    Origins stay relative to camera.position (the frame's), as camera_rays' are."""
    from dataclasses import replace

    from .camera import camera_rays

    local = replace(camera, matrix_world=np.eye(4), motion_matrices=None)
    rays = camera_rays(local, raster_x, raster_y, lens_u)
    if camera.motion_lens is not None and camera.kind == "PERSP" and camera.aperture_radius() == 0:
        _zoom(rays, [camera_rays(replace(local, lens=lens), raster_x, raster_y, lens_u)
                     for lens in camera.motion_lens], ray_time, float(camera.clip_start), float(camera.clip_end))
    steps = camera.motion_matrices
    if steps is None:  # zoom only: the frame's matrix throughout
        steps = np.stack([np.asarray(camera.matrix_world, np.float64)] * 2)
    rotation, position = camera_transforms(steps, ray_time)
    offset = position - np.asarray(camera.position, np.float64)
    origins = np.einsum("nij,nj->ni", rotation, rays.origins.astype(np.float64)) + offset
    directions = np.einsum("nij,nj->ni", rotation, rays.directions.astype(np.float64))
    rays.origins = origins.astype(np.float32)
    rays.directions = directions.astype(np.float32)
    return rays


def _zoom(rays, ends, ray_time: np.ndarray, clip_start: float, clip_end: float) -> None:
    """Perspective motion in place on camera-local pinhole rays: each ray's point on the plane z = -1 moves
    linearly from the shutter-open rays' (ends[0]) to its own (the frame's lens) at time 1/2 to the close
    rays' (ends[1]); direction, clipping and depth scale follow it (as core.camera's kernel sets them)."""
    def on_plane(r):
        d = r.directions.astype(np.float64)
        return d / -d[:, 2:3]

    centre = on_plane(rays)
    t = np.asarray(ray_time, np.float64)[:, None]
    early = t < 0.5
    point = np.where(early, on_plane(ends[0]) + (centre - on_plane(ends[0])) * (2 * t),
                     centre + (on_plane(ends[1]) - centre) * (2 * t - 1))
    length = np.linalg.norm(point, axis=1)
    direction = point / length[:, None]
    scale = 1.0 / length
    t0 = clip_start / scale
    rays.directions = direction.astype(np.float32)
    rays.origins = (direction * t0[:, None]).astype(np.float32)
    rays.depth_scale = scale.astype(np.float32)
    rays.t_start = t0.astype(np.float32)
    rays.tmax = np.minimum(clip_end / scale - t0, 3e38).astype(np.float32)
