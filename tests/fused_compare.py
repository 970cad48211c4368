"""Not a test module: one scene rendered by the fused path kernel and by the per-bounce integrator (the
`MONTE_FUSED` switch), compared bit for bit."""

from __future__ import annotations

import numpy as np

from monte.core.fused_tracer import FUSED_ENV
from monte.core.render import render


def render_with(scene, settings, monkeypatch, fused: bool):
    """The RenderResult of `scene` with the fused kernel allowed (fused) or turned off."""
    monkeypatch.setenv(FUSED_ENV, "1" if fused else "0")
    return render(scene, settings)


def assert_fused_equals_per_bounce(scene, settings, monkeypatch, aovs=("albedo", "normal", "depth")):
    """Render both ways; the fused kernel must have run in the second render only, and the colour, the
    variance and the first-hit passes `aovs` must be equal bit for bit. Returns (per_bounce, fused)."""
    old = render_with(scene, settings, monkeypatch, fused=False)
    new = render_with(scene, settings, monkeypatch, fused=True)
    assert new.stats["fused_kernel"] and not old.stats["fused_kernel"]
    assert np.array_equal(new.color, old.color)
    assert np.array_equal(new.variance, old.variance)
    for aov in aovs:
        assert np.array_equal(getattr(new, aov), getattr(old, aov)), aov
    return old, new


def assert_fused_bit_identical_across_thread_counts(scene, fast_settings, monkeypatch, spp: int = 8, **kw):
    """The fused render of `scene` in batches of 1024 paths on one thread and on two: the same colour,
    variance and albedo bits. Returns the one-thread result."""
    one = render_with(scene, fast_settings(spp=spp, threads=1, batch_paths=1024, **kw), monkeypatch, fused=True)
    two = render_with(scene, fast_settings(spp=spp, threads=2, batch_paths=1024, **kw), monkeypatch, fused=True)
    assert one.stats["fused_kernel"]
    assert np.array_equal(one.color, two.color)
    assert np.array_equal(one.variance, two.variance)
    assert np.array_equal(one.albedo, two.albedo)
    return one
