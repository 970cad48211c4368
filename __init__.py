"""Monte: a physically based Monte Carlo path tracer, as a Blender render engine.

Blender imports this folder as the extension; `pip install -e .` maps it to the package `monte`.
`register()`/`unregister()` import the add-on lazily so that `import monte.core` never loads `bpy`.
"""


def register() -> None:
    from .addon import register as _register

    _register()


def unregister() -> None:
    from .addon import unregister as _unregister

    _unregister()
