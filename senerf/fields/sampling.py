"""Ray sampling: stratified bins (even in distance, or even in contracted space for unbounded scenes) and the NDC
transform for forward-facing scenes."""

from __future__ import annotations

import torch

from .base import contract_unit

__all__ = ["bin_fractions", "linear_bins", "contracted_bins", "ray_bins", "ndc_points", "ndc_rays",
           "ndc_t_to_depth", "CONTRACTED_CANDIDATES"]

#: Distances per ray, geometrically spaced from near to far, whose contracted positions place contracted bins.
CONTRACTED_CANDIDATES = 128


def check_rays(rays_o: torch.Tensor, rays_d: torch.Tensor) -> None:
    """Raise ``ValueError`` unless ``rays_o`` and ``rays_d`` share one shape ``(R, 3)``."""
    if rays_o.ndim != 2 or rays_o.shape[1] != 3 or rays_d.shape != rays_o.shape:
        raise ValueError(f"rays_o/rays_d: expected equal shapes (R, 3), got {tuple(rays_o.shape)}, "
                         f"{tuple(rays_d.shape)}")


def _check_bounds(near: torch.Tensor, far: torch.Tensor) -> None:
    if near.ndim != 1 or far.shape != near.shape:
        raise ValueError(f"near/far: expected equal shapes (R,), got {tuple(near.shape)}, {tuple(far.shape)}")


def bin_fractions(near: torch.Tensor, n_bins: int, generator: torch.Generator | None = None,
                  randomized: bool = True) -> torch.Tensor:
    """Where each sample sits inside its bin: ``u (R, n_bins)`` uniform in ``[0, 1)`` from ``generator``
    (``randomized=False``: 0.5, the bin centres), with ``R``, dtype and device those of ``near (R,)``."""
    if n_bins < 1:
        raise ValueError(f"n_bins: expected >= 1, got {n_bins}")
    if randomized:
        if generator is None:
            raise ValueError("generator: required when randomized=True")
        return torch.rand(near.numel(), n_bins, generator=generator, dtype=near.dtype, device=near.device)
    return torch.full((near.numel(), n_bins), 0.5, dtype=near.dtype, device=near.device)


def linear_bins(near: torch.Tensor, far: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """The points ``near + (k + u_k) (far - near) / S`` of ``S`` evenly spaced bins.

    Args:
        near, far: ``(R,)``; u: ``(R, S)`` fractions in ``[0, 1)`` (:func:`bin_fractions`).
    Returns:
        t ``(R, S)``.
    """
    k = torch.arange(u.shape[-1], dtype=near.dtype, device=near.device)
    step = (far - near)[:, None] / u.shape[-1]
    return near[:, None] + (k[None, :] + u) * step


def contracted_bins(origins: torch.Tensor, dirs: torch.Tensor, near: torch.Tensor, far: torch.Tensor,
                    u: torch.Tensor, aabb, n_candidates: int = CONTRACTED_CANDIDATES) -> torch.Tensor:
    """``S`` bins per ray spanning equal lengths of the ray's path in contracted space
    (:func:`~senerf.fields.contract_unit` around ``aabb``): even in distance inside the box, nearly even in
    disparity far beyond it, and for every ray, wherever its camera stands.

    The path is measured at ``n_candidates + 1`` distances spaced geometrically from ``near`` to ``far`` (chord
    lengths between their contracted positions); bin edges are placed by inverting that cumulative length,
    linearly in distance between two candidates (exact inside the box, where the contraction is the identity).
    The bins depend on the ray only, so a teacher and a student pair bin by bin.

    Args:
        origins, dirs: ``(R, 3)`` rays in the model frame.
        near, far: ``(R,)``, ``0 < near <= far`` (a ``near`` below ``1e-9 far`` starts there).
        u: ``(R, S)`` fractions in ``[0, 1)`` (:func:`bin_fractions`).
        aabb: ``(2, 3)`` inner box of the contraction.
    Returns:
        t ``(R, S)``, non-decreasing along each ray, in ``[near, far]``.
    """
    check_rays(origins, dirs)
    _check_bounds(near, far)
    box = torch.as_tensor(aabb, dtype=origins.dtype, device=origins.device)
    centre, half = (box[0] + box[1]) / 2, (box[1] - box[0]) / 2
    o, d = (origins - centre) / half, dirs / half
    start = torch.maximum(near, far * 1e-9).clamp_min(torch.finfo(near.dtype).tiny)
    j = torch.arange(n_candidates + 1, dtype=near.dtype, device=near.device) / n_candidates
    cand = start[:, None] * (far / start)[:, None] ** j                           # (R, M + 1)
    pts = contract_unit(o[:, None, :] + cand[..., None] * d[:, None, :])          # (R, M + 1, 3)
    seg = (pts[:, 1:] - pts[:, :-1]).norm(dim=-1)                                 # (R, M)
    seg = seg + 1e-30                                                             # an empty segment: even bins
    cdf = torch.cat([torch.zeros_like(seg[:, :1]), torch.cumsum(seg, dim=-1)], dim=-1)
    cdf = cdf / cdf[:, -1:]
    s = (torch.arange(u.shape[-1], dtype=u.dtype, device=u.device) + u) / u.shape[-1]
    hi = torch.searchsorted(cdf, s.contiguous(), right=True).clamp(1, n_candidates)
    c0, c1 = cdf.gather(1, hi - 1), cdf.gather(1, hi)
    t0, t1 = cand.gather(1, hi - 1), cand.gather(1, hi)
    t = t0 + (s - c0) / (c1 - c0).clamp_min(1e-30) * (t1 - t0)
    return torch.minimum(torch.maximum(t, near[:, None]), far[:, None])


def ray_bins(origins: torch.Tensor, dirs: torch.Tensor, near: torch.Tensor, far: torch.Tensor, u: torch.Tensor,
             contract_aabb=None) -> torch.Tensor:
    """The sample distances ``t (R, S)`` of fractions ``u (R, S)``: :func:`linear_bins`, or :func:`contracted_bins`
    around ``contract_aabb`` (a field's box when it contracts space: :attr:`RadianceField.contract`)."""
    if contract_aabb is None:
        _check_bounds(near, far)
        return linear_bins(near, far, u)
    return contracted_bins(origins, dirs, near, far, u, contract_aabb)


def ndc_points(xyz: torch.Tensor, fx: float, fy: float, width: float, height: float, near: float = 1.0
               ) -> torch.Tensor:
    """The NDC map of :func:`ndc_rays`, ``(X, Y, Z) -> (ax X / Z, ay Y / Z, 1 - 2 near / Z)``, of points
    ``xyz (..., 3)`` in the frame whose +z is the scene's forward direction (``Z`` clamped to ``1e-9``)."""
    x, y, z = xyz.unbind(-1)
    z = z.clamp(min=1e-9)
    ax, ay = 2.0 * fx / width, 2.0 * fy / height
    return torch.stack([ax * x / z, ay * y / z, 1.0 - 2.0 * near / z], dim=-1)


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
    o_ndc = ndc_points(o, fx, fy, width, height, near)
    d_ndc = torch.stack([ax * (rays_d[:, 0] / dz - ox / oz), ay * (rays_d[:, 1] / dz - oy / oz),
                         2.0 * near / oz], dim=-1)
    return o_ndc, d_ndc


def ndc_t_to_depth(t: torch.Tensor, near: float = 1.0) -> torch.Tensor:
    """Camera-frame depth ``Z = near / (1 - t)`` of NDC parameter ``t`` (any shape); ``t -> 1`` is clamped
    to ``1 - 1e-6`` so the result stays finite."""
    return near / (1.0 - t).clamp(min=1e-6)
