"""Blender world -> core World: a uniform background of radiance colour x strength.

Supported: the active World Output's Surface linked to a Background node (colour and strength unlinked, or
the colour from an Image/Environment texture, replaced by its average colour with a warning); no node tree:
the world's viewport colour; no world at all: black.
"""

from __future__ import annotations

import numpy as np

from ...core.scene import World
from .material import follow_link, image_average_color, node_tree, socket_value


def export_world(world, warnings: list[str]) -> World:
    if world is None:
        return World(np.zeros(3))
    name = world.name
    visibility = getattr(world, "cycles_visibility", None)
    if visibility is not None:
        off = [label for prop, label in (("camera", "Camera"), ("diffuse", "Diffuse"), ("glossy", "Glossy"),
                                         ("transmission", "Transmission"), ("scatter", "Volume Scatter"))
               if not getattr(visibility, prop, True)]
        if off:
            warnings.append(f"world {name!r}: Ray Visibility {', '.join(off)} off is not supported; the world is "
                            "seen by every ray")
    tree = node_tree(world)
    if tree is None:
        return World(np.array(world.color[:3], dtype=np.float64))
    output = tree.get_output_node("CYCLES")
    if output is None:
        warnings.append(f"world {name!r}: no active World Output node; the background is black")
        return World(np.zeros(3))
    volume = output.inputs.get("Volume")
    if volume is not None and volume.is_linked:
        warnings.append(f"world {name!r}: world volumes are not supported; the volume shader is ignored")
    surface = output.inputs.get("Surface")
    node = follow_link(surface)
    if node is None:
        return World(np.zeros(3))
    if node.bl_idname != "ShaderNodeBackground":
        warnings.append(f"world {name!r}: node {node.name!r} ({node.bl_label}) is not supported on the world "
                        "surface; using the world's viewport colour as a uniform background")
        return World(np.array(world.color[:3], dtype=np.float64))
    color = _background_color(node.inputs["Color"], name, warnings)
    strength = float(socket_value(node.inputs["Strength"], f"world {name!r}", warnings))
    return World(np.maximum(color * strength, 0.0))


def _background_color(sock, world_name: str, warnings: list[str]) -> np.ndarray:
    src = follow_link(sock)
    if src is None:
        return np.array(sock.default_value[:3], dtype=np.float64)
    if src.bl_idname in ("ShaderNodeTexEnvironment", "ShaderNodeTexImage") and src.image is not None:
        avg = image_average_color(src.image)
        warnings.append(f"world {world_name!r}: texture {src.name!r} ({src.image.name}) on the background is "
                        f"not supported; using its average colour {np.round(avg, 4).tolist()}")
        return avg
    warnings.append(f"world {world_name!r}: node {src.name!r} ({src.bl_label}) driving the background colour is "
                    "not supported; using the socket's own colour")
    return np.array(sock.default_value[:3], dtype=np.float64)
