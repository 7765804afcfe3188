"""Tests of senerf.selftrain.loop.run_selftraining on the tiny procedural scene: what a run writes, and that a run
killed inside an iteration, or after a finished one, or extended from a finished baseline, ends bit for bit as the
uninterrupted run (the same host, the CPU)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import senerf.selftrain.loop as loop_mod
from senerf.config import SelfTrainConfig, TrainConfig
from senerf.runfolder import checkpoint_path
from senerf.train import PHASES

QUIET = dict(progress=False, echo=lambda s: None)
RECORDED = dict(command=["senerf-fit", "scene"], config={"note": "recorded as given"})   # into metrics.json


@pytest.fixture(scope="module")
def setup(tiny_scene):
    """(scene, train_idx, test_idx, model, TrainConfig, SelfTrainConfig) of an 8-step fit with a step checkpoint
    at step 4 and one self-training iteration of 3 pseudo views."""
    from senerf.train import choose_model

    train_idx, test_idx = tiny_scene.splits["train"][:3], tiny_scene.splits["test"]
    model = choose_model(tiny_scene, train_idx, {"n_samples": 16, "resolution": 32, "occupancy_resolution": 16},
                         echo=lambda s: None)
    tcfg = TrainConfig(steps=8, batch_rays=128, warmup_steps=2, checkpoint_every=4, occupancy_warmup=4,
                       occupancy_every=4)
    cfg = SelfTrainConfig(iterations=1, n_pseudo_per_input=1, batch_reliable=64, batch_prior=16)
    return tiny_scene, train_idx, test_idx, model, tcfg, cfg


def _run(setup, out, cfg=None, **kwargs):
    scene, train_idx, test_idx, model, tcfg, cfg0 = setup
    return loop_mod.run_selftraining(scene, train_idx, test_idx, model, tcfg, cfg or cfg0, out,
                                     **{**QUIET, **kwargs})


class TrainSpy:
    """Stands in for the loop's ``train_field``: records each call's ``extra_loss`` and the step it resumed from."""

    def __init__(self):
        self.real, self.calls = loop_mod.train_field, []

    def __call__(self, *args, **kwargs):
        result = self.real(*args, **kwargs)
        self.calls.append((kwargs.get("extra_loss"), result.resumed_from))
        return result


@pytest.fixture(scope="module")
def reference(setup, tmp_path_factory):
    """The uninterrupted run: (folder, returned metrics, the TrainSpy's calls)."""
    out = tmp_path_factory.mktemp("reference") / "run"
    spy = TrainSpy()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loop_mod, "train_field", spy)
        metrics = _run(setup, out, **RECORDED)
    return out, metrics, spy.calls


def test_a_tiny_run_writes_what_the_design_promises(setup, reference):
    from senerf.selftrain import DistillationLoss
    from senerf.train import evaluate, load_field

    scene, train_idx, test_idx, model, tcfg, cfg = setup
    out, metrics, calls = reference
    doc = json.loads((out / "metrics.json").read_text())
    assert doc == json.loads(json.dumps(metrics))
    assert doc["command"] == RECORDED["command"] and doc["config"] == RECORDED["config"]
    assert doc["train_views"] == train_idx.tolist() and doc["test_views"] == test_idx.tolist()
    for key, idx in (("train_images", train_idx), ("test_images", test_idx)):   # each index's photo
        assert doc[key] == [scene.image_paths[int(i)].relative_to(scene.root).as_posix() for i in idx], key
    assert doc["resolution"] == [32, 32] and doc["scene"] == scene.name
    rows = doc["iterations"]
    assert [r["iteration"] for r in rows] == [0, 1]
    assert rows[0]["reliable_fraction"] is None and 0.0 < rows[1]["reliable_fraction"] <= 1.0
    for r in rows:
        assert np.isfinite(r["psnr"]) and r["per_view"]["psnr"] == [r["psnr"]] and len(r["per_view"]["ssim"]) == 1
        assert r["host"]["device"] == "cpu" and r["seconds"] > 0
        assert list(r["phases"]) == list(PHASES) and min(r["phases"].values()) >= 0.0
        assert sum(r["phases"].values()) <= r["seconds"] and r["phases"]["train"] > 0 and r["phases"]["evaluation"] > 0
        pseudo = cfg.batch_reliable + (cfg.batch_prior if cfg.prior and cfg.lambda_prior > 0 else 0)
        pseudo = pseudo if r["iteration"] else 0
        samples = tcfg.steps * (tcfg.batch_rays + pseudo) * model.n_samples   # a student's pseudo rays count too
        assert r["train_samples_per_s"] == pytest.approx(samples / r["phases"]["train"])
    labelling = ("pseudo_render", "features", "reliability")   # the teacher labels nothing; the student's pseudo views
    assert all(rows[0]["phases"][p] == 0.0 for p in labelling) and all(rows[1]["phases"][p] > 0 for p in labelling)
    assert doc["seconds_total"] == pytest.approx(sum(r["seconds"] for r in rows))
    # iteration 0 trains on the photos alone, iteration 1 with the distillation loss
    assert calls[0] == (None, 0) and isinstance(calls[1][0], DistillationLoss) and calls[1][1] == 0
    for k in (0, 1):
        assert (out / f"iter_{k}" / "test" / "rgb_000.png").is_file() and (out / f"iter_{k}" / "test" /
                                                                         "depth_000.png").is_file()
        # the field iteration K's checkpoint holds is the one its row scored
        field, occupancy = load_field(checkpoint_path(out, k), model, tcfg.seed, tcfg.steps)
        assert evaluate(field, scene, test_idx, None, model, occupancy=occupancy, progress=False)["psnr"] == \
            rows[k]["psnr"]
    assert not (out / "iter_0" / "pseudo").exists()
    pseudo = sorted(p.name for p in (out / "iter_1" / "pseudo").iterdir())
    assert pseudo == [f"{kind}_{i:03d}.png" for kind in ("mask", "rgb", "similarity") for i in range(3)]
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["iter_0_train.pt", "iter_1_train.pt"]


def _files(folder: Path) -> dict:
    """Every file under ``folder`` by relative name: the renders' bytes, metrics.json without its timings (seconds,
    phases, samples/s), and the checkpoints' step, field and occupancy grid (they also record the training's
    seconds)."""
    from senerf.train import load_checkpoint

    files = {}
    for path in sorted(folder.rglob("*")):
        name = path.relative_to(folder).as_posix()
        if path.suffix == ".png":
            files[name] = path.read_bytes()
        elif path.suffix == ".pt":
            state = load_checkpoint(path)
            files[name] = (state["step"], {f"{part}.{key}": value.numpy().tobytes()
                                           for part in ("field", "occupancy") for key, value in state[part].items()})
        elif path.is_file():
            files[name] = json.loads(path.read_text())
            for row in files[name]["iterations"]:
                del row["seconds"], row["phases"], row["train_samples_per_s"]
            del files[name]["seconds_total"]
    return files


class StopAfter:
    """Stands in for ``real``: calls it, and raises KeyboardInterrupt after its ``n``-th call (a kill right after
    that call, e.g. just after a step checkpoint was written)."""

    def __init__(self, real, n: int):
        self.real, self.n, self.calls = real, n, 0

    def __call__(self, *args, **kwargs):
        out = self.real(*args, **kwargs)
        self.calls += 1
        if self.calls == self.n:
            raise KeyboardInterrupt
        return out


@pytest.mark.parametrize("interruption", ["in the teacher's training", "in the labelling", "in the student's training",
                                          "in the student's evaluation", "none: a finished baseline extended"])
def test_an_interrupted_run_resumes_and_ends_bit_identical(setup, reference, tmp_path, monkeypatch, interruption,
                                                            similarity_spy, render_spy):
    """Killed runs resume from the step checkpoint inside an iteration, or after the finished iteration (the
    teacher from its checkpoint), and every file they end with equals the uninterrupted run's (renders, pseudo
    views, checkpoints bit for bit; metrics.json but for its seconds)."""
    import senerf.train.loop as train_loop

    out = tmp_path / "run"
    saves = StopAfter(train_loop.save_checkpoint, {"in the teacher's training": 1,
                                                   "in the student's training": 3}.get(interruption, 0))
    monkeypatch.setattr(train_loop, "save_checkpoint", saves)   # saves at steps 4 and 8 of each training
    similarity_spy.stop_at = 2 if interruption == "in the labelling" else None     # the 2nd of 3 pseudo views
    render_spy.stop_at = 2 if interruption == "in the student's evaluation" else None   # iteration 1's test view
    if interruption.startswith("none"):
        _run(setup, out, cfg=dataclasses.replace(setup[5], iterations=0), **RECORDED)
    else:
        with pytest.raises(KeyboardInterrupt):
            _run(setup, out, **RECORDED)
    saves.n = similarity_spy.stop_at = render_spy.stop_at = None
    spy = TrainSpy()
    monkeypatch.setattr(loop_mod, "train_field", spy)
    metrics = _run(setup, out, **RECORDED)
    # what the resumed call trained, from which step: nothing of a finished iteration, a training from its last
    # step checkpoint (an interrupted evaluation: from its end, step 8)
    expected = {"in the teacher's training": [4, 0], "in the labelling": [0], "in the student's training": [4],
                "in the student's evaluation": [8], "none: a finished baseline extended": [0]}[interruption]
    assert [resumed for _, resumed in spy.calls] == expected
    ref_out, ref_metrics, _ = reference
    files = _files(out)
    # 2 checkpoints, 4 test renders, 9 pseudo-view PNGs, metrics.json
    assert files.keys() == _files(ref_out).keys() and len(files) == 2 + 4 + 9 + 1
    assert files == _files(ref_out)
    assert [r["psnr"] for r in metrics["iterations"]] == [r["psnr"] for r in ref_metrics["iterations"]]


def test_a_folder_with_more_iterations_is_left_untouched(setup, reference, tmp_path, monkeypatch):
    out = tmp_path / "run"
    shutil.copytree(reference[0], out)
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in out.rglob("*") if p.is_file()}
    monkeypatch.setattr(loop_mod, "train_field", lambda *a, **k: pytest.fail("trained"))
    monkeypatch.setattr(loop_mod, "evaluate", lambda *a, **k: pytest.fail("evaluated"))
    lines: list[str] = []
    for iterations in (0, 1):       # fewer iterations than the folder holds, and as many
        got = _run(setup, out, cfg=dataclasses.replace(setup[5], iterations=iterations), echo=lines.append)
        assert got == json.loads((out / "metrics.json").read_text())
        assert [r["iteration"] for r in got["iterations"]] == [0, 1]
    assert len(lines) == 2          # one line each: nothing to train
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in out.rglob("*") if p.is_file()} == before


@pytest.fixture(scope="module")
def baseline(setup, tmp_path_factory):
    """A finished 2-step baseline (iteration 0 only) of the tiny scene, to be copied: (folder, TrainConfig)."""
    tcfg = TrainConfig(steps=2, batch_rays=32, warmup_steps=1, checkpoint_every=0, occupancy_warmup=4,
                       occupancy_every=4)
    out = tmp_path_factory.mktemp("baseline") / "run"
    scene, train_idx, test_idx, model, _, cfg = setup
    loop_mod.run_selftraining(scene, train_idx, test_idx, model, tcfg, dataclasses.replace(cfg, iterations=0), out,
                              **QUIET)
    return out, tcfg


class Stop(Exception):
    pass


def _extend(setup, baseline, tmp_path, cfg, scene=None, **kwargs):
    """Iteration 1 on a copy of ``baseline``, with ``cfg``; returns once a stand-in raised :class:`Stop`."""
    out = tmp_path / "run"
    shutil.copytree(baseline[0], out)
    scene0, train_idx, test_idx, model, _, _ = setup
    with pytest.raises(Stop):
        loop_mod.run_selftraining(scene or scene0, train_idx, test_idx, model, baseline[1], cfg, out,
                                  **{**QUIET, **kwargs})


def test_the_labelling_gets_the_fits_device_and_each_pseudo_view_its_source_views_intrinsics(
        setup, baseline, tmp_path, monkeypatch):
    """VGG-19 is built on the device ``features_device`` chooses for the fit, with the run's ``normalize_layers``;
    the pseudo views keep their source views' intrinsics (source ``k % m``)."""
    from senerf.geometry import Intrinsics

    scene, train_idx = setup[0], setup[1]
    built, chosen = [], []

    def extractor(**kwargs):
        built.append(kwargs)
        raise Stop

    def device(scene, idx, device, echo):
        chosen.append((list(idx), str(device)))
        return "sentinel"

    monkeypatch.setattr(loop_mod, "VGG19Features", extractor)
    monkeypatch.setattr(loop_mod, "features_device", device)
    _extend(setup, baseline, tmp_path / "vgg19", SelfTrainConfig(iterations=1, normalize_layers=False))
    assert built == [{"normalize_layers": False, "device": "sentinel"}]
    assert chosen == [(train_idx.tolist(), "cpu")]
    monkeypatch.undo()

    handed = {}

    def stop(*args, **kwargs):
        handed.update(c2w=args[5], intrinsics=kwargs["pseudo_intrinsics"])
        raise Stop

    monkeypatch.setattr(loop_mod, "estimate_reliability", stop)
    ks = [Intrinsics.from_fov(f, scene.intrinsics.width, scene.intrinsics.height) for f in (50, 55, 60)]
    all_k = list(scene.intrinsics_all)
    for i, k in zip(train_idx, ks):
        all_k[int(i)] = k
    _extend(setup, baseline, tmp_path / "own", SelfTrainConfig(iterations=1, n_pseudo_per_input=2),
            scene=dataclasses.replace(scene, intrinsics_all=tuple(all_k)))
    assert handed["intrinsics"] == tuple(ks) * 2 and handed["c2w"].shape == (6, 4, 4)


def test_a_nerf_teacher_is_resumed_with_the_annealing_it_was_scored_with(setup, tmp_path):
    """After one step a NeRF field's high frequencies are still off; the teacher a resumed run loads from the
    finished iteration's checkpoint must be that field (switching them on made other pseudo labels)."""
    from senerf.config import ModelConfig
    from senerf.train import evaluate, load_field

    scene, train_idx, test_idx, _, _, cfg = setup
    model = ModelConfig(field="nerf", aabb=setup[3].aabb, n_samples=8, occupancy_resolution=0)
    tcfg = TrainConfig(steps=1, batch_rays=64, warmup_steps=0, checkpoint_every=0)
    metrics = loop_mod.run_selftraining(scene, train_idx, test_idx, model, tcfg,
                                        dataclasses.replace(cfg, iterations=0), tmp_path / "run", **QUIET)
    field, occupancy = load_field(checkpoint_path(tmp_path / "run", 0), model, tcfg.seed, tcfg.steps)
    assert float(field.band_weights.max()) < 1.0
    assert evaluate(field, scene, test_idx, None, model, occupancy=occupancy, progress=False)["psnr"] == \
        metrics["iterations"][0]["psnr"]
