"""Training, evaluation and checkpointing of one radiance field (torch).

Public API (see DESIGN.md): :class:`TrainConfig`, :class:`ModelConfig`, :func:`choose_model`,
:func:`build_field` (:func:`nerf_description`: what ``field='nerf'`` builds), :class:`RayBatchSource`,
:func:`train_field`, :func:`evaluate`, :func:`render_views`, :func:`psnr`, :func:`ssim`, :func:`save_checkpoint`,
:func:`load_checkpoint`; ``metrics.json``: :func:`metrics_document`, :func:`iteration_row`, :func:`host_record`,
:func:`host_change`, :func:`resume_host_line`, :func:`finished_metrics`.
"""

from .checkpoint import atomic_write_bytes, atomic_write_text, load_checkpoint, save_checkpoint
from .config import (NERF_FREQS, NERF_HIDDEN, NERF_LAYERS, PRESETS, ModelConfig, TrainConfig, build_field,
                     camera_aabb, choose_model, nerf_description, nerf_refusal,
                     config_to_dict, differences_text, preset_train_config,
                     settings_differences)
from .evaluate import depth_to_color, eval_images, evaluate, render_views, write_png
from .loop import TrainResult, background_color, load_state_keeping_box, lr_factor, make_occupancy, train_field
from .metrics import LPIPS_UNAVAILABLE, mse, psnr, ssim
from .record import finished_metrics, host_change, host_record, iteration_row, metrics_document, resume_host_line
from .rays import RayBatchSource, camera_rays, per_view_intrinsics, ray_aabb_bounds, ray_dist_to_z_depth

__all__ = [
    "TrainConfig", "ModelConfig", "PRESETS", "preset_train_config", "choose_model", "build_field",
    "nerf_description", "nerf_refusal",
    "NERF_FREQS", "NERF_HIDDEN", "NERF_LAYERS",
    "camera_aabb", "config_to_dict", "settings_differences", "differences_text",
    "RayBatchSource", "camera_rays", "per_view_intrinsics", "ray_aabb_bounds", "ray_dist_to_z_depth",
    "train_field", "TrainResult", "lr_factor", "make_occupancy", "background_color", "load_state_keeping_box",
    "evaluate", "eval_images", "render_views", "depth_to_color", "write_png",
    "psnr", "ssim", "mse", "LPIPS_UNAVAILABLE",
    "save_checkpoint", "load_checkpoint", "atomic_write_bytes", "atomic_write_text",
    "metrics_document", "iteration_row", "host_record", "host_change", "resume_host_line", "finished_metrics",
]
