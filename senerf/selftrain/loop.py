"""The self-training loop (SE-NeRF, Algorithm 1): iterations ``0..K`` of one fit, resumable.

Iteration 0 trains the baseline teacher on the sparse views with the photometric loss; each later iteration
samples pseudo cameras, labels them, builds the distillation loss, trains a fresh student and evaluates it.  The
data flow with tensor shapes and the resume rules are in DESIGN.md ("One self-training iteration", "Resume").
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..atomic import atomic_write_text
from ..config import ModelConfig, SelfTrainConfig, TrainConfig
from ..runfolder import METRICS_FILE, checkpoint_path, read_metrics
from ..train import (RayBatchSource, build_field, evaluate, iteration_row, load_field, metrics_document, timed,
                     train_field)
from .distill import DistillationLoss
from .features import VGG19Features, features_device, known_view_features
from .labels import (PseudoLabels, estimate_reliability, known_images, labels_text, pseudo_rays, sample_pseudo_cameras,
                     write_pseudo_pngs)

__all__ = ["run_selftraining"]


class _Labelling:
    """Labels the pseudo views of an iteration with a given teacher; the VGG-19 extractor and the known views'
    features are made once per run, when first needed."""

    def __init__(self, scene, train_idx, model: ModelConfig, cfg: SelfTrainConfig, device, progress: bool,
                 echo: Callable[[str], None]):
        self.scene, self.train_idx, self.model, self.cfg = scene, train_idx, model, cfg
        self.device, self.progress, self.echo = device, progress, echo
        self.extractor = self.known_features = None

    def __call__(self, teacher, occupancy, k: int, phases: dict) -> PseudoLabels:
        cfg, scene, train_idx = self.cfg, self.scene, self.train_idx
        n = cfg.n_pseudo_per_input * train_idx.size
        self.echo(f"selftrain: iteration {k}: labelling {n} pseudo views (teacher renders, vgg19 features, "
                  f"reprojection into {train_idx.size} known views)")
        if self.extractor is None:
            with timed(phases, "features"):
                self.extractor = VGG19Features(normalize_layers=cfg.normalize_layers,
                                               device=features_device(scene, train_idx, self.device, self.echo))
                self.known_features = known_view_features(self.extractor, known_images(scene, train_idx, self.model))
        c2w, intrinsics = sample_pseudo_cameras(scene, train_idx, cfg, k)
        return estimate_reliability(teacher, occupancy, self.model, scene, train_idx, c2w, self.extractor, cfg,
                                    cfg.alpha(k), known_features=self.known_features, device=self.device,
                                    pseudo_intrinsics=intrinsics, progress=self.progress, phases=phases)


def run_selftraining(scene, train_idx, test_idx, model: ModelConfig, train_cfg: TrainConfig, cfg: SelfTrainConfig,
                     out_dir, command: list | None = None, config: dict | None = None, progress: bool = True,
                     echo: Callable[[str], None] = print) -> dict:
    """Iterations ``0..cfg.iterations`` of one fit into ``out_dir``, resuming what a killed call left there.

    ``out_dir`` must hold this run only (``senerf.fit`` checks its ``run.json`` first): its finished iterations
    are taken as this run's.  A folder holding more iterations than asked is left as it is.

    Args:
        scene: the :class:`senerf.data.Scene`.
        train_idx: (m,) known (training) view indices; test_idx: (t,) evaluation view indices.
        model: the :class:`~senerf.config.ModelConfig` (from :func:`senerf.train.choose_model`).
        train_cfg: the training of the teacher and of every student.
        out_dir: the run folder (``iter_K/``, ``checkpoints/``, ``metrics.json``).
        command, config: recorded in ``metrics.json``.
        progress: tqdm bars; echo: where one-line status messages go.

    Returns:
        the ``metrics.json`` document (DESIGN.md contract).
    """
    out = Path(out_dir)
    device = torch.device(train_cfg.device)
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    test_idx = np.asarray(test_idx, dtype=np.int64).reshape(-1)
    metrics = metrics_document(scene, train_idx, test_idx, command, config or {})
    stored = read_metrics(out)
    metrics["iterations"] = [] if stored is None else stored["iterations"]
    done = len(metrics["iterations"])
    if done > cfg.iterations:
        echo(f"selftrain: {out} holds iterations 0-{done - 1} already; nothing to train")
        return stored
    teacher = occupancy = None
    if done:
        teacher, occupancy = load_field(checkpoint_path(out, done - 1), model, train_cfg.seed, train_cfg.steps, device)
        echo(f"selftrain: resuming after iteration {done - 1}")
    rays = RayBatchSource.from_scene(scene, train_idx, model, device)
    label = _Labelling(scene, train_idx, model, cfg, device, progress, echo)
    for k in range(done, cfg.iterations + 1):
        t0 = time.perf_counter()
        labels = distillation = None
        phases = {}
        if k > 0:
            labels = label(teacher, occupancy, k, phases)
            write_pseudo_pngs(out / f"iter_{k}" / "pseudo", labels)
            echo(f"selftrain: iteration {k}: {labels.c2w.shape[0]} pseudo views within {cfg.pseudo_range(k):g} deg, "
                 f"{labels_text(labels, cfg)}")
            distillation = DistillationLoss(teacher, pseudo_rays(labels, model, device, cfg.kernel_size), cfg,
                                            model.n_samples, model.train_background, teacher_occupancy=occupancy)
        # a fresh field from the same initialisation seed in every iteration, so that iteration-to-iteration
        # differences are the distillation's and not the initialisation's
        student = build_field(model, seed=train_cfg.seed, steps=train_cfg.steps)
        result = train_field(student, rays, train_cfg, extra_loss=distillation, checkpoint=checkpoint_path(out, k),
                             progress=progress)
        phases["train"] = result.seconds + result.seconds_before
        with timed(phases, "evaluation"):
            ev = evaluate(result.field, scene, test_idx, out / f"iter_{k}" / "test", model,
                          occupancy=result.occupancy, device=device, progress=progress)
        reliable = None if labels is None or not labels.foreground.any() else labels.reliable_fraction
        seconds = time.perf_counter() - t0 + result.seconds_before
        # the rays a step trains on: the real views' and, for a student, the pseudo views' (the teacher's forward
        # queries of the reliable rays are not counted)
        prior = cfg.batch_prior if cfg.prior and cfg.lambda_prior > 0 else 0
        step_rays = train_cfg.batch_rays + (cfg.batch_reliable + prior if k else 0)
        samples = result.steps * step_rays * model.n_samples
        metrics["iterations"].append(iteration_row(k, ev, reliable, seconds, device, phases, samples))
        metrics["seconds_total"] = float(sum(row["seconds"] for row in metrics["iterations"]))
        atomic_write_text(out / METRICS_FILE, json.dumps(metrics, indent=1))
        echo(f"selftrain: iteration {k}: test PSNR {ev['psnr']:.2f} dB, SSIM {ev['ssim']:.3f}")
        teacher, occupancy = result.field, result.occupancy
    return metrics
