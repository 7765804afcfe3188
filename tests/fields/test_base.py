"""Tests of senerf/fields/base.py: the RadianceField contract (every field), AABB and point checks, the scene
contraction against mip-NeRF 360's formula written point by point."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from senerf.fields import KPlanesField, NeRFField, RadianceField, contract_unit, field_coords, uncontract_unit
from senerf.fields.base import as_aabb, check_points


def test_the_base_field_leaves_density_and_forward_to_subclasses():
    field, xyz = RadianceField(), torch.zeros(2, 3)
    with pytest.raises(NotImplementedError):
        field.density(xyz)
    with pytest.raises(NotImplementedError):
        field(xyz, xyz)
    assert torch.equal(field.regularizer(), torch.zeros(()))   # no parameters: a CPU zero


@pytest.mark.parametrize("aabb", [[[0.0, 0.0, 0.0]], [[0.0, 0.0], [1.0, 1.0]], [[0.0, 0.0, 0.0], [1.0, 0.0, 1.0]],
                                  [[0.0, 0.0, 0.0], [1.0, 1.0, -1.0]]], ids=["one-row", "2d", "flat", "inverted"])
def test_as_aabb_refuses_misshapen_or_empty_boxes(aabb):
    # an empty box (max == min) would divide by zero when points are normalised
    with pytest.raises(ValueError, match="aabb: "):
        as_aabb(aabb)
    box = as_aabb([[0.0, 0.0, 0.0], [0.5, 0.5, 0.5]])
    assert box.dtype == torch.float32 and box.tolist() == [[0.0, 0.0, 0.0], [0.5, 0.5, 0.5]]


def test_check_points_refuses_integer_points():
    with pytest.raises(ValueError, match="pts: expected a floating tensor"):
        check_points(torch.zeros(2, 3, dtype=torch.int64), "pts")
    for dtype in (torch.float16, torch.float32, torch.float64):
        check_points(torch.zeros(2, 3, dtype=dtype))


def _fields():
    gen = torch.Generator().manual_seed(0)
    box = [[-1.0] * 3, [1.0] * 3]
    return {
        "kplanes": KPlanesField(box, resolution=8, n_features=4, multires=(1, 2), hidden=8, geo_features=4,
                                generator=gen),
        "kplanes-gather": KPlanesField(box, resolution=8, n_features=4, multires=(1,), hidden=8, geo_features=4,
                                       generator=gen, backend="gather"),
        "kplanes-grid_sample": KPlanesField(box, resolution=8, n_features=4, multires=(1, 2), hidden=8,
                                            geo_features=4, generator=gen, backend="grid_sample"),
        "nerf": NeRFField(aabb=box, n_freqs=4, hidden=16, n_layers=2, generator=gen),
        "nerf-unbounded-annealed": NeRFField(aabb=None, n_freqs=4, hidden=16, n_layers=2, view_dependent=False,
                                             anneal_steps=10, generator=gen),
    }


FIELDS = sorted(_fields())


@pytest.mark.parametrize("name", FIELDS)
def test_every_field_takes_zero_points(name):
    # An occupancy grid can drop every sample of a chunk of rays (all in empty space): the field then gets
    # (0, 3) points, forward and backward.
    f = _fields()[name]
    xyz = torch.zeros(0, 3, requires_grad=True)
    dirs = torch.zeros(0, 3)
    sigma, rgb = f(xyz, dirs)
    assert sigma.shape == (0,) and rgb.shape == (0, 3)
    assert f.density(xyz).shape == (0,)
    (sigma.sum() + rgb.sum()).backward()   # a training step whose batch kept no sample still steps
    assert xyz.grad.shape == (0, 3)


@pytest.mark.parametrize("name", FIELDS)
def test_rendering_through_a_grid_with_no_occupied_cell_gives_the_background(name):
    from senerf.fields import OccupancyGrid, render_rays

    f = _fields()[name]
    grid = OccupancyGrid([[-1.0] * 3, [1.0] * 3], resolution=4)
    grid.mask.zero_()
    o = torch.tensor([[0.0, 0.0, -3.0], [0.5, 0.0, -3.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    out = render_rays(f, o, d, torch.full((2,), 2.0), torch.full((2,), 4.0), 8, torch.Generator().manual_seed(0),
                      background=torch.tensor([0.2, 0.4, 0.6]), occupancy=grid)
    assert torch.equal(out["acc"], torch.zeros(2))
    assert torch.allclose(out["rgb"], torch.tensor([[0.2, 0.4, 0.6]] * 2))


@pytest.mark.parametrize("make", [
    lambda: KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=2, n_features=2, multires=(1,), hidden=4, geo_features=2),
    lambda: NeRFField([[-1.0] * 3, [1.0] * 3], n_freqs=1, hidden=4, n_layers=2)], ids=["kplanes", "nerf"])
def test_view_dependent_fields_refuse_missing_or_misshapen_directions(make):
    # None, (N, 2) directions and (1, 3) directions (which would broadcast over N points) are all refused
    field, xyz = make(), torch.zeros(2, 3)
    for dirs in (None, torch.zeros(2, 2), torch.zeros(1, 3)):
        with pytest.raises(ValueError, match=r"dirs: expected shape \(2, 3\)"):
            field(xyz, dirs)
    sigma, rgb = field(xyz, torch.tensor([[0.0, 0.0, 1.0]] * 2))
    assert sigma.shape == (2,) and rgb.shape == (2, 3)


# ---------------------------------------------------------------------------------------------------------
# The scene contraction of unbounded fields


def _contract_reference(u: np.ndarray) -> np.ndarray:
    """mip-NeRF 360's contraction in the L-infinity norm, point by point, halved into [-1, 1]."""
    out = np.empty_like(u)
    for i, p in enumerate(u):
        n = max(abs(p[0]), abs(p[1]), abs(p[2]))
        out[i] = p / 2 if n <= 1 else (2 - 1 / n) * (p / n) / 2
    return out


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_contraction_is_the_l_infinity_scene_contraction_and_inverts(dtype):
    rng = np.random.default_rng(0)
    u = np.concatenate([rng.uniform(-1, 1, (200, 3)), rng.normal(0, 30, (200, 3)), [[1, 0, 0], [0, -1, 1]]])
    got = contract_unit(torch.tensor(u, dtype=dtype))
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    np.testing.assert_allclose(got.numpy(), _contract_reference(u), rtol=tol, atol=tol)
    assert got.abs().max() < 1.0
    back = uncontract_unit(got)
    np.testing.assert_allclose(back.numpy(), u, rtol=1e-4 if dtype == torch.float32 else 1e-10)


def test_contraction_is_continuous_across_the_box_face_and_monotone_outward():
    r = torch.linspace(0.0, 1e4, 20001, dtype=torch.float64) ** 1.0
    ray = torch.stack([r, 0.3 * r, -0.2 * r], dim=-1)
    c = contract_unit(ray)[:, 0]
    assert (c[1:] > c[:-1]).all()                                           # strictly outward
    face = torch.tensor([[1.0 - 1e-9, 0.0, 0.0], [1.0 + 1e-9, 0.0, 0.0]], dtype=torch.float64)
    assert abs(float(contract_unit(face)[1, 0] - contract_unit(face)[0, 0])) < 1e-8
    assert float(contract_unit(torch.tensor([[1e30, 0.0, 0.0]]))[0, 0]) == pytest.approx(1.0)


def test_field_coords_contract_all_finite_points_and_leave_nan_ones_outside():
    box = as_aabb([[-2.0, -1.0, 0.0], [2.0, 1.0, 4.0]])
    xyz = torch.tensor([[0.0, 0.0, 2.0], [100.0, 0.0, 2.0], [float("inf"), 0.0, 2.0], [float("nan"), 0.0, 0.0]])
    u, inside = field_coords(xyz, box, contract=True)
    assert inside.tolist() == [True, True, True, False]
    assert torch.isfinite(u).all() and u.abs().max() <= 1.0
    assert u[0].tolist() == [0.0, 0.0, 0.0] and float(u[2, 0]) == pytest.approx(1.0)
    assert field_coords(xyz, box, contract=False)[1].tolist() == [True, False, False, False]


def test_a_contracted_field_has_density_far_outside_its_box():
    gen = torch.Generator().manual_seed(0)
    far = torch.tensor([[0.0, 0.0, 0.0], [50.0, -30.0, 7.0], [1e6, 0.0, 0.0]])
    for make in (lambda c: KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=8, multires=(1,), contract=c,
                                        generator=gen),
                 lambda c: NeRFField([[-1.0] * 3, [1.0] * 3], n_freqs=2, hidden=16, contract=c, generator=gen)):
        assert (make(True).density(far) > 0).all()
        assert (make(False).density(far)[1:] == 0).all()
