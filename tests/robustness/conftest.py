"""Shared helpers of the robustness suite: tiny scenes, folder snapshots, CLI runners."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

#: Small, fast settings for every fit in this suite (seconds on 2 cores at 24x24).
TINY_FIT = ["--iterations", "0", "--steps", "16", "--batch-rays", "128", "--samples", "12", "--resolution", "8",
            "--quiet"]


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """Fits in this suite use one torch thread: on a shared 2-core machine two threads are ~4x slower.

    Module scope, so that module-scoped fixtures that fit (set up before function-scoped ones) get it too.
    """
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def scene24(tmp_path_factory) -> Path:
    """A Blender-format procedural scene: 24x24 RGBA, 6 train / 1 val / 2 test views (read-only: copy it)."""
    from senerf.procedural import export_blender_scene

    return export_blender_scene(tmp_path_factory.mktemp("scene24") / "s24", width=24, height=24, n_train=6,
                                n_val=1, n_test=2, seed=0)


@pytest.fixture
def scene_copy(scene24, tmp_path) -> Path:
    """A private, editable copy of :func:`scene24`."""
    dst = tmp_path / "scene"
    shutil.copytree(scene24, dst)
    return dst


def edit_json(path: Path, edit) -> None:
    """Load ``path``, call ``edit(doc)`` (in place), write it back."""
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


def transform_translations(scene: Path, scale: float = 1.0, offset=(0.0, 0.0, 0.0)) -> None:
    """``t -> scale * t + offset`` for every camera of a Blender scene (rotations and images unchanged)."""
    off = np.asarray(offset, dtype=np.float64)
    for split in ("train", "val", "test"):
        p = scene / f"transforms_{split}.json"
        if not p.exists():
            continue

        def edit(doc):
            for fr in doc["frames"]:
                m = np.asarray(fr["transform_matrix"], dtype=np.float64)
                m[:3, 3] = m[:3, 3] * scale + off
                fr["transform_matrix"] = m.tolist()

        edit_json(p, edit)


def snapshot(folder: Path) -> dict:
    """``{relative path: (size, mtime_ns, bytes)}`` of every file under ``folder`` (empty if missing)."""
    if not folder.exists():
        return {}
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            st = p.stat()
            out[str(p.relative_to(folder))] = (st.st_size, st.st_mtime_ns, p.read_bytes())
    return out


def run_cli_subprocess(args, timeout=300, env=None, **kw) -> subprocess.CompletedProcess:
    """``python -m senerf.cli ARGS`` in a fresh interpreter (one torch thread: the machine is shared)."""
    full_env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", **(env or {}))
    return subprocess.run([sys.executable, "-m", "senerf.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=full_env, **kw)
