"""The training loop (senerf/train/loop.py) and ray source (senerf/train/rays.py) on tiny synthetic rays."""

from __future__ import annotations

import math
import re

import pytest
import torch

from senerf.errors import InputError
from senerf.train import (ModelConfig, RayBatchSource, TrainConfig, build_field, lr_factor, ray_aabb_bounds,
                          train_field)

MODEL = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), resolution=8, multires=(1,), n_features=4, n_samples=8,
                    occupancy_resolution=8, train_background="random", eval_background="white")


def _rays(n: int = 512, model: ModelConfig = MODEL) -> RayBatchSource:
    g = torch.Generator().manual_seed(0)
    o = torch.cat([torch.rand(n, 2, generator=g) * 1.6 - 0.8, torch.full((n, 1), -3.0)], dim=1)
    d = torch.nn.functional.normalize(torch.tensor([0.0, 0.0, 1.0]) + 0.1 * torch.randn(n, 3, generator=g), dim=-1)
    rgb = torch.rand(n, 3, generator=g)
    alpha = (o[:, 0] > 0).float()
    near, far = ray_aabb_bounds(o, d, model.aabb)
    return RayBatchSource(o, d, rgb, alpha, near, far, model)


def _cfg(**kw) -> TrainConfig:
    base = dict(steps=12, batch_rays=64, lr=0.02, warmup_steps=3, occupancy_every=3, occupancy_warmup=2,
                checkpoint_every=5, seed=3)
    return TrainConfig(**{**base, **kw})


def _zero_loss(field, step, generator, occupancy):
    return torch.zeros(()), {}


class _Crash(Exception):
    pass


def _crash_at_step_8(rays, cfg, checkpoint) -> None:
    """Train seed-1 field until step 8 raises, leaving the checkpoint of step 5 (checkpoint_every 5)."""
    def crash_at_8(field, step, generator, occupancy):
        if step == 8:
            raise _Crash()
        return _zero_loss(field, step, generator, occupancy)

    with pytest.raises(_Crash):
        train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=crash_at_8, checkpoint=checkpoint,
                    progress=False)


def test_ray_aabb_bounds_by_hand():
    o = torch.tensor([[0.0, 0.0, -3.0], [0.0, 0.0, 0.0], [5.0, 5.0, -3.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    near, far = ray_aabb_bounds(o, d, ((-1, -1, -1), (1, 1, 1)), min_near=1e-3)
    assert near.tolist() == pytest.approx([2.0, 1e-3, near[2].item()])
    assert far[:2].tolist() == pytest.approx([4.0, 1.0])
    assert far[2] == near[2]  # the miss is an empty segment


def test_lr_schedule_warmup_then_cosine():
    cfg = TrainConfig(steps=100, warmup_steps=10, lr_final_factor=0.1)
    assert lr_factor(0, cfg) == pytest.approx(0.1)
    assert lr_factor(9, cfg) == pytest.approx(1.0)
    assert lr_factor(10, cfg) == pytest.approx(1.0)
    assert lr_factor(55, cfg) == pytest.approx(0.1 + 0.9 * 0.5)
    assert lr_factor(100, cfg) == pytest.approx(0.1)


def test_training_reduces_the_loss():
    rays = _rays()
    res = train_field(build_field(MODEL, seed=0), rays, _cfg(steps=40, lr=0.05), progress=False, log_every=5)
    assert res.history[-1]["loss"] < res.history[0]["loss"]
    assert res.steps == 40 and res.occupancy is not None


def test_resume_reproduces_uninterrupted_run(tmp_path):
    rays = _rays()
    cfg = _cfg()
    full = train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss,
                       checkpoint=tmp_path / "a.pt", progress=False)

    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    assert torch.load(tmp_path / "b.pt", weights_only=True)["step"] == 5
    at_5 = torch.load(tmp_path / "b.pt", weights_only=True)["seconds"]
    fresh = build_field(MODEL, seed=1)
    resumed = train_field(fresh, rays, cfg, extra_loss=_zero_loss, checkpoint=tmp_path / "b.pt", progress=False)
    assert resumed.resumed_from == 5
    a, b = full.field.state_dict(), resumed.field.state_dict()
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    assert torch.equal(full.occupancy.mask, resumed.occupancy.mask)
    # the interrupted call's training time is carried: the checkpoint records it and the resume reports it
    # (before, a resumed run's seconds counted only the resumed part, so at b013c1a)
    assert full.seconds_before == 0.0 and at_5 > 0.0 and resumed.seconds_before == at_5
    final = torch.load(tmp_path / "b.pt", weights_only=True)["seconds"]
    assert at_5 < final <= at_5 + resumed.seconds
    # and the parameters really changed during training (the comparison is not between two inits)
    init = build_field(MODEL, seed=1).state_dict()
    assert not torch.equal(init["table"], a["table"])


def test_a_resume_on_another_host_says_so_and_the_same_host_is_silent(tmp_path):
    """The checkpoint records its host (device, threads, torch, NumPy); on the CPU the float sums follow the
    thread count, so a resume with another count warns that the rest is not bit for bit an uninterrupted run
    (the self-training controller says the same of a finished iteration's host).  No host (a checkpoint from
    before session 20) and the same host resume silently."""
    import warnings

    from senerf.train import host_record

    rays, cfg = _rays(), _cfg()
    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    state = torch.load(tmp_path / "b.pt", weights_only=True)
    here = host_record("cpu")
    assert state["host"] == here
    for name, host in (("same", here), ("legacy", None)):
        if host is None:
            state.pop("host")
        torch.save(state, tmp_path / f"{name}.pt")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss,
                        checkpoint=tmp_path / f"{name}.pt", progress=False)
    state["host"] = dict(here, threads=here["threads"] + 14)
    torch.save(state, tmp_path / "moved.pt")
    threads = f"{here['threads']} thread" + ("" if here["threads"] == 1 else "s")
    with pytest.warns(UserWarning) as caught:
        res = train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss,
                          checkpoint=tmp_path / "moved.pt", progress=False)
    assert res.resumed_from == 5
    assert [str(w.message) for w in caught] == [
        f"{tmp_path / 'moved.pt'}: step 5 was reached with {here['threads'] + 14} threads, this call with {threads}: "
        f"the rest is reproducible, but not bit for bit an uninterrupted run"]


def _as_if_written_on_cuda(src: Path, dst: Path, legacy: bool = False) -> None:
    """A copy of CPU checkpoint ``src`` whose generator state is a CUDA one (16 bytes: seed, offset), written on a
    GPU host (with another thread count)."""
    state = torch.load(src, weights_only=True)
    state["generator"] = torch.zeros(16, dtype=torch.uint8)
    state["host"] = dict(state["host"], device="NVIDIA H100", threads=state["host"]["threads"] + 14)
    if legacy:  # written before the checkpoint named its generator's device
        state.pop("generator_device")
    else:
        assert state["generator_device"] == "cpu"
        state["generator_device"] = "cuda"
    torch.save(state, dst)


@pytest.mark.parametrize("legacy", [False, True])
def test_resume_on_another_device_type_reseeds_with_a_warning(tmp_path, legacy):
    """A run started on a GPU and resumed on the CPU (the fingerprint leaves the device out on purpose)
    continues, reproducibly, from a stream seeded from (seed, step) instead of failing on the foreign
    generator state."""
    rays, cfg = _rays(), _cfg()

    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    results = []
    for k in range(2):
        _as_if_written_on_cuda(tmp_path / "b.pt", tmp_path / f"gpu{k}.pt", legacy)
        with pytest.warns(UserWarning) as caught:
            res = train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss,
                              checkpoint=tmp_path / f"gpu{k}.pt", progress=False)
        # one warning: the reseeding one says the run is not an uninterrupted one; no host line besides it
        (only,) = [str(w.message) for w in caught]
        assert re.search(r"gpu\d\.pt: written on (cuda|another device), resumed on cpu", only), only
        assert res.resumed_from == 5 and res.steps == cfg.steps
        results.append(res.field.state_dict()["table"])
    assert torch.equal(results[0], results[1])  # reproducible
    same_device = train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss,
                              checkpoint=tmp_path / "b.pt", progress=False)
    assert not torch.equal(results[0], same_device.field.state_dict()["table"])  # a new stream, as it says


def test_unreadable_generator_state_is_input_error(tmp_path):
    rays = _rays()
    train_field(build_field(MODEL, seed=0), rays, _cfg(steps=5), checkpoint=tmp_path / "c.pt", progress=False)
    state = torch.load(tmp_path / "c.pt", weights_only=True)
    state["generator"], state["step"] = torch.zeros(3, dtype=torch.uint8), 3
    torch.save(state, tmp_path / "c.pt")
    with pytest.raises(InputError, match="random-generator state is unreadable") as err:
        train_field(build_field(MODEL, seed=0), rays, _cfg(steps=5), checkpoint=tmp_path / "c.pt", progress=False)
    assert str(tmp_path / "c.pt") in str(err.value)


def test_checkpoint_of_another_configuration_is_refused(tmp_path):
    rays = _rays()
    train_field(build_field(MODEL, seed=0), rays, _cfg(steps=5), checkpoint=tmp_path / "c.pt", progress=False)
    with pytest.raises(InputError, match="different training configuration"):
        train_field(build_field(MODEL, seed=0), rays, _cfg(steps=5, lr=0.03), checkpoint=tmp_path / "c.pt",
                    progress=False)


def test_extra_loss_is_added_and_logged():
    rays = _rays()
    calls = []

    def extra(field, step, generator, occupancy):
        calls.append((step, occupancy))
        return 0.0 * field.regularizer() + 1.0, {"distill": 1.0}

    res = train_field(build_field(MODEL, seed=0), rays, _cfg(steps=6), extra_loss=extra, progress=False,
                      log_every=3)
    assert [step for step, _ in calls] == list(range(6))
    # the hook sees the grid the step renders with: none before occupancy_warmup (2), the trainer's after
    assert res.occupancy is not None
    assert all((grid is None) if step < 2 else (grid is res.occupancy) for step, grid in calls)
    assert res.history[-1]["distill"] == 1.0 and res.history[-1]["loss"] > 1.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_trains_on_cuda():
    rays = _rays()
    cuda = RayBatchSource(*(t.cuda() for t in (rays.origins, rays.dirs, rays.rgb, rays.alpha, rays.near,
                                               rays.far)), MODEL)
    res = train_field(build_field(MODEL, seed=0), cuda, _cfg(steps=6, device="cuda"), progress=False)
    assert next(res.field.parameters()).is_cuda and math.isfinite(res.history[-1]["loss"])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_resume_on_cuda_continues_with_host_step_counters(tmp_path, monkeypatch):
    """A CUDA run killed at step 8 resumes from step 5's checkpoint (loaded on the host, copied into the
    device tensors): it finishes on the GPU, close to the uninterrupted run (CUDA's index_add_ is not
    deterministic, so not to the bit), and Adam's step counters live where a fresh run's do (the host)."""
    optimizers = []

    class RecordingAdam(torch.optim.Adam):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            optimizers.append(self)

    monkeypatch.setattr(torch.optim, "Adam", RecordingAdam)
    device = "cuda"
    rays = _rays()
    moved = RayBatchSource(*(t.to(device) for t in (rays.origins, rays.dirs, rays.rgb, rays.alpha, rays.near,
                                                    rays.far)), MODEL)
    cfg = _cfg(device=device)
    full = train_field(build_field(MODEL, seed=1), moved, cfg, extra_loss=_zero_loss, checkpoint=tmp_path / "a.pt",
                       progress=False)
    _crash_at_step_8(moved, cfg, tmp_path / "b.pt")
    resumed = train_field(build_field(MODEL, seed=1), moved, cfg, extra_loss=_zero_loss,
                          checkpoint=tmp_path / "b.pt", progress=False)
    assert resumed.resumed_from == 5 and len(optimizers) == 3
    assert next(resumed.field.parameters()).device.type == device
    fresh = {s["step"].device for s in optimizers[0].state.values()}     # the uninterrupted run's
    resumed_steps = {s["step"].device for s in optimizers[-1].state.values()}
    assert fresh and resumed_steps == fresh
    a, b = full.field.state_dict(), resumed.field.state_dict()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-3, atol=1e-4)


def test_a_nerf_field_built_without_its_step_count_anneals_over_a_quarter_of_the_training():
    # build_field(model) (steps=None, documented) gave a NeRF field without anneal_steps, and train_field's
    # set_progress(step) raised "give total_steps" at step 0 (so at 98f1a55). Expected: the same training as a
    # field built with steps=cfg.steps (annealing over cfg.steps / 4), bit for bit.
    import dataclasses

    nerf = dataclasses.replace(MODEL, field="nerf")
    rays, cfg = _rays(model=nerf), _cfg(steps=8)
    bare = train_field(build_field(nerf, seed=0), rays, cfg, progress=False).field
    told = train_field(build_field(nerf, seed=0, steps=cfg.steps), rays, cfg, progress=False).field
    for (name, a), (_, b) in zip(bare.state_dict().items(), told.state_dict().items()):
        assert torch.equal(a, b), name
