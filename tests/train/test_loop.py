"""The training loop (senerf/train/loop.py): the lr schedule and one step's loss by hand, when the occupancy grid
updates and checkpoints are written, a resumed training that ends bit for bit as an uninterrupted one, and what a
resume refuses or warns about.

``EmptyField`` has zero density, so its renders are exactly the background and every loss value can be worked
out by hand; the other tests train a tiny K-Planes field on random rays."""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import pytest
import torch

import senerf.train.loop as loop
from senerf.config import ModelConfig, TrainConfig
from senerf.errors import InputError
from senerf.fields import RadianceField
from senerf.train import (RayBatchSource, background_color, build_field, host_record, lr_factor, make_occupancy,
                          ray_aabb_bounds, save_checkpoint, train_field)

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
    """Train a seed-1 field until step 8 raises, leaving the checkpoint of step 5 (checkpoint_every 5)."""
    def crash_at_8(field, step, generator, occupancy):
        if step == 8:
            raise _Crash()
        return _zero_loss(field, step, generator, occupancy)

    with pytest.raises(_Crash):
        train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=crash_at_8, checkpoint=checkpoint,
                    progress=False)


def _resume(rays, cfg, checkpoint):
    return train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss, checkpoint=checkpoint,
                       progress=False)


class EmptyField(RadianceField):
    """Zero density everywhere (colour 0.5); one parameter so Adam has something to step.  Records its density
    calls (the occupancy grid's updates) and the steps of the hook in ``log``, and the points it renders."""

    def __init__(self, tv=0.5):
        super().__init__()
        self.p = torch.nn.Parameter(torch.zeros(()))
        self.tv = tv
        self.log = []
        self.points = []

    def density(self, xyz):
        self.log.append("density")
        return torch.zeros(xyz.shape[0]) + 0.0 * self.p

    def forward(self, xyz, dirs):
        self.points.append(xyz.detach().clone())
        return torch.zeros(xyz.shape[0]) + 0.0 * self.p, torch.full((xyz.shape[0], 3), 0.5) + 0.0 * self.p

    def regularizer(self):
        return self.tv + 0.0 * self.p


COLOUR = torch.tensor([0.1, 0.2, 0.4])


def _straight_rays(background: str, alpha: float | None, occupancy: int = 0, n: int = 32) -> RayBatchSource:
    """``n`` rays from z = -3 along +z, near 2, far 4, target colour COLOUR."""
    model = dataclasses.replace(MODEL, occupancy_resolution=occupancy, train_background=background)
    o = torch.tensor([0.0, 0.0, -3.0]).expand(n, 3).contiguous()
    d = torch.tensor([0.0, 0.0, 1.0]).expand(n, 3).contiguous()
    a = None if alpha is None else torch.full((n,), alpha)
    return RayBatchSource(o, d, COLOUR.expand(n, 3).contiguous(), a, torch.full((n,), 2.0), torch.full((n,), 4.0),
                          model)


def _hand_cfg(**kw) -> TrainConfig:
    base = dict(steps=4, batch_rays=16, lr=0.1, warmup_steps=2, lr_final_factor=0.1, tv_weight=0.2,
                occupancy_every=3, occupancy_warmup=2, checkpoint_every=5, seed=0)
    return TrainConfig(**{**base, **kw})


# ---------------------------------------------------------------------------------------------------------
# one step, by hand


def test_lr_schedule_warmup_then_cosine():
    cfg = TrainConfig(steps=100, warmup_steps=10, lr_final_factor=0.1)
    assert lr_factor(0, cfg) == pytest.approx(0.1)
    assert lr_factor(9, cfg) == pytest.approx(1.0)
    assert lr_factor(10, cfg) == pytest.approx(1.0)
    assert lr_factor(55, cfg) == pytest.approx(0.1 + 0.9 * 0.5)
    assert lr_factor(100, cfg) == pytest.approx(0.1)


@pytest.mark.parametrize("background,alpha,photo", [
    # black, no alpha: rendered 0, target c: mean(c^2) = (0.01 + 0.04 + 0.16) / 3 = 0.07
    ("black", None, 0.07),
    # white, alpha 0.25: rendered 1, target 0.25 c + 0.75 -> differences 0.25 (1 - c) = (0.225, 0.2, 0.15):
    # mean of squares = (0.050625 + 0.04 + 0.0225) / 3 = 0.037708333
    ("white", 0.25, 0.037708333333333),
    # black, alpha 0.25: target 0.25 c, rendered 0: 0.0625 * 0.07 = 0.004375
    ("black", 0.25, 0.004375),
])
def test_logged_loss_psnr_and_lr_by_hand(background, alpha, photo):
    # Catches: the photometric loss summed over channels instead of averaged, the target composited with
    # alpha and 1 - alpha swapped (or not at all), the TV term not weighted by tv_weight (0.2 * 0.5 = 0.1),
    # the logged PSNR taken from the total loss instead of the photometric one, and the lr of step s set
    # from lr_factor(s + 1).  lr: warm-up 2 -> factors 1/2, 2/2; then cosine over 2 steps to 0.1:
    # step 2 progress 0 -> 1, step 3 progress 1/2 -> 0.1 + 0.9 * 0.5 = 0.55; times lr 0.1.
    res = train_field(EmptyField(), _straight_rays(background, alpha), _hand_cfg(), progress=False, log_every=1)
    assert [h["step"] for h in res.history] == [1, 2, 3, 4]
    for h in res.history:
        assert h["loss"] == pytest.approx(photo + 0.2 * 0.5, rel=1e-6)
        assert h["psnr"] == pytest.approx(-10 * math.log10(photo), rel=1e-6)
    assert [h["lr"] for h in res.history] == pytest.approx([0.05, 0.1, 0.1, 0.055], rel=1e-12)


def test_training_samples_are_jittered_inside_their_bins():
    # Catches: training rays rendered at the deterministic bin centres (randomized=False), which aliases.
    # Rays from z = -3 along +z, near 2, far 4, 8 bins of 0.25: sample k lies in z in [-1 + 0.25 k,
    # -1 + 0.25 (k + 1)], and the centres are -1 + 0.25 (k + 0.5).
    field = EmptyField()
    train_field(field, _straight_rays("black", None), _hand_cfg(steps=1), progress=False)
    z = field.points[0][:, 2].view(16, 8)
    lo = -1.0 + 0.25 * torch.arange(8.0)
    assert ((z >= lo - 1e-6) & (z <= lo + 0.25 + 1e-6)).all()
    assert (z - (lo + 0.125)).abs().max() > 0.05


def test_background_colours_white_black_or_drawn_from_the_generator():
    # Catches: white and black swapped, a random colour drawn from the global generator (a resume would not
    # repeat it), an unknown policy giving None (no background) instead of an error.
    assert background_color("white", torch.Generator(), "cpu").tolist() == [1.0, 1.0, 1.0]
    assert background_color("black", torch.Generator(), "cpu").tolist() == [0.0, 0.0, 0.0]
    a, b = (background_color("random", torch.Generator().manual_seed(5), "cpu") for _ in range(2))
    assert torch.equal(a, b) and a.shape == (3,) and ((a >= 0) & (a < 1)).all()
    with pytest.raises(ValueError, match="grey"):
        background_color("grey", torch.Generator(), "cpu")


def test_extra_loss_is_added_and_logged_and_sees_the_grid_of_its_step():
    calls = []

    def extra(field, step, generator, occupancy):
        calls.append((step, occupancy))
        return 0.0 * field.regularizer() + 1.0, {"distill": 1.0}

    res = train_field(build_field(MODEL, seed=0), _rays(), _cfg(steps=6), extra_loss=extra, progress=False,
                      log_every=3)
    assert [step for step, _ in calls] == list(range(6))
    # the hook sees the grid the step renders with: none before occupancy_warmup (2), the trainer's after
    assert res.occupancy is not None
    assert all((grid is None) if step < 2 else (grid is res.occupancy) for step, grid in calls)
    assert res.history[-1]["distill"] == 1.0 and res.history[-1]["loss"] > 1.0


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_loss_that_is_not_finite_stops_training_before_its_checkpoint(tmp_path, bad):
    # Catches: the finiteness check dropped (training went on, saving a NaN field), made for NaN only (inf
    # passed), the step named 0-based (5 instead of 6), or the bad field checkpointed before the check.
    def extra(field, step, generator, occupancy):
        # a constant: no gradient, so only step index 5 (the 6th, a logged one with log_every 3) is bad
        return torch.tensor(bad if step == 5 else 0.0), {}

    ckpt = tmp_path / "c.pt"
    with pytest.raises(RuntimeError, match="step 6"):
        train_field(build_field(MODEL, seed=0), _rays(), _cfg(steps=9, checkpoint_every=3), extra_loss=extra,
                    checkpoint=ckpt, progress=False, log_every=3)
    assert torch.load(ckpt, weights_only=True)["step"] == 3   # the last checkpoint is the sound one before it


# ---------------------------------------------------------------------------------------------------------
# the schedule of the grid, the checkpoints and the NeRF annealing


def test_occupancy_grid_updates_at_warmup_then_every_n_steps():
    # Catches: the first update one period late (step > warmup), the period counted from step 0 instead of
    # from the warm-up, updates before the warm-up.  warmup 2, every 3, 12 steps: updates at 2, 5, 8, 11.
    field = EmptyField()
    steps_seen = []

    def hook(f, step, generator, occupancy):
        field.log.append(step)
        return torch.zeros(()), {}

    train_field(field, _straight_rays("black", None, occupancy=8), _hand_cfg(steps=12), extra_loss=hook,
                progress=False)
    updates = []
    for entry in field.log:
        if entry == "density":
            updates.append(len(steps_seen))       # the step whose hook has not run yet
        else:
            steps_seen.append(entry)
    assert steps_seen == list(range(12))
    assert updates == [2, 5, 8, 11]


def test_make_occupancy_uses_the_models_grid_settings():
    # Catches: make_occupancy dropping the model's threshold/decay (OccupancyGrid's own defaults differ from
    # ModelConfig's), its box the world's instead of the model frame's, or a grid built in NDC / at resolution 0.
    model = ModelConfig(aabb=((1, 2, 3), (2, 4, 6)), occupancy_resolution=8, occupancy_threshold=0.3,
                        occupancy_decay=0.6)
    grid = make_occupancy(model, "cpu")
    assert (grid.resolution, grid.threshold, grid.decay) == (8, 0.3, 0.6)
    assert torch.equal(grid.aabb, torch.tensor(model.field_aabb, dtype=torch.float32))
    assert make_occupancy(dataclasses.replace(model, occupancy_resolution=0), "cpu") is None
    assert make_occupancy(dataclasses.replace(model, ndc=True), "cpu") is None


@pytest.mark.parametrize("steps,every,expect", [(12, 5, [5, 10, 12]), (10, 5, [5, 10]), (7, 0, [7])])
def test_checkpoints_every_n_done_steps_and_at_the_end(monkeypatch, tmp_path, steps, every, expect):
    # Catches: the modulo taken on the 0-based step (checkpoints at 1, 6, 11), no final checkpoint, a
    # duplicate final write when the last step is also a multiple.
    written = []
    monkeypatch.setattr(loop, "save_checkpoint", lambda path, state: written.append(state["step"]))
    train_field(EmptyField(), _straight_rays("black", None), _hand_cfg(steps=steps, checkpoint_every=every),
                checkpoint=tmp_path / "c.pt", progress=False)
    assert written == expect


def test_nerf_field_is_annealed_at_every_step():
    # Catches: the loop not calling set_progress(step) (NeRF would train with every band on from step 0),
    # or calling it with step + 1.  build_field(steps=8) anneals over N = 8 // 4 = 2 steps of 10 bands:
    # eta = 10 s / 2 -> step 0: all off; step 1: eta 5, bands 0..4 on; step >= 2: all on.
    model = dataclasses.replace(MODEL, field="nerf", occupancy_resolution=0, train_background="black")
    rays = _straight_rays("black", None)
    rays = RayBatchSource(rays.origins, rays.dirs, rays.rgb, None, rays.near, rays.far, model)
    seen = {}

    def hook(field, step, generator, occupancy):
        seen[step] = field.band_weights.clone()
        return torch.zeros(()), {}

    train_field(build_field(model, seed=0, steps=8), rays, _hand_cfg(steps=4, tv_weight=0.0), extra_loss=hook,
                progress=False)
    assert torch.equal(seen[0], torch.zeros(10))
    assert torch.equal(seen[1], torch.tensor([1.0] * 5 + [0.0] * 5))
    assert torch.equal(seen[2], torch.ones(10)) and torch.equal(seen[3], torch.ones(10))


def test_a_nerf_field_built_without_its_step_count_anneals_over_a_quarter_of_the_training():
    # Catches: build_field(model) (steps=None, documented) giving a NeRF field whose set_progress(step) fails at
    # step 0.  Expected: the same training as a field built with steps=cfg.steps, bit for bit.
    nerf = dataclasses.replace(MODEL, field="nerf")
    rays, cfg = _rays(model=nerf), _cfg(steps=8)
    bare = train_field(build_field(nerf, seed=0), rays, cfg, progress=False).field
    told = train_field(build_field(nerf, seed=0, steps=cfg.steps), rays, cfg, progress=False).field
    for (name, a), (_, b) in zip(bare.state_dict().items(), told.state_dict().items()):
        assert torch.equal(a, b), name


# ---------------------------------------------------------------------------------------------------------
# training and resuming a K-Planes field


def test_training_reduces_the_loss():
    res = train_field(build_field(MODEL, seed=0), _rays(), _cfg(steps=40, lr=0.05), progress=False, log_every=5)
    assert res.history[-1]["loss"] < res.history[0]["loss"]
    assert res.steps == 40 and res.resumed_from == 0 and res.occupancy is not None
    assert not res.field.training


def test_a_resumed_training_ends_bit_identical_to_an_uninterrupted_one(tmp_path):
    # Catches: any state a resume does not restore (the generator's stream, Adam's moments and step counts, the
    # occupancy grid, the lr schedule's step), a checkpoint that is not plain data, and the interrupted call's
    # training seconds lost.
    rays, cfg = _rays(), _cfg()
    full = train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss, checkpoint=tmp_path / "a.pt",
                       progress=False)
    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    at_5 = torch.load(tmp_path / "b.pt", weights_only=True)
    assert at_5["step"] == 5 and at_5["seconds"] > 0.0
    at_5["seconds"] = 1000.0   # as if the first call had trained slowly
    torch.save(at_5, tmp_path / "b.pt")
    resumed = _resume(rays, cfg, tmp_path / "b.pt")
    assert resumed.resumed_from == 5 and resumed.steps == cfg.steps
    a, b = full.field.state_dict(), resumed.field.state_dict()
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    assert torch.equal(full.occupancy.mask, resumed.occupancy.mask)
    assert full.seconds_before == 0.0 and resumed.seconds_before == 1000.0
    final = torch.load(tmp_path / "b.pt", weights_only=True)["seconds"]
    assert 1000.0 < final <= 1000.0 + resumed.seconds
    # the parameters really changed during training (the comparison is not between two inits)
    assert not torch.equal(build_field(MODEL, seed=1).state_dict()["table"], a["table"])
    # a finished training resumes at its end: nothing more is trained
    again = _resume(rays, cfg, tmp_path / "b.pt")
    assert again.resumed_from == cfg.steps and all(torch.equal(a[k], again.field.state_dict()[k]) for k in a)


def test_each_checkpoint_records_its_host_and_a_resume_reads_only_the_training_state(tmp_path):
    # Catches: the host record dropped from the checkpoint, or the resume depending on it (a warning, or other
    # figures, for a checkpoint written with another thread count).
    rays, cfg = _rays(), _cfg()
    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    state = torch.load(tmp_path / "b.pt", weights_only=True)
    assert state["host"] == host_record("cpu")
    state["host"] = dict(state["host"], threads=state["host"]["threads"] + 14)
    torch.save(state, tmp_path / "moved.pt")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        moved = _resume(rays, cfg, tmp_path / "moved.pt")
    same = _resume(rays, cfg, tmp_path / "b.pt")
    assert moved.resumed_from == same.resumed_from == 5
    assert all(torch.equal(v, same.field.state_dict()[k]) for k, v in moved.field.state_dict().items())


def test_a_resume_on_another_device_type_reseeds_reproducibly_with_a_warning(tmp_path):
    # A run started on a GPU and resumed on the CPU continues, reproducibly, from a stream seeded from
    # (seed, step) instead of failing on the foreign generator state; one warning says so.
    rays, cfg = _rays(), _cfg()
    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    state = torch.load(tmp_path / "b.pt", weights_only=True)
    assert state["generator_device"] == "cpu"
    state["generator"], state["generator_device"] = torch.zeros(16, dtype=torch.uint8), "cuda"   # (seed, offset)
    tables = []
    for k in range(2):
        torch.save(state, tmp_path / f"gpu{k}.pt")
        with pytest.warns(UserWarning) as caught:
            res = _resume(rays, cfg, tmp_path / f"gpu{k}.pt")
        (line,) = [str(w.message) for w in caught]   # the reseeding one
        assert f"gpu{k}.pt" in line and "cuda" in line
        assert res.resumed_from == 5 and res.steps == cfg.steps
        tables.append(res.field.state_dict()["table"])
    assert torch.equal(tables[0], tables[1])   # reproducible
    same_device = _resume(rays, cfg, tmp_path / "b.pt")
    assert not torch.equal(tables[0], same_device.field.state_dict()["table"])  # a new stream, as it says


def _other_model_checkpoint(tmp_path: Path) -> dict:
    other = dataclasses.replace(MODEL, resolution=16)
    train_field(build_field(other, seed=0), _rays(model=other), _cfg(steps=2), checkpoint=tmp_path / "o.pt",
                progress=False)
    return torch.load(tmp_path / "o.pt", weights_only=True)


def _sound_checkpoint(tmp_path: Path) -> dict:
    train_field(build_field(MODEL, seed=0), _rays(), _cfg(steps=5), checkpoint=tmp_path / "s.pt", progress=False)
    return torch.load(tmp_path / "s.pt", weights_only=True)


@pytest.mark.parametrize("damage", [
    lambda s, p: dict(format="senerf-selftrain-1", iteration=0),
    lambda s, p: {k: v for k, v in s.items() if k != "format"},
    lambda s, p: dict(s, format=1),
    lambda s, p: _other_model_checkpoint(p),
    lambda s, p: {k: v for k, v in s.items() if k != "occupancy"},
    lambda s, p: dict(s, step=3, generator=torch.zeros(3, dtype=torch.uint8)),
    lambda s, p: dict(s, field=[1, 2]),
    lambda s, p: {k: v for k, v in s.items() if k != "seconds"},
], ids=["selftrain-teacher", "no-format", "format-a-number", "another-model", "no-grid", "bad-generator",
        "field-not-a-dict", "no-seconds"])
def test_a_checkpoint_the_training_cannot_resume_from_is_refused_naming_it(tmp_path, damage):
    # Catches: a checkpoint of another kind, of another model's shapes or without the state it needs resumed
    # (or failing as a traceback) instead of one line naming the file.
    path = tmp_path / "c.pt"
    save_checkpoint(path, damage(_sound_checkpoint(tmp_path), tmp_path))
    with pytest.raises(InputError) as err:
        train_field(build_field(MODEL, seed=0), _rays(), _cfg(steps=5), checkpoint=path, progress=False)
    assert err.value.file == str(path) and "\n" not in str(err.value)


def test_train_field_refuses_rays_it_cannot_train_on():
    with pytest.raises(ValueError, match="RayBatchSource"):
        train_field(EmptyField(), dict(origins=torch.zeros(4, 3)), _cfg(steps=1), progress=False)
    rays = _straight_rays("black", None)
    meta = RayBatchSource(*(t.to("meta") for t in (rays.origins, rays.dirs, rays.rgb)), None,
                          rays.near.to("meta"), rays.far.to("meta"), rays.model)
    with pytest.raises(ValueError, match="meta"):
        train_field(EmptyField(), meta, _cfg(steps=1), progress=False)


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without a GPU")
def test_cuda_without_a_gpu_is_refused_naming_the_device():
    with pytest.raises(InputError) as err:
        train_field(EmptyField(), _straight_rays("black", None), _cfg(steps=1, device="cuda"), progress=False)
    assert err.value.field == "device"


def _on(rays: RayBatchSource, device: str) -> RayBatchSource:
    return RayBatchSource(*(t.to(device) for t in (rays.origins, rays.dirs, rays.rgb, rays.alpha, rays.near,
                                                   rays.far)), rays.model)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_trains_on_cuda():
    res = train_field(build_field(MODEL, seed=0), _on(_rays(), "cuda"), _cfg(steps=6, device="cuda"), progress=False)
    assert next(res.field.parameters()).is_cuda and math.isfinite(res.history[-1]["loss"])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_resume_on_cuda_continues_with_host_step_counters(tmp_path, monkeypatch):
    # A CUDA run killed at step 8 resumes from step 5's checkpoint (loaded on the host, copied into the device
    # tensors): it finishes on the GPU, close to the uninterrupted run (CUDA's index_add_ is not deterministic,
    # so not to the bit), and Adam's step counters live where a fresh run's do (the host).
    optimizers = []

    class RecordingAdam(torch.optim.Adam):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            optimizers.append(self)

    monkeypatch.setattr(torch.optim, "Adam", RecordingAdam)
    rays, cfg = _on(_rays(), "cuda"), _cfg(device="cuda")
    full = train_field(build_field(MODEL, seed=1), rays, cfg, extra_loss=_zero_loss, checkpoint=tmp_path / "a.pt",
                       progress=False)
    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    resumed = _resume(rays, cfg, tmp_path / "b.pt")
    assert resumed.resumed_from == 5 and len(optimizers) == 3
    assert next(resumed.field.parameters()).device.type == "cuda"
    fresh = {s["step"].device for s in optimizers[0].state.values()}     # the uninterrupted run's
    assert fresh and {s["step"].device for s in optimizers[-1].state.values()} == fresh
    a, b = full.field.state_dict(), resumed.field.state_dict()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-3, atol=1e-4)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_cpu_checkpoint_resumed_on_cuda_warns_and_finishes_there(tmp_path):
    # The real case the simulated one above stands for: a CPU run's generator state cannot continue as a CUDA
    # stream, so the resume reseeds with one warning and finishes on the GPU.
    rays, cfg = _rays(), _cfg()
    _crash_at_step_8(rays, cfg, tmp_path / "b.pt")
    with pytest.warns(UserWarning) as caught:
        res = _resume(_on(rays, "cuda"), _cfg(device="cuda"), tmp_path / "b.pt")
    assert len(caught) == 1 and "b.pt" in str(caught[0].message)
    assert res.resumed_from == 5 and next(res.field.parameters()).is_cuda
