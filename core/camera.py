"""Camera rays in Blender's conventions (see `scene.Camera`), in the integrator's shifted frame.

The integrator renders relative to the camera: positions are (world - camera position), so perspective rays
start at the origin, where float32 is most precise, wherever the scene sits in the world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .jit_cache import jit, jit_inline
from .scene import Camera
from .warps import sample_disk


@dataclass
class CameraRays:
    """origins (N,3) float32 relative to the camera position; directions (N,3) float32 unit; tmax (N,) from
    clip_end; z-depth of a hit at distance t along the ray = (t_start + t) x depth_scale. alive (N,) bool: False
    for rays a panoramic camera does not cast (outside the fisheye circle or the mirror ball), which add nothing
    to their pixel (black, opaque); None when every ray is alive (perspective and orthographic cameras)."""

    origins: np.ndarray
    directions: np.ndarray
    tmax: np.ndarray
    depth_scale: np.ndarray
    t_start: np.ndarray
    alive: np.ndarray | None = None



@dataclass
class PinholeRays:
    """A batch of a pinhole camera's rays (perspective or orthographic, no depth of field), not made yet: the fused
    path kernel makes each path's ray from its raster position as camera_rays would (the same bits), and its ray
    differentials only if the path reaches a material that reads them (Bump nodes); `rays` and `footprints` make
    them all. raster_x, raster_y (N,) float64: raster positions (camera_rays' convention); params: the camera
    (pinhole_params). The rays are the camera's, before any origin shift."""

    raster_x: np.ndarray
    raster_y: np.ndarray
    params: np.ndarray

    def __len__(self) -> int:
        return self.raster_x.shape[0]

    def rays(self) -> CameraRays:
        """camera_rays' rays at these raster positions."""
        n = len(self)
        rays = CameraRays(np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32),
                          np.empty(n, np.float32), np.empty(n, np.float32))
        _camera_rays(self.raster_x, self.raster_y, self.params, rays.origins, rays.directions, rays.tmax,
                     rays.depth_scale, rays.t_start)
        return rays

    def footprints(self, rays: CameraRays) -> tuple[np.ndarray, np.ndarray]:
        """(dp, dd) (N,) float32 of `rays` (self.rays()): pinhole_differentials' values."""
        n = len(self)
        dp, dd = np.empty(n, np.float32), np.empty(n, np.float32)
        _pinhole_differentials(self.raster_x, self.raster_y, self.params,
                               np.ascontiguousarray(rays.origins, np.float32),
                               np.ascontiguousarray(rays.directions, np.float32), dp, dd)
        return dp, dd


@jit
def aperture_point(u0, u1, blades, rotation, inv_ratio):
    """A uniform point of the unit aperture (Cycles' conventions): the unit disk, or for blades >= 3 the regular
    polygon inscribed in it, its corners at rotation + (2k + 1) pi / blades; x then squeezed by inv_ratio
    (anamorphic bokeh). Returns (x, y) along the camera's right and up axes."""
    if blades >= 3:
        # One of the polygon's wedges (the triangle centre, corner k, corner k + 1), then a uniform point in it.
        n = float(blades)
        wedge = min(math.floor(u0 * n), n - 1.0)
        su = math.sqrt(u0 * n - wedge)
        a, b = 1.0 - su, u1 * su
        half = math.pi / n
        px, py = (a + b) * math.cos(half), (a - b) * math.sin(half)
        turn = rotation + wedge * 2.0 * half
        c, s = math.cos(turn), math.sin(turn)
        x, y = c * px - s * py, s * px + c * py
    else:
        x, y = sample_disk(1.0, u0, u1)
    return x * inv_ratio, y


@jit_inline
def _pinhole_ray_scalars(rx, ry, width, height, xmin, xmax, ymin, ymax, r0, r1, r2, u0, u1, u2, b0, b1, b2, ortho,
                         clip_start, clip_end):
    """One pinhole camera ray in float64: (ox, oy, oz, dx, dy, dz, tmax, depth scale, t_start). frame (xmin, xmax,
    ymin, ymax): the image on the plane at distance 1 (perspective) or in world units (orthographic); the camera's
    unit right, up and back axes as their components (r, u, b); the ray starts at clip_start and ends at
    clip_end."""
    x = xmin + (rx / width) * (xmax - xmin)
    y = ymax - (ry / height) * (ymax - ymin)
    if ortho:
        dx, dy, dz = -b0, -b1, -b2
        ox = x * r0 + y * u0 + clip_start * dx
        oy = x * r1 + y * u1 + clip_start * dy
        oz = x * r2 + y * u2 + clip_start * dz
        tm, scale, t0 = clip_end - clip_start, 1.0, clip_start
    else:
        lx = x * r0 + y * u0 - b0
        ly = x * r1 + y * u1 - b1
        lz = x * r2 + y * u2 - b2
        length = math.sqrt(lx * lx + ly * ly + lz * lz)
        dx, dy, dz = lx / length, ly / length, lz / length
        scale = 1.0 / length  # cos of the angle between the ray and the view axis
        t0 = clip_start / scale
        ox, oy, oz = dx * t0, dy * t0, dz * t0
        tm = clip_end / scale - t0
    return ox, oy, oz, dx, dy, dz, tm, scale, t0


@jit
def _camera_rays(raster_x, raster_y, p, origins, directions, tmax, depth_scale, t_start):
    """Camera rays through raster positions (see camera_rays) of the camera p (pinhole_params), in float64, written
    as float32."""
    for k in range(raster_x.shape[0]):
        ox, oy, oz, dx, dy, dz, tm, scale, t0 = pinhole_ray(raster_x[k], raster_y[k], p)
        origins[k, 0], origins[k, 1], origins[k, 2] = ox, oy, oz
        directions[k, 0], directions[k, 1], directions[k, 2] = dx, dy, dz
        tmax[k] = min(tm, 3e38)
        depth_scale[k] = scale
        t_start[k] = t0


@jit
def _offset_length(ax, ay, az, bx, by, bz):
    """Length in float64 of (a as float32) - b, b float32 values: (x^2 + y^2) + z^2, as row_lengths."""
    x = np.float64(np.float32(ax)) - np.float64(bx)
    y = np.float64(np.float32(ay)) - np.float64(by)
    z = np.float64(np.float32(az)) - np.float64(bz)
    return math.sqrt(x * x + y * y + z * z)


# pinhole_params' layout: one float64 vector that the compiled kernels read a perspective or orthographic camera
# (without depth of field) from
PINHOLE_PARAMS = 18  # width, height, frame (xmin, xmax, ymin, ymax), right, up, back (3 each), ortho, clip start, end


def pinhole_params(camera: Camera) -> np.ndarray | None:
    """(PINHOLE_PARAMS,) float64: the camera as pinhole_footprint reads it (resolution in pixels, the image frame,
    the unit right, up and back axes in world space, 1.0 for orthographic, the clipping distances); None for a
    camera that is not a pinhole (panoramic, or depth of field)."""
    if camera.kind == "PANO" or float(camera.aperture_radius()) > 0:
        return None
    w, h = camera.resolution
    right, up, back, _, _ = _axes_and_raster(camera, np.zeros(0), np.zeros(0))
    return np.concatenate([[float(w), float(h)], np.asarray(camera.frame(), np.float64), right, up, back,
                           [1.0 if camera.kind == "ORTHO" else 0.0, float(camera.clip_start),
                            float(camera.clip_end)]]).astype(np.float64)


@jit_inline
def pinhole_ray(rx, ry, p):
    """One ray of the camera p (pinhole_params) through raster position (rx, ry), in float64: _pinhole_ray_scalars'
    (ox, oy, oz, dx, dy, dz, tmax, depth scale, t_start)."""
    return _pinhole_ray_scalars(rx, ry, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11],
                                p[12], p[13], p[14], p[15] != 0.0, p[16], p[17])


@jit_inline
def pinhole_footprint(rx, ry, p, ox, oy, oz, dx, dy, dz):
    """Cycles' compact camera-ray differentials (dP, dD) as float32 (see shading.vector_context
    .camera_differentials) of the ray that _camera_rays wrote for raster position (rx, ry) (origin o, direction d,
    float32), for the camera p (pinhole_params): from the rays one pixel over in x and in y, each rounded to
    float32 as _camera_rays stores it. The fused path kernel calls it for the paths that reach a Bump node."""
    ax, ay, az, adx, ady, adz, _, _, _ = pinhole_ray(rx + 1.0, ry, p)
    bx, by, bz, bdx, bdy, bdz, _, _, _ = pinhole_ray(rx, ry + 1.0, p)
    dp = np.float32(0.5 * (_offset_length(ax, ay, az, ox, oy, oz) + _offset_length(bx, by, bz, ox, oy, oz)))
    dd = np.float32(0.5 * (_offset_length(adx, ady, adz, dx, dy, dz) + _offset_length(bdx, bdy, bdz, dx, dy, dz)))
    return dp, dd


@jit
def _pinhole_differentials(raster_x, raster_y, p, origins, directions, dp, dd):
    """pinhole_footprint of every ray _camera_rays wrote (origins, directions float32) at raster positions
    (raster_x, raster_y), for the camera p (pinhole_params)."""
    for k in range(raster_x.shape[0]):
        dp[k], dd[k] = pinhole_footprint(raster_x[k], raster_y[k], p, origins[k, 0], origins[k, 1], origins[k, 2],
                                         directions[k, 0], directions[k, 1], directions[k, 2])


@jit
def _lens_camera_rays(raster_x, raster_y, width, height, frame, right, up, back, ortho, clip_start, clip_end,
                      lens_u, aperture, focus, blades, rotation, inv_ratio,
                      origins, directions, tmax, depth_scale, t_start):
    """Camera rays through a thin lens (see _pinhole_ray_scalars for the shared arguments): aperture is the lens
    radius, focus the distance of the plane in focus along the view axis, lens_u (N, 2) the lens samples (see
    aperture_point). A kernel of its own so that the pinhole camera's loop stays as lean as it was."""
    xmin, xmax, ymin, ymax = frame[0], frame[1], frame[2], frame[3]
    for k in range(raster_x.shape[0]):
        x = xmin + (raster_x[k] / width) * (xmax - xmin)
        y = ymax - (raster_y[k] / height) * (ymax - ymin)
        ax, ay = aperture_point(np.float64(lens_u[k, 0]), np.float64(lens_u[k, 1]), blades, rotation, inv_ratio)
        ax *= aperture
        ay *= aperture
        if ortho:
            # Towards the point in focus straight ahead of the raster position, from the lens point; the ray
            # starts where it crosses the near clipping plane (Cycles' orthographic lens).
            cx, cy, cz = -ax, -ay, focus
            ex, ey = x + ax, y + ay  # the lens point, camera space
        else:
            # From the lens point to where the pinhole ray meets the plane in focus (z = focus ahead).
            cx, cy, cz = x * focus - ax, y * focus - ay, focus
            ex, ey = ax, ay
        inv = 1.0 / math.sqrt(cx * cx + cy * cy + cz * cz)
        cx, cy, cz = cx * inv, cy * inv, cz * inv  # camera space, z forward
        if ortho:
            t0, tm = clip_start / cz, clip_end - clip_start
        else:
            # The clipping distances stay those of the pinhole ray, as in Cycles.
            length = math.sqrt(x * x + y * y + 1.0)  # the pinhole ray's length per unit of depth
            t0, tm = clip_start * length, (clip_end - clip_start) * length
        dx = cx * right[0] + cy * up[0] - cz * back[0]
        dy = cx * right[1] + cy * up[1] - cz * back[1]
        dz = cx * right[2] + cy * up[2] - cz * back[2]
        origins[k, 0] = ex * right[0] + ey * up[0] + t0 * dx
        origins[k, 1] = ex * right[1] + ey * up[1] + t0 * dy
        origins[k, 2] = ex * right[2] + ey * up[2] + t0 * dz
        directions[k, 0], directions[k, 1], directions[k, 2] = dx, dy, dz
        tmax[k] = min(tm, 3e38)
        depth_scale[k] = cz  # the z-depth of the ray's points: (t0 + t) x its view-axis component
        t_start[k] = t0


# Panorama kinds as the compiled kernel numbers them (core.scene.PANORAMA_TYPES order).
_PANO_KIND = {"EQUIRECTANGULAR": 0, "FISHEYE_EQUIDISTANT": 1, "FISHEYE_EQUISOLID": 2, "MIRRORBALL": 3,
              "FISHEYE_LENS_POLYNOMIAL": 4, "CENTRAL_CYLINDRICAL": 5}


@jit
def _panorama_rays(raster_x, raster_y, width, height, kind, params, right, up, back, clip_start, clip_end,
                   lens_u, aperture, focus, blades, rotation, inv_ratio,
                   origins, directions, tmax, depth_scale, t_start, alive):
    """Panoramic camera rays (Cycles' panorama projections; see core.scene.Camera for each kind).

    params: (shift_x, shift_y, then per kind) equirectangular: lon_min, lon_max, lat_min, lat_max; fisheye
    equidistant: fov; equisolid: lens, fov, sensor width, sensor height (mm); lens polynomial: fov, sensor width,
    sensor height, k0..k4; central cylindrical: lon_min, lon_max, height_min / radius, height_max / radius.
    Directions are first found in
    Cycles' panorama space (x ahead, y left, z up; for the mirror ball x right, y ahead, z up), then turned to
    the camera's axes. Depth of field (aperture > 0, the lens radius; lens_u (N, 2) as for _lens_camera_rays,
    unread when aperture is 0) as Cycles does it on panoramas, in that panorama space: the point in focus lies
    at distance `focus` along the pinhole direction D (a sphere of focus, not a plane); the lens point is
    offset from the camera centre in the plane perpendicular to D, along U (the panorama x axis made
    perpendicular to D) and D x U; the ray runs from the lens point to the point in focus."""
    for k in range(raster_x.shape[0]):
        u = raster_x[k] / width + params[0]
        v = 1.0 - raster_y[k] / height + params[1]
        px, py, pz = 0.0, 0.0, 0.0
        ok = True
        if kind == 0:
            phi = (params[2] - params[3]) * u - params[2]
            theta = (params[4] - params[5]) * v + 0.5 * math.pi - params[4]
            px, py, pz = math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)
        elif kind == 5:
            theta = params[2] + (params[3] - params[2]) * u
            # Longitude grows to the left as u grows to the right (as equirectangular): angle -theta.
            px, py, pz = math.cos(theta), -math.sin(theta), params[4] + (params[5] - params[4]) * v
        elif kind == 1 or kind == 2 or kind == 4:
            if kind == 1:
                fu, fv = (u - 0.5) * 2.0, (v - 0.5) * 2.0
                r = math.sqrt(fu * fu + fv * fv)
                ok = r <= 1.0
                theta = r * params[2] * 0.5
            elif kind == 4:
                fu, fv = (u - 0.5) * params[3], (v - 0.5) * params[4]
                r = math.sqrt(fu * fu + fv * fv)
                theta = -(params[5] + r * (params[6] + r * (params[7] + r * (params[8] + r * params[9]))))
                ok = abs(theta) <= 0.5 * params[2]
            else:
                lens = params[2]
                fu, fv = (u - 0.5) * params[4], (v - 0.5) * params[5]
                r = math.sqrt(fu * fu + fv * fv)
                ok = r <= 2.0 * lens * math.sin(params[3] * 0.25)
                theta = 2.0 * math.asin(min(r / (2.0 * lens), 1.0))
            phi = math.acos(max(-1.0, min(1.0, fu / r))) if r != 0.0 else 0.5 * math.pi
            if fv < 0.0:
                phi = -phi
            px, py, pz = math.cos(theta), -math.cos(phi) * math.sin(theta), math.sin(phi) * math.sin(theta)
        else:
            bx, bz = 2.0 * u - 1.0, 2.0 * v - 1.0
            ok = bx * bx + bz * bz <= 1.0
            by = -math.sqrt(max(1.0 - bx * bx - bz * bz, 0.0))
            # The view direction (0, -1, 0) reflected about the ball's normal (bx, by, bz).
            twice = -2.0 * by
            px, py, pz = twice * bx, twice * by + 1.0, twice * bz
        length = math.sqrt(px * px + py * py + pz * pz)
        ox, oy, oz = 0.0, 0.0, 0.0  # the lens point, in panorama space
        if ok and length > 0.0 and aperture > 0.0:
            fx, fy, fz = px / length, py / length, pz / length
            ax, ay = aperture_point(np.float64(lens_u[k, 0]), np.float64(lens_u[k, 1]), blades, rotation, inv_ratio)
            ux, uy, uz = 1.0 - fx * fx, -fx * fy, -fx * fz
            ul = math.sqrt(ux * ux + uy * uy + uz * uz)
            if ul < 1e-12:  # looking straight along x: any perpendicular will do (Cycles' U is undefined there)
                ux, uy, uz, ul = 0.0, 1.0, 0.0, 1.0
            ux, uy, uz = ux / ul, uy / ul, uz / ul
            vx, vy, vz = fy * uz - fz * uy, fz * ux - fx * uz, fx * uy - fy * ux
            ox, oy, oz = ux * ax * aperture + vx * ay * aperture, uy * ax * aperture + vy * ay * aperture, \
                uz * ax * aperture + vz * ay * aperture
            px, py, pz = fx * focus - ox, fy * focus - oy, fz * focus - oz
        if kind == 3:
            cx, cy, cz = px, pz, py  # mirror ball space -> camera local (x right, y up, z back)
            lx, ly, lz = ox, oz, oy
        else:
            cx, cy, cz = -py, pz, -px
            lx, ly, lz = -oy, oz, -ox
        length = math.sqrt(cx * cx + cy * cy + cz * cz)
        if not ok or length == 0.0:
            alive[k] = False
            origins[k, 0], origins[k, 1], origins[k, 2] = 0.0, 0.0, 0.0
            directions[k, 0], directions[k, 1], directions[k, 2] = 0.0, 0.0, 1.0
            tmax[k], depth_scale[k], t_start[k] = 0.0, 1.0, 0.0
            continue
        cx, cy, cz = cx / length, cy / length, cz / length
        dx = cx * right[0] + cy * up[0] + cz * back[0]
        dy = cx * right[1] + cy * up[1] + cz * back[1]
        dz = cx * right[2] + cy * up[2] + cz * back[2]
        alive[k] = True
        wx = lx * right[0] + ly * up[0] + lz * back[0]
        wy = lx * right[1] + ly * up[1] + lz * back[1]
        wz = lx * right[2] + ly * up[2] + lz * back[2]
        origins[k, 0], origins[k, 1], origins[k, 2] = wx + dx * clip_start, wy + dy * clip_start, wz + dz * clip_start
        directions[k, 0], directions[k, 1], directions[k, 2] = dx, dy, dz
        tmax[k] = min(clip_end - clip_start, 3e38)
        depth_scale[k] = 1.0  # the depth pass of a panorama is the distance along the ray
        t_start[k] = clip_start


def panorama_params(camera: Camera) -> np.ndarray:
    """The kernel's parameter row of a panoramic camera (see _panorama_rays): shift, then the kind's own, with
    the equisolid sensor fitted as Cycles fits it (the fitted side's sensor size, the other by the aspect)."""
    w, h = camera.resolution
    kind = camera.panorama_type
    params = np.zeros(10, np.float64)
    params[0], params[1] = camera.shift_x, camera.shift_y
    if kind == "EQUIRECTANGULAR":
        params[2:6] = camera.longitude_min, camera.longitude_max, camera.latitude_min, camera.latitude_max
    elif kind == "FISHEYE_EQUIDISTANT":
        params[2] = camera.fisheye_fov
    elif kind in ("FISHEYE_EQUISOLID", "FISHEYE_LENS_POLYNOMIAL"):
        fit = camera.sensor_fit
        horizontal = w > h if fit == "AUTO" else fit == "HORIZONTAL"
        size = camera.sensor_height if fit == "VERTICAL" else camera.sensor_width
        sw, sh = (size, size * h / w) if horizontal else (size * w / h, size)
        if kind == "FISHEYE_EQUISOLID":
            params[2:6] = camera.fisheye_lens, camera.fisheye_fov, sw, sh
        else:
            params[2:5] = camera.fisheye_fov, sw, sh
            params[5:10] = camera.fisheye_polynomial
    elif kind == "CENTRAL_CYLINDRICAL":
        r = camera.cylinder_radius
        params[2:6] = (camera.longitude_min, camera.longitude_max, camera.cylinder_height_min / r,
                       camera.cylinder_height_max / r)
    return params


def _axes_and_raster(camera: Camera, raster_x: np.ndarray, raster_y: np.ndarray) -> tuple[np.ndarray, ...]:
    """The camera's right, up and back axes in world space, normalised (Blender camera matrices may carry scale,
    which doesn't change the image; Cycles normalises them too), and the raster coordinates as flat float64."""
    basis = np.asarray(camera.matrix_world, np.float64)[:3, :3]
    right = basis[:, 0] / np.linalg.norm(basis[:, 0])
    up = basis[:, 1] / np.linalg.norm(basis[:, 1])
    back = basis[:, 2] / np.linalg.norm(basis[:, 2])
    rx = np.ascontiguousarray(raster_x, np.float64).reshape(-1)
    ry = np.ascontiguousarray(raster_y, np.float64).reshape(-1)
    return right, up, back, rx, ry


def camera_rays(camera: Camera, raster_x: np.ndarray, raster_y: np.ndarray,
                lens_u: np.ndarray | None = None) -> CameraRays:
    """Rays through raster positions (pixels; x from the left edge, y from the TOP edge, pixel (i, j)'s centre
    at (i + 0.5, j + 0.5)).

    Rays start at the near clipping plane and end at the far one. A camera with depth of field
    (`Camera.aperture_radius() > 0`) needs lens_u: (N, 2) uniform numbers in [0, 1), one lens point per ray;
    a pinhole camera ignores it."""
    w, h = camera.resolution
    right, up, back, rx, ry = _axes_and_raster(camera, raster_x, raster_y)
    n = rx.shape[0]
    aperture = float(camera.aperture_radius())
    if aperture > 0:
        if lens_u is None:
            raise ValueError("camera_rays: a camera with depth of field needs lens samples (lens_u)")
        lens = np.ascontiguousarray(lens_u, np.float32).reshape(-1, 2)
        if lens.shape[0] != n:
            raise ValueError(f"camera_rays: {lens.shape[0]} lens samples for {n} rays")
    rays = CameraRays(np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32),
                      np.empty(n, np.float32), np.empty(n, np.float32))
    if camera.kind == "PANO":
        rays.alive = np.empty(n, bool)
        _panorama_rays(rx, ry, float(w), float(h), _PANO_KIND[camera.panorama_type], panorama_params(camera),
                       right, up, back, float(camera.clip_start), float(camera.clip_end),
                       lens if aperture > 0 else np.zeros((1, 2), np.float32), aperture,
                       float(camera.focus_distance), int(camera.aperture_blades), float(camera.aperture_rotation),
                       1.0 / float(camera.aperture_ratio), rays.origins,
                       rays.directions, rays.tmax, rays.depth_scale, rays.t_start, rays.alive)
        if rays.alive.all():
            rays.alive = None
        return rays
    outputs = (rays.origins, rays.directions, rays.tmax, rays.depth_scale, rays.t_start)
    if aperture > 0:
        _lens_camera_rays(rx, ry, float(w), float(h), np.asarray(camera.frame(), np.float64), right, up, back,
                          camera.kind == "ORTHO", float(camera.clip_start), float(camera.clip_end), lens, aperture,
                          float(camera.focus_distance), int(camera.aperture_blades), float(camera.aperture_rotation),
                          1.0 / float(camera.aperture_ratio), *outputs)
    else:
        _camera_rays(rx, ry, pinhole_params(camera), *outputs)
    return rays


def pinhole_differentials(camera: Camera, raster_x: np.ndarray, raster_y: np.ndarray,
                          rays: CameraRays) -> tuple[np.ndarray, np.ndarray] | None:
    """shading.vector_context.camera_differentials of a perspective or orthographic camera without depth of
    field, compiled (the same bits); None for any other camera (panoramic, or a lens), which that computes."""
    p = pinhole_params(camera)
    if p is None:
        return None
    rx = np.ascontiguousarray(raster_x, np.float64).reshape(-1)
    ry = np.ascontiguousarray(raster_y, np.float64).reshape(-1)
    n = rx.shape[0]
    dp, dd = np.empty(n, np.float32), np.empty(n, np.float32)
    _pinhole_differentials(rx, ry, p, np.ascontiguousarray(rays.origins, np.float32),
                           np.ascontiguousarray(rays.directions, np.float32), dp, dd)
    return dp, dd
