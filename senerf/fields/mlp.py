"""Small MLP helpers with seeded initialisation (no global RNG)."""

from __future__ import annotations

import math

import torch
from torch import nn

__all__ = ["seeded_linear", "make_generator", "relu_mlp"]


def make_generator(generator: torch.Generator | None) -> torch.Generator:
    """``generator`` itself, or a new CPU generator seeded with 0."""
    return generator if generator is not None else torch.Generator().manual_seed(0)


def seeded_linear(n_in: int, n_out: int, generator: torch.Generator) -> nn.Linear:
    """``nn.Linear`` with PyTorch's default init law (``U(-1/sqrt(n_in), 1/sqrt(n_in))``) drawn from ``generator``."""
    layer = nn.Linear(n_in, n_out)
    bound = 1.0 / math.sqrt(n_in)
    with torch.no_grad():
        layer.weight.copy_(torch.rand(n_out, n_in, generator=generator) * (2 * bound) - bound)
        layer.bias.copy_(torch.rand(n_out, generator=generator) * (2 * bound) - bound)
    return layer


class _ReluMLP(torch.autograd.Function):
    """``Linear -> ReLU -> ... -> Linear`` with a hand-written backward that reuses buffers in place
    (the ReLU mask is applied to the incoming gradient in place; activations are the only saved state)."""

    @staticmethod
    def forward(ctx, x, *params):
        ws, bs = params[0::2], params[1::2]
        acts = [x]
        h = x
        for i, (w, b) in enumerate(zip(ws, bs)):
            h = torch.addmm(b, h, w.t())
            if i < len(ws) - 1:
                h.relu_()
                acts.append(h)
        ctx.save_for_backward(*acts, *params)
        ctx.n_layers = len(ws)
        return h

    @staticmethod
    def backward(ctx, g):
        saved = ctx.saved_tensors
        n = ctx.n_layers
        acts, params = saved[:n], saved[n:]
        ws = params[0::2]
        grads = [None] * (2 * n)
        g = g.contiguous()
        for i in range(n - 1, -1, -1):
            a = acts[i]
            grads[2 * i] = g.t().mm(a)
            grads[2 * i + 1] = g.sum(0)
            if i > 0 or ctx.needs_input_grad[0]:
                g = g.mm(ws[i])
                if i > 0:   # a = relu output of layer i - 1: zero the gradient where it was clipped
                    torch.ops.aten.threshold_backward.grad_input(g, a, 0.0, grad_input=g)
        gx = g if ctx.needs_input_grad[0] else None
        return (gx, *grads)


def relu_mlp(x: torch.Tensor, net: nn.Sequential) -> torch.Tensor:
    """Apply ``net`` (alternating ``nn.Linear`` and ``nn.ReLU``, ending with a Linear) through :class:`_ReluMLP`.

    Args:
        x: ``(N, in_features)``.
    Returns:
        ``(N, out_features)``; same value and gradients as ``net(x)``.
    """
    params = []
    for m in net:
        if isinstance(m, nn.Linear):
            params += [m.weight, m.bias]
        elif not isinstance(m, nn.ReLU):
            raise ValueError(f"relu_mlp: unsupported layer {type(m).__name__}")
    return _ReluMLP.apply(x, *params)
