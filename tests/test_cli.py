"""The senerf-fit command (senerf/cli.py): flags, exit statuses, one-line errors, what it prints."""

from __future__ import annotations

import json
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
        with pytest.raises(InputError, match="--views"):
            parse_views(bad)


@pytest.mark.parametrize("extra, needle", [
    (["--views", "a,b"], "argument --views: expected comma-separated integers"),
    (["--steps", "0"], "argument --steps: must be >= 1, got 0"),
    (["--steps", "x"], "argument --steps: expected an integer, got 'x'"),
    (["--pseudo-views", "0"], "argument --pseudo-views"),
    (["--empty-opacity", "nan"], "argument --empty-opacity: expected a finite number >= 0 and <= 0.5"),
    (["--empty-opacity", "0.7"], "argument --empty-opacity"),
    (["--bogus"], "unrecognized"),
    (["--views", "0,999"], "out of range"),
    (["--views", "1,1"], "duplicate"),
    (["--downscale", "0.5"], "argument --downscale"),
    (["--aabb", "0"], "argument --aabb: expected a finite number > 0"),
    (["--device", "tpu"], "--device"),
    (["--threads", "0"], "argument --threads: must be >= 1 and <= 1024"),
    (["--seed", "99999999999999999999"], "argument --seed"),
    (["--protocol", "llff", "--views", "0"], "--views"),
    (["--resolution", "100000"], "--resolution: 100000 needs"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tiny_scene, tmp_path, capsys, extra, needle):
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *SMALL, *extra]) == 2
    assert needle in _one_error_line(capsys)
    assert not out.exists()


def test_a_missing_scene_in_a_fresh_process_is_one_line_and_no_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "senerf.cli", str(tmp_path / "nope"), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert proc.stderr.startswith("senerf-fit: error: ") and "not found" in proc.stderr
    assert not (tmp_path / "o").exists()


def test_a_fit_prints_its_rows_and_the_next_command_and_resumes(tiny_scene, tmp_path, capsys):
    out = tmp_path / "run"
    assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith(f"fit: reading {tiny_scene} (blender, downscale 1)\n")
    assert "senerf-fit: iteration 0: PSNR " in printed and f"senerf-render {out}\n" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["command"] == ["senerf-fit", str(tiny_scene), "--out", str(out), *TINY]
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--seed", "1"]) == 2
    assert "holds a different run" in _one_error_line(capsys)
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--seed", "1", "--overwrite"]) == 0
    assert "--overwrite: removed the earlier run's" in capsys.readouterr().out


def test_threads_set_torchs_thread_count_and_are_not_part_of_the_run(tiny_scene, tmp_path):
    import torch

    before = torch.get_num_threads()
    out = tmp_path / "run"
    try:
        assert main([str(tiny_scene), "--out", str(out), *TINY, "--threads", "1"]) == 0
        assert torch.get_num_threads() == 1
        assert json.loads((out / "metrics.json").read_text())["iterations"][0]["host"]["threads"] == 1
        torch.set_num_threads(2)
        assert main([str(tiny_scene), "--out", str(out), *TINY]) == 0   # the same run, resumed
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("flags, expected", [
    ([], {}),
    (["--pseudo-range", "15", "--pseudo-range-step", "20", "--empty-opacity", "0", "--pseudo-views", "32"],
     {"pseudo_range_deg": 15.0, "pseudo_range_step_deg": 20.0, "empty_opacity": 0.0, "n_pseudo_per_input": 32}),
    (["--threshold", "unified", "--no-prior", "--no-density-distill"],
     {"threshold": "unified", "prior": False, "density_distill": False}),
])
def test_the_flags_reach_the_recorded_settings_and_the_rest_keep_the_configs_defaults(tiny_scene, tmp_path, flags,
                                                                                      expected):
    from senerf.config import SelfTrainConfig, config_to_dict

    out = tmp_path / "o"
    assert main([str(tiny_scene), "--out", str(out), *TINY, *flags]) == 0
    recorded = json.loads((out / "run.json").read_text())["settings"]["selftrain"]
    defaults = config_to_dict(SelfTrainConfig())
    assert recorded == {k: expected.get(k, v) for k, v in defaults.items() if k != "iterations"}


def test_model_flags_override_the_choice_and_are_recorded(tiny_scene, tmp_path):
    out = tmp_path / "o"
    assert main([str(tiny_scene), "--out", str(out), *TINY, "--hidden", "8", "--background", "white", "--aabb", "2",
                 "--no-view-dependence", "--no-occupancy"]) == 0
    model = json.loads((out / "run.json").read_text())["settings"]["model"]
    assert (model["hidden"], model["train_background"], model["view_dependent"], model["occupancy_resolution"]) == \
        (8, "white", False, 0)
    assert model["aabb"] == [[-2.0] * 3, [2.0] * 3] and model["n_samples"] == 12 and model["resolution"] == 8


def test_help_names_every_output_and_the_presets(capsys):
    assert main(["--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for name in ("summary.png", "metrics.json", "iter_K/test/", "iter_K/pseudo/", "run.json", "checkpoints/",
                 "fast: 600 steps x 1024 rays", "balanced: 3000 steps x 1024 rays"):
        assert name in text, name


def test_warnings_are_one_line_each(tiny_scene, tmp_path, capsys, monkeypatch):
    import senerf.fields.ckernel as ckernel

    monkeypatch.setattr(ckernel, "cpu_planes_warning", lambda n_features=16: "the compiled kernel cannot be used")
    assert main([str(tiny_scene), "--out", str(tmp_path / "o"), *TINY]) == 0
    assert "senerf-fit: warning: the compiled kernel cannot be used\n" in capsys.readouterr().err


def test_the_demo_refuses_options_it_would_ignore_and_checks_the_device_before_writing(tmp_path, capsys):
    out = tmp_path / "demo"
    for argv, flag in ((["--demo", "--preset", "balanced"], "--preset"), (["--demo", "scene"], "SCENE_DIR"),
                       (["--demo", "--device", "tpu"], "--device")):
        assert main([*argv, "--out", str(out)]) == 2
        assert flag in _one_error_line(capsys)
    assert not out.exists()
