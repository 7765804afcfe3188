"""``metrics.json``: the one document a fit writes (DESIGN.md contract), built and read in one place.

``senerf-fit``'s baseline and :func:`senerf.selftrain.run_selftraining` write the same document; its header and
its per-iteration rows come from here, so a field added to it reaches both.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from senerf import __version__
from senerf.data import view_names

__all__ = ["metrics_document", "iteration_row", "finished_metrics"]


def metrics_document(scene, train_idx, test_idx, command, config: dict) -> dict:
    """A run's ``metrics.json`` before any iteration: version, command, settings, scene, the training and test
    views (``(m,)`` / ``(t,)`` int indices) by index and by photo, and the image size; no rows yet."""
    h, w = scene.intrinsics.size
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    test_idx = np.asarray(test_idx, dtype=np.int64).reshape(-1)
    return {"senerf_version": __version__, "command": list(command or []), "config": config, "scene": scene.name,
            "train_views": train_idx.tolist(), "test_views": test_idx.tolist(),
            "train_images": view_names(scene, train_idx), "test_images": view_names(scene, test_idx),
            "resolution": [int(h), int(w)], "iterations": [], "seconds_total": 0.0}


def iteration_row(iteration: int, ev: dict, reliable_fraction: float | None, seconds: float) -> dict:
    """One row of ``metrics['iterations']`` from :func:`senerf.train.evaluate`'s result ``ev``
    (``reliable_fraction`` None for the teacher, or when the pseudo views held no foreground)."""
    return dict(iteration=int(iteration), psnr=ev["psnr"], ssim=ev["ssim"], lpips=ev["lpips"], avg=ev["avg"],
                reliable_fraction=reliable_fraction, seconds=seconds, per_view=ev["per_view"])


def finished_metrics(out_dir: str | Path, iteration: int = 0) -> dict | None:
    """``out_dir/metrics.json`` when it records ``iteration`` (a row for it or a later one), else None (missing,
    unreadable, or written before that iteration finished)."""
    try:
        metrics = json.loads((Path(out_dir) / "metrics.json").read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    rows = metrics.get("iterations") if isinstance(metrics, dict) else None
    if isinstance(rows, list) and any(isinstance(r, dict) and isinstance(r.get("iteration"), int)
                                      and r["iteration"] >= iteration for r in rows):
        return metrics
    return None
