"""Camera path files: senerf's keyframes round-trip and interpolate; nerfstudio's paths convert from OpenGL axes
and a vertical field of view; bad files are one line naming the file and the field."""

from __future__ import annotations

import json

import numpy as np
import pytest

from senerf.camerapath import read_camera_path, write_camera_path
from senerf.errors import InputError
from senerf.geometry import Intrinsics, look_at

_K = Intrinsics(40.0, 42.0, 31.5, 24.0, 64, 48)


def _keys() -> np.ndarray:
    eyes = np.array([[3.0, 0.0, 1.0], [0.0, 3.0, 1.5], [-3.0, 0.0, 1.0]])
    return np.stack([look_at(e, np.zeros(3), np.array([0.0, 0.0, 1.0])) for e in eyes])


def test_written_keyframes_read_back_as_the_same_cameras(tmp_path):
    keys = _keys()
    write_camera_path(tmp_path / "p.json", keys, _K, fps=12.5, frames=3)
    path = read_camera_path(tmp_path / "p.json")
    np.testing.assert_allclose(path.c2w, keys, atol=1e-12)
    assert path.intrinsics == (_K,) * 3 and path.fps == 12.5


def test_more_frames_pass_through_every_keyframe_and_interpolate_intrinsics(tmp_path):
    keys = _keys()
    k2 = Intrinsics(60.0, 62.0, 32.0, 24.0, 64, 48)
    write_camera_path(tmp_path / "p.json", keys[:2], [_K, k2], frames=2)
    path = read_camera_path(tmp_path / "p.json", frames=5)
    np.testing.assert_allclose(path.c2w[[0, 4]], keys[:2], atol=1e-9)
    assert path.intrinsics[2].fx == pytest.approx(50.0) and path.intrinsics[2].cx == pytest.approx(31.75)
    centres = path.c2w[:, :3, 3]   # linear between the two keyframe positions
    np.testing.assert_allclose(centres[2], keys[:2, :3, 3].mean(axis=0), atol=1e-12)


def test_a_nerfstudio_path_converts_opengl_poses_and_the_vertical_fov(tmp_path):
    keys = _keys()
    gl = keys.copy()
    gl[:, :3, 1:3] *= -1.0   # OpenCV (y down, z forward) -> OpenGL (y up, z back): negate the y and z axes
    doc = dict(render_width=80, render_height=60, fps=30, seconds=1.0,
               camera_path=[dict(camera_to_world=c.reshape(-1).tolist(), fov=90.0, aspect=80 / 60) for c in gl])
    (tmp_path / "camera_path.json").write_text(json.dumps(doc))
    path = read_camera_path(tmp_path / "camera_path.json")
    np.testing.assert_allclose(path.c2w, keys, atol=1e-12)
    k = path.intrinsics[0]
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == pytest.approx((30.0, 30.0, 40.0, 30.0, 80, 60))
    assert path.fps == 30 and len(read_camera_path(tmp_path / "camera_path.json", frames=7).c2w) == 7


@pytest.mark.parametrize("edit, field", [
    (lambda d: d.update(keyframes=[]), "keyframes"),
    (lambda d: d["keyframes"][1].update(c2w=np.diag([2.0, 1.0, 1.0, 1.0]).tolist()), "keyframes[1].c2w"),
    (lambda d: d["keyframes"][0].update(intrinsics=[1, 2, 3]), "keyframes[0].intrinsics"),
    (lambda d: d["keyframes"][0].update(intrinsics=[40, 40, 32, 24, 65, 48]), "keyframes"),
    (lambda d: d.update(frames=0), "frames"),
    (lambda d: d.update(fps=float("nan")), "fps"),
    (lambda d: d.update(senerf_camera_path=99), "senerf_camera_path"),
])
def test_a_bad_senerf_path_names_the_field(tmp_path, edit, field):
    write_camera_path(tmp_path / "p.json", _keys(), _K)
    doc = json.loads((tmp_path / "p.json").read_text())
    edit(doc)
    (tmp_path / "p.json").write_text(json.dumps(doc))
    with pytest.raises(InputError) as info:
        read_camera_path(tmp_path / "p.json")
    assert info.value.field == field and str(tmp_path / "p.json") in str(info.value)


def test_a_bad_nerfstudio_fov_or_a_foreign_file_is_refused(tmp_path):
    doc = dict(render_width=80, render_height=60, camera_path=[dict(camera_to_world=np.eye(4).ravel().tolist(),
                                                                    fov=180.0)])
    (tmp_path / "a.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"camera_path\[0\]\.fov"):
        read_camera_path(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(json.dumps({"frames": []}))
    with pytest.raises(InputError, match="neither a senerf camera path"):
        read_camera_path(tmp_path / "b.json")
    with pytest.raises(InputError, match="not found"):
        read_camera_path(tmp_path / "missing.json")

