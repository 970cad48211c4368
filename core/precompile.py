"""Compile (or load) every render kernel ahead of the first render, so that cache can be built once and shipped.

`precompile_kernels()` renders a few tiny scenes that together reach every kernel a render can call: each
built-in scene, each sampler, pixel filter and light-sampling strategy, adaptive sampling and clamping, a
panoramic camera, one scene holding every light kind, every lobe kind, a texture, smooth normals and a
thin-lens camera, and one holding the features whose kernels compile only when a scene uses them (node
programs, whose one interpreter holds every node family; an environment-map world; ray visibility); then the
node compiler's constant folding. What the add-on's renders of real scenes compile beyond these is checked
by the extension's install test (a node material under an environment map: nothing). numba
writes each kernel it compiles into the on-disk cache (core/jit_cache.py), so a later process loads them all.

Run by `make setup` (`python -m monte.core.precompile`) for a checkout and by tools/build_extension.py, under
Blender's import name, for the extension zip. `main()` runs the work in worker processes, one per CPU core up to
two (MONTE_PRECOMPILE_JOBS sets how many): each takes the next case no other has taken, and a kernel signature
that one worker is compiling another waits for and then loads from the cache, so nothing compiles twice (a cold
precompile on 2 cores: 104 s instead of ~200 s). `kernel_cache_counts()` says what this process compiled and what
it loaded from the cache (the tests check that a process using a built cache compiled nothing).

The cache holds every kernel numba compiled, device functions included (~330 signatures), but a render calls
only ~45 of them from Python: a cached kernel carries the code of the device functions it calls, so those are
never loaded again. The precompile records the signatures its renders call from Python (the entry kernels) in
the cache folder (`ENTRY_KERNELS_FILE`); the add-on's loader thread loads only those, and stops when the
add-on unregisters (the end of a `monte render X.blend` process), so a short render no longer waits at exit for
hundreds of device functions nobody calls.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import threading
import time
from contextlib import contextmanager
from types import ModuleType
from typing import Callable, Iterator

import numpy as np

from . import jit_cache


def _kernel_modules() -> list[ModuleType]:
    """The kernel modules as imported now (importing them defines their dispatchers)."""
    import importlib

    return [importlib.import_module(f"{jit_cache.PACKAGE}.{name.replace('/', '.')}")
            for name in jit_cache.KERNEL_MODULES]


def _dispatchers() -> list:
    from numba.core.dispatcher import Dispatcher

    out, seen = [], set()
    for module in _kernel_modules():
        for value in vars(module).values():
            if isinstance(value, Dispatcher) and id(value) not in seen and \
                    getattr(value.py_func, "__module__", None) == module.__name__:
                seen.add(id(value))
                out.append(value)
    return out


def kernel_cache_counts() -> dict[str, int]:
    """Over the kernel modules' dispatchers in this process: `compiled` (signatures numba compiled because the
    disk cache had no valid entry), `loaded` (signatures loaded from the cache), `kernels` (dispatchers) and
    `used` (dispatchers with at least one signature)."""
    compiled = loaded = used = 0
    dispatchers = _dispatchers()
    for d in dispatchers:
        stats = d.stats
        compiled += sum(stats.cache_misses.values())
        loaded += sum(stats.cache_hits.values())
        used += bool(d.signatures)
    return {"compiled": compiled, "loaded": loaded, "kernels": len(dispatchers), "used": used}


ENTRY_KERNELS_FILE = "entry-kernels.json"  # in jit_cache.cache_dir(), beside numba's index files


def entry_kernels_path() -> str:
    """The file listing the kernels a render calls from Python (written by precompile_kernels)."""
    return os.path.join(jit_cache.cache_dir(), ENTRY_KERNELS_FILE)


def _dispatcher_name(d) -> tuple[str, str]:
    """(kernel module as listed in jit_cache.KERNEL_MODULES, function's qualified name)."""
    module = d.py_func.__module__[len(jit_cache.PACKAGE) + 1:].replace(".", "/")
    return module, d.py_func.__qualname__


EntryKernel = tuple[str, str, str]  # (kernel module as in jit_cache.KERNEL_MODULES, qualified name, signature)


@contextmanager
def _recording_entry_calls(found: dict) -> Iterator[None]:
    """Record into found {(module, qualname, str(signature)): None} each signature a kernel compiles or loads for
    a call from Python, in the order of their first calls (the dict's order): numba's dispatcher calls
    _compile_for_args when a Python call finds no loaded overload, while a device function is compiled or loaded
    through compile() alone (while typing its caller)."""
    from numba.core.dispatcher import Dispatcher

    original = Dispatcher._compile_for_args
    lock = threading.Lock()

    def recording(self, *args, **kws):
        before = set(self.overloads)
        try:
            return original(self, *args, **kws)
        finally:
            added = set(self.overloads) - before
            if added and getattr(self.py_func, "__module__", "").startswith(jit_cache.PACKAGE + "."):
                with lock:
                    for sig in added:  # one per call
                        found.setdefault((*_dispatcher_name(self), str(sig)), None)

    Dispatcher._compile_for_args = recording
    try:
        yield
    finally:
        Dispatcher._compile_for_args = original


ENTRY_KERNELS_FORMAT = 2  # 2: one row per signature, in the order of first calls (1: one row per kernel)


def write_entry_kernels(found) -> None:
    """Write the entry kernels (the (module, qualname, signature) rows found by _recording_entry_calls) with the
    sources they were recorded for, one row per signature in the order the precompile first called them: it
    folds a node constant first (as the add-on's export does) and then renders a default scene, so the loader
    loads what an export and a render need first, signature by signature, in the order they ask for them (a
    kernel's other signatures, for other features, come when a case first calls them)."""
    from .atomic_file import write_bytes_atomically

    body = {"sources": jit_cache.sources_digest(), "format": ENTRY_KERNELS_FORMAT,
            "kernels": [list(row) for row in found]}
    os.makedirs(jit_cache.cache_dir(), exist_ok=True)
    write_bytes_atomically(entry_kernels_path(), (json.dumps(body, indent=1) + "\n").encode())


def read_entry_kernels() -> list[EntryKernel] | None:
    """The (module, qualname, signature) rows of the cache folder's entry-kernel list, in its order, or None when
    there is none, it cannot be read, it has an unknown format or it was written for other sources (then every
    cached signature is loaded). A list of the first format (one row per kernel, from an earlier `make setup`)
    gives each kernel's signatures together, in its kernels' order."""
    try:
        with open(entry_kernels_path(), encoding="utf-8") as fh:
            body = json.load(fh)
        if body.get("sources") != jit_cache.sources_digest():
            return None
        if body.get("format", 1) == 1:
            rows = [(module, name, sig) for module, name, sigs in body["kernels"] for sig in sigs]
        elif body["format"] == ENTRY_KERNELS_FORMAT:
            rows = [(module, name, sig) for module, name, sig in body["kernels"]]
        else:
            return None
        if not all(isinstance(part, str) for row in rows for part in row):
            return None
        return rows
    except (OSError, ValueError, KeyError, TypeError):
        return None


def load_cached_kernels(entries_only: bool = True, should_stop: Callable[[], bool] | None = None) -> int:
    """Load kernel signatures the disk cache holds for these sources and this CPU, as the first call of each
    would (numba loads a kernel on its first call: about 0.3 s spread over a process's first render, more on a
    loaded machine). entries_only: only the entry kernels the precompile recorded (read_entry_kernels; every
    cached signature when there is no valid list), signature by signature in the list's order (an export's and
    a default render's first). should_stop() is asked before each signature: True ends the loading there.
    Compiles nothing: an entry that does not apply here is skipped. Returns how many signatures it loaded. Safe
    beside a render on another thread: numba loads and compiles under one lock."""
    from numba.core.registry import cpu_target

    entries = read_entry_kernels() if entries_only else None
    codegen = cpu_target.target_context.codegen()
    dispatchers = _dispatchers()
    indexes: dict[int, dict] = {}

    def applicable(d) -> dict:
        """{str(signature): signature} of d's cached entries valid for these sources and this CPU."""
        if id(d) not in indexes:
            cache = getattr(d, "_cache", None)
            try:
                index = cache._cache_file._load_index()  # {} when the cache is stale or absent
            except Exception:  # noqa: BLE001 - an unreadable index is numba's to report on the first call
                index = {}
            indexes[id(d)] = {str(key[0]): key[0] for key in index
                              if cache._index_key(key[0], codegen) == key}  # else another CPU or other code
        return indexes[id(d)]

    if entries is not None:
        by_name = {_dispatcher_name(d): d for d in dispatchers}
        order = [(by_name[(module, name)], sig) for module, name, sig in entries if (module, name) in by_name]
    else:
        # lazily, so a stop is seen between the kernels' cache indexes too, not after all were read
        order = ((d, sig) for d in dispatchers if not (should_stop is not None and should_stop())
                 for sig in applicable(d))
    loaded = 0
    for d, text in order:
        sig = applicable(d).get(text)
        if sig is None or sig in d.overloads:  # not cached here, or loaded already
            continue
        if should_stop is not None and should_stop():
            return loaded
        d.compile(sig)
        loaded += 1
    return loaded


_loader: threading.Thread | None = None
_loader_lock = threading.Lock()
_stop_loading = threading.Event()
_renders = threading.Condition()  # guards _renders_running; notified when it falls or the loader is stopped
_renders_running = 0


@contextmanager
def loader_paused() -> Iterator[None]:
    """While a render runs the background loader loads nothing (it waits before its next signature): the render
    loads the kernels it calls itself, in the order it calls them, and no other feature's signature competes with
    it for the GIL and numba's lock. A `monte render X.blend` of the Cornell bench scene (64x64, 1 spp) calls 25 of
    the list's 47 signatures; the loader loading the other 22 (0.28 s) beside it made the whole process 0.1-0.3 s
    slower than no loader at all. In Blender the loader goes on after the render."""
    global _renders_running
    with _renders:
        _renders_running += 1
    try:
        yield
    finally:
        with _renders:
            _renders_running -= 1
            _renders.notify_all()


def _loader_should_stop() -> bool:
    """The background loader's check before each signature: waits while a render runs; True once stopped."""
    with _renders:
        while _renders_running and not _stop_loading.is_set():
            _renders.wait(0.5)
    return _stop_loading.is_set()


def load_cached_kernels_in_background() -> threading.Thread:
    """load_cached_kernels() on a daemon thread, started once per process (later calls return the same
    thread): the add-on starts it when it registers (after bpy's import: a thread importing modules while
    the bpy module itself is being imported can deadlock), so the kernels load while Blender starts or opens
    the file and the first render finds them loaded. stop_loading_kernels() ends it early. Errors are left to
    the first render, which loads (or compiles) the kernels itself."""
    global _loader

    def work() -> None:
        try:
            import importlib

            importlib.import_module(f"{jit_cache.PACKAGE}.render")  # the rest of the renderer's modules too
            if not _stop_loading.is_set():  # before the kernels: a render needs all of it, the list's tail not
                warm_first_render()
            if not _stop_loading.is_set():  # (stopped during the warm-up: `monte render`'s render started then;
                load_cached_kernels(should_stop=_loader_should_stop)  # reading the list etc. was ~3 ms of CPU)
        except Exception:  # noqa: BLE001 - only a head start
            pass

    with _loader_lock:
        if _loader is None:
            _stop_loading.clear()
            _loader = threading.Thread(target=work, name="monte-load-kernels", daemon=True)
            _loader.start()
        return _loader


def warm_first_render() -> None:
    """What a process's first render does once on the Python side besides loading kernels, done ahead by the
    loader thread before the kernels (every render needs all of it, whereas the kernel list's tail serves only
    some features; it runs even while a render holds loader_paused, which only holds back kernel signatures):
    NumPy's masked arrays (`np.unique`, which the export calls, imports numpy.ma on its first call: 0.014-0.04 s),
    the microfacet tables the BSDF kernels take (read from their .npz once per process: 0.002-0.03 s) and the
    Embree library (core.embree.load: embreex's import, which loads it and its TBB, and the device: ~0.008 s,
    paid by the first render even after the loader had finished every kernel). All are cached for the process,
    so a render that comes first does the same; one that comes during it waits for what is in flight (Python's
    import lock, core.embree's lock) instead of doing it twice."""
    import numpy.ma  # noqa: F401

    from . import embree
    from .microfacet import kernel_tables

    kernel_tables()
    embree.load()


def stop_loading_kernels(timeout: float = 60.0, wait: bool = True) -> None:
    """Stop the background loader after the signature it is loading (what it has not loaded, a render loads on
    its first call) and wait for it: nothing is left loading while the process or Blender shuts down.
    wait=False: only ask it to stop (it ends after its current signature; a later call with wait=True joins it)."""
    _stop_loading.set()
    with _renders:
        _renders.notify_all()
    if not wait:
        return
    with _loader_lock:
        loader = _loader
    if loader is not None:
        loader.join(timeout=timeout)


def every_feature_scene(resolution: tuple[int, int] = (12, 8)):
    """A tiny scene using every light kind, every lobe kind and Fresnel mode, a texture, smooth normals and
    UVs, seen through a thin-lens camera with aperture blades: one render reaches every material and light
    kernel."""
    from .builtin_scenes import icosphere, quad
    from .scene import AreaLight, Camera, Lobe, Material, PointLight, Scene, SpotLight, SunLight, Texture, World

    def moved(x: float, y: float, z: float) -> np.ndarray:
        m = np.eye(4)
        m[:3, 3] = (x, y, z)
        return m

    grey = np.full(3, 0.6)
    materials = [
        Material("diffuse", [Lobe("diffuse", grey, color_texture=0)]),
        Material("mirror", [Lobe("glossy", grey, roughness=0.0, fresnel="schlick")]),
        Material("rough-metal", [Lobe("glossy", grey, roughness=0.4, fresnel="none")]),
        Material("dielectric-coat", [Lobe("glossy", grey, roughness=0.2, fresnel="dielectric")]),
        Material("principled", [Lobe("glossy", np.ones(3), roughness=0.3, fresnel="generalized_schlick",
                                     f0=np.full(3, 0.04)),
                                Lobe("diffuse", grey, under=0)]),
        Material("glass", [Lobe("glass", np.ones(3), roughness=0.0, ior=1.45)]),
        Material("rough-glass", [Lobe("glass", np.ones(3), roughness=0.3, ior=1.45, fresnel="generalized_schlick",
                                      color_texture=0)]),
        Material("refraction", [Lobe("refraction", np.ones(3), roughness=0.2, ior=1.33)]),
        Material("emitter", [Lobe("diffuse", grey)], emission=np.full(3, 2.0)),
    ]
    meshes = [quad("ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], 0)]
    meshes[0].uvs = np.array([[(0, 0), (1, 0), (1, 1)], [(0, 0), (1, 1), (0, 1)]], np.float64)
    for i, material in enumerate(range(1, len(materials))):
        x = -2.4 + 0.6 * i
        meshes.append(icosphere(materials[material].name, (x, 0.5 * (i % 2), 0.3), 0.25, material,
                                smooth=i % 2 == 0))
    texels = np.linspace(0.2, 0.9, 4 * 4 * 3, dtype=np.float32).reshape(4, 4, 3)
    lights = [
        PointLight("point", np.array((0.0, -1.0, 2.0)), np.full(3, 30.0)),
        PointLight("point-radius", np.array((1.0, -1.0, 2.0)), np.full(3, 30.0), radius=0.1),
        SpotLight("spot", np.array((-1.0, -1.0, 2.0)), np.array((0.0, 0.3, -1.0)), np.full(3, 40.0), radius=0.05),
        SunLight("sun", np.array((0.3, 0.2, -1.0)), np.full(3, 1.5), angle=math.radians(3.0)),
    ]
    for i, shape in enumerate(("SQUARE", "RECTANGLE", "DISK", "ELLIPSE")):
        flipped = moved(-1.5 + i, 1.5, 2.5)
        flipped[:3, :3] = np.diag((1.0, -1.0, -1.0))  # facing down
        lights.append(AreaLight(f"area-{shape.lower()}", flipped, np.full(3, 20.0), shape=shape, size_x=0.4,
                                size_y=0.2, spread=math.radians(90.0) if i % 2 else math.pi))
    camera = Camera.look_at((0.0, -5.0, 1.5), (0.0, 0.0, 0.3), horizontal_fov=math.radians(60.0),
                            resolution=resolution)
    camera.use_dof, camera.focus_distance, camera.aperture_fstop, camera.aperture_blades = True, 5.0, 2.0, 6
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=lights,
                 world=World(np.array((0.2, 0.25, 0.3))), textures=[Texture("ramp", texels)], name="every-feature")


def _program(instructions: list[tuple[str, dict]], registers: list, lobes: int, binds: dict[tuple[int, int], int],
             emission: int = -1):
    """A ShadingProgram written by hand (what the add-on's node compiler writes): instructions (opcode name,
    {operand: value}), initial registers (floats or RGB), and the register bound to each (lobe, parameter)."""
    from .shading import registry
    from .shading.program import N_BIND, WIDTH, ShadingProgram

    code = np.full((len(instructions), WIDTH), -1, np.int32)
    for i, (name, operands) in enumerate(instructions):
        spec = registry.op(name)
        code[i, 0] = spec.code
        for j, (_, kind) in enumerate(spec.operands):
            if kind == "int":
                code[i, j + 1] = 0
        for key, value in operands.items():
            code[i, spec.slot(key)] = value
    regs = np.asarray([np.broadcast_to(np.asarray(r, np.float32), 3) for r in registers], np.float32)
    bind = np.full((lobes, N_BIND), -1, np.int32)
    for (lobe, parameter), register in binds.items():
        bind[lobe, parameter] = register
    return ShadingProgram(code, regs, bind, emission)


def node_feature_scene(resolution: tuple[int, int] = (12, 8)):
    """A tiny scene using the features whose kernels compile only when a scene has them: node programs (a
    textured, per-point roughness Principled-like material and a textured emitter: the program interpreter
    holds every node family), an environment-map world (its importance tables) and ray visibility (a sphere
    hidden from diffuse, glossy and shadow rays, one hidden from the camera)."""
    from .builtin_scenes import icosphere, quad
    from .scene import Camera, Lobe, Material, PointLight, Scene, Texture, World
    from .shading.program import BIND_ROUGHNESS, BIND_WEIGHT
    from .world import EnvironmentMap

    grey = np.full(3, 0.6)
    # registers: 0 uv, 1 image colour, 2 noise value, 3 product, 4 constant 0.5
    textured = _program([("texture_coordinate", {"uv": 0, "generated": 5}),
                         ("image", {"color": 1, "vector": 0, "texture": 0}),
                         ("math", {"out": 3, "a": 4, "b": 1, "c": 4, "operation": 2}),
                         ("mix", {"out": 2, "factor": 4, "a": 1, "b": 3})],
                        [0.0, 0.0, 0.0, 0.0, 0.5, 0.0], 2,
                        {(0, BIND_WEIGHT): 2, (0, BIND_ROUGHNESS): 3, (1, BIND_WEIGHT): 1})
    glowing = _program([("texture_coordinate", {"uv": 0}), ("image", {"color": 1, "vector": 0, "texture": 0})],
                       [0.0, 0.0], 1, {}, emission=1)
    materials = [
        Material("textured", [Lobe("glossy", np.ones(3), roughness=0.3, fresnel="generalized_schlick",
                                   f0=np.full(3, 0.04)), Lobe("diffuse", grey, under=0)], program=textured),
        Material("glowing", [Lobe("diffuse", grey)], emission=np.full(3, 1.0), program=glowing),
        Material("grey", [Lobe("diffuse", grey)]),
    ]
    ground = quad("ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], 0)
    ground.uvs = np.array([[(0, 0), (1, 0), (1, 1)], [(0, 0), (1, 1), (0, 1)]], np.float64)
    hidden = icosphere("hidden-from-rays", (-0.6, 0.0, 0.4), 0.3, 2)
    hidden.visible_diffuse = hidden.visible_glossy = hidden.visible_shadow = False
    unseen = icosphere("hidden-from-camera", (0.6, 0.0, 0.4), 0.3, 1)
    unseen.visible_camera = False
    texels = np.linspace(0.2, 0.9, 4 * 4 * 3, dtype=np.float32).reshape(4, 4, 3)
    sky = np.linspace(0.1, 2.0, 8 * 16 * 3, dtype=np.float32).reshape(8, 16, 3)
    camera = Camera.look_at((0.0, -4.0, 1.5), (0.0, 0.0, 0.3), horizontal_fov=math.radians(60.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=[ground, hidden, unseen], materials=materials,
                 lights=[PointLight("point", np.array((0.0, -1.0, 2.0)), np.full(3, 30.0))],
                 world=World(environment=EnvironmentMap(sky, name="precompile-sky")),
                 textures=[Texture("ramp", texels)], name="node-features")


def fused_program_scene(resolution: tuple[int, int] = (12, 8)):
    """A tiny scene whose node programs the fused path kernel evaluates per vertex (core.fused_tracer
    .program_reason: no normal, Bump, Light Path, emission...): on a UV-mapped floor (Principled-like glossy over
    diffuse) and two smooth balls (two objects of one glossy + diffuse material), an Image Texture on the base
    colour, Noise (of the Object coordinates) into a Color Ramp driving the specular F0 or colour, roughness from
    the Object Info Random and the texture, the Generated coordinates, Fresnel and Geometry Incoming. Its render
    compiles trace_paths' node-program signature (tests/test_fused_programs.py renders it both ways)."""
    from .builtin_scenes import icosphere, quad
    from .scene import Camera, Lobe, Material, PointLight, Scene, Texture, World
    from .shading.procedural import pack_flags
    from .shading.program import (BIND_F0, BIND_ROUGHNESS, BIND_WEIGHT, OBJECT_BOX_MIN, OBJECT_BOX_SIZE,
                                  OBJECT_INVERSE, OBJECT_LOCATION, OBJECT_RANDOM, identity_object_row)

    grey = np.full(3, 0.6)
    # registers: 0 uv, 1 generated, 2 object, 3 image colour, 4 noise fac, 5 ramp colour, 6 random,
    # 7 roughness, 8 base colour, 9 0.5, 10 scale 4, 11 detail 2, 12 roughness 0.5, 13 lacunarity 2, 14 0, 15 1
    ramp = [0.1, 0.2, 0.8, 1.0, 0.9, 0.5, 0.1, 1.0, 0.2, 0.9, 0.3, 1.0]
    noise = {"fac": 4, "vector": 2, "w": 14, "scale": 10, "detail": 11, "roughness": 12, "lacunarity": 13,
             "offset": 14, "gain": 15, "distortion": 14, "flags": pack_flags(3, 0, 1)}
    code = [("texture_coordinate", {"uv": 0, "generated": 1, "object": 2}),
            ("image", {"color": 3, "vector": 0, "texture": 0}),
            ("tex_noise", noise),
            ("color_ramp", {"color": 5, "fac": 4, "table": 0, "rows": 3, "interpolate": 1}),
            ("object_info", {"random": 6}),
            ("mix", {"out": 7, "factor": 6, "a": 9, "b": 3}),
            ("mix", {"out": 8, "factor": 1, "a": 3, "b": 5})]
    regs = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 4.0, 2.0, 0.5, 2.0, 0.0, 1.0]
    floor = _program(code, regs, 2, {(0, BIND_F0): 5, (0, BIND_ROUGHNESS): 7, (1, BIND_WEIGHT): 8})
    # the balls' glossy colour: Fresnel (IOR 1.45, register 17) mixing the ramp into the Geometry's Incoming
    ball = _program(code + [("fresnel", {"out": 16, "ior": 17}), ("geometry", {"incoming": 18}),
                            ("mix", {"out": 19, "factor": 16, "a": 5, "b": 18})],
                    regs + [0.0, 1.45, 0.0, 0.0], 2, {(0, BIND_WEIGHT): 19, (0, BIND_ROUGHNESS): 7,
                                                     (1, BIND_WEIGHT): 5})
    for p in (floor, ball):
        p.data = np.asarray(ramp, np.float32)
    materials = [
        Material("floor", [Lobe("glossy", np.ones(3), roughness=0.3, fresnel="generalized_schlick",
                                f0=np.full(3, 0.04)), Lobe("diffuse", grey, under=0)], program=floor),
        Material("ball", [Lobe("glossy", np.ones(3), roughness=0.2, fresnel="dielectric"),
                          Lobe("diffuse", grey)], program=ball),
        Material("grey", [Lobe("diffuse", grey)]),
    ]
    ground = quad("ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], 0)
    ground.uvs = np.array([[(0, 0), (1, 0), (1, 1)], [(0, 0), (1, 1), (0, 1)]], np.float64)
    meshes = [ground, icosphere("ball-a", (-0.6, 0.0, 0.4), 0.4, 1), icosphere("ball-b", (0.6, 0.0, 0.4), 0.4, 1),
              icosphere("plain", (0.0, 0.8, 0.3), 0.3, 2)]
    objects = []  # the balls as objects (Object Info Random, Texture Coordinate Object and Generated)
    for i, (center, random) in enumerate((((-0.6, 0.0, 0.4), 0.25), ((0.6, 0.0, 0.4), 0.8))):
        row = identity_object_row()
        row[OBJECT_INVERSE + 3], row[OBJECT_INVERSE + 7], row[OBJECT_INVERSE + 11] = -np.asarray(center)
        row[OBJECT_LOCATION:OBJECT_LOCATION + 3] = center
        row[OBJECT_RANDOM] = random
        row[OBJECT_BOX_MIN:OBJECT_BOX_MIN + 3] = -0.4
        row[OBJECT_BOX_SIZE:OBJECT_BOX_SIZE + 3] = 0.8
        objects.append(row)
        meshes[1 + i].object_index = i
    texels = np.linspace(0.2, 0.9, 4 * 4 * 3, dtype=np.float32).reshape(4, 4, 3)
    camera = Camera.look_at((0.0, -4.0, 1.5), (0.0, 0.0, 0.3), horizontal_fov=math.radians(60.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=meshes, materials=materials,
                 lights=[PointLight("point", np.array((0.0, -1.0, 2.0)), np.full(3, 30.0))],
                 world=World(np.array((0.2, 0.25, 0.3))), textures=[Texture("ramp", texels)], name="fused-programs",
                 objects=np.asarray(objects, np.float32))


def _fold_constants_once() -> None:
    """The add-on's node compiler folds constant subgraphs at export through evaluator.run_single (its own
    kernel): compile it here too, so that exporting a node material compiles nothing."""
    from .shading import evaluator

    program = _program([("math", {"out": 0, "a": 1, "b": 2, "c": 2, "operation": 0})], [0.0, 1.0, 2.0], 0, {})
    program.validate("precompile", 0, 0)
    evaluator.run_single(program)


def _bump_shadowing_once() -> None:
    """Points whose node program sets the normal (Normal Map, Bump) take Cycles' bump shadowing
    (geometry_kernels.bump_shadowing_terms, through the integrator's helper, on a surface batch's column views,
    and the diffuse-only lobe weights, geometry_kernels.diffuse_lobe_weights), and a Bump node's scene the
    compiled camera-ray differentials (camera.pinhole_differentials) and, where the per-bounce integrator renders
    it, the per-point differentials (geometry_kernels.differentials): compile them here, so that the first such
    render compiles nothing."""
    from . import bsdf
    from .camera import camera_rays, pinhole_differentials
    from .geometry_kernels import differentials
    from .integrator import PathTracer, SurfaceBatch, _bump_terms
    from .scene import Camera

    g = SurfaceBatch.empty(1, False)
    g.data[:] = 0.0
    none = np.zeros((0, 3), np.float32)
    for local in (False, True):
        _bump_terms(g, np.zeros(0, np.int64), none, none, local)
    lobes = bsdf.LobeBatch(kind=np.zeros((1, 1), np.int8), weight=np.zeros((1, 1, 3), np.float32),
                           roughness=np.zeros((1, 1), np.float32), ior=np.ones((1, 1), np.float32),
                           fresnel=np.zeros((1, 1), np.int8), select=np.ones((1, 1), np.float32))
    PathTracer._diffuse_only(lobes, np.zeros(1, np.int64))
    camera = Camera(matrix_world=np.eye(4), kind="PERSP", resolution=(2, 2))
    x = y = np.array([0.5])
    pinhole_differentials(camera, x, y, camera_rays(camera, x, y))
    # the per-bounce integrator's per-point ray differentials (shading.vector_context._differentials)
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    differentials(np.zeros(1, np.int64), np.array([[0, 0, 1]], np.float32), np.ones(1, np.float32), tri,
                  np.zeros((1, 3, 2), np.float32), np.empty((1, 2, 3), np.float32), np.empty((1, 2, 2), np.float32),
                  np.empty((1, 2, 2), np.float32))


def _panoramic(scene):
    """The scene seen through Cycles' equirectangular panoramic camera (its own ray kernel)."""
    scene.camera.kind = "PANO"
    scene.camera.panorama_type = "EQUIRECTANGULAR"
    return scene


def _cases() -> list[tuple[str, Callable[[], object], dict]]:
    from .builtin_scenes import BUILTIN_SCENES, builtin_scene
    from .light_passes import LIGHT_PASSES

    small = (12, 8)
    cases: list[tuple[str, Callable[[], object], dict]] = [
        (name, (lambda n=name: builtin_scene(n, small)), {}) for name in BUILTIN_SCENES]
    cases += [
        ("every-feature", every_feature_scene, {}),
        ("every-feature, no AOVs", every_feature_scene, {"aovs": False}),
        ("node programs, environment map, ray visibility", node_feature_scene, {}),
        ("node programs in the fused kernel", fused_program_scene, {}),
        ("node programs in the fused kernel, no AOVs", fused_program_scene, {"aovs": False}),
        ("spheres-sky, panoramic camera", lambda: _panoramic(builtin_scene("spheres-sky", small)), {}),
        ("cornell, stratified, tent", lambda: builtin_scene("cornell", small),
         {"sampler": "stratified", "filter_type": "tent", "filter_width": 2.0}),
        ("cornell, independent, gaussian", lambda: builtin_scene("cornell", small),
         {"sampler": "independent", "filter_type": "gaussian"}),
        ("cornell, box filter, clamp", lambda: builtin_scene("cornell", small),
         {"filter_type": "box", "filter_width": 1.0, "clamp": 4.0}),
        ("cornell, BSDF sampling only", lambda: builtin_scene("cornell", small), {"light_sampling": "bsdf"}),
        ("spheres-sky, light sampling only", lambda: builtin_scene("spheres-sky", small),
         {"light_sampling": "light"}),
        ("cornell, adaptive", lambda: builtin_scene("cornell", small),
         {"spp": 16, "adaptive_threshold": 0.05, "adaptive_min_samples": 4}),
        ("cornell, one thread", lambda: builtin_scene("cornell", small), {"threads": 1}),
        # one sample per pixel: whole tiles written without a film (core.film_kernels.one_sample_images)
        ("cornell, one sample", lambda: builtin_scene("cornell", small), {"spp": 1}),
        ("every-feature, light passes", every_feature_scene, {"light_passes": LIGHT_PASSES}),
    ]
    return cases


def _tasks() -> list[tuple[str, Callable[[], object]]]:
    """The precompile's work as (name, run) pieces in its serial order: the node compiler's constant folding
    first (as the add-on's export folds constants before its render), each case's render (a few pixels, 2
    samples), the bump-shadowing kernels last."""
    from .render import render
    from .settings import RenderSettings

    def rendering(build, overrides):
        def run():
            settings = RenderSettings(**{"spp": 2, "seed": 1, "threads": 2, "tile_size": 8, **overrides})
            render(build(), settings.validate())
        return run

    return ([("node constant folding", _fold_constants_once)]
            + [(name, rendering(build, overrides)) for name, build, overrides in _cases()]
            + [("bump shadowing", _bump_shadowing_once)])


def precompile_kernels(log: Callable[[str], None] | None = None) -> dict[str, int]:
    """Render every warm-up case (a few pixels, 2 samples each), compiling and caching each kernel the cache
    does not hold yet, and write the entry kernels they called from Python (ENTRY_KERNELS_FILE) when this
    process had run no kernel before (else the list is left as it is); returns kernel_cache_counts(), the number
    of entry signatures (None when not listed) and the seconds it took."""
    say = log or (lambda m: None)
    t0 = time.perf_counter()
    entries: dict = {}
    # A kernel this process already ran is called without being seen: the list would miss it; keep the one there.
    fresh = not any(d.signatures for d in _dispatchers())
    with _recording_entry_calls(entries):
        for name, run in _tasks():
            run()
            say(f"  {name}")
    if fresh:
        write_entry_kernels(entries)
    counts = kernel_cache_counts()
    counts["entry_signatures"] = len(entries) if fresh else None
    counts["seconds"] = time.perf_counter() - t0
    return counts


# The parallel precompile: worker processes share the task list, each claiming the next unclaimed task, and a
# signature that one is compiling the others wait for and then load from the cache instead of compiling it again.
# The two kinds of the fused path kernel (with and without node programs) are the two largest compiles (about a
# third of the whole): their tasks go first, so that two workers start one each.
_FIRST_TASKS = ("node programs in the fused kernel", "cornell")
JOBS_ENV = "MONTE_PRECOMPILE_JOBS"  # how many worker processes (default: up to 2, one per CPU core)
_MAX_DEFAULT_JOBS = 2  # measured: 2 workers on 2 cores, each at most ~1.1 GB resident while it compiles


def _parallel_order(tasks: list) -> list:
    first = [task for name in _FIRST_TASKS for task in tasks if task[0] == name]
    return first + [task for task in tasks if task not in first]


@contextmanager
def _compiles_one_process_at_a_time(lock_dir: str) -> Iterator[None]:
    """While it lasts, a Monte kernel's signature that this process does not hold yet is loaded or compiled under
    a lock file of lock_dir named after the kernel and signature: a process that finds another compiling it waits,
    and then numba loads the other's result from the cache. Taken under numba's compiler lock (re-entrant, held by
    numba's compile anyway), so this process's threads take the file locks one at a time and in numba's order;
    between processes a wait cannot go round in a circle, since a kernel waits only for the device functions it
    calls, which never call it back."""
    from numba.core import sigutils
    from numba.core.compiler_lock import global_compiler_lock
    from numba.core.dispatcher import Dispatcher

    original = Dispatcher.compile
    prefix = jit_cache.PACKAGE + "."

    def compile(self, sig):
        module = getattr(self.py_func, "__module__", None) or ""
        if not module.startswith(prefix):
            return original(self, sig)
        args, _ = sigutils.normalize_signature(sig)
        if tuple(args) in self.overloads:
            return original(self, sig)
        name = hashlib.sha256(f"{module}.{self.py_func.__qualname__}{tuple(args)}".encode()).hexdigest()[:32]
        with global_compiler_lock, jit_cache.file_lock(os.path.join(lock_dir, f"{name}.lock")):
            return original(self, sig)

    Dispatcher.compile = compile
    try:
        yield
    finally:
        Dispatcher.compile = original


def _claim(lock_dir: str, index: int) -> bool:
    """True for the one process that creates task `index`'s claim file in lock_dir."""
    try:
        os.close(os.open(os.path.join(lock_dir, f"task-{index}.claimed"), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


def precompile_worker(lock_dir: str, worker: int) -> int:
    """One worker process of the parallel precompile: runs each task of _parallel_order(_tasks()) that it claims
    first, with its compiles coordinated with the other workers' (_compiles_one_process_at_a_time); prints what
    it did and, last, its kernel_cache_counts() as JSON. Returns 0."""
    t0 = time.perf_counter()
    with _compiles_one_process_at_a_time(lock_dir):
        for index, (name, run) in enumerate(_parallel_order(_tasks())):
            if _claim(lock_dir, index):
                started = time.perf_counter()
                run()
                print(f"  {name} (worker {worker}, {time.perf_counter() - started:.1f} s)", flush=True)
    counts = kernel_cache_counts()
    counts["seconds"] = time.perf_counter() - t0
    print(json.dumps(counts), flush=True)
    return 0


def precompile_jobs() -> int:
    """How many worker processes the precompile runs: MONTE_PRECOMPILE_JOBS when set (1: one process, no workers),
    else one per CPU core up to 2; 1 where numba's cache saves are not locked (MONTE_PLAIN_NUMBA_LOADS=1 or a numba
    this package was not read for: see core/jit_cache.py), where parallel compiles could corrupt its index."""
    if not jit_cache.KERNEL_CACHES_DEFERRED:
        return 1
    text = os.environ.get(JOBS_ENV, "").strip()
    if text:
        try:
            jobs = int(text)
        except ValueError:
            raise SystemExit(f"Monte: {JOBS_ENV}={text!r} is not a whole number of processes") from None
        if jobs < 1:
            raise SystemExit(f"Monte: {JOBS_ENV}={text!r} must be at least 1")
        return jobs
    return max(1, min(os.cpu_count() or 1, _MAX_DEFAULT_JOBS))


def _python_here(code: str) -> list[str]:
    """A command running `code` in a new interpreter with this process's module path (the package may be
    importable only through it: the extension build imports it under Blender's name)."""
    return [sys.executable, "-c", f"import sys; sys.path[:0] = {sys.path!r}; {code}"]


def _precompile_in_parallel(jobs: int) -> dict | None:
    """Run `jobs` precompile workers; their output passes through. Returns the summed counts (with the wall
    seconds), or None when a worker failed (its output says why)."""
    import subprocess
    import tempfile

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="monte-precompile-") as lock_dir:
        procs = [subprocess.Popen(_python_here(f"from {jit_cache.PACKAGE}.precompile import precompile_worker; "
                                               f"sys.exit(precompile_worker({lock_dir!r}, {worker}))"),
                                  stdout=subprocess.PIPE, text=True) for worker in range(jobs)]
        counts: list[dict] = [{} for _ in procs]  # each worker's closing counts, filled by its own relay thread

        def relay(proc, into: dict) -> None:
            for line in proc.stdout:
                if line.startswith("{"):
                    try:
                        into.update(json.loads(line))
                        continue
                    except ValueError:
                        pass
                print(line, end="", flush=True)

        relays = [threading.Thread(target=relay, args=(proc, into), daemon=True) for proc, into in zip(procs, counts)]
        for thread in relays:
            thread.start()
        failed = False
        for proc, thread in zip(procs, relays):
            failed |= proc.wait() != 0
            thread.join()
    if failed:
        return None
    totals = {key: sum(c.get(key, 0) for c in counts) for key in ("compiled", "loaded")}
    totals["seconds"] = time.perf_counter() - t0
    return totals


def main() -> int:
    jobs = precompile_jobs()
    print(f"Monte: compiling the render kernels for {jit_cache.KERNEL_CPU} CPUs into {jit_cache.cache_dir()} "
          f"(cached: the first time takes about three to four minutes of CPU"
          f"{f', in {jobs} processes' if jobs > 1 else ''})", flush=True)
    if jobs > 1:
        counts = _precompile_in_parallel(jobs)
        if counts is None:
            print("Monte: a precompile worker failed (see above)", flush=True)
            return 1
        print(f"Monte: {counts.get('compiled', 0)} kernel signatures compiled, {counts.get('loaded', 0)} loaded from "
              f"the cache, by {jobs} processes in {counts['seconds']:.1f} s", flush=True)
    else:
        counts = precompile_kernels(log=lambda m: print(m, flush=True))
        print(f"Monte: {counts['compiled']} kernel signatures compiled, {counts['loaded']} loaded from the cache, "
              f"{counts['used']} of {counts['kernels']} kernels used, {counts['seconds']:.1f} s", flush=True)
    if jobs > 1 or counts["compiled"]:
        # A kernel compiled first as another's device function, then called from Python, was not seen being
        # called (numba had it already): list the entry kernels from a process that finds them all cached.
        # (The workers list none: each ran only some of the cases.)
        import subprocess

        proc = subprocess.run(_python_here(f"from {jit_cache.PACKAGE}.precompile import precompile_kernels; "
                                           "print(precompile_kernels()['entry_signatures'])"),
                              capture_output=True, text=True)
        if proc.returncode != 0:
            print(f"Monte: listing the entry kernels failed:\n{proc.stderr[-2000:]}", flush=True)
            return 1
        counts["entry_signatures"] = proc.stdout.strip().splitlines()[-1]
    print(f"Monte: {counts['entry_signatures']} entry signatures listed in {entry_kernels_path()}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
