"""Loaders for the JSON camera formats: NeRF Synthetic (Blender) and instant-ngp / nerfstudio.

* **Blender** (``transforms_{train,val,test}.json``): ``camera_angle_x`` (horizontal field of view,
  radians), per frame ``file_path`` without extension (``.png`` is appended) and ``transform_matrix``;
  the instant-ngp intrinsics below (``fl_x``, ``cx``, ... at the top level or per frame) are read here too.
  ``transforms_train.json`` is required; a missing ``transforms_val.json`` / ``transforms_test.json``
  gives an empty split.  The arrays hold train, then val, then test frames in file order.  A frame whose
  image is missing is an error (view indices must stay stable).
* **instant-ngp / nerfstudio** (one ``transforms.json``): intrinsics ``fl_x, fl_y, cx, cy, w, h`` at the
  top level or per frame (per frame wins), with ``camera_angle_x`` (and ``camera_angle_y``) as fallback
  for the focal length and ``(W/2, H/2)`` for the principal point.  A frame whose image is missing is
  skipped with a warning naming it.  Splits: nerfstudio's ``train_filenames`` / ``val_filenames`` /
  ``test_filenames`` lists are honoured when present (a frame listed in none is in no split); otherwise
  every frame is ``'train'`` and ``'val'``/``'test'`` are empty (choose test views with a protocol, see
  :func:`senerf.data.fewshot_split`).  Distortion coefficients are ignored with a warning.

Convention:
    ``transform_matrix`` is camera-to-world in the OpenGL camera convention (x right, y up, looking
    along -z); it is converted here, once, with :func:`senerf.geometry.opengl_to_opencv`.  ``file_path``
    values without an image suffix get ``.png``; absolute paths and paths leaving the scene folder are
    refused.  Declared ``w``/``h`` must equal the decoded image size.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Intrinsics, opengl_to_opencv
from . import _io
from .scene import Scene

__all__ = ["load_blender", "load_ngp", "BLENDER_SPLITS"]

BLENDER_SPLITS = ("train", "val", "test")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
_UNSUPPORTED_MODELS = ("OPENCV_FISHEYE", "EQUIRECTANGULAR", "FISHEYE")


def _image_path(root: Path, frame: dict, file: Path, field: str) -> Path:
    rel = _io.get_field(frame, "file_path", file, field)
    path = _io.resolve_inside(root, rel, file, field)
    if path.suffix.lower() not in _io.IMAGE_SUFFIXES:
        path = path.with_name(path.name + ".png")
    return path


def _frames(meta: dict, file: Path, allow_empty: bool) -> list:
    frames = _io.get_field(meta, "frames", file, "frames")
    if not isinstance(frames, list):
        raise InputError(f"expected a list, got {type(frames).__name__}", file=file, field="frames")
    if not frames and not allow_empty:
        raise InputError("empty frame list", file=file, field="frames")
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict):
            raise InputError(f"expected an object, got {type(fr).__name__}", file=file, field=f"frames[{i}]")
    return frames


def _frame_entry(root: Path, meta: dict, frame: dict, i: int, file: Path) -> dict:
    """One validated frame ``frames[i]`` of ``file``: image path, camera fields and OpenGL ``c2w_gl (4, 4)``."""
    prefix = f"frames[{i}]"
    path = _image_path(root, frame, file, f"{prefix}.file_path")
    c2w = _io.as_pose(_io.get_field(frame, "transform_matrix", file, f"{prefix}.transform_matrix"),
                      file, f"{prefix}.transform_matrix")
    params = _camera_params(meta, frame, file, prefix)
    distortion = [k for k in _DISTORTION_KEYS if frame.get(k, meta.get(k, 0.0)) not in (0, 0.0, None)]
    return dict(path=path, field=f"{prefix}.file_path", file=file, params=params, c2w_gl=c2w,
                distortion=distortion, frame=prefix)


def _warn_distortion(entries: list, file: Path) -> None:
    """One warning for all frames of ``file`` whose distortion coefficients are ignored (not one per frame)."""
    hit = [e for e in entries if e["distortion"]]
    if hit:
        keys = sorted({k for e in hit for k in e["distortion"]})
        where = ", ".join(e["frame"] for e in hit[:3]) + (", ..." if len(hit) > 3 else "")
        warnings.warn(f"{file}: distortion {keys} ignored in {len(hit)} of {len(entries)} frame(s) ({where}); "
                      "the images are used as pinhole", stacklevel=3)


def _camera_params(meta: dict, frame: dict, file: Path, prefix: str) -> dict:
    """Validated numeric camera fields of one frame (frame value overrides the file-level one)."""
    out = {}
    for key in ("fl_x", "fl_y", "camera_angle_x", "camera_angle_y", "w", "h", "cx", "cy"):
        if key in frame:
            src, field = frame[key], f"{prefix}.{key}"
        elif key in meta:
            src, field = meta[key], key
        else:
            continue
        # every field is positive, cx/cy included: senerf.geometry.Intrinsics refuses a principal point
        # on or beyond the image's top/left edge, and the user must hear it with file and field
        out[key] = (_io.as_positive(src, file, field), field)
        if key.startswith("camera_angle") and not out[key][0] < math.pi:
            raise InputError(f"field of view must be below pi radians, got {src!r}", file=file, field=field)
    if "fl_x" not in out and "camera_angle_x" not in out:
        raise InputError("missing field (need fl_x or camera_angle_x)", file=file, field="camera_angle_x")
    model = frame.get("camera_model", meta.get("camera_model"))
    if isinstance(model, str) and model.upper() in _UNSUPPORTED_MODELS:
        raise InputError(f"camera model {model!r} is not supported (pinhole only)", file=file, field="camera_model")
    return out


def _intrinsics(params: dict, height: int, width: int, file: Path) -> Intrinsics:
    """Intrinsics at the decoded image size ``(height, width)``; checks declared ``w``/``h``."""
    for key, actual in (("w", width), ("h", height)):
        if key in params and abs(params[key][0] - actual) > 1e-6:
            raise InputError(
                f"declared {params[key][0]:g} but the images are {width}x{height}", file=file, field=params[key][1]
            )
    if "fl_x" in params:
        fx = params["fl_x"][0]
    else:
        fx = 0.5 * width / math.tan(0.5 * params["camera_angle_x"][0])
    if "fl_y" in params:
        fy = params["fl_y"][0]
    elif "camera_angle_y" in params:
        fy = 0.5 * height / math.tan(0.5 * params["camera_angle_y"][0])
    else:
        fy = fx
    cx = params["cx"][0] if "cx" in params else 0.5 * width
    cy = params["cy"][0] if "cy" in params else 0.5 * height
    return Intrinsics(fx, fy, cx, cy, width, height)


def _build(root: Path, entries: list, downscale: float, splits: dict) -> Scene:
    """Decode the images of ``entries`` (dicts: path, field, file, params, c2w_gl) and build the Scene."""
    rgb, alpha, (h0, w0) = _io.load_images(
        [e["path"] for e in entries], [e["field"] for e in entries], [e["file"] for e in entries], downscale
    )
    h, w = rgb.shape[1:3]
    intr = tuple(_intrinsics(e["params"], h0, w0, e["file"]).resized(w, h) for e in entries)
    c2w = opengl_to_opencv(np.stack([e["c2w_gl"] for e in entries]))
    return Scene(
        name=root.resolve().name,  # "." (a relative marker file or the current folder) has no name
        root=root,
        rgb=rgb,
        alpha=alpha,
        intrinsics=intr[0],
        intrinsics_all=intr,
        c2w=c2w.astype(np.float64),
        splits=splits,
        kind="object",
        near=None,
        far=None,
        image_paths=tuple(e["path"] for e in entries),
    )


def load_blender(root: Path, downscale: float = 1.0) -> Scene:
    """Load a NeRF Synthetic scene folder (``transforms_{train,val,test}.json``).

    Args:
        root: the scene folder.
        downscale: divide image sides by this (``>= 1``; validated by :func:`senerf.data.load_scene`).

    Returns:
        A :class:`Scene` with ``kind='object'``, ``near = far = None`` (the format gives no bounds).

    Raises:
        InputError: missing train JSON, malformed JSON, missing field, bad matrix, bad focal, missing or
            corrupt image, mixed image sizes, empty train frame list, path outside the scene.
    """
    root = Path(root)
    entries, splits = [], {}
    for split in BLENDER_SPLITS:
        file = root / f"transforms_{split}.json"
        if split != "train" and not file.exists():
            splits[split] = np.zeros(0, np.int64)
            continue
        meta = _io.read_json(file)
        frames = _frames(meta, file, allow_empty=split != "train")
        start = len(entries)
        for i, fr in enumerate(frames):
            entry = _frame_entry(root, meta, fr, i, file)
            if not entry["path"].is_file():
                raise InputError(f"image not found: {entry['path']}", file=file, field=entry["field"])
            entries.append(entry)
        _warn_distortion(entries[start:], file)
        splits[split] = np.arange(start, len(entries), dtype=np.int64)
    return _build(root, entries, downscale, splits)


def _norm_rel(rel: str) -> str:
    return os.path.normpath(str(rel).replace("\\", "/"))


def load_ngp(root: Path, downscale: float = 1.0) -> Scene:
    """Load an instant-ngp / nerfstudio scene folder (one ``transforms.json``); see the module docstring.

    Args:
        root: the scene folder.
        downscale: divide image sides by this (``>= 1``).

    Returns:
        A :class:`Scene` with ``kind='object'`` and ``near = far = None``; frames in file order, those with
        a missing image left out (with a warning).

    Raises:
        InputError: as :func:`load_blender`, and when no frame's image exists.
    """
    root = Path(root)
    file = root / "transforms.json"
    meta = _io.read_json(file)
    frames = _frames(meta, file, allow_empty=False)
    split_lists = {}
    for split in BLENDER_SPLITS:
        key = f"{split}_filenames"
        if key in meta:
            names = meta[key]
            if not isinstance(names, list) or not all(isinstance(x, str) for x in names):
                raise InputError("expected a list of file names", file=file, field=key)
            split_lists[split] = {_norm_rel(x) for x in names}
    entries, missing, split_idx = [], [], {s: [] for s in BLENDER_SPLITS}
    for i, fr in enumerate(frames):
        entry = _frame_entry(root, meta, fr, i, file)
        if not entry["path"].is_file():
            missing.append(f"frames[{i}] ({fr['file_path']})")
            continue
        k = len(entries)
        entries.append(entry)
        if split_lists:
            rel = _norm_rel(fr["file_path"])
            rel_png = _norm_rel(os.path.relpath(entry["path"], root))
            for split, names in split_lists.items():
                if rel in names or rel_png in names:
                    split_idx[split].append(k)
        else:
            split_idx["train"].append(k)
    if not entries:
        raise InputError("no frame has an existing image", file=file, field="frames")
    _warn_distortion(entries, file)
    if missing:
        warnings.warn(f"{file}: skipped {len(missing)} frame(s) whose image is missing: {', '.join(missing)}",
                      stacklevel=2)
    splits = {s: np.asarray(v, np.int64) for s, v in split_idx.items()}
    return _build(root, entries, downscale, splits)
