"""Paired comparisons over seeds against independent references: closed-form Student t tails, scipy's
ttest_rel and statistics worked out by hand."""

from __future__ import annotations

import math

import pytest
from scipy import stats

from senerf.bench import ladder
from senerf.bench.ladder import (LADDER_ALPHA, LADDER_MIN_SEEDS, method_contrasts, paired_gain_p_value,
                                 paired_markdown, preset_ladder)


def _line(seed, preset, psnr, seconds, k=1, iteration=None, method="senerf", status="ok", attempt=None):
    return {"run_key": f"lego|p|{method}|{preset}|seed{seed}|K{k}", "attempt": attempt or f"a{seed}{preset}{k}{method}",
            "status": status, "scene": "lego", "protocol": "synthetic-extreme3@100", "method": method,
            "preset": preset, "seed": seed, "iterations": k, "iteration": k if iteration is None else iteration,
            "psnr": psnr, "seconds_cumulative": seconds}


def _t_sf_2dof(t: float) -> float:
    """Upper tail of Student's t with 2 degrees of freedom, closed form: 1/2 (1 - t / sqrt(t^2 + 2))."""
    return 0.5 * (1.0 - t / math.sqrt(t * t + 2.0))


def _two_rungs(gains, fast=17.0):
    """fast (80 s) and quality (200 s) final lines for seeds 0.. with quality = fast + gain."""
    out = []
    for s, g in enumerate(gains):
        out += [_line(s, "fast", fast + 0.1 * s, 80), _line(s, "quality", fast + 0.1 * s + g, 200)]
    return out


def test_p_value_matches_the_closed_form_for_two_dof():
    # diffs 1, 2, 3: mean 2, sample std 1, t = 2 * sqrt(3); a negative mean mirrors it
    assert paired_gain_p_value([1.0, 2.0, 3.0]) == pytest.approx(_t_sf_2dof(2 * math.sqrt(3)), rel=1e-9)
    assert paired_gain_p_value([-1.0, -2.0, -3.0]) == pytest.approx(1 - _t_sf_2dof(2 * math.sqrt(3)), rel=1e-9)
    assert paired_gain_p_value([-1.0, -2.0, -3.0], "two-sided") == pytest.approx(2 * _t_sf_2dof(2 * math.sqrt(3)))


def test_p_value_without_pairs_or_spread():
    assert paired_gain_p_value([0.4]) is None
    assert paired_gain_p_value([0.5, 0.5, 0.5]) == 0.0 and paired_gain_p_value([0.0, 0.0]) == 1.0
    assert paired_gain_p_value([-0.5, -0.5]) == 1.0 and paired_gain_p_value([-0.5, -0.5], "two-sided") == 0.0
    assert paired_gain_p_value([0.0, 0.0], alternative="two-sided") == 1.0


def test_ladder_p_value_is_scipys_one_sided_paired_t_test():
    # diffs 1, 2, 3: one-sided p = 0.037 < 0.05 but two-sided p = 0.074, so the tail decides the verdict
    (rung,) = preset_ladder(_two_rungs([1.0, 2.0, 3.0]))
    fast = [17.0 + 0.1 * s for s in range(3)]
    want = stats.ttest_rel([f + g for f, g in zip(fast, [1.0, 2.0, 3.0])], fast, alternative="greater").pvalue
    assert rung.p_value == pytest.approx(want, rel=1e-9) and rung.measurable
    (loss,) = preset_ladder(_two_rungs([-1.0, -2.0, -3.0]))         # the slower rung worse: never measurable
    assert loss.p_value == pytest.approx(1 - want, rel=1e-9) and not loss.measurable


def test_ladder_rule_is_p_strictly_below_alpha_with_enough_pairs(monkeypatch):
    assert (LADDER_ALPHA, LADDER_MIN_SEEDS) == (0.05, 3)
    records = _two_rungs([1.0, 2.0, 3.0])
    p = preset_ladder(records)[0].p_value
    monkeypatch.setattr(ladder, "LADDER_ALPHA", p)
    assert not preset_ladder(records)[0].measurable
    monkeypatch.setattr(ladder, "LADDER_ALPHA", math.nextafter(p, 1.0))
    assert preset_ladder(records)[0].measurable
    monkeypatch.undo()
    (rung,) = preset_ladder(_two_rungs([1.0, 2.0, 0.3]))              # p = 0.078: not measurable at 0.05
    assert 0.05 < rung.p_value < 0.1 and not rung.measurable
    (two,) = preset_ladder(_two_rungs([1.0, 1.1]))                     # p < 0.05 on 2 pairs: too few
    assert two.p_value < 0.05 and not two.measurable
    assert "too few seeds" in "\n".join(paired_markdown([two]))
    assert preset_ladder([_line(0, "fast", 10.0, 10)]) == [] and paired_markdown([]) == []


def test_ladder_pairs_common_seeds_and_orders_by_seconds():
    records = []
    for s, (f, b, q) in enumerate([(17.0, 18.0, 17.1), (16.0, 17.5, 16.2), (17.5, 18.2, 17.4), (16.5, 17.1, 0)]):
        records += [_line(s, "fast", 0.0, 30, iteration=0), _line(s, "fast", f, 80), _line(s, "balanced", b, 300, k=3)]
        if s < 3:  # quality has seeds 0-2 only
            records += [_line(s, "quality", q, 200)]
    records.append(_line(9, "balanced", 30.0, 300, k=3, status="failed"))   # failed: left out
    q_f, b_f, b_q = preset_ladder(records)
    assert [(r.a, r.b) for r in (q_f, b_f, b_q)] == [("senerf quality K=1", "senerf fast K=1"),
                                                     ("senerf balanced K=3", "senerf fast K=1"),
                                                     ("senerf balanced K=3", "senerf quality K=1")]
    assert q_f.seeds == (0, 1, 2) and b_f.seeds == (0, 1, 2, 3)
    assert b_f.diff.mean == pytest.approx((1.0 + 1.5 + 0.7 + 0.6) / 4)
    assert (b_f.a_seconds, b_f.b_seconds) == pytest.approx((300, 80)) and b_f.measurable
    assert q_f.diff.mean == pytest.approx((0.1 + 0.2 - 0.1) / 3) and not q_f.measurable
    md = "\n".join(paired_markdown([q_f, b_f, b_q]))
    assert "| lego | senerf balanced K=3 | senerf fast K=1 | 4 | 300 / 80 | 0.95 ± 0.40 |" in md
    assert md.count("| yes |") == 2 and md.count("| no |") == 1


def test_ladder_seconds_are_means_over_the_paired_seeds_only():
    # seeds 0-2 in both rungs (80 s / 200 s); seed 3 only in quality, at 1000 s, is not a pair
    (rung,) = preset_ladder(_two_rungs([1.0, 2.0, 3.0]) + [_line(3, "quality", 30.0, 1000)])
    assert rung.seeds == (0, 1, 2) and (rung.a_seconds, rung.b_seconds) == pytest.approx((200.0, 80.0))


def test_method_contrasts_pair_ablations_with_the_reference():
    records = []
    for s, (ref, abl) in enumerate([(17.0, 16.0), (17.5, 15.5), (16.0, 13.0)]):
        records += [_line(s, "fast", ref, 80), _line(s, "fast", abl, 80, method="senerf-no-empty")]
    records += [_line(0, "fast", 15.0, 30, k=0, method="baseline")]          # K = 0: no rung in common
    records += [_line(0, "balanced", 18.0, 300, k=3, method="senerf-no-prior")]  # no reference at balanced
    (c,) = method_contrasts(records)
    assert (c.a, c.b, c.seeds) == ("senerf-no-empty fast K=1", "senerf fast K=1", (0, 1, 2))
    # diffs -1, -2, -3: mean -2, std 1, t = -2 sqrt(3), two-sided with 2 dof
    assert c.diff.mean == pytest.approx(-2.0) and c.diff.std == pytest.approx(1.0)
    assert c.p_value == pytest.approx(2 * _t_sf_2dof(2 * math.sqrt(3)), rel=1e-9)
    assert "| lego | senerf-no-empty fast K=1 | senerf fast K=1 | 3 | 80 / 80 | -2.00 ± 1.00 | 0.074 | no |" in (
        "\n".join(paired_markdown([c], ladder=False)))


def test_frontier_names_each_faster_configuration_that_is_measurably_better():
    # seeds 0-3: the teacher (iteration 0, 30 s) beats its own student (K=1, 80 s) by 1.0-1.3 dB on every seed;
    # quality (200 s) beats fast's student by 1.0-1.3 dB but never the teacher, which is faster and worse by 0.0
    records = []
    for s, d in enumerate([1.0, 1.1, 1.3, 1.2]):
        records += [_line(s, "fast", 18.0 + d, 30, iteration=0), _line(s, "fast", 18.0, 80),
                    _line(s, "quality", 18.0 + d, 200)]
    rungs = ladder.frontier(records)
    assert [(r.config, r.seconds) for r in rungs] == [("baseline fast K=0", 30.0), ("senerf fast K=1", 80.0),
                                                       ("senerf quality K=1", 200.0)]
    teacher, student, quality = rungs
    assert teacher.beaten_by == () and quality.beaten_by == ()          # equal PSNR is not better
    (beaten,) = student.beaten_by
    assert (beaten.a, beaten.b, beaten.seeds) == ("baseline fast K=0", "senerf fast K=1", (0, 1, 2, 3))
    assert beaten.diff.mean == pytest.approx(1.15) and beaten.measurable
    md = "\n".join(ladder.frontier_markdown(rungs))
    assert md.count("| none |") == 2
    row = "| lego | senerf fast K=1 | 4 | 80 | 18.00 ± 0.00 | baseline fast K=0 (30 s, 1.15 ± 0.13 dB, p 0.000) |"
    assert row in md


def test_frontier_needs_enough_pairs_to_call_a_configuration_beaten():
    records = []
    for s in range(2):   # two pairs, the faster one far better: still too few to say
        records += [_line(s, "fast", 20.0 + s, 30), _line(s, "quality", 15.0, 200)]
    assert all(r.beaten_by == () for r in ladder.frontier(records)) and ladder.frontier_markdown([]) == []
