"""Tests of senerf/data/_io.py: image decoding (unusual formats against Pillow, OpenCV and hand values), area
downscaling against block means, photo loading, and the JSON, path and pose checks naming file and field."""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
import pytest
from PIL import Image

from senerf.data import _io
from senerf.errors import InputError


def _raises(call, file, field) -> InputError:
    """``call()`` raises a one-line :class:`InputError` naming ``file`` and ``field``."""
    with pytest.raises(InputError) as info:
        call()
    assert (info.value.file, info.value.field) == (None if file is None else str(file), field)
    assert "\n" not in str(info.value)
    return info.value


def _entries(paths, file=None):
    return [dict(path=p, field=f"frames[{i}].file_path", file=file or p, distortion=None) for i, p in enumerate(paths)]


def _load(paths, file=None, **kw):
    """``load_photos`` of ``paths`` with each photo's own size as its camera (only images matter here)."""
    from senerf.geometry import Intrinsics

    return _io.load_photos(_entries(paths, file), lambda e, h, w: Intrinsics(w, w, w / 2, h / 2, w, h), **kw)


# --- decoding: every format read today, against independent values ------------------------------------------

def test_rgba_8bit_scaled_by_255(tmp_path):
    img = np.random.default_rng(0).integers(0, 256, (3, 5, 4), dtype=np.uint8)
    iio.imwrite(tmp_path / "a.png", img)
    out = _io.read_rgba(tmp_path / "a.png", "f")
    assert out.dtype == np.float32 and out.shape == (3, 5, 4)
    np.testing.assert_allclose(out, img / 255.0, atol=1e-7)


def test_grey_png_expands_to_three_equal_channels(tmp_path):
    img = np.random.default_rng(1).integers(0, 256, (4, 6), dtype=np.uint8)
    iio.imwrite(tmp_path / "g.png", img)
    out = _io.read_rgba(tmp_path / "g.png", "f")
    assert out.shape == (4, 6, 3)
    for c in range(3):
        np.testing.assert_allclose(out[..., c], img / 255.0, atol=1e-7)


def test_grey_alpha_png_keeps_alpha(tmp_path):
    img = np.random.default_rng(2).integers(0, 256, (4, 6, 2), dtype=np.uint8)
    iio.imwrite(tmp_path / "ga.png", img)
    out = _io.read_rgba(tmp_path / "ga.png", "f")
    np.testing.assert_allclose(out[..., 1], img[..., 0] / 255.0, atol=1e-7)
    np.testing.assert_allclose(out[..., 3], img[..., 1] / 255.0, atol=1e-7)


def test_16bit_grey_png_scaled_by_65535(tmp_path):
    # 65535 -> 1.0 and 32768 -> 32768/65535 (not /255, not truncated to 8 bits).
    img = np.array([[0, 1, 32768, 65535]], dtype=np.uint16)
    iio.imwrite(tmp_path / "g16.png", img)
    out = _io.read_rgba(tmp_path / "g16.png", "f")
    assert out.shape == (1, 4, 3)
    np.testing.assert_allclose(out[0, :, 0], img[0] / 65535.0, rtol=0, atol=1e-7)


def test_16bit_rgba_png_keeps_16_bits(tmp_path):
    # Pillow would truncate a 16-bit colour PNG to 8 bits; values 1 and 257 would then collide.
    img = np.random.default_rng(4).integers(0, 65536, (3, 4, 4), dtype=np.uint16)
    img[0, 0, :3] = (1, 257, 65535)
    cv2.imwrite(str(tmp_path / "c16.png"), img[..., [2, 1, 0, 3]])  # OpenCV stores BGRA order
    np.testing.assert_allclose(_io.read_rgba(tmp_path / "c16.png", "f"), img / 65535.0, atol=1e-7)


@pytest.mark.parametrize("suffix", [".tif", ".tiff"])
def test_16bit_colour_tiff_keeps_16_bits(tmp_path, suffix):
    # Pillow reads a 16-bit RGB TIFF as 8-bit RGB: values 1 and 257 would collide; a 16-bit grey TIFF too.
    img = np.random.default_rng(5).integers(0, 65536, (3, 4, 3), dtype=np.uint16)
    img[0, 0] = (1, 257, 65535)
    path = tmp_path / f"c16{suffix}"
    cv2.imwrite(str(path), img[..., ::-1])  # OpenCV stores BGR order
    np.testing.assert_allclose(_io.read_rgba(path, "f"), img / 65535.0, atol=1e-7)
    grey = np.array([[0, 1, 257, 65535]], dtype=np.uint16)
    cv2.imwrite(str(tmp_path / f"g16{suffix}"), grey)
    np.testing.assert_allclose(_io.read_rgba(tmp_path / f"g16{suffix}", "f")[..., 0], grey / 65535.0, atol=1e-7)


def test_big_endian_16bit_grey_tiff_is_read_as_pillow_sees_it(tmp_path):
    Image.frombytes("I;16B", (3, 2), (np.arange(6, dtype=">u2") * 10000).tobytes()).save(tmp_path / "b.tif")
    with Image.open(tmp_path / "b.tif") as im:   # the samples as Pillow's own pixel access gives them
        assert im.mode == "I;16B"
        samples = np.array([im.getpixel((x, y)) for y in range(2) for x in range(3)], np.float64)
    grey = _io.read_rgba(tmp_path / "b.tif", "f")
    assert samples.max() > 255 and np.allclose(grey[..., 0].ravel(), samples / 65535.0, atol=1e-6)


def test_cmyk_and_transparent_palette_images_are_read_as_rgb_and_rgba(tmp_path):
    # a CMYK JPEG's four channels must not pass for RGBA, and a palette PNG keeps its transparency; expected
    # values from Pillow's own conversions of the same files
    rgba = np.random.default_rng(3).integers(0, 256, (6, 8, 4), dtype=np.uint8)
    Image.fromarray(rgba[..., :3]).convert("CMYK").save(tmp_path / "c.jpg", quality=95)
    rgb = _io.read_rgba(tmp_path / "c.jpg", "f")
    with Image.open(tmp_path / "c.jpg") as im:
        assert im.mode == "CMYK"
        expected = np.asarray(im.convert("RGB")) / 255.0
    assert rgb.shape == (6, 8, 3) and np.allclose(rgb, expected, atol=1e-6)
    assert np.abs(rgb - rgba[..., :3] / 255.0).mean() < 0.1   # close to the colours saved, not their inverse
    # palette entry 0 transparent (left half), entries 1-3 opaque red, green, blue (right half)
    index = np.where(np.arange(8) < 4, 0, 1 + np.arange(8) % 3)[None].repeat(6, axis=0).astype(np.uint8)
    pal = Image.fromarray(index, "P")
    pal.putpalette([9, 9, 9, 255, 0, 0, 0, 255, 0, 0, 0, 255] + [0] * (256 * 3 - 12))
    pal.save(tmp_path / "p.png", transparency=0)
    out = _io.read_rgba(tmp_path / "p.png", "f")
    assert out.shape == (6, 8, 4) and out[:, :4, 3].max() == 0.0 and out[:, 4:, 3].min() == 1.0
    colours = np.eye(3)[np.arange(8)[4:] % 3]   # index 1 + k % 3 -> red, green, blue
    assert np.array_equal(out[:, 4:, :3], np.broadcast_to(colours, (6, 4, 3)))


def test_premultiplied_rgba_is_read_straight(tmp_path, monkeypatch):
    # No Pillow plugin opens a file as "RGBa" (its TIFF reader un-premultiplies itself), so the image Pillow
    # hands back is substituted here; the expected colour is Pillow's own un-premultiplication.
    straight = Image.new("RGBA", (3, 2), (200, 100, 50, 128))
    premultiplied = straight.convert("RGBa")
    expected = np.asarray(premultiplied.convert("RGBA")) / 255.0
    assert np.asarray(premultiplied)[0, 0, 0] < 110                   # stored premultiplied: about 200 * 128 / 255
    straight.save(tmp_path / "p.png")
    monkeypatch.setattr(Image, "open", lambda p: premultiplied)
    np.testing.assert_allclose(_io.read_rgba(tmp_path / "p.png", "f"), expected, atol=1e-7)


def test_grey_with_associated_alpha_tiff_is_read_straight(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    grey = np.zeros((2, 3, 2), np.uint8)
    grey[..., 0], grey[..., 1] = 60, 128
    tifffile.imwrite(tmp_path / "la.tif", grey, photometric="minisblack", extrasamples=["assocalpha"])
    with Image.open(tmp_path / "la.tif") as im:
        assert im.mode == "La"
    out = _io.read_rgba(tmp_path / "la.tif", "f")
    np.testing.assert_allclose(out[0, 0], (119 / 255.0,) * 3 + (128 / 255.0,), atol=1e-7)   # 60 * 255 / 128


def test_webp_and_bmp_are_read_as_stored(tmp_path):
    img = np.random.default_rng(6).integers(0, 256, (5, 7, 4), dtype=np.uint8)
    Image.fromarray(img).save(tmp_path / "a.webp", lossless=True)
    Image.fromarray(img[..., :3]).save(tmp_path / "b.bmp")
    np.testing.assert_allclose(_io.read_rgba(tmp_path / "a.webp", "f"), img / 255.0, atol=1e-7)
    np.testing.assert_allclose(_io.read_rgba(tmp_path / "b.bmp", "f"), img[..., :3] / 255.0, atol=1e-7)


def test_bilevel_and_float_images_are_read_as_their_values(tmp_path):
    bits = np.array([[0, 1, 1], [1, 0, 0]], bool)
    Image.fromarray(bits).save(tmp_path / "b.png")   # mode "1"
    Image.fromarray(np.full((2, 3), 0.25, np.float32), "F").save(tmp_path / "f.tif")
    np.testing.assert_array_equal(_io.read_rgba(tmp_path / "b.png", "f")[..., 0], bits)
    np.testing.assert_array_equal(_io.read_rgba(tmp_path / "f.tif", "f"), 0.25)


def test_float_images_outside_the_unit_range_are_clipped_and_said_once_per_scene(tmp_path):
    Image.fromarray(np.linspace(-0.5, 0.5, 16, dtype=np.float32).reshape(4, 4), "F").save(tmp_path / "n.tif")
    clipped = []
    out = _io.read_rgba(tmp_path / "n.tif", "frames[2].file_path", tmp_path / "t.json", clipped)
    assert out.min() == 0.0 and out.max() == 0.5 and len(clipped) == 1   # below 0 is clipped too
    Image.fromarray(np.full((4, 4), 1.0, np.float32), "F").save(tmp_path / "one.tif")
    assert _io.read_rgba(tmp_path / "one.tif", "f", clipped=clipped).max() == 1.0 and len(clipped) == 1   # in range
    paths = []
    for i in range(3):
        paths.append(tmp_path / f"{i}.tif")
        Image.fromarray(np.full((4, 4), 2.0 + i, np.float32), "F").save(paths[-1])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rgb, _, _ = _load(paths, tmp_path / "t.json")
    (line,) = [str(w.message) for w in caught]
    assert line.startswith(f"{tmp_path / 't.json'}: frames[0].file_path: ") and "2 more of the 3 photos" in line
    assert rgb.max() == 1.0


# --- refusals, each naming the file and field ---------------------------------------------------------------

@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_float_images_holding_nan_or_inf_are_refused(tmp_path, bad):
    samples = np.full((2, 2), 0.5, np.float32)
    samples[1, 0] = bad
    Image.fromarray(samples, "F").save(tmp_path / "n.tif")
    _raises(lambda: _io.read_rgba(tmp_path / "n.tif", "frames[4].file_path", tmp_path / "t.json"), tmp_path / "t.json",
            "frames[4].file_path")


def test_unread_formats_and_modes_are_one_error_naming_file_and_field(tmp_path):
    (tmp_path / "v.exr").write_bytes(b"v/1\x01")
    (tmp_path / "v.img").write_bytes(b"junk")
    Image.new("I", (4, 4), 7).save(tmp_path / "i.tif")   # 32-bit integer samples
    (tmp_path / "empty.png").write_bytes(b"")
    for name in ("v.exr", "v.img", "i.tif", "empty.png", "missing.png", "a" * 300 + ".png"):
        _raises(lambda: _io.read_rgba(tmp_path / name, "image 0", tmp_path / "t.json"), tmp_path / "t.json", "image 0")


@pytest.mark.parametrize("damage", ["flip", "cut"])
def test_a_corrupt_16bit_png_is_one_error_and_nothing_else_on_stderr(tmp_path, capfd, damage):
    # libpng inside OpenCV prints "libpng error: IDAT: CRC error" beside the one line unless Pillow checks first
    path = tmp_path / "d.png"
    cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 65535, (16, 16, 3), dtype=np.uint16))
    data = bytearray(path.read_bytes())
    at = data.index(b"IDAT") + 20
    if damage == "flip":
        data[at] ^= 0xFF
    else:
        del data[at:]
    path.write_bytes(bytes(data))
    capfd.readouterr()
    _raises(lambda: _io.read_rgba(path, "frames[0].file_path"), path, "frames[0].file_path")
    assert capfd.readouterr().err == ""


def test_a_file_that_cannot_be_opened_names_the_os_reason(tmp_path, monkeypatch):
    # a permission problem is said as such, not as a corrupt file
    iio.imwrite(tmp_path / "a.png", np.zeros((2, 2, 3), np.uint8))

    def refused(p):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(Image, "open", refused)
    error = _raises(lambda: _io.read_rgba(tmp_path / "a.png", "f", tmp_path / "t.json"), tmp_path / "t.json", "f")
    assert "Permission denied" in error.problem


def test_json_files_that_cannot_be_parsed_are_one_error_naming_the_file(tmp_path):
    (tmp_path / "deep.json").write_text('{"frames": ' + "[" * 200000 + "]" * 200000 + "}")
    (tmp_path / "big.json").write_text('{"camera_angle_x": ' + "9" * 5000 + "}")
    (tmp_path / "folder.json").mkdir()
    (tmp_path / "list.json").write_text("[1, 2]")
    for name in ("deep.json", "big.json", "folder.json", "list.json", "missing.json", "a" * 300 + ".json"):
        _raises(lambda: _io.read_json(tmp_path / name), tmp_path / name, None)
    (tmp_path / "ok.json").write_text('{"a": 1}')
    assert _io.read_json(tmp_path / "ok.json") == {"a": 1}


@pytest.mark.parametrize(
    "rel, ok",
    [("a/b.png", True), ("./a/../b.png", True), ("../b.png", False), ("a/../../b.png", False), ("/etc/passwd", False),
     ("C:\\x.png", False), ("\\x.png", False), ("", False), (".", False), ("train/..", False), (3, False)],
)
def test_resolve_inside_refuses_paths_leaving_the_scene_folder(rel, ok, tmp_path):
    if ok:
        p = _io.resolve_inside(tmp_path, rel, tmp_path / "t.json", "file_path")
        assert Path(p).parent.resolve().is_relative_to(tmp_path.resolve())
    else:
        _raises(lambda: _io.resolve_inside(tmp_path, rel, tmp_path / "t.json", "file_path"), tmp_path / "t.json",
                "file_path")


def test_as_pose_accepts_3x4_and_real_float32_noise(tmp_path):
    # A rotation printed in float32 (error ~1e-7, like the lego JSON) is accepted; 3x4 gets 0 0 0 1.
    theta = 0.3
    rot = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    m = np.concatenate([rot, [[1.0], [2.0], [3.0]]], axis=1).astype(np.float32).astype(np.float64)
    out = _io.as_pose(m.tolist(), tmp_path, "m")
    np.testing.assert_array_equal(out[3], (0, 0, 0, 1))
    np.testing.assert_array_equal(out[:3], m)


def test_as_pose_refuses_ragged_rows_by_field(tmp_path):
    ragged = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    _raises(lambda: _io.as_pose(ragged, tmp_path / "t.json", "frames[2].transform_matrix"), tmp_path / "t.json",
            "frames[2].transform_matrix")


# --- downscaling and loading ---------------------------------------------------------------------------------

def test_resize_transparent_pixels_get_zero_colour():
    # A block whose alpha is all 0 has no defined colour; the loader stores 0.
    img = np.zeros((2, 2, 4), np.float32)
    img[..., :3] = 0.7
    np.testing.assert_array_equal(_io.resize_area(img, (1, 1)), 0.0)


def test_resize_straight_colour_of_half_covered_block():
    # 2x2 block: one red pixel alpha 1, three pixels alpha 0 (colour garbage).  Premultiplied mean colour
    # is (0.25, 0, 0), mean alpha 0.25 -> straight colour exactly red (1, 0, 0), alpha 0.25.
    img = np.zeros((2, 2, 4), np.float32)
    img[..., 1] = 0.9
    img[0, 0] = (1.0, 0.0, 0.0, 1.0)
    np.testing.assert_allclose(_io.resize_area(img, (1, 1))[0, 0], (1.0, 0.0, 0.0, 0.25), atol=1e-6)


def test_resize_area_rgb_is_the_block_mean():
    # 8 x 12 -> 2 x 3 is the mean of 4 x 4 blocks (a bilinear filter would average only the middle 2 x 2).
    img = np.random.default_rng(7).random((8, 12, 3)).astype(np.float32)
    np.testing.assert_allclose(_io.resize_area(img.copy(), (2, 3)), img.reshape(2, 4, 3, 4, 3).mean(axis=(1, 3)),
                               atol=1e-6)


def test_target_size_rounds_half_up():
    # floor(side / d + 0.5), not Python's round() (half to even): 10 / 4 = 2.5 -> 3 (round() gives 2).
    assert _io.target_size(10, 6, 4) == (3, 2)
    assert _io.target_size(5, 7, 2) == (3, 4)
    assert _io.target_size(7, 10, 4) == (2, 3)
    assert _io.target_size(1, 1, 8) == (1, 1)   # never 0


def test_load_photos_mixed_alpha_makes_missing_alpha_opaque_with_a_warning(tmp_path):
    iio.imwrite(tmp_path / "a.png", np.full((2, 2, 4), 128, np.uint8))
    iio.imwrite(tmp_path / "b.png", np.full((2, 2, 3), 64, np.uint8))
    with pytest.warns(UserWarning, match=r"1 of 2 photos have no alpha channel \(frames\[1\]\.file_path: b\.png\)"):
        rgb, alpha, _ = _load([tmp_path / "a.png", tmp_path / "b.png"])
    np.testing.assert_allclose(alpha[0], 128 / 255.0, atol=1e-7)
    np.testing.assert_array_equal(alpha[1], 1.0)
    np.testing.assert_allclose(rgb[1], 64 / 255.0, atol=1e-7)
    assert _load([tmp_path / "b.png"])[1] is None   # no photo with alpha: alpha is None


def test_a_photo_is_checked_against_its_camera_before_the_arrays_are_allocated(tmp_path, monkeypatch):
    # a camera declaring a huge size must not make load_photos allocate (n, H, W, 3) before the check
    iio.imwrite(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))

    def photo_camera(e, height, width):
        raise InputError("image is 4x4 but its camera is 4611686018427387904x4", file=tmp_path, field="image 1")

    allocated = []
    real_empty = np.empty
    monkeypatch.setattr(_io.np, "empty", lambda *a, **kw: allocated.append(a) or real_empty(*a, **kw))
    with pytest.raises(InputError, match="but its camera is"):
        _io.load_photos(_entries([tmp_path / "a.png"]), photo_camera, size=(2 ** 62, 4))
    assert allocated == []
