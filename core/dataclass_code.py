"""The methods that `dataclasses` generates for Monte's dataclasses, compiled once and kept beside the bytecode.

Defining a dataclass compiles the source text of its generated methods (`__init__`, `__repr__`, `__eq__`, ...)
in every process: Python's bytecode cache holds the module, not the text `dataclasses` builds and `exec`s at
class creation. A render process defines ~64 of Monte's, ~0.5 ms each, nearly all of it in `compile`: ~0.03 s
of every `monte render` process and of every Blender session's first render (docs/performance.md, "round
eleven"). `install()` gives the `dataclasses` module an `exec` that, for classes of Monte's own modules, runs
the code compiled from the same text by an earlier process (a text-keyed table in
`core/__pycache__/dataclass-code.<cache tag>.bin`); the code is what `exec` itself compiles from that text (same
file name, no inherited `__future__` flags, the interpreter's optimisation level), so the classes are the same.
Other modules' dataclasses, and any text not in the table, go to `exec` as before; a text first seen is compiled,
run and added to the table, which is written unless Python writes no bytecode (PYTHONDONTWRITEBYTECODE, as the
extension build sets). A table written by another Python or damaged is ignored and rewritten.
`MONTE_PLAIN_DATACLASSES=1` leaves `dataclasses` alone."""

from __future__ import annotations

import builtins
import importlib.util
import marshal
import os
import sys
import threading
import types

PLAIN_ENV = "MONTE_PLAIN_DATACLASSES"
# The package whose classes are served: "monte", or "bl_ext.user_default.monte" as Blender imports the extension.
_ROOT = __name__.rsplit(".", 2)[0]
_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__",
                     f"dataclass-code.{sys.implementation.cache_tag}.bin")
# The file's first bytes: this interpreter's bytecode magic, the table's layout, the optimisation level.
_HEADER = importlib.util.MAGIC_NUMBER + b"monte-dataclass-code-1/" + str(sys.flags.optimize).encode() + b"\n"
MAX_ENTRIES = 512  # texts kept; past it the oldest go (each edit of a dataclass adds a text)

_lock = threading.Lock()
_table: dict[str, object] | None = None  # text -> code, read on first use
_stats = {"hits": 0, "compiled": 0, "written": 0}
_unwritable: list[bool] = []  # [True] once writing the table failed in this process


def _ours(globals_: object) -> bool:
    name = globals_.get("__name__", "") if isinstance(globals_, dict) else ""
    return isinstance(name, str) and (name == _ROOT or name.startswith(_ROOT + "."))


def _read() -> dict[str, object]:
    try:
        with open(_FILE, "rb") as f:
            data = f.read()
    except OSError:
        return {}
    if not data.startswith(_HEADER):
        return {}
    try:
        table = marshal.loads(data[len(_HEADER):])
    except (EOFError, ValueError, TypeError):
        return {}
    if not isinstance(table, dict):
        return {}
    return {k: v for k, v in table.items() if isinstance(k, str) and isinstance(v, types.CodeType)}


def _write(table: dict[str, object]) -> None:
    """The table, replacing the file whole (a reader sees the old file or the new one, never a part)."""
    if sys.dont_write_bytecode or _unwritable:
        return
    tmp = f"{_FILE}.{os.getpid()}.{threading.get_ident()}.tmp"
    try:
        os.makedirs(os.path.dirname(_FILE), exist_ok=True)
        with open(tmp, "wb") as f:
            f.write(_HEADER + marshal.dumps(table))
        os.replace(tmp, _FILE)
        _stats["written"] += 1
    except OSError:  # a read-only install: the classes are compiled each time, as without the table
        _unwritable.append(True)  # (not tried again in this process)
        try:
            os.remove(tmp)
        except OSError:
            pass


def _code_for(text: str):
    global _table
    with _lock:
        if _table is None:
            _table = _read()
        code = _table.get(text)
        if code is not None:
            _stats["hits"] += 1
            return code
        # as exec(text) compiles it in dataclasses' frame: no __future__ flags there
        code = compile(text, "<string>", "exec", dont_inherit=True)
        _stats["compiled"] += 1
        _table[text] = code
        while len(_table) > MAX_ENTRIES:
            del _table[next(iter(_table))]
        _write(_table)
        return code


def _exec(source, globals_=None, locals_=None, /, **kwargs):
    """`exec` for the `dataclasses` module: Monte's classes' generated methods from the table."""
    if isinstance(source, str) and not kwargs and _ours(globals_):
        source = _code_for(source)
    return builtins.exec(source, globals_, locals_, **kwargs)


def _applies() -> bool:
    """Whether `dataclasses` is as read: it builds each class's methods with a bare `exec` of their text (Python
    3.10-3.14) and nothing has replaced that `exec` yet."""
    import dataclasses

    if os.environ.get(PLAIN_ENV, "").strip() not in ("", "0") or not (3, 10) <= sys.version_info[:2] <= (3, 14):
        return False
    if "exec" in vars(dataclasses):
        return vars(dataclasses)["exec"] is _exec
    builder = getattr(getattr(dataclasses, "_FuncBuilder", None), "add_fns_to_class", None)  # 3.13 and later
    creator = builder or getattr(dataclasses, "_create_fn", None)  # 3.10-3.12: one exec per method
    return "exec" in getattr(getattr(creator, "__code__", None), "co_names", ())


def install() -> bool:
    """Serve Monte's dataclasses' generated methods from the table from now on in this process; returns whether
    it is in place (see the module's docstring for when it is not)."""
    import dataclasses

    if not _applies():
        return False
    dataclasses.exec = _exec
    return True


def stats() -> dict[str, int]:
    """This process's counts: texts served from the table, compiled, and table writes."""
    return dict(_stats)
