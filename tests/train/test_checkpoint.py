"""Atomic checkpoints, ``weights_only`` loading, and the one loader of a trained field (senerf/train/checkpoint.py)."""

from __future__ import annotations

import dataclasses
import errno
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from senerf.config import ModelConfig, TrainConfig
from senerf.errors import InputError
from senerf.geometry import Intrinsics, look_at
from senerf.train import (RayBatchSource, build_field, load_checkpoint, load_field, ray_aabb_bounds, render_views,
                          save_checkpoint, train_field)

MODEL = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), resolution=8, multires=(1,), n_features=4, n_samples=8,
                    occupancy_resolution=8, train_background="random", eval_background="white")


class _Evil:
    """Unpickling this calls ``open(marker, 'w')``: a stand-in for arbitrary code execution."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_a_checkpoint_round_trips_plain_data_and_leaves_no_temporary_file(tmp_path):
    state = dict(step=7, w=torch.arange(6.0).view(2, 3), gen=torch.Generator().manual_seed(3).get_state(),
                 nested=dict(lr=0.5, betas=(0.9, 0.99), name="x", flags=[True, None]))
    save_checkpoint(tmp_path / "c.pt", state)
    back = load_checkpoint(tmp_path / "c.pt")
    assert back["step"] == 7 and torch.equal(back["w"], state["w"]) and torch.equal(back["gen"], state["gen"])
    assert back["nested"] == state["nested"]
    assert [p.name for p in tmp_path.iterdir()] == ["c.pt"]


def test_a_failed_write_keeps_the_old_checkpoint(tmp_path, monkeypatch):
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


def test_a_crafted_pickle_is_refused_in_one_line_without_running_its_code(tmp_path):
    marker = tmp_path / "pwned.txt"
    bad = tmp_path / "bad.pt"
    torch.save({"step": 1, "payload": _Evil(marker)}, bad)
    torch.load(bad, weights_only=False)   # the payload is live: an unsafe load runs it
    assert marker.exists()
    marker.unlink()
    with pytest.raises(InputError) as err:
        load_checkpoint(bad)
    assert err.value.file == str(bad) and "\n" not in str(err.value)
    assert "weights_only" not in str(err.value)   # torch's advice to load it unsafely is not passed on
    assert not marker.exists()


def test_a_missing_corrupt_or_non_dict_checkpoint_is_refused_naming_it(tmp_path):
    # Catches: save_checkpoint accepting a non-dict state (the trainer indexes it like a dict on resume), and
    # load_checkpoint returning whatever plain data the file holds, or failing as a traceback.
    (tmp_path / "junk.pt").write_bytes(os.urandom(64))
    torch.save(torch.zeros(3), tmp_path / "tensor.pt")   # plain data, loads with weights_only=True
    for name in ("none.pt", "junk.pt", "tensor.pt"):
        with pytest.raises(InputError) as err:
            load_checkpoint(tmp_path / name)
        assert err.value.file == str(tmp_path / name) and "\n" not in str(err.value)
    with pytest.raises(ValueError, match="dict"):
        save_checkpoint(tmp_path / "a.pt", [1, 2])
    assert not (tmp_path / "a.pt").exists()


def test_a_checkpoint_that_cannot_be_read_is_not_called_damaged(tmp_path, monkeypatch):
    # A checkpoint at chmod 000 was reported as a damaged file to delete.
    path = tmp_path / "c.pt"
    save_checkpoint(path, {"a": torch.zeros(2)})

    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(torch, "load", denied)
    with pytest.raises(InputError) as err:
        load_checkpoint(path)
    assert err.value.file == str(path) and "Permission denied" in str(err.value)
    assert "delete" not in str(err.value)


# ---------------------------------------------------------------------------------------------------------
# load_field


def _rays(model: ModelConfig = MODEL, n: int = 256) -> RayBatchSource:
    g = torch.Generator().manual_seed(0)
    o = torch.cat([torch.rand(n, 2, generator=g) * 1.6 - 0.8, torch.full((n, 1), -3.0)], dim=1)
    d = torch.nn.functional.normalize(torch.tensor([0.0, 0.0, 1.0]) + 0.1 * torch.randn(n, 3, generator=g), dim=-1)
    near, far = ray_aabb_bounds(o, d, model.aabb)
    return RayBatchSource(o, d, torch.rand(n, 3, generator=g), None, near, far, model)


CFG = TrainConfig(steps=8, batch_rays=64, warmup_steps=2, occupancy_every=2, occupancy_warmup=2, seed=3)


def _trained(tmp_path: Path, model: ModelConfig = MODEL):
    path = tmp_path / "iter_0_train.pt"
    res = train_field(build_field(model, seed=CFG.seed, steps=CFG.steps), _rays(model), CFG, checkpoint=path,
                      progress=False)
    return path, res


@pytest.mark.parametrize("field", ["kplanes", "nerf"])
def test_load_field_gives_back_the_trained_field_and_grid(tmp_path, field):
    # Catches: a loaded field that is not the trained one (a fresh init, a NeRF field with another annealing
    # schedule), left in training mode, or without its occupancy grid (renders would march empty space).
    model = dataclasses.replace(MODEL, field=field)
    path, res = _trained(tmp_path, model)
    loaded, grid = load_field(path, model, seed=CFG.seed, steps=CFG.steps)
    assert not loaded.training
    trained = res.field.state_dict()
    assert all(torch.equal(trained[k], v) for k, v in loaded.state_dict().items())
    assert torch.equal(grid.mask, res.occupancy.mask)
    if field == "nerf":
        assert loaded.anneal_steps == CFG.steps // 4
    cam = look_at(np.array([0.0, -4.0, 0.5]), np.zeros(3))
    k = Intrinsics(12.0, 12.0, 6.0, 6.0, 12, 12)
    want = render_views(res.field, model, k, cam, occupancy=res.occupancy)["rgb"]
    np.testing.assert_array_equal(render_views(loaded, model, k, cam, occupancy=grid)["rgb"], want)


def test_load_field_without_a_grid_in_the_model_gives_none(tmp_path):
    model = dataclasses.replace(MODEL, occupancy_resolution=0)
    path, _ = _trained(tmp_path, model)
    assert load_field(path, model, seed=CFG.seed, steps=CFG.steps)[1] is None


@pytest.mark.parametrize("change", [dict(resolution=16), dict(n_features=8), dict(field="nerf"),
                                    dict(view_dependent=False), dict(occupancy_resolution=16)],
                         ids=["resolution", "features", "field", "view-dependence", "grid"])
def test_load_field_refuses_a_checkpoint_that_does_not_fit_the_model(tmp_path, change):
    # Catches: a checkpoint loaded into a model of other shapes (a traceback from load_state_dict, or a field
    # built from other settings than it was trained with) instead of one line naming the file.
    path, _ = _trained(tmp_path)
    with pytest.raises(InputError) as err:
        load_field(path, dataclasses.replace(MODEL, **change), seed=CFG.seed, steps=CFG.steps)
    assert err.value.file == str(path) and "\n" not in str(err.value)


@pytest.mark.parametrize("damage", [
    lambda s: dict(format="senerf-selftrain-1", field=s["field"]),
    lambda s: {k: v for k, v in s.items() if k != "field"},
    lambda s: dict(s, field=[1, 2]),
    lambda s: dict(s, field={**s["field"], "table": torch.full_like(s["field"]["table"], float("nan"))}),
    lambda s: dict(s, field={**s["field"], "table": torch.full_like(s["field"]["table"], float("inf"))}),
    lambda s: dict(s, occupancy={k: torch.full_like(v, float("nan")) if v.is_floating_point() else v
                                 for k, v in s["occupancy"].items()}),
], ids=["another-kind", "no-field", "field-not-a-dict", "nan-field", "inf-field", "nan-grid"])
def test_load_field_refuses_a_checkpoint_it_cannot_trust_naming_it(tmp_path, damage):
    # Catches: a checkpoint of another kind, without a field, or holding NaN / infinite weights loaded as a field
    # that renders NaN.
    path, _ = _trained(tmp_path)
    save_checkpoint(path, damage(load_checkpoint(path)))
    with pytest.raises(InputError) as err:
        load_field(path, MODEL, seed=CFG.seed, steps=CFG.steps)
    assert err.value.file == str(path) and "\n" not in str(err.value)


def test_load_field_takes_a_grid_with_cells_not_yet_measured(tmp_path):
    # Catches: the occupancy grid refused for the infinities that mark cells it has not measured yet.
    path, _ = _trained(tmp_path)
    state = load_checkpoint(path)
    assert torch.isfinite(state["occupancy"]["density_grid"]).all()
    state["occupancy"]["density_grid"][:5] = float("inf")
    save_checkpoint(path, state)
    _, grid = load_field(path, MODEL, seed=CFG.seed, steps=CFG.steps)
    assert torch.isinf(grid.density_grid).sum() == 5


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_load_field_puts_the_field_and_grid_on_the_device_asked_for(tmp_path):
    path, res = _trained(tmp_path)
    field, grid = load_field(path, MODEL, seed=CFG.seed, steps=CFG.steps, device="cuda")
    assert next(field.parameters()).is_cuda and grid.mask.is_cuda
    cam = look_at(np.array([0.0, -4.0, 0.5]), np.zeros(3))
    k = Intrinsics(12.0, 12.0, 6.0, 6.0, 12, 12)
    want = render_views(res.field, MODEL, k, cam, occupancy=res.occupancy)["rgb"]
    np.testing.assert_allclose(render_views(field, MODEL, k, cam, occupancy=grid)["rgb"], want, atol=1e-4)
