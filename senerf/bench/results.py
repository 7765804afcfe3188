"""The results file: JSON lines, appended once per run by the driver, read back skipping any line that is not a
results line.  A run is finished when the file holds an ``"ok"`` line with its key; a failed run leaves one
``"failed"`` line and is retried by the next invocation.  One line per self-training iteration of an ok run:

==================  ===========================================================================
``run_key``         :meth:`RunSpec.key`; ``attempt``: random hex id shared by one run's lines
``status``          ``"ok"`` or ``"failed"``; ``timestamp``: UTC ISO 8601 when written
``scene``           scene name; ``protocol`` (``"synthetic-extreme3@100"``, a known one); ``resolution`` [H, W]
``views``           training-view indices (from metrics.json); ``test_views``: the test views
``method``          method name; ``preset``; ``seed``; ``iterations`` (K requested); ``steps``; ``device``
``schedule``        what each field trained, ``"600x1024"`` (steps x rays a step, from metrics.json)
``iteration``       0 = teacher/baseline, 1.. = students (None on failed lines)
``psnr`` ``ssim``   floats (test-set means, dB and [-1, 1])
``lpips`` ``avg``   float, or ``"unavailable"`` (no LPIPS weights); ``reliable_fraction``: float or None
``seconds``         this iteration's seconds; ``seconds_cumulative``: sum over iterations 0..this one
``phases``          this iteration's seconds per phase (metrics.json's ``phases``; None from older fits)
``run_seconds``     wall clock of the whole ``senerf-fit`` process (start-up and I/O included)
``peak_memory_mib`` max RSS of the ``senerf-fit`` process, MiB (None: not measured)
``per_view``        {"psnr": [...], "ssim": [...]} per test view
``commit``          ``git describe --dirty`` of the driver's checkout; ``hostname`` of the machine that ran it
``host``            the fit's record of its device, CPU, threads and builds (metrics.json)
``fit_command``     argv of the fit; ``bench_command``: argv of the benchmark invocation
``error``           failed lines only: one-line reason, plus ``returncode`` and ``log_tail``
==================  ===========================================================================
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import uuid
from pathlib import Path

from senerf.errors import InputError, is_number

from .protocols import RunSpec, parse_protocol

__all__ = ["result_lines", "append_lines", "load_results", "line_problem", "latest_ok_lines", "final_ok_lines"]

#: What every ok line carries, as the commands read it: field -> its type (``float``: a finite number).
_OK_FIELDS = {"scene": str, "protocol": str, "method": str, "preset": str, "seed": int, "iterations": int,
              "iteration": int, "psnr": float, "ssim": float, "seconds_cumulative": float, "commit": str,
              "timestamp": str, "bench_command": list}


def result_lines(spec: RunSpec, outcome: dict, commit: str, bench_command: list[str]) -> list[dict]:
    """Results-file lines for one run outcome (from :func:`senerf.bench.runner.execute_run`; module docstring)."""
    common = {
        "run_key": spec.key(), "attempt": uuid.uuid4().hex, "status": outcome["status"],
        "timestamp": _dt.datetime.now(_dt.timezone.utc).isoformat(), "scene": spec.scene, "protocol": spec.protocol,
        "method": spec.method, "preset": spec.preset, "seed": spec.seed, "iterations": spec.iterations,
        "device": spec.device, "steps": spec.steps, "run_seconds": outcome.get("run_seconds"),
        "peak_memory_mib": outcome.get("peak_memory_mib"), "commit": commit, "hostname": outcome.get("hostname"),
        "fit_command": list(outcome.get("fit_command") or []), "bench_command": list(bench_command),
        "run_dir": outcome.get("run_dir"),
    }
    if outcome["status"] != "ok":
        return [{**common, "iteration": None, "error": outcome["error"], "returncode": outcome.get("returncode"),
                 "log_tail": outcome.get("log_tail", "")}]
    metrics = outcome["metrics"]
    train = metrics["config"]["train"]
    common.update(resolution=metrics["resolution"], views=metrics["train_views"], test_views=metrics.get("test_views"),
                  senerf_version=metrics.get("senerf_version"), schedule=f"{train['steps']}x{train['batch_rays']}")
    lines, cumulative = [], 0.0
    for it in sorted(metrics["iterations"], key=lambda d: d["iteration"]):
        cumulative += float(it["seconds"])
        lines.append({**common, "iteration": it["iteration"], "psnr": float(it["psnr"]), "ssim": float(it["ssim"]),
                      **{m: float(it[m]) if is_number(it.get(m)) else "unavailable" for m in ("lpips", "avg")},
                      "reliable_fraction": it.get("reliable_fraction"), "seconds": float(it["seconds"]),
                      "seconds_cumulative": round(cumulative, 3), "phases": it.get("phases"),
                      "per_view": it.get("per_view"),
                      "host": it.get("host")})
    return lines


def append_lines(path: str | Path, lines: list[dict]) -> None:
    """Append ``lines`` as JSON lines in one write under an advisory ``fcntl`` lock (two drivers sharing a file never
    interleave), then flush and fsync; a line torn by an earlier killed writer is ended first, so it stays one
    unreadable line."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = "".join(json.dumps(line, sort_keys=True) + "\n" for line in lines)
    with open(path, "a+b") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        try:
            if f.seek(0, os.SEEK_END) > 0:
                f.seek(-1, os.SEEK_END)
                payload = payload if f.read(1) == b"\n" else "\n" + payload
            f.write(payload.encode("utf-8"))
            f.flush()
            os.fsync(f.fileno())
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def line_problem(line) -> str | None:
    """Why a decoded JSON value is not a results line the commands can read, or None when it is one: a JSON
    object with a string ``run_key`` and ``status`` ``"ok"`` or ``"failed"``; an ok line also carries every
    field the tables read, each of its type (a finite number for PSNR, SSIM and seconds), and a known protocol."""
    if not isinstance(line, dict) or not isinstance(line.get("run_key"), str) or \
            line.get("status") not in ("ok", "failed"):
        return "not a results line"
    if line["status"] == "failed":
        return None
    for name, kind in _OK_FIELDS.items():
        value = line.get(name)
        if not (is_number(value) if kind is float else isinstance(value, kind) and not isinstance(value, bool)):
            return f"{name}: missing or not {'a finite number' if kind is float else 'of type ' + kind.__name__}"
    try:
        parse_protocol(line["protocol"])
    except InputError as exc:
        return str(exc)
    return None


def load_results(path: str | Path) -> tuple[list[dict], list[tuple[int, str]]]:
    """The results lines of a file, and ``(line number, why)`` for each non-blank line skipped
    (:func:`line_problem`, or not UTF-8 JSON).  A missing file is an empty result (a fresh benchmark)."""
    if not Path(path).exists():
        return [], []
    records, skipped = [], []
    with open(path, "rb") as f:
        for number, raw in enumerate(f, start=1):
            if not raw.strip():
                continue
            try:
                line = json.loads(raw)
            except (ValueError, RecursionError):   # not UTF-8, not JSON, nested 100000 deep
                skipped.append((number, "not JSON"))
                continue
            problem = line_problem(line)
            if problem is None:
                records.append(line)
            else:
                skipped.append((number, problem))
    return records, skipped


def latest_ok_lines(records: list[dict]) -> list[dict]:
    """The ``"ok"`` lines of the last successful attempt of each run key (file order decides "last"), so a run
    recorded twice (two drivers, or concatenated files) counts once."""
    last_attempt = {r["run_key"]: r.get("attempt") for r in records if r["status"] == "ok"}
    return [r for r in records if r["status"] == "ok" and r.get("attempt") == last_attempt[r["run_key"]]]


def final_ok_lines(records: list[dict]) -> list[dict]:
    """:func:`latest_ok_lines` at each run's last iteration (``iteration == iterations``): the result a user
    gets (a baseline's iteration 0; a self-training run's iteration K, not its teacher)."""
    return [r for r in latest_ok_lines(records) if r["iteration"] == r["iterations"]]
