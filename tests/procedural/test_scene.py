"""Tests of senerf/procedural/scene.py: configuration, determinism, bounds, analytic textures."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from senerf.procedural.scene import (
    GROUND_TOP,
    OBJECT_NAMES,
    ObjectTexture,
    SceneConfig,
    build_scene,
    texture_color,
)


def test_does_not_import_torch():
    code = "import sys, senerf.procedural; sys.exit(1 if 'torch' in sys.modules else 0)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


@pytest.mark.parametrize(
    "kwargs",
    [dict(ground_radius=3.0), dict(sphere_subdivisions=9), dict(texture_scale=0.0), dict(ambient=1.5),
     dict(jitter=0.5), dict(light_dir=(0.0, 0.0, 0.0)), dict(light_dir=(1.0, 2.0))],
)
def test_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        SceneConfig(**kwargs)


def test_build_rejects_non_config():
    with pytest.raises(ValueError):
        build_scene({"seed": 0})


def test_scene_bounded_and_has_all_objects():
    scene = build_scene(SceneConfig(seed=3))
    assert np.all(scene.bounds[0] >= -1.5) and np.all(scene.bounds[1] <= 1.5)
    assert scene.object_ids == tuple(range(len(OBJECT_NAMES)))
    assert len(scene.face_object) == len(scene.mesh.faces)
    assert scene.mesh.is_watertight
    # the ground disc's top face is at GROUND_TOP
    ground = scene.mesh.triangles[scene.face_object == 0]
    assert np.isclose(ground[..., 2].max(), GROUND_TOP)


def test_without_ground_drops_object_zero():
    scene = build_scene(SceneConfig(with_ground=False))
    assert scene.object_ids == (1, 2, 3, 4)


def test_deterministic_given_seed_and_seed_matters():
    a, b, c = build_scene(SceneConfig(seed=7)), build_scene(SceneConfig(seed=7)), build_scene(SceneConfig(seed=8))
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
    assert all(np.array_equal(x.colors, y.colors) for x, y in zip(a.textures, b.textures))
    assert not np.array_equal(a.mesh.vertices, c.mesh.vertices)


def test_checker_textures_flip_across_cell_boundaries():
    tex = ObjectTexture("checker3d", 4.0, np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.25]]))
    eps = 1e-9
    # cells are [k/4 - 1/8, (k+1)/4 - 1/8): boundary at x = 1/8
    pts = np.array([[0.125 - eps, 0.01, 0.01], [0.125 + eps, 0.01, 0.01], [0.3, 0.01, 0.01]])
    col = texture_color(tex, pts)
    assert np.array_equal(col[0], [0.0, 0.0, 0.0])
    assert np.array_equal(col[1], [1.0, 0.5, 0.25])
    assert np.array_equal(col[2], col[1])


@pytest.mark.parametrize("kind", ["checker2d", "checker3d", "torus_checker", "helix", "noise"])
def test_every_texture_kind_in_range_and_high_frequency(kind):
    scene = build_scene(SceneConfig(seed=1))
    tex = next(t for t in scene.textures if t.kind == kind)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.6, 0.6, size=(4000, 3))
    pts[:, 2] *= 0.2  # stay near the torus tube / the ground plane's neighbourhood
    col = texture_color(tex, pts)
    assert col.shape == (4000, 3) and col.min() >= 0.0 and col.max() <= 1.0
    # high frequency: points 0.25 units apart usually differ in colour
    step = rng.normal(size=(4000, 3))
    step[:, 2] = 0.0 if kind == "checker2d" else step[:, 2]
    step *= 0.25 / np.linalg.norm(step, axis=1, keepdims=True)
    other = texture_color(tex, pts + step)
    differ = np.abs(col - other).sum(axis=1) > 0.05
    assert differ.mean() > 0.3, differ.mean()
    if kind != "checker2d":  # two-colour textures reach both palette colours
        d0 = np.abs(col - tex.colors[0]).sum(1) < 1e-9
        d1 = np.abs(col - tex.colors[1]).sum(1) < 1e-9
        assert d0.mean() > 0.05 and d1.mean() > 0.05


def test_texture_rejects_bad_shape_and_kind():
    tex = ObjectTexture("checker3d", 4.0, np.zeros((2, 3)))
    with pytest.raises(ValueError):
        texture_color(tex, np.zeros((3, 2)))
    with pytest.raises(ValueError):
        texture_color(ObjectTexture("plaid", 1.0, np.zeros((2, 3))), np.zeros((3, 3)))
