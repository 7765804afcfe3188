"""Projecting world points into a pinhole camera, and lifting pixels with depth back to the world.

Convention:
    ``w2c`` and ``K w2c`` are composed and applied in float64 whatever the points' dtype (``K [R|t]`` in
    float32 cancels catastrophically far from the origin); the results come back in the points' dtype.
"""

from __future__ import annotations

import cv2
import numpy as np

from ._util import as_float, broadcast_batch, check_intrinsics, check_last
from .intrinsics import Intrinsics
from .poses import POSE_ATOL, invert_rigid, validate_rigid

__all__ = ["project", "unproject", "projection_matrix", "INVALID_UV", "INVALID_Z"]

#: Placeholder written into ``uv`` of invalid projections (finite, outside every image).
INVALID_UV = -1.0
#: Placeholder written into ``z_depth`` of invalid projections.
INVALID_Z = 0.0


def projection_matrix(intrinsics: Intrinsics, c2w) -> np.ndarray:
    """``K @ inv(c2w)[:3]``, the ``(..., 3, 4)`` float64 world-to-image matrix.

    Example:
        >>> projection_matrix(Intrinsics(500.0, 500.0, 256.0, 256.0, 512, 512), np.eye(4)).tolist()[0]
        [500.0, 0.0, 256.0, 0.0]
    """
    check_intrinsics(intrinsics)
    pose = validate_rigid(c2w, atol=POSE_ATOL).astype(np.float64)
    return intrinsics.K @ invert_rigid(pose)[..., :3, :]


def project(points_world, intrinsics: Intrinsics, c2w, near: float = 1e-8):
    """Project world points to pixels.

    Args:
        points_world: ``(..., 3)`` world points.
        c2w: ``(4, 4)``/``(3, 4)`` camera-to-world, or ``(..., 4, 4)`` whose batch broadcasts (NumPy rules)
            against ``points_world``'s batch.
        near: points need ``z_depth > near`` to be valid.

    Returns:
        ``uv (..., 2)``, ``z_depth (..., )``, ``valid (...)`` bool; dtype of ``points_world``.
        ``valid`` is false for points behind the camera or at ``z <= near``, outside ``[0, W) x [0, H)``,
        and for non-finite input; invalid entries hold :data:`INVALID_UV` and :data:`INVALID_Z` (no NaN or inf).

    Example:
        >>> k = Intrinsics(500.0, 500.0, 256.0, 256.0, 1024, 1024)
        >>> uv, z, ok = project(np.array([[0, 0, 1], [1, 2, 2], [0.1, 0.1, -1]], float), k, np.eye(4))
        >>> uv.tolist(), z.tolist(), ok.tolist()
        ([[256.0, 256.0], [506.0, 756.0], [-1.0, -1.0]], [1.0, 2.0, 0.0], [True, True, False])
    """
    pts = as_float(points_world, "points_world")
    check_last(pts, (3,), "points_world")
    mat = projection_matrix(intrinsics, c2w)
    broadcast_batch(("points_world", pts.shape[:-1]), ("c2w", mat.shape[:-2]))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # non-finite points: invalid, not warned
        if mat.ndim == 2:
            uv, z, valid = _project_flat(pts.reshape(-1, 3), mat, intrinsics, near)
            return uv.reshape(pts.shape[:-1] + (2,)), z.reshape(pts.shape[:-1]), valid.reshape(pts.shape[:-1])
        uvw = np.matmul(mat[..., :3], pts.astype(np.float64)[..., None])[..., 0]
        uvw += mat[..., 3]
        # the quotients are rounded to the points' dtype before the bounds are tested (NaN compares false)
        u = np.divide(uvw[..., 0], uvw[..., 2]).astype(pts.dtype, copy=False)
        v = np.divide(uvw[..., 1], uvw[..., 2]).astype(pts.dtype, copy=False)
        z = uvw[..., 2].astype(pts.dtype, copy=False)
        valid = (z > near) & (z < np.inf) & (u >= 0.0) & (u < intrinsics.width)
        valid &= (v >= 0.0) & (v < intrinsics.height)
    return (*placeholders(u, v, z, valid), valid)


def _project_flat(pts: np.ndarray, mat: np.ndarray, intrinsics: Intrinsics, near: float):
    """Single-camera fast path for ``pts (N, 3)``: the arithmetic of :func:`project`, in chunks of 16 k points
    with preallocated buffers that stay in cache; ``cv2.transform`` applies the float64 ``3 x 4`` matrix
    (float32 points are widened chunk by chunk first).  Runs under :func:`project`'s ``np.errstate``."""
    n, dt = pts.shape[0], pts.dtype
    pts = np.ascontiguousarray(pts)
    uv = np.empty((n, 2), dtype=dt)
    z_out = np.empty(n, dtype=dt)
    valid = np.empty(n, dtype=bool)
    width, height = dt.type(intrinsics.width), dt.type(intrinsics.height)
    c = min(1 << 14, max(n, 1))
    hom_buf = np.empty((c, 1, 3))
    wide_buf = None if dt == np.float64 else np.empty((c, 1, 3))
    u_buf, v_buf = np.empty(c, dtype=dt), np.empty(c, dtype=dt)
    tmp_buf = np.empty(c, dtype=bool)
    for start in range(0, n, c):
        stop = min(start + c, n)
        m = stop - start
        u, v, tmp, ok, z = u_buf[:m], v_buf[:m], tmp_buf[:m], valid[start:stop], z_out[start:stop]
        src = pts[start:stop].reshape(m, 1, 3)
        if wide_buf is not None:
            np.copyto(wide_buf[:m], src)
            src = wide_buf[:m]
        hom = cv2.transform(src, mat, dst=hom_buf[:m]).reshape(m, 3)
        np.copyto(z, hom[:, 2], casting="same_kind")
        np.divide(hom[:, 0], hom[:, 2], out=u, casting="same_kind")
        np.divide(hom[:, 1], hom[:, 2], out=v, casting="same_kind")
        np.greater(z, near, out=ok)
        for arr, op, bound in ((z, np.less, np.inf), (u, np.greater_equal, 0.0), (u, np.less, width),
                               (v, np.greater_equal, 0.0), (v, np.less, height)):
            op(arr, bound, out=tmp)  # NaN compares false
            ok &= tmp
        np.logical_not(ok, out=tmp)
        bad = np.flatnonzero(tmp)  # usually few: cheaper than three masked copies
        u[bad] = INVALID_UV
        v[bad] = INVALID_UV
        z[bad] = INVALID_Z
        uv[start:stop, 0] = u
        uv[start:stop, 1] = v
    return uv, z_out, valid


def placeholders(u: np.ndarray, v: np.ndarray, z: np.ndarray, valid: np.ndarray):
    """``uv (..., 2)`` and ``z (...)`` of ``u, v, z (...)``, holding ``INVALID_UV`` and ``INVALID_Z`` where not
    ``valid``."""
    uv = np.where(valid[..., None], np.stack([u, v], axis=-1), u.dtype.type(INVALID_UV))
    return uv, np.where(valid, z, z.dtype.type(INVALID_Z))


def unproject(uv, z_depth, intrinsics: Intrinsics, c2w) -> np.ndarray:
    """World points at camera-frame depth ``z_depth`` behind image points ``uv``.

    ``X_cam = z ((u - cx) / fx, (v - cy) / fy, 1)``, ``X_world = R X_cam + t``.

    Args:
        uv: ``(..., 2)`` image points (pixel centres at ``i + 0.5``).
        z_depth: ``(...)`` camera-frame z, broadcast against ``uv[..., 0]``.
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)``, batch broadcast against ``uv``'s.

    Returns:
        ``(..., 3)`` world points, dtype of ``uv``; a non-finite ``uv`` or ``z_depth`` gives a non-finite point.

    Raises:
        ValueError: batches of ``uv``, ``z_depth`` and ``c2w`` that do not broadcast (named).

    Example:
        >>> k = Intrinsics(500.0, 500.0, 256.0, 256.0, 512, 512)
        >>> unproject([506.0, 756.0], 2.0, k, np.eye(4)).tolist()
        [1.0, 2.0, 2.0]
    """
    check_intrinsics(intrinsics)
    uv_a = as_float(uv, "uv")
    check_last(uv_a, (2,), "uv")
    dt = uv_a.dtype
    z = as_float(z_depth, "z_depth", dt)
    pose = validate_rigid(c2w, atol=POSE_ATOL).astype(np.float64).astype(dt)
    broadcast_batch(("uv", uv_a.shape[:-1]), ("z_depth", z.shape), ("c2w", pose.shape[:-2]))
    k = intrinsics
    z_b = np.broadcast_to(z, np.broadcast_shapes(z.shape, uv_a.shape[:-1]))
    cam = np.empty(z_b.shape + (3,), dtype=dt)
    cam[..., 0] = (uv_a[..., 0] - dt.type(k.cx)) * (z_b / dt.type(k.fx))
    cam[..., 1] = (uv_a[..., 1] - dt.type(k.cy)) * (z_b / dt.type(k.fy))
    cam[..., 2] = z_b
    return np.matmul(pose[..., :3, :3], cam[..., None])[..., 0] + pose[..., :3, 3]
