"""Mean and spread over seeds, per (scene, protocol, method, preset, iteration); never the best run.

The spread is the sample standard deviation (``ddof=1``); with a single seed it is ``None`` (printed as
``n=1``), since one run says nothing about spread.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from .results import latest_ok_lines

__all__ = ["Stat", "Aggregate", "aggregate", "final_iterations", "format_table", "preset_label", "GROUP_FIELDS",
           "PRESET_ORDER"]

GROUP_FIELDS = ("scene", "protocol", "method", "preset", "iterations", "iteration")
#: display order of preset names ("quality" sorts results of the removed preset after the current ones)
PRESET_ORDER = {"fast": 0, "balanced": 1, "quality": 2}
_METRICS = ("psnr", "ssim", "lpips", "avg", "seconds_cumulative", "peak_memory_mib")


@dataclass(frozen=True)
class Stat:
    """Mean and sample standard deviation of one metric over ``n`` seeds (``None`` where undefined)."""

    mean: float | None
    std: float | None
    n: int

    @staticmethod
    def of(values: list) -> "Stat":
        """Stat of the numeric entries of ``values`` ("unavailable" and None are left out)."""
        xs = np.array([v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v)], dtype=np.float64)
        if xs.size == 0:
            return Stat(None, None, 0)
        return Stat(float(xs.mean()), float(xs.std(ddof=1)) if xs.size > 1 else None, int(xs.size))

    def text(self, digits: int = 2) -> str:
        """``"17.49 ± 0.31"``, ``"17.49 (n=1)"`` or ``"-"``."""
        if self.mean is None:
            return "-"
        if self.std is None:
            return f"{self.mean:.{digits}f} (n=1)"
        return f"{self.mean:.{digits}f} ± {self.std:.{digits}f}"


@dataclass(frozen=True)
class Aggregate:
    """Statistics over seeds of one group.

    Attributes:
        scene, protocol, method, preset (:func:`preset_label`), iteration: the group.
        seeds: the seeds present.
        iterations: K, the self-training rounds of the group's runs (part of the group).
        psnr, ssim, lpips, avg: metric stats (dB, [0, 1], LPIPS, Avg.).
        seconds: cumulative seconds up to this iteration; peak_memory_mib: max RSS of the fit, MiB.
    """

    scene: str
    protocol: str
    method: str
    preset: str
    iteration: int
    seeds: tuple[int, ...]
    iterations: int
    psnr: Stat
    ssim: Stat
    lpips: Stat
    avg: Stat
    seconds: Stat
    peak_memory_mib: Stat


def preset_label(line: dict) -> str:
    """The preset as reported: ``"fast"``, or ``"fast+steps20"`` / ``"fast+cuda"`` when a run overrides the
    preset's steps or runs on a GPU, so different experiments never share a row."""
    label = str(line["preset"])
    if line.get("steps") is not None:
        label += f"+steps{line['steps']}"
    if line.get("device", "cpu") != "cpu":
        label += f"+{line['device']}"
    return label


def aggregate(records: list[dict]) -> list[Aggregate]:
    """Group the ok lines (last attempt per run) and compute stats over seeds, sorted by group.

    Groups are (scene, protocol, method, :func:`preset_label`, K = ``iterations``, iteration): runs with a
    different number of self-training rounds are different experiments even where their iterations overlap.
    """
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in latest_ok_lines(records):
        groups[(r["scene"], r["protocol"], r["method"], preset_label(r), int(r.get("iterations", 0)),
                r["iteration"])].append(r)
    out = []
    for key in sorted(groups, key=lambda k: (k[0], k[1], k[2], PRESET_ORDER.get(k[3].split("+")[0], 9), k[3],
                                             k[4], k[5])):
        rows = groups[key]
        stats = {m: Stat.of([r.get(m) for r in rows]) for m in _METRICS}
        out.append(Aggregate(*key[:4], iteration=key[5], seeds=tuple(sorted(r["seed"] for r in rows)),
                             iterations=key[4],
                             psnr=stats["psnr"], ssim=stats["ssim"], lpips=stats["lpips"], avg=stats["avg"],
                             seconds=stats["seconds_cumulative"], peak_memory_mib=stats["peak_memory_mib"]))
    return out


def final_iterations(aggs: list[Aggregate]) -> list[Aggregate]:
    """Only each (scene, protocol, method, preset, K)'s last iteration (the result a user gets)."""
    last: dict[tuple, Aggregate] = {}
    for a in aggs:
        k = (a.scene, a.protocol, a.method, a.preset, a.iterations)
        if k not in last or a.iteration > last[k].iteration:
            last[k] = a
    return [a for a in aggs if last[(a.scene, a.protocol, a.method, a.preset, a.iterations)] is a]


def format_table(aggs: list[Aggregate], markdown: bool = False) -> str:
    """A table of the aggregates: plain text (aligned columns) or GitHub markdown."""
    header = ["scene", "protocol", "method", "preset", "iter", "seeds", "PSNR", "SSIM", "LPIPS", "Avg.",
              "seconds", "peak MiB"]
    rows = [[a.scene, a.protocol, a.method, a.preset, str(a.iteration), str(len(a.seeds)), a.psnr.text(2),
             a.ssim.text(3), _lpips_text(a.lpips, 3), _lpips_text(a.avg, 3), a.seconds.text(0),
             a.peak_memory_mib.text(0)] for a in aggs]
    if markdown:
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return "\n".join([fmt.format(*header), fmt.format(*("-" * w for w in widths))] + [fmt.format(*r) for r in rows])


def _lpips_text(stat: Stat, digits: int) -> str:
    return "unavailable" if stat.mean is None else stat.text(digits)
