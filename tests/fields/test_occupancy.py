"""Tests of senerf/fields/occupancy.py: cells, decay, dilation and axis order, by hand."""

import numpy as np
import pytest
import torch

from senerf.fields import OccupancyGrid, field_coords

from .analytic_fields import BallField, ConstantField


def test_fresh_grid_full_outside_never():
    g = OccupancyGrid([[-1.0] * 3, [1.0] * 3], 8)
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.99, -0.99, 0.5], [1.01, 0.0, 0.0], [0.0, 0.0, -3.0]])
    assert g.is_occupied(pts).tolist() == [True, True, False, False]


def test_update_marks_ball_cells_and_decays():
    ball = BallField(center=(0.5, 0.5, 0.5), radius=0.3, value=5.0)
    g = OccupancyGrid([[0.0] * 3, [2.0] * 3], 10, threshold=1.0, decay=0.5, dilate=0)
    frac = g.update(ball)
    # cells of side 0.2 whose centres lie within 0.3 of (0.5, 0.5, 0.5): centres at 0.1 + 0.2 k;
    # offsets -0.2/0/+0.2 per axis within radius: 1 + 6 + 12 = 19 cells (sqrt(3)*0.2 = 0.35 > 0.3 excluded)
    assert round(frac * 1000) == 19
    assert g.is_occupied(torch.tensor([[0.5, 0.5, 0.5], [1.5, 1.5, 1.5]])).tolist() == [True, False]
    # the ball moves away: old estimate 5 decays to 2.5 (still > 1), then to 1.25, then 0.625 (empty)
    ball.center.fill_(1.5)
    for expect in (True, True, False):
        g.update(ball)
        assert bool(g.is_occupied(torch.tensor([[0.5, 0.5, 0.5]]))[0]) is expect
    dil = OccupancyGrid([[0.0] * 3, [2.0] * 3], 10, threshold=1.0, dilate=1)
    dil.update(BallField(center=(0.5, 0.5, 0.5), radius=0.05, value=5.0))   # exactly one cell
    assert round(dil.occupied_fraction() * 1000) == 27


def test_axis_order_with_an_off_diagonal_ball():
    # Catches: x and z (or any two axes) swapped in is_occupied's flat index, or in cell_centers' layout.
    # Box [0, 2]^3, 10 cells of 0.2 per side, centres at 0.1 + 0.2 k.  A ball of radius 0.15 at
    # (0.3, 1.5, 0.9) is the centre of cell (i, j, k) = (1, 7, 4) and reaches no other cell centre (the
    # nearest are 0.2 away), so exactly that cell, flat index (1 * 10 + 7) * 10 + 4 = 174, is occupied.
    g = OccupancyGrid([[0.0] * 3, [2.0] * 3], 10, threshold=1.0, dilate=0)
    g.update(BallField(center=(0.3, 1.5, 0.9), radius=0.15, value=5.0))
    assert torch.nonzero(g.mask).flatten().tolist() == [174]
    assert torch.allclose(g.cell_centers()[174], torch.tensor([0.3, 1.5, 0.9]), atol=1e-6)
    inside_cell = [[0.3, 1.5, 0.9], [0.21, 1.41, 0.81], [0.39, 1.59, 0.99]]  # centre and near corners
    others = [[0.9, 1.5, 0.3], [0.3, 0.9, 1.5], [1.5, 0.3, 0.9],  # the same coordinates in other orders
              [0.5, 1.5, 0.9], [0.1, 1.5, 0.9], [0.3, 1.7, 0.9], [0.3, 1.3, 0.9], [0.3, 1.5, 1.1],
              [0.3, 1.5, 0.7], [0.19, 1.5, 0.9], [0.3, 1.61, 0.9], [0.3, 1.5, 0.79]]  # neighbour cells
    occ = g.is_occupied(torch.tensor(inside_cell + others))
    assert occ.tolist() == [True] * 3 + [False] * len(others)


class _RecordingField:
    """Zero density everywhere; keeps the points it was asked about."""

    def __init__(self):
        self.points = []

    def density(self, xyz):
        self.points.append(xyz.clone())
        return torch.zeros(xyz.shape[0])


def test_update_evaluates_the_density_at_the_cell_centres_in_chunks():
    # Catches: points other than the cell centres (or in another order), or a chunk dropped or repeated.
    g = OccupancyGrid([[0.0, 0.0, 0.0], [2.0, 1.0, 4.0]], 10, dilate=0)
    field = _RecordingField()
    g.update(field, chunk=300)
    assert [p.shape[0] for p in field.points] == [300, 300, 300, 100]
    assert torch.equal(torch.cat(field.points), g.cell_centers())
    assert torch.allclose(g.cell_centers()[[0, 999]], torch.tensor([[0.1, 0.05, 0.2], [1.9, 0.95, 3.8]]))


def test_occupancy_grid_needs_at_least_one_cell():
    for bad in (0, -2):
        with pytest.raises(ValueError, match="resolution: expected >= 1"):
            OccupancyGrid([[-1.0] * 3, [1.0] * 3], resolution=bad)
    grid = OccupancyGrid([[-1.0] * 3, [1.0] * 3], resolution=1)
    assert grid.mask.shape == (1,) and grid.is_occupied(torch.zeros(1, 3)).tolist() == [True]


def test_a_contracted_grid_covers_all_of_space_with_cells_that_grow_outward():
    g = OccupancyGrid([[-1.0] * 3, [1.0] * 3], 8, threshold=1.0, dilate=0, contract=True)
    far = torch.tensor([[0.1, 0.0, 0.0], [40.0, 0.0, 0.0], [-1e5, 3.0, 2e4], [float("nan"), 0.0, 0.0]])
    assert g.is_occupied(far).tolist() == [True, True, True, False]   # a fresh grid: everywhere but NaN
    # the cell centres, mapped back through the contraction, land in the cells they stand for
    centres = g.cell_centers()
    u, _ = field_coords(centres, g.aabb, contract=True)
    ijk = ((u + 1.0) * 4.0).floor().long()
    flat = (ijk[:, 0] * 8 + ijk[:, 1]) * 8 + ijk[:, 2]
    assert torch.equal(flat, torch.arange(8 ** 3))
    # a constant density 0.3 per unit: a cell counts its density times its size relative to an inner cell,
    # 1 / (2 - m)^2 at contracted radius m (cells of the outer two rings: m = 1.25 and 1.75 -> 1.78 and 16)
    frac = g.update(ConstantField(value=0.3))
    m = np.abs(np.arange(8) + 0.5 - 4.0) / 2.0                       # per-axis |contracted coordinate| x 2
    radius = np.maximum.reduce(np.meshgrid(m, m, m, indexing="ij"))
    stretch = np.where(radius > 1.0, 1.0 / (2.0 - radius) ** 2, 1.0)
    assert frac == pytest.approx(float(np.mean(0.3 * stretch > 1.0)))
    assert 0.0 < frac < 1.0
    assert not bool(g.is_occupied(torch.tensor([[0.0, 0.0, 0.0]]))[0])
    assert bool(g.is_occupied(torch.tensor([[100.0, 0.0, 0.0]]))[0])


@pytest.mark.parametrize("contract", [False, True])
def test_cells_no_training_ray_crosses_stay_empty_after_every_update(contract):
    # Catches: a novel view rendering the untouched initial density of space no training camera saw (the space
    # right in front of a test camera, behind the training cameras), or a seen cell along a ray left out.
    g = OccupancyGrid([[-1.0] * 3, [1.0] * 3], 16, threshold=0.01, dilate=0, contract=contract)
    ys, zs = torch.meshgrid(torch.linspace(-0.1, 0.1, 24), torch.linspace(-0.1, 0.1, 24), indexing="ij")
    dirs = torch.stack([torch.ones_like(ys), ys, zs], -1).reshape(-1, 3)
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)                    # a bundle of rays along +x ...
    origins = torch.tensor([-1.5, 0.0, 0.0]).expand_as(dirs)         # ... from a camera outside the box
    near, far = torch.full((dirs.shape[0],), 0.1), torch.full((dirs.shape[0],), 1e3 if contract else 6.0)
    seen = g.mark_seen(origins, dirs, near, far)
    assert 0.0 < seen < 0.5
    on_axis = torch.tensor([[x, 0.0, 0.0] for x in np.linspace(-0.9, 0.9, 10)])
    assert g.is_occupied(on_axis).all()                               # every cell the rays cross
    aside = torch.tensor([[0.0, 0.9, 0.0], [0.0, 0.0, -0.9], [0.5, -0.8, 0.6]])  # outside the bundle
    assert not g.is_occupied(aside).any()
    g.update(ConstantField(value=1.0))                                # dense everywhere: only the seen cells
    assert g.is_occupied(on_axis).all() and not g.is_occupied(aside).any()
    assert g.occupied_fraction() == pytest.approx(seen)
    if contract:   # behind the camera and far beyond the box along the bundle
        assert not g.is_occupied(torch.tensor([[-50.0, 0.0, 0.0]])).any()
        assert g.is_occupied(torch.tensor([[50.0, 0.0, 0.0]])).all()
