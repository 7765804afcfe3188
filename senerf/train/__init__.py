"""Training, evaluation and checkpointing of one radiance field (torch): the public API is ``__all__`` (grouped
by module, DESIGN.md); the configurations live in :mod:`senerf.config`.
"""

from .checkpoint import load_checkpoint, load_field, save_checkpoint
from .evaluate import depth_to_color, eval_images, evaluate, render_views, write_png
from .loop import TrainResult, background_color, lr_factor, make_occupancy, train_field
from .metrics import LPIPS_UNAVAILABLE, mse, psnr, ssim
from .model import (NDC_AABB, NERF_FREQS, NERF_HIDDEN, NERF_LAYERS, build_field, camera_aabb, choose_model,
                    nerf_description)
from .rays import RayBatchSource, camera_rays, per_view_intrinsics, ray_aabb_bounds, ray_dist_to_z_depth
from .record import PHASES, host_record, iteration_row, metrics_document, phase_breakdown, timed

__all__ = [
    "choose_model", "build_field", "camera_aabb", "nerf_description", "NDC_AABB", "NERF_FREQS", "NERF_HIDDEN",
    "NERF_LAYERS",
    "RayBatchSource", "camera_rays", "per_view_intrinsics", "ray_aabb_bounds", "ray_dist_to_z_depth",
    "train_field", "TrainResult", "lr_factor", "make_occupancy", "background_color",
    "evaluate", "eval_images", "render_views", "depth_to_color", "write_png",
    "psnr", "ssim", "mse", "LPIPS_UNAVAILABLE",
    "save_checkpoint", "load_checkpoint", "load_field",
    "metrics_document", "iteration_row", "host_record", "timed", "PHASES", "phase_breakdown",
]
