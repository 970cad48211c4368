"""Light portals in the core (core.world.portal_table, core.world_kernels' portal sampling, the world light of
core.light_kernels): the directions through a portal and their pdf against the portal's exact solid angle, and
a diffuse plane under an environment map with a portal above it, whose exact radiance the world sampled through
the portal (and by the map, MIS) must still give."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from monte.core import metrics
from monte.core import world_kernels as wk
from monte.core.render import render
from monte.core.scene import SceneError, World
from monte.core.world import EnvironmentMap, portal_table

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_world import Z, _banded_map, _plane_scene, _upward_irradiance  # noqa: E402


def square_portal(centre=(0.0, 0.0, 1.0), side=1.0, inward=(0.0, 0.0, -1.0)) -> np.ndarray:
    """(1, 4, 3): a horizontal square portal letting the world in downwards."""
    return np.array([[centre, (side, 0.0, 0.0), (0.0, side, 0.0), inward]], dtype=np.float64)


def rectangle_solid_angle(a: float, b: float, d: float) -> float:
    """Solid angle of a 2a x 2b rectangle seen from distance d above its centre."""
    return 4.0 * math.asin(a * b / math.sqrt((a * a + d * d) * (b * b + d * d)))


def sample(table, points, n=1 << 15, seed=3):
    rng = np.random.default_rng(seed)
    p = np.repeat(np.asarray(points, np.float64).reshape(-1, 3), n, axis=0)
    u = rng.random((len(p), 2))
    d, pdf = np.empty((len(p), 3)), np.empty(len(p))
    wk.portal_sample_batch(table, p, u, d, pdf)
    return p, d, pdf


def test_directions_through_a_portal_and_their_pdf():
    """From below the square, E[1 / pdf] over its sampled directions is its solid angle (and each direction
    hits it); from above (outside) no portal faces the point; two portals split the samples."""
    table = portal_table(square_portal(), np.zeros(3))
    p, d, pdf = sample(table, (0.0, 0.0, 0.0))
    exact = rectangle_solid_angle(0.5, 0.5, 1.0)
    inv = 1.0 / pdf
    assert abs(inv.mean() - exact) < 5 * inv.std() / math.sqrt(len(inv))
    assert inv.std() / inv.mean() < 0.5  # area sampling of a square seen square-on: nearly the solid angle's
    t = 1.0 / d[:, 2]
    hit = p + t[:, None] * d
    assert np.abs(hit[:, :2]).max() <= 0.5 + 1e-9 and (d[:, 2] > 0).all()
    _, _, outside = sample(table, (0.0, 0.0, 2.0), n=16)
    assert (outside == 0).all()
    # Two portals (the second shifted, both above): each sample goes through one; E[1/pdf] is no longer a solid
    # angle, but the pdf of a direction through both squares' union still integrates to 1: check by the estimator
    # of the union's solid angle.
    two = portal_table(np.concatenate([square_portal(), square_portal(centre=(2.0, 0.0, 1.0))]), np.zeros(3))
    _, _, pdf2 = sample(two, (0.0, 0.0, 0.0))
    union = exact + _offset_square_solid_angle()
    inv2 = 1.0 / pdf2
    assert abs(inv2.mean() - union) < 5 * inv2.std() / math.sqrt(len(inv2))


def _offset_square_solid_angle() -> float:
    """Solid angle from the origin of the unit square centred at (2, 0, 1), by the rectangle formula's
    corner decomposition (a rectangle [x0, x1] x [y0, y1] at height d from its corner terms)."""
    def corner(x, y, d=1.0):
        return math.atan2(x * y, d * math.sqrt(x * x + y * y + d * d))
    x0, x1, y0, y1 = 1.5, 2.5, -0.5, 0.5
    return corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0)


def test_portal_table_follows_the_integrator_shift():
    table = portal_table(square_portal(centre=(10.0, 0.0, 1.0)), np.array([10.0, 0.0, 0.0]))
    assert np.allclose(table[0, wk.P_CX:wk.P_CX + 3], (-0.5, -0.5, 1.0))
    assert table[0, wk.P_AREA] == pytest.approx(1.0)
    assert portal_table(None, np.zeros(3)).shape == (0, wk.P_FIELDS)


@pytest.mark.parametrize("mode", ["mis", "light"])
def test_a_portal_keeps_the_plane_under_a_map_exact(fast_settings, mode):
    """A 0.6 m square portal 0.5 m above the plane (the camera's view of the plane lies under it): half of the
    world samples go through it, the rest follow the map, MIS-weighted by the mixture's pdf: the plane's radiance
    is still the exact integral."""
    px = _banded_map()
    env = EnvironmentMap(px, interpolation="CLOSEST", map_resolution=32)
    world = World(environment=env, portals=square_portal(centre=(0.0, 0.0, 0.5), side=0.6))
    result = render(_plane_scene(world), fast_settings(spp=128, light_sampling=mode, max_bounces=1))
    expected = 0.8 * _upward_irradiance(px) / math.pi
    mean, sigma = metrics.channel_means(result.color), metrics.channel_mean_sigma(result.variance)
    assert np.all(np.abs(mean - expected) <= Z * sigma), (mode, mean, expected, sigma)
    assert np.all(Z * sigma < 0.02 * expected), Z * sigma / expected


def test_bad_portals_are_named():
    world = World(color=np.ones(3), portals=np.zeros((1, 3, 3)))
    scene = _plane_scene_with(world)
    with pytest.raises(SceneError, match=r"world portals must be a finite \(P, 4, 3\) array"):
        scene.validate()
    flat = square_portal()
    flat[0, 2] = 0.0  # no second edge: no area
    scene = _plane_scene_with(World(color=np.ones(3), portals=flat)).validate()
    assert scene.world.portals is None and "1 light portal(s) of zero area are ignored" in scene.warnings


def _plane_scene_with(world):
    from monte.core import builtin_scenes as scenes

    scene = scenes.plane_under_world((8, 8), albedo=0.8, world=1.0)
    scene.world = world
    return scene
