"""Tests of senerf/geometry/poses.py."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from senerf.geometry import (
    Intrinsics,
    invert_rigid,
    is_rigid,
    look_at,
    opencv_to_opengl,
    opengl_to_opencv,
    project,
    validate_rigid,
)

DTYPES = [np.float32, np.float64]
finite = st.floats(-100, 100, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite)


def random_rigid(rng, n=None):
    shape = () if n is None else (n,)
    q = rng.normal(size=shape + (4,))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    rot = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    out = np.zeros(shape + (4, 4))
    out[..., :3, :3] = rot
    out[..., :3, 3] = rng.normal(size=shape + (3,)) * 5
    out[..., 3, 3] = 1
    return out


@pytest.mark.parametrize("dtype", DTYPES)
def test_opengl_camera_looking_down_minus_z_sees_origin(dtype):
    # An OpenGL camera at (0, 0, 5) with identity rotation looks along -z, i.e. at the origin, with image up +y.
    gl = np.eye(4, dtype=dtype)
    gl[2, 3] = 5
    cv = opengl_to_opencv(gl)
    assert cv.dtype == dtype
    k = Intrinsics(100.0, 100.0, 50.0, 50.0, 100, 100)
    uv, z, ok = project(np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype), k, cv)
    assert ok.all()
    np.testing.assert_allclose(uv[0], [50, 50])
    np.testing.assert_allclose(z, [5, 5])
    assert uv[1, 1] < 50  # world +y (OpenGL image up) appears above the centre: smaller row index
    np.testing.assert_array_equal(cv[:3, 3], gl[:3, 3])  # the centre does not move


@pytest.mark.parametrize("dtype", DTYPES)
def test_convention_round_trip_and_shapes(dtype):
    c2w = random_rigid(np.random.default_rng(0), 5).astype(dtype)
    np.testing.assert_array_equal(opencv_to_opengl(opengl_to_opencv(c2w)), c2w)
    np.testing.assert_array_equal(opengl_to_opencv(c2w), c2w @ np.diag([1, -1, -1, 1]).astype(dtype))
    assert opengl_to_opencv(c2w[:, :3]).shape == (5, 3, 4)
    with pytest.raises(ValueError, match="c2w"):
        opengl_to_opencv(np.eye(3))


def test_is_rigid_and_validate_messages():
    good = random_rigid(np.random.default_rng(1), 4)
    assert is_rigid(good).all() and is_rigid(good).shape == (4,)
    validate_rigid(good)
    cases = {
        "non-finite": lambda p: p.__setitem__((0, 0), np.nan),
        "orthonormal": lambda p: p.__setitem__((0, 1), p[0, 1] + 0.01),
        "det": lambda p: p.__setitem__((slice(None), 0), -p[:, 0]),
        "last row": lambda p: p.__setitem__((3, 0), 0.5),
    }
    for what, corrupt in cases.items():
        poses = good.copy()
        corrupt(poses[2])
        assert is_rigid(poses).tolist() == [True, True, False, True]
        with pytest.raises(ValueError, match=what) as info:
            validate_rigid(poses, name="frames")
        assert "frames[2]" in str(info.value)
    # Within tolerance is fine, beyond it is not.
    off = good[0].copy()
    off[0, 1] += 1e-6
    assert is_rigid(off) and not is_rigid(off, atol=1e-9)


@pytest.mark.parametrize("dtype", DTYPES)
def test_invert_rigid_matches_linalg_inv(dtype):
    c2w = random_rigid(np.random.default_rng(3), (7)).astype(dtype)
    w2c = invert_rigid(c2w)
    assert w2c.dtype == dtype and w2c.shape == (7, 4, 4)
    tol = 1e-12 if dtype == np.float64 else 1e-5
    np.testing.assert_allclose(w2c, np.linalg.inv(c2w.astype(np.float64)), atol=tol)
    np.testing.assert_allclose(invert_rigid(c2w[:, :3]), w2c)


def check_look_at(c2w, eye, target, up):
    rot = c2w[:3, :3]
    assert abs(np.linalg.det(rot) - 1) < 1e-12
    assert np.abs(rot.T @ rot - np.eye(3)).max() < 1e-12
    view = (np.asarray(target) - np.asarray(eye)) / np.linalg.norm(np.subtract(target, eye))
    np.testing.assert_allclose(rot[:, 2], view, atol=1e-12)
    np.testing.assert_array_equal(c2w[:3, 3], eye)
    np.testing.assert_array_equal(c2w[3], [0, 0, 0, 1])
    up_u = np.asarray(up) / np.linalg.norm(up)
    assert -rot[:, 1] @ up_u >= -1e-12  # image up (-y) leans towards up (or is perpendicular at the pole)
    assert abs(rot[:, 0] @ up_u) < 1e-9 or np.linalg.norm(np.cross(view, up_u)) < 1e-6  # x horizontal


@settings(max_examples=150, deadline=None)
@given(vec3, vec3, vec3)
def test_look_at_valid_everywhere(eye, target, up):
    eye, target, up = np.array(eye), np.array(target), np.array(up)
    if np.linalg.norm(eye - target) < 1e-6 or np.linalg.norm(up) < 1e-6:
        return
    check_look_at(look_at(eye, target, up), eye, target, up)


@pytest.mark.parametrize("offset", [0.0, 1e-15, 1e-12, 1e-9, 1e-6, 1e-3])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_look_at_near_pole(offset, sign):
    # Eye exactly above (or below) the target along up, then slightly off the axis: still a proper rotation.
    up = np.array([0.0, 0.0, 1.0])
    target = np.array([0.3, -0.2, 0.1])
    for direction in (np.array([1.0, 0, 0]), np.array([0.6, 0.8, 0])):
        eye = target + sign * 4.0 * up + offset * direction
        check_look_at(look_at(eye, target, up), eye, target, up)


def test_look_at_batched_float32_and_errors():
    eyes = np.array([[0, -4, 1], [3, 0, 0], [0, 0, 5]], np.float32)
    c2w = look_at(eyes, np.zeros(3), (0, 0, 1))
    assert c2w.shape == (3, 4, 4) and c2w.dtype == np.float32
    assert is_rigid(c2w, atol=1e-6).all()
    # x = +x, y = -z, z = +y for a camera on -y looking at the origin (worked out by hand).
    np.testing.assert_allclose(look_at([0.0, -4.0, 0.0], [0.0, 0.0, 0.0])[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-15)
    with pytest.raises(ValueError, match="eye == target"):
        look_at([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="up"):
        look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="non-finite"):
        look_at([np.nan, 2.0, 3.0], [0.0, 0.0, 0.0])


@pytest.mark.parametrize("scale", [1e-300, 1e-200, 1e-150, 1.0, 1e150, 1e200, 1e300])
def test_look_at_is_scale_invariant(scale):
    # A scene in any unit: scaling eye, target and up by s changes the translation only, also where the
    # squares of the lengths (near 1e+-200) overflow or underflow float64.
    eye, target, up = np.array([0.7, -4.0, 1.3]), np.array([0.1, 0.2, -0.3]), np.array([0.1, 0.2, 1.0])
    ref = look_at(eye, target, up)
    with np.errstate(all="raise"):
        c2w = look_at(eye * scale, target * scale, up * scale)
    np.testing.assert_allclose(c2w[:3, :3], ref[:3, :3], atol=1e-15)
    np.testing.assert_array_equal(c2w[:3, 3], eye * scale)


def test_look_at_extremes_of_the_float64_range():
    # Eye and target at +-1e308: their difference overflows float64, the direction does not.
    np.testing.assert_array_equal(look_at([-1e308, 0, 0], [1e308, 0, 0])[:3, 2], [1, 0, 0])
    # Far from the origin, a target 4 away: the direction keeps every bit (t - e is exact here).
    c2w = look_at([1e6, 1e6, 1e6], [1e6, 1e6 + 4, 1e6])
    np.testing.assert_array_equal(c2w[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]])
