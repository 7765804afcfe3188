"""What counts as a number in a setting: ``senerf.errors.is_number`` (a finite real, Python or NumPy, not a bool),
the one test every config applies, and TrainConfig / ModelConfig refusing everything else with an InputError
naming the setting (the CLI prints it as one line) while NumPy scalars and JSON ints (run.json) still pass."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from senerf.errors import InputError
from senerf.train.config import ModelConfig, TrainConfig

NAN, INF = float("nan"), float("inf")
#: not numbers: the message says so ("must be a number"), whatever the setting's range
NOT_NUMBERS = [True, False, np.True_, "0.5", "1", None, 1j, [0.5]]
#: numbers that are not finite: refused with the setting's own range message
NOT_FINITE = [NAN, INF, -INF, 10 ** 400]

#: every real-valued setting, with the values each other setting needs for it to be checked
TRAIN_REALS = {"lr": {}, "lr_final_factor": {}, "tv_weight": {}}
MODEL_REALS = {"ndc_near": {}, "near": {"far": 3.0}, "far": {"near": 0.5}, "density_shift": {},
               "occupancy_threshold": {}, "occupancy_decay": {}}
#: NumPy scalars and plain ints (what a JSON number without a point loads as) each setting accepts
GOOD = {"lr": [np.float32(0.5), np.float64(0.5), np.int64(1), 1],
        "lr_final_factor": [np.float32(0.5), np.float64(0.5), np.int64(1), 0, 1],
        "tv_weight": [np.float32(0.5), np.float64(0.5), np.int64(0), 0],
        "ndc_near": [np.float32(0.5), np.float64(0.5), np.int64(1), 1],
        "near": [np.float32(0.5), np.float64(0.5), np.int64(0), 0],
        "far": [np.float32(3.0), np.float64(3.0), np.int64(3), 3],
        "density_shift": [np.float32(-1.5), np.float64(-1.5), np.int64(-2), -2],
        "occupancy_threshold": [np.float32(0.5), np.float64(0.5), np.int64(0), 0],
        "occupancy_decay": [np.float32(0.5), np.float64(0.5), np.int64(1), 1]}


def _refused(make, name: str, value) -> InputError:
    with pytest.raises(InputError) as info:
        make(value)
    assert info.value.field == name, (name, value, str(info.value))
    assert str(info.value).startswith(f"{name}: ") and "\n" not in str(info.value)
    return info.value


def test_is_number_is_one_function_in_both_places():
    # Catches: is_number defined twice (the configs' and the distillation's checks drifting apart), or dropped
    # from senerf.selftrain.distill (callers import it from there) or from either __all__.
    import senerf.errors as errors
    import senerf.selftrain.distill as distill

    assert distill.is_number is errors.is_number
    assert "is_number" in errors.__all__ and "is_number" in distill.__all__


def test_is_number_needs_no_torch_and_no_numpy():
    # Catches: is_number moved back into a module that imports torch (senerf.errors is for torch-free loaders).
    code = ("import sys, senerf.errors as e; assert e.is_number(0.5) and not e.is_number(True); "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'numpy')); assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_is_number_values():
    # Catches: bools, strings or non-finite values counted as numbers; NumPy scalars not; an int too large for
    # a float raising OverflowError instead of answering False.
    from senerf.errors import is_number

    for value in (0, -3, 0.5, 1e308, np.float32(0.5), np.float64(-2.0), np.int64(7), np.uint8(3)):
        assert is_number(value) is True, value
    for value in NOT_NUMBERS + NOT_FINITE + [np.float64(NAN), np.float32(INF), -(10 ** 400)]:
        assert is_number(value) is False, value


@pytest.mark.parametrize("name", sorted(TRAIN_REALS))
def test_train_config_refuses_what_is_not_a_finite_number(name):
    # Catches: TrainConfig taking a bool as a real (lr=True trained at lr 1), a string failing as a TypeError
    # (a traceback, not the CLI's one line), or a NaN / infinity, under a message that does not name the field.
    def make(value):
        return TrainConfig(**{**TRAIN_REALS[name], name: value})

    for value in NOT_NUMBERS:
        assert str(_refused(make, name, value)) == f"{name}: must be a number, got {value!r}"
    for value in NOT_FINITE:
        _refused(make, name, value)


@pytest.mark.parametrize("name", sorted(MODEL_REALS))
def test_model_config_refuses_what_is_not_a_finite_number(name):
    # Catches: ModelConfig taking a bool as a real, a string failing as a TypeError, an unchecked setting
    # (density_shift took NaN, far took infinity), or a message naming the pair "near/far" or another field.
    def make(value):
        return ModelConfig(**{**MODEL_REALS[name], name: value})

    # None is near/far's "no constant bounds", refused alone as the pair's error (tests/train/test_api_edges.py)
    for value in [v for v in NOT_NUMBERS if not (v is None and name in ("near", "far"))]:
        assert str(_refused(make, name, value)) == f"{name}: must be a number, got {value!r}"
    for value in NOT_FINITE:
        _refused(make, name, value)


def test_model_config_refuses_an_aabb_value_that_is_not_a_finite_number():
    # Catches: aabb's values converted by NumPy without a check (True became 1.0 and "-1" became -1.0).
    for value in (True, np.True_, "-1", NAN, INF, 10 ** 400):
        with pytest.raises(InputError, match=r"^aabb: must be \(\(xmin,ymin,zmin\),\(xmax,ymax,zmax\)\) with max > ") \
                as info:
            ModelConfig(aabb=((value, -1, -1), (2, 1, 1)))
        assert info.value.field == "aabb"


@pytest.mark.parametrize("multires", [(1, True), (True,), (np.True_, 2), (1, 2.0), (1, "2"), "12", 3, None])
def test_model_config_refuses_multires_that_are_not_integers(multires):
    # Catches: multires passed through int() (a bool, a float or a numeric string became a scale, and a
    # number or None failed as a TypeError).
    with pytest.raises(InputError, match=r"^multires: must be positive integers, got ") as info:
        ModelConfig(multires=multires)
    assert info.value.field == "multires"


def test_model_config_takes_numpy_multires_as_plain_ints():
    # Catches: NumPy integers refused as multires, or kept as NumPy scalars (json.dumps of run.json refuses them);
    # NumPy bools taken as integers.
    cfg = ModelConfig(multires=[np.int64(1), np.int32(2), 4])
    assert cfg.multires == (1, 2, 4) and all(type(m) is int for m in cfg.multires)
    with pytest.raises(InputError, match="^multires: "):
        ModelConfig(multires=(np.True_,))


@pytest.mark.parametrize("name", sorted(TRAIN_REALS) + sorted(MODEL_REALS))
def test_numpy_numbers_and_json_ints_pass_and_numpy_bools_do_not(name):
    # Catches: a NumPy scalar (a value taken from an array) or an int (what JSON loads "lr": 1 as, in a run.json
    # or a settings file) refused, or changed (the stored run's settings and checkpoint fingerprint would no
    # longer match); a NumPy bool taken as a number.
    cls, others = (TrainConfig, TRAIN_REALS[name]) if name in TRAIN_REALS else (ModelConfig, MODEL_REALS[name])
    for value in GOOD[name]:
        cfg = cls(**{**others, name: value})
        assert getattr(cfg, name) == value and type(getattr(cfg, name)) is type(value)
    for value in (np.True_, np.False_):
        _refused(lambda v: cls(**{**others, name: v}), name, value)


def test_aabb_takes_numpy_scalars_and_arrays():
    # Catches: an aabb of NumPy scalars (choose_model's, from np.round) or a NumPy array refused by the value check;
    # NumPy bools inside it accepted.
    box = ((np.float64(-1.5), np.float32(-1), np.int64(-1)), (1.5, 1, 1))
    assert ModelConfig(aabb=box).aabb == ((-1.5, -1.0, -1.0), (1.5, 1.0, 1.0))
    assert ModelConfig(aabb=np.array([[-1, -2, -3], [1, 2, 3]], dtype=np.float32)).aabb == ((-1, -2, -3), (1, 2, 3))
    with pytest.raises(InputError, match="^aabb: "):
        ModelConfig(aabb=np.array([[False, False, False], [True, True, True]]))


@pytest.mark.parametrize("name", ["ndc", "view_dependent"])
def test_model_config_switches_are_bools(name):
    # Catches: a string such as "no" or a 0/1 taken as a switch ("no" counted as true at 7c49076); a NumPy bool
    # refused, or kept as a NumPy bool (json.dumps of run.json refuses those).
    for bad in ("no", "False", 0, 1, None, 1.0):
        with pytest.raises(InputError, match=f"^{name}: must be True or False, got "):
            ModelConfig(**{name: bad})
    for good, want in ((True, True), (False, False), (np.True_, True), (np.False_, False)):
        value = getattr(ModelConfig(**{name: good}), name)
        assert value is want


def test_aabb_takes_a_torch_tensor():
    # Catches: an aabb given as a tensor (or rows of tensors) refused because its elements are 0-d tensors, not
    # numbers (accepted at 79e2799, refused at 61dd78c); a bool tensor accepted.
    import torch

    want = ((-1.0, -2.0, -3.0), (1.0, 2.0, 3.0))
    assert ModelConfig(aabb=torch.tensor(want)).aabb == want
    assert ModelConfig(aabb=(torch.tensor(want[0]), np.array(want[1]))).aabb == want
    with pytest.raises(InputError, match="^aabb: "):
        ModelConfig(aabb=torch.tensor([[False] * 3, [True] * 3]))


def test_zero_dimensional_arrays_and_tensors_are_taken_as_their_numbers():
    # Catches: a 0-d array or tensor (what x.sum() or torch.tensor(0.5) gives) refused as "must be a number"
    # (accepted at 79e2799, refused at 61dd78c), or kept as an array (json.dumps of run.json refuses it); a 0-d
    # bool accepted as a number.
    import torch

    model = ModelConfig(near=torch.tensor(0.5), far=np.array(4.0), density_shift=np.array(-1),
                        aabb=((np.array(-1.0), torch.tensor(-1.0), -1), (1, 1, 1)), multires=torch.tensor([1, 2]),
                        view_dependent=torch.tensor(False), ndc=np.array(False))
    assert (model.near, model.far, model.density_shift, model.multires) == (0.5, 4.0, -1, (1, 2))
    assert type(model.near) is float and type(model.density_shift) is int
    assert model.view_dependent is False and model.ndc is False
    assert TrainConfig(lr=np.array(0.01)).lr == 0.01 and type(TrainConfig(lr=np.array(0.01)).lr) is float
    with pytest.raises(InputError, match="^lr: must be a number, got "):
        TrainConfig(lr=np.array(True))
    with pytest.raises(InputError, match="^tv_weight: must be a number, got "):
        TrainConfig(tv_weight=np.array([0.1]))   # one value, but not a 0-d one
    with pytest.raises(InputError, match="^view_dependent: must be True or False"):
        ModelConfig(view_dependent=torch.tensor(1))


def test_a_zero_dimensional_value_without_data_is_refused_in_one_line():
    # Catches: item() of a tensor on the "meta" device (no data) escaping as a RuntimeError (an internal error)
    # instead of the setting's one-line refusal (second review of 8fa9547).
    import torch

    with pytest.raises(InputError, match="^lr: must be a number, got "):
        TrainConfig(lr=torch.tensor(0.01, device="meta"))
