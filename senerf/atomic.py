"""Atomic file writes (no torch): a temporary file in the same folder, flushed and fsynced, then renamed
over the target, so a crash leaves the old file or the new one, never half of one; whole output folders the same
way (:func:`replace_folder`); and the check the commands make of an output folder before writing anything there
(:func:`output_folder`)."""

from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path

from senerf.errors import InputError

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "output_folder", "partial_folder",
           "replace_folder", "replaceable_folder"]


def partial_folder(out: Path) -> Path:
    """The hidden sibling ``.<name>.partial`` of ``out`` that :func:`replace_folder` writes into (what a killed
    write leaves; the next write there removes it)."""
    return out.with_name(f".{out.name}.partial")


def replaceable_folder(out, flag: str, overwrite: bool, ours, what: str) -> bool:
    """Refuse an ``out`` that :func:`replace_folder` may not write, after removing what a killed write there left
    (returns whether it did): not a folder, existing without ``overwrite``, or with it a folder that is neither empty
    nor an earlier output (``ours(out)``; nothing else is ever removed).  ``flag`` and ``what`` (``"a senerf-render
    output"``) name them in the one-line :class:`InputError`."""
    out = Path(out)
    partial = partial_folder(out)
    left = partial.is_dir()
    if left:
        shutil.rmtree(partial)
    output_folder(out, flag)
    if not os.path.lexists(out):
        return left
    if not overwrite:
        raise InputError(f"exists; use --overwrite (replaces {what}) or another {flag}", file=out)
    if out.is_dir() and any(out.iterdir()) and not ours(out):
        raise InputError(f"is not {what}; --overwrite replaces only those: choose another {flag}", file=out)
    return left


def replace_folder(out, fill) -> Path:
    """Write the folder ``out`` whole or not at all: ``fill(folder)`` writes into ``.<name>.partial/new`` beside it,
    which then takes ``out``'s place; an earlier ``out`` is moved aside first (and back, if the new one cannot take
    its place) and removed.

    Raises:
        InputError: a write or rename failed (a full disk, a mount point), naming ``out``.
    """
    out = Path(out)
    new, old = partial_folder(out) / "new", partial_folder(out) / "old"
    shutil.rmtree(partial_folder(out), ignore_errors=True)
    try:
        new.mkdir(parents=True)
        fill(new)
        if os.path.lexists(out):
            out.rename(old)
            try:
                new.rename(out)
            except BaseException:   # an interrupt or a failure between the renames: the earlier output goes back
                old.rename(out)
                raise
        else:
            new.rename(out)
    except OSError as exc:
        raise InputError(f"cannot write there ({exc.strerror or exc})", file=out) from None
    finally:
        shutil.rmtree(partial_folder(out), ignore_errors=True)
    return out


def output_folder(path, flag: str) -> Path:
    """``path`` as an output folder; :class:`InputError` naming it when something other than a folder is
    there (``flag``: the option that gave it, for the message)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"exists and is not a folder; choose another {flag}", file=path)
    _check_creatable(path, flag, name=path)
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
    """Call ``write(binary file)`` on a temporary file beside ``path``, fsync it, rename it over ``path``."""
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
    """Write ``data`` to ``path`` atomically (:func:`atomic_write`)."""
    atomic_write(Path(path), lambda fh: fh.write(data))


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))
