"""Loader for COLMAP sparse reconstructions (``sparse/0/{cameras,images,points3D}.{bin,txt}`` + ``images/``).

The three model files are read in either of COLMAP's formats (binary or text) with NumPy.  Camera models: those
of :data:`~senerf.data.undistort.PERSPECTIVE_MODELS` and ``FISHEYE_MODELS``, their lens distortion undone at load
(:mod:`senerf.data.undistort`); others are refused.

Folders: the model is the first of ``ROOT/sparse/0/``, ``ROOT/sparse/``, ``ROOT/`` holding ``cameras.bin`` or
``cameras.txt`` (binary preferred when both exist); images are ``ROOT/images/NAME`` for each registered
image's ``NAME``, or ``ROOT/images_N/NAME`` as LLFF and nerfstudio write downscaled copies, the folder chosen
as LLFF's (:func:`senerf.data.llff.llff_image_folder`), its photos their cameras' size divided by ``N`` (to a
pixel).  Views are the registered images sorted by name (LLFF's order), at ``1 / downscale`` of their cameras'
size, split as LLFF's (:func:`~senerf.data.llff.llff_splits`).

Kind: **forward-facing** when every camera and ray looks close to the cameras' mean viewing direction
(:func:`view_spread`), else **unbounded** (a capture around something, background in every photo, kept in
COLMAP's world frame), or **object** for photos with alpha. A forward-facing scene is normalised as :func:`load_llff`
normalises LLFF (``bd_factor``, ``recenter``); its per-image depth bounds are what LLFF's ``imgs2poses`` takes, the
0.1th and 99.9th percentiles of the depths of the 3D points each image sees, and it needs one camera (NDC is built from
one focal length).

Convention:
    COLMAP stores world-to-camera ``(qvec (w, x, y, z), tvec)`` in the OpenCV camera convention, and puts
    pixel centres at ``i + 0.5`` as :class:`senerf.geometry.Intrinsics` does: only the inversion to ``c2w``
    happens here.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Intrinsics
from . import _io
from .llff import folder_factor, llff_image_folder, llff_splits, normalise_forward_facing
from .scene import SCENE_KINDS, Scene
from .undistort import FISHEYE_MODELS, PERSPECTIVE_MODELS, Distortion

__all__ = ["load_colmap", "colmap_model_folder", "view_spread", "read_cameras", "read_images", "read_points3d",
           "sparse_points", "ColmapCamera", "ColmapImage", "FORWARD_FACING_DEG", "MAX_RAY_DEG", "CAMERA_MODELS"]

#: The largest camera and ray angles (degrees) of a forward-facing capture (module docstring, :func:`view_spread`).
FORWARD_FACING_DEG = 30.0
MAX_RAY_DEG = 80.0

#: COLMAP's camera models: id -> (name, number of parameters); those missing from ``_READ`` are refused.
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5), 4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
}
_N_PARAMS = {name: n for name, n in CAMERA_MODELS.values()}
_SUPPORTED = ", ".join(PERSPECTIVE_MODELS + FISHEYE_MODELS)
#: How the supported models' parameters read (COLMAP's ``src/colmap/sensor/models.h``): indices of ``fx, fy, cx,
#: cy``, the distortion model, indices of its coefficients in OpenCV's order (``-1``: one the model lacks, 0).
_READ = {
    "SIMPLE_PINHOLE": ((0, 0, 1, 2), None, ()),
    "PINHOLE": ((0, 1, 2, 3), None, ()),
    "SIMPLE_RADIAL": ((0, 0, 1, 2), "opencv", (3, -1, -1, -1, -1)),
    "RADIAL": ((0, 0, 1, 2), "opencv", (3, 4, -1, -1, -1)),
    "OPENCV": ((0, 1, 2, 3), "opencv", (4, 5, 6, 7, -1)),
    "OPENCV_FISHEYE": ((0, 1, 2, 3), "fisheye", (4, 5, 6, 7)),
    "SIMPLE_RADIAL_FISHEYE": ((0, 0, 1, 2), "fisheye", (3, -1, -1, -1)),
    "RADIAL_FISHEYE": ((0, 0, 1, 2), "fisheye", (3, 4, -1, -1)),
}


@dataclass(frozen=True)
class ColmapCamera:
    """One COLMAP camera: ``model`` name, image ``width`` x ``height`` and its ``params`` tuple."""

    model: str
    width: int
    height: int
    params: tuple

    def intrinsics_and_distortion(self) -> tuple:
        """``(Intrinsics, Distortion or None)``; ``ValueError`` naming the model when it is not supported."""
        if self.model not in _READ:
            raise ValueError(f"camera model {self.model} is not supported (supported: {_SUPPORTED})")
        focal_centre, model, coeffs = _READ[self.model]
        p = self.params + (0.0,)
        k = Intrinsics(*(p[i] for i in focal_centre), self.width, self.height)
        d = None if model is None else Distortion(model, tuple(p[i] for i in coeffs))
        return k, (None if d is None or d.is_identity else d)


@dataclass(frozen=True)
class ColmapImage:
    """One registered image: ``image_id``, world-to-camera ``qvec (w, x, y, z)``, ``tvec``, ``camera_id``, ``name``."""

    image_id: int
    qvec: tuple
    tvec: tuple
    camera_id: int
    name: str

    def c2w(self) -> np.ndarray:
        """``(4, 4)`` float64 OpenCV camera-to-world (the quaternion normalised first, as COLMAP does)."""
        w, x, y, z = np.asarray(self.qvec, np.float64) / np.linalg.norm(self.qvec)
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        out = np.eye(4)
        out[:3, :3] = rot.T
        out[:3, 3] = -rot.T @ np.asarray(self.tvec, np.float64)
        return out


def _read(path: Path, binary: bool = False):
    """A model file's bytes, or its text (UTF-8); ``InputError`` when it cannot be read."""
    try:
        return path.read_bytes() if binary else path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read ({exc})", file=path) from None


class _Reader:
    """Sequential reads from a binary model file, each short read an ``InputError`` naming the file."""

    def __init__(self, path: Path) -> None:
        self.path, self.data, self.pos = path, _read(path, binary=True), 0

    def skip(self, size: int, what: str) -> int:
        """Move past ``size`` bytes; returns where they start."""
        if size < 0 or self.pos + size > len(self.data):
            raise InputError(f"file ends inside {what} (truncated or not a COLMAP model)", file=self.path)
        self.pos += size
        return self.pos - size

    def take(self, fmt: str, what: str) -> tuple:
        return struct.unpack_from("<" + fmt, self.data, self.skip(struct.calcsize("<" + fmt), what))

    def name(self, what: str) -> str:
        """A NUL-terminated name, decoded as the file system does (``os.fsdecode``: any bytes are a name)."""
        end = self.data.find(b"\0", self.pos)   # the name and its NUL; no NUL is a short read
        return self.data[self.skip(end + 1 - self.pos if end >= 0 else -1, what):end].decode("utf-8", "surrogateescape")


def _text_lines(path: Path):
    """``(line number, fields)`` of the non-comment, non-empty lines of a text model file."""
    for number, line in enumerate(_read(path).splitlines(), 1):
        if line.strip() and not line.lstrip().startswith("#"):
            yield number, line.split()


def _numbers(fields, kind, path: Path, where: str) -> list:
    try:
        values = [kind(f) for f in fields]
    except ValueError:
        raise InputError(f"expected numbers, got {' '.join(fields)[:80]!r}", file=path, field=where) from None
    if kind is float and not all(math.isfinite(v) for v in values):
        raise InputError("NaN or inf", file=path, field=where)
    return values


def read_cameras(path: Path) -> dict:
    """``camera_id -> ColmapCamera`` from ``cameras.bin`` or ``cameras.txt``."""
    path, cams = Path(path), {}
    if path.suffix == ".bin":
        r = _Reader(path)
        for i in range(r.take("Q", "the camera count")[0]):
            cam_id, model_id, width, height = r.take("iiQQ", f"camera {i}")
            if model_id not in CAMERA_MODELS:   # a newer COLMAP's model: its parameter count is unknown here
                raise InputError(f"camera model id {model_id} is not one senerf reads (supported: {_SUPPORTED})",
                                 file=path, field=f"camera {cam_id}")
            model, n_params = CAMERA_MODELS[model_id]
            cams[cam_id] = ColmapCamera(model, width, height, r.take("d" * n_params, f"camera {cam_id}"))
        return cams
    for number, fields in _text_lines(path):
        where, model = f"line {number}", (fields + [""])[1]
        if model not in _N_PARAMS:
            raise InputError(f"camera model {model} is not supported (supported: {_SUPPORTED})", file=path, field=where)
        if len(fields) != 4 + _N_PARAMS[model]:
            raise InputError(f"expected CAMERA_ID MODEL WIDTH HEIGHT and the {_N_PARAMS[model]} parameters of {model}, "
                             f"got {len(fields)} fields", file=path, field=where)
        cam_id, width, height = _numbers([fields[0], fields[2], fields[3]], int, path, where)
        cams[cam_id] = ColmapCamera(fields[1], width, height, tuple(_numbers(fields[4:], float, path, where)))
    return cams


def read_images(path: Path) -> list:
    """The registered images (:class:`ColmapImage`, file order) of ``images.bin`` or ``images.txt``; their 2D
    points are skipped (the depth bounds come from ``points3D``'s tracks)."""
    path, out = Path(path), []
    if path.suffix == ".bin":
        r = _Reader(path)
        for i in range(r.take("Q", "the image count")[0]):
            rec = r.take("i7di", f"image {i}")
            name = r.name(f"image {rec[0]}")
            r.skip(24 * r.take("Q", f"image {rec[0]}'s point count")[0], f"image {rec[0]}'s points")
            out.append(ColmapImage(rec[0], rec[1:5], rec[5:8], rec[8], name))
        return out
    # as COLMAP reads it: blank and comment lines are skipped to find an image line; the line after it holds
    # the image's 2D points (X Y POINT3D_ID triples), empty when it has none, and must be there
    lines, i = _read(path).splitlines(), 0
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
        out.append(ColmapImage(image_id, tuple(values[:4]), tuple(values[4:7]), camera_id, line.split(None, 9)[9]))
        points = lines[i + 1].split() if i + 1 < len(lines) else []
        try:
            np.asarray(points, np.float64).reshape(-1, 3)
        except ValueError:
            raise InputError(f"expected image {image_id}'s 2D points (X Y POINT3D_ID triples, an empty line for "
                             "none): COLMAP writes two lines an image", file=path, field=f"line {i + 2}") from None
        i += 2
    return out


def read_points3d(path: Path) -> tuple:
    """3D points and who sees them, from ``points3D.bin`` / ``.txt``: ``xyz (P, 3)`` float64 and
    ``(image_ids (T,), point_index (T,))`` int64, one pair per track element."""
    path = Path(path)
    xyz, image_ids, index = [], [], []
    if path.suffix == ".bin":
        r = _Reader(path)
        for i in range(r.take("Q", "the point count")[0]):
            rec = r.take("Q3d3BdQ", f"point {i}")
            start = r.skip(8 * rec[8], f"point {rec[0]}'s track")   # checks the length before anything is read
            xyz.append(rec[1:4])
            image_ids.append(np.frombuffer(r.data, dtype="<i4", count=2 * rec[8], offset=start)[0::2])
            index.append(np.full(rec[8], i))
    else:
        for number, fields in _text_lines(path):
            where = f"line {number}"
            if len(fields) < 8 or (len(fields) - 8) % 2:
                raise InputError("expected POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX) pairs",
                                 file=path, field=where)
            xyz.append(_numbers(fields[1:4], float, path, where))
            image_ids.append(np.asarray(_numbers(fields[8::2], int, path, where), np.int64))
            index.append(np.full(len(image_ids[-1]), len(xyz) - 1))
    cat = (lambda parts: np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64))
    return np.asarray(xyz, np.float64).reshape(-1, 3), (cat(image_ids), cat(index))


def colmap_model_folder(root: Path) -> Path | None:
    """The folder holding the model (see the module docstring), or ``None``."""
    for folder in (root / "sparse" / "0", root / "sparse", root):
        if (folder / "cameras.bin").is_file() or (folder / "cameras.txt").is_file():
            return folder
    return None


def _model_file(root: Path, stem: str, missing_ok: bool = False) -> Path | None:
    """``stem``'s file (``.bin`` preferred to ``.txt``) in the model folder of the scene folder ``root``."""
    folder = colmap_model_folder(Path(root))
    if folder is None:
        raise InputError("no COLMAP model (sparse/0/cameras.bin or cameras.txt)", file=root)
    for suffix in (".bin", ".txt"):
        if (folder / (stem + suffix)).is_file():
            return folder / (stem + suffix)
    if missing_ok:
        return None
    raise InputError(f"missing {stem}.bin or {stem}.txt beside the cameras file", file=folder, field=stem)


def sparse_points(root: Path) -> np.ndarray | None:
    """COLMAP's 3D points of the scene folder ``root``: ``(P, 3)`` float64 in COLMAP's world frame (an object
    capture's; a forward-facing scene is normalised after loading), or ``None`` without a ``points3D`` file.

    Raises:
        InputError: no COLMAP model in ``root``, or a malformed ``points3D`` file.
    """
    path = _model_file(root, "points3D", missing_ok=True)
    return None if path is None else read_points3d(path)[0]


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
        bd_factor, recenter: LLFF's normalisation of a forward-facing capture (:func:`load_llff`).
        kind: ``None`` to decide as the module docstring says, or one of :data:`~senerf.data.SCENE_KINDS`
            (``'forward_facing'`` is refused when a ray turns 90 degrees or more from the mean direction: NDC
            cannot hold it).

    Raises:
        InputError: naming the file and field (a bad model file or camera model, a missing or mis-sized image; a
            forward-facing capture with several cameras or an image that sees no point).
    """
    root = Path(root)
    if kind is not None and kind not in SCENE_KINDS:
        raise InputError(f"expected one of {', '.join(SCENE_KINDS)}, got {kind!r}", field="kind")
    cam_file, img_file = _model_file(root, "cameras"), _model_file(root, "images")
    cameras = read_cameras(cam_file)
    images = sorted(read_images(img_file), key=lambda im: im.name)
    if not images:
        raise InputError("no registered image", file=img_file)
    image_folder = llff_image_folder(root, downscale)   # images/ or images_N/ (N <= downscale, exact preferred)
    factor = folder_factor(image_folder.name)
    entries, c2w = [], []
    for im in images:
        where = f"image {im.image_id} ({im.name})"
        if im.camera_id not in cameras:
            raise InputError(f"camera {im.camera_id} is not in {cam_file.name}", file=img_file, field=where)
        try:
            k, distortion = cameras[im.camera_id].intrinsics_and_distortion()
        except ValueError as exc:
            raise InputError(str(exc), file=cam_file, field=f"camera {im.camera_id}") from None
        entries.append(dict(path=_io.resolve_inside(image_folder, im.name, img_file, where), field=where,
                            file=img_file, k_photo=k, distortion=distortion, distortion_file=cam_file,
                            distortion_field=f"camera {im.camera_id}"))
        c2w.append(im.c2w())
        _io.check_rigid(c2w[-1], img_file, where)
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

    k0 = entries[0]["k_photo"]
    size = None if factor == downscale else _io.target_size(k0.height, k0.width, downscale)
    rgb, alpha, intr = _io.load_photos(entries, photo_camera, size=size)
    axis_deg, ray_deg, forward_facing = view_spread(c2w, intr)
    if kind is None and forward_facing:
        kind, why = "forward_facing", (f"the cameras all look one way (axes within {axis_deg:.0f} degrees, rays "
                                       f"within {ray_deg:.0f} of their mean direction): forward-facing, fitted in NDC")
    elif kind is None:
        kind, why = ("object", "photos with alpha: an object on a transparent background") if alpha is not None \
            else ("unbounded", f"RGB photos without alpha, cameras looking up to {axis_deg:.0f} degrees away from "
                               "their mean direction: background in every pixel, fitted as an unbounded scene")
    elif kind == "forward_facing" and (ray_deg >= 90.0 or axis_deg > 2 * FORWARD_FACING_DEG):
        raise InputError(f"the cameras look up to {axis_deg:.0f} degrees and their rays up to {ray_deg:.0f} degrees "
                         "away from their mean direction (cameras around the scene); a forward-facing (NDC) fit "
                         f"needs the cameras within {2 * FORWARD_FACING_DEG:.0f} and every ray within 90",
                         field="kind")
    else:
        why = "chosen with --scene-kind"
    common = dict(name=root.resolve().name, root=root, rgb=rgb, alpha=alpha, intrinsics=intr[0],
                  intrinsics_all=intr, splits=llff_splits(len(images)), image_paths=tuple(e["path"] for e in entries),
                  kind_reason=why)
    if kind != "forward_facing":
        return Scene(c2w=c2w, kind=kind, source_files=(cam_file, img_file), **common)
    if len(set(intr)) > 1:
        raise InputError("a forward-facing capture is fitted in one NDC frustum, built from one camera; these "
                         f"images use {len(set(intr))} different cameras", file=cam_file)
    points_file = _model_file(root, "points3D")   # its depth bounds set the scene's scale
    bounds = _depth_bounds(c2w, [im.image_id for im in images], read_points3d(points_file), points_file)
    c2w, bounds = normalise_forward_facing(c2w, bounds, bd_factor, recenter)
    return Scene(c2w=c2w, kind="forward_facing", near=float(bounds.min()), far=float(bounds.max()),
                 source_files=(cam_file, img_file, points_file), **common)
