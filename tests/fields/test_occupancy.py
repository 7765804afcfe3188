import torch

from senerf.fields import OccupancyGrid

from ._fields_helpers import BallField


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
