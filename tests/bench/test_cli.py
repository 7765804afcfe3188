"""``senerf-bench`` end to end with the fake fit: run (resume), summarize, report, plot."""

from __future__ import annotations

import json
import shlex

import imageio.v3 as iio

from senerf.bench.cli import main
from senerf.bench.report import PAPER_NUMBERS, make_report
from senerf.bench.results import load_results

#: One finished baseline row of a results file, as ``senerf-bench run`` appends it.
_FINISHED_LINE = json.dumps({"run_key": "k", "status": "ok", "attempt": "a", "scene": "s", "protocol": "p",
                             "method": "baseline", "preset": "fast", "seed": 0, "iterations": 0, "iteration": 0,
                             "psnr": 20.0, "ssim": 0.5, "lpips": "unavailable", "avg": "unavailable",
                             "seconds": 1.0, "seconds_cumulative": 1.0, "peak_memory_mib": 100.0}) + "\n"


def _run_args(scene, out, fit, *extra):
    return ["run", "--scenes", str(scene), "--protocols", "synthetic-extreme3@100", "--methods", "baseline",
            "senerf", "--presets", "fast", "balanced", "--seeds", "0", "1", "--iterations", "2", "--out",
            str(out), "--workers", "2", "--fit-command", shlex.join(fit), *extra]


def test_run_resume_summarize_report_plot(blender_scene, fake_fit_command, tmp_path, monkeypatch, capsys):
    out = tmp_path / "bench"
    monkeypatch.setenv("FAKE_FIT_CRASH_SEEDS", "1")
    assert main(_run_args(blender_scene, out, fake_fit_command)) == 1          # seed 1 runs crashed
    monkeypatch.delenv("FAKE_FIT_CRASH_SEEDS")
    capsys.readouterr()
    assert main(_run_args(blender_scene, out, fake_fit_command, "--dry-run")) == 0
    dry = capsys.readouterr().out
    assert "4 already finished, 4 to run" in dry and "--seed 1" in dry
    assert sum(ln.startswith("senerf-fit ") for ln in dry.splitlines()) == 4
    # the scene's marker file names the same scene (it was "scene folder not found", so at 320e4c6)
    assert main(_run_args(blender_scene / "transforms_train.json", out, fake_fit_command, "--dry-run")) == 0
    assert capsys.readouterr().out == dry
    assert main(_run_args(blender_scene, out, fake_fit_command)) == 0
    records, bad = load_results(out / "results.jsonl")
    assert bad == 0 and len([r for r in records if r["status"] == "failed"]) == 4
    assert records[0]["bench_command"][:2] == ["senerf-bench", "run"]
    assert all(r["machine"].get("cores") for r in records if r["status"] == "ok")

    capsys.readouterr()
    assert main(["summarize", str(out / "results.jsonl"), "--final"]) == 0
    table = capsys.readouterr().out
    # fake fit: PSNR = 20 + iteration + seed / 10; seeds 0 and 1 -> mean 22.05, std 0.07 at iteration 2
    assert "22.05 ± 0.07" in table and "20.05 ± 0.07" in table

    report_path = tmp_path / "section.md"
    assert main(["report", str(out / "results.jsonl"), "--out", str(report_path)]) == 0
    text = report_path.read_text()
    for needle in ("14.67 / 0.68 / 0.31", "16.65 / 0.75 / 0.24", "17.49", "ours 100x100", "800x800",
                   "senerf-bench run --scenes", "senerf-bench report", "22.05 ± 0.07", "torch"):
        assert needle in text, needle

    # the generated section of a hand-written document is replaced in place; the rest is kept byte for byte
    from senerf.bench.cli import REPORT_BEGIN, REPORT_END

    doc = tmp_path / "BENCHMARKS.md"
    head, tail = "# ours\n\nhand-written intro\n", "\nhand-written outro\n"
    doc.write_text(f"{head}{REPORT_BEGIN}\nstale table\n{REPORT_END}{tail}")
    assert main(["report", str(out / "results.jsonl"), "--into", str(doc)]) == 0
    new = doc.read_text()
    assert new.startswith(head + REPORT_BEGIN) and new.endswith(REPORT_END + tail)
    assert "stale table" not in new and "22.05 ± 0.07" in new and "--into" in new
    assert main(["report", str(out / "results.jsonl"), "--into", str(doc)]) == 0   # idempotent markers
    assert doc.read_text().count(REPORT_BEGIN) == 1
    doc.write_text("no markers\n")
    assert main(["report", str(out / "results.jsonl"), "--into", str(doc)]) == 2
    assert doc.read_text() == "no markers\n"

    # a bench_selftrain masks result is tabulated from its JSON
    masks = tmp_path / "bench_masks.json"
    row = dict(features="vgg19-norm", threshold="adaptive", tau=0.9475, precision=0.9265, recall=0.165,
               fpr=0.0672, predicted_reliable_rate=0.149, gt_reliable_rate=0.837)
    masks.write_text(json.dumps(dict(rows=[row, dict(row, threshold="unified", tau=None)], eval_angles_deg=[3.9, 11.9],
                                     argv=["benchmarks/bench_selftrain.py", "masks"], commit="abc", steps=600,
                                     batch_rays=1024, teacher_psnr=16.57, max_error=0.1, timestamp="2026-11-21T09:00")))
    assert main(["report", str(out / "results.jsonl"), "--masks", str(masks), "--out", str(report_path)]) == 0
    text = report_path.read_text()
    assert "| vgg19-norm | adaptive | 0.948 | 92.65 % | 16.50 % | 6.72 % | 14.90 % | 83.70 % |" in text
    assert "| vgg19-norm | unified | soft |" in text and "3.9-11.9 degrees" in text and "commit abc" in text
    # the results' tables stay, and the masks file is tabulated, not copied (at 8939e23-7c49076 the masks JSON
    # replaced the whole report)
    assert "22.05 ± 0.07" in text and '"rows"' not in text and text.index("22.05") < text.index("vgg19-norm")
    (tmp_path / "bad.json").write_text("{")
    assert main(["report", str(out / "results.jsonl"), "--masks", str(tmp_path / "bad.json")]) == 2
    (tmp_path / "other.json").write_text("{}")
    assert main(["report", str(out / "results.jsonl"), "--masks", str(tmp_path / "other.json")]) == 2

    assert main(["plot", str(out / "results.jsonl"), "--out-dir", str(tmp_path / "plots")]) == 0
    pngs = sorted((tmp_path / "plots").glob("*.png"))
    assert [p.name.split("_")[0] for p in pngs] == ["frontier", "gain", "iterations"]
    assert all(iio.imread(p).ndim == 3 for p in pngs)


def test_bad_input_exits_2(tmp_path, capsys):
    assert main(["run", "--scenes", str(tmp_path / "missing")]) == 2
    assert main(["run", "--scenes", str(tmp_path), "--protocols", "nope@1"]) == 2
    assert main(["summarize", str(tmp_path / "none.jsonl")]) == 2
    assert "error" in capsys.readouterr().err
    # run flags out of range: one line naming the flag once (checked by argparse), before anything runs
    for flags, message in ((["--workers", "0"], "argument --workers: must be >= 1, got 0"),
                           (["--timeout", "-5"], "argument --timeout: expected a finite number > 0, got '-5'"),
                           (["--seeds", "0", "-1"],
                            "argument --seeds: must be >= 0 and <= 9223372036854775807, got -1"),
                           (["--seeds", "99999999999999999999"],   # senerf-fit's limit, before any fit
                            "argument --seeds: must be >= 0 and <= 9223372036854775807, "
                            "got 99999999999999999999"),
                           (["--iterations", "-1"], "argument --iterations: must be >= 1, got -1"),
                           (["--steps", "0"], "argument --steps: must be >= 1, got 0"),
                           (["--threads", "0"], "argument --threads: must be >= 1, got 0"),
                           (["--cpus-per-run", "-1"], "argument --cpus-per-run: expected a finite number > 0, "
                                                      "got '-1'"),
                           (["--cpus-per-run", "nan"], "argument --cpus-per-run: expected a finite number > 0, "
                                                       "got 'nan'")):
        assert main(["run", "--scenes", str(tmp_path), "--out", str(tmp_path / "o"), *flags]) == 2
        assert capsys.readouterr().err.strip() == f"senerf-bench: error: {message}"
        assert not (tmp_path / "o").exists()
    # a file where an output folder should be
    a_file = tmp_path / "a_file"
    a_file.write_text("mine")
    assert main(["run", "--scenes", str(tmp_path), "--out", str(a_file)]) == 2
    assert capsys.readouterr().err.strip() == (f"senerf-bench: error: {a_file}: exists and is not a folder; "
                                               "choose another --out")
    results = tmp_path / "results.jsonl"
    results.write_text(_FINISHED_LINE)
    assert main(["plot", str(results), "--out-dir", str(a_file)]) == 2
    assert "exists and is not a folder; choose another --out-dir" in capsys.readouterr().err
    assert a_file.read_text() == "mine"
    # a folder where an output file should be; nothing else written first
    doc = tmp_path / "doc.md"
    doc.write_text("x\n<!-- senerf-bench report: BEGIN (generated, do not edit by hand) -->\n"
                   "<!-- senerf-bench report: END -->\n")
    before = doc.read_text()
    assert main(["report", str(results), "--into", str(doc), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == (f"senerf-bench: error: {tmp_path}: is a folder; --out takes a "
                                               "file name")
    assert doc.read_text() == before
    assert main(["angles", str(results), "--scene", str(tmp_path), "--protocol", "llff3", "--out",
                 str(tmp_path)]) == 2
    assert "is a folder; --out takes a file name" in capsys.readouterr().err


def test_report_paper_rows_per_protocol():
    line = {"run_key": "k", "attempt": "a", "status": "ok", "scene": "fern", "protocol": "llff3@504x378",
            "method": "baseline", "preset": "fast", "seed": 0, "iterations": 0, "iteration": 0, "psnr": 17.0,
            "ssim": 0.5, "lpips": "unavailable", "avg": "unavailable", "seconds_cumulative": 60.0,
            "peak_memory_mib": 900.0, "commit": "abc", "machine": {"cpu": "X"}, "timestamp": "2026-01-01T00:00",
            "bench_command": ["senerf-bench", "run", "--scenes", "fern"]}
    text = make_report([line], ["senerf-bench", "report", "r.jsonl"])
    assert "K-Planes (paper): 18.22" in text and "FreeNeRF: 19.63" in text
    assert "ours 504x378" in text and "paper 504x378." in text
    assert "`senerf-bench run --scenes fern`" in text and "abc" in text
    assert len({(r.family, r.scene, r.label) for r in PAPER_NUMBERS}) == len(PAPER_NUMBERS)


def test_report_leaves_out_lines_of_another_resolution():
    # before: a line recorded at 252x189 was averaged into the 504x378 protocol's row (the header said checked)
    def line(key, seed, psnr, resolution):
        return {"run_key": key, "attempt": "a", "status": "ok", "scene": "fern", "protocol": "llff3@504x378",
                "method": "baseline", "preset": "fast", "seed": seed, "iterations": 0, "iteration": 0, "psnr": psnr,
                "ssim": 0.5, "lpips": "unavailable", "avg": "unavailable", "seconds_cumulative": 60.0,
                "peak_memory_mib": 900.0, "commit": "abc", "machine": {"cpu": "X"},
                "timestamp": "2026-01-01T00:00", "bench_command": ["senerf-bench", "run"], "resolution": resolution}
    text = make_report([line("k0", 0, 17.0, [378, 504]), line("k1", 1, 19.0, [378, 504]),
                        line("k2", 2, 30.0, [189, 252]), line("k3", 3, 18.0, None)],
                       ["senerf-bench", "report", "r.jsonl"])
    assert "Left out: 1 finished line(s) whose resolution is not their protocol's (`k2`)." in text
    row = next(ln for ln in text.splitlines() if ln.startswith("| fern | baseline | fast | 0 |"))
    assert "| 3 | 18.00 ± 1.00 |" in row, row          # seeds 0, 1 and the unrecorded 3; not the 30 dB line
    assert "Left out" not in make_report([line("k0", 0, 17.0, [378, 504])], ["r"])


def _one_error_line(capsys) -> str:
    """The single ``senerf-bench: error:`` line on stderr (no traceback, no usage)."""
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("senerf-bench: error: "), err
    return err.strip()


def test_argparse_errors_are_one_line(tmp_path, capsys):
    # before: argparse printed its multi-line usage and exited through SystemExit
    for argv, needle in ((["run"], "required: --scenes"), (["summarize"], "required: results"),
                         (["bogus"], "invalid choice: 'bogus'"),
                         (["run", "--scenes", "s", "--workers", "x"],
                          "argument --workers: expected an integer, got 'x'"),
                         (["report", "r.jsonl", "--nope"], "unrecognized arguments: --nope")):
        assert main(argv) == 2, argv
        assert needle in _one_error_line(capsys)
    assert main(["--help"]) == 0 and "usage: senerf-bench" in capsys.readouterr().out


def test_unreadable_results_file_is_an_error(tmp_path, capsys):
    bad = tmp_path / "bad.jsonl"
    bad.write_text("garbage\n{torn\n[1, 2]\n")
    for command in (["summarize"], ["report"], ["plot"]):
        assert main([*command, str(bad)]) == 2, command
        assert f"{bad}: no line could be read (3 unparseable line(s))" in _one_error_line(capsys)
    binary = tmp_path / "binary.jsonl"   # before: UnicodeDecodeError traceback
    binary.write_bytes(b"\xd0\xff\x00\n\x89PNG\n")
    assert main(["summarize", str(binary)]) == 2
    assert "no line could be read (2 unparseable line(s))" in _one_error_line(capsys)
    # some bad lines: a warning, the rest is summarized; an empty file is an empty benchmark
    good = json.dumps({"run_key": "k", "status": "failed", "error": "x"})
    bad.write_text(f"garbage\n{good}\n")
    assert main(["summarize", str(bad)]) == 0
    assert "warning: skipped 1 unparseable line(s)" in capsys.readouterr().err
    (tmp_path / "empty.jsonl").write_text("")
    assert main(["summarize", str(tmp_path / "empty.jsonl")]) == 0


def test_output_paths_that_cannot_be_written(blender_scene, fake_fit_command, tmp_path, capsys):
    """A file in the way, a folder where a file goes, a place the kernel refuses (``/proc``): one line
    naming the flag, exit 2, nothing written (before: FileExistsError / IsADirectoryError / PermissionError
    tracebacks, exit 1)."""
    a_file = tmp_path / "afile"
    a_file.write_text("mine")
    a_dir = tmp_path / "adir"
    a_dir.mkdir()
    results = tmp_path / "results.jsonl"
    results.write_text("")
    doc = tmp_path / "doc.md"
    doc.write_text("x\n<!-- senerf-bench report: BEGIN (generated, do not edit by hand) -->\n"
                   "<!-- senerf-bench report: END -->\n")
    before = doc.read_text()
    for out in (a_file / "x.md", "/proc/senerf-bench-test/x.md", "/proc/x.md"):
        assert main(["report", str(results), "--into", str(doc), "--out", str(out)]) == 2, out
        assert "--out" in _one_error_line(capsys)
        assert doc.read_text() == before
    assert main(["report", str(results), "--into", str(a_dir)]) == 2
    assert "--into" in _one_error_line(capsys)
    finished = tmp_path / "finished.jsonl"
    finished.write_text(_FINISHED_LINE)
    for out_dir in (a_file / "x", "/proc/senerf-bench-test"):
        assert main(["plot", str(finished), "--out-dir", str(out_dir)]) == 2, out_dir
        assert "--out-dir" in _one_error_line(capsys)

    run = ["run", "--scenes", str(blender_scene), "--methods", "baseline", "--fit-command",
           shlex.join(fake_fit_command)]
    bench = tmp_path / "bench"
    for flags, flag in ((["--results", str(a_dir), "--dry-run"], "--results"),
                        (["--results", str(a_dir)], "--results"),
                        (["--results", str(a_file / "r.jsonl")], "--results"),
                        (["--results", "/proc/senerf-bench-test.jsonl"], "--results"),
                        (["--out", str(a_file / "o")], "--out"),
                        (["--out", "/proc/senerf-bench-test"], "--out")):
        argv = [*run, "--out", str(bench), *flags] if "--out" not in flags else [*run, *flags]
        assert main(argv) == 2, flags
        assert flag in _one_error_line(capsys), flags
        assert not list(bench.glob("runs/*")), flags      # no fit ran
    assert a_file.read_text() == "mine" and not any(a_dir.iterdir())


def test_run_refuses_to_append_to_a_file_that_is_not_results(blender_scene, fake_fit_command, tmp_path, capsys):
    """``--results README.md``: no line of it is a results line, so appending would mix our lines into the
    user's file; refused before any fit, the file untouched (before: appended to, so at 384706f)."""
    readme = tmp_path / "README.md"
    readme.write_text("# my notes\n\nsome text\n")
    run = ["run", "--scenes", str(blender_scene), "--methods", "baseline", "--fit-command",
           shlex.join(fake_fit_command), "--out", str(tmp_path / "bench")]
    for extra in ([], ["--dry-run"]):
        assert main([*run, "--results", str(readme), *extra]) == 2
        line = _one_error_line(capsys)
        assert f"{readme}: not a senerf-bench results file (2 non-blank line(s), none a results line)" in line
        assert "--results" in line
        assert readme.read_text() == "# my notes\n\nsome text\n"
        assert not list((tmp_path / "bench").glob("runs/*"))
    # a results file with one torn line (a killed writer) still resumes
    torn = tmp_path / "torn.jsonl"
    torn.write_text(_FINISHED_LINE.rstrip("\n") + "\n{\"run_key\": \"x\", \"sta\n")
    assert main([*run, "--results", str(torn), "--dry-run"]) == 0
    capsys.readouterr()
    # ... and so does one whose only line is torn (killed during its first append)
    torn.write_text("{\"run_key\": \"x\", \"sta\n")
    assert main([*run, "--results", str(torn), "--dry-run"]) == 0
    capsys.readouterr()
    # but another tool's JSON-lines log is someone else's file
    log = tmp_path / "app.jsonl"
    log.write_text('{"level": "info", "msg": "a"}\n{"level": "warn", "msg": "b"}\n')
    assert main([*run, "--results", str(log), "--dry-run"]) == 2
    assert "not a senerf-bench results file (2 non-blank line(s)" in _one_error_line(capsys)


def test_mistyped_lines_are_skipped_with_a_warning_not_crashed_on_or_counted(tmp_path, capsys):
    # a string seed or iteration crashed summarize/report/plot with a TypeError, and a PSNR of "abc", null or
    # NaN was averaged without a word (and counted the run as finished) (so at 9e0fdc2)
    good = json.loads(_FINISHED_LINE)
    results = tmp_path / "r.jsonl"
    bad_values = [("seed", "0"), ("iteration", "1"), ("scene", 5), ("iterations", "x"), ("run_key", ["a"]),
                  ("commit", None), ("psnr", "abc"), ("psnr", None), ("psnr", float("nan")), ("views", ["a"]),
                  # each check's other cases (mutations survived): an infinite PSNR, a NaN SSIM, a bool index,
                  # a resolution of strings
                  ("psnr", float("inf")), ("ssim", float("nan")), ("test_views", [True, 1]), ("resolution", ["a", 1])]
    lines = [_FINISHED_LINE] + [json.dumps({**good, "run_key": f"k{i}", name: value}) + "\n"
                                for i, (name, value) in enumerate(bad_values)]
    results.write_text("".join(lines))
    records, bad = load_results(results)
    assert [r["run_key"] for r in records] == ["k"] and bad == len(bad_values)
    assert main(["summarize", str(results)]) == 0
    captured = capsys.readouterr()
    assert f"skipped {len(bad_values)} unparseable line(s)" in captured.err and "20.00" in captured.out
    # the first one named, with why (at 0b7a241 only the count was said)
    assert f"(line 2: seed: str is not int; {len(bad_values) - 1} more)" in captured.err
    skipped = []
    load_results(results, skipped)
    assert [n for n, _ in skipped] == list(range(2, 2 + len(bad_values)))
    assert skipped[6] == (8, "psnr: str is not float/int") and skipped[10] == (12, "psnr: inf is not a finite number")
    results.write_text('{"no": "run_key"}\n[1]\n{torn\n' + json.dumps({"run_key": "k", "status": "ok"}) + "\n"
                       + _FINISHED_LINE)
    skipped = []
    load_results(results, skipped)
    assert skipped == [(1, "not a results line (no run_key)"), (2, "not a results line (no run_key)"),
                       (3, "not JSON"), (4, "an ok line without iteration")]   # the first missing, by name
    # lines json.loads refuses with a plain ValueError or a RecursionError, not a JSONDecodeError (an internal
    # error at 5eb7a2a), a JSON null, and bytes that are not UTF-8
    results.write_bytes(b"1" * 5000 + b"\n" + b"[" * 100000 + b"\n" + b"null\n\xd0\xff\n"
                        + _FINISHED_LINE.encode())
    skipped = []
    records, bad = load_results(results, skipped)
    assert len(records) == 1 and bad == 4
    assert skipped == [(1, "not JSON"), (2, "not JSON"), (3, "not a results line (no run_key)"), (4, "not UTF-8")]


def test_a_report_or_plot_over_its_own_results_file_is_refused(tmp_path, capsys):
    # report --out results.jsonl replaced every measured run with the report (so at 9e0fdc2)
    results = tmp_path / "r.jsonl"
    results.write_text(_FINISHED_LINE)
    assert main(["report", str(results), "--out", str(results)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"senerf-bench: error: {results}: is {results}, which this command reads; "
                           f"choose another --out")
    assert results.read_text() == _FINISHED_LINE
    masks = tmp_path / "masks.json"                # and the other inputs: --into the results, --out a masks file,
    masks.write_text("{}")                          # angles --out the results
    for argv, flag in ((["report", str(results), "--into", str(results)], "--into"),
                       (["report", str(results), "--masks", str(masks), "--out", str(masks)], "--out"),
                       (["angles", str(results), "--scene", str(tmp_path), "--protocol", "llff3",
                         "--out", str(results)], "--out")):
        assert main(argv) == 2
        assert capsys.readouterr().err.strip().endswith(f"which this command reads; choose another {flag}")
    assert results.read_text() == _FINISHED_LINE and masks.read_text() == "{}"


def test_an_interrupt_exits_130_with_one_line(tmp_path, capsys, monkeypatch):
    # SIGTERM (raised as KeyboardInterrupt by the handler run_command installs) ended senerf-bench with 143 and
    # no word, where Ctrl-C gave 130 (so at 9e0fdc2)
    import signal

    from senerf.bench import cli

    seen = []

    def interrupted(args, argv):
        seen.append(signal.getsignal(signal.SIGTERM))
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_dispatch", interrupted)
    assert main(["summarize", str(tmp_path / "r.jsonl")]) == 130
    assert capsys.readouterr().err.startswith("senerf-bench: interrupted (")
    assert seen and seen[0] not in (signal.SIG_DFL, None)   # a handler was in place for SIGTERM


def test_a_local_cuda_run_without_a_gpu_and_an_empty_grid_are_refused_before_anything_runs(
        blender_scene, fake_fit_command, tmp_path, capsys):
    # each fit failed on --device cuda (exit 1 after writing failed lines), and a grid matching nothing printed
    # "# 0 runs" and exited 0 (so at 9e0fdc2)
    import pytest
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    out = tmp_path / "b"
    assert main(_run_args(blender_scene, out, fake_fit_command, "--device", "cuda")) == 2
    assert "--device: CUDA requested but torch sees no GPU" in capsys.readouterr().err
    assert not (out / "results.jsonl").exists()
    args = _run_args(blender_scene, out, fake_fit_command)
    args[args.index("--protocols") + 1] = "llff3@504x378"   # an LLFF protocol: no Blender scene fits it
    assert main(args) == 2
    assert "--protocols: the grid of scenes" in capsys.readouterr().err


def test_unknown_methods_presets_and_protocols_name_the_flag(blender_scene, fake_fit_command, tmp_path, capsys):
    # they said "method: unknown method 'nosuch'", the setting's name, not the flag the user typed (so at 3cbad99)
    for flag, value in (("--methods", "nosuch"), ("--presets", "nosuch"), ("--protocols", "nosuch@1")):
        args = _run_args(blender_scene, tmp_path / "b", fake_fit_command)
        at = args.index(flag) + 1
        while at < len(args) and not args[at].startswith("--"):   # the flag's values, replaced by one bad one
            del args[at]
        args.insert(at, value)
        assert main(args) == 2
        assert capsys.readouterr().err.startswith(f"senerf-bench: error: {flag}: unknown ")
    assert main(["angles", str(tmp_path / "r.jsonl"), "--scene", str(blender_scene), "--protocol", "bogus",
                 "--out", str(tmp_path / "a.png")]) == 2
    assert capsys.readouterr().err.startswith("senerf-bench: error: --protocol: unknown protocol")
