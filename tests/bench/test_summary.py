"""Mean ± sample std over seeds, per group, against numpy and by hand; never the best run."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from senerf.bench.summary import Stat, aggregate, final_iterations, format_table, preset_label


def _line(seed, iteration, psnr, method="senerf", preset="fast", lpips="unavailable", attempt=None):
    return {"run_key": f"lego|p|{method}|{preset}|seed{seed}", "attempt": attempt or f"a{seed}{method}{preset}",
            "status": "ok", "scene": "lego", "protocol": "synthetic-extreme3@100", "method": method,
            "preset": preset, "seed": seed, "iterations": 2, "iteration": iteration, "psnr": psnr,
            "ssim": psnr / 100, "lpips": lpips, "avg": lpips, "seconds_cumulative": 10.0 * (iteration + 1),
            "peak_memory_mib": 100.0 + seed}


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(5, 40, allow_nan=False), min_size=2, max_size=6))
def test_mean_std_match_numpy(values):
    (agg,) = aggregate([_line(seed, 0, v) for seed, v in enumerate(values)])
    assert agg.psnr.n == len(values) and agg.seeds == tuple(range(len(values)))
    assert agg.psnr.mean == pytest.approx(np.mean(values), rel=1e-12, abs=1e-12)
    assert agg.psnr.std == pytest.approx(np.std(values, ddof=1), rel=1e-9, abs=1e-12)
    assert agg.peak_memory_mib.mean == pytest.approx(np.mean(100.0 + np.arange(len(values))))


def test_stat_keeps_only_finite_numbers():
    # numbers 1 and 3: mean 2, sample std sqrt(((1-2)^2 + (3-2)^2) / (2 - 1)) = sqrt(2); the rest is left out
    s = Stat.of([1.0, float("nan"), 3.0, float("inf"), True, False, "unavailable", None])
    assert (s.mean, s.n) == (2.0, 2) and s.std == pytest.approx(math.sqrt(2.0))
    assert Stat.of(["unavailable", None]) == Stat(None, None, 0) and Stat.of([]).text() == "-"
    assert Stat.of([17.494]).text() == "17.49 (n=1)" and s.text(1) == "2.0 ± 1.4"


def test_groups_single_seed_and_unavailable():
    records = [_line(s, it, 20.0 + it + s, lpips=0.1 * (s + 1)) for s in range(3) for it in range(3)]
    records += [{**_line(0, 0, 12.0, method="baseline"), "iterations": 0}]
    records += [{**_line(5, 0, 0.0, method="failed-one"), "status": "failed"}]
    aggs = aggregate(records)
    assert [(a.method, a.iteration) for a in aggs] == [("baseline", 0), ("senerf", 0), ("senerf", 1), ("senerf", 2)]
    base = aggs[0]
    assert base.psnr == Stat(12.0, None, 1) and base.lpips == Stat(None, None, 0)
    assert aggs[3].psnr.mean == pytest.approx(23.0) and aggs[3].lpips.mean == pytest.approx(0.2)
    assert [(a.method, a.iteration) for a in final_iterations(aggs)] == [("baseline", 0), ("senerf", 2)]
    text = format_table(aggs)
    assert "12.00 (n=1)" in text and "23.00 ± 1.00" in text and "0.200 ± 0.100" in text
    md = format_table(aggs, markdown=True).splitlines()
    assert md[0].startswith("| scene | protocol |") and len(md) == 2 + len(aggs)


def test_mean_not_best_and_the_last_attempt_counts_once():
    records = [_line(0, 0, 10.0), _line(1, 0, 30.0), _line(1, 0, 50.0, attempt="later")]
    (agg,) = aggregate(records)
    assert agg.psnr.n == 2 and agg.psnr.mean == pytest.approx(30.0)


def test_steps_device_and_k_are_separate_experiments_and_presets_sort_by_cost():
    a = _line(0, 1, 20.0)
    b = {**_line(1, 1, 30.0), "steps": 20}                          # steps override: not the preset's run
    c = {**_line(2, 1, 40.0), "iterations": 3, "run_key": "other"}  # K = 3 run at iteration 1
    d = {**_line(3, 1, 50.0, preset="balanced"), "device": "cuda"}
    e = _line(4, 1, 60.0, preset="balanced")
    aggs = aggregate([d, e, a, b, c])
    assert [(x.preset, x.iterations, x.psnr.mean) for x in aggs] == [
        ("fast", 2, 20.0), ("fast", 3, 40.0), ("fast+steps20", 2, 30.0), ("balanced", 2, 60.0),
        ("balanced+cuda", 2, 50.0)]
    assert preset_label({"preset": "fast", "steps": 20, "device": "cuda"}) == "fast+steps20+cuda"
