"""Loader for LLFF forward-facing scenes (``poses_bounds.npy`` + ``images/`` or ``images_N/``).

``poses_bounds.npy`` is an ``(N, 17)`` array: 15 numbers reshape to ``3 x 5 = [R | t | (H, W, f)]`` at
full resolution, rotation columns ordered ``[down, right, back]``, then the near/far depth bounds of the
image.  Images are the sorted image files of the chosen folder, one per row.

Folder choice: ``downscale`` is relative to the full resolution ``(H, W)`` of ``poses_bounds.npy``.
``images_{downscale}/`` is used when it exists (``downscale=8`` -> ``images_8/``, the few-shot protocol's
504x378 for fern); otherwise the folder with the largest factor ``k <= downscale`` (``images/`` counts as
``k = 1``) is area-resized to ``floor(side / downscale + 0.5)``.  There is no upsampling: if only
``images_8/`` exists, ``downscale=1`` is an error that lists the folders found.

Normalisation (the standard LLFF recipe of the NeRF code, kept as parameters):

1. ``bd_factor`` (default 0.75): scale the world so that the smallest near bound becomes ``1 / bd_factor``
   (camera centres and bounds are multiplied by ``1 / (min(near) * bd_factor)``); ``None`` skips it.
2. ``recenter`` (default True): left-multiply every pose by the inverse of the average pose (mean camera
   centre; forward axis = normalised sum of forward axes; right axis from the summed down axes), so the
   average camera is the identity: world x right, y down, z forward (the OpenCV camera convention).  This
   is the NeRF code's world frame rotated 180 degrees about x (it recentres in the OpenGL convention).

Splits: ``'test'`` is every 8th image (``index % 8 == 0``), ``'train'`` the rest, ``'val'`` empty.
``near`` / ``far`` are the smallest near and largest far bound after scaling (NeRF's code then uses
``0.9 * near`` for non-NDC rendering; that choice belongs to the renderer).

Convention:
    LLFF rotation columns are ``[down, right, back]``; the OpenCV camera axes are ``x = right = column 1``,
    ``y = down = column 0``, ``z = forward = -column 2`` (a proper rotation: one swap and one sign flip).
    This is the only place the LLFF convention is converted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Intrinsics, invert_rigid
from . import _io
from .scene import Scene

__all__ = ["load_llff", "llff_image_folder", "recenter_poses", "normalise_forward_facing", "LLFF_HOLDOUT",
           "MAX_DEPTH_RANGE"]

#: Every ``LLFF_HOLDOUT``-th image (index % 8 == 0) is a test view in the LLFF protocol.
LLFF_HOLDOUT = 8


#: The largest far / near ratio over a forward-facing scene's bounds (fern's: 4.7); beyond it the NDC near
#: plane sits so close that the rays' NDC depths lose their precision (near bounds of 1e-300 trained to NaN).
MAX_DEPTH_RANGE = 1e6


def _read_poses_bounds(file: Path) -> np.ndarray:
    if not file.is_file():
        raise InputError("file not found", file=file)
    with open(file, "rb") as fh:
        magic = fh.read(6)
    if magic != b"\x93NUMPY":
        raise InputError("not a .npy file (bad magic bytes)", file=file)
    try:
        arr = np.load(file, allow_pickle=False)
    except Exception as exc:  # np.load raises ValueError/OSError/EOFError/UnpicklingError
        raise InputError(f"cannot read as a .npy array ({type(exc).__name__}: {exc})", file=file) from None
    if arr.dtype.kind not in "biuf":
        raise InputError(f"expected a numeric array, got dtype {arr.dtype}", file=file, field="shape")
    if arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] < 1:
        raise InputError(f"expected shape (N, 17) with N >= 1, got {arr.shape}", file=file, field="shape")
    return arr.astype(np.float64)


def _opencv_poses(arr: np.ndarray, file: Path) -> np.ndarray:
    """``(N, 4, 4)`` OpenCV camera-to-world poses from the LLFF rows (checked finite and rigid)."""
    mats = arr[:, :15].reshape(-1, 3, 5)
    n = mats.shape[0]
    c2w = np.zeros((n, 4, 4))
    # LLFF columns [down, right, back] -> OpenCV [x = right, y = down, z = forward = -back].
    c2w[:, :3, 0] = mats[:, :, 1]
    c2w[:, :3, 1] = mats[:, :, 0]
    c2w[:, :3, 2] = -mats[:, :, 2]
    c2w[:, :3, 3] = mats[:, :, 3]
    c2w[:, 3, 3] = 1.0
    for i in range(n):
        _io.check_rigid(c2w[i], file, f"row {i} [R|t]")
    return c2w


def recenter_poses(c2w: np.ndarray) -> np.ndarray:
    """Left-multiply ``c2w (N, 4, 4)`` (OpenCV) by the inverse of their average pose.

    The average pose has the mean camera centre, z = normalised sum of the forward axes and
    x = normalise(sum of down axes x z), y = z x x.  Returns ``(N, 4, 4)`` float64 whose average pose is
    the identity.
    """
    center = c2w[:, :3, 3].mean(axis=0)
    z = c2w[:, :3, 2].sum(axis=0)
    z = z / np.linalg.norm(z)
    x = np.cross(c2w[:, :3, 1].sum(axis=0), z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    avg = np.eye(4)
    avg[:3, 0], avg[:3, 1], avg[:3, 2], avg[:3, 3] = x, y, z, center
    return invert_rigid(avg) @ c2w


def normalise_forward_facing(c2w: np.ndarray, bounds: np.ndarray, bd_factor: float | None = 0.75,
                             recenter: bool = True) -> tuple:
    """LLFF's normalisation (module docstring) of ``c2w (N, 4, 4)`` OpenCV poses and their ``bounds (N, 2)``
    near/far: scaled so that the smallest near becomes ``1 / bd_factor`` (``None``: not scaled), then
    recentred (:func:`recenter_poses`).  Returns new ``(c2w, bounds)``.

    Raises:
        InputError: ``bd_factor`` not a positive finite number (field ``bd_factor``).
    """
    c2w, bounds = np.array(c2w, np.float64), np.array(bounds, np.float64)
    if bd_factor is not None:
        bd = float(bd_factor)
        if not np.isfinite(bd) or bd <= 0:
            raise InputError(f"must be positive, got {bd_factor!r}", field="bd_factor")
        scale = 1.0 / (bounds.min() * bd)
        c2w[:, :3, 3] *= scale
        bounds *= scale
    if recenter:
        c2w = recenter_poses(c2w)
    return c2w, bounds


def _folder_factor(name: str) -> int | None:
    if name == "images":
        return 1
    if name.startswith("images_") and name[7:].isdigit() and int(name[7:]) >= 1:
        return int(name[7:])
    return None


def llff_image_folder(root: Path, downscale: float) -> Path:
    """The image folder to read for ``downscale`` (see the module docstring); ``InputError`` if none fits."""
    found = {}
    for p in sorted(Path(root).iterdir()) if Path(root).is_dir() else []:
        k = _folder_factor(p.name)
        if k is not None and p.is_dir():
            found[k] = p
    usable = [k for k in found if k <= downscale + 1e-9]
    if not usable:
        have = ", ".join(found[k].name for k in sorted(found)) or "none"
        hint = f" (e.g. downscale={min(found)})" if found else ""
        raise InputError(
            f"no image folder at factor <= {downscale:g}; found: {have}{hint}", file=root, field="images"
        )
    exact = [k for k in usable if abs(k - downscale) < 1e-9]
    return found[exact[0] if exact else max(usable)]


def _list_images(folder: Path) -> list:
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in _io.IMAGE_SUFFIXES)


def load_llff(root: Path, downscale: float = 1.0, bd_factor: float | None = 0.75, recenter: bool = True) -> Scene:
    """Load an LLFF scene folder; see the module docstring for the folder choice and the normalisation.

    Args:
        root: the scene folder holding ``poses_bounds.npy``.
        downscale: image shrink factor relative to the full resolution in ``poses_bounds.npy`` (``>= 1``).
        bd_factor: the smallest near bound becomes ``1 / bd_factor``; ``None`` keeps the original scale.
        recenter: make the average pose the identity.

    Returns:
        A :class:`Scene` with ``kind='forward_facing'``, ``near``/``far`` after scaling, splits as above.

    Raises:
        InputError: missing/unreadable ``poses_bounds.npy``, wrong shape, NaN/inf, non-rigid rotation,
            non-positive focal or size, focal lengths that differ between rows, bad bounds, no suitable image
            folder, image count mismatch, corrupt image, mixed image sizes.
    """
    root = Path(root)
    file = root / "poses_bounds.npy"
    arr = _read_poses_bounds(file)
    n = arr.shape[0]
    if not np.all(np.isfinite(arr)):
        row = int(np.argwhere(~np.isfinite(arr))[0, 0])
        raise InputError("contains NaN or inf", file=file, field=f"row {row}")
    hwf = arr[:, :15].reshape(-1, 3, 5)[:, :, 4]
    for i in range(n):
        for j, key in enumerate(("H", "W", "f")):
            if hwf[i, j] <= 0:
                raise InputError(f"must be positive, got {float(hwf[i, j])!r}", file=file, field=f"row {i} hwf.{key}")
    if np.any(hwf[:, :2] != hwf[0, :2]):
        i = int(np.argwhere(np.any(hwf[:, :2] != hwf[0, :2], axis=1))[0, 0])
        raise InputError("all rows must share one image size", file=file, field=f"row {i} hwf.H,W")
    if np.any(hwf[:, 2] != hwf[0, 2]):  # forward-facing scenes are fitted in one NDC frustum, built from one focal
        i = int(np.flatnonzero(hwf[:, 2] != hwf[0, 2])[0])
        raise InputError(f"all rows must share one focal length (NDC uses one), got {float(hwf[i, 2])!r} "
                         f"against row 0's {float(hwf[0, 2])!r}", file=file, field=f"row {i} hwf.f")
    bounds = arr[:, 15:17].copy()
    for i in range(n):
        if not 0 < bounds[i, 0] <= bounds[i, 1]:
            raise InputError(f"expected 0 < near <= far, got {bounds[i].tolist()}", file=file, field=f"row {i} bounds")
    depth_range = bounds[:, 1].max() / bounds[:, 0].min()
    if not depth_range <= MAX_DEPTH_RANGE:   # NDC and its near plane are built from the smallest near bound
        i = int(np.argmin(bounds[:, 0]))
        raise InputError(f"near bound {bounds[i, 0]:g} is {depth_range:.3g} times smaller than the largest far "
                         f"bound; forward-facing scenes are fitted with far / near up to {MAX_DEPTH_RANGE:g}",
                         file=file, field=f"row {i} bounds")
    c2w = _opencv_poses(arr, file)
    with np.errstate(over="ignore", invalid="ignore"):
        c2w, bounds = normalise_forward_facing(c2w, bounds, bd_factor, recenter)
    if not (np.isfinite(c2w).all() and np.isfinite(bounds).all()):
        i = int(np.flatnonzero(~np.isfinite(c2w).all(axis=(1, 2)) | ~np.isfinite(bounds).all(axis=1))[0])
        raise InputError("the camera positions overflow when the scene is normalised (LLFF's scaling and "
                         "recentring); are the poses in a sane unit?", file=file, field=f"row {i}")
    from .colmap import view_spread   # here: colmap imports this module

    size = max(1, int(round(hwf[0, 1]))), max(1, int(round(hwf[0, 0])))   # a size under 1 is refused below
    full_k = [Intrinsics(f, f, 0.5 * size[0], 0.5 * size[1], *size) for f in hwf[:, 2]]
    _, ray_deg, _ = view_spread(c2w, full_k)
    if not ray_deg < 90.0:   # NDC holds the half-space in front of the mean camera only (as COLMAP's check)
        axes = c2w[:, :3, 2] @ (c2w[:, :3, 2].sum(axis=0) / max(np.linalg.norm(c2w[:, :3, 2].sum(axis=0)), 1e-12))
        i = int(np.argmin(axes))
        from .colmap import colmap_model_folder

        hint = (" (the cameras surround the scene; this folder also holds a COLMAP model, which senerf fits as an "
                "object scene: move poses_bounds.npy aside)" if colmap_model_folder(root) is not None else "")
        raise InputError(f"some rays look {ray_deg:.0f} degrees away from the cameras' mean direction; a "
                         f"forward-facing (NDC) fit needs every ray within 90 (row {i}'s camera turns furthest)"
                         + hint, file=file, field=f"row {i}")
    offset = np.abs(c2w[:, :3, 3]).max(axis=1)   # from the mean camera, after normalising
    if not offset.max() <= MAX_DEPTH_RANGE * bounds.max():   # one NDC frustum cannot hold such a spread
        i = int(np.argmax(offset))
        raise InputError(f"the camera sits {offset[i]:.3g} from the cameras' mean, {offset[i] / bounds.max():.3g} "
                         f"times the scene's far bound (a forward-facing capture's cameras stand close together); "
                         f"are the poses in a sane unit?", file=file, field=f"row {i}")

    folder = llff_image_folder(root, downscale)
    paths = _list_images(folder)
    if len(paths) != n:
        raise InputError(f"{len(paths)} images but {n} rows in poses_bounds.npy", file=folder, field="images")
    full_h, full_w = int(round(hwf[0, 0])), int(round(hwf[0, 1]))
    # The exact folder is used at its own size (LLFF's images_N may round sides differently); any other
    # folder is resized to the size implied by the full resolution.  Intrinsics scale per axis.
    k = _folder_factor(folder.name)
    size = None if k == downscale else _io.target_size(full_h, full_w, downscale)
    rgb, alpha, native = _io.load_images(paths, [p.name for p in paths], [folder] * n, size=size)
    if abs(native[0] * k - full_h) > k or abs(native[1] * k - full_w) > k:  # more than one image pixel off
        raise InputError(f"images are {native[1]}x{native[0]}, but poses_bounds.npy's H, W = {full_h}, {full_w} "
                         f"at factor {k} give {full_w / k:.0f}x{full_h / k:.0f}", file=folder, field="images")
    h, w = rgb.shape[1:3]
    intr = tuple(Intrinsics(f, f, 0.5 * full_w, 0.5 * full_h, full_w, full_h).resized(w, h) for f in hwf[:, 2])
    idx = np.arange(n)
    return Scene(
        name=root.resolve().name,
        root=root,
        rgb=rgb,
        alpha=alpha,
        intrinsics=intr[0],
        intrinsics_all=intr,
        c2w=c2w.astype(np.float64),
        splits={"train": idx[idx % LLFF_HOLDOUT != 0], "val": idx[:0], "test": idx[idx % LLFF_HOLDOUT == 0]},
        kind="forward_facing",
        near=float(bounds.min()),
        far=float(bounds.max()),
        image_paths=tuple(paths),
        source_files=(file,),
    )
