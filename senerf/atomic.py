"""Atomic file writes (no torch): a temporary file in the same folder, flushed and fsynced, then renamed
over the target, so a crash leaves the old file or the new one, never half of one.  Used by checkpoints,
metrics, renders and the benchmark report.  Also the checks the command lines make of an output path
before writing anything there (:func:`output_folder`, :func:`output_file`), and the digest-stamped ``.npz``
records that let interrupted work resume (:func:`write_npz_record`, :func:`read_npz_record`: the labelling
record of self-training, the frames of ``senerf-render``)."""

from __future__ import annotations

import io
import os
import secrets
import zipfile
from pathlib import Path

import numpy as np

from senerf.errors import InputError

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "output_folder", "output_file",
           "write_npz_record", "read_npz_record"]


def output_folder(path, flag: str) -> Path:
    """``path`` as an output folder; :class:`InputError` naming it when something other than a folder is
    there (``flag``: the option that gave it, for the message)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"exists and is not a folder; choose another {flag}", file=path)
    _check_creatable(path, flag, name=path)
    return path


def output_file(path, flag: str) -> Path:
    """``path`` as an output file; :class:`InputError` naming it when a folder is there."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"is a folder; {flag} takes a file name", file=path)
    _check_creatable(path.parent, flag, name=path)
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"is not writable; choose another {flag}", file=path)
    return path


def _check_creatable(folder: Path, flag: str, name: Path) -> None:
    """:class:`InputError` (naming ``name``) unless ``folder`` exists and is writable, or can be created: its
    nearest existing ancestor must be a writable folder.  A file in the way, or a folder without write
    permission, is refused now rather than after the work; places only the kernel refuses (``/sys``, as
    root) are caught where the first file is written."""
    existing = Path(os.path.abspath(folder))
    while not existing.exists() and existing != existing.parent:
        if existing.is_symlink():   # a broken link: creating the folder there fails (after the work, for a render)
            raise InputError(f"cannot be created: {existing} is a broken symbolic link (to {os.readlink(existing)}); "
                             f"choose another {flag}", file=name)
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"cannot be created: {existing} is not a folder; choose another {flag}", file=name)
    if not os.access(existing, os.W_OK | os.X_OK):
        where = "is not writable" if existing == Path(os.path.abspath(folder)) else f"cannot be created in {existing}"
        raise InputError(f"{where} (no write permission); choose another {flag}", file=name)


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


def _create_temp(path: Path) -> tuple[int, str]:
    """A new, exclusively created temporary file beside ``path``: (fd, its path).  Created with mode 0o666
    less the umask, as ``open`` would make ``path`` itself (``tempfile.mkstemp`` makes 0o600, and the
    rename would leave every output readable by its owner only)."""
    for _ in range(100):
        tmp = str(path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666), tmp
        except FileExistsError:  # pragma: no cover - 48 random bits collided
            continue
    raise FileExistsError(f"no free temporary name beside {path}")  # pragma: no cover


def atomic_write(path: Path, write) -> None:
    """Call ``write(binary file)`` on a temporary file beside ``path``, fsync it, rename it over ``path``.
    The file gets the permissions ``open`` would give a new file (0o666 less the umask)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _create_temp(path)
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


def write_npz_record(path: str | Path, digest: str, arrays: dict, compress: bool = False, **scalars: float) -> None:
    """Write ``arrays`` (name: array) and float ``scalars`` to the ``.npz`` file ``path`` atomically, stamped with
    ``digest`` (a string naming everything the arrays depend on), zlib-compressed with ``compress``; ``path``'s
    folder is created."""
    buf = io.BytesIO()
    save = np.savez_compressed if compress else np.savez
    save(buf, digest=np.str_(digest), **{name: np.float64(v) for name, v in scalars.items()},
         **{name: np.asarray(a) for name, a in arrays.items()})
    atomic_write_bytes(path, buf.getvalue())


def read_npz_record(path: str | Path, digest: str, layout: dict, scalars: tuple[str, ...] = ()) -> dict | None:
    """The arrays and ``scalars`` (floats) of the record ``path`` when it was written under ``digest`` and holds
    every array of ``layout`` (``{name: (shape, dtype)}``) with that shape and dtype; else None (no file, another
    digest, an unreadable or truncated file, a missing name: the work is done again and the file replaced)."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as f:
            if str(f["digest"]) != digest:
                return None
            out = {name: np.array(f[name]) for name in layout}
            out.update({name: float(f[name]) for name in scalars})
    except (OSError, ValueError, KeyError, EOFError, TypeError, zipfile.BadZipFile):   # TypeError: a bare .npy
        return None
    for name, (shape, dtype) in layout.items():
        if out[name].shape != tuple(shape) or out[name].dtype != np.dtype(dtype):
            return None
    return out
