"""Tests of senerf/geometry/projection.py."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from senerf.geometry import Intrinsics, look_at, project, unproject

DTYPES = [np.float32, np.float64]
K_GOLD = Intrinsics(500.0, 500.0, 256.0, 256.0, 1024, 1024)


@pytest.mark.parametrize("dtype", DTYPES)
def test_golden_values(dtype):
    # In our convention cx is the principal point's coordinate in the pixel-centre-at-i+0.5 system.
    # (0,0,1): u = 500*0/1 + 256 = 256.  (1,2,2): u = 500*1/2 + 256 = 506, v = 500*2/2 + 256 = 756.
    # (0.1,0.1,-1) is behind the camera (a sign-unaware division would put it at (206, 206), inside the image).
    pts = np.array([[0, 0, 1], [1, 2, 2], [0.1, 0.1, -1]], dtype)
    uv, z, ok = project(pts, K_GOLD, np.eye(4))
    assert uv.dtype == dtype and z.dtype == dtype
    np.testing.assert_allclose(uv[:2], [[256, 256], [506, 756]])
    np.testing.assert_allclose(z[:2], [1, 2])
    assert ok.tolist() == [True, True, False]
    np.testing.assert_array_equal(uv[2], [-1, -1])
    assert z[2] == 0


@pytest.mark.parametrize("dtype", DTYPES)
def test_matches_cv2_project_points(dtype):
    rng = np.random.default_rng(0)
    k = Intrinsics(612.3, 580.1, 321.7, 239.2, 640, 480)
    c2w = look_at([1.0, -3.0, 0.5], [0.1, 0.2, -0.1], up=[0.0, 0.0, 1.0])
    pts = rng.normal(size=(2000, 3)) * 0.5
    uv, z, ok = project(pts.astype(dtype), k, c2w)
    w2c = np.linalg.inv(c2w)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    k_cv = k.K.copy()
    k_cv[:2, 2] -= 0.5  # OpenCV puts the centre of pixel 0 at 0.0
    uv_cv, _ = cv2.projectPoints(pts, rvec, w2c[:3, 3], k_cv, None)
    uv_cv = uv_cv[:, 0] + 0.5
    in_img = (uv_cv[:, 0] >= 0) & (uv_cv[:, 0] < 640) & (uv_cv[:, 1] >= 0) & (uv_cv[:, 1] < 480)
    assert ok.sum() > 1000
    np.testing.assert_array_equal(ok, in_img)
    tol = 1e-8 if dtype == np.float64 else 2e-3
    np.testing.assert_allclose(uv[ok], uv_cv[ok], atol=tol)
    np.testing.assert_allclose(z, np.where(ok, (pts @ w2c[:3, :3].T + w2c[:3, 3])[:, 2], 0), rtol=1e-6)


def test_image_bounds_are_half_open_and_near():
    k = Intrinsics(1.0, 1.0, 2.0, 1.5, 4, 3)  # image covers [0, 4) x [0, 3)
    # Points at z = 1 land at (x + 2, y + 1.5).
    pts = np.array([[-2, 0, 1], [1.999, 0, 1], [2, 0, 1], [0, -1.5, 1], [0, 1.5, 1], [0, 0, 1e-9], [0, 0, 0.0]])
    _, _, ok = project(pts, k, np.eye(4))
    assert ok.tolist() == [True, True, False, True, False, False, False]
    _, _, ok = project(np.array([[0.0, 0.0, 0.5]]), k, np.eye(4), near=0.5)
    assert not ok[0]


@pytest.mark.parametrize("dtype", DTYPES)
def test_non_finite_and_behind_never_leak_nan(dtype):
    non_finite = np.array([[np.nan, 0, 1], [0, 0, np.inf], [np.inf, 0, 1], [0, 0, -np.inf], [np.inf] * 3], dtype)
    behind = np.array([[0, 0, 0], [0, 0, -1], [1e30, 0, 1e-30], [0.1, 0.1, -1]], dtype)
    c2w = look_at([0.1, 0.2, -3.0], [0.0, 0.0, 0.0], [0, 1, 0])
    for pts, pose in ((non_finite, np.eye(4)), (non_finite, c2w), (behind, np.eye(4))):
        with np.errstate(all="raise"):
            uv, z, ok = project(pts, K_GOLD, pose)
        assert not ok.any()
        assert np.isfinite(uv).all() and np.isfinite(z).all()
        assert (uv == -1).all() and (z == 0).all()


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("depth", [1e-6, 1e6])
def test_extreme_depths(dtype, depth):
    pts = np.array([[0.3 * depth, -0.2 * depth, depth]], dtype)
    uv, z, ok = project(pts, K_GOLD, np.eye(4))
    assert ok[0]
    np.testing.assert_allclose(uv[0], [256 + 150, 256 - 100], rtol=1e-6)  # by hand: 500 * 0.3 + 256, ...
    np.testing.assert_allclose(z[0], depth, rtol=1e-6)
    back = unproject(uv, z, K_GOLD, np.eye(4))
    np.testing.assert_allclose(back, pts, rtol=1e-5)


def test_width_height_one():
    k = Intrinsics(10.0, 10.0, 0.5, 0.5, 1, 1)
    uv, z, ok = project(np.array([[0.0, 0.0, 1.0], [0.06, 0.0, 1.0]]), k, np.eye(4))
    assert ok.tolist() == [True, False] and uv[0].tolist() == [0.5, 0.5]


finite = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=100, deadline=None)
@given(st.tuples(finite, finite), st.floats(0.01, 100.0), st.tuples(finite, finite, finite),
       st.sampled_from(DTYPES))
def test_unproject_project_round_trip(uv01, z, eye, dtype):
    k = Intrinsics(300.0, 280.0, 160.5, 119.5, 320, 240)
    c2w = look_at(np.array(eye) * 5 + [0, 0, -6], [0.0, 0.0, 0.0])
    uv = np.array([0.5 + (uv01[0] + 1) / 2 * 319.0, 0.5 + (uv01[1] + 1) / 2 * 239.0], dtype)  # >= 0.5 px inside
    pts = unproject(uv, np.asarray(z, dtype), k, c2w)
    assert pts.dtype == dtype
    uv2, z2, ok = project(pts, k, c2w)
    assert ok
    # float32: world coordinates (|.| <~ 11) carry ~6e-8 * 11 = 7e-7 of error each way (unproject, then
    # project's float32 K [R|t] p), i.e. about 2 * 300 px * 7e-7 / z; 6e-4 / z leaves a margin of 1.4
    tol = 1e-7 if dtype == np.float64 else 1e-3 + 6e-4 / z
    np.testing.assert_allclose(uv2, uv, atol=tol)
    # float32 world coordinates carry ~6e-8 * |camera distance ~ 11| of absolute error.
    np.testing.assert_allclose(z2, z, rtol=1e-12 if dtype == np.float64 else 1e-5, atol=0 if dtype == np.float64 else 2e-6)


def test_batched_poses_broadcast():
    rng = np.random.default_rng(1)
    c2w = look_at(rng.normal(size=(3, 3)) + [0, 0, -5], np.zeros(3))
    pts = rng.normal(size=(3, 50, 3)) * 0.3
    uv, z, ok = project(pts, K_GOLD, c2w[:, None])
    assert uv.shape == (3, 50, 2) and ok.shape == (3, 50)
    for i in range(3):
        uv_i, z_i, ok_i = project(pts[i], K_GOLD, c2w[i])
        np.testing.assert_allclose(uv[i], uv_i, atol=1e-10)
        np.testing.assert_array_equal(ok[i], ok_i)
    with pytest.raises(ValueError, match="points_world"):
        project(np.zeros((4, 2)), K_GOLD, np.eye(4))
    with pytest.raises(ValueError, match="intrinsics"):
        project(np.zeros((4, 3)), K_GOLD.K, np.eye(4))


@pytest.mark.parametrize("offset", [0.0, 1e5, 5e5])
@pytest.mark.parametrize("batched", [False, True])
def test_float32_points_far_from_the_origin(offset, batched):
    # Georeferenced float32 points: the projection of the float32 values must be as exact as the float32
    # output allows.  Golden: the pinhole formula in float64 on the same values, K (R^T (X - C)), written
    # out here with C subtracted first (no cancellation).
    rng = np.random.default_rng(3)
    k = Intrinsics(100.0, 100.0, 50.0, 50.0, 100, 100)
    origin = np.array([offset, -offset, offset / 3])
    c2w = look_at(origin + [0.0, -4.0, 0.5], origin)
    pts = (origin + rng.uniform(-1, 1, (5000, 3))).astype(np.float32)
    cam = (pts.astype(np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    uv_ref = cam[:, :2] / cam[:, 2:] * [k.fx, k.fy] + [k.cx, k.cy]
    pose = c2w[None] if batched else c2w
    uv, z, ok = project(pts[None] if batched else pts, k, pose)
    uv, z, ok = (a[0] if batched else a for a in (uv, z, ok))
    assert uv.dtype == np.float32 and ok.sum() > 4000
    np.testing.assert_allclose(uv[ok], uv_ref[ok], atol=1e-4)  # float32 rounding of ~100 px: 4e-6
    np.testing.assert_allclose(z[ok], cam[ok, 2], rtol=1e-6)


def test_float32_bounds_are_tested_after_rounding():
    # u = 4 - 1e-9 is inside [0, 4) in float64 but rounds to 4.0 in float32: it must come back invalid.
    k = Intrinsics(1.0, 1.0, 2.0, 1.5, 4, 3)
    pts = np.array([[2 - 1e-9, 0.0, 1.0]])
    for dtype in DTYPES:
        uv, _, ok = project(pts.astype(dtype), k, np.eye(4))
        assert bool(ok[0]) == (dtype == np.float64)
        assert not ok[0] or uv[0, 0] < 4


def test_clashing_batches_are_named():
    k = Intrinsics(100.0, 100.0, 2.0, 2.0, 4, 4)
    poses = np.stack([np.eye(4)] * 5)
    with pytest.raises(ValueError, match=r"batch shapes of points_world \(7,\) and c2w \(5,\) do not broadcast"):
        project(np.zeros((7, 3)), k, poses)
    with pytest.raises(ValueError, match=r"uv \(7,\) and z_depth \(\) and c2w \(5,\) do not broadcast"):
        unproject(np.zeros((7, 2)), 1.0, k, poses)
    with pytest.raises(ValueError, match=r"uv \(7,\) and z_depth \(5,\) and c2w \(\) do not broadcast"):
        unproject(np.zeros((7, 2)), np.ones(5), k, np.eye(4))
    assert unproject(np.zeros((5, 2)), np.ones(5), k, poses).shape == (5, 3)   # broadcasting ones still do
