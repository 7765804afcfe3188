"""One figure per ``senerf-fit`` run, ``summary.png``: what the run bought, where, and what it looks like.

* top left: mean test PSNR per iteration (0 = the teacher), SSIM on the right axis, the reliable share of
  each iteration's pseudo pixels beside its point;
* top right: per-test-view PSNR against the angle to the nearest training camera, for iteration 0 and the
  last iteration (faint points, binned means as lines): where self-training helped;
* below: three test views (nearest, median and farthest from the training cameras), ground truth beside
  the renders of iteration 0 and of the last iteration, each titled with its PSNR.

It reads only ``metrics.json``'s rows (DESIGN.md contract) and the test renders the run wrote
(``iter_K/test/rgb_XXX.png``); the ground truth and the angles come from the caller (the scene).  Written
atomically with matplotlib's Agg canvas (no pyplot state, no global backend switch).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Callable

import numpy as np

from .atomic import atomic_write_bytes

__all__ = ["plot_run_summary", "pick_views", "binned_means"]


def pick_views(angles_deg: np.ndarray | None, psnr: np.ndarray, k: int = 3) -> list[int]:
    """Positions of up to ``k`` test views to show: nearest, median and farthest by ``angles_deg (n,)``
    (spread evenly over the sorted angles when ``k != 3``), or by ``psnr (n,)`` (best, median, worst) when
    there are no angles.  Distinct positions, in that order."""
    key = np.asarray(angles_deg if angles_deg is not None else -np.asarray(psnr, np.float64), np.float64)
    n = key.size
    if n == 0:
        return []
    order = np.argsort(key, kind="stable")
    picks = [int(order[int(round(q * (n - 1)))]) for q in np.linspace(0.0, 1.0, min(k, n))]
    return list(dict.fromkeys(picks))


def binned_means(a: np.ndarray, p: np.ndarray, bin_deg: float) -> tuple[list[float], list[float]]:
    """(bin centres, mean of ``p (n,)`` in each non-empty ``bin_deg``-wide bin of ``a (n,)`` from 0)."""
    a, p = np.asarray(a, np.float64), np.asarray(p, np.float64)
    if a.size == 0:
        return [], []
    edges = bin_deg * np.arange(int(a.max() // bin_deg) + 2)   # the last bin holds the maximum (an edge too)
    which = np.digitize(a, edges) - 1
    centres, means = [], []
    for b in range(len(edges) - 1):
        sel = which == b
        if sel.any():
            centres.append((edges[b] + edges[b + 1]) / 2)
            means.append(float(p[sel].mean()))
    return centres, means


def _shrink(image: np.ndarray, max_side: int = 400) -> np.ndarray:
    """``image (H, W, C)`` with every ``s``-th pixel per axis, ``s`` the smallest stride that brings its longer
    side to ``max_side`` or below (a panel is ~400 px wide: full-size 4032x3024 photos cost seconds and GBs)."""
    stride = max(1, -(-max(image.shape[:2]) // max_side))
    return image[::stride, ::stride]


def _read_render(run_dir: Path, iteration: int, position: int) -> np.ndarray | None:
    import imageio.v2 as imageio

    path = run_dir / f"iter_{iteration}" / "test" / f"rgb_{position:03d}.png"
    try:
        return np.asarray(imageio.imread(path))[..., :3]
    except (OSError, ValueError):
        return None


def _checked_rows(metrics: dict) -> list[dict]:
    """``metrics["iterations"]`` sorted by iteration, each with ``psnr``, ``ssim`` and ``per_view["psnr"]``."""
    rows = metrics.get("iterations") or []
    if not rows:
        raise ValueError("metrics has no iteration rows")
    if not all(isinstance(r, dict) and isinstance(r.get("iteration"), int) for r in rows):
        raise ValueError("an iteration row is not an object with an integer 'iteration'")
    rows = sorted(rows, key=lambda r: r["iteration"])
    for r in rows:
        if not ({"psnr", "ssim"} <= r.keys() and isinstance(r.get("per_view"), dict) and "psnr" in r["per_view"]):
            raise ValueError(f"iteration {r['iteration']}'s row lacks psnr, ssim or per_view.psnr")
    if len(rows[0]["per_view"]["psnr"]) != len(rows[-1]["per_view"]["psnr"]):
        raise ValueError(f"per-view PSNR lengths differ: {len(rows[0]['per_view']['psnr'])} and "
                         f"{len(rows[-1]['per_view']['psnr'])}")
    return rows


def _draw_curves(ax_psnr, ax_ssim, rows: list[dict]) -> None:
    """Mean PSNR and SSIM per iteration; the reliable share under each self-training iteration's tick."""
    first, last = rows[0], rows[-1]
    its = [r["iteration"] for r in rows]
    for ax, key, colour, label in ((ax_psnr, "psnr", "C0", "mean test PSNR (dB)"),
                                   (ax_ssim, "ssim", "C1", "mean test SSIM")):
        ax.plot(its, [r[key] for r in rows], "-o", color=colour)
        ax.set_xlabel("iteration (0 = teacher)")
        ax.set_ylabel(label)
        ax.set_xticks(its)
        ax.margins(x=0.15, y=0.2)
        ax.grid(alpha=0.3)
    # the reliable share of each self-training iteration under its tick (labels beside close points overlap)
    ax_psnr.set_xticks(its, labels=[f"{r['iteration']}" if r.get("reliable_fraction") is None else
                                    f"{r['iteration']}\n{100 * r['reliable_fraction']:.0f} %" for r in rows])
    if any(r.get("reliable_fraction") is not None for r in rows):
        ax_psnr.set_xlabel("iteration (0 = teacher)\nand its reliable share of pseudo pixels")
    ax_psnr.set_title(f"{first['psnr']:.2f} -> {last['psnr']:.2f} dB ({last['psnr'] - first['psnr']:+.2f})",
                      fontsize=9)
    ax_ssim.set_title(f"{first['ssim']:.3f} -> {last['ssim']:.3f}", fontsize=9)


def _draw_per_view(ax, compare: list[dict], angles_deg: np.ndarray | None, bin_deg: float) -> None:
    """Per-view PSNR against the angle to the nearest input (first and last iteration), or without angles a
    histogram of the per-view change."""
    ax.set_title("per test view", fontsize=9)
    if angles_deg is not None and angles_deg.size:
        for row, colour in zip(compare, ("C0", "C3")):
            p = np.asarray(row["per_view"]["psnr"], np.float64)
            ax.scatter(angles_deg, p, s=6, alpha=0.25, color=colour)
            ax.plot(*binned_means(angles_deg, p, bin_deg), "-o", ms=3, color=colour,
                    label=f"iteration {row['iteration']}")
        ax.set_xlabel("angle to the nearest training view (degrees)")
        ax.set_ylabel("test-view PSNR (dB)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        return
    change = (np.asarray(compare[-1]["per_view"]["psnr"], np.float64)
              - np.asarray(compare[0]["per_view"]["psnr"], np.float64))
    change = change[np.isfinite(change)]   # a perfect render's PSNR is inf
    lo, hi = (float(change.min()), float(change.max())) if change.size else (0.0, 0.0)
    if hi - lo < 1e-3:   # (nearly) one value: numpy cannot split a zero-width range into 20 bins
        lo, hi = lo - 0.5, hi + 0.5
    ax.hist(change, bins=20, range=(lo, hi), color="C0")
    ax.set_xlabel(f"PSNR change per test view, iteration {compare[-1]['iteration']} - 0 (dB)")
    ax.set_ylabel("test views")


def _draw_views(subfig, metrics: dict, views: list[int], compare: list[dict], run_dir: Path,
                angles_deg: np.ndarray | None, ground_truth: Callable[[int], np.ndarray] | None) -> None:
    """One row per test view position in ``views``: ground truth (when given), then each compared iteration's
    render, titled with the photo's file (``metrics['test_images']``; else the view's index), its angle and each
    render's PSNR."""
    n_cols = (ground_truth is not None) + len(compare)
    axes = np.asarray(subfig.subplots(len(views), n_cols, squeeze=False))
    test_views, test_images = metrics.get("test_views"), metrics.get("test_images")
    n_test = len(compare[0]["per_view"]["psnr"])
    for i, pos in enumerate(views):
        images = ([np.clip(np.asarray(ground_truth(pos), np.float32), 0.0, 1.0)] if ground_truth else [])
        images += [_read_render(run_dir, r["iteration"], pos) for r in compare]
        if isinstance(test_images, list) and len(test_images) == n_test:   # the photo's file, as the user has it
            name = str(test_images[pos]) if len(str(test_images[pos])) <= 32 else "..." + str(test_images[pos])[-29:]
        elif isinstance(test_views, list) and len(test_views) == n_test:
            name = f"image {test_views[pos]}"
        else:
            name = f"test view {pos}"
        titles = ([f"ground truth ({name})"] if ground_truth else [])
        titles += [f"iteration {r['iteration']}: {r['per_view']['psnr'][pos]:.2f} dB" for r in compare]
        if angles_deg is not None:
            titles[0] += f", {angles_deg[pos]:.0f} deg"
        for ax, image, title in zip(axes[i], images, titles):
            if image is not None:
                ax.imshow(_shrink(image))
            ax.set_title(title, fontsize=8)
            ax.set_axis_off()


def plot_run_summary(metrics: dict, run_dir: str | Path, path: str | Path,
                     angles_deg: np.ndarray | None = None,
                     ground_truth: Callable[[int], np.ndarray] | None = None, bin_deg: float = 15.0) -> Path:
    """Draw the run's summary figure to ``path`` (PNG, atomic).

    Args:
        metrics: the run's ``metrics.json`` dict (``scene``, ``test_views``, ``iterations`` rows with
            ``iteration``, ``psnr``, ``ssim``, ``reliable_fraction``, ``per_view["psnr"]``).
        run_dir: the run's folder (its ``iter_K/test/rgb_XXX.png`` renders; missing ones are left blank).
        path: the PNG to write.
        angles_deg: (n_test,) degrees from each test view to its nearest training camera
            (:func:`senerf.geometry.nearest_view_angles`), or None (no angle panel; views picked by PSNR).
        ground_truth: ``position -> (H, W, 3)`` image in [0, 1] of test view ``position``, or None.
        bin_deg: angle bin width of the mean lines.
    Returns:
        ``Path(path)``.
    Raises:
        ValueError: no iteration rows, a row without an integer ``iteration``, ``psnr``, ``ssim`` or
            ``per_view["psnr"]``, or per-view / angle lengths that disagree.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows = _checked_rows(metrics)
    first, last = rows[0], rows[-1]
    compare = [first] if first is last else [first, last]
    p_first = np.asarray(first["per_view"]["psnr"], np.float64)
    if angles_deg is not None:
        angles_deg = np.asarray(angles_deg, np.float64).reshape(-1)
        if angles_deg.shape != p_first.shape:
            raise ValueError(f"angles_deg has {angles_deg.size} values for {p_first.size} test views")
    views = pick_views(angles_deg, p_first)

    fig = Figure(figsize=(12.0, 3.4 + 2.8 * len(views)), layout="constrained")
    top, bottom = fig.subfigures(2, 1, height_ratios=[3.4, 2.8 * max(len(views), 1)])
    ax_psnr, ax_ssim, ax_view = top.subplots(1, 3, width_ratios=[1.0, 1.0, 1.6])
    _draw_curves(ax_psnr, ax_ssim, rows)
    _draw_per_view(ax_view, compare, angles_deg, bin_deg)
    top.suptitle(f"{metrics.get('scene', '')}: {len(rows) - 1} self-training iteration(s), {len(p_first)} "
                 f"test views", fontsize=10)
    if views:
        _draw_views(bottom, metrics, views, compare, Path(run_dir), angles_deg, ground_truth)
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=100, format="png")
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)
