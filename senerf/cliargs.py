"""Command-line argument helpers shared by ``senerf-fit``, ``senerf-render`` and ``senerf-bench``.

Every problem is an :class:`senerf.errors.InputError` whose message names the flag, so each command
print it as one ``<prog>: error: argument --flag: <problem>`` line and exit with status 2.
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

__all__ = ["OneLineParser", "console_entry", "argument_type", "int_flag", "float_flag", "check_device", "threads_flag",
           "set_threads", "short_openmp_waits", "warn_planes_path", "run_command", "SEED_MAX", "THREADS_MAX",
           "THREADS_HELP", "OPENMP_SPINS"]

#: Largest seed either command accepts (torch generators take a signed 64-bit seed).
SEED_MAX = 2**63 - 1


class OneLineParser(argparse.ArgumentParser):
    """argparse that raises :class:`InputError` instead of printing usage and exiting."""

    def error(self, message: str):  # noqa: D401 - argparse hook
        raise InputError(message)


def argument_type(convert):
    """An argparse ``type`` from a converter raising :class:`InputError`: argparse reports a ValueError as
    "invalid <function> value", so the problem is handed over as an ``ArgumentTypeError`` (argparse then
    writes ``argument --flag: <problem>``)."""
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


def _bounds_text(minimum: float | None, positive: bool, maximum: float | None) -> str:
    """`` > 0 and <= 3``: every bound given, for a message (empty when none)."""
    bounds = []
    if positive:
        bounds.append("> 0")
    if minimum is not None:
        bounds.append(f">= {minimum:g}")
    if maximum is not None:
        bounds.append(f"<= {maximum:g}")
    return " " + " and ".join(bounds) if bounds else ""


def float_flag(flag: str, minimum: float | None = None, positive: bool = False, maximum: float | None = None):
    """A finite float, at least ``minimum`` / at most ``maximum`` when given, above 0 when ``positive``."""
    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"expected a number, got {text!r}", field=flag) from None
        if (value != value or value in (float("inf"), float("-inf")) or (minimum is not None and value < minimum)
                or (positive and value <= 0) or (maximum is not None and value > maximum)):
            raise InputError(f"expected a finite number{_bounds_text(minimum, positive, maximum)}, got {text!r}",
                             field=flag)
        return value
    return argument_type(convert)


def check_device(device: str, flag: str = "--device") -> str:
    """``device`` when torch can use it: ``cpu``, ``cuda`` or ``cuda:N`` with an N this machine has; else an
    :class:`InputError` naming ``flag`` (torch is imported only for a name other than ``cpu``)."""
    if device == "cpu":
        return device
    import torch

    from senerf.train.config import is_device_name

    if not is_device_name(device):
        raise InputError(f"expected cpu, cuda or cuda:N, got {device!r}", field=flag)
    if not torch.cuda.is_available():
        raise InputError("CUDA requested but torch sees no GPU (use --device cpu)", field=flag)
    index = torch.device(device).index
    if index is not None and index >= torch.cuda.device_count():
        raise InputError(f"{device} requested but torch sees {torch.cuda.device_count()} GPU(s) "
                         f"(cuda:0 ... cuda:{torch.cuda.device_count() - 1})", field=flag)
    return device


#: The most CPU threads ``--threads`` accepts (far above any machine's cores; a typo like 20000 is refused).
THREADS_MAX = 1024

THREADS_HELP = ("torch's CPU threads (default: torch's, usually one per core). A CPU fit repeats to the bit "
                "for the same seed, thread count, processor and torch build only; give the count a run was made "
                "with (metrics.json's host.threads) to repeat it on another machine with the same processor "
                "(host.cpu: another one takes other kernels, and the figures move)")


def threads_flag(flag: str = "--threads"):
    """The ``--threads`` argument type: an integer in ``[1, THREADS_MAX]``."""
    return int_flag(flag, maximum=THREADS_MAX)


def set_threads(threads: int | None) -> None:
    """``torch.set_num_threads(threads)`` unless ``threads`` is None (torch keeps its default).

    The count sets how torch's CPU kernels, and senerf's compiled K-Planes kernel (which splits its points over
    ``torch.get_num_threads()`` workers), divide their sums, so it decides a CPU fit's figures to the last bit
    (BENCHMARKS.md, session 19); ``--threads N`` lets another machine with the same processor and torch build
    repeat them (another processor takes other kernels: lego balanced seed 0's teacher moved by 0.6 dB from an AMD
    EPYC to an Intel Xeon, session 23).  Importing torch is left to this
    call's first use, as with :func:`check_device`.
    """
    if threads is None:
        return
    import torch

    torch.set_num_threads(int(threads))


#: Spins an idle OpenMP worker makes before it sleeps (GNU libgomp, torch's OpenMP on Linux), senerf-fit's and
#: senerf-render's default; see :func:`short_openmp_waits`.
OPENMP_SPINS = 1000


def warn_planes_path(prog: str, model, device: str) -> None:
    """Print ``PROG: warning: ...`` to stderr when ``model`` (a :class:`senerf.train.ModelConfig`) is a K-Planes
    field on the CPU and its compiled kernel cannot be used (no C compiler: the pure-PyTorch path runs, slower and
    to other bits; :func:`senerf.fields.ckernel.cpu_planes_warning`)."""
    if model.field == "kplanes" and device.split(":")[0] == "cpu":
        from senerf.fields.ckernel import cpu_planes_warning

        line = cpu_planes_warning(model.n_features)
        if line is not None:
            print(f"{prog}: warning: {line}", file=sys.stderr)


def short_openmp_waits(environ=os.environ) -> None:
    """Let torch's OpenMP workers spin briefly, then sleep, unless the user chose (``setdefault``); only effective
    before torch is first imported.

    libgomp reckons ~100000 spins a millisecond, so 1000 spins is ~10 us where its default, 300000, is ~3 ms.
    Workers that spin long make small torch ops many times slower when the cores are shared: two 200-step
    trainings side by side on the 2-core machine took 161 s each with 30000 spins against 28 s with sleeping
    waits (``OMP_WAIT_POLICY=PASSIVE``).  Sleeping at once costs a futex wake per parallel region: alone, a lego
    fast fit at 100x100 took 79-82 s wall with PASSIVE and 61-62 s with 1000 spins, the same figures to the bit.
    Side by side, two such fits took 87 s each with PASSIVE and 112-113 s with 1000 spins (65 s each with
    ``--threads 1``).  BENCHMARKS.md, "OpenMP waits and CPU threads on the 2-core machine" (session 20).
    ``OMP_WAIT_POLICY=PASSIVE`` stays set for OpenMP runtimes that do not read ``GOMP_SPINCOUNT``; libgomp
    lets ``GOMP_SPINCOUNT`` override it.
    """
    environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    environ.setdefault("GOMP_SPINCOUNT", str(OPENMP_SPINS))


#: OSError numbers that say a path the user gave cannot be used as it is (permissions, a name too long, a loop
#: of links): bad input, reported in one line with the path, wherever a loader met it
_USER_ERRNOS = frozenset({errno.EACCES, errno.EPERM, errno.ENAMETOOLONG, errno.ELOOP})
#: OSError numbers that say the disk is full (or the user's quota spent): not a bug, and nothing finished is lost
#: (every output is written atomically), so one line saying what to do, as for an interrupt
_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


def _chain(exc: BaseException | None):
    """``exc`` and the exceptions behind it (each one's ``__cause__``, else its ``__context__``), once each."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        yield exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__


def _full_disk(exc: BaseException) -> OSError | None:
    """The full-disk OSError behind ``exc``, or None: torch.save, for one, reports a failed write as a
    RuntimeError raised while handling the ENOSPC OSError, so the whole chain is searched."""
    return next((e for e in _chain(exc) if isinstance(e, OSError) and e.errno in _FULL_ERRNOS), None)


def _interrupt_behind(exc: BaseException) -> bool:
    """True when a KeyboardInterrupt is behind ``exc``: an error raised while an interrupt unwound (a cleanup
    that imports a module the interrupt left half-imported, say) is the interrupt's, not a bug."""
    return any(isinstance(e, KeyboardInterrupt) for e in _chain(exc))


def _one_line(exc: Exception) -> str:
    """``exc`` in one line: an :class:`InputError`'s own message, else ``Type: message``."""
    said = " ".join(str(exc).split())
    if isinstance(exc, InputError):
        return said
    return f"{type(exc).__name__}: {said}" if said else type(exc).__name__


def console_entry(main) -> NoReturn:
    """Exit with ``main()``'s status, ignoring Ctrl-C once it has returned: the command is done, and an interrupt
    during the interpreter's shutdown would only print the traceback of an ignored KeyboardInterrupt (seen in
    5 of 5 SIGINTs sent 0-10 ms after senerf-fit's last line), or kill the finished command.  What the console
    scripts and ``python -m`` call; :func:`run_command` handles interrupts while ``main`` runs."""
    status = main()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.exit(status)


def run_command(prog: str, body, interrupted: str) -> int:
    """``body()``'s exit status, with every way out of a command mapped to one: 2 for bad input (one line
    ``<prog>: error: <message>``, no traceback), argparse's own status for ``--help`` / ``--version``, 130 when
    interrupted (``interrupted`` says what to do next; also for an error raised while an interrupt unwound,
    which the line names), 2 also for a full disk (one line, with ``interrupted``), 1 for an internal error
    (with the traceback).
    Warnings raised meanwhile print as one ``<prog>: warning: <message>`` line each, without source lines.
    A SIGTERM (what batch schedulers send) counts as an interrupt, so ``finally`` blocks run and temporary
    files go."""
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
        return int(exc.code or 0) if isinstance(exc.code, int) or exc.code is None else 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted ({interrupted})", file=sys.stderr)
        return 130
    except Exception as exc:
        if _interrupt_behind(exc):   # named, in case it is a bug of the cleanup rather than the interrupt's
            print(f"{prog}: interrupted ({interrupted}); while stopping: {_one_line(exc)}", file=sys.stderr)
            return 130
        if isinstance(exc, InputError):
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2
        if isinstance(exc, OSError) and exc.errno in _USER_ERRNOS and exc.filename:
            # a file or folder of the user's we may not read or search (or name): theirs to fix, one line
            print(f"{prog}: error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        full = _full_disk(exc)
        if full is not None:
            where = f"{full.filename}: " if full.filename else ""
            print(f"{prog}: error: {where}{full.strerror or full}; free some space ({interrupted})", file=sys.stderr)
            return 2
        traceback.print_exc()   # an internal error: keep the traceback for the bug report
        print(f"{prog}: internal error (please report it with the traceback above)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:   # None: not set from Python (or not the main thread), nothing to restore
            signal.signal(signal.SIGTERM, previous)
