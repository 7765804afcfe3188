"""Branches of senerf/selftrain/controller.py the rest of the suite never ran: ``reliability_mask_quality`` (the
benchmarks' mask figures), and the run folder holding a teacher checkpoint of another format or a damaged
scene-files record."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import senerf.geometry
from senerf.errors import InputError
from senerf.selftrain import SelfTrainConfig
from senerf.selftrain import controller as controller_mod

H, W = 2, 3

# Two held-out views (scene indices 3 and 1, in that order) of 2 x 3 pixels, each pixel given as
# (teacher opacity, similarity, teacher colour, ground-truth colour).  Opacity 0.1 is background (below the
# opacity threshold 0.5: not counted).  'unified' weights are sigmoid(16 (s - 0.7)): reliable (> 0.5) iff s > 0.7,
# so 0.72 is (weight 0.58) and 0.68 is not (0.42).  Ground truth: mean |clip(teacher) - gt| < 0.1.
_VIEW_3 = [[(0.9, 0.90, 0.55, 0.5),    # predicted, right (err 0.05)          -> TP
            (0.9, 0.72, 0.80, 0.5),    # predicted (0.58), wrong (err 0.3)     -> FP
            (0.9, 0.68, 0.55, 0.5)],   # not predicted (0.42), right          -> FN
           [(0.9, 0.20, 0.80, 0.5),    # not predicted, wrong                  -> TN
            (0.1, 0.90, 0.55, 0.5),    # background: not counted
            (0.9, 0.95, 1.20, 1.0)]]   # predicted, right once clipped to 1    -> TP
_VIEW_1 = [[(0.9, 0.85, 0.80, 0.5),    # predicted, wrong                      -> FP
            (0.9, 0.10, 0.55, 0.5),    # not predicted, right                  -> FN
            (0.9, 0.30, 0.00, 0.5)],   # not predicted, wrong                  -> TN
           [(0.9, 0.99, 0.50, 0.5),    # predicted, right                      -> TP
            (0.1, 0.20, 0.80, 0.5),    # background: not counted
            (0.9, 0.80, 0.70, 0.5)]]   # predicted, wrong (err 0.2)            -> FP
# by hand: TP 3, FP 3, FN 2, TN 2 over 10 foreground pixels
EXPECTED = dict(tp=3, fp=3, fn=2, tn=2, precision=3 / 6, recall=3 / 5, fpr=3 / 5, gt_reliable_rate=5 / 10,
                predicted_reliable_rate=6 / 10)


def _canned_quality(monkeypatch, eval_idx=(3, 1), train_idx=(0, 2)):
    """``reliability_mask_quality`` on a 5-view stand-in scene whose held-out views 3 and 1 are ``_VIEW_3`` and
    ``_VIEW_1``: renders handed in, ``view_similarity`` returning the canned similarities view by view."""
    from senerf.selftrain.reliability import ViewSimilarity

    views = np.array([_VIEW_3, _VIEW_1], np.float32)            # (2, H, W, 4)
    acc, sims, teacher, truth = (views[..., j] for j in range(4))
    calls = iter(range(2))

    def canned_similarity(feats, z, opacity, *args, opacity_threshold, **kwargs):
        i = next(calls)
        return ViewSimilarity(sims[i], np.zeros((1, H, W), np.float32), np.zeros((1, H, W), bool),
                              np.asarray(opacity) >= opacity_threshold)

    monkeypatch.setattr(controller_mod, "view_similarity", canned_similarity)
    ks = tuple(senerf.geometry.Intrinsics.from_fov(f, W, H) for f in (40.0, 45.0, 50.0, 55.0, 60.0))
    c2w = np.stack([np.eye(4)] * 5)
    c2w[:, 0, 3] = np.arange(5.0)                                # tells the views apart
    rgb = np.random.default_rng(0).uniform(0.0, 1.0, (5, H, W, 3)).astype(np.float32)   # the known views: noise
    rgb[3], rgb[1] = truth[0, ..., None], truth[1, ..., None]
    scene = SimpleNamespace(intrinsics=ks[0], intrinsics_all=ks, c2w=c2w, rgb=rgb, alpha=None)
    m = len(train_idx)
    known = dict(acc=np.ones((m, H, W), np.float32), z_depth=np.ones((m, H, W), np.float32))
    pseudo = dict(acc=acc, z_depth=np.ones((2, H, W), np.float32),
                  rgb=np.repeat(teacher[..., None], 3, axis=-1))
    cfg = SelfTrainConfig(features="daisy", threshold="unified", beta=16.0, empty_opacity=0.0)
    extractor = lambda images: np.zeros((images.shape[0], H, W, 2), np.float32)  # noqa: E731
    return controller_mod.reliability_mask_quality(
        None, None, None, scene, list(train_idx), eval_idx, extractor, cfg, 0.15, max_error=0.1,
        known_features=np.zeros((m, H, W, 2), np.float32), renders=(known, pseudo)), scene


def test_mask_quality_counts_a_case_known_by_hand(monkeypatch):
    # Catches: 'unified' weights counted reliable above 0 instead of 0.5, the teacher colour not clipped before the
    # ground-truth comparison, background pixels counted (region dropped), predicted and truth swapped, the
    # ground truth taken from other views than eval_idx (or in another order), the rates computed over all pixels.
    (quality, labels), scene = _canned_quality(monkeypatch)
    for key, value in EXPECTED.items():
        assert quality[key] == pytest.approx(value, abs=1e-12), key
    # the labels are those of the held-out cameras, each with its own intrinsics
    np.testing.assert_array_equal(labels.c2w, scene.c2w[[3, 1]])
    assert labels.intrinsics == (scene.intrinsics_all[3], scene.intrinsics_all[1])


def test_eval_views_among_the_known_ones_are_refused(monkeypatch):
    # Catches: the overlap check dropped (a known view scored against its own photo), or made on the wrong arrays.
    for eval_idx in ([3, 2], 2, [0]):
        with pytest.raises(ValueError, match="eval_idx must not contain known views"):
            _canned_quality(monkeypatch, eval_idx=eval_idx)
    _canned_quality(monkeypatch, eval_idx=[3, 1], train_idx=[0, 4])   # disjoint: accepted


def test_mask_quality_on_a_tiny_teacher_matches_a_count_from_its_labels(tiny_scene, tiny_teacher):
    # Catches: the real path (teacher renders and DAISY features of the held-out views) scoring other pixels than
    # its labels: the RGBA ground truth composited on another colour than the teacher's white, weights > 0 as the
    # predicted mask, the rates over the background.
    from senerf.selftrain import make_feature_extractor

    scene = tiny_scene
    train_idx, model, res = tiny_teacher
    held = np.setdiff1d(np.arange(scene.n_images), train_idx)[:2]
    assert scene.alpha is not None and model.eval_background == "white"
    cfg = SelfTrainConfig(features="daisy", threshold="unified", empty_opacity=0.0, opacity_threshold=0.3)
    quality, labels = controller_mod.reliability_mask_quality(
        res.field, res.occupancy, model, scene, train_idx, held, make_feature_extractor("daisy"), cfg, 0.15,
        max_error=0.15)
    a = scene.alpha[held][..., None]
    gt = scene.rgb[held] * a + (1.0 - a)                       # straight colour on white, written out
    truth = np.abs(np.clip(labels.rgb, 0, 1) - gt).mean(-1) < 0.15
    pred, fg = labels.weights > 0.5, labels.foreground
    counts = dict(tp=int(np.sum(pred & truth & fg)), fp=int(np.sum(pred & ~truth & fg)),
                  fn=int(np.sum(~pred & truth & fg)), tn=int(np.sum(~pred & ~truth & fg)))
    assert {k: quality[k] for k in counts} == counts
    assert min(counts.values()) > 0 and fg.sum() < fg.size   # every cell filled, and a background left out
    assert quality["precision"] == pytest.approx(counts["tp"] / (counts["tp"] + counts["fp"]))
    assert quality["recall"] == pytest.approx(counts["tp"] / (counts["tp"] + counts["fn"]))
    assert quality["fpr"] == pytest.approx(counts["fp"] / (counts["fp"] + counts["tn"]))
    assert quality["gt_reliable_rate"] == pytest.approx(truth[fg].mean())
    assert quality["predicted_reliable_rate"] == pytest.approx(pred[fg].mean())
    # soft weights between 0 and 0.5 exist, so the 0.5 cut is what is being counted
    assert np.any(fg & (labels.weights > 0) & (labels.weights <= 0.5))


# ---------------------------------------------------------------------------------------------------------
# Run folders that cannot be resumed: refused naming the file, before anything trains


def _run(out: Path, monkeypatch, scene_files=None):
    """``run_selftraining`` of a 4-view in-memory scene into ``out`` (iterations 0), its training replaced by a
    stop: only what it does before the teacher trains runs."""
    from senerf.data import Scene
    from senerf.train import ModelConfig, TrainConfig

    class TrainingStarted(Exception):
        pass

    def stop(*args, **kwargs):
        raise TrainingStarted

    monkeypatch.setattr(controller_mod, "train_field", stop)
    k = senerf.geometry.Intrinsics.from_fov(40.0, 8, 6)
    c2w = np.stack([senerf.geometry.pose_from_spherical(a, 20.0, 4.0) for a in (0.0, 40.0, 80.0, 120.0)])
    scene = Scene(name="s", root=out.parent, rgb=np.zeros((4, 6, 8, 3), np.float32), alpha=None, intrinsics=k,
                  intrinsics_all=(k,) * 4, c2w=c2w, image_paths=tuple(f"{i}.png" for i in range(4)))
    model = ModelConfig(resolution=8, multires=(1,), n_features=4, n_samples=8, occupancy_resolution=0)
    with pytest.raises(TrainingStarted):
        controller_mod.run_selftraining(scene, [0, 1, 2], [3], model, TrainConfig(steps=2, batch_rays=16),
                                        SelfTrainConfig(iterations=0), out, progress=False, echo=lambda s: None,
                                        scene_files=scene_files)


def test_a_teacher_checkpoint_of_another_format_is_refused(tmp_path, monkeypatch):
    # Catches: the format check dropped (a senerf-fit training checkpoint in checkpoints/teacher.pt was then
    # refused as "a run with different settings", or loaded as a teacher), or its message not naming the file.
    from senerf.train import save_checkpoint

    out = tmp_path / "run"
    teacher = out / "checkpoints" / "teacher.pt"
    teacher.parent.mkdir(parents=True)
    for state in (dict(format="senerf-train-1", step=2), dict(iteration=0)):
        save_checkpoint(teacher, state)
        with pytest.raises(InputError, match="holds a checkpoint of another format; use --overwrite") as err:
            _run(out, monkeypatch)
        assert err.value.file == str(teacher)
    teacher.unlink()
    _run(out, monkeypatch)   # without it the run starts (and stops at its first training step)


@pytest.mark.parametrize("content", [b"{not json", b"\xff\xfe\x00bad", b"[1, 2]", b'"a string"', b"null"],
                         ids=["not-json", "not-utf8", "a-list", "a-string", "null"])
def test_a_damaged_scene_files_record_is_refused_naming_it(tmp_path, monkeypatch, content):
    # Catches: a JSON / UTF-8 decoding error escaping as a crash (not an InputError), a record that is JSON but not
    # an object reaching changed_files (AttributeError), the message naming another file.
    out = tmp_path / "run"
    record = out / "checkpoints" / "scene_files.json"
    record.parent.mkdir(parents=True)
    record.write_bytes(content)
    with pytest.raises(InputError, match="is not a scene-files record of senerf; use --overwrite") as err:
        _run(out, monkeypatch, scene_files={"0.png": "0123456789abcdef"})
    assert err.value.file == str(record)
    record.write_text('{"0.png": "0123456789abcdef"}')   # a record of the same files: the run goes on
    _run(out, monkeypatch, scene_files={"0.png": "0123456789abcdef"})
