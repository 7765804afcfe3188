"""Loader for LLFF forward-facing scenes (``poses_bounds.npy`` + ``images/`` or ``images_N/``).

``poses_bounds.npy`` is an ``(N, 17)`` array: 15 numbers reshape to ``3 x 5 = [R | t | (H, W, f)]`` at
full resolution, rotation columns ordered ``[down, right, back]``, then the near/far depth bounds of the
image.  Images are the sorted image files of the chosen folder, one per row.

Folder choice: ``downscale`` is relative to the full resolution ``(H, W)`` of ``poses_bounds.npy``.
``images_{downscale}/`` is used when it exists (``downscale=8`` -> ``images_8/``), at its own size; otherwise the
folder with the largest factor ``k <= downscale`` (``images/`` counts as ``k = 1``) is resized (:mod:`.load`).
There is no upsampling: if only ``images_8/`` exists, ``downscale=1`` is an error that lists the folders found.

Normalisation (the standard LLFF recipe of the NeRF code, kept as parameters):

1. ``bd_factor`` (default 0.75): scale the world so that the smallest near bound becomes ``1 / bd_factor``
   (camera centres and bounds are multiplied by ``1 / (min(near) * bd_factor)``); ``None`` skips it.
2. ``recenter`` (default True): left-multiply every pose by the inverse of the average pose (mean camera
   centre, ``z`` = normalised sum of the forward axes, ``x`` = normalise(sum of the down axes x ``z``),
   ``y = z x x``), so the average camera is the identity: world x right, y down, z forward (the OpenCV camera
   convention).  This is the NeRF code's world frame rotated 180 degrees about x (it recentres in OpenGL's).

Splits: :func:`llff_splits`.  ``near`` / ``far`` are the smallest near and largest far bound after scaling.
The scene is fitted in one NDC frustum: every row shares one focal length, every ray lies within 90 degrees of
the cameras' mean direction, and far / near is at most :data:`MAX_DEPTH_RANGE`.

Convention:
    LLFF rotation columns are ``[down, right, back]``; the OpenCV camera axes are ``x = right = column 1``,
    ``y = down = column 0``, ``z = forward = -column 2`` (a proper rotation: one swap and one sign flip).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError, is_number
from ..geometry import Intrinsics, invert_rigid
from . import _io
from .scene import Scene

__all__ = ["load_llff", "llff_image_folder", "folder_factor", "llff_splits", "normalise_forward_facing",
           "MAX_DEPTH_RANGE"]

#: The largest far / near ratio over a forward-facing scene's bounds: beyond it the NDC near plane sits so close
#: that the rays' NDC depths lose their precision.
MAX_DEPTH_RANGE = 1e6


def llff_splits(n: int) -> dict:
    """LLFF's splits of ``n`` views: ``'test'`` every 8th (``index % 8 == 0``), ``'train'`` the rest, ``'val'``
    empty; int64 index arrays."""
    idx = np.arange(n, dtype=np.int64)
    return {"train": idx[idx % 8 != 0], "val": idx[:0], "test": idx[idx % 8 == 0]}


def _read_poses_bounds(file: Path) -> tuple:
    """The ``(N, 17)`` float64 rows, checked (finite; positive ``H, W, f`` shared by every row; ``0 < near <= far``
    with far / near up to :data:`MAX_DEPTH_RANGE`), and their ``(N, 4, 4)`` OpenCV poses, checked rigid."""
    if not file.is_file():
        raise InputError("file not found", file=file)
    try:
        with open(file, "rb") as fh:
            arr = np.lib.format.read_array(fh, allow_pickle=False)
    except Exception as exc:  # ValueError (not a .npy file), OSError, EOFError
        raise InputError(f"not a .npy file ({type(exc).__name__}: {exc})", file=file) from None
    if arr.dtype.kind not in "biuf" or arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] < 1:
        raise InputError(f"expected a numeric array of shape (N, 17), N >= 1, got {arr.dtype} {arr.shape}",
                         file=file, field="shape")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise InputError("contains NaN or inf", file=file, field=f"row {np.argwhere(~np.isfinite(arr))[0, 0]}")
    hwf, bounds = arr[:, 4:15:5], arr[:, 15:17]   # (H, W, f): column 4 of each row of the 3 x 5 matrix
    for bad, problem, field in ((hwf <= 0, "must be positive", "hwf.{}"),
                                (hwf[:, :2] != hwf[0, :2], "all rows must share one image size", "hwf.H,W"),
                                (hwf[:, 2:] != hwf[0, 2:], "all rows must share one focal length (NDC uses one)",
                                 "hwf.f"),
                                (~(bounds[:, :1] > 0) | (bounds[:, :1] > bounds[:, 1:]), "expected 0 < near <= far",
                                 "bounds")):
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise InputError(f"{problem}; the row has H, W, f = {hwf[i].tolist()} and near, far = "
                             f"{bounds[i].tolist()}", file=file, field=f"row {i} " + field.format("HWf"[j]))
    if not bounds[:, 1].max() / bounds[:, 0].min() <= MAX_DEPTH_RANGE:   # NDC's near plane: the smallest near
        i = int(np.argmin(bounds[:, 0]))
        raise InputError(f"near bound {bounds[i, 0]:g} is {bounds[:, 1].max() / bounds[i, 0]:.3g} times smaller than "
                         f"the largest far bound; forward-facing scenes are fitted with far / near up to "
                         f"{MAX_DEPTH_RANGE:g}", file=file, field=f"row {i} bounds")
    mats = arr[:, :15].reshape(-1, 3, 5)
    c2w = np.zeros((len(mats), 4, 4))
    c2w[:, :3] = mats[:, :, [1, 0, 2, 3]] * [1.0, 1.0, -1.0, 1.0]   # [down, right, back] -> [right, down, forward]
    c2w[:, 3, 3] = 1.0
    for i, pose in enumerate(c2w):
        _io.check_rigid(pose, file, f"row {i} [R|t]")
    return arr, c2w


def normalise_forward_facing(c2w: np.ndarray, bounds: np.ndarray, bd_factor: float | None = 0.75,
                             recenter: bool = True) -> tuple:
    """LLFF's normalisation (module docstring: scaled by ``bd_factor``, then recentred) of ``c2w (N, 4, 4)``
    OpenCV poses and their ``bounds (N, 2)`` near/far.  Returns new ``(c2w, bounds)``, float64.

    Raises:
        InputError: ``bd_factor`` not a positive finite number (field ``bd_factor``).
    """
    c2w, bounds = np.array(c2w, np.float64), np.array(bounds, np.float64)
    if bd_factor is not None:
        if not is_number(bd_factor) or bd_factor <= 0:
            raise InputError(f"must be positive, got {bd_factor!r}", field="bd_factor")
        scale = 1.0 / (bounds.min() * float(bd_factor))
        c2w[:, :3, 3] *= scale
        bounds *= scale
    if recenter:   # the average pose becomes the identity
        z = c2w[:, :3, 2].sum(axis=0)
        z = z / np.linalg.norm(z)
        x = np.cross(c2w[:, :3, 1].sum(axis=0), z)
        x = x / np.linalg.norm(x)
        avg = np.eye(4)
        avg[:3, 0], avg[:3, 1], avg[:3, 2], avg[:3, 3] = x, np.cross(z, x), z, c2w[:, :3, 3].mean(axis=0)
        c2w = invert_rigid(avg) @ c2w
    return c2w, bounds


def folder_factor(name: str) -> int | None:
    """The downscale factor of an image folder's name: 1 for ``images``, N for ``images_N``, else ``None``."""
    if name == "images":
        return 1
    return int(name[7:]) if name.startswith("images_") and name[7:].isdigit() and int(name[7:]) >= 1 else None


def llff_image_folder(root: Path, downscale: float) -> Path:
    """The image folder to read for ``downscale`` (see the module docstring); ``InputError`` if none fits."""
    folders = sorted(p for p in Path(root).iterdir() if p.is_dir())
    found = {folder_factor(p.name): p for p in folders if folder_factor(p.name) is not None}
    usable = [k for k in found if k <= downscale + 1e-9]
    if not usable:
        raise InputError(f"no image folder at factor <= {downscale:g}; found: "
                         + (", ".join(found[k].name for k in sorted(found)) + f" (e.g. downscale={min(found)})"
                            if found else "none"), file=root, field="images")
    exact = [k for k in usable if abs(k - downscale) < 1e-9]
    return found[exact[0] if exact else max(usable)]


def load_llff(root: Path, downscale: float = 1.0, bd_factor: float | None = 0.75, recenter: bool = True) -> Scene:
    """Load an LLFF scene folder; see the module docstring for the folder choice and the normalisation.

    Args:
        root: the scene folder holding ``poses_bounds.npy``.
        downscale: image shrink factor relative to the full resolution in ``poses_bounds.npy`` (``>= 1``).
        bd_factor, recenter: the normalisation (module docstring); ``bd_factor=None`` keeps the original scale.

    Returns:
        A :class:`Scene` with ``kind='forward_facing'``, ``near``/``far`` after scaling, splits as above.

    Raises:
        InputError: naming the file and field (a bad ``poses_bounds.npy``, rays an NDC frustum cannot hold, no
            suitable image folder, a wrong image count or size, a corrupt image).
    """
    from .colmap import colmap_model_folder, view_spread   # here: colmap imports this module

    root = Path(root)
    file = root / "poses_bounds.npy"
    arr, c2w = _read_poses_bounds(file)
    n, bounds = len(arr), arr[:, 15:17]
    full_h, full_w, focal = max(1, int(round(arr[0, 4]))), max(1, int(round(arr[0, 9]))), arr[0, 14]
    c2w, bounds = normalise_forward_facing(c2w, bounds, bd_factor, recenter)
    full_k = Intrinsics(focal, focal, 0.5 * full_w, 0.5 * full_h, full_w, full_h)
    _, ray_deg, _ = view_spread(c2w, [full_k] * n)
    if not ray_deg < 90.0:   # NDC holds the half-space in front of the mean camera only
        i = int(np.argmin(c2w[:, :3, 2] @ c2w[:, :3, 2].sum(axis=0)))
        hint = (" (the cameras surround the scene; this folder also holds a COLMAP model, which senerf fits as an "
                "object scene: move poses_bounds.npy aside)" if colmap_model_folder(root) is not None else "")
        raise InputError(f"some rays look {ray_deg:.0f} degrees away from the cameras' mean direction; a "
                         f"forward-facing (NDC) fit needs every ray within 90 (row {i}'s camera turns furthest)"
                         + hint, file=file, field=f"row {i}")

    folder = llff_image_folder(root, downscale)
    paths = sorted(p for p in folder.iterdir()
                   if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in _io.IMAGE_SUFFIXES)
    if len(paths) != n:
        raise InputError(f"{len(paths)} images but {n} rows in poses_bounds.npy", file=folder, field="images")
    k = folder_factor(folder.name)

    def photo_camera(e: dict, height: int, width: int) -> Intrinsics:
        """The full-resolution camera, once the photo is checked to be its size divided by ``k`` (to a pixel)."""
        if abs(height * k - full_h) > k or abs(width * k - full_w) > k:
            raise InputError(f"images are {width}x{height}, but poses_bounds.npy's H, W = {full_h}, {full_w} at "
                             f"factor {k} give {full_w / k:.0f}x{full_h / k:.0f}", file=folder, field="images")
        return full_k

    # the exact folder at its own size (LLFF's images_N may round sides differently), any other resized
    size = None if k == downscale else _io.target_size(full_h, full_w, downscale)
    entries = [dict(path=p, field=p.name, file=folder, distortion=None) for p in paths]
    rgb, alpha, intr = _io.load_photos(entries, photo_camera, size=size)
    return Scene(name=root.resolve().name, root=root, rgb=rgb, alpha=alpha, intrinsics=intr[0], intrinsics_all=intr,
                 c2w=c2w, splits=llff_splits(n), kind="forward_facing", near=float(bounds.min()),
                 far=float(bounds.max()), image_paths=tuple(paths), source_files=(file,))
