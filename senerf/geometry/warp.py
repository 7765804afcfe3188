"""Warping a source depth map into other cameras, with occlusion and forward-backward tests.

Convention:
    Depths are camera-frame **z-depths**.  ``T_dst_src = inv(c2w_dst) @ c2w_src`` and ``K_dst T_dst_src`` are
    composed in float64, then applied in the dtype of ``z_depth_src``; world coordinates are never formed, so
    float32 depth maps of scenes far from the origin keep their precision.

Occlusion test (``z_depth_dst`` given):
    A warped point with destination depth ``z`` at ``uv`` is visible when
    ``z <= D_hi (1 + rel_tol) + abs_tol + slope_tol (D_hi - D_lo)``, where ``D_hi``/``D_lo`` are the max/min
    of the 2 x 2 destination pixels of the bilinear footprint of ``uv`` (pixel centres around ``uv``; at the
    image border the footprint is shifted inwards, so it always spans two columns/rows when the image does).
    Why the max: the depth of a plane is ``1 / (affine in u, v)``, a convex function, so the true depth at
    ``uv`` never exceeds the bilinear interpolant, which never exceeds the footprint max: correct warps stay
    valid at any grazing angle without a tolerance that also lets occluded points through.  At a depth
    discontinuity the footprint max is the far side, so points within about one pixel of an occluding edge
    count as visible (bilinear blending would instead invent a depth in between and reject both sides).
    ``slope_tol (D_hi - D_lo)`` covers the half-pixel extrapolation at the image border and noisy (rendered)
    depth.  Non-finite or ``<= 0`` destination depths mean "no surface" (background) and occlude nothing.

Forward-backward test (``forward_backward=True``, needs ``z_depth_dst``):
    The destination depth is sampled bilinearly at ``uv`` (the same footprint; "no surface" in the footprint
    fails the test), lifted, and projected back into the source; the pixel must land within ``fb_px_tol``
    pixels of where it started and its source depth within ``fb_rel_tol`` (relative).  Bilinear sampling
    blends across depth edges, so this test rejects pixels next to discontinuities (conservative).
"""

from __future__ import annotations

import numpy as np

from ._util import as_4x4, as_float, check_intrinsics
from .intrinsics import Intrinsics
from .poses import POSE_ATOL, invert_rigid, validate_rigid
from .projection import placeholders
from .rays import pixel_centers

__all__ = ["reproject"]


def _footprint(u: np.ndarray, v: np.ndarray, width: int, height: int):
    """Flat indices of the 4 footprint pixels and the bilinear weights along u and v (inward at borders)."""
    fu = np.floor(u - 0.5)
    fv = np.floor(v - 0.5)
    i0 = np.clip(fu, 0, max(width - 2, 0)).astype(np.intp)
    j0 = np.clip(fv, 0, max(height - 2, 0)).astype(np.intp)
    di = 1 if width > 1 else 0
    dj = width if height > 1 else 0
    base = j0 * width + i0
    wu = (u - 0.5 - i0) if width > 1 else np.zeros_like(u)
    wv = (v - 0.5 - j0) if height > 1 else np.zeros_like(v)
    return (base, base + di, base + dj, base + di + dj), wu, wv


def reproject(z_depth_src, intrinsics_src: Intrinsics, c2w_src, intrinsics_dst: Intrinsics, c2w_dst,
              z_depth_dst=None, rel_tol: float = 0.01, abs_tol: float = 0.0, slope_tol: float = 0.5,
              forward_backward: bool = False, fb_px_tol: float = 1.0, fb_rel_tol: float = 0.01, near: float = 1e-8,
              return_z: bool = False):
    """Warp every pixel of a source z-depth map into one or several destination cameras.

    Args:
        z_depth_src: ``(H, W)`` source z-depth; non-positive or non-finite pixels are invalid.
        intrinsics_src: source :class:`Intrinsics` (size ``H x W``).
        c2w_src: ``(4, 4)`` (or ``(3, 4)``) source camera-to-world (OpenCV).
        intrinsics_dst: destination :class:`Intrinsics` (size ``H' x W'``), shared by all destinations.
        c2w_dst: ``(..., 4, 4)`` (or ``(..., 3, 4)``) destination camera-to-world poses.
        z_depth_dst: optional ``(..., H', W')`` destination z-depths (batch of ``c2w_dst``) for the occlusion test.
        rel_tol, abs_tol, slope_tol: occlusion-test tolerances (module docstring).
        forward_backward: also require the forward-backward check (needs ``z_depth_dst``).
        fb_px_tol, fb_rel_tol: forward-backward pixel and relative depth tolerances.
        near: destination z must exceed ``near``.
        return_z: also return the destination z-depth of each warped pixel.

    Returns:
        ``uv_dst (..., H, W, 2)`` in the destination pixel-centre system and ``valid (..., H, W)``
        (inside ``[0, W') x [0, H')``, in front of the camera, source depth usable, tests passed);
        with ``return_z``, also ``z_dst (..., H, W)``.  Invalid entries hold ``uv = -1`` and ``z = 0``.
        Dtype of ``z_depth_src``.

    Example:
        >>> k = Intrinsics(100.0, 100.0, 2.0, 2.0, 4, 4)
        >>> uv, ok = reproject(np.full((4, 4), 2.0), k, np.eye(4), k, np.eye(4))
        >>> uv[0, 0].tolist(), bool(ok.all())
        ([0.5, 0.5], True)
    """
    check_intrinsics(intrinsics_src, "intrinsics_src")
    check_intrinsics(intrinsics_dst, "intrinsics_dst")
    for name, tol in (("rel_tol", rel_tol), ("abs_tol", abs_tol), ("slope_tol", slope_tol),
                      ("fb_px_tol", fb_px_tol), ("fb_rel_tol", fb_rel_tol)):
        if not (np.isfinite(tol) and tol >= 0):
            raise ValueError(f"{name}: must be finite and >= 0, got {tol!r}")
    zs = as_float(z_depth_src, "z_depth_src")
    dt = zs.dtype
    if zs.shape != intrinsics_src.size:
        raise ValueError(f"z_depth_src: expected shape {intrinsics_src.size} (H, W), got {zs.shape}")
    src = as_4x4(validate_rigid(c2w_src, atol=POSE_ATOL, name="c2w_src").astype(np.float64))
    if src.ndim != 2:
        raise ValueError(f"c2w_src: expected a single pose (4, 4), got {src.shape}")
    dst = as_4x4(validate_rigid(c2w_dst, atol=POSE_ATOL, name="c2w_dst").astype(np.float64))
    batch = dst.shape[:-2]
    dst = dst.reshape((-1,) + dst.shape[-2:])
    hd, wd = intrinsics_dst.size
    depth_dst = None
    if z_depth_dst is not None:
        depth_dst = as_float(z_depth_dst, "z_depth_dst")
        if depth_dst.shape != batch + (hd, wd):
            raise ValueError(f"z_depth_dst: expected shape {batch + (hd, wd)}, got {depth_dst.shape}")
        with np.errstate(invalid="ignore"):
            no_surface = ~(depth_dst > 0) | ~np.isfinite(depth_dst)
        depth_dst = np.where(no_surface, np.inf, depth_dst).astype(dt).reshape(dst.shape[0], hd * wd)
    elif forward_backward:
        raise ValueError("reproject: forward_backward=True needs z_depth_dst")

    h, w = intrinsics_src.size
    ks = intrinsics_src
    uv_src = pixel_centers(ks).reshape(h * w, 2)
    # source camera rays with unit z: X_src = z * ray
    ray = np.stack([(uv_src[:, 0] - ks.cx) / ks.fx, (uv_src[:, 1] - ks.cy) / ks.fy, np.ones(h * w)])
    z_flat = zs.reshape(-1)
    with np.errstate(invalid="ignore"):
        src_ok = (z_flat > 0) & (z_flat < np.inf)
    z_safe = np.where(src_ok, z_flat, dt.type(1.0))

    n_view = dst.shape[0]
    uv_out = np.empty((n_view, h * w, 2), dtype=dt)
    valid_out = np.empty((n_view, h * w), dtype=bool)
    z_out = np.empty((n_view, h * w), dtype=dt)
    for k in range(n_view):
        t_dst_src = invert_rigid(dst[k]) @ src
        mat = intrinsics_dst.K @ t_dst_src[:3]  # (3, 4) float64
        a = (mat[:, :3] @ ray).astype(dt)  # (3, N): homogeneous image point per unit z
        hom = a * z_safe
        hom += mat[:, 3:].astype(dt)
        zd = hom[2]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            u = hom[0] / zd
            v = hom[1] / zd
            valid = src_ok & (zd > near)
            valid &= (u >= 0.0) & (u < wd) & (v >= 0.0) & (v < hd)
        if depth_dst is not None:
            u_c = np.where(valid, u, dt.type(0.5))
            v_c = np.where(valid, v, dt.type(0.5))
            idx, wu, wv = _footprint(u_c, v_c, wd, hd)
            d00, d10, d01, d11 = (depth_dst[k].take(ix) for ix in idx)
            d_hi = np.maximum(np.maximum(d00, d10), np.maximum(d01, d11))
            d_lo = np.minimum(np.minimum(d00, d10), np.minimum(d01, d11))
            with np.errstate(invalid="ignore", over="ignore"):
                bound = d_hi * dt.type(1.0 + rel_tol) + dt.type(abs_tol) + dt.type(slope_tol) * (d_hi - d_lo)
                valid &= ~(zd > bound)  # a NaN bound (inf - inf) means no surface: visible
            if forward_backward:
                valid &= _fb_ok(u_c, v_c, (d00, d10, d01, d11), wu, wv, intrinsics_dst, invert_rigid(t_dst_src),
                                ks, z_safe, uv_src, fb_px_tol, fb_rel_tol, dt)
        uv_out[k], z_out[k] = placeholders(u, v, zd, valid)
        valid_out[k] = valid
    out = uv_out.reshape(batch + (h, w, 2)), valid_out.reshape(batch + (h, w)), z_out.reshape(batch + (h, w))
    return out if return_z else out[:2]


def _fb_ok(u, v, corners, wu, wv, k_dst, t_src_dst, k_src, z_src, uv_src, px_tol, rel_tol, dt):
    """Forward-backward consistency of warped pixels (flat arrays ``(N,)``; ``uv_src (N, 2)`` their starts)."""
    d00, d10, d01, d11 = corners
    with np.errstate(invalid="ignore", over="ignore"):
        d = (d00 * (1 - wu) + d10 * wu) * (1 - wv) + (d01 * (1 - wu) + d11 * wu) * wv
        has = np.isfinite(d) & (d > 0)
        d = np.where(has, d, dt.type(1.0))
        cam = np.stack([(u - k_dst.cx) / k_dst.fx * d, (v - k_dst.cy) / k_dst.fy * d, d])
        mat = (k_src.K @ t_src_dst[:3]).astype(dt)
        hom = mat[:, :3] @ cam + mat[:, 3:]
        ub = hom[0] / hom[2]
        vb = hom[1] / hom[2]
    u0, v0 = uv_src.astype(dt).T
    with np.errstate(invalid="ignore"):
        ok = has & (hom[2] > 0)
        ok &= (ub - u0) ** 2 + (vb - v0) ** 2 <= px_tol * px_tol
        ok &= np.abs(hom[2] - z_src) <= rel_tol * z_src
    return ok
