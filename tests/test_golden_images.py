"""Images are bit-identical to stored fingerprints: the guard for changes meant to leave behaviour alone.

Each case renders a small image (tiny resolution, few samples, fixed seed) and compares a SHA-256 of every
output array (colour, variance, albedo, normal, depth, sample counts) with the values in
tests/data/golden_images.json. The cases cover every built-in scene, the four bench scenes built in bpy and
exported by the add-on, each sampler, each pixel filter, each light-sampling strategy, adaptive sampling and
clamping, so a refactor that changes any bit of any path's radiance fails here.

A change that is meant to change images regenerates the fingerprints (and says why in its commit):

    .venv/bin/python tests/test_golden_images.py --regenerate

The kernels use no fast-math, and the same fingerprints come out of Python 3.11 / NumPy 1.26.4 / numba 0.62.1
and Python 3.13 / NumPy 2.5.5 / numba 0.68.1 (x86-64): an environment that renders other bits is a finding to
look into before regenerating. The stored means give a readable hint of how far a failing image moved.

They hold on every x86-64 CPU with AVX-512, Intel's and AMD's alike (the stored ones were made on an AMD Zen 4
and hold on an Intel Sapphire Rapids). The kernels compile for one level (core.jit_cache: x86-64-v3), Embree's
AVX-512 code computes the same hits on all of them, and NumPy's AVX-512 loops give the same bits as its AVX2 ones,
which the last test checks by turning them off. On a CPU without AVX-512 Embree runs its AVX2 or SSE code, which
starts from the CPU's approximate reciprocal (RCPPS, whose last bits differ between CPU makers): hit distances
move by an ulp or two, so the bit-identity cases skip there and say why.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

GOLDEN = Path(__file__).parent / "data" / "golden_images.json"
RESOLUTION = (24, 16)
BASE = dict(spp=4, seed=7, threads=2, tile_size=16, batch_paths=1 << 14)

# name -> (scene source, scene name, settings overrides)
CASES: dict[str, tuple[str, str, dict]] = {
    "cornell": ("core", "cornell", {}),
    "cornell-diffuse": ("core", "cornell-diffuse", {}),
    "furnace": ("core", "furnace", {}),
    "plane-world": ("core", "plane-world", {}),
    "point-in-sphere": ("core", "point-in-sphere", {}),
    "spheres-sky": ("core", "spheres-sky", {}),
    "cornell-stratified-tent": ("core", "cornell", {"sampler": "stratified", "filter_type": "tent",
                                                   "filter_width": 2.0}),
    "cornell-independent-gaussian": ("core", "cornell", {"sampler": "independent", "filter_type": "gaussian"}),
    "cornell-box-filter-clamp": ("core", "cornell", {"filter_type": "box", "filter_width": 1.0, "clamp": 4.0}),
    "cornell-bsdf-sampling": ("core", "cornell", {"light_sampling": "bsdf"}),
    "spheres-sky-light-sampling": ("core", "spheres-sky", {"light_sampling": "light"}),
    "cornell-adaptive": ("core", "cornell", {"spp": 64, "adaptive_threshold": 0.05, "adaptive_min_samples": 16}),
    "bench-cornell": ("bpy", "cornell", {}),
    "bench-interior": ("bpy", "interior", {}),
    "bench-glass": ("bpy", "glass", {}),
    "bench-instances": ("bpy", "instances", {}),
}


def _scene(source: str, name: str):
    if source == "core":
        from monte.core.builtin_scenes import builtin_scene

        return builtin_scene(name, RESOLUTION)
    import bpy

    from monte.addon.export import export_scene
    from monte.lab import bpy_scenes

    bpy_scenes.build(name, RESOLUTION)
    scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    return scene


def _fingerprint(case: str) -> dict:
    from monte.core.render import render
    from monte.core.settings import RenderSettings

    source, name, overrides = CASES[case]
    result = render(_scene(source, name), RenderSettings(**{**BASE, **overrides}))
    arrays = {"color": result.color, "variance": result.variance, "albedo": result.albedo,
              "normal": result.normal, "depth": result.depth, "sample_count": result.sample_count}
    out = {k: hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest() for k, a in arrays.items()}
    out["mean_rgb"] = [float(v) for v in result.color[..., :3].reshape(-1, 3).mean(axis=0)]
    return out


def _stored() -> dict:
    return json.loads(GOLDEN.read_text())


def _changed(expected: dict, got: dict) -> list[str]:
    """The arrays whose fingerprints differ."""
    return [k for k in expected if k != "mean_rgb" and got[k] != expected[k]]


# The CPU features Embree's AVX-512 code needs (its AVX512 ISA: Skylake-SP's set), as LLVM names them.
EMBREE_AVX512_FEATURES = ("avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl")


def embree_runs_its_avx512_code() -> bool:
    """Whether this CPU has every feature of Embree's AVX-512 code (the code the stored fingerprints come from)."""
    import llvmlite.binding as ll

    try:
        features = dict(ll.get_host_cpu_features())
    except RuntimeError:
        return False
    return all(features.get(f) for f in EMBREE_AVX512_FEATURES)


def _needs(source: str):
    if not embree_runs_its_avx512_code():
        pytest.skip("this CPU has no AVX-512: Embree runs its AVX2/SSE code, whose approximate reciprocals (RCPPS) "
                    "differ between CPU makers, so hit distances and these fingerprints differ by ulps")
    if source == "bpy":
        pytest.importorskip("bpy")


@pytest.mark.parametrize("case", list(CASES))
def test_image_is_bit_identical(case):
    source = CASES[case][0]
    _needs(source)
    expected = _stored()[case]
    got = _fingerprint(case)
    changed = _changed(expected, got)
    assert not changed, (f"{case}: {', '.join(changed)} changed; mean RGB {got['mean_rgb']} "
                         f"(stored {expected['mean_rgb']})")


def test_every_case_has_a_fingerprint():
    assert sorted(_stored()) == sorted(CASES)


PORTABLE_CASES = ("cornell", "spheres-sky")  # NumPy's transcendental functions (the sky) and the film


def _avx512_dispatch() -> list[str]:
    """NumPy's dispatch targets that use AVX-512 on this CPU (its names differ between versions)."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:  # NumPy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    return [t for t in __cpu_dispatch__ if ("AVX512" in t or t == "X86_V4") and __cpu_features__.get(t)]


def test_numpy_s_avx512_loops_render_the_same_bits():
    """Without NumPy's AVX-512 loops (as on a CPU that has only AVX2) the same fingerprints come out."""
    targets = _avx512_dispatch()
    if not targets:
        pytest.skip("this CPU runs none of NumPy's AVX-512 loops: nothing to turn off")
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(targets)}
    done = subprocess.run([sys.executable, __file__, "--print", *PORTABLE_CASES], env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    got, stored = json.loads(done.stdout.splitlines()[-1]), _stored()
    for case in PORTABLE_CASES:
        changed = _changed(stored[case], got[case])
        assert not changed, f"{case} without NumPy's {targets}: {', '.join(changed)} changed"


if __name__ == "__main__":
    if sys.argv[1:2] == ["--print"]:  # the fingerprints of the named cases, as one JSON line
        print(json.dumps({case: _fingerprint(case) for case in sys.argv[2:]}))
        sys.exit(0)
    if sys.argv[1:] != ["--regenerate"]:
        sys.exit("usage: tests/test_golden_images.py --regenerate")
    GOLDEN.parent.mkdir(exist_ok=True)
    table = {case: _fingerprint(case) for case in CASES}
    GOLDEN.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
    print(f"wrote {len(table)} fingerprints to {GOLDEN}")
