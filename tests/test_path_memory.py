"""Paths in flight (core/integrator.py): next-event estimation in chunks of NEE_CHUNK paths gives the same image
bit for bit as in one piece, and `monte perf` prints the memory per million paths in flight."""

import json
import re

import numpy as np
import pytest

from monte.core import builtin_scenes as scenes
from monte.core import integrator
from monte.core.render import render
from monte.core.settings import RenderSettings


@pytest.mark.parametrize("build, extra", [
    (scenes.cornell_box, {"denoising_features": True}),
    (scenes.spheres_under_sky, {"light_passes": ("Diffuse Direct", "Glossy Direct", "Diffuse Indirect",
                                                 "Environment")}),
])
def test_light_samples_in_chunks_give_the_same_image(monkeypatch, build, extra):
    # 40 x 40 x 4 = 6400 paths in one batch: one piece with the default chunk, 66 chunks with 97 paths
    settings = RenderSettings(spp=4, threads=1, seed=3, aovs=True, **extra).validate()
    assert 40 * 40 * 4 < integrator.NEE_CHUNK
    whole = render(build((40, 40)), settings)
    monkeypatch.setattr(integrator, "NEE_CHUNK", 97)
    chunked = render(build((40, 40)), settings)
    assert whole.stats["rays_shadow"] > 0 and chunked.stats["rays_shadow"] == whole.stats["rays_shadow"]
    for name in ("color", "variance", "albedo", "normal", "depth", "denoising_albedo", "denoising_normal"):
        a, b = getattr(whole, name), getattr(chunked, name)
        assert (a is None) == (b is None), name
        if a is not None:
            assert np.array_equal(a, b), name
    for name, image in (whole.light_passes or {}).items():
        assert np.array_equal(image, chunked.light_passes[name]), name
    assert whole.color[..., :3].mean() > 0.01


def test_perf_prints_memory_per_million_paths(tmp_path, capsys):
    from monte.cli import main

    out = tmp_path / "perf.json"
    assert main(["perf", "--sections", "memory", "--memory-resolution", "48", "--memory-batches", "16384", "32768",
                 "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    found = re.search(r"paths in flight (\d+) MB per million", printed)
    assert found, printed
    report = json.loads(out.read_text())["memory"]
    assert int(found.group(1)) == round(report["mb_per_million_paths"]) and report["mb_per_million_paths"] > 0
    sizes = [row["largest_batch"] for row in report["rows"]]
    assert 16384 <= sizes[0] < sizes[1]
    # a batch holds at least its paths' float32 radiance and camera rays, and far less than a kilobyte per path
    assert all(28 < row["bytes_per_path"] < 1000 for row in report["rows"])
