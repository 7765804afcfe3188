"""Private input helpers of :mod:`senerf.data`: JSON, paths, poses, numbers and image decoding.

Every problem with what the user gave us is raised as :class:`senerf.errors.InputError` naming the file and
the field; nothing here imports torch.

Convention:
    Images come back as float32 in ``[0, 1]``: straight (not premultiplied) colour ``(H, W, 3)`` and alpha
    ``(H, W)`` or ``None``.  8-bit samples are divided by 255, 16-bit samples by 65535.  Downscaling uses
    area interpolation on *premultiplied* colour, then un-premultiplies, so that compositing the downscaled
    image onto any background equals area-downscaling the composited full-size image (no dark fringes).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np

from ..errors import InputError
from ..geometry import is_rigid

__all__ = [
    "RIGID_ATOL",
    "IMAGE_SUFFIXES",
    "read_json",
    "get_field",
    "as_positive",
    "as_finite",
    "as_pose",
    "check_rigid",
    "resolve_inside",
    "read_rgba",
    "read_image",
    "target_size",
    "resize_area",
    "load_images",
]

#: Tolerance on ``|R^T R - I|`` for user poses.  The lego JSON (float32 printed) is off by 1.3e-6,
#: LLFF fern by 4e-16; 1e-4 accepts both with margin and rejects scaled or sheared matrices.
RIGID_ATOL = 1e-4

#: File suffixes recognised as images (a Blender ``file_path`` without one of them gets ``.png``).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".bmp", ".tif", ".tiff", ".webp")


def read_json(path: Path) -> dict:
    """Parse a JSON file whose top level must be an object; ``InputError`` for missing/malformed files."""
    try:
        found = path.is_file()
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", file=path) from None
    if not found:
        raise InputError("file not found" if not path.exists() else "is not a file", file=path)
    try:
        with open(path, "r", encoding="utf-8") as fh:
            data = json.load(fh)
    except json.JSONDecodeError as exc:
        raise InputError(f"malformed JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})", file=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read ({exc})", file=path) from None
    except RecursionError:
        raise InputError("malformed JSON (nested too deeply to read)", file=path) from None
    except ValueError as exc:   # Python's limit on an integer's digits
        raise InputError(f"malformed JSON ({str(exc).splitlines()[0]})", file=path) from None
    if not isinstance(data, dict):
        raise InputError(f"top level must be a JSON object, got {type(data).__name__}", file=path)
    return data


def get_field(obj: dict, key: str, file: Path, field: str):
    """``obj[key]``, or ``InputError`` naming ``field`` when it is absent."""
    if key not in obj:
        raise InputError("missing field", file=file, field=field)
    return obj[key]


def _is_json_number(value) -> bool:
    """A JSON number: int or float (NumPy's included), not a bool and not a string."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _as_float(value, file: Path, field: str) -> float:
    """``float(value)`` of a JSON number; a 400-digit integer is out of float's range: ``InputError``."""
    try:
        return float(value)
    except OverflowError:
        raise InputError(f"number out of range: {str(value)[:20]}...", file=file, field=field) from None


def as_positive(value, file: Path, field: str) -> float:
    """A positive finite float (focal lengths, principal points, sizes, angles); ``InputError`` otherwise."""
    if not _is_json_number(value):  # "0.69" (a string) or true are mistakes in the file, not numbers
        raise InputError(f"expected a number, got {value!r}", file=file, field=field)
    v = _as_float(value, file, field)
    if not math.isfinite(v) or v <= 0.0:
        raise InputError(f"must be positive and finite, got {value!r}", file=file, field=field)
    return v


def as_finite(value, file: Path, field: str, allow_string: bool = False) -> float:
    """A finite float of either sign (distortion coefficients); ``InputError`` otherwise.

    ``allow_string``: also take a number written as a string (``"-0.05"``), as some converters write them.
    """
    if allow_string and isinstance(value, str):
        try:
            value = float(value.strip())
        except ValueError:
            raise InputError(f"expected a number, got {value!r}", file=file, field=field) from None
    if not _is_json_number(value):
        raise InputError(f"expected a number, got {value!r}", file=file, field=field)
    v = _as_float(value, file, field)
    if not math.isfinite(v):
        raise InputError(f"must be finite, got {value!r}", file=file, field=field)
    return v


def as_pose(value, file: Path, field: str) -> np.ndarray:
    """A user camera-to-world matrix as ``(4, 4)`` float64, checked finite and rigid.

    Accepts a 4x4 or 3x4 nested list (3x4 gets the row ``0 0 0 1``).  The frame convention is *not*
    changed here; callers convert at their edge.
    """
    rows = value if isinstance(value, (list, tuple)) else None
    if rows is None or not all(isinstance(r, (list, tuple)) and all(_is_json_number(x) for x in r) for r in rows):
        raise InputError("expected a 4x4 matrix of numbers (a list of rows)", file=file, field=field)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):  # ragged rows
        raise InputError("expected a 4x4 matrix of numbers", file=file, field=field) from None
    if arr.shape == (3, 4):
        arr = np.concatenate([arr, [[0.0, 0.0, 0.0, 1.0]]], axis=0)
    if arr.shape != (4, 4):
        raise InputError(f"expected a 4x4 matrix, got shape {arr.shape}", file=file, field=field)
    check_rigid(arr, file, field)
    return arr


def check_rigid(c2w: np.ndarray, file: Path, field: str) -> None:
    """``InputError`` unless the ``(4, 4)`` pose is finite and rigid (tolerance :data:`RIGID_ATOL`)."""
    if not np.all(np.isfinite(c2w)):
        raise InputError("matrix contains NaN or inf", file=file, field=field)
    if not bool(is_rigid(c2w, atol=RIGID_ATOL)):
        rot = c2w[:3, :3]
        err = np.abs(rot.T @ rot - np.eye(3)).max()
        det = np.linalg.det(rot)
        raise InputError(
            f"not a rigid camera-to-world transform (max |R^T R - I| = {err:.3g}, det R = {det:.4g}, "
            f"last row {c2w[3].tolist()}; tolerance {RIGID_ATOL:g})",
            file=file,
            field=field,
        )


def resolve_inside(root: Path, rel: str, file: Path, field: str) -> Path:
    """``root / rel`` after refusing absolute paths and paths that leave ``root``.

    The check is lexical (``os.path.normpath``): ``..`` components may not climb out of the scene folder.
    Symbolic links *inside* the scene folder are followed as usual (a user who links an image folder into
    the scene chose to), so a linked folder is accepted even though it resolves elsewhere.
    """
    if not isinstance(rel, str) or not rel.strip():
        raise InputError(f"expected a non-empty path string, got {rel!r}", file=file, field=field)
    if "\x00" in rel:   # no file system takes it (and a raw NUL would reach the terminal)
        raise InputError(f"path {rel!r} contains a NUL character", file=file, field=field)
    if os.path.isabs(rel) or rel.startswith(("/", "\\")) or (len(rel) > 1 and rel[1] == ":"):
        raise InputError(f"absolute path {rel!r} refused; paths must be relative to the scene folder",
                         file=file, field=field)
    norm = os.path.normpath(rel.replace("\\", "/"))
    if norm == ".." or norm.startswith("../"):
        raise InputError(f"path {rel!r} leaves the scene folder", file=file, field=field)
    if norm == ".":   # the folder itself (a loader adding a suffix would read its sibling <folder>.png)
        raise InputError(f"path {rel!r} names the folder itself, not a file in it", file=file, field=field)
    return root / norm


_PILLOW_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def _png_bit_depth(path: Path) -> int | None:
    """Bit depth from a PNG header (IHDR byte 24), or ``None`` if not a PNG."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(25)
    except OSError:
        return None
    if len(head) == 25 and head[:8] == b"\x89PNG\r\n\x1a\n":
        return head[24]
    return None


#: Pillow modes read as they are (samples as stored); others are converted (:func:`_read_pillow`).
_PILLOW_AS_IS = ("1", "L", "LA", "RGB", "RGBA", "I;16", "I;16B", "I;16L", "F")


def _read_pillow(path: Path, field: str, file: Path) -> np.ndarray:
    """Decode with Pillow, as stored: grey, grey+alpha, RGB, RGBA, 16-bit grey or float (16-bit colour TIFFs
    with OpenCV, which keeps their 16 bits); a palette image
    becomes RGBA when its palette has transparency (RGB otherwise), CMYK / YCbCr / premultiplied RGBa become
    RGB(A) (read as they are, CMYK's four channels would pass for RGBA).  The EXIF orientation tag is not applied:
    the pixels are read as stored, as COLMAP reads them to compute the poses.

    Raises:
        InputError: a mode with no RGB reading, naming ``file`` and ``field``.
    """
    from PIL import Image

    with Image.open(path) as im:
        mode = im.mode
        if im.format == "TIFF" and mode in ("RGB", "RGBA") and max(_tiff_bits(im), default=8) > 8:
            return _read_opencv(path)   # Pillow reads 16-bit colour TIFFs as 8-bit RGB(A): 1/255 steps, not 1/65535
        if mode in ("P", "PA"):
            im = im.convert("RGBA" if mode == "PA" or "transparency" in im.info else "RGB")
        elif mode in ("CMYK", "YCbCr", "LAB", "HSV"):
            im = im.convert("RGB")
        elif mode == "RGBa":
            im = im.convert("RGBA")
        elif mode == "La":
            im = im.convert("LA")
        elif mode not in _PILLOW_AS_IS:
            raise InputError(f"image {path} has Pillow mode {mode!r}, which senerf does not read; save it as 8- or "
                             f"16-bit RGB(A) or grey", file=file, field=field)
        return np.asarray(im)


def _tiff_bits(im) -> tuple:
    """An open Pillow TIFF's BitsPerSample tag (258), as a tuple; empty when absent."""
    bits = im.tag_v2.get(258, ())
    return tuple(bits) if isinstance(bits, (tuple, list)) else (bits,)


def _read_opencv(path: Path) -> np.ndarray:
    """Decode with OpenCV as stored (16-bit samples kept), channels reordered BGR(A) -> RGB(A)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError("OpenCV could not decode it")
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = img[..., [2, 1, 0, 3][: img.shape[2]]]  # BGR(A) -> RGB(A)
    return img


def read_rgba(path: Path, field: str, file: Path | None = None, clipped: list | None = None) -> np.ndarray:
    """Decode one image to float32 ``(H, W, 3)`` (no alpha) or ``(H, W, 4)`` straight RGBA in ``[0, 1]``.

    8-bit samples are divided by 255, 16-bit by 65535 (converted to float32 once).  Grey is expanded to
    three equal channels; grey+alpha becomes RGBA.  Float samples outside [0, 1] are clipped, with a warning, or
    with a ``(file, field, what)`` entry appended to ``clipped`` when it is given (:func:`load_images` warns once).

    Raises:
        InputError: missing, unreadable or corrupt file, unsupported sample type or channel count, NaN/inf.
    """
    file = path if file is None else file
    try:
        found = path.is_file()
    except OSError as exc:   # a name too long, a folder that cannot be searched
        raise InputError(f"cannot read image {path} ({exc.strerror or exc})", file=file, field=field) from None
    if not found:
        raise InputError(f"image not found: {path}", file=file, field=field)
    if path.suffix.lower() == ".exr":   # listed as an image (so a file_path keeps it), but nothing installed decodes it
        raise InputError(f"cannot read image {path}: no installed decoder reads OpenEXR (imageio has no backend for "
                         "it and OpenCV's wheels are built without it); convert it to a 16-bit PNG or TIFF",
                         file=file, field=field)
    try:
        if _png_bit_depth(path) == 16:
            # Pillow (behind imageio) truncates 16-bit colour PNGs to 8 bits; OpenCV keeps all 16.  Pillow checks
            # the chunks first: libpng, inside OpenCV, prints its own line on a corrupt file before failing
            from PIL import Image

            with Image.open(path) as im:
                im.verify()
            img = _read_opencv(path)
        elif path.suffix.lower() in _PILLOW_SUFFIXES:
            img = _read_pillow(path, field, file)
        else:
            img = iio.imread(path)
    except InputError:
        raise
    except Exception as exc:  # corrupt file: the decoders raise many different types
        if isinstance(exc, OSError) and exc.errno is not None:   # the file itself: permissions, a long name, ...
            raise InputError(f"cannot read image {path} ({exc.strerror or exc})", file=file, field=field) from None
        msg = f"cannot decode image {path} ({type(exc).__name__}: {exc})".splitlines()[0]
        if path.suffix.lower() not in IMAGE_SUFFIXES:   # e.g. imageio's "itk could not be found" for '.img'
            readable = ", ".join(x for x in IMAGE_SUFFIXES if x != ".exr")
            msg = f"cannot decode image {path}: {path.suffix or 'no suffix'} is not a format senerf reads ({readable})"
        raise InputError(msg, file=file, field=field) from None
    img = np.asarray(img)
    if img.ndim == 4 and img.shape[0] == 1:   # a one-frame animation (GIF, APNG): imageio gives (1, H, W, C)
        img = img[0]
    if img.dtype.byteorder not in ("=", "|"):   # Pillow's I;16B: big-endian samples, as native ones
        img = img.astype(img.dtype.newbyteorder("="))
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 2, 3, 4) or img.shape[0] < 1 or img.shape[1] < 1:
        raise InputError(f"unsupported image shape {img.shape} in {path}", file=file, field=field)
    scale = {np.dtype(np.uint8): 1.0 / 255.0, np.dtype(np.uint16): 1.0 / 65535.0}.get(img.dtype)
    if scale is None and img.dtype.kind not in "fb":
        raise InputError(f"unsupported sample type {img.dtype} in {path}", file=file, field=field)
    out = img.astype(np.float32)
    if scale is not None:
        out *= np.float32(scale)
    elif not np.all(np.isfinite(out)):
        raise InputError(f"image {path} contains NaN or inf", file=file, field=field)
    elif out.size and (out.min() < 0.0 or out.max() > 1.0):   # HDR, or a resampling's overshoot: clipped, said
        what = f"image {path} holds float samples in [{out.min():g}, {out.max():g}]"
        if clipped is None:
            warnings.warn(f"{file}: {field}: {what}; clipped to [0, 1]", stacklevel=3)
        else:   # load_images says it once for all its photos
            clipped.append((file, field, what))
        np.clip(out, 0.0, 1.0, out=out)
    c = out.shape[2]
    if c == 1:
        out = np.repeat(out, 3, axis=2)
    elif c == 2:
        out = out[..., [0, 0, 0, 1]]
    return out


def read_image(path: Path, field: str, file: Path | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Decode one image file to straight colour and optional alpha, float32 in ``[0, 1]``.

    Args:
        path: the image file.
        field: the field that named it (``"frames[3].file_path"``), for error messages.
        file: the file that named it (a JSON); defaults to ``path``.

    Returns:
        ``rgb (H, W, 3)`` float32 and ``alpha (H, W)`` float32, or ``None`` when the image has no alpha
        channel (see :func:`read_rgba`).
    """
    img = read_rgba(path, field, file)
    return img[..., :3], (img[..., 3] if img.shape[2] == 4 else None)


def target_size(height: int, width: int, downscale: float) -> tuple[int, int]:
    """Size ``(H', W')`` after dividing by ``downscale``: each side ``floor(side / downscale + 0.5)``, >= 1.

    Sides that do not divide evenly are rounded (half up); intrinsics must then be scaled per axis by the
    actual ratio ``W'/W``, ``H'/H`` (:meth:`Intrinsics.resized`), which keeps them exact.
    """
    return (max(1, int(math.floor(height / downscale + 0.5))), max(1, int(math.floor(width / downscale + 0.5))))


def resize_area(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area-resize float32 ``img (H, W, 3)`` or straight RGBA ``(H, W, 4)`` to ``size = (H', W')``.

    RGBA colour is premultiplied before and un-premultiplied after (colour 0 where the new alpha is 0), so
    compositing the result equals area-resizing the composited image.  ``img`` may be modified in place.
    Returns ``img`` itself when the size already matches.
    """
    h, w = size
    if img.shape[:2] == (h, w):
        return img
    if img.shape[2] == 3:
        return np.clip(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA), 0.0, 1.0)
    img[..., :3] *= img[..., 3:]
    small = np.clip(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA), 0.0, 1.0)
    a = small[..., 3:]
    np.divide(small[..., :3], a, out=small[..., :3], where=a > 0.0)
    small[..., :3] *= a > 0.0
    return np.clip(small, 0.0, 1.0, out=small)


def load_images(paths, fields, file_of, downscale: float = 1.0, size: tuple[int, int] | None = None,
                prepare=None):
    """Decode, size-check and downscale a list of images.

    Args:
        paths: image paths, length n >= 1.
        fields: the field naming each path (for messages), length n.
        file_of: the file (JSON / folder) naming each path, length n.
        downscale: divide both sides by this (>= 1), see :func:`target_size`; ignored when ``size`` is given.
        size: the output size ``(H', W')``, or ``None`` to derive it from ``downscale``.
        prepare: ``None``, or ``prepare(k, img) -> img`` applied to image ``k`` as decoded (float32
            ``(H, W, 3)`` or straight RGBA ``(H, W, 4)``, after the size check, before downscaling) and
            returning the same shape: the loaders' lens undistortion.

    Returns:
        ``rgb (n, H', W', 3)`` float32, ``alpha (n, H', W')`` float32 or ``None``, and the decoded
        size ``(H, W)`` before downscaling.  When only some images carry alpha, the others get alpha 1
        (opaque, with a warning naming the first); when none do, alpha is ``None``.

    Raises:
        InputError: any :func:`read_rgba` problem, or an image whose size differs from the first one.
    """
    n = len(paths)
    if n == 0:
        raise ValueError("load_images: no images given (callers check for empty frame lists)")
    rgb_all = alpha_all = None
    any_alpha = False
    opaque = []   # images without an alpha channel
    size0 = out_size = None
    clipped: list = []
    for k, (path, field, file) in enumerate(zip(paths, fields, file_of)):
        img = read_rgba(path, field, file, clipped)
        if size0 is not None and img.shape[:2] != size0:
            raise InputError(
                f"image {path} is {img.shape[1]}x{img.shape[0]} but {paths[0]} is {size0[1]}x{size0[0]} "
                "(all images of a scene must share one size)",
                file=file,
                field=field,
            )
        decoded = img.shape[:2]
        if prepare is not None:   # checks the photo against its camera's size before anything is allocated
            img = prepare(k, img)
        if size0 is None:
            size0 = decoded
            out_size = tuple(size) if size is not None else target_size(size0[0], size0[1], downscale)
            rgb_all = np.empty((n,) + out_size + (3,), np.float32)
            alpha_all = np.ones((n,) + out_size, np.float32)
        img = resize_area(img, out_size)
        rgb_all[k] = img[..., :3]
        if img.shape[2] == 4:
            alpha_all[k] = img[..., 3]
            any_alpha = True
        else:
            opaque.append(k)
    if clipped:   # one line for a scene of HDR photos, not one per photo
        file, field, what = clipped[0]
        more = f" (and {len(clipped) - 1} more of the {n} photos)" if len(clipped) > 1 else ""
        warnings.warn(f"{file}: {field}: {what}{more}; clipped to [0, 1]", stacklevel=3)
    if any_alpha and opaque:   # an RGB photo among RGBA ones: its background is trained as part of the object
        k = opaque[0]
        warnings.warn(f"{file_of[k]}: {len(opaque)} of {n} photos have no alpha channel ({fields[k]}: "
                      f"{Path(paths[k]).name}); they are taken as fully opaque, background included", stacklevel=3)
    return rgb_all, (alpha_all if any_alpha else None), size0
