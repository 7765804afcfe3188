"""Does each slower preset buy PSNR?  Paired comparisons over seeds (issue #5's rule for presets).

A *rung* is one (scene, protocol, method, preset label, K) group at its final iteration: what a user gets
from ``senerf-fit --preset P --iterations K``.  Within one (scene, protocol, method), every rung is compared
with every faster one (by mean seconds) over the seeds both have: the per-seed PSNR differences
``slower - faster`` give the gain (mean ± sample std) and a one-sided paired t-test (H1: the slower rung is
better).  The rule, stated once here and in the report: a slower rung *buys measurable PSNR* over a faster
one when it has at least ``min_seeds`` paired seeds and ``p < alpha`` (defaults 3 and 0.05).  Seeds pair
runs that share the initialisation and the ray order's seed, which removes part of the seed-to-seed spread
(few-shot PSNR moves ~0.6 dB with the seed alone).

No torch import (the harness summarises results on machines without it).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .results import final_ok_lines, latest_ok_lines
from .summary import Stat, preset_label

__all__ = ["Rung", "preset_ladder", "paired_gain_p_value", "ladder_markdown", "LADDER_ALPHA", "LADDER_MIN_SEEDS",
           "Contrast", "method_contrasts", "contrasts_markdown", "TeacherFit", "teacher_dependence",
           "teacher_dependence_markdown"]

LADDER_ALPHA = 0.05
LADDER_MIN_SEEDS = 3


@dataclass(frozen=True)
class Rung:
    """One comparison of a slower preset against a faster one.

    Attributes:
        scene, protocol, method: the group both rungs belong to.
        slower, faster: rung labels, ``"balanced K=3"`` (preset label and self-training rounds).
        seeds: the seeds both rungs have (the pairs).
        slower_seconds, faster_seconds: mean seconds of fitting over those seeds.
        gain: stats of the per-seed PSNR differences ``slower - faster`` (dB).
        p_value: one-sided paired t-test p-value (``None`` with fewer than 2 pairs).
        measurable: ``p_value < alpha`` with at least ``min_seeds`` pairs.
    """

    scene: str
    protocol: str
    method: str
    slower: str
    faster: str
    seeds: tuple[int, ...]
    slower_seconds: float
    faster_seconds: float
    gain: Stat
    p_value: float | None
    measurable: bool


def paired_gain_p_value(diffs, alternative: str = "greater") -> float | None:
    """p-value of the paired t-test on ``diffs`` (shape ``(n,)``): one-sided, that their mean is above 0
    (``alternative="greater"``, the default), or ``"two-sided"``.

    ``None`` for fewer than 2 differences; with zero spread (the t statistic is infinite or undefined) 0.0
    when the mean is on the tested side of 0 and 1.0 otherwise.

    Example:
        >>> round(paired_gain_p_value([1.0, 2.0, 3.0]), 4)   # t = 2 / (1 / sqrt 3), 2 dof
        0.0371
    """
    d = np.asarray(diffs, dtype=np.float64).reshape(-1)
    if d.size < 2:
        return None
    if float(d.std(ddof=1)) == 0.0:
        mean = float(d.mean())
        return 0.0 if (mean > 0 if alternative == "greater" else mean != 0) else 1.0
    return float(stats.ttest_1samp(d, 0.0, alternative=alternative).pvalue)


def _final_lines(records: list[dict]) -> dict[tuple, dict[int, dict]]:
    """(scene, protocol, method, rung label) -> seed -> the run's last-iteration line."""
    finals: dict[tuple, dict[int, dict]] = defaultdict(dict)
    for r in final_ok_lines(records):
        finals[(r["scene"], r["protocol"], r["method"], f"{preset_label(r)} K={r['iteration']}")][r["seed"]] = r
    return finals


def preset_ladder(records: list[dict], alpha: float = LADDER_ALPHA,
                  min_seeds: int = LADDER_MIN_SEEDS) -> list[Rung]:
    """Every slower rung against every faster one, per (scene, protocol, method); see the module doc.

    Args:
        records: results-file lines (:func:`senerf.bench.results.load_results`); failed runs and earlier
            attempts are left out (:func:`senerf.bench.results.final_ok_lines`).
        alpha: significance level of the one-sided paired t-test.
        min_seeds: fewest paired seeds for a verdict of "measurable".

    Returns:
        Rungs sorted by (scene, protocol, method, slower's seconds, faster's seconds); groups with a single
        rung give none.
    """
    finals = _final_lines(records)
    groups: dict[tuple, list[str]] = defaultdict(list)
    for scene, protocol, method, label in finals:
        groups[(scene, protocol, method)].append(label)
    out = []
    for (scene, protocol, method), labels in sorted(groups.items()):
        secs = {lb: float(np.mean([r["seconds_cumulative"] for r in finals[(scene, protocol, method, lb)].values()]))
                for lb in labels}
        order = sorted(labels, key=lambda lb: (secs[lb], lb))
        for i, slower in enumerate(order):
            for faster in order[:i]:
                a, b = finals[(scene, protocol, method, slower)], finals[(scene, protocol, method, faster)]
                seeds = tuple(sorted(set(a) & set(b)))
                diffs = [a[s]["psnr"] - b[s]["psnr"] for s in seeds]
                p = paired_gain_p_value(diffs)
                out.append(Rung(scene, protocol, method, slower, faster, seeds,
                                float(np.mean([a[s]["seconds_cumulative"] for s in seeds])) if seeds else math.nan,
                                float(np.mean([b[s]["seconds_cumulative"] for s in seeds])) if seeds else math.nan,
                                Stat.of(diffs), p,
                                measurable=p is not None and len(seeds) >= min_seeds and p < alpha))
    return out


def ladder_markdown(rungs: list[Rung], alpha: float = LADDER_ALPHA, min_seeds: int = LADDER_MIN_SEEDS) -> list[str]:
    """Markdown lines: the rule, then one table row per rung (empty list when there are no rungs)."""
    if not rungs:
        return []
    out = ["", f"Does each slower preset buy PSNR? Paired over seeds (same seed in both rungs): gain = slower - "
           f"faster, mean ± std; one-sided paired t-test; *measurable* when p < {alpha:g} with at least "
           f"{min_seeds} pairs.", "",
           "| scene | method | slower | faster | pairs | seconds (slower / faster) | PSNR gain | p | measurable |",
           "|" + "---|" * 9]
    for r in rungs:
        p = "-" if r.p_value is None else f"{r.p_value:.3f}"
        verdict = "yes" if r.measurable else ("no" if len(r.seeds) >= min_seeds else "too few seeds")
        out.append(f"| {r.scene} | {r.method} | {r.slower} | {r.faster} | {len(r.seeds)} | "
                   f"{r.slower_seconds:.0f} / {r.faster_seconds:.0f} | {r.gain.text(2)} | {p} | {verdict} |")
    return out


@dataclass(frozen=True)
class Contrast:
    """A method against the reference method at the same preset and K, paired by seed.

    Attributes:
        scene, protocol, rung: the group (rung label ``"fast K=1"``).
        method, reference: the compared method and the reference (``"senerf"``).
        seeds: the seeds both have.
        diff: stats of the per-seed PSNR differences ``method - reference`` (dB).
        p_value: two-sided paired t-test p-value (``None`` with fewer than 2 pairs).
    """

    scene: str
    protocol: str
    rung: str
    method: str
    reference: str
    seeds: tuple[int, ...]
    diff: Stat
    p_value: float | None


def method_contrasts(records: list[dict], reference: str = "senerf") -> list[Contrast]:
    """Every method that shares a (scene, protocol, preset, K) rung with ``reference`` (ablations, analyses),
    paired by seed; the baseline (K = 0) never shares a rung with a self-training method.

    Returns:
        Contrasts sorted by (scene, protocol, rung, method).
    """
    finals = _final_lines(records)
    out = []
    for (scene, protocol, method, rung), runs in sorted(finals.items()):
        ref = finals.get((scene, protocol, reference, rung))
        if method == reference or ref is None:
            continue
        seeds = tuple(sorted(set(runs) & set(ref)))
        diffs = [runs[s]["psnr"] - ref[s]["psnr"] for s in seeds]
        out.append(Contrast(scene, protocol, rung, method, reference, seeds, Stat.of(diffs),
                            paired_gain_p_value(diffs, alternative="two-sided")))
    return sorted(out, key=lambda c: (c.scene, c.protocol, c.rung, c.method))


def contrasts_markdown(contrasts: list[Contrast]) -> list[str]:
    """Markdown lines: one row per contrast (empty list when there are none)."""
    if not contrasts:
        return []
    out = ["", "Ablations and analyses against SE-NeRF at the same preset, paired over seeds: difference = "
           "method - reference, mean ± std; two-sided paired t-test.", "",
           "| scene | rung | method | reference | pairs | PSNR difference | p |", "|" + "---|" * 7]
    for c in contrasts:
        p = "-" if c.p_value is None else f"{c.p_value:.3f}"
        out.append(f"| {c.scene} | {c.rung} | {c.method} | {c.reference} | {len(c.seeds)} | {c.diff.text(2)} | {p} |")
    return out


@dataclass(frozen=True)
class TeacherFit:
    """How a self-training rung's gain over its own teacher depends on that teacher, over its runs.

    One point per run (seed): ``x`` = the teacher's PSNR (iteration 0 of the same run), ``y`` = the final
    iteration's PSNR minus it.  A least-squares line ``y = intercept + slope * x`` with Pearson's ``r`` and
    the two-sided p-value of a zero slope (``scipy.stats.linregress``).  A slope near -1 means the final PSNR
    does not depend on the teacher (the gain is what the teacher lacked); near 0, a fixed gain.

    Attributes:
        scene, protocol, method, rung: the group (rung label ``"balanced K=3"``).
        seeds: (n,) the runs' seeds; teacher_psnr, gain: (n,) tuples of floats, in seed order.
        slope, intercept, r, p_value: the fit (``p_value`` None with fewer than 3 runs, ``r`` and slope None
            when the teachers' PSNR does not vary).
    """

    scene: str
    protocol: str
    method: str
    rung: str
    seeds: tuple[int, ...]
    teacher_psnr: tuple[float, ...]
    gain: tuple[float, ...]
    slope: float | None
    intercept: float | None
    r: float | None
    p_value: float | None

    def gain_at(self, teacher_psnr: float) -> float | None:
        """The fitted gain for a teacher of ``teacher_psnr`` dB (None without a fit)."""
        return None if self.slope is None else self.intercept + self.slope * float(teacher_psnr)


def teacher_dependence(records: list[dict]) -> list[TeacherFit]:
    """A :class:`TeacherFit` per self-training rung (scene, protocol, method, preset label, K > 0) with at
    least 2 runs that have both their teacher and their final iteration; sorted by group.

    Example:
        >>> lines = [dict(run_key=f"k{s}", status="ok", attempt="a", scene="lego", protocol="p", method="m",
        ...               preset="fast", seed=s, iterations=1, iteration=i, psnr=psnr)
        ...          for s, t in enumerate((15.0, 16.0, 17.0)) for i, psnr in ((0, t), (1, 17.5))]
        >>> fit, = teacher_dependence(lines)
        >>> round(fit.slope, 6), round(fit.gain_at(14.0), 6)      # a final PSNR independent of the teacher
        (-1.0, 3.5)
    """
    runs: dict[str, dict[int, dict]] = defaultdict(dict)
    for r in latest_ok_lines(records):
        runs[r["run_key"]][int(r["iteration"])] = r
    groups: dict[tuple, list[tuple[int, float, float]]] = defaultdict(list)
    for its in runs.values():
        k = max(its)
        final = its[k]
        if k == 0 or k != int(final.get("iterations", 0)) or 0 not in its:
            continue
        key = (final["scene"], final["protocol"], final["method"], f"{preset_label(final)} K={k}")
        groups[key].append((int(final["seed"]), float(its[0]["psnr"]), float(final["psnr"]) - float(its[0]["psnr"])))
    out = []
    for (scene, protocol, method, rung), points in sorted(groups.items()):
        if len(points) < 2:
            continue
        seeds, teacher, gain = zip(*sorted(points))
        x, y = np.array(teacher), np.array(gain)
        slope = intercept = r = p_value = None
        if float(np.ptp(x)) > 0:
            fit = stats.linregress(x, y)
            slope, intercept, r = float(fit.slope), float(fit.intercept), float(fit.rvalue)
            p_value = float(fit.pvalue) if len(points) >= 3 else None
        out.append(TeacherFit(scene, protocol, method, rung, seeds, teacher, gain, slope, intercept, r, p_value))
    return out


def teacher_dependence_markdown(fits: list[TeacherFit]) -> list[str]:
    """Markdown lines: one row per fit with at least 3 runs (empty list when there are none)."""
    fits = [f for f in fits if len(f.seeds) >= 3]
    if not fits:
        return []
    out = ["", "Gain over the teacher against the teacher's PSNR, one point per run (seed): least-squares line "
           "gain = a + b * teacher, Pearson's r, two-sided p of b = 0 (b = -1: the final PSNR does not depend "
           "on the teacher; b = 0: a fixed gain). Plot: `gain_vs_teacher_*.png` (`senerf-bench plot`).", "",
           "| scene | rung | method | runs | teacher PSNR | gain | b (dB/dB) | r | p | fitted gain at teacher "
           "mean - 1 dB / mean + 1 dB |", "|" + "---|" * 10]
    for f in fits:
        t, g = Stat.of(list(f.teacher_psnr)), Stat.of(list(f.gain))
        if f.slope is None:
            b = r = p = at = "-"
        else:
            b, r = f"{f.slope:+.2f}", f"{f.r:+.2f}"
            p = "-" if f.p_value is None else f"{f.p_value:.3f}"
            at = f"{f.gain_at(t.mean - 1.0):+.2f} / {f.gain_at(t.mean + 1.0):+.2f}"
        out.append(f"| {f.scene} | {f.rung} | {f.method} | {len(f.seeds)} | {t.text(2)} | {g.text(2)} | {b} | {r} | "
                   f"{p} | {at} |")
    return out
