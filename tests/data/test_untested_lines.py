"""Lines of senerf.data no other in-process test ran: rare refusals and branches, each checked for its exact
behaviour (the error naming its file and field, the accepted side of each boundary)."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
import pytest

from senerf.data import Distortion, Scene, fewshot_split, load_llff, load_ngp
from senerf.data import _io
from senerf.data.colmap import load_colmap, read_cameras
from senerf.data.undistort import Undistorter, photo_coverage, undistort_image
from senerf.errors import InputError
from senerf.geometry import Intrinsics


def _raises(call, match: str, file=None, field=None) -> InputError:
    """``call()`` raises an :class:`InputError` matching ``match`` whose ``file`` / ``field`` are the given ones."""
    with pytest.raises(InputError, match=match) as info:
        call()
    assert (info.value.file, info.value.field) == (None if file is None else str(file), field)
    assert "\n" not in str(info.value)
    return info.value


# -- _io.py ----------------------------------------------------------------------------------------------------------

def test_read_json_a_name_the_file_system_refuses_is_one_error(tmp_path):
    # Catches: read_json's OSError guard around path.is_file() deleted (a 300-character name raised a raw OSError).
    path = tmp_path / ("a" * 300 + ".json")
    _raises(lambda: _io.read_json(path), r"cannot read \(File name too long\)", file=path)
    (tmp_path / "ok.json").write_text('{"a": 1}')
    assert _io.read_json(tmp_path / "ok.json") == {"a": 1}   # an ordinary name is read


def test_as_pose_ragged_rows_are_refused_by_field(tmp_path):
    # Catches: as_pose's except (TypeError, ValueError) around np.asarray dropped (ragged rows gave numpy's error).
    ragged = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    _raises(lambda: _io.as_pose(ragged, tmp_path / "t.json", "frames[2].transform_matrix"),
            r"^.*frames\[2\]\.transform_matrix: expected a 4x4 matrix of numbers$", tmp_path / "t.json",
            "frames[2].transform_matrix")
    np.testing.assert_array_equal(_io.as_pose(np.eye(4).tolist(), tmp_path, "m"), np.eye(4))


def test_png_bit_depth_reads_the_header_and_none_for_what_it_cannot_open(tmp_path):
    # Catches: _png_bit_depth's "except OSError: return None" deleted or returning a depth (a file that cannot be
    # opened raised out of it); the header byte 24 and the 25-byte minimum checked on real files.
    assert _io._png_bit_depth(tmp_path / "missing.png") is None       # open() raises FileNotFoundError
    assert _io._png_bit_depth(tmp_path) is None                       # a folder: IsADirectoryError
    iio.imwrite(tmp_path / "a.png", np.zeros((2, 2, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((2, 2, 3), np.uint16))
    assert (_io._png_bit_depth(tmp_path / "a.png"), _io._png_bit_depth(tmp_path / "b.png")) == (8, 16)
    (tmp_path / "short.png").write_bytes((tmp_path / "b.png").read_bytes()[:24])
    assert _io._png_bit_depth(tmp_path / "short.png") is None         # 24 bytes: no byte 24


def test_premultiplied_rgba_is_read_straight(tmp_path, monkeypatch):
    # Catches: _read_pillow's RGBa -> RGBA conversion deleted (premultiplied colour read as straight colour).
    # No Pillow 13 plugin opens a file as "RGBa" (its TIFF reader un-premultiplies to RGBA itself), so the
    # image Pillow hands back is substituted here.
    from PIL import Image

    straight = Image.new("RGBA", (3, 2), (200, 100, 50, 128))
    premultiplied = straight.convert("RGBa")
    expected = np.asarray(premultiplied.convert("RGBA")) / 255.0     # Pillow's own un-premultiplication
    assert np.asarray(premultiplied)[0, 0, 0] < 110                   # stored premultiplied: about 200 * 128 / 255
    path = tmp_path / "p.png"
    straight.save(path)
    monkeypatch.setattr(Image, "open", lambda p: premultiplied)
    rgb, alpha = _io.read_image(path, "frames[0].file_path")
    np.testing.assert_allclose(rgb, expected[..., :3], atol=1e-7)
    np.testing.assert_allclose(alpha, 128 / 255.0, atol=1e-7)


def test_grey_with_associated_alpha_tiff_is_read_straight(tmp_path):
    # Catches: _read_pillow's La -> LA conversion deleted ("La" refused as an unread mode, or read premultiplied).
    tifffile = pytest.importorskip("tifffile")
    from PIL import Image

    grey = np.zeros((2, 3, 2), np.uint8)
    grey[..., 0], grey[..., 1] = 60, 128
    tifffile.imwrite(tmp_path / "la.tif", grey, photometric="minisblack", extrasamples=["assocalpha"])
    with Image.open(tmp_path / "la.tif") as im:
        assert im.mode == "La"
        expected = np.asarray(im.convert("LA")) / 255.0   # 60 * 255 / 128 = 119.5 -> 119
    rgb, alpha = _io.read_image(tmp_path / "la.tif", "f")
    np.testing.assert_allclose(rgb, np.repeat(expected[..., :1], 3, axis=2), atol=1e-7)
    np.testing.assert_allclose(rgb[0, 0, 0], 119 / 255.0, atol=1e-7)
    np.testing.assert_allclose(alpha, 128 / 255.0, atol=1e-7)


def test_a_16bit_png_opencv_cannot_decode_is_one_error_naming_the_field(tmp_path, monkeypatch):
    # Catches: _read_opencv's "img is None" check deleted (None went on to fail as a shape, or as an AttributeError).
    path = tmp_path / "d.png"
    cv2.imwrite(str(path), np.zeros((2, 2, 3), np.uint16))
    monkeypatch.setattr(_io.cv2, "imread", lambda *a: None)
    _raises(lambda: _io.read_image(path, "frames[1].file_path", tmp_path / "t.json"),
            r"cannot decode image .*d\.png \(ValueError: OpenCV could not decode it\)", tmp_path / "t.json",
            "frames[1].file_path")


@pytest.mark.parametrize("decoded, message", [
    (np.zeros((2, 2, 5), np.uint8), r"unsupported image shape \(2, 2, 5\)"),
    (np.zeros((2, 2, 2, 3), np.uint8), r"unsupported image shape \(2, 2, 2, 3\)"),   # a stack of frames
    (np.zeros((0, 2, 3), np.uint8), r"unsupported image shape \(0, 2, 3\)"),
    (np.zeros((2, 0, 3), np.uint8), r"unsupported image shape \(2, 0, 3\)"),
    (np.zeros((2, 2, 3), np.int32), "unsupported sample type int32"),
    (np.zeros((2, 2, 3), np.int16), "unsupported sample type int16"),
])
def test_decoded_arrays_senerf_cannot_take_are_refused(tmp_path, monkeypatch, decoded, message):
    # Catches: read_rgba's shape check (channels, empty sides) or sample-type check deleted; files whose suffix
    # Pillow does not handle go through imageio (line 278), whose result is substituted here.
    path = tmp_path / "v.pgm"
    path.write_bytes(b"P5")
    monkeypatch.setattr(_io.iio, "imread", lambda p: decoded)
    _raises(lambda: _io.read_image(path, "image 3", tmp_path), message, tmp_path, "image 3")


def test_a_one_frame_animation_is_read_as_its_frame(tmp_path, monkeypatch):
    # Catches: imageio's (1, H, W, C) for a one-frame GIF refused as "unsupported image shape (1, 4, 4, 3)" (so
    # before 2026-11-23).
    path = tmp_path / "v.gif"
    iio.imwrite(path, np.full((1, 4, 4, 3), 255, np.uint8))
    rgb, alpha = _io.read_image(path, "image 0", tmp_path)
    assert rgb.shape == (4, 4, 3) and np.allclose(rgb, 1.0) and alpha is None


def test_exr_and_unknown_formats_say_what_senerf_reads(tmp_path):
    # Catches: an .exr photo failing with imageio's "Could not find a backend" and a '.img' with "itk could not be
    # found" (so before 2026-11-23): the first is named as unreadable here, the second as not a format senerf reads.
    exr = tmp_path / "v.exr"
    exr.write_bytes(b"v/1\x01")
    _raises(lambda: _io.read_image(exr, "image 0", tmp_path), r"no installed decoder reads OpenEXR", tmp_path,
            "image 0")
    img = tmp_path / "v.img"
    img.write_bytes(b"junk")
    _raises(lambda: _io.read_image(img, "image 0", tmp_path),
            r"cannot decode image .*v\.img: \.img is not a format senerf reads \(\.png, \.jpg, \.jpeg, \.bmp, "
            r"\.tif, \.tiff, \.webp\)$", tmp_path, "image 0")


def test_decoded_arrays_at_the_edges_of_the_checks_are_accepted(tmp_path, monkeypatch):
    # Catches: the shape check tightened (1x1, 4 channels) or the float branch refused (kind "f" / "b" accepted).
    path = tmp_path / "v.pgm"
    path.write_bytes(b"P5")
    for decoded, rgb, alpha in [
        (np.full((1, 1, 4), 0.25, np.float64), [[[0.25] * 3]], [[0.25]]),
        (np.ones((1, 1, 1), bool), [[[1.0] * 3]], None),
        (np.full((1, 1, 2), 65535, np.uint16), [[[1.0] * 3]], [[1.0]]),
    ]:
        monkeypatch.setattr(_io.iio, "imread", lambda p: decoded)
        got_rgb, got_alpha = _io.read_image(path, "f")
        np.testing.assert_allclose(got_rgb, rgb, atol=1e-7)
        assert (got_alpha is None) if alpha is None else np.allclose(got_alpha, alpha)


def test_a_file_that_cannot_be_opened_while_decoding_names_the_os_reason(tmp_path, monkeypatch):
    # Catches: read_rgba's "OSError with an errno" branch deleted (a permission problem said "cannot decode",
    # as if the file were corrupt).
    from PIL import Image

    path = tmp_path / "a.png"
    iio.imwrite(path, np.zeros((2, 2, 3), np.uint8))

    def refused(p):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(Image, "open", refused)
    _raises(lambda: _io.read_image(path, "frames[0].file_path", tmp_path / "t.json"),
            r"cannot read image .*a\.png \(Permission denied\)$", tmp_path / "t.json", "frames[0].file_path")


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_float_images_holding_nan_or_inf_are_refused(tmp_path, bad):
    # Catches: read_rgba's isfinite check deleted (NaN was clipped into [0, 1] and trained on).
    from PIL import Image

    samples = np.full((2, 2), 0.5, np.float32)
    samples[1, 0] = bad
    Image.fromarray(samples, "F").save(tmp_path / "n.tif")
    _raises(lambda: _io.read_image(tmp_path / "n.tif", "frames[4].file_path", tmp_path / "t.json"),
            r"image .*n\.tif contains NaN or inf", tmp_path / "t.json", "frames[4].file_path")


def test_load_images_of_no_paths_is_a_programming_error():
    # Catches: load_images' empty-list check deleted (it returned None arrays for the callers to trip over).
    with pytest.raises(ValueError, match="load_images: no images given") as info:
        _io.load_images([], [], [])
    assert not isinstance(info.value, InputError)


# -- blender.py ------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("names", ["images/f_0.png", [1, 2], {"images/f_0.png": 1}])
def test_ngp_split_lists_that_are_not_lists_of_names_are_refused(tmp_path, writers, names):
    # Catches: load_ngp's "{split}_filenames must be a list of strings" check deleted or loosened.
    root = writers.ngp(tmp_path / "s", meta_extra={"test_filenames": names})
    _raises(lambda: load_ngp(root), "expected a list of file names", root / "transforms.json", "test_filenames")
    writers.ngp(tmp_path / "ok", meta_extra={"test_filenames": ["images/f_0.png"],
                                             "train_filenames": ["images/f_1.png", "images/f_2.png"]})
    scene = load_ngp(tmp_path / "ok")
    assert scene.splits["test"].tolist() == [0] and scene.splits["train"].tolist() == [1, 2]


# -- colmap.py -------------------------------------------------------------------------------------------------------

def test_a_cameras_bin_cut_inside_a_fixed_size_record_names_what_it_ends_in(tmp_path):
    # Catches: _Reader.take's length check deleted (struct.error escaped) or off by one.
    path = tmp_path / "cameras.bin"
    path.write_bytes(b"\0" * 7)
    _raises(lambda: read_cameras(path), "file ends inside the camera count", path)
    path.write_bytes(struct.pack("<Q", 0))        # exactly 8 bytes: no camera, nothing left over
    assert read_cameras(path) == {}
    record = struct.pack("<QiiQQ", 1, 1, 1, 16, 12)
    path.write_bytes(record + struct.pack("<3d", 20.0, 21.0, 8.0))   # PINHOLE has 4 parameters: one missing
    _raises(lambda: read_cameras(path), r"file ends inside camera 1 \(truncated or not a COLMAP model\)", path)
    path.write_bytes(record + struct.pack("<4d", 20.0, 21.0, 8.0, 6.0))
    assert read_cameras(path)[1].params == (20.0, 21.0, 8.0, 6.0)


def test_model_files_that_cannot_be_read_are_one_error_naming_them(tmp_path):
    # Catches: colmap._read's except (OSError, UnicodeDecodeError) deleted.
    text = tmp_path / "cameras.txt"
    text.write_bytes(b"1 PINHOLE 16 12 20 21 8 6 \xff\n")
    _raises(lambda: read_cameras(text), r"cannot read \('utf-8' codec can't decode byte 0xff", text)
    folder = tmp_path / "cameras.bin"
    folder.mkdir()
    _raises(lambda: read_cameras(folder), r"cannot read \(\[Errno 21\] Is a directory", folder)


def test_load_colmap_without_a_model_or_without_a_registered_image(tmp_path):
    # Catches: load_colmap's "no COLMAP model" (a None folder then crashed in a / b) or "no registered image"
    # check deleted (an empty model went on to fail as an empty stack).
    _raises(lambda: load_colmap(tmp_path), r"no COLMAP model \(sparse/0/cameras.bin or cameras.txt\)", tmp_path)
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text("1 PINHOLE 16 12 20 21 8 6\n")
    (model / "images.txt").write_text("# Image list with two lines of data per image:\n")
    _raises(lambda: load_colmap(tmp_path), "no registered image", model / "images.txt")
    (model / "images.bin").write_bytes(struct.pack("<Q", 0))   # .bin is preferred over .txt
    (model / "images.txt").unlink()
    _raises(lambda: load_colmap(tmp_path), "no registered image", model / "images.bin")


# -- fewshot.py ------------------------------------------------------------------------------------------------------

def _scene(n: int, splits: dict, kind: str = "forward_facing") -> Scene:
    k = Intrinsics(1.0, 1.0, 0.5, 0.5, 1, 1)
    return Scene(name="s", root=Path("s"), rgb=np.zeros((n, 1, 1, 3), np.float32), alpha=None, intrinsics=k,
                 intrinsics_all=(k,) * n, c2w=np.broadcast_to(np.eye(4), (n, 4, 4)).copy(), splits=splits,
                 kind=kind, image_paths=tuple(Path(f"{i}.png") for i in range(n)))


@pytest.mark.parametrize("n_views", [2.0, True, "2", np.float64(2.0)])
def test_a_number_of_views_that_is_not_an_integer_is_refused(n_views):
    # Catches: _n_views' integer check deleted (2.0 passed, True counted as 1, "2" failed in a comparison).
    scene = _scene(10, {"train": np.arange(10)})
    _raises(lambda: fewshot_split(scene, "llff", n_views=n_views), re.escape(f"expected an integer, got {n_views!r}"),
            field="--n-views")
    assert fewshot_split(scene, "llff", n_views=np.int64(2))[0].tolist() == [1, 9]   # rest 1..7, 9: ends


def test_protocol_all_refuses_an_empty_train_split():
    # Catches: the 'all' protocol's empty-train check deleted (an empty training set went on to the trainer).
    scene = _scene(3, {"test": [0, 1, 2]}, kind="object")
    _raises(lambda: fewshot_split(scene, "all"), "scene 's' has an empty train split", field="--protocol")
    train, test = fewshot_split(_scene(3, {"train": [2], "test": [0, 1]}, kind="object"), "all")
    assert (train.tolist(), test.tolist()) == ([2], [0, 1])


def test_llff_holdout_of_a_single_image_is_refused():
    # Catches: the llff protocol's "rest is empty" check deleted (_n_views then said --n-views must be in [1, 0]).
    _raises(lambda: fewshot_split(_scene(1, {}), "llff"), r"scene 's' has too few images \(1\) for the LLFF hold-out",
            field="--protocol")
    train, test = fewshot_split(_scene(2, {}), "llff", n_views=1)   # index 0 held out, index 1 trains
    assert (train.tolist(), test.tolist()) == ([1], [0])


def test_views_covering_every_image_leave_nothing_to_test():
    # Catches: the views protocol's empty-test check deleted (an empty test set was scored as NaN).
    scene = _scene(3, {"test": [0]})
    _raises(lambda: fewshot_split(scene, "views", views=[0, 1, 2]), "every image is a training view; nothing left",
            field="--views")
    assert fewshot_split(scene, "views", views=[0, 1])[1].tolist() == [2]   # split test view 0 trains: the rest
    assert fewshot_split(scene, "views", views=[1, 2])[1].tolist() == [0]


# -- llff.py ---------------------------------------------------------------------------------------------------------

def test_llff_poses_bounds_missing_unreadable_or_not_numeric(tmp_path, writers):
    # Catches: _read_poses_bounds' "file not found", np.load guard or numeric-dtype check deleted.
    file = tmp_path / "poses_bounds.npy"
    _raises(lambda: load_llff(tmp_path), "^[^:]*poses_bounds.npy: file not found$", file)
    file.write_bytes(b"\x93NUMPY\x01\x00garbage")
    _raises(lambda: load_llff(tmp_path), r"cannot read as a \.npy array \(", file)
    np.save(file, writers.llff_rows().astype(np.complex128))
    _raises(lambda: load_llff(tmp_path), "expected a numeric array, got dtype complex128", file, "shape")
    root = writers.llff(tmp_path / "ok", rows=writers.llff_rows().astype(np.float32))   # kind "f": read
    assert load_llff(root, downscale=2).n_images == 9


@pytest.mark.parametrize("column, row", [(4, 6), (9, 4)])   # hwf is column 4 of the 3x5 matrix: H at 4, W at 9
def test_llff_rows_of_different_image_sizes_name_the_first_odd_row(tmp_path, writers, column, row):
    # Catches: load_llff's one-size check deleted, or the row it names computed wrongly.
    rows = writers.llff_rows()
    rows[row, column] += 8.0
    rows[row + 1, column] += 8.0
    root = writers.llff(tmp_path / "s", rows=rows)
    _raises(lambda: load_llff(root), "all rows must share one image size", root / "poses_bounds.npy",
            f"row {row} hwf.H,W")


# -- scene.py --------------------------------------------------------------------------------------------------------

def test_scene_refuses_a_main_camera_of_another_size():
    # Catches: Scene's check of intrinsics.size against the images deleted (intrinsics_all alone was checked).
    k, wide = Intrinsics(1.0, 1.0, 0.5, 0.5, 1, 1), Intrinsics(1.0, 1.0, 1.0, 0.5, 2, 1)
    args = dict(name="s", root=Path("s"), rgb=np.zeros((1, 1, 1, 3), np.float32), alpha=None,
                intrinsics_all=(k,), c2w=np.eye(4)[None], image_paths=(Path("0.png"),))
    with pytest.raises(ValueError, match=r"^Scene\.intrinsics: size \(1, 2\) differs from images \(1, 1\)$"):
        Scene(intrinsics=wide, **args)
    assert Scene(intrinsics=k, **args).intrinsics == k


# -- undistort.py ----------------------------------------------------------------------------------------------------

def test_photo_coverage_refuses_a_pinhole_of_another_size():
    # Catches: photo_coverage's size check deleted (the shoelace area was divided by the other camera's).
    k = Intrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)
    d = Distortion("opencv", (0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"^photo_coverage: sizes differ, \(240, 320\) and \(480, 640\)$"):
        photo_coverage(k, d, Intrinsics(250.0, 250.0, 160.0, 120.0, 320, 240))
    assert photo_coverage(k, d, k) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 2), (4, 4, 5), (1, 4, 4, 3)])
def test_undistort_image_refuses_images_that_are_not_rgb_or_rgba(shape):
    # Catches: undistort_image's shape check deleted (grey+alpha was remapped and premultiplied by its grey).
    maps = (np.zeros((4, 4), np.float32), np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match=r"undistort_image: expected \(H, W, 3\) or \(H, W, 4\), got "
                                         + re.escape(str(shape))):
        undistort_image(np.zeros(shape, np.float32), maps)
    for c in (3, 4):   # sampled at pixel (0, 0): the value there, alpha 1 keeps colour straight
        img = np.full((4, 4, c), 0.5, np.float32)
        img[..., 3:] = 1.0
        np.testing.assert_allclose(undistort_image(img, maps), img, atol=1e-6)


def test_undistorter_keeps_the_maps_of_the_four_cameras_used_last(monkeypatch):
    # Catches: Undistorter._camera's eviction dropped (every camera's maps kept) or evicting the newest / ignoring
    # use (popitem(last=True), no move_to_end): the least recently used camera is the one recomputed.
    import senerf.data.undistort as und

    computed = []
    real = und.undistorted_intrinsics
    monkeypatch.setattr(und, "undistorted_intrinsics", lambda k, d: computed.append(d.coeffs[0]) or real(k, d))
    entries = [dict(distortion=Distortion("opencv", (-0.01 * (i + 1), 0.0, 0.0, 0.0, 0.0)), path=Path(f"{i}.png"),
                    file=Path("t.json"), distortion_field=f"frames[{i}].k1") for i in range(5)]
    undistort = Undistorter(entries, lambda e, h, w: Intrinsics(8.0, 8.0, w / 2, h / 2, w, h))
    img = np.full((8, 8, 3), 0.5, np.float32)
    for view in (0, 1, 2, 3, 0, 4, 0, 1):
        assert undistort(view, img).shape == (8, 8, 3)
    # 0-3 computed; 0 again is kept (and becomes the newest); 4 computed, evicting 1; 0 kept; 1 computed again
    assert computed == [-0.01, -0.02, -0.03, -0.04, -0.05, -0.02]
    assert len(undistort._maps) == und._MAPS_KEPT == 4
