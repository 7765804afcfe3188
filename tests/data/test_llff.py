"""Tests of senerf/data/llff.py: LLFF column convention, normalisation, folder choice; real fern scene."""

from __future__ import annotations

import numpy as np
import pytest

from senerf.data import fewshot_split, load_llff, load_scene
from senerf.geometry import closest_point_to_axes, is_rigid, project


def test_llff_columns_to_opencv_identity(tmp_path, writers):
    # The tiny rows encode [down, right, back] = [+y, +x, -z]: an OpenCV camera with identity rotation.
    root = writers.llff(tmp_path / "l")
    scene = load_llff(root, downscale=2, bd_factor=None, recenter=False)
    for k in range(9):
        np.testing.assert_allclose(scene.c2w[k, :3, :3], np.eye(3), atol=0)
        np.testing.assert_allclose(scene.c2w[k, :3, 3], (0.1 * k, 0.0, 0.0))
    assert scene.kind == "forward_facing"
    assert (scene.near, scene.far) == (2.0, 10.0)
    assert scene.source_files == (root / "poses_bounds.npy",)   # what scene_file_digests hashes


def test_llff_rotated_camera_projects_consistently(tmp_path, writers):
    # Camera 0 rotated 90 degrees about the world z axis: its right = world +y, down = world -x,
    # forward = world +z (back = -z).  The point 5 ahead and 1 along world +y lies to the image right:
    # u = cx + f * 1 / 5 with f = 40 px at 48 px width -> 20 px at 24 px (downscale 2), cx = 12: u = 16.
    rows = writers.llff_rows()
    m = rows[0, :15].reshape(3, 5)
    m[:, 0] = (-1.0, 0.0, 0.0)  # down
    m[:, 1] = (0.0, 1.0, 0.0)   # right
    m[:, 2] = (0.0, 0.0, -1.0)  # back
    m[:, 3] = 0.0
    rows[0, :15] = m.reshape(-1)
    scene = load_llff(writers.llff(tmp_path / "l", rows=rows), downscale=2, bd_factor=None, recenter=False)
    uv, z, valid = project(np.array([0.0, 1.0, 5.0]), scene.intrinsics, scene.c2w[0])
    assert valid and z == pytest.approx(5.0)
    np.testing.assert_allclose(uv, (16.0, 8.0), atol=1e-12)


def test_llff_bd_factor_and_recenter(tmp_path, writers):
    # bd_factor 0.75: near 2 -> 1/0.75, so everything scales by 1/(2 * 0.75) = 2/3; far 10 -> 20/3.
    # Recentring moves the mean camera centre (0.4, 0, 0) * 2/3 to the origin; rotations stay identity.
    scene = load_llff(writers.llff(tmp_path / "l"), downscale=2)
    assert scene.near == pytest.approx(1 / 0.75) and scene.far == pytest.approx(20 / 3)
    x = (0.1 * np.arange(9) - 0.4) * (2 / 3)
    np.testing.assert_allclose(scene.c2w[:, 0, 3], x, atol=1e-12)
    np.testing.assert_allclose(scene.c2w[:, :3, :3], np.broadcast_to(np.eye(3), (9, 3, 3)), atol=1e-12)


def test_llff_folder_choice_and_resize(tmp_path, writers):
    # Full size 48x32 (rows' hwf).  Only images_2 (24x16) exists: downscale 2 uses it as is, downscale 4
    # resizes it to 12x8, downscale 3 resizes to floor(48/3+.5) x floor(32/3+.5) = 16 x 11.
    root = writers.llff(tmp_path / "l")
    assert load_scene(root, downscale=2).size == (16, 24)
    s4 = load_scene(root, downscale=4)
    assert s4.size == (8, 12) and s4.intrinsics.fx == pytest.approx(10.0)  # f 40 at 48 px -> 10 at 12 px
    s3 = load_scene(root, downscale=3)
    assert s3.size == (11, 16)
    assert s3.intrinsics.fx == pytest.approx(40 * 16 / 48) and s3.intrinsics.fy == pytest.approx(40 * 11 / 32)


def test_llff_prefers_exact_folder(tmp_path, writers):
    root = writers.llff(tmp_path / "l", folder="images", size=(32, 48))
    writers.llff(root, folder="images_4", size=(8, 12))
    scene = load_scene(root, downscale=4)
    assert scene.image_paths[0].parent.name == "images_4"
    assert load_scene(root, downscale=1).image_paths[0].parent.name == "images"


def test_llff_splits_every_eighth(tmp_path, writers):
    scene = load_scene(writers.llff(tmp_path / "l"), downscale=2)
    assert scene.splits["test"].tolist() == [0, 8]
    assert scene.splits["train"].tolist() == [1, 2, 3, 4, 5, 6, 7]
    assert scene.alpha is None


# --- the real fern scene ---------------------------------------------------------------------------------

def test_fern_size_and_focal(fern_dir, fern8):
    raw = np.load(fern_dir / "poses_bounds.npy")
    h, w, f = raw[0, :15].reshape(3, 5)[:, 4]
    assert (h, w) == (3024, 4032)
    assert fern8.rgb.shape == (20, 378, 504, 3)
    # images_8: 4032 / 8 = 504, 3024 / 8 = 378, so f / 8 exactly.
    assert fern8.intrinsics.fx == pytest.approx(f / 8) and fern8.intrinsics.fy == pytest.approx(f / 8)
    assert (fern8.intrinsics.cx, fern8.intrinsics.cy) == (252.0, 189.0)


def test_fern_poses_rigid_bounds_scaled(fern_dir, fern8):
    raw = np.load(fern_dir / "poses_bounds.npy")
    assert is_rigid(fern8.c2w, atol=1e-9).all()
    assert fern8.near == pytest.approx(1 / 0.75)
    assert fern8.far / fern8.near == pytest.approx(raw[:, 16].max() / raw[:, 15].min())


def test_fern_forward_facing(fern8):
    # All optical axes roughly parallel (within ~10 degrees of their mean); after recentring the mean
    # forward axis is world +z and the mean camera centre the origin.
    fwd = fern8.c2w[:, :3, 2]
    mean = fwd.mean(axis=0) / np.linalg.norm(fwd.mean(axis=0))
    assert (fwd @ mean).min() > np.cos(np.radians(10))
    np.testing.assert_allclose(mean, (0, 0, 1), atol=1e-9)
    np.testing.assert_allclose(fern8.c2w[:, :3, 3].mean(axis=0), 0, atol=1e-9)
    # The point nearest all axes lies in front of every camera, inside the scene bounds, near the centre.
    uv, z, valid = project(closest_point_to_axes(fern8.c2w), fern8.intrinsics, fern8.c2w)
    assert valid.all() and (z > fern8.near).all() and (z < fern8.far).all()
    assert np.abs(uv - (252.0, 189.0)).max() < 40


def test_fern_llff_protocol(fern8):
    # 20 images: test = 0, 8, 16; the rest has 17 images, linspace(0, 16, 3) = 0, 8, 16 picks
    # rest[0] = 1, rest[8] = 10 (rest = 1..7, 9..15, 17..19), rest[16] = 19.
    train, test = fewshot_split(fern8, "llff", n_views=3)
    assert test.tolist() == [0, 8, 16]
    assert train.tolist() == [1, 10, 19]


def test_fern_downscale_1_without_images_folder_is_refused(fern_dir):
    from senerf.errors import InputError

    with pytest.raises(InputError, match="images_8"):
        load_scene(fern_dir)


def test_cameras_looking_away_from_the_others_are_refused_by_row(tmp_path, writers):
    # a row turned 180 degrees (facing back) cannot be held by one NDC frustum; with a COLMAP model beside (as
    # mip-NeRF 360 folders ship poses_bounds.npy), the refusal is the same row
    from senerf.errors import InputError

    rows = writers.llff_rows()
    m = rows[3, :15].reshape(3, 5)
    m[:, 1], m[:, 2] = (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)   # right -x, back +z: row 3 looks along -z
    rows[3, :15] = m.reshape(-1)
    root = writers.llff(tmp_path / "360", rows)
    for _ in range(2):
        with pytest.raises(InputError) as info:
            load_llff(root, downscale=2)
        assert (info.value.file, info.value.field) == (str(root / "poses_bounds.npy"), "row 3")
        (root / "sparse" / "0").mkdir(parents=True, exist_ok=True)
        (root / "sparse" / "0" / "cameras.txt").write_text("")


def test_the_forward_facing_limits_sit_where_the_docs_say(tmp_path, writers):
    # far / near up to MAX_DEPTH_RANGE (1e6) and rays up to 90 degrees from the cameras' mean direction
    from senerf.data.llff import MAX_DEPTH_RANGE
    from senerf.errors import InputError

    def load(name, rows):
        return load_llff(writers.llff(tmp_path / name, rows), downscale=2)

    assert MAX_DEPTH_RANGE == 1e6
    load("range_ok", writers.llff_rows(near=1.0, far=0.99e6))
    rows = writers.llff_rows(near=1.0, far=1.01e6)
    rows[3, 15] = 0.5   # row 3's near bound is the smallest: it is named
    with pytest.raises(InputError) as info:
        load("range_bad", rows)
    assert info.value.field == "row 3 bounds"
    for degrees, ok in ((60.0, True), (70.0, False)):   # row 3 turned about y: its rays reach 94 degrees at 70
        rows = writers.llff_rows()
        m = rows[3, :15].reshape(3, 5)
        t = np.radians(degrees)
        m[:, :3] = np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]]) @ m[:, :3]
        rows[3, :15] = m.reshape(-1)
        if ok:
            load(f"turn_{degrees:g}", rows)
        else:
            with pytest.raises(InputError) as info:
                load(f"turn_{degrees:g}", rows)
            assert info.value.field == "row 3"


def test_poses_bounds_missing_unreadable_or_not_numeric_are_refused(tmp_path, writers):
    from senerf.errors import InputError

    file = tmp_path / "poses_bounds.npy"
    for content in (None, b"\x93NUMPY\x01\x00garbage", writers.llff_rows().astype(np.complex128)):
        if isinstance(content, bytes):
            file.write_bytes(content)
        elif content is not None:
            np.save(file, content)
        with pytest.raises(InputError) as info:
            load_llff(tmp_path)
        assert info.value.file == str(file)
    root = writers.llff(tmp_path / "ok", rows=writers.llff_rows().astype(np.float32))   # float32 rows are read
    assert load_llff(root, downscale=2).n_images == 9


@pytest.mark.parametrize("column, row", [(4, 6), (9, 4)])   # hwf is column 4 of the 3x5 matrix: H at 4, W at 9
def test_rows_of_different_image_sizes_name_the_first_odd_row(tmp_path, writers, column, row):
    from senerf.errors import InputError

    rows = writers.llff_rows()
    rows[row, column] += 8.0
    rows[row + 1, column] += 8.0
    root = writers.llff(tmp_path / "s", rows=rows)
    with pytest.raises(InputError) as info:
        load_llff(root)
    assert (info.value.file, info.value.field) == (str(root / "poses_bounds.npy"), f"row {row} hwf.H,W")


# --- against the original NeRF LLFF code (bmild/nerf, load_llff.py), written out in float64 -------------------

def _nerf_normalize(x):
    return x / np.linalg.norm(x)


def _nerf_viewmatrix(z, up, pos):
    vec2 = _nerf_normalize(z)
    vec0 = _nerf_normalize(np.cross(up, vec2))
    vec1 = _nerf_normalize(np.cross(vec2, vec0))
    return np.stack([vec0, vec1, vec2, pos], 1)


def _nerf_recenter_poses(poses):
    center = poses[:, :3, 3].mean(0)
    avg = _nerf_viewmatrix(poses[:, :3, 2].sum(0), poses[:, :3, 1].sum(0), center)
    bottom = np.reshape([0, 0, 0, 1.0], [1, 4])
    c2w = np.concatenate([avg, bottom], -2)
    bottom = np.tile(np.reshape(bottom, [1, 1, 4]), [poses.shape[0], 1, 1])
    return np.linalg.inv(c2w) @ np.concatenate([poses[:, :3, :4], bottom], -2)


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
    d = np.diag([1.0, -1.0, -1.0, 1.0])
    return d @ _nerf_recenter_poses(poses) @ d, bds.min(), bds.max()


def _random_llff_rows(n: int, seed: int) -> np.ndarray:
    """Forward-facing rows with *different* rotations (each a random tilt of up to ~20 degrees) and scattered
    centres, so that the sums of axes differ from any single camera's axes."""
    rng = np.random.default_rng(seed)
    rows = np.zeros((n, 17))
    for k in range(n):
        a = rng.normal(scale=0.2, size=3)  # small rotation vector (radians)
        theta = np.linalg.norm(a)
        kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]]) / theta
        rot = np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx  # Rodrigues, OpenCV axes
        m = np.zeros((3, 5))
        m[:, 0], m[:, 1], m[:, 2] = rot[:, 1], rot[:, 0], -rot[:, 2]   # down = y, right = x, back = -z
        m[:, 3] = rng.normal(scale=0.5, size=3)
        m[:, 4] = (32.0, 48.0, 40.0)
        rows[k, :15] = m.reshape(-1)
        rows[k, 15:] = (rng.uniform(1.5, 3.0), rng.uniform(8.0, 12.0))
    return rows


def test_normalisation_matches_the_original_nerf_code_on_random_rotations(tmp_path, writers):
    # cameras whose rotations all differ: recentring from sums of axes, the cross-product order, the side the
    # average pose is applied on, bd_factor scaling only positions, the [down, right, back] conversion
    rows = _random_llff_rows(9, seed=5)
    scene = load_llff(writers.llff(tmp_path / "l", rows=rows), downscale=2)
    want, near, far = _nerf_llff_opencv(rows)
    np.testing.assert_allclose(scene.c2w, want, atol=1e-12)
    assert scene.near == pytest.approx(near, rel=1e-12) and scene.far == pytest.approx(far, rel=1e-12)


def test_fern_poses_match_the_original_nerf_code(fern_dir, fern8):
    want, near, far = _nerf_llff_opencv(np.load(fern_dir / "poses_bounds.npy"))
    np.testing.assert_allclose(fern8.c2w, want, atol=1e-10)
    assert fern8.near == pytest.approx(near, rel=1e-12) and fern8.far == pytest.approx(far, rel=1e-12)


# --- image folders and downscaling --------------------------------------------------------------------------

def test_the_exact_folder_is_read_at_its_own_size(tmp_path, writers):
    # Full size 48 x 33 (H odd): images_2 holds 24 x 16 (LLFF floors), while floor(33 / 2 + 0.5) = 17.
    # The intrinsics then scale by the actual ratio: fy = 40 * 16 / 33, cy = 16.5 * 16 / 33 = 8.
    import imageio.v3 as iio

    rows = writers.llff_rows(H=33.0)
    scene = load_scene(writers.llff(tmp_path / "l", rows=rows, folder="images_2", size=(16, 24)), downscale=2)
    assert scene.size == (16, 24)
    k = scene.intrinsics
    assert k.fx == pytest.approx(40.0 * 24 / 48) and k.fy == pytest.approx(40.0 * 16 / 33)
    assert (k.cx, k.cy) == pytest.approx((12.0, 8.0))
    np.testing.assert_allclose(scene.rgb[3], iio.imread(scene.image_paths[3]) / 255.0, atol=1e-7)   # not resampled


@pytest.mark.parametrize("folders, downscale, block", [(("images",), 4, 4), (("images", "images_2"), 4, 2)])
def test_other_folders_are_area_resized_from_the_largest_factor_below(tmp_path, writers, folders, downscale, block):
    # area interpolation by an integer factor is the block mean (bilinear would average only the middle 2 x 2);
    # with images/ and images_2/, downscale 4 reads images_2 (whose content differs from images/'s)
    import imageio.v3 as iio

    root = tmp_path / "l"
    for folder in folders:   # full size 48 x 32 (the rows' H, W)
        writers.llff(root, folder=folder, size={"images": (32, 48), "images_2": (16, 24)}[folder])
    scene = load_scene(root, downscale=downscale)
    assert {p.parent.name for p in scene.image_paths} == {folders[-1]}
    src = iio.imread(scene.image_paths[5]).astype(np.float64) / 255.0
    h, w = src.shape[0] // block, src.shape[1] // block
    np.testing.assert_allclose(scene.rgb[5], src.reshape(h, block, w, block, 3).mean(axis=(1, 3)), atol=1e-6)
