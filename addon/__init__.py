"""Everything that imports bpy: the render engine, export, properties, UI and the headless entry point.

`register()`/`unregister()` are called by the package root's (Blender's extension entry point); importing
this package alone does not register anything.
"""

from __future__ import annotations

_registered = False
_kernel_loader = None  # the thread loading the cached render kernels (started by register)


def _load_kernels_in_background():
    """Load the compiled render kernels (numba's cache, shipped in the zip) on a thread while Blender goes on,
    so that the first render does not spend its first ~0.3 s loading them (later renders never do). Compiles
    nothing; where no cache applies, the first render compiles as before."""
    import threading

    def work() -> None:
        try:
            from ..core.precompile import load_cached_kernels

            load_cached_kernels()
        except Exception:  # noqa: BLE001 - only a head start: the first render loads (or compiles) them itself
            pass

    thread = threading.Thread(target=work, name="monte-load-kernels", daemon=True)
    thread.start()
    return thread


def register() -> None:
    global _registered
    if _registered:
        return
    import bpy

    from . import engine, operators, properties, ui

    properties.register()
    bpy.utils.register_class(engine.MonteRenderEngine)
    operators.register()
    ui.register()
    _registered = True
    global _kernel_loader
    if _kernel_loader is None:
        _kernel_loader = _load_kernels_in_background()


def unregister() -> None:
    global _registered
    if not _registered:
        return
    import bpy

    from . import engine, operators, properties, ui

    ui.unregister()
    operators.unregister()
    bpy.utils.unregister_class(engine.MonteRenderEngine)
    properties.unregister()
    _registered = False
    if _kernel_loader is not None:
        _kernel_loader.join(timeout=60)  # not still loading while Blender shuts down
_kernel_loader = None  # the thread loading the cached render kernels (started by register)


def _load_kernels_in_background():
    """Load the compiled render kernels (numba's cache, shipped in the zip) on a thread while Blender goes on,
    so that the first render does not spend its first ~0.3 s loading them (later renders never do). Compiles
    nothing; where no cache applies, the first render compiles as before."""
    import threading

    def work() -> None:
        try:
            from ..core.precompile import load_cached_kernels

            load_cached_kernels()
        except Exception:  # noqa: BLE001 - only a head start: the first render loads (or compiles) them itself
            pass

    thread = threading.Thread(target=work, name="monte-load-kernels", daemon=True)
    thread.start()
    return thread


def is_registered() -> bool:
    return _registered
