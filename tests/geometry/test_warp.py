"""Tests of senerf/geometry/warp.py (reproject), against analytic scenes built here by ray casting."""

import numpy as np
import pytest
from scipy import ndimage

from senerf.geometry import Intrinsics, look_at, pose_from_spherical, project, reproject
from senerf.procedural import SceneConfig, build_scene, cast_rays, render

DTYPES = [np.float32, np.float64]
K = Intrinsics(200.0, 200.0, 64.0, 48.0, 128, 96)


def camera_rays(k, c2w):
    """World origins and directions whose camera-frame z component is 1 (so ray parameter = z-depth)."""
    j, i = np.mgrid[0 : k.height, 0 : k.width]
    pix = np.stack([i + 0.5, j + 0.5, np.ones_like(i, dtype=float)], -1)
    d_cam = pix @ np.linalg.inv(k.K).T
    return np.broadcast_to(c2w[:3, 3], d_cam.shape), d_cam @ c2w[:3, :3].T


def plane_depth(k, c2w, n, d):
    """z-depth of the plane n . X = d, inf where the ray misses it."""
    o, dirs = camera_rays(k, c2w)
    n = np.asarray(n, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (d - o @ n) / (dirs @ n)
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def box_depth(k, c2w, lo, hi):
    """z-depth of the axis-aligned box [lo, hi] (slab method), inf where missed."""
    o, dirs = camera_rays(k, c2w)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (np.asarray(lo) - o) / dirs
        t2 = (np.asarray(hi) - o) / dirs
    t_near = np.nanmax(np.minimum(t1, t2), axis=-1)
    t_far = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (t_near <= t_far) & (t_near > 0)
    return np.where(hit, t_near, np.inf)


def homography(k_src, c2w_src, k_dst, c2w_dst, n, d):
    """Plane-induced homography for the world plane n . X = d: H = K_dst (R + t n_c^T / d_c) K_src^-1.

    With the plane written in the source camera frame as n_c . X = d_c (n_c = R_src^T n, d_c = d - n . o_src),
    X_dst = R X + t = (R + t n_c^T / d_c) X on the plane (the textbook form K (R - t n^T / d) K^-1 uses
    n^T X + d = 0, i.e. d -> -d_c).
    """
    n = np.asarray(n, float)
    t_ds = np.linalg.inv(c2w_dst) @ c2w_src
    n_c = c2w_src[:3, :3].T @ n
    d_c = d - n @ c2w_src[:3, 3]
    return k_dst.K @ (t_ds[:3, :3] + np.outer(t_ds[:3, 3], n_c) / d_c) @ np.linalg.inv(k_src.K)


def apply_h(h, k):
    j, i = np.mgrid[0 : k.height, 0 : k.width]
    p = np.stack([i + 0.5, j + 0.5, np.ones(i.shape)], -1) @ h.T
    return p[..., :2] / p[..., 2:]


def in_image(uv, k):
    return (uv[..., 0] >= 0) & (uv[..., 0] < k.width) & (uv[..., 1] >= 0) & (uv[..., 1] < k.height)


@pytest.mark.parametrize("dtype", DTYPES)
def test_plane_matches_homography(dtype):
    n, d = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0]), -0.2
    src = look_at([0.5, -3.0, 2.5], [0.0, 0.0, 0.0])
    dst = look_at([-1.5, -2.5, 2.0], [0.2, 0.1, 0.0])
    z_src = plane_depth(K, src, n, d)
    assert np.isfinite(z_src).all()
    uv, ok, z = reproject(z_src.astype(dtype), K, src, K, dst, return_z=True)
    assert uv.dtype == dtype and uv.shape == (96, 128, 2) and ok.shape == (96, 128)
    uv_ref = apply_h(homography(K, src, K, dst, n, d), K)
    expect = in_image(uv_ref, K)
    assert 0.3 < expect.mean() < 1.0  # part of the warp falls outside: both branches exercised
    np.testing.assert_array_equal(ok, expect)
    tol = 1e-7 if dtype == np.float64 else 2e-3
    np.testing.assert_allclose(uv[ok], uv_ref[ok], atol=tol)
    assert (uv[~ok] == -1).all() and (z[~ok] == 0).all()
    # With the analytic destination depth, every correct warp passes the z-test and forward-backward check.
    z_dst = plane_depth(K, dst, n, d).astype(dtype)
    _, ok_z = reproject(z_src.astype(dtype), K, src, K, dst, z_depth_dst=z_dst)
    np.testing.assert_array_equal(ok_z, expect)
    _, ok_fb = reproject(z_src.astype(dtype), K, src, K, dst, z_depth_dst=z_dst, forward_backward=True)
    np.testing.assert_array_equal(ok_fb, expect)
    # A destination depth 5 % too far fails forward-backward (the back-projected depth is off by > 1 %).
    _, ok_bad = reproject(z_src.astype(dtype), K, src, K, dst, z_depth_dst=z_dst * 1.05, forward_backward=True)
    assert not ok_bad.any()


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("angle", [80.0, 85.0, 89.0, 89.9])
@pytest.mark.parametrize("grazing", ["dst", "src"])
def test_grazing_plane_stays_valid(dtype, angle, grazing):
    # Plane z = 0; one camera 1 unit above it looks at the plane at `angle` from the normal, the other looks
    # straight down at the same spot from 3 + 4 tan(angle) units (wide enough to share many pixels with the
    # oblique view).  Every geometrically correct warp must stay valid.
    k = Intrinsics(500.0, 500.0, 64.0, 48.0, 128, 96)
    spot = np.array([0.0, np.tan(np.radians(angle)), 0.0])
    oblique = look_at([0.0, 0.0, 1.0], spot)
    frontal = look_at(spot + [0, 0, 3.0 + 4.0 * spot[1]], spot, up=[0.0, 1.0, 0.0])
    src, dst = (frontal, oblique) if grazing == "dst" else (oblique, frontal)
    z_src = plane_depth(k, src, [0, 0, 1], 0.0)
    z_dst = plane_depth(k, dst, [0, 0, 1], 0.0)
    if grazing == "dst":
        # The case is hard: adjacent destination rows differ by more than a fixed 1 % where the warps land.
        fin = np.isfinite(z_dst[47:50, 64])
        assert (np.abs(np.diff(z_dst[47:50, 64])) / z_dst[47:49, 64] > 0.01).any() and fin.all()
    src_ok = np.isfinite(z_src)
    z_src = np.where(src_ok, z_src, 0.0).astype(dtype)  # misses -> invalid source pixels
    uv_plain, ok_plain = reproject(z_src, k, src, k, dst)
    uv, ok = reproject(z_src, k, src, k, dst, z_depth_dst=z_dst.astype(dtype))
    assert ok_plain.sum() > 50
    np.testing.assert_array_equal(ok, ok_plain)


@pytest.mark.parametrize("dtype", DTYPES)
def test_occluding_box(dtype):
    # A far plane z = 0 and a box floating above it; the destination sees the box hide part of the plane that
    # the source sees.  Ground truth: a source point is hidden in dst when the dst ray to it hits the box first.
    lo, hi = np.array([-0.3, -0.3, 0.5]), np.array([0.3, 0.3, 1.1])
    src = look_at([2.5, -2.0, 3.0], [0.0, 0.0, 0.0])
    dst = look_at([-0.5, -3.0, 3.0], [0.0, 0.0, 0.3])

    def depth(c2w):
        return np.minimum(plane_depth(K, c2w, [0, 0, 1], 0.0), box_depth(K, c2w, lo, hi))

    z_src, z_dst = depth(src), depth(dst)
    assert np.isfinite(z_src).all() and np.isfinite(z_dst).all()
    o, dirs = camera_rays(K, src)
    pts = o + dirs * z_src[..., None]
    w2c = np.linalg.inv(dst)
    cam = pts @ w2c[:3, :3].T + w2c[:3, 3]
    z_true = cam[..., 2]
    ray = cam / z_true[..., None]  # dst camera-frame ray with z = 1 through each point
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - dst[:3, 3]) @ np.eye(3) / (ray @ dst[:3, :3].T)
        t2 = (hi - dst[:3, 3]) / (ray @ dst[:3, :3].T)
    t_near = np.nanmax(np.minimum(t1, t2), -1)
    t_far = np.nanmin(np.maximum(t1, t2), -1)
    hidden = (t_near <= t_far) & (t_near > 0) & (t_near < z_true * (1 - 1e-6))

    uv_geo, ok_geo = reproject(z_src.astype(dtype), K, src, K, dst)
    uv, ok = reproject(z_src.astype(dtype), K, src, K, dst, z_depth_dst=z_dst.astype(dtype))
    occluded = ok_geo & hidden
    visible = ok_geo & ~hidden
    assert occluded.sum() > 300 and visible.sum() > 3000
    assert ok[visible].all()  # no visible pixel is lost
    # Occluded points landing 2+ px inside the box's dst silhouette are all flagged; overall >= 90 %.
    box_dst = np.isfinite(box_depth(K, dst, lo, hi))
    core = ndimage.binary_erosion(box_dst, iterations=2)
    lands = core[np.clip(uv_geo[..., 1].astype(int), 0, 95), np.clip(uv_geo[..., 0].astype(int), 0, 127)]
    assert not ok[occluded & lands].any()
    assert (~ok[occluded]).mean() >= 0.9
    # Forward-backward on top keeps the same decision for occluded pixels.
    _, ok_fb = reproject(z_src.astype(dtype), K, src, K, dst, z_depth_dst=z_dst.astype(dtype), forward_backward=True)
    assert not (ok_fb & ~ok).any() and not ok_fb[occluded & lands].any()


def test_float32_far_from_origin():
    # Scene offset 1e5: composing T_dst_src in float64 keeps float32 warps within 0.01 px of the exact
    # homography, in both directions (a round trip src -> dst -> src).
    off = np.array([1e5, 1e5, 1e5])
    n, d = np.array([0.0, 0.0, 1.0]), 1e5
    src = look_at(off + [0.5, -3.0, 2.5], off)
    dst = look_at(off + [-1.5, -2.5, 2.0], off + [0.2, 0.1, 0.0])
    for a, b in ((src, dst), (dst, src)):
        z_a = plane_depth(K, a, n, d)
        uv, ok = reproject(z_a.astype(np.float32), K, a, K, b)
        uv_ref = apply_h(homography(K, a, K, b, n, d), K)
        assert ok.sum() > 1000
        assert np.abs(uv[ok] - uv_ref[ok]).max() < 0.01


@pytest.mark.parametrize("far", [1e3, 1e5])
def test_a_far_background_in_float32_warps_onto_its_homography_and_is_not_occluded_by_itself(far):
    # An unbounded scene's background lies up to ~1000 camera distances away; its z-depths are rendered in
    # float32.  Its pixels must land where the plane's homography (computed apart, in float64) puts them, which
    # tends to the infinite homography K R_dst^T R_src K^-1, and the destination's own far depth must not occlude
    # them (the occlusion test is relative).
    n, d = np.array([0.0, 0.0, 1.0]), -far
    src = look_at([0.5, -3.0, 2.5], [0.0, 0.0, 0.0])
    dst = look_at([0.0, -3.1, 2.3], [0.1, 0.05, 0.0])   # a pseudo view 10 degrees away
    z_src, z_dst = plane_depth(K, src, n, d), plane_depth(K, dst, n, d)
    assert np.isfinite(z_src).all() and z_src.min() > 0.5 * far
    uv, ok = reproject(z_src.astype(np.float32), K, src, K, dst, z_depth_dst=z_dst.astype(np.float32))
    uv_ref = apply_h(homography(K, src, K, dst, n, d), K)
    lands = (uv_ref[..., 0] >= 0) & (uv_ref[..., 0] < K.width) & (uv_ref[..., 1] >= 0) & (uv_ref[..., 1] < K.height)
    inner = lands & (uv_ref[..., 0] > 1) & (uv_ref[..., 0] < K.width - 1) & (uv_ref[..., 1] > 1) \
        & (uv_ref[..., 1] < K.height - 1)
    assert inner.sum() > 5000 and ok[inner].all() and not ok[~lands].any()
    assert np.abs(uv[ok] - uv_ref[ok]).max() < 0.01
    r_src, r_dst = src[:3, :3], dst[:3, :3]
    kmat = np.array([[K.fx, 0, K.cx], [0, K.fy, K.cy], [0, 0, 1.0]])
    uv_inf = apply_h(kmat @ r_dst.T @ r_src @ np.linalg.inv(kmat), K)
    parallax = K.fx * np.linalg.norm(src[:3, 3] - dst[:3, 3]) / z_src.min()   # pixels, an upper bound
    assert np.abs(uv[ok] - uv_inf[ok]).max() < 2 * parallax + 0.01


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_scale_invariance_extreme_depths(scale):
    n, d = np.array([0.0, 0.0, 1.0]), 0.0
    src = look_at([0.5, -3.0, 2.5], [0.0, 0.0, 0.0])
    dst = look_at([-1.5, -2.5, 2.0], [0.2, 0.1, 0.0])
    ref_uv, ref_ok = reproject(plane_depth(K, src, n, d), K, src, K, dst, z_depth_dst=plane_depth(K, dst, n, d))
    s_src, s_dst = src.copy(), dst.copy()
    s_src[:3, 3] *= scale
    s_dst[:3, 3] *= scale
    z_src = plane_depth(K, s_src, n, d)
    assert 0.5 * scale < z_src.min() and z_src.max() < 10 * scale
    uv, ok = reproject(z_src, K, s_src, K, s_dst, z_depth_dst=plane_depth(K, s_dst, n, d))
    np.testing.assert_array_equal(ok, ref_ok)
    np.testing.assert_allclose(uv, ref_uv, atol=1e-6)


@pytest.mark.parametrize("dtype", DTYPES)
def test_bad_source_depth_is_invalid_and_finite(dtype):
    z = np.full((96, 128), 3.0)
    z[0, :5] = [0.0, -1.0, np.nan, np.inf, -np.inf]
    dst = np.eye(4)
    dst[0, 3] = 0.3  # translated only: the plane z_depth = 3 has depth 3 in dst too
    z_dst = np.full((96, 128), np.nan)
    z_dst[10:] = 3.0
    with np.errstate(all="raise"):
        uv, ok, zd = reproject(z.astype(dtype), K, np.eye(4), K, dst, z_depth_dst=z_dst.astype(dtype),
                               forward_backward=True, return_z=True)
    assert not ok[0, :5].any() and ok[50, 50]
    assert np.isfinite(uv).all() and np.isfinite(zd).all()


def test_behind_destination_camera_is_invalid():
    dst = look_at([0.0, 0.0, 6.0], [0.0, 0.0, 10.0])  # sits beyond the plane z_depth = 3, looking away
    _, ok = reproject(np.full((96, 128), 3.0), K, np.eye(4), K, dst)
    assert not ok.any()


def test_tiny_images_and_batches():
    k1 = Intrinsics(10.0, 10.0, 0.5, 0.5, 1, 1)
    uv, ok = reproject(np.ones((1, 1)), k1, np.eye(4), k1, np.eye(4), z_depth_dst=np.ones((1, 1)),
                       forward_backward=True)
    assert ok.all() and uv[0, 0].tolist() == [0.5, 0.5]
    k_row = Intrinsics(10.0, 10.0, 2.5, 0.5, 5, 1)
    uv, ok = reproject(np.ones((1, 5)), k_row, np.eye(4), k_row, np.eye(4), z_depth_dst=np.ones((1, 5)))
    assert ok.all()
    dsts = look_at(np.array([[0.1, 0, 0], [0, 0.1, 0], [-0.1, 0, 0]]), np.array([0.0, 0.0, 3.0]))
    z = np.full((96, 128), 3.0)
    uv, ok = reproject(z, K, np.eye(4), K, dsts, z_depth_dst=np.full((3, 96, 128), 3.0))
    assert uv.shape == (3, 96, 128, 2)
    for i in range(3):
        uv_i, ok_i = reproject(z, K, np.eye(4), K, dsts[i], z_depth_dst=np.full((96, 128), 3.0))
        np.testing.assert_array_equal(uv[i], uv_i)
        np.testing.assert_array_equal(ok[i], ok_i)
    with pytest.raises(ValueError, match="z_depth_src"):
        reproject(np.ones((5, 5)), K, np.eye(4), K, np.eye(4))
    with pytest.raises(ValueError, match="z_depth_dst"):
        reproject(z, K, np.eye(4), K, dsts, z_depth_dst=np.ones((96, 128)))
    with pytest.raises(ValueError, match="forward_backward"):
        reproject(z, K, np.eye(4), K, np.eye(4), forward_backward=True)


def test_matches_unproject_then_project_random_scenes():
    # Independent path: lift every pixel centre to the world with unproject, project into dst with project.
    from senerf.geometry import pixel_centers, project, unproject

    rng = np.random.default_rng(11)
    for _ in range(5):
        src = look_at(rng.normal(size=3) * 2 + [0, 0, -4], rng.normal(size=3) * 0.2)
        dst = look_at(rng.normal(size=3) * 2 + [0, 0, -4], rng.normal(size=3) * 0.2)
        z = rng.uniform(2.0, 6.0, size=(96, 128))
        uv, ok, zd = reproject(z, K, src, K, dst, return_z=True)
        uv_ref, z_ref, ok_ref = project(unproject(pixel_centers(K), z, K, src), K, dst)
        np.testing.assert_array_equal(ok, ok_ref)
        assert ok.mean() > 0.05
        np.testing.assert_allclose(uv[ok], uv_ref[ok], atol=1e-8)
        np.testing.assert_allclose(zd[ok], z_ref[ok], rtol=1e-10)


def test_three_by_four_poses_warp_as_their_four_by_four():
    """(3, 4) poses, which every other pose function accepts, give the same warp as the (4, 4) ones."""
    src = look_at(np.array([0.3, -0.2, -4.0]), np.zeros(3))
    dst = look_at(np.array([[1.5, 0.4, -3.8], [-1.0, 1.0, -4.2]]), np.zeros(3))
    depth = np.full((K.height, K.width), 4.0)
    full = reproject(depth, K, src, K, dst, z_depth_dst=np.full((2, K.height, K.width), 4.0))
    short = reproject(depth, K, src[:3], K, dst[:, :3], z_depth_dst=np.full((2, K.height, K.width), 4.0))
    assert full[1].any()
    for a, b in zip(full, short):
        np.testing.assert_array_equal(a, b)


def test_a_single_source_pose_is_required():
    with pytest.raises(ValueError, match=r"c2w_src: expected a single pose"):
        reproject(np.full((96, 128), 2.0), K, np.stack([np.eye(4)] * 2), K, np.eye(4))
    uv, ok = reproject(np.full((96, 128), 2.0), K, np.eye(4)[:3], K, np.stack([np.eye(4)] * 2))   # (3, 4) is one pose
    assert uv.shape == (2, 96, 128, 2) and ok.all()


@pytest.mark.parametrize("name", ["rel_tol", "abs_tol", "slope_tol", "fb_px_tol", "fb_rel_tol"])
def test_negative_or_non_finite_tolerances_are_refused(name):
    depth = np.full((K.height, K.width), 4.0)
    pose = look_at(np.array([0.0, 0.0, -4.0]), np.zeros(3))
    for bad in (-0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match=rf"{name}: must be finite and >= 0"):
            reproject(depth, K, pose, K, pose, z_depth_dst=depth, **{name: bad})


# A frontal source 4 units above the plane z = 0 and a destination 4 units from the origin at 60 degrees from
# the normal, both looking at the origin: every source pixel sees the plane and ~98 % of them warp into dst.
K500 = Intrinsics(500.0, 500.0, 64.0, 48.0, 128, 96)
FB_SRC = look_at([0.0, 0.0, 4.0], [0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])
FB_DST = look_at([0.0, -4.0 * np.sin(np.radians(60.0)), 4.0 * np.cos(np.radians(60.0))], [0.0, 0.0, 0.0])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shift", [-2.0, 2.0])
def test_forward_backward_rejects_a_sideways_shifted_destination_depth(dtype, shift):
    # Catches: the forward-backward pixel-distance check deleted (or loosened) in _fb_ok.
    # The destination depth map is the true plane depth shifted `shift` rows (rendered with cy + shift, so no
    # wrap-around): plausible depths in the wrong place.  Lifting dst pixel uv with that depth puts the point
    # on the right dst ray at the depth of the ray through (u, v - shift); computed here by ray casting, its
    # back-projection lands 2.6 - 3.5 px from the source pixel while its source depth is off by < 0.4 %, so
    # only the pixel check (fb_px_tol = 1) can reject it.
    n, d = np.array([0.0, 0.0, 1.0]), 0.0
    z_src = plane_depth(K500, FB_SRC, n, d)
    assert np.isfinite(z_src).all()
    uv_ref = apply_h(homography(K500, FB_SRC, K500, FB_DST, n, d), K500)
    expect = in_image(uv_ref, K500)
    assert expect.mean() > 0.9
    z_shifted = plane_depth(Intrinsics(500.0, 500.0, 64.0, 48.0 + shift, 128, 96), FB_DST, n, d)
    # Independent forward-backward: lift uv_ref with the shifted depth, project back into the source.
    u, v = uv_ref[..., 0], uv_ref[..., 1]
    o_d = FB_DST[:3, 3]
    dirs = np.stack([(u - 64.0) / 500.0, (v - 48.0 - shift) / 500.0, np.ones_like(u)], -1) @ FB_DST[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        z_lift = (d - o_d @ n) / (dirs @ n)
    cam_d = np.stack([(u - 64.0) / 500.0 * z_lift, (v - 48.0) / 500.0 * z_lift, z_lift], -1)
    world = cam_d @ FB_DST[:3, :3].T + o_d
    w2c = np.linalg.inv(FB_SRC)
    cam_s = world @ w2c[:3, :3].T + w2c[:3, 3]
    j, i = np.mgrid[0:96, 0:128]
    px_err = np.hypot(500.0 * cam_s[..., 0] / cam_s[..., 2] + 64.0 - (i + 0.5),
                      500.0 * cam_s[..., 1] / cam_s[..., 2] + 48.0 - (j + 0.5))
    depth_err = np.abs(cam_s[..., 2] - z_src) / z_src
    assert px_err[expect].min() > 2.0 and depth_err[expect].max() < 0.005  # the premise of the test
    zs, zd = z_src.astype(dtype), z_shifted.astype(dtype)
    _, ok_z = reproject(zs, K500, FB_SRC, K500, FB_DST, z_depth_dst=zd)
    np.testing.assert_array_equal(ok_z, expect)  # the occlusion test alone keeps them all
    _, ok_depth_only = reproject(zs, K500, FB_SRC, K500, FB_DST, z_depth_dst=zd, forward_backward=True,
                                 fb_px_tol=1e9)
    np.testing.assert_array_equal(ok_depth_only, expect)  # the 1 % depth check passes them all
    _, ok_fb = reproject(zs, K500, FB_SRC, K500, FB_DST, z_depth_dst=zd, forward_backward=True)
    assert not ok_fb.any()


@pytest.mark.parametrize("dtype", DTYPES)
def test_forward_backward_tight_pixel_tolerance_keeps_exact_warps(dtype):
    # Catches: the pixel centre of the start pixel in _fb_ok taken as i (or j) instead of i + 0.5 (a 0.5 px
    # error that fb_px_tol = 1 hides).  With the exact destination plane depth every round trip returns to the
    # pixel centre up to bilinear-interpolation and rounding error (<< 0.1 px), so fb_px_tol = 0.1 must keep
    # exactly the in-image warps (the plane homography's).
    n, d = np.array([0.0, 0.0, 1.0]), 0.0
    z_src = plane_depth(K500, FB_SRC, n, d).astype(dtype)
    z_dst = plane_depth(K500, FB_DST, n, d).astype(dtype)
    expect = in_image(apply_h(homography(K500, FB_SRC, K500, FB_DST, n, d), K500), K500)
    _, ok = reproject(z_src, K500, FB_SRC, K500, FB_DST, z_depth_dst=z_dst, forward_backward=True, fb_px_tol=0.1)
    assert expect.mean() > 0.9
    np.testing.assert_array_equal(ok, expect)


@pytest.mark.parametrize("dtype", DTYPES)
def test_warps_in_the_outer_half_pixel_of_a_steep_destination_stay_valid(dtype):
    # Catches: the slope_tol (D_hi - D_lo) term dropped from the occlusion bound.
    # The destination looks at the plane z = 0 from 1 unit above at 82 degrees from the normal: along its top
    # row (ray ~87.4 degrees) the depth grows ~4.4 % per pixel towards the top edge.  A frontal source 10
    # units above the spot that row sees makes many warps land in v in [0, 0.5), above the top pixel-centre
    # row, where the footprint is shifted inwards and the true depth exceeds the footprint max by up to ~2 %,
    # more than rel_tol = 1 % covers; slope_tol = 0.5 must cover it (every geometrically correct warp valid).
    k = K500
    dst = look_at([0.0, 0.0, 1.0], [0.0, np.tan(np.radians(82.0)), 0.0])
    z_dst = plane_depth(k, dst, [0, 0, 1], 0.0)
    assert np.isfinite(z_dst).all()  # the horizon is above the image
    assert 0.03 < z_dst[0, 64] / z_dst[1, 64] - 1 < 0.06  # steep along v at the top edge
    o, dirs = camera_rays(k, dst)
    spot = o[0, 64] + dirs[0, 64] * z_dst[0, 64]  # where the top-centre pixel's ray meets the plane
    src = look_at(spot + [0.0, 0.0, 10.0], spot, up=[0.0, 1.0, 0.0])
    z_src = plane_depth(k, src, [0, 0, 1], 0.0).astype(dtype)
    assert np.isfinite(z_src).all()
    uv, ok_plain = reproject(z_src, k, src, k, dst)
    outer = ok_plain & (uv[..., 1] < 0.5)
    assert outer.sum() > 1000
    _, ok = reproject(z_src, k, src, k, dst, z_depth_dst=z_dst.astype(dtype))
    np.testing.assert_array_equal(ok, ok_plain)
    # The case needs the term: without it, warps in the outer half pixel (and only there) are rejected.
    _, ok0 = reproject(z_src, k, src, k, dst, z_depth_dst=z_dst.astype(dtype), slope_tol=0.0)
    lost = ok_plain & ~ok0
    assert lost.sum() > 100 and not (lost & ~outer).any()


def test_an_empty_batch_of_destinations_with_their_depths():
    # reshape(0, -1) is ambiguous: an empty batch must give empty arrays with z_depth_dst as without it
    k = Intrinsics(100.0, 100.0, 2.0, 2.0, 4, 4)
    for depths in (None, np.zeros((0, 4, 4))):
        uv, valid = reproject(np.full((4, 4), 2.0), k, np.eye(4), k, np.zeros((0, 4, 4)), z_depth_dst=depths)
        assert uv.shape == (0, 4, 4, 2) and valid.shape == (0, 4, 4)


# Against the exact ray-cast geometry of the procedural scene (senerf.procedural): reprojecting view A's exact
# z-depth into view B equals geometry.project of the same surface points, and the occlusion test (given B's exact
# depth) agrees with ground-truth visibility from casting a ray from B's camera centre towards each 3D point.

SIZE = 96
INTR = Intrinsics.from_fov(39.6, SIZE, SIZE)
# (source, destination) view pairs, (azimuth, elevation) in degrees: small and large baselines
PAIRS = [((20.0, 35.0), (55.0, 45.0)), ((0.0, 25.0), (100.0, 60.0)), ((200.0, 15.0), (250.0, 40.0))]


@pytest.fixture(scope="module")
def proc_scene():
    return build_scene(SceneConfig(seed=0))


def _views(scene, pair):
    c2w = [pose_from_spherical(az, el, 4.0) for az, el in pair]
    return c2w, [render(scene, INTR, p) for p in c2w]


def _depth_arg(r):
    """Exact z-depth with 0 where the ray missed (the form reproject receives from exported depth files)."""
    return np.where(np.isfinite(r.z_depth), r.z_depth, 0.0)


@pytest.mark.parametrize("pair", PAIRS)
def test_reproject_exact_depth_matches_projection(proc_scene, pair):
    (c_src, c_dst), (r_src, _) = _views(proc_scene, pair)
    uv, valid = reproject(_depth_arg(r_src), INTR, c_src, INTR, c_dst)
    hit = r_src.alpha == 1.0
    uv_ref, z_ref, in_front = project(r_src.points, INTR, c_dst)
    sel = hit & in_front
    assert sel.sum() > 1000
    err = np.linalg.norm(uv[sel] - uv_ref[sel], axis=-1)
    assert err.max() < 0.01
    assert valid[sel].all()  # without a destination depth nothing in view is rejected
    assert not valid[~hit].any()  # no depth, no warp


def _gt_visible(scene, points, eye):
    """Ground truth: True where the first hit of the ray from ``eye`` towards each point is the point itself."""
    v = points - eye
    dist = np.linalg.norm(v, axis=1)
    h = cast_rays(scene, np.tile(eye, (len(points), 1)), v / dist[:, None])
    # occluded if something is hit nearer than the point by more than 1e-4 relative (~0.4 mm at 4 units;
    # the hit distances are float64-exact on the mesh, so a visible point comes back within ~1e-9)
    return ~(h.hit & (h.ray_dist < dist * (1.0 - 1e-4)))


def _mixed_footprint(r, uv, plane_tol=0.01):
    """(H, W) True where the 2 x 2 bilinear footprint of ``uv`` (H, W, 2) in view ``r`` spans two surfaces.

    The footprint is the 4 pixels whose centres surround ``uv`` (the pixels reproject's z-test reads).  Two
    footprint pixels are on different surfaces when one is background and the other not, or when one's 3D
    point lies more than ``plane_tol`` scene units off the other's surface plane.  Smooth curved surfaces
    stay well below that (sphere r = 0.5, pixel footprint ~0.03 units: ~1e-3 off-plane); occlusion steps
    here are >= 0.05 units.
    """
    h, w = r.alpha.shape
    base = np.floor(uv - 0.5).astype(int)
    taps = []
    for dy in (0, 1):
        for dx in (0, 1):
            y = np.clip(base[..., 1] + dy, 0, h - 1)
            x = np.clip(base[..., 0] + dx, 0, w - 1)
            taps.append((r.alpha[y, x] == 1.0, np.nan_to_num(r.points[y, x]), r.normals[y, x].astype(np.float64)))
    mixed = np.zeros(uv.shape[:-1], dtype=bool)
    for a_hit, a_p, a_n in taps:
        for b_hit, b_p, b_n in taps:
            off = np.abs(np.einsum("...k,...k->...", b_p - a_p, a_n)) > plane_tol
            mixed |= (a_hit != b_hit) | (a_hit & b_hit & off)
    return mixed


@pytest.mark.parametrize("pair", PAIRS)
def test_occlusion_flags_match_ray_cast_visibility(proc_scene, pair):
    (c_src, c_dst), (r_src, r_dst) = _views(proc_scene, pair)
    uv, valid = reproject(_depth_arg(r_src), INTR, c_src, INTR, c_dst, z_depth_dst=_depth_arg(r_dst))
    hit = r_src.alpha == 1.0
    uv_ref, _, in_front = project(r_src.points, INTR, c_dst)
    inside = in_front & np.all((uv_ref >= 0) & (uv_ref < SIZE), axis=-1)
    cand = hit & inside
    visible = np.zeros_like(hit)
    visible[cand] = _gt_visible(proc_scene, r_src.points[cand], c_dst[:3, 3])
    # exclude points whose 2 x 2 bilinear footprint in the destination (the pixels reproject's z-test
    # reads) spans two surfaces, i.e. points within ~1 px of a depth discontinuity: there reproject
    # deliberately keeps points next to an occluding edge (warp.py docstring), so "occluded" is ambiguous
    near = _mixed_footprint(r_dst, np.where(cand[..., None], uv_ref, 0.5)) & cand
    keep = cand & ~near
    occluded_gt, flagged = ~visible[keep], ~valid[keep]
    tp = int(np.sum(occluded_gt & flagged))
    fp = int(np.sum(~occluded_gt & flagged))
    fn = int(np.sum(occluded_gt & ~flagged))
    tn = int(np.sum(~occluded_gt & ~flagged))
    precision, recall = tp / max(tp + fp, 1), tp / max(tp + fn, 1)
    assert tp >= 100 and tn >= 500  # both classes well represented
    assert keep.sum() >= 0.5 * cand.sum()  # the exclusion band stays a minority of the points
    # Missed occlusions (FN) may only be points hidden by a surface within reproject's depth tolerance
    # (rel_tol 1 % plus slope_tol times the footprint's depth range): here the 0.1-thick rim of the ground
    # slab and the cylinder's cap edge, hidden by a face 0.5 - 2 % of the depth nearer.
    fn_mask = np.zeros_like(cand)
    fn_mask[keep] = occluded_gt & ~flagged
    if fn_mask.any():
        pts, eye = r_src.points[fn_mask], c_dst[:3, 3]
        dist = np.linalg.norm(pts - eye, axis=1)
        first = cast_rays(proc_scene, np.tile(eye, (len(pts), 1)), (pts - eye) / dist[:, None]).ray_dist
        gap = (dist - first) / dist
        assert gap.max() < 0.03
    assert precision > 0.97 and recall > 0.97
    # visible points keep their warp (specificity)
    assert tn / (tn + fp) > 0.97
