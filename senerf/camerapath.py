"""Camera path files: keyframes ``senerf-view`` saves and ``senerf-render --path FILE`` replays (no torch).

Two formats are read:

- **senerf's** (written by :func:`write_camera_path`)::

      {"senerf_camera_path": 1, "fps": 20.0, "frames": 60,
       "keyframes": [{"c2w": [[...4 rows...]], "intrinsics": [fx, fy, cx, cy, width, height]}, ...]}

  The keyframes are interpolated into ``frames`` frames (:func:`senerf.geometry.keyframe_path`; the intrinsics
  linearly).
- **nerfstudio's** ``camera_path.json`` (its viewer's "export path"): ``render_width``, ``render_height``, ``fps`` and
  the dense ``camera_path`` list of ``camera_to_world`` (16 numbers, row-major, OpenGL axes) and ``fov`` (vertical,
  degrees); its frames are replayed as they are unless a frame count is asked for.  nerfstudio writes its poses in
  the frame of its own data parser (which recentres and rescales a capture); they are read as poses in the scene's
  world frame, so a path saved by nerfstudio's viewer replays faithfully only where that frame is the scene's.

Convention: poses are OpenCV camera-to-world (x right, y down, z forward) in the scene's world frame; intrinsics
are in pixels with pixel centres at ``i + 0.5``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from senerf.errors import InputError, is_number

__all__ = ["CameraPath", "read_camera_path", "write_camera_path", "CAMERA_PATH_FORMAT"]

#: The version of senerf's camera path format (its ``senerf_camera_path`` key).
CAMERA_PATH_FORMAT = 1
_FRAMES_DEFAULT = 60
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


class CameraPath(NamedTuple):
    """Frames to render: ``c2w (n, 4, 4)`` float64 OpenCV camera-to-world, ``intrinsics`` (``n``
    :class:`senerf.geometry.Intrinsics`, one image size) and the path's ``fps``."""

    c2w: np.ndarray
    intrinsics: tuple
    fps: float


def write_camera_path(path, key_c2w, intrinsics, fps: float = 20.0, frames: int = _FRAMES_DEFAULT) -> Path:
    """Write keyframes as a senerf camera path file, atomically (a killed write leaves the old file or none).

    Args:
        path: the ``.json`` file to write.
        key_c2w: ``(k, 4, 4)`` OpenCV camera-to-world keyframes, ``k >= 1``.
        intrinsics: one :class:`senerf.geometry.Intrinsics` for every keyframe, or ``k`` of one image size.
        fps, frames: the frame rate and frame count the replay renders.

    Raises:
        ValueError: keyframes that are not ``(k, 4, 4)`` finite poses, or intrinsics of another count or size.
    """
    from senerf.atomic import atomic_write_bytes
    from senerf.geometry import Intrinsics

    keys = np.asarray(key_c2w, dtype=np.float64)
    if keys.ndim != 3 or keys.shape[1:] != (4, 4) or len(keys) < 1 or not np.isfinite(keys).all():
        raise ValueError(f"key_c2w: expected finite (k, 4, 4) poses with k >= 1, got shape {keys.shape}")
    ks = (intrinsics,) * len(keys) if isinstance(intrinsics, Intrinsics) else tuple(intrinsics)
    if len(ks) != len(keys) or len({k.size for k in ks}) != 1:
        raise ValueError(f"intrinsics: expected one or {len(keys)} of one image size, got {len(ks)}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1 or not fps > 0:
        raise ValueError(f"expected frames >= 1 and fps > 0, got {frames!r} and {fps!r}")
    doc = dict(senerf_camera_path=CAMERA_PATH_FORMAT, fps=float(fps), frames=int(frames),
               convention="OpenCV camera-to-world (x right, y down, z forward), the scene's world frame; intrinsics "
                          "fx, fy, cx, cy, width, height in pixels (pixel centres at i + 0.5)",
               keyframes=[dict(c2w=c.tolist(), intrinsics=[k.fx, k.fy, k.cx, k.cy, k.width, k.height])
                          for c, k in zip(keys, ks)])
    atomic_write_bytes(Path(path), (json.dumps(doc, indent=1) + "\n").encode())
    return Path(path)


def read_camera_path(path, frames: int | None = None) -> CameraPath:
    """The frames of a camera path file (senerf's or nerfstudio's; module docstring).

    Args:
        path: the ``.json`` file.
        frames: how many frames to render through the path's poses (default: the file's ``frames`` for senerf's
            format, the listed frames for nerfstudio's).

    Raises:
        InputError: not readable, or not a camera path of either format, naming the file and the field.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError("not found", file=path) from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"cannot be read as JSON ({exc})", file=path) from None
    if isinstance(doc, dict) and "senerf_camera_path" in doc:
        if doc["senerf_camera_path"] != CAMERA_PATH_FORMAT:
            raise InputError(f"is a camera path of another senerf version (format {doc['senerf_camera_path']!r}, "
                             f"this version reads {CAMERA_PATH_FORMAT})", file=path, field="senerf_camera_path")
        keys, ks = _senerf_keyframes(doc, path)
        fps, count = doc.get("fps", 20.0), doc.get("frames", _FRAMES_DEFAULT) if frames is None else frames
    elif isinstance(doc, dict) and "camera_path" in doc:
        keys, ks = _nerfstudio_frames(doc, path)
        fps, count = doc.get("fps", 24.0), len(keys) if frames is None else frames
    else:
        raise InputError("is neither a senerf camera path (no 'senerf_camera_path') nor a nerfstudio one (no "
                         "'camera_path')", file=path)
    if not (is_number(fps) and 0 < fps <= 1000):
        raise InputError(f"expected a frame rate in (0, 1000], got {fps!r}", file=path, field="fps")
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 100000:
        raise InputError(f"expected a frame count from 1 to 100000, got {count!r}", file=path, field="frames")
    return _interpolate(keys, ks, count, float(fps))


def _interpolate(keys: np.ndarray, ks: list, count: int, fps: float) -> CameraPath:
    from senerf.geometry import Intrinsics, keyframe_path

    if count == len(keys) and len(keys) > 1:   # the frames as listed (keyframe_path would give the same poses)
        return CameraPath(keys, tuple(ks), fps)
    s = np.linspace(0.0, len(keys) - 1, count) if count > 1 else np.zeros(1)
    params = np.array([[k.fx, k.fy, k.cx, k.cy] for k in ks], dtype=np.float64)
    lerp = np.stack([np.interp(s, np.arange(len(ks)), params[:, j]) for j in range(4)], axis=-1)
    w, h = ks[0].width, ks[0].height
    return CameraPath(keyframe_path(keys, count), tuple(Intrinsics(*row, w, h) for row in lerp), fps)


def _pose(value, path: Path, field: str) -> np.ndarray:
    """A 4x4 rigid pose from ``value`` (4 rows of 4, or 16 numbers row-major)."""
    arr = np.asarray(value, dtype=object)
    if arr.size != 16 or not all(is_number(v) for v in arr.reshape(-1)):
        raise InputError("expected a 4x4 matrix of numbers", file=path, field=field)
    pose = arr.astype(np.float64).reshape(4, 4)
    rot = pose[:3, :3]
    if not (np.isfinite(pose).all() and np.allclose(pose[3], (0, 0, 0, 1), atol=1e-6)
            and np.allclose(rot @ rot.T, np.eye(3), atol=1e-3) and np.linalg.det(rot) > 0):
        raise InputError("expected a rigid camera-to-world pose (a rotation, a translation, last row 0 0 0 1)",
                         file=path, field=field)
    return pose


def _size(doc: dict, keys: tuple, path: Path) -> tuple[int, int]:
    values = [doc.get(k) for k in keys]
    for key, v in zip(keys, values):
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 16384:
            raise InputError(f"expected a whole number of pixels from 1 to 16384, got {v!r}", file=path, field=key)
    return values[0], values[1]


def _frames(rows, key: str, path: Path, members: str, parse) -> tuple[np.ndarray, list]:
    """``(c2w (n, 4, 4), n intrinsics)`` of the non-empty list ``rows`` (the file's ``key``), each object read by
    ``parse(row, field) -> (c2w (4, 4), Intrinsics)``; ``members`` names what an object holds, for the error."""
    if not isinstance(rows, list) or not rows:
        raise InputError("expected a non-empty list", file=path, field=key)
    keys, ks = [], []
    for i, row in enumerate(rows):
        field = f"{key}[{i}]"
        if not isinstance(row, dict):
            raise InputError(f"expected an object with {members}", file=path, field=field)
        c2w, k = parse(row, field)
        keys.append(c2w)
        ks.append(k)
    return np.stack(keys), ks


def _senerf_keyframes(doc: dict, path: Path) -> tuple[np.ndarray, list]:
    from senerf.geometry import Intrinsics

    def parse(row: dict, field: str):
        c2w, k = _pose(row.get("c2w"), path, f"{field}.c2w"), row.get("intrinsics")
        if not (isinstance(k, list) and len(k) == 6 and all(is_number(v) for v in k)):
            raise InputError("expected [fx, fy, cx, cy, width, height]", file=path, field=f"{field}.intrinsics")
        w, h = _size(dict(width=k[4], height=k[5]), ("width", "height"), path)
        try:
            return c2w, Intrinsics(*map(float, k[:4]), w, h)
        except ValueError as exc:
            raise InputError(str(exc), file=path, field=f"{field}.intrinsics") from None

    keys, ks = _frames(doc.get("keyframes"), "keyframes", path, "'c2w' and 'intrinsics'", parse)
    if len({k.size for k in ks}) != 1:
        raise InputError("expected one image size for all keyframes", file=path, field="keyframes")
    return keys, ks


def _nerfstudio_frames(doc: dict, path: Path) -> tuple[np.ndarray, list]:
    from senerf.geometry import Intrinsics

    w, h = _size(doc, ("render_width", "render_height"), path)

    def parse(row: dict, field: str):
        fov = row.get("fov")
        if not (is_number(fov) and 0 < fov < 180):
            raise InputError(f"expected a vertical field of view in degrees, in (0, 180), got {fov!r}", file=path,
                             field=f"{field}.fov")
        f = 0.5 * h / math.tan(math.radians(fov) / 2.0)
        c2w = _pose(row.get("camera_to_world"), path, f"{field}.camera_to_world") @ _GL_TO_CV
        return c2w, Intrinsics(f, f, w / 2.0, h / 2.0, w, h)

    return _frames(doc["camera_path"], "camera_path", path, "'camera_to_world' and 'fov'", parse)
