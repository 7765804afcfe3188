"""Fixtures for the harness tests: tiny scene folders, the fake fit command, finished results lines."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

FAKE_FIT = Path(__file__).with_name("fake_fit.py")
BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


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
    """``make_blender_scene(root, name="lego", side=800)`` for tests needing other names or image sizes."""
    return make_blender_scene


def make_llff_scene(root: Path, name: str = "fern") -> Path:
    """A folder that looks like an LLFF scene (poses_bounds.npy records 4032x3024)."""
    d = root / name
    d.mkdir(parents=True)
    pb = np.zeros((20, 17))
    pb[:, 4], pb[:, 9], pb[:, 14] = 3024, 4032, 3260.5
    np.save(d / "poses_bounds.npy", pb)
    return d


def make_dtu_scene(root: Path, name: str = "scan24") -> Path:
    """A folder that looks like the DTU copies: a nerfstudio transforms.json of 49 frames, the first image 384x384."""
    d = root / name
    (d / "images").mkdir(parents=True)
    frames = [{"file_path": f"images/{i:06d}.png"} for i in range(49)]
    (d / "transforms.json").write_text(json.dumps({"frames": frames}))
    Image.new("RGB", (384, 384)).save(d / "images" / "000000.png")
    return d


@pytest.fixture()
def llff_scene(tmp_path: Path) -> Path:
    """An LLFF-like scene named ``fern``."""
    return make_llff_scene(tmp_path)


@pytest.fixture()
def data_tree(tmp_path: Path) -> Path:
    """A data folder laid out as ``../shared/data``: Blender lego and mic, a Blender scene with no published Extreme
    views (``mine``), LLFF fern, DTU scan24, and a folder under ``dtu/`` that is no scene."""
    data = tmp_path / "data"
    for name in ("mic", "lego", "mine"):
        make_blender_scene(data / "nerf_synthetic", name)
    make_llff_scene(data / "nerf_llff_data")
    make_dtu_scene(data / "dtu")
    (data / "dtu" / "notes").mkdir()
    return data


@pytest.fixture()
def fake_fit_command() -> tuple[str, ...]:
    """Program prefix running the fake fit with this interpreter."""
    return (sys.executable, str(FAKE_FIT))


@pytest.fixture()
def ok_line():
    """``ok_line(**fields)``: a finished results line as ``senerf-bench run`` writes it (a lego Extreme baseline at
    20 dB unless ``fields`` say otherwise)."""
    def make(**fields) -> dict:
        line = {"run_key": "k", "attempt": "a", "status": "ok", "timestamp": "2026-01-01T00:00", "scene": "lego",
                "protocol": "synthetic-extreme3@100", "resolution": [100, 100], "method": "baseline", "preset": "fast",
                "seed": 0, "iterations": 0, "iteration": 0, "psnr": 20.0, "ssim": 0.5, "lpips": "unavailable",
                "avg": "unavailable", "seconds": 1.0, "seconds_cumulative": 1.0, "run_seconds": 1.5,
                "peak_memory_mib": 100.0, "commit": "c0ffee", "host": {"cpu": "X", "device": "cpu"},
                "fit_command": ["senerf-fit"], "bench_command": ["senerf-bench", "run"]}
        return {**line, **fields}
    return make


@pytest.fixture()
def load_script():
    """``load_script(name)``: the module ``benchmarks/<name>.py``, imported afresh."""
    def load(name: str):
        spec = importlib.util.spec_from_file_location(f"{name}_under_test", BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load
