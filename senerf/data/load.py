"""``load_scene``: detect a scene folder's format and load it (NeRF Synthetic, instant-ngp, LLFF, COLMAP).

Detection order: ``transforms_train.json`` -> Blender / NeRF Synthetic; ``transforms.json`` ->
instant-ngp / nerfstudio; ``poses_bounds.npy`` -> LLFF; a COLMAP model (``sparse/0/cameras.bin`` or
``.txt``, see :mod:`senerf.data.colmap`) -> COLMAP (a marker file given instead of its folder: :func:`scene_root`).

Downscaling: ``downscale`` divides both image sides (``>= 1``, not necessarily an integer; LLFF and COLMAP read
an ``images_N/`` folder when one fits, see :mod:`senerf.data.llff`).  Sides are rounded half up
(``floor(side / downscale + 0.5)``), images area-interpolated (``cv2.INTER_AREA``) on premultiplied colour, and
intrinsics scaled per axis by the actual ratio (``Intrinsics.resized``), exact with pixel centres at ``i + 0.5``.

Scene kind (:data:`~senerf.data.SCENE_KINDS`, what the fit models): LLFF is ``forward_facing``; Blender and
instant-ngp / nerfstudio scenes are ``object`` when their photos have alpha (an object on a transparent
background, fitted in a box) and ``unbounded`` otherwise (background in every pixel: all of space is fitted);
COLMAP decides from its cameras (:mod:`senerf.data.colmap`).  ``kind`` overrides the choice, except that
``forward_facing`` needs the depth bounds only LLFF and COLMAP captures give, and rays within 90 degrees of the
cameras' mean direction.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections import Counter
from pathlib import Path

from ..errors import InputError, is_number
from .blender import load_blender, load_ngp
from .colmap import colmap_model_folder, load_colmap
from .llff import load_llff
from .scene import SCENE_KINDS, Scene, as_background

__all__ = ["load_scene", "detect_format", "scene_root", "FORMAT_FILES"]

#: Marker file of each format, in detection order.
FORMAT_FILES = (("blender", "transforms_train.json"), ("ngp", "transforms.json"), ("llff", "poses_bounds.npy"))
#: Files that name their scene folder when given instead of it.
_MARKER_NAMES = frozenset({m for _, m in FORMAT_FILES} | {"transforms_val.json", "transforms_test.json"})


def scene_root(path) -> Path:
    """The scene folder of ``path``: the path itself, or the folder of a marker file given instead (unchecked)."""
    path = Path(path)
    return path.parent if path.is_file() and path.name in _MARKER_NAMES else path


def detect_format(root) -> str:
    """``'blender'``, ``'ngp'``, ``'llff'`` or ``'colmap'`` for a scene folder (or its marker file, see
    :func:`scene_root`); ``InputError`` when it matches none."""
    root = scene_root(root)
    if not root.is_dir():
        raise InputError(f"is a file; expected a scene folder (or one of its {', '.join(sorted(_MARKER_NAMES))})"
                         if root.is_file() else "scene folder not found", file=root)
    for fmt, marker in FORMAT_FILES:
        if (root / marker).is_file():
            return fmt
    if colmap_model_folder(root) is not None:
        return "colmap"
    looked = ", ".join(m for _, m in FORMAT_FILES) + ", sparse/0/cameras.bin (or .txt)"
    raise InputError(f"not a scene folder: none of {looked} found", file=root)


def load_scene(path, downscale: float = 1, background=None, kind: str | None = None) -> Scene:
    """Load a scene folder of any supported format.

    Args:
        path: the scene folder, or a marker file in it (:func:`scene_root`).
        downscale: divide image sides by this, ``>= 1`` (see the module docstring; LLFF: relative to the
            full resolution).
        background: ``None`` keeps straight colour; a grey value or ``(r, g, b)`` in ``[0, 1]`` returns
            ``rgb`` already composited onto it (``alpha`` is kept, ``Scene.background`` records the colour).
        kind: one of :data:`~senerf.data.SCENE_KINDS` instead of the kind the module docstring says.

    Returns:
        :class:`Scene` with OpenCV ``c2w`` (see :class:`Scene` for the fields).

    Raises:
        InputError: one line naming the file and field for every problem with the input.

    Example (the benchmark data's lego, 400x400 photos; the published 800x800 set gives this at ``downscale=8``):
        >>> scene = load_scene("data/nerf_synthetic/lego", downscale=4, background=(1, 1, 1))  # doctest: +SKIP
        >>> scene.rgb.shape, round(scene.intrinsics.fx, 3)                                     # doctest: +SKIP
        ((400, 100, 100, 3), 138.889)
    """
    if not is_number(downscale) or downscale < 1:
        raise InputError(f"expected a number >= 1 (no upsampling), got {downscale!r}", field="downscale")
    bg = None if background is None else as_background(background)
    root = scene_root(path)
    fmt = detect_format(root)
    if kind is not None and kind not in SCENE_KINDS:
        raise InputError(f"expected one of {', '.join(SCENE_KINDS)}, got {kind!r}", field="kind")
    if kind == "forward_facing" and fmt in ("blender", "ngp"):
        raise InputError(f"a forward-facing (NDC) fit needs the depth bounds only LLFF and COLMAP captures give; "
                         f"this is {'an instant-ngp' if fmt == 'ngp' else 'a Blender'} scene: fit it as unbounded or "
                         "object", file=root, field="kind")
    loaders = {"blender": load_blender, "ngp": load_ngp, "llff": load_llff, "colmap": load_colmap}
    scene = loaders[fmt](root, downscale=float(downscale), **({"kind": kind} if fmt == "colmap" else {}))
    if fmt != "colmap":
        scene = _with_kind(scene, fmt, kind)
    _warn_odd_views(scene)
    if bg is None:
        return scene
    return dataclasses.replace(scene, rgb=scene.composite(bg), background=tuple(float(c) for c in bg))


def _with_kind(scene: Scene, fmt: str, kind: str | None) -> Scene:
    """``scene`` with the kind the module docstring gives a ``fmt`` scene, or ``kind`` when given, and why."""
    if kind is not None:
        return dataclasses.replace(scene, kind=kind, kind_reason="chosen with --scene-kind")
    if fmt == "llff":
        return dataclasses.replace(scene, kind_reason="an LLFF capture (poses_bounds.npy): forward-facing, fitted "
                                                      "in NDC")
    if scene.alpha is not None:
        return dataclasses.replace(scene, kind="object", kind_reason="photos with alpha: an object on a transparent "
                                                                     "background, fitted in a box")
    return dataclasses.replace(scene, kind="unbounded", kind_reason="RGB photos without alpha: background in every "
                                                                    "pixel, fitted as an unbounded scene")


def _warn_odd_views(scene: Scene) -> None:
    """Warn, once each, about what loads but is most likely a mistake: a principal point outside its image
    and one photo listed twice in a split."""
    for k, path in zip(scene.intrinsics_all, scene.image_paths):
        if not (0.0 <= k.cx <= k.width and 0.0 <= k.cy <= k.height):
            warnings.warn(f"{path}: cx, cy: the principal point ({k.cx:g}, {k.cy:g}) lies outside the "
                          f"{k.width}x{k.height} image; check that cx, cy are in pixels at this size", stacklevel=3)
            break
    for split, idx in scene.splits.items():
        twice = [(p, n) for p, n in Counter(scene.image_paths[i] for i in idx).items() if n > 1]
        if twice:
            warnings.warn(f"{twice[0][0]}: listed {twice[0][1]} times in the {split} split"
                          + (f" ({len(twice) - 1} more photo(s) likewise)" if len(twice) > 1 else "")
                          + "; each copy counts as a view", stacklevel=3)
