"""`monte render scene.blend` as a user runs it from a shell, on every Blender of the support table: the
process ends with the right status and a complete output file. (The bpy module of Blender 4.2 crashes at
interpreter exit and 4.5's hangs; Monte ends such processes itself once the output is written.)

Runs each command in a fresh process, as a shell would; `make test-install-matrix` runs this file on every
older Blender, `make test` on the newest."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plane_scene import PLANE_SCENE  # noqa: E402

pytest.importorskip("bpy")
pytestmark = [pytest.mark.blender, pytest.mark.matrix]

# The plane under a white world (tests/plane_scene.py): every pixel exactly 0.5; saved with or without a camera.
SCENE = textwrap.dedent(r"""
    import sys
    import bpy
    path, with_camera = sys.argv[1], sys.argv[2] == "1"
    bpy.ops.wm.read_factory_settings(use_empty=True)
    # PLANE_SCENE
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 12, 8, 100
    bpy.ops.wm.save_as_mainfile(filepath=path)
""").replace("# PLANE_SCENE\n", PLANE_SCENE)

TIMEOUT = 600  # a cold first render compiles Monte's kernels (about a minute on 2 cores); a hang ends here


def _run(args: list[str], cwd: Path, temp_folder: Path | None = None) -> subprocess.CompletedProcess:
    """args run by this Python in cwd; temp_folder: the process's TMPDIR (where Blender makes its session folder)."""
    env = dict(os.environ, TMPDIR=str(temp_folder)) if temp_folder is not None else None
    try:
        return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=TIMEOUT, cwd=cwd,
                              env=env)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"{' '.join(args)} did not end within {TIMEOUT} s (hung at exit?):\n{exc.stdout}\n{exc.stderr}")


@pytest.fixture(scope="module")
def blends(tmp_path_factory):
    folder = tmp_path_factory.mktemp("blends")
    paths = {}
    for name, camera in (("plane", "1"), ("no_camera", "0")):
        paths[name] = folder / f"{name}.blend"
        proc = _run(["-c", SCENE, str(paths[name]), camera], folder)
        assert proc.returncode == 0 and paths[name].is_file(), proc.stderr[-3000:]
    return paths


def test_headless_render_exits_zero_with_a_complete_exr(blends, tmp_path):
    import bpy

    from monte.core import exr

    out, temp = tmp_path / "plane.exr", tmp_path.parent / f"{tmp_path.name}-tmp"
    temp.mkdir()
    proc = _run(["-m", "monte", "render", str(blends["plane"]), "-o", str(out), "--spp", "4", "--threads", "2"],
                tmp_path, temp)
    assert proc.returncode == 0, f"Blender {bpy.app.version_string}: status {proc.returncode}\n{proc.stderr[-3000:]}"
    assert f"wrote {out}" in proc.stdout
    # Blender's own (C) output line reaches the pipe too: the quick exit flushes the C library's streams
    assert "Read blend" in proc.stdout, proc.stdout[-2000:]
    channels = exr.read_exr(out)
    assert {"R", "G", "B", "A", "albedo.R", "normal.X", "Z"} <= set(channels)
    assert "variance.R" not in channels  # only with --variance (its estimate costs the image noise)
    rgb = np.stack([channels[c] for c in "RGB"], axis=-1)
    assert rgb.shape == (8, 12, 3)
    np.testing.assert_allclose(rgb, 0.5, atol=1e-5)
    np.testing.assert_allclose(channels["Z"], 1.0, rtol=1e-5)  # the plane is 1 m below the camera
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plane.exr"]  # no temporary files left
    # Blender's session folder removed (the process ends without the interpreter's teardown, which removed it)
    assert list(temp.iterdir()) == []


def test_failed_headless_render_exits_one_and_keeps_the_existing_output(blends, tmp_path):
    out, temp = tmp_path / "keep.exr", tmp_path.parent / f"{tmp_path.name}-tmp"
    out.write_bytes(b"an earlier render")
    temp.mkdir()
    proc = _run(["-m", "monte", "render", str(blends["no_camera"]), "-o", str(out), "--spp", "1"], tmp_path, temp)
    assert proc.returncode == 1, proc.stderr[-3000:]
    assert "has no camera" in proc.stderr and "Traceback" not in proc.stderr
    assert out.read_bytes() == b"an earlier render"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.exr"]
    assert list(temp.iterdir()) == []


# end_bpy_process(status, quick_exit=True), as `monte render` ends: the exit handlers run, Blender's session
# folder goes, the process ends with the status there; with a non-daemon thread still running it returns instead
# (a normal exit waits for that thread).
QUICK_EXIT = textwrap.dedent(r"""
    import atexit, sys, threading, time
    import bpy
    from monte.addon.headless import end_bpy_process
    atexit.register(lambda: print("exit handler ran", flush=True))
    if sys.argv[1] == "thread":
        threading.Thread(target=lambda: (time.sleep(0.5), print("thread finished", flush=True))).start()
    end_bpy_process(3, quick_exit=True)
    print("returned", flush=True)
    sys.exit(4)
""")


@pytest.mark.parametrize("case", ["alone", "thread"])
def test_quick_exit_runs_the_exit_handlers_and_waits_for_threads(tmp_path, case):
    import bpy

    temp = tmp_path / "tmp"
    temp.mkdir()
    proc = _run(["-c", QUICK_EXIT, case], tmp_path, temp)
    lines = proc.stdout.splitlines()
    returns = case == "thread" and bpy.app.version >= (5, 0, 0)  # before 5.0 it ends at once, thread or not
    assert proc.returncode == (4 if returns else 3), proc.stderr[-3000:]
    if returns:
        assert lines[0] == "returned" and sorted(lines[1:]) == ["exit handler ran", "thread finished"]
    elif bpy.app.version >= (5, 0, 0):
        assert lines == ["exit handler ran"]
    else:
        assert "returned" not in lines
    assert list(temp.iterdir()) == []
