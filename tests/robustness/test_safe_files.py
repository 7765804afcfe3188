"""Safe files: checkpoints are plain data (senerf/train/checkpoint.py and every ``torch.load`` in the package).

* A source scan (AST) of ``senerf/`` finds every ``torch.load(...)`` call and requires ``weights_only=True``;
  ``pickle.load(s)`` and ``np.load(..., allow_pickle=True)`` are not allowed at all.
* A crafted pickle whose ``__reduce__`` would create a marker file is refused by
  :func:`senerf.train.load_checkpoint` (``InputError`` naming the file) and by ``senerf-fit`` resume, both when
  the trainer resumes from ``checkpoints/iter_0_train.pt`` and when self-training loads its teacher from it: exit
  status 2, one line naming the checkpoint, and the marker never appears.
  A control shows the crafted file *does* run code when loaded unsafely, so the test can fail.
"""

from __future__ import annotations

import ast
import pickle
from pathlib import Path

import pytest
import torch

import senerf
from senerf.cli import main
from senerf.errors import InputError
from senerf.train import load_checkpoint, save_checkpoint

from .conftest import TINY_FIT, snapshot

PACKAGE = Path(senerf.__file__).resolve().parent


class _Payload:
    """Unpickling this creates ``marker`` (through ``builtins.open``): proof that code ran."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _craft(path: Path, marker: Path, legacy: bool = False) -> None:
    """A checkpoint-shaped file (a dict with the trainer's keys) carrying the payload."""
    state = {"format": "senerf-train-1", "step": 1, "field": {"w": torch.zeros(2)},
             "evil": _Payload(marker)}
    path.parent.mkdir(parents=True, exist_ok=True)
    if legacy:
        with open(path, "wb") as fh:
            pickle.dump(state, fh)
    else:
        torch.save(state, path)


def _calls(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = None
            if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
                name = f"{f.value.id}.{f.attr}"
            elif isinstance(f, ast.Attribute) and isinstance(f.value, ast.Attribute) and isinstance(f.value.value, ast.Name):
                name = f"{f.value.value.id}.{f.value.attr}.{f.attr}"
            if name:
                yield name, node


def _kw(node: ast.Call, key: str):
    for kw in node.keywords:
        if kw.arg == key:
            return kw.value
    return None


def test_every_torch_load_in_the_package_is_weights_only():
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 20
    torch_loads, bad = 0, []
    for path in files:
        tree = ast.parse(path.read_text(), filename=str(path))
        for name, node in _calls(tree):
            where = f"{path.relative_to(PACKAGE.parent)}:{node.lineno}"
            if name in ("torch.load", "torch.serialization.load"):
                torch_loads += 1
                wo = _kw(node, "weights_only")
                if not (isinstance(wo, ast.Constant) and wo.value is True):
                    bad.append(f"{where}: {name} without weights_only=True")
            elif name in ("pickle.load", "pickle.loads", "torch.jit.load", "dill.load", "joblib.load"):
                bad.append(f"{where}: {name}")
            elif name in ("np.load", "numpy.load"):
                ap = _kw(node, "allow_pickle")
                if ap is not None and not (isinstance(ap, ast.Constant) and ap.value is False):
                    bad.append(f"{where}: {name} with allow_pickle")
    assert bad == []
    assert torch_loads >= 1  # the checkpoint loader itself is found by the scan


def test_crafted_file_runs_code_when_loaded_unsafely(tmp_path):
    # control: the payload is real, so the refusals below are meaningful
    marker = tmp_path / "pwned"
    _craft(tmp_path / "evil.pt", marker)
    torch.load(tmp_path / "evil.pt", weights_only=False)
    assert marker.exists()


@pytest.mark.parametrize("legacy", [False, True], ids=["torch-zip", "raw-pickle"])
def test_library_loader_refuses_a_code_running_checkpoint(tmp_path, legacy):
    marker = tmp_path / "pwned"
    path = tmp_path / "ckpt.pt"
    _craft(path, marker, legacy=legacy)
    with pytest.raises(InputError) as info:
        load_checkpoint(path)
    msg = str(info.value)
    assert str(path) in msg and "refusing to load" in msg and "\n" not in msg
    assert not marker.exists()


def test_library_loader_round_trips_plain_data_and_refuses_junk(tmp_path):
    path = tmp_path / "ok.pt"
    save_checkpoint(path, {"step": 3, "w": torch.arange(4.0), "nested": {"a": [1, 2]}})
    state = load_checkpoint(path)
    assert state["step"] == 3 and torch.equal(state["w"], torch.arange(4.0)) and state["nested"] == {"a": [1, 2]}
    (tmp_path / "junk.pt").write_bytes(b"\x00" * 100)
    with pytest.raises(InputError, match="junk.pt"):
        load_checkpoint(tmp_path / "junk.pt")
    save_checkpoint(tmp_path / "cut.pt", {"w": torch.zeros(1000)})
    data = (tmp_path / "cut.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(data[: len(data) // 2])  # a truncated checkpoint
    with pytest.raises(InputError, match="cut.pt"):
        load_checkpoint(tmp_path / "cut.pt")


@pytest.mark.parametrize("iterations", ["0", "1"])
def test_fit_resume_refuses_a_code_running_checkpoint(scene24, tmp_path, capsys, iterations):
    """An interrupted baseline resumes from its training checkpoint; a finished one that self-training extends
    loads its field from the same file as the next teacher."""
    out = tmp_path / "run"
    base = [str(scene24), "--views", "0,1,2", "--out", str(out), *TINY_FIT]
    assert main(base) == 0  # a finished baseline run: run.json records the settings
    marker = tmp_path / "pwned"
    ckpt = out / "checkpoints" / "iter_0_train.pt"
    _craft(ckpt, marker)
    if iterations == "0":  # a finished baseline is not reloaded: make it an interrupted one, which is
        (out / "metrics.json").unlink()
    before = snapshot(out)
    capsys.readouterr()
    i = base.index("--iterations")
    argv = [*base[: i + 1], iterations, *base[i + 2:]]
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("senerf-fit: error: ") and "Traceback" not in err
    assert str(ckpt) in lines[0]
    assert not marker.exists()
    # every file keeps its bytes (run.json is rewritten with the same content before training starts)
    assert {k: v[2] for k, v in snapshot(out).items()} == {k: v[2] for k, v in before.items()}
