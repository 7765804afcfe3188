"""Tests of senerf.selftrain.distill: the prior's Gaussian kernel and neighbour weights by hand, the pairing of the
teacher's and the student's bins, the prior target against a dense reference written out pixel by pixel, the losses
by hand, the ray pools."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from senerf.config import SelfTrainConfig
from senerf.selftrain.distill import (DistillationLoss, PseudoRays, gaussian_kernel,
                                      neighbour_offsets, prior_weights, unified_prior_weights)

EDGE, DIAG = math.exp(-0.5), math.exp(-1.0)   # unnormalised 3 x 3 kernel, std 1: edge and diagonal neighbours

# ---------------------------------------------------------------------------------------------------------
# The kernel and the neighbour weights


def test_gaussian_kernel_3x3_std1_by_hand():
    g = gaussian_kernel(3, 1.0)
    offs = neighbour_offsets(3)
    assert offs.shape == (8, 2) and not np.any(np.all(offs == 0, axis=1))
    for (dy, dx), w in zip(offs, g):
        assert w == pytest.approx((DIAG if dy and dx else EDGE) / (4 * EDGE + 4 * DIAG), rel=1e-12)
    assert g.sum() == pytest.approx(1.0)


def test_gaussian_kernel_5x5_std_1p5_by_hand():
    """Catches a wrong variance in the exponent (``2 std`` instead of ``2 std^2``: equal at std = 1 only)."""
    g = gaussian_kernel(5, 1.5)
    # 2 std^2 = 4.5; squared radii of the 24 offsets: 1 (x4), 2 (x4), 4 (x4), 5 (x8), 8 (x4)
    unnorm = {r2: math.exp(-r2 / 4.5) for r2 in (1, 2, 4, 5, 8)}
    total = 4 * unnorm[1] + 4 * unnorm[2] + 4 * unnorm[4] + 8 * unnorm[5] + 4 * unnorm[8]
    offs = neighbour_offsets(5)
    assert g.shape == (24,)
    for (dy, dx), w in zip(offs, g):
        assert w == pytest.approx(unnorm[int(dy * dy + dx * dx)] / total, rel=1e-12)
    # the edge neighbour against the corner (+-2, +-2): exp((8 - 1) / 4.5) = 4.7377...
    assert g[offs.tolist().index([0, 1])] / g[offs.tolist().index([2, 2])] == pytest.approx(4.73772, rel=1e-5)


@pytest.mark.parametrize("q", [1, 2, 4, -3])
def test_neighbour_offsets_refuse_an_even_or_small_window(q):
    with pytest.raises(ValueError, match="q must be odd"):
        neighbour_offsets(q)


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
    one, has_one = prior_weights(np.ones((1, 1), bool))   # a one-pixel image: no neighbour inside it
    assert one.shape == (1, 1, 8) and not has_one.any()


def test_prior_weights_of_an_edge_and_a_diagonal_neighbour_by_hand():
    m = np.zeros((4, 4), bool)
    m[1, 2] = True   # edge neighbour of (1, 1)
    m[2, 2] = True   # diagonal neighbour of (1, 1)
    m[0, 3] = True   # outside (1, 1)'s 3x3 window
    w, has = prior_weights(m)
    offs = [tuple(o) for o in neighbour_offsets(3)]
    expected = np.zeros(8)
    expected[offs.index((0, 1))] = EDGE / (EDGE + DIAG)
    expected[offs.index((1, 1))] = DIAG / (EDGE + DIAG)
    np.testing.assert_allclose(w[1, 1], expected, rtol=1e-6)
    assert has[1, 1] and not has[3, 0] and np.all(w[3, 0] == 0)


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


def test_unified_prior_weights_ignore_background_neighbours():
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
    raw = np.zeros(8)
    raw[offs.index((-1, -1))] = 0.5 * DIAG   # (0, 1): 0.6 - 0.1
    raw[offs.index((0, -1))] = 0.3 * EDGE    # (1, 1): 0.4 - 0.1
    np.testing.assert_allclose(w[1, 2], raw / raw.sum(), rtol=1e-6)
    # (0, 1), s = 0.6: its only more similar neighbour is the background (0, 0): no prior neighbour at all
    assert not has[0, 1] and np.all(w[0, 1] == 0)


@pytest.mark.parametrize("call", [
    lambda: prior_weights(np.ones(5, bool)),                                     # not (..., H, W)
    lambda: unified_prior_weights(np.zeros((2, 3)), np.ones((1, 3), bool)),     # would broadcast
], ids=["prior-1d", "unified-broadcast"])
def test_prior_weights_refuse_misshapen_arrays(call):
    with pytest.raises(ValueError):
        call()


# ---------------------------------------------------------------------------------------------------------
# PseudoRays and DistillationLoss on parallel rays along +z


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
        return self.density(xyz), torch.sigmoid(xyz * self.scale)


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


class ConstField(torch.nn.Module):
    """Constant density and colour everywhere."""

    def __init__(self, sigma: float, rgb=(0.5, 0.5, 0.5)):
        super().__init__()
        self.sigma = sigma
        self.rgb = torch.tensor(rgb, dtype=torch.float32)

    def density(self, xyz):
        return torch.full((xyz.shape[0],), self.sigma)

    def forward(self, xyz, dirs):
        return self.density(xyz), self.rgb.expand(xyz.shape[0], 3)


def make_pseudo(p=1, h=6, w=7, reliable=None, prior=None) -> PseudoRays:
    """Parallel rays along +z over [0, 2] from a grid of origins: pixel (y, x) of view p starts at (x/10, y/10, 0).
    Default: the left half of every view reliable; prior on the other pixels with a reliable neighbour."""
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    o = np.stack([xs / 10.0, ys / 10.0, np.zeros_like(xs, dtype=float)], -1)
    o = np.broadcast_to(o, (p, h, w, 3)).reshape(-1, 3)
    d = np.tile([0.0, 0.0, 1.0], (o.shape[0], 1))
    if reliable is None:
        reliable = np.zeros((p, h, w), bool)
        reliable[:, :, : w // 2] = True
    nb, has = prior_weights(reliable > 0)
    if prior is None:
        prior = (~(reliable > 0)) & has
    n = p * h * w
    f32 = lambda a: torch.from_numpy(np.array(a, dtype=np.float32))  # a writable copy  # noqa: E731
    return PseudoRays(f32(o), f32(d), torch.zeros(n), torch.full((n,), 2.0), (p, h, w), f32(reliable.reshape(-1)),
                      f32(prior.reshape(-1)), f32(nb.reshape(n, 8)))


def config(**kwargs) -> SelfTrainConfig:
    return SelfTrainConfig(**{"batch_reliable": 32, "batch_prior": 8, **kwargs})


def bin_of(points: torch.Tensor, s: int) -> torch.Tensor:
    return torch.floor(points[:, 2] / 2.0 * s).long()   # rays go along +z from z = 0 over [0, 2]


def test_teacher_and_student_are_queried_in_the_same_bins_at_different_points():
    s = 16
    teacher, student = SpyField(), SpyField()
    loss = DistillationLoss(teacher, make_pseudo(), config(prior=False), n_samples=s, background="white")
    loss(student, 0, torch.Generator().manual_seed(0))
    (tp,), (sp,) = teacher.calls, student.calls
    expected = torch.arange(s).expand(32, s)
    assert torch.equal(bin_of(tp, s).reshape(-1, s), expected) and torch.equal(bin_of(sp, s).reshape(-1, s), expected)
    assert not torch.allclose(tp, sp)   # the student's noise: another random point in each bin


def test_prior_queries_reliable_neighbours_at_shared_fractions():
    s = 8
    teacher, student = SpyField(), SpyField()
    loss = DistillationLoss(teacher, make_pseudo(), config(batch_reliable=4, batch_prior=5), n_samples=s,
                            background="white")
    _, logs = loss(student, 0, torch.Generator().manual_seed(1))
    assert logs["n_prior"] == 5 and "distill_prior" in logs
    assert len(teacher.calls) == 2  # reliable rays, then the prior's neighbours
    pts = teacher.calls[1].reshape(-1, s, 3)
    assert torch.all(pts[:, 0, 0] < 0.25)   # every queried neighbour lies in the reliable columns 0..2
    # neighbours are grouped per centre; within one centre's group, the per-bin fraction is shared
    frac = (pts[..., 2] / (2.0 / s)) % 1.0
    groups: dict = {}
    for f in frac:
        key = tuple(np.round(f.numpy(), 5))
        groups[key] = groups.get(key, 0) + 1
    assert len(groups) <= 5 and max(groups.values()) >= 2


def dense_prior_target(reliable: np.ndarray, teacher: np.ndarray, q: int = 3, std: float = 1.0) -> np.ndarray:
    """The prior target of every pixel written out one by one: the average of the teacher's values ``teacher
    (H, W, S)`` on its reliable in-image neighbours (``reliable (H, W)``, centre excluded), each weighted
    ``exp(-(dx^2 + dy^2) / (2 std^2))``; zero without one."""
    h, w = reliable.shape
    r = q // 2
    target = np.zeros(teacher.shape)
    for y in range(h):
        for x in range(w):
            num, den = 0.0, 0.0
            for dy in range(-r, r + 1):
                for dx in range(-r, r + 1):
                    if (dy, dx) != (0, 0) and 0 <= y + dy < h and 0 <= x + dx < w and reliable[y + dy, x + dx]:
                        g = math.exp(-(dx * dx + dy * dy) / (2.0 * std * std))
                        num, den = num + g * teacher[y + dy, x + dx], den + g
            if den:
                target[y, x] = num / den
    return target


class OpaqueBinField(torch.nn.Module):
    """Empty along z in [0, 2] up to bin ``k0 = (round(10 x) + round(10 y)) mod s`` and opaque from it on, so a
    ray's per-bin weights are ``one_hot(k0)`` wherever in its bins the samples fall (pixel (y, x) of
    :func:`make_pseudo` starts at (x/10, y/10))."""

    def __init__(self, s: int):
        super().__init__()
        self.s = s

    def density(self, xyz):
        k0 = torch.remainder(torch.round(10.0 * xyz[:, 0]) + torch.round(10.0 * xyz[:, 1]), self.s)
        return torch.where(torch.floor(xyz[:, 2] * self.s / 2.0) >= k0, 1e8, 0.0)

    def forward(self, xyz, dirs):
        return self.density(xyz), torch.full_like(xyz, 0.5)


def test_prior_target_is_the_dense_reference():
    """The prior loss of each prior ray alone is ``sum_k (target_k - w_S,k)^2``: against an empty student
    (weights 0) the target's sum of squares, against one opaque at its first sample (weights ``[1, 0, ...]``)
    that minus ``2 target_0 - 1``; both must be those of the dense reference on the ray's own view (catches
    dropping the Gaussian weights or mixing views)."""
    s, p, h, w = 8, 2, 5, 6
    rel = np.zeros((p, h, w), bool)
    rel[0, :, :2] = True                      # view 0: a vertical band
    rel[0, 4, 2:4] = True
    rel[1, 0, :] = True                       # view 1: the top row and a few scattered pixels
    rel[1, 3, 1] = rel[1, 2, 4] = True
    base = make_pseudo(p=p, h=h, w=w, reliable=rel)
    base.origins.view(p, h, w, 3)[1, ..., 0] += 1.0   # view 1's rays sit at x + 1: other teacher values
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    expected = np.zeros((p, h, w, s))
    for v in range(p):                         # the teacher's weights of every pixel's ray in every bin
        teacher = np.eye(s)[(xs + 10 * v + ys) % s]
        expected[v] = dense_prior_target(rel[v], teacher)
    expected = expected.reshape(-1, s)
    prior_rays = torch.nonzero(base.prior > 0).squeeze(1).tolist()
    assert len(prior_rays) > 10
    cfg = config(batch_reliable=1, batch_prior=2)
    for i in prior_rays:
        one = torch.zeros_like(base.prior)
        one[i] = 1.0
        pseudo = PseudoRays(base.origins, base.dirs, base.near, base.far, base.shape, base.reliable, one,
                            base.neighbour)
        loss = DistillationLoss(OpaqueBinField(s), pseudo, cfg, n_samples=s, background="black")
        l0 = loss(ConstField(0.0), 0, torch.Generator().manual_seed(i))[1]["distill_prior"]
        l1 = loss(ConstField(1e7), 0, torch.Generator().manual_seed(i))[1]["distill_prior"]
        assert float(l0) == pytest.approx(np.sum(expected[i] ** 2), rel=1e-5)
        assert (float(l0) + 1.0 - float(l1)) / 2.0 == pytest.approx(expected[i][0], abs=1e-6)


def test_loss_is_small_for_identical_fields_and_has_gradients():
    pseudo = make_pseudo()
    cfg = config(batch_reliable=64, batch_prior=16)
    same = DistillationLoss(SpyField(), pseudo, cfg, n_samples=48, background="random")
    other = DistillationLoss(SpyField(shift=0.4), pseudo, cfg, n_samples=48, background="random")
    student = SpyField()
    l_same, logs = same(student, 0, torch.Generator().manual_seed(2))
    l_other, _ = other(student, 0, torch.Generator().manual_seed(2))
    assert torch.isfinite(l_same) and l_same.item() < 0.2 * l_other.item()
    l_other.backward()
    assert student.scale.grad is not None and torch.isfinite(student.scale.grad)
    assert {"distill_color", "distill_geometry", "distill_prior"} <= set(logs)


def test_no_reliable_rays_give_zero_loss_and_ablations_drop_their_terms():
    nothing = make_pseudo(reliable=np.zeros((1, 6, 7), bool))
    value, logs = DistillationLoss(SpyField(), nothing, config(), 8, background="black")(
        SpyField(), 0, torch.Generator().manual_seed(0))
    assert float(value) == 0.0 and logs["n_reliable"] == 0
    for off in (dict(density_distill=False, prior=False), dict(lambda_geometry=0.0, lambda_prior=0.0)):
        _, logs = DistillationLoss(SpyField(), make_pseudo(), config(**off), 8)(
            SpyField(), 0, torch.Generator().manual_seed(0))
        assert "distill_color" in logs and "distill_geometry" not in logs and "distill_prior" not in logs
        assert logs["n_prior"] == 0


def soft_weights(pseudo: PseudoRays, m: float, prior: float) -> PseudoRays:
    """The same rays with reliable weight ``m`` on the reliable rays and prior weight ``prior`` on the prior rays
    (as the 'unified' weighting makes: not 0 / 1)."""
    return PseudoRays(pseudo.origins, pseudo.dirs, pseudo.near, pseudo.far, pseudo.shape, pseudo.reliable * m,
                      pseudo.prior * prior, pseudo.neighbour)


def test_losses_by_hand_with_soft_weights():
    """Catches ignoring the soft reliable weight ``m`` in the colour or geometry loss, ignoring the prior
    weight ``1 - m`` in the prior loss, and a mean instead of the sum over bins of the 'weights' distance."""
    pseudo = soft_weights(make_pseudo(), m=0.25, prior=0.75)
    # teacher: opaque at its first sample (weights exactly [1, 0, 0, 0]), colour (0.2, 0.4, 0.6); student: empty
    # (weights 0), so it renders the black background
    teacher, student = ConstField(1e7, [0.2, 0.4, 0.6]), ConstField(0.0, [0.9, 0.9, 0.9])
    _, logs = DistillationLoss(teacher, pseudo, config(batch_reliable=16), n_samples=4, background="black")(
        student, 0, torch.Generator().manual_seed(0))
    assert logs["n_reliable"] == 16 and logs["n_prior"] == 8
    # L_c = mean_r m ||C_T - C_S||^2 = 0.25 (0.04 + 0.16 + 0.36) = 0.14
    assert logs["distill_color"] == pytest.approx(0.14, rel=1e-6)
    # L_g = mean_r m sum_k (w_T - w_S)^2 = 0.25 (1 + 0 + 0 + 0) = 0.25  (a mean over the 4 bins: 0.0625)
    assert logs["distill_geometry"] == pytest.approx(0.25, rel=1e-6)
    # the prior target is the normalised average of the neighbours' [1, 0, 0, 0]; L_p = (1 - m) * 1 = 0.75
    assert logs["distill_prior"] == pytest.approx(0.75, rel=1e-6)


class HalfGrid:
    """An occupancy stand-in: only points with z < 1 are occupied (``far``: only z > 1)."""

    def __init__(self, far: bool = False):
        self.far = far

    def is_occupied(self, xyz):
        return xyz[:, 2] > 1.0 if self.far else xyz[:, 2] < 1.0


def test_the_student_is_marched_through_the_teachers_grid_not_the_trainers():
    s, n = 16, (8 + 4) * 16
    pseudo = make_pseudo()

    def run(teacher_occupancy, occupancy=None):
        teacher, student = SpyField(), SpyField()
        DistillationLoss(teacher, pseudo, config(batch_reliable=8, batch_prior=4), s,
                         teacher_occupancy=teacher_occupancy)(student, 0, torch.Generator().manual_seed(3),
                                                              occupancy=occupancy)
        return teacher.calls, student.calls[0]

    teacher, student = run(HalfGrid())
    assert all(bool((c[:, 2] < 1.0).all()) for c in teacher + [student]) and student.shape[0] < n
    # the grid the trainer hands over (here: z > 1 occupied) is not the one the student is marched through
    teacher, student = run(HalfGrid(), HalfGrid(far=True))
    assert bool((student[:, 2] < 1.0).all()) and student.shape[0] < n
    assert run(None, HalfGrid(far=True))[1].shape[0] == n      # a teacher without a grid: every sample


def test_neighbours_flat_indices_in_the_second_view_and_along_x():
    """Flat index = view * H * W + row * W + column, the window clamped at the image edges (catches a lost view
    offset and an ignored column offset)."""
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


def _ray_args(**replace) -> dict:
    """Arguments of a valid PseudoRays of one 2 x 2 view: ray 0 reliable, rays 1 and 2 prior, ray 3 neither."""
    n = 4
    args = dict(origins=torch.zeros(n, 3), dirs=torch.zeros(n, 3), near=torch.zeros(n), far=torch.ones(n),
                shape=(1, 2, 2), reliable=torch.tensor([1.0, 0.0, 0.0, 0.0]),
                prior=torch.tensor([0.0, 1.0, 0.5, 0.0]), neighbour=torch.zeros(n, 8))
    return {**args, **replace}


@pytest.mark.parametrize("name, value", [
    ("shape", (4, 1)), ("origins", torch.zeros(4, 2)), ("dirs", torch.zeros(3, 3)), ("near", torch.zeros(4, 1)),
    ("far", torch.zeros(5)), ("reliable", torch.zeros(3)), ("prior", torch.zeros(2, 2)),
    ("neighbour", torch.zeros(4, 9))])
def test_pseudo_rays_refuse_each_misshapen_tensor_naming_it(name, value):
    with pytest.raises(ValueError, match=f"^{name} must be"):
        PseudoRays(**_ray_args(**{name: value}))


def test_pseudo_rays_draw_from_their_reliable_and_their_prior_rays():
    gen = torch.Generator().manual_seed(0)
    for shape in ((1, 2, 2), (1, 1, 4)):                            # (1, 1, 4) is a valid (P, H, W) too
        pr = PseudoRays(**_ray_args(shape=shape))
        assert set(pr.sample_reliable(50, gen).tolist()) == {0} and set(pr.sample_prior(50, gen).tolist()) == {1, 2}
    assert PseudoRays(**_ray_args(prior=torch.zeros(4))).sample_prior(8, gen).numel() == 0   # an empty pool


def test_distillation_loss_refuses_zero_samples_and_an_unknown_background_when_built():
    pr = PseudoRays(**_ray_args())
    with pytest.raises(ValueError, match="n_samples"):
        DistillationLoss(ConstField(1.0), pr, config(), 0)
    with pytest.raises(ValueError, match="background"):
        DistillationLoss(ConstField(1.0), pr, config(), 4, background="grey")
    for kind in ("random", "white", "black"):
        assert DistillationLoss(ConstField(1.0), pr, config(), 1, background=kind).n_samples == 1
