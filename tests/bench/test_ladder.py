"""Preset ladder: paired gains over seeds and the one-sided t-test, against closed forms."""

from __future__ import annotations

import math

import pytest

from senerf.bench.ladder import (contrasts_markdown, ladder_markdown, method_contrasts, paired_gain_p_value,
                                 preset_ladder, teacher_dependence, teacher_dependence_markdown)


def _line(seed, preset, psnr, seconds, k=1, iteration=None, method="senerf", status="ok"):
    it = k if iteration is None else iteration
    return {"run_key": f"lego|p|{method}|{preset}|seed{seed}|K{k}", "attempt": f"a{seed}{preset}{k}{method}",
            "status": status, "scene": "lego", "protocol": "synthetic-extreme3@100", "method": method,
            "preset": preset, "seed": seed, "iterations": k, "iteration": it, "psnr": psnr,
            "seconds_cumulative": seconds}


def _t_sf_2dof(t: float) -> float:
    """Upper tail of Student's t with 2 degrees of freedom, closed form: 1/2 (1 - t / sqrt(t^2 + 2))."""
    return 0.5 * (1.0 - t / math.sqrt(t * t + 2.0))


def test_p_value_matches_closed_form_for_two_dof():
    # diffs 1, 2, 3: mean 2, sample std 1, t = 2 * sqrt(3)
    assert paired_gain_p_value([1.0, 2.0, 3.0]) == pytest.approx(_t_sf_2dof(2 * math.sqrt(3)), rel=1e-9)
    # a negative mean gives p above one half, mirrored
    assert paired_gain_p_value([-1.0, -2.0, -3.0]) == pytest.approx(1 - _t_sf_2dof(2 * math.sqrt(3)), rel=1e-9)


def test_p_value_edge_cases():
    assert paired_gain_p_value([0.4]) is None
    assert paired_gain_p_value([0.5, 0.5, 0.5]) == 0.0
    assert paired_gain_p_value([0.0, 0.0]) == 1.0
    assert paired_gain_p_value([-0.5, -0.5], alternative="two-sided") == 0.0
    assert paired_gain_p_value([0.0, 0.0], alternative="two-sided") == 1.0


def test_ladder_pairs_common_seeds_and_orders_by_seconds():
    records = []
    for s, (f, b, q) in enumerate([(17.0, 18.0, 17.1), (16.0, 17.5, 16.2), (17.5, 18.2, 17.4), (16.5, 17.1, 0)]):
        records += [_line(s, "fast", 0.0, 30, iteration=0), _line(s, "fast", f, 80)]
        records += [_line(s, "balanced", b, 300, k=3)]
        if s < 3:  # quality has seeds 0-2 only
            records += [_line(s, "quality", q, 200)]
    records.append(_line(9, "balanced", 30.0, 300, k=3, status="failed"))   # failed: left out
    rungs = preset_ladder(records)
    assert [(r.slower, r.faster) for r in rungs] == [("quality K=1", "fast K=1"), ("balanced K=3", "fast K=1"),
                                                    ("balanced K=3", "quality K=1")]
    q_f, b_f, b_q = rungs
    assert q_f.seeds == (0, 1, 2) and b_f.seeds == (0, 1, 2, 3)
    assert b_f.gain.mean == pytest.approx((1.0 + 1.5 + 0.7 + 0.6) / 4)
    assert b_f.slower_seconds == pytest.approx(300) and b_f.faster_seconds == pytest.approx(80)
    assert b_f.measurable and b_f.p_value < 0.05
    assert q_f.gain.mean == pytest.approx((0.1 + 0.2 - 0.1) / 3) and not q_f.measurable
    md = "\n".join(ladder_markdown(rungs))
    assert "| lego | senerf | balanced K=3 | fast K=1 | 4 | 300 / 80 | 0.95 ± 0.40 |" in md
    assert md.count("| yes |") == 2 and md.count("| no |") == 1


def test_too_few_seeds_is_never_measurable():
    records = [_line(0, "fast", 10.0, 10), _line(0, "quality", 20.0, 100),
               _line(1, "fast", 10.0, 10), _line(1, "quality", 21.0, 100)]
    (rung,) = preset_ladder(records)
    assert rung.p_value is not None and rung.p_value < 0.05 and not rung.measurable
    assert "too few seeds" in "\n".join(ladder_markdown([rung]))
    assert preset_ladder([_line(0, "fast", 10.0, 10)]) == [] and ladder_markdown([]) == []


def _t_two_sided_2dof(t: float) -> float:
    return 2 * _t_sf_2dof(abs(t))


def test_method_contrasts_pair_ablations_with_the_reference():
    records = []
    for s, (ref, abl) in enumerate([(17.0, 16.0), (17.5, 15.5), (16.0, 13.0)]):
        records += [_line(s, "fast", ref, 80), _line(s, "fast", abl, 80, method="senerf-no-empty")]
    records += [_line(0, "fast", 15.0, 30, k=0, method="baseline")]          # K = 0: no rung in common
    records += [_line(0, "balanced", 18.0, 300, k=3, method="senerf-oracle")]  # no reference at balanced
    (c,) = method_contrasts(records)
    assert (c.method, c.reference, c.rung, c.seeds) == ("senerf-no-empty", "senerf", "fast K=1", (0, 1, 2))
    # diffs -1, -2, -3: t = -2 sqrt(3), two-sided with 2 dof
    assert c.diff.mean == pytest.approx(-2.0) and c.diff.std == pytest.approx(1.0)
    assert c.p_value == pytest.approx(_t_two_sided_2dof(2 * math.sqrt(3)), rel=1e-9)
    md = "\n".join(contrasts_markdown([c]))
    assert "| lego | fast K=1 | senerf-no-empty | senerf | 3 | -2.00 ± 1.00 | 0.074 |" in md
    assert contrasts_markdown([]) == []


def _run(seed, teacher, final, k=1, preset="fast", method="senerf", attempt="a", last=None):
    """The lines of one run: its teacher (iteration 0) and iterations 1..``last`` (default k) at ``final``."""
    return [{**_line(seed, preset, teacher if i == 0 else final, 10.0 * (i + 1), k=k, iteration=i, method=method),
             "attempt": attempt} for i in range((last if last is not None else k) + 1)]


def test_teacher_dependence_fits_gain_against_teacher_by_hand():
    # teachers 15, 16, 17 dB; gains 3, 2, 1.5 (finals 18, 18, 18.5)
    lines = _run(0, 15.0, 18.0) + _run(1, 16.0, 18.0) + _run(2, 17.0, 18.5)
    (fit,) = teacher_dependence(lines)
    assert (fit.method, fit.rung, fit.seeds) == ("senerf", "fast K=1", (0, 1, 2))
    assert fit.teacher_psnr == (15.0, 16.0, 17.0) and fit.gain == (3.0, 2.0, 1.5)
    # by hand: Sxx = 2, Sxy = -1.5, Syy = 7/6; slope -0.75, intercept 13/6 + 12 = 85/6, r = -1.5 / sqrt(7/3)
    assert fit.slope == pytest.approx(-0.75) and fit.intercept == pytest.approx(85 / 6)
    r = -1.5 / math.sqrt(7 / 3)
    assert fit.r == pytest.approx(r)
    # the slope's two-sided p: t = r sqrt(n - 2) / sqrt(1 - r^2) with 1 dof, p = 1 - 2 atan(|t|) / pi
    t = r / math.sqrt(1 - r * r)
    assert fit.p_value == pytest.approx(1 - 2 * math.atan(abs(t)) / math.pi, rel=1e-9)
    assert fit.gain_at(14.0) == pytest.approx(85 / 6 - 0.75 * 14)


def test_teacher_dependence_groups_and_skips():
    lines = (_run(0, 15.0, 17.0) + _run(1, 16.0, 17.5)                          # two runs: a fit, no p
             + _run(0, 15.0, 18.0, k=3, preset="balanced") + _run(1, 15.0, 18.2, k=3, preset="balanced")
             + _run(2, 16.0, 17.0, k=1, method="baseline")[:1]                   # a baseline: never
             + _run(3, 16.0, 17.0, k=3, preset="balanced", last=2)               # unfinished: left out
             + _run(4, 17.0, 99.0, attempt="old") + _run(4, 17.0, 17.4, attempt="new"))   # last attempt wins
    for line in lines:
        if line["method"] == "baseline":
            line.update(iterations=0, iteration=0)
    fits = {(f.method, f.rung): f for f in teacher_dependence(lines)}
    assert set(fits) == {("senerf", "fast K=1"), ("senerf", "balanced K=3")}
    fast = fits[("senerf", "fast K=1")]
    assert fast.seeds == (0, 1, 4) and fast.gain == pytest.approx((2.0, 1.5, 0.4)) and fast.p_value is not None
    balanced = fits[("senerf", "balanced K=3")]
    assert balanced.seeds == (0, 1) and balanced.slope is None and balanced.p_value is None   # equal teachers
    rows = [r for r in teacher_dependence_markdown(list(fits.values())) if r.startswith("| lego")]
    assert len(rows) == 1 and "| fast K=1 | senerf | 3 |" in rows[0]                 # only fits of >= 3 runs
    assert teacher_dependence_markdown([balanced]) == []


def test_docstring_examples_run():
    import doctest

    import senerf.bench.ladder as ladder

    result = doctest.testmod(ladder)
    assert result.attempted >= 2 and result.failed == 0
