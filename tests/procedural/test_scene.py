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
    assert np.all(scene.mesh.bounds[0] >= -1.5) and np.all(scene.mesh.bounds[1] <= 1.5)
    assert np.unique(scene.face_object).tolist() == list(range(len(OBJECT_NAMES)))
    assert len(scene.face_object) == len(scene.mesh.faces)
    assert scene.mesh.is_watertight
    # the ground disc's top face is at GROUND_TOP
    ground = scene.mesh.triangles[scene.face_object == 0]
    assert np.isclose(ground[..., 2].max(), GROUND_TOP)


def test_without_ground_drops_object_zero():
    scene = build_scene(SceneConfig(with_ground=False))
    assert np.unique(scene.face_object).tolist() == [1, 2, 3, 4]


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


def test_config_accepts_the_ends_of_its_ranges():
    for kwargs in (dict(ground_radius=0.3), dict(ground_radius=1.5), dict(sphere_subdivisions=0),
                   dict(sphere_subdivisions=6), dict(ambient=0.0), dict(ambient=1.0), dict(jitter=0.0),
                   dict(jitter=0.1), dict(texture_scale=1e-3)):
        SceneConfig(**kwargs)
    for kwargs in (dict(ground_radius=0.29), dict(ground_radius=1.51), dict(sphere_subdivisions=-1),
                   dict(sphere_subdivisions=7), dict(ambient=-0.01), dict(jitter=-0.01), dict(jitter=0.11)):
        with pytest.raises(ValueError):
            SceneConfig(**kwargs)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_objects_stand_on_the_ground_and_jitter_moves_them_at_most_jitter(seed):
    """The box (0.8 cube), sphere (r 0.5) and cylinder (h 1.3) touch the ground's top face, neither floating
    nor sunk, whatever the seed; jitter only shifts them sideways, by at most ``jitter`` along x and y."""
    nominal = {1: (-0.45, -0.35), 2: (0.45, 0.30), 3: (0.40, -0.62)}  # centres without jitter (design)
    for jitter in (0.0, 0.1):
        scene = build_scene(SceneConfig(seed=seed, jitter=jitter))
        for oid, xy in nominal.items():
            pts = scene.mesh.triangles[scene.face_object == oid].reshape(-1, 3)
            assert abs(pts[:, 2].min() - GROUND_TOP) < 1e-9, (OBJECT_NAMES[oid], pts[:, 2].min())
            centre = (pts.min(axis=0) + pts.max(axis=0)) / 2  # all three are symmetric about their centre
            offset = np.abs(centre[:2] - xy)
            assert np.all(offset <= jitter + 1e-9), (OBJECT_NAMES[oid], offset)
            if jitter == 0.0:
                assert np.all(offset < 1e-9)


def test_checker_cells_are_centred_and_signed_coordinates_count():
    """checker3d: cells of 1/freq centred on the origin, parity of the summed cell indices (hand-computed at
    freq 7.5: local 0.05 -> cell 0, 0.1 -> 1, -0.1 -> -1, 0.3 -> 2, -0.3 -> -2, 0.4 -> 3)."""
    tex = ObjectTexture("checker3d", 7.5, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    pts = np.array([[0.05, 0.05, 0.4], [0.1, 0.05, 0.4], [-0.1, 0.3, 0.4], [-0.3, -0.1, 0.4],
                    [0.1, 0.1, 0.4], [0.3, 0.05, 0.4], [-0.1, -0.1, 0.4], [-0.1, 0.05, 0.0]])
    parity = [1, 0, 0, 0, 1, 1, 1, 1]
    assert np.array_equal(texture_color(tex, pts)[:, 0], parity)


def test_checker2d_has_a_coarser_modulation_by_hand():
    """checker2d at freq 6: fine cells of 1/6 and coarse cells of 1/2; t = 0.15 on even fine cells, 1.0 on
    odd fine cells in odd coarse cells, 0.66 on odd fine cells in even coarse cells; z is ignored."""
    tex = ObjectTexture("checker2d", 6.0, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    pts = np.array([[1.1, -0.2, 0.05],    # fine (6, -2): even                      -> 0.15
                    [1.1, -0.1, 0.05],    # fine (6, -1): odd;  coarse (2, -1): odd  -> 1.0
                    [-0.8, -0.95, 0.05],  # fine (-5, -6): odd; coarse (-2, -2): even -> 0.66
                    [-1.05, 0.1, 9.0],    # fine (-7, 0): odd;  coarse (-3, 0): odd  -> 1.0
                    [0.05, -1.2, -3.0]])  # fine (0, -8): even                        -> 0.15
    assert np.allclose(texture_color(tex, pts)[:, 0], [0.15, 1.0, 0.66, 1.0, 0.15], atol=1e-12)


def test_torus_checker_by_hand():
    """torus_checker at freq 2: 2 cells per quarter turn around the axis (angle a), 2 per half turn around
    the tube (angle b); points built from (a, b) on a tube of radius 0.14 around major radius 0.42."""
    tex = ObjectTexture("torus_checker", 2.0, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]),
                        {"major_radius": 0.42})
    ab = np.array([[0.3, 0.2], [2.0, 0.2], [-1.0, -0.5], [1.0, -2.0], [2.8, 1.0], [-2.0, 2.5], [0.5, -0.3]])
    # u = a / (pi/2) * 2, v = b / pi * 2:  (0.38, 0.13) (2.55, 0.13) (-1.27, -0.32) (1.27, -1.27)
    # (3.57, 0.64) (-2.55, 1.59) (0.64, -0.19) -> floor sums 0, 2, -3, -1, 3, -2, -1
    parity = [0, 0, 1, 1, 1, 0, 1]
    a, b = ab[:, 0], ab[:, 1]
    ring = 0.42 + 0.14 * np.cos(b)
    pts = np.stack([ring * np.cos(a), ring * np.sin(a), 0.14 * np.sin(b)], axis=-1)
    assert np.array_equal(texture_color(tex, pts)[:, 0], parity)


def test_torus_texture_follows_the_torus_tube():
    """The torus texture's major radius is the torus mesh's: its vertices, in the texture frame, lie
    between major - minor and major + minor from the local z axis, symmetric about the major radius."""
    scene = build_scene(SceneConfig(seed=5))
    verts = scene.mesh.triangles[scene.face_object == 4].reshape(-1, 3)
    w2l = scene.world_to_local[4]
    local = verts @ w2l[:3, :3].T + w2l[:3, 3]
    rho = np.hypot(local[:, 0], local[:, 1])
    major = scene.textures[4].params["major_radius"]
    assert abs((rho.min() + rho.max()) / 2 - major) < 1e-3
    assert np.max(np.abs(local[:, 2])) <= 0.14 + 1e-9  # the texture's z axis is the torus axis


def test_value_noise_is_a_smoothstep_blend_of_a_16_periodic_lattice():
    """'noise' at freq 1 over a lattice near 0.5 (so the ramp 4 (n - 0.5) + 0.5 does not clip): at lattice
    points the value is the lattice entry (index 256 i + 16 j + k, of p + 8 mod 16); a quarter cell on the
    weight is smoothstep(0.25) = 0.15625; at i = 15 the next entry is i = 0."""
    rng = np.random.default_rng(0)
    lat = rng.uniform(0.4, 0.6, size=16**3)
    tex = ObjectTexture("noise", 1.0, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]), {"lattice": lat})

    def at(i, j, k):
        return lat[256 * (i % 16) + 16 * (j % 16) + k % 16]

    w = 0.15625
    cases = [((3.0, 5.0, 7.0), at(3, 5, 7)),
             ((3.25, 5.0, 7.0), (1 - w) * at(3, 5, 7) + w * at(4, 5, 7)),
             ((3.0, 5.0, 7.75), w * at(3, 5, 7) + (1 - w) * at(3, 5, 8)),
             ((15.5, 0.0, 0.0), 0.5 * at(15, 0, 0) + 0.5 * at(0, 0, 0)),
             ((-0.75, 2.0, 2.0), (1 - w) * at(15, 2, 2) + w * at(0, 2, 2)),
             ((20.0, 17.0, 16.0), at(4, 1, 0))]
    p = np.array([c[0] for c in cases]) - 8.0  # the texture samples the noise at local * freq + 8
    n = np.array([c[1] for c in cases])
    assert np.allclose(texture_color(tex, p)[:, 0], (n - 0.5) * 4.0 + 0.5, atol=1e-12)


def test_cells_mix_the_checker_parity_with_a_16_periodic_cell_value_by_hand():
    """'cells' at freq 2 (cells of 1/2 in local x, y; z ignored): t = 0.6 parity + 0.4 lattice[16 (i mod 16) +
    (j mod 16)], here with lattice k / 256 so the index shows; neighbouring cells differ by at least 0.2."""
    lat = np.arange(256) / 256.0
    tex = ObjectTexture("cells", 2.0, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]), {"lattice": lat})
    pts = np.array([[0.1, 0.1, 0.0],     # cell (0, 0): even,            lattice[0]
                    [0.6, 0.1, 5.0],     # cell (1, 0): odd,             lattice[16]
                    [-0.2, 0.3, 0.0],    # cell (-1, 0): odd,            lattice[240]
                    [8.1, 0.7, -1.0],    # cell (16, 1): odd,            lattice[1]
                    [-3.9, -7.6, 0.0]])  # cell (-8, -16): even,         lattice[128]
    t = np.array([0.0, 0.6 + 0.4 * 16 / 256, 0.6 + 0.4 * 240 / 256, 0.6 + 0.4 / 256, 0.4 * 128 / 256])
    assert np.allclose(texture_color(tex, pts)[:, 0], t, atol=1e-12)
    rng = np.random.default_rng(0)
    tex = ObjectTexture("cells", 2.0, tex.colors, {"lattice": rng.uniform(size=256)})
    p = rng.uniform(-9.0, 9.0, size=(2000, 3))
    for step in ([0.5, 0.0, 0.0], [0.0, 0.5, 0.0]):
        assert np.abs(texture_color(tex, p) - texture_color(tex, p + step))[:, 0].min() >= 0.2 - 1e-12
