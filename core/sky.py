"""Blender's Sky Texture models evaluated per direction and baked into an environment map: Preetham (analytic)
and Single Scattering (Nishita's atmosphere, Blender 4.x's "Nishita"), with that one's sun disc as a sun light.
Multiple Scattering (Blender 5.x), a spectral atmosphere with a fitted multiple-scattering term, tabulated as
Cycles does (see its section below). Hosek-Wilkie (analytic, from its published fitted coefficients in
core.hosek_wilkie_data; see its section below).

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
           "wrap_sun_position", "sun_direction", "multiple_scattering_xyz", "multiple_scattering_lut",
           "multiple_scattering_sun", "multiple_scattering_transmittance", "earth_horizon_dip",
           "hosek_wilkie_state", "hosek_wilkie_radiance"]

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


# ------------------------------------------------------------------------------------------ Hosek-Wilkie
# "An Analytic Model for Full Spectral Sky-Dome Radiance" (Hosek and Wilkie 2012), its CIE XYZ version as Cycles
# evaluates it: per channel F(theta, gamma) = (1 + A exp(B / (cos theta + 0.01))) (C + D exp(E gamma) + F cos^2
# gamma + G (1 + cos^2 gamma) / (1 + I^2 - 2 I cos gamma)^1.5 + H sqrt(cos theta)) times the channel's radiance;
# A..I and the radiance from the published fit (core.hosek_wilkie_data): a quintic Bezier curve over (solar
# elevation / (pi / 2))^(1/3), linear between integer turbidities and between ground albedo 0 and 1. Cycles
# scales the XYZ result by 2 pi / 683 and clamps negative RGB to 0; the view angle stops 0.001 rad above the
# horizon (the lower hemisphere repeats the horizon), the sun's elevation is clamped to 0..pi/2.
_HW_VIEW_CLAMP = 0.001  # radians above the horizon
_HW_SCALE = 2.0 * math.pi / 683.0


@functools.lru_cache(maxsize=1)
def _hosek_wilkie_tables() -> tuple[np.ndarray, np.ndarray]:
    from . import hosek_wilkie_data as data

    return (np.array(data.CONFIGURATION, np.float64).reshape(data.CONFIGURATION_SHAPE),
            np.array(data.RADIANCE, np.float64).reshape(data.RADIANCE_SHAPE))


def _bezier5(points: np.ndarray, t: float) -> np.ndarray:
    """The quintic Bezier curve of control points along axis -2 of `points` (..., 6, k) at t in [0, 1]."""
    weights = np.array([math.comb(5, k) * (1.0 - t) ** (5 - k) * t ** k for k in range(6)])
    return np.einsum("k,...kj->...j", weights, points)


def hosek_wilkie_state(turbidity: float, ground_albedo: float, sun_elevation: float) -> tuple[np.ndarray, np.ndarray]:
    """(configuration (3, 9): A..I per X, Y, Z channel; radiance (3,)) for `turbidity` (clamped to 1..10),
    `ground_albedo` (0..1) and the sun `sun_elevation` radians above the horizon (clamped to 0..pi/2)."""
    config, radiance = _hosek_wilkie_tables()
    turbidity = min(max(float(turbidity), 1.0), 10.0)
    albedo = min(max(float(ground_albedo), 0.0), 1.0)
    t = (min(max(float(sun_elevation), 0.0), 0.5 * math.pi) / (0.5 * math.pi)) ** (1.0 / 3.0)
    low = int(turbidity)
    rest = turbidity - low
    out_config, out_radiance = np.zeros((3, 9)), np.zeros(3)
    for albedo_index, albedo_weight in ((0, 1.0 - albedo), (1, albedo)):
        for turb, turb_weight in ((low, 1.0 - rest), (min(low + 1, 10), rest if low < 10 else 0.0)):
            w = albedo_weight * turb_weight
            if w == 0.0:
                continue
            out_config += w * _bezier5(config[:, albedo_index, turb - 1], t)
            out_radiance += w * _bezier5(radiance[:, albedo_index, turb - 1, :, None], t)[:, 0]
    return out_config, out_radiance


def hosek_wilkie_radiance(directions: np.ndarray, sun_direction, turbidity: float,
                          ground_albedo: float) -> np.ndarray:
    """Linear RGB radiance (N, 3) of the Hosek-Wilkie sky in unit world directions (N, 3), for the sun in
    `sun_direction` (any length > 0; Blender's Sun Direction), `turbidity` and `ground_albedo` (Blender's)."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    s = np.asarray(sun_direction, np.float64).reshape(3)
    n = float(np.linalg.norm(s))
    s = s / n if n > 0 else np.array([0.0, 0.0, 1.0])
    sun_elevation = 0.5 * math.pi - math.acos(min(max(s[2], -1.0), 1.0))
    config, radiance = hosek_wilkie_state(turbidity, ground_albedo, sun_elevation)
    cos_gamma = np.clip(d @ s, -1.0, 1.0)
    gamma = np.arccos(cos_gamma)
    theta = np.minimum(np.arccos(np.clip(d[:, 2], -1.0, 1.0)), 0.5 * math.pi - _HW_VIEW_CLAMP)
    cos_theta = np.cos(theta)[:, None]
    a, b, c, dd, e, f, g, h, i = (config[:, k][None, :] for k in range(9))
    cg = cos_gamma[:, None]
    mie = (1.0 + cg * cg) / (1.0 + i * i - 2.0 * i * cg) ** 1.5
    xyz = (1.0 + a * np.exp(b / (cos_theta + 0.01))) * \
        (c + dd * np.exp(e * gamma[:, None]) + f * cg * cg + g * mie + h * np.sqrt(cos_theta)) * radiance
    rgb = xyz @ XYZ_TO_LINEAR_RGB.T * _HW_SCALE
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
    `single_scattering_lut` (or `multiple_scattering_lut`: the same layout) and Cycles' (wrapped) sun rotation
    (its ground below the horizon included)."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    z = np.clip(d[:, 2], -1.0, 1.0)
    phi = np.arctan2(d[:, 1], d[:, 0])
    x = np.mod((-phi - 0.5 * math.pi + sun_rotation) / (2.0 * math.pi), 1.0)
    el = 0.5 * math.pi - np.arccos(z)
    y = np.sqrt(np.abs(el) / (0.5 * math.pi)) * np.sign(el) * 0.5 + 0.5
    return np.maximum(lut_lookup(lut, x, y) @ XYZ_TO_LINEAR_RGB.T, 0.0)

MIN_SUN_SIZE = 0.0005  # radians: Cycles' clamp of Sun Size (numerical precision)
_LIMB_DARKENING_MEAN = 0.8  # Cycles' limb darkening 1 - 0.6 (1 - sqrt(1 - r^2)) averaged over the disc


# ------------------------------------------------------------------------------------------ multiple scattering
# Blender 5.x's "Multiple Scattering" sky (Fernando Garcia Linan's spectral model, as Cycles bakes it): a spherical
# Earth (6371 km) under a 100 km atmosphere; air (Rayleigh, a fitted height profile), aerosols (absorbing and
# scattering, Henyey-Greenstein-like phase with g = 0.8, 0.73 km scale height over a background density) and ozone
# (absorbing, a log-normal profile); four wavelengths (630, 560, 490, 430 nm) mapped to XYZ by a fitted matrix.
# Single scattering towards the sun is integrated along each view ray (64 steps, each step integrated analytically
# in its extinction); multiple scattering is a fitted term plus second-order light from a grey (0.3) ground. Unlike
# the single-scattering sky the view ray below the horizon is integrated up to the ground, so the lower half of the
# table is computed, not faded. Lengths in km inside this model.
MS_EARTH_RADIUS = 6371.0  # km
MS_ATMOSPHERE_THICKNESS = 100.0  # km
_MS_ATMOSPHERE_RADIUS = MS_EARTH_RADIUS + MS_ATMOSPHERE_THICKNESS
_MS_STEPS = 64  # ray-marching steps, for the transmittance table and along each view ray
_MS_TRANSMITTANCE_SIZE = (64, 256)  # (normalized altitude 0..1, cos(sun zenith) -1..1), both ends on texels
_MS_GROUND_ALBEDO = 0.3
_MS_AEROSOL_G = 0.8
_MS_SUN_IRRADIANCE = np.array([1.679, 1.828, 1.986, 1.307])  # at 630, 560, 490, 430 nm
_MS_RAYLEIGH_BASE = np.array([6.605e-3, 1.067e-2, 1.842e-2, 3.156e-2])  # 1/km at sea level
_MS_OZONE_CROSS_SECTION = np.array([3.472e-25, 3.914e-25, 1.349e-25, 11.03e-27])
_MS_OZONE_DOBSON = 334.5
_MS_AEROSOL_ABSORPTION = np.array([2.8722e-24, 4.6168e-24, 7.9706e-24, 1.3578e-23])
_MS_AEROSOL_SCATTERING = np.array([1.5908e-22, 1.7711e-22, 2.0942e-22, 2.4033e-22])
_MS_AEROSOL_DENSITY = 1.3681e20
_MS_AEROSOL_BACKGROUND = 2e6
_MS_AEROSOL_SCALE = 0.73  # km
_MS_FITTED_MULTIPLE = 0.02 * np.array([0.217, 0.347, 0.594, 1.0])
# The four wavelengths' radiance -> CIE XYZ (rows: wavelengths).
_MS_SPECTRAL_TO_XYZ = np.array([[53.386917738564668, 22.981337506691025, 0.0],
                                [43.904844466369358, 71.347795700053394, 0.102506867965741],
                                [1.6137278251608962, 18.422960591455485, 31.742921188390806],
                                [20.762668673810577, 2.3614213523314369, 110.48009643252140]])


def _ray_sphere_distance(pos: np.ndarray, d: np.ndarray, radius: float) -> np.ndarray:
    """Distance along unit d (..., 3) from pos (..., 3) to the sphere of `radius` about the origin: the exit from
    inside, the nearer hit from outside, -1 when missed or behind."""
    b = np.sum(pos * d, -1)
    c = np.sum(pos * pos, -1) - radius * radius
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    t = np.where(c <= 0.0, -b + root, -b - root)
    return np.where(((c > 0.0) & (b > 0.0)) | (disc < 0.0), -1.0, t)


def _ms_collision(height: np.ndarray, air: float, aerosol: float, ozone: float):
    """(molecular scattering, aerosol scattering, total extinction), each (..., 4) in 1/km, at heights (...) km."""
    h = np.maximum(height, 0.0)[..., None]
    molecular = air * _MS_RAYLEIGH_BASE * np.exp(-0.07771971 * h ** 1.16364243)
    log_h = np.log(np.maximum(h, 1e-4))
    ozone_density = 3.78547397e20 * np.exp(-(log_h - 3.22261) ** 2 * 5.55555555 - log_h)
    ozone_absorption = ozone * _MS_OZONE_CROSS_SECTION * _MS_OZONE_DOBSON * ozone_density
    particles = aerosol * _MS_AEROSOL_DENSITY * (np.exp(-h / _MS_AEROSOL_SCALE)
                                                 + _MS_AEROSOL_BACKGROUND / _MS_AEROSOL_DENSITY)
    aerosol_scattering = _MS_AEROSOL_SCATTERING * particles
    extinction = molecular + ozone_absorption + aerosol_scattering + _MS_AEROSOL_ABSORPTION * particles
    return molecular, aerosol_scattering, extinction


def multiple_scattering_transmittance(cos_zenith: np.ndarray, normalized_altitude: np.ndarray, air: float,
                                      aerosol: float, ozone: float) -> np.ndarray:
    """(..., 4) transmittance from `normalized_altitude` (0 ground .. 1 top of the atmosphere) towards a direction
    whose cosine from the zenith is `cos_zenith` to the top of the atmosphere (the ground is not an obstacle: rays
    below the horizon run through the lowest air, as the model's table does)."""
    cz = np.asarray(cos_zenith, np.float64)
    na = np.broadcast_to(np.asarray(normalized_altitude, np.float64), cz.shape)
    d = np.stack([-np.sqrt(np.maximum(1.0 - cz * cz, 0.0)), np.zeros_like(cz), cz], -1)
    origin = np.zeros(cz.shape + (3,))
    origin[..., 2] = MS_EARTH_RADIUS + na * MS_ATMOSPHERE_THICKNESS
    length = _ray_sphere_distance(origin, d, _MS_ATMOSPHERE_RADIUS)
    step = length / _MS_STEPS
    depth = np.zeros(cz.shape + (4,))
    for i in range(_MS_STEPS):
        p = origin + ((i + 0.5) * step)[..., None] * d
        depth += _ms_collision(np.linalg.norm(p, axis=-1) - MS_EARTH_RADIUS, air, aerosol, ozone)[2]
    return np.exp(-depth * step[..., None])


class _TransmittanceTable:
    """The model's transmittance table (64 altitudes x 256 zenith cosines, both ranges' ends on texels) and its
    bilinear lookup."""

    def __init__(self, air: float, aerosol: float, ozone: float):
        rows, cols = _MS_TRANSMITTANCE_SIZE
        cz = np.linspace(-1.0, 1.0, cols)[None, :]
        na = np.linspace(0.0, 1.0, rows)[:, None]
        self.table = multiple_scattering_transmittance(np.broadcast_to(cz, (rows, cols)), na, air, aerosol, ozone)

    def __call__(self, cos_zenith: np.ndarray, normalized_altitude: np.ndarray) -> np.ndarray:
        rows, cols = _MS_TRANSMITTANCE_SIZE
        x = (cols - 1) * np.clip(0.5 * cos_zenith + 0.5, 0.0, 1.0)
        y = (rows - 1) * np.clip(normalized_altitude, 0.0, 1.0)
        x0, y0 = np.minimum(x.astype(np.int64), cols - 2), np.minimum(y.astype(np.int64), rows - 2)
        fx, fy = (x - x0)[..., None], (y - y0)[..., None]
        flat = self.table.reshape(-1, 4)
        i = y0 * cols + x0
        low = flat.take(i, 0) * (1.0 - fx) + flat.take(i + 1, 0) * fx
        high = flat.take(i + cols, 0) * (1.0 - fx) + flat.take(i + cols + 1, 0) * fx
        return low * (1.0 - fy) + high * fy

    def at_ground(self, cos_zenith: np.ndarray) -> np.ndarray:
        """The lookup at altitude 0 (along the table's first row)."""
        cols = _MS_TRANSMITTANCE_SIZE[1]
        x = (cols - 1) * np.clip(0.5 * cos_zenith + 0.5, 0.0, 1.0)
        x0 = np.minimum(x.astype(np.int64), cols - 2)
        fx = (x - x0)[..., None]
        return self.table[0].take(x0, 0) * (1.0 - fx) + self.table[0].take(x0 + 1, 0) * fx

    def towards_zenith(self, normalized_altitude: np.ndarray) -> np.ndarray:
        """The lookup straight up (along the table's last column)."""
        rows = _MS_TRANSMITTANCE_SIZE[0]
        y = (rows - 1) * np.clip(normalized_altitude, 0.0, 1.0)
        y0 = np.minimum(y.astype(np.int64), rows - 2)
        fy = (y - y0)[..., None]
        column = self.table[:, -1]
        return column.take(y0, 0) * (1.0 - fy) + column.take(y0 + 1, 0) * fy


def _ms_light_from_elsewhere(table: _TransmittanceTable, cos_sun: np.ndarray, normalized_altitude: np.ndarray,
                             centre_distance: np.ndarray) -> np.ndarray:
    """(..., 4) the model's multiple-scattering source (per unit scattering coefficient): the fitted term for
    light scattered more than once in the air plus the ground's second-order light (the sunlit grey ground seen
    through the air below the point, spread isotropically over the solid angle the Earth fills)."""
    omega = 2.0 * math.pi * (1.0 - np.sqrt(1.0 - (MS_EARTH_RADIUS / centre_distance) ** 2))
    to_ground = table.at_ground(cos_sun)
    ground_to_point = table.table[0, -1] / table.towards_zenith(normalized_altitude)
    ground = ((omega / (4.0 * math.pi)) * cos_sun)[..., None] * (_MS_GROUND_ALBEDO / math.pi) * to_ground * \
        ground_to_point
    fitted = _MS_FITTED_MULTIPLE / (1.0 + 5.0 * np.exp(-17.92 * cos_sun))[..., None]
    return fitted + ground


def multiple_scattering_xyz(directions: np.ndarray, sun_elevation: float, altitude: float, air: float,
                            aerosol: float, ozone: float) -> np.ndarray:
    """CIE XYZ radiance (N, 3) reaching an observer `altitude` m above sea level (clamped to 1..99999 m) along
    unit `directions` (N, 3), without the sun's disc, the sun at `sun_elevation` (radians) towards -x; air,
    aerosol and ozone scale the three densities (Blender's Air, Aerosol, Ozone). Below the horizon the light
    scattered between the observer and the ground (the ground itself is not seen)."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    elevation = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
    azimuth = np.arctan2(d[:, 1], d[:, 0])
    return _ms_inscattering(elevation, azimuth, sun_elevation, altitude, air, aerosol, ozone)


def _ms_inscattering(elevation: np.ndarray, azimuth: np.ndarray, sun_elevation: float, altitude: float,
                     air: float, aerosol: float, ozone: float) -> np.ndarray:
    """multiple_scattering_xyz for view directions at `elevation` and `azimuth` (radians, from +x towards +y),
    arrays that broadcast together (shape S): what depends on the elevation alone (the heights along the ray, the
    extinction) is computed at the elevations' shape, so a grid (elevations (H, 1), azimuths (1, W)) costs little
    more than its table lookups. Returns S + (3,)."""
    table = _TransmittanceTable(air, aerosol, ozone)
    r0 = MS_EARTH_RADIUS + min(max(float(altitude), 1.0), 99999.0) / 1000.0
    sin_el, cos_el = np.sin(elevation), np.cos(elevation)
    sin_sun, cos_sun_el = math.sin(sun_elevation), math.cos(sun_elevation)
    origin = np.stack([np.zeros_like(sin_el), np.zeros_like(sin_el), np.full_like(sin_el, r0)], -1)
    up_down = np.stack([cos_el, np.zeros_like(sin_el), sin_el], -1)  # the ray turned into the x-z plane
    to_ground = _ray_sphere_distance(origin, up_down, MS_EARTH_RADIUS)
    length = np.where(to_ground < 0.0, _ray_sphere_distance(origin, up_down, _MS_ATMOSPHERE_RADIUS), to_ground)
    step = length / _MS_STEPS
    d_dot_sun = -cos_el * np.cos(azimuth) * cos_sun_el + sin_el * sin_sun  # view direction . sun direction
    mu = -d_dot_sun  # the cosine the model's phase functions take
    phase_molecular = (3.0 / (16.0 * math.pi) * (1.0 + mu * mu))[..., None]
    g = _MS_AEROSOL_G
    den = 1.0 + g * g + 2.0 * g * mu
    phase_aerosol = ((1.0 - g * g) / (4.0 * math.pi * den * np.sqrt(den)))[..., None]
    shape = np.broadcast_shapes(sin_el.shape, d_dot_sun.shape)
    radiance = np.zeros(shape + (4,))
    through = np.ones(shape + (4,))
    for i in range(_MS_STEPS):
        t = (i + 0.5) * step
        r = np.sqrt(r0 * r0 + 2.0 * t * r0 * sin_el + t * t)
        h = np.maximum(r - MS_EARTH_RADIUS, 0.0)
        cos_sun = (r0 * sin_sun + t * d_dot_sun) / r  # the sun's cosine from the local zenith
        molecular, aerosol_scattering, extinction = _ms_collision(h, air, aerosol, ozone)
        to_sun = table(cos_sun, np.broadcast_to(h / MS_ATMOSPHERE_THICKNESS, shape))
        elsewhere = _ms_light_from_elsewhere(table, cos_sun, h / MS_ATMOSPHERE_THICKNESS, r)
        source = _MS_SUN_IRRADIANCE * (molecular * (phase_molecular * to_sun + elsewhere)
                                       + aerosol_scattering * (phase_aerosol * to_sun + elsewhere))
        step_through = np.exp(-step[..., None] * extinction)
        # the step's in-scattering integrated exactly for a constant source and extinction
        radiance += through * source * (1.0 - step_through) / np.maximum(extinction, 1e-7)
        through = through * step_through
    return radiance @ _MS_SPECTRAL_TO_XYZ


@functools.lru_cache(maxsize=4)
def multiple_scattering_lut(sun_elevation: float, altitude: float, air: float, aerosol: float,
                            ozone: float) -> np.ndarray:
    """The (256, 512, 3) XYZ look-up table of the multiple-scattering sky, row 0 at the bottom as Cycles reads it:
    column x at azimuth 2 pi (x + 0.5) / 512 with the sun at azimuth pi (mirrored about it), row y at elevation
    sign(l) l^2 pi / 2 with l = 2 (y + 0.5) / 256 - 1 (more rows near the horizon), the lower half computed too.
    `sun_elevation` is Cycles' wrapped value (wrap_sun_position). Seconds of CPU: the last few tables are kept
    (read-only)."""
    h, w = SKY_LUT_SIZE
    az = 2.0 * math.pi * (np.arange(w // 2) + 0.5) / w
    lv = 2.0 * (np.arange(h) + 0.5) / h - 1.0
    el = np.sign(lv) * lv * lv * 0.5 * math.pi
    xyz = _ms_inscattering(el[:, None], az[None, :], sun_elevation, altitude, air, aerosol, ozone)
    lut = np.concatenate([xyz, xyz[:, ::-1]], axis=1)
    lut.flags.writeable = False
    return lut


def multiple_scattering_sun(sun_elevation: float, angular_diameter: float, altitude: float, air: float,
                            aerosol: float, ozone: float) -> tuple[np.ndarray, np.ndarray]:
    """XYZ radiance of the multiple-scattering sky's sun disc at its lowest and highest points (each (3,)): the
    four wavelengths' irradiance over the disc's solid angle, times the transmittance from the observer towards
    each point (not cut by the horizon here: see earth_horizon_dip)."""
    half = 0.5 * angular_diameter
    solid_angle = 2.0 * math.pi * (1.0 - math.cos(half))
    height = min(max(float(altitude), 1.0), 99999.0) / 1000.0 / MS_ATMOSPHERE_THICKNESS
    out = []
    for el in (sun_elevation - half, sun_elevation + half):
        t = multiple_scattering_transmittance(np.array(math.sin(el)), np.array(height), air, aerosol, ozone)
        out.append(_MS_SUN_IRRADIANCE * t / solid_angle @ _MS_SPECTRAL_TO_XYZ)
    return out[0], out[1]


def earth_horizon_dip(altitude: float) -> float:
    """Radians by which the Earth's horizon lies below the horizontal for an observer `altitude` m above sea level
    (the multiple-scattering sky hides its sun disc below it)."""
    return math.pi / 2 - math.asin(MS_EARTH_RADIUS / (MS_EARTH_RADIUS + max(float(altitude), 0.0) / 1000.0))


def sun_disc_light(name: str, elevation: float, rotation: float, sun_size: float, intensity: float,
                   altitude: float, air: float, aerosol: float, ozone: float = 1.0,
                   multiple_scattering: bool = False):
    """The sun's disc of a scattering sky (single by default, or multiple) as a core.scene.SunLight seen by camera
    rays (its radiance is far too concentrated for the baked map), or None when the disc is below the horizon (the
    multiple-scattering sky's horizon lies earth_horizon_dip(altitude) below the horizontal).

    Cycles draws the disc with radiance lerp(bottom, top, height across the disc) x limb darkening x Sun Intensity
    (`single_scattering_sun` / `multiple_scattering_sun`); averaged over the disc that is the centre's value x 0.8,
    and a sun light of strength S has radiance S / (pi sin^2(angle / 2)) (core.lights), so S = that radiance x
    pi sin^2(angle / 2). elevation and rotation: Cycles' wrapped values (wrap_sun_position)."""
    from .scene import SunLight

    size = max(float(sun_size), MIN_SUN_SIZE)
    horizon = -earth_horizon_dip(altitude) if multiple_scattering else 0.0
    if elevation + 0.5 * size <= horizon or not intensity > 0.0:
        return None
    if multiple_scattering:
        bottom, top = multiple_scattering_sun(elevation, size, altitude, air, aerosol, ozone)
    else:
        bottom, top = single_scattering_sun(elevation, size, altitude, air, aerosol)
    rgb = np.maximum(0.5 * (bottom + top) @ XYZ_TO_LINEAR_RGB.T, 0.0) * _LIMB_DARKENING_MEAN * intensity
    strength = rgb * math.pi * math.sin(0.5 * size) ** 2
    return SunLight(name=name, direction=-sun_direction(elevation, rotation), strength=strength, angle=size,
                    visible_camera=True)
