"""Tests of senerf/procedural/room.py: a closed room, exact depths, the instant-ngp export read back."""

from __future__ import annotations

import json
import time

import imageio.v3 as iio
import numpy as np
import pytest

from senerf.data import load_scene
from senerf.data.llff import llff_splits
from senerf.errors import InputError
from senerf.geometry import Intrinsics, opengl_to_opencv, pixel_rays
from senerf.procedural import (
    GROUND_TOP,
    ROOM_OBJECT_NAMES,
    RoomConfig,
    SceneConfig,
    build_room_scene,
    build_scene,
    cast_rays,
    export_room_scene,
    render,
    room_ring_poses,
    shade,
    texture_color,
)

W, H = 40, 32  # non-square on purpose: catches width/height mix-ups
ROOM_IDS = {name: i for i, name in enumerate(ROOM_OBJECT_NAMES)}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("room") / "scene"
    cfg = RoomConfig(seed=2, half_width=3.0, ceiling_height=2.4)
    export_room_scene(out, cfg, n_views=12, width=W, height=H, fov_deg=70.0, seed=5)
    return out, cfg


def _planes(cfg: RoomConfig) -> dict:
    """Room surface name -> (axis, coordinate) of its plane, from the config alone."""
    w = cfg.half_width
    return {"wall_px": (0, w), "wall_nx": (0, -w), "wall_py": (1, w), "wall_ny": (1, -w),
            "floor": (2, GROUND_TOP), "ceiling": (2, GROUND_TOP + cfg.ceiling_height)}


def test_default_export_hits_a_surface_in_every_pixel_of_every_view_in_seconds(tmp_path):
    t0 = time.perf_counter()
    out = export_room_scene(tmp_path / "room")
    seconds = time.perf_counter() - t0
    depth = np.stack([np.load(out / "depth" / f"frame_{k:05d}.npy") for k in range(48)])
    assert depth.shape == (48, 100, 100) and depth.dtype == np.float32
    assert np.all(np.isfinite(depth)) and depth.min() > 0.5
    assert depth.max() > 5.0  # the far walls are seen
    assert iio.imread(out / "images" / "frame_00047.png").shape == (100, 100, 3)
    assert seconds < 10.0


def test_rays_from_anywhere_in_the_room_hit_an_inward_facing_surface():
    """Random rays from inside (off the objects), and rays aimed exactly at the room's corners, edges and the
    diagonals of its quads, all hit; room surfaces face the rays that hit them (inward normals)."""
    cfg = RoomConfig(seed=1)
    scene = build_room_scene(cfg)
    rng = np.random.default_rng(0)
    n = 200_000
    r, phi = rng.uniform(1.5, 3.4, n), rng.uniform(0.0, 2 * np.pi, n)
    o = np.column_stack([r * np.cos(phi), r * np.sin(phi), rng.uniform(GROUND_TOP + 0.05, cfg.ceiling_z - 0.05, n)])
    o[:, :2] = np.clip(o[:, :2], -3.45, 3.45)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = cast_rays(scene, o, d)
    assert hits.hit.all()
    room = hits.object_id >= ROOM_IDS["wall_px"]
    room |= hits.object_id == ROOM_IDS["floor"]
    assert room.mean() > 0.5
    assert np.all(np.einsum("ij,ij->i", hits.normals[room], d[room]) < 0)
    w, lo, hi, s = 3.5, GROUND_TOP, cfg.ceiling_z, np.linspace(-3.5, 3.5, 701)
    targets = [(x, y, z) for x in (-w, w) for y in (-w, w) for z in (lo, hi)]
    for a in (-w, w):
        for z in (lo, hi):
            targets += [(a, t, z) for t in s] + [(t, a, z) for t in s]
        targets += [(a, a, z) for z in np.linspace(lo, hi, 301)] + [(a, -a, z) for z in np.linspace(lo, hi, 301)]
    targets += [(t, t, z) for t in s for z in (lo, hi)]
    targets = np.array(targets)
    for eye in ([2.2, 0.3, 0.4], [-1.6, -1.6, 0.8], [0.0, 1.7, 1.6]):
        d = targets - eye
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        assert cast_rays(scene, np.tile(eye, (len(d), 1)), d).hit.all()


def test_room_depths_equal_the_analytic_plane_intersections(exported):
    """Each pixel's saved z-depth: where a room surface is seen, the nearest of the six planes along the pixel's
    ray (pixel_rays, planes from the config); elsewhere an object in front of it."""
    out, cfg = exported
    intr = Intrinsics.from_fov(70.0, W, H)
    poses = room_ring_poses(12, seed=5)
    scene = build_room_scene(cfg)
    seen = {name: 0 for name in _planes(cfg)}
    for k in range(12):
        o, d, z_per_dist = pixel_rays(intr, poses[k])
        depth = np.load(out / "depth" / f"frame_{k:05d}.npy")
        dist = {}
        for name, (axis, c) in _planes(cfg).items():
            with np.errstate(divide="ignore"):
                t = (c - o[..., axis]) / d[..., axis]
            dist[name] = np.where(t > 0, t, np.inf)
        names = list(dist)
        stack = np.stack([dist[m] for m in names])
        nearest, exit_dist = stack.argmin(axis=0), stack.min(axis=0)
        analytic = exit_dist * z_per_dist
        object_id = render(scene, intr, poses[k]).object_id
        on_room = np.isin(object_id, [ROOM_IDS[m] for m in names])
        assert np.array_equal(object_id[on_room], np.array([ROOM_IDS[names[i]] for i in nearest[on_room]]))
        assert np.allclose(depth[on_room], analytic[on_room], rtol=1e-6, atol=0.0)
        assert np.all(depth[~on_room] < analytic[~on_room])
        for i, name in enumerate(names):
            seen[name] += int(np.sum(on_room & (nearest == i)))
    assert all(v > 20 for v in seen.values()), seen  # every surface is checked


def test_export_loads_as_an_rgb_only_scene_with_the_rendered_cameras(exported):
    out, cfg = exported
    scene = load_scene(out)
    assert scene.alpha is None and scene.rgb.shape == (12, H, W, 3)
    intr = Intrinsics.from_fov(70.0, W, H)
    assert np.allclose(scene.intrinsics.K, intr.K, rtol=1e-12, atol=1e-12)
    poses = room_ring_poses(12, seed=5)
    assert np.max(np.abs(scene.c2w - poses)) < 1e-9
    built = build_room_scene(cfg)
    for k in range(12):
        view = render(built, intr, poses[k])
        assert np.max(np.abs(scene.rgb[k] - view.rgb)) <= 0.5 / 255 + 1e-6  # 8-bit quantisation
    doc = json.loads((out / "transforms.json").read_text())
    assert "aabb_scale" not in doc and doc["camera_model"] == "OPENCV"
    assert (doc["w"], doc["h"]) == (W, H) and [f["file_path"] for f in doc["frames"][:2]] == [
        "images/frame_00000.png", "images/frame_00001.png"]
    gl = np.array([f["transform_matrix"] for f in doc["frames"]])
    assert np.max(np.abs(opengl_to_opencv(gl) - poses)) < 1e-12
    meta = json.loads((out / "procedural.json").read_text())
    assert meta["room_config"]["seed"] == 2 and meta["camera_seed"] == 5
    assert meta["room"] == {"floor_z": GROUND_TOP, "ceiling_z": GROUND_TOP + 2.4, "half_width": 3.0}


def test_aabb_scale_is_written_only_when_given_and_must_be_instant_ngps(tmp_path):
    small = dict(n_views=2, width=8, height=6)
    out = export_room_scene(tmp_path / "a", aabb_scale=4, **small)
    assert json.loads((out / "transforms.json").read_text())["aabb_scale"] == 4
    assert load_scene(out).n_images == 2
    for bad in (0, 3, -4, 4.5, 256, True, "4", float("nan")):
        with pytest.raises(ValueError, match="aabb_scale"):
            export_room_scene(tmp_path / "b", aabb_scale=bad, **small)
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("seed", [0, 3])
def test_room_holds_the_object_scenes_objects_inside_its_six_surfaces(seed):
    room = build_room_scene(RoomConfig(seed=seed, half_width=4.0, ceiling_height=3.0))
    objects = build_scene(SceneConfig(seed=seed, with_ground=False))
    for oid in (1, 2, 3, 4):
        assert np.array_equal(room.mesh.triangles[room.face_object == oid],
                              objects.mesh.triangles[objects.face_object == oid])
        assert np.array_equal(room.textures[oid].colors, objects.textures[oid].colors)
        pts = room.mesh.triangles[room.face_object == oid].reshape(-1, 3)
        assert np.hypot(pts[:, 0], pts[:, 1]).max() < 1.3  # the cameras' 1.5 from the z axis clears them
    for name, (axis, c) in _planes(RoomConfig(half_width=4.0, ceiling_height=3.0)).items():
        tri = room.mesh.triangles[room.face_object == ROOM_IDS[name]]
        assert len(tri) == 2 and np.allclose(tri[..., axis], c, atol=1e-12)
        normal = room.mesh.face_normals[room.face_object == ROOM_IDS[name]]
        assert np.allclose(normal, -np.sign(c) * np.eye(3)[axis])  # inward
    assert room.object_names == ROOM_OBJECT_NAMES and np.unique(room.face_object).tolist() == list(range(10))


def test_room_surfaces_are_lit_through_their_inward_normals():
    """colour = albedo x (ambient + (1 - ambient) max(0, n . l)) with n pointing into the room: the floor is lit
    from above, the ceiling (n = -z) and the walls facing away from the light get the ambient term only."""
    cfg = RoomConfig(seed=4, ambient=0.3)
    scene = build_room_scene(cfg)
    light = np.array(cfg.light_dir) / np.linalg.norm(cfg.light_dir)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-3.0, 3.0, size=(50, 2))
    xy[:, 0] = np.where(np.abs(xy[:, 0]) < 1.5, 2.0, xy[:, 0])  # off the objects
    for name, z0, dz, n in (("floor", 1.0, -1.0, (0, 0, 1)), ("ceiling", 0.0, 1.0, (0, 0, -1))):
        o = np.column_stack([xy, np.full(50, z0)])
        hits = cast_rays(scene, o, np.tile([0.0, 0.0, dz], (50, 1)))
        assert np.all(hits.object_id == ROOM_IDS[name])
        w2l = scene.world_to_local[ROOM_IDS[name]]
        albedo = texture_color(scene.textures[ROOM_IDS[name]], hits.points @ w2l[:3, :3].T + w2l[:3, 3])
        lam = max(0.0, float(np.dot(n, light)))
        assert np.allclose(shade(scene, hits), albedo * (0.3 + 0.7 * lam), atol=1e-12)
    # wall_px faces -x, away from the light (x component 0.45): ambient only, from any viewpoint
    pts = np.column_stack([np.full(20, 3.5), rng.uniform(-3, 3, 20), rng.uniform(-0.5, 1.7, 20)])
    for eye in ([0.0, 2.0, 0.5], [-2.0, -2.0, 1.2]):
        d = pts - eye
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        hits = cast_rays(scene, np.tile(eye, (20, 1)), d)
        wall = hits.object_id == ROOM_IDS["wall_px"]
        assert wall.sum() > 10 and np.allclose(hits.points[wall], pts[wall], atol=1e-9)
        w2l = scene.world_to_local[ROOM_IDS["wall_px"]]
        albedo = texture_color(scene.textures[ROOM_IDS["wall_px"]], pts[wall] @ w2l[:3, :3].T + w2l[:3, 3])
        assert np.allclose(shade(scene, hits)[wall], albedo * 0.3, atol=1e-12)


def test_room_textures_are_structured_at_about_half_a_unit():
    """On every room surface the mean colour difference between points ``dist`` apart (in units of the
    palette's span) levels off between 0.4 and 1 unit (cells of 0.6 and 0.8, noise blobs of 0.5): at 0.05 it is
    under a fifth of its level at 2, at 0.2 under two thirds, at 1 over four fifths, and the level is high."""
    scene = build_room_scene(RoomConfig(seed=0))
    rng = np.random.default_rng(2)
    local = np.column_stack([rng.uniform(-3.5, 3.5, (4000, 2)), np.zeros(4000)])
    angle = rng.uniform(0, 2 * np.pi, 4000)
    step = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(4000)])
    for oid in (0, 5, 6, 7, 8, 9):
        tex = scene.textures[oid]
        col, span = texture_color(tex, local), np.abs(tex.colors[1] - tex.colors[0]).sum()
        diff = {dist: np.mean(np.abs(col - texture_color(tex, local + dist * step)).sum(axis=1)) / span
                for dist in (0.05, 0.2, 1.0, 2.0)}
        level = diff[2.0]
        assert level > 0.3 and diff[0.05] < 0.2 * level, (ROOM_OBJECT_NAMES[oid], diff)
        assert diff[0.2] < 2 / 3 * level and diff[1.0] > 0.8 * level, (ROOM_OBJECT_NAMES[oid], diff)


def test_deterministic_given_the_seeds_and_the_seeds_matter():
    intr = Intrinsics.from_fov(60.0, 24, 20)
    c2w = room_ring_poses(5, seed=1)[3]
    a, b, c = (render(build_room_scene(RoomConfig(seed=s)), intr, c2w) for s in (7, 7, 8))
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.z_depth, b.z_depth)
    assert not np.array_equal(a.rgb, c.rgb)
    assert np.array_equal(room_ring_poses(9, seed=3), room_ring_poses(9, seed=3))
    assert not np.array_equal(room_ring_poses(9, seed=3), room_ring_poses(9, seed=4))
    assert np.array_equal(room_ring_poses(9, height_jitter=0.0, seed=3), room_ring_poses(9, height_jitter=0.0, seed=4))


def test_ring_views_look_at_the_target_and_llff_test_views_lie_between_training_views_at_every_height():
    poses = room_ring_poses(48, radius=2.2, heights=(0.0, 0.4, 0.8), height_jitter=0.05, seed=0)
    eye = poses[:, :3, 3]
    assert np.allclose(np.hypot(eye[:, 0], eye[:, 1]), 2.2, atol=1e-12)
    forward = -eye / np.linalg.norm(eye, axis=1, keepdims=True)   # toward the target (0, 0, 0)
    assert np.allclose(poses[:, :3, 2], forward, atol=1e-12)
    assert np.all(poses[:, 2, 1] < 0)  # image y (down) points down in the world: upright images
    azimuth = np.degrees(np.arctan2(eye[:, 1], eye[:, 0])) % 360.0
    assert np.allclose(azimuth, 7.5 * np.arange(48), atol=1e-9)
    level = np.round(eye[:, 2] / 0.4).astype(int)
    assert np.all(np.abs(eye[:, 2] - 0.4 * level) <= 0.05) and np.array_equal(level, np.arange(48) % 3)
    split = llff_splits(48)
    assert set(level[split["test"]]) == {0, 1, 2}
    assert np.all(np.isin((split["test"][:, None] + [-1, 1]) % 48, split["train"]))


@pytest.mark.parametrize(
    "kwargs",
    [dict(half_width=1.5), dict(half_width=60.0), dict(ceiling_height=2.0), dict(ceiling_height=51.0),
     dict(texture_scale=0.0), dict(ambient=1.5), dict(ambient=-0.1), dict(light_dir=(0.0, 0.0, 0.0)),
     dict(light_dir=(1.0, 2.0)), dict(half_width=float("nan"))],
)
def test_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        RoomConfig(**kwargs)


def test_config_accepts_the_ends_of_its_ranges():
    for kwargs in (dict(half_width=1.51), dict(half_width=50.0), dict(ceiling_height=2.16),
                   dict(ceiling_height=50.0), dict(ambient=0.0), dict(ambient=1.0)):
        RoomConfig(**kwargs)
    with pytest.raises(ValueError, match="RoomConfig"):
        build_room_scene(SceneConfig())


def test_refuses_an_existing_scene_bad_arguments_and_cameras_outside_the_room(exported, tmp_path):
    out, _ = exported
    with pytest.raises(InputError, match="already holds a scene"):
        export_room_scene(out, n_views=1, width=8, height=8)
    a_file = tmp_path / "a_file"
    a_file.write_text("mine")
    with pytest.raises(InputError, match="not a folder"):
        export_room_scene(a_file, n_views=1, width=8, height=8)
    assert a_file.read_text() == "mine"
    for kwargs, field in ((dict(n_views=0), "n_views"), (dict(n_views=True), "n_views"), (dict(width=0), "width"),
                          (dict(fov_deg=180.0), "fov_deg"), (dict(fov_deg=0.0), "fov_deg"),
                          (dict(radius=3.45), "camera"), (dict(radius=1.4), "camera"),
                          (dict(heights=(0.0, 1.8)), "camera"), (dict(heights=(-0.6,)), "camera"),
                          (dict(config=RoomConfig(half_width=2.0)), "camera"), (dict(heights=()), "heights")):
        with pytest.raises(ValueError, match=field):
            export_room_scene(tmp_path / "b", **kwargs)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]  # nothing written for a refused call


def test_overwrite_with_fewer_views_leaves_no_unlisted_frames(tmp_path):
    out = tmp_path / "s"
    export_room_scene(out, n_views=5, width=8, height=6)
    (out / "images" / "notes.txt").write_text("mine")
    export_room_scene(out, RoomConfig(seed=1), n_views=3, width=8, height=6, overwrite=True)
    assert sorted(p.name for p in (out / "images").iterdir()) == [
        "frame_00000.png", "frame_00001.png", "frame_00002.png", "notes.txt"]
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["frame_00000.npy", "frame_00001.npy",
                                                                 "frame_00002.npy"]
    assert load_scene(out).n_images == 3
    assert json.loads((out / "procedural.json").read_text())["room_config"]["seed"] == 1


def test_exact_room_depths_warp_each_pixel_onto_its_own_colour_in_the_next_view(exported):
    # The reliability estimate warps a pseudo pixel with its z-depth into a known view; in an unbounded scene
    # those depths reach the walls, several camera distances away. With the exact depths, a warped pixel must
    # land on the same surface point: its colour (Lambertian) agrees, and the occlusion test keeps nearly all
    # pixels that land in the image. Catches a z-depth / ray-distance mix-up or a convention slip in the warp.
    from senerf.geometry import reproject
    from senerf.selftrain import bilinear_sample

    root, _ = exported
    scene = load_scene(root)
    z = np.stack([np.load(root / "depth" / f"frame_{k:05d}.npy") for k in range(2)]).astype(np.float64)
    assert z.max() > 2.0 * np.linalg.norm(scene.c2w[0, :3, 3])   # the far wall: beyond twice the camera radius
    k = scene.intrinsics
    uv, ok = reproject(z[0], k, scene.c2w[0], k, scene.c2w[1], z_depth_dst=z[1], rel_tol=0.01)
    assert ok.mean() > 0.6
    warped = bilinear_sample(scene.rgb[1], uv[ok])
    err = np.median(np.abs(warped - scene.rgb[0][ok]).max(axis=-1))   # aliasing of 40x32 renders: ~0.05
    assert err < 0.06
    wrong, lands = reproject(z[0] * 1.2, k, scene.c2w[0], k, scene.c2w[1])   # depths 20 % off: colours disagree
    sel = ok & lands
    assert np.median(np.abs(bilinear_sample(scene.rgb[1], wrong[sel]) - scene.rgb[0][sel]).max(axis=-1)) > 2 * err
