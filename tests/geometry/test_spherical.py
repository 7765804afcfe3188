"""Tests of senerf/geometry/spherical.py."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from senerf.geometry import (
    closest_point_to_axes,
    default_up,
    is_rigid,
    look_at,
    opengl_to_opencv,
    pose_from_spherical,
    sample_pseudo_views,
    spherical_basis,
    spherical_from_pose,
)

DTYPES = [np.float32, np.float64]


def nerf_pose_spherical(theta, phi, radius):
    """The original NeRF's composition (OpenGL camera, z-up world), re-typed as an independent reference."""
    trans_t = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, radius], [0, 0, 0, 1]], float)
    p, t = np.radians(phi), np.radians(theta)
    rot_phi = np.array([[1, 0, 0, 0], [0, np.cos(p), -np.sin(p), 0], [0, np.sin(p), np.cos(p), 0], [0, 0, 0, 1]])
    rot_theta = np.array([[np.cos(t), 0, -np.sin(t), 0], [0, 1, 0, 0], [np.sin(t), 0, np.cos(t), 0], [0, 0, 0, 1]])
    flip = np.array([[-1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)
    return flip @ rot_theta @ rot_phi @ trans_t


@pytest.mark.parametrize("dtype", DTYPES)
def test_golden_az90_el30_r4(dtype):
    # By hand: centre = 4 (cos30 cos90, cos30 sin90, sin30) = (0, 3.4641, 2.0), NeRF's pose_spherical(0, -30, 4).
    c2w = pose_from_spherical(np.asarray(90.0, dtype), 30.0, 4.0)
    assert c2w.dtype == dtype
    np.testing.assert_allclose(c2w[:3, 3], [0.0, 4 * np.sqrt(3) / 2, 2.0], atol=1e-5)
    np.testing.assert_allclose(c2w, opengl_to_opencv(nerf_pose_spherical(0, -30, 4)), atol=1e-6)


@pytest.mark.parametrize("theta", [-170, -90, -20, 0, 45, 130])
@pytest.mark.parametrize("phi", [-80, -30, 0, 25, 70])
def test_matches_nerf_composition(theta, phi):
    # NeRF's camera looks at the origin with image up towards +z, like ours: the full poses must agree once
    # the angles are read back from the position.
    ref = opengl_to_opencv(nerf_pose_spherical(theta, phi, 3.0))
    az, el, r = spherical_from_pose(ref)
    assert float(el) == pytest.approx(-phi, abs=1e-9) and float(r) == pytest.approx(3.0)
    np.testing.assert_allclose(pose_from_spherical(az, el, r), ref, atol=1e-12)


def test_basis_right_handed_for_any_up():
    rng = np.random.default_rng(0)
    ups = np.concatenate([rng.normal(size=(50, 3)), np.eye(3), -np.eye(3)])
    e1, e2, u = spherical_basis(ups)
    frame = np.stack([e1, e2, u], -1)
    np.testing.assert_allclose(frame.transpose(0, 2, 1) @ frame, np.broadcast_to(np.eye(3), (56, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frame), 1.0)


angles = st.floats(-179.999, 180.0, allow_nan=False)
elevations = st.floats(-90.0, 90.0, allow_nan=False)
unit_ish = st.tuples(*(st.floats(-1, 1, allow_nan=False),) * 3).filter(lambda v: np.linalg.norm(v) > 0.1)


@settings(max_examples=150, deadline=None)
@given(angles, elevations, st.floats(1e-3, 1e3), unit_ish, unit_ish)
def test_spherical_round_trip(az, el, r, center, up):
    c2w = pose_from_spherical(az, el, r, center=center, up=up)
    assert is_rigid(c2w, atol=1e-12)
    assert np.linalg.det(c2w[:3, :3]) == pytest.approx(1.0, abs=1e-12)
    to_center = (np.asarray(center) - c2w[:3, 3]) / r
    np.testing.assert_allclose(c2w[:3, 2], to_center, atol=1e-9)  # looks at the centre
    up_u = np.asarray(up) / np.linalg.norm(up)
    assert -c2w[:3, 1] @ up_u >= -1e-12  # image up leans towards up
    az2, el2, r2 = spherical_from_pose(c2w, center, up)
    assert float(r2) == pytest.approx(r, rel=1e-12)
    assert float(el2) == pytest.approx(el, abs=1e-6)
    # Azimuth round trips too, also at the poles (read from the camera x axis there); compare on the circle.
    assert abs((float(az2) - az + 180) % 360 - 180) < 1e-6
    assert -180 < float(az2) <= 180


@pytest.mark.parametrize("el", [90.0, -90.0, 89.9999999, -89.9999999])
def test_poles_are_proper_rotations(el):
    az = np.linspace(-180, 180, 13)
    c2w = pose_from_spherical(az, el, 2.0)
    assert is_rigid(c2w, atol=1e-12).all()
    np.testing.assert_allclose(np.linalg.det(c2w[:, :3, :3]), 1.0, atol=1e-12)
    az2, el2, _ = spherical_from_pose(c2w)
    np.testing.assert_allclose(el2, el, atol=1e-6)
    np.testing.assert_allclose(np.cos(np.radians(az2 - az)), 1.0, atol=1e-9)


def test_bad_spherical_inputs():
    with pytest.raises(ValueError, match="elevation"):
        pose_from_spherical(0.0, 91.0, 1.0)
    with pytest.raises(ValueError, match="radius"):
        pose_from_spherical(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="centre"):
        spherical_from_pose(np.eye(4), center=(0, 0, 0))


@pytest.mark.parametrize("dtype", DTYPES)
def test_closest_point_to_axes(dtype):
    rng = np.random.default_rng(4)
    target = np.array([0.5, -1.0, 2.0])
    eyes = target + rng.normal(size=(6, 3)) * 4
    c2w = look_at(eyes, target).astype(dtype)
    p = closest_point_to_axes(c2w)
    assert p.shape == (3,) and p.dtype == dtype
    np.testing.assert_allclose(p, target, atol=1e-9 if dtype == np.float64 else 1e-4)
    # Two skew lines: x-axis through (0,0,0) and y-axis through (0,0,2): midpoint (0,0,1) by hand.
    a = look_at([-5.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    b = look_at([0.0, -5.0, 2.0], [0.0, 0.0, 2.0])
    np.testing.assert_allclose(closest_point_to_axes(np.stack([a, b])), [0, 0, 1], atol=1e-12)


def test_closest_point_parallel_axes_raise():
    c2w = look_at(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0.0, 0, 1], [1, 0, 1], [0, 1, 1]]))
    with pytest.raises(ValueError, match="parallel"):
        closest_point_to_axes(c2w)
    with pytest.raises(ValueError, match="parallel"):
        closest_point_to_axes(c2w[:1])


def wrap(a):
    return (np.asarray(a) + 180) % 360 - 180


@pytest.mark.parametrize("dtype", DTYPES)
def test_sample_pseudo_views(dtype):
    center = np.array([0.1, 0.2, 0.3])
    inputs = pose_from_spherical(np.array([0.0, 100.0, -150.0]), np.array([20.0, 89.5, -45.0]),
                                 np.array([4.0, 3.0, 5.0]), center=center).astype(dtype)
    c2w, src = sample_pseudo_views(inputs, 10.0, 30, np.random.default_rng(7), up=(0, 0, 1))
    assert c2w.shape == (30, 4, 4) and c2w.dtype == dtype and src.dtype == np.int64
    assert src.tolist() == [k % 3 for k in range(30)]
    assert is_rigid(c2w, atol=1e-5).all()
    # Default centre: the axes' meeting point.
    az, el, r = spherical_from_pose(c2w.astype(np.float64), center, (0, 0, 1))
    az0, el0, r0 = spherical_from_pose(inputs.astype(np.float64), center, (0, 0, 1))
    tol = 1e-4 if dtype == np.float32 else 1e-8
    assert (np.abs(wrap(az - az0[src])) <= 10 + tol).all()
    assert (np.abs(el - el0[src]) <= 10 + tol).all()
    assert (np.abs(el) <= 89.9 + tol).all()  # the view at 89.5 never crosses the pole
    np.testing.assert_allclose(r, r0[src], rtol=1e-5)
    np.testing.assert_allclose(c2w[:, :3, 2], (center - c2w[:, :3, 3]) / r[:, None], atol=1e-4)
    # Deterministic for a seed, different for another.
    again, _ = sample_pseudo_views(inputs, 10.0, 30, np.random.default_rng(7), up=(0, 0, 1))
    np.testing.assert_array_equal(again, c2w)
    other, _ = sample_pseudo_views(inputs, 10.0, 30, np.random.default_rng(8), up=(0, 0, 1))
    assert not np.allclose(other, c2w)
    # The offsets actually spread over the window.
    assert np.abs(wrap(az - az0[src])).max() > 5


def test_sample_pseudo_views_zero_offset_explicit_center_up_and_errors():
    inputs = pose_from_spherical(np.array([30.0, 60.0]), 10.0, 4.0, up=(0, 1, 0))
    c2w, src = sample_pseudo_views(inputs, 0.0, 4, np.random.default_rng(0), center=(0, 0, 0), up=(0, 1, 0))
    np.testing.assert_allclose(c2w, inputs[src], atol=1e-12)
    # Default up = normalized mean of the image-up axes (-y); at elevation 0 each one is exactly up = +y.
    level = pose_from_spherical(np.array([30.0, 60.0, 150.0]), 0.0, 4.0, up=(0, 1, 0))
    c2w, _ = sample_pseudo_views(level, 0.0, 3, np.random.default_rng(0))
    np.testing.assert_allclose(c2w, level, atol=1e-9)
    assert sample_pseudo_views(inputs, 5.0, 0, np.random.default_rng(0))[0].shape == (0, 4, 4)
    with pytest.raises(ValueError, match="rng"):
        sample_pseudo_views(inputs, 5.0, 2, 0)
    with pytest.raises(ValueError, match="max_offset"):
        sample_pseudo_views(inputs, -1.0, 2, np.random.default_rng(0))


def _rodrigues(axis, angle_deg):
    """Rotation about ``axis`` by ``angle_deg`` (right hand), by OpenCV's Rodrigues (independent of senerf)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    return cv2.Rodrigues(k * np.radians(angle_deg))[0]


def _rolled_off_axis_inputs():
    """Three cameras around a centre, each rolled about its optical axis and aimed a little off the centre."""
    center = np.array([0.3, -0.2, 0.5])
    base = pose_from_spherical(np.array([10.0, 140.0, -100.0]), np.array([30.0, 55.0, 15.0]), 4.0, center=center)
    out = base.copy()
    for i, (roll, yaw) in enumerate([(12.0, 2.0), (-25.0, -3.0), (40.0, 1.5)]):
        out[i, :3, :3] = base[i, :3, :3] @ _rodrigues([0, 0, 1], roll) @ _rodrigues([0, 1, 0], yaw)
    return out, center


@pytest.mark.parametrize("dtype", DTYPES)
def test_zero_offset_returns_the_inputs_whatever_their_roll(dtype):
    """Offset 0 reproduces every input exactly, with the default centre and up, whatever the inputs' roll."""
    inputs, _ = _rolled_off_axis_inputs()
    inputs = inputs.astype(dtype)
    c2w, src = sample_pseudo_views(inputs, 0.0, 6, np.random.default_rng(3))
    tol = 1e-5 if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(c2w, inputs[src], atol=tol)
    level = pose_from_spherical(np.array([0.0, 120.0]), 20.0, 4.0)  # the docstring's example, not rolled
    again, src = sample_pseudo_views(level, 0.0, 2, np.random.default_rng(0))
    np.testing.assert_allclose(again, level[src], atol=1e-12)


def test_pseudo_views_are_their_sources_carried_rigidly_about_the_centre():
    """Each pseudo pose = R @ source about ``center``, with R the elevation turn about the source's tangent
    then the azimuth turn about ``up`` (built here with Rodrigues' formula from the angles the output has)."""
    inputs, center = _rolled_off_axis_inputs()
    up = np.array([0.0, 0.0, 1.0])
    c2w, src = sample_pseudo_views(inputs, 10.0, 12, np.random.default_rng(5), center=center, up=up)
    az, el, r = spherical_from_pose(c2w, center, up)
    az0, el0, r0 = spherical_from_pose(inputs, center, up)
    assert is_rigid(c2w, atol=1e-9).all()
    np.testing.assert_allclose(r, r0[src], rtol=1e-12)
    for k in range(12):
        d = inputs[src[k], :3, 3] - center
        tangent_axis = np.cross(d, up)
        rot = _rodrigues(up, az[k] - az0[src[k]]) @ _rodrigues(tangent_axis, el[k] - el0[src[k]])
        np.testing.assert_allclose(c2w[k, :3, :3], rot @ inputs[src[k], :3, :3], atol=1e-9)
        np.testing.assert_allclose(c2w[k, :3, 3], center + rot @ d, atol=1e-9)
    assert np.abs(wrap(az - az0[src])).max() > 5 and np.abs(el - el0[src]).max() > 5


def test_default_up_is_the_common_horizon_normal():
    # cameras at three azimuths and elevations 20-60 degrees about +z: the plane of their x axes is level
    inputs = pose_from_spherical(np.array([0.0, 30.0, 200.0]), np.array([20.0, 60.0, 35.0]), 4.0)
    np.testing.assert_allclose(default_up(inputs), [0.0, 0.0, 1.0], atol=1e-12)
    mean_up = -inputs[:, :3, 1].mean(axis=0)
    assert np.degrees(np.arccos(mean_up[2] / np.linalg.norm(mean_up))) > 10  # the plain mean leans over
    # about another axis, and for float32 input
    tilted = pose_from_spherical(np.array([0.0, 90.0]), np.array([10.0, 40.0]), 3.0, up=(0.0, 1.0, 1.0))
    np.testing.assert_allclose(default_up(tilted.astype(np.float32)), np.array([0, 1, 1]) / np.sqrt(2), atol=1e-6)
    # one camera, or x axes (nearly) parallel (a forward-facing capture): the mean image-up axis
    one = pose_from_spherical(45.0, 30.0, 4.0)[None]
    np.testing.assert_allclose(default_up(one), -one[0, :3, 1], atol=1e-12)
    forward = pose_from_spherical(np.array([0.0, 3.0, 6.0]), np.array([0.0, 2.0, -2.0]), 4.0)
    mean_fwd = -forward[:, :3, 1].mean(axis=0)
    np.testing.assert_allclose(default_up(forward), mean_fwd / np.linalg.norm(mean_fwd), atol=1e-12)
    with pytest.raises(ValueError, match="cancel out"):
        flipped = np.stack([one[0], one[0] @ np.diag([-1.0, -1.0, 1.0, 1.0])])  # rolled by 180: ups cancel
        default_up(flipped)


@pytest.mark.parametrize("dtype", DTYPES)
def test_azimuth_stays_in_the_half_open_range_after_the_cast(dtype):
    """(-180, 180] in the output dtype: an azimuth a hair above -180 rounds to -180 in float32 and must
    come back as +180 (the same direction)."""
    pose = pose_from_spherical(np.array([-179.999999, 180.0, -180.0, 179.9]), 10.0, 4.0).astype(dtype)
    az, _, _ = spherical_from_pose(pose)
    assert az.dtype == dtype and np.all(az > -180.0) and np.all(az <= 180.0)
    np.testing.assert_allclose(wrap(az.astype(np.float64) - [-179.999999, 180.0, 180.0, 179.9]), 0, atol=1e-4)


def test_nearest_view_angles_refuses_undefined_directions():
    from senerf.geometry import nearest_view_angles

    train = pose_from_spherical(np.array([0.0, 90.0]), 0.0, 4.0)
    test = pose_from_spherical(np.array([45.0]), 0.0, 4.0)
    np.testing.assert_allclose(nearest_view_angles(train, test), [45.0], atol=1e-9)
    at_centre = test.copy()
    at_centre[0, :3, 3] = 0.0
    with pytest.raises(ValueError, match=r"test_c2w\[0\]: .*camera centre at center"):
        nearest_view_angles(train, at_centre)
    nan_pose = train.copy()
    nan_pose[1, 0, 3] = np.nan
    with pytest.raises(ValueError, match=r"train_c2w\[1\]: non-finite"):
        nearest_view_angles(nan_pose, test)


@pytest.mark.parametrize("radius", [1e-300, 1e-200, 1e200, 1e300])
def test_spherical_round_trip_at_extreme_radii(radius):
    # Squared radii under- or overflow float64 here; the angles must not notice (by hand: az 30, el 20).
    c2w = pose_from_spherical(30.0, 20.0, radius)
    az, el, r = spherical_from_pose(c2w)
    assert float(az) == pytest.approx(30.0, abs=1e-9) and float(el) == pytest.approx(20.0, abs=1e-9)
    assert float(r) == pytest.approx(radius, rel=1e-12)
    np.testing.assert_allclose(c2w[:3, :3], pose_from_spherical(30.0, 20.0, 1.0)[:3, :3], atol=1e-15)
    from senerf.geometry import nearest_view_angles

    train = pose_from_spherical(np.array([0.0, 90.0]), 0.0, radius)
    # Nearest is the view at az 0 (cos = cos 20 cos 30, against cos 20 cos 60 for az 90).
    expected = np.degrees(np.arccos(np.cos(np.radians(20.0)) * np.cos(np.radians(30.0))))
    np.testing.assert_allclose(nearest_view_angles(train, c2w[None], center=np.zeros(3)), [expected], atol=1e-9)


def test_nearest_view_angles_takes_the_nearest_and_the_optical_axis_path():
    # Catches: the minimum over training views replaced by the maximum (a test view at 45 degrees between
    # views at 0 and 90 cannot tell them apart), and the center=None path reading anything but camera z.
    from senerf.geometry import nearest_view_angles

    # Directions from the origin: training views at azimuth 0 and 90 (elevation 0), test view at azimuth 10:
    # nearest 10 degrees (the farthest would be 80).
    train = pose_from_spherical(np.array([0.0, 90.0]), 0.0, 4.0)
    test = pose_from_spherical(np.array([10.0, -30.0]), 0.0, np.array([2.0, 7.0]))
    np.testing.assert_allclose(nearest_view_angles(train, test), [10.0, 30.0], atol=1e-9)
    # Optical axes (center=None), rotations built with cv2.Rodrigues.  Train: identity (z = +z) at (5, 0, 0)
    # and a 90-degree turn about +y (z = +x) at (0, 5, 0).  Test: 30 degrees about +x (z = (0, -sin 30,
    # cos 30)) at (0, 0, 7): its axis is 30 degrees from +z and 90 from +x, so the answer is 30, while the
    # directions from the origin (+x, +y against +z) are 90 degrees from both.
    def pose(axis, angle, position):
        c2w = np.eye(4)
        c2w[:3, :3] = _rodrigues(axis, angle)
        c2w[:3, 3] = position
        return c2w

    train_ff = np.stack([pose([0, 1, 0], 0.0, [5.0, 0, 0]), pose([0, 1, 0], 90.0, [0, 5.0, 0])])
    test_ff = pose([1, 0, 0], 30.0, [0, 0, 7.0])[None]
    np.testing.assert_allclose(train_ff[1, :3, 2], [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(test_ff[0, :3, 2], [0.0, -0.5, np.sqrt(3) / 2], atol=1e-15)
    np.testing.assert_allclose(nearest_view_angles(train_ff, test_ff, center=None), [30.0], atol=1e-9)
    np.testing.assert_allclose(nearest_view_angles(train_ff, test_ff), [90.0], atol=1e-9)
    np.testing.assert_allclose(nearest_view_angles(train_ff[:, :3], test_ff[:, :3], center=None), [30.0],
                               atol=1e-9)


@pytest.mark.parametrize("dtype", DTYPES)
def test_sample_pseudo_views_offsets_go_both_ways(dtype):
    # Catches: azimuth offsets drawn from [0, off] instead of [-off, off], and the elevation window starting
    # at the source elevation (upward only) instead of el - off.
    # Three views about a centre with +z up, elevations far from the poles (the window is never clipped).
    # Their x axes are horizontal and their axes meet at the centre, so the sampler's default up is +z and
    # its default centre is `center`; the offsets are measured here about those, with 60 draws from 10 degrees.
    center = np.array([0.1, -0.2, 0.3])
    inputs = pose_from_spherical(np.array([0.0, 130.0, -110.0]), np.array([20.0, 35.0, -15.0]), 4.0,
                                 center=center).astype(dtype)
    np.testing.assert_allclose(default_up(inputs), [0.0, 0.0, 1.0], atol=1e-5)
    np.testing.assert_allclose(closest_point_to_axes(inputs), center, atol=1e-4)
    c2w, src = sample_pseudo_views(inputs, 10.0, 60, np.random.default_rng(1))
    az, el, _ = spherical_from_pose(c2w.astype(np.float64), center, (0, 0, 1))
    az0, el0, _ = spherical_from_pose(inputs.astype(np.float64), center, (0, 0, 1))
    d_az, d_el = wrap(az - az0[src]), el - el0[src]
    tol = 1e-3 if dtype == np.float32 else 1e-8
    assert (np.abs(d_az) <= 10 + tol).all() and (np.abs(d_el) <= 10 + tol).all()
    assert d_az.min() < -5 and d_az.max() > 5
    assert d_el.min() < -5 and d_el.max() > 5


@pytest.mark.parametrize("center", [(0.1, 0.2, 0.3), (1e3, -2e3, 5.0)])
@pytest.mark.parametrize("elevation", [90.0, -90.0])
def test_float32_cameras_put_on_a_pole_keep_their_azimuth(center, elevation):
    # A float32 camera centre is off the pole by its own rounding (~1e-7 |t|): its azimuth must still be the one
    # given, not that rounding's. Expected values: the azimuths given, and for the derived functions the same
    # calls on float64 poses.
    for az in (30.0, -150.0, 180.0):
        pose = pose_from_spherical(np.float32(az), elevation, 4.0, center=center)
        assert pose.dtype == np.float32
        got = float(spherical_from_pose(pose, center=center)[0])
        assert abs((got - az + 180.0) % 360.0 - 180.0) < 1e-3, (az, got)
    az_in, el_in = np.array([30.0, 150.0]), np.array([elevation, 20.0])
    inputs32 = pose_from_spherical(az_in.astype(np.float32), el_in, 4.0, center=center)
    inputs64 = pose_from_spherical(az_in, el_in, 4.0, center=center)
    for offset in (0.0, 5.0):
        pseudo32, _ = sample_pseudo_views(inputs32, offset, 6, np.random.default_rng(0), center=center, up=(0, 0, 1))
        pseudo64, _ = sample_pseudo_views(inputs64, offset, 6, np.random.default_rng(0), center=center, up=(0, 0, 1))
        assert np.abs(pseudo32 - pseudo64).max() < 1e-3 * max(1.0, np.abs(center).max())
    from senerf.geometry import orbit_path

    frames = orbit_path(inputs32, 4, center=center, up=(0, 0, 1))
    az_frames = spherical_from_pose(frames.astype(np.float64), center=center)[0]
    # float32 frames 2e3 from the origin hold their azimuth to ~1e-3 degrees
    tol = 1e-3 * max(1.0, np.abs(center).max() / 100.0)
    assert np.allclose((az_frames - np.array([30.0, 120.0, 210.0, 300.0]) + 180.0) % 360.0 - 180.0, 0.0, atol=tol)


@pytest.mark.parametrize("dtype", DTYPES)
def test_offset_zero_gives_back_views_at_the_poles_and_wider_offsets_never_cross_one(dtype):
    # a top view (90) comes back at 90, not clipped to the +-89.9 window
    inputs = pose_from_spherical(np.array([30.0, 120.0, -60.0]), np.array([90.0, 20.0, -90.0]), 4.0).astype(dtype)
    same, _ = sample_pseudo_views(inputs, 0.0, 3, np.random.default_rng(0), center=(0, 0, 0), up=(0, 0, 1))
    assert np.abs(same - inputs).max() < (1e-12 if dtype == np.float64 else 1e-5)
    wide, src = sample_pseudo_views(inputs, 10.0, 30, np.random.default_rng(1), center=(0, 0, 0), up=(0, 0, 1))
    el = spherical_from_pose(wide.astype(np.float64))[1]
    assert (el[src == 0] >= 80.0 - 1e-4).all() and (el[src == 0] <= 90.0).all()
    assert (el[src == 2] <= -80.0 + 1e-4).all() and (el[src == 2] >= -90.0).all()
    assert is_rigid(wide, atol=1e-5).all()


@pytest.mark.parametrize("eye", [(0.0, 0.0, 0.0), (1.0, 2.0, 3.0), (1e4, -3.0, 0.5)])
def test_inputs_sharing_one_camera_centre_are_refused_naming_center(eye):
    # cameras turned about one point: their optical axes meet at it, so the default centre is a camera centre
    # plus rounding, and turning about it is undefined
    same = np.stack([look_at(eye, np.add(eye, d)) for d in ([1, 0, 0], [0, 1, 0], [0.3, 0.2, -1.0])])
    with pytest.raises(ValueError, match=r"input_c2w\[0\]'s camera centre coincides with center"):
        sample_pseudo_views(same, 5.0, 3, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"input_c2w\[1\]'s camera centre coincides with center"):
        sample_pseudo_views(np.stack([look_at(np.add(eye, (5.0, 0.0, 0.0)), eye), same[0]]), 5.0, 3,
                            np.random.default_rng(0), center=eye, up=(0, 0, 1))


def test_sample_pseudo_views_names_bad_counts_and_centres():
    inputs = pose_from_spherical(np.array([0.0, 120.0]), 20.0, 4.0)
    for n in (np.nan, np.inf, 2.5, True, "3"):
        with pytest.raises(ValueError, match="^n: must be an integer >= 0"):
            sample_pseudo_views(inputs, 1.0, n, np.random.default_rng(0))
    assert sample_pseudo_views(inputs, 1.0, 3.0, np.random.default_rng(0))[0].shape == (3, 4, 4)
    with pytest.raises(ValueError, match="center"):
        sample_pseudo_views(inputs, 1.0, 2, np.random.default_rng(0), center=(0.0, 0.0))
    with pytest.raises(ValueError, match=r"input_c2w\[0\]: non-finite"):
        default_up(np.full((2, 4, 4), np.nan))


def test_functions_reading_camera_axes_refuse_scaled_or_mirrored_rotations():
    # closest_point_to_axes, default_up and nearest_view_angles (optical-axis mode) use the rotations as such:
    # a rotation scaled by 2 or a reflection is refused, naming the argument
    from senerf.geometry import nearest_view_angles

    poses = pose_from_spherical(np.array([0.0, 90.0, 200.0]), 20.0, 4.0)
    scaled, mirrored = poses.copy(), poses.copy()
    scaled[1, :3, :3] *= 2.0
    mirrored[2, :3, 0] *= -1.0
    for bad in (scaled, mirrored):
        with pytest.raises(ValueError, match="c2w"):
            closest_point_to_axes(bad)
        with pytest.raises(ValueError, match="input_c2w"):
            default_up(bad)
        with pytest.raises(ValueError, match="train_c2w"):
            nearest_view_angles(bad, poses, center=None)
    assert np.isfinite(nearest_view_angles(scaled, poses)).all()   # positions only: the rotation is not used


# Argument checks at the edge: each bad input is refused with a ValueError naming the argument, and the accepted
# side of each boundary passes.


@pytest.mark.parametrize("up", [(np.nan, 0.0, 1.0), (0.0, np.inf, 1.0), (0.0, 0.0, 0.0)])
def test_a_non_finite_or_zero_up_is_refused(up):
    with pytest.raises(ValueError, match="up: must be finite and non-zero"):
        spherical_basis(up)
    with pytest.raises(ValueError, match="up: must be finite and non-zero"):
        pose_from_spherical(0.0, 10.0, 4.0, up=up)


def test_a_zero_row_of_up_is_refused_and_a_tiny_up_is_a_direction():
    # a zero-length check on the squared length would refuse 1e-200 (its square underflows to 0)
    with pytest.raises(ValueError, match="up: must be finite and non-zero"):
        spherical_basis(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]))
    e1, e2, u = spherical_basis((0.0, 0.0, 1e-200))
    assert (e1.tolist(), e2.tolist(), u.tolist()) == ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])


@pytest.mark.parametrize("kw", [dict(azimuth=np.nan), dict(azimuth=np.array([0.0, np.inf])),
                                dict(center=(0.0, np.nan, 0.0)), dict(center=(np.inf, 0.0, 0.0))])
def test_pose_from_spherical_refuses_a_non_finite_azimuth_or_center(kw):
    args = {"azimuth": 30.0, "center": (0.0, 0.0, 0.0), **kw}
    with pytest.raises(ValueError, match="azimuth and center must be finite"):
        pose_from_spherical(args["azimuth"], 10.0, 4.0, center=args["center"])
    c2w = pose_from_spherical(750.0, 10.0, 4.0, center=(1e6, -2.0, 3.0))   # any finite azimuth and center
    assert np.isfinite(c2w).all() and is_rigid(c2w)


def test_spherical_from_pose_refuses_an_offset_that_is_not_finite():
    with pytest.raises(ValueError, match="center must be finite"):
        spherical_from_pose(np.eye(4), center=(np.inf, 0.0, 0.0))
    far = np.eye(4)
    far[0, 3] = 1e308
    with np.errstate(over="ignore"), pytest.raises(ValueError, match="too far from center"):
        spherical_from_pose(far, center=(-1e308, 0.0, 0.0))      # 2e308 overflows float64
    az, el, r = spherical_from_pose(far, center=(1e307, 0.0, 0.0))   # a huge finite offset is fine
    assert (float(az), float(el), float(r)) == pytest.approx((0.0, 0.0, 9e307))


def test_closest_point_to_axes_needs_a_pose():
    with pytest.raises(ValueError, match="at least one"):
        closest_point_to_axes(np.zeros((0, 4, 4)))


@pytest.mark.parametrize("c2w", [np.eye(4), np.zeros((0, 4, 4)), np.zeros((2, 3, 3)), np.zeros((1, 2, 4, 4))],
                         ids=["one-pose-unbatched", "none", "3x3", "two-batch-dims"])
def test_default_up_refuses_what_is_not_a_list_of_poses(c2w):
    with pytest.raises(ValueError, match="input_c2w: expected shape"):
        default_up(c2w)


def test_default_up_of_one_pose_of_either_shape_is_its_image_up_axis():
    pose = pose_from_spherical(30.0, 20.0, 4.0)
    for c2w in (pose[None], pose[None, :3]):
        np.testing.assert_allclose(default_up(c2w), -pose[:3, 1])


@pytest.mark.parametrize("c2w", [pose_from_spherical(0.0, 20.0, 4.0), np.zeros((0, 4, 4))], ids=["unbatched", "none"])
def test_sample_pseudo_views_needs_a_list_of_at_least_one_pose(c2w):
    with pytest.raises(ValueError, match=r"input_c2w: expected shape \(m, 4, 4\)"):
        sample_pseudo_views(c2w, 5.0, 2, np.random.default_rng(0))
    one = pose_from_spherical(0.0, 20.0, 4.0)[None]   # m = 1 with a center
    out, src = sample_pseudo_views(one, 0.0, 2, np.random.default_rng(0), center=(0.0, 0.0, 0.0))
    assert src.tolist() == [0, 0]
    np.testing.assert_allclose(out, np.repeat(one, 2, axis=0), atol=1e-12)
