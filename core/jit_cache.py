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

A cache is valid while the sources are: its stamp is a SHA-256 of the kernel modules' contents and the numba
options, not the files' times, so a cache built once and shipped (the extension zip,
`make setup`) stays valid when unzipping or checking out rewrites the times, and any edit of a kernel module
recompiles. Kernels are compiled for a named level of the architecture rather than for this exact CPU (x86-64-v3
where the CPU has AVX2 and the rest of that level, else the generic baseline), so a cache built on one machine loads
on every other of its level: see `_select_kernel_cpu()`.
"""

from __future__ import annotations

import contextlib
import copy as copy_module
import errno
import hashlib
import os
import sys
import threading
import warnings
import weakref
from typing import Callable


class _YamlOnUse:
    """numba.core.config's `yaml` where numba was imported without YAML (_import_numba_without_scipy_version_check):
    YAML is imported when numba first reads a `.numba_config.yaml`."""

    def __getattr__(self, name):
        import yaml

        return getattr(yaml, name)


def _install_patch(owner, name: str, replacement, original, flag: str) -> bool:
    """Put `replacement` where numba had `original` (owner.name), marked with `flag` (a later call of the same
    installer finds it in place) and keeping numba's function as `_numba_original`, and numba's docstring where
    the replacement has none of its own (a module-level replacement keeps the one saying how it differs).
    Returns True."""
    setattr(replacement, flag, True)
    replacement._numba_original = original
    if not replacement.__doc__:
        replacement.__doc__ = original.__doc__
    setattr(owner, name, replacement)
    return True


def _import_numba_without_scipy_version_check() -> bool:
    """Import numba without its import-time SciPy check: numba's __init__ imports SciPy only to refuse a SciPy
    older than 1.0 (~0.02 s of CPU of every `monte render` process here: SciPy's package and Cython's shadow
    module; Blender ships no SciPy). SciPy is hidden for that one import (sys.modules[name] = None makes an import
    of it fail) and put back at once; numba's own later uses of SciPy (np.linalg and np.dot's BLAS/LAPACK lookups)
    import it when called and keep working. Nothing is changed when numba or SciPy is already imported.

    YAML too, where no `.numba_config.yaml` is in the working folder: numba's config imports PyYAML at its import
    only to read that file when there is one (0.006-0.01 s of CPU where PyYAML is installed: the venv, not
    Blender). numba's config then gets YAML on first use (_YamlOnUse) and still reads a config file that
    appears later (numba checks for it before each compile). Returns True when numba was imported this way."""
    if "numba" in sys.modules or "scipy" in sys.modules or threading.active_count() > 1:
        return False  # (another thread could import SciPy while it is hidden: import it plainly then)
    hidden = ["scipy"]
    if "yaml" not in sys.modules and not os.path.exists(".numba_config.yaml"):
        hidden.append("yaml")
    for name in hidden:
        sys.modules[name] = None  # type: ignore[assignment]
    try:
        import numba  # noqa: F401
    finally:
        for name in hidden:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]
    if "yaml" in hidden:
        _defer_yaml_of_numba_config()
    return True


def _defer_yaml_of_numba_config() -> None:
    """numba's config, imported with YAML hidden, found none: give it YAML to import on first use where PyYAML is
    installed (so that a `.numba_config.yaml` is read as numba would), else leave numba's "no YAML" as it is."""
    from importlib.util import find_spec

    config = sys.modules.get("numba.core.config")
    if config is None or getattr(config, "_HAVE_YAML", True) or "yaml" in vars(config):
        return
    try:
        have = find_spec("yaml") is not None
    except (ImportError, ValueError):
        have = False
    if have:
        config.yaml = _YamlOnUse()
        config._HAVE_YAML = True


NUMBA_IMPORTED_WITHOUT_SCIPY = _import_numba_without_scipy_version_check()

import numba  # noqa: E402
from numba.core import caching  # noqa: E402
from numba.core import event as numba_events  # noqa: E402

_CORE_DIR = os.path.dirname(os.path.abspath(__file__))
KERNEL_CPU_ENV = "MONTE_KERNEL_CPU"  # "auto" (the default), "generic", "x86-64-v3" or "host"
KERNEL_CPU_CHOICES = ("auto", "generic", "x86-64-v3", "host")

# The x86-64-v3 level's features as LLVM names them: x86-64-v2's (SSE3 to SSE4.2, POPCNT, CMPXCHG16B, LAHF) and
# AVX, AVX2, BMI1, BMI2, F16C, FMA, LZCNT, MOVBE, XSAVE. Intel's Core CPUs since Haswell (2013) and AMD's since
# Excavator (2015), every Zen included, have them; Intel's Atom-class Pentium and Celeron parts long did not.
X86_64_V3_FEATURES = ("cx16", "sahf", "popcnt", "sse3", "sse4.1", "sse4.2", "ssse3", "avx", "avx2", "bmi", "bmi2",
                      "f16c", "fma", "lzcnt", "movbe", "xsave")


def level_kernel_cpu(triple: str, features: "dict[str, bool]") -> str:
    """The CPU level Monte's kernels are compiled for on a machine whose LLVM target triple and host features (as
    llvmlite.binding.get_host_cpu_features names them) are given: "x86-64-v3" on an x86-64 CPU that has all of
    X86_64_V3_FEATURES, else "generic" (the architecture's baseline: SSE2 on x86-64)."""
    if triple.split("-", 1)[0] in ("x86_64", "amd64") and all(features.get(f) for f in X86_64_V3_FEATURES):
        return "x86-64-v3"
    return "generic"


def _host_level() -> str:
    """level_kernel_cpu of this machine (generic where LLVM cannot say)."""
    import llvmlite.binding as ll

    try:
        features = dict(ll.get_host_cpu_features())
    except RuntimeError:  # (LLVM knows no features for this host)
        features = {}
    return level_kernel_cpu(ll.get_process_triple(), features)


def _numba_codegen_exists() -> bool:
    """True once numba has made its CPU code generator (the first kernel defined in the process, by any
    package), after which the CPU it compiles for is fixed."""
    from numba.core.registry import cpu_target

    return "_toplevel_target_context" in vars(cpu_target)


def _select_kernel_cpu() -> str:
    """Make numba compile for a named CPU level rather than this machine's exact CPU, so that cached kernels built
    elsewhere (the extension zip, `make setup`) load on every machine of that level: numba keys each cached kernel
    by the CPU name and features it was compiled for. The level (MONTE_KERNEL_CPU=auto, the default) is x86-64-v3
    where the CPU has it (AVX2, FMA, BMI2, ...: docs/performance.md measured up to 7 % less render CPU than SSE2-only
    code, the most on scenes with node programs), else the architecture's generic baseline;
    MONTE_KERNEL_CPU=generic or x86-64-v3 names one (x86-64-v3 on a CPU without it falls back to generic, with a
    warning: its code would not run here). The image bits are the same at every level: the
    kernels use no fast-math, so LLVM neither fuses multiply-adds nor reorders float arithmetic, and the math
    functions are the same library calls.

    Left alone when the user chose a CPU for numba (NUMBA_CPU_NAME), when MONTE_KERNEL_CPU=host asks for kernels
    tuned to this exact CPU (compiled on the first render, never shipped), and when numba already compiled for
    this process's CPU before Monte was imported (another add-on's kernels): then Monte compiles its own kernels
    once, with a warning. Returns the CPU name numba uses ("x86-64-v3", "generic", or "host")."""
    if os.environ.get("NUMBA_CPU_NAME"):
        return os.environ["NUMBA_CPU_NAME"]
    choice = os.environ.get(KERNEL_CPU_ENV, "auto").strip().lower() or "auto"
    if choice not in KERNEL_CPU_CHOICES:
        warnings.warn(f"{KERNEL_CPU_ENV}={os.environ[KERNEL_CPU_ENV]!r} is not one of "
                      f"{', '.join(KERNEL_CPU_CHOICES)}; using 'auto'", stacklevel=2)
        choice = "auto"
    if choice == "host":
        return "host"
    if choice != "generic":
        level = _host_level()
        if choice == "x86-64-v3" and level != choice:
            warnings.warn(f"{KERNEL_CPU_ENV}=x86-64-v3: this CPU lacks some of that level's features "
                          f"({', '.join(X86_64_V3_FEATURES)}); compiling for a generic CPU", stacklevel=2)
        choice = level
    if _numba_codegen_exists():
        warnings.warn("numba was already compiling for this machine's CPU before Monte was loaded (another "
                      "package's kernels): Monte's shipped kernels do not apply and are compiled once on the "
                      "first render", stacklevel=2)
        return "host"
    # The environment too: numba re-reads NUMBA_* variables before each compile and would reset the config.
    os.environ["NUMBA_CPU_NAME"] = choice
    os.environ["NUMBA_CPU_FEATURES"] = ""
    NUMBA_ENVIRONMENT_WRITTEN.update(NUMBA_CPU_NAME=choice, NUMBA_CPU_FEATURES="")
    numba.config.CPU_NAME = choice
    numba.config.CPU_FEATURES = ""
    return choice


# What _select_kernel_cpu wrote into this process's environment (nothing where the user chose numba's CPU, or
# asked for host kernels). Child processes inherit it, and there it would win over their own choice: see
# child_environment.
NUMBA_ENVIRONMENT_WRITTEN: dict[str, str] = {}


def child_environment(env: "dict[str, str] | None" = None) -> dict[str, str]:
    """A copy of env (default: this process's environment) without the NUMBA_* values Monte wrote into it
    (NUMBA_ENVIRONMENT_WRITTEN), for starting another process that should choose its own kernel CPU level: a
    Monte of another checkout (whose `auto` may differ), a bench's renderer. NUMBA_* values the user set stay."""
    copy = dict(os.environ if env is None else env)
    for name, value in NUMBA_ENVIRONMENT_WRITTEN.items():
        if copy.get(name) == value:
            del copy[name]
    return copy


KERNEL_CPU = _select_kernel_cpu()


def _import_numba_array_support_without_blas() -> bool:
    """Import numba's NumPy-array implementations (numba.np.arraymath) without letting it import SciPy's linear
    algebra, which it does only to ask whether a BLAS exists (0.4-0.45 s of a process's first kernel load on the
    2-core machine, the largest single part of loading the cached kernels). Monte's kernels call no BLAS: they
    compile and load in Blender, which ships no SciPy. numba's answer feeds one choice only (the inner product of
    its np.correlate and np.convolve: a plain loop instead of BLAS); numba's np.dot and np.linalg ask for the
    BLAS again themselves and keep working with SciPy. Done under numba's compiler lock, so no kernel compiled
    on another thread meanwhile sees the stand-in. Nothing is changed when numba.np.arraymath or SciPy's
    linear algebra is already imported (another package in the process chose already, or the import is free).
    Returns True when it imported arraymath this way."""
    import sys

    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return False
    from numba.core.compiler_lock import global_compiler_lock
    from numba.np import linalg

    def no_blas_lookup() -> None:
        raise ImportError("numba.np.arraymath imported by Monte without SciPy's BLAS lookup")

    with global_compiler_lock:
        if "numba.np.arraymath" in sys.modules:
            return False
        original = linalg.ensure_blas
        linalg.ensure_blas = no_blas_lookup
        try:
            import numba.np.arraymath  # noqa: F401 - its import-time BLAS check sees no_blas_lookup
        finally:
            linalg.ensure_blas = original
    return True


_FRESH_CALLEE = threading.local()  # .active: inline_ir is inlining an IR that inline_function has just built
_INLINE_FUNCTION_NAMES = frozenset({"run_untyped_passes", "__code__", "co_freevars", "inline_ir"})
_inline_patch_state: list[bool] = []  # [installed?] once decided


class _CopyUnlessFresh:
    """numba.core.inline_closurecall's `copy` module, whose deepcopy returns its argument while inline_ir inlines
    a callee IR that nobody else holds (_FRESH_CALLEE.active); everything else is the copy module's."""

    def __init__(self, module) -> None:
        self._module = module

    def __getattr__(self, name: str):
        return getattr(self._module, name)

    def deepcopy(self, x, memo=None):
        if getattr(_FRESH_CALLEE, "active", False):
            return x
        return self._module.deepcopy(x, memo)


def _inline_fresh_callees_without_copies() -> bool:
    """Inline Monte's `jit_inline` device functions (numba's inline="always") without numba deep-copying each
    callee's IR twice per call site. numba's InlineWorker.inline_function builds the callee's IR afresh from its
    bytecode (run_untyped_passes) and hands it to inline_ir, which deep-copies it block by block before mutating
    it, and deep-copies the copy again to return an unmutated original, which the only caller of inline_function
    (the untyped InlineInlinables pass) discards. Neither copy protects anything there: nothing else holds that
    IR. The copies were ~45 % of the fused path kernel's cold compile (cProfile: 64 s of 140 s in `deepcopy`, for
    118 inlined calls). inline_ir called directly (typed overload inlining, whose IR is cached and reused) keeps
    both copies. The inlined IR is the same either way, and so is the compiled code (checked by
    tests/test_jit_cache.py). Installed on numba's first compile in the process (the registries' first load,
    _defer_numba_array_support_to_first_compile: where another package compiled first, numba's own inliner
    stays), so a process that only loads cached kernels does not pay for installing it; only on the numba
    versions whose code was read, with inline_function's code as read; MONTE_PLAIN_NUMBA_LOADS=1 leaves numba's
    own. The two other cuts of the cold compile are installed beside it, each on its own check of numba's code
    (_live_maps_as_bits, _ssa_rewrites_only_where_named). Returns True when this one is installed."""
    if _inline_patch_state:
        return _inline_patch_state[0]
    installed = False
    if _numba_patchable():
        from numba.core import inline_closurecall

        worker = getattr(inline_closurecall, "InlineWorker", None)
        original = getattr(worker, "__dict__", {}).get("inline_function")
        code = getattr(original, "__code__", None)
        if getattr(original, "_monte_fresh_callee", False):
            installed = True  # installed by another import of this package
        elif (code is not None and frozenset(code.co_names) == _INLINE_FUNCTION_NAMES
                and getattr(inline_closurecall, "copy", None) is copy_module):

            def inline_function(self, caller_ir, block, i, function, arg_typs=None):
                callee_ir = self.run_untyped_passes(function)
                _FRESH_CALLEE.active = True
                try:
                    return self.inline_ir(caller_ir, block, i, callee_ir, function.__code__.co_freevars,
                                          arg_typs=arg_typs)
                finally:
                    _FRESH_CALLEE.active = False

            inline_closurecall.copy = _CopyUnlessFresh(copy_module)
            installed = _install_patch(worker, "inline_function", inline_function, original, "_monte_fresh_callee")
        _live_maps_as_bits()
        _ssa_rewrites_only_where_named()
    _inline_patch_state.append(installed)
    return installed


# The names numba's compute_live_map (numba 0.68) and its nested functions use, as read for _live_map_as_bits.
_LIVE_MAP_NAMES = frozenset({"topo_order", "defaultdict", "set", "keys", "tuple", "values", "len", "successors",
                             "predecessors", "reversed"})


def _code_names(code) -> frozenset:
    """The global and attribute names a code object and the functions nested in it use."""
    names = set(code.co_names)
    for const in code.co_consts:
        if hasattr(const, "co_names"):
            names |= _code_names(const)
    return frozenset(names)


def _live_map_as_bits(cfg, blocks, var_use_map, var_def_map):
    """numba.core.analysis.compute_live_map (the variables live at the entry of each block) with each block's
    sets of variable names held as the bits of one Python int: the same two fixed points over the same block
    order (definitions reaching each block's entry, forward; liveness, backward), where numba unions sets of
    names. On the fused path kernel's IR (~650 blocks, thousands of variables after inlining) the set unions of
    the reaching definitions were ~16 s of its cold compile under cProfile (numba computes the map after every
    pass that changes the IR). The result is the least fixed point of the same monotone equations, so the same
    sets: checked against numba's on all 1,476 maps of the fused kernel's two compiles (docs/performance.md,
    *The cold compile*) and on IR with loops, break and continue in tests/test_jit_cache.py."""
    topo_order = cfg.topo_order()
    bits: dict = {}
    names: list = []

    def mask(vars_) -> int:
        m = 0
        for name in vars_:
            b = bits.get(name)
            if b is None:
                b = bits[name] = 1 << len(names)
                names.append(name)
            m |= b
        return m

    defs: dict = {}
    uses = {offset: mask(var_use_map[offset]) for offset in blocks.keys()}

    def defs_of(offset) -> int:
        m = defs.get(offset)
        if m is None:
            m = defs[offset] = mask(var_def_map[offset])
        return m

    reach: dict = {}
    changed = True
    while changed:
        changed = False
        for offset in topo_order:
            here = reach.get(offset, 0)
            now = here | defs_of(offset) | (uses[offset] if offset in uses else mask(var_use_map[offset]))
            if now != here:
                reach[offset] = now
                changed = True
            for out_blk, _ in cfg.successors(offset):
                before = reach.get(out_blk, 0)
                after = before | now
                if after != before:
                    reach[out_blk] = after
                    changed = True
    live = dict(uses)
    changed = True
    while changed:
        changed = False
        for offset in reversed(topo_order):
            live_vars = live[offset]
            for inc_blk, _ in cfg.predecessors(offset):
                before = live[inc_blk]
                after = before | (live_vars & reach.get(inc_blk, 0) & ~defs_of(inc_blk))
                if after != before:
                    live[inc_blk] = after
                    changed = True
                    if inc_blk == offset:
                        live_vars = after

    def names_of(m: int) -> set:
        out = set()
        while m:
            low = m & -m
            out.add(names[low.bit_length() - 1])
            m ^= low
        return out

    return {offset: names_of(m) for offset, m in live.items()}


def _live_maps_as_bits() -> bool:
    """Install _live_map_as_bits as numba's compute_live_map (numba.core.analysis's, which the IR post-processor
    calls after every IR-changing pass, and ir_utils' copy, which dead-code removal calls), where numba's
    function is the one read (its code calling exactly what was read). Installed with the inliner patch, on
    numba's first compile. Returns True when installed."""
    from numba.core import analysis, ir_utils

    original = analysis.__dict__.get("compute_live_map")
    if getattr(original, "_monte_bits", False):
        return True
    code = getattr(original, "__code__", None)
    if code is None or _code_names(code) != _LIVE_MAP_NAMES or code.co_argcount != 4 or \
            getattr(ir_utils, "compute_live_map", None) is not original:
        return False
    _install_patch(analysis, "compute_live_map", _live_map_as_bits, original, "_monte_bits")
    ir_utils.compute_live_map = _live_map_as_bits
    return True


_SSA_OCCURRENCES = threading.local()  # .labels: {variable name: labels of the blocks naming it} during _run_ssa
_RUN_SSA_NAMES = frozenset({"CompilerError", "_CacheListVars", "_find_defs_violators", "_fix_ssa_vars", "_fresh_vars",
                            "_iterated_domfronts", "_lazy_pformat", "_logger", "compute_cfg_from_blocks", "debug",
                            "errors"})
_BLOCK_REWRITE_NAMES = frozenset({"Block", "_logger", "_run_ssa_block_pass", "append", "body", "debug", "ir", "items",
                                  "loc", "scope"})


def _ssa_rewrites_only_where_named() -> bool:
    """Let numba's SSA reconstruction rewrite only the blocks that name the variable it is fixing. numba's
    _run_ssa fixes one variable with several definitions at a time, and for each it rewrites every statement of
    every block twice (fresh names for its definitions, then each use tied to its reaching definition): ~324
    variables x ~26,000 statements in the fused path kernel's IR after inlining, where a variable is named in a
    handful of blocks. A statement that does not name the variable comes back from both rewrites as it is, with
    nothing else changed, so a block naming it nowhere becomes a new block holding the same statements, as numba
    would make it, without the per-statement work. Which blocks name which variable is listed once per _run_ssa
    (every statement's list_vars, a superset of what the two rewrites read); fixing one variable never makes
    another appear in a block (its new names are fresh, its phi nodes name only its own versions). The blocks
    that name it are rewritten by numba's own code, in numba's order, so the IR is the same. Installed with the
    inliner patch, on numba's first compile, where numba's two functions are the ones read. Returns True when
    installed."""
    from numba.core import ir, ssa

    run_ssa = ssa.__dict__.get("_run_ssa")
    rewrite = ssa.__dict__.get("_run_block_rewrite")
    if getattr(run_ssa, "_monte_named_blocks", False):
        return True
    handlers = (getattr(ssa, "_FreshVarHandler", None), getattr(ssa, "_FixSSAVars", None))
    if (getattr(run_ssa, "__code__", None) is None or getattr(rewrite, "__code__", None) is None or None in handlers
            or frozenset(run_ssa.__code__.co_names) != _RUN_SSA_NAMES
            or frozenset(rewrite.__code__.co_names) != _BLOCK_REWRITE_NAMES):
        return False

    def naming_blocks(blocks) -> dict:
        labels: dict = {}
        for label, block in blocks.items():
            for stmt in block.body:
                for var in stmt.list_vars():
                    labels.setdefault(var.name, set()).add(label)
        return labels

    def _run_ssa(blocks):
        outer = getattr(_SSA_OCCURRENCES, "labels", None)
        _SSA_OCCURRENCES.labels = naming_blocks(blocks) if blocks else None
        try:
            return run_ssa(blocks)
        finally:
            _SSA_OCCURRENCES.labels = outer

    def _run_block_rewrite(blocks, states, handler):
        occurrences = getattr(_SSA_OCCURRENCES, "labels", None)
        if occurrences is None or type(handler) not in handlers:
            return rewrite(blocks, states, handler)
        named = occurrences.get(states["varname"], ())
        newblocks = {}
        for label, block in blocks.items():
            if label in named:
                newblocks.update(rewrite({label: block}, states, handler))
            else:
                same = ir.Block(scope=block.scope, loc=block.loc)
                same.body = list(block.body)
                newblocks[label] = same
        return newblocks

    _install_patch(ssa, "_run_block_rewrite", _run_block_rewrite, rewrite, "_monte_named_blocks")
    return _install_patch(ssa, "_run_ssa", _run_ssa, run_ssa, "_monte_named_blocks")


def _defer_numba_array_support_to_first_compile() -> bool:
    """Import numba's array support (_import_numba_array_support_without_blas) when numba first installs its
    registries, not at Monte's import: a process that only loads cached kernels never needs it (they load
    without the registries: _load_cached_kernels_without_refresh), and its import was ~0.025 s of CPU of every
    `monte render` process. numba installs its registries in CPUContext.refresh, through
    load_additional_registries, which imports numba.np.arraymath among ~55 modules (and with it SciPy's linear
    algebra, the lookup this avoids): that method is wrapped to import arraymath without the lookup first. Where
    the method is not numba's own function (another version or package replaced it) arraymath is imported now,
    as before. Returns True when numba's array support is (or will be) imported without the BLAS lookup."""
    from numba.core import cpu

    original = cpu.CPUContext.__dict__.get("load_additional_registries")
    if getattr(original, "_monte_array_support_first", False):
        return True  # wrapped by another import of this package
    if "numba.np.arraymath" in sys.modules or getattr(original, "__module__", None) != "numba.core.cpu":
        return _import_numba_array_support_without_blas()

    def load_additional_registries(self):
        _import_numba_array_support_without_blas()  # no-op once imported (a dict lookup)
        _inline_fresh_callees_without_copies()  # (a flag check once installed)
        _initialize_numba_extensions()  # (numba's first dispatcher call would have; a flag check once done)
        result = original(self)
        _complete_deferred_environments()  # (defined below; a list check once nothing is pending)
        return result

    return _install_patch(cpu.CPUContext, "load_additional_registries", load_additional_registries, original,
                          "_monte_array_support_first")


NUMBA_ARRAY_SUPPORT_WITHOUT_BLAS = _defer_numba_array_support_to_first_compile()


def _drop_numba_llvm_lock_events() -> bool:
    """Stop numba broadcasting an event on every LLVM call. numba registers two callbacks with llvmlite's LLVM
    lock (numba.core.base) that broadcast a "numba:llvm_lock" start and end event each time any LLVM C function
    is called; their only listener is the timer a compile or cache load installs to record the `llvm_lock` entry
    of the kernel's metadata["timers"] (a diagnostic; without the events that entry is absent, nothing else reads
    it). Loading a cached kernel makes ~200 LLVM calls (parsing its library, listing its symbols): the events were
    ~9 % of the CPU time of loading the 47 entry kernels (0.32-0.33 s against 0.35-0.36 s, 4 processes each).
    Process-wide, like numba's own registration; other numba users in the process lose only that timer. Returns
    True when the callbacks were found and removed."""
    import numba.core.base  # noqa: F401 - registers the callbacks at its import
    from llvmlite.binding import ffi

    lock = getattr(getattr(ffi, "lib", None), "_lock", None)
    callbacks = [cb for cb in getattr(lock, "_cblist", ())
                 if getattr(cb[0], "__module__", None) == "numba.core.base"
                 and getattr(cb[0], "__name__", None) == "enter_fn"]
    rlock = getattr(lock, "_lock", None)
    if rlock is None:
        return False
    with rlock:  # no LLVM call in another thread is between its acquire and release callbacks meanwhile
        for acquire, release in callbacks:
            ffi.unregister_lock_callback(acquire, release)
    return bool(callbacks)


NUMBA_LLVM_LOCK_EVENTS_DROPPED = _drop_numba_llvm_lock_events()

# Set (to anything but 0) to load cached kernels numba's own way (the registries refreshed, every library's
# bitcode parsed at once): the fallback should a numba version misbehave with the two patches below.
PLAIN_NUMBA_LOADS_ENV = "MONTE_PLAIN_NUMBA_LOADS"
# numba versions whose Cache.load_overload was read for _load_cached_kernels_without_refresh (its code is checked too).
_CACHE_LOAD_NUMBA_VERSIONS = ((0, 59), (0, 68))
_CACHE_LOAD_NAMES = frozenset({"refresh", "_guard_against_spurious_io_errors", "_load_overload"})


def _numba_patchable() -> bool:
    """The two conditions every patch of numba's internals here shares: MONTE_PLAIN_NUMBA_LOADS unset (or 0) and
    numba within the versions whose code was read (_CACHE_LOAD_NUMBA_VERSIONS). Each patch checks numba's code
    itself too."""
    if os.environ.get(PLAIN_NUMBA_LOADS_ENV, "").strip() not in ("", "0"):
        return False
    return _CACHE_LOAD_NUMBA_VERSIONS[0] <= tuple(numba.version_info[:2]) <= _CACHE_LOAD_NUMBA_VERSIONS[1]


def _load_cached_kernels_without_refresh() -> bool:
    """Load cached CPU kernels without numba's typing and lowering registries. numba's Cache.load_overload
    refreshes the target context before every cached load ("to ensure it is initialized"): the first refresh of a
    process imports ~55 numba modules of implementations (typed containers, np.random, jitclass, cffi, ...) and
    installs every registry (~0.08 s of CPU, the largest part of a process's first kernel load; the export's
    constant folding waits for it), each later one ~0.3 ms. A cached kernel needs none of it: its library is
    machine code already, linked with every function it calls; the only run-time piece it takes from numba is
    NRT (the reference-counting runtime, whose C symbols an NRT kernel's code links against), which is
    initialized here as the refresh would. Compiling still refreshes both contexts first (numba's CompilerBase
    does so before every compile), so a kernel compiled later in the process, Monte's or another add-on's, finds
    the registries installed as before.

    Applied only where numba's method is the one read (numba 0.59-0.68, its code calling exactly refresh,
    _guard_against_spurious_io_errors and _load_overload), and only to Monte's kernels (those cached by
    _PerImportNameLocator) on numba's CPU context: other packages' functions, other targets (CUDA) and other
    numba versions keep numba's own; MONTE_PLAIN_NUMBA_LOADS=1 turns it off. tests/test_jit_cache.py fails when
    this stops applying. Returns True when installed."""
    from numba.core import caching, cpu

    if not _numba_patchable():
        return False
    cache_class = getattr(caching, "Cache", None)
    original = getattr(cache_class, "__dict__", {}).get("load_overload")
    code = getattr(original, "__code__", None)
    if getattr(original, "_monte_without_refresh", False):
        return True  # installed by another import of this package (a second import name in one process)
    if code is None or frozenset(code.co_names) != _CACHE_LOAD_NAMES or code.co_argcount != 3:
        return False
    from numba.core.runtime import rtsys

    cpu_context = cpu.CPUContext

    def load_overload(self, sig, target_context):
        if type(target_context) is not cpu_context or not getattr(getattr(getattr(self, "_impl", None), "locator",
                                                                          None), "_monte_kernel", False):
            return original(self, sig, target_context)
        rtsys.initialize(target_context)  # what the refresh did that a cached kernel needs: NRT's symbols
        _LAZY.active = True  # this thread's libraries rebuilt now may leave their bitcode unparsed
        try:
            with self._guard_against_spurious_io_errors():
                return self._load_overload(sig, target_context)
            # (None when the `with` swallows an I/O error, as numba's)
        finally:
            _LAZY.active = False

    return _install_patch(cache_class, "load_overload", load_overload, original, "_monte_without_refresh")


NUMBA_CACHE_LOADS_WITHOUT_REFRESH = _load_cached_kernels_without_refresh()


class _ParsedWhenRead(property):
    """JITCodeLibrary._shared_module as installed by _parse_bitcode_when_needed."""

    _monte = True


_LAZY = threading.local()  # .active: a Monte kernel's cached load is under way on this thread
_PENDING_BITCODE = "_monte_pending_bitcode"  # a library's attribute: its bitcode, not parsed yet


def _parse_bitcode_when_needed() -> bool:
    """Leave a cached kernel's LLVM bitcode unparsed until something needs it. numba's cache holds each kernel as
    its object code (what runs) and its optimized LLVM bitcode; loading parses the bitcode (~40 % of a load) and
    lists the symbols it defines (~7 %), but only two things ever use that module: linking the kernel into a
    function compiled later (a compile in the process that calls it) and answering "is this symbol defined"
    for names the library defines. The object code is loaded as before (numba hands it to LLVM's JIT for the
    library's empty final module), so the kernel runs the same machine code. Loading the 51 entry signatures in
    a fresh process: 0.25 -> 0.095 s of CPU.

    Only for libraries rebuilt while a Monte kernel loads from the cache (the `load_overload` above) on numba's
    JIT libraries: `JITCodeLibrary._shared_module` becomes a property that parses the kept bitcode (and lists
    its symbols) the first time it is read; numba's engine parses every pending library before it answers "not
    defined"; the one name a load asks for at once, the kernel's Python wrapper (numba's CPUContext.get_executable
    takes its address), is the name numba compiled the library for, so it is recorded as defined without the
    parse. Guarded: the numba versions of _load_cached_kernels_without_refresh, numba's methods' code checked,
    nothing installed unless every piece is as read. Returns True when installed."""
    from numba.core import codegen, cpu

    library_class, engine_class = getattr(codegen, "JITCodeLibrary", None), getattr(codegen, "JitEngine", None)
    unserialize = getattr(codegen, "CPUCodeLibrary", object).__dict__.get("_unserialize")
    get_executable = cpu.CPUContext.__dict__.get("get_executable")
    is_defined = getattr(engine_class, "__dict__", {}).get("is_symbol_defined")
    if library_class is None or engine_class is None or unserialize is None or get_executable is None:
        return False
    if isinstance(library_class.__dict__.get("_shared_module"), property):
        return bool(getattr(library_class.__dict__["_shared_module"], "_monte", False))
    names = set(getattr(getattr(getattr(unserialize, "__func__", None), "__code__", None), "co_names", ()))
    if not {"parse_bitcode", "_set_compiled_object", "_load_defined_symbols", "_shared_module",
            "_finalize_final_module", "enable_object_caching"} <= names or is_defined is None:
        return False
    original_unserialize = unserialize.__func__
    import llvmlite.binding as ll

    lock = threading.RLock()

    def materialize(library) -> None:
        # The pending bitcode goes only once the module is in place, so that a reader on another thread either
        # waits here or finds the module (never None), and a parse that raises leaves it pending, raising again.
        with lock:
            data = library.__dict__.get(_PENDING_BITCODE)
            if data is not None:
                module = ll.parse_bitcode(data)
                library.__dict__["_shared_module"] = module
                library._codegen._engine._load_defined_symbols(module)
                del library.__dict__[_PENDING_BITCODE]

    def shared_module(self):
        if _PENDING_BITCODE in self.__dict__:
            materialize(self)
        return self.__dict__.get("_shared_module")

    def set_shared_module(self, value):
        self.__dict__["_shared_module"] = value

    def lazy_unserialize(cls, cg, state):
        name, kind, data = state
        if kind != "object" or not getattr(_LAZY, "active", False) or cls is not library_class:
            return original_unserialize(cls, cg, state)
        self = cg.create_library(name)
        object_code, shared_bitcode = data
        self.enable_object_caching()
        self._set_compiled_object(object_code)
        self.__dict__["_shared_module"] = None
        self.__dict__[_PENDING_BITCODE] = shared_bitcode
        with lock:
            cg._engine.__dict__.setdefault("_monte_pending", weakref.WeakSet()).add(self)
        self._finalize_final_module()
        return self

    def lazy_is_symbol_defined(self, name):
        if name in self._defined_symbols:
            return True
        pending = self.__dict__.get("_monte_pending")
        if pending:
            with lock:
                for library in list(pending):
                    materialize(library)
                pending.clear()
        return name in self._defined_symbols

    def executable(self, library, fndesc, env):
        if _PENDING_BITCODE in getattr(library, "__dict__", {}):
            library._codegen._engine._defined_symbols.add(fndesc.llvm_cpython_wrapper_name)
        return get_executable(self, library, fndesc, env)

    library_class._shared_module = _ParsedWhenRead(shared_module, set_shared_module)
    library_class._unserialize = classmethod(lazy_unserialize)
    engine_class.is_symbol_defined = lazy_is_symbol_defined
    executable.__doc__ = get_executable.__doc__
    cpu.CPUContext.get_executable = executable
    return True


NUMBA_CACHE_LOADS_PARSE_LATER = NUMBA_CACHE_LOADS_WITHOUT_REFRESH and _parse_bitcode_when_needed()

# numba's _rebuild_env as read for _rebuild_numba_environments_without_import (its code is checked too).
_REBUILD_ENV_NAMES = frozenset({"Environment", "__dict__", "_memo", "consts", "env_name", "import_module",
                                "importlib", "lookup_environment"})
# Environments of numba's own modules rebuilt without importing the module: (environment, module name).
_DEFERRED_ENVIRONMENTS: list = []


def _rebuild_numba_environments_without_import() -> bool:
    """Rebuild the environments of numba's own implementations in a cached kernel without importing their
    modules. A cached kernel's data holds the Environment (the globals dict and constants) of every function
    compiled into it, numba's helpers included: np.empty's allocation helper refers to numba.np.arrayobj, an
    integer power to numba.cpython.numbers. numba's _rebuild_env imports the module to take its __dict__ as the
    environment's globals, and importing those two (with charseq, unicode, listobj, ... behind arrayobj) was
    0.03-0.07 s of every `monte render` process (the first load of `_sobol_fill`), for a dict nothing reads:
    a function compiled in nopython mode, numba's helpers all, reads only its environment's constants (the
    globals serve object mode's LOAD_GLOBAL). So while a Monte kernel loads from the cache
    (_load_cached_kernels_without_refresh), an environment whose module is one of numba's own and not imported
    yet gets a globals dict holding only the module's name (what pickling it again and numba's `can_cache` read)
    and its constants as numba's; the module's globals are copied in when numba installs its registries (the
    first compile of the process imports those modules: _complete_deferred_environments). Other modules (Monte's
    kernels' own, other packages') and environments rebuilt outside a Monte kernel's load go numba's way.
    Guarded by the numba versions of _load_cached_kernels_without_refresh and _rebuild_env's code. Returns True
    when installed."""
    from numba.core import environment

    original = environment.__dict__.get("_rebuild_env")
    if getattr(original, "_monte_without_import", False):
        return True
    code = getattr(original, "__code__", None)
    if (code is None or frozenset(code.co_names) != _REBUILD_ENV_NAMES or code.co_argcount != 3
            or not isinstance(getattr(environment, "Environment", None), type)):
        return False
    env_class = environment.Environment

    def _rebuild_env(modname, consts, env_name):
        if (not getattr(_LAZY, "active", False) or not isinstance(modname, str) or modname in sys.modules
                or not modname.startswith("numba.")):
            return original(modname, consts, env_name)
        env = environment.lookup_environment(env_name)
        if env is not None:
            return env
        env = env_class({"__name__": modname})
        env.consts[:] = consts
        env.env_name = env_name
        env_class._memo[env_name] = env
        with _DEFERRED_LOCK:
            _DEFERRED_ENVIRONMENTS.append((weakref.ref(env), modname))
        return env

    # Environment.__reduce__ names the module's _rebuild_env: every compile that saves a kernel pickles it, and a
    # closure would be pickled by value (with this module's thread-local state, which cannot be). Named as
    # numba's own, it pickles by reference, as numba's did, and unpickles to whichever one the module holds.
    _rebuild_env.__module__, _rebuild_env.__qualname__ = original.__module__, original.__qualname__
    return _install_patch(environment, "_rebuild_env", _rebuild_env, original, "_monte_without_import")


_DEFERRED_LOCK = threading.Lock()


def _complete_deferred_environments() -> None:
    """Copy each deferred environment's module globals in (importing the module: numba's registries import
    them all anyway), so that the environments look as numba's own rebuild made them. Called when numba
    installs its registries (the first compile of the process)."""
    with _DEFERRED_LOCK:
        pending = list(_DEFERRED_ENVIRONMENTS)
        _DEFERRED_ENVIRONMENTS.clear()
    import importlib

    for ref, modname in pending:
        env = ref()
        if env is not None:
            module = importlib.import_module(modname)
            for key, value in vars(module).items():
                env.globals.setdefault(key, value)


NUMBA_ENVIRONMENTS_WITHOUT_IMPORT = NUMBA_CACHE_LOADS_WITHOUT_REFRESH and _rebuild_numba_environments_without_import()

NRT_CACHE_PREFIX = "nrt-"  # the cached NRT module's file in cache_dir(): nrt-<key>.bin
_NRT_COMPILE_NAMES = frozenset({"create_nrt_module", "add_ir_module", "finalize"})


def _nrt_cache_key(ctx) -> str:
    """What NRT's compiled module depends on: numba's and llvmlite's versions, numba's NRT module source, the
    code generator (target triple, CPU name and features), the calling convention (its abort function), and the
    numba settings its IR and optimization read (NRT debugging and atomicity, word size, optimization level)."""
    import llvmlite
    from numba.core import config
    from numba.core.runtime import nrtdynmod

    h = hashlib.sha256(repr((numba.__version__, llvmlite.__version__, ctx.codegen().magic_tuple(),
                             type(ctx.call_conv).__qualname__, config.DEBUG_NRT,
                             getattr(nrtdynmod, "print_nrt_stack", None), getattr(nrtdynmod, "_disable_atomicity", None),
                             config.MACHINE_BITS, str(config.OPT))).encode())
    h.update(file_digest(nrtdynmod.__file__).encode())
    return h.hexdigest()[:24]


def _cache_nrt_module() -> bool:
    """Keep NRT's compiled module (numba's reference-counting runtime: atomic increments, incref/decref, the
    unresolved-symbol abort) beside the kernels, as numba keeps a kernel: its object code and bitcode. numba
    builds that module with LLVM in every process, on the first kernel load (rtsys.initialize): 0.01-0.02 s of
    CPU of every `monte render` process, spent before the export's first kernel. The cached module loads as
    numba loads a cached kernel (CPUCodeLibrary's unserialize: the object code run, the bitcode kept for
    linking into later compiles), so the runtime is the same machine code; the C helpers' symbols are still
    registered by numba's own initialize. Keyed by _nrt_cache_key (numba and llvmlite versions, numba's NRT
    source, the CPU); a missing, unreadable or foreign file means numba's compile, whose result is then written
    (when the folder is writable). Only for numba's CPU context on the numba versions of
    _load_cached_kernels_without_refresh with compile_nrt_functions's code as read; MONTE_PLAIN_NUMBA_LOADS=1
    turns it off. Returns True when installed."""
    from numba.core import cpu
    from numba.core.runtime import nrt, nrtdynmod

    original = nrtdynmod.__dict__.get("compile_nrt_functions")
    if getattr(original, "_monte_cached", False):
        return True
    code = getattr(original, "__code__", None)
    if code is None or frozenset(code.co_names) != _NRT_COMPILE_NAMES or code.co_argcount != 1:
        return False
    if getattr(getattr(nrt, "nrtdynmod", None), "compile_nrt_functions", None) is not original:
        return False
    import pickle

    def compile_nrt_functions(ctx):
        if type(ctx) is not cpu.CPUContext:
            return original(ctx)
        try:
            path = os.path.join(cache_dir(), f"{NRT_CACHE_PREFIX}{_nrt_cache_key(ctx)}.bin")
        except Exception:  # noqa: BLE001 - numba's own way
            return original(ctx)
        codegen = ctx.codegen()
        try:
            with open(path, "rb") as fh:
                name, object_code, bitcode = pickle.load(fh)
            if not (isinstance(object_code, bytes) and isinstance(bitcode, bytes)):
                raise ValueError(path)
        except Exception:  # noqa: BLE001 - absent, unreadable or foreign: compile it
            pass
        else:
            try:
                return codegen.unserialize_library((name, "object", (object_code, bitcode)))
            except Exception:  # noqa: BLE001
                pass
        ir_mod, library = nrtdynmod.create_nrt_module(ctx)
        library.enable_object_caching()  # (records the object code LLVM emits; the code itself is the same)
        library.add_ir_module(ir_mod)
        library.finalize()
        tmp = None
        try:
            state = library.serialize_using_object_code()
            os.makedirs(os.path.dirname(path), exist_ok=True)
            tmp = f"{path}.{os.getpid()}.{threading.get_ident()}.tmp"
            with open(tmp, "wb") as fh:
                pickle.dump((state[0], *state[2]), fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except Exception:  # noqa: BLE001 - a read-only folder: compiled again next time
            try:
                if tmp is not None:
                    os.unlink(tmp)
            except OSError:
                pass
        return library

    return _install_patch(nrtdynmod, "compile_nrt_functions", compile_nrt_functions, original, "_monte_cached")


NUMBA_NRT_MODULE_CACHED = NUMBA_CACHE_LOADS_WITHOUT_REFRESH and _cache_nrt_module()


def _initialize_numba_extensions() -> None:
    from numba.core import entrypoints

    entrypoints.init_all()  # returns at once when done


def _defer_numba_extensions_past_cached_kernels() -> bool:
    """Let a Monte kernel's first call skip numba's extension scan: numba's dispatcher, before its first
    compile-or-load of any function, runs every installed package's `numba_extensions` entry point
    (entrypoints.init_all: importlib.metadata reads every distribution's entry points, ~0.003 s of CPU in the
    venv), which registers the extensions' types and implementations for the compiler. Loading a cached kernel
    compiles nothing, so a Monte kernel's call leaves the scan to the first thing that needs it: any compile
    (numba refreshes its registries first: load_additional_registries, wrapped above, runs the scan before them,
    as numba's order) and the first call of any other package's function (numba's own hook). Installed only with
    that wrapper (_defer_numba_array_support_to_first_compile) and with the numba versions of
    _load_cached_kernels_without_refresh, the hook's code as read. Returns True when installed."""
    from numba.core import cpu, dispatcher

    base = getattr(dispatcher, "_DispatcherBase", None)
    original = getattr(base, "__dict__", {}).get("_compilation_chain_init_hook")
    if getattr(original, "_monte_deferred", False):
        return True
    code = getattr(original, "__code__", None)
    if (code is None or frozenset(code.co_names) != {"entrypoints", "init_all"} or code.co_argcount != 1
            or not getattr(cpu.CPUContext.__dict__.get("load_additional_registries"),
                           "_monte_array_support_first", False)):
        return False
    from numba.core import entrypoints

    def _compilation_chain_init_hook(self):
        if not entrypoints._already_initialized and getattr(
                getattr(getattr(getattr(self, "_cache", None), "_impl", None), "locator", None), "_monte_kernel", False):
            return  # a Monte kernel: loaded from the cache, or compiled (the refresh runs the scan first)
        return original(self)

    return _install_patch(base, "_compilation_chain_init_hook", _compilation_chain_init_hook, original,
                          "_monte_deferred")


NUMBA_EXTENSIONS_DEFERRED = NUMBA_CACHE_LOADS_WITHOUT_REFRESH and _defer_numba_extensions_past_cached_kernels()
PACKAGE = __name__.rpartition(".")[0] or "core"  # "monte.core", "bl_ext.user_default.monte.core", ...


# (path) -> ((mtime_ns, size, inode), sha256 hex): a file is hashed again only when its stat changes.
_DIGESTS: dict[str, tuple[tuple[int, int, int], str]] = {}


def file_digest(path: str) -> str:
    """SHA-256 (hex) of a file's contents; "" for a file that cannot be read (so its cache can never match)."""
    try:
        st = os.stat(path)
        key = (st.st_mtime_ns, st.st_size, st.st_ino)
        memo = _DIGESTS.get(path)
        if memo is not None and memo[0] == key:
            return memo[1]
        with open(path, "rb") as fh:
            digest = hashlib.sha256(fh.read()).hexdigest()
    except OSError:
        return ""
    _DIGESTS[path] = (key, digest)
    return digest


# (folder, names) -> (the files' stat keys, digest): recomputed only when a file's stat changes.
_SOURCES: dict[tuple[str, tuple[str, ...]], tuple[tuple, str]] = {}


def _stat_key(path: str) -> tuple[int, int, int]:
    try:
        st = os.stat(path)
    except OSError:
        return (-1, -1, -1)
    return st.st_mtime_ns, st.st_size, st.st_ino


def sources_digest(folder: str | None = None, names: tuple[str, ...] | None = None) -> str:
    """One SHA-256 (hex) over the numba options (OPTIONS_KEY) and the contents of the kernel modules `names`
    (default KERNEL_MODULES) in `folder` (default this package's core/): the key every cached kernel is valid
    for. Asked once per kernel when its module is imported, so it is memoized on the files' stat."""
    folder = folder or _CORE_DIR
    files = tuple(sorted(names if names is not None else KERNEL_MODULES))
    paths = [os.path.join(folder, f"{name}.py") for name in files]
    stats = (OPTIONS_KEY, *(_stat_key(path) for path in paths))
    memo = _SOURCES.get((folder, files))
    if memo is not None and memo[0] == stats:
        return memo[1]
    h = hashlib.sha256(OPTIONS_KEY.encode())
    for name, path in zip(files, paths):
        h.update(f"{name}.py:{file_digest(path)};".encode())
    _SOURCES[(folder, files)] = (stats, h.hexdigest())
    return h.hexdigest()


def cache_dir() -> str:
    """The folder this import of the package caches its kernels in."""
    return os.path.join(_CORE_DIR, "__pycache__", f"numba-{PACKAGE}")


# numba >= 0.59 names it InTreeCacheLocator; earlier versions _InTreeCacheLocator.
_InTree = getattr(caching, "InTreeCacheLocator", None) or getattr(caching, "_InTreeCacheLocator", None)
_CacheImpl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)

_WRITABLE: set[str] = set()  # cache folders this process found writable

# (the import's module spec, the module's file, the stamp) of the last kernel stamped
_LAST_STAMP: list = [None]


def _import_underway(module_name: str | None):
    """The spec of module `module_name` while Python is executing its import (or reload), else None: one object
    per import, so a digest kept for it is never reused by a later import of the module."""
    module = sys.modules.get(module_name) if module_name else None
    spec = getattr(module, "__spec__", None)
    return spec if getattr(spec, "_initializing", False) else None


def _kernel_source_stamp(py_file: str, module_name: str | None) -> tuple[str, str, str]:
    """A Monte kernel's cache stamp (_PerImportNameLocator.get_source_stamp): its own file's digest and every
    kernel module's (sources_digest), the latter taken once per import of a module (_import_underway)."""
    underway = _import_underway(module_name)
    last = _LAST_STAMP[0]
    if underway is not None and last is not None and last[0] is underway and last[1] == py_file:
        return last[2]  # (the module's file as read for its first kernel, in this import)
    stamp = "sha256", file_digest(py_file), sources_digest()
    if underway is not None:
        _LAST_STAMP[0] = (underway, py_file, stamp)
    return stamp


if _InTree is not None and _CacheImpl is not None:

    class _PerImportNameLocator(_InTree):
        """numba's in-tree locator, moved into this import name's folder, for functions defined here only.
        (A folder that cannot be written falls through to numba's next locator, as with the in-tree one.)"""

        _monte_kernel = True  # loaded without numba's registries: _load_cached_kernels_without_refresh

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            self._cache_path = cache_dir()
            self._module_name = getattr(py_func, "__module__", None)

        def get_source_stamp(self):
            """The contents of the function's own file and of every kernel module: numba checks only the file a
            function is defined in, but kernels call (and inline) functions of other kernel modules (core.warps
            from the light and BSDF kernels, core.geometry_kernels from core.path_kernels), whose edits must
            recompile them too. Contents, not numba's file times: see the module's docstring.

            numba asks once per kernel, as each is defined; the kernel modules' digest is taken once per import of
            a module (_import_underway) and reused for the module's further kernels (~340 kernels, each checking
            the stat of the 17 modules: ~0.01 s of CPU of every process's import)."""
            return _kernel_source_stamp(self._py_file, self._module_name)

        def ensure_cache_path(self):
            """numba's check (create the folder, write a temporary file in it), once per process instead of
            once per kernel: it was a file created and deleted for each of ~130 kernels at import."""
            if self._cache_path not in _WRITABLE:
                super().ensure_cache_path()
                _WRITABLE.add(self._cache_path)

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
# The options every kernel is compiled with, part of the cache key (edits elsewhere in this file are not).
OPTIONS_KEY = repr(sorted(_OPTIONS.items())) + "; no NRT; inline always"


class _CacheOnUse:
    """A Monte kernel's numba cache (FunctionCache), made the first time anything asks it for something: the
    kernel's first call (numba loads or compiles it through its cache), the background loader reading its
    index, a test. numba makes it when the kernel is defined (Dispatcher.enable_caching): ~0.05 ms per kernel
    (the locator search with its file checks, path work, the index file's names), ~0.015 s of every process's
    import for ~350 kernels, of which a 1-spp render calls ~15. The stamp its index is checked against is taken
    when the kernel is defined, as numba's is, so a kernel module edited between the import and the first call
    does not file the imported code under the edited sources' stamp. Module-level (nothing of it is pickled: a
    dispatcher pickles its function and options, never its cache). Its saves take the cache folder's lock
    (_OneSaveAtATime). See _defer_kernel_caches."""

    __slots__ = ("_dispatcher", "_stamp", "__weakref__")

    def __init__(self, dispatcher, stamp) -> None:
        self._dispatcher = weakref.ref(dispatcher)
        self._stamp = stamp

    def _made(self):
        dispatcher = self._dispatcher()
        if dispatcher is None:
            raise ReferenceError("the kernel of this cache is gone")
        with _CACHES_MADE:
            cache = dispatcher.__dict__.get("_cache")
            if cache is self or cache is None:
                cache = caching.FunctionCache(dispatcher.py_func)
                if type(getattr(cache._impl, "locator", None)) is _PerImportNameLocator:
                    cache._cache_file._source_stamp = self._stamp  # (the sources as they were when defined)
                    _save_under_lock(cache)
                dispatcher._cache = cache
        return cache

    def __getattr__(self, name):
        return getattr(self._made(), name)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} of {self._dispatcher()!r}>"


_CACHES_MADE = threading.Lock()


@contextlib.contextmanager
def file_lock(path: str):
    """An exclusive lock between processes on the file `path` (created if missing, left in place), held while the
    block runs; the operating system drops it when the process ends, however it ends. Yields True when locked;
    where the file cannot be created or locked (a read-only folder, a file system without locks) the block runs
    unlocked and it yields False. Not re-entrant: a second `with` on the same path in one process waits for the
    first to end, even on the same thread."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        yield False
        return
    locked = False
    try:
        try:
            if os.name == "nt":
                import msvcrt

                while True:
                    try:
                        msvcrt.locking(fd, msvcrt.LK_LOCK, 1)  # (gives up after ~10 s: then ask again)
                        break
                    except OSError as exc:
                        if exc.errno not in (errno.EDEADLK, getattr(errno, "EDEADLOCK", errno.EDEADLK),
                                             errno.EACCES):
                            raise
            else:
                import fcntl

                fcntl.flock(fd, fcntl.LOCK_EX)
            locked = True
        except OSError:
            pass
        yield locked
    finally:
        if locked and os.name == "nt":
            import msvcrt

            try:
                os.lseek(fd, 0, os.SEEK_SET)
                msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
            except OSError:
                pass
        os.close(fd)  # (drops a flock)


SAVE_LOCK_NAME = "save.lock"  # in cache_dir(): held while a kernel's index and data files are written


class _OneSaveAtATime(caching.IndexDataCacheFile):
    """numba's index and data files of one kernel, saved by one process at a time. numba's save reads the index,
    takes the first data file name it does not list and writes both: two processes saving two signatures of one
    kernel at once (two renders compiling, the parallel precompile) could take the same name, and the index would
    then file one signature's machine code under the other's. Under the cache folder's lock (SAVE_LOCK_NAME) each
    save reads the index the other one wrote. Loads take no lock: numba replaces each file whole."""

    def save(self, key, data):
        with file_lock(os.path.join(self._cache_path, SAVE_LOCK_NAME)):
            super().save(key, data)


def _save_under_lock(cache) -> None:
    """A Monte kernel's numba cache (FunctionCache) made to save under its folder's lock (_OneSaveAtATime)."""
    if type(getattr(cache, "_cache_file", None)) is caching.IndexDataCacheFile:
        cache._cache_file.__class__ = _OneSaveAtATime


# numba's code read for _defer_kernel_caches (names its functions use).
_ENABLE_CACHING_NAMES = frozenset({"FunctionCache", "_cache", "py_func"})
_CACHE_INIT_NAMES = frozenset({"_impl", "_impl_class", "locator", "get_source_stamp", "IndexDataCacheFile",
                               "_cache_file", "_cache_path", "get_cache_path", "filename_base", "enable"})


def _kernel_caches_deferrable() -> bool:
    """Whether numba is as read for _defer_kernel_caches: numba 0.59-0.68 (_CACHE_LOAD_NUMBA_VERSIONS), its
    Dispatcher.enable_caching making a FunctionCache of the function, the cache taking its locator's stamp into
    its index file's `_source_stamp`, Monte's locator among numba's, and MONTE_PLAIN_NUMBA_LOADS unset."""
    from numba.core import dispatcher

    if not _numba_patchable():
        return False
    if "_PerImportNameLocator" not in globals() or _PerImportNameLocator not in _CacheImpl._locator_classes:
        return False
    enable = getattr(getattr(dispatcher, "Dispatcher", None), "__dict__", {}).get("enable_caching")
    cache_init = getattr(getattr(caching, "Cache", None), "__dict__", {}).get("__init__")
    index_init = getattr(getattr(caching, "IndexDataCacheFile", None), "__dict__", {}).get("__init__")
    return (getattr(enable, "__code__", None) is not None
            and frozenset(enable.__code__.co_names) == _ENABLE_CACHING_NAMES
            and getattr(dispatcher, "FunctionCache", None) is caching.FunctionCache
            and getattr(cache_init, "__code__", None) is not None
            and _CACHE_INIT_NAMES <= frozenset(cache_init.__code__.co_names)
            and "_source_stamp" in getattr(getattr(index_init, "__code__", None), "co_names", ()))


KERNEL_CACHES_DEFERRED = _kernel_caches_deferrable()


_SIGNATURE_CHECKED: list = []  # [True] once _signature agreed with inspect.signature, [False] if it did not


def _signature(func):
    """inspect.signature(func) for a plain function of positional-or-keyword parameters (every kernel's), built
    from its code object, defaults and annotations without inspect's per-parameter checks (the kind's enum
    lookup, the name's checks): ~6 us against ~25 us per kernel, 0.002 s against 0.008-0.01 s for the ~350 of
    an import. Any other shape of function (keyword-only or positional-only parameters, *args, **kwargs), a
    Parameter of another layout, a wrapper (`__wrapped__`: inspect follows it), or a first result that differs
    from inspect's goes to inspect.signature."""
    import inspect

    code = func.__code__
    if (_SIGNATURE_CHECKED == [False] or code.co_kwonlyargcount or code.co_posonlyargcount
            or "__wrapped__" in func.__dict__
            or code.co_flags & (inspect.CO_VARARGS | inspect.CO_VARKEYWORDS)
            or getattr(inspect.Parameter, "__slots__", None) != ("_name", "_kind", "_default", "_annotation")):
        return inspect.signature(func)
    empty, kind = inspect.Parameter.empty, inspect.Parameter.POSITIONAL_OR_KEYWORD
    names = code.co_varnames[:code.co_argcount]
    annotations = func.__annotations__
    defaults = func.__defaults__ or ()
    first_default = len(names) - len(defaults)
    parameters = []
    for i, name in enumerate(names):
        parameter = object.__new__(inspect.Parameter)
        parameter._name, parameter._kind = name, kind
        parameter._default = defaults[i - first_default] if i >= first_default else empty
        parameter._annotation = annotations.get(name, empty)
        parameters.append(parameter)
    signature = inspect.Signature(parameters, return_annotation=annotations.get("return", empty),
                                  __validate_parameters__=False)
    if not _SIGNATURE_CHECKED:  # the first kernel of the process: the same as inspect's, or inspect's from now
        _SIGNATURE_CHECKED.append(signature == inspect.signature(func))  # (names, kinds, defaults, annotations)
        if not _SIGNATURE_CHECKED[0]:
            return inspect.signature(func)
    return signature


_KERNEL_FILES: dict[str, bool] = {}  # (a function's file) -> whether Monte's locator caches its functions


def _is_kernel_file(path: str) -> bool:
    """Whether functions of the file `path` are cached by Monte's locator (_PerImportNameLocator.from_function:
    an existing file of core/ or of a package of it); asked once per file and process."""
    known = _KERNEL_FILES.get(path)
    if known is None:
        folder = os.path.dirname(os.path.abspath(path))
        known = _KERNEL_FILES[path] = ((folder == _CORE_DIR or os.path.dirname(folder) == _CORE_DIR)
                                       and os.path.exists(path))
    return known


def _saving_one_at_a_time(dispatcher):
    """dispatcher, its numba cache made now (the first kernel of a process: it finds the cache folder writable)
    saving under the folder's lock as a deferred one does (_OneSaveAtATime), where the deferral applies at all
    (KERNEL_CACHES_DEFERRED) and the cache is Monte's."""
    cache = dispatcher.__dict__.get("_cache")
    locator = getattr(getattr(cache, "_impl", None), "locator", None)
    if KERNEL_CACHES_DEFERRED and type(locator) is _PerImportNameLocator:
        _save_under_lock(cache)
    return dispatcher


def _defer_kernel_caches(**options):
    """A decorator defining a cached kernel as numba.njit(**options) does, with two pieces of numba's work per
    kernel left to when they are needed (every process defines ~350 kernels at import; a 1-spp render calls
    ~15):

    - the kernel's disk cache (numba's FunctionCache: its locator search, file checks and index names) is made
      on first use (_CacheOnUse), its stamp taken now;
    - the function's signature is taken once, not twice (numba takes it for the dispatcher and again for the
      dispatcher's compiler), and built from the code object (_signature): it is kept as the function's
      `__signature__`, which inspect.signature returns as it is (the same parameters, names and defaults).

    Together ~0.02 s of CPU of every process's import (numbers in docs/performance.md, "round eleven"). Only
    where numba is as read (_kernel_caches_deferrable), for functions Monte's locator caches (defined in core/
    or a package of it, the cache folder found writable by an earlier kernel of the process) and with numba's
    cache folder settings unset (NUMBA_CACHE_DIR, NUMBA_CACHE_LOCATOR_CLASSES); otherwise, and with
    MONTE_PLAIN_NUMBA_LOADS=1, numba's own decorator (the cache made at once)."""
    from numba.core import config

    plain = numba.njit(**options)
    uncached = numba.njit(**{key: value for key, value in options.items() if key != "cache"})

    def decorate(func):
        code = getattr(func, "__code__", None)
        if (not KERNEL_CACHES_DEFERRED or not options.get("cache") or code is None or config.DISABLE_JIT
                or config.CACHE_DIR or getattr(config, "CACHE_LOCATOR_CLASSES", "")
                or cache_dir() not in _WRITABLE or "__signature__" in getattr(func, "__dict__", {})):
            return _saving_one_at_a_time(plain(func))
        if not _is_kernel_file(code.co_filename):
            return plain(func)
        func.__signature__ = _signature(func)
        stamp = _kernel_source_stamp(code.co_filename, getattr(func, "__module__", None))
        dispatcher = uncached(func)
        dispatcher._cache = _CacheOnUse(dispatcher, stamp)
        return dispatcher

    decorate.__doc__ = f"numba.njit({', '.join(f'{k}={v!r}' for k, v in options.items())}), its cache made on use"
    return decorate


jit = _defer_kernel_caches(**_OPTIONS)
jit_no_nrt = _defer_kernel_caches(**_OPTIONS, _nrt=False)
jit_inline = _defer_kernel_caches(**_OPTIONS, _nrt=False, inline="always")

# Modules of this folder that define cached kernels (their cache index files are named after them).
KERNEL_MODULES = ("geometry_kernels", "path_kernels", "mesh_checks", "camera", "sampling", "warps", "bsdf_kernels",
                  "world_kernels", "light_kernels", "embree", "shading/regs", "shading/evaluator",
                  "shading/procedural", "shading/color", "ray_visibility", "film_kernels", "fused_path")


# Kernel modules whose kernels run only for scenes that use their feature (an environment-map world, ray
# visibility, node programs, a lens or panoramic camera: a pinhole camera's rays are made inside the fused path
# kernel): the precompiled cache holds them (core.precompile renders such a scene), but one filled by renders
# alone (or by `make render`'s shipped kernels) may not; every render runs the others, so those decide whether a
# cache is cold.
FEATURE_KERNEL_MODULES = ("world_kernels", "ray_visibility", "shading/regs", "shading/evaluator", "fused_path",
                          "shading/procedural", "shading/color", "camera")


def compile_cache_is_cold(with_node_programs: bool = False) -> bool:
    """True when some kernel module has no numba cache index yet for this import of the package (first render
    after an install or an update of the sources): that render compiles the kernels first, about a minute on a
    2-core machine. The node-program evaluator (core/shading/) compiles only for scenes with node programs:
    counted when `with_node_programs`. Once warm, it stays so for the process (no need to list the folder on
    every render)."""
    if _cache_warm[with_node_programs]:
        return False
    try:  # one listing of the folder (hundreds of files), not one glob per module: ~0.1 s off a first render
        indexes = {entry.split(".", 1)[0] for entry in os.listdir(cache_dir()) if entry.endswith(".nbi")}
    except OSError:
        indexes = set()
    cold = any(os.path.basename(name) not in indexes
               for name in KERNEL_MODULES if name not in FEATURE_KERNEL_MODULES
               or (with_node_programs and name.startswith("shading/")))
    _cache_warm[with_node_programs] = not cold
    if not cold and with_node_programs:
        _cache_warm[False] = True
    return cold


_cache_warm = {False: False, True: False}


def _is_cached_monte_kernel(dispatcher) -> bool:
    """Whether a numba dispatcher is one of Monte's kernels with a disk cache (a compile of it is a cache miss
    that the next process will not repeat), not one of its uncached helpers or another package's function."""
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", None) or ""
    if not module.startswith(_PACKAGE_PREFIX):
        return False
    return not isinstance(dispatcher.__dict__.get("_cache"), (type(None), caching.NullCache))


_PACKAGE_PREFIX = __name__.rsplit(".", 2)[0] + "."  # "monte." (or "bl_ext.<repository>.monte.")


class _CompileNotices(numba_events.Listener):
    """numba's "numba:compile" events relayed to the render calls under way, each told once. numba fires the event
    only when a signature is compiled because no cache entry held it, on the thread that compiles (a render's
    worker). compile_cache_is_cold sees only whether a kernel module has any cache index: a scene whose kernels the
    cache lacks in a cache that is not cold (a built-in scene other than the Cornell box after `make render`'s
    shipped kernels, a feature no earlier render used) compiled silently for ~10 s before its first progress."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._waiting: list[Callable[[str], None]] = []

    def wait(self, say: Callable[[str], None]) -> None:
        with self._lock:
            self._waiting.append(say)

    def done(self, say: Callable[[str], None]) -> None:
        with self._lock:
            if say in self._waiting:
                self._waiting.remove(say)

    def on_start(self, event) -> None:
        if not self._waiting:
            return
        dispatcher = (event.data or {}).get("dispatcher")
        if not _is_cached_monte_kernel(dispatcher):
            return
        with self._lock:
            waiting, self._waiting = self._waiting, []
        name = f"{dispatcher.py_func.__module__.rsplit('.', 1)[-1]}.{dispatcher.py_func.__name__}"
        for say in waiting:
            try:
                say(f"compiling the render kernels this scene needs that the kernel cache does not hold yet "
                    f"({name} first; once, cached after)")
            except Exception:  # a notice must not fail the compile it announces (numba holds its lock here)
                pass

    def on_end(self, event) -> None:
        pass


_COMPILE_NOTICES = _CompileNotices()
numba_events.register("numba:compile", _COMPILE_NOTICES)  # (returns at once while no render waits)


@contextlib.contextmanager
def compile_notices(say: Callable[[str], None] | None):
    """While the block runs, the first compile of a cached Monte kernel (on any thread) calls `say` once with a
    line naming it; None does nothing. say must be callable from a worker thread."""
    if say is None:
        yield
        return
    _COMPILE_NOTICES.wait(say)
    try:
        yield
    finally:
        _COMPILE_NOTICES.done(say)
