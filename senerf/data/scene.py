"""The :class:`Scene` container: images, cameras, splits and bounds of one loaded scene (no torch).

Convention:
    ``c2w`` is camera-to-world in the OpenCV camera convention (x right, y down, z forward), float64.
    Loaders convert at their edge; nothing downstream converts again.  Pixel ``(i, j)`` has its centre at
    ``(i + 0.5, j + 0.5)`` (see :class:`senerf.geometry.Intrinsics`).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError, is_number
from ..geometry import Intrinsics

__all__ = ["Scene", "SPLIT_NAMES", "SCENE_KINDS", "as_background", "scene_file_digests", "changed_files", "view_names"]

#: The split names every :class:`Scene` carries (possibly empty).
SPLIT_NAMES = ("train", "val", "test")
#: What a scene can be fitted as (:attr:`Scene.kind`).
SCENE_KINDS = ("object", "forward_facing", "unbounded")


def as_background(background, field: str = "background") -> np.ndarray:
    """A background colour as a ``(3,)`` float32 array in ``[0, 1]`` (a scalar means grey).

    Raises:
        InputError: not 1 or 3 finite numbers in ``[0, 1]`` (``field`` names it).
    """
    bg = np.asarray(background, dtype=object).reshape(-1)
    bg = np.repeat(bg, 3) if bg.size == 1 else bg
    if bg.size != 3 or not all(is_number(c) and 0.0 <= c <= 1.0 for c in bg):
        raise InputError(f"expected 1 or 3 numbers in [0, 1], got {background!r}", field=field)
    return bg.astype(np.float32)


@dataclass(frozen=True, eq=False)
class Scene:
    """One loaded scene, as its loader built it (not checked again); all images share one size.

    Attributes:
        name: scene name (the folder name, e.g. ``"lego"``).
        root: the scene folder.
        rgb: ``(n, H, W, 3)`` float32 in ``[0, 1]``: straight colour, or composited onto ``background``.
        alpha: ``(n, H, W)`` float32 in ``[0, 1]``, or ``None`` when no image had an alpha channel.
        intrinsics: the shared-size intrinsics (those of image 0).
        intrinsics_all: per-image intrinsics, length ``n`` (same width/height for all).
        c2w: ``(n, 4, 4)`` float64 camera-to-world, OpenCV convention.
        splits: ``'train'``, ``'val'``, ``'test'`` -> int64 index arrays into the arrays above (empty if not given).
        kind: one of :data:`SCENE_KINDS`: ``'object'`` (photos with alpha, e.g. Blender: an object in a box),
            ``'forward_facing'`` (LLFF: NDC) or ``'unbounded'`` (RGB captures with background in every pixel).
        kind_reason: why the loader chose ``kind`` (one line, printed and recorded by a fit).
        near, far: scene depth bounds in world units where the format gives them (LLFF), else ``None``.
        bound: ``((xmin, ymin, zmin), (xmax, ymax, zmax))``, the world box the scene lies in where the format
            says (instant-ngp's ``aabb_scale``), else ``None``.
        image_paths: the image file of each view, length ``n``.
        source_files: the pose, camera and split files read, each once (:func:`scene_file_digests` hashes them).
        background: ``(r, g, b)`` that ``rgb`` was composited onto at load time, or ``None`` (straight).
    """

    name: str
    root: Path
    rgb: np.ndarray
    alpha: np.ndarray | None
    intrinsics: Intrinsics
    intrinsics_all: tuple
    c2w: np.ndarray
    splits: dict = field(default_factory=dict)
    kind: str = "object"
    near: float | None = None
    far: float | None = None
    kind_reason: str = ""
    bound: tuple | None = None
    image_paths: tuple = ()
    background: tuple | None = None
    source_files: tuple = ()

    def __post_init__(self) -> None:
        splits = {key: np.asarray(self.splits.get(key, ()), dtype=np.int64).reshape(-1) for key in SPLIT_NAMES}
        object.__setattr__(self, "splits", splits)
        object.__setattr__(self, "intrinsics_all", tuple(self.intrinsics_all))
        object.__setattr__(self, "image_paths", tuple(Path(p) for p in self.image_paths))
        object.__setattr__(self, "source_files", tuple(dict.fromkeys(Path(p) for p in self.source_files)))

    @property
    def n_images(self) -> int:
        """Number of views ``n``."""
        return int(self.rgb.shape[0])

    @property
    def size(self) -> tuple[int, int]:
        """``(H, W)`` of every image."""
        return (int(self.rgb.shape[1]), int(self.rgb.shape[2]))

    def composite(self, background, idx=None) -> np.ndarray:
        """``rgb`` composited onto a background colour: ``rgb * alpha + background * (1 - alpha)``.

        Args:
            background: one grey value or ``(r, g, b)``, each in ``[0, 1]``.
            idx: optional int view indices ``(m,)``; only those views are composited (saves memory).

        Returns:
            ``(n, H, W, 3)`` (or ``(m, H, W, 3)``) float32, a new array (a copy of ``rgb`` without alpha).

        Raises:
            InputError: a malformed background.
            ValueError: ``rgb`` was already composited at load time onto a *different* background.
            IndexError: ``idx`` out of range.
        """
        bg = as_background(background)
        if self.background is not None and not np.allclose(bg, np.asarray(self.background, np.float32), atol=1e-6):
            raise ValueError(f"Scene.composite: rgb was composited onto {tuple(self.background)} at load time; "
                             "reload with background=None to composite onto another colour")
        idx = slice(None) if idx is None else np.asarray(idx, dtype=np.int64).reshape(-1)
        rgb = self.rgb[idx]   # a copy when idx is an index array
        if self.background is not None or self.alpha is None:
            return rgb.copy() if isinstance(idx, slice) else rgb
        a = self.alpha[idx][..., None]
        return (rgb * a + bg * (1.0 - a)).astype(np.float32)


def _name_in(root, path) -> str:
    """``path`` named as :func:`view_names` names it, lexically (a symlinked photo keeps its name in the folder)."""
    root, full = Path(os.path.abspath(root)), Path(os.path.abspath(path))
    return full.relative_to(root).as_posix() if full.is_relative_to(root) else str(full)


def view_names(scene: Scene, views) -> list[str]:
    """The image file of each of ``views`` (int indices ``(m,)``), named relative to the scene folder
    (``/``-separated; a file outside it by its absolute path): what a view index stands for.

    Example:
        >>> view_names(load_scene("lego", downscale=4), [0, 1, 51])   # doctest: +SKIP
        ['train/r_0.png', 'train/r_1.png', 'train/r_51.png']
    """
    return [_name_in(scene.root, scene.image_paths[int(i)]) for i in np.asarray(views, dtype=np.int64).reshape(-1)]


def scene_file_digests(scene: Scene, views=None) -> dict:
    """What the scene's files held when read: ``{name: sha256 hex digest, first 16 characters}``.

    The files are ``scene.source_files`` (poses, cameras) and the image files of ``views``, named as
    :func:`view_names` names them.  Two loads of unchanged files give equal dicts on any machine (bytes, not
    decoded pixels, are hashed), so a run can tell whether its scene changed between a fit and a resume.

    Args:
        views: int view indices ``(m,)`` whose images count; ``None`` for all.

    Raises:
        InputError: a file can no longer be read (named).
    """
    idx = range(scene.n_images) if views is None else np.asarray(views, dtype=np.int64).reshape(-1)
    paths = list(scene.source_files) + [scene.image_paths[int(i)] for i in idx]
    out = {}
    for path in dict.fromkeys(paths):
        digest = hashlib.sha256()   # in 1 MiB chunks (Python 3.10 has no hashlib.file_digest)
        try:
            with open(os.path.abspath(path), "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    digest.update(chunk)
        except OSError as exc:
            raise InputError(f"cannot be read any more ({exc.strerror or exc})", file=path) from None
        out[_name_in(scene.root, path)] = digest.hexdigest()[:16]
    return dict(sorted(out.items()))


def changed_files(then: dict, now: dict) -> list[str]:
    """How two :func:`scene_file_digests` records differ, one line per file, sorted by name.

    Example:
        >>> changed_files({"a.png": "01", "b.json": "02"}, {"a.png": "ff", "c.json": "03"})
        ['a.png changed', 'b.json was read then, not now', 'c.json is read now, not then']
    """
    lines = []
    for name in sorted(set(then) | set(now)):
        if name not in now:
            lines.append(f"{name} was read then, not now")
        elif name not in then:
            lines.append(f"{name} is read now, not then")
        elif then[name] != now[name]:
            lines.append(f"{name} changed")
    return lines
