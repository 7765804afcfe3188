"""Tests of senerf/geometry/rays.py."""

import numpy as np
import pytest

from senerf.geometry import Intrinsics, look_at, pixel_centers, pixel_rays, project, rays_from_pixels

DTYPES = [np.float32, np.float64]


@pytest.mark.parametrize("dtype", DTYPES)
def test_pixel_rays_consistent_with_project(dtype):
    k = Intrinsics(40.0, 35.0, 12.3, 9.1, 24, 18)
    c2w = look_at([1.0, 2.0, -4.0], [0.0, 0.0, 0.5]).astype(dtype)
    o, d, zpd = pixel_rays(k, c2w)
    assert o.shape == d.shape == (18, 24, 3) and zpd.shape == (18, 24)
    assert o.dtype == d.dtype == zpd.dtype == dtype
    tol = 1e-12 if dtype == np.float64 else 1e-6
    np.testing.assert_allclose(np.linalg.norm(d.astype(np.float64), axis=-1), 1.0, atol=tol)
    ray_dist = np.linspace(0.5, 7.0, 18 * 24).reshape(18, 24).astype(dtype)
    pts = o + d * ray_dist[..., None]
    uv, z, ok = project(pts, k, c2w.astype(np.float64))
    assert ok.all()
    np.testing.assert_allclose(uv, pixel_centers(k), atol=1e-8 if dtype == np.float64 else 1e-3)
    np.testing.assert_allclose(z, ray_dist * zpd, rtol=1e-10 if dtype == np.float64 else 1e-5)


def test_centre_ray_and_corner_by_hand():
    # Pixel (0, 0) of a 2x2 image with f = 1, c = (1, 1): direction (-0.5, -0.5, 1) / sqrt(1.5).
    k = Intrinsics(1.0, 1.0, 1.0, 1.0, 2, 2)
    _, d, zpd = pixel_rays(k, np.eye(4))
    np.testing.assert_allclose(d[0, 0], np.array([-0.5, -0.5, 1.0]) / np.sqrt(1.5))
    np.testing.assert_allclose(zpd[0, 0], 1 / np.sqrt(1.5))


def test_rays_from_pixels_matches_pixel_rays_and_batches():
    k = Intrinsics(30.0, 30.0, 8.0, 6.0, 16, 12)
    c2w = look_at(np.array([[0.0, -3, 1], [2, 2, 2]]), np.zeros(3))
    o, d, zpd = pixel_rays(k, c2w)
    assert o.shape == (2, 12, 16, 3)
    o2, d2, zpd2 = rays_from_pixels(pixel_centers(k), k, c2w[:, None, None])
    np.testing.assert_allclose(d2, d, atol=1e-15)
    np.testing.assert_allclose(o2, o)
    np.testing.assert_allclose(zpd2, zpd)
    o3, d3, z3 = rays_from_pixels(np.array([8.0, 6.0], np.float32), k, np.eye(4))
    assert d3.dtype == np.float32 and d3.tolist() == [0.0, 0.0, 1.0] and float(z3) == 1.0


def test_width_or_height_one():
    for w, h in ((1, 5), (5, 1), (1, 1)):
        k = Intrinsics(10.0, 10.0, w / 2, h / 2, w, h)
        o, d, zpd = pixel_rays(k, np.eye(4))
        assert d.shape == (h, w, 3)
        uv, _, ok = project(o + 2 * d, k, np.eye(4))
        assert ok.all()
        np.testing.assert_allclose(uv, pixel_centers(k))


def test_rays_from_pixels_refuses_non_finite_points_and_names_clashing_batches():
    k = Intrinsics(100.0, 100.0, 2.0, 2.0, 4, 4)
    for bad in ([np.nan, 1.0], [1.0, np.inf]):
        with pytest.raises(ValueError, match="uv: image points must be finite"):
            rays_from_pixels(bad, k, np.eye(4))
    with pytest.raises(ValueError, match=r"batch shapes of uv \(7,\) and c2w \(5,\) do not broadcast"):
        rays_from_pixels(np.ones((7, 2)), k, np.stack([np.eye(4)] * 5))


def test_directions_stay_unit_where_their_squares_overflow():
    # a focal length of 1e-160 puts (u - cx) / fx near 1e160, whose square overflows. By hand, pixel (0, 0) of a
    # 2x2 image with cx = cy = 1:
    # d = (-0.5e160, -0.5e160, 1), |d| = 0.5e160 sqrt(2), so d / |d| = (-1/sqrt(2), -1/sqrt(2), 2e-160/sqrt(2))
    # and z_per_dist = 1 / |d| = 2e-160 / sqrt(2).
    o, d, zpd = pixel_rays(Intrinsics(1e-160, 1e-160, 1.0, 1.0, 2, 2), np.eye(4))
    assert np.allclose(d[0, 0, :2], [-2 ** -0.5, -2 ** -0.5], rtol=1e-15, atol=0)
    assert np.isclose(d[0, 0, 2], 2e-160 / 2 ** 0.5, rtol=1e-14, atol=0)
    assert np.isclose(zpd[0, 0], 2e-160 / 2 ** 0.5, rtol=1e-14, atol=0)
    assert np.allclose(np.linalg.norm(d, axis=-1), 1.0)
    _, d1, z1 = rays_from_pixels([1e160, 1.0], Intrinsics(1.0, 1.0, 1.0, 1.0, 2, 2), np.eye(4))
    assert np.allclose(d1, [1.0, 0.0, 1e-160], rtol=1e-12, atol=0) and np.isclose(z1, 1e-160, rtol=1e-12, atol=0)
