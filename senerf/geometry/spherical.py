"""Spherical camera placement around a centre, optical-axis centres, and pseudo-view sampling.

Convention:
    For a unit ``up`` the fixed right-handed basis ``(e1, e2, up)`` is ``e1 = normalize(a - (a . up) up)``
    with ``a = +x`` (or ``+y`` when ``|up_x| > 0.9``) and ``e2 = up x e1``; for ``up = +z`` this is
    ``e1 = +x``, ``e2 = +y``.  The camera centre of ``(azimuth, elevation, radius)`` (degrees) is
    ``center + r (cos el cos az e1 + cos el sin az e2 + sin el up)``.  The OpenCV camera looks at ``center``
    (z = -d with ``d`` the unit offset above), its x axis is the azimuth tangent ``t_az = -sin az e1 +
    cos az e2`` and y = z x x = -(elevation tangent), so the image up (-y) leans towards ``up``.  Built by
    composition (never via look-at), the rotation is proper at every elevation in [-90, 90], poles included.
"""

from __future__ import annotations

import numpy as np

from ._util import as_4x4, as_float, check_last, check_pose, rigid_matrix, unit_and_norm
from .poses import POSE_ATOL, pose_list, validate_rigid

__all__ = ["pose_from_spherical", "spherical_from_pose", "closest_point_to_axes", "sample_pseudo_views", "default_up",
           "spherical_basis", "nearest_view_angles"]


def spherical_basis(up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The right-handed basis ``(e1, e2, up_unit)`` of the spherical convention, each ``(..., 3)`` float64.

    Example:
        >>> [b.tolist() for b in spherical_basis((0.0, 0.0, 2.0))]
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    u = as_float(up, "up", np.float64)
    check_last(u, (3,), "up")
    finite = np.isfinite(u).all(axis=-1)
    u, norm = unit_and_norm(np.where(finite[..., None], u, 0.0))
    if not (finite & (norm > 0)).all():
        raise ValueError("up: must be finite and non-zero")
    a = np.where((np.abs(u[..., :1]) > 0.9), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    e1 = a - np.sum(a * u, axis=-1, keepdims=True) * u
    e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(u, e1)
    return e1, e2, u


def pose_from_spherical(azimuth, elevation, radius, center=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world pose of a camera on a sphere around ``center``, looking at it (see module convention).

    Args:
        azimuth: ``(...)`` degrees, any value.
        elevation: ``(...)`` degrees in ``[-90, 90]``.
        radius: ``(...)`` positive distance to ``center``.
        center: ``(..., 3)`` world point looked at.
        up: ``(..., 3)`` world up (any non-zero length).

    Returns:
        ``(..., 4, 4)`` OpenCV camera-to-world (batch = broadcast of all inputs), dtype of ``azimuth``.

    Example:
        >>> c2w = pose_from_spherical(90.0, 30.0, 4.0)   # NeRF's pose_spherical(0, -30, 4) position
        >>> c2w[:3, 3].round(4).tolist()
        [0.0, 3.4641, 2.0]
    """
    az_a = as_float(azimuth, "azimuth")
    dtype = az_a.dtype
    az = np.deg2rad(az_a.astype(np.float64))
    el_deg = as_float(elevation, "elevation", np.float64)
    r = as_float(radius, "radius", np.float64)
    c = as_float(center, "center", np.float64)
    check_last(c, (3,), "center")
    if not (np.isfinite(az).all() and np.isfinite(c).all()):
        raise ValueError("pose_from_spherical: azimuth and center must be finite")
    if not np.isfinite(el_deg).all() or (np.abs(el_deg) > 90.0).any():
        raise ValueError("pose_from_spherical: elevation must be finite and within [-90, 90] degrees")
    if not np.isfinite(r).all() or (r <= 0).any():
        raise ValueError("pose_from_spherical: radius must be positive and finite")
    e1, e2, u = spherical_basis(up)
    el = np.deg2rad(el_deg)
    az, el, r = np.broadcast_arrays(az, el, r)
    ca, sa, ce, se = np.cos(az)[..., None], np.sin(az)[..., None], np.cos(el)[..., None], np.sin(el)[..., None]
    d = ce * ca * e1 + ce * sa * e2 + se * u  # unit offset from the centre
    t_az = -sa * e1 + ca * e2
    t_el = -se * ca * e1 - se * sa * e2 + ce * u
    return rigid_matrix(np.stack([t_az, -t_el, -d], axis=-1), c + r[..., None] * d, dtype)


def spherical_from_pose(c2w, center=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)):
    """``(azimuth, elevation, radius)`` of camera centres around ``center`` (inverse of :func:`pose_from_spherical`).

    Azimuth is in ``(-180, 180]``, elevation in ``[-90, 90]`` (degrees).  Only the camera centre matters,
    except at the poles (horizontal offset below ``1e-12 r``, or below 8 units in the last place of the
    coordinates' dtype: ``8 eps max(|t|, |center|)``), where the azimuth of the position is undefined:
    there the azimuth is read from the camera x axis as the azimuth tangent (``atan2(-x.e1, x.e2)``), which
    returns the azimuth that :func:`pose_from_spherical` was given.

    Args:
        c2w: ``(..., 4, 4)`` or ``(..., 3, 4)`` camera-to-world.
        center: ``(..., 3)``; up: ``(..., 3)``.

    Returns:
        Three arrays ``(...)``, dtype of ``c2w``.

    Raises:
        ValueError: a camera centre equal to ``center`` (radius 0).
    """
    arr = check_pose(c2w)
    dtype = arr.dtype
    az, el, r = _spherical_angles(arr.astype(np.float64), center, up, dtype)
    az = az.astype(dtype)
    az = np.where(az <= -180.0, dtype.type(180.0), az)  # -179.999999 may round to -180 in float32
    return az, el.astype(dtype), r.astype(dtype)


def _spherical_angles(a: np.ndarray, center, up, dtype) -> tuple:
    """:func:`spherical_from_pose` in float64 of float64 poses ``a (..., 4, 4)`` that carry the rounding of
    ``dtype`` (poses made in float32 and widened, as ``sample_pseudo_views`` and ``orbit_path`` compute): the
    pole test scales with ``dtype``'s precision.  Azimuth in ``(-180, 180]`` before any cast."""
    c = as_float(center, "center", np.float64)
    check_last(c, (3,), "center")
    e1, e2, u = spherical_basis(up)
    if not np.isfinite(c).all():
        raise ValueError("spherical_from_pose: center must be finite")
    p = a[..., :3, 3] - c
    if not np.isfinite(p).all():
        raise ValueError("spherical_from_pose: a camera centre is non-finite, or too far from center to subtract")
    p_unit, r = unit_and_norm(p)  # the direction is exact at any scale, r may overflow to inf
    if (r <= 0).any():
        raise ValueError("spherical_from_pose: a camera centre equals center")
    pu = np.sum(p_unit * u, axis=-1)
    p1, p2 = np.sum(p_unit * e1, axis=-1), np.sum(p_unit * e2, axis=-1)
    el = np.degrees(np.arctan2(pu, np.hypot(p1, p2)))
    x = a[..., :3, 0]
    scale = np.maximum(np.abs(a[..., :3, 3]).max(axis=-1), np.abs(c).max(axis=-1))
    pole = np.hypot(p1, p2) <= np.maximum(1e-12, 8.0 * np.finfo(dtype).eps * scale / r)
    az = np.degrees(np.where(pole, np.arctan2(-np.sum(x * e1, axis=-1), np.sum(x * e2, axis=-1)),
                             np.arctan2(p2, p1)))
    return np.where(az <= -180.0, az + 360.0, az), el, r


def closest_point_to_axes(c2w) -> np.ndarray:
    """Least-squares point nearest to every optical axis (the +z ray line of each camera).

    Minimises ``sum_i |(I - z_i z_i^T)(p - o_i)|^2``; solved in float64.

    Args:
        c2w: ``(n, 4, 4)`` or ``(n, 3, 4)`` camera-to-world (any leading dims, flattened), ``n >= 1``.

    Returns:
        ``(3,)`` world point, dtype of ``c2w``.

    Raises:
        ValueError: the axes are (nearly) all parallel (condition number above 1e10), or non-finite input.

    Example:
        >>> poses = np.stack([pose_from_spherical(a, 10.0, 4.0, center=(1, 2, 3)) for a in (0, 90, 200)])
        >>> closest_point_to_axes(poses).round(9).tolist()
        [1.0, 2.0, 3.0]
    """
    arr = validate_rigid(c2w, atol=POSE_ATOL, name="c2w")   # a scaled axis would weigh its camera differently
    a = arr.astype(np.float64).reshape((-1,) + arr.shape[-2:])
    if a.shape[0] == 0:
        raise ValueError("closest_point_to_axes: need at least one pose")
    z = a[:, :3, 2] / np.linalg.norm(a[:, :3, 2], axis=-1, keepdims=True)
    o = a[:, :3, 3]
    proj = np.eye(3) - z[:, :, None] * z[:, None, :]
    lhs = proj.sum(axis=0)
    rhs = (proj @ o[:, :, None]).sum(axis=0)[:, 0]
    w = np.linalg.eigvalsh(lhs)
    if w[0] <= 1e-10 * w[-1]:
        raise ValueError("closest_point_to_axes: the optical axes are all parallel, so no unique closest point "
                         "exists; pass the scene centre explicitly")
    return np.linalg.solve(lhs, rhs).astype(arr.dtype)


def default_up(input_c2w) -> np.ndarray:
    """The up axis :func:`sample_pseudo_views` measures azimuth and elevation about, from the inputs alone.

    Cameras that share a horizon (no roll) have their x axes (``c2w[:, :3, 0]``) in one plane, whose normal is
    the world's up: the eigenvector of the smallest eigenvalue of ``mean(x x^T)``, signed to agree with the
    image-up axes, used when the two smaller eigenvalues differ by more than 0.01 (two cameras at least ~12
    degrees of azimuth apart).  Otherwise (one camera, or parallel x axes as in a forward-facing capture) it is
    the normalized mean of the image-up axes (``-c2w[:, :3, 1]``), which leans towards the cameras' side.

    Args:
        input_c2w: ``(m, 4, 4)`` or ``(m, 3, 4)`` camera-to-world poses (OpenCV), ``m >= 1``.
    Returns:
        ``(3,)`` float64 unit vector.
    Raises:
        ValueError: the image-up axes cancel out and the plane normal cannot be used.

    Example:
        >>> inputs = pose_from_spherical(np.array([0.0, 120.0]), np.array([20.0, 50.0]), 4.0)
        >>> np.round(default_up(inputs), 12).tolist()
        [0.0, 0.0, 1.0]
    """
    a = pose_list(input_c2w, "input_c2w").astype(np.float64)
    mean_up = -a[:, :3, 1].mean(axis=0)
    norm = np.linalg.norm(mean_up)
    x = a[:, :3, 0]
    eigval, eigvec = np.linalg.eigh(x.T @ x / x.shape[0])  # ascending
    normal = eigvec[:, 0]
    if eigval[1] - eigval[0] > 0.01 and norm > 1e-6 and abs(normal @ mean_up) > 0.5 * norm:
        return normal * np.sign(normal @ mean_up)
    if not norm > 1e-6:
        raise ValueError("default_up: the input cameras' image-up axes cancel out and their x axes do not "
                         "fix a horizon; pass up explicitly")
    return mean_up / norm


def sample_pseudo_views(input_c2w, max_offset_deg, n, rng, center=None, up=None):
    """Random poses near the input views, for pseudo-view rendering.

    Pseudo view ``k`` comes from input ``source_index[k] = k % m`` (round robin over the ``m`` inputs).  Its
    azimuth is the source's plus an offset drawn uniformly from ``[-max_offset, max_offset]``; its elevation
    is drawn uniformly from ``[el - max_offset, el + max_offset]`` intersected with ``[-89.9, 89.9]``, or
    ``[-|el|, |el|]`` for a source nearer a pole (so it never crosses one); its radius is the source's
    distance to ``center``.  The source camera is carried there rigidly, by the rotation about ``center``
    that takes the :func:`pose_from_spherical` pose at the source's angles to the one at the new angles: a
    camera keeps its roll and its aim relative to ``center``, offset 0 returns the inputs exactly, and a
    source that looks at ``center`` with image up towards ``up`` gives exactly :func:`pose_from_spherical`
    of the new angles.  ``rng`` draws ``n`` azimuth uniforms, then ``n`` elevation uniforms.

    Args:
        input_c2w: ``(m, 4, 4)`` camera-to-world of the known views, ``m >= 1``.
        max_offset_deg: ``>= 0`` half-width of the angular window, degrees.
        n: number of pseudo views, ``>= 0``.
        rng: ``np.random.Generator``.
        center: ``(3,)`` point the views turn about; default :func:`closest_point_to_axes` of the inputs.
        up: ``(3,)`` the axis of azimuth; default :func:`default_up` of the inputs.

    Returns:
        ``(c2w (n, 4, 4), source_index (n,) int64)``; ``c2w`` has the dtype of ``input_c2w``.

    Raises:
        ValueError: bad arguments (named), or an input camera centre at ``center`` (within rounding).

    Example:
        >>> inputs = pose_from_spherical(np.array([0.0, 120.0]), 20.0, 4.0)
        >>> c2w, src = sample_pseudo_views(inputs, 10.0, 4, np.random.default_rng(0))
        >>> c2w.shape, src.tolist()
        ((4, 4, 4), [0, 1, 0, 1])
        >>> same, _ = sample_pseudo_views(inputs, 0.0, 2, np.random.default_rng(0))
        >>> bool(np.allclose(same, inputs, atol=1e-12))
        True
    """
    arr = pose_list(input_c2w, "input_c2w")
    if not isinstance(rng, np.random.Generator):
        raise ValueError("rng: expected a numpy.random.Generator")
    off = float(max_offset_deg)
    if not np.isfinite(off) or off < 0:
        raise ValueError(f"max_offset_deg: must be finite and >= 0, got {max_offset_deg!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) and not (
            isinstance(n, (float, np.floating)) and float(n).is_integer()) or n < 0:
        raise ValueError(f"n: must be an integer >= 0, got {n!r}")
    n = int(n)
    a = as_4x4(arr.astype(np.float64))
    guessed = center is None
    if guessed:
        center = closest_point_to_axes(a)
    c = as_float(center, "center", np.float64)
    check_last(c, (3,), "center")
    c = c.reshape(3)
    u = default_up(a) if up is None else as_float(up, "up", np.float64).reshape(3)
    dist = np.linalg.norm(a[:, :3, 3] - c, axis=-1)
    tiny = dist <= 64.0 * np.finfo(arr.dtype).eps * max(np.abs(c).max(), np.abs(a[:, :3, 3]).max())
    if tiny.any():
        i = int(np.flatnonzero(tiny)[0])
        why = " (the point nearest the inputs' optical axes, which meet at their common centre)" if guessed else ""
        raise ValueError(f"sample_pseudo_views: input_c2w[{i}]'s camera centre coincides with center{why}; pseudo "
                         f"views turn about center, so pass one away from the cameras")
    az0, el0, r0 = _spherical_angles(a, c, u, arr.dtype)
    src = np.arange(n, dtype=np.int64) % arr.shape[0]
    d_az = rng.uniform(-off, off, size=n)
    t_el = rng.uniform(0.0, 1.0, size=n)
    lim = np.maximum(89.9, np.abs(el0[src]))
    lo = np.clip(el0[src] - off, -lim, lim)
    hi = np.clip(el0[src] + off, -lim, lim)
    el = lo + t_el * (hi - lo)
    at_source = pose_from_spherical(az0[src], el0[src], r0[src], center=c, up=u).reshape(n, 4, 4)
    at_target = pose_from_spherical(az0[src] + d_az, el, r0[src], center=c, up=u).reshape(n, 4, 4)
    rot = at_target[:, :3, :3] @ np.swapaxes(at_source[:, :3, :3], 1, 2)  # (n, 3, 3)
    t = c + np.einsum("nij,nj->ni", rot, a[src, :3, 3] - c)
    return rigid_matrix(rot @ a[src, :3, :3], t, arr.dtype), src


def nearest_view_angles(train_c2w: np.ndarray, test_c2w: np.ndarray,
                        center: np.ndarray | tuple | None = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Angle in degrees between each test camera and its nearest training camera.

    Args:
        train_c2w: (m, 4, 4) or (m, 3, 4) camera-to-world poses of the training views.
        test_c2w: (n, 4, 4) or (n, 3, 4) poses of the test views.
        center: (3,) point the cameras orbit (the origin for NeRF Synthetic): the angle between the
            directions from ``center`` to the camera centres.  ``None``: the angle between the optical axes
            (camera z, OpenCV), the meaningful choice for forward-facing (LLFF) captures.

    Returns:
        (n,) float64 degrees in [0, 180].

    Raises:
        ValueError: a non-finite pose, or a camera centre at ``center`` (its direction from it is undefined).
    """
    train_c2w = pose_list(train_c2w, "train_c2w", rigid=False).astype(np.float64)
    test_c2w = pose_list(test_c2w, "test_c2w", rigid=False).astype(np.float64)
    for name, a in (("train_c2w", train_c2w), ("test_c2w", test_c2w)):
        if center is None and np.isfinite(a).all():   # the optical axes are used: they must be unit
            validate_rigid(a, atol=POSE_ATOL, name=name)
    if center is None:
        d_tr, d_te = train_c2w[:, :3, 2].copy(), test_c2w[:, :3, 2].copy()
    else:
        c = np.asarray(center, np.float64).reshape(3)
        d_tr, d_te = train_c2w[:, :3, 3] - c, test_c2w[:, :3, 3] - c
    for name, d in (("train_c2w", d_tr), ("test_c2w", d_te)):
        finite = np.isfinite(d).all(axis=-1)
        unit, norm = unit_and_norm(np.where(finite[:, None], d, 0.0))  # no inf / inf warnings
        ok = finite & (norm > 0)
        if not ok.all():
            bad = int(np.flatnonzero(~ok)[0])
            what = "a camera centre at center" if center is not None else "a zero optical axis"
            raise ValueError(f"{name}[{bad}]: non-finite pose or {what}: its direction is undefined")
        d[:] = unit
    dot = d_te @ d_tr.T                                                        # (n, m)
    cross = np.linalg.norm(np.cross(d_te[:, None, :], d_tr[None, :, :]), axis=-1)  # (n, m)
    return np.degrees(np.arctan2(cross, dot).min(axis=1))                      # precise near 0 and 180
