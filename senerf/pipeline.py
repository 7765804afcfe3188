"""``senerf.fit``: one fit of a scene folder, from its photos to a run folder (what ``senerf-fit`` runs; its
steps are listed in DESIGN.md, "One fit").

Example (a few minutes on 2 CPU cores)::

    import senerf
    result = senerf.fit("data/nerf_synthetic/lego", "runs/lego", protocol="extreme", downscale=4, preset="fast")
    print(result.psnr)   # test PSNR of the teacher, then of each SE-NeRF iteration
"""

from __future__ import annotations

import dataclasses
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from senerf.config import PRESETS, ModelConfig, SelfTrainConfig, TrainConfig, config_to_dict
from senerf.errors import InputError
from senerf.memory import physical_memory_bytes

__all__ = ["fit", "FitResult", "Split", "preflight", "default_protocol", "MAX_CAMERA_BOXES"]

#: How far a test camera may stand from the box the field is fitted in, in box half sizes: beyond it the object
#: is far below a pixel, and float32 rays (relative to the box) lose it altogether.
MAX_CAMERA_BOXES = 1e6
#: A COLMAP object capture with at least this share of its 3D points outside the fitted box gets a warning.
POINTS_OUTSIDE_WARN = 0.25
#: an unbounded scene's plane TV weight unless one is given (0.1, the object scenes', cost a dense DTU fit 0.6 dB)
UNBOUNDED_TV_WEIGHT = 0.0


@dataclass(frozen=True)
class Split:
    """The views of a fit: ``train_idx (m,)`` and ``test_idx (t,)`` int64 indices into the scene's arrays, and the
    protocol that chose them."""

    protocol: str
    train_idx: np.ndarray
    test_idx: np.ndarray


@dataclass(frozen=True)
class FitResult:
    """What :func:`fit` leaves: the run folder ``out`` and its ``metrics.json`` document."""

    out: Path
    metrics: dict

    @property
    def psnr(self) -> list[float]:
        """Test PSNR (dB) of every finished iteration, the teacher (iteration 0) first."""
        return [row["psnr"] for row in self.metrics["iterations"]]


def default_protocol(scene, fmt: str, views) -> str:
    """The protocol when none is given: ``views`` when views are given; for a Blender-style object scene with a
    test split, ``extreme`` when it is a NeRF Synthetic scene (:data:`senerf.data.EXTREME_VIEWS`) and ``spread``
    otherwise; ``llff`` (every 8th image tests) for every other scene."""
    from senerf.data import EXTREME_VIEWS

    if views is not None:
        return "views"
    if scene.kind == "object" and fmt != "colmap" and len(scene.splits["test"]) > 0:
        return "extreme" if scene.name.lower() in EXTREME_VIEWS else "spread"
    return "llff"


def _split(scene, fmt: str, protocol, views, n_views, test_views, seed: int) -> Split:
    from senerf.data import fewshot_split, spread_views

    protocol = protocol or default_protocol(scene, fmt, views)
    train_idx, test_idx = fewshot_split(scene, protocol, views=views, n_views=n_views, seed=seed)
    if len(test_idx) == 0:
        raise InputError(f"protocol {protocol!r} leaves no test views (scene {scene.name!r} has no test split); use "
                         "'llff' or 'views'", field="--protocol")
    if test_views is not None:
        test_idx = spread_views(test_idx, test_views)
    return Split(protocol, np.asarray(train_idx, np.int64), np.asarray(test_idx, np.int64))


def _check_cameras(scene, split: Split, model: ModelConfig) -> None:
    """Refuse test cameras too far from the fitted box to see it; warn about test views with a training pose."""
    from senerf.data import view_names

    if not model.ndc:
        box = np.asarray(model.aabb, dtype=np.float64)
        centre, half = box.mean(axis=0), float((box[1] - box[0]).max()) / 2
        with np.errstate(over="ignore", invalid="ignore"):   # the largest offset along an axis: no squares
            dist = np.abs(scene.c2w[split.test_idx, :3, 3] - centre).max(axis=-1)
        far = ~(dist <= MAX_CAMERA_BOXES * half)
        if far.any():
            i = int(split.test_idx[np.flatnonzero(far)[0]])
            raise InputError(f"test view {i} ({view_names(scene, [i])[0]}) stands {float(dist[far][0]):.3g} from the "
                             f"centre of the box the field is fitted in, more than {MAX_CAMERA_BOXES:g} times its half "
                             f"size {half:.3g}; are its pose and unit right?", file=scene.root, field="test views")
    train_c2w = scene.c2w[split.train_idx]
    for i in split.test_idx:
        same = np.flatnonzero(np.abs(train_c2w - scene.c2w[i]).max(axis=(1, 2)) <= 1e-9)
        if same.size:
            j = int(split.train_idx[same[0]])
            warnings.warn(f"test view {int(i)} ({view_names(scene, [i])[0]}) has the pose of training view {j} "
                          f"({view_names(scene, [j])[0]}); its scores measure a view the field is trained on")


def _check_memory(model: ModelConfig, batch_rays: int, device: str) -> None:
    """Refuse a field or a step that cannot fit: the K-Planes planes with their gradients and Adam's two moments
    (4 copies) against half of this machine's memory, or, on CUDA, with the backward pass's blend buffers (about 5
    more) against the GPU's; the MLPs with their optimiser state, or one step's activations and gradients
    (2 x rays x samples x (3 hidden + features) floats), against all of it."""
    if model.field != "kplanes":
        return
    from senerf.fields.interp import plane_layout

    _, rows = plane_layout(tuple(int(model.resolution * m) for m in model.multires))
    table = rows * model.n_features * 4   # one float32 copy of the planes
    have = physical_memory_bytes()
    if have is not None and 4 * table > have // 2:
        raise InputError(f"{model.resolution} needs {4 * table / 2**30:.1f} GiB for the feature planes and their "
                         f"optimiser state, more than half of this machine's {have / 2**30:.0f} GiB",
                         field="--resolution")
    if device.startswith("cuda"):
        import torch

        gpu = torch.cuda.get_device_properties(torch.device(device).index or 0).total_memory
        if 9 * table > gpu:
            raise InputError(f"{model.resolution} needs {9 * table / 2**30:.1f} GiB of GPU memory for the feature "
                             f"planes, their optimiser state and gradients, more than the GPU's {gpu / 2**30:.0f} GiB",
                             field="--resolution")
    if have is None:
        return
    weights = 4 * 4 * (model.hidden ** 2 + 64 * model.hidden)
    if weights > have:
        raise InputError(f"{model.hidden} needs {weights / 2**30:.1f} GiB for the MLPs and their optimiser state, "
                         f"more than this machine's {have / 2**30:.0f} GiB", field="--hidden")
    step = 2 * 4 * batch_rays * model.n_samples * (3 * model.hidden + model.n_features * len(model.multires))
    if step > have:
        raise InputError(f"{batch_rays} rays of {model.n_samples} samples need up to {step / 2**30:.1f} GiB a step, "
                         f"more than this machine's {have / 2**30:.0f} GiB", field="--batch-rays")


def _warn_points_outside(scene, model: ModelConfig) -> None:
    """Warn when much of a COLMAP object capture's sparse point cloud lies outside the box the field is fitted in:
    a background around the object is not modelled, and the fit paints it onto the box's faces."""
    from senerf.data.colmap import sparse_points

    try:
        xyz = sparse_points(scene.root)
    except InputError as exc:   # the fit does not use the points: a check that cannot run must not stop it
        warnings.warn(f"the 3D points could not be checked against the box ({exc})")
        return
    if xyz is None or len(xyz) == 0:
        return
    box = np.asarray(model.aabb, dtype=np.float64)
    share = float(np.mean(~np.all((xyz >= box[0]) & (xyz <= box[1]), axis=1)))
    if share >= POINTS_OUTSIDE_WARN:
        warnings.warn(f"{share:.0%} of the capture's {len(xyz)} 3D points lie outside the box the field is fitted in: "
                      "senerf fits a bounded object, so a background around it is not modelled and ends up painted "
                      "on the box; photos with the background masked out (RGBA) avoid this")


def preflight(scene, split: Split, model: ModelConfig, train: TrainConfig, selftrain: SelfTrainConfig) -> None:
    """Every check of a fit that can be made before anything is written or trained, made once.

    Raises:
        InputError: images too small to score, test cameras that cannot see the fitted box, a field or a step
            that cannot fit in memory, reliability features that cannot fit in memory, training views that leave the
            pseudo views no centre.

    Warns:
        UserWarning: a test view with a training view's pose, a COLMAP object capture with much of its point
            cloud outside the box, K-Planes on the CPU without the compiled kernel.
    """
    from senerf.train.metrics import SSIM_MIN_SIDE

    if min(scene.size) < SSIM_MIN_SIDE:
        raise InputError(f"the images are {scene.size[1]}x{scene.size[0]}; the evaluation (SSIM) needs at least "
                         f"{SSIM_MIN_SIDE}x{SSIM_MIN_SIDE}", field="--downscale")
    _check_cameras(scene, split, model)
    from senerf.fields.ckernel import warn_without_kernel

    warn_without_kernel(model, train.device)
    from senerf.data import detect_format

    if scene.kind == "object" and detect_format(scene.root) == "colmap":
        _warn_points_outside(scene, model)
    if selftrain.iterations > 0:
        _check_selftraining(scene, split, selftrain)
    _check_memory(model, train.batch_rays, train.device)   # after the features, the likelier cause


def _check_selftraining(scene, split: Split, selftrain: SelfTrainConfig) -> None:
    """Refuse self-training that cannot run (the last two refusals of :func:`preflight`)."""
    from senerf.selftrain import features_memory_problem, pseudo_view_centre_problem

    problem = features_memory_problem(scene.size)
    if problem is not None:
        raise InputError(problem, field="--downscale")
    problem = pseudo_view_centre_problem(scene, split.train_idx)
    if problem is not None:
        raise InputError(problem, file=scene.root, field=f"training views (protocol {split.protocol})")


def _refuse_out_among_inputs(out: Path, scene) -> None:
    """Refuse ``out`` when it is the scene folder or a folder of its photos (the next load would count the run's
    files among them); a new folder inside is fine."""
    folders = [scene.root, *sorted({Path(p).parent for p in scene.image_paths} |
                                   {p for p in Path(scene.root).glob("images*") if p.is_dir()})]
    for folder in folders:
        try:
            if os.path.samefile(out, folder):
                raise InputError("is the scene folder or a folder of its photos; choose another --out (a new folder "
                                 "inside it is fine)", file=out)
        except OSError:   # out not there yet
            continue


def fit(scene_dir, out=None, *, protocol: str | None = None, views=None, n_views: int | None = None,
        test_views: int | None = None, downscale: float | None = None, scene_kind: str | None = None,
        preset: str = "balanced", iterations: int | None = None, seed: int = 0, device: str = "cpu",
        train: dict[str, Any] | None = None, model: dict[str, Any] | None = None,
        selftrain: dict[str, Any] | None = None, overwrite: bool = False, progress: bool = True,
        command: list[str] | None = None, echo: Callable[[str], None] = print) -> FitResult:
    """Fit a scene folder with SE-NeRF (iteration 0: the baseline teacher) and write its run folder.

    Args:
        scene_dir: a NeRF Synthetic / instant-ngp / nerfstudio / LLFF / COLMAP scene folder (or its marker file).
        out: the run folder (default ``runs/<scene>-<protocol>``).  The same settings resume the run there; other
            settings are refused unless ``overwrite``.
        protocol: ``extreme``, ``spread``, ``llff``, ``all``, ``infonerf4``, ``random8`` or ``views`` (default:
            :func:`default_protocol`).
        views: training view indices (protocol ``views``); n_views: the number of views (``llff``, ``spread``,
            ``random8``); test_views: score on this many of the test views, spread evenly (default: all).
        downscale: image downscale factor (default 1; LLFF: 8, as LLFF's ``factor``).
        scene_kind: ``object``, ``forward_facing`` or ``unbounded`` instead of the kind chosen from the format, the
            photos and the cameras (:func:`senerf.data.load_scene`).
        preset: ``fast`` or ``balanced`` (:data:`senerf.config.PRESETS`): steps, rays per step and iterations.
        iterations: self-training iterations after the teacher (default: the preset's).
        seed: seeds the fields, the ray batches and the pseudo views.
        device: ``cpu``, ``cuda`` or ``cuda:N``.
        train, model, selftrain: overrides of :class:`~senerf.config.TrainConfig`,
            :class:`~senerf.config.ModelConfig` (else chosen from the scene) and
            :class:`~senerf.config.SelfTrainConfig` fields.
        overwrite: replace a different run in ``out``.
        progress: tqdm bars; command: recorded in ``metrics.json``; echo: where one-line status messages go.

    Returns:
        :class:`FitResult`.

    Raises:
        InputError: bad input (one line naming the file and the field), before anything is written.
    """
    from senerf.cliargs import check_device
    from senerf.data import detect_format, load_scene, scene_file_digests, scene_root, view_names
    from senerf.selftrain import run_selftraining
    from senerf.train import choose_model

    device = check_device(device)
    if preset not in PRESETS:
        raise InputError(f"must be one of {', '.join(PRESETS)}, got {preset!r}", field="--preset")
    root = scene_root(scene_dir)
    fmt = detect_format(root)
    downscale = downscale if downscale is not None else (8.0 if fmt == "llff" else 1.0)
    model = dict(model or {})
    train_cfg = PRESETS[preset].train_config(seed=seed, device=device, **(train or {}))
    st_cfg = SelfTrainConfig(**{"iterations": PRESETS[preset].iterations if iterations is None else iterations,
                                "seed": seed, **(selftrain or {})})
    echo(f"fit: reading {root} ({fmt}, downscale {downscale:g})")
    try:
        scene = load_scene(root, downscale=downscale, kind=scene_kind)
    except InputError as exc:   # the kind is a flag here
        if exc.field != "kind":
            raise
        raise InputError(exc.problem, file=exc.file, field="--scene-kind") from None
    if "aabb" in model and scene.kind == "forward_facing":
        raise InputError("a forward-facing scene is fitted in NDC, whose box is fixed; --aabb (a box in world units) "
                         "applies to object and unbounded scenes", file=root, field="--aabb")
    split = _split(scene, fmt, protocol, views, n_views, test_views, seed)
    more = " ..." if len(split.train_idx) > 12 else ""
    echo(f"fit: scene {scene.name} ({fmt}, {scene.size[1]}x{scene.size[0]}), protocol {split.protocol}: "
         f"{len(split.train_idx)} training views {split.train_idx[:12].tolist()}{more} "
         f"({', '.join(view_names(scene, split.train_idx[:12]))}{more}), {len(split.test_idx)} test views")
    echo(f"fit: fitted as {scene.kind.replace('_', '-')}: {scene.kind_reason}"
         + ("" if scene_kind else " (--scene-kind to choose)"))
    model_cfg = choose_model(scene, split.train_idx, model, echo=echo)
    if scene.kind == "unbounded" and "tv_weight" not in (train or {}):
        train_cfg = dataclasses.replace(train_cfg, tv_weight=UNBOUNDED_TV_WEIGHT)
        echo(f"fit: tv_weight {UNBOUNDED_TV_WEIGHT:g}: plane total variation off for an unbounded scene (it blurs the "
             "coarse contracted planes)")
    preflight(scene, split, model_cfg, train_cfg, st_cfg)

    out = Path(out) if out is not None else Path("runs") / f"{scene.name}-{split.protocol}"
    _refuse_out_among_inputs(out, scene)
    settings = dict(downscale=downscale, scene_kind=scene.kind, train_views=split.train_idx.tolist(),
                    test_views=split.test_idx.tolist(),
                    train={k: v for k, v in config_to_dict(train_cfg).items() if k != "device"},
                    model=config_to_dict(model_cfg),
                    selftrain={k: v for k, v in config_to_dict(st_cfg).items() if k != "iterations"})
    scene_files = scene_file_digests(scene, np.union1d(split.train_idx, split.test_idx))
    from senerf.runfolder import prepare_run_folder

    prepare_run_folder(out, dict(scene_dir=str(Path(root).resolve()), scene_files=scene_files, settings=settings,
                                 scene_kind_reason=scene.kind_reason), overwrite, echo)
    echo(f"fit: writing to {out}")
    config = dict(scene_dir=str(Path(root).resolve()), format=fmt, downscale=downscale, protocol=split.protocol,
                  views=views, n_views=n_views, test_views=test_views, preset=preset, scene_kind=scene.kind,
                  train=config_to_dict(train_cfg), model=config_to_dict(model_cfg), selftrain=config_to_dict(st_cfg))
    metrics = run_selftraining(scene, split.train_idx, split.test_idx, model_cfg, train_cfg, st_cfg, out,
                               command=command or [], config=config, progress=progress, echo=echo)
    from senerf.report import write_summary
    from senerf.train import phase_breakdown

    echo(f"fit: time {phase_breakdown(metrics)}")
    write_summary(metrics, scene, split.train_idx, split.test_idx, model_cfg, out, echo)
    sys.stdout.flush()
    return FitResult(out, metrics)
