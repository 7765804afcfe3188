"""Tests of senerf/data/load.py: format detection, downscaling, background, and the bad-input table.

Each case of the table ``BAD_INPUT`` builds a scene folder in tmp_path, breaks one thing and checks that
``load_scene`` raises a one-line ``InputError`` naming the file and the field, and which check refused it.
Accepted-but-unusual inputs (grey / 16-bit / RGB-only images, missing ngp images) are tested in
test_io.py and test_blender.py.
"""

from __future__ import annotations

import math
import warnings

import cv2
import imageio.v3 as iio
import numpy as np
import pytest

from senerf.data import detect_format, load_scene
from senerf.errors import InputError


# --- the bad-input table --------------------------------------------------------------------------------
# Each builder gets (tmp_path, writers) and returns (call, file_part, field_part, problem_part):
# ``call()`` must raise InputError whose message contains all three parts.

def _blender(tmp, w):
    return w.blender(tmp / "scene")


def _edit_train(tmp, w, edit):
    root = _blender(tmp, w)
    meta = w.read_json(root / "transforms_train.json")
    edit(meta)
    w.write_json(root / "transforms_train.json", meta)
    return root


def case_missing_folder(tmp, w):
    return (lambda: load_scene(tmp / "nope"), "nope", "", "scene folder not found")


def case_no_marker(tmp, w):
    (tmp / "empty").mkdir()
    return (lambda: load_scene(tmp / "empty"), "empty", "", "not a scene folder")


def case_malformed_json(tmp, w):
    root = _blender(tmp, w)
    (root / "transforms_train.json").write_text('{"camera_angle_x": 0.9, "frames": [')
    return (lambda: load_scene(root), "transforms_train.json", "", "malformed JSON")


def case_json_not_object(tmp, w):
    root = _blender(tmp, w)
    (root / "transforms_train.json").write_text("[1, 2]")
    return (lambda: load_scene(root), "transforms_train.json", "", "JSON object")


def case_missing_frames(tmp, w):
    root = _edit_train(tmp, w, lambda m: m.pop("frames"))
    return (lambda: load_scene(root), "transforms_train.json", "frames", "missing field")


def case_frames_not_list(tmp, w):
    root = _edit_train(tmp, w, lambda m: m.update(frames={"a": 1}))
    return (lambda: load_scene(root), "transforms_train.json", "frames", "expected a list")


def case_missing_matrix(tmp, w):
    root = _edit_train(tmp, w, lambda m: m["frames"][1].pop("transform_matrix"))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "missing field")


def case_missing_file_path(tmp, w):
    root = _edit_train(tmp, w, lambda m: m["frames"][0].pop("file_path"))
    return (lambda: load_scene(root), "transforms_train.json", "frames[0].file_path", "missing field")


def case_missing_angle(tmp, w):
    root = _edit_train(tmp, w, lambda m: m.pop("camera_angle_x"))
    return (lambda: load_scene(root), "transforms_train.json", "camera_angle_x", "missing field")


def _set_matrix(value):
    def edit(m):
        m["frames"][1]["transform_matrix"] = value
    return edit


def case_nan_matrix(tmp, w):
    mat = np.eye(4).tolist()
    mat[0][3] = float("nan")  # json.dumps writes NaN, which json.loads reads back
    root = _edit_train(tmp, w, _set_matrix(mat))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "NaN or inf")


def case_inf_matrix(tmp, w):
    mat = np.eye(4).tolist()
    mat[1][1] = float("inf")
    root = _edit_train(tmp, w, _set_matrix(mat))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "NaN or inf")


def case_scaled_matrix(tmp, w):
    mat = (np.diag([2.0, 2.0, 2.0, 1.0])).tolist()  # R^T R = 4 I: a scale, not a rotation
    root = _edit_train(tmp, w, _set_matrix(mat))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "not a rigid")


def case_reflection_matrix(tmp, w):
    mat = np.diag([1.0, 1.0, -1.0, 1.0]).tolist()  # orthonormal but det -1
    root = _edit_train(tmp, w, _set_matrix(mat))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "det R = -1")


def case_bad_last_row(tmp, w):
    mat = np.eye(4)
    mat[3, 0] = 0.5
    root = _edit_train(tmp, w, _set_matrix(mat.tolist()))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "not a rigid")


def case_matrix_shape(tmp, w):
    root = _edit_train(tmp, w, _set_matrix(np.eye(3).tolist()))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "4x4")


def case_angle_as_string(tmp, w):
    # a string is a mistake in the file, not a number (float("0.69") accepted it, so at 7e504ce)
    root = _edit_train(tmp, w, lambda m: m.update(camera_angle_x="0.69"))
    return (lambda: load_scene(root), "transforms_train.json", "camera_angle_x", "'0.69'")


def case_matrix_of_booleans(tmp, w):
    rows = [[True, False, False, False], [False, True, False, False], [False, False, True, False],
            [False, False, False, True]]  # a rigid identity as 0/1: accepted before
    root = _edit_train(tmp, w, _set_matrix(rows))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].transform_matrix", "matrix of numbers")


def case_zero_angle(tmp, w):
    root = _edit_train(tmp, w, lambda m: m.update(camera_angle_x=0.0))
    return (lambda: load_scene(root), "transforms_train.json", "camera_angle_x", "positive")


def case_negative_focal_ngp(tmp, w):
    root = w.ngp(tmp / "ngp", meta_extra={"fl_x": -5.0})
    return (lambda: load_scene(root), "transforms.json", "fl_x", "positive")


def case_zero_focal_per_frame_ngp(tmp, w):
    root = w.ngp(tmp / "ngp")
    meta = w.read_json(root / "transforms.json")
    meta["frames"][2]["fl_y"] = 0
    w.write_json(root / "transforms.json", meta)
    return (lambda: load_scene(root), "transforms.json", "frames[2].fl_y", "positive")


def case_string_focal_ngp(tmp, w):
    root = w.ngp(tmp / "ngp", meta_extra={"fl_x": "big"})
    return (lambda: load_scene(root), "transforms.json", "fl_x", "'big'")


def case_mixed_sizes(tmp, w):
    root = _blender(tmp, w)
    iio.imwrite(root / "train" / "r_1.png", w.rgba(7, 5, 4))
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].file_path", "share one size")


def case_empty_frames(tmp, w):
    root = _edit_train(tmp, w, lambda m: m.update(frames=[]))
    return (lambda: load_scene(root), "transforms_train.json", "frames", "empty frame list")


def case_path_escapes(tmp, w):
    root = _blender(tmp, w)
    iio.imwrite(tmp / "outside.png", w.rgba(9))  # exists, so only the escape check can refuse it
    meta = w.read_json(root / "transforms_train.json")
    meta["frames"][0]["file_path"] = "./train/../../outside"
    w.write_json(root / "transforms_train.json", meta)
    return (lambda: load_scene(root), "transforms_train.json", "frames[0].file_path", "leaves the scene folder")


def case_absolute_path(tmp, w):
    root = _blender(tmp, w)
    meta = w.read_json(root / "transforms_train.json")
    meta["frames"][0]["file_path"] = str((root / "train" / "r_0").resolve())
    w.write_json(root / "transforms_train.json", meta)
    return (lambda: load_scene(root), "transforms_train.json", "frames[0].file_path", "absolute path")


def case_missing_image(tmp, w):
    root = _blender(tmp, w)
    (root / "test" / "r_0.png").unlink()
    return (lambda: load_scene(root), "transforms_test.json", "frames[0].file_path", "image not found")


def case_corrupt_image(tmp, w):
    root = _blender(tmp, w)
    data = (root / "train" / "r_1.png").read_bytes()
    (root / "train" / "r_1.png").write_bytes(data[:40] + b"garbage" * 10)  # valid header, broken body
    return (lambda: load_scene(root), "transforms_train.json", "frames[1].file_path", "cannot decode")


def case_empty_image_file(tmp, w):
    root = _blender(tmp, w)
    (root / "val" / "r_0.png").write_bytes(b"")
    return (lambda: load_scene(root), "transforms_val.json", "frames[0].file_path", "cannot decode")


def case_image_is_folder(tmp, w):
    root = _blender(tmp, w)
    (root / "train" / "r_0.png").unlink()
    (root / "train" / "r_0.png").mkdir()  # exists but is not a readable file
    return (lambda: load_scene(root), "transforms_train.json", "frames[0].file_path", "image not found")


def case_ngp_declared_size(tmp, w):
    root = w.ngp(tmp / "ngp", meta_extra={"w": 8})
    return (lambda: load_scene(root), "transforms.json", "w", "declared 8")


def case_ngp_all_missing(tmp, w):
    root = w.ngp(tmp / "ngp")
    for p in (root / "images").iterdir():
        p.unlink()
    def call():
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the error comes alone, with no "skipped" warning first
            load_scene(root)
    return (call, "transforms.json", "frames", "no frame has an existing image")


def case_llff_wrong_shape(tmp, w):
    root = w.llff(tmp / "llff", rows=w.llff_rows()[:, :15])
    return (lambda: load_scene(root, downscale=2), "poses_bounds.npy", "shape", "(N, 17)")


def case_llff_not_npy(tmp, w):
    root = w.llff(tmp / "llff")
    (root / "poses_bounds.npy").write_bytes(b"not a numpy file")
    return (lambda: load_scene(root, downscale=2), "poses_bounds.npy", "", "not a .npy file")


def case_llff_nan(tmp, w):
    rows = w.llff_rows()
    rows[4, 3] = np.nan
    root = w.llff(tmp / "llff", rows=rows)
    return (lambda: load_scene(root, downscale=2), "poses_bounds.npy", "row 4", "NaN or inf")


def case_llff_nonrigid(tmp, w):
    rows = w.llff_rows()
    rows[3, :15] = (rows[3, :15].reshape(3, 5) * np.array([1.1, 1.1, 1.1, 1.0, 1.0])).reshape(-1)
    root = w.llff(tmp / "llff", rows=rows)
    return (lambda: load_scene(root, downscale=2), "poses_bounds.npy", "row 3", "not a rigid")


def case_llff_zero_focal(tmp, w):
    rows = w.llff_rows()
    rows[2, 14] = 0.0  # entry (2, 4) of the 3x5 block is f
    root = w.llff(tmp / "llff", rows=rows)
    return (lambda: load_scene(root, downscale=2), "poses_bounds.npy", "row 2 hwf.f", "positive")


def case_llff_focals_differ(tmp, w):
    rows = w.llff_rows()
    rows[6, 14] *= 1.01  # NDC is built from one focal: a second one would silently bend view 6's rays
    root = w.llff(tmp / "llff", rows=rows)
    return (lambda: load_scene(root, downscale=2), "poses_bounds.npy", "row 6 hwf.f", "share one focal")


def case_llff_size_disagrees_with_images(tmp, w):
    rows = w.llff_rows(H=1000.0, W=800.0)  # images_2 holds 24x16 files: 800x1000 / 2 would be 400x500
    root = w.llff(tmp / "llff", rows=rows)
    return (lambda: load_scene(root, downscale=2), "images_2", "images", "H, W = 1000, 800 at factor 2 give 400x500")


def case_llff_bad_bounds(tmp, w):
    rows = w.llff_rows()
    rows[5, 15:] = (10.0, 2.0)
    root = w.llff(tmp / "llff", rows=rows)
    return (lambda: load_scene(root, downscale=2), "poses_bounds.npy", "row 5 bounds", "near <= far")


def case_llff_count_mismatch(tmp, w):
    root = w.llff(tmp / "llff", n_images=8)
    return (lambda: load_scene(root, downscale=2), "images_2", "images", "8 images but 9 rows")


def case_llff_no_folder(tmp, w):
    root = w.llff(tmp / "llff")
    return (lambda: load_scene(root, downscale=1), "llff", "images", "found: images_2")


BAD_INPUT = [v for k, v in sorted(globals().items()) if k.startswith("case_")]


@pytest.mark.parametrize("build", BAD_INPUT, ids=[b.__name__[5:] for b in BAD_INPUT])
def test_bad_input_raises_one_line_naming_file_and_field(build, tmp_path, writers):
    call, file_part, field_part, problem_part = build(tmp_path, writers)
    with pytest.raises(InputError) as info:
        call()
    err = info.value
    msg = str(err)
    assert "\n" not in msg
    assert file_part in (err.file or ""), msg
    assert field_part in (err.field or ""), msg
    assert problem_part in err.problem, msg


@pytest.mark.parametrize("bad", [0.5, 0, -2, float("nan"), float("inf"), "x", True])
def test_bad_downscale(bad, tmp_path, writers):
    root = writers.blender(tmp_path / "s")
    with pytest.raises(InputError) as info:
        load_scene(root, downscale=bad)
    assert info.value.field == "downscale"


@pytest.mark.parametrize("bad", [(1, 1), (0, 0, 2), (float("nan"),) * 3, "white"])
def test_bad_background(bad, tmp_path, writers):
    root = writers.blender(tmp_path / "s")
    with pytest.raises(InputError) as info:
        load_scene(root, background=bad)
    assert info.value.field == "background"


# --- detection --------------------------------------------------------------------------------------------

def test_detect_format_each_kind(tmp_path, writers):
    assert detect_format(writers.blender(tmp_path / "b")) == "blender"
    assert detect_format(writers.ngp(tmp_path / "n")) == "ngp"
    assert detect_format(writers.llff(tmp_path / "l")) == "llff"


def test_blender_wins_over_single_file(tmp_path, writers):
    root = writers.blender(tmp_path / "b")
    writers.write_json(root / "transforms.json", {"frames": []})
    assert detect_format(root) == "blender"


def test_marker_file_path_is_accepted(tmp_path, writers):
    root = writers.blender(tmp_path / "b")
    scene = load_scene(root / "transforms_train.json")
    assert scene.root == root and scene.n_images == 4
    # detect_format too (senerf-fit calls it first: it said "scene folder not found", so at ed16e9a), and
    # any other file is named as a file, not as missing
    assert detect_format(root / "transforms_test.json") == "blender"
    # a relative marker path from inside the folder: the scene keeps its folder's name (it was "")
    import os

    cwd = os.getcwd()
    try:
        os.chdir(root)
        assert load_scene("transforms_train.json").name == "b" and load_scene(".").name == "b"
    finally:
        os.chdir(cwd)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match=r"notes\.txt: is a file; expected a scene folder"):
        detect_format(tmp_path / "notes.txt")


# --- downscaling -----------------------------------------------------------------------------------------

def _block_mean(img: np.ndarray, s: int) -> np.ndarray:
    h, w = img.shape[:2]
    return img.reshape(h // s, s, w // s, s, -1).mean(axis=(1, 3))


def test_downscale_composite_equals_block_mean_of_composite(tmp_path, writers):
    # Area interpolation by an integer factor s is the mean of s x s blocks.  Compositing is linear in
    # (premultiplied colour, alpha), so compositing the downscaled scene must equal the block mean of the
    # full-size composite, also at semi-transparent edges (a straight-colour resize would darken them).
    root = writers.blender(tmp_path / "s", image=lambda seed: writers.rgba(seed, 8, 8))
    full = load_scene(root)
    half = load_scene(root, downscale=2)
    bg = np.array([0.2, 0.9, 0.4], np.float32)
    want = np.stack([_block_mean(im, 2) for im in full.composite(bg)])
    np.testing.assert_allclose(half.composite(bg), want, atol=2e-6)
    np.testing.assert_allclose(half.alpha, np.stack([_block_mean(a[..., None], 2)[..., 0] for a in full.alpha]),
                               atol=2e-6)


def test_downscale_intrinsics_integer_factor(tmp_path, writers):
    root = writers.blender(tmp_path / "s", image=lambda seed: writers.rgba(seed, 8, 8))
    # camera_angle_x = 2 atan(0.5): f = 0.5 * 8 / 0.5 = 8 px at 8x8; halving the image halves f and c.
    k = load_scene(root, downscale=2).intrinsics
    assert (k.width, k.height) == (4, 4)
    assert k.fx == pytest.approx(4.0) and k.fy == pytest.approx(4.0)
    assert (k.cx, k.cy) == pytest.approx((2.0, 2.0))


def test_downscale_half_pixel_side_rounds_up(tmp_path, writers):
    # a 10 x 4 (W x H) image at downscale 4 is 3 x 1 (10/4 = 2.5 -> 3, not round()'s 2); f = 10 px at full size,
    # fx' = 10 * 3/10 = 3, fy' = 10 * 1/4
    root = writers.blender(tmp_path / "s", image=lambda seed: writers.rgba(seed, 4, 10))
    k = load_scene(root, downscale=4).intrinsics
    assert (k.width, k.height) == (3, 1)
    assert (k.fx, k.fy) == pytest.approx((3.0, 2.5))


def test_downscale_non_integer_rounds_and_scales_per_axis(tmp_path, writers):
    # 10 x 7 image, downscale 3: W' = floor(10/3 + 0.5) = 3, H' = floor(7/3 + 0.5) = 2.
    # f at full size = 0.5 * 10 / tan(atan(0.5)) = 10 px; fx' = 10 * 3/10 = 3, fy' = 10 * 2/7.
    root = writers.blender(tmp_path / "s", image=lambda seed: writers.rgba(seed, 7, 10))
    k = load_scene(root, downscale=3).intrinsics
    assert (k.width, k.height) == (3, 2)
    assert k.fx == pytest.approx(3.0)
    assert k.fy == pytest.approx(20.0 / 7.0)
    assert (k.cx, k.cy) == pytest.approx((1.5, 1.0))


# --- background ------------------------------------------------------------------------------------------

def test_background_composites_and_keeps_alpha(tmp_path, writers):
    root = writers.blender(tmp_path / "s")
    straight = load_scene(root)
    white = load_scene(root, background=(1, 1, 1))
    raw = iio.imread(root / "train" / "r_0.png").astype(np.float64) / 255.0
    want = raw[..., :3] * raw[..., 3:] + 1.0 * (1.0 - raw[..., 3:])  # "over" a white background
    np.testing.assert_allclose(white.rgb[0], want, atol=1e-6)
    np.testing.assert_array_equal(white.alpha, straight.alpha)
    assert white.background == (1.0, 1.0, 1.0) and straight.background is None


def test_lego_white_background_corner_is_white(lego4):
    # The lego render has a fully transparent border (alpha 0): composited onto white it is white.
    assert lego4.alpha[:, 0, 0].max() == 0.0
    np.testing.assert_array_equal(lego4.composite(1.0)[:, 0, 0], 1.0)


def test_16bit_rgb_png_survives_loader(tmp_path, writers):
    # A 16-bit colour PNG written by OpenCV (BGR order on disk) must come back as RGB / 65535.
    root = writers.blender(tmp_path / "s", n_val=0, n_test=0)
    img = np.random.default_rng(3).integers(0, 65536, size=(4, 4, 3), dtype=np.uint16)
    cv2.imwrite(str(root / "train" / "r_0.png"), img[..., ::-1])
    with pytest.warns(UserWarning, match=r"transforms_train\.json: 1 of 2 photos have no alpha channel \(frames\[0\]"):
        scene = load_scene(root)
    np.testing.assert_allclose(scene.rgb[0], img / 65535.0, atol=1e-7)
    assert math.isclose(float(scene.alpha[0].min()), 1.0)  # frame without alpha is opaque, r_1 keeps its own


def test_principal_point_outside_the_image_warns(tmp_path, writers):
    # before: cx given at another resolution (or mistyped) loaded silently and trained to nothing
    root = writers.ngp(tmp_path / "n", meta_extra={"cx": 40.0})
    with pytest.warns(UserWarning, match=r"f_0\.png: cx, cy: the principal point \(40, 2\.5\) lies outside the "
                                         r"4x4 image") as caught:
        load_scene(root)
    assert len([w for w in caught if "principal point" in str(w.message)]) == 1    # once, not per photo
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_scene(writers.ngp(tmp_path / "ok", meta_extra={"cx": 4.0, "cy": 0.5}))  # on the border: fine
    with pytest.warns(UserWarning, match=r"principal point \(1\.5, 4\.5\) lies outside"):   # cy is checked too,
        load_scene(writers.ngp(tmp_path / "cy", meta_extra={"cy": 4.5}))            # against the height
    wide = writers.ngp(tmp_path / "wide", meta_extra={"w": 8, "cy": 5.0}, image=lambda s: writers.rgba(s, h=4, w=8))
    with pytest.warns(UserWarning, match=r"\(1\.5, 5\) lies outside the 8x4 image"):
        load_scene(wide)


def test_photo_listed_twice_in_a_split_warns(tmp_path, writers):
    root = writers.blender(tmp_path / "b", n_train=3)
    meta = writers.read_json(root / "transforms_train.json")
    meta["frames"][2]["file_path"] = meta["frames"][0]["file_path"]
    writers.write_json(root / "transforms_train.json", meta)
    with pytest.warns(UserWarning, match=r"r_0\.png: listed 2 times in the train split; each copy counts as a view"):
        scene = load_scene(root)
    assert scene.splits["train"].size == 3
    root = writers.blender(tmp_path / "b2", n_train=4)                   # two photos twice: one line, counting
    meta = writers.read_json(root / "transforms_train.json")
    meta["frames"][2]["file_path"], meta["frames"][3]["file_path"] = (meta["frames"][0]["file_path"],
                                                                      meta["frames"][1]["file_path"])
    writers.write_json(root / "transforms_train.json", meta)
    with pytest.warns(UserWarning, match=r"r_0\.png: listed 2 times in the train split \(1 more photo\(s\) "
                                         r"likewise\); each copy counts as a view"):
        load_scene(root)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_scene(writers.blender(tmp_path / "ok", n_train=3))
