"""The kernels' disk cache: keyed by the sources' contents, so a cache built once (`make setup`, the extension
zip) stays valid when checking out or unzipping rewrites the file times, and any edit of any kernel module
invalidates every kernel (kernels call and inline functions of other modules: core.warps, core.geometry_kernels;
numba alone checks only the file a function is defined in). Kernels are compiled for a generic CPU, so a cache
built on one machine applies on another; a process that finds a built cache compiles nothing."""

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


def test_kernels_are_compiled_for_a_generic_cpu():
    result = _python("""
        import json
        from monte.core import jit_cache, warps
        from numba.core.registry import cpu_target
        print("RESULT " + json.dumps({"cpu": jit_cache.KERNEL_CPU,
                                      "magic": list(cpu_target.target_context.codegen().magic_tuple())}))
    """)
    assert result["cpu"] == "generic"
    assert result["magic"][1:] == ["generic", ""]  # the CPU name and features numba keys the cache by


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
    from numba.core import caching
    from numba.core.base import builtin_registry
    from numba.core.registry import cpu_target
    from monte.core import jit_cache
    from monte.core.precompile import kernel_cache_counts, load_cached_kernels
    from monte.core.builtin_scenes import builtin_scene
    from monte.core.render import render
    from monte.core.settings import RenderSettings
    ctx = cpu_target.target_context
    if REFRESH_FIRST:
        ctx.refresh()  # numba's own first cached load did this
    loaded = load_cached_kernels()
    result = render(builtin_scene("cornell", (16, 16)), RenderSettings(spp=2, threads=2, seed=3))
    image = np.concatenate([np.ravel(a).astype(np.float64) for a in (result.color, result.variance, result.albedo, result.normal) if a is not None])
    counts = kernel_cache_counts()
    registries_after_loading = builtin_registry in ctx._registries
    typed_list_imported = "numba.typed.listobject" in sys.modules

    import numba

    @numba.njit
    def needs_the_registries(n):  # array creation, a reduction, np.random: implementations the refresh installs
        np.random.seed(n)
        return np.arange(n).sum() + int(np.random.random() >= 0.0)

    value = needs_the_registries(10)
    print("RESULT " + json.dumps({
        "applied": jit_cache.NUMBA_CACHE_LOADS_WITHOUT_REFRESH,
        "patched": bool(getattr(caching.Cache.load_overload, "_monte_without_refresh", False)),
        "loaded": loaded, "counts": counts, "image": hashlib.sha256(image.tobytes()).hexdigest(),
        "registries_after_loading": registries_after_loading, "typed_list_imported": typed_list_imported,
        "registries_after_compiling": builtin_registry in ctx._registries, "value": int(value)}))
"""


def test_cached_kernels_load_without_numba_registries_and_render_the_same_image():
    """jit_cache loads Monte's cached kernels without numba's registry refresh (its first one: ~0.08 s of CPU of
    every render process): in a fresh process the kernels load and render with no registry installed and nothing
    compiled, the image is bit for bit the one rendered with the registries installed first (numba's way), and a
    function compiled afterwards (array creation, np.random: implementations the registries hold) still compiles
    and runs, the compile installing the registries itself. Fails too when the patch stops applying (a numba
    version or method it was not read for): then re-read numba's Cache.load_overload before widening the check."""
    ours = _python(_LOAD_AND_RENDER.replace("REFRESH_FIRST", "False"))
    numbas = _python(_LOAD_AND_RENDER.replace("REFRESH_FIRST", "True"))
    assert ours["applied"] is True and ours["patched"] is True, ours
    assert ours["loaded"] > 0 and ours["counts"]["compiled"] == 0 and numbas["counts"]["compiled"] == 0
    assert ours["registries_after_loading"] is False and ours["typed_list_imported"] is False
    assert numbas["registries_after_loading"] is True
    assert ours["image"] == numbas["image"]
    assert ours["registries_after_compiling"] is True and ours["value"] == 46 == numbas["value"]


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
