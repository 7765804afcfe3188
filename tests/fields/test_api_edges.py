"""Input checks at the edges of senerf.fields' rendering and sampling: each bad argument is refused with an error
naming it, and each check's boundary value is accepted (so an off-by-one in the comparison fails a test too)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from senerf.fields import ndc_rays, render_image, render_rays, stratified_bins, volume_render, volume_render_reference

from ._fields_helpers import BallField

R, S = 3, 4


def _composite(**replace) -> dict:
    """A valid volume_render call of R = 3 rays with S = 4 samples."""
    t = torch.linspace(1.0, 2.0, S).expand(R, S)
    args = dict(sigma=torch.ones(R, S), rgb=torch.zeros(R, S, 3), t=t, t_far=torch.full((R,), 2.5))
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value, message", [
    ("sigma", torch.ones(R * S), "sigma: expected shape (R, S), got (12,)"),
    ("sigma", torch.ones(R, S, 1), "sigma: expected shape (R, S), got (3, 4, 1)"),
    ("rgb", torch.zeros(R, S, 4), "rgb: expected shape (3, 4, 3), got (3, 4, 4)"),
    ("t", torch.zeros(R, S + 1), "t: expected shape (3, 4), got (3, 5)"),
    ("t_far", torch.ones(R, 1), "t_far: expected shape (3,), got (3, 1)"),
    ("t_far", torch.ones(R + 1), "t_far: expected shape (3,), got (4,)"),
])
@pytest.mark.parametrize("composite", [volume_render, volume_render_reference])
def test_volume_render_refuses_each_misshapen_input(composite, name, value, message):
    # Catches: one of render._check's four shape checks deleted (sigma's ndim, rgb, t, t_far), in either renderer.
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        composite(**_composite(**{name: value}))
    assert composite(**_composite())["acc"].shape == (R,)


def _march(**replace) -> dict:
    """A valid render_rays call: R = 3 rays along +z through a ball at the origin."""
    args = dict(rays_o=torch.tensor([[0.0, 0.0, -2.0]] * R), rays_d=torch.tensor([[0.0, 0.0, 1.0]] * R),
                near=torch.ones(R), far=torch.full((R,), 3.0))
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value, message", [
    ("rays_o", torch.zeros(R * 3), "rays_o/rays_d: expected equal shapes (R, 3), got (9,), (3, 3)"),
    ("rays_o", torch.zeros(R, 2), "rays_o/rays_d: expected equal shapes (R, 3), got (3, 2), (3, 3)"),
    ("rays_d", torch.ones(R + 1, 3), "rays_o/rays_d: expected equal shapes (R, 3), got (3, 3), (4, 3)"),
    ("near", torch.ones(R + 1), "near/far: expected shape (3,), got (4,), (3,)"),
    ("far", torch.ones(R, 1), "near/far: expected shape (3,), got (3,), (3, 1)"),
])
def test_render_rays_refuses_each_misshapen_input(name, value, message):
    # Catches: render_rays' rays_o/rays_d or near/far shape check deleted, or one of its conditions dropped.
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        render_rays(BallField(), **_march(**{name: value}), n_samples=S, randomized=False)
    assert render_rays(BallField(), **_march(), n_samples=S, randomized=False)["acc"].shape == (R,)


@pytest.mark.parametrize("o_shape, d_shape", [((4, 3), (4, 3)), ((2, 2, 2), (2, 2, 2)), ((2, 2, 3), (2, 1, 3))])
def test_render_image_refuses_origins_and_dirs_that_are_not_h_w_3(o_shape, d_shape):
    # Catches: render_image's origins/dirs shape check deleted, or one of its three conditions dropped.
    with pytest.raises(ValueError, match="^" + re.escape(f"origins/dirs: expected equal shapes (H, W, 3), got "
                                                         f"{o_shape}, {d_shape}") + "$"):
        render_image(BallField(), np.zeros(o_shape), np.ones(d_shape), 1.0, 3.0, S)
    o, d = np.array([[[0.0, 0.0, -2.0]]]), np.array([[[0.0, 0.0, 1.0]]])
    assert render_image(BallField(), o, d, 1.0, 3.0, S)["acc"].shape == (1, 1)


@pytest.mark.parametrize("near_shape, far_shape", [((R, 1), (R, 1)), ((R,), (R + 1,)), ((), ())])
def test_stratified_bins_refuses_near_and_far_that_are_not_equal_r(near_shape, far_shape):
    # Catches: stratified_bins' ``near.ndim != 1`` or ``far.shape != near.shape`` condition dropped.
    with pytest.raises(ValueError, match="^" + re.escape(f"near/far: expected equal shapes (R,), got {near_shape}, "
                                                         f"{far_shape}") + "$"):
        stratified_bins(torch.zeros(near_shape), torch.ones(far_shape), S, randomized=False)


@pytest.mark.parametrize("n_bins", [0, -1])
def test_stratified_bins_refuses_fewer_than_one_bin_and_accepts_one(n_bins):
    # Catches: stratified_bins' ``n_bins < 1`` check deleted or made ``n_bins < 2`` (one bin is its centre).
    with pytest.raises(ValueError, match=f"^n_bins: expected >= 1, got {n_bins}$"):
        stratified_bins(torch.zeros(R), torch.ones(R), n_bins, randomized=False)
    torch.testing.assert_close(stratified_bins(torch.zeros(R), torch.full((R,), 2.0), 1, randomized=False),
                               torch.ones(R, 1))


@pytest.mark.parametrize("near", [0.0, -1.0])
def test_ndc_rays_refuses_a_near_plane_at_or_behind_the_camera(near):
    # Catches: ndc_rays' ``near <= 0`` check deleted or made ``near < 0`` (near = 0 maps every ray to z' = 1).
    o, d = torch.zeros(2, 3), torch.tensor([[0.0, 0.0, 1.0]] * 2)
    with pytest.raises(ValueError, match=f"^near: expected > 0, got {near}$"):
        ndc_rays(o, d, 2.0, 2.0, 4.0, 4.0, near=near)
    o_ndc, _ = ndc_rays(o, d, 2.0, 2.0, 4.0, 4.0, near=1e-3)
    torch.testing.assert_close(o_ndc[:, 2], torch.full((2,), -1.0))   # the origin moved to z = near: z' = -1
