"""PNG plots (matplotlib's Agg canvas; no global backend switch, no pyplot state).

* :func:`plot_frontier`: PSNR vs wall-clock seconds and vs peak memory, one series per method, one point
  per preset (self-training methods: one point per iteration, joined per preset).
* :func:`plot_iterations`: PSNR and SSIM per self-training iteration, mean ± std over seeds.
* :func:`plot_psnr_vs_angle` (+ :func:`nearest_view_angles`, :func:`line_view_angles`): per-test-view PSNR
  against the angle to the nearest training camera.  ``metrics.json`` gives per-view PSNR and the view
  indices; the poses come from the scene (``senerf-bench angles`` loads it), no fit hook needed.
* :func:`plot_gain_vs_teacher`: each self-training run's gain over its own teacher against that teacher's
  PSNR, with the least-squares line per rung (:func:`senerf.bench.ladder.teacher_dependence`).
* :func:`plot_mask_quality`: reliability-mask precision / recall / false-positive rate per feature
  extractor and threshold (rows from ``benchmarks/bench_selftrain.py masks``, which scores the masks with
  :func:`senerf.selftrain.reliability.mask_quality` against masks from ground-truth colour).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

from senerf.geometry import nearest_view_angles  # re-exported: the bench's angle plots use it
from senerf.report import binned_means

from .summary import PRESET_ORDER, Aggregate

__all__ = ["plot_frontier", "plot_iterations", "nearest_view_angles", "line_view_angles", "plot_psnr_vs_angle",
           "plot_gain_vs_teacher", "plot_mask_quality"]



def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120, bbox_inches="tight", format="png")   # at ``path`` as given, no suffix added
    return path


def _method_label(a: Aggregate) -> str:
    """``"senerf K=3"`` for self-training runs (runs with another K are another series), else the name."""
    return f"{a.method} K={a.iterations}" if a.iterations else a.method


def _err(stat) -> float:
    return 0.0 if stat.std is None else stat.std


def plot_frontier(aggs: list[Aggregate], path: str | Path, title: str = "") -> Path:
    """PSNR vs cumulative fit seconds (left) and vs peak memory MiB (right); error bars = std over seeds.

    Per method, a solid line joins the final iterations of the presets (fast -> balanced; results of the removed
    ``quality`` preset sort after them); on
    the left, a dotted line per preset also traces its self-training iterations (0 = teacher).  Memory is
    a whole-run figure, so the right panel shows final iterations only.

    Args:
        aggs: aggregates of one scene/protocol (others are drawn too but share the axes).
        path: output PNG.
    """
    fig = Figure(figsize=(11, 4.2))
    ax_t, ax_m = fig.subplots(1, 2)
    runs: dict[tuple, list[Aggregate]] = defaultdict(list)
    for a in aggs:
        runs[(a.scene, a.protocol, _method_label(a), a.preset)].append(a)
    by_method: dict[tuple, list[Aggregate]] = defaultdict(list)
    for (scene, protocol, method, preset), group in runs.items():
        group.sort(key=lambda a: a.iteration)
        by_method[(scene, protocol, method)].append(group[-1])
        if len(group) > 1:
            ax_t.plot([a.seconds.mean for a in group], [a.psnr.mean for a in group], ":", color="0.5", lw=1)
    colours = _distinct_colours(len(by_method))
    for i, (key, finals) in enumerate(sorted(by_method.items())):
        finals.sort(key=lambda a: PRESET_ORDER.get(a.preset, 9))
        label = " ".join(key[2:]) if len({k[:2] for k in by_method}) == 1 else " ".join(key)
        for ax, stat in ((ax_t, "seconds"), (ax_m, "peak_memory_mib")):
            shown = [a for a in finals if getattr(a, stat).mean is not None]   # memory: null when unmeasured
            if not shown:
                continue
            xs, ys = [getattr(a, stat).mean for a in shown], [a.psnr.mean for a in shown]
            ax.errorbar(xs, ys, xerr=[_err(getattr(a, stat)) for a in shown], yerr=[_err(a.psnr) for a in shown],
                        color=colours[i], marker="os^Dv"[i % 5], capsize=3, label=label)
            for a, x, y in zip(shown, xs, ys):
                ax.annotate(a.preset, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax_t.set_xscale("log")
    ax_t.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))   # 20, 50, 100, 200, 500 s ...
    ax_t.xaxis.set_major_formatter(ScalarFormatter())   # ... as plain numbers, not 2 x 10^1
    ax_t.xaxis.set_minor_formatter(NullFormatter())     # and no crowded minor labels
    ax_t.set_xlabel("fit seconds, cumulative over iterations (log)")
    ax_m.set_xlabel("peak memory of the fit process (MiB)")
    for ax in (ax_t, ax_m):
        ax.set_ylabel("test PSNR (dB)")
        ax.grid(alpha=0.3)
    _legend_outside(fig, ax_t)
    fig.suptitle(title or "PSNR vs cost per preset (dotted: self-training iterations)")
    return _save(fig, path)


def plot_iterations(aggs: list[Aggregate], path: str | Path, title: str = "") -> Path:
    """PSNR (left) and SSIM (right) vs self-training iteration, one line per (scene, method, preset)."""
    fig = Figure(figsize=(11, 4.2))
    ax_p, ax_s = fig.subplots(1, 2)
    series: dict[tuple, list[Aggregate]] = defaultdict(list)
    for a in aggs:
        series[(a.scene, a.protocol, _method_label(a), a.preset)].append(a)
    colours = _distinct_colours(len(series))
    for colour, ((scene, protocol, method, preset), group) in zip(colours, sorted(series.items())):
        group.sort(key=lambda a: a.iteration)
        it = [a.iteration for a in group]
        label = f"{scene} {method} {preset}"
        ax_p.errorbar(it, [a.psnr.mean for a in group], yerr=[_err(a.psnr) for a in group], marker="o",
                      capsize=3, label=label, color=colour)
        ax_s.errorbar(it, [a.ssim.mean for a in group], yerr=[_err(a.ssim) for a in group], marker="o",
                      capsize=3, label=label, color=colour)
    for ax, name in ((ax_p, "test PSNR (dB)"), (ax_s, "test SSIM")):
        ax.set_xlabel("self-training iteration (0 = teacher)")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.xaxis.get_major_locator().set_params(integer=True)
    _legend_outside(fig, ax_p)
    fig.suptitle(title or "quality per self-training iteration")
    return _save(fig, path)


def line_view_angles(line: dict, c2w: np.ndarray, center: np.ndarray | tuple | None = (0.0, 0.0, 0.0)
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(angles (n,) degrees, per-view PSNR (n,)) of one results line.

    Args:
        line: an ok results line; uses ``views`` and ``test_views`` (indices into the scene's arrays,
            DESIGN.md / :func:`senerf.data.fewshot_split`) and ``per_view["psnr"]``.
        c2w: (N, 4, 4) all poses of the scene (``senerf.data.load_scene(...).c2w``).
        center: see :func:`nearest_view_angles`.
    """
    per_view = (line.get("per_view") or {}).get("psnr")
    test, train = line.get("test_views"), line.get("views")
    if not per_view or not test or not train or len(per_view) != len(test):
        raise ValueError(f"{line.get('run_key')}: needs views, test_views and per_view.psnr of equal length")
    c2w = np.asarray(c2w)
    angles = nearest_view_angles(c2w[np.asarray(train)], c2w[np.asarray(test)], center)
    return angles, np.asarray(per_view, np.float64)


def _legend_outside(fig: Figure, ax) -> None:
    """One legend for the figure, to the right of its panels (where it hides no data), from ``ax``'s series."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8, frameon=False)


def _distinct_colours(n: int) -> list:
    """``n`` colours no two alike: matplotlib's 10-colour cycle, 'tab20' for 11-20 series, evenly spaced
    'turbo' colours beyond."""
    from matplotlib import colormaps

    if n <= 10:
        return [f"C{i}" for i in range(n)]
    if n <= 20:
        return [colormaps["tab20"](i) for i in range(n)]
    return [colormaps["turbo"](x) for x in np.linspace(0.0, 1.0, n)]


def plot_psnr_vs_angle(angles_deg: dict[str, np.ndarray], psnr: dict[str, np.ndarray], path: str | Path,
                       title: str = "", bin_deg: float = 15.0) -> Path:
    """Per-view PSNR vs angle to the nearest training view: faint points, and per label a line through the
    mean PSNR of each ``bin_deg`` bin of angle (the paper's Figure 1 reading).

    Args:
        angles_deg: label -> (n,) degrees (from :func:`nearest_view_angles`).
        psnr: label -> (n,) per-view PSNR (``per_view["psnr"]`` of a results line).
        bin_deg: width of the angle bins of the mean lines.
    """
    fig = Figure(figsize=(6.4, 4.4))
    ax = fig.subplots()
    colours = _distinct_colours(len(angles_deg))
    for label, colour in zip(angles_deg, colours):
        a, p = np.asarray(angles_deg[label], np.float64), np.asarray(psnr[label], np.float64)
        if a.shape != p.shape:
            raise ValueError(f"{label}: angles {a.shape} and psnr {p.shape} differ")
        dots = ax.scatter(a, p, s=6, alpha=0.25, color=colour)
        centres, means = binned_means(a, p, bin_deg)
        ax.plot(centres, means, "-o", ms=3, color=dots.get_facecolor()[0][:3], label=label)
    ax.set_xlabel("angle to the nearest training view (degrees)")
    ax.set_ylabel("test-view PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title or "PSNR vs distance from the training views", fontsize=9)
    return _save(fig, path)


def plot_gain_vs_teacher(fits: list, path: str | Path, title: str = "") -> Path:
    """Gain over the teacher (final - iteration 0, dB) against the teacher's PSNR: one point per run, one
    colour and fitted line per :class:`senerf.bench.ladder.TeacherFit` (method and rung), legend outside.

    Args:
        fits: TeacherFit records (e.g. of one method, all its rungs).
        path: output PNG.
    """
    fig = Figure(figsize=(6.4, 4.4))
    ax = fig.subplots()
    for fit, colour in zip(fits, _distinct_colours(len(fits))):
        x, y = np.asarray(fit.teacher_psnr), np.asarray(fit.gain)
        label = f"{fit.method} {fit.rung} (n={len(fit.seeds)}"
        label += ")" if fit.slope is None else f", b={fit.slope:+.2f}, r={fit.r:+.2f})"
        ax.scatter(x, y, s=18, color=colour, label=label)
        if fit.slope is not None:
            xs = np.array([x.min(), x.max()])
            ax.plot(xs, fit.intercept + fit.slope * xs, "-", lw=1, color=colour)
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlabel("teacher (iteration 0) PSNR (dB)")
    ax.set_ylabel("final - teacher PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.set_title(title or "Gain over the teacher vs the teacher", fontsize=9)
    _legend_outside(fig, ax)
    return _save(fig, path)


def plot_mask_quality(records: list[dict], path: str | Path, title: str = "") -> Path:
    """Grouped bars of precision, recall and FPR per (feature extractor, threshold).

    Args:
        records: dicts with ``feature`` (``"vgg19"``), ``threshold`` (``"adaptive"``), ``precision``,
            ``recall``, ``fpr`` (e.g. :func:`senerf.selftrain.reliability.mask_quality` results plus the two labels).
    """
    if not records:
        raise ValueError("no mask-quality records to plot")
    labels = [f"{r['feature']}\n{r['threshold']}" for r in records]
    x = np.arange(len(records))
    fig = Figure(figsize=(max(5.0, 1.4 * len(records)), 4.2))
    ax = fig.subplots()
    for k, name in enumerate(("precision", "recall", "fpr")):
        ax.bar(x + (k - 1) * 0.27, [r[name] for r in records], width=0.27, label=name)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylim(0, 1)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title or "reliability mask vs ground-truth mask")
    return _save(fig, path)
