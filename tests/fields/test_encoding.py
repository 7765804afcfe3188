"""Tests of senerf/fields/encoding.py: spherical harmonics, positional encoding and its annealing weights."""

import math

import numpy as np
import pytest
import torch

from senerf.fields import anneal_weights, positional_encoding, sh_encoding
from senerf.fields.encoding import sh_encoding_reference


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


@pytest.mark.parametrize("degree", [0, 5, -1])
def test_sh_degree_outside_1_to_4_is_refused(degree):
    # degree 5 would give 25 columns of which 9 are never computed
    with pytest.raises(ValueError, match=f"degree: expected 1..4, got {degree}"):
        sh_encoding_reference(torch.zeros(2, 3), degree)
    assert [sh_encoding_reference(torch.zeros(2, 3), d).shape[1] for d in (1, 2, 3, 4)] == [1, 4, 9, 16]


@pytest.mark.parametrize("shape", [(5, 2), (5, 4), (5,), (1, 5, 3)])
@pytest.mark.parametrize("encode", [sh_encoding, sh_encoding_reference])
def test_sh_encoding_refuses_directions_that_are_not_n_by_3(encode, shape):
    with pytest.raises(ValueError, match=r"dirs: expected shape \(N, 3\)"):
        encode(torch.zeros(shape), 4)
    # +z: Y_00 = 1 / (2 sqrt(pi)) = 0.28209..., Y_1,0 = sqrt(3 / (4 pi)) z = 0.48860...
    out = encode(torch.tensor([[0.0, 0.0, 1.0]]), 2)
    torch.testing.assert_close(out, torch.tensor([[0.28209479177387814, 0.0, 0.48860251190291987, 0.0]]))


def test_positional_encoding_refuses_unbatched_input_and_misshapen_band_weights():
    with pytest.raises(ValueError, match=r"x: expected shape \(N, D\)"):
        positional_encoding(torch.zeros(3), 2)
    for weights in (torch.ones(3), torch.ones(1, 2)):
        with pytest.raises(ValueError, match=r"weights: expected shape \(2,\)"):
            positional_encoding(torch.zeros(1, 1), 2, weights=weights)
    # by hand, x = 0.25, bands pi x = pi/4 and 2 pi x = pi/2 weighted 1 and 0.5:
    # [x, sin(pi/4), cos(pi/4), 0.5 sin(pi/2), 0.5 cos(pi/2)] = [0.25, 0.7071, 0.7071, 0.5, 0]
    out = positional_encoding(torch.tensor([[0.25]], dtype=torch.float64), 2, weights=torch.tensor([1.0, 0.5]))
    r = 0.5 ** 0.5
    torch.testing.assert_close(out, torch.tensor([[0.25, r, r, 0.5, 0.0]], dtype=torch.float64))


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
