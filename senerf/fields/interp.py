"""Bilinear interpolation of many 2D feature planes stored in one flat table.

Every plane of every scale lives in one ``(rows, F)`` table: a plane of resolution ``r`` is ``r * r``
consecutive rows, row ``b * r + a`` holds texel ``(a, b)``, ``a`` along the first coordinate of the pair.
:func:`plane_interp` is the pure-PyTorch path (any device; on CPU the compiled kernel of
:mod:`senerf.fields.ckernel` replaces it), :func:`plane_interp_reference` the ``grid_sample`` one.  Both agree
in value and gradient, except exactly on the box's faces (``u = +-1``), where the interpolation has a kink:
``gather`` returns a one-sided gradient there and ``grid_sample`` 0, both valid subgradients.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["PAIRS", "plane_layout", "plane_interp", "plane_interp_reference", "plane_tv", "plane_tv_reference"]

#: lookups per backward chunk: keeps each temporary at a few MB so the allocator reuses heap memory
_CHUNK = 1 << 15

#: coordinate pairs of the three planes, in order xy, xz, yz
PAIRS = ((0, 1), (0, 2), (1, 2))


def plane_layout(resolutions: tuple[int, ...], n_planes: int = 3) -> tuple[list[int], int]:
    """Row offsets of plane ``(s, p)`` at ``offsets[s * n_planes + p]`` and the total row count."""
    offsets, row = [], 0
    for r in resolutions:
        if r < 2:
            raise ValueError(f"resolution: every plane needs at least 2 texels per side, got {r}")
        for _ in range(n_planes):
            offsets.append(row)
            row += r * r
    return offsets, row


class _GatherBlend(torch.autograd.Function):
    """``out[m] = sum_c w[m, c] * table[idx[m, c]]`` for ``table (R, F)``, ``idx (M, 4)``, ``w (M, 4)``.

    ``idx[:, 1:] == idx[:, :1] + (1, r, r + 1)`` must hold, with ``r = strides[k]`` for lookups whose base row
    lies in ``spans[k] = (first_row, end_row)`` (one plane, or a run of planes sharing ``r``).  Backward into
    the table: the gradients of a quad's four corners go into one ``(rows, 4F)`` buffer with a single
    ``index_add_`` at ``base`` (one row of 4F per lookup, not four rows of F), then fold back by slice adds.
    """

    @staticmethod
    def forward(ctx, table, idx, w, strides, spans):
        out = torch.nn.functional.embedding_bag(idx, table, per_sample_weights=w, mode="sum")
        ctx.save_for_backward(table, idx, w)
        ctx.strides, ctx.spans = strides, spans
        return out

    @staticmethod
    def backward(ctx, g):
        table, idx, w = ctx.saved_tensors
        g = g.contiguous()
        g_table = g_w = None
        if ctx.needs_input_grad[0]:
            rows, nf = table.shape
            quad = g.new_zeros(rows, 4 * nf)
            base = idx[:, 0]
            for s in range(0, g.shape[0], _CHUNK):   # chunks keep temporaries small (no mmap page faults)
                src = (w[s:s + _CHUNK].unsqueeze(-1) * g[s:s + _CHUNK].unsqueeze(1)).view(-1, 4 * nf)
                quad.index_add_(0, base[s:s + _CHUNK], src)
            g_table = quad[:, :nf].clone()
            for (lo, hi), r in zip(ctx.spans, ctx.strides):
                for c, shift in ((1, 1), (2, r), (3, r + 1)):
                    g_table[lo + shift:hi] += quad[lo:hi - shift, c * nf:(c + 1) * nf]
        if ctx.needs_input_grad[2]:
            g_w = torch.stack([(table.index_select(0, idx[:, c]) * g).sum(-1) for c in range(4)], dim=-1)
        return g_table, None, g_w, None, None


def plane_interp(table: torch.Tensor, u: torch.Tensor, resolutions: tuple[int, ...],
                 offsets: list[int], pairs=PAIRS) -> torch.Tensor:
    """Bilinear features (``align_corners=True``) of every plane of every scale (fast path).

    Args:
        table: ``(rows, F)`` all planes (layout in the module docstring).
        u: ``(N, 3)`` normalised coordinates in ``[-1, 1]`` (values outside are clamped to the border).
        resolutions: per-scale plane resolution ``r_s``.
        offsets: from :func:`plane_layout`.
    Returns:
        ``(N, S, P, F)``, differentiable in ``table`` and ``u``.
    """
    n = u.shape[0]
    n_s, n_p = len(resolutions), len(pairs)
    cols = [c for pr in pairs for c in pr]
    up = u[:, cols].view(n, 1, n_p, 2)                                          # (N, 1, P, 2)
    res = torch.tensor(resolutions, dtype=u.dtype, device=u.device).view(1, n_s, 1, 1)
    pos = ((up + 1.0) * 0.5 * (res - 1.0)).clamp(min=0.0)
    pos = torch.minimum(pos, res - 1.0)                                         # (N, S, P, 2)
    i0 = torch.minimum(pos.detach().floor(), res - 2.0)
    f = pos - i0
    i0 = i0.long()
    res_i = torch.tensor(resolutions, dtype=torch.long, device=u.device).view(1, n_s, 1)
    off = torch.tensor(offsets, dtype=torch.long, device=u.device).view(1, n_s, n_p)
    base = off + i0[..., 1] * res_i + i0[..., 0]                               # (N, S, P)
    # rows point, scale, plane; columns the corners (a0, b0), (a0 + 1, b0), (a0, b0 + 1), (a0 + 1, b0 + 1)
    step = torch.stack([torch.zeros_like(res_i), torch.ones_like(res_i), res_i, res_i + 1], dim=-1)
    idx = (base.unsqueeze(-1) + step).reshape(-1, 4)
    fa, fb = f[..., 0], f[..., 1]
    ga, gb = 1.0 - fa, 1.0 - fb
    w = torch.stack([ga * gb, fa * gb, ga * fb, fa * fb], dim=-1).reshape(-1, 4)
    spans = [(offsets[s * n_p], offsets[s * n_p] + n_p * r * r) for s, r in enumerate(resolutions)]
    out = _GatherBlend.apply(table, idx, w.to(table.dtype), tuple(resolutions), tuple(spans))
    return out.view(n, n_s, n_p, table.shape[1])


def plane_interp_reference(planes: list[torch.Tensor], u: torch.Tensor, pairs=PAIRS) -> torch.Tensor:
    """Plain ``grid_sample(align_corners=True, padding_mode='border')`` reference.

    Args:
        planes: ``S * P`` tensors ``(F, r_s, r_s)`` (channel, row b, column a), order scale then plane.
        u: ``(N, 3)`` coordinates in ``[-1, 1]``.
    Returns:
        ``(N, S, P, F)``.
    """
    n_p = len(pairs)
    feats = []
    for k, plane in enumerate(planes):
        a, b = pairs[k % n_p]
        grid = u[:, [a, b]].view(1, -1, 1, 2).to(plane.dtype)
        s = F.grid_sample(plane.unsqueeze(0), grid, mode="bilinear", padding_mode="border",
                          align_corners=True)                                  # (1, F, N, 1)
        feats.append(s[0, :, :, 0].t())
    n_s = len(planes) // n_p
    return torch.stack(feats, dim=1).view(u.shape[0], n_s, n_p, planes[0].shape[0])


def _planes(table: torch.Tensor, resolutions: tuple[int, ...], offsets: list[int]):
    """The ``(r, r, F)`` views of every plane in ``table``, scale-major (as :func:`plane_layout` lays them out)."""
    n_planes = len(offsets) // len(resolutions)
    for k, o in enumerate(offsets):
        r = resolutions[k // n_planes]
        yield table[o:o + r * r].view(r, r, table.shape[-1])


def plane_tv_reference(table: torch.Tensor, resolutions: tuple[int, ...], offsets: list[int]) -> torch.Tensor:
    """Plane total variation ``mean(d_b^2) + mean(d_a^2)`` per plane (``d``: differences of neighbouring texels
    along each axis), summed over the planes, averaged over the scales; plain autograd through slices of
    ``table (rows, F)``.  Each slice's backward fills a gradient of the whole table, which makes this a costly
    part of a step for large planes: :func:`plane_tv` is the same value in two passes."""
    total = table.new_zeros(())
    for pl in _planes(table, resolutions, offsets):
        total = total + (pl[1:] - pl[:-1]).square().mean() + (pl[:, 1:] - pl[:, :-1]).square().mean()
    return total / len(resolutions)


def plane_tv(table: torch.Tensor, resolutions: tuple[int, ...], offsets: list[int]) -> torch.Tensor:
    """:func:`plane_tv_reference` of ``table (rows, F)``: on the CPU by the compiled kernel
    (:func:`~senerf.fields.ckernel.fused_plane_tv`: one pass for the value, one writing the gradient), elsewhere, or
    without a compiler, the reference.

    Example:
        >>> offsets, rows = plane_layout((2,), 1)
        >>> table = torch.tensor([[0.0], [1.0], [0.0], [1.0]], requires_grad=True)   # one 2x2 plane, columns differ
        >>> loss = plane_tv(table, (2,), offsets)
        >>> float(loss.detach()), table.grad is None
        (1.0, True)
    """
    from .ckernel import fused_plane_tv

    fused = fused_plane_tv(table, resolutions, offsets)
    return plane_tv_reference(table, resolutions, offsets) if fused is None else fused
