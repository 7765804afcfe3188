"""Argument checks at the edge of senerf.geometry that the rest of the suite never reached: each bad input is
refused with a ValueError naming the argument, and the accepted side of each boundary still passes."""

import numpy as np
import pytest

from senerf.geometry import (
    Intrinsics,
    closest_point_to_axes,
    default_up,
    is_rigid,
    orthonormalize,
    pixel_centers,
    pixel_rays,
    pose_from_spherical,
    rays_from_pixels,
    reproject,
    sample_pseudo_views,
    spherical_basis,
    spherical_from_pose,
    unproject,
)

K = Intrinsics(10.0, 10.0, 2.0, 2.0, 4, 4)


# spherical.py


@pytest.mark.parametrize("up", [(np.nan, 0.0, 1.0), (0.0, np.inf, 1.0)])
def test_a_non_finite_up_is_refused(up):
    # Catches: _unit's finiteness check dropped (a NaN up gave a NaN basis, and NaN poses downstream).
    with pytest.raises(ValueError, match="up: must be finite and non-zero"):
        spherical_basis(up)
    with pytest.raises(ValueError, match="up: must be finite and non-zero"):
        pose_from_spherical(0.0, 10.0, 4.0, up=up)


def test_a_zero_up_is_refused_and_a_tiny_one_is_a_direction():
    # Catches: _unit's zero-length check dropped (0 / 0: a NaN basis), or made on the squared length (1e-200
    # underflows to 0 there, though it is a direction).
    with pytest.raises(ValueError, match="up: must be finite and non-zero"):
        spherical_basis((0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="up: must be finite and non-zero"):
        spherical_basis(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]))   # any zero row of a batch
    e1, e2, u = spherical_basis((0.0, 0.0, 1e-200))
    assert (e1.tolist(), e2.tolist(), u.tolist()) == ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])


@pytest.mark.parametrize("kw", [dict(azimuth=np.nan), dict(azimuth=np.array([0.0, np.inf])),
                                dict(center=(0.0, np.nan, 0.0)), dict(center=(np.inf, 0.0, 0.0))])
def test_pose_from_spherical_refuses_a_non_finite_azimuth_or_center(kw):
    # Catches: the azimuth / center finiteness check dropped (a NaN pose returned without a word).
    args = {"azimuth": 30.0, "center": (0.0, 0.0, 0.0), **kw}
    with pytest.raises(ValueError, match="pose_from_spherical: azimuth and center must be finite"):
        pose_from_spherical(args["azimuth"], 10.0, 4.0, center=args["center"])
    # the accepted side: any finite azimuth (beyond 360 too) and center
    c2w = pose_from_spherical(750.0, 10.0, 4.0, center=(1e6, -2.0, 3.0))
    assert np.isfinite(c2w).all() and is_rigid(c2w)


def test_spherical_from_pose_refuses_an_offset_that_is_not_finite():
    # Catches: the check on the camera's offset from center dropped (a non-finite center, or an offset that
    # overflows, gave NaN angles and an infinite radius).
    # (before 2026-11-23 all three said "camera centre equals center (or is non-finite)", blaming the camera)
    with pytest.raises(ValueError, match=r"spherical_from_pose: center must be finite"):
        spherical_from_pose(np.eye(4), center=(np.inf, 0.0, 0.0))
    far = np.eye(4)
    far[0, 3] = 1e308
    with np.errstate(over="ignore"), pytest.raises(ValueError, match="too far from center to subtract"):
        spherical_from_pose(far, center=(-1e308, 0.0, 0.0))      # 2e308 overflows float64
    with pytest.raises(ValueError, match="spherical_from_pose: a camera centre equals center$"):
        spherical_from_pose(np.eye(4), center=(0.0, 0.0, 0.0))
    az, el, r = spherical_from_pose(far, center=(1e307, 0.0, 0.0))   # the accepted side: a huge finite offset
    assert (float(az), float(el), float(r)) == pytest.approx((0.0, 0.0, 9e307))


def test_closest_point_to_axes_needs_a_pose():
    # Catches: the empty-input check dropped (no poses then read as "axes all parallel", a misleading reason).
    with pytest.raises(ValueError, match="closest_point_to_axes: need at least one finite pose"):
        closest_point_to_axes(np.zeros((0, 4, 4)))


@pytest.mark.parametrize("c2w", [np.eye(4), np.zeros((0, 4, 4)), np.zeros((2, 3, 3)), np.zeros((1, 2, 4, 4))],
                         ids=["one-pose-unbatched", "none", "3x3", "two-batch-dims"])
def test_default_up_refuses_what_is_not_a_list_of_poses(c2w):
    # Catches: default_up's shape check dropped (an IndexError, or NaN from the mean of no cameras, instead).
    with pytest.raises(ValueError, match=r"input_c2w: expected shape \(m, 4, 4\) with m >= 1"):
        default_up(c2w)


def test_default_up_accepts_one_pose_of_either_shape():
    # Catches: the shape check made too strict (m >= 2, or (4, 4) blocks only).
    pose = pose_from_spherical(30.0, 20.0, 4.0)
    for c2w in (pose[None], pose[None, :3]):
        np.testing.assert_allclose(default_up(c2w), -pose[:3, 1])   # one camera: its image-up axis


@pytest.mark.parametrize("c2w", [pose_from_spherical(0.0, 20.0, 4.0), np.zeros((0, 4, 4))], ids=["unbatched", "none"])
def test_sample_pseudo_views_needs_a_list_of_at_least_one_pose(c2w):
    # Catches: sample_pseudo_views' shape check dropped (an unbatched pose failed later, as parallel axes).
    with pytest.raises(ValueError, match=r"input_c2w: expected shape \(m, 4, 4\) with m >= 1"):
        sample_pseudo_views(c2w, 5.0, 2, np.random.default_rng(0))
    one = pose_from_spherical(0.0, 20.0, 4.0)[None]   # the accepted side: m = 1 with a center
    out, src = sample_pseudo_views(one, 0.0, 2, np.random.default_rng(0), center=(0.0, 0.0, 0.0))
    assert src.tolist() == [0, 0]
    np.testing.assert_allclose(out, np.repeat(one, 2, axis=0), atol=1e-12)


# warp.py, projection.py, rays.py: an Intrinsics, not a K matrix


@pytest.mark.parametrize("which", ["intrinsics_src", "intrinsics_dst"])
def test_reproject_refuses_a_matrix_for_intrinsics(which):
    # Catches: _check_k dropped (a 3x3 K then failed deep inside with an AttributeError, or was used wrongly).
    ks = {"intrinsics_src": K, "intrinsics_dst": K, which: K.K}
    with pytest.raises(ValueError, match=f"{which}: expected an Intrinsics, got ndarray"):
        reproject(np.full((4, 4), 2.0), ks["intrinsics_src"], np.eye(4), ks["intrinsics_dst"], np.eye(4))


def test_reproject_takes_one_source_pose():
    # Catches: the single-source-pose check dropped (a batch of source poses broadcast silently).
    with pytest.raises(ValueError, match=r"c2w_src: expected a single pose \(4, 4\), got \(2, 4, 4\)"):
        reproject(np.full((4, 4), 2.0), K, np.stack([np.eye(4)] * 2), K, np.eye(4))
    uv, ok = reproject(np.full((4, 4), 2.0), K, np.eye(4)[:3], K, np.stack([np.eye(4)] * 2))   # (3, 4) is one pose
    assert uv.shape == (2, 4, 4, 2) and ok.all()


@pytest.mark.parametrize("call", [
    lambda k: unproject([1.0, 1.0], 2.0, k, np.eye(4)),
    lambda k: pixel_centers(k),
    lambda k: pixel_rays(k, np.eye(4)),
    lambda k: rays_from_pixels([[1.0, 1.0]], k, np.eye(4)),
], ids=["unproject", "pixel_centers", "pixel_rays", "rays_from_pixels"])
@pytest.mark.parametrize("bad", [K.K, (10.0, 10.0, 2.0, 2.0, 4, 4), None], ids=["matrix", "tuple", "none"])
def test_camera_functions_refuse_what_is_not_an_intrinsics(call, bad):
    # Catches: the isinstance check of unproject (projection.py) or of rays.py's _check_intrinsics dropped.
    with pytest.raises(ValueError, match=f"intrinsics: expected an Intrinsics, got {type(bad).__name__}"):
        call(bad)
    assert np.isfinite(np.asarray(call(K)[0])).all()   # the accepted side


# poses.py, _util.py, intrinsics.py


def test_orthonormalize_needs_a_rotation_block_of_rank_two():
    # Catches: the rank check dropped (a rank-1 block has no nearest rotation; SVD picked an arbitrary one).
    rank1 = np.eye(4)
    rank1[1, 1] = rank1[2, 2] = 0.0
    with pytest.raises(ValueError, match="c2w: rotation block has rank < 2, cannot orthonormalize"):
        orthonormalize(rank1)
    rank2 = np.eye(4)                       # the accepted side: rank 2 fixes the rotation (third axis = cross)
    rank2[2, 2] = 0.0
    rank2[:3, 3] = (1.0, 2.0, 3.0)
    np.testing.assert_allclose(orthonormalize(rank2), np.array(
        [[1.0, 0, 0, 1.0], [0, 1.0, 0, 2.0], [0, 0, 1.0, 3.0], [0, 0, 0, 1.0]]), atol=1e-12)


@pytest.mark.parametrize("value,dtype", [("north", "<U5"), (1 + 2j, "complex128"), (None, "object")])
def test_non_numeric_arrays_are_refused_naming_the_argument(value, dtype):
    # Catches: as_float's dtype check dropped (a string raised NumPy's own error, a complex lost its imaginary part).
    with pytest.raises(ValueError, match=f"azimuth: expected a real numeric array, got dtype {dtype}"):
        pose_from_spherical(value, 10.0, 4.0)
    with pytest.raises(ValueError, match="uv: expected a real numeric array"):
        unproject(np.array([value, value]), 2.0, K, np.eye(4))
    for ok in (True, 3, np.uint8(7), 30.0):      # the accepted side: bools, ints and floats ("biuf")
        assert np.isfinite(pose_from_spherical(ok, 10.0, 4.0)).all()


@pytest.mark.parametrize("value", ["abc", None, [1.0], object()])
def test_intrinsics_refuse_a_value_that_is_not_a_number(value):
    # Catches: _positive_finite's conversion guard dropped (a TypeError / NumPy error escaping instead of a
    # ValueError naming the field).
    for i, name in enumerate(("fx", "fy", "cx", "cy")):
        args = [10.0, 10.0, 2.0, 2.0]
        args[i] = value
        with pytest.raises(ValueError, match=f"Intrinsics.{name}: expected a real number, got "):
            Intrinsics(*args, 4, 4)
    with pytest.raises(ValueError, match=r"Intrinsics.scaled\(factor\): expected a real number"):
        K.scaled(value)
    assert Intrinsics("10", np.float32(10.0), 2, 2.5, 4, 4).fx == 10.0   # the accepted side: what float() takes
