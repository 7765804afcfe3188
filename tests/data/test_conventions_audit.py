"""Mutation-audit tests of senerf/data: conventions the older tests could not tell apart (square images,
identity rotations, symmetric camera rows, one folder per scene).  Every golden value is computed by hand
or by a different method (the original NeRF LLFF code written out below, numpy block means); each test
names the bug it catches."""

from __future__ import annotations

import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from senerf.data import EXTREME_VIEWS, Scene, fewshot_split, load_llff, load_scene
from senerf.data import _io
from senerf.errors import InputError
from senerf.geometry import Intrinsics

# --- the original NeRF LLFF pose code (bmild/nerf, load_llff.py), written out in float64 -------------------


def _nerf_normalize(x):
    return x / np.linalg.norm(x)


def _nerf_viewmatrix(z, up, pos):
    vec2 = _nerf_normalize(z)
    vec1_avg = up
    vec0 = _nerf_normalize(np.cross(vec1_avg, vec2))
    vec1 = _nerf_normalize(np.cross(vec2, vec0))
    return np.stack([vec0, vec1, vec2, pos], 1)


def _nerf_poses_avg(poses):
    center = poses[:, :3, 3].mean(0)
    vec2 = _nerf_normalize(poses[:, :3, 2].sum(0))
    up = poses[:, :3, 1].sum(0)
    return _nerf_viewmatrix(vec2, up, center)


def _nerf_recenter_poses(poses):
    bottom = np.reshape([0, 0, 0, 1.0], [1, 4])
    c2w = np.concatenate([_nerf_poses_avg(poses), bottom], -2)
    bottom = np.tile(np.reshape(bottom, [1, 1, 4]), [poses.shape[0], 1, 1])
    poses = np.concatenate([poses[:, :3, :4], bottom], -2)
    return np.linalg.inv(c2w) @ poses


def _nerf_llff_opencv(raw: np.ndarray, bd_factor: float = 0.75):
    """NeRF's ``_load_data`` + ``load_llff_data`` (recenter=True, no spherify) on a ``poses_bounds`` array,
    then its OpenGL camera-to-world in its world frame converted to senerf's: the OpenCV camera axes are the
    OpenGL ones with y and z negated (``@ D``), and senerf's world is NeRF's rotated 180 degrees about x
    (``D @``), D = diag(1, -1, -1, 1).  Returns (c2w (N, 4, 4), near, far)."""
    poses = raw[:, :-2].reshape([-1, 3, 5]).transpose([1, 2, 0])
    bds = raw[:, -2:].transpose([1, 0])
    # [down, right, back] -> [right, up, back] (NeRF: "Correct rotation matrix ordering")
    poses = np.concatenate([poses[:, 1:2, :], -poses[:, 0:1, :], poses[:, 2:, :]], 1)
    poses = np.moveaxis(poses, -1, 0).astype(np.float64)
    bds = np.moveaxis(bds, -1, 0).astype(np.float64)
    sc = 1.0 / (bds.min() * bd_factor)
    poses[:, :3, 3] *= sc
    bds *= sc
    c2w_gl = _nerf_recenter_poses(poses)
    d = np.diag([1.0, -1.0, -1.0, 1.0])
    return d @ c2w_gl @ d, bds.min(), bds.max()


def _random_llff_rows(n: int, seed: int) -> np.ndarray:
    """Forward-facing-ish rows with *different* rotations (each a random tilt of up to ~20 degrees) and
    scattered centres, so that the sums of axes differ from any single camera's axes."""
    rng = np.random.default_rng(seed)
    rows = np.zeros((n, 17))
    for k in range(n):
        a = rng.normal(scale=0.2, size=3)  # small rotation vector (radians)
        theta = np.linalg.norm(a)
        kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]]) / theta
        rot = np.eye(3) + math.sin(theta) * kx + (1 - math.cos(theta)) * kx @ kx  # Rodrigues, OpenCV axes
        m = np.zeros((3, 5))
        m[:, 0] = rot[:, 1]    # down  = OpenCV y
        m[:, 1] = rot[:, 0]    # right = OpenCV x
        m[:, 2] = -rot[:, 2]   # back  = -OpenCV z
        m[:, 3] = rng.normal(scale=0.5, size=3)
        m[:, 4] = (32.0, 48.0, 40.0)
        rows[k, :15] = m.reshape(-1)
        rows[k, 15:] = (rng.uniform(1.5, 3.0), rng.uniform(8.0, 12.0))
    return rows


def test_llff_normalisation_matches_original_nerf_code_on_random_rotations(tmp_path, writers):
    # Catches: recentring from one camera's axes instead of the sums (e.g. x from camera 0's down axis),
    # a wrong cross-product order, the average pose applied on the wrong side, bd_factor scaling the
    # rotations, and any column-order / sign slip of the [down, right, back] conversion, on cameras whose
    # rotations all differ (the tiny rows of the conftest all have identity rotation).
    rows = _random_llff_rows(9, seed=5)
    scene = load_llff(writers.llff(tmp_path / "l", rows=rows), downscale=2)
    want, near, far = _nerf_llff_opencv(rows)
    np.testing.assert_allclose(scene.c2w, want, atol=1e-12)
    assert scene.near == pytest.approx(near, rel=1e-12) and scene.far == pytest.approx(far, rel=1e-12)


def test_fern_poses_match_original_nerf_code(fern_dir, fern8):
    # Same bug class as above on the real capture (fern's rotations differ by a few degrees).
    want, near, far = _nerf_llff_opencv(np.load(fern_dir / "poses_bounds.npy"))
    np.testing.assert_allclose(fern8.c2w, want, atol=1e-10)
    assert fern8.near == pytest.approx(near, rel=1e-12) and fern8.far == pytest.approx(far, rel=1e-12)


def test_llff_exact_folder_is_read_at_its_own_size(tmp_path, writers):
    # Catches: resizing the exact images_N folder to floor(side / N + 0.5) instead of using it as is.
    # Full size 48 x 33 (H odd): images_2 holds 24 x 16 (LLFF floors), while floor(33 / 2 + 0.5) = 17.
    # The intrinsics then scale by the actual ratio: fy = 40 * 16 / 33, cy = 16.5 * 16 / 33 = 8.
    rows = writers.llff_rows(H=33.0)
    scene = load_scene(writers.llff(tmp_path / "l", rows=rows, folder="images_2", size=(16, 24)), downscale=2)
    assert scene.size == (16, 24)
    k = scene.intrinsics
    assert k.fx == pytest.approx(40.0 * 24 / 48) and k.fy == pytest.approx(40.0 * 16 / 33)
    assert (k.cx, k.cy) == pytest.approx((12.0, 8.0))
    want = iio.imread(scene.image_paths[3]).astype(np.float32) / 255.0
    np.testing.assert_allclose(scene.rgb[3], want, atol=1e-7)   # not resampled


def test_llff_resizes_from_the_largest_factor_below(tmp_path, writers):
    # Catches: picking the smallest usable factor (images/, full size) instead of the largest one <= the
    # downscale (images_2) when no exact folder exists.  Downscale 4 from images_2 (24 x 16) is a 2 x 2 block
    # mean of images_2's pixels, which differ from images/'s (different random content).
    root = writers.llff(tmp_path / "l", folder="images", size=(32, 48))
    writers.llff(root, folder="images_2", size=(16, 24))
    scene = load_scene(root, downscale=4)
    assert {p.parent.name for p in scene.image_paths} == {"images_2"}
    src = iio.imread(scene.image_paths[0]).astype(np.float64) / 255.0
    np.testing.assert_allclose(scene.rgb[0], src.reshape(8, 2, 12, 2, 3).mean(axis=(1, 3)), atol=1e-6)


def test_llff_rgb_area_downscale_is_block_mean(tmp_path, writers):
    # Catches: INTER_LINEAR (or any non-area filter) on the RGB (no-alpha) path.  At factor 4 area
    # interpolation is the mean of 4 x 4 blocks; bilinear would average only the middle 2 x 2.
    root = writers.llff(tmp_path / "l", folder="images", size=(32, 48))
    scene = load_scene(root, downscale=4)
    src = iio.imread(scene.image_paths[5]).astype(np.float64) / 255.0
    np.testing.assert_allclose(scene.rgb[5], src.reshape(8, 4, 12, 4, 3).mean(axis=(1, 3)), atol=1e-6)


def test_resize_area_rgb_block_mean_direct():
    # Same bug class on _io.resize_area itself (no alpha): 8 x 12 -> 2 x 3 is the mean of 4 x 4 blocks.
    img = np.random.default_rng(7).random((8, 12, 3)).astype(np.float32)
    out = _io.resize_area(img.copy(), (2, 3))
    np.testing.assert_allclose(out, img.reshape(2, 4, 3, 4, 3).mean(axis=(1, 3)), atol=1e-6)


def test_target_size_rounds_half_up():
    # Catches: Python's round() (half to even) or truncation instead of floor(side / d + 0.5).
    # 10 / 4 = 2.5 -> 3 (round() gives 2); 6 / 4 = 1.5 -> 2; 5 / 2 = 2.5 -> 3; 7 / 4 = 1.75 -> 2.
    assert _io.target_size(10, 6, 4) == (3, 2)
    assert _io.target_size(5, 7, 2) == (3, 4)
    assert _io.target_size(7, 10, 4) == (2, 3)
    assert _io.target_size(1, 1, 8) == (1, 1)   # never 0


def test_downscale_half_pixel_side_rounds_up_in_the_loader(tmp_path, writers):
    # Same bug through load_scene: a 10 x 4 (W x H) Blender image at downscale 4 is 3 x 1 (10/4 = 2.5 -> 3,
    # 4/4 = 1).  f = 0.5 * 10 / tan(atan(0.5)) = 10 px at full size; fx' = 10 * 3/10 = 3, fy' = 10 * 1/4.
    root = writers.blender(tmp_path / "s", image=lambda seed: writers.rgba(seed, 4, 10))
    k = load_scene(root, downscale=4).intrinsics
    assert (k.width, k.height) == (3, 1)
    assert (k.fx, k.fy) == pytest.approx((3.0, 2.5))


# --- instant-ngp / nerfstudio: non-square images ---------------------------------------------------------

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
    # Catches: fy from camera_angle_y but with the width (or fx from the height), and a principal point
    # with width/height swapped; the conftest's images are square, so those slips were invisible.
    # W = 6, H = 4: fx = 0.5 * 6 / tan(atan(0.5)) = 6, fy = 0.5 * 4 / tan(atan(0.25)) = 8, c = (3, 2).
    root = _ngp_nonsquare(tmp_path / "n", writers, camera_angle_x=2 * math.atan(0.5),
                          camera_angle_y=2 * math.atan(0.25), w=6, h=4)
    k = load_scene(root).intrinsics
    assert (k.width, k.height) == (6, 4)
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((6.0, 8.0, 3.0, 2.0))
    # without camera_angle_y, fy = fx (square pixels): 6, not 0.5 * 4 / 0.5 = 4
    root2 = _ngp_nonsquare(tmp_path / "n2", writers, camera_angle_x=2 * math.atan(0.5))
    k2 = load_scene(root2).intrinsics
    assert (k2.fx, k2.fy) == pytest.approx((6.0, 6.0))


def test_ngp_declared_w_h_checked_against_the_right_sides(tmp_path, writers):
    # Catches: checking declared w against the image height (and h against the width).  Declared w = 6,
    # h = 4 match 6 x 4 images and must load; swapped declarations must be refused naming the field.
    ok = _ngp_nonsquare(tmp_path / "ok", writers, fl_x=5.0, w=6, h=4)
    assert load_scene(ok).size == (4, 6)
    bad = _ngp_nonsquare(tmp_path / "bad", writers, fl_x=5.0, w=4, h=6)
    with pytest.raises(InputError) as info:
        load_scene(bad)
    assert info.value.field in ("w", "h")


def test_ngp_split_lists_match_file_paths_without_suffix(tmp_path, writers):
    # Catches: matching the split lists only against the frame's literal file_path.  A frame written
    # "images/f_0" (no suffix, .png appended by the loader) listed as "images/f_0.png" is a train frame.
    root = writers.ngp(tmp_path / "n", meta_extra={"train_filenames": ["images/f_0.png", "images/f_1.png"],
                                                   "test_filenames": ["images/f_2.png"]})
    meta = writers.read_json(root / "transforms.json")
    meta["frames"][0]["file_path"] = "images/f_0"
    meta["frames"][2]["file_path"] = "./images/f_2"
    writers.write_json(root / "transforms.json", meta)
    scene = load_scene(root)
    assert scene.splits["train"].tolist() == [0, 1]
    assert scene.splits["test"].tolist() == [2]


# --- few-shot protocols ----------------------------------------------------------------------------------

#: REFERENCE.md section 5, copied by hand: "chair 26,31,32; drums 3,9,14; ficus 12,36,56; hotdog 31,33,48;
#: lego 0,1,51; materials 47,63,73; ship 36,55,66; mic 35,65,82".
_REFERENCE_EXTREME = {"chair": (26, 31, 32), "drums": (3, 9, 14), "ficus": (12, 36, 56), "hotdog": (31, 33, 48),
                      "lego": (0, 1, 51), "materials": (47, 63, 73), "ship": (36, 55, 66), "mic": (35, 65, 82)}


def test_extreme_views_table_is_the_reference_for_every_scene():
    # Catches: a typo in any scene's Extreme views (only lego, chair, mic and ship were checked before).
    assert {k: tuple(v) for k, v in EXTREME_VIEWS.items()} == _REFERENCE_EXTREME


def test_extreme_protocol_uses_the_table_for_every_scene():
    # Same, through fewshot_split: 100 train views after 10 val views, so index v -> 10 + v.
    for name, views in _REFERENCE_EXTREME.items():
        scene = _object_scene(130, {"val": np.arange(10), "train": np.arange(10, 110), "test": np.arange(110, 130)},
                              name=name)
        train, _ = fewshot_split(scene, "extreme")
        assert train.tolist() == [10 + v for v in views], name


def _object_scene(n: int, splits: dict, name: str = "obj") -> Scene:
    """A 1x1-pixel object scene with ``n`` views (only indices matter)."""
    k = Intrinsics(1.0, 1.0, 0.5, 0.5, 1, 1)
    return Scene(name=name, root=Path(name), rgb=np.zeros((n, 1, 1, 3), np.float32), alpha=None, intrinsics=k,
                 intrinsics_all=(k,) * n, c2w=np.broadcast_to(np.eye(4), (n, 4, 4)).copy(), splits=splits,
                 kind="object", image_paths=tuple(f"{i}.png" for i in range(n)))


@pytest.mark.parametrize("other", ["test", "val"])
def test_views_index_the_train_split_when_only_one_other_split_exists(other):
    # Catches: requiring *both* a val and a test split before views index the train split (a nerfstudio
    # file with train and test lists but no val list, or train and val only).  Train split = 3, 4, 5: view 0
    # is image 3.
    scene = _object_scene(6, {"train": [3, 4, 5], other: [0, 1, 2]})
    if other == "test":
        train, test = fewshot_split(scene, "views", views=[0, 2])
        assert train.tolist() == [3, 5] and test.tolist() == [0, 1, 2]
    else:
        with pytest.raises(InputError, match="no test split"):   # indexes the train split, then needs a test split
            fewshot_split(scene, "views", views=[0, 2])
