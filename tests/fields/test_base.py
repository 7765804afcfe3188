"""Tests of senerf/fields/base.py: the RadianceField contract (every field), AABB and point checks."""

from __future__ import annotations

import pytest
import torch

from senerf.fields import KPlanesField, NeRFField, RadianceField
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
