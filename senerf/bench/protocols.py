"""What a benchmark runs: protocols, methods and presets, their ``senerf-fit`` flags, and the grid of runs (no torch
import).

A protocol name is ``FAMILY@RESOLUTION``; the resolution is part of the name because numbers at 100x100 and at
800x800 are different experiments.  ``S`` in ``synthetic-extreme3@S`` is the square side in pixels (a divisor of
800); ``WxH`` in ``llff3@WxH`` divides LLFF's 4032x3024 by an integer factor (``504x378`` = factor 8).  Without
``@...`` the paper's resolution is used (800; 400 for random8; 504x378 for LLFF).  ``senerf-fit`` picks the views
(:func:`senerf.data.fewshot_split`); the harness checks them against the published lists where a protocol has them.
"""

from __future__ import annotations

import itertools
import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from senerf.config import PRESETS as _FIT_PRESETS
from senerf.data.fewshot import EXTREME_VIEWS, INFONERF4_VIEWS  # one copy of REFERENCE.md section 5's lists
from senerf.errors import InputError

__all__ = ["FAMILIES", "METHODS", "PRESETS", "Protocol", "parse_protocol", "scene_kind", "native_size", "RunSpec",
           "expand_specs"]

_SYNTHETIC_SIDE = 800            # NeRF Synthetic images are 800x800
_LLFF_SIZE = (4032, 3024)        # LLFF full resolution (W, H)
_DIGITS = re.compile(r"[0-9]+")   # ASCII digits only: str.isdigit() takes '²', which int() refuses

#: family -> (scene kind, number of training views, default resolution suffix, ``senerf-fit --protocol``)
FAMILIES: dict[str, tuple[str, int, str, str]] = {
    "synthetic-extreme3": ("object", 3, "800", "extreme"),        # per-scene Extreme lists (lego 0, 1, 51)
    "synthetic-infonerf4": ("object", 4, "800", "infonerf4"),     # InfoNeRF's [26, 86, 2, 55]
    "synthetic-random8": ("object", 8, "400", "random8"),         # 8 train views drawn with the run seed
    "llff3": ("forward_facing", 3, "504x378", "llff"),            # every 8th image held out, the rest spread
    "llff6": ("forward_facing", 6, "504x378", "llff"),
    "llff9": ("forward_facing", 9, "504x378", "llff"),
}

#: Methods under test: name -> the ``senerf-fit`` flags it adds to ``--iterations K`` (the baseline runs K = 0).
METHODS: dict[str, tuple[str, ...]] = {
    "baseline": (),                                                 # the teacher alone: K-Planes on the sparse views
    "senerf": (),                                                   # SE-NeRF with the paper's defaults
    "senerf-no-density-distill": ("--no-density-distill",),
    "senerf-no-prior": ("--no-prior",),                             # unreliable rays not distilled
    "senerf-threshold-fixed": ("--threshold", "fixed"),             # tau = 0.6
    "senerf-threshold-unified": ("--threshold", "unified"),         # soft weighting
    "senerf-no-empty": ("--empty-opacity", "0"),                    # background pseudo pixels unused
    "senerf-range-step20": ("--pseudo-range-step", "20"),           # pseudo-view range 10, 30, 50 degrees
}


@dataclass(frozen=True)
class Protocol:
    """One evaluation protocol at one resolution.

    Attributes:
        name: canonical ``FAMILY@RES`` name, e.g. ``"synthetic-extreme3@100"``.
        family: key of :data:`FAMILIES`.
        kind: ``"object"`` (NeRF Synthetic) or ``"forward_facing"`` (LLFF).
        n_views: number of training views.
        downscale: the ``--downscale`` factor for original-size data.
        size: image size ``(H, W)`` in pixels.
    """

    name: str
    family: str
    kind: str
    n_views: int
    downscale: int
    size: tuple[int, int]

    def views(self, scene: str) -> tuple[int, ...] | None:
        """The training views this protocol fixes for ``scene`` (a name such as ``"lego"``), as indices into the
        train split; ``None`` where it fixes none (random8 draws them with the run's seed, LLFF spreads them)."""
        if self.family == "synthetic-extreme3":
            return EXTREME_VIEWS.get(scene.lower())
        return INFONERF4_VIEWS if self.family == "synthetic-infonerf4" else None

    def downscale_for(self, native_size: tuple[int, int], scene_dir: str | Path | None = None) -> float:
        """``--downscale`` that turns images of ``native_size`` (H, W) into this protocol's size.

        Scene copies are not always at the dataset's original size (a NeRF Synthetic copy at 400x400 needs
        ``--downscale 4`` for 100x100), so the factor comes from the files.  Raises ``InputError`` (naming
        ``scene_dir``) when no single factor gives exactly :attr:`size`.
        """
        (h0, w0), (h, w) = native_size, self.size
        if h0 * w != w0 * h or h0 < h:
            raise InputError(f"images of {w0}x{h0} cannot be downscaled to {w}x{h} ({self.name})", file=scene_dir,
                             field="protocol")
        return h0 / h

    def fit_flags(self, downscale: float | None = None) -> list[str]:
        """``senerf-fit`` flags selecting this protocol's views and resolution (DESIGN.md contract);
        ``downscale``: the factor for this scene's files (default: the one for original-size data)."""
        flags = ["--protocol", FAMILIES[self.family][3]]
        if self.kind == "forward_facing":
            flags += ["--n-views", str(self.n_views)]
        return flags + ["--downscale", f"{self.downscale if downscale is None else downscale:g}"]


def parse_protocol(name: str) -> Protocol:
    """Parse ``"FAMILY@RES"`` (or a bare family) into a :class:`Protocol`; raises ``InputError``.

    Example:
        >>> parse_protocol("llff3").size, parse_protocol("synthetic-extreme3@100").downscale
        ((378, 504), 8)
    """
    family, _, res = name.strip().partition("@")
    if family not in FAMILIES:
        raise InputError(f"unknown protocol {family!r}; choose from {', '.join(FAMILIES)}", field="protocol")
    kind, n_views, default_res, _ = FAMILIES[family]
    res = res or default_res
    if kind == "object":
        if not _DIGITS.fullmatch(res) or int(res) <= 0 or _SYNTHETIC_SIDE % int(res):
            raise InputError(f"{name!r}: resolution must be a divisor of 800 such as 100, 200, 400, 800",
                             field="protocol")
        side = int(res)
        return Protocol(f"{family}@{side}", family, kind, n_views, _SYNTHETIC_SIDE // side, (side, side))
    w, _, h = res.partition("x")
    factor = _LLFF_SIZE[0] // int(w) if _DIGITS.fullmatch(w) and _DIGITS.fullmatch(h) and int(w) > 0 else 0
    if not factor or (int(w) * factor, int(h) * factor) != _LLFF_SIZE:
        raise InputError(f"{name!r}: LLFF resolution must be 4032x3024 divided by an integer factor, such as "
                         "504x378", field="protocol")
    return Protocol(f"{family}@{int(w)}x{int(h)}", family, kind, n_views, factor, (int(h), int(w)))


def scene_kind(scene_dir: str | Path) -> str | None:
    """``"object"`` for a Blender folder, ``"forward_facing"`` for LLFF, ``None`` when unrecognised."""
    d = Path(scene_dir)
    if (d / "transforms_train.json").is_file():
        return "object"
    return "forward_facing" if (d / "poses_bounds.npy").is_file() else None


def native_size(scene_dir: str | Path) -> tuple[int, int]:
    """(H, W) of a scene's images as stored: Blender: the first train frame's PNG header; LLFF: the
    full-resolution size recorded in ``poses_bounds.npy`` (what ``senerf-fit --downscale`` divides)."""
    d = Path(scene_dir)
    path, field = d / "poses_bounds.npy", "hwf"
    try:
        if path.is_file():
            h, w = (int(round(v)) for v in np.load(path)[0, :15].reshape(3, 5)[:2, 4])
        else:
            path, field = d / "transforms_train.json", "frames[0].file_path"
            rel = str(json.loads(path.read_text())["frames"][0]["file_path"])
            path, field = (d / rel) if Path(rel).suffix else (d / (rel + ".png")), None
            with Image.open(path) as im:
                w, h = im.size
    except (OSError, ValueError, KeyError, IndexError, TypeError, OverflowError) as exc:
        raise InputError(f"cannot read the image size ({exc})", file=path, field=field) from None
    return h, w


#: Presets understood by ``senerf-fit --preset`` (:data:`senerf.config.PRESETS`).
PRESETS: tuple[str, ...] = tuple(_FIT_PRESETS)


@dataclass(frozen=True)
class RunSpec:
    """One ``senerf-fit`` invocation: scene x protocol x method x preset x seed; frozen and picklable, so that it
    travels to local threads and Ray workers unchanged.

    Attributes:
        scene_dir: scene folder handed to ``senerf-fit`` (must exist on the worker's machine).
        scene: scene name (the folder's basename), e.g. ``"lego"``.
        protocol: canonical protocol name, e.g. ``"synthetic-extreme3@100"``.
        method: a name in :data:`senerf.bench.protocols.METHODS`.
        preset: one of :data:`PRESETS`.
        seed: run seed (``--seed``; also draws the random8 views).
        iterations: self-training rounds K (0 for the baseline).
        device: ``"cpu"`` or ``"cuda"``.
        steps: optional ``--steps`` override (``None``: the preset decides).
        downscale: ``--downscale`` for this scene's files (``None``: the protocol's nominal factor).
    """

    scene_dir: str
    scene: str
    protocol: str
    method: str
    preset: str
    seed: int
    iterations: int
    device: str = "cpu"
    steps: int | None = None
    downscale: float | None = None

    def key(self) -> str:
        """The run's identifier in the results file (a rerun skips every finished key), e.g.
        ``"lego|synthetic-extreme3@100|senerf|fast|seed0|K3|cpu"`` (``|steps20`` when the preset's steps are
        overridden)."""
        parts = [self.scene, self.protocol, self.method, self.preset, f"seed{self.seed}", f"K{self.iterations}",
                 self.device] + ([] if self.steps is None else [f"steps{self.steps}"])
        return "|".join(parts)

    def dirname(self) -> str:
        """A filesystem-safe folder name derived from :meth:`key`."""
        return re.sub(r"[^A-Za-z0-9_.@-]+", "_", self.key().replace("|", "__"))

    def fit_args(self, out_dir: str | Path) -> list[str]:
        """``senerf-fit`` arguments (without the program) writing into ``out_dir`` (DESIGN.md contract)."""
        steps = [] if self.steps is None else ["--steps", str(self.steps)]
        return [self.scene_dir, *parse_protocol(self.protocol).fit_flags(self.downscale), "--iterations",
                str(self.iterations), *METHODS[self.method], "--preset", self.preset, "--seed", str(self.seed),
                "--device", self.device, *steps, "--out", str(out_dir), "--overwrite"]


def expand_specs(scene_dirs: list[str], protocols: list[str], methods: list[str], presets: list[str],
                 seeds: list[int], iterations: int | None = None, device: str = "cpu", steps: int | None = None,
                 check_scenes: bool = True) -> list[RunSpec]:
    """The full grid scenes x protocols x methods x presets x seeds, in that nesting order.

    Protocols whose scene kind (object / forward-facing) does not match a scene are skipped for that scene
    (so ``--scenes lego fern --protocols synthetic-extreme3@100 llff3`` does the sensible thing).

    Args:
        scene_dirs: scene folders; with ``check_scenes`` each must be a Blender or LLFF folder.
        protocols, methods, presets: names (an unknown one raises ``InputError``).
        iterations: K for self-training methods (every method but the baseline); default: each preset's own.
        device, steps: passed through to ``senerf-fit``.
        check_scenes: read the scene folders (kind, image size -> ``--downscale``); off for dry runs on
            machines without the data (then the nominal factors for original-size data).
    """
    for name, known, field in [*((m, METHODS, "method") for m in methods), *((p, PRESETS, "preset") for p in presets)]:
        if name not in known:
            raise InputError(f"unknown {field} {name!r}; choose from {', '.join(known)}", field=field)
    protos = [parse_protocol(p) for p in protocols]
    specs: list[RunSpec] = []
    for scene_dir in scene_dirs:
        kind = size = None
        if check_scenes:
            kind = scene_kind(scene_dir)
            if kind is None:
                raise InputError("not a Blender (transforms_train.json) or LLFF (poses_bounds.npy) scene folder",
                                 file=scene_dir)
            size = native_size(scene_dir)
        for proto, method, preset, seed in itertools.product(protos, methods, presets, seeds):
            if kind is not None and proto.kind != kind:
                continue
            factor = None if size is None else proto.downscale_for(size, scene_dir)
            specs.append(RunSpec(str(scene_dir), Path(scene_dir).name, proto.name, method, preset, int(seed),
                                 0 if method == "baseline" else iterations or _FIT_PRESETS[preset].iterations,
                                 device, steps, factor))
    return specs
