"""Atomic checkpoints that are loaded with ``torch.load(weights_only=True)`` only.

A checkpoint is a dict of tensors, numbers, strings, lists and dicts (no pickled objects): the field's
and optimiser's state dicts, the step, the generator state (a uint8 tensor) and a config fingerprint.
It is written to a temporary file in the same folder, flushed and fsynced, then renamed over the target,
so a crash leaves either the old or the new checkpoint, never half of one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from senerf.atomic import atomic_write, atomic_write_bytes, atomic_write_text
from senerf.errors import InputError

__all__ = ["save_checkpoint", "load_checkpoint", "atomic_write_bytes", "atomic_write_text"]


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

