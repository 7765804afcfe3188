"""senerf.fit (senerf/pipeline.py): a fit end to end, its run identity and resume, and the pre-flight checks."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest

import senerf
from senerf.train import phase_breakdown
from senerf.errors import InputError

SMALL = dict(iterations=0, train=dict(steps=24, batch_rays=128), model=dict(n_samples=12, resolution=8),
             progress=False, echo=lambda line: None)


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    from senerf.procedural.export import export_blender_scene

    return export_blender_scene(tmp_path_factory.mktemp("scene") / "tiny", n_train=5, n_val=0, n_test=2,
                                width=16, height=16, seed=0)


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_a_fit_writes_the_documented_run_folder_and_the_same_call_resumes_it(tiny_scene, tmp_path):
    out, lines = tmp_path / "run", []
    result = senerf.fit(tiny_scene, out, protocol="all", **{**SMALL, "echo": lines.append})
    metrics = json.loads((out / "metrics.json").read_text())
    assert [line for line in lines if line.startswith("fit: time ")] == [f"fit: time {phase_breakdown(metrics)}"]
    assert result.metrics == metrics and result.psnr == [metrics["iterations"][0]["psnr"]]
    assert set(metrics) == {"senerf_version", "command", "config", "scene", "train_views", "test_views",
                            "train_images", "test_images", "resolution", "iterations", "seconds_total"}
    assert metrics["train_images"] == [f"train/r_{k}.png" for k in range(5)]
    assert metrics["test_images"] == ["test/r_0.png", "test/r_1.png"] and metrics["test_views"] == [5, 6]
    (row,) = metrics["iterations"]
    assert set(row) == {"iteration", "psnr", "ssim", "lpips", "avg", "reliable_fraction", "seconds", "phases",
                        "train_samples_per_s", "per_view", "host"}
    assert row["lpips"] == row["avg"] == "unavailable" and row["reliable_fraction"] is None
    assert row["psnr"] == pytest.approx(np.mean(row["per_view"]["psnr"]))
    run = json.loads((out / "run.json").read_text())
    assert set(run) == {"senerf_run", "senerf_version", "scene_dir", "scene_files", "settings", "scene_kind_reason"}
    assert run["scene_kind_reason"].startswith("photos with alpha")
    assert set(run["settings"]) == {"downscale", "scene_kind", "train_views", "test_views", "train", "model",
                                    "selftrain"}
    assert "device" not in run["settings"]["train"] and "iterations" not in run["settings"]["selftrain"]
    names = {"run.json", "metrics.json", "summary.png", "checkpoints/iter_0_train.pt", "iter_0/test/rgb_000.png",
             "iter_0/test/depth_001.png"}
    assert names <= set(_files(out))
    before = _files(out)
    again = senerf.fit(tiny_scene, out, protocol="all", **SMALL)   # finished: nothing trained or written again
    assert again.metrics == metrics
    assert {k: v for k, v in _files(out).items() if k != "summary.png"} == \
        {k: v for k, v in before.items() if k != "summary.png"}


def test_another_run_is_refused_before_any_work_and_overwrite_replaces_it(tiny_scene, tmp_path):
    out = tmp_path / "run"
    senerf.fit(tiny_scene, out, protocol="all", **SMALL)
    before = _files(out)
    with pytest.raises(InputError, match=r"different run \(selftrain.seed: 0 in the folder, 1 now and 1 more"):
        senerf.fit(tiny_scene, out, protocol="all", seed=1, **SMALL)
    with pytest.raises(InputError, match=r"different run \(test_views"):
        senerf.fit(tiny_scene, out, protocol="all", test_views=1, **SMALL)
    assert _files(out) == before
    senerf.fit(tiny_scene, out, protocol="all", seed=1, overwrite=True, **SMALL)
    assert json.loads((out / "run.json").read_text())["settings"]["train"]["seed"] == 1


def test_a_scene_whose_files_changed_is_refused_but_not_for_photos_the_run_does_not_read(tiny_scene, tmp_path):
    scene = shutil.copytree(tiny_scene, tmp_path / "scene")
    out = tmp_path / "run"
    senerf.fit(scene, out, views=[0, 1, 3], **SMALL)
    assert sorted(json.loads((out / "run.json").read_text())["scene_files"]) == [
        "test/r_0.png", "test/r_1.png", "train/r_0.png", "train/r_1.png", "train/r_3.png", "transforms_test.json",
        "transforms_train.json"]
    unused = scene / "train" / "r_2.png"
    unused.write_bytes(unused.read_bytes() + b"\0")
    senerf.fit(scene, out, views=[0, 1, 3], **SMALL)   # the same run
    photo = scene / "train" / "r_3.png"
    photo.write_bytes(photo.read_bytes() + b"\0")
    with pytest.raises(InputError, match=r"different run \(scene files differ: train/r_3.png changed\)"):
        senerf.fit(scene, out, views=[0, 1, 3], **SMALL)


def test_self_training_extends_a_finished_baseline_without_training_it_again(tiny_scene, tmp_path):
    out = tmp_path / "run"
    flags = dict(SMALL, selftrain=dict(n_pseudo_per_input=1), views=[0, 1, 3])
    base = senerf.fit(tiny_scene, out, **flags)
    checkpoint = (out / "checkpoints" / "iter_0_train.pt").read_bytes()
    more = senerf.fit(tiny_scene, out, **{**flags, "iterations": 1})
    assert [r["iteration"] for r in more.metrics["iterations"]] == [0, 1]
    assert more.metrics["iterations"][0] == base.metrics["iterations"][0]
    assert (out / "checkpoints" / "iter_0_train.pt").read_bytes() == checkpoint
    assert 0 <= more.metrics["iterations"][1]["reliable_fraction"] <= 1
    assert {"rgb_000.png", "similarity_000.png", "mask_000.png"} <= {p.name for p in (out / "iter_1" / "pseudo").iterdir()}
    fewer = senerf.fit(tiny_scene, out, **flags)   # asking for less leaves the folder as it is
    assert fewer.metrics == more.metrics


def test_test_views_score_an_even_spread_of_the_test_split_with_the_same_renders(tmp_path):
    from senerf.procedural.export import export_blender_scene

    scene = export_blender_scene(tmp_path / "s", n_train=4, n_val=0, n_test=7, width=16, height=16, seed=1)
    every = senerf.fit(scene, tmp_path / "all", protocol="all", **SMALL).metrics
    some = senerf.fit(scene, tmp_path / "some", protocol="all", test_views=3, **SMALL).metrics
    kept = [0, 3, 6]   # round(linspace(0, 6, 3)), by hand
    assert some["test_views"] == [every["test_views"][k] for k in kept] == [4, 7, 10]
    (a,), (b,) = every["iterations"], some["iterations"]
    assert b["per_view"]["psnr"] == [a["per_view"]["psnr"][k] for k in kept]   # each view's render: the field's
    senerf.fit(scene, tmp_path / "all", protocol="all", test_views=7, **SMALL)   # all of them: the same run


def test_the_default_protocol_by_scene(tiny_scene, tmp_path):
    import types

    from senerf.pipeline import default_protocol

    def scene(name, n_test, kind="object"):
        return types.SimpleNamespace(name=name, kind=kind, splits={"test": np.arange(n_test)})

    assert default_protocol(scene("Lego", 200), "blender", None) == "extreme"   # a NeRF Synthetic name
    assert default_protocol(scene("my_capture", 1), "blender", None) == "spread"
    assert default_protocol(scene("my_capture", 0), "ngp", None) == "llff"
    assert default_protocol(scene("lego", 20), "colmap", None) == "llff"
    assert default_protocol(scene("fern", 0, "forward_facing"), "llff", None) == "llff"
    assert default_protocol(scene("lego", 200), "blender", [0, 1]) == "views"
    # spread over the tiny scene's 5 train views: round(linspace(0, 4, 3)) = [0, 2, 4]
    metrics = senerf.fit(tiny_scene, tmp_path / "o", **SMALL).metrics
    assert metrics["train_views"] == [0, 2, 4] and metrics["test_views"] == [5, 6]


def _bad_camera_positions(scene, position):
    for split in ("train", "test"):
        path = scene / f"transforms_{split}.json"
        meta = json.loads(path.read_text())
        for i, frame in enumerate(meta["frames"]):
            for row in range(3):
                frame["transform_matrix"][row][3] = position * (1.0 + row + 0.1 * i)
        path.write_text(json.dumps(meta))


@pytest.mark.parametrize("kwargs, needle", [
    (dict(model=dict(resolution=100000)), "--resolution: 100000 needs"),
    (dict(model=dict(hidden=100000)), "--hidden: 100000 needs"),
    (dict(train=dict(batch_rays=10**8)), "--batch-rays: 100000000 rays of 12 samples need up to"),
    (dict(downscale=2), "--downscale: the images are 8x8; the evaluation (SSIM) needs at least 11x11"),
    (dict(views=[0], iterations=1), "1 training view has no such point"),
    (dict(model=dict(field="nerf", hidden=64)), "hidden: sets the K-Planes field"),
    (dict(protocol="spread", test_views=3), "--test-views"),
    (dict(scene_kind="forward_facing"), "--scene-kind: a forward-facing (NDC) fit needs the depth bounds"),
    (dict(scene_kind="inside_out"), "--scene-kind: expected one of"),
    (dict(device="cuda:x"), "--device"),
    (dict(preset="slow"), "--preset"),
    (dict(selftrain=dict(empty_opacity=0.7)), "empty_opacity: must be <= opacity_threshold"),
])
def test_bad_settings_are_refused_in_one_line_before_anything_is_written(tiny_scene, tmp_path, kwargs, needle):
    out = tmp_path / "o"
    with pytest.raises(InputError) as caught:
        senerf.fit(tiny_scene, out, **{**SMALL, **kwargs})
    assert needle in str(caught.value) and "\n" not in str(caught.value)
    assert not out.exists()


def test_reliability_features_too_large_for_the_machine_are_refused_up_front(tiny_scene, tmp_path, monkeypatch):
    import os

    real = os.sysconf
    monkeypatch.setattr(os, "sysconf", lambda name: 256 if name == "SC_PHYS_PAGES" else real(name))   # 1 MiB
    with pytest.raises(InputError, match="--downscale: VGG-19 reliability features of one"):
        senerf.fit(tiny_scene, tmp_path / "o", **{**SMALL, "iterations": 1})
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("position, needle", [(0.0, "all stand at one camera centre"),
                                              (1e300, "the cameras' box cannot be computed")])
def test_cameras_without_a_usable_position_are_refused(tiny_scene, tmp_path, position, needle):
    scene = shutil.copytree(tiny_scene, tmp_path / "scene")
    _bad_camera_positions(scene, position)
    with pytest.raises(InputError, match=needle):
        senerf.fit(scene, tmp_path / "o", protocol="all", **SMALL)
    assert not (tmp_path / "o").exists()


def test_a_far_test_camera_is_refused_and_a_test_view_posed_as_a_training_view_is_warned(tiny_scene, tmp_path):
    def edited(name, edit):
        root = shutil.copytree(tiny_scene, tmp_path / name)
        test, train = (json.loads((root / f"transforms_{s}.json").read_text()) for s in ("test", "train"))
        edit(test, train)
        (root / "transforms_test.json").write_text(json.dumps(test))
        return root

    def far(test, train):
        test["frames"][1]["transform_matrix"][0][3] = 1e300

    def same(test, train):
        test["frames"][0]["transform_matrix"] = train["frames"][2]["transform_matrix"]

    with pytest.raises(InputError, match=r"test view 6 \(test/r_1.png\) stands 1e\+300 from the centre of the box"):
        senerf.fit(edited("far", far), tmp_path / "far_out", protocol="all", **SMALL)
    with pytest.warns(UserWarning, match=r"test view 5 \(test/r_0.png\) has the pose of training view 2"):
        senerf.fit(edited("same", same), tmp_path / "same_out", protocol="all", **SMALL)


def test_out_the_scene_folder_or_a_folder_of_its_photos_is_refused(tiny_scene, tmp_path):
    before = _files(tiny_scene)
    for out in (tiny_scene, tiny_scene / "train" / "..", tiny_scene / "train"):
        with pytest.raises(InputError, match="is the scene folder or a folder of its photos"):
            senerf.fit(tiny_scene, out, protocol="all", overwrite=True, **SMALL)
    assert _files(tiny_scene) == before


def test_a_summary_figure_that_cannot_be_drawn_is_a_warning_not_a_failed_fit(tiny_scene, tmp_path, monkeypatch):
    import senerf.report

    def broken(*args, **kwargs):
        raise ValueError("no rows")

    monkeypatch.setattr(senerf.report, "plot_run_summary", broken)
    with pytest.warns(UserWarning, match=r"no summary figure \(no rows\)"):
        senerf.fit(tiny_scene, tmp_path / "o", protocol="all", **SMALL)
    assert (tmp_path / "o" / "metrics.json").is_file() and not (tmp_path / "o" / "summary.png").exists()


def _colmap_writers():
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("colmap_writers", Path(__file__).parent / "data" / "test_colmap.py")
    writers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(writers)
    return writers


def test_colmap_captures_choose_their_kind_and_an_object_with_a_background_is_warned_about(tmp_path):
    # Catches: an RGB capture around something fitted as a box over black (the default must be unbounded), the
    # choice or its reason missing from run.json, an impossible kind accepted, a forward-facing capture not in NDC.
    writers = _colmap_writers()
    ring, _ = writers.ring_scene(tmp_path / "bg", True, np.arange(0, 360, 30), far_points=60)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # an unbounded fit models the points outside the box
        senerf.fit(ring, tmp_path / "o1", **SMALL)
    run = json.loads((tmp_path / "o1" / "run.json").read_text())
    assert run["settings"]["scene_kind"] == "unbounded" and "background in every pixel" in run["scene_kind_reason"]
    with pytest.raises(InputError, match="different run"), pytest.warns(UserWarning):   # another kind: another run
        senerf.fit(ring, tmp_path / "o1", scene_kind="object", **SMALL)
    with pytest.warns(UserWarning, match="60% of the capture's 100 3D points lie outside the box"):
        senerf.fit(ring, tmp_path / "o4", scene_kind="object", **SMALL)
    assert json.loads((tmp_path / "o4" / "run.json").read_text())["scene_kind_reason"] == "chosen with --scene-kind"
    with pytest.raises(InputError, match="--scene-kind: the cameras look up to 70 degrees"):
        senerf.fit(ring, tmp_path / "o5", scene_kind="forward_facing", **SMALL)
    assert not (tmp_path / "o5").exists()
    front, _ = writers.ring_scene(tmp_path / "ff", True, [0, 5, 10, 15, 20], far_points=60)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # no box to check the points against in NDC
        metrics = senerf.fit(front, tmp_path / "o2", **SMALL).metrics
    assert metrics["config"]["scene_kind"] == "forward_facing" and np.isfinite(metrics["iterations"][0]["psnr"])
    with pytest.raises(InputError, match="--aabb: a forward-facing scene is fitted in NDC"):
        senerf.fit(front, tmp_path / "o3", **{**SMALL, "model": {"aabb": ((-2,) * 3, (2,) * 3)}})


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="needs a CUDA GPU")
def test_a_self_training_fit_on_cuda_end_to_end_and_resumed(tiny_scene, tmp_path):
    import torch

    out = tmp_path / "gpu"
    kwargs = dict(SMALL, protocol="all", iterations=1, device="cuda",
                  selftrain=dict(n_pseudo_per_input=1))
    rows = senerf.fit(tiny_scene, out, **kwargs).metrics["iterations"]
    assert [r["iteration"] for r in rows] == [0, 1] and all(np.isfinite(r["psnr"]) for r in rows)
    assert all(r["host"]["device"] == torch.cuda.get_device_name() for r in rows)
    assert senerf.fit(tiny_scene, out, **kwargs).metrics["iterations"] == rows


def test_an_rgb_capture_around_a_room_is_fitted_unbounded_self_trained_and_orbited(tmp_path):
    # Catches: an instant-ngp capture without alpha fitted as a box over black, aabb_scale ignored, the
    # unbounded labelling (every pixel has content) or senerf-render's orbit failing on a contracted field.
    import imageio.v3 as iio

    from senerf.flythrough import main as render_main
    from senerf.procedural import export_room_scene

    room = export_room_scene(tmp_path / "room", n_views=12, width=16, height=16, aabb_scale=8)
    lines = []
    result = senerf.fit(room, tmp_path / "fit", **{**SMALL, "iterations": 1, "echo": lines.append},
                        protocol="llff", n_views=4, selftrain=dict(n_pseudo_per_input=1))
    run = json.loads((tmp_path / "fit" / "run.json").read_text())
    model = run["settings"]["model"]
    assert run["settings"]["scene_kind"] == "unbounded" and model["contract"] and model["bound"] is not None
    assert run["settings"]["train"]["tv_weight"] == 0.0
    assert any(line.startswith("fit: fitted as unbounded: RGB photos without alpha") for line in lines)
    assert len(result.psnr) == 2 and np.isfinite(result.psnr).all()
    labels = result.metrics["iterations"][1]["reliable_fraction"]
    assert labels is not None and 0.0 < labels < 1.0   # every pseudo pixel scored, some reliable, some not
    assert render_main([str(tmp_path / "fit"), "--frames", "3", "--quiet", "--format", "png"]) == 0
    frames = sorted((tmp_path / "fit" / "render" / "orbit_iter1").glob("rgb_*.png"))
    assert len(frames) == 3 and all(iio.imread(f).std() > 0 for f in frames)
