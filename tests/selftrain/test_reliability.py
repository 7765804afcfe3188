"""Tests of senerf.selftrain.reliability: warped feature similarity on a textured plane seen by known cameras
(checked against the geometry of the plane), the bilinear lookup against its reference, thresholds against
``numpy.quantile``, mask quality counted by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import senerf.fields.ckernel as ck
from senerf import geometry
from senerf.selftrain.reliability import (
    NO_MATCH,
    adaptive_threshold,
    bilinear_sample,
    bilinear_sample_reference,
    cosine_similarity,
    gt_reliable_mask,
    mask_quality,
    resolve_threshold,
    threshold_weights,
    view_similarity,
)

K = geometry.Intrinsics.from_fov(60.0, 40, 32)


def _disable_kernel(monkeypatch) -> None:
    """No compiled kernel loads from here on (a machine without a C compiler): the NumPy and torch lookups run."""
    monkeypatch.setattr(ck, "load_kernel", lambda dtype, n_features=16: None)


@pytest.fixture
def no_kernel(monkeypatch):
    _disable_kernel(monkeypatch)


def _kernel_or_skip() -> None:
    if ck.load_kernel(torch.float32) is None:
        pytest.skip(f"compiled kernel {ck.kernel_status()}")
PLANE_Z = 3.0


def feature_field(points: np.ndarray) -> np.ndarray:
    """A deterministic zero-mean feature field over world space: 24 sinusoids (periods ~0.1 - 0.5 units)."""
    rng = np.random.default_rng(7)
    freq = rng.normal(size=(24, 3)) * 12.0
    phase = rng.uniform(0, 2 * np.pi, size=24)
    return np.sin(points @ freq.T + phase).astype(np.float32)


def camera(tx: float, ty: float = 0.0) -> np.ndarray:
    c2w = np.eye(4)
    c2w[:3, 3] = (tx, ty, 0.0)
    return c2w


def plane_view(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Features and z-depth of a fronto-parallel plane z = PLANE_Z seen from a camera looking along +z."""
    z = np.full(K.size, PLANE_Z - c2w[2, 3])
    pts = geometry.unproject(geometry.pixel_centers(K), z, K, c2w)
    return feature_field(pts), z


def test_bilinear_sample_pixel_centre_convention():
    img = np.arange(12, dtype=np.float32).reshape(3, 4, 1)
    uv = np.array([[0.5, 0.5], [3.5, 2.5], [1.0, 0.5], [1.5, 1.0], [-3.0, 0.5]])
    out = bilinear_sample(img, uv)[:, 0]
    np.testing.assert_allclose(out, [0.0, 11.0, 0.5, 3.0, 0.0])


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8])
def test_bilinear_sample_matches_the_reference_bit_for_bit(dtype):
    rng = np.random.default_rng(3)
    image = rng.uniform(0, 255, size=(9, 13, 5)).astype(dtype)
    before = image.copy()
    uv = np.concatenate([rng.uniform(-2.0, 15.0, size=(200, 2)), [[0.5, 0.5], [12.5, 8.5], [13.0, 9.0]]])
    out = bilinear_sample(image, uv)
    assert out.dtype == np.float32 and out.shape == (uv.shape[0], 5)
    np.testing.assert_array_equal(out, bilinear_sample_reference(image, uv))
    np.testing.assert_array_equal(image, before)   # the in-place arithmetic works on copies


def test_cosine_similarity_values():
    a = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 0.0]])
    b = np.array([[2.0, 0.0], [-1.0, -1.0], [1.0, 0.0]])
    np.testing.assert_allclose(cosine_similarity(a, b), [1.0, -1.0, 0.0], atol=1e-6)


def test_pseudo_view_equal_to_known_view_is_fully_consistent():
    feats, z = plane_view(camera(0.0))
    opacity = np.ones(K.size)
    res = view_similarity(feats, z, opacity, K, camera(0.0), feats[None], z[None], K, camera(0.0)[None])
    assert res.valid.all()
    np.testing.assert_allclose(res.similarity, 1.0, atol=1e-5)


def _two_known_views_and_a_pseudo_view():
    """Features and depths of the textured plane seen by two known cameras and a pseudo camera between them:
    (known features (2,H,W,C), known z (2,H,W), known c2w (2,4,4), pseudo features, pseudo z, opacity)."""
    known = [camera(-0.9), camera(1.0, 0.2)]
    kf, kz = zip(*(plane_view(c) for c in known))
    pf, pz = plane_view(camera(0.05))
    return np.stack(kf), np.stack(kz), np.stack(known), pf, pz, np.ones(K.size)


def test_true_depth_high_wrong_depth_low_similarity():
    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    good = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    seen = good.valid.any(axis=0)
    assert seen.mean() > 0.9
    assert np.median(good.similarity[seen]) > 0.98
    assert np.all(good.similarity[~seen] == NO_MATCH)
    # a 30 % too large depth puts the points behind the known views' surface: occluded, so they do not count
    hidden = view_similarity(pf, pz * 1.3, opacity, K, camera(0.05), kf, kz, K, kc)
    assert not hidden.valid.any() and np.all(hidden.similarity == NO_MATCH)
    # without occlusion buffers (no surface known), the wrongly lifted points land on unrelated texture
    bad = view_similarity(pf, pz * 1.3, opacity, K, camera(0.05), kf, np.full_like(kz, np.inf), K, kc)
    seen_b = bad.valid.any(axis=0)
    assert seen_b.mean() > 0.5
    assert np.median(bad.similarity[seen_b]) < np.median(good.similarity[seen]) - 0.3


def test_chunked_feature_lookup_is_exact(monkeypatch, no_kernel):
    """Without the compiled kernel, view_similarity samples known features in pixel chunks (bounded memory): same
    result as one go."""
    import senerf.selftrain.reliability as rel

    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    whole = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    monkeypatch.setattr(rel, "_SAMPLE_CHUNK", 7)
    parts = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    assert whole.valid.sum() > 7 * 3
    np.testing.assert_array_equal(parts.per_view, whole.per_view)
    np.testing.assert_array_equal(parts.valid, whole.valid)


def test_known_features_may_be_lazy():
    """Known features given as a one-view-at-a-time object (``extractor.lazy``) give the array's result."""
    from senerf.selftrain.features import LazyViewFeatures

    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    built = []

    def expand(j):
        built.append(j)
        return kf[j].copy()

    lazy = LazyViewFeatures(expand, kf.shape)
    whole = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    deferred = view_similarity(pf, pz, opacity, K, camera(0.05), lazy, kz, K, kc)
    np.testing.assert_array_equal(deferred.per_view, whole.per_view)
    np.testing.assert_array_equal(deferred.similarity, whole.similarity)
    assert sorted(built) == list(range(kf.shape[0]))  # each known view built once per pseudo view


def test_occluded_and_background_pixels():
    kf, kz = plane_view(camera(0.0))
    occluded = kz.copy()
    occluded[:, :20] = 1.0  # an occluder at z = 1 covers the left half of the known view
    pf, pz = plane_view(camera(0.0))
    opacity = np.ones(K.size)
    opacity[0, :] = 0.1
    res = view_similarity(pf, pz, opacity, K, camera(0.0), kf[None], occluded[None], K, camera(0.0)[None])
    assert not res.valid[0, :, :19].any()
    assert res.valid[0, :, 21:].all()
    assert np.all(res.similarity[:, :19] == NO_MATCH)
    assert not res.foreground[0].any() and res.foreground[1:].all()
    # background pixels never become reliable, whatever their similarity
    w = threshold_weights(res.similarity, res.foreground, "fixed", tau=0.6)
    assert not w[0].any() and w[1:, 21:].all()


def test_foreground_only_scores_the_foreground_alone_and_the_same(monkeypatch):
    """foreground_only (what the labels use): foreground pixels get exactly the full call's values, background
    ones NO_MATCH and no valid view, and fewer features are looked up."""
    import senerf.selftrain.reliability as rel

    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    opacity = opacity.copy()
    opacity[:, :15] = 0.2          # a background band on the left
    looked_up = []
    real = rel._lookup_similarity   # the compiled kernel's path or NumPy's
    monkeypatch.setattr(rel, "_lookup_similarity",
                        lambda src, idx, feats, uv: (looked_up.append(len(uv)), real(src, idx, feats, uv))[1])
    full = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    n_full = sum(looked_up)
    looked_up.clear()
    part = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc, foreground_only=True)
    fg = full.foreground
    assert fg.any() and (~fg).any() and full.valid[:, ~fg].any()   # the background was scored before
    np.testing.assert_array_equal(part.foreground, fg)
    np.testing.assert_array_equal(part.similarity[fg], full.similarity[fg])
    np.testing.assert_array_equal(part.per_view[:, fg], full.per_view[:, fg])
    np.testing.assert_array_equal(part.valid[:, fg], full.valid[:, fg])
    assert np.all(part.similarity[~fg] == NO_MATCH) and not part.valid[:, ~fg].any()
    assert sum(looked_up) == full.valid[:, fg].sum() < n_full


def test_adaptive_threshold_is_numpy_quantile():
    rng = np.random.default_rng(3)
    s = rng.uniform(-0.2, 1.0, size=1001)
    for alpha in (0.15, 0.2, 0.25, 0.0, 1.0):
        assert adaptive_threshold(s, alpha) == pytest.approx(np.quantile(s, 1 - alpha))
    # NO_MATCH pixels are not part of the scene's similarity distribution
    with_sentinel = np.concatenate([s, np.full(500, NO_MATCH)])
    assert resolve_threshold("adaptive", with_sentinel, alpha=0.15) == pytest.approx(np.quantile(s, 0.85))
    # exactly a fraction alpha of distinct similarities lies strictly above tau
    tau = adaptive_threshold(s, 0.15)
    assert abs(np.mean(s > tau) - 0.15) < 2e-3
    with pytest.raises(ValueError):
        adaptive_threshold(s, 1.5)
    with pytest.raises(ValueError):
        adaptive_threshold(np.array([]), 0.1)


def test_fixed_and_unified_weights():
    s = np.array([[0.59, 0.6, 0.61], [0.7, 0.9, NO_MATCH]])
    fg = np.array([[True, True, True], [True, False, True]])
    assert resolve_threshold("fixed", s, tau=0.6) == 0.6
    assert resolve_threshold("unified", s) is None
    np.testing.assert_array_equal(threshold_weights(s, fg, "fixed", tau=0.6), [[0, 0, 1], [1, 0, 0]])
    beta = 16.0
    u = threshold_weights(s, fg, "unified", beta=beta)
    expected = np.where(fg, 1 / (1 + np.exp(-beta * (s - 0.7))), 0.0)
    np.testing.assert_allclose(u, expected, rtol=1e-6)
    assert u[1, 0] == pytest.approx(0.5)
    with pytest.raises(ValueError):
        threshold_weights(s, fg, "adaptive")  # no tau
    with pytest.raises(ValueError):
        threshold_weights(s, fg, "topk", tau=0.5)


def test_gt_mask_and_mask_quality_by_hand():
    teacher = np.zeros((1, 2, 3, 3), np.float32)
    gt = teacher.copy()
    gt[0, 0, 0] = 0.5      # wrong pixel
    gt[0, 1, 2] = 0.05     # small error: still right
    truth = gt_reliable_mask(teacher, gt)
    np.testing.assert_array_equal(truth, [[[False, True, True], [True, True, True]]])
    pred = np.array([[[True, True, False], [False, True, True]]])
    q = mask_quality(pred, truth)
    # tp = 3, fp = 1, fn = 2, tn = 0
    assert (q["tp"], q["fp"], q["fn"], q["tn"]) == (3, 1, 2, 0)
    assert q["precision"] == pytest.approx(0.75)
    assert q["recall"] == pytest.approx(0.6)
    assert q["fpr"] == pytest.approx(1.0)
    region = np.array([[[False, True, True], [True, True, True]]])
    assert mask_quality(pred, truth, region)["fpr"] != mask_quality(pred, truth, region)["fpr"]  # NaN: no negatives
    assert np.isnan(mask_quality(np.zeros(3, bool), np.zeros(3, bool))["precision"])  # nothing predicted


def _similarity_args(**replace) -> dict:
    """A valid view_similarity call: a 4 x 4 pseudo view with C = 2 against k = 2 known 4 x 4 views."""
    k4 = geometry.Intrinsics(4.0, 4.0, 2.0, 2.0, 4, 4)
    args = dict(pseudo_features=np.ones((4, 4, 2)), pseudo_z=np.ones((4, 4)), pseudo_opacity=np.ones((4, 4)),
                pseudo_intrinsics=k4, pseudo_c2w=np.eye(4), known_features=np.ones((2, 4, 4, 2)),
                known_z=np.ones((2, 4, 4)), known_intrinsics=k4, known_c2w=np.stack([np.eye(4)] * 2))
    return {**args, **replace}


@pytest.mark.parametrize("call, name", [
    (lambda: bilinear_sample(np.zeros((4, 4)), np.full((2, 2), 0.5)), "image"),
    (lambda: bilinear_sample(np.zeros((4, 4, 1, 1)), np.full((2, 2), 0.5)), "image"),
    (lambda: bilinear_sample(np.zeros((4, 4, 3)), np.full((2, 3), 0.5)), "uv"),
    (lambda: bilinear_sample(np.zeros((4, 4, 3)), np.full((2,), 0.5)), "uv"),
    (lambda: cosine_similarity(np.ones((3, 4)), np.ones((1, 4))), "b must be"),            # would broadcast
    (lambda: view_similarity(**_similarity_args(pseudo_features=np.ones((4, 4)))), "pseudo_features"),
    (lambda: view_similarity(**_similarity_args(pseudo_z=np.ones((4, 3)))), "pseudo_z"),
    (lambda: view_similarity(**_similarity_args(known_features=np.ones((2, 4, 4, 5)))), "known_features"),
    (lambda: view_similarity(**_similarity_args(known_z=np.ones((2, 4, 3)))), "known_z"),
    (lambda: view_similarity(**_similarity_args(known_z=np.ones((1, 4, 4)))), "known_z"),
    (lambda: view_similarity(**_similarity_args(known_c2w=np.stack([np.eye(4)] * 3))), "known_c2w"),
    (lambda: view_similarity(**_similarity_args(known_c2w=np.zeros((2, 3, 4)))), "known_c2w"),
    (lambda: threshold_weights(np.zeros((2, 2)), np.ones((1, 2), bool), "fixed", tau=0.5), "foreground"),
    (lambda: gt_reliable_mask(np.zeros((2, 2, 3)), np.zeros((2, 1, 3))), "gt_rgb"),
    (lambda: gt_reliable_mask(np.zeros((2, 2, 4)), np.zeros((2, 2, 4))), "gt_rgb"),
    (lambda: mask_quality(np.ones(3, bool), np.ones(1, bool)), "truth"),
])
def test_misshapen_arguments_are_refused_naming_them(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_unknown_threshold_kinds_are_refused():
    with pytest.raises(ValueError, match="topk"):
        resolve_threshold("topk", np.zeros(3))
    with pytest.raises(ValueError, match="topk"):
        threshold_weights(np.zeros(3), np.ones(3, bool), "topk", tau=0.5)


def test_view_similarity_with_no_known_view_matches_nothing():
    opacity = np.array([[0.0, 0.49, 0.5, 1.0]] * 4)
    out = view_similarity(**_similarity_args(pseudo_opacity=opacity, known_features=np.ones((0, 4, 4, 2)),
                                             known_z=np.ones((0, 4, 4)), known_c2w=np.zeros((0, 4, 4))),
                          opacity_threshold=0.5)
    np.testing.assert_array_equal(out.similarity, np.full((4, 4), NO_MATCH, np.float32))
    assert out.similarity.dtype == np.float32
    assert out.per_view.shape == (0, 4, 4) and out.valid.shape == (0, 4, 4) and out.valid.dtype == bool
    np.testing.assert_array_equal(out.foreground, opacity >= 0.5)


def test_per_view_intrinsics_match_separate_single_view_calls():
    """Catches a list of known-view intrinsics not being used view by view (e.g. the pseudo view's
    intrinsics used for every known view): each view's result must equal a call with that view alone."""
    k_narrow = geometry.Intrinsics.from_fov(45.0, 40, 32)       # same image size, another focal length
    assert k_narrow.fx != K.fx
    cams = [camera(-0.9), camera(1.0, 0.2)]
    intrs = [K, k_narrow]
    kf, kz = [], []
    for c, intr in zip(cams, intrs):
        z = np.full(intr.size, PLANE_Z - c[2, 3])
        kf.append(feature_field(geometry.unproject(geometry.pixel_centers(intr), z, intr, c)))
        kz.append(z)
    kf, kz, kc = np.stack(kf), np.stack(kz), np.stack(cams)
    pf, pz = plane_view(camera(0.05))
    opacity = np.ones(K.size)
    both = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, intrs, kc)
    for j in range(2):
        alone = view_similarity(pf, pz, opacity, K, camera(0.05), kf[j:j + 1], kz[j:j + 1], intrs[j], kc[j:j + 1])
        np.testing.assert_array_equal(both.valid[j], alone.valid[0])
        np.testing.assert_allclose(both.per_view[j], alone.per_view[0], atol=1e-6)
        # and the right intrinsics make the narrow view consistent too (the warp lands on the same surface)
        assert both.valid[j].mean() > 0.3 and np.median(both.per_view[j][both.valid[j]]) > 0.98
    with pytest.raises(ValueError):
        view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, [K], kc)   # one intrinsics for two views
    # a list of equal intrinsics is the shared case (one batched warp): the same result as passing one
    shared = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    listed = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, [K, K], kc)
    np.testing.assert_array_equal(listed.valid, shared.valid)
    np.testing.assert_array_equal(listed.per_view, shared.per_view)


def test_foreground_includes_opacity_exactly_at_the_threshold():
    """Catches ``opacity > threshold`` for the documented ``opacity >= threshold``."""
    feats, z = plane_view(camera(0.0))
    opacity = np.full(K.size, 0.9)
    opacity[0, 0] = 0.5                       # exactly the threshold: foreground
    opacity[0, 1] = np.nextafter(0.5, 0.0)    # just below: background
    opacity[0, 2] = 0.25                      # exactly another threshold, below this one
    res = view_similarity(feats, z, opacity, K, camera(0.0), feats[None], z[None], K, camera(0.0)[None],
                          opacity_threshold=0.5)
    assert res.foreground[0, 0] and not res.foreground[0, 1] and not res.foreground[0, 2]
    assert res.foreground[1:].all()
    res = view_similarity(feats, z, opacity, K, camera(0.0), feats[None], z[None], K, camera(0.0)[None],
                          opacity_threshold=0.25)
    assert res.foreground[0, 2] and res.foreground[0, 1]


def test_a_nan_in_one_known_view_does_not_veto_the_others_and_weighs_nothing():
    # a NaN passed through the max over views would let one corrupt known view veto pixels another confirmed,
    # and make the unified weight NaN: that view does not count there.
    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    clean = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    corrupt = kf.copy()
    corrupt[0] = np.nan
    got = view_similarity(pf, pz, opacity, K, camera(0.05), corrupt, kz, K, kc)
    assert not got.valid[0].any() and np.all(got.per_view[0] == NO_MATCH)
    only_second = np.where(clean.valid[1], clean.per_view[1], NO_MATCH)
    assert np.array_equal(got.similarity, only_second) and np.isfinite(got.similarity).all()
    s = np.array([[0.95, np.nan, 0.2]])
    assert threshold_weights(s, np.ones_like(s, bool), "unified").tolist()[0][1] == 0.0


def test_an_adaptive_quantile_on_a_tie_keeps_the_tied_pixels():
    # saturated similarities put the (1 - alpha) quantile on a tie, where "> tau" would keep no pixel at all and
    # the adaptive threshold exists to keep its top share
    fg = np.ones((4, 4), bool)
    flat = np.full((4, 4), 0.93)
    tau = resolve_threshold("adaptive", flat[fg], alpha=0.15)
    assert threshold_weights(flat, fg, "adaptive", tau=tau).mean() == 1.0
    top = np.r_[np.linspace(0.2, 0.8, 80), np.ones(20)].reshape(10, 10)   # top 20 % saturated at 1.0
    tau = resolve_threshold("adaptive", top.ravel(), alpha=0.15)
    assert threshold_weights(top, np.ones_like(top, bool), "adaptive", tau=tau).mean() == pytest.approx(0.2)
    spread = np.linspace(0.0, 1.0, 100).reshape(10, 10)   # no tie: "> tau"
    tau = resolve_threshold("adaptive", spread.ravel(), alpha=0.15)
    assert threshold_weights(spread, np.ones_like(spread, bool), "adaptive", tau=tau).mean() == pytest.approx(0.15)
    assert threshold_weights(flat, fg, "fixed", tau=0.93).sum() == 0.0   # the fixed threshold stays strict
    # a tie at tau with pixels above it: ">" keeps those alone (the fallback is for "none kept" only)
    mixed = np.r_[np.full(80, 0.5), np.full(10, 0.7), np.full(10, 0.9)].reshape(10, 10)
    tau = resolve_threshold("adaptive", mixed.ravel(), alpha=0.15)
    assert tau == 0.7 and threshold_weights(mixed, np.ones_like(mixed, bool), "adaptive", tau=tau).mean() == 0.1
    # the fallback looks at the foreground: a background pixel above tau does not count as one kept
    fg_flat = np.ones((4, 4), bool)
    fg_flat[0, 0] = False
    with_bg = np.where(fg_flat, 0.93, 0.99)
    tau = resolve_threshold("adaptive", with_bg[fg_flat], alpha=0.15)
    assert threshold_weights(with_bg, fg_flat, "adaptive", tau=tau).sum() == 15.0


def _devices():
    return ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.mark.parametrize("device", _devices())
@pytest.mark.parametrize("known_as", ["array", "tensor", "lazy"])
@pytest.mark.parametrize("pseudo_scale", [1.0, -1e-3])
@pytest.mark.parametrize("kernel", [True, False])
def test_tensor_features_are_looked_up_in_torch_with_the_same_result(monkeypatch, device, known_as, pseudo_scale,
                                                                     kernel):
    """Features handed over as tensors (a CUDA fit keeps VGG's features on the GPU) are looked up in torch on
    their device (on the CPU by the compiled kernel where it loads): the NumPy path's valid views and NO_MATCH
    pixels exactly, its similarities within float32 rounding, across lookup chunks, with a partly dropped
    background and a NaN known view not counted; also for pseudo features scaled by -1e-3 (negative cosines,
    small norms) and zero vectors (similarity 0)."""
    import senerf.selftrain.reliability as rel
    from senerf.selftrain.features import LazyViewFeatures

    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    pf = (pf * pseudo_scale).astype(np.float32)
    pf[20:, 20:] = 0.0      # zero vectors: similarity 0 with everything
    opacity = opacity.copy()
    opacity[:, :15] = 0.2
    kf = kf.copy()
    kf[1, :4] = np.nan      # a corrupt band in one known view
    monkeypatch.setattr(rel, "_SAMPLE_CHUNK", 5)            # torch takes 4 x 5 pixels a chunk: many chunks
    with monkeypatch.context() as plain:
        _disable_kernel(plain)
        expect = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc, foreground_only=True)
    if not kernel:
        _disable_kernel(monkeypatch)
    known = {"array": kf, "tensor": torch.from_numpy(kf).to(device),
             "lazy": LazyViewFeatures(lambda j: kf[j].copy(), kf.shape)}[known_as]

    def numpy_path(*args):
        raise AssertionError("the NumPy lookup ran for tensor features")

    monkeypatch.setattr(rel, "cosine_similarity", numpy_path)
    got = view_similarity(torch.from_numpy(pf).to(device), pz, opacity, K, camera(0.05), known, kz, K, kc,
                          foreground_only=True)
    assert isinstance(got.similarity, np.ndarray) and got.similarity.dtype == np.float32
    assert expect.valid.sum() > 4 * 5 * 3 and (expect.per_view == NO_MATCH).any()
    assert (expect.per_view[expect.valid] < 0).any() == (pseudo_scale < 0)
    assert (expect.per_view[:, 20:, 20:][expect.valid[:, 20:, 20:]] == 0.0).sum() > 10
    np.testing.assert_array_equal(got.valid, expect.valid)
    np.testing.assert_array_equal(got.per_view == NO_MATCH, expect.per_view == NO_MATCH)
    np.testing.assert_allclose(got.per_view, expect.per_view, rtol=0, atol=2e-6)
    np.testing.assert_allclose(got.similarity, expect.similarity, rtol=0, atol=2e-6)


@pytest.mark.parametrize("device", _devices())
def test_array_pseudo_features_with_tensor_known_features_take_the_numpy_path(device):
    """Known features as a tensor (a GPU extractor's) beside array pseudo features: the host path (the compiled
    kernel's or NumPy's), after copying each known view to the host, to the bit (``np.asarray`` of a CUDA tensor
    raised before)."""
    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    expect = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)
    got = view_similarity(pf, pz, opacity, K, camera(0.05), torch.from_numpy(kf).to(device), kz, K, kc)
    np.testing.assert_array_equal(got.per_view, expect.per_view)
    np.testing.assert_array_equal(got.valid, expect.valid)


def _kernel_case(c: int, common: float = 0.0, seed: int = 5):
    """Random float32 features ``(9, 13, c)`` of a known view, pixel features ``(40, c)`` and ``(N,)`` rows with
    ``(N, 2)`` positions: random ones in and around the image, every exact pixel centre, the edges and corners,
    far out of range on every side; a block of zero known features (sampled at its centres: zero vectors) and
    zero pixel rows.  ``common`` is put in the first 16 channels of all the others: a large shared component
    whose squares swamp float32 sums of the small rest (the kernel's are double)."""
    rng = np.random.default_rng(seed)
    h, w = 9, 13
    feats = rng.normal(size=(h, w, c)).astype(np.float32)
    src = rng.normal(size=(40, c)).astype(np.float32)
    if common:
        feats[..., :16] = src[:, :16] = common
    feats[:3, :3] = 0.0
    src[:2] = 0.0
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    centres = np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], 1)
    edges = [[0.0, 0.0], [w, h], [w - 0.5, h - 0.5], [0.5, h], [w, 0.25], [6.0, 0.0], [0.0, 4.0], [w, 4.7],
             [-3.0, 20.0], [100.0, -5.0], [-1e6, -1e6], [1e6, 1e6], [6.3, -40.0], [-7.0, 4.2]]
    uv = np.concatenate([rng.uniform(-2.0, 15.0, size=(3000, 2)), centres, edges])
    rows = rng.integers(0, src.shape[0], size=uv.shape[0])
    return src, rows, feats, uv


@pytest.mark.parametrize("c", [960, 37, 3])
@pytest.mark.parametrize("common", [0.0, 1e4])
def test_the_fused_kernel_matches_the_reference_lookup(c, common):
    """The compiled similarity: the cosine of each pixel's row with bilinear_sample_reference's sample (its float32
    bits: a sample blended in double rounds ~20 % of the cosines otherwise), summed in double, so the float64
    cosine of that sample rounded to float32 (but for a rare tie), and ~1e-6 of the NumPy path's float32 sums;
    exact centres give the corner row itself, clamped positions the edge's values, zero vectors 0."""
    _kernel_or_skip()
    src, rows, feats, uv = _kernel_case(c, common)
    got = ck.fused_feature_similarity(src, rows, feats, uv)
    assert got.dtype == np.float32 and got.shape == rows.shape
    b = bilinear_sample_reference(feats, uv).astype(np.float64)
    a = src[rows].astype(np.float64)
    exact = (a * b).sum(-1) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), 1e-8)
    np.testing.assert_allclose(got, exact, rtol=0, atol=1e-7)
    assert np.mean(got != exact.astype(np.float32)) < 1e-3
    numpy_path = cosine_similarity(src[rows], bilinear_sample(feats, uv))
    np.testing.assert_allclose(got, numpy_path, rtol=0, atol=1e-6)
    zero = (rows < 2) | (np.abs(b).sum(-1) == 0)
    assert zero.sum() > 50 and np.all(got[zero] == 0.0)
    h, w = feats.shape[:2]
    centre = slice(3000, 3000 + h * w)   # the exact centres, in raster order: the known rows unblended
    flat = feats.reshape(h * w, c).astype(np.float64)
    a_c = a[centre]
    want = (a_c * flat).sum(-1) / np.maximum(np.linalg.norm(a_c, axis=-1) * np.linalg.norm(flat, axis=-1), 1e-8)
    np.testing.assert_allclose(got[centre], want, rtol=0, atol=1e-7)


def test_the_fused_kernel_gives_the_same_bits_on_one_and_two_threads():
    _kernel_or_skip()
    src, rows, feats, uv = _kernel_case(96)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = ck.fused_feature_similarity(src, rows, feats, uv)
        torch.set_num_threads(2)
        assert len(ck._split(rows.size, 2)) == 2   # the pixels really are split
        two = ck.fused_feature_similarity(src, rows, feats, uv)
    finally:
        torch.set_num_threads(before)
    np.testing.assert_array_equal(one, two)


def test_the_fused_kernel_takes_cpu_tensors_and_refuses_what_it_cannot_read():
    """CPU tensors give the arrays' result (a strided one is copied); float64 features, a missing kernel and (where
    there is one) a CUDA tensor give None, the callers' cue for their own path; bad rows and shapes raise."""
    _kernel_or_skip()
    src, rows, feats, uv = _kernel_case(8)
    want = ck.fused_feature_similarity(src, rows, feats, uv)
    strided = torch.from_numpy(np.ascontiguousarray(feats.transpose(1, 0, 2))).permute(1, 0, 2)
    np.testing.assert_array_equal(ck.fused_feature_similarity(torch.from_numpy(src), rows, strided, uv), want)
    assert ck.fused_feature_similarity(src, rows, feats.astype(np.float64), uv) is None
    assert ck.fused_feature_similarity(torch.from_numpy(src).double(), rows, feats, uv) is None
    if torch.cuda.is_available():
        assert ck.fused_feature_similarity(src, rows, torch.from_numpy(feats).cuda(), uv) is None
    assert ck.fused_feature_similarity(src, rows[:0], feats, uv[:0]).shape == (0,)
    with pytest.raises(IndexError, match=r"rows must lie in \[0, 40\)"):
        ck.fused_feature_similarity(src, rows + 1, feats, uv)
    with pytest.raises(ValueError, match="uv"):
        ck.fused_feature_similarity(src, rows, feats, uv[:-1])
    with pytest.raises(ValueError, match="features"):
        ck.fused_feature_similarity(src, rows, feats[..., :5], uv)


def test_without_a_kernel_the_fused_similarity_is_none(no_kernel):
    src, rows, feats, uv = _kernel_case(8)
    assert ck.fused_feature_similarity(src, rows, feats, uv) is None


@pytest.mark.parametrize("known_as", ["array", "lazy"])
def test_view_similarity_with_the_kernel_matches_the_numpy_path(monkeypatch, known_as):
    """Labelling with the compiled kernel (no NumPy lookup runs) scores what the NumPy path scores: the same valid
    views and NO_MATCH pixels, similarities within 1e-5, a NaN known view dropped alike, zero vectors 0."""
    import senerf.selftrain.reliability as rel
    from senerf.selftrain.features import LazyViewFeatures

    _kernel_or_skip()
    kf, kz, kc, pf, pz, opacity = _two_known_views_and_a_pseudo_view()
    pf = pf.copy()
    pf[20:, 20:] = 0.0
    kf = kf.copy()
    kf[1, :4] = np.nan
    with monkeypatch.context() as plain:
        _disable_kernel(plain)
        expect = view_similarity(pf, pz, opacity, K, camera(0.05), kf, kz, K, kc)

    def numpy_path(*args):
        raise AssertionError("the NumPy lookup ran with the kernel loaded")

    monkeypatch.setattr(rel, "bilinear_sample", numpy_path)
    known = kf if known_as == "array" else LazyViewFeatures(lambda j: kf[j].copy(), kf.shape)
    got = view_similarity(pf, pz, opacity, K, camera(0.05), known, kz, K, kc)
    assert expect.valid.sum() > 500 and (expect.per_view == NO_MATCH).any()
    assert (expect.per_view[:, 20:, 20:][expect.valid[:, 20:, 20:]] == 0.0).sum() > 10
    np.testing.assert_array_equal(got.valid, expect.valid)
    np.testing.assert_array_equal(got.per_view == NO_MATCH, expect.per_view == NO_MATCH)
    np.testing.assert_allclose(got.per_view, expect.per_view, rtol=0, atol=1e-5)
    np.testing.assert_allclose(got.similarity, expect.similarity, rtol=0, atol=1e-5)
