"""The run folder (senerf/runfolder.py): one identity in run.json, refusals, --overwrite's reach."""

from __future__ import annotations

import json
import re

import pytest

from senerf.errors import InputError
from senerf.runfolder import (RUN_FORMAT, checkpoint_path, finished_iterations, prepare_run_folder, read_metrics,
                              read_run, settings_differences)

RUN = dict(scene_dir="/scenes/lego", scene_files={"a.png": "01", "t.json": "02"},
           settings={"downscale": 4.0, "train": {"seed": 0, "steps": 10}, "model": {"aabb": [[0, 0, 0], [1, 1, 1]]}})


def test_a_new_folder_gets_run_json_and_the_same_run_is_resumed(tmp_path):
    out = tmp_path / "run"
    assert prepare_run_folder(out, RUN, overwrite=False) is False
    record = read_run(out)
    assert record["senerf_run"] == RUN_FORMAT and record["settings"] == RUN["settings"]
    assert prepare_run_folder(out, json.loads(json.dumps(RUN)), overwrite=False) is True


def test_another_run_is_refused_naming_the_first_difference_and_the_folder_is_untouched(tmp_path):
    out = tmp_path / "run"
    prepare_run_folder(out, RUN, overwrite=False)
    (out / "metrics.json").write_text('{"iterations": []}')
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    other = dict(RUN, settings={**RUN["settings"], "train": {"seed": 1, "steps": 11}})
    with pytest.raises(InputError, match=r"holds a different run \(train.seed: 0 in the folder, 1 now and 1 more\); "
                                         r"use --overwrite"):
        prepare_run_folder(out, other, overwrite=False)
    changed = dict(RUN, scene_files={"a.png": "ff", "t.json": "02"})
    with pytest.raises(InputError, match=r"scene files differ: a.png changed"):
        prepare_run_folder(out, changed, overwrite=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_overwrite_removes_only_what_senerf_fit_writes(tmp_path):
    out = tmp_path / "run"
    prepare_run_folder(out, RUN, overwrite=False)
    for name in ("checkpoints", "iter_0", "render"):
        (out / name).mkdir()
    (out / "metrics.json").write_text("{}")
    (out / "notes.txt").write_text("mine")
    said = []
    other = dict(RUN, settings={**RUN["settings"], "downscale": 2.0})
    assert prepare_run_folder(out, other, overwrite=True, echo=said.append) is False
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "run.json"]
    assert read_run(out)["settings"]["downscale"] == 2.0 and "removed the earlier run's" in said[0]


@pytest.mark.parametrize("content", ["{not json", '{"name": "my experiment"}'])
def test_a_folder_that_is_not_a_run_folder_is_refused_even_with_overwrite(tmp_path, content):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "data.csv").write_text("1,2")
    with pytest.raises(InputError, match="is not a senerf-fit run folder"):
        prepare_run_folder(out, RUN, overwrite=True)
    (out / "run.json").write_text(content)
    with pytest.raises(InputError, match="run.json"):
        prepare_run_folder(out, RUN, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["data.csv", "run.json"]


def test_a_run_folder_of_an_older_format_is_refused_in_one_line_and_replaced_with_overwrite(tmp_path):
    out = tmp_path / "old"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"scene_dir": "/scenes/lego", "format": "blender", "train": {}}))
    with pytest.raises(InputError) as caught:
        read_run(out)
    assert "another senerf version" in str(caught.value) and "\n" not in str(caught.value)
    with pytest.raises(InputError, match="another senerf version"):
        prepare_run_folder(out, RUN, overwrite=False)
    assert prepare_run_folder(out, RUN, overwrite=True, echo=lambda line: None) is False
    assert read_run(out)["senerf_run"] == RUN_FORMAT


def test_metrics_and_checkpoint_paths(tmp_path):
    assert read_metrics(tmp_path) is None and finished_iterations(None) == []
    (tmp_path / "metrics.json").write_text(json.dumps({"iterations": [{"iteration": 0}, {"iteration": 1}]}))
    assert finished_iterations(read_metrics(tmp_path)) == [0, 1]
    for bad, field in (([], ""), ({"iterations": [{"iteration": 1}]}, "iterations[0]"),
                       ({"iterations": [{"iteration": 0}, "x"]}, "iterations[1]")):
        (tmp_path / "metrics.json").write_text(json.dumps(bad))
        with pytest.raises(InputError, match=re.escape(f"metrics.json: {field}")):
            read_metrics(tmp_path)
    assert checkpoint_path(tmp_path, 2) == tmp_path / "checkpoints" / "iter_2_train.pt"


def test_settings_differences_names_nested_settings_one_line_each():
    assert settings_differences({"a": 1, "m": {"x": [1, 2]}}, {"a": 1, "m": {"x": [1, 3]}, "b": None}) == [
        "b: absent in the folder, null now", "m.x: [1, 2] in the folder, [1, 3] now"]
    assert settings_differences(RUN["settings"], json.loads(json.dumps(RUN["settings"]))) == []
