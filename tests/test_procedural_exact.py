"""The hash-based procedural textures' exact outputs (core/shading/procedural.py): fixed inputs, stored digests of
the float32 results. Any change of a single output bit fails, so a speed-up of the noise, hash or Voronoi code
must keep every value as it is (Cycles' definitions in float32; tests/test_procedural_textures.py checks those
against Cycles, pixel by pixel, to about 1e-6).

Only textures built from integer hashes, float32 add/multiply, floor, fmod and sqrt are digested (results that
IEEE arithmetic fixes on every platform); Minkowski's pow, Wave's and Magic's sin are left to the Cycles checks.
The digests were computed by the code as it stood before the speed-ups of docs/performance.md's "Procedural
texture kernels" round."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from monte.core.shading import procedural as tex


def _coords() -> np.ndarray:
    """512 points in [-10, 10]^4 from a fixed low-discrepancy sequence, plus lattice points, points in the wrapped
    ranges (|p| >= 1e5, >= 1e6) and signed zeros."""
    i = np.arange(512 * 4, dtype=np.float64)
    co = ((i * 0.6180339887498949) % 1.0 * 20.0 - 10.0).reshape(-1, 4)
    special = np.array([[0.0, 0.0, 0.0, 0.0], [-0.0, -0.0, -0.0, -0.0], [1.0, -2.0, 3.0, -4.0],
                        [0.5, 0.5, 0.5, 0.5], [1.0e5 + 0.25, -1.0e5 - 0.75, 3.0e5, 7.5],
                        [1.5e6 + 0.5, -2.25e6, 0.125, 4.0e6], [-0.2, -1.3, -7.9, -0.01]])
    return np.concatenate([co, special / 5.0]).astype(np.float32)  # / 5: the textures' default Scale is 5


CO = _coords()


def digest(arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a, np.float32).tobytes())
    return h.hexdigest()[:16]


def _noise_case(dim, noise_type, detail, distortion, normalize=True):
    return lambda: tex.noise(CO, dim, scale=5.0, detail=detail, roughness=0.6, lacunarity=2.1, offset=0.3,
                             gain=1.2, distortion=distortion, noise_type=noise_type, normalize=normalize)


def _voronoi_case(dim, feature, metric, detail=0.0):
    def run():
        r = tex.voronoi(CO, dim, scale=5.0, detail=detail, roughness=0.6, lacunarity=2.0, smoothness=0.7,
                        randomness=0.9, feature=feature, distance=metric, normalize=detail > 0)
        return [r[k] for k in ("Distance", "Color", "Position", "W", "Radius")]
    return run


CASES = {}
for _dim in (1, 2, 3, 4):
    CASES[f"white {_dim}D"] = (lambda d: lambda: tex.white_noise(CO, d))(_dim)
    for _type in tex.NOISE_TYPES:
        CASES[f"noise {_dim}D {_type} detail 2.5 distorted"] = _noise_case(_dim, _type, 2.5, 0.7)
        CASES[f"noise {_dim}D {_type} detail 0"] = _noise_case(_dim, _type, 0.0, 0.0)
    CASES[f"noise {_dim}D FBM detail 8 raw"] = _noise_case(_dim, "FBM", 8.0, 0.0, normalize=False)
    for _feature in tex.VORONOI_FEATURES:
        CASES[f"voronoi {_dim}D {_feature}"] = _voronoi_case(_dim, _feature, "EUCLIDEAN")
    for _metric in ("MANHATTAN", "CHEBYCHEV"):
        CASES[f"voronoi {_dim}D F2 {_metric}"] = _voronoi_case(_dim, "F2", _metric)
    CASES[f"voronoi {_dim}D F1 fractal"] = _voronoi_case(_dim, "F1", "EUCLIDEAN", detail=1.5)

DIGESTS = {
    'white 1D': '26c142f3659c431b',
    'noise 1D FBM detail 2.5 distorted': '42ebf315474206f9',
    'noise 1D FBM detail 0': '293ae439a6e08fd6',
    'noise 1D MULTIFRACTAL detail 2.5 distorted': '756018a398394aeb',
    'noise 1D MULTIFRACTAL detail 0': 'a577e6f599c65bbc',
    'noise 1D HYBRID_MULTIFRACTAL detail 2.5 distorted': 'aa651bacadfc7d1f',
    'noise 1D HYBRID_MULTIFRACTAL detail 0': 'd7057d649da66468',
    'noise 1D RIDGED_MULTIFRACTAL detail 2.5 distorted': '3cea0c8a2a5b9a91',
    'noise 1D RIDGED_MULTIFRACTAL detail 0': 'eb47c0d13100deda',
    'noise 1D HETERO_TERRAIN detail 2.5 distorted': '2d9cbcf6fd786c50',
    'noise 1D HETERO_TERRAIN detail 0': 'd7057d649da66468',
    'noise 1D FBM detail 8 raw': '0ab04f11b5c74ffd',
    'voronoi 1D F1': '02b69cc68c4e0a7e',
    'voronoi 1D F2': 'df6f0fe7de3baf28',
    'voronoi 1D SMOOTH_F1': '9715ec334ea3eda3',
    'voronoi 1D DISTANCE_TO_EDGE': '0f96af1f39e7bc9b',
    'voronoi 1D N_SPHERE_RADIUS': '6b62d7374afa0c2e',
    'voronoi 1D F2 MANHATTAN': 'df6f0fe7de3baf28',
    'voronoi 1D F2 CHEBYCHEV': 'df6f0fe7de3baf28',
    'voronoi 1D F1 fractal': 'aa7c7dca00c5dad4',
    'white 2D': 'e3394cee0843fc71',
    'noise 2D FBM detail 2.5 distorted': 'e72fcb3dca13dd25',
    'noise 2D FBM detail 0': '3352c18d20b27e23',
    'noise 2D MULTIFRACTAL detail 2.5 distorted': 'f777409a721ffcf3',
    'noise 2D MULTIFRACTAL detail 0': '7641806fbcb9b89c',
    'noise 2D HYBRID_MULTIFRACTAL detail 2.5 distorted': '8ee2a02047094bc1',
    'noise 2D HYBRID_MULTIFRACTAL detail 0': 'd11812da6dca114d',
    'noise 2D RIDGED_MULTIFRACTAL detail 2.5 distorted': '8d9510ce85e0602f',
    'noise 2D RIDGED_MULTIFRACTAL detail 0': '3c41b213690829fc',
    'noise 2D HETERO_TERRAIN detail 2.5 distorted': '0624dc19ad22d7df',
    'noise 2D HETERO_TERRAIN detail 0': 'd11812da6dca114d',
    'noise 2D FBM detail 8 raw': '4c7f755f9160e4fd',
    'voronoi 2D F1': 'd06579fd7025bf25',
    'voronoi 2D F2': '9408b6ede979ed84',
    'voronoi 2D SMOOTH_F1': 'bce6a0b7d237d499',
    'voronoi 2D DISTANCE_TO_EDGE': '2d3a9ade3a1bf00c',
    'voronoi 2D N_SPHERE_RADIUS': '2fe7d2c4ba6b03f9',
    'voronoi 2D F2 MANHATTAN': '9b45d49971527f21',
    'voronoi 2D F2 CHEBYCHEV': '37f846881ad0a818',
    'voronoi 2D F1 fractal': 'ec473d286a16897e',
    'white 3D': '5549a8c7fe3ac7fa',
    'noise 3D FBM detail 2.5 distorted': '1386ea193cd63aad',
    'noise 3D FBM detail 0': '8989ac1cbfb710d3',
    'noise 3D MULTIFRACTAL detail 2.5 distorted': '8ff01bb680316144',
    'noise 3D MULTIFRACTAL detail 0': '6b3051552f93f92a',
    'noise 3D HYBRID_MULTIFRACTAL detail 2.5 distorted': 'b62dc467aa616571',
    'noise 3D HYBRID_MULTIFRACTAL detail 0': 'ef056d61c2f91106',
    'noise 3D RIDGED_MULTIFRACTAL detail 2.5 distorted': '4f6c631eca6ad3e0',
    'noise 3D RIDGED_MULTIFRACTAL detail 0': '13ec9bf52563505a',
    'noise 3D HETERO_TERRAIN detail 2.5 distorted': '123eee467306a76b',
    'noise 3D HETERO_TERRAIN detail 0': 'ef056d61c2f91106',
    'noise 3D FBM detail 8 raw': 'a5ee226ddc62c638',
    'voronoi 3D F1': 'e7866c31a00f87bb',
    'voronoi 3D F2': 'd0059cddfdc489c4',
    'voronoi 3D SMOOTH_F1': '9250e0dce609ce14',
    'voronoi 3D DISTANCE_TO_EDGE': '695e85a01979eaa7',
    'voronoi 3D N_SPHERE_RADIUS': 'c02536b4aefd5a7a',
    'voronoi 3D F2 MANHATTAN': 'cc24a16ea996e94f',
    'voronoi 3D F2 CHEBYCHEV': 'eb4e3b39ec4b4d3a',
    'voronoi 3D F1 fractal': '34d53116d536cca9',
    'white 4D': '137e8a9e279e689d',
    'noise 4D FBM detail 2.5 distorted': '929f531e9d1e16e7',
    'noise 4D FBM detail 0': '4b59c4045600555f',
    'noise 4D MULTIFRACTAL detail 2.5 distorted': '097bb512237a5303',
    'noise 4D MULTIFRACTAL detail 0': '94e7276cfd148753',
    'noise 4D HYBRID_MULTIFRACTAL detail 2.5 distorted': 'fd92e707e06158df',
    'noise 4D HYBRID_MULTIFRACTAL detail 0': '6d448195cedccd79',
    'noise 4D RIDGED_MULTIFRACTAL detail 2.5 distorted': '92614bb0e2dcdaae',
    'noise 4D RIDGED_MULTIFRACTAL detail 0': '1cc80976103a3c9d',
    'noise 4D HETERO_TERRAIN detail 2.5 distorted': 'fea607e231e32e6b',
    'noise 4D HETERO_TERRAIN detail 0': '6d448195cedccd79',
    'noise 4D FBM detail 8 raw': '9d484deaa92b1e8c',
    'voronoi 4D F1': 'fe580c769c5503c7',
    'voronoi 4D F2': '08b0331ce8bc3fe1',
    'voronoi 4D SMOOTH_F1': 'ca2e011b734ee58f',
    'voronoi 4D DISTANCE_TO_EDGE': 'db92e3946fb05105',
    'voronoi 4D N_SPHERE_RADIUS': '815675d4f0443e6c',
    'voronoi 4D F2 MANHATTAN': 'd13687d2fbac9d5a',
    'voronoi 4D F2 CHEBYCHEV': '79967d6219f5c195',
    'voronoi 4D F1 fractal': 'd0fdf652812ecea3',
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_texture_outputs_are_bit_exact(name):
    assert digest(CASES[name]()) == DIGESTS[name], name


def test_digests_cover_every_case_and_tell_cases_apart():
    assert set(DIGESTS) == set(CASES)
    # the inputs reach different values per case: only the cases that coincide by definition share a digest
    # (hybrid multifractal and hetero terrain at detail 0: offset + noise; 1D Voronoi's metrics: all |dx|)
    assert len(set(DIGESTS.values())) == len(DIGESTS) - 6


def test_the_inlined_floor_is_numpy_floor_bit_for_bit():
    """procedural._floor (the Perlin and Voronoi cells' floor without a libm call) against np.floor, float32 and
    float64: signed zeros, integers, the values next to them, both sides of 2^23 (where it hands over to
    np.floor), non-finite values and a random spread over many magnitudes."""
    import numba

    @numba.njit
    def floors(x):
        out = np.empty_like(x)
        for i in range(x.shape[0]):
            out[i] = tex._floor(x[i])
        return out

    rng = np.random.default_rng(7)
    for dt in (np.float32, np.float64):
        base = np.array([0.0, 1.0, 2.0, 0.5, 1.5, 2.5, 1e-30, 1e-45, 0.999, 100000.0, 1000000.0,
                         8388607.0, 8388607.5, 8388608.0, 8388609.0, 16777216.0, 1e9, 3e38], dt)
        ups = np.nextafter(base, dt(np.inf))
        downs = np.nextafter(base, dt(-np.inf))
        spread = (rng.standard_normal(20000) * 10.0 ** rng.uniform(-8, 9, 20000)).astype(dt)
        x = np.concatenate([base, ups, downs, spread, [np.inf, np.nan]])
        x = np.concatenate([x, -x]).astype(dt)
        got, want = floors(x), np.floor(x)
        assert got.dtype == want.dtype
        assert np.array_equal(got.view(np.uint32 if dt is np.float32 else np.uint64),
                              want.view(np.uint32 if dt is np.float32 else np.uint64)), dt
