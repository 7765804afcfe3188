"""Pinhole camera intrinsics.

Convention:
    Pixel ``(i, j)`` (column ``i``, row ``j``) covers ``[i, i+1) x [j, j+1)``, its centre is ``(i + 0.5, j + 0.5)``
    and ``(cx, cy)`` lies in that system (DESIGN.md), so resizing an image by ``s`` is exactly
    ``K' = diag(s, s, 1) K``.  OpenCV puts the centre of pixel 0 at 0.0: subtract 0.5 from ``cx, cy`` (or from
    ``uv``) when handing them to ``cv2``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

__all__ = ["Intrinsics"]


def _positive_finite(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"Intrinsics.{name}: expected a real number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"Intrinsics.{name}: must be positive and finite, got {value!r}")
    return v


def _size(value, name: str) -> int:
    whole = isinstance(value, numbers.Integral) or (isinstance(value, numbers.Real) and math.isfinite(float(value))
                                                    and float(value).is_integer())   # 800.0 from a JSON file
    if isinstance(value, (bool, np.bool_)) or not whole:
        raise ValueError(f"Intrinsics.{name}: expected an integer >= 1, got {value!r}")
    v = int(value)
    if v < 1:
        raise ValueError(f"Intrinsics.{name}: must be >= 1, got {value!r}")
    return v


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a ``width x height`` image (no distortion).

    Args:
        fx, fy: focal lengths in pixels, positive and finite.
        cx, cy: principal point in pixels (module convention), positive and finite (one on or beyond the
            top/left edge is almost always a convention error).
        width, height: image size in pixels, integers ``>= 1``.

    Raises:
        ValueError: naming the field that breaks one of these rules.

    Example:
        >>> k = Intrinsics(500.0, 500.0, 256.0, 256.0, 512, 512)
        >>> k.K.tolist()
        [[500.0, 0.0, 256.0], [0.0, 500.0, 256.0], [0.0, 0.0, 1.0]]
        >>> k.size
        (512, 512)
        >>> k.scaled(0.5).K[0].tolist()
        [250.0, 0.0, 128.0]
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, _positive_finite(getattr(self, name), name))
        for name in ("width", "height"):
            object.__setattr__(self, name, _size(getattr(self, name), name))

    @classmethod
    def from_fov(cls, fov_x_deg: float, width: int, height: int) -> "Intrinsics":
        """Square pixels, principal point ``(W/2, H/2)``, horizontal field of view ``fov_x_deg`` in (0, 180).

        ``f = 0.5 W / tan(0.5 fov_x)`` (Blender's ``camera_angle_x``, in degrees here).

        Example:
            >>> k = Intrinsics.from_fov(math.degrees(0.6911112070083618), 800, 800)
            >>> round(k.fx, 3)
            1111.111
        """
        fov = float(fov_x_deg)
        if not math.isfinite(fov) or not 0.0 < fov < 180.0:
            raise ValueError(f"Intrinsics.fov_x_deg: must be in (0, 180) degrees, got {fov_x_deg!r}")
        w = _size(width, "width")
        h = _size(height, "height")
        f = 0.5 * w / math.tan(0.5 * math.radians(fov))
        if not math.isfinite(f):   # a field of view so small that the focal length overflows
            raise ValueError(f"Intrinsics.fov_x_deg: {fov_x_deg!r} degrees gives an infinite focal length")
        return cls(f, f, 0.5 * w, 0.5 * h, w, h)

    @property
    def K(self) -> np.ndarray:
        """The ``(3, 3)`` float64 calibration matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """``(height, width)``, the order of image array shapes."""
        return (self.height, self.width)

    def scaled(self, factor: float) -> "Intrinsics":
        """Intrinsics of the image resized by ``factor`` (``0.5`` halves it): ``K' = diag(s, s, 1) K``.

        Raises:
            ValueError: a non-positive / non-finite factor, or a new size ``width * factor`` or ``height * factor``
                that is not whole (to 1e-9): :meth:`resized` scales each axis by its own exact ratio.
        """
        s = _positive_finite(factor, "scaled(factor)")
        w, h = self.width * s, self.height * s
        if abs(w - round(w)) > 1e-9 * max(1.0, w) or abs(h - round(h)) > 1e-9 * max(1.0, h):
            raise ValueError(
                f"Intrinsics.scaled: factor {factor!r} gives a non-integer size {w} x {h}; "
                "use resized(width, height) instead"
            )
        return Intrinsics(self.fx * s, self.fy * s, self.cx * s, self.cy * s, int(round(w)), int(round(h)))

    def resized(self, width: int, height: int) -> "Intrinsics":
        """Intrinsics of the image resized to exactly ``width x height`` (per-axis ratios ``W'/W``, ``H'/H``).

        Example:
            >>> Intrinsics(1111.0, 1111.0, 400.0, 400.0, 800, 800).resized(266, 266).cx
            133.0
        """
        w = _size(width, "width")
        h = _size(height, "height")
        sx, sy = w / self.width, h / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, w, h)
