"""Sample warps: uniform numbers in [0, 1)^2 to directions and points, the one compiled copy the renderer runs.

The light kernels (core.light_kernels) and the BSDF kernels (core.bsdf_kernels) call the scalar functions here
from their per-path loops; tests and tools call the same functions through the batch forms at the bottom, so
what is tested is what renders.

Conventions: scalars in float64 (float32 inputs are promoted), unit directions as (x, y, z) tuples; a local
frame has its normal along +z; azimuths are phi = 2 pi u1. Each warp's density is stated in its docstring
(solid angle for directions, area for points) and given by the matching `*_pdf`.
"""

from __future__ import annotations

import math

import numpy as np

from .jit_cache import jit_no_nrt as jit  # warps never allocate

_TWO_PI = 2.0 * math.pi
_INV_PI = 1.0 / math.pi
_INV_4PI = 1.0 / (4.0 * math.pi)
_ZERO32, _ONE32 = np.float32(0.0), np.float32(1.0)


# ------------------------------------------------------------------------------------------------- frames
@jit
def onb(x, y, z):
    """Two unit vectors (t, b) completing the unit vector n = (x, y, z) to a right-handed orthonormal frame
    (t x b = n), branchless (Duff et al. 2017, "Building an Orthonormal Basis, Revisited")."""
    s = 1.0 if z >= 0.0 else -1.0
    a = -1.0 / (s + z)
    b = x * y * a
    return 1.0 + s * x * x * a, s * b, -s * x, b, s + y * y * a, -y


@jit
def onb_f32(x, y, z):
    """`onb` in float32 arithmetic, for float32 x, y, z (the shading frames of surface hits, which the integrator
    keeps in float32): the same formula, rounded as float32 code rounds it."""
    s = _ONE32 if z >= _ZERO32 else -_ONE32
    a = -_ONE32 / (s + z)
    b = x * y * a
    return _ONE32 + s * x * x * a, s * b, -s * x, b, s + y * y * a, -y


@jit
def around(ax, ay, az, cos_t, sin_t, phi):
    """The unit direction at polar angle (cos_t, sin_t) and azimuth phi about the unit axis a (phi measured in
    the frame `onb(a)`)."""
    tx, ty, tz, bx, by, bz = onb(ax, ay, az)
    c, s = sin_t * math.cos(phi), sin_t * math.sin(phi)
    return ax * cos_t + tx * c + bx * s, ay * cos_t + ty * c + by * s, az * cos_t + tz * c + bz * s


# --------------------------------------------------------------------------------------------- directions
@jit
def sample_cos_hemisphere_local(u0, u1):
    """Cosine-weighted direction about +z, the seed's inverse transform: cos(theta) = sqrt(1 - u0),
    sin(theta) = sqrt(u0), phi = 2 pi u1. Density cos(theta) / pi per steradian (`cos_hemisphere_pdf`)."""
    r = math.sqrt(u0)
    phi = _TWO_PI * u1
    return r * math.cos(phi), r * math.sin(phi), math.sqrt(max(1.0 - u0, 0.0))


@jit
def sample_cos_hemisphere(nx, ny, nz, u0, u1):
    """`sample_cos_hemisphere_local` turned into the frame about the unit normal n; returns (wx, wy, wz,
    cos_theta)."""
    x, y, cos_t = sample_cos_hemisphere_local(u0, u1)
    tx, ty, tz, bx, by, bz = onb(nx, ny, nz)
    return nx * cos_t + tx * x + bx * y, ny * cos_t + ty * x + by * y, nz * cos_t + tz * x + bz * y, cos_t


@jit
def cos_hemisphere_pdf(cos_t):
    """Solid-angle density of the cosine-weighted hemisphere at cos(theta) (>= 0)."""
    return _INV_PI * cos_t


@jit
def sample_cone(ax, ay, az, one_minus_cos_max, u0, u1):
    """Uniform direction in the cone about the unit axis a whose half-angle has 1 - cos = one_minus_cos_max
    (kept as 1 - cos so that tiny cones, distant sphere lights, keep their precision): cos(theta) =
    1 - u0 (1 - cos_max), phi = 2 pi u1. Returns (wx, wy, wz, cos_theta); density `cone_pdf`."""
    x = u0 * one_minus_cos_max
    cos_t = 1.0 - x
    sin_t = math.sqrt(max(x * (2.0 - x), 0.0))
    wx, wy, wz = around(ax, ay, az, cos_t, sin_t, _TWO_PI * u1)
    return wx, wy, wz, cos_t


@jit
def cone_pdf(one_minus_cos_max):
    """Solid-angle density 1 / (2 pi (1 - cos_max)) of `sample_cone` inside its cone."""
    return 1.0 / (_TWO_PI * one_minus_cos_max)


@jit
def one_minus_cos_from_sin2(sin2):
    """1 - sqrt(1 - sin2) without cancellation: a sphere of radius r at distance d subtends the cone with
    sin^2(theta_max) = r^2 / d^2."""
    return sin2 / (1.0 + math.sqrt(max(1.0 - sin2, 0.0)))


@jit
def sample_sphere(u0, u1):
    """Uniform direction on the unit sphere: z = 1 - 2 u0, phi = 2 pi u1; density 1 / (4 pi) (`sphere_pdf`)."""
    z = 1.0 - 2.0 * u0
    r = math.sqrt(max(1.0 - z * z, 0.0))
    phi = _TWO_PI * u1
    return r * math.cos(phi), r * math.sin(phi), z


@jit
def sphere_pdf():
    return _INV_4PI


# ------------------------------------------------------------------------------------------------- points
@jit
def sample_disk(radius, u0, u1):
    """Uniform point of the disk of the given radius about the origin (polar map: r = radius sqrt(u0),
    phi = 2 pi u1); density 1 / (pi radius^2) per unit area."""
    rad = radius * math.sqrt(u0)
    phi = _TWO_PI * u1
    return rad * math.cos(phi), rad * math.sin(phi)


@jit
def sample_triangle(u0, u1):
    """Uniform barycentrics (b1, b2) of a triangle v0 + b1 e1 + b2 e2 (the square-root map: b1 = 1 - sqrt(u0),
    b2 = u1 sqrt(u0)); density 1 / area per unit area."""
    su = math.sqrt(u0)
    return 1.0 - su, u1 * su


# ------------------------------------------------------------------------- batch forms (tests and tools)
@jit
def _cos_hemisphere_local_batch(u, out):
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = sample_cos_hemisphere_local(u[k, 0], u[k, 1])


@jit
def _cos_hemisphere_batch(n, u, out):
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1], out[k, 2], _ = sample_cos_hemisphere(n[k, 0], n[k, 1], n[k, 2], u[k, 0], u[k, 1])


@jit
def _cone_batch(axis, one_minus_cos_max, u, out):
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1], out[k, 2], _ = sample_cone(axis[k, 0], axis[k, 1], axis[k, 2],
                                                         one_minus_cos_max[k], u[k, 0], u[k, 1])


@jit
def _sphere_batch(u, out):
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = sample_sphere(u[k, 0], u[k, 1])


@jit
def _disk_batch(radius, u, out):
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1] = sample_disk(radius[k], u[k, 0], u[k, 1])


@jit
def _triangle_batch(u, out):
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1] = sample_triangle(u[k, 0], u[k, 1])


@jit
def _onb_batch(n, t, b):
    for k in range(n.shape[0]):
        t[k, 0], t[k, 1], t[k, 2], b[k, 0], b[k, 1], b[k, 2] = onb(n[k, 0], n[k, 1], n[k, 2])


@jit
def _onb_f32_batch(n, t, b):
    for k in range(n.shape[0]):
        t[k, 0], t[k, 1], t[k, 2], b[k, 0], b[k, 1], b[k, 2] = onb_f32(n[k, 0], n[k, 1], n[k, 2])


def _u(u) -> np.ndarray:
    a = np.ascontiguousarray(u, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"expected u of shape (N, 2), got {a.shape}")
    return a


def _rows(v, n: int, width: int) -> np.ndarray:
    """v (a scalar or one row, or one value per row) as a contiguous float64 (n, width) array ((n,) for width 1)."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64), (n, width) if width > 1 else (n,)))


def cos_hemisphere_local_many(u) -> np.ndarray:
    """`sample_cos_hemisphere_local` of each row of u (N, 2): directions (N, 3) float64."""
    u = _u(u)
    out = np.empty((len(u), 3))
    _cos_hemisphere_local_batch(u, out)
    return out


def cos_hemisphere_many(normal, u) -> np.ndarray:
    """`sample_cos_hemisphere` about normal ((3,) or (N, 3)) for each row of u: directions (N, 3) float64."""
    u = _u(u)
    out = np.empty((len(u), 3))
    _cos_hemisphere_batch(_rows(normal, len(u), 3), u, out)
    return out


def cone_many(axis, one_minus_cos_max, u) -> np.ndarray:
    """`sample_cone` about axis ((3,) or (N, 3)) with 1 - cos_max (scalar or (N,)): directions (N, 3)."""
    u = _u(u)
    out = np.empty((len(u), 3))
    _cone_batch(_rows(axis, len(u), 3), _rows(one_minus_cos_max, len(u), 1), u, out)
    return out


def sphere_many(u) -> np.ndarray:
    """`sample_sphere` of each row of u: directions (N, 3) float64."""
    u = _u(u)
    out = np.empty((len(u), 3))
    _sphere_batch(u, out)
    return out


def disk_many(radius, u) -> np.ndarray:
    """`sample_disk` (radius scalar or (N,)) of each row of u: points (N, 2) float64."""
    u = _u(u)
    out = np.empty((len(u), 2))
    _disk_batch(_rows(radius, len(u), 1), u, out)
    return out


def triangle_many(u) -> np.ndarray:
    """`sample_triangle` of each row of u: barycentrics (b1, b2), (N, 2) float64."""
    u = _u(u)
    out = np.empty((len(u), 2))
    _triangle_batch(u, out)
    return out


def onb_many(normals) -> tuple[np.ndarray, np.ndarray]:
    """`onb` of each unit normal (N, 3): (t, b), each (N, 3) float64; float32 normals go through `onb_f32`
    and give float32 frames."""
    if np.asarray(normals).dtype == np.float32:
        n = np.ascontiguousarray(normals)
        t, b = np.empty_like(n), np.empty_like(n)
        _onb_f32_batch(n, t, b)
        return t, b
    n = np.ascontiguousarray(normals, dtype=np.float64)
    t, b = np.empty_like(n), np.empty_like(n)
    _onb_batch(n, t, b)
    return t, b
