"""What a benchmark runs: protocols, methods and presets, their ``senerf-fit`` flags, the grid of runs, and the
scenes of a data folder (no torch import).

A protocol name is ``FAMILY@RESOLUTION``; the resolution is part of the name because numbers at 100x100 and at
800x800 are different experiments.  ``S`` in ``synthetic-extreme3@S`` is the square side in pixels (a divisor of
800); ``WxH`` in ``llff3@WxH`` divides LLFF's 4032x3024 by an integer factor (``504x378`` = factor 8); ``S`` in
``dtu3@S`` divides 384, the side of the DTU copies senerf reads (MonoSDF's 384x384 crop of the 1600x1200 photos).
Without ``@...`` the paper's resolution is used (800; 400 for random8; 504x378 for LLFF; DTU, where the paper
publishes nothing: 384).  ``senerf-fit`` picks the views (:func:`senerf.data.fewshot_split`); the harness checks them
against the published lists where a protocol has them.
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
from senerf.data.fewshot import DTU_TRAIN_VIEWS, EXTREME_VIEWS, INFONERF4_VIEWS  # one copy of the published lists
from senerf.errors import InputError

__all__ = ["FAMILIES", "METHODS", "PRESETS", "Protocol", "parse_protocol", "scene_kind", "native_size", "RunSpec",
           "expand_specs", "SUITE", "SUITE_FULL", "discover_scenes"]

_SIDES = {"object": 800, "dtu": 384}   # square image sides: NeRF Synthetic 800x800, the DTU copies 384x384
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
    "dtu3": ("dtu", 3, "384", "dtu"),                             # DTU_TRAIN_VIEWS[:3]; 25 fixed test views
    "dtu6": ("dtu", 6, "384", "dtu"),
    "dtu9": ("dtu", 9, "384", "dtu"),
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
        kind: ``"object"`` (NeRF Synthetic), ``"forward_facing"`` (LLFF) or ``"dtu"`` (a 49-image DTU scan).
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
        train split (DTU: into its 49 images); ``None`` where it fixes none (random8 draws them with the run's seed,
        LLFF spreads them)."""
        if self.family == "synthetic-extreme3":
            return EXTREME_VIEWS.get(scene.lower())
        if self.kind == "dtu":
            return DTU_TRAIN_VIEWS[:self.n_views]
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
        if self.kind != "object":
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
    if kind in _SIDES:
        full = _SIDES[kind]
        if not _DIGITS.fullmatch(res) or int(res) <= 0 or full % int(res):
            examples = ", ".join(str(full // f) for f in (8, 4, 2, 1))
            raise InputError(f"{name!r}: resolution must be a divisor of {full} such as {examples}", field="protocol")
        side = int(res)
        return Protocol(f"{family}@{side}", family, kind, n_views, full // side, (side, side))
    w, _, h = res.partition("x")
    factor = _LLFF_SIZE[0] // int(w) if _DIGITS.fullmatch(w) and _DIGITS.fullmatch(h) and int(w) > 0 else 0
    if not factor or (int(w) * factor, int(h) * factor) != _LLFF_SIZE:
        raise InputError(f"{name!r}: LLFF resolution must be 4032x3024 divided by an integer factor, such as "
                         "504x378", field="protocol")
    return Protocol(f"{family}@{int(w)}x{int(h)}", family, kind, n_views, factor, (int(h), int(w)))


def scene_kind(scene_dir: str | Path) -> str | None:
    """``"object"`` for a Blender folder, ``"forward_facing"`` for LLFF, ``"dtu"`` for an instant-ngp / nerfstudio
    folder (``transforms.json``: the harness runs only the DTU protocols on those, and ``senerf-fit --protocol dtu``
    refuses a folder without DTU's 49 images), ``None`` when unrecognised."""
    d = Path(scene_dir)
    if (d / "transforms_train.json").is_file():
        return "object"
    if (d / "transforms.json").is_file():
        return "dtu"
    return "forward_facing" if (d / "poses_bounds.npy").is_file() else None


def native_size(scene_dir: str | Path) -> tuple[int, int]:
    """(H, W) of a scene's images as stored: Blender / DTU: the first (train) frame's image header; LLFF: the
    full-resolution size recorded in ``poses_bounds.npy`` (what ``senerf-fit --downscale`` divides)."""
    d = Path(scene_dir)
    path, field = d / "poses_bounds.npy", "hwf"
    try:
        if path.is_file():
            h, w = (int(round(v)) for v in np.load(path)[0, :15].reshape(3, 5)[:2, 4])
        else:
            path = d / "transforms_train.json"
            path, field = (path if path.is_file() else d / "transforms.json"), "frames[0].file_path"
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

    Protocols whose scene kind (object / forward-facing / DTU) does not match a scene are skipped for that scene
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
                raise InputError("not a Blender (transforms_train.json), LLFF (poses_bounds.npy) or DTU "
                                 "(transforms.json) scene folder", file=scene_dir)
            size = native_size(scene_dir)
        for proto, method, preset, seed in itertools.product(protos, methods, presets, seeds):
            if kind is not None and proto.kind != kind:
                continue
            factor = None if size is None else proto.downscale_for(size, scene_dir)
            specs.append(RunSpec(str(scene_dir), Path(scene_dir).name, proto.name, method, preset, int(seed),
                                 0 if method == "baseline" else iterations or _FIT_PRESETS[preset].iterations,
                                 device, steps, factor))
    return specs


#: ``senerf-bench suite``'s protocols: the paper's per-scene tables on every scene at hand, at sizes 2 CPU cores fit
#: in about an hour (Extreme at 100x100 as BENCHMARKS.md's lego; DTU at 192x192 as its scan24 fits, ea6330b).
SUITE: tuple[str, ...] = ("synthetic-extreme3@100", "llff3@504x378", "dtu3@192")
#: ``suite --full`` adds these (resumable over several invocations).
SUITE_FULL: tuple[str, ...] = ("synthetic-extreme3@200", "llff6@504x378", "llff9@504x378", "dtu6@192", "dtu9@192")
#: Where :func:`discover_scenes` looks under the data folder: sub-folder -> the scene kind it holds.
_DATA_LAYOUT = (("nerf_synthetic", "object"), ("nerf_llff_data", "forward_facing"), ("dtu", "dtu"))


def discover_scenes(data_dir: str | Path) -> tuple[list[Path], list[str]]:
    """The scene folders of a data folder laid out as ``../shared/data``: each folder of ``nerf_synthetic/`` that
    is a Blender scene, of ``nerf_llff_data/`` an LLFF scene, of ``dtu/`` a DTU scan (``transforms.json``), sorted
    by name within each; and one note per folder left out (not a scene of its kind, or a Blender scene without
    published Extreme views: only the paper's eight have them).

    Raises:
        InputError: naming ``data_dir`` when it holds none of them.
    """
    data = Path(data_dir)
    if not data.is_dir():
        raise InputError("data folder not found", file=data, field="--data")
    scenes: list[Path] = []
    notes: list[str] = []
    for sub, kind in _DATA_LAYOUT:
        for d in sorted(p for p in (data / sub).glob("*") if p.is_dir()):
            if scene_kind(d) != kind:
                notes.append(f"{d}: left out, not a {kind.replace('_', '-')} scene folder")
            elif kind == "object" and d.name.lower() not in EXTREME_VIEWS:
                notes.append(f"{d}: left out, no published Extreme views (only {', '.join(EXTREME_VIEWS)})")
            else:
                scenes.append(d)
    if not scenes:
        raise InputError("no scene folders in nerf_synthetic/, nerf_llff_data/ or dtu/", file=data, field="--data")
    return scenes, notes
