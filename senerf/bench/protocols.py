"""Evaluation protocols and methods, and how each maps to ``senerf-fit`` flags (no torch import).

A protocol name is ``FAMILY@RESOLUTION``; the resolution is part of the name because numbers at 100x100 and
at 800x800 are different experiments:

========================  ======================================  =====================================
name                      views (REFERENCE.md section 5)          ``senerf-fit`` flags
========================  ======================================  =====================================
``synthetic-extreme3@S``  per-scene Extreme lists (lego 0,1,51)   ``--protocol extreme --downscale 800/S``
``synthetic-infonerf4@S`` InfoNeRF's [26, 86, 2, 55]              ``--views 26,86,2,55 --downscale ..``
``synthetic-random8@S``   8 train views drawn with the run seed   ``--views a,b,... --downscale ..``
``llffN@WxH`` (N=3,6,9)   every 8th image held out, linspace      ``--protocol llff --n-views N --downscale 4032/W``
========================  ======================================  =====================================

``S`` is the square side in pixels (a divisor of 800); ``WxH`` a size that divides LLFF's 4032x3024 by an
integer factor (``504x378`` = factor 8).  Without ``@...`` the paper's resolution is used (800; 400 for
random8; 504x378 for LLFF).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from senerf.data.fewshot import EXTREME_VIEWS, INFONERF4_VIEWS  # one copy of REFERENCE.md section 5's lists
from senerf.errors import InputError

__all__ = [
    "EXTREME_VIEWS",
    "INFONERF4_VIEWS",
    "FAMILIES",
    "METHODS",
    "Protocol",
    "Method",
    "parse_protocol",
    "get_method",
    "random_views",
    "count_train_views",
    "scene_kind",
    "native_size",
]

_SYNTHETIC_SIDE = 800            # NeRF Synthetic images are 800x800
_DIGITS = re.compile(r"[0-9]+")   # ASCII digits only: str.isdigit() takes '²', which int() refuses
_LLFF_SIZE = (4032, 3024)        # LLFF full resolution (W, H)

#: family -> (scene kind, number of training views, default resolution suffix)
FAMILIES: dict[str, tuple[str, int, str]] = {
    "synthetic-extreme3": ("object", 3, "800"),
    "synthetic-infonerf4": ("object", 4, "800"),
    "synthetic-random8": ("object", 8, "400"),
    "llff3": ("forward_facing", 3, "504x378"),
    "llff6": ("forward_facing", 6, "504x378"),
    "llff9": ("forward_facing", 9, "504x378"),
}


@dataclass(frozen=True)
class Protocol:
    """One evaluation protocol at one resolution.

    Attributes:
        name: canonical ``FAMILY@RES`` name, e.g. ``"synthetic-extreme3@100"``.
        family: key of :data:`FAMILIES`.
        kind: ``"object"`` (NeRF Synthetic) or ``"forward_facing"`` (LLFF).
        n_views: number of training views.
        downscale: integer factor passed as ``--downscale``.
        size: expected image size ``(H, W)`` in pixels.
    """

    name: str
    family: str
    kind: str
    n_views: int
    downscale: int
    size: tuple[int, int]

    def views(self, scene: str, seed: int, n_train: int = 100) -> tuple[int, ...] | None:
        """The training-view indices this protocol fixes (``None`` when ``senerf-fit`` chooses them).

        Args:
            scene: scene name (``"lego"``); used by the Extreme lists.
            seed: run seed; picks the random8 views.
            n_train: size of the Blender train split (random8 only).
        """
        if self.family == "synthetic-extreme3":
            return EXTREME_VIEWS.get(scene)
        if self.family == "synthetic-infonerf4":
            return INFONERF4_VIEWS
        if self.family == "synthetic-random8":
            return random_views(n_train, self.n_views, seed)
        return None

    def downscale_for(self, native_size: tuple[int, int]) -> float:
        """``--downscale`` that turns images of ``native_size`` (H, W) into this protocol's size.

        Scene copies are not always at the dataset's original size (a NeRF Synthetic copy at 400x400 needs
        ``--downscale 4`` for 100x100), so the factor comes from the files.  Raises ``InputError`` when no
        single factor gives exactly :attr:`size`.
        """
        (h0, w0), (h, w) = native_size, self.size
        if h0 * w != w0 * h or h0 < h:
            raise InputError(f"images of {w0}x{h0} cannot be downscaled to {w}x{h} ({self.name})",
                             field="protocol")
        factor = h0 / h
        return float(int(factor)) if factor == int(factor) else factor

    def fit_flags(self, scene: str, seed: int, n_train: int = 100, downscale: float | None = None) -> list[str]:
        """``senerf-fit`` flags selecting this protocol's views and resolution (DESIGN.md contract).

        ``downscale``: the factor for this scene's files (:meth:`downscale_for`); default the nominal one
        for original-size data (800x800 NeRF Synthetic, 4032x3024 LLFF).
        """
        if self.family == "synthetic-extreme3":
            flags = ["--protocol", "extreme"]
        elif self.kind == "forward_facing":
            flags = ["--protocol", "llff", "--n-views", str(self.n_views)]
        else:
            views = self.views(scene, seed, n_train)
            flags = ["--views", ",".join(str(v) for v in views)]
        factor = self.downscale if downscale is None else downscale
        return flags + ["--downscale", f"{factor:g}"]


def random_views(n_train: int, n_views: int, seed: int) -> tuple[int, ...]:
    """``n_views`` distinct sorted indices in ``[0, n_train)`` from ``np.random.default_rng(seed)``."""
    if not 0 < n_views <= n_train:
        raise ValueError(f"need 0 < n_views <= n_train, got {n_views}, {n_train}")
    rng = np.random.default_rng(seed)
    return tuple(int(v) for v in np.sort(rng.choice(n_train, size=n_views, replace=False)))


def parse_protocol(name: str) -> Protocol:
    """Parse ``"FAMILY@RES"`` (or a bare family) into a :class:`Protocol`; raises ``InputError``."""
    family, _, res = name.strip().partition("@")
    if family not in FAMILIES:
        raise InputError(f"unknown protocol {family!r}; choose from {', '.join(FAMILIES)}", field="protocol")
    kind, n_views, default_res = FAMILIES[family]
    res = res or default_res
    if kind == "object":
        if not _DIGITS.fullmatch(res) or int(res) <= 0 or _SYNTHETIC_SIDE % int(res):
            raise InputError(f"{name!r}: resolution must be a divisor of 800 such as 100, 200, 400, 800",
                             field="protocol")
        side = int(res)
        return Protocol(f"{family}@{side}", family, kind, n_views, _SYNTHETIC_SIDE // side, (side, side))
    w_s, _, h_s = res.partition("x")
    if not (_DIGITS.fullmatch(w_s) and _DIGITS.fullmatch(h_s)) or int(w_s) <= 0 or int(h_s) <= 0:
        raise InputError(f"{name!r}: LLFF resolution must be WxH such as 504x378", field="protocol")
    w, h = int(w_s), int(h_s)
    factor = _LLFF_SIZE[0] // w
    if _LLFF_SIZE[0] % w or _LLFF_SIZE[1] % h or _LLFF_SIZE[1] // h != factor:
        raise InputError(f"{name!r}: {w}x{h} is not 4032x3024 divided by an integer factor", field="protocol")
    return Protocol(f"{family}@{w}x{h}", family, kind, n_views, factor, (h, w))


@dataclass(frozen=True)
class Method:
    """A method under test: a name and the ``senerf-fit`` flags it adds.

    ``selftrain`` methods run ``--iterations K`` (K from the run spec); the baseline runs ``--iterations 0``.
    """

    name: str
    flags: tuple[str, ...]
    selftrain: bool
    description: str

    def fit_flags(self, iterations: int) -> list[str]:
        """Flags for this method with ``iterations`` self-training rounds (ignored by the baseline)."""
        k = iterations if self.selftrain else 0
        return ["--iterations", str(k), *self.flags]


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("baseline", (), False, "teacher only (K-Planes on the sparse views)"),
    Method("senerf", (), True, "SE-NeRF, paper defaults"),
    Method("senerf-no-density-distill", ("--no-density-distill",), True, "no density distillation"),
    Method("senerf-no-prior", ("--no-prior",), True, "no prior-based distillation of unreliable rays"),
    Method("senerf-threshold-fixed", ("--threshold", "fixed"), True, "fixed tau = 0.6"),
    Method("senerf-threshold-unified", ("--threshold", "unified"), True, "unified soft weighting"),
    Method("senerf-daisy", ("--features", "daisy"), True, "DAISY features instead of VGG-19"),
    Method("senerf-no-empty", ("--empty-opacity", "0"), True,
           "no empty-space distillation (the paper's letter: background pseudo pixels unused)"),
    Method("senerf-range-step20", ("--pseudo-range-step", "20"), True,
           "pseudo-view range widened by 20 degrees per iteration (10, 30, 50) instead of 5 (10, 15, 20)"),
    Method("senerf-student-grid", ("--student-grid", "student"), True,
           "the student's pseudo rays marched through its own occupancy grid (default: the teacher's)"),
    Method("senerf-no-grid", ("--student-grid", "none"), True,
           "the student's pseudo rays evaluated at every sample (no occupancy grid)"),
    Method("senerf-batch-empty", ("--batch-empty", "512"), True,
           "512 empty-space rays per step drawn apart from 512 reliable surface rays (default: one pool)"),
    Method("senerf-oracle", ("--reliability", "oracle"), True,
           "analysis: held-out dataset views as pseudo views, masks from ground-truth colour (paper Fig. 1)"),
    Method("senerf-oracle-all", ("--reliability", "oracle", "--pseudo-range", "180", "--pseudo-views", "32"), True,
           "analysis: the oracle with 32 held-out views per input from anywhere (96 of lego's 197: the whole "
           "hemisphere), a bound on what reliability masks and pseudo-view range can buy"),
)}


def get_method(name: str) -> Method:
    """Look a method up by name; raises ``InputError`` for unknown names."""
    try:
        return METHODS[name]
    except KeyError:
        raise InputError(f"unknown method {name!r}; choose from {', '.join(METHODS)}", field="method") from None


def count_train_views(scene_dir: str | Path) -> int:
    """Number of frames in a Blender scene's ``transforms_train.json`` (100 for NeRF Synthetic)."""
    path = Path(scene_dir) / "transforms_train.json"
    try:
        return len(json.loads(path.read_text())["frames"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"cannot count training frames ({exc})", file=path, field="frames") from None


def native_size(scene_dir: str | Path) -> tuple[int, int]:
    """(H, W) of a scene's images as stored: Blender: the first train frame's PNG header; LLFF: the
    full-resolution size recorded in ``poses_bounds.npy`` (what ``senerf-fit --downscale`` divides)."""
    d = Path(scene_dir)
    if (d / "poses_bounds.npy").is_file():
        path = d / "poses_bounds.npy"
        try:
            hwf = np.load(path)[0, :15].reshape(3, 5)[:, 4]
        except (OSError, ValueError, IndexError) as exc:
            raise InputError(f"cannot read the image size ({exc})", file=path, field="hwf") from None
        if not (np.isfinite(hwf[:2]).all() and (hwf[:2] >= 1).all()):
            raise InputError(f"the image size must be finite and >= 1, got {hwf[0]!r} x {hwf[1]!r}", file=path,
                             field="hwf")
        return int(round(hwf[0])), int(round(hwf[1]))
    path = d / "transforms_train.json"
    try:
        rel = json.loads(path.read_text())["frames"][0]["file_path"]
    except (OSError, ValueError, KeyError, IndexError, TypeError) as exc:
        raise InputError(f"cannot find the first frame ({exc})", file=path, field="frames[0].file_path") from None
    if not isinstance(rel, str):
        raise InputError(f"must be a string, got {rel!r}", file=path, field="frames[0].file_path")
    image = (d / rel) if Path(rel).suffix else (d / (rel + ".png"))
    from PIL import Image   # pillow is a dependency; reads the header only

    try:
        with Image.open(image) as im:
            w, h = im.size
    except OSError as exc:
        raise InputError(f"cannot read the image size ({exc})", file=image) from None
    return h, w


def scene_kind(scene_dir: str | Path) -> str | None:
    """``"object"`` for a Blender folder, ``"forward_facing"`` for LLFF, ``None`` when unrecognised."""
    d = Path(scene_dir)
    if (d / "transforms_train.json").is_file():
        return "object"
    if (d / "poses_bounds.npy").is_file():
        return "forward_facing"
    return None
