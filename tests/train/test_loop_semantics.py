"""What one training step computes (loss, target compositing, lr per step), and when the loop updates the
occupancy grid and writes checkpoints (senerf/train/loop.py; mutation audit).

The fields here have zero density, so the rendered colour is exactly the background and every loss value
can be worked out by hand."""

from __future__ import annotations

import math

import pytest
import torch

import senerf.train.loop as loop
from senerf.fields import RadianceField
from senerf.train import ModelConfig, RayBatchSource, TrainConfig, train_field


class EmptyField(RadianceField):
    """Zero density everywhere (colour 0.5); one parameter so Adam has something to step.  Records the
    points it renders and its density calls (the occupancy grid's updates) in ``log``."""

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


def _rays(background: str, alpha: float | None, occupancy: int = 0, n: int = 32) -> RayBatchSource:
    model = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), resolution=8, multires=(1,), n_features=4, n_samples=8,
                        occupancy_resolution=occupancy, train_background=background, eval_background="white")
    o = torch.tensor([0.0, 0.0, -3.0]).expand(n, 3).contiguous()
    d = torch.tensor([0.0, 0.0, 1.0]).expand(n, 3).contiguous()
    a = None if alpha is None else torch.full((n,), alpha)
    return RayBatchSource(o, d, COLOUR.expand(n, 3).contiguous(), a, torch.full((n,), 2.0), torch.full((n,), 4.0),
                          model)


def _cfg(**kw) -> TrainConfig:
    base = dict(steps=4, batch_rays=16, lr=0.1, warmup_steps=2, lr_final_factor=0.1, tv_weight=0.2,
                occupancy_every=3, occupancy_warmup=2, checkpoint_every=5, seed=0)
    return TrainConfig(**{**base, **kw})


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
    res = train_field(EmptyField(), _rays(background, alpha), _cfg(), progress=False, log_every=1)
    assert [h["step"] for h in res.history] == [1, 2, 3, 4]
    for h in res.history:
        assert h["loss"] == pytest.approx(photo + 0.2 * 0.5, rel=1e-6)
        assert h["psnr"] == pytest.approx(-10 * math.log10(photo), rel=1e-6)
    assert [h["lr"] for h in res.history] == pytest.approx([0.05, 0.1, 0.1, 0.055], rel=1e-12)


def test_occupancy_grid_updates_at_warmup_then_every_n_steps():
    # Catches: the first update one period late (step > warmup), the period counted from step 0 instead of
    # from the warm-up, updates before the warm-up.  warmup 2, every 3, 12 steps: updates at 2, 5, 8, 11.
    field = EmptyField()
    steps_seen = []

    def hook(f, step, generator, occupancy):
        field.log.append(step)
        return torch.zeros(()), {}

    train_field(field, _rays("black", None, occupancy=8), _cfg(steps=12), extra_loss=hook, progress=False)
    updates = []
    for entry in field.log:
        if entry == "density":
            updates.append(len(steps_seen))       # the step whose hook has not run yet
        else:
            steps_seen.append(entry)
    assert steps_seen == list(range(12))
    assert updates == [2, 5, 8, 11]


@pytest.mark.parametrize("steps,every,expect", [(12, 5, [5, 10, 12]), (10, 5, [5, 10]), (7, 0, [7])])
def test_checkpoints_every_n_done_steps_and_at_the_end(monkeypatch, tmp_path, steps, every, expect):
    # Catches: the modulo taken on the 0-based step (checkpoints at 1, 6, 11), no final checkpoint, a
    # duplicate final write when the last step is also a multiple.
    written = []
    monkeypatch.setattr(loop, "save_checkpoint", lambda path, state: written.append(state["step"]))
    train_field(EmptyField(), _rays("black", None), _cfg(steps=steps, checkpoint_every=every),
                checkpoint=tmp_path / "c.pt", progress=False)
    assert written == expect


def test_training_samples_are_jittered_inside_their_bins():
    # Catches: training rays rendered at the deterministic bin centres (randomized=False), which aliases.
    # Rays from z = -3 along +z, near 2, far 4, 8 bins of 0.25: sample k lies in z in [-1 + 0.25 k,
    # -1 + 0.25 (k + 1)], and the centres are -1 + 0.25 (k + 0.5).
    field = EmptyField()
    train_field(field, _rays("black", None), _cfg(steps=1), progress=False)
    z = field.points[0][:, 2].view(16, 8)
    lo = -1.0 + 0.25 * torch.arange(8.0)
    assert ((z >= lo - 1e-6) & (z <= lo + 0.25 + 1e-6)).all()
    assert (z - (lo + 0.125)).abs().max() > 0.05


def test_checkpoint_every_is_not_part_of_the_run_identity(tmp_path):
    # Catches: checkpoint_every in the resume fingerprint (changing only how often checkpoints are written
    # must not refuse a resume); a changed lr is still refused.
    from senerf.errors import InputError

    rays = _rays("black", None)
    train_field(EmptyField(), rays, _cfg(checkpoint_every=0), checkpoint=tmp_path / "c.pt", progress=False)
    res = train_field(EmptyField(), rays, _cfg(checkpoint_every=3), checkpoint=tmp_path / "c.pt", progress=False)
    assert res.resumed_from == 4
    with pytest.raises(InputError, match="different training configuration"):
        train_field(EmptyField(), rays, _cfg(lr=0.2), checkpoint=tmp_path / "c.pt", progress=False)


def test_nerf_field_is_annealed_at_every_step():
    # Catches: the loop not calling set_progress(step) (NeRF would train with every band on from step 0),
    # or calling it with step + 1.  build_field(steps=8) anneals over N = 8 // 4 = 2 steps of 10 bands:
    # eta = 10 s / 2 -> step 0: all off; step 1: eta 5, bands 0..4 on; step >= 2: all on.
    from senerf.train import build_field

    rays = _rays("black", None)
    model = ModelConfig(field="nerf", aabb=((-1, -1, -1), (1, 1, 1)), n_samples=8, occupancy_resolution=0,
                        train_background="black", eval_background="black")
    rays = RayBatchSource(rays.origins, rays.dirs, rays.rgb, None, rays.near, rays.far, model)
    seen = {}

    def hook(field, step, generator, occupancy):
        seen[step] = field.band_weights.clone()
        return torch.zeros(()), {}

    train_field(build_field(model, seed=0, steps=8), rays, _cfg(steps=4, tv_weight=0.0), extra_loss=hook,
                progress=False)
    assert torch.equal(seen[0], torch.zeros(10))
    assert torch.equal(seen[1], torch.tensor([1.0] * 5 + [0.0] * 5))
    assert torch.equal(seen[2], torch.ones(10)) and torch.equal(seen[3], torch.ones(10))


def test_make_occupancy_uses_the_models_grid_settings():
    # Catches: make_occupancy dropping the model's threshold/decay (OccupancyGrid's defaults 0.01/0.95 differ
    # from ModelConfig's 0.1/0.7), or building a grid in NDC / with occupancy_resolution 0.
    import dataclasses

    from senerf.train import make_occupancy

    model = ModelConfig(aabb=((1, 2, 3), (2, 4, 6)), occupancy_resolution=8, occupancy_threshold=0.3,
                        occupancy_decay=0.6)
    grid = make_occupancy(model, "cpu")
    assert (grid.resolution, grid.threshold, grid.decay) == (8, 0.3, 0.6)
    assert torch.equal(grid.aabb, torch.tensor(model.field_aabb, dtype=torch.float32))
    assert make_occupancy(dataclasses.replace(model, occupancy_resolution=0), "cpu") is None
    assert make_occupancy(dataclasses.replace(model, ndc=True), "cpu") is None
