"""Blender lights -> core lights, with Blender's (and Cycles') power units.

Power = colour (x blackbody colour when "Temperature" is on) x energy x 2^exposure, as Cycles' sync_light.
Point/spot radius = shadow_soft_size; spot cone = spot_size (full angle) and spot_blend; sun angle = angle;
area shape, size, size_y and spread. Direction is the light's local -Z. An area light with "Normalize" off
emits power per unit area (Cycles multiplies by the area): Monte converts that to the equivalent power.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.scene import AreaLight, PointLight, SpotLight, SunLight
from .material import node_tree


def light_color_power(light) -> np.ndarray:
    color = np.array(light.color[:3], dtype=np.float64)
    if getattr(light, "use_temperature", False):
        color = color * np.array(light.temperature_color[:3], dtype=np.float64)
    exposure = float(getattr(light, "exposure", 0.0))
    return color * float(light.energy) * (2.0 ** exposure)


def is_portal(light) -> bool:
    """Whether an area light is a Cycles light portal (the flag sits on `light.cycles` in Blender 4.x-5.x and on
    the light itself where Blender moved it)."""
    if light.type != "AREA":
        return False
    # The original light's: a change of an add-on's setting (Cycles' is_portal) may not reach the evaluated copy
    light = getattr(light, "original", None) or light
    cycles = getattr(light, "cycles", None)
    return bool(getattr(light, "is_portal", False) or getattr(cycles, "is_portal", False))


def portal_geometry(light, matrix_world) -> np.ndarray:
    """A light portal as core.scene.World.portals holds it: (4, 3) centre, the two full edges (the light's size
    along its local x and y, object scale included; a disk or ellipse by its bounding rectangle) and the unit
    direction it lets the world in (the light's local -Z, where it would emit)."""
    m = np.array(matrix_world, dtype=np.float64).reshape(4, 4)
    size_x = float(light.size)
    size_y = float(light.size_y) if light.shape in ("RECTANGLE", "ELLIPSE") else size_x
    inward = -m[:3, 2]
    norm = np.linalg.norm(inward)
    return np.stack([m[:3, 3], m[:3, 0] * size_x, m[:3, 1] * size_y,
                     inward / norm if norm > 0 else np.zeros(3)])


def export_light(name: str, light, matrix_world, warnings: list[str]):
    """One light instance (light data + world matrix) -> core light, or None for a light Monte skips.

    A light portal is no light (None): in Cycles it emits nothing and no ray sees it; it guides the world's
    sampling (see portal_geometry and core.scene.World.portals), which changes noise, not the image."""
    if is_portal(light):
        return None
    m = np.array(matrix_world, dtype=np.float64).reshape(4, 4)
    position = m[:3, 3].copy()
    down = -m[:3, 2]
    norm = np.linalg.norm(down)
    direction = down / norm if norm > 0 else np.array([0.0, 0.0, -1.0])
    power = light_color_power(light)
    owner = f"light {name!r}"
    if node_tree(light) is not None:
        _warn_light_nodes(light, owner, warnings)
    normalize = bool(getattr(light, "normalize", True))
    if light.type == "POINT":
        if not normalize:
            warnings.append(f"{owner}: 'Normalize' off is only supported for area lights; rendered normalized")
        return PointLight(name, position, power, radius=float(light.shadow_soft_size))
    if light.type == "SPOT":
        if not normalize:
            warnings.append(f"{owner}: 'Normalize' off is only supported for area lights; rendered normalized")
        return SpotLight(name, position, direction, power, radius=float(light.shadow_soft_size),
                         spot_size=min(float(light.spot_size), math.pi), spot_blend=float(light.spot_blend))
    if light.type == "SUN":
        return SunLight(name, direction, power, angle=float(light.angle))
    if light.type == "AREA":
        size_x = float(light.size)
        size_y = float(light.size_y) if light.shape in ("RECTANGLE", "ELLIPSE") else size_x
        if not normalize:
            sx = np.linalg.norm(m[:3, 0])
            sy = np.linalg.norm(m[:3, 1])
            area = size_x * sx * size_y * sy * (math.pi / 4 if light.shape in ("DISK", "ELLIPSE") else 1.0)
            power = power * area
        return AreaLight(name, m, power, shape=light.shape, size_x=size_x, size_y=size_y,
                         spread=min(float(getattr(light, "spread", math.pi)), math.pi))
    warnings.append(f"{owner}: light type {light.type} is not supported and is skipped")
    return None


def _warn_light_nodes(light, owner: str, warnings: list[str]) -> None:
    tree = node_tree(light)
    out = tree.get_output_node("CYCLES")
    if out is None:
        return
    sock = out.inputs.get("Surface")
    if sock is None or not sock.is_linked:
        return
    node = sock.links[0].from_node
    if node.bl_idname != "ShaderNodeEmission":
        warnings.append(f"{owner}: light node {node.name!r} ({node.bl_label}) is not supported; nodes ignored")
        return
    col = node.inputs["Color"]
    stren = node.inputs["Strength"]
    if col.is_linked or stren.is_linked or any(abs(c - 1.0) > 1e-6 for c in col.default_value[:3]) \
            or abs(stren.default_value - 1.0) > 1e-6:
        warnings.append(f"{owner}: light node tree settings are ignored; using the light's colour and power")
