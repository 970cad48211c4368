"""The precompile's worker processes (core/precompile.py) and what makes them safe: a file lock between processes
(core.jit_cache.file_lock), numba's index saved by one process at a time (jit_cache._OneSaveAtATime), and a kernel
signature compiled by one process while another that needs it waits and loads it
(precompile._compiles_one_process_at_a_time)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from monte.core import jit_cache, precompile

sys.path.insert(0, str(Path(__file__).resolve().parent))
from throwaway_kernels import (child_result as _result, python_child as _start,  # noqa: E402
                              throwaway_kernel_module)

MODULE = "_test_parallel_precompile_kernel"  # a throwaway kernel module in core/ (Monte's locator caches only there)


@pytest.mark.skipif(os.name == "nt", reason="checks the lock with fcntl")
def test_file_lock_holds_off_other_processes_until_released_or_the_holder_dies(tmp_path):
    """While another process holds the lock, taking it without waiting fails here; once that process is killed
    (no clean-up of its own), the operating system has dropped it and it can be taken."""
    import fcntl

    path = tmp_path / "held.lock"
    holder = _start(f"""
        import sys
        from monte.core.jit_cache import file_lock
        with file_lock({str(path)!r}) as locked:
            print("HELD", locked, flush=True)
            sys.stdin.readline()  # until the test kills it
    """)
    try:
        assert holder.stdout.readline().split() == ["HELD", "True"]
        fd = os.open(path, os.O_RDWR)
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            holder.kill()
            holder.wait(timeout=60)
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # dropped with its process
        finally:
            os.close(fd)
    finally:
        if holder.poll() is None:
            holder.kill()
        holder.communicate()


def test_file_lock_runs_the_block_unlocked_where_the_file_cannot_be_made(tmp_path):
    ran = []
    with jit_cache.file_lock(str(tmp_path / "no such folder" / "x.lock")) as locked:
        ran.append(locked)
    assert ran == [False]


SAVER = """
    import os, sys, time
    from monte.core import jit_cache
    folder, worker, count, go = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    index = jit_cache._OneSaveAtATime(folder, "kernel", ("stamp",))
    while not os.path.exists(go):  # both start saving together
        time.sleep(0.001)
    for i in range(count):
        index.save((f"signature {worker}-{i}", "cpu"), (worker, i))
    print("RESULT {}")
"""


def test_saves_from_two_processes_keep_every_signature_with_its_own_code(tmp_path):
    """Two processes save 60 signatures each into one kernel's index at once: every signature is listed, each in
    its own data file, and each loads what was saved for it (numba's unlocked save let two processes take the
    same data file name, one signature's entry then loading the other's code)."""
    go, count = tmp_path / "go", 60
    procs = [subprocess.Popen([sys.executable, "-c", textwrap.dedent(SAVER), str(tmp_path), str(w), str(count),
                               str(go)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for w in range(2)]
    go.touch()
    for proc in procs:
        _result(proc)
    index = jit_cache._OneSaveAtATime(str(tmp_path), "kernel", ("stamp",))
    overloads = index._load_index()
    assert sorted(overloads) == sorted((f"signature {w}-{i}", "cpu") for w in range(2) for i in range(count))
    assert len(set(overloads.values())) == 2 * count
    for (name, _), data_name in overloads.items():
        worker, i = name.split()[1].split("-")
        assert index._load_data(data_name) == (int(worker), int(i))
    assert (tmp_path / jit_cache.SAVE_LOCK_NAME).exists()


def test_a_monte_kernels_cache_saves_under_the_lock():
    from monte.core import sampling

    kernel = next(d for d in precompile._dispatchers() if d.py_func.__module__ == sampling.__name__)
    if not jit_cache.KERNEL_CACHES_DEFERRED:
        pytest.skip("numba's own caches (MONTE_PLAIN_NUMBA_LOADS or an unread numba)")
    assert type(kernel._cache._cache_file) is jit_cache._OneSaveAtATime


KERNELS = """
import numpy as np

from .jit_cache import jit, jit_inline


@jit_inline
def _term(x, k):
    s = 0.0
    for j in range(k):
        s += np.sin(x * j) / (1.0 + j)
    return s


@jit
def weighted(values, k):
    total = 0.0
    for v in values:
        total += _term(v, k) + np.cos(v) * np.exp(-v * v)
    return total
"""

COMPILER = f"""
    import os, sys, time
    import numpy as np
    from monte.core import precompile
    from monte.core import {MODULE} as mod
    lock_dir, go = sys.argv[1], sys.argv[2]
    with precompile._compiles_one_process_at_a_time(lock_dir):
        while not os.path.exists(go):  # both ask for the signature together
            time.sleep(0.001)
        value = float(mod.weighted(np.linspace(0.0, 1.0, 5), 3))
    stats = mod.weighted.stats
    print("RESULT " + json.dumps({{"value": value, "compiled": sum(stats.cache_misses.values()),
                                  "loaded": sum(stats.cache_hits.values())}}))
"""


@pytest.fixture
def kernel_module():
    with throwaway_kernel_module(MODULE, KERNELS) as path:
        yield path


def test_two_processes_needing_one_new_signature_compile_it_once(kernel_module, tmp_path):
    """Two processes call a kernel whose signature no cache holds, at the same moment, coordinated as the
    precompile's workers are: one compiles it, the other waits, then loads the first one's result from the
    disk cache; both compute the same."""
    import numpy as np

    go = tmp_path / "go"
    code = "import json\n" + textwrap.dedent(COMPILER)
    procs = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path), str(go)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    go.touch()
    results = [_result(proc) for proc in procs]
    assert sorted((r["compiled"], r["loaded"]) for r in results) == [(0, 1), (1, 0)]
    x = np.linspace(0.0, 1.0, 5)
    expected = sum(sum(np.sin(v * j) / (1.0 + j) for j in range(3)) + np.cos(v) * np.exp(-v * v) for v in x)
    for r in results:
        assert r["value"] == pytest.approx(expected, rel=1e-12)
    assert list(tmp_path.glob("*.lock"))  # the signature's lock file


def test_the_workers_start_the_two_largest_compiles_first():
    """The parallel order puts the fused path kernel's two kinds (its node-program case and a built-in scene
    without node programs) first, so two workers take one each; every task is in it once."""
    tasks = precompile._tasks()
    order = [name for name, _ in precompile._parallel_order(tasks)]
    assert order[:2] == ["node programs in the fused kernel", "cornell"]
    assert sorted(order) == sorted(name for name, _ in tasks) and len(set(order)) == len(order)


@pytest.mark.parametrize("value, expected", [("1", 1), ("3", 3), (" 2 ", 2), ("", None)])
def test_precompile_jobs_from_the_environment(monkeypatch, value, expected):
    if not jit_cache.KERNEL_CACHES_DEFERRED:
        pytest.skip("one process where numba's saves are not locked")
    monkeypatch.setenv(precompile.JOBS_ENV, value)
    default = max(1, min(os.cpu_count() or 1, 2))
    assert precompile.precompile_jobs() == (default if expected is None else expected)


@pytest.mark.parametrize("value, message", [("two", "is not a whole number of processes"),
                                            ("0", "must be at least 1")])
def test_precompile_jobs_refuses_a_bad_value(monkeypatch, value, message):
    if not jit_cache.KERNEL_CACHES_DEFERRED:
        pytest.skip("one process where numba's saves are not locked")
    monkeypatch.setenv(precompile.JOBS_ENV, value)
    with pytest.raises(SystemExit, match=f"MONTE_PRECOMPILE_JOBS='{value}' {message}"):
        precompile.precompile_jobs()


def test_the_precompile_in_two_workers_runs_each_task_once_and_lists_the_entries():
    """`python -m monte.core.precompile` with 2 workers on the built cache: every task runs in exactly one worker,
    nothing compiles (all loaded), and the entry-kernel list is written by the listing process, the same list."""
    if not jit_cache.KERNEL_CACHES_DEFERRED:
        pytest.skip("one process where numba's saves are not locked")
    before = precompile.read_entry_kernels()
    proc = _start("import runpy; runpy.run_module('monte.core.precompile', run_name='__main__')",
                  **{precompile.JOBS_ENV: "2"})
    out, err = proc.communicate(timeout=900)
    assert proc.returncode == 0, f"{out[-3000:]}\n{err[-3000:]}"
    ran = [line.strip().rsplit(" (worker ", 1)[0] for line in out.splitlines() if " (worker " in line]
    assert sorted(ran) == sorted(name for name, _ in precompile._tasks())
    assert "in 2 processes" in out and "Monte: 0 kernel signatures compiled" in out and "by 2 processes" in out
    assert precompile.read_entry_kernels() == before and before
