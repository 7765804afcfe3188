"""Camera rays through pixels.

Convention:
    The camera-frame direction through image point ``(u, v)`` is ``d = ((u - cx) / fx, (v - cy) / fy, 1)``;
    ``dirs`` are unit world vectors and ``z_per_dist = 1 / |d|`` is the camera-frame z gained per unit of
    distance along the ray: ``z_depth = ray_dist * z_per_dist``.  Computed in float64.
"""

from __future__ import annotations

import numpy as np

from ._util import as_float, broadcast_batch, check_intrinsics, check_last, unit_and_norm
from .intrinsics import Intrinsics
from .poses import POSE_ATOL, validate_rigid

__all__ = ["pixel_rays", "rays_from_pixels", "pixel_centers"]


def pixel_centers(intrinsics: Intrinsics, dtype=np.float64) -> np.ndarray:
    """``(H, W, 2)`` image coordinates ``(i + 0.5, j + 0.5)`` of every pixel centre (u = column, v = row).

    Example:
        >>> pixel_centers(Intrinsics(1.0, 1.0, 1.0, 0.5, 2, 1)).tolist()
        [[[0.5, 0.5], [1.5, 0.5]]]
    """
    check_intrinsics(intrinsics)
    h, w = intrinsics.size
    out = np.empty((h, w, 2), dtype=dtype)
    out[..., 0] = np.arange(w) + 0.5
    out[..., 1] = (np.arange(h) + 0.5)[:, None]
    return out


def _world_rays(uv: np.ndarray, k: Intrinsics, pose: np.ndarray, dtype):
    """Rays through float64 ``uv (..., 2)`` of cameras ``pose (..., 4, 4)`` (float64, batch broadcast with
    ``uv``'s): ``origins (..., 3)``, unit ``dirs (..., 3)``, ``z_per_dist (...)``, in ``dtype``."""
    d = np.empty(uv.shape[:-1] + (3,))
    d[..., 0] = (uv[..., 0] - k.cx) / k.fx
    d[..., 1] = (uv[..., 1] - k.cy) / k.fy
    d[..., 2] = 1.0
    dirs_cam, norm = unit_and_norm(d)   # scaled: unit even where |d|^2 overflows (a focal length of 1e-160)
    dirs = np.einsum("...ij,...j->...i", pose[..., :3, :3], dirs_cam)
    origins = np.broadcast_to(pose[..., :3, 3], dirs.shape)
    zpd = np.broadcast_to(1.0 / norm, dirs.shape[:-1])
    return origins.astype(dtype), dirs.astype(dtype), zpd.astype(dtype)


def rays_from_pixels(uv, intrinsics: Intrinsics, c2w):
    """World rays through arbitrary image points.

    Args:
        uv: ``(..., 2)`` image coordinates (pixel centres at ``i + 0.5``), finite.
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)`` OpenCV camera-to-world, batch broadcast against ``uv``'s.

    Returns:
        ``origins (..., 3)`` (camera centres), ``dirs (..., 3)`` unit world directions,
        ``z_per_dist (...)``; dtype of ``uv``.

    Raises:
        ValueError: a non-finite ``uv``, or batches of ``uv`` and ``c2w`` that do not broadcast (named).

    Example:
        >>> k = Intrinsics(500.0, 500.0, 256.0, 256.0, 512, 512)
        >>> o, d, zpd = rays_from_pixels([256.0, 256.0], k, np.eye(4))
        >>> d.tolist(), float(zpd)
        ([0.0, 0.0, 1.0], 1.0)
    """
    check_intrinsics(intrinsics)
    uv_a = as_float(uv, "uv")
    check_last(uv_a, (2,), "uv")
    if not np.isfinite(uv_a).all():
        raise ValueError("uv: image points must be finite")
    pose = validate_rigid(c2w, atol=POSE_ATOL).astype(np.float64)
    broadcast_batch(("uv", uv_a.shape[:-1]), ("c2w", pose.shape[:-2]))
    return _world_rays(uv_a.astype(np.float64), intrinsics, pose, uv_a.dtype)


def pixel_rays(intrinsics: Intrinsics, c2w):
    """World rays through every pixel centre.

    Args:
        intrinsics: :class:`Intrinsics` of an ``H x W`` image.
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)`` OpenCV camera-to-world.

    Returns:
        ``origins (..., H, W, 3)``, ``dirs (..., H, W, 3)`` unit, ``z_per_dist (..., H, W)``; dtype of ``c2w``.

    Example:
        >>> o, d, zpd = pixel_rays(Intrinsics(2.0, 2.0, 1.0, 1.0, 2, 2), np.eye(4))
        >>> d.shape, zpd.shape
        ((2, 2, 3), (2, 2))
        >>> bool(np.allclose(np.linalg.norm(d, axis=-1), 1.0))
        True
    """
    uv = pixel_centers(intrinsics)   # checks the intrinsics
    pose = validate_rigid(c2w, atol=POSE_ATOL)
    p64 = pose.astype(np.float64)[..., None, None, :, :]   # (..., 1, 1, 4, 4) against (H, W) pixels
    return _world_rays(uv, intrinsics, p64, pose.dtype)
