"""Lens undistortion at the loaders' edge: distorted photos become pinhole images with their own intrinsics.

Downstream of the loaders every camera is a pinhole (:class:`senerf.geometry.Intrinsics`), so a photo taken
through a distorting lens is resampled once, when the scene is loaded, onto a pinhole camera at the same
pose.  Two models are understood, those the instant-ngp / nerfstudio ``transforms.json`` writers emit:

* ``'opencv'`` (COLMAP's ``OPENCV``, ``RADIAL``, ``SIMPLE_RADIAL``; instant-ngp's perspective cameras): with
  normalised coordinates ``(x, y)`` and ``r^2 = x^2 + y^2``::

      x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
      y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y

* ``'fisheye'`` (``OPENCV_FISHEYE``, instant-ngp's ``is_fisheye``): ``theta = atan(r)``,
  ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``, ``(x_d, y_d) = theta_d / r (x, y)``.

The photo's pixel is then ``(fx x_d + cx, fy y_d + cy)``.  The pinhole camera keeps the photo's size,
principal point and ``fx / fy`` ratio; its focal length is scaled by the smallest factor for which every one of
its pixels samples within the photo's pixel centres, where the lens model does not fold back on itself: the
widest pinhole view without an invalid (black or repeated) pixel, as OpenCV's ``alpha = 0``.  A photo whose
outer part lies beyond the fold of its model (a strong negative ``k1`` on a wide lens) is cropped to the part
inside it.

Convention:
    :class:`Intrinsics` put the centre of pixel ``i`` at ``i + 0.5``; OpenCV at ``i``.  Every ``cv2`` call
    here gets ``cx - 0.5, cy - 0.5``, and the maps it returns are in OpenCV's pixel coordinates.  Images are
    float32 ``(H, W, 3)`` or straight RGBA ``(H, W, 4)``; RGBA is resampled premultiplied (no dark fringes).
"""

from __future__ import annotations

import math
import warnings
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from ..geometry import Intrinsics

__all__ = ["Distortion", "distort_pixels", "undistorted_intrinsics", "undistortion_maps", "undistort_image",
           "photo_coverage", "DistortionError", "Undistorter", "PERSPECTIVE_MODELS", "FISHEYE_MODELS",
           "COVERAGE_WARN"]

#: COLMAP's camera model names that senerf reads (the JSON formats' ``camera_model`` and COLMAP's own):
#: pinholes and the OpenCV radial-tangential family, then the fisheyes (OpenCV's equidistant family).
PERSPECTIVE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
FISHEYE_MODELS = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE")

_N_COEFFS = {"opencv": 5, "fisheye": 4}
# The pinhole focal factor is searched within [1/_SCALE_LIMIT, _SCALE_LIMIT] of the photo's, and no wider than
# a view whose farthest pixel is _MAX_OFF_AXIS_DEG off the optical axis.
_SCALE_LIMIT = 64.0
_MAX_OFF_AXIS_DEG = 80.0
# Undistortion maps an Undistorter keeps: frames of up to this many cameras interleaved reuse theirs.
_MAPS_KEPT = 4
_BISECTIONS = 40
# The focal search keeps every border sample within the photo's pixel centres exactly; the full float32 maps may
# then fall this far (pixels) outside them, float32's rounding at 10^4 pixels being 1e-3.
_MAP_TOL = 1e-2
#: A photo whose pinhole view keeps less than this share of it gets a warning when the scene loads, saying why: a
#: lens model that folds back well inside the photo (a strong coefficient, perhaps of the wrong sign or scale), or a
#: lens wider than a pinhole image can hold (a circular fisheye).  Ordinary lenses keep 0.77-0.98; a model folding
#: just inside the corners can keep 0.5-0.7 and is not warned about.
COVERAGE_WARN = 0.5


class DistortionError(ValueError):
    """The distortion cannot be undone over the image (it folds it, or no pinhole view fits inside it)."""


@dataclass(frozen=True)
class Distortion:
    """A lens distortion model and its coefficients.

    Args:
        model: ``'opencv'`` or ``'fisheye'`` (module docstring).
        coeffs: OpenCV's order: ``(k1, k2, p1, p2, k3)`` for ``'opencv'``, ``(k1, k2, k3, k4)`` for
            ``'fisheye'``; finite floats.

    Raises:
        ValueError: unknown model, wrong number of coefficients, or a non-finite one.
    """

    model: str
    coeffs: tuple

    def __post_init__(self) -> None:
        if self.model not in _N_COEFFS:
            raise ValueError(f"Distortion.model: expected 'opencv' or 'fisheye', got {self.model!r}")
        coeffs = tuple(float(c) for c in self.coeffs)
        if len(coeffs) != _N_COEFFS[self.model] or not all(math.isfinite(c) for c in coeffs):
            raise ValueError(f"Distortion.coeffs: expected {_N_COEFFS[self.model]} finite numbers for "
                             f"{self.model!r}, got {self.coeffs!r}")
        object.__setattr__(self, "coeffs", coeffs)

    @property
    def is_identity(self) -> bool:
        """True for the pinhole itself: the ``'opencv'`` model with every coefficient 0 (a fisheye never is)."""
        return self.model == "opencv" and not any(self.coeffs)


def _cv_K(k: Intrinsics) -> np.ndarray:
    """``(3, 3)`` float64 camera matrix in OpenCV's pixel convention (pixel 0's centre at 0.0)."""
    return np.array([[k.fx, 0.0, k.cx - 0.5], [0.0, k.fy, k.cy - 0.5], [0.0, 0.0, 1.0]])


def _project(xy: np.ndarray, k_photo: Intrinsics, distortion: Distortion) -> np.ndarray:
    """Normalised pinhole coordinates ``(n, 2)`` -> photo pixels ``(n, 2)``, OpenCV convention."""
    pts = np.concatenate([xy, np.ones((len(xy), 1))], axis=1).reshape(1, -1, 3).astype(np.float64)
    zero = np.zeros(3)
    coeffs = np.asarray(distortion.coeffs, np.float64)
    if distortion.model == "fisheye":
        out, _ = cv2.fisheye.projectPoints(pts, zero, zero, _cv_K(k_photo), coeffs)
    else:
        out, _ = cv2.projectPoints(pts, zero, zero, _cv_K(k_photo), coeffs)
    return out.reshape(-1, 2)


def distort_pixels(uv: np.ndarray, k_pinhole: Intrinsics, k_photo: Intrinsics, distortion: Distortion) -> np.ndarray:
    """Where pinhole pixels land in the distorted photo.

    Args:
        uv: ``(..., 2)`` pixel positions of the pinhole camera ``k_pinhole`` (:class:`Intrinsics` convention).
        k_pinhole: the pinhole camera.
        k_photo: the photo's intrinsics (its principal point and focal before distortion).
        distortion: the photo's lens distortion.

    Returns:
        ``(..., 2)`` float64 positions in the photo, same convention.

    Example:
        >>> k = Intrinsics(100.0, 100.0, 50.0, 50.0, 100, 100)
        >>> distort_pixels(np.array([50.0, 50.0]), k, k, Distortion("opencv", (-0.2, 0, 0, 0, 0))).tolist()
        [50.0, 50.0]
    """
    uv = np.asarray(uv, np.float64)
    if uv.shape[-1:] != (2,):
        raise ValueError(f"distort_pixels: uv must have shape (..., 2), got {uv.shape}")
    flat = uv.reshape(-1, 2)
    xy = np.stack([(flat[:, 0] - k_pinhole.cx) / k_pinhole.fx, (flat[:, 1] - k_pinhole.cy) / k_pinhole.fy], axis=1)
    return (_project(xy, k_photo, distortion) + 0.5).reshape(uv.shape)


def _probe_uv(width: int, height: int) -> np.ndarray:
    """Pixel centres of the border rows and columns of a ``width x height`` image and of a 17 x 17 grid
    inside it, ``(n, 2)``: where the pinhole view is tested."""
    us, vs = np.arange(width) + 0.5, np.arange(height) + 0.5
    gu, gv = np.meshgrid(np.linspace(0.5, width - 0.5, 17), np.linspace(0.5, height - 0.5, 17))
    return np.concatenate([
        np.stack([us, np.full(width, 0.5)], 1), np.stack([us, np.full(width, height - 0.5)], 1),
        np.stack([np.full(height, 0.5), vs], 1), np.stack([np.full(height, width - 0.5), vs], 1),
        np.stack([gu.ravel(), gv.ravel()], 1),
    ])


def _pinhole(k_photo: Intrinsics, scale: float) -> Intrinsics:
    return Intrinsics(k_photo.fx * scale, k_photo.fy * scale, k_photo.cx, k_photo.cy, k_photo.width, k_photo.height)


def _on_centres(u: np.ndarray, v: np.ndarray, k: Intrinsics, tol: float) -> bool:
    """True when every ``(u, v)`` lies within the photo's outermost pixel centres, ``[0.5, W - 0.5] x
    [0.5, H - 0.5]`` of ``k``, give or take ``tol``: bilinear sampling there never reaches past the photo."""
    return bool(np.all(np.isfinite(u)) and np.all(np.isfinite(v))
                and u.min() >= 0.5 - tol and v.min() >= 0.5 - tol
                and u.max() <= k.width - 0.5 + tol and v.max() <= k.height - 0.5 + tol)


def _view_fits(k_photo: Intrinsics, distortion: Distortion, k_pinhole: Intrinsics, probe: np.ndarray) -> bool:
    """True when the ``probe`` pixels of ``k_pinhole`` land on the photo, where the lens does not fold (the
    Jacobian determinant of pinhole pixel -> photo pixel, by central differences of 1e-3 pixel, is positive)."""
    h = 1e-3
    n = len(probe)
    steps = ((0.0, 0.0), (h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h))
    uv = distort_pixels(np.concatenate([probe + step for step in steps]), k_pinhole, k_photo, distortion)
    p0, pu, pv = uv[:n], uv[n:2 * n] - uv[2 * n:3 * n], uv[3 * n:4 * n] - uv[4 * n:]
    if not _on_centres(p0[:, 0], p0[:, 1], k_photo, 1e-9):
        return False
    det = pu[:, 0] * pv[:, 1] - pv[:, 0] * pu[:, 1]
    return bool(np.all(det > 0.0))


def undistorted_intrinsics(k_photo: Intrinsics, distortion: Distortion) -> Intrinsics:
    """The pinhole camera a distorted photo is resampled onto (module docstring).

    Args:
        k_photo: the photo's intrinsics.
        distortion: its lens distortion.

    Returns:
        ``k_photo`` itself for an identity distortion; otherwise the same size, principal point and
        ``fx / fy``, with both focal lengths times the smallest factor for which every border pixel (and a
        grid inside) lands within the photo's pixel centres where the lens does not fold, found by bisection
        (~1e-12 relative).  A lens that sees wider still (a fisheye beyond 160 degrees) gets the view whose
        corners are 80 degrees off axis: a pinhole image cannot hold a hemisphere.

    Raises:
        DistortionError: the principal point lies outside the photo, or no factor up to 64 gives a view
            that fits.
    """
    if distortion.is_identity:
        return k_photo
    if not (0.5 <= k_photo.cx <= k_photo.width - 0.5 and 0.5 <= k_photo.cy <= k_photo.height - 0.5):
        raise DistortionError(f"the principal point ({k_photo.cx:g}, {k_photo.cy:g}) lies outside the photo's "
                              "pixel centres; no pinhole view around it fits inside the photo")
    probe = _probe_uv(k_photo.width, k_photo.height)
    radius = np.hypot((probe[:, 0] - k_photo.cx) / k_photo.fx, (probe[:, 1] - k_photo.cy) / k_photo.fy).max()
    widest = max(radius / math.tan(math.radians(_MAX_OFF_AXIS_DEG)), 1.0 / _SCALE_LIMIT)

    def fits(scale: float) -> bool:
        return _view_fits(k_photo, distortion, _pinhole(k_photo, scale), probe)

    if fits(widest):
        return _pinhole(k_photo, widest)
    lo, hi = widest, 1.0
    while not fits(hi):
        lo, hi = hi, 2.0 * hi
        if hi > _SCALE_LIMIT:
            raise DistortionError("no pinhole view up to 64 times the focal length fits inside the photo "
                                  "where the lens does not fold; check the coefficients")
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return _pinhole(k_photo, hi)


def photo_coverage(k_photo: Intrinsics, distortion: Distortion, k_pinhole: Intrinsics) -> float:
    """The share of a photo that its pinhole view samples.

    Args:
        k_photo: the photo's intrinsics.
        distortion: its lens distortion.
        k_pinhole: the pinhole camera it is resampled onto (:func:`undistorted_intrinsics`), same size.

    Returns:
        The area, in photo pixels, enclosed by where the pinhole view's border pixel centres land in the photo,
        over the area ``(W - 1) x (H - 1)`` enclosed by the photo's own border pixel centres: 1 for an identity
        distortion, less where the pinhole view crops the photo (as it does wherever a barrel lens's corners
        bend inwards: 0.96 for ``k1 = -0.1`` on a 640x480 photo with a 500-pixel focal length); NaN for a photo one
        pixel across.

    Example:
        >>> k = Intrinsics(500, 500, 320, 240, 640, 480)
        >>> round(photo_coverage(k, Distortion("opencv", (0, 0, 0, 0, 0)), k), 6)
        1.0
    """
    if k_pinhole.size != k_photo.size:
        raise ValueError(f"photo_coverage: sizes differ, {k_pinhole.size} and {k_photo.size}")
    width, height = k_photo.width, k_photo.height
    if width < 2 or height < 2:
        return float("nan")
    us, vs = np.arange(width) + 0.5, np.arange(height) + 0.5
    border = np.concatenate([  # the pinhole view's outermost pixel centres, once round, clockwise on screen
        np.stack([us, np.full(width, 0.5)], 1), np.stack([np.full(height, width - 0.5), vs], 1),
        np.stack([us[::-1], np.full(width, height - 0.5)], 1), np.stack([np.full(height, 0.5), vs[::-1]], 1),
    ])
    uv = distort_pixels(border, k_pinhole, k_photo, distortion)
    u, v = uv[:, 0], uv[:, 1]
    area = 0.5 * abs(float(np.dot(u, np.roll(v, -1)) - np.dot(v, np.roll(u, -1))))   # shoelace
    return area / ((width - 1) * (height - 1))


def _check_maps(map_x: np.ndarray, map_y: np.ndarray, k_photo: Intrinsics) -> None:
    """``DistortionError`` unless the maps (OpenCV pixels) stay on the photo's pixel centres and do not fold."""
    if not _on_centres(map_x + 0.5, map_y + 0.5, k_photo, _MAP_TOL):
        raise DistortionError("a pinhole pixel samples outside the photo")
    height, width = map_x.shape
    if height == 1 or width == 1:  # one row or column: the one coordinate along it must increase
        along = map_x.ravel() if height == 1 else map_y.ravel()
        folded = width * height > 1 and not np.all(np.diff(along) > 0.0)
    else:
        folded = False
        for r0 in range(0, height - 1, 512):  # rows in chunks: no full-size temporaries
            xs, ys = map_x[r0:r0 + 513], map_y[r0:r0 + 513]
            dxu, dyu = np.diff(xs, axis=1)[:-1], np.diff(ys, axis=1)[:-1]
            dxv, dyv = np.diff(xs, axis=0)[:, :-1], np.diff(ys, axis=0)[:, :-1]
            if not np.all(dxu * dyv - dxv * dyu > 0.0):
                folded = True
                break
    if folded:
        raise DistortionError("the distortion folds the image over itself (not invertible over the image)")


def undistortion_maps(k_photo: Intrinsics, distortion: Distortion, k_pinhole: Intrinsics) -> tuple:
    """Sampling maps for :func:`cv2.remap`: where each pinhole pixel lies in the photo.

    Args:
        k_photo: the photo's intrinsics.
        distortion: its lens distortion.
        k_pinhole: the target pinhole camera (usually :func:`undistorted_intrinsics`), same size.

    Returns:
        ``(map_x, map_y)``, each ``(H, W)`` float32 in OpenCV's pixel convention.

    Raises:
        DistortionError: a pinhole pixel samples outside the photo's pixel centres, or the mapping folds (its
            Jacobian determinant is not positive everywhere: the distortion is not invertible over the view).
    """
    if k_pinhole.size != k_photo.size:
        raise ValueError(f"undistortion_maps: sizes differ, {k_pinhole.size} and {k_photo.size}")
    size = (k_photo.width, k_photo.height)
    coeffs = np.asarray(distortion.coeffs, np.float64)
    if distortion.model == "fisheye":
        map_x, map_y = cv2.fisheye.initUndistortRectifyMap(_cv_K(k_photo), coeffs, np.eye(3), _cv_K(k_pinhole),
                                                           size, cv2.CV_32FC1)
    else:
        map_x, map_y = cv2.initUndistortRectifyMap(_cv_K(k_photo), coeffs, None, _cv_K(k_pinhole), size,
                                                   cv2.CV_32FC1)
    _check_maps(map_x, map_y, k_photo)
    return map_x, map_y


def undistort_image(img: np.ndarray, maps: tuple) -> np.ndarray:
    """Resample a photo onto its pinhole camera (bilinear).

    Args:
        img: ``(H, W, 3)`` float32 colour or ``(H, W, 4)`` straight RGBA, values in ``[0, 1]``.
        maps: ``(map_x, map_y)`` from :func:`undistortion_maps`, each ``(H', W')``.

    Returns:
        ``(H', W', C)`` float32 in ``[0, 1]``; RGBA stays straight (resampled premultiplied).
    """
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"undistort_image: expected (H, W, 3) or (H, W, 4), got {img.shape}")
    src = np.ascontiguousarray(img, np.float32)
    if src.shape[2] == 4:
        src = np.concatenate([src[..., :3] * src[..., 3:], src[..., 3:]], axis=2)
    out = cv2.remap(src, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = np.clip(out, 0.0, 1.0)
    if out.shape[2] == 4:
        a = out[..., 3:]
        np.divide(out[..., :3], a, out=out[..., :3], where=a > 0.0)
        out[..., :3] *= a > 0.0
        np.clip(out, 0.0, 1.0, out=out)
    return out


def _why_cropped(k_photo: Intrinsics, distortion: Distortion, k_pinhole: Intrinsics) -> str:
    """What stopped :func:`undistorted_intrinsics` from widening ``k_pinhole``: the 80-degree cap, the lens model's
    fold (a view a millionth wider lands on the photo but folds), or the photo's border."""
    probe = _probe_uv(k_pinhole.width, k_pinhole.height)
    off_axis = np.hypot((probe[:, 0] - k_pinhole.cx) / k_pinhole.fx, (probe[:, 1] - k_pinhole.cy) / k_pinhole.fy)
    if math.degrees(math.atan(off_axis.max())) > _MAX_OFF_AXIS_DEG - 1e-6:
        return "the lens sees wider than a pinhole view can hold (160 degrees across), as a circular fisheye does"
    wider = _pinhole(k_photo, k_pinhole.fx / k_photo.fx * (1.0 - 1e-6))
    on_photo = distort_pixels(probe, wider, k_photo, distortion)
    if _on_centres(on_photo[:, 0], on_photo[:, 1], k_photo, 1e-9):
        return ("its lens model folds back inside the photo, and the view stops at the fold; check the "
                "coefficients' signs and scale")
    return "the widest pinhole view inside the photo is that narrow; check the coefficients"


class Undistorter:
    """The loaders' ``prepare`` for :func:`senerf.data._io.load_images`: undistorts each view's photo as it is
    decoded and records the pinhole camera it was resampled onto.

    Args:
        entries: one dict per view with ``distortion`` (:class:`Distortion` or ``None``), and for error
            messages ``path`` (the image), ``file`` and ``distortion_field`` (where the distortion was given;
            ``distortion_file`` when that is not ``file``).
        photo_camera: ``photo_camera(entry, height, width) -> Intrinsics``, the photo's camera at its decoded
            size.

    After loading, :meth:`cameras` gives every view's camera (``pinhole`` maps each undistorted view's index
    to its pinhole camera, decoded size).  The
    sampling maps of the last few cameras are kept, so frames sharing a camera compute them once.
    """

    def __init__(self, entries: list, photo_camera) -> None:
        self.entries = entries
        self.photo_camera = photo_camera
        self.pinhole = {}
        self._maps = OrderedDict()  # (k_photo, distortion) -> (k_pinhole, maps)
        self._warned = False   # one coverage warning per load

    def _camera(self, e: dict, k_photo: Intrinsics) -> tuple:
        key = (k_photo, e["distortion"])
        if key in self._maps:
            self._maps.move_to_end(key)
            return self._maps[key]
        try:
            k_pinhole = undistorted_intrinsics(k_photo, e["distortion"])
            entry = (k_pinhole, undistortion_maps(k_photo, e["distortion"], k_pinhole))
        except DistortionError as exc:
            raise InputError(f"cannot undistort {e['path'].name}: {exc}", file=e.get("distortion_file", e["file"]),
                             field=e["distortion_field"]) from None
        self._warn_coverage(e, k_photo, k_pinhole)
        self._maps[key] = entry
        while len(self._maps) > _MAPS_KEPT:
            self._maps.popitem(last=False)
        return entry

    def _warn_coverage(self, e: dict, k_photo: Intrinsics, k_pinhole: Intrinsics) -> None:
        """Warn (once per load) when the first photo's pinhole view keeps less than :data:`COVERAGE_WARN` of it."""
        if self._warned:
            return
        share = photo_coverage(k_photo, e["distortion"], k_pinhole)
        if not share < COVERAGE_WARN:
            return
        self._warned = True
        warnings.warn(f"{e.get('distortion_file', e['file'])}: undistorting {e['path'].name} keeps {share:.0%} of "
                      f"the photo ({e['distortion_field']}: {e['distortion'].model} {tuple(e['distortion'].coeffs)}); "
                      f"{_why_cropped(k_photo, e['distortion'], k_pinhole)}", stacklevel=4)

    def cameras(self, height: int, width: int) -> list:
        """After loading: each view's camera at the decoded size ``(height, width)``, the pinhole one where the
        photo was undistorted, its own elsewhere."""
        return [self.pinhole[k] if k in self.pinhole else self.photo_camera(e, height, width)
                for k, e in enumerate(self.entries)]

    def __call__(self, k: int, img: np.ndarray) -> np.ndarray:
        e = self.entries[k]
        if e["distortion"] is None:
            return img
        k_pinhole, maps = self._camera(e, self.photo_camera(e, img.shape[0], img.shape[1]))
        self.pinhole[k] = k_pinhole
        return undistort_image(img, maps)
