"""``senerf-fit``: train the baseline (and self-train) on a scene folder; write renders and metrics.json.

Exit status: 0 done, 2 bad input (one line ``senerf-fit: error: <message>`` on stderr, no traceback, and
nothing written), 1 internal error.  The output folder (``--out``, default ``runs/<scene>-<protocol>``)
records its run's settings in ``run.json``; the same command resumes its own run, a different one is
refused unless ``--overwrite``.  See DESIGN.md ("Command line and outputs") for the ``metrics.json``
contract.

Measured on the 2-core CPU machine (lego, ``--downscale 4`` = 100x100, ``--iterations 0``, 200 test views;
BENCHMARKS.md has the commands and commits):

* ``--protocol all`` (balanced preset: 1000 steps x 4096 rays, 48 samples): 26.70 dB, SSIM 0.921, 65 s wall.
* Extreme (views 0, 1, 51), seeds 0/1/2: ``--preset fast`` (600 steps x 1024 rays) 16.60 ± 0.63 dB in
  31 s of fitting; balanced 16.58 ± 1.18 dB in 63 s;
  ``--steps 3000 --batch-rays 2048`` 17.46 ± 0.20 dB in 122 s.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import sys
import time
from pathlib import Path

from senerf import __version__
from senerf.cliargs import (SEED_MAX, THREADS_HELP, OneLineParser, argument_type, check_device, float_flag, int_flag,
                            run_command, set_threads, short_openmp_waits, threads_flag, warn_planes_path)
from senerf.errors import InputError
from senerf.memory import physical_memory_bytes

__all__ = ["main", "console", "build_parser", "parse_views"]

PROG = "senerf-fit"
_CLI_PROTOCOLS = ("extreme", "spread", "llff", "all", "infonerf4", "random8")
_RUN_FILE = "run.json"


def parse_views(text: str) -> list[int]:
    """``"0,1,51"`` -> ``[0, 1, 51]``; :class:`InputError` naming ``--views`` otherwise."""
    items = [t.strip() for t in str(text).split(",")]
    if not items or any(not t for t in items):
        raise InputError(f"expected comma-separated integers like 0,1,51, got {text!r}", field="--views")
    try:
        return [int(t) for t in items]
    except ValueError:
        raise InputError(f"expected comma-separated integers like 0,1,51, got {text!r}", field="--views") from None


def build_parser() -> argparse.ArgumentParser:
    """The ``senerf-fit`` argument parser (errors raise :class:`InputError`)."""
    p = OneLineParser(prog=PROG, description="Few-shot NeRF with SE-NeRF self-training (K-Planes teacher/student).",
                      epilog="Writes into --out: summary.png (quality per iteration and per test view, renders "
                             "beside the ground truth), metrics.json, iter_K/test/ (test-view renders, K = 0 the "
                             "teacher), iter_K/pseudo/ (pseudo views, similarity maps, reliability masks), "
                             "run.json and checkpoints/. Run the same command again to resume. Exit status: 0 "
                             "done, 2 bad input (one line naming the file and field), 130 interrupted (Ctrl-C or "
                             "SIGTERM; rerun to resume), 1 internal error.")
    p.add_argument("scene", nargs="?", help="scene folder (NeRF Synthetic / instant-ngp / nerfstudio / LLFF / COLMAP)")
    g = p.add_argument_group("views")
    g.add_argument("--views", type=argument_type(parse_views),
                   help="training view indices, e.g. 0,1,51 (into the train split of a scene that has one, NeRF "
                        "Synthetic style; else into all images)")
    g.add_argument("--n-views", type=int_flag("--n-views"), help="number of views (llff, spread, random8)")
    g.add_argument("--protocol", choices=_CLI_PROTOCOLS,
                   help="few-shot protocol (default: 'views' with --views; extreme for the NeRF Synthetic scenes; "
                        "spread for other scenes with a test split: 3 views spread over the train split; else "
                        "llff: every 8th image tests, 3 views spread over the rest train)")
    g.add_argument("--test-views", type=int_flag("--test-views"), metavar="N",
                   help="score on N of the protocol's test views, spread evenly over them (default: all of them, "
                        "as published tables are; fewer cost less where a test render takes seconds)")
    g.add_argument("--scene-kind", choices=("object", "forward-facing"),
                   help="COLMAP scenes: fit as an object or as a forward-facing (LLFF, NDC) capture instead of "
                        "the kind the cameras' spread suggests")
    g.add_argument("--downscale", type=float_flag("--downscale", 1.0),
                   help="image downscale factor (default 1; LLFF: 8, relative to full resolution)")
    t = p.add_argument_group("training")
    t.add_argument("--preset", choices=("fast", "balanced"), default="balanced",
                   help="fast: 600 steps x 1024 rays, 1 self-training iteration (66 s on lego Extreme at "
                        "100x100, 2 CPU cores); balanced (default): 1000 x 4096, 3 iterations (5 min with "
                        "--test-views 25, +0.8 dB over fast on 9 seeds; BENCHMARKS.md)")
    t.add_argument("--steps", type=int_flag("--steps"), help="training steps per iteration (overrides preset)")
    t.add_argument("--batch-rays", type=int_flag("--batch-rays"), help="rays per step (overrides preset)")
    t.add_argument("--iterations", type=int_flag("--iterations", allow_zero=True), default=None,
                   help="self-training iterations after the baseline (0 = baseline only; default: the "
                        "preset's: 3 for balanced, 1 for fast)")
    t.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    t.add_argument("--threads", type=threads_flag(), default=None, metavar="N", help=THREADS_HELP)
    t.add_argument("--seed", type=int_flag("--seed", allow_zero=True, maximum=SEED_MAX), default=0)
    m = p.add_argument_group("model overrides (default: chosen from the scene and printed)")
    m.add_argument("--field", choices=("kplanes", "nerf"),
                   help="kplanes (default) or nerf (an MLP with frequency annealing; BENCHMARKS.md has both on lego)")
    m.add_argument("--resolution", type=int_flag("--resolution", minimum=2), help="base plane resolution (K-Planes)")
    m.add_argument("--samples", type=int_flag("--samples"), help="samples per ray")
    m.add_argument("--hidden", type=int_flag("--hidden"), help="width of the K-Planes MLPs (default 32)")
    m.add_argument("--aabb", type=float_flag("--aabb", positive=True),
                   help="half size of a cube AABB around the world origin (object scenes; forward-facing ones "
                        "are fitted in NDC's fixed box)")
    m.add_argument("--background", choices=("random", "white", "black"), help="training background")
    m.add_argument("--no-view-dependence", action="store_true", help="colour ignores the view direction")
    m.add_argument("--no-occupancy", action="store_true", help="no occupancy grid")
    s = p.add_argument_group("self-training")
    s.add_argument("--features", choices=("vgg19", "daisy"), default="vgg19")
    s.add_argument("--threshold", choices=("adaptive", "fixed", "unified"), default="adaptive")
    s.add_argument("--no-density-distill", action="store_true")
    s.add_argument("--no-prior", action="store_true")
    s.add_argument("--empty-opacity", type=float_flag("--empty-opacity", 0.0, maximum=OPACITY_THRESHOLD_DEFAULT),
                   default=None,
                   help="pseudo pixels the teacher renders with opacity below this are distilled as empty "
                        f"space (0: off, the paper's letter; default {EMPTY_OPACITY_DEFAULT:g}; at most the "
                        f"foreground threshold {OPACITY_THRESHOLD_DEFAULT:g})")
    s.add_argument("--pseudo-range", type=float_flag("--pseudo-range", 0.0), default=None, metavar="DEG",
                   help="azimuth/elevation range of the first iteration's pseudo views around each input "
                        f"(default {PSEUDO_RANGE_DEFAULT:g}, the paper's)")
    s.add_argument("--pseudo-range-step", type=float_flag("--pseudo-range-step", 0.0), default=None, metavar="DEG",
                   help=f"widening of that range per later iteration (default {PSEUDO_RANGE_STEP_DEFAULT:g})")
    s.add_argument("--pseudo-views", type=int_flag("--pseudo-views"), default=None, metavar="N",
                   help=f"pseudo views per input view and iteration (default {PSEUDO_VIEWS_DEFAULT})")
    s.add_argument("--batch-empty", type=int_flag("--batch-empty", allow_zero=True), default=None, metavar="N",
                   help="empty-space pseudo rays per step drawn apart from the reliable surface rays (0: one "
                        f"shared pool; default {BATCH_EMPTY_DEFAULT})")
    s.add_argument("--student-grid", choices=("teacher", "student", "none"), default=None,
                   help="occupancy grid the student's pseudo rays are marched through (default "
                        f"{STUDENT_GRID_DEFAULT})")
    s.add_argument("--reliability", choices=("features", "oracle"), default="features",
                   help="oracle: an analysis, not the method: held-out dataset views as pseudo views, reliable "
                        "where the teacher's colour matches the real image (the paper's Figure 1)")
    o = p.add_argument_group("output")
    o.add_argument("--out", type=Path, help="output folder (default runs/<scene>-<protocol>)")
    o.add_argument("--overwrite", action="store_true", help="replace a different run in --out")
    o.add_argument("--demo", action="store_true", help="build a small procedural scene and fit it")
    o.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


#: SelfTrainConfig.empty_opacity's default, repeated here so that --help needs no torch import (a test
#: checks the two agree)
EMPTY_OPACITY_DEFAULT = 0.2
#: SelfTrainConfig.opacity_threshold's default (foreground pixels), likewise repeated and tested
OPACITY_THRESHOLD_DEFAULT = 0.5
#: SelfTrainConfig.pseudo_range_deg / pseudo_range_step_deg defaults, likewise repeated and tested
PSEUDO_RANGE_DEFAULT = 10.0
PSEUDO_RANGE_STEP_DEFAULT = 5.0
PSEUDO_VIEWS_DEFAULT = 8
#: SelfTrainConfig.batch_empty / student_grid defaults, likewise
BATCH_EMPTY_DEFAULT = 0
STUDENT_GRID_DEFAULT = "teacher"


def _selftrain_flags(args) -> dict:
    """The SelfTrainConfig fields every self-training run sets from the command line."""
    return dict(features=args.features, threshold=args.threshold, density_distill=not args.no_density_distill,
                prior=not args.no_prior, reliability=args.reliability)


def _selftrain_overrides(args) -> dict:
    """SelfTrainConfig fields given on the command line (absent ones keep the config's defaults, and stay
    out of run.json's identity so runs made before a flag existed still resume)."""
    pairs = (("empty_opacity", args.empty_opacity), ("pseudo_range_deg", args.pseudo_range),
             ("pseudo_range_step_deg", args.pseudo_range_step), ("n_pseudo_per_input", args.pseudo_views),
             ("batch_empty", args.batch_empty), ("student_grid", args.student_grid))
    return {k: v for k, v in pairs if v is not None}


def _model_overrides(args) -> dict:
    out = {}
    if args.field:
        out["field"] = args.field
    if args.resolution:
        out["resolution"] = args.resolution
    if args.samples:
        out["n_samples"] = args.samples
    if args.hidden:
        out["hidden"] = args.hidden
    if args.aabb:
        out["aabb"] = ((-args.aabb,) * 3, (args.aabb,) * 3)
    if args.background:
        out["train_background"] = args.background
    if args.no_view_dependence:
        out["view_dependent"] = False
    if args.no_occupancy:
        out["occupancy_resolution"] = 0
    return out


#: How far a test camera may stand from the box the field is fitted in, in box half sizes: beyond it the object
#: is far below a pixel, and float32 rays (relative to the box) lose it altogether (a camera at 1e300 scored NaN).
MAX_CAMERA_BOXES = 1e6


def _check_test_views(scene, train_idx, test_idx, model, scene_dir: Path) -> None:
    """Refuse test cameras that cannot see the fitted box (too far from it); warn about test views that are
    training views (their scores would measure a view the field was trained on)."""
    import numpy as np

    from senerf.data import view_names

    if not model.ndc:
        box = np.asarray(model.aabb, dtype=np.float64)
        centre, half = box.mean(axis=0), float((box[1] - box[0]).max()) / 2
        with np.errstate(over="ignore", invalid="ignore"):   # the largest offset along an axis: no squares
            dist = np.abs(scene.c2w[test_idx, :3, 3] - centre).max(axis=-1)
        far = ~(dist <= MAX_CAMERA_BOXES * half)
        if far.any():
            i = int(np.asarray(test_idx)[np.flatnonzero(far)[0]])
            raise InputError(f"test view {i} ({view_names(scene, [i])[0]}) stands {float(dist[far][0]):.3g} from the "
                             f"centre of the box the field is fitted in, more than {MAX_CAMERA_BOXES:g} times its half "
                             f"size {half:.3g}; are its pose and unit right?", file=scene_dir, field="test views")
    train_c2w = scene.c2w[train_idx]
    for i in np.asarray(test_idx):
        same = np.flatnonzero(np.abs(train_c2w - scene.c2w[i]).max(axis=(1, 2)) <= 1e-9)
        if same.size:
            j = int(np.asarray(train_idx)[same[0]])
            print(f"{PROG}: warning: test view {int(i)} ({view_names(scene, [i])[0]}) has the pose of training view "
                  f"{j} ({view_names(scene, [j])[0]}); its scores measure a view the field is trained on",
                  file=sys.stderr)


def _check_model_fits(model, device: str = "cpu") -> None:
    """:class:`InputError` when the field's feature planes would not fit, refused before anything is written.

    Host: the planes with their gradients and Adam's two moments (4 copies) against half of this machine's
    memory (also with ``--device cuda``, where the scene and the renders live on the host).  CUDA: those 4
    copies plus the backward pass's blend buffers (about 5 more, ``senerf.fields.interp``) against the GPU's
    total memory.
    """
    if model.field != "kplanes":
        return
    from senerf.fields.interp import plane_layout

    _, rows = plane_layout(tuple(int(model.resolution * m) for m in model.multires))
    table = rows * model.n_features * 4  # one float32 copy of the planes
    have = physical_memory_bytes()
    if have is not None and 4 * table > have // 2:
        raise InputError(f"{model.resolution} needs {4 * table / 2**30:.1f} GiB for the feature planes and "
                         f"their optimiser state, more than half of this machine's {have / 2**30:.0f} GiB",
                         field="--resolution")
    if device.startswith("cuda"):
        import torch

        gpu = torch.cuda.get_device_properties(torch.device(device).index or 0).total_memory
        if 9 * table > gpu:
            raise InputError(f"{model.resolution} needs {9 * table / 2**30:.1f} GiB of GPU memory for the feature "
                             f"planes, their optimiser state and gradients, more than the GPU's "
                             f"{gpu / 2**30:.0f} GiB", field="--resolution")


def _check_step_fits(model, batch_rays: int) -> None:
    """:class:`InputError` when one training step could not fit in this machine's memory even at a generous
    estimate, refused before anything is written (a huge ``--hidden`` or ``--batch-rays`` otherwise failed in
    torch's allocator, or under the kernel's OOM killer, after the folder was made or an old run removed).

    K-Planes only (the NeRF field's MLP is fixed).  Counted: the MLP weights with gradients and Adam's moments
    (4 x (hidden^2 + 64 hidden) float32) and, per step, every sample's activations and their gradients
    (2 x batch_rays x n_samples x (3 hidden + planes' features) float32; the occupancy grid only lowers it).
    Refused when one of them alone exceeds the machine's physical memory, so no run that fits is refused.
    """
    have = physical_memory_bytes()
    if have is None or model.field != "kplanes":
        return
    weights = 4 * 4 * (model.hidden ** 2 + 64 * model.hidden)
    if weights > have:
        raise InputError(f"{model.hidden} needs {weights / 2**30:.1f} GiB for the MLPs and their optimiser state, "
                         f"more than this machine's {have / 2**30:.0f} GiB", field="--hidden")
    per_sample = 3 * model.hidden + model.n_features * len(model.multires)
    step = 2 * 4 * batch_rays * model.n_samples * per_sample
    if step > have:
        raise InputError(f"{batch_rays} rays of {model.n_samples} samples need up to {step / 2**30:.1f} GiB a step, "
                         f"more than this machine's {have / 2**30:.0f} GiB", field="--batch-rays")


def _default_protocol(scene, fmt: str, views) -> str:
    """The protocol when ``--protocol`` is not given: ``views`` when views are given; for a Blender-style
    object scene with a test split (not COLMAP's), ``extreme`` when it is named in
    :data:`senerf.data.EXTREME_VIEWS` (a NeRF Synthetic scene) and ``spread`` otherwise (3 training views
    spread over its train split, its test split held out); for every other scene ``llff`` (every 8th image
    held out for testing, 3 training views spread over the rest).  A capture of one's own has no published
    views, so only the benchmark scenes default to theirs."""
    from senerf.data import EXTREME_VIEWS

    if views is not None:
        return "views"
    if scene.kind == "object" and fmt != "colmap" and len(scene.splits["test"]) > 0:
        return "extreme" if scene.name.lower() in EXTREME_VIEWS else "spread"
    return "llff"


#: A COLMAP object capture with at least this share of its 3D points outside the fitted box gets a warning.
POINTS_OUTSIDE_WARN = 0.25


def _warn_points_outside(scene_dir, model) -> None:
    """Warn when much of a COLMAP object capture's sparse point cloud lies outside the box the field is fitted
    in: a background around the object (a 360-degree capture of a room or a garden) is not modelled, so the
    fit paints it onto the box's faces and scores poorly.  Captures without a points3D file are not checked."""
    import numpy as np

    from senerf.data.colmap import sparse_points

    try:
        xyz = sparse_points(scene_dir)
    except InputError as exc:   # the fit does not use the points: a check that cannot run must not stop it
        print(f"{PROG}: warning: the 3D points could not be checked against the box ({exc})", file=sys.stderr)
        return
    if xyz is None or len(xyz) == 0:
        return
    box = np.asarray(model.aabb, dtype=np.float64)
    share = float(np.mean(~np.all((xyz >= box[0]) & (xyz <= box[1]), axis=1)))
    if share >= POINTS_OUTSIDE_WARN:
        centre, half = box.mean(axis=0), float(box[1, 0] - box[0, 0]) / 2
        print(f"{PROG}: warning: {share:.0%} of the capture's {len(xyz)} 3D points lie outside the box the field is "
              f"fitted in (centre ({centre[0]:.3g}, {centre[1]:.3g}, {centre[2]:.3g}), half size {half:.3g}): senerf "
              "fits a bounded object, so a background around it is not modelled and ends up painted on the box; "
              "photos with the background masked out (RGBA) avoid this", file=sys.stderr)


#: Keys every run.json that senerf-fit writes has: how a folder is recognised as one of its runs.
_RUN_KEYS = frozenset({"scene_dir", "format", "protocol", "train", "model"})
#: What senerf-fit writes into its folder (and ``--overwrite`` removes from a folder of another run);
#: ``render`` holds senerf-render's fly-throughs of the run's fields, stale once the run is replaced.
_OUTPUT_NAMES = ("checkpoints", "metrics.json", "summary.png", "render", _RUN_FILE)


def _files_changed(old: dict, identity: dict) -> str:
    """One line saying which of the scene's files changed since ``old`` was recorded, or ``''`` (also when
    ``old`` predates the record: a run.json written before senerf-fit hashed the files cannot tell)."""
    from senerf.data import changed_files
    from senerf.train import differences_text

    then, now = old.get("scene_files"), identity.get("scene_files")
    if not isinstance(then, dict) or not isinstance(now, dict):
        return ""
    lines = changed_files(then, now)
    return f"scene files differ: {differences_text(lines)}" if lines else ""


def _comparable(identity: dict) -> dict:
    """``identity`` with the self-training overrides that equal their defaults left out (an override given
    explicitly at its default value, or recorded as None, names the same run as one not given), ``n_views``
    at its protocol's default as None (likewise), and without the scene files' digests (:func:`_files_changed`
    compares those)."""
    from senerf.data.fewshot import explicit_n_views

    identity = {k: v for k, v in identity.items() if k != "scene_files"}
    if "n_views" in identity:   # a folder written before --n-views at its default was recorded as None
        identity["n_views"] = explicit_n_views(identity.get("protocol"), identity["n_views"])
    defaults = {"empty_opacity": EMPTY_OPACITY_DEFAULT, "pseudo_range_deg": PSEUDO_RANGE_DEFAULT,
                "pseudo_range_step_deg": PSEUDO_RANGE_STEP_DEFAULT, "n_pseudo_per_input": PSEUDO_VIEWS_DEFAULT,
                "batch_empty": BATCH_EMPTY_DEFAULT, "student_grid": STUDENT_GRID_DEFAULT}
    flags = identity.get("selftrain_flags")
    if not isinstance(flags, dict):
        return identity
    kept = {k: v for k, v in flags.items() if not (k in defaults and (v is None or v == defaults[k]))}
    return {**identity, "selftrain_flags": kept}


def _own_outputs(out: Path) -> list[Path]:
    """The entries of ``out`` with the names senerf-fit writes (``iter_*`` folders included)."""
    found = [out / name for name in _OUTPUT_NAMES if (out / name).exists()]
    return found + sorted(p for p in out.glob("iter_*") if p.is_dir())


def _refuse_out_among_inputs(out: Path, scene_dir: Path, image_paths) -> None:
    """:class:`InputError` when ``out`` is the scene folder or a folder of its photos (with ``--overwrite`` the
    run's files would land among them, and the next load would count them); a new folder inside is fine."""
    photo_folders = {Path(p).parent for p in image_paths}   # and the other resolutions' (LLFF's images_N)
    photo_folders |= {p for p in scene_dir.glob("images*") if p.is_dir()}
    inputs = [(scene_dir, "the scene folder")] + [(f, "a folder of the scene's photos") for f in sorted(photo_folders)]
    for folder, what in inputs:
        try:
            same = os.path.samefile(out, folder)
        except OSError:   # out not there yet (or unresolvable, a link loop: output_folder names that later)
            continue
        if same:
            raise InputError(f"is {what}; choose another --out (a new folder inside it is fine)", file=out)


def _prepare_out(out: Path, identity: dict, overwrite: bool) -> None:
    """Refuse a folder holding another run (unless ``overwrite``); record this run's identity.

    ``--overwrite`` only ever removes what senerf-fit wrote: a folder whose ``run.json`` is not one of ours
    (unreadable, or without our keys) is refused even then, and so is a folder of other files that holds
    any name senerf-fit would write (``metrics.json``, ``summary.png``, ``checkpoints``, ``render``, ``iter_*``).
    """
    from senerf.atomic import output_folder
    from senerf.train import atomic_write_text, differences_text, settings_differences

    output_folder(out, "--out")
    run_file = out / _RUN_FILE
    if run_file.exists():
        try:
            old = json.loads(run_file.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            old = None
        if not (isinstance(old, dict) and _RUN_KEYS <= old.keys()):
            raise InputError(f"holds a {_RUN_FILE} that senerf-fit did not write; choose another --out "
                             f"(--overwrite never deletes files it did not make)", file=out)
        changed = _files_changed(old, identity)
        if _comparable(old) != _comparable(identity) or changed:
            if not overwrite:
                diffs = settings_differences(_comparable(old), _comparable(identity))
                what = differences_text(diffs) if diffs else (changed or "settings differ")
                raise InputError(f"holds a different run ({what}); use --overwrite or another --out", file=out)
            removed = []
            for target in _own_outputs(out):
                removed.append(target.name + ("/" if target.is_dir() else ""))
                if target.is_dir():
                    shutil.rmtree(target)
                else:
                    target.unlink()
            print(f"{PROG}: --overwrite: removed the earlier run's {', '.join(removed)} from {out}")
    elif out.exists() and any(out.iterdir()):
        clash = _own_outputs(out)
        if clash:
            raise InputError(f"is not a senerf-fit output folder but holds {clash[0].name}, which a run would "
                             f"overwrite; choose another --out", file=out)
        if not overwrite:
            raise InputError("exists and is not a senerf-fit output folder; use --overwrite or another --out",
                             file=out)
    try:
        atomic_write_text(run_file, json.dumps(identity, indent=1, sort_keys=True))
    except OSError as exc:  # the first write: nothing has been computed yet
        raise InputError(f"cannot write there ({exc.strerror or exc}); choose another --out", file=out) from None


def _run_baseline(scene, train_idx, test_idx, model, train_cfg, out: Path, argv, config: dict, progress: bool) -> dict:
    """Iteration 0 only: train the teacher, evaluate, write metrics.json (DESIGN.md contract).

    A folder whose metrics.json already holds iteration 0 (this run's baseline, finished, perhaps followed
    by self-training iterations) is left as it is: its rows are returned, nothing is retrained or dropped.
    """
    from senerf.train import (RayBatchSource, atomic_write_text, build_field, evaluate, finished_metrics,
                              iteration_row, metrics_document, train_field)

    done = finished_metrics(out, 0)
    if done is not None:
        print(f"{PROG}: iteration 0 is already done in {out} ({len(done['iterations'])} iteration(s) recorded)")
        return done
    t0 = time.perf_counter()
    rays = RayBatchSource.from_scene(scene, train_idx, model, train_cfg.device)
    field = build_field(model, seed=train_cfg.seed, steps=train_cfg.steps)
    result = train_field(field, rays, train_cfg, checkpoint=out / "checkpoints" / "iter_0_train.pt",
                         progress=progress)
    eval_record = out / "checkpoints" / "iter_0_eval.json"
    ev = evaluate(result.field, scene, test_idx, out / "iter_0" / "test", model, occupancy=result.occupancy,
                  device=train_cfg.device, progress=progress, resume=eval_record)
    # interrupted calls' training and evaluation count too
    seconds = time.perf_counter() - t0 + result.seconds_before + ev["seconds_before"]
    metrics = metrics_document(scene, train_idx, test_idx, argv, config)
    metrics["iterations"].append(iteration_row(0, ev, None, seconds, train_cfg.device))
    metrics["seconds_total"] = seconds
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=1))
    # the evaluation record stays: self-training that extends this run reads the teacher's scores back from it
    # instead of rendering every test view again (it removes the record once its own metrics.json holds them)
    return metrics


def _selftrain_available():
    try:
        from senerf.selftrain import SelfTrainConfig, run_selftraining
    except ImportError as exc:
        return None, str(exc)
    return (SelfTrainConfig, run_selftraining), None


def _check_field_flags(args) -> None:
    """:class:`InputError` for a K-Planes setting given with ``--field nerf``, which would be ignored."""
    if args.field == "nerf":
        for flag, value in (("--resolution", args.resolution), ("--hidden", args.hidden)):
            if value:
                from senerf.train import nerf_refusal

                raise InputError(nerf_refusal(), field=flag)


def _run(args, argv) -> int:
    device = check_device(args.device)   # before the demo writes its scene
    _check_field_flags(args)
    set_threads(args.threads)
    if args.demo:
        try:
            from senerf.demo import run_demo
        except ImportError:
            raise InputError("--demo is not available in this build (senerf.demo.run_demo is missing)",
                             field="--demo") from None
        return int(run_demo(args, argv[1:]) or 0)
    if not args.scene:
        raise InputError("a SCENE_DIR is required (or --demo)", field="SCENE_DIR")

    from senerf.data import detect_format, fewshot_split, load_scene, scene_root, spread_views, view_names
    from senerf.data.fewshot import explicit_n_views
    from senerf.train import PRESETS, choose_model, config_to_dict, preset_train_config

    scene_dir = scene_root(args.scene)  # a marker file (transforms_train.json, ...) names its folder
    fmt = detect_format(scene_dir)
    downscale = args.downscale if args.downscale is not None else (8.0 if fmt == "llff" else 1.0)
    kind = None if args.scene_kind is None else args.scene_kind.replace("-", "_")
    if kind is not None and fmt != "colmap":
        raise InputError(f"applies to COLMAP scenes only; {scene_dir} is a {fmt} scene", field="--scene-kind")
    print(f"{PROG}: reading {scene_dir} ({fmt}, downscale {downscale:g})", flush=True)   # seconds for 400 photos
    scene = load_scene(scene_dir, downscale=downscale, kind=kind)
    if args.out is not None:
        _refuse_out_among_inputs(args.out, scene_dir, scene.image_paths)
    from senerf.train.metrics import SSIM_MIN_SIDE

    if min(scene.size) < SSIM_MIN_SIDE:
        raise InputError(f"the images are {scene.size[1]}x{scene.size[0]} at downscale {downscale:g}; the "
                         f"evaluation (SSIM) needs at least {SSIM_MIN_SIDE}x{SSIM_MIN_SIDE}", field="--downscale")
    protocol = args.protocol or _default_protocol(scene, fmt, args.views)
    train_idx, test_idx = fewshot_split(scene, protocol, views=args.views, n_views=args.n_views, seed=args.seed)
    if len(test_idx) == 0:   # protocol 'all' on a scene without a test split: a fit is scored on its test views
        raise InputError(f"protocol {protocol!r} leaves no test views (scene {scene.name!r} has no test split); "
                         "use 'llff' or 'views'", field="--protocol")
    tested, test_views = f"{len(test_idx)} test views", args.test_views
    if test_views is not None:
        subset = spread_views(test_idx, test_views)   # checks the number
        if test_views == len(test_idx):   # all of them: the run the flag's absence makes
            test_views = None
        elif args.reliability == "oracle":   # its pseudo views are the images outside the whole test split
            raise InputError("the oracle's held-out views are those outside the whole test split; score on all "
                             "of it (leave --test-views out)", field="--test-views")
        else:
            tested, test_idx = f"{test_views} of the {len(test_idx)} test views (--test-views)", subset
    more = ' ...' if len(train_idx) > 12 else ''
    print(f"{PROG}: scene {scene.name} ({fmt}, {scene.size[1]}x{scene.size[0]}), protocol {protocol}: "
          f"{len(train_idx)} training views {list(map(int, train_idx))[:12]}{more} "
          f"({', '.join(view_names(scene, train_idx[:12]))}{more}), {tested}")
    if fmt == "colmap":   # the kind was decided from the cameras (or chosen): say which, and why
        from senerf.data.colmap import FORWARD_FACING_DEG, MAX_RAY_DEG, view_spread

        axis, ray, _ = view_spread(scene.c2w, scene.intrinsics_all)
        why = ("--scene-kind" if kind is not None else
               f"limits {FORWARD_FACING_DEG:g} and {MAX_RAY_DEG:g} for forward-facing; --scene-kind to choose")
        print(f"{PROG}: fitted as {scene.kind.replace('_', '-')}: camera axes within {axis:.1f} degrees of their "
              f"mean direction, rays within {ray:.1f} ({why})")
    if args.aabb and scene.kind == "forward_facing":   # the flag's box is in world units around the origin
        from senerf.train.config import ndc_box_text

        raise InputError(f"a forward-facing scene is fitted in NDC, whose box is fixed ({ndc_box_text()}); --aabb "
                         f"(a cube in world units) applies to object scenes", file=scene_dir, field="--aabb")
    model = choose_model(scene, train_idx, {**PRESETS[args.preset]["model"], **_model_overrides(args)})
    _check_model_fits(model, device)
    warn_planes_path(PROG, model, device)
    _check_test_views(scene, train_idx, test_idx, model, scene_dir)
    if fmt == "colmap" and scene.kind == "object":
        _warn_points_outside(scene_dir, model)
    overrides = {k: v for k, v in (("steps", args.steps), ("batch_rays", args.batch_rays)) if v is not None}
    train_cfg = preset_train_config(args.preset, seed=args.seed, device=device, **overrides)

    selftrain = None
    st_cfg = None
    iterations = args.iterations if args.iterations is not None else int(PRESETS[args.preset]["iterations"])
    if iterations > 0:
        selftrain, why = _selftrain_available()
        if selftrain is None:
            print(f"{PROG}: self-training is not available ({why}); running the baseline only", file=sys.stderr)
        else:
            st_cfg = selftrain[0](iterations=iterations, seed=args.seed, **_selftrain_flags(args),
                                  **_selftrain_overrides(args))

    if st_cfg is not None and st_cfg.reliability == "oracle":
        import numpy as np

        held_out = np.setdiff1d(np.arange(scene.n_images), np.union1d(train_idx, test_idx))
        if held_out.size == 0:  # checked now, not after the baseline has trained
            raise InputError(f"--reliability oracle needs held-out views (neither training nor test); protocol "
                             f"{protocol} leaves none of the {scene.n_images} images", file=scene_dir,
                             field="--reliability")
    if st_cfg is not None and st_cfg.reliability != "oracle":   # checked now, not after the baseline has trained
        from senerf.selftrain import features_memory_problem, pseudo_view_centre_problem

        problem = features_memory_problem(st_cfg.features, scene.size)
        if problem is not None:
            raise InputError(problem, field="--downscale")

        problem = pseudo_view_centre_problem(scene, train_idx)
        if problem is not None:
            flag = ("--views" if args.views else "--n-views" if args.n_views else
                    "--protocol" if args.protocol else f"training views (protocol {protocol})")
            raise InputError(problem, file=scene_dir, field=flag)
    _check_step_fits(model, train_cfg.batch_rays)   # after the features' check, which names the likelier cause
    out = args.out if args.out is not None else Path("runs") / f"{scene.name}-{protocol}"
    config = dict(scene_dir=str(scene_dir.resolve()), format=fmt, downscale=downscale, protocol=protocol,
                  views=args.views, n_views=explicit_n_views(protocol, args.n_views), preset=args.preset,
                  train=config_to_dict(train_cfg),
                  model=config_to_dict(model),
                  selftrain=None if st_cfg is None else config_to_dict(st_cfg))
    if kind is not None:  # only when chosen: runs made before the flag existed keep their identity
        config["scene_kind"] = kind
    if test_views is not None:   # likewise
        config["test_views"] = test_views
    # what must match to resume: everything but the device and the number of iterations (a finished
    # baseline can be extended by self-training with the same settings)
    identity = {k: v for k, v in config.items() if k != "selftrain"}
    identity["train"] = {k: v for k, v in identity["train"].items() if k != "device"}
    # empty_opacity is always part of the fingerprint (None when not given), as before the other overrides
    identity["selftrain_flags"] = {**_selftrain_flags(args), "empty_opacity": args.empty_opacity,
                                   **_selftrain_overrides(args)}
    from senerf.data import run_file_digests

    identity["scene_files"] = run_file_digests(scene, train_idx, test_idx, oracle=args.reliability == "oracle")
    _prepare_out(out, identity, args.overwrite)
    print(f"{PROG}: writing to {out}")

    progress = not args.quiet
    if selftrain is None:
        metrics = _run_baseline(scene, train_idx, test_idx, model, train_cfg, out, argv, config, progress)
    else:
        extra = {k: v for k, v in config.items() if k not in ("train", "model", "selftrain")}
        metrics = selftrain[1](scene, train_idx, test_idx, model, train_cfg, st_cfg, out, command=argv,
                               extra_config=extra, progress=progress, scene_files=identity["scene_files"])
    for it in metrics["iterations"]:
        print(f"{PROG}: iteration {it['iteration']}: PSNR {it['psnr']:.2f} dB, SSIM {it['ssim']:.3f}, "
              f"LPIPS {it['lpips']}, {it['seconds']:.0f} s")
    print(f"{PROG}: metrics in {out / 'metrics.json'}")
    summary = _write_summary(metrics, scene, train_idx, test_idx, model, out)
    if summary is not None:
        print(f"{PROG}: summary figure in {summary}")
    print(f"{PROG}: to fly around the fitted scene: senerf-render {shlex.quote(str(out))}")
    return 0


def _write_summary(metrics: dict, scene, train_idx, test_idx, model, out: Path) -> Path | None:
    """``out/summary.png`` (:func:`senerf.report.plot_run_summary`); the metrics are already on disk, so a
    figure that cannot be drawn is a one-line warning, never a failed run."""
    import numpy as np

    from senerf.geometry import closest_point_to_axes, nearest_view_angles
    from senerf.report import plot_run_summary
    from senerf.train import eval_images

    train_c2w, test_c2w = scene.c2w[np.asarray(train_idx)], scene.c2w[np.asarray(test_idx)]
    try:
        # object scenes: the angle about the point the cameras look at; forward-facing: between optical axes
        center = None if scene.kind == "forward_facing" else closest_point_to_axes(scene.c2w)
        angles = nearest_view_angles(train_c2w, test_c2w, center)
    except ValueError:   # all axes parallel, or a camera at that point: the angle between optical axes
        try:
            angles = nearest_view_angles(train_c2w, test_c2w, None)
        except ValueError:
            angles = None
    def ground_truth(position: int) -> np.ndarray:
        return eval_images(scene, [test_idx[position]], model)[0]

    try:
        return plot_run_summary(metrics, out, out / "summary.png", angles_deg=angles, ground_truth=ground_truth)
    except (OSError, ValueError, MemoryError) as exc:
        print(f"{PROG}: warning: no summary figure ({str(exc) or type(exc).__name__})", file=sys.stderr)
        return None


def _attach_negative_values(argv: list[str]) -> list[str]:
    """``--views -1,0`` as ``--views=-1,0``: argparse takes a value starting with ``-`` for an option and
    reports "expected one argument"; attached, the value reaches its own check (and its clear message)."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--views" and i + 1 < len(argv) and argv[i + 1][:1] == "-" and argv[i + 1][1:2].isdigit():
            out.append(f"--views={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``senerf-fit``; returns the exit status (0 ok, 2 bad input, 1 internal error)."""
    argv = _attach_negative_values(list(sys.argv[1:] if argv is None else argv))
    short_openmp_waits()   # before torch is imported: OpenMP workers spin briefly, then sleep
    return run_command(PROG, lambda: _run(build_parser().parse_args(argv), [PROG, *argv]),
                       "rerun the same command to resume")


def console() -> None:
    """The ``senerf-fit`` console script: :func:`main`, exiting with its status
    (:func:`senerf.cliargs.console_entry`)."""
    from senerf.cliargs import console_entry

    console_entry(main)


if __name__ == "__main__":  # pragma: no cover
    console()
