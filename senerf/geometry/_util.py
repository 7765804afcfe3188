"""Private helpers of the geometry modules: dtypes (the rule is in the package docstring), argument checks,
rigid matrices and lengths safe at any scale."""

from __future__ import annotations

import numpy as np

from .intrinsics import Intrinsics


def as_float(x, name: str, dtype=None) -> np.ndarray:
    """``x`` as a float array (dtype by the package rule unless given); raises ``ValueError`` if not numeric."""
    try:
        arr = np.asarray(x)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise ValueError(f"{name}: cannot be converted to an array ({exc})") from None
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{name}: expected a real numeric array, got dtype {arr.dtype}")
    if dtype is None:
        dtype = np.float32 if arr.dtype == np.float32 else np.float64
    return arr.astype(dtype, copy=False)


def check_last(arr: np.ndarray, tail: tuple, name: str) -> None:
    """Raise ``ValueError`` unless ``arr.shape`` ends with ``tail`` (``None`` matches any size)."""
    n = len(tail)
    ok = arr.ndim >= n and all(t is None or s == t for s, t in zip(arr.shape[arr.ndim - n:], tail))
    if not ok:
        want = "(..., " + ", ".join("*" if t is None else str(t) for t in tail) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")


def check_pose(c2w, name: str = "c2w") -> np.ndarray:
    """Return ``c2w`` as a float array of shape ``(..., 4, 4)`` or ``(..., 3, 4)`` (shape check only)."""
    arr = as_float(c2w, name)
    if arr.ndim < 2 or arr.shape[-1] != 4 or arr.shape[-2] not in (3, 4):
        raise ValueError(f"{name}: expected shape (..., 4, 4) or (..., 3, 4), got {arr.shape}")
    return arr


def check_intrinsics(k, name: str = "intrinsics") -> None:
    """Raise ``ValueError`` unless ``k`` is an :class:`Intrinsics` (a ``K`` matrix is refused, not guessed)."""
    if not isinstance(k, Intrinsics):
        raise ValueError(f"{name}: expected an Intrinsics, got {type(k).__name__}")


def rigid_matrix(rot: np.ndarray, t: np.ndarray, dtype=np.float64) -> np.ndarray:
    """``(..., 4, 4)`` ``[[rot, t], [0, 0, 0, 1]]`` of ``rot (..., 3, 3)`` and ``t (..., 3)`` (batches broadcast)."""
    out = np.zeros(np.broadcast_shapes(rot.shape[:-2], t.shape[:-1]) + (4, 4), dtype=dtype)
    out[..., :3, :3] = rot
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def as_4x4(c2w: np.ndarray) -> np.ndarray:
    """``(..., 3, 4)`` poses completed with the row ``[0, 0, 0, 1]``; ``(..., 4, 4)`` returned as is."""
    if c2w.shape[-2] == 4:
        return c2w
    last = np.broadcast_to(np.array([0.0, 0.0, 0.0, 1.0], dtype=c2w.dtype), c2w.shape[:-2] + (1, 4))
    return np.concatenate([c2w, last], axis=-2)


def unit_and_norm(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors ``(..., 3)`` and lengths ``(...)`` of float64 ``v (..., 3)``, safe at any finite scale.

    Each row is divided by a power of two near its largest ``|v_i|`` (an exact division) before the norm is
    taken, so lengths whose squares underflow or overflow still give exact directions.  A zero row gives
    ``(0, 0)``; a length beyond the float64 range comes back ``inf`` with a finite direction.
    """
    scale = pow2_scale(v)
    scaled = v / scale
    n = np.linalg.norm(scaled, axis=-1, keepdims=True)
    with np.errstate(over="ignore"):
        length = (scale * n)[..., 0]
    return scaled / np.where(n > 0, n, 1.0), length


def pow2_scale(*vs: np.ndarray) -> np.ndarray:
    """``(..., 1)`` power of two within a factor 2 of the largest ``|entry|`` of the rows of ``vs``.

    Scaled rows have entries below 2 (1 for zero rows, which stay zero).  Dividing by a power of two is
    exact (barring subnormals), so differences of scaled rows keep every bit and cannot overflow.
    """
    peak = np.max([np.max(np.abs(v), axis=-1, keepdims=True) for v in vs], axis=0)
    _, exponent = np.frexp(peak)  # peak = m 2**exponent, m in [0.5, 1): 2**(exponent - 1) <= peak
    return np.where(peak > 0, np.ldexp(1.0, exponent - 1), 1.0)


def broadcast_batch(*named: tuple) -> tuple:
    """The broadcast of the batch shapes ``(name, shape)``, or a ValueError naming the arguments that clash."""
    try:
        return np.broadcast_shapes(*(shape for _, shape in named))
    except ValueError:
        what = " and ".join(f"{name} {tuple(shape)}" for name, shape in named)
        raise ValueError(f"batch shapes of {what} do not broadcast") from None
