"""``senerf-bench`` end to end with the fake fit (run, resume, summarize, report, plot), and bad input as one
line with exit 2, nothing written."""

from __future__ import annotations

import json
import runpy
import shlex
import sys

import imageio.v3 as iio
import pytest

from senerf.bench import cli
from senerf.bench.cli import REPORT_BEGIN, REPORT_END, main
from senerf.bench.results import load_results


def _run_args(scene, out, fit, *extra):
    return ["run", "--scenes", str(scene), "--protocols", "synthetic-extreme3@100", "--methods", "baseline",
            "senerf", "--presets", "fast", "balanced", "--seeds", "0", "1", "--iterations", "2", "--out",
            str(out), "--workers", "2", "--fit-command", shlex.join(fit), *extra]


def _error(capsys) -> str:
    """The single ``senerf-bench: error:`` line on stderr (no traceback, no usage)."""
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("senerf-bench: error: "), err
    return err.strip().removeprefix("senerf-bench: error: ")


def test_run_resume_summarize_report_plot(blender_scene, fake_fit_command, tmp_path, monkeypatch, capsys):
    out = tmp_path / "bench"
    monkeypatch.setenv("FAKE_FIT_CRASH_SEEDS", "1")
    assert main(_run_args(blender_scene, out, fake_fit_command)) == 1          # seed 1 runs crashed
    monkeypatch.delenv("FAKE_FIT_CRASH_SEEDS")
    capsys.readouterr()
    assert main(_run_args(blender_scene, out, fake_fit_command, "--dry-run")) == 0
    dry = capsys.readouterr().out
    assert dry.startswith("# 8 runs: 4 already finished, 4 to run\n") and "--seed 1" in dry
    assert sum(ln.startswith("senerf-fit ") for ln in dry.splitlines()) == 4
    # the scene's marker file names the same scene
    assert main(_run_args(blender_scene / "transforms_train.json", out, fake_fit_command, "--dry-run")) == 0
    assert capsys.readouterr().out == dry
    assert main(_run_args(blender_scene, out, fake_fit_command)) == 0
    records, skipped = load_results(out / "results.jsonl")
    assert skipped == [] and len([r for r in records if r["status"] == "failed"]) == 4
    assert records[0]["bench_command"][:2] == ["senerf-bench", "run"]

    capsys.readouterr()
    assert main(["summarize", str(out / "results.jsonl"), "--final"]) == 0
    table = capsys.readouterr().out
    # fake fit: PSNR = 20 + iteration + seed / 10; seeds 0 and 1 -> mean 22.05, std 0.07 at iteration 2
    assert "22.05 ± 0.07" in table and "20.05 ± 0.07" in table and "21.05" not in table

    report = tmp_path / "section.md"
    assert main(["report", str(out / "results.jsonl"), "--out", str(report)]) == 0
    text = report.read_text()
    for needle in ("14.67 / 0.68 / 0.31", "16.65 / 0.75 / 0.24", "17.49", "ours 100x100", "800x800",
                   "senerf-bench run --scenes", "senerf-bench report", "22.05 ± 0.07", "Fake CPU"):
        assert needle in text, needle

    # the generated section of a hand-written document is replaced in place; the rest is kept byte for byte
    doc = tmp_path / "BENCHMARKS.md"
    head, tail = "# ours\n\nhand-written intro\n", "\nhand-written outro\n"
    doc.write_text(f"{head}{REPORT_BEGIN}\nstale table\n{REPORT_END}{tail}")
    for _ in range(2):   # and again over its own output
        assert main(["report", str(out / "results.jsonl"), "--into", str(doc)]) == 0
        new = doc.read_text()
        assert new.startswith(head + REPORT_BEGIN) and new.endswith(REPORT_END + tail)
        assert "stale table" not in new and "22.05 ± 0.07" in new and "--into" in new
    for markers in ("no markers\n", f"{REPORT_END}\n{REPORT_BEGIN}\n", f"{REPORT_BEGIN}\n{REPORT_BEGIN}\n{REPORT_END}"):
        doc.write_text(markers)
        assert main(["report", str(out / "results.jsonl"), "--into", str(doc)]) == 2
        assert _error(capsys).startswith(f"{doc}: report markers: needs exactly one")
        assert doc.read_text() == markers

    assert main(["plot", str(out / "results.jsonl"), "--out-dir", str(tmp_path / "plots")]) == 0
    (png,) = (tmp_path / "plots").glob("*.png")
    assert png.name == "frontier_lego_synthetic-extreme3_at_100.png" and iio.imread(png).ndim == 3


@pytest.mark.parametrize("argv, message", [
    (["run"], "the following arguments are required: --scenes"),
    (["summarize"], "the following arguments are required: results"),
    (["bogus"], "argument command: invalid choice: 'bogus'"),
    (["report", "r.jsonl", "--nope"], "unrecognized arguments: --nope"),
    (["run", "--scenes", "s", "--workers", "0"], "argument --workers: must be >= 1, got 0"),
    (["run", "--scenes", "s", "--workers", "x"], "argument --workers: expected an integer, got 'x'"),
    (["run", "--scenes", "s", "--timeout", "-5"], "argument --timeout: expected a finite number > 0, got '-5'"),
    (["run", "--scenes", "s", "--cpus-per-run", "nan"], "argument --cpus-per-run: expected a finite number > 0"),
    (["run", "--scenes", "s", "--seeds", "0", "-1"], "argument --seeds: must be >= 0 and <= 9223372036854775807"),
    (["run", "--scenes", "s", "--iterations", "0"], "argument --iterations: must be >= 1, got 0"),
    (["run", "--scenes", "s", "--methods", "nosuch"], "argument --methods: invalid choice: 'nosuch'"),
    (["run", "--scenes", "s", "--presets", "turbo"], "argument --presets: invalid choice: 'turbo'"),
    (["run", "--scenes", "s", "--protocols", "nosuch@1"], "argument --protocols: unknown protocol 'nosuch'"),
    (["run", "--scenes", "s", "--protocols", "llff3@500x378"], "argument --protocols: 'llff3@500x378': LLFF"),
    (["run", "--scenes", "s", "--fit-command", 'x "'], "argument --fit-command: invalid split value: 'x \"'"),
])
def test_bad_flags_are_one_line_naming_the_flag_before_anything_runs(tmp_path, capsys, argv, message):
    assert main([*argv, "--out", str(tmp_path / "o")] if argv[0] == "run" and len(argv) > 1 else argv) == 2
    assert _error(capsys).startswith(message)
    assert not (tmp_path / "o").exists()


def test_help_and_the_module_entry_point(monkeypatch, tmp_path, capsys):
    assert main(["--help"]) == 0 and "usage: senerf-bench" in capsys.readouterr().out
    monkeypatch.setattr(sys, "argv", ["senerf-bench", "summarize", str(tmp_path / "none.jsonl")])
    with pytest.raises(SystemExit) as info:
        runpy.run_module("senerf.bench", run_name="__main__")
    assert info.value.code == 2 and _error(capsys) == f"{tmp_path / 'none.jsonl'}: results file not found"


def test_missing_scenes_and_folders_that_are_no_scene_are_refused(blender_factory, tmp_path, capsys):
    assert main(["run", "--scenes", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert _error(capsys) == f"{tmp_path / 'missing'}: scene folder not found"
    assert main(["run", "--scenes", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert _error(capsys).startswith(f"{tmp_path}: not a Blender (transforms_train.json), LLFF (poses_bounds.npy)")
    small = blender_factory(tmp_path, name="lego400", side=400)
    assert main(["run", "--scenes", str(small), "--protocols", "synthetic-extreme3@800", "--out",
                 str(tmp_path / "o"), "--dry-run"]) == 2
    assert _error(capsys).startswith(f"{small}: protocol: images of 400x400 cannot be downscaled to 800x800")
    assert not (tmp_path / "o").exists()
    # a dry run on a machine without the data lists the fits with the factors of original-size data
    assert main(["run", "--scenes", str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--dry-run"]) == 0
    assert "--protocol extreme --downscale 8" in capsys.readouterr().out


def test_a_results_file_that_is_not_one_is_neither_read_nor_appended_to(blender_scene, fake_fit_command, tmp_path,
                                                                         capsys, ok_line):
    readme = tmp_path / "README.md"
    readme.write_text("# my notes\n\nsome text\n")
    run = ["run", "--scenes", str(blender_scene), "--methods", "baseline", "--fit-command",
           shlex.join(fake_fit_command), "--out", str(tmp_path / "bench"), "--results", str(readme)]
    for argv in (run, run + ["--dry-run"], ["summarize", str(readme)], ["report", str(readme)], ["plot", str(readme)]):
        assert main(argv) == 2, argv
        assert _error(capsys).startswith(f"{readme}: not a senerf-bench results file (2 line(s), none a results line; "
                                         "line 1: not JSON)")
        assert readme.read_text() == "# my notes\n\nsome text\n" and not (tmp_path / "bench").exists()
    # some unreadable lines (a torn one, a hand edit): a warning naming the first, and the rest is used
    results = tmp_path / "r.jsonl"
    torn = '{"run_key": "x\n'
    results.write_text(json.dumps(ok_line()) + "\n" + json.dumps(ok_line(run_key="k2", seed="1")) + "\n" + torn)
    assert main(["summarize", str(results)]) == 0
    captured = capsys.readouterr()
    assert "20.00 (n=1)" in captured.out and captured.err == (
        f"senerf-bench: warning: skipped 2 line(s) that are not results lines in {results} (line 2: seed: missing or "
        "not of type int)\n")
    assert main(["summarize", str(tmp_path / "empty.jsonl")]) == 2            # missing
    (tmp_path / "empty.jsonl").write_text("")
    assert main(["summarize", str(tmp_path / "empty.jsonl")]) == 0            # an empty benchmark


def test_outputs_that_cannot_be_written_are_refused_naming_the_flag(blender_scene, fake_fit_command, tmp_path,
                                                                    capsys, ok_line):
    a_file = tmp_path / "afile"
    a_file.write_text("mine")
    results = tmp_path / "results.jsonl"
    results.write_text(json.dumps(ok_line()) + "\n")
    run = ["run", "--scenes", str(blender_scene), "--methods", "baseline", "--fit-command",
           shlex.join(fake_fit_command)]
    for flags, flag in ((["--out", str(a_file)], "--out"), (["--out", "/proc/senerf-bench-test"], "--out"),
                        (["--out", str(tmp_path / "b"), "--results", str(tmp_path)], "--results"),
                        (["--out", str(tmp_path / "b"), "--results", str(a_file / "r.jsonl")], "--results")):
        assert main([*run, *flags]) == 2, flags
        assert _error(capsys).endswith(f"; choose another {flag}"), flags
        assert not list(tmp_path.glob("b/runs/*")), flags      # no fit ran
    for argv, flag in ((["report", str(results), "--out", str(tmp_path)], "--out"),
                       (["report", str(results), "--out", "/proc/x.md"], "--out"),
                       (["report", str(results), "--into", str(a_file / "x.md")], "--into"),
                       (["plot", str(results), "--out-dir", str(a_file)], "--out-dir"),
                       (["plot", str(results), "--out-dir", "/proc/senerf-bench-test"], "--out-dir")):
        assert main(argv) == 2, argv
        assert _error(capsys).endswith(f"; choose another {flag}"), argv
    assert main(["report", str(results), "--out", str(results)]) == 2      # the results it reads
    assert _error(capsys) == f"{results}: is {results}, which this command reads; choose another --out"
    assert a_file.read_text() == "mine" and results.read_text() == json.dumps(ok_line()) + "\n"


def test_nothing_to_report_on_or_plot(tmp_path, capsys, ok_line):
    results = tmp_path / "r.jsonl"
    results.write_text(json.dumps({"run_key": "k", "status": "failed", "error": "x"}) + "\n")
    assert main(["plot", str(results), "--out-dir", str(tmp_path / "plots")]) == 2
    assert _error(capsys) == f"{results}: no finished runs to plot" and not (tmp_path / "plots").exists()
    results.write_text(json.dumps(ok_line(protocol="p", run_key="k7")) + "\n")   # a protocol this version lacks
    assert main(["report", str(results)]) == 2
    assert _error(capsys).startswith(f"{results}: not a senerf-bench results file (1 line(s), none a results line; "
                                     "line 1: protocol: unknown protocol 'p'")


def test_a_local_cuda_run_without_a_gpu_is_refused_before_anything_runs(blender_scene, fake_fit_command, tmp_path,
                                                                        capsys):
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    out = tmp_path / "b"
    assert main(_run_args(blender_scene, out, fake_fit_command, "--device", "cuda")) == 2
    assert "--device: CUDA requested but torch sees no GPU" in _error(capsys)
    assert not (out / "results.jsonl").exists()


def test_without_ray_installed_the_error_names_ray_address(monkeypatch, blender_scene, fake_fit_command, tmp_path,
                                                           capsys):
    monkeypatch.setitem(sys.modules, "ray", None)      # "import ray" raises ImportError
    assert main(_run_args(blender_scene, tmp_path / "b", fake_fit_command, "--ray-address", "auto")) == 2
    assert _error(capsys) == "--ray-address: Ray is not installed: pip install 'senerf[cluster]' (ray>=2.9)"
    assert not list((tmp_path / "b" / "runs").iterdir())   # no fit started


def test_an_interrupt_exits_130_at_once_naming_the_results_file(monkeypatch, blender_scene, fake_fit_command,
                                                                tmp_path, capsys):
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    exits = []

    def fake_exit(code):
        exits.append(code)
        raise SystemExit(code)
    monkeypatch.setattr(cli, "run_benchmark", interrupted)
    monkeypatch.setattr(cli.os, "_exit", fake_exit)
    out = tmp_path / "b"
    assert main(_run_args(blender_scene, out, fake_fit_command)) == 130 and exits == [130]
    assert capsys.readouterr().err == (f"senerf-bench: interrupted; finished runs are in {out / 'results.jsonl'}, "
                                       "rerun to resume\n")


def test_suite_estimates_runs_every_scene_at_hand_and_resumes(data_tree, fake_fit_command, tmp_path, capsys):
    out = tmp_path / "suite"
    args = ["suite", "--data", str(data_tree), "--out", str(out), "--fit-command", shlex.join(fake_fit_command)]
    assert main([*args, "--dry-run"]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert lines[:5] == ["# estimate: 12 runs to run (0 already finished)",
                         "#   synthetic-extreme3@100 senerf fast K=1: 6 runs x ~89 s (default) = 9 min",
                         "#   llff3@504x378 senerf fast K=1: 3 runs x ~555 s (default) = 28 min",
                         "#   dtu3@192 senerf fast K=1: 3 runs x ~146 s (default) = 7 min",
                         "# total ~44 min of fitting"]
    assert lines[5] == "# 12 runs: 0 already finished, 12 to run"
    fits = [ln for ln in lines if ln.startswith("senerf-fit ")]
    assert len(fits) == 12 and sum("--protocol dtu --n-views 3 --downscale 2 " in f for f in fits) == 3
    assert "mine: left out, no published Extreme views" in captured.err and not (out / "results.jsonl").exists()

    assert main([*args, "--workers", "2"]) == 0
    records, _ = load_results(out / "results.jsonl")
    assert {(r["scene"], r["protocol"]) for r in records} == {
        ("lego", "synthetic-extreme3@100"), ("mic", "synthetic-extreme3@100"), ("fern", "llff3@504x378"),
        ("scan24", "dtu3@192")}
    assert {r["seed"] for r in records} == {0, 1, 2} and all(r["status"] == "ok" for r in records)
    capsys.readouterr()
    assert main([*args, "--full", "--dry-run"]) == 0          # resumed: the default suite's runs are finished
    text = capsys.readouterr().out
    assert text.startswith("# estimate: 18 runs to run (12 already finished)\n") and "(measured)" not in text
    for protocol in ("synthetic-extreme3@200", "llff6@504x378", "llff9@504x378", "dtu6@192", "dtu9@192"):
        assert f"#   {protocol} senerf fast K=1: " in text, protocol
    assert main([*args, "--seeds", "0", "1", "2", "3", "--dry-run"]) == 0
    assert "# 16 runs: 12 already finished, 4 to run" in capsys.readouterr().out


def test_suite_refuses_a_data_folder_without_scenes(tmp_path, capsys):
    assert main(["suite", "--data", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert _error(capsys) == f"{tmp_path}: --data: no scene folders in nerf_synthetic/, nerf_llff_data/ or dtu/"
    assert not (tmp_path / "o").exists()


def test_report_into_a_marked_section_and_figures_per_protocol(ok_line, tmp_path, capsys):
    results = tmp_path / "results.jsonl"
    lines = [ok_line(run_key=f"{scene}{seed}", scene=scene, protocol=protocol, method="senerf", seed=seed,
                     iterations=1, iteration=it, psnr=15.0 + seed + it)
             for scene, protocol in (("lego", "synthetic-extreme3@100"), ("fern", "llff3@504x378"))
             for seed in (0, 1) for it in (0, 1)]
    results.write_text("".join(json.dumps(line) + "\n" for line in lines))
    doc = tmp_path / "README.md"
    doc.write_text(f"# senerf\n{REPORT_BEGIN}\nold\n{REPORT_END}\nrest\n")
    assert main(["report", str(results), "--into", str(doc), "--figures", str(tmp_path / "fig")]) == 0
    text = doc.read_text()
    assert text.startswith(f"# senerf\n{REPORT_BEGIN}\n") and text.endswith(f"{REPORT_END}\nrest\n")
    assert "| fern | 2 | 15.50 ± 0.71 | 16.50 ± 0.71 | +1.00 ± 0.00 (p 0.000) | 18.22 -> 18.83 (+0.61) |" in text
    assert "Final iteration" in text and "report " + str(results) + " --into" in text
    pngs = sorted(p.name for p in (tmp_path / "fig").glob("*.png"))
    assert pngs == ["paper_llff3_at_504x378_fast_K1.png", "paper_synthetic-extreme3_at_100_fast_K1.png"]
    assert all(iio.imread(tmp_path / "fig" / p).ndim == 3 for p in pngs)


def test_report_readme_form_replaces_the_marked_section(ok_line, tmp_path):
    results = tmp_path / "results.jsonl"
    lines = [ok_line(run_key=f"fern{seed}", scene="fern", protocol="llff3@504x378", method="senerf", seed=seed,
                     iterations=1, iteration=it, psnr=15.0 + seed + it) for seed in (0, 1) for it in (0, 1)]
    results.write_text("".join(json.dumps(line) + "\n" for line in lines))
    doc = tmp_path / "README.md"
    doc.write_text(f"# senerf\n{REPORT_BEGIN}\nold\n{REPORT_END}\nrest\n")
    assert main(["report", str(results), "--readme", "--into", str(doc)]) == 0
    text = doc.read_text()
    assert "old" not in text and text.endswith(f"{REPORT_END}\nrest\n")
    assert "| llff3@504x378, fast K=1 | fern | 2 | 15.50 ± 0.71 | 16.50 ± 0.71 | +1.00 ± 0.00 (0.000) | " \
           "18.22 -> 18.83 |" in text
