"""The benchmark driver: skip finished runs, submit the rest, write each outcome as it arrives.

One code path for every executor: ``executor.submit(execute_run, spec, cfg)`` returns a future; the driver
waits with ``concurrent.futures.as_completed`` and appends each run's lines to the results file the moment
its future resolves.  An exception from a future (a lost Ray worker, a bug in the worker) becomes a
``"failed"`` line for that run only; the other runs go on.
"""

from __future__ import annotations

import concurrent.futures as cf
from dataclasses import dataclass
import shlex
from pathlib import Path
from typing import Callable

from .execute import RunnerConfig, execute_run
from .executors import Executor
from .machine import git_commit
from .results import append_lines, finished_keys, impossible_value, load_results, result_lines
from .specs import RunSpec

__all__ = ["BenchOutcome", "pending_specs", "dry_run_lines", "run_benchmark"]


@dataclass(frozen=True)
class BenchOutcome:
    """Counts of one driver invocation: ``skipped`` (already finished), ``ok`` and ``failed`` runs."""

    skipped: int
    ok: int
    failed: int


def dry_run_lines(specs: list[RunSpec], results_path: str | Path, runs_dir: str | Path) -> list[str]:
    """What ``--dry-run`` prints: a count line, then the ``senerf-fit`` command of every pending run."""
    todo, skipped = pending_specs(specs, results_path)
    return ([f"# {skipped + len(todo)} runs: {skipped} already finished, {len(todo)} to run"]   # duplicates once
            + [shlex.join(["senerf-fit", *spec.fit_args(Path(runs_dir) / spec.dirname())]) for spec in todo])


def pending_specs(specs: list[RunSpec], results_path: str | Path) -> tuple[list[RunSpec], int]:
    """Specs still to run (no ``"ok"`` line in the results file; duplicates dropped), and how many were
    skipped as finished."""
    records, _ = load_results(results_path)
    done = finished_keys(records)
    todo, seen, skipped = [], set(), 0
    for spec in specs:
        key = spec.key()
        if key in seen:
            continue
        seen.add(key)
        if key in done:
            skipped += 1
        else:
            todo.append(spec)
    return todo, skipped


def run_benchmark(specs: list[RunSpec], executor: Executor, results_path: str | Path, cfg: RunnerConfig,
                  bench_command: list[str], commit: str | None = None,
                  log: Callable[[str], None] = print,
                  run_fn: Callable[[RunSpec, RunnerConfig], dict] = execute_run) -> BenchOutcome:
    """Run every pending spec on ``executor`` and append the results (resumable).

    Args:
        specs: the grid (see :func:`senerf.bench.specs.expand_specs`).
        executor: a :class:`senerf.bench.executors.Executor`.
        results_path: JSON-lines results file (created if absent).
        cfg: how each run executes.
        bench_command: the benchmark's own argv, recorded on every line.
        commit: code version to record (default: :func:`git_commit` of the senerf checkout).
        log: progress sink, one line per event.
        run_fn: what executes one run (default :func:`execute_run`; must be picklable for Ray).
    """
    commit = commit if commit is not None else git_commit()
    todo, skipped = pending_specs(specs, results_path)
    log(f"{skipped + len(todo)} runs: {skipped} already finished, {len(todo)} to run")   # duplicates counted once
    futures = {executor.submit(run_fn, spec, cfg): spec for spec in todo}
    ok = failed = 0
    for fut in cf.as_completed(futures):
        spec = futures[fut]
        outcome, lines = _lines_of(_outcome_of(fut, spec), spec, commit, bench_command)
        append_lines(results_path, lines)
        if outcome["status"] == "ok":
            ok += 1
            final = outcome["metrics"]["iterations"][-1]
            memory = outcome.get("peak_memory_mib")   # None: not measured (the wrapper's record unreadable)
            log(f"ok      {spec.key()}  PSNR {final['psnr']:.2f}  {outcome['run_seconds']:.0f} s  "
                + ("memory not measured" if memory is None else f"{memory:.0f} MiB"))
        else:
            failed += 1
            log(f"FAILED  {spec.key()}  {outcome['error']}")
    return BenchOutcome(skipped, ok, failed)


def _lines_of(outcome: dict, spec: RunSpec, commit: str, bench_command: list[str]) -> tuple[dict, list[dict]]:
    """``(outcome, its results lines)``; an ok outcome whose lines would hold a value no run can have (a fit
    command's negative seconds, say: :func:`impossible_value`) becomes a failed one, retried by the next
    invocation, since every later command would refuse the results file."""
    lines = result_lines(spec, outcome, commit, bench_command)
    found = next(((line, problem) for line in lines if (problem := impossible_value(line)) is not None), None)
    if outcome["status"] != "ok" or found is None:
        return outcome, lines
    line, (field, problem) = found
    source = "the run's" if field in _MEASURED_BY_DRIVER else f"metrics.json: iteration {line['iteration']}:"
    outcome = {**outcome, "status": "failed", "error": f"{source} {field}: {problem}"}
    return outcome, result_lines(spec, outcome, commit, bench_command)


#: Fields of a results line that the driver measures (the rest come from the fit's metrics.json).
_MEASURED_BY_DRIVER = ("run_seconds", "peak_memory_mib")


def _outcome_of(fut: cf.Future, spec: RunSpec) -> dict:
    """The future's outcome, or a failed outcome carrying the exception (e.g. a lost worker)."""
    try:
        return fut.result()
    except Exception as exc:  # noqa: BLE001 - any worker-side loss costs only this run
        return {"key": spec.key(), "status": "failed", "returncode": None,
                "error": f"worker lost: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}",
                "log_tail": "", "run_seconds": None, "peak_memory_mib": None, "machine": {},
                "fit_command": [], "run_dir": None, "metrics": None}
