"""The run folder ``senerf-fit`` writes, read and guarded in one place (no torch); its layout and files are in
DESIGN.md ("The run folder").  senerf is 0.x: a run folder of another format is refused, not migrated.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable

from senerf import __version__
from senerf.atomic import atomic_write_text, output_folder
from senerf.data import changed_files
from senerf.errors import InputError

__all__ = ["RUN_FORMAT", "RUN_FILE", "METRICS_FILE", "read_run", "read_metrics", "finished_iterations",
           "checkpoint_path", "prepare_run_folder", "settings_differences"]

#: The run folder format this version writes and reads (``run.json``'s ``senerf_run``).
RUN_FORMAT = 2
RUN_FILE = "run.json"
METRICS_FILE = "metrics.json"
#: What senerf-fit writes into a run folder, and all that ``--overwrite`` removes.
_OUTPUT_NAMES = ("checkpoints", METRICS_FILE, "summary.png", "render", RUN_FILE)


def checkpoint_path(folder: str | Path, iteration: int) -> Path:
    """Iteration ``iteration``'s training checkpoint: ``folder/checkpoints/iter_K_train.pt``."""
    return Path(folder) / "checkpoints" / f"iter_{int(iteration)}_train.pt"


def _read_json(path: Path) -> object:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError("not found: is this a senerf-fit run folder?", file=path) from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"cannot be read as JSON ({exc})", file=path) from None


def read_run(folder: str | Path) -> dict:
    """``folder/run.json`` of a run of this version's format.

    Raises:
        InputError: no such file, not JSON, or a run folder of another format (an older senerf's).
    """
    path = Path(folder) / RUN_FILE
    run = _read_json(path)
    if not isinstance(run, dict) or "scene_dir" not in run:   # every senerf version wrote it
        raise InputError("was not written by senerf-fit", file=path)
    if run.get("senerf_run") != RUN_FORMAT:
        raise InputError(f"is a run folder of another senerf version (format {run.get('senerf_run')!r}, this "
                         f"version reads {RUN_FORMAT}); refit the scene", file=path)
    return run


def read_metrics(folder: str | Path) -> dict | None:
    """``folder/metrics.json``, or None when the run has not finished an iteration yet."""
    path = Path(folder) / METRICS_FILE
    if not path.exists():
        return None
    metrics = _read_json(path)
    if not isinstance(metrics, dict) or not isinstance(metrics.get("iterations"), list):
        raise InputError("is not a senerf metrics file (no 'iterations' list)", file=path)
    for k, row in enumerate(metrics["iterations"]):
        if not (isinstance(row, dict) and type(row.get("iteration")) is int and row["iteration"] == k):
            raise InputError(f"expected the row of iteration {k}", file=path, field=f"iterations[{k}]")
    return metrics


def finished_iterations(metrics: dict | None) -> list[int]:
    """The iterations ``metrics`` (a :func:`read_metrics` document, or None) has rows for: ``0 .. K``."""
    return [] if metrics is None else list(range(len(metrics["iterations"])))


def _flatten(record: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in record.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def settings_differences(stored: dict, current: dict) -> list[str]:
    """Where two nested settings records differ, one line per dotted setting name, sorted.

    Example:
        >>> settings_differences({"train": {"seed": 0}}, {"train": {"seed": 1}})
        ['train.seed: 0 in the folder, 1 now']
    """
    old, new = _flatten(stored), _flatten(current)
    missing = "absent"
    lines = []
    for name in sorted(set(old) | set(new)):
        if old.get(name, missing) != new.get(name, missing):
            said = [missing if name not in rec else json.dumps(rec[name], default=str) for rec in (old, new)]
            lines.append(f"{name}: {said[0]} in the folder, {said[1]} now")
    return lines


def prepare_run_folder(out: str | Path, run: dict, overwrite: bool, echo: Callable[[str], None] = print) -> bool:
    """Make ``out`` the folder of ``run`` (a ``run.json`` record): returns True when it already held this run
    (to be resumed), False for a new one, whose ``run.json`` is written here.

    A folder holding another run (other settings, or scene files whose bytes changed) is refused, naming the
    first difference, unless ``overwrite``; ``--overwrite`` removes only what senerf-fit writes there.  A
    non-empty folder that is not a run folder is refused even then.

    Raises:
        InputError: as above, or ``out`` cannot be a folder (``--out``).
    """
    out = output_folder(out, "--out")
    hint = "use --overwrite or another --out"
    if (out / RUN_FILE).exists():
        old = _read_json(out / RUN_FILE)
        if not (isinstance(old, dict) and "scene_dir" in old):   # every senerf version wrote it
            raise InputError(f"holds a {RUN_FILE} that senerf-fit did not write; choose another --out", file=out)
        if not overwrite:
            read_run(out)   # a folder of another format is refused here
        elif old.get("senerf_run") != RUN_FORMAT:
            old = {"settings": {}, "scene_files": {}}
        if old.get("settings") == run["settings"] and old.get("scene_files") == run["scene_files"]:
            return True
        if not overwrite:
            diffs = settings_differences(old["settings"], run["settings"])
            diffs = diffs or [f"scene files differ: {line}"
                              for line in changed_files(old["scene_files"], run["scene_files"])]
            more = f" and {len(diffs) - 1} more" if len(diffs) > 1 else ""
            raise InputError(f"holds a different run ({diffs[0]}{more}); {hint}", file=out)
        removed = [p for p in [out / n for n in _OUTPUT_NAMES] + sorted(out.glob("iter_*")) if p.exists()]
        for p in removed:
            shutil.rmtree(p) if p.is_dir() else p.unlink()
        echo(f"--overwrite: removed the earlier run's {', '.join(p.name for p in removed)} from {out}")
    elif out.exists() and any(out.iterdir()):
        raise InputError("exists and is not a senerf-fit run folder; choose another --out", file=out)
    atomic_write_text(out / RUN_FILE, json.dumps({"senerf_run": RUN_FORMAT, "senerf_version": __version__, **run},
                                                 indent=1, sort_keys=True))
    return False
