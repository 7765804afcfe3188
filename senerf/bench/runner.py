"""Running the grid: each run is ``senerf-fit`` in a child process, on this machine or on a Ray cluster, through one
driver (:func:`run_benchmark`) whatever the executor; one failed or lost run costs only itself.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import math
import os
import platform
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from senerf.config import PRESETS
from senerf.errors import is_number

from .protocols import RunSpec, parse_protocol
from .results import append_lines, final_ok_lines, load_results, result_lines
from .summary import preset_label

__all__ = ["RunnerConfig", "default_fit_command", "execute_run", "read_metrics", "RayExecutor",
           "make_executor", "BenchOutcome", "pending_specs", "dry_run_lines", "estimate_seconds", "estimate_lines",
           "run_benchmark", "git_commit"]

#: ``python -S -c _WRAPPER REPORT PROG ARGS...`` runs PROG and writes ``"MAXRSS EXITCODE"`` to REPORT: PROG's peak
#: resident set size in KiB (``ru_maxrss`` from ``os.wait4``) and its exit code (``-N`` when signal N killed it).
#: A child's ``ru_maxrss`` also counts its parent's peak before ``exec``, so the driver (numpy, matplotlib) does not
#: spawn the fit itself: this minimal interpreter (about 10 MiB, the only bias left) does.  It forwards SIGTERM /
#: SIGINT / SIGHUP to PROG, and kills its process group (itself, PROG and PROG's children) when its own parent (the
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
while True:
    done, status, usage = os.wait4(pid, os.WNOHANG)
    if done == pid:
        break
    if os.getppid() != parent:
        os.killpg(0, signal.SIGKILL)
    time.sleep(0.2)
with open(report, "w") as f:
    f.write(f"{usage.ru_maxrss} {os.waitstatus_to_exitcode(status)}")
"""


def default_fit_command() -> tuple[str, ...]:
    """``senerf-fit`` through this process's interpreter (no reliance on PATH); evaluated where the run
    executes, so a Ray worker uses its own Python."""
    return (sys.executable, "-c", "import sys; from senerf.cli import main; sys.exit(main(sys.argv[1:]))")


@dataclass(frozen=True)
class RunnerConfig:
    """How runs are executed.

    Attributes:
        runs_dir: parent folder of the per-run output folders (``runs_dir/<spec.dirname()>``).
        fit_command: program prefix; the spec's ``senerf-fit`` arguments are appended.  ``None``:
            :func:`default_fit_command` on the executing machine.  Tests pass a small fake fit here.
        timeout_s: wall-clock limit per run in seconds (``None``: no limit).
        threads: ``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` for the child (``None``: inherit).
    """

    runs_dir: str
    fit_command: tuple[str, ...] | None = None
    timeout_s: float | None = None
    threads: int | None = None


def execute_run(spec: RunSpec, cfg: RunnerConfig) -> dict:
    """Run one fit from a clean folder and return its outcome (a JSON-ready dict; never raises for a failed fit).

    Every attempt starts from scratch: ``senerf-fit`` would resume its own run from checkpoints, and then the
    seconds and peak memory would cover only the remainder.

    Returns:
        dict with ``status`` (``"ok"``/``"failed"``), ``error`` (one line, None when ok), ``returncode`` (None on
        timeout), ``log_tail``, ``metrics`` (:func:`read_metrics`, None when failed) and the fields
        :func:`senerf.bench.results.result_lines` copies: ``run_seconds``, ``peak_memory_mib``, ``hostname``, ...
    """
    runs_dir = Path(cfg.runs_dir)
    run_dir, log_path, report_path = (runs_dir / f"{spec.dirname()}{ext}" for ext in ("", ".log", ".maxrss"))
    runs_dir.mkdir(parents=True, exist_ok=True)
    report_path.unlink(missing_ok=True)
    shutil.rmtree(run_dir, ignore_errors=True)
    argv = [*(cfg.fit_command or default_fit_command()), *spec.fit_args(run_dir)]
    env = dict(os.environ)
    if cfg.threads is not None:
        env.update({name: str(cfg.threads) for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
    start = time.perf_counter()
    with open(log_path, "wb") as log:   # the wrapper leads its own process group: a timeout kills the fit too
        proc = subprocess.Popen([sys.executable, "-S", "-c", _WRAPPER, str(report_path), *argv], stdout=log,
                                stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            returncode = proc.wait(timeout=cfg.timeout_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            returncode = None
    run_seconds, peak_memory_mib = round(time.perf_counter() - start, 3), None
    with contextlib.suppress(OSError, ValueError):   # no report: the wrapper could not start PROG, or was killed
        maxrss, returncode = (int(v) for v in report_path.read_text().split())
        peak_memory_mib = round(maxrss / 1024.0, 1)
    log_tail = "\n".join(log_path.read_text(errors="replace").splitlines()[-20:])[-4000:]
    outcome = {"returncode": returncode, "run_seconds": run_seconds,
               "peak_memory_mib": peak_memory_mib, "hostname": platform.node(), "fit_command": argv,
               "run_dir": str(run_dir), "log_tail": log_tail, "metrics": None, "error": None}
    if returncode is None:
        outcome["error"] = f"timed out after {cfg.timeout_s} s"
    elif returncode != 0:
        outcome["error"] = f"senerf-fit exited with status {returncode}" + (
            f" (signal {-returncode})" if returncode < 0 else "")
    else:
        try:
            outcome["metrics"] = read_metrics(run_dir / "metrics.json", spec)
        except ValueError as exc:
            outcome["error"] = str(exc)
    outcome["status"] = "ok" if outcome["error"] is None else "failed"
    return outcome


def read_metrics(path: str | Path, spec: RunSpec) -> dict:
    """A fit's ``metrics.json`` (DESIGN.md contract), checked to describe ``spec``'s run, so that a number measured
    under another protocol is never filed under this one: its ``iterations`` rows are exactly 0..K, each with finite
    ``psnr``, ``ssim`` and ``seconds >= 0``; ``resolution`` is the protocol's ``[H, W]``; ``train_views`` are the
    protocol's number of views, and its views where it fixes them (Extreme, InfoNeRF 4).

    Raises:
        ValueError: naming the file and the first problem.
    """
    proto = parse_protocol(spec.protocol)
    try:
        data = json.loads(Path(path).read_text())
        found = [row["iteration"] for row in data["iterations"]]
        views, size = list(data["train_views"]), list(data["resolution"])
        bad = next((f"iteration {row['iteration']}: {name}: {row.get(name)!r} is not a measure"
                    for row in data["iterations"] for name in ("psnr", "ssim", "seconds")
                    if not is_number(row.get(name)) or (name == "seconds" and row[name] < 0)), None)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a metrics.json ({type(exc).__name__}: {exc})") from None
    fixed = proto.views(spec.scene)
    checks = [(found == list(range(spec.iterations + 1)), f"iterations: expected 0..{spec.iterations}, found {found}"),
              (size == list(proto.size), f"resolution: {size} is not {list(proto.size)} of {spec.protocol}"),
              (len(views) == proto.n_views and (fixed is None or sorted(views) == sorted(fixed)),
               f"train_views: {views} are not the {proto.n_views} views of {spec.protocol}"
               + ("" if fixed is None else f" {list(fixed)}"))]
    bad = bad or next((problem for ok, problem in checks if not ok), None)
    if bad is not None:
        raise ValueError(f"{path}: {bad}")
    return data


class RayExecutor:
    """Runs tasks on Ray.

    Args:
        address: cluster address (``"auto"``, ``"ray://host:10001"``), or ``None`` to start a private local
            Ray instance (tests) with ``num_cpus`` CPUs and no dashboard.
        num_cpus: CPUs of the private local instance (ignored with an address).
        cpus_per_run: CPUs Ray reserves per run (limits concurrency per node).

    Ray re-runs a task once when its worker process dies (a fit crash is a "failed" outcome, not a worker death).
    """

    def __init__(self, address: str | None = None, num_cpus: int | None = None, cpus_per_run: float = 1.0):
        try:
            import ray
        except ImportError:
            raise ImportError("Ray is not installed: pip install 'senerf[cluster]' (ray>=2.9)") from None
        self._ray = ray
        self._started_here = not ray.is_initialized()
        if self._started_here and address is None:
            ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, configure_logging=False)
        elif self._started_here:
            ray.init(address=address, log_to_driver=False)
        self._options = {"num_cpus": cpus_per_run, "max_retries": 1}
        self._remote: dict[Callable, Any] = {}

    def submit(self, fn: Callable[..., Any], *args: Any) -> cf.Future:
        """Schedule ``fn(*args)`` as a Ray task; the future's result is ``fn``'s return value."""
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(fn).options(**self._options)
        return self._remote[fn].remote(*args).future()

    def shutdown(self) -> None:
        """Stop Ray when this executor started it (a cluster it joined keeps running)."""
        if self._started_here:
            self._ray.shutdown()


def make_executor(workers: int = 1, ray_address: str | None = None, cpus_per_run: float = 1.0):
    """A :class:`RayExecutor` on ``ray_address`` when given, else ``workers`` threads on this machine (each only
    starts a ``senerf-fit`` child and waits for it, so a crash or out-of-memory kill of one fit never touches the
    pool, where a ``ProcessPoolExecutor`` would mark itself broken and lose every queued run)."""
    if ray_address:
        return RayExecutor(address=ray_address, cpus_per_run=cpus_per_run)
    return cf.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="senerf-bench")


@dataclass(frozen=True)
class BenchOutcome:
    """Counts of one driver invocation: ``skipped`` (already finished), ``ok`` and ``failed`` runs."""

    skipped: int
    ok: int
    failed: int


def pending_specs(specs: list[RunSpec], results_path: str | Path) -> tuple[list[RunSpec], int]:
    """Specs still to run (no ``"ok"`` line in the results file; duplicates dropped), and how many were
    skipped as finished."""
    done = {r["run_key"] for r in load_results(results_path)[0] if r["status"] == "ok"}
    unique = {spec.key(): spec for spec in specs}
    todo = [spec for key, spec in unique.items() if key not in done]
    return todo, len(unique) - len(todo)


def dry_run_lines(specs: list[RunSpec], results_path: str | Path, runs_dir: str | Path) -> list[str]:
    """What ``--dry-run`` prints: a count line, then the ``senerf-fit`` command of every pending run."""
    todo, skipped = pending_specs(specs, results_path)
    return ([f"# {skipped + len(todo)} runs: {skipped} already finished, {len(todo)} to run"]
            + [shlex.join(["senerf-fit", *spec.fit_args(Path(runs_dir) / spec.dirname())]) for spec in todo])


#: Seconds of one ``senerf-fit`` process (wall clock, start-up and evaluation included, the machine to itself) at the
#: fast preset (600 steps x 1024 rays), per scene kind, used where the results file has no run to go by: (reference
#: pixels, teacher training, the teacher's other seconds, a student's training, its other seconds, its labelling per
#: training view: the pseudo views' renders, features and reliability).
#: - object: lego Extreme 100x100, benchmarks/results/lego-extreme3@100.jsonl (EPYC, 6 seeds, 200 test views):
#:   baseline 37.7 s, SE-NeRF K=1 88.8 s (51.1 s a student); training 15.9 s (teacher) and 24.0 s (a student),
#:   BENCHMARKS.md section 2 ("the fused Adam ..."); labelling 4 s a view ("whole fits phase by phase": 12.4 s over
#:   3 iterations of 3 views).
#: - forward_facing: fern 3 views 504x378, BENCHMARKS.md section 2 (Xeon-167, de22d79): 552 s of fitting, of it
#:   training 279 s (1024 of the teacher's and 2688 of the student's rays a step: 106 s and 173 s), labelling 247 s
#:   (82 s a view), evaluation 21 s (11 s each), + 8 s start-up.
#: - dtu: scan24 3 views 192x192, BENCHMARKS.md "Unbounded scenes" (Xeon-167, ea6330b): 39 + 101 s of fitting, + 6 s
#:   start-up; not broken down there: training taken as 33 s (teacher) and 50 s (student, 1.5x as lego's), labelling
#:   15 s a view.
_FAST_SECONDS = {"object": (100 * 100, 15.9, 21.8, 24.0, 15.1, 4.0),
                 "forward_facing": (504 * 378, 106.0, 19.0, 173.0, 11.0, 82.0),
                 "dtu": (192 * 192, 33.0, 12.0, 50.0, 6.0, 15.0)}


def _estimate_key(run: dict) -> tuple:
    """(scene, protocol, method, preset label with the schedule, K) of a results line or a RunSpec's ``vars``: a
    line without its ``schedule`` is taken to have trained its preset as defined now (an estimate only)."""
    preset = PRESETS.get(run["preset"])
    schedule = run.get("schedule") or (preset and f"{run.get('steps') or preset.steps}x{preset.batch_rays}")
    return run["scene"], run["protocol"], run["method"], preset_label({**run, "schedule": schedule}), run["iterations"]


def estimate_seconds(spec: RunSpec, measured: dict[tuple, list[float]] | None = None) -> tuple[float, str]:
    """Estimated wall-clock seconds of one run and where the figure comes from.

    ``"measured"``: the mean ``run_seconds`` of the finished runs with the same scene, protocol, method, preset label
    and K in ``measured`` (keyed as :func:`estimate_lines` builds it).  Else ``"default"``: :data:`_FAST_SECONDS`
    for the protocol's scene kind, the teacher plus K students; their training times the run's steps x rays
    over fast's; the whole times the square root of the pixels over the reference's (lego
    fast 100x100 -> 400x400 took 61 -> 235 s, 3.9x for 16x the pixels, BENCHMARKS.md section 2).
    """
    key = _estimate_key(vars(spec))
    if measured and measured.get(key):
        return sum(measured[key]) / len(measured[key]), "measured"
    proto = parse_protocol(spec.protocol)
    pixels, teacher, teacher_other, student, student_other, per_view = _FAST_SECONDS[proto.kind]
    preset, fast = PRESETS[spec.preset], PRESETS["fast"]
    factor = (spec.steps or preset.steps) * preset.batch_rays / (fast.steps * fast.batch_rays)
    seconds = (teacher + spec.iterations * student) * factor + teacher_other + spec.iterations * (
        student_other + per_view * proto.n_views)
    return seconds * math.sqrt(proto.size[0] * proto.size[1] / pixels), "default"


def estimate_lines(specs: list[RunSpec], results_path: str | Path, workers: int = 1) -> list[str]:
    """The time estimate printed before a suite starts: per (protocol, method, preset, K), the runs still to run x
    the seconds of one (:func:`estimate_seconds`, measured where the results file has that run's peers), then the
    total, divided by ``workers`` for the wall clock (concurrent fits share the machine: an upper bound on the
    speed-up)."""
    measured: dict[tuple, list[float]] = {}
    for r in final_ok_lines(load_results(results_path)[0]):
        if is_number(r.get("run_seconds")):
            key = _estimate_key(r)
            measured.setdefault(key, []).append(float(r["run_seconds"]))
    todo, skipped = pending_specs(specs, results_path)
    groups: dict[tuple, list[tuple[float, str]]] = {}
    for spec in todo:
        groups.setdefault((spec.protocol, spec.method, spec.preset, spec.iterations), []).append(
            estimate_seconds(spec, measured))
    out, total = [f"# estimate: {len(todo)} runs to run ({skipped} already finished)"], 0.0
    for (protocol, method, preset, k), est in groups.items():
        seconds = sum(s for s, _ in est)
        total += seconds
        sources = "/".join(sorted({src for _, src in est}))
        out.append(f"#   {protocol} {method} {preset} K={k}: {len(est)} runs x ~{seconds / len(est):.0f} s ({sources})"
                   f" = {_duration(seconds)}")
    out.append(f"# total ~{_duration(total)} of fitting" + (f", ~{_duration(total / workers)} with {workers} workers"
                                                             if workers > 1 else ""))
    return out


def _duration(seconds: float) -> str:
    """``"1 h 05 min"``, ``"12 min"`` or ``"40 s"``."""
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{minutes} min"


def run_benchmark(specs: list[RunSpec], executor, results_path: str | Path, cfg: RunnerConfig,
                  bench_command: list[str], commit: str | None = None, log: Callable[[str], None] | None = None,
                  run_fn: Callable[[RunSpec, RunnerConfig], dict] = execute_run) -> BenchOutcome:
    """Run every pending spec on ``executor`` and append the results (resumable).

    Args:
        specs: the grid (see :func:`senerf.bench.protocols.expand_specs`).
        executor: a ``concurrent.futures`` executor or a :class:`RayExecutor` (:func:`make_executor`).
        results_path: JSON-lines results file (created if absent).
        bench_command: the benchmark's own argv, recorded on every line.
        commit: code version to record (default: :func:`git_commit` of the senerf checkout).
        log: progress sink, one line per event (default: print, flushed, so a log file follows the runs).
        run_fn: what executes one run (default :func:`execute_run`; must be picklable for Ray).
    """
    commit = commit if commit is not None else git_commit()
    log = log or (lambda line: print(line, flush=True))
    todo, skipped = pending_specs(specs, results_path)
    log(f"{skipped + len(todo)} runs: {skipped} already finished, {len(todo)} to run")
    futures = {executor.submit(run_fn, spec, cfg): spec for spec in todo}
    ok = failed = 0
    for fut in cf.as_completed(futures):
        spec = futures[fut]
        try:
            outcome = fut.result()
        except Exception as exc:  # noqa: BLE001 - any worker-side loss costs only this run
            outcome = {"status": "failed", "error": f"worker lost: {type(exc).__name__}: "
                                                    f"{' '.join(str(exc).split())[:300]}"}
        append_lines(results_path, result_lines(spec, outcome, commit, bench_command))
        done = f"[{ok + failed + 1}/{len(todo)}]"
        if outcome["status"] == "ok":
            ok += 1
            mib = outcome["peak_memory_mib"]
            log(f"{done} ok      {spec.key()}  PSNR {outcome['metrics']['iterations'][-1]['psnr']:.2f}  "
                f"{outcome['run_seconds']:.0f} s  " + ("memory not measured" if mib is None else f"{mib:.0f} MiB"))
        else:
            failed += 1
            log(f"{done} FAILED  {spec.key()}  {outcome['error']}")
    return BenchOutcome(skipped, ok, failed)


def git_commit(repo: str | Path | None = None) -> str:
    """The full commit hash of ``repo`` (default: the senerf checkout), ``-dirty`` appended when tracked files
    differ from it (``git describe --always --dirty --abbrev=40``); ``"unknown"`` without git or a repository."""
    repo = Path(repo) if repo is not None else Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=40"], cwd=repo,
                             capture_output=True, text=True, timeout=30, check=True)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() or "unknown"
