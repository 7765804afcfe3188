"""metrics.json's document helpers (senerf.train.record)."""

from __future__ import annotations


def test_finished_metrics_reads_a_run_through_the_iteration_asked_for(tmp_path):
    import json

    from senerf.train import finished_metrics

    assert finished_metrics(tmp_path) is None                          # no metrics.json
    (tmp_path / "metrics.json").write_text("{not json")
    assert finished_metrics(tmp_path) is None
    (tmp_path / "metrics.json").write_text(json.dumps({"iterations": []}))
    assert finished_metrics(tmp_path, 0) is None                       # written before iteration 0 finished
    doc = {"iterations": [{"iteration": 0}, {"iteration": 1}]}
    (tmp_path / "metrics.json").write_text(json.dumps(doc))
    assert finished_metrics(tmp_path, 0) == doc and finished_metrics(tmp_path, 1) == doc
    assert finished_metrics(tmp_path, 2) is None                       # iteration 2 not finished
    (tmp_path / "metrics.json").write_text(json.dumps([1, 2]))
    assert finished_metrics(tmp_path) is None                          # not a metrics document
