"""core/jit_cache.py's kernel decorators leave numba's per-kernel cache object to the kernel's first use and take
each kernel's signature once (round eleven of docs/performance.md, "Cold start and fixed cost"): a kernel a
render never calls costs no cache object, a called one still loads from the disk cache (or compiles and saves
once), under the stamp its sources had when it was defined, and numba's own decorator is used where the
deferral does not apply."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from monte.core import jit_cache

sys.path.insert(0, str(Path(__file__).resolve().parent))
from throwaway_kernels import child_result, python_child, throwaway_kernel_module  # noqa: E402

MODULE = "_test_deferred_kernel_cache"  # a throwaway kernel module in core/ (Monte's locator caches only there)

KERNELS = """
import numpy as np

from .jit_cache import jit, jit_no_nrt


@jit
def scaled(n, factor=2.0):
    return np.arange(n).sum() * factor


@jit_no_nrt
def never_called(a, b):
    return a + b
"""


def _python(code: str, **env) -> dict:
    return child_result(python_child(code, **env))


@pytest.fixture
def kernel_module():
    with throwaway_kernel_module(MODULE, KERNELS) as path:
        yield path


CALL = f"""
    import json, os, sys
    from numba.core.caching import FunctionCache
    import monte.core.render  # noqa: F401 - the renderer's ~350 kernels, none called
    from monte.core import jit_cache, precompile
    from monte.core import {MODULE} as mod
    ours = [d for d in precompile._dispatchers()]
    made_at_import = sum(type(d.__dict__.get("_cache")) is FunctionCache for d in ours)
    deferred = [type(d.__dict__.get("_cache")).__name__ for d in (mod.scaled, mod.never_called)]
    if os.environ.get("EDIT_BEFORE_CALL"):  # the module's file changes after its import, before the first call
        with open(mod.__file__, "a") as fh:
            fh.write("# edited\\n")
    value = float(mod.scaled(10))
    print("RESULT " + json.dumps({{
        "installed": jit_cache.KERNEL_CACHES_DEFERRED, "made_at_import": made_at_import, "kernels": len(ours),
        "deferred": deferred, "value": value,
        "hits": sum(mod.scaled.stats.cache_hits.values()), "misses": sum(mod.scaled.stats.cache_misses.values()),
        "scaled_after": type(mod.scaled.__dict__["_cache"]).__name__,
        "never_called_after": type(mod.never_called.__dict__["_cache"]).__name__,
        "made_after": sum(type(d.__dict__.get("_cache")) is FunctionCache for d in ours),
    }}))
"""


def test_a_deferred_kernel_compiles_saves_and_loads_from_its_cache(kernel_module):
    """A cold compile with the deferral in place saves the kernel (its cache object made on the call: the
    compile's pickle names nothing of the deferral), the next process loads it from the disk without compiling
    and computes the same, and numba's own decorator (MONTE_PLAIN_NUMBA_LOADS=1) finds the same entry: the
    stamp and index are numba's. The ~350 kernels of the renderer get no cache object at import (the first
    kernel of a process does: it finds the cache folder writable) and none when another kernel is called."""
    cold = _python(CALL)
    assert cold["installed"] is True and cold["value"] == 90.0
    assert cold["misses"] == 1 and cold["hits"] == 0  # compiled here ...
    assert any(p.suffix == ".nbc" for p in Path(jit_cache.cache_dir()).glob(f"{MODULE}.scaled-*"))  # ... saved
    assert cold["deferred"] == ["_CacheOnUse", "_CacheOnUse"]
    assert cold["scaled_after"] == "FunctionCache" and cold["never_called_after"] == "_CacheOnUse"
    assert cold["kernels"] > 300 and cold["made_at_import"] == 1 and cold["made_after"] == 1

    warm = _python(CALL)
    assert warm["value"] == 90.0 and warm["hits"] == 1 and warm["misses"] == 0

    plain = _python(CALL, MONTE_PLAIN_NUMBA_LOADS="1")
    assert plain["installed"] is False and plain["deferred"] == ["FunctionCache", "FunctionCache"]
    assert plain["made_at_import"] == plain["kernels"]
    assert plain["value"] == 90.0 and plain["hits"] == 1 and plain["misses"] == 0


def test_the_stamp_is_the_sources_at_definition_not_at_the_first_call(kernel_module):
    """numba stamps a kernel with its sources as they were when it was defined (the code it compiles); the
    deferred cache keeps that stamp: a module edited after its import and before the kernel's first call loads
    the entry compiled from the imported code instead of filing that code under the edited file's stamp."""
    assert _python(CALL)["value"] == 90.0  # compiled and saved for the module as written
    edited = _python(CALL, EDIT_BEFORE_CALL="1")
    assert edited["deferred"][0] == "_CacheOnUse" and edited["hits"] == 1 and edited["misses"] == 0
    # and the next process, importing the edited file, does not take the old entry for it
    again = _python(CALL)
    assert again["value"] == 90.0 and again["misses"] == 1 and again["hits"] == 0


def test_numbas_own_decorator_where_the_deferral_does_not_apply(tmp_path):
    """With numba's cache folder chosen by the user (NUMBA_CACHE_DIR: numba's locator, not Monte's) every kernel
    gets numba's cache object when it is defined, as numba's decorator makes it."""
    result = _python("""
        import json
        from numba.core.caching import FunctionCache
        import monte.core.render  # noqa: F401
        from monte.core import precompile
        kinds = sorted({type(d.__dict__.get("_cache")).__name__ for d in precompile._dispatchers()})
        print("RESULT " + json.dumps({"kinds": kinds}))
    """, NUMBA_CACHE_DIR=str(tmp_path))
    assert result["kinds"] == ["FunctionCache"]


def test_every_kernels_signature_is_inspects():
    """The signature kept for each kernel (built from its code object, once) is the one inspect.signature
    computes: names, kinds, defaults and annotations; numba's dispatcher and compiler hold that one."""
    import inspect

    import monte.core.render  # noqa: F401
    from monte.core import precompile

    dispatchers = precompile._dispatchers()
    assert len(dispatchers) > 300
    # (the process's first kernel is numba's own: it finds the cache folder writable)
    assert sum("__signature__" not in d.py_func.__dict__ for d in dispatchers) <= 1
    for d in dispatchers:
        kept = d.py_func.__dict__.get("__signature__")
        if kept is None:
            continue
        del d.py_func.__signature__
        try:
            assert inspect.signature(d.py_func) == kept, d
        finally:
            d.py_func.__signature__ = kept
        assert d._compiler.pysig is kept


def test_the_fast_signature_falls_back_for_other_shapes():
    """Keyword-only, positional-only, *args and **kwargs parameters take inspect's own way, with the same
    result."""
    import inspect

    def f(a, /, b, *args, c=3, **kw):
        return a

    def g(a, b=1.5, *, c):
        return a

    def h(x: int, y: "float" = 2.0) -> float:
        return x

    for func in (f, g, h):
        assert jit_cache._signature(func) == inspect.signature(func)
