"""Tests of senerf/data/colmap.py: COLMAP model files (binary and text), poses, bounds, kinds, errors.

The model files are written here from COLMAP's documented layouts, independently of the reader; quaternions
come from scipy.  On the real fern scene the reader is checked against what LLFF's ``imgs2poses`` computed from
the same COLMAP model (``poses_bounds.npy``: focal, image size and every view's depth bounds).
"""

from __future__ import annotations

import os
import shutil
import struct

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from senerf.data import Distortion, detect_format, load_llff, load_scene, undistorted_intrinsics
from senerf.data.colmap import read_cameras, read_images, read_points3d
from senerf.errors import InputError
from senerf.geometry import Intrinsics, invert_rigid, pose_from_spherical

MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4, "OPENCV_FISHEYE": 5,
             "FULL_OPENCV": 6}


def qvec_tvec(c2w: np.ndarray) -> tuple:
    """COLMAP's world-to-camera ``(qw, qx, qy, qz)``, ``t`` of an OpenCV ``c2w`` (scipy's quaternion)."""
    w2c = invert_rigid(c2w)
    x, y, z, w = Rotation.from_matrix(w2c[:3, :3]).as_quat()
    return (w, x, y, z), tuple(w2c[:3, 3])


def write_model(folder, cameras: dict, images: list, points: list, binary: bool) -> None:
    """``cameras``: id -> (model, w, h, params); ``images``: (id, c2w, camera id, name); ``points``:
    (xyz, [image ids])."""
    folder.mkdir(parents=True, exist_ok=True)
    if binary:
        out = struct.pack("<Q", len(cameras))
        for cid, (model, w, h, params) in cameras.items():
            out += struct.pack("<iiQQ", cid, MODEL_IDS[model], w, h) + struct.pack(f"<{len(params)}d", *params)
        (folder / "cameras.bin").write_bytes(out)
        out = struct.pack("<Q", len(images))
        for iid, c2w, cid, name in images:
            q, t = qvec_tvec(c2w)
            out += struct.pack("<i7di", iid, *q, *t, cid) + name.encode() + b"\0"
            out += struct.pack("<Q", 2) + struct.pack("<ddq", 1.5, 2.5, -1) + struct.pack("<ddq", 3.0, 4.0, 7)
        (folder / "images.bin").write_bytes(out)
        out = struct.pack("<Q", len(points))
        for pid, (xyz, seen) in enumerate(points, 1):
            out += struct.pack("<Q3d3BdQ", pid, *xyz, 10, 20, 30, 0.5, len(seen))
            out += b"".join(struct.pack("<ii", s, 0) for s in seen)
        (folder / "points3D.bin").write_bytes(out)
        return
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    lines += [f"{cid} {model} {w} {h} " + " ".join(repr(float(p)) for p in params)
              for cid, (model, w, h, params) in cameras.items()]
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:"]
    for k, (iid, c2w, cid, name) in enumerate(images):
        q, t = qvec_tvec(c2w)
        lines.append(f"{iid} " + " ".join(repr(float(v)) for v in (*q, *t)) + f" {cid} {name}")
        lines.append("1.5 2.5 -1 3.0 4.0 7" if k % 2 else "")  # an image without 2D points: an empty line
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    lines = ["# 3D point list"]
    for pid, (xyz, seen) in enumerate(points, 1):
        lines.append(f"{pid} " + " ".join(repr(float(v)) for v in xyz) + " 10 20 30 0.5 "
                     + " ".join(f"{s} 0" for s in seen))
    (folder / "points3D.txt").write_text("\n".join(lines) + "\n")


def ring_scene(root, binary: bool, azimuths, model=("PINHOLE", (20.0, 21.0, 8.0, 6.0)), elevation=20.0,
               far_points: int = 0):
    """Cameras on a ring looking at the origin, tiny images, 40 points around the origin seen by all (and
    ``far_points`` more on a sphere of radius 20 around it, a background)."""
    poses = [pose_from_spherical(az, elevation, 4.0) for az in azimuths]
    names = [f"v_{k:02d}.png" for k in range(len(poses))]
    images = [(10 + k, pose, 1, name) for k, (pose, name) in enumerate(zip(poses, names))]
    rng = np.random.default_rng(0)
    points = [(tuple(rng.uniform(-0.5, 0.5, 3)), [10 + k for k in range(len(poses))]) for _ in range(40)]
    for _ in range(far_points):
        direction = rng.normal(size=3)
        points.append((tuple(20.0 * direction / np.linalg.norm(direction)), [10]))
    write_model(root / "sparse" / "0", {1: (model[0], 16, 12, model[1])}, images[::-1], points, binary)
    (root / "images").mkdir(parents=True, exist_ok=True)
    for k, name in enumerate(names):
        iio.imwrite(root / "images" / name, np.random.default_rng(k).integers(0, 256, (12, 16, 3), dtype=np.uint8))
    return root, np.stack(poses)


@pytest.mark.parametrize("binary", [True, False])
def test_object_capture_poses_and_cameras_read_back(tmp_path, binary):
    root, poses = ring_scene(tmp_path / "s", binary, np.arange(0, 360, 30))
    assert detect_format(root) == "colmap"
    scene = load_scene(root)
    assert scene.kind == "unbounded" and scene.near is None and scene.n_images == 12   # RGB photos
    np.testing.assert_allclose(scene.c2w, poses, atol=1e-12)  # sorted by name, COLMAP's world frame kept
    assert scene.intrinsics == Intrinsics(20.0, 21.0, 8.0, 6.0, 16, 12)
    assert [p.name for p in scene.image_paths] == [f"v_{k:02d}.png" for k in range(12)]
    assert scene.splits["test"].tolist() == [0, 8] and len(scene.splits["train"]) == 10
    ext = "bin" if binary else "txt"   # the files scene_file_digests hashes (points3D: forward-facing only)
    assert scene.source_files == tuple(root / "sparse" / "0" / f"{stem}.{ext}" for stem in ("cameras", "images"))


def test_binary_and_text_models_read_the_same(tmp_path):
    for binary in (True, False):
        ring_scene(tmp_path / str(binary), binary, [0, 10, 20], model=("OPENCV", (20, 21, 8, 6, -0.1, 0.01, 1e-3, 0)))
    folders = [tmp_path / str(b) / "sparse" / "0" for b in (True, False)]
    assert read_cameras(folders[0] / "cameras.bin") == read_cameras(folders[1] / "cameras.txt")
    assert read_images(folders[0] / "images.bin") == read_images(folders[1] / "images.txt")
    (xyz_b, (ids_b, idx_b)), (xyz_t, (ids_t, idx_t)) = (read_points3d(folders[0] / "points3D.bin"),
                                                        read_points3d(folders[1] / "points3D.txt"))
    np.testing.assert_array_equal(xyz_b, xyz_t)
    assert ids_b.tolist() == ids_t.tolist() == [10, 11, 12] * 40 and idx_b.tolist() == idx_t.tolist()


def test_forward_facing_capture_is_normalised_as_llff(tmp_path):
    root, poses = ring_scene(tmp_path / "s", True, [0, 5, 10, 15, 20])
    scene = load_scene(root)
    assert scene.kind == "forward_facing" and 0 < scene.near < scene.far
    assert np.allclose(scene.c2w[:, :3, :3].mean(0), np.eye(3), atol=0.1)  # recentred: mean pose ~ identity
    assert np.abs(scene.c2w[:, :3, 3].mean(0)).max() < 1e-12
    # bd_factor: the nearest bound becomes 1 / 0.75
    assert scene.near == pytest.approx(1 / 0.75)
    # its depth bounds, and so its scale, come from points3D too
    assert scene.source_files == tuple(root / "sparse" / "0" / f"{s}.bin" for s in ("cameras", "images", "points3D"))


def test_lens_distortion_is_undone(tmp_path):
    root, _ = ring_scene(tmp_path / "s", False, np.arange(0, 360, 60),
                         model=("SIMPLE_RADIAL", (20.0, 8.0, 6.0, -0.08)))
    scene = load_scene(root)
    expected = undistorted_intrinsics(Intrinsics(20.0, 20.0, 8.0, 6.0, 16, 12),
                                      Distortion("opencv", (-0.08, 0.0, 0.0, 0.0, 0.0)))
    assert scene.intrinsics == expected != Intrinsics(20.0, 20.0, 8.0, 6.0, 16, 12)


def test_real_fern_model_agrees_with_llffs_poses_bounds(fern_dir):
    # poses_bounds.npy was made by LLFF's imgs2poses from this very COLMAP model
    from senerf.data.colmap import _depth_bounds

    rows = np.load(fern_dir / "poses_bounds.npy").astype(np.float64)
    (cam,) = read_cameras(fern_dir / "sparse" / "0" / "cameras.bin").values()
    assert (cam.model, cam.height, cam.width) == ("SIMPLE_RADIAL", 3024, 4032)
    np.testing.assert_allclose(rows[:, 4:15:5], [[3024, 4032, cam.params[0]]] * 20, rtol=1e-12)
    points = read_points3d(fern_dir / "sparse" / "0" / "points3D.bin")
    c2w = load_llff(fern_dir, downscale=8, bd_factor=None, recenter=False).c2w   # the rows' poses, in OpenCV's frame
    bounds = _depth_bounds(c2w, list(range(1, 21)), points, fern_dir)
    np.testing.assert_allclose(bounds, rows[:, 15:17], rtol=1e-12)


def test_fern_as_a_colmap_folder_loads_as_llff_does(fern_dir, tmp_path):
    # a COLMAP folder made from fern: its real cameras (scaled to images_8) and points, and images.txt holding
    # the poses of poses_bounds.npy; poses and bounds must come out as load_llff's
    poses = load_llff(fern_dir, downscale=8, bd_factor=None, recenter=False).c2w
    (cam,) = read_cameras(fern_dir / "sparse" / "0" / "cameras.bin").values()
    f, cx, cy, k = cam.params
    names = sorted(p.name for p in (fern_dir / "images_8").iterdir())
    images = [(i + 1, pose, 1, name) for i, (pose, name) in enumerate(zip(poses, names))]
    model = tmp_path / "fern" / "sparse" / "0"
    write_model(model, {1: ("SIMPLE_RADIAL", 504, 378, (f / 8, cx / 8, cy / 8, k))}, images[::-1], [], False)
    (model / "points3D.txt").unlink()
    shutil.copy(fern_dir / "sparse" / "0" / "points3D.bin", model / "points3D.bin")
    shutil.copytree(fern_dir / "images_8", tmp_path / "fern" / "images")
    ours, llff = load_scene(tmp_path / "fern"), load_llff(fern_dir, downscale=8)
    assert ours.kind == "forward_facing"
    np.testing.assert_allclose(ours.c2w, llff.c2w, atol=1e-10)
    assert (ours.near, ours.far) == pytest.approx((llff.near, llff.far), rel=1e-12)
    assert ours.splits["test"].tolist() == llff.splits["test"].tolist()
    # LLFF ignores the lens's k = 0.0198; COLMAP's camera is used, undistorted
    assert ours.intrinsics == undistorted_intrinsics(Intrinsics(f / 8, f / 8, cx / 8, cy / 8, 504, 378),
                                                     Distortion("opencv", (k, 0.0, 0.0, 0.0, 0.0)))


def _error(root, **kw) -> InputError:
    """The one-line :class:`InputError` that loading ``root`` raises."""
    with pytest.raises(InputError) as info:
        load_scene(root, **kw)
    assert "\n" not in str(info.value)
    return info.value


def _names(error: InputError, file, field) -> bool:
    """Whether ``error`` names the model file ``file`` (a path or its name) and ``field``."""
    return (error.file or "").endswith(str(file)) and error.field == field


def test_bad_models_name_the_file_and_field(tmp_path):
    root, _ = ring_scene(tmp_path / "a", True, np.arange(0, 360, 60))
    model = root / "sparse" / "0"
    data = (model / "images.bin").read_bytes()
    (model / "images.bin").write_bytes(data[:-5])
    assert _names(_error(root), "images.bin", None)   # the file ends inside a record
    (model / "images.bin").unlink()
    assert _names(_error(root), "sparse/0", "images")   # missing images.bin and .txt

    root, _ = ring_scene(tmp_path / "b", False, np.arange(0, 360, 60), model=("FULL_OPENCV", tuple(range(1, 13))))
    assert _names(_error(root), "cameras.txt", "camera 1")   # a model senerf does not undistort
    for line in ("1 PINHOLE 16 12 20 20 8\n", "1 PINHOLE 16 12 20 20 8 six\n", "1 SIMPLE_FISHEYE 16 12 20 8 6\n"):
        (root / "sparse" / "0" / "cameras.txt").write_text(line)
        assert _names(_error(root), "cameras.txt", "line 1"), line
    (root / "sparse" / "0" / "cameras.txt").write_text("2 PINHOLE 16 12 20 20 8 6\n")
    assert _names(_error(root), "images.txt", "image 10 (v_00.png)")   # its camera 1 is not in cameras.txt

    root, _ = ring_scene(tmp_path / "c", False, np.arange(0, 360, 60))
    (root / "images" / "v_03.png").unlink()
    assert _names(_error(root), "images.txt", "image 13 (v_03.png)")   # image not found
    iio.imwrite(root / "images" / "v_03.png", np.zeros((12, 15, 3), np.uint8))
    assert _names(_error(root), "images.txt", "image 13 (v_03.png)")   # not the others' size (nor its camera's)

    root, _ = ring_scene(tmp_path / "d", False, [0, 5, 10])
    text = (root / "sparse" / "0" / "images.txt").read_text().replace(" 1 v_01.png", " 2 v_01.png")
    (root / "sparse" / "0" / "images.txt").write_text(text)
    with open(root / "sparse" / "0" / "cameras.txt", "a") as fh:
        fh.write("2 PINHOLE 16 12 30 30 8 6\n")
    assert _names(_error(root), "cameras.txt", None)   # a forward-facing capture needs one camera (one NDC)


def test_newer_colmap_camera_models_in_a_binary_file_are_refused_by_camera(tmp_path):
    root, _ = ring_scene(tmp_path / "s", True, [0, 5, 10])
    path = root / "sparse" / "0" / "cameras.bin"
    data = bytearray(path.read_bytes())
    data[12:16] = struct.pack("<i", 14)   # a model id this reader does not know: its parameter count is unknown
    path.write_bytes(bytes(data))
    assert _names(_error(root), "cameras.bin", "camera 1")


def test_a_cameras_bin_cut_inside_a_fixed_size_record_is_refused(tmp_path):
    path = tmp_path / "cameras.bin"
    path.write_bytes(b"\0" * 7)
    with pytest.raises(InputError):
        read_cameras(path)
    path.write_bytes(struct.pack("<Q", 0))        # exactly 8 bytes: no camera
    assert read_cameras(path) == {}
    record = struct.pack("<QiiQQ", 1, 1, 1, 16, 12)
    path.write_bytes(record + struct.pack("<3d", 20.0, 21.0, 8.0))   # PINHOLE has 4 parameters: one missing
    with pytest.raises(InputError) as info:
        read_cameras(path)
    assert info.value.file == str(path)
    path.write_bytes(record + struct.pack("<4d", 20.0, 21.0, 8.0, 6.0))
    assert read_cameras(path)[1].params == (20.0, 21.0, 8.0, 6.0)


def test_model_files_that_cannot_be_read_are_one_error_naming_them(tmp_path):
    text = tmp_path / "cameras.txt"
    text.write_bytes(b"1 PINHOLE 16 12 20 21 8 6 \xff\n")   # not UTF-8
    folder = tmp_path / "cameras.bin"
    folder.mkdir()
    for path in (text, folder):
        with pytest.raises(InputError) as info:
            read_cameras(path)
        assert info.value.file == str(path)


def test_a_folder_without_a_model_or_without_a_registered_image_is_refused(tmp_path):
    from senerf.data import load_colmap

    with pytest.raises(InputError) as info:
        load_colmap(tmp_path)
    assert info.value.file == str(tmp_path)
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text("1 PINHOLE 16 12 20 21 8 6\n")
    (model / "images.txt").write_text("# Image list with two lines of data per image:\n")
    with pytest.raises(InputError) as info:
        load_colmap(tmp_path)
    assert info.value.file == str(model / "images.txt")
    (model / "images.bin").write_bytes(struct.pack("<Q", 0))   # .bin is preferred over .txt
    (model / "images.txt").unlink()
    with pytest.raises(InputError) as info:
        load_colmap(tmp_path)
    assert info.value.file == str(model / "images.bin")


@pytest.mark.parametrize("model, params, expected", [
    ("SIMPLE_RADIAL", (20, 8, 6, -0.1), ("opencv", (-0.1, 0, 0, 0, 0))),
    ("RADIAL", (20, 8, 6, -0.1, 0.02), ("opencv", (-0.1, 0.02, 0, 0, 0))),
    ("OPENCV", (20, 21, 8, 6, -0.1, 0.02, 0.003, -0.004), ("opencv", (-0.1, 0.02, 0.003, -0.004, 0))),
    ("OPENCV_FISHEYE", (20, 21, 8, 6, 0.01, -0.02, 0.003, -0.004), ("fisheye", (0.01, -0.02, 0.003, -0.004))),
    ("SIMPLE_RADIAL_FISHEYE", (20, 8, 6, 0.01), ("fisheye", (0.01, 0, 0, 0))),
    ("RADIAL_FISHEYE", (20, 8, 6, 0.01, -0.02), ("fisheye", (0.01, -0.02, 0, 0))),
])
def test_each_camera_model_maps_to_its_pinhole_and_distortion(model, params, expected):
    # COLMAP's parameter orders (src/colmap/sensor/models.h): f or fx, fy; cx, cy; then the model's coefficients
    from senerf.data.colmap import ColmapCamera

    k, d = ColmapCamera(model, 16, 12, tuple(map(float, params))).intrinsics_and_distortion()
    fy = params[1] if model in ("OPENCV", "OPENCV_FISHEYE") else params[0]
    assert k == Intrinsics(20.0, fy, 8.0, 6.0, 16, 12) and d == Distortion(*expected)


def test_depth_bounds_worked_out_by_hand(tmp_path):
    # camera 10 at the origin looking down +z sees points at depths 2 and 12, and (twice in one track) 7:
    # 0.1th percentile of [2, 7, 12] = 2 + 0.002 * 5 = 2.01, 99.9th = 12 - 0.002 * 5 = 11.99
    from senerf.data.colmap import _depth_bounds

    c2w = np.eye(4)[None]
    pts = (np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 7.0], [0.0, -1.0, 12.0], [0.0, 0.0, -3.0]]),
           (np.array([10, 10, 10, 10, 11, 10]), np.array([0, 1, 1, 2, 3, 3])))
    np.testing.assert_allclose(_depth_bounds(c2w, [10], pts, tmp_path), [[2.01, 11.99]], rtol=1e-12)


@pytest.mark.parametrize("azimuths, f, kind", [
    (np.arange(0, 360, 30), 20.0, "unbounded"),           # all around
    (np.arange(0, 41, 10), 20.0, "forward_facing"),    # optical axes within 20 degrees of their mean
    (np.arange(0, 91, 15), 20.0, "unbounded"),            # within 45 degrees: an arc around an object
    (np.arange(0, 21, 5), 3.0, "unbounded"),              # a wide lens: corner rays 83 degrees off the mean
])
def test_the_kind_follows_the_spread_of_cameras_and_rays(tmp_path, azimuths, f, kind):
    root, _ = ring_scene(tmp_path / "s", True, azimuths, model=("PINHOLE", (f, f, 8.0, 6.0)))
    assert load_scene(root).kind == kind


def test_the_kind_can_be_chosen(tmp_path, writers):
    root, _ = ring_scene(tmp_path / "s", True, [0, 5, 10, 15, 20])
    assert load_scene(root, kind="object").kind == "object"
    root, _ = ring_scene(tmp_path / "o", True, np.arange(0, 360, 30), elevation=5.0)  # axes 85 degrees off down
    assert _error(root, kind="forward_facing").field == "kind"   # rays beyond 90 degrees: NDC cannot hold them
    assert load_scene(root, kind="unbounded").kind == "unbounded"
    ngp = writers.ngp(tmp_path / "n")
    assert load_scene(ngp, kind="object").kind == "object"
    assert _error(ngp, kind="forward_facing").field == "kind"   # no depth bounds for NDC in a transforms.json


def test_images_txt_needs_its_points_lines_and_skips_blank_lines_as_colmap(tmp_path):
    root, _ = ring_scene(tmp_path / "s", False, np.arange(0, 360, 60))
    path = root / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], "", "  "] + lines[1:]) + "\n")   # blank lines before an image line
    assert load_scene(root).n_images == 6
    path.write_text("\n".join(line for line in lines if line and not line[0].isdigit() or " v_" in line) + "\n")
    assert _names(_error(root), "images.txt", "line 3")  # hand-written without points lines: the second image


def test_downscaled_image_folders_are_used_as_llff_does(tmp_path):
    # nerfstudio and LLFF write images_2/, images_4/ ... beside images/; the cameras stay at full size
    import cv2

    root, _ = ring_scene(tmp_path / "s", True, np.arange(0, 360, 60), model=("SIMPLE_RADIAL", (20.0, 8.0, 6.0, -0.05)))
    (root / "images_2").mkdir()
    for path in sorted((root / "images").iterdir()):
        small = cv2.resize(iio.imread(path), (8, 6), interpolation=cv2.INTER_AREA)
        iio.imwrite(root / "images_2" / path.name, small)
    k_full = Intrinsics(20.0, 20.0, 8.0, 6.0, 16, 12)
    d = Distortion("opencv", (-0.05, 0.0, 0.0, 0.0, 0.0))
    half = load_scene(root, downscale=2)
    assert {p.parent.name for p in half.image_paths} == {"images_2"} and half.size == (6, 8)
    assert half.intrinsics == undistorted_intrinsics(k_full.resized(8, 6), d)   # undistorted at images_2's size
    quarter = load_scene(root, downscale=4)   # the largest factor below 4: images_2, then area-resized
    assert {p.parent.name for p in quarter.image_paths} == {"images_2"} and quarter.size == (3, 4)
    assert quarter.intrinsics == undistorted_intrinsics(k_full.resized(8, 6), d).resized(4, 3)
    full = load_scene(root, downscale=1.5)    # below 2: images/
    assert {p.parent.name for p in full.image_paths} == {"images"} and full.size == (8, 11)
    for path in (root / "images_2").iterdir():   # more than one pixel off what the cameras give at /2
        iio.imwrite(path, np.zeros((4, 8, 3), np.uint8))
    assert _names(_error(root, downscale=2), "images.bin", "image 10 (v_00.png)")


def test_undistortion_failures_name_the_cameras_file_and_camera(tmp_path):
    root, _ = ring_scene(tmp_path / "d", False, np.arange(0, 360, 60),
                         model=("OPENCV", (20.0, 20.0, 30.0, 6.0, -0.1, 0.0, 0.0, 0.0)))   # cx outside the photo
    assert _names(_error(root), "cameras.txt", "camera 1")


def test_a_points3d_bin_cut_inside_a_track_is_refused(tmp_path):
    root, _ = ring_scene(tmp_path / "a", True, [0, 5, 10])
    model = root / "sparse" / "0"
    data = bytearray((model / "points3D.bin").read_bytes())
    data[8 + 43:8 + 51] = struct.pack("<Q", 2 ** 63)   # the first point's track length
    (model / "points3D.bin").write_bytes(bytes(data))
    assert _names(_error(root), "points3D.bin", None)
    (model / "points3D.bin").write_bytes(bytes(data[:8 + 51 + 4]))
    assert _names(_error(root), "points3D.bin", None)


def test_quaternions_are_normalised_as_colmap_does(tmp_path):
    root, poses = ring_scene(tmp_path / "s", False, np.arange(0, 360, 60))
    path = root / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    for factor in (0.4, 1.5, 2.5):
        scaled = []
        for line in lines:
            if " v_" in line:  # an image line: IMAGE_ID QW QX QY QZ ...
                f = line.split()
                f[1:5] = [repr(float(x) * factor) for x in f[1:5]]
                line = " ".join(f)
            scaled.append(line)
        path.write_text("\n".join(scaled) + "\n")
        np.testing.assert_allclose(load_scene(root).c2w, poses, atol=1e-12)


def test_a_binary_name_cut_short_is_refused_and_any_bytes_are_a_name(tmp_path):
    root, _ = ring_scene(tmp_path / "s", True, [0, 5, 10])
    path = root / "sparse" / "0" / "images.bin"
    data = path.read_bytes()
    path.write_bytes(data[:data.rindex(b".png")])  # the last record (image 10) ends in its name
    assert _names(_error(root), "images.bin", None)
    path.write_bytes(data.replace(b"v_00.png", b"v_\xff0.png"))   # not UTF-8: named as the file system names it
    assert [im.name for im in read_images(path)][-1] == os.fsdecode(b"v_\xff0.png")


@pytest.mark.parametrize("stem, text, field", [
    ("cameras", "1 PINHOLE 16\n", "line 1"),
    ("images", "1 1 0 0 0 0 0 0 1\n\n", "line 1"),
    ("images", "# c\n1 1 0 0 0 0 0 0 1 a.png\n1.5 2.5\n", "line 3"),
    ("images", "1 1 0 0 0 0 0 0 1 a.png\n1.5 2.5 x\n", "line 2"),
    ("points3D", "1 0 0 1 10 20 30 0.5 10 0 11\n", "line 1"),
    ("points3D", "1 0 0 1 10 20 30 0.5 10 0\n2 nan 0 1 10 20 30 0.5 10 0\n", "line 2"),
])
def test_malformed_text_lines_name_the_line(tmp_path, stem, text, field):
    path = tmp_path / f"{stem}.txt"
    path.write_text(text)
    reader = {"cameras": read_cameras, "images": read_images, "points3D": read_points3d}[stem]
    with pytest.raises(InputError) as info:
        reader(path)
    assert (info.value.file, info.value.field) == (str(path), field)


def test_image_names_with_spaces_are_kept_whole(tmp_path):
    path = tmp_path / "images.txt"
    path.write_text("1 1 0 0 0 0 0 0 1  my photo 01.png \n\n")
    (im,) = read_images(path)
    assert im.name == "my photo 01.png"


def _move_model(root, to) -> None:
    to.mkdir(parents=True, exist_ok=True)
    for p in list((root / "sparse" / "0").iterdir()):
        p.rename(to / p.name)


def test_the_model_folder_is_sparse_0_then_sparse_then_the_scene_folder(tmp_path):
    expected = Intrinsics(20.0, 21.0, 8.0, 6.0, 16, 12)
    root, _ = ring_scene(tmp_path / "a", False, np.arange(0, 360, 60))
    _move_model(root, root / "sparse")
    assert load_scene(root).intrinsics == expected
    root, _ = ring_scene(tmp_path / "b", False, np.arange(0, 360, 60))
    _move_model(root, root)
    assert load_scene(root).intrinsics == expected
    root, _ = ring_scene(tmp_path / "c", False, np.arange(0, 360, 60))
    for p in (root / "sparse" / "0").iterdir():  # another model beside the scene folder's images: not read
        shutil.copy(p, root / p.name)
    (root / "cameras.txt").write_text("1 PINHOLE 16 12 30 30 8 6\n")
    assert load_scene(root).intrinsics == expected


def test_binary_model_files_are_preferred_to_text(tmp_path):
    root, _ = ring_scene(tmp_path / "s", True, np.arange(0, 360, 60))
    (root / "sparse" / "0" / "cameras.txt").write_text("1 PINHOLE 16 12 30 30 8 6\n")
    assert load_scene(root).intrinsics == Intrinsics(20.0, 21.0, 8.0, 6.0, 16, 12)


def test_a_point_on_the_cameras_plane_is_not_in_front_of_it(tmp_path):
    from senerf.data.colmap import _depth_bounds

    c2w = np.eye(4)[None]
    pts = (np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 7.0], [0.0, -1.0, 12.0], [1.0, 1.0, 0.0]]),
           (np.array([10, 10, 10, 10]), np.array([0, 1, 2, 3])))
    np.testing.assert_allclose(_depth_bounds(c2w, [10], pts, tmp_path), [[2.01, 11.99]], rtol=1e-12)


@pytest.mark.parametrize("azimuths, f, kind", [
    (np.arange(0, 61, 15), 20.0, "forward_facing"),   # axes 28.1 degrees from their mean
    (np.arange(0, 71, 10), 20.0, "unbounded"),           # 32.7
    (np.arange(0, 21, 5), 3.5, "forward_facing"),     # axes 9.4, corner rays 78.5
])
def test_the_kind_thresholds_are_30_and_80_degrees(tmp_path, azimuths, f, kind):
    from senerf.data.colmap import view_spread

    root, poses = ring_scene(tmp_path / "s", True, azimuths, model=("PINHOLE", (f, f, 8.0, 6.0)))
    axis, ray, _ = view_spread(poses, [Intrinsics(f, f, 8.0, 6.0, 16, 12)] * len(poses))
    assert abs(axis - 30.0) > 1.5 and abs(ray - 80.0) > 1.0
    assert load_scene(root).kind == kind


def test_a_chosen_forward_facing_kind_takes_rays_up_to_90_degrees(tmp_path):
    root, _ = ring_scene(tmp_path / "a", True, np.arange(0, 41, 10), model=("PINHOLE", (3.0, 3.0, 8.0, 6.0)))
    assert load_scene(root).kind == "unbounded"  # corner rays 89.4 degrees off the mean
    assert load_scene(root, kind="forward_facing").kind == "forward_facing"
    root, _ = ring_scene(tmp_path / "b", True, np.arange(0, 56, 5), model=("PINHOLE", (4.0, 4.0, 8.0, 6.0)))
    error = _error(root, kind="forward_facing")
    assert error.field == "kind" and "91 degrees" in error.problem   # the widest ray, just beyond 90
    assert _error(root, kind="forward").field == "kind"


def test_images_must_have_their_cameras_size(tmp_path):
    root, _ = ring_scene(tmp_path / "s", False, np.arange(0, 360, 60))
    (root / "sparse" / "0" / "cameras.txt").write_text("1 PINHOLE 32 24 20 21 8 6\n")
    assert _names(_error(root), "images.txt", "image 10 (v_00.png)")


def test_forward_facing_normalisation_is_llffs_own(tmp_path):
    # one normalisation for both loaders: its bd_factor check applies to COLMAP folders too
    from senerf.data import load_colmap

    root, _ = ring_scene(tmp_path / "s", True, [0, 5, 10, 15, 20])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError) as info:
            load_colmap(root, bd_factor=bad)
        assert info.value.field == "bd_factor"
    raw, scaled = load_colmap(root, bd_factor=None, recenter=False), load_colmap(root, recenter=False)
    factor = 1.0 / (0.75 * raw.near)   # the smallest near becomes 1 / 0.75
    np.testing.assert_allclose(scaled.c2w[:, :3, 3], raw.c2w[:, :3, 3] * factor, rtol=1e-12)
    assert (scaled.near, scaled.far) == pytest.approx((raw.near * factor, raw.far * factor), rel=1e-12)


def test_sparse_points_are_the_model_s_points_in_colmap_s_frame(tmp_path):
    from senerf.data.colmap import sparse_points

    root, _ = ring_scene(tmp_path / "s", False, [0, 90, 180], far_points=2)
    xyz = sparse_points(root)
    assert xyz.shape == (42, 3)
    np.testing.assert_allclose(np.linalg.norm(xyz[40:], axis=1), 20.0, rtol=1e-12)   # as written, not normalised
    assert np.abs(xyz[:40]).max() <= 0.5
    (root / "sparse" / "0" / "points3D.txt").unlink()
    assert sparse_points(root) is None
    with pytest.raises(InputError) as info:   # no COLMAP model at all
        sparse_points(tmp_path)
    assert info.value.file == str(tmp_path)


def test_a_forward_facing_view_without_points_names_the_points_file_and_the_image(tmp_path):
    root, _ = ring_scene(tmp_path / "ff", True, [0, 5, 10])
    (root / "sparse" / "0" / "points3D.bin").write_bytes(struct.pack("<Q", 0))   # a model without points
    assert _names(_error(root), root / "sparse" / "0" / "points3D.bin", "image 10")
