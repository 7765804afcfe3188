import math

import numpy as np
import pytest
import torch

from senerf.fields import NeRFField, anneal_weights, positional_encoding, sh_encoding


def test_sh_orthonormal_by_exact_quadrature():
    # Gauss-Legendre in cos(theta) (8 nodes: exact to polynomial degree 15) x 16 uniform phi (exact for
    # trigonometric degree < 16) integrates products of degree <= 6 exactly: the Gram matrix must be I.
    x, wx = np.polynomial.legendre.leggauss(8)
    phi = np.arange(16) * 2 * np.pi / 16
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = torch.tensor(np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3))
    w = torch.tensor((wx[:, None] * np.full(16, 2 * np.pi / 16)[None, :]).reshape(-1))
    y = sh_encoding(dirs, 4)
    gram = (y * w[:, None]).T @ y
    np.testing.assert_allclose(gram.numpy(), np.eye(16), atol=1e-12)


def test_sh_known_values_on_z_axis():
    # at +z only m = 0 terms survive: Y_l0 = sqrt((2l + 1) / (4 pi))
    y = sh_encoding(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), 4)[0].numpy()
    expect = np.zeros(16)
    for l_, idx in ((0, 0), (1, 2), (2, 6), (3, 12)):
        expect[idx] = math.sqrt((2 * l_ + 1) / (4 * math.pi))
    np.testing.assert_allclose(y, expect, atol=1e-12)
    assert sh_encoding(torch.zeros(5, 3), 2).shape == (5, 4)


def test_anneal_weights_boundaries():
    m = 6
    assert torch.equal(anneal_weights(0.0, m), torch.zeros(m))
    assert torch.equal(anneal_weights(m, m), torch.ones(m))
    w = anneal_weights(3.0, m, dtype=torch.float64)      # eta = j: band j off, bands < j fully on
    np.testing.assert_allclose(w.numpy(), [1, 1, 1, 0, 0, 0], atol=1e-15)
    w = anneal_weights(2.5, m, dtype=torch.float64)      # half-way into band 2: (1 - cos(pi/2)) / 2 = 0.5
    np.testing.assert_allclose(w.numpy(), [1, 1, 0.5, 0, 0, 0], atol=1e-15)
    w = anneal_weights(1.25, m, dtype=torch.float64)     # (1 - cos(pi/4)) / 2 = 0.1464466
    np.testing.assert_allclose(w[1].item(), (1 - math.sqrt(0.5)) / 2, atol=1e-15)


def test_positional_encoding_values_and_band_weights():
    x = torch.tensor([[0.25, -0.5]], dtype=torch.float64)
    enc = positional_encoding(x, 2)
    # [x, sin(pi x), cos(pi x), sin(2 pi x), cos(2 pi x)], each over both dims
    expect = [0.25, -0.5, math.sin(math.pi / 4), math.sin(-math.pi / 2), math.cos(math.pi / 4), math.cos(-math.pi / 2),
              math.sin(math.pi / 2), math.sin(-math.pi), math.cos(math.pi / 2), math.cos(-math.pi)]
    np.testing.assert_allclose(enc[0].numpy(), expect, atol=1e-12)
    enc_w = positional_encoding(x, 2, torch.tensor([1.0, 0.0], dtype=torch.float64))
    np.testing.assert_allclose(enc_w[0, 6:].numpy(), 0.0)
    np.testing.assert_allclose(enc_w[0, :6].numpy(), expect[:6], atol=1e-12)


def test_nerf_field_progress_schedule():
    f = NeRFField(aabb=[[-1] * 3, [1] * 3], n_freqs=8, hidden=16, n_layers=2)
    assert torch.equal(f.set_progress(0, 400), torch.zeros(8))            # eta = 0
    assert torch.equal(f.set_progress(100, 400), torch.ones(8))           # step = N = total / 4: eta = m
    w = f.set_progress(25, 400)                                            # eta = 8 * 25 / 100 = 2
    np.testing.assert_allclose(w.numpy(), [1, 1, 0, 0, 0, 0, 0, 0], atol=1e-7)
    g = NeRFField(n_freqs=4, hidden=16, n_layers=2, anneal_steps=10)
    np.testing.assert_allclose(g.set_progress(5).numpy(), [1, 1, 0, 0], atol=1e-7)
    with pytest.raises(ValueError):
        NeRFField(n_freqs=4, hidden=8, n_layers=2).set_progress(3)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sh_compiled_kernel_matches_reference(dtype):
    from senerf.fields.ckernel import fused_sh4
    from senerf.fields.encoding import sh_encoding_reference

    gen = torch.Generator().manual_seed(3)
    dirs = torch.nn.functional.normalize(torch.randn(5003, 3, generator=gen, dtype=torch.float64), dim=-1).to(dtype)
    ref = sh_encoding_reference(dirs, 4)
    fast = fused_sh4(dirs)
    if fast is None:
        pytest.skip("compiled kernel unavailable here (no C compiler)")
    assert fast.shape == (5003, 16) and fast.dtype == dtype
    tol = 1e-6 if dtype == torch.float32 else 1e-14
    torch.testing.assert_close(fast, ref, atol=tol, rtol=0)
    torch.testing.assert_close(sh_encoding(dirs, 4), ref, atol=tol, rtol=0)
    # directions that need a gradient go through the differentiable reference
    d = dirs[:7].clone().requires_grad_(True)
    assert fused_sh4(d) is None
    sh_encoding(d, 4).sum().backward()
    assert d.grad is not None and torch.isfinite(d.grad).all()
