"""The labelling record: each pseudo view's teacher render, similarity and foreground kept on disk as soon as it
is labelled, so that a run interrupted while labelling, or resumed inside the student's training, does not
label again (at 400x400 a view takes ~4 s on 2 cores, an iteration's 24 views ~100 s; BENCHMARKS.md).

One ``view_XXX.npz`` per pseudo view (``XXX``: its position) in a folder (``checkpoints/iter_K_labels/`` in a
run), each written atomically when its view is done and stamped with :func:`labelling_digest`, a SHA-256 of
everything the view's arrays depend on.  A file with another digest, of another shape or unreadable is not
used (the view is labelled again and the file replaced).  Only per-view results are kept: the threshold, the
weights and the prior are computed from them on every call (milliseconds).

Used by :func:`senerf.selftrain.estimate_reliability` (its ``resume`` argument).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import torch

from ..atomic import read_npz_record, write_npz_record
from ..train.evaluate import evaluation_digest

__all__ = ["labelling_digest", "read_labelled_view", "write_labelled_view", "labelled_view_layout",
           "LABELLED_VIEW_ARRAYS"]

#: The per-view arrays a record holds: teacher ``rgb (H, W, 3)``, ``z_depth``, ``acc``, max ``similarity`` (all
#: ``(H, W)`` float32) and ``foreground (H, W)`` bool (:func:`labelled_view_layout`).
LABELLED_VIEW_ARRAYS = ("rgb", "z_depth", "acc", "similarity", "foreground")


def labelled_view_layout(size: tuple[int, int]) -> dict[str, tuple[tuple[int, ...], type]]:
    """``{name: (shape, dtype)}`` of each of :data:`LABELLED_VIEW_ARRAYS` for one view of ``size (H, W)``."""
    h, w = size
    return {name: ((h, w, 3) if name == "rgb" else (h, w), bool if name == "foreground" else np.float32)
            for name in LABELLED_VIEW_ARRAYS}


def labelling_digest(teacher, occupancy, model, scene, train_idx, pseudo_c2w: np.ndarray, pseudo_intrinsics,
                     extractor, opacity_threshold: float, occlusion_rel_tol: float) -> str:
    """SHA-256 naming one labelling: the teacher's and its grid's tensors, the model settings, the known views
    ``train_idx`` (cameras and photos, as :func:`senerf.train.evaluation_digest`), the pseudo cameras
    ``pseudo_c2w (P, 4, 4)`` and ``pseudo_intrinsics`` (P ``Intrinsics``), the feature extractor (its class,
    settings and weights) and the occlusion test's settings."""
    h = hashlib.sha256(evaluation_digest(teacher, occupancy, model, scene, train_idx).encode())
    h.update(np.ascontiguousarray(pseudo_c2w, dtype=np.float64).tobytes())
    for k in pseudo_intrinsics:
        h.update(repr(k).encode())
    _update(h, (type(extractor).__module__, type(extractor).__qualname__, getattr(extractor, "name", ""),
                getattr(extractor, "__dict__", {})))
    h.update(repr((float(opacity_threshold), float(occlusion_rel_tol))).encode())
    return h.hexdigest()


def _update(h, value) -> None:
    """Feed ``value`` (scalars, strings, arrays, tensors and dicts / sequences of them) into the hash ``h``."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    if isinstance(value, np.ndarray):
        h.update(f"{value.dtype}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, dict):
        h.update(b"{")
        for key in sorted(value, key=repr):
            h.update(repr(key).encode())
            _update(h, value[key])
        h.update(b"}")
    elif isinstance(value, (list, tuple)):
        h.update(b"[")
        for item in value:
            _update(h, item)
        h.update(b"]")
    else:
        h.update(repr(value).encode())


def _view_path(folder: Path, i: int) -> Path:
    return Path(folder) / f"view_{i:03d}.npz"


def read_labelled_view(folder, i: int, digest: str, size: tuple[int, int]) -> dict | None:
    """The recorded arrays of pseudo view ``i`` (:data:`LABELLED_VIEW_ARRAYS`, plus ``seconds``: the time its
    labelling took) when ``folder`` holds them under ``digest`` at image ``size (H, W)``; else None."""
    return read_npz_record(_view_path(folder, i), digest, labelled_view_layout(size), scalars=("seconds",))


def write_labelled_view(folder, i: int, digest: str, arrays: dict, seconds: float) -> None:
    """Record pseudo view ``i``'s ``arrays`` (:data:`LABELLED_VIEW_ARRAYS`) and the ``seconds`` they took under
    ``digest``, atomically (``folder`` is created)."""
    write_npz_record(_view_path(folder, i), digest, {name: arrays[name] for name in LABELLED_VIEW_ARRAYS},
                     seconds=seconds)
