"""benchmarks/research_fit.py: environment overrides reach the fit and are recorded as its settings."""

from __future__ import annotations

import json

import numpy as np
import pytest


def test_overrides_from_env_parse_and_refuse(load_script):
    mod = load_script("research_fit")
    assert mod.overrides_from_env({}) == ({}, {}, None)
    env = {"SENERF_ST": '{"lambda_prior": 0.05}', "SENERF_TRAIN": '{"tv_weight": 0.3}', "SENERF_KEEP_KNOWN": "2"}
    assert mod.overrides_from_env(env) == ({"lambda_prior": 0.05}, {"tv_weight": 0.3}, 2)
    for bad in ({"SENERF_ST": "[1]"}, {"SENERF_TRAIN": "3"}, {"SENERF_KEEP_KNOWN": "-1"}):
        with pytest.raises(ValueError):
            mod.overrides_from_env(bad)


def test_overrides_reach_the_run(tmp_path, monkeypatch, load_script):
    import senerf.pipeline as pipeline
    import senerf.selftrain.loop as loop
    from senerf.procedural.export import export_blender_scene
    from senerf.selftrain import LazyViewFeatures, VGG19Features

    mod = load_script("research_fit")
    # install() replaces these two module attributes; monkeypatch puts them back afterwards
    monkeypatch.setattr(pipeline, "fit", pipeline.fit)
    monkeypatch.setattr(loop, "known_view_features", loop.known_view_features)
    scene = export_blender_scene(tmp_path / "tiny", n_train=5, n_val=0, n_test=2, width=16, height=16, seed=0)
    env = {"SENERF_ST": '{"lambda_prior": 0.05}', "SENERF_TRAIN": '{"tv_weight": 0.3}', "SENERF_KEEP_KNOWN": "1"}
    out = tmp_path / "run"
    assert mod.main([str(scene), "--protocol", "all", "--iterations", "1", "--steps", "8", "--batch-rays", "64",
                     "--samples", "8", "--resolution", "8", "--quiet", "--out", str(out)],
                    environ=env) == 0
    known = loop.known_view_features(VGG19Features(), np.zeros((3, 16, 16, 3), np.float32))
    assert isinstance(known, LazyViewFeatures) and known.keep == 1
    settings = json.loads((out / "run.json").read_text())["settings"]
    assert settings["selftrain"]["lambda_prior"] == 0.05
    assert settings["train"]["tv_weight"] == 0.3 and settings["train"]["steps"] == 8
