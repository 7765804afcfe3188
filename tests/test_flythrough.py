"""senerf-render (senerf/flythrough.py): fly-throughs of a finished fit, written whole or not at all.

The run folders are made by :func:`senerf.fit` on a tiny procedural scene.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import types
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

import senerf.flythrough as fly
from senerf.errors import InputError
from senerf.flythrough import load_run, main, path_cameras, render_frames, side_by_side
from senerf.geometry import Intrinsics

_K8 = Intrinsics(8.0, 8.0, 4.0, 4.0, 8, 8)


def _fit(scene_dir: Path, out: Path, train_idx, iterations: int = 0, field: str = "kplanes", steps: int = 24) -> Path:
    """A finished run folder of ``iterations + 1`` iterations, made by :func:`senerf.fit` on tiny settings."""
    import senerf

    model = dict(n_samples=12, **(dict(resolution=8) if field == "kplanes" else dict(field="nerf")))
    senerf.fit(scene_dir, out, views=list(train_idx), iterations=iterations, train=dict(steps=steps, batch_rays=128),
               model=model, selftrain=dict(n_pseudo_per_input=1), progress=False, echo=lambda line: None)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A tiny scene (views 0-4 train, 5-7 test), a teacher-only run on all training views, a two-iteration run on
    views 0, 1, 3 and a NeRF-field run of one step."""
    from senerf.procedural.export import export_blender_scene

    root = tmp_path_factory.mktemp("fly")
    scene = export_blender_scene(root / "scene", n_train=5, n_val=0, n_test=3, width=16, height=16, seed=0)
    return types.SimpleNamespace(scene=scene, base=_fit(scene, root / "base", [0, 1, 2, 3, 4]),
                                 st=_fit(scene, root / "st", [0, 1, 3], iterations=1),
                                 nerf=_fit(scene, root / "nerf", [0, 1, 2, 3, 4], field="nerf", steps=1))


def _copy(run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run, tmp_path / run.name, ignore=shutil.ignore_patterns("render")))


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("senerf-render: error: "), err
    return err[0]


def _edit_json(path: Path, edit) -> None:
    record = json.loads(path.read_text())
    edit(record)
    path.write_text(json.dumps(record))


def _edit_checkpoint(path: Path, edit) -> None:
    import torch

    state = torch.load(path, weights_only=True)
    edit(state)
    torch.save(state, path)


def _beside(out: Path) -> list[str]:
    """The hidden names beside ``out`` (a partial folder left behind would be one)."""
    return sorted(p.name for p in out.parent.iterdir() if p.name.startswith("."))


# --- what is rendered ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("which, iteration", [("base", None), ("st", 0), ("st", 1), ("nerf", None)])
def test_the_test_path_reproduces_the_renders_senerf_fit_scored(runs, tmp_path, which, iteration):
    """Same field, cameras and renderer as the fit's evaluation: the PNGs agree to the last bit (a NeRF field with
    the frequency-annealing weights it was scored with, after 1 step only its first bands)."""
    run = getattr(runs, which)
    out = tmp_path / "t"
    flags = [] if iteration is None else ["--iteration", str(iteration)]
    assert main([str(run), "--path", "test", "--out", str(out), "--quiet", "--format", "png", *flags]) == 0
    k = 1 if which == "st" and iteration is None else iteration or 0
    scored = sorted((run / f"iter_{k}" / "test").glob("rgb_*.png"))
    assert len(scored) == 3
    for png in scored:
        np.testing.assert_array_equal(iio.imread(out / png.name), iio.imread(png))
    record = json.loads((out / "path.json").read_text())
    assert record["iteration"] == k and record["path"] == "test" and len(record["c2w"]) == 3
    if which == "nerf":
        assert load_run(run).field.band_weights.min() < 1.0


def test_iterations_differ_and_the_last_is_the_default(runs, tmp_path):
    common = ["--path", "test", "--quiet", "--format", "png"]
    for it in ("0", "1"):
        assert main([str(runs.st), "--iteration", it, "--out", str(tmp_path / it), *common]) == 0
    assert main([str(runs.st), "--out", str(tmp_path / "last"), *common]) == 0
    last, one, zero = (iio.imread(tmp_path / name / "rgb_000.png") for name in ("last", "1", "0"))
    np.testing.assert_array_equal(last, one)
    assert not np.array_equal(one, zero)


def test_the_default_orbit_writes_videos_and_the_poses(runs, tmp_path, capsys):
    import torch

    from senerf.data import load_scene
    from senerf.geometry import orbit_path

    run = _copy(runs.st, tmp_path)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert main([str(run), "--frames", "6", "--fps", "10", "--quiet", "--threads", "1"]) == 0
        assert torch.get_num_threads() == 1                 # --threads is torch.set_num_threads
    finally:
        torch.set_num_threads(before)
    out = run / "render" / "orbit_iter1"                    # the last finished iteration, the object default
    assert f"rgb.mp4 and depth.mp4 in {out}" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["depth.mp4", "path.json", "rgb.mp4"]   # mp4 by default
    record = json.loads((out / "path.json").read_text())
    scene = load_scene(runs.scene)
    np.testing.assert_allclose(record["c2w"], orbit_path(scene.c2w[[0, 1, 3]], 6), atol=1e-12)
    k = scene.intrinsics_all[0]
    assert record["intrinsics"] == [[k.fx, k.fy, k.cx, k.cy, 16, 16]] * 6
    assert record["format"] == "mp4" and record["fps"] == 10.0
    assert _beside(out) == []                               # no partial folder left


def test_scale_and_elevation_shape_the_orbit(runs):
    from senerf.geometry import closest_point_to_axes, default_up, spherical_from_pose

    run = load_run(runs.base)
    c2w, ks = path_cameras(run, "orbit", 4, scale=2.0, elevation=60.0)
    assert ks[0].size == (32, 32)
    inputs = run.scene.c2w[run.train_idx]
    el = spherical_from_pose(c2w, closest_point_to_axes(inputs), default_up(inputs))[1]
    np.testing.assert_allclose(el, 60.0, atol=1e-9)
    frames = render_frames(run, c2w, ks, progress=False)
    assert frames["rgb"].shape == (4, 32, 32, 3) and frames["rgb"].dtype == np.uint8
    assert frames["depth"].shape == (4, 32, 32, 3)


def test_the_occupancy_grid_of_the_checkpoint_is_used(runs, tmp_path):
    """A checkpoint whose grid marks every cell empty renders nothing: the grid is loaded and used."""
    run_dir = _copy(runs.base, tmp_path)

    def empty_grid(state):
        state["occupancy"]["mask"] = state["occupancy"]["mask"] & False
        state["occupancy"]["density_grid"] = state["occupancy"]["density_grid"] * 0.0
    _edit_checkpoint(run_dir / "checkpoints" / "iter_0_train.pt", empty_grid)
    run = load_run(run_dir)
    c2w, ks = path_cameras(run, "test", 0)
    frames = render_frames(run, c2w[:1], ks[:1], progress=False)
    assert frames["acc"].max() == 0.0 and (frames["rgb"] == 255).all()   # the white background only
    full = render_frames(load_run(runs.base), c2w[:1], ks[:1], progress=False)
    assert full["acc"].max() > 0.5        # the same view with the fitted grid is not empty


def _fake_renders(monkeypatch, fake: dict) -> None:
    """``render_views`` replaced by one that hands out ``fake``'s frames."""
    import senerf.train

    monkeypatch.setattr(senerf.train, "render_views", lambda *a, **k: {key: np.asarray(v) for key, v in fake.items()})


def _stand_in_run(background: str = "white"):
    return types.SimpleNamespace(field=None, model=types.SimpleNamespace(eval_background=background), occupancy=None)


def test_one_depth_colour_range_for_the_whole_path(monkeypatch):
    """The same depth gets the same colour in every frame (per-frame ranges would give 1.5 two colours)."""
    z = np.stack([np.linspace(1.0, 2.0, 64).reshape(8, 8), np.linspace(1.0, 4.0, 64).reshape(8, 8)]).astype(np.float32)
    z[0, 0, 7] = z[1, 0, 5] = 1.5
    _fake_renders(monkeypatch, dict(rgb=np.zeros((2, 8, 8, 3), np.float32), z_depth=z, acc=np.ones((2, 8, 8))))
    depth = render_frames(_stand_in_run(), np.zeros((2, 4, 4)), _K8, progress=False)["depth"]
    np.testing.assert_array_equal(depth[0, 0, 7], depth[1, 0, 5])
    assert not np.array_equal(depth[0, 0, 0], depth[0, 7, 7])   # and the map is not flat


def test_depth_colours_span_the_1st_to_99th_percentile_of_opaque_pixels(monkeypatch):
    # 101 opaque pixels at depths 0..100 (1st / 99th percentiles exactly 1 and 99), 20 half-transparent and 7
    # empty ones far away (left out of the range), in two frames of 8 x 8
    z = np.full(128, 1000.0)
    acc = np.zeros(128)
    z[:101], acc[:101], acc[101:121] = np.arange(101.0), 1.0, 0.3
    rgb = np.zeros((128, 3))
    rgb[0], rgb[1] = -0.5, 1.5   # out-of-range colours are clipped, not wrapped around
    fake = dict(rgb=rgb.reshape(2, 8, 8, 3), z_depth=z.reshape(2, 8, 8), acc=acc.reshape(2, 8, 8))
    for background, grey in (("white", 255), ("black", 0)):
        _fake_renders(monkeypatch, fake)
        out = render_frames(_stand_in_run(background), np.zeros((2, 4, 4)), _K8, progress=False)
        depth = out["depth"].reshape(128, 3)
        np.testing.assert_array_equal(depth[0], depth[1])       # depth 0 clipped to the 1st percentile, 1
        np.testing.assert_array_equal(depth[100], depth[99])    # depth 100 clipped to the 99th, 99
        assert not np.array_equal(depth[1], depth[2]) and not np.array_equal(depth[98], depth[99])
        assert (depth[121:] == grey).all()                      # empty pixels: the background
        assert out["rgb"].reshape(128, 3)[:2].tolist() == [[0, 0, 0], [255, 255, 255]]


def test_compare_puts_the_teacher_beside_the_rendered_iteration(runs, tmp_path, capsys):
    teacher, last, both = tmp_path / "t", tmp_path / "l", tmp_path / "b"
    common = ["--frames", "3", "--quiet", "--format", "png"]
    assert main([str(runs.st), "--iteration", "0", "--out", str(teacher), *common]) == 0
    assert main([str(runs.st), "--out", str(last), *common]) == 0
    assert main([str(runs.st), "--out", str(both), "--compare", *common[:-1], "gif"]) == 0
    assert "compare.gif" in capsys.readouterr().out
    gif = iio.imread(both / "compare.gif", index=None)[..., :3]
    assert gif.shape == (3, 18 + 16, 16 + 4 + 16, 3)

    def mad(a, b):   # mean absolute difference: a GIF holds 256 colours, so the halves are near, not equal
        return np.abs(a.astype(float) - b.astype(float)).mean()
    for i in range(3):
        t, s = iio.imread(teacher / f"rgb_{i:03d}.png"), iio.imread(last / f"rgb_{i:03d}.png")
        assert mad(gif[i, 18:, :16], t) < 1.5 < mad(gif[i, 18:, :16], s)
        assert mad(gif[i, 18:, 20:], s) < 1.5 < mad(gif[i, 18:, 20:], t)
        assert (gif[i, :, 16:20] == 255).all()                                     # the gap, header included:
        assert (gif[i, :18, :16] < 128).any() and (gif[i, :18, 20:] < 128).any()   # each label within its panel
    assert json.loads((both / "path.json").read_text())["compared_with"] == 0


def test_compare_needs_a_finished_teacher_and_another_iteration(runs, tmp_path, capsys, monkeypatch):
    rendered = []
    monkeypatch.setattr(fly, "render_frames", lambda *a, **k: rendered.append(1))
    assert main([str(runs.base), "--out", str(tmp_path / "z"), "--compare", "--quiet"]) == 2
    assert "--compare" in _error(capsys)
    missing = _copy(runs.st, tmp_path / "m")  # a missing teacher checkpoint is found before rendering
    (missing / "checkpoints" / "iter_0_train.pt").unlink()
    assert main([str(missing), "--compare", "--quiet"]) == 2
    assert "iter_0_train.pt" in _error(capsys)
    assert rendered == [] and not (missing / "render").exists() and not (tmp_path / "z").exists()


def test_side_by_side_places_both_stacks_and_checks_them():
    a, b = np.full((2, 5, 6, 3), 10, np.uint8), np.full((2, 5, 6, 3), 200, np.uint8)
    out = side_by_side(a, b, ("l", "r"), header=10, gap=2)
    assert out.shape == (2, 15, 14, 3)
    assert (out[:, 10:, :6] == 10).all() and (out[:, 10:, 8:] == 200).all() and (out[:, :, 6:8] == 255).all()
    with pytest.raises(ValueError, match="one shape"):
        side_by_side(a, a[:1], ("l", "r"))
    with pytest.raises(ValueError, match="uint8"):
        side_by_side(a.astype(np.float32), a, ("l", "r"))


# --- output formats and videos ---------------------------------------------------------------------------------


def _decode(mp4: Path) -> tuple[dict, np.ndarray]:
    """The stream's metadata as the bundled ffmpeg reads it (codec, pix_fmt, size, fps) and its decoded frames
    ``(n, H, W, 3)`` uint8."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    w, h = meta["size"]
    return meta, np.stack([np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in reader])


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10.0 * np.log10(255.0 ** 2 / np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def _luma(rgb: np.ndarray) -> np.ndarray:
    """BT.601 luma ``(..., )`` of ``rgb (..., 3)``: the channel yuv420p keeps at full resolution."""
    return rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


@pytest.mark.parametrize("scale, size", [("1", (16, 16)), ("0.9375", (15, 15))])
def test_the_mp4s_play_as_h264_yuv420p_of_even_size_close_to_the_png_frames(runs, tmp_path, scale, size):
    """Decoded by ffmpeg, the videos hold every frame in order, at the frame rate asked for, each frame's luma
    within 30 dB of the lossless PNG of the same render (a neighbouring frame is under 28 dB).  yuv420p keeps
    colour at half resolution, which costs a 16-pixel colour-mapped depth most (about 23 dB in RGB): the RGB
    bound is for the photo-like rgb.mp4 only.  An odd 15 x 15 render is padded to 16 x 16 by repeating its last
    row and column."""
    common = [str(runs.st), "--frames", "5", "--fps", "8", "--scale", scale, "--quiet"]
    assert main([*common, "--out", str(tmp_path / "mp4")]) == 0
    assert main([*common, "--out", str(tmp_path / "png"), "--format", "png"]) == 0
    h, w = size
    for name in ("rgb", "depth"):
        meta, video = _decode(tmp_path / "mp4" / f"{name}.mp4")
        assert meta["codec"] == "h264" and meta["pix_fmt"].startswith("yuv420p") and meta["fps"] == 8.0
        assert meta["size"] == (w + w % 2, h + h % 2) and video.shape[0] == 5
        pngs = np.stack([iio.imread(tmp_path / "png" / f"{name}_{i:03d}.png") for i in range(5)])
        assert min(_psnr(_luma(v[:h, :w]), _luma(png)) for v, png in zip(video, pngs)) > 30.0
        if name == "rgb":
            assert _psnr(video[:, :h, :w], pngs) > 30.0
        if h % 2:   # the repeated edge, as close to the last rendered row and column
            assert _psnr(_luma(video[:, h, :w]), _luma(pngs[:, h - 1])) > 30.0
            assert _psnr(_luma(video[:, :h, w]), _luma(pngs[:, :, w - 1])) > 30.0


@pytest.mark.parametrize("fmt, names", [
    ("mp4", ["compare.mp4", "depth.mp4", "path.json", "rgb.mp4"]),
    ("gif", ["compare.gif", "depth.gif", "path.json", "rgb.gif"]),
    ("png", [f"{n}_{i:03d}.png" for n in ("compare", "depth") for i in range(2)] + ["path.json"]
     + [f"rgb_{i:03d}.png" for i in range(2)]),
])
def test_each_format_writes_only_its_own_files(runs, tmp_path, capsys, fmt, names):
    out = tmp_path / "o"
    assert main([str(runs.st), "--out", str(out), "--frames", "2", "--fps", "10", "--compare", "--quiet",
                 "--format", fmt]) == 0
    assert sorted(p.name for p in out.iterdir()) == names
    assert json.loads((out / "path.json").read_text())["format"] == fmt
    assert "compare" in capsys.readouterr().out
    if fmt == "gif":
        meta = iio.immeta(out / "rgb.gif")
        assert meta["duration"] == 100 and meta["loop"] == 0   # 1000 / 10 ms a frame, forever
    if fmt == "png":
        assert iio.imread(out / "compare_001.png").shape == (18 + 16, 16 + 4 + 16, 3)


# --- camera path files ----------------------------------------------------------------------------------------


def test_a_saved_camera_path_is_replayed_at_its_own_size_and_frame_rate(runs, tmp_path, capsys):
    from senerf.camerapath import write_camera_path
    from senerf.data import load_scene

    scene = load_scene(runs.scene)
    keys, f = scene.c2w[[5, 6, 7]], scene.intrinsics_all[0].fx
    k = Intrinsics(0.75 * f, 0.75 * f, 6.0, 5.0, 12, 10)     # not the fit's 16 x 16
    cam = write_camera_path(tmp_path / "cam.json", keys, k, fps=8.0, frames=3)
    assert main([str(runs.st), "--path", str(cam), "--quiet"]) == 0
    out = runs.st / "render" / "cam_iter1"
    assert f"in {out}" in capsys.readouterr().out
    record = json.loads((out / "path.json").read_text())
    np.testing.assert_allclose(record["c2w"], keys, atol=1e-12)   # frames == keyframes: the keyframes themselves
    assert record["intrinsics"] == [[k.fx, k.fy, 6.0, 5.0, 12, 10]] * 3
    assert record["path"] == str(cam) and record["fps"] == 8.0
    meta, video = _decode(out / "rgb.mp4")
    assert meta["size"] == (12, 10) and meta["fps"] == 8.0 and len(video) == 3
    # --frames resamples the path (through its first and last keyframe), --scale and --fps apply
    assert main([str(runs.st), "--path", str(cam), "--frames", "5", "--scale", "2", "--fps", "4", "--quiet",
                 "--format", "png", "--out", str(tmp_path / "o")]) == 0
    record = json.loads((tmp_path / "o" / "path.json").read_text())
    np.testing.assert_allclose(np.array(record["c2w"])[[0, -1]], keys[[0, -1]], atol=1e-9)
    assert len(record["c2w"]) == 5 and record["intrinsics"][0][4:] == [24, 20] and record["fps"] == 4.0
    assert iio.imread(tmp_path / "o" / "rgb_004.png").shape == (20, 24, 3)


def test_a_nerfstudio_camera_path_is_accepted(runs, tmp_path):
    from senerf.data import load_scene

    c2w = load_scene(runs.scene).c2w[[5, 6]]
    gl = c2w @ np.diag([1.0, -1.0, -1.0, 1.0])   # nerfstudio's poses are OpenGL camera-to-world
    doc = dict(render_width=16, render_height=14, fps=24,
               camera_path=[dict(camera_to_world=m.reshape(-1).tolist(), fov=50.0) for m in gl])
    (tmp_path / "camera_path.json").write_text(json.dumps(doc))
    out = tmp_path / "o"
    assert main([str(runs.st), "--path", str(tmp_path / "camera_path.json"), "--out", str(out), "--quiet"]) == 0
    record = json.loads((out / "path.json").read_text())
    np.testing.assert_allclose(record["c2w"], c2w, atol=1e-12)
    fy = 7.0 / np.tan(np.radians(25.0))   # half the height over the tangent of half the vertical field of view
    np.testing.assert_allclose(record["intrinsics"][0], [fy, fy, 8.0, 7.0, 16, 14])
    meta, video = _decode(out / "rgb.mp4")
    assert meta["size"] == (16, 14) and meta["fps"] == 24.0 and len(video) == 2


@pytest.mark.parametrize("content, needle", [
    (None, "--path: '{cam}' is neither orbit, spiral, test nor a camera path file (not found)"),
    ("{not json", "cannot be read as JSON"),
    ("[1, 2]", "is neither a senerf camera path"),
    ('{"senerf_camera_path": 1, "keyframes": []}', "keyframes: expected a non-empty list"),
])
def test_a_bad_camera_path_file_is_one_line_naming_it_and_writes_nothing(runs, tmp_path, capsys, content, needle):
    cam = tmp_path / "cam.json"
    if content is not None:
        cam.write_text(content)
    run = _copy(runs.st, tmp_path)
    assert main([str(run), "--path", str(cam), "--quiet"]) == 2
    assert (needle.format(cam=cam) if content is None else f"{cam}: {needle}") in _error(capsys)
    assert not (run / "render").exists()


def test_a_camera_paths_frame_rate_over_50_is_refused_for_a_gif_only(runs, tmp_path, capsys):
    from senerf.camerapath import write_camera_path
    from senerf.data import load_scene

    scene = load_scene(runs.scene)
    cam = write_camera_path(tmp_path / "cam.json", scene.c2w[[5]], scene.intrinsics_all[5], fps=60.0, frames=2)
    argv = [str(runs.st), "--path", str(cam), "--quiet", "--out"]
    assert main([*argv, str(tmp_path / "gif"), "--format", "gif"]) == 2
    assert "--fps: a GIF plays at most 50 frames a second, got 60 (the camera path file's)" in _error(capsys)
    assert main([*argv, str(tmp_path / "gif"), "--format", "gif", "--fps", "30"]) == 0
    assert main([*argv, str(tmp_path / "mp4")]) == 0
    assert _decode(tmp_path / "mp4" / "rgb.mp4")[0]["fps"] == 60.0


# --- orbits and spirals ---------------------------------------------------------------------------------------


def _k(f):
    return Intrinsics(f, f, 8.0, 8.0, 16, 16)


def _ring_run(train, near=None, far=None, ndc=False):
    """A stand-in run: four cameras on a ring of radius 4 at height 1, looking at the origin, focal 10-40."""
    from senerf.geometry import look_at

    eyes = np.array([[4.0, 0.0, 1.0], [0.0, 4.0, 1.0], [-4.0, 0.0, 1.0], [0.0, -4.0, 1.0]])
    scene = types.SimpleNamespace(c2w=look_at(eyes, np.zeros(3), up=(0.0, 0.0, 1.0)), near=near, far=far,
                                  intrinsics_all=[_k(10.0), _k(20.0), _k(30.0), _k(40.0)])
    return types.SimpleNamespace(scene=scene, model=types.SimpleNamespace(ndc=ndc), train_idx=np.array(train),
                                 test_idx=np.array([3, 0]))


def test_each_path_takes_the_intrinsics_of_its_own_views():
    run = _ring_run([2, 1], near=1.0, far=8.0)
    _, ks = path_cameras(run, "test", 0)
    assert [k.fx for k in ks] == [40.0, 10.0]
    _, ks = path_cameras(run, "test", 0, scale=2.0)
    assert [(k.fx, k.width) for k in ks] == [(80.0, 32), (20.0, 32)]
    for path in ("orbit", "spiral"):
        _, ks = path_cameras(run, path, 3)
        assert [k.fx for k in ks] == [30.0] * 3   # the first training view's


def test_the_spiral_focuses_by_the_scenes_bounds_or_on_the_point_the_cameras_look_at():
    from senerf.geometry import spiral_focus_depth, spiral_path

    run = _ring_run([0, 1], near=2.0, far=6.0)
    np.testing.assert_allclose(path_cameras(run, "spiral", 5)[0],
                               spiral_path(run.scene.c2w[[0, 1]], 5, spiral_focus_depth(2.0, 6.0)), atol=1e-12)
    # no bounds (an object): by hand, the inputs' mean centre is (2, 2, 1), the origin sqrt(4 + 4 + 1) = 3 from it
    np.testing.assert_allclose(path_cameras(_ring_run([0, 1]), "spiral", 5)[0],
                               spiral_path(run.scene.c2w[[0, 1]], 5, focus_depth=3.0), atol=1e-12)


def test_one_training_view_orbits_the_point_all_the_scenes_cameras_look_at():
    """One input camera has no point it looks at by itself: the orbit falls back on all the scene's cameras."""
    from senerf.geometry import look_at

    eyes = np.array([[4.0, 0.0, 1.0], [0.0, 3.0, 2.0], [-2.0, -2.0, 1.0]])
    scene = types.SimpleNamespace(c2w=look_at(eyes, np.zeros(3), up=(0.0, 0.0, 1.0)),
                                  intrinsics_all=[_k(10.0)] * 3, near=None, far=None)
    run = types.SimpleNamespace(scene=scene, model=types.SimpleNamespace(ndc=False), train_idx=np.array([1]))
    c2w, _ = path_cameras(run, "orbit", 4, elevation=30.0)
    r = np.linalg.norm(eyes[1])
    for pose in c2w:   # about the origin, at input 1's distance, 30 degrees above the horizon of its image up
        np.testing.assert_allclose(np.linalg.norm(pose[:3, 3]), r, atol=1e-9)
        np.testing.assert_allclose(pose[:3, 2], -pose[:3, 3] / r, atol=1e-9)
        np.testing.assert_allclose(np.degrees(np.arcsin(pose[:3, 3] @ -scene.c2w[1, :3, 1] / r)), 30.0, atol=1e-9)


def test_paths_a_scene_cannot_have_are_refused_naming_path():
    parallel = np.stack([np.eye(4)] * 3)   # three cameras on the x axis looking along +z: no common point
    parallel[:, 0, 3] = (0.0, 1.0, 2.0)
    scene = types.SimpleNamespace(c2w=parallel, intrinsics_all=[_K8] * 3, near=None, far=None)
    run = types.SimpleNamespace(scene=scene, model=types.SimpleNamespace(ndc=False), train_idx=np.array([0, 1]),
                                test_idx=np.array([2]))
    for path in ("orbit", "spiral"):
        with pytest.raises(InputError, match=f"no {path} for this scene") as info:
            path_cameras(run, path, 3)
        assert info.value.field == "--path"
    np.testing.assert_array_equal(path_cameras(run, "test", 0)[0], parallel[[2]])   # what the line suggests works
    for bad in ("zigzag", "Orbit"):
        with pytest.raises(InputError, match="--path"):
            path_cameras(run, bad, 3)
    with pytest.raises(InputError, match="--path: an orbit goes behind a forward-facing"):
        path_cameras(_ring_run([0, 1], ndc=True), "orbit", 3)
    opposed = types.SimpleNamespace(c2w=np.stack([np.eye(4), np.diag([-1.0, 1.0, -1.0, 1.0])]),
                                    intrinsics_all=[_K8] * 2, near=1.0, far=4.0)   # optical axes cancel out
    with pytest.raises(InputError, match="--path: no spiral for this scene"):
        path_cameras(types.SimpleNamespace(**{**vars(run), "scene": opposed}), "spiral", 3)


def test_forward_facing_runs_default_to_the_spiral_of_60_frames(runs, tmp_path, capsys, monkeypatch):
    import dataclasses

    real = fly.load_run

    def forward_facing(*a, **k):
        run = real(*a, **k)
        return dataclasses.replace(run, scene=dataclasses.replace(run.scene, kind="forward_facing", near=2.0, far=6.0))
    rendered = []

    def stop(run, c2w, intrinsics, **k):
        rendered.append(len(c2w))
        raise KeyboardInterrupt
    monkeypatch.setattr(fly, "load_run", forward_facing)
    monkeypatch.setattr(fly, "render_frames", stop)
    assert main([str(runs.base), "--out", str(tmp_path / "o"), "--quiet"]) == 130
    assert "spiral path: 60 frames at 16x16" in capsys.readouterr().out and rendered == [60]
    assert main([str(runs.base), "--out", str(tmp_path / "o"), "--elevation", "10"]) == 2
    assert "--elevation" in _error(capsys)


# --- bad input -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("flags, needle", [
    (["--iteration", "2"], "--iteration: iteration 2 is not finished"),
    (["--path", "test", "--elevation", "10"], "--elevation"),
    (["--scale", "0.3"], "--scale"),
    (["--scale", "65"], "--scale"),
    (["--frames", "0"], "--frames"),
    (["--frames", "10001"], "--frames"),
    (["--fps", "0.001"], "--fps"),   # a GIF delay over 655.35 s
    (["--fps", "241"], "--fps"),
    (["--fps", "60", "--format", "gif"], "--fps: a GIF plays at most 50 frames a second, got 60"),
    (["--format", "avi"], "--format"),
    (["--elevation", "90"], "--elevation"),
    (["--path", "test", "--frames", "5"], "--frames"),
    (["--path", "zigzag"], "--path"),
    (["--frames", "10000", "--scale", "64"], "--frames: 10000 frames at 1024x1024"),   # the memory check
    (["--device", "tpu"], "--device"),
    (["--threads", "0"], "--threads"),
])
def test_bad_flags_are_one_line_exit_2_and_write_nothing(runs, tmp_path, capsys, flags, needle):
    out = tmp_path / "o"
    assert main([str(runs.st), "--out", str(out), "--quiet", *flags]) == 2
    assert needle in _error(capsys)
    assert not out.exists() and _beside(out) == []


def test_out_problems_are_found_before_the_run_is_loaded(tmp_path, capsys):
    empty = tmp_path / "empty"      # not a run: loading it would fail with "run.json: not found"
    empty.mkdir()
    assert main([str(empty), "--out", str(empty)]) == 2
    assert f"{empty}: exists" in _error(capsys)
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main([str(empty), "--out", str(afile), "--overwrite"]) == 2
    assert f"{afile}: exists and is not a folder" in _error(capsys)
    assert afile.read_text() == "x"


def test_folders_that_are_not_finished_runs_are_refused_by_name(runs, tmp_path, capsys):
    assert main([str(tmp_path / "nowhere")]) == 2
    assert "nowhere: not a folder" in _error(capsys)
    assert main([str(tmp_path)]) == 2
    assert str(tmp_path / "run.json") in _error(capsys)
    run = _copy(runs.base, tmp_path)
    (run / "checkpoints" / "iter_0_train.pt").unlink()
    assert main([str(run)]) == 2
    assert "iter_0_train.pt" in _error(capsys)
    (run / "metrics.json").unlink()   # a fit killed in its first iteration: run.json, no metrics.json
    assert main([str(run)]) == 2
    assert f"{run}: holds no finished iteration yet" in _error(capsys)
    old = _copy(runs.base, tmp_path / "old")   # a run folder of an earlier senerf: refused, not migrated
    _edit_json(old / "run.json", lambda r: r.update(senerf_run=1))
    assert main([str(old)]) == 2
    assert str(old / "run.json") in _error(capsys)
    moved = _copy(runs.base, tmp_path / "moved")
    _edit_json(moved / "run.json", lambda r: r.update(scene_dir=str(tmp_path / "gone")))
    assert main([str(moved)]) == 2
    assert "gone" in _error(capsys)
    assert not any((tmp_path / name / "render").exists() for name in ("base", "old", "moved"))


def _nan_field(state):
    key = next(k for k, v in state["field"].items() if v.is_floating_point())
    state["field"][key] = state["field"][key] * float("nan")


@pytest.mark.parametrize("file, edit, needle", [
    ("run.json", lambda r: r["settings"]["model"].update(resolution="8"), "run.json: settings.model.resolution"),
    ("run.json", lambda r: r["settings"]["model"].update(field="zzz"), "run.json: settings.model.field"),
    ("run.json", lambda r: r["settings"]["model"].update(bogus=1), "run.json: settings.model"),
    ("run.json", lambda r: r["settings"]["model"].update(occupancy_resolution=32), "iter_0_train.pt"),
    ("run.json", lambda r: r["settings"]["train"].update(seed=True), "run.json: settings.train.seed"),
    ("run.json", lambda r: r["settings"].pop("train"), "run.json: settings.train"),
    ("run.json", lambda r: r.update(scene_dir=5), "5: scene folder not found"),
    ("run.json", lambda r: r["settings"].update(downscale=0), "downscale"),
    ("metrics.json", lambda m: m.update(train_views=[0, 8]), "metrics.json: train_views"),   # 8 views in the scene
    ("metrics.json", lambda m: m.update(train_views=[0, 1.0]), "metrics.json: train_views"),
    ("metrics.json", lambda m: m.update(test_views=[]), "metrics.json: test_views"),
    ("metrics.json", lambda m: m["iterations"][0].update(iteration="x"), "metrics.json: iterations"),
    ("metrics.json", lambda m: m.update(iterations=None), "metrics.json"),
    ("checkpoints/iter_0_train.pt", lambda s: s.update(field=5), "iter_0_train.pt"),
    ("checkpoints/iter_0_train.pt", _nan_field, "iter_0_train.pt"),
    ("checkpoints/iter_0_train.pt", lambda s: s.update(format="other"), "iter_0_train.pt"),
])
def test_a_damaged_run_folder_is_one_line_naming_the_file_and_field(runs, tmp_path, capsys, file, edit, needle):
    run = _copy(runs.base, tmp_path)
    (_edit_checkpoint if file.endswith(".pt") else _edit_json)(run / file, edit)
    assert main([str(run), "--quiet", "--frames", "2"]) == 2
    assert needle in _error(capsys)
    assert not (run / "render").exists()


def test_a_scene_whose_files_changed_since_the_fit_is_rendered_with_a_warning(runs, tmp_path, capsys):
    run = _copy(runs.base, tmp_path)
    assert main([str(run), "--path", "test", "--out", str(tmp_path / "same"), "--quiet"]) == 0
    assert "warning" not in capsys.readouterr().err   # the files the fit read, unchanged
    _edit_json(run / "run.json", lambda r: r["scene_files"].update({"test/r_1.png": "0" * 16}))
    assert main([str(run), "--path", "test", "--out", str(tmp_path / "changed"), "--quiet"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"senerf-render: warning: {run / 'run.json'}")
    assert "test/r_1.png" in err[0]
    assert (tmp_path / "changed" / "rgb.mp4").is_file()
    # a run of some views only: the photos it did not read are not compared (no false warning)
    assert main([str(runs.st), "--path", "test", "--out", str(tmp_path / "st"), "--quiet"]) == 0
    assert "warning" not in capsys.readouterr().err


def _memory(monkeypatch, gib):
    monkeypatch.setattr(fly, "physical_memory_bytes", lambda: None if gib is None else int(gib * 2**30))


@pytest.mark.parametrize("frames, compare, fits", [("25", False, True), ("26", False, False), ("12", True, True),
                                                   ("13", True, False)])
def test_a_path_that_would_not_fit_in_memory_is_refused_at_80_percent(runs, tmp_path, capsys, monkeypatch, frames,
                                                                      compare, fits):
    # 32 bytes a pixel and render: a 1024x1024 frame is 32 MiB; 80 % of 1 GiB is 819.2 MiB (25 frames: 800 MiB,
    # 26: 832 MiB; with --compare each frame is rendered twice)
    _memory(monkeypatch, 1)
    monkeypatch.setattr(fly, "render_frames", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    flags = ["--frames", frames, "--scale", "64", "--quiet", *(["--compare"] if compare else [])]
    status = main([str(runs.st), "--out", str(tmp_path / "o"), *flags])
    if fits:
        assert status == 130   # on to the render (interrupted here)
    else:
        assert status == 2 and f"--frames: {frames} frames at 1024x1024" in _error(capsys)
    _memory(monkeypatch, None)   # not a POSIX system: no check
    assert main([str(runs.st), "--out", str(tmp_path / "o"), "--frames", "10000", "--scale", "64", "--quiet"]) == 130


def test_a_render_without_the_compiled_kernel_says_so(runs, tmp_path, capsys, monkeypatch):
    import senerf.fields.ckernel as ck

    monkeypatch.setattr(ck, "load_kernel", lambda dtype, n_features=16: None)
    monkeypatch.setitem(ck._STATUS, "status", "unavailable: OSError: no C compiler found")
    out = tmp_path / "t"
    assert main([str(runs.base), "--path", "test", "--out", str(out), "--quiet"]) == 0
    assert "senerf-render: warning: the compiled K-Planes kernel cannot be used" in capsys.readouterr().err
    assert (out / "path.json").is_file()


# --- writing the output: whole or not at all --------------------------------------------------------------------


def _frames(out: Path) -> int:
    return len(json.loads((out / "path.json").read_text())["c2w"])


def test_an_existing_out_is_refused_without_overwrite_and_replaced_whole_with_it(runs, tmp_path, capsys):
    out = tmp_path / "r"
    argv = [str(runs.base), "--out", str(out), "--quiet", "--format", "png"]
    assert main([*argv, "--frames", "3"]) == 0
    assert main([*argv, "--frames", "2"]) == 2
    assert f"{out}: exists; use --overwrite" in _error(capsys)
    assert _frames(out) == 3
    assert main([*argv, "--overwrite", "--frames", "2"]) == 0     # replaced whole: no frame of the old path left
    assert _frames(out) == 2 and sorted(p.name for p in out.glob("rgb_*.png")) == ["rgb_000.png", "rgb_001.png"]
    assert _beside(out) == []
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main([str(runs.base), "--out", str(empty), "--frames", "2", "--quiet"]) == 2   # exists
    capsys.readouterr()
    assert main([str(runs.base), "--out", str(empty), "--frames", "2", "--quiet", "--overwrite"]) == 0
    assert _frames(empty) == 2


def test_overwrite_never_removes_a_folder_senerf_render_did_not_write(runs, tmp_path, capsys):
    for i, content in enumerate(("notes", "[1, 2]")):   # a folder of the user's; a path.json that is not ours
        mine = tmp_path / f"mine{i}"
        mine.mkdir()
        (mine / ("notes.txt" if i == 0 else "path.json")).write_text(content)
        assert main([str(runs.base), "--out", str(mine), "--overwrite", "--quiet"]) == 2
        assert f"{mine}: is not a senerf-render output" in _error(capsys)
        assert [p.read_text() for p in mine.iterdir()] == [content]


def test_an_interrupt_mid_render_or_mid_write_leaves_no_output_and_no_partial_folder(runs, tmp_path, capsys,
                                                                                     monkeypatch):
    import importlib

    import senerf.train
    from tests.conftest import CallSpy

    evaluate = importlib.import_module("senerf.train.evaluate")   # (``senerf.train.evaluate`` is the function)

    out = tmp_path / "a" / "b" / "out"
    spy = CallSpy(evaluate.camera_rays)
    monkeypatch.setattr(evaluate, "camera_rays", spy)
    spy.stop_at = 2   # Ctrl-C while rendering the second frame
    png = ["--frames", "3", "--quiet", "--format", "png"]
    assert main([str(runs.base), "--out", str(out), *png]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()   # nothing was created for it
    monkeypatch.undo()
    writes = CallSpy(senerf.train.write_png)
    monkeypatch.setattr(senerf.train, "write_png", writes)
    writes.stop_at = 4   # Ctrl-C while writing the frames
    assert main([str(runs.base), "--out", str(out), *png]) == 130
    assert not out.exists() and _beside(out) == []
    assert main([str(runs.base), "--out", str(tmp_path / "old"), *png]) == 0
    writes.calls = 0   # over an earlier output with --overwrite: the earlier output stays whole
    assert main([str(runs.base), "--out", str(tmp_path / "old"), *png, "--frames", "2", "--overwrite"]) == 130
    assert _frames(tmp_path / "old") == 3 and len(list((tmp_path / "old").glob("*.png"))) == 6
    assert _beside(tmp_path / "old") == []
    writes.calls, writes.stop_at = 0, None
    assert main([str(runs.base), "--out", str(out), *png]) == 0   # the rerun starts over
    assert _frames(out) == 3


def test_an_interrupt_between_the_renames_puts_the_earlier_output_back(runs, tmp_path, monkeypatch):
    out = tmp_path / "o"
    assert main([str(runs.base), "--out", str(out), "--frames", "3", "--quiet"]) == 0
    real = Path.rename

    def interrupted(self, target):
        if self.name == "new" and Path(target) == out:
            raise KeyboardInterrupt   # SIGTERM, as senerf's commands raise it, after the earlier output moved aside
        return real(self, target)
    monkeypatch.setattr(Path, "rename", interrupted)
    assert main([str(runs.base), "--out", str(out), "--frames", "2", "--quiet", "--overwrite"]) == 130
    assert _frames(out) == 3 and _beside(out) == []


def test_a_failed_write_is_one_line_and_keeps_the_earlier_output(runs, tmp_path, capsys, monkeypatch):
    import imageio_ffmpeg

    import senerf.train

    out = tmp_path / "o"
    assert main([str(runs.base), "--out", str(out), "--frames", "3", "--quiet"]) == 0

    def full_disk(path, image):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(senerf.train, "write_png", full_disk)
    assert main([str(runs.base), "--out", str(out), "--frames", "2", "--quiet", "--overwrite", "--format", "png"]) == 2
    assert f"{out}: cannot write there (No space left on device)" in _error(capsys)
    assert _frames(out) == 3 and _beside(out) == []
    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", lambda: shutil.which("false"))   # ffmpeg fails, silently
    assert main([str(runs.base), "--out", str(out), "--frames", "2", "--quiet", "--overwrite"]) == 2
    assert f"{out}: cannot write there (ffmpeg: exit status 1)" in _error(capsys)
    assert _frames(out) == 3 and _beside(out) == []


_KILLED_MID_WRITE = """
import os, signal, sys
import senerf.train
real, calls = senerf.train.write_png, []
def write_png(path, image):
    calls.append(path)
    if len(calls) == 3:
        os.kill(os.getpid(), signal.SIGKILL)
    real(path, image)
senerf.train.write_png = write_png
from senerf.flythrough import main
main(sys.argv[1:])
"""


def test_a_render_killed_outright_leaves_a_partial_folder_the_next_render_removes(runs, tmp_path, capsys):
    out = tmp_path / "o"
    argv = [str(runs.base), "--out", str(out), "--frames", "2", "--quiet", "--format", "png"]
    killed = subprocess.run([sys.executable, "-c", _KILLED_MID_WRITE, *argv], capture_output=True, timeout=300,
                            cwd=Path(fly.__file__).parents[1])
    assert killed.returncode == -signal.SIGKILL, killed.stderr.decode()
    assert not out.exists() and _beside(out) == [".o.partial"]
    assert main(argv) == 0
    assert f"removed {tmp_path / '.o.partial'}" in capsys.readouterr().out
    assert _beside(out) == [] and _frames(out) == 2
