"""render_views, evaluate and depth_to_color with an empty field, whose renders are known exactly
(senerf/train/evaluate.py; mutation audit)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from senerf.fields import RadianceField
from senerf.geometry import Intrinsics, look_at
from senerf.train import ModelConfig
from senerf.train.evaluate import depth_to_color, evaluate, render_views

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
    from senerf.data import Scene

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


def test_an_interrupted_evaluation_resumes_at_its_first_missing_view(tmp_path, render_spy):
    # Catches: finished views rendered again after an interruption (200 views at 400x400 take ~20 min), figures
    # differing from an uninterrupted call's, the interrupted call's seconds lost, a record of another field or
    # of other test views reused, a view whose PNGs were deleted not rendered again.
    import dataclasses
    import json

    from senerf.data import Scene
    from senerf.train import build_field

    rng = np.random.default_rng(0)
    c2w = np.stack([look_at(np.array([4 * math.cos(a), 4 * math.sin(a), 1.0]), np.zeros(3))
                    for a in np.linspace(0, 2, 5)])
    scene = Scene(name="e", root=".", rgb=rng.random((5, 12, 14, 3)).astype(np.float32), alpha=None, intrinsics=K,
                  intrinsics_all=(K,) * 5, c2w=c2w, image_paths=tuple(f"{i}.png" for i in range(5)))
    model = _model("black")
    field = build_field(model, seed=0).eval()
    test_idx = [4, 0, 2, 3]
    whole = evaluate(field, scene, test_idx, tmp_path / "whole", model, progress=False)
    assert whole["seconds_before"] == 0.0

    record = tmp_path / "eval.json"
    render_spy.calls, render_spy.stop_at = 0, 3
    with pytest.raises(KeyboardInterrupt):
        evaluate(field, scene, test_idx, tmp_path / "run", model, progress=False, resume=record)
    kept = json.loads(record.read_text())
    assert sorted(kept["views"]) == ["0", "1"] and kept["seconds"] > 0
    render_spy.calls, render_spy.stop_at = 0, None
    again = evaluate(field, scene, test_idx, tmp_path / "run", model, progress=False, resume=record)
    assert render_spy.calls == 2   # views 2 and 3 only
    assert again["per_view"] == whole["per_view"] and again["psnr"] == whole["psnr"] and again["ssim"] == whole["ssim"]
    assert again["seconds_before"] == kept["seconds"] and again["seconds"] > kept["seconds"]
    for k in range(4):
        name = f"rgb_{k:03d}.png"
        assert (tmp_path / "run" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    # a deleted render is made again; the others are not
    (tmp_path / "run" / "depth_001.png").unlink()
    render_spy.calls = 0
    assert evaluate(field, scene, test_idx, tmp_path / "run", model, progress=False, resume=record)["per_view"] \
        == whole["per_view"]
    assert render_spy.calls == 1 and (tmp_path / "run" / "depth_001.png").is_file()
    # the record now holds all four views: the same evaluation renders nothing (no PNGs asked for), while another
    # field, other test views or a test photo changed are not its evaluation, and every view is rendered
    finished = record.read_bytes()
    edited = dataclasses.replace(scene, rgb=scene.rgb.copy())
    edited.rgb[3, 5, 5] += 0.01
    for other_field, other_scene, other_idx, renders in ((field, scene, test_idx, 0),
                                                         (build_field(model, seed=1).eval(), scene, test_idx, 4),
                                                         (field, scene, [4, 0, 2, 1], 4), (field, edited, test_idx, 4)):
        record.write_bytes(finished)
        render_spy.calls = 0
        evaluate(other_field, other_scene, other_idx, None, model, progress=False, resume=record)
        assert render_spy.calls == renders


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
    from senerf.data import Scene
    from senerf.train import eval_images

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
