"""Two renders' images compared bit for bit, for tests that change how a render is scheduled or summed (threads,
tiles, windows of films) and not what it computes."""

from __future__ import annotations

import numpy as np

IMAGES = ("color", "variance", "albedo", "normal", "depth", "sample_count", "denoising_albedo", "denoising_normal")


def assert_same_images(a, b, names: tuple[str, ...] = IMAGES) -> None:
    """Each named image of RenderResult `a` equals `b`'s bit for bit (NaNs where b has them), or both are None."""
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert np.array_equal(x, y, equal_nan=True), name
