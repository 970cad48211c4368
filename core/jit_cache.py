"""Where the compiled (numba) kernels are cached on disk: in core/__pycache__/numba-<import name>/, one folder
per name the package is imported under.

numba's cache files record the import name of each kernel's module (to rebuild the function's environment
when the cache is loaded). With numba's default, one folder next to the sources, a cache written while the
package was imported as `monte.core` (the CLI, pytest) and read when it is imported under another name
(Blender imports an extension as `bl_ext.<repository>.monte`; a checkout linked into Blender's extensions
folder is both) fails with ModuleNotFoundError instead of compiling. One folder per name keeps them apart.

Every kernel module imports this module before it defines its kernels (numba picks a function's cache folder
when the function is decorated). Only functions defined in this folder are affected; other numba users in
the process (other Blender add-ons) keep numba's own choice.
"""

from __future__ import annotations

import os

from numba.core import caching

_CORE_DIR = os.path.dirname(os.path.abspath(__file__))
PACKAGE = __name__.rpartition(".")[0] or "core"  # "monte.core", "bl_ext.user_default.monte.core", ...


def cache_dir() -> str:
    """The folder this import of the package caches its kernels in."""
    return os.path.join(_CORE_DIR, "__pycache__", f"numba-{PACKAGE}")


# numba >= 0.59 names it InTreeCacheLocator; earlier versions _InTreeCacheLocator.
_InTree = getattr(caching, "InTreeCacheLocator", None) or getattr(caching, "_InTreeCacheLocator", None)
_CacheImpl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)

if _InTree is not None and _CacheImpl is not None:

    class _PerImportNameLocator(_InTree):
        """numba's in-tree locator, moved into this import name's folder, for functions defined here only.
        (A folder that cannot be written falls through to numba's next locator, as with the in-tree one.)"""

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            self._cache_path = cache_dir()

        @classmethod
        def from_function(cls, py_func, py_file):
            if os.path.dirname(os.path.abspath(py_file)) != _CORE_DIR:
                return None
            return super().from_function(py_func, py_file)

    _classes = _CacheImpl._locator_classes
    # After NUMBA_CACHE_DIR's locator (the user's explicit choice wins), before the in-tree one.
    _classes.insert(1 if _classes and _classes[0].__name__.endswith("UserProvidedCacheLocator") else 0,
                    _PerImportNameLocator)
