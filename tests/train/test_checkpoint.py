"""Atomic checkpoints and weights_only loading (senerf/train/checkpoint.py)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from senerf.errors import InputError
from senerf.train.checkpoint import atomic_write_text, load_checkpoint, save_checkpoint


class _Evil:
    """Unpickling this calls ``open(marker, 'w')`` - a stand-in for arbitrary code execution."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_roundtrip_plain_data(tmp_path):
    state = dict(step=7, w=torch.arange(6.0).view(2, 3), gen=torch.Generator().manual_seed(3).get_state(),
                 nested=dict(lr=0.5, betas=(0.9, 0.99), name="x", flags=[True, None]))
    save_checkpoint(tmp_path / "c.pt", state)
    back = load_checkpoint(tmp_path / "c.pt")
    assert back["step"] == 7 and torch.equal(back["w"], state["w"]) and torch.equal(back["gen"], state["gen"])
    assert back["nested"] == state["nested"]
    assert [p.name for p in tmp_path.iterdir()] == ["c.pt"]  # no temp file left behind


def test_failed_write_keeps_the_old_checkpoint(tmp_path, monkeypatch):
    path = tmp_path / "c.pt"
    save_checkpoint(path, dict(step=1))
    before = path.read_bytes()

    def broken_save(obj, fh):
        fh.write(b"half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        save_checkpoint(path, dict(step=2))
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.pt"]


def test_crafted_pickle_is_refused_without_running_code(tmp_path):
    marker = tmp_path / "pwned.txt"
    bad = tmp_path / "bad.pt"
    torch.save({"step": 1, "payload": _Evil(marker)}, bad)
    # the payload is live: an unsafe load runs it (so the assertion below can fail)
    torch.load(bad, weights_only=False)
    assert marker.exists()
    marker.unlink()
    with pytest.raises(InputError, match="refusing to load") as err:
        load_checkpoint(bad)
    assert str(bad) in str(err.value) and "\n" not in str(err.value)
    # the way out is named, and torch's advice to load with weights_only=False is not passed on
    assert str(err.value).endswith("delete it to redo that step")  # (--overwrite would not help: same run)
    assert "weights_only" not in str(err.value)
    assert not marker.exists()


def test_missing_or_corrupt_checkpoint_is_input_error(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_checkpoint(tmp_path / "none.pt")
    (tmp_path / "junk.pt").write_bytes(os.urandom(64))
    with pytest.raises(InputError, match="refusing to load"):
        load_checkpoint(tmp_path / "junk.pt")
    atomic_write_text(tmp_path / "t.txt", "hello")
    assert (tmp_path / "t.txt").read_text() == "hello"


def test_only_dicts_are_saved_or_loaded(tmp_path):
    # Catches: save_checkpoint accepting a non-dict state (the trainer indexes it like a dict on resume), and
    # load_checkpoint returning whatever plain data the file holds instead of refusing a non-dict.
    with pytest.raises(ValueError, match="must be a dict"):
        save_checkpoint(tmp_path / "a.pt", [1, 2])
    assert not (tmp_path / "a.pt").exists()
    torch.save(torch.zeros(3), tmp_path / "t.pt")          # plain data, loads with weights_only=True
    with pytest.raises(InputError, match="expected a dict"):
        load_checkpoint(tmp_path / "t.pt")



def test_a_checkpoint_that_cannot_be_read_is_not_called_damaged(tmp_path, monkeypatch):
    # a checkpoint at chmod 000 was "not a plain-data checkpoint (PermissionError; a damaged file ...); delete it
    # to redo that step": advice to delete a good file (so at 9e0fdc2)
    import errno

    import torch

    from senerf.errors import InputError
    from senerf.train import load_checkpoint, save_checkpoint

    path = tmp_path / "c.pt"
    save_checkpoint(path, {"a": torch.zeros(2)})

    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(torch, "load", denied)
    with pytest.raises(InputError) as info:
        load_checkpoint(path)
    assert str(info.value) == f"{path}: cannot be read (Permission denied)" and "delete" not in str(info.value)
