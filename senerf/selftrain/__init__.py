"""Self-training (SE-NeRF): reliability estimation, reliability-based distillation, the teacher-student loop.

Public API (see DESIGN.md):

* features: :class:`FeatureExtractor`, :class:`VGG19Features` ('vgg19'), :class:`DaisyFeatures` ('daisy'),
  :func:`make_feature_extractor`, :class:`LazyViewFeatures`, :func:`known_view_features` (eager or lazy
  by the memory they take);
* reliability: :func:`view_similarity`, :func:`adaptive_threshold`, :func:`resolve_threshold`,
  :func:`threshold_weights`, :func:`gt_reliable_mask`, :func:`mask_quality`;
* distillation: :class:`DistillConfig`, :func:`gaussian_kernel`, :func:`prior_weights`,
  :func:`gaussian_prior`, :class:`PseudoRays`, :class:`DistillationLoss`;
* the loop: :class:`SelfTrainConfig`, :func:`run_selftraining`, :func:`pseudo_view_centre_problem` (why the
  training views leave the pseudo views no centre, checked before training), :func:`estimate_reliability`,
  :func:`reliability_mask_quality` (masks vs ground-truth colour at held-out poses).
"""

from .controller import (RELIABILITY_KINDS, PseudoLabels, SelfTrainConfig, dataset_pseudo_views, estimate_reliability,
                         known_images, oracle_reliability, pseudo_view_centre_problem, reliability_mask_quality,
                         run_selftraining)
from .distill import (DistillationLoss, DistillConfig, DistillConfigError, PseudoRays, bins_with_fractions,
                      gaussian_kernel, gaussian_prior, neighbour_offsets, prior_weights, unified_prior_weights)
from .features import (FEATURE_CHANNELS, DaisyFeatures, FeatureExtractor, LazyViewFeatures, VGG19Features,
                       features_fit_gpu, features_memory_problem, features_on_device, known_view_features,
                       make_feature_extractor)
from .reliability import (NO_MATCH, ViewSimilarity, adaptive_threshold, bilinear_sample, cosine_similarity,
                          gt_reliable_mask, mask_quality, resolve_threshold, threshold_weights, view_similarity)

__all__ = [
    "FeatureExtractor", "VGG19Features", "DaisyFeatures", "make_feature_extractor", "LazyViewFeatures",
    "known_view_features", "features_on_device", "features_fit_gpu", "FEATURE_CHANNELS", "features_memory_problem",
    "NO_MATCH", "ViewSimilarity", "bilinear_sample", "cosine_similarity", "view_similarity",
    "adaptive_threshold", "resolve_threshold", "threshold_weights", "gt_reliable_mask", "mask_quality",
    "DistillConfig", "DistillConfigError", "gaussian_kernel", "neighbour_offsets", "prior_weights",
    "unified_prior_weights", "gaussian_prior", "bins_with_fractions", "PseudoRays", "DistillationLoss",
    "SelfTrainConfig", "PseudoLabels", "run_selftraining", "estimate_reliability", "known_images",
    "reliability_mask_quality", "dataset_pseudo_views", "oracle_reliability", "RELIABILITY_KINDS",
    "pseudo_view_centre_problem",
]
