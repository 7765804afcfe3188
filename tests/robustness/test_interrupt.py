"""Interruption: ``senerf-fit`` killed with SIGKILL mid-training resumes from its last checkpoint.

* A subprocess fit (24x24 scene, 3 views, ``--iterations 0 --steps 700``; the preset checkpoints every 500
  steps) is killed with SIGKILL as soon as ``checkpoints/iter_0_train.pt`` appears.  Then every JSON file in the
  output folder parses, the checkpoint loads (``weights_only``) and holds step 500, and no metrics exist yet.
  Rerunning the same command resumes at step 500 and ends with exactly the metrics and weights of an
  uninterrupted run of the same seed (CPU, one thread: bit-identical).
* The same with self-training (``--iterations 1``), killed as soon as iteration 0 is finished:
  the rerun resumes after iteration 0 and ends with the uninterrupted run's metrics for both iterations.
* Every file of a fit's output is written through the atomic helpers (temp file, fsync, ``os.replace``): an AST
  scan of the fit's modules finds no other write call.
"""

from __future__ import annotations

import ast
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import torch

import senerf
import senerf.selftrain.loop
from senerf.cli import main
from senerf.config import PRESETS
from senerf.train import load_checkpoint

from .conftest import run_cli_subprocess

PACKAGE = Path(senerf.__file__).resolve().parent
CKPT_EVERY = PRESETS["balanced"].train_config().checkpoint_every  # senerf-fit's default preset (500)
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
    real = senerf.selftrain.loop.train_field

    def spy(*args, **kwargs):
        result = real(*args, **kwargs)
        seen.append(result.resumed_from)
        return result

    monkeypatch.setattr(senerf.selftrain.loop, "train_field", spy)   # where the fit calls it
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
    return [str(scene), "--views", "0,1,2", "--out", str(out), "--iterations", "1", "--steps", "40", "--batch-rays",
            "64", "--samples", "8", "--resolution", "8", "--no-occupancy", "--quiet"]


def test_sigkill_during_self_training_resumes_after_the_finished_iteration(scene24, tmp_path, capsys):
    ref_out, out = tmp_path / "ref", tmp_path / "run"
    ref = run_cli_subprocess(_selftrain_argv(scene24, ref_out), timeout=300)
    assert ref.returncode == 0, ref.stderr
    reference = json.loads((ref_out / "metrics.json").read_text())
    assert [it["iteration"] for it in reference["iterations"]] == [0, 1]

    # iteration 0 is finished once its row is in metrics.json; iteration 1 labels its pseudo views next
    _sigkill_fit_when(_selftrain_argv(scene24, out), out / "metrics.json", "iteration 0's metrics")
    assert [it["iteration"] for it in json.loads((out / "metrics.json").read_text())["iterations"]] == [0]
    assert load_checkpoint(out / "checkpoints" / "iter_0_train.pt")["step"] == 40

    capsys.readouterr()
    assert main(_selftrain_argv(scene24, out)) == 0
    assert "selftrain: resuming after iteration 0" in capsys.readouterr().out
    resumed = json.loads((out / "metrics.json").read_text())
    for a, b in zip(reference["iterations"], resumed["iterations"], strict=True):
        for key in ("psnr", "ssim", "per_view", "reliable_fraction"):
            assert a[key] == b[key], (a["iteration"], key)


# calls that write files; the atomic helpers are the only places allowed to use them
_WRITERS = {"write_text", "write_bytes", "imwrite", "savefig", "save", "dump", "write", "open"}
_ALLOWED = {
    ("atomic.py", "write"),                 # the temp file inside senerf.atomic.atomic_write
    ("train/checkpoint.py", "save"),        # torch.save into that temp file
    ("train/evaluate.py", "imwrite"),       # PNG encoded into a BytesIO, then atomic_write_bytes
    ("report.py", "savefig"),               # summary.png into a BytesIO, then atomic_write_bytes
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
        PACKAGE / name for name in ("cli.py", "pipeline.py", "runfolder.py", "report.py", "demo.py", "atomic.py")]
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
