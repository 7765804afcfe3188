"""``senerf-render``: render a finished ``senerf-fit`` run along a camera path and write PNG frames and GIFs.

Paths (:mod:`senerf.geometry.paths`): ``orbit`` circles the point the input cameras look at, level, at their
mean elevation and distance (the default for object scenes); ``spiral`` is NeRF's spiral in front of a
forward-facing capture, focused by the scene's depth bounds (the default for LLFF scenes); ``test`` renders
the run's test views in order (each with its own intrinsics), the very renders ``senerf-fit`` scored.

The field is the one a finished iteration ended with (``checkpoints/iter_K_train.pt``, loaded with
``weights_only=True``); the scene folder named in ``run.json`` gives the cameras.  Outputs go to a new folder
(default ``RUN/render/<path>_iter<K>``): ``rgb_XXX.png``, ``depth_XXX.png`` (one depth colour range for the
whole path, so the colours do not flicker), ``rgb.gif``, ``depth.gif`` and ``path.json`` (the poses, OpenCV
camera-to-world in the scene's world frame, and the intrinsics).  Nothing is written until every frame is
rendered; the folder appears whole, by one rename.

Exit status: 0 done, 2 bad input (one line ``senerf-render: error: ...`` naming the file or flag), 130
interrupted, 1 internal error.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from senerf import __version__
from senerf.cliargs import OneLineParser, check_device, float_flag, int_flag, run_command
from senerf.errors import InputError

__all__ = ["FittedRun", "load_fitted_run", "path_cameras", "render_frames", "write_frames", "main", "PATHS"]

PROG = "senerf-render"
#: The camera paths ``senerf-render`` draws.
PATHS = ("orbit", "spiral", "test")
_MARKER = "path.json"


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
    """

    folder: Path
    scene: object
    model: object
    field: object
    occupancy: object
    iteration: int
    train_idx: np.ndarray
    test_idx: np.ndarray


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


def _key(record: dict, key: str, path: Path, kind=None):
    if key not in record or (kind is not None and not isinstance(record[key], kind)):
        raise InputError("missing or of the wrong type", file=path, field=key)
    return record[key]


def load_fitted_run(folder, iteration: int | None = None, device: str = "cpu") -> FittedRun:
    """Load a run folder's field after ``iteration`` (default: the last finished one).

    Raises:
        InputError: not a senerf-fit folder, no finished iteration (or not ``iteration``), a missing
            checkpoint, a scene folder that no longer matches the run.
    """
    import torch

    from senerf.data import load_scene
    from senerf.train import ModelConfig, build_field, load_checkpoint, load_state_keeping_box, make_occupancy

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder", file=folder)
    run_path, metrics_path = folder / "run.json", folder / "metrics.json"
    run = _read_json(run_path)
    metrics = _read_json(metrics_path)
    rows = _key(metrics, "iterations", metrics_path, list)
    done = sorted(int(r["iteration"]) for r in rows if isinstance(r, dict) and isinstance(r.get("iteration"), int))
    if not done:
        raise InputError("holds no finished iteration yet; let senerf-fit finish one", file=metrics_path)
    k = done[-1] if iteration is None else int(iteration)
    if k not in done:
        raise InputError(f"iteration {k} is not finished in this run (finished: {done})", field="--iteration")
    try:
        model = ModelConfig(**_key(run, "model", run_path, dict))
    except TypeError as exc:
        raise InputError(f"not a model of this senerf version ({exc})", file=run_path, field="model") from None
    train = _key(run, "train", run_path, dict)
    seed, steps = _key(train, "seed", run_path, int), _key(train, "steps", run_path, int)
    scene_dir = Path(_key(run, "scene_dir", run_path, str))
    downscale = _key(run, "downscale", run_path, (int, float))
    scene = load_scene(scene_dir, downscale=downscale)
    resolution = _key(metrics, "resolution", metrics_path, list)
    if list(scene.size) != [int(v) for v in resolution]:
        raise InputError(f"the scene is {scene.size[0]}x{scene.size[1]} (H x W) at downscale {downscale:g}, the run "
                         f"was fitted at {resolution[0]}x{resolution[1]}", file=scene_dir)
    train_idx = np.asarray(_key(metrics, "train_views", metrics_path, list), dtype=np.int64)
    test_idx = np.asarray(_key(metrics, "test_views", metrics_path, list), dtype=np.int64)
    if max(train_idx.max(initial=-1), test_idx.max(initial=-1)) >= scene.n_images:
        raise InputError(f"names views beyond the scene's {scene.n_images} images", file=metrics_path,
                         field="train_views/test_views")
    ckpt = folder / "checkpoints" / f"iter_{k}_train.pt"
    if not ckpt.is_file():
        raise InputError("missing: the run's checkpoints were removed", file=ckpt)
    state = load_checkpoint(ckpt, map_location="cpu")
    if state.get("format") != "senerf-train-1" or "field" not in state:
        raise InputError("not a senerf training checkpoint", file=ckpt)
    field = build_field(model, seed=seed, steps=steps)
    try:
        load_state_keeping_box(field, state["field"])
    except RuntimeError as exc:
        raise InputError(f"does not fit the run's model ({str(exc).splitlines()[0]})", file=ckpt) from None
    if hasattr(field, "set_progress"):
        field.set_progress(steps)   # all frequencies on, as at the end of training
    occupancy = make_occupancy(model, "cpu")
    if occupancy is not None and "occupancy" in state:
        load_state_keeping_box(occupancy, state["occupancy"])
    field = field.to(torch.device(device)).eval()
    occupancy = None if occupancy is None else occupancy.to(torch.device(device))
    return FittedRun(folder, scene, model, field, occupancy, k, train_idx, test_idx)


def path_cameras(run: FittedRun, path: str, frames: int, scale: float = 1.0, elevation: float | None = None):
    """Cameras of a path: ``(c2w (n, 4, 4) float64, intrinsics: a tuple of n)``.

    ``orbit`` and ``spiral`` use the first input view's intrinsics, scaled by ``scale``; ``test`` the test
    views' own (``frames`` is ignored).  ``elevation`` (degrees) overrides the orbit's.
    """
    from senerf.geometry import orbit_path, spiral_focus_depth, spiral_path

    scene = run.scene
    if path == "test":
        idx = run.test_idx
        return scene.c2w[idx], tuple(_scaled(scene.intrinsics_all[int(i)], scale) for i in idx)
    inputs = scene.c2w[run.train_idx]
    k = _scaled(scene.intrinsics_all[int(run.train_idx[0])], scale)
    if path == "orbit":
        try:
            c2w = orbit_path(inputs, frames, elevation=elevation)
        except ValueError:   # the inputs look along parallel axes: orbit what all the scene's cameras look at
            try:
                c2w = orbit_path(inputs, frames, center=_common_point(scene), elevation=elevation)
            except ValueError as exc:
                raise InputError(f"no orbit for this scene ({exc}); use --path spiral", field="--path") from None
    elif path == "spiral":
        near, far = scene.near, scene.far
        if near is None or far is None:   # object scenes: focus on the point the inputs look at
            focus = float(np.linalg.norm(_common_point(scene) - inputs[:, :3, 3].mean(axis=0)))
        else:
            focus = spiral_focus_depth(near, far)
        c2w = spiral_path(inputs, frames, focus_depth=focus)
    else:
        raise InputError(f"expected one of {', '.join(PATHS)}, got {path!r}", field="--path")
    return np.asarray(c2w, dtype=np.float64), (k,) * int(frames)


def _common_point(scene) -> np.ndarray:
    from senerf.geometry import closest_point_to_axes

    try:
        return closest_point_to_axes(scene.c2w)
    except ValueError as exc:
        raise InputError(f"the scene's cameras look along parallel axes ({exc})", field="--path") from None


def _scaled(k, scale: float):
    try:
        return k if scale == 1.0 else k.scaled(scale)
    except ValueError:
        raise InputError(f"{k.width}x{k.height} times {scale:g} is not a whole number of pixels",
                         field="--scale") from None


def render_frames(run: FittedRun, c2w: np.ndarray, intrinsics, device=None, progress: bool = True) -> dict:
    """Render the path: ``rgb (n, H, W, 3)`` uint8, ``depth (n, H, W, 3)`` uint8 colour-mapped over one
    depth range for all frames (1st-99th percentile of the opaque pixels), ``z_depth``/``acc (n, H, W)``."""
    from senerf.train import depth_to_color, render_views

    out = render_views(run.field, run.model, intrinsics, c2w, occupancy=run.occupancy, device=device,
                       progress=progress)
    rgb = np.clip(np.round(np.clip(out["rgb"], 0.0, 1.0).astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    opaque = out["z_depth"][(out["acc"] > 0.5) & np.isfinite(out["z_depth"])]
    lo, hi = (np.percentile(opaque, [1.0, 99.0]) if opaque.size else (None, None))
    bg = 1.0 if run.model.eval_background == "white" else 0.0
    depth = np.stack([depth_to_color(z, a, lo=lo, hi=hi, background=bg) for z, a in zip(out["z_depth"], out["acc"])])
    return dict(rgb=rgb, depth=depth, z_depth=out["z_depth"], acc=out["acc"])


def write_frames(out: Path, frames: dict, record: dict, fps: float, overwrite: bool = False) -> Path:
    """Write the frames, the two GIFs and ``path.json`` into a temporary sibling of ``out``, then rename it
    to ``out``.  An existing ``out`` is replaced only with ``overwrite`` and only when it is a senerf-render
    folder (it holds ``path.json`` written by this command)."""
    import imageio.v3 as iio

    from senerf.train import write_png

    out = Path(out)
    _check_out(out, overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        for i, (rgb, depth) in enumerate(zip(frames["rgb"], frames["depth"])):
            write_png(tmp / f"rgb_{i:03d}.png", rgb)
            write_png(tmp / f"depth_{i:03d}.png", depth)
        duration = 1000.0 / fps
        for name in ("rgb", "depth"):
            iio.imwrite(tmp / f"{name}.gif", frames[name], extension=".gif", duration=duration, loop=0)
        (tmp / _MARKER).write_text(json.dumps(record, indent=1))
        os.chmod(tmp, 0o755)
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            out.rename(old)
            tmp.rename(out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return out


def _check_out(out: Path, overwrite: bool) -> None:
    from senerf.atomic import output_folder

    output_folder(out, "--out")
    if not out.exists():
        return
    if not overwrite:
        raise InputError("exists; use --overwrite (replaces an earlier senerf-render output) or another --out",
                         file=out)
    marker = out / _MARKER
    try:
        ours = json.loads(marker.read_text()).get("senerf_render") is not None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        ours = False
    if not ours:
        raise InputError(f"is not a senerf-render output (no {_MARKER} of ours); --overwrite never deletes files "
                         f"it did not make; choose another --out", file=out)


def build_parser() -> argparse.ArgumentParser:
    """The ``senerf-render`` argument parser (errors raise :class:`InputError`)."""
    p = OneLineParser(prog=PROG, description="Render a finished senerf-fit run along a camera path.",
                      epilog="Writes into --out (default RUN/render/<path>_iter<K>): rgb_XXX.png, depth_XXX.png, "
                             "rgb.gif, depth.gif and path.json (poses: OpenCV camera-to-world, the scene's "
                             "world frame). Exit status: 0 done, 2 bad input, 130 interrupted, 1 internal error.")
    p.add_argument("run", type=Path, help="a senerf-fit output folder (its --out)")
    p.add_argument("--path", choices=PATHS, default=None,
                   help="orbit (default for object scenes), spiral (default for forward-facing scenes) or test "
                        "(the run's test views)")
    p.add_argument("--frames", type=int_flag("--frames", maximum=10000), default=60, help="frames (default 60)")
    p.add_argument("--fps", type=float_flag("--fps", positive=True, maximum=100.0), default=20.0,
                   help="GIF frame rate (default 20)")
    p.add_argument("--iteration", type=int_flag("--iteration", allow_zero=True), default=None,
                   help="which finished iteration's field (default: the last; 0 = the teacher)")
    p.add_argument("--scale", type=float_flag("--scale", positive=True), default=1.0,
                   help="render at this multiple of the fitted resolution (default 1)")
    p.add_argument("--elevation", type=float_flag("--elevation", -90.0, maximum=90.0), default=None, metavar="DEG",
                   help="orbit elevation (default: the input views' mean)")
    p.add_argument("--out", type=Path, help="output folder (default RUN/render/<path>_iter<K>)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier senerf-render output in --out")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def _run(args, argv: list[str]) -> int:
    device = check_device(args.device)
    if args.elevation is not None and args.path not in (None, "orbit"):
        raise InputError("applies to --path orbit only", field="--elevation")
    if not Path(args.run).is_dir():
        raise InputError("not a folder", file=args.run)
    if args.out is not None:
        _check_out(args.out, args.overwrite)   # before loading anything
    run = load_fitted_run(args.run, args.iteration, device)
    path = args.path or ("spiral" if run.scene.kind == "forward_facing" else "orbit")
    if args.elevation is not None and path != "orbit":
        raise InputError("applies to --path orbit only", field="--elevation")
    out = args.out if args.out is not None else run.folder / "render" / f"{path}_iter{run.iteration}"
    _check_out(out, args.overwrite)
    c2w, intrinsics = path_cameras(run, path, args.frames, args.scale, args.elevation)
    print(f"{PROG}: {run.scene.name}, iteration {run.iteration}, {path} path: {len(c2w)} frames at "
          f"{intrinsics[0].width}x{intrinsics[0].height}")
    frames = render_frames(run, c2w, intrinsics, device=device, progress=not args.quiet)
    record = dict(senerf_render=__version__, command=argv, run=str(run.folder.resolve()), iteration=run.iteration,
                  path=path, fps=args.fps, convention="OpenCV camera-to-world (x right, y down, z forward), the "
                  "scene's world frame; intrinsics fx, fy, cx, cy, width, height (pixel centres at i + 0.5)",
                  intrinsics=[[k.fx, k.fy, k.cx, k.cy, k.width, k.height] for k in intrinsics],
                  c2w=c2w.tolist())
    written = write_frames(out, frames, record, args.fps, args.overwrite)
    print(f"{PROG}: {len(c2w)} frames, rgb.gif and depth.gif in {written}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``senerf-render``; returns the exit status (0 ok, 2 bad input, 130 interrupted, 1 internal)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")   # as senerf-fit (sleeping OpenMP waits on shared cores)
    return run_command(PROG, lambda: _run(build_parser().parse_args(argv), [PROG, *argv]), "nothing was written")

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
