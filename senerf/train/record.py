"""``metrics.json``: the one document a fit writes (DESIGN.md contract), and the host its figures depend on
(:func:`host_record`, recorded in every row and every training checkpoint; DESIGN.md, "Resume").
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np

from senerf import __version__
from senerf.data import view_names
from senerf.memory import cpu_model

__all__ = ["metrics_document", "iteration_row", "host_record", "timed", "PHASES", "phase_breakdown"]

#: The phases a row's ``phases`` times, in the order of an iteration: training, the teacher's renders of the pseudo
#: and known views, VGG-19 features, reprojection and reliability, and the test views' evaluation.
PHASES = ("train", "pseudo_render", "features", "reliability", "evaluation")


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
    thread count, the processor (:func:`senerf.memory.cpu_model`), the torch and NumPy versions and, on the CPU,
    which code runs K-Planes' planes (``kernel``: ``'compiled'`` or ``'pytorch'``,
    :func:`senerf.fields.ckernel.cpu_planes_path`)."""
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


@contextmanager
def timed(phases: dict | None, name: str):
    """Add the wall time of the ``with`` block to ``phases[name]`` (seconds); nothing when ``phases`` is None.
    Times are taken at the phase boundaries: on a GPU, work still queued is counted in the phase that waits for it."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        if phases is not None:
            phases[name] = phases.get(name, 0.0) + time.perf_counter() - t0


def iteration_row(iteration: int, ev: dict, reliable_fraction: float | None, seconds: float, device="cpu",
                  phases: dict | None = None, train_samples: int = 0) -> dict:
    """One row of ``metrics['iterations']`` from :func:`senerf.train.evaluate`'s result ``ev``
    (``reliable_fraction`` None for the teacher, or when the pseudo views held no foreground), with the
    :func:`host_record` of ``device``, the host that finished the iteration, the seconds of each of
    :data:`PHASES` (``phases``) and the training's samples per second (``train_samples``: the ray samples the steps
    trained on, ``steps x rays x n_samples``, before empty-space skipping)."""
    phases = {name: float((phases or {}).get(name, 0.0)) for name in PHASES}
    per_s = train_samples / phases["train"] if phases["train"] > 0 else 0.0
    return dict(iteration=int(iteration), psnr=ev["psnr"], ssim=ev["ssim"], lpips=ev["lpips"], avg=ev["avg"],
                reliable_fraction=reliable_fraction, seconds=seconds, phases=phases, train_samples_per_s=per_s,
                per_view=ev["per_view"], host=host_record(device))


def phase_breakdown(metrics: dict) -> str:
    """One line: the run's time per phase over its iterations and the training's samples per second, e.g.
    ``12.8 min: train 9.1 min (0.18 M samples/s), pseudo_render 1.2 min, ...``."""
    rows = metrics["iterations"]

    def text(s: float) -> str:
        return f"{s / 60:.1f} min" if s >= 90 else f"{s:.0f} s"

    totals = {name: sum(row.get("phases", {}).get(name, 0.0) for row in rows) for name in PHASES}
    samples = sum(row.get("train_samples_per_s", 0.0) * row.get("phases", {}).get("train", 0.0) for row in rows)
    rate = f" ({samples / totals['train'] / 1e6:.2f} M samples/s)" if totals["train"] > 0 else ""
    parts = [f"{name} {text(s)}{rate if name == 'train' else ''}" for name, s in totals.items() if s > 0]
    return f"{text(metrics.get('seconds_total', 0.0))}: " + ", ".join(parts)
