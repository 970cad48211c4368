"""Camera rays in Blender's conventions (see `scene.Camera`), in the integrator's shifted frame.

The integrator renders relative to the camera: positions are (world - camera position), so perspective rays
start at the origin, where float32 is most precise, wherever the scene sits in the world.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
    xmin, xmax, ymin, ymax = camera.frame()
    x = xmin + (np.asarray(raster_x, np.float64) / w) * (xmax - xmin)
    y = ymax - (np.asarray(raster_y, np.float64) / h) * (ymax - ymin)
    m = np.asarray(camera.matrix_world, np.float64)
    basis = m[:3, :3]
    # Camera axes in world space, normalised: Blender camera matrices may carry scale, which doesn't change
    # the image (Cycles normalises them too).
    right = basis[:, 0] / np.linalg.norm(basis[:, 0])
    up = basis[:, 1] / np.linalg.norm(basis[:, 1])
    back = basis[:, 2] / np.linalg.norm(basis[:, 2])
    n = x.shape[0]
    if camera.kind == "ORTHO":
        d = np.broadcast_to(-back, (n, 3))
        o = x[:, None] * right + y[:, None] * up + camera.clip_start * d
        tmax = np.full(n, camera.clip_end - camera.clip_start)
        scale = np.ones(n)
        t0 = np.full(n, camera.clip_start)
    else:
        local = x[:, None] * right + y[:, None] * up - back  # point on the plane at distance 1
        length = np.linalg.norm(local, axis=1)
        d = local / length[:, None]
        scale = 1.0 / length  # cos of the angle between the ray and the view axis
        t0 = camera.clip_start / scale
        o = d * t0[:, None]
        tmax = camera.clip_end / scale - t0
    return CameraRays(o.astype(np.float32), np.ascontiguousarray(d, dtype=np.float32),
                      np.minimum(tmax, 3e38).astype(np.float32), scale.astype(np.float32), t0.astype(np.float32))
