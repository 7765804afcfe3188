"""Lines of senerf.fields no other test ran: argument checks (each bad value refused with an error naming it, the
boundary value accepted) and the compiled kernel's build and fallback paths."""

from __future__ import annotations

import ctypes
import re

import pytest
import torch
from torch import nn

import senerf.fields.ckernel as ck
from senerf.fields import KPlanesField, NeRFField, OccupancyGrid, RadianceField, positional_encoding, sh_encoding
from senerf.fields.base import as_aabb, check_points
from senerf.fields.encoding import sh_dim, sh_encoding_reference
from senerf.fields.interp import gather_blend, plane_layout
from senerf.fields.mlp import relu_mlp

BOX = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]


def _exact(message: str):
    return "^" + re.escape(message) + "$"


# -- base.py ---------------------------------------------------------------------------------------------------------

def test_the_base_field_leaves_density_and_forward_to_subclasses():
    # Catches: RadianceField.density / forward returning something (None) instead of raising NotImplementedError.
    field, xyz = RadianceField(), torch.zeros(2, 3)
    with pytest.raises(NotImplementedError):
        field.density(xyz)
    with pytest.raises(NotImplementedError):
        field(xyz, xyz)
    assert torch.equal(field.regularizer(), torch.zeros(()))   # no parameters: a CPU zero


@pytest.mark.parametrize("aabb, message", [
    ([[0.0, 0.0, 0.0]], "aabb: expected shape (2, 3), got (1, 3)"),
    ([[0.0, 0.0], [1.0, 1.0]], "aabb: expected shape (2, 3), got (2, 2)"),
    ([[0.0, 0.0, 0.0], [1.0, 0.0, 1.0]],
     "aabb: every max must exceed its min, got [[0.0, 0.0, 0.0], [1.0, 0.0, 1.0]]"),
    ([[0.0, 0.0, 0.0], [1.0, 1.0, -1.0]],
     "aabb: every max must exceed its min, got [[0.0, 0.0, 0.0], [1.0, 1.0, -1.0]]"),
])
def test_as_aabb_refuses_misshapen_or_empty_boxes(aabb, message):
    # Catches: as_aabb's shape check or its max > min check deleted, or > loosened to >= (an empty box divided by 0).
    with pytest.raises(ValueError, match=_exact(message)):
        as_aabb(aabb)
    box = as_aabb([[0.0, 0.0, 0.0], [0.5, 0.5, 0.5]])   # max just above min on every axis: accepted, float32
    assert box.dtype == torch.float32 and box.tolist() == [[0.0, 0.0, 0.0], [0.5, 0.5, 0.5]]


def test_check_points_refuses_integer_points():
    # Catches: check_points' floating-dtype check deleted (integer points were truncated by the AABB mapping).
    with pytest.raises(ValueError, match=_exact("pts: expected a floating tensor, got torch.int64")):
        check_points(torch.zeros(2, 3, dtype=torch.int64), "pts")
    for dtype in (torch.float16, torch.float32, torch.float64):
        check_points(torch.zeros(2, 3, dtype=dtype))


# -- encoding.py -----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("degree", [0, 5, -1])
def test_sh_degree_outside_1_to_4_is_refused(degree):
    # Catches: sh_dim's range check deleted or widened (degree 5 gave 25 columns of which 9 were never computed).
    with pytest.raises(ValueError, match=_exact(f"degree: expected 1..4, got {degree}")):
        sh_dim(degree)
    assert [sh_dim(d) for d in (1, 2, 3, 4)] == [1, 4, 9, 16]


@pytest.mark.parametrize("shape", [(5, 2), (5, 4), (5,), (1, 5, 3)])
@pytest.mark.parametrize("encode", [sh_encoding, sh_encoding_reference])
def test_sh_encoding_refuses_directions_that_are_not_n_by_3(encode, shape):
    # Catches: sh_encoding_reference's shape check deleted ((N, 4) directions were encoded from their first 3).
    with pytest.raises(ValueError, match=_exact(f"dirs: expected shape (N, 3), got {shape}")):
        encode(torch.zeros(shape), 4)
    z = torch.tensor([[0.0, 0.0, 1.0]])   # +z: Y_00 = 0.28209..., Y_1,0 = 0.48860... z
    out = encode(z, 2)
    torch.testing.assert_close(out, torch.tensor([[0.28209479177387814, 0.0, 0.48860251190291987, 0.0]]))


def test_positional_encoding_refuses_unbatched_input_and_misshapen_band_weights():
    # Catches: positional_encoding's x.ndim check or its weights shape check deleted (a (3,) weight vector for two
    # bands broadcast into a wrong shape error, or a 1-D x was encoded as N rows of one value).
    with pytest.raises(ValueError, match=_exact("x: expected shape (N, D), got (3,)")):
        positional_encoding(torch.zeros(3), 2)
    with pytest.raises(ValueError, match=_exact("weights: expected shape (2,), got (3,)")):
        positional_encoding(torch.zeros(1, 1), 2, weights=torch.ones(3))
    with pytest.raises(ValueError, match=_exact("weights: expected shape (2,), got (1, 2)")):
        positional_encoding(torch.zeros(1, 1), 2, weights=torch.ones(1, 2))
    # by hand, x = 0.25, bands pi x = pi/4 and 2 pi x = pi/2 weighted 1 and 0.5:
    # [x, sin(pi/4), cos(pi/4), 0.5 sin(pi/2), 0.5 cos(pi/2)] = [0.25, 0.7071, 0.7071, 0.5, 0]
    out = positional_encoding(torch.tensor([[0.25]], dtype=torch.float64), 2, weights=torch.tensor([1.0, 0.5]))
    r = 0.5 ** 0.5
    torch.testing.assert_close(out, torch.tensor([[0.25, r, r, 0.5, 0.0]], dtype=torch.float64))


# -- interp.py -------------------------------------------------------------------------------------------------------

def test_plane_layout_refuses_planes_of_fewer_than_two_texels():
    # Catches: plane_layout's r < 2 check deleted or moved to r < 1 (a 1-texel plane has no bilinear neighbour).
    with pytest.raises(ValueError, match=_exact("resolution: every plane needs at least 2 texels per side, got 1")):
        plane_layout((4, 1))
    assert plane_layout((2, 3)) == ([0, 4, 8, 12, 21, 30], 39)   # 3 planes of 2x2, then 3 of 3x3


@pytest.mark.parametrize("table, idx, w", [
    (torch.ones(4), torch.zeros(1, 4, dtype=torch.int64), torch.ones(1, 4)),
    (torch.ones(4, 1), torch.zeros(1, 3, dtype=torch.int64), torch.ones(1, 3)),
    (torch.ones(4, 1), torch.zeros(4, dtype=torch.int64), torch.ones(4)),
    (torch.ones(4, 1), torch.zeros(1, 4, dtype=torch.int64), torch.ones(2, 4)),
])
def test_gather_blend_refuses_bad_shapes(table, idx, w):
    # Catches: gather_blend's shape check deleted (a bad index shape read past the rows in the backward pass).
    message = (f"gather_blend: bad shapes table {tuple(table.shape)}, idx {tuple(idx.shape)}, w {tuple(w.shape)}")
    with pytest.raises(ValueError, match=_exact(message)):
        gather_blend(table, idx, w, (2,), ((0, 4),))
    # one 2x2 plane of rows 1, 2, 3, 4: 0.1 * 1 + 0.2 * 2 + 0.3 * 3 + 0.4 * 4 = 3
    out = gather_blend(torch.tensor([[1.0], [2.0], [3.0], [4.0]]), torch.tensor([[0, 1, 2, 3]]),
                       torch.tensor([[0.1, 0.2, 0.3, 0.4]]), (2,), ((0, 4),))
    torch.testing.assert_close(out, torch.tensor([[3.0]]))


# -- kplanes.py, nerf.py, mlp.py, occupancy.py -----------------------------------------------------------------------

def _kplanes(**kw) -> KPlanesField:
    return KPlanesField(BOX, resolution=2, n_features=2, multires=(1,), hidden=4, geo_features=2,
                        generator=torch.Generator().manual_seed(0), **kw)


@pytest.mark.parametrize("kw, message", [
    (dict(backend="cuda"), "backend: expected auto, fused, gather or grid_sample, got 'cuda'"),
    (dict(backend="Gather"), "backend: expected auto, fused, gather or grid_sample, got 'Gather'"),
    (dict(chunk=0), "chunk: expected >= 1, got 0"),
    (dict(chunk=-5), "chunk: expected >= 1, got -5"),
])
def test_kplanes_refuses_unknown_backends_and_empty_chunks(kw, message):
    # Catches: KPlanesField's backend check (an unknown one ran the gather path) or chunk >= 1 check deleted (chunk 0
    # made torch.split fail at the first query).
    with pytest.raises(ValueError, match=_exact(message)):
        _kplanes(**kw)
    field = _kplanes(chunk=1, backend="grid_sample")   # the boundary: one point a chunk
    sigma, rgb = field(torch.zeros(3, 3), torch.tensor([[0.0, 0.0, 1.0]] * 3))
    assert sigma.shape == (3,) and rgb.shape == (3, 3)
    torch.testing.assert_close(sigma, _kplanes(backend="gather").density(torch.zeros(3, 3)))


@pytest.mark.parametrize("make", [_kplanes, lambda: NeRFField(BOX, n_freqs=1, hidden=4, n_layers=2)])
def test_view_dependent_fields_refuse_missing_or_misshapen_directions(make):
    # Catches: KPlanesField.forward's / NeRFField.forward's dirs check deleted (None crashed in torch.split, a
    # (N, 2) direction in the SH encoding; (1, 3) directions broadcast over N points).
    field, xyz = make(), torch.zeros(2, 3)
    for dirs in (None, torch.zeros(2, 2), torch.zeros(1, 3)):
        with pytest.raises(ValueError, match=re.escape("dirs: expected shape (2, 3)")):
            field(xyz, dirs)
    sigma, rgb = field(xyz, torch.tensor([[0.0, 0.0, 1.0]] * 2))
    assert sigma.shape == (2,) and rgb.shape == (2, 3)


def test_relu_mlp_refuses_layers_it_does_not_fuse():
    # Catches: relu_mlp's layer check deleted (a Tanh was skipped: the fused pass computed another function).
    net = nn.Sequential(nn.Linear(2, 3), nn.Tanh(), nn.Linear(3, 1))
    with pytest.raises(ValueError, match=_exact("relu_mlp: unsupported layer Tanh")):
        relu_mlp(torch.zeros(4, 2), net)
    net[1] = nn.ReLU()
    x = torch.randn(4, 2, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(relu_mlp(x, net), net(x))


def test_occupancy_grid_needs_at_least_one_cell():
    # Catches: OccupancyGrid's resolution >= 1 check deleted or off by one.
    for bad in (0, -2):
        with pytest.raises(ValueError, match=_exact(f"resolution: expected >= 1, got {bad}")):
            OccupancyGrid(BOX, resolution=bad)
    grid = OccupancyGrid(BOX, resolution=1)
    assert grid.mask.shape == (1,) and grid.is_occupied(torch.zeros(1, 3)).tolist() == [True]


# -- ckernel.py ------------------------------------------------------------------------------------------------------

def test_cache_dir_skips_folders_it_cannot_make_and_says_when_none_is_left(tmp_path, monkeypatch):
    # Catches: _cache_dir's "except OSError: continue" deleted (a $SENERF_CACHE naming a file stopped the kernel
    # instead of falling back), or its final raise replaced by returning None.
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("x")
    monkeypatch.setenv("SENERF_CACHE", str(not_a_folder))
    monkeypatch.setattr(ck.Path, "home", classmethod(lambda cls: tmp_path / "home"))
    assert ck._cache_dir() == tmp_path / "home" / ".cache" / "senerf"   # the next candidate, created
    monkeypatch.setattr(ck.Path, "home", classmethod(lambda cls: not_a_folder))
    monkeypatch.setattr(ck.tempfile, "gettempdir", lambda: str(not_a_folder))
    with pytest.raises(OSError, match="no writable cache folder for the compiled kernel"):
        ck._cache_dir()
    monkeypatch.setenv("SENERF_CACHE", str(tmp_path / "mine"))
    monkeypatch.setattr(ck.os, "access", lambda path, mode: False)   # made, but not writable: skipped too
    with pytest.raises(OSError, match="no writable cache folder"):
        ck._cache_dir()
    monkeypatch.undo()
    monkeypatch.setenv("SENERF_CACHE", str(tmp_path / "mine"))
    assert ck._cache_dir() == tmp_path / "mine"


def test_cpu_flags_fall_back_to_the_processor_name_without_proc_cpuinfo(monkeypatch):
    # Catches: _cpu_flags' "except OSError" deleted (no /proc/cpuinfo, as on macOS, stopped the kernel build).
    def missing(*args, **kwargs):
        raise FileNotFoundError(2, "No such file or directory", "/proc/cpuinfo")
    monkeypatch.setattr(ck.platform, "processor", lambda: "cpu-name")
    monkeypatch.setattr(ck, "open", missing, raising=False)
    assert ck._cpu_flags() == "cpu-name"
    monkeypatch.undo()
    if ck.Path("/proc/cpuinfo").is_file():
        assert ck._cpu_flags().startswith(("flags", "Features"))


def test_build_without_a_compiler_says_so(monkeypatch):
    # Catches: _build's "no C compiler found" check deleted (subprocess.run([None, ...]) raised a TypeError).
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(ck.shutil, "which", lambda name: None)
    with pytest.raises(OSError, match=_exact("no C compiler found")):
        ck._build("float", 3)


def test_build_compiles_once_into_a_fresh_cache(tmp_path, monkeypatch):
    # Catches: _build's os.replace of the finished library deleted (nothing at the returned path) or its return of
    # the path dropped; the second call must find the library and not compile again.
    if not (ck.os.environ.get("CC") or ck.shutil.which("cc") or ck.shutil.which("gcc")):
        pytest.skip("no C compiler")
    monkeypatch.setenv("SENERF_CACHE", str(tmp_path))
    out = ck._build("double", 3)
    assert out.parent == tmp_path and out.name.startswith("kplanes_double_f3_") and out.suffix == ".so"
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]   # the temporary file was renamed, none left
    lib = ctypes.CDLL(str(out))
    assert lib.kp_nf() == 3                                            # compiled with -DNF=3

    def no_compiler(*args, **kwargs):
        raise AssertionError("compiled again")
    monkeypatch.setattr(ck.subprocess, "run", no_compiler)
    assert ck._build("double", 3) == out


def test_load_kernel_refuses_other_dtypes_and_feature_counts_and_falls_back_when_the_build_fails(monkeypatch):
    # Catches: load_kernel's dtype / 1 <= n_features <= MAX_FEATURES check deleted or off by one, or its
    # "except Exception" fallback deleted (a failed build raised instead of returning None for the PyTorch path).
    built = []

    def failing_build(real, nf):
        built.append((real, nf))
        raise OSError("boom")
    monkeypatch.setattr(ck, "_build", failing_build)
    monkeypatch.setitem(ck._STATUS, "status", ck._STATUS["status"])   # restored afterwards
    load = ck.load_kernel.__wrapped__   # past the per-process cache
    for dtype, nf in ((torch.float16, 16), (torch.int32, 16), (torch.float32, 0), (torch.float32, ck.MAX_FEATURES + 1)):
        assert load(dtype, nf) is None
    assert built == []                  # refused before any build
    assert load(torch.float32, 1) is None and load(torch.float64, ck.MAX_FEATURES) is None
    assert built == [("float", 1), ("double", 256)]
    assert ck.kernel_status() == "unavailable: OSError: boom"
