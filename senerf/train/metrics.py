"""Image metrics: PSNR and SSIM (scikit-image's Gaussian-window SSIM), on NumPy images in [0, 1].

LPIPS needs pretrained network weights that cannot be downloaded here, so it is reported as
``"unavailable"`` (never an invented value); so is the "Avg." metric that depends on it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["psnr", "ssim", "mse", "LPIPS_UNAVAILABLE"]

LPIPS_UNAVAILABLE = "unavailable"


def _pair(a, b) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[-1] not in (1, 3)):
        raise ValueError(f"expected (H, W) or (H, W, 3) images, got {a.shape}")
    return a, b


def mse(a, b) -> float:
    """Mean squared error of two images ``(H, W[, 3])``."""
    a, b = _pair(a, b)
    return float(np.mean((a - b) ** 2))


def psnr(a, b, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB, ``10 log10(data_range^2 / MSE)``; ``inf`` for identical images.

    Args:
        a, b: (H, W, 3) or (H, W) images.
        data_range: the value range of the images (1.0 for [0, 1]).
    """
    err = mse(a, b)
    if err == 0.0:
        return math.inf
    return float(10.0 * math.log10(data_range**2 / err))


#: Smallest image side :func:`ssim` accepts: skimage's Gaussian window at sigma 1.5 (truncated at 3.5 sigma)
#: is ``2 * int(3.5 * 1.5 + 0.5) + 1 = 11`` pixels wide.
SSIM_MIN_SIDE = 11


def ssim(a, b, data_range: float = 1.0) -> float:
    """Structural similarity as in ``skimage.metrics.structural_similarity(gaussian_weights=True,
    sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1)`` (the NeRF papers' SSIM).

    Args:
        a, b: (H, W, 3) or (H, W) images, at least ``SSIM_MIN_SIDE`` (11) pixels per side.
    """
    from skimage.metrics import structural_similarity

    a, b = _pair(a, b)
    if min(a.shape[:2]) < SSIM_MIN_SIDE:
        raise ValueError(f"SSIM needs images of at least {SSIM_MIN_SIDE}x{SSIM_MIN_SIDE} pixels, got {a.shape[:2]}")
    kwargs = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=data_range)
    if a.ndim == 3:
        kwargs["channel_axis"] = -1
    return float(structural_similarity(a, b, **kwargs))
