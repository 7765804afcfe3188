"""Run specifications: one ``senerf-fit`` invocation each, and the grid expansion (no torch import).

A :class:`RunSpec` is frozen and picklable (it travels to local threads and to Ray workers unchanged).  Its
:meth:`RunSpec.key` identifies the run in the results file: a rerun of the benchmark skips every spec whose
key already has a finished ("ok") result.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass
from pathlib import Path

from senerf.errors import InputError

from .protocols import EXTREME_VIEWS, count_train_views, get_method, native_size, parse_protocol, scene_kind

__all__ = ["PRESETS", "RunSpec", "expand_specs"]

#: Presets understood by ``senerf-fit --preset`` (their values live in the trainer).
PRESETS: tuple[str, ...] = ("fast", "balanced")


@dataclass(frozen=True)
class RunSpec:
    """One fit: scene x protocol x method x preset x seed.

    Attributes:
        scene_dir: scene folder handed to ``senerf-fit`` (must exist on the worker's machine).
        scene: scene name (the folder's basename), e.g. ``"lego"``.
        protocol: canonical protocol name, e.g. ``"synthetic-extreme3@100"``.
        method: a name in :data:`senerf.bench.protocols.METHODS`.
        preset: one of :data:`PRESETS`.
        seed: run seed (``--seed``; also draws the random8 views).
        iterations: self-training rounds K for self-training methods (0 for the baseline).
        device: ``"cpu"`` or ``"cuda"``.
        steps: optional ``--steps`` override (``None``: the preset decides).
        n_train: size of the scene's train split (random8 draws from it).
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
    n_train: int = 100
    downscale: float | None = None

    def key(self) -> str:
        """Stable identifier of the run, e.g. ``"lego|synthetic-extreme3@100|senerf|fast|seed0|K3|cpu"``."""
        parts = [self.scene, self.protocol, self.method, self.preset, f"seed{self.seed}",
                 f"K{self.iterations}", self.device]
        if self.steps is not None:
            parts.append(f"steps{self.steps}")
        return "|".join(parts)

    def dirname(self) -> str:
        """A filesystem-safe folder name derived from :meth:`key`."""
        return re.sub(r"[^A-Za-z0-9_.@-]+", "_", self.key().replace("|", "__"))

    def views(self) -> tuple[int, ...] | None:
        """Training views the protocol fixes for this run (``None``: chosen by ``senerf-fit``)."""
        return parse_protocol(self.protocol).views(self.scene, self.seed, self.n_train)

    def fit_args(self, out_dir: str | Path) -> list[str]:
        """``senerf-fit`` arguments (without the program) writing into ``out_dir`` (DESIGN.md contract)."""
        proto = parse_protocol(self.protocol)
        args = [self.scene_dir, *proto.fit_flags(self.scene, self.seed, self.n_train, self.downscale),
                *get_method(self.method).fit_flags(self.iterations),
                "--preset", self.preset, "--seed", str(self.seed), "--device", self.device]
        if self.steps is not None:
            args += ["--steps", str(self.steps)]
        return args + ["--out", str(out_dir), "--overwrite"]


def expand_specs(scene_dirs: list[str], protocols: list[str], methods: list[str], presets: list[str],
                 seeds: list[int], iterations: int = 3, device: str = "cpu", steps: int | None = None,
                 check_scenes: bool = True) -> list[RunSpec]:
    """The full grid scenes x protocols x methods x presets x seeds, in that nesting order.

    Protocols whose scene kind (object / forward-facing) does not match a scene are skipped for that scene
    (so ``--scenes lego fern --protocols synthetic-extreme3@100 llff3`` does the sensible thing).

    Args:
        scene_dirs: scene folders; with ``check_scenes`` each must be a Blender or LLFF folder.
        protocols, methods, presets: names (validated here; bad names raise ``InputError``).
        seeds: run seeds.
        iterations: K for self-training methods (>= 1).
        device, steps: passed through to ``senerf-fit``.
        check_scenes: read the scene folders (kind, train-split size, image size -> ``--downscale``); off
            for dry runs on machines without the data (then the nominal factors for original-size data).
    """
    if iterations < 1:
        raise InputError(f"iterations must be >= 1 for self-training methods, got {iterations}",
                         field="iterations")
    if steps is not None and steps < 1:
        raise InputError(f"steps must be positive, got {steps}", field="steps")
    for p in presets:
        if p not in PRESETS:
            raise InputError(f"unknown preset {p!r}; choose from {', '.join(PRESETS)}", field="preset")
    protos = [parse_protocol(p) for p in protocols]
    meths = [get_method(m) for m in methods]
    specs: list[RunSpec] = []
    for scene_dir in scene_dirs:
        kind, n_train, size = _scene_info(scene_dir, check_scenes)
        for proto, meth, preset, seed in itertools.product(protos, meths, presets, seeds):
            if kind is not None and proto.kind != kind:
                continue
            try:
                factor = None if size is None else proto.downscale_for(size)
            except InputError as exc:   # which scene's images
                raise InputError(exc.problem, file=scene_dir, field=exc.field) from None
            if proto.family == "synthetic-extreme3" and Path(scene_dir).name.lower() not in EXTREME_VIEWS:
                raise InputError(f"{proto.name} uses the published Extreme views, known for "
                                 f"{', '.join(sorted(EXTREME_VIEWS))}; {Path(scene_dir).name!r} is none of them",
                                 file=scene_dir, field="protocol")
            if proto.family == "synthetic-random8" and n_train < proto.n_views:   # drawn from the train split
                raise InputError(f"{proto.name} draws {proto.n_views} training views; the train split has "
                                 f"{n_train}", file=scene_dir, field="protocol")
            specs.append(RunSpec(str(scene_dir), Path(scene_dir).name, proto.name, meth.name, preset,
                                 int(seed), iterations if meth.selftrain else 0, device, steps, n_train, factor))
    return specs


def _scene_info(scene_dir: str, check: bool) -> tuple[str | None, int, tuple[int, int] | None]:
    """(kind, train-split size, native image size (H, W)) of a scene folder; (None, 100, None) unchecked."""
    if not check:
        return None, 100, None
    kind = scene_kind(scene_dir)
    if kind is None:
        raise InputError("not a Blender (transforms_train.json) or LLFF (poses_bounds.npy) scene folder",
                         file=scene_dir)
    return kind, count_train_views(scene_dir) if kind == "object" else 0, native_size(scene_dir)
