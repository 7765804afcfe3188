"""Camera paths for fly-through renders: an orbit and a spiral built from the input cameras alone, and a path
through saved keyframes.  Orbit and spiral frames are evenly spaced and the last one does not repeat the first,
so a path played in a loop has no doubled frame.
"""

from __future__ import annotations

import numpy as np

from .poses import look_at, pose_list
from .spherical import _spherical_angles, closest_point_to_axes, default_up, pose_from_spherical
from .spherical import spherical_from_pose  # noqa: F401  (the docstrings' examples use it)

__all__ = ["orbit_path", "spiral_path", "spiral_focus_depth", "keyframe_path"]


def _count(n, fn: str) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"{fn}: n must be an integer >= 1, got {n!r}")
    return int(n)


def orbit_path(input_c2w, n: int, center=None, up=None, elevation: float | None = None,
               radius: float | None = None) -> np.ndarray:
    """``n`` cameras on a circle around ``center``, level with the horizon, each looking at ``center``.

    Frame ``k`` sits at azimuth ``az_0 + 360 k / n`` about ``up``, where ``az_0`` is the first input camera's
    azimuth (:func:`spherical_from_pose`), so frame 0 is beside input 0.  Each pose is
    :func:`pose_from_spherical` (no roll: image up points along ``up``); at elevation +-90 every frame sits at
    the pole and only turns about the view axis.

    Args:
        input_c2w: ``(m, 4, 4)`` or ``(m, 3, 4)`` input camera-to-world poses, ``m >= 1``.
        n: number of frames, ``>= 1``.
        center: ``(3,)`` point orbited and looked at (default :func:`closest_point_to_axes` of the inputs,
            the point they look at; needs two inputs whose optical axes are not parallel).
        up: ``(3,)`` orbit axis (default :func:`default_up` of the inputs).
        elevation: degrees above the plane through ``center`` normal to ``up`` (default: the inputs' mean).
        radius: distance to ``center`` (default: the inputs' mean distance).

    Returns:
        ``(n, 4, 4)`` OpenCV camera-to-world, dtype of ``input_c2w``.

    Example:
        >>> inputs = pose_from_spherical(np.array([10.0, 50.0]), np.array([20.0, 40.0]), 4.0)
        >>> path = orbit_path(inputs, 4)
        >>> np.round(spherical_from_pose(path)[0], 6).tolist()   # azimuths from input 0's, 90 apart
        [10.0, 100.0, -170.0, -80.0]
        >>> np.round(spherical_from_pose(path)[1], 6).tolist()   # the inputs' mean elevation
        [30.0, 30.0, 30.0, 30.0]
    """
    arr = pose_list(input_c2w, "input_c2w")
    count = _count(n, "orbit_path")
    a = arr.astype(np.float64)
    c = closest_point_to_axes(a) if center is None else np.asarray(center, dtype=np.float64)
    u = default_up(a) if up is None else np.asarray(up, dtype=np.float64)
    az, el, r = _spherical_angles(a, c, u, arr.dtype)
    el_path = float(np.mean(el)) if elevation is None else float(elevation)
    r_path = float(np.mean(r)) if radius is None else float(radius)
    azimuths = az[0] + 360.0 * np.arange(count, dtype=np.float64) / count
    poses = pose_from_spherical(azimuths, np.full(count, el_path), np.full(count, r_path), center=c, up=u)
    return poses.astype(arr.dtype, copy=False)


def spiral_focus_depth(near: float, far: float) -> float:
    """Distance in front of the mean camera that a spiral path looks at: NeRF's LLFF choice, the harmonic
    blend ``1 / (0.25 / (0.9 near) + 0.75 / (5 far))`` of the scene's near and far bounds.

    Example:
        >>> round(spiral_focus_depth(1.0, 10.0), 6)
        3.41556
    """
    near, far = float(near), float(far)
    if not (np.isfinite(near) and np.isfinite(far) and 0.0 < near <= far):
        raise ValueError(f"spiral_focus_depth: need 0 < near <= far, got {near!r}, {far!r}")
    return 1.0 / (0.25 / (0.9 * near) + 0.75 / (5.0 * far))


def spiral_path(input_c2w, n: int, focus_depth: float, radii=None, rotations: float = 2.0,
                z_rate: float = 0.5) -> np.ndarray:
    """``n`` cameras on a spiral around the inputs' mean pose, each looking at one focus point.

    The mean pose sits at the inputs' mean centre, looking along their mean optical axis, image up along their
    mean image-up axis.  Frame ``k`` (``theta = 2 pi rotations k / n``) sits at ``radii * (cos theta,
    sin theta, sin(z_rate theta))`` in the mean camera's frame (right, down, forward) and looks at the point
    ``focus_depth`` along the mean axis, image up toward the mean image-up axis (NeRF's ``render_path_spiral``).

    Args:
        input_c2w: ``(m, 4, 4)`` or ``(m, 3, 4)`` input camera-to-world poses, ``m >= 1``.
        n: number of frames, ``>= 1``.
        focus_depth: positive distance of the focus point along the mean optical axis
            (:func:`spiral_focus_depth` from the scene's bounds).
        radii: ``(3,)`` non-negative extents along the mean camera's x, y, z (default: the 90th percentile
            of the inputs' absolute offsets from their mean centre along those axes, as NeRF does).
        rotations: turns around the mean axis over the path.
        z_rate: turns of the forward/backward motion per turn.

    Returns:
        ``(n, 4, 4)`` OpenCV camera-to-world, dtype of ``input_c2w``.

    Raises:
        ValueError: bad shapes or values; optical or image-up axes that cancel out; a frame at the focus point.

    Example:
        >>> path = spiral_path(np.eye(4)[None], 4, focus_depth=10.0, radii=(1.0, 1.0, 0.0), rotations=1.0)
        >>> (np.round(path[:, :3, 3], 12) + 0.0).tolist()   # right, down, left, up of the mean camera
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    """
    arr = pose_list(input_c2w, "input_c2w")
    count = _count(n, "spiral_path")
    focus = float(focus_depth)
    if not (np.isfinite(focus) and focus > 0.0):
        raise ValueError(f"spiral_path: focus_depth must be positive and finite, got {focus_depth!r}")
    for value, name in ((rotations, "rotations"), (z_rate, "z_rate")):
        try:
            finite = np.isfinite(float(value))
        except (TypeError, ValueError):
            finite = False
        if not finite:
            raise ValueError(f"spiral_path: {name} must be a finite number, got {value!r}")
    a = arr.astype(np.float64)
    centre = a[:, :3, 3].mean(axis=0)
    forward, image_up = a[:, :3, 2].mean(axis=0), -a[:, :3, 1].mean(axis=0)
    if np.linalg.norm(forward) < 1e-6 or np.linalg.norm(image_up) < 1e-6:
        raise ValueError("spiral_path: the inputs' optical axes or image-up axes cancel out; no mean pose")
    mean_pose = look_at(centre, centre + forward / np.linalg.norm(forward), up=image_up)
    rot = mean_pose[:3, :3]
    if radii is None:
        offsets = (a[:, :3, 3] - centre) @ rot   # in the mean camera's frame
        rad = np.percentile(np.abs(offsets), 90, axis=0)
    else:
        rad = np.asarray(radii, dtype=np.float64)
        if rad.shape != (3,) or not np.isfinite(rad).all() or (rad < 0).any():
            raise ValueError(f"spiral_path: radii must be 3 finite numbers >= 0, got {radii!r}")
    theta = 2.0 * np.pi * float(rotations) * np.arange(count, dtype=np.float64) / count
    local = rad * np.stack([np.cos(theta), np.sin(theta), np.sin(float(z_rate) * theta)], axis=-1)
    eyes = centre + local @ rot.T
    target = centre + focus * rot[:, 2]
    if (np.linalg.norm(eyes - target, axis=-1) <= 1e-9 * focus).any():   # relative: small scenes too
        raise ValueError("spiral_path: a frame reaches the focus point; use a larger focus_depth or smaller radii")
    poses = look_at(eyes, np.broadcast_to(target, eyes.shape), up=image_up)
    return poses.astype(arr.dtype, copy=False)


def keyframe_path(key_c2w, n: int) -> np.ndarray:
    """``n`` cameras through keyframes, from the first to the last, evenly spaced in keyframe index: rotations
    are spherically interpolated (SLERP, the shorter arc) and positions linearly between neighbouring keyframes.

    Args:
        key_c2w: ``(k, 4, 4)`` or ``(k, 3, 4)`` camera-to-world keyframes, ``k >= 1`` (one keyframe: ``n`` copies).
        n: number of frames, ``>= 1`` (one frame: the first keyframe).

    Returns:
        ``(n, 4, 4)`` camera-to-world, dtype of ``key_c2w``; frame 0 is keyframe 0 and frame ``n - 1`` keyframe
        ``k - 1``.

    Example:
        >>> keys = np.stack([np.eye(4), np.eye(4)])
        >>> keys[1, :2, :2] = [[0.0, -1.0], [1.0, 0.0]]   # a quarter turn about z
        >>> keys[1, :3, 3] = (2.0, 0.0, 0.0)
        >>> mid = keyframe_path(keys, 3)[1]
        >>> np.round(mid[:3, 3], 6).tolist(), np.round(mid[:2, 0], 6).tolist()   # half way: an eighth of a turn
        ([1.0, 0.0, 0.0], [0.707107, 0.707107])
    """
    from scipy.spatial.transform import Rotation, Slerp

    keys = pose_list(key_c2w, "key_c2w")
    count = _count(n, "keyframe_path")
    a = keys.astype(np.float64)
    s = np.linspace(0.0, len(a) - 1, count) if count > 1 else np.zeros(1)
    out = np.tile(np.eye(4), (count, 1, 1))
    if len(a) == 1:
        out[:, :3, :] = a[0, :3, :]
        return out.astype(keys.dtype, copy=False)
    seg = np.minimum(np.floor(s).astype(np.int64), len(a) - 2)
    frac = (s - seg)[:, None]
    out[:, :3, 3] = (1.0 - frac) * a[seg, :3, 3] + frac * a[seg + 1, :3, 3]
    out[:, :3, :3] = Slerp(np.arange(len(a)), Rotation.from_matrix(a[:, :3, :3]))(s).as_matrix()
    return out.astype(keys.dtype, copy=False)
