"""Tests of senerf.selftrain.labels: the pseudo cameras (checked against the geometry of the inputs), the labels of
estimate_reliability on canned similarities (thresholds and priors written out by hand) and on a tiny teacher, the
held-out views and the mask quality counted by hand, the pseudo rays checked by projecting them, the pseudo-view PNGs."""

from __future__ import annotations

import ast
import dataclasses
import math
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import senerf.geometry
import senerf.selftrain.labels as labels_mod
from senerf.config import ModelConfig, SelfTrainConfig
from senerf.errors import InputError
from senerf.selftrain.distill import neighbour_offsets
from senerf.selftrain.labels import (PseudoLabels, dataset_pseudo_views, estimate_reliability, known_images,
                                     labels_text, pseudo_rays, pseudo_view_centre_problem, reliability_mask_quality,
                                     sample_pseudo_cameras, write_pseudo_pngs)
from senerf.selftrain.reliability import ViewSimilarity

SELFTRAIN = Path(labels_mod.__file__).parent
CAMERA_WORDS = ("project", "pixel_rays", "rays_from_pixels", "pose", "look_at", "invert", "rigid",
                "intrinsics", "spherical", "pseudo_views", "opengl", "opencv", "warp", "camera", "ndc")
# the trainer's whole-camera rendering / ray building (documented in DESIGN.md): they call senerf.geometry
TRAINER_CAMERA_API = {("..train", "camera_rays")}


def _imports(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            mod = ("." * node.level) + (node.module or "")
            for alias in node.names:
                yield mod, alias.name
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, alias.name


@pytest.mark.parametrize("name", ["labels.py", "loop.py", "reliability.py"])
def test_cameras_only_through_geometry(name):
    """Camera-like names come from senerf.geometry only; no matrix products or inverses of our own."""
    tree = ast.parse((SELFTRAIN / name).read_text())
    for mod, imported in _imports(tree):
        if any(w in imported.lower() for w in CAMERA_WORDS) and (mod, imported) not in TRAINER_CAMERA_API:
            # (the loop takes its cameras from .labels, itself held to this rule)
            assert mod in ("..geometry", "senerf.geometry", ".labels"), f"{name}: {imported} imported from {mod}"
        assert "cv2" not in mod and "kornia" not in mod, f"{name} imports {mod}"
    for node in ast.walk(tree):
        assert not (isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult)), f"{name} multiplies matrices"
        if isinstance(node, ast.Attribute):
            assert node.attr not in ("inv", "pinv", "solve", "K", "fx", "fy", "cx", "cy"), \
                f"{name} does its own camera math ({node.attr})"
    # every geometry function the module calls is a public name of senerf.geometry
    used = {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)
            and isinstance(n.value, ast.Name) and n.value.id == "geometry"}
    assert used <= set(senerf.geometry.__all__)


# ---------------------------------------------------------------------------------------------------------
# Pseudo cameras


def _orbit_scene(azimuths_deg, elevation_deg=0.0, intrinsics=None):
    """A stand-in scene with cameras at distance 4 looking at the origin (z up)."""
    c2w = np.stack([senerf.geometry.pose_from_spherical(a, elevation_deg, 4.0) for a in azimuths_deg])
    k = intrinsics or senerf.geometry.Intrinsics.from_fov(60.0, 8, 6)
    return SimpleNamespace(c2w=c2w, intrinsics=k, intrinsics_all=(k,) * len(azimuths_deg))


def test_pseudo_cameras_keep_their_source_views_intrinsics():
    """Each pseudo view is its source input carried rigidly (source ``k % m``), so it keeps that input's K."""
    k0 = senerf.geometry.Intrinsics.from_fov(60.0, 8, 6)
    k1 = senerf.geometry.Intrinsics.from_fov(40.0, 8, 6)
    cfg = SelfTrainConfig(n_pseudo_per_input=3)
    scene = _orbit_scene([0.0, 30.0, 60.0], 20.0)
    scene.intrinsics_all = (k0, k1, k0)
    c2w, intr = sample_pseudo_cameras(scene, [1, 2], cfg, 1)
    assert c2w.shape == (6, 4, 4) and c2w.dtype == np.float64
    assert intr == (k1, k0, k1, k0, k1, k0)
    scene.intrinsics_all = (k1, k1, k1)
    same_c2w, same = sample_pseudo_cameras(scene, [1, 2], cfg, 1)
    assert same == (k1,) * 6 and np.array_equal(same_c2w, c2w)


def test_pseudo_cameras_turn_about_the_inputs_centre_within_the_iterations_range():
    scene = _orbit_scene([0.0, 40.0, 80.0], 20.0)
    train_idx = [0, 1, 2]
    at_zero, _ = sample_pseudo_cameras(scene, train_idx, SelfTrainConfig(n_pseudo_per_input=2, pseudo_range_deg=0.0),
                                       1)
    np.testing.assert_allclose(at_zero, scene.c2w[[0, 1, 2, 0, 1, 2]], atol=1e-9)   # offset 0: the inputs
    cfg = SelfTrainConfig(n_pseudo_per_input=20, seed=3)
    centre = senerf.geometry.closest_point_to_axes(scene.c2w)
    np.testing.assert_allclose(centre, 0.0, atol=1e-9)                                # the cameras look at the origin
    for k in (1, 2):
        c2w, _ = sample_pseudo_cameras(scene, train_idx, cfg, k)
        source = scene.c2w[np.arange(60) % 3]
        eye, src_eye = c2w[:, :3, 3], source[:, :3, 3]
        np.testing.assert_allclose(np.linalg.norm(eye, axis=1), 4.0, rtol=1e-9)      # the same distance
        cos = np.sum(eye * src_eye, axis=1) / 16.0
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        # azimuth and elevation each move by at most pseudo_range(k): at most twice that along the sphere
        assert angle.max() <= 2 * cfg.pseudo_range(k) + 1e-6 and angle.max() > 0.5 * cfg.pseudo_range(k)
        # each still looks at the centre: its optical axis (+z, OpenCV) points from its eye to the origin
        np.testing.assert_allclose(c2w[:, :3, 2], -eye / 4.0, atol=1e-9)
    again, _ = sample_pseudo_cameras(scene, train_idx, cfg, 1)
    np.testing.assert_array_equal(again, sample_pseudo_cameras(scene, train_idx, cfg, 1)[0])   # seeded by (seed, K)
    assert not np.allclose(again, sample_pseudo_cameras(scene, train_idx, cfg, 2)[0])


def test_pseudo_view_centre_problem_names_views_without_a_centre():
    eyes = np.array([[4.0, 0.0, 1.0], [0.0, 4.0, 1.0], [-4.0, 0.0, 1.0]])
    converging = SimpleNamespace(c2w=senerf.geometry.look_at(eyes, np.zeros(3)))
    assert pseudo_view_centre_problem(converging, [0, 1, 2]) is None
    assert "1 training view" in pseudo_view_centre_problem(converging, [1])
    shifted = np.repeat(senerf.geometry.look_at(eyes[:1], np.zeros(3)), 2, axis=0)
    shifted[1, :3, 3] += shifted[1, :3, 0]   # the same camera moved sideways: parallel axes
    assert "parallel" in pseudo_view_centre_problem(SimpleNamespace(c2w=shifted), [0, 1])
    # axes that meet, but image-up axes that cancel (one camera upside down, both level): no up axis to turn about
    level = senerf.geometry.look_at(np.array([[4.0, 0.0, 0.0], [0.0, 4.0, 0.0]]), np.zeros(3)).copy()
    level[1, :3, :2] *= -1.0
    text = pseudo_view_centre_problem(SimpleNamespace(c2w=level), [0, 1])
    assert text is not None and "2 training views" in text
    with pytest.raises(ValueError):       # and the sampler indeed refuses them
        sample_pseudo_cameras(SimpleNamespace(c2w=level, intrinsics_all=(None, None)), [0, 1], SelfTrainConfig(), 1)


# ---------------------------------------------------------------------------------------------------------
# estimate_reliability on canned similarities (renders handed in, view_similarity replaced)


def _canned_labels(monkeypatch, sims, acc, cfg, alpha, model=ModelConfig()):
    """``estimate_reliability`` on ``P`` pseudo views whose per-pixel similarity is ``sims (P, H, W)`` and
    teacher opacity ``acc (P, H, W)`` (foreground: ``acc >= cfg.opacity_threshold``); no rendering, no
    features: the renders are handed in and ``view_similarity`` returns the canned values view by view."""
    p, h, w = sims.shape
    acc = np.asarray(acc, np.float32)
    calls = iter(range(p))

    def canned_similarity(feats, z, opacity, *args, opacity_threshold, **kwargs):
        i = next(calls)
        assert np.array_equal(opacity, acc[i])
        return ViewSimilarity(sims[i].astype(np.float32), np.zeros((1, h, w), np.float32),
                              np.zeros((1, h, w), bool), np.asarray(opacity) >= opacity_threshold)

    monkeypatch.setattr(labels_mod, "view_similarity", canned_similarity)
    k = senerf.geometry.Intrinsics.from_fov(60.0, w, h)
    scene = SimpleNamespace(intrinsics=k, intrinsics_all=(k,), c2w=np.eye(4)[None])
    known = dict(acc=np.ones((1, h, w), np.float32), z_depth=np.ones((1, h, w), np.float32))
    pseudo = dict(acc=acc, z_depth=np.ones((p, h, w), np.float32), rgb=np.zeros((p, h, w, 3), np.float32))
    extractor = lambda images: np.zeros((images.shape[0], h, w, 2), np.float32)  # noqa: E731
    return estimate_reliability(None, None, model, scene, [0], np.stack([np.eye(4)] * p), extractor, cfg, alpha,
                                known_features=np.zeros((1, h, w, 2), np.float32), renders=(known, pseudo))


def _quantile_by_sorting(values: np.ndarray, q: float) -> float:
    """The linear-interpolation quantile written out: position q (n - 1) in the sorted sample."""
    v = np.sort(values.reshape(-1))
    pos = q * (v.size - 1)
    lo = int(math.floor(pos))
    hi = min(lo + 1, v.size - 1)
    return float(v[lo] + (pos - lo) * (v[hi] - v[lo]))


def _has_neighbour(ok: np.ndarray, y: int, x: int) -> bool:
    """Whether any pixel of the 3 x 3 window around (y, x), centre excluded, inside the image satisfies ``ok``."""
    h, w = ok.shape
    return any(ok[y + dy, x + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)
               if (dy, dx) != (0, 0) and 0 <= y + dy < h and 0 <= x + dx < w)


def test_adaptive_labels_threshold_on_foreground_and_prior_on_foreground_only(monkeypatch):
    """Catches the adaptive threshold taken over all pixels (background included) instead of the foreground
    ones, and the prior given to background pixels next to reliable ones."""
    rng = np.random.default_rng(11)
    sims = rng.uniform(0.0, 0.9, size=(2, 6, 7))
    acc = np.full((2, 6, 7), 0.9)
    acc[:, :, :3] = 0.3            # the left three columns background, with a bright similarity
    sims[:, :, :3] = 0.99
    fg = acc >= 0.5
    labels = _canned_labels(monkeypatch, sims, acc, SelfTrainConfig(threshold="adaptive", empty_opacity=0.0),
                            alpha=0.25)
    tau = _quantile_by_sorting(sims[fg], 0.75)
    assert labels.tau == pytest.approx(tau, rel=1e-6)
    assert _quantile_by_sorting(sims, 0.75) > tau + 0.05       # the bright background would move it
    np.testing.assert_array_equal(labels.foreground, fg)
    reliable = fg & (sims > tau)
    np.testing.assert_array_equal(labels.weights, reliable.astype(np.float32))
    expected_prior = np.zeros_like(fg)
    for v, y, x in np.ndindex(*fg.shape):
        expected_prior[v, y, x] = fg[v, y, x] and not reliable[v, y, x] and _has_neighbour(reliable[v], y, x)
    np.testing.assert_array_equal(labels.prior, expected_prior.astype(np.float32))
    assert any(_has_neighbour(reliable[v], y, x) for v, y, x in zip(*np.nonzero(~fg)))   # the case arises
    assert labels.reliable_fraction == pytest.approx(reliable[fg].mean())


def test_the_prior_comes_from_reliable_surface_neighbours_never_from_empty_space(monkeypatch):
    """Empty-space pixels are reliable (distilled as empty rays) but are no neighbours of the prior: catches an
    object's unreliable edge pixels pulled towards the empty rays beside them (which erased mic's cable)."""
    rng = np.random.default_rng(7)
    sims = rng.uniform(0.0, 0.9, size=(2, 6, 7))
    acc = np.full((2, 6, 7), 0.9)
    acc[:, :, :2] = 0.05           # the left two columns empty space (below empty_opacity 0.2)
    sims[0, 0:3, 2:4] = 0.0        # view 0, rows 0-2: dissimilar edge pixels, (1, 2) with no reliable surface near
    labels = _canned_labels(monkeypatch, sims, acc, SelfTrainConfig(threshold="adaptive", empty_opacity=0.2),
                            alpha=0.25)
    fg, empty = acc >= 0.5, acc < 0.2
    surface = fg & (sims > labels.tau)
    np.testing.assert_array_equal(labels.weights, (surface | empty).astype(np.float32))
    expected_prior = np.zeros_like(fg)
    for v, y, x in np.ndindex(*fg.shape):
        expected_prior[v, y, x] = fg[v, y, x] and not surface[v, y, x] and _has_neighbour(surface[v], y, x)
    np.testing.assert_array_equal(labels.prior, expected_prior.astype(np.float32))
    assert not surface[0, 1, 2] and labels.prior[0, 1, 2] == 0    # its reliable neighbours are all empty space
    offsets = neighbour_offsets(3)
    for v, y, x in zip(*np.nonzero(labels.prior)):
        on_empty = [i for i, (dy, dx) in enumerate(offsets) if 0 <= y + dy < 6 and 0 <= x + dx < 7
                    and empty[v, y + dy, x + dx]]
        assert not labels.neighbour[v, y, x, on_empty].any()
        assert labels.neighbour[v, y, x].sum() == pytest.approx(1.0)


def test_unbounded_labels_count_every_pixel_and_label_no_empty_space(monkeypatch):
    """An unbounded scene has content in every pixel: a dim (low-opacity) teacher pixel is scored and thresholded
    like any other, never left out as background nor labelled reliable empty space (catches the object-scene
    opacity rules applied to a real capture)."""
    rng = np.random.default_rng(3)
    sims = rng.uniform(0.0, 0.9, size=(2, 6, 7))
    acc = np.full((2, 6, 7), 0.9)
    acc[:, :, :3] = 0.05           # below both the foreground and the empty-space opacity of an object scene
    unbounded = ModelConfig(contract=True, near=0.1, far=100.0)
    labels = _canned_labels(monkeypatch, sims, acc, SelfTrainConfig(threshold="adaptive"), 0.25, unbounded)
    assert labels.foreground.all() and not labels.empty.any()
    assert labels.tau == pytest.approx(_quantile_by_sorting(sims, 0.75), rel=1e-6)
    np.testing.assert_array_equal(labels.weights, (sims > labels.tau).astype(np.float32))
    as_object = _canned_labels(monkeypatch, sims, acc, SelfTrainConfig(threshold="adaptive"), 0.25)
    assert as_object.empty[:, :, :3].all() and not as_object.foreground[:, :, :3].any()   # the rules differ


def test_unified_labels_soft_weights_and_prior_one_minus_weight(monkeypatch):
    """Weights are ``sigmoid(beta (s - 0.7))`` on the foreground; the prior weight is ``1 - weight`` where a more
    similar foreground neighbour exists (catches ``weights`` for ``1 - weights``, a prior on the background)."""
    rng = np.random.default_rng(5)
    sims = rng.uniform(0.4, 1.0, size=(2, 5, 6))
    acc = np.full((2, 5, 6), 0.9)
    acc[0, :, 0] = acc[1, 4, :] = 0.3            # background: a column of view 0, a row of view 1
    sims[acc < 0.5] = 0.1                         # dim background: its foreground neighbours are more similar
    fg = acc >= 0.5
    labels = _canned_labels(monkeypatch, sims, acc, SelfTrainConfig(threshold="unified", beta=16.0,
                                                                    empty_opacity=0.0), alpha=0.25)
    assert labels.tau is None
    weights = np.where(fg, 1.0 / (1.0 + np.exp(-16.0 * (sims - 0.7))), 0.0)
    np.testing.assert_allclose(labels.weights, weights, rtol=1e-6, atol=1e-7)
    expected = np.zeros(fg.shape)
    for v, y, x in np.ndindex(*fg.shape):
        if fg[v, y, x] and _has_neighbour(fg[v] & (sims[v] > sims[v, y, x]), y, x):
            expected[v, y, x] = 1.0 - weights[v, y, x]
    assert np.count_nonzero(expected) > 20
    np.testing.assert_allclose(labels.prior, expected, rtol=1e-6, atol=1e-7)


def test_known_views_are_rendered_and_warped_into_with_their_own_intrinsics(monkeypatch):
    """Per-frame intrinsics: the known views get their own K (equal ones as well); the pseudo views get the K
    given for them (default image 0's); only the foreground is scored."""
    h, w = 4, 5
    k0 = senerf.geometry.Intrinsics.from_fov(60.0, w, h)
    k1 = senerf.geometry.Intrinsics.from_fov(45.0, w, h)
    seen: dict = {}

    def fake_render(teacher, model, intrinsics, c2w, **kwargs):
        seen.setdefault("render", []).append(intrinsics)
        n = np.asarray(c2w).reshape(-1, 4, 4).shape[0]
        return dict(rgb=np.zeros((n, h, w, 3), np.float32), z_depth=np.ones((n, h, w), np.float32),
                    acc=np.ones((n, h, w), np.float32))

    def fake_similarity(feats, z, opacity, pseudo_k, pseudo_c2w, known_f, known_z, known_k, known_c2w, **kw):
        seen["pseudo_k"], seen["known_k"], seen["foreground_only"] = pseudo_k, known_k, kw.get("foreground_only")
        return ViewSimilarity(np.zeros((h, w), np.float32), np.zeros((2, h, w), np.float32),
                              np.zeros((2, h, w), bool), np.ones((h, w), bool))

    monkeypatch.setattr(labels_mod, "render_views", fake_render)
    monkeypatch.setattr(labels_mod, "view_similarity", fake_similarity)
    extractor = lambda images: np.zeros((images.shape[0], h, w, 2), np.float32)  # noqa: E731
    for known, expect in (((k0, k1, k0), [k1, k0]), ((k0, k0, k0), [k0, k0])):
        seen.clear()
        scene = SimpleNamespace(intrinsics=k0, intrinsics_all=known, c2w=np.stack([np.eye(4)] * 3))
        labels = estimate_reliability(None, None, ModelConfig(), scene, [1, 2], np.stack([np.eye(4)] * 2), extractor,
                                      SelfTrainConfig(), 0.15, known_features=np.zeros((2, h, w, 2), np.float32))
        assert seen["render"] == [expect, k0, k0]      # the known views, then the pseudo views one at a time
        assert seen["known_k"] == expect and seen["pseudo_k"] == k0 and labels.intrinsics == k0
        assert seen["foreground_only"] is True


@pytest.mark.parametrize("n_known, n_pseudo", [(1, 1), (2, 2), (3, 0)])
def test_renders_of_other_cameras_are_refused(n_known, n_pseudo):
    k = senerf.geometry.Intrinsics(4.0, 4.0, 2.0, 2.0, 4, 4)
    scene = SimpleNamespace(intrinsics=k, intrinsics_all=[k, k], c2w=np.stack([np.eye(4)] * 2))
    renders = ({"acc": np.zeros((n_known, 4, 4))}, {"acc": np.zeros((n_pseudo, 4, 4))})
    with pytest.raises(ValueError, match="renders"):
        estimate_reliability(None, None, None, scene, [0, 1], np.eye(4)[None], None, SelfTrainConfig(), 0.15,
                             renders=renders)


def _labels(p=1, h=2, w=2, weights=None, prior=None, foreground=None, empty=None, similarity=None, tau=0.5):
    """Hand-made PseudoLabels of ``p`` views of ``h x w`` looking at the origin from distance 4."""
    ones = np.ones((p, h, w), np.float32)
    weights = ones if weights is None else np.asarray(weights, np.float32)
    c2w = np.stack([senerf.geometry.pose_from_spherical(30.0 * i, 20.0, 4.0) for i in range(p)])
    return PseudoLabels(c2w=c2w, rgb=np.full((p, h, w, 3), 0.25, np.float32), z_depth=4 * ones, acc=ones,
                        similarity=ones * 0.5 if similarity is None else similarity,
                        foreground=np.ones((p, h, w), bool) if foreground is None else foreground, tau=tau,
                        weights=weights, prior=0 * ones if prior is None else np.asarray(prior, np.float32),
                        neighbour=np.zeros((p, h, w, 8), np.float32),
                        empty=np.zeros((p, h, w), bool) if empty is None else empty,
                        intrinsics=senerf.geometry.Intrinsics.from_fov(30.0, w, h))


@pytest.mark.parametrize("empty", [np.zeros((1, 2, 3), bool), np.zeros((1, 2, 2), np.float32)],
                         ids=["other-shape", "not-bool"])
def test_pseudo_labels_refuse_an_empty_mask_of_another_shape_or_dtype(empty):
    with pytest.raises(ValueError, match="empty"):
        _labels(empty=empty)


def test_pseudo_labels_refuse_empty_pixels_that_are_not_reliable():
    with pytest.raises(ValueError, match="reliable"):
        _labels(weights=np.array([[[1.0, 0.0], [1.0, 1.0]]]), empty=np.array([[[False, True], [False, False]]]))


# ---------------------------------------------------------------------------------------------------------
# estimate_reliability with a tiny teacher


def test_each_pseudo_view_is_rendered_with_its_own_intrinsics(tiny_scene, tiny_teacher, vgg):
    from senerf.train import render_views

    train_idx, model, res = tiny_teacher
    c2w, ks = sample_pseudo_cameras(tiny_scene, train_idx, SelfTrainConfig(n_pseudo_per_input=1), 1)
    k = ks[1]
    ks = (ks[0], senerf.geometry.Intrinsics(k.fx * 1.2, k.fy * 1.2, k.cx, k.cy, k.width, k.height), ks[2])
    labels = estimate_reliability(res.field, res.occupancy, model, tiny_scene, train_idx, c2w[:2],
                                  vgg, SelfTrainConfig(), 0.15, pseudo_intrinsics=ks[:2])
    own = render_views(res.field, model, ks[1], c2w[1], occupancy=res.occupancy)
    np.testing.assert_array_equal(labels.rgb[1], own["rgb"][0])
    other = render_views(res.field, model, ks[0], c2w[1], occupancy=res.occupancy)
    assert not np.array_equal(labels.rgb[1], other["rgb"][0])


def test_empty_space_pixels_become_reliable_and_reach_the_pseudo_rays(tiny_scene, tiny_teacher, vgg):
    """With ``empty_opacity`` the teacher's low-opacity pseudo pixels are reliable empty rays (reliable weight 1
    among the pseudo rays); 0 = off."""
    train_idx, model, res = tiny_teacher
    pseudo_c2w = np.asarray(tiny_scene.c2w[tiny_scene.splits["test"]], dtype=np.float64)
    out = {e: estimate_reliability(res.field, res.occupancy, model, tiny_scene, train_idx, pseudo_c2w, vgg,
                                   SelfTrainConfig(empty_opacity=e, opacity_threshold=0.7), 0.15)
           for e in (0.0, 0.6)}
    low = out[0.6].acc < 0.6
    assert low.any() and (~low).any()
    assert np.all(out[0.6].weights[low] == 1.0)
    np.testing.assert_array_equal(out[0.6].weights[~low], out[0.0].weights[~low])
    assert np.all(out[0.0].weights[~out[0.0].foreground] == 0.0)
    np.testing.assert_array_equal(out[0.6].empty, low)
    assert not out[0.0].empty.any()
    assert np.all(pseudo_rays(out[0.6], model, "cpu", 3).reliable.numpy()[low.reshape(-1)] == 1.0)


# ---------------------------------------------------------------------------------------------------------
# Held-out views and the mask quality


def test_dataset_pseudo_views_are_the_nearest_held_out_views_within_range():
    # views 0 (0 deg) and 1 (90 deg) known, 2 (5 deg) is a test view; held out: 3 (8), 4 (30), 5 (95), 6 (180)
    scene = _orbit_scene([0, 90, 5, 8, 30, 95, 180])
    assert dataset_pseudo_views(scene, [0, 1], [2], max_angle_deg=10.0, count=4).tolist() == [5, 3]
    # fewer than count // 2 inside the range: the nearest count // 2 regardless
    assert dataset_pseudo_views(scene, [0, 1], [2], max_angle_deg=1.0, count=6).tolist() == [5, 3, 4]
    with pytest.raises(InputError):
        dataset_pseudo_views(scene, [0, 1], [2, 3, 4, 5, 6], 10.0, 4)


H, W = 2, 3

# Two held-out views (scene indices 3 and 1, in that order) of 2 x 3 pixels, each pixel given as
# (teacher opacity, similarity, teacher colour, ground-truth colour).  Opacity 0.1 is background (below the
# opacity threshold 0.5: not counted).  'unified' weights are sigmoid(16 (s - 0.7)): reliable (> 0.5) iff s > 0.7,
# so 0.72 is (weight 0.58) and 0.68 is not (0.42).  Ground truth: mean |clip(teacher) - gt| < 0.1.
_VIEW_3 = [[(0.9, 0.90, 0.55, 0.5),    # predicted, right (err 0.05)          -> TP
            (0.9, 0.72, 0.80, 0.5),    # predicted (0.58), wrong (err 0.3)     -> FP
            (0.9, 0.68, 0.55, 0.5)],   # not predicted (0.42), right          -> FN
           [(0.9, 0.20, 0.80, 0.5),    # not predicted, wrong                  -> TN
            (0.1, 0.90, 0.55, 0.5),    # background: not counted
            (0.9, 0.95, 1.20, 1.0)]]   # predicted, right once clipped to 1    -> TP
_VIEW_1 = [[(0.9, 0.85, 0.80, 0.5),    # predicted, wrong                      -> FP
            (0.9, 0.10, 0.55, 0.5),    # not predicted, right                  -> FN
            (0.9, 0.30, 0.00, 0.5)],   # not predicted, wrong                  -> TN
           [(0.9, 0.99, 0.50, 0.5),    # predicted, right                      -> TP
            (0.1, 0.20, 0.80, 0.5),    # background: not counted
            (0.9, 0.80, 0.70, 0.5)]]   # predicted, wrong (err 0.2)            -> FP
# by hand: TP 3, FP 3, FN 2, TN 2 over 10 foreground pixels
EXPECTED = dict(tp=3, fp=3, fn=2, tn=2, precision=3 / 6, recall=3 / 5, fpr=3 / 5, gt_reliable_rate=5 / 10,
                predicted_reliable_rate=6 / 10)


def _canned_quality(monkeypatch, eval_idx=(3, 1), train_idx=(0, 2)):
    """``reliability_mask_quality`` on a 5-view stand-in scene whose held-out views 3 and 1 are ``_VIEW_3`` and
    ``_VIEW_1``: renders handed in, ``view_similarity`` returning the canned similarities view by view."""
    views = np.array([_VIEW_3, _VIEW_1], np.float32)            # (2, H, W, 4)
    acc, sims, teacher, truth = (views[..., j] for j in range(4))
    calls = iter(range(2))

    def canned_similarity(feats, z, opacity, *args, opacity_threshold, **kwargs):
        return ViewSimilarity(sims[next(calls)], np.zeros((1, H, W), np.float32), np.zeros((1, H, W), bool),
                              np.asarray(opacity) >= opacity_threshold)

    monkeypatch.setattr(labels_mod, "view_similarity", canned_similarity)
    ks = tuple(senerf.geometry.Intrinsics.from_fov(f, W, H) for f in (40.0, 45.0, 50.0, 55.0, 60.0))
    c2w = np.stack([np.eye(4)] * 5)
    c2w[:, 0, 3] = np.arange(5.0)                                # tells the views apart
    rgb = np.random.default_rng(0).uniform(0.0, 1.0, (5, H, W, 3)).astype(np.float32)   # the known views: noise
    rgb[3], rgb[1] = truth[0, ..., None], truth[1, ..., None]
    scene = SimpleNamespace(intrinsics=ks[0], intrinsics_all=ks, c2w=c2w, rgb=rgb, alpha=None)
    m = len(train_idx)
    known = dict(acc=np.ones((m, H, W), np.float32), z_depth=np.ones((m, H, W), np.float32))
    pseudo = dict(acc=acc, z_depth=np.ones((2, H, W), np.float32), rgb=np.repeat(teacher[..., None], 3, axis=-1))
    cfg = SelfTrainConfig(threshold="unified", beta=16.0, empty_opacity=0.0)
    extractor = lambda images: np.zeros((images.shape[0], H, W, 2), np.float32)  # noqa: E731
    return reliability_mask_quality(None, None, ModelConfig(), scene, list(train_idx), eval_idx, extractor, cfg, 0.15,
                                    max_error=0.1, known_features=np.zeros((m, H, W, 2), np.float32),
                                    renders=(known, pseudo)), scene


def test_mask_quality_counts_a_case_known_by_hand(monkeypatch):
    # Catches: 'unified' weights counted reliable above 0 instead of 0.5, the teacher colour not clipped before the
    # ground-truth comparison, background pixels counted, predicted and truth swapped, the ground truth taken from
    # other views than eval_idx (or in another order), the rates computed over all pixels.
    (quality, labels), scene = _canned_quality(monkeypatch)
    for key, value in EXPECTED.items():
        assert quality[key] == pytest.approx(value, abs=1e-12), key
    # the labels are those of the held-out cameras, each with its own intrinsics
    np.testing.assert_array_equal(labels.c2w, scene.c2w[[3, 1]])
    assert labels.intrinsics == (scene.intrinsics_all[3], scene.intrinsics_all[1])


def test_mask_quality_refuses_known_views_as_held_out_views(monkeypatch):
    for eval_idx in ([3, 2], 2, [0]):
        with pytest.raises(ValueError, match="eval_idx"):
            _canned_quality(monkeypatch, eval_idx=eval_idx)
    _canned_quality(monkeypatch, eval_idx=[3, 1], train_idx=[0, 4])   # disjoint: accepted


def test_mask_quality_on_a_tiny_teacher_matches_a_count_from_its_labels(tiny_scene, tiny_teacher, vgg):
    # Catches: the real path (teacher renders and VGG-19 features of the held-out views) scoring other pixels than
    # its labels: the RGBA ground truth composited on another colour than the teacher's white, weights > 0 as the
    # predicted mask, the rates over the background.
    scene = tiny_scene
    train_idx, model, res = tiny_teacher
    held = np.setdiff1d(np.arange(scene.n_images), train_idx)   # the three views not known
    assert scene.alpha is not None and model.eval_background == "white"
    cfg = SelfTrainConfig(threshold="unified", empty_opacity=0.0, opacity_threshold=0.3)
    quality, labels = reliability_mask_quality(res.field, res.occupancy, model, scene, train_idx, held, vgg, cfg,
                                               0.15, max_error=0.3)
    a = scene.alpha[held][..., None]
    gt = scene.rgb[held] * a + (1.0 - a)                       # straight colour on white, written out
    truth = np.abs(np.clip(labels.rgb, 0, 1) - gt).mean(-1) < 0.3
    pred, fg = labels.weights > 0.5, labels.foreground
    counts = dict(tp=int(np.sum(pred & truth & fg)), fp=int(np.sum(pred & ~truth & fg)),
                  fn=int(np.sum(~pred & truth & fg)), tn=int(np.sum(~pred & ~truth & fg)))
    assert {k: quality[k] for k in counts} == counts
    assert min(counts.values()) > 0 and fg.sum() < fg.size   # every cell filled, and a background left out
    assert quality["precision"] == pytest.approx(counts["tp"] / (counts["tp"] + counts["fp"]))
    assert quality["recall"] == pytest.approx(counts["tp"] / (counts["tp"] + counts["fn"]))
    assert quality["fpr"] == pytest.approx(counts["fp"] / (counts["fp"] + counts["tn"]))
    assert quality["gt_reliable_rate"] == pytest.approx(truth[fg].mean())
    assert quality["predicted_reliable_rate"] == pytest.approx(pred[fg].mean())
    # soft weights between 0 and 0.5 exist, so the 0.5 cut is what is being counted
    assert np.any(fg & (labels.weights > 0) & (labels.weights <= 0.5))
    np.testing.assert_array_equal(known_images(scene, held, model), gt.astype(np.float32))


# ---------------------------------------------------------------------------------------------------------
# Pseudo rays, PNGs, the labelling line, the features' device


def test_pseudo_rays_pass_through_their_pixel_centres_in_view_row_column_order():
    """Ray ``i = p H W + y W + x`` carries pixel (y, x) of view p's weights and, projected back with that view's
    camera (``senerf.geometry.project``), lands on the pixel centre ``(x + 0.5, y + 0.5)``."""
    p, h, w = 2, 3, 4
    rng = np.random.default_rng(0)
    weights = rng.uniform(0.1, 1.0, (p, h, w)).astype(np.float32)
    prior = rng.uniform(0.0, 1.0, (p, h, w)).astype(np.float32)
    labels = dataclasses.replace(_labels(p, h, w, weights=weights, prior=prior),
                                 neighbour=rng.uniform(size=(p, h, w, 8)).astype(np.float32))
    model = ModelConfig()
    assert model.frame_origin == (0.0, 0.0, 0.0)                 # the model frame is the world frame here
    rays = pseudo_rays(labels, model, "cpu", 3)
    assert rays.shape == (p, h, w) and rays.origins.shape == (p * h * w, 3)
    np.testing.assert_array_equal(rays.reliable.numpy(), weights.reshape(-1))
    np.testing.assert_array_equal(rays.prior.numpy(), prior.reshape(-1))
    np.testing.assert_array_equal(rays.neighbour.numpy(), labels.neighbour.reshape(-1, 8))
    t = ((rays.near + rays.far) / 2).double().numpy()[:, None]
    points = rays.origins.double().numpy() + t * rays.dirs.double().numpy()
    views, ys, xs = np.unravel_index(np.arange(p * h * w), (p, h, w))
    uv, _, ok = senerf.geometry.project(points, labels.intrinsics, labels.c2w[views])
    assert ok.all()
    np.testing.assert_allclose(uv, np.stack([xs + 0.5, ys + 0.5], axis=1), atol=1e-4)


def test_pseudo_pngs_show_the_render_the_similarity_and_the_mask(tmp_path):
    import imageio.v3 as iio

    fg = np.array([[[True, True, True, False]]])
    labels = _labels(1, 1, 4, weights=[[[1.0, 0.0, 0.0, 0.0]]], prior=[[[0.0, 0.7, 0.0, 0.0]]], foreground=fg,
                     similarity=np.array([[[0.9, -1.0, 0.25, 2.0]]], np.float32))
    write_pseudo_pngs(tmp_path, labels)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mask_000.png", "rgb_000.png", "similarity_000.png"]
    read = lambda name: iio.imread(tmp_path / name)[..., :3].astype(float) / 255.0  # noqa: E731
    np.testing.assert_allclose(read("rgb_000.png"), 0.25, atol=1 / 255)
    np.testing.assert_allclose(read("similarity_000.png")[0, :, 0], [0.9, 0.0, 0.25, 1.0], atol=1 / 255)
    # white reliable, blue unreliable with a prior target, black unreliable without one, grey background
    np.testing.assert_allclose(read("mask_000.png")[0], [[1, 1, 1], [0.2, 0.4, 1.0], [0, 0, 0], [0.5, 0.5, 0.5]],
                               atol=1 / 255)


def test_the_labelling_line_without_foreground_and_without_the_prior():
    fg = np.array([[[True, False], [True, True]]])
    labels = _labels(weights=[[[1.0, 0.0], [0.0, 0.0]]], prior=[[[0.0, 0.0], [1.0, 0.0]]], foreground=fg, tau=0.8)
    cfg = SelfTrainConfig()
    text = labels_text(labels, cfg)
    assert "0.800" in text and "33.3 %" in text and "prior on 33.3 %" in text   # reliable 1 of 3, prior 1 of 3
    assert "prior off" in labels_text(labels, dataclasses.replace(cfg, prior=False))
    assert "prior off" in labels_text(labels, dataclasses.replace(cfg, lambda_prior=0.0))
    nothing = dataclasses.replace(labels, foreground=np.zeros_like(fg), weights=np.zeros((1, 2, 2), np.float32),
                                  tau=float("inf"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # no NumPy warning of a mean over nothing
        text = labels_text(nothing, cfg)
    assert "nan" not in text and "inf" not in text
