"""Built-in scenes: the seed's Cornell box first, and small analytic scenes with closed-form answers.

Every builder returns a fresh `Scene` (Z up, metres, Blender's conventions) and accepts a resolution.
"""

from __future__ import annotations

import math
from functools import lru_cache
from importlib import resources
from typing import Callable

import numpy as np

from .scene import Camera, Lobe, Material, Mesh, PointLight, Scene, SunLight, World


@lru_cache(maxsize=1)
def _icosphere_unit() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unit icosphere Blender builds with bmesh.ops.create_icosphere(subdivisions=5, radius=1): 2562
    vertices, 5120 triangles, with Blender's smooth vertex normals, so Monte and Cycles see the same mesh."""
    with resources.files(__package__).joinpath("data/icosphere5.npz").open("rb") as f:
        data = np.load(f)
        return data["vertices"].astype(np.float64), data["triangles"].astype(np.int32), data["normals"]


def icosphere(name: str, center, radius: float, material: int, smooth: bool = True) -> Mesh:
    """A smooth-shaded icosphere mesh (Blender's subdivision-5 icosphere scaled and moved)."""
    verts, tris, normals = _icosphere_unit()
    center = np.asarray(center, dtype=np.float64)
    corner_normals = normals[tris] if smooth else None
    return Mesh(name, verts * radius + center, tris.copy(), material, normals=corner_normals)


def quad(name: str, corners, material: int) -> Mesh:
    """Two triangles over corners given counter-clockwise as seen from the side the normal points to."""
    v = np.asarray(corners, dtype=np.float64)
    return Mesh(name, v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), material)


def cornell_box(resolution: tuple[int, int] = (256, 256), mirror: str = "glossy") -> Scene:
    """The seed's Cornell box: box x, y in [-1, 1], z in [0, 2], open at y = -1; a square lamp
    of radiance 12 under the ceiling; a mirror sphere and a glass sphere; camera at (0, -3.9, 1) looking
    along +y with a 39 degree horizontal field of view.

    mirror: "glossy" = Blender's Glossy BSDF at roughness 0 (constant reflectance 0.999, as the Cycles
    reference); "schlick" = the seed's specular conductor: Schlick Fresnel with F0 from IOR 1.5, tinted 0.999.
    """
    white, red, blue = (0.75, 0.75, 0.75), (0.75, 0.25, 0.25), (0.25, 0.25, 0.75)
    fresnel = "none" if mirror == "glossy" else "schlick"
    materials = [
        Material("white", [Lobe("diffuse", np.array(white))]),
        Material("red", [Lobe("diffuse", np.array(red))]),
        Material("blue", [Lobe("diffuse", np.array(blue))]),
        Material("lamp", [Lobe("diffuse", np.zeros(3))], emission=np.full(3, 12.0)),
        Material("mirror", [Lobe("glossy", np.full(3, 0.999), roughness=0.0, fresnel=fresnel, ior=1.5)]),
        Material("glass", [Lobe("glass", np.full(3, 0.999), roughness=0.0, ior=1.5)]),
    ]
    meshes = [
        quad("floor", [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], 0),
        quad("ceiling", [(-1, -1, 2), (-1, 1, 2), (1, 1, 2), (1, -1, 2)], 0),
        quad("back", [(-1, 1, 0), (1, 1, 0), (1, 1, 2), (-1, 1, 2)], 0),
        quad("left", [(-1, -1, 0), (-1, 1, 0), (-1, 1, 2), (-1, -1, 2)], 1),
        quad("right", [(1, -1, 0), (1, -1, 2), (1, 1, 2), (1, 1, 0)], 2),
        quad("lamp", [(-0.3, -0.3, 1.98), (-0.3, 0.3, 1.98), (0.3, 0.3, 1.98), (0.3, -0.3, 1.98)], 3),
        icosphere("mirror_sphere", (-0.45, 0.35, 0.35), 0.35, 4),
        icosphere("glass_sphere", (0.45, -0.2, 0.35), 0.35, 5),
    ]
    camera = Camera.look_at((0, -3.9, 1), (0, 0, 1), horizontal_fov=math.radians(39.0), resolution=resolution)
    return Scene(camera=camera, meshes=meshes, materials=materials, name="cornell")


def cornell_diffuse(resolution: tuple[int, int] = (256, 256)) -> Scene:
    """The Cornell box with both spheres diffuse white: a diffuse-only interior for benchmarks."""
    scene = cornell_box(resolution)
    scene.materials[4] = Material("sphere_a", [Lobe("diffuse", np.array((0.75, 0.75, 0.75)))])
    scene.materials[5] = Material("sphere_b", [Lobe("diffuse", np.array((0.75, 0.75, 0.75)))])
    scene.name = "cornell-diffuse"
    return scene


def furnace(resolution: tuple[int, int] = (32, 32), albedo: float = 0.5, emission: float = 1.0) -> Scene:
    """A closed diffuse sphere (radius 1, normals inward) of albedo a and emission Le everywhere, seen from
    its centre: every pixel's radiance is Le / (1 - a) with unlimited bounces, or
    Le (1 - a^(B+2)) / (1 - a) with Cycles' max_bounces B."""
    verts, tris, _ = _icosphere_unit()
    mesh = Mesh("furnace", verts.copy(), tris[:, ::-1].copy(), 0)  # reversed winding: normals face inward
    mat = Material("furnace", [Lobe("diffuse", np.full(3, albedo))], emission=np.full(3, emission))
    camera = Camera.look_at((0, 0, 0), (0, 1, 0), horizontal_fov=math.radians(60.0), resolution=resolution)
    return Scene(camera=camera, meshes=[mesh], materials=[mat], name="furnace")


def plane_under_world(resolution: tuple[int, int] = (32, 32), albedo: float = 0.8, world: float = 1.0) -> Scene:
    """A large diffuse plane of albedo rho under a uniform world of radiance Lw, seen from above: the plane's
    radiance is rho x Lw (one bounce; it sees only the sky)."""
    s = 1000.0
    mesh = quad("plane", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], 0)
    mat = Material("plane", [Lobe("diffuse", np.full(3, albedo))])
    camera = Camera.look_at((0, 0, 1), (0, 0, 0), up=(0, 1, 0), horizontal_fov=math.radians(40.0),
                            resolution=resolution)
    return Scene(camera=camera, meshes=[mesh], materials=[mat], world=World(np.full(3, world)), name="plane-world")


def point_in_sphere(resolution: tuple[int, int] = (32, 32), albedo: float = 0.5, power: float = 100.0) -> Scene:
    """A point light of power P at the centre of a closed diffuse sphere of radius R = 1 (normals inward):
    walls have radiance rho P / (4 pi^2 R^2 (1 - rho)) once all bounces are counted."""
    verts, tris, _ = _icosphere_unit()
    mesh = Mesh("sphere", verts.copy(), tris[:, ::-1].copy(), 0)
    mat = Material("wall", [Lobe("diffuse", np.full(3, albedo))])
    camera = Camera.look_at((0, 0, 0), (0, 1, 0), horizontal_fov=math.radians(60.0), resolution=resolution)
    light = PointLight("lamp", np.zeros(3), np.full(3, power), radius=0.0)
    return Scene(camera=camera, meshes=[mesh], materials=[mat], lights=[light], name="point-in-sphere")


def spheres_under_sky(resolution: tuple[int, int] = (256, 256)) -> Scene:
    """Three spheres (red and white diffuse, rough glossy) on a 40 m diffuse ground under a sun (3 W/m^2,
    2 degrees) and a pale blue sky, seen so that the sky fills the top third: pixels converge at very different
    rates (the sky after the first samples, sun-lit ground soon, shadows and the glossy sphere last), the case
    adaptive sampling is for. No glass or mirror: their sun caustics would be fireflies that swamp the error."""
    materials = [
        Material("ground", [Lobe("diffuse", np.array((0.5, 0.48, 0.45)))]),
        Material("clay", [Lobe("diffuse", np.array((0.7, 0.25, 0.15)))]),
        Material("metal", [Lobe("glossy", np.array((0.9, 0.8, 0.5)), roughness=0.3)]),
        Material("white", [Lobe("diffuse", np.full(3, 0.8))]),
    ]
    meshes = [
        quad("ground", [(-20, -20, 0), (20, -20, 0), (20, 20, 0), (-20, 20, 0)], 0),
        icosphere("clay_sphere", (-1.1, 0.3, 0.5), 0.5, 1),
        icosphere("metal_sphere", (0.0, 0.8, 0.5), 0.5, 2),
        icosphere("white_sphere", (1.1, 0.0, 0.5), 0.5, 3),
    ]
    sun_dir = -np.array((0.4, -0.3, 0.85)) / np.linalg.norm((0.4, -0.3, 0.85))
    lights = [SunLight("sun", sun_dir, np.full(3, 3.0), angle=math.radians(2.0))]
    camera = Camera.look_at((0, -5.5, 1.6), (0, 0.5, 0.9), horizontal_fov=math.radians(50.0), resolution=resolution)
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=lights,
                 world=World(np.array((0.35, 0.45, 0.6))), name="spheres-sky")


BUILTIN_SCENES: dict[str, tuple[Callable[..., Scene], str]] = {
    "cornell": (cornell_box, "the seed's Cornell box: diffuse walls, square lamp, mirror and glass spheres"),
    "cornell-diffuse": (cornell_diffuse, "the Cornell box with both spheres diffuse (diffuse-only interior)"),
    "furnace": (furnace, "closed diffuse emitting sphere: radiance Le/(1-albedo) everywhere"),
    "plane-world": (plane_under_world, "diffuse plane under a uniform sky: radiance albedo x sky"),
    "point-in-sphere": (point_in_sphere, "point light inside a closed diffuse sphere"),
    "spheres-sky": (spheres_under_sky, "diffuse and glossy spheres on a ground under sun and sky"),
}


def builtin_scene(name: str, resolution: tuple[int, int] | None = None) -> Scene:
    """Build a built-in scene by name (see BUILTIN_SCENES); a ValueError lists the names on a typo."""
    if name not in BUILTIN_SCENES:
        raise ValueError(f"unknown built-in scene {name!r}; built-in scenes: {', '.join(BUILTIN_SCENES)}")
    builder, _ = BUILTIN_SCENES[name]
    return builder(resolution) if resolution else builder()
