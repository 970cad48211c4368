"""Direct calls into the Embree 4 library that the embreex wheel ships, for the two things its Python wrapper
makes slow.

- Building: embreex's TriangleMesh copies vertices and indices into Embree's buffers element by element
  through untyped NumPy indexing, ~1 us per triangle (0.36 s for 320k triangles, 4.5x Embree's own BVH build).
  Here Embree reads the NumPy arrays in place (shared buffers): no copy at all.
- Tracing: a compiled (numba, GIL released) loop calls rtcIntersect1 / rtcOccluded1 per ray and writes straight
  into the caller's arrays (no result dictionary, no clean-up pass); as fast as embreex's loop or a little
  faster, and bit-identical hits (same library, same robust scene flag, same single-ray queries), which the
  tests check against embreex itself.

The library is the one embreex loads (its wheel bundles it: embreex.libs/ on Linux and Windows, embreex/.dylibs/
on macOS), so nothing new is installed. `load()` returns None with the reason when it cannot be found (a source
build of embreex against a system Embree elsewhere, say); core.accel then falls back to embreex's wrapper.

Conventions: float32 coordinates, unit directions, tnear 0 (callers offset ray origins themselves), triangles as
(T, 3) vertex indices, one geometry (geomID 0) per scene. Motion blur (`new_motion_scene`): a static geometry and
a time-stepped one (Embree's motion-blur triangles, S vertex buffers at times evenly spaced over [0, 1], linear in
between), traced by the *_timed loops, which set each ray's time; a scene without motion never reaches them. Embree's RTCRayHit is laid out as 4-byte words:
org 0-2, tnear 3, dir 4-6, time 7, tfar 8, mask 9, id 10, flags 11, Ng 12-14, u 15, v 16, primID 17,
geomID 18, instID 19.. (rtcore_ray.h, Embree 4).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import threading
from typing import Iterator

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .jit_cache import jit as _jit
from .jit_cache import jit_inline as _inline

_INVALID_ID = np.uint32(0xFFFFFFFF)
_FAR = np.float32(3e38)
_RAY_WORDS = 64  # one RTCRayHit (24 words with one instance level) plus room for alignment and more levels

# Enum values from Embree 4's rtcore_common.h / rtcore_buffer.h / rtcore_geometry.h.
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX = 0
_BUFFER_TYPE_VERTEX = 1
_FORMAT_UINT3 = 0x5003
_FORMAT_FLOAT3 = 0x9003
_SCENE_FLAG_ROBUST = 1 << 2
_MAX_TIME_STEPS = 129  # RTC_MAX_TIME_STEP_COUNT


@intrinsic
def _call_embree(typingctx, function, scene, ray, arguments):
    """Call a C function void f(void*, void*, void*) at address `function` (rtcIntersect1, rtcOccluded1) with
    three addresses. The address is a run-time argument, so the compiled kernel caches across processes (a
    ctypes function object would be baked in as a constant and forbid caching)."""
    signature = types.void(types.intp, types.intp, types.intp, types.intp)

    def codegen(context, builder, sig, args):
        pointer = ir.IntType(8).as_pointer()
        function_type = ir.FunctionType(ir.VoidType(), [pointer, pointer, pointer])
        callee = builder.inttoptr(args[0], function_type.as_pointer())
        builder.call(callee, [builder.inttoptr(a, pointer) for a in args[1:]])
        return context.get_dummy_value()

    return signature, codegen


@_jit
def _ray_buffer():
    """A 16-byte aligned RTCRayHit (Embree's requirement) as float32 and uint32 views, plus its address."""
    raw = np.zeros(_RAY_WORDS, np.float32)
    skip = ((16 - raw.ctypes.data % 16) % 16) // 4
    words = raw[skip:skip + 32]
    return words, words.view(np.uint32), words.ctypes.data


@_jit
def set_ray(words, ids, ox, oy, oz, dx, dy, dz, tfar):
    """Load one ray into the RTCRayHit words/ids (origin o, direction d, tnear 0, time 0, tfar capped at
    _FAR, every geometry's mask, id and flags 0); a closest-hit query also resets the hit's ids itself."""
    words[0], words[1], words[2], words[3] = ox, oy, oz, 0.0
    words[4], words[5], words[6], words[7] = dx, dy, dz, 0.0
    words[8] = min(tfar, _FAR)
    ids[9] = _INVALID_ID  # mask: every geometry
    ids[10] = 0
    ids[11] = 0


@_inline  # as the two copies were: a call per ray would pass six arrays, each as its expanded struct
def _intersect(intersect1, scene, words, ids, address, k, prim, u, v, t):
    """Trace the loaded ray k for its closest hit (trace_closest and trace_closest_timed): on a miss prim[k] = -1,
    u, v = 0 and t = inf; on a hit the barycentrics and t are written and True is returned (the caller writes
    prim[k], from Embree's ids[17] primID and ids[18] geomID)."""
    ids[17] = _INVALID_ID
    ids[18] = _INVALID_ID
    ids[19] = _INVALID_ID
    _call_embree(intersect1, scene, address, 0)
    if ids[18] == _INVALID_ID:
        prim[k] = -1
        u[k] = 0.0
        v[k] = 0.0
        t[k] = np.inf
        return False
    u[k] = words[15]
    v[k] = words[16]
    t[k] = words[8]
    return True


@_jit
def _load_ray(words, ids, origins, directions, k, tfar):
    set_ray(words, ids, origins[k, 0], origins[k, 1], origins[k, 2], directions[k, 0], directions[k, 1],
            directions[k, 2], tfar)


@_jit
def trace_closest(intersect1, scene, origins, directions, tmax, prim, u, v, t):
    """Closest hit of each ray within (0, tmax[k]] (tmax of length 0: unbounded). Writes prim (-1 = miss), the
    barycentrics u, v of vertices 1 and 2, and t (inf on a miss)."""
    words, ids, address = _ray_buffer()
    bounded = len(tmax) > 0
    for k in range(origins.shape[0]):
        _load_ray(words, ids, origins, directions, k, tmax[k] if bounded else _FAR)
        if _intersect(intersect1, scene, words, ids, address, k, prim, u, v, t):
            prim[k] = np.int32(ids[17])


@_jit
def trace_occluded(occluded1, scene, origins, directions, tmax, blocked):
    """blocked[k] = something lies along ray k within (0, tmax[k]). Embree marks an occluded ray by setting its
    tfar to -inf."""
    words, ids, address = _ray_buffer()
    for k in range(origins.shape[0]):
        _load_ray(words, ids, origins, directions, k, tmax[k])
        _call_embree(occluded1, scene, address, 0)
        blocked[k] = words[8] < 0.0


@_jit
def trace_closest_timed(intersect1, scene, origins, directions, tmax, time, order, first, prim, u, v, t):
    """trace_closest for a motion-blur scene: ray k at time[k] in [0, 1] (shutter open to close); the hit's
    triangle is order[first[geomID] + primID] (the scene's triangle index; geometries keep their own numbering)."""
    words, ids, address = _ray_buffer()
    bounded = len(tmax) > 0
    for k in range(origins.shape[0]):
        _load_ray(words, ids, origins, directions, k, tmax[k] if bounded else _FAR)
        words[7] = time[k]
        if _intersect(intersect1, scene, words, ids, address, k, prim, u, v, t):
            prim[k] = order[first[ids[18]] + ids[17]]


@_jit
def trace_occluded_timed(occluded1, scene, origins, directions, tmax, time, blocked):
    """trace_occluded for a motion-blur scene: ray k at time[k] in [0, 1]."""
    words, ids, address = _ray_buffer()
    for k in range(origins.shape[0]):
        _load_ray(words, ids, origins, directions, k, tmax[k])
        words[7] = time[k]
        _call_embree(occluded1, scene, address, 0)
        blocked[k] = words[8] < 0.0


def _library_candidates() -> Iterator[str]:
    """Where the embreex wheels put Embree 4 (auditwheel, delvewheel, delocate), then the system's (looked up
    only when none of the wheel's loads: find_library runs ldconfig or a compiler, ~30 ms a first render paid)."""
    import embreex.rtcore_scene  # noqa: F401  (loads the library and its TBB the way embreex's wheel arranges)

    package = os.path.dirname(os.path.abspath(embreex.rtcore_scene.__file__))
    patterns = [
        os.path.join(package, os.pardir, "embreex.libs", "libembree4*.so*"),  # Linux
        os.path.join(package, os.pardir, "embreex.libs", "embree4*.dll"),  # Windows
        os.path.join(package, ".dylibs", "libembree4*.dylib"),  # macOS
    ]
    for pattern in patterns:
        yield from sorted(glob.glob(pattern))
    system = ctypes.util.find_library("embree4")
    if system:
        yield system


# The device's configuration: Embree's own choice of instruction set. Its AVX-512 code computes the same hits
# on every CPU with AVX-512, Intel's and AMD's alike (its reciprocals are exact there), so images are the same bits
# on all of them. Its AVX2 and SSE code starts from the CPU's approximate reciprocal (RCPPS), whose last bits
# differ between CPU makers, so no cap makes all CPUs agree: a cap at AVX2 made Intel and AMD machines render
# other bits (docs/performance.md, "Embree's ISA").
DEVICE_CONFIG = ""


class EmbreeLibrary:
    """The Embree 4 C API through ctypes: one device per process, scenes over shared NumPy buffers, and the
    addresses of rtcIntersect1 / rtcOccluded1 for the compiled trace loops."""

    def __init__(self, path: str, config: str = DEVICE_CONFIG) -> None:
        """path: the Embree 4 library; config: the device's configuration string (Embree's rtcNewDevice)."""
        lib = ctypes.CDLL(path)
        p = ctypes.c_void_p
        for name, restype, argtypes in (
            ("rtcNewDevice", p, [ctypes.c_char_p]),
            ("rtcGetDeviceError", ctypes.c_int, [p]),
            ("rtcGetDeviceLastErrorMessage", ctypes.c_char_p, [p]),
            ("rtcNewScene", p, [p]),
            ("rtcReleaseScene", None, [p]),
            ("rtcCommitScene", None, [p]),
            ("rtcSetSceneFlags", None, [p, ctypes.c_int]),
            ("rtcNewGeometry", p, [p, ctypes.c_int]),
            ("rtcSetSharedGeometryBuffer", None,
             [p, ctypes.c_int, ctypes.c_uint, ctypes.c_int, p, ctypes.c_size_t, ctypes.c_size_t, ctypes.c_size_t]),
            ("rtcCommitGeometry", None, [p]),
            ("rtcSetGeometryTimeStepCount", None, [p, ctypes.c_uint]),
            ("rtcAttachGeometry", ctypes.c_uint, [p, p]),
            ("rtcReleaseGeometry", None, [p]),
        ):
            function = getattr(lib, name)
            function.restype, function.argtypes = restype, argtypes
        self.path = path
        self._lib = lib
        self.intersect1 = ctypes.cast(lib.rtcIntersect1, ctypes.c_void_p).value
        self.occluded1 = ctypes.cast(lib.rtcOccluded1, ctypes.c_void_p).value
        self.config = config
        self.device = lib.rtcNewDevice(config.encode() if config else None)
        if not self.device:
            raise OSError(f"rtcNewDevice failed in {path}")

    def check(self, what: str) -> None:
        """Raise RuntimeError with Embree's own message if the last call on the device failed."""
        code = self._lib.rtcGetDeviceError(self.device)
        if code:
            message = self._lib.rtcGetDeviceLastErrorMessage(self.device) or b""
            raise RuntimeError(f"Embree error {code} while {what}: {message.decode(errors='replace')}")

    def new_triangle_scene(self, vertices: np.ndarray, triangles: np.ndarray) -> int:
        """Build (commit) a scene over one triangle mesh whose buffers Embree reads in place: the caller keeps
        vertices ((V + 1, 3) float32, C-contiguous, the last row padding Embree may read past the end) and
        triangles ((T, 3) uint32, C-contiguous) alive and unchanged until release_scene."""
        lib = self._lib
        scene = lib.rtcNewScene(self.device)
        # Robust (watertight) traversal, as embreex sets it and Cycles does: no rays slip through shared edges.
        lib.rtcSetSceneFlags(scene, _SCENE_FLAG_ROBUST)
        geometry = lib.rtcNewGeometry(self.device, _GEOMETRY_TYPE_TRIANGLE)
        lib.rtcSetSharedGeometryBuffer(geometry, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, vertices.ctypes.data, 0,
                                       12, len(vertices) - 1)
        lib.rtcSetSharedGeometryBuffer(geometry, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, triangles.ctypes.data, 0,
                                       12, len(triangles))
        lib.rtcCommitGeometry(geometry)
        lib.rtcAttachGeometry(scene, geometry)
        lib.rtcReleaseGeometry(geometry)  # the scene holds it now
        lib.rtcCommitScene(scene)
        try:
            self.check(f"building the ray-tracing scene ({len(triangles)} triangles)")
        except RuntimeError:
            lib.rtcReleaseScene(scene)
            raise
        return scene

    def new_motion_scene(self, vertices: np.ndarray, triangles: np.ndarray, step_vertices: list[np.ndarray],
                         moving_triangles: np.ndarray) -> tuple[int, list[int]]:
        """Build (commit) a scene of a static triangle mesh (vertices, triangles as new_triangle_scene; skipped
        when it has no triangles) and a moving one: moving_triangles ((M, 3) uint32) over S = len(step_vertices)
        vertex buffers ((V' + 1, 3) float32 each, the last row padding), the positions at times s / (S - 1) of the
        shutter; Embree interpolates linearly between steps. Returns the scene and the geomID of each mesh built
        (static first). The caller keeps every buffer alive and unchanged until release_scene."""
        steps = len(step_vertices)
        if not 2 <= steps <= _MAX_TIME_STEPS:
            raise ValueError(f"motion blur needs 2 to {_MAX_TIME_STEPS} time steps, got {steps}")
        lib = self._lib
        scene = lib.rtcNewScene(self.device)
        lib.rtcSetSceneFlags(scene, _SCENE_FLAG_ROBUST)
        ids = []
        for buffers, tris in (([vertices], triangles), (step_vertices, moving_triangles)):
            if not len(tris):
                continue
            geometry = lib.rtcNewGeometry(self.device, _GEOMETRY_TYPE_TRIANGLE)
            if len(buffers) > 1:
                lib.rtcSetGeometryTimeStepCount(geometry, len(buffers))
            for slot, verts in enumerate(buffers):
                lib.rtcSetSharedGeometryBuffer(geometry, _BUFFER_TYPE_VERTEX, slot, _FORMAT_FLOAT3, verts.ctypes.data,
                                               0, 12, len(verts) - 1)
            lib.rtcSetSharedGeometryBuffer(geometry, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, tris.ctypes.data, 0, 12,
                                           len(tris))
            lib.rtcCommitGeometry(geometry)
            ids.append(int(lib.rtcAttachGeometry(scene, geometry)))
            lib.rtcReleaseGeometry(geometry)
        lib.rtcCommitScene(scene)
        try:
            self.check(f"building the motion-blur scene ({len(triangles)} static, {len(moving_triangles)} moving "
                       f"triangles, {steps} time steps)")
        except RuntimeError:
            lib.rtcReleaseScene(scene)
            raise
        return scene, ids

    def release_scene(self, scene: int) -> None:
        self._lib.rtcReleaseScene(scene)


_library: EmbreeLibrary | None = None
_library_error: str | None = None
_library_lock = threading.Lock()


def load() -> tuple[EmbreeLibrary | None, str | None]:
    """The process's EmbreeLibrary (created on first use), or (None, why not)."""
    global _library, _library_error
    with _library_lock:
        if _library is None and _library_error is None:
            tried = []
            for path in _library_candidates():
                try:
                    _library = EmbreeLibrary(path)
                    break
                except (OSError, AttributeError) as error:  # not loadable, or an Embree without these symbols
                    tried.append(f"{path}: {error}")
            else:
                _library_error = ("no loadable Embree 4 library next to embreex"
                                  + (f" ({'; '.join(tried)})" if tried else ""))
        return _library, _library_error
