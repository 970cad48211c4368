"""A kernel's disk cache is invalidated when any kernel module changes, not only its own file: kernels call (and
inline) functions of other modules (core.warps, core.geometry_kernels), and numba alone checks only the file a
function is defined in, so an edit of a warp would leave the light kernels running the old one."""

from __future__ import annotations

import os
import re

import pytest

from monte.core import jit_cache, light_kernels, warps


def _stamp(dispatcher):
    py_func = dispatcher.py_func
    locator = jit_cache._PerImportNameLocator.from_function(py_func, py_func.__code__.co_filename)
    assert locator is not None, "core's kernels are cached by the per-import-name locator"
    return locator.get_source_stamp()


def test_editing_a_callee_module_invalidates_the_caller():
    before = _stamp(light_kernels.sample_batch)
    path = warps.__file__
    st = os.stat(path)
    try:
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
        assert _stamp(light_kernels.sample_batch) != before
    finally:
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert _stamp(light_kernels.sample_batch) == before  # restored: the cache is valid again


@pytest.mark.parametrize("name", jit_cache.KERNEL_MODULES)
def test_every_kernel_module_is_there(name):
    # a module missing from the list would not invalidate its callers; a stale name would stamp nothing
    assert os.path.isfile(os.path.join(os.path.dirname(jit_cache.__file__), f"{name}.py"))


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
