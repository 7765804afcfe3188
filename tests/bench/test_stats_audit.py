"""Mutation-audit tests of senerf.bench's statistics and report: the preset-ladder rule at its boundaries,
the paired t-test against scipy.stats.ttest_rel, the teacher-dependence table against numpy.polyfit, the
mean ± std filter, the report's sections, and the published figures against REFERENCE.md.  Each test says
which bug it catches."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from senerf.bench.ladder import (LADDER_ALPHA, LADDER_MIN_SEEDS, preset_ladder, teacher_dependence,
                                 teacher_dependence_markdown)
from senerf.bench.report import PAPER_NUMBERS, make_report
from senerf.bench.summary import Stat, aggregate


def _line(seed, preset, psnr, seconds, k=1, iteration=None, method="senerf", scene="lego",
          protocol="synthetic-extreme3@100", attempt=None):
    it = k if iteration is None else iteration
    return {"run_key": f"{scene}|{protocol}|{method}|{preset}|seed{seed}|K{k}",
            "attempt": attempt or f"a{seed}{preset}{k}{method}", "status": "ok", "scene": scene,
            "protocol": protocol, "method": method, "preset": preset, "seed": seed, "iterations": k,
            "iteration": it, "psnr": psnr, "ssim": 0.5, "lpips": "unavailable", "avg": "unavailable",
            "seconds_cumulative": seconds, "peak_memory_mib": 100.0, "commit": "c0ffee",
            "machine": {"cpu": "X"}, "timestamp": "2026-01-01T00:00", "bench_command": ["senerf-bench", "run"]}


def _two_rungs(gains, fast=17.0):
    """fast (80 s) and quality (200 s) final lines for seeds 0.. with quality = fast + gain."""
    out = []
    for s, g in enumerate(gains):
        out += [_line(s, "fast", fast + 0.1 * s, 80), _line(s, "quality", fast + 0.1 * s + g, 200)]
    return out


# --- the ladder rule -----------------------------------------------------------------------------------

def test_ladder_p_value_is_scipy_one_sided_paired_t_test():
    # Catches: the ladder using a two-sided test (or the other tail).  diffs 1, 2, 3: one-sided p = 0.037
    # < 0.05 but two-sided p = 0.074 > 0.05, so the verdict flips too.
    records = _two_rungs([1.0, 2.0, 3.0])
    (rung,) = preset_ladder(records)
    fast = [17.0 + 0.1 * s for s in range(3)]
    quality = [f + g for f, g in zip(fast, [1.0, 2.0, 3.0])]
    want = stats.ttest_rel(quality, fast, alternative="greater").pvalue
    assert rung.p_value == pytest.approx(want, rel=1e-9)
    assert rung.measurable
    # a loss (slower rung worse) has p above one half and is never measurable
    (loss,) = preset_ladder(_two_rungs([-1.0, -2.0, -3.0]))
    assert loss.p_value == pytest.approx(1 - want, rel=1e-9) and not loss.measurable


def test_ladder_alpha_is_a_strict_bound():
    # Catches: p <= alpha instead of p < alpha ("measurable when p < alpha").  With alpha set to the rung's
    # own p the verdict is "no"; a hair above it, "yes".
    records = _two_rungs([1.0, 2.0, 3.0])
    p = preset_ladder(records)[0].p_value
    assert not preset_ladder(records, alpha=p)[0].measurable
    assert preset_ladder(records, alpha=math.nextafter(p, 1.0))[0].measurable


def test_ladder_default_rule_is_p_below_0_05_with_3_pairs():
    # Catches: a changed default alpha or minimum seed count.  diffs 1, 2, 0.3 give a one-sided p of 0.078
    # (between 0.05 and 0.1): not measurable under the documented rule "p < 0.05 with >= 3 pairs".
    assert (LADDER_ALPHA, LADDER_MIN_SEEDS) == (0.05, 3)
    records = _two_rungs([1.0, 2.0, 0.3])
    (rung,) = preset_ladder(records)
    assert 0.05 < rung.p_value < 0.1 and not rung.measurable


def test_ladder_seconds_are_means_over_the_paired_seeds_only():
    # Catches: reporting each rung's mean seconds over all of its seeds instead of over the paired ones.
    # Seeds 0-2 in both rungs (80 s / 200 s); seed 3 only in quality, at 1000 s, is not a pair.
    records = _two_rungs([1.0, 2.0, 3.0]) + [_line(3, "quality", 30.0, 1000)]
    (rung,) = preset_ladder(records)
    assert rung.seeds == (0, 1, 2)
    assert (rung.slower_seconds, rung.faster_seconds) == pytest.approx((200.0, 80.0))


# --- mean ± std --------------------------------------------------------------------------------------------

def test_stat_ignores_non_finite_bool_and_text_entries():
    # Catches: NaN / inf (a diverged run's metric) or True/False counted as numbers.  Numbers 1 and 3:
    # mean 2, sample std sqrt(((1-2)^2 + (3-2)^2) / (2 - 1)) = sqrt(2).
    s = Stat.of([1.0, float("nan"), 3.0, float("inf"), True, False, "unavailable", None])
    assert (s.mean, s.n) == (2.0, 2) and s.std == pytest.approx(math.sqrt(2.0))


def test_aggregate_orders_presets_fast_balanced_quality():
    # Catches: presets sorted alphabetically (balanced, fast, quality) instead of by cost.
    records = [_line(0, p, 20.0, 10, k=1) for p in ("quality", "balanced", "fast")]
    assert [a.preset for a in aggregate(records)] == ["fast", "balanced", "quality"]


# --- teacher dependence ------------------------------------------------------------------------------------

def _run(seed, teacher, final, k=1, preset="fast", last=None):
    return [_line(seed, preset, teacher if i == 0 else final, 10.0 * (i + 1), k=k, iteration=i)
            for i in range((k if last is None else last) + 1)]


def test_teacher_markdown_row_against_polyfit():
    # Catches: slope and r swapped in the table, the fitted gains at teacher mean - 1 / + 1 swapped, and a
    # wrong sign.  Teachers 15, 16, 17; gains 3, 2, 1.5: numpy.polyfit gives b = -0.75, a = 85/6;
    # r = -1.5 / sqrt(2 * 7/6) = -0.98; fitted gain at 15 dB = 2.92, at 17 dB = 1.42.
    fits = teacher_dependence(_run(0, 15.0, 18.0) + _run(1, 16.0, 18.0) + _run(2, 17.0, 18.5))
    b, a = np.polyfit([15.0, 16.0, 17.0], [3.0, 2.0, 1.5], 1)
    r = np.corrcoef([15.0, 16.0, 17.0], [3.0, 2.0, 1.5])[0, 1]
    t = r / math.sqrt(1 - r * r)                       # 1 dof: p = 1 - 2 atan(|t|) / pi
    p = 1 - 2 * math.atan(abs(t)) / math.pi
    rows = [x for x in teacher_dependence_markdown(fits) if x.startswith("| lego")]
    assert rows == [f"| lego | fast K=1 | senerf | 3 | 16.00 ± 1.00 | 2.17 ± 0.76 | {b:+.2f} | {r:+.2f} | {p:.3f} | "
                    f"{a + b * 15.0:+.2f} / {a + b * 17.0:+.2f} |"]
    assert rows[0].endswith("| -0.75 | -0.98 | 0.121 | +2.92 / +1.42 |")      # the same, by hand


def test_teacher_fit_of_two_runs_has_a_slope_but_no_p_value():
    # Catches: a p-value reported for a two-point fit (0 degrees of freedom; the docstring says None).
    (fit,) = teacher_dependence(_run(0, 15.0, 18.0) + _run(1, 17.0, 18.5))
    assert fit.slope == pytest.approx((1.5 - 3.0) / (17.0 - 15.0)) and fit.p_value is None


def test_unfinished_runs_never_form_a_rung():
    # Catches: counting a run that stopped before its K-th iteration as a (shorter) rung.  Two K=3 runs that
    # stopped at iteration 2 would otherwise form a "fast K=2" fit.
    lines = _run(0, 15.0, 18.0, k=3, last=2) + _run(1, 16.0, 18.0, k=3, last=2)
    assert teacher_dependence(lines) == []


# --- the report ----------------------------------------------------------------------------------------

_LLFF_SCENES = ("fern", "flower", "fortress", "horns", "leaves", "orchids", "room", "trex")


def _report(records):
    return make_report(records, ["senerf-bench", "report", "r.jsonl"])


def _final_table(text: str) -> list[str]:
    lines = text.splitlines()
    start = lines.index("Final iteration of each run:") + 4
    end = next(i for i in range(start, len(lines)) if not lines[i].startswith("|"))
    return lines[start:end]


def test_report_mean_of_scenes_is_the_arithmetic_mean():
    # Catches: the "mean of 8 scenes" row computed as anything but the plain mean of the per-scene means.
    # PSNR 10, 11, ..., 17 over the 8 LLFF scenes: mean 13.5.
    records = [_line(0, "fast", 10.0 + i, 60, k=0, method="baseline", scene=s, protocol="llff3@504x378")
               for i, s in enumerate(_LLFF_SCENES)]
    text = _report(records)
    assert "| mean of 8 scenes | baseline | fast | - | - | 13.50 |" in text
    assert "K-Planes (paper): 15.77" in text


def test_report_final_table_has_only_final_iterations_and_paper_rows_only_for_our_methods():
    # Catches: every self-training iteration listed in the final table, and a paper figure attached to an
    # ablation (which has no published counterpart).  Runs: senerf K=2 (iterations 0, 1, 2) and the
    # ablation senerf-no-empty K=2, both on lego.
    records = []
    for method in ("senerf", "senerf-no-empty"):
        records += [_line(0, "fast", 15.0 + i, 10.0 * (i + 1), k=2, iteration=i, method=method) for i in range(3)]
    rows = _final_table(_report(records))
    assert [r.split(" | ")[3] for r in rows] == ["2", "2"]              # the iter column
    senerf, ablation = sorted(rows, key=lambda r: "no-empty" in r)
    assert senerf.endswith("| SE-NeRF K-Planes (paper): 16.65 / 0.75 / 0.24 |")
    assert ablation.endswith("| - |")


def test_report_per_iteration_section_only_with_self_training():
    # Catches: the "Per self-training iteration" table printed for baseline-only results.
    base = [_line(0, "fast", 15.0, 30, k=0, method="baseline")]
    assert "Per self-training iteration" not in _report(base)
    assert "Per self-training iteration" in _report(base + _run(0, 15.0, 17.0))


#: REFERENCE.md section 6 ("Numbers to beat"), copied by hand: (family, scene, method, label) -> (PSNR,
#: SSIM, LPIPS).
_REFERENCE_FIGURES = {
    ("synthetic-extreme3", "mean", "K-Planes (paper, 8 scenes)"): (15.45, 0.73, 0.28),
    ("synthetic-extreme3", "mean", "SE-NeRF K-Planes (paper, 8 scenes)"): (17.49, 0.78, 0.23),
    ("synthetic-extreme3", "mean", "SE-NeRF NeRF (paper, 8 scenes)"): (17.41, None, None),
    ("synthetic-extreme3", "lego", "K-Planes (paper)"): (14.67, 0.68, 0.31),
    ("synthetic-extreme3", "lego", "SE-NeRF K-Planes (paper)"): (16.65, 0.75, 0.24),
    ("synthetic-infonerf4", "mean", "K-Planes (paper)"): (17.99, None, None),
    ("synthetic-infonerf4", "mean", "SE-NeRF K-Planes (paper)"): (19.93, None, None),
    ("synthetic-infonerf4", "mean", "SE-NeRF NeRF (paper)"): (20.53, None, None),
    ("synthetic-random8", "mean", "FreeNeRF (DietNeRF views, not seeded-random)"): (24.26, None, None),
    ("synthetic-random8", "mean", "DropGaussian (DietNeRF views, not seeded-random)"): (25.42, None, None),
    ("llff3", "mean", "K-Planes (paper)"): (15.77, None, None),
    ("llff3", "mean", "SE-NeRF K-Planes (paper)"): (16.30, None, None),
    ("llff3", "mean", "SE-NeRF NeRF (paper)"): (18.10, None, None),
    ("llff3", "mean", "FreeNeRF"): (19.63, None, None),
    ("llff3", "mean", "DropGaussian"): (20.76, None, None),
    ("llff3", "fern", "K-Planes (paper)"): (18.22, None, None),
    ("llff3", "fern", "SE-NeRF K-Planes (paper)"): (18.83, None, None),
}


def test_paper_figures_are_reference_section_6():
    # Catches: a mistyped published figure (only some were visible in the end-to-end report test).
    got = {(r.family, r.scene, r.label): (r.psnr, r.ssim, r.lpips) for r in PAPER_NUMBERS}
    assert got == _REFERENCE_FIGURES


def test_bench_protocol_view_lists_are_reference_section_5():
    # Catches: a typo in the bench's own copy of the Extreme / InfoNeRF view lists (REFERENCE.md section 5:
    # "chair 26,31,32; drums 3,9,14; ficus 12,36,56; hotdog 31,33,48; lego 0,1,51; materials 47,63,73;
    # ship 36,55,66; mic 35,65,82"; InfoNeRF [26, 86, 2, 55]).
    from senerf.bench import protocols

    assert dict(protocols.EXTREME_VIEWS) == {
        "chair": (26, 31, 32), "drums": (3, 9, 14), "ficus": (12, 36, 56), "hotdog": (31, 33, 48),
        "lego": (0, 1, 51), "materials": (47, 63, 73), "ship": (36, 55, 66), "mic": (35, 65, 82)}
    assert tuple(protocols.INFONERF4_VIEWS) == (26, 86, 2, 55)

