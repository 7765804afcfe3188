"""Tests of senerf/fields/sampling.py: stratified bins, contracted bins and the NDC map, against hand-written
formulas."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from senerf.fields import bin_fractions, contracted_bins, linear_bins, ndc_points, ndc_rays, ndc_t_to_depth, ray_bins


def stratified_bins(near, far, n_bins, generator=None, randomized=True):
    """Even bins with one sample each, as ``render_rays`` places them for a bounded field (``ray_bins``)."""
    rays = torch.zeros(near.numel(), 3), torch.tensor([[0.0, 0.0, 1.0]]).expand(near.numel(), 3)
    return ray_bins(*rays, near, far, bin_fractions(near, n_bins, generator, randomized))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_bins=st.integers(1, 64))
def test_stratified_points_lie_in_their_bins(seed, n_bins):
    gen = torch.Generator().manual_seed(seed)
    near = torch.rand(50, generator=gen, dtype=torch.float64) * 3
    far = near + torch.rand(50, generator=gen, dtype=torch.float64) * 5 + 1e-3
    t = stratified_bins(near, far, n_bins, gen)
    k = torch.arange(n_bins, dtype=torch.float64)
    lo = near[:, None] + k * (far - near)[:, None] / n_bins
    hi = near[:, None] + (k + 1) * (far - near)[:, None] / n_bins
    assert t.shape == (50, n_bins)
    assert (t >= lo - 1e-12).all() and (t <= hi + 1e-12).all()


def test_stratified_deterministic_per_seed_and_centres():
    near, far = torch.full((8,), 2.0), torch.full((8,), 6.0)
    a = stratified_bins(near, far, 16, torch.Generator().manual_seed(11))
    b = stratified_bins(near, far, 16, torch.Generator().manual_seed(11))
    c = stratified_bins(near, far, 16, torch.Generator().manual_seed(12))
    assert torch.equal(a, b) and not torch.equal(a, c)
    mid = stratified_bins(near, far, 16, None, randomized=False)
    np.testing.assert_allclose(mid[0].numpy(), 2.0 + (np.arange(16) + 0.5) * 0.25, rtol=1e-6)
    # the per-bin offsets are spread over the bin: in 8 x 16 draws some fall in each half
    frac = ((a - 2.0) / 0.25) % 1.0
    assert (frac < 0.5).any() and (frac > 0.5).any()
    with pytest.raises(ValueError):
        stratified_bins(near, far, 16, None)


def _ndc_of_point(p, fx, fy, w, h, near):
    # the projective map itself, written independently: (ax X/Z, ay Y/Z, 1 - 2 near / Z)
    return torch.stack([2 * fx / w * p[:, 0] / p[:, 2], 2 * fy / h * p[:, 1] / p[:, 2], 1 - 2 * near / p[:, 2]], -1)


def test_ndc_depth_and_straight_rays():
    gen = torch.Generator().manual_seed(0)
    fx, fy, w, h, near = 400.0, 380.0, 504.0, 378.0, 1.0
    n = 200
    o = torch.randn(n, 3, generator=gen, dtype=torch.float64) * 0.3
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=torch.float64) * 0.3
                                      + torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), dim=-1)
    o_ndc, d_ndc = ndc_rays(o, d, fx, fy, w, h, near)
    # the origin lands on the near plane (NDC z = -1)
    np.testing.assert_allclose(o_ndc[:, 2].numpy(), -1.0, atol=1e-12)
    for depth in (1.0, 1.7, 4.0, 50.0):
        s = (depth - o[:, 2]) / d[:, 2]                  # world point at camera depth `depth`
        p = o + s[:, None] * d
        t_ndc = 1.0 - near / depth
        np.testing.assert_allclose((o_ndc + t_ndc * d_ndc).numpy(), _ndc_of_point(p, fx, fy, w, h, near).numpy(),
                                   rtol=1e-9, atol=1e-9)
        # a point's NDC image (senerf.load_run's density queries) lies on its ray's NDC line
        np.testing.assert_allclose(ndc_points(p, fx, fy, w, h, near).numpy(), (o_ndc + t_ndc * d_ndc).numpy(),
                                   rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ndc_t_to_depth(torch.tensor(t_ndc, dtype=torch.float64), near).item(), depth, rtol=1e-12)


def test_ndc_xy_is_normalised_pixel_coordinate():
    # a pinhole ray through pixel (u, v), principal point at the centre: NDC x = (u - W/2) / (W/2) at any t
    fx, fy, w, h = 300.0, 300.0, 64.0, 48.0
    uv = torch.tensor([[0.5, 0.5], [32.0, 24.0], [63.5, 10.25]], dtype=torch.float64)
    d = torch.stack([(uv[:, 0] - w / 2) / fx, (uv[:, 1] - h / 2) / fy, torch.ones(3, dtype=torch.float64)], -1)
    o_ndc, d_ndc = ndc_rays(torch.zeros(3, 3, dtype=torch.float64), d, fx, fy, w, h, near=0.5)
    for t in (0.0, 0.3, 0.99):
        p = o_ndc + t * d_ndc
        np.testing.assert_allclose(p[:, 0].numpy(), ((uv[:, 0] - w / 2) / (w / 2)).numpy(), atol=1e-12)
        np.testing.assert_allclose(p[:, 1].numpy(), ((uv[:, 1] - h / 2) / (h / 2)).numpy(), atol=1e-12)
    with pytest.raises(ValueError):
        ndc_rays(torch.zeros(3, 2), d, fx, fy, w, h)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_stratified_jitter_is_uniform_and_per_ray(dtype):
    # 4000 rays x 8 bins of U[0, 1) offsets: the mean offset is 0.5 +- 0.0016 (std 1/sqrt(12 * 32000)); a jitter
    # over half a bin would have mean 0.25, one shared by every ray would repeat across rays.
    gen = torch.Generator().manual_seed(0)
    near, far = torch.full((4000,), 1.0, dtype=dtype), torch.full((4000,), 3.0, dtype=dtype)
    t = stratified_bins(near, far, 8, gen)
    u = (t - 1.0) / 0.25 - torch.arange(8, dtype=dtype)        # offset inside each bin
    assert float(u.min()) >= -1e-5 and float(u.max()) <= 1 + 1e-5
    assert abs(float(u.mean()) - 0.5) < 0.01
    assert float(u.max()) > 0.99 and float(u.min()) < 0.01
    assert not torch.equal(t[0], t[1])                           # rays draw their own offsets


@pytest.mark.parametrize("near_shape, far_shape", [((3, 1), (3, 1)), ((3,), (4,)), ((), ())])
def test_stratified_bins_refuses_near_and_far_that_are_not_equal_r(near_shape, far_shape):
    with pytest.raises(ValueError, match="near/far: expected equal shapes"):
        stratified_bins(torch.zeros(near_shape), torch.ones(far_shape), 4, randomized=False)


@pytest.mark.parametrize("n_bins", [0, -1])
def test_stratified_bins_refuses_fewer_than_one_bin_and_one_bin_is_its_centre(n_bins):
    with pytest.raises(ValueError, match="n_bins: expected >= 1"):
        stratified_bins(torch.zeros(3), torch.ones(3), n_bins, randomized=False)
    torch.testing.assert_close(stratified_bins(torch.zeros(3), torch.full((3,), 2.0), 1, randomized=False),
                               torch.ones(3, 1))


@pytest.mark.parametrize("near", [0.0, -1.0])
def test_ndc_rays_refuses_a_near_plane_at_or_behind_the_camera(near):
    # near = 0 would map every ray to z' = 1
    o, d = torch.zeros(2, 3), torch.tensor([[0.0, 0.0, 1.0]] * 2)
    with pytest.raises(ValueError, match="near: expected > 0"):
        ndc_rays(o, d, 2.0, 2.0, 4.0, 4.0, near=near)
    o_ndc, _ = ndc_rays(o, d, 2.0, 2.0, 4.0, 4.0, near=1e-3)
    torch.testing.assert_close(o_ndc[:, 2], torch.full((2,), -1.0))   # the origin moved to z = near: z' = -1


# ---------------------------------------------------------------------------------------------------------
# Contracted bins (unbounded scenes)


def _inverse_radial(c: np.ndarray) -> np.ndarray:
    """Box-unit distance from the centre of a radial ray's point at (unhalved) contracted coordinate ``c``."""
    return np.where(c <= 1.0, c, 1.0 / (2.0 - np.minimum(c, 2.0 - 1e-12)))


def test_contracted_bins_are_linear_while_the_segment_stays_in_the_box():
    o = torch.tensor([[-0.5, 0.2, 0.1], [0.3, -0.9, 0.0]], dtype=torch.float64)
    d = torch.nn.functional.normalize(torch.tensor([[1.0, 0.1, 0.0], [0.0, 1.0, 0.2]], dtype=torch.float64), dim=-1)
    near, far = torch.tensor([0.05, 0.1], dtype=torch.float64), torch.tensor([1.2, 1.5], dtype=torch.float64)
    u = bin_fractions(near, 16, torch.Generator().manual_seed(1))
    t = contracted_bins(o, d, near, far, u, [[-1.0] * 3, [1.0] * 3])
    torch.testing.assert_close(t, linear_bins(near, far, u), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_contracted_bin_edges_are_evenly_spaced_in_contracted_space(dtype):
    # a radial ray from the centre of a box of half size 2 (box units = world / 2), out to 1e4 world units
    o, d = torch.zeros(1, 3, dtype=dtype), torch.tensor([[1.0, 0.0, 0.0]], dtype=dtype)
    near, far = torch.tensor([0.2], dtype=dtype), torch.tensor([1e4], dtype=dtype)
    edges = torch.arange(33, dtype=dtype)[None, :32] * 0.0      # u = 0: the bin's start
    t = contracted_bins(o, d, near, far, edges, [[-2.0] * 3, [2.0] * 3])[0].double().numpy()
    c0, c1 = 0.1, 2.0 - 1.0 / 5e3                                  # contracted near and far (unhalved)
    want = 2.0 * _inverse_radial(c0 + (c1 - c0) * np.arange(32) / 32)
    np.testing.assert_allclose(t, want, rtol=0.02)
    assert (np.diff(t) > 0).all()
    inside = want < 1.8                                              # (the box face is at 2)
    np.testing.assert_allclose(t[inside], want[inside], rtol=1e-4)   # exact where the contraction is the identity


def test_contracted_bins_pair_bin_by_bin_and_stay_within_the_bounds():
    gen = torch.Generator().manual_seed(3)
    o = torch.randn(64, 3, generator=gen) * 3
    d = torch.nn.functional.normalize(torch.randn(64, 3, generator=gen), dim=-1)
    near, far = torch.full((64,), 0.1), torch.full((64,), 500.0)
    near[0] = far[0] = 7.0                                          # an empty segment
    box = [[-1.0, -2.0, -1.0], [1.0, 0.0, 3.0]]
    u1 = bin_fractions(near, 24, gen)
    t1 = contracted_bins(o, d, near, far, u1, box)
    assert torch.equal(t1, contracted_bins(o, d, near, far, u1, box))       # a function of the ray only
    assert (t1 >= near[:, None]).all() and (t1 <= far[:, None]).all() and (t1[0] == 7.0).all()
    assert (t1[:, 1:] >= t1[:, :-1]).all()
    lo = contracted_bins(o, d, near, far, torch.zeros_like(u1), box)
    hi = contracted_bins(o, d, near, far, torch.full_like(u1, 1.0 - 1e-6), box)
    assert (lo <= t1).all() and (t1 <= hi + 1e-4).all()                       # each point in its bin
    assert torch.equal(ray_bins(o, d, near, far, u1, None), linear_bins(near, far, u1))
    assert torch.equal(ray_bins(o, d, near, far, u1, torch.tensor(box)), t1)
