"""``senerf-render``: render a finished ``senerf-fit`` run along a camera path (an orbit, a spiral, the test views or
a saved camera path file) and write H.264 mp4 videos, GIFs or PNG frames (the output files are listed in
:func:`build_parser`'s epilog; the exit statuses are :func:`senerf.cliargs.run_command`'s).

Convention: poses are OpenCV camera-to-world in the scene's world frame.  The output is written into a hidden
sibling of ``--out``, ``.<name>.partial``, and renamed into place once whole, so ``--out`` holds a whole output or
none; the next render into the same ``--out`` removes what a killed one left there.  Two renders into one ``--out``
at once are not supported.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from senerf import __version__
from senerf.cliargs import (THREADS_HELP, OneLineParser, check_device, command_main, console_entry, float_flag,
                            int_flag, set_threads, threads_flag)
from senerf.errors import InputError
from senerf.memory import physical_memory_bytes
from senerf.fitted import FittedRun, load_run, with_iteration

__all__ = ["path_cameras", "render_frames", "side_by_side", "write_mp4",
           "write_output", "main", "console", "PATHS", "FORMATS"]

PROG = "senerf-render"
#: The camera paths ``senerf-render`` draws.
PATHS = ("orbit", "spiral", "test")
#: The output formats of ``senerf-render --format`` (the first is the default).
FORMATS = ("mp4", "gif", "png")
#: Frames of an orbit or spiral when ``--frames`` is not given.
FRAMES_DEFAULT = 60
#: Frame rate when neither ``--fps`` nor a camera path file gives one.
FPS_DEFAULT = 20.0
_RECORD = "path.json"


def path_cameras(run: FittedRun, path: str, frames: int, scale: float = 1.0, elevation: float | None = None):
    """Cameras of a path: ``(c2w (n, 4, 4) float64, intrinsics: a tuple of n)``.

    ``orbit`` (the default for object scenes) circles the point the input (training) cameras look at, level, at
    their mean elevation (or ``elevation``, degrees) and distance; ``spiral`` (the default for forward-facing
    scenes) is NeRF's spiral in front of them, looking at the depth NeRF's LLFF code picks from the scene's near
    and far bounds (:func:`senerf.geometry.spiral_focus_depth`), or, without bounds (an object), at the point the
    cameras look at.  Both use the first input's intrinsics, scaled by ``scale``.  ``test`` takes the run's test
    views with their own intrinsics (``frames`` is ignored): the cameras ``senerf-fit`` scored.

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
    if path == "orbit":
        if getattr(run.model, "ndc", False):
            raise InputError("an orbit goes behind a forward-facing (NDC) capture, where nothing was fitted; use "
                             "--path spiral or test", field="--path")
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


def render_frames(run: FittedRun, c2w: np.ndarray, intrinsics, device=None, progress: bool = True) -> dict:
    """Render the path: ``rgb (n, H, W, 3)`` uint8, ``depth (n, H, W, 3)`` uint8 colour-mapped over one
    depth range for all frames (1st-99th percentile of the opaque pixels), ``z_depth``/``acc (n, H, W)``.

    Args:
        run: the field to render (``field``, ``occupancy``, ``model``).
        c2w: ``(n, 4, 4)`` OpenCV camera-to-world poses.
        intrinsics: one :class:`senerf.geometry.Intrinsics` for all frames, or one per frame.
        device, progress: as :func:`senerf.train.render_views`, which renders them, so the ``test`` path
            reproduces ``senerf-fit``'s test renders.
    """
    from senerf.train import depth_to_color, render_views
    from senerf.train.evaluate import to_uint8

    out = render_views(run.field, run.model, intrinsics, c2w, occupancy=run.occupancy, device=device,
                       progress=progress)
    z_depth, acc = out["z_depth"], out["acc"]
    opaque = z_depth[(acc > 0.5) & np.isfinite(z_depth)]
    lo, hi = (np.percentile(opaque, [1.0, 99.0]) if opaque.size else (None, None))
    bg = 1.0 if run.model.eval_background == "white" else 0.0
    depth = np.stack([depth_to_color(z, a, lo=lo, hi=hi, background=bg) for z, a in zip(z_depth, acc)])
    return dict(rgb=to_uint8(out["rgb"]), depth=depth, z_depth=z_depth, acc=acc)


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


def _is_output(folder: Path) -> bool:
    """True when ``folder`` holds a ``path.json`` written by senerf-render (an output ``--overwrite`` replaces)."""
    try:
        record = json.loads((folder / _RECORD).read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(record, dict) and "senerf_render" in record


def _check_out(out: Path, overwrite: bool) -> None:
    """:func:`senerf.atomic.replaceable_folder` for ``--out`` (an earlier senerf-render output may be replaced)."""
    from senerf.atomic import partial_folder, replaceable_folder

    if replaceable_folder(out, "--out", overwrite, _is_output, "a senerf-render output"):
        print(f"{PROG}: removed {partial_folder(out)}, left by an interrupted render")


def write_mp4(path: Path, frames: np.ndarray, fps: float) -> None:
    """Write ``frames (n, H, W, 3)`` uint8 as an H.264 (libx264) yuv420p mp4, the video every player and browser
    plays, through the ffmpeg that imageio-ffmpeg's wheel bundles.  yuv420p needs an even width and height: an odd
    one gets its last row or column repeated (padding loses no rendered pixel, as cropping would, and resamples
    none, as scaling would).  Constant quality CRF 18 (visually lossless for x264).

    Raises:
        OSError: ffmpeg failed (its last line of errors), so no broken file passes for a whole one.
    """
    import subprocess

    import imageio_ffmpeg

    h, w = frames.shape[1:3]
    if h % 2 or w % 2:
        frames = np.pad(frames, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
           "-s", f"{w + w % 2}x{h + h % 2}", "-r", repr(float(fps)), "-i", "-", "-an", "-c:v", "libx264",
           "-pix_fmt", "yuv420p", "-crf", "18", "-movflags", "+faststart", str(path)]
    done = subprocess.run(cmd, input=memoryview(np.ascontiguousarray(frames).reshape(-1)), capture_output=True)
    if done.returncode != 0:   # (subprocess.run kills ffmpeg on an interrupt)
        lines = done.stderr.decode(errors="replace").strip().splitlines() or [f"exit status {done.returncode}"]
        raise OSError(f"ffmpeg: {lines[-1]}")


def write_output(out: Path, frames: dict, record: dict, fps: float, overwrite: bool = False,
                 compare: np.ndarray | None = None, fmt: str = "mp4") -> Path:
    """Write the frames in ``fmt`` (``rgb`` and ``depth``, and ``compare`` when given: ``rgb.mp4``... for mp4,
    ``rgb.gif``... for gif, ``rgb_000.png``... for png) and ``path.json`` (``record``) into ``out``, whole or not at
    all (module Convention).  With ``overwrite`` an earlier output there is first moved into the partial folder
    (back, if the new one cannot take its place), and goes with it.

    Args:
        frames: ``rgb`` and ``depth`` ``(n, H, W, 3)`` uint8 (:func:`render_frames`).
        compare: ``(n, H', W', 3)`` uint8 (:func:`side_by_side`), or ``None``.
        fps: the frame rate of the videos and GIFs.

    Raises:
        InputError: ``out`` is taken, or a write or rename failed (a full disk, a mount point), naming ``out``.
    """
    import imageio.v3 as iio

    from senerf.atomic import replace_folder
    from senerf.train import write_png

    out = Path(out)
    _check_out(out, overwrite)

    def fill(new: Path) -> None:
        stacks = dict(rgb=frames["rgb"], depth=frames["depth"], **({} if compare is None else dict(compare=compare)))
        for name, stack in stacks.items():
            if fmt == "png":
                for i, image in enumerate(stack):
                    write_png(new / f"{name}_{i:03d}.png", image)
            elif fmt == "gif":
                iio.imwrite(new / f"{name}.gif", stack, extension=".gif", duration=1000.0 / fps, loop=0)
            else:
                write_mp4(new / f"{name}.mp4", stack, fps)
        (new / _RECORD).write_text(json.dumps(record, indent=1))

    return replace_folder(out, fill)


def _check_memory(intrinsics, renders: int) -> None:
    """Refuse a path whose frames would not fit in this machine's memory: ~32 bytes a pixel (the float renders and
    the 8-bit frames are all held until the files are written), ``renders`` times (2 with ``--compare``)."""
    need, have = 32.0 * renders * sum(k.width * k.height for k in intrinsics), physical_memory_bytes()
    if have is not None and need > 0.8 * have:   # (None: not a POSIX system, no check)
        k, twice = intrinsics[0], " twice (--compare)" if renders == 2 else ""
        raise InputError(f"{len(intrinsics)} frames at {k.width}x{k.height}{twice} need about {need / 2**30:.1f} GiB "
                         f"of memory, this machine has {have / 2**30:.1f} GiB; use fewer --frames or a smaller --scale",
                         field="--frames")


def build_parser() -> argparse.ArgumentParser:
    """The ``senerf-render`` argument parser (errors raise :class:`InputError`)."""
    p = OneLineParser(prog=PROG, description="Render a finished senerf-fit run along a camera path.",
                      epilog="Writes into --out (default RUN/render/<path>_iter<K>): with --format mp4 rgb.mp4 and "
                             "depth.mp4 (H.264, yuv420p; an odd width or height gets its last column or row "
                             "repeated), with gif rgb.gif and depth.gif, with png rgb_XXX.png and depth_XXX.png (with "
                             "--compare also compare.mp4, .gif or _XXX.png), and always path.json (the frames' poses: "
                             "OpenCV camera-to-world, the scene's world frame). Exit status: 0 done, 2 bad input, 130 "
                             "interrupted, 1 internal error.")
    p.add_argument("run", type=Path, help="a senerf-fit output folder (its --out)")
    p.add_argument("--path", default=None, metavar="{orbit,spiral,test} or FILE",
                   help="orbit (default for object and unbounded scenes), spiral (default for forward-facing scenes), "
                        "test (the run's test views) or a camera path file to replay (senerf-view's keyframes or "
                        "nerfstudio's camera_path.json; rendered at its image size times --scale)")
    p.add_argument("--frames", type=int_flag("--frames", maximum=10000), default=None,
                   help=f"frames of an orbit or spiral (default {FRAMES_DEFAULT}) or of a camera path file (default: "
                        "the file's)")
    p.add_argument("--format", choices=FORMATS, default=FORMATS[0],
                   help="mp4 (default: rgb.mp4 and depth.mp4), gif or png (the frames)")
    p.add_argument("--fps", type=float_flag("--fps", minimum=0.01, maximum=240.0), default=None,
                   help="frame rate, 0.01 to 240, of a GIF at most 50 (its delays are whole hundredths of a second, "
                        "at most 655 s; default: a camera path file's, else 20)")
    p.add_argument("--iteration", type=int_flag("--iteration", allow_zero=True), default=None,
                   help="which finished iteration's field (default: the last; 0 = the teacher)")
    p.add_argument("--scale", type=float_flag("--scale", positive=True, maximum=64.0), default=1.0,
                   help="render at this multiple of the fitted resolution, at most 64 (default 1)")
    p.add_argument("--elevation", type=float_flag("--elevation", -89.0, maximum=89.0), default=None, metavar="DEG",
                   help="orbit elevation, -89 to 89 (default: the input views' mean)")
    p.add_argument("--compare", action="store_true",
                   help="also write compare.mp4 (.gif, _XXX.png): the teacher (iteration 0) beside the rendered "
                        "iteration")
    p.add_argument("--out", type=Path, help="output folder (default RUN/render/<path>_iter<K>)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier senerf-render output in --out")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--threads", type=threads_flag(), default=None, metavar="N", help=THREADS_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def _run(args) -> int:
    device = check_device(args.device)
    set_threads(args.threads)
    if args.out is not None:   # before loading anything
        args.out = Path(os.path.abspath(args.out))   # `--out .` has a name then
        _check_out(args.out, args.overwrite)
    replay = None
    if args.path is not None and args.path not in PATHS:   # a camera path file, read before the run is loaded
        from senerf.camerapath import read_camera_path

        if not os.path.exists(args.path):
            raise InputError(f"{args.path!r} is neither {', '.join(PATHS)} nor a camera path file (not found)",
                             field="--path")
        replay = read_camera_path(args.path, frames=args.frames)
    fps = args.fps or (replay.fps if replay else FPS_DEFAULT)
    if args.format == "gif" and fps > 50.0:
        whose = "" if args.fps else " (the camera path file's)"
        raise InputError(f"a GIF plays at most 50 frames a second, got {fps:g}{whose}; use --format mp4", field="--fps")
    run = load_run(args.run, args.iteration, device)
    from senerf.fields.ckernel import warn_without_kernel

    warn_without_kernel(run.model, device)
    path = args.path or ("spiral" if run.scene.kind == "forward_facing" else "orbit")
    if args.elevation is not None and path != "orbit":
        raise InputError("applies to --path orbit only", field="--elevation")
    name = Path(path).stem if replay else path
    if args.frames is not None and path == "test":
        raise InputError("the test path has one frame per test view; leave --frames out", field="--frames")
    out = args.out
    if out is None:
        out = Path(os.path.abspath(run.folder)) / "render" / f"{name}_iter{run.iteration}"
        _check_out(out, args.overwrite)
    if replay:
        c2w, intrinsics = replay.c2w, tuple(_scaled(k, args.scale) for k in replay.intrinsics)
        path = os.path.abspath(path)
    else:
        c2w, intrinsics = path_cameras(run, path, args.frames or FRAMES_DEFAULT, args.scale, args.elevation)
    teacher = None
    if args.compare:   # before rendering: a missing teacher checkpoint is found now, not after the frames
        if run.iteration == 0:
            raise InputError("compares the teacher (iteration 0) with a self-training iteration; this one is 0",
                             field="--compare")
        teacher = with_iteration(run, 0, device, flag="--compare")
    _check_memory(intrinsics, renders=2 if teacher is not None else 1)
    print(f"{PROG}: {run.scene.name}, iteration {run.iteration}{' and the teacher' if teacher else ''}, {name} "
          f"path: {len(c2w)} frames at {intrinsics[0].width}x{intrinsics[0].height}")
    frames = render_frames(run, c2w, intrinsics, device=device, progress=not args.quiet)
    compare = None
    if teacher is not None:
        first = render_frames(teacher, c2w, intrinsics, device=device, progress=not args.quiet)
        compare = side_by_side(first["rgb"], frames["rgb"], ("teacher", f"iteration {run.iteration}"))
    record = dict(senerf_render=__version__, run=os.path.abspath(run.folder), iteration=run.iteration,
                  compared_with=0 if compare is not None else None, path=path, format=args.format, fps=fps,
                  convention="OpenCV camera-to-world (x right, y down, z forward), the scene's world frame; "
                             "intrinsics fx, fy, cx, cy, width, height (pixel centres at i + 0.5)",
                  intrinsics=[[k.fx, k.fy, k.cx, k.cy, k.width, k.height] for k in intrinsics], c2w=c2w.tolist())
    write_output(out, frames, record, fps, args.overwrite, compare=compare, fmt=args.format)
    names = ["rgb", "depth", *(["compare"] if compare is not None else [])]
    files = [f"{n}_XXX.png" if args.format == "png" else f"{n}.{args.format}" for n in names]
    print(f"{PROG}: {len(c2w)} frames, {', '.join(files[:-1])} and {files[-1]} in {out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``senerf-render``; returns the exit status (0 ok, 2 bad input, 130 interrupted, 1 internal)."""
    return command_main(PROG, lambda a: _run(build_parser().parse_args(a)), argv, "no output written")


def console() -> None:
    """The ``senerf-render`` console script: :func:`main` through :func:`senerf.cliargs.console_entry`."""
    console_entry(main)


if __name__ == "__main__":  # pragma: no cover
    console()
