"""Everything that imports bpy: the render engine, export, properties, UI and the headless entry point.

`register()`/`unregister()` are called by the package root's (Blender's extension entry point); importing
this package alone does not register anything.
"""

from __future__ import annotations

_registered = False


def register() -> None:
    global _registered
    if _registered:
        return
    import bpy

    from . import cluster, engine, operators, properties, ui

    properties.register()
    bpy.utils.register_class(engine.MonteRenderEngine)
    operators.register()
    cluster.register()
    ui.register()
    _registered = True


def unregister() -> None:
    global _registered
    if not _registered:
        return
    import bpy

    from . import cluster, engine, operators, properties, ui

    ui.unregister()
    cluster.unregister()
    operators.unregister()
    bpy.utils.unregister_class(engine.MonteRenderEngine)
    properties.unregister()
    _registered = False


def is_registered() -> bool:
    return _registered
