"""Tests of the labelling record (senerf.selftrain.labelrecord, ``estimate_reliability(resume=...)``).

Before it, labelling started again from its first pseudo view after any interruption, and a run resumed
inside the student's training labelled the whole iteration again before training on (~3 min an iteration at
400x400 on 2 cores, measured).  Each test here fails on that code (``resume`` did not exist).  A mutation audit
of the change (session 17) added the cases for the pseudo intrinsics and the opacity threshold in the digest, the
dtype check, the empty file, the recorded seconds, the resumed bar and the per-view intrinsics of the renders.
"""

from __future__ import annotations

import copy
import dataclasses
import shutil
import time

import numpy as np
import pytest
import torch

import senerf
import senerf.selftrain.controller as controller_mod
from senerf.selftrain import SelfTrainConfig, make_feature_extractor
from senerf.selftrain.labelrecord import LABELLED_VIEW_ARRAYS, read_labelled_view, write_labelled_view

N_PSEUDO = 4


@pytest.fixture(scope="module")
def setup(tiny_scene, tiny_teacher):
    """(scene, train_idx, model, teacher, occupancy, pseudo c2w (N_PSEUDO, 4, 4), pseudo intrinsics, cfg)."""
    train_idx, model, res = tiny_teacher
    cfg = SelfTrainConfig(features="daisy", n_pseudo_per_input=2, empty_opacity=0.0)
    c2w, k = controller_mod._sample_pseudo_poses(tiny_scene, train_idx, cfg, 1)
    return tiny_scene, train_idx, model, res.field.eval(), res.occupancy, c2w[:N_PSEUDO], k[:N_PSEUDO], cfg


def _label(setup, resume=None, teacher=None, c2w=None, extractor=None, cfg=None, alpha=0.15, scene=None, pk=None,
           **kw):
    sc, train_idx, model, field, occ, pc2w, pk0, cfg0 = setup
    cfg = cfg or cfg0
    return controller_mod.estimate_reliability(
        teacher or field, occ, model, scene or sc, train_idx, pc2w if c2w is None else c2w,
        extractor or make_feature_extractor("daisy"), cfg, alpha, pseudo_intrinsics=pk or pk0, resume=resume, **kw)


def _wider_second_view(setup):
    """The pseudo intrinsics with view 1's focal length 1.2 times longer."""
    pk = list(setup[6])
    k = pk[1]
    pk[1] = senerf.geometry.Intrinsics(k.fx * 1.2, k.fy * 1.2, k.cx, k.cy, k.width, k.height)
    return tuple(pk)


def _assert_same_labels(a, b):
    for f in dataclasses.fields(a):
        if f.name in ("seconds_recorded", "views_recorded", "intrinsics"):
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


@pytest.fixture(scope="module")
def reference(setup):
    """The labels of one uninterrupted call without a record."""
    return _label(setup)


@pytest.fixture(scope="module")
def recorded(setup, tmp_path_factory):
    """A folder holding the whole labelling's record (read-only: copy it)."""
    folder = tmp_path_factory.mktemp("labels") / "iter_1_labels"
    _label(setup, resume=folder)
    return folder


def test_a_complete_record_is_read_back_without_rendering_or_labelling(setup, reference, recorded, tmp_path,
                                                                       similarity_spy, monkeypatch):
    folder = tmp_path / "rec"
    shutil.copytree(recorded, folder)
    assert sorted(p.name for p in folder.iterdir()) == [f"view_{i:03d}.npz" for i in range(N_PSEUDO)]
    renders = []
    real_render = controller_mod.render_views
    monkeypatch.setattr(controller_mod, "render_views", lambda *a, **k: (renders.append(1), real_render(*a, **k))[1])
    asked = []
    labels = _label(setup, resume=folder, known_features=lambda: asked.append(1))
    assert similarity_spy.calls == 0 and renders == [] and asked == []   # no render, warp or known-view features
    _assert_same_labels(labels, reference)
    recorded_seconds = sum(read_labelled_view(folder, i, _digest(setup), reference.acc.shape[1:])["seconds"]
                           for i in range(N_PSEUDO))
    assert labels.seconds_recorded == pytest.approx(recorded_seconds) and labels.seconds_recorded > 0
    assert labels.views_recorded == N_PSEUDO
    assert reference.seconds_recorded == 0.0 and reference.views_recorded == 0


def _digest(setup):
    from senerf.selftrain.labelrecord import labelling_digest

    sc, train_idx, model, field, occ, pc2w, pk, cfg = setup
    return labelling_digest(field, occ, model, sc, train_idx, pc2w, pk, make_feature_extractor("daisy"),
                            cfg.opacity_threshold, cfg.occlusion_rel_tol)


def test_an_interrupted_labelling_labels_only_the_views_it_lacks(setup, reference, tmp_path, similarity_spy):
    folder = tmp_path / "rec"
    similarity_spy.stop_at = 3
    with pytest.raises(KeyboardInterrupt):
        _label(setup, resume=folder)
    assert sorted(p.name for p in folder.iterdir()) == ["view_000.npz", "view_001.npz"]
    similarity_spy.calls, similarity_spy.stop_at = 0, None
    labels = _label(setup, resume=folder)
    assert similarity_spy.calls == N_PSEUDO - 2 and labels.views_recorded == 2
    _assert_same_labels(labels, reference)


def test_a_missing_or_damaged_view_is_labelled_again(setup, reference, recorded, tmp_path, similarity_spy):
    folder = tmp_path / "rec"
    shutil.copytree(recorded, folder)
    (folder / "view_000.npz").write_bytes(b"")                                              # empty
    (folder / "view_001.npz").unlink()
    (folder / "view_002.npz").write_bytes((folder / "view_002.npz").read_bytes()[:100])   # cut short
    labels = _label(setup, resume=folder)
    assert similarity_spy.calls == 3
    _assert_same_labels(labels, reference)
    assert read_labelled_view(folder, 2, _digest(setup), reference.acc.shape[1:]) is not None   # rewritten


def _other_teacher(setup):
    other = copy.deepcopy(setup[3])
    with torch.no_grad():
        next(other.parameters()).add_(1e-3)
    return other


def _other_photo_scene(setup):
    scene, train_idx = setup[0], setup[1]
    rgb = np.array(scene.rgb, copy=True)
    rgb[int(train_idx[0]), 0, 0] = 1.0 - rgb[int(train_idx[0]), 0, 0]
    return dataclasses.replace(scene, rgb=rgb)


CHANGES = {
    "teacher": lambda s: dict(teacher=_other_teacher(s)),
    "pseudo cameras": lambda s: dict(c2w=s[5] + np.pad(np.full((3, 1), 1e-6), ((0, 1), (3, 0)))),
    "extractor": lambda s: dict(extractor=make_feature_extractor("daisy", radius=10.0)),
    "occlusion tolerance": lambda s: dict(cfg=dataclasses.replace(s[7], occlusion_rel_tol=0.2)),
    "opacity threshold": lambda s: dict(cfg=dataclasses.replace(s[7], opacity_threshold=0.4)),
    "pseudo intrinsics": lambda s: dict(pk=_wider_second_view(s)),
    "known photo": lambda s: dict(scene=_other_photo_scene(s)),
}


@pytest.mark.parametrize("change", sorted(CHANGES))
def test_a_record_of_another_labelling_is_not_used(setup, recorded, tmp_path, similarity_spy, change):
    folder = tmp_path / "rec"
    shutil.copytree(recorded, folder)   # the finished record of the reference labelling, fresh for each case
    kwargs = CHANGES[change](setup)
    expected = _label(setup, **kwargs)   # the changed labelling, no record
    similarity_spy.calls = 0
    labels = _label(setup, resume=folder, **kwargs)
    assert similarity_spy.calls == N_PSEUDO
    _assert_same_labels(labels, expected)


def test_the_threshold_is_not_part_of_the_record(setup, recorded, tmp_path, similarity_spy):
    """The record holds per-view similarities; another alpha or threshold kind reuses it and thresholds anew."""
    folder = tmp_path / "rec"
    shutil.copytree(recorded, folder)
    for cfg, alpha in ((setup[7], 0.4), (dataclasses.replace(setup[7], threshold="unified"), 0.15)):
        expected = _label(setup, cfg=cfg, alpha=alpha)
        similarity_spy.calls = 0
        labels = _label(setup, resume=folder, cfg=cfg, alpha=alpha)
        assert similarity_spy.calls == 0
        _assert_same_labels(labels, expected)


def test_the_record_holds_the_arrays_it_names(setup, reference, recorded):
    rec = read_labelled_view(recorded, 1, _digest(setup), reference.acc.shape[1:])
    for name in LABELLED_VIEW_ARRAYS:
        np.testing.assert_array_equal(rec[name], getattr(reference, name)[1], err_msg=name)
    assert read_labelled_view(recorded, 1, "0" * 64, reference.acc.shape[1:]) is None
    assert read_labelled_view(recorded, 1, _digest(setup), (5, 5)) is None


def test_a_view_of_another_dtype_is_not_read_back(setup, reference, recorded, tmp_path):
    folder = tmp_path / "rec"
    shutil.copytree(recorded, folder)
    rec = read_labelled_view(folder, 1, _digest(setup), reference.acc.shape[1:])
    write_labelled_view(folder, 1, _digest(setup), dict(rec, similarity=rec["similarity"].astype(np.float64)), 1.0)
    assert read_labelled_view(folder, 1, _digest(setup), reference.acc.shape[1:]) is None


def test_the_recorded_seconds_are_the_labelling_time(setup, tmp_path):
    folder = tmp_path / "rec"
    t0 = time.perf_counter()
    _label(setup, resume=folder)
    elapsed = time.perf_counter() - t0
    assert 0 < _label(setup, resume=folder).seconds_recorded <= elapsed


def test_each_pseudo_view_is_rendered_with_its_own_intrinsics(setup):
    """Pseudo views are rendered one at a time now: each must still get its own K (view 1's differs here)."""
    sc, train_idx, model, field, occ, pc2w, pk, cfg = setup
    ks = _wider_second_view(setup)
    labels = _label(setup, pk=ks)
    own = controller_mod.render_views(field, model, ks[1], pc2w[1], occupancy=occ)
    np.testing.assert_array_equal(labels.rgb[1], own["rgb"][0])
    assert not np.array_equal(labels.rgb[1], controller_mod.render_views(field, model, ks[0], pc2w[1],
                                                                         occupancy=occ)["rgb"][0])


def test_a_resumed_labellings_bar_starts_at_the_views_read_back(setup, recorded, tmp_path, capsys):
    folder = tmp_path / "rec"
    shutil.copytree(recorded, folder)
    (folder / f"view_{N_PSEUDO - 1:03d}.npz").unlink()
    capsys.readouterr()
    _label(setup, resume=folder, progress=True)
    err = capsys.readouterr().err
    assert f"{N_PSEUDO - 1}/{N_PSEUDO}" in err and f"{N_PSEUDO}/{N_PSEUDO}" in err
    assert f"0/{N_PSEUDO}" not in err
