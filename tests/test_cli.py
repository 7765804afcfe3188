"""The senerf-fit command (senerf/cli.py): bad input, a tiny end-to-end fit, resume and overwrite."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys

import pytest

from senerf.cli import main, parse_views
from senerf.errors import InputError

SMALL = ["--iterations", "0", "--steps", "24", "--batch-rays", "128", "--samples", "12", "--resolution", "8",
         "--quiet"]
TINY = ["--protocol", "all", *SMALL]


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    from senerf.procedural.export import export_blender_scene

    return export_blender_scene(tmp_path_factory.mktemp("scene") / "tiny", n_train=5, n_val=0, n_test=2,
                                width=16, height=16, seed=0)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("senerf-fit: error: ") and "Traceback" not in err
    return lines[0]


def test_parse_views():
    assert parse_views("0, 1,51") == [0, 1, 51]
    for bad in ("", "0,,1", "a,b", "1.5"):
        with pytest.raises(InputError):
            parse_views(bad)


@pytest.mark.parametrize("extra, needle", [
    (["--views", "a,b"], "argument --views: expected comma-separated integers like 0,1,51, got 'a,b'"),
    (["--steps", "0"], "argument --steps: must be >= 1, got 0"),
    (["--steps", "x"], "argument --steps: expected an integer, got 'x'"),
    (["--pseudo-views", "0"], "argument --pseudo-views: must be >= 1, got 0"),
    (["--empty-opacity", "nan"], "argument --empty-opacity: expected a finite number >= 0 and <= 0.5, got 'nan'"),
    (["--empty-opacity", "0.7"], "argument --empty-opacity: expected a finite number >= 0 and <= 0.5, got '0.7'"),
    (["--bogus"], "unrecognized"),
    (["--views", "0,999"], "out of range"),
    (["--views", "1,1"], "duplicate"),
    (["--downscale", "0.5"], "argument --downscale: expected a finite number >= 1, got '0.5'"),
    (["--aabb", "0"], "argument --aabb: expected a finite number > 0, got '0'"),
    (["--device", "tpu"], "--device"),
    (["--threads", "0"], "argument --threads: must be >= 1 and <= 1024, got 0"),
    (["--threads", "1025"], "argument --threads: must be >= 1 and <= 1024, got 1025"),
    (["--protocol", "llff", "--views", "0"], "--views"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tiny_scene, tmp_path, capsys, extra, needle):
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *SMALL, *extra]) == 2
    assert needle in _one_error_line(capsys)
    assert not out.exists()


def test_missing_scene_via_subprocess_has_no_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "senerf.cli", str(tmp_path / "nope"), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert proc.stderr.startswith("senerf-fit: error: ") and "not found" in proc.stderr
    assert not (tmp_path / "o").exists()


def test_tiny_end_to_end_fit_resume_and_overwrite(tiny_scene, tmp_path, capsys):
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) == {"senerf_version", "command", "config", "scene", "train_views", "test_views",
                            "train_images", "test_images", "resolution", "iterations", "seconds_total"}
    # which photo each view index stands for (train split first, then test, in file order)
    assert metrics["train_images"] == [f"train/r_{k}.png" for k in range(5)]
    assert metrics["test_images"] == ["test/r_0.png", "test/r_1.png"] and metrics["test_views"] == [5, 6]
    assert metrics["resolution"] == [16, 16] and len(metrics["train_views"]) == 5 and len(metrics["test_views"]) == 2
    assert metrics["command"][0] == "senerf-fit" and metrics["config"]["train"]["steps"] == 24
    (it,) = metrics["iterations"]
    assert set(it) == {"iteration", "psnr", "ssim", "lpips", "avg", "reliable_fraction", "seconds", "per_view",
                       "host"}
    assert it["host"]["device"] == "cpu" and it["host"]["threads"] == __import__("torch").get_num_threads()
    assert it["iteration"] == 0 and it["lpips"] == "unavailable" and it["avg"] == "unavailable"
    assert it["reliable_fraction"] is None and len(it["per_view"]["psnr"]) == 2
    assert it["psnr"] == pytest.approx(sum(it["per_view"]["psnr"]) / 2)
    for k in range(2):
        assert (out / "iter_0" / "test" / f"rgb_{k:03d}.png").is_file()
        assert (out / "iter_0" / "test" / f"depth_{k:03d}.png").is_file()
    assert (out / "checkpoints" / "iter_0_train.pt").is_file()
    assert (out / "summary.png").is_file()
    printed = capsys.readouterr().out
    assert printed.startswith(f"senerf-fit: reading {tiny_scene} (blender, downscale 1)\n")   # before the photos load
    assert f"summary figure in {out / 'summary.png'}" in printed
    assert f"to fly around the fitted scene: senerf-render {out}\n" in printed

    # the same command resumes its own (finished) run: same result, no retraining
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    again = json.loads((out / "metrics.json").read_text())
    assert again["iterations"][0]["per_view"] == it["per_view"]

    # a folder extended by self-training keeps its rows when the baseline-only command is run again
    # (before, metrics.json was rewritten with iteration 0 alone, so at 06e386d)
    extended = dict(again, iterations=again["iterations"] + [dict(again["iterations"][0], iteration=1)])
    (out / "metrics.json").write_text(json.dumps(extended))
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    assert json.loads((out / "metrics.json").read_text()) == extended
    assert "iteration 0 is already done" in capsys.readouterr().out
    (out / "metrics.json").write_text(json.dumps(again))

    # a different run is refused, without touching the folder ...
    capsys.readouterr()
    before = (out / "metrics.json").read_bytes()
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--seed", "1"]) == 2
    assert "different run (train.seed: 0 in the folder, 1 now)" in _one_error_line(capsys)
    assert (out / "metrics.json").read_bytes() == before
    # ... and a folder whose run.json senerf-fit did not write is refused even with --overwrite
    run_json = (out / "run.json").read_bytes()
    for foreign in ("{not json", '{"name": "my experiment"}'):
        (out / "run.json").write_text(foreign)
        assert main([str(tiny_scene), "--out", str(out), *TINY, "--overwrite"]) == 2
        assert "holds a run.json that senerf-fit did not write" in _one_error_line(capsys)
        assert (out / "run.json").read_text() == foreign and (out / "metrics.json").read_bytes() == before
    (out / "run.json").write_bytes(run_json)
    # ... unless --overwrite, which says what it removed
    capsys.readouterr()
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--seed", "1", "--overwrite"]) == 0
    assert (f"senerf-fit: --overwrite: removed the earlier run's checkpoints/, metrics.json, summary.png, run.json, "
            f"iter_0/ from {out}\n") in capsys.readouterr().out
    assert json.loads((out / "metrics.json").read_text())["config"]["train"]["seed"] == 1


def test_threads_sets_torchs_thread_count_and_is_not_part_of_the_run(tiny_scene, tmp_path, capsys):
    """--threads N is torch.set_num_threads(N) before any work: the row's host records it, and the same run
    made with another count (or torch's default) is the same run (a resume, not a refusal)."""
    import torch

    before = torch.get_num_threads()
    out = tmp_path / "run"
    try:
        torch.set_num_threads(2)
        assert main([str(tiny_scene), "--out", str(out), *TINY, "--threads", "1"]) == 0
        assert torch.get_num_threads() == 1
        (row,) = json.loads((out / "metrics.json").read_text())["iterations"]
        assert row["host"]["threads"] == 1
        torch.set_num_threads(2)
        assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
        assert "iteration 0 is already done" in capsys.readouterr().out
    finally:
        torch.set_num_threads(before)


def test_a_scene_whose_files_changed_is_not_resumed(tiny_scene, tmp_path, capsys):
    # Before, run.json held the scene's path, not what its files held: a photo or pose edited between a fit and
    # its resume was trained on beside the finished iterations' old one (so at ce8cdd5).
    import shutil

    scene = shutil.copytree(tiny_scene, tmp_path / "scene")
    out = tmp_path / "run"
    argv = [str(scene), "--out", str(out), *TINY]
    assert main(argv) == 0
    run_json = json.loads((out / "run.json").read_text())
    assert sorted(run_json["scene_files"]) == [*(f"test/r_{k}.png" for k in range(2)),
                                              "train/r_0.png", "train/r_1.png", "train/r_2.png", "train/r_3.png",
                                              "train/r_4.png", "transforms_test.json", "transforms_train.json"]
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    photo, poses = scene / "train" / "r_3.png", scene / "transforms_train.json"
    for edited, name in ((photo, "train/r_3.png"), (poses, "transforms_train.json")):
        original = edited.read_bytes()
        edited.write_bytes(original + b"\0" if edited.suffix == ".png" else original.replace(b"{", b"{ ", 1))
        capsys.readouterr()
        assert main(argv) == 2
        assert f"holds a different run (scene files differ: {name} changed); use --overwrite" in _one_error_line(capsys)
        assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before   # nothing touched
        edited.write_bytes(original)
    assert main(argv) == 0   # the files as they were: the same run, resumed
    # a run.json from before the files were recorded cannot tell, so it resumes (and records them from now on)
    (out / "run.json").write_text(json.dumps({k: v for k, v in run_json.items() if k != "scene_files"}))
    photo.write_bytes(photo.read_bytes() + b"\0")
    assert main(argv) == 0
    assert json.loads((out / "run.json").read_text())["scene_files"]["train/r_3.png"] != run_json["scene_files"][
        "train/r_3.png"]
    # with --overwrite a changed scene starts over
    (out / "metrics.json").write_bytes(before[out / "metrics.json"])
    poses.write_bytes(poses.read_bytes().replace(b"{", b"{ ", 1))
    assert main([*argv, "--overwrite"]) == 0
    from senerf.data import load_scene, scene_file_digests

    assert json.loads((out / "run.json").read_text())["scene_files"] == scene_file_digests(load_scene(scene))


def test_only_the_files_a_run_reads_are_compared_and_oracle_runs_extend(tiny_scene, tmp_path, capsys):
    # The review of 7745791: every resume test used `--protocol all`, so nothing showed that a photo the run
    # does not read may change; and an oracle run started with --iterations 0 hashed only the training and
    # test photos, then refused its own extension ("test/r_0.png is read now, not then").
    import shutil

    scene = shutil.copytree(tiny_scene, tmp_path / "scene")
    argv = [str(scene), "--out", str(tmp_path / "o"), *SMALL, "--views", "0,1,3"]
    assert main(argv) == 0
    recorded = json.loads((tmp_path / "o" / "run.json").read_text())["scene_files"]
    assert sorted(recorded) == ["test/r_0.png", "test/r_1.png", "train/r_0.png", "train/r_1.png", "train/r_3.png",
                                "transforms_test.json", "transforms_train.json"]
    unused = scene / "train" / "r_2.png"
    unused.write_bytes(unused.read_bytes() + b"\0")
    assert main(argv) == 0   # not a photo this run reads
    oracle = [str(scene), "--out", str(tmp_path / "oracle"), *SMALL, "--views", "0,1", "--reliability", "oracle",
              "--features", "daisy", "--pseudo-views", "1"]
    assert main([*oracle, "--iterations", "0"]) == 0
    assert len(json.loads((tmp_path / "oracle" / "run.json").read_text())["scene_files"]) == 2 + 7   # every photo
    assert main([*oracle, "--iterations", "1"]) == 0
    assert [it["iteration"] for it in json.loads((tmp_path / "oracle" / "metrics.json").read_text())["iterations"]] \
        == [0, 1]


def test_overwrite_never_deletes_what_senerf_fit_did_not_make(tiny_scene, tmp_path, capsys):
    # A user's folder: no run.json of ours, but a metrics.json and a checkpoints folder of their own.
    # Before, a foreign run.json counted as "a different run" and --overwrite deleted checkpoints/ (so at 71d19d4).
    out = tmp_path / "proj"
    (out / "checkpoints").mkdir(parents=True)
    (out / "checkpoints" / "my_model.ckpt").write_bytes(b"mine")
    (out / "metrics.json").write_text("{}")
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--overwrite"]) == 2
    assert "is not a senerf-fit output folder but holds checkpoints" in _one_error_line(capsys)
    (out / "run.json").write_text('{"name": "my experiment"}')
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--overwrite"]) == 2
    assert "did not write" in _one_error_line(capsys)
    assert (out / "checkpoints" / "my_model.ckpt").read_bytes() == b"mine"
    assert sorted(p.name for p in out.iterdir()) == ["checkpoints", "metrics.json", "run.json"]
    # other files are fine with --overwrite: the run goes beside them
    other = tmp_path / "notes"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    assert main([str(tiny_scene), "--out", str(other), *TINY]) == 2
    assert "not a senerf-fit output folder; use --overwrite" in _one_error_line(capsys)
    # a user's own summary.png is a name a run writes: refused, even with --overwrite
    figure = tmp_path / "figs"
    figure.mkdir()
    (figure / "summary.png").write_bytes(b"my figure")
    assert main([str(tiny_scene), "--out", str(figure), *TINY, "--overwrite"]) == 2
    assert "holds summary.png, which a run would overwrite" in _one_error_line(capsys)
    assert (figure / "summary.png").read_bytes() == b"my figure"


def test_an_out_that_cannot_be_created_is_refused_before_any_work(tiny_scene, tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    assert main([str(tiny_scene), "--out", str(tmp_path / "afile" / "sub"), *TINY]) == 2
    line = _one_error_line(capsys)
    assert "--out" in line and "cannot be created" in line and "afile is not a folder" in line
    assert (tmp_path / "afile").read_text() == "x"


@pytest.mark.parametrize("flags, needle", [
    (["--resolution", "1"], "argument --resolution: must be >= 2, got 1"),
    (["--resolution", "100000"], "--resolution: 100000 needs"),
    # one step's MLP weights or activations beyond the machine's memory: a torch allocator traceback, or the
    # kernel's OOM killer, after run.json was written (so before 2026-11-23)
    (["--hidden", "100000"], "--hidden: 100000 needs 149.1 GiB for the MLPs and their optimiser state, more than"),
    (["--batch-rays", "100000000"], "--batch-rays: 100000000 rays of 12 samples need up to "),
    (["--seed", "99999999999999999999"], "argument --seed: must be >= 0 and <= 9223372036854775807"),
    (["--downscale", "2"],
     "--downscale: the images are 8x8 at downscale 2; the evaluation (SSIM) needs at least 11x11"),
    (["--reliability", "oracle", "--iterations", "1", "--features", "daisy"],  # protocol all: nothing held out
     "--reliability: --reliability oracle needs held-out views (neither training nor test)"),
])
def test_bad_model_and_size_settings_are_refused_before_anything_is_written(tiny_scene, tmp_path, capsys, flags,
                                                                           needle):
    # Before, each of these crashed with a traceback after run.json was written, and that run.json then
    # refused the corrected command (so at 71d19d4); the oracle's check came after the baseline's training.
    out = tmp_path / "o"
    assert main([str(tiny_scene), "--out", str(out), *TINY, *flags]) == 2
    assert needle in _one_error_line(capsys)
    assert not out.exists()


def test_a_step_that_cannot_fit_is_refused_before_an_overwrite_removes_the_old_run(tiny_scene, tmp_path, capsys,
                                                                                  monkeypatch):
    # Catches: --overwrite removing a finished run before a fit that then failed on a size knowable up front (so
    # before 2026-11-23); and the step check's bound: on a machine of 1 GiB, 2 x 4 x 128 x 12 x (3 x 32 + 16 x 2)
    # bytes = 1.5 MiB a step fit, 300000 rays (3.4 GiB) do not.
    import senerf.cli as cli_mod

    out = tmp_path / "o"
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    before = sorted(p.name for p in out.iterdir())
    monkeypatch.setattr(cli_mod, "physical_memory_bytes", lambda: 2**30)
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--seed", "3", "--overwrite", "--batch-rays",
                 "300000"]) == 2
    assert _one_error_line(capsys).startswith("senerf-fit: error: --batch-rays: 300000 rays of 12 samples need up "
                                              "to 3.4 GiB a step, more than this machine's 1 GiB")
    assert sorted(p.name for p in out.iterdir()) == before and (out / "metrics.json").is_file()
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0   # the default batch fits the same 1 GiB


@pytest.mark.parametrize("flags, needle", [
    (["--hidden", "64"], "--hidden: sets the K-Planes field; the NeRF field has no such setting (its MLP is fixed: "
                         "4 layers x 128, 10 frequency bands"),
    (["--resolution", "32"], "--resolution: sets the K-Planes field; the NeRF field has no such setting"),
])
def test_k_planes_settings_with_the_nerf_field_are_refused(tiny_scene, tmp_path, capsys, flags, needle):
    # They were ignored without a word (so at 64a97d5).
    out = tmp_path / "o"
    small = [a for a in SMALL if a not in ("--resolution", "8")]
    assert main([str(tiny_scene), "--out", str(out), "--protocol", "all", *small, "--field", "nerf", *flags]) == 2
    assert needle in _one_error_line(capsys)
    assert not out.exists()


def test_self_training_on_one_view_is_refused_before_anything_is_written(tiny_scene, tmp_path, capsys):
    # It crashed after the teacher had trained ("internal error": the pseudo views had no centre; so at d0f9581).
    out = tmp_path / "o"
    small = [a for a in SMALL if a not in ("--iterations", "0")]
    assert main([str(tiny_scene), "--out", str(out), *small, "--views", "0", "--iterations", "1",
                 "--features", "daisy"]) == 2
    line = _one_error_line(capsys)
    assert line.startswith(f"senerf-fit: error: {tiny_scene}: --views: self-training turns its pseudo views about")
    assert "1 training view has no such point" in line and "or fit the baseline alone (--iterations 0)" in line
    assert not out.exists()
    assert main([str(tiny_scene), "--out", str(out), *SMALL, "--views", "0"]) == 0   # the baseline alone fits


def test_reliability_features_too_large_for_the_machine_are_refused_before_anything_is_written(
        tiny_scene, tmp_path, capsys, monkeypatch):
    # fern at 2016x1512 (VGG-19: 10.9 GiB a view) trained its teacher and rendered for an hour on 2 cores, then
    # ran out of memory in its first pseudo view's features (an audit, so at 102f604)
    # (the limit itself: tests/selftrain/test_features.py)
    import os

    real = os.sysconf
    monkeypatch.setattr(os, "sysconf", lambda name: 256 if name == "SC_PHYS_PAGES" else real(name))   # 1 MiB "RAM"
    out = tmp_path / "o"
    small = [a for a in SMALL if a not in ("--iterations", "0")]
    assert main([str(tiny_scene), "--out", str(out), *small, "--iterations", "1"]) == 2
    assert "--downscale: vgg19 reliability features of one" in _one_error_line(capsys)
    assert not out.exists()


@pytest.mark.parametrize("position, needle", [
    (0.0, "all stand at one camera centre"),     # a tripod pan: no parallax (math.log(0) crashed, so at 71d19d4)
    (1e300, "the cameras' box cannot be computed"),  # norms overflow
])
def test_cameras_without_a_usable_position_are_refused(tiny_scene, tmp_path, capsys, position, needle):
    import shutil as _shutil

    scene = tmp_path / "scene"
    _shutil.copytree(tiny_scene, scene)
    for split in ("train", "val", "test"):
        path = scene / f"transforms_{split}.json"
        if path.exists():
            meta = json.loads(path.read_text())
            for i, frame in enumerate(meta["frames"]):
                for row in range(3):
                    frame["transform_matrix"][row][3] = position * (1.0 + row + 0.1 * i)
            path.write_text(json.dumps(meta))
    out = tmp_path / "o"
    assert main([str(scene), "--out", str(out), *TINY]) == 2
    line = _one_error_line(capsys)
    assert needle in line and "camera positions" in line and str(scene) in line
    assert not out.exists()


def test_help_states_the_selftraining_defaults():
    from senerf.cli import (BATCH_EMPTY_DEFAULT, EMPTY_OPACITY_DEFAULT, OPACITY_THRESHOLD_DEFAULT,
                            PSEUDO_RANGE_DEFAULT, PSEUDO_RANGE_STEP_DEFAULT, PSEUDO_VIEWS_DEFAULT,
                            STUDENT_GRID_DEFAULT)
    from senerf.selftrain import SelfTrainConfig

    assert SelfTrainConfig().n_pseudo_per_input == PSEUDO_VIEWS_DEFAULT
    assert SelfTrainConfig().empty_opacity == EMPTY_OPACITY_DEFAULT
    assert SelfTrainConfig().opacity_threshold == OPACITY_THRESHOLD_DEFAULT
    assert SelfTrainConfig().pseudo_range_deg == PSEUDO_RANGE_DEFAULT
    assert SelfTrainConfig().pseudo_range_step_deg == PSEUDO_RANGE_STEP_DEFAULT
    assert SelfTrainConfig().batch_empty == BATCH_EMPTY_DEFAULT
    assert SelfTrainConfig().student_grid == STUDENT_GRID_DEFAULT


def test_preset_names_agree_across_the_cli_the_trainer_and_the_harness():
    from senerf.bench.specs import PRESETS as BENCH_PRESETS
    from senerf.cli import build_parser
    from senerf.train import PRESETS as TRAIN_PRESETS

    (action,) = [a for a in build_parser()._actions if a.dest == "preset"]
    assert tuple(action.choices) == tuple(TRAIN_PRESETS) == BENCH_PRESETS == ("fast", "balanced")


@pytest.mark.parametrize("flags, expected", [
    ([], {}),
    (["--pseudo-range", "15", "--pseudo-range-step", "20", "--empty-opacity", "0"],
     {"pseudo_range_deg": 15.0, "pseudo_range_step_deg": 20.0, "empty_opacity": 0.0}),
    (["--batch-empty", "256", "--student-grid", "none"], {"batch_empty": 256, "student_grid": "none"}),
    (["--pseudo-views", "32"], {"n_pseudo_per_input": 32}),
])
def test_selftraining_flags_reach_the_config(tiny_scene, tmp_path, monkeypatch, flags, expected):
    import senerf.cli as cli
    from senerf.selftrain import SelfTrainConfig

    seen = []

    def fake_run(scene, train_idx, test_idx, model, train_cfg, st_cfg, out, **kw):
        seen.append(st_cfg)
        return {"iterations": []}

    monkeypatch.setattr(cli, "_selftrain_available", lambda: ((SelfTrainConfig, fake_run), None))
    argv = [str(tiny_scene), "--out", str(tmp_path / "o"), *TINY, "--iterations", "2", *flags]
    assert main(argv) == 0
    (cfg,) = seen
    assert cfg.iterations == 2
    defaults = SelfTrainConfig()
    for field in ("pseudo_range_deg", "pseudo_range_step_deg", "empty_opacity", "batch_empty", "student_grid",
                  "n_pseudo_per_input"):
        assert getattr(cfg, field) == expected.get(field, getattr(defaults, field)), field
    assert cfg.pseudo_range(2) == cfg.pseudo_range_deg + cfg.pseudo_range_step_deg


def test_a_default_given_explicitly_resumes_the_same_run(tiny_scene, tmp_path, monkeypatch, capsys):
    # Before, `--empty-opacity 0.2` (the default) was "a different run (selftrain_flags.empty_opacity: null in
    # the folder, 0.2 now)" (so at 4f9d442).
    import senerf.cli as cli
    from senerf.selftrain import SelfTrainConfig

    monkeypatch.setattr(cli, "_selftrain_available",
                        lambda: ((SelfTrainConfig, lambda *a, **k: {"iterations": []}), None))
    argv = [str(tiny_scene), "--out", str(tmp_path / "o"), *TINY, "--iterations", "1"]
    assert main(argv) == 0
    for same in (["--empty-opacity", "0.2"], ["--pseudo-views", "8", "--student-grid", "teacher"], []):
        assert main(argv + same) == 0, same
    capsys.readouterr()
    assert main(argv + ["--pseudo-views", "9"]) == 2
    assert "different run (selftrain_flags.n_pseudo_per_input: absent in the folder, 9 now)" in _one_error_line(capsys)


def test_n_views_given_at_its_protocols_default_resumes_the_same_run(tiny_scene, tmp_path, capsys):
    # Before, `--n-views 3` with the spread protocol (whose default is 3) was "a different run (n_views: null
    # in the folder, 3 now)" (so at 7c49076).
    argv = [str(tiny_scene), "--out", str(tmp_path / "o"), "--protocol", "spread", *SMALL]
    assert main(argv) == 0
    assert main(argv + ["--n-views", "3"]) == 0
    capsys.readouterr()
    assert main(argv + ["--n-views", "2"]) == 2
    assert "different run (n_views: null in the folder, 2 now)" in _one_error_line(capsys)
    other = [str(tiny_scene), "--out", str(tmp_path / "p"), "--protocol", "spread", "--n-views", "3", *SMALL]
    assert main(other) == 0 and main(other[:5] + other[7:]) == 0   # the other way round too


def test_n_views_at_its_default_resumes_a_self_training_run(tiny_scene, tmp_path, capsys, monkeypatch):
    # Before, the teacher checkpoint's settings kept the raw count: "output folder holds a run with different
    # settings (config.n_views: null in the folder, 3 now)" (so at 5258768).
    import senerf.cli as cli
    import senerf.data.fewshot as fewshot

    flags = ["--protocol", "spread", *SMALL, "--iterations", "1", "--reliability", "oracle", "--pseudo-views", "1"]
    for i, (first, then) in enumerate(((["--n-views", "3"], []), ([], ["--n-views", "3"]))):
        out = ["--out", str(tmp_path / f"o{i}")]
        if i == 0:   # as senerf-fit recorded it before: the count as given, 3, in run.json and the checkpoints
            monkeypatch.setitem(fewshot.DEFAULT_N_VIEWS, "spread", 99)
        assert main([str(tiny_scene), *out, *flags, *first]) == 0
        monkeypatch.undo()
        assert main([str(tiny_scene), *out, *flags, *then]) == 0, capsys.readouterr().err
        assert "nothing to train" in capsys.readouterr().out
    assert json.loads((tmp_path / "o1" / "run.json").read_text())["n_views"] is None   # recorded as not given
    assert cli.main([str(tiny_scene), "--out", str(tmp_path / "o1"), *flags, "--n-views", "2"]) == 2


def test_out_the_scene_folder_itself_is_refused(tiny_scene, tmp_path, capsys):
    # Before, `--out SCENE --overwrite` wrote run.json, metrics.json, checkpoints/ and iter_0/ among the photos
    # (so at 7c49076).
    before = sorted(p.name for p in tiny_scene.iterdir())
    photos = sorted(p.name for p in (tiny_scene / "train").iterdir())
    for out, what in ((tiny_scene, "the scene folder"), (tiny_scene / "train" / "..", "the scene folder"),
                      (tiny_scene / "train", "a folder of the scene's photos")):
        assert main([str(tiny_scene), "--out", str(out), "--overwrite", *TINY]) == 2
        assert f"{out}: is {what}; choose another --out" in _one_error_line(capsys)
    assert sorted(p.name for p in tiny_scene.iterdir()) == before
    assert sorted(p.name for p in (tiny_scene / "train").iterdir()) == photos
    inside = tiny_scene / "fits" / "a"
    assert main([str(tiny_scene), "--out", str(inside), *TINY]) == 0
    shutil.rmtree(tiny_scene / "fits")
    loop = tmp_path / "loop"   # a link to itself: one line naming it (an internal error at 7e0bca1)
    loop.symlink_to(loop)
    assert main([str(tiny_scene), "--out", str(loop), *TINY]) == 2
    assert str(loop) in _one_error_line(capsys)


def test_out_a_folder_of_another_resolutions_photos_is_refused(tmp_path):
    # Catches: only the folders of the photos loaded this time checked (an LLFF fit at --downscale 2 reads
    # images_2/; --out SCENE/images --overwrite then put summary.png among the full-size photos; second review).
    from senerf.cli import _refuse_out_among_inputs

    scene = tmp_path / "fern"
    for name in ("images", "images_2", "images_8"):
        (scene / name).mkdir(parents=True)
        (scene / name / "a.png").write_bytes(b"")
    (scene / "fits").mkdir()
    used = [scene / "images_2" / "a.png"]
    for name in ("images", "images_2", "images_8"):
        with pytest.raises(InputError, match="is a folder of the scene's photos; choose another --out"):
            _refuse_out_among_inputs(scene / name, scene, used)
    with pytest.raises(InputError, match="is the scene folder"):
        _refuse_out_among_inputs(scene / "fits" / "..", scene, used)
    for fine in (scene / "fits", scene / "new", tmp_path):
        assert _refuse_out_among_inputs(fine, scene, used) is None


def test_negative_views_get_the_range_message_and_a_file_is_not_missing(tiny_scene, tmp_path, capsys):
    # `--views -1,0` gave argparse's "expected one argument" (so at ed16e9a)
    assert main([str(tiny_scene), "--out", str(tmp_path / "o"), *SMALL, "--views", "-1,0"]) == 2
    assert "--views: view index -1 out of range" in _one_error_line(capsys)
    # the scene's marker file names its folder (it said "scene folder not found"); another file is a file
    out = tmp_path / "o2"
    assert main([str(tiny_scene / "transforms_train.json"), "--out", str(out), *TINY]) == 0
    assert json.loads((out / "run.json").read_text())["scene_dir"] == str(tiny_scene.resolve())
    capsys.readouterr()
    assert main([str(out / "metrics.json"), "--out", str(tmp_path / "o3"), *TINY]) == 2
    assert "metrics.json: is a file; expected a scene folder" in _one_error_line(capsys)
    assert not (tmp_path / "o").exists() and not (tmp_path / "o3").exists()


@pytest.mark.parametrize("device", ["cuda:x", "cuda:", "cuda:01", "cuda:-1", "cudafoo", "CUDA", "cpu:0", "tpu"])
def test_malformed_devices_are_refused_by_name(device, monkeypatch):
    """Before, anything starting with 'cuda:' passed the check and torch raised at the first tensor, after
    run.json was written (so at 9bf94cf)."""
    import torch

    from senerf.cliargs import check_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)   # the name is wrong whatever the machine
    with pytest.raises(InputError, match=r"--device.*expected cpu, cuda or cuda:N"):
        check_device(device)


def test_cuda_ordinal_and_gpu_memory_are_checked_before_anything_is_written(tiny_scene, tmp_path, monkeypatch,
                                                                          capsys):
    import types

    import torch

    from senerf.cli import _check_model_fits
    from senerf.cliargs import check_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert check_device("cuda") == "cuda" and check_device("cuda:1") == "cuda:1"
    with pytest.raises(InputError, match=r"cuda:2 requested but torch sees 2 GPU\(s\) \(cuda:0 \.\.\. cuda:1\)"):
        check_device("cuda:2")
    # GPU memory: the planes (rows x features float32) times 9 against the card's total
    from senerf.fields.interp import plane_layout

    model = types.SimpleNamespace(field="kplanes", resolution=64, multires=(1, 2), n_features=16)
    _, rows = plane_layout((64, 128))
    table = rows * 16 * 4
    asked = []

    def props(index):
        asked.append(index)
        return types.SimpleNamespace(total_memory=gpu_bytes)

    monkeypatch.setattr(torch.cuda, "get_device_properties", props)
    gpu_bytes = 9 * table
    _check_model_fits(model, "cuda:1")                     # exactly fits
    gpu_bytes = 9 * table - 1
    with pytest.raises(InputError, match="GiB of GPU memory"):
        _check_model_fits(model, "cuda:1")
    _check_model_fits(model, "cpu")                        # the GPU is not asked on the CPU
    assert asked == [1, 1]
    with pytest.raises(InputError, match="GPU memory"):
        _check_model_fits(model, "cuda")
    assert asked[-1] == 0
    # ... and through the command line: refused before run.json is written
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *SMALL, "--device", "cuda:5"]) == 2
    assert "cuda:5 requested but torch sees 2 GPU(s)" in _one_error_line(capsys)
    assert not out.exists()


def test_demo_checks_the_device_before_writing_its_scene(tmp_path, capsys):
    """Before, ``--demo --device tpu`` wrote the demo scene and then failed (so at 9bf94cf)."""
    out = tmp_path / "demo"
    assert main(["--demo", "--out", str(out), "--device", "tpu", "--quiet"]) == 2
    assert "--device" in _one_error_line(capsys)
    assert not out.exists()


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("features", ["daisy", "vgg19"])
def test_a_selftraining_fit_on_cuda_end_to_end_and_resumed(tiny_scene, tmp_path, capsys, features):
    """The whole command on the GPU: rays, baseline, teacher renders, reliability (VGG-19's features kept and
    looked up on the GPU; DAISY's on the host), the student with the teacher queried on the device,
    evaluation, teacher.pt; then the same command finds the run finished and leaves it as it is."""
    out = tmp_path / "gpu"
    argv = [str(tiny_scene), "--out", str(out), "--protocol", "all", "--steps", "16", "--batch-rays", "128",
            "--samples", "12", "--resolution", "8", "--iterations", "1", "--pseudo-views", "1",
            "--features", features, "--device", "cuda", "--quiet"]
    assert main(argv) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert [it["iteration"] for it in doc["iterations"]] == [0, 1]
    assert all(math.isfinite(it["psnr"]) for it in doc["iterations"])
    assert doc["config"]["train"]["device"] == "cuda" and (out / "checkpoints" / "teacher.pt").is_file()
    assert all(it["host"]["device"] == __import__("torch").cuda.get_device_name() for it in doc["iterations"])
    capsys.readouterr()
    assert main(argv) == 0
    assert json.loads((out / "metrics.json").read_text())["iterations"] == doc["iterations"]
    # (this line expected "resuming after iteration 1", the message before fbf5b94: the test first ran on a GPU
    # in session 19)
    assert "holds iterations 0-1 already (1 asked for); nothing to train" in capsys.readouterr().out


def test_a_summary_figure_that_cannot_be_drawn_is_a_warning_not_a_failed_run(tiny_scene, tmp_path, capsys,
                                                                              monkeypatch):
    import senerf.report

    def broken(*args, **kwargs):
        raise ValueError("iteration 0's row lacks psnr, ssim or per_view.psnr")

    monkeypatch.setattr(senerf.report, "plot_run_summary", broken)
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    err = capsys.readouterr().err
    assert "senerf-fit: warning: no summary figure (iteration 0's row lacks" in err
    assert (out / "metrics.json").is_file() and not (out / "summary.png").exists()


def test_summary_angles_fall_back_to_optical_axes_when_the_cameras_have_no_common_point(tiny_scene, tmp_path,
                                                                                         monkeypatch):
    import numpy as np

    import senerf.geometry
    import senerf.report
    from senerf.data import load_scene

    seen = {}

    def capture(metrics, run_dir, path, angles_deg=None, ground_truth=None):
        seen["angles"] = angles_deg
        return path

    def no_point(c2w):
        raise ValueError("the optical axes are (nearly) parallel")

    monkeypatch.setattr(senerf.report, "plot_run_summary", capture)
    monkeypatch.setattr(senerf.geometry, "closest_point_to_axes", no_point)
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    c2w = load_scene(tiny_scene).c2w
    z_train = c2w[metrics["train_views"], :3, 2]
    z_test = c2w[metrics["test_views"], :3, 2]
    cos = np.clip(z_test @ z_train.T, -1.0, 1.0)   # unit optical axes: the nearest one by the largest cosine
    np.testing.assert_allclose(seen["angles"], np.degrees(np.arccos(cos.max(axis=1))), atol=1e-6)


def test_help_names_every_output(capsys):
    from senerf.cli import _OUTPUT_NAMES

    assert main(["--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for name in (*_OUTPUT_NAMES, "iter_K/test/", "iter_K/pseudo/"):
        assert name in text, name


def test_scene_kind_is_chosen_for_colmap_scenes_recorded_and_rendered_with(tmp_path, tiny_scene, capsys):
    # a COLMAP capture around an object, fitted as chosen; senerf-render reloads it with the recorded kind
    import numpy as np

    from senerf.flythrough import main as render

    writers = _colmap_writers()
    root, _ = writers.ring_scene(tmp_path / "ring", True, np.arange(0, 360, 30), elevation=5.0)
    assert main([str(root), "--out", str(tmp_path / "o"), "--scene-kind", "forward-facing", *SMALL]) == 2
    assert "kind: some rays look" in _one_error_line(capsys)
    assert main([str(tiny_scene), "--out", str(tmp_path / "o"), "--scene-kind", "object", *TINY]) == 2
    assert "--scene-kind: applies to COLMAP scenes only" in _one_error_line(capsys)
    out = tmp_path / "fit"
    capsys.readouterr()
    assert main([str(root), "--out", str(tmp_path / "auto"), *SMALL]) == 0
    assert ("senerf-fit: fitted as object: camera axes within 85.0 degrees of their mean direction, rays within "
            in capsys.readouterr().out)
    assert main([str(root), "--out", str(out), "--scene-kind", "object", *SMALL]) == 0
    assert "fitted as object: camera axes within 85.0 degrees" in capsys.readouterr().out
    record = json.loads((out / "run.json").read_text())
    assert record["format"] == "colmap" and record["scene_kind"] == "object" and record["protocol"] == "llff"
    assert render([str(out), "--path", "test", "--quiet"]) == 0
    capsys.readouterr()
    assert main([str(root), "--out", str(out), *SMALL]) == 2   # resuming without the choice is another run
    assert "scene_kind" in _one_error_line(capsys)


def test_a_colmap_object_capture_with_a_background_is_warned_about(tmp_path, capsys):
    # Before, a capture whose sparse points mostly lie beyond the fitted box (a background all around) was
    # fitted without a word, its background baked onto the box (so at 737942e).
    import numpy as np

    writers = _colmap_writers()
    # 40 points at the centre, inside the box (half size ~1.7 around the origin), and 60 at radius 20
    root, _ = writers.ring_scene(tmp_path / "bg", True, np.arange(0, 360, 30), far_points=60)
    assert main([str(root), "--out", str(tmp_path / "o1"), *SMALL]) == 0
    err = capsys.readouterr().err
    assert "senerf-fit: warning: 60% of the capture's 100 3D points lie outside the box the field is fitted in" in err
    assert len(err.strip().splitlines()) == 1 and "RGBA" in err
    (root / "sparse" / "0" / "points3D.bin").unlink()   # an object capture may come without points: no check
    assert main([str(root), "--out", str(tmp_path / "o2"), *SMALL]) == 0
    assert "warning" not in capsys.readouterr().err
    root, _ = writers.ring_scene(tmp_path / "plain", False, np.arange(0, 360, 30), far_points=10)  # 20 %
    assert main([str(root), "--out", str(tmp_path / "o3"), *SMALL]) == 0
    assert "warning" not in capsys.readouterr().err
    # a points3D the fit does not need, malformed: the check says so and the fit goes on (before, exit 2)
    with open(root / "sparse" / "0" / "points3D.txt", "a") as f:
        f.write("1 2 3\n")
    assert main([str(root), "--out", str(tmp_path / "o4"), *SMALL]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("senerf-fit: warning: the 3D points could not be checked against "
                                               "the box (") and "points3D.txt" in err[0]


def test_a_protocol_that_leaves_no_test_views_is_refused_before_anything_is_written(tmp_path, capsys):
    # Catches: `--protocol all` on a scene without a test split training for the whole run and then stopping
    # with an internal error ("no test views", a traceback) and a half-written output folder (so at 79e2799).
    from senerf.procedural.export import export_blender_scene

    scene = export_blender_scene(tmp_path / "no_test", n_train=4, n_val=0, n_test=0, width=16, height=16, seed=0)
    out = tmp_path / "run"
    assert main([str(scene), "--out", str(out), *TINY]) == 2
    assert _one_error_line(capsys) == ("senerf-fit: error: --protocol: protocol 'all' leaves no test views (scene "
                                       "'no_test' has no test split); use 'llff' or 'views'")
    assert not out.exists()


def test_the_default_protocol_is_one_every_scene_folder_supports(tiny_scene, tmp_path, capsys):
    # Before, every object scene defaulted to `extreme`, which only the NeRF Synthetic scenes (looked up by
    # folder name) can use: a capture of one's own failed with "no Extreme views known" (so at a325121).
    import types

    import numpy as np

    from senerf.cli import _default_protocol

    def scene(name, n_test, kind="object"):
        return types.SimpleNamespace(name=name, kind=kind, splits={"test": np.arange(n_test)})

    assert _default_protocol(scene("lego", 200), "blender", None) == "extreme"
    assert _default_protocol(scene("Chair", 200), "blender", None) == "extreme"   # names are case-insensitive
    assert _default_protocol(scene("chair", 0), "ngp", None) == "llff"             # no test split: not the benchmark
    assert _default_protocol(scene("my_capture", 200), "blender", None) == "spread"   # its test split stays held out
    assert _default_protocol(scene("my_capture", 0), "ngp", None) == "llff"
    assert _default_protocol(scene("my_capture", 1), "blender", None) == "spread"   # one test view is a split
    assert _default_protocol(scene("fern", 3, "forward_facing"), "llff", None) == "llff"   # LLFF's every 8th
    assert _default_protocol(scene("lego", 20), "colmap", None) == "llff"
    assert _default_protocol(scene("fern", 0, "forward_facing"), "llff", None) == "llff"
    assert _default_protocol(scene("lego", 200), "blender", [0, 1]) == "views"
    # the tiny scene (5 train, 2 test views; not a NeRF Synthetic name) by hand: spread takes the train split at
    # round(linspace(0, 4, 3)) = [0, 2, 4]; its test split stays the test
    out = tmp_path / "o"
    assert main([str(tiny_scene), "--out", str(out), *SMALL]) == 0
    assert ("protocol spread: 3 training views [0, 2, 4] (train/r_0.png, train/r_2.png, train/r_4.png), 2 test "
            "views" in capsys.readouterr().out)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["train_images"] == ["train/r_0.png", "train/r_2.png", "train/r_4.png"]
    assert metrics["test_images"] == ["test/r_0.png", "test/r_1.png"]
    # llff, asked for, over all 7 views: test = every 8th = [0]; the rest [1..6] at round(linspace(0, 5, 3)) =
    # [0, 2, 5] (2.5 rounds to even) -> views 1, 3, 6
    assert main([str(tiny_scene), "--out", str(tmp_path / "l"), *SMALL, "--protocol", "llff"]) == 0
    assert ("protocol llff: 3 training views [1, 3, 6] (train/r_1.png, train/r_3.png, test/r_1.png), 1 test views"
            in capsys.readouterr().out)


def _colmap_writers():
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("colmap_writers", Path(__file__).parent / "data" / "test_colmap.py")
    writers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(writers)
    return writers


def test_the_box_check_by_hand(monkeypatch, capsys):
    # The mutation audit: the 25 % boundary, the figures printed and an empty points3D were untested.
    import types
    import warnings

    import numpy as np

    import senerf.data.colmap as colmap
    from senerf.cli import _warn_points_outside

    model = types.SimpleNamespace(aabb=((-1.0, -1.0, -1.0), (3.0, 3.0, 3.0)))   # centre (1, 1, 1), half size 2
    inside, outside = [0.0, 0.0, 0.0], [5.0, 0.0, 0.0]
    for points, warned in (([inside] * 3 + [outside], "25% of the capture's 4 3D points"),   # at the limit
                           ([inside] * 4 + [outside], None), ([], None)):
        monkeypatch.setattr(colmap, "sparse_points", lambda root, xyz=points: np.asarray(xyz, float).reshape(-1, 3))
        with warnings.catch_warnings():   # no numpy warning for an empty cloud either
            warnings.simplefilter("error")
            _warn_points_outside("scene", model)
        err = capsys.readouterr().err
        if warned is None:
            assert err == ""
        else:
            assert f"senerf-fit: warning: {warned} lie outside the box the field is fitted in (centre (1, 1, 1), " \
                   "half size 2)" in err


def test_a_forward_facing_colmap_capture_is_not_checked_against_a_box(tmp_path, capsys):
    # its points are in COLMAP's frame, its field in the normalised NDC one: no box to check
    import numpy as np

    root, _ = _colmap_writers().ring_scene(tmp_path / "ff", True, [0, 5, 10, 15, 20], far_points=60)
    assert main([str(root), "--out", str(tmp_path / "o"), *SMALL]) == 0
    captured = capsys.readouterr()
    assert "fitted as forward-facing" in captured.out and "lie outside the box" not in captured.err
    assert np.isfinite(json.loads((tmp_path / "o" / "metrics.json").read_text())["iterations"][0]["psnr"])


def test_aabb_is_refused_for_a_forward_facing_capture_before_anything_is_written(tmp_path, capsys):
    # before, --aabb 2 on an LLFF/COLMAP forward-facing capture replaced the NDC box with [-2, 2]^3 in NDC
    # (the flag means world units around the origin), without a word (so at 534d38e)
    root, _ = _colmap_writers().ring_scene(tmp_path / "ff", True, [0, 5, 10, 15, 20], far_points=60)
    out = tmp_path / "o"
    assert main([str(root), "--out", str(out), "--aabb", "2", *SMALL]) == 2
    line = _one_error_line(capsys)
    assert f"{root}: --aabb: a forward-facing scene is fitted in NDC" in line and "applies to object scenes" in line
    assert not out.exists()


def test_the_printed_views_stop_at_twelve(tmp_path, capsys):
    from senerf.procedural.export import export_blender_scene

    scene = export_blender_scene(tmp_path / "s", n_train=13, n_val=0, n_test=1, width=16, height=16, seed=0)
    assert main([str(scene), "--out", str(tmp_path / "o13"), *TINY]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if "training views" in s)
    assert line.endswith("13 training views [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11] ... (train/r_0.png, "
                         "train/r_1.png, train/r_2.png, train/r_3.png, train/r_4.png, train/r_5.png, train/r_6.png, "
                         "train/r_7.png, train/r_8.png, train/r_9.png, train/r_10.png, train/r_11.png ...), "
                         "1 test views")
    assert main([str(scene), "--out", str(tmp_path / "o12"), *SMALL, "--views", ",".join(map(str, range(12)))]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if "training views" in s)
    assert "..." not in line and line.endswith("train/r_11.png), 1 test views")


def test_a_photo_the_run_read_and_no_longer_reads_is_named(tiny_scene, tmp_path, capsys):
    # a frame pointed at another copy of its photo: the old name "was read then", the new one "is read now"
    import shutil

    scene = shutil.copytree(tiny_scene, tmp_path / "scene")
    argv = [str(scene), "--out", str(tmp_path / "o"), *TINY]
    assert main(argv) == 0
    shutil.copy(scene / "train" / "r_0.png", scene / "train" / "copy.png")
    poses = scene / "transforms_train.json"
    poses.write_text(poses.read_text().replace('"./train/r_0"', '"./train/copy"'))
    capsys.readouterr()
    assert main(argv) == 2
    assert ("holds a different run (scene files differ: train/copy.png is read now, not then and 2 more)"
            in _one_error_line(capsys))


def test_a_test_camera_far_beyond_the_box_is_refused_and_a_test_view_posed_as_a_training_view_is_warned(
        tmp_path, tiny_scene, capsys):
    # a test camera at 1e300 scored NaN after two numpy cast warnings, and a test frame with a training frame's
    # pose scored a training view, without a word (so at 5e35cd6)
    import shutil

    def edited(name, edit):
        root = tmp_path / name
        shutil.copytree(tiny_scene, root)
        doc = json.loads((root / "transforms_test.json").read_text())
        edit(doc, json.loads((root / "transforms_train.json").read_text()))
        (root / "transforms_test.json").write_text(json.dumps(doc))
        return root

    def far(doc, train):
        doc["frames"][1]["transform_matrix"][0][3] = 1e300

    out = tmp_path / "far_out"
    assert main([str(edited("far", far)), "--out", str(out), *TINY]) == 2
    line = _one_error_line(capsys)
    assert "test views: test view 6 (test/r_1.png) stands 1e+300 from the centre of the box" in line
    assert not out.exists()

    def posed_as_train(doc, train):
        doc["frames"][0]["transform_matrix"] = train["frames"][2]["transform_matrix"]

    assert main([str(edited("same", posed_as_train)), "--out", str(tmp_path / "same_out"), *TINY]) == 0
    err = capsys.readouterr().err
    assert ("senerf-fit: warning: test view 5 (test/r_0.png) has the pose of training view 2 (train/r_2.png); its "
            "scores measure a view the field is trained on") in err
    assert main([str(tiny_scene), "--out", str(tmp_path / "plain"), *TINY]) == 0
    assert "has the pose of training view" not in capsys.readouterr().err


def test_test_views_scores_an_even_spread_of_the_test_split(tmp_path, capsys):
    """``--test-views N`` gives the figures of the whole test split's run restricted to the N views it keeps
    (each view's render depends on the field alone), records the choice and resumes only with the same N."""
    from senerf.procedural.export import export_blender_scene

    scene = export_blender_scene(tmp_path / "s", n_train=4, n_val=0, n_test=7, width=16, height=16, seed=1)
    argv = [str(scene), *TINY]
    assert main([*argv, "--out", str(tmp_path / "all")]) == 0
    assert main([*argv, "--out", str(tmp_path / "some"), "--test-views", "3"]) == 0
    printed = capsys.readouterr().out
    assert "4 training views [0, 1, 2, 3] (train/r_0.png, train/r_1.png, train/r_2.png, train/r_3.png), 3 of the 7 " \
           "test views (--test-views)" in printed
    every = json.loads((tmp_path / "all" / "metrics.json").read_text())
    some = json.loads((tmp_path / "some" / "metrics.json").read_text())
    kept = [0, 3, 6]   # round(linspace(0, 6, 3)), by hand
    assert some["test_views"] == [every["test_views"][k] for k in kept] == [4, 7, 10]
    assert some["test_images"] == ["test/r_0.png", "test/r_3.png", "test/r_6.png"]
    assert some["config"]["test_views"] == 3 and "test_views" not in every["config"]
    (a,), (b,) = every["iterations"], some["iterations"]
    for metric in ("psnr", "ssim"):
        assert b["per_view"][metric] == [a["per_view"][metric][k] for k in kept]   # the same renders, to the bit
        assert b[metric] == pytest.approx(sum(b["per_view"][metric]) / 3)
    for k, name in enumerate(("rgb_000.png", "rgb_003.png", "rgb_006.png")):
        assert (tmp_path / "some" / "iter_0" / "test" / f"rgb_{k:03d}.png").read_bytes() == \
            (tmp_path / "all" / "iter_0" / "test" / name).read_bytes()
    # all 7 is the flag's absence (the same run); another number is another run, refused before any work
    assert main([*argv, "--out", str(tmp_path / "all"), "--test-views", "7"]) == 0
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "some"), "--test-views", "4"]) == 2
    assert "different run (test_views: 3 in the folder, 4 now)" in _one_error_line(capsys)
    assert main([*argv, "--out", str(tmp_path / "some")]) == 2
    assert "different run (test_views: 3 in the folder, absent now)" in _one_error_line(capsys)


@pytest.mark.parametrize("flags, needle", [
    (["--test-views", "3"], "--test-views: expected a number of views from 1 to the 2 there are, got 3"),
    (["--test-views", "0"], "argument --test-views: must be >= 1, got 0"),
    (["--test-views", "1", "--iterations", "1", "--reliability", "oracle"],
     "--test-views: the oracle's held-out views are those outside the whole test split"),
])
def test_test_views_that_cannot_be_kept_are_refused_before_anything_is_written(tiny_scene, tmp_path, capsys, flags,
                                                                              needle):
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *SMALL, "--protocol", "spread", *flags]) == 2
    assert needle in _one_error_line(capsys)
    assert not out.exists()


def test_spread_views_keeps_the_ends_and_spreads_the_rest():
    import numpy as np

    from senerf.data import spread_views

    idx = np.arange(100, 300)
    # round(linspace(0, 199, 25)) = round(8.2917 k): 0, 8, 17, 25, 33, ... 191, 199 (by hand)
    kept = spread_views(idx, 25)
    assert kept[:5].tolist() == [100, 108, 117, 125, 133] and kept[-2:].tolist() == [291, 299]
    assert len(set(kept.tolist())) == 25 and (np.diff(kept) > 0).all() and kept.dtype == np.int64
    assert spread_views(idx, 200).tolist() == idx.tolist() and spread_views(idx, 1).tolist() == [100]
    assert spread_views([5, 3, 9], 2).tolist() == [5, 9]   # the given order
    for bad in (0, 201, 2.0, True):
        with pytest.raises(InputError, match="--test-views"):
            spread_views(idx, bad)
    # Catches: an empty list of views read as "a number of views from 1 to the 0 there are"
    with pytest.raises(InputError, match="--test-views: there are no views to choose 1 from"):
        spread_views(np.arange(0), 1)


def test_self_training_that_extends_a_baseline_run_does_not_score_the_teacher_again(tiny_scene, tmp_path, capsys,
                                                                                   render_spy):
    # Extending a baseline-only run rendered and scored every test view of iteration 0 again (the baseline had
    # deleted its evaluation record; at 403e181): 150 s for lego's 200 test views at 400x400.
    out = tmp_path / "o"
    argv = [str(tiny_scene), "--out", str(out), *SMALL, "--views", "0,1,3", "--features", "daisy",
            "--pseudo-views", "1"]
    assert main(argv) == 0
    baseline = json.loads((out / "metrics.json").read_text())["iterations"]
    assert render_spy.calls == 2 and (out / "checkpoints" / "iter_0_eval.json").is_file()
    from senerf.train import load_checkpoint

    recorded = (load_checkpoint(out / "checkpoints" / "iter_0_train.pt")["seconds"]
                + json.loads((out / "checkpoints" / "iter_0_eval.json").read_text())["seconds"])
    render_spy.calls = 0
    assert main([*argv, "--iterations", "1"]) == 0
    rows = json.loads((out / "metrics.json").read_text())["iterations"]
    assert render_spy.calls == 2   # iteration 1's two test views; iteration 0's were read back
    assert rows[0]["per_view"] == baseline[0]["per_view"] and rows[0]["psnr"] == baseline[0]["psnr"]
    assert recorded <= rows[0]["seconds"] < baseline[0]["seconds"] + 5.0   # the recorded training and scoring
    assert not list((out / "checkpoints").glob("iter_*_eval.json"))   # removed once metrics.json holds them


def test_a_fit_without_the_compiled_kernel_says_so_and_records_it(tiny_scene, tmp_path, capsys, monkeypatch):
    """Catches: senerf-fit on a machine without a C compiler running the slower pure-PyTorch planes without a word,
    its metrics.json rows indistinguishable from the kernel's (session 24)."""
    import senerf.fields.ckernel as ck

    monkeypatch.setattr(ck, "load_kernel", lambda dtype, n_features=16: None)
    monkeypatch.setitem(ck._STATUS, "status", "unavailable: OSError: no C compiler found")
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    err = capsys.readouterr().err
    assert ("senerf-fit: warning: the compiled K-Planes kernel cannot be used (OSError: no C compiler found)"
            in err), err
    rows = json.loads((out / "metrics.json").read_text())["iterations"]
    assert rows and all(row["host"]["kernel"] == "pytorch" for row in rows)
    monkeypatch.undo()
    if ck.load_kernel(__import__("torch").float32) is None:
        pytest.skip("no C compiler here: the fit with the kernel cannot be checked")
    assert main([str(tiny_scene), "--out", str(tmp_path / "again"), *TINY]) == 0
    assert "K-Planes kernel" not in capsys.readouterr().err   # with the kernel: no line
