"""``metrics.json``'s header and rows, and the host a fit's figures depend on (senerf/train/record.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

import senerf.fields.ckernel as ckernel
from senerf import __version__
from senerf.data import Scene
from senerf.geometry import Intrinsics
from senerf.memory import cpu_model
from senerf.train import PHASES, host_record, iteration_row, metrics_document, phase_breakdown, timed

EV = {"psnr": 20.0, "ssim": 0.5, "lpips": "unavailable", "avg": "unavailable", "per_view": {"psnr": [20.0],
                                                                                            "ssim": [0.5]}}


def test_metrics_document_is_json_with_the_views_by_index_and_photo():
    # Catches: NumPy indices left in the document (json.dumps refuses them), the image size given as (W, H), the
    # photos not the views' own.
    k = Intrinsics(10.0, 10.0, 7.0, 5.0, 14, 10)
    scene = Scene(name="s", root=Path("."), rgb=np.zeros((4, 10, 14, 3), np.float32), alpha=None, intrinsics=k,
                  intrinsics_all=(k,) * 4, c2w=np.tile(np.eye(4), (4, 1, 1)),
                  image_paths=tuple(Path(f"img_{i}.png") for i in range(4)))
    doc = json.loads(json.dumps(metrics_document(scene, np.array([3, 1]), np.int64(2), ["senerf-fit", "s"],
                                                 {"train": {"seed": 0}})))
    assert doc["train_views"] == [3, 1] and doc["test_views"] == [2] and doc["resolution"] == [10, 14]
    assert [Path(n).stem for n in doc["train_images"]] == ["img_3", "img_1"]
    assert [Path(n).stem for n in doc["test_images"]] == ["img_2"]
    assert doc["senerf_version"] == __version__ and doc["command"] == ["senerf-fit", "s"]
    assert doc["config"] == {"train": {"seed": 0}} and doc["iterations"] == [] and doc["scene"] == "s"


def test_each_row_records_the_host_that_finished_it(monkeypatch):
    # A fit's figures depend on torch's thread count on the CPU (the float sums' order), the processor, the
    # torch and NumPy builds and which code ran K-Planes' planes; they are not repeatable on CUDA.  Every row says
    # where it was made.
    monkeypatch.setattr(ckernel, "cpu_planes_path", lambda *args, **kwargs: "pytorch")
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert host_record("cpu") == {"device": "cpu", "threads": 1, "cpu": cpu_model(), "torch": torch.__version__,
                                      "numpy": np.__version__, "kernel": "pytorch"}
        torch.set_num_threads(2)
        row = iteration_row(1, EV, 0.25, 3.0, torch.device("cpu"))
    finally:
        torch.set_num_threads(threads)
    assert row["host"]["threads"] == 2 and row["host"]["device"] == "cpu"
    assert {k: row[k] for k in ("iteration", "psnr", "ssim", "reliable_fraction", "seconds", "per_view")} == {
        "iteration": 1, "psnr": 20.0, "ssim": 0.5, "reliable_fraction": 0.25, "seconds": 3.0,
        "per_view": EV["per_view"]}
    json.dumps(row)   # torch.__version__ is a TorchVersion: stored as a plain str
    monkeypatch.setattr(ckernel, "cpu_planes_path", lambda *args, **kwargs: "compiled")
    assert host_record("cpu")["kernel"] == "compiled"
    # a GPU is named, not just "cuda" (no GPU needed to check: torch is asked for the name); no CPU kernel there
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: f"Fake GPU {torch.device(device)}")
    assert host_record("cuda:1")["device"] == "Fake GPU cuda:1" and "kernel" not in host_record("cuda:1")
    assert iteration_row(1, EV, None, 1.0, "cuda:1")["host"]["device"] == "Fake GPU cuda:1"


def test_timed_adds_each_blocks_seconds_even_when_it_raises(monkeypatch):
    clock = iter([10.0, 12.5, 20.0, 21.0, 30.0, 31.0])
    monkeypatch.setattr("senerf.train.record.time.perf_counter", lambda: next(clock))
    phases = {}
    with timed(phases, "features"):
        pass
    try:
        with timed(phases, "features"):
            raise RuntimeError
    except RuntimeError:
        pass
    assert phases == {"features": 3.5}
    with timed(None, "features"):   # no record asked for
        pass


def test_a_row_times_every_phase_and_the_breakdown_sums_them_over_iterations():
    rows = [iteration_row(0, EV, None, 130.0, phases=dict(train=120.0, evaluation=5.0), train_samples=60e6),
            iteration_row(1, EV, 0.5, 70.0, phases=dict(train=40.0, pseudo_render=10.0, features=6.0, reliability=4.0,
                                                          evaluation=5.0), train_samples=20e6)]
    assert list(rows[0]["phases"]) == list(PHASES) and rows[0]["phases"]["features"] == 0.0
    assert rows[0]["train_samples_per_s"] == 0.5e6 and rows[1]["train_samples_per_s"] == 0.5e6
    line = phase_breakdown(dict(seconds_total=200.0, iterations=rows))
    assert line == ("3.3 min: train 2.7 min (0.50 M samples/s), pseudo_render 10 s, features 6 s, reliability 4 s, "
                    "evaluation 10 s")
