"""Self-training (SE-NeRF): reliability estimation, reliability-based distillation, the teacher-student loop
(:func:`run_selftraining`, settings in :class:`senerf.config.SelfTrainConfig`; one iteration in DESIGN.md).
"""

from .distill import (DistillationLoss, PseudoRays, gaussian_kernel, neighbour_offsets,
                      prior_weights, unified_prior_weights)
from .features import (LazyViewFeatures, VGG19Features, features_device, features_memory_problem, features_on_device,
                       known_view_features)
from .labels import (PseudoLabels, dataset_pseudo_views, estimate_reliability, known_images, pseudo_view_centre_problem,
                     reliability_mask_quality, sample_pseudo_cameras)
from .loop import run_selftraining
from .reliability import (NO_MATCH, ViewSimilarity, adaptive_threshold, bilinear_sample, cosine_similarity,
                          gt_reliable_mask, mask_quality, resolve_threshold, threshold_weights, view_similarity)

__all__ = [
    "VGG19Features", "LazyViewFeatures", "known_view_features", "features_on_device", "features_device",
    "features_memory_problem",
    "NO_MATCH", "ViewSimilarity", "bilinear_sample", "cosine_similarity", "view_similarity",
    "adaptive_threshold", "resolve_threshold", "threshold_weights", "gt_reliable_mask", "mask_quality",
    "gaussian_kernel", "neighbour_offsets", "prior_weights", "unified_prior_weights",
    "PseudoRays", "DistillationLoss",
    "PseudoLabels", "sample_pseudo_cameras", "estimate_reliability", "known_images", "dataset_pseudo_views",
    "reliability_mask_quality", "pseudo_view_centre_problem",
    "run_selftraining",
]
