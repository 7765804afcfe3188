"""Bad input through ``senerf-fit`` (senerf/cli.py -> senerf/data): one line, exit 2, output left intact.

Table-driven: every case mutates a private copy of a 24x24 procedural Blender scene (or an instant-ngp
conversion of it) and runs ``senerf.cli.main`` in-process against an ``--out`` folder that already holds a
finished run; the case passes when the exit status is 2, stderr is exactly one ``senerf-fit: error: ...``
line naming the file and the field (no traceback), and every file of the existing output folder keeps its
bytes and mtime.  Three of the cases are repeated through a subprocess (a fresh interpreter) to show that
nothing on stderr but that one line appears.

Cases tried: 61.  Refused (exit 2): the 50 input cases of ``BAD_CASES`` (3 of them also by subprocess)
and 3 output folders (one holding a different run, one not a senerf-fit folder at all, one a file).  Accepted and
fitted: grayscale PNG, 16-bit PNG (colour and grey), an RGB frame in an RGBA scene, an RGBA frame in an RGB
scene, an all-RGB scene, an instant-ngp scene with one missing image (skipped with a warning), the same
command resuming its own run, and ``--overwrite`` replacing a different run: 8.
"""

from __future__ import annotations

import json
import re
import math
import shutil
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
import pytest

from senerf.cli import main

from .conftest import TINY_FIT, edit_json, run_cli_subprocess, snapshot

FOV = 0.6911112070083618


@pytest.fixture(scope="module")
def prior_run(tmp_path_factory, scene24) -> Path:
    """An output folder holding a finished tiny run (the bad commands point --out at it)."""
    out = tmp_path_factory.mktemp("prior") / "run"
    assert main([str(scene24), "--views", "0,1,2", "--out", str(out), *TINY_FIT]) == 0
    assert (out / "metrics.json").is_file()
    return out


# --- scene mutations ---------------------------------------------------------------------------------

def _train(scene):
    return scene / "transforms_train.json"


def _frame(split, i, key, value):
    def mutate(scene):
        def edit(doc):
            doc["frames"][i][key] = value
        edit_json(scene / f"transforms_{split}.json", edit)
    return mutate


def _pose(i, fn, split="train"):
    def mutate(scene):
        def edit(doc):
            m = np.asarray(doc["frames"][i]["transform_matrix"], dtype=np.float64)
            doc["frames"][i]["transform_matrix"] = fn(m)
        edit_json(scene / f"transforms_{split}.json", edit)
    return mutate


def _top(key, value, split="train"):
    def mutate(scene):
        def edit(doc):
            if value is _DELETE:
                del doc[key]
            else:
                doc[key] = value
        edit_json(scene / f"transforms_{split}.json", edit)
    return mutate


_DELETE = object()


def _write_text(rel, text):
    def mutate(scene):
        (scene / rel).write_text(text)
    return mutate


def _delete(rel):
    def mutate(scene):
        (scene / rel).unlink()
    return mutate


def _replace_bytes(rel, fn):
    def mutate(scene):
        p = scene / rel
        p.write_bytes(fn(p.read_bytes()))
    return mutate


def _image_is_folder(rel):
    def mutate(scene):
        (scene / rel).unlink()
        (scene / rel).mkdir()
    return mutate


def _resize_image(rel, w, h):
    def mutate(scene):
        img = iio.imread(scene / rel)
        iio.imwrite(scene / rel, cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA))
    return mutate


def _scale_rotation(s):
    def fn(m):
        m[:3, :3] *= s
        return m.tolist()
    return fn


def _shear(m):
    m[0, 1] += 0.2
    return m.tolist()


def _set(r, c, v):
    def fn(m):
        out = m.tolist()
        out[r][c] = v
        return out
    return fn


def _to_ngp(scene: Path, fl_x=None, extra=None, missing=()) -> None:
    """Replace the Blender files with one instant-ngp ``transforms.json`` over the train+test frames."""
    frames = []
    for split in ("train", "test"):
        doc = json.loads((scene / f"transforms_{split}.json").read_text())
        frames += doc["frames"]
    for split in ("train", "val", "test"):
        (scene / f"transforms_{split}.json").unlink()
    meta = {"camera_angle_x": FOV, "frames": frames}
    if fl_x is not None:
        meta["fl_x"] = fl_x
    meta.update(extra or {})
    (scene / "transforms.json").write_text(json.dumps(meta))
    for rel in missing:
        (scene / rel).unlink()


def _ngp(**kw):
    return lambda scene: _to_ngp(scene, **kw)


def _both(*fns):
    def mutate(scene):
        for fn in fns:
            fn(scene)
    return mutate


def _nothing(scene):
    pass


V = ["--views", "0,1,2"]
# (id, mutation, extra argv, strings the one error line must contain)
BAD_CASES = [
    ("no-transforms-json", _delete("transforms_train.json"), V, ["scene", "not a scene folder"]),
    ("scene-is-a-file", lambda s: None, V, ["procedural.json", "scene folder"]),
    ("missing-scene", lambda s: shutil.rmtree(s), V, ["scene", "not found"]),
    ("malformed-train-json", _write_text("transforms_train.json", '{"frames": [ {'), V,
     ["transforms_train.json", "malformed JSON"]),
    ("malformed-test-json", _write_text("transforms_test.json", "not json at all"), V,
     ["transforms_test.json", "malformed JSON"]),
    ("binary-json", _replace_bytes("transforms_val.json", lambda b: b"\xff\xfe\x00" + b[:10]), V,
     ["transforms_val.json"]),
    ("json-top-level-list", _write_text("transforms_train.json", "[1, 2]"), V,
     ["transforms_train.json", "top level"]),
    ("no-frames-field", _top("frames", _DELETE), V, ["transforms_train.json", "frames", "missing"]),
    ("frames-not-a-list", _top("frames", {"a": 1}), V, ["transforms_train.json", "frames", "list"]),
    ("frame-not-an-object", _top("frames", [1, 2]), V, ["transforms_train.json", "frames[0]"]),
    ("empty-train-frames", _top("frames", []), V, ["transforms_train.json", "frames", "empty frame list"]),
    ("empty-test-frames", _top("frames", [], split="test"), V, ["--protocol", "no test split"]),
    ("no-camera-angle", _top("camera_angle_x", _DELETE), V, ["transforms_train.json", "camera_angle_x"]),
    ("zero-focal", _top("camera_angle_x", 0.0), V, ["transforms_train.json", "camera_angle_x", "positive"]),
    ("negative-focal", _top("camera_angle_x", -0.69), V, ["transforms_train.json", "camera_angle_x", "positive"]),
    ("fov-above-pi", _top("camera_angle_x", 3.5), V, ["transforms_train.json", "camera_angle_x", "below pi"]),
    ("focal-string", _top("camera_angle_x", "wide"), V, ["transforms_train.json", "camera_angle_x", "number"]),
    ("focal-nan", _top("camera_angle_x", float("nan")), V, ["transforms_train.json", "camera_angle_x"]),
    ("frame-focal-negative", _frame("train", 2, "camera_angle_x", -1.0), V,
     ["transforms_train.json", "frames[2].camera_angle_x"]),
    ("no-transform-matrix", lambda s: edit_json(_train(s), lambda d: d["frames"][2].pop("transform_matrix")), V,
     ["transforms_train.json", "frames[2].transform_matrix", "missing"]),
    ("pose-nan", _pose(1, _set(0, 3, float("nan"))), V, ["transforms_train.json", "frames[1].transform_matrix", "NaN"]),
    ("pose-inf", _pose(4, _set(2, 3, float("inf"))), V, ["transforms_train.json", "frames[4].transform_matrix", "inf"]),
    ("pose-nan-test-split", _pose(0, _set(1, 1, float("nan")), split="test"), V,
     ["transforms_test.json", "frames[0].transform_matrix"]),
    ("pose-scaled", _pose(3, _scale_rotation(2.0)), V, ["transforms_train.json", "frames[3].transform_matrix", "rigid"]),
    ("pose-sheared", _pose(0, _shear), V, ["transforms_train.json", "frames[0].transform_matrix", "rigid"]),
    ("pose-mirrored", _pose(5, _scale_rotation(-1.0)), V, ["transforms_train.json", "frames[5].transform_matrix", "rigid"]),
    ("pose-bad-last-row", _pose(2, _set(3, 0, 0.5)), V, ["transforms_train.json", "frames[2].transform_matrix"]),
    ("pose-3x3", _pose(1, lambda m: m[:3, :3].tolist()), V, ["transforms_train.json", "frames[1].transform_matrix", "4x4"]),
    ("pose-strings", _frame("train", 1, "transform_matrix", [["a"] * 4] * 4), V,
     ["transforms_train.json", "frames[1].transform_matrix"]),
    ("missing-train-image", _delete("train/r_3.png"), V, ["transforms_train.json", "frames[3].file_path", "not found"]),
    ("missing-test-image", _delete("test/r_1.png"), V, ["transforms_test.json", "frames[1].file_path", "not found"]),
    ("image-is-a-folder", _image_is_folder("train/r_1.png"), V, ["transforms_train.json", "frames[1].file_path"]),
    ("image-garbage", _replace_bytes("train/r_2.png", lambda b: b"this is not a png" * 10), V,
     ["transforms_train.json", "frames[2].file_path", "cannot decode"]),
    ("image-truncated", _replace_bytes("train/r_2.png", lambda b: b[:60]), V,
     ["transforms_train.json", "frames[2].file_path", "cannot decode"]),
    ("image-empty", _replace_bytes("val/r_0.png", lambda b: b""), V,
     ["transforms_val.json", "frames[0].file_path", "cannot decode"]),
    ("mixed-image-sizes", _resize_image("train/r_4.png", 20, 24), V,
     ["transforms_train.json", "frames[4].file_path", "share one size"]),
    ("file-path-parent", _frame("train", 1, "file_path", "../../outside/r_1"), V,
     ["transforms_train.json", "frames[1].file_path", "leaves the scene folder"]),
    ("file-path-absolute", _frame("train", 0, "file_path", "/etc/passwd"), V,
     ["transforms_train.json", "frames[0].file_path", "absolute"]),
    ("file-path-not-string", _frame("train", 0, "file_path", 7), V, ["transforms_train.json", "frames[0].file_path"]),
    ("views-duplicate", _nothing, ["--views", "0,2,0"], ["--views", "duplicate"]),
    ("views-out-of-range", _nothing, ["--views", "0,6"], ["--views", "out of range"]),
    ("views-negative", _nothing, ["--views=-1,2"], ["--views", "out of range"]),
    ("views-option-like", _nothing, ["--views", "-1,2"], ["--views"]),
    ("views-not-integers", _nothing, ["--views", "0,one"], ["--views"]),
    ("ngp-zero-focal", _ngp(fl_x=0.0), V, ["transforms.json", "fl_x", "positive"]),
    ("ngp-zero-principal-point", _ngp(extra={"cx": 0.0}), V, ["transforms.json", "cx", "positive"]),
    ("ngp-negative-principal-point", _ngp(extra={"cy": -3.0}), V, ["transforms.json", "cy", "positive"]),
    ("ngp-negative-focal", _ngp(fl_x=-20.0), V, ["transforms.json", "fl_x", "positive"]),
    ("ngp-declared-width-wrong", _ngp(extra={"w": 32, "h": 24}), V, ["transforms.json", "w", "declared"]),
    ("ngp-every-image-missing", _ngp(missing=[f"train/r_{k}.png" for k in range(6)] + ["test/r_0.png", "test/r_1.png"]),
     V, ["transforms.json", "frames", "no frame has an existing image"]),
]
SUBPROCESS_CASES = ("malformed-train-json", "pose-nan", "missing-train-image")


def _scene_arg(case_id: str, scene: Path) -> str:
    return str(scene / "procedural.json") if case_id == "scene-is-a-file" else str(scene)


def _check_one_line(err: str, needles) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith("senerf-fit: error: "), line
    assert "Traceback" not in err
    for needle in needles:
        assert needle in line, (needle, line)
    return line


@pytest.mark.parametrize("case_id, mutate, extra, needles", BAD_CASES, ids=[c[0] for c in BAD_CASES])
def test_bad_input_is_one_line_exit_2_and_output_intact(case_id, mutate, extra, needles, scene_copy, prior_run,
                                                       capsys):
    mutate(scene_copy)
    before = snapshot(prior_run)
    capsys.readouterr()
    status = main([_scene_arg(case_id, scene_copy), "--out", str(prior_run), *TINY_FIT, *extra])
    err = capsys.readouterr().err
    assert status == 2, err
    _check_one_line(err, needles)
    assert snapshot(prior_run) == before


@pytest.mark.parametrize("case_id", SUBPROCESS_CASES)
def test_bad_input_in_a_fresh_process_prints_no_traceback(case_id, scene_copy, prior_run):
    ((_, mutate, extra, needles),) = [c for c in BAD_CASES if c[0] == case_id]
    mutate(scene_copy)
    before = snapshot(prior_run)
    proc = run_cli_subprocess([_scene_arg(case_id, scene_copy), "--out", prior_run, *TINY_FIT, *extra], timeout=120)
    assert proc.returncode == 2, proc.stderr
    _check_one_line(proc.stderr, needles)
    assert snapshot(prior_run) == before


# --- the output folder ---------------------------------------------------------------------------------

def test_different_run_is_refused_without_overwrite_and_replaced_with_it(scene24, tmp_path, capsys):
    out = tmp_path / "run"
    base = [str(scene24), "--views", "0,1,2", "--out", str(out), *TINY_FIT]
    assert main(base) == 0
    before = snapshot(out)
    capsys.readouterr()
    other = [*base, "--seed", "3"]
    assert main(other) == 2
    _check_one_line(capsys.readouterr().err, [str(out), "different run", "--overwrite"])
    assert snapshot(out) == before
    # a folder that is not a senerf-fit output at all
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    assert main([str(scene24), "--views", "0,1,2", "--out", str(stranger), *TINY_FIT]) == 2
    _check_one_line(capsys.readouterr().err, [str(stranger), "not a senerf-fit run folder"])
    assert (stranger / "notes.txt").read_text() == "mine"
    # a file where the output folder should be
    a_file = tmp_path / "a_file"
    a_file.write_text("mine")
    assert main([str(scene24), "--views", "0,1,2", "--out", str(a_file), *TINY_FIT]) == 2
    _check_one_line(capsys.readouterr().err, [str(a_file), "not a folder", "--out"])
    assert a_file.read_text() == "mine"
    # --overwrite replaces the other run: metrics now record seed 3
    assert main([*other, "--overwrite"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["config"]["train"]["seed"] == 3


def test_same_command_resumes_its_own_run(scene24, tmp_path, capsys):
    out = tmp_path / "run"
    argv = [str(scene24), "--views", "0,1,2", "--out", str(out), *TINY_FIT]
    assert main(argv) == 0
    first = json.loads((out / "metrics.json").read_text())
    ckpt = out / "checkpoints" / "iter_0_train.pt"
    ckpt_bytes = ckpt.read_bytes()
    capsys.readouterr()
    assert main(argv) == 0
    assert "error" not in capsys.readouterr().err
    second = json.loads((out / "metrics.json").read_text())
    # the finished checkpoint is reused, not retrained: same weights, same metrics
    assert ckpt.read_bytes() == ckpt_bytes
    assert second["iterations"][0]["per_view"] == first["iterations"][0]["per_view"]


# --- inputs that must be accepted ----------------------------------------------------------------------

def _fit_ok(scene: Path, tmp_path: Path, capsys, views=("--views", "0,1,2")) -> tuple[dict, str]:
    out = tmp_path / "fit"
    capsys.readouterr()
    status = main([str(scene), *views, "--out", str(out), *TINY_FIT])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    metrics = json.loads((out / "metrics.json").read_text())
    assert all(math.isfinite(p) for p in metrics["iterations"][0]["per_view"]["psnr"])
    return metrics, captured.err


def test_grayscale_png_is_accepted_and_fits(scene_copy, tmp_path, capsys):
    from senerf.data import load_scene

    p = scene_copy / "train" / "r_1.png"
    rgba = iio.imread(p)
    gray = np.round(rgba[..., :3].astype(np.float64).mean(axis=-1)).astype(np.uint8)
    iio.imwrite(p, gray)
    assert iio.imread(p).ndim == 2
    with pytest.warns(UserWarning, match=r"1 of 9 photos have no alpha channel \(frames\[1\]\.file_path: r_1\.png\)"):
        scene = load_scene(scene_copy)
    k = 1  # train frame 1 is array index 1
    assert np.allclose(scene.rgb[k], (gray / 255.0)[..., None], atol=1e-6)
    assert np.all(scene.alpha[k] == 1.0)  # no alpha channel: opaque
    _fit_ok(scene_copy, tmp_path, capsys)


def test_16bit_png_is_accepted_with_full_precision_and_fits(scene_copy, tmp_path, capsys):
    from senerf.data import load_scene

    p = scene_copy / "train" / "r_2.png"
    rgba8 = iio.imread(p)
    rgba16 = rgba8.astype(np.uint16) * 257 + np.uint16(3) * (rgba8 < 255)  # low bits that 8-bit reading would lose
    assert cv2.imwrite(str(p), rgba16[..., [2, 1, 0, 3]])
    scene = load_scene(scene_copy)
    assert np.allclose(scene.rgb[2], rgba16[..., :3] / 65535.0, atol=1e-6)
    assert np.allclose(scene.alpha[2], rgba16[..., 3] / 65535.0, atol=1e-6)
    # 16-bit grey too
    g = scene_copy / "train" / "r_0.png"
    grey16 = (rgba16[..., 0].astype(np.uint32) * 0 + 40000).astype(np.uint16)
    assert cv2.imwrite(str(g), grey16)
    with pytest.warns(UserWarning, match=r"1 of 9 photos have no alpha channel \(frames\[0\]\.file_path: r_0\.png\)"):
        scene = load_scene(scene_copy)
    assert np.allclose(scene.rgb[0], 40000 / 65535.0, atol=1e-6)
    _fit_ok(scene_copy, tmp_path, capsys)


def test_rgb_frame_in_an_rgba_scene_is_opaque_and_fits(scene_copy, tmp_path, capsys):
    from senerf.data import load_scene

    p = scene_copy / "train" / "r_0.png"
    rgba = iio.imread(p)
    iio.imwrite(p, rgba[..., :3])
    with pytest.warns(UserWarning, match=r"1 of 9 photos have no alpha channel .* taken as fully opaque"):
        scene = load_scene(scene_copy)
    assert scene.alpha is not None and np.all(scene.alpha[0] == 1.0) and scene.alpha[1].min() == 0.0
    assert np.allclose(scene.rgb[0], rgba[..., :3] / 255.0, atol=1e-6)
    _fit_ok(scene_copy, tmp_path, capsys)


def test_all_rgb_scene_is_accepted_and_rendered_over_black(scene_copy, tmp_path, capsys):
    for png in scene_copy.rglob("r_*.png"):
        rgba = iio.imread(png)
        iio.imwrite(png, rgba[..., :3])
    metrics, _ = _fit_ok(scene_copy, tmp_path, capsys)
    assert metrics["config"]["model"]["train_background"] == "black"


def test_rgba_frame_in_an_rgb_scene_is_accepted_and_fits(scene_copy, tmp_path, capsys):
    from senerf.data import load_scene

    for png in scene_copy.rglob("r_*.png"):
        if png.name != "r_2.png" or png.parent.name != "train":
            iio.imwrite(png, iio.imread(png)[..., :3])
    with pytest.warns(UserWarning, match=r"8 of 9 photos have no alpha channel"):
        scene = load_scene(scene_copy)
    assert scene.alpha is not None and scene.alpha[2].min() == 0.0  # the RGBA frame keeps its alpha
    assert np.all(scene.alpha[np.arange(scene.n_images) != 2] == 1.0)  # the RGB frames are opaque
    _fit_ok(scene_copy, tmp_path, capsys)


def test_ngp_frame_without_image_is_skipped_with_a_warning(scene_copy, tmp_path, capsys):
    _to_ngp(scene_copy, missing=["train/r_4.png"])
    metrics, err = _fit_ok(scene_copy, tmp_path, capsys)
    # the CLI prints the loader's warning as one line of its own
    warning_lines = [line for line in err.splitlines() if line.startswith("senerf-fit: warning:")]
    assert len(warning_lines) == 1, err
    assert re.search(r"skipped 1 frame\(s\) whose image is missing: frames\[4\]", warning_lines[0])
    # 7 of the 8 frames remain; --views index all remaining images, the rest are test views
    assert metrics["train_views"] == [0, 1, 2] and metrics["test_views"] == [3, 4, 5, 6]


def test_docstring_counts_match_the_table():
    assert f"the {len(BAD_CASES)} input cases" in __doc__
    assert f"Cases tried: {len(BAD_CASES) + 3 + 8}." in __doc__
