"""Image texture lookup: bilinear filtering with repeat wrapping, Blender's UV convention.

Blender's Image Texture node with Linear interpolation and Repeat extension: texel (row r, column c) of an H x W
image has its centre at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H, because Scene textures store row 0 at the *top*
while Blender's v = 0 is the *bottom* edge of the image.
"""

from __future__ import annotations

import numpy as np


def sample_texture(pixels: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinearly filtered, repeat-wrapped lookup of an (H, W, 3) float32 image at (N, 2) UVs -> (N, 3) float32.

    Non-finite UVs read texel (0, 0)'s neighbourhood as if uv were 0."""
    px = np.asarray(pixels, dtype=np.float32)
    h, w = px.shape[:2]
    flat = px.reshape(h * w, -1)[:, :3]
    uv = np.asarray(uv, dtype=np.float32).reshape(-1, 2)
    uv = np.where(np.isfinite(uv), uv, np.float32(0.0))
    # continuous texel coordinates with texel centres at integers; rows counted from the top
    x = uv[:, 0] * np.float32(w) - np.float32(0.5)
    y = (np.float32(1.0) - uv[:, 1]) * np.float32(h) - np.float32(0.5)
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    # repeat wrap (np.mod gives non-negative results for negative coordinates)
    xi0 = np.mod(x0.astype(np.int64), w)
    yi0 = np.mod(y0.astype(np.int64), h)
    xi1 = xi0 + 1
    xi1[xi1 == w] = 0
    yi1 = yi0 + 1
    yi1[yi1 == h] = 0
    r0 = yi0 * w
    r1 = yi1 * w
    top = flat[r0 + xi0] * (1.0 - fx) + flat[r0 + xi1] * fx
    bot = flat[r1 + xi0] * (1.0 - fx) + flat[r1 + xi1] * fx
    top += (bot - top) * fy
    return top.astype(np.float32, copy=False)
