"""senerf.load_run: a fitted run's renders, depths, density and colour queries, and its cameras."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import senerf
from senerf.geometry import Intrinsics, pixel_rays

_K = Intrinsics(10.0, 10.0, 4.0, 4.0, 8, 8)


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A tiny teacher-only fit of a procedural scene (views 0-3 train, 4-5 test)."""
    from senerf.procedural.export import export_blender_scene

    root = tmp_path_factory.mktemp("fitted")
    scene = export_blender_scene(root / "scene", n_train=4, n_val=0, n_test=2, width=16, height=16, seed=0)
    senerf.fit(scene, root / "run", views=[0, 1, 2, 3], iterations=0, train=dict(steps=30, batch_rays=128),
               model=dict(n_samples=12, resolution=8), progress=False, echo=lambda line: None)
    return root / "run"


def _box_bounds(o: np.ndarray, d: np.ndarray, aabb) -> tuple[np.ndarray, np.ndarray]:
    """Slab-method entry and exit distances of rays ``(R, 3)`` into the box, in float64."""
    lo, hi = (np.asarray(a, np.float64) for a in aabb)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    return np.minimum(t0, t1).max(-1), np.maximum(t0, t1).min(-1)


def test_render_equals_a_quadrature_of_density_and_color_queries(run):
    """Volume rendering ``density`` and ``color`` along a camera's rays at the renderer's bin centres (intervals
    between them, the last ending at the far bound) gives the renderer's colour and opacity: the queries are the
    field the renders come from, in the world frame."""
    fitted = senerf.load_run(run)
    c2w = fitted.cameras.c2w[fitted.cameras.test[0]]
    out = fitted.render(c2w, _K)
    o, d, _ = pixel_rays(_K, c2w[None])
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    near, far = _box_bounds(o, d, fitted.model.aabb)
    near = np.maximum(near, 1e-3)
    hit = far > near
    n = fitted.model.n_samples
    edges = near[:, None] + (far - near)[:, None] * np.linspace(0.0, 1.0, n + 1)
    t = 0.5 * (edges[:, 1:] + edges[:, :-1])
    delta = np.diff(np.concatenate([t, far[:, None]], axis=1), axis=1)   # between centres, the last to far
    pts = o[:, None] + t[..., None] * d[:, None]
    sigma = fitted.density(pts)
    rgb = fitted.color(pts, np.broadcast_to(d[:, None], pts.shape))
    assert sigma.shape == t.shape and rgb.shape == pts.shape
    alpha = 1.0 - np.exp(-sigma * delta)
    trans = np.cumprod(np.concatenate([np.ones((len(t), 1)), 1.0 - alpha[:, :-1]], axis=1), axis=1)
    weights = np.where(hit[:, None], alpha * trans, 0.0)
    acc = weights.sum(-1)
    bg = 1.0 if fitted.model.eval_background == "white" else 0.0
    colour = (weights[..., None] * rgb).sum(1) + (1.0 - acc)[:, None] * bg
    assert acc.max() > 0.05, "the fit should have some opacity in view"
    np.testing.assert_allclose(acc, out["acc"].reshape(-1), atol=2e-4)
    np.testing.assert_allclose(colour, out["rgb"].reshape(-1, 3), atol=2e-4)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_density_keeps_the_batch_shape_and_is_zero_outside_the_box(run, dtype):
    fitted = senerf.load_run(run)
    (lo, hi) = (np.asarray(a) for a in fitted.model.aabb)
    rng = np.random.default_rng(0)
    inside = rng.uniform(lo, hi, size=(2, 5, 3)).astype(dtype)
    outside = (hi + 1.0 + rng.uniform(0, 1, size=(7, 3))).astype(dtype)
    sigma = fitted.density(inside)
    assert sigma.shape == (2, 5) and sigma.dtype == np.float32 and np.all(sigma >= 0)
    np.testing.assert_array_equal(fitted.density(outside), 0.0)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        fitted.density(np.zeros((4, 2)))


def test_depth_is_the_renders_z_depth_and_at_iteration_switches_the_field(run):
    fitted = senerf.load_run(run)
    c2w = fitted.cameras.c2w[:2]
    np.testing.assert_array_equal(fitted.depth(c2w, _K), fitted.render(c2w, _K)["z_depth"])
    assert fitted.at_iteration(0).iteration == 0
    with pytest.raises(senerf.errors.InputError, match="iteration 3 is not finished"):
        fitted.at_iteration(3)


def test_cameras_give_the_runs_split_and_the_scenes_poses(run):
    cams = senerf.load_run(run).cameras
    assert list(cams.train) == [0, 1, 2, 3] and list(cams.test) == [4, 5]
    assert cams.c2w.shape == (6, 4, 4) and len(cams.intrinsics) == 6 and len(cams.image_paths) == 6
