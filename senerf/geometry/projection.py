"""Projecting world points into a pinhole camera, and lifting pixels with depth back to the world.

Convention:
    OpenCV camera (x right, y down, z forward); ``uv`` in the pixel-centre-at-``i + 0.5`` system, so the
    image covers ``[0, W) x [0, H)``; ``z_depth`` is the camera-frame z (not the distance along the ray).
    ``w2c`` and ``K w2c`` are composed in float64 and applied in float64 whatever the points' dtype (a
    float32 point is exact in float64; applying ``K [R|t]`` in float32 cancels catastrophically far from
    the origin: 0.5 px of error for points 1e5 from it); the results come back in the points' dtype.
"""

from __future__ import annotations

import cv2
import numpy as np

from ._util import as_float, broadcast_batch, check_last
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
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
    pose = validate_rigid(c2w, atol=POSE_ATOL).astype(np.float64)
    return intrinsics.K @ invert_rigid(pose)[..., :3, :]


def project(points_world, intrinsics: Intrinsics, c2w, near: float = 1e-8):
    """Project world points to pixels.

    Args:
        points_world: ``(..., 3)`` world points.
        intrinsics: :class:`Intrinsics`.
        c2w: ``(4, 4)``/``(3, 4)`` camera-to-world, or ``(..., 4, 4)`` whose batch broadcasts (NumPy rules)
            against ``points_world``'s batch.
        near: points need ``z_depth > near`` to be valid.

    Returns:
        ``uv (..., 2)``, ``z_depth (..., )``, ``valid (...)`` bool; dtype of ``points_world``.
        ``valid`` is false for points behind the camera or at ``z <= near``, outside ``[0, W) x [0, H)``,
        and for non-finite input.  Invalid entries hold the finite placeholders ``uv = (-1, -1)``,
        ``z_depth = 0``: no NaN or inf is ever returned.

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
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite points are reported invalid, not warned
        return _project(pts, mat, intrinsics, near)


def _project(pts: np.ndarray, mat: np.ndarray, intrinsics: Intrinsics, near: float):
    if mat.ndim == 2:
        batch = pts.shape[:-1]
        uv, z, valid = _project_flat(pts.reshape(-1, 3), mat, intrinsics, near)
        return uv.reshape(batch + (2,)), z.reshape(batch), valid.reshape(batch)
    uvw = np.matmul(mat[..., :3], pts.astype(np.float64)[..., None])[..., 0]
    uvw += mat[..., 3]
    return _finish(uvw[..., 0], uvw[..., 1], uvw[..., 2], intrinsics, near, pts.dtype)


_CHUNK = 1 << 14


def _project_flat(pts: np.ndarray, mat: np.ndarray, intrinsics: Intrinsics, near: float):
    """Single-camera fast path for ``pts (N, 3)``.

    Works in chunks of 16 k points with preallocated scratch buffers, so the temporaries stay in cache and
    memory traffic is close to reading the input and writing the outputs once
    (``benchmarks/bench_geometry.py``).  ``cv2.transform`` applies the float64 ``3 x 4`` matrix to the
    interleaved points in one pass (float32 points are widened chunk by chunk first); the rest is the
    arithmetic of :func:`_finish`, each quotient rounded once to the points' dtype and the bounds tested on
    the rounded values (a float32 ``u`` just under ``W`` may round to ``W``).
    """
    n, dt = pts.shape[0], pts.dtype
    pts = np.ascontiguousarray(pts)
    uv = np.empty((n, 2), dtype=dt)
    z_out = np.empty(n, dtype=dt)
    valid = np.empty(n, dtype=bool)
    width, height = dt.type(intrinsics.width), dt.type(intrinsics.height)
    c = min(_CHUNK, max(n, 1))
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
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
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


def _finish(u_h: np.ndarray, v_h: np.ndarray, z_h: np.ndarray, intrinsics: Intrinsics, near: float, dtype):
    """Float64 homogeneous image coordinates ``(...)`` x 3 -> ``(uv (..., 2), z (...), valid (...))``.

    The quotients are rounded to ``dtype`` before the bounds are tested; invalid entries get placeholders.
    """
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        u = np.divide(u_h, z_h).astype(dtype, copy=False)
        v = np.divide(v_h, z_h).astype(dtype, copy=False)
        z = z_h.astype(dtype, copy=False)
        valid = z > near
        valid &= z < np.inf
        valid &= u >= 0.0  # NaN compares false
        valid &= u < intrinsics.width
        valid &= v >= 0.0
        valid &= v < intrinsics.height
    invalid = ~valid
    uv = np.empty(u.shape + (2,), dtype=u.dtype)
    uv[..., 0] = u
    uv[..., 1] = v
    np.copyto(uv[..., 0], INVALID_UV, where=invalid)
    np.copyto(uv[..., 1], INVALID_UV, where=invalid)
    z_out = np.where(valid, z, z.dtype.type(INVALID_Z))
    return uv, z_out, valid


def unproject(uv, z_depth, intrinsics: Intrinsics, c2w) -> np.ndarray:
    """World points at camera-frame depth ``z_depth`` behind image points ``uv``.

    ``X_cam = z ((u - cx) / fx, (v - cy) / fy, 1)``, ``X_world = R X_cam + t``.

    Args:
        uv: ``(..., 2)`` image points (pixel centres at ``i + 0.5``).
        z_depth: ``(...)`` camera-frame z, broadcast against ``uv[..., 0]``.
        intrinsics: :class:`Intrinsics`.
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)``, batch broadcast against ``uv``'s.

    Returns:
        ``(..., 3)`` world points, dtype of ``uv``; a non-finite ``uv`` or ``z_depth`` gives a non-finite point
        (propagated, as NumPy does, not checked: unlike :func:`project`, whose ``valid`` reports it).

    Raises:
        ValueError: batches of ``uv``, ``z_depth`` and ``c2w`` that do not broadcast (named).

    Example:
        >>> k = Intrinsics(500.0, 500.0, 256.0, 256.0, 512, 512)
        >>> unproject([506.0, 756.0], 2.0, k, np.eye(4)).tolist()
        [1.0, 2.0, 2.0]
    """
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
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
