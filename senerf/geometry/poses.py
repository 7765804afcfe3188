"""Rigid camera poses: convention changes, validation, inversion, look-at.

Convention:
    Poses are camera-to-world ``c2w`` matrices ``(..., 4, 4)`` (or ``(..., 3, 4)`` where stated) in the
    **OpenCV** camera convention: camera x right, y down, z forward.  ``c2w[..., :3, :3]`` holds the camera
    axes as columns in world coordinates, ``c2w[..., :3, 3]`` the camera centre.  World-to-camera is
    ``w2c = invert_rigid(c2w)``.  Output dtype follows ``c2w`` (float32 stays float32, else float64).
"""

from __future__ import annotations

import numpy as np

from ._util import as_float, check_last, check_pose, pow2_scale, unit_and_norm

__all__ = [
    "opengl_to_opencv",
    "opencv_to_opengl",
    "is_rigid",
    "validate_rigid",
    "orthonormalize",
    "invert_rigid",
    "look_at",
]

_FLIP = np.array([1.0, -1.0, -1.0, 1.0])


def _flip_yz(c2w) -> np.ndarray:
    arr = check_pose(c2w)
    return arr * _FLIP.astype(arr.dtype)  # right-multiplying by diag(1,-1,-1,1) scales columns


def opengl_to_opencv(c2w) -> np.ndarray:
    """OpenGL/Blender camera (x right, y up, looking along -z) to OpenCV (x right, y down, z forward).

    ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``: the camera frame changes, the centre does not.

    Args:
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)`` camera-to-world, OpenGL camera convention.

    Returns:
        Same shape, OpenCV camera convention (a new array).

    Example:
        >>> c2w = opengl_to_opencv(np.eye(4))
        >>> np.diag(c2w).tolist()
        [1.0, -1.0, -1.0, 1.0]
    """
    return _flip_yz(c2w)


def opencv_to_opengl(c2w) -> np.ndarray:
    """Inverse of :func:`opengl_to_opencv` (the same right-multiplication by ``diag(1, -1, -1, 1)``)."""
    return _flip_yz(c2w)


def _rigid_problems(c2w: np.ndarray, atol: float):
    """Boolean masks ``(...)``: non-finite, non-orthonormal, det < 0, bad last row."""
    c2w64 = c2w.astype(np.float64, copy=False)
    finite = np.isfinite(c2w64).all(axis=(-2, -1))
    safe = np.where(finite[..., None, None], c2w64, 0.0)
    rot = safe[..., :3, :3]
    gram = np.swapaxes(rot, -1, -2) @ rot
    non_ortho = np.abs(gram - np.eye(3)).max(axis=(-2, -1)) > atol
    neg_det = np.linalg.det(rot) < 0.0
    if c2w.shape[-2] == 4:
        bad_row = np.abs(safe[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1) > atol
    else:
        bad_row = np.zeros(c2w.shape[:-2], dtype=bool)
    nf = ~finite
    return nf, non_ortho & finite, neg_det & finite, bad_row & finite


def is_rigid(c2w, atol: float = 1e-4) -> np.ndarray:
    """Whether each pose is a finite rigid transform: ``|R^T R - I| <= atol``, ``det R > 0``, last row ``0 0 0 1``.

    Args:
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)``.
        atol: tolerance on the entries of ``R^T R - I`` and of the last row.

    Returns:
        Bool array ``(...)``.

    Example:
        >>> bool(is_rigid(np.eye(4))), bool(is_rigid(np.diag([1.0, 1.0, -1.0, 1.0])))
        (True, False)
    """
    arr = check_pose(c2w)
    nf, no, nd, br = _rigid_problems(arr, float(atol))
    return ~(nf | no | nd | br)


#: Tolerance of the rigidity check made by every public function that uses a pose's rotation as one
#: (projection, rays, reprojection, pseudo-view sampling): loose enough for float32 and exported poses,
#: tight enough to refuse a scaled matrix or a reflection, which would otherwise give wrong numbers silently.
POSE_ATOL = 1e-3


def validate_rigid(c2w, atol: float = 1e-4, name: str = "c2w") -> np.ndarray:
    """Return ``c2w`` (as a float array) if every pose is rigid, else raise ``ValueError`` saying what is wrong.

    The message names ``name``, the first bad index and the problem: ``non-finite entries``,
    ``rotation not orthonormal (max |R^T R - I| = ...)``, ``det(R) < 0 (a reflection)`` or
    ``last row is not [0, 0, 0, 1]``.  Slightly-off rotations can be repaired with :func:`orthonormalize`.
    """
    arr = check_pose(c2w, name)
    nf, no, nd, br = _rigid_problems(arr, float(atol))
    for mask, what in (
        (nf, "non-finite entries"),
        (no, "rotation not orthonormal"),
        (nd, "det(R) < 0 (a reflection, e.g. a mixed-up camera convention)"),
        (br, "last row is not [0, 0, 0, 1]"),
    ):
        if mask.any():
            idx = tuple(int(i) for i in np.argwhere(mask)[0])
            where = f"{name}[{', '.join(map(str, idx))}]" if idx else name
            detail = ""
            if mask is no:
                rot = arr[idx][:3, :3].astype(np.float64)
                detail = f" (max |R^T R - I| = {np.abs(rot.T @ rot - np.eye(3)).max():.3g} > atol {atol:g})"
            raise ValueError(f"{where}: {what}{detail}")
    return arr


def orthonormalize(c2w) -> np.ndarray:
    """Replace each rotation by the nearest proper rotation (SVD, ``U diag(1, 1, det(U V^T)) V^T``).

    Args:
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)`` finite poses with slightly-off rotations.

    Returns:
        ``(..., 4, 4)`` with the same translation and last row ``0 0 0 1``, dtype of ``c2w``.

    Raises:
        ValueError: non-finite entries, or a rotation block of rank < 2.

    Example:
        >>> c2w = np.eye(4); c2w[0, 1] = 1e-3
        >>> bool(is_rigid(orthonormalize(c2w), atol=1e-12))
        True
    """
    arr = check_pose(c2w)
    a64 = arr.astype(np.float64)
    if not np.isfinite(a64).all():
        raise ValueError("c2w: non-finite entries, cannot orthonormalize")
    u, s, vt = np.linalg.svd(a64[..., :3, :3])
    if (s[..., 1] <= 1e-12 * np.maximum(s[..., 0], 1e-300)).any():
        raise ValueError("c2w: rotation block has rank < 2, cannot orthonormalize")
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    u = u.copy()
    u[..., :, 2] *= d[..., None]
    out = np.zeros(arr.shape[:-2] + (4, 4))
    out[..., :3, :3] = u @ vt
    out[..., :3, 3] = a64[..., :3, 3]
    out[..., 3, 3] = 1.0
    return out.astype(arr.dtype, copy=False)


def invert_rigid(c2w) -> np.ndarray:
    """Inverse of a rigid transform: ``[R | t]^-1 = [R^T | -R^T t]`` (no check that ``R`` is a rotation).

    Args:
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)`` (camera-to-world, or any rigid ``T_dst_src``).

    Returns:
        ``(..., 4, 4)`` inverse (world-to-camera for a ``c2w``), dtype of ``c2w``.

    Example:
        >>> c2w = look_at([0.0, -4.0, 1.0], [0.0, 0.0, 0.0])
        >>> np.allclose(invert_rigid(c2w) @ c2w, np.eye(4))
        True
    """
    arr = check_pose(c2w)
    rot_t = np.swapaxes(arr[..., :3, :3], -1, -2)
    out = np.zeros(arr.shape[:-2] + (4, 4), dtype=arr.dtype)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -(rot_t @ arr[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera at ``eye`` looking at ``target``: z toward the target, y down, image up toward ``up``.

    ``z = normalize(target - eye)``, ``x = normalize(z x up)``, ``y = z x x``, computed in float64 and
    re-orthogonalised, so the rotation is proper (det +1) and orthonormal to ~1e-15 everywhere.

    Convention at the pole (``up`` parallel to the view direction, where "image up toward ``up``" is
    undefined): when ``|z x up_unit| < 1e-12`` the world axis least parallel to ``z`` replaces ``up``.
    Up to 1e-12 off the pole axis the usual formula is kept (after re-orthogonalisation it is still an
    exact rotation), so poses are continuous everywhere except exactly at the pole.

    Args:
        eye: ``(..., 3)`` camera centres, world frame.
        target: ``(..., 3)`` points looked at, world frame (broadcast against ``eye``).
        up: ``(..., 3)`` world "up" direction (any non-zero length), broadcast.

    Returns:
        ``(..., 4, 4)`` camera-to-world, dtype of ``eye`` (float32 stays float32).

    Raises:
        ValueError: ``eye == target``, zero ``up``, non-finite input, or bad shapes.

    Example:
        >>> c2w = look_at([0.0, -4.0, 0.0], [0.0, 0.0, 0.0], up=[0.0, 0.0, 1.0])
        >>> c2w[:3, :3].round(12).tolist()   # x = +x, y = -z (down), z = +y (toward the origin)
        [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
    """
    eye_a = as_float(eye, "eye")
    dtype = eye_a.dtype
    e = eye_a.astype(np.float64)
    t = as_float(target, "target", np.float64)
    u = as_float(up, "up", np.float64)
    for arr, nm in ((e, "eye"), (t, "target"), (u, "up")):
        check_last(arr, (3,), nm)
        if not np.isfinite(arr).all():
            raise ValueError(f"look_at: {nm} has non-finite entries")
    e, t, u = np.broadcast_arrays(e, t, u)
    scale = pow2_scale(e, t)  # exact: t - e neither overflows nor loses bits
    z, dist = unit_and_norm(t / scale - e / scale)
    if (dist <= 0.0).any():
        raise ValueError("look_at: eye == target, the view direction is undefined")
    u, un = unit_and_norm(u)
    if (un <= 0.0).any():
        raise ValueError("look_at: up is the zero vector")
    x_raw = np.cross(z, u)
    sin = np.linalg.norm(x_raw, axis=-1)
    pole = sin < 1e-12
    if pole.any():
        # Fallback: the world axis least parallel to z (smallest |z_i|).
        axis = np.eye(3)[np.argmin(np.abs(z), axis=-1)]
        x_raw = np.where(pole[..., None], np.cross(z, axis), x_raw)
    x, _ = unit_and_norm(x_raw)
    x, _ = unit_and_norm(x - np.sum(x * z, axis=-1, keepdims=True) * z)  # exact orthogonality to z
    y = np.cross(z, x)
    out = np.zeros(e.shape[:-1] + (4, 4))
    out[..., :3, 0] = x
    out[..., :3, 1] = y
    out[..., :3, 2] = z
    out[..., :3, 3] = e
    out[..., 3, 3] = 1.0
    return out.astype(dtype, copy=False)
