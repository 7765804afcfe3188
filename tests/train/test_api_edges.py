"""Input checks at the edges of senerf.train's API: each bad argument is refused with an error naming it, and each
check's boundary value is accepted (so an off-by-one in the comparison fails a test too)."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from senerf.errors import InputError
from senerf.geometry import Intrinsics, look_at
from senerf.train import ModelConfig, RayBatchSource, TrainConfig, camera_rays, choose_model, ray_aabb_bounds
from senerf.train.config import camera_aabb
from senerf.train.evaluate import depth_to_color, evaluate, render_views
from senerf.train.loop import background_color, train_field
from senerf.train.metrics import mse, psnr, ssim

K4 = Intrinsics(4.0, 4.0, 2.0, 2.0, 4, 4)
MODEL = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), near=1.0, far=3.0, resolution=8, multires=(1,), n_features=4,
                    n_samples=4, occupancy_resolution=0)
NAN, INF = float("nan"), float("inf")


def _c2w(n: int = 1) -> np.ndarray:
    return np.stack([look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))] * n)


class _Field(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(1))


# ---------------------------------------------------------------------------------------------------------
# TrainConfig / ModelConfig (InputError "<field>: <problem>")


@pytest.mark.parametrize("kwargs, message", [
    (dict(lr=0.0), "lr: must be a positive number, got 0.0"),
    (dict(lr=-0.01), "lr: must be a positive number, got -0.01"),
    (dict(lr=NAN), "lr: must be a positive number, got nan"),
    (dict(lr=INF), "lr: must be a positive number, got inf"),
    (dict(lr_final_factor=-0.01), "lr_final_factor: must be in [0, 1], got -0.01"),
    (dict(lr_final_factor=1.01), "lr_final_factor: must be in [0, 1], got 1.01"),
    (dict(tv_weight=-1e-6), "tv_weight: must be >= 0, got -1e-06"),
    (dict(tv_weight=NAN), "tv_weight: must be >= 0, got nan"),
    (dict(tv_weight=INF), "tv_weight: must be >= 0, got inf"),
    (dict(seed=1.0), "seed: must be an integer, got 1.0"),
    (dict(seed=True), "seed: must be an integer, got True"),
    (dict(seed="0"), "seed: must be an integer, got '0'"),
])
def test_train_config_refuses_each_bad_setting(kwargs, message):
    # Catches: any one of TrainConfig's lr / lr_final_factor / tv_weight / seed checks deleted or loosened
    # (the finiteness or the bool exclusion dropped), or its raise naming another field.
    with pytest.raises(InputError, match="^" + re.escape(message) + "$") as info:
        TrainConfig(**kwargs)
    assert info.value.field == message.split(":")[0]


@pytest.mark.parametrize("kwargs", [dict(lr=1e-9), dict(lr_final_factor=0.0), dict(lr_final_factor=1.0),
                                    dict(tv_weight=0.0), dict(seed=-7)])
def test_train_config_accepts_each_boundary_value(kwargs):
    # Catches: ``>= 0`` for ``> 0`` on lr, ``< 1`` for ``<= 1`` on lr_final_factor, ``> 0`` for ``>= 0`` on tv_weight.
    cfg = TrainConfig(**kwargs)
    assert all(getattr(cfg, k) == v for k, v in kwargs.items())


def test_train_config_takes_a_numpy_seed_as_a_plain_int():
    # Catches: a NumPy integer seed (a loop over np.arange) refused as "must be an integer" (so before 2026-11-23),
    # or kept as a NumPy scalar, which json.dumps of the run's config refuses.
    cfg = TrainConfig(seed=np.int64(3))
    assert cfg.seed == 3 and type(cfg.seed) is int


@pytest.mark.parametrize("kwargs, message", [
    (dict(near=1.0), "near/far: give both near and far, or neither"),
    (dict(far=3.0), "near/far: give both near and far, or neither"),
    (dict(near=-0.1, far=3.0), "near/far: need 0 <= near < far, got -0.1, 3.0"),
    (dict(near=2.0, far=2.0), "near/far: need 0 <= near < far, got 2.0, 2.0"),
    (dict(near=3.0, far=2.0), "near/far: need 0 <= near < far, got 3.0, 2.0"),
    (dict(ndc_near=0.0), "ndc_near: must be positive, got 0.0"),
    (dict(ndc_near=NAN), "ndc_near: must be positive, got nan"),
    (dict(ndc_near=INF), "ndc_near: must be positive, got inf"),
    (dict(occupancy_threshold=-1e-6), "occupancy_threshold: must be >= 0, got -1e-06"),
    (dict(occupancy_threshold=NAN), "occupancy_threshold: must be >= 0, got nan"),
    (dict(occupancy_threshold=INF), "occupancy_threshold: must be >= 0, got inf"),
    (dict(occupancy_decay=-0.01), "occupancy_decay: must be in [0, 1], got -0.01"),
    (dict(occupancy_decay=1.01), "occupancy_decay: must be in [0, 1], got 1.01"),
    (dict(multires=()), "multires: must be positive integers, got ()"),
    (dict(multires=(1, 0)), "multires: must be positive integers, got (1, 0)"),
    (dict(eval_background="random"), "eval_background: must be 'white' or 'black', got 'random'"),
    (dict(train_background="grey"), "train_background: must be one of random, white, black, got 'grey'"),
])
def test_model_config_refuses_each_bad_setting(kwargs, message):
    # Catches: any one of ModelConfig's near/far, ndc_near, occupancy, multires or eval_background checks deleted
    # or loosened, or its raise naming another field.
    with pytest.raises(InputError, match="^" + re.escape(message) + "$") as info:
        ModelConfig(**kwargs)
    assert info.value.field == message.split(":")[0]


@pytest.mark.parametrize("kwargs", [dict(near=0.0, far=1e-6), dict(ndc_near=1e-9), dict(occupancy_threshold=0.0),
                                    dict(occupancy_decay=0.0), dict(occupancy_decay=1.0), dict(multires=(1,)),
                                    dict(eval_background="black")])
def test_model_config_accepts_each_boundary_value(kwargs):
    # Catches: ``0 < near`` for ``0 <= near``, ``>= 0`` for ``> 0`` on ndc_near, ``> 0`` on the occupancy
    # threshold, an open interval for the decay, ``< 2`` for ``< 1`` on multires.
    cfg = ModelConfig(**kwargs)
    assert all(getattr(cfg, k) == v for k, v in kwargs.items())


@pytest.mark.parametrize("shape", [(4, 4), (1, 3, 4), (2, 4, 4, 1)])
def test_camera_aabb_refuses_poses_that_are_not_n_by_4_by_4(shape):
    # Catches: camera_aabb's c2w shape check deleted.
    with pytest.raises(ValueError, match="^" + re.escape(f"c2w must be (n, 4, 4), got {shape}") + "$"):
        camera_aabb(np.zeros(shape), 40.0)


def test_choose_model_refuses_no_training_views():
    # Catches: choose_model's empty train_idx check deleted (it would then fail on the scene, not as InputError).
    with pytest.raises(InputError, match="^train_idx: no training views$"):
        choose_model(object(), [], echo=lambda s: None)


# ---------------------------------------------------------------------------------------------------------
# rays.py


@pytest.mark.parametrize("o_shape, d_shape", [((3,), (3,)), ((4, 2), (4, 2)), ((4, 3), (3, 3)), ((4, 3), (4, 3, 1))])
def test_ray_aabb_bounds_refuses_misshapen_rays(o_shape, d_shape):
    # Catches: one condition of ray_aabb_bounds' origins / dirs shape check dropped.
    with pytest.raises(ValueError, match="^" + re.escape(f"origins and dirs must both be (R, 3), got {o_shape}, "
                                                         f"{d_shape}") + "$"):
        ray_aabb_bounds(torch.zeros(o_shape), torch.ones(d_shape), MODEL.aabb)


@pytest.mark.parametrize("aabb", [[[0, 0, 0], [1, 1, 1], [2, 2, 2]], [0, 0, 0, 1, 1, 1], [[0, 0], [1, 1]]])
def test_ray_aabb_bounds_refuses_a_box_that_is_not_2_by_3(aabb):
    # Catches: ray_aabb_bounds' aabb shape check deleted.
    shape = tuple(np.shape(aabb))
    with pytest.raises(ValueError, match="^" + re.escape(f"aabb must be (2, 3), got {shape}") + "$"):
        ray_aabb_bounds(torch.zeros(2, 3), torch.ones(2, 3), aabb)


@pytest.mark.parametrize("shape", [(16,), (1, 3, 4), (1, 4, 3)])
def test_camera_rays_refuses_poses_that_are_not_n_by_4_by_4(shape):
    # Catches: camera_rays' c2w shape check deleted.
    with pytest.raises(ValueError, match="^" + re.escape(f"c2w must be (n, 4, 4), got {shape}") + "$"):
        camera_rays(K4, np.zeros(shape), MODEL)


def _source(**replace) -> dict:
    n = 4
    args = dict(origins=torch.zeros(n, 3), dirs=torch.ones(n, 3), rgb=torch.zeros(n, 3), alpha=torch.ones(n),
                near=torch.zeros(n), far=torch.ones(n), model=MODEL)
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value, message", [
    ("dirs", torch.ones(3, 3), "dirs must be (4, 3) float32, got (3, 3) torch.float32"),
    ("rgb", torch.zeros(4, 4), "rgb must be (4, 3) float32, got (4, 4) torch.float32"),
    ("rgb", torch.zeros(4, 3, dtype=torch.float64), "rgb must be (4, 3) float32, got (4, 3) torch.float64"),
    ("origins", torch.zeros(4, 3, dtype=torch.float16), "origins must be (4, 3) float32, got (4, 3) torch.float16"),
    ("near", torch.zeros(3), "near must be (4,) float32, got (3,) torch.float32"),
    ("far", torch.ones(4, dtype=torch.float64), "far must be (4,) float32, got (4,) torch.float64"),
    ("alpha", torch.ones(4, 1), "alpha must be (4,) float32, got (4, 1) torch.float32"),
])
def test_ray_batch_source_refuses_each_misshapen_tensor(name, value, message):
    # Catches: RayBatchSource's (n, 3) or (n,) float32 check deleted, or its shape or dtype half dropped,
    # or ``alpha`` left out of the (n,) names.
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        RayBatchSource(**_source(**{name: value}))
    assert len(RayBatchSource(**_source(alpha=None))) == 4   # no alpha is allowed


def test_ray_batch_source_refuses_no_rays():
    # Catches: the ``n == 0`` check of RayBatchSource deleted (sampling a batch of no rays fails later).
    with pytest.raises(ValueError, match="^no rays$"):
        RayBatchSource(torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(0, 3), None, torch.zeros(0), torch.zeros(0),
                       MODEL)
    assert len(RayBatchSource(**_source(**{k: v[:1] for k, v in _source().items() if k != "model"}))) == 1


def _scene(n: int = 2) -> SimpleNamespace:
    return SimpleNamespace(n_images=n, intrinsics_all=[K4] * n, c2w=_c2w(n), rgb=np.zeros((n, 4, 4, 3), np.float32),
                           alpha=None, background=None)


@pytest.mark.parametrize("idx, message", [
    ([], "views: no training views"),
    ([0, 2], "views: view index out of range [0, 2)"),
    ([-1], "views: view index out of range [0, 2)"),
])
def test_ray_batch_source_from_scene_refuses_bad_view_indices(idx, message):
    # Catches: from_scene's empty or out-of-range index check deleted, or ``> n`` for ``>= n`` (index n).
    with pytest.raises(InputError, match="^" + re.escape(message) + "$"):
        RayBatchSource.from_scene(_scene(), idx, MODEL)


def test_ray_batch_source_from_scene_accepts_the_first_and_last_views():
    # Catches: the range check made ``idx.min() < 1`` or ``idx.max() >= n - 1``.
    assert len(RayBatchSource.from_scene(_scene(), [0, 1], MODEL)) == 2 * 16


# ---------------------------------------------------------------------------------------------------------
# loop.py


def test_background_color_refuses_an_unknown_policy():
    # Catches: background_color's final raise deleted (an unknown policy would give None, no background).
    with pytest.raises(ValueError, match="^unknown background policy 'grey'$"):
        background_color("grey", torch.Generator(), "cpu")
    assert [background_color(p, torch.Generator(), "cpu").shape for p in ("white", "black", "random")] == [(3,)] * 3


def test_train_field_refuses_rays_that_are_not_a_ray_batch_source():
    # Catches: train_field's RayBatchSource type check deleted (a dict of rays would fail later, elsewhere).
    with pytest.raises(ValueError, match="^rays must be a RayBatchSource, got dict$"):
        train_field(_Field(), _source(), TrainConfig(steps=1), progress=False)


def test_train_field_refuses_rays_on_another_device_than_the_config():
    # Catches: train_field's device-type check deleted (rays on one device, generator and field on another).
    meta = {k: v.to("meta") for k, v in _source().items() if k != "model"}
    rays = RayBatchSource(**meta, model=MODEL)
    with pytest.raises(ValueError, match="^rays are on meta, the config asks for cpu$"):
        train_field(_Field(), rays, TrainConfig(steps=1), progress=False)


# ---------------------------------------------------------------------------------------------------------
# evaluate.py, metrics.py


@pytest.mark.parametrize("shape", [(16,), (1, 3, 4), (2, 2, 4, 4)])
def test_render_views_refuses_poses_that_are_not_n_by_4_by_4(shape):
    # Catches: render_views' c2w shape check deleted.
    with pytest.raises(ValueError, match="^" + re.escape(f"c2w must be (n, 4, 4), got {shape}") + "$"):
        render_views(_Field(), MODEL, K4, np.zeros(shape))


@pytest.mark.parametrize("z_shape, acc_shape", [((4,), (4,)), ((2, 2), (2, 3)), ((1, 2, 2), (1, 2, 2))])
def test_depth_to_color_refuses_bad_shapes(z_shape, acc_shape):
    # Catches: depth_to_color's ``ndim != 2`` or ``acc.shape != z_depth.shape`` condition dropped.
    with pytest.raises(ValueError, match="^" + re.escape(f"z_depth and acc must both be (H, W), got {z_shape}, "
                                                         f"{acc_shape}") + "$"):
        depth_to_color(np.ones(z_shape), np.ones(acc_shape))
    assert depth_to_color(np.ones((1, 1)), np.ones((1, 1))).shape == (1, 1, 3)


def test_evaluate_refuses_no_test_views():
    # Catches: evaluate's empty test_idx check deleted (a mean over no views would be NaN).
    with pytest.raises(ValueError, match="^no test views$"):
        evaluate(_Field(), _scene(), [], None, MODEL, progress=False)


@pytest.mark.parametrize("shape", [(4,), (4, 4, 2), (4, 4, 4), (1, 4, 4, 3)])
@pytest.mark.parametrize("metric", [mse, psnr])
def test_metrics_refuse_images_that_are_not_h_w_or_h_w_3(metric, shape):
    # Catches: metrics._pair's image-shape check deleted (or one of its allowed channel counts changed).
    with pytest.raises(ValueError, match="^" + re.escape(f"expected (H, W) or (H, W, 3) images, got {shape}") + "$"):
        metric(np.zeros(shape), np.zeros(shape))


@pytest.mark.parametrize("shape", [(11, 11), (11, 11, 1), (11, 11, 3)])
def test_metrics_accept_h_w_and_one_or_three_channels(shape):
    # Catches: the channel check refusing (H, W, 1) or (H, W, 3), or the ndim check refusing (H, W).
    assert mse(np.zeros(shape), np.full(shape, 0.5)) == 0.25
    assert psnr(np.zeros(shape), np.full(shape, 0.5)) == pytest.approx(10 * np.log10(4))
    assert ssim(np.zeros(shape), np.zeros(shape)) == pytest.approx(1.0)
