"""Configs and the scene-driven model choice (senerf/train/config.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from senerf.data import Scene
from senerf.errors import InputError
from senerf.geometry import Intrinsics, pose_from_spherical
from senerf.train import ModelConfig, TrainConfig, choose_model, preset_train_config

LEGO_FOV_DEG = math.degrees(0.6911112070083618)  # NeRF Synthetic camera_angle_x


def _scene(kind="object", alpha=True, n=6, size=20, radius=4.031, near=None) -> Scene:
    intr = Intrinsics.from_fov(LEGO_FOV_DEG, size, size)
    if kind == "object":
        c2w = np.stack([pose_from_spherical(a, e, radius) for a, e in zip(np.linspace(0, 300, n),
                                                                            np.linspace(10, 60, n))])
    else:  # forward-facing: small translations, all looking along +z
        c2w = np.tile(np.eye(4), (n, 1, 1))
        c2w[:, 0, 3] = np.linspace(-0.1, 0.1, n)
    rgb = np.zeros((n, size, size, 3), np.float32)
    return Scene(name="t", root=Path("."), rgb=rgb, alpha=np.ones((n, size, size), np.float32) if alpha else None,
                 intrinsics=intr, intrinsics_all=(intr,) * n, c2w=c2w.astype(np.float64),
                 splits={"train": np.arange(n)}, kind=kind, near=near, far=None,
                 image_paths=tuple(Path(f"{i}.png") for i in range(n)))


def test_object_scene_gets_a_camera_derived_box_of_about_1_5(capsys):
    model = choose_model(_scene(), np.arange(6))
    box = np.asarray(model.aabb)
    assert np.allclose(box[0], -box[1], atol=0.02)           # centred on the point the cameras look at
    assert 1.4 < box[1, 0] < 1.6                              # lego: cameras at 4.03, fov 39.6 deg
    assert not model.ndc and model.near is None and model.occupancy_resolution > 0
    assert (model.train_background, model.eval_background) == ("random", "white")
    lines = capsys.readouterr().out.strip().splitlines()
    assert any("aabb" in line for line in lines) and all(line.startswith("model: ") for line in lines)


def test_box_follows_the_camera_distance():
    near_box = np.asarray(choose_model(_scene(radius=2.0), np.arange(6), echo=lambda s: None).aabb)
    far_box = np.asarray(choose_model(_scene(radius=8.0), np.arange(6), echo=lambda s: None).aabb)
    assert far_box[1, 0] == pytest.approx(4 * near_box[1, 0], rel=0.02)


def test_forward_facing_uses_ndc_and_rgb_uses_black():
    model = choose_model(_scene(kind="forward_facing", alpha=False, near=4 / 3), np.arange(6), echo=lambda s: None)
    assert model.ndc and model.ndc_near == pytest.approx(1.0) and model.occupancy_resolution == 0
    assert model.train_background == "black"


def test_overrides_win_and_are_reported(capsys):
    model = choose_model(_scene(), np.arange(6), {"n_samples": 17, "view_dependent": False,
                                                   "aabb": ((-1, -1, -1), (1, 1, 1))})
    assert (model.n_samples, model.view_dependent, model.aabb[1]) == (17, False, (1.0, 1.0, 1.0))
    out = capsys.readouterr().out
    assert "n_samples = 17 (override)" in out and "view_dependent = False (override)" in out
    with pytest.raises(InputError, match="unknown model setting"):
        choose_model(_scene(), np.arange(6), {"n_sample": 3})


def test_config_validation():
    with pytest.raises(InputError):
        TrainConfig(steps=-1)
    with pytest.raises(InputError):
        TrainConfig(device="tpu")
    with pytest.raises(InputError):
        ModelConfig(aabb=((0, 0, 0), (0, 1, 1)))
    with pytest.raises(InputError):
        ModelConfig(train_background="green")
    with pytest.raises(InputError):
        preset_train_config("turbo")
    assert preset_train_config("fast", steps=3).steps == 3


def test_settings_differences_names_each_setting_by_its_dotted_path():
    from senerf.train import settings_differences

    stored = {"train": {"seed": 0, "lr": 0.01}, "model": {"aabb": [[-1, -1, -1], [1, 1, 1]]}, "extra": {}}
    assert settings_differences(stored, stored) == []
    current = {"train": {"seed": 1, "lr": 0.01}, "model": {"aabb": [[-1, -1, -1], [1, 1, 2]]}, "extra": {}}
    # sorted by name; lists are compared whole; values written as JSON
    assert settings_differences(stored, current) == [
        "model.aabb: [[-1, -1, -1], [1, 1, 1]] in the folder, [[-1, -1, -1], [1, 1, 2]] now",
        "train.seed: 0 in the folder, 1 now"]
    # tuples and numpy scalars compare as the JSON they are written as
    assert settings_differences({"a": [1, 2], "b": 0.5}, {"a": (1, 2), "b": np.float64(0.5)}) == []
    # a setting the folder lacks: no difference only at the value registered for it
    assert settings_differences({"t": {}}, {"t": {"k": "x"}}) == ['t.k: absent in the folder, "x" now']
    assert settings_differences({"t": {"j": 1}}, {"t": {"j": 1, "k": "x"}}, added={"t.k": "x"}) == []
    assert settings_differences({"t": {"j": 1}}, {"t": {"j": 1, "k": "y"}}, added={"t.k": "x"}) == [
        't.k: absent in the folder, "y" now']
    # one the current run lacks is always a difference
    assert settings_differences({"t": {"j": 1, "k": "x"}}, {"t": {"j": 1}}, added={"t.k": "x"}) == [
        't.k: "x" in the folder, absent now']


def test_differences_text_names_the_first_and_counts_the_rest():
    from senerf.train import differences_text

    assert differences_text(["a: 1 in the folder, 2 now"]) == "a: 1 in the folder, 2 now"
    assert differences_text(["a: x", "b: y", "c: z"]) == "a: x and 2 more"


def test_docstring_examples_run():
    import doctest

    import senerf.train.config as config

    result = doctest.testmod(config)
    assert result.attempted >= 2 and result.failed == 0
