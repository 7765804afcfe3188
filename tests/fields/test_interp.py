"""Tests of senerf/fields/interp.py: the plane layout, bilinear interpolation by hand, and plane TV."""

from __future__ import annotations

import pytest
import torch

from senerf.fields.interp import plane_interp, plane_interp_reference, plane_layout, plane_tv, plane_tv_reference


def test_plane_layout_by_hand_and_refuses_planes_of_fewer_than_two_texels():
    assert plane_layout((2, 3)) == ([0, 4, 8, 12, 21, 30], 39)   # 3 planes of 2x2, then 3 of 3x3
    with pytest.raises(ValueError, match="resolution: every plane needs at least 2 texels per side, got 1"):
        plane_layout((4, 1))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_plane_interp_by_hand_on_2x2_planes(dtype):
    # One scale of three 2x2 planes, one feature; plane p holds texels (a, b) at row b * 2 + a:
    # xy = [[1, 2], [3, 4]] (rows b), xz = 10 x that, yz = 100 x that.  u = (x, y, z) in [-1, 1]^3 maps to
    # texel coordinates (x + 1) / 2 etc.  At u = (0, -1, 0.5): xy at (0.5, 0) -> 1.5; xz at (0.5, 0.75) ->
    # 10 (1.5 + 0.75 * 2) = 30; yz at (0, 0.75) -> 100 (1 + 0.75 * 2) = 250.
    offsets, rows = plane_layout((2,))
    table = torch.cat([torch.tensor([[1.0], [2.0], [3.0], [4.0]]) * m for m in (1, 10, 100)]).to(dtype)
    u = torch.tensor([[0.0, -1.0, 0.5], [-1.0, -1.0, -1.0]], dtype=dtype)
    out = plane_interp(table, u, (2,), offsets)
    assert out.shape == (2, 1, 3, 1) and rows == 12
    torch.testing.assert_close(out[:, 0, :, 0], torch.tensor([[1.5, 30.0, 250.0], [1.0, 10.0, 100.0]], dtype=dtype))
    planes = [table[o:o + 4].view(2, 2, 1).permute(2, 0, 1) for o in offsets]
    torch.testing.assert_close(plane_interp_reference(planes, u), out)


def test_the_grid_sample_reference_takes_zero_points():
    planes = [torch.rand(4, 5, 5) for _ in range(6)]   # two scales x three planes, four features
    assert plane_interp_reference(planes, torch.zeros(0, 3)).shape == (0, 2, 3, 4)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_plane_tv_and_its_gradient_equal_the_slicing_reference(dtype, threads, monkeypatch):
    from senerf.fields.ckernel import load_kernel

    if load_kernel(dtype, 3) is None:
        pytest.skip("no C compiler: plane_tv is the reference itself")
    monkeypatch.setattr(torch, "get_num_threads", lambda: threads)
    """The compiled kernel's value and gradient (written texel by texel) are autograd's through slices, on planes of
    two scales and three features, scaled by the incoming gradient, with the planes' rows split over threads or not."""
    resolutions = (3, 70)   # 70 x 70 texels x 3 features: two row ranges with 2 threads
    offsets, rows = plane_layout(resolutions)
    values = torch.rand(rows, 3, generator=torch.Generator().manual_seed(0), dtype=dtype)
    grads = []
    for tv in (plane_tv, plane_tv_reference):
        table = values.clone().requires_grad_()
        loss = tv(table, resolutions, offsets)
        (2.5 * loss).backward()
        grads.append((loss, table.grad))
    (fast, g_fast), (ref, g_ref) = grads
    assert fast.grad_fn is not None and type(fast.grad_fn).__name__ == "_FusedTVBackward" and g_fast.dtype == dtype
    tol = 1e-6 if dtype == torch.float32 else 1e-13
    torch.testing.assert_close(fast.detach(), ref.detach(), rtol=tol, atol=0.0)
    torch.testing.assert_close(g_fast, g_ref, rtol=tol, atol=tol * float(g_ref.abs().max()))


def test_plane_tv_gradient_of_a_bump_by_hand():
    """One 3x3 plane, one feature, a bump h at the centre: along each axis 2 of the 6 differences are +-h, so
    TV = 2 (2 h^2 / 6) (both axes, one scale); the centre is in 4 differences, d TV / d centre = 4 (2 h / 6), and
    each of its 4 neighbours is in one, -2 h / 6."""
    offsets, rows = plane_layout((3,), 1)
    table = torch.zeros(rows, 1, dtype=torch.float64)
    table[4, 0] = 0.5   # row b=1, column a=1
    table.requires_grad_()
    loss = plane_tv(table, (3,), offsets)
    loss.backward()
    assert float(loss.detach()) == pytest.approx(2 * 2 * 0.25 / 6)
    grad = table.grad.view(3, 3)
    assert float(grad[1, 1]) == pytest.approx(4 * 2 * 0.5 / 6)
    for b, a in ((0, 1), (2, 1), (1, 0), (1, 2)):
        assert float(grad[b, a]) == pytest.approx(-2 * 0.5 / 6)
    assert float(grad[0, 0]) == 0.0
