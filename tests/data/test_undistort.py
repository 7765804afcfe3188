"""Lens undistortion (senerf.data.undistort), against models typed here from their definitions.

The golden values do not come from OpenCV (which the module calls): the Brown-Conrady and Kannala-Brandt
formulas are written out below, their inverses solved by this file's own iterations, and the photos
rendered from an analytic texture, so a resampled image can be compared with the texture itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from senerf.data import Distortion, distort_pixels, undistort_image, undistorted_intrinsics, undistortion_maps
from senerf.data.undistort import COVERAGE_WARN, DistortionError, photo_coverage
from senerf.geometry import Intrinsics

K_PHOTO = Intrinsics(160.0, 150.0, 100.3, 79.6, 200, 160)

CASES = {
    "barrel": Distortion("opencv", (-0.25, 0.06, 0.0, 0.0, 0.0)),
    "pincushion": Distortion("opencv", (0.12, 0.01, 0.0, 0.0, 0.0)),
    "tangential": Distortion("opencv", (-0.1, 0.02, 0.003, -0.004, -0.005)),
    "fisheye": Distortion("fisheye", (0.04, -0.01, 0.002, -0.0005)),
    "fisheye-equidistant": Distortion("fisheye", (0.0, 0.0, 0.0, 0.0)),
}


def brown_conrady(x, y, c):
    """OpenCV's radial-tangential model, coefficients ``(k1, k2, p1, p2, k3)``, on normalised coordinates."""
    k1, k2, p1, p2, k3 = c
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def kannala_brandt(x, y, c):
    """OpenCV's fisheye (equidistant) model, coefficients ``(k1, k2, k3, k4)``."""
    r = np.hypot(x, y)
    theta = np.arctan(r)
    theta_d = theta * (1.0 + c[0] * theta ** 2 + c[1] * theta ** 4 + c[2] * theta ** 6 + c[3] * theta ** 8)
    ratio = np.where(r > 1e-12, theta_d / np.maximum(r, 1e-300), 1.0)
    return x * ratio, y * ratio


def distort(x, y, d: Distortion):
    return (kannala_brandt if d.model == "fisheye" else brown_conrady)(x, y, d.coeffs)


def undistort_normalised(xd, yd, d: Distortion):
    """Invert :func:`distort` by Newton's method with a numerical Jacobian (this file's own solver)."""
    x, y = xd.copy(), yd.copy()
    h = 1e-7
    for _ in range(50):
        fx, fy = distort(x, y, d)
        rx, ry = fx - xd, fy - yd
        ax, ay = distort(x + h, y, d)
        bx, by = distort(x, y + h, d)
        j11, j21, j12, j22 = (ax - fx) / h, (ay - fy) / h, (bx - fx) / h, (by - fy) / h
        det = j11 * j22 - j12 * j21
        x, y = x - (j22 * rx - j12 * ry) / det, y - (-j21 * rx + j11 * ry) / det
    fx, fy = distort(x, y, d)
    assert max(np.abs(fx - xd).max(), np.abs(fy - yd).max()) < 1e-12
    return x, y


def texture(x, y):
    """A smooth colour image over normalised coordinates, ``(..., 3)``."""
    return np.stack([0.5 + 0.4 * np.sin(2.0 * x + 0.3) * np.cos(1.5 * y),
                     0.5 + 0.3 * np.cos(1.7 * x - 2.1 * y),
                     0.4 + 0.3 * x * y], axis=-1)


def pixel_grid(k: Intrinsics):
    return np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)


def render_photo(k_photo: Intrinsics, d: Distortion) -> np.ndarray:
    """The texture as a camera with lens ``d`` sees it (each pixel centre's undistorted ray, sampled)."""
    u, v = pixel_grid(k_photo)
    x, y = undistort_normalised((u - k_photo.cx) / k_photo.fx, (v - k_photo.cy) / k_photo.fy, d)
    return texture(x, y).astype(np.float32)


def test_distort_pixels_golden_by_hand():
    k = Intrinsics(100.0, 100.0, 50.0, 50.0, 100, 100)
    # k1 = -0.2 at normalised (0.5, 0): r^2 = 0.25, factor 1 - 0.05 = 0.95, x_d = 0.475 -> u = 50 + 47.5
    out = distort_pixels(np.array([[100.0, 50.0]]), k, k, Distortion("opencv", (-0.2, 0.0, 0.0, 0.0, 0.0)))
    np.testing.assert_allclose(out, [[97.5, 50.0]], atol=1e-9)
    # p2 = 0.01 at normalised (0, 0.5): x_d = p2 (r^2 + 0) = 0.0025, y_d = 0.5 + 0 -> (50.25, 100)
    out = distort_pixels(np.array([[50.0, 100.0]]), k, k, Distortion("opencv", (0.0, 0.0, 0.0, 0.01, 0.0)))
    np.testing.assert_allclose(out, [[50.25, 100.0]], atol=1e-9)
    # equidistant fisheye at normalised (1, 0): theta = pi/4, x_d = pi/4 -> u = 50 + 25 pi
    out = distort_pixels(np.array([[150.0, 50.0]]), k, k, Distortion("fisheye", (0.0, 0.0, 0.0, 0.0)))
    np.testing.assert_allclose(out, [[50.0 + 25.0 * math.pi, 50.0]], atol=1e-9)


@pytest.mark.parametrize("name", sorted(CASES))
def test_distort_pixels_matches_the_model_typed_here(name):
    d = CASES[name]
    k_pin = Intrinsics(120.0, 110.0, 90.0, 85.0, 200, 160)
    uv = np.random.default_rng(0).uniform([0, 0], [200, 160], size=(4, 50, 2))
    xd, yd = distort((uv[..., 0] - 90.0) / 120.0, (uv[..., 1] - 85.0) / 110.0, d)
    expected = np.stack([K_PHOTO.fx * xd + K_PHOTO.cx, K_PHOTO.fy * yd + K_PHOTO.cy], -1)
    np.testing.assert_allclose(distort_pixels(uv, k_pin, K_PHOTO, d), expected, atol=1e-8)


@pytest.mark.parametrize("name", sorted(CASES))
def test_pinhole_is_the_widest_view_inside_the_photo(name):
    d = CASES[name]
    k = undistorted_intrinsics(K_PHOTO, d)
    assert (k.cx, k.cy, k.size) == (K_PHOTO.cx, K_PHOTO.cy, K_PHOTO.size)
    assert k.fx / k.fy == pytest.approx(K_PHOTO.fx / K_PHOTO.fy, rel=1e-12)

    def landed(kk):
        u, v = pixel_grid(kk)
        xd, yd = distort((u - kk.cx) / kk.fx, (v - kk.cy) / kk.fy, d)
        return K_PHOTO.fx * xd + K_PHOTO.cx, K_PHOTO.fy * yd + K_PHOTO.cy

    def on_centres(pu, pv, tol):
        return pu.min() >= 0.5 - tol and pv.min() >= 0.5 - tol and pu.max() <= 199.5 + tol and pv.max() <= 159.5 + tol

    pu, pv = landed(k)
    assert on_centres(pu, pv, 1e-6)
    assert not on_centres(*landed(_scaled(k, 0.999)), 0.0)  # any wider view leaves the photo somewhere


def _scaled(k: Intrinsics, s: float) -> Intrinsics:
    return Intrinsics(k.fx * s, k.fy * s, k.cx, k.cy, k.width, k.height)


def test_identity_distortion_keeps_the_camera():
    assert undistorted_intrinsics(K_PHOTO, Distortion("opencv", (0, 0, 0, 0, 0))) is K_PHOTO
    assert undistorted_intrinsics(K_PHOTO, Distortion("fisheye", (0, 0, 0, 0))) != K_PHOTO  # equidistant


@pytest.mark.parametrize("name", sorted(CASES))
def test_undistorted_photo_is_the_pinhole_view_of_the_texture(name):
    d = CASES[name]
    k_pin = undistorted_intrinsics(K_PHOTO, d)
    out = undistort_image(render_photo(K_PHOTO, d), undistortion_maps(K_PHOTO, d, k_pin))
    u, v = pixel_grid(k_pin)
    expected = texture((u - k_pin.cx) / k_pin.fx, (v - k_pin.cy) / k_pin.fy)
    err = np.abs(out - expected)
    assert out.dtype == np.float32 and out.shape == (160, 200, 3)
    assert err[2:-2, 2:-2].max() < 2e-4  # bilinear interpolation of a smooth texture
    assert err.max() < 3e-3  # the edge pixels repeat within half a pixel: no black border anywhere
    # without undistortion the photo is measurably not that view
    assert np.abs(render_photo(K_PHOTO, d) - expected).max() > max(0.01, 20 * err[2:-2, 2:-2].max())


def test_rgba_is_resampled_premultiplied():
    # a black opaque disc; outside it, transparent pixels holding white: the white must not bleed in
    d = CASES["barrel"]
    u, v = pixel_grid(K_PHOTO)
    disc = (u - 100.0) ** 2 + (v - 80.0) ** 2 < 50.0 ** 2
    photo = np.zeros((160, 200, 4), np.float32)
    photo[~disc, :3] = 1.0
    photo[disc, 3] = 1.0
    out = undistort_image(photo, undistortion_maps(K_PHOTO, d, undistorted_intrinsics(K_PHOTO, d)))
    partly = (out[..., 3] > 0) & (out[..., 3] < 1)
    assert partly.any() and np.abs(out[..., :3][out[..., 3] > 0]).max() < 1e-6


def test_float32_maps_of_a_large_photo_stay_inside():
    k = Intrinsics(3000.0, 3000.0, 2000.2, 1499.7, 4000, 3000)
    d = Distortion("opencv", (-0.12, 0.03, 0.0005, 0.0007, 0.0))
    map_x, map_y = undistortion_maps(k, d, undistorted_intrinsics(k, d))
    assert map_x.min() >= -0.51 and map_x.max() <= 3999.51 and map_y.min() >= -0.51 and map_y.max() <= 2999.51


def test_a_photo_beyond_the_fold_of_its_model_is_cropped_to_the_part_before_it():
    # r_d = r (1 - 0.9 r^2) peaks at r = 1/sqrt(2.7) (r_d = 0.365), but the photo reaches r_d = 0.63 to the side:
    # its outer part is not described by the model.  The view stops where the model folds.
    d = Distortion("opencv", (-0.9, 0.0, 0.0, 0.0, 0.0))
    k = undistorted_intrinsics(K_PHOTO, d)
    u, v = pixel_grid(k)
    r = np.hypot((u - k.cx) / k.fx, (v - k.cy) / k.fy)
    assert r.max() <= 1.0 / math.sqrt(2.7) + 1e-6 and r.max() > 0.95 / math.sqrt(2.7)
    undistortion_maps(K_PHOTO, d, k)  # valid: no fold, nothing outside
    with pytest.raises(DistortionError, match="folds"):
        undistortion_maps(K_PHOTO, d, _scaled(k, 0.9))  # wider: the fold is inside the view
    with pytest.raises(DistortionError, match="outside the photo"):
        undistortion_maps(K_PHOTO, CASES["barrel"], _scaled(undistorted_intrinsics(K_PHOTO, CASES["barrel"]), 0.9))


def test_wide_lens_with_a_fold_past_its_corners_loads():
    # a 1920x1080-style frame (at a tenth of the size) with k1 = -0.25: the model folds at r = 1.15, past the
    # corners' r = 1.10 at the photo's own focal; a search that ignored the fold would refuse the camera
    k = Intrinsics(100.0, 100.0, 96.0, 54.0, 192, 108)
    d = Distortion("opencv", (-0.25, 0.0, 0.0, 0.0, 0.0))
    pin = undistorted_intrinsics(k, d)
    undistortion_maps(k, d, pin)
    assert 0.9 < pin.fx / k.fx < 1.0


def test_hemispherical_fisheye_gets_the_80_degree_view():
    # an equidistant fisheye whose photo spans 100 degrees off axis: every pinhole view fits; the widest kept has
    # its corners 80 degrees off axis
    k = Intrinsics(30.0, 30.0, 50.0, 50.0, 100, 100)
    pin = undistorted_intrinsics(k, Distortion("fisheye", (0.0, 0.0, 0.0, 0.0)))
    corner = math.hypot(49.5, 49.5) / pin.fx
    assert math.degrees(math.atan(corner)) == pytest.approx(80.0, abs=1e-9)


@pytest.mark.parametrize("size", [(1, 1), (1, 7), (7, 1)])
def test_one_pixel_wide_images(size):
    k = Intrinsics(5.0, 5.0, size[1] / 2, size[0] / 2, size[1], size[0])
    d = CASES["barrel"]
    pin = undistorted_intrinsics(k, d)
    out = undistort_image(np.full(size + (3,), 0.25, np.float32), undistortion_maps(k, d, pin))
    assert out.shape == size + (3,) and np.allclose(out, 0.25)


def test_principal_point_outside_the_photo_is_refused():
    with pytest.raises(DistortionError, match="principal point"):
        undistorted_intrinsics(Intrinsics(100.0, 100.0, 250.0, 80.0, 200, 160), CASES["barrel"])


def test_distortion_validates_its_fields():
    with pytest.raises(ValueError, match="model"):
        Distortion("brown", (0, 0, 0, 0, 0))
    with pytest.raises(ValueError, match="5 finite numbers"):
        Distortion("opencv", (0.1, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        Distortion("fisheye", (float("nan"), 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        distort_pixels(np.zeros(3), K_PHOTO, K_PHOTO, CASES["barrel"])


# --- through the JSON loaders ---------------------------------------------------------------------------

def _photo_meta(d: Distortion | None = None) -> dict:
    meta = {"fl_x": K_PHOTO.fx, "fl_y": K_PHOTO.fy, "cx": K_PHOTO.cx, "cy": K_PHOTO.cy, "w": 200, "h": 160}
    if d is not None and d.model == "opencv":
        meta.update(dict(zip(("k1", "k2", "p1", "p2", "k3"), d.coeffs)))
    elif d is not None:
        meta.update(dict(zip(("k1", "k2", "k3", "k4"), d.coeffs)), camera_model="OPENCV_FISHEYE")
    return meta


def _photo_writer(d: Distortion):
    photo = np.round(render_photo(K_PHOTO, d) * 255.0).astype(np.uint8)
    return lambda seed: photo


@pytest.mark.parametrize("name", ["tangential", "fisheye"])
def test_ngp_scene_is_undistorted_at_load(tmp_path, writers, name):
    from senerf.data import load_scene
    d = CASES[name]
    scene = load_scene(writers.ngp(tmp_path / "n", meta_extra=_photo_meta(d), image=_photo_writer(d)))
    k_pin = undistorted_intrinsics(K_PHOTO, d)
    assert scene.intrinsics == k_pin and all(k == k_pin for k in scene.intrinsics_all)
    u, v = pixel_grid(k_pin)
    expected = texture((u - k_pin.cx) / k_pin.fx, (v - k_pin.cy) / k_pin.fy)
    err = np.abs(scene.rgb - expected[None])
    assert err[:, 2:-2, 2:-2].max() < 4e-3  # 8-bit photos: 1/510 rounding, then bilinear resampling
    assert np.abs(render_photo(K_PHOTO, d) - expected).max() > 0.02  # what the loader did before: nothing


def test_undistortion_happens_before_downscaling(tmp_path, writers):
    from senerf.data import load_scene
    from senerf.data._io import resize_area
    d = CASES["barrel"]
    root = writers.ngp(tmp_path / "n", meta_extra=_photo_meta(d), image=_photo_writer(d))
    full, half = load_scene(root), load_scene(root, downscale=2)
    assert half.intrinsics == undistorted_intrinsics(K_PHOTO, d).resized(100, 80)
    np.testing.assert_array_equal(half.rgb[1], resize_area(full.rgb[1].copy(), (80, 100)))


def test_frame_distortion_overrides_the_file_and_zero_is_a_pinhole(tmp_path, writers):
    from senerf.data import load_scene
    d = CASES["barrel"]
    root = writers.ngp(tmp_path / "n", meta_extra=_photo_meta(d), image=_photo_writer(d))
    meta = writers.read_json(root / "transforms.json")
    meta["frames"][1].update(k1=0.0, k2=0.0)
    meta["frames"][2].update(k1=-0.1)
    writers.write_json(root / "transforms.json", meta)
    scene = load_scene(root)
    k0, k1, k2 = scene.intrinsics_all
    assert k0 == undistorted_intrinsics(K_PHOTO, d) and k1 == K_PHOTO
    assert k2 == undistorted_intrinsics(K_PHOTO, Distortion("opencv", (-0.1, 0.06, 0.0, 0.0, 0.0)))
    assert k2.fx > k0.fx  # less barrel, less to crop


def test_instant_ngp_fisheye_flag(tmp_path, writers):
    from senerf.data import load_scene
    d = CASES["fisheye-equidistant"]
    meta = dict(_photo_meta(), k1=0, k2=0, k3=0, k4=0, p1=0, p2=0, is_fisheye=True)
    scene = load_scene(writers.ngp(tmp_path / "n", meta_extra=meta, image=_photo_writer(d)))
    assert scene.intrinsics == undistorted_intrinsics(K_PHOTO, d) != K_PHOTO
    meta["is_fisheye"] = False  # instant-ngp writes the flag and zeros for every pinhole capture
    scene = load_scene(writers.ngp(tmp_path / "p", meta_extra=meta, image=_photo_writer(d)))
    assert scene.intrinsics == K_PHOTO


@pytest.mark.parametrize("extra, frame_extra, field", [
    ({"k1": "0.1x"}, {}, "k1"),
    ({"k1": 10 ** 400}, {}, "k1"),
    ({"k2": float("inf")}, {}, "k2"),
    ({}, {"p1": True}, "frames[0].p1"),
    ({"is_fisheye": "yes"}, {}, "is_fisheye"),
    ({"k4": 0.01}, {}, "k4"),
    ({"is_fisheye": True, "p2": 0.01}, {}, "p2"),
    ({"camera_model": "EQUIRECTANGULAR"}, {}, "camera_model"),
    ({}, {"camera_model": "fisheye624"}, "frames[0].camera_model"),
    ({"camera_model": 5}, {}, "camera_model"),
    ({"camera_model": "FULL_OPENCV"}, {}, "camera_model"),
    ({"camera_model": "OPENCV", "is_fisheye": True}, {}, "is_fisheye"),
    ({"camera_model": "OPENCV_FISHEYE", "is_fisheye": False}, {}, "is_fisheye"),
    ({"cx": 250.0, "k1": -0.1}, {}, "k1"),
])
def test_bad_distortion_fields_name_file_and_field(tmp_path, writers, extra, frame_extra, field):
    from senerf.data import load_scene
    from senerf.errors import InputError
    root = writers.ngp(tmp_path / "n", meta_extra=dict(_photo_meta(), **extra), image=_photo_writer(CASES["barrel"]))
    if frame_extra:
        meta = writers.read_json(root / "transforms.json")
        meta["frames"][0].update(frame_extra)
        writers.write_json(root / "transforms.json", meta)
    with pytest.raises(InputError) as info:
        load_scene(root)
    assert (info.value.file, info.value.field) == (str(root / "transforms.json"), field)
    assert "\n" not in str(info.value)


def test_blender_format_reads_distortion_too(tmp_path, writers):
    from senerf.data import load_scene
    root = writers.blender(tmp_path / "b", n_train=2, n_val=0, n_test=1)
    for split in ("train", "test"):
        meta = writers.read_json(root / f"transforms_{split}.json")
        meta.update(k1=-0.05)
        writers.write_json(root / f"transforms_{split}.json", meta)
    scene = load_scene(root)
    pinhole = load_scene(writers.blender(tmp_path / "p", n_train=2, n_val=0, n_test=1))
    expected = undistorted_intrinsics(pinhole.intrinsics, Distortion("opencv", (-0.05, 0.0, 0.0, 0.0, 0.0)))
    assert expected != pinhole.intrinsics and all(k == expected for k in scene.intrinsics_all)


def test_coefficients_written_as_strings_are_read(tmp_path, writers):
    # older nerfstudio converters (RealityCapture) wrote "k1": "-0.05"; nerfstudio reads them with float()
    from senerf.data import load_scene
    d = CASES["barrel"]
    meta = dict(_photo_meta(d), k1=" -0.25", k2="0.06")
    scene = load_scene(writers.ngp(tmp_path / "n", meta_extra=meta, image=_photo_writer(d)))
    assert scene.intrinsics == undistorted_intrinsics(K_PHOTO, d)


def test_frame_null_falls_back_to_the_file_and_frame_fisheye_needs_no_file_model(tmp_path, writers):
    from senerf.data import load_scene
    d, fe = CASES["barrel"], CASES["fisheye"]
    root = writers.ngp(tmp_path / "n", meta_extra=_photo_meta(d), image=_photo_writer(d))
    meta = writers.read_json(root / "transforms.json")
    meta["frames"][0].update(k1=None, camera_model=None)
    meta["frames"][2].update(dict(zip(("k1", "k2", "k3", "k4"), fe.coeffs)), camera_model="opencv_fisheye ",
                             p1=0.0, p2=0.0)
    writers.write_json(root / "transforms.json", meta)
    k0, k1, k2 = load_scene(root).intrinsics_all
    assert k0 == k1 == undistorted_intrinsics(K_PHOTO, d) and k2 == undistorted_intrinsics(K_PHOTO, fe)


def test_interleaved_cameras_and_rgba_through_the_loader(tmp_path, writers):
    # frames of two cameras, alternating (instant-ngp writes per-frame intrinsics for several cameras); RGBA
    from senerf.data import load_scene
    from senerf.data._io import read_rgba
    d = CASES["tangential"]
    rng = np.random.default_rng(3)
    photos = [rng.uniform(0, 1, (160, 200, 4)).astype(np.float32) for _ in range(5)]
    root = writers.ngp(tmp_path / "n", n=5, meta_extra=_photo_meta(d),
                       image=lambda seed: np.round(photos[seed - 100] * 255).astype(np.uint8))
    meta = writers.read_json(root / "transforms.json")
    for i in (1, 3):
        meta["frames"][i]["fl_x"] = 140.0
    writers.write_json(root / "transforms.json", meta)
    scene = load_scene(root)
    for i in range(5):
        k = Intrinsics(140.0 if i in (1, 3) else K_PHOTO.fx, K_PHOTO.fy, K_PHOTO.cx, K_PHOTO.cy, 200, 160)
        pin = undistorted_intrinsics(k, d)
        assert scene.intrinsics_all[i] == pin
        expected = undistort_image(read_rgba(scene.image_paths[i], "f"), undistortion_maps(k, d, pin))
        np.testing.assert_array_equal(scene.rgb[i], expected[..., :3])
        np.testing.assert_array_equal(scene.alpha[i], expected[..., 3])


def test_negligible_distortion_is_nearly_the_identity():
    # the view is bounded by the photo's pixel centres, so a vanishing distortion leaves the camera (nearly)
    # as it was instead of widening it by half a pixel at each edge
    for k1 in (1e-300, -1e-12, 1e-12):
        k = undistorted_intrinsics(K_PHOTO, Distortion("opencv", (k1, 0.0, 0.0, 0.0, 0.0)))
        assert k.fx == pytest.approx(K_PHOTO.fx, rel=1e-9) and k.fy == pytest.approx(K_PHOTO.fy, rel=1e-9)


# --- added by the mutation audit -------------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(CASES))
def test_the_focal_search_reaches_the_widest_view_to_1e9(name):
    # the bisection is documented to ~1e-12 relative: a view wider by 1e-9 already leaves the photo
    d = CASES[name]
    k = undistorted_intrinsics(K_PHOTO, d)
    wider = _scaled(k, 1.0 - 1e-9)
    u, v = pixel_grid(wider)
    xd, yd = distort((u - wider.cx) / wider.fx, (v - wider.cy) / wider.fy, d)
    pu, pv = K_PHOTO.fx * xd + K_PHOTO.cx, K_PHOTO.fy * yd + K_PHOTO.cy
    assert pu.min() < 0.5 or pv.min() < 0.5 or pu.max() > 199.5 or pv.max() > 159.5


def test_a_focal_factor_up_to_64_is_searched_and_beyond_it_refused():
    # k1 = -1000 folds at r = 1/sqrt(3000): the corners (r = 0.82 at the photo's focal) need a factor of ~45
    d = Distortion("opencv", (-1000.0, 0.0, 0.0, 0.0, 0.0))
    k = undistorted_intrinsics(K_PHOTO, d)
    assert 32.0 < k.fx / K_PHOTO.fx < 64.0
    corner = math.hypot(99.8 / k.fx, 79.9 / k.fy)  # the farthest pixel centre, (0.5, 159.5)
    assert corner == pytest.approx(1.0 / math.sqrt(3000.0), rel=0.01)  # at the fold (probed by differences)
    undistortion_maps(K_PHOTO, d, k)
    with pytest.raises(DistortionError, match="no pinhole view up to 64 times"):
        undistorted_intrinsics(K_PHOTO, Distortion("opencv", (-1e5, 0.0, 0.0, 0.0, 0.0)))


def test_distortion_refuses_too_many_coefficients():
    with pytest.raises(ValueError, match="5 finite numbers"):
        Distortion("opencv", (0.1, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="4 finite numbers"):
        Distortion("fisheye", (0.1, 0.0, 0.0, 0.0, 0.0))


def test_maps_a_third_of_a_pixel_outside_the_photo_are_refused():
    k = undistorted_intrinsics(K_PHOTO, CASES["barrel"])
    with pytest.raises(DistortionError, match="outside the photo"):
        undistortion_maps(K_PHOTO, CASES["barrel"], _scaled(k, 0.995))  # its top row samples 0.34 px above


def test_a_fold_inside_the_view_away_from_its_border_is_found():
    # r (1 + k1 r^2 + k2 r^4 + k3 r^6) turns back and forward again: a ring folds inside a view whose border
    # samples unfolded photo; only the grid inside the view sees it
    d = Distortion("opencv", (-1.4, 0.12, 0.012, 0.072, 2.26))
    k = undistorted_intrinsics(K_PHOTO, d)
    undistortion_maps(K_PHOTO, d, k)  # no fold in the view chosen
    with pytest.raises(DistortionError, match="folds"):
        undistortion_maps(K_PHOTO, d, _scaled(k, 0.75))


def test_principal_point_on_the_half_pixel_edge():
    pincushion = CASES["pincushion"]
    with pytest.raises(DistortionError, match="principal point"):
        undistorted_intrinsics(Intrinsics(160.0, 150.0, 0.4, 79.6, 200, 160), pincushion)
    with pytest.raises(DistortionError, match="principal point"):
        undistorted_intrinsics(Intrinsics(160.0, 150.0, 100.3, 159.6, 200, 160), pincushion)
    undistorted_intrinsics(Intrinsics(160.0, 150.0, 0.5, 79.6, 200, 160), pincushion)  # on the centre: accepted


def test_hemispherical_fisheye_with_unequal_focals_gets_the_80_degree_view():
    k = Intrinsics(30.0, 24.0, 50.0, 50.0, 100, 100)
    pin = undistorted_intrinsics(k, Distortion("fisheye", (0.0, 0.0, 0.0, 0.0)))
    assert pin.fx / pin.fy == pytest.approx(1.25, rel=1e-12)
    corner = math.hypot(49.5 / pin.fx, 49.5 / pin.fy)
    assert math.degrees(math.atan(corner)) == pytest.approx(80.0, abs=1e-9)


def test_a_fold_between_the_last_two_rows_of_a_513_row_image_is_found():
    # rows are checked in chunks of 512 cells; the last pair of rows of a 513-row image is a chunk's edge.
    # k1 = -0.9 folds at r = 1/sqrt(2.7) = 486.9 px at f = 800: between rows 511 (511.5) and 512 (512.5) with cy 24.6
    k = Intrinsics(800.0, 800.0, 2.0, 24.6, 4, 513)
    d = Distortion("opencv", (-0.9, 0.0, 0.0, 0.0, 0.0))
    beyond = Intrinsics(800.0, 800.0, 2.0, 25.6, 4, 513)
    undistortion_maps(beyond, d, beyond)  # the fold a pixel further down, past the last row: fine
    with pytest.raises(DistortionError, match="folds"):
        undistortion_maps(k, d, k)


def test_maps_and_coverage_refuse_a_pinhole_of_another_size():
    other = Intrinsics(160.0, 150.0, 100.3, 79.6, 100, 80)
    with pytest.raises(ValueError):
        undistortion_maps(K_PHOTO, CASES["barrel"], other)
    with pytest.raises(ValueError):
        photo_coverage(K_PHOTO, CASES["barrel"], other)


def test_fully_transparent_pixels_come_out_black_not_nan():
    d = CASES["barrel"]
    photo = np.zeros((160, 200, 4), np.float32)
    photo[:, :, :3] = 0.7
    photo[:, 100:, 3] = 1.0  # left half fully transparent
    with np.errstate(all="ignore"):
        out = undistort_image(photo, undistortion_maps(K_PHOTO, d, undistorted_intrinsics(K_PHOTO, d)))
    assert np.all(np.isfinite(out))
    clear = out[..., 3] == 0.0
    assert clear.any() and np.all(out[..., :3][clear] == 0.0)
    np.testing.assert_allclose(out[..., :3][out[..., 3] > 0], 0.7, rtol=1e-5)


@pytest.mark.parametrize("extra, field", [
    ({"is_fisheye": 1}, "is_fisheye"),  # JSON's 1 is not true
    ({"camera_model": "OPENCV_FISHEYE", "is_fisheye": True, "cx": 250.0}, "camera_model"),
    ({"camera_model": "OPENCV_FISHEYE", "k2": 0.01, "cx": 250.0}, "k2"),
    ({"k1": 0.0, "k2": -0.1, "p2": 0.01, "cx": 250.0}, "k2"),  # the first non-zero one
])
def test_distortion_errors_name_the_field_that_set_it(tmp_path, writers, extra, field):
    from senerf.data import load_scene
    from senerf.errors import InputError
    root = writers.ngp(tmp_path / "n", meta_extra=dict(_photo_meta(), **extra), image=_photo_writer(CASES["barrel"]))
    with pytest.raises(InputError) as info:
        load_scene(root)
    assert (info.value.file, info.value.field) == (str(root / "transforms.json"), field)


def test_file_level_null_counts_as_absent(tmp_path, writers):
    from senerf.data import load_scene
    d = CASES["barrel"]
    meta = dict(_photo_meta(d), k3=None, k4=None, p1=None, camera_model=None, is_fisheye=None)
    scene = load_scene(writers.ngp(tmp_path / "n", meta_extra=meta, image=_photo_writer(d)))
    assert scene.intrinsics == undistorted_intrinsics(K_PHOTO, d)


@pytest.mark.parametrize("camera_model, coeffs, expected", [
    ("PINHOLE", {}, None),
    ("SIMPLE_PINHOLE", {}, None),
    ("SIMPLE_RADIAL", {"k1": -0.1}, Distortion("opencv", (-0.1, 0.0, 0.0, 0.0, 0.0))),
    ("SIMPLE_RADIAL_FISHEYE", {"k1": 0.04}, Distortion("fisheye", (0.04, 0.0, 0.0, 0.0))),
    ("RADIAL_FISHEYE", {"k1": 0.04, "k2": -0.01}, Distortion("fisheye", (0.04, -0.01, 0.0, 0.0))),
])
def test_every_named_camera_model_is_read(tmp_path, writers, camera_model, coeffs, expected):
    from senerf.data import load_scene
    meta = dict(_photo_meta(), camera_model=camera_model, **coeffs)
    scene = load_scene(writers.ngp(tmp_path / "n", meta_extra=meta, image=_photo_writer(CASES["barrel"])))
    assert scene.intrinsics == (K_PHOTO if expected is None else undistorted_intrinsics(K_PHOTO, expected))


# --- how much of the photo the pinhole view keeps, and the warning when it is little -----------------------------

def test_photo_coverage_of_a_zoomed_pinhole_is_one_over_the_zoom_squared():
    # golden by hand: with no distortion a pinhole of focal s f samples the photo's centre (W-1)/s x (H-1)/s
    d = Distortion("opencv", (0.0, 0.0, 0.0, 0.0, 0.0))
    k = Intrinsics(160.0, 150.0, 100.0, 80.0, 201, 161)
    for s in (1.0, 2.0, 4.0):
        assert photo_coverage(k, d, _scaled(k, s)) == pytest.approx(1.0 / s ** 2, rel=1e-12)


@pytest.mark.parametrize("name", sorted(CASES))
def test_photo_coverage_matches_a_count_of_photo_pixels_inside_the_view(name):
    # a different method: undistort every photo pixel centre with this file's own Newton solver, project it with
    # the pinhole camera, and count those landing within the pinhole's outermost pixel centres
    d = CASES[name]
    k_pin = undistorted_intrinsics(K_PHOTO, d)
    step = 0.25   # a midpoint grid over the photo's pixel-centre box, [0.5, W - 0.5] x [0.5, H - 0.5]
    u, v = np.meshgrid(0.5 + step * (np.arange(round((K_PHOTO.width - 1) / step)) + 0.5),
                       0.5 + step * (np.arange(round((K_PHOTO.height - 1) / step)) + 0.5))
    x, y = undistort_normalised((u - K_PHOTO.cx) / K_PHOTO.fx, (v - K_PHOTO.cy) / K_PHOTO.fy, d)
    pu, pv = k_pin.fx * x + k_pin.cx, k_pin.fy * y + k_pin.cy
    inside = (pu >= 0.5) & (pu <= k_pin.width - 0.5) & (pv >= 0.5) & (pv <= k_pin.height - 0.5)
    assert photo_coverage(K_PHOTO, d, k_pin) == pytest.approx(inside.mean(), abs=2e-3)


def test_photo_coverage_of_one_pixel_wide_photos_is_nan():
    k = Intrinsics(5.0, 5.0, 0.5, 3.5, 1, 7)
    assert math.isnan(photo_coverage(k, CASES["barrel"], undistorted_intrinsics(k, CASES["barrel"])))


def _coverage_warnings(record) -> list:
    return [str(w.message) for w in record if "of the photo" in str(w.message)]


def _grey(h: int, w: int):
    return lambda seed: np.full((h, w, 3), 99, np.uint8)


def test_a_lens_model_folding_inside_the_photo_warns_once_naming_file_and_field(tmp_path, writers):
    from senerf.data import load_scene
    d = Distortion("opencv", (-0.9, 0.0, 0.0, 0.0, 0.0))   # folds at r_d = 0.365; the photo reaches 0.63
    assert photo_coverage(K_PHOTO, d, undistorted_intrinsics(K_PHOTO, d)) < COVERAGE_WARN
    root = writers.ngp(tmp_path / "n", meta_extra=_photo_meta(d), image=_grey(160, 200))
    meta = writers.read_json(root / "transforms.json")
    meta["frames"][1]["k1"] = -0.95   # three cameras, each cropped: still one warning for the load
    meta["frames"][2]["k1"] = -1.0
    writers.write_json(root / "transforms.json", meta)
    with pytest.warns(UserWarning) as record:
        load_scene(root)
    lines = _coverage_warnings(record)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"{root / 'transforms.json'}: undistorting f_0.png keeps 34% of the photo (k1: opencv")


def test_a_circular_fisheye_warns_that_its_pinhole_view_keeps_little_of_it(tmp_path, writers):
    from senerf.data import load_scene
    d = Distortion("fisheye", (0.0, 0.0, 0.0, 0.0))
    f = 45.0 / (math.pi / 2.0)   # an equidistant 180-degree circle inscribed in a 120x90 photo's short side
    k = Intrinsics(f, f, 60.0, 45.0, 120, 90)
    meta = {"fl_x": f, "fl_y": f, "cx": 60.0, "cy": 45.0, "w": 120, "h": 90, "camera_model": "OPENCV_FISHEYE",
            "k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0}
    assert photo_coverage(k, d, undistorted_intrinsics(k, d)) == pytest.approx(0.438, abs=1e-3)
    root = writers.ngp(tmp_path / "n", meta_extra=meta, image=_grey(90, 120))
    with pytest.warns(UserWarning) as record:
        load_scene(root)
    (line,) = _coverage_warnings(record)
    assert line.startswith(f"{root / 'transforms.json'}: undistorting f_0.png keeps 44% of the photo (camera_model:")


@pytest.mark.parametrize("name", sorted(CASES))
def test_ordinary_lenses_load_without_a_coverage_warning(tmp_path, writers, name):
    import warnings
    from senerf.data import load_scene
    d = CASES[name]
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        load_scene(writers.ngp(tmp_path / "n", meta_extra=_photo_meta(d), image=_photo_writer(d)))
    assert _coverage_warnings(record) == []
