"""Tests of senerf/fields/kplanes.py: the K-Planes field against grid_sample, its backends and regulariser."""

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from senerf.fields import KPlanesField, RadianceField
from senerf.fields.ckernel import fused_plane_features, load_kernel
from senerf.fields.interp import plane_interp, plane_interp_reference, plane_layout

RES = (5, 9, 16)


def _table_and_planes(dtype, gen, nf=3):
    offs, rows = plane_layout(RES)
    table = torch.rand(rows, nf, generator=gen, dtype=dtype)
    return table, offs


def _planes_of(table, offs):
    out = []
    for s, r in enumerate(RES):
        for p in range(3):
            o = offs[3 * s + p]
            out.append(table[o:o + r * r].view(r, r, -1).permute(2, 0, 1))
    return out


def _points(gen, dtype, n=300):
    u = torch.rand(n, 3, generator=gen, dtype=dtype) * 2 - 1
    u[:10] = torch.tensor([-1.0, 1.0, 0.0], dtype=dtype)     # exactly on the border
    u[10:20, 1] = 1.0
    return u


def test_gather_path_equals_grid_sample_values_and_gradients_float64():
    gen = torch.Generator().manual_seed(0)
    table, offs = _table_and_planes(torch.float64, gen)
    table.requires_grad_()
    u = _points(gen, torch.float64).requires_grad_()
    fast = plane_interp(table, u, RES, offs)
    ref = plane_interp_reference(_planes_of(table, offs), u)
    torch.testing.assert_close(fast, ref, rtol=1e-12, atol=1e-12)
    g = torch.randn(fast.shape, generator=gen, dtype=torch.float64)
    gt_f, gu_f = torch.autograd.grad(fast, (table, u), g)
    gt_r, gu_r = torch.autograd.grad(ref, (table, u), g)
    torch.testing.assert_close(gt_f, gt_r, rtol=1e-10, atol=1e-12)
    inner = (u.detach().abs() < 1).all(-1)   # at the border grid_sample's one-sided gradient convention differs
    torch.testing.assert_close(gu_f[inner], gu_r[inner], rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_fused_kernel_equals_grid_sample(dtype):
    if load_kernel(dtype) is None:
        pytest.skip("no C compiler: the fused kernel is unavailable (the gather path is used instead)")
    gen = torch.Generator().manual_seed(1)
    table, offs = _table_and_planes(dtype, gen, nf=5)
    table.requires_grad_()
    u = _points(gen, dtype)
    fused = fused_plane_features(table, u, RES, offs)
    ref = plane_interp_reference(_planes_of(table, offs), u)
    ref = (ref[:, :, 0] * ref[:, :, 1] * ref[:, :, 2]).reshape(u.shape[0], -1)
    tol = dict(rtol=1e-12, atol=1e-13) if dtype == torch.float64 else dict(rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(fused, ref, **tol)
    g = torch.randn(fused.shape, generator=gen, dtype=dtype)
    torch.testing.assert_close(torch.autograd.grad(fused, table, g)[0], torch.autograd.grad(ref, table, g)[0], **tol)


def test_fused_kernel_refuses_points_off_the_cpu(monkeypatch):
    """The C kernel reads raw host pointers: a CPU table with points on another device (``meta`` stands in
    for CUDA here) must fall back (``None``) before any kernel is loaded or called."""
    import senerf.fields.ckernel as ck

    def no_kernel(*args, **kwargs):
        raise AssertionError("the compiled CPU kernel was reached with points off the CPU")

    monkeypatch.setattr(ck, "load_kernel", no_kernel)
    gen = torch.Generator().manual_seed(2)
    table, offs = _table_and_planes(torch.float32, gen)
    u_meta = torch.empty(7, 3, device="meta")
    assert fused_plane_features(table, u_meta, RES, offs) is None
    assert fused_plane_features(table.to("meta"), _points(gen, torch.float32), RES, offs) is None


def _field(backend="auto", **kw):
    return KPlanesField([[-1.0, -2.0, -1.0], [1.0, 2.0, 3.0]], resolution=6, n_features=4, multires=(1, 2),
                        generator=torch.Generator().manual_seed(0), backend=backend, **kw)


def test_backends_agree_on_outputs_and_parameter_gradients():
    gen = torch.Generator().manual_seed(2)
    xyz = torch.rand(500, 3, generator=gen) * torch.tensor([2.4, 4.4, 4.4]) + torch.tensor([-1.2, -2.2, -1.2])
    dirs = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=-1)
    outs = {}
    for backend in ("auto", "gather", "grid_sample"):
        f = _field(backend)
        sigma, rgb = f(xyz, dirs)
        (sigma.sum() + rgb.square().sum()).backward()
        outs[backend] = (sigma.detach(), rgb.detach(), [p.grad.clone() for p in f.parameters()])
    for backend in ("auto", "gather"):
        torch.testing.assert_close(outs[backend][0], outs["grid_sample"][0], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(outs[backend][1], outs["grid_sample"][1], rtol=1e-5, atol=1e-6)
        for a, b in zip(outs[backend][2], outs["grid_sample"][2]):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_field_contract_outside_zero_and_view_switch():
    f = _field()
    assert isinstance(f, RadianceField)
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.99, 1.9, 2.9], [1.01, 0.0, 0.0], [0.0, -2.5, 0.0], [0.0, 0.0, 3.2]])
    d = torch.nn.functional.normalize(torch.ones(5, 3), dim=-1)
    sigma, rgb = f(pts, d)
    assert sigma.shape == (5,) and rgb.shape == (5, 3)
    assert (sigma[:2] > 0).all() and torch.equal(sigma[2:], torch.zeros(3))
    assert ((rgb >= 0) & (rgb <= 1)).all()
    torch.testing.assert_close(f.density(pts), sigma)
    # view dependence: directions change the colour only when view_dependent
    d2 = -d
    assert not torch.allclose(f(pts, d2)[1], rgb)
    g = _field(view_dependent=False)
    torch.testing.assert_close(g(pts, d)[1], g(pts, d2)[1], rtol=0, atol=0)
    with pytest.raises(ValueError):
        f.density(torch.zeros(4, 2))


def test_init_is_seeded_and_uniform_range():
    a, b = _field(), _field()
    for p, q in zip(a.parameters(), b.parameters()):
        assert torch.equal(p, q)
    c = KPlanesField([[-1] * 3, [1] * 3], resolution=6, n_features=4, generator=torch.Generator().manual_seed(1))
    assert not torch.equal(a.table, c.table)
    assert float(a.table.detach().min()) >= 0.1 and float(a.table.detach().max()) <= 0.5
    assert a.table.std() > 0.1  # spread over (0.1, 0.5): U(0.1, 0.5) has std 0.115


def test_plane_tv_regularizer():
    f = _field()
    with torch.no_grad():
        f.table.fill_(0.3)
    assert float(f.regularizer().detach()) == 0.0
    with torch.no_grad():
        # a single texel bump of height h in plane (scale 0, xy) changes 2 differences per axis; each axis
        # of a 6x6 plane has 5 * 6 * 4 differences (features 4): TV = 2 * (2 h^2 / 120) / n_scales(2)
        f.plane(0, 0)[2, 3, 0] += 0.5
    np.testing.assert_allclose(float(f.regularizer().detach()), 2 * (2 * 0.25 / 120) / 2, rtol=1e-6)
    f.regularizer().backward()
    assert f.table.grad.abs().sum() > 0


def test_internal_chunking_is_invisible():
    gen = torch.Generator().manual_seed(5)
    xyz = torch.rand(300, 3, generator=gen) * 2 - 1
    dirs = torch.nn.functional.normalize(torch.randn(300, 3, generator=gen), dim=-1)
    res = []
    for chunk in (64, 10_000):
        f = _field(chunk=chunk)
        sigma, rgb = f(xyz, dirs)
        (sigma.sum() + rgb.sum()).backward()
        res.append((sigma.detach(), rgb.detach(), f.density(xyz).detach(), [p.grad for p in f.parameters()]))
    for a, b in zip(res[0][:3], res[1][:3]):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)
    for a, b in zip(res[0][3], res[1][3]):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_points_with_gradient_use_differentiable_path():
    f = _field()
    xyz = torch.tensor([[0.1, 0.2, 0.3], [0.5, -1.0, 2.0]], requires_grad=True)
    f.density(xyz).sum().backward()
    assert xyz.grad is not None and torch.isfinite(xyz.grad).all() and xyz.grad.abs().sum() > 0


def test_training_steps_reduce_photometric_loss():
    # a few Adam steps on a fixed colour target must lower the loss (gradients reach planes and MLPs)
    from senerf.fields import render_rays
    gen = torch.Generator().manual_seed(8)
    f = _field()
    o = torch.tensor([0.0, 0.0, -3.0]).expand(64, 3)
    d = torch.nn.functional.normalize(torch.randn(64, 3, generator=gen) * 0.1 + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    near, far = torch.full((64,), 1.5), torch.full((64,), 6.0)
    target = torch.tensor([0.9, 0.1, 0.1])
    opt = torch.optim.Adam(f.parameters(), lr=0.02)
    losses = []
    for _ in range(15):
        out = render_rays(f, o, d, near, far, 24, gen, torch.zeros(3))
        loss = (out["rgb"] - target).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0]


def test_falls_back_to_gather_without_compiler(monkeypatch):
    import senerf.fields.ckernel as ck
    monkeypatch.setattr(ck, "load_kernel", lambda dtype, n_features=16: None)
    f = _field()
    ref = _field(backend="gather")
    xyz = torch.rand(50, 3) * 2 - 1
    d = torch.nn.functional.normalize(torch.ones(50, 3), dim=-1)
    torch.testing.assert_close(f(xyz, d)[1], ref(xyz, d)[1])
    with pytest.raises(RuntimeError):
        _field(backend="fused")(xyz, d)
    monkeypatch.setenv("CC", "/nonexistent/cc")
    monkeypatch.setenv("SENERF_CACHE", str(__import__("tempfile").mkdtemp()))
    with pytest.raises(Exception):
        ck._build("float", 3)


@pytest.mark.parametrize("backend", ["auto", "gather", "grid_sample"])
def test_nan_and_far_points_are_safe(backend):
    f = _field(backend)
    xyz = torch.tensor([[float("nan"), 0.0, 0.0], [1e30, -1e30, 0.0], [0.0, 0.0, 0.0]])
    sigma, rgb = f(xyz, torch.nn.functional.normalize(torch.ones(3, 3), dim=-1))
    assert torch.equal(sigma[:2], torch.zeros(2)) and sigma[2] > 0
    assert torch.isfinite(rgb).all()


def test_an_interrupted_kernel_call_keeps_its_tensors_alive_until_its_workers_end():
    # An interrupt (senerf raises SIGTERM as KeyboardInterrupt) right after the main thread's share of the fused
    # kernel left _run while a worker still wrote into the output tensor, which the caller then freed: senerf-fit
    # died of a segmentation fault instead of exiting 130 (2 of 13 SIGTERMs in a review; so at 16e5117). The
    # tensors a call writes into now stay referenced by its workers until they end.
    import gc
    import threading
    import time
    import weakref

    from senerf.fields.ckernel import _run

    kept = torch.zeros(4)
    alive = weakref.ref(kept)
    seen = []
    done = threading.Event()

    def worker():
        time.sleep(0.3)   # still "writing" when the caller has dropped its reference
        seen.append(alive() is not None)
        done.set()

    def main_share():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run([main_share, worker], keep=(kept,))
    del kept
    gc.collect()
    assert done.wait(5.0) and seen == [True]
    out = []
    _run([lambda: out.append(0), lambda: out.append(1), lambda: out.append(2)], keep=())   # the ordinary case
    assert sorted(out) == [0, 1, 2]


def _grid_sample_features(field, u):
    """Hadamard product over the 3 planes of each scale, by torch.nn.functional.grid_sample directly."""
    pairs = ((0, 1), (0, 2), (1, 2))
    feats = []
    for s in range(len(field.resolutions)):
        prod = 1.0
        for p, (a, b) in enumerate(pairs):
            plane = field.plane(s, p).permute(2, 0, 1)[None]               # (1, F, r(b), r(a))
            grid = u[:, [a, b]].view(1, -1, 1, 2)
            v = F.grid_sample(plane, grid, mode="bilinear", padding_mode="border", align_corners=True)
            prod = prod * v[0, :, :, 0].t()                               # (N, F)
        feats.append(prod)
    return torch.cat(feats, dim=1)


@pytest.mark.parametrize("backend", ["auto", "gather", "grid_sample"])
def test_kplanes_features_are_the_product_of_the_three_planes(backend):
    # the Hadamard product (not the sum) of the plane features, in every backend
    f = KPlanesField([[-1.0, -2.0, -1.0], [1.0, 2.0, 3.0]], resolution=6, n_features=4, multires=(1, 2),
                     generator=torch.Generator().manual_seed(0), backend=backend)
    gen = torch.Generator().manual_seed(1)
    xyz = torch.rand(200, 3, generator=gen) * torch.tensor([2.0, 4.0, 4.0]) + torch.tensor([-1.0, -2.0, -1.0])
    u = (xyz - torch.tensor([-1.0, -2.0, -1.0])) * (2.0 / torch.tensor([2.0, 4.0, 4.0])) - 1.0
    with torch.no_grad():
        feat, inside = f.features(xyz)
        ref = _grid_sample_features(f, u)
    assert inside.all()
    torch.testing.assert_close(feat, ref, rtol=1e-5, atol=1e-6)


def test_kplanes_tv_counts_both_plane_axes():
    # Table constant 0.3 except plane (scale 0, xy) = 0.3 + 0.1 a (a ramp along its columns, 6x6, 4 features):
    # along the ramp every difference is 0.1 -> mean 0.01; across it 0 -> 0.01 in all, / 2 scales = 0.005.
    # The same ramp along the rows (b) must give the same value.
    f = KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=6, n_features=4, multires=(1, 2),
                     generator=torch.Generator().manual_seed(0))
    ramp = 0.1 * torch.arange(6.0)
    for view in (ramp.view(1, 6, 1), ramp.view(6, 1, 1)):
        with torch.no_grad():
            f.table.fill_(0.3)
            f.plane(0, 0).add_(view)
        np.testing.assert_allclose(float(f.regularizer().detach()), 0.005, rtol=1e-5)


def test_kplanes_density_shift_multiplies_density_by_exp_shift():
    # sigma = exp(raw + shift) (raw < 15 here), so two fields with the same seed differ by the factor
    # exp(0.7) = 2.0137527 inside the box.
    xyz = torch.rand(50, 3, generator=torch.Generator().manual_seed(2)) * 1.8 - 0.9
    sig = [KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=6, n_features=4, density_shift=s,
                        generator=torch.Generator().manual_seed(0)).density(xyz).detach() for s in (0.0, 0.7)]
    torch.testing.assert_close(sig[1] / sig[0], torch.full((50,), math.exp(0.7)), rtol=1e-5, atol=0)


@pytest.mark.parametrize("kw", [dict(backend="cuda"), dict(backend="Gather"), dict(chunk=0), dict(chunk=-5)])
def test_kplanes_refuses_unknown_backends_and_empty_chunks(kw):
    # an unknown backend would run the gather path, chunk 0 would fail at the first query
    tiny = dict(resolution=2, n_features=2, multires=(1,), hidden=4, geo_features=2)
    with pytest.raises(ValueError, match=next(iter(kw))):
        KPlanesField([[-1.0] * 3, [1.0] * 3], **tiny, **kw)
    field = KPlanesField([[-1.0] * 3, [1.0] * 3], **tiny, chunk=1, backend="grid_sample")   # one point a chunk
    sigma, rgb = field(torch.zeros(3, 3), torch.tensor([[0.0, 0.0, 1.0]] * 3))
    assert sigma.shape == (3,) and rgb.shape == (3, 3)
    torch.testing.assert_close(sigma, KPlanesField([[-1.0] * 3, [1.0] * 3], **tiny, backend="gather").density(
        torch.zeros(3, 3)))
