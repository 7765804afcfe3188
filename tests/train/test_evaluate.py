"""Rendering cameras and scoring test views (senerf/train/evaluate.py) with an empty field, whose renders are known
exactly: the background, the far bound's camera z-depth, the ground truth composited onto the evaluation
background, and the depth colour map."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from senerf.config import ModelConfig
from senerf.data import Scene
from senerf.fields import RadianceField
from senerf.geometry import Intrinsics, look_at
from senerf.train import depth_to_color, eval_images, evaluate, render_views

K = Intrinsics(20.0, 25.0, 7.0, 6.5, 14, 12)   # principal point off the centre: z_per_dist varies


class EmptyField(RadianceField):
    """Zero density everywhere: every pixel renders the background, with acc 0 and ray_dist = far."""

    def density(self, xyz):
        return torch.zeros(xyz.shape[0], dtype=xyz.dtype)

    def forward(self, xyz, dirs):
        return self.density(xyz), torch.full((xyz.shape[0], 3), 0.5, dtype=xyz.dtype)


def _model(bg):
    return ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), near=1.0, far=3.0, resolution=8, multires=(1,),
                       n_features=4, n_samples=8, occupancy_resolution=0, train_background=bg, eval_background=bg)


@pytest.mark.parametrize("bg,value", [("white", 1.0), ("black", 0.0)])
def test_empty_field_renders_background_and_far_z_depth(bg, value):
    # Catches: white and black swapped, z_depth reported as the ray distance instead of camera z.
    # Empty rays: ray_dist = far = 3, so z_depth = 3 z_per_dist, with z_per_dist = 1 / |((u - cx)/fx,
    # (v - cy)/fy, 1)| at pixel centre (u, v) = (i + 0.5, j + 0.5).
    c2w = look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))
    out = render_views(EmptyField(), _model(bg), K, c2w)
    assert out["rgb"].shape == (1, 12, 14, 3)
    np.testing.assert_array_equal(out["rgb"], value)
    np.testing.assert_array_equal(out["acc"], 0.0)
    u, v = np.meshgrid(np.arange(14) + 0.5, np.arange(12) + 0.5)
    zpd = 1.0 / np.sqrt(((u - 7.0) / 20.0) ** 2 + ((v - 6.5) / 25.0) ** 2 + 1.0)
    np.testing.assert_allclose(out["z_depth"][0], 3.0 * zpd, rtol=1e-6)
    # the other background when asked by name
    other = render_views(EmptyField(), _model(bg), K, c2w, background="black" if bg == "white" else "white")
    np.testing.assert_array_equal(other["rgb"], 1.0 - value)


def test_evaluate_composites_the_ground_truth_on_the_eval_background(tmp_path):
    # Catches: the RGBA ground truth composited onto black whatever eval_background says (a white render of
    # a fully transparent view would score 0 dB instead of a perfect match), a view compared with the ground
    # truth of its position in test_idx instead of its scene index, PNGs not written.
    # View 0 is transparent (ground truth white on white), view 1 opaque grey 0.3: the white render is off
    # by 0.7 everywhere, PSNR = 10 log10(1 / 0.49) = 3.0980392 dB.
    c2w = np.stack([look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3)), look_at(np.array([4.0, 0.0, 0.0]), np.zeros(3))])
    alpha = np.zeros((2, 12, 14), np.float32)
    alpha[1] = 1.0
    scene = Scene(name="e", root=".", rgb=np.full((2, 12, 14, 3), 0.3, np.float32), alpha=alpha, intrinsics=K,
                  intrinsics_all=(K, K), c2w=c2w, image_paths=("a.png", "b.png"))
    res = evaluate(EmptyField(), scene, [1, 0], tmp_path, _model("white"), progress=False)
    assert res["per_view"]["psnr"][0] == pytest.approx(10 * math.log10(1 / 0.49), abs=1e-5)
    assert res["per_view"]["psnr"][1] == math.inf and res["per_view"]["ssim"][1] == pytest.approx(1.0)
    assert res["lpips"] == "unavailable"
    import imageio.v2 as imageio

    for k in range(2):
        np.testing.assert_array_equal(imageio.imread(tmp_path / f"rgb_{k:03d}.png"), 255)
        np.testing.assert_array_equal(imageio.imread(tmp_path / f"depth_{k:03d}.png"), 255)  # acc 0: background
    # on black: the transparent view matches a black render, the grey one is off by 0.3 (10.457575 dB)
    black = evaluate(EmptyField(), scene, [0, 1], None, _model("black"), progress=False)
    assert black["per_view"]["psnr"][0] == math.inf
    assert black["per_view"]["psnr"][1] == pytest.approx(10 * math.log10(1 / 0.09), abs=1e-5)


def test_renders_are_clipped_to_0_1_before_they_are_scored():
    # Catches: a colour beyond [0, 1] (a field's raw output, a background of 1 plus a colour) scored and written
    # as it is: a render of 1.5 against a white photo must score as the white it is written as.
    class Bright(RadianceField):
        def density(self, xyz):
            return torch.full((xyz.shape[0],), 1e3, dtype=xyz.dtype)

        def forward(self, xyz, dirs):
            return self.density(xyz), torch.full((xyz.shape[0], 3), 1.5, dtype=xyz.dtype)

    scene = Scene(name="w", root=".", rgb=np.ones((1, 12, 14, 3), np.float32), alpha=None, intrinsics=K,
                  intrinsics_all=(K,), c2w=look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))[None],
                  image_paths=("a.png",))
    assert render_views(Bright(), _model("black"), K, scene.c2w)["rgb"].max() > 1.4
    assert evaluate(Bright(), scene, [0], None, _model("black"), progress=False)["psnr"] == math.inf


def test_depth_to_color_near_is_red_far_is_blue_and_empty_fades():
    # Catches: the colour map not reversed (near must be turbo's red end, turbo(1.0); far its blue end,
    # turbo(0.0)), or empty pixels not faded to the background.
    from matplotlib import colormaps

    z = np.array([[1.0, 2.0, 1.5, 1.5]])
    acc = np.array([[1.0, 1.0, 0.0, 0.5]])
    img = depth_to_color(z, acc, lo=1.0, hi=2.0, background=1.0)
    turbo = colormaps["turbo"]
    near, far, mid = (np.asarray(turbo(x)[:3]) for x in (1.0, 0.0, 0.5))
    assert near[0] > near[2] and far[2] > far[0]               # turbo: 1.0 red, 0.0 blue (the golden's sense)
    np.testing.assert_array_equal(img[0, 0], np.round(near * 255))
    np.testing.assert_array_equal(img[0, 1], np.round(far * 255))
    np.testing.assert_array_equal(img[0, 2], [255, 255, 255])
    np.testing.assert_array_equal(img[0, 3], np.round((0.5 * mid + 0.5) * 255))


def test_eval_images_composites_only_the_views_asked_for():
    c2w = np.stack([look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))] * 3)
    rgb = np.stack([np.full((12, 14, 3), v, np.float32) for v in (0.2, 0.4, 0.6)])
    alpha = np.stack([np.full((12, 14), a, np.float32) for a in (0.0, 0.5, 1.0)])
    scene = Scene(name="e", root=".", rgb=rgb, alpha=alpha, intrinsics=K, intrinsics_all=(K, K, K), c2w=c2w,
                  image_paths=("a.png", "b.png", "c.png"))
    white = eval_images(scene, [2, 1], _model("white"))
    assert white.shape == (2, 12, 14, 3) and white.dtype == np.float32
    np.testing.assert_allclose(white[0], 0.6)                       # opaque: its colour
    np.testing.assert_allclose(white[1], 0.4 * 0.5 + 1.0 * 0.5)     # half on white: 0.7
    np.testing.assert_allclose(eval_images(scene, [0, 1], _model("black"))[:, 0, 0, 0], [0.0, 0.2])
    opaque = Scene(name="o", root=".", rgb=rgb, alpha=None, intrinsics=K, intrinsics_all=(K, K, K), c2w=c2w,
                   image_paths=("a.png", "b.png", "c.png"))
    np.testing.assert_array_equal(eval_images(opaque, [1], _model("white"))[0], rgb[1])   # no alpha: as loaded


def test_renders_and_scores_refuse_inputs_of_the_wrong_shape():
    # Catches: a pose, depth or test-view list of the wrong shape failing later, elsewhere, or scoring NaN (a
    # mean over no views).
    for shape in [(16,), (1, 3, 4), (2, 2, 4, 4)]:
        with pytest.raises(ValueError, match="c2w"):
            render_views(EmptyField(), _model("white"), K, np.zeros(shape))
    for z_shape, acc_shape in [((4,), (4,)), ((2, 2), (2, 3)), ((1, 2, 2), (1, 2, 2))]:
        with pytest.raises(ValueError, match="z_depth"):
            depth_to_color(np.ones(z_shape), np.ones(acc_shape))
    assert depth_to_color(np.ones((1, 1)), np.ones((1, 1))).shape == (1, 1, 3)
    scene = Scene(name="e", root=".", rgb=np.zeros((1, 12, 14, 3), np.float32), alpha=None, intrinsics=K,
                  intrinsics_all=(K,), c2w=look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))[None],
                  image_paths=("a.png",))
    with pytest.raises(ValueError, match="test views"):
        evaluate(EmptyField(), scene, [], None, _model("white"), progress=False)
