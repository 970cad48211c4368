"""A world whose colour a node program drives, baked over directions into an equirectangular environment map.

The world's shader runs as a `core.shading` program (the compiler and evaluator materials use) in Cycles'
background shading context: for a ray escaping along the unit direction D, P = D, N = Ng = -D, I = -D, UV = 0,
no object (so the Texture Coordinate node's Generated and Object outputs read D, Normal reads -D). The program's
emission register holds the Background's colour x strength. It is evaluated at the texel centres of an
equirectangular map (core.sky.equirectangular_directions, core.world_kernels' parametrisation) and the map is then
an ordinary `core.world.EnvironmentMap`: the camera sees it bilinearly interpolated, and it is importance sampled
(with MIS against BSDF rays) like any environment image. At the default 1024 x 512 texels the interpolation error
of a smooth world (gradients, noise of scale ~1) is far below the noise of a render; a world with detail finer
than a texel (0.35 degrees) is blurred to that scale.
"""

from __future__ import annotations

import numpy as np

from .bsdf import LobeBatch
from .shading.evaluator import PreparedShading
from .shading.program import PATH_COLUMNS, ShadingProgram
from .sky import SKY_BAKE_WIDTH, equirectangular_directions

_CHUNK = 1 << 16  # directions per evaluator call (bounds the temporary arrays)


def evaluate_world_program(program: ShadingProgram, directions: np.ndarray, textures=(),
                           path_flags: int = 0) -> np.ndarray:
    """The world program's emission (N, 3) float32, W/(sr m^2), for unit world directions (N, 3) of escaping
    rays. path_flags: the Light Path node's ray flags (core.shading.program RAY_*) of those rays."""
    if program.emission < 0:
        raise ValueError("a world program binds its radiance to the emission register; this one binds none")
    d = np.ascontiguousarray(np.asarray(directions, np.float32).reshape(-1, 3))
    n = d.shape[0]
    prepared = PreparedShading([program], textures, 1)
    out = np.zeros((n, 3), np.float32)
    for s in range(0, n, _CHUNK):
        e = min(n, s + _CHUNK)
        m = e - s
        D = d[s:e]
        back = -D
        lobes = LobeBatch(kind=np.full((m, 1), -1, np.int8), weight=np.zeros((m, 1, 3), np.float32),
                          roughness=np.zeros((m, 1), np.float32), ior=np.ones((m, 1), np.float32),
                          fresnel=np.zeros((m, 1), np.int8), select=np.zeros((m, 1), np.float32))
        extra = None
        if prepared.uses_light_path:
            extra = np.zeros((m, PATH_COLUMNS), np.float32)
            extra[:, 0] = float(path_flags)
        emission = np.zeros((m, 3), np.float32)
        prepared.evaluate(np.arange(m), np.zeros(m, np.int64), D, back, back, back, None, np.zeros(m, np.bool_),
                          np.zeros(m, np.int32), lobes, np.ones((1, 1), np.float32), emission, extra=extra)
        out[s:e] = emission
    return out


def bake_world_program(program: ShadingProgram, textures=(), width: int = SKY_BAKE_WIDTH,
                       path_flags: int = 0) -> np.ndarray:
    """The (width // 2, width, 3) float32 equirectangular map (row 0 at the top) of the world program's radiance,
    non-finite values read as 0 (Cycles' background ignores them). The last few bakes of programs without
    textures are kept (a viewport re-exports the world on every change elsewhere); each call returns its own
    copy."""
    key = None
    if not len(textures):
        key = (program.code.tobytes(), program.registers.tobytes(), program.data.tobytes(), program.emission,
               int(width), int(path_flags))
        hit = _BAKED.get(key)
        if hit is not None:
            return hit.copy()
    d = equirectangular_directions(width)
    pixels = evaluate_world_program(program, d.reshape(-1, 3), textures, path_flags).reshape(d.shape)
    pixels = np.where(np.isfinite(pixels), pixels, np.float32(0)).astype(np.float32)
    if key is not None:
        while len(_BAKED) >= _KEEP:
            _BAKED.pop(next(iter(_BAKED)))
        _BAKED[key] = pixels.copy()
    return pixels


_KEEP = 4
_BAKED: dict = {}
