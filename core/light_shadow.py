"""Lights whose Cast Shadow is off (`cast_shadow = False` on a core light): which light samples came from them.

Cycles traces no shadow ray for such a light's samples (next-event estimation sees it unoccluded), while rays
that BSDF sampling sends towards it are blocked as usual. The light sampler does not report which light a
sample came from, so the sampled point is matched to the lights geometrically: on a point or spot light's sphere
(its centre for radius 0), in an area light's rectangle (its bounding rectangle for a disk or an ellipse), or,
for samples at infinity, inside a sun's cone. Two lights would have to overlap for a sample to be matched to the
wrong one. Only scenes with such a light pay for this (NoShadowLights.build returns None otherwise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .scene import AreaLight, PointLight, SpotLight, SunLight


@dataclass
class NoShadowLights:
    """The lights that cast no shadow, in the integrator's shifted frame (float64)."""

    spheres: np.ndarray  # (S, 4): centre x, y, z, radius of point and spot lights
    areas: np.ndarray  # (A, 4, 4): world-to-light matrices of area lights (shifted frame)
    area_half: np.ndarray  # (A, 2): half sizes along the light's local x and y
    suns: np.ndarray  # (U, 4): direction towards the sun x, y, z, cos of half its angle

    @classmethod
    def build(cls, lights: list, shift: np.ndarray) -> "NoShadowLights | None":
        return cls.of([lt for lt in lights if not getattr(lt, "cast_shadow", True)], shift)

    @classmethod
    def of(cls, chosen: list, shift: np.ndarray) -> "NoShadowLights | None":
        """The geometric matcher of the lights `chosen` (None when empty); core.light_linking uses it to tell
        which light samples came from shadow-linked lights."""
        if not chosen:
            return None
        shift = np.asarray(shift, np.float64)
        spheres, areas, halves, suns = [], [], [], []
        for lt in chosen:
            if isinstance(lt, (PointLight, SpotLight)):
                spheres.append([*(np.asarray(lt.position, np.float64) - shift), float(lt.radius)])
            elif isinstance(lt, AreaLight):
                m = np.array(lt.matrix_world, np.float64).reshape(4, 4)
                m[:3, 3] -= shift
                areas.append(np.linalg.inv(m))
                sy = lt.size_y if lt.shape in ("RECTANGLE", "ELLIPSE") else lt.size_x
                halves.append([0.5 * lt.size_x, 0.5 * sy])
            elif isinstance(lt, SunLight):
                d = -np.asarray(lt.direction, np.float64)
                suns.append([*(d / np.linalg.norm(d)), math.cos(0.5 * float(lt.angle))])
        return cls(np.array(spheres, np.float64).reshape(-1, 4), np.array(areas, np.float64).reshape(-1, 4, 4),
                   np.array(halves, np.float64).reshape(-1, 2), np.array(suns, np.float64).reshape(-1, 4))

    def matches(self, p: np.ndarray, wi: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """(N,) bool: the light samples (from points p (N, 3), towards unit wi (N, 3), at distance dist (N,),
        inf for lights at infinity) that lie on one of these lights."""
        p64, w64 = np.asarray(p, np.float64), np.asarray(wi, np.float64)
        d = np.asarray(dist, np.float64)
        far = ~np.isfinite(d)
        q = p64 + w64 * np.where(far, 0.0, d)[:, None]
        # float32 positions and directions: a tolerance relative to the distance travelled and the coordinates
        tol = 1e-4 * (np.where(far, 0.0, d) + np.abs(q).max(axis=1) + 1e-3)
        hit = np.zeros(len(d), bool)
        for cx, cy, cz, r in self.spheres:
            off = np.sqrt((q[:, 0] - cx) ** 2 + (q[:, 1] - cy) ** 2 + (q[:, 2] - cz) ** 2)
            hit |= ~far & (off <= r * (1 + 1e-4) + tol)
        for inv, (hx, hy) in zip(self.areas, self.area_half):
            local = q @ inv[:3, :3].T + inv[:3, 3]
            scale = np.linalg.norm(inv[:3, :3], axis=1)  # local units per world unit, per axis
            hit |= (~far & (np.abs(local[:, 0]) <= hx + tol * scale[0]) & (np.abs(local[:, 1]) <= hy + tol * scale[1])
                    & (np.abs(local[:, 2]) <= tol * scale[2]))
        for sx, sy, sz, cos_half in self.suns:
            hit |= far & (w64[:, 0] * sx + w64[:, 1] * sy + w64[:, 2] * sz >= min(cos_half, 1.0 - 1e-7) - 1e-6)
        return hit
