"""NeRF annealing reaches the network, K-Planes' Hadamard product, TV axes and density shift (mutation audit)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from senerf.fields import KPlanesField, NeRFField


def test_nerf_annealed_bands_carry_no_gradient_into_the_trunk():
    # Catches: NeRFField ignoring its band weights (encoding without them), or applying them to the wrong
    # columns.  Encoding columns: [x (3), band 0 sin/cos (6), band 1 (6), ...], into the first layer and
    # again at the skip layer (after `hidden` columns).  With N = 100 and 4 bands, step 25 gives
    # eta = 4 * 25 / 100 = 1: band 0 fully on, bands 1..3 off, so their weight columns get exactly 0 gradient.
    gen = torch.Generator().manual_seed(0)
    f = NeRFField(aabb=None, n_freqs=4, hidden=16, n_layers=2, view_dependent=False, anneal_steps=100,
                  generator=gen)
    xyz = torch.rand(64, 3, generator=gen) * 2 - 1
    f.set_progress(25)
    f.density(xyz).sum().backward()
    g0, g1 = f.trunk[0].weight.grad, f.trunk[1].weight.grad      # g1: skip layer, enc after 16 columns
    assert torch.equal(g0[:, 9:], torch.zeros_like(g0[:, 9:])) and g0[:, 3:9].abs().sum() > 0
    assert torch.equal(g1[:, 16 + 9:], torch.zeros_like(g1[:, 16 + 9:])) and g1[:, 16 + 3:16 + 9].abs().sum() > 0
    f.zero_grad()
    f.set_progress(100)                                            # eta = 4: every band on
    f.density(xyz).sum().backward()
    assert (f.trunk[0].weight.grad[:, 9:].abs().sum(0) > 0).all()


def test_nerf_band_weights_change_the_density_only_through_high_bands():
    # Catches: set_progress not reaching forward() (band weights ignored): the same field and points at
    # step 0 (eta = 0, every band off) and at step N (every band on) must give different densities.
    f = NeRFField(aabb=[[-1] * 3, [1] * 3], n_freqs=3, hidden=16, n_layers=2, anneal_steps=10,
                  generator=torch.Generator().manual_seed(1))
    xyz = torch.tensor([[0.3, -0.2, 0.5], [0.1, 0.7, -0.4]])
    f.set_progress(0)
    off = f.density(xyz).detach()
    f.set_progress(10)
    on = f.density(xyz).detach()
    assert not torch.allclose(off, on)


def _grid_sample_features(field, u):
    """Hadamard product over the 3 planes of each scale, by torch.nn.functional.grid_sample directly."""
    pairs = ((0, 1), (0, 2), (1, 2))
    feats = []
    for s in range(len(field.resolutions)):
        prod = 1.0
        for p, (a, b) in enumerate(pairs):
            plane = field.plane(s, p).permute(2, 0, 1)[None]               # (1, F, r(b), r(a))
            grid = u[:, [a, b]].view(1, -1, 1, 2)
            v = F.grid_sample(plane, grid, mode="bilinear", padding_mode="border", align_corners=True)
            prod = prod * v[0, :, :, 0].t()                               # (N, F)
        feats.append(prod)
    return torch.cat(feats, dim=1)


@pytest.mark.parametrize("backend", ["auto", "gather", "grid_sample"])
def test_kplanes_features_are_the_product_of_the_three_planes(backend):
    # Catches: the sum (or any other combination) instead of the Hadamard product of the plane features, in
    # every backend (the gather and grid_sample paths do not depend on the compiled kernel being available).
    f = KPlanesField([[-1.0, -2.0, -1.0], [1.0, 2.0, 3.0]], resolution=6, n_features=4, multires=(1, 2),
                     generator=torch.Generator().manual_seed(0), backend=backend)
    gen = torch.Generator().manual_seed(1)
    xyz = torch.rand(200, 3, generator=gen) * torch.tensor([2.0, 4.0, 4.0]) + torch.tensor([-1.0, -2.0, -1.0])
    u = (xyz - torch.tensor([-1.0, -2.0, -1.0])) * (2.0 / torch.tensor([2.0, 4.0, 4.0])) - 1.0
    with torch.no_grad():
        feat, inside = f.features(xyz)
        ref = _grid_sample_features(f, u)
    assert inside.all()
    torch.testing.assert_close(feat, ref, rtol=1e-5, atol=1e-6)


def test_kplanes_tv_counts_both_plane_axes():
    # Catches: both TV terms differencing the same axis (the second must run along the other one).
    # Table constant 0.3 except plane (scale 0, xy) = 0.3 + 0.1 a (a ramp along its columns, 6x6, 4 features):
    # along the ramp every difference is 0.1 -> mean 0.01; across it 0 -> 0.01 in all, / 2 scales = 0.005.
    # The same ramp along the rows (b) must give the same value.
    f = KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=6, n_features=4, multires=(1, 2),
                     generator=torch.Generator().manual_seed(0))
    ramp = 0.1 * torch.arange(6.0)
    for view in (ramp.view(1, 6, 1), ramp.view(6, 1, 1)):
        with torch.no_grad():
            f.table.fill_(0.3)
            f.plane(0, 0).add_(view)
        np.testing.assert_allclose(float(f.regularizer().detach()), 0.005, rtol=1e-5)


def test_kplanes_density_shift_multiplies_density_by_exp_shift():
    # Catches: density_shift subtracted instead of added.  sigma = exp(raw + shift) (raw < 15 here), so two
    # fields with the same seed differ by the factor exp(0.7) = 2.0137527 inside the box.
    xyz = torch.rand(50, 3, generator=torch.Generator().manual_seed(2)) * 1.8 - 0.9
    sig = [KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=6, n_features=4, density_shift=s,
                        generator=torch.Generator().manual_seed(0)).density(xyz).detach() for s in (0.0, 0.7)]
    torch.testing.assert_close(sig[1] / sig[0], torch.full((50,), math.exp(0.7)), rtol=1e-5, atol=0)


def _fields():
    gen = torch.Generator().manual_seed(0)
    box = [[-1.0] * 3, [1.0] * 3]
    return {
        "kplanes": KPlanesField(box, resolution=8, n_features=4, multires=(1, 2), hidden=8, geo_features=4,
                                sh_degree=2, generator=gen),
        "kplanes-gather": KPlanesField(box, resolution=8, n_features=4, multires=(1,), hidden=8, geo_features=4,
                                       sh_degree=2, generator=gen, backend="gather"),
        "kplanes-grid_sample": KPlanesField(box, resolution=8, n_features=4, multires=(1, 2), hidden=8,
                                            geo_features=4, sh_degree=2, generator=gen, backend="grid_sample"),
        "nerf": NeRFField(aabb=box, n_freqs=4, hidden=16, n_layers=2, generator=gen),
        "nerf-unbounded-annealed": NeRFField(aabb=None, n_freqs=4, hidden=16, n_layers=2, view_dependent=False,
                                             anneal_steps=10, generator=gen),
    }


@pytest.mark.parametrize("name", sorted(_fields()))
def test_every_field_takes_zero_points(name):
    # An occupancy grid can drop every sample of a chunk of rays (all in empty space): the field then gets
    # (0, 3) points.  The NeRF field's positional encoding once failed there (reshape(0, -1) is ambiguous),
    # which crashed `senerf-fit --field nerf` on lego Extreme at its first test-view render.
    f = _fields()[name]
    xyz = torch.zeros(0, 3, requires_grad=True)
    dirs = torch.zeros(0, 3)
    sigma, rgb = f(xyz, dirs)
    assert sigma.shape == (0,) and rgb.shape == (0, 3)
    assert f.density(xyz).shape == (0,)
    (sigma.sum() + rgb.sum()).backward()   # a training step whose batch kept no sample still steps
    assert xyz.grad.shape == (0, 3)


@pytest.mark.parametrize("name", sorted(_fields()))
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


def test_the_grid_sample_reference_takes_zero_points():
    from senerf.fields.interp import plane_interp_reference
    planes = [torch.rand(4, 5, 5) for _ in range(6)]   # two scales x three planes, four features
    assert plane_interp_reference(planes, torch.zeros(0, 3)).shape == (0, 2, 3, 4)
