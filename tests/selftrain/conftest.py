"""Fixtures shared by the self-training tests (made once per session): a tiny procedural scene, a teacher trained
on it and the VGG-19 extractor."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    pytest.importorskip("trimesh")
    from senerf.data import load_scene
    from senerf.procedural import export_blender_scene

    root = tmp_path_factory.mktemp("tiny") / "scene"
    try:
        export_blender_scene(root, n_train=4, n_val=1, n_test=1, width=32, height=32, n_one_side=3)
    except Exception as exc:  # pragma: no cover - missing ray caster
        pytest.skip(f"procedural scene unavailable: {exc}")
    return load_scene(root)


@pytest.fixture(scope="session")
def vgg():
    """The default VGG-19 extractor, built once (it holds no state between calls)."""
    from senerf.selftrain import VGG19Features

    return VGG19Features()


@pytest.fixture(scope="session")
def tiny_teacher(tiny_scene):
    """A 10-step teacher on three views of the tiny scene: (train_idx, model, TrainResult)."""
    import torch

    from senerf.config import TrainConfig
    from senerf.train import RayBatchSource, build_field, choose_model, train_field

    train_idx = tiny_scene.splits["train"][:3]
    model = choose_model(tiny_scene, train_idx, {"n_samples": 16, "resolution": 32, "occupancy_resolution": 16},
                         echo=lambda s: None)
    tcfg = TrainConfig(steps=10, batch_rays=128, warmup_steps=2, checkpoint_every=0, occupancy_warmup=4,
                       occupancy_every=4)
    rays = RayBatchSource.from_scene(tiny_scene, train_idx, model, torch.device("cpu"))
    return train_idx, model, train_field(build_field(model), rays, tcfg, progress=False)
