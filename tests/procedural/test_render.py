"""Tests of senerf/procedural/render.py: exact hits, depth conventions, view independence."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from senerf.geometry import Intrinsics, pixel_rays, pose_from_spherical, project
from senerf.procedural.render import cast_rays, render, shade
from senerf.procedural.scene import GROUND_TOP, SceneConfig, build_scene

SIZE = 96
INTR = Intrinsics.from_fov(39.6, SIZE, SIZE)


@pytest.fixture(scope="module")
def scene():
    return build_scene(SceneConfig(seed=0))


@pytest.fixture(scope="module")
def view(scene):
    c2w = pose_from_spherical(35.0, 40.0, 4.0)
    return c2w, render(scene, INTR, c2w)


def test_render_shapes_and_miss_conventions(view):
    _, r = view
    assert r.rgb.shape == (SIZE, SIZE, 3) and r.rgb.dtype == np.float32
    hit = r.alpha == 1.0
    assert set(np.unique(r.alpha)) == {0.0, 1.0}
    assert 0.2 < hit.mean() < 0.95  # object-centric: the scene fills much of the view, background remains
    assert np.all(np.isinf(r.z_depth[~hit])) and np.all(np.isfinite(r.z_depth[hit]))
    assert np.all(r.object_id[~hit] == -1) and np.all(r.object_id[hit] >= 0)
    assert np.all(r.rgb[~hit] == 0) and np.all(np.isnan(r.points[~hit]))
    assert np.allclose(np.linalg.norm(r.normals[hit], axis=-1), 1.0, atol=1e-6)
    assert np.array_equal(r.depth_or_zero()[~hit], np.zeros((~hit).sum(), np.float32))
    white = r.composite((1.0, 1.0, 1.0))
    assert np.all(white[~hit] == 1.0) and np.array_equal(white[hit], r.rgb[hit])


def test_pixel_rays_hit_surface_at_rendered_depth(scene, view):
    """origin + ray_dist * dir is the ray-cast hit: on the hit triangle, equal to trimesh's own location,
    and its camera-frame z (geometry.project) equals z_depth = ray_dist * z_per_dist."""
    c2w, r = view
    o, d, zpd = pixel_rays(INTR, c2w)
    hit = r.alpha == 1.0
    pts = o[hit] + r.ray_dist[hit][:, None] * d[hit]
    assert np.allclose(pts, r.points[hit], atol=1e-12)
    # z-depth convention, checked through geometry.project (independent of the renderer)
    uv, z, valid = project(pts, INTR, c2w)
    assert valid.all()
    assert np.max(np.abs(z - r.z_depth[hit])) < 1e-9
    assert np.max(np.abs(r.z_depth[hit] - r.ray_dist[hit] * zpd[hit])) < 1e-12
    # the point projects back to the pixel centre it came from
    jj, ii = np.nonzero(hit)
    assert np.max(np.abs(uv - np.stack([ii + 0.5, jj + 0.5], -1))) < 1e-6
    # the point lies on the triangle embree reported (plane distance and barycentric coordinates)
    hits = cast_rays(scene, o[hit], d[hit])
    tri = scene.mesh.triangles[hits.face]
    plane = np.einsum("ij,ij->i", scene.mesh.face_normals[hits.face], pts - tri[:, 0])
    assert np.max(np.abs(plane)) < 1e-10
    bary = trimesh.triangles.points_to_barycentric(tri, pts)
    assert bary.min() > -1e-4 and bary.max() < 1 + 1e-4
    # trimesh's own first-hit location (independent float32/float64 pipeline) agrees
    loc, idx_ray, _ = scene.intersector.intersects_location(o[hit], d[hit], multiple_hits=False)
    assert len(idx_ray) == hit.sum()
    assert np.max(np.abs(loc - pts[idx_ray])) < 1e-5


def test_vertical_rays_hit_ground_at_known_height(scene):
    xy = np.array([[1.1, -0.2], [-0.8, -0.95], [0.05, -1.2]])  # ground only, inside the disc
    o = np.column_stack([xy, np.full(3, 3.0)])
    d = np.tile([0.0, 0.0, -1.0], (3, 1))
    h = cast_rays(scene, o, d)
    assert h.hit.all() and np.all(h.object_id == 0)
    assert np.allclose(h.ray_dist, 3.0 - GROUND_TOP, atol=1e-12)
    assert np.allclose(h.normals, [0.0, 0.0, 1.0])
    # a ray outside the disc misses
    miss = cast_rays(scene, np.array([[2.0, 2.0, 3.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert not miss.hit[0] and np.isinf(miss.ray_dist[0]) and miss.object_id[0] == -1


def test_colour_is_view_independent(scene, view):
    """The same surface point seen from another camera gets exactly the same colour."""
    c2w, r = view
    hit = r.alpha == 1.0
    pts = r.points[hit][::7]
    eye2 = pose_from_spherical(120.0, 60.0, 4.0)[:3, 3]
    d2 = pts - eye2
    dist = np.linalg.norm(d2, axis=1)
    h2 = cast_rays(scene, np.tile(eye2, (len(pts), 1)), d2 / dist[:, None])
    same = h2.hit & (np.abs(h2.ray_dist - dist) < 1e-6) & (h2.face == cast_rays(
        scene, np.tile(c2w[:3, 3], (len(pts), 1)), (pts - c2w[:3, 3]) / np.linalg.norm(
            pts - c2w[:3, 3], axis=1)[:, None]).face)
    assert same.sum() > 50  # enough co-visible points to make the comparison meaningful
    c1 = r.rgb[hit][::7][same]
    c2 = shade(scene, h2)[same].astype(np.float32)
    assert np.max(np.abs(c1 - c2)) < 1e-5


def test_without_ground_alpha_is_object_silhouette():
    c2w = pose_from_spherical(200.0, 25.0, 4.0)
    full = render(build_scene(SceneConfig(with_ground=True)), INTR, c2w)
    objs = render(build_scene(SceneConfig(with_ground=False)), INTR, c2w)
    assert np.array_equal(objs.alpha == 1.0, objs.object_id >= 1)
    # where the full render sees an object, the objects-only render sees the same thing
    sel = full.object_id >= 1
    assert np.array_equal(objs.object_id[sel], full.object_id[sel])
    assert np.allclose(objs.z_depth[sel], full.z_depth[sel])
    assert (full.alpha > objs.alpha).any()  # the ground adds coverage


def test_render_deterministic_and_checks_inputs(scene, view):
    c2w, r = view
    again = render(scene, INTR, c2w)
    assert np.array_equal(again.rgb, r.rgb) and np.array_equal(again.z_depth, r.z_depth)
    with pytest.raises(ValueError):
        render(scene, INTR, c2w[:3])
    with pytest.raises(ValueError):
        render(scene, INTR.K, c2w)
    with pytest.raises(ValueError):
        cast_rays(scene, np.zeros((2, 3)), np.ones((2, 3)))  # not unit
    with pytest.raises(ValueError):
        cast_rays(scene, np.zeros((2, 3)), np.zeros((3, 3)))


def _lambert(normal) -> float:
    """ambient + (1 - ambient) * max(0, n . l) for the default light (0.45, -0.35, 0.82), normalised here."""
    light = np.array([0.45, -0.35, 0.82]) / np.sqrt(0.45**2 + 0.35**2 + 0.82**2)
    return 0.35 + 0.65 * max(0.0, float(np.dot(normal, light)))


def _down(scene, xy, z0=3.0):
    """Hits of vertical rays from height ``z0`` down through the points ``xy`` (N, 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    return cast_rays(scene, np.column_stack([xy, np.full(len(xy), z0)]), np.tile([0.0, 0.0, -1.0], (len(xy), 1)))


def test_ground_colour_is_its_checker_times_lambert_by_hand(scene):
    """Ground (object 0, checker2d at 6 cells per unit, coarse cells of 1/2): t by hand at five points, colour
    = ((1 - t) c0 + t c1) x shade, from above (lit) and from below (facing away from the light: ambient)."""
    xy = np.array([[1.1, -0.2], [1.1, -0.1], [-0.8, -0.95], [-1.05, 0.1], [0.05, -1.2]])
    t = np.array([0.15, 1.0, 0.66, 1.0, 0.15])  # see test_scene.test_checker2d_has_a_coarser_modulation_by_hand
    c0, c1 = scene.textures[0].colors
    albedo = (1 - t)[:, None] * c0 + t[:, None] * c1
    top = _down(scene, xy)
    assert np.all(top.object_id == 0) and np.allclose(top.points[:, 2], GROUND_TOP, atol=1e-12)
    assert np.allclose(shade(scene, top), albedo * _lambert([0.0, 0.0, 1.0]), atol=1e-12)
    below = cast_rays(scene, np.column_stack([xy, np.full(len(xy), -3.0)]), np.tile([0.0, 0.0, 1.0], (len(xy), 1)))
    assert np.all(below.object_id == 0) and np.allclose(below.normals, [0.0, 0.0, -1.0])
    assert np.allclose(shade(scene, below), albedo * 0.35, atol=1e-12)


def test_cylinder_top_shows_the_helix_in_the_cylinder_frame(scene):
    """The cylinder's top cap, hit from above at angle phi around its axis (found from its mesh): helix
    stripe floor(6 z + 4 phi / 2 pi) mod 2 with local z = 0.65 (half its height), by hand."""
    pts = scene.mesh.triangles[scene.face_object == 3].reshape(-1, 3)
    axis = (pts.min(axis=0) + pts.max(axis=0))[:2] / 2
    assert np.isclose(pts[:, 2].max() - pts[:, 2].min(), 1.3)
    phi = np.array([0.1, 0.3, -0.5, 2.0, -2.5, 1.0])
    stripe = np.array([1, 0, 1, 1, 0, 0])  # floor(3.9 + 2 phi / pi): 3.96, 4.09, 3.58, 5.17, 2.31, 4.54
    hits = _down(scene, axis + 0.15 * np.column_stack([np.cos(phi), np.sin(phi)]))
    assert np.all(hits.object_id == 3) and np.allclose(hits.points[:, 2], pts[:, 2].max(), atol=1e-12)
    c0, c1 = scene.textures[3].colors
    expect = np.where(stripe[:, None] == 1, c1, c0) * _lambert([0.0, 0.0, 1.0])
    assert np.allclose(shade(scene, hits), expect, atol=1e-12)


def test_box_top_shows_the_3d_checker_in_the_box_frame(scene):
    """The box (rotated about z) hit from above: its checker3d texture is evaluated in the box's own frame,
    found here from the mesh (centre, a side normal), not from the scene's transforms."""
    corners = scene.mesh.triangles[scene.face_object == 1].reshape(-1, 3)
    centre = (corners.min(axis=0) + corners.max(axis=0)) / 2  # a box turned about z: its bounds' centre
    normals = scene.mesh.face_normals[scene.face_object == 1]
    side = normals[np.abs(normals[:, 2]) < 0.5][0]  # any side normal: the centred checker is symmetric
    ex, ey = side, np.cross([0.0, 0.0, 1.0], side)
    ab = np.array([[0.05, 0.05], [0.1, 0.05], [-0.1, 0.3], [-0.3, -0.1], [0.1, 0.1], [0.3, 0.05], [-0.1, -0.1]])
    parity = np.array([1, 0, 0, 0, 1, 1, 1])  # test_scene.test_checker_cells_are_centred_and_signed_coordinates_count
    hits = _down(scene, centre[:2] + ab[:, :1] * ex[:2] + ab[:, 1:] * ey[:2])
    assert np.all(hits.object_id == 1) and np.allclose(hits.points[:, 2], centre[2] + 0.4, atol=1e-12)
    c0, c1 = scene.textures[1].colors
    expect = np.where(parity[:, None] == 1, c1, c0) * _lambert([0.0, 0.0, 1.0])
    assert np.allclose(shade(scene, hits), expect, atol=1e-12)


def test_first_and_last_faces_are_hits(scene):
    """Face 0 (the ground's underside) and the last face (the torus) count as hits: a ray straight at a
    face's centroid from 0.01 in front of it hits that face at distance 0.01."""
    faces = np.array([0, len(scene.mesh.faces) - 1])
    n = scene.mesh.face_normals[faces]
    h = cast_rays(scene, scene.mesh.triangles_center[faces] + 0.01 * n, -n)
    assert h.hit.all() and np.array_equal(h.face, faces)
    assert np.allclose(h.ray_dist, 0.01, atol=1e-12) and np.array_equal(h.object_id, [0, 4])


def test_rays_cast_in_chunks_land_where_cast_at_once(scene, view, monkeypatch):
    import importlib

    render_module = importlib.import_module("senerf.procedural.render")  # the package exports render() too
    c2w, _ = view
    o, d, _ = pixel_rays(Intrinsics.from_fov(39.6, 9, 7), c2w)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    whole = cast_rays(scene, o, d)
    monkeypatch.setattr(render_module, "_CHUNK", 10)  # 63 rays: 7 chunks, the last one short
    chunked = cast_rays(scene, o, d)
    assert whole.hit.sum() > 10 and (~whole.hit).sum() > 0
    assert np.array_equal(chunked.face, whole.face) and np.array_equal(chunked.ray_dist, whole.ray_dist)


def test_cast_rays_refuses_non_finite_or_non_unit_rays(scene):
    o, d = np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1))
    cast_rays(scene, o, d * (1 + 5e-7))  # within the 1e-6 tolerance
    for bad_o, bad_d in ((o, d * (1 + 5e-6)), (o, d * (1 - 5e-6)), (np.array([[0.0, 0.0, np.nan], [0, 0, 0]]), d),
                         (o, np.array([[0.0, 0.0, np.inf], [0.0, 0.0, 1.0]]))):
        with pytest.raises(ValueError):
            cast_rays(scene, bad_o, bad_d)


def test_composite_refuses_a_background_that_is_not_one_colour(view):
    _, r = view
    with pytest.raises(ValueError, match=r"background"):
        r.composite((1.0, 1.0))
    with pytest.raises(ValueError, match=r"background"):
        r.composite(np.ones((SIZE, SIZE, 3)))
