"""Everything that imports bpy: the render engine, export, properties, UI and the headless entry point.

`register()`/`unregister()` are called by the package root's (Blender's extension entry point); importing
this package alone does not register anything.
"""

from __future__ import annotations

_registered = False
_kernel_loader = None  # the thread loading the cached render kernels (core.precompile), started by register


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
    global _kernel_loader
    if _kernel_loader is None:  # the first render then finds the compiled kernels loaded
        from ..core.precompile import load_cached_kernels_in_background

        _kernel_loader = load_cached_kernels_in_background()


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
    if _kernel_loader is not None:  # stopped after its current kernel: not still loading while Blender shuts down
        from ..core.precompile import stop_loading_kernels

        stop_loading_kernels()


def is_registered() -> bool:
    return _registered
