"""Volume rendering: stable compositing, ray marching through a field, chunked image rendering."""

from __future__ import annotations

import numpy as np
import torch

from .sampling import bin_fractions, check_rays, ray_bins

__all__ = ["volume_render", "render_rays", "render_image", "contraction_box", "bin_distortion", "EMPTY_ACC"]

#: rays whose accumulated opacity is below this are "empty": their ray_dist is t_far
EMPTY_ACC = 1e-6


def volume_render(sigma: torch.Tensor, rgb: torch.Tensor, t: torch.Tensor, t_far: torch.Tensor,
                  background=None) -> dict:
    """Composite samples along rays (transmittance in log space).

    ``delta_i = t_{i+1} - t_i`` (last: ``t_far - t_{S-1}``), ``tau_i = sigma_i delta_i``,
    ``T_i = exp(-sum_{k<i} tau_k)``, ``alpha_i = -expm1(-tau_i)``, ``w_i = T_i alpha_i``.
    Finite values and gradients for sigma in [0, 1e8] and delta in [0, 1e3].

    Args:
        sigma: ``(R, S)`` densities >= 0.
        rgb: ``(R, S, 3)`` colours.
        t: ``(R, S)`` increasing sample distances.
        t_far: ``(R,)`` end of the last interval (finite).
        background: ``(3,)`` or ``(R, 3)`` colour composited as ``rgb + (1 - acc) * bg``; ``None`` = black.
    Returns:
        dict ``rgb (R, 3)``, ``acc (R,)`` (sum of weights), ``ray_dist (R,)`` (``sum w t / sum w``; for an
        empty ray, ``acc < EMPTY_ACC``, it is ``t_far``), ``weights (R, S)``, ``t (R, S)``.
    """
    if sigma.ndim != 2:
        raise ValueError(f"sigma: expected shape (R, S), got {tuple(sigma.shape)}")
    r, s = sigma.shape
    for name, x, want in (("rgb", rgb, (r, s, 3)), ("t", t, (r, s)), ("t_far", t_far, (r,))):
        if x.shape != want:
            raise ValueError(f"{name}: expected shape {want}, got {tuple(x.shape)}")
    delta = (torch.cat([t[:, 1:], t_far[:, None].to(t)], dim=1) - t).clamp(min=0.0)   # (R, S), >= 0
    tau = sigma * delta
    # exclusive cumsum by shifting (not cumsum - tau: that cancels catastrophically after a huge tau)
    log_t = torch.cat([torch.zeros_like(tau[:, :1]), torch.cumsum(tau[:, :-1], dim=1)], dim=1)
    weights = torch.exp(-log_t) * (-torch.expm1(-tau))
    acc = weights.sum(dim=1)
    color = (weights.unsqueeze(-1) * rgb).sum(dim=1)
    if background is not None:
        bg = torch.as_tensor(background, dtype=color.dtype, device=color.device)
        if bg.shape not in ((3,), tuple(color.shape)):
            raise ValueError(f"background: expected shape (3,) or {tuple(color.shape)}, got {tuple(bg.shape)}")
        color = color + (1.0 - acc).unsqueeze(-1) * bg
    num = (weights * t).sum(dim=1)
    dist = torch.where(acc >= EMPTY_ACC, num / acc.clamp(min=EMPTY_ACC), t_far.to(num))
    return {"rgb": color, "acc": acc, "ray_dist": dist, "weights": weights, "t": t}


def bin_distortion(weights: torch.Tensor) -> torch.Tensor:
    """mip-NeRF 360's distortion loss for ``S`` bins of equal length ``1/S`` (the contracted bins of
    :func:`~senerf.fields.contracted_bins` in their own coordinate), averaged over rays:
    ``(sum_ij w_i w_j |i - j| + sum_i w_i^2 / 3) / S``.  It is small when each ray's weight gathers in few
    neighbouring bins, so it removes the thin haze ("floaters") a field can put anywhere along a ray.

    Args:
        weights: ``(R, S)`` volume-rendering weights.
    Returns:
        a scalar.

    Example:
        >>> float(bin_distortion(torch.tensor([[0.5, 0.0, 0.5]])))   # (2 * 0.25 * 2 + 0.5 / 3) / 3
        0.388888...
    """
    s = weights.shape[-1]
    k = torch.arange(s, dtype=weights.dtype, device=weights.device)
    before = torch.cumsum(weights, dim=-1) - weights                  # sum_{j<i} w_j
    before_k = torch.cumsum(weights * k, dim=-1) - weights * k        # sum_{j<i} j w_j
    pairs = 2.0 * (weights * (k * before - before_k)).sum(dim=-1)    # sum_{i != j} w_i w_j |i - j|
    return ((pairs + weights.square().sum(dim=-1) / 3.0) / s).mean()


def contraction_box(field) -> torch.Tensor | None:
    """``field.aabb`` when ``field`` contracts space (the inner box of its samples' spacing), else None."""
    return field.aabb if getattr(field, "contract", False) else None


def render_rays(field, rays_o: torch.Tensor, rays_d: torch.Tensor, near: torch.Tensor, far: torch.Tensor,
                n_samples: int, generator: torch.Generator | None = None, background=None,
                occupancy=None, randomized: bool = True) -> dict:
    """Stratified ray marching through ``field`` and :func:`volume_render`.

    The bins are even in distance, or, for a field that contracts space (``field.contract``), even along the
    ray's path in contracted space (:func:`~senerf.fields.contracted_bins` around ``field.aabb``).  With
    ``occupancy`` (an :class:`~senerf.fields.OccupancyGrid`), samples in empty cells are dropped
    before the field is evaluated (their density and colour are 0).

    Args:
        rays_o: ``(R, 3)`` origins; rays_d: ``(R, 3)`` directions (unit for metric ``ray_dist``).
        near, far: ``(R,)``; the last interval ends at ``far``.  For the rays of :func:`~senerf.fields.ndc_rays`
            pass 0 and 1: ``ray_dist`` is then the NDC parameter (:func:`~senerf.fields.ndc_t_to_depth`).
        n_samples: stratified bins per ray.
        background: see :func:`volume_render`.
    Returns:
        dict of :func:`volume_render` plus ``sigma (R, S)`` (the densities used).
    """
    check_rays(rays_o, rays_d)
    r = rays_o.shape[0]
    if near.shape != (r,) or far.shape != (r,):
        raise ValueError(f"near/far: expected shape ({r},), got {tuple(near.shape)}, {tuple(far.shape)}")
    t = ray_bins(rays_o, rays_d, near, far, bin_fractions(near, n_samples, generator, randomized),
                 contraction_box(field))
    pts = (rays_o[:, None, :] + t[..., None] * rays_d[:, None, :]).reshape(-1, 3)
    dirs = rays_d[:, None, :].expand(r, n_samples, 3).reshape(-1, 3)
    if occupancy is None:
        sigma, rgb = field(pts, dirs)
    else:
        keep = occupancy.is_occupied(pts).nonzero().squeeze(1)
        s_k, c_k = field(pts[keep], dirs[keep])
        sigma = s_k.new_zeros(pts.shape[0]).index_copy(0, keep, s_k)
        rgb = c_k.new_zeros(pts.shape[0], 3).index_copy(0, keep, c_k)
    out = volume_render(sigma.view(r, n_samples), rgb.view(r, n_samples, 3), t, far, background)
    out["sigma"] = sigma.view(r, n_samples)
    return out


@torch.no_grad()
def render_image(field, origins, dirs, near, far, n_samples: int, background=None, occupancy=None,
                 chunk: int = 4096, generator: torch.Generator | None = None, randomized: bool = False,
                 device=None) -> dict:
    """Render a full image in chunks of rays under ``torch.no_grad`` (memory bounded by ``chunk``).

    Args:
        origins, dirs: ``(H, W, 3)`` arrays or tensors (numpy float64 is cast to float32).
        near, far: floats or ``(H, W)`` arrays.
        n_samples: bins per ray; ``randomized=False`` uses bin centres (deterministic).
        background: ``(3,)`` colour or ``None``.
        chunk: rays per field call.
    Returns:
        dict of numpy float32 ``rgb (H, W, 3)``, ``acc (H, W)``, ``ray_dist (H, W)``.
    """
    p = next(field.parameters(), None)
    dev = device if device is not None else (p.device if p is not None else "cpu")
    o, d, nr, fr = (torch.as_tensor(x if torch.is_tensor(x) else np.asarray(x), dtype=torch.float32, device=dev)
                    for x in (origins, dirs, near, far))
    if o.ndim != 3 or o.shape[-1] != 3 or d.shape != o.shape:
        raise ValueError(f"origins/dirs: expected equal shapes (H, W, 3), got {tuple(o.shape)}, {tuple(d.shape)}")
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk: expected an integer >= 1 (rays per field call), got {chunk!r}")
    h, w = o.shape[:2]
    n = h * w
    o, d, nr, fr = o.reshape(n, 3), d.reshape(n, 3), nr.expand(h, w).reshape(n), fr.expand(h, w).reshape(n)
    out = {"rgb": np.empty((n, 3), np.float32), "acc": np.empty(n, np.float32), "ray_dist": np.empty(n, np.float32)}
    for s in range(0, n, int(chunk)):
        e = min(n, s + int(chunk))
        part = render_rays(field, o[s:e], d[s:e], nr[s:e], fr[s:e], n_samples, generator, background,
                           occupancy, randomized)
        for key, arr in out.items():
            arr[s:e] = part[key].float().cpu().numpy()
    return {key: arr.reshape((h, w) + arr.shape[1:]) for key, arr in out.items()}
