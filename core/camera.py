"""Camera rays in Blender's conventions (see `scene.Camera`), in the integrator's shifted frame.

The integrator renders relative to the camera: positions are (world - camera position), so perspective rays
start at the origin, where float32 is most precise, wherever the scene sits in the world.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import geometry_kernels
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
    geometry_kernels.camera_rays(rx, ry, float(w), float(h), np.asarray(camera.frame(), np.float64), right, up, back,
                        camera.kind == "ORTHO", float(camera.clip_start), float(camera.clip_end), rays.origins,
                        rays.directions, rays.tmax, rays.depth_scale, rays.t_start)
    return rays
