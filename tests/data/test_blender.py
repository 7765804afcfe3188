"""Tests of senerf/data/blender.py: NeRF Synthetic (three JSON files) and instant-ngp (one JSON file),
on tiny scenes written in tmp_path and on the real lego scene."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from senerf.data import load_scene
from senerf.geometry import closest_point_to_axes, project


def test_blender_order_splits_and_focal(tmp_path, writers):
    root = writers.blender(tmp_path / "s", n_train=3, n_val=2, n_test=1)
    scene = load_scene(root)
    assert scene.n_images == 6 and scene.kind == "object" and scene.near is None
    assert scene.splits["train"].tolist() == [0, 1, 2]
    assert scene.splits["val"].tolist() == [3, 4]
    assert scene.splits["test"].tolist() == [5]
    assert scene.image_paths[3] == root / "val" / "r_0.png"
    # camera_angle_x = 2 atan(0.5) at W = 4: f = 0.5 * 4 / 0.5 = 4, principal point (2, 2).
    k = scene.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((4.0, 4.0, 2.0, 2.0))


def test_blender_pose_converted_to_opencv(tmp_path, writers):
    # Frame 0: OpenGL camera at (0, 0, 4) with identity rotation looks along world -z, image up = world +y.
    # In OpenCV terms: the origin is 4 in front (z_depth 4) at the principal point (2, 2); the point
    # (0.5, 0, 0) is right of it: u = 2 + f * 0.5 / 4 = 2.5; the point (0, 1, 0) is *up* in the image:
    # v = 2 - f * 1 / 4 = 1 (rows grow downwards).  f = 4 (see the conftest).
    scene = load_scene(writers.blender(tmp_path / "s"))
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 1.0, 0.0]])
    uv, z, valid = project(pts, scene.intrinsics, scene.c2w[0])
    assert valid.all()
    np.testing.assert_allclose(z, (4.0, 4.0, 4.0), atol=1e-12)
    np.testing.assert_allclose(uv, [[2.0, 2.0], [2.5, 2.0], [2.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(scene.c2w[0, :3, 3], (0.0, 0.0, 4.0))
    assert scene.c2w.dtype == np.float64


def test_blender_file_path_with_extension_is_not_doubled(tmp_path, writers):
    root = writers.blender(tmp_path / "s")
    meta = writers.read_json(root / "transforms_train.json")
    meta["frames"][0]["file_path"] = "train/r_0.png"
    writers.write_json(root / "transforms_train.json", meta)
    assert load_scene(root).image_paths[0] == root / "train" / "r_0.png"


def test_blender_missing_val_and_test_files_give_empty_splits(tmp_path, writers):
    root = writers.blender(tmp_path / "s", n_train=2)
    (root / "transforms_val.json").unlink()
    (root / "transforms_test.json").unlink()
    scene = load_scene(root)
    assert scene.n_images == 2 and scene.splits["val"].size == 0 and scene.splits["test"].size == 0


def test_blender_rgb_only_images_give_alpha_none(tmp_path, writers):
    root = writers.blender(tmp_path / "s", image=lambda seed: writers.rgba(seed)[..., :3])
    scene = load_scene(root, background=(1, 1, 1))
    assert scene.alpha is None
    # Nothing to composite: rgb is the decoded colour unchanged.
    np.testing.assert_allclose(scene.rgb[0], writers.rgba(0)[..., :3] / 255.0, atol=1e-7)


# --- instant-ngp / nerfstudio ----------------------------------------------------------------------------

def test_ngp_global_intrinsics_and_all_train(tmp_path, writers):
    scene = load_scene(writers.ngp(tmp_path / "n"))
    k = scene.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (5.0, 6.0, 1.5, 2.5, 4, 4)
    assert scene.splits["train"].tolist() == [0, 1, 2]
    assert scene.splits["val"].size == 0 and scene.splits["test"].size == 0


def test_ngp_per_frame_intrinsics_override_global(tmp_path, writers):
    root = writers.ngp(tmp_path / "n")
    meta = writers.read_json(root / "transforms.json")
    meta["frames"][1].update(fl_x=7.0, cx=1.0)
    writers.write_json(root / "transforms.json", meta)
    scene = load_scene(root, downscale=2)
    k0, k1 = scene.intrinsics_all[0], scene.intrinsics_all[1]
    # downscale 2 on 4x4: every value halves.
    assert (k0.fx, k0.fy, k0.cx, k0.cy) == pytest.approx((2.5, 3.0, 0.75, 1.25))
    assert (k1.fx, k1.fy, k1.cx, k1.cy) == pytest.approx((3.5, 3.0, 0.5, 1.25))


def test_ngp_camera_angle_fallback(tmp_path, writers):
    root = writers.ngp(tmp_path / "n")
    meta = writers.read_json(root / "transforms.json")
    for key in ("fl_x", "fl_y", "cx", "cy"):
        meta.pop(key)
    meta["camera_angle_x"] = 2.0 * math.atan(0.5)   # f = 0.5 * 4 / 0.5 = 4
    meta["camera_angle_y"] = 2.0 * math.atan(0.25)  # f_y = 0.5 * 4 / 0.25 = 8
    writers.write_json(root / "transforms.json", meta)
    k = load_scene(root).intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((4.0, 8.0, 2.0, 2.0))


def test_ngp_missing_image_is_skipped_with_warning(tmp_path, writers):
    root = writers.ngp(tmp_path / "n")
    (root / "images" / "f_1.png").unlink()
    with pytest.warns(UserWarning, match=r"frames\[1\] \(images/f_1.png\)"):
        scene = load_scene(root)
    assert [p.name for p in scene.image_paths] == ["f_0.png", "f_2.png"]
    np.testing.assert_allclose(scene.c2w[:, 2, 3], (4.0, 6.0))  # frames 0 and 2 kept, in order


def test_ngp_nerfstudio_split_lists(tmp_path, writers):
    root = writers.ngp(tmp_path / "n", meta_extra={"train_filenames": ["images/f_0.png", "images/f_2.png"],
                                                   "test_filenames": ["./images/f_1.png"]})
    scene = load_scene(root)
    assert scene.splits["train"].tolist() == [0, 2]
    assert scene.splits["test"].tolist() == [1]


def test_ngp_split_lists_match_file_paths_without_suffix(tmp_path, writers):
    # A frame written "images/f_0" (no suffix, .png appended by the loader) listed as "images/f_0.png" is a train
    # frame, and "./images/f_2" matches "images/f_2.png".
    root = writers.ngp(tmp_path / "n", meta_extra={"train_filenames": ["images/f_0.png", "images/f_1.png"],
                                                   "test_filenames": ["images/f_2.png"]})
    meta = writers.read_json(root / "transforms.json")
    meta["frames"][0]["file_path"] = "images/f_0"
    meta["frames"][2]["file_path"] = "./images/f_2"
    writers.write_json(root / "transforms.json", meta)
    scene = load_scene(root)
    assert scene.splits["train"].tolist() == [0, 1] and scene.splits["test"].tolist() == [2]


@pytest.mark.parametrize("extra, field", [
    ({"train_filenames": []}, "train_filenames"),
    ({"train_filenames": ["images/f_0.png"], "test_filenames": ["f_1.png"]}, "test_filenames"),
    ({"train_filenames": ["img/f_0.png", "img/f_2.png"]}, "train_filenames"),
    ({"test_filenames": ["images/f_1.png"], "val_filenames": []}, "train_filenames"),   # no training list
    ({"test_filenames": "images/f_0.png"}, "test_filenames"),
    ({"train_filenames": [1, 2]}, "train_filenames"),
])
def test_ngp_split_lists_that_select_no_frame_or_are_not_lists_of_names_are_refused(tmp_path, writers, extra, field):
    from senerf.errors import InputError

    root = writers.ngp(tmp_path / "n", meta_extra=extra)
    with pytest.raises(InputError) as info:
        load_scene(root)
    assert info.value.field == field and info.value.file == str(root / "transforms.json")
    ok = writers.ngp(tmp_path / "ok", meta_extra={"train_filenames": ["images/f_0.png"], "val_filenames": []})
    assert load_scene(ok).splits["val"].size == 0   # an empty val list is no val split


def test_ngp_aabb_scale_bounds_the_scene_in_world_units(tmp_path, writers):
    # instant-ngp maps a world point x to x * scale + offset and keeps the cube [0.5 - a/2, 0.5 + a/2]^3 there
    # (a = aabb_scale; scale 0.33 and offset 0.5 by default): the world box is (0.5 -+ a/2 - offset) / scale.
    assert load_scene(writers.ngp(tmp_path / "none")).bound is None
    scene = load_scene(writers.ngp(tmp_path / "d", meta_extra={"aabb_scale": 4}))
    assert np.allclose(scene.bound, [[-2 / 0.33] * 3, [2 / 0.33] * 3])   # (0.5 -+ 2 - 0.5) / 0.33
    scene = load_scene(writers.ngp(tmp_path / "o", meta_extra={"aabb_scale": 2, "scale": 0.5,
                                                                "offset": [0.5, 0.0, 1.0]}))
    assert np.allclose(scene.bound, [[-2.0, -1.0, -3.0], [2.0, 3.0, 1.0]])
    rgb = writers.ngp(tmp_path / "k", meta_extra={"aabb_scale": 4}, image=lambda seed: writers.rgba(seed)[..., :3])
    assert load_scene(rgb).kind == "unbounded" and load_scene(tmp_path / "d").kind == "object"   # alpha: object


@pytest.mark.parametrize("extra, field", [
    ({"aabb_scale": 0}, "aabb_scale"), ({"aabb_scale": -4}, "aabb_scale"), ({"aabb_scale": "4x"}, "aabb_scale"),
    ({"aabb_scale": True}, "aabb_scale"), ({"aabb_scale": float("nan")}, "aabb_scale"),
    ({"aabb_scale": 4, "scale": 0}, "scale"), ({"aabb_scale": 4, "offset": [0.5, 0.5]}, "offset"),
    ({"aabb_scale": 4, "offset": "middle"}, "offset"),
])
def test_a_bad_aabb_scale_is_one_line_naming_the_file_and_field(tmp_path, writers, extra, field):
    from senerf.errors import InputError

    root = writers.ngp(tmp_path / "n", meta_extra=extra)
    with pytest.raises(InputError) as info:
        load_scene(root)
    assert info.value.field == field and info.value.file == str(root / "transforms.json")
    assert "\n" not in str(info.value)


# --- non-square images: each intrinsic from its own axis ---------------------------------------------------

def _ngp_nonsquare(root, writers, **meta):
    """An ngp folder with 4 x 6 (H x W) images and only the given intrinsics at the top level."""
    root = writers.ngp(root, image=lambda seed: writers.rgba(seed, 4, 6))
    m = writers.read_json(root / "transforms.json")
    for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        m.pop(key)
    m.update(meta)
    writers.write_json(root / "transforms.json", m)
    return root


def test_ngp_camera_angles_use_their_own_axis_on_non_square_images(tmp_path, writers):
    # W = 6, H = 4: fx = 0.5 * 6 / tan(atan(0.5)) = 6, fy = 0.5 * 4 / tan(atan(0.25)) = 8, c = (3, 2).
    root = _ngp_nonsquare(tmp_path / "n", writers, camera_angle_x=2 * math.atan(0.5),
                          camera_angle_y=2 * math.atan(0.25), w=6, h=4)
    k = load_scene(root).intrinsics
    assert (k.width, k.height) == (6, 4)
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((6.0, 8.0, 3.0, 2.0))
    # without camera_angle_y, fy = fx (square pixels): 6, not 0.5 * 4 / 0.5 = 4
    k2 = load_scene(_ngp_nonsquare(tmp_path / "n2", writers, camera_angle_x=2 * math.atan(0.5))).intrinsics
    assert (k2.fx, k2.fy) == pytest.approx((6.0, 6.0))


def test_ngp_declared_w_h_checked_against_the_right_sides(tmp_path, writers):
    from senerf.errors import InputError

    assert load_scene(_ngp_nonsquare(tmp_path / "ok", writers, fl_x=5.0, w=6, h=4)).size == (4, 6)
    with pytest.raises(InputError) as info:
        load_scene(_ngp_nonsquare(tmp_path / "bad", writers, fl_x=5.0, w=4, h=6))
    assert info.value.field in ("w", "h")


# --- the real lego scene ---------------------------------------------------------------------------------

def test_lego_split_sizes_counted_in_json(lego_dir, lego4):
    counts = {s: len(json.loads((lego_dir / f"transforms_{s}.json").read_text())["frames"])
              for s in ("train", "val", "test")}
    assert counts == {"train": 100, "val": 100, "test": 200}
    assert {s: len(v) for s, v in lego4.splits.items()} == counts
    assert lego4.rgb.shape == (400, 100, 100, 3) and lego4.alpha.shape == (400, 100, 100)


def test_lego_focal_full_and_downscaled(lego_dir, lego4):
    angle = json.loads((lego_dir / "transforms_train.json").read_text())["camera_angle_x"]
    f400 = 0.5 * 400 / math.tan(0.5 * angle)
    assert f400 == pytest.approx(555.555, abs=1e-3)  # the data README's value at 400 px
    k = lego4.intrinsics
    assert (k.width, k.height) == (100, 100)
    assert k.fx == pytest.approx(f400 / 4) and k.fy == pytest.approx(f400 / 4)
    assert (k.cx, k.cy) == (50.0, 50.0)


def test_lego_real_loader_matches_decoded_train_image(lego_dir, lego4):
    # Frame 0 of the train split, area-downscaled by 4 with premultiplied colour, equals the block mean.
    import imageio.v3 as iio

    raw = iio.imread(lego_dir / "train" / "r_0.png").astype(np.float64) / 255.0
    pre = np.concatenate([raw[..., :3] * raw[..., 3:], raw[..., 3:]], axis=2)
    mean = pre.reshape(100, 4, 100, 4, 4).mean(axis=(1, 3))
    np.testing.assert_allclose(lego4.alpha[0], mean[..., 3], atol=1e-5)
    np.testing.assert_allclose(lego4.rgb[0] * lego4.alpha[0][..., None], mean[..., :3], atol=1e-5)


def test_lego_every_camera_looks_at_the_centre(lego4):
    # All lego cameras aim at the origin: the least-squares point of the optical axes is the origin, and
    # the origin projects in front of every camera onto the image centre (50, 50).  A wrong OpenGL ->
    # OpenCV conversion puts the origin behind the camera (invalid) or mirrors it.
    centre = closest_point_to_axes(lego4.c2w)
    assert np.linalg.norm(centre) < 1e-3
    uv, z, valid = project(np.zeros(3), lego4.intrinsics, lego4.c2w)
    assert valid.all()
    assert np.abs(uv - 50.0).max() < 0.01
    # radius ~4.03 (REFERENCE section 1)
    np.testing.assert_allclose(z, 4.031, atol=0.01)
