"""``metrics.json``: the one document a fit writes (DESIGN.md contract), and the host its figures depend on
(:func:`host_record`, recorded in every row and every training checkpoint; DESIGN.md, "Resume").
"""

from __future__ import annotations

import numpy as np

from senerf import __version__
from senerf.data import view_names
from senerf.memory import cpu_model

__all__ = ["metrics_document", "iteration_row", "host_record"]


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


def iteration_row(iteration: int, ev: dict, reliable_fraction: float | None, seconds: float, device="cpu") -> dict:
    """One row of ``metrics['iterations']`` from :func:`senerf.train.evaluate`'s result ``ev``
    (``reliable_fraction`` None for the teacher, or when the pseudo views held no foreground), with the
    :func:`host_record` of ``device``, the host that finished the iteration."""
    return dict(iteration=int(iteration), psnr=ev["psnr"], ssim=ev["ssim"], lpips=ev["lpips"], avg=ev["avg"],
                reliable_fraction=reliable_fraction, seconds=seconds, per_view=ev["per_view"],
                host=host_record(device))
