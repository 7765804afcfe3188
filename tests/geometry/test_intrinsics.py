"""Tests of senerf/geometry/intrinsics.py."""

import json
import math

import numpy as np
import pytest

from senerf.geometry import Intrinsics


def test_K_layout():
    k = Intrinsics(500.0, 400.0, 256.0, 128.0, 512, 300)
    np.testing.assert_array_equal(k.K, [[500, 0, 256], [0, 400, 128], [0, 0, 1]])
    assert k.K.dtype == np.float64
    assert k.size == (300, 512)


def test_blender_lego_focal():
    # f = 0.5 W / tan(0.5 camera_angle_x) = 400 / tan(0.345555603504) = 400 / 0.3600000... = 1111.111 px
    k = Intrinsics.from_fov(math.degrees(0.6911112070083618), 800, 800)
    assert k.fx == pytest.approx(1111.111, abs=1e-3)
    assert (k.cx, k.cy) == (400.0, 400.0)
    assert math.degrees(2.0 * math.atan(400.0 / k.fx)) == pytest.approx(math.degrees(0.6911112070083618), rel=1e-12)


def test_lego_file_focal(lego_dir):
    meta = json.loads((lego_dir / "transforms_train.json").read_text())
    k = Intrinsics.from_fov(math.degrees(meta["camera_angle_x"]), 800, 800)
    assert k.fx == pytest.approx(1111.111, abs=1e-3)


def test_scaled_is_diag_s_s_1_times_K():
    k = Intrinsics(1111.1, 1000.0, 400.0, 300.0, 800, 600)
    for s in (0.5, 0.25, 2.0):
        ks = k.scaled(s)
        np.testing.assert_allclose(ks.K, np.diag([s, s, 1.0]) @ k.K, rtol=1e-15)
        assert (ks.width, ks.height) == (800 * s, 600 * s)


def test_scaled_pixel_centres_map_exactly():
    # Pixel-centre convention: half-size pixel 0 covers full-size [0, 2), so its centre 0.5 must be the
    # full-size coordinate 1.0 (the edge between pixels 0 and 1): u_half = 0.5 * u_full for every point.
    k_small = Intrinsics(500.0, 500.0, 256.0, 200.0, 512, 400).scaled(0.5)
    ray_at_full_1 = np.linalg.solve(Intrinsics(500.0, 500.0, 256.0, 200.0, 512, 400).K, [1.0, 1.0, 1.0])
    np.testing.assert_allclose((k_small.K @ ray_at_full_1)[:2], [0.5, 0.5])
    k = Intrinsics(500.0, 500.0, 256.0, 200.0, 512, 400)
    x = np.array([0.3, -0.1, 1.0])
    u_full = k.K @ x
    u_half = k.scaled(0.5).K @ x
    np.testing.assert_allclose(u_half[:2], 0.5 * u_full[:2])


def test_scaled_non_integer_size_raises_and_resized_works():
    k = Intrinsics(1111.0, 1111.0, 400.0, 400.0, 800, 800)
    with pytest.raises(ValueError, match="non-integer"):
        k.scaled(1 / 3)
    r = k.resized(266, 266)
    assert r.fx == pytest.approx(1111.0 * 266 / 800)
    assert (r.width, r.height) == (266, 266)


BAD_VALUES = {"fx": [0.0, -1.0, float("nan"), float("inf")], "fy": [0.0, -1.0, float("nan"), float("inf")],
              "cx": [0.0, -3.0, float("nan"), float("-inf")], "cy": [0.0, -3.0, float("nan"), float("-inf")],
              "width": [0, -3, 2.5, True, float("nan"), "4"], "height": [0, -3, 2.5, True, float("nan"), "4"]}


@pytest.mark.parametrize("field, bad", [(f, v) for f, values in BAD_VALUES.items() for v in values])
def test_a_bad_value_is_refused_naming_its_field(field, bad):
    # non-positive or non-finite focal lengths and principal points; sizes that are not integers >= 1
    args = dict(fx=500.0, fy=500.0, cx=1.0, cy=1.0, width=2, height=2)
    args[field] = bad
    with pytest.raises(ValueError, match=f"Intrinsics.{field}"):
        Intrinsics(**args)


def test_size_one_and_integral_float_and_numpy_int():
    k = Intrinsics(10.0, 10.0, 0.5, 0.5, 1, np.int64(1))
    assert k.size == (1, 1) and isinstance(k.height, int)
    assert Intrinsics(10.0, 10.0, 0.5, 0.5, 800.0, 1).width == 800


def test_frozen():
    k = Intrinsics(1.0, 1.0, 0.5, 0.5, 1, 1)
    with pytest.raises(Exception):
        k.fx = 2.0


@pytest.mark.parametrize("fov", [0.0, 180.0, -5.0, float("nan")])
def test_from_fov_rejects_bad_fov(fov):
    with pytest.raises(ValueError, match="fov"):
        Intrinsics.from_fov(fov, 10, 10)


def test_resized_non_square_uses_each_axis_ratio():
    # Catches: resized() applying the height ratio to x (or the width ratio to y).
    # 800 x 600 -> 400 x 200: sx = 400/800 = 0.5, sy = 200/600 = 1/3.  Pixel edges map to pixel edges, so
    # every coordinate scales by its axis ratio with no half-pixel shift: fx = 1000 * 0.5 = 500,
    # cx = 410 * 0.5 = 205, fy = 900 / 3 = 300, cy = 290 / 3 = 96.666...
    k = Intrinsics(1000.0, 900.0, 410.0, 290.0, 800, 600)
    r = k.resized(400, 200)
    assert (r.width, r.height) == (400, 200)
    assert r.fx == pytest.approx(500.0, rel=1e-15) and r.cx == pytest.approx(205.0, rel=1e-15)
    assert r.fy == pytest.approx(300.0, rel=1e-15) and r.cy == pytest.approx(290.0 / 3.0, rel=1e-15)
    # Same thing through the pixel-centre convention: the centre (0.5, 0.5) of small pixel (0, 0) covers
    # full-size [0, 2) x [0, 3), whose centre is (1.0, 1.5): both must see the same ray.
    ray_small = np.linalg.solve(r.K, [0.5, 0.5, 1.0])
    ray_full = np.linalg.solve(k.K, [1.0, 1.5, 1.0])
    np.testing.assert_allclose(ray_small, ray_full, rtol=1e-14)


def test_a_field_of_view_too_small_for_a_finite_focal_length_is_named():
    with pytest.raises(ValueError, match="Intrinsics.fov_x_deg: 1e-320 degrees"):
        Intrinsics.from_fov(1e-320, 800, 600)


@pytest.mark.parametrize("value", ["abc", None, [1.0], object()])
def test_a_value_that_is_not_a_number_is_refused_naming_the_field(value):
    for i, name in enumerate(("fx", "fy", "cx", "cy")):
        args = [10.0, 10.0, 2.0, 2.0]
        args[i] = value
        with pytest.raises(ValueError, match=f"Intrinsics.{name}: expected a real number"):
            Intrinsics(*args, 4, 4)
    with pytest.raises(ValueError, match=r"Intrinsics.scaled\(factor\): expected a real number"):
        Intrinsics(10.0, 10.0, 2.0, 2.0, 4, 4).scaled(value)
    assert Intrinsics("10", np.float32(10.0), 2, 2.5, 4, 4).fx == 10.0   # what float() takes is accepted
