"""``senerf-render``: render a finished ``senerf-fit`` run along a camera path and write PNG frames and GIFs.

Paths (:mod:`senerf.geometry.paths`): ``orbit`` circles the point the input cameras look at, level, at their
mean elevation and distance (the default for object scenes); ``spiral`` is NeRF's spiral in front of a
forward-facing capture, focused by the scene's depth bounds (the default for LLFF scenes); ``test`` renders
the run's test views in order (each with its own intrinsics), the very renders ``senerf-fit`` scored.

The field is the one a finished iteration ended with (``checkpoints/iter_K_train.pt``, loaded with
``weights_only=True``); the scene folder named in ``run.json`` gives the cameras.  Outputs go to a new folder
(default ``RUN/render/<path>_iter<K>``): ``rgb_XXX.png``, ``depth_XXX.png`` (one depth colour range for the
whole path, so the colours do not flicker), ``rgb.gif``, ``depth.gif`` and ``path.json`` (the poses, OpenCV
camera-to-world in the scene's world frame, and the intrinsics); with ``--compare`` also ``compare.gif``, the
teacher (iteration 0) beside the rendered iteration along the same path.  The output folder is written once every
frame is rendered and appears whole, by one rename (an empty folder of the user's is filled, and an earlier output in
the current folder or a mount point is replaced in place: :func:`write_frames`).  Until then each rendered frame is
kept in a hidden folder beside it (``.<name>.frames``, :func:`frames_record`, marked as senerf-render's), so that a
render interrupted (Ctrl-C, SIGTERM, a kill, a full disk) goes on where it stopped when the same command is run
again, with the same frames to the bit (on the same kind of device); that folder is removed once the output lands.

Exit status: 0 done, 2 bad input (one line ``senerf-render: error: ...`` naming the file or flag), 130
interrupted (Ctrl-C or SIGTERM; no output is written, the frames rendered so far are kept), 1 internal error.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import re
import shutil
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from senerf import __version__
from senerf.cliargs import (THREADS_HELP, OneLineParser, check_device, float_flag, int_flag, run_command, set_threads,
                            short_openmp_waits, threads_flag, warn_planes_path)
from senerf.errors import InputError
from senerf.memory import physical_memory_bytes

__all__ = ["FittedRun", "load_fitted_run", "with_iteration", "path_cameras", "render_frames", "frames_record",
           "side_by_side", "write_frames", "recover_interrupted", "main", "console", "PATHS"]

PROG = "senerf-render"
#: The camera paths ``senerf-render`` draws.
PATHS = ("orbit", "spiral", "test")
#: Frames of an orbit or spiral when ``--frames`` is not given.
FRAMES_DEFAULT = 60
_MARKER = "path.json"
#: The file that marks a temporary folder of senerf-render (removed with it when a run was killed outright).
_PARTIAL = ".senerf-render-partial"


@dataclass(frozen=True, eq=False)
class FittedRun:
    """A finished iteration of a ``senerf-fit`` run, ready to render.

    Attributes:
        folder: the run folder.
        scene: the :class:`senerf.data.Scene` named by ``run.json`` (at the run's downscale).
        model: the run's :class:`senerf.train.ModelConfig`.
        field: the field the iteration ended with, in eval mode, on the requested device.
        occupancy: its occupancy grid, or ``None``.
        iteration: the iteration (0 = the teacher).
        train_idx, test_idx: ``(m,)``, ``(t,)`` the run's view indices into the scene.
        seed, steps: the run's initialisation seed and training steps (to rebuild its fields).
        finished: the run's finished iterations, ascending.
    """

    folder: Path
    scene: object
    model: object
    field: object
    occupancy: object
    iteration: int
    train_idx: np.ndarray
    test_idx: np.ndarray
    seed: int
    steps: int
    finished: tuple


def _read_json(path: Path) -> dict:
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError("not found: is this a senerf-fit output folder?", file=path) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot be read as JSON ({exc})", file=path) from None
    if not isinstance(record, dict):
        raise InputError("expected a JSON object", file=path)
    return record


def _key(record: dict, key: str, path: Path, kind=None, field: str | None = None):
    if key not in record or (kind is not None and not isinstance(record[key], kind)):
        raise InputError("missing or of the wrong type", file=path, field=field or key)
    return record[key]


def _int(record: dict, key: str, path: Path, field: str, minimum: int = 0) -> int:
    value = record.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise InputError(f"expected an integer >= {minimum}, got {value!r}", file=path, field=field)
    return value


def _views(metrics: dict, key: str, path: Path, n_images: int) -> np.ndarray:
    """``metrics[key]`` as an index array: a non-empty list of distinct integers in ``[0, n_images)``."""
    views = metrics.get(key)
    if (not isinstance(views, list) or not views
            or any(isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < n_images for v in views)):
        raise InputError(f"expected a non-empty list of view indices in [0, {n_images}), got {views!r}"[:200],
                         file=path, field=key)
    return np.asarray(views, dtype=np.int64)


def _views_by_photo(metrics: dict, key: str, path: Path, scene, idx: np.ndarray) -> np.ndarray:
    """``idx``, or, when ``metrics`` names the views' photos (``train_images`` / ``test_images``; runs made
    before senerf-fit recorded them have indices only) and the scene now holds them at other indices (a
    split file added since the fit), the indices of those photos; a photo the scene no longer has is an
    :class:`InputError` naming it."""
    from senerf.data import view_names

    names = metrics.get(key)
    if not (isinstance(names, list) and len(names) == idx.size and all(isinstance(n, str) for n in names)):
        return idx   # a run from before the names were recorded: the indices are all there is
    if view_names(scene, idx) == names:
        return idx
    where = {name: i for i, name in enumerate(view_names(scene, range(scene.n_images)))}
    missing = [name for name in names if name not in where]
    if missing:
        raise InputError(f"the fit's photo {missing[0]} is not in the scene any more", file=path, field=key)
    return np.asarray([where[name] for name in names], dtype=np.int64)


def _model(run: dict, run_path: Path):
    from senerf.train import ModelConfig

    record = _key(run, "model", run_path, dict)
    try:
        return ModelConfig(**record)
    except InputError as exc:   # ModelConfig's own check, named in run.json
        raise InputError(exc.problem, file=run_path, field=f"model.{exc.field}") from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"not a model of this senerf version ({exc})", file=run_path, field="model") from None


def _load_state(module, state, name: str, ckpt: Path, allow_inf: bool = False) -> None:
    """``module`` loaded from ``state`` (one line naming ``ckpt`` when it does not fit or holds NaN; inf only
    with ``allow_inf``: an occupancy grid marks cells not yet measured with inf)."""
    from senerf.train import load_state_keeping_box

    if not isinstance(state, dict):
        raise InputError(f"its {name} is not a state dict", file=ckpt)
    try:
        load_state_keeping_box(module, state)
    except (RuntimeError, TypeError, KeyError, ValueError, AttributeError) as exc:
        raise InputError(f"its {name} does not fit the run's model ({str(exc).splitlines()[0]})", file=ckpt) from None
    floats = [v for v in module.state_dict().values() if v.is_floating_point()]
    if any(bool(v.isnan().any()) or (not allow_inf and bool(v.isinf().any())) for v in floats):
        raise InputError(f"its {name} holds non-finite values ({'NaN' if allow_inf else 'NaN or inf'})", file=ckpt)


def load_fitted_run(folder, iteration: int | None = None, device: str = "cpu") -> FittedRun:
    """Load a run folder's field after ``iteration`` (default: the last finished one).

    Raises:
        InputError: not a senerf-fit folder, a bad ``run.json`` / ``metrics.json`` value, no finished
            iteration (or not ``iteration``), a missing or foreign checkpoint, a scene folder that no longer
            matches the run.

    Warns:
        UserWarning: the scene's files no longer hold what the fit read (``run.json``'s ``scene_files``).
    """
    from senerf.data import load_scene

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder", file=folder)
    run_path, metrics_path = folder / "run.json", folder / "metrics.json"
    run = _read_json(run_path)
    if not metrics_path.exists():   # a fit that has not finished its first iteration (or was killed in it)
        raise InputError("holds no finished iteration yet (no metrics.json); let senerf-fit finish one (rerun its "
                         "command to resume)", file=folder)
    metrics = _read_json(metrics_path)
    rows = _key(metrics, "iterations", metrics_path, list)
    for i, r in enumerate(rows):   # a row skipped here would make "the last iteration" an earlier one
        if not (isinstance(r, dict) and type(r.get("iteration")) is int and r["iteration"] >= 0):
            raise InputError(f"expected an integer >= 0, got {r.get('iteration') if isinstance(r, dict) else r!r}",
                             file=metrics_path, field=f"iterations[{i}].iteration")
    done = sorted(r["iteration"] for r in rows)
    if not done:
        raise InputError("holds no finished iteration yet; let senerf-fit finish one", file=metrics_path)
    k = done[-1] if iteration is None else int(iteration)
    if k not in done:
        raise InputError(f"iteration {k} is not finished in this run (finished: {done})", field="--iteration")
    model = _model(run, run_path)
    train = _key(run, "train", run_path, dict)
    seed, steps = _int(train, "seed", run_path, "train.seed"), _int(train, "steps", run_path, "train.steps", 1)
    scene_dir = Path(_key(run, "scene_dir", run_path, str))
    downscale = run.get("downscale")
    if isinstance(downscale, bool) or not isinstance(downscale, (int, float)) or not 1.0 <= downscale < float("inf"):
        raise InputError(f"expected a number >= 1, got {downscale!r}", file=run_path, field="downscale")
    kind = run.get("scene_kind")
    if kind not in (None, "object", "forward_facing"):
        raise InputError(f"expected 'object' or 'forward_facing', got {kind!r}", file=run_path, field="scene_kind")
    resolution = metrics.get("resolution")
    if not (isinstance(resolution, list) and len(resolution) == 2
            and all(type(v) is int and v > 0 for v in resolution)):   # before the scene is blamed for it
        raise InputError(f"expected [H, W], two integers > 0, got {resolution!r}"[:200], file=metrics_path,
                         field="resolution")
    scene = load_scene(scene_dir, downscale=downscale, kind=kind)
    if list(scene.size) != resolution:
        raise InputError(f"the scene is {scene.size[0]}x{scene.size[1]} (H x W) at downscale {downscale:g}; the run "
                         f"was fitted at {resolution!r}"[:200], file=scene_dir)
    train_idx = _views_by_photo(metrics, "train_images", metrics_path, scene,
                                _views(metrics, "train_views", metrics_path, scene.n_images))
    test_idx = _views_by_photo(metrics, "test_images", metrics_path, scene,
                               _views(metrics, "test_views", metrics_path, scene.n_images))
    _warn_if_files_changed(run.get("scene_files"), scene, run_path)
    field, occupancy = _load_field(folder, model, k, seed, steps, device)
    return FittedRun(folder, scene, model, field, occupancy, k, train_idx, test_idx, seed, steps, tuple(done))


def _warn_if_files_changed(recorded, scene, run_path: Path) -> None:
    """Warn when the scene's files no longer hold what the fit read (``run.json``'s ``scene_files``; runs
    made before senerf-fit recorded them are not checked): the cameras then come from the files as they are
    now, which may not be the frame the field was fitted in."""
    from senerf.data import changed_files, scene_file_digests, view_names
    from senerf.train import differences_text

    if not isinstance(recorded, dict):
        return
    views = [i for i, name in enumerate(view_names(scene, range(scene.n_images))) if name in recorded]
    now = scene_file_digests(scene, views)   # the photos the fit read (and the pose and camera files)
    lines = changed_files(recorded, {name: digest for name, digest in now.items() if name in recorded})
    if lines:   # the first difference and how many more, as senerf-fit's refusal says it
        warnings.warn(f"{run_path}: the scene's files changed since the fit ({differences_text(lines)}); its "
                      "cameras and photos are read as they are now", stacklevel=3)


def _load_field(folder: Path, model, k: int, seed: int, steps: int, device: str):
    """The field (eval mode) and occupancy grid iteration ``k`` ended with, from ``iter_K_train.pt``."""
    import torch

    from senerf.train import build_field, load_checkpoint, make_occupancy

    ckpt = folder / "checkpoints" / f"iter_{k}_train.pt"
    if not ckpt.is_file():
        raise InputError("missing: the run's checkpoints were removed", file=ckpt)
    state = load_checkpoint(ckpt, map_location="cpu")
    if state.get("format") != "senerf-train-1" or "field" not in state:
        raise InputError("not a senerf training checkpoint", file=ckpt)
    field = build_field(model, seed=seed, steps=steps)
    _load_state(field, state["field"], "field", ckpt)   # a NeRF field's annealing weights included, as scored
    occupancy = make_occupancy(model, "cpu")
    if occupancy is not None and "occupancy" in state:
        _load_state(occupancy, state["occupancy"], "occupancy grid", ckpt, allow_inf=True)
    field = field.to(torch.device(device)).eval()
    occupancy = None if occupancy is None else occupancy.to(torch.device(device))
    return field, occupancy


def with_iteration(run: FittedRun, iteration: int, device: str = "cpu", flag: str = "--iteration") -> FittedRun:
    """``run`` with the field of another finished ``iteration`` (the scene is not read again); an unfinished
    one is an :class:`InputError` naming ``flag``, the option that asked for it."""
    if iteration not in run.finished:
        raise InputError(f"iteration {iteration} is not finished in this run (finished: {list(run.finished)})",
                         field=flag)
    field, occupancy = _load_field(run.folder, run.model, iteration, run.seed, run.steps, device)
    return dataclasses.replace(run, field=field, occupancy=occupancy, iteration=iteration)


def path_cameras(run: FittedRun, path: str, frames: int, scale: float = 1.0, elevation: float | None = None):
    """Cameras of a path: ``(c2w (n, 4, 4) float64, intrinsics: a tuple of n)``.

    ``orbit`` and ``spiral`` are built from the run's input (training) cameras and use the first one's
    intrinsics, scaled by ``scale``; ``test`` takes the test views with their own (``frames`` is ignored).
    ``elevation`` (degrees) overrides the orbit's.  The spiral looks at the depth NeRF's LLFF code picks from
    the scene's near and far bounds (:func:`senerf.geometry.spiral_focus_depth`); a scene without bounds (an
    object) at the point the cameras look at.

    Raises:
        InputError: no such path for this scene (an orbit of a forward-facing NDC run, degenerate cameras),
            or a ``scale`` that gives a fractional image size.
    """
    from senerf.geometry import orbit_path, spiral_focus_depth, spiral_path

    scene = run.scene
    if path == "test":
        idx = run.test_idx
        return scene.c2w[idx], tuple(_scaled(scene.intrinsics_all[int(i)], scale) for i in idx)
    inputs = scene.c2w[run.train_idx]
    k = _scaled(scene.intrinsics_all[int(run.train_idx[0])], scale)
    if path == "orbit" and getattr(run.model, "ndc", False):
        raise InputError("an orbit goes behind a forward-facing (NDC) capture, where nothing was fitted; use "
                         "--path spiral or test", field="--path")
    if path == "orbit":
        try:
            c2w = orbit_path(inputs, frames, elevation=elevation)
        except ValueError:   # the inputs look along parallel axes: orbit what all the scene's cameras look at
            center = _common_point(scene, "orbit")
            try:
                c2w = orbit_path(inputs, frames, center=center, elevation=elevation)
            except ValueError as exc:
                raise InputError(f"no orbit for this scene ({exc}); use --path test", field="--path") from None
    elif path == "spiral":
        near, far = scene.near, scene.far
        if near is None or far is None:   # object scenes: focus on the point the inputs look at
            focus = float(np.linalg.norm(_common_point(scene, "spiral") - inputs[:, :3, 3].mean(axis=0)))
        else:
            focus = spiral_focus_depth(near, far)
        try:
            c2w = spiral_path(inputs, frames, focus_depth=focus)
        except ValueError as exc:
            raise InputError(f"no spiral for this scene ({exc}); use --path orbit or test", field="--path") from None
    else:
        raise InputError(f"expected one of {', '.join(PATHS)}, got {path!r}", field="--path")
    return np.asarray(c2w, dtype=np.float64), (k,) * int(frames)


def _common_point(scene, path: str) -> np.ndarray:
    """The point the scene's cameras look at, for an orbit or spiral around it; InputError naming ``--path``
    when they look along parallel axes (no such point, and no flag of senerf-render gives one)."""
    from senerf.geometry import closest_point_to_axes

    try:
        return closest_point_to_axes(scene.c2w)
    except ValueError:
        raise InputError(f"no {path} for this scene: its cameras look along parallel axes, so there is no point "
                         "they all look at; use --path test", field="--path") from None


def _scaled(k, scale: float):
    try:
        return k if scale == 1.0 else k.scaled(scale)
    except ValueError:
        raise InputError(f"{k.width}x{k.height} times {scale:g} is not a whole number of pixels",
                         field="--scale") from None


def frames_record(out: Path) -> Path:
    """The folder beside ``out`` (``.NAME.frames``) where each rendered frame is kept until the output lands, so
    that a rerun after an interrupt renders only the frames it lacks (:func:`render_frames`' ``resume``)."""
    out = Path(out)
    return out.with_name(f".{out.name}.frames")


#: The file that marks a frames record as senerf-render's (only such a folder is written into and removed).
_RECORD_MARK = ".senerf-render-frames"
#: The names senerf-render writes into a frames record: the frames and atomic_write's temporaries of them.
_RECORD_FILES = re.compile(r"(frame|teacher)_\d{3,}\.npz|\.(frame|teacher)_\d{3,}\.npz\.[0-9a-f]+\.tmp")


def _open_record(record: Path) -> int:
    """Make the frames record ``record`` (marked as ours) or check that an existing one is ours; returns the
    frames it holds.  A folder of that name senerf-render did not mark is an :class:`InputError`."""
    if record.exists() or record.is_symlink():
        if record.is_symlink() or not record.is_dir() or not (record / _RECORD_MARK).is_file():
            raise InputError("is in the way: senerf-render keeps the frames of an unfinished render there, and did "
                             "not make this; move it or choose another --out", file=record)
        return sum(1 for p in record.iterdir() if p.suffix == ".npz" and _RECORD_FILES.fullmatch(p.name))
    record.mkdir()
    (record / _RECORD_MARK).touch()
    return 0


def _landed(out: Path, path_record: dict) -> bool:
    """True when ``out`` holds this render's ``path.json`` (written last, so the output is whole)."""
    return _marker(out) == json.loads(json.dumps(path_record))


def _close_record(record: Path, landed: bool) -> None:
    """Remove the frames record once the output ``landed``, or when it holds no frame (an interrupt before the
    first one): only the files senerf-render wrote there, then the folder when nothing else is left."""
    if record.is_symlink() or not (record / _RECORD_MARK).is_file():
        return
    ours = [p for p in record.iterdir() if _RECORD_FILES.fullmatch(p.name)]
    if not landed and any(p.suffix == ".npz" for p in ours):
        return   # kept for the rerun
    for p in [*ours, record / _RECORD_MARK]:
        p.unlink(missing_ok=True)
    try:
        record.rmdir()
    except OSError:   # something else was put there: it stays
        pass


def _frame_digest(base: str, c2w: np.ndarray, k) -> str:
    """SHA-256 naming one frame: ``base`` (the field, its grid, the model and the device) and the frame's
    camera."""
    h = hashlib.sha256(base.encode())
    h.update(np.ascontiguousarray(c2w, dtype=np.float64).tobytes())
    h.update(repr(k).encode())
    return h.hexdigest()


def _frame_layout(size: tuple[int, int]) -> dict:
    h, w = size
    return dict(rgb=((h, w, 3), np.uint8), z_depth=((h, w), np.float32), acc=((h, w), np.float32))


def render_frames(run: FittedRun, c2w: np.ndarray, intrinsics, device=None, progress: bool = True,
                  resume: Path | None = None, name: str = "frame") -> dict:
    """Render the path: ``rgb (n, H, W, 3)`` uint8, ``depth (n, H, W, 3)`` uint8 colour-mapped over one
    depth range for all frames (1st-99th percentile of the opaque pixels), ``z_depth``/``acc (n, H, W)``.

    With ``resume`` (a folder), each frame is written there as ``NAME_XXX.npz`` (compressed) as soon as it is
    rendered, stamped with a digest of the field, its grid, the model, the device type and the frame's camera,
    and a frame already there under its digest is read back instead of rendered (``read_back`` in the result
    counts them): an interrupted render goes on where it stopped, with the same frames to the bit."""
    import torch

    from senerf.atomic import read_npz_record, write_npz_record
    from senerf.train import depth_to_color, per_view_intrinsics, render_views
    from senerf.train.evaluate import field_digest, to_uint8

    c2w = np.asarray(c2w, dtype=np.float64)
    per_view = per_view_intrinsics(intrinsics, len(c2w))
    size = per_view[0].size
    layout = _frame_layout(size)
    frames = {key: np.empty((len(c2w), *shape), dtype) for key, (shape, dtype) in layout.items()}
    base = None
    if resume is not None:   # CPU and CUDA renders differ in their last bits
        where = torch.device(device) if device is not None else next(run.field.parameters()).device
        base = field_digest(run.field, run.occupancy, run.model) + where.type
    todo = []
    for i, (pose, k) in enumerate(zip(c2w, per_view)):
        digest = None if resume is None else _frame_digest(base, pose, k)
        rec = None if resume is None else read_npz_record(Path(resume) / f"{name}_{i:03d}.npz", digest, layout)
        if rec is None:
            todo.append((i, digest))
        else:
            for key in layout:
                frames[key][i] = rec[key]
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(c2w), initial=len(c2w) - len(todo), desc="render", unit="frame", dynamic_ncols=True)
        if len(todo) < len(c2w):
            bar.set_postfix_str(f"{len(c2w) - len(todo)} read back")
    try:
        for i, digest in todo:
            out = render_views(run.field, run.model, per_view[i], c2w[i:i + 1], occupancy=run.occupancy,
                               device=device)
            frame = dict(rgb=to_uint8(out["rgb"][0]), z_depth=out["z_depth"][0], acc=out["acc"][0])
            for key in layout:   # as senerf-fit's PNGs, a frame at a time
                frames[key][i] = frame[key]
            if resume is not None:
                write_npz_record(Path(resume) / f"{name}_{i:03d}.npz", digest, frame, compress=True)
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
    z_depth, acc = frames["z_depth"], frames["acc"]
    opaque = z_depth[(acc > 0.5) & np.isfinite(z_depth)]
    lo, hi = (np.percentile(opaque, [1.0, 99.0]) if opaque.size else (None, None))
    bg = 1.0 if run.model.eval_background == "white" else 0.0
    depth = np.stack([depth_to_color(z, a, lo=lo, hi=hi, background=bg) for z, a in zip(z_depth, acc)])
    return dict(rgb=frames["rgb"], depth=depth, z_depth=z_depth, acc=acc, read_back=len(c2w) - len(todo))


def side_by_side(left: np.ndarray, right: np.ndarray, labels: tuple[str, str], header: int = 18,
                 gap: int = 4) -> np.ndarray:
    """Two uint8 frame stacks ``(n, H, W, 3)`` beside each other, white ``gap`` between them, each labelled in
    a white ``header`` above it (a label wider than its panel is cut at the panel's edge):
    ``(n, header + H, 2 W + gap, 3)`` uint8."""
    from PIL import Image, ImageDraw

    left, right = np.asarray(left), np.asarray(right)
    if left.dtype != np.uint8 or right.dtype != np.uint8:
        raise ValueError(f"expected uint8 frames, got {left.dtype} and {right.dtype}")
    if left.shape != right.shape or left.ndim != 4 or left.shape[-1] != 3:
        raise ValueError(f"expected two (n, H, W, 3) stacks of one shape, got {left.shape} and {right.shape}")
    n, h, w, _ = left.shape
    out = np.full((n, header + h, 2 * w + gap, 3), 255, np.uint8)
    out[:, header:, :w], out[:, header:, w + gap:] = left, right
    for label, x in zip(labels, (0, w + gap)):
        title = Image.new("RGB", (w, header), (255, 255, 255))
        ImageDraw.Draw(title).text((2, 3), label, fill=(0, 0, 0))
        out[:, :header, x:x + w] = np.asarray(title)
    return out


def write_frames(out: Path, frames: dict, record: dict, fps: float, overwrite: bool = False,
                 compare: np.ndarray | None = None) -> Path:
    """Write the frames, the two GIFs (and ``compare.gif`` of ``compare (n, H', W', 3)`` uint8 when given)
    and ``path.json`` into a temporary sibling of ``out``, then rename it to ``out``.  An existing ``out`` is
    replaced only with ``overwrite`` and only when it is a senerf-render folder (it holds ``path.json``
    written by this command); an empty folder (not a link) is filled instead, its files moved in, path.json
    last.  An earlier output in a folder that cannot be renamed aside (a mount point) or that is the current
    folder (a shell inside it) is replaced in place (:func:`_refill`): there an interrupt leaves the folder
    without the earlier output, where elsewhere it puts the earlier output back."""
    import imageio.v3 as iio

    from senerf.train import write_png

    out = Path(out)
    _check_out(out, overwrite)
    tmp = _temp_sibling(out)
    in_place = False
    try:
        for i, (rgb, depth) in enumerate(zip(frames["rgb"], frames["depth"])):
            write_png(tmp / f"rgb_{i:03d}.png", rgb)
            write_png(tmp / f"depth_{i:03d}.png", depth)
        duration = 1000.0 / fps
        gifs = dict(rgb=frames["rgb"], depth=frames["depth"], **({} if compare is None else dict(compare=compare)))
        for name, stack in gifs.items():
            iio.imwrite(tmp / f"{name}.gif", stack, extension=".gif", duration=duration, loop=0)
        (tmp / _MARKER).write_text(json.dumps(record, indent=1))
        (tmp / _PARTIAL).unlink()   # from here on path.json marks it (recover_interrupted)
        os.chmod(tmp, 0o755)
        if _empty_folder(out):   # the user's own folder, kept (its mode, its owner, a shell inside it)
            _fill(out, tmp)
        elif out.exists() and _replaced_in_place(out):
            in_place = True
            _refill(out, tmp)
        elif out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            try:
                out.rename(old)
                tmp.rename(out)
            except BaseException:   # Ctrl-C / SIGTERM between the renames: the earlier output goes back
                if old.exists() and not out.exists():
                    old.rename(out)
                raise
            if old.is_symlink():   # --out a link to an earlier output: the link goes, what it led to stays
                old.unlink()
            else:
                shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(out)
    except OSError as exc:   # a full disk, a folder that turned read-only: the earlier output (if any) stays,
        gone = "; the earlier output there was removed first (replaced in place)" if in_place else ""   # but here
        raise InputError(f"cannot write there ({exc.strerror or exc}){gone}", file=out) from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return out


#: The file a fill of the user's folder (:func:`_fill`, :func:`_refill`) puts there first and removes last.  It
#: names the temporary folder whose files are moved in, so that after a kill :func:`recover_interrupted` knows the
#: senerf-render files there are that fill's (or the earlier output's it replaces), never the user's.
_FILLING = ".senerf-render-filling"
#: Files a folder may hold and still count as empty (a Finder's view settings).
_IGNORED = frozenset({".DS_Store"})


def _fill(out: Path, tmp: Path) -> None:
    """Move ``tmp``'s files into the folder ``out`` (empty, or holding the files an interrupted fill moved),
    ``path.json`` last, with :data:`_FILLING` naming ``tmp`` in ``out`` meanwhile; an interrupt (Ctrl-C, SIGTERM)
    moves back what this call moved.  A move across file systems (``out`` a mount point) copies, then deletes; a
    kill mid-way is finished by :func:`recover_interrupted`."""
    filling = out / _FILLING
    marked = _filling_of(out) != tmp.name   # False when a caller (_refill) or a killed call marked it already
    names = sorted(p.name for p in tmp.iterdir() if p.name != _MARKER) + [_MARKER]
    begun = []   # recorded before each move: an interrupt inside one (a copy across file systems) is undone too
    try:
        if marked:
            _mark_filling(out, tmp)
        for name in names:
            begun.append(name)
            shutil.move(tmp / name, out / name)
    except BaseException:
        for name in begun:
            if (tmp / name).exists():   # not moved, or copied and not yet deleted: the copy in out goes
                (out / name).unlink(missing_ok=True)
            else:
                shutil.move(out / name, tmp / name)
        if marked:   # a killed call's mark stays: its files in out are still to be moved in by the next call
            filling.unlink(missing_ok=True)
        raise
    filling.unlink(missing_ok=True)


def _mark_filling(out: Path, tmp: Path) -> None:
    """Write ``out``'s :data:`_FILLING`, naming ``tmp``, whole or not at all: written as
    ``.senerf-render-filling.PID`` first, then renamed (:func:`_tidy_filling` removes such a part of a dead
    process)."""
    part = _filling_part(out)
    part.write_text(tmp.name)
    os.replace(part, out / _FILLING)


def _filling_part(out: Path) -> Path:
    """Where :func:`_mark_filling` writes ``out``'s mark before its rename (``.senerf-render-filling.PID``)."""
    return out / f"{_FILLING}.{os.getpid()}"


def _replaced_in_place(out: Path) -> bool:
    """True for a folder (not a link) that :func:`write_frames` cannot rename aside without harm: a mount point
    (the rename fails) or the current folder (a shell inside it would be left in a deleted folder)."""
    if out.is_symlink() or not out.is_dir():
        return False
    try:
        return os.path.ismount(out) or os.path.samefile(out, os.getcwd())
    except OSError:   # no current folder (it was deleted)
        return os.path.ismount(out)


def _remove_ours(folder: Path, keep=()) -> None:
    """Remove the files senerf-render writes (:data:`_OUR_FILES`) from ``folder``, ``path.json`` first (so that
    the folder stops being a finished output before any frame goes), except the names in ``keep``."""
    names = [p.name for p in folder.iterdir() if _OUR_FILES.fullmatch(p.name) and p.name not in keep]
    for name in sorted(names, key=lambda n: (n != _MARKER, n)):
        (folder / name).unlink(missing_ok=True)


def _refill(out: Path, tmp: Path) -> None:
    """Replace the earlier senerf-render output in the folder ``out`` by ``tmp``'s files, in place: with
    :data:`_FILLING` naming ``tmp`` in ``out``, the earlier files are removed (``path.json`` first), then ``tmp``'s
    are moved in (:func:`_fill`, ``path.json`` last).  An interrupt or a write that fails leaves ``out`` without any
    of them (the earlier output is gone by then: no half of either stays); a kill mid-way is finished by
    :func:`recover_interrupted`."""
    try:
        _mark_filling(out, tmp)
        _remove_ours(out)
        _fill(out, tmp)
    except BaseException:
        _remove_ours(out)
        (out / _FILLING).unlink(missing_ok=True)
        _filling_part(out).unlink(missing_ok=True)
        raise


def _expected_names(marker: dict) -> set[str] | None:
    """The file names of the output whose ``path.json`` holds ``marker``; None when it does not say."""
    c2w, compared = marker.get("c2w"), marker.get("compared_with")
    if not isinstance(c2w, list):
        return None
    frames = {f"{kind}_{i:03d}.png" for kind in ("rgb", "depth") for i in range(len(c2w))}
    return frames | {"rgb.gif", "depth.gif", _MARKER} | ({"compare.gif"} if compared is not None else set())


def _filling_of(out: Path) -> str | None:
    """The temporary folder's name that ``out``'s :data:`_FILLING` names (a fill under way or killed), or None."""
    mark = out / _FILLING
    if out.is_symlink() or not out.is_dir() or mark.is_symlink() or not mark.is_file():
        return None
    try:
        return mark.read_text()
    except (OSError, UnicodeDecodeError):
        return None


def _begun_fill(out: Path, tmp: Path) -> bool:
    """True when ``tmp``, a complete output (our ``path.json``, no :data:`_PARTIAL`), was being moved into
    ``out``: ``out``'s :data:`_FILLING` names it, and ``out`` holds no whole ``path.json`` of ours yet."""
    return (_is_ours(tmp) and not (tmp / _PARTIAL).exists() and _filling_of(out) == tmp.name
            and not _is_ours(out))   # (a path.json cut short by a kill while it was copied is not ours)


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and its parents that do not exist yet, deepest first (what a write into it would create)."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def _temp_sibling(out: Path) -> Path:
    """A new hidden folder ``.NAME.PID.xxxxxxxx`` beside ``out`` (``out``'s parents created), holding
    :data:`_PARTIAL` so that :func:`recover_interrupted` knows it; :class:`InputError` if impossible."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.{os.getpid()}.", dir=out.parent))
        (tmp / _PARTIAL).touch()
        return tmp
    except OSError as exc:
        raise InputError(f"cannot write there ({exc.strerror or exc}); choose another --out", file=out) from None


def _process_gone(pid: int) -> bool:
    """True when no process ``pid`` exists (one we may not signal exists)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:
        return False
    return False


def _temp_name(out: Path):
    """The pattern of :func:`_temp_sibling`'s names for ``out`` (group 1: the process id)."""
    return re.compile(rf"\.{re.escape(out.name)}\.(\d+)\.[A-Za-z0-9_]{{8}}")


def recover_interrupted(out: Path) -> list[str]:
    """Tidy what a senerf-render killed outright (SIGKILL, power loss) left beside ``out``; returns what it did.

    * ``.NAME.old-PID``, the earlier output moved aside for ``--overwrite`` (or a link to one): renamed back to
      ``out`` when the kill came before the new output took its place, removed when it came after (``out`` is
      then whole).
    * ``.NAME.PID.xxxxxxxx``, a temporary folder holding :data:`_PARTIAL` (or, once complete, our
      ``path.json``, or nothing: a fill moved all of it and was killed before it removed the folder): removed; a
      complete one whose files were being moved into the user's folder ``out`` (:func:`_fill`, :func:`_refill`:
      ``out``'s :data:`_FILLING` names it) has the rest moved in first, after the earlier output's files the new
      one lacks are removed.
    * ``out``'s :data:`_FILLING` of a dead render: removed once ``out`` holds its ``path.json`` (with the emptied
      temporary folder); without ``path.json`` and with the temporary folder gone (an interrupt while an in-place
      replacement was undone), the senerf-render files it marks are removed too, leaving ``out`` empty of them.

    Only folders of processes that no longer exist are touched, and only those that senerf-render marked.
    """
    done = []
    parent = out.parent
    if not parent.is_dir():
        return done
    old_name, tmp_name = re.compile(rf"\.{re.escape(out.name)}\.old-(\d+)"), _temp_name(out)
    for entry in sorted(parent.iterdir()):
        old, tmp = old_name.fullmatch(entry.name), tmp_name.fullmatch(entry.name)
        match = old or tmp
        if match is None or not _process_gone(int(match.group(1))):
            continue
        link = entry.is_symlink()
        if old and (link or entry.is_dir()) and _is_ours(entry):   # the earlier output, or a link to it, moved aside
            what = "the link to the earlier output" if link else "the earlier output"
            if out.exists() or out.is_symlink():
                if link:
                    entry.unlink()
                else:
                    shutil.rmtree(entry, ignore_errors=True)
                done.append(f"removed {entry.name}, {what} an interrupted {PROG} had replaced")
            else:
                entry.rename(out)
                done.append(f"restored {out}, {what} an interrupted {PROG} had moved aside")
        elif link or not entry.is_dir():
            continue
        elif tmp and _begun_fill(out, entry):
            expected = _expected_names(_marker(entry))
            if expected is not None:   # frames of an output replaced in place (_refill) that the new one lacks
                _remove_ours(out, keep=expected)
            _fill(out, entry)
            shutil.rmtree(entry, ignore_errors=True)
            done.append(f"finished {out}, which an interrupted {PROG} had begun to fill")
        elif tmp and ((entry / _PARTIAL).is_file() or _is_ours(entry)):
            shutil.rmtree(entry, ignore_errors=True)
            done.append(f"removed {entry.name}, a partial folder an interrupted {PROG} left")
        elif tmp and not any(entry.iterdir()) and _filling_of(out) != entry.name:
            # emptied by a fill that finished (its mark gone) and was killed before it removed the folder; a
            # folder the mark still names is _tidy_filling's
            entry.rmdir()
            done.append(f"removed {entry.name}, an empty folder an interrupted {PROG} left")
    done += _tidy_filling(out, tmp_name)
    return done


def _tidy_filling(out: Path, tmp_name) -> list[str]:
    """The last part of :func:`recover_interrupted`: ``out``'s :data:`_FILLING` left by a dead render (and the
    part of one, ``.senerf-render-filling.PID``, a kill left before its rename)."""
    if out.is_dir() and not out.is_symlink():
        for part in out.iterdir():
            pid = re.fullmatch(rf"{re.escape(_FILLING)}\.(\d+)", part.name)   # (_filling_part's names)
            if pid and part.is_file() and _process_gone(int(pid.group(1))):
                part.unlink(missing_ok=True)
    named = _filling_of(out)
    match = tmp_name.fullmatch(named) if named is not None else None
    if match is None or not _process_gone(int(match.group(1))):
        return []
    tmp = out.parent / named
    if _is_ours(out):   # killed once the output landed, before the mark went
        if tmp.is_dir() and not tmp.is_symlink() and not any(tmp.iterdir()):
            tmp.rmdir()
        (out / _FILLING).unlink(missing_ok=True)
        return []
    if tmp.exists():   # a temporary folder recover_interrupted did not take for ours: leave both alone
        return []
    _remove_ours(out)
    (out / _FILLING).unlink(missing_ok=True)
    return [f"emptied {out} of what an interrupted {PROG} left half replaced (its temporary folder was gone)"]


def _check_memory(intrinsics, renders: int = 1) -> None:
    """Refuse a path whose frames would not fit in this machine's memory (~32 bytes a pixel: the float
    renders and the 8-bit frames are all held until the GIFs are written), rendered ``renders`` times
    (2 with ``--compare``)."""
    need = 32.0 * renders * sum(k.width * k.height for k in intrinsics)
    have = physical_memory_bytes()
    if have is None:   # not a POSIX system: no check
        return
    if need > 0.8 * have:
        k = intrinsics[0]
        twice = " twice (--compare)" if renders == 2 else f" {renders} times" if renders > 2 else ""
        raise InputError(f"{len(intrinsics)} frames at {k.width}x{k.height}{twice} need about "
                         f"{need / 2**30:.1f} GiB of "
                         f"memory, this machine has {have / 2**30:.1f} GiB; use fewer --frames or a smaller --scale",
                         field="--frames")


#: The names senerf-render writes into its folder (write_frames).
_OUR_FILES = re.compile(r"(rgb|depth)_\d{3,}\.png|(rgb|depth|compare)\.gif|path\.json")


def _marker(folder: Path):
    """``folder``'s ``path.json``, parsed; None when it cannot be read or is no JSON."""
    try:
        return json.loads((folder / _MARKER).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None


def _is_ours(folder: Path) -> bool:
    """True when ``folder`` holds a ``path.json`` written by senerf-render."""
    marker = _marker(folder)
    return isinstance(marker, dict) and marker.get("senerf_render") is not None


def _absolute(out: Path) -> Path:
    """``out`` with its folder resolved (links followed, so ``link/..`` is the link target's parent) and its
    own name kept (a link named there stays a link); ``.`` and ``..`` resolved whole."""
    if out.name in ("", ".", ".."):
        return Path(os.path.realpath(out))
    return Path(os.path.realpath(out.parent)) / out.name


def _empty_folder(path: Path) -> bool:
    """True for an empty folder (but for :data:`_IGNORED` files) that is not a symbolic link (:func:`write_frames`
    fills it; a link is refused, with or without ``--overwrite``, unless it leads to an earlier senerf-render
    output)."""
    return path.is_dir() and not path.is_symlink() and all(p.name in _IGNORED for p in path.iterdir())


def _check_out(out: Path, overwrite: bool, command: list | None = None) -> bool:
    """Check ``out`` before rendering (after tidying what a killed render left beside it); InputError when it
    cannot be written.  Returns True when the fill of ``out`` that a killed call of ``command`` (senerf-render's
    argv, as its ``path.json`` records it) had begun was finished now: that call's output is whole (the caller
    checks that the command still means the same run and iteration).  A frames record beside an output of the
    same command is no such sign: it can be that of a later call, killed before its output replaced this one."""
    from senerf.atomic import output_folder

    output_folder(out, "--out")
    finished = False
    try:
        for line in recover_interrupted(out):
            finished = finished or line.startswith("finished ")
            warnings.warn(line, stacklevel=2)
    except OSError:   # an unreadable parent: the write below reports it
        pass
    if command is not None and finished and not out.is_symlink():
        marker = _marker(out)
        if isinstance(marker, dict) and marker.get("senerf_render") is not None and marker.get("command") == command:
            return True
    filling = _filling_of(out)
    if filling is not None:   # recover_interrupted left it: its process lives
        pid = _temp_name(out).fullmatch(filling)
        raise InputError(f"is being filled by another {PROG}" + (f" (process {pid.group(1)})" if pid else "")
                         + f"; wait for it to end, or remove {out / _FILLING} if no render is running", file=out)
    if out.is_symlink() and not _is_ours(out):   # (a link to an earlier output is replaced with --overwrite)
        raise InputError(f"is a symbolic link (to {os.readlink(out)}); senerf-render writes into a folder, not "
                         f"through a link: give the folder itself or another --out", file=out)
    if not out.exists() or _empty_folder(out):   # an empty folder holds nothing to lose
        return False
    if not overwrite:
        raise InputError("exists; use --overwrite (replaces an earlier senerf-render output) or another --out",
                         file=out)
    if not _is_ours(out):
        raise InputError(f"is not a senerf-render output (no {_MARKER} of ours); --overwrite never deletes files "
                         f"it did not make; choose another --out", file=out)
    foreign = sorted(p.name for p in out.iterdir() if not (_OUR_FILES.fullmatch(p.name) or p.name in _IGNORED))
    if foreign:   # --overwrite replaces the whole folder: a file put there since would go with it
        raise InputError(f"holds {foreign[0]}, which senerf-render did not write; --overwrite replaces only its own "
                         f"outputs: move it or choose another --out", file=out)
    return False


def build_parser() -> argparse.ArgumentParser:
    """The ``senerf-render`` argument parser (errors raise :class:`InputError`)."""
    p = OneLineParser(prog=PROG, description="Render a finished senerf-fit run along a camera path.",
                      epilog="Writes into --out (default RUN/render/<path>_iter<K>): rgb_XXX.png, depth_XXX.png, "
                             "rgb.gif, depth.gif (with --compare also compare.gif) and path.json (poses: OpenCV "
                             "camera-to-world, the scene's world frame). Exit status: 0 done, 2 bad input, 130 "
                             "interrupted, 1 internal error.")
    p.add_argument("run", type=Path, help="a senerf-fit output folder (its --out)")
    p.add_argument("--path", choices=PATHS, default=None,
                   help="orbit (default for object scenes), spiral (default for forward-facing scenes) or test "
                        "(the run's test views)")
    p.add_argument("--frames", type=int_flag("--frames", maximum=10000), default=None,
                   help=f"frames of an orbit or spiral (default {FRAMES_DEFAULT})")
    p.add_argument("--fps", type=float_flag("--fps", minimum=0.01, maximum=50.0), default=20.0,
                   help="GIF frame rate, 0.01 to 50 (GIF delays are whole hundredths of a second, at most 655 s; "
                        "default 20)")
    p.add_argument("--iteration", type=int_flag("--iteration", allow_zero=True), default=None,
                   help="which finished iteration's field (default: the last; 0 = the teacher)")
    p.add_argument("--scale", type=float_flag("--scale", positive=True, maximum=64.0), default=1.0,
                   help="render at this multiple of the fitted resolution, at most 64 (default 1)")
    p.add_argument("--elevation", type=float_flag("--elevation", -89.0, maximum=89.0), default=None, metavar="DEG",
                   help="orbit elevation, -89 to 89 (default: the input views' mean)")
    p.add_argument("--compare", action="store_true",
                   help="also write compare.gif: the teacher (iteration 0) beside the rendered iteration")
    p.add_argument("--out", type=Path, help="output folder (default RUN/render/<path>_iter<K>)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier senerf-render output in --out")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--threads", type=threads_flag(), default=None, metavar="N", help=THREADS_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def _run(args, argv: list[str]) -> int:
    device = check_device(args.device)
    set_threads(args.threads)
    if args.elevation is not None and args.path not in (None, "orbit"):
        raise InputError("applies to --path orbit only", field="--elevation")
    command = argv   # what path.json records
    finished = False   # a killed call of this command had begun to fill --out, and that fill was finished now
    if args.out is not None:
        args.out = _absolute(args.out)   # `--out .` has no name to make a sibling of
        finished = _check_out(args.out, args.overwrite, command)   # before loading anything
    run = load_fitted_run(args.run, args.iteration, device)
    warn_planes_path(PROG, run.model, device)
    path = args.path or ("spiral" if run.scene.kind == "forward_facing" else "orbit")
    if args.elevation is not None and path != "orbit":
        raise InputError("applies to --path orbit only", field="--elevation")
    if args.frames is not None and path == "test":
        raise InputError("the test path has one frame per test view; leave --frames out", field="--frames")
    out = args.out
    if out is None:   # a given --out was checked before loading
        out = run.folder / "render" / f"{path}_iter{run.iteration}"
        finished = _check_out(out, args.overwrite, command)
    if finished:
        marker = _marker(out)
        if marker.get("run") == str(run.folder.resolve()) and marker.get("iteration") == run.iteration:
            return _written_before(out)
        _check_out(out, args.overwrite)   # the command now means another run or iteration: an existing output
    c2w, intrinsics = path_cameras(run, path, args.frames or FRAMES_DEFAULT, args.scale, args.elevation)
    teacher = None
    if args.compare:   # before rendering: a missing teacher checkpoint is found now, not after the frames
        if run.iteration == 0:
            raise InputError("compares the teacher (iteration 0) with a self-training iteration; this one is 0",
                             field="--compare")
        teacher = with_iteration(run, 0, device, flag="--compare")
    _check_memory(intrinsics, renders=2 if args.compare else 1)
    created = _missing_folders(out.parent)   # removed again unless the render lands (Ctrl-C, bad input)
    record = frames_record(out)
    path_record = None   # what path.json will hold, once known
    try:
        shutil.rmtree(_temp_sibling(out))   # the folder can be written: found out before rendering, not after
        found = _open_record(record)
        print(f"{PROG}: {run.scene.name}, iteration {run.iteration}{' and the teacher' if teacher else ''}, {path} "
              f"path: {len(c2w)} frames at {intrinsics[0].width}x{intrinsics[0].height}")
        if found:
            print(f"{PROG}: {found} frame{'s' if found > 1 else ''} of an interrupted render found in {record}")
        frames = render_frames(run, c2w, intrinsics, device=device, progress=not args.quiet, resume=record)
        compare, read_back = None, frames["read_back"]
        if teacher is not None:
            first = render_frames(teacher, c2w, intrinsics, device=device, progress=not args.quiet, resume=record,
                                  name="teacher")
            compare = side_by_side(first["rgb"], frames["rgb"], ("teacher", f"iteration {run.iteration}"))
            read_back += first["read_back"]
        if read_back:
            print(f"{PROG}: ({read_back} frame{'s' if read_back > 1 else ''} read back, not rendered again)")
        path_record = dict(senerf_render=__version__, command=command, run=str(run.folder.resolve()),
                           iteration=run.iteration, compared_with=0 if compare is not None else None, path=path,
                           fps=args.fps,
                           convention="OpenCV camera-to-world (x right, y down, z forward), the scene's world "
                           "frame; intrinsics fx, fy, cx, cy, width, height (pixel centres at i + 0.5)",
                           intrinsics=[[k.fx, k.fy, k.cx, k.cy, k.width, k.height] for k in intrinsics],
                           c2w=c2w.tolist())
        try:
            written = write_frames(out, frames, path_record, args.fps, args.overwrite, compare=compare)
        except InputError as exc:   # a full disk, say: the frames stay for the rerun
            raise InputError(f"{exc.problem}; the rendered frames are kept in {record}: rerun the same command to "
                             f"write them", file=exc.file, field=exc.field) from None
        _close_record(record, landed=True)   # its frames are not needed again
        gifs = "rgb.gif, depth.gif and compare.gif" if compare is not None else "rgb.gif and depth.gif"
        print(f"{PROG}: {len(c2w)} frames, {gifs} in {written}")
    except KeyboardInterrupt:   # say where the frames wait (run_command then prints the interrupt line)
        if path_record is not None and _landed(out, path_record):   # the interrupt came after the output landed
            _close_record(record, landed=True)
            print(f"{PROG}: {len(c2w)} frames in {out} (the interrupt came once they were written)")
            return 0
        kept = len([p for p in record.glob("*.npz") if _RECORD_FILES.fullmatch(p.name)]) if record.is_dir() else 0
        if kept:
            print(f"{PROG}: {kept} rendered frame{'s' if kept > 1 else ''} kept in {record}", file=sys.stderr)
        raise
    finally:
        _close_record(record, landed=False)   # interrupted before its first frame: nothing to keep
        if not out.exists():
            for folder in created:   # deepest first; one that holds anything stays
                try:
                    folder.rmdir()
                except OSError:
                    break
    return 0


def _written_before(out: Path) -> int:
    """Finish a call whose output a killed call of the same command had begun to move into place, finished now
    (:func:`_check_out`): remove the frames record that call left; exit status 0."""
    _close_record(frames_record(out), landed=True)
    print(f"{PROG}: {out} holds this command's output, finished from its interrupted call; nothing to render")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``senerf-render``; returns the exit status (0 ok, 2 bad input, 130 interrupted, 1 internal)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    short_openmp_waits()   # as senerf-fit: OpenMP workers spin briefly, then sleep
    return run_command(PROG, lambda: _run(build_parser().parse_args(argv), [PROG, *argv]),
                       "no output written; the frames rendered so far are kept: rerun the same command to resume")


def console() -> None:
    """The ``senerf-render`` console script: :func:`main`, exiting with its status
    (:func:`senerf.cliargs.console_entry`)."""
    from senerf.cliargs import console_entry

    console_entry(main)


if __name__ == "__main__":  # pragma: no cover
    console()
