"""Atomic checkpoints (:mod:`senerf.atomic`) that are loaded with ``torch.load(weights_only=True)`` only: a
checkpoint is a dict of tensors, numbers, strings, lists and dicts, no pickled objects (its keys: DESIGN.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from senerf.atomic import atomic_write
from senerf.errors import InputError

__all__ = ["save_checkpoint", "load_checkpoint", "load_field"]

_FORMAT = "senerf-train-1"   # the format tag of a training checkpoint (train_field's)


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> None:
    """Atomically save ``state`` (tensors, numbers, strings, lists, dicts only) to ``path``."""
    if not isinstance(state, dict):
        raise ValueError(f"state must be a dict, got {type(state).__name__}")
    atomic_write(Path(path), lambda fh: torch.save(state, fh))


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint` with ``weights_only=True``.

    Anything that is not plain data (a pickle that would construct arbitrary objects or run code) is
    refused with :class:`senerf.errors.InputError` naming the file; nothing in it is executed.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("checkpoint not found", file=path)
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # UnpicklingError for forbidden globals, RuntimeError for corrupt files
        if isinstance(exc, OSError) and exc.errno is not None:   # permissions: not a damaged file to delete
            raise InputError(f"cannot be read ({exc.strerror or exc})", file=path) from None
        # torch's own message suggests weights_only=False, i.e. running the file's code: not quoted
        raise InputError(f"refusing to load: not a plain-data checkpoint ({type(exc).__name__}; a damaged file, "
                         "or one senerf did not write, and senerf never runs code from a file); delete it to "
                         "redo that step", file=path) from None
    if not isinstance(state, dict):
        raise InputError(f"checkpoint holds a {type(state).__name__}, expected a dict", file=path)
    return state


def _load_training_state(path: Path, field, occupancy=None, optimizer=None) -> dict:
    """Load the training checkpoint ``path`` (:func:`senerf.train.train_field`'s) into ``field`` and, unless None,
    ``occupancy`` and ``optimizer``; returns its dict.

    Raises:
        InputError: naming ``path``: not a plain-data training checkpoint, states that do not fit the objects, or
            non-finite weights (inf only in the grid, where it marks cells not yet measured).
    """
    state = load_checkpoint(path, map_location="cpu")
    if state.get("format") != _FORMAT:
        raise InputError("not a senerf training checkpoint", file=path)
    try:
        for module, key in ((field, "field"), (occupancy, "occupancy"), (optimizer, "optimizer")):
            if module is not None:
                module.load_state_dict(state[key])
    except (RuntimeError, KeyError, ValueError, TypeError, AttributeError) as exc:
        raise InputError(f"does not fit the model it is loaded into ({str(exc).splitlines()[0] or type(exc).__name__})"
                         "; delete it or use another output folder", file=path) from None
    for module, inf_ok in ((field, False), (occupancy, True)):
        floats = [] if module is None else [v for v in module.state_dict().values() if v.is_floating_point()]
        if any(bool(v.isnan().any()) or (not inf_ok and bool(v.isinf().any())) for v in floats):
            raise InputError("holds non-finite weights", file=path)
    return state


def load_field(path: str | Path, model, seed: int, steps: int, device: str | torch.device = "cpu"):
    """The field (eval mode) and occupancy grid (or None) of the training checkpoint ``path``.

    Args:
        path: a checkpoint :func:`senerf.train.train_field` wrote (``checkpoints/iter_K_train.pt``).
        model: the :class:`senerf.config.ModelConfig` it was trained with.
        seed, steps: the training's seed and steps (a NeRF field's annealing schedule is built from them).

    Raises:
        InputError: no such file, not a plain-data checkpoint, or tensors that do not fit ``model``.
    """
    from .loop import make_occupancy
    from .model import build_field

    field, occupancy = build_field(model, seed=seed, steps=steps), make_occupancy(model, "cpu")
    _load_training_state(Path(path), field, occupancy)
    device = torch.device(device)
    return field.to(device).eval(), None if occupancy is None else occupancy.to(device)
