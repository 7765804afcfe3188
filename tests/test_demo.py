"""``senerf-fit --demo`` wiring: scene built once, both PSNRs and the output folder printed, resumable.

The full demo (fast preset) is timed in BENCHMARKS.md; here it runs with a few steps so it stays quick.
"""

from __future__ import annotations

import json
import re

from senerf.cli import main
from senerf.procedural import DEMO_FEWSHOT_VIEWS
from senerf.train import PRESETS


def test_demo_runs_baseline_and_senerf_and_prints_both(tmp_path, capsys):
    out = tmp_path / "demo"
    argv = ["--demo", "--out", str(out), "--steps", "30", "--batch-rays", "256", "--quiet"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert re.search(r"baseline \(iteration 0\) test PSNR \d+\.\d+ dB; SE-NeRF \(iteration \d+\) test PSNR", text)
    assert str((out / "fit").resolve()) in text
    metrics = json.loads((out / "fit" / "metrics.json").read_text())
    assert metrics["train_views"] == list(DEMO_FEWSHOT_VIEWS)
    iterations = [it["iteration"] for it in metrics["iterations"]]
    # the baseline teacher, then the fast preset's self-training iterations (--iterations not given)
    assert iterations == list(range(1 + PRESETS["fast"]["iterations"]))
    assert (out / "demo_scene" / "transforms_train.json").is_file()
    assert not [p for p in out.iterdir() if p.name.startswith(".scene-")]  # no half-built scene left

    # the same command again reuses the scene and resumes the finished run
    scene_mtime = (out / "demo_scene" / "transforms_train.json").stat().st_mtime_ns
    assert main(argv) == 0
    assert (out / "demo_scene" / "transforms_train.json").stat().st_mtime_ns == scene_mtime
    assert json.loads((out / "fit" / "metrics.json").read_text())["iterations"] == metrics["iterations"]


def test_demo_refuses_a_file_as_out(tmp_path, capsys):
    from senerf.cli import main

    a_file = tmp_path / "a_file"
    a_file.write_text("mine")
    assert main(["--demo", "--out", str(a_file), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"senerf-fit: error: {a_file}: exists and is not a folder; choose another --out"]
    assert a_file.read_text() == "mine"


def test_demo_refuses_options_it_would_ignore_and_a_users_folder(tmp_path, capsys):
    # Before, --demo ignored --iterations / --views / --preset without a word and wrote demo_scene/ and
    # fit/ beside a user's files (so at 06e386d).
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    for extra, flag in ((["--iterations", "0"], "--iterations"), (["--views", "5,6"], "--views"),
                        (["--preset", "fast"], "--preset"), ([str(tmp_path)], "SCENE_DIR"),
                        (["--preset", "balanced"], "--preset"),            # the default, given: still ignored
                        (["--threshold", "adaptive"], "--threshold")):
        assert main(["--demo", "--out", str(tmp_path / "d"), "--quiet", *extra]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line.startswith(f"senerf-fit: error: {flag}: --demo chooses its own") and f"drop {flag}" in line
    assert main(["--demo", "--out", str(user), "--quiet"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "not a senerf-fit --demo output folder (it holds notes.txt)" in line
    (user / "demo_scene").mkdir()
    assert main(["--demo", "--out", str(user), "--quiet", "--overwrite"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "holds a demo_scene that senerf-fit --demo did not write" in line
    assert sorted(p.name for p in user.iterdir()) == ["demo_scene", "notes.txt"] and not (tmp_path / "d").exists()
    # hidden leftovers (a killed scene build's .scene-* folder, .DS_Store) do not make a folder foreign
    from senerf.demo import _check_demo_folder

    leftovers = tmp_path / "demo_out"
    (leftovers / ".scene-abc").mkdir(parents=True)
    (leftovers / ".DS_Store").write_text("")
    _check_demo_folder(leftovers, overwrite=False)
