"""senerf-view (senerf/viewer.py): the camera conversion, the frames it shows, its controls, and a real browser.

The run folder is made by :func:`senerf.fit` on a tiny procedural scene (a teacher and one student).  The browser
test drives headless Chromium (Debian's ``chromium`` package) and skips where none is installed.
"""

from __future__ import annotations

import json
import math
import shutil
import socket
import subprocess
import types
from pathlib import Path

import numpy as np
import pytest

import senerf
from senerf.geometry import Intrinsics
from senerf.viewer import ViewSettings, Viewer, camera_from_viser, frame_size, main, render_frame

_CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A teacher and one student (views 0, 1, 3 train, 4-5 test; one pseudo view per input)."""
    from senerf.procedural.export import export_blender_scene

    root = tmp_path_factory.mktemp("view")
    scene = export_blender_scene(root / "scene", n_train=4, n_val=0, n_test=2, width=16, height=16, seed=0)
    senerf.fit(scene, root / "run", views=[0, 1, 3], iterations=1, train=dict(steps=30, batch_rays=128),
               model=dict(n_samples=12, resolution=8), selftrain=dict(n_pseudo_per_input=1), progress=False,
               echo=lambda line: None)
    return root / "run"


def _wxyz(rot: np.ndarray) -> np.ndarray:
    """The unit quaternion (w first) of a rotation matrix, by scipy (independent of the code under test)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return np.array([w, x, y, z])


def _params(k: Intrinsics) -> tuple:
    return k.fx, k.fy, k.cx, k.cy, k.width, k.height


def _camera(c2w, fov, width, height):
    """A stand-in for a browser tab as viser hands it over: its camera and its notifications."""
    notes = []
    camera = types.SimpleNamespace(wxyz=_wxyz(c2w[:3, :3]), position=c2w[:3, 3].copy(), fov=fov,
                                   aspect=width / height)
    return types.SimpleNamespace(camera=camera, notes=notes, add_notification=lambda *a, **k: notes.append(a))


def test_a_viser_camera_is_the_opencv_pose_with_the_intrinsics_of_its_vertical_fov():
    # a quarter turn about the world y axis: the camera looks along world +x, its image down is world +y
    c2w, k = camera_from_viser((math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0), (1.0, 2.0, 3.0),
                               fov=2 * math.atan(0.5), width=40, height=20)
    np.testing.assert_allclose(c2w, [[0, 0, 1, 1], [0, 1, 0, 2], [-1, 0, 0, 3], [0, 0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(_params(k), (20.0, 20.0, 20.0, 10.0, 40, 20))   # f = (H / 2) / tan(fov / 2) = 10 / 0.5
    # a third of a turn about (1, 1, 1), given unnormalised: x -> y -> z -> x
    np.testing.assert_allclose(camera_from_viser((2.0, 2.0, 2.0, 2.0), (0, 0, 0), 1.0, 8, 8)[0][:3, :3],
                               [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)


def test_frame_size_keeps_the_pixel_budget_and_the_aspect():
    assert frame_size(1.0, 10000) == (100, 100)
    assert frame_size(16 / 9, 10000) == (133, 75)
    assert frame_size(0.01, 100) == (8, 100)   # no side below 8 pixels


def test_the_viewers_frame_is_the_runs_render_of_the_same_camera(run):
    from senerf.train import depth_to_color

    fitted = senerf.load_run(run)
    c2w = fitted.cameras.c2w[fitted.cameras.test[0]]
    fov = 2 * math.atan(0.75)   # f = (12 / 2) / 0.75 = 8
    viewer_c2w, k = camera_from_viser(_wxyz(c2w[:3, :3]), c2w[:3, 3], fov, 20, 12)
    expected = fitted.render(c2w, Intrinsics(8.0, 8.0, 10.0, 6.0, 20, 12))
    image, z, acc = render_frame(fitted, viewer_c2w, k)
    np.testing.assert_array_equal(image, np.round(np.clip(expected["rgb"][0], 0, 1) * 255).astype(np.uint8))
    np.testing.assert_allclose(z, expected["z_depth"][0], atol=1e-4)
    depth, _, _ = render_frame(fitted, viewer_c2w, k, show="depth")
    np.testing.assert_array_equal(depth, depth_to_color(expected["z_depth"][0], expected["acc"][0], background=1.0))


def test_the_iteration_and_show_menus_switch_the_field_its_pseudo_views_and_the_colouring(run):
    from senerf.config import SelfTrainConfig
    from senerf.selftrain import sample_pseudo_cameras

    fitted = senerf.load_run(run)
    viewer = Viewer(fitted, port=0)
    try:
        assert viewer.run.iteration == 1 and len(viewer.pseudo) == 3
        expected, _ = sample_pseudo_cameras(fitted.scene, fitted.train_idx, SelfTrainConfig(n_pseudo_per_input=1), 1)
        np.testing.assert_allclose([h.position for h in viewer.pseudo], expected[:, :3, 3], atol=1e-6)
        tab = _camera(fitted.cameras.c2w[4], 0.8, 16, 16)
        student = viewer.frame(tab, still=True)[0]
        viewer.iteration_menu.value = "0: teacher"   # as chosen in the panel
        assert viewer.run.iteration == 0 and viewer.pseudo == []
        teacher = viewer.frame(tab, still=True)[0]
        assert not np.array_equal(student, teacher)
        teacher_run = senerf.load_run(run, 0)
        np.testing.assert_array_equal(teacher, render_frame(teacher_run, *viewer.camera(tab, True))[0])
        viewer.show_mode.value = "depth"   # the panel's RGB / depth menu
        np.testing.assert_array_equal(viewer.frame(tab, still=False)[0],
                                      render_frame(teacher_run, *viewer.camera(tab, False), show="depth")[0])
    finally:
        viewer.stop()


def test_saved_keyframes_replay_as_the_cameras_they_were_taken_from(run, tmp_path):
    from senerf.camerapath import read_camera_path

    fitted = senerf.load_run(run)
    viewer = Viewer(fitted, ViewSettings(scale=2.0), port=0)
    try:
        tab = _camera(fitted.cameras.c2w[0], 2 * math.atan(0.5), 64, 16)
        assert viewer.save_path(tab) is None and not (run / "camera_path.json").exists()   # nothing to save
        viewer.add_keyframe(tab)
        tab.camera = _camera(fitted.cameras.c2w[1], 2 * math.atan(0.25), 32, 32).camera   # another aspect and fov
        viewer.add_keyframe(tab)
        viewer.path_file.value = str(tmp_path / "path.json")
        assert viewer.save_path(tab) == tmp_path / "path.json"
    finally:
        viewer.stop()
    replay = read_camera_path(tmp_path / "path.json", frames=2)
    np.testing.assert_allclose(replay.c2w, fitted.cameras.c2w[:2], atol=1e-9)
    # 2^2 x 256 pixels at 4:1 -> 64 x 16, the first keyframe's size, for both; each keeps its vertical fov
    np.testing.assert_allclose([_params(k) for k in replay.intrinsics],
                               [(16, 16, 32, 8, 64, 16), (32, 32, 32, 8, 64, 16)])
    from senerf.flythrough import main as render_main   # and senerf-render replays the file through them

    out = tmp_path / "replayed"
    assert render_main([str(run), "--path", str(tmp_path / "path.json"), "--format", "png", "--out", str(out),
                        "--quiet"]) == 0
    c2w = np.asarray(json.loads((out / "path.json").read_text())["c2w"])   # the file's 60 frames, key to key
    assert c2w.shape == (60, 4, 4) and len(list(out.glob("rgb_*.png"))) == 60
    np.testing.assert_allclose(c2w[[0, -1]], fitted.cameras.c2w[:2], atol=1e-9)


def test_a_busy_port_is_one_line_naming_it_and_the_flag(run, capsys):
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        port = sock.getsockname()[1]
        assert main([str(run), "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"senerf-view: error: --port: cannot listen on 127.0.0.1:{port} (Address already in use); choose "
                   "another with --port"]


def _screenshot(url: str, ready, folder: Path, timeout: float = 60.0) -> np.ndarray:
    """``(H, W, 3)`` uint8: headless Chromium's screenshot of ``url`` once ``ready()`` holds, taken through the
    DevTools protocol (a ``--screenshot`` run takes its picture at a time of its own choosing)."""
    import base64
    import io
    import json
    import time
    import urllib.request

    from PIL import Image
    from websockets.sync.client import connect

    browser = subprocess.Popen([_CHROMIUM, "--headless", "--no-sandbox", "--disable-dev-shm-usage", "--hide-scrollbars",
                                "--window-size=800,900", "--remote-debugging-port=0", f"--user-data-dir={folder}", url],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    start, page = time.monotonic(), None
    try:
        while page is None or not ready():
            assert time.monotonic() - start < timeout, "the page did not show a still frame in time"
            time.sleep(0.1)
            if page is None and (folder / "DevToolsActivePort").is_file():
                port = (folder / "DevToolsActivePort").read_text().split()[0]
                pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list"))
                page = next((p["webSocketDebuggerUrl"] for p in pages if p["type"] == "page"), None)
        with connect(page, max_size=None) as ws:
            ws.send(json.dumps(dict(id=1, method="Page.captureScreenshot", params=dict(format="png"))))
            while (reply := json.loads(ws.recv())).get("id") != 1:
                pass
    finally:
        browser.terminate()
        browser.wait(timeout=30)
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(reply["result"]["data"]))).convert("RGB"))


@pytest.mark.skipif(_CHROMIUM is None, reason="no Chromium found (Debian: apt-get install chromium); the browser "
                                              "test needs headless Chromium")
def test_a_browser_shows_the_rendered_scene_at_the_camera_the_server_set(run, tmp_path):
    import time

    from PIL import Image

    fitted = senerf.load_run(run)
    viewer = Viewer(fitted, ViewSettings(scale=4.0), port=0)
    viewer.show_cameras.value = False   # the panel's checkbox: no frustum drawn over the scene
    assert not any(h.visible for h in viewer.frustums + viewer.pseudo)
    shown, frame = [], viewer.frame   # a spy on the frames the viewer renders: (still, when)

    def spy(client, still):
        out = frame(client, still)
        shown.append((still, time.monotonic()))
        return out
    viewer.frame = spy
    try:   # a still frame shown a second ago, nothing since
        seen = _screenshot(viewer.address, lambda: shown and shown[-1][0] and time.monotonic() - shown[-1][1] > 1.0,
                           tmp_path)
    finally:
        viewer.stop()
    height, width = seen.shape[:2]
    # the first test view, at the still frame's size for this canvas (4^2 x 16 x 16 pixels)
    w, h = frame_size(width / height, 4096)
    view = fitted.cameras.test[0]
    c2w, k = fitted.cameras.c2w[view], fitted.cameras.intrinsics[view]
    f = h / 2 / (k.height / 2 / k.fy)
    expected = fitted.render(c2w, Intrinsics(f, f, w / 2, h / 2, w, h))["rgb"][0]
    small = np.asarray(Image.fromarray(seen).resize((w, h), Image.BOX), np.float64) / 255   # the frame's pixels
    region = (slice(int(np.ceil(h * 280 / height)), h), slice(int(np.ceil(w * 70 / width)), w))   # below the panel
    assert small[region].std() > 0.05, "the browser shows a blank image"
    np.testing.assert_allclose(small[region], expected[region], atol=0.05)
    assert np.abs(small[region] - expected[region]).mean() < 0.01
