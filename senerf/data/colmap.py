"""Loader for COLMAP sparse reconstructions (``sparse/0/{cameras,images,points3D}.{bin,txt}`` + ``images/``).

The three model files are read in either of COLMAP's formats (binary or text, layouts as COLMAP documents them
and as its own ``read_write_model.py`` reads them) with NumPy, not pycolmap: three fixed-layout files do not
need a 38 MB compiled dependency.  Camera models: ``SIMPLE_PINHOLE``, ``PINHOLE``, and with their lens
distortion undone at load (:mod:`senerf.data.undistort`) ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``,
``OPENCV_FISHEYE``, ``SIMPLE_RADIAL_FISHEYE``, ``RADIAL_FISHEYE``; others are refused.

Folders: the model is the first of ``ROOT/sparse/0/``, ``ROOT/sparse/``, ``ROOT/`` holding ``cameras.bin`` or
``cameras.txt`` (binary preferred when both exist); images are ``ROOT/images/NAME`` for each registered
image's ``NAME``, or ``ROOT/images_N/NAME`` as LLFF and nerfstudio write downscaled copies: the folder is
chosen as LLFF's (:func:`senerf.data.llff.llff_image_folder`: ``images_{downscale}`` when it exists, else the
largest factor below), and its photos must be their cameras' size divided by ``N`` (to a pixel).  Views are
the registered images sorted by name (LLFF's order), at ``1 / downscale`` of their cameras' size.

Kind: **forward-facing** when every camera looks within :data:`FORWARD_FACING_DEG` degrees of the cameras'
mean viewing direction and every ray, image corners included, within :data:`MAX_RAY_DEG` (an LLFF-style
capture: fern's cameras stay within 10 degrees; :func:`view_spread`), else **object** (a capture around something, fitted in a
box as the JSON formats' captures are, in COLMAP's world frame).  A forward-facing scene is normalised as :func:`load_llff` normalises
LLFF (``bd_factor``, ``recenter``); its per-image depth bounds are what LLFF's ``imgs2poses`` takes, the 0.1th
and 99.9th percentiles of the depths of the 3D points each image sees, and it needs one camera (NDC is built
from one focal length).  Splits, either kind, as LLFF's: every 8th view (``index % 8 == 0``) is a test
view, the rest train.

Convention:
    COLMAP stores world-to-camera ``(qvec (w, x, y, z), tvec)`` in the OpenCV camera convention, and puts
    pixel centres at ``i + 0.5`` as :class:`senerf.geometry.Intrinsics` does: only the inversion to ``c2w``
    happens here.
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Intrinsics
from . import _io
from .llff import LLFF_HOLDOUT, _folder_factor, llff_image_folder, normalise_forward_facing
from .scene import Scene
from .undistort import FISHEYE_MODELS, PERSPECTIVE_MODELS, Distortion, Undistorter

__all__ = ["load_colmap", "colmap_model_folder", "view_spread", "read_cameras", "read_images", "read_points3d",
           "sparse_points",
           "ColmapCamera", "ColmapImage", "FORWARD_FACING_DEG", "MAX_RAY_DEG", "CAMERA_MODELS"]

#: A capture is forward-facing when every camera looks within this many degrees of the cameras' mean direction
#: and every ray (image corners included) within MAX_RAY_DEG of it: NDC needs every ray to move forward.
FORWARD_FACING_DEG = 30.0
MAX_RAY_DEG = 80.0

#: COLMAP's camera models: id -> (name, number of parameters); those with a ``None`` reader are refused.
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5), 4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
}
_N_PARAMS = {name: n for name, n in CAMERA_MODELS.values()}
_SUPPORTED = ", ".join(PERSPECTIVE_MODELS + FISHEYE_MODELS)


@dataclass(frozen=True)
class ColmapCamera:
    """One COLMAP camera: ``model`` name, image ``width`` x ``height`` and its ``params`` tuple."""

    model: str
    width: int
    height: int
    params: tuple

    def intrinsics_and_distortion(self) -> tuple:
        """``(Intrinsics, Distortion or None)``; ``ValueError`` naming the model when it is not supported."""
        p, m = self.params, self.model
        if m in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
            k = Intrinsics(p[0], p[0], p[1], p[2], self.width, self.height)
        elif m in ("PINHOLE", "OPENCV", "OPENCV_FISHEYE"):
            k = Intrinsics(p[0], p[1], p[2], p[3], self.width, self.height)
        else:
            raise ValueError(f"camera model {m} is not supported (supported: {_SUPPORTED})")
        distortion = None
        if m == "SIMPLE_RADIAL":
            distortion = ("opencv", (p[3], 0.0, 0.0, 0.0, 0.0))
        elif m == "RADIAL":
            distortion = ("opencv", (p[3], p[4], 0.0, 0.0, 0.0))
        elif m == "OPENCV":
            distortion = ("opencv", (p[4], p[5], p[6], p[7], 0.0))
        elif m == "OPENCV_FISHEYE":
            distortion = ("fisheye", tuple(p[4:8]))
        elif m == "SIMPLE_RADIAL_FISHEYE":
            distortion = ("fisheye", (p[3], 0.0, 0.0, 0.0))
        elif m == "RADIAL_FISHEYE":
            distortion = ("fisheye", (p[3], p[4], 0.0, 0.0))
        d = None if distortion is None else Distortion(*distortion)
        return k, (None if d is None or d.is_identity else d)


@dataclass(frozen=True)
class ColmapImage:
    """One registered image: ``image_id``, world-to-camera ``qvec (w, x, y, z)`` and ``tvec``, ``camera_id``,
    ``name`` (relative to the image folder)."""

    image_id: int
    qvec: tuple
    tvec: tuple
    camera_id: int
    name: str

    def c2w(self) -> np.ndarray:
        """``(4, 4)`` float64 OpenCV camera-to-world (the quaternion normalised first)."""
        w, x, y, z = np.asarray(self.qvec, np.float64) / np.linalg.norm(self.qvec)
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        out = np.eye(4)
        out[:3, :3] = rot.T
        out[:3, 3] = -rot.T @ np.asarray(self.tvec, np.float64)
        return out


class _Reader:
    """Sequential reads from a binary model file, each short read an ``InputError`` naming the file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = _read(path, binary=True)
        self.pos = 0

    def _ends_inside(self, what: str) -> InputError:
        return InputError(f"file ends inside {what} (truncated or not a COLMAP model)", file=self.path)

    def take(self, fmt: str, what: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise self._ends_inside(what)
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def skip(self, size: int, what: str) -> None:
        if size < 0 or self.pos + size > len(self.data):
            raise self._ends_inside(what)
        self.pos += size

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise self._ends_inside(what)
        raw, self.pos = self.data[self.pos:end], end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{what}: image name is not UTF-8", file=self.path) from None

    def done(self) -> None:
        if self.pos != len(self.data):
            raise InputError(f"{len(self.data) - self.pos} bytes left after the last record (not a COLMAP model)",
                             file=self.path)


def _read(path: Path, binary: bool = False):
    """A model file's bytes, or its text (UTF-8); ``InputError`` when it cannot be read."""
    try:
        return path.read_bytes() if binary else path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read ({exc})", file=path) from None


def _text_lines(path: Path):
    """``(line number, fields)`` of the non-comment, non-empty lines of a text model file."""
    for number, line in enumerate(_read(path).splitlines(), 1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield number, line.split()


def _numbers(fields, kind, path: Path, where: str) -> list:
    try:
        values = [kind(f) for f in fields]
    except ValueError:
        raise InputError(f"expected numbers, got {' '.join(fields)[:80]!r}", file=path, field=where) from None
    if kind is float and not all(math.isfinite(v) for v in values):
        raise InputError("NaN or inf", file=path, field=where)
    return values


def _camera(model: str, width: int, height: int, params, path: Path, where: str) -> ColmapCamera:
    if len(params) != _N_PARAMS[model]:
        raise InputError(f"{model} takes {_N_PARAMS[model]} parameters, got {len(params)}", file=path, field=where)
    if width < 1 or height < 1:
        raise InputError(f"image size must be positive, got {width}x{height}", file=path, field=where)
    if not all(math.isfinite(p) for p in params):
        raise InputError("NaN or inf in the parameters", file=path, field=where)
    return ColmapCamera(model, int(width), int(height), tuple(float(p) for p in params))


def read_cameras(path: Path) -> dict:
    """``camera_id -> ColmapCamera`` from ``cameras.bin`` or ``cameras.txt``."""
    path = Path(path)
    cams = {}
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.take("Q", "the camera count")
        for i in range(n):
            cam_id, model_id, width, height = r.take("iiQQ", f"camera {i}")
            if model_id not in CAMERA_MODELS:   # a newer COLMAP's model: its parameter count is unknown here
                raise InputError(f"camera model id {model_id} is not one senerf reads (supported: {_SUPPORTED})",
                                 file=path, field=f"camera {cam_id}")
            model, n_params = CAMERA_MODELS[model_id]
            cams[cam_id] = _camera(model, width, height, r.take("d" * n_params, f"camera {cam_id}"), path,
                                   f"camera {cam_id}")
        r.done()
        return cams
    for number, fields in _text_lines(path):
        where = f"line {number}"
        if len(fields) < 4:
            raise InputError("expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]", file=path, field=where)
        if fields[1] not in _N_PARAMS:
            raise InputError(f"camera model {fields[1]} is not supported (supported: {_SUPPORTED})", file=path,
                             field=where)
        cam_id, width, height = _numbers([fields[0], fields[2], fields[3]], int, path, where)
        cams[cam_id] = _camera(fields[1], width, height, _numbers(fields[4:], float, path, where), path, where)
    return cams


def read_images(path: Path) -> list:
    """The registered images (:class:`ColmapImage`, file order) of ``images.bin`` or ``images.txt``; their 2D
    points are skipped (the depth bounds come from ``points3D``'s tracks)."""
    path = Path(path)
    out = []
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.take("Q", "the image count")
        for i in range(n):
            rec = r.take("i7di", f"image {i}")
            name = r.name(f"image {rec[0]}")
            (n_points,) = r.take("Q", f"image {rec[0]}'s point count")
            r.skip(24 * n_points, f"image {rec[0]}'s points")
            out.append(_image(rec[0], rec[1:5], rec[5:8], rec[8], name, path, f"image {rec[0]}"))
        r.done()
        return out
    text = _read(path)
    # as COLMAP reads it: blank and comment lines are skipped to find an image line; the line after it holds
    # the image's 2D points (X Y POINT3D_ID triples), empty when it has none, and must be there
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        if not line or line.startswith("#"):
            i += 1
            continue
        fields, where = line.split(), f"line {i + 1}"
        if len(fields) < 10:
            raise InputError("expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", file=path, field=where)
        image_id, camera_id = _numbers([fields[0], fields[8]], int, path, where)
        values = _numbers(fields[1:8], float, path, where)
        out.append(_image(image_id, values[:4], values[4:7], camera_id, line.split(None, 9)[9].strip(), path,
                          where))
        points = lines[i + 1].split() if i + 1 < len(lines) else []
        if len(points) % 3 or not all(_is_number(f) for f in points):
            raise InputError(f"expected image {image_id}'s 2D points (X Y POINT3D_ID triples, an empty line for "
                             "none): COLMAP writes two lines an image", file=path, field=f"line {i + 2}")
        i += 2
    return out


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _image(image_id, qvec, tvec, camera_id, name, path: Path, where: str) -> ColmapImage:
    q = np.asarray(qvec, np.float64)
    if not np.all(np.isfinite(q)) or not np.all(np.isfinite(tvec)) or not 0.5 < np.linalg.norm(q) < 2.0:
        raise InputError(f"bad pose: qvec {list(qvec)}, tvec {list(tvec)}", file=path, field=where)
    return ColmapImage(int(image_id), tuple(map(float, qvec)), tuple(map(float, tvec)), int(camera_id), name)


def read_points3d(path: Path) -> tuple:
    """3D points and who sees them, from ``points3D.bin`` / ``.txt``: ``xyz (P, 3)`` float64 and
    ``(image_ids (T,), point_index (T,))`` int64, one pair per track element."""
    path = Path(path)
    xyz, image_ids, index = [], [], []
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.take("Q", "the point count")
        for i in range(n):
            rec = r.take("Q3d3BdQ", f"point {i}")
            start = r.pos
            r.skip(8 * rec[8], f"point {rec[0]}'s track")   # checks the length before anything is read
            track = np.frombuffer(r.data, dtype="<i4", count=2 * rec[8], offset=start) if rec[8] else np.zeros(0)
            xyz.append(rec[1:4])
            image_ids.append(track[0::2])
            index.append(np.full(rec[8], i))
        r.done()
    else:
        for number, fields in _text_lines(path):
            where = f"line {number}"
            if len(fields) < 8 or (len(fields) - 8) % 2:
                raise InputError("expected POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX) pairs",
                                 file=path, field=where)
            xyz.append(_numbers(fields[1:4], float, path, where))
            image_ids.append(np.asarray(_numbers(fields[8::2], int, path, where), np.int64))
            index.append(np.full(len(image_ids[-1]), len(xyz) - 1))
    pts = np.asarray(xyz, np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(pts)):
        raise InputError("NaN or inf in the point coordinates", file=path)
    cat = (lambda parts: np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64))
    return pts, (cat(image_ids), cat(index))


def colmap_model_folder(root: Path) -> Path | None:
    """The folder holding the model (see the module docstring), or ``None``."""
    for folder in (root / "sparse" / "0", root / "sparse", root):
        if (folder / "cameras.bin").is_file() or (folder / "cameras.txt").is_file():
            return folder
    return None


def sparse_points(root: Path) -> np.ndarray | None:
    """COLMAP's 3D points of the scene folder ``root``: ``(P, 3)`` float64 in COLMAP's world frame (an
    object capture's frame; a forward-facing scene is normalised after loading), or ``None`` when the model
    has no ``points3D`` file (an object capture needs none).

    Raises:
        InputError: no COLMAP model in ``root``, or a malformed ``points3D`` file.
    """
    folder = colmap_model_folder(Path(root))
    if folder is None:
        raise InputError("no COLMAP model (sparse/0/cameras.bin or cameras.txt)", file=root)
    try:
        path = _model_file(folder, "points3D")
    except InputError:
        return None
    return read_points3d(path)[0]


def _model_file(folder: Path, stem: str) -> Path:
    for suffix in (".bin", ".txt"):
        if (folder / (stem + suffix)).is_file():
            return folder / (stem + suffix)
    raise InputError(f"missing {stem}.bin or {stem}.txt beside the cameras file", file=folder, field=stem)


def _depth_bounds(c2w: np.ndarray, image_ids: list, points: tuple, file: Path) -> np.ndarray:
    """``(n, 2)`` near/far per view: the 0.1th and 99.9th percentile depths of the points each view sees."""
    xyz, (seen_by, point_index) = points
    order = np.argsort(seen_by, kind="stable")
    seen_sorted, index_sorted = seen_by[order], point_index[order]
    bounds = np.zeros((len(image_ids), 2))
    for k, (pose, image_id) in enumerate(zip(c2w, image_ids)):
        lo, hi = np.searchsorted(seen_sorted, [image_id, image_id + 1])
        pts = xyz[np.unique(index_sorted[lo:hi])]  # a point its track lists twice counts once
        z = (pts - pose[:3, 3]) @ pose[:3, 2]
        z = z[z > 0]
        if z.size == 0:
            raise InputError("sees no 3D point in front of it; its depth bounds (forward-facing fits take them from "
                             "the points) are unknown", file=file, field=f"image {image_id}")
        bounds[k] = np.percentile(z, 0.1), np.percentile(z, 99.9)
    return bounds


def view_spread(c2w: np.ndarray, intrinsics) -> tuple:
    """How far a capture's cameras and rays turn from their mean viewing direction.

    Args:
        c2w: ``(n, 4, 4)`` OpenCV camera-to-world.
        intrinsics: ``n`` :class:`Intrinsics`.

    Returns:
        ``(axis_deg, ray_deg, forward_facing)``: the largest angle between a camera's optical axis and the
        normalised sum of them all; the largest between an image corner's ray and that sum; and whether the
        capture is forward-facing: ``axis_deg <= FORWARD_FACING_DEG`` and ``ray_deg <= MAX_RAY_DEG``.
    """
    mean = c2w[:, :3, 2].sum(axis=0)
    mean = mean / max(float(np.linalg.norm(mean)), 1e-12)
    axis = np.degrees(np.arccos(np.clip(c2w[:, :3, 2] @ mean, -1.0, 1.0))).max()
    rays = []
    for pose, k in zip(c2w, intrinsics):
        for u, v in ((0.0, 0.0), (k.width, 0.0), (0.0, k.height), (k.width, k.height)):
            d = pose[:3, :3] @ np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0])
            rays.append(d / np.linalg.norm(d))
    ray = np.degrees(np.arccos(np.clip(np.asarray(rays) @ mean, -1.0, 1.0))).max()
    return float(axis), float(ray), bool(axis <= FORWARD_FACING_DEG and ray <= MAX_RAY_DEG)


def load_colmap(root: Path, downscale: float = 1.0, bd_factor: float | None = 0.75, recenter: bool = True,
                kind: str | None = None) -> Scene:
    """Load a COLMAP scene folder; see the module docstring.

    Args:
        root: the scene folder (``sparse/0/`` and ``images/`` inside).
        downscale: divide image sides by this (``>= 1``).
        bd_factor, recenter: LLFF's normalisation of a forward-facing capture (:func:`load_llff`); unused for
            an object capture, which keeps COLMAP's world frame.
        kind: ``None`` to decide from :func:`view_spread`, or ``'object'`` / ``'forward_facing'`` (the latter
            refused when a ray turns 90 degrees or more from the mean direction: NDC cannot hold it).

    Raises:
        InputError: a missing or malformed model file, an unsupported camera model, a missing image, an image
            whose size is not its camera's, a forward-facing capture with more than one camera or an image
            that sees no point.
    """
    root = Path(root)
    if kind not in (None, "object", "forward_facing"):
        raise InputError(f"expected 'object' or 'forward_facing', got {kind!r}", field="kind")
    folder = colmap_model_folder(root)
    if folder is None:
        raise InputError("no COLMAP model (sparse/0/cameras.bin or cameras.txt)", file=root)
    cam_file, img_file = _model_file(folder, "cameras"), _model_file(folder, "images")
    cameras = read_cameras(cam_file)
    images = sorted(read_images(img_file), key=lambda im: im.name)
    if not images:
        raise InputError("no registered image", file=img_file)
    # names compared as paths: "./a.png" and "a.png" are one photo
    for key, what in ((lambda im: im.image_id, "id"),
                      (lambda im: os.path.normpath(im.name.replace("\\", "/")), "name")):
        values = [key(im) for im in images]
        twice = sorted({v for v in values if values.count(v) > 1}, key=str)
        if twice:
            raise InputError(f"image {what} {twice[0]!r} appears {values.count(twice[0])} times", file=img_file)
    image_folder = llff_image_folder(root, downscale)   # images/ or images_N/ (N <= downscale, exact preferred)
    factor = _folder_factor(image_folder.name)
    entries, c2w = [], []
    for im in images:
        where = f"image {im.image_id} ({im.name})"
        if im.camera_id not in cameras:
            raise InputError(f"camera {im.camera_id} is not in {cam_file.name}", file=img_file, field=where)
        try:
            k, distortion = cameras[im.camera_id].intrinsics_and_distortion()
        except ValueError as exc:
            raise InputError(str(exc), file=cam_file, field=f"camera {im.camera_id}") from None
        path = _io.resolve_inside(image_folder, im.name, img_file, where)
        entries.append(dict(path=path, field=where, file=img_file, k_photo=k, distortion=distortion,
                            distortion_file=cam_file, distortion_field=f"camera {im.camera_id}"))
        pose = im.c2w()
        _io.check_rigid(pose, img_file, where)
        c2w.append(pose)
    c2w = np.stack(c2w)

    def photo_camera(e: dict, height: int, width: int) -> Intrinsics:
        """The camera at the decoded size: the model's own, or scaled to an images_N/ photo."""
        k = e["k_photo"]
        if (height, width) == k.size:
            return k
        if factor > 1 and abs(height * factor - k.height) <= factor and abs(width * factor - k.width) <= factor:
            return k.resized(width, height)
        raise InputError(f"image is {width}x{height} but its camera is {k.width}x{k.height}"
                         + (f" (/{factor} in {image_folder.name}: about {k.width / factor:.0f}x"
                            f"{k.height / factor:.0f})" if factor > 1 else ""), file=e["file"], field=e["field"])

    undistorter = Undistorter(entries, photo_camera)
    # an images_N/ folder at exactly the factor asked is used at its own size; any other is area-resized to
    # the size the cameras give at that factor
    size = None if factor == downscale else _io.target_size(entries[0]["k_photo"].height, entries[0]["k_photo"].width,
                                                              downscale)
    rgb, alpha, (h0, w0) = _io.load_images([e["path"] for e in entries], [e["field"] for e in entries],
                                           [e["file"] for e in entries], size=size, prepare=undistorter)
    h, w = rgb.shape[1:3]
    intr = tuple(k.resized(w, h) for k in undistorter.cameras(h0, w0))
    _, ray_deg, forward_facing = view_spread(c2w, intr)
    if kind is None:
        kind = "forward_facing" if forward_facing else "object"
    elif kind == "forward_facing" and ray_deg >= 90.0:
        raise InputError(f"some rays look {ray_deg:.0f} degrees away from the cameras' mean direction; a "
                         "forward-facing (NDC) fit needs every ray within 90", field="kind")
    idx = np.arange(len(images))
    splits = {"train": idx[idx % LLFF_HOLDOUT != 0], "val": idx[:0], "test": idx[idx % LLFF_HOLDOUT == 0]}
    common = dict(name=root.resolve().name, root=root, rgb=rgb, alpha=alpha, intrinsics=intr[0],
                  intrinsics_all=intr, image_paths=tuple(e["path"] for e in entries),
                  source_files=(cam_file, img_file))
    if kind == "object":
        return Scene(c2w=c2w, splits=splits, kind="object", near=None, far=None, **common)
    if len(set(intr)) > 1:
        raise InputError("a forward-facing capture is fitted in one NDC frustum, built from one camera; these "
                         f"images use {len(set(intr))} different cameras", file=cam_file)
    points_file = _model_file(folder, "points3D")
    bounds = _depth_bounds(c2w, [im.image_id for im in images], read_points3d(points_file), points_file)
    c2w, bounds = normalise_forward_facing(c2w, bounds, bd_factor, recenter)
    common["source_files"] += (points_file,)   # its depth bounds set the scene's scale
    return Scene(c2w=c2w, splits=splits, kind="forward_facing", near=float(bounds.min()), far=float(bounds.max()), **common)
