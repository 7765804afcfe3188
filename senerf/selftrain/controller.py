"""The self-training loop: teacher -> pseudo labels -> reliability -> fresh student -> next teacher.

Iteration 0 trains the baseline teacher on the sparse views (photometric loss only).  Iteration ``K >= 1``:

1. ``n_pseudo_per_input x m`` pseudo poses from ``senerf.geometry.sample_pseudo_views`` within
   ``pseudo_range_deg + (K - 1) pseudo_range_step_deg`` degrees of the ``m`` inputs (10, 15, 20 ...), each
   with the intrinsics of the input it was carried from;
2. the teacher renders them and the known views (rgb, z-depth, opacity; ``senerf.train.render_views``);
3. features of the pseudo renders and of the *real* known images (computed once per run), feature
   consistency through ``geometry.reproject`` (:func:`senerf.selftrain.reliability.view_similarity`, with the
   teacher's known-view z-depth as occlusion buffer; known pixels with opacity < ``opacity_threshold`` are
   "no surface"), the threshold of the iteration (adaptive ``alpha = alpha0 + (K - 1) alpha_step``);
4. a freshly initialised student is trained on the real rays plus :class:`DistillationLoss` (through the
   trainer's ``extra_loss`` hook), then becomes the teacher.

Outputs under ``out_dir`` (DESIGN.md): ``iter_K/test/`` (``senerf.train.evaluate``), ``iter_K/pseudo/``
(``rgb_XXX.png`` teacher render, ``similarity_XXX.png`` grey = max similarity clipped to [0, 1], black on
the background, which is not scored,
``mask_XXX.png``: white reliable, blue unreliable with a prior target, black unreliable without one, grey
background), ``metrics.json`` (atomic, after every iteration) and ``checkpoints/``: ``teacher.pt``
(the finished iteration's field, atomic), the trainer's own ``iter_K_train.pt``, ``scene_files.json``
(digests of the scene files the run reads), and while iteration K runs ``iter_K_labels/`` (each labelled pseudo
view, :mod:`senerf.selftrain.labelrecord`) and ``iter_K_eval.json`` (each scored test view).  A killed run resumes
from the last finished iteration (and inside an iteration from the labelled views and the trainer's checkpoint,
without labelling again); everything in an iteration is seeded from ``(seed, K)``, so the
resumed run repeats the same pseudo views.  A folder whose run read other bytes from the scene's files is not
resumed (:func:`senerf.data.scene_file_digests`, as ``senerf-fit`` checks its ``run.json``).

Cameras are reached only through ``senerf.geometry`` (pose sampling, warps) and the trainer's rendering and
ray-building functions (``render_views``, ``camera_rays``); this module does no projection math itself.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import numbers
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from .. import geometry
from ..data import changed_files, run_file_digests
from ..data.fewshot import DEFAULT_N_VIEWS, explicit_n_views
from ..errors import InputError
from ..train import (atomic_write_text, build_field, camera_rays, config_to_dict, differences_text, eval_images,
                     evaluate, finished_metrics, iteration_row, load_checkpoint, resume_host_line,
                     load_state_keeping_box, make_occupancy, metrics_document, render_views, save_checkpoint,
                     settings_differences, train_field, write_png)
from .distill import (DistillationLoss, DistillConfig, DistillConfigError, PseudoRays, is_number, prior_weights,
                      unified_prior_weights)
from .features import (FEATURE_NAMES, features_fit_gpu, features_memory_problem, features_on_device,
                       known_view_features, make_feature_extractor)
from .labelrecord import (LABELLED_VIEW_ARRAYS, labelled_view_layout, labelling_digest, read_labelled_view,
                          write_labelled_view)
from .reliability import (THRESHOLD_KINDS, gt_reliable_mask, mask_quality, resolve_threshold, threshold_weights,
                          view_similarity)

__all__ = ["SelfTrainConfig", "PseudoLabels", "run_selftraining", "estimate_reliability", "known_images",
           "reliability_mask_quality", "oracle_reliability", "dataset_pseudo_views", "pseudo_view_centre_problem",
           "RELIABILITY_KINDS"]

_CKPT_FORMAT = "senerf-selftrain-1"
_FILES_RECORD = "scene_files.json"   # in checkpoints/: what the scene's files held when the run read them
RELIABILITY_KINDS = ("features", "oracle")


@dataclass(frozen=True)
class SelfTrainConfig(DistillConfig):
    """Self-training settings (every one is recorded in ``metrics.json``).

    It extends :class:`DistillConfig` (whose fields it inherits, one definition of each, and validates as
    :class:`~senerf.errors.InputError` under the field name ``distillation``) with the loop's own settings,
    so it is itself the :class:`DistillationLoss`'s configuration.

    Attributes:
        iterations: self-training iterations after the baseline (0 = baseline only).
        n_pseudo_per_input: pseudo views per known view and iteration.
        pseudo_range_deg: max azimuth/elevation offset of pseudo views in iteration 1 (paper: 10).
        pseudo_range_step_deg: widening per later iteration.
        features: 'vgg19' | 'daisy'.
        normalize_layers: VGG only: L2-normalise each layer before concatenating.
        threshold: 'adaptive' | 'fixed' | 'unified'.
        alpha0, alpha_step: adaptive threshold: ``tau`` = (1 - alpha) quantile, alpha grows per iteration
            (paper: 0.15, 0.05; alpha0 = 0.3 measured +0.00 ± 0.13 dB, see :class:`DistillConfig` for how).
        fixed_tau: the fixed threshold.
        beta: the unified weighting's sigmoid slope.  The 'unified' ablation keeps the three loss weights of
            the hard thresholds (``lambda_color``, ``lambda_geometry``, ``lambda_prior``); the paper's unified
            objective (its appendix) writes none, so its ``(1 - s)`` neighbour term weighs 1 there, 200 times
            ``lambda_prior``.  Its measured -0.33 dB (BENCHMARKS.md) is of this variant.
        opacity_threshold: teacher opacity below which a pixel is background (ignored).
        occlusion_rel_tol: relative depth slack of the occlusion test.
        batch_reliable, batch_prior, batch_empty, lambda_color, lambda_geometry, lambda_prior, geometry_target,
        density_distill, prior, kernel_size, kernel_std, student_grid: inherited, see :class:`DistillConfig`.
        seed: seeds pseudo-view sampling (fields are initialised from ``TrainConfig.seed``).
        reliability: 'features' (the method: feature consistency across views) or 'oracle' (the paper's
            Figure 1 toy experiment, an analysis that needs ground truth: pseudo views are held-out dataset
            poses, see :func:`dataset_pseudo_views`, and a pixel is reliable where the teacher's colour is
            within ``oracle_max_error`` (mean absolute RGB) of the real image, background included).
        oracle_max_error: the oracle's colour tolerance.
        empty_opacity: pseudo pixels the teacher renders with opacity below this are reliable *empty* rays
            (colour = background, density distilled to the teacher's near-zero weights); 0 switches it off.
            The paper's reliability is defined for surface pixels only and says nothing of background
            pixels; this is our addition (ablation ``senerf-no-empty``).  With the adaptive and fixed
            thresholds empty rays also count as reliable neighbours of the prior, so unreliable pixels at a
            silhouette get a partly empty prior target; the unified weighting's neighbour weights come from
            the foreground similarities alone (the paper's equation), so there they do not.  At most
            ``opacity_threshold`` (a foreground pixel is never labelled empty).
            Measured on lego Extreme at 100x100, fast preset, one iteration, student seed 0 (teacher
            16.59 dB): off 16.78, 0.05 17.31, 0.2 17.44, 0.5 17.10 dB (student seed 1: off 16.73, 0.2
            17.08; the student's seed alone moves the result by ~0.4 dB).  Hence 0.2.
    """

    iterations: int = 3
    n_pseudo_per_input: int = 8
    pseudo_range_deg: float = 10.0
    pseudo_range_step_deg: float = 5.0
    features: str = "vgg19"
    normalize_layers: bool = True
    threshold: str = "adaptive"
    alpha0: float = 0.15
    alpha_step: float = 0.05
    fixed_tau: float = 0.6
    beta: float = 16.0
    opacity_threshold: float = 0.5
    occlusion_rel_tol: float = 0.05
    seed: int = 0
    reliability: str = "features"
    oracle_max_error: float = 0.1
    empty_opacity: float = 0.2

    def __post_init__(self) -> None:
        if self.reliability not in RELIABILITY_KINDS:
            raise InputError(f"must be one of {', '.join(RELIABILITY_KINDS)}, got {self.reliability!r}",
                             field="reliability")
        for name, least in (("iterations", 0), ("n_pseudo_per_input", 1), ("seed", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
                raise InputError(f"must be an integer >= {least}, got {value!r}", field=name)
            object.__setattr__(self, name, int(value))   # a NumPy integer as a plain int (JSON, checkpoints)
        if self.features not in FEATURE_NAMES:
            raise InputError(f"must be one of {', '.join(FEATURE_NAMES)}, got {self.features!r}", field="features")
        if self.threshold not in THRESHOLD_KINDS:
            raise InputError(f"must be one of {', '.join(THRESHOLD_KINDS)}, got {self.threshold!r}",
                             field="threshold")
        for name, low, high, low_open in (("empty_opacity", 0, 1, False), ("oracle_max_error", 0, 1, True),
                                          ("alpha0", 0, 1, False), ("fixed_tau", -1, 1, False),   # a cosine
                                          ("opacity_threshold", 0, 1, True)):
            value = getattr(self, name)
            if not (is_number(value) and (low < value if low_open else low <= value) and value <= high):
                raise InputError(f"must be in {'(' if low_open else '['}{low}, {high}], got {value!r}", field=name)
        for name in ("alpha_step", "pseudo_range_deg", "pseudo_range_step_deg", "occlusion_rel_tol"):
            value = getattr(self, name)
            if not (is_number(value) and value >= 0):
                raise InputError(f"must be a finite number >= 0, got {value!r}", field=name)
        if not (is_number(self.beta) and self.beta > 0):
            raise InputError(f"must be a finite number > 0, got {self.beta!r}", field="beta")
        try:
            super().__post_init__()   # the distillation settings, batch_empty's type among them
        except DistillConfigError as exc:
            raise InputError(exc.message, field=exc.field) from None
        if self.empty_opacity > self.opacity_threshold:
            raise InputError(f"must be <= opacity_threshold ({self.opacity_threshold!r}), got "
                             f"{self.empty_opacity!r}: foreground pixels would be labelled empty space",
                             field="empty_opacity")
        if self.batch_empty > 0 and self.empty_opacity <= 0:
            raise InputError("batch_empty > 0 draws empty-space rays apart, which needs empty_opacity > 0",
                             field="batch_empty")

    def alpha(self, iteration: int) -> float:
        """Adaptive-threshold alpha of iteration ``iteration >= 1`` (capped at 1)."""
        return min(1.0, self.alpha0 + (iteration - 1) * self.alpha_step)

    def pseudo_range(self, iteration: int) -> float:
        """Max angular offset (degrees) of the pseudo views of iteration ``iteration >= 1``."""
        return self.pseudo_range_deg + (iteration - 1) * self.pseudo_range_step_deg


@dataclass(frozen=True)
class PseudoLabels:
    """Teacher renders of pseudo views and their reliability.

    Attributes:
        c2w: (P, 4, 4) pseudo poses.  rgb: (P, H, W, 3).  z_depth, acc: (P, H, W).
        similarity: (P, H, W) max feature similarity (-1 where no known view sees the pixel).
        foreground: (P, H, W) bool.  tau: the hard threshold used (None for 'unified').
        weights: (P, H, W) reliable weight in [0, 1].
        prior: (P, H, W) prior weight (unreliable foreground pixels with a reliable neighbour).
        neighbour: (P, H, W, Q*Q - 1) normalised neighbour weights.
        empty: (P, H, W) bool: reliable pixels that are empty space (teacher opacity below
            ``SelfTrainConfig.empty_opacity``; all False when it is 0).  A subset of ``weights > 0``; the one
            place this test is made, by whichever producer (features or oracle) made the labels.
        intrinsics: the ``Intrinsics`` the views were rendered with: one shared, or a tuple of P.
        seconds_recorded: seconds the views read back from a labelling record took when they were labelled
            (``estimate_reliability``'s ``resume``; 0 without one), for the iteration's time.
        views_recorded: how many views were read back from that record rather than labelled.
    """

    c2w: np.ndarray
    rgb: np.ndarray
    z_depth: np.ndarray
    acc: np.ndarray
    similarity: np.ndarray
    foreground: np.ndarray
    tau: float | None
    weights: np.ndarray
    prior: np.ndarray
    neighbour: np.ndarray
    empty: np.ndarray
    intrinsics: "geometry.Intrinsics | tuple[geometry.Intrinsics, ...]"
    seconds_recorded: float = 0.0
    views_recorded: int = 0

    def __post_init__(self) -> None:
        if self.empty.shape != self.weights.shape or self.empty.dtype != bool:
            raise ValueError(f"empty must be a {self.weights.shape} bool array, got {self.empty.shape} "
                             f"{self.empty.dtype}")
        if np.any(self.empty & ~(self.weights > 0)):
            raise ValueError("empty pixels must be reliable (weights > 0)")

    @property
    def reliable_fraction(self) -> float:
        """Mean reliable weight over foreground pseudo pixels (NaN without foreground)."""
        fg = self.foreground
        return float(self.weights[fg].mean()) if fg.any() else float("nan")


#: The real images ``idx`` as the teacher sees them at evaluation (``senerf.train.eval_images``).
known_images = eval_images


def estimate_reliability(teacher, occupancy, model, scene, train_idx, pseudo_c2w: np.ndarray, extractor,
                         cfg: SelfTrainConfig, alpha: float, known_features=None,
                         device=None, renders: tuple[dict, dict] | None = None,
                         pseudo_intrinsics=None, progress: bool = False, resume=None) -> PseudoLabels:
    """Render ``pseudo_c2w (P, 4, 4)`` with the teacher and estimate every pixel's reliability.

    Args:
        teacher, occupancy: the teacher field and its occupancy grid (or None).
        model: its :class:`senerf.train.ModelConfig`.
        scene, train_idx: the known views ``train_idx (m,)``.
        extractor: a :class:`~senerf.selftrain.features.FeatureExtractor`.
        cfg: thresholds, occlusion tolerance, kernel.
        alpha: the adaptive threshold's alpha for this iteration.
        known_features: (m, H, W, C) features of :func:`known_images` (an array, ``extractor.lazy(...)``, or a
            tensor on the extractor's GPU when :func:`~senerf.selftrain.features.features_on_device`), or a
            function of no arguments returning them (called only when a view is labelled here, not read from
            ``resume``); computed with :func:`known_view_features` when None.
        renders: ``(known, pseudo)`` teacher renders (``senerf.train.render_views`` dicts of the known and the
            pseudo cameras) to reuse; rendered when None (the pseudo views one at a time, as each is labelled).
        pseudo_intrinsics: the pseudo cameras' ``Intrinsics`` (one, or a sequence of P); default image 0's
            (the controller passes each pseudo view its source input's, see ``_sample_pseudo_poses``).
            The known views always use their own (``scene.intrinsics_all``).
        progress: a tqdm bar over the pseudo views' labelling (render, features, warps), which shows the known
            views' renders and features as its postfix while they are computed.
        resume: a folder recording each labelled view (its render, similarity and foreground;
            :mod:`senerf.selftrain.labelrecord`) under a digest of the teacher, the model, the known views, the
            pseudo cameras, the extractor and the occlusion settings.  A call that finds views recorded there
            with the same digest labels only the others and returns what one uninterrupted call returns (the
            recorded views' seconds in ``PseudoLabels.seconds_recorded``).  ``known_features`` are taken to be
            the extractor's of :func:`known_images`.  The caller deletes the folder once it is done with it.
    Returns:
        :class:`PseudoLabels`.
    """
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    intr = scene.intrinsics if pseudo_intrinsics is None else pseudo_intrinsics
    known_intr = [scene.intrinsics_all[i] for i in train_idx]
    known_c2w = np.asarray(scene.c2w[train_idx], dtype=np.float64)
    n = pseudo_c2w.shape[0]
    pseudo_k = (intr,) * n if isinstance(intr, geometry.Intrinsics) else tuple(intr)
    if renders is not None and (renders[0]["acc"].shape[0] != train_idx.size or renders[1]["acc"].shape[0] != n):
        raise ValueError("renders do not match the known / pseudo cameras")
    size = pseudo_k[0].size if n else (0, 0)
    digest = None if resume is None else labelling_digest(teacher, occupancy, model, scene, train_idx, pseudo_c2w,
                                                           pseudo_k, extractor, cfg.opacity_threshold,
                                                           cfg.occlusion_rel_tol)
    views = {name: np.empty((n, *shape), dtype) for name, (shape, dtype) in labelled_view_layout(size).items()}
    seconds_recorded = 0.0
    todo = []
    for i in range(n):
        rec = None if resume is None else read_labelled_view(resume, i, digest, size)
        if rec is None:
            todo.append(i)
            continue
        for name in LABELLED_VIEW_ARRAYS:
            views[name][i] = rec[name]
        seconds_recorded += rec["seconds"]
    bar = todo
    if progress:   # a resumed labelling's bar starts at the views read back, so its rate and ETA are its own
        from tqdm.auto import tqdm

        bar = tqdm(todo, desc="labelling", unit="view", dynamic_ncols=True, total=n, initial=n - len(todo))
    if todo:
        if progress:   # the known views' part (seconds at 400x400) shows on the bar, and is left out of its rate
            bar.set_postfix_str("known views: teacher renders, features")
        known_z = _known_z_depth(teacher, occupancy, model, known_intr, known_c2w, cfg, device, renders)
        if callable(known_features):
            known_features = known_features()
        if known_features is None:
            known_features = known_view_features(extractor, known_images(scene, train_idx, model))
        if progress:
            bar.set_postfix_str("")
            bar.unpause()
    # on a GPU the features stay there and view_similarity looks them up with torch
    extract = extractor.device_features if features_on_device(extractor) else extractor
    for i in bar:
        t0 = time.perf_counter()
        if renders is None:
            view = {name: a[0] for name, a in render_views(teacher, model, pseudo_k[i], pseudo_c2w[i],
                                                           occupancy=occupancy, device=device).items()}
        else:
            view = {name: renders[1][name][i] for name in ("rgb", "z_depth", "acc")}
        feats = extract(np.clip(view["rgb"][None], 0.0, 1.0))[0]
        res = view_similarity(feats, view["z_depth"], view["acc"], pseudo_k[i], pseudo_c2w[i],
                              known_features, known_z, known_intr, known_c2w,
                              opacity_threshold=cfg.opacity_threshold, rel_tol=cfg.occlusion_rel_tol,
                              foreground_only=True)
        view.update(similarity=res.similarity, foreground=res.foreground)
        for name in LABELLED_VIEW_ARRAYS:
            views[name][i] = view[name]
        if resume is not None:
            write_labelled_view(resume, i, digest, view, time.perf_counter() - t0)
    return replace(_labels_from_views(views, pseudo_c2w, intr, cfg, alpha),
                   seconds_recorded=seconds_recorded, views_recorded=n - len(todo))


def _known_z_depth(teacher, occupancy, model, known_intr, known_c2w, cfg: SelfTrainConfig, device,
                   renders) -> np.ndarray:
    """(m, H, W) the teacher's z-depth of the known views, ``inf`` where it renders no surface (the occlusion
    buffer of :func:`view_similarity`); from ``renders[0]`` when given, else rendered."""
    known = (renders[0] if renders is not None else
             render_views(teacher, model, known_intr, known_c2w, occupancy=occupancy, device=device))
    return np.where(known["acc"] >= cfg.opacity_threshold, known["z_depth"], np.inf)


def _labels_from_views(views: dict, pseudo_c2w: np.ndarray, intr, cfg: SelfTrainConfig,
                       alpha: float) -> PseudoLabels:
    """:class:`PseudoLabels` from every pseudo view's render, similarity and foreground (``views``: the
    :data:`LABELLED_VIEW_ARRAYS`, each ``(P, H, W, ...)``): the threshold over all of them, weights, prior."""
    sims, fg, acc = views["similarity"], views["foreground"], views["acc"]
    tau = resolve_threshold(cfg.threshold, sims[fg], alpha=alpha, tau=cfg.fixed_tau)
    weights = threshold_weights(sims, fg, cfg.threshold, tau=tau, beta=cfg.beta)
    empty = _empty_pixels(acc, cfg.empty_opacity)
    weights = np.where(empty, np.float32(1.0), weights).astype(np.float32)
    if cfg.threshold == "unified":
        neighbour, has = unified_prior_weights(sims, fg, cfg.kernel_size, cfg.kernel_std)
        prior = np.where(fg & has, 1.0 - weights, 0.0).astype(np.float32)
    else:
        neighbour, has = prior_weights(weights > 0, cfg.kernel_size, cfg.kernel_std)
        prior = (fg & has & (weights <= 0)).astype(np.float32)
    return PseudoLabels(c2w=pseudo_c2w, rgb=views["rgb"], z_depth=views["z_depth"], acc=acc,
                        similarity=sims, foreground=fg, tau=tau, weights=weights, prior=prior,
                        neighbour=neighbour, empty=empty, intrinsics=intr)


def _empty_pixels(acc: np.ndarray, empty_opacity: float) -> np.ndarray:
    """(...) bool: pixels the teacher renders with opacity ``acc (...)`` below ``empty_opacity`` (none at 0)."""
    return np.asarray(acc) < empty_opacity if empty_opacity > 0 else np.zeros(np.shape(acc), bool)


def reliability_mask_quality(teacher, occupancy, model, scene, train_idx, eval_idx, extractor,
                             cfg: SelfTrainConfig, alpha: float, max_error: float = 0.1,
                             known_features: np.ndarray | None = None, device=None,
                             renders: tuple[dict, dict] | None = None) -> tuple[dict, PseudoLabels]:
    """Our reliable masks vs masks from ground-truth colour, at held-out dataset poses used as pseudo views.

    The ground-truth mask of a pixel is ``mean |C_T - C_gt| < max_error`` (teacher render vs the real image,
    both on ``model.eval_background``); pixels are counted on the teacher's foreground (where our masks are
    defined).  'unified' weights count as reliable above 0.5.

    Args:
        eval_idx: (P,) indices of held-out images of ``scene`` (not in ``train_idx``).
        the rest: as :func:`estimate_reliability` (``renders``: of the known and the ``eval_idx`` cameras,
            each with its own ``scene.intrinsics_all``).
    Returns:
        (dict ``precision, recall, fpr, tp, fp, fn, tn, gt_reliable_rate`` (share of foreground pixels
        that are right by the ground truth: the precision of a mask that keeps everything), the labels).
    """
    eval_idx = np.asarray(eval_idx, dtype=np.int64).reshape(-1)
    if np.intersect1d(eval_idx, np.asarray(train_idx)).size:
        raise ValueError("eval_idx must not contain known views")
    labels = estimate_reliability(teacher, occupancy, model, scene, train_idx,
                                  np.asarray(scene.c2w[eval_idx], dtype=np.float64), extractor, cfg, alpha,
                                  known_features=known_features, device=device, renders=renders,
                                  pseudo_intrinsics=tuple(scene.intrinsics_all[i] for i in eval_idx))
    truth = gt_reliable_mask(np.clip(labels.rgb, 0.0, 1.0), known_images(scene, eval_idx, model), max_error)
    predicted = labels.weights > 0.5
    quality = mask_quality(predicted, truth, labels.foreground)
    fg = labels.foreground
    quality["gt_reliable_rate"] = float(truth[fg].mean()) if fg.any() else float("nan")
    quality["predicted_reliable_rate"] = float(predicted[fg].mean()) if fg.any() else float("nan")
    return quality, labels


def dataset_pseudo_views(scene, train_idx, exclude_idx, max_angle_deg: float, count: int) -> np.ndarray:
    """Held-out dataset views to use as pseudo views (the oracle needs their real images).

    Candidates are the scene's views outside ``train_idx`` and ``exclude_idx`` (the test views); each gets
    the angle between its optical axis and the nearest known view's (``geometry.nearest_view_angles``).
    The ``count`` nearest within ``max_angle_deg`` are returned; when fewer than ``count // 2`` lie within
    it, the nearest ``count // 2`` (at least 1) are taken regardless, so that an iteration has pseudo views.

    Args:
        scene: the :class:`senerf.data.Scene`; train_idx (m,), exclude_idx (k,): indices into it.
        max_angle_deg: the iteration's pseudo-view range.
        count: the most views to return.
    Returns:
        (P,) int64 scene indices, nearest first.
    """
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    taken = np.union1d(train_idx, np.asarray(exclude_idx, dtype=np.int64).reshape(-1))
    cand = np.setdiff1d(np.arange(scene.c2w.shape[0]), taken)
    if cand.size == 0:
        raise InputError("the oracle needs held-out views (not training, not test) with images", field="views")
    c2w = np.asarray(scene.c2w, dtype=np.float64)
    angle = geometry.nearest_view_angles(c2w[train_idx], c2w[cand], center=None)
    order = np.argsort(angle, kind="stable")
    inside = order[angle[order] <= max_angle_deg][:count]
    if inside.size < max(1, count // 2):
        inside = order[:max(1, count // 2)]
    return cand[inside]


def oracle_reliability(teacher, occupancy, model, scene, pseudo_idx, cfg: SelfTrainConfig,
                       device=None) -> PseudoLabels:
    """Labels of the oracle (Figure 1 of the paper): held-out dataset views ``pseudo_idx (P,)`` rendered by
    the teacher; reliable where ``mean |C_T - C_gt| < cfg.oracle_max_error`` on ``model.eval_background``
    (every pixel, background included); the prior goes to the other pixels with a reliable neighbour."""
    pseudo_idx = np.asarray(pseudo_idx, dtype=np.int64).reshape(-1)
    c2w = np.asarray(scene.c2w[pseudo_idx], dtype=np.float64)
    intr = tuple(scene.intrinsics_all[i] for i in pseudo_idx)
    pseudo = render_views(teacher, model, intr, c2w, occupancy=occupancy, device=device)
    truth = gt_reliable_mask(np.clip(pseudo["rgb"], 0.0, 1.0), known_images(scene, pseudo_idx, model),
                             cfg.oracle_max_error)
    weights = truth.astype(np.float32)
    everything = np.ones_like(truth)
    neighbour, has = prior_weights(truth, cfg.kernel_size, cfg.kernel_std)
    prior = (has & ~truth).astype(np.float32)
    empty = truth & _empty_pixels(pseudo["acc"], cfg.empty_opacity)
    return PseudoLabels(c2w=c2w, rgb=pseudo["rgb"], z_depth=pseudo["z_depth"], acc=pseudo["acc"],
                        similarity=weights.copy(), foreground=everything, tau=None, weights=weights,
                        prior=prior, neighbour=neighbour, empty=empty, intrinsics=intr)


def _features_device(scene, train_idx, device, echo) -> torch.device:
    """Where VGG-19 runs and labelling keeps its features: the fit's device, unless that is a GPU too small for
    the known views' and a pseudo view's features (:func:`~senerf.selftrain.features.features_fit_gpu`): then
    the host, said in one line."""
    device = torch.device(device)
    if device.type != "cuda":
        return device
    index = torch.cuda.current_device() if device.index is None else device.index
    gpu = torch.cuda.get_device_properties(index).total_memory
    if features_fit_gpu(scene.size, len(train_idx), gpu):
        return device
    echo(f"selftrain: VGG-19 features of {len(train_idx)} known views at {scene.size[1]}x{scene.size[0]} and their "
         f"lookups take more than half of the GPU's {gpu / 2**30:.0f} GiB: computed and looked up on the host")
    return torch.device("cpu")


def _pseudo_rays(labels: PseudoLabels, model, device, q: int) -> PseudoRays:
    rays = camera_rays(labels.intrinsics, labels.c2w, model, device)
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32, device=device)  # noqa: E731
    n = labels.weights.size
    empty = torch.as_tensor(np.ascontiguousarray(labels.empty.reshape(-1)), device=device)
    return PseudoRays(rays["origins"], rays["dirs"], rays["near"], rays["far"], tuple(labels.weights.shape),
                      t(labels.weights.reshape(-1)), t(labels.prior.reshape(-1)),
                      t(labels.neighbour.reshape(n, -1)), q=q, empty=empty)


def _write_pseudo_pngs(folder: Path, labels: PseudoLabels) -> None:
    for i in range(labels.c2w.shape[0]):
        write_png(folder / f"rgb_{i:03d}.png", np.clip(labels.rgb[i], 0.0, 1.0))
        sim = np.clip(labels.similarity[i], 0.0, 1.0)
        write_png(folder / f"similarity_{i:03d}.png", np.repeat(sim[..., None], 3, axis=-1))
        mask = np.zeros(labels.similarity[i].shape + (3,), np.float32)
        mask[~labels.foreground[i]] = 0.5
        mask[labels.prior[i] > 0] = (0.2, 0.4, 1.0)
        w = labels.weights[i][..., None]
        mask = np.where(labels.weights[i][..., None] > 0, w * 1.0 + (1 - w) * mask, mask)
        write_png(folder / f"mask_{i:03d}.png", mask)


def _sample_pseudo_poses(scene, train_idx, cfg: SelfTrainConfig, iteration: int):
    """The pseudo cameras of ``iteration``: ``(c2w (P, 4, 4) float64, intrinsics (P,) tuple)``.

    Each pseudo view is its source input view carried rigidly (``sample_pseudo_views``) and keeps that view's
    intrinsics (``camera_rays`` and ``render_views`` cast equal ones exactly as one shared ``Intrinsics``).
    """
    rng = np.random.default_rng([cfg.seed, iteration])
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    known_c2w = np.asarray(scene.c2w[train_idx], dtype=np.float64)
    c2w, source = geometry.sample_pseudo_views(known_c2w, cfg.pseudo_range(iteration),
                                               cfg.n_pseudo_per_input * known_c2w.shape[0], rng)
    return (np.asarray(c2w, dtype=np.float64),
            tuple(scene.intrinsics_all[int(train_idx[s])] for s in source))


def pseudo_view_centre_problem(scene, train_idx) -> str | None:
    """Why pseudo views cannot be sampled around the training views, or None when they can.

    :func:`senerf.geometry.sample_pseudo_views` turns each training camera about the point the training views'
    optical axes pass closest to (:func:`senerf.geometry.closest_point_to_axes`), measuring azimuth about the
    views' common up axis (:func:`senerf.geometry.default_up`); one view, or views whose axes are all parallel,
    have no such point.  Checked before any training by sampling the pseudo views at offset 0 (the oracle, which
    takes held-out dataset views instead, needs neither).

    Args:
        scene: anything with ``c2w`` ``(n_images, 4, 4)`` (a :class:`senerf.data.Scene`).
        train_idx: ``(m,)`` training view indices into it.

    Returns:
        One line saying what is wrong and what to do, or None.
    """
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    c2w = np.asarray(scene.c2w[train_idx], dtype=np.float64)
    advice = ("train on 2 or more views that look at the scene from different directions, or fit the baseline "
              "alone (--iterations 0)")
    try:
        geometry.closest_point_to_axes(c2w)
    except ValueError:
        views = ("1 training view has" if train_idx.size == 1 else
                 f"the {train_idx.size} training views' axes are all parallel, so they have")
        return (f"self-training turns its pseudo views about the point the training views' optical axes pass "
                f"closest to, and {views} no such point; {advice}")
    try:
        geometry.sample_pseudo_views(c2w, 0.0, c2w.shape[0], np.random.default_rng(0))
    except ValueError as exc:
        return f"self-training cannot place pseudo views around the {train_idx.size} training views ({exc}); {advice}"
    return None


def _labels_text(labels: PseudoLabels, cfg: SelfTrainConfig) -> str:
    """What the labelling found, for the iteration's line: the threshold, the reliable share of the pseudo views'
    foreground and the share the prior covers (``prior off`` without it); without foreground, says so."""
    if not labels.foreground.any():
        return (f"no foreground in them (the teacher renders every pixel below opacity {cfg.opacity_threshold:g}): "
                "no colour, density or prior labels, only empty space")
    tau = ("oracle" if cfg.reliability == "oracle" else "soft" if labels.tau is None else f"{labels.tau:.3f}")
    use_prior = cfg.prior and cfg.lambda_prior > 0
    prior = (f"prior on {100 * float(labels.prior[labels.foreground].mean()):.1f} %" if use_prior else "prior off")
    return f"tau {tau}, reliable {100 * labels.reliable_fraction:.1f} % of foreground, {prior}"


def _selftrain_identity(selftrain: dict) -> dict:
    """The self-training settings as the resume fingerprint sees them: settings added later are written the
    way earlier versions recorded the same behaviour (``batch_empty = 0`` did not exist; ``student_grid``
    'teacher' / 'none' was ``skip_empty`` True / False), so run folders made before they existed resume."""
    out = dict(selftrain)
    if out.get("batch_empty") == 0:
        del out["batch_empty"]
    legacy = {"teacher": True, "none": False}
    if out.get("student_grid") in legacy:
        out["skip_empty"] = legacy[out.pop("student_grid")]
    return out


_VOLATILE = ("iterations", "device", "checkpoint_every")  # may change between a run and its resume

# settings added after the checkpoint started recording its settings (``settings_json``): dotted name ->
# the value that reproduces the behaviour before the setting existed (see ``settings_differences``)
_ADDED_SETTINGS: dict = {}


def _run_settings(config: dict, scene_name: str, train_idx: np.ndarray, test_idx: np.ndarray, size: tuple) -> dict:
    """What must match for a run folder to resume: the run's ``config`` less what may change on resume
    (the iteration count, the device, the checkpoint interval), the scene, the views and the image size."""
    return dict(
        config={name: ({k: v for k, v in part.items() if k not in _VOLATILE} if isinstance(part, dict) else part)
                for name, part in config.items()},
        scene=scene_name, train=np.asarray(train_idx).tolist(), test=np.asarray(test_idx).tolist(),
        size=list(size))


def _run_fingerprints(settings: dict) -> tuple[str, str]:
    """The resume fingerprints of checkpoints written before ``settings_json`` (they hold only a hash of
    :func:`_run_settings`): ``(mapped, as_is)``.

    The mapped one sees the self-training settings through :func:`_selftrain_identity` (as versions before
    ``batch_empty`` / ``student_grid`` recorded the same behaviour); the other sees them as they are (as the
    versions between those settings' introduction and that mapping, commits 2af0d7f-4f7b14e, recorded
    them), so run folders of both kinds resume.
    """
    def fingerprint(selftrain: dict) -> str:
        return _fingerprint({**settings, "config": {**settings["config"], "selftrain": selftrain}})

    selftrain = settings["config"]["selftrain"]
    return fingerprint(_selftrain_identity(selftrain)), fingerprint(selftrain)


def _fingerprint(record: dict) -> str:
    return hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _save_teacher(path: Path, field, occupancy, iteration: int, settings: dict, iterations: list) -> None:
    """The finished iteration's field (+ grid), its run's settings and the metrics rows up to it, in one
    atomic file."""
    state = dict(format=_CKPT_FORMAT, iteration=int(iteration), settings_json=json.dumps(settings, sort_keys=True),
                 field=field.state_dict(), iterations_json=json.dumps(iterations))
    if occupancy is not None:
        state["occupancy"] = occupancy.state_dict()
    save_checkpoint(path, state)


def _n_views_as_recorded(settings):
    """``settings`` with ``config.n_views`` at its protocol's default as None (:func:`explicit_n_views`): folders
    written before senerf-fit recorded it so resume with or without ``--n-views`` at its default."""
    config = settings.get("config") if isinstance(settings, dict) else None
    if not isinstance(config, dict) or "n_views" not in config:
        return settings
    return {**settings, "config": {**config, "n_views": explicit_n_views(config.get("protocol"), config["n_views"])}}


def _check_settings(path: Path, state: dict, settings: dict) -> None:
    """Refuse a teacher checkpoint of another run, naming the first setting that differs (checkpoints from
    before ``settings_json`` are matched by fingerprint and cannot name it)."""
    hint = "use --overwrite or another --out"
    if state.get("format") != _CKPT_FORMAT:
        raise InputError(f"output folder holds a checkpoint of another format; {hint}", file=path)
    if "settings_json" in state:
        diffs = settings_differences(_n_views_as_recorded(json.loads(state["settings_json"])),
                                     _n_views_as_recorded(settings), _ADDED_SETTINGS)
        if diffs:
            raise InputError(f"output folder holds a run with different settings ({differences_text(diffs)}); "
                             f"{hint}", file=path)
    elif state.get("fingerprint") not in _old_fingerprints(settings):
        raise InputError(f"output folder holds a run with different settings; {hint}", file=path)


def _old_fingerprints(settings: dict) -> tuple[str, ...]:
    """:func:`_run_fingerprints` of ``settings``, and, where ``config.n_views`` is recorded as not given, of the
    same settings with the protocol's default count (what ``--n-views`` at its default hashed before)."""
    fingerprints, config = _run_fingerprints(settings), settings["config"]   # this run's: built by _run_settings
    default = DEFAULT_N_VIEWS.get(config.get("protocol"))
    if "n_views" in config and config["n_views"] is None and default is not None:
        fingerprints += _run_fingerprints({**settings, "config": {**config, "n_views": default}})
    return fingerprints


def _check_scene_files(record: Path, now: dict | None) -> None:
    """Refuse a run folder whose run read other bytes from the scene's files than ``now`` (named, as
    senerf-fit names them); a folder without ``record`` (made before it was written) cannot tell."""
    if now is None or not record.is_file():
        return
    try:
        then = json.loads(record.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        then = None
    if not isinstance(then, dict):
        raise InputError("is not a scene-files record of senerf; use --overwrite or another --out", file=record)
    lines = changed_files(then, now)
    if lines:
        raise InputError(f"holds a different run (scene files differ: {differences_text(lines)}); use --overwrite "
                         f"or another --out", file=record.parent.parent)


def _record_scene_files(record: Path, now: dict | None) -> None:
    if now is not None and not record.is_file():
        atomic_write_text(record, json.dumps(now, indent=1, sort_keys=True))


def _load_teacher(path: Path, model, cfg_train, settings: dict, device):
    state = load_checkpoint(path, map_location=device)
    _check_settings(path, state, settings)
    iteration = int(state["iteration"])
    field = build_field(model, seed=cfg_train.seed, steps=cfg_train.steps).to(device)
    load_state_keeping_box(field, state["field"])   # a NeRF field's annealing weights included, as trained
    field.eval()
    occupancy = make_occupancy(model, device)
    if occupancy is not None and "occupancy" in state:
        load_state_keeping_box(occupancy, state["occupancy"])
    return field, occupancy, iteration, json.loads(state.get("iterations_json", "[]"))


def _remove_iteration_records(ckpt_dir: Path, k: int) -> None:
    """Delete iteration ``k``'s evaluation and labelling records (once ``metrics.json`` holds the iteration)."""
    (ckpt_dir / f"iter_{k}_eval.json").unlink(missing_ok=True)
    shutil.rmtree(ckpt_dir / f"iter_{k}_labels", ignore_errors=True)


def _started(out: Path, ckpt_dir: Path, k: int) -> bool:
    """True when iteration ``k`` left work behind (its folder, its training checkpoint or labelling record)."""
    return any(p.exists() for p in (out / f"iter_{k}", ckpt_dir / f"iter_{k}_train.pt", ckpt_dir / f"iter_{k}_labels"))


def run_selftraining(scene, train_idx, test_idx, model, train_cfg, cfg: SelfTrainConfig, out_dir,
                     student_cfg=None, command: list | None = None, extra_config: dict | None = None,
                     progress: bool = True, echo: Callable[[str], None] = print,
                     scene_files: dict | None = None) -> dict:
    """Baseline teacher + ``cfg.iterations`` self-training iterations, with outputs and resume.

    Args:
        scene: the :class:`senerf.data.Scene`.
        train_idx: (m,) known (training) view indices; test_idx: (t,) evaluation view indices.
        model: :class:`senerf.train.ModelConfig` (from ``choose_model``).
        train_cfg: :class:`senerf.train.TrainConfig` of the baseline teacher (iteration 0).
        cfg: :class:`SelfTrainConfig`.
        out_dir: output folder (created; an existing run with the same settings is resumed).
        student_cfg: TrainConfig of the students (default ``train_cfg``).
        command: argv recorded in ``metrics.json``.
        extra_config: more settings to record under ``config`` (e.g. the CLI's preset).
        progress: tqdm bars; echo: where one-line status messages go.
        scene_files: the scene files' digests (:func:`senerf.data.scene_file_digests` of the files the run reads)
            when the caller has them (senerf-fit, from its run.json); computed here otherwise.
    Returns:
        the ``metrics.json`` dict (DESIGN.md contract).

    Raises:
        InputError: before anything is trained, when ``test_idx`` is empty, when pseudo views cannot be sampled
            around the training views (:func:`pseudo_view_centre_problem`), or when one view's features would not
            fit in memory (:func:`senerf.selftrain.features_memory_problem`).
    """
    from ..train import RayBatchSource

    t_run = time.perf_counter()
    out = Path(out_dir)
    student_cfg = student_cfg or train_cfg
    device = torch.device(train_cfg.device)
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    if np.asarray(test_idx).size == 0:   # every iteration is scored on them: refused before any training
        raise InputError("no test views to score the iterations on", field="test_idx")
    problem = (pseudo_view_centre_problem(scene, train_idx) if cfg.iterations > 0 and cfg.reliability != "oracle"
               else None)
    if problem is not None:
        raise InputError(problem, field="train_idx")
    problem = (features_memory_problem(cfg.features, scene.size) if cfg.iterations > 0 and cfg.reliability != "oracle"
               else None)
    if problem is not None:
        raise InputError(problem, field="cfg.features")
    test_idx = np.asarray(test_idx, dtype=np.int64).reshape(-1)
    config = dict(train=config_to_dict(train_cfg), student=config_to_dict(student_cfg),
                  model=config_to_dict(model), selftrain=config_to_dict(cfg), **(extra_config or {}))
    h, w = scene.intrinsics.size
    settings = _run_settings(config, scene.name, train_idx, test_idx, (h, w))
    metrics = metrics_document(scene, train_idx, test_idx, command, config)
    ckpt_dir = out / "checkpoints"
    teacher_path = ckpt_dir / "teacher.pt"
    metrics_path = out / "metrics.json"
    files_record = ckpt_dir / _FILES_RECORD
    files_now = (scene_files if scene_files is not None else
                 run_file_digests(scene, train_idx, test_idx, oracle=cfg.reliability == "oracle", missing_ok=True))
    teacher, occupancy, start = None, None, 0
    seconds_before = 0.0
    if teacher_path.exists():
        teacher, occupancy, done, rows = _load_teacher(teacher_path, model, train_cfg, settings, device)
        _check_scene_files(files_record, files_now)   # after the settings: those are named first, as senerf-fit does
        metrics["iterations"] = [it for it in rows if it["iteration"] <= done]
        seconds_before = float(sum(it.get("seconds", 0.0) for it in metrics["iterations"]))
        start = done + 1
        for k in range(start):   # a kill between metrics.json and the records' removal left them behind
            _remove_iteration_records(ckpt_dir, k)
        if done >= cfg.iterations:   # finished (perhaps beyond what is asked now): reported as it is, untouched
            echo(f"selftrain: {out} holds iterations 0-{done} already ({cfg.iterations} asked for); nothing to train")
            if _started(out, ckpt_dir, done + 1):
                echo(f"selftrain: iteration {done + 1} was started and is kept; --iterations {done + 1} goes on "
                     "with it")
            stored = finished_metrics(out, done)   # None: killed before its metrics.json, rebuilt below
            if stored is not None:
                return stored
        else:
            echo(f"selftrain: resuming after iteration {done} from {teacher_path}")
            line = resume_host_line(metrics["iterations"][-1].get("host"), device, f"selftrain: iteration {done} ran")
            if line:
                echo(line)
    else:
        _check_scene_files(files_record, files_now)
        if not any(ckpt_dir.glob("*.pt")):   # a fresh run (a folder of an older one records them with its teacher)
            _record_scene_files(files_record, files_now)
    rays = RayBatchSource.from_scene(scene, train_idx, model, device)
    extractor = None
    known_feats = None   # the known views' features: computed once per run, when a view is first labelled
    carried = 0.0  # training and evaluation seconds of interrupted earlier calls, from what they recorded
    for k in range(start, cfg.iterations + 1):
        t_it = time.perf_counter()
        reliable_fraction = None
        labelled_before = 0.0   # seconds of pseudo views labelled by an interrupted earlier call
        label_dir = ckpt_dir / f"iter_{k}_labels"
        tcfg = train_cfg if k == 0 else student_cfg
        # a fresh field (not a copy of the teacher) from the same initialisation seed in every iteration:
        # on 3 views the initialisation alone moved test PSNR by 1 dB (lego Extreme, 200 steps, seeds 0
        # and 1), so this keeps iteration-to-iteration differences about distillation
        field = build_field(model, seed=tcfg.seed, steps=tcfg.steps)
        extra = None
        if k > 0:
            if cfg.reliability == "features":   # the seconds before the labels' line below, said
                found = len(list(label_dir.glob("view_*.npz"))) if label_dir.is_dir() else 0
                echo(f"selftrain: iteration {k}: labelling {cfg.n_pseudo_per_input * train_idx.size} pseudo views "
                     f"(teacher renders, {cfg.features} features, reprojection into {train_idx.size} known views)"
                     + (f"; {found} labelled by an interrupted run found in {label_dir}" if found else ""))
            if extractor is None and cfg.reliability == "features":
                extractor = make_feature_extractor(cfg.features, **(
                    {"normalize_layers": cfg.normalize_layers, "device": _features_device(scene, train_idx, device,
                                                                                       echo)}
                    if cfg.features == "vgg19" else {}))
                known_feats = functools.cache(
                    lambda: known_view_features(extractor, known_images(scene, train_idx, model)))
            if cfg.reliability == "oracle":
                pseudo_idx = dataset_pseudo_views(scene, train_idx, test_idx, cfg.pseudo_range(k),
                                                  cfg.n_pseudo_per_input * train_idx.size)
                labels = oracle_reliability(teacher, occupancy, model, scene, pseudo_idx, cfg, device=device)
                pseudo_c2w = labels.c2w
            else:
                pseudo_c2w, pseudo_k = _sample_pseudo_poses(scene, train_idx, cfg, k)
                labels = estimate_reliability(
                    teacher, occupancy, model, scene, train_idx, pseudo_c2w, extractor, cfg, cfg.alpha(k),
                    known_features=known_feats,
                    device=device, pseudo_intrinsics=pseudo_k, progress=progress,
                    resume=label_dir)
            reliable_fraction = labels.reliable_fraction
            labelled_before = labels.seconds_recorded
            _write_pseudo_pngs(out / f"iter_{k}" / "pseudo", labels)
            kept = f" ({labels.views_recorded} read back, not labelled again)" if labels.views_recorded else ""
            echo(f"selftrain: iteration {k}: {pseudo_c2w.shape[0]} pseudo views within "
                 f"{cfg.pseudo_range(k):g} deg{kept}, {_labels_text(labels, cfg)}")
            pseudo = _pseudo_rays(labels, model, device, cfg.kernel_size)
            extra = DistillationLoss(teacher, pseudo, cfg, model.n_samples,
                                     model.train_background, teacher_occupancy=occupancy)
        result = train_field(field, rays, tcfg, extra_loss=extra, checkpoint=ckpt_dir / f"iter_{k}_train.pt",
                             progress=progress)
        teacher, occupancy = result.field, result.occupancy
        carried += result.seconds_before
        teacher.eval()
        eval_record = ckpt_dir / f"iter_{k}_eval.json"
        ev = evaluate(teacher, scene, test_idx, out / f"iter_{k}" / "test", model, occupancy=occupancy,
                      device=device, progress=progress, resume=eval_record)
        carried += ev["seconds_before"] + labelled_before
        rf = None if reliable_fraction is None or math.isnan(reliable_fraction) else float(reliable_fraction)
        metrics["iterations"].append(iteration_row(
            k, ev, rf, time.perf_counter() - t_it + result.seconds_before + ev["seconds_before"] + labelled_before,
            device))
        _save_teacher(teacher_path, teacher, occupancy, k, settings, metrics["iterations"])
        _record_scene_files(files_record, files_now)
        metrics["seconds_total"] = seconds_before + carried + time.perf_counter() - t_run
        atomic_write_text(metrics_path, json.dumps(metrics, indent=1))
        _remove_iteration_records(ckpt_dir, k)
        echo(f"selftrain: iteration {k}: test PSNR {ev['psnr']:.2f} dB, SSIM {ev['ssim']:.3f}")
    metrics["seconds_total"] = seconds_before + carried + time.perf_counter() - t_run
    atomic_write_text(metrics_path, json.dumps(metrics, indent=1))
    return metrics
