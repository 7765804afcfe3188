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
    assert torch.all(pts[:, 0, 0] < 0.25)  # column 3 (x = 0.3) is the unreliable centre column
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


# ---------------------------------------------------------------------------------------------------------
# Kernel at another size / std, neighbour indexing across views, the prior target against the dense
# reference, and the losses by hand (soft weights, both geometry targets).


def test_gaussian_kernel_5x5_std_1p5_by_hand():
    """Catches a wrong variance in the exponent (``2 std`` instead of ``2 std^2``: equal at std = 1 only)."""
    g = gaussian_kernel(5, 1.5)
    # 2 std^2 = 4.5; squared radii of the 24 offsets: 1 (x4), 2 (x4), 4 (x4), 5 (x8), 8 (x4)
    unnorm = {1: math.exp(-1 / 4.5), 2: math.exp(-2 / 4.5), 4: math.exp(-4 / 4.5), 5: math.exp(-5 / 4.5),
              8: math.exp(-8 / 4.5)}
    total = 4 * unnorm[1] + 4 * unnorm[2] + 4 * unnorm[4] + 8 * unnorm[5] + 4 * unnorm[8]
    offs = neighbour_offsets(5)
    assert g.shape == (24,)
    for (dy, dx), w in zip(offs, g):
        assert w == pytest.approx(unnorm[int(dy * dy + dx * dx)] / total, rel=1e-12)
    # e.g. the edge neighbour against the corner (+-2, +-2): exp((8 - 1) / 4.5) = exp(1.5556) = 4.7377...
    assert g[offs.tolist().index([0, 1])] / g[offs.tolist().index([2, 2])] == pytest.approx(4.73772, rel=1e-5)


def test_unified_prior_weights_ignore_background_neighbours():
    """Catches using every neighbour in the unified weights instead of foreground ones only (``fg_n``)."""
    s = np.array([[0.95, 0.6, 0.1],
                  [0.1, 0.4, 0.1],
                  [0.1, 0.1, 0.99]])
    fg = np.ones_like(s, bool)
    fg[0, 0] = False   # background, more similar than the centre (0.95 > 0.4)
    fg[2, 2] = False   # background, the most similar pixel of all
    w, has = unified_prior_weights(s, fg)
    offs = [tuple(o) for o in neighbour_offsets(3)]
    # centre (1, 1): the only more similar *foreground* neighbour is (0, 1): all the weight there
    expected = np.zeros(8)
    expected[offs.index((-1, 0))] = 1.0
    np.testing.assert_allclose(w[1, 1], expected, atol=1e-7)
    # (1, 2), s = 0.1: foreground (0, 1) 0.6 and (1, 1) 0.4 are more similar, background (2, 2) 0.99 does not count
    g_edge, g_diag = math.exp(-0.5), math.exp(-1.0)
    raw = np.zeros(8)
    raw[offs.index((-1, -1))] = 0.5 * g_diag   # (0, 1): 0.6 - 0.1
    raw[offs.index((0, -1))] = 0.3 * g_edge    # (1, 1): 0.4 - 0.1
    np.testing.assert_allclose(w[1, 2], raw / raw.sum(), rtol=1e-6)
    # (0, 1), s = 0.6: its only more similar neighbour is the background (0, 0): no prior neighbour at all
    assert not has[0, 1] and np.all(w[0, 1] == 0)


def test_neighbours_flat_indices_in_the_second_view_and_along_x():
    """Catches a lost view offset (``base = 0``) and an ignored column offset (``nx = x``) in
    ``PseudoRays.neighbours``: flat index = view * H * W + row * W + column, window clamped at the edges."""
    p, h, w = 2, 4, 5
    rel = np.zeros((p, h, w), bool)
    rel[0, :, :2] = True      # view 0: two left columns reliable
    rel[1, 2:, :] = True      # view 1: two bottom rows reliable
    pseudo = make_pseudo(p=p, h=h, w=w, reliable=rel)
    # offsets in the order (-1,-1) (-1,0) (-1,1) (0,-1) (0,1) (1,-1) (1,0) (1,1)
    table = {
        7: [1, 2, 3, 6, 8, 11, 12, 13],           # view 0, (1, 2)
        27: [21, 22, 23, 26, 28, 31, 32, 33],     # view 1, (1, 2): 20 + the row above
        24: [23, 24, 24, 23, 24, 28, 29, 29],     # view 1, (0, 4): top-right corner, clamped
        39: [33, 34, 34, 38, 39, 38, 39, 39],     # view 1, (3, 4): bottom-right corner, clamped
        20: [20, 20, 21, 20, 21, 25, 25, 26],     # view 1, (0, 0): top-left corner, clamped
    }
    idx = torch.tensor(list(table))
    flat, wts = pseudo.neighbours(idx)
    assert flat.tolist() == list(table.values())
    torch.testing.assert_close(wts, pseudo.neighbour[idx])


class BinField(torch.nn.Module):
    """Teacher density constant inside each of ``s`` bins of [0, 2] along z, varying with x and y:
    ``sigma = (1 + 5 x + 3 y) (1 + k)``, bin ``k = floor(z s / 2)``; so its per-bin values do not depend on
    where in the bin a sample falls and a dense per-pixel reference can be written down."""

    def __init__(self, s: int):
        super().__init__()
        self.s = s

    def density(self, xyz):
        k = torch.floor(xyz[:, 2] * self.s / 2.0)
        return (1.0 + 5.0 * xyz[:, 0] + 3.0 * xyz[:, 1]) * (1.0 + k)

    def forward(self, xyz, dirs):
        return self.density(xyz), torch.full_like(xyz, 0.5)


def test_prior_target_is_the_dense_gaussian_prior():
    """Catches dropping the Gaussian neighbour weights in ``_prior_target`` (a plain sum of the neighbours'
    values) and mixing views: the target of every prior ray equals ``gaussian_prior`` on its own view."""
    s, p, h, w = 8, 2, 5, 6
    rel = np.zeros((p, h, w), bool)
    rel[0, :, :2] = True                      # view 0: a vertical band
    rel[0, 4, 2:4] = True
    rel[1, 0, :] = True                       # view 1: the top row and a few scattered pixels
    rel[1, 3, 1] = rel[1, 2, 4] = True
    pseudo = make_pseudo(p=p, h=h, w=w, reliable=rel)
    pseudo.origins.view(p, h, w, 3)[1, ..., 0] += 1.0   # view 1's rays sit at x + 1: other teacher values
    cfg = DistillConfig(geometry_target="log_density")
    loss = DistillationLoss(BinField(s), pseudo, cfg, n_samples=s, background="black")
    idx = torch.nonzero(pseudo.prior > 0).squeeze(1)
    assert idx.numel() > 10
    got = loss._prior_target(idx, torch.Generator().manual_seed(0)).numpy()
    # dense reference: the teacher's log1p(density) of every pixel's ray in every bin
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    k = np.arange(s)
    expected = np.zeros((p, h, w, s))
    for v in range(p):
        x, y = xs / 10.0 + v, ys / 10.0
        teacher = np.log1p((1 + 5 * x + 3 * y)[..., None] * (1 + k))
        target, has = gaussian_prior(rel[v], teacher)
        expected[v] = target
        assert np.all(has[~rel[v]] == (pseudo.prior.view(p, h, w)[v].numpy() > 0)[~rel[v]])
    # the neighbours of one centre have unequal weights (edge and diagonal) and unequal values
    wts = pseudo.neighbour[idx]
    assert bool(((wts > 0).sum(1) >= 2).any()) and len({round(float(v), 6) for v in wts[wts > 0]}) >= 3
    np.testing.assert_allclose(got, expected.reshape(-1, s)[idx.numpy()], rtol=1e-5)


class ConstField(torch.nn.Module):
    """Constant density and colour everywhere."""

    def __init__(self, sigma: float, rgb):
        super().__init__()
        self.sigma = sigma
        self.rgb = torch.tensor(rgb, dtype=torch.float32)

    def density(self, xyz):
        return torch.full((xyz.shape[0],), self.sigma)

    def forward(self, xyz, dirs):
        return self.density(xyz), self.rgb.expand(xyz.shape[0], 3)


def soft_weights(pseudo: PseudoRays, m: float, prior: float) -> PseudoRays:
    """The same rays with reliable weight ``m`` on the reliable rays and prior weight ``prior`` on the prior rays
    (as the 'unified' weighting makes: not 0 / 1)."""
    return PseudoRays(pseudo.origins, pseudo.dirs, pseudo.near, pseudo.far, pseudo.shape, pseudo.reliable * m,
                      pseudo.prior * prior, pseudo.neighbour)


def test_losses_by_hand_with_soft_weights_weights_target():
    """Catches ignoring the soft reliable weight ``m`` in the colour or geometry loss, ignoring the prior
    weight ``1 - m`` in the prior loss, and a mean instead of the sum over bins of the 'weights' distance."""
    s = 4
    pseudo = soft_weights(make_pseudo(), m=0.25, prior=0.75)
    # teacher: opaque at its first sample (sigma delta >= 1e4 * 0.001: weights exactly [1, 0, 0, 0]),
    # colour (0.2, 0.4, 0.6); student: empty (weights 0), so it renders the black background
    teacher = ConstField(1e7, [0.2, 0.4, 0.6])
    student = ConstField(0.0, [0.9, 0.9, 0.9])
    cfg = DistillConfig(batch_reliable=16, batch_prior=8, geometry_target="weights")
    _, logs = DistillationLoss(teacher, pseudo, cfg, n_samples=s, background="black")(
        student, 0, torch.Generator().manual_seed(0))
    assert logs["n_reliable"] == 16 and logs["n_prior"] == 8
    # L_c = mean_r m ||C_T - C_S||^2 = 0.25 (0.04 + 0.16 + 0.36) = 0.14
    assert logs["distill_color"] == pytest.approx(0.14, rel=1e-6)
    # L_g = mean_r m sum_k (w_T - w_S)^2 = 0.25 (1 + 0 + 0 + 0) = 0.25  (a mean over the 4 bins: 0.0625)
    assert logs["distill_geometry"] == pytest.approx(0.25, rel=1e-6)
    # the prior target is the normalised average of neighbours' [1, 0, 0, 0]: [1, 0, 0, 0];
    # L_p = mean_r (1 - m) sum_k (target - w_S)^2 = 0.75
    assert logs["distill_prior"] == pytest.approx(0.75, rel=1e-6)


def test_losses_by_hand_log_density_target():
    """Catches the 'log_density' target computed on raw densities (``sigma`` for ``log1p(sigma)``), in the
    reliable geometry loss or in the prior target, and a sum instead of the mean over bins there."""
    s = 4
    pseudo = soft_weights(make_pseudo(), m=0.25, prior=0.75)
    teacher, student = ConstField(3.0, [0.5, 0.5, 0.5]), ConstField(1.0, [0.5, 0.5, 0.5])
    cfg = DistillConfig(batch_reliable=16, batch_prior=8, geometry_target="log_density")
    _, logs = DistillationLoss(teacher, pseudo, cfg, n_samples=s, background="black")(
        student, 0, torch.Generator().manual_seed(0))
    # every bin: (log1p(3) - log1p(1))^2 = (ln 4 - ln 2)^2 = (ln 2)^2 = 0.480453; the mean over bins is the same
    d = math.log(2.0) ** 2
    assert logs["distill_geometry"] == pytest.approx(0.25 * d, rel=1e-5)   # raw densities: 0.25 * 4 = 1
    assert logs["distill_prior"] == pytest.approx(0.75 * d, rel=1e-5)
