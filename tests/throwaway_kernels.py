"""A throwaway kernel module in core/ for tests of the kernel cache (Monte's locator caches only functions defined
there): written for the test, removed afterwards with its cache entries and bytecode."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from monte.core import jit_cache

CORE = Path(jit_cache.__file__).parent


@contextmanager
def throwaway_kernel_module(name: str, source: str) -> Iterator[Path]:
    """core/<name>.py holding `source` while the block runs; then the file, its kernels' cache files and its
    bytecode are removed."""
    path = CORE / f"{name}.py"
    path.write_text(source)
    try:
        yield path
    finally:
        path.unlink()
        for entry in Path(jit_cache.cache_dir()).glob(f"{name}.*"):
            entry.unlink()
        for entry in (CORE / "__pycache__").glob(f"{name}.*.pyc"):
            entry.unlink()


def python_child(code: str, **env) -> subprocess.Popen:
    """`code` (dedented) started in a new Python with this environment less numba's and Monte's kernel variables
    (NUMBA_*, the kernel CPU, plain numba loads: the child compiles and loads as a user's process does), plus
    `env`; stdin, stdout and stderr piped, as text."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != jit_cache.KERNEL_CPU_ENV
             and k != jit_cache.PLAIN_NUMBA_LOADS_ENV}
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**clean, **env})


def child_result(proc: subprocess.Popen, timeout: float = 900) -> dict:
    """The JSON a python_child printed after its last "RESULT " once it exits; the test fails with the child's
    output when it exited non-zero or printed no result."""
    out, err = proc.communicate(timeout=timeout)
    lines = [ln for ln in out.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{out[-3000:]}\n{err[-3000:]}"
    return json.loads(lines[-1][len("RESULT "):])
