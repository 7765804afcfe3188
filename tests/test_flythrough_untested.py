"""Lines of senerf/flythrough.py no other in-process test ran: unreadable run files, paths a scene cannot have,
the progress bar, and the guards around process and memory queries.  No fit is needed: runs and scenes are
stand-ins holding what the functions read."""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

import senerf.flythrough as fly
from senerf.errors import InputError
from senerf.geometry import Intrinsics

_K8 = Intrinsics(8.0, 8.0, 4.0, 4.0, 8, 8)


@pytest.mark.parametrize("content, reason", [
    (b"{", "Expecting property name enclosed in double quotes"),
    (b'{"a": 1}}', "Extra data"),
    (b'{"scene_dir": "\xff"}', "'utf-8' codec can't decode byte 0xff"),
    (None, "Is a directory"),
])
def test_a_run_json_that_cannot_be_read_is_one_line_naming_it(tmp_path, content, reason):
    # Catches: _read_json's except (OSError, UnicodeDecodeError, JSONDecodeError) deleted (a traceback, exit 1).
    run_json = tmp_path / "run.json"
    if content is None:
        run_json.mkdir()
    else:
        run_json.write_bytes(content)
    with pytest.raises(InputError, match=r"^[^\n]*run\.json: cannot be read as JSON \(.*" + reason) as info:
        fly.load_fitted_run(tmp_path)
    assert info.value.file == str(run_json) and info.value.field is None
    run_json.unlink() if content is not None else run_json.rmdir()
    run_json.write_text('{"model": {}}')   # readable: the next check speaks (no metrics.json yet)
    with pytest.raises(InputError, match="holds no finished iteration yet"):
        fly.load_fitted_run(tmp_path)


def test_views_whose_photos_are_where_the_fit_saw_them_keep_their_indices(tmp_path):
    # Catches: _views_by_photo's "names match at idx: return idx" deleted; the lookup by name that follows gives a
    # photo listed twice the index of its last listing (view 1 here), not the one the fit trained on.
    scene = types.SimpleNamespace(root=tmp_path, n_images=3,
                                  image_paths=(tmp_path / "a.png", tmp_path / "a.png", tmp_path / "b.png"))
    metrics = {"train_images": ["a.png", "b.png"]}
    got = fly._views_by_photo(metrics, "train_images", tmp_path / "metrics.json", scene, np.array([0, 2]))
    assert got.tolist() == [0, 2]
    moved = fly._views_by_photo({"train_images": ["b.png"]}, "train_images", tmp_path, scene, np.array([0]))
    assert moved.tolist() == [2]   # b.png is view 2 now: found by its name


@pytest.mark.parametrize("metrics", [
    {},                                         # a run from before senerf-fit recorded the photos' names
    {"train_images": None},
    {"train_images": ["b.png"]},                # one name for two views
    {"train_images": ["b.png", 3]},             # not all names
    {"train_images": "ab"},                     # a string of two characters for two views
])
def test_views_without_usable_photo_names_are_taken_by_index(tmp_path, metrics):
    # Catches: _views_by_photo's early "return idx" for runs without (usable) names deleted (the lookup by name then
    # iterated None or a string, or failed on a missing photo the run never named).
    scene = types.SimpleNamespace(root=tmp_path, n_images=3,
                                  image_paths=(tmp_path / "a.png", tmp_path / "b.png", tmp_path / "c.png"))
    got = fly._views_by_photo(metrics, "train_images", tmp_path / "metrics.json", scene, np.array([2, 0]))
    assert got.tolist() == [2, 0]
    named = fly._views_by_photo({"train_images": ["b.png", "a.png"]}, "train_images", tmp_path, scene, np.array([2, 0]))
    assert named.tolist() == [1, 0]   # usable names win over the indices


def _stand_in(c2w: np.ndarray, train=(0, 1), near=None, far=None):
    scene = types.SimpleNamespace(c2w=c2w, intrinsics_all=[_K8] * len(c2w), near=near, far=far)
    return types.SimpleNamespace(scene=scene, model=types.SimpleNamespace(ndc=False), train_idx=np.array(train),
                                 test_idx=np.array([len(c2w) - 1]))


def _parallel() -> np.ndarray:
    """Three cameras on the x axis, all looking along +z: their optical axes meet nowhere."""
    c2w = np.stack([np.eye(4)] * 3)
    c2w[:, 0, 3] = (0.0, 1.0, 2.0)
    return c2w


def test_no_orbit_or_spiral_around_cameras_that_look_along_parallel_axes():
    # Catches: path_cameras' second "except ValueError" (orbit about all cameras) or _common_point's ValueError ->
    # InputError deleted (a traceback), and the spiral of an object scene that has no point to focus on.  Before
    # 2026-11-23 the orbit's line repeated "--path:" inside itself, passed on the geometry's "pass the scene centre
    # explicitly" (no flag does that) and suggested --path spiral, which fails the same way here.
    run = _stand_in(_parallel())
    for path in ("orbit", "spiral"):
        with pytest.raises(InputError, match=rf"^--path: no {path} for this scene: its cameras look along parallel "
                                             r"axes, so there is no point they all look at; use --path test$") as info:
            fly.path_cameras(run, path, 3)
        assert info.value.field == "--path"
    c2w, _ = fly.path_cameras(run, "test", 0)   # what the line suggests works
    np.testing.assert_array_equal(c2w, run.scene.c2w[run.test_idx])
    c2w, ks = fly.path_cameras(_stand_in(_parallel(), near=1.0, far=4.0), "spiral", 3)   # bounds: no point needed
    assert c2w.shape == (3, 4, 4) and ks == (_K8,) * 3


@pytest.mark.parametrize("path", ["zigzag", "Orbit", ""])
def test_an_unknown_path_is_refused_by_name(path):
    # Catches: path_cameras' final else (unknown path) deleted (c2w was then unbound: UnboundLocalError).
    run = _stand_in(_parallel(), near=1.0, far=4.0)
    with pytest.raises(InputError, match=f"^--path: expected one of orbit, spiral, test, got {path!r}$"):
        fly.path_cameras(run, path, 3)
    c2w, ks = fly.path_cameras(run, "test", 0)   # a known one: the last view, its own camera
    np.testing.assert_array_equal(c2w, run.scene.c2w[[2]])


def _fake_renders(monkeypatch, fail_at: int | None = None) -> list:
    """``render_views`` replaced by a flat grey frame of the camera's size (``fail_at``: that call raises)."""
    import senerf.train

    calls = []

    def one(field, model, k, c2w, **kwargs):
        calls.append(1)
        if len(calls) == fail_at:
            raise KeyboardInterrupt
        h, w = k.height, k.width
        return dict(rgb=np.full((1, h, w, 3), 0.5, np.float32), z_depth=np.ones((1, h, w), np.float32),
                    acc=np.ones((1, h, w), np.float32))

    monkeypatch.setattr(senerf.train, "render_views", one)
    return calls


def _spy_bars(monkeypatch) -> list:
    import tqdm.auto

    made = []

    class Spy(tqdm.auto.tqdm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(tqdm.auto, "tqdm", Spy)
    return made


def _run():
    import torch

    from senerf.train import ModelConfig

    return types.SimpleNamespace(field=torch.nn.Linear(1, 1), occupancy=None, model=ModelConfig())


def test_the_progress_bar_counts_frames_says_how_many_were_read_back_and_is_closed(tmp_path, monkeypatch, capsys):
    # Catches: render_frames' bar.update(), its "N read back" postfix or its close() deleted, or the bar started at 0
    # when frames were read back.
    calls, bars = _fake_renders(monkeypatch), _spy_bars(monkeypatch)
    run, c2w = _run(), np.stack([np.eye(4)] * 3)
    fly.render_frames(run, c2w[:1], _K8, progress=False, resume=tmp_path / "rec")   # frame 0 kept
    assert bars == [] and len(calls) == 1                                            # progress=False: no bar
    out = fly.render_frames(run, c2w, _K8, progress=True, resume=tmp_path / "rec")
    assert out["read_back"] == 1 and len(calls) == 3
    (bar,) = bars
    assert (bar.total, bar.n, bar.postfix, bar.disable) == (3, 3, "1 read back", True)   # disable: closed
    err = capsys.readouterr().err
    assert "render" in err and "3/3" in err and "1 read back" in err
    fly.render_frames(run, c2w, _K8, progress=True)                                  # nothing read back
    assert bars[1].postfix is None and bars[1].n == 3


def test_the_progress_bar_is_closed_when_a_render_is_interrupted(monkeypatch):
    # Catches: the bar's close() moved out of render_frames' finally (an interrupt left the bar's line open).
    _fake_renders(monkeypatch, fail_at=2)
    bars = _spy_bars(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        fly.render_frames(_run(), np.stack([np.eye(4)] * 3), _K8, progress=True)
    (bar,) = bars
    assert bar.n == 1 and bar.disable


@pytest.mark.parametrize("error, tidied", [(ProcessLookupError, True), (PermissionError, False), (None, False)])
def test_a_temporary_folder_is_removed_only_when_its_process_is_gone(tmp_path, monkeypatch, error, tidied):
    # Catches: _process_gone's "except OSError: return False" deleted or returning True (a folder of a render running
    # under another user, which we may not signal, was removed under it).
    def kill(pid, sig):
        assert (pid, sig) == (4242, 0)
        if error is not None:
            raise error
    monkeypatch.setattr(fly.os, "kill", kill)
    partial = tmp_path / ".orbit_iter1.4242.abcd1234"
    partial.mkdir()
    (partial / fly._PARTIAL).touch()
    done = fly.recover_interrupted(tmp_path / "orbit_iter1")
    assert partial.exists() is not tidied
    assert done == ([f"removed {partial.name}, a partial folder an interrupted senerf-render left"] if tidied else [])


def test_without_a_memory_size_the_memory_check_is_skipped(monkeypatch):
    # Catches: _check_memory's "have is None: return" deleted (0.8 * None raised a TypeError on non-POSIX systems).
    big = [types.SimpleNamespace(width=4096, height=4096)] * 10000   # 5 TiB of frames
    monkeypatch.setattr(fly, "physical_memory_bytes", lambda: None)
    assert fly._check_memory(big, renders=2) is None
    monkeypatch.setattr(fly, "physical_memory_bytes", lambda: 2 ** 30)
    with pytest.raises(InputError, match="--frames: 10000 frames at 4096x4096 twice"):
        fly._check_memory(big, renders=2)


def test_an_unreadable_parent_while_tidying_does_not_stop_the_out_check(tmp_path, monkeypatch):
    # Catches: _check_out's "except OSError: pass" around recover_interrupted deleted (a parent it cannot list stopped
    # the command with a traceback before the write could name the problem).
    def unreadable(out: Path):
        raise PermissionError(13, "Permission denied", str(out.parent))
    monkeypatch.setattr(fly, "recover_interrupted", unreadable)
    assert fly._check_out(tmp_path / "new", overwrite=False) is False   # nothing written before: go on
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "frame.png").write_bytes(b"")   # an empty folder is no longer refused
    with pytest.raises(InputError, match="exists; use --overwrite"):   # the checks after it still run
        fly._check_out(tmp_path / "old", overwrite=False)
