"""A throwaway kernel module in core/ for tests of the kernel cache (Monte's locator caches only functions defined
there): written for the test, removed afterwards with its cache entries and bytecode."""

from __future__ import annotations

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
