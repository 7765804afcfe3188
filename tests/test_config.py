"""The settings of a fit (senerf/config.py): every field refuses a bad value with an InputError naming the field and
accepts its boundary values, NumPy numbers are stored as plain Python numbers, the checks between fields, the
schedules, the presets, and the JSON round trip ``run.json`` relies on."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from senerf.config import PRESETS, ModelConfig, SelfTrainConfig, TrainConfig, config_to_dict, is_device_name
from senerf.errors import InputError

NAN, INF = float("nan"), float("inf")

#: what no integer, real, choice or flag field takes, whatever its range
NOT_INTEGERS = [1.0, 2.5, True, np.True_, "1", None, [1], NAN]
NOT_REALS = [True, False, np.True_, "0.5", None, 1j, [0.5], NAN, INF, -INF, 10 ** 400]
NOT_CHOICES = [None, 1, True, ["white"]]
NOT_FLAGS = ["no", "False", 0, 1, 1.0, None, np.True_, np.False_]

#: {config class: {field: (kind, out-of-range values, boundary values it accepts)}}; with the values of the kind
#: above, every field's rule is tried on both sides of its bounds
RULES = {
    TrainConfig: {
        "steps": ("int", [-1], [0]),
        "batch_rays": ("int", [0], [1]),
        "lr": ("real", [0.0, -0.01], [1e-9]),
        "warmup_steps": ("int", [-1], [0]),
        "lr_final_factor": ("real", [-0.01, 1.01], [0.0, 1.0]),
        "tv_weight": ("real", [-1e-6], [0.0]),
        "distortion_weight": ("real", [-1e-6], [0.0]),
        "occupancy_every": ("int", [-1], [0]),
        "occupancy_warmup": ("int", [-1], [0]),
        "checkpoint_every": ("int", [-1], [0]),
        "seed": ("int", [-1, 2 ** 63], [0, 2 ** 63 - 1]),
        "device": ("choice", ["tpu", "CPU", "cudafoo", "cuda:", "cuda:01", "cuda:-1", "cuda:0 "],
                   ["cpu", "cuda", "cuda:0", "cuda:12"]),
    },
    ModelConfig: {
        "field": ("choice", ["NeRF", "mlp"], ["kplanes", "nerf"]),
        "aabb": ("box", [], []),   # tried apart: test_a_box_is_two_corners_with_every_max_above_its_min
        "ndc": ("flag", [], [True, False]),
        "ndc_near": ("real", [0.0, -1.0], [1e-9]),
        "contract": ("flag", [], [False]),   # True needs near/far: test_a_contracted_field_needs_metric_ray_bounds
        "bound": ("box", [], []),   # tried apart: test_a_contracted_field_needs_metric_ray_bounds
        "near": ("real", [-0.1], []),   # None is "no constant bounds"; near/far are tried as a pair below
        "far": ("real", [-0.1], []),
        "resolution": ("int", [0], [1]),
        "multires": ("scales", [], []),   # tried apart: test_multires_is_a_non_empty_sequence_of_positive_integers
        "n_features": ("int", [0], [1]),
        "density_shift": ("real", [], [-2.0, 0.0, 3.5]),
        "view_dependent": ("flag", [], [True, False]),
        "hidden": ("int", [0], [1]),
        "n_samples": ("int", [0], [1]),
        "occupancy_resolution": ("int", [-1], [0]),
        "occupancy_threshold": ("real", [-1e-6], [0.0]),
        "occupancy_decay": ("real", [-0.01, 1.01], [0.0, 1.0]),
        "train_background": ("choice", ["grey", "Random"], ["random", "white", "black"]),
        "eval_background": ("choice", ["random", "grey"], ["white", "black"]),
    },
    SelfTrainConfig: {
        "iterations": ("int", [-1], [0]),
        "n_pseudo_per_input": ("int", [0], [1]),
        "pseudo_range_deg": ("real", [-1.0], [0.0]),
        "pseudo_range_step_deg": ("real", [-1.0], [0.0]),
        "seed": ("int", [-1, 2 ** 63], [0, 2 ** 63 - 1]),
        "normalize_layers": ("flag", [], [True, False]),
        "threshold": ("choice", ["topk"], ["adaptive", "fixed", "unified"]),
        "alpha0": ("real", [-0.01, 1.01], [0.0, 1.0]),
        "alpha_step": ("real", [-0.01], [0.0]),
        "fixed_tau": ("real", [-1.01, 1.01], [-1.0, 1.0]),
        "beta": ("real", [0.0], [1e-9]),
        "opacity_threshold": ("real", [0.0, 1.01], [1.0]),
        "occlusion_rel_tol": ("real", [-0.01], [0.0]),
        "empty_opacity": ("real", [-0.01, 1.01], [0.0, 0.5]),
        "batch_reliable": ("int", [0], [1]),
        "batch_prior": ("int", [0], [1]),
        "lambda_color": ("real", [-1e-9], [0.0]),
        "lambda_geometry": ("real", [-1e-9], [0.0]),
        "lambda_prior": ("real", [-1e-9], [0.0]),
        "density_distill": ("flag", [], [True, False]),
        "prior": ("flag", [], [True, False]),
        "kernel_size": ("int", [1, 2, 4], [3, 5]),
        "kernel_std": ("real", [0.0], [1e-9]),
    },
}
NOT_OF_KIND = {"int": NOT_INTEGERS, "real": NOT_REALS, "choice": NOT_CHOICES, "flag": NOT_FLAGS}
CASES = [(cls, name) for cls, rules in RULES.items() for name in rules if rules[name][0] in NOT_OF_KIND]
NUMBERS = [(cls, name) for cls, name in CASES if RULES[cls][name][0] in ("int", "real")]
#: what near or far needs beside it to be accepted
PAIRED = {"near": {"far": 3.0}, "far": {"near": 0.25}}


def _refused(make, value, field: str) -> None:
    with pytest.raises(InputError) as info:
        make(value)
    assert info.value.field == field, (field, value, str(info.value))
    assert "\n" not in str(info.value)


def test_the_rules_table_holds_every_field():
    # Catches: a field added to a config without its values tried here.
    for cls, rules in RULES.items():
        assert set(rules) == {f.name for f in dataclasses.fields(cls)}, cls.__name__


@pytest.mark.parametrize("cls, name", CASES, ids=[f"{c.__name__}.{n}" for c, n in CASES])
def test_each_field_refuses_bad_values_naming_itself_and_takes_its_boundaries(cls, name):
    # Catches: any field's rule deleted or loosened (a bool taken as a number, NaN or infinity let through, an
    # open bound for a closed one or back), a string or None failing as a TypeError traceback instead of one
    # line, or the refusal naming another field.
    kind, out_of_range, boundary = RULES[cls][name]
    for value in NOT_OF_KIND[kind] + out_of_range:
        if value is None and name in PAIRED:   # no constant bounds
            continue
        _refused(lambda v: cls(**{name: v}), value, name)
    for value in boundary:
        stored = getattr(cls(**{name: value}), name)
        assert stored == value and type(stored) is type(value), (value, stored)


@pytest.mark.parametrize("cls, name", NUMBERS, ids=[f"{c.__name__}.{n}" for c, n in NUMBERS])
def test_numpy_numbers_are_stored_as_plain_python_numbers(cls, name):
    # Catches: a NumPy scalar (a value from an array, a loop over np.arange) refused, or kept as a NumPy scalar,
    # which json.dumps of run.json refuses.
    base = {"near": 0.5, "far": 2.0}[name] if name in PAIRED else getattr(cls(), name)   # a valid value
    if RULES[cls][name][0] == "int":
        values, want = [np.int64(base), np.int32(base), np.uint16(base)], int
    else:
        values, want = [np.float32(base), np.float64(base)], float
    for value in values:
        stored = getattr(cls(**{**PAIRED.get(name, {}), name: value}), name)
        assert type(stored) is want and stored == pytest.approx(float(value), rel=1e-6), (value, stored)
        json.dumps(stored)


def test_a_json_int_for_a_real_setting_is_stored_as_a_float():
    # Catches: "lr": 1 in a settings file kept as an int (run.json would then read 1 where the run used 1.0).
    assert type(TrainConfig(lr=1).lr) is float and TrainConfig(lr=1).lr == 1.0
    assert type(ModelConfig(density_shift=-2).density_shift) is float


def test_a_choice_is_a_string_not_an_array_holding_one():
    # An array of one name passes ``value in options`` (its == answers True for the one element) and is stored
    # as an array, which json.dumps of run.json refuses.
    _refused(lambda v: ModelConfig(field=v), np.array(["nerf"]), "field")


@pytest.mark.parametrize("aabb", [(1, 2, 3), None, ((0.0, 0.0, 0.0),), {0: (0, 0, 0)}, "box", ((0, 0), (1, 1, 1)),
                                  (("a", 0, 0), (1, 1, 1)), ((True, -1, -1), (2, 1, 1)), ((NAN, 0, 0), (1, 1, 1)),
                                  ((0, 0, 0), (INF, 1, 1)), ((0, 0, 0), (10 ** 400, 1, 1)),
                                  ((1, -1, -1), (-1, 1, 1)), ((1, -1, -1), (1, 1, 1)),
                                  np.array([[False] * 3, [True] * 3])],
                         ids=["flat", "none", "one-row", "dict", "string", "ragged", "word", "bool", "nan", "inf",
                              "huge", "inverted", "no-width", "bool-array"])
def test_a_box_is_two_corners_with_every_max_above_its_min(aabb):
    # Catches: a malformed box failing as a TypeError / IndexError / NumPy error instead of the field's one line,
    # a bool or a non-finite corner taken as a number, a box of no or negative width accepted.
    _refused(lambda v: ModelConfig(aabb=v), aabb, "aabb")


def test_a_contracted_field_needs_metric_ray_bounds_and_only_it_takes_a_bound():
    # Catches: an unbounded field accepted without a near bound > 0 (its contracted bins start at ``near``) or in
    # NDC, a scene bound silently ignored by a bounded field, a malformed bound let through.
    for bad in ({}, {"near": 0.0, "far": 5.0}, {"ndc": True, "near": 0.5, "far": 5.0}):
        _refused(lambda v: ModelConfig(contract=True, **v), bad, "contract")
    _refused(lambda v: ModelConfig(bound=v), ((-1, -1, -1), (1, 1, 1)), "bound")
    _refused(lambda v: ModelConfig(contract=True, near=0.1, far=9.0, bound=v), ((1, 1, 1), (0, 0, 0)), "bound")
    ok = ModelConfig(contract=True, near=0.1, far=9.0, bound=[[-2, -2, -2], [2, 2, 2]])
    assert ok.bound == ((-2.0, -2.0, -2.0), (2.0, 2.0, 2.0)) and ok.field_bound == ok.bound


def test_a_box_of_numpy_numbers_or_an_array_is_stored_as_nested_tuples_of_floats():
    want = ((-1.5, -1.0, -1.0), (1.5, 1.0, 1.0))
    for box in (((np.float64(-1.5), np.float32(-1), np.int64(-1)), (1.5, 1, 1)), np.array(want, np.float32),
                [[-1.5, -1, -1], [1.5, 1, 1]]):
        stored = ModelConfig(aabb=box).aabb
        assert stored == want and all(type(v) is float for row in stored for v in row)


@pytest.mark.parametrize("multires", [(), (1, 0), (1, True), (True,), (np.True_, 2), (1, 2.0), (1, "2"), "12", 3,
                                      None])
def test_multires_is_a_non_empty_sequence_of_positive_integers(multires):
    # Catches: scales passed through int() (a bool, a float or a numeric string became a scale; a number or None
    # failed as a TypeError), an empty or zero scale accepted.
    _refused(lambda v: ModelConfig(multires=v), multires, "multires")
    stored = ModelConfig(multires=[np.int64(1), np.int32(2), 4]).multires
    assert stored == (1, 2, 4) and all(type(m) is int for m in stored)


@pytest.mark.parametrize("near, far", [(1.0, None), (None, 3.0), (2.0, 2.0), (3.0, 2.0)])
def test_constant_ray_bounds_come_as_a_pair_with_near_below_far(near, far):
    # Catches: near without far (or back) accepted, near == far (every ray empty) or near > far accepted.
    _refused(lambda v: ModelConfig(near=v, far=far), near, "near/far")
    cfg = ModelConfig(near=0.0, far=1e-6)
    assert (cfg.near, cfg.far) == (0.0, 1e-6)


def test_the_empty_space_threshold_stays_below_the_foreground_one():
    # Catches: a foreground pixel (opacity between the two thresholds) labelled empty space.
    _refused(lambda v: SelfTrainConfig(empty_opacity=v, opacity_threshold=0.5), 0.6, "empty_opacity")
    assert SelfTrainConfig(empty_opacity=0.5, opacity_threshold=0.5).empty_opacity == 0.5


def test_is_device_name_takes_only_cpu_cuda_and_cuda_n():
    assert [is_device_name(d) for d in ("cpu", "cuda", "cuda:0", "cuda:7", "cuda:10")] == [True] * 5
    assert not any(is_device_name(d) for d in ("gpu", "cuda:", "cuda:01", "cuda:-1", "mps", "", None, 0, b"cpu"))


def test_the_configs_are_frozen_and_a_replacement_is_checked_again():
    # Catches: a config that can be changed after its checks (frozen dropped), or dataclasses.replace skipping
    # them (a run's settings edited into a bad value).
    cfg = TrainConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.lr = 1.0
    _refused(lambda v: dataclasses.replace(cfg, lr=v), -1.0, "lr")
    _refused(lambda v: dataclasses.replace(SelfTrainConfig(), empty_opacity=v), 0.9, "empty_opacity")


def test_the_self_training_schedules_by_hand():
    # alpha = alpha0 + (K - 1) alpha_step, at most 1; range = pseudo_range_deg + (K - 1) step (paper: 0.15, 0.05)
    cfg = SelfTrainConfig()
    assert [cfg.alpha(k) for k in (1, 2, 3)] == pytest.approx([0.15, 0.20, 0.25])
    assert cfg.alpha(18) == pytest.approx(1.0) and cfg.alpha(100) == 1.0
    assert [cfg.pseudo_range(k) for k in (1, 2, 4)] == [10.0, 15.0, 25.0]
    other = SelfTrainConfig(alpha0=0.3, alpha_step=0.0, pseudo_range_deg=4.0, pseudo_range_step_deg=2.5)
    assert other.alpha(5) == 0.3 and other.pseudo_range(3) == 9.0


def test_presets_give_their_training_with_overrides_checked():
    assert set(PRESETS) == {"fast", "balanced"}
    for name, preset in PRESETS.items():
        cfg = preset.train_config()
        assert (cfg.steps, cfg.batch_rays) == (preset.steps, preset.batch_rays), name
    cfg = PRESETS["fast"].train_config(steps=3, seed=7)
    assert (cfg.steps, cfg.batch_rays, cfg.seed) == (3, PRESETS["fast"].batch_rays, 7)
    _refused(lambda v: PRESETS["balanced"].train_config(batch_rays=v), 0, "batch_rays")


@pytest.mark.parametrize("cfg", [TrainConfig(), ModelConfig(), SelfTrainConfig(),
                                 TrainConfig(seed=np.int64(5), lr=np.float32(0.5), device="cuda:1"),
                                 ModelConfig(aabb=np.array([[0, 0, 0], [1, 2, 3]]), multires=(1, 2, 4), near=0.5,
                                             far=2, ndc=True, field="nerf"),
                                 SelfTrainConfig(threshold="unified", empty_opacity=0.0, kernel_size=np.int64(5))],
                         ids=["train", "model", "selftrain", "train-numpy", "model-numpy", "selftrain-numpy"])
def test_a_config_survives_the_json_round_trip_of_run_json(cfg):
    # Catches: config_to_dict leaving a tuple, a NumPy scalar or an array in its dict (json.dumps refuses them,
    # or a reread run.json no longer equals the run's settings, and a resume is refused).
    text = json.dumps(config_to_dict(cfg))
    assert config_to_dict(cfg) == json.loads(text)   # what run.json is compared with on a rerun
    back = type(cfg)(**json.loads(text))
    assert back == cfg and json.dumps(config_to_dict(back)) == text


def test_the_model_frame_origin_is_zero_near_the_world_origin_and_absorbs_far_offsets():
    # Catches: a frame origin that moves a box holding the world origin (the model frame would then differ from
    # the world frame in the last bit), one that leaves a far box's centre more than one extent away (float32
    # model points would be coarse), field_aabb not the box minus the origin, an NDC box shifted.
    box = np.array([[-1.2, -1.0, -0.8], [1.2, 1.0, 0.8]])
    extent = box[1] - box[0]

    def model(offset):
        return ModelConfig(aabb=box + np.asarray(offset, dtype=np.float64))

    assert model((0, 0, 0)).frame_origin == (0.0, 0.0, 0.0)
    assert model((1.1, -0.9, 0.7)).frame_origin == (0.0, 0.0, 0.0)   # still holds the origin: the world frame
    assert model((0, 0, 0)).field_aabb == model((0, 0, 0)).aabb
    for offset in [(1e6, -3e5, 2e4), (-7.3e7, 0.0, 1e-3), (2.5, -2.5, 1.7)]:
        m = model(offset)
        local = np.asarray(m.field_aabb)
        np.testing.assert_allclose(local[1] - local[0], extent, atol=1e-6)
        assert np.all(np.abs(local.mean(axis=0)) < extent)
        np.testing.assert_allclose(np.asarray(m.frame_origin) + local, np.asarray(m.aabb), rtol=0, atol=1e-6)
    ndc = ModelConfig(ndc=True, aabb=((3, 3, 3), (5, 5, 5)))
    assert ndc.frame_origin == (0.0, 0.0, 0.0) and ndc.field_aabb == ndc.aabb


def test_importing_the_configs_needs_no_torch():
    # Catches: senerf.config importing torch (the command line checks its flags before torch loads).
    code = "import sys, senerf.config; assert 'torch' not in sys.modules, 'imported torch'"
    subprocess.run([sys.executable, "-c", code], check=True)
