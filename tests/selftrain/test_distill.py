"""Tests of senerf.selftrain.distill: Gaussian prior weights, bin pairing, the distillation loss."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from senerf.fields import stratified_bins
from senerf.selftrain.distill import (
    DistillationLoss,
    DistillConfig,
    PseudoRays,
    bins_with_fractions,
    gaussian_kernel,
    gaussian_prior,
    neighbour_offsets,
    prior_weights,
    unified_prior_weights,
)


def test_gaussian_kernel_3x3_std1_by_hand():
    g = gaussian_kernel(3, 1.0)
    edge, diag = math.exp(-0.5), math.exp(-1.0)
    total = 4 * edge + 4 * diag
    offs = neighbour_offsets(3)
    assert offs.shape == (8, 2) and not np.any(np.all(offs == 0, axis=1))
    for (dy, dx), w in zip(offs, g):
        expected = (diag if dy and dx else edge) / total
        assert w == pytest.approx(expected, rel=1e-12)
    assert g.sum() == pytest.approx(1.0)


def test_prior_only_where_a_reliable_neighbour_exists():
    m = np.zeros((5, 6), bool)
    m[2, 2] = True
    w, has = prior_weights(m)
    expected_has = np.zeros_like(m)
    expected_has[1:4, 1:4] = True
    expected_has[2, 2] = False  # the centre itself is excluded from its own kernel
    np.testing.assert_array_equal(has, expected_has)
    # a pixel whose only reliable neighbour is that pixel puts all its weight on it
    offs = neighbour_offsets(3)
    for y, x in zip(*np.nonzero(has)):
        k = [i for i, (dy, dx) in enumerate(offs) if (y + dy, x + dx) == (2, 2)]
        assert w[y, x, k[0]] == pytest.approx(1.0)
    assert np.all(w[~has] == 0)


def test_gaussian_prior_weighted_average_by_hand():
    h, w_, s = 4, 4, 5
    rng = np.random.default_rng(0)
    teacher = rng.uniform(size=(h, w_, s))
    m = np.zeros((h, w_), bool)
    m[1, 2] = True   # edge neighbour of (1, 1)
    m[2, 2] = True   # diagonal neighbour of (1, 1)
    m[0, 3] = True   # outside (1, 1)'s 3x3 window
    target, has = gaussian_prior(m, teacher)
    edge, diag = math.exp(-0.5), math.exp(-1.0)
    expected = (edge * teacher[1, 2] + diag * teacher[2, 2]) / (edge + diag)
    np.testing.assert_allclose(target[1, 1], expected, rtol=1e-6)
    assert has[1, 1] and not has[3, 0]
    np.testing.assert_array_equal(target[3, 0], 0.0)


def test_unified_prior_weights_use_only_more_similar_neighbours():
    s = np.array([[0.2, 0.9, 0.1], [0.5, 0.4, 0.3], [0.0, 0.0, 0.0]])
    fg = np.ones_like(s, bool)
    fg[0, 0] = False
    w, has = unified_prior_weights(s, fg)
    # centre (1, 1), s = 0.4: more similar foreground neighbours are (0, 1) (+0.5, edge) and (1, 0) (+0.1, edge)
    offs = [tuple(o) for o in neighbour_offsets(3)]
    raw = np.zeros(8)
    raw[offs.index((-1, 0))] = 0.5
    raw[offs.index((0, -1))] = 0.1
    np.testing.assert_allclose(w[1, 1], raw / raw.sum(), rtol=1e-6)
    assert not has[0, 1]  # the most similar pixel has no more similar neighbour


def test_bins_with_fractions_matches_stratified_bins():
    near = torch.tensor([2.0, 1.0, 0.5])
    far = torch.tensor([6.0, 3.0, 0.5])
    g1 = torch.Generator().manual_seed(4)
    g2 = torch.Generator().manual_seed(4)
    t_ref = stratified_bins(near, far, 7, g1)
    u = torch.rand(3, 7, generator=g2)
    torch.testing.assert_close(bins_with_fractions(near, far, u), t_ref)


class SpyField(torch.nn.Module):
    """Density a smooth function of position; records every batch of points it is asked about."""

    def __init__(self, shift: float = 0.0):
        super().__init__()
        self.scale = torch.nn.Parameter(torch.tensor(2.0))
        self.shift = shift
        self.calls: list[torch.Tensor] = []

    def density(self, xyz):
        self.calls.append(xyz.detach().clone())
        return self.scale * torch.exp(-((xyz[:, 2] - 1.0 - self.shift) ** 2) * 8.0) * 5.0

    def forward(self, xyz, dirs):
        sigma = self.density(xyz)
        rgb = torch.sigmoid(xyz * self.scale)
        return sigma, rgb

    def regularizer(self):
        return torch.zeros(())


def make_pseudo(p=1, h=6, w=7, reliable=None, n_near=0.0, n_far=2.0) -> PseudoRays:
    """Parallel rays along +z from a grid of origins: pixel (y, x) of view p starts at (x/10, y/10, 0)."""
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    o = np.stack([xs / 10.0, ys / 10.0, np.zeros_like(xs, dtype=float)], -1)
    o = np.broadcast_to(o, (p, h, w, 3)).reshape(-1, 3)
    d = np.tile([0.0, 0.0, 1.0], (o.shape[0], 1))
    if reliable is None:
        reliable = np.zeros((p, h, w), bool)
        reliable[:, :, : w // 2] = True
    nb, has = prior_weights(reliable)
    prior = (~reliable) & has
    n = p * h * w
    f32 = lambda a: torch.from_numpy(np.array(a, dtype=np.float32))  # a writable copy  # noqa: E731
    return PseudoRays(f32(o), f32(d), torch.full((n,), n_near), torch.full((n,), n_far), (p, h, w),
                      f32(reliable.reshape(-1)), f32(prior.reshape(-1)), f32(nb.reshape(n, 8)))


def bin_of(points: torch.Tensor, near: float, far: float, s: int) -> torch.Tensor:
    t = points[:, 2]  # rays go along +z from z = 0 with unit direction
    return torch.floor((t - near) / (far - near) * s).long()


def test_density_pairing_uses_the_same_bins():
    s = 16
    pseudo = make_pseudo()
    teacher, student = SpyField(), SpyField()
    cfg = DistillConfig(batch_reliable=32, batch_prior=8, prior=False)
    loss = DistillationLoss(teacher, pseudo, cfg, n_samples=s, background="white")
    loss(student, 0, torch.Generator().manual_seed(0))
    (tp,), (sp,) = teacher.calls, student.calls
    kt = bin_of(tp, 0.0, 2.0, s).reshape(-1, s)
    ks = bin_of(sp, 0.0, 2.0, s).reshape(-1, s)
    expected = torch.arange(s).expand(32, s)
    assert torch.equal(kt, expected) and torch.equal(ks, expected)
    # the teacher's and the student's points in a bin are different random points (the student's noise)
    assert not torch.allclose(tp, sp)


def test_prior_queries_reliable_neighbours_at_shared_fractions():
    s = 8
    pseudo = make_pseudo()
    teacher, student = SpyField(), SpyField()
    cfg = DistillConfig(batch_reliable=4, batch_prior=5)
    loss = DistillationLoss(teacher, pseudo, cfg, n_samples=s, background="white")
    gen = torch.Generator().manual_seed(1)
    _, logs = loss(student, 0, gen)
    assert logs["n_prior"] == 5 and "distill_prior" in logs
    assert len(teacher.calls) == 2  # reliable rays, then the prior's neighbours
    pts = teacher.calls[1].reshape(-1, s, 3)
    # every queried neighbour lies in the reliable half of the image (x < w // 2 -> x/10 < 0.3)
    assert torch.all(pts[:, 0, 0] < 0.35)
    # neighbours are grouped per centre; within one centre's group, the per-bin fraction is shared
    frac = (pts[..., 2] / (2.0 / s)) % 1.0
    groups = {}
    for f in frac:
        groups.setdefault(tuple(np.round(f.numpy(), 5)), 0)
        groups[tuple(np.round(f.numpy(), 5))] += 1
    assert len(groups) <= 5  # at most one fraction vector per prior ray
    assert max(groups.values()) >= 2  # and it is shared by several neighbours


def test_loss_is_small_for_identical_fields_and_has_gradients():
    s = 48
    pseudo = make_pseudo()
    cfg = DistillConfig(batch_reliable=64, batch_prior=16)
    same = DistillationLoss(SpyField(), pseudo, cfg, n_samples=s, background="random")
    other = DistillationLoss(SpyField(shift=0.4), pseudo, cfg, n_samples=s, background="random")
    student = SpyField()
    l_same, logs = same(student, 0, torch.Generator().manual_seed(2))
    l_other, _ = other(student, 0, torch.Generator().manual_seed(2))
    assert torch.isfinite(l_same) and l_same.item() < 0.2 * l_other.item()
    l_other.backward()
    assert student.scale.grad is not None and torch.isfinite(student.scale.grad)
    assert {"distill_color", "distill_geometry", "distill_prior"} <= set(logs)


def test_ablation_flags_and_empty_pools():
    pseudo = make_pseudo(reliable=np.zeros((1, 6, 7), bool))
    loss = DistillationLoss(SpyField(), pseudo, DistillConfig(), n_samples=8, background="black")
    value, logs = loss(SpyField(), 0, torch.Generator().manual_seed(0))
    assert float(value) == 0.0 and logs["n_reliable"] == 0
    pseudo = make_pseudo()
    cfg = DistillConfig(density_distill=False, prior=False)
    _, logs = DistillationLoss(SpyField(), pseudo, cfg, 8)(SpyField(), 0, torch.Generator().manual_seed(0))
    assert "distill_geometry" not in logs and "distill_prior" not in logs
    with pytest.raises(ValueError):
        DistillConfig(geometry_target="depth")
    with pytest.raises(ValueError):
        DistillConfig(kernel_size=4)


class HalfGrid:
    """An occupancy stand-in: only points with z < 1 are occupied."""

    def is_occupied(self, xyz):
        return xyz[:, 2] < 1.0


class FarHalfGrid:
    """The other half: only points with z > 1 are occupied."""

    def is_occupied(self, xyz):
        return xyz[:, 2] > 1.0


def test_student_grid_chooses_where_the_student_is_marched():
    s = 16
    pseudo = make_pseudo()
    teacher, student = SpyField(), SpyField()
    cfg = DistillConfig(batch_reliable=8, batch_prior=4)
    loss = DistillationLoss(teacher, pseudo, cfg, n_samples=s, background="white", teacher_occupancy=HalfGrid())
    loss(student, 0, torch.Generator().manual_seed(3))
    assert all(bool((c[:, 2] < 1.0).all()) for c in teacher.calls + student.calls)
    assert student.calls[0].shape[0] < (8 + 4) * s  # empty samples were skipped
    student2 = SpyField()
    DistillationLoss(SpyField(), pseudo, DistillConfig(batch_reliable=8, batch_prior=4, student_grid="none"), s,
                     teacher_occupancy=HalfGrid())(student2, 0, torch.Generator().manual_seed(3))
    assert student2.calls[0].shape[0] == (8 + 4) * s
    # 'student': the grid the trainer hands over (here: z > 1 occupied), the teacher keeps its own
    teacher3, student3 = SpyField(), SpyField()
    DistillationLoss(teacher3, pseudo, DistillConfig(batch_reliable=8, batch_prior=4, student_grid="student"), s,
                     teacher_occupancy=HalfGrid())(student3, 0, torch.Generator().manual_seed(3),
                                                   occupancy=FarHalfGrid())
    assert bool((student3.calls[0][:, 2] > 1.0).all()) and bool((teacher3.calls[0][:, 2] < 1.0).all())
    student4 = SpyField()                                   # no grid yet (trainer warm-up): every sample
    DistillationLoss(SpyField(), pseudo, DistillConfig(batch_reliable=8, batch_prior=4, student_grid="student"), s,
                     teacher_occupancy=HalfGrid())(student4, 0, torch.Generator().manual_seed(3))
    assert student4.calls[0].shape[0] == (8 + 4) * s
    with pytest.raises(ValueError, match="student_grid"):
        DistillConfig(student_grid="own")


def with_empty(pseudo: PseudoRays, empty: np.ndarray) -> PseudoRays:
    """The same rays with an ``empty`` mask (a subset of the reliable rays)."""
    return PseudoRays(pseudo.origins, pseudo.dirs, pseudo.near, pseudo.far, pseudo.shape, pseudo.reliable,
                      pseudo.prior, pseudo.neighbour, q=pseudo.q, empty=torch.from_numpy(empty.reshape(-1)))


def test_surface_and_empty_pools_are_disjoint_and_cover_the_reliable_rays():
    base = make_pseudo()                                   # reliable: columns 0..2 of a 6 x 7 image
    empty = np.zeros((1, 6, 7), bool)
    empty[:, :, 0] = True                                  # column 0 is empty space
    pseudo = with_empty(base, empty)
    gen = torch.Generator().manual_seed(0)
    w = 7
    surface = pseudo.sample_surface(400, gen) % w
    hollow = pseudo.sample_empty(400, gen) % w
    assert set(surface.tolist()) == {1, 2} and set(hollow.tolist()) == {0}
    with pytest.raises(ValueError, match="reliable"):
        bad = np.zeros((1, 6, 7), bool)
        bad[:, :, 6] = True                                # column 6 is not reliable
        with_empty(base, bad)
    with pytest.raises(ValueError, match="bool"):
        PseudoRays(base.origins, base.dirs, base.near, base.far, base.shape, base.reliable, base.prior,
                   base.neighbour, empty=torch.zeros(base.origins.shape[0]))
    with pytest.raises(ValueError, match="no 'empty'"):
        base.sample_empty(4, gen)


def test_batch_empty_draws_surface_and_empty_rays_on_top_of_each_other():
    s = 8
    empty = np.zeros((1, 6, 7), bool)
    empty[:, :, 0] = True
    pseudo = with_empty(make_pseudo(), empty)
    teacher = SpyField()
    cfg = DistillConfig(batch_reliable=6, batch_empty=10, prior=False)
    _, logs = DistillationLoss(teacher, pseudo, cfg, n_samples=s, background="white")(
        SpyField(), 0, torch.Generator().manual_seed(4))
    assert logs["n_reliable"] == 16
    columns = torch.round(teacher.calls[0].reshape(-1, s, 3)[:, 0, 0] * 10).long()
    assert int((columns == 0).sum()) == 10 and int(((columns == 1) | (columns == 2)).sum()) == 6
    # 0 keeps the shared pool (and its random stream): the same draws as before the option existed
    a, b = SpyField(), SpyField()
    DistillationLoss(a, pseudo, DistillConfig(prior=False), s)(SpyField(), 0, torch.Generator().manual_seed(5))
    DistillationLoss(b, make_pseudo(), DistillConfig(prior=False), s)(SpyField(), 0,
                                                                       torch.Generator().manual_seed(5))
    assert torch.equal(a.calls[0], b.calls[0])
    with pytest.raises(ValueError):
        DistillConfig(batch_empty=-1)
