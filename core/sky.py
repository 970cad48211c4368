"""Blender's Sky Texture models evaluated per direction and baked into an environment map: Preetham (analytic)
and Single Scattering (Nishita's atmosphere, Blender 4.x's "Nishita"), with that one's sun disc as a sun light.
Hosek-Wilkie and Multiple Scattering are not here (the add-on warns by name).

Preetham ("A Practical Analytic Model for Daylight", Preetham, Shirley and Smits 1999), as Cycles evaluates it:
the Perez distribution F(theta, gamma) = (1 + A exp(B / cos theta)) (1 + C exp(D gamma) + E cos^2 gamma) for each
of the CIE xyY components, A..E linear in the turbidity T, scaled so that the zenith holds the paper's zenith
values (Y in kcd/m^2 x 0.06, Cycles' scale); theta is the view direction's angle from +z (clamped just above the
horizon, so the lower hemisphere repeats the horizon's colour), gamma its angle to the sun (measured before the
clamp). xyY -> XYZ -> linear RGB (XYZ_TO_LINEAR_RGB), negative channels clamped to 0.

Conventions (Cycles'): directions are unit (x, y, z) with z up; spherical (theta, phi) = (acos z, atan2(x, y)).

`bake_equirectangular` evaluates any such model on the texel centres of an equirectangular map (row 0 at the top,
core.world's convention) so that the world renders through core.world's EnvironmentMap: its bilinear lookup and its
importance-sampled distribution.
"""

from __future__ import annotations

import functools
import math
from typing import Callable

import numpy as np

__all__ = ["XYZ_TO_LINEAR_RGB", "preetham_radiance", "bake_equirectangular", "SKY_BAKE_WIDTH", "single_scattering_xyz",
           "single_scattering_lut", "single_scattering_sun", "single_scattering_radiance", "sun_disc_light",
           "wrap_sun_position", "sun_direction"]

# CIE XYZ (D65 white) -> linear Rec.709 / sRGB primaries, the scene-linear space of Blender's default config.
XYZ_TO_LINEAR_RGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                              [-0.9692660, 1.8760108, 0.0415560],
                              [0.0556434, -0.2040259, 1.0572252]])
# Width of the baked map (height half of it): 0.35 degrees a texel, finer than the analytic models vary away from
# the sun's immediate surroundings (see tests/test_sky.py for the measured baking error).
SKY_BAKE_WIDTH = 1024

# Perez coefficients (A..E) = slope x T + offset, for Y, x and y.
_PEREZ_Y = np.array([[0.1787, -1.4630], [-0.3554, 0.4275], [-0.0227, 5.3251], [0.1206, -2.5771],
                     [-0.0670, 0.3703]])
_PEREZ_X = np.array([[-0.0193, -0.2592], [-0.0665, 0.0008], [-0.0004, 0.2125], [-0.0641, -0.8989],
                     [-0.0033, 0.0452]])
_PEREZ_YY = np.array([[-0.0167, -0.2608], [-0.0950, 0.0092], [-0.0079, 0.2102], [-0.0441, -1.6537],
                      [-0.0109, 0.0529]])
# Zenith chromaticity: rows T^2, T, 1; columns theta^3, theta^2, theta, 1 (theta the sun's zenith angle).
_ZENITH_X = np.array([[0.00166, -0.00375, 0.00209, 0.0], [-0.02903, 0.06377, -0.03202, 0.00394],
                      [0.11693, -0.21196, 0.06052, 0.25886]])
_ZENITH_Y = np.array([[0.00275, -0.00610, 0.00317, 0.0], [-0.04214, 0.08970, -0.04153, 0.00516],
                      [0.15346, -0.26756, 0.06670, 0.26688]])
_HORIZON_CLAMP = 0.001  # radians above the horizon where the view angle stops (Cycles' clamp)


def _perez(coef: np.ndarray, theta: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    a, b, c, d, e = coef
    cg = np.cos(gamma)
    return (1.0 + a * np.exp(b / np.cos(theta))) * (1.0 + c * np.exp(d * gamma) + e * cg * cg)


def _spherical(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.arccos(np.clip(d[..., 2], -1.0, 1.0)), np.arctan2(d[..., 0], d[..., 1])


def preetham_radiance(directions: np.ndarray, sun_direction, turbidity: float) -> np.ndarray:
    """Linear RGB radiance (N, 3) of Preetham's clear sky in unit world directions (N, 3), for the sun in
    `sun_direction` (any length > 0; Blender's Sun Direction) and `turbidity` (Blender's, 1..10 sensible)."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    s = np.asarray(sun_direction, np.float64).reshape(3)
    n = float(np.linalg.norm(s))
    s = s / n if n > 0 else np.array([0.0, 0.0, 1.0])
    sun_theta, sun_phi = _spherical(s)
    sun_theta, sun_phi = float(sun_theta), float(sun_phi)
    T = float(turbidity)
    perez = [np.array([sl * T + off for sl, off in table]) for table in (_PEREZ_Y, _PEREZ_X, _PEREZ_YY)]
    chi = (4.0 / 9.0 - T / 120.0) * (math.pi - 2.0 * sun_theta)
    zenith_Y = ((4.0453 * T - 4.9710) * math.tan(chi) - 0.2155 * T + 2.4192) * 0.06
    powers_t = np.array([T * T, T, 1.0])
    powers_th = np.array([sun_theta ** 3, sun_theta ** 2, sun_theta, 1.0])
    zenith_x = float(powers_t @ _ZENITH_X @ powers_th)
    zenith_y = float(powers_t @ _ZENITH_Y @ powers_th)
    zenith = [z / float(_perez(c, np.float64(0.0), np.float64(sun_theta)))
              for z, c in zip((zenith_Y, zenith_x, zenith_y), perez)]
    theta, phi = _spherical(d)
    cos_gamma = np.sin(theta) * math.sin(sun_theta) * np.cos(phi - sun_phi) + np.cos(theta) * math.cos(sun_theta)
    gamma = np.arccos(np.clip(cos_gamma, -1.0, 1.0))
    theta = np.minimum(theta, math.pi / 2 - _HORIZON_CLAMP)
    Y, x, y = (z * _perez(c, theta, gamma) for z, c in zip(zenith, perez))
    safe_y = np.where(y != 0, y, 1.0)
    X = np.where(y != 0, x / safe_y * Y, 0.0)
    Z = np.where((y != 0) & (Y != 0), (1.0 - x - y) / safe_y * Y, 0.0)
    rgb = np.stack([X, Y, Z], -1) @ XYZ_TO_LINEAR_RGB.T
    return np.maximum(np.where(np.isfinite(rgb), rgb, 0.0), 0.0)


def equirectangular_directions(width: int) -> np.ndarray:
    """Unit directions (H, W, 3), H = width // 2, of the texel centres of an equirectangular map with row 0 at the
    top (core.world_kernels' parametrisation: u = 0.5 - atan2(y, x) / 2 pi, v = 0.5 + elevation / pi)."""
    height = max(width // 2, 1)
    u = (np.arange(width) + 0.5) / width
    v = 1.0 - (np.arange(height) + 0.5) / height
    phi = math.pi - 2.0 * math.pi * u
    el = math.pi * (v - 0.5)
    ce = np.cos(el)[:, None]
    return np.stack([ce * np.cos(phi)[None, :], ce * np.sin(phi)[None, :],
                     np.broadcast_to(np.sin(el)[:, None], (height, width))], -1)


def bake_equirectangular(radiance: Callable[[np.ndarray], np.ndarray], width: int = SKY_BAKE_WIDTH) -> np.ndarray:
    """The (width // 2, width, 3) float32 map (row 0 at the top) of radiance(directions (N, 3)) -> (N, 3)."""
    d = equirectangular_directions(width)
    return radiance(d.reshape(-1, 3)).reshape(d.shape).astype(np.float32)


# ------------------------------------------------------------------------------------------ single scattering
# Nishita's single-scattering atmosphere as Blender computes it (Blender 5.x "Single Scattering", 4.x "Nishita"):
# a spherical Earth and atmosphere, Rayleigh (air) and Mie (aerosol) scattering with exponential height profiles,
# ozone absorption in a tent 10..40 km up, 21 wavelengths 380..780 nm integrated against the CIE 1931 observer.
# The sky is tabulated on a 512 x 256 look-up table over (azimuth from the sun, elevation with more rows near the
# horizon), read bilinearly, as Cycles does; the sun's disc is a separate light (see `single_scattering_sun`).
EARTH_RADIUS = 6360e3  # m
ATMOSPHERE_RADIUS = 6420e3  # m
_RAYLEIGH_SCALE = 8e3  # m, scale height
_MIE_SCALE = 1.2e3  # m
_MIE_COEFF = 2e-5  # 1/m, scattering; extinction 1.11 x
_MIE_G = 0.76
_MARCH_STEPS = 32
_LAMBDA_STEP = 20.0  # nm
SKY_LUT_SIZE = (256, 512)  # (rows, columns) of the look-up table, Cycles' size
# Sun spectral irradiance at the top of the atmosphere (W m^-2 nm^-1), 380..780 nm by 20 nm.
_IRRADIANCE = np.array([1.45756830, 1.56596306, 1.65148449, 1.71496243, 1.75797984, 1.78256408, 1.79095108,
                        1.78541550, 1.76815555, 1.74122070, 1.70647127, 1.66556087, 1.61993437, 1.57083597,
                        1.51932335, 1.46628495, 1.41245853, 1.35844962, 1.30474914, 1.25174963, 1.19975999])
# Rayleigh scattering coefficient at sea level (1/m).
_RAYLEIGH_COEFF = np.array([5.424820088e-05, 4.418549867e-05, 3.635151910e-05, 3.017929012e-05, 2.526320227e-05,
                            2.130859311e-05, 1.809838025e-05, 1.547057129e-05, 1.330284977e-05, 1.150184784e-05,
                            9.995574300e-06, 8.727999736e-06, 7.655137010e-06, 6.742172038e-06, 5.961341258e-06,
                            5.290345981e-06, 4.711156876e-06, 4.209104811e-06, 3.772183813e-06, 3.390512555e-06,
                            3.055915317e-06])
# Ozone absorption coefficient at the tent's peak (1/m).
_OZONE_COEFF = np.array([3.251268499e-09, 5.853953650e-09, 1.977191155e-08, 7.309568763e-08, 2.008456151e-07,
                         4.038395810e-07, 6.355133591e-07, 9.670704118e-07, 1.547974004e-06, 2.090386472e-06,
                         2.461280562e-06, 2.735512995e-06, 2.151258631e-06, 1.590518408e-06, 1.123561980e-06,
                         7.352755149e-07, 4.645013036e-07, 3.309607992e-07, 2.251261229e-07, 1.487912927e-07,
                         1.682862336e-07])
# CIE 1931 2-degree colour matching functions x, y, z at 380..780 nm by 20 nm.
_CMF = np.array([[0.001368, 0.000039, 0.006450001], [0.01431, 0.000396, 0.06785001], [0.13438, 0.004, 0.6456],
                 [0.34828, 0.023, 1.74706], [0.2908, 0.06, 1.6692], [0.09564, 0.13902, 0.8129501],
                 [0.0049, 0.323, 0.272], [0.06327, 0.71, 0.07824999], [0.2904, 0.954, 0.0203],
                 [0.5945, 0.995, 0.0039], [0.9163, 0.87, 0.001650001], [1.0622, 0.631, 0.0008],
                 [0.8544499, 0.381, 0.00019], [0.4479, 0.175, 0.00002], [0.1649, 0.061, 0.0],
                 [0.04677, 0.017, 0.0], [0.01135916, 0.004102, 0.0], [0.002899327, 0.001047, 0.0],
                 [0.0006900786, 0.0002492, 0.0], [0.0001661505, 0.00006, 0.0], [0.00004150994, 0.00001499, 0.0]])


def _optical_depth_quadrature() -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Laguerre (8 nodes) along a ray to the top of the atmosphere, its parameter scaled so that x = 25 is the
    ray's end: nodes in [0, 1] of the ray length and weights with the e^x factor folded in."""
    x, w = np.polynomial.laguerre.laggauss(8)
    return x / 25.0, w * np.exp(x) / 25.0


_QUAD_NODES, _QUAD_WEIGHTS = _optical_depth_quadrature()


def _densities(height: np.ndarray) -> np.ndarray:
    """(..., 3) relative densities of air (Rayleigh), aerosol (Mie) and ozone at heights (m) above sea level."""
    return np.stack([np.exp(-height / _RAYLEIGH_SCALE), np.exp(-height / _MIE_SCALE),
                     np.maximum(1.0 - np.abs(height - 25000.0) / 15000.0, 0.0)], -1)


def _to_atmosphere_edge(pos: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Distance from points pos (..., 3) along unit d (..., 3) to the atmosphere's outer sphere."""
    b = 2.0 * np.sum(d * pos, -1)
    c = np.sum(pos * pos, -1) - ATMOSPHERE_RADIUS ** 2
    return 0.5 * (-b + np.sqrt(np.maximum(b * b - 4.0 * c, 0.0)))


def _optical_depth(pos: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(..., 3) optical depth factors (air, aerosol, ozone; m) from pos along d to the top of the atmosphere."""
    length = _to_atmosphere_edge(pos, d)
    depth = np.zeros(pos.shape[:-1] + (3,))
    for node, weight in zip(_QUAD_NODES, _QUAD_WEIGHTS):
        p = pos + (node * length)[..., None] * d
        depth += weight * _densities(np.linalg.norm(p, axis=-1) - EARTH_RADIUS)
    return depth * length[..., None]


def _phases(mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    g2 = _MIE_G * _MIE_G
    rayleigh = 3.0 / (16.0 * math.pi) * (1.0 + mu * mu)
    mie = (3.0 * (1.0 - g2) * (1.0 + mu * mu)) / (8.0 * math.pi * (2.0 + g2) * (1.0 + g2 - 2.0 * _MIE_G * mu) ** 1.5)
    return rayleigh, mie


def _clamp_altitude(altitude: float) -> float:
    return min(max(float(altitude), 1.0), 59999.0)


def single_scattering_xyz(directions: np.ndarray, sun_elevation: float, altitude: float, air: float,
                          aerosol: float, ozone: float) -> np.ndarray:
    """CIE XYZ radiance (N, 3) scattered once towards an observer `altitude` m above sea level, looking along unit
    `directions` (N, 3), the sun at `sun_elevation` (radians) in the +x direction; air, aerosol and ozone scale the
    three densities (Blender's Air, Aerosol/Dust, Ozone)."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    pos0 = np.array([0.0, 0.0, EARTH_RADIUS + _clamp_altitude(altitude)])
    sun = np.array([math.cos(sun_elevation), 0.0, math.sin(sun_elevation)])
    scale = np.array([air, aerosol, ozone], np.float64)
    seg = _to_atmosphere_edge(np.broadcast_to(pos0, d.shape), d) / _MARCH_STEPS
    phase_r, phase_m = _phases(d @ sun)
    depth = np.zeros((d.shape[0], 3))
    spectrum = np.zeros((d.shape[0], _IRRADIANCE.size))
    extinction = np.stack([_RAYLEIGH_COEFF, np.full(_IRRADIANCE.size, 1.11 * _MIE_COEFF), _OZONE_COEFF])  # (3, 21)
    for i in range(_MARCH_STEPS):
        p = pos0 + ((i + 0.5) * seg)[:, None] * d
        density = scale * _densities(np.linalg.norm(p, axis=-1) - EARTH_RADIUS)
        depth += seg[:, None] * density
        # the Earth's shadow: the line towards the sun meets the ground sphere (Blender's test)
        b = 2.0 * (p @ sun)
        c = np.sum(p * p, -1) - EARTH_RADIUS ** 2
        lit = ~((sun[2] < 0.0) & (b * b - 4.0 * c >= 0.0))
        if not np.any(lit):
            continue
        total = depth[lit] + scale * _optical_depth(p[lit], np.broadcast_to(sun, p[lit].shape))
        attenuation = np.exp(-(total @ extinction))  # (n, 21)
        scattering = (density[lit, 0] * phase_r[lit])[:, None] * _RAYLEIGH_COEFF + \
            (density[lit, 1] * phase_m[lit] * _MIE_COEFF)[:, None]
        spectrum[lit] += attenuation * scattering * _IRRADIANCE * seg[lit, None]
    return spectrum @ _CMF * _LAMBDA_STEP


@functools.lru_cache(maxsize=4)
def single_scattering_lut(sun_elevation: float, altitude: float, air: float, aerosol: float,
                          ozone: float) -> np.ndarray:
    """The (256, 512, 3) XYZ look-up table, row 0 at the bottom as Cycles reads it (Blender 5.x's layout): column x
    is the azimuth 2 pi x / 512 - pi from the sun (mirrored about the sun's azimuth); row y the elevation
    +-pi/2 (y / 128 - 1)^2 (more rows near the horizon; row 128 the horizon), the sky computed from row 128 up;
    below it the ground: the horizon's row x (1 - 2.5 sin|elevation|)^3, black from sin|elevation| = 0.4. Seconds
    of CPU: the last few tables are kept (read-only), so that re-exports (the viewport) reuse them."""
    h, w = SKY_LUT_SIZE
    half = h // 2
    rows = np.arange(half, h)
    lat = 0.5 * math.pi * (rows / half - 1.0) ** 2
    lon = 2.0 * math.pi / w * np.arange(w // 2) - math.pi
    cl = np.cos(lat)[:, None]
    d = np.stack([cl * np.cos(lon)[None, :], cl * np.sin(lon)[None, :],
                  np.broadcast_to(np.sin(lat)[:, None], (rows.size, lon.size))], -1)
    xyz = single_scattering_xyz(d.reshape(-1, 3), sun_elevation, altitude, air, aerosol, ozone)
    lut = np.zeros((h, w, 3))
    lut[rows, :w // 2] = xyz.reshape(rows.size, w // 2, 3)
    lut[rows, w // 2:] = lut[rows, :w // 2][:, ::-1]
    below = np.arange(half)
    z = np.sin(0.5 * math.pi * (below / half - 1.0) ** 2)
    fade = np.where(z < 0.4, (1.0 - 2.5 * z) ** 3, 0.0)
    lut[below] = lut[half][None] * fade[:, None, None]
    lut.flags.writeable = False
    return lut


def single_scattering_sun(sun_elevation: float, angular_diameter: float, altitude: float, air: float,
                          aerosol: float) -> tuple[np.ndarray, np.ndarray]:
    """XYZ radiance of the sun's disc at its lowest and highest points (each (3,)): the irradiance spectrum spread
    over the disc's solid angle, attenuated along the path (air and aerosol; black when the disc is below the
    horizon)."""
    half = 0.5 * angular_diameter
    solid_angle = 2.0 * math.pi * (1.0 - math.cos(half))
    pos = np.array([[0.0, 0.0, EARTH_RADIUS + _clamp_altitude(altitude)]])
    out = []
    for el in (max(sun_elevation - half, 0.0), max(sun_elevation + half, 0.0)):
        if sun_elevation + half <= 0.0:
            out.append(np.zeros(3))
            continue
        d = np.array([[math.cos(el), 0.0, math.sin(el)]])
        depth = _optical_depth(pos, d)[0]
        spectrum = _IRRADIANCE * np.exp(-(_RAYLEIGH_COEFF * depth[0] * air + 1.11 * _MIE_COEFF * depth[1] * aerosol))
        out.append(spectrum / solid_angle @ _CMF * _LAMBDA_STEP)
    return out[0], out[1]


def lut_lookup(lut: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup (N, 3) of the (H, W, 3) table (row 0 at v = 0) at texture coordinates x, y in [0, 1], texel
    centres at (i + 0.5) / size, edges extended (Cycles' Linear, Extend)."""
    h, w = lut.shape[:2]
    px, py = x * w - 0.5, y * h - 0.5
    ix, iy = np.floor(px).astype(np.int64), np.floor(py).astype(np.int64)
    tx, ty = (px - ix)[:, None], (py - iy)[:, None]
    x0, x1 = np.clip(ix, 0, w - 1), np.clip(ix + 1, 0, w - 1)
    y0, y1 = np.clip(iy, 0, h - 1), np.clip(iy + 1, 0, h - 1)
    return ((1 - ty) * ((1 - tx) * lut[y0, x0] + tx * lut[y0, x1]) + ty * ((1 - tx) * lut[y1, x0] + tx * lut[y1, x1]))


def wrap_sun_position(elevation: float, rotation: float) -> tuple[float, float]:
    """Blender's Sun Elevation and Rotation as Cycles uses them: the elevation wrapped into [-pi/2, pi/2] (past the
    zenith the sun turns round: rotation + pi), then the rotation wrapped into [0, 2 pi) and mirrored
    (2 pi - rotation)."""
    el = math.fmod(elevation, 2 * math.pi)
    if abs(el) >= math.pi:
        el -= math.copysign(2.0 * math.pi, el)
    rot = rotation
    if el >= math.pi / 2 or el <= -math.pi / 2:
        el = math.copysign(math.pi, el) - el
        rot += math.pi
    rot = math.fmod(rot, 2 * math.pi)
    if rot < 0.0:
        rot += 2 * math.pi
    return el, 2 * math.pi - rot


def sun_direction(elevation: float, rotation: float) -> np.ndarray:
    """Unit direction towards the sun for Cycles' (wrapped) elevation and rotation (see wrap_sun_position)."""
    ce = math.cos(elevation)
    return np.array([-ce * math.sin(rotation), ce * math.cos(rotation), math.sin(elevation)])


def single_scattering_radiance(directions: np.ndarray, lut: np.ndarray, sun_rotation: float) -> np.ndarray:
    """Linear RGB sky radiance (N, 3), without the sun's disc, in unit directions (N, 3) from the look-up table of
    `single_scattering_lut` and Cycles' (wrapped) sun rotation (its ground below the horizon included)."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    z = np.clip(d[:, 2], -1.0, 1.0)
    phi = np.arctan2(d[:, 1], d[:, 0])
    x = np.mod((-phi - 0.5 * math.pi + sun_rotation) / (2.0 * math.pi), 1.0)
    el = 0.5 * math.pi - np.arccos(z)
    y = np.sqrt(np.abs(el) / (0.5 * math.pi)) * np.sign(el) * 0.5 + 0.5
    return np.maximum(lut_lookup(lut, x, y) @ XYZ_TO_LINEAR_RGB.T, 0.0)

MIN_SUN_SIZE = 0.0005  # radians: Cycles' clamp of Sun Size (numerical precision)
_LIMB_DARKENING_MEAN = 0.8  # Cycles' limb darkening 1 - 0.6 (1 - sqrt(1 - r^2)) averaged over the disc


def sun_disc_light(name: str, elevation: float, rotation: float, sun_size: float, intensity: float,
                   altitude: float, air: float, aerosol: float):
    """The sun's disc of the single-scattering sky as a core.scene.SunLight seen by camera rays (its radiance is
    far too concentrated for the baked map), or None when the disc is below the horizon.

    Cycles draws the disc with radiance lerp(bottom, top, height across the disc) x limb darkening x Sun Intensity
    (`single_scattering_sun`); averaged over the disc that is the centre's value x 0.8, and a sun light of
    strength S has radiance S / (pi sin^2(angle / 2)) (core.lights), so S = that radiance x pi sin^2(angle / 2).
    elevation and rotation: Cycles' wrapped values (wrap_sun_position)."""
    from .scene import SunLight

    size = max(float(sun_size), MIN_SUN_SIZE)
    if elevation + 0.5 * size <= 0.0 or not intensity > 0.0:
        return None
    bottom, top = single_scattering_sun(elevation, size, altitude, air, aerosol)
    rgb = np.maximum(0.5 * (bottom + top) @ XYZ_TO_LINEAR_RGB.T, 0.0) * _LIMB_DARKENING_MEAN * intensity
    strength = rgb * math.pi * math.sin(0.5 * size) ** 2
    return SunLight(name=name, direction=-sun_direction(elevation, rotation), strength=strength, angle=size,
                    visible_camera=True)
