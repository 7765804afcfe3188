"""Tests of senerf/fields/mlp.py: the fused ReLU MLP against torch's own."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from senerf.fields.mlp import relu_mlp


def test_relu_mlp_equals_sequential_in_value_and_gradient():
    gen = torch.Generator().manual_seed(3)
    net = nn.Sequential(nn.Linear(5, 7), nn.ReLU(), nn.Linear(7, 6), nn.ReLU(), nn.Linear(6, 2)).double()
    x = torch.randn(40, 5, generator=gen, dtype=torch.float64, requires_grad=True)
    a, b = relu_mlp(x, net), net(x)
    torch.testing.assert_close(a, b, rtol=0, atol=1e-14)
    g = torch.randn(a.shape, generator=gen, dtype=torch.float64)
    inputs = [x, *net.parameters()]
    for p, q in zip(torch.autograd.grad(a, inputs, g), torch.autograd.grad(b, inputs, g)):
        torch.testing.assert_close(p, q, rtol=1e-12, atol=1e-13)


def test_relu_mlp_refuses_layers_it_does_not_fuse():
    # a Tanh skipped silently would compute another function
    net = nn.Sequential(nn.Linear(2, 3), nn.Tanh(), nn.Linear(3, 1))
    with pytest.raises(ValueError, match="relu_mlp: unsupported layer Tanh"):
        relu_mlp(torch.zeros(4, 2), net)
