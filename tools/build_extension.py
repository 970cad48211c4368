#!/usr/bin/env python3
"""Build Monte's Blender extension zips: download the bundled wheels, validate, build one zip per platform.

    python tools/build_extension.py                 # all platforms -> dist/monte-<version>-<platform>.zip
    python tools/build_extension.py --platform linux-x64
    python tools/build_extension.py --single        # one zip with every platform's wheels

Wheels listed in blender_manifest.toml are downloaded into wheels/ with `pip download --only-binary=:all:`
(exact versions, Python and platform taken from the file names: cp311 wheels for Blender 4.2 - 5.0, cp313 for
Blender 5.3; stable-ABI (abi3) wheels fetched for Python 3.11 and used by both; pure-Python wheels (py3-none-any,
e.g. dask and distributed for the cluster render) go into every platform's zip; files already there are
reused). The zips are made by Blender's
own extension builder, shipped inside the `bpy` wheel (bpy/<ver>/scripts/addons_core/bl_pkg/cli/
blender_ext.py), with plain Python: no Blender binary needed. Each zip is then checked to hold only the
add-on (the package __init__.py, core/, addon/, the manifest, LICENSE, its wheels and its bytecode).

The zip for the platform the build runs on also carries the compiled render kernels (numba's cache, built by
core/precompile.py under the name Blender imports the extension as, bl_ext.user_default.monte, for the CPU
levels --kernel-cpu names (all, the default: this machine's, x86-64-v3 on any recent x86-64 CPU, and generic,
for CPUs without AVX2; or one level) and keyed by the sources' contents), so the first render after installing
does not compile: for this interpreter's Python, and for each --kernel-python interpreter (e.g. a Python 3.11
environment with the manifest's numba, for Blender 4.2 - 5.0). Zips for other platforms compile on their first render.

Every zip also carries Python bytecode, for each Python the manifest's wheels are for (3.11: Blender 4.2 - 5.0,
3.13: Blender 5.3), compiled by an interpreter of that version (this one, a --kernel-python, a --bytecode-python,
or pythonX.Y as tools/find_python.sh finds it; a version with none found is skipped, with a note): the add-on's
(core/__pycache__/render.cpython-313.pyc beside core/render.py, ...) and, inside the wheels, that of the wheels
a render imports (RENDER_WHEELS). Blender unpacks wheels without compiling them, so without it the first process
after installing compiles ~190 modules of numba, llvmlite and PyYAML as it imports them (0.4-0.5 s of its
start-up on a quiet 2-core machine; docs/performance.md). They are hash-based pycs (PEP 552), since unzipping
gives the sources new times: "checked" ones (the default), used while the source's hash matches them, so a user
who edits an installed source runs the edit; --pyc unchecked-hash ships ones used without reading the source,
edits ignored (measured no faster).
"""

from __future__ import annotations

import argparse
import glob
import hashlib
import json
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = ROOT / "blender_manifest.toml"

# Blender platform -> pip --platform tags that select its wheels (the newest tag first; pip accepts older ones
# for manylinux/macOS when given the newest, but listing them is explicit).
PIP_PLATFORMS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-x64": ["macosx_13_0_x86_64"],
    "macos-arm64": ["macosx_13_0_arm64"],  # pip takes older macOS tags (numba's 12.0, OpenEXR's 11.0) too
}
# Blender installs an extension from a file into the "user_default" repository, which it imports as this package;
# numba's cache records the import name, so the shipped kernels are built under it.
BLENDER_PACKAGE = "bl_ext.user_default.monte"
KERNEL_CACHE_DIR = f"core/__pycache__/numba-{BLENDER_PACKAGE}.core"
# Top-level entries a built zip may hold.
# (the GPL travels with the code; __pycache__ holds the bytecode of __init__.py)
ALLOWED_TOP = {"__init__.py", "__pycache__", "blender_manifest.toml", "LICENSE", "core", "addon", "wheels"}


# Where the add-on's Python sources are: the package's __init__.py and these folders (what the zip ships).
PY_SOURCES = ("__init__.py", "core", "addon")
PYC_MODES = {"checked-hash": "CHECKED_HASH", "unchecked-hash": "UNCHECKED_HASH"}
# The wheels a render imports (numba reads its config with PyYAML): their bytecode ships too. The cluster
# render's (dask, distributed, ...) would add ~25 MB of bytecode to the zip for a feature that starts processes
# anyway: they compile on its first use.
RENDER_WHEELS = ("numba", "llvmlite", "pyyaml", "embreex")  # (openexr's one module, Imath.py, is top-level)


class BuildError(RuntimeError):
    pass


def log(msg: str) -> None:
    print(f"build_extension: {msg}", flush=True)


def load_manifest() -> dict:
    with open(MANIFEST, "rb") as fh:
        return tomllib.load(fh)


# The Python that stable-ABI (abi3) and pure-Python wheels are fetched for: the oldest Blender Python bundled.
BASE_PYTHON = "3.11"


def wheel_tags(wheel: str) -> tuple[str, str, str, str]:
    """(name, version, python, platform) of a wheel file name: ('numba', '0.68.1', '3.13', 'linux-x64'); python
    is "abi3" for a stable-ABI wheel (any CPython from its tag on) and "any" for a pure-Python wheel, whose
    platform is "any" too; a universal2 macOS wheel's platform is "macos-arm64" (it serves both Macs)."""
    parts = Path(wheel).stem.split("-")
    name, version, python_tag, abi_tag = parts[0], parts[1], parts[-3], parts[-2]
    if parts[-1] == "any":
        if not re.fullmatch(r"(py2\.)?py3", python_tag) or abi_tag != "none":
            raise BuildError(f"{wheel}: a platform-independent wheel must be pure Python (py3-none-any)")
        return name, version, "any", "any"
    if not re.fullmatch(r"cp3\d+", python_tag):
        raise BuildError(f"{wheel}: expected a CPython wheel (cp3XX tag), found {python_tag!r}")
    python = "abi3" if abi_tag == "abi3" else f"3.{python_tag[3:]}"
    return name, version, python, wheel_platform(wheel)


def wheel_platforms(wheel: str) -> list[str]:
    """The Blender platforms whose zip carries the wheel (all of them for a pure-Python wheel, both Macs for a
    universal2 one)."""
    tag = Path(wheel).stem.split("-")[-1]
    if tag == "any":
        return list(PIP_PLATFORMS)
    if tag.startswith("macosx") and tag.endswith("universal2"):
        return ["macos-x64", "macos-arm64"]
    return [wheel_platform(wheel)]


def wheel_requirements(wheels: list[str]) -> dict[tuple[str, str], dict[str, str]]:
    """{(platform, python): {name: version}} from the manifest's wheel file names (python "abi3" and platform /
    python "any" as wheel_tags gives them). A package may differ in version between platforms (Intel Macs keep
    an older numba) but not twice for one platform and Python."""
    pins: dict[tuple[str, str], dict[str, str]] = {}
    for w in wheels:
        name, version, python, platform = wheel_tags(w)
        group = pins.setdefault((platform, python), {})
        if group.get(name, version) != version:
            raise BuildError(f"the manifest lists two versions of {name} for {platform}, Python {python}: "
                             f"{group[name]} and {version}")
        group[name] = version
    return pins


def wheel_platform(wheel: str) -> str:
    """The Blender platform a wheel file is for (from its platform tag)."""
    tag = Path(wheel).stem.split("-")[-1]
    if "manylinux" in tag and "x86_64" in tag:
        return "linux-x64"
    if tag == "win_amd64":
        return "windows-x64"
    if tag.startswith("macosx") and tag.endswith("x86_64"):
        return "macos-x64"
    if tag.startswith("macosx") and tag.endswith(("arm64", "universal2")):
        return "macos-arm64"
    raise BuildError(f"unknown wheel platform tag {tag!r} in {wheel}")


def download_wheels(manifest: dict, platforms: list[str], refresh: bool) -> None:
    """Fetch the manifest's wheels for `platforms` into wheels/ (one pip call per platform and Python)."""
    wheels = manifest.get("wheels", [])
    dest = ROOT / "wheels"
    dest.mkdir(exist_ok=True)
    for (platform, python), pins in sorted(wheel_requirements(wheels).items()):
        wanted = [w for w in wheels if wheel_tags(w)[2:] == (python, platform)]
        if not any(p in platforms for w in wanted for p in wheel_platforms(w)):
            continue
        missing = [w for w in wanted if not (ROOT / w).is_file()]
        if not missing and not refresh:
            log(f"{platform}, Python {python}: wheels present ({', '.join(Path(w).name for w in wanted)})")
            continue
        pip_python = BASE_PYTHON if python in ("abi3", "any") else python
        cmd = [sys.executable, "-m", "pip", "download", "--only-binary=:all:", "--no-deps",
               "--python-version", pip_python, "--implementation", "cp", "-d", str(dest)]
        for tag in PIP_PLATFORMS.get(platform, []):  # none for pure-Python wheels
            cmd += ["--platform", tag]
        cmd += [f"{name}=={version}" for name, version in sorted(pins.items())]
        log(f"{platform}, Python {python}: " + " ".join(cmd[3:]))
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise BuildError(f"pip download failed for {platform}, Python {python}:\n{proc.stdout[-2000:]}\n"
                             f"{proc.stderr[-2000:]}")
        still = [w for w in wanted if not (ROOT / w).is_file()]
        if still:
            have = sorted(p.name for p in dest.glob("*.whl"))
            raise BuildError(
                f"{platform}: pip did not produce {', '.join(Path(w).name for w in still)}; wheels/ holds "
                f"{', '.join(have)}. If PyPI now serves other file names, update blender_manifest.toml's wheels.")


def find_blender_ext() -> Path:
    env = os.environ.get("BLENDER_EXT")
    if env:
        return Path(env)
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise BuildError("the bpy module is not installed (pip install bpy==5.3.0), and BLENDER_EXT is not set to "
                         "Blender's scripts/addons_core/bl_pkg/cli/blender_ext.py")
    for base in spec.submodule_search_locations:
        hits = sorted(glob.glob(os.path.join(base, "*", "scripts", "addons_core", "bl_pkg", "cli",
                                             "blender_ext.py")))
        if hits:
            return Path(hits[-1])
    raise BuildError("blender_ext.py not found inside the bpy package")


def run_blender_ext(tool: Path, *args: str) -> str:
    cmd = [sys.executable, str(tool), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    out = (proc.stdout + proc.stderr).strip()
    if proc.returncode != 0:
        raise BuildError(f"{' '.join(cmd[1:3])} failed:\n{out}")
    return out


def this_platform() -> str | None:
    """The Blender platform name of the machine the build runs on (None: no Monte build for it)."""
    import platform

    return {("Linux", "x86_64"): "linux-x64", ("Windows", "AMD64"): "windows-x64",
            ("Darwin", "x86_64"): "macos-x64", ("Darwin", "arm64"): "macos-arm64"}.get(
        (platform.system(), platform.machine()))


def stage_subset(manifest: dict, platforms: list[str], stage: Path) -> Path:
    """A copy of the source tree whose manifest lists only `platforms` and their wheels (Blender's builder
    wants every listed wheel on disk, and one platform's build should not need the others' wheels), placed
    where it imports as BLENDER_PACKAGE (stage/bl_ext/user_default/monte) for building the kernel cache. The
    copy's manifest lets __pycache__ folders and .pyc files in (they hold only that cache and the bytecode
    compile_bytecode writes: the kernel build writes no .pyc)."""
    (stage / "bl_ext" / "user_default").mkdir(parents=True)
    for pkg in (stage / "bl_ext", stage / "bl_ext" / "user_default"):
        (pkg / "__init__.py").write_text("")
    src = stage / "bl_ext" / "user_default" / "monte"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", ".venv-*", "dist", "build", "wheels", "__pycache__", ".pytest_cache", "*.egg-info", "out"))
    wheels = [w for w in manifest.get("wheels", []) if any(p in platforms for p in wheel_platforms(w))]
    (src / "wheels").mkdir()
    for w in wheels:
        shutil.copy2(ROOT / w, src / w)
    text = (ROOT / "blender_manifest.toml").read_text()
    text, n1 = re.subn(r"(?ms)^platforms\s*=\s*\[.*?\]", "platforms = [" + ", ".join(f'"{p}"' for p in platforms)
                       + "]", text, count=1)
    text, n2 = re.subn(r"(?ms)^wheels\s*=\s*\[.*?\]", "wheels = [" + ", ".join(f'"{w}"' for w in wheels) + "]",
                       text, count=1)
    text, n3 = re.subn(r'(?m)^\s*"__pycache__/",\n', "", text, count=1)
    text, n4 = re.subn(r'(?m)^\s*"\*\.pyc",\n', "", text, count=1)
    if n1 != 1 or n2 != 1 or n3 != 1 or n4 != 1:
        raise BuildError("could not rewrite platforms, wheels, __pycache__/ and *.pyc in a copy of "
                         "blender_manifest.toml")
    (src / "blender_manifest.toml").write_text(text)
    return src


KERNEL_BUILDS = ROOT / "build" / "kernel-cache"  # earlier builds' compiled kernels, one folder per kernel_build_key
KEPT_KERNEL_BUILDS = 6  # the most recent ones kept


def kernel_build_key(python: str, root: Path, env: dict) -> tuple[str, str] | None:
    """(the kernel CPU level env resolves to, what a built kernel cache depends on as one hex digest: the
    interpreter's full version, its numba's and llvmlite's, that level, the platform, and the kernel sources'
    digest with the numba options: core.jit_cache.sources_digest, numba's own cache key). None when the probe
    fails."""
    code = (f"import sys; sys.path.insert(0, {str(root)!r}); import llvmlite, numba, platform; "
            f"from {BLENDER_PACKAGE}.core import jit_cache; print(sys.version, numba.__version__, "
            "llvmlite.__version__, jit_cache.KERNEL_CPU, platform.system(), platform.machine(), "
            "jit_cache.sources_digest(), sep='\\n')")
    proc = subprocess.run([python, "-c", code], capture_output=True, text=True, env=env, cwd=root)
    if proc.returncode != 0:
        return None
    level = proc.stdout.splitlines()[-4]  # (the sources' digest, machine and system follow it)
    return level, hashlib.sha256(proc.stdout.encode()).hexdigest()[:24]


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    """{name: (size, mtime_ns)} of the plain files in folder (none when it does not exist)."""
    if not folder.is_dir():
        return {}
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.iterdir() if p.is_file()}


def keep_kernel_build(cache: Path, names: list[str], key: str) -> None:
    """Copy the files `names` of the built cache folder into KERNEL_BUILDS/key (whole: written beside and renamed
    into place, replacing one kept before under that key), then remove all but the KEPT_KERNEL_BUILDS most
    recently kept or used folders. A failure to keep costs only the next build's time: it is logged, never
    raised."""
    tmp = KERNEL_BUILDS / f".{key}.{os.getpid()}.tmp"
    old_copy = KERNEL_BUILDS / f".{key}.{os.getpid()}.old"
    try:
        tmp.mkdir(parents=True)
        for name in names:
            shutil.copy2(cache / name, tmp / name)
        if (KERNEL_BUILDS / key).exists():  # (--recompile-kernels): the new compile replaces it
            os.replace(KERNEL_BUILDS / key, old_copy)
        os.replace(tmp, KERNEL_BUILDS / key)
        shutil.rmtree(old_copy, ignore_errors=True)
        kept = sorted((p for p in KERNEL_BUILDS.iterdir() if p.is_dir() and not p.name.startswith(".")),
                      key=lambda p: p.stat().st_mtime, reverse=True)
        for old in kept[KEPT_KERNEL_BUILDS:]:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:  # (a build keeping the same key at the same moment, a read-only checkout, ...)
        shutil.rmtree(tmp, ignore_errors=True)
        log(f"kernel cache: not kept for later builds ({exc})")


def kernel_levels(python: str, root: Path, env: dict, kernel_cpu: str) -> list[tuple[str, str | None]]:
    """[(level, its kernel_build_key digest or None)] to compile the shipped kernels for with `python`, levels as
    core.jit_cache's MONTE_KERNEL_CPU values: kernel_cpu itself, or for "all" the level this machine's `auto`
    picks and then "generic" where that differs (x86-64-v3 and generic on a recent x86-64 machine: a user's CPU
    without AVX2 then loads the generic ones instead of compiling). A level above this machine's cannot be
    compiled here: precompiling runs the kernels."""
    first = kernel_build_key(python, root, {**env, "MONTE_KERNEL_CPU": "auto" if kernel_cpu == "all" else kernel_cpu})
    if kernel_cpu != "all":
        return [(kernel_cpu, first and first[1])]
    if first is None:
        return [("auto", None), ("generic", None)]  # (the precompile itself will say what fails)
    own, key = first
    if own == "generic":
        return [(own, key)]
    generic = kernel_build_key(python, root, {**env, "MONTE_KERNEL_CPU": "generic"})
    return [(own, key), ("generic", generic and generic[1])]


def build_kernel_cache(src: Path, python: str, manifest: dict, platform: str, reuse: bool = True,
                       kernel_cpu: str = "all") -> bool:
    """Compile every render kernel of the staged copy `src` with `python` into src/KERNEL_CACHE_DIR, for the CPU
    levels kernel_cpu names (kernel_levels: all, the default, is this machine's level and generic; or one of
    core.jit_cache's MONTE_KERNEL_CPU values: auto, generic, x86-64-v3). The levels compile one after the other
    into the one folder: numba's index file of a kernel module holds every level's entries, each keyed by the CPU
    it was compiled for, and the loading process picks its own. Skipped, with a note, when
    that Python's numba is not the one the manifest bundles for it (the cache would not match the numba Blender
    installs). With `reuse`, a cache an earlier build compiled for
    the same key (kernel_build_key of every level: the same sources, interpreter, numba and llvmlite) is copied from
    KERNEL_BUILDS instead of compiling again; what a build compiles is kept there either way. Returns whether a
    cache was built."""
    probe = subprocess.run([python, "-c", "import sys, numba; "
                            "print(f'{sys.version_info[0]}.{sys.version_info[1]}', numba.__version__)"],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        log(f"kernel cache: skipped for {python}: it cannot import numba ({probe.stderr.strip()[-300:]})")
        return False
    py_version, numba_version = probe.stdout.split()
    wanted = wheel_requirements(manifest.get("wheels", [])).get((platform, py_version), {}).get("numba")
    if wanted != numba_version:
        log(f"kernel cache: skipped for Python {py_version} ({python}): it has numba {numba_version}, the zip "
            f"bundles {wanted or 'no numba'} for it on {platform}")
        return False
    base_env = {k: v for k, v in os.environ.items()
                if not k.startswith("NUMBA_") and k not in ("MONTE_KERNEL_CPU", "PYTHONPATH")}
    base_env["PYTHONDONTWRITEBYTECODE"] = "1"  # the cache folders ship: no .pyc in them
    root = src.parent.parent.parent
    levels, level_keys = zip(*kernel_levels(python, root, base_env, kernel_cpu))
    envs = [{**base_env, "MONTE_KERNEL_CPU": level} for level in levels]
    cache = src / KERNEL_CACHE_DIR
    key = None if None in level_keys else (
        level_keys[0] if len(level_keys) == 1 else hashlib.sha256("+".join(level_keys).encode()).hexdigest()[:24])
    named = f"MONTE_KERNEL_CPU={' and '.join(levels)}"
    if reuse and key is not None and (KERNEL_BUILDS / key / "entry-kernels.json").is_file():
        shutil.copytree(KERNEL_BUILDS / key, cache, dirs_exist_ok=True)
        os.utime(KERNEL_BUILDS / key)  # (recently used: kept the longest)
        log(f"kernel cache: Python {py_version}, {named}: the one an earlier build compiled for these sources, numba "
            f"{numba_version} and this interpreter ({KERNEL_BUILDS / key}; --recompile-kernels compiles anew)")
        return True
    before = _files(cache)
    code = (f"import sys; sys.path.insert(0, {str(root)!r}); "
            f"from {BLENDER_PACKAGE}.core.precompile import main; sys.exit(main())")
    for level, env in zip(levels, envs):
        log(f"kernel cache: compiling for Python {py_version} (numba {numba_version}), MONTE_KERNEL_CPU={level} ...")
        proc = subprocess.run([python, "-c", code], capture_output=True, text=True, env=env, cwd=root)
        if proc.returncode != 0:
            raise BuildError(f"compiling the kernel cache with {python} for {level} CPUs failed:\n"
                             f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
        log(f"kernel cache: {proc.stdout.strip().splitlines()[-1]}")
    # The lock file its saves took (core/jit_cache.py: SAVE_LOCK_NAME) is not part of the cache; the staged copy
    # is this build's alone, so nothing else holds it now.
    (cache / "save.lock").unlink(missing_ok=True)
    if key is not None:  # what this compile wrote (an earlier interpreter's files in the folder are not its),
        after = _files(cache)  # and NRT's module, which it may have loaded from an earlier interpreter's compile
        keep_kernel_build(cache, sorted(n for n, stat in after.items()
                                        if before.get(n) != stat or n.startswith("nrt-")), key)
    return True


def manifest_pythons(manifest: dict, platforms: list[str]) -> list[str]:
    """The Python versions ("3.11", "3.13") the manifest bundles compiled wheels for on `platforms`."""
    return sorted({python for (platform, python) in wheel_requirements(manifest.get("wheels", []))
                   if platform in platforms and python not in ("abi3", "any")}, key=lambda v: int(v.split(".")[1]))


def python_version(python: str) -> str | None:
    """"3.13" for an interpreter that runs, None otherwise."""
    try:
        proc = subprocess.run([python, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                              capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    return proc.stdout.strip() if proc.returncode == 0 else None


def find_interpreters(versions: list[str], candidates: list[str]) -> dict[str, str]:
    """{version: interpreter} for each of `versions`: the first of `candidates` of that version, else pythonX.Y
    as tools/find_python.sh finds it (PATH, then pyenv's versions), else shutil.which("pythonX.Y")."""
    found: dict[str, str] = {}
    for python in candidates:
        v = python_version(python)
        if v in versions and v not in found:
            found[v] = python
    for v in versions:
        if v in found:
            continue
        finder = ROOT / "tools" / "find_python.sh"
        bash = shutil.which("bash")
        if bash and finder.is_file():
            proc = subprocess.run([bash, str(finder), v], capture_output=True, text=True)
            if proc.returncode == 0 and proc.stdout.strip():
                found[v] = proc.stdout.strip()
                continue
        which = shutil.which(f"python{v}")
        if which and python_version(which) == v:
            found[v] = which
    return found


def py_sources(src: Path) -> list[Path]:
    """The add-on's .py files in the staged copy `src` (those the zip ships), sorted."""
    files = []
    for entry in PY_SOURCES:
        path = src / entry
        files += [path] if path.is_file() else sorted(p for p in path.rglob("*.py") if "__pycache__" not in p.parts)
    return files


# Run by each interpreter: compile the listed files into __pycache__ beside them as hash-based pycs, the name
# stored in the code (co_filename; Python replaces it by the real path on import) relative to the package.
_COMPILE = """
import importlib.util, json, py_compile, sys
root, mode, strict, files = sys.argv[1], sys.argv[2], sys.argv[3] == "1", sys.argv[4:]
written, failed = [], []
for f in files:
    cfile = importlib.util.cache_from_source(f)
    try:
        py_compile.compile(f, cfile=cfile, dfile=f[len(root) + 1:], doraise=True,
                           invalidation_mode=getattr(py_compile.PycInvalidationMode, mode))
    except (py_compile.PyCompileError, SyntaxError, ValueError, UnicodeDecodeError) as exc:
        if strict:
            raise
        failed.append(f)  # a wheel's file that is not Python of this version (a template, a test for Python 2)
        continue
    written.append(cfile)
print(json.dumps({"tag": sys.implementation.cache_tag, "written": written, "failed": failed}))
"""


def _run_compile(python: str, root: Path, files: list[Path], mode: str, strict: bool) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    proc = subprocess.run([python, "-I", "-c", _COMPILE, str(root), PYC_MODES[mode], "1" if strict else "0",
                           *map(str, files)], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise BuildError(f"compiling bytecode with {python} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def compile_bytecode(src: Path, interpreters: dict[str, str], mode: str) -> list[str]:
    """Compile the add-on's sources in `src` with each interpreter ({version: python}) as `mode` hash-based
    pycs; returns the cache tags written ("cpython-311", ...)."""
    files = py_sources(src)
    tags = []
    for version, python in sorted(interpreters.items()):
        result = _run_compile(python, src.parent, files, mode, strict=True)
        missing = [f for f in files if not (f.parent / "__pycache__" / f"{f.stem}.{result['tag']}.pyc").is_file()]
        if missing:
            raise BuildError(f"{python} wrote no {result['tag']} bytecode for {missing[:3]}")
        tags.append(result["tag"])
        log(f"bytecode: {len(files)} modules compiled for Python {version} ({python}, {mode} pycs)")
    return tags


def add_wheel_bytecode(src: Path, interpreters: dict[str, str], mode: str) -> None:
    """Add bytecode to the RENDER_WHEELS in src/wheels (rewritten in place, same names): Blender unpacks a wheel's files
    as they are and writes no bytecode, so without this the first process after installing compiles numba's,
    llvmlite's and the others' modules as it imports them (~190 modules for a render). A version-specific wheel
    gets its Python's bytecode, a stable-ABI or pure-Python one every found Python's; RECORD is left as it was
    (pip, too, installs bytecode it does not list there)."""
    import zipfile

    for wheel in sorted((src / "wheels").glob("*.whl")):
        name, _, python, _ = wheel_tags(wheel.name)
        if name.lower() not in RENDER_WHEELS:
            continue
        versions = sorted(interpreters) if python in ("abi3", "any") else [python]
        pythons = [interpreters[v] for v in versions if v in interpreters]
        if not pythons:
            continue
        with tempfile.TemporaryDirectory(prefix="monte-wheel-") as tmp:
            root = Path(tmp)
            with zipfile.ZipFile(wheel) as zf:
                infos = zf.infolist()
                members = {i.filename for i in infos}
                zf.extractall(root)
            # in the wheel's packages only: a top-level module's __pycache__ (openexr's Imath.py) would be a
            # top-level folder of site-packages that no wheel's RECORD owns, which Blender's wheel manager prunes
            files = sorted(p for p in root.rglob("*.py") if len(p.relative_to(root).parts) > 1
                           and not p.relative_to(root).parts[0].endswith(".data"))
            added = []
            for py in pythons:
                result = _run_compile(py, root, files, mode, strict=False)
                added += [Path(c).relative_to(root).as_posix() for c in result["written"]]
            added = [a for a in added if a not in members]
            if not added:
                continue
            rewritten = wheel.with_suffix(".tmp")
            with zipfile.ZipFile(wheel) as zin, zipfile.ZipFile(rewritten, "w", zipfile.ZIP_DEFLATED) as zout:
                for info in infos:
                    zout.writestr(info, zin.read(info))
                for name in sorted(added):
                    zout.write(root / name, name)
            os.replace(rewritten, wheel)
        log(f"bytecode: {wheel.name}: {len(added)} pycs added ({', '.join(versions)})")


def pyc_name(source: str, tag: str) -> str:
    """The zip member that holds the bytecode of the zip member `source` ("core/render.py", "/"-separated) for
    the interpreter cache tag `tag` ("cpython-313"): core/__pycache__/render.cpython-313.pyc, as Python looks
    for it."""
    folder, _, name = source.rpartition("/")
    return f"{folder + '/' if folder else ''}__pycache__/{name[:-3]}.{tag}.pyc"


def check_zip(path: Path, manifest: dict, pyc_tags: list[str] = ()) -> None:
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
    tops = {n.split("/", 1)[0] for n in names}
    unexpected = sorted(tops - ALLOWED_TOP)
    if unexpected:
        raise BuildError(f"{path.name} holds files the add-on does not need: {', '.join(unexpected)} "
                         "(extend [build] paths_exclude_pattern in blender_manifest.toml)")
    sources = {n for n in names if n.endswith(".py") and not n.startswith("wheels/")}
    bytecode = {pyc_name(n, tag) for n in sources for tag in pyc_tags}
    junk = [n for n in names if (n.endswith(".pyc") and n not in bytecode) or ("__pycache__" in n and not (
        n in bytecode or n.startswith(KERNEL_CACHE_DIR + "/") and (n.endswith((".nbi", ".nbc", "/entry-kernels.json"))
                                                    or n.rpartition("/")[2].startswith("nrt-") and n.endswith(".bin"))))]
    if junk:
        raise BuildError(f"{path.name} holds compiled Python files that are not the add-on's: {junk[:5]}")
    missing = sorted(bytecode - set(names))
    if missing:
        raise BuildError(f"{path.name} lacks the add-on's bytecode: {missing[:5]}")
    for required in ("__init__.py", "blender_manifest.toml", "core/render.py", "addon/engine.py"):
        if required not in names:
            raise BuildError(f"{path.name} lacks {required}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--platform", action="append", choices=sorted(PIP_PLATFORMS),
                        help="build only this platform (repeatable; default: every platform in the manifest)")
    parser.add_argument("--single", action="store_true",
                        help="one zip holding every platform's wheels instead of one zip per platform")
    parser.add_argument("--output-dir", default=str(ROOT / "dist"), help="where the zips go (default dist/)")
    parser.add_argument("--refresh", action="store_true", help="download the wheels again")
    parser.add_argument("--no-download", action="store_true", help="use the wheels already in wheels/")
    parser.add_argument("--kernel-python", action="append", default=[], metavar="PYTHON",
                        help="also build the shipped kernel cache with this interpreter (repeatable; e.g. a Python "
                             "3.11 with the manifest's numba, for Blender 4.2 - 5.0)")
    parser.add_argument("--no-kernel-cache", action="store_true",
                        help="ship no compiled kernels (the first render after installing compiles them)")
    parser.add_argument("--kernel-cpu", choices=("all", "auto", "generic", "x86-64-v3"), default="all",
                        help="the CPU levels the shipped kernels are compiled for: all (default: this machine's "
                             "level and generic, so every CPU of the architecture loads them: x86-64-v3 and "
                             "generic on x86-64 CPUs with AVX2, FMA and BMI2, else generic alone), auto (this "
                             "machine's alone), generic (runs on every CPU of the architecture, up to 7%% slower), "
                             "or x86-64-v3; a machine of a level not shipped compiles the kernels on its first "
                             "render")
    parser.add_argument("--recompile-kernels", action="store_true",
                        help="compile the shipped kernels even where an earlier build kept a cache for the same "
                             "sources, interpreter and numba (build/kernel-cache/)")
    parser.add_argument("--pyc", choices=[*PYC_MODES, "none"], default="checked-hash",
                        help="the Python bytecode shipped (the add-on's, the render wheels') for each Python of the "
                             "manifest: checked-hash "
                             "(default: used while the source is unchanged), unchecked-hash (used even after the "
                             "source is edited) or none (compiled on the first start after installing)")
    parser.add_argument("--bytecode-python", action="append", default=[], metavar="PYTHON",
                        help="an interpreter to compile the add-on's bytecode with (repeatable; by default this "
                             "one, the --kernel-python ones, and pythonX.Y found on PATH or in pyenv)")
    args = parser.parse_args(argv)

    try:
        manifest = load_manifest()
        with open(ROOT / "pyproject.toml", "rb") as fh:
            package_version = tomllib.load(fh)["project"]["version"]
        if package_version != manifest["version"]:
            raise BuildError(f"blender_manifest.toml says version {manifest['version']} but pyproject.toml says "
                             f"{package_version}: make them agree")
        platforms = args.platform or list(manifest.get("platforms", PIP_PLATFORMS))
        if args.single:
            platforms = list(manifest.get("platforms", PIP_PLATFORMS))
        if not args.no_download:
            download_wheels(manifest, platforms, args.refresh)
        tool = find_blender_ext()
        log(f"using {tool}")
        out_dir = Path(args.output_dir).resolve()
        out_dir.mkdir(parents=True, exist_ok=True)  # the builder needs it to exist
        version = manifest["version"]
        before = {p: p.stat().st_mtime for p in out_dir.glob(f"{manifest['id']}-{version}*.zip")}
        host = this_platform()
        cache_platforms = [] if args.no_kernel_cache or host not in platforms else [host]
        if args.single:
            groups = [(platforms, bool(cache_platforms))]
        else:  # the kernel cache is for this machine's platform: its zip is built from its own staged copy
            others = [p for p in platforms if p not in cache_platforms]
            groups = [(g, g == cache_platforms) for g in (cache_platforms, others) if g]
        pyc_tags: dict[str, list[str]] = {}  # platform -> the cache tags its zip's bytecode was compiled for
        for group, with_cache in groups:
            with tempfile.TemporaryDirectory(prefix="monte-ext-") as tmp:
                source = stage_subset(manifest, group, Path(tmp))
                if with_cache:
                    built_for = [build_kernel_cache(source, py, manifest, host, reuse=not args.recompile_kernels,
                                                  kernel_cpu=args.kernel_cpu)
                                 for py in [sys.executable, *args.kernel_python]]
                    if not any(built_for):
                        log("kernel cache: none built; the first render after installing compiles the kernels")
                if args.pyc != "none":  # after the kernel cache: its build writes no .pyc, this writes only them
                    versions = manifest_pythons(manifest, group)
                    interpreters = find_interpreters(
                        versions, [*args.bytecode_python, sys.executable, *args.kernel_python])
                    for v in versions:
                        if v not in interpreters:
                            log(f"bytecode: no Python {v} found (--bytecode-python): its Blenders compile the "
                                "add-on on their first start")
                    tags = compile_bytecode(source, interpreters, args.pyc)
                    add_wheel_bytecode(source, interpreters, args.pyc)
                    for p in group:
                        pyc_tags[p] = tags
                log(run_blender_ext(tool, "validate", str(source)).splitlines()[-1])
                build_args = ["build", "--source-dir", str(source), "--output-dir", str(out_dir)]
                if not args.single:
                    build_args.append("--split-platforms")
                log(run_blender_ext(tool, *build_args).splitlines()[-1])
        built = sorted(p for p in out_dir.glob(f"{manifest['id']}-{version}*.zip")
                       if before.get(p) != p.stat().st_mtime)
        if not built:
            raise BuildError(f"the builder wrote no zip into {out_dir}")
        for p in built:
            # --single builds one zip for every platform, all compiled alike; --split-platforms one per platform
            tags = next((t for plat, t in pyc_tags.items()
                         if args.single or p.name.endswith(f"-{plat.replace('-', '_')}.zip")), [])
            check_zip(p, manifest, tags)
            log(f"built {p} ({p.stat().st_size / 1e6:.1f} MB)")
    except BuildError as exc:
        print(f"build_extension: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
