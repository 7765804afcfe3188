"""Camera rays through pixels.

Convention:
    Pixel ``(i, j)`` has its centre at ``(i + 0.5, j + 0.5)``; the camera-frame direction through image
    point ``(u, v)`` is ``((u - cx) / fx, (v - cy) / fy, 1)`` (OpenCV: x right, y down, z forward).
    ``dirs`` are unit vectors in the world frame and ``z_per_dist = 1 / |((u - cx)/fx, (v - cy)/fy, 1)|``
    is the camera-frame z gained per unit of distance along the ray: ``z_depth = ray_dist * z_per_dist``.
    Computed in float64, returned in the dtype of ``c2w`` (pixel_rays) or ``uv`` (rays_from_pixels).
"""

from __future__ import annotations

import numpy as np

from ._util import as_float, broadcast_batch, check_last, unit_and_norm
from .intrinsics import Intrinsics
from .poses import POSE_ATOL, validate_rigid

__all__ = ["pixel_rays", "rays_from_pixels", "pixel_centers"]


def pixel_centers(intrinsics: Intrinsics, dtype=np.float64) -> np.ndarray:
    """``(H, W, 2)`` image coordinates ``(i + 0.5, j + 0.5)`` of every pixel centre (u = column, v = row).

    Example:
        >>> pixel_centers(Intrinsics(1.0, 1.0, 1.0, 0.5, 2, 1)).tolist()
        [[[0.5, 0.5], [1.5, 0.5]]]
    """
    _check_intrinsics(intrinsics)
    h, w = intrinsics.size
    out = np.empty((h, w, 2), dtype=dtype)
    out[..., 0] = np.arange(w) + 0.5
    out[..., 1] = (np.arange(h) + 0.5)[:, None]
    return out


def _check_intrinsics(intrinsics) -> None:
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")


def _camera_dirs(uv: np.ndarray, k: Intrinsics):
    """Unit camera-frame directions ``(..., 3)`` and ``z_per_dist (...)`` for float64 ``uv (..., 2)``."""
    d = np.empty(uv.shape[:-1] + (3,))
    d[..., 0] = (uv[..., 0] - k.cx) / k.fx
    d[..., 1] = (uv[..., 1] - k.cy) / k.fy
    d[..., 2] = 1.0
    unit, norm = unit_and_norm(d)   # scaled: unit even where |d|^2 overflows (a focal length of 1e-160)
    return unit, 1.0 / norm


def rays_from_pixels(uv, intrinsics: Intrinsics, c2w):
    """World rays through arbitrary image points.

    Args:
        uv: ``(..., 2)`` image coordinates (pixel centres at ``i + 0.5``), finite.
        intrinsics: the camera's :class:`Intrinsics`.
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
    _check_intrinsics(intrinsics)
    uv_a = as_float(uv, "uv")
    check_last(uv_a, (2,), "uv")
    if not np.isfinite(uv_a).all():
        raise ValueError("uv: image points must be finite")
    pose = validate_rigid(c2w, atol=POSE_ATOL).astype(np.float64)
    broadcast_batch(("uv", uv_a.shape[:-1]), ("c2w", pose.shape[:-2]))
    dirs_cam, zpd = _camera_dirs(uv_a.astype(np.float64), intrinsics)
    dirs = np.einsum("...ij,...j->...i", pose[..., :3, :3], dirs_cam)
    origins = np.broadcast_to(pose[..., :3, 3], dirs.shape)
    zpd = np.broadcast_to(zpd, dirs.shape[:-1])
    dt = uv_a.dtype
    return origins.astype(dt), dirs.astype(dt), zpd.astype(dt)


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
    _check_intrinsics(intrinsics)
    pose = validate_rigid(c2w, atol=POSE_ATOL)
    dt = pose.dtype
    p64 = pose.astype(np.float64)
    dirs_cam, zpd = _camera_dirs(pixel_centers(intrinsics), intrinsics)  # (H, W, 3), (H, W)
    rot = p64[..., None, None, :3, :3]  # (..., 1, 1, 3, 3)
    dirs = np.einsum("...ij,...j->...i", rot, dirs_cam)
    batch = pose.shape[:-2]
    h, w = intrinsics.size
    origins = np.broadcast_to(p64[..., None, None, :3, 3], batch + (h, w, 3))
    zpd = np.broadcast_to(zpd, batch + (h, w))
    return origins.astype(dt), dirs.astype(dt), zpd.astype(dt)
