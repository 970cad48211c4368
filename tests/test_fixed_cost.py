"""A render's fixed cost: what the `monte` command imports before it needs it, and the add-on's kernel loader
(only the kernels a render calls from Python, in the order renders need them, stopped when the add-on
unregisters). Speed itself is measured by `monte bench --vs cycles --whole-process` and lab/fixed_cost.py,
never asserted here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

from monte.core import jit_cache, precompile

HEAVY = ("numba", "llvmlite", "dask", "distributed", "OpenEXR", "bpy", "scipy")


def _python(code: str, cwd=None) -> dict:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != jit_cache.KERNEL_CPU_ENV}
    if cwd is not None:  # (the package must stay importable from another folder)
        clean["PYTHONPATH"] = os.pathsep.join([os.path.dirname(os.path.dirname(os.path.abspath(jit_cache.__file__)))]
                                              + [p for p in clean.get("PYTHONPATH", "").split(os.pathsep) if p])
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=600, env=clean, cwd=cwd)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return json.loads(lines[-1][len("RESULT "):])


def test_the_command_line_imports_no_heavy_module_before_it_needs_one():
    """Parsing any command and listing the built-in scenes import none of numba, Dask, OpenEXR, bpy, scipy;
    a built-in scene's construction neither (the world's kernels load on its first use)."""
    result = _python(f"""
        import json, sys
        from monte.cli import build_parser, main
        build_parser().parse_args(["render", "scene.blend", "-o", "out.exr", "--spp", "1"])
        after_parse = [m for m in {HEAVY!r} if m in sys.modules]
        # nor NumPy or a lab command's module: their options come from lab/bench_args.py (argparse only)
        parser_extra = sorted(m for m in sys.modules if m == "numpy" or m.startswith("monte.lab.")
                              and m != "monte.lab.bench_args")
        main(["render", "--list"])
        from monte.core.builtin_scenes import builtin_scene
        builtin_scene("cornell", (8, 8))
        after_list = [m for m in {HEAVY!r} if m in sys.modules]
        from monte.core import render  # the renderer itself does import numba: the check above can fail
        print("RESULT " + json.dumps({{"parse": after_parse, "parser_extra": parser_extra, "list": after_list,
                                      "render": "numba" in sys.modules}}))
    """)
    assert result == {"parse": [], "parser_extra": [], "list": [], "render": True}


def test_entry_kernel_list_round_trip_and_staleness(tmp_path, monkeypatch):
    path = tmp_path / precompile.ENTRY_KERNELS_FILE
    monkeypatch.setattr(precompile, "entry_kernels_path", lambda: str(path))
    monkeypatch.setattr(jit_cache, "cache_dir", lambda: str(tmp_path))
    assert precompile.read_entry_kernels() is None  # none written: every cached signature is loaded
    # one row per signature, in the order of first calls (the loading order): a kernel's second signature
    # (another feature's) after a kernel the first case called later
    found = {("embree", "trace_closest", "(int64,)"): None, ("camera", "_camera_rays", "(array(float64, 2d, C),)"):
             None, ("embree", "trace_closest", "(int32,)"): None}
    precompile.write_entry_kernels(found)
    assert precompile.read_entry_kernels() == list(found)
    body = json.loads(path.read_text())
    earlier = {k: v for k, v in body.items() if k != "format"}  # the first format: one row per kernel
    earlier["kernels"] = [["embree", "trace_closest", ["(int32,)", "(int64,)"]], ["camera", "_camera_rays", ["(x,)"]]]
    path.write_text(json.dumps(earlier))
    assert precompile.read_entry_kernels() == [("embree", "trace_closest", "(int32,)"),
                                               ("embree", "trace_closest", "(int64,)"),
                                               ("camera", "_camera_rays", "(x,)")]
    path.write_text(json.dumps(dict(body, format=99)))  # a format this version does not know: ignored
    assert precompile.read_entry_kernels() is None
    body["sources"] = "0" * 64  # written for other sources (an edited kernel module): ignored
    path.write_text(json.dumps(body))
    assert precompile.read_entry_kernels() is None
    path.write_text("{not json")
    assert precompile.read_entry_kernels() is None


def test_the_loader_loads_only_entry_kernels_and_they_cover_a_render():
    """The precompile (in a fresh process) lists its entry kernels: far fewer than the signatures the cache holds
    (device functions are carried inside their callers), and a render after loading them loads and compiles
    nothing more. A process that had run kernels before does not rewrite the list (it would miss those)."""
    written = _python("""
        import json
        from monte.core.precompile import precompile_kernels
        print("RESULT " + json.dumps(precompile_kernels()))
    """)  # a few seconds when `make setup` built the cache
    entries = precompile.read_entry_kernels()
    assert entries is not None and written["entry_signatures"] == len(entries) == len(set(entries))
    result = _python("""
        import json
        from monte.core.precompile import (entry_kernels_path, kernel_cache_counts, load_cached_kernels,
                                           precompile_kernels)
        from monte.core.builtin_scenes import builtin_scene
        from monte.core.render import render
        from monte.core.settings import RenderSettings
        counted = []
        stopped = load_cached_kernels(should_stop=lambda: len(counted) >= 3 or counted.append(1))
        preloaded = stopped + load_cached_kernels()
        before = kernel_cache_counts()
        render(builtin_scene("cornell", (16, 16)), RenderSettings(spp=2, threads=2))
        after = kernel_cache_counts()
        everything = load_cached_kernels(entries_only=False)
        listed = open(entry_kernels_path()).read()
        again = precompile_kernels()["entry_signatures"]
        print("RESULT " + json.dumps({"stopped": stopped, "preloaded": preloaded, "before": before,
                                      "after": after, "rest": everything, "again": again,
                                      "kept": open(entry_kernels_path()).read() == listed}))
    """)
    listed = len(entries)
    assert result["stopped"] == 3  # should_stop() True ends the loading there
    assert result["preloaded"] == result["before"]["loaded"] == listed
    assert result["after"]["compiled"] == 0
    assert result["after"]["loaded"] == result["before"]["loaded"]  # the render found its kernels loaded
    assert result["rest"] > 2 * listed  # what the loader no longer loads: device functions nobody calls
    assert result["again"] is None and result["kept"]


def test_unregister_stops_the_loader():
    """`monte render X.blend` ends by unregistering: the loader stops after its current kernel instead of
    loading the rest first."""
    result = _python("""
        import json, time
        import bpy
        import monte
        from monte.core import precompile
        monte.register()
        loader = precompile._loader
        monte.unregister()
        print("RESULT " + json.dumps({"started": loader is not None, "alive": loader.is_alive(),
                                      "stop_set": precompile._stop_loading.is_set()}))
    """)
    assert result == {"started": True, "alive": False, "stop_set": True}


def test_cold_cache_check_lists_the_folder_once(tmp_path, monkeypatch):
    """compile_cache_is_cold: cold while a module every render runs has no index in the cache folder, warm once
    each has one (and then remembered for the process)."""
    monkeypatch.setattr(jit_cache, "cache_dir", lambda: str(tmp_path))
    monkeypatch.setattr(jit_cache, "_cache_warm", {False: False, True: False})
    common = [n for n in jit_cache.KERNEL_MODULES if n not in jit_cache.FEATURE_KERNEL_MODULES]
    for name in common[:-1]:
        (tmp_path / f"{os.path.basename(name)}.kernel-12.py313.nbi").write_bytes(b"")
    (tmp_path / f"{os.path.basename(common[-1])}.kernel-12.py313.1.nbc").write_bytes(b"")  # data, no index
    assert jit_cache.compile_cache_is_cold()
    (tmp_path / f"{os.path.basename(common[-1])}.kernel-12.py313.nbi").write_bytes(b"")
    assert not jit_cache.compile_cache_is_cold()
    assert jit_cache.compile_cache_is_cold(with_node_programs=True)  # the node evaluator's modules: no index yet


def test_kernel_loading_skips_scipy_linear_algebra_and_numba_linalg_still_works():
    """numba's array support is imported without its SciPy BLAS lookup (scipy.linalg's import was ~0.45 s of a
    process's first kernel load), and only when numba first compiles (cached kernels load without it: ~0.025 s of
    CPU): loading the cached kernels imports neither numba.np.arraymath nor scipy.linalg; a function compiled
    afterwards imports arraymath still without the lookup, and numba's own np.dot still finds the BLAS (only its
    np.correlate/np.convolve inner product uses a plain loop)."""
    result = _python("""
        import json, sys
        import numpy as np
        from monte.core import jit_cache, precompile
        import monte.core.render  # noqa: F401
        loaded = precompile.load_cached_kernels()
        arraymath_after_load = "numba.np.arraymath" in sys.modules
        linalg_after_load = "scipy.linalg" in sys.modules
        import numba

        @numba.njit
        def product(a, b):
            return np.dot(a, b)

        a = np.array([[1.0, 2.0], [3.0, 4.0]])
        b = np.array([[5.0, 6.0], [7.0, 8.0]])
        dot = product(a, b).tolist()
        print("RESULT " + json.dumps({"patched": jit_cache.NUMBA_ARRAY_SUPPORT_WITHOUT_BLAS, "loaded": loaded,
                                      "arraymath_after_load": arraymath_after_load,
                                      "linalg_after_load": linalg_after_load,
                                      "have_blas": sys.modules["numba.np.arraymath"]._HAVE_BLAS,
                                      "dot": dot, "numpy_dot": (a @ b).tolist()}))
    """)
    assert result["patched"] is True and result["loaded"] > 0
    assert result["arraymath_after_load"] is False and result["linalg_after_load"] is False
    assert result["have_blas"] is False
    assert result["dot"] == result["numpy_dot"] == [[19.0, 22.0], [43.0, 50.0]]


def test_entry_kernels_list_an_export_and_a_default_render_first():
    """The loader loads signature by signature in the list's order: first the export's constant folding, then
    exactly the signatures a default render of the first built-in scene calls, so such a render started while
    the loader works finds its kernels loaded in the order it asks for them (other features' come after)."""
    entries = precompile.read_entry_kernels()
    assert entries is not None
    result = _python("""
        import json
        from monte.core import precompile
        from monte.core.builtin_scenes import BUILTIN_SCENES, builtin_scene
        from monte.core.render import render
        from monte.core.settings import RenderSettings
        render(builtin_scene(list(BUILTIN_SCENES)[0], (16, 16)), RenderSettings(spp=2, threads=2).validate())
        used = [[*precompile._dispatcher_name(d), str(sig)] for d in precompile._dispatchers() for sig in d.overloads]
        print("RESULT " + json.dumps(used))
    """)
    used = {tuple(row) for row in result}
    assert entries[0][:2] == ("shading/evaluator", "_run_one")
    assert set(entries[1:1 + len(used)]) == used
    assert len(entries) > len(used) + 1  # other features' signatures follow


def test_the_loader_warms_what_a_first_render_does_once():
    """The loader thread does a first render's once-per-process Python work ahead: NumPy's masked arrays
    (np.unique, which the export calls, imports them), the microfacet tables and the Embree library (embreex's
    import and the device, which a first render paid even after the loader had loaded every kernel)."""
    result = _python("""
        import json, sys
        from monte.core import embree, microfacet, precompile
        import monte.core.render  # noqa: F401

        def state():
            return ["numpy.ma" in sys.modules, microfacet.kernel_tables.cache_info().currsize,
                    "embreex" in sys.modules, embree._library is not None]
        before = state()
        precompile.load_cached_kernels_in_background().join()
        print("RESULT " + json.dumps({"before": before, "after": state()}))
    """)
    assert result == {"before": [False, 0, False, False], "after": [True, 1, True, True]}


def test_the_loader_waits_while_a_render_runs():
    """While a render runs (precompile.loader_paused, which the engine's render holds) the background loader loads
    nothing: the render loads what it calls itself, and the list's other signatures do not compete with it. It
    goes on once the render is over; stopped during a render it ends (the end of `monte render X.blend`). The
    once-per-process work a render needs whatever it calls (warm_first_render) comes first and is not held back."""
    result = _python("""
        import json, sys
        from monte.core import embree, precompile
        with precompile.loader_paused():
            loader = precompile.load_cached_kernels_in_background()
            loader.join(timeout=10)  # loading all of them takes ~1-2 s
            during = [loader.is_alive(), precompile.kernel_cache_counts()["loaded"],
                      "numpy.ma" in sys.modules, embree._library is not None]
        loader.join()
        after = precompile.kernel_cache_counts()["loaded"]
        precompile._loader = None  # a second loader, stopped while a render runs
        precompile._stop_loading.clear()
        with precompile.loader_paused():
            second = precompile.load_cached_kernels_in_background()
            precompile.stop_loading_kernels()
            stopped = second.is_alive()
        print("RESULT " + json.dumps({"during": during, "after": after, "stopped_alive": stopped,
                                      "entries": len(precompile.read_entry_kernels())}))
    """)
    assert result["during"] == [True, 0, True, True]
    assert result["after"] == result["entries"] > 0
    assert result["stopped_alive"] is False


def test_a_loader_stopped_during_its_warm_up_reads_no_kernel_list():
    """A loader stopped while it warms up (a `monte render X.blend` whose render started then) ends without
    reading the entry list, listing the dispatchers or reading their cache indexes (~3 ms of CPU beside the
    export); one not stopped goes on to the kernels."""
    result = _python("""
        import json
        from monte.core import precompile
        calls = []
        warm = precompile.warm_first_render
        precompile.load_cached_kernels = lambda **k: calls.append("kernels") or 0

        def warm_then_stop():
            warm()
            calls.append("warm")
            precompile.stop_loading_kernels(wait=False)  # as `monte render` does when its render starts

        precompile.warm_first_render = warm_then_stop
        precompile.load_cached_kernels_in_background().join()
        stopped = list(calls)
        precompile._loader, calls[:] = None, []
        precompile._stop_loading.clear()
        precompile.warm_first_render = lambda: calls.append("warm")
        precompile.load_cached_kernels_in_background().join()
        print("RESULT " + json.dumps({"stopped": stopped, "not_stopped": calls}))
    """)
    assert result == {"stopped": ["warm"], "not_stopped": ["warm", "kernels"]}


def test_numba_is_imported_without_its_scipy_check_and_scipy_still_imports():
    """numba's __init__ imports SciPy only to refuse one older than 1.0; Monte's import of numba hides SciPy for
    that one import: importing the renderer imports no SciPy, and SciPy imports normally afterwards."""
    result = _python("""
        import importlib.util, json, sys
        from monte.core import jit_cache
        import monte.core.render  # noqa: F401
        after_import = "scipy" in sys.modules
        have = importlib.util.find_spec("scipy") is not None
        imported = None
        if have:
            import scipy
            imported = scipy.__name__
        print("RESULT " + json.dumps({"patched": jit_cache.NUMBA_IMPORTED_WITHOUT_SCIPY, "numba": "numba" in
                                      sys.modules, "after_import": after_import, "have": have,
                                      "imported": imported}))
    """)
    assert result["patched"] is True and result["numba"] is True
    assert result["after_import"] is False
    assert result["imported"] == ("scipy" if result["have"] else None)


_YAML_CONFIG = """
    import json, os, sys
    from monte.core import jit_cache
    import numba
    from numba.core import config
    at_import = "yaml" in sys.modules, config.BOUNDSCHECK
    with open(".numba_config.yaml", "w") as fh:
        fh.write("boundscheck: 1\\n")
    config.reload_config()  # (numba's compiler does this before each compile)
    print("RESULT " + json.dumps({"patched": jit_cache.NUMBA_IMPORTED_WITHOUT_SCIPY, "at_import": at_import,
                                  "after": ["yaml" in sys.modules, config.BOUNDSCHECK]}))
"""


def test_numba_is_imported_without_yaml_and_still_reads_its_config_file(tmp_path):
    """numba's config imports PyYAML only to read a `.numba_config.yaml`: without one in the working folder,
    Monte's import of numba imports no YAML, and a config file written later is still read (YAML imported then).
    With the file there at import, numba imports YAML and reads it as always."""
    import pytest

    pytest.importorskip("yaml")
    (tmp_path / "a").mkdir()
    without = _python(_YAML_CONFIG, cwd=tmp_path / "a")
    assert without["patched"] is True
    assert without["at_import"] == [False, None] and without["after"] == [True, 1]
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / ".numba_config.yaml").write_text("boundscheck: 1\n")
    with_file = _python(_YAML_CONFIG, cwd=tmp_path / "b")
    assert with_file["at_import"] == [True, 1] and with_file["after"] == [True, 1]


def _save_plane_blend(plane_scene: str) -> str:
    """A script that builds the plane scene (tests/plane_scene.py's PLANE_SCENE, with a camera) at 12x8 pixels
    and saves it as the .blend file named by its first argument."""
    return textwrap.dedent("""
        import sys
        import bpy
        bpy.ops.wm.read_factory_settings(use_empty=True)
        with_camera = True
        # PLANE_SCENE
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 12, 8, 100
        bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1])
    """).replace("# PLANE_SCENE\n", plane_scene)


def test_a_headless_render_stops_the_loader_when_its_render_starts(tmp_path):
    """`monte render X.blend` renders once: the loader is asked to stop as its render starts (it was paused during
    the render and loaded other features' kernels after it, until the exit stopped it), before the add-on
    unregisters."""
    import pytest

    pytest.importorskip("bpy")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from plane_scene import PLANE_SCENE

    blend, out = tmp_path / "plane.blend", tmp_path / "out.exr"
    code = _save_plane_blend(PLANE_SCENE) + textwrap.dedent("""
        import json
        from monte.addon import engine, headless
        from monte.core import precompile
        seen = {}
        original = engine.render_with_operator

        def render_with_operator(*args, **kwargs):
            seen["stop_set_at_render"] = precompile._stop_loading.is_set()
            return original(*args, **kwargs)

        engine.render_with_operator = render_with_operator
        headless.render_blend_file(sys.argv[1], sys.argv[2], {"spp": 1}, log=lambda _m: None)
        loader = precompile._loader
        loader.join(timeout=60)
        seen.update(started=loader is not None, alive_after=loader.is_alive(),
                    registered=__import__("monte.addon", fromlist=["is_registered"]).is_registered())
        print("RESULT " + json.dumps(seen))
    """)
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != jit_cache.KERNEL_CPU_ENV}
    proc = subprocess.run([sys.executable, "-c", code, str(blend), str(out)], capture_output=True, text=True,
                          timeout=600, env=clean)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    result = json.loads(lines[-1][len("RESULT "):])
    assert result == {"stop_set_at_render": True, "started": True, "alive_after": False, "registered": True}
    assert out.is_file()


def test_a_headless_render_imports_nothing_it_does_not_use(tmp_path):
    """`monte render X.blend` of a scene without a sky world (the plane scene): numba's NumPy-array and number
    implementations (numba.np.arrayobj, numba.cpython.numbers: named by the cached kernels' environments, 0.02-0.06
    s), PyYAML, SciPy, numba's registries (numba.typed's list implementation), core.sky, the built-in scenes and
    the lab's command-line options (other subcommands') stay unimported; the image is written."""
    import pytest

    pytest.importorskip("bpy")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from plane_scene import PLANE_SCENE

    blend, out = tmp_path / "plane.blend", tmp_path / "out.exr"
    save = _save_plane_blend(PLANE_SCENE)
    render = textwrap.dedent("""
        import json, os, sys
        WATCH = ("numba.np.arrayobj", "numba.cpython.numbers", "yaml", "scipy", "numba.typed.listobject",
                 "monte.core.sky", "monte.core.builtin_scenes", "monte.lab.bench_args")
        real_exit = os._exit

        def exit_(status):
            print("RESULT " + json.dumps({"status": status, "imported": [m for m in WATCH if m in sys.modules],
                                          "numba": "numba" in sys.modules}))
            sys.stdout.flush()
            real_exit(status)

        os._exit = exit_
        sys.argv = ["monte", "render", sys.argv[1], "-o", sys.argv[2], "--no-png", "-q", "--spp", "1"]
        from monte import cli
        cli.run()
    """)
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != jit_cache.KERNEL_CPU_ENV}
    for code in (save, render):
        proc = subprocess.run([sys.executable, "-c", code, str(blend), str(out)], capture_output=True, text=True,
                              timeout=600, env=clean, cwd=tmp_path)
        assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert lines, proc.stdout[-3000:]
    assert json.loads(lines[-1][len("RESULT "):]) == {"status": 0, "imported": [], "numba": True}
    assert out.is_file()


def test_a_render_says_when_it_compiles_a_kernel_the_cache_lacks():
    """A render whose cache is not cold but lacks a kernel the scene needs (a built-in scene other than the Cornell
    box after `make render`'s shipped kernels) says so once, when numba starts compiling it (numba's
    "numba:compile" event: fired on cache misses only, here triggered on the render's thread with one of Monte's
    cached kernels); nothing is said after the render, nor for another package's function."""
    import numba
    from numba.core import event as numba_events

    from monte.core import builtin_scenes, embree
    from monte.core.render import render
    from monte.core.settings import RenderSettings

    messages: list[str] = []
    plain = numba.njit(lambda x: x)

    def compile_event(dispatcher) -> None:
        with numba_events.trigger_event("numba:compile", data={"dispatcher": dispatcher, "args": (),
                                                               "return_type": None}):
            pass

    def progress(_p) -> None:
        compile_event(plain)
        compile_event(embree.trace_closest)
        compile_event(embree.trace_closest)

    scene = builtin_scenes.builtin_scene("plane-world", (8, 8))
    render(scene, RenderSettings(spp=1, threads=1), on_progress=progress, log=messages.append)
    notices = [m for m in messages if m.startswith("compiling")]
    assert notices == ["compiling the render kernels this scene needs that the kernel cache does not hold yet "
                       "(embree.trace_closest first; once, cached after)"], messages
    compile_event(embree.trace_closest)
    assert [m for m in messages if m.startswith("compiling")] == notices


def test_a_real_compile_of_a_kernel_is_said_and_a_cached_one_is_not(tmp_path):
    """The compile notice on a real cache miss: under an import name of its own (its own, empty kernel cache
    folder), the first process compiles Embree's closest-hit kernel and is told once; the next process loads it
    from the cache and is told nothing (nor for a function numba compiles that is not Monte's)."""
    import shutil
    from pathlib import Path

    root = Path(jit_cache.__file__).resolve().parent.parent
    (tmp_path / "montenotice").symlink_to(root, target_is_directory=True)
    cache = root / "core" / "__pycache__" / "numba-montenotice.core"
    shutil.rmtree(cache, ignore_errors=True)
    code = f"""
        import json, sys
        sys.path.insert(0, {str(tmp_path)!r})
        sys.modules["monte"] = None
        import numba
        import numpy as np
        from montenotice.core import jit_cache
        from montenotice.core.accel import Accelerator
        told = []
        with jit_cache.compile_notices(told.append):
            numba.njit(lambda x: x + 1)(1)
            accel = Accelerator(np.array([[0, 0, 1], [2, 0, 1], [0, 2, 1]], np.float32),
                                np.array([[0, 1, 2]], np.int32))
            hits = accel.intersect(np.array([[0.5, 0.5, 0]], np.float32), np.array([[0, 0, 1]], np.float32))
        print("RESULT " + json.dumps({{"told": told, "prim": int(hits.prim[0])}}))
    """
    try:
        first, second = _python(code, cwd=str(tmp_path)), _python(code, cwd=str(tmp_path))
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    assert first["prim"] == second["prim"] == 0
    assert len(first["told"]) == 1 and first["told"][0].startswith(
        "compiling the render kernels this scene needs that the kernel cache does not hold yet ("), first
    assert second["told"] == [], second
