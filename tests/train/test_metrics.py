"""PSNR and SSIM (senerf/train/metrics.py) against hand-computed values and an independent SSIM (SciPy's Gaussian
filter)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from senerf.train.metrics import mse, psnr, ssim


def _ssim_reference(a: np.ndarray, b: np.ndarray) -> float:
    """Wang et al. SSIM with a Gaussian window (sigma 1.5, truncated at 3.5 sigma: 11x11), population
    statistics, C1 = (0.01)^2, C2 = (0.03)^2, mean over the valid (uncropped by 5 px) region and channels."""
    c1, c2 = 0.01**2, 0.03**2
    vals = []
    for ch in range(a.shape[-1]):
        x, y = a[..., ch].astype(np.float64), b[..., ch].astype(np.float64)
        f = lambda z: gaussian_filter(z, sigma=1.5, truncate=3.5)  # noqa: E731
        mx, my = f(x), f(y)
        vx, vy, cxy = f(x * x) - mx * mx, f(y * y) - my * my, f(x * y) - mx * my
        s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
        vals.append(s[5:-5, 5:-5].mean())
    return float(np.mean(vals))


def test_psnr_golden_values():
    a = np.zeros((8, 8, 3), np.float32)
    assert psnr(a, a + 0.1) == pytest.approx(20.0, abs=1e-5)  # MSE 0.01 -> 10 log10(100)
    b = a.copy()
    b[:4] = 0.2  # half the pixels off by 0.2: MSE 0.02
    assert mse(a, b) == pytest.approx(0.02, rel=1e-6)
    assert psnr(a, b) == pytest.approx(10 * math.log10(50.0), abs=1e-5)
    assert psnr(a, a) == math.inf


def test_ssim_identical_is_one_and_constant_images_by_hand():
    rng = np.random.default_rng(0)
    img = rng.random((20, 24, 3)).astype(np.float32)
    assert ssim(img, img) == pytest.approx(1.0, abs=1e-12)
    # constant images: variances/covariance are 0, SSIM = (2 a b + C1) / (a^2 + b^2 + C1)
    a, b = np.full((16, 16, 3), 0.5), np.full((16, 16, 3), 0.25)
    c1 = 1e-4
    assert ssim(a, b) == pytest.approx((2 * 0.5 * 0.25 + c1) / (0.25 + 0.0625 + c1), abs=1e-9)


def test_ssim_matches_independent_gaussian_implementation():
    rng = np.random.default_rng(1)
    a = rng.random((40, 33, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    ours = ssim(a, b)
    assert 0.3 < ours < 0.99
    assert ours == pytest.approx(_ssim_reference(a, b), abs=1e-6)


def test_ssim_refuses_images_smaller_than_its_window():
    # skimage's Gaussian window (sigma 1.5, truncated at 3.5 sigma) is 2 * int(3.5 * 1.5 + 0.5) + 1 = 11 wide:
    # 10 px is refused by our check (not skimage's own error), 11 px works
    for shape in [(5, 5, 3), (10, 12, 3), (12, 10)]:
        with pytest.raises(ValueError, match="11"):
            ssim(np.zeros(shape), np.zeros(shape))
    assert ssim(np.full((11, 11, 3), 0.5), np.full((11, 11, 3), 0.5)) == pytest.approx(1.0)


@pytest.mark.parametrize("metric", [mse, psnr, ssim])
def test_metrics_take_h_w_or_h_w_1_or_3_and_refuse_other_shapes(metric):
    # Catches: the image-shape check deleted (or one of its channel counts changed), two images of different
    # shapes compared by broadcasting.
    for shape in [(11,), (11, 11, 2), (11, 11, 4), (1, 11, 11, 3)]:
        with pytest.raises(ValueError):
            metric(np.zeros(shape), np.zeros(shape))
    with pytest.raises(ValueError):
        metric(np.zeros((11, 11, 3)), np.zeros((11, 12, 3)))
    for shape in [(11, 11), (11, 11, 1), (11, 11, 3)]:
        a, b = np.zeros(shape), np.full(shape, 0.5)
        want = {mse: 0.25, psnr: 10 * np.log10(4), ssim: (0.0 + 1e-4) / (0.25 + 1e-4)}[metric]
        assert metric(a, b) == pytest.approx(want, rel=1e-9)


def test_psnr_and_ssim_honour_data_range():
    # Catches: PSNR with data_range instead of data_range^2 in the numerator, SSIM ignoring data_range
    # (skimage's C1, C2 scale with it).  Images in [0, 255] with data_range 255 score exactly as the same
    # images in [0, 1] with data_range 1: PSNR of a 0.1 (25.5) offset = 10 log10(1 / 0.01) = 20 dB.
    rng = np.random.default_rng(2)
    a = rng.random((16, 16, 3))
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    assert psnr(255 * a, 255 * (a + 0.1), data_range=255.0) == pytest.approx(20.0, abs=1e-9)
    assert psnr(255 * a, 255 * b, data_range=255.0) == pytest.approx(psnr(a, b), abs=1e-9)
    assert ssim(255 * a, 255 * b, data_range=255.0) == pytest.approx(ssim(a, b), abs=1e-9)
    assert ssim(255 * a, 255 * b, data_range=255.0) == pytest.approx(_ssim_reference(a, b), abs=1e-6)
