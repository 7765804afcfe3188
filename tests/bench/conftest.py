"""Fixtures for the harness tests: tiny scene folders and the fake fit command."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

FAKE_FIT = Path(__file__).with_name("fake_fit.py")


def make_blender_scene(root: Path, name: str = "lego", side: int = 800) -> Path:
    """A folder that looks like a Blender scene: 100 train frames, only the first image exists."""
    d = root / name
    (d / "train").mkdir(parents=True)
    frames = [{"file_path": f"./train/r_{i}"} for i in range(100)]
    (d / "transforms_train.json").write_text(json.dumps({"frames": frames}))
    Image.new("RGBA", (side, side)).save(d / "train" / "r_0.png")
    return d


@pytest.fixture()
def blender_scene(tmp_path: Path) -> Path:
    """An 800x800 Blender-like scene named ``lego``."""
    return make_blender_scene(tmp_path)


@pytest.fixture()
def blender_factory():
    """``make_blender_scene(root, name="lego", side=800)`` for tests needing other image sizes."""
    return make_blender_scene


@pytest.fixture()
def llff_scene(tmp_path: Path) -> Path:
    """A folder that looks like an LLFF scene named ``fern`` (poses_bounds.npy records 4032x3024)."""
    d = tmp_path / "fern"
    d.mkdir()
    pb = np.zeros((20, 17))
    pb[:, 4], pb[:, 9], pb[:, 14] = 3024, 4032, 3260.5
    np.save(d / "poses_bounds.npy", pb)
    return d


@pytest.fixture()
def fake_fit_command() -> tuple[str, ...]:
    """Program prefix running the fake fit with this interpreter."""
    return (sys.executable, str(FAKE_FIT))
