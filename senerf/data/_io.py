"""Private input helpers of :mod:`senerf.data`: JSON fields, paths, poses, and decoding and loading photos.

Convention:
    Images come back as float32 in ``[0, 1]``: straight (not premultiplied) colour ``(H, W, 3)`` or straight
    RGBA ``(H, W, 4)``.  8-bit samples are divided by 255, 16-bit samples by 65535.  Downscaling and
    undistortion resample premultiplied colour (:func:`~senerf.data.undistort.resample_premultiplied`).
"""

from __future__ import annotations

import functools
import json
import math
import os
import warnings
from pathlib import Path, PureWindowsPath

import cv2
import numpy as np
from PIL import Image

from ..errors import InputError, is_number
from ..geometry import Intrinsics, is_rigid
from .undistort import (COVERAGE_WARN, Distortion, DistortionError, photo_coverage, resample_premultiplied,
                        undistort_image, undistorted_intrinsics, undistortion_maps)

__all__ = ["IMAGE_SUFFIXES", "read_json", "get_field", "as_number", "as_pose", "check_rigid",
           "norm_rel", "resolve_inside", "read_rgba", "target_size", "resize_area", "load_photos"]

#: File suffixes recognised as images (a Blender ``file_path`` without one of them gets ``.png``).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".bmp", ".tif", ".tiff", ".webp")

#: Pillow modes converted on reading (and ``P``, to RGB(A)); those in ``_AS_IS`` are read as stored, others refused.
_CONVERT = {"PA": "RGBA", "CMYK": "RGB", "YCbCr": "RGB", "RGBa": "RGBA", "La": "LA"}
_AS_IS = ("1", "L", "LA", "RGB", "RGBA", "F")


def read_json(path: Path) -> dict:
    """Parse a JSON file whose top level must be an object; ``InputError`` for missing/malformed files."""
    if not os.path.isfile(path):
        raise InputError("is not a file" if os.path.exists(path) else "file not found", file=path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise InputError(f"malformed JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})", file=path) from None
    except (OSError, ValueError, RecursionError) as exc:   # permissions, not UTF-8, nested too deeply
        raise InputError(f"cannot read ({exc})", file=path) from None
    if not isinstance(data, dict):
        raise InputError(f"top level must be a JSON object, got {type(data).__name__}", file=path)
    return data


def get_field(obj: dict, key: str, file: Path, field: str):
    """``obj[key]``, or ``InputError`` naming ``field`` when it is absent."""
    if key not in obj:
        raise InputError("missing field", file=file, field=field)
    return obj[key]


def as_number(value, file: Path, field: str, positive: bool = False, allow_string: bool = False) -> float:
    """A finite float from a JSON value (not a bool, not a string), positive when ``positive``; ``InputError``
    naming ``file`` and ``field`` otherwise.  ``allow_string``: also take a number written as a string
    (``"-0.05"``), as some converters write them."""
    if allow_string and isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if not is_number(value) or (positive and value <= 0):
        what = "a positive finite number" if positive else "a finite number"
        raise InputError(f"expected {what}, got {value!r:.40}", file=file, field=field)
    return float(value)


def as_pose(value, file: Path, field: str) -> np.ndarray:
    """A user camera-to-world matrix, a 4x4 or 3x4 nested list (3x4 gets the row ``0 0 0 1``), as ``(4, 4)``
    float64 checked finite and rigid.  The frame convention is *not* changed here; callers convert at their edge."""
    if not (isinstance(value, list) and len(value) in (3, 4) and all(
            isinstance(r, list) and len(r) == 4 and all(type(x) in (int, float) for x in r) for r in value)):
        raise InputError("expected a 4x4 (or 3x4) matrix of numbers, a list of rows", file=file, field=field)
    arr = np.asarray(value + [[0.0, 0.0, 0.0, 1.0]] * (4 - len(value)), dtype=np.float64)
    check_rigid(arr, file, field)
    return arr


def check_rigid(c2w: np.ndarray, file: Path, field: str) -> None:
    """``InputError`` unless the ``(4, 4)`` pose is finite and rigid, ``|R^T R - I| <= 1e-4``: rotations printed
    in float32 (error ~1e-6) pass, scaled or sheared matrices do not."""
    if not np.all(np.isfinite(c2w)):
        raise InputError("matrix contains NaN or inf", file=file, field=field)
    if not bool(is_rigid(c2w, atol=1e-4)):
        rot = c2w[:3, :3]
        err = np.abs(rot.T @ rot - np.eye(3)).max()
        raise InputError(f"not a rigid camera-to-world transform (max |R^T R - I| = {err:.3g}, det R = "
                         f"{np.linalg.det(rot):.4g}, last row {c2w[3].tolist()})", file=file, field=field)


def norm_rel(rel: str) -> str:
    """A relative path as one spelling: ``/``-separated (Windows separators too), ``.`` and ``..`` folded."""
    return os.path.normpath(rel.replace("\\", "/"))


def resolve_inside(root: Path, rel: str, file: Path, field: str) -> Path:
    """``root / rel`` after refusing absolute paths (POSIX or Windows) and paths that leave ``root``, lexically
    (``os.path.normpath``): symbolic links *inside* the scene folder are followed as usual."""
    if not isinstance(rel, str) or not rel.strip():
        raise InputError(f"expected a non-empty path string, got {rel!r}", file=file, field=field)
    if PureWindowsPath(rel).anchor:   # "/a", "\\a", "C:\\a" and "C:a" alike
        raise InputError(f"absolute path {rel!r} refused; paths must be relative to the scene folder",
                         file=file, field=field)
    norm = norm_rel(rel)
    if norm == ".." or norm.startswith("../"):
        raise InputError(f"path {rel!r} leaves the scene folder", file=file, field=field)
    if norm == ".":   # the folder itself (a loader adding a suffix would read its sibling <folder>.png)
        raise InputError(f"path {rel!r} names the folder itself, not a file in it", file=file, field=field)
    return root / norm


def _decode(path: Path) -> np.ndarray:
    """The samples of an image file as stored, ``(H, W)`` or ``(H, W, C)`` in RGB(A) order: by Pillow, or by OpenCV
    for 16-bit samples (Pillow truncates 16-bit colour to 8 bits; it checks the file first, so that libpng inside
    OpenCV prints nothing on a corrupt one).  The EXIF orientation is not applied, as COLMAP does not."""
    with Image.open(path) as im:
        tile = getattr(im, "tile", None)   # how the file stores its samples: "RGB;16B" for 16-bit colour
        if im.mode.startswith("I;16") or (tile and ";16" in str(tile[0][3])):
            im.verify()
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise ValueError("OpenCV could not decode it")
            return img[..., [2, 1, 0, 3][: img.shape[2]]] if img.ndim == 3 else img   # BGR(A) -> RGB(A)
        if im.mode == "P":
            im = im.convert("RGBA" if "transparency" in im.info else "RGB")
        elif im.mode in _CONVERT:
            im = im.convert(_CONVERT[im.mode])
        elif im.mode not in _AS_IS:
            raise ValueError(f"Pillow mode {im.mode!r} is not read; save it as 8- or 16-bit RGB(A) or grey")
        return np.asarray(im)


def read_rgba(path: Path, field: str, file: Path | None = None, clipped: list | None = None) -> np.ndarray:
    """Decode one image to float32 ``(H, W, 3)`` (no alpha) or ``(H, W, 4)`` straight RGBA in ``[0, 1]`` (module
    docstring); grey is expanded to three equal channels, grey+alpha becomes RGBA.

    Args:
        field: the field that named it (``"frames[3].file_path"``), for error messages.
        file: the file that named it (a JSON); defaults to ``path``.
        clipped: float samples outside ``[0, 1]`` are clipped, and a line saying so is appended here when given
            (:func:`load_photos` warns once for all its photos).

    Raises:
        InputError: missing, unreadable or corrupt file, OpenEXR, unsupported mode or sample type, NaN/inf.
    """
    file = path if file is None else file
    if not os.path.isfile(path):
        raise InputError(f"image not found: {path}", file=file, field=field)
    if path.suffix.lower() == ".exr":
        raise InputError(f"cannot read image {path}: OpenEXR is not read; convert it to a 16-bit PNG or TIFF",
                         file=file, field=field)
    try:
        img = _decode(path)
    except Exception as exc:  # the decoders raise many types; an OSError with an errno is the file itself
        why = exc.strerror if isinstance(exc, OSError) and exc.errno else f"{type(exc).__name__}: {exc}"
        verb = "read" if isinstance(exc, OSError) and exc.errno else "decode"
        raise InputError(f"cannot {verb} image {path} ({why})", file=file, field=field) from None
    scale = {np.dtype(np.uint8): 1.0 / 255.0, np.dtype(np.uint16): 1.0 / 65535.0}.get(img.dtype)
    if scale is None and img.dtype.kind not in "fb":
        raise InputError(f"unsupported sample type {img.dtype} in {path}", file=file, field=field)
    out = img.astype(np.float32).reshape(img.shape[:2] + (-1,))
    if scale is not None:
        out *= np.float32(scale)
    elif not np.all(np.isfinite(out)):
        raise InputError(f"image {path} contains NaN or inf", file=file, field=field)
    elif out.min() < 0.0 or out.max() > 1.0:   # HDR, or a resampling's overshoot
        if clipped is not None:
            clipped.append(f"{file}: {field}: image {path} holds float samples in [{out.min():g}, {out.max():g}]")
        np.clip(out, 0.0, 1.0, out=out)
    channels = {1: [0, 0, 0], 2: [0, 0, 0, 1]}.get(out.shape[2])
    return out if channels is None else out[..., channels]


def target_size(height: int, width: int, downscale: float) -> tuple[int, int]:
    """Size ``(H', W')`` after dividing by ``downscale``, each side rounded as :mod:`senerf.data.load` says."""
    return (max(1, int(math.floor(height / downscale + 0.5))), max(1, int(math.floor(width / downscale + 0.5))))


def resize_area(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area-resize float32 ``img (H, W, 3)`` or straight RGBA ``(H, W, 4)`` to ``size = (H', W')``
    (:func:`~senerf.data.undistort.resample_premultiplied`); ``img`` itself when the size already matches."""
    h, w = size
    if img.shape[:2] == (h, w):
        return img
    return resample_premultiplied(img, lambda src: cv2.resize(src, (w, h), interpolation=cv2.INTER_AREA))


def load_photos(entries: list, photo_camera, downscale: float = 1.0, size: tuple | None = None) -> tuple:
    """Decode, size-check, undistort and downscale the photos of a scene: every loader's image step.

    Args:
        entries: one dict per view: ``path``, ``field`` and ``file`` (the photo and where it is named, for
            messages), ``distortion`` (:class:`~senerf.data.undistort.Distortion` or ``None``) and with a
            distortion ``distortion_field`` (where it was given; ``distortion_file`` too when that is not ``file``).
        photo_camera: ``photo_camera(entry, height, width) -> Intrinsics``, the camera of the photo as decoded at
            ``height x width`` (a distorted photo's at that size); it may raise ``InputError``, and is called on
            each photo before anything is allocated.
        downscale: divide both sides by this (``>= 1``), see :func:`target_size`; ignored when ``size`` is given.
        size: the output size ``(H', W')``, or ``None`` to derive it from ``downscale`` and the first photo.

    Returns:
        ``rgb (n, H', W', 3)`` float32; ``alpha (n, H', W')`` float32, or ``None`` when no photo has alpha (when
        only some do, the others get alpha 1, with a warning); and each view's :class:`Intrinsics` at ``(H', W')``:
        the pinhole camera a distorted photo was resampled onto (:mod:`senerf.data.undistort`), else the photo's own.

    Raises:
        InputError: any :func:`read_rgba` problem, a photo whose size differs from the first one, or a distortion
            that cannot be undone over its photo.
    """
    n = len(entries)
    cameras, opaque, clipped, coverage = [], [], [], []   # opaque: photos without an alpha channel

    @functools.lru_cache(maxsize=4)   # frames of up to 4 cameras, interleaved, compute their maps once
    def pinhole_and_maps(k_photo: Intrinsics, distortion: Distortion) -> tuple:
        k_pinhole = undistorted_intrinsics(k_photo, distortion)
        maps = undistortion_maps(k_photo, distortion, k_pinhole)
        return k_pinhole, maps, photo_coverage(k_photo, distortion, k_pinhole)

    for k, e in enumerate(entries):
        img = read_rgba(e["path"], e["field"], e["file"], clipped)
        if k == 0:
            size0 = img.shape[:2]
        elif img.shape[:2] != size0:
            raise InputError(f"image {e['path']} is {img.shape[1]}x{img.shape[0]} but {entries[0]['path']} is "
                             f"{size0[1]}x{size0[0]} (all images of a scene must share one size)", file=e["file"],
                             field=e["field"])
        cameras.append(photo_camera(e, img.shape[0], img.shape[1]))
        if e["distortion"] is not None:
            file, field = e.get("distortion_file", e["file"]), e["distortion_field"]
            try:
                cameras[k], maps, share = pinhole_and_maps(cameras[k], e["distortion"])
            except DistortionError as exc:
                raise InputError(f"cannot undistort {e['path'].name}: {exc}", file=file, field=field) from None
            if share < COVERAGE_WARN:
                coverage.append(f"{file}: undistorting {e['path'].name} keeps {share:.0%} of the photo ({field}: "
                                f"{e['distortion'].model} {e['distortion'].coeffs})")
            img = undistort_image(img, maps)
        if k == 0:
            out_size = tuple(size) if size is not None else target_size(size0[0], size0[1], downscale)
            rgb_all = np.empty((n,) + out_size + (3,), np.float32)
            alpha_all = np.ones((n,) + out_size, np.float32)
        img = resize_area(img, out_size)
        rgb_all[k] = img[..., :3]
        if img.shape[2] == 4:
            alpha_all[k] = img[..., 3]
        else:
            opaque.append(k)
    for found, then in ((clipped, "clipped to [0, 1]"), (coverage, "the lens model folds back inside the photo, or "
                         "the lens sees wider than a pinhole view can hold; check the coefficients' signs and scale")):
        if found:   # one line for a scene of such photos, not one per photo
            more = f" (and {len(found) - 1} more of the {n} photos)" if len(found) > 1 else ""
            warnings.warn(f"{found[0]}{more}; {then}", stacklevel=3)
    if 0 < len(opaque) < n:   # an RGB photo among RGBA ones: its background is trained as part of the object
        e = entries[opaque[0]]
        warnings.warn(f"{e['file']}: {len(opaque)} of {n} photos have no alpha channel ({e['field']}: "
                      f"{e['path'].name}); they are taken as fully opaque, background included", stacklevel=3)
    h, w = rgb_all.shape[1:3]
    return rgb_all, (alpha_all if len(opaque) < n else None), tuple(k.resized(w, h) for k in cameras)
