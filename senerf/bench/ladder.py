"""Paired comparisons over seeds: does a slower preset buy PSNR, is a configuration on the speed/accuracy frontier,
does a method differ from SE-NeRF (no torch import).

Seeds pair runs that share the initialisation and the ray order, which removes part of the seed-to-seed spread.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .results import final_ok_lines, latest_ok_lines
from .summary import Stat, preset_label

__all__ = ["LADDER_ALPHA", "LADDER_MIN_SEEDS", "paired_gain_p_value", "Paired", "pair_runs", "preset_ladder",
           "Rung", "frontier", "frontier_markdown", "method_contrasts", "paired_markdown"]

LADDER_ALPHA = 0.05
LADDER_MIN_SEEDS = 3


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


@dataclass(frozen=True)
class Paired:
    """Two configurations of one (scene, protocol) compared over the seeds both have, at their final iteration.

    Attributes:
        scene, protocol: the group.
        a, b: the configurations, ``"senerf fast 600x1024 K=1"`` (method, preset label, K): the slower and the faster
            rung in the ladder, the method and the reference in a contrast.
        seeds: the seeds both have (the pairs).
        a_seconds, b_seconds: mean seconds of fitting over those seeds.
        diff: stats of the per-seed PSNR differences ``a - b`` (dB).
        p_value: paired t-test p-value (``None`` with fewer than 2 pairs): one-sided (H1: ``a`` is better) in the
            ladder, two-sided in a contrast.
        measurable: ``p_value <`` :data:`LADDER_ALPHA` with at least :data:`LADDER_MIN_SEEDS` pairs.
    """

    scene: str
    protocol: str
    a: str
    b: str
    seeds: tuple[int, ...]
    a_seconds: float
    b_seconds: float
    diff: Stat
    p_value: float | None
    measurable: bool


def _configurations(records: list[dict]) -> dict[tuple, dict[int, dict]]:
    """(scene, protocol, method, configuration ``"senerf fast K=1"``) -> seed -> the run's final line."""
    finals: dict[tuple, dict[int, dict]] = defaultdict(dict)
    for r in final_ok_lines(records):
        label = f"{r['method']} {preset_label(r)} K={r['iteration']}"
        finals[(r["scene"], r["protocol"], r["method"], label)][r["seed"]] = r
    return finals


def pair_runs(group: tuple, a: tuple[str, dict], b: tuple[str, dict], alternative: str) -> Paired:
    """Configuration ``a`` (label, seed -> a line with ``psnr`` and ``seconds_cumulative``) against ``b`` in ``group``
    (scene, protocol), over the seeds both have."""
    seeds = tuple(sorted(set(a[1]) & set(b[1])))
    diffs = [a[1][s]["psnr"] - b[1][s]["psnr"] for s in seeds]
    seconds = [float(np.mean([runs[s]["seconds_cumulative"] for s in seeds])) if seeds else math.nan
               for runs in (a[1], b[1])]
    p = paired_gain_p_value(diffs, alternative)
    return Paired(*group, a[0], b[0], seeds, *seconds, Stat.of(diffs), p,
                  p is not None and len(seeds) >= LADDER_MIN_SEEDS and p < LADDER_ALPHA)


def preset_ladder(records: list[dict]) -> list[Paired]:
    """Every slower rung against every faster one (by mean seconds), per (scene, protocol, method).

    A *rung* is one (scene, protocol, method, preset label, K) group at its final iteration: what a user gets from
    ``senerf-fit --preset P --iterations K``.  Each pair is a :class:`Paired` with ``a`` the slower rung and the
    one-sided test.  Failed runs and earlier attempts are left out; a method with a single rung gives none.
    Sorted by (scene, protocol, method, slower's seconds, faster's seconds).
    """
    groups: dict[tuple, dict[str, dict]] = defaultdict(dict)
    for (scene, protocol, method, label), runs in sorted(_configurations(records).items()):
        groups[(scene, protocol, method)][label] = runs
    out = []
    for (scene, protocol, _), rungs in groups.items():
        order = sorted(rungs.items(), key=lambda kv: (np.mean([r["seconds_cumulative"] for r in kv[1].values()]),
                                                      kv[0]))
        out += [pair_runs((scene, protocol), slower, faster, "greater") for i, slower in enumerate(order)
                for faster in order[:i]]
    return out


@dataclass(frozen=True)
class Rung:
    """One configuration of a (scene, protocol) on the speed/accuracy plane.

    Attributes:
        scene, protocol: the group.
        config: ``"senerf balanced 3000x1024 K=1"``, or ``"baseline fast 600x1024 K=0"`` for a teacher alone.
        seeds: its seeds; seconds: mean fitting seconds over them; psnr: :class:`Stat` of the final PSNR.
        beaten_by: every faster configuration measurably better than this one (:class:`Paired`, ``a`` the faster);
            empty: on the measured frontier.
    """

    scene: str
    protocol: str
    config: str
    seeds: tuple[int, ...]
    seconds: float
    psnr: Stat
    beaten_by: tuple[Paired, ...]


def frontier(records: list[dict]) -> list[Rung]:
    """Every measured configuration of each (scene, protocol), whether a faster one is measurably better.

    The configurations are the final iterations of every method and preset label (what ``senerf-fit`` gives) and
    the teachers of the self-training runs (iteration 0 is the baseline fit at the same schedule and seed, so it
    is a configuration a user can run: ``--iterations 0``).  A configuration is *beaten* by a faster one (mean
    seconds over its seeds) when the faster one's PSNR is higher, paired over common seeds, one-sided
    ``p <`` :data:`LADDER_ALPHA` with at least :data:`LADDER_MIN_SEEDS` pairs.  Sorted by group, then seconds.
    """
    groups: dict[tuple, dict[str, dict[int, dict]]] = defaultdict(dict)
    for (scene, protocol, _, label), runs in _configurations(records).items():
        groups[(scene, protocol)][label] = runs
    for r in latest_ok_lines(records):
        if r["iteration"] == 0:
            groups[(r["scene"], r["protocol"])].setdefault(f"baseline {preset_label(r)} K=0", {})[r["seed"]] = r
    out = []
    for group, configs in sorted(groups.items()):
        seconds = {label: float(np.mean([r["seconds_cumulative"] for r in runs.values()]))
                   for label, runs in configs.items()}
        for label, runs in configs.items():
            beaten = [pair_runs(group, (other, configs[other]), (label, runs), "greater")
                      for other in sorted(configs, key=seconds.get) if seconds[other] < seconds[label]]
            out.append(Rung(*group, label, tuple(sorted(runs)), seconds[label],
                            Stat.of([r["psnr"] for r in runs.values()]), tuple(p for p in beaten if p.measurable)))
    return sorted(out, key=lambda r: (r.scene, r.protocol, r.seconds, r.config))


def frontier_markdown(rungs: list[Rung]) -> list[str]:
    """Markdown lines: what is checked, then one row per :class:`Rung` (empty list when there are none)."""
    if not rungs:
        return []
    out = ["", "The speed/accuracy frontier: every configuration (K=0: a teacher alone) and each faster one that is "
           f"measurably better (paired over seeds, one-sided p < {LADDER_ALPHA:g}, at least {LADDER_MIN_SEEDS} "
           "pairs); none: on the frontier.", "",
           "| scene | configuration | seeds | seconds | PSNR | faster and measurably better |", "|" + "---|" * 6]
    for r in rungs:
        beaten = "; ".join(f"{p.a} ({p.a_seconds:.0f} s, {p.diff.text(2)} dB, p {p.p_value:.3f})"
                           for p in r.beaten_by) or "none"
        out.append(f"| {r.scene} | {r.config} | {len(r.seeds)} | {r.seconds:.0f} | {r.psnr.text(2)} | {beaten} |")
    return out


def method_contrasts(records: list[dict], reference: str = "senerf") -> list[Paired]:
    """Every method against ``reference`` at the same (scene, protocol, preset, K) (ablations, analyses), with the
    two-sided test, sorted by (scene, protocol, configuration); the baseline (K = 0) never shares a rung with a
    self-training method."""
    finals = _configurations(records)
    out = []
    for (scene, protocol, method, label), runs in sorted(finals.items()):
        ref_label = reference + label.removeprefix(method)
        ref = finals.get((scene, protocol, reference, ref_label))
        if method != reference and ref is not None:
            out.append(pair_runs((scene, protocol), (label, runs), (ref_label, ref), "two-sided"))
    return out


def paired_markdown(pairs: list[Paired], ladder: bool = True) -> list[str]:
    """Markdown lines: what is compared, then one table row per pair (empty list when there are none);
    ``ladder``: pairs of :func:`preset_ladder`, else of :func:`method_contrasts`."""
    if not pairs:
        return []
    a, b, test = ("slower", "faster", "one-sided") if ladder else ("method", "reference", "two-sided")
    intro = ("Does each slower preset buy PSNR?" if ladder else
             "Ablations and analyses against SE-NeRF at the same preset.")
    out = ["", f"{intro} Paired over seeds: PSNR {a} - {b}, mean ± std; {test} paired t-test; *measurable* when "
           f"p < {LADDER_ALPHA:g} with at least {LADDER_MIN_SEEDS} pairs.", "",
           f"| scene | {a} | {b} | pairs | seconds ({a} / {b}) | PSNR {a} - {b} | p | measurable |", "|" + "---|" * 8]
    for r in pairs:
        p = "-" if r.p_value is None else f"{r.p_value:.3f}"
        verdict = "yes" if r.measurable else ("no" if len(r.seeds) >= LADDER_MIN_SEEDS else "too few seeds")
        out.append(f"| {r.scene} | {r.a} | {r.b} | {len(r.seeds)} | {r.a_seconds:.0f} / {r.b_seconds:.0f} | "
                   f"{r.diff.text(2)} | {p} | {verdict} |")
    return out
