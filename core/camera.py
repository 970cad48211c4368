"""Camera rays in Blender's conventions (see `scene.Camera`), in the integrator's shifted frame.

The integrator renders relative to the camera: positions are (world - camera position), so perspective rays
start at the origin, where float32 is most precise, wherever the scene sits in the world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .jit_cache import jit
from .scene import Camera


@dataclass
class CameraRays:
    """origins (N,3) float32 relative to the camera position; directions (N,3) float32 unit; tmax (N,) from
    clip_end; z-depth of a hit at distance t along the ray = (t_start + t) x depth_scale."""

    origins: np.ndarray
    directions: np.ndarray
    tmax: np.ndarray
    depth_scale: np.ndarray
    t_start: np.ndarray



@jit
def _camera_rays(raster_x, raster_y, width, height, frame, right, up, back, ortho, clip_start, clip_end,
                 origins, directions, tmax, depth_scale, t_start):
    """Camera rays through raster positions (see camera_rays), in float64, written as float32.

    frame: (xmin, xmax, ymin, ymax) of the image on the plane at distance 1 (perspective) or in world units
    (orthographic); right, up, back: the camera's unit axes; rays start at clip_start and end at clip_end."""
    xmin, xmax, ymin, ymax = frame[0], frame[1], frame[2], frame[3]
    for k in range(raster_x.shape[0]):
        x = xmin + (raster_x[k] / width) * (xmax - xmin)
        y = ymax - (raster_y[k] / height) * (ymax - ymin)
        if ortho:
            dx, dy, dz = -back[0], -back[1], -back[2]
            ox = x * right[0] + y * up[0] + clip_start * dx
            oy = x * right[1] + y * up[1] + clip_start * dy
            oz = x * right[2] + y * up[2] + clip_start * dz
            tm, scale, t0 = clip_end - clip_start, 1.0, clip_start
        else:
            lx = x * right[0] + y * up[0] - back[0]
            ly = x * right[1] + y * up[1] - back[1]
            lz = x * right[2] + y * up[2] - back[2]
            length = math.sqrt(lx * lx + ly * ly + lz * lz)
            dx, dy, dz = lx / length, ly / length, lz / length
            scale = 1.0 / length  # cos of the angle between the ray and the view axis
            t0 = clip_start / scale
            ox, oy, oz = dx * t0, dy * t0, dz * t0
            tm = clip_end / scale - t0
        origins[k, 0], origins[k, 1], origins[k, 2] = ox, oy, oz
        directions[k, 0], directions[k, 1], directions[k, 2] = dx, dy, dz
        tmax[k] = min(tm, 3e38)
        depth_scale[k] = scale
        t_start[k] = t0

def camera_rays(camera: Camera, raster_x: np.ndarray, raster_y: np.ndarray) -> CameraRays:
    """Rays through raster positions (pixels; x from the left edge, y from the TOP edge, pixel (i, j)'s centre
    at (i + 0.5, j + 0.5)).

    Rays start at the near clipping plane and end at the far one."""
    w, h = camera.resolution
    m = np.asarray(camera.matrix_world, np.float64)
    basis = m[:3, :3]
    # Camera axes in world space, normalised: Blender camera matrices may carry scale, which doesn't change
    # the image (Cycles normalises them too).
    right = basis[:, 0] / np.linalg.norm(basis[:, 0])
    up = basis[:, 1] / np.linalg.norm(basis[:, 1])
    back = basis[:, 2] / np.linalg.norm(basis[:, 2])
    rx = np.ascontiguousarray(raster_x, np.float64).reshape(-1)
    ry = np.ascontiguousarray(raster_y, np.float64).reshape(-1)
    n = rx.shape[0]
    rays = CameraRays(np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32),
                      np.empty(n, np.float32), np.empty(n, np.float32))
    _camera_rays(rx, ry, float(w), float(h), np.asarray(camera.frame(), np.float64), right, up, back,
                 camera.kind == "ORTHO", float(camera.clip_start), float(camera.clip_end), rays.origins,
                 rays.directions, rays.tmax, rays.depth_scale, rays.t_start)
    return rays
