"""Tests of senerf/data/_io.py: image decoding (accepted unusual formats), path checks, pose checks."""

from __future__ import annotations

from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
import pytest

from senerf.data import _io
from senerf.errors import InputError


def test_rgba_8bit_scaled_by_255(tmp_path):
    img = np.random.default_rng(0).integers(0, 256, (3, 5, 4), dtype=np.uint8)
    iio.imwrite(tmp_path / "a.png", img)
    rgb, alpha = _io.read_image(tmp_path / "a.png", "f")
    assert rgb.dtype == np.float32 and rgb.shape == (3, 5, 3) and alpha.shape == (3, 5)
    np.testing.assert_allclose(rgb, img[..., :3] / 255.0, atol=1e-7)
    np.testing.assert_allclose(alpha, img[..., 3] / 255.0, atol=1e-7)


def test_grey_png_expands_to_three_equal_channels(tmp_path):
    img = np.random.default_rng(1).integers(0, 256, (4, 6), dtype=np.uint8)
    iio.imwrite(tmp_path / "g.png", img)
    rgb, alpha = _io.read_image(tmp_path / "g.png", "f")
    assert alpha is None and rgb.shape == (4, 6, 3)
    for c in range(3):
        np.testing.assert_allclose(rgb[..., c], img / 255.0, atol=1e-7)


def test_grey_alpha_png_keeps_alpha(tmp_path):
    img = np.random.default_rng(2).integers(0, 256, (4, 6, 2), dtype=np.uint8)
    iio.imwrite(tmp_path / "ga.png", img)
    rgb, alpha = _io.read_image(tmp_path / "ga.png", "f")
    np.testing.assert_allclose(rgb[..., 1], img[..., 0] / 255.0, atol=1e-7)
    np.testing.assert_allclose(alpha, img[..., 1] / 255.0, atol=1e-7)


def test_16bit_grey_png_scaled_by_65535(tmp_path):
    # 65535 -> 1.0 and 32768 -> 32768/65535 (not /255, not truncated to 8 bits).
    img = np.array([[0, 1, 32768, 65535]], dtype=np.uint16)
    iio.imwrite(tmp_path / "g16.png", img)
    rgb, alpha = _io.read_image(tmp_path / "g16.png", "f")
    assert alpha is None
    np.testing.assert_allclose(rgb[0, :, 0], img[0] / 65535.0, rtol=0, atol=1e-7)


def test_16bit_rgba_png_keeps_16_bits(tmp_path):
    # Pillow would truncate a 16-bit colour PNG to 8 bits; values 1 and 257 would then collide.
    img = np.random.default_rng(4).integers(0, 65536, (3, 4, 4), dtype=np.uint16)
    img[0, 0, :3] = (1, 257, 65535)
    cv2.imwrite(str(tmp_path / "c16.png"), img[..., [2, 1, 0, 3]])  # OpenCV stores BGRA order
    rgb, alpha = _io.read_image(tmp_path / "c16.png", "f")
    np.testing.assert_allclose(rgb, img[..., :3] / 65535.0, atol=1e-7)
    np.testing.assert_allclose(alpha, img[..., 3] / 65535.0, atol=1e-7)


@pytest.mark.parametrize("suffix", [".tif", ".tiff"])
def test_16bit_colour_tiff_keeps_16_bits(tmp_path, suffix):
    # Pillow reads a 16-bit RGB TIFF as 8-bit RGB: values 1 and 257 collided and every sample was off by up to
    # 1/255 (so until this test); a 16-bit grey TIFF Pillow reads as it is.
    img = np.random.default_rng(5).integers(0, 65536, (3, 4, 3), dtype=np.uint16)
    img[0, 0] = (1, 257, 65535)
    path = tmp_path / f"c16{suffix}"
    cv2.imwrite(str(path), img[..., ::-1])  # OpenCV stores BGR order
    rgb, alpha = _io.read_image(path, "f")
    assert alpha is None
    np.testing.assert_allclose(rgb, img / 65535.0, atol=1e-7)
    grey = np.array([[0, 1, 257, 65535]], dtype=np.uint16)
    cv2.imwrite(str(tmp_path / f"g16{suffix}"), grey)
    np.testing.assert_allclose(_io.read_image(tmp_path / f"g16{suffix}", "f")[0][..., 0], grey / 65535.0, atol=1e-7)


def test_rgb_png_has_no_alpha(tmp_path):
    iio.imwrite(tmp_path / "c.png", np.zeros((2, 2, 3), np.uint8))
    assert _io.read_image(tmp_path / "c.png", "f")[1] is None


def test_load_images_mixed_alpha_makes_missing_alpha_opaque(tmp_path):
    iio.imwrite(tmp_path / "a.png", np.full((2, 2, 4), 128, np.uint8))
    iio.imwrite(tmp_path / "b.png", np.full((2, 2, 3), 64, np.uint8))
    paths = [tmp_path / "a.png", tmp_path / "b.png"]
    # said, since its background is then trained as part of the object (before, silently; so at 9ca9fe6)
    with pytest.warns(UserWarning, match=r"1 of 2 photos have no alpha channel \(frames\[1\]: b\.png\); they are "
                                         r"taken as fully opaque"):
        rgb, alpha, size = _io.load_images(paths, ["frames[0]", "frames[1]"], paths, 1.0)
    assert size == (2, 2)
    np.testing.assert_allclose(alpha[0], 128 / 255.0, atol=1e-7)
    np.testing.assert_array_equal(alpha[1], 1.0)
    np.testing.assert_allclose(rgb[1], 64 / 255.0, atol=1e-7)


def test_load_images_all_rgb_gives_alpha_none(tmp_path):
    iio.imwrite(tmp_path / "b.png", np.full((2, 2, 3), 64, np.uint8))
    assert _io.load_images([tmp_path / "b.png"], ["b"], [tmp_path], 1.0)[1] is None


def test_resize_transparent_pixels_get_zero_colour():
    # A block whose alpha is all 0 has no defined colour; the loader stores 0.
    img = np.zeros((2, 2, 4), np.float32)
    img[..., :3] = 0.7
    out = _io.resize_area(img, (1, 1))
    np.testing.assert_array_equal(out, 0.0)


def test_resize_straight_colour_of_half_covered_block():
    # 2x2 block: one red pixel alpha 1, three pixels alpha 0 (colour garbage).  Premultiplied mean colour
    # is (0.25, 0, 0), mean alpha 0.25 -> straight colour exactly red (1, 0, 0), alpha 0.25.
    img = np.zeros((2, 2, 4), np.float32)
    img[..., 1] = 0.9
    img[0, 0] = (1.0, 0.0, 0.0, 1.0)
    out = _io.resize_area(img, (1, 1))
    np.testing.assert_allclose(out[0, 0], (1.0, 0.0, 0.0, 0.25), atol=1e-6)


@pytest.mark.parametrize(
    "rel, ok",
    [("a/b.png", True), ("./a/../b.png", True), ("../b.png", False), ("a/../../b.png", False),
     ("/etc/passwd", False), ("C:\\x.png", False), ("", False)],
)
def test_resolve_inside(rel, ok, tmp_path):
    if ok:
        p = _io.resolve_inside(tmp_path, rel, tmp_path / "t.json", "file_path")
        assert Path(p).parent.resolve().is_relative_to(tmp_path.resolve())
    else:
        with pytest.raises(InputError) as info:
            _io.resolve_inside(tmp_path, rel, tmp_path / "t.json", "file_path")
        assert info.value.field == "file_path"


def test_as_pose_accepts_3x4_and_real_float32_noise(tmp_path):
    # A rotation printed in float32 (error ~1e-7, like the lego JSON) is accepted; 3x4 gets 0 0 0 1.
    theta = 0.3
    rot = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    m = np.concatenate([rot, [[1.0], [2.0], [3.0]]], axis=1).astype(np.float32).astype(np.float64)
    out = _io.as_pose(m.tolist(), tmp_path, "m")
    np.testing.assert_array_equal(out[3], (0, 0, 0, 1))
    np.testing.assert_array_equal(out[:3], m)


def test_cmyk_and_transparent_palette_images_are_read_as_rgb_and_rgba(tmp_path):
    # a CMYK JPEG's four channels passed for RGBA (K as alpha, colours inverted) and a palette PNG lost its
    # transparency (so at 2e4108c); expected values from Pillow's own conversions of the same files
    from PIL import Image

    rgba = np.random.default_rng(3).integers(0, 256, (6, 8, 4), dtype=np.uint8)
    rgba[..., 3] = np.where(np.arange(8) < 4, 0, 255)[None, :]
    Image.fromarray(rgba[..., :3]).convert("CMYK").save(tmp_path / "c.jpg", quality=95)
    rgb, alpha = _io.read_image(tmp_path / "c.jpg", "f")
    with Image.open(tmp_path / "c.jpg") as im:
        assert im.mode == "CMYK"
        expected = np.asarray(im.convert("RGB")) / 255.0
    assert alpha is None and np.allclose(rgb, expected, atol=1e-6)
    assert np.abs(rgb - rgba[..., :3] / 255.0).mean() < 0.1   # close to the colours saved, not their inverse
    # palette entry 0 transparent (left half), entries 1-3 opaque red, green, blue (right half)
    index = np.where(np.arange(8) < 4, 0, 1 + np.arange(8) % 3)[None].repeat(6, axis=0).astype(np.uint8)
    pal = Image.fromarray(index, "P")
    pal.putpalette([9, 9, 9, 255, 0, 0, 0, 255, 0, 0, 0, 255] + [0] * (256 * 3 - 12))
    pal.save(tmp_path / "p.png", transparency=0)
    with Image.open(tmp_path / "p.png") as im:
        assert im.mode == "P" and "transparency" in im.info
    rgb, alpha = _io.read_image(tmp_path / "p.png", "f")
    assert alpha is not None and alpha[:, :4].max() == 0.0 and alpha[:, 4:].min() == 1.0
    colours = np.eye(3)[np.arange(8)[4:] % 3]   # index 1 + k % 3 -> red, green, blue
    assert np.array_equal(rgb[:, 4:], np.broadcast_to(colours, (6, 4, 3)))


def test_float_images_outside_the_unit_range_are_clipped_with_a_warning_and_unread_modes_refused(tmp_path):
    # float samples were taken as they are (a 0-255 float TIFF trained as values up to 253; so at 2e4108c)
    import warnings

    from PIL import Image

    Image.fromarray(np.full((4, 4), 200.0, np.float32), "F").save(tmp_path / "f.tif")
    with pytest.warns(UserWarning, match=r"frames\[1\].file_path: image .*f.tif holds float samples in \[200, 200\]; "
                                         r"clipped to \[0, 1\]"):
        rgb, _ = _io.read_image(tmp_path / "f.tif", "frames[1].file_path", tmp_path / "t.json")
    assert rgb.max() == 1.0
    Image.fromarray(np.linspace(-0.5, 0.5, 16, dtype=np.float32).reshape(4, 4), "F").save(tmp_path / "n.tif")
    with pytest.warns(UserWarning, match=r"n.tif holds float samples in \[-0.5, 0.5\]; clipped to \[0, 1\]"):
        rgb, _ = _io.read_image(tmp_path / "n.tif", "frames[2].file_path", tmp_path / "t.json")
    assert rgb.min() == 0.0 and rgb.max() == 0.5                  # below 0 is clipped too (a mutation survived)
    Image.fromarray(np.full((4, 4), 1.0, np.float32), "F").save(tmp_path / "one.tif")
    with warnings.catch_warnings():                               # exactly 1.0 is inside [0, 1]: no warning
        warnings.simplefilter("error")
        assert _io.read_image(tmp_path / "one.tif", "frames[3].file_path")[0].max() == 1.0
    # big-endian 16-bit grey (Pillow's I;16B) was refused as "unsupported sample type >u2" (a review)
    Image.frombytes("I;16B", (3, 2), (np.arange(6, dtype=">u2") * 10000).tobytes()).save(tmp_path / "b.tif")
    with Image.open(tmp_path / "b.tif") as im:   # the samples as Pillow's own pixel access gives them
        assert im.mode == "I;16B"
        samples = np.array([im.getpixel((x, y)) for y in range(2) for x in range(3)], np.float64)
    grey, _ = _io.read_image(tmp_path / "b.tif", "f")
    assert samples.max() > 255 and np.allclose(grey[..., 0].ravel(), samples / 65535.0, atol=1e-6)
    Image.fromarray(np.full((4, 4), 0.5, np.float32), "F").save(tmp_path / "h.tif")
    assert np.allclose(_io.read_image(tmp_path / "h.tif", "f")[0], 0.5)   # in range: read as it is
    Image.new("I", (4, 4), 7).save(tmp_path / "i.tif")
    with pytest.raises(InputError, match="Pillow mode 'I', which senerf does not read"):
        _io.read_image(tmp_path / "i.tif", "f")


def test_a_path_naming_the_scene_folder_itself_is_refused(tmp_path):
    # "." and "train/.." normalise to the folder; a loader adding ".png" then read the sibling <folder>.png
    for rel in (".", "train/..", "./"):
        with pytest.raises(InputError, match="names the folder itself"):
            _io.resolve_inside(tmp_path, rel, tmp_path / "t.json", "frames[1].file_path")
    with pytest.raises(InputError, match=r"path 'a\\x00b.png' contains a NUL character") as info:
        _io.resolve_inside(tmp_path, "a\x00b.png", tmp_path / "t.json", "frames[1].file_path")
    assert "\x00" not in str(info.value)


def test_unreadable_names_and_json_beyond_the_parsers_limits_are_one_line_errors(tmp_path):
    with pytest.raises(InputError, match="cannot read image .*File name too long") as info:
        _io.read_image(tmp_path / ("a" * 300 + ".png"), "frames[0].file_path", tmp_path / "t.json")
    assert info.value.field == "frames[0].file_path"
    (tmp_path / "deep.json").write_text('{"frames": ' + "[" * 200000 + "]" * 200000 + "}")
    with pytest.raises(InputError, match="nested too deeply"):
        _io.read_json(tmp_path / "deep.json")
    (tmp_path / "big.json").write_text('{"camera_angle_x": ' + "9" * 5000 + "}")
    with pytest.raises(InputError, match="malformed JSON .*digits"):
        _io.read_json(tmp_path / "big.json")
    (tmp_path / "folder.json").mkdir()
    with pytest.raises(InputError, match="is not a file"):
        _io.read_json(tmp_path / "folder.json")


def test_a_photo_is_checked_against_its_camera_before_the_arrays_are_allocated(tmp_path, monkeypatch):
    # a camera declaring a huge size made load_images allocate (n, H, W, 3) before the check (so at 2e4108c)
    iio.imwrite(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))

    def prepare(k, img):
        raise InputError("image is 4x4 but its camera is 4611686018427387904x4", file=tmp_path, field="image 1")

    allocated = []
    real_empty = np.empty
    monkeypatch.setattr(_io.np, "empty", lambda *a, **kw: allocated.append(a) or real_empty(*a, **kw))
    with pytest.raises(InputError, match="but its camera is"):
        _io.load_images([tmp_path / "a.png"], ["image 1"], [tmp_path], size=(2 ** 62, 4), prepare=prepare)
    assert allocated == []


@pytest.mark.parametrize("damage", ["flip", "cut"])
def test_a_corrupt_16bit_png_is_one_error_and_nothing_else_on_stderr(tmp_path, capfd, damage):
    # OpenCV's libpng printed "libpng error: IDAT: CRC error" / "Read Error" beside our one line (so at c5dcf82)
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
    with pytest.raises(InputError, match="cannot decode image"):
        _io.read_image(path, "frames[0].file_path")
    assert capfd.readouterr().err == ""


def test_a_scene_of_float_photos_outside_the_unit_range_warns_once(tmp_path):
    # each photo warned on its own: a hundred lines for a hundred HDR photos (so at 287b5e3)
    import warnings

    from PIL import Image

    paths = []
    for i in range(3):
        paths.append(tmp_path / f"{i}.tif")
        Image.fromarray(np.full((4, 4), 2.0 + i, np.float32), "F").save(paths[-1])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rgb, _, _ = _io.load_images(paths, [f"frames[{i}].file_path" for i in range(3)], [tmp_path / "t.json"] * 3)
    lines = [str(w.message) for w in caught]
    assert len(lines) == 1 and "frames[0].file_path: image" in lines[0] and "[2, 2] (and 2 more of the 3 photos)" \
        in lines[0] and lines[0].endswith("clipped to [0, 1]")
    assert rgb.max() == 1.0
