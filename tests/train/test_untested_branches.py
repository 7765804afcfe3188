"""Branches of senerf/train (config.py, evaluate.py, loop.py) the rest of the suite never ran: images composited
at load time, malformed box overrides, one camera, a damaged evaluation record, a checkpoint that is not a
training one, and a loss that stops being finite."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from senerf.data import Scene
from senerf.errors import InputError
from senerf.geometry import Intrinsics, look_at, pose_from_spherical
from senerf.train import ModelConfig, RayBatchSource, TrainConfig, build_field, choose_model, train_field

LEGO_FOV_DEG = math.degrees(0.6911112070083618)  # NeRF Synthetic camera_angle_x


def _scene(n=6, background=None, alpha=True, size=20) -> Scene:
    """``n`` cameras 4.031 units from the origin looking at it (lego's ring), black RGBA (or RGB) images."""
    intr = Intrinsics.from_fov(LEGO_FOV_DEG, size, size)
    c2w = np.stack([pose_from_spherical(a, e, 4.031) for a, e in zip(np.linspace(0, 300, n), np.linspace(10, 60, n))])
    return Scene(name="t", root=Path("."), rgb=np.zeros((n, size, size, 3), np.float32),
                 alpha=np.ones((n, size, size), np.float32) if alpha else None, intrinsics=intr,
                 intrinsics_all=(intr,) * n, c2w=c2w.astype(np.float64), splits={"train": np.arange(n)},
                 kind="object", image_paths=tuple(Path(f"{i}.png") for i in range(n)), background=background)


# ---------------------------------------------------------------------------------------------------------
# choose_model


@pytest.mark.parametrize("background,name", [((1.0, 1.0, 1.0), "white"), ((0.0, 0.0, 0.0), "black")])
def test_images_composited_at_load_time_train_and_evaluate_on_that_colour(background, name):
    # Catches: the load-time background ignored (RGBA images then trained on random colours, though their
    # transparent pixels are already the background colour), white and black swapped, only one of the two set.
    lines = []
    model = choose_model(_scene(background=background), np.arange(6), echo=lines.append)
    assert (model.train_background, model.eval_background) == (name, name)
    assert (f"model: train_background: images composited onto {name} at load time: trained and evaluated on "
            f"{name}") in lines
    # straight RGBA colour (no load-time background): random while training, white at evaluation
    straight = choose_model(_scene(), np.arange(6), echo=lambda s: None)
    assert (straight.train_background, straight.eval_background) == ("random", "white")


@pytest.mark.parametrize("background", [(0.5, 0.5, 0.5), (1.0, 1.0, 0.0), (0.0, 0.0, 1e-3)])
def test_images_composited_onto_another_colour_are_refused_naming_the_background(background):
    # Catches: a grey (or almost black) load-time background taken as black or white (a colour the photos do not
    # have), or refused as another error than an InputError naming 'background'.
    with pytest.raises(InputError, match=r"images were composited onto \(.*\) at load time") as err:
        choose_model(_scene(background=background), np.arange(6), echo=lambda s: None)
    assert err.value.field == "background"
    # an RGB scene keeps its colour whatever a background says (nothing was composited: black)
    rgb = choose_model(_scene(background=background, alpha=False), np.arange(6), echo=lambda s: None)
    assert (rgb.train_background, rgb.eval_background) == ("black", "black")


@pytest.mark.parametrize("aabb", [(1, 2, 3), None, ((0.0, 0.0, 0.0),), {0: (0, 0, 0)}, "box",
                                  ((0, 0), (1, 1, 1)), (("a", 0, 0), (1, 1, 1))],
                         ids=["flat", "none", "one-row", "dict", "string", "ragged", "word"])
def test_a_malformed_box_override_is_named_by_the_model_check(aabb):
    # Catches: the width of a malformed aabb override read without the guard (a TypeError / IndexError / KeyError
    # traceback instead of the InputError of ModelConfig's check), and ModelConfig's own conversion letting
    # NumPy's error out ("could not convert string to float: 'box'" as a ValueError, a dict as a TypeError
    # reported under 'overrides'; so at 3317e00).
    with pytest.raises(InputError, match="must be \\(\\(xmin,ymin,zmin\\),\\(xmax,ymax,zmax\\)\\)") as err:
        choose_model(_scene(), np.arange(6), {"aabb": aabb}, echo=lambda s: None)
    assert err.value.field == "aabb"
    with pytest.raises(InputError) as err:
        ModelConfig(aabb=aabb)
    assert err.value.field == "aabb"


@pytest.mark.parametrize("aabb", [((1, -1, -1), (-1, 1, 1)), ((1, -1, -1), (1, 1, 1)),
                                  ((0, 0, 0), (float("nan"), 1, 1))], ids=["inverted", "flat", "nan"])
def test_a_box_override_of_no_positive_width_gets_no_density_scaling(aabb):
    # Catches: _scale_densities' early return for a width that is not positive and finite dropped (math.log of
    # -2 or 0 raised a "math domain error" ValueError before ModelConfig could name aabb).
    with pytest.raises(InputError, match="with max > min") as err:
        choose_model(_scene(), np.arange(6), {"aabb": aabb}, echo=lambda s: None)
    assert err.value.field == "aabb"


def test_one_camera_is_not_refused_for_want_of_parallax():
    # Catches: the parallax check run on a single camera (its spread is 0, so "all stand at one camera centre"
    # refused every one-view scene); the check is for two or more cameras.
    model = choose_model(_scene(n=1), [0], echo=lambda s: None)
    box = np.asarray(model.aabb)
    assert np.isfinite(box).all() and np.all(box[1] > box[0])
    still = _scene(n=2)                                  # two cameras at one centre are refused
    still.c2w[1, :3, 3] = still.c2w[0, :3, 3]
    with pytest.raises(InputError, match="all stand at one camera centre"):
        choose_model(still, [0, 1], echo=lambda s: None)


# ---------------------------------------------------------------------------------------------------------
# evaluate: a damaged resume record is ignored


K = Intrinsics(20.0, 25.0, 7.0, 6.5, 14, 12)


def _eval_setup():
    rng = np.random.default_rng(0)
    c2w = np.stack([look_at(np.array([4 * math.cos(a), 4 * math.sin(a), 1.0]), np.zeros(3))
                    for a in np.linspace(0, 2, 3)])
    scene = Scene(name="e", root=".", rgb=rng.random((3, 12, 14, 3)).astype(np.float32), alpha=None, intrinsics=K,
                  intrinsics_all=(K,) * 3, c2w=c2w, image_paths=tuple(f"{i}.png" for i in range(3)))
    model = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), near=1.0, far=3.0, resolution=8, multires=(1,),
                        n_features=4, n_samples=8, occupancy_resolution=0, train_background="black",
                        eval_background="black")
    return scene, model, build_field(model, seed=0).eval()


def _damaged_records(digest: str) -> dict:
    ok = {"digest": digest, "views": {"0": [20.0, 0.5]}, "seconds": 3.0}
    return {
        "not-json": b"{\"digest\": ",
        "not-utf8": b"\xff\xfe\x00\x01",
        "a-list": b"[1, 2]",
        "no-views": json.dumps({"digest": digest}).encode(),
        "views-a-list": json.dumps({**ok, "views": [[20.0, 0.5]]}).encode(),
        "view-a-number": json.dumps({**ok, "views": {"0": 20.0}}).encode(),
        "view-too-short": json.dumps({**ok, "views": {"0": [20.0]}}).encode(),
        "view-not-numbers": json.dumps({**ok, "views": {"0": ["a", "b"]}}).encode(),
        "key-not-a-number": json.dumps({**ok, "views": {"first": [20.0, 0.5]}}).encode(),
        "seconds-null": json.dumps({**ok, "seconds": None}).encode(),
        "seconds-a-word": json.dumps({**ok, "seconds": "soon"}).encode(),
    }


@pytest.mark.parametrize("case", list(_damaged_records("d")))
def test_a_damaged_evaluation_record_is_ignored_and_every_view_rendered_again(tmp_path, render_spy, case):
    # Catches: one of the errors a damaged record raises (JSON, UTF-8, a list for a dict, a missing key, a value of
    # the wrong type) escaping _finished_views' guard as a crash, or a damaged record's figures or seconds kept.
    from senerf.train.evaluate import evaluate, evaluation_digest

    scene, model, field = _eval_setup()
    test_idx = [2, 0]
    whole = evaluate(field, scene, test_idx, None, model, progress=False)
    digest = evaluation_digest(field, None, model, scene, test_idx)
    record = tmp_path / "eval.json"
    record.write_bytes(_damaged_records(digest)[case])
    render_spy.calls = 0
    res = evaluate(field, scene, test_idx, None, model, progress=False, resume=record)
    assert render_spy.calls == 2                      # both views rendered again
    assert res["per_view"] == whole["per_view"] and res["seconds_before"] == 0.0
    rewritten = json.loads(record.read_text())        # and the record replaced by a sound one
    assert rewritten["digest"] == digest and sorted(rewritten["views"]) == ["0", "1"]
    # the sound record of the same evaluation is used: nothing rendered
    render_spy.calls = 0
    assert evaluate(field, scene, test_idx, None, model, progress=False, resume=record)["per_view"] \
        == whole["per_view"]
    assert render_spy.calls == 0


# ---------------------------------------------------------------------------------------------------------
# train_field

MODEL = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), resolution=8, multires=(1,), n_features=4, n_samples=8,
                    occupancy_resolution=8, train_background="random", eval_background="white")


def _rays(n: int = 256) -> RayBatchSource:
    from senerf.train import ray_aabb_bounds

    g = torch.Generator().manual_seed(0)
    o = torch.cat([torch.rand(n, 2, generator=g) * 1.6 - 0.8, torch.full((n, 1), -3.0)], dim=1)
    d = torch.nn.functional.normalize(torch.tensor([0.0, 0.0, 1.0]) + 0.1 * torch.randn(n, 3, generator=g), dim=-1)
    near, far = ray_aabb_bounds(o, d, MODEL.aabb)
    return RayBatchSource(o, d, torch.rand(n, 3, generator=g), None, near, far, MODEL)


def _cfg(**kw) -> TrainConfig:
    return TrainConfig(**{**dict(steps=9, batch_rays=32, lr=0.02, warmup_steps=2, occupancy_every=3,
                                 occupancy_warmup=2, checkpoint_every=3, seed=3), **kw})


@pytest.mark.parametrize("state", [dict(format="senerf-selftrain-1", iteration=0), dict(step=3), dict(format=1)],
                         ids=["selftrain-teacher", "no-format", "format-a-number"])
def test_a_checkpoint_that_is_not_a_training_one_is_refused_naming_it(tmp_path, state):
    # Catches: the format check dropped (a self-training teacher in the training checkpoint's place was then
    # called "a different training configuration", or a KeyError once its fingerprint matched), its file unnamed.
    from senerf.train import save_checkpoint

    path = tmp_path / "c.pt"
    save_checkpoint(path, state)
    with pytest.raises(InputError, match="not a senerf training checkpoint") as err:
        train_field(build_field(MODEL, seed=0), _rays(), _cfg(), checkpoint=path, progress=False)
    assert err.value.file == str(path)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_a_loss_that_is_not_finite_stops_training_naming_the_step(tmp_path, bad):
    # Catches: the finiteness check dropped (training went on, saving a NaN field), made for NaN only (inf
    # passed), the step named 0-based (5 instead of 6), or the bad field checkpointed before the check.
    def extra(field, step, generator, occupancy):
        # a constant: no gradient, so only step index 5 (the 6th, a logged one with log_every 3) is bad
        return torch.tensor(bad if step == 5 else 0.0), {}

    ckpt = tmp_path / "c.pt"
    with pytest.raises(RuntimeError, match=rf"loss became {bad} at step 6; check the ray bounds and lr"):
        train_field(build_field(MODEL, seed=0), _rays(), _cfg(), extra_loss=extra, checkpoint=ckpt, progress=False,
                    log_every=3)
    assert torch.load(ckpt, weights_only=True)["step"] == 3   # the last checkpoint is the sound one before it
    # the same loss at a step that is not logged is not looked at, and training ends (the loss is finite again)
    res = train_field(build_field(MODEL, seed=0), _rays(), _cfg(), extra_loss=extra, progress=False, log_every=4)
    assert all(math.isfinite(h["loss"]) for h in res.history)
