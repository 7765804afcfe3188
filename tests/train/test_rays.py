"""Rays and their bounds (senerf/train/rays.py) against hand-worked geometry: the ray-box slab test, the bounds
and z-depth of camera rays in the world and in NDC, per-view intrinsics, float32 rays that keep their precision far
from the origin, and the training rays' random batches."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from senerf.config import ModelConfig
from senerf.data import Scene
from senerf.errors import InputError
from senerf.fields import render_rays
from senerf.geometry import Intrinsics, look_at, project
from senerf.train import (RayBatchSource, build_field, camera_rays, per_view_intrinsics, ray_aabb_bounds,
                          ray_dist_to_z_depth, render_views)

K = Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 24)
BOX = ((-1.2, -1.0, -0.8), (1.2, 1.0, 0.8))


def _model(offset=(0.0, 0.0, 0.0), **kw) -> ModelConfig:
    box = np.asarray(BOX) + np.asarray(offset, dtype=np.float64)
    return ModelConfig(**{**dict(aabb=box, resolution=8, multires=(1,), n_features=4, n_samples=16,
                                 occupancy_resolution=0), **kw})


def _ndc_model(near=0.5):
    return ModelConfig(ndc=True, ndc_near=near, aabb=((-1.5, -1.5, -1.0), (1.5, 1.5, 1.0)), resolution=8,
                       multires=(1,), n_features=4, occupancy_resolution=0)


def _c2w(offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    offset = np.asarray(offset, dtype=np.float64)
    return look_at(np.array([3.0, -2.0, 1.5]) + offset, offset, np.array([0.0, 0.0, 1.0]))[None]


def _render(field, rays, model) -> torch.Tensor:
    """``(R, 3)`` colours of ``rays`` (from :func:`camera_rays`), deterministic samples, white background."""
    with torch.no_grad():
        return render_rays(field, rays["origins"], rays["dirs"], rays["near"], rays["far"], model.n_samples, None,
                           torch.ones(3), randomized=False)["rgb"]


# ---------------------------------------------------------------------------------------------------------
# ray_aabb_bounds


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ray_aabb_bounds_by_hand(dtype):
    # Catches: the slab test without the per-axis min/max (t0 taken as the entry, t1 as the exit), which only
    # works for directions with positive components; min_near not applied to a camera inside the box; a miss
    # not an empty segment.  Box [-1, 1] x [-2, 2] x [-3, 3]:
    #  ray 0: o (0, 0, -5), d (0, 0, 1): z-slab [2, 8].
    #  ray 1: o (0.5, 5, 0), d (0, -1, 0): y-slab t in [(2 - 5)/-1, (-2 - 5)/-1] = [3, 7].
    #  ray 2: o (4, 0, 1), d (-0.8, 0, -0.6): x in [(1 - 4)/-0.8, (-1 - 4)/-0.8] = [3.75, 6.25];
    #         z in [(3 - 1)/-0.6, (-3 - 1)/-0.6] = [-3.33, 6.67]; y unbounded -> [3.75, 6.25].
    #  ray 3: o (0, 0, 0) inside, d (1, 0, 0): [min_near, 1].
    #  ray 4: o (0, 0, 10), d (0, 0, 1): the box is behind it: an empty segment (far = near).
    o = torch.tensor([[0.0, 0.0, -5.0], [0.5, 5.0, 0.0], [4.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 10.0]],
                     dtype=dtype)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [-0.8, 0.0, -0.6], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                     dtype=dtype)
    near, far = ray_aabb_bounds(o, d, ((-1, -2, -3), (1, 2, 3)), min_near=1e-3)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    assert near.dtype == dtype and far.dtype == dtype
    np.testing.assert_allclose(near[:4].numpy(), [2.0, 3.0, 3.75, 1e-3], rtol=tol)
    np.testing.assert_allclose(far[:4].numpy(), [8.0, 7.0, 6.25, 1.0], rtol=tol)
    assert float(far[4]) == float(near[4])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("zero", [0.0, -0.0, 1e-13, -1e-13])
def test_ray_aabb_bounds_rays_lying_in_a_face_are_inside_on_either_face(dtype, zero):
    # Catches: the parallel-axis guard replacing a zero component by +1e-12, which kept a ray lying in the
    # box's y = -2 face (t in [0, huge]) but dropped one lying in the y = +2 face (t in [-huge, 0]): the box is
    # closed, so both run along x through it.  Box [-1, 1] x [-2, 2] x [-3, 3], d = (1, zero, 0):
    #  rays 0 / 1: o (-5, -2, 0) / (-5, 2, 0): x-slab [4, 6] on either face;
    #  ray 2: o (-5, 0, 3), lying in the z = +3 face as well: [4, 6];
    #  ray 3: o (-5, 2.5, 0), beside the y slab: misses (far = near);
    #  ray 4: o (0, -2, 0) inside on the face: the camera is in the box, [min_near, 1].
    o = torch.tensor([[-5.0, -2.0, 0.0], [-5.0, 2.0, 0.0], [-5.0, 0.0, 3.0], [-5.0, 2.5, 0.0], [0.0, -2.0, 0.0]],
                     dtype=dtype)
    d = torch.tensor([[1.0, zero, 0.0]] * 5, dtype=dtype)
    near, far = ray_aabb_bounds(o, d, ((-1, -2, -3), (1, 2, 3)), min_near=1e-3)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    np.testing.assert_allclose(near[[0, 1, 2, 4]].numpy(), [4.0, 4.0, 4.0, 1e-3], rtol=tol)
    np.testing.assert_allclose(far[[0, 1, 2, 4]].numpy(), [6.0, 6.0, 6.0, 1.0], rtol=tol)
    assert float(far[3]) == float(near[3]) and np.isfinite(float(near[3]))


def test_ray_aabb_bounds_are_symmetric_under_mirroring_the_scene():
    # Catches: any face- or sign-dependent guard: mirroring origins, directions and box through y = 0 must give
    # the same bounds, here for rays that lie in faces, graze edges and cross the box along and off the axes.
    g = torch.Generator().manual_seed(0)
    box = torch.tensor([[-1.0, -2.0, -3.0], [1.0, 2.0, 3.0]], dtype=torch.float64)
    corners = torch.tensor([[x, y, z] for x in (-1.0, 0.0, 1.0) for y in (-2.0, 0.0, 2.0) for z in (-3.0, 3.0)],
                           dtype=torch.float64)
    axes = torch.eye(3, dtype=torch.float64)
    d = torch.cat([axes, -axes, torch.randn(12, 3, generator=g, dtype=torch.float64)])
    o = (corners[:, None, :] - 4.0 * d[None, :, :]).reshape(-1, 3)
    d = d.repeat(corners.shape[0], 1)
    mirror = torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64)
    near, far = ray_aabb_bounds(o, d, box)
    near_m, far_m = ray_aabb_bounds(o * mirror, d * mirror, box)   # the box is its own mirror image
    assert torch.equal(near, near_m) and torch.equal(far, far_m)
    hits = far > near
    assert 0 < int(hits.sum()) < hits.numel()   # some rays cross the box, some miss it


@pytest.mark.parametrize("o_shape, d_shape, aabb", [
    ((3,), (3,), BOX), ((4, 2), (4, 2), BOX), ((4, 3), (3, 3), BOX), ((4, 3), (4, 3, 1), BOX),
    ((2, 3), (2, 3), [[0, 0, 0], [1, 1, 1], [2, 2, 2]]), ((2, 3), (2, 3), [0, 0, 0, 1, 1, 1]),
])
def test_ray_aabb_bounds_refuses_misshapen_rays_or_box(o_shape, d_shape, aabb):
    name = "aabb" if o_shape == d_shape == (2, 3) else "origins and dirs"
    with pytest.raises(ValueError, match=name):
        ray_aabb_bounds(torch.zeros(o_shape), torch.ones(d_shape), aabb)


# ---------------------------------------------------------------------------------------------------------
# camera_rays and ray_dist_to_z_depth


def test_a_camera_inside_a_tiny_box_starts_at_a_box_relative_near():
    # Catches: camera_rays clamping near to an absolute 1e-3 (which would empty a 1e-2-wide scene's rays
    # near the camera) instead of min(1e-3, 1e-3 x the box's smallest side): box side 0.02 -> 2e-5.
    model = _model(aabb=((-0.01, -0.01, -0.01), (0.01, 0.01, 0.01)))
    rays = camera_rays(K, np.eye(4)[None], model)
    np.testing.assert_allclose(rays["near"].numpy(), 2e-5, rtol=1e-6)
    assert (rays["far"] >= 0.01 - 1e-7).all()


def test_constant_bounds_give_every_ray_the_same_segment():
    rays = camera_rays(K, _c2w(), _model(near=0.5, far=7.0))
    assert torch.equal(rays["near"], torch.full((32 * 24,), 0.5)) and torch.equal(rays["far"], torch.full((768,), 7.0))


def test_ndc_rays_span_the_near_plane_to_the_far_plane():
    # Catches: camera_rays giving NDC rays far = 1 instead of |d_ndc| (the directions are normalised, so
    # t' = 1 lies at distance |d_ndc|).  NDC z = 1 - 2 near / Z: -1 at Z = near, +1 at Z = infinity.
    c2w = np.eye(4)
    c2w[:3, 3] = (0.1, -0.2, 0.3)
    rays = camera_rays(K, c2w[None], _ndc_model())
    np.testing.assert_allclose(rays["near"].numpy(), 0.0)
    np.testing.assert_allclose(rays["origins"][:, 2].numpy(), -1.0, atol=1e-6)
    end = rays["origins"] + rays["far"][:, None] * rays["dirs"]
    np.testing.assert_allclose(end[:, 2].numpy(), 1.0, atol=1e-5)
    np.testing.assert_allclose(rays["dirs"].norm(dim=-1).numpy(), 1.0, rtol=1e-6)


@pytest.mark.parametrize("z_world", [1.0, 2.5, 10.0])
def test_ndc_ray_dist_to_z_depth_by_hand(z_world):
    # Catches in ray_dist_to_z_depth's NDC branch: the NDC length multiplied instead of divided, the camera's
    # own z not subtracted, the default near plane (1) used instead of ndc_near (0.5).
    # The camera sits at world z 0.3 looking along +z (identity rotation).  A point at world z Z has NDC
    # z = 1 - 2 near / Z; the NDC ray starts at z -1 with d_ndc_z = 2, so its parameter is t' = 1 - near / Z
    # and its distance along the unit NDC ray t' |d_ndc|.  Its camera z-depth is Z - 0.3.
    near = 0.5
    c2w = np.eye(4)
    c2w[:3, 3] = (0.1, -0.2, 0.3)
    rays = camera_rays(K, c2w[None], _ndc_model(near))
    dist = (1.0 - near / z_world) * rays["ndc_len"]
    z = ray_dist_to_z_depth(dist, rays, _ndc_model(near))
    np.testing.assert_allclose(z.numpy(), z_world - 0.3, rtol=1e-4)


def test_world_ray_dist_to_z_depth_is_the_projection_on_the_optical_axis():
    # Catches: ray_dist divided by z_per_dist instead of multiplied.  For the point p = o + s d (unit d) the
    # camera z-depth is (p - o) . axis = s (d . axis), axis = the camera's +z column of c2w.
    c2w = look_at(np.array([3.0, -2.0, 1.5]), np.zeros(3))
    model = _model()
    rays = camera_rays(K, c2w[None], model)
    s = 2.5
    expect = s * (rays["dirs"].double().numpy() @ c2w[:3, 2])
    z = ray_dist_to_z_depth(torch.full((rays["dirs"].shape[0],), s), rays, model)
    assert expect.min() < 0.95 * s                  # off-axis rays: z-depth and distance really differ
    np.testing.assert_allclose(z.numpy(), expect, rtol=1e-5)


@pytest.mark.parametrize("offset", [(1e6, 1e6, 1e6), (-3e7, 4e5, 2e6)])
def test_rays_of_a_scene_far_from_the_origin_match_the_same_scene_at_the_origin(offset):
    # Translate the cameras and the box together: the sample points in box coordinates are the same as at the
    # origin to float32 rounding of small numbers (in the world frame, a float32 origin at 1e6 is only known
    # to 0.06 units, 2.5 % of this box).
    near_rays = camera_rays(K, _c2w(), _model())
    far_model = _model(offset)
    far_rays = camera_rays(K, _c2w(offset), far_model)
    shift = torch.as_tensor(np.asarray(offset) - np.asarray(far_model.frame_origin), dtype=torch.float64)

    def box_coords(rays, lo):
        t = 0.5 * (rays["near"] + rays["far"]).double()
        pts = rays["origins"].double() + t[:, None] * rays["dirs"].double()
        return (pts - torch.as_tensor(lo, dtype=torch.float64)) / torch.as_tensor(
            np.asarray(BOX)[1] - np.asarray(BOX)[0])

    torch.testing.assert_close(far_rays["dirs"], near_rays["dirs"], rtol=0, atol=1e-6)
    torch.testing.assert_close(far_rays["near"], near_rays["near"], rtol=0, atol=2e-5)
    torch.testing.assert_close(far_rays["far"], near_rays["far"], rtol=0, atol=2e-5)
    torch.testing.assert_close(far_rays["origins"].double() - shift, near_rays["origins"].double(), rtol=0,
                               atol=2e-6)
    torch.testing.assert_close(box_coords(far_rays, far_model.field_aabb[0]),
                               box_coords(near_rays, BOX[0]), rtol=0, atol=1e-5)


def test_a_field_renders_the_same_image_far_from_the_origin():
    offset = (2e6, -2e6, 5e5)
    out = [_render(build_field(_model(off), seed=0), camera_rays(K, _c2w(off), _model(off)), _model(off))
           for off in [(0, 0, 0), offset]]
    torch.testing.assert_close(out[1], out[0], rtol=0, atol=1e-4)


def _two_camera_scene():
    k0, k1 = Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 24), Intrinsics(55.0, 50.0, 15.0, 13.0, 32, 24)
    c2w = np.concatenate([_c2w(), look_at([-2.5, -2.0, 1.0], [0.0, 0.0, 0.0])[None]])
    rgb = np.zeros((2, 24, 32, 3), np.float32)
    return Scene(name="two", root=".", rgb=rgb, alpha=None, intrinsics=k0, intrinsics_all=(k0, k1), c2w=c2w,
                 image_paths=("a.png", "b.png"))


def test_training_rays_use_each_views_own_intrinsics():
    # Per-frame intrinsics (instant-ngp/nerfstudio frames may carry their own fl_x): every training ray of
    # view i passes through its pixel centre under view i's K.  Golden: senerf.geometry.project, a separately
    # tested function.
    scene = _two_camera_scene()
    rays = RayBatchSource.from_scene(scene, [1, 0], _model())
    h, w = 24, 32
    jj, ii = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    centres = np.stack([ii, jj], axis=-1).reshape(-1, 2)
    pts = (rays.origins + 2.0 * rays.dirs).double().numpy().reshape(2, h * w, 3)
    for slot, view in enumerate([1, 0]):
        uv, _, ok = project(pts[slot], scene.intrinsics_all[view], scene.c2w[view])
        assert ok.all()
        np.testing.assert_allclose(uv, centres, atol=1e-4)


def test_render_views_and_camera_rays_take_one_intrinsics_per_camera():
    scene = _two_camera_scene()
    model = _model()
    field = build_field(model, seed=0)
    both = render_views(field, model, scene.intrinsics_all, scene.c2w)
    for i in range(2):
        one = render_views(field, model, scene.intrinsics_all[i], scene.c2w[i])
        for key in ("rgb", "z_depth", "acc"):
            np.testing.assert_array_equal(both[key][i], one[key][0])
    assert not np.array_equal(both["rgb"][1], render_views(field, model, scene.intrinsics, scene.c2w[1])["rgb"][0])
    ndc = dataclasses.replace(model, ndc=True, aabb=((-1.5, -1.5, -1.0), (1.5, 1.5, 1.0)), ndc_near=1.0)
    with pytest.raises(ValueError, match="NDC"):   # the NDC warp is built from one focal length
        camera_rays(scene.intrinsics_all, scene.c2w, ndc)


def test_camera_rays_refuse_poses_or_intrinsics_that_do_not_fit():
    for shape in [(16,), (1, 3, 4), (1, 4, 3)]:
        with pytest.raises(ValueError, match="c2w"):
            camera_rays(K, np.zeros(shape), _model())
    assert per_view_intrinsics(K, 2) == (K, K)
    for intrinsics in ([K], [K, K, K], [K, "K"], [K, Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 25)]):
        with pytest.raises(ValueError, match="intrinsics"):
            per_view_intrinsics(intrinsics, 2)


# ---------------------------------------------------------------------------------------------------------
# RayBatchSource


def _source(**replace) -> dict:
    n = 4
    args = dict(origins=torch.zeros(n, 3), dirs=torch.ones(n, 3), rgb=torch.zeros(n, 3), alpha=torch.ones(n),
                near=torch.zeros(n), far=torch.ones(n), model=_model())
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value", [
    ("dirs", torch.ones(3, 3)), ("rgb", torch.zeros(4, 4)), ("rgb", torch.zeros(4, 3, dtype=torch.float64)),
    ("origins", torch.zeros(4, 3, dtype=torch.float16)), ("near", torch.zeros(3)),
    ("far", torch.ones(4, dtype=torch.float64)), ("alpha", torch.ones(4, 1)),
])
def test_a_ray_batch_source_refuses_a_misshapen_tensor_naming_it(name, value):
    with pytest.raises(ValueError, match=name):
        RayBatchSource(**_source(**{name: value}))
    assert len(RayBatchSource(**_source(alpha=None))) == 4   # no alpha is allowed
    with pytest.raises(ValueError):
        RayBatchSource(**_source(**{k: torch.zeros((0,) + v.shape[1:]) for k, v in _source().items()
                                    if k != "model"}))


def test_from_scene_refuses_bad_view_indices_and_takes_the_first_and_last():
    scene = _two_camera_scene()
    for idx in ([], [0, 2], [-1]):
        with pytest.raises(InputError) as err:
            RayBatchSource.from_scene(scene, idx, _model())
        assert err.value.field == "views"
    assert len(RayBatchSource.from_scene(scene, [0, 1], _model())) == 2 * 24 * 32


def test_from_scene_keeps_alpha_only_for_straight_colour():
    # Catches: RayBatchSource.from_scene dropping the alpha of straight RGBA images (the trainer then cannot
    # composite the target onto each batch's background), or keeping it for images composited at load time.
    alpha = np.full((1, 24, 32), 0.25, np.float32)
    kw = dict(name="s", root=".", rgb=np.zeros((1, 24, 32, 3), np.float32), alpha=alpha, intrinsics=K,
              intrinsics_all=(K,), c2w=_c2w(), image_paths=("a.png",))
    straight = RayBatchSource.from_scene(Scene(**kw), [0], _model())
    assert straight.alpha is not None and torch.equal(straight.alpha, torch.full((24 * 32,), 0.25))
    composited = RayBatchSource.from_scene(Scene(**kw, background=(1.0, 1.0, 1.0)), [0], _model())
    assert composited.alpha is None
    assert math.isfinite(float(straight.far.max()))


def test_batches_draw_every_ray_uniformly():
    # Catches: an off-by-one in RayBatchSource.sample's index range (the last ray never drawn), a batch whose
    # colours are not its rays'.  3 rays, 3000 draws: each index about 1000 times (binomial std 26).
    o = torch.zeros(3, 3)
    rays = RayBatchSource(o, o + torch.tensor([0.0, 0.0, 1.0]), torch.rand(3, 3), torch.rand(3), torch.ones(3),
                          torch.full((3,), 2.0), _model())
    batch = rays.sample(3000, torch.Generator().manual_seed(0))
    counts = torch.bincount(batch["index"], minlength=3)
    assert counts.shape == (3,) and (counts > 850).all()
    assert torch.equal(batch["rgb"], rays.rgb[batch["index"]])
    assert torch.equal(batch["alpha"], rays.alpha[batch["index"]])
    again = rays.sample(3000, torch.Generator().manual_seed(0))
    assert torch.equal(again["index"], batch["index"])   # the generator decides the batch
