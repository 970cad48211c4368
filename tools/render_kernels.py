#!/usr/bin/env python3
"""The compiled kernels of `make render` (the Cornell box through `monte render`), shipped in the repository, so
that a fresh clone's first render loads them instead of compiling them (about 40 s on two cores).

    python tools/render_kernels.py unpack   # make render: put them into this checkout's kernel cache
    python tools/render_kernels.py check    # exit 1, saying why, when the archive is not for these sources
    python tools/render_kernels.py build    # after editing a kernel module: rebuild the archive (make render-kernels;
                                            # a no-op while it is up to date, --force rebuilds anyway)

kernels/render-set.tar.xz holds numba's cache files (the .nbi indexes and .nbc data) of every kernel signature
that `monte render cornell --spp 64` compiles, built in a copy of this checkout with an empty cache, and a
manifest: the sources' digest (core.jit_cache.sources_digest: the kernel modules' contents and the numba
options), the kernel CPU level, Python's, numba's and llvmlite's versions, the platform and the import name.
`unpack` copies them into the cache only where all of those match this checkout's (else it says why and the
first render compiles, as without the archive), and never over a kernel the cache has for these sources (which
may hold more signatures); a kernel cached for sources edited since is replaced, as numba's next save would. numba
checks each entry again when it loads it (its version, the CPU, the sources' stamp), so a file that does not
apply is recompiled, never run.

After an edit of a kernel module the archive no longer applies: tests/test_render_kernels.py fails until
`make render-kernels` rebuilds it.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import os
import pickle
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ARCHIVE = ROOT / "kernels" / "render-set.tar.xz"
MANIFEST_NAME = "manifest.json"
FORMAT = 1
# make render's command (its SPP's default), less the output path
RENDER_ARGS = ["render", "cornell", "--spp", "64"]
# numba's cache files: <module>.<qualname>-<line>.py<ver>.nbi (a kernel's index) and ...py<ver>.<n>.nbc (data);
# and Monte's cached NRT module (core.jit_cache: nrt-<key>.bin), which a process loads before its first kernel
_CACHE_FILE = re.compile(r"^(?:(?P<kernel>[\w.<>]+-\d+\.py\d+[a-z]*)(?:\.\d+\.nbc|\.nbi)|(?P<nrt>nrt-[0-9a-f]+\.bin))$")


def _kernel_of(name: str) -> str | None:
    """The kernel (with the Python it is cached for: one cache folder serves several) or the NRT module that a cache
    file belongs to, None for any other file."""
    match = _CACHE_FILE.match(name)
    return None if match is None else match.group("kernel") or match.group("nrt")


_KEY_CODE = """
import json, platform, sys
import llvmlite, numba
from monte.core import jit_cache
print(json.dumps({"sources": jit_cache.sources_digest(), "kernel_cpu": jit_cache.KERNEL_CPU,
                  "python": "%d.%d%s" % (*sys.version_info[:2], sys.abiflags), "numba": numba.__version__,
                  "llvmlite": llvmlite.__version__, "platform": sys.platform + "-" + platform.machine(),
                  "package": jit_cache.PACKAGE, "cache_dir": jit_cache.cache_dir()}))
"""


def environment_key(pythonpath: str | None = None, clean: bool = True) -> dict:
    """What a cached kernel is valid for, as `monte` imports here (or from `pythonpath`), with its cache folder
    ("cache_dir", not part of the key). Asked of a new interpreter, so that the kernel CPU level is chosen as a
    render process chooses it: by default with the machine's own level (`clean`: without the user's NUMBA_* and
    MONTE_KERNEL_CPU settings, as the archive is built), else as this environment's renders choose it."""
    env = _clean_environment(pythonpath) if clean else dict(os.environ)
    # -P: nothing from the working folder (a stray ./monte) comes before the package asked about
    proc = subprocess.run([sys.executable, "-P", "-c", _KEY_CODE], capture_output=True, text=True, env=env,
                          cwd=pythonpath or ROOT)
    if proc.returncode != 0:
        raise SystemExit(f"render_kernels: importing monte failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _clean_environment(pythonpath: str | None) -> dict:
    """This environment without the settings that would choose another kernel CPU or cache folder."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("NUMBA_") and k not in ("MONTE_KERNEL_CPU", "PYTHONDONTWRITEBYTECODE")}
    if pythonpath is not None:
        env["PYTHONPATH"] = pythonpath
    return env


def _atomic_file():
    """This checkout's core/atomic_file.py (the project's one writer of whole files; standard library only),
    loaded from its file: importing the package would run core's start-up and could find another checkout's."""
    spec = importlib.util.spec_from_file_location("_monte_atomic_file", ROOT / "core" / "atomic_file.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def read_manifest(archive: Path = ARCHIVE) -> dict:
    with tarfile.open(archive, "r:xz") as tar:
        member = tar.extractfile(MANIFEST_NAME)
        if member is None:
            raise SystemExit(f"render_kernels: {archive} has no {MANIFEST_NAME}")
        return json.load(member)


# What a machine is rather than what the checkout is: `check` leaves these out.
MACHINE_KEYS = ("kernel_cpu", "platform")
SHIPPED_FOR = ("x86-64-v3", "linux-x86_64")  # the machines the archive is built on and for


def machine_of(key: dict) -> tuple[str, ...]:
    """A key's MACHINE_KEYS values, to compare with SHIPPED_FOR."""
    return tuple(key[name] for name in MACHINE_KEYS)


def mismatches(manifest: dict, key: dict, ignore: tuple[str, ...] = ()) -> list[str]:
    """Where the archive's key differs from this checkout's (less the names in ignore), one line each (empty:
    it applies)."""
    if manifest.get("format") != FORMAT:
        return [f"archive format {manifest.get('format')!r}, this tool reads {FORMAT}"]
    shipped = manifest["key"]
    return [f"{name}: shipped for {shipped.get(name)!r}, here {value!r}" for name, value in key.items()
            if name != "cache_dir" and name not in ignore and shipped.get(name) != value]


def _saved_for_the_same(own: bytes, shipped: bytes) -> bool:
    """Whether the cache's own index (bytes) was saved by the same numba for the same sources as the archive's,
    read as numba reads one: its version first, then the source stamp. False where it cannot be read (numba
    would fail on it too)."""
    try:
        own_stream, shipped_stream = io.BytesIO(own), io.BytesIO(shipped)
        if pickle.load(own_stream) != pickle.load(shipped_stream):
            return False
        return pickle.loads(own_stream.read())[0] == pickle.loads(shipped_stream.read())[0]
    except Exception:  # noqa: BLE001 - anything numba's own read would fail on
        return False


def unpack_into(cache_dir: str, archive: Path = ARCHIVE) -> tuple[int, int, int]:
    """Copy the archive's cache files into cache_dir, each written whole (a temporary file renamed). A kernel the
    folder has files of (for the same Python) keeps them where its index was saved by the same numba for the same
    sources as the archive's (the cache's own, perhaps with more signatures); otherwise (an index saved for
    sources edited since or by another numba, one that cannot be read, or data without an index) those files are
    removed and the archive's written, as numba would overwrite them at its next save. Returns (files written, of
    them replacing a kernel's stale files, files left to the cache's own kernels)."""
    os.makedirs(cache_dir, exist_ok=True)
    own: dict[str, list[str]] = {}
    for name in os.listdir(cache_dir):
        if (kernel := _kernel_of(name)) is not None:
            own.setdefault(kernel, []).append(name)
    shipped: dict[str, dict[str, bytes]] = {}
    with tarfile.open(archive, "r:xz") as tar:
        for member in tar.getmembers():
            if member.name == MANIFEST_NAME:
                continue
            kernel = _kernel_of(member.name)
            if not member.isfile() or kernel is None:
                raise SystemExit(f"render_kernels: unexpected entry {member.name!r} in {archive}")
            shipped.setdefault(kernel, {})[member.name] = tar.extractfile(member).read()
    write_bytes_atomically = _atomic_file().write_bytes_atomically
    written = replaced = kept = 0
    for kernel, files in shipped.items():
        if kernel in own:
            own_index = [name for name in own[kernel] if name.endswith(".nbi")]
            index = [data for name, data in files.items() if name.endswith(".nbi")]
            if kernel.startswith("nrt-") or (own_index and index and _saved_for_the_same(
                    Path(cache_dir, own_index[0]).read_bytes(), index[0])):
                kept += len(files)
                continue
            for name in own[kernel]:
                os.remove(os.path.join(cache_dir, name))
            replaced += len(files)
        for name, data in files.items():
            write_bytes_atomically(os.path.join(cache_dir, name), data)
            written += 1
    return written, replaced, kept


def copy_package(dest: Path) -> Path:
    """A copy of what `python -m monte render` imports (the package's top-level modules and core/, without
    caches) as dest/monte; returns it."""
    package = dest / "monte"
    package.mkdir(parents=True)
    for path in ROOT.glob("*.py"):
        shutil.copy2(path, package / path.name)
    shutil.copytree(ROOT / "core", package / "core", ignore=shutil.ignore_patterns("__pycache__"))
    return package


def render_in(pythonpath: str, out_dir: str) -> subprocess.CompletedProcess:
    """make render's command, run on the package under pythonpath, writing into out_dir."""
    return subprocess.run([sys.executable, "-m", "monte", *RENDER_ARGS, "-o", os.path.join(out_dir, "cornell.exr")],
                          capture_output=True, text=True, env=_clean_environment(pythonpath), cwd=out_dir)


def build(archive: Path = ARCHIVE, force: bool = False) -> int:
    """Rebuild the archive, unless it already applies to these sources (and `force` is false): numba's cache
    files name the folder they were compiled in and number symbols in the order a process compiled them, so a
    rebuild of the same sources gives other bytes, which would only churn the repository."""
    if not force and archive.exists():
        try:
            wrong = mismatches(read_manifest(archive), environment_key(), ignore=MACHINE_KEYS)
        except (tarfile.TarError, OSError, KeyError):
            wrong = ["unreadable"]
        if not wrong:
            print(f"render_kernels: {archive} already holds these sources' kernels: nothing to do (--force "
                  "rebuilds it)")
            return 0
    with tempfile.TemporaryDirectory(prefix="monte-render-kernels-") as tmp:
        return _build_in(tmp, archive)


def _build_in(tmp: str, archive: Path) -> int:
    """Compile make render's kernels in a copy of the package at tmp and pack them into archive."""
    copy_package(Path(tmp))
    key = environment_key(tmp)
    cache_dir = key.pop("cache_dir")
    if not Path(cache_dir).resolve().is_relative_to(Path(tmp).resolve()):
        print(f"render_kernels: the copy's `monte` did not import from the copy ({cache_dir})")
        return 1
    if machine_of(key) != SHIPPED_FOR:
        print(f"render_kernels: the archive is built for {SHIPPED_FOR[0]} kernels on {SHIPPED_FOR[1]} (what "
              f"the README promises), and this machine gives {key['kernel_cpu']} on {key['platform']}: build "
              "it on such a machine (CI's, for one)")
        return 1
    print(f"render_kernels: compiling `monte {' '.join(RENDER_ARGS)}`'s kernels for {key['kernel_cpu']} "
          "CPUs in a copy of this checkout (about a minute on two cores)", flush=True)
    proc = render_in(tmp, tmp)
    if proc.returncode != 0:
        print(proc.stdout[-2000:], proc.stderr[-2000:], sep="\n")
        return 1
    names = sorted(name for name in os.listdir(cache_dir) if _kernel_of(name))
    if not names:
        print(f"render_kernels: the render cached no kernel in {cache_dir}")
        return 1
    manifest = {"format": FORMAT, "key": key, "command": ["monte", *RENDER_ARGS], "files": len(names)}
    archive.parent.mkdir(parents=True, exist_ok=True)

    def add(tar: tarfile.TarFile, name: str, data: bytes) -> None:
        info = tarfile.TarInfo(name)  # fixed metadata: the same files give the same archive
        info.size, info.mode, info.mtime = len(data), 0o644, 0
        tar.addfile(info, io.BytesIO(data))

    def write(path: str) -> None:
        with tarfile.open(path, "w:xz", preset=9) as tar:
            add(tar, MANIFEST_NAME, (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode())
            for name in names:
                add(tar, name, Path(cache_dir, name).read_bytes())

    _atomic_file().write_atomically(archive, write)
    print(f"render_kernels: wrote {archive} ({len(names)} files, {archive.stat().st_size:,} bytes): commit it with "
          "the kernel edit", flush=True)
    return 0


def unpack() -> int:
    if not ARCHIVE.exists():
        print(f"Monte: no {ARCHIVE.relative_to(ROOT)}: the first render compiles its kernels")
        return 0
    chosen = [name for name in ("NUMBA_CACHE_DIR", "NUMBA_CACHE_LOCATOR_CLASSES") if os.environ.get(name)]
    if chosen:
        print(f"Monte: {' and '.join(chosen)} set: numba caches the kernels where that says, so the shipped ones "
              "are not unpacked (the first render compiles them)")
        return 0
    key = environment_key(clean=False)  # as `make render`'s render will choose its kernels
    if not Path(key["cache_dir"]).resolve().is_relative_to(ROOT.resolve()):
        print(f"Monte: `monte` imports from outside {ROOT} here ({key['cache_dir']}): nothing unpacked")
        return 0
    try:
        manifest = read_manifest()
    except (tarfile.TarError, ImportError, OSError) as exc:  # e.g. a Python built without lzma
        print(f"Monte: cannot read {ARCHIVE.relative_to(ROOT)} ({exc}): the first render compiles its kernels")
        return 0
    wrong = mismatches(manifest, key)
    if wrong:
        print("Monte: the shipped render kernels do not apply here (" + "; ".join(wrong)
              + "): the first render compiles them (about a minute)")
        return 0
    written, replaced, kept = unpack_into(key["cache_dir"])
    print(f"Monte: {written} compiled kernel files unpacked into {key['cache_dir']}"
          + (f" ({replaced} of them over kernels compiled for earlier sources)" if replaced else "")
          + (f"; {kept} left to the kernels the cache has" if kept else ""))
    return 0


def check() -> int:
    """Whether the archive is for these sources and the pinned Python, numba and llvmlite (whatever the CPU)."""
    wrong = mismatches(read_manifest(), environment_key(), ignore=MACHINE_KEYS)
    if wrong:
        print(f"{ARCHIVE.relative_to(ROOT)} is not for this checkout: " + "; ".join(wrong)
              + ". Rebuild it with `make render-kernels`.")
        return 1
    print(f"{ARCHIVE.relative_to(ROOT)} applies here")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("command", choices=("unpack", "check", "build"))
    parser.add_argument("--force", action="store_true", help="build: even where the archive is up to date")
    args = parser.parse_args(argv)
    if args.command == "build":
        return build(force=args.force)
    return {"unpack": unpack, "check": check}[args.command]()


if __name__ == "__main__":
    sys.exit(main())
