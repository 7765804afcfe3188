"""The plots of a results file: the frontier, and ours against the paper per scene (matplotlib's Agg canvas; no
global backend switch, no pyplot state)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

from .summary import PRESET_ORDER, Aggregate

if TYPE_CHECKING:
    from .report import SceneComparison

__all__ = ["plot_frontier", "plot_paper_comparison"]


def plot_frontier(aggs: list[Aggregate], path: str | Path, title: str = "") -> Path:
    """PSNR vs cumulative fit seconds (left) and vs peak memory MiB (right); error bars = std over seeds.

    Per method (and K: ``"senerf K=3"``), a solid line joins the final iterations of the presets (fast ->
    balanced); on the left, a dotted line per preset also traces its self-training iterations from its teacher (a
    hollow marker, labelled ``K=0``).
    Memory is a whole-run figure, so the right panel shows final iterations only (runs whose memory was not
    measured are left out).  The legend sits to the right of the panels, where it hides no data.

    Args:
        aggs: aggregates of one scene/protocol (others are drawn too but share the axes).
        path: output PNG, written as given (no suffix added), its folder made.
    """
    fig = Figure(figsize=(11, 4.2))
    ax_t, ax_m = fig.subplots(1, 2)
    runs: dict[tuple, list[Aggregate]] = defaultdict(list)
    for a in aggs:
        runs[(a.scene, a.protocol, f"{a.method} K={a.iterations}" if a.iterations else a.method, a.preset)].append(a)
    by_method: dict[tuple, list[Aggregate]] = defaultdict(list)
    for (scene, protocol, method, preset), group in runs.items():
        group.sort(key=lambda a: a.iteration)
        by_method[(scene, protocol, method)].append(group[-1])
        if len(group) > 1:   # the iterations, from the teacher (hollow: a configuration too, --iterations 0)
            ax_t.plot([a.seconds.mean for a in group], [a.psnr.mean for a in group], ":", color="0.5", lw=1)
            ax_t.plot(group[0].seconds.mean, group[0].psnr.mean, "o", mfc="none", color="0.4", ms=6)
            ax_t.annotate(f"{preset} K=0", (group[0].seconds.mean, group[0].psnr.mean), textcoords="offset points",
                          xytext=(4, -10), fontsize=7, color="0.4")
    one_group = len({k[:2] for k in by_method}) == 1
    n = len(by_method)   # matplotlib's 10-colour cycle, evenly spaced 'turbo' colours beyond: no two alike
    colours = [f"C{i}" for i in range(n)] if n <= 10 else [colormaps["turbo"](x) for x in np.linspace(0.0, 1.0, n)]
    for i, ((key, finals), colour) in enumerate(zip(sorted(by_method.items()), colours)):
        finals.sort(key=lambda a: PRESET_ORDER.get(a.preset, len(PRESET_ORDER)))
        for ax, stat in ((ax_t, "seconds"), (ax_m, "peak_memory_mib")):
            shown = [a for a in finals if getattr(a, stat).mean is not None]
            if shown:
                xs, ys = [getattr(a, stat).mean for a in shown], [a.psnr.mean for a in shown]
                ax.errorbar(xs, ys, xerr=[getattr(a, stat).std or 0.0 for a in shown],
                            yerr=[a.psnr.std or 0.0 for a in shown], color=colour, marker="os^Dv"[i % 5], capsize=3,
                            label=" ".join(key[2:] if one_group else key))
                for a, x, y in zip(shown, xs, ys):
                    ax.annotate(a.preset, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax_t.set_xscale("log")
    ax_t.margins(x=0.15)   # room for the labels of the rightmost points
    ax_t.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))   # 20, 50, 100, 200, 500 s ...
    ax_t.xaxis.set_major_formatter(ScalarFormatter())   # ... as plain numbers, not 2 x 10^1
    ax_t.xaxis.set_minor_formatter(NullFormatter())
    ax_t.set_xlabel("fit seconds, cumulative over iterations (log)")
    ax_m.set_xlabel("peak memory of the fit process (MiB)")
    for ax in (ax_t, ax_m):
        ax.set_ylabel("test PSNR (dB)")
        ax.grid(alpha=0.3)
    handles, labels = ax_t.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8, frameon=False)
    fig.suptitle(title or "PSNR vs cost per preset (dotted: self-training iterations)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120, bbox_inches="tight", format="png")
    return path


def plot_paper_comparison(rows: list[SceneComparison], path: str | Path, title: str = "") -> Path:
    """Bars per scene (and the mean row): our baseline and SE-NeRF PSNR (error bars: std over seeds) beside the
    paper's K-Planes and SE-NeRF (K-Planes), hatched; a missing figure leaves its bar out.

    Args:
        rows: one table of :func:`senerf.bench.report.compare_to_paper`.
        path: output PNG, written as given, its folder made.
    """
    fig = Figure(figsize=(max(5.0, 1.3 * len(rows) + 2.0), 4.0))
    ax = fig.subplots()
    x = np.arange(len(rows))
    nan = float("nan")
    bars = [("ours: baseline (teacher)", [r.baseline[0] for r in rows], "C0", ""),
            ("ours: SE-NeRF", [r.senerf[0] for r in rows], "C1", ""),
            ("paper: K-Planes", [r.paper[0] for r in rows], "C0", "//"),
            ("paper: SE-NeRF (K-Planes)", [r.paper[1] for r in rows], "C1", "//")]
    width = 0.8 / len(bars)
    for i, (label, values, colour, hatch) in enumerate(bars):
        if hatch:   # the paper's rows: one figure, no spread
            heights = [nan if v is None or v.psnr is None else v.psnr for v in values]
            errors = None
        else:       # our Stats over seeds
            heights = [nan if v.mean is None else v.mean for v in values]
            errors = [v.std or 0.0 for v in values]
        ax.bar(x + (i - 1.5) * width, heights, width, yerr=errors, capsize=3, label=label, color=colour,
               alpha=0.45 if hatch else 0.9, hatch=hatch, edgecolor="0.3")
    ax.set_xticks(x, [r.scene for r in rows])
    ax.set_ylabel("test PSNR (dB)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.0, 0.5), frameon=False)
    paper_res = sorted({p.resolution for r in rows for p in r.paper if p is not None})
    ax.set_title(title or f"{rows[0].protocol}, {rows[0].config}: ours against the paper"
                 + (f" (at {', '.join(paper_res)})" if paper_res else " (no published figures)"), fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120, bbox_inches="tight", format="png")
    return path
