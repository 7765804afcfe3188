"""Encodings: real spherical harmonics (degree 4 = 16 coefficients), positional encoding with
coarse-to-fine frequency annealing (Nerfies / BARF / the SE-NeRF paper's vanilla NeRF teacher)."""

from __future__ import annotations

import math

import torch

from .ckernel import fused_sh4

__all__ = ["sh_encoding", "sh_encoding_reference", "positional_encoding", "anneal_weights"]


def sh_encoding(dirs: torch.Tensor, degree: int = 4) -> torch.Tensor:
    """:func:`sh_encoding_reference`, by :func:`~senerf.fields.ckernel.fused_sh4` for degree 4 where it can run.

    Args:
        dirs: ``(N, 3)`` unit directions.
        degree: 1..4; ``degree ** 2`` outputs.
    Returns:
        ``(N, degree ** 2)``.
    """
    if degree == 4 and dirs.ndim == 2 and dirs.shape[1] == 3:
        out = fused_sh4(dirs)
        if out is not None:
            return out
    return sh_encoding_reference(dirs, degree)


def sh_encoding_reference(dirs: torch.Tensor, degree: int = 4) -> torch.Tensor:
    """Real spherical harmonics ``Y_lm`` for ``l < degree`` (tiny-cuda-nn's convention and signs), in PyTorch.

    Orthonormal on the unit sphere: ``integral Y_i Y_j dOmega = delta_ij``.

    Args:
        dirs: ``(N, 3)`` unit directions.
        degree: 1..4; ``degree ** 2`` outputs (4 -> 16, as K-Planes).
    Returns:
        ``(N, degree ** 2)``.
    """
    if degree not in (1, 2, 3, 4):
        raise ValueError(f"degree: expected 1..4, got {degree}")
    if dirs.ndim != 2 or dirs.shape[1] != 3:
        raise ValueError(f"dirs: expected shape (N, 3), got {tuple(dirs.shape)}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, 0.28209479177387814)]
    if degree > 1:
        out += [-0.48860251190291987 * y, 0.48860251190291987 * z, -0.48860251190291987 * x]
    if degree > 2:
        x2, y2, z2 = x * x, y * y, z * z
        out += [
            1.0925484305920792 * x * y,
            -1.0925484305920792 * y * z,
            0.94617469575755997 * z2 - 0.31539156525251999,
            -1.0925484305920792 * x * z,
            0.54627421529603959 * (x2 - y2),
        ]
    if degree > 3:
        out += [
            0.59004358992664352 * y * (-3.0 * x2 + y2),
            2.8906114426405538 * x * y * z,
            0.45704579946446572 * y * (1.0 - 5.0 * z2),
            0.3731763325901154 * z * (5.0 * z2 - 3.0),
            0.45704579946446572 * x * (1.0 - 5.0 * z2),
            1.4453057213202769 * z * (x2 - y2),
            0.59004358992664352 * x * (-x2 + 3.0 * y2),
        ]
    return torch.stack(out, dim=-1)


def anneal_weights(eta: float, n_freqs: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """Coarse-to-fine weights ``w_j = (1 - cos(pi * clamp(eta - j, 0, 1))) / 2`` for ``j < n_freqs``.

    Args:
        eta: ``n_freqs * step / N``; band ``j`` is off for ``eta <= j``, fully on for ``eta >= j + 1``.
    Returns:
        ``(n_freqs,)``.
    """
    j = torch.arange(n_freqs, dtype=torch.float64)
    a = (float(eta) - j).clamp(0.0, 1.0)
    return ((1.0 - torch.cos(math.pi * a)) / 2.0).to(dtype=dtype, device=device)


def positional_encoding(x: torch.Tensor, n_freqs: int, weights: torch.Tensor | None = None) -> torch.Tensor:
    """NeRF positional encoding ``[x, sin(2^j pi x), cos(2^j pi x)]_j`` with optional band weights.

    Args:
        x: ``(N, D)``.
        n_freqs: number of octaves.
        weights: ``(n_freqs,)`` per-band weights (:func:`anneal_weights`) or ``None`` (all ones).
    Returns:
        ``(N, D * (2 * n_freqs + 1))``: ``x``, then for band j the ``sin`` then the ``cos`` of every input
        dimension.
    """
    if x.ndim != 2:
        raise ValueError(f"x: expected shape (N, D), got {tuple(x.shape)}")
    freqs = (2.0 ** torch.arange(n_freqs, dtype=x.dtype, device=x.device)) * math.pi
    xb = x[:, None, :] * freqs[None, :, None]                       # (N, F, D)
    enc = torch.cat([torch.sin(xb), torch.cos(xb)], dim=-1)          # (N, F, 2D)
    if weights is not None:
        if weights.shape != (n_freqs,):
            raise ValueError(f"weights: expected shape ({n_freqs},), got {tuple(weights.shape)}")
        enc = enc * weights.to(enc)[None, :, None]
    enc = enc.reshape(x.shape[0], 2 * n_freqs * x.shape[1])   # explicit: N = 0 (no sample kept) is valid
    return torch.cat([x, enc], dim=-1)
