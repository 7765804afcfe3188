"""Tests of senerf/fields/render.py: compositing against the textbook cumprod form and values worked out by hand,
ray marching through analytic fields, occupancy skipping, chunked image rendering and the shape checks."""

import math

import numpy as np
import pytest
import torch

from senerf.fields import (EMPTY_ACC, KPlanesField, OccupancyGrid, bin_distortion, render_image, render_rays,
                           volume_render)

from .analytic_fields import BallField, ConstantField


def cumprod_reference(sigma, rgb, t, t_far, background=None) -> dict:
    """Textbook compositing, written independently of volume_render (use float64):
    ``alpha_i = 1 - exp(-sigma_i delta_i)``, ``T_i = prod_{k<i} (1 - alpha_k)``, ``w_i = T_i alpha_i``."""
    delta = torch.cat([t[:, 1:] - t[:, :-1], t_far[:, None] - t[:, -1:]], dim=1).clamp(min=0.0)
    alpha = 1.0 - torch.exp(-sigma * delta)
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha[:, :-1]], dim=1), dim=1)
    weights = trans * alpha
    acc = weights.sum(1)
    color = (weights[..., None] * rgb).sum(1)
    if background is not None:
        color = color + (1.0 - acc)[:, None] * torch.as_tensor(background, dtype=color.dtype)
    dist = torch.where(acc >= EMPTY_ACC, (weights * t).sum(1) / acc.clamp(min=EMPTY_ACC), t_far.to(t))
    return {"rgb": color, "acc": acc, "ray_dist": dist, "weights": weights}


def _random_case(gen, r=64, s=32, dtype=torch.float64):
    sigma = torch.rand(r, s, generator=gen, dtype=dtype) * 5.0
    sigma[torch.rand(r, s, generator=gen) < 0.3] = 0.0
    rgb = torch.rand(r, s, 3, generator=gen, dtype=dtype)
    deltas = torch.rand(r, s, generator=gen, dtype=dtype) * 0.2 + 1e-3
    t = 2.0 + torch.cumsum(deltas, dim=1)
    t_far = t[:, -1] + torch.rand(r, generator=gen, dtype=dtype) * 0.2
    return sigma, rgb, t, t_far


def test_matches_cumprod_reference_float64():
    gen = torch.Generator().manual_seed(1)
    sigma, rgb, t, t_far = _random_case(gen)
    bg = torch.rand(sigma.shape[0], 3, generator=gen, dtype=torch.float64)
    a = volume_render(sigma, rgb, t, t_far, bg)
    b = cumprod_reference(sigma, rgb, t, t_far, bg)
    for k in ("rgb", "acc", "ray_dist", "weights"):
        torch.testing.assert_close(a[k], b[k], rtol=1e-10, atol=1e-12)
    assert (a["acc"] > 0.05).all()  # the case is not trivially empty


def test_constant_slab_opacity():
    # sigma constant on [a, b] sampled at the left ends of S equal intervals whose last one ends at b:
    # total optical depth sum sigma * delta = sigma * (b - a), so acc = 1 - exp(-sigma L) exactly.
    a, b, s, sig = 2.0, 3.5, 40, 0.7
    t = torch.linspace(a, b, s + 1, dtype=torch.float64)[:-1].expand(3, s)
    sigma = torch.full((3, s), sig, dtype=torch.float64)
    rgb = torch.full((3, s, 3), 0.25, dtype=torch.float64)
    out = volume_render(sigma, rgb, t, torch.full((3,), b, dtype=torch.float64), torch.ones(3, dtype=torch.float64))
    expect = 1.0 - np.exp(-sig * (b - a))  # 0.6500622...
    np.testing.assert_allclose(out["acc"].numpy(), expect, rtol=1e-12)
    # colour: 0.25 * acc + 1 * (1 - acc)
    np.testing.assert_allclose(out["rgb"].numpy(), 0.25 * expect + (1 - expect), rtol=1e-12)


def test_thin_opaque_wall_depth():
    t = torch.linspace(2.0, 6.0, 81)[:-1].expand(2, 80).contiguous()   # step 0.05
    sigma = torch.zeros(2, 80)
    sigma[0, 20] = 1e6     # t = 3.0
    sigma[1, 50] = 1e6     # t = 4.5
    out = volume_render(sigma, torch.rand(2, 80, 3), t, torch.full((2,), 6.0))
    np.testing.assert_allclose(out["acc"].numpy(), 1.0, atol=1e-6)
    np.testing.assert_allclose(out["ray_dist"].numpy(), [3.0, 4.5], atol=1e-5)


def test_empty_ray_returns_t_far_and_background():
    t = torch.linspace(2.0, 6.0, 10).expand(2, 10).contiguous()
    sigma = torch.zeros(2, 10)
    sigma[1] = 1e-9  # acc ~ 4e-9 < EMPTY_ACC: still "empty"
    out = volume_render(sigma, torch.rand(2, 10, 3), t, torch.tensor([6.5, 7.0]), torch.tensor([0.1, 0.2, 0.3]))
    assert (out["acc"] < EMPTY_ACC).all()
    np.testing.assert_allclose(out["ray_dist"].numpy(), [6.5, 7.0])
    np.testing.assert_allclose(out["rgb"][0].numpy(), [0.1, 0.2, 0.3], rtol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_extremes_finite_values_and_gradients(dtype):
    deltas = torch.logspace(-9, 3, 25, dtype=dtype)                     # 1e-9 .. 1e3
    deltas = torch.stack([deltas, deltas.flip(0)])
    t0 = torch.cumsum(deltas, dim=1)
    rows = []
    for pattern in ("zero", "huge", "mixed"):
        sig = torch.zeros_like(t0)
        if pattern == "huge":
            sig[:] = 1e8
        elif pattern == "mixed":
            sig[:, ::2] = 1e8
        rows.append(sig)
    sigma = torch.cat(rows).requires_grad_()
    t = t0.repeat(3, 1).requires_grad_()
    rgb = torch.rand(6, 25, 3, dtype=dtype, requires_grad=True)
    t_far = (t0[:, -1] + 1e3).repeat(3).requires_grad_()
    out = volume_render(sigma, rgb, t, t_far, torch.ones(3, dtype=dtype))
    total = sum(v.sum() for k, v in out.items() if k != "t")
    total.backward()
    for k, v in out.items():
        assert torch.isfinite(v).all(), k
    for x in (sigma, t, rgb, t_far):
        assert torch.isfinite(x.grad).all()
    assert torch.allclose(out["acc"][:2], torch.zeros(2, dtype=dtype))
    assert torch.allclose(out["acc"][2:], torch.ones(4, dtype=dtype))


def _rays(n, gen):
    o = torch.tensor([0.0, 0.0, -3.0]).expand(n, 3).contiguous()
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen) * 0.15 + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    return o, d, torch.full((n,), 1.5), torch.full((n,), 4.5)


def test_render_rays_ball_depth_and_opacity():
    gen = torch.Generator().manual_seed(0)
    o = torch.tensor([[0.0, 0.0, -3.0], [0.0, 2.0, -3.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    out = render_rays(BallField(value=1e4), o, d, torch.full((2,), 1.0), torch.full((2,), 5.0), 400, gen,
                      torch.zeros(3))
    # ray 0 enters the ball (radius 0.5) at distance 2.5; bins are 0.01 long; ray 1 misses it
    assert out["acc"][0] > 0.999 and abs(float(out["ray_dist"][0]) - 2.5) < 0.011
    assert float(out["acc"][1]) == 0.0 and float(out["ray_dist"][1]) == 5.0


def test_occupancy_full_grid_identical_and_empty_grid_zero():
    gen = torch.Generator().manual_seed(3)
    field = KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=8, n_features=4, generator=gen)
    o, d, near, far = _rays(32, gen)
    bg = torch.tensor([1.0, 1.0, 1.0])
    plain = render_rays(field, o, d, near, far, 24, torch.Generator().manual_seed(5), bg)
    grid = OccupancyGrid(field.aabb, 16)   # fresh: everything occupied
    skip = render_rays(field, o, d, near, far, 24, torch.Generator().manual_seed(5), bg, occupancy=grid)
    for k in ("rgb", "acc", "ray_dist", "weights", "sigma"):
        assert torch.equal(plain[k], skip[k]), k
    empty = OccupancyGrid(field.aabb, 16, threshold=1e30)
    empty.update(field)
    assert empty.occupied_fraction() == 0.0
    none = render_rays(field, o, d, near, far, 24, torch.Generator().manual_seed(5), bg, occupancy=empty)
    assert torch.equal(none["acc"], torch.zeros(32)) and torch.equal(none["rgb"], bg.expand(32, 3))


def test_occupancy_partial_grid_skips_only_empty_cells():
    gen = torch.Generator().manual_seed(4)
    ball = BallField(radius=0.4, value=50.0)
    grid = OccupancyGrid([[-1.0] * 3, [1.0] * 3], 16, threshold=1.0)
    assert 0.0 < grid.update(ball) < 0.2
    o, d, near, far = _rays(64, gen)
    plain = render_rays(ball, o, d, near, far, 64, torch.Generator().manual_seed(9), None)
    ball.calls = 0
    skip = render_rays(ball, o, d, near, far, 64, torch.Generator().manual_seed(9), None, occupancy=grid)
    assert ball.calls < 0.3 * 64 * 64            # the field saw only the kept samples
    pts = (o[:, None] + plain["t"][..., None] * d[:, None]).reshape(-1, 3)
    occ = grid.is_occupied(pts).view(64, 64)
    assert torch.equal(skip["sigma"][~occ], torch.zeros(int((~occ).sum())))
    assert torch.equal(skip["sigma"][occ], plain["sigma"][occ])
    # the ball lies inside occupied cells, so nothing visible was dropped
    torch.testing.assert_close(skip["rgb"], plain["rgb"])


def test_render_image_matches_render_rays_and_chunking():
    gen = torch.Generator().manual_seed(7)
    field = KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=8, n_features=4, generator=gen)
    o, d, near, far = _rays(6 * 5, gen)
    img = render_image(field, o.view(6, 5, 3).numpy(), d.view(6, 5, 3).numpy(), 1.5, 4.5, 16,
                       background=(1.0, 1.0, 1.0), chunk=7)
    img2 = render_image(field, o.view(6, 5, 3), d.view(6, 5, 3), 1.5, 4.5, 16, background=(1.0, 1.0, 1.0),
                        chunk=1000)
    assert img["rgb"].shape == (6, 5, 3) and img["acc"].shape == (6, 5) and img["ray_dist"].shape == (6, 5)
    assert img["rgb"].dtype == np.float32
    with torch.no_grad():
        ref = render_rays(field, o, d, near, far, 16, None, torch.ones(3), randomized=False)
    np.testing.assert_allclose(img["rgb"].reshape(-1, 3), ref["rgb"].numpy(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(img["ray_dist"], img2["ray_dist"], rtol=1e-5)
    # a chunk below 1 would slice nothing and return uninitialised memory
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="chunk: expected an integer >= 1"):
            render_image(field, o.view(6, 5, 3), d.view(6, 5, 3), 1.5, 4.5, 16, chunk=bad)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_two_samples_by_hand(dtype):
    # t = (1, 1.5), t_far = 2.5 -> deltas (0.5, 1.0); sigma (2, 1) -> tau (1, 1).
    # w0 = 1 - e^-1 = 0.6321206, w1 = e^-1 (1 - e^-1) = 0.2325442, acc = 1 - e^-2 = 0.8646647.
    # rgb (1,0,0), (0,1,0); bg (0.2, 0.4, 0.6): colour = (w0, w1, 0) + (1 - acc) bg.
    # ray_dist = (1 w0 + 1.5 w1) / acc = 0.9809369 / 0.8646647 = 1.1344711.
    e1 = math.exp(-1.0)
    w0, w1 = 1 - e1, e1 * (1 - e1)
    acc = 1 - math.exp(-2.0)
    bg = (0.2, 0.4, 0.6)
    sigma = torch.tensor([[2.0, 1.0]], dtype=dtype)
    rgb = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]], dtype=dtype)
    t = torch.tensor([[1.0, 1.5]], dtype=dtype)
    out = volume_render(sigma, rgb, t, torch.tensor([2.5], dtype=dtype), torch.tensor(bg, dtype=dtype))
    tol = 1e-6 if dtype == torch.float32 else 1e-14
    np.testing.assert_allclose(out["weights"][0].numpy(), [w0, w1], rtol=tol)
    np.testing.assert_allclose(out["acc"].numpy(), [acc], rtol=tol)
    np.testing.assert_allclose(out["rgb"][0].numpy(),
                               [w0 + (1 - acc) * bg[0], w1 + (1 - acc) * bg[1], (1 - acc) * bg[2]], rtol=tol)
    np.testing.assert_allclose(out["ray_dist"].numpy(), [(w0 + 1.5 * w1) / acc], rtol=tol)


def test_single_sample_last_interval_is_t_far_minus_t():
    # t = 2, t_far = 3: delta 1, sigma 0.5 -> alpha = 1 - e^-0.5 = 0.3934693 (not 1 for an infinite last
    # interval, nor 0 for an empty one).
    out = volume_render(torch.tensor([[0.5]], dtype=torch.float64), torch.ones(1, 1, 3, dtype=torch.float64),
                        torch.tensor([[2.0]], dtype=torch.float64), torch.tensor([3.0], dtype=torch.float64))
    np.testing.assert_allclose(out["acc"].numpy(), [1 - math.exp(-0.5)], rtol=1e-14)


def test_background_none_is_black():
    # Same case as above with colour (1, 1, 1): acc = 1 - e^-0.5 = 0.3934693, so the colour on black is acc.
    out = volume_render(torch.tensor([[0.5]], dtype=torch.float64), torch.ones(1, 1, 3, dtype=torch.float64),
                        torch.tensor([[2.0]], dtype=torch.float64), torch.tensor([3.0], dtype=torch.float64))
    np.testing.assert_allclose(out["rgb"][0].numpy(), [1 - math.exp(-0.5)] * 3, rtol=1e-14)


def test_render_rays_bin_centres_constant_density_by_hand():
    # near 1, far 3, 4 bins of 0.5: centres t = 1.25, 1.75, 2.25, 2.75; intervals 0.5, 0.5, 0.5 and
    # far - 2.75 = 0.25: optical depth sigma * 1.75 = 0.5 * 1.75 = 0.875, acc = 1 - e^-0.875 = 0.5831457.
    o = torch.zeros(2, 3, dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    out = render_rays(ConstantField(0.5), o, d, torch.full((2,), 1.0, dtype=torch.float64),
                      torch.full((2,), 3.0, dtype=torch.float64), 4, None, torch.zeros(3, dtype=torch.float64),
                      randomized=False)
    np.testing.assert_allclose(out["t"][0].numpy(), [1.25, 1.75, 2.25, 2.75], rtol=1e-15)
    np.testing.assert_allclose(out["acc"].numpy(), 1 - math.exp(-0.875), rtol=1e-14)
    # black background: colour = acc * (0.2, 0.4, 0.6)
    np.testing.assert_allclose(out["rgb"][1].numpy(), (1 - math.exp(-0.875)) * np.array([0.2, 0.4, 0.6]),
                               rtol=1e-6)


def test_render_image_passes_randomized_and_generator_through():
    # with randomized=True and a seeded generator render_image equals one render_rays call with a generator of
    # the same seed (one chunk), and differs from the bin centres
    field = ConstantField(0.8)
    o = torch.zeros(2, 3, 3)
    d = torch.nn.functional.normalize(torch.rand(2, 3, 3, generator=torch.Generator().manual_seed(0)) + 1, dim=-1)
    img = render_image(field, o, d, 0.5, 2.5, 8, randomized=True, generator=torch.Generator().manual_seed(4))
    ref = render_rays(field, o.view(6, 3), d.view(6, 3), torch.full((6,), 0.5), torch.full((6,), 2.5), 8,
                      torch.Generator().manual_seed(4), None, randomized=True)
    np.testing.assert_array_equal(img["ray_dist"].reshape(-1), ref["ray_dist"].numpy())
    centred = render_image(field, o, d, 0.5, 2.5, 8)
    assert not np.allclose(img["ray_dist"], centred["ray_dist"])


R, S = 3, 4


def _composite(**replace) -> dict:
    """A valid volume_render call of R = 3 rays with S = 4 samples."""
    t = torch.linspace(1.0, 2.0, S).expand(R, S)
    args = dict(sigma=torch.ones(R, S), rgb=torch.zeros(R, S, 3), t=t, t_far=torch.full((R,), 2.5))
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value", [
    ("sigma", torch.ones(R * S)), ("sigma", torch.ones(R, S, 1)), ("rgb", torch.zeros(R, S, 4)),
    ("t", torch.zeros(R, S + 1)), ("t_far", torch.ones(R, 1)), ("t_far", torch.ones(R + 1)),
    ("background", torch.zeros(2)),
])
def test_volume_render_refuses_each_misshapen_input(name, value):
    with pytest.raises(ValueError, match=f"{name}: expected shape"):
        volume_render(**_composite(**{name: value}))
    assert volume_render(**_composite())["acc"].shape == (R,)


def _march(**replace) -> dict:
    """A valid render_rays call: R = 3 rays along +z through a ball at the origin."""
    args = dict(rays_o=torch.tensor([[0.0, 0.0, -2.0]] * R), rays_d=torch.tensor([[0.0, 0.0, 1.0]] * R),
                near=torch.ones(R), far=torch.full((R,), 3.0))
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value, arg", [
    ("rays_o", torch.zeros(R * 3), "rays_o/rays_d"), ("rays_o", torch.zeros(R, 2), "rays_o/rays_d"),
    ("rays_d", torch.ones(R + 1, 3), "rays_o/rays_d"), ("near", torch.ones(R + 1), "near/far"),
    ("far", torch.ones(R, 1), "near/far"),
])
def test_render_rays_refuses_each_misshapen_input(name, value, arg):
    with pytest.raises(ValueError, match=f"{arg}: expected"):
        render_rays(BallField(), **_march(**{name: value}), n_samples=S, randomized=False)
    assert render_rays(BallField(), **_march(), n_samples=S, randomized=False)["acc"].shape == (R,)


@pytest.mark.parametrize("o_shape, d_shape", [((4, 3), (4, 3)), ((2, 2, 2), (2, 2, 2)), ((2, 2, 3), (2, 1, 3))])
def test_render_image_refuses_origins_and_dirs_that_are_not_h_w_3(o_shape, d_shape):
    with pytest.raises(ValueError, match=r"origins/dirs: expected equal shapes \(H, W, 3\)"):
        render_image(BallField(), np.zeros(o_shape), np.ones(d_shape), 1.0, 3.0, S)
    o, d = np.array([[[0.0, 0.0, -2.0]]]), np.array([[[0.0, 0.0, 1.0]]])
    assert render_image(BallField(), o, d, 1.0, 3.0, S)["acc"].shape == (1, 1)


def test_bin_distortion_is_the_double_sum_of_mip_nerf_360():
    w = torch.rand(6, 9, generator=torch.Generator().manual_seed(2), dtype=torch.float64) / 3
    s = w.shape[1]
    mid = (torch.arange(s, dtype=torch.float64) + 0.5) / s                 # bins [k/S, (k+1)/S]
    pairs = (w[:, :, None] * w[:, None, :] * (mid[:, None] - mid[None, :]).abs()).sum(dim=(1, 2))
    want = (pairs + (w.square() / s).sum(dim=1) / 3).mean()
    torch.testing.assert_close(bin_distortion(w), want)
    peaked, spread = torch.zeros(1, 9), torch.full((1, 9), 1.0 / 9)
    peaked[0, 4] = 1.0
    assert float(bin_distortion(peaked)) < float(bin_distortion(spread))   # it rewards compact weights


def test_a_contracting_field_is_sampled_beyond_its_box():
    field = KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=8, multires=(1,), contract=True)
    o, d = torch.tensor([[0.0, 0.0, -3.0]]), torch.tensor([[0.0, 0.0, 1.0]])
    out = render_rays(field, o, d, torch.tensor([0.1]), torch.tensor([1e3]), 32, randomized=False)
    t = out["t"][0]
    inside = int(((t > 2.0) & (t < 4.0)).sum())                 # the box spans t in [2, 4]
    # contracted path: 2/3 from the camera (at 3 box units) to the box, 2 across it, ~1 beyond: 2 / 3.67 of 32
    assert t[-1] > 10.0 and 16 <= inside <= 19
