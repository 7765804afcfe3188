"""Tests of senerf/geometry/__init__.py: import hygiene, and the checks every public function makes at its edge
(an Intrinsics, not a K matrix; numeric arrays; rigid poses)."""

import subprocess
import sys

import numpy as np
import pytest

import senerf.geometry as geometry
from senerf.geometry import (Intrinsics, orbit_path, pixel_centers, pixel_rays, pose_from_spherical, project,
                             projection_matrix, rays_from_pixels, reproject, sample_pseudo_views, spiral_path,
                             unproject)

K = Intrinsics(10.0, 10.0, 2.0, 2.0, 4, 4)


def test_import_does_not_import_torch():
    code = "import senerf.geometry; import sys; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_all_names_exist():
    for name in geometry.__all__:
        assert hasattr(geometry, name), name


CAMERA_USERS = {
    "projection_matrix": lambda k: projection_matrix(k, np.eye(4)),
    "project": lambda k: project(np.array([[0.0, 0.0, 2.0]]), k, np.eye(4)),
    "unproject": lambda k: unproject([1.0, 1.0], 2.0, k, np.eye(4)),
    "pixel_centers": lambda k: pixel_centers(k),
    "pixel_rays": lambda k: pixel_rays(k, np.eye(4)),
    "rays_from_pixels": lambda k: rays_from_pixels([[1.0, 1.0]], k, np.eye(4)),
    "reproject intrinsics_src": lambda k: reproject(np.full((4, 4), 2.0), k, np.eye(4), K, np.eye(4)),
    "reproject intrinsics_dst": lambda k: reproject(np.full((4, 4), 2.0), K, np.eye(4), k, np.eye(4)),
}


@pytest.mark.parametrize("name", sorted(CAMERA_USERS))
@pytest.mark.parametrize("bad", [K.K, (10.0, 10.0, 2.0, 2.0, 4, 4), None], ids=["matrix", "tuple", "none"])
def test_camera_functions_refuse_what_is_not_an_intrinsics(name, bad):
    call = CAMERA_USERS[name]
    arg = name.split()[1] if " " in name else "intrinsics"
    with pytest.raises(ValueError, match=f"{arg}: expected an Intrinsics, got {type(bad).__name__}"):
        call(bad)
    assert np.isfinite(np.asarray(call(K)[0])).all()


@pytest.mark.parametrize("value,dtype", [("north", "<U5"), (1 + 2j, "complex128"), (None, "object")])
def test_non_numeric_arrays_are_refused_naming_the_argument(value, dtype):
    with pytest.raises(ValueError, match=f"azimuth: expected a real numeric array, got dtype {dtype}"):
        pose_from_spherical(value, 10.0, 4.0)
    with pytest.raises(ValueError, match="uv: expected a real numeric array"):
        unproject(np.array([value, value]), 2.0, K, np.eye(4))
    for ok in (True, 3, np.uint8(7), 30.0):      # bools, ints and floats are accepted
        assert np.isfinite(pose_from_spherical(ok, 10.0, 4.0)).all()


def _pose_users():
    """Every public function that uses a pose's rotation as one, called with pose ``p``."""
    k = Intrinsics(20.0, 20.0, 8.0, 6.0, 16, 12)
    depth = np.full((12, 16), 3.0)
    good = np.eye(4)
    return {
        "projection_matrix": lambda p: projection_matrix(k, p),
        "project": lambda p: project(np.array([[0.0, 0.0, 3.0]]), k, p),
        "unproject": lambda p: unproject([8.0, 6.0], 3.0, k, p),
        "pixel_rays": lambda p: pixel_rays(k, p),
        "rays_from_pixels": lambda p: rays_from_pixels([8.0, 6.0], k, p),
        "reproject c2w_src": lambda p: reproject(depth, k, p, k, good),
        "reproject c2w_dst": lambda p: reproject(depth, k, good, k, p),
        "sample_pseudo_views": lambda p: sample_pseudo_views(p[None], 5.0, 2, np.random.default_rng(0),
                                                             center=np.zeros(3)),
        "orbit_path": lambda p: orbit_path(p[None], 3, center=np.zeros(3), up=(0.0, 1.0, 0.0)),
        "spiral_path": lambda p: spiral_path(p[None], 3, focus_depth=2.0),
    }


@pytest.mark.parametrize("name", sorted(_pose_users()))
def test_scaled_or_reflected_poses_are_refused(name):
    """A scaled c2w (an SfM scale folded into the rotation) or a reflection (a mixed-up convention) gives
    wrong numbers silently if used as a rotation: every function that does so refuses it, by name."""
    call = _pose_users()[name]
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, -1.0]
    call(pose)                                  # a rigid pose is fine
    call(pose + np.diag([4e-4, 0.0, 0.0, 0.0]))  # and so is float noise within POSE_ATOL
    lists = ("sample_pseudo_views", "orbit_path", "spiral_path")
    arg = name.split()[1] if " " in name else ("input_c2w" if name in lists else "c2w")
    with pytest.raises(ValueError, match=rf"{arg}.*rotation not orthonormal"):
        call(pose @ np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match=rf"{arg}.*reflection"):
        call(pose @ np.diag([1.0, 1.0, -1.0, 1.0]))
