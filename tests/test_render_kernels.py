"""The Cornell box's compiled kernels shipped in kernels/render-set.tar.xz (tools/render_kernels.py), which the first
`make render` after a clone loads instead of compiling: the archive is for these sources, a render from it alone
compiles nothing, and unpacking never replaces a kernel the cache already has."""

from __future__ import annotations

import importlib.util
import io
import os
import pickle
import tarfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("render_kernels", ROOT / "tools" / "render_kernels.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _listing(folder: str) -> dict[str, tuple[int, int]]:
    return {entry.name: (entry.stat().st_size, entry.stat().st_mtime_ns) for entry in os.scandir(folder)}


def test_the_shipped_kernels_are_for_these_sources(tool):
    """Fails after an edit of a kernel module (or a new numba pin) until `make render-kernels` rebuilds the
    archive: the first `make render` would compile again, silently. (Skipped on a machine that cannot build it:
    CI's can.)"""
    manifest = tool.read_manifest()
    key = tool.environment_key()
    assert tool.machine_of(manifest["key"]) == tool.SHIPPED_FOR
    if tool.machine_of(key) != tool.SHIPPED_FOR:
        pytest.skip(f"the archive is built on {tool.SHIPPED_FOR}; this machine is not one")
    wrong = tool.mismatches(manifest, key, ignore=tool.MACHINE_KEYS)
    assert not wrong, "kernels/render-set.tar.xz is stale (rebuild it: make render-kernels): " + "; ".join(wrong)
    # so `make render-kernels` leaves it as it is (a rebuild gives other bytes: symbol numbers, the build folder)
    before = (tool.ARCHIVE.stat().st_mtime_ns, tool.ARCHIVE.read_bytes())
    assert tool.build() == 0
    assert (tool.ARCHIVE.stat().st_mtime_ns, tool.ARCHIVE.read_bytes()) == before
    assert manifest["command"] == ["monte", "render", "cornell", "--spp", "64"]
    makefile = (ROOT / "Makefile").read_text()
    assert "SPP ?= 64" in makefile and "$(BIN)/python -m monte render cornell -o cornell.exr --spp $(SPP)" in makefile


def test_a_first_render_from_the_shipped_kernels_compiles_nothing(tool, tmp_path):
    """make render's command, run on a copy of the package whose kernel cache holds only the archive's files,
    saves nothing into the cache (every kernel signature and numba's runtime module came from the archive) and
    does not say that it compiles."""
    tool.copy_package(tmp_path)
    key = tool.environment_key(str(tmp_path))
    manifest = tool.read_manifest()
    wrong = tool.mismatches(manifest, key)
    if any(line.startswith(("kernel_cpu", "platform")) for line in wrong):
        pytest.skip(f"the shipped kernels are for another machine: {'; '.join(wrong)}")
    assert not wrong
    cache_dir = key["cache_dir"]
    assert not os.path.exists(cache_dir)
    assert tool.unpack_into(cache_dir) == (manifest["files"], 0, 0)
    before = _listing(cache_dir)
    proc = tool.render_in(str(tmp_path), str(tmp_path))
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert (tmp_path / "cornell.exr").stat().st_size > 0
    assert "wrote " in proc.stdout and "compiling the render kernels" not in proc.stdout + proc.stderr
    after = _listing(cache_dir)
    assert after == before, f"compiled and saved: {sorted(set(after.items()) - set(before.items()))}"


def test_unpacking_keeps_a_kernel_cached_for_these_sources_and_replaces_a_stale_one(tool, tmp_path):
    with tarfile.open(tool.ARCHIVE, "r:xz") as tar:
        shipped = {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.name != tool.MANIFEST_NAME}

    def files_of(word: str) -> tuple[dict[str, bytes], str]:
        """A kernel's shipped files and the name of its index."""
        index = next(name for name in shipped if word in name and name.endswith(".nbi"))
        return {name: data for name, data in shipped.items() if tool._kernel_of(name) == tool._kernel_of(index)}, index

    current, current_index = files_of(".trace_paths-")
    stale, stale_index = files_of(".albedo_batch-")
    unreadable, unreadable_index = files_of(".add_colour-")
    other_numba, other_numba_index = files_of(".gather_batch-")
    version = pickle.load(io.BytesIO(current[current_index]))
    cache = tmp_path / "cache"
    cache.mkdir()
    # the cache's own for these sources, with one more signature: kept whole
    (cache / current_index).write_bytes(current[current_index])
    extra = current_index.replace(".nbi", ".7.nbc")
    (cache / extra).write_bytes(b"another signature")
    # saved for other sources, with a data file the archive does not have: replaced, that file removed
    (cache / stale_index).write_bytes(pickle.dumps(version) + pickle.dumps((("edited since",), {})))
    old_data = stale_index.replace(".nbi", ".9.nbc")
    (cache / old_data).write_bytes(b"stale")
    # an index numba could not read either, and one saved by another numba (its rest not readable here): replaced
    (cache / unreadable_index).write_bytes(b"not a pickle")
    (cache / other_numba_index).write_bytes(pickle.dumps("0.1.0") + b"another numba's format")
    # the same kernel cached for another Python does not count
    other_python = stale_index.replace(".py313.", ".py311.")
    (cache / other_python).write_bytes(b"Python 3.11's")
    (cache / "save.lock").write_bytes(b"")

    written, replaced, kept = tool.unpack_into(str(cache))
    assert kept == len(current)
    assert replaced == len(stale) + len(unreadable) + len(other_numba)
    assert written == len(shipped) - kept
    for name, data in {**stale, **unreadable, **other_numba}.items():
        assert (cache / name).read_bytes() == data
    assert not (cache / old_data).exists()
    assert (cache / extra).read_bytes() == b"another signature"
    assert (cache / other_python).read_bytes() == b"Python 3.11's"
    assert sorted(os.listdir(cache)) == sorted({*shipped} - {*current} | {current_index, extra, other_python,
                                                                            "save.lock"})
    assert tool.unpack_into(str(cache)) == (0, 0, len(shipped))  # a second unpack writes nothing


def test_a_stale_archive_is_named_with_what_differs(tool, tmp_path):
    manifest = tool.read_manifest()
    key = {**manifest["key"], "cache_dir": "/x"}
    assert tool.mismatches(manifest, key) == []
    edited = {**key, "sources": "0" * 64, "kernel_cpu": "generic"}
    assert sorted(tool.mismatches(manifest, edited)) == [
        f"kernel_cpu: shipped for {manifest['key']['kernel_cpu']!r}, here 'generic'",
        f"sources: shipped for {manifest['key']['sources']!r}, here {'0' * 64!r}"]
    assert tool.mismatches(manifest, edited, ignore=tool.MACHINE_KEYS) == [
        f"sources: shipped for {manifest['key']['sources']!r}, here {'0' * 64!r}"]
    assert tool.mismatches({**manifest, "format": 99}, key) == ["archive format 99, this tool reads 1"]
    with tarfile.open(tool.ARCHIVE, "r:xz") as tar:
        assert manifest["files"] == len(tar.getnames()) - 1
