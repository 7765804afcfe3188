"""``senerf-export``: a finished ``senerf-fit`` run as a coloured mesh, a fused point cloud and 16-bit depth maps.

* ``--mesh FILE`` (``.ply``, ``.obj`` or ``.glb``, written by trimesh): marching cubes (scikit-image) on the
  density sampled on a grid over the fitted box (an unbounded fit's inner, uncontracted box; a forward-facing NDC
  fit is refused: its box is in NDC, and a world mesh of its frustum would be mostly the far plane's haze).
  Vertex colours are the field's colour at the vertex seen along the inward normal.
* ``--points FILE`` (``.ply``): every pixel with opacity above 0.5 of the rendered training views and of the pseudo
  views the loaded field labels next (the next iteration's, :meth:`senerf.fitted.FittedRun.pseudo_cameras`),
  lifted with its rendered depth and kept when another view agrees: the warp's forward-backward test
  (:func:`senerf.geometry.reproject`) finds that view's rendered depth where the point lands, and its pixel back.
* ``--depth DIR``: ``depth_XXX.png`` 16-bit z-depth per view and ``depth_scale.json``: ``z = value * scale`` in
  the scene's units (camera z, OpenCV), ``0`` = no surface (opacity <= 0.5), with each view's camera.

Every output is written into a temporary sibling and renamed into place, so it is whole or absent.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from senerf import __version__
from senerf.cliargs import (THREADS_HELP, OneLineParser, check_device, command_main, console_entry, float_flag,
                            int_flag, set_threads, threads_flag)
from senerf.atomic import replace_folder
from senerf.errors import InputError

__all__ = ["mesh_region", "default_level", "density_grid", "grid_mesh", "colour_mesh", "fused_points",
           "depth_png", "write_depth_maps", "main", "console", "RESOLUTION", "OPACITY"]

PROG = "senerf-export"
#: Default marching-cubes grid side (BENCHMARKS.md: the procedural scene's Chamfer distance and export time).
RESOLUTION = 256
#: Pixels with rendered opacity above this have a surface (points, depth maps).
OPACITY = 0.5
_MESH_TYPES, _SCALE_FILE = (".ply", ".obj", ".glb"), "depth_scale.json"


def mesh_region(model) -> tuple[np.ndarray, np.ndarray]:
    """The world box ``(lo (3,), hi (3,))`` a mesh is extracted in: the fitted box (an unbounded fit's inner one).

    Raises:
        InputError: a forward-facing (NDC) fit, naming ``--mesh``.
    """
    if model.ndc:
        raise InputError("a forward-facing (NDC) fit has no world box to mesh; use --points or --depth",
                         field="--mesh")
    lo, hi = (np.asarray(a, dtype=np.float64) for a in model.aabb)
    return lo, hi


def default_level(model) -> float:
    """The density at which one sample interval of the renderer is half opaque, ``ln 2 / delta``, with
    ``delta`` = the box's mean side / ``n_samples`` (a ray across the box): the surface the renders show."""
    lo, hi = mesh_region(model)
    return math.log(2.0) * model.n_samples / float(np.mean(hi - lo))


def density_grid(density, lo, hi, resolution: int, chunk: int = 1 << 18, progress: bool = False) -> np.ndarray:
    """``density (..., 3) -> (...)`` sampled at the ``resolution ** 3`` nodes of a grid spanning ``[lo, hi]``
    (corners included), queried in slabs of about ``chunk`` points to bound memory: ``(N, N, N)`` float32
    indexed ``[x, y, z]``."""
    n = int(resolution)
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi)]
    out = np.empty((n, n, n), np.float32)
    yz = np.stack(np.meshgrid(axes[1], axes[2], indexing="ij"), axis=-1)   # (N, N, 2)
    step = max(1, chunk // (n * n))
    for s in tqdm(range(0, n, step), desc="density grid", unit="slab", disable=not progress):
        xs = axes[0][s:s + step]
        pts = np.concatenate([np.broadcast_to(xs[:, None, None, None], (len(xs), n, n, 1)),
                              np.broadcast_to(yz, (len(xs), n, n, 2))], axis=-1)
        out[s:s + step] = density(pts)
    return out


def grid_mesh(grid: np.ndarray, lo, hi, level: float, components: str = "all"):
    """Marching cubes on ``grid (N, N, N)`` (:func:`density_grid`) at ``level``: a ``trimesh.Trimesh`` in world
    units, faces wound and vertex normals pointing outwards (down the density), all its connected components or
    the ``'largest'`` (most faces).

    Raises:
        InputError: the level does not cross the grid (no surface), naming ``--level``.
    """
    import trimesh
    from skimage.measure import marching_cubes

    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if not grid.min() < level < grid.max():
        raise InputError(f"the density ({grid.min():.3g} to {grid.max():.3g} in the box) never crosses {level:g}; "
                         "give a --level between those", field="--level")
    spacing = (hi - lo) / (np.asarray(grid.shape) - 1)
    verts, faces, normals, _ = marching_cubes(grid, level, spacing=tuple(spacing))
    mesh = trimesh.Trimesh(verts + lo, faces[:, ::-1], vertex_normals=normals, process=False)
    if components == "largest":
        parts = mesh.split(only_watertight=False)
        mesh = max(parts, key=lambda m: len(m.faces)) if len(parts) else mesh
    return mesh


def colour_mesh(run, mesh) -> None:
    """Set ``mesh``'s vertex colours (uint8 RGBA) to the field's colour at each vertex seen along its inward
    normal, the direction a camera in front of the surface looks at it."""
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    rgb = run.color(np.asarray(mesh.vertices), -normals)
    mesh.visual.vertex_colors = rgb   # trimesh rounds [0, 1] floats to uint8 RGBA


def _render(run, c2w, intrinsics, progress: bool, desc: str) -> list:
    """One :meth:`FittedRun.render` per camera (their intrinsics may differ in size): a list of dicts of
    ``rgb (H, W, 3)``, ``z_depth (H, W)`` (0 where the opacity is <= :data:`OPACITY`)."""
    out = []
    for i in tqdm(range(len(c2w)), desc=desc, unit="view", disable=not progress):
        r = run.render(c2w[i], intrinsics[i])
        out.append(dict(rgb=r["rgb"][0], z_depth=np.where(r["acc"][0] > OPACITY, r["z_depth"][0], 0.0)))
    return out


def fused_points(c2w, intrinsics, renders, rel_tol: float = 0.01):
    """The pixels of ``renders`` (:func:`_render`'s, of cameras ``c2w (n, 4, 4)`` with ``intrinsics`` (n,)) that
    have a surface, lifted to the world where another view's depth agrees (:func:`senerf.geometry.reproject`'s
    forward-backward test: it lands within a pixel of itself and within ``rel_tol`` of its depth).

    Returns:
        ``xyz (P, 3)`` float64 world points and ``rgb (P, 3)`` float32 colours.
    """
    from senerf.geometry import pixel_centers, reproject, unproject

    xyz, rgb = [], []
    for i, (k, r) in enumerate(zip(intrinsics, renders)):
        z = r["z_depth"].astype(np.float64)
        agree = np.zeros(z.shape, bool)
        for kd in set(intrinsics[j] for j in range(len(c2w)) if j != i):   # one batched warp per camera model
            others = [j for j in range(len(c2w)) if j != i and intrinsics[j] == kd]
            _, ok = reproject(z, k, c2w[i], kd, c2w[others], z_depth_dst=np.stack([renders[j]["z_depth"]
                              for j in others]), forward_backward=True, fb_rel_tol=rel_tol)
            agree |= np.asarray(ok).any(axis=0)
        keep = agree & (z > 0)
        xyz.append(unproject(pixel_centers(k)[keep], z[keep], k, c2w[i]))
        rgb.append(r["rgb"][keep])
    return np.concatenate(xyz), np.concatenate(rgb).astype(np.float32)


def depth_png(z_depth: np.ndarray, scale: float) -> np.ndarray:
    """``z_depth (H, W)`` as uint16 ``round(z / scale)`` (clipped to 65535); no surface (``z <= 0``) is 0."""
    q = np.clip(np.round(np.asarray(z_depth, np.float64) / scale), 0, 65535)
    return np.where(np.asarray(z_depth) > 0, np.maximum(q, 1), 0).astype(np.uint16)


def write_depth_maps(folder: Path, renders: list, views, c2w, intrinsics, record: dict) -> None:
    """Write ``depth_XXX.png`` (:func:`depth_png`) and ``depth_scale.json`` (one scale for all: the farthest
    depth maps to 65535) into ``folder`` (a new, empty folder)."""
    import imageio.v3 as iio

    far = max([float(r["z_depth"].max()) for r in renders] + [1e-12])
    scale = far / 65535.0
    files = []
    for i, r in enumerate(renders):
        files.append(f"depth_{i:03d}.png")
        iio.imwrite(folder / files[-1], depth_png(r["z_depth"], scale))
    record = dict(record, scale=scale, meaning="z = value * scale: camera z (OpenCV), the scene's units; 0 = no "
                  f"surface (rendered opacity <= {OPACITY})", views=[
                      dict(file=f, view=int(v), c2w=np.asarray(p).tolist(), intrinsics=[k.fx, k.fy, k.cx, k.cy,
                           k.width, k.height]) for f, v, p, k in zip(files, views, c2w, intrinsics)])
    (folder / _SCALE_FILE).write_text(json.dumps(record, indent=1))


def _check_file(path: Path | None, flag: str, types: tuple, overwrite: bool) -> None:
    """Refuse (naming ``flag``) an output file of another type, a folder, or an existing one without
    ``overwrite``, and one whose folder cannot be created."""
    from senerf.atomic import output_folder

    if path is None:
        return
    if path.suffix.lower() not in types:
        raise InputError(f"expected a file ending in {', '.join(types)}", file=path, field=flag)
    if path.is_dir():
        raise InputError(f"is a folder; {flag} takes a file", file=path)
    if os.path.lexists(path) and not overwrite:
        raise InputError(f"exists; use --overwrite or another {flag}", file=path)
    output_folder(path.parent, flag)


def _check_dir(path: Path | None, overwrite: bool) -> None:
    """:func:`senerf.atomic.replaceable_folder` for ``--depth`` (an earlier depth export may be replaced)."""
    from senerf.atomic import replaceable_folder

    if path is not None:
        replaceable_folder(path, "--depth", overwrite, lambda p: (p / _SCALE_FILE).is_file(),
                           "a senerf-export depth output")


def _write_file(path: Path, geometry) -> None:
    """Export a trimesh ``geometry`` to ``path`` (type from its suffix), atomically."""
    from senerf.atomic import atomic_write

    atomic_write(path, lambda fh: geometry.export(file_obj=fh, file_type=path.suffix.lower()[1:]))


def build_parser() -> OneLineParser:
    """The ``senerf-export`` argument parser (errors raise :class:`InputError`)."""
    p = OneLineParser(prog=PROG, description="Export a finished senerf-fit run as a mesh, a point cloud or depth "
                      "maps (poses and points in the scene's world frame, OpenCV cameras).",
                      epilog="Exit status: 0 done, 2 bad input, 130 interrupted, 1 internal error.")
    p.add_argument("run", type=Path, help="a senerf-fit output folder (its --out)")
    p.add_argument("--mesh", type=Path, help="write a coloured mesh: .ply, .obj or .glb")
    p.add_argument("--points", type=Path, help="write a fused, coloured point cloud: .ply")
    p.add_argument("--depth", type=Path, metavar="DIR", help="write 16-bit depth PNGs and depth_scale.json here")
    p.add_argument("--resolution", type=int_flag("--resolution", minimum=8, maximum=512), default=RESOLUTION,
                   help=f"marching-cubes grid side, 8 to 512 (default {RESOLUTION})")
    p.add_argument("--level", type=float_flag("--level", positive=True), default=None,
                   help="density of the surface (default: where one render sample interval is half opaque, "
                        "ln 2 x samples / mean box side)")
    p.add_argument("--components", choices=("all", "largest"), default="all",
                   help="keep every connected part of the mesh (default) or the largest")
    p.add_argument("--views", choices=("train", "test", "all"), default="train",
                   help="the views --depth writes (default train)")
    p.add_argument("--iteration", type=int_flag("--iteration", allow_zero=True), default=None,
                   help="which finished iteration's field (default: the last; 0 = the teacher)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--threads", type=threads_flag(), default=None, metavar="N", help=THREADS_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def _run(args) -> int:
    from senerf.fitted import load_run

    device = check_device(args.device)
    set_threads(args.threads)
    if args.mesh is None and args.points is None and args.depth is None:
        raise InputError("nothing to export: give --mesh FILE, --points FILE and/or --depth DIR")
    _check_file(args.mesh, "--mesh", _MESH_TYPES, args.overwrite)
    _check_file(args.points, "--points", (".ply",), args.overwrite)
    _check_dir(args.depth, args.overwrite)
    run = load_run(args.run, args.iteration, device)
    progress, said = not args.quiet, f"{run.scene.name}, iteration {run.iteration}"
    if args.mesh is not None:
        lo, hi = mesh_region(run.model)
        level = default_level(run.model) if args.level is None else args.level
        grid = density_grid(run.density, lo, hi, args.resolution, progress=progress)
        mesh = grid_mesh(grid, lo, hi, level, args.components)
        colour_mesh(run, mesh)
        _write_file(args.mesh, mesh)
        print(f"{PROG}: {said}: mesh of {len(mesh.vertices)} vertices, {len(mesh.faces)} faces at density {level:.3g} "
              f"({args.resolution}^3 grid) in {args.mesh}")
    if args.points is not None:
        import trimesh

        cams = run.cameras
        pc2w, pk = run.pseudo_cameras(run.iteration + 1)
        c2w = np.concatenate([cams.c2w[run.train_idx], pc2w])
        intr = tuple(cams.intrinsics[int(i)] for i in run.train_idx) + tuple(pk)
        xyz, rgb = fused_points(c2w, intr, _render(run, c2w, intr, progress, "points: render"))
        _write_file(args.points, trimesh.PointCloud(xyz, colors=rgb))
        print(f"{PROG}: {said}: {len(xyz)} points from {len(c2w)} views ({len(pc2w)} pseudo) in {args.points}")
    if args.depth is not None:
        cams = run.cameras
        views = dict(train=run.train_idx, test=run.test_idx, all=np.arange(len(cams.c2w)))[args.views]
        intr = tuple(cams.intrinsics[int(i)] for i in views)
        renders = _render(run, cams.c2w[views], intr, progress, "depth: render")
        record = dict(senerf_export=__version__, run=os.path.abspath(run.folder), iteration=run.iteration)
        replace_folder(args.depth, lambda tmp: write_depth_maps(tmp, renders, views, cams.c2w[views], intr, record))
        print(f"{PROG}: {said}: {len(views)} depth maps in {args.depth}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``senerf-export``; returns the exit status (0 ok, 2 bad input, 130 interrupted, 1 internal)."""
    return command_main(PROG, lambda a: _run(build_parser().parse_args(a)), argv, "no output written")


def console() -> None:
    """The ``senerf-export`` console script: :func:`main` through :func:`senerf.cliargs.console_entry`."""
    console_entry(main)


if __name__ == "__main__":  # pragma: no cover
    console()
