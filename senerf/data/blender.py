"""Loaders for the JSON camera formats: NeRF Synthetic (Blender) and instant-ngp / nerfstudio.

* **Blender** (``transforms_{train,val,test}.json``; train required, a missing val or test file gives an empty
  split): ``camera_angle_x`` (horizontal field of view, radians), per frame ``file_path`` and
  ``transform_matrix``.  The arrays hold train, then val, then test frames in file order; a frame whose image
  is missing is an error (view indices must stay stable).
* **instant-ngp / nerfstudio** (one ``transforms.json``): intrinsics ``fl_x, fl_y, cx, cy, w, h``, with
  ``camera_angle_x`` (and ``camera_angle_y``) as fallback for the focal length and ``(W/2, H/2)`` for the
  principal point (a Blender file may hold them too).  A frame whose image is missing is skipped with a
  warning.  Splits: nerfstudio's ``train_filenames`` / ``val_filenames`` / ``test_filenames`` when present (a
  frame listed in none is in no split); otherwise every frame is ``'train'`` (choose test views with a
  protocol, see :func:`senerf.data.fewshot_split`).
* **Lens distortion** (undone at load time, :mod:`senerf.data.undistort`): ``k1, k2, k3, p1, p2``, or ``k1 .. k4``
  with ``"camera_model": "OPENCV_FISHEYE"`` or ``"is_fisheye": true`` (instant-ngp), numbers or numeric strings.
  ``camera_model`` must be one of :data:`~senerf.data.undistort.PERSPECTIVE_MODELS` or ``FISHEYE_MODELS`` and
  agree with ``is_fisheye``; ``k4`` (an ``r^8`` term) on a perspective camera is refused, as nerfstudio does.

Every camera and distortion field may be given at the top level or per frame; a frame's value, ``null``
excepted, wins over the file's, key by key (per-frame intrinsics).

* **Scene bound** (instant-ngp): ``aabb_scale`` (a positive number; instant-ngp uses powers of two) says the scene
  lies in a cube ``aabb_scale`` times instant-ngp's unit cube, which is ``[0, 1]^3`` after ``p * scale + offset``
  (defaults 0.33 and 0.5 per axis): ``Scene.bound`` is that cube in the file's world coordinates.

Convention:
    ``transform_matrix`` is camera-to-world in the OpenGL camera convention (x right, y up, looking
    along -z); it is converted here, once, with :func:`senerf.geometry.opengl_to_opencv`.  ``file_path``
    values without an image suffix get ``.png`` (paths: :func:`~senerf.data._io.resolve_inside`).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Intrinsics, opengl_to_opencv
from . import _io
from .scene import SPLIT_NAMES, Scene
from .undistort import FISHEYE_MODELS, PERSPECTIVE_MODELS, Distortion

__all__ = ["load_blender", "load_ngp"]

_CAMERA_KEYS = ("fl_x", "fl_y", "camera_angle_x", "camera_angle_y", "w", "h", "cx", "cy")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def _lookup(meta: dict, frame: dict, key: str, prefix: str):
    """``(value, field)`` of ``key`` as the module docstring says (frame over file), or ``None`` when absent."""
    if frame.get(key) is not None:
        return frame[key], f"{prefix}.{key}"
    if meta.get(key) is not None:
        return meta[key], key
    return None


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
    field, matrix = f"{prefix}.file_path", f"{prefix}.transform_matrix"
    path = _io.resolve_inside(root, _io.get_field(frame, "file_path", file, field), file, field)
    if path.suffix.lower() not in _io.IMAGE_SUFFIXES:
        path = path.with_name(path.name + ".png")
    c2w_gl = _io.as_pose(_io.get_field(frame, "transform_matrix", file, matrix), file, matrix)
    camera = {}
    for key in _CAMERA_KEYS:
        found = _lookup(meta, frame, key, prefix)
        if found is not None:   # cx, cy too: Intrinsics refuses a principal point on or beyond the top/left edge
            camera[key] = (_io.as_number(found[0], file, found[1], positive=True), found[1])
            if key.startswith("camera_angle") and not camera[key][0] < math.pi:
                raise InputError(f"field of view must be below pi radians, got {found[0]!r}", file=file,
                                 field=found[1])
    if "fl_x" not in camera and "camera_angle_x" not in camera:
        raise InputError("missing field (need fl_x or camera_angle_x)", file=file, field="camera_angle_x")
    distortion, distortion_field = _distortion(meta, frame, file, prefix)
    return dict(path=path, field=field, file=file, camera=camera, c2w_gl=c2w_gl, distortion=distortion,
                distortion_field=distortion_field)


def _distortion(meta: dict, frame: dict, file: Path, prefix: str) -> tuple:
    """The frame's lens distortion and the field to name in its errors, ``(Distortion, field)``, or
    ``(None, None)`` for a pinhole (a perspective camera whose coefficients are all 0 or absent)."""
    model, fisheye = _lookup(meta, frame, "camera_model", prefix), None
    if model is not None:
        name = model[0].strip().upper() if isinstance(model[0], str) else None
        if name not in PERSPECTIVE_MODELS + FISHEYE_MODELS:
            raise InputError(f"camera model {model[0]!r} is not supported (supported: "
                             f"{', '.join(PERSPECTIVE_MODELS + FISHEYE_MODELS)})", file=file, field=model[1])
        fisheye = name in FISHEYE_MODELS
    flag = _lookup(meta, frame, "is_fisheye", prefix)
    if flag is not None:
        if not isinstance(flag[0], bool):
            raise InputError(f"expected true or false, got {flag[0]!r}", file=file, field=flag[1])
        if fisheye is not None and flag[0] != fisheye:
            raise InputError(f"is {str(flag[0]).lower()} but camera_model is {model[0]!r}", file=file, field=flag[1])
        fisheye = flag[0]
    found = {key: _lookup(meta, frame, key, prefix) for key in _DISTORTION_KEYS}
    c = {key: 0.0 if v is None else _io.as_number(v[0], file, v[1], allow_string=True) for key, v in found.items()}
    field = next((found[key][1] for key in _DISTORTION_KEYS if c[key] != 0.0), None)
    if fisheye:
        for key in ("p1", "p2"):
            if c[key] != 0.0:
                raise InputError(f"a fisheye camera has no tangential term {key} (OPENCV_FISHEYE takes k1..k4)",
                                 file=file, field=found[key][1])
        return Distortion("fisheye", (c["k1"], c["k2"], c["k3"], c["k4"])), field or (model or flag)[1]
    if c["k4"] != 0.0:
        raise InputError("k4 (an r^8 radial term) is not supported on a perspective camera (OpenCV's model takes "
                         "k1, k2, k3, p1, p2)", file=file, field=found["k4"][1])
    if field is None:
        return None, None
    return Distortion("opencv", (c["k1"], c["k2"], c["p1"], c["p2"], c["k3"])), field


def _intrinsics(camera: dict, height: int, width: int, file: Path) -> Intrinsics:
    """Intrinsics at the decoded image size ``(height, width)``; checks declared ``w``/``h``."""
    for key, actual in (("w", width), ("h", height)):
        if key in camera and abs(camera[key][0] - actual) > 1e-6:
            raise InputError(f"declared {camera[key][0]:g} but the images are {width}x{height}", file=file,
                             field=camera[key][1])
    value = {key: v for key, (v, _) in camera.items()}
    for axis, side in (("x", width), ("y", height)):   # a focal length from the field of view where not given
        if f"fl_{axis}" not in value and f"camera_angle_{axis}" in value:
            value[f"fl_{axis}"] = 0.5 * side / math.tan(0.5 * value[f"camera_angle_{axis}"])
    fx, cx, cy = value["fl_x"], value.get("cx", 0.5 * width), value.get("cy", 0.5 * height)
    return Intrinsics(fx, value.get("fl_y", fx), cx, cy, width, height)


def _scene(root: Path, entries: list, downscale: float, splits: dict) -> Scene:
    """Decode (and undistort) the images of ``entries`` (:func:`_frame_entry`) and build the Scene."""
    rgb, alpha, intr = _io.load_photos(entries, lambda e, h, w: _intrinsics(e["camera"], h, w, e["file"]), downscale)
    c2w = opengl_to_opencv(np.stack([e["c2w_gl"] for e in entries]))
    return Scene(name=root.resolve().name, root=root, rgb=rgb, alpha=alpha, intrinsics=intr[0], intrinsics_all=intr,
                 c2w=c2w, splits=splits, kind="object", image_paths=tuple(e["path"] for e in entries),
                 source_files=tuple(e["file"] for e in entries))


def load_blender(root: Path, downscale: float = 1.0) -> Scene:
    """Load a NeRF Synthetic scene folder (``transforms_{train,val,test}.json``).

    Args:
        downscale: divide image sides by this (``>= 1``; validated by :func:`senerf.data.load_scene`).

    Returns:
        A :class:`Scene` with ``kind='object'``, ``near = far = None`` (the format gives no bounds).

    Raises:
        InputError: naming the file and field (a missing train JSON; a bad field, matrix, path or image).
    """
    root = Path(root)
    entries, splits = [], {}
    for split in SPLIT_NAMES:
        file = root / f"transforms_{split}.json"
        if split != "train" and not file.exists():   # an empty split
            continue
        meta = _io.read_json(file)
        start = len(entries)
        entries += [_frame_entry(root, meta, fr, i, file) for i, fr in enumerate(_frames(meta, file, split != "train"))]
        splits[split] = np.arange(start, len(entries), dtype=np.int64)
    return _scene(root, entries, downscale, splits)


def load_ngp(root: Path, downscale: float = 1.0) -> Scene:
    """Load an instant-ngp / nerfstudio scene folder (one ``transforms.json``); see the module docstring.

    Args:
        downscale: divide image sides by this (``>= 1``).

    Returns:
        A :class:`Scene` with ``kind='object'`` and ``near = far = None``; frames in file order.

    Raises:
        InputError: as :func:`load_blender`, when no frame's image exists, and for split lists that are not
            lists of names, select no frame, or lack a training list beside the others (as nerfstudio).
    """
    root = Path(root)
    file = root / "transforms.json"
    meta = _io.read_json(file)
    frames = _frames(meta, file, allow_empty=False)
    lists = {}
    for split in SPLIT_NAMES:
        key = f"{split}_filenames"
        if key in meta:
            if not isinstance(meta[key], list) or not all(isinstance(x, str) for x in meta[key]):
                raise InputError("expected a list of file names", file=file, field=key)
            lists[split] = {_io.norm_rel(x) for x in meta[key]}
    if lists and "train" not in lists:
        raise InputError(f"missing beside {', '.join(f'{s}_filenames' for s in lists)}: no frame to train on",
                         file=file, field="train_filenames")
    entries, missing, split_idx = [], [], {s: [] for s in SPLIT_NAMES}
    for i, fr in enumerate(frames):
        entry = _frame_entry(root, meta, fr, i, file)
        if not entry["path"].is_file():
            missing.append(f"frames[{i}] ({fr['file_path']})")
            continue
        names = {_io.norm_rel(fr["file_path"]), entry["path"].relative_to(root).as_posix()}   # with .png or not
        for split in lists or ("train",):
            if not lists or names & lists[split]:
                split_idx[split].append(len(entries))
        entries.append(entry)
    if not entries:
        raise InputError("no frame has an existing image", file=file, field="frames")
    for split, names in lists.items():   # a list that selects nothing is a mistake, not "no split"
        if not split_idx[split] and (names or split == "train"):
            raise InputError(f"none of its {len(names)} names is the file_path of a frame with an existing image "
                             f"(e.g. {sorted(names)[0]!r})" if names else "is empty: no frame to train on",
                             file=file, field=f"{split}_filenames")
    if missing:
        warnings.warn(f"{file}: skipped {len(missing)} frame(s) whose image is missing: {', '.join(missing)}",
                      stacklevel=2)
    scene = _scene(root, entries, downscale, {s: np.asarray(v, np.int64) for s, v in split_idx.items()})
    bound = _ngp_bound(meta, file)
    return scene if bound is None else dataclasses.replace(scene, bound=bound)


def _ngp_bound(meta: dict, file: Path) -> tuple | None:
    """The world box of instant-ngp's ``aabb_scale`` (module docstring), or None without one."""
    if meta.get("aabb_scale") is None:
        return None
    size = _io.as_number(meta["aabb_scale"], file, "aabb_scale", positive=True)
    scale = _io.as_number(meta.get("scale", 0.33), file, "scale", positive=True)
    offset = meta.get("offset", 0.5)
    offset = offset if isinstance(offset, list) else [offset] * 3
    if len(offset) != 3:
        raise InputError(f"expected a number or 3 numbers, got {meta.get('offset')!r:.40}", file=file, field="offset")
    offset = np.array([_io.as_number(v, file, "offset") for v in offset])
    lo, hi = (0.5 - size / 2 - offset) / scale, (0.5 + size / 2 - offset) / scale
    return tuple(map(float, lo)), tuple(map(float, hi))
