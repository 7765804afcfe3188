"""senerf/train/rays.py and ModelConfig's model frame: float32 rays keep their precision far from the origin."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from senerf.fields import render_rays
from senerf.geometry import Intrinsics, look_at
from senerf.train import ModelConfig, build_field, camera_rays

K = Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 24)
BOX = ((-1.2, -1.0, -0.8), (1.2, 1.0, 0.8))


def _c2w(offset) -> np.ndarray:
    offset = np.asarray(offset, dtype=np.float64)
    return look_at(np.array([3.0, -2.0, 1.5]) + offset, offset, np.array([0.0, 0.0, 1.0]))[None]


def _model(offset) -> ModelConfig:
    box = np.asarray(BOX) + np.asarray(offset, dtype=np.float64)
    return ModelConfig(aabb=tuple(map(tuple, box)), resolution=8, multires=(1,), n_features=4, n_samples=16,
                       occupancy_resolution=0)


def _render(field, rays, model) -> torch.Tensor:
    """``(R, 3)`` colours of ``rays`` (from :func:`camera_rays`), deterministic samples, white background."""
    with torch.no_grad():
        return render_rays(field, rays["origins"], rays["dirs"], rays["near"], rays["far"], model.n_samples, None,
                           torch.ones(3), randomized=False)["rgb"]


def test_frame_origin_is_zero_near_the_origin_and_absorbs_far_offsets():
    assert _model((0, 0, 0)).frame_origin == (0.0, 0.0, 0.0)
    assert _model((1.1, -0.9, 0.7)).frame_origin == (0.0, 0.0, 0.0)   # contains the origin: world frame
    extent = np.asarray(BOX)[1] - np.asarray(BOX)[0]
    for offset in [(1e6, -3e5, 2e4), (-7.3e7, 0.0, 1e-3), (2.5, -2.5, 1.7)]:
        m = _model(offset)
        local = np.asarray(m.field_aabb)
        # the model-frame box is the same size and its centre within one extent of the origin per axis
        np.testing.assert_allclose(local[1] - local[0], extent, atol=1e-6)
        assert np.all(np.abs(local.mean(axis=0)) < extent)
        np.testing.assert_allclose(np.asarray(m.frame_origin) + local, np.asarray(m.aabb), rtol=0, atol=1e-6)
    assert ModelConfig(ndc=True, aabb=((-1.5, -1.5, -1), (1.5, 1.5, 1))).frame_origin == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("offset", [(1e6, 1e6, 1e6), (-3e7, 4e5, 2e6)])
def test_rays_of_a_scene_far_from_the_origin_match_the_same_scene_at_the_origin(offset):
    """Translate the cameras and the box together: the sample points in box coordinates are the same as at
    the origin to float32 rounding of small numbers (before the model frame, a float32 origin at 1e6 is
    only known to 0.06 units, 2.5 % of this box)."""
    near_rays = camera_rays(K, _c2w((0, 0, 0)), _model((0, 0, 0)))
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


def test_a_world_frame_checkpoint_loads_into_the_model_frame():
    """A checkpoint written before the model frame holds the box in world coordinates; its learned values
    are indexed by box-normalised coordinates, so loading it (keeping the module's box) renders as the field
    that wrote it, where a plain ``load_state_dict`` would put the world box back and miss every point."""
    from senerf.train import load_state_keeping_box, make_occupancy

    offset = (4e5, 0.0, -2e5)
    model = _model(offset)
    writer = build_field(model, seed=0)
    grid = make_occupancy(dataclasses.replace(model, occupancy_resolution=8), "cpu")
    old_field, old_grid = writer.state_dict(), grid.state_dict()
    world_box = torch.as_tensor(model.aabb, dtype=old_field["aabb"].dtype)
    old_field["aabb"], old_grid["aabb"] = world_box.clone(), world_box.clone()

    reader = build_field(model, seed=1)
    load_state_keeping_box(reader, old_field)
    reader_grid = make_occupancy(dataclasses.replace(model, occupancy_resolution=8), "cpu")
    load_state_keeping_box(reader_grid, old_grid)
    torch.testing.assert_close(reader.aabb, writer.aabb)
    torch.testing.assert_close(reader_grid.aabb, grid.aabb)
    plain = build_field(model, seed=1)
    plain.load_state_dict(old_field)
    a, b, c = (_render(f, camera_rays(K, _c2w(offset), model), model) for f in (writer, reader, plain))
    torch.testing.assert_close(b, a, rtol=0, atol=0)
    assert (c - a).abs().max() > 0.01  # the world box in the model frame: the points fall outside it


def _two_camera_scene():
    from senerf.data import Scene

    k0, k1 = Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 24), Intrinsics(55.0, 50.0, 15.0, 13.0, 32, 24)
    c2w = np.concatenate([_c2w((0, 0, 0)), look_at([-2.5, -2.0, 1.0], [0.0, 0.0, 0.0])[None]])
    rgb = np.zeros((2, 24, 32, 3), np.float32)
    return Scene(name="two", root=".", rgb=rgb, alpha=None, intrinsics=k0, intrinsics_all=(k0, k1), c2w=c2w,
                 image_paths=("a.png", "b.png"))


def test_training_rays_use_each_views_own_intrinsics():
    # Per-frame intrinsics (instant-ngp/nerfstudio frames may carry their own fl_x): every training ray of
    # view i must pass through its pixel centre under view i's K.  Golden: senerf.geometry.project, a
    # separately tested function.  Before, every view's rays were cast with image 0's K (so at a79fcfc).
    from senerf.geometry import project
    from senerf.train import RayBatchSource

    scene = _two_camera_scene()
    model = _model((0, 0, 0))
    rays = RayBatchSource.from_scene(scene, [1, 0], model)
    h, w = 24, 32
    jj, ii = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    centres = np.stack([ii, jj], axis=-1).reshape(-1, 2)
    pts = (rays.origins + 2.0 * rays.dirs).double().numpy().reshape(2, h * w, 3)
    for slot, view in enumerate([1, 0]):
        uv, _, ok = project(pts[slot], scene.intrinsics_all[view], scene.c2w[view])
        assert ok.all()
        np.testing.assert_allclose(uv, centres, atol=1e-4)


def test_render_views_and_camera_rays_take_one_intrinsics_per_camera():
    from senerf.train import render_views

    scene = _two_camera_scene()
    model = _model((0, 0, 0))
    field = build_field(model, seed=0)
    both = render_views(field, model, scene.intrinsics_all, scene.c2w)
    for i in range(2):
        one = render_views(field, model, scene.intrinsics_all[i], scene.c2w[i])
        for key in ("rgb", "z_depth", "acc"):
            np.testing.assert_array_equal(both[key][i], one[key][0])
    assert not np.array_equal(both["rgb"][1], render_views(field, model, scene.intrinsics, scene.c2w[1])["rgb"][0])
    ndc = dataclasses.replace(model, ndc=True, aabb=((-1.5, -1.5, -1.0), (1.5, 1.5, 1.0)), ndc_near=1.0)
    with pytest.raises(ValueError, match="NDC rays need one shared Intrinsics"):
        camera_rays(scene.intrinsics_all, scene.c2w, ndc)
    with pytest.raises(ValueError, match="sequence of 2"):
        camera_rays(scene.intrinsics_all[:1], scene.c2w, model)
