"""Results lines with values no run can have: a schema this version does not read, a negative iteration, a
negative or non-finite time, an absurd PSNR.  Each was read without a word by summarize, report and plot (so at
d822679); now every command that reads a results file refuses it in one line naming the file, the field, the line
and the run, while the committed results and every value a run can write still load."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from senerf.bench.cli import main
from senerf.bench.results import load_results, validate_line
from senerf.errors import InputError

_REPO = Path(__file__).resolve().parents[2]

#: A finished baseline line with every field ``senerf-bench run`` writes (``report`` and ``plot`` read them).
_LINE = dict(schema=1, run_key="k", attempt="a", status="ok", timestamp="2026-01-01T00:00", scene="lego",
             protocol="synthetic-extreme3@100", resolution=[100, 100], views=None, n_views=None, method="baseline",
             preset="fast", seed=0, iterations=0, iteration=0, psnr=20.0, ssim=0.5, lpips="unavailable",
             avg="unavailable", seconds=1.0, seconds_cumulative=1.0, run_seconds=1.5, peak_memory_mib=100.0,
             commit="c", machine={}, fit_command=["senerf-fit"], bench_command=["senerf-bench", "run"])


def _results(tmp_path: Path, **second) -> Path:
    """A results file of two runs (seeds 0 and 1), the second one's line (line 2, run ``k1``) changed by
    ``second``."""
    path = tmp_path / "r.jsonl"
    lines = [_LINE, {**_LINE, "run_key": "k1", "seed": 1, "psnr": 21.0, **second}]
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    return path


def _every_command_refuses(path: Path, tmp_path: Path, capsys, message: str) -> None:
    """summarize, report and plot each exit 2 printing ``senerf-bench: error: <path>: <message>``, nothing else."""
    for argv in (["summarize", str(path)], ["report", str(path)],
                 ["plot", str(path), "--out-dir", str(tmp_path / "plots")]):
        assert main(argv) == 2, argv
        captured = capsys.readouterr()
        assert captured.err == f"senerf-bench: error: {path}: {message}\n", argv
        assert captured.out == "", argv
    assert not (tmp_path / "plots").exists()


def test_a_line_of_a_newer_schema_is_refused_naming_the_versions_read(tmp_path, capsys, blender_scene):
    path = _results(tmp_path, schema=99)
    _every_command_refuses(path, tmp_path, capsys, "schema: 99 is newer than this version of senerf reads "
                                                   "(schema 1); upgrade senerf to read it (line 2, run k1)")
    # before the shape checks: a newer schema's line without today's fields is still named, not skipped
    path.write_text(json.dumps(_LINE) + "\n\n" + json.dumps({"schema": 2, "id": "x"}) + "\n")
    with pytest.raises(InputError, match=r"r\.jsonl: schema: 2 is newer than .* \(line 3\)$"):
        load_results(path)
    # and `run` does not append schema-1 lines to that file
    assert main(["run", "--scenes", str(blender_scene), "--results", str(path), "--dry-run"]) == 2
    assert "schema: 2 is newer" in capsys.readouterr().err
    # a schema that never existed is named too
    with pytest.raises(InputError, match=r": schema: 0 is not a schema this version of senerf reads \(schema 1\)"):
        load_results(_results(tmp_path, schema=0))
    # the accepted side: schema 1, a hand-cut line without a schema, and every committed results file, read in full
    records, bad = load_results(_results(tmp_path))
    assert [r["run_key"] for r in records] == ["k", "k1"] and bad == 0
    no_schema = {k: v for k, v in _LINE.items() if k != "schema"}
    (tmp_path / "old.jsonl").write_text(json.dumps(no_schema) + "\n")
    assert load_results(tmp_path / "old.jsonl") == ([no_schema], 0)
    committed = sorted((_REPO / "benchmarks" / "results").glob("*.jsonl"))
    assert committed
    for path in committed:
        records, bad = load_results(path)
        assert bad == 0 and len(records) == sum(1 for line in path.read_text().splitlines() if line.strip())
        for r in records:
            validate_line(r)   # the stricter check too: every committed line is one a run can write


@pytest.mark.parametrize("second, message", [
    (dict(iteration=-1), "iteration: -1 is negative (0 is the teacher or baseline, 1.. the students)"),
    (dict(iteration=3), "iteration: 3 is beyond the run's iterations (0)"),
    (dict(iterations=-2), "iterations: -2 is negative (the run's self-training rounds, 0 for a baseline)"),
], ids=["negative", "beyond-K", "negative-K"])
def test_an_impossible_iteration_is_refused(tmp_path, capsys, second, message):
    path = _results(tmp_path, **second)
    _every_command_refuses(path, tmp_path, capsys, f"{message} (line 2, run k1)")


def test_a_non_integer_iteration_is_still_skipped_with_the_warning(tmp_path, capsys):
    # the accepted side of the check above: a mistyped iteration (1.5, "1") stays an unparseable line, skipped
    # with the warning (test_cli.py), and iterations 0..K of a self-training run all load
    assert main(["summarize", str(_results(tmp_path, iteration=1.5))]) == 0
    assert "skipped 1 unparseable line(s)" in capsys.readouterr().err
    path = tmp_path / "k2.jsonl"
    path.write_text("".join(json.dumps({**_LINE, "method": "senerf", "iterations": 2, "iteration": i}) + "\n"
                            for i in range(3)))
    assert [r["iteration"] for r in load_results(path)[0]] == [0, 1, 2]
    # and the refusal names a negative iteration where the loader is called directly
    with pytest.raises(InputError, match=r"r\.jsonl: iteration: -1 is negative"):
        load_results(_results(tmp_path, iteration=-1))


@pytest.mark.parametrize("name", ["seconds", "seconds_cumulative", "run_seconds", "peak_memory_mib"])
@pytest.mark.parametrize("value, shown", [(-1.0, "-1.0"), (-5, "-5"), (math.nan, "nan"), (math.inf, "inf")],
                         ids=["negative", "negative-int", "NaN", "Infinity"])
def test_a_negative_or_non_finite_time_or_memory_is_refused(tmp_path, capsys, name, value, shown):
    path = _results(tmp_path, **{name: value})
    _every_command_refuses(path, tmp_path, capsys, f"{name}: {shown} is not a finite number >= 0 (line 2, run k1)")


def test_zero_and_unmeasured_times_still_load(tmp_path):
    # the accepted side: 0 s (a cached step), and null run_seconds / peak_memory_mib (not measured)
    path = _results(tmp_path, seconds=0, seconds_cumulative=0.0, run_seconds=None, peak_memory_mib=None)
    assert [r["run_key"] for r in load_results(path)[0]] == ["k", "k1"]
    with pytest.raises(InputError, match=r"seconds: -0\.5 is not a finite number >= 0 \(line 2, run k1\)$"):
        load_results(_results(tmp_path, seconds=-0.5))


def test_plot_refuses_an_absurd_psnr_instead_of_overflowing(tmp_path, capsys):
    # a PSNR of 1e308 dB made plot (and summarize, report) print NumPy's "overflow encountered in square" and draw
    # a mean of 5e307 dB (so at d822679): no render of images in [0, 1] has a finite PSNR above 3234 dB
    path = _results(tmp_path, psnr=1e308)
    message = "psnr: 1e+308 dB is not the PSNR of images in [0, 1] (a finite one is 0 to 3234 dB) (line 2, run k1)"
    _every_command_refuses(path, tmp_path, capsys, message)
    with pytest.raises(InputError, match=r"psnr: -1e\+308 dB is not the PSNR"):
        load_results(_results(tmp_path, psnr=-1e308))
    with pytest.raises(InputError, match=r"ssim: 1e\+308 is outside \[-1, 1\] \(line 2, run k1\)$"):
        load_results(_results(tmp_path, ssim=1e308))
    # the accepted side: the bounds themselves plot without a warning ...
    for psnr in (0.0, 3234.0):
        assert main(["plot", str(_results(tmp_path, psnr=psnr)), "--out-dir", str(tmp_path / "p")]) == 0
        assert capsys.readouterr().err == ""
    # ... and an exactly rendered test set (PSNR Infinity) does not crash: that line is skipped as before
    path = _results(tmp_path, psnr=math.inf)
    assert "Infinity" in path.read_text()
    assert main(["plot", str(path), "--out-dir", str(tmp_path / "p")]) == 0
    assert capsys.readouterr().err == (f"senerf-bench: warning: skipped 1 unparseable line(s) in {path} (line 2: psnr: "
                                       "inf is not a finite number)\n")


def test_validate_line_names_an_impossible_value():
    validate_line(_LINE)
    for field, value, problem in (("iteration", -1, "-1 is negative"), ("seconds", -1.0, "-1.0 is not a finite"),
                                  ("peak_memory_mib", math.inf, "inf is not a finite"),
                                  ("psnr", 5000.0, "5000.0 dB is not the PSNR"), ("ssim", -2.0, "-2.0 is outside")):
        with pytest.raises(ValueError, match=rf"^{field}: {problem}"):
            validate_line({**_LINE, field: value})

