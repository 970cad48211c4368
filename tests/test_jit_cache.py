"""The kernels' disk cache: keyed by the sources' contents, so a cache built once (`make setup`, the extension
zip) stays valid when checking out or unzipping rewrites the file times, and any edit of any kernel module
invalidates every kernel (kernels call and inline functions of other modules: core.warps, core.geometry_kernels;
numba alone checks only the file a function is defined in). Kernels are compiled for a named CPU level
(x86-64-v3 or generic), so a cache built on one machine applies on another of its level; a process that finds a
built cache compiles nothing."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import textwrap

import pytest

from monte.core import jit_cache, light_kernels

CORE = os.path.dirname(jit_cache.__file__)


def _stamp(dispatcher):
    py_func = dispatcher.py_func
    locator = jit_cache._PerImportNameLocator.from_function(py_func, py_func.__code__.co_filename)
    assert locator is not None, "core's kernels are cached by the per-import-name locator"
    return locator.get_source_stamp()


@pytest.fixture
def sources(tmp_path):
    """A copy of the kernel modules (the files the cache key covers)."""
    for name in jit_cache.KERNEL_MODULES:
        (tmp_path / f"{name}.py").parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(os.path.join(CORE, f"{name}.py"), tmp_path / f"{name}.py")
    return tmp_path


def test_the_stamp_is_the_contents_of_every_kernel_module():
    own = light_kernels.__file__
    assert _stamp(light_kernels.sample_batch) == ("sha256", jit_cache.file_digest(own), jit_cache.sources_digest())
    assert len(jit_cache.sources_digest()) == 64


@pytest.mark.parametrize("name", ["warps", "geometry_kernels", "light_kernels"])
def test_editing_any_kernel_module_changes_the_key(sources, name):
    before = jit_cache.sources_digest(str(sources))
    path = sources / f"{name}.py"
    path.write_text(path.read_text() + "\n# an edit\n")
    assert jit_cache.sources_digest(str(sources)) != before


def test_other_numba_options_change_the_key(sources, monkeypatch):
    before = jit_cache.sources_digest(str(sources))
    monkeypatch.setattr(jit_cache, "OPTIONS_KEY", jit_cache.OPTIONS_KEY.replace("'numpy'", "'python'"))
    assert jit_cache.sources_digest(str(sources)) != before


def test_new_file_times_alone_keep_the_key(sources):
    """Unzipping the extension or checking out the repository writes new times: the cache must still apply."""
    before = jit_cache.sources_digest(str(sources))
    for name in jit_cache.KERNEL_MODULES:
        path = sources / f"{name}.py"
        st = os.stat(path)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 3_600_000_000_000))
    assert jit_cache.sources_digest(str(sources)) == before


def test_an_unreadable_module_never_matches(sources):
    before = jit_cache.sources_digest(str(sources))
    os.remove(sources / "warps.py")
    assert jit_cache.file_digest(str(sources / "warps.py")) == ""
    assert jit_cache.sources_digest(str(sources)) != before


@pytest.mark.parametrize("name", jit_cache.KERNEL_MODULES)
def test_every_kernel_module_is_there(name):
    # a module missing from the list would not invalidate its callers; a stale name would stamp nothing
    assert os.path.isfile(os.path.join(CORE, f"{name}.py"))


def test_the_list_names_every_module_a_render_compiles():
    """KERNEL_MODULES (the cold-cache notice and the stamp above) lists every module that defines kernels, but
    microfacet, whose kernels only the table generator and tests run (listing it would make every render
    announce a compile that never happens)."""
    core = os.path.dirname(jit_cache.__file__)
    decorators = re.compile(r"from \.\.?jit_cache import (jit|jit_no_nrt|jit_inline)\b")
    users = {os.path.join(folder, name[:-3]) for folder in ("", "shading")
             for name in os.listdir(os.path.join(core, folder)) if name.endswith(".py")
             and decorators.search(open(os.path.join(core, folder, name)).read())}
    assert users - set(jit_cache.KERNEL_MODULES) == {"microfacet"}
    assert set(jit_cache.KERNEL_MODULES) <= users


def test_a_subpackage_kernel_is_cached_by_the_per_import_name_locator():
    """core/shading/'s kernels cache in the import name's folder too (not next to their sources, where another
    import name of the package would read them)."""
    from monte.core.shading import color

    py_func = color.mix_color.py_func
    locator = jit_cache._PerImportNameLocator.from_function(py_func, py_func.__code__.co_filename)
    assert locator is not None and locator.get_cache_path() == jit_cache.cache_dir()


def _python(code: str, **env) -> dict:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != jit_cache.KERNEL_CPU_ENV}
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=900, env={**clean, **env})
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return json.loads(lines[-1][len("RESULT "):])


def _host_level() -> str:
    """The level LLVM's report of this machine's CPU calls for (what the default, auto, must pick); which features
    make a level is test_the_cpu_level_is_x86_64_v3_only_with_all_its_features'."""
    import llvmlite.binding as ll

    return jit_cache.level_kernel_cpu(ll.get_process_triple(), dict(ll.get_host_cpu_features()))


def test_kernels_are_compiled_for_the_cpu_level_not_the_exact_cpu():
    code = """
        import json
        from monte.core import jit_cache, warps
        from numba.core.registry import cpu_target
        print("RESULT " + json.dumps({"cpu": jit_cache.KERNEL_CPU,
                                      "magic": list(cpu_target.target_context.codegen().magic_tuple())}))
    """
    level = _host_level()
    for env, expected in (({}, level), ({"MONTE_KERNEL_CPU": "auto"}, level),
                          ({"MONTE_KERNEL_CPU": "generic"}, "generic")):
        result = _python(code, **env)
        assert result["cpu"] == expected, env
        assert result["magic"][1:] == [expected, ""], env  # the CPU name and features numba keys the cache by


def test_the_cpu_level_is_x86_64_v3_only_with_all_its_features():
    everything = {f: True for f in jit_cache.X86_64_V3_FEATURES}
    assert jit_cache.level_kernel_cpu("x86_64-unknown-linux-gnu", everything) == "x86-64-v3"
    assert jit_cache.level_kernel_cpu("x86_64-pc-windows-msvc", {**everything, "avx512f": True}) == "x86-64-v3"
    for missing in ("avx2", "fma", "bmi2", "movbe", "sse4.2"):
        assert jit_cache.level_kernel_cpu("x86_64-unknown-linux-gnu", {**everything, missing: False}) == "generic"
    assert jit_cache.level_kernel_cpu("x86_64-apple-darwin", {}) == "generic"
    assert jit_cache.level_kernel_cpu("aarch64-unknown-linux-gnu", everything) == "generic"
    assert jit_cache.level_kernel_cpu("arm64-apple-darwin", everything) == "generic"


def test_a_level_the_cpu_lacks_or_an_unknown_choice_warns_and_falls_back():
    code = """
        import json, warnings
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            from monte.core import jit_cache
        print("RESULT " + json.dumps({"cpu": jit_cache.KERNEL_CPU, "warnings": [str(w.message) for w in caught]}))
    """
    result = _python(code, MONTE_KERNEL_CPU="pentium")
    assert result["cpu"] == _host_level()
    assert any("MONTE_KERNEL_CPU='pentium' is not one of auto, generic, x86-64-v3, host" in w
               for w in result["warnings"]), result["warnings"]
    result = _python(code, MONTE_KERNEL_CPU="x86-64-v3")
    if _host_level() == "x86-64-v3":
        assert result["cpu"] == "x86-64-v3" and not result["warnings"], result
    else:
        assert result["cpu"] == "generic"
        assert any("compiling for a generic CPU" in w for w in result["warnings"]), result["warnings"]


def test_child_processes_choose_their_own_level_unless_the_user_chose():
    code = """
        import json, os
        from monte.core import jit_cache
        child = jit_cache.child_environment()
        print("RESULT " + json.dumps({"cpu": jit_cache.KERNEL_CPU, "own": os.environ.get("NUMBA_CPU_NAME"),
                                      "child": [child.get("NUMBA_CPU_NAME"), child.get("NUMBA_CPU_FEATURES")],
                                      "other": child.get("MONTE_TEST_MARK")}))
    """
    # Monte wrote its level into its own environment (numba re-reads it); a child process does not inherit that ...
    result = _python(code, MONTE_KERNEL_CPU="generic", MONTE_TEST_MARK="kept")
    assert result["cpu"] == "generic" and result["own"] == "generic"
    assert result["child"] == [None, None] and result["other"] == "kept"
    # ... but a level the user set is passed on
    result = _python(code, NUMBA_CPU_NAME="generic", NUMBA_CPU_FEATURES="")
    assert result["cpu"] == "generic" and result["child"] == ["generic", ""]
    # and an explicit environment is filtered the same way, without touching this process's
    written = dict(jit_cache.NUMBA_ENVIRONMENT_WRITTEN)
    if written:
        assert not set(written) & set(jit_cache.child_environment({**written, "PATH": "/bin"}))
    assert jit_cache.child_environment({"NUMBA_CPU_NAME": "users-own"})["NUMBA_CPU_NAME"] == "users-own"


def test_host_tuned_kernels_on_request_and_after_another_package_compiled():
    result = _python("""
        import json, warnings
        import numba
        numba.njit(lambda x: x + 1)(1)  # another package's kernel: numba's code generator now exists
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            from monte.core import jit_cache
        print("RESULT " + json.dumps({"cpu": jit_cache.KERNEL_CPU, "warnings": [str(w.message) for w in caught]}))
    """)
    assert result["cpu"] == "host"
    assert any("compiled once on the first render" in w for w in result["warnings"]), result["warnings"]
    assert _python("""
        import json
        from monte.core import jit_cache
        print("RESULT " + json.dumps({"cpu": jit_cache.KERNEL_CPU}))
    """, MONTE_KERNEL_CPU="host")["cpu"] == "host"


PRECOMPILE = """
    import json
    from monte.core.precompile import precompile_kernels
    print("RESULT " + json.dumps(precompile_kernels()))
"""


def test_a_process_finding_the_built_cache_compiles_nothing():
    """The first process fills the cache (`make setup` already did: then it too compiles nothing); a second
    process renders every warm-up case from the cache alone."""
    first = _python(PRECOMPILE)
    second = _python(PRECOMPILE)
    assert second["compiled"] == 0, second
    assert second["used"] == first["used"] > 0
    if first["compiled"] == 0:
        assert second["loaded"] == first["loaded"] > 0
    else:
        # A kernel the first process compiled also loaded the kernels it calls (numba types a call through the
        # callee's dispatcher, a cache hit of its own); a later process loads the compiled caller alone, so its
        # count is smaller. Processes after the first must agree exactly.
        assert _python(PRECOMPILE) == second


def test_loading_the_cached_kernels_ahead_leaves_nothing_for_the_first_render():
    """What the add-on does on a thread when it registers: every cached kernel loaded ahead, none compiled, so
    the first render loads none itself."""
    _python(PRECOMPILE)  # the cache is built (a no-op after `make setup`)
    result = _python("""
        import json
        from monte.core.precompile import kernel_cache_counts, load_cached_kernels
        from monte.core.builtin_scenes import builtin_scene
        from monte.core.render import render
        from monte.core.settings import RenderSettings
        preloaded = load_cached_kernels()
        before = kernel_cache_counts()
        render(builtin_scene("cornell", (16, 16)), RenderSettings(spp=2, threads=2))
        print("RESULT " + json.dumps({"preloaded": preloaded, "before": before, "after": kernel_cache_counts()}))
    """)
    assert result["preloaded"] == result["before"]["loaded"] > 0
    assert result["before"]["compiled"] == result["after"]["compiled"] == 0
    assert result["after"]["loaded"] == result["before"]["loaded"]  # the render found every kernel loaded


def test_numba_llvm_lock_events_are_dropped_and_kernels_still_compile_and_load():
    """jit_cache removes numba's per-LLVM-call event callbacks (a diagnostic timer only): none is left registered
    with llvmlite's lock, a new function still compiles and runs, and a cached kernel still loads."""
    code = """
        import json
        import numba
        from llvmlite.binding import ffi
        from monte.core import jit_cache, precompile
        import monte.core.render  # noqa: F401
        left = [cb[0].__module__ for cb in ffi.lib._lock._cblist]

        @numba.njit
        def twice(x):
            return 2 * x

        loaded = precompile.load_cached_kernels()
        d = twice
        value = twice(21)
        timers = d.get_metadata(d.signatures[0]).get("timers", {})
        print("RESULT " + json.dumps({"dropped": jit_cache.NUMBA_LLVM_LOCK_EVENTS_DROPPED, "left": left,
                                      "value": value, "loaded": loaded, "compiler_timer": "compiler_lock" in timers,
                                      "llvm_timer": "llvm_lock" in timers}))
    """
    result = _python(code)
    assert result["dropped"] is True and "numba.core.base" not in result["left"]
    assert result["value"] == 42 and result["loaded"] > 0
    assert result["compiler_timer"] is True and result["llvm_timer"] is False


_LOAD_AND_RENDER = """
    import hashlib, json, sys
    import numpy as np
    from numba.core import caching, codegen
    from numba.core.base import builtin_registry
    from numba.core.registry import cpu_target
    from monte.core import jit_cache, sampling
    from monte.core.precompile import kernel_cache_counts, load_cached_kernels
    from monte.core.builtin_scenes import builtin_scene
    from monte.core.render import render
    from monte.core.settings import RenderSettings
    ctx = cpu_target.target_context
    loaded = load_cached_kernels()
    result = render(builtin_scene("cornell", (16, 16)), RenderSettings(spp=2, threads=2, seed=3))
    image = np.concatenate([np.ravel(a).astype(np.float64) for a in (result.color, result.variance, result.albedo,
                                                                      result.normal) if a is not None])
    counts = kernel_cache_counts()
    registries_after_loading = builtin_registry in ctx._registries
    typed_list_imported = "numba.typed.listobject" in sys.modules
    arrayobj_imported = "numba.np.arrayobj" in sys.modules  # np.empty's helper's environment (in _sobol_fill)
    deferred = [(ref(), name) for ref, name in jit_cache._DEFERRED_ENVIRONMENTS]
    deferred_globals = sorted({len(env.globals) for env, _ in deferred if env is not None})
    mix = sampling._mix32
    mix_library = mix.overloads[mix.signatures[0]].library
    pending = sum(jit_cache._PENDING_BITCODE in d.overloads[s].library.__dict__
                  for d in [mix] + [v for v in vars(sampling).values() if hasattr(v, "overloads")]
                  for s in d.signatures)
    mix_pending = jit_cache._PENDING_BITCODE in mix_library.__dict__

    import numba

    @numba.njit
    def needs_the_registries(n):  # array creation, a reduction, np.random: implementations the refresh installs
        np.random.seed(n)
        return np.arange(n).sum() + int(np.random.random() >= 0.0)

    @numba.njit
    def calls_a_loaded_kernel(x):  # links the loaded library: its bitcode is parsed now
        return mix(x)

    value = needs_the_registries(10)
    mixed = int(calls_a_loaded_kernel(np.uint32(12345))), int(mix(np.uint32(12345)))
    print("RESULT " + json.dumps({
        "applied": jit_cache.NUMBA_CACHE_LOADS_WITHOUT_REFRESH, "parse_later": jit_cache.NUMBA_CACHE_LOADS_PARSE_LATER,
        "patched": bool(getattr(caching.Cache.load_overload, "_monte_without_refresh", False)),
        "loaded": loaded, "counts": counts, "image": hashlib.sha256(image.tobytes()).hexdigest(),
        "registries_after_loading": registries_after_loading, "typed_list_imported": typed_list_imported,
        "pending": pending, "mix_pending": mix_pending, "arrayobj_imported": arrayobj_imported,
        "environments": jit_cache.NUMBA_ENVIRONMENTS_WITHOUT_IMPORT, "deferred_globals": deferred_globals,
        "deferred_modules": sorted({name for _, name in deferred}),
        "completed": all(set(vars(sys.modules[name])) <= set(env.globals) and env.globals["__name__"] == name
                         for env, name in deferred if env is not None),
        "left": len(jit_cache._DEFERRED_ENVIRONMENTS),
        "mix_parsed_after": jit_cache._PENDING_BITCODE not in mix_library.__dict__
                            and mix_library._shared_module is not None,
        "registries_after_compiling": builtin_registry in ctx._registries, "value": int(value), "mixed": mixed}))
"""


def test_cached_kernels_load_without_registries_or_bitcode_and_render_the_same_image():
    """jit_cache loads Monte's cached kernels without numba's registry refresh (its first one: ~0.08 s of CPU of
    every render process) and leaves each library's bitcode unparsed until something links it (~60 % of a
    load). In a fresh process the kernels load and render with no registry installed, nothing compiled and the
    bitcode pending, and the image is bit for bit the one numba's own loading gives (MONTE_PLAIN_NUMBA_LOADS=1).
    A function compiled afterwards (array creation, np.random: implementations the registries hold) still
    compiles and runs, and one calling a loaded kernel links it (its bitcode parsed then) and computes the same.
    Fails too when the patches stop applying (a numba version or method they were not read for): then re-read
    numba's Cache.load_overload and CPUCodeLibrary._unserialize before widening the checks."""
    ours = _python(_LOAD_AND_RENDER)
    numbas = _python(_LOAD_AND_RENDER, MONTE_PLAIN_NUMBA_LOADS="1")
    assert ours["applied"] is True and ours["patched"] is True and ours["parse_later"] is True, ours
    assert numbas["applied"] is False and numbas["parse_later"] is False
    assert ours["loaded"] > 0 and ours["counts"]["compiled"] == 0 and numbas["counts"]["compiled"] == 0
    assert ours["registries_after_loading"] is False and ours["typed_list_imported"] is False
    assert numbas["registries_after_loading"] is True
    assert ours["pending"] > 0 and ours["mix_pending"] is True and numbas["pending"] == 0
    assert ours["image"] == numbas["image"]
    # numba's own modules named by the kernels' environments are not imported by a load (numba.np.arrayobj:
    # 0.02-0.06 s); the environments get the modules' globals when numba installs its registries.
    assert ours["environments"] is True and numbas["environments"] is False
    assert ours["arrayobj_imported"] is False and numbas["arrayobj_imported"] is True
    assert "numba.np.arrayobj" in ours["deferred_modules"] and ours["deferred_globals"] == [1]
    assert ours["completed"] is True and ours["left"] == 0 and numbas["deferred_modules"] == []
    assert ours["registries_after_compiling"] is True and ours["value"] == 46 == numbas["value"]
    assert ours["mix_parsed_after"] is True and ours["mixed"][0] == ours["mixed"][1] == numbas["mixed"][0]


def test_other_packages_cached_functions_keep_numbas_refresh():
    """The loader without the refresh applies to Monte's kernels only (cached by the per-import-name locator):
    another package's cached function, or a context other than numba's CPU one, goes through numba's method,
    which refreshes the context first."""
    from types import SimpleNamespace
    from contextlib import nullcontext

    from numba.core import caching
    from numba.core.registry import cpu_target

    assert jit_cache.NUMBA_CACHE_LOADS_WITHOUT_REFRESH is True

    class Context:
        refreshed = 0

        def refresh(self):
            Context.refreshed += 1

    def cache(locator):
        return SimpleNamespace(_impl=SimpleNamespace(locator=locator), _load_overload=lambda sig, ctx: ("loaded", ctx),
                               _guard_against_spurious_io_errors=nullcontext)

    load = caching.Cache.load_overload
    other = cache(SimpleNamespace())  # another package's locator
    context = Context()
    assert load(other, "sig", context) == ("loaded", context) and Context.refreshed == 1
    ours = cache(jit_cache._PerImportNameLocator.__new__(jit_cache._PerImportNameLocator))
    assert load(ours, "sig", context) == ("loaded", context)  # not numba's CPU context: numba's way
    assert Context.refreshed == 2
    refreshes = []
    ctx = cpu_target.target_context
    original_refresh = ctx.refresh
    ctx.refresh = lambda: refreshes.append(1)
    try:
        assert load(ours, "sig", ctx) == ("loaded", ctx)  # Monte's kernel on the CPU context: no refresh
        assert refreshes == []
        load(other, "sig", ctx)
        assert refreshes == [1]
    finally:
        del ctx.refresh
        assert ctx.refresh == original_refresh


def test_the_kernel_modules_digest_is_taken_once_per_module_import():
    """numba stamps each kernel as it is defined; the kernel modules' digest (17 files' stats) is taken once per
    import of a kernel module, not once per kernel (~340), and every kernel's stamp is still its own file's
    contents and the digest of all kernel modules. A stamp made outside an import checks the files again."""
    result = _python("""
        import json
        from monte.core import jit_cache
        calls = []
        original = jit_cache.sources_digest
        jit_cache.sources_digest = lambda *a, **k: calls.append(1) or original(*a, **k)
        import monte.core.render, monte.core.shading.evaluator  # noqa: E401,F401
        from monte.core import precompile
        during_import = len(calls)
        stamps = [d._cache._cache_file._source_stamp for d in precompile._dispatchers()]
        files = [d.py_func.__code__.co_filename for d in precompile._dispatchers()]
        locator = jit_cache._PerImportNameLocator.from_function(precompile._dispatchers()[0].py_func, files[0])
        before = len(calls)
        locator.get_source_stamp()
        print("RESULT " + json.dumps({
            "during_import": during_import, "before": before, "after": len(calls), "kernels": len(stamps),
            "right": sum(s == ["sha256", jit_cache.file_digest(f), original()] or
                         s == ("sha256", jit_cache.file_digest(f), original()) for s, f in zip(stamps, files))}))
    """)
    assert result["kernels"] > 200 and result["right"] == result["kernels"]
    assert 0 < result["during_import"] <= len(jit_cache.KERNEL_MODULES)
    assert result["after"] == result["before"] + 1


def test_a_symbol_of_an_unparsed_library_is_still_found():
    """numba's engine answers "is this symbol defined" for every loaded library: a name that only a library
    whose bitcode is still pending defines is found (the pending libraries are parsed before a "no")."""
    result = _python("""
        import json
        import llvmlite.binding as ll
        from monte.core import jit_cache, precompile, sampling
        precompile.load_cached_kernels()
        d = sampling._mix32
        library = d.overloads[d.signatures[0]].library
        engine = library._codegen._engine
        pending = jit_cache._PENDING_BITCODE in library.__dict__
        module = ll.parse_bitcode(library.__dict__[jit_cache._PENDING_BITCODE])
        names = [f.name for f in module.functions if not f.is_declaration and f.name.startswith("_ZN")]
        known_before = [n in engine._defined_symbols for n in names]
        found = [engine.is_symbol_defined(n) for n in names]
        print("RESULT " + json.dumps({"pending": pending, "names": len(names), "known_before": known_before,
                                      "found": found, "parsed": jit_cache._PENDING_BITCODE not in library.__dict__,
                                      "missing": engine.is_symbol_defined("no_such_symbol_in_any_library")}))
    """)
    assert result["pending"] is True and result["names"] > 0
    assert not all(result["known_before"])
    assert all(result["found"]) and result["parsed"] is True and result["missing"] is False


_NRT_MODULE = """
    import hashlib, json, os, sys
    import numpy as np
    from numba.core.registry import cpu_target
    from numba.core.runtime import nrtdynmod, rtsys
    from monte.core import jit_cache
    ctx = cpu_target.target_context
    path = os.path.join(jit_cache.cache_dir(), f"{jit_cache.NRT_CACHE_PREFIX}{jit_cache._nrt_cache_key(ctx)}.bin")
    if sys.argv[-1] == "corrupt":
        with open(path, "wb") as fh:
            fh.write(b"not a cached module")
    built = []
    create = nrtdynmod.create_nrt_module
    nrtdynmod.create_nrt_module = lambda c: built.append(1) or create(c)
    from monte.core.builtin_scenes import builtin_scene
    from monte.core.precompile import load_cached_kernels
    from monte.core.render import render
    from monte.core.settings import RenderSettings
    load_cached_kernels()
    result = render(builtin_scene("cornell", (16, 16)), RenderSettings(spp=2, threads=2, seed=3))
    import numba

    @numba.njit
    def allocates(n):  # NRT: allocation, incref/decref of the arrays
        a = np.arange(n)
        b = a[::2].copy()
        return (a.sum(), b.sum(), b)

    total, half, kept = allocates(10)
    abort = rtsys.library.get_pointer_to_function("nrt_unresolved_abort")
    with open(path, "rb") as fh:
        valid = fh.read(2) == b"\\x80\\x05"  # a pickle (what the cache writes), not the stand-in
    print("RESULT " + json.dumps({"cached": jit_cache.NUMBA_NRT_MODULE_CACHED, "built": len(built),
                                  "image": hashlib.sha256(np.ascontiguousarray(result.color).tobytes()).hexdigest(),
                                  "values": [int(total), int(half), kept.tolist()], "abort": abort != 0,
                                  "valid": valid}))
"""


def test_nrt_module_is_cached_and_a_bad_file_is_compiled_again():
    """NRT's module (numba's runtime, compiled with LLVM in every process: 0.01-0.02 s) is kept in the kernel
    cache: a process with the file builds nothing; one whose file is unreadable compiles it numba's way and
    writes it again; numba's own loading (MONTE_PLAIN_NUMBA_LOADS=1) always builds it. The image, a function
    compiled afterwards that allocates and refcounts arrays, and the runtime's abort symbol are the same."""
    def run(*args, **env):
        code = textwrap.dedent(_NRT_MODULE)
        clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != jit_cache.KERNEL_CPU_ENV}
        proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=900,
                              env={**clean, **env})
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        return json.loads(lines[-1][len("RESULT "):])

    rebuilt = run("corrupt")
    cached = run()
    numbas = run(MONTE_PLAIN_NUMBA_LOADS="1")
    assert rebuilt["cached"] is True and rebuilt["built"] == 1 and rebuilt["valid"] is True
    assert cached["cached"] is True and cached["built"] == 0
    assert numbas["cached"] is False and numbas["built"] == 1
    for result in (rebuilt, cached):
        assert result["image"] == numbas["image"] and result["values"] == numbas["values"] == [45, 20, [0, 2, 4, 6, 8]]
        assert result["abort"] is True


def test_numba_extensions_initialize_at_the_first_compile_not_at_a_cached_kernels_call(tmp_path):
    """numba runs the installed `numba_extensions` entry points before a dispatcher's first compile-or-load;
    Monte's cached kernels load and render without that scan, and an extension is still initialized before
    the first compile (here a cfunc, which no dispatcher hook covers: the registries' refresh runs it) or the
    first call of another package's function, once."""
    dist = tmp_path / "monte_fake_numba_ext-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: monte-fake-numba-ext\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[numba_extensions]\ninit = monte_fake_numba_ext:init\n")
    (tmp_path / "monte_fake_numba_ext.py").write_text("CALLS = []\n\ndef init():\n    CALLS.append(1)\n")
    code = """
        import json, sys
        import numba
        from monte.core import jit_cache
        from monte.core.builtin_scenes import builtin_scene
        from monte.core.precompile import load_cached_kernels
        from monte.core.render import render
        from monte.core.settings import RenderSettings
        load_cached_kernels()
        render(builtin_scene("cornell", (16, 16)), RenderSettings(spp=1, threads=2, seed=3))
        after_render = len(sys.modules["monte_fake_numba_ext"].CALLS) if "monte_fake_numba_ext" in sys.modules else 0
        if sys.argv[-1] == "cfunc":
            value = numba.cfunc("int64(int64)")(lambda x: x + 1).ctypes(41)
        else:
            value = numba.njit(lambda x: x + 1)(41)
        numba.njit(lambda x: x + 2)(40)
        print("RESULT " + json.dumps({"deferred": jit_cache.NUMBA_EXTENSIONS_DEFERRED, "after_render": after_render,
                                      "after": len(sys.modules["monte_fake_numba_ext"].CALLS), "value": value}))
    """
    path = os.pathsep.join([str(tmp_path)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
    for how in ("cfunc", "njit"):
        clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != jit_cache.KERNEL_CPU_ENV}
        proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code), how], capture_output=True, text=True,
                              timeout=900, env={**clean, "PYTHONPATH": path})
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        assert proc.returncode == 0 and lines, f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        result = json.loads(lines[-1][len("RESULT "):])
        assert result == {"deferred": True, "after_render": 0, "after": 1, "value": 42}, (how, result)


def test_the_nrt_module_key_follows_what_its_code_depends_on(monkeypatch):
    """The cached NRT module's key changes with the numba settings its IR or optimization reads (NRT debugging,
    the optimization level) and with the CPU numba compiles for."""
    from numba.core import config
    from numba.core.registry import cpu_target

    ctx = cpu_target.target_context
    key = jit_cache._nrt_cache_key(ctx)
    assert jit_cache._nrt_cache_key(ctx) == key
    monkeypatch.setattr(config, "DEBUG_NRT", not config.DEBUG_NRT)
    debug = jit_cache._nrt_cache_key(ctx)
    monkeypatch.undo()
    monkeypatch.setattr(config, "OPT", 0)
    opt = jit_cache._nrt_cache_key(ctx)
    monkeypatch.undo()
    codegen = ctx.codegen()
    monkeypatch.setattr(type(codegen), "magic_tuple", lambda self: ("x86_64-unknown-linux-gnu", "znver4", "+avx512f"))
    cpu = jit_cache._nrt_cache_key(ctx)
    assert len({key, debug, opt, cpu}) == 4


def test_a_function_compiled_with_the_patches_in_place_saves_its_cache_and_reloads(tmp_path):
    """Every compile that saves a kernel pickles its Environment, which names numba's `_rebuild_env`: with
    Monte's version of it installed (environments rebuilt without importing numba's modules) the pickle must
    still name a function by reference, not a closure by value (its thread-local state cannot be pickled: a cold
    `precompile` failed on its first saved kernel). A cached function compiled and saved in one process loads
    in the next and gives the same value."""
    (tmp_path / "cached_mod.py").write_text(textwrap.dedent("""
        import numba
        import numpy as np

        @numba.njit(cache=True)
        def summed(n):
            return np.arange(n).sum() * 2
    """))
    code = f"""
        import json, sys
        sys.path.insert(0, {str(tmp_path)!r})
        from monte.core import jit_cache
        import cached_mod
        value = int(cached_mod.summed(10))
        hits = cached_mod.summed.stats.cache_hits
        print("RESULT " + json.dumps({{"installed": jit_cache.NUMBA_ENVIRONMENTS_WITHOUT_IMPORT, "value": value,
                                       "hits": sum(hits.values())}}))
    """
    first = _python(code)
    assert first["installed"] is True and first["value"] == 90 and first["hits"] == 0
    assert any(p.suffix == ".nbc" for p in (tmp_path / "__pycache__").iterdir())
    second = _python(code)
    assert second["value"] == 90 and second["hits"] == 1


def _numbas_live_map():
    from numba.core import analysis

    live_map = analysis.compute_live_map
    return getattr(live_map, "_numba_original", live_map)


def _loops_and_branches(a, n):
    total = 0.0
    i = 0
    while i < n:
        if a[i] > 0:
            for j in range(i):
                if j == 3:
                    continue
                total += a[j]
                if total > 100:
                    break
        else:
            k = i
            while k > 0:
                k -= 2
            total -= k
        i += 1
    x = total if n else -1.0
    return x


def _straight_line(a):
    b = a + 1
    c = b * 2
    return c - a


def _self_loop(n):
    while n > 0:
        n -= 1
    return n


@pytest.mark.parametrize("func", [_loops_and_branches, _straight_line, _self_loop])
def test_the_live_map_as_bits_is_numbas(func):
    """The live map numba's post-processor computes after every IR-changing pass, from bit masks
    (jit_cache._live_map_as_bits), is numba's own set for set on every block, for IR with loops, nested loops,
    break, continue, a self-loop and straight-line code."""
    from numba.core import analysis
    from numba.core.compiler import run_frontend

    func_ir = run_frontend(func)
    cfg = analysis.compute_cfg_from_blocks(func_ir.blocks)
    usedefs = analysis.compute_use_defs(func_ir.blocks)
    expected = _numbas_live_map()(cfg, func_ir.blocks, usedefs.usemap, usedefs.defmap)
    got = jit_cache._live_map_as_bits(cfg, func_ir.blocks, usedefs.usemap, usedefs.defmap)
    assert got == expected
    assert len(expected) == 1 if func is _straight_line else any(expected.values())  # loops carry live variables


_INLINED_KERNELS = """
    import numba
    import numpy as np

    @numba.njit(inline="always")
    def _weight(a, i, scale):
        w = 0.0
        for k in range(i):
            if a[k] > scale:
                w += a[k] * scale
            else:
                w -= 1.0
        return w

    @numba.njit(inline="always")
    def _pair(a, i):
        return _weight(a, i, 0.5) + _weight(a, i + 1, 0.25)

    @numba.njit
    def kernel(a, out):
        for i in range(a.shape[0] - 1):
            out[i] = _pair(a, i) if a[i] > 0 else _weight(a, i, 2.0)
        return out.sum()
"""


def test_the_compile_patches_install_on_the_first_compile_and_change_no_code(tmp_path):
    """numba's inlining of inline="always" device functions without the two deep copies of each fresh callee IR,
    its live map from bit masks and its SSA reconstruction rewriting only the blocks that name the variable
    (jit_cache._inline_fresh_callees_without_copies) are installed by the first compile of a process and not
    before; a kernel with nested inlined device functions, loops, branches and variables defined more than once
    compiles to the same LLVM IR, and gives the same value, with them and without them."""
    (tmp_path / "inlined_mod.py").write_text(textwrap.dedent(_INLINED_KERNELS))
    code = f"""
        import hashlib, json, sys
        sys.path.insert(0, {str(tmp_path)!r})
        from monte.core import jit_cache
        before = "numba.core.inline_closurecall" in sys.modules and bool(jit_cache._inline_patch_state)
        if sys.argv[1] == "off":
            jit_cache._inline_patch_state.append(False)
        import numpy as np
        import inlined_mod
        a = np.linspace(-1.0, 3.0, 40)
        value = float(inlined_mod.kernel(a, np.zeros(40)))
        from numba.core import analysis, inline_closurecall, ssa
        (cres,) = inlined_mod.kernel.overloads.values()
        print("RESULT " + json.dumps({{
            "before": before, "state": jit_cache._inline_patch_state, "value": value,
            "llvm": hashlib.sha256(cres.library.get_llvm_str().encode()).hexdigest(),
            "bits": analysis.compute_live_map is jit_cache._live_map_as_bits,
            "bits_doc": (jit_cache._live_map_as_bits.__doc__ or "").split(" (")[0],
            "fresh": bool(getattr(inline_closurecall.InlineWorker.inline_function, "_monte_fresh_callee", False)),
            "ssa": bool(getattr(ssa._run_ssa, "_monte_named_blocks", False))}}))
    """
    on = _python(code.replace("sys.argv[1]", "'on'"))
    off = _python(code.replace("sys.argv[1]", "'off'"))
    assert on["before"] is False and on["state"] == [True] and on["bits"] and on["fresh"] and on["ssa"]
    assert on["bits_doc"] == "numba.core.analysis.compute_live_map"  # its own docstring, not numba's, once installed
    assert off["state"] == [False] and not off["bits"] and not off["fresh"] and not off["ssa"]
    assert on["llvm"] == off["llvm"] and on["value"] == off["value"]


def test_a_copy_outside_a_fresh_inline_is_still_deep():
    """inline_ir called directly (numba's typed inlining of overloads, whose IR is cached and reused) keeps its
    deep copies: the stand-in copies unless inline_function marked the callee fresh."""
    from numba.core import ir

    jit_cache._inline_fresh_callees_without_copies()
    from numba.core import inline_closurecall

    block = ir.Block(ir.Scope(None, ir.Loc("f", 1)), ir.Loc("f", 1))
    copied = inline_closurecall.copy.deepcopy(block)
    assert copied is not block and isinstance(copied, ir.Block)
    jit_cache._FRESH_CALLEE.active = True
    try:
        assert inline_closurecall.copy.deepcopy(block) is block
    finally:
        jit_cache._FRESH_CALLEE.active = False
