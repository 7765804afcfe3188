"""Results lines: schema, one locked append per run, tolerant reading, last-attempt dedupe."""

from __future__ import annotations

import json

import pytest

from senerf.bench.results import (REQUIRED_OK_FIELDS, append_lines, final_ok_lines, finished_keys, latest_ok_lines,
                                  load_results, result_lines, validate_line)
from senerf.bench.specs import RunSpec

SPEC = RunSpec("/data/lego", "lego", "synthetic-extreme3@100", "senerf", "fast", 1, 2)


def _metrics(n_iter=3, lpips="unavailable"):
    return {"senerf_version": "x", "train_views": [0, 1, 51], "test_views": [0, 1], "resolution": [100, 100],
            "iterations": [{"iteration": k, "psnr": 15.0 + k, "ssim": 0.6, "lpips": lpips, "avg": lpips,
                            "reliable_fraction": None, "seconds": 2.0 + k,
                            "per_view": {"psnr": [1.0, 2.0], "ssim": [0.5, 0.5]}} for k in range(n_iter)]}


def _ok_outcome(**kw):
    return {"status": "ok", "metrics": _metrics(**kw), "run_seconds": 12.5, "peak_memory_mib": 300.0,
            "machine": {"cpu": "x"}, "fit_command": ["senerf-fit", "a"], "run_dir": "/r"}


def test_ok_lines_follow_the_schema():
    lines = result_lines(SPEC, _ok_outcome(), "abc-dirty", ["senerf-bench", "run"])
    assert [ln["iteration"] for ln in lines] == [0, 1, 2]
    for ln in lines:
        validate_line(ln)
        assert set(REQUIRED_OK_FIELDS) <= set(ln)
        json.dumps(ln)  # JSON-ready
    assert [ln["seconds_cumulative"] for ln in lines] == [2.0, 5.0, 9.0]
    assert len({ln["attempt"] for ln in lines}) == 1
    assert lines[2]["psnr"] == 17.0 and lines[0]["lpips"] == "unavailable" and lines[0]["views"] == [0, 1, 51]
    assert lines[0]["commit"] == "abc-dirty" and lines[0]["bench_command"] == ["senerf-bench", "run"]
    numeric = result_lines(SPEC, _ok_outcome(lpips=0.25), "c", [])
    assert numeric[0]["lpips"] == 0.25 and numeric[0]["avg"] == 0.25


def test_failed_line_and_validation_errors():
    (line,) = result_lines(SPEC, {"status": "failed", "error": "exited with status -9", "returncode": -9},
                           "c", [])
    validate_line(line)
    assert line["iteration"] is None and line["run_key"] == SPEC.key()
    good = result_lines(SPEC, _ok_outcome(), "c", [])[0]
    for field, value in (("psnr", "17"), ("seed", True), ("lpips", "n/a")):
        with pytest.raises(ValueError, match=field):
            validate_line({**good, field: value})
    bad = dict(good)
    del bad["machine"]
    with pytest.raises(ValueError, match="machine"):
        validate_line(bad)
    # what the runner writes when it cannot read the fit's max RSS: valid, as load_results keeps it
    validate_line({**good, "peak_memory_mib": None, "run_seconds": None})
    for field, value in (("peak_memory_mib", "x"), ("psnr", None), ("views", [0.5])):
        with pytest.raises(ValueError, match=field):
            validate_line({**good, field: value})


def test_append_load_tolerates_a_torn_line(tmp_path):
    path = tmp_path / "r.jsonl"
    assert load_results(path) == ([], 0)
    first = result_lines(SPEC, _ok_outcome(), "c", [])
    append_lines(path, first)
    with open(path, "a") as f:
        f.write('{"run_key": "torn')           # a writer died mid-line
    second = result_lines(RunSpec("/d", "lego", "synthetic-extreme3@100", "baseline", "fast", 0, 0),
                          _ok_outcome(n_iter=1), "c", [])
    append_lines(path, second)
    records, bad = load_results(path)
    assert bad == 1 and len(records) == len(first) + len(second)
    assert finished_keys(records) == {SPEC.key(), second[0]["run_key"]}


def test_an_ok_line_without_its_fields_is_unparseable(tmp_path, capsys):
    # A hand-edited or foreign line marked "ok" but missing what the summaries index by crashed summarize
    # with a KeyError traceback (so at 0ba0767); it is now skipped as unparseable, with the usual warning.
    from senerf.bench.cli import main

    path = tmp_path / "r.jsonl"
    append_lines(path, result_lines(SPEC, _ok_outcome(), "c", []))
    with open(path, "a") as f:
        f.write('{"run_key": "k", "status": "ok"}\n')
    records, bad = load_results(path)
    assert bad == 1 and all(r["run_key"] != "k" for r in records)
    assert main(["summarize", str(path)]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_latest_attempt_wins():
    old = result_lines(SPEC, _ok_outcome(), "c", [])
    new = result_lines(SPEC, _ok_outcome(), "c", [])
    for ln in new:
        ln["psnr"] += 100
    failed = result_lines(SPEC, {"status": "failed", "error": "x"}, "c", [])
    kept = latest_ok_lines(old + new + failed)
    assert [ln["psnr"] for ln in kept] == [ln["psnr"] for ln in new]
    # the result a user gets: the last attempt's line at the run's last iteration (K = 2), not its teacher
    (final,) = final_ok_lines(old + new + failed)
    assert final["iteration"] == final["iterations"] == 2 and final["psnr"] == new[-1]["psnr"]


def test_an_ok_line_whose_memory_or_wall_time_was_not_measured_is_kept(tmp_path):
    # execute.py writes peak_memory_mib / run_seconds as null when it cannot read them; the first version of the
    # type check dropped such finished runs, so every `run` redid them (a review, so at 3cbad99)
    path = tmp_path / "r.jsonl"
    good = dict(schema=1, run_key="k", attempt="a", status="ok", timestamp="t", scene="s", protocol="p",
                resolution=[8, 8], views=[0, 1], n_views=2, method="baseline", preset="fast", seed=0, iterations=0,
                iteration=0, psnr=20.0, ssim=0.5, lpips="unavailable", avg="unavailable", seconds=1.0,
                seconds_cumulative=1.0, run_seconds=None, peak_memory_mib=None, commit="c", machine={},
                fit_command=[], bench_command=[])
    path.write_text(json.dumps(good) + "\n" + json.dumps({**good, "run_key": "k2", "run_seconds": "x"}) + "\n")
    records, bad = load_results(path)
    assert [r["run_key"] for r in records] == ["k"] and bad == 1
