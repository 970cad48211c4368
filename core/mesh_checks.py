"""Triangle checks of scene validation (core.scene): which triangles have finite corners and a non-zero area.

Compiled (numba): one pass over the triangles instead of a (T, 3, 3) gather and a dozen NumPy reductions, which
dominated validating large instanced meshes.
"""

from __future__ import annotations

import math

from .jit_cache import jit as _jit


@_jit
def triangle_checks(vertices, triangles, finite, area2, edge):
    """Per triangle of float64 vertices (V, 3) and int64 indices (T, 3): finite[t] (all 9 coordinates finite),
    area2[t] = |(b - a) x (c - a)| (twice the area) and edge[t] = the largest |coordinate difference| of b and c
    from a. One pass instead of a (T, 3, 3) gather and a dozen NumPy reductions (scene validation of large
    instanced meshes)."""
    for t in range(triangles.shape[0]):
        i0, i1, i2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        ok = True
        e = 0.0
        for c in range(3):
            a, b, d = vertices[i0, c], vertices[i1, c], vertices[i2, c]
            if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(d)):
                ok = False
            e = max(e, abs(b - a), abs(d - a))
        finite[t] = ok
        edge[t] = e
        ux, uy, uz = vertices[i1, 0] - vertices[i0, 0], vertices[i1, 1] - vertices[i0, 1], vertices[i1, 2] - vertices[i0, 2]
        vx, vy, vz = vertices[i2, 0] - vertices[i0, 0], vertices[i2, 1] - vertices[i0, 1], vertices[i2, 2] - vertices[i0, 2]
        cx, cy, cz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        area2[t] = math.sqrt(cx * cx + cy * cy + cz * cz)
