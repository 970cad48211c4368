"""Image texture lookup: bilinear filtering with repeat wrapping, Blender's UV convention.

Blender's Image Texture node with Linear interpolation and Repeat extension: texel (row r, column c) of an H x W
image has its centre at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H, because Scene textures store row 0 at the *top*
while Blender's v = 0 is the *bottom* edge of the image. The filter itself is compiled
(core.bsdf_kernels.texel_bilinear), shared with the material gather that tints lobes per hit.
"""

from __future__ import annotations

import numpy as np

from . import bsdf_kernels as bk


def sample_texture(pixels: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinearly filtered, repeat-wrapped lookup of an (H, W, 3) float32 image at (N, 2) UVs -> (N, 3) float32.

    Non-finite UVs read texel (0, 0)'s neighbourhood as if uv were 0."""
    px = np.asarray(pixels, dtype=np.float32)
    h, w = px.shape[:2]
    flat = np.ascontiguousarray(px.reshape(h, w, -1)[..., :3]).reshape(-1)
    uv = np.ascontiguousarray(np.asarray(uv, dtype=np.float32).reshape(-1, 2))
    out = np.empty((uv.shape[0], 3), np.float32)
    bk.texture_batch(flat, h, w, uv, out)
    return out
