"""Fixtures for the senerf.data tests: tiny scene folders written into tmp_path, and cached real scenes."""

from __future__ import annotations

import json
import math
import types
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

# Focal of the tiny Blender scenes: camera_angle_x = 2 atan(0.5) gives f = 0.5 W / tan(atan(0.5)) = W.
TINY_W = 4
TINY_ANGLE_X = 2.0 * math.atan(0.5)


def tiny_rgba(seed: int, h: int = TINY_W, w: int = TINY_W) -> np.ndarray:
    """A deterministic random uint8 RGBA image (H, W, 4)."""
    return np.random.default_rng(seed).integers(0, 256, size=(h, w, 4), dtype=np.uint8)


def gl_pose(center=(0.0, 0.0, 4.0)) -> list:
    """OpenGL camera-to-world at ``center`` with identity rotation: the camera looks along world -z."""
    m = np.eye(4)
    m[:3, 3] = center
    return m.tolist()


def write_blender(root: Path, n_train: int = 2, n_val: int = 1, n_test: int = 1, image=tiny_rgba) -> Path:
    """Write a NeRF-Synthetic-style folder: ``transforms_{split}.json`` and ``{split}/r_{i}.png``."""
    root.mkdir(parents=True, exist_ok=True)
    seed = 0
    for split, n in (("train", n_train), ("val", n_val), ("test", n_test)):
        (root / split).mkdir(exist_ok=True)
        frames = []
        for i in range(n):
            iio.imwrite(root / split / f"r_{i}.png", image(seed))
            seed += 1
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": gl_pose((0.0, 0.0, 4.0 + i))})
        write_json(root / f"transforms_{split}.json", {"camera_angle_x": TINY_ANGLE_X, "frames": frames})
    return root


def write_ngp(root: Path, n: int = 3, meta_extra=None, image=tiny_rgba) -> Path:
    """Write an instant-ngp-style folder: ``transforms.json`` with global intrinsics and ``images/*.png``."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    frames = []
    for i in range(n):
        iio.imwrite(root / "images" / f"f_{i}.png", image(100 + i))
        frames.append({"file_path": f"images/f_{i}.png", "transform_matrix": gl_pose((0.0, 0.0, 4.0 + i))})
    meta = {"fl_x": 5.0, "fl_y": 6.0, "cx": 1.5, "cy": 2.5, "w": TINY_W, "h": TINY_W, "frames": frames}
    meta.update(meta_extra or {})
    write_json(root / "transforms.json", meta)
    return root


def llff_rows(n: int = 9, H: float = 32.0, W: float = 48.0, f: float = 40.0, near=2.0, far=10.0) -> np.ndarray:
    """``(n, 17)`` poses_bounds rows; camera k sits at x = 0.1 k with OpenCV rotation = identity.

    LLFF columns are [down, right, back]: for an OpenCV identity camera down = +y, right = +x and
    back = -z (forward is +z).
    """
    rows = np.zeros((n, 17))
    for k in range(n):
        m = np.zeros((3, 5))
        m[:, 0] = (0.0, 1.0, 0.0)   # down
        m[:, 1] = (1.0, 0.0, 0.0)   # right
        m[:, 2] = (0.0, 0.0, -1.0)  # back
        m[:, 3] = (0.1 * k, 0.0, 0.0)
        m[:, 4] = (H, W, f)
        rows[k, :15] = m.reshape(-1)
        rows[k, 15:] = (near, far)
    return rows


def write_llff(root: Path, rows=None, folder: str = "images_2", size=(16, 24), n_images=None) -> Path:
    """Write an LLFF folder: ``poses_bounds.npy`` and ``folder/img_XXX.png`` RGB images of ``size=(H, W)``."""
    rows = llff_rows() if rows is None else rows
    root.mkdir(parents=True, exist_ok=True)
    np.save(root / "poses_bounds.npy", rows)
    (root / folder).mkdir(exist_ok=True)
    n = len(rows) if n_images is None else n_images
    for i in range(n):
        iio.imwrite(root / folder / f"img_{i:03d}.png", tiny_rgba(200 + i, *size)[..., :3])
    return root


def write_json(path: Path, obj) -> None:
    path.write_text(json.dumps(obj, indent=1))


def read_json(path: Path):
    return json.loads(path.read_text())


@pytest.fixture
def writers():
    """The scene-writing helpers above, as one namespace."""
    return types.SimpleNamespace(
        blender=write_blender, ngp=write_ngp, llff=write_llff, llff_rows=llff_rows, rgba=tiny_rgba,
        write_json=write_json, read_json=read_json, gl_pose=gl_pose, W=TINY_W, angle_x=TINY_ANGLE_X,
    )


@pytest.fixture(scope="session")
def lego4(lego_dir):
    """The real lego scene at downscale 4 (100x100, all 400 frames), loaded once per session."""
    from senerf.data import load_scene

    return load_scene(lego_dir, downscale=4)


@pytest.fixture(scope="session")
def fern8(fern_dir):
    """The real fern scene at downscale 8 (images_8, 504x378), loaded once per session."""
    from senerf.data import load_scene

    return load_scene(fern_dir, downscale=8)
