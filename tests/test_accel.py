"""Ray casting (core.accel): exact hits against closed forms, the direct Embree backend against embreex's wrapper
(bit for bit), thread safety, ownership of the buffers Embree reads in place, and the fallback."""

import threading

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import embree
from monte.core.accel import Accelerator
from monte.core.integrator import PreparedScene

# One triangle in the plane z = 1: vertices (0,0,1), (2,0,1), (0,2,1).
TRIANGLE_VERTICES = np.array([[0, 0, 1], [2, 0, 1], [0, 2, 1]], np.float32)
TRIANGLE = np.array([[0, 1, 2]], np.int32)


def _rays_up(points_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    origins = np.column_stack([points_xy, np.zeros(len(points_xy))]).astype(np.float32)
    directions = np.tile(np.array([0, 0, 1], np.float32), (len(points_xy), 1))
    return origins, directions


@pytest.fixture(scope="module")
def cornell_soup():
    scene = scenes.cornell_box((32, 32))
    scene.validate()
    prepared = PreparedScene.build(scene, sample_world=False)
    rng = np.random.default_rng(7)
    n = 20000
    lo, hi = prepared.vertices.min(0), prepared.vertices.max(0)
    origins = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
    directions = rng.normal(size=(n, 3)).astype(np.float32)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    tmax = rng.uniform(0.0, float(np.linalg.norm(hi - lo)), n).astype(np.float32)
    return prepared, origins, directions, tmax


@pytest.fixture
def avx2_embree(monkeypatch):
    """The process's Embree library replaced by one whose device uses at most AVX2, as on the many CPUs without
    AVX-512."""
    library, _ = embree.load()
    monkeypatch.setattr(embree, "_library", embree.EmbreeLibrary(library.path, config="max_isa=avx2"))


def test_the_direct_embree_backend_loads_from_the_embreex_wheel():
    library, why_not = embree.load()
    assert why_not is None and library is not None
    assert Accelerator(TRIANGLE_VERTICES, TRIANGLE).backend == "embree"


@pytest.mark.parametrize("backend", ["embree", "embreex"])
def test_hits_match_the_closed_form(backend):
    accel = Accelerator(TRIANGLE_VERTICES, TRIANGLE, backend=backend)
    xy = np.array([[0.5, 0.25], [0.2, 1.5], [1.5, 1.5], [-0.1, 0.5]], np.float32)  # two inside, two outside
    hits = accel.intersect(*_rays_up(xy))
    np.testing.assert_array_equal(hits.prim, [0, 0, -1, -1])
    # Barycentrics of vertices 1 and 2 are x/2 and y/2 here; t is the height of the plane.
    np.testing.assert_allclose(hits.u[:2], xy[:2, 0] / 2, atol=1e-6)
    np.testing.assert_allclose(hits.v[:2], xy[:2, 1] / 2, atol=1e-6)
    np.testing.assert_allclose(hits.t[:2], 1.0, atol=1e-6)
    assert np.all(np.isinf(hits.t[2:]))
    assert accel.rays_closest == 4


@pytest.mark.parametrize("backend", ["embree", "embreex"])
def test_tmax_bounds_closest_hits_and_occlusion(backend):
    accel = Accelerator(TRIANGLE_VERTICES, TRIANGLE, backend=backend)
    origins, directions = _rays_up(np.array([[0.5, 0.5]] * 3, np.float32))
    tmax = np.array([0.999, 1.001, np.inf], np.float32)
    np.testing.assert_array_equal(accel.intersect(origins, directions, tmax).prim, [-1, 0, 0])
    np.testing.assert_array_equal(accel.occluded(origins, directions, tmax), [False, True, True])
    assert accel.rays_shadow == 3


def test_direct_backend_is_bit_identical_to_embreex(cornell_soup):
    # both devices take Embree's own choice of instruction set
    prepared, origins, directions, tmax = cornell_soup
    direct = Accelerator(prepared.vertices, prepared.triangles, backend="embree")
    wrapper = Accelerator(prepared.vertices, prepared.triangles, backend="embreex")
    for bound in (None, tmax):
        a, b = direct.intersect(origins, directions, bound), wrapper.intersect(origins, directions, bound)
        assert 0.3 < np.mean(a.prim >= 0) <= 1.0  # the test exercises hits and misses
        np.testing.assert_array_equal(a.prim, b.prim)
        hit = a.prim >= 0
        for x, y in ((a.u, b.u), (a.v, b.v), (a.t, b.t)):
            np.testing.assert_array_equal(x[hit], y[hit])
        assert np.all(np.isinf(a.t[~hit]))
    blocked = direct.occluded(origins, directions, tmax)
    assert 0.1 < blocked.mean() < 0.9
    np.testing.assert_array_equal(blocked, wrapper.occluded(origins, directions, tmax))


def test_the_device_takes_embree_s_own_instruction_set():
    """No cap: Embree's AVX-512 code computes the same hits on every CPU with AVX-512 (Intel's and AMD's), its AVX2
    code not (the CPU's approximate reciprocal differs between makers), so a cap at AVX2 would only make more CPUs
    disagree (core.embree.DEVICE_CONFIG)."""
    library, _ = embree.load()
    assert library.config == "" == embree.DEVICE_CONFIG


def test_embree_s_avx2_code_hits_what_its_own_choice_hits(cornell_soup, request):
    """On a CPU without AVX-512, Embree's AVX2 code rounds some hits differently (on these rays, against AVX-512,
    ~6 % of the hits move by an ulp or two), never which triangle a ray hits."""
    prepared, origins, directions, tmax = cornell_soup
    own = Accelerator(prepared.vertices, prepared.triangles, backend="embree").intersect(origins, directions, tmax)
    request.getfixturevalue("avx2_embree")
    avx2 = Accelerator(prepared.vertices, prepared.triangles, backend="embree").intersect(origins, directions, tmax)
    np.testing.assert_array_equal(avx2.prim, own.prim)
    hit = own.prim >= 0
    np.testing.assert_allclose(avx2.t[hit], own.t[hit], rtol=1e-5)
    np.testing.assert_allclose(avx2.u[hit], own.u[hit], atol=1e-5)


def test_threads_share_one_scene(cornell_soup):
    prepared, origins, directions, tmax = cornell_soup
    accel = Accelerator(prepared.vertices, prepared.triangles)
    serial = accel.intersect(origins, directions, tmax).prim
    results = [None] * 4

    def work(i):
        results[i] = accel.intersect(origins, directions, tmax).prim

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in results:
        np.testing.assert_array_equal(r, serial)
    assert accel.rays_closest == 5 * len(origins)


def test_the_scene_owns_the_buffers_embree_reads():
    """Embree reads vertices and indices in place: changing or freeing the caller's arrays must not move hits."""
    vertices, triangles = TRIANGLE_VERTICES.copy(), TRIANGLE.copy()
    accel = Accelerator(vertices, triangles)
    vertices[:] = 100.0
    triangles[:] = 0
    del vertices, triangles
    hits = accel.intersect(*_rays_up(np.array([[0.5, 0.25]], np.float32)))
    assert hits.prim[0] == 0 and abs(hits.t[0] - 1.0) < 1e-6


def test_falls_back_to_embreex_with_a_warning(monkeypatch):
    monkeypatch.setattr(embree, "load", lambda: (None, "no loadable Embree 4 library next to embreex"))
    with pytest.warns(RuntimeWarning, match="no loadable Embree 4 library.*through embreex's wrapper"):
        accel = Accelerator(TRIANGLE_VERTICES, TRIANGLE)
    assert accel.backend == "embreex"
    assert accel.intersect(*_rays_up(np.array([[0.5, 0.25]], np.float32))).prim[0] == 0
    with pytest.raises(RuntimeError, match="the Embree backend is not available: no loadable"):
        Accelerator(TRIANGLE_VERTICES, TRIANGLE, backend="embree")


def test_unknown_backend_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown ray-casting backend 'optix'"):
        Accelerator(TRIANGLE_VERTICES, TRIANGLE, backend="optix")


def test_empty_scene_misses_everything():
    accel = Accelerator(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    origins, directions = _rays_up(np.zeros((2, 2), np.float32))
    assert np.all(accel.intersect(origins, directions).prim == -1)
    assert not accel.occluded(origins, directions, np.ones(2, np.float32)).any()
