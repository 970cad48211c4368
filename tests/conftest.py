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
