"""How the renderer's kernels are compiled (the numba options, `jit`, `jit_no_nrt`, `jit_inline`) and where they
are cached on disk: in core/__pycache__/numba-<import name>/, one folder per name the package is imported under.

Options shared by every kernel: cached on disk, the GIL released (render worker threads run kernels in
parallel), NumPy's error model (a division by zero gives inf/nan like NumPy, no exception check per division),
no bounds checks, and no fast-math (images are bit-identical for a seed, whatever the thread count).
`jit_no_nrt` drops NRT reference counting: unpacking tuples of arrays and passing arrays to device functions
otherwise costs atomic incref/decref calls per path (measured 2-4x slower in the BSDF and light kernels); such
kernels must never allocate (callers pass scratch buffers). `jit_inline` also inlines a device function into its
callers (numba IR inlining), for device functions that take arrays; scalar-only helpers are left to LLVM, which
keeps the first compile short.

numba's cache files record the import name of each kernel's module (to rebuild the function's environment
when the cache is loaded). With numba's default, one folder next to the sources, a cache written while the
package was imported as `monte.core` (the CLI, pytest) and read when it is imported under another name
(Blender imports an extension as `bl_ext.<repository>.monte`; a checkout linked into Blender's extensions
folder is both) fails with ModuleNotFoundError instead of compiling. One folder per name keeps them apart.

Kernel modules take their decorators from here, so the locator below is installed before any kernel is defined
(numba picks a function's cache folder when the function is decorated). Only functions defined in this folder are
affected; other numba users in the process (other Blender add-ons) keep numba's own choice.
"""

from __future__ import annotations

import glob
import os

import numba
from numba.core import caching

_CORE_DIR = os.path.dirname(os.path.abspath(__file__))
PACKAGE = __name__.rpartition(".")[0] or "core"  # "monte.core", "bl_ext.user_default.monte.core", ...


def _file_stamp(path: str) -> tuple[float, int]:
    try:
        st = os.stat(path)
    except OSError:
        return 0.0, 0
    return st.st_mtime, st.st_size


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

        def get_source_stamp(self):
            """The function's own file and every kernel module: numba checks only the file a function is defined
            in, but kernels call (and inline) functions of other kernel modules (core.warps from the light and
            BSDF kernels, core.geometry_kernels from core.path_kernels), whose edits must recompile them too."""
            own = super().get_source_stamp()
            return own, tuple(_file_stamp(os.path.join(_CORE_DIR, f"{name}.py")) for name in KERNEL_MODULES)

        @classmethod
        def from_function(cls, py_func, py_file):
            folder = os.path.dirname(os.path.abspath(py_file))
            if folder != _CORE_DIR and os.path.dirname(folder) != _CORE_DIR:  # core/ and its packages (shading/)
                return None
            return super().from_function(py_func, py_file)

    _classes = _CacheImpl._locator_classes
    # After NUMBA_CACHE_DIR's locator (the user's explicit choice wins), before the in-tree one.
    _classes.insert(1 if _classes and _classes[0].__name__.endswith("UserProvidedCacheLocator") else 0,
                    _PerImportNameLocator)


_OPTIONS = dict(cache=True, nogil=True, error_model="numpy", boundscheck=False)
jit = numba.njit(**_OPTIONS)
jit_no_nrt = numba.njit(**_OPTIONS, _nrt=False)
jit_inline = numba.njit(**_OPTIONS, _nrt=False, inline="always")

# Modules of this folder that define cached kernels (their cache index files are named after them).
KERNEL_MODULES = ("geometry_kernels", "path_kernels", "mesh_checks", "camera", "sampling", "warps", "bsdf_kernels",
                  "world_kernels", "light_kernels", "embree", "shading/regs", "shading/evaluator",
                  "shading/procedural", "shading/color", "ray_visibility")


def compile_cache_is_cold(with_node_programs: bool = False) -> bool:
    """True when some kernel module has no numba cache index yet for this import of the package (first render
    after an install or an update of the sources): that render compiles the kernels first, about a minute on a
    2-core machine. The node-program evaluator (core/shading/) compiles only for scenes with node programs:
    counted when `with_node_programs`."""
    cache = cache_dir()
    return any(not glob.glob(os.path.join(cache, f"{os.path.basename(name)}.*.nbi"))
               for name in KERNEL_MODULES if with_node_programs or not name.startswith("shading/"))
