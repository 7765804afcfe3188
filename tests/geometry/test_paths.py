"""Tests of senerf/geometry/paths.py: orbit, spiral and keyframe camera paths."""

import numpy as np
import pytest

from senerf.geometry import (
    is_rigid,
    keyframe_path,
    look_at,
    opencv_to_opengl,
    opengl_to_opencv,
    orbit_path,
    pose_from_spherical,
    spherical_from_pose,
    spiral_focus_depth,
    spiral_path,
)

DTYPES = [np.float32, np.float64]


def _by_hand_position(center, az_deg, el_deg, r):
    az, el = np.radians(az_deg), np.radians(el_deg)
    return np.asarray(center, float) + r * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _inputs_looking_at(center, azs, els, rs):
    """Input cameras built with look_at (not with pose_from_spherical, which the orbit uses)."""
    eyes = [_by_hand_position(center, a, e, r) for a, e, r in zip(azs, els, rs)]
    return np.stack([look_at(eye, center, up=(0.0, 0.0, 1.0)) for eye in eyes])


@pytest.mark.parametrize("dtype", DTYPES)
def test_orbit_golden_positions_and_aim(dtype):
    center = np.array([1.0, 2.0, 3.0])
    inputs = _inputs_looking_at(center, azs=[10.0, 100.0, 200.0], els=[20.0, 40.0, 30.0], rs=[3.0, 5.0, 4.0])
    path = orbit_path(inputs.astype(dtype), 4)
    assert path.shape == (4, 4, 4) and path.dtype == dtype
    # by hand: mean elevation 30, mean radius 4, azimuths 10, 100, 190, 280 about the point the inputs look at
    for k, az in enumerate([10.0, 100.0, 190.0, 280.0]):
        np.testing.assert_allclose(path[k, :3, 3], _by_hand_position(center, az, 30.0, 4.0), atol=2e-5)
        to_center = (center - path[k, :3, 3]) / np.linalg.norm(center - path[k, :3, 3])
        np.testing.assert_allclose(path[k, :3, 2], to_center, atol=2e-6)   # looks at the centre
        assert abs(path[k, 2, 0]) < 2e-6                                    # level horizon: x is horizontal
        assert -path[k, 2, 1] > 0                                           # image up points up
    assert is_rigid(path).all()


def test_orbit_frame_zero_is_input_zero_when_the_inputs_share_elevation_and_radius():
    inputs = _inputs_looking_at(np.zeros(3), azs=[-35.0, 60.0, 150.0], els=[25.0] * 3, rs=[4.0] * 3)
    path = orbit_path(inputs, 7)
    np.testing.assert_allclose(path[0], inputs[0], atol=1e-12)
    az = spherical_from_pose(path)[0]
    np.testing.assert_allclose(np.diff(np.unwrap(np.radians(az))), 2 * np.pi / 7, atol=1e-12)  # no doubled frame


def test_orbit_overrides_and_rotation_equivariance():
    rng = np.random.default_rng(3)
    inputs = pose_from_spherical(np.array([0.0, 70.0, 130.0]), np.array([10.0, 35.0, 50.0]), np.array([3.0, 4.0, 5.0]),
                                 center=(0.5, -1.0, 0.2))
    path = orbit_path(inputs, 5, elevation=-20.0, radius=2.5)
    az, el, r = spherical_from_pose(path, center=(0.5, -1.0, 0.2))
    np.testing.assert_allclose(el, -20.0, atol=1e-9)
    np.testing.assert_allclose(r, 2.5, atol=1e-12)
    # a rigid motion of the whole capture moves the path with it (centre and up derived from the inputs)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    motion = np.eye(4)
    motion[:3, :3], motion[:3, 3] = q, [10.0, -4.0, 7.0]
    np.testing.assert_allclose(orbit_path(motion @ inputs, 5), motion @ orbit_path(inputs, 5), atol=1e-9)


def test_orbit_far_from_the_origin_in_float32():
    center = np.array([1e6, -2e6, 50.0])
    inputs = _inputs_looking_at(center, azs=[0.0, 90.0, 180.0], els=[30.0] * 3, rs=[4.0] * 3)
    path = orbit_path(inputs.astype(np.float32), 12)
    assert path.dtype == np.float32 and np.isfinite(path).all()
    # float32 positions are 0.06-0.25 apart out there; the distance to the centre holds to that
    dist = np.linalg.norm(path[:, :3, 3].astype(np.float64) - center, axis=-1)
    np.testing.assert_allclose(dist, 4.0, atol=0.3)


def test_orbit_errors():
    inputs = pose_from_spherical(np.array([0.0, 90.0]), np.array([20.0, 20.0]), 4.0)
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="n must be an integer"):
            orbit_path(inputs, bad)
    parallel = np.stack([np.eye(4), np.eye(4)])
    parallel[1, 0, 3] = 1.0
    with pytest.raises(ValueError, match="pass the scene centre"):
        orbit_path(parallel, 3)
    orbit_path(parallel, 3, center=(0.0, 0.0, 5.0), up=(0.0, -1.0, 0.0))   # fine once the centre is given
    with pytest.raises(ValueError, match="input_c2w"):
        orbit_path(np.eye(4), 3)


def _nerf_spiral_opengl(c2w_gl, rads, focal, rots, n, zrate=0.5):
    """NeRF's poses_avg + render_path_spiral (LLFF loader), re-typed in its OpenGL convention."""
    def normalize(v):
        return v / np.linalg.norm(v)

    def viewmatrix(z, up, pos):
        vec2 = normalize(z)
        vec0 = normalize(np.cross(up, vec2))
        vec1 = normalize(np.cross(vec2, vec0))
        return np.stack([vec0, vec1, vec2, pos], 1)

    center = c2w_gl[:, :3, 3].mean(0)
    up = normalize(c2w_gl[:, :3, 1].sum(0))
    avg = viewmatrix(c2w_gl[:, :3, 2].sum(0), up, center)
    rads = np.array(list(rads) + [1.0])
    out = []
    for theta in np.linspace(0.0, 2.0 * np.pi * rots, n + 1)[:-1]:
        c = avg @ (np.array([np.cos(theta), -np.sin(theta), -np.sin(theta * zrate), 1.0]) * rads)
        z = normalize(c - avg @ np.array([0.0, 0.0, -focal, 1.0]))
        out.append(np.concatenate([viewmatrix(z, up, c), [[0.0, 0.0, 0.0, 1.0]]], 0))
    return np.stack(out), avg


@pytest.mark.parametrize("dtype", DTYPES)
def test_spiral_matches_nerfs_render_path_spiral(dtype):
    rng = np.random.default_rng(0)
    # a forward-facing capture: cameras on a small patch, looking roughly along +y at a wall
    eyes = np.c_[rng.uniform(-0.5, 0.5, 6), rng.uniform(-0.1, 0.1, 6), rng.uniform(0.8, 1.2, 6)]
    targets = np.c_[rng.uniform(-0.2, 0.2, 6), np.full(6, 5.0), rng.uniform(0.9, 1.1, 6)]
    inputs = look_at(eyes, targets, up=(0.0, 0.0, 1.0))
    path = spiral_path(inputs.astype(dtype), 10, focus_depth=3.0)
    assert path.dtype == dtype and path.shape == (10, 4, 4)
    gl = opencv_to_opengl(inputs)
    _, avg = _nerf_spiral_opengl(gl, (1.0, 1.0, 1.0), 3.0, 2.0, 1)
    rads = np.percentile(np.abs((gl[:, :3, 3] - avg[:, 3]) @ avg[:, :3]), 90, 0)   # NeRF: after recentring
    want, _ = _nerf_spiral_opengl(gl, rads, 3.0, 2.0, 10)
    np.testing.assert_allclose(path, opengl_to_opencv(want), atol=2e-6 if dtype == np.float32 else 1e-12)
    assert is_rigid(path).all()


def test_spiral_golden_about_the_identity_pose():
    # by hand: theta = 0, 90, 180, 270 degrees; offset (cos, sin, sin(theta / 2)) * (1, 2, 0.5), focus (0, 0, 10)
    path = spiral_path(np.eye(4)[None], 4, focus_depth=10.0, radii=(1.0, 2.0, 0.5), rotations=1.0)
    s = 0.5 * np.sqrt(0.5)
    want = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, s], [-1.0, 0.0, 0.5], [0.0, -2.0, s]])
    np.testing.assert_allclose(path[:, :3, 3], want, atol=1e-12)
    for k in range(4):
        aim = np.array([0.0, 0.0, 10.0]) - want[k]
        np.testing.assert_allclose(path[k, :3, 2], aim / np.linalg.norm(aim), atol=1e-12)
        assert path[k, :3, 1] @ np.array([0.0, 1.0, 0.0]) > 0.9   # image down stays the mean camera's down


def test_spiral_focus_depth_golden_and_errors():
    # by hand: 1 / (0.25 / 0.9 + 0.75 / 50) = 1 / 0.29277... = 3.4155597723
    assert spiral_focus_depth(1.0, 10.0) == pytest.approx(3.4155597723, rel=1e-10)
    for near, far in ((0.0, 1.0), (2.0, 1.0), (np.nan, 1.0), (1.0, np.inf)):
        with pytest.raises(ValueError, match="near <= far"):
            spiral_focus_depth(near, far)
    with pytest.raises(ValueError, match="focus_depth"):
        spiral_path(np.eye(4)[None], 3, focus_depth=0.0)
    with pytest.raises(ValueError, match="radii"):
        spiral_path(np.eye(4)[None], 3, focus_depth=1.0, radii=(1.0, -1.0, 0.0))
    with pytest.raises(ValueError, match="focus point"):
        spiral_path(np.eye(4)[None], 4, focus_depth=1.0, radii=(0.0, 0.0, 1.0), rotations=1.0, z_rate=1.0)
    for bad in (None, "x", np.inf):
        with pytest.raises(ValueError, match="rotations must be a finite number"):
            spiral_path(np.eye(4)[None], 3, focus_depth=1.0, rotations=bad)
    opposed = np.stack([np.eye(4), np.diag([-1.0, 1.0, -1.0, 1.0])])
    with pytest.raises(ValueError, match="cancel out"):
        spiral_path(opposed, 3, focus_depth=1.0)


def test_orbit_uses_the_mean_not_the_median_elevation_and_distance():
    # by hand: elevations 10, 20, 60 -> mean 30 (median 20); distances 2, 3, 7 -> mean 4 (median 3)
    center = np.array([0.5, -1.0, 2.0])
    inputs = _inputs_looking_at(center, azs=[0.0, 120.0, 240.0], els=[10.0, 20.0, 60.0], rs=[2.0, 3.0, 7.0])
    path = orbit_path(inputs, 3)
    for k, az in enumerate([0.0, 120.0, 240.0]):
        np.testing.assert_allclose(path[k, :3, 3], _by_hand_position(center, az, 30.0, 4.0), atol=1e-9)


def test_spiral_input_checks_cover_every_argument():
    eye = np.eye(4)[None]
    # near == far is allowed (0 < near <= far); by hand 1 / (0.25 / 1.8 + 0.75 / 10) = 1 / (77 / 360) = 360 / 77
    assert spiral_focus_depth(2.0, 2.0) == pytest.approx(360.0 / 77.0, rel=1e-12)
    with pytest.raises(ValueError, match="focus_depth must be positive and finite"):
        spiral_path(eye, 3, focus_depth=np.inf)
    for bad in (None, "x", np.nan, np.inf):
        with pytest.raises(ValueError, match="z_rate must be a finite number"):
            spiral_path(eye, 3, focus_depth=1.0, z_rate=bad)
    for bad in ((0.5,), (1.0, 1.0), (1.0, np.nan, 0.0), (1.0, np.inf, 0.0)):
        with pytest.raises(ValueError, match="radii must be 3 finite numbers"):
            spiral_path(eye, 3, focus_depth=1.0, radii=bad)
    rolled = np.stack([np.eye(4), np.diag([-1.0, -1.0, 1.0, 1.0])])   # same optical axis, image-up axes opposed
    with pytest.raises(ValueError, match="cancel out"):
        spiral_path(rolled, 3, focus_depth=1.0)


def test_spiral_refuses_a_frame_within_a_relative_tolerance_of_the_focus_point():
    # the test is relative to the focus depth: at focus 1e4 an eye 1e-6 from the focus point is refused
    # (by hand: frame 1 has theta = pi / 2, so its offset is (0, 0, radii_z * sin(pi / 2)) = (0, 0, 1e4 - 1e-6))
    with pytest.raises(ValueError, match="focus point"):
        spiral_path(np.eye(4)[None], 4, focus_depth=1e4, radii=(0.0, 0.0, 1e4 - 1e-6), rotations=1.0, z_rate=1.0)
    spiral_path(np.eye(4)[None], 4, focus_depth=1e4, radii=(0.0, 0.0, 1e4 - 1e-3), rotations=1.0, z_rate=1.0)


def test_spiral_of_a_tiny_scene_is_the_unit_spiral_scaled():
    # The focus-point refusal is relative, so a spiral scales with the scene (independent expectation: the
    # same call at unit size, positions times 1e-10, rotations equal).
    unit = spiral_path(np.eye(4)[None], 4, focus_depth=1.0, radii=(0.1, 0.1, 0.0), rotations=1.0)
    tiny = spiral_path(np.eye(4)[None], 4, focus_depth=1e-10, radii=(1e-11, 1e-11, 0.0), rotations=1.0)
    assert np.allclose(tiny[:, :3, :3], unit[:, :3, :3], atol=1e-12)
    assert np.allclose(tiny[:, :3, 3], 1e-10 * unit[:, :3, 3], rtol=1e-12, atol=1e-24)


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("dtype", DTYPES)
def test_keyframe_path_turns_at_constant_rate_and_moves_linearly(dtype):
    """Keyframes 0, 60 and 150 degrees about z: 7 frames turn by 20, then 30 degrees a frame (SLERP within a
    segment is uniform), positions move in straight lines, every frame is rigid, frames 0 and 6 are the ends."""
    keys = np.tile(np.eye(4), (3, 1, 1))
    for i, (deg, pos) in enumerate([(0.0, (0, 0, 0)), (60.0, (3, 0, 0)), (150.0, (3, 6, 0))]):
        keys[i, :3, :3], keys[i, :3, 3] = _rot_z(deg), pos
    path = keyframe_path(keys.astype(dtype), 7)
    assert path.dtype == dtype and path.shape == (7, 4, 4) and all(is_rigid(p) for p in path.astype(np.float64))
    tol = 1e-5 if dtype == np.float32 else 1e-12
    angles = np.degrees(np.arctan2(path[:, 1, 0], path[:, 0, 0]))
    np.testing.assert_allclose(angles, [0, 20, 40, 60, 90, 120, 150], atol=10 * tol)
    np.testing.assert_allclose(path[:, :3, 3], [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [3, 2, 0], [3, 4, 0],
                                                [3, 6, 0]], atol=10 * tol)


def test_keyframe_path_of_one_keyframe_or_one_frame():
    keys = np.tile(np.eye(4), (2, 1, 1))
    keys[1, :3, 3] = (1.0, 2.0, 3.0)
    np.testing.assert_array_equal(keyframe_path(keys[1:], 3), np.repeat(keys[1:], 3, axis=0))
    np.testing.assert_array_equal(keyframe_path(keys, 1), keys[:1])
    with pytest.raises(ValueError, match="n must be an integer >= 1"):
        keyframe_path(keys, 0)
