"""The scene-driven model choice and the fields it builds (senerf/train/model.py): the camera box and plane
resolution by hand, the background policy, NDC, the density scaling of boxes far from one unit wide, overrides,
and the scenes it refuses."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from senerf.config import ModelConfig
from senerf.data import Scene
from senerf.errors import InputError
from senerf.geometry import Intrinsics, pose_from_spherical
from senerf.train import (NERF_FREQS, NERF_HIDDEN, NERF_LAYERS, build_field, camera_aabb, choose_model,
                          make_occupancy, nerf_description)

LEGO_FOV_DEG = math.degrees(0.6911112070083618)  # NeRF Synthetic camera_angle_x


def _ring(center, radius, n=6):
    return np.stack([pose_from_spherical(a, e, radius, center=center)
                     for a, e in zip(np.linspace(0, 300, n), np.linspace(10, 60, n))])


def _scene(kind="object", alpha=True, n=6, width=20, height=None, radius=4.031, near=None, background=None) -> Scene:
    """``n`` cameras ``radius`` from the origin looking at it (lego's ring), or forward-facing ones along +z;
    black RGBA (or RGB) images."""
    height = width if height is None else height
    intr = Intrinsics.from_fov(LEGO_FOV_DEG, width, height)
    if kind == "object":
        c2w = _ring(np.zeros(3), radius, n)
    else:
        c2w = np.tile(np.eye(4), (n, 1, 1))
        c2w[:, 0, 3] = np.linspace(-0.1, 0.1, n)
    return Scene(name="t", root=Path("."), rgb=np.zeros((n, height, width, 3), np.float32),
                 alpha=np.ones((n, height, width), np.float32) if alpha else None, intrinsics=intr,
                 intrinsics_all=(intr,) * n, c2w=c2w.astype(np.float64), splits={"train": np.arange(n)}, kind=kind,
                 near=near, far=None, image_paths=tuple(Path(f"{i}.png") for i in range(n)), background=background)


def _choose(scene, overrides=None, lines=None, idx=None):
    return choose_model(scene, np.arange(scene.n_images) if idx is None else idx, overrides,
                        echo=(lambda s: None) if lines is None else lines.append)


def _scaled(scene: Scene, factor: float) -> Scene:
    c2w = scene.c2w.copy()
    c2w[:, :3, 3] *= factor
    return dataclasses.replace(scene, c2w=c2w)


def _width(model: ModelConfig) -> float:
    return float(np.ptp(np.asarray(model.aabb), axis=0).max())


def test_camera_aabb_half_size_by_hand():
    # Catches: a margin other than 1.05, the full field of view instead of its half, no clamp keeping the
    # cameras outside the box.  Six cameras at distance 4 around (1, 2, 3), all looking at it:
    # fov 40 deg: half = 4 tan(20 deg) 1.05 = 4 * 0.36397023 * 1.05 = 1.5286750;
    # fov 120 deg: 4 tan(60 deg) 1.05 = 7.27 > 0.95 * 4 / sqrt(3) = 2.1939310, which wins.
    c = np.array([1.0, 2.0, 3.0])
    box, dist, centre = camera_aabb(_ring(c, 4.0), 40.0)
    np.testing.assert_allclose(centre, c, atol=1e-9)
    assert dist == pytest.approx(4.0, rel=1e-9)
    np.testing.assert_allclose(box, [c - 1.5286750, c + 1.5286750], atol=1e-6)
    box, _, _ = camera_aabb(_ring(c, 4.0), 120.0)
    np.testing.assert_allclose(box, [c - 2.1939310, c + 2.1939310], atol=1e-6)
    for shape in [(4, 4), (1, 3, 4), (2, 4, 4, 1)]:
        with pytest.raises(ValueError, match="c2w"):
            camera_aabb(np.zeros(shape), 40.0)


def test_an_object_scene_gets_a_box_centred_where_the_cameras_look_and_says_so():
    lines = []
    model = _choose(_scene(), lines=lines)
    box = np.asarray(model.aabb)
    assert np.allclose(box[0], -box[1], atol=0.02)           # centred on the point the cameras look at
    assert 1.4 < box[1, 0] < 1.6                              # lego: cameras at 4.03, fov 39.6 deg
    assert not model.ndc and model.near is None and model.occupancy_resolution > 0
    assert model.field == "kplanes" and model.density_shift == 0.0
    assert any("aabb" in line for line in lines) and all(line.startswith("model: ") for line in lines)
    # the box scales with the camera distance
    near_box, far_box = (_width(_choose(_scene(radius=r))) for r in (2.0, 8.0))
    assert far_box == pytest.approx(4 * near_box, rel=0.02)


def test_a_forward_facing_scene_is_fitted_in_ndc_without_a_grid():
    model = _choose(_scene(kind="forward_facing", alpha=False, near=4 / 3))
    assert model.ndc and model.ndc_near == pytest.approx(1.0) and model.occupancy_resolution == 0
    assert model.near is None and model.frame_origin == (0.0, 0.0, 0.0)


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
    model = _choose(_scene(kind=kind, alpha=False, width=width, near=1.0 if kind != "object" else None))
    assert model.resolution == expect


def test_the_box_uses_the_narrower_field_of_view():
    # Catches: camera_aabb given the wider (horizontal) field of view of a landscape image.  30 x 20 image,
    # square pixels: tan(fov_y / 2) = 10 / f with f = 15 / tan(fov_x / 2); half = d tan(fov_y / 2) 1.05.
    scene = _scene(width=30, height=20, alpha=False)
    half = 4.031 * (10.0 / scene.intrinsics.fy) * 1.05
    assert _width(_choose(scene)) == pytest.approx(2 * half, abs=2.5e-3)


@pytest.mark.parametrize("background,name", [((1.0, 1.0, 1.0), "white"), ((0.0, 0.0, 0.0), "black")])
def test_the_background_policy_follows_how_the_images_were_loaded(background, name):
    # Catches: the load-time background ignored (RGBA images then trained on random colours, though their
    # transparent pixels are already the background colour), white and black swapped, only one of the two set;
    # straight RGBA not trained on random colours and evaluated on white; RGB not rendered over black.
    model = _choose(_scene(background=background))
    assert (model.train_background, model.eval_background) == (name, name)
    straight = _choose(_scene())
    assert (straight.train_background, straight.eval_background) == ("random", "white")
    rgb = _choose(_scene(alpha=False))
    assert (rgb.train_background, rgb.eval_background) == ("black", "black")


@pytest.mark.parametrize("background", [(0.5, 0.5, 0.5), (1.0, 1.0, 0.0), (0.0, 0.0, 1e-3)])
def test_images_composited_onto_another_colour_are_refused_naming_the_background(background):
    # Catches: a grey (or almost black) load-time background taken as black or white (a colour the photos do not
    # have); an RGB scene refused for a background it was never composited onto.
    with pytest.raises(InputError) as err:
        _choose(_scene(background=background))
    assert err.value.field == "background"
    rgb = _choose(_scene(background=background, alpha=False))
    assert (rgb.train_background, rgb.eval_background) == ("black", "black")


def test_a_small_box_starts_denser_by_one_over_its_width():
    # Catches: the small-box density shift with the wrong sign.  A box s < 1 unit wide starts 1/s times
    # denser per unit length, so the shift is -ln(s) > 0 (cameras at 0.2: s = 2 * 0.2 tan(fov/2) 1.05 = 0.151);
    # the NeRF field has no density shift and gets none.
    lines = []
    model = _choose(_scene(radius=0.2), lines=lines)
    width = _width(model)
    assert 0.1 < width < 0.2
    assert model.density_shift == pytest.approx(-math.log(width), rel=1e-9) and model.occupancy_threshold == 0.1
    assert any("scaled by" in line for line in lines)
    lines = []
    nerf = _choose(_scene(radius=0.2), {"field": "nerf"}, lines=lines)
    assert nerf.density_shift == 0.0 and not any("scaled by" in line for line in lines)


def test_a_wide_box_scales_densities_and_the_occupancy_threshold_to_a_four_unit_one():
    # A scene 10x its unit started 10x more opaque and the grid's absolute threshold emptied it.  Boxes 1-4
    # units wide (lego's 3.02) are fitted as they are.
    base = _choose(_scene())
    width = _width(base)
    assert 1.0 < width < 4.0 and base.density_shift == 0.0 and base.occupancy_threshold == 0.1
    for factor in (10.0, 1000.0):
        model = _choose(_scaled(_scene(), factor))
        w = _width(model)
        assert w == pytest.approx(width * factor, rel=1e-3)
        assert model.density_shift == pytest.approx(-math.log(w / 4.0))
        assert model.occupancy_threshold == pytest.approx(0.1 * 4.0 / w)
        nerf = _choose(_scaled(_scene(), factor), {"field": "nerf"})
        assert nerf.density_shift == 0.0 and nerf.occupancy_threshold == pytest.approx(0.1 * 4.0 / w)
    # the box scaled for is the one fitted: an aabb override's, not the cameras'; a value given is kept
    cube = lambda half: ((-half,) * 3, (half,) * 3)   # noqa: E731
    own = _choose(_scaled(_scene(), 10.0), {"aabb": cube(1.5)})
    assert own.density_shift == 0.0 and own.occupancy_threshold == 0.1
    wide = _choose(_scene(), {"aabb": cube(50.0)})
    assert wide.density_shift == pytest.approx(-math.log(25.0)) and wide.occupancy_threshold == pytest.approx(0.004)
    given = _choose(_scene(), {"aabb": cube(50.0), "density_shift": 0.5})
    assert given.density_shift == 0.5 and given.occupancy_threshold == pytest.approx(0.004)
    given = _choose(_scene(), {"aabb": cube(50.0), "occupancy_threshold": 0.3})
    assert given.occupancy_threshold == 0.3 and given.density_shift == pytest.approx(-math.log(25.0))


def test_the_grid_keeps_a_fog_of_one_optical_depth_at_any_scale():
    # A fog ball of optical depth 5 across its radius (density 5 / r, r a quarter of the box) occupies the same
    # cells whatever the unit; with an absolute threshold it vanished at 100x.
    from senerf.fields import RadianceField

    def fog_fraction(factor: float) -> float:
        model = _choose(_scaled(_scene(), factor))
        box = np.asarray(model.aabb)
        radius = _width(model) / 4.0
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


def test_overrides_win_and_are_reported():
    lines = []
    model = _choose(_scene(), {"n_samples": 17, "view_dependent": False, "aabb": ((-1, -1, -1), (1, 1, 1))},
                    lines=lines)
    assert (model.n_samples, model.view_dependent, model.aabb[1]) == (17, False, (1.0, 1.0, 1.0))
    for key in ("n_samples", "view_dependent", "aabb"):
        assert any(key in line and "override" in line for line in lines), key
    with pytest.raises(InputError) as err:
        _choose(_scene(), {"n_sample": 3})
    assert err.value.field == "overrides"


@pytest.mark.parametrize("overrides, field", [
    ({"aabb": "box"}, "aabb"), ({"aabb": (1, 2, 3)}, "aabb"), ({"aabb": None}, "aabb"),
    ({"aabb": ((1, -1, -1), (-1, 1, 1))}, "aabb"), ({"aabb": ((0, 0, 0), (float("nan"), 1, 1))}, "aabb"),
    ({"n_samples": 0}, "n_samples"), ({"field": "nerf", "resolution": 16}, "resolution"),
    ({"field": "nerf", "hidden": 16}, "hidden"),
], ids=["word", "flat", "none", "inverted", "nan", "no-samples", "nerf-resolution", "nerf-hidden"])
def test_a_bad_override_is_refused_naming_its_setting(overrides, field):
    # Catches: a malformed box override read for its width before the check (a TypeError, or math.log of a
    # non-positive width, instead of the InputError naming aabb); a K-Planes setting given to the NeRF field
    # (which has no such setting) silently ignored.
    with pytest.raises(InputError) as err:
        _choose(_scene(), overrides)
    assert err.value.field == field and "\n" not in str(err.value)


def test_the_k_planes_settings_apply_to_the_k_planes_field():
    for key in ("resolution", "hidden"):
        assert getattr(_choose(_scene(), {key: 16}), key) == 16


def test_the_nerf_field_is_the_one_its_model_lines_describe():
    # Catches: `field nerf` printing the K-Planes plane resolution it does not have, or a NeRF field built
    # other than nerf_description says.
    lines = []
    model = _choose(_scene(), {"field": "nerf"}, lines=lines)
    assert any(line.startswith("model: field") and nerf_description() in line for line in lines)
    assert not any(line.startswith("model: resolution") for line in lines)
    field = build_field(model, seed=0, steps=40)
    linears = [m for m in field.trunk if isinstance(m, torch.nn.Linear)]
    assert field.n_freqs == NERF_FREQS and len(linears) == NERF_LAYERS
    assert all(m.out_features == NERF_HIDDEN for m in linears)
    assert nerf_description().startswith(f"{NERF_LAYERS} layers x {NERF_HIDDEN}, {NERF_FREQS} frequency bands")
    kplanes = []
    _choose(_scene(), lines=kplanes)
    assert any(line.startswith("model: resolution") for line in kplanes)


def test_build_field_anneals_nerf_over_a_quarter_of_the_steps():
    # Catches: build_field giving NeRF an annealing length other than steps // 4 (400 steps -> 100).
    field = build_field(ModelConfig(field="nerf", aabb=((-1, -1, -1), (1, 1, 1))), seed=0, steps=400)
    assert field.anneal_steps == 100
    # step 50 of 100 with 10 bands: eta = 10 * 50 / 100 = 5 -> bands 0..4 on, 5..9 off
    np.testing.assert_allclose(field.set_progress(50).numpy(), [1.0] * 5 + [0.0] * 5, atol=1e-7)


def test_build_field_is_seeded_and_built_in_the_model_frame():
    # Catches: the initialisation drawn from the global generator (two runs of one seed differ), or the field's
    # box the world box instead of the model frame's (a scene far from the origin would miss every point).
    model = ModelConfig(aabb=((1e6 - 1, -1, -1), (1e6 + 1, 1, 1)), resolution=8, multires=(1,), n_features=4)
    a, b, c = build_field(model, seed=3), build_field(model, seed=3), build_field(model, seed=4)
    assert all(torch.equal(a.state_dict()[k], b.state_dict()[k]) for k in a.state_dict())
    assert not torch.equal(a.state_dict()["table"], c.state_dict()["table"])
    assert torch.equal(a.aabb, torch.tensor(model.field_aabb, dtype=a.aabb.dtype))


def test_one_camera_has_a_box_and_cameras_at_one_centre_are_refused():
    # Catches: the parallax check run on a single camera (its spread is 0, so every one-view scene was refused);
    # two cameras at one centre (a tripod pan: no depth) accepted.
    model = _choose(_scene(n=1), idx=[0])
    box = np.asarray(model.aabb)
    assert np.isfinite(box).all() and np.all(box[1] > box[0])
    still = _scene(n=2)
    still.c2w[1, :3, 3] = still.c2w[0, :3, 3]
    with pytest.raises(InputError) as err:
        _choose(still)
    assert err.value.field == "camera positions"


def test_a_field_of_view_too_narrow_for_a_box_is_refused_naming_the_intrinsics():
    # camera_angle_x 1e-300 (or fl_x 1e308) rounded the box to zero width and math.log(0) raised a traceback
    scene = _scene()
    tiny = Intrinsics(1e302, 1e302, 10.0, 10.0, 20, 20)
    with pytest.raises(InputError) as err:
        _choose(dataclasses.replace(scene, intrinsics=tiny, intrinsics_all=(tiny,) * scene.n_images))
    assert err.value.field == "camera intrinsics"


def test_no_training_views_are_refused():
    with pytest.raises(InputError) as err:
        choose_model(_scene(), [], echo=lambda s: None)
    assert err.value.field == "train_idx"
