"""Interruption: ``senerf-fit`` killed with SIGKILL mid-training resumes from its last checkpoint.

* A subprocess fit (24x24 scene, 3 views, ``--iterations 0 --steps 700``; the preset checkpoints every 500
  steps, read from ``preset_train_config``) is killed with SIGKILL as soon as ``checkpoints/iter_0_train.pt`` appears.  Then: every JSON file
  in the output folder parses, every checkpoint loads (``weights_only``) and holds step 500, and no metrics
  exist yet.  Rerunning the same command (in-process, ``train_field`` wrapped to read ``resumed_from``)
  resumes at step 500 and ends with exactly the metrics and weights of an uninterrupted run of the same
  seed (CPU, one thread: bit-identical, measured).
* The same with self-training (``--iterations 1 --features daisy``): killed as soon as iteration 0's
  ``checkpoints/teacher.pt`` appears, the rerun prints ``selftrain: resuming after iteration 0`` and ends
  with the uninterrupted run's metrics for both iterations (bit-identical, measured).
* Every file of a fit's output is written through the atomic helpers (temp file, fsync, ``os.replace``):
  an AST scan of ``senerf/train``, ``senerf/selftrain`` and ``senerf/cli.py`` finds no other write call
  (the helpers' own behaviour on a failed write is tested in tests/train/test_checkpoint.py).
"""

from __future__ import annotations

import ast
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

import senerf
import senerf.train
from senerf.cli import main
from senerf.train import load_checkpoint, preset_train_config

from .conftest import run_cli_subprocess

PACKAGE = Path(senerf.__file__).resolve().parent
CKPT_EVERY = preset_train_config("balanced").checkpoint_every  # senerf-fit's default preset (500)
STEPS = CKPT_EVERY + 200  # one checkpoint mid-run, then 200 more steps


def _argv(scene: Path, out: Path) -> list[str]:
    return [str(scene), "--views", "0,1,2", "--out", str(out), "--iterations", "0", "--steps", str(STEPS),
            "--batch-rays", "64", "--samples", "8", "--resolution", "8", "--no-occupancy", "--quiet"]


def _env():
    return dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")


def _sigkill_fit_when(argv: list[str], path: Path, what: str, timeout: float = 240) -> None:
    """Run ``senerf-fit argv`` in a subprocess and SIGKILL it the moment ``path`` exists (``what`` names the
    awaited event in failure messages); asserts the process died of that signal."""
    proc = subprocess.Popen([sys.executable, "-m", "senerf.cli", *argv], env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + timeout
        while not path.exists():
            assert proc.poll() is None, f"fit ended before {what}: {proc.stderr.read()!r}"
            assert time.monotonic() < deadline, f"no {what} within {timeout:g} s"
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL


def test_sigkill_mid_fit_then_rerun_resumes_and_matches_uninterrupted(scene24, tmp_path, monkeypatch):
    ref_out, out = tmp_path / "ref", tmp_path / "run"
    # the uninterrupted reference (one torch thread, like the resumed run below)
    ref = run_cli_subprocess(_argv(scene24, ref_out), timeout=300)
    assert ref.returncode == 0, ref.stderr
    reference = json.loads((ref_out / "metrics.json").read_text())

    ckpt = out / "checkpoints" / "iter_0_train.pt"
    _sigkill_fit_when(_argv(scene24, out), ckpt, "its first checkpoint")

    # what the kill left: parseable JSON, a loadable step-500 checkpoint, no metrics yet
    for js in out.rglob("*.json"):
        json.loads(js.read_text())
    assert not (out / "metrics.json").exists()
    finished = [p for p in (out / "checkpoints").iterdir() if not p.name.endswith(".tmp")]
    assert finished == [ckpt]
    state = load_checkpoint(ckpt)
    assert state["step"] == CKPT_EVERY, "the run finished before the kill; the test did not interrupt it"

    # the same command again, in-process, with train_field wrapped to see where it starts
    seen = []
    real = senerf.train.train_field

    def spy(*args, **kwargs):
        result = real(*args, **kwargs)
        seen.append(result.resumed_from)
        return result

    monkeypatch.setattr(senerf.train, "train_field", spy)
    assert main(_argv(scene24, out)) == 0
    assert seen == [CKPT_EVERY]
    resumed = json.loads((out / "metrics.json").read_text())
    a, b = reference["iterations"][0], resumed["iterations"][0]
    for key in ("psnr", "ssim", "per_view"):
        assert a[key] == b[key], key  # bit-identical on the CPU
    wa = load_checkpoint(ref_out / "checkpoints" / "iter_0_train.pt")
    wb = load_checkpoint(ckpt)
    assert wa["step"] == wb["step"] == STEPS
    for name, tensor in wa["field"].items():
        assert torch.equal(tensor, wb["field"][name]), name


def test_sigterm_mid_fit_is_an_interrupt_with_its_message_and_a_resumable_folder(scene24, tmp_path):
    """A batch scheduler's SIGTERM: before, the process died of the signal (no message, exit -15); now it is
    handled as Ctrl-C is: exit 130, one line saying how to resume, and the checkpoint on disk resumes."""
    out = tmp_path / "run"
    ckpt = out / "checkpoints" / "iter_0_train.pt"
    proc = subprocess.Popen([sys.executable, "-m", "senerf.cli", *_argv(scene24, out)], env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not ckpt.exists():
            assert proc.poll() is None, f"fit ended before its first checkpoint: {proc.stderr.read()!r}"
            assert time.monotonic() < deadline, "no checkpoint within 240 s"
            time.sleep(0.005)
        proc.send_signal(signal.SIGTERM)
        err = proc.communicate(timeout=60)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "senerf-fit: interrupted (rerun the same command to resume)"
    assert load_checkpoint(ckpt)["step"] == CKPT_EVERY
    assert not (out / "metrics.json").exists()


def _selftrain_argv(scene: Path, out: Path) -> list[str]:
    return [str(scene), "--views", "0,1,2", "--out", str(out), "--iterations", "1", "--features", "daisy",
            "--steps", "40", "--batch-rays", "64", "--samples", "8", "--resolution", "8", "--no-occupancy",
            "--quiet"]


def test_sigkill_during_selftraining_resumes_after_the_finished_iteration(scene24, tmp_path, capsys):
    ref_out, out = tmp_path / "ref", tmp_path / "run"
    ref = run_cli_subprocess(_selftrain_argv(scene24, ref_out), timeout=300)
    assert ref.returncode == 0, ref.stderr
    reference = json.loads((ref_out / "metrics.json").read_text())
    assert [it["iteration"] for it in reference["iterations"]] == [0, 1]

    teacher = out / "checkpoints" / "teacher.pt"
    _sigkill_fit_when(_selftrain_argv(scene24, out), teacher, "the iteration-0 teacher checkpoint")
    for js in out.rglob("*.json"):
        json.loads(js.read_text())
    assert load_checkpoint(teacher)["iteration"] == 0
    partial = json.loads((out / "metrics.json").read_text()) if (out / "metrics.json").exists() else None
    assert partial is None or [it["iteration"] for it in partial["iterations"]] == [0]

    capsys.readouterr()
    assert main(_selftrain_argv(scene24, out)) == 0
    assert "selftrain: resuming after iteration 0" in capsys.readouterr().out
    resumed = json.loads((out / "metrics.json").read_text())
    assert [it["iteration"] for it in resumed["iterations"]] == [0, 1]
    for a, b in zip(reference["iterations"], resumed["iterations"]):
        for key in ("psnr", "ssim", "per_view", "reliable_fraction"):
            assert a[key] == b[key], (a["iteration"], key)


@pytest.mark.parametrize("iterations", [0, 1])
def test_an_interrupt_during_evaluation_resumes_at_the_first_view_not_scored(scene24, tmp_path, render_spy, capsys,
                                                                               iterations):
    """Ctrl-C while the test views are rendered (the baseline's evaluation, or iteration 1's): the rerun
    renders only the views not yet scored and ends with the uninterrupted run's figures; the per-view record
    (``checkpoints/iter_K_eval.json``) is gone once metrics.json holds the iteration, except a baseline-only run's,
    which self-training that extends the run reads back."""
    def argv(out: Path) -> list[str]:
        args = _selftrain_argv(scene24, out)
        args[args.index("--iterations") + 1] = str(iterations)
        return args

    assert main(argv(tmp_path / "ref")) == 0
    reference = json.loads((tmp_path / "ref" / "metrics.json").read_text())
    n_views = len(reference["iterations"][0]["per_view"]["psnr"])
    assert n_views >= 2
    render_spy.calls, render_spy.stop_at = 0, iterations * n_views + 2   # the last iteration's first view scored
    out = tmp_path / "run"
    assert main(argv(out)) == 130
    record = out / "checkpoints" / f"iter_{iterations}_eval.json"
    assert sorted(json.loads(record.read_text())["views"]) == ["0"]
    if iterations:   # as a kill between metrics.json and the record's removal leaves it: removed on resuming
        (out / "checkpoints" / "iter_0_eval.json").write_text("{}")
    render_spy.calls, render_spy.stop_at = 0, None
    capsys.readouterr()
    assert main(argv(out)) == 0
    assert render_spy.calls == n_views - 1
    kept = sorted(p.name for p in (out / "checkpoints").glob("*_eval.json"))
    assert kept == (["iter_0_eval.json"] if iterations == 0 else [])
    resumed = json.loads((out / "metrics.json").read_text())
    assert [it["iteration"] for it in resumed["iterations"]] == list(range(iterations + 1))
    for a, b in zip(reference["iterations"], resumed["iterations"]):
        for key in ("psnr", "ssim", "per_view", "reliable_fraction"):
            assert a[key] == b[key], (a["iteration"], key)


@pytest.mark.parametrize("where", ["labelling", "student"])
def test_an_interrupt_in_iteration_1_resumes_without_labelling_again(scene24, tmp_path, similarity_spy, monkeypatch,
                                                                     capsys, where):
    """Ctrl-C while iteration 1 labels its pseudo views (at the third), or while its student trains: the rerun
    labels only the views not yet labelled (none, for the student) and ends with the uninterrupted run's figures;
    the labelling record (``checkpoints/iter_1_labels/``) is gone once metrics.json holds the iteration.  Before,
    the rerun labelled all 24 views again."""
    import senerf.selftrain.controller as controller_mod

    assert main(_selftrain_argv(scene24, tmp_path / "ref")) == 0
    reference = json.loads((tmp_path / "ref" / "metrics.json").read_text())
    n_pseudo = similarity_spy.calls
    assert n_pseudo == 24   # 8 per input view
    similarity_spy.calls = 0
    students = controller_mod.train_field
    if where == "labelling":
        similarity_spy.stop_at = 3
    else:
        def train_then_stop(field, rays, cfg, extra_loss=None, **kwargs):
            if extra_loss is not None:   # iteration 1's student, labelled and about to train
                raise KeyboardInterrupt
            return students(field, rays, cfg, extra_loss=extra_loss, **kwargs)

        monkeypatch.setattr(controller_mod, "train_field", train_then_stop)
    out = tmp_path / "run"
    assert main(_selftrain_argv(scene24, out)) == 130
    record = out / "checkpoints" / "iter_1_labels"
    n_recorded = 2 if where == "labelling" else n_pseudo
    assert len(list(record.glob("view_*.npz"))) == n_recorded
    (out / "checkpoints" / "iter_0_labels").mkdir()   # as a kill after iteration 0's metrics leaves it
    for path in record.glob("view_*.npz"):   # each recorded view "took" 1000 s: the rerun's seconds must count it
        with np.load(path) as f:
            arrays = {name: f[name] for name in f.files}
        buf = io.BytesIO()
        np.savez(buf, **dict(arrays, seconds=np.float64(1000.0)))
        path.write_bytes(buf.getvalue())
    monkeypatch.setattr(controller_mod, "train_field", students)
    similarity_spy.calls, similarity_spy.stop_at = 0, None
    capsys.readouterr()
    assert main(_selftrain_argv(scene24, out)) == 0
    assert similarity_spy.calls == n_pseudo - n_recorded
    said = capsys.readouterr().out   # what a user sees of it
    assert f"; {n_recorded} labelled by an interrupted run found in {record}" in said
    assert f"24 pseudo views within 10 deg ({n_recorded} read back, not labelled again)" in said
    assert not list((out / "checkpoints").glob("iter_*_labels"))
    resumed = json.loads((out / "metrics.json").read_text())
    assert [it["iteration"] for it in resumed["iterations"]] == [0, 1]
    for a, b in zip(reference["iterations"], resumed["iterations"]):
        for key in ("psnr", "ssim", "per_view", "reliable_fraction"):
            assert a[key] == b[key], (a["iteration"], key)
    assert 1000 * n_recorded <= resumed["iterations"][1]["seconds"] < 1000 * (n_recorded + 1)
    assert resumed["seconds_total"] >= 1000 * n_recorded


def test_each_iteration_labels_into_its_own_record_and_the_known_features_are_computed_once(scene24, tmp_path,
                                                                                           monkeypatch):
    import senerf.selftrain.controller as controller_mod

    features, records = [], []
    real_features, real_labelling = controller_mod.known_view_features, controller_mod.estimate_reliability
    monkeypatch.setattr(controller_mod, "known_view_features",
                        lambda *a, **k: (features.append(1), real_features(*a, **k))[1])
    monkeypatch.setattr(controller_mod, "estimate_reliability",
                        lambda *a, **k: (records.append(k["resume"].name), real_labelling(*a, **k))[1])
    argv = _selftrain_argv(scene24, tmp_path / "run")
    argv[argv.index("--iterations") + 1] = "2"
    assert main(argv) == 0
    assert features == [1]
    assert records == ["iter_1_labels", "iter_2_labels"]
    assert not list((tmp_path / "run" / "checkpoints").glob("iter_*_labels"))


# calls that write files; the atomic helpers are the only places allowed to use them
_WRITERS = {"write_text", "write_bytes", "imwrite", "savefig", "save", "dump", "write", "open"}
_ALLOWED = {
    ("atomic.py", "write"),                 # the temp file inside senerf.atomic.atomic_write
    ("train/checkpoint.py", "save"),        # torch.save into that temp file
    ("train/evaluate.py", "imwrite"),       # PNG encoded into a BytesIO, then atomic_write_bytes
}


def _writes(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        name = f.attr if isinstance(f, ast.Attribute) else (f.id if isinstance(f, ast.Name) else None)
        if name not in _WRITERS:
            continue
        if name == "open":
            mode = node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
            if not (isinstance(mode, ast.Constant) and any(c in str(mode.value) for c in "wax+")):
                continue
        if name == "save" and not (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name)
                                   and f.value.id in ("torch", "np", "numpy")):
            continue
        if name == "dump" and not (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name)
                                   and f.value.id in ("json", "pickle")):
            continue
        yield name, node.lineno


def test_fit_outputs_are_written_only_through_the_atomic_helpers():
    files = sorted((PACKAGE / "train").rglob("*.py")) + sorted((PACKAGE / "selftrain").rglob("*.py")) + [
        PACKAGE / "cli.py", PACKAGE / "atomic.py"]
    offenders, allowed_seen = [], set()
    for path in files:
        rel = str(path.relative_to(PACKAGE))
        for name, line in _writes(path):
            if (rel, name) in _ALLOWED:
                allowed_seen.add((rel, name))
            else:
                offenders.append(f"senerf/{rel}:{line}: {name}(...)")
    assert offenders == [], "write fit outputs with senerf.atomic.atomic_write_* / save_checkpoint / write_png"
    assert allowed_seen == _ALLOWED  # the scan does see the helpers' own writes
