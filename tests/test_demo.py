"""``senerf-fit --demo`` wiring: scene built once, both PSNRs and the output folder printed, resumable.

The full demo (fast preset) is timed in BENCHMARKS.md; here it runs with a few steps so it stays quick.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

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


def _scene_seed(scene_dir):
    return json.loads((scene_dir / "procedural.json").read_text())["camera_seed"]


def test_demo_scene_is_reused_or_rebuilt_whole(tmp_path):
    """The same seed reuses the scene; another seed, or a damaged procedural.json (unreadable, or JSON but
    not an object), rebuilds it; no build leaves a .scene-* temporary behind."""
    from senerf.demo import ensure_demo_scene

    scene = tmp_path / "demo_scene"
    assert ensure_demo_scene(scene, seed=0) == scene and _scene_seed(scene) == 0
    stamp = (scene / "transforms_train.json").stat().st_mtime_ns
    ensure_demo_scene(scene, seed=0)
    assert (scene / "transforms_train.json").stat().st_mtime_ns == stamp
    ensure_demo_scene(scene, seed=1)
    assert _scene_seed(scene) == 1
    for damaged in ("{ half written", "[]", "null"):  # JSON that is no object crashed it (a traceback) before
        (scene / "procedural.json").write_text(damaged)
        ensure_demo_scene(scene, seed=1)
        assert _scene_seed(scene) == 1
    assert len(json.loads((scene / "transforms_train.json").read_text())["frames"]) == 20
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo_scene"]


def test_an_interrupted_scene_build_leaves_nothing(tmp_path, monkeypatch):
    import senerf.procedural
    from senerf.demo import ensure_demo_scene

    def killed_halfway(out_dir, seed=0, overwrite=False):
        (out_dir / "train").mkdir(parents=True)
        (out_dir / "transforms_train.json").write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(senerf.procedural, "make_demo_scene", killed_halfway)
    with pytest.raises(KeyboardInterrupt):
        ensure_demo_scene(tmp_path / "out" / "demo_scene", seed=0)
    assert list((tmp_path / "out").iterdir()) == []  # no half scene, no temporary


def test_overwrite_puts_the_demo_beside_a_users_files(tmp_path):
    from senerf.demo import _check_demo_folder
    from senerf.errors import InputError

    user = tmp_path / "user"
    (user / "fit").mkdir(parents=True)
    (user / "b.txt").write_text("mine")
    (user / "a.txt").write_text("mine")
    with pytest.raises(InputError, match=r"it holds a\.txt\); use --overwrite"):
        _check_demo_folder(user, overwrite=False)
    _check_demo_folder(user, overwrite=True)
    _check_demo_folder(tmp_path / "absent", overwrite=False)


def test_demo_hands_its_own_choices_and_the_users_to_the_fit(tmp_path, monkeypatch, capsys):
    """run_demo's call of senerf-fit (stubbed here: it records its arguments and writes a metrics.json):
    the demo's scene, views and preset; the user's seed, overwrite, quiet, steps, batch rays and threads; the
    default --out runs/demo; then both PSNRs of the metrics and their difference."""
    import senerf.cli
    from senerf.demo import run_demo

    calls = []

    def fit(argv):
        calls.append(senerf.cli.build_parser().parse_args(argv))
        iterations = [{"iteration": 0, "psnr": 20.0}, {"iteration": 1, "psnr": 21.5}, {"iteration": 2, "psnr": 23.25}]
        (calls[-1].out / "metrics.json").parent.mkdir(parents=True, exist_ok=True)
        (calls[-1].out / "metrics.json").write_text(json.dumps({"iterations": iterations, "seconds_total": 12.4}))
        return status

    monkeypatch.setattr(senerf.cli, "main", fit)
    monkeypatch.chdir(tmp_path)
    argv = ["--demo", "--seed", "7", "--overwrite", "--quiet", "--steps", "30", "--threads", "1"]
    status = 0
    assert run_demo(senerf.cli.build_parser().parse_args(argv), argv) == 0
    demo = tmp_path.resolve() / "runs" / "demo"
    (got,) = calls
    assert (Path(got.scene).resolve(), got.out.resolve()) == (demo / "demo_scene", demo / "fit")
    assert (got.views, got.preset) == (list(DEMO_FEWSHOT_VIEWS), "fast")
    assert (got.seed, got.overwrite, got.quiet, got.steps, got.batch_rays, got.threads) == (7, True, True, 30, None, 1)
    assert _scene_seed(demo / "demo_scene") == 7
    text = capsys.readouterr().out
    assert ("baseline (iteration 0) test PSNR 20.00 dB; SE-NeRF (iteration 2) test PSNR 23.25 dB (+3.25 dB); 12 s"
            in text)
    status = 1  # a failed fit: its status, and no PSNR line
    argv = ["--demo", "--seed", "7", "--batch-rays", "64"]
    assert run_demo(senerf.cli.build_parser().parse_args(argv), argv) == 1
    assert (calls[-1].overwrite, calls[-1].quiet, calls[-1].steps, calls[-1].batch_rays, calls[-1].threads) == (
        False, False, None, 64, None)
    assert "PSNR" not in capsys.readouterr().out


def test_another_seed_is_refused_before_the_scene_is_redrawn(tmp_path, capsys, monkeypatch):
    # the scene was redrawn for the new seed, then senerf-fit refused the run: the earlier fit's photos had
    # changed under it (so at 908b324)
    from senerf import demo

    out = tmp_path / "demo"
    (out / "demo_scene").mkdir(parents=True)
    marker = out / "demo_scene" / "procedural.json"
    marker.write_text(json.dumps({"camera_seed": 0}))
    (out / "fit").mkdir()
    (out / "fit" / "run.json").write_text("{}")
    drawn = []
    monkeypatch.setattr(demo, "ensure_demo_scene", lambda scene_dir, seed=0: drawn.append(seed) or scene_dir)
    monkeypatch.setattr("senerf.cli.main", lambda argv: 0 if drawn else 1)   # reached only past the checks
    assert main(["--demo", "--out", str(out), "--seed", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"senerf-fit: error: {out / 'fit'}: holds a different run (train.seed: 0 in the folder, 1 now; "
                   f"the demo's scene is drawn from the seed too); use --overwrite or another --out")
    assert drawn == [] and json.loads(marker.read_text()) == {"camera_seed": 0}
