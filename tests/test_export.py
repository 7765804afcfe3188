"""senerf-export (senerf/export.py): meshes, fused point clouds and 16-bit depth maps, checked against exact geometry.

Golden values come from analytic shapes (a sphere's radius) and from the procedural scene's exact meshes and
depths (:mod:`senerf.procedural`); the run folder for the command is a tiny :func:`senerf.fit`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from senerf.config import ModelConfig
from senerf.errors import InputError
from senerf.export import default_level, density_grid, depth_png, fused_points, grid_mesh, main, mesh_region
from senerf.geometry import Intrinsics


def _spheres(centres, radii):
    """A density of solid balls: 100 inside, 0 outside, a linear ramp of width 0.1 across each surface."""
    def density(points):
        p = np.asarray(points, np.float64)
        out = np.zeros(p.shape[:-1])
        for c, r in zip(centres, radii):
            out = np.maximum(out, np.clip((r - np.linalg.norm(p - np.asarray(c), axis=-1)) / 0.1 + 0.5, 0, 1) * 100)
        return out
    return density


def _sphere_points(centre, radius, n=4000) -> np.ndarray:
    """``(n, 3)`` points spread evenly on a sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z, phi = 1 - 2 * i / n, math.pi * (1 + 5 ** 0.5) * i
    s = np.sqrt(1 - z * z)
    return np.asarray(centre) + radius * np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def test_marching_cubes_of_a_ball_density_lies_on_the_ball_with_outward_normals():
    lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    grid = density_grid(_spheres([(0.1, -0.05, 0.0)], [0.6]), lo, hi, 41, chunk=5000)
    mesh = grid_mesh(grid, lo, hi, level=50.0)
    voxel = 2.0 / 40
    radius = np.linalg.norm(mesh.vertices - (0.1, -0.05, 0.0), axis=1)
    assert np.abs(radius - 0.6).max() < 0.1 * voxel
    exact = _sphere_points((0.1, -0.05, 0.0), 0.6, 20000)
    samples = trimesh.sample.sample_surface(mesh, 20000, seed=0)[0]
    to_exact, to_mesh = cKDTree(exact).query(samples)[0], cKDTree(samples).query(exact)[0]
    assert (to_exact.mean() + to_mesh.mean()) / 2 < 0.25 * voxel
    radial = mesh.vertices - (0.1, -0.05, 0.0)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", mesh.vertex_normals, radial).min() > 0.9
    assert mesh.volume == pytest.approx(4 / 3 * math.pi * 0.6 ** 3, rel=0.03)   # faces wound outwards


def test_largest_keeps_the_bigger_ball_and_all_keeps_both():
    lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    grid = density_grid(_spheres([(-0.5, 0, 0), (0.55, 0, 0)], [0.4, 0.2]), lo, hi, 40)
    both, largest = grid_mesh(grid, lo, hi, 50.0, "all"), grid_mesh(grid, lo, hi, 50.0, "largest")
    assert len(both.split(only_watertight=False)) == 2
    assert largest.bounds[1, 0] < 0.0 and largest.bounds[0, 0] == pytest.approx(-0.9, abs=0.05)


def test_a_level_the_density_never_crosses_is_refused_naming_level():
    grid = np.zeros((8, 8, 8), np.float32)
    with pytest.raises(InputError, match="never crosses") as exc:
        grid_mesh(grid, np.zeros(3), np.ones(3), 1.0)
    assert exc.value.field == "--level"


def test_the_mesh_region_is_the_box_and_ndc_fits_are_refused_naming_mesh():
    box = ((-1.0, -2.0, -1.0), (1.0, 2.0, 3.0))
    lo, hi = mesh_region(ModelConfig(aabb=box))
    np.testing.assert_array_equal(lo, box[0])
    np.testing.assert_array_equal(hi, box[1])
    # half opaque per sample interval: 1 - exp(-level * mean side / n_samples) = 0.5
    cfg = ModelConfig(aabb=box, n_samples=30)
    assert 1 - math.exp(-default_level(cfg) * (2 + 4 + 4) / 3 / 30) == pytest.approx(0.5)
    with pytest.raises(InputError) as exc:
        mesh_region(ModelConfig(ndc=True, aabb=((-1, -1, -1), (1, 1, 1))))
    assert exc.value.field == "--mesh"


def test_a_16_bit_depth_png_decodes_to_z_within_half_a_step(tmp_path):
    rng = np.random.default_rng(0)
    z = rng.uniform(0.5, 7.0, size=(12, 9)).astype(np.float32)
    z[0, :3] = 0.0                                     # no surface
    scale = 7.0 / 65535
    iio.imwrite(tmp_path / "d.png", depth_png(z, scale))
    back = iio.imread(tmp_path / "d.png")
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back[0, :3], 0)
    assert np.abs(back[z > 0] * scale - z[z > 0]).max() <= scale / 2 + 1e-7


def _distance_to_surface(mesh, points) -> np.ndarray:
    """Distance of ``points (n, 3)`` to ``mesh``: the mesh cut into triangles of sides below 0.05, and each point's
    distance to the 64 with the nearest centroids; an upper bound, exact when the nearest triangle is among them
    (on the procedural scene 16 missed it for a few points of 1000, 64 for none)."""
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=0.05)
    tri = v[f]
    _, near = cKDTree(tri.mean(axis=1)).query(points, k=64)
    closest = trimesh.triangles.closest_point(tri[near.reshape(-1)], np.repeat(points, 64, axis=0))
    return np.linalg.norm(closest - np.repeat(points, 64, axis=0), axis=1).reshape(-1, 64).min(axis=1)


@pytest.fixture(scope="module")
def exact_views():
    """Exact renders (z-depth 0 where the ray misses) of four cameras round the procedural scene."""
    from senerf.procedural.export import hemisphere_poses
    from senerf.procedural.render import render
    from senerf.procedural.scene import build_scene

    scene = build_scene()
    k = Intrinsics.from_fov(40.0, 32, 32)
    c2w = hemisphere_poses(4, np.random.default_rng(3))
    views = [render(scene, k, p) for p in c2w]
    return scene, c2w, (k,) * 4, [dict(rgb=v.rgb, z_depth=v.depth_or_zero()) for v in views]


def test_points_fused_from_exact_depths_lie_on_the_exact_mesh(exact_views):
    scene, c2w, intr, renders = exact_views
    xyz, rgb = fused_points(c2w, intr, renders)
    assert len(xyz) > 0.5 * sum(int((r["z_depth"] > 0).sum()) for r in renders)
    dist = _distance_to_surface(scene.mesh, xyz)
    assert dist.max() < 1e-4
    assert rgb.shape == xyz.shape and rgb.min() >= 0 and rgb.max() <= 1


def test_a_view_whose_depth_no_other_view_agrees_with_adds_few_points_and_only_near_the_surface(exact_views):
    """View 0's depth 10 % too far puts its lifted pixels 0.3 to 0.5 off the surface.  The forward-backward test
    keeps a pixel of it only where another view sees a surface within a pixel of it (a surface hidden from view 0
    behind the one it sees): few of them, all within 1.5 pixel footprints (at the farthest depth) of the surface."""
    scene, c2w, intr, renders = exact_views
    wrong = [dict(r) for r in renders]
    wrong[0]["z_depth"] = renders[0]["z_depth"] * 1.1
    xyz, _ = fused_points(c2w, intr, wrong)
    dist = _distance_to_surface(scene.mesh, xyz)
    off = dist > 1e-3                                   # the other views' points are exact
    assert off.sum() < 0.15 * (renders[0]["z_depth"] > 0).sum()
    assert dist.max() < 1.5 * renders[0]["z_depth"].max() * 1.1 / intr[0].fx


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A tiny teacher-only fit of a procedural scene (views 0-3 train, 4 test)."""
    import senerf
    from senerf.procedural.export import export_blender_scene

    root = tmp_path_factory.mktemp("export")
    scene = export_blender_scene(root / "scene", n_train=4, n_val=0, n_test=1, width=16, height=16, seed=0)
    senerf.fit(scene, root / "run", views=[0, 1, 2, 3], iterations=0, train=dict(steps=30, batch_rays=128),
               model=dict(n_samples=12, resolution=8), selftrain=dict(n_pseudo_per_input=1), progress=False,
               echo=lambda line: None)
    return root / "run"


@pytest.fixture(scope="module")
def level(run) -> str:
    """A density level the tiny fit's density crosses (its median over the box): ``--level``'s text."""
    import senerf

    fitted = senerf.load_run(run)
    return f"{float(np.median(density_grid(fitted.density, *mesh_region(fitted.model), 16))):.6g}"


def test_the_command_writes_a_coloured_mesh_points_and_depth_maps(run, level, tmp_path, capsys):
    import senerf

    mesh, points, depth = tmp_path / "m.ply", tmp_path / "p.ply", tmp_path / "d"
    assert main([str(run), "--mesh", str(mesh), "--resolution", "24", "--level", level, "--points", str(points),
                 "--depth", str(depth), "--quiet", "--threads", "1"]) == 0
    fitted = senerf.load_run(run)
    m = trimesh.load(mesh)
    lo, hi = mesh_region(fitted.model)
    assert len(m.faces) > 0 and np.all(m.vertices >= lo - 1e-6) and np.all(m.vertices <= hi + 1e-6)
    assert m.visual.vertex_colors.shape == (len(m.vertices), 4)
    cloud = trimesh.load(points)
    assert len(cloud.vertices) > 0 and np.all(np.abs(cloud.vertices) < 10)
    record = json.loads((depth / "depth_scale.json").read_text())
    assert [v["view"] for v in record["views"]] == [0, 1, 2, 3]
    out = fitted.render(fitted.cameras.c2w[fitted.train_idx], fitted.cameras.intrinsics[0])
    for i, view in enumerate(record["views"]):
        back = iio.imread(depth / view["file"]).astype(np.float64) * record["scale"]
        surface = out["acc"][i] > 0.5
        assert np.abs(back[surface] - out["z_depth"][i][surface]).max() <= record["scale"] / 2 + 1e-6
        np.testing.assert_array_equal(back[~surface], 0)
    assert not list(tmp_path.glob(".*")), "no temporary left behind"
    said = capsys.readouterr().out
    assert "m.ply" in said and "from 8 views (4 pseudo)" in said   # 4 training views, 1 pseudo view each


@pytest.mark.parametrize("suffix", [".obj", ".glb"])
def test_obj_and_glb_meshes_load_with_their_faces(run, level, tmp_path, suffix):
    out = tmp_path / f"m{suffix}"
    assert main([str(run), "--mesh", str(out), "--resolution", "16", "--level", level, "--quiet"]) == 0
    assert len(trimesh.load(out, force="mesh").faces) > 0


@pytest.mark.parametrize("flags, names", [
    ([], "--mesh"),
    (["--mesh", "m.stl"], "--mesh"),
    (["--points", "p.obj"], "--points"),
    (["--mesh", "m.ply", "--resolution", "4"], "--resolution"),
    (["--mesh", "m.ply", "--level", "-1"], "--level"),
    (["--depth", "d", "--iteration", "3"], "--iteration"),
])
def test_bad_flags_exit_2_with_one_line_naming_the_flag(run, tmp_path, capsys, monkeypatch, flags, names):
    monkeypatch.chdir(tmp_path)
    assert main([str(run), *flags, "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("senerf-export: error: ") and names in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_an_existing_output_is_kept_without_overwrite(run, tmp_path, capsys):
    mesh, depth = tmp_path / "m.ply", tmp_path / "d"
    mesh.write_text("mine")
    (depth / "x").mkdir(parents=True)
    for flags in (["--mesh", str(mesh)], ["--depth", str(depth)]):
        assert main([str(run), *flags, "--quiet"]) == 2
        assert "--overwrite" in capsys.readouterr().err
    assert main([str(run), "--depth", str(depth), "--overwrite", "--quiet"]) == 2   # not an export of ours
    assert mesh.read_text() == "mine" and (depth / "x").is_dir()


def test_overwrite_replaces_an_earlier_depth_export_whole(run, tmp_path):
    depth = tmp_path / "d"
    assert main([str(run), "--depth", str(depth), "--views", "test", "--quiet"]) == 0
    assert sorted(p.name for p in depth.iterdir()) == ["depth_000.png", "depth_scale.json"]
    assert main([str(run), "--depth", str(depth), "--views", "all", "--overwrite", "--quiet"]) == 0
    assert len(list(depth.glob("depth_*.png"))) == 5 and [p.name for p in tmp_path.iterdir()] == ["d"]
