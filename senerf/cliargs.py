"""What ``senerf-fit``, ``senerf-render`` and ``senerf-bench`` share on the command line: argument types whose
problems are :class:`senerf.errors.InputError`\\ s naming the flag, the thread and OpenMP settings, and
:func:`run_command`, which maps every way out of a command to its exit status and one line.
"""

from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import threading
import traceback
import warnings
from typing import NoReturn

from senerf.errors import InputError

__all__ = ["OneLineParser", "console_entry", "command_main", "argument_type", "int_flag", "float_flag", "check_device",
           "threads_flag", "set_threads", "short_openmp_waits", "huge_page_tensors", "run_command", "SEED_MAX",
           "THREADS_MAX", "THREADS_HELP", "OPENMP_SPINS"]

#: Largest seed the commands accept (torch generators take a signed 64-bit seed).
SEED_MAX = 2**63 - 1
#: The most CPU threads ``--threads`` accepts (far above any machine's cores; a typo like 20000 is refused).
THREADS_MAX = 1024
THREADS_HELP = ("torch's CPU threads (default: torch's, one per core). A CPU fit repeats to the bit for the same "
                "seed, thread count, processor and torch build; give the count a run was made with (metrics.json's "
                "host.threads) to repeat it on another machine with the same processor")
#: Spins an idle OpenMP worker makes before it sleeps (GNU libgomp), the commands' default
#: (:func:`short_openmp_waits`).
OPENMP_SPINS = 1000


class OneLineParser(argparse.ArgumentParser):
    """argparse that raises :class:`InputError` instead of printing usage and exiting."""

    def error(self, message: str):  # noqa: D401 - argparse hook
        raise InputError(message)


def argument_type(convert):
    """An argparse ``type`` from a converter raising :class:`InputError` (argparse then writes
    ``argument --flag: <problem>``)."""
    def checked(text: str):
        try:
            return convert(text)
        except InputError as exc:
            raise argparse.ArgumentTypeError(exc.problem) from None
    return checked


def int_flag(flag: str, allow_zero: bool = False, minimum: int | None = None, maximum: int | None = None):
    """An integer >= 1 (>= 0 with ``allow_zero``; >= ``minimum`` when given), at most ``maximum`` when given."""
    low = minimum if minimum is not None else (0 if allow_zero else 1)

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise InputError(f"expected an integer, got {text!r}", field=flag) from None
        if value < low or (maximum is not None and value > maximum):
            bound = f">= {low}" + ("" if maximum is None else f" and <= {maximum}")
            raise InputError(f"must be {bound}, got {value}", field=flag)
        return value
    return argument_type(convert)


def float_flag(flag: str, minimum: float | None = None, positive: bool = False, maximum: float | None = None):
    """A finite float, at least ``minimum`` / at most ``maximum`` when given, above 0 when ``positive``."""
    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"expected a number, got {text!r}", field=flag) from None
        if (value != value or abs(value) == float("inf") or (minimum is not None and value < minimum)
                or (positive and value <= 0) or (maximum is not None and value > maximum)):
            bounds = " and ".join(b for b in ("> 0" if positive else "",
                                              "" if minimum is None else f">= {minimum:g}",
                                              "" if maximum is None else f"<= {maximum:g}") if b)
            raise InputError(f"expected a finite number{' ' + bounds if bounds else ''}, got {text!r}", field=flag)
        return value
    return argument_type(convert)


def check_device(device: str, flag: str = "--device") -> str:
    """``device`` when torch can use it: ``cpu``, ``cuda`` or ``cuda:N`` with an N this machine has; else an
    :class:`InputError` naming ``flag`` (torch is imported only for a name other than ``cpu``)."""
    if device == "cpu":
        return device
    from senerf.config import is_device_name

    if not is_device_name(device):
        raise InputError(f"expected cpu, cuda or cuda:N, got {device!r}", field=flag)
    import torch

    if not torch.cuda.is_available():
        raise InputError("CUDA requested but torch sees no GPU (use --device cpu)", field=flag)
    index = torch.device(device).index
    if index is not None and index >= torch.cuda.device_count():
        raise InputError(f"{device} requested but torch sees {torch.cuda.device_count()} GPU(s)", field=flag)
    return device


def threads_flag(flag: str = "--threads"):
    """The ``--threads`` argument type: an integer in ``[1, THREADS_MAX]``."""
    return int_flag(flag, maximum=THREADS_MAX)


def set_threads(threads: int | None) -> None:
    """``torch.set_num_threads(threads)`` unless ``threads`` is None (torch keeps its default).  The count sets
    how torch's CPU kernels and senerf's compiled K-Planes kernel divide their sums, so it decides a CPU fit's
    figures to the last bit."""
    if threads is not None:
        import torch

        torch.set_num_threads(int(threads))


def short_openmp_waits(environ=os.environ) -> None:
    """Let torch's OpenMP workers spin :data:`OPENMP_SPINS` times (~10 us), then sleep, unless the user chose
    (``setdefault``); effective only before torch is first imported.  libgomp's default (~3 ms of spinning) makes
    small torch ops many times slower when fits share the cores, and sleeping at once costs a futex wake per
    parallel region (BENCHMARKS.md, "Threads").  ``OMP_WAIT_POLICY=PASSIVE`` is for OpenMP runtimes that do not
    read ``GOMP_SPINCOUNT``; libgomp lets ``GOMP_SPINCOUNT`` override it."""
    environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    environ.setdefault("GOMP_SPINCOUNT", str(OPENMP_SPINS))


def huge_page_tensors(environ=os.environ) -> None:
    """Let torch put tensors of 2 MiB and more on transparent huge pages (``THP_MEM_ALLOC_ENABLE=1``) unless the
    user chose; effective only before torch is first imported, and only where the kernel offers huge pages
    (``/sys/kernel/mm/transparent_hugepage/enabled`` not ``never``).  Each fresh large tensor otherwise costs a page
    fault per 4 KiB written, and a large field's step allocates several of its plane table's size (gradients of
    16.5 M parameters on LLFF): a fifth of the step (BENCHMARKS.md, "Whole fits phase by phase")."""
    environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")


def _behind(exc: BaseException, found) -> BaseException | None:
    """The first of ``exc`` and the exceptions behind it (causes, else contexts) for which ``found`` holds, or None:
    torch.save reports a full disk as a RuntimeError raised while handling the OSError, and a cleanup that fails
    while an interrupt unwinds raises its own error on top of the KeyboardInterrupt."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if found(exc):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def console_entry(main) -> NoReturn:
    """Exit with ``main()``'s status, ignoring Ctrl-C once it has returned (the command is done; an interrupt
    during the interpreter's shutdown would only print an ignored KeyboardInterrupt's traceback)."""
    status = main()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.exit(status)


def command_main(prog: str, body, argv: list[str] | None, interrupted: str) -> int:
    """A command's ``main``: ``body(argv)`` (default ``sys.argv[1:]``) through :func:`run_command`, with OpenMP's
    short waits and huge pages set before torch is imported (:func:`short_openmp_waits`,
    :func:`huge_page_tensors`)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    short_openmp_waits()
    huge_page_tensors()
    return run_command(prog, lambda: body(argv), interrupted)


def run_command(prog: str, body, interrupted: str) -> int:
    """``body()``'s exit status, with every way out of a command mapped to one: 2 and one line
    ``<prog>: error: <message>`` for bad input (:class:`InputError`) and for a full disk (with ``interrupted``,
    which says what to do next), argparse's own status for ``--help`` / ``--version``, 130 when interrupted
    (Ctrl-C or SIGTERM, which batch schedulers send), 1 with the traceback for an internal error.  Warnings print
    as one ``<prog>: warning: <message>`` line each."""
    def one_line(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"{prog}: warning: {' '.join(str(message).split())}", file=sys.stderr if file is None else file)

    def terminated(signum, frame):
        raise KeyboardInterrupt

    in_main = threading.current_thread() is threading.main_thread()   # only there can a handler be set
    previous = signal.signal(signal.SIGTERM, terminated) if in_main else None
    try:
        with warnings.catch_warnings():  # restores warnings.showwarning on exit
            warnings.showwarning = one_line
            return body()
    except SystemExit as exc:  # --help / --version
        return exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted ({interrupted})", file=sys.stderr)
        return 130
    except Exception as exc:
        if _behind(exc, lambda e: isinstance(e, KeyboardInterrupt)):   # the interrupt's; the error named in case
            print(f"{prog}: interrupted ({interrupted}); while stopping: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 130
        if isinstance(exc, InputError):
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2
        full = _behind(exc, lambda e: isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT))
        if full is not None:
            where = f"{full.filename}: " if full.filename else ""
            print(f"{prog}: error: {where}{full.strerror or full}; free some space ({interrupted})", file=sys.stderr)
            return 2
        traceback.print_exc()   # an internal error: keep the traceback for the bug report
        print(f"{prog}: internal error (please report it with the traceback above)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
