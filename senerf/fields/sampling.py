"""Ray sampling: stratified bins and the NDC transform for forward-facing scenes."""

from __future__ import annotations

import torch

__all__ = ["stratified_bins", "ndc_rays", "ndc_t_to_depth"]


def check_rays(rays_o: torch.Tensor, rays_d: torch.Tensor) -> None:
    """Raise ``ValueError`` unless ``rays_o`` and ``rays_d`` share one shape ``(R, 3)``."""
    if rays_o.ndim != 2 or rays_o.shape[1] != 3 or rays_d.shape != rays_o.shape:
        raise ValueError(f"rays_o/rays_d: expected equal shapes (R, 3), got {tuple(rays_o.shape)}, "
                         f"{tuple(rays_d.shape)}")


def stratified_bins(near: torch.Tensor, far: torch.Tensor, n_bins: int,
                    generator: torch.Generator | None = None, randomized: bool = True) -> torch.Tensor:
    """One point per evenly spaced bin.

    Bin ``k`` of a ray is ``[near + k (far - near) / n_bins, near + (k + 1) (far - near) / n_bins)``; the
    point is ``near + (k + u) (far - near) / n_bins`` with ``u ~ U[0, 1)`` from ``generator``
    (``randomized=False``: ``u = 0.5``, the bin centre).  Bin k has the same bounds for every call, so a
    teacher and a student sampled with the same near/far pair bin by bin.

    Args:
        near: ``(R,)`` start distances.
        far: ``(R,)`` end distances, ``>= near``.
        n_bins: bins per ray.
        generator: torch.Generator on ``near``'s device (required when ``randomized``).
    Returns:
        t ``(R, n_bins)``, increasing along each ray.
    """
    if near.ndim != 1 or far.shape != near.shape:
        raise ValueError(f"near/far: expected equal shapes (R,), got {tuple(near.shape)}, {tuple(far.shape)}")
    if n_bins < 1:
        raise ValueError(f"n_bins: expected >= 1, got {n_bins}")
    k = torch.arange(n_bins, dtype=near.dtype, device=near.device)
    if randomized:
        if generator is None:
            raise ValueError("generator: required when randomized=True")
        u = torch.rand(near.shape[0], n_bins, generator=generator, dtype=near.dtype, device=near.device)
    else:
        u = torch.full((near.shape[0], n_bins), 0.5, dtype=near.dtype, device=near.device)
    step = (far - near)[:, None] / n_bins
    return near[:, None] + (k[None, :] + u) * step


def ndc_rays(rays_o: torch.Tensor, rays_d: torch.Tensor, fx: float, fy: float, width: float,
             height: float, near: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """LLFF normalised device coordinates for cameras looking along **+z** (OpenCV convention).

    Rays must be expressed in a frame whose +z is the scene's forward direction (e.g. the mean camera
    frame of a forward-facing capture) with every ray having ``d_z > 0``.  The map is
    ``(X, Y, Z) -> (ax X / Z, ay Y / Z, 1 - 2 near / Z)`` with ``ax = fx / (W / 2)``, ``ay = fy / (H / 2)``
    (principal point at the image centre); it keeps rays straight.  Each origin is first moved to the
    plane ``Z = near``; then ``o' = (ax ox/oz, ay oy/oz, 1 - 2 near/oz) = (.., .., -1)`` and
    ``d' = (ax (dx/dz - ox/oz), ay (dy/dz - oy/oz), 2 near / oz)``, so a point at depth ``Z`` lies at NDC
    parameter ``t' = 1 - near / Z`` (``t'`` in ``[0, 1)`` for ``Z`` in ``[near, inf)``).

    Args:
        rays_o: ``(R, 3)`` origins; rays_d: ``(R, 3)`` directions (any length, ``d_z > 0``).
    Returns:
        ``(o_ndc (R, 3), d_ndc (R, 3))``; sample with ``t`` in ``[0, 1]``.
    """
    check_rays(rays_o, rays_d)
    if near <= 0:
        raise ValueError(f"near: expected > 0, got {near}")
    dz = rays_d[:, 2].clamp(min=1e-9)
    t = (near - rays_o[:, 2]) / dz
    o = rays_o + t[:, None] * rays_d
    ox, oy, oz = o.unbind(-1)
    oz = oz.clamp(min=1e-9)
    ax, ay = 2.0 * fx / width, 2.0 * fy / height
    o_ndc = torch.stack([ax * ox / oz, ay * oy / oz, 1.0 - 2.0 * near / oz], dim=-1)
    d_ndc = torch.stack([ax * (rays_d[:, 0] / dz - ox / oz), ay * (rays_d[:, 1] / dz - oy / oz),
                         2.0 * near / oz], dim=-1)
    return o_ndc, d_ndc


def ndc_t_to_depth(t: torch.Tensor, near: float = 1.0) -> torch.Tensor:
    """Camera-frame depth ``Z = near / (1 - t)`` of NDC parameter ``t`` (any shape); ``t -> 1`` is clamped
    to ``1 - 1e-6`` so the result stays finite."""
    return near / (1.0 - t).clamp(min=1e-6)
