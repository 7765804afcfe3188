"""Rigid camera poses: convention changes, validation, inversion, look-at.

Convention:
    ``c2w[..., :3, :3]`` holds the OpenCV camera axes (x right, y down, z forward) as columns in world
    coordinates, ``c2w[..., :3, 3]`` the camera centre; world-to-camera is ``w2c = invert_rigid(c2w)``.
"""

from __future__ import annotations

import numpy as np

from ._util import as_4x4, as_float, check_last, check_pose, pow2_scale, rigid_matrix, unit_and_norm

__all__ = ["opengl_to_opencv", "opencv_to_opengl", "is_rigid", "validate_rigid", "invert_rigid", "look_at"]

_FLIP = np.array([1.0, -1.0, -1.0, 1.0])


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
    arr = check_pose(c2w)
    return arr * _FLIP.astype(arr.dtype)  # right-multiplying by diag(1,-1,-1,1) scales columns


def opencv_to_opengl(c2w) -> np.ndarray:
    """Inverse of :func:`opengl_to_opencv` (the same right-multiplication by ``diag(1, -1, -1, 1)``)."""
    return opengl_to_opencv(c2w)


def _rigid_problems(c2w: np.ndarray, atol: float):
    """Boolean masks ``(...)``: non-finite, non-orthonormal, det < 0, bad last row."""
    c2w64 = c2w.astype(np.float64, copy=False)
    finite = np.isfinite(c2w64).all(axis=(-2, -1))
    safe = np.where(finite[..., None, None], c2w64, 0.0)
    rot = safe[..., :3, :3]
    gram = np.swapaxes(rot, -1, -2) @ rot
    non_ortho = np.abs(gram - np.eye(3)).max(axis=(-2, -1)) > atol
    neg_det = np.linalg.det(rot) < 0.0
    bad_row = np.abs(as_4x4(safe)[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1) > atol
    return ~finite, non_ortho & finite, neg_det & finite, bad_row & finite


def is_rigid(c2w, atol: float = 1e-4) -> np.ndarray:
    """Whether each pose is a finite rigid transform: ``|R^T R - I| <= atol``, ``det R > 0``, last row ``0 0 0 1``.

    Args:
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)``.

    Returns:
        Bool array ``(...)``.

    Example:
        >>> bool(is_rigid(np.eye(4))), bool(is_rigid(np.diag([1.0, 1.0, -1.0, 1.0])))
        (True, False)
    """
    arr = check_pose(c2w)
    nf, no, nd, br = _rigid_problems(arr, float(atol))
    return ~(nf | no | nd | br)


#: Tolerance of the rigidity check of every public function that uses a pose's rotation as one: loose enough
#: for float32 and exported poses, tight enough to refuse a scaled matrix or a reflection (silently wrong numbers).
POSE_ATOL = 1e-3


def validate_rigid(c2w, atol: float = 1e-4, name: str = "c2w") -> np.ndarray:
    """Return ``c2w`` (as a float array) if every pose is rigid, else raise ``ValueError`` naming ``name``, the
    first bad index and the problem."""
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


def pose_list(c2w, name: str, rigid: bool = True) -> np.ndarray:
    """``c2w`` as a float array ``(m, 4, 4)`` or ``(m, 3, 4)``, ``m >= 1``, every pose rigid to ``POSE_ATOL``
    unless ``rigid`` is false; raises ``ValueError`` naming ``name``."""
    arr = check_pose(c2w, name)
    if arr.ndim != 3 or arr.shape[0] < 1:
        raise ValueError(f"{name}: expected shape (m, 4, 4) or (m, 3, 4) with m >= 1, got {arr.shape}")
    return validate_rigid(arr, atol=POSE_ATOL, name=name) if rigid else arr


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
    return rigid_matrix(rot_t, -(rot_t @ arr[..., :3, 3:4])[..., 0], arr.dtype)


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
        axis = np.eye(3)[np.argmin(np.abs(z), axis=-1)]
        x_raw = np.where(pole[..., None], np.cross(z, axis), x_raw)
    x, _ = unit_and_norm(x_raw)
    x, _ = unit_and_norm(x - np.sum(x * z, axis=-1, keepdims=True) * z)  # exact orthogonality to z
    return rigid_matrix(np.stack([x, np.cross(z, x), z], axis=-1), e, dtype)
