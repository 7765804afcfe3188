"""The results file: JSON lines, appended once per run, read back tolerant of a torn last line.

Every finished run appends all its lines in one locked ``write`` followed by ``flush`` + ``fsync``; only the
driver process writes (workers return their outcome), and an advisory ``fcntl`` lock also keeps two drivers
sharing one file from interleaving.  A run is "finished" when the file holds an ``"ok"`` line with its key;
failed runs leave one ``"failed"`` line and are retried by the next invocation.

Line schema (``schema`` = 1; a reader refuses a line of a schema it does not know, see :data:`READABLE_SCHEMAS`),
one line per self-training iteration of an ok run:

==================  ===========================================================================
``run_key``         :meth:`RunSpec.key`; ``attempt``: random hex id shared by one run's lines
``status``          ``"ok"`` or ``"failed"``; ``timestamp``: UTC ISO 8601 when written
``scene``           scene name; ``protocol`` (``"synthetic-extreme3@100"``); ``resolution`` [H, W]
``views``           training-view indices (from metrics.json); ``n_views``
``method``          method name; ``preset``; ``seed``; ``iterations`` (K requested)
``iteration``       0 = teacher/baseline, 1.. = students (None on failed lines)
``psnr`` ``ssim``   floats (test-set means, dB and [-1, 1])
``lpips`` ``avg``   float, or ``"unavailable"`` (no LPIPS weights); ``reliable_fraction``: float or None
``seconds``         this iteration's seconds; ``seconds_cumulative``: sum over iterations 0..this one
``run_seconds``     wall clock of the whole ``senerf-fit`` process (start-up and I/O included)
``peak_memory_mib`` max RSS of the ``senerf-fit`` process, MiB
``per_view``        {"psnr": [...], "ssim": [...]} per test view; ``test_views`` their indices
``commit``          ``git describe --dirty`` of the driver's checkout; ``machine``: see machine_info
``fit_command``     argv of the fit; ``bench_command``: argv of the benchmark invocation
``error``           failed lines only: one-line reason, plus ``returncode`` and ``log_tail``
==================  ===========================================================================
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import math
import os
import uuid
from pathlib import Path

from ..errors import InputError
from .specs import RunSpec

__all__ = ["SCHEMA_VERSION", "READABLE_SCHEMAS", "REQUIRED_OK_FIELDS", "result_lines", "validate_line",
           "impossible_value", "append_lines", "load_results", "finished_keys", "latest_ok_lines", "final_ok_lines"]

SCHEMA_VERSION = 1
#: ``schema`` numbers this version reads (a line without one is read as schema 1); a newer one is refused.
READABLE_SCHEMAS = (1,)

#: field -> accepted types on an ``"ok"`` line.
REQUIRED_OK_FIELDS: dict[str, tuple[type, ...]] = {
    "schema": (int,), "run_key": (str,), "attempt": (str,), "status": (str,), "timestamp": (str,),
    "scene": (str,), "protocol": (str,), "resolution": (list, type(None)), "views": (list, type(None)),
    "n_views": (int, type(None)), "method": (str,), "preset": (str,), "seed": (int,), "iterations": (int,),
    "iteration": (int,), "psnr": (float, int), "ssim": (float, int), "lpips": (float, int, str),
    "avg": (float, int, str), "seconds": (float, int), "seconds_cumulative": (float, int),
    "run_seconds": (float, int), "peak_memory_mib": (float, int), "commit": (str,), "machine": (dict,),
    "fit_command": (list,), "bench_command": (list,),
}


def result_lines(spec: RunSpec, outcome: dict, commit: str, bench_command: list[str]) -> list[dict]:
    """Results-file lines for one run outcome (from :func:`senerf.bench.execute.execute_run`).

    An ok outcome gives one line per iteration in ``metrics.json``; a failed one gives a single line.
    """
    common = {
        "schema": SCHEMA_VERSION, "run_key": spec.key(), "attempt": uuid.uuid4().hex,
        "status": outcome["status"], "timestamp": _dt.datetime.now(_dt.timezone.utc).isoformat(),
        "scene": spec.scene, "protocol": spec.protocol, "method": spec.method, "preset": spec.preset,
        "seed": spec.seed, "iterations": spec.iterations, "device": spec.device, "steps": spec.steps,
        "run_seconds": outcome.get("run_seconds"), "peak_memory_mib": outcome.get("peak_memory_mib"),
        "commit": commit, "machine": outcome.get("machine") or {},
        "fit_command": list(outcome.get("fit_command") or []), "bench_command": list(bench_command),
        "run_dir": outcome.get("run_dir"),
    }
    if outcome["status"] != "ok":
        views = spec.views()
        return [{**common, "iteration": None, "views": None if views is None else list(views),
                 "error": outcome.get("error") or "unknown error", "returncode": outcome.get("returncode"),
                 "log_tail": outcome.get("log_tail", "")}]
    metrics = outcome["metrics"]
    views = metrics.get("train_views")
    common.update(resolution=metrics.get("resolution"), views=views,
                  n_views=len(views) if isinstance(views, list) else None,
                  test_views=metrics.get("test_views"), senerf_version=metrics.get("senerf_version"))
    lines, cumulative = [], 0.0
    for it in sorted(metrics["iterations"], key=lambda d: d["iteration"]):
        cumulative += float(it["seconds"])
        lines.append({**common, "iteration": it["iteration"], "psnr": float(it["psnr"]),
                      "ssim": float(it["ssim"]), "lpips": _metric(it.get("lpips")),
                      "avg": _metric(it.get("avg")), "reliable_fraction": it.get("reliable_fraction"),
                      "seconds": float(it["seconds"]), "seconds_cumulative": round(cumulative, 3),
                      "per_view": it.get("per_view")})
    return lines


def _metric(value) -> float | str:
    """A float, or ``"unavailable"`` for anything else (missing, null, the string itself)."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else "unavailable"


def validate_line(line: dict) -> None:
    """Raise ``ValueError`` naming the first field of an ``"ok"`` line that is missing, mistyped or impossible
    (:func:`_mistyped` and :func:`impossible_value`, which :func:`load_results` applies to the fields a line has)."""
    if line.get("status") != "ok":
        for name in ("run_key", "status", "error"):
            if not isinstance(line.get(name), str):
                raise ValueError(f"failed line: {name}: missing or not a string")
        return
    for name in REQUIRED_OK_FIELDS:
        if name not in line:
            raise ValueError(f"{name}: missing")
    problem = _mistyped(line)
    if problem is None:
        found = impossible_value(line)
        problem = None if found is None else f"{found[0]}: {found[1]}"
    if problem is not None:
        raise ValueError(problem)


#: Fields an "ok" line may hold as null: what the driver could not measure about a finished run.
_MAY_BE_NULL = frozenset({"run_seconds", "peak_memory_mib"})


def _int_list(value) -> bool:
    return isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)


def _mistyped(line: dict) -> str | None:
    """The first field of ``line`` present with a value of the wrong type (a non-finite PSNR or SSIM, a list of
    indices with a non-integer), or None; a field that is absent is not checked here."""
    if line.get("status") != "ok":
        return None if isinstance(line.get("run_key"), str) else "run_key: not a string"
    for name, types in REQUIRED_OK_FIELDS.items():
        if name in _MAY_BE_NULL and line.get(name, 0) is None:   # not measured (the maxrss file unreadable)
            continue
        if name in line and (isinstance(line[name], bool) or not isinstance(line[name], types)):
            return f"{name}: {type(line[name]).__name__} is not {'/'.join(t.__name__ for t in types)}"
    for name in ("lpips", "avg"):
        if isinstance(line.get(name), str) and line[name] != "unavailable":
            return f"{name}: string must be 'unavailable', got {line[name]!r}"
    for name in ("psnr", "ssim"):
        if name in line and not math.isfinite(line[name]):
            return f"{name}: {line[name]!r} is not a finite number"
    for name in ("resolution", "views", "test_views"):
        if line.get(name) is not None and not _int_list(line[name]):
            return f"{name}: expected a list of integers"
    return None


#: Non-negative quantities of an "ok" line (seconds, MiB): a negative, NaN or infinite one was not measured.
_AMOUNTS = ("seconds", "seconds_cumulative", "run_seconds", "peak_memory_mib")
#: Largest finite PSNR of images in [0, 1] (renders are clipped), dB: 10 log10(1 / MSE) with the MSE at the
#: smallest positive float64, rounded up.  An exact render's PSNR is infinite, not large (:func:`_mistyped`).
_PSNR_MAX_DB = math.ceil(-10.0 * math.log10(math.ulp(0.0)))
#: How far beyond [-1, 1] a mean SSIM may round.
_SSIM_SLACK = 1e-9


def _unreadable_schema(line: dict) -> str | None:
    """What is wrong with ``line``'s ``schema`` number when this version cannot read it, else None (a line without
    a number, or with a string, is left to :func:`_mistyped`)."""
    schema = line.get("schema")
    if not isinstance(schema, int) or isinstance(schema, bool) or schema in READABLE_SCHEMAS:
        return None
    known = ", ".join(str(v) for v in READABLE_SCHEMAS)
    if schema > max(READABLE_SCHEMAS):
        return f"{schema} is newer than this version of senerf reads (schema {known}); upgrade senerf to read it"
    return f"{schema} is not a schema this version of senerf reads (schema {known})"


def impossible_value(line: dict) -> tuple[str, str] | None:
    """``(field, problem)`` of the first value of a well-typed ``"ok"`` line (:func:`_mistyped` is None) that no
    run can have: a negative ``iteration`` or ``iterations``, an ``iteration`` beyond the run's ``iterations``, a
    negative or non-finite time or peak memory, a PSNR outside [0, 3234] dB or an SSIM outside [-1, 1]; None
    when there is none, or for a failed line."""
    if line.get("status") != "ok":
        return None
    for name, what in (("iterations", "the run's self-training rounds, 0 for a baseline"),
                       ("iteration", "0 is the teacher or baseline, 1.. the students")):
        if isinstance(line.get(name), int) and line[name] < 0:
            return name, f"{line[name]} is negative ({what})"
    if isinstance(line.get("iterations"), int) and isinstance(line.get("iteration"), int) \
            and line["iteration"] > line["iterations"]:
        return "iteration", f"{line['iteration']} is beyond the run's iterations ({line['iterations']})"
    for name in _AMOUNTS:
        value = line.get(name)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and not 0 <= value < math.inf:
            return name, f"{value!r} is not a finite number >= 0"
    if isinstance(line.get("psnr"), (int, float)) and not 0 <= line["psnr"] <= _PSNR_MAX_DB:
        return "psnr", (f"{line['psnr']!r} dB is not the PSNR of images in [0, 1] (a finite one is 0 to "
                        f"{_PSNR_MAX_DB} dB)")
    if isinstance(line.get("ssim"), (int, float)) and not -1 - _SSIM_SLACK <= line["ssim"] <= 1 + _SSIM_SLACK:
        return "ssim", f"{line['ssim']!r} is outside [-1, 1]"
    return None


def append_lines(path: str | Path, lines: list[dict]) -> None:
    """Append ``lines`` as JSON lines in one locked write, then flush and fsync."""
    if not lines:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = "".join(json.dumps(line, sort_keys=True, allow_nan=True) + "\n" for line in lines)
    with open(path, "a", encoding="utf-8") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            if f.tell() > 0 and not _ends_with_newline(path):
                payload = "\n" + payload          # a torn last line stays isolated
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as f:
        f.seek(-1, os.SEEK_END)
        return f.read(1) == b"\n"


#: Fields every finished ("ok") line carries: the summaries, plots and reports index by them.
_OK_FIELDS = frozenset({"scene", "protocol", "method", "preset", "seed", "iteration", "psnr"})


def load_results(path: str | Path, skipped: list | None = None) -> tuple[list[dict], int]:
    """All parseable lines of a results file, and the number of lines skipped as unparseable (not UTF-8,
    not JSON, not a results line, an "ok" line without the fields every finished line carries, or one with a
    field of the wrong type: a string seed, a non-finite PSNR; see :func:`validate_line`).

    A missing file is an empty result (a fresh benchmark).  ``skipped``, when given, receives
    ``(line number, why)`` for each skipped line.

    Raises:
        InputError: a line of a schema this version does not read (:data:`READABLE_SCHEMAS`), or an "ok" line
            with a value no run can have (a negative iteration, a negative or non-finite time, a PSNR of 1e308
            dB; see :func:`impossible_value`); one line naming the file, the field, the line number and the run.
    """
    name, path = path, Path(path)   # errors name the file as given
    if not path.exists():
        return [], 0
    records, bad = [], 0
    with open(path, "rb") as f:
        for number, raw in enumerate(f, start=1):
            raw = raw.strip()
            if not raw:
                continue
            rec, why = None, None
            try:
                rec = json.loads(raw.decode("utf-8"))
            except UnicodeDecodeError:
                why = "not UTF-8"
            except (ValueError, RecursionError):   # bad JSON, an integer of 5000 digits, nesting 100000 deep
                why = "not JSON"
            unreadable = _unreadable_schema(rec) if isinstance(rec, dict) else None
            if unreadable is not None:   # before the shape checks: a newer schema may have renamed any field
                raise _line_error(name, number, rec, "schema", unreadable)
            # mistyped lines would crash the tables, or count a run done on a made-up figure
            why = why or _unparseable(rec)
            if why is not None:
                bad += 1
                if skipped is not None:
                    skipped.append((number, why))
                continue
            impossible = impossible_value(rec)
            if impossible is not None:   # a made-up figure: refused, not skipped, so no table silently lacks it
                raise _line_error(name, number, rec, *impossible)
            records.append(rec)
    return records, bad


def _unparseable(rec) -> str | None:
    """Why a decoded line is no results line :func:`load_results` can use, or None."""
    if not isinstance(rec, dict) or "run_key" not in rec:
        return "not a results line (no run_key)"
    if rec.get("status") == "ok" and not _OK_FIELDS <= rec.keys():
        return f"an ok line without {sorted(_OK_FIELDS - rec.keys())[0]}"
    return _mistyped(rec)


def _line_error(path: str | Path, number: int, line: dict, field: str, problem: str) -> InputError:
    """``"<path>: <field>: <problem> (line <number>, run <run_key>)"`` (no run where the line names none)."""
    run = f", run {line['run_key']}" if isinstance(line.get("run_key"), str) else ""
    return InputError(f"{problem} (line {number}{run})", file=path, field=field)


def finished_keys(records: list[dict]) -> set[str]:
    """Keys of runs with at least one ``"ok"`` line."""
    return {r["run_key"] for r in records if r.get("status") == "ok"}


def latest_ok_lines(records: list[dict]) -> list[dict]:
    """The ``"ok"`` lines of the last successful attempt of each run key (file order decides "last").

    Guards summaries against a run recorded twice (two drivers, or a resumed file that was concatenated).
    """
    last_attempt: dict[str, str] = {}
    for r in records:
        if r.get("status") == "ok":
            last_attempt[r["run_key"]] = r.get("attempt", "")
    return [r for r in records if r.get("status") == "ok" and r.get("attempt", "") == last_attempt[r["run_key"]]]


def final_ok_lines(records: list[dict]) -> list[dict]:
    """:func:`latest_ok_lines` at each run's last iteration (``iteration == iterations``): the result a user
    gets (a baseline's iteration 0; a self-training run's iteration K, not its teacher)."""
    return [r for r in latest_ok_lines(records) if r["iteration"] == int(r.get("iterations", 0))]
