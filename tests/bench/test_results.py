"""Results lines: one locked append per run, reading that skips what is not a results line, last attempt wins."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from senerf.bench.results import append_lines, final_ok_lines, latest_ok_lines, line_problem, load_results, result_lines
from senerf.bench.protocols import RunSpec

SPEC = RunSpec("/data/lego", "lego", "synthetic-extreme3@100", "senerf", "fast", 1, 2)
REPO = Path(__file__).resolve().parents[2]


def _ok_outcome(n_iter=3, lpips="unavailable"):
    rows = [{"iteration": k, "psnr": 15.0 + k, "ssim": 0.6, "lpips": lpips, "avg": lpips, "reliable_fraction": None,
             "seconds": 2.0 + k, "per_view": {"psnr": [1.0, 2.0], "ssim": [0.5, 0.5]}, "host": {"threads": 2}}
            for k in range(n_iter)]
    metrics = {"senerf_version": "x", "train_views": [0, 1, 51], "test_views": [0, 1], "resolution": [100, 100],
               "iterations": rows, "config": {"train": {"steps": 600, "batch_rays": 1024}}}
    return {"status": "ok", "metrics": metrics, "run_seconds": 12.5, "peak_memory_mib": 300.0, "hostname": "h",
            "fit_command": ["senerf-fit", "a"], "run_dir": "/r"}


def test_an_ok_run_gives_one_readable_line_per_iteration():
    lines = result_lines(SPEC, _ok_outcome(), "abc-dirty", ["senerf-bench", "run"])
    assert [ln["iteration"] for ln in lines] == [0, 1, 2] and all(line_problem(ln) is None for ln in lines)
    assert [ln["seconds_cumulative"] for ln in lines] == [2.0, 5.0, 9.0]           # 2, 2 + 3, 2 + 3 + 4
    assert len({ln["attempt"] for ln in lines}) == 1 and json.loads(json.dumps(lines)) == lines
    assert lines[2]["psnr"] == 17.0 and lines[0]["lpips"] == "unavailable" and lines[0]["views"] == [0, 1, 51]
    assert lines[0]["commit"] == "abc-dirty" and lines[0]["bench_command"] == ["senerf-bench", "run"]
    assert lines[0]["host"] == {"threads": 2} and lines[0]["run_key"] == SPEC.key()
    assert lines[0]["schedule"] == "600x1024"   # what the fit trained, whatever the preset means later
    numeric = result_lines(SPEC, _ok_outcome(lpips=0.25), "c", [])
    assert numeric[0]["lpips"] == 0.25 and numeric[0]["avg"] == 0.25


def test_a_failed_run_gives_one_line_with_its_reason():
    (line,) = result_lines(SPEC, {"status": "failed", "error": "exited with status -9", "returncode": -9}, "c", [])
    assert line_problem(line) is None and line["iteration"] is None and line["error"] == "exited with status -9"
    assert latest_ok_lines([line]) == []


def test_append_and_load_skip_a_torn_line(tmp_path):
    path = tmp_path / "r.jsonl"
    assert load_results(path) == ([], [])
    first = result_lines(SPEC, _ok_outcome(), "c", [])
    append_lines(path, first)
    with open(path, "a") as f:
        f.write('{"run_key": "torn')           # a writer died mid-line: the next append starts a new line
    second = result_lines(RunSpec("/d", "lego", "synthetic-extreme3@100", "baseline", "fast", 0, 0),
                          _ok_outcome(n_iter=1), "c", [])
    append_lines(path, second)
    records, skipped = load_results(path)
    assert skipped == [(4, "not JSON")] and records == first + second


@pytest.mark.parametrize("change, problem", [
    ({"seed": "0"}, "seed: missing or not of type int"), ({"iteration": True}, "iteration: missing or not of type int"),
    ({"iteration": 1.5}, "iteration: missing or not of type int"), ({"scene": 5}, "scene: missing or not of type str"),
    ({"psnr": "abc"}, "psnr: missing or not a finite number"), ({"psnr": None}, "psnr: missing or not a finite number"),
    ({"psnr": float("nan")}, "psnr: missing or not a finite number"),
    ({"ssim": float("inf")}, "ssim: missing or not a finite number"),
    ({"commit": None}, "commit: missing or not of type str"),
    ({"protocol": "tanks3@400"}, "protocol: unknown protocol 'tanks3'; choose from synthetic-extreme3, "),
    ({"protocol": "dtu3@400"}, "protocol: 'dtu3@400': resolution must be a divisor of 384"),
    ({"run_key": ["a"]}, "not a results line"), ({"status": "done"}, "not a results line"),
])
def test_a_line_the_tables_cannot_read_is_skipped_naming_the_field(tmp_path, ok_line, change, problem):
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps(ok_line()) + "\n\n" + json.dumps(ok_line(**{"run_key": "k2", **change})) + "\n")
    records, skipped = load_results(path)
    assert [r["run_key"] for r in records] == ["k"] and len(skipped) == 1 and skipped[0][0] == 3
    assert skipped[0][1].startswith(problem)


def test_lines_that_are_not_json_or_not_objects_are_skipped(tmp_path, ok_line):
    path = tmp_path / "r.jsonl"
    path.write_bytes(b"1" * 5000 + b"\n" + b"[" * 100000 + b"\nnull\n\xd0\xff\n[1]\n" + json.dumps(ok_line()).encode())
    records, skipped = load_results(path)
    assert len(records) == 1 and skipped == [(1, "not JSON"), (2, "not JSON"), (3, "not a results line"),
                                             (4, "not JSON"), (5, "not a results line")]


def test_unmeasured_memory_and_a_missing_schema_are_read(tmp_path, ok_line):
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps(ok_line(peak_memory_mib=None, run_seconds=None, seconds=0)) + "\n")
    assert load_results(path)[1] == []


def test_the_committed_results_files_read_in_full():
    committed = sorted((REPO / "benchmarks" / "results").glob("*.jsonl"))
    assert committed
    for path in committed:
        records, skipped = load_results(path)
        assert skipped == [] and len(records) == sum(1 for line in path.read_text().splitlines() if line.strip())


def test_the_last_attempt_of_a_run_wins():
    old = result_lines(SPEC, _ok_outcome(), "c", [])
    new = result_lines(SPEC, _ok_outcome(), "c", [])
    for ln in new:
        ln["psnr"] += 100
    failed = result_lines(SPEC, {"status": "failed", "error": "x"}, "c", [])
    assert [ln["psnr"] for ln in latest_ok_lines(old + new + failed)] == [ln["psnr"] for ln in new]
    # the result a user gets: the last attempt's line at the run's last iteration (K = 2), not its teacher
    (final,) = final_ok_lines(old + new + failed)
    assert final["iteration"] == final["iterations"] == 2 and final["psnr"] == new[-1]["psnr"]
