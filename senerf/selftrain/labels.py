"""Pseudo views and their labels (SE-NeRF, Section 3.2): the pseudo cameras, their teacher renders, every pixel's
reliability, and the student's pseudo rays.  Cameras are reached only through :mod:`senerf.geometry` and the
trainer's ``render_views`` / ``camera_rays``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import geometry
from ..config import SelfTrainConfig
from ..errors import InputError
from ..train import camera_rays, eval_images, render_views, timed, write_png
from .distill import PseudoRays, prior_weights, unified_prior_weights
from .features import features_on_device, known_view_features
from .reliability import gt_reliable_mask, mask_quality, resolve_threshold, threshold_weights, view_similarity

__all__ = ["PseudoLabels", "sample_pseudo_cameras", "estimate_reliability", "known_images", "dataset_pseudo_views",
           "reliability_mask_quality", "pseudo_rays", "write_pseudo_pngs", "labels_text", "pseudo_view_centre_problem"]


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
            ``SelfTrainConfig.empty_opacity``; all False when it is 0).  A subset of ``weights > 0``: they are
            distilled as the other reliable pixels, but are never the prior's neighbours (the prior spreads
            surface densities).
        intrinsics: the ``Intrinsics`` the views were rendered with: one shared, or a tuple of P.
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
                         cfg: SelfTrainConfig, alpha: float, known_features=None, device=None,
                         renders: tuple[dict, dict] | None = None, pseudo_intrinsics=None,
                         progress: bool = False, phases: dict | None = None) -> PseudoLabels:
    """Render ``pseudo_c2w (P, 4, 4)`` with the teacher and estimate every pixel's reliability.

    Each render's features are compared with those of the *real* known images where its pixels land
    (:func:`~senerf.selftrain.reliability.view_similarity`, the teacher's known-view z-depth as occlusion buffer);
    the threshold, the reliable weights and the prior's neighbour weights are then taken over all pseudo views.

    Args:
        teacher, occupancy: the teacher field and its occupancy grid (or None).
        scene, train_idx: the known views ``train_idx (m,)``.
        extractor: a :class:`~senerf.selftrain.features.VGG19Features`.
        cfg: thresholds, occlusion tolerance, kernel.
        alpha: the adaptive threshold's alpha for this iteration.
        known_features: (m, H, W, C) features of :func:`known_images` (an array, ``extractor.lazy(...)``, or a
            tensor on the extractor's GPU when :func:`~senerf.selftrain.features.features_on_device`); computed
            with :func:`~senerf.selftrain.features.known_view_features` when None.
        renders: ``(known, pseudo)`` teacher renders (``senerf.train.render_views`` dicts of the known and the
            pseudo cameras) to reuse; rendered when None (the pseudo views one at a time).
        pseudo_intrinsics: the pseudo cameras' ``Intrinsics`` (one, or a sequence of P); default image 0's.
            The known views always use their own (``scene.intrinsics_all``).
        progress: a tqdm bar over the pseudo views.
        phases: seconds spent are added to its ``pseudo_render``, ``features`` and ``reliability``
            (:func:`senerf.train.timed`).
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
    with timed(phases, "pseudo_render"):
        known = (renders[0] if renders is not None else
                 render_views(teacher, model, known_intr, known_c2w, occupancy=occupancy, device=device))
    # an unbounded scene has content in every pixel: no background to leave out and no empty space to label
    opacity, empty_opacity = (0.0, 0.0) if model.contract else (cfg.opacity_threshold, cfg.empty_opacity)
    known_z = np.where(known["acc"] >= opacity, known["z_depth"], np.inf)   # occlusion buffers
    if known_features is None:
        with timed(phases, "features"):
            known_features = known_view_features(extractor, known_images(scene, train_idx, model))
    extract = extractor.device_features if features_on_device(extractor) else extractor
    h, w = pseudo_k[0].size if n else (0, 0)
    views = dict(rgb=np.empty((n, h, w, 3), np.float32), z_depth=np.empty((n, h, w), np.float32),
                 acc=np.empty((n, h, w), np.float32), similarity=np.empty((n, h, w), np.float32),
                 foreground=np.empty((n, h, w), bool))
    todo = range(n)
    if progress:
        from tqdm.auto import tqdm

        todo = tqdm(todo, desc="labelling", unit="view", dynamic_ncols=True)
    for i in todo:
        with timed(phases, "pseudo_render"):
            if renders is None:
                view = {name: a[0] for name, a in render_views(teacher, model, pseudo_k[i], pseudo_c2w[i],
                                                               occupancy=occupancy, device=device).items()}
            else:
                view = {name: renders[1][name][i] for name in ("rgb", "z_depth", "acc")}
        with timed(phases, "features"):
            feats = extract(np.clip(view["rgb"][None], 0.0, 1.0))[0]
        with timed(phases, "reliability"):
            res = view_similarity(feats, view["z_depth"], view["acc"], pseudo_k[i], pseudo_c2w[i],
                                  known_features, known_z, known_intr, known_c2w,
                                  opacity_threshold=opacity, rel_tol=cfg.occlusion_rel_tol,
                                  foreground_only=True)
        view.update(similarity=res.similarity, foreground=res.foreground)
        for name, array in views.items():
            array[i] = view[name]
    with timed(phases, "reliability"):
        return _labels_from_views(views, pseudo_c2w, intr, cfg, alpha, empty_opacity)


def _labels_from_views(views: dict, pseudo_c2w: np.ndarray, intr, cfg: SelfTrainConfig,
                       alpha: float, empty_opacity: float) -> PseudoLabels:
    """:class:`PseudoLabels` from every pseudo view's render, similarity and foreground (``views``: the
    ``rgb, z_depth, acc, similarity, foreground``, each ``(P, H, W, ...)``): the threshold over all of them, the
    weights and the prior."""
    sims, fg, acc = views["similarity"], views["foreground"], views["acc"]
    tau = resolve_threshold(cfg.threshold, sims[fg], alpha=alpha, tau=cfg.fixed_tau)
    weights = threshold_weights(sims, fg, cfg.threshold, tau=tau, beta=cfg.beta)
    empty = _empty_pixels(acc, empty_opacity)
    weights = np.where(empty, np.float32(1.0), weights).astype(np.float32)
    if cfg.threshold == "unified":
        neighbour, has = unified_prior_weights(sims, fg, cfg.kernel_size, cfg.kernel_std)
        prior = np.where(fg & has, 1.0 - weights, 0.0).astype(np.float32)
    else:
        # the prior spreads reliable *surface* densities (the paper's depth-smoothness assumption); empty-space
        # rays are reliable too but would pull an object's edge pixels towards no density at all
        neighbour, has = prior_weights((weights > 0) & ~empty, cfg.kernel_size, cfg.kernel_std)
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
    """Held-out dataset views to use as pseudo views whose real photos are known (:func:`reliability_mask_quality`).

    Candidates are the scene's views outside ``train_idx`` and ``exclude_idx`` (the test views); each gets
    the angle between its optical axis and the nearest known view's (``geometry.nearest_view_angles``).
    The ``count`` nearest within ``max_angle_deg`` are returned; when fewer than ``count // 2`` lie within
    it, the nearest ``count // 2`` (at least 1) are taken regardless, so that an iteration has pseudo views.

    Args:
        scene: the :class:`senerf.data.Scene`; train_idx (m,), exclude_idx (k,): indices into it.
        max_angle_deg: the iteration's pseudo-view range.
    Returns:
        (P,) int64 scene indices, nearest first.
    """
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    taken = np.union1d(train_idx, np.asarray(exclude_idx, dtype=np.int64).reshape(-1))
    cand = np.setdiff1d(np.arange(scene.c2w.shape[0]), taken)
    if cand.size == 0:
        raise InputError("needs held-out views (not training, not test) with photos", field="views")
    c2w = np.asarray(scene.c2w, dtype=np.float64)
    angle = geometry.nearest_view_angles(c2w[train_idx], c2w[cand], center=None)
    order = np.argsort(angle, kind="stable")
    inside = order[angle[order] <= max_angle_deg][:count]
    if inside.size < max(1, count // 2):
        inside = order[:max(1, count // 2)]
    return cand[inside]


def pseudo_rays(labels: PseudoLabels, model, device, q: int) -> PseudoRays:
    """Every pixel of the labelled pseudo views as a ray of the model (``camera_rays``), with its reliable
    weight, prior weight and ``q x q`` neighbour weights, flattened over ``(P, H, W)``."""
    rays = camera_rays(labels.intrinsics, labels.c2w, model, device)
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32, device=device)  # noqa: E731
    n = labels.weights.size
    return PseudoRays(rays["origins"], rays["dirs"], rays["near"], rays["far"], tuple(labels.weights.shape),
                      t(labels.weights.reshape(-1)), t(labels.prior.reshape(-1)),
                      t(labels.neighbour.reshape(n, -1)), q=q)


def write_pseudo_pngs(folder: Path, labels: PseudoLabels) -> None:
    """``rgb_XXX.png`` (the teacher's render), ``similarity_XXX.png`` (the best feature similarity, clipped to
    [0, 1]) and ``mask_XXX.png`` (white reliable, blue unreliable with a prior target, black unreliable without
    one, grey background) of every pseudo view, into ``folder``."""
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


def sample_pseudo_cameras(scene, train_idx, cfg: SelfTrainConfig, iteration: int):
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
    have no such point.  Checked before any training by sampling the pseudo views at offset 0.

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


def labels_text(labels: PseudoLabels, cfg: SelfTrainConfig) -> str:
    """What the labelling found, for the iteration's line: the threshold, the reliable share of the pseudo views'
    foreground and the share the prior covers (``prior off`` without it); without foreground, says so."""
    if not labels.foreground.any():
        return (f"no foreground in them (the teacher renders every pixel below opacity {cfg.opacity_threshold:g}): "
                "no colour, density or prior labels, only empty space")
    tau = "soft" if labels.tau is None else f"{labels.tau:.3f}"
    use_prior = cfg.prior and cfg.lambda_prior > 0
    prior = (f"prior on {100 * float(labels.prior[labels.foreground].mean()):.1f} %" if use_prior else "prior off")
    return f"tau {tau}, reliable {100 * labels.reliable_fraction:.1f} % of foreground, {prior}"


