"""Mean and sample standard deviation over seeds, per (scene, protocol, method, preset, K, iteration); never the
best run."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from senerf.errors import is_number

from .results import latest_ok_lines

__all__ = ["Stat", "Aggregate", "aggregate", "final_iterations", "format_table", "preset_label", "preset_name",
           "PRESET_ORDER"]

#: Display order of preset names (cheapest first; other names after them).
PRESET_ORDER = {"fast": 0, "balanced": 1}
_METRICS = ("psnr", "ssim", "lpips", "avg", "seconds_cumulative", "peak_memory_mib")


@dataclass(frozen=True)
class Stat:
    """Mean and sample standard deviation (``ddof=1``) of one metric over ``n`` seeds; ``None`` where undefined (the
    spread of a single seed, printed ``n=1``: one run says nothing about spread)."""

    mean: float | None
    std: float | None
    n: int

    @staticmethod
    def of(values: list) -> "Stat":
        """Stat of the finite numbers among ``values`` (``"unavailable"``, None and NaN are left out).

        Example:
            >>> Stat.of([1.0, 3.0, "unavailable"]).text()
            '2.00 ± 1.41'
        """
        xs = np.array([v for v in values if is_number(v)], dtype=np.float64)
        if xs.size == 0:
            return Stat(None, None, 0)
        return Stat(float(xs.mean()), float(xs.std(ddof=1)) if xs.size > 1 else None, int(xs.size))

    def text(self, digits: int = 2) -> str:
        """``"17.49 ± 0.31"``, ``"17.49 (n=1)"`` or ``"-"``."""
        if self.mean is None:
            return "-"
        return f"{self.mean:.{digits}f} " + ("(n=1)" if self.std is None else f"± {self.std:.{digits}f}")


@dataclass(frozen=True)
class Aggregate:
    """Statistics over seeds of one group.

    Attributes:
        scene, protocol, method, preset (:func:`preset_label`), iterations (K, the self-training rounds of the
            group's runs), iteration: the group.
        seeds: the seeds present.
        psnr, ssim, lpips, avg: metric stats (dB, [-1, 1], LPIPS, Avg.).
        seconds: cumulative seconds up to this iteration; peak_memory_mib: max RSS of the fit, MiB.
    """

    scene: str
    protocol: str
    method: str
    preset: str
    iterations: int
    iteration: int
    seeds: tuple[int, ...]
    psnr: Stat
    ssim: Stat
    lpips: Stat
    avg: Stat
    seconds: Stat
    peak_memory_mib: Stat


def preset_label(line: dict) -> str:
    """The preset as reported, with the schedule it trained where the line records one (``"fast 600x1024"``:
    steps x rays a step, so a preset redefined between runs never shares a row), else ``"fast"`` or
    ``"fast+steps20"`` when the run overrides the preset's steps; ``"+cuda"`` when it ran on a GPU."""
    label = str(line["preset"])
    if line.get("schedule"):
        label += f" {line['schedule']}"
    elif line.get("steps") is not None:
        label += f"+steps{line['steps']}"
    if line.get("device", "cpu") != "cpu":
        label += f"+{line['device']}"
    return label


def preset_name(label: str) -> str:
    """The preset's name in a :func:`preset_label`: ``"fast"`` of ``"fast 600x1024+cuda"``."""
    return label.split("+")[0].split(" ")[0]


def aggregate(records: list[dict]) -> list[Aggregate]:
    """Group the ok lines (last attempt per run) and compute stats over seeds, sorted by group.

    Groups are (scene, protocol, method, :func:`preset_label`, K = ``iterations``, iteration): runs with a
    different number of self-training rounds are different experiments even where their iterations overlap.
    """
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in latest_ok_lines(records):
        groups[(r["scene"], r["protocol"], r["method"], preset_label(r), r["iterations"], r["iteration"])].append(r)
    out = []
    for key in sorted(groups, key=lambda k: (*k[:3], PRESET_ORDER.get(preset_name(k[3]), len(PRESET_ORDER)), *k[3:])):
        rows = groups[key]
        psnr, ssim, lpips, avg, seconds, memory = (Stat.of([r.get(m) for r in rows]) for m in _METRICS)
        out.append(Aggregate(*key, tuple(sorted(r["seed"] for r in rows)), psnr, ssim, lpips, avg, seconds, memory))
    return out


def final_iterations(aggs: list[Aggregate]) -> list[Aggregate]:
    """Only each (scene, protocol, method, preset, K)'s last iteration (the result a user gets)."""
    return [a for a in aggs if a.iteration == a.iterations]


def format_table(aggs: list[Aggregate], markdown: bool = False, extra: tuple[str, list[str]] | None = None) -> str:
    """A table of the aggregates: plain text (aligned columns) or GitHub markdown; ``extra``: (header, one cell per
    aggregate) of a last column."""
    header = ["scene", "protocol", "method", "preset", "K", "iter", "seeds", "PSNR", "SSIM", "LPIPS", "Avg.",
              "seconds", "peak MiB"]
    rows = [[a.scene, a.protocol, a.method, a.preset, str(a.iterations), str(a.iteration), str(len(a.seeds)),
             a.psnr.text(2), a.ssim.text(3), a.lpips.text(3), a.avg.text(3), a.seconds.text(0),
             a.peak_memory_mib.text(0)] for a in aggs]
    if extra is not None:
        header, rows = header + [extra[0]], [row + [cell] for row, cell in zip(rows, extra[1])]
    if markdown:
        return "\n".join(["| " + " | ".join(r) + " |" for r in [header, ["---"] * len(header), *rows]])
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip()
                     for r in [header, ["-" * w for w in widths], *rows])
