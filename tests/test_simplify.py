"""Render > Simplify as Monte renders it.

Max Subdivision (and Child Particles) are applied by Blender's depsgraph for the render: the engine's export
sees the simplified geometry, checked here by the triangles a render through Blender's operator exports from a
cube with a Subdivision Surface modifier and from the child particles (shown as objects) of an emitter.
Cycles' own Simplify settings (Texture Limit, Texture Resolution, AO Bounces) are named in a warning
(tests/test_never_silently_different.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_fixtures as bf  # noqa: E402

from monte.addon import engine  # noqa: E402
from monte.addon.engine import render_with_operator  # noqa: E402

pytestmark = [pytest.mark.blender]


def subdivided_cube():
    """A cube (6 quads) with a Subdivision Surface modifier: 1 level in the viewport, 3 for the render."""
    scene = bf.reset()
    v = [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    cube = bf.mesh_object("cube", v, f, bf.diffuse("cube", (0.5, 0.5, 0.5)))
    mod = cube.modifiers.new("subdivision", "SUBSURF")
    mod.levels, mod.render_levels = 1, 3
    bf.camera_object(scene, (0, -6, 0), (1.5708, 0, 0))
    bf.set_world(scene, (0.5, 0.5, 0.5), 1.0)
    scene.render.resolution_x, scene.render.resolution_y = 8, 8
    scene.render.resolution_percentage = 100
    scene.render.engine = "MONTE"
    scene.monte.samples, scene.monte.threads = 1, 1
    return scene


def rendered_triangles(scene, monkeypatch) -> int:
    """Triangles the engine exported for one render through Blender's operator (the real export, its result
    recorded on the way out)."""
    seen = []
    real = engine.export_scene

    def recording(*args, **kwargs):
        out = real(*args, **kwargs)
        seen.append(out[1].triangles)
        return out

    monkeypatch.setattr(engine, "export_scene", recording)
    render_with_operator(scene)
    monkeypatch.setattr(engine, "export_scene", real)
    assert len(seen) == 1
    return seen[0]


def test_max_subdivision_reaches_the_render(monkeypatch):
    scene = subdivided_cube()
    quads = 6
    assert rendered_triangles(scene, monkeypatch) == quads * 4**3 * 2  # the modifier's render levels
    scene.render.use_simplify = True
    scene.render.simplify_subdivision_render = 2
    scene.render.simplify_subdivision = 0  # the viewport's: not the render's
    assert rendered_triangles(scene, monkeypatch) == quads * 4**2 * 2
    scene.render.simplify_subdivision_render = 0
    assert rendered_triangles(scene, monkeypatch) == quads * 2


def particle_children_scene():
    """subdivided_cube's scene with its cube replaced by a plane emitting 5 particles shown as a small cube object,
    each with 8 simple children (rendered as objects: no hair), all at frame 1."""
    scene = subdivided_cube()
    bpy.data.objects.remove(bpy.data.objects["cube"])
    emitter = bf.mesh_object("emitter", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)],
                             bf.diffuse("emitter", (0.5, 0.5, 0.5)))
    v = [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    piece = bf.mesh_object("piece", v, f, bf.diffuse("piece", (0.8, 0.2, 0.2)))
    piece.location.z = 50.0  # the instanced object itself out of view, its instances counted all the same
    piece.hide_render = True
    settings = emitter.modifiers.new("particles", "PARTICLE_SYSTEM").particle_system.settings
    settings.count, settings.frame_start, settings.frame_end, settings.lifetime = 5, 1, 1, 1000
    settings.render_type, settings.instance_object, settings.particle_size = "OBJECT", piece, 0.05
    settings.child_type, settings.child_percent, settings.rendered_child_count = "SIMPLE", 8, 8
    emitter.show_instancer_for_render = True
    scene.frame_set(1)
    return scene


def test_child_particles_reach_the_render(monkeypatch):
    """Simplify > Child Particles (render) scales the children Blender makes for the render: Monte renders what
    the depsgraph gives, as Cycles does. 5 parents x 8 children (children replace their parents) of a 12-triangle
    cube, over the 2-triangle emitter; half the children with Child Particles 0.5."""
    scene = particle_children_scene()
    emitter_tris, piece_tris = 2, 12
    full = rendered_triangles(scene, monkeypatch)
    assert full == emitter_tris + 5 * 8 * piece_tris
    scene.render.use_simplify = True
    scene.render.simplify_child_particles_render = 0.5
    assert rendered_triangles(scene, monkeypatch) == emitter_tris + 5 * 4 * piece_tris
