"""The :class:`Scene` container: images, cameras, splits and bounds of one loaded scene (no torch).

Convention:
    ``c2w`` is camera-to-world in the OpenCV camera convention (x right, y down, z forward), float64.
    Loaders convert at their edge; nothing downstream converts again.  ``rgb`` is straight (not
    premultiplied) colour unless ``background`` is set, in which case it was composited onto that colour at
    load time (``alpha`` is still kept).  Pixel ``(i, j)`` has its centre at ``(i + 0.5, j + 0.5)`` (see
    :class:`senerf.geometry.Intrinsics`).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import Intrinsics

__all__ = ["Scene", "SPLIT_NAMES", "as_background", "scene_file_digests", "run_file_digests", "changed_files",
           "view_names"]

#: The split names every :class:`Scene` carries (possibly empty).
SPLIT_NAMES = ("train", "val", "test")


def as_background(background, field: str = "background") -> np.ndarray:
    """A background colour as a ``(3,)`` float32 array in ``[0, 1]`` (a scalar means grey).

    Raises:
        InputError: not 1 or 3 finite numbers in ``[0, 1]`` (``field`` names it).
    """
    try:
        bg = np.asarray(background, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"expected 1 or 3 numbers in [0, 1], got {background!r}", field=field) from None
    if bg.size == 1:
        bg = np.repeat(bg, 3)
    if bg.size != 3 or not np.all(np.isfinite(bg)) or bg.min() < 0.0 or bg.max() > 1.0:
        raise InputError(f"expected 1 or 3 numbers in [0, 1], got {background!r}", field=field)
    return bg.astype(np.float32)


@dataclass(frozen=True, eq=False)
class Scene:
    """One loaded scene; all images share one size.

    Attributes:
        name: scene name (the folder name, e.g. ``"lego"``).
        root: the scene folder.
        rgb: ``(n, H, W, 3)`` float32 in ``[0, 1]``: straight colour, or composited onto ``background``.
        alpha: ``(n, H, W)`` float32 in ``[0, 1]``, or ``None`` when no image had an alpha channel.
        intrinsics: the shared-size intrinsics (those of image 0).
        intrinsics_all: per-image intrinsics, length ``n`` (same width/height for all).
        c2w: ``(n, 4, 4)`` float64 camera-to-world, OpenCV convention.
        splits: ``'train'``, ``'val'``, ``'test'`` -> int64 index arrays into the arrays above.
        kind: ``'object'`` (360 degree, e.g. Blender) or ``'forward_facing'`` (LLFF).
        near, far: scene depth bounds in world units where the format gives them (LLFF), else ``None``.
        image_paths: the image file of each view, length ``n``.
        source_files: the other files the loader read (poses, cameras, splits: ``transforms_*.json``,
            ``poses_bounds.npy``, COLMAP's model files), each once; :func:`scene_file_digests` hashes them.
        background: ``(r, g, b)`` that ``rgb`` was composited onto at load time, or ``None`` (straight).

    Raises:
        ValueError: inconsistent shapes or lengths (a programming error, not user input).
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
    image_paths: tuple = ()
    background: tuple | None = None
    source_files: tuple = ()

    def __post_init__(self) -> None:
        rgb, c2w = self.rgb, self.c2w
        if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.float32:
            raise ValueError(f"Scene.rgb: expected (n, H, W, 3) float32, got {rgb.shape} {rgb.dtype}")
        n, h, w = rgb.shape[:3]
        if self.alpha is not None and (self.alpha.shape != (n, h, w) or self.alpha.dtype != np.float32):
            raise ValueError(f"Scene.alpha: expected ({n}, {h}, {w}) float32, got {self.alpha.shape}")
        if c2w.shape != (n, 4, 4) or c2w.dtype != np.float64:
            raise ValueError(f"Scene.c2w: expected ({n}, 4, 4) float64, got {c2w.shape} {c2w.dtype}")
        if len(self.intrinsics_all) != n or any(k.size != (h, w) for k in self.intrinsics_all):
            raise ValueError(f"Scene.intrinsics_all: expected {n} Intrinsics of size {(h, w)}")
        if self.intrinsics.size != (h, w):
            raise ValueError(f"Scene.intrinsics: size {self.intrinsics.size} differs from images {(h, w)}")
        if len(self.image_paths) != n:
            raise ValueError(f"Scene.image_paths: expected {n} paths, got {len(self.image_paths)}")
        if self.kind not in ("object", "forward_facing"):
            raise ValueError(f"Scene.kind: expected 'object' or 'forward_facing', got {self.kind!r}")
        splits = {}
        for key in SPLIT_NAMES:
            idx = np.asarray(self.splits.get(key, ()), dtype=np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                raise ValueError(f"Scene.splits[{key!r}]: index out of range [0, {n})")
            splits[key] = idx
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
            ``(n, H, W, 3)`` (or ``(m, H, W, 3)``) float32, a new array.  Without alpha this is a copy of
            ``rgb``.

        Raises:
            InputError: a malformed background.
            ValueError: ``rgb`` was already composited at load time onto a *different* background (the
                straight colour is gone; reload with ``background=None``), or ``idx`` out of range.
        """
        bg = as_background(background)
        if idx is None:
            rgb, alpha = self.rgb, self.alpha
        else:
            idx = np.asarray(idx, dtype=np.int64).reshape(-1)
            if idx.size and (idx.min() < -self.n_images or idx.max() >= self.n_images):
                raise ValueError(f"Scene.composite: idx out of range [0, {self.n_images})")
            rgb, alpha = self.rgb[idx], None if self.alpha is None else self.alpha[idx]
        if self.background is not None:
            if not np.allclose(bg, np.asarray(self.background, np.float32), atol=1e-6):
                raise ValueError(
                    f"Scene.composite: rgb was composited onto {tuple(self.background)} at load time; "
                    "reload with background=None to composite onto another colour"
                )
            return rgb.copy()
        if alpha is None:
            return rgb.copy()
        a = alpha[..., None]
        return (rgb * a + bg * (1.0 - a)).astype(np.float32)


def _name_in(root, path) -> str:
    """``path`` relative to ``root`` (``/``-separated), or its absolute path when it lies outside; lexically,
    so a symlinked photo keeps the name it has in the scene folder."""
    root, full = Path(os.path.abspath(root)), Path(os.path.abspath(path))
    return full.relative_to(root).as_posix() if full.is_relative_to(root) else str(full)


def view_names(scene: Scene, views) -> list[str]:
    """The image file of each of ``views`` (int indices ``(m,)``), named relative to the scene folder: what a
    view index stands for (``metrics.json`` records both).

    Example:
        >>> view_names(load_scene("lego", downscale=4), [0, 1, 51])   # doctest: +SKIP
        ['train/r_0.png', 'train/r_1.png', 'train/r_51.png']
    """
    return [_name_in(scene.root, scene.image_paths[int(i)]) for i in np.asarray(views, dtype=np.int64).reshape(-1)]


def _sha256_prefix(path: str) -> str:
    """The first 16 hex digits of the SHA-256 of the file's bytes, read in 1 MiB chunks (Python 3.10 has no
    ``hashlib.file_digest``)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()[:16]


def scene_file_digests(scene: Scene, views=None) -> dict:
    """What the scene's files held when read: ``{name: sha256 hex digest, first 16 characters}``.

    The files are ``scene.source_files`` (poses, cameras) and the image files of ``views``; a name is the
    path relative to ``scene.root`` (``/``-separated), or the absolute path of a file outside it.  Two
    loads of unchanged files give equal dicts on any machine (bytes, not decoded pixels, are hashed), so a
    run can tell whether its scene changed between a fit and a resume.

    Args:
        scene: a loaded :class:`Scene`.
        views: int view indices ``(m,)`` whose images count; ``None`` for all.

    Raises:
        InputError: a file can no longer be read (named).

    Example:
        >>> digests = scene_file_digests(load_scene("lego", downscale=4), views=[0, 1])  # doctest: +SKIP
        >>> sorted(digests)[:2]                                                           # doctest: +SKIP
        ['train/r_0.png', 'train/r_1.png']
    """
    idx = range(scene.n_images) if views is None else np.asarray(views, dtype=np.int64).reshape(-1)
    paths = list(scene.source_files) + [scene.image_paths[int(i)] for i in idx]
    out = {}
    for path in dict.fromkeys(paths):
        try:
            out[_name_in(scene.root, path)] = _sha256_prefix(os.path.abspath(path))
        except OSError as exc:
            raise InputError(f"cannot be read any more ({exc.strerror or exc})", file=path) from None
    return dict(sorted(out.items()))


def run_file_digests(scene: Scene, train_idx, test_idx, oracle: bool = False, missing_ok: bool = False) -> dict | None:
    """:func:`scene_file_digests` of the files a run reads: the poses and cameras, the training and test views'
    photos, and with ``oracle`` (held-out views label the pseudo views) every view's.  The same record for
    senerf-fit's ``run.json`` and ``run_selftraining``'s ``scene_files.json``.

    Args:
        scene: a loaded :class:`Scene`; train_idx, test_idx: int view indices ``(m,)``, ``(t,)``.
        oracle: the run's reliability is the oracle (decided by the setting, not by whether a call self-trains,
            so ``--iterations 0`` then 1 is one run).
        missing_ok: return None when the files are not all on disk (a scene built in memory: nothing to compare)
            instead of raising.

    Raises:
        InputError: a file can no longer be read (named), unless ``missing_ok``.
    """
    views = np.arange(scene.n_images) if oracle else np.union1d(np.asarray(train_idx), np.asarray(test_idx))
    if missing_ok and not all(Path(f).is_file() for f in (*scene.source_files,
                                                          *(scene.image_paths[int(i)] for i in views))):
        return None
    return scene_file_digests(scene, views)


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
