"""The run-time-against-error arithmetic (exact answers on synthetic numbers), the reference cache, and the
Monte-only bench commands (sampler/batch ladders, the seed's table) at tiny sizes. No bpy."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from monte.cli import main
from monte.core import metrics
from monte.lab import bench_math as bm
from monte.lab.bench_ladders import seed_display_values, seed_table, seed_table_markdown
from monte.lab.bench_reference import (BUNDLED_OWN_RMSE, BUNDLED_PARAMS, ReferenceCache, read_reference_file,
                                        reference_key)


# --------------------------------------------------------------------------------------------- arithmetic
def test_corrected_rmse_subtracts_reference_noise_in_quadrature():
    assert bm.corrected_rmse(0.05, 0.03**2) == pytest.approx(0.04, rel=1e-12)
    assert bm.corrected_rmse(0.01, 0.02**2) == 0.0  # reference noisier than the error: clipped, not NaN


def test_efficiency_is_one_over_seconds_times_mse():
    assert bm.efficiency(2.0, 0.01) == pytest.approx(50.0, rel=1e-12)  # 1 / (seconds x MSE)
    assert bm.efficiency(0.0, 0.01) == math.inf and bm.efficiency(1.0, 0.0) == math.inf


def test_reference_from_seeds_mean_and_own_noise():
    a = np.full((2, 3, 3), 1.0)
    b = np.full((2, 3, 3), 3.0)
    mean, own = bm.reference_from_seeds([a, b])
    assert np.all(mean == 2.0)
    assert own == pytest.approx(1.0, rel=1e-12)  # spread s^2 = 2 (ddof 1), over K = 2 seeds
    with pytest.raises(ValueError, match="at least 2"):
        bm.reference_from_seeds([a])


def test_seconds_at_rmse_interpolates_the_loglog_line_exactly():
    # t = 0.16 / e^2 is a straight line in log-log; piecewise-linear interpolation reproduces it exactly.
    e = np.array([0.4, 0.2, 0.1])
    t = 0.16 / e**2
    levels = [0.4, 0.2 * math.sqrt(2), 0.15, 0.1, 0.05, 0.5]
    got = bm.seconds_at_rmse(t, e, levels)
    assert got[:4] == pytest.approx(0.16 / np.array(levels[:4]) ** 2, rel=1e-12)
    assert np.isnan(got[4]) and np.isnan(got[5])  # outside the measured range


def test_equal_error_ratio_of_two_power_laws_is_exact():
    # Monte: t = 1 / e^2, Cycles: t = 3 / e^2 at different errors: Monte is 3x as efficient everywhere.
    e_m = np.array([0.3, 0.15, 0.08, 0.04])
    e_c = np.array([0.25, 0.12, 0.06, 0.05])
    r = bm.equal_error_ratio((1 / e_m**2, e_m), (3 / e_c**2, e_c), n_levels=4)
    assert not r["extrapolated"]
    assert r["levels"][0] == pytest.approx(0.05) and r["levels"][-1] == pytest.approx(0.25)
    assert r["ratios"] == pytest.approx([3.0] * 4, rel=1e-12)
    assert r["ratio"] == pytest.approx(3.0, rel=1e-12)
    # Efficiencies 1/(t e^2) at the levels agree with the ratio.
    eff_m = [1 / (t * e * e) for t, e in zip(r["seconds_this"], r["levels"])]
    eff_c = [1 / (t * e * e) for t, e in zip(r["seconds_other"], r["levels"])]
    assert np.array(eff_m) / np.array(eff_c) == pytest.approx([3.0] * 4, rel=1e-12)


def test_equal_error_ratio_extrapolates_when_errors_do_not_overlap():
    e_m = np.array([0.1, 0.05])
    e_c = np.array([0.4, 0.2])
    r = bm.equal_error_ratio((2 / e_m**2, e_m), (1 / e_c**2, e_c))
    assert r["extrapolated"] and r["ratio"] == pytest.approx(0.5, rel=1e-9)
    assert math.isnan(bm.equal_error_ratio(([1.0], [0.1]), ([], []))["ratio"])


def test_loglog_fit_slope():
    t = np.array([1.0, 4.0, 16.0])
    a, b = bm.loglog_fit(t, 0.3 / np.sqrt(t))
    assert b == pytest.approx(-0.5, abs=1e-12) and math.exp(a) == pytest.approx(0.3, rel=1e-12)


def test_format_table_and_plot(tmp_path):
    md = bm.format_table(["a", "b"], [[1, 0.123456], [2, float("nan")]], markdown=True)
    assert md.splitlines() == ["| a | b |", "|---|---|", "| 1 | 0.1235 |", "| 2 | - |"]
    png = bm.plot_rmse_vs_seconds([{"title": "x", "series": [
        {"label": "monte", "seconds": [1, 2, 4], "rmse": [0.2, 0.14, 0.1], "spp": [16, 32, 64]},
        {"label": "cycles", "seconds": [1, 2], "rmse": [0.1, 0.0]}]}], tmp_path / "p.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------------------------- reference cache
def test_reference_cache_round_trip_and_keys(tmp_path):
    cache = ReferenceCache(tmp_path / "refs")
    params = {"scene": "box", "resolution": [4, 3], "max_bounces": 8, "filter_type": "blackman-harris",
              "filter_width": 1.5, "spp_per_seed": 16, "seeds": 2}
    assert cache.load(params) is None
    img = np.random.default_rng(1).random((3, 4, 3)).astype(np.float32)
    path = cache.store(img, 0.0025, params)
    ref = cache.load(params)
    assert ref.source == "cache" and ref.own_mse == 0.0025 and np.array_equal(ref.image, img)
    assert reference_key(params) != reference_key({**params, "max_bounces": 9})
    assert reference_key(params) == reference_key(dict(reversed(list(params.items()))))
    assert read_reference_file(path).own_mse == 0.0025


def test_reference_cache_starts_from_the_bundled_cornell_box(tmp_path):
    cache = ReferenceCache(tmp_path)
    ref = cache.load({**BUNDLED_PARAMS, "renderer": "cycles 5.0.1"})
    assert ref.source == "bundled" and ref.image.shape == (256, 256, 3)
    assert ref.own_mse == pytest.approx(BUNDLED_OWN_RMSE**2)
    again = cache.load({**BUNDLED_PARAMS, "renderer": "cycles 5.0.1"})
    assert again.source == "cache" and np.array_equal(again.image, ref.image)


# --------------------------------------------------------------------------------------------- seed table
def test_seed_luma_variance_is_the_bt709_quadratic_form_of_the_channel_covariance():
    rgb = np.random.default_rng(2).random((8, 9, 3)) * 1.5
    table = metrics.seed_variance_table(seed_display_values(rgb))
    cov = np.cov(seed_display_values(rgb).reshape(-1, 3).T, ddof=0)
    assert table["luma"] == pytest.approx(metrics.BT709 @ cov @ metrics.BT709, rel=1e-12)
    assert [table[c] for c in "RGB"] == pytest.approx(np.diag(cov).tolist(), rel=1e-12)
    assert seed_display_values(np.array([[[-1.0, 0.25, 4.0]]])).tolist() == [[[0.0, 0.25 ** (1 / 2.2), 1.0]]]


def test_seed_table_tiny(fast_settings):
    table = seed_table((1, 2), resolution=(16, 16), overrides={"threads": 2, "seed": 1})
    assert [r["samples_per_stratum"] for r in table["rows"]] == [1, 2]
    assert [r["spp"] for r in table["rows"]] == [4, 8]
    for r in table["rows"]:
        for group in ("seed_variance", "seed_variance_linear", "mean_pixel_variance"):
            values = np.array(list(r[group].values()))
            assert np.all(np.isfinite(values)) and np.all(values > 0)
        pv = r["mean_pixel_variance"]
        assert pv["luma"] == pytest.approx(sum(w * w * pv[c] for w, c in zip(metrics.BT709, "RGB")), rel=1e-9)
        assert math.isnan(r["rmse"])  # no reference at 16x16
    md = seed_table_markdown(table).splitlines()
    assert md[0].startswith("| per stratum | spp |") and len([ln for ln in md if ln.startswith("| ")]) == 3
    assert "Cornell box 16x16" in md[-1]


def test_seed_table_command(tmp_path):
    rc = main(["bench", "--seed-table", "--strata-samples", "1,2", "--resolution", "16x16", "--threads", "2",
               "-o", str(tmp_path)])
    assert rc == 0
    report = json.loads((tmp_path / "bench.json").read_text())
    assert [r["spp"] for r in report["seed_table"]["rows"]] == [4, 8]
    assert report["seed_table"]["resolution"] == [16, 16]
    lines = (tmp_path / "seed_table.md").read_text().splitlines()
    assert len([ln for ln in lines if ln.startswith("| ")]) == 3  # header + 2 rows


def test_sampler_and_batch_ladders_command(tmp_path, capsys):
    rc = main(["bench", "--samplers", "--batch-sizes", "1024,4096", "--ladder", "2", "--spp", "2",
               "--resolution", "16x16", "--threads", "2", "-o", str(tmp_path)])
    assert rc == 0
    report = json.loads((tmp_path / "bench.json").read_text())
    assert {p["sampler"] for p in report["samplers"]["points"]} == {"sobol", "stratified", "independent"}
    assert [p["batch_paths"] for p in report["batch_sizes"]["points"]] == [1024, 4096]
    assert all(p["seconds"] > 0 and p["samples_per_second"] > 0 for p in report["batch_sizes"]["points"])
    assert "batch" in capsys.readouterr().out


def test_bench_rejects_bad_ladders(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "--samplers", "--ladder", "16,0"])
    assert "positive integers" in capsys.readouterr().err
