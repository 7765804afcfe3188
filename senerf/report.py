"""One figure per ``senerf-fit`` run, ``summary.png``: what the run bought, where, and what it looks like.

* top: mean test PSNR and SSIM per iteration (0 = the teacher), with each iteration's reliable share of pseudo
  pixels under its tick; per-test-view PSNR against the angle to the nearest training camera, for iteration 0
  and the last (faint points, binned means as lines): where self-training helped;
* below: three test views (nearest, median and farthest from the training cameras), ground truth beside
  the renders of iteration 0 and of the last iteration, each titled with its PSNR.

Drawn with matplotlib's Agg canvas (no pyplot state, no global backend switch).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Callable

import numpy as np

from .atomic import atomic_write_bytes

__all__ = ["plot_run_summary", "write_summary", "pick_views", "binned_means"]


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


def _read_render(path: Path) -> np.ndarray | None:
    import imageio.v2 as imageio

    try:
        return np.asarray(imageio.imread(path))[..., :3]
    except (OSError, ValueError):
        return None


def _checked_rows(metrics: dict) -> list[dict]:
    """``metrics["iterations"]`` (in order, as :func:`senerf.runfolder.read_metrics` checks), each with its
    ``iteration``, ``psnr``, ``ssim`` and ``per_view["psnr"]``, all of one length."""
    rows = metrics.get("iterations") or []
    if not rows:
        raise ValueError("metrics has no iteration rows")
    n = len(rows[0].get("per_view", {}).get("psnr", []))
    for k, r in enumerate(rows):
        if not ({"iteration", "psnr", "ssim"} <= r.keys() and len(r.get("per_view", {}).get("psnr", [])) == n > 0):
            raise ValueError(f"row {k} lacks its iteration, psnr, ssim or per_view.psnr of every test view")
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
    """Per-view PSNR against the angle to the nearest input (first and last iteration; binned means as lines), or
    against the view's position when there are no angles."""
    ax.set_title("per test view", fontsize=9)
    for row, colour in zip(compare, ("C0", "C3")):
        p = np.asarray(row["per_view"]["psnr"], np.float64)
        x = np.arange(p.size) if angles_deg is None else angles_deg
        ax.scatter(x, p, s=6, alpha=0.25 if angles_deg is not None else 1.0, color=colour,
                   label=None if angles_deg is not None else f"iteration {row['iteration']}")
        if angles_deg is not None:
            ax.plot(*binned_means(angles_deg, p, bin_deg), "-o", ms=3, color=colour,
                    label=f"iteration {row['iteration']}")
    ax.set_xlabel("test view" if angles_deg is None else "angle to the nearest training view (degrees)")
    ax.set_ylabel("test-view PSNR (dB)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)


def _draw_views(subfig, metrics: dict, views: list[int], compare: list[dict], run_dir: Path,
                angles_deg: np.ndarray | None, ground_truth: Callable[[int], np.ndarray] | None) -> None:
    """One row per test view position in ``views``: ground truth (when given), then each compared iteration's
    render (blank when missing), titled with the photo's file (``metrics['test_images']``, its last 29 characters
    past 32; else the view's position), its angle and each render's PSNR."""
    n_cols = (ground_truth is not None) + len(compare)
    axes = np.asarray(subfig.subplots(len(views), n_cols, squeeze=False))
    test_images = metrics.get("test_images")
    for i, pos in enumerate(views):
        images = ([np.clip(np.asarray(ground_truth(pos), np.float32), 0.0, 1.0)] if ground_truth else [])
        images += [_read_render(run_dir / f"iter_{r['iteration']}" / "test" / f"rgb_{pos:03d}.png") for r in compare]
        name = f"test view {pos}"
        if isinstance(test_images, list) and len(test_images) == len(compare[0]["per_view"]["psnr"]):
            name = str(test_images[pos]) if len(str(test_images[pos])) <= 32 else "..." + str(test_images[pos])[-29:]
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
        metrics: the run's ``metrics.json`` dict (``scene``, ``test_images``, ``iterations`` rows with
            ``iteration``, ``psnr``, ``ssim``, ``reliable_fraction``, ``per_view["psnr"]``).
        run_dir: the run's folder (its ``iter_K/test/rgb_XXX.png`` renders; missing ones are left blank).
        path: the PNG to write.
        angles_deg: (n_test,) degrees from each test view to its nearest training camera
            (:func:`senerf.geometry.nearest_view_angles`), or None (views by position, picked by PSNR).
        ground_truth: ``position -> (H, W, 3)`` image in [0, 1] of test view ``position``, or None.
        bin_deg: angle bin width of the mean lines.
    Returns:
        ``Path(path)``.
    Raises:
        ValueError: no iteration rows, a row without ``psnr``, ``ssim`` or ``per_view["psnr"]``, or per-view /
            angle lengths that disagree.
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


def write_summary(metrics: dict, scene, train_idx, test_idx, model, out: str | Path,
                  echo: Callable[[str], None] = print) -> Path | None:
    """``out/summary.png`` of a fit (:func:`plot_run_summary`), with the angles from each test view to its
    nearest training camera (about the point the cameras look at; between optical axes in a forward-facing
    scene, or where the axes meet nowhere).  The metrics are already on disk, so a figure that cannot be drawn
    is a one-line warning, never a failed run.  Returns the figure's path, or None."""
    import warnings

    from senerf.geometry import closest_point_to_axes, nearest_view_angles
    from senerf.train import eval_images

    train_c2w, test_c2w = scene.c2w[np.asarray(train_idx)], scene.c2w[np.asarray(test_idx)]
    angles = None
    for center in ("look-at", None):
        try:
            point = closest_point_to_axes(scene.c2w) if center and scene.kind != "forward_facing" else None
            angles = nearest_view_angles(train_c2w, test_c2w, point)
            break
        except ValueError:   # all axes parallel, or a camera at that point
            continue

    def ground_truth(position: int) -> np.ndarray:
        return eval_images(scene, [test_idx[position]], model)[0]

    try:
        path = plot_run_summary(metrics, out, Path(out) / "summary.png", angles_deg=angles, ground_truth=ground_truth)
    except (OSError, ValueError, MemoryError) as exc:
        warnings.warn(f"no summary figure ({str(exc) or type(exc).__name__})")
        return None
    echo(f"fit: summary figure in {path}")
    return path
