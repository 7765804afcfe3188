"""Lens undistortion at the loaders' edge: a photo taken through a distorting lens is resampled once, at load,
onto a pinhole camera (:class:`senerf.geometry.Intrinsics`) at the same pose, as every camera downstream is.

Two models are understood, those the instant-ngp / nerfstudio ``transforms.json`` writers emit:

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
from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import Intrinsics

__all__ = ["Distortion", "distort_pixels", "undistorted_intrinsics", "undistortion_maps", "undistort_image",
           "photo_coverage", "resample_premultiplied", "DistortionError", "PERSPECTIVE_MODELS", "FISHEYE_MODELS",
           "COVERAGE_WARN"]

#: COLMAP's camera model names senerf reads: pinholes and OpenCV's radial-tangential family, then the fisheyes.
PERSPECTIVE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
FISHEYE_MODELS = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE")

_N_COEFFS = {"opencv": 5, "fisheye": 4}
# The focal search keeps every border sample within the photo's pixel centres exactly; the full float32 maps may
# then fall this far (pixels) outside them, float32's rounding at 10^4 pixels being 1e-3.
_MAP_TOL = 1e-2
#: A photo whose pinhole view keeps less than this share of it (:func:`photo_coverage`) is warned about at load.
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


def distort_pixels(uv: np.ndarray, k_pinhole: Intrinsics, k_photo: Intrinsics, distortion: Distortion) -> np.ndarray:
    """Where pinhole pixels land in the distorted photo.

    Args:
        uv: ``(..., 2)`` pixel positions of the pinhole camera ``k_pinhole`` (:class:`Intrinsics` convention).
        k_photo, distortion: the photo's intrinsics (principal point and focal before distortion) and lens distortion.

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
    xy1 = np.stack([(flat[:, 0] - k_pinhole.cx) / k_pinhole.fx, (flat[:, 1] - k_pinhole.cy) / k_pinhole.fy,
                    np.ones(len(flat))], axis=1).reshape(1, -1, 3)
    project = cv2.fisheye.projectPoints if distortion.model == "fisheye" else cv2.projectPoints
    out, _ = project(xy1, np.zeros(3), np.zeros(3), _cv_K(k_photo), np.asarray(distortion.coeffs, np.float64))
    return (out.reshape(-1, 2) + 0.5).reshape(uv.shape)


def _border_uv(width: int, height: int) -> np.ndarray:
    """The outermost pixel centres of a ``width x height`` image, once round, clockwise on screen, ``(n, 2)``."""
    us, vs = np.arange(width) + 0.5, np.arange(height) + 0.5
    return np.concatenate([
        np.stack([us, np.full(width, 0.5)], 1), np.stack([np.full(height, width - 0.5), vs], 1),
        np.stack([us[::-1], np.full(width, height - 0.5)], 1), np.stack([np.full(height, 0.5), vs[::-1]], 1),
    ])


def _pinhole(k_photo: Intrinsics, scale: float) -> Intrinsics:
    return Intrinsics(k_photo.fx * scale, k_photo.fy * scale, k_photo.cx, k_photo.cy, k_photo.width, k_photo.height)


def _on_centres(u: np.ndarray, v: np.ndarray, k: Intrinsics, tol: float) -> bool:
    """True when every ``(u, v)`` lies within the photo's outermost pixel centres, ``[0.5, W - 0.5] x
    [0.5, H - 0.5]`` of ``k``, give or take ``tol``: bilinear sampling there never reaches past the photo."""
    return bool(np.all(np.isfinite(u)) and np.all(np.isfinite(v))
                and u.min() >= 0.5 - tol and v.min() >= 0.5 - tol
                and u.max() <= k.width - 0.5 + tol and v.max() <= k.height - 0.5 + tol)


def undistorted_intrinsics(k_photo: Intrinsics, distortion: Distortion) -> Intrinsics:
    """The pinhole camera a distorted photo is resampled onto (module docstring).

    Returns:
        ``k_photo`` itself for an identity distortion; otherwise the module docstring's pinhole, its focal factor
        found by bisection (~1e-12 relative) on the border pixels and a 17 x 17 grid inside.  A lens that sees
        wider still (a fisheye beyond 160 degrees) gets the view whose corners are 80 degrees off axis.

    Raises:
        DistortionError: the principal point lies outside the photo, or no factor up to 64 gives a view that fits.
    """
    if distortion.is_identity:
        return k_photo
    if not (0.5 <= k_photo.cx <= k_photo.width - 0.5 and 0.5 <= k_photo.cy <= k_photo.height - 0.5):
        raise DistortionError(f"the principal point ({k_photo.cx:g}, {k_photo.cy:g}) lies outside the photo's "
                              "pixel centres; no pinhole view around it fits inside the photo")
    gu, gv = np.meshgrid(np.linspace(0.5, k_photo.width - 0.5, 17), np.linspace(0.5, k_photo.height - 0.5, 17))
    probe = np.concatenate([_border_uv(k_photo.width, k_photo.height), np.stack([gu.ravel(), gv.ravel()], 1)])
    radius = np.hypot((probe[:, 0] - k_photo.cx) / k_photo.fx, (probe[:, 1] - k_photo.cy) / k_photo.fy).max()
    widest = max(radius / math.tan(math.radians(80.0)), 1.0 / 64.0)   # a pinhole image cannot hold a hemisphere
    h, n = 1e-3, len(probe)
    shifted = np.concatenate([probe + step for step in ((0.0, 0.0), (h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h))])

    def fits(scale: float) -> bool:
        """Whether the probe pixels of the pinhole at ``scale`` land on the photo where the lens does not fold
        (the Jacobian determinant of pinhole pixel -> photo pixel, by central differences of ``h``, is positive)."""
        uv = distort_pixels(shifted, _pinhole(k_photo, scale), k_photo, distortion)
        p0, pu, pv = uv[:n], uv[n:2 * n] - uv[2 * n:3 * n], uv[3 * n:4 * n] - uv[4 * n:]
        det = pu[:, 0] * pv[:, 1] - pv[:, 0] * pu[:, 1]
        return _on_centres(p0[:, 0], p0[:, 1], k_photo, 1e-9) and bool(np.all(det > 0.0))

    if fits(widest):
        return _pinhole(k_photo, widest)
    lo, hi = widest, 1.0
    while not fits(hi):
        lo, hi = hi, 2.0 * hi
        if hi > 64.0:
            raise DistortionError("no pinhole view up to 64 times the focal length fits inside the photo "
                                  "where the lens does not fold; check the coefficients")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return _pinhole(k_photo, hi)


def photo_coverage(k_photo: Intrinsics, distortion: Distortion, k_pinhole: Intrinsics) -> float:
    """The share of a photo that its pinhole view samples.

    Args:
        k_pinhole: the pinhole camera it is resampled onto (:func:`undistorted_intrinsics`), same size.

    Returns:
        The area enclosed by where the pinhole view's border pixel centres land in the photo, over the area
        ``(W - 1) x (H - 1)`` they enclose in the pinhole view: 1 for an identity distortion, less where the pinhole
        view crops the photo (a barrel lens's corners); NaN for a photo one pixel across.

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
    u, v = distort_pixels(_border_uv(width, height), k_pinhole, k_photo, distortion).T
    area = 0.5 * abs(float(np.dot(u, np.roll(v, -1)) - np.dot(v, np.roll(u, -1))))   # shoelace
    return area / ((width - 1) * (height - 1))


def undistortion_maps(k_photo: Intrinsics, distortion: Distortion, k_pinhole: Intrinsics) -> tuple:
    """Sampling maps for :func:`cv2.remap`: where each pinhole pixel lies in the photo.

    Args:
        k_pinhole: the target pinhole camera (usually :func:`undistorted_intrinsics`), same size.

    Returns:
        ``(map_x, map_y)``, each ``(H, W)`` float32 in OpenCV's pixel convention.

    Raises:
        DistortionError: a pinhole pixel samples outside the photo's pixel centres, or the mapping folds (its
            Jacobian determinant is not positive everywhere: the distortion is not invertible over the view).
    """
    if k_pinhole.size != k_photo.size:
        raise ValueError(f"undistortion_maps: sizes differ, {k_pinhole.size} and {k_photo.size}")
    init = cv2.fisheye.initUndistortRectifyMap if distortion.model == "fisheye" else cv2.initUndistortRectifyMap
    map_x, map_y = init(_cv_K(k_photo), np.asarray(distortion.coeffs, np.float64), np.eye(3), _cv_K(k_pinhole),
                        (k_photo.width, k_photo.height), cv2.CV_32FC1)
    if not _on_centres(map_x + 0.5, map_y + 0.5, k_photo, _MAP_TOL):
        raise DistortionError("a pinhole pixel samples outside the photo")
    for r0 in range(0, map_x.shape[0] - 1, 512):   # the Jacobian determinant, in chunks of rows (small temporaries)
        xs, ys = map_x[r0:r0 + 513], map_y[r0:r0 + 513]
        dxu, dyu = np.diff(xs, axis=1)[:-1], np.diff(ys, axis=1)[:-1]
        dxv, dyv = np.diff(xs, axis=0)[:, :-1], np.diff(ys, axis=0)[:, :-1]
        if not np.all(dxu * dyv - dxv * dyu > 0.0):
            raise DistortionError("the distortion folds the image over itself (not invertible over the image)")
    return map_x, map_y


def undistort_image(img: np.ndarray, maps: tuple) -> np.ndarray:
    """Resample a photo onto its pinhole camera (bilinear).

    Args:
        img: ``(H, W, 3)`` float32 colour or ``(H, W, 4)`` straight RGBA, values in ``[0, 1]``.
        maps: ``(map_x, map_y)`` from :func:`undistortion_maps`, each ``(H', W')``.

    Returns:
        ``(H', W', C)`` float32 in ``[0, 1]``; RGBA stays straight (:func:`resample_premultiplied`).
    """
    return resample_premultiplied(img, lambda src: cv2.remap(src, maps[0], maps[1], interpolation=cv2.INTER_LINEAR,
                                                             borderMode=cv2.BORDER_REPLICATE))


def resample_premultiplied(img: np.ndarray, resample) -> np.ndarray:
    """``resample(img)`` clipped to ``[0, 1]``: float32 colour ``(H, W, 3)`` as it is, straight RGBA ``(H, W, 4)``
    premultiplied before and straight again after (colour 0 where the new alpha is 0), so that compositing the
    result equals resampling the composited image (no dark fringes).  ``resample`` maps an image to a new one."""
    src = np.ascontiguousarray(img, np.float32)
    if src.shape[2] == 3:
        return np.clip(resample(src), 0.0, 1.0)
    out = np.clip(resample(np.concatenate([src[..., :3] * src[..., 3:], src[..., 3:]], axis=2)), 0.0, 1.0)
    a = out[..., 3:]
    np.divide(out[..., :3], a, out=out[..., :3], where=a > 0.0)
    out[..., :3] *= a > 0.0
    return np.clip(out, 0.0, 1.0, out=out)
