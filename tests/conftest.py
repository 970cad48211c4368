"""Shared test helpers: small render settings so the default suite stays fast on 2 cores."""

import pytest


@pytest.fixture
def fast_settings():
    from monte.core.settings import RenderSettings

    def make(**kw):
        base = dict(spp=16, seed=1, threads=2, filter_type="box", filter_width=1.0, max_bounces=16)
        base.update(kw)
        return RenderSettings(**base)

    return make


# ------------------------------------------------------------------------------------ bpy module at exit
# Blender 4.2's bpy module crashes (SIGSEGV) at interpreter exit once a class was registered, and 4.5's hangs,
# even after unregistering; pytest's status would then be 139 or never come. At the end of the session
# addon.headless.end_bpy_process unregisters Monte and, on those versions, ends the process with pytest's status.
_exit_status = {}


def pytest_sessionfinish(session, exitstatus):
    _exit_status["status"] = int(exitstatus)


def pytest_unconfigure(config):
    import sys

    if "bpy" not in sys.modules:
        return
    from monte.addon.headless import end_bpy_process

    end_bpy_process(_exit_status.get("status", 0))


@pytest.fixture
def patch_engine():
    """patch(name, value) sets an attribute of Monte's RenderEngine class for one test; the class's own attributes
    come back (or the patched ones go) afterwards. Needs the bpy module."""
    from monte.addon.engine import MonteRenderEngine as Engine

    saved = {}

    def patch(name, value):
        saved.setdefault(name, Engine.__dict__.get(name))
        setattr(Engine, name, value)

    yield patch
    for name, value in saved.items():
        if value is None:
            delattr(Engine, name)
        else:
            setattr(Engine, name, value)
