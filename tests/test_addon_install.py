"""The built extension zip installs and works the way a user gets it: Blender's extension machinery, a fresh
user repository, F12 with write_still. Runs Blender (the bpy module) in a subprocess, since
BLENDER_USER_RESOURCES must be set before bpy is first imported and this process may have imported it."""

from __future__ import annotations

import functools
import importlib.util
import json
import os
import platform
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plane_scene import PLANE_SCENE  # noqa: E402

pytest.importorskip("bpy")
pytestmark = [pytest.mark.blender, pytest.mark.matrix]  # on every Blender of the support table
ROOT = Path(__file__).resolve().parent.parent

_THIS_PLATFORM = {("Linux", "x86_64"): "linux-x64", ("Windows", "AMD64"): "windows-x64",
                  ("Darwin", "x86_64"): "macos-x64", ("Darwin", "arm64"): "macos-arm64"}.get(
    (platform.system(), platform.machine()))

SCRIPT = textwrap.dedent(r"""
    import json, os, sys
    import bpy  # BLENDER_USER_RESOURCES is already set in the environment
    zip_path, out_dir = sys.argv[1], sys.argv[2]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    res = bpy.ops.extensions.package_install_files(repo="user_default", filepath=zip_path, enable_on_install=True)
    engines = sorted(str(getattr(c, "bl_idname", None)) for c in bpy.types.RenderEngine.__subclasses__())
    module = sys.modules.get("bl_ext.user_default.monte")
    # The cluster render's packages came with the zip: distributed (and everything it imports) imports from the
    # extension's site-packages alone (-S: none of this interpreter's own site-packages).
    import subprocess
    ext_sites = [os.path.join(r, d) for r, dirs, _ in os.walk(os.environ["BLENDER_USER_RESOURCES"]) for d in dirs
                 if d == "site-packages"]
    probe = subprocess.run([sys.executable, "-S", "-c", "import sys; sys.path[:0] = sys.argv[1:]; "
                            "import distributed; from distributed import Client, LocalCluster; "
                            "print(distributed.__version__, distributed.__file__)", *ext_sites],
                           capture_output=True, text=True)
    distributed_import = (probe.stdout.strip() or probe.stderr.strip()[-1000:]).split(" ", 1)

    with_camera = True
    # PLANE_SCENE
    scene.render.engine = "MONTE"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 16, 16, 100
    scene.monte.samples, scene.monte.threads = 16, 2
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = os.path.join(out_dir, "plane")
    rendered = bpy.ops.render.render(write_still=True)

    import numpy as np, OpenEXR
    with OpenEXR.File(os.path.join(out_dir, "plane.exr")) as f:
        px = np.asarray(f.channels()["RGBA"].pixels, dtype=np.float64)
    def selectable():
        try:
            scene.render.engine = "MONTE"
            return True
        except TypeError:  # not an engine Blender knows
            return False

    # The renderer called Embree directly (the library found next to the embreex the extension installed).
    library, why_not = sys.modules["bl_ext.user_default.monte.core.embree"].load()
    # What the render compiled and what it loaded from the kernel cache shipped in the zip.
    import importlib
    precompile = importlib.import_module("bl_ext.user_default.monte.core.precompile")
    kernels = precompile.kernel_cache_counts()

    # A first textured render: the plane's albedo from a node program (0.5 + 0 x Generated X: never folded to a
    # constant at export) under an environment map (a constant image of radiance 1): image 0.5 again.
    tree.nodes.remove(dif)
    coord, sep = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeSeparateXYZ")
    times, plus = tree.nodes.new("ShaderNodeMath"), tree.nodes.new("ShaderNodeMath")
    times.operation, plus.operation = "MULTIPLY", "ADD"
    times.inputs[1].default_value, plus.inputs[1].default_value = 0.0, 0.5
    textured = tree.nodes.new("ShaderNodeBsdfDiffuse")
    tree.links.new(coord.outputs["Generated"], sep.inputs[0])
    tree.links.new(sep.outputs["X"], times.inputs[0])
    tree.links.new(times.outputs[0], plus.inputs[0])
    tree.links.new(plus.outputs[0], textured.inputs["Color"])
    tree.links.new(textured.outputs[0], out.inputs["Surface"])
    env_image = bpy.data.images.new("sky", 16, 8, float_buffer=True)
    env_image.pixels = [1.0] * (16 * 8 * 4)
    wtree = world.node_tree
    env = wtree.nodes.new("ShaderNodeTexEnvironment")
    env.image = env_image
    wtree.links.new(env.outputs["Color"], wtree.nodes["Background"].inputs["Color"])
    scene.render.filepath = os.path.join(out_dir, "textured")
    textured_render = bpy.ops.render.render(write_still=True)
    with OpenEXR.File(os.path.join(out_dir, "textured.exr")) as f:
        textured_px = np.asarray(f.channels()["RGBA"].pixels, dtype=np.float64)
    textured_kernels = precompile.kernel_cache_counts()
    # the feature kernels that render ran: [signatures loaded from the cache, signatures compiled] of each
    feature_kernels = {f"{d.py_func.__module__.rpartition('.')[2]}.{d.py_func.__name__}":
                       [sum(d.stats.cache_hits.values()), sum(d.stats.cache_misses.values())]
                       for d in precompile._dispatchers() if d.signatures
                       and d.py_func.__name__ in ("run_programs", "importance_grid")}

    before = selectable()
    bpy.ops.preferences.addon_disable(module="bl_ext.user_default.monte")
    after = selectable()
    print("RESULT " + json.dumps({
        "install": sorted(res), "engines": engines, "module_file": getattr(module, "__file__", None),
        "render": sorted(rendered), "shape": list(px.shape), "mean_rgb": px[..., :3].mean(),
        "alpha": px[..., 3].mean(), "menu_before_disable": before, "menu_after_disable": after,
        "embree_library": library.path if library else None, "embree_error": why_not, "kernels": kernels,
        "textured_render": sorted(textured_render), "textured_mean_rgb": textured_px[..., :3].mean(),
        "textured_kernels": textured_kernels, "feature_kernels": feature_kernels,
        "distributed_import": distributed_import,
        "kernel_cpu": sys.modules["bl_ext.user_default.monte.core.jit_cache"].KERNEL_CPU,
    }))
""").replace("# PLANE_SCENE\n", PLANE_SCENE)  # the plane under a white world (tests/plane_scene.py)


@pytest.fixture(scope="module")
def built_zip(tmp_path_factory):
    if _THIS_PLATFORM is None:
        pytest.skip(f"no Monte extension build for {platform.system()} {platform.machine()}")
    out = tmp_path_factory.mktemp("dist")
    # (the build compiles every kernel, feature kernels included: ~3-4 minutes of CPU, far more wall time on a
    # loaded machine)
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "build_extension.py"), "--platform", _THIS_PLATFORM,
                           "--output-dir", str(out)], capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:  # offline too: a failure that says so, never a skip (the wheels are cached in wheels/)
        hint = ("\nThe bundled wheels could not be downloaded: run `make extension` once online, or put the "
                "manifest's wheel files into wheels/.") if "pip download failed" in proc.stderr else ""
        pytest.fail(f"build_extension.py failed:{hint}\n{proc.stdout}\n{proc.stderr}")
    zips = sorted(out.glob(f"monte-*-{_THIS_PLATFORM.replace('-', '_')}.zip"))
    assert len(zips) == 1, proc.stdout
    return zips[0]


@functools.cache
def _build_module():
    """tools/build_extension.py, loaded once (it is a script, not a package module)."""
    spec = importlib.util.spec_from_file_location("build_extension", ROOT / "tools" / "build_extension.py")
    build = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build)
    return build


def _bytecode_pythons() -> list[str]:
    """The Python versions the build compiled the add-on's bytecode for: those of the manifest it found an
    interpreter of (as tools/build_extension.py finds them)."""
    build = _build_module()
    versions = build.manifest_pythons(build.load_manifest(), [_THIS_PLATFORM])
    return sorted(build.find_interpreters(versions, [sys.executable]))


def _pyc_name(source: str, tag: str) -> str:
    return _build_module().pyc_name(source, tag)


def test_zip_holds_only_the_add_on(built_zip):

    names = zipfile.ZipFile(built_zip).namelist()
    tops = {n.split("/", 1)[0] for n in names}
    assert tops == {"__init__.py", "__pycache__", "blender_manifest.toml", "LICENSE", "core", "addon", "wheels"}
    # The compiled kernels for this Python, built under the name Blender imports the extension as: an index
    # per kernel module.
    cache = "core/__pycache__/numba-bl_ext.user_default.monte.core/"
    tag = f"py{sys.version_info[0]}{sys.version_info[1]}"
    from monte.core.jit_cache import KERNEL_MODULES

    # every kernel module's, those of node programs, environment maps and ray visibility included
    for module in KERNEL_MODULES:
        name = module.rpartition("/")[2]
        assert any(n.startswith(f"{cache}{name}.") and n.endswith(f".{tag}.nbi") for n in names), module
    assert any(n.startswith(cache) and n.endswith(".nbc") for n in names)
    # numba's runtime module (NRT) compiled for the same CPU level, so the first process builds nothing with LLVM
    assert any(n.startswith(f"{cache}nrt-") and n.endswith(".bin") for n in names)
    # The add-on's bytecode beside every source, for this Python and each other Python of the manifest the build
    # found (Blender 4.2 - 5.0's 3.11, 5.3's 3.13), and nothing else in a __pycache__ folder.
    tags = {f"cpython-{v.replace('.', '')}" for v in _bytecode_pythons()}
    assert sys.implementation.cache_tag in tags
    sources = [n for n in names if n.endswith(".py") and not n.startswith("wheels/")]
    assert len(sources) > 50 and "core/render.py" in sources and "__init__.py" in sources
    pycs = {_pyc_name(n, tag) for n in sources for tag in tags}
    assert pycs <= set(names), sorted(pycs - set(names))[:5]
    assert all(n.startswith(cache) or n in pycs for n in names if "__pycache__" in n)
    with zipfile.ZipFile(built_zip) as zf:
        for n in sources:  # checked-hash pycs (PEP 552) of the sources shipped: an edited source wins
            for tag in tags:
                header = zf.read(_pyc_name(n, tag))[:16]
                assert int.from_bytes(header[4:8], "little") == 0b11, (n, tag)  # hash-based, checked
            # this Python's: of the source shipped (the hash is keyed by the Python version that wrote it)
            header = zf.read(_pyc_name(n, sys.implementation.cache_tag))[:16]
            assert header[:4] == importlib.util.MAGIC_NUMBER
            assert header[8:16] == importlib.util.source_hash(zf.read(n)), n
    wheels = sorted(Path(n).name for n in names if n.endswith(".whl"))
    # Each compiled dependency for both Pythons Blender bundles: cp311 (Blender 4.2 - 5.0) and cp313 (Blender
    # 5.3); the cluster render's stable-ABI wheels once (cp311 and newer) and its pure-Python ones once.
    tags = sorted((w.split("-")[0], w.split("-")[2]) for w in wheels if w.split("-")[3] != "abi3" and
                  not w.endswith("-none-any.whl"))
    assert tags == [(name, py) for name in ("embreex", "llvmlite", "markupsafe", "msgpack", "numba", "openexr",
                                            "pyyaml") for py in ("cp311", "cp313")]
    assert sorted(w.split("-")[0] for w in wheels if w.split("-")[3] == "abi3") == ["psutil", "tornado"]
    assert sorted(w.split("-")[0] for w in wheels if w.endswith("-none-any.whl")) == [
        "click", "cloudpickle", "dask", "distributed", "fsspec", "importlib_metadata", "jinja2", "locket",
        "packaging", "partd", "sortedcontainers", "tblib", "toolz", "zict", "zipp"]
    assert not any(n.startswith(("tests/", "tools/", ".venv", "dist/")) for n in names)


def test_a_second_build_ships_the_kernels_the_first_one_kept(built_zip, tmp_path):
    """The fixture's build kept the kernels it compiled in build/kernel-cache/ (or took ones an earlier build had
    kept): a second build of the same sources copies them instead of compiling, and its zip's kernel cache is the
    first one's, file for file and byte for byte."""
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "build_extension.py"), "--platform", _THIS_PLATFORM,
                           "--output-dir", str(tmp_path)], capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    assert "the one an earlier build compiled for these sources" in proc.stdout
    assert "kernel cache: compiling" not in proc.stdout
    (second,) = tmp_path.glob(f"monte-*-{_THIS_PLATFORM.replace('-', '_')}.zip")
    cache = "core/__pycache__/numba-bl_ext.user_default.monte.core/"
    with zipfile.ZipFile(built_zip) as first_zip, zipfile.ZipFile(second) as second_zip:
        first = {n: first_zip.read(n) for n in first_zip.namelist() if n.startswith(cache)}
        again = {n: second_zip.read(n) for n in second_zip.namelist() if n.startswith(cache)}
    assert len(first) > 300 and first.keys() == again.keys()
    assert [n for n in first if first[n] != again[n]] == []


def test_kept_kernel_builds_are_replaced_whole_and_only_the_newest_stay(tmp_path, monkeypatch):
    """keep_kernel_build: a key kept again (--recompile-kernels) holds the new files only, nothing half-written
    or set aside is left, and past KEPT_KERNEL_BUILDS keys the least recently kept go."""
    build = _build_module()
    monkeypatch.setattr(build, "KERNEL_BUILDS", tmp_path / "kept")
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "a.nbi").write_bytes(b"first")
    (cache / "b.nbc").write_bytes(b"other")
    build.keep_kernel_build(cache, ["a.nbi", "b.nbc"], "k0")
    (cache / "a.nbi").write_bytes(b"second")
    build.keep_kernel_build(cache, ["a.nbi"], "k0")
    assert sorted(p.name for p in (tmp_path / "kept").iterdir()) == ["k0"]
    assert [(p.name, p.read_bytes()) for p in (tmp_path / "kept" / "k0").iterdir()] == [("a.nbi", b"second")]
    for i in range(1, build.KEPT_KERNEL_BUILDS + 2):
        os.utime(tmp_path / "kept" / f"k{i - 1}", (i, i))  # (each earlier than the next)
        build.keep_kernel_build(cache, ["a.nbi"], f"k{i}")
    kept = sorted(int(p.name[1:]) for p in (tmp_path / "kept").iterdir())
    assert kept == list(range(2, build.KEPT_KERNEL_BUILDS + 2))


def _install_and_render(built_zip: Path, tmp_path: Path, **env_vars: str) -> dict:
    """SCRIPT in a new Blender process with an empty user folder: what installing the zip and two first renders
    gave."""
    user = tmp_path / "user"
    out = tmp_path / "out"
    user.mkdir()
    out.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != "MONTE_KERNEL_CPU"}
    env.update(BLENDER_USER_RESOURCES=str(user), **env_vars)
    env.pop("PYTHONPATH", None)
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(built_zip), str(out)], capture_output=True, text=True,
                          timeout=600, env=env, cwd=str(tmp_path))
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return json.loads(lines[-1][len("RESULT "):])


def _host_kernel_level() -> str:
    """The CPU level this machine's kernels are compiled for by default (tests/test_jit_cache.py checks it)."""
    from monte.core.jit_cache import _host_level

    return _host_level()


def test_zip_installs_enables_and_renders(built_zip, tmp_path):
    result = _install_and_render(built_zip, tmp_path)
    user = tmp_path / "user"
    assert result["kernel_cpu"] == _host_kernel_level()
    assert result["install"] == ["FINISHED"]
    assert "MONTE" in result["engines"]
    # The engine came from the installed zip, not from this checkout.
    assert result["module_file"] and str(user) in result["module_file"]
    assert result["render"] == ["FINISHED"]
    assert result["shape"] == [16, 16, 4]
    assert result["alpha"] == pytest.approx(1.0)
    # A diffuse plane of albedo 0.5 under a uniform white world: radiance 0.5 (16 spp of noise allowed).
    assert result["mean_rgb"] == pytest.approx(0.5, abs=0.03)
    assert result["menu_before_disable"] and not result["menu_after_disable"]
    assert result["embree_error"] is None and "embree4" in Path(result["embree_library"]).name
    # The first render after installing loaded every kernel it ran from the zip's cache and compiled none.
    assert result["kernels"]["compiled"] == 0, result["kernels"]
    assert result["kernels"]["loaded"] > 0
    # So did the first render with a node material and an environment map: their kernels are in the zip too.
    assert result["textured_render"] == ["FINISHED"]
    # (by the render, or earlier by the add-on's background loading of the cached kernels: either way from the zip)
    features = result["feature_kernels"]
    assert sorted(features) == ["evaluator.run_programs", "world_kernels.importance_grid"], features
    assert all(loaded > 0 and compiled == 0 for loaded, compiled in features.values()), features
    assert result["textured_kernels"]["compiled"] == 0, result["textured_kernels"]
    # albedo 0.5 from the program under a world of radiance 1 (16 spp, MIS with the map's sampling)
    assert result["textured_mean_rgb"] == pytest.approx(0.5, abs=0.03)
    # Render Properties > Cluster works offline: distributed came with the zip, pinned as requirements/common.txt.
    version, where = result["distributed_import"]
    common = (ROOT / "requirements" / "common.txt").read_text().splitlines()
    pinned = next(line.split("==")[1].strip() for line in common if line.startswith("distributed=="))
    assert version == pinned and where.startswith(str(user)), result["distributed_import"]


def test_a_cpu_without_avx2_loads_the_zip_s_generic_kernels(built_zip, tmp_path):
    """The zip carries the kernels for this machine's CPU level and for the architecture's generic one (the build's
    --kernel-cpu all): a CPU without x86-64-v3's AVX2, FMA and BMI2 (here: MONTE_KERNEL_CPU=generic, the level such
    a CPU picks) loads them too, and its first renders after installing compile nothing."""
    if _host_kernel_level() == "generic":
        pytest.skip("this machine's kernels are the generic level already (test_zip_installs_enables_and_renders)")
    result = _install_and_render(built_zip, tmp_path, MONTE_KERNEL_CPU="generic")
    assert result["kernel_cpu"] == "generic"
    assert result["render"] == ["FINISHED"] and result["textured_render"] == ["FINISHED"]
    assert result["kernels"]["compiled"] == 0 and result["kernels"]["loaded"] > 0, result["kernels"]
    assert result["textured_kernels"]["compiled"] == 0, result["textured_kernels"]
    assert all(compiled == 0 for _, compiled in result["feature_kernels"].values()), result["feature_kernels"]
    assert result["mean_rgb"] == pytest.approx(0.5, abs=0.03)
    assert result["textured_mean_rgb"] == pytest.approx(0.5, abs=0.03)


# Imports the unpacked extension as Blender names it, with the render's wheels (unpacked as Blender unpacks
# them) first on the path, and lists the sources Python compiled (none where the shipped bytecode served).
_IMPORT = textwrap.dedent("""
    import importlib, importlib._bootstrap_external as be, json, pkgutil, sys
    root = sys.argv[1]
    sys.path[:0] = [root, root + "/site"]
    compiled = []
    source_to_code = be.SourceLoader.source_to_code
    def counting(self, data, path, *args, **kwargs):
        compiled.append(path)
        return source_to_code(self, data, path, *args, **kwargs)
    be.SourceLoader.source_to_code = counting
    import numba, llvmlite, yaml
    core = importlib.import_module("bl_ext.user_default.monte.core")
    modules = [m.name for m in pkgutil.walk_packages(core.__path__, core.__name__ + ".")]
    for name in modules:
        importlib.import_module(name)
    mine = sorted(p[len(root) + 1:] for p in compiled if p.startswith(root) and "/bl_ext/user_default/monte/" in p)
    wheels = sorted({p[len(root) + 6:].split("/")[0] for p in compiled if p.startswith(root + "/site/")})
    print("RESULT " + json.dumps({"modules": len(modules), "numba": numba.__file__, "compiled": mine,
                                  "wheels_compiled": wheels,
                                  "edited": getattr(sys.modules["bl_ext.user_default.monte.core.camera"],
                                                    "MONTE_EDITED", None)}))
""")


def test_shipped_bytecode_serves_and_an_edited_source_wins(built_zip, tmp_path):
    """The extension's bytecode, and that of the wheels a render imports, is what Python uses after unpacking
    (no module of them compiled, as in the first process after installing), and a source edited after
    installing is compiled and run, not its stale bytecode (checked-hash pycs)."""
    ext = tmp_path / "bl_ext" / "user_default" / "monte"
    site = tmp_path / "site"
    tag = f"cp{sys.version_info[0]}{sys.version_info[1]}"
    with zipfile.ZipFile(built_zip) as zf:
        zf.extractall(ext, [n for n in zf.namelist() if not n.startswith("wheels/")])
        for n in zf.namelist():  # the render's wheels for this Python, unpacked file by file (zip times: new)
            w = Path(n).name
            if n.startswith("wheels/") and w.split("-")[0] in ("numba", "llvmlite", "pyyaml") and \
                    w.split("-")[2] == tag:
                zf.extract(n, tmp_path / "whl")
                with zipfile.ZipFile(tmp_path / "whl" / n) as wheel:
                    wheel.extractall(site)
    for pkg in (tmp_path / "bl_ext", tmp_path / "bl_ext" / "user_default"):
        (pkg / "__init__.py").write_text("")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "NUMBA_"))}

    def run() -> dict:
        proc = subprocess.run([sys.executable, "-c", _IMPORT, str(tmp_path)], capture_output=True, text=True,
                              env=env, timeout=600)
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        assert proc.returncode == 0 and lines, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        return json.loads(lines[-1][len("RESULT "):])

    first = run()
    assert first["numba"].startswith(str(site)), first["numba"]
    assert first["modules"] > 30
    assert first["compiled"] == [] and first["wheels_compiled"] == [], first
    assert first["edited"] is None
    camera = ext / "core" / "camera.py"
    camera.write_text(camera.read_text() + "\nMONTE_EDITED = 1\n")
    edited = run()
    assert edited["edited"] == 1
    assert edited["compiled"] == ["bl_ext/user_default/monte/core/camera.py"], edited
