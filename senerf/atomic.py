"""Atomic file writes (no torch): a temporary file in the same folder, flushed and fsynced, then renamed
over the target, so a crash leaves the old file or the new one, never half of one.  Used by checkpoints,
metrics, renders and the benchmark report.  Also the checks the command lines make of an output path
before writing anything there (:func:`output_folder`, :func:`output_file`)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from senerf.errors import InputError

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "output_folder", "output_file"]


def output_folder(path, flag: str) -> Path:
    """``path`` as an output folder; :class:`InputError` naming it when something other than a folder is
    there (``flag``: the option that gave it, for the message)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"exists and is not a folder; choose another {flag}", file=path)
    return path


def output_file(path, flag: str) -> Path:
    """``path`` as an output file; :class:`InputError` naming it when a folder is there."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"is a folder; {flag} takes a file name", file=path)
    return path


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def atomic_write(path: Path, write) -> None:
    """Call ``write(binary file)`` on a temporary file beside ``path``, fsync it, rename it over ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    _fsync_dir(path.parent)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, ``os.replace``)."""
    atomic_write(Path(path), lambda fh: fh.write(data))


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))
