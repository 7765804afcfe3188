"""Input checks at the edges of senerf.selftrain's API: each bad argument is refused with an error naming it, and
each check's boundary value is accepted (so an off-by-one in the comparison fails a test too)."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from senerf.errors import InputError
from senerf.geometry import Intrinsics
from senerf.selftrain.controller import PseudoLabels, SelfTrainConfig, estimate_reliability
from senerf.selftrain.distill import (
    DistillationLoss,
    DistillConfig,
    PseudoRays,
    gaussian_prior,
    neighbour_offsets,
    prior_weights,
    unified_prior_weights,
)
from senerf.selftrain.features import DaisyFeatures, LazyViewFeatures, VGG19Features
from senerf.selftrain.reliability import (
    NO_MATCH,
    bilinear_sample,
    cosine_similarity,
    gt_reliable_mask,
    mask_quality,
    resolve_threshold,
    threshold_weights,
    view_similarity,
)

K4 = Intrinsics(4.0, 4.0, 2.0, 2.0, 4, 4)
NAN = float("nan")
INF = float("inf")


# ---------------------------------------------------------------------------------------------------------
# SelfTrainConfig.__post_init__ (InputError "<field>: <problem>")


@pytest.mark.parametrize("kwargs, message", [
    (dict(oracle_max_error=0.0), "oracle_max_error: must be in (0, 1], got 0.0"),
    (dict(oracle_max_error=1.01), "oracle_max_error: must be in (0, 1], got 1.01"),
    (dict(oracle_max_error=NAN), "oracle_max_error: must be in (0, 1]"),
    (dict(iterations=-1), "iterations: must be an integer >= 0, got -1"),
    (dict(iterations=2.0), "iterations: must be an integer >= 0, got 2.0"),
    (dict(iterations=True), "iterations: must be an integer >= 0, got True"),
    (dict(n_pseudo_per_input=0), "n_pseudo_per_input: must be an integer >= 1, got 0"),
    (dict(n_pseudo_per_input=3.0), "n_pseudo_per_input: must be an integer >= 1, got 3.0"),
    (dict(seed=1.5), "seed: must be an integer >= 0, got 1.5"),
    (dict(seed=-1), "seed: must be an integer >= 0, got -1"),   # np.random.default_rng refused it after the teacher
    (dict(fixed_tau="0.5"), "fixed_tau: must be in [-1, 1], got '0.5'"),   # a TypeError traceback before
    (dict(alpha0=None), "alpha0: must be in [0, 1], got None"),
    (dict(beta=True), "beta: must be a finite number > 0, got True"),
    (dict(alpha_step=True), "alpha_step: must be a finite number >= 0, got True"),
    (dict(batch_empty=None), "batch_empty: must be an integer >= 0, got None"),   # checked before its use below
    (dict(alpha0=-0.01), "alpha0: must be in [0, 1], got -0.01"),
    (dict(alpha0=1.01), "alpha0: must be in [0, 1], got 1.01"),
    (dict(alpha_step=-0.01), "alpha_step: must be a finite number >= 0, got -0.01"),
    (dict(pseudo_range_deg=-1.0), "pseudo_range_deg: must be a finite number >= 0, got -1.0"),
    (dict(pseudo_range_deg=INF), "pseudo_range_deg: must be a finite number >= 0, got inf"),
    (dict(pseudo_range_step_deg=-1.0), "pseudo_range_step_deg: must be a finite number >= 0, got -1.0"),
    (dict(occlusion_rel_tol=NAN), "occlusion_rel_tol: must be a finite number >= 0, got nan"),
    (dict(fixed_tau=1.01), "fixed_tau: must be in [-1, 1], got 1.01"),
    (dict(fixed_tau=NAN), "fixed_tau: must be in [-1, 1], got nan"),
    (dict(beta=0.0), "beta: must be a finite number > 0, got 0.0"),
    (dict(beta=INF), "beta: must be a finite number > 0, got inf"),
    (dict(opacity_threshold=0.0), "opacity_threshold: must be in (0, 1], got 0.0"),
    (dict(opacity_threshold=1.01), "opacity_threshold: must be in (0, 1], got 1.01"),
])
def test_selftrain_config_refuses_each_bad_setting(kwargs, message):
    # Catches: any one of SelfTrainConfig's range / type checks deleted, or its raise naming another field (before
    # 2026-11-23 alpha_step was reported as alpha0 and pseudo_range_step_deg as pseudo_range_deg, without values,
    # and a bool counted as iterations).
    with pytest.raises(InputError, match="^" + re.escape(message)) as info:
        SelfTrainConfig(**kwargs)
    assert info.value.field == message.split(":")[0]


@pytest.mark.parametrize("kwargs", [
    dict(oracle_max_error=1.0),
    dict(iterations=0),
    dict(n_pseudo_per_input=1),
    dict(alpha0=0.0, alpha_step=0.0),
    dict(alpha0=1.0),
    dict(pseudo_range_deg=0.0, pseudo_range_step_deg=0.0),
    dict(opacity_threshold=1.0),
    dict(fixed_tau=-1.0, occlusion_rel_tol=0.0),
    dict(fixed_tau=1.0, beta=1e-3),
])
def test_selftrain_config_accepts_each_boundary_value(kwargs):
    # Catches: an off-by-one comparison (``< 1`` for ``<= 1``, ``<= 0`` for ``< 0``, ``< 2`` for ``< 1``) in a check.
    cfg = SelfTrainConfig(**kwargs)
    assert all(getattr(cfg, k) == v for k, v in kwargs.items())


def test_distill_config_error_pickles_with_its_field():
    # Catches: a two-argument exception whose args hold one string (pickle.loads re-calls __init__ with it and
    # fails), so a worker process could not hand the error back.
    import pickle

    from senerf.selftrain.distill import DistillConfigError

    err = pickle.loads(pickle.dumps(DistillConfigError("kernel_std", "must be > 0")))
    assert (str(err), err.field, err.message) == ("kernel_std must be > 0", "kernel_std", "must be > 0")


def test_selftrain_config_takes_numpy_integers_as_plain_ints():
    # Catches: NumPy integers (what a loop over np.arange hands over) refused as "must be an integer", or kept as
    # NumPy scalars, which json.dumps of the run's config refuses.
    cfg = SelfTrainConfig(iterations=np.int64(2), n_pseudo_per_input=np.int32(4), seed=np.int64(7),
                          batch_reliable=np.int64(256), kernel_size=np.int64(5))
    values = (cfg.iterations, cfg.n_pseudo_per_input, cfg.seed, cfg.batch_reliable, cfg.kernel_size)
    assert values == (2, 4, 7, 256, 5) and all(type(v) is int for v in values)


def _labels(empty: np.ndarray) -> PseudoLabels:
    p, h, w = 1, 2, 2
    z = np.zeros((p, h, w), np.float32)
    return PseudoLabels(c2w=np.eye(4)[None], rgb=np.zeros((p, h, w, 3), np.float32), z_depth=z, acc=z,
                        similarity=z, foreground=np.ones((p, h, w), bool), tau=0.5,
                        weights=np.ones((p, h, w), np.float32), prior=z, neighbour=np.zeros((p, h, w, 8), np.float32),
                        empty=empty, intrinsics=Intrinsics(2.0, 2.0, 1.0, 1.0, 2, 2))


@pytest.mark.parametrize("empty, got", [
    (np.zeros((1, 2, 3), bool), r"got \(1, 2, 3\) bool"),         # wrong shape
    (np.zeros((1, 2, 2), np.float32), r"got \(1, 2, 2\) float32"),  # right shape, not bool
])
def test_pseudo_labels_refuse_an_empty_mask_of_another_shape_or_dtype(empty, got):
    # Catches: the shape or the dtype half of PseudoLabels' ``empty`` check dropped.
    with pytest.raises(ValueError, match=r"^empty must be a \(1, 2, 2\) bool array, " + got):
        _labels(empty)
    assert _labels(np.zeros((1, 2, 2), bool)).empty.shape == (1, 2, 2)


@pytest.mark.parametrize("n_known, n_pseudo", [(1, 1), (2, 2), (3, 0)])
def test_estimate_reliability_refuses_renders_of_other_cameras(n_known, n_pseudo):
    # Catches: the ``renders`` count check deleted, or comparing only the known (or only the pseudo) renders.
    scene = SimpleNamespace(intrinsics=K4, intrinsics_all=[K4, K4], c2w=np.stack([np.eye(4)] * 2))
    renders = ({"acc": np.zeros((n_known, 4, 4))}, {"acc": np.zeros((n_pseudo, 4, 4))})
    with pytest.raises(ValueError, match="^renders do not match the known / pseudo cameras$"):
        estimate_reliability(None, None, None, scene, [0, 1], np.eye(4)[None], None, SelfTrainConfig(), 0.15,
                             renders=renders)


# ---------------------------------------------------------------------------------------------------------
# distill.py


@pytest.mark.parametrize("kwargs, message", [
    (dict(batch_reliable=0), "batch_reliable must be an integer >= 1, got 0"),
    (dict(batch_reliable=1.5), "batch_reliable must be an integer >= 1, got 1.5"),
    (dict(batch_prior=True), "batch_prior must be an integer >= 1, got True"),
    (dict(lambda_color=True), "lambda_color must be a finite number >= 0, got True"),
    (dict(batch_prior=0), "batch_prior must be an integer >= 1, got 0"),
    (dict(batch_empty=-1), "batch_empty must be an integer >= 0, got -1"),
    (dict(lambda_color=-1e-6), "lambda_color must be a finite number >= 0, got -1e-06"),
    (dict(lambda_geometry=NAN), "lambda_geometry must be a finite number >= 0, got nan"),
    (dict(lambda_prior=-1e-6), "lambda_prior must be a finite number >= 0, got -1e-06"),
    (dict(lambda_prior=INF), "lambda_prior must be a finite number >= 0, got inf"),
    (dict(kernel_size=3.0), "kernel_size must be an integer >= 3, got 3.0"),
    (dict(kernel_size=4), "kernel_size must be odd and >= 3, got 4"),
    (dict(kernel_std=0.0), "kernel_std must be a finite number > 0, got 0.0"),
    (dict(kernel_std=NAN), "kernel_std must be a finite number > 0, got nan"),
    (dict(kernel_std=INF), "kernel_std must be a finite number > 0, got inf"),
])
def test_distill_config_refuses_each_bad_setting(kwargs, message):
    # Catches: a DistillConfig check deleted or checking one field of a group; before 2026-11-23 a NaN loss weight
    # passed (min() skips NaN) and the loss became NaN at training time, a float kernel_size failed later with a
    # TypeError, and the messages ("batch sizes must be >= 1") named no field.
    with pytest.raises(ValueError, match="^" + re.escape(message)) as info:
        DistillConfig(**kwargs)
    field = message.split(" ")[0]
    assert info.value.field == field
    # the same check reaches the self-training config as an InputError naming the field
    with pytest.raises(InputError, match="^" + re.escape(message.replace(" ", ": ", 1)) + "$") as info:
        SelfTrainConfig(**kwargs)
    assert info.value.field == field


def test_distill_config_accepts_the_boundary_values():
    # Catches: ``< 2`` for ``< 1`` on the batch sizes, ``<= 0`` for ``< 0`` on the weights, ``>= 0`` for ``> 0``.
    cfg = DistillConfig(batch_reliable=1, batch_prior=1, lambda_color=0.0, lambda_geometry=0.0, lambda_prior=0.0,
                        kernel_std=1e-3)
    assert (cfg.batch_reliable, cfg.batch_prior, cfg.lambda_prior, cfg.kernel_std) == (1, 1, 0.0, 1e-3)


@pytest.mark.parametrize("q", [1, 2, 4, -3])
def test_neighbour_offsets_refuses_an_even_or_small_window(q):
    # Catches: the ``q < 3`` or the ``q % 2 == 0`` half of neighbour_offsets' check dropped.
    with pytest.raises(ValueError, match=f"^q must be odd and >= 3, got {q}$"):
        neighbour_offsets(q)
    assert neighbour_offsets(3).shape == (8, 2)


def test_prior_weights_refuses_fewer_than_two_axes():
    # Catches: prior_weights' ``ndim < 2`` check deleted (or raised to ``ndim < 3``, refusing one (H, W) image).
    with pytest.raises(ValueError, match=r"^reliable must be \(\.\.\., H, W\), got \(5,\)$"):
        prior_weights(np.ones(5, bool))
    w, has = prior_weights(np.ones((1, 1), bool))
    assert w.shape == (1, 1, 8) and not has.any()


def test_unified_prior_weights_refuses_mismatched_shapes():
    # Catches: unified_prior_weights' shape check deleted (NumPy would broadcast (2, 3) against (1, 3)).
    with pytest.raises(ValueError, match=r"^similarity \(2, 3\) and foreground \(1, 3\) differ$"):
        unified_prior_weights(np.zeros((2, 3)), np.ones((1, 3), bool))


@pytest.mark.parametrize("reliable_shape, teacher_shape", [
    ((1, 3, 3), (3, 3, 4)),   # reliable not (H, W)
    ((3, 3), (3, 3)),         # teacher not (H, W, S)
    ((3, 3), (3, 2, 4)),      # teacher of another image size
])
def test_gaussian_prior_refuses_bad_shapes(reliable_shape, teacher_shape):
    # Catches: one of gaussian_prior's three shape conditions dropped.
    with pytest.raises(ValueError, match=r"^need reliable \(H, W\) and teacher \(H, W, S\), got "
                                         + re.escape(f"{reliable_shape}, {teacher_shape}")):
        gaussian_prior(np.ones(reliable_shape, bool), np.zeros(teacher_shape))


def _rays(**replace) -> dict:
    """Arguments of a valid PseudoRays of one 2 x 2 view: ray 0 reliable, rays 1 and 2 prior, ray 3 neither."""
    n = 4
    args = dict(origins=torch.zeros(n, 3), dirs=torch.zeros(n, 3), near=torch.zeros(n), far=torch.ones(n),
                shape=(1, 2, 2), reliable=torch.tensor([1.0, 0.0, 0.0, 0.0]),
                prior=torch.tensor([0.0, 1.0, 0.5, 0.0]), neighbour=torch.zeros(n, 8))
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value, message", [
    ("shape", (4, 1), "shape must be (P, H, W), got (4, 1)"),
    ("origins", torch.zeros(4, 2), "origins must be (4, 3), got (4, 2)"),
    ("dirs", torch.zeros(3, 3), "dirs must be (4, 3), got (3, 3)"),
    ("near", torch.zeros(4, 1), "near must be (4,), got (4, 1)"),
    ("far", torch.zeros(5), "far must be (4,), got (5,)"),
    ("reliable", torch.zeros(3), "reliable must be (4,), got (3,)"),
    ("prior", torch.zeros(2, 2), "prior must be (4,), got (2, 2)"),
    ("neighbour", torch.zeros(4, 9), "neighbour must be (4, 8), got (4, 9)"),
])
def test_pseudo_rays_refuse_each_misshapen_tensor(name, value, message):
    # Catches: PseudoRays' ``len(shape) != 3`` check or one entry of its per-tensor shape table deleted.
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        PseudoRays(**_rays(**{name: value}))


def test_pseudo_rays_count_their_reliable_and_prior_rays():
    # Catches: n_reliable / n_prior counting the other pool, every ray, or the rays with weight >= 0.
    pr = PseudoRays(**_rays())
    assert (pr.n_reliable, pr.n_prior) == (1, 2)
    assert PseudoRays(**_rays(shape=(1, 1, 4))).n_prior == 2   # (1, 1, 4) is a valid (P, H, W) too


class _Teacher(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(1))


def test_distillation_loss_refuses_zero_samples_and_accepts_one():
    # Catches: DistillationLoss' ``n_samples < 1`` check deleted or made ``n_samples < 2``.
    pr = PseudoRays(**_rays())
    with pytest.raises(ValueError, match="^n_samples must be >= 1, got 0$"):
        DistillationLoss(_Teacher(), pr, DistillConfig(), 0)
    assert DistillationLoss(_Teacher(), pr, DistillConfig(), 1).n_samples == 1


def test_distillation_loss_refuses_an_unknown_background_when_built():
    # Catches: the constructor's check deleted (before 2026-11-23 'grey' was accepted and refused at the first
    # training step), or the final raise of distill._background deleted (an unknown name would return None).
    from senerf.selftrain.distill import _background

    message = "^background must be one of \\('random', 'white', 'black'\\), got 'grey'$"
    with pytest.raises(ValueError, match=message):
        DistillationLoss(_Teacher(), PseudoRays(**_rays()), DistillConfig(), 4, background="grey")
    with pytest.raises(ValueError, match=message):
        _background("grey", torch.Generator().manual_seed(0), "cpu")
    for kind in ("random", "white", "black"):   # the accepted side
        assert DistillationLoss(_Teacher(), PseudoRays(**_rays()), DistillConfig(), 4, background=kind)


# ---------------------------------------------------------------------------------------------------------
# reliability.py


@pytest.mark.parametrize("image_shape, uv_shape, message", [
    ((4, 4), (2, 2), "image must be (H, W, C), got (4, 4)"),
    ((4, 4, 1, 1), (2, 2), "image must be (H, W, C), got (4, 4, 1, 1)"),
    ((4, 4, 3), (2, 3), "uv must be (N, 2), got (2, 3)"),
    ((4, 4, 3), (2,), "uv must be (N, 2), got (2,)"),
])
def test_bilinear_sample_refuses_bad_shapes(image_shape, uv_shape, message):
    # Catches: bilinear_sample's image or uv shape check deleted (or only one half of the uv check kept).
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        bilinear_sample(np.zeros(image_shape), np.full(uv_shape, 0.5))


def test_cosine_similarity_refuses_shapes_that_would_broadcast():
    # Catches: cosine_similarity's shape check deleted ((3, 4) against (1, 4) would broadcast silently).
    with pytest.raises(ValueError, match=r"^shapes differ: \(3, 4\) vs \(1, 4\)$"):
        cosine_similarity(np.ones((3, 4)), np.ones((1, 4)))


def _similarity_args(**replace) -> dict:
    """A valid view_similarity call: a 4 x 4 pseudo view with C = 2 against k = 2 known 4 x 4 views."""
    args = dict(pseudo_features=np.ones((4, 4, 2)), pseudo_z=np.ones((4, 4)), pseudo_opacity=np.ones((4, 4)),
                pseudo_intrinsics=K4, pseudo_c2w=np.eye(4), known_features=np.ones((2, 4, 4, 2)),
                known_z=np.ones((2, 4, 4)), known_intrinsics=K4, known_c2w=np.stack([np.eye(4)] * 2))
    args.update(replace)
    return args


@pytest.mark.parametrize("name, value, message", [
    ("pseudo_features", np.ones((4, 4)), "pseudo_features must be (H, W, C), got (4, 4)"),
    ("known_z", np.ones((2, 4, 3)), "known_z must be (2, 4, 4), got (2, 4, 3)"),
    ("known_z", np.ones((1, 4, 4)), "known_z must be (2, 4, 4), got (1, 4, 4)"),
    ("known_c2w", np.stack([np.eye(4)] * 3), "known_c2w must be (2, 4, 4), got (3, 4, 4)"),
    ("known_c2w", np.zeros((2, 3, 4)), "known_c2w must be (2, 4, 4), got (2, 3, 4)"),
])
def test_view_similarity_refuses_bad_shapes(name, value, message):
    # Catches: view_similarity's pseudo_features, known_z or known_c2w shape check deleted.
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        view_similarity(**_similarity_args(**{name: value}))


def test_view_similarity_with_no_known_view_matches_nothing():
    # Catches: the ``k == 0`` early return deleted (the warp of zero views fails) or returning another
    # similarity than NO_MATCH there; the foreground is still the pseudo opacity >= the threshold.
    opacity = np.array([[0.0, 0.49, 0.5, 1.0]] * 4)
    out = view_similarity(**_similarity_args(pseudo_opacity=opacity, known_features=np.ones((0, 4, 4, 2)),
                                             known_z=np.ones((0, 4, 4)), known_c2w=np.zeros((0, 4, 4))),
                          opacity_threshold=0.5)
    np.testing.assert_array_equal(out.similarity, np.full((4, 4), NO_MATCH, np.float32))
    assert out.similarity.dtype == np.float32
    assert out.per_view.shape == (0, 4, 4) and out.valid.shape == (0, 4, 4) and out.valid.dtype == bool
    np.testing.assert_array_equal(out.foreground, opacity >= 0.5)


def test_resolve_threshold_refuses_an_unknown_kind():
    # Catches: resolve_threshold's final raise deleted (an unknown kind would act as 'unified', tau None).
    with pytest.raises(ValueError, match=r"^unknown threshold kind 'topk'; choose one of \("):
        resolve_threshold("topk", np.zeros(3))


def test_threshold_weights_refuses_mismatched_shapes():
    # Catches: threshold_weights' shape check deleted ((2, 2) against (1, 2) would broadcast).
    with pytest.raises(ValueError, match=r"^similarity \(2, 2\) and foreground \(1, 2\) differ in shape$"):
        threshold_weights(np.zeros((2, 2)), np.ones((1, 2), bool), "fixed", tau=0.5)


@pytest.mark.parametrize("a_shape, b_shape", [((2, 2, 3), (2, 1, 3)), ((2, 2, 4), (2, 2, 4))])
def test_gt_reliable_mask_refuses_bad_shapes(a_shape, b_shape):
    # Catches: either half of gt_reliable_mask's check (equal shapes, last axis 3) dropped.
    with pytest.raises(ValueError, match="^" + re.escape(f"teacher_rgb {a_shape} and gt_rgb {b_shape} must match")):
        gt_reliable_mask(np.zeros(a_shape), np.zeros(b_shape))


def test_mask_quality_refuses_mismatched_shapes():
    # Catches: mask_quality's shape check deleted ((3,) against (1,) would broadcast).
    with pytest.raises(ValueError, match=r"^predicted \(3,\) and truth \(1,\) differ in shape$"):
        mask_quality(np.ones(3, bool), np.ones(1, bool))


# ---------------------------------------------------------------------------------------------------------
# features.py


@pytest.mark.parametrize("shape", [(0, 4, 4, 3), (1, 0, 4, 3), (1, 4, 0, 3)])
def test_feature_extractor_refuses_empty_images(shape):
    # Catches: the non-empty check of features._check_images deleted, or one of its three axes left out.
    with pytest.raises(ValueError, match="^" + re.escape(f"images must be non-empty, got {shape}") + "$"):
        DaisyFeatures()(np.zeros(shape, np.float32))


def test_feature_extractor_accepts_a_one_pixel_image():
    # Catches: the non-empty check made ``< 2`` (refusing a 1 x 1 image) instead of ``< 1``.
    d = DaisyFeatures(q_radius=1, q_theta=1, q_hist=1)
    assert d(np.zeros((1, 1, 1, 3), np.float32)).shape == (1, 1, 1, 2)


def test_lazy_view_features_refuses_a_shape_without_four_axes():
    # Catches: LazyViewFeatures' ``len(shape) != 4`` check deleted.
    with pytest.raises(ValueError, match=r"^shape must be \(n, H, W, C\), got \(2, 4, 4\)$"):
        LazyViewFeatures(lambda j: np.zeros((4, 4, 1), np.float32), (2, 4, 4))


def test_vgg_refuses_a_chunk_below_one():
    # Catches: VGG19Features' ``chunk < 1`` check deleted (a 0 chunk would loop forever or skip every image).
    with pytest.raises(ValueError, match="^chunk must be >= 1, got 0$"):
        VGG19Features(chunk=0, weights="random")


@pytest.mark.parametrize("kwargs, message", [
    (dict(radius=0.0), "radius must be > 0, got 0.0"), (dict(radius=-1.0), "radius must be > 0, got -1.0"),
    (dict(radius=NAN), "radius must be > 0, got nan"), (dict(q_radius=0), "q_radius must be >= 1, got 0"),
    (dict(q_theta=0), "q_theta must be >= 1, got 0"), (dict(q_hist=0), "q_hist must be >= 1, got 0")])
def test_daisy_refuses_a_non_positive_parameter(kwargs, message):
    # Catches: any one of DaisyFeatures' four positivity checks dropped, or the message not naming the parameter
    # (before 2026-11-23: "DAISY parameters must be positive", and a NaN radius passed).
    with pytest.raises(ValueError, match="^DAISY " + re.escape(message) + "$"):
        DaisyFeatures(**kwargs)


def test_daisy_accepts_the_smallest_parameters():
    # Catches: ``<= 1`` for ``< 1`` in DaisyFeatures' checks; channels = (q_radius q_theta + 1) q_hist.
    assert DaisyFeatures(radius=1e-3, q_radius=1, q_theta=1, q_hist=1).channels == 2
