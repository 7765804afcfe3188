"""benchmarks/research_fit.py: environment overrides reach the fit and are recorded in metrics.json."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _module():
    spec = importlib.util.spec_from_file_location("research_fit", ROOT / "benchmarks" / "research_fit.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_overrides_from_env_parse_and_refuse():
    mod = _module()
    assert mod.overrides_from_env({}) == ({}, {}, None)
    env = {"SENERF_ST": '{"lambda_prior": 0.05}', "SENERF_STUDENT": '{"steps": 3}', "SENERF_KEEP_KNOWN": "2"}
    assert mod.overrides_from_env(env) == ({"lambda_prior": 0.05}, {"steps": 3}, 2)
    for bad in ({"SENERF_ST": "[1]"}, {"SENERF_STUDENT": "3"}, {"SENERF_KEEP_KNOWN": "-1"}):
        with pytest.raises(ValueError):
            mod.overrides_from_env(bad)


def test_overrides_reach_the_run(tmp_path, monkeypatch):
    import senerf.cli as cli
    import senerf.selftrain.controller as controller
    from senerf.procedural.export import export_blender_scene
    from senerf.selftrain import LazyViewFeatures

    mod = _module()
    # install() replaces these two module attributes; monkeypatch puts them back afterwards
    monkeypatch.setattr(cli, "_selftrain_available", cli._selftrain_available)
    monkeypatch.setattr(controller, "known_view_features", controller.known_view_features)
    scene = export_blender_scene(tmp_path / "tiny", n_train=5, n_val=0, n_test=2, width=16, height=16, seed=0)
    env = {"SENERF_ST": '{"lambda_prior": 0.05}', "SENERF_STUDENT": '{"steps": 6}', "SENERF_KEEP_KNOWN": "1"}
    out = tmp_path / "run"
    assert mod.main([str(scene), "--protocol", "all", "--iterations", "1", "--steps", "8", "--batch-rays", "64",
                     "--samples", "8", "--resolution", "8", "--features", "daisy", "--quiet", "--out", str(out)],
                    environ=env) == 0
    from senerf.selftrain import make_feature_extractor

    known = controller.known_view_features(make_feature_extractor("vgg19"), np.zeros((3, 16, 16, 3), np.float32))
    assert isinstance(known, LazyViewFeatures) and known.keep == 1
    config = json.loads((out / "metrics.json").read_text())["config"]
    assert config["selftrain"]["lambda_prior"] == 0.05 and config["selftrain"]["features"] == "daisy"
    assert config["student"]["steps"] == 6 and config["train"]["steps"] == 8
