"""A finished ``senerf-fit`` run, loaded for rendering and for queries of its field: :func:`load_run`.

Example (a run folder ``runs/lego`` written by ``senerf-fit``)::

    import senerf
    run = senerf.load_run("runs/lego")                          # the last finished iteration
    out = run.render(run.cameras.c2w[run.cameras.test[:1]])     # rgb, z_depth, acc of a test view
    sigma = run.density([[0.0, 0.0, 0.0]])                      # (1,) density at the world origin

Convention: poses are OpenCV camera-to-world (x right, y down, z forward) in the scene's world frame (the frame of
its ``transforms.json`` / COLMAP model / LLFF poses, converted at the loaders' edge); depths are camera z, in the
scene's units; pixel centres are at ``i + 0.5``.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from senerf.errors import InputError
from senerf.runfolder import METRICS_FILE, RUN_FILE, checkpoint_path, finished_iterations, read_metrics, read_run

__all__ = ["Cameras", "FittedRun", "load_run", "with_iteration"]


class Cameras(NamedTuple):
    """A fitted scene's cameras: ``c2w (n, 4, 4)`` float64 OpenCV camera-to-world, ``intrinsics`` (n
    :class:`senerf.geometry.Intrinsics`), the run's ``train`` and ``test`` view indices, and ``image_paths``."""

    c2w: np.ndarray
    intrinsics: tuple
    train: np.ndarray
    test: np.ndarray
    image_paths: tuple


@dataclass(frozen=True, eq=False)
class FittedRun:
    """A finished iteration of a ``senerf-fit`` run, ready to render.

    Attributes:
        scene: the :class:`senerf.data.Scene` named by ``run.json`` (at the run's downscale).
        model: the run's :class:`senerf.config.ModelConfig`.
        field: the field the iteration ended with, in eval mode, on the requested device.
        occupancy: its occupancy grid, or ``None``.
        iteration: the iteration (0 = the teacher).
        train_idx, test_idx: ``(m,)``, ``(t,)`` the run's view indices into the scene.
        train: the run's :class:`senerf.config.TrainConfig` (its seed and steps rebuild the fields).
        finished: the run's finished iterations, ascending.
        selftrain: the run's :class:`senerf.config.SelfTrainConfig` (its pseudo cameras).
    """

    folder: Path
    scene: object
    model: object
    field: object
    occupancy: object
    iteration: int
    train_idx: np.ndarray
    test_idx: np.ndarray
    train: object
    finished: tuple
    selftrain: object = None

    @property
    def cameras(self) -> Cameras:
        """The scene's cameras (all views) and the run's train/test split."""
        s = self.scene
        return Cameras(s.c2w, s.intrinsics_all, self.train_idx, self.test_idx, s.image_paths)

    def pseudo_cameras(self, iteration: int):
        """``(c2w (P, 4, 4), P intrinsics)``: the pseudo cameras self-training iteration ``iteration`` (>= 1) samples,
        the same draws as the fit (:func:`senerf.selftrain.labels.sample_pseudo_cameras`)."""
        from senerf.selftrain.labels import sample_pseudo_cameras

        return sample_pseudo_cameras(self.scene, self.train_idx, self.selftrain, int(iteration))

    def at_iteration(self, iteration: int) -> "FittedRun":
        """This run with the field of another finished ``iteration`` (0 = the teacher), on the same device."""
        return with_iteration(self, int(iteration), self.device)

    @property
    def device(self) -> str:
        """Where the field lives (``'cpu'``, ``'cuda:0'``, ...)."""
        return str(next(self.field.parameters()).device)

    def render(self, c2w, intrinsics=None, progress: bool = False) -> dict:
        """Render views as ``senerf-fit`` scored its test views.

        Args:
            c2w: ``(4, 4)`` or ``(n, 4, 4)`` OpenCV camera-to-world poses, the scene's world frame.
            intrinsics: one :class:`senerf.geometry.Intrinsics` or ``n`` of one size (default: the first
                training view's).
            progress: a progress bar over the views.

        Returns:
            float32 arrays ``rgb (n, H, W, 3)`` in [0, 1], ``z_depth (n, H, W)`` (camera z, metric), ``acc (n, H, W)``.
        """
        from senerf.train import render_views

        k = self.scene.intrinsics_all[int(self.train_idx[0])] if intrinsics is None else intrinsics
        return render_views(self.field, self.model, k, c2w, occupancy=self.occupancy, progress=progress)

    def depth(self, c2w, intrinsics=None) -> np.ndarray:
        """``(n, H, W)`` float32 camera z-depth of the views (:meth:`render`'s ``z_depth``)."""
        return self.render(c2w, intrinsics)["z_depth"]

    def density(self, points, chunk: int = 1 << 16) -> np.ndarray:
        """The field's density ``(...)`` float32 at world points ``points (..., 3)``; zero where the occupancy grid
        is empty (as the renderer skips it) and outside the fitted region.  Forward-facing (NDC) fits are queried at
        the points' NDC coordinates, so there the density is per unit of the NDC ray parameter."""
        return self._query(points, None, chunk)[0]

    def color(self, points, view_dirs, chunk: int = 1 << 16) -> np.ndarray:
        """The field's colour ``(..., 3)`` float32 in [0, 1] at world ``points (..., 3)`` seen along the unit
        directions ``view_dirs (..., 3)`` (from the camera into the scene)."""
        return self._query(points, view_dirs, chunk)[1]

    def _query(self, points, view_dirs, chunk: int):
        import torch

        pts = np.asarray(points, dtype=np.float64)
        if pts.shape[-1:] != (3,):
            raise ValueError(f"points: expected (..., 3), got {pts.shape}")
        flat = pts.reshape(-1, 3)
        dirs = None
        if view_dirs is not None:
            dirs = np.broadcast_to(np.asarray(view_dirs, dtype=np.float64), pts.shape).reshape(-1, 3)
            dirs = dirs / np.clip(np.linalg.norm(dirs, axis=-1, keepdims=True), 1e-12, None)
        if self.model.ndc:   # the NDC warp of the fit's rays (one focal length, the first training view's)
            from senerf.fields import ndc_points

            k = self.scene.intrinsics_all[int(self.train_idx[0])]
            flat = ndc_points(torch.as_tensor(flat), k.fx, k.fy, k.width, k.height, self.model.ndc_near).numpy()
        else:
            flat = flat - np.asarray(self.model.frame_origin, dtype=np.float64)
        sigma = np.empty(len(flat), np.float32)
        rgb = np.empty((len(flat), 3), np.float32)
        dev = self.device
        with torch.no_grad():
            for s in range(0, len(flat), chunk):
                xyz = torch.as_tensor(flat[s:s + chunk], dtype=torch.float32, device=dev)
                if dirs is None:
                    out = self.field.density(xyz)
                else:
                    out, colour = self.field(xyz, torch.as_tensor(dirs[s:s + chunk], dtype=torch.float32, device=dev))
                    rgb[s:s + chunk] = colour.float().cpu().numpy()
                if self.occupancy is not None:
                    out = torch.where(self.occupancy.is_occupied(xyz), out, torch.zeros_like(out))
                sigma[s:s + chunk] = out.reshape(-1).float().cpu().numpy()
        return sigma.reshape(pts.shape[:-1]), rgb.reshape(pts.shape)


def _views(metrics: dict, which: str, path: Path, n_images: int) -> np.ndarray:
    """``metrics['<which>_views']`` (``which``: ``'train'`` or ``'test'``) as indices ``(m,)`` into the scene."""
    idx = metrics.get(f"{which}_views")
    if not (isinstance(idx, list) and idx and all(type(i) is int and 0 <= i < n_images for i in idx)):
        raise InputError(f"expected a non-empty list of view indices below {n_images}", file=path,
                         field=f"{which}_views")
    return np.asarray(idx, dtype=np.int64)


def load_run(folder, iteration: int | None = None, device: str = "cpu") -> FittedRun:
    """Load a run folder's field after ``iteration`` (default: the last finished one).

    Raises:
        InputError: not a run folder of this senerf version (:func:`senerf.runfolder.read_run`), a bad
            ``run.json`` / ``metrics.json`` value, no finished iteration (or not ``iteration``, naming
            ``--iteration``), a missing or foreign checkpoint, a scene folder that no longer matches the run.

    Warns:
        UserWarning: the scene's files no longer hold what the fit read (``run.json``'s ``scene_files``).
    """
    from senerf.config import ModelConfig, SelfTrainConfig, TrainConfig
    from senerf.data import changed_files, detect_format, load_scene, scene_file_digests, view_names

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder", file=folder)
    run_path, metrics_path = folder / RUN_FILE, folder / METRICS_FILE
    run = read_run(folder)
    metrics = read_metrics(folder)
    done = finished_iterations(metrics)
    if not done:
        raise InputError("holds no finished iteration yet; let senerf-fit finish one (rerun its command to resume)",
                         file=folder)
    configs = {}
    for key, config in (("model", ModelConfig), ("train", TrainConfig), ("selftrain", SelfTrainConfig)):
        try:
            configs[key] = config(**run["settings"][key])
        except InputError as exc:   # the config's own check, named in run.json
            raise InputError(exc.problem, file=run_path, field=f"settings.{key}.{exc.field}") from None
        except (KeyError, TypeError) as exc:   # missing, or holding a setting of another senerf version
            raise InputError(f"missing or not of this senerf version ({exc})", file=run_path,
                             field=f"settings.{key}") from None
    settings, model, train = run["settings"], configs["model"], configs["train"]
    scene_dir = str(run["scene_dir"])
    kind = settings.get("scene_kind") if detect_format(scene_dir) == "colmap" else None   # only COLMAP's is chosen
    scene = load_scene(scene_dir, downscale=settings.get("downscale"), kind=kind)
    train_idx, test_idx = (_views(metrics, which, metrics_path, scene.n_images) for which in ("train", "test"))
    recorded = run.get("scene_files") or {}
    now = scene_file_digests(scene, [i for i, name in enumerate(view_names(scene, range(scene.n_images)))
                                     if name in recorded])
    lines = changed_files(recorded, {name: digest for name, digest in now.items() if name in recorded})
    if lines:   # the cameras then may not be in the frame the field was fitted in
        more = f" and {len(lines) - 1} more" if len(lines) > 1 else ""
        warnings.warn(f"{run_path}: the scene's files changed since the fit ({lines[0]}{more}); its cameras and "
                      "photos are read as they are now", stacklevel=2)
    fitted = FittedRun(folder, scene, model, None, None, -1, train_idx, test_idx, train, tuple(done),
                       configs["selftrain"])
    return with_iteration(fitted, done[-1] if iteration is None else int(iteration), device)


def with_iteration(run: FittedRun, iteration: int, device: str = "cpu", flag: str = "--iteration") -> FittedRun:
    """``run`` with the field of another finished ``iteration`` (the scene is not read again); an unfinished
    one is an :class:`InputError` naming ``flag``, the option that asked for it."""
    from senerf.train.checkpoint import load_field

    if iteration not in run.finished:
        raise InputError(f"iteration {iteration} is not finished in this run (finished: {list(run.finished)})",
                         field=flag)
    field, occupancy = load_field(checkpoint_path(run.folder, iteration), run.model, run.train.seed, run.train.steps,
                                  device)
    return dataclasses.replace(run, field=field, occupancy=occupancy, iteration=iteration)
