"""Ray-box bounds, ray bounds of camera_rays and camera z-depth against hand-worked geometry
(senerf/train/rays.py; mutation audit)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from senerf.geometry import Intrinsics, look_at
from senerf.train import ModelConfig, camera_rays, ray_aabb_bounds
from senerf.train.rays import per_view_intrinsics, ray_dist_to_z_depth

K = Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 24)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ray_aabb_bounds_negative_and_mixed_directions_by_hand(dtype):
    # Catches: the slab test without the per-axis min/max (t0 taken as the entry, t1 as the exit), which
    # only works for directions with positive components.  Box [-1, 1] x [-2, 2] x [-3, 3]:
    #  ray 0: o (0.5, 5, 0), d (0, -1, 0): y-slab t in [(2 - 5)/-1, (-2 - 5)/-1] = [3, 7].
    #  ray 1: o (4, 0, 1), d (-0.8, 0, -0.6): x in [(1 - 4)/-0.8, (-1 - 4)/-0.8] = [3.75, 6.25];
    #         z in [(3 - 1)/-0.6, (-3 - 1)/-0.6] = [-3.33, 6.67]; y unbounded -> [3.75, 6.25].
    #  ray 2: o (0, 0, 10), d (0, 0, 1): z-slab [-13, -7], behind it: near = min_near, far = near (empty).
    o = torch.tensor([[0.5, 5.0, 0.0], [4.0, 0.0, 1.0], [0.0, 0.0, 10.0]], dtype=dtype)
    d = torch.tensor([[0.0, -1.0, 0.0], [-0.8, 0.0, -0.6], [0.0, 0.0, 1.0]], dtype=dtype)
    near, far = ray_aabb_bounds(o, d, ((-1, -2, -3), (1, 2, 3)))
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    np.testing.assert_allclose(near[:2].numpy(), [3.0, 3.75], rtol=tol)
    np.testing.assert_allclose(far[:2].numpy(), [7.0, 6.25], rtol=tol)
    assert float(far[2]) == float(near[2])


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
    # Catches: any face- or sign-dependent guard (the old +1e-12 substitute for a zero component): mirroring
    # origins, directions and box through y = 0 must give the same bounds, here for rays that lie in faces,
    # graze edges and cross the box along and off the axes (directions with exact zeros, by construction).
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


def test_camera_inside_a_tiny_box_starts_at_a_box_relative_near():
    # Catches: camera_rays clamping near to an absolute 1e-3 (which would empty a 1e-2-wide scene's rays
    # near the camera) instead of min(1e-3, 1e-3 x the box's smallest side): box side 0.02 -> 2e-5.
    model = ModelConfig(aabb=((-0.01, -0.01, -0.01), (0.01, 0.01, 0.01)), resolution=8, multires=(1,),
                        n_features=4, occupancy_resolution=0)
    rays = camera_rays(K, np.eye(4)[None], model)
    np.testing.assert_allclose(rays["near"].numpy(), 2e-5, rtol=1e-6)
    assert (rays["far"] >= 0.01 - 1e-7).all()


def _ndc_model(near=0.5):
    return ModelConfig(ndc=True, ndc_near=near, aabb=((-1.5, -1.5, -1.0), (1.5, 1.5, 1.0)), resolution=8,
                       multires=(1,), n_features=4, occupancy_resolution=0)


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
    t_ndc = 1.0 - near / z_world
    dist = t_ndc * rays["ndc_len"]
    z = ray_dist_to_z_depth(dist, rays, _ndc_model(near))
    np.testing.assert_allclose(z.numpy(), z_world - 0.3, rtol=1e-4)


def test_world_ray_dist_to_z_depth_is_the_projection_on_the_optical_axis():
    # Catches: ray_dist divided by z_per_dist instead of multiplied.  For the point p = o + s d (unit d) the
    # camera z-depth is (p - o) . axis = s (d . axis), axis = the camera's +z column of c2w.
    c2w = look_at(np.array([3.0, -2.0, 1.5]), np.zeros(3))
    model = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), resolution=8, multires=(1,), n_features=4,
                        occupancy_resolution=0)
    rays = camera_rays(K, c2w[None], model)
    s = 2.5
    expect = s * (rays["dirs"].double().numpy() @ c2w[:3, 2])
    z = ray_dist_to_z_depth(torch.full((rays["dirs"].shape[0],), s), rays, model)
    assert expect.min() < 0.95 * s                  # off-axis rays: z-depth and distance really differ
    np.testing.assert_allclose(z.numpy(), expect, rtol=1e-5)


def test_per_view_intrinsics_refuses_mixed_image_sizes():
    # Catches: per_view_intrinsics without its image-size check (images of one batch must share H x W).
    other = Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 25)
    assert per_view_intrinsics(K, 2) == (K, K)
    with pytest.raises(ValueError, match="image sizes differ"):
        per_view_intrinsics([K, other], 2)


def test_from_scene_keeps_alpha_only_for_straight_colour():
    # Catches: RayBatchSource.from_scene dropping the alpha of straight RGBA images (the trainer then cannot
    # composite the target onto each batch's background), or keeping it for images composited at load time.
    from senerf.data import Scene
    from senerf.train import RayBatchSource

    alpha = np.full((1, 24, 32), 0.25, np.float32)
    model = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), resolution=8, multires=(1,), n_features=4,
                        occupancy_resolution=0)
    c2w = look_at(np.array([3.0, -2.0, 1.5]), np.zeros(3))[None]
    kw = dict(name="s", root=".", rgb=np.zeros((1, 24, 32, 3), np.float32), alpha=alpha, intrinsics=K,
              intrinsics_all=(K,), c2w=c2w, image_paths=("a.png",))
    straight = RayBatchSource.from_scene(Scene(**kw), [0], model)
    assert straight.alpha is not None and torch.equal(straight.alpha, torch.full((24 * 32,), 0.25))
    composited = RayBatchSource.from_scene(Scene(**kw, background=(1.0, 1.0, 1.0)), [0], model)
    assert composited.alpha is None
    assert math.isfinite(float(straight.far.max()))


def test_batches_draw_every_ray_uniformly():
    # Catches: an off-by-one in RayBatchSource.sample's index range (the last ray never drawn).  3 rays,
    # 3000 draws: each index about 1000 times (binomial std 26).
    from senerf.train import RayBatchSource

    model = ModelConfig(aabb=((-1, -1, -1), (1, 1, 1)), resolution=8, multires=(1,), n_features=4)
    o = torch.zeros(3, 3)
    rays = RayBatchSource(o, o + torch.tensor([0.0, 0.0, 1.0]), torch.rand(3, 3), None, torch.ones(3),
                          torch.full((3,), 2.0), model)
    batch = rays.sample(3000, torch.Generator().manual_seed(0))
    counts = torch.bincount(batch["index"], minlength=3)
    assert counts.shape == (3,) and (counts > 850).all()
    assert torch.equal(batch["rgb"], rays.rgb[batch["index"]])
