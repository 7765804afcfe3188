"""Execute one run: ``senerf-fit`` in a child process, timed, its peak memory measured, metrics parsed.

:func:`execute_run` is what every executor (local threads or Ray workers) calls; it never raises for a
failed fit: a crash, an out-of-memory kill, a timeout or a malformed ``metrics.json`` all come back as a
``"failed"`` outcome, so one bad run costs only itself.

Peak memory is the fit's maximum resident set size (Linux ``ru_maxrss`` from ``os.wait4``, covering the fit
and the descendants it waited for).  ``ru_maxrss`` of a child also counts the memory of the process that
spawned it (the pages it shared before ``exec``), so the driver (numpy, matplotlib: ~70 MiB) does not spawn
the fit itself: a minimal wrapper interpreter (``python -S``, ~10 MiB, the only bias left) spawns it, waits
for it and writes its ``ru_maxrss`` to a file.  Each run has its own wrapper, so concurrent runs never mix
their figures.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .machine import machine_info
from .protocols import parse_protocol
from .specs import RunSpec

__all__ = ["default_fit_command", "RunnerConfig", "execute_run", "parse_metrics", "check_protocol"]

#: Minimal wrapper: ``python -S -c _WRAPPER REPORT PROG ARGS...`` runs PROG, writes its ru_maxrss (KiB) to
#: REPORT, and ends the way PROG ended (same status, or killed by the same signal).  It forwards SIGTERM /
#: SIGINT / SIGHUP to PROG, and stops PROG (SIGTERM, then SIGKILL after 10 s) when its own parent (the
#: driver or Ray worker) dies, so an interrupted benchmark leaves no orphaned fits behind.
_WRAPPER = """
import os, signal, sys, time
report, argv = sys.argv[1], sys.argv[2:]
parent = os.getppid()
try:
    pid = os.posix_spawnp(argv[0], argv, os.environ)
except OSError as exc:
    print(f"cannot start {argv[0]}: {exc}", flush=True)
    sys.exit(127)
for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
    signal.signal(sig, lambda n, f: os.kill(pid, n))
orphaned_at = None
while True:
    done, status, usage = os.wait4(pid, os.WNOHANG)
    if done == pid:
        break
    if orphaned_at is None and os.getppid() != parent:
        orphaned_at = time.monotonic()
        os.kill(pid, signal.SIGTERM)
    elif orphaned_at is not None and time.monotonic() - orphaned_at > 10:
        os.kill(pid, signal.SIGKILL)
    time.sleep(0.2)
with open(report, "w") as f:
    f.write(str(usage.ru_maxrss))
if os.WIFSIGNALED(status):
    try:
        signal.signal(os.WTERMSIG(status), signal.SIG_DFL)
    except (OSError, ValueError):
        pass
    os.kill(os.getpid(), os.WTERMSIG(status))
sys.exit(os.waitstatus_to_exitcode(status))
"""

_FIT_CODE = "import sys; from senerf.cli import main; sys.exit(main(sys.argv[1:]))"


def default_fit_command() -> tuple[str, ...]:
    """``senerf-fit`` through this process's interpreter (no reliance on PATH); evaluated where the run
    executes, so a Ray worker uses its own Python."""
    return (sys.executable, "-c", _FIT_CODE)


@dataclass(frozen=True)
class RunnerConfig:
    """How runs are executed.

    Attributes:
        runs_dir: parent folder of the per-run output folders (``runs_dir/<spec.dirname()>``).
        fit_command: program prefix; the spec's ``senerf-fit`` arguments are appended.  ``None``:
            :func:`default_fit_command` on the executing machine.  Tests pass a small fake fit here.
        timeout_s: wall-clock limit per run in seconds (``None``: no limit).
        threads: ``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` for the child (``None``: inherit).
        poll_s: polling period while waiting for the child, seconds.
        env: extra environment variables for the child, as ``(name, value)`` pairs.
    """

    runs_dir: str
    fit_command: tuple[str, ...] | None = None
    timeout_s: float | None = None
    threads: int | None = None
    poll_s: float = 0.1
    env: tuple[tuple[str, str], ...] = field(default_factory=tuple)


def execute_run(spec: RunSpec, cfg: RunnerConfig) -> dict:
    """Run one fit and return its outcome (a JSON-ready dict; never raises for a failed fit).

    Returns:
        dict with ``key``, ``status`` (``"ok"``/``"failed"``), ``returncode`` (None on timeout), ``error``
        (one line, None when ok), ``log_tail`` (last lines of the child's output), ``run_seconds`` (wall
        clock of the child, s), ``peak_memory_mib`` (child's max RSS, MiB), ``metrics`` (parsed
        ``metrics.json`` or None), ``machine`` (:func:`machine_info`), ``fit_command`` (argv), ``run_dir``.
    """
    run_dir = Path(cfg.runs_dir) / spec.dirname()
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    argv = [*(cfg.fit_command or default_fit_command()), *spec.fit_args(run_dir)]
    log_path = run_dir.parent / f"{spec.dirname()}.log"   # beside the folder: --overwrite may wipe it
    rss_path = run_dir.parent / f"{spec.dirname()}.maxrss"
    rss_path.unlink(missing_ok=True)
    _clear_run_dir(run_dir, Path(cfg.runs_dir))
    wrapped = [sys.executable, "-S", "-c", _WRAPPER, str(rss_path), *argv]
    returncode, seconds = _run_child(wrapped, log_path, _child_env(cfg), cfg.timeout_s, cfg.poll_s)
    maxrss_kib = _read_int(rss_path)
    outcome = {"key": spec.key(), "returncode": returncode, "run_seconds": round(seconds, 3),
               "peak_memory_mib": None if maxrss_kib is None else round(maxrss_kib / 1024.0, 1),
               "machine": machine_info(spec.device),
               "fit_command": argv, "run_dir": str(run_dir), "log_tail": _tail(log_path), "metrics": None}
    metrics_path = run_dir / "metrics.json"
    error = None
    if returncode is None:
        error = f"timed out after {cfg.timeout_s} s"
    elif returncode != 0:
        error = f"senerf-fit exited with status {returncode}" + (
            f" (signal {-returncode})" if returncode < 0 else "")
    else:
        try:
            outcome["metrics"] = parse_metrics(metrics_path, expected_iterations=spec.iterations)
            check_protocol(spec, outcome["metrics"])
        except ValueError as exc:
            error = str(exc)
    outcome["status"] = "ok" if error is None else "failed"
    outcome["error"] = error
    return outcome


def parse_metrics(path: str | Path, expected_iterations: int | None = None) -> dict:
    """Read and check a ``metrics.json`` (DESIGN.md contract); raises ``ValueError`` naming the problem.

    Checks: the file parses; ``iterations`` is a non-empty list whose entries have an int ``iteration``,
    numeric ``psnr``/``ssim``/``seconds``; with ``expected_iterations`` K the entries are exactly 0..K.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read metrics ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    iters = data.get("iterations") if isinstance(data, dict) else None
    if not isinstance(iters, list) or not iters:
        raise ValueError(f"{path}: iterations: missing or empty")
    for i, it in enumerate(iters):
        if not isinstance(it, dict) or not isinstance(it.get("iteration"), int):
            raise ValueError(f"{path}: iterations[{i}].iteration: missing or not an integer")
        for name in ("psnr", "ssim", "seconds"):
            if not _is_number(it.get(name)):
                raise ValueError(f"{path}: iterations[{i}].{name}: missing or not a number")
    found = [it["iteration"] for it in iters]
    if expected_iterations is not None and found != list(range(expected_iterations + 1)):
        raise ValueError(f"{path}: iterations: expected 0..{expected_iterations}, found {found}")
    return data


def check_protocol(spec: RunSpec, metrics: dict) -> None:
    """Raise ``ValueError`` when a fit's ``metrics.json`` does not describe the spec's protocol.

    Checks ``resolution`` == the protocol's ``[H, W]``, ``len(train_views)`` == its view count and, where the
    protocol fixes the views (Extreme, InfoNeRF 4, seeded random 8), ``train_views`` == those views (as
    sets; indices into the Blender train split, which come first in the scene arrays).  A number measured
    under another protocol must never be filed under this one.
    """
    proto = parse_protocol(spec.protocol)
    if list(metrics.get("resolution") or []) != list(proto.size):
        raise ValueError(f"metrics.json: resolution {metrics.get('resolution')} is not {list(proto.size)} "
                         f"required by {spec.protocol}")
    views = metrics.get("train_views")
    if not isinstance(views, list) or len(views) != proto.n_views:
        raise ValueError(f"metrics.json: train_views {views} should hold {proto.n_views} views for {spec.protocol}")
    expected = spec.views()
    if expected is not None and sorted(views) != sorted(expected):
        raise ValueError(f"metrics.json: train_views {views} differ from the protocol's {list(expected)}")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _child_env(cfg: RunnerConfig) -> dict[str, str]:
    env = dict(os.environ)
    if cfg.threads is not None:
        for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
            env[name] = str(cfg.threads)
    env.update(dict(cfg.env))
    return env


def _run_child(argv: list[str], log_path: Path, env: dict[str, str], timeout_s: float | None,
               poll_s: float) -> tuple[int | None, float]:
    """Run ``argv`` with output to ``log_path``; returns (returncode or None on timeout, wall seconds).

    The child gets its own session so a timeout kills its whole process group.
    """
    start = time.perf_counter()
    with open(log_path, "wb") as log:
        try:
            proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env,
                                    start_new_session=True)
        except OSError as exc:
            log.write(f"cannot start {argv[0]}: {exc}\n".encode())
            return 127, time.perf_counter() - start
        timed_out = False
        while True:
            pid, status = os.waitpid(proc.pid, os.WNOHANG)
            if pid == proc.pid:
                break
            if timeout_s is not None and time.perf_counter() - start > timeout_s and not timed_out:
                timed_out = True
                _kill_group(proc.pid)
            time.sleep(poll_s)
    seconds = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    proc.returncode = code              # reaped here; keep Popen from waiting again
    return (None if timed_out else code), seconds


def _clear_run_dir(run_dir: Path, runs_dir: Path) -> None:
    """Remove an earlier attempt's folder so every attempt starts from scratch.

    ``senerf-fit`` resumes its own run from checkpoints; a retried benchmark run must not, or its seconds
    and peak memory would cover only the remainder (and a stale metrics.json could pass for this attempt's).
    """
    if run_dir.is_dir() and run_dir.resolve().parent == runs_dir.resolve():
        shutil.rmtree(run_dir)


def _read_int(path: Path) -> int | None:
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


def _kill_group(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def _tail(path: Path, n_lines: int = 20, max_chars: int = 4000) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    return "\n".join(text.splitlines()[-n_lines:])[-max_chars:]
