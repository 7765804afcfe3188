"""Configs and the scene-driven model choice (senerf/train/config.py)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import torch
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
    for device in ("tpu", "cudafoo", "cuda:", "cuda:01", "cuda:-1"):   # before: any 'cuda...' passed
        with pytest.raises(InputError, match="'cpu', 'cuda' or 'cuda:N'"):
            TrainConfig(device=device)
    for device in ("cpu", "cuda", "cuda:0", "cuda:12"):   # a name torch accepts (GPUs are checked at use)
        assert TrainConfig(device=device).device == device
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


def _ring(center, radius, n=6):
    return np.stack([pose_from_spherical(a, e, radius, center=center)
                     for a, e in zip(np.linspace(0, 300, n), np.linspace(10, 60, n))])


def test_camera_aabb_half_size_by_hand():
    # Catches: a margin other than 1.05, the full field of view instead of its half, no clamp keeping the
    # cameras outside the box.  Six cameras at distance 4 around (1, 2, 3), all looking at it:
    # fov 40 deg: half = 4 tan(20 deg) 1.05 = 4 * 0.36397023 * 1.05 = 1.5286750;
    # fov 120 deg: 4 tan(60 deg) 1.05 = 7.27 > 0.95 * 4 / sqrt(3) = 2.1939310, which wins.
    from senerf.train import camera_aabb

    c = np.array([1.0, 2.0, 3.0])
    box, dist, centre = camera_aabb(_ring(c, 4.0), 40.0)
    np.testing.assert_allclose(centre, c, atol=1e-9)
    assert dist == pytest.approx(4.0, rel=1e-9)
    np.testing.assert_allclose(box, [c - 1.5286750, c + 1.5286750], atol=1e-6)
    box, _, _ = camera_aabb(_ring(c, 4.0), 120.0)
    np.testing.assert_allclose(box, [c - 2.1939310, c + 2.1939310], atol=1e-6)


def _scene_wh(width, height, radius=4.031, kind="object"):
    intr = Intrinsics.from_fov(LEGO_FOV_DEG, width, height)
    n = 6
    if kind == "object":
        c2w = _ring(np.zeros(3), radius, n)
    else:
        c2w = np.tile(np.eye(4), (n, 1, 1))
        c2w[:, 0, 3] = np.linspace(-0.1, 0.1, n)
    return Scene(name="t", root=Path("."), rgb=np.zeros((n, height, width, 3), np.float32), alpha=None,
                 intrinsics=intr, intrinsics_all=(intr,) * n, c2w=c2w, splits={"train": np.arange(n)}, kind=kind,
                 near=1.0 if kind != "object" else None, far=None,
                 image_paths=tuple(Path(f"{i}.png") for i in range(n)))


@pytest.mark.parametrize("width,kind,expect", [
    (180, "object", 96),           # box ~1.05 W = 189 px wide: 189 / 2 / 8 = 11.81 -> 12 -> 96
    (400, "object", 128),          # 420 / 16 = 26.25 -> 208, capped at 128
    (20, "object", 32),            # 21 / 16 = 1.3 -> 8, raised to 32
    (180, "forward_facing", 88),   # NDC: max(H, W) = 180: 180 / 16 = 11.25 -> 11 -> 88
])
def test_plane_resolution_is_half_the_box_pixels_rounded_to_8(width, kind, expect):
    # Catches: the resolution floored instead of rounded (88 for 189 px), the /2 dropped, the [32, 128] clamp
    # widened.  The object box is 2 d tan(fov/2) 1.05 wide at the camera distance d, so with
    # fx = W / (2 tan(fov/2)) it covers 1.05 W pixels.
    model = choose_model(_scene_wh(width, width, kind=kind), np.arange(6), echo=lambda s: None)
    assert model.resolution == expect


def test_box_uses_the_narrower_field_of_view():
    # Catches: camera_aabb given the wider (horizontal) field of view of a landscape image.  30 x 20 image,
    # square pixels: tan(fov_y / 2) = 10 / f with f = 15 / tan(fov_x / 2); half = d tan(fov_y / 2) 1.05.
    scene = _scene_wh(30, 20)
    model = choose_model(scene, np.arange(6), echo=lambda s: None)
    f = scene.intrinsics.fy
    half = 4.031 * (10.0 / f) * 1.05
    assert model.aabb[1][0] - model.aabb[0][0] == pytest.approx(2 * half, abs=2.5e-3)


def test_small_box_gets_a_positive_density_shift_of_minus_log_width():
    # Catches: the small-box density shift with the wrong sign.  A box s < 1 unit wide starts 1/s times
    # denser per unit length, so the shift is -ln(s) > 0 (cameras at 0.2: s = 2 * 0.2 tan(fov/2) 1.05 = 0.151).
    model = choose_model(_scene_wh(20, 20, radius=0.2), np.arange(6), echo=lambda s: None)
    width = model.aabb[1][0] - model.aabb[0][0]
    assert 0.1 < width < 0.2
    assert model.density_shift == pytest.approx(-math.log(width), rel=1e-9)
    assert choose_model(_scene(), np.arange(6), echo=lambda s: None).density_shift == 0.0


def test_build_field_anneals_nerf_over_a_quarter_of_the_steps():
    # Catches: build_field giving NeRF an annealing length other than steps // 4 (400 steps -> 100).
    from senerf.train import build_field

    model = ModelConfig(field="nerf", aabb=((-1, -1, -1), (1, 1, 1)))
    field = build_field(model, seed=0, steps=400)
    assert field.anneal_steps == 100
    # step 50 of 100 with 10 bands: eta = 10 * 50 / 100 = 5 -> bands 0..4 on, 5..9 off
    np.testing.assert_allclose(field.set_progress(50).numpy(), [1.0] * 5 + [0.0] * 5, atol=1e-7)


def test_the_nerf_field_is_the_one_its_model_lines_describe():
    # Before, `--field nerf` printed the K-Planes plane resolution it does not have (so at 64a97d5).
    from senerf.train import build_field, nerf_description

    lines = []
    model = choose_model(_scene(), np.arange(6), {"field": "nerf"}, echo=lines.append)
    assert "model: field = 'nerf' (override): NeRF MLP, 4 layers x 128, 10 frequency bands annealed over the first " \
           "quarter of each training" in lines
    assert not any(line.startswith("model: resolution") for line in lines)
    field = build_field(model, seed=0, steps=40)
    linears = [m for m in field.trunk]
    assert field.n_freqs == 10 and len(linears) == 4 and all(m.out_features == 128 for m in linears)
    assert nerf_description().startswith("4 layers x 128, 10 frequency bands")
    kplanes = []
    choose_model(_scene(), np.arange(6), echo=kplanes.append)
    assert any(line.startswith("model: resolution: base") for line in kplanes)
    assert "model: field: K-Planes (the paper's main backbone)" in kplanes


@pytest.mark.parametrize("key", ["resolution", "hidden"])
def test_choose_model_refuses_k_planes_settings_for_the_nerf_field(key):
    with pytest.raises(InputError, match=f"{key} sets the K-Planes field; the NeRF field has no such setting"):
        choose_model(_scene(), np.arange(6), {"field": "nerf", key: 16}, echo=lambda s: None)
    assert getattr(choose_model(_scene(), np.arange(6), {key: 16}, echo=lambda s: None), key) == 16   # K-Planes


def test_a_field_of_view_too_narrow_for_a_box_is_refused_naming_the_intrinsics():
    # camera_angle_x 1e-300 (or fl_x 1e308) rounded the box to zero width and math.log(0) raised a
    # "math domain error" traceback (so at 2e4108c)
    scene = _scene()
    tiny = Intrinsics(1e302, 1e302, 10.0, 10.0, 20, 20)
    narrow = dataclasses.replace(scene, intrinsics=tiny, intrinsics_all=(tiny,) * scene.n_images)
    with pytest.raises(InputError, match="the cameras see a box of half size 0 .*check the focal length") as info:
        choose_model(narrow, np.arange(6))
    assert info.value.field == "camera intrinsics"


def _scaled(scene: Scene, factor: float) -> Scene:
    c2w = scene.c2w.copy()
    c2w[:, :3, 3] *= factor
    return dataclasses.replace(scene, c2w=c2w)


def test_a_wide_box_scales_densities_and_the_occupancy_threshold_to_a_four_unit_one():
    # a scene 10x its unit trained to 6.5 dB against 15.2 (a review's measurement): its field started 10x more
    # opaque and the grid's absolute threshold emptied it (so at d8df175). Boxes 1-4 units wide (lego's 3.02)
    # are unchanged, and so is the small-box rule below 1 unit.
    from senerf.train.config import DENSITY_PLATEAU_WIDTH

    base = choose_model(_scene(), np.arange(6), echo=lambda s: None)
    width = float(np.ptp(np.asarray(base.aabb), axis=0).max())
    assert 1.0 < width < DENSITY_PLATEAU_WIDTH and base.density_shift == 0.0 and base.occupancy_threshold == 0.1
    for factor in (10.0, 1000.0):
        lines = []
        model = choose_model(_scaled(_scene(), factor), np.arange(6), echo=lines.append)
        w = float(np.ptp(np.asarray(model.aabb), axis=0).max())
        assert w == pytest.approx(width * factor, rel=1e-3)
        assert model.density_shift == pytest.approx(-math.log(w / 4.0))
        assert model.occupancy_threshold == pytest.approx(0.1 * 4.0 / w)
        assert any("densities and the occupancy threshold scaled by 1/" in line for line in lines)
        nerf = choose_model(_scaled(_scene(), factor), np.arange(6), {"field": "nerf"}, echo=lambda s: None)
        assert nerf.density_shift == 0.0 and nerf.occupancy_threshold == pytest.approx(0.1 * 4.0 / w)
    lines = []
    small = choose_model(_scaled(_scene(), 0.1), np.arange(6), echo=lines.append)
    w = float(np.ptp(np.asarray(small.aabb), axis=0).max())
    assert small.density_shift == pytest.approx(-math.log(w), rel=1e-3) and small.occupancy_threshold == 0.1
    assert any(f"initial densities scaled by 1/{w:.3g} for a box" in line for line in lines)   # said, as wide boxes'
    # the NeRF field has no density shift: none recorded for it (run.json's identity held an unused 1.19)
    lines = []
    small_nerf = choose_model(_scaled(_scene(), 0.1), np.arange(6), {"field": "nerf"}, echo=lines.append)
    assert small_nerf.density_shift == 0.0 and not any("scaled by" in line for line in lines)
    # the box fitted is the one scaled for: an --aabb override's, not the cameras' (a review, so at 3cbad99)
    cube = lambda half: ((-half,) * 3, (half,) * 3)   # noqa: E731
    own = choose_model(_scaled(_scene(), 10.0), np.arange(6), {"aabb": cube(1.5)}, echo=lambda s: None)
    assert own.density_shift == 0.0 and own.occupancy_threshold == 0.1
    wide = choose_model(_scene(), np.arange(6), {"aabb": cube(50.0)}, echo=lambda s: None)
    assert wide.density_shift == pytest.approx(-math.log(25.0)) and wide.occupancy_threshold == pytest.approx(0.004)
    given = choose_model(_scene(), np.arange(6), {"aabb": cube(50.0), "density_shift": 0.5}, echo=lambda s: None)
    assert given.density_shift == 0.5 and given.occupancy_threshold == pytest.approx(0.004)   # an override is kept
    given = choose_model(_scene(), np.arange(6), {"aabb": cube(50.0), "occupancy_threshold": 0.3}, echo=lambda s: None)
    assert given.occupancy_threshold == 0.3 and given.density_shift == pytest.approx(-math.log(25.0))   # this one too


def test_the_grid_keeps_a_fog_of_one_optical_depth_at_any_scale():
    # a fog ball of optical depth 5 across its radius (density 5 / r, r a quarter of the box) occupies the same
    # cells whatever the unit; with the absolute threshold it vanished at 100x (so at d8df175)
    from senerf.fields import RadianceField
    from senerf.train import make_occupancy

    def fog_fraction(factor: float) -> float:
        model = choose_model(_scaled(_scene(), factor), np.arange(6), echo=lambda s: None)
        box = np.asarray(model.aabb)
        radius = float(np.ptp(box, axis=0).max()) / 4.0
        centre = torch.tensor(box.mean(axis=0) - np.asarray(model.frame_origin), dtype=torch.float32)

        class Fog(RadianceField):
            def density(self, xyz):
                return ((xyz - centre).norm(dim=-1) < radius).float() * (5.0 / radius)

            def forward(self, xyz, dirs):
                return self.density(xyz), torch.full((xyz.shape[0], 3), 0.5)

        grid = make_occupancy(model, "cpu")
        grid.update(Fog())
        return grid.occupied_fraction()

    unit = fog_fraction(1.0)
    assert unit >= 4.0 / 3.0 * math.pi / 64.0   # at least the ball's share of the box (dilated by the grid)
    for factor in (10.0, 100.0):
        assert fog_fraction(factor) == pytest.approx(unit, abs=0.01), factor
