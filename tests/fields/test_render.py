import numpy as np
import pytest
import torch

from senerf.fields import (EMPTY_ACC, KPlanesField, OccupancyGrid, render_image, render_rays, volume_render,
                           volume_render_reference)

from ._fields_helpers import BallField


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
    b = volume_render_reference(sigma, rgb, t, t_far, bg)
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


def test_shape_checks():
    with pytest.raises(ValueError):
        volume_render(torch.zeros(4, 5), torch.zeros(4, 5, 3), torch.zeros(4, 6), torch.zeros(4))
    with pytest.raises(ValueError):
        volume_render(torch.zeros(4, 5), torch.zeros(4, 5), torch.zeros(4, 5), torch.zeros(4))
    with pytest.raises(ValueError):
        volume_render(torch.zeros(4, 5), torch.zeros(4, 5, 3), torch.zeros(4, 5), torch.zeros(4), torch.zeros(2))


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
    # chunk 0 or below stepped by 1 but sliced nothing: uninitialised memory came back (so at 98f1a55)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="chunk: expected an integer >= 1"):
            render_image(field, o.view(6, 5, 3), d.view(6, 5, 3), 1.5, 4.5, 16, chunk=bad)
