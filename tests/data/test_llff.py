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


def test_bounds_spanning_too_many_decades_and_overflowing_poses_are_refused(tmp_path, writers):
    # near bounds of 1e-300, or a camera at 1e308, loaded and then trained to a NaN loss (so at 2e4108c)
    from senerf.data.llff import MAX_DEPTH_RANGE
    from senerf.errors import InputError

    rows = writers.llff_rows()
    rows[3, 15] = 1e-300
    with pytest.raises(InputError, match="near bound 1e-300 is .* times smaller than the largest far bound") as info:
        load_llff(writers.llff(tmp_path / "near", rows), downscale=2)
    assert info.value.field == "row 3 bounds"
    rows = writers.llff_rows(near=1.0, far=0.99 * MAX_DEPTH_RANGE)   # within the limit: loads
    assert load_llff(writers.llff(tmp_path / "ok", rows), downscale=2).far > 0
    rows = writers.llff_rows()
    rows[2, 3] = 1e308   # row 2's x translation (column 3 of the first matrix row)
    with pytest.raises(InputError, match="times the scene's far bound") as info:
        load_llff(writers.llff(tmp_path / "far", rows), downscale=2)
    assert info.value.field == "row 2"
    rows = writers.llff_rows(near=0.5, far=1.0)   # positions scaled by 1 / (0.75 near) = 8 / 3: 1e308 overflows
    rows[2, 3] = 1e308
    with pytest.raises(InputError, match="overflow when the scene is normalised"):
        load_llff(writers.llff(tmp_path / "inf", rows), downscale=2)


def test_cameras_looking_away_from_the_others_are_refused(tmp_path, writers):
    # odd rows turned 180 degrees (facing back) loaded and trained to 4.8 dB (so at 05e263a); COLMAP's
    # forward-facing check already refused rays beyond 90 degrees from the mean direction
    from senerf.errors import InputError

    rows = writers.llff_rows()
    m = rows[3, :15].reshape(3, 5)
    m[:, 1] = (-1.0, 0.0, 0.0)   # right: -x
    m[:, 2] = (0.0, 0.0, 1.0)    # back: +z, so the camera looks along -z, away from the others
    rows[3, :15] = m.reshape(-1)
    with pytest.raises(InputError, match="some rays look .* degrees away from the cameras' mean direction") as info:
        load_llff(writers.llff(tmp_path / "back", rows), downscale=2)
    assert info.value.field == "row 3"


def test_a_surrounding_capture_with_a_colmap_model_beside_is_pointed_to_it_and_tiny_sizes_are_not_a_traceback(
        tmp_path, writers):
    # mip-NeRF 360 folders ship poses_bounds.npy beside sparse/0: the refusal now says how to fit the capture
    # (a review); and a width under 0.5 pixels built an Intrinsics of width 0 and raised a traceback (so at 3cbad99)
    from senerf.errors import InputError

    rows = writers.llff_rows()
    m = rows[3, :15].reshape(3, 5)
    m[:, 1], m[:, 2] = (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)   # row 3 looks back
    rows[3, :15] = m.reshape(-1)
    root = writers.llff(tmp_path / "360", rows)
    (root / "sparse" / "0").mkdir(parents=True)
    (root / "sparse" / "0" / "cameras.txt").write_text("")
    with pytest.raises(InputError, match="move poses_bounds.npy aside") as info:
        load_llff(root, downscale=2)
    assert info.value.field == "row 3"
    rows = writers.llff_rows(W=0.3)
    with pytest.raises(InputError) as info:   # one line, exit 2: not a ValueError from Intrinsics
        load_llff(writers.llff(tmp_path / "thin", rows), downscale=2)
    assert "images are" in str(info.value)


def test_the_forward_facing_limits_sit_where_the_docs_say(tmp_path, writers):
    # each limit was only tested far beyond it (1e-300 bounds, a camera at 1e308, one turned 180 degrees), so a
    # limit moved by decades still passed (mutations of MAX_DEPTH_RANGE, the 90 degrees and the offset survived)
    from senerf.errors import InputError

    def load(name, rows):
        return load_llff(writers.llff(tmp_path / name, rows), downscale=2)

    load("range_ok", writers.llff_rows(near=1.0, far=0.99e6))                  # far / near up to 1e6 (README)
    with pytest.raises(InputError, match="times smaller than the largest far bound"):
        load("range_bad", writers.llff_rows(near=1.0, far=1.01e6))
    for x, ok in ((5.6e6, True), (2.25e7, False)):   # camera 2's offset from the mean: 8/9 x / far 10 = 5e5, 2e6
        rows = writers.llff_rows()
        rows[2, 3] = x
        if ok:
            load(f"offset_{x:g}", rows)
        else:
            with pytest.raises(InputError, match=r"times the scene's far bound") as info:
                load(f"offset_{x:g}", rows)
            assert info.value.field == "row 2"
    for degrees, ok in ((60.0, True), (70.0, False)):   # row 3 turned about y: its rays reach 94 degrees at 70
        rows = writers.llff_rows()
        m = rows[3, :15].reshape(3, 5)
        t = np.radians(degrees)
        m[:, :3] = np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]]) @ m[:, :3]
        rows[3, :15] = m.reshape(-1)
        if ok:
            load(f"turn_{degrees:g}", rows)
        else:
            with pytest.raises(InputError, match=r"some rays look 9\d degrees away"):
                load(f"turn_{degrees:g}", rows)
