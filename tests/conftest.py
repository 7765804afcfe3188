"""Shared fixtures: the location of the real benchmark scenes, and a spy on the evaluation's renders."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# torch's OpenMP workers wait as senerf-fit's do (cliargs.short_openmp_waits: 1000 spins, then sleep), set here
# before anything imports torch: libgomp's default of ~3 ms of spinning makes small ops many times slower on a
# shared 2-core machine, and sleeping at once costs a fit about a quarter of its time.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("GOMP_SPINCOUNT", "1000")

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """``$SENERF_DATA`` if set, else ``../shared/data`` beside the repository."""
    env = os.environ.get("SENERF_DATA")
    return Path(env) if env else REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real benchmark scenes folder; skips the test when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real benchmark data not found at {path} (set SENERF_DATA to run this test)")
    return path


@pytest.fixture(scope="session")
def lego_dir(shared_data: Path) -> Path:
    path = shared_data / "nerf_synthetic" / "lego"
    if not path.is_dir():
        pytest.skip(f"lego scene not found at {path}")
    return path


@pytest.fixture(scope="session")
def fern_dir(shared_data: Path) -> Path:
    path = shared_data / "nerf_llff_data" / "fern"
    if not path.is_dir():
        pytest.skip(f"fern scene not found at {path}")
    return path


class CallSpy:
    """Counts the calls of the function ``real`` it stands in for; with ``stop_at = n`` the n-th call raises
    KeyboardInterrupt instead, as a Ctrl-C at that point (e.g. mid-evaluation, mid-labelling)."""

    def __init__(self, real):
        self.real, self.calls, self.stop_at = real, 0, None

    def __call__(self, *args, **kwargs):
        self.calls += 1
        if self.calls == self.stop_at:
            raise KeyboardInterrupt
        return self.real(*args, **kwargs)


@pytest.fixture
def render_spy(monkeypatch) -> CallSpy:
    """A :class:`CallSpy` installed in place of evaluate's ``render_views`` (one call per test view
    :func:`senerf.train.evaluate` renders) for the test."""
    import importlib

    module = importlib.import_module("senerf.train.evaluate")   # ``senerf.train.evaluate`` is the function
    spy = CallSpy(module.render_views)
    monkeypatch.setattr(module, "render_views", spy)
    return spy


@pytest.fixture
def similarity_spy(monkeypatch) -> CallSpy:
    """A :class:`CallSpy` installed in place of the labelling's ``view_similarity`` (one call per pseudo view
    :func:`senerf.selftrain.estimate_reliability` labels) for the test."""
    import senerf.selftrain.labels as labels_mod

    spy = CallSpy(labels_mod.view_similarity)
    monkeypatch.setattr(labels_mod, "view_similarity", spy)
    return spy
