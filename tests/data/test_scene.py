"""Tests of senerf/data/scene.py: the Scene container and compositing."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from senerf.data import Scene, scene_file_digests
from senerf.errors import InputError
from senerf.geometry import Intrinsics


def _scene(with_alpha=True, **over) -> Scene:
    k = Intrinsics(2.0, 2.0, 1.0, 1.0, 2, 2)
    rgb = np.array([[[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0.0, 0.0, 1.0], [0.5, 0.5, 0.5]]]], np.float32)
    a = np.array([[[1.0, 0.0], [0.5, 0.25]]], np.float32)
    fields = dict(name="t", root=Path("t"), rgb=rgb, alpha=a if with_alpha else None, intrinsics=k,
                  intrinsics_all=(k,), c2w=np.eye(4)[None], splits={"train": [0]}, image_paths=("a.png",))
    fields.update(over)
    return Scene(**fields)


def test_composite_over_background():
    # rgb * a + bg * (1 - a), pixel by pixel, bg = (0, 0, 1):
    # red a=1 -> red; green a=0 -> bg; blue a=.5 -> blue; grey .5 a=.25 -> .125 + .75 * bg.
    out = _scene().composite((0.0, 0.0, 1.0))
    want = [[[1, 0, 0], [0, 0, 1]], [[0, 0, 1], [0.125, 0.125, 0.875]]]
    np.testing.assert_allclose(out[0], want, atol=1e-7)
    assert out.dtype == np.float32


def test_composite_subset_matches_full():
    k = Intrinsics(2.0, 2.0, 1.0, 1.0, 2, 2)
    rng = np.random.default_rng(0)
    s = _scene(rgb=rng.random((3, 2, 2, 3), dtype=np.float32), alpha=rng.random((3, 2, 2), dtype=np.float32),
               intrinsics_all=(k,) * 3, c2w=np.broadcast_to(np.eye(4), (3, 4, 4)).copy(),
               image_paths=("a", "b", "c"))
    np.testing.assert_array_equal(s.composite(0.3, idx=[2, 0]), s.composite(0.3)[[2, 0]])
    with pytest.raises(IndexError):
        s.composite(0.3, idx=[3])


def test_composite_without_alpha_is_a_copy():
    s = _scene(with_alpha=False)
    out = s.composite(1.0)
    np.testing.assert_array_equal(out, s.rgb)
    assert out is not s.rgb


def test_composite_refuses_other_background_after_load_time_composite():
    s = dataclasses.replace(_scene(), background=(1.0, 1.0, 1.0))
    np.testing.assert_array_equal(s.composite(1.0), s.rgb)
    with pytest.raises(ValueError, match="reload"):
        s.composite(0.0)


def test_composite_bad_background():
    with pytest.raises(InputError):
        _scene().composite((2.0, 0.0, 0.0))


def test_splits_normalised_to_all_names():
    s = _scene()
    assert set(s.splits) == {"train", "val", "test"}
    assert s.splits["train"].dtype == np.int64 and s.splits["test"].size == 0


def test_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        _scene().name = "x"


def test_senerf_data_never_imports_torch():
    code = "import sys, senerf.data; assert 'torch' not in sys.modules, 'torch imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


# --- scene_file_digests / changed_files: what a run checks before it resumes -------------------------------

def test_scene_file_digests_are_sha256_of_the_bytes_named_relative_to_the_root(tmp_path):
    from senerf.data import scene_file_digests

    # golden: FIPS 180-2's first SHA-256 example, sha256("abc") = ba7816bf 8f01cfea 414140de ...
    (tmp_path / "poses.json").write_bytes(b"abc")
    (tmp_path / "img").mkdir()
    (tmp_path / "img" / "a.png").write_bytes(b"")   # sha256 of no bytes: e3b0c442 98fc1c14 ...
    outside = tmp_path.parent / f"{tmp_path.name}-outside.png"
    outside.write_bytes(b"abc")
    k = Intrinsics(2.0, 2.0, 1.0, 1.0, 2, 2)
    s = _scene(root=tmp_path, rgb=np.zeros((2, 2, 2, 3), np.float32), alpha=None, intrinsics_all=(k, k),
               c2w=np.broadcast_to(np.eye(4), (2, 4, 4)).copy(), image_paths=(tmp_path / "img" / "a.png", outside),
               source_files=(tmp_path / "poses.json", tmp_path / "poses.json"))
    assert s.source_files == (tmp_path / "poses.json",)   # each file once
    assert scene_file_digests(s) == {"img/a.png": "e3b0c44298fc1c14", "poses.json": "ba7816bf8f01cfea",
                                     str(outside.resolve()): "ba7816bf8f01cfea"}
    assert scene_file_digests(s, views=[0]) == {"img/a.png": "e3b0c44298fc1c14", "poses.json": "ba7816bf8f01cfea"}
    # a photo linked in from elsewhere is named where the scene has it, and hashed as what it points to
    (tmp_path / "img" / "a.png").unlink()
    (tmp_path / "img" / "a.png").symlink_to(outside)
    assert scene_file_digests(s, views=[0])["img/a.png"] == "ba7816bf8f01cfea"
    (tmp_path / "img" / "a.png").unlink()
    with pytest.raises(InputError, match=r"a\.png: cannot be read any more"):
        scene_file_digests(s, views=[0])


def test_scene_file_digests_of_some_views_hash_their_photos_and_the_pose_files(tmp_path):
    for name, data in (("poses.json", b"abc"), ("0.png", b""), ("1.png", b"abc"), ("2.png", b"x")):
        (tmp_path / name).write_bytes(data)
    k = Intrinsics(2.0, 2.0, 1.0, 1.0, 2, 2)
    s = _scene(root=tmp_path, rgb=np.zeros((3, 2, 2, 3), np.float32), alpha=None, intrinsics_all=(k,) * 3,
               c2w=np.broadcast_to(np.eye(4), (3, 4, 4)).copy(),
               image_paths=tuple(tmp_path / f"{i}.png" for i in range(3)), source_files=(tmp_path / "poses.json",))
    # golden: sha256("abc") = ba7816bf..., sha256("") = e3b0c442...
    assert scene_file_digests(s, [0, 1]) == {"0.png": "e3b0c44298fc1c14", "1.png": "ba7816bf8f01cfea",
                                             "poses.json": "ba7816bf8f01cfea"}
    (tmp_path / "2.png").unlink()   # a photo the views do not include is not read
    assert sorted(scene_file_digests(s, [0, 1])) == ["0.png", "1.png", "poses.json"]


def test_changed_files_names_every_difference():
    from senerf.data.scene import changed_files

    assert changed_files({"a": "1", "b": "2"}, {"a": "1", "b": "2"}) == []
    assert changed_files({"a": "1", "b": "2"}, {"b": "3", "c": "4"}) == [
        "a was read then, not now", "b changed", "c is read now, not then"]


def test_each_loader_records_the_files_it_read_its_cameras_from(tmp_path):
    from senerf.data import load_scene
    from senerf.procedural.export import export_blender_scene

    root = export_blender_scene(tmp_path / "s", n_train=3, n_val=1, n_test=2, width=8, height=8, seed=0)
    assert load_scene(root).source_files == tuple(root / f"transforms_{s}.json" for s in ("train", "val", "test"))


def test_a_scene_read_through_a_symlinked_folder_keeps_its_names(tmp_path):
    # The mutation audit: a resolved (realpath) root would name every file by its absolute path when the
    # scene folder is reached through a link, as dataset folders often are.
    from senerf.data import load_scene, scene_file_digests, view_names
    from senerf.procedural.export import export_blender_scene

    real = export_blender_scene(tmp_path / "real", n_train=3, n_val=0, n_test=1, width=8, height=8, seed=0)
    (tmp_path / "link").symlink_to(real, target_is_directory=True)
    via_link, direct = load_scene(tmp_path / "link"), load_scene(real)
    assert view_names(via_link, [0, 3]) == ["train/r_0.png", "test/r_0.png"]
    assert scene_file_digests(via_link) == scene_file_digests(direct)
    assert "transforms_train.json" in scene_file_digests(via_link)


def test_digests_cover_every_byte_of_a_file_longer_than_one_read(tmp_path):
    import hashlib

    from senerf.data import scene_file_digests

    data = bytearray(np.random.default_rng(0).integers(0, 256, (1 << 21) + 1, dtype=np.uint8).tobytes())
    s = _scene(root=tmp_path, image_paths=(tmp_path / "big.bin",))
    for _ in range(2):
        (tmp_path / "big.bin").write_bytes(bytes(data))
        assert scene_file_digests(s) == {"big.bin": hashlib.sha256(bytes(data)).hexdigest()[:16]}
        data[-1] ^= 1   # the last byte, past two 1 MiB reads


def test_changed_files_are_sorted_by_name_whatever_the_records_order():
    from senerf.data import changed_files

    assert changed_files({"b": "1", "a": "1"}, {"c": "1", "b": "2"}) == [
        "a was read then, not now", "b changed", "c is read now, not then"]
