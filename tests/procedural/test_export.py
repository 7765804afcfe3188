"""Tests of senerf/procedural/export.py: Blender-format export read back by senerf.data.load_scene."""

from __future__ import annotations

import json
import math
import time

import imageio.v3 as iio
import numpy as np
import pytest

from senerf.data import load_scene
from senerf.errors import InputError
from senerf.geometry import Intrinsics, opengl_to_opencv, spherical_from_pose
from senerf.procedural.export import (
    DEMO_FEWSHOT_VIEWS,
    export_blender_scene,
    hemisphere_poses,
    make_demo_scene,
    one_side_poses,
    ring_poses,
)
from senerf.procedural.render import render
from senerf.procedural.scene import SceneConfig, build_scene

W, H = 48, 40  # non-square on purpose: catches width/height mix-ups


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("proc") / "scene"
    cfg = SceneConfig(seed=2)
    export_blender_scene(out, cfg, n_train=5, n_val=2, n_test=3, width=W, height=H, seed=4, n_one_side=2)
    return out, cfg


def _json_poses(out, split):
    doc = json.loads((out / f"transforms_{split}.json").read_text())
    return doc, opengl_to_opencv(np.array([f["transform_matrix"] for f in doc["frames"]], dtype=np.float64))


def test_round_trip_through_load_scene(exported):
    out, cfg = exported
    scene = load_scene(out)
    assert [len(scene.splits[s]) for s in ("train", "val", "test")] == [5, 2, 3]
    assert scene.rgb.shape == (10, H, W, 3) and scene.alpha.shape == (10, H, W)
    intr = Intrinsics.from_fov(math.degrees(0.6911112070083618), W, H)
    assert np.allclose(scene.intrinsics.K, intr.K, rtol=1e-12, atol=1e-9)
    built = build_scene(cfg)
    # regenerate the cameras independently from the same seed and compare poses to 1e-9
    rng = np.random.default_rng(4)
    train = np.concatenate([one_side_poses(2, rng), hemisphere_poses(3, rng)])
    expect = {"train": train, "val": hemisphere_poses(2, rng), "test": ring_poses(3)}
    for split, poses in expect.items():
        idx = scene.splits[split]
        assert np.max(np.abs(scene.c2w[idx] - poses)) < 1e-9
        for k, i in enumerate(idx):
            r = render(built, intr, poses[k])
            # images equal up to 8-bit quantisation (straight colour, transparent background)
            assert np.max(np.abs(scene.rgb[i] - r.rgb)) <= 0.5 / 255 + 1e-6
            assert np.array_equal(scene.alpha[i], r.alpha)
            depth = np.load(out / split / f"r_{k}_depth.npy")
            assert depth.dtype == np.float32 and depth.shape == (H, W)
            assert np.array_equal(depth, r.depth_or_zero())


def test_json_follows_blender_convention(exported):
    out, _ = exported
    doc, c2w = _json_poses(out, "test")
    assert doc["camera_angle_x"] == pytest.approx(0.6911112070083618)
    assert [f["file_path"] for f in doc["frames"]] == ["./test/r_0", "./test/r_1", "./test/r_2"]
    # OpenGL camera looks along -z: the origin is in front of (negative camera z of) each camera
    gl = np.array([f["transform_matrix"] for f in doc["frames"]])
    to_origin = -gl[:, :3, 3]
    assert np.all(np.einsum("nij,ni->nj", gl[:, :3, :3], to_origin)[:, 2] < 0)
    az, el, rad = spherical_from_pose(c2w)
    assert np.allclose(el, 30.0) and np.allclose(rad, 4.0)
    assert np.allclose(np.sort(np.mod(az, 360.0)), [0.0, 120.0, 240.0], atol=1e-9)
    png = iio.imread(out / "test" / "r_0.png")
    assert png.shape == (H, W, 4) and png.dtype == np.uint8
    assert np.all(png[png[..., 3] == 0][:, :3] == 0)  # transparent background
    meta = json.loads((out / "procedural.json").read_text())
    assert meta["one_side_train_views"] == [0, 1]


def test_camera_layouts():
    rng = np.random.default_rng(0)
    az, el, rad = spherical_from_pose(hemisphere_poses(200, rng))
    assert el.min() >= 10.0 - 1e-9 and el.max() <= 80.0 + 1e-9 and np.allclose(rad, 4.0)
    assert np.ptp(np.mod(az, 360.0)) > 300.0  # spread all around
    az, el, _ = spherical_from_pose(one_side_poses(50, rng))
    assert np.all((np.mod(az, 360.0) >= 0.0) & (np.mod(az, 360.0) <= 70.0))
    assert np.all((el >= 15.0) & (el <= 55.0))
    a = hemisphere_poses(5, np.random.default_rng(9))
    assert np.array_equal(a, hemisphere_poses(5, np.random.default_rng(9)))


def test_refuses_existing_scene_and_bad_arguments(exported, tmp_path):
    out, _ = exported
    with pytest.raises(InputError):
        export_blender_scene(out, n_train=1, n_val=0, n_test=0, width=8, height=8)
    with pytest.raises(ValueError):
        export_blender_scene(tmp_path / "a", n_train=0)
    with pytest.raises(ValueError):
        export_blender_scene(tmp_path / "b", n_train=2, n_one_side=3)
    with pytest.raises(ValueError):
        export_blender_scene(tmp_path / "c", camera_angle_x=4.0)
    with pytest.raises(ValueError):
        export_blender_scene(tmp_path / "d", radius=1.0)
    # cameras at 2.5 could sit inside the scene's bounds [-1.5, 1.5]^3 (its corners are 1.5 sqrt(3) = 2.6 out)
    with pytest.raises(ValueError, match="radius"):
        export_blender_scene(tmp_path / "e", radius=2.5)
    with pytest.raises(ValueError, match="camera_angle_x"):
        export_blender_scene(tmp_path / "f", camera_angle_x=0.0)
    with pytest.raises(ValueError, match="n_train"):
        export_blender_scene(tmp_path / "g", n_train=True)  # a bool is not a count
    with pytest.raises(ValueError, match="elevation_range"):
        hemisphere_poses(3, np.random.default_rng(0), elevation_range=(60.0, 30.0))
    a_file = tmp_path / "a_file"
    a_file.write_text("mine")
    with pytest.raises(InputError, match="exists and is not a folder"):
        export_blender_scene(a_file, n_train=1, n_val=0, n_test=0, width=8, height=8)
    assert a_file.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]  # nothing written for a refused call


def test_overwrite_replaces_a_scene_and_all_train_views_may_be_one_sided(tmp_path):
    out = tmp_path / "s"
    small = dict(n_val=0, n_test=0, width=8, height=6)
    export_blender_scene(out, SceneConfig(seed=1), n_train=2, seed=3, **small)
    export_blender_scene(out, SceneConfig(seed=2), n_train=3, n_one_side=3, seed=5, overwrite=True, **small)
    meta = json.loads((out / "procedural.json").read_text())
    assert meta["camera_seed"] == 5 and meta["scene_config"]["seed"] == 2
    assert meta["one_side_train_views"] == [0, 1, 2]
    _, c2w = _json_poses(out, "train")
    assert np.max(np.abs(c2w - one_side_poses(3, np.random.default_rng(5)))) < 1e-9


def test_hemisphere_poses_are_area_uniform():
    """Uniform over the spherical zone's area: P(elevation < 45) = (sin 45 - sin 10) / (sin 80 - sin 10)
    = 0.658 (0.5 if elevations were uniform in angle)."""
    _, el, _ = spherical_from_pose(hemisphere_poses(4000, np.random.default_rng(1)))
    assert abs(np.mean(el < 45.0) - 0.6577) < 0.03


def test_make_demo_scene(tmp_path):
    t0 = time.perf_counter()
    out = make_demo_scene(tmp_path / "demo", seed=1)
    dt = time.perf_counter() - t0
    scene = load_scene(out)
    assert [len(scene.splits[s]) for s in ("train", "val", "test")] == [20, 8, 16]
    assert scene.rgb.shape[1:3] == (100, 100)
    az, el, _ = spherical_from_pose(scene.c2w[scene.splits["train"][list(DEMO_FEWSHOT_VIEWS)]])
    assert np.all(np.mod(az, 360.0) <= 70.0)
    meta = json.loads((out / "procedural.json").read_text())
    assert meta["camera_seed"] == 1 and meta["scene_config"]["seed"] == 1  # the seed drives both
    assert dt < 10.0


def test_overwrite_with_fewer_views_leaves_no_unlisted_images(tmp_path):
    """A smaller export over a larger one removes the views no transforms file lists; a user's own file in a
    split folder stays."""
    out = tmp_path / "s"
    small = dict(n_val=0, width=8, height=6)
    export_blender_scene(out, n_train=4, n_test=3, **small)
    (out / "train" / "notes.txt").write_text("mine")
    (out / "train" / "r_7_mask.png").write_bytes(b"mine too")
    export_blender_scene(out, n_train=2, n_test=3, overwrite=True, **small)
    assert sorted(p.name for p in (out / "train").iterdir()) == [
        "notes.txt", "r_0.png", "r_0_depth.npy", "r_1.png", "r_1_depth.npy", "r_7_mask.png"]
    assert len(list((out / "test").glob("r_*.png"))) == 3
