"""lab.floor_variance's arithmetic: the variant names and the floor's split by direct light and by distance to the
objects' footprints, on synthetic inputs (its per-pixel variance is lab.error_split's). No bpy, no render."""

from __future__ import annotations

import numpy as np
import pytest

from monte.lab.floor_variance import floor_regions, variant


def test_variant_names():
    assert variant("full") == (16, False)
    assert variant("norr") == (16, True)
    assert variant("b0") == (0, False)
    assert variant("b12") == (12, False)
    for bad in ("b", "bx", "rr", "16"):
        with pytest.raises(ValueError):
            variant(bad)


def test_floor_regions_split_by_direct_light_and_distance():
    h, w = 4, 10
    floor = np.ones((h, w), bool)
    floor[0] = False  # a row of something else
    # positions: x runs 0..9 along the columns, y = 0
    position = np.zeros((h, w, 3))
    position[..., 0] = np.arange(w)[None, :]
    lum = np.ones((h, w))
    lum[:, :3] = 0.01  # columns 0-2 in shadow
    lum[:, 3:5] = 0.3  # columns 3-4 penumbra
    direct = np.repeat(lum[..., None], 3, axis=-1)
    footprint = (np.array([8.0, -1.0, 0.0]), np.array([9.0, 1.0, 1.0]))  # columns 8-9 under an object
    r = floor_regions(position, direct, floor, [footprint], near=1.5)
    assert not (r["lit"] | r["penumbra"] | r["shadow"])[0].any()  # only floor pixels
    assert r["shadow"][1:, :3].all() and not r["shadow"][1:, 3:].any()
    assert r["penumbra"][1:, 3:5].all() and not r["penumbra"][1:, 5:].any()
    assert r["lit"][1:, 5:].all()
    # columns 7 (1 m away), 8, 9 are near; column 6 (2 m) is far
    assert r["near"][1:, 7:].all() and not r["near"][:, :7].any()
    assert (r["near"] ^ r["far"] == floor).all()
