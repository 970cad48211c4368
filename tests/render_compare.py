"""Two renders' images compared bit for bit, for tests that change how a render is scheduled or summed (threads,
tiles, windows of films) and not what it computes."""

from __future__ import annotations

from typing import Callable

import numpy as np

IMAGES = ("color", "variance", "albedo", "normal", "depth", "sample_count", "denoising_albedo", "denoising_normal")


def assert_same_images(a, b, names: tuple[str, ...] = IMAGES) -> None:
    """Each named image of RenderResult `a` equals `b`'s bit for bit (NaNs where b has them), or both are None."""
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert np.array_equal(x, y, equal_nan=True), name


def tile_recorder() -> tuple[list, Callable]:
    """(calls, on_tile): an on_tile callback for core.render.render that records each tile it is handed, in
    order, as (x0, y0, samples, and the bytes of its colour, variance and albedo or None), so two renders' tile
    callbacks compare with ==."""
    calls: list = []

    def on_tile(tile) -> None:
        calls.append((tile.x0, tile.y0, tile.samples, tile.color.tobytes(),
                      *(None if image is None else image.tobytes() for image in (tile.variance, tile.albedo))))

    return calls, on_tile
