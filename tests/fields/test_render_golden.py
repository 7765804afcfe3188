"""Hand-computed golden values for the volume renderer, ray marching and stratified sampling (mutation audit).

Every expected value below is worked out by hand (arithmetic in the comments) or by a different method, not
by calling the code under test."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from senerf.fields import RadianceField, render_image, render_rays, stratified_bins, volume_render


class ConstantField(RadianceField):
    """Density ``value`` and colour ``rgb`` everywhere (no parameters)."""

    def __init__(self, value=0.5, rgb=(0.2, 0.4, 0.6)):
        super().__init__()
        self.value = value
        self.colour = torch.tensor(rgb)

    def density(self, xyz):
        return torch.full((xyz.shape[0],), self.value, dtype=xyz.dtype)

    def forward(self, xyz, dirs):
        return self.density(xyz), self.colour.to(xyz.dtype).expand(xyz.shape[0], 3)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_two_samples_by_hand(dtype):
    # Catches: inclusive instead of exclusive transmittance, the last interval not ending at t_far (1e10 or
    # 0), the background weighted by acc (or unweighted), ray_dist not normalised by acc.
    # t = (1, 1.5), t_far = 2.5 -> deltas (0.5, 1.0); sigma (2, 1) -> tau (1, 1).
    # w0 = 1 - e^-1 = 0.6321206, w1 = e^-1 (1 - e^-1) = 0.2325442, acc = 1 - e^-2 = 0.8646647.
    # rgb (1,0,0), (0,1,0); bg (0.2, 0.4, 0.6): colour = (w0, w1, 0) + (1 - acc) bg.
    # ray_dist = (1 w0 + 1.5 w1) / acc = 0.9809369 / 0.8646647 = 1.1344711.
    e1 = math.exp(-1.0)
    w0, w1 = 1 - e1, e1 * (1 - e1)
    acc = 1 - math.exp(-2.0)
    bg = (0.2, 0.4, 0.6)
    sigma = torch.tensor([[2.0, 1.0]], dtype=dtype)
    rgb = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]], dtype=dtype)
    t = torch.tensor([[1.0, 1.5]], dtype=dtype)
    out = volume_render(sigma, rgb, t, torch.tensor([2.5], dtype=dtype), torch.tensor(bg, dtype=dtype))
    tol = 1e-6 if dtype == torch.float32 else 1e-14
    np.testing.assert_allclose(out["weights"][0].numpy(), [w0, w1], rtol=tol)
    np.testing.assert_allclose(out["acc"].numpy(), [acc], rtol=tol)
    np.testing.assert_allclose(out["rgb"][0].numpy(),
                               [w0 + (1 - acc) * bg[0], w1 + (1 - acc) * bg[1], (1 - acc) * bg[2]], rtol=tol)
    np.testing.assert_allclose(out["ray_dist"].numpy(), [(w0 + 1.5 * w1) / acc], rtol=tol)


def test_single_sample_last_interval_is_t_far_minus_t():
    # Catches: the last delta as 1e10 (alpha 1) or 0 (alpha 0) instead of t_far - t.
    # t = 2, t_far = 3: delta 1, sigma 0.5 -> alpha = 1 - e^-0.5 = 0.3934693.
    out = volume_render(torch.tensor([[0.5]], dtype=torch.float64), torch.ones(1, 1, 3, dtype=torch.float64),
                        torch.tensor([[2.0]], dtype=torch.float64), torch.tensor([3.0], dtype=torch.float64))
    np.testing.assert_allclose(out["acc"].numpy(), [1 - math.exp(-0.5)], rtol=1e-14)


def test_render_rays_bin_centres_constant_density_by_hand():
    # Catches in render_rays/stratified_bins: the last interval not ending at `far`, bins at edges instead of
    # centres when randomized=False, a step of (far - near) / (n - 1).
    # near 1, far 3, 4 bins of 0.5: centres t = 1.25, 1.75, 2.25, 2.75; intervals 0.5, 0.5, 0.5 and
    # far - 2.75 = 0.25: optical depth sigma * 1.75 = 0.5 * 1.75 = 0.875, acc = 1 - e^-0.875 = 0.5831457.
    o = torch.zeros(2, 3, dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    out = render_rays(ConstantField(0.5), o, d, torch.full((2,), 1.0, dtype=torch.float64),
                      torch.full((2,), 3.0, dtype=torch.float64), 4, None, torch.zeros(3, dtype=torch.float64),
                      randomized=False)
    np.testing.assert_allclose(out["t"][0].numpy(), [1.25, 1.75, 2.25, 2.75], rtol=1e-15)
    np.testing.assert_allclose(out["acc"].numpy(), 1 - math.exp(-0.875), rtol=1e-14)
    # black background: colour = acc * (0.2, 0.4, 0.6)
    np.testing.assert_allclose(out["rgb"][1].numpy(), (1 - math.exp(-0.875)) * np.array([0.2, 0.4, 0.6]),
                               rtol=1e-6)


@pytest.mark.parametrize("fn", ["volume_render", "volume_render_reference"])
def test_background_none_is_black(fn):
    # Catches: background=None not meaning black, as volume_render's docstring says.  Same case as
    # test_single_sample_last_interval_is_t_far_minus_t with colour (1, 1, 1): acc = 1 - e^-0.5 = 0.3934693,
    # so the composited colour on black is acc itself.  (Found by a mutation audit: the result was
    # acc (2 - acc) = 0.6321206, the colour composited onto itself, from ef724e4 to 38bd6c3.)
    import senerf.fields as fields

    out = getattr(fields, fn)(torch.tensor([[0.5]], dtype=torch.float64), torch.ones(1, 1, 3, dtype=torch.float64),
                              torch.tensor([[2.0]], dtype=torch.float64), torch.tensor([3.0], dtype=torch.float64))
    np.testing.assert_allclose(out["rgb"][0].numpy(), [1 - math.exp(-0.5)] * 3, rtol=1e-14)


def test_render_image_passes_randomized_and_generator_through():
    # Catches: render_image ignoring `randomized` (always bin centres): with randomized=True and a seeded
    # generator it must equal one render_rays call with a generator of the same seed (one chunk).
    field = ConstantField(0.8)
    o = torch.zeros(2, 3, 3)
    d = torch.nn.functional.normalize(torch.rand(2, 3, 3, generator=torch.Generator().manual_seed(0)) + 1, dim=-1)
    img = render_image(field, o, d, 0.5, 2.5, 8, randomized=True, generator=torch.Generator().manual_seed(4))
    ref = render_rays(field, o.view(6, 3), d.view(6, 3), torch.full((6,), 0.5), torch.full((6,), 2.5), 8,
                      torch.Generator().manual_seed(4), None, randomized=True)
    np.testing.assert_array_equal(img["ray_dist"].reshape(-1), ref["ray_dist"].numpy())
    centred = render_image(field, o, d, 0.5, 2.5, 8)
    assert not np.allclose(img["ray_dist"], centred["ray_dist"])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_stratified_jitter_is_uniform_and_per_ray(dtype):
    # Catches: jitter over half a bin (u * 0.5, mean 0.25), one jitter shared by every ray of the batch.
    # 4000 rays x 8 bins of U[0, 1) offsets: the mean offset is 0.5 +- 0.0016 (std 1/sqrt(12 * 32000)).
    gen = torch.Generator().manual_seed(0)
    near, far = torch.full((4000,), 1.0, dtype=dtype), torch.full((4000,), 3.0, dtype=dtype)
    t = stratified_bins(near, far, 8, gen)
    u = (t - 1.0) / 0.25 - torch.arange(8, dtype=dtype)        # offset inside each bin
    assert float(u.min()) >= -1e-5 and float(u.max()) <= 1 + 1e-5
    assert abs(float(u.mean()) - 0.5) < 0.01
    assert float(u.max()) > 0.99 and float(u.min()) < 0.01
    assert not torch.equal(t[0], t[1])                           # rays draw their own offsets
