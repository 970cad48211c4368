"""The first `make render` after a clone installs only requirements/render.txt (no Blender, tests, cluster or
denoiser) before it renders the Cornell box: a built-in scene's render must need nothing else."""

import importlib.metadata as md
import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REQUIREMENTS = ROOT / "requirements"


def _name(distribution: str) -> str:
    return re.sub(r"[-_.]+", "-", distribution).lower()  # PEP 503 normalisation


def _pins(path: Path) -> dict[str, str]:
    """{normalised name: version} of the `name==version` lines of a requirements file and the files it includes
    (`-r`); a name pinned twice to different versions is an error."""
    pins: dict[str, str] = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith("-r "):
            found = _pins(path.parent / line[3:].strip())
        elif "==" in line:
            name, version = line.split("==", 1)
            found = {_name(name.strip()): version.split(";", 1)[0].strip()}
        else:
            assert not line, f"{path.name}: unexpected line {line!r}"
            continue
        for name, version in found.items():
            assert pins.setdefault(name, version) == version, f"{path.name}: {name} pinned to two versions"
    return pins


# Renders the Cornell box through the `monte` command in a process that cannot import any installed package
# outside the render set (as if it were not installed: an optional import falls back, a needed one fails).
_PROBE = """
import importlib.abc, importlib.metadata as md, json, re, sys
allowed = set(json.loads(sys.argv[2]))
owners = md.packages_distributions()
blocked = set()

class RenderSetOnly(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if path is None and name in owners and not {re.sub(r"[-_.]+", "-", d).lower() for d in owners[name]} & allowed:
            blocked.add(name)
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, RenderSetOnly())
from monte.cli import main
code = main(["render", "cornell", "-o", sys.argv[1], "--spp", "2", "--resolution", "8x8", "--threads", "2"])
print(json.dumps({"code": code, "blocked": sorted(blocked)}))
"""


def test_render_set_is_the_core_and_its_numpy():
    render = _pins(REQUIREMENTS / "render.txt")
    assert set(render) == {"embreex", "openexr", "numba", "llvmlite", "numpy"}, render
    # The default environment (make setup, CI) holds the same versions: it includes the render set.
    default = _pins(ROOT / "requirements.txt")
    assert {name: default[name] for name in render} == render
    assert "bpy" in default and "bpy" not in render
    # and this environment runs the core's (the same for every Blender; numpy is pinned per Blender version)
    core = _pins(REQUIREMENTS / "core.txt")
    assert set(core) == set(render) - {"numpy"}
    assert {name: md.version(name) for name in core} == core


def test_a_builtin_scene_renders_with_the_render_set_alone(tmp_path):
    out = tmp_path / "cornell.exr"
    allowed = sorted(_pins(REQUIREMENTS / "render.txt")) + ["monte"]
    proc = subprocess.run([sys.executable, "-c", _PROBE, str(out), json.dumps(allowed)], capture_output=True,
                          text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["code"] == 0, (result, proc.stderr[-3000:])
    assert out.exists() and out.with_suffix(".png").exists()
    assert "bpy" not in result["blocked"]  # (the command never tried Blender for a built-in scene)


# tools/install_render_set.sh, run with an empty requirements file (pip installs nothing, so no package index is
# needed): how the venv is made and how Monte becomes importable from this checkout.
_SCRIPT = ROOT / "tools" / "install_render_set.sh"
_WHERE = ("import importlib.util, sysconfig; spec = importlib.util.find_spec('monte'); "
          "print(spec.origin if spec else None); print(sysconfig.get_path('purelib'))")


def _install(venv: Path, python: str, tmp_path: Path) -> tuple[str, Path]:
    """Run the script; returns where `monte` imports from in the venv (without running it) and its purelib.
    (Without PYTHONPATH, which would name where this test's own `monte` comes from.)"""
    requirements = tmp_path / "empty.txt"
    requirements.write_text("")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([str(_SCRIPT), str(venv), python, str(requirements)], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300, env=env)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    where = subprocess.run([str(venv / "bin" / "python"), "-P", "-c", _WHERE], capture_output=True, text=True,
                           cwd=tmp_path, check=True, env=env).stdout.split("\n")
    return where[0], Path(where[1])


def _has_pip(venv: Path) -> bool:
    return subprocess.run([str(venv / "bin" / "python"), "-c", "import pip"], capture_output=True).returncode == 0


def test_the_quick_install_makes_a_venv_without_pip_and_links_monte_to_this_checkout(tmp_path):
    """The interpreter's own pip (22.3 or newer) installs into a venv made without pip, and `monte` is a link to
    this checkout in its site-packages (no editable install's wheel build); a second run changes nothing."""
    venv = tmp_path / "venv"
    origin, purelib = _install(venv, sys.executable, tmp_path)
    assert not _has_pip(venv)
    link = purelib / "monte"
    assert link.is_symlink() and link.resolve() == ROOT
    assert Path(origin).resolve() == ROOT / "__init__.py"
    assert _install(venv, sys.executable, tmp_path) == (origin, purelib)
    assert link.is_symlink() and link.resolve() == ROOT and not _has_pip(venv)


def test_the_quick_install_leaves_an_installed_monte_alone(tmp_path):
    """Where the venv has Monte installed (`make setup`'s editable install), no link is added beside it."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    purelib = Path(subprocess.run([str(venv / "bin" / "python"), "-c",
                                   "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                  capture_output=True, text=True, check=True).stdout.strip())
    dist_info = purelib / "monte-0.1.0.dist-info"
    dist_info.mkdir(parents=True)
    (dist_info / "METADATA").write_text("Metadata-Version: 2.1\nName: monte\nVersion: 0.1.0\n")
    origin, _ = _install(venv, sys.executable, tmp_path)
    assert not (purelib / "monte").exists() and origin == "None"


def test_the_quick_install_gives_the_venv_its_own_pip_where_the_interpreter_has_none(tmp_path):
    """An interpreter without pip (here a venv made without it) cannot install into another environment: the
    venv is made with pip, as before."""
    bare = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(bare)], check=True)
    venv = tmp_path / "venv"
    origin, purelib = _install(venv, str(bare / "bin" / "python"), tmp_path)
    assert _has_pip(venv)
    assert (purelib / "monte").resolve() == ROOT and Path(origin).resolve() == ROOT / "__init__.py"
