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
add-on (the package __init__.py, core/, addon/, the manifest, LICENSE and its wheels).

The zip for the platform the build runs on also carries the compiled render kernels (numba's cache, built by
core/precompile.py under the name Blender imports the extension as, bl_ext.user_default.monte, for a generic
CPU and keyed by the sources' contents), so the first render after installing does not compile: for this
interpreter's Python, and for each --kernel-python interpreter (e.g. a Python 3.11 environment with the
manifest's numba, for Blender 4.2 - 5.0). Zips for other platforms compile on their first render.
"""

from __future__ import annotations

import argparse
import glob
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
ALLOWED_TOP = {"__init__.py", "blender_manifest.toml", "LICENSE", "core", "addon", "wheels"}  # the GPL travels with the code


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
    copy's manifest lets __pycache__ folders in (they hold only that cache: no .pyc is written there)."""
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
    if n1 != 1 or n2 != 1 or n3 != 1:
        raise BuildError("could not rewrite platforms, wheels and __pycache__/ in a copy of blender_manifest.toml")
    (src / "blender_manifest.toml").write_text(text)
    return src


def build_kernel_cache(src: Path, python: str, manifest: dict, platform: str) -> bool:
    """Compile every render kernel of the staged copy `src` with `python` into src/KERNEL_CACHE_DIR (for a
    generic CPU). Skipped, with a note, when that Python's numba is not the one the manifest bundles for it
    (the cache would not match the numba Blender installs). Returns whether a cache was built."""
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
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("NUMBA_") and k not in ("MONTE_KERNEL_CPU", "PYTHONPATH")}
    env["PYTHONDONTWRITEBYTECODE"] = "1"  # the cache folders ship: no .pyc in them
    root = src.parent.parent.parent
    code = (f"import sys; sys.path.insert(0, {str(root)!r}); "
            f"from {BLENDER_PACKAGE}.core.precompile import main; sys.exit(main())")
    log(f"kernel cache: compiling for Python {py_version} (numba {numba_version}) ...")
    proc = subprocess.run([python, "-c", code], capture_output=True, text=True, env=env, cwd=root)
    if proc.returncode != 0:
        raise BuildError(f"compiling the kernel cache with {python} failed:\n{proc.stdout[-3000:]}\n"
                         f"{proc.stderr[-3000:]}")
    log(f"kernel cache: {proc.stdout.strip().splitlines()[-1]}")
    return True


def check_zip(path: Path, manifest: dict) -> None:
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
    tops = {n.split("/", 1)[0] for n in names}
    unexpected = sorted(tops - ALLOWED_TOP)
    if unexpected:
        raise BuildError(f"{path.name} holds files the add-on does not need: {', '.join(unexpected)} "
                         "(extend [build] paths_exclude_pattern in blender_manifest.toml)")
    junk = [n for n in names if n.endswith(".pyc") or ("__pycache__" in n and not (
        n.startswith(KERNEL_CACHE_DIR + "/") and n.endswith((".nbi", ".nbc", "/entry-kernels.json"))))]
    if junk:
        raise BuildError(f"{path.name} holds compiled Python files: {junk[:5]}")
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
        for group, with_cache in groups:
            with tempfile.TemporaryDirectory(prefix="monte-ext-") as tmp:
                source = stage_subset(manifest, group, Path(tmp))
                if with_cache:
                    built_for = [build_kernel_cache(source, py, manifest, host)
                                 for py in [sys.executable, *args.kernel_python]]
                    if not any(built_for):
                        log("kernel cache: none built; the first render after installing compiles the kernels")
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
            check_zip(p, manifest)
            log(f"built {p} ({p.stat().st_size / 1e6:.1f} MB)")
    except BuildError as exc:
        print(f"build_extension: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
