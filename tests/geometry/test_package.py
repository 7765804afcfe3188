"""Tests of senerf/geometry/__init__.py: import hygiene, runnable docstring examples, and the rigidity check
every pose-using public function makes at its edge."""

import doctest
import importlib
import subprocess
import sys

import numpy as np
import pytest

import senerf.geometry as geometry

MODULES = ["intrinsics", "poses", "spherical", "paths", "rays", "projection", "warp"]


def test_import_does_not_import_torch():
    code = "import senerf.geometry; import sys; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_all_names_exist():
    for name in geometry.__all__:
        assert hasattr(geometry, name), name


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    mod = importlib.import_module(f"senerf.geometry.{name}")
    result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def _pose_users():
    """Every public function that uses a pose's rotation as one, called with pose ``p``."""
    from senerf.geometry import (Intrinsics, orbit_path, pixel_rays, project, projection_matrix, rays_from_pixels,
                                 reproject, sample_pseudo_views, spiral_path, unproject)

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
    arg = name.split()[1] if " " in name else ("input_c2w" if name in ("sample_pseudo_views", "orbit_path", "spiral_path") else "c2w")
    with pytest.raises(ValueError, match=rf"{arg}.*rotation not orthonormal"):
        call(pose @ np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match=rf"{arg}.*reflection"):
        call(pose @ np.diag([1.0, 1.0, -1.0, 1.0]))
