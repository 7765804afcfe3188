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
from senerf.memory import cpu_model

__all__ = ["metrics_document", "iteration_row", "host_record", "host_change", "resume_host_line",
           "finished_metrics"]


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


def host_record(device) -> dict:
    """What a fit's figures depend on beyond its settings: the device (``'cpu'`` or the GPU's name), torch's CPU
    thread count, the processor (:func:`senerf.memory.cpu_model`) and the torch and NumPy versions.  On the CPU a
    fit is the same to the bit for the same seed, thread count, processor and builds; with another thread count
    the float sums run in another order (lego Extreme fast seed 0, 25 test views: 16.708767 -> 17.431559 dB with 2
    threads, 16.653053 -> 17.420419 with 1; BENCHMARKS.md, session 19), and another processor takes other kernels
    (lego Extreme balanced seed 0, 2 threads: a teacher of 15.252562 dB on an AMD EPYC, 14.650693 on an Intel
    Xeon; session 23).  On the CPU it also records which code runs K-Planes' planes (``kernel``: ``'compiled'`` or,
    without a C compiler, ``'pytorch'``; :func:`senerf.fields.ckernel.cpu_planes_path`), whose sums differ in
    order (recorded for every CPU row; only K-Planes fields use it).  On CUDA repeated runs differ (``index_add_``
    and ``cumsum`` are not deterministic there)."""
    import torch

    from senerf.fields.ckernel import cpu_planes_path

    device = torch.device(device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else device.type
    # plain str: torch.__version__ is a TorchVersion, which a weights_only checkpoint load refuses
    host = {"device": str(name), "threads": int(torch.get_num_threads()), "cpu": cpu_model(),
            "torch": str(torch.__version__), "numpy": str(np.__version__)}
    if device.type == "cpu":
        host["kernel"] = cpu_planes_path()
    return host


def host_change(before: dict | None, now: dict) -> str:
    """How a recorded :func:`host_record` ``before`` differs from ``now``, in words, or ``''`` when it does not
    (or when ``before`` is not a dict: ``metrics.json`` rows written before session 19 and training checkpoints
    written before session 20 record no host; a key only one side records, such as ``cpu`` before session 23 or
    ``kernel`` before session 24, is no difference).

    Example:
        >>> host_change({"device": "cpu", "threads": 16}, {"device": "cpu", "threads": 1})
        'with 16 threads, this call with 1 thread'
    """
    if not isinstance(before, dict):
        return ""
    words = {"device": "on {}", "threads": "with {} thread{}", "cpu": "with processor {}", "torch": "with torch {}",
             "numpy": "with NumPy {}", "kernel": "with the {} K-Planes code"}
    keys = [k for k in words if k in before and k in now and before[k] != now[k]]

    def said(host: dict) -> str:
        return ", ".join(words[k].format(host[k], "" if host[k] == 1 else "s") for k in keys)

    return f"{said(before)}, this call {said(now)}" if keys else ""


def resume_host_line(before: dict | None, device, what: str) -> str:
    """The line a resume on ``device`` prints when the recorded host ``before`` differs from this call's, or ``''``:
    ``"{what} {host_change}: the rest is reproducible, but not bit for bit an uninterrupted run"``.

    On the CPU only: there a run repeats to the bit for the same host, and another thread count, processor, torch,
    NumPy or K-Planes code (``kernel``) breaks that.  ``''`` on a GPU, where runs do not repeat to the bit anyway
    (``index_add_`` and ``cumsum``) and CPU threads hardly matter.  ``what`` says what ran on ``before``
    ("selftrain: iteration 2 ran").
    """
    import torch

    if torch.device(device).type != "cpu":
        return ""
    moved = host_change(before, host_record(device))
    return f"{what} {moved}: the rest is reproducible, but not bit for bit an uninterrupted run" if moved else ""


def iteration_row(iteration: int, ev: dict, reliable_fraction: float | None, seconds: float, device="cpu") -> dict:
    """One row of ``metrics['iterations']`` from :func:`senerf.train.evaluate`'s result ``ev``
    (``reliable_fraction`` None for the teacher, or when the pseudo views held no foreground), with the
    :func:`host_record` of ``device``, the host that finished the iteration."""
    return dict(iteration=int(iteration), psnr=ev["psnr"], ssim=ev["ssim"], lpips=ev["lpips"], avg=ev["avg"],
                reliable_fraction=reliable_fraction, seconds=seconds, per_view=ev["per_view"],
                host=host_record(device))


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
