"""Tests of senerf/fields/nerf.py: the field contract and the coarse-to-fine annealing schedule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from senerf.fields import NeRFField, RadianceField


def test_nerf_field_contract():
    f = NeRFField(aabb=[[-1] * 3, [1] * 3], n_freqs=4, hidden=32, n_layers=3,
                  generator=torch.Generator().manual_seed(0))
    assert isinstance(f, RadianceField)
    pts = torch.tensor([[0.1, 0.2, 0.3], [2.0, 0.0, 0.0]])
    sigma, rgb = f(pts, torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    assert sigma.shape == (2,) and rgb.shape == (2, 3) and sigma[1] == 0 and sigma[0] > 0
    torch.testing.assert_close(f.density(pts), sigma)
    assert float(f.regularizer().detach()) == 0.0


def test_nerf_field_progress_schedule():
    f = NeRFField(aabb=[[-1] * 3, [1] * 3], n_freqs=8, hidden=16, n_layers=2)
    assert torch.equal(f.set_progress(0, 400), torch.zeros(8))            # eta = 0
    assert torch.equal(f.set_progress(100, 400), torch.ones(8))           # step = N = total / 4: eta = m
    w = f.set_progress(25, 400)                                            # eta = 8 * 25 / 100 = 2
    np.testing.assert_allclose(w.numpy(), [1, 1, 0, 0, 0, 0, 0, 0], atol=1e-7)
    g = NeRFField(n_freqs=4, hidden=16, n_layers=2, anneal_steps=10)
    np.testing.assert_allclose(g.set_progress(5).numpy(), [1, 1, 0, 0], atol=1e-7)
    with pytest.raises(ValueError, match="total_steps"):
        NeRFField(n_freqs=4, hidden=8, n_layers=2).set_progress(3)


def test_nerf_annealed_bands_carry_no_gradient_into_the_trunk():
    # Encoding columns: [x (3), band 0 sin/cos (6), band 1 (6), ...], into the first layer and again at the skip
    # layer (after `hidden` columns).  With N = 100 and 4 bands, step 25 gives eta = 4 * 25 / 100 = 1: band 0
    # fully on, bands 1..3 off, so their weight columns get exactly 0 gradient.
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


def test_nerf_band_weights_reach_the_density():
    # the same field and points at step 0 (eta = 0, every band off) and at step N (every band on) differ
    f = NeRFField(aabb=[[-1] * 3, [1] * 3], n_freqs=3, hidden=16, n_layers=2, anneal_steps=10,
                  generator=torch.Generator().manual_seed(1))
    xyz = torch.tensor([[0.3, -0.2, 0.5], [0.1, 0.7, -0.4]])
    f.set_progress(0)
    off = f.density(xyz).detach()
    f.set_progress(10)
    on = f.density(xyz).detach()
    assert not torch.allclose(off, on)
