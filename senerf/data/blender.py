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
  :func:`senerf.data.fewshot_split`).
* **Lens distortion** (either format, top level or per frame): ``k1, k2, k3, p1, p2`` (OpenCV's radial and
  tangential model: COLMAP's ``OPENCV``, ``RADIAL``, ``SIMPLE_RADIAL``), or ``k1 .. k4`` with
  ``"camera_model": "OPENCV_FISHEYE"`` or ``"is_fisheye": true`` (instant-ngp).  Each distorted photo is
  resampled at load time onto a pinhole camera at the same pose, with the photo's size and principal point
  and a focal length chosen so that no pixel falls outside the photo (:mod:`senerf.data.undistort`); the
  scene's intrinsics are that camera's.  ``camera_model`` must be one of
  :data:`senerf.data.undistort.PERSPECTIVE_MODELS` or :data:`~senerf.data.undistort.FISHEYE_MODELS` (any other is refused, never read as a pinhole), and agree with ``is_fisheye``;
  ``k4`` (an ``r^8`` term) on a perspective camera is refused, as nerfstudio does.  A coefficient written as a
  string (``"-0.05"``, older nerfstudio converters) is read as the number.  A frame's value, ``null``
  excepted, wins over the file's, key by key.

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
from .undistort import FISHEYE_MODELS, PERSPECTIVE_MODELS, Distortion, Undistorter

__all__ = ["load_blender", "load_ngp", "BLENDER_SPLITS"]

BLENDER_SPLITS = ("train", "val", "test")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")

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
    distortion, distortion_field = _distortion(meta, frame, file, prefix)
    return dict(path=path, field=f"{prefix}.file_path", file=file, params=params, c2w_gl=c2w,
                distortion=distortion, distortion_field=distortion_field, frame=prefix)


def _frame_or_meta(meta: dict, frame: dict, key: str, prefix: str):
    """``(value, field)`` of ``key``, the frame's value winning over the file's, or ``None`` when neither has it
    (a ``null`` value counts as absent)."""
    if frame.get(key) is not None:
        return frame[key], f"{prefix}.{key}"
    if meta.get(key) is not None:
        return meta[key], key
    return None


def _camera_model(meta: dict, frame: dict, file: Path, prefix: str) -> tuple:
    """``(is_fisheye, field)`` from ``camera_model`` and ``is_fisheye``: ``(None, None)`` when neither is given."""
    found = _frame_or_meta(meta, frame, "camera_model", prefix)
    fisheye = field = None
    if found is not None:
        value, field = found
        name = value.strip().upper() if isinstance(value, str) else None
        if name not in PERSPECTIVE_MODELS + FISHEYE_MODELS:
            raise InputError(f"camera model {value!r} is not supported (supported: "
                             f"{', '.join(PERSPECTIVE_MODELS + FISHEYE_MODELS)})", file=file, field=field)
        fisheye = name in FISHEYE_MODELS
    flag = _frame_or_meta(meta, frame, "is_fisheye", prefix)
    if flag is not None:
        if not isinstance(flag[0], bool):
            raise InputError(f"expected true or false, got {flag[0]!r}", file=file, field=flag[1])
        if fisheye is not None and flag[0] != fisheye:
            raise InputError(f"is {str(flag[0]).lower()} but camera_model is {found[0]!r}", file=file, field=flag[1])
        fisheye, field = flag[0], (field or flag[1])
    return fisheye, field


def _distortion(meta: dict, frame: dict, file: Path, prefix: str) -> tuple:
    """The frame's lens distortion and the field to name in errors: ``(Distortion, field)`` or ``(None, None)``.

    A perspective camera whose coefficients are all 0 (or absent) is a pinhole: ``(None, None)``.
    """
    fisheye, model_field = _camera_model(meta, frame, file, prefix)
    values, fields = {}, {}
    for key in _DISTORTION_KEYS:
        found = _frame_or_meta(meta, frame, key, prefix)
        if found is not None:
            values[key] = _io.as_finite(found[0], file, found[1], allow_string=True)
            fields[key] = found[1]
    nonzero = [k for k in _DISTORTION_KEYS if values.get(k, 0.0) != 0.0]
    c = {k: values.get(k, 0.0) for k in _DISTORTION_KEYS}
    if fisheye:
        for key in ("p1", "p2"):
            if c[key] != 0.0:
                raise InputError(f"a fisheye camera has no tangential term {key} (OPENCV_FISHEYE takes k1..k4)",
                                 file=file, field=fields[key])
        return Distortion("fisheye", (c["k1"], c["k2"], c["k3"], c["k4"])), (fields[nonzero[0]] if nonzero
                                                                             else model_field)
    if c["k4"] != 0.0:
        raise InputError("k4 (an r^8 radial term) is not supported on a perspective camera (OpenCV's model takes "
                         "k1, k2, k3, p1, p2)", file=file, field=fields["k4"])
    if not nonzero:
        return None, None
    return Distortion("opencv", (c["k1"], c["k2"], c["p1"], c["p2"], c["k3"])), fields[nonzero[0]]


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
    """Decode (and undistort) the images of ``entries`` (dicts: path, field, file, params, c2w_gl,
    distortion, distortion_field) and build the Scene."""
    undistorter = Undistorter(entries, lambda e, h, w: _intrinsics(e["params"], h, w, e["file"]))
    rgb, alpha, (h0, w0) = _io.load_images(
        [e["path"] for e in entries], [e["field"] for e in entries], [e["file"] for e in entries], downscale,
        prepare=undistorter,
    )
    h, w = rgb.shape[1:3]
    intr = tuple(k.resized(w, h) for k in undistorter.cameras(h0, w0))
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
        source_files=tuple(e["file"] for e in entries),   # each view's camera, once per file (Scene)
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
    if split_lists and "train" not in split_lists:   # as nerfstudio: given split lists, the training one is needed
        raise InputError(f"missing beside {', '.join(f'{s}_filenames' for s in split_lists)}: no frame to train on",
                         file=file, field="train_filenames")
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
    for split, names in split_lists.items():   # a list that selects nothing is a mistake, not "no split"
        if split_idx[split]:
            continue
        if names:
            raise InputError(f"none of its {len(names)} names is the file_path of a frame with an existing image "
                             f"(e.g. {sorted(names)[0]!r})", file=file, field=f"{split}_filenames")
        if split == "train":
            raise InputError("is empty: no frame to train on", file=file, field="train_filenames")
    if missing:
        warnings.warn(f"{file}: skipped {len(missing)} frame(s) whose image is missing: {', '.join(missing)}",
                      stacklevel=2)
    splits = {s: np.asarray(v, np.int64) for s, v in split_idx.items()}
    return _build(root, entries, downscale, splits)
