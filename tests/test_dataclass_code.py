"""Monte's dataclasses' generated methods served compiled from core.dataclass_code's table: the same classes as
`dataclasses` compiles itself, the table ignored when damaged or another Python's, never written where Python
writes no bytecode, and other modules' dataclasses untouched. The time it saves is measured in
docs/performance.md, never asserted here."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

from monte.core import dataclass_code

# Imports the renderer and its scene and settings modules, then prints each Monte dataclass's generated methods
# (the code objects' every field, nested functions included) and a settings object's repr and equality.
_PROBE = """
    import json, sys, types
    from monte.core import dataclass_code
    dataclass_code._FILE = sys.argv[1]
    import dataclasses
    import monte.core.render, monte.core.settings, monte.core.builtin_scenes

    def const_print(c):  # (a frozenset's order follows the process's string hashes)
        if isinstance(c, types.CodeType):
            return code_print(c)
        return repr(sorted(c)) if isinstance(c, frozenset) else repr(c)

    def code_print(code):
        return [code.co_code.hex(), code.co_names, code.co_varnames, code.co_freevars, code.co_cellvars,
                code.co_flags, code.co_argcount, code.co_kwonlyargcount, code.co_filename, code.co_name,
                [const_print(c) for c in code.co_consts]]

    classes = {}
    for name, module in sorted(sys.modules.items()):
        if not name.startswith("monte."):
            continue
        for cls in vars(module).values():
            if isinstance(cls, type) and dataclasses.is_dataclass(cls) and cls.__module__ == name:
                methods = {m: code_print(f.__code__) for m, f in sorted(vars(cls).items())
                           if isinstance(f, types.FunctionType) and f.__code__.co_filename == "<string>"}
                classes[f"{name}.{cls.__qualname__}"] = methods
    settings = monte.core.settings.RenderSettings(spp=3)
    print("RESULT " + json.dumps({"classes": classes, "stats": dataclass_code.stats(),
                                  "write_failures": len(dataclass_code._unwritable),
                                  "installed": vars(dataclasses).get("exec") is dataclass_code._exec,
                                  "repr": repr(settings), "eq": settings == monte.core.settings.RenderSettings(spp=3)},
                                 default=repr))
"""


def _probe(table, **env) -> dict:
    clean = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", dataclass_code.PLAIN_ENV)}
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(_PROBE), str(table)], capture_output=True,
                          text=True, timeout=600, env={**clean, **env})
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return json.loads(lines[-1][len("RESULT "):])


def test_the_table_gives_the_classes_dataclasses_compiles_itself(tmp_path):
    table = tmp_path / "dataclass-code.bin"
    plain = _probe(table, **{dataclass_code.PLAIN_ENV: "1"})
    assert not plain["installed"] and plain["stats"] == {"hits": 0, "compiled": 0, "written": 0}
    assert not table.exists()
    first = _probe(table)  # compiles each text once and writes the table
    assert first["installed"]
    assert first["stats"]["hits"] == 0 and first["stats"]["compiled"] >= 20 and first["stats"]["written"] >= 1
    assert table.read_bytes().startswith(dataclass_code._HEADER)
    served = _probe(table)  # every text from the table: nothing compiled, nothing written
    assert served["stats"] == {"hits": first["stats"]["compiled"], "compiled": 0, "written": 0}
    assert len(plain["classes"]) >= 20 and all(plain["classes"].values())
    assert served["classes"] == plain["classes"] == first["classes"]
    assert served["repr"] == plain["repr"] and served["eq"] is plain["eq"] is True


def test_a_damaged_or_another_pythons_table_is_ignored_and_rewritten(tmp_path):
    table = tmp_path / "dataclass-code.bin"
    compiled = _probe(table)["stats"]["compiled"]
    good = table.read_bytes()
    for bad in (good[:len(good) // 2],  # cut short
                b"\x00" * 64,  # not a table
                b"\x01\x02\r\n" + good[4:],  # another interpreter's magic number
                dataclass_code._HEADER + b"\xff\xfe garbage"):  # the header, then no marshal data
        table.write_bytes(bad)
        assert _probe(table)["stats"] == {"hits": 0, "compiled": compiled, "written": compiled}
        assert table.read_bytes().startswith(dataclass_code._HEADER)
        assert _probe(table)["stats"]["hits"] == compiled


def test_no_table_is_written_where_python_writes_no_bytecode(tmp_path):
    table = tmp_path / "dataclass-code.bin"
    result = _probe(table, PYTHONDONTWRITEBYTECODE="1")  # as the extension build runs
    assert result["installed"] and result["stats"]["compiled"] >= 20 and result["stats"]["written"] == 0
    assert not table.exists()
    assert not list(tmp_path.iterdir())  # no temporary file left either


def test_other_modules_dataclasses_are_left_to_dataclasses():
    before = dataclass_code.stats()

    @dataclasses.dataclass(frozen=True)
    class NotMonte:
        x: int = 1
        y: tuple = ()

    assert dataclass_code.stats() == before
    assert NotMonte(2) == NotMonte(2) and repr(NotMonte(2)) == "test_other_modules_dataclasses_are_left_to_" \
        "dataclasses.<locals>.NotMonte(x=2, y=())"


def test_only_monte_packages_are_served():
    ours = dataclass_code._ours
    root = dataclass_code._ROOT
    assert ours({"__name__": root}) and ours({"__name__": root + ".core.settings"})
    assert not ours({"__name__": root + "x.core"}) and not ours({"__name__": "numba.core"})
    assert not ours({}) and not ours(None) and not ours({"__name__": 3})


def test_a_table_that_cannot_be_written_is_tried_once(tmp_path):
    folder = tmp_path / "not-a-folder"
    folder.write_text("a file where the table's folder would be")
    result = _probe(folder / "dataclass-code.bin")  # every write fails: compiled as without the table
    assert result["installed"] and result["stats"]["compiled"] >= 20 and result["stats"]["written"] == 0
    assert result["write_failures"] == 1  # the first failure stops the process's further tries
    assert result["eq"] is True
