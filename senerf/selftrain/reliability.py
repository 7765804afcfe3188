"""Ray reliability by feature consistency across views (NumPy; the feature lookups by the compiled kernel of
:func:`senerf.fields.ckernel.fused_feature_similarity` on the CPU where it loads, else in NumPy, or in torch on the
features' device when they are handed over as tensors off the CPU, as a CUDA fit does).

**Background** pseudo pixels (teacher opacity ``< opacity_threshold``), a case the paper leaves open, are neither
reliable nor unreliable here: they do not enter the adaptive threshold's distribution and get no prior target (the
labelling makes the nearly empty ones reliable empty space, ``SelfTrainConfig.empty_opacity``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import geometry
from ..config import THRESHOLD_KINDS

__all__ = ["NO_MATCH", "ViewSimilarity", "bilinear_sample", "bilinear_sample_reference", "cosine_similarity",
           "view_similarity", "adaptive_threshold", "resolve_threshold", "threshold_weights", "gt_reliable_mask",
           "mask_quality"]

NO_MATCH = -1.0


def check_shape(name: str, shape: tuple, want: tuple) -> None:
    """``ValueError`` naming ``name`` unless ``shape`` is ``want`` (``None`` in ``want`` matches any size)."""
    shape = tuple(shape)
    if len(shape) != len(want) or any(w is not None and s != w for s, w in zip(shape, want)):
        text = ", ".join("*" if w is None else str(w) for w in want)
        raise ValueError(f"{name} must be ({text}{',' if len(want) == 1 else ''}), got {shape}")


@dataclass(frozen=True)
class ViewSimilarity:
    """Feature consistency of one pseudo view against the known views.

    Attributes:
        similarity: (H, W) float32, max over valid known views of the cosine similarity; ``NO_MATCH`` where
            no known view sees the pixel.
        per_view: (k, H, W) float32 cosine similarity per known view, ``NO_MATCH`` where invalid.
        valid: (k, H, W) bool, the warp landed in the image, in front of the camera and unoccluded.
        foreground: (H, W) bool, teacher opacity >= the opacity threshold.
    """

    similarity: np.ndarray
    per_view: np.ndarray
    valid: np.ndarray
    foreground: np.ndarray


def _bilinear_corners(h: int, w: int, uv: np.ndarray) -> tuple[np.ndarray, ...]:
    """The four neighbours and weights of each ``uv (N, 2)`` (float64; pixel centres at ``i + 0.5``, clamped to
    the ``h x w`` image): ``(y0, x0, y1, x1)`` int64 ``(N,)`` and ``(fy, fx)`` float32 ``(N, 1)``."""
    x = np.clip(uv[:, 0] - 0.5, 0.0, w - 1.0)
    y = np.clip(uv[:, 1] - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 1)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    return y0, x0, y1, x1, (y - y0).astype(np.float32)[:, None], (x - x0).astype(np.float32)[:, None]


def bilinear_sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with the pixel-centre convention and edge clamping.

    Args:
        image: (H, W, C) array.
        uv: (N, 2) continuous pixel coordinates (u = column, v = row); pixel (i, j)'s centre is
            (i + 0.5, j + 0.5), so ``uv = (0.5, 0.5)`` returns ``image[0, 0]`` exactly.
    Returns:
        (N, C) float32.
    """
    image = np.asarray(image)
    uv = np.asarray(uv, dtype=np.float64)
    check_shape("image", image.shape, (None, None, None))
    check_shape("uv", uv.shape, (None, 2))
    h, w = image.shape[:2]
    y0, x0, y1, x1, fy, fx = _bilinear_corners(h, w, uv)
    # the reference's operations in its order (the same bits), in place on the gathered rows (fewer temporaries)
    flat = image.reshape(h * w, -1)
    dtype = np.result_type(flat.dtype, np.float32)
    top = flat.take(y0 * w + x0, axis=0).astype(dtype, copy=False)
    top *= 1 - fx
    tmp = flat.take(y0 * w + x1, axis=0).astype(dtype, copy=False)
    tmp *= fx
    top += tmp
    bottom = flat.take(y1 * w + x0, axis=0).astype(dtype, copy=False)
    bottom *= 1 - fx
    tmp = flat.take(y1 * w + x1, axis=0).astype(dtype, copy=False)
    tmp *= fx
    bottom += tmp
    top *= 1 - fy
    bottom *= fy
    top += bottom
    return top.astype(np.float32, copy=False)


def bilinear_sample_reference(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """:func:`bilinear_sample`'s interpolation written out with temporaries: the reference the in-place version
    matches bit for bit (tests) and is timed against (``bench_selftrain.py labelling``)."""
    image = np.asarray(image)
    y0, x0, y1, x1, fy, fx = _bilinear_corners(*image.shape[:2], np.asarray(uv, dtype=np.float64))
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def cosine_similarity(a: np.ndarray, b: np.ndarray, eps: float = 1e-8) -> np.ndarray:
    """Cosine similarity along the last axis: ``a (..., C), b (..., C) -> (...)`` float32.

    A zero vector (norm < eps) has similarity 0 with everything.
    """
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)
    check_shape("b", b.shape, a.shape)
    num = np.einsum("...c,...c->...", a, b)
    den = np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1)
    return (num / np.maximum(den, eps)).astype(np.float32)


_SAMPLE_CHUNK = 16384   # pixels per feature lookup in view_similarity (NumPy; 4 times as many in torch)


def _lookup_similarity_torch(src_flat, idx: np.ndarray, features, uv: np.ndarray, eps: float = 1e-8) -> np.ndarray:
    """:func:`bilinear_sample` of ``features (H', W', C)`` (an array or a tensor) at ``uv (N, 2)`` and
    :func:`cosine_similarity` with the rows ``idx (N,)`` of ``src_flat (H W, C)``, in torch on ``src_flat``'s
    device (the same operations; float32 rounding apart, the same values): ``(N,)`` float32 on the host."""
    import torch

    dev = src_flat.device
    rows = torch.from_numpy(idx).to(dev)
    feats = torch.as_tensor(features).to(dev, torch.float32)
    h, w, c = feats.shape
    flat = feats.reshape(h * w, c)
    y0, x0, y1, x1, fy, fx = (torch.from_numpy(np.ascontiguousarray(a)).to(dev)
                              for a in _bilinear_corners(h, w, uv))
    out = torch.empty(uv.shape[0], dtype=torch.float32, device=dev)
    step = 4 * _SAMPLE_CHUNK
    for s in range(0, uv.shape[0], step):
        p = slice(s, s + step)
        top = flat[y0[p] * w + x0[p]] * (1 - fx[p]) + flat[y0[p] * w + x1[p]] * fx[p]
        bottom = flat[y1[p] * w + x0[p]] * (1 - fx[p]) + flat[y1[p] * w + x1[p]] * fx[p]
        b = top * (1 - fy[p]) + bottom * fy[p]
        a = src_flat[rows[p]].to(torch.float32)
        out[p] = (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1)).clamp_min(eps)
    return out.cpu().numpy()


def _lookup_similarity_numpy(flat_src: np.ndarray, idx: np.ndarray, features: np.ndarray,
                             uv: np.ndarray) -> np.ndarray:
    """:func:`cosine_similarity` of the rows ``idx (N,)`` of ``flat_src (H W, C)`` with :func:`bilinear_sample` of
    ``features (H', W', C)`` at ``uv (N, 2)``, in chunks of ``_SAMPLE_CHUNK`` pixels (a ``(pixels, C)`` lookup makes
    ~6 temporaries of that size): ``(N,)`` float32.  The reference the compiled kernel is held to (to ~1e-6: its
    sums are in double) and timed against (``bench_selftrain.py similarity``)."""
    out = np.empty(idx.size, dtype=np.float32)
    for start in range(0, idx.size, _SAMPLE_CHUNK):
        part = slice(start, start + _SAMPLE_CHUNK)
        out[part] = cosine_similarity(flat_src[idx[part]], bilinear_sample(features, uv[part]))
    return out


def _lookup_similarity(flat_src, idx: np.ndarray, features, uv: np.ndarray) -> np.ndarray:
    """The similarity of the rows ``idx (N,)`` of ``flat_src (H W, C)`` with ``features (H', W', C)`` sampled at
    ``uv (N, 2)``: ``(N,)`` float32.  The compiled kernel where it can run (it reads the four corner rows and the
    pixel's row once and makes no ``(N, C)`` temporaries: the lookup is memory bound); else, for tensor pseudo
    features, :func:`_lookup_similarity_torch` on their device; else :func:`_lookup_similarity_numpy`."""
    from ..fields.ckernel import fused_feature_similarity

    on_torch = not isinstance(flat_src, np.ndarray)
    if not on_torch:
        if hasattr(features, "cpu") and not isinstance(features, np.ndarray):   # a tensor, on any device
            features = features.cpu().numpy()
        features = np.asarray(features, dtype=np.float32)
    fast = fused_feature_similarity(flat_src, idx, features, uv)
    if fast is not None:
        return fast
    if on_torch:
        return _lookup_similarity_torch(flat_src, idx, features, uv)
    return _lookup_similarity_numpy(flat_src, idx, features, uv)


def view_similarity(pseudo_features: np.ndarray, pseudo_z: np.ndarray, pseudo_opacity: np.ndarray,
                    pseudo_intrinsics, pseudo_c2w: np.ndarray,
                    known_features: np.ndarray, known_z: np.ndarray, known_intrinsics, known_c2w: np.ndarray,
                    opacity_threshold: float = 0.5, rel_tol: float = 0.05,
                    foreground_only: bool = False) -> ViewSimilarity:
    """Per-pixel feature consistency of one pseudo view against all known views.

    A pixel, lifted with its z-depth, is warped into every known view (``geometry.reproject`` with the known
    view's z-depth as occlusion buffer); the known view's features are sampled there (:func:`bilinear_sample`),
    and the cosine similarity with the pixel's own feature is that view's score.  Warps that leave the image,
    land behind the camera or are occluded do not count.  A pixel's similarity is the maximum over the views
    that count, ``NO_MATCH`` when none does.

    Args:
        pseudo_features: (H, W, C) features of the teacher's pseudo-view render: an array, or a tensor (then the
            feature lookups run in torch on its device where the compiled kernel cannot take them, and
            ``known_features[j]`` may be tensors there too).
        pseudo_z: (H, W) teacher z-depth of the pseudo view.
        pseudo_opacity: (H, W) teacher accumulated opacity of the pseudo view.
        pseudo_intrinsics: ``geometry.Intrinsics`` of the pseudo view (size H x W).
        pseudo_c2w: (4, 4) pseudo camera-to-world (OpenCV).
        known_features: (k, H', W', C) features of the known (real) images: an array, or anything with
            ``shape``, ``ndim`` and ``[j] -> (H', W', C)`` (e.g. ``extractor.lazy(images)``, which builds one
            view's full-size features at a time).
        known_z: (k, H', W') teacher z-depth of the known views (occlusion buffers).
        known_intrinsics: one ``Intrinsics`` shared by the known views, or a sequence of k (equal ones: one
            batched warp, as for a shared one; differing ones: one warp per view).
        known_c2w: (k, 4, 4).
        opacity_threshold: foreground = opacity >= this.
        rel_tol: relative occlusion tolerance handed to ``geometry.reproject`` (its test compares with the max
            depth of the 2 x 2 footprint; 5 % relative slack absorbs the noise of rendered depth).
        foreground_only: score only the foreground pixels (the background ones get ``NO_MATCH`` and no valid
            view), which is all the labels use.  Each scored pixel's values are the same either way.
    Returns:
        :class:`ViewSimilarity`.
    """
    on_torch = not isinstance(pseudo_features, np.ndarray) and hasattr(pseudo_features, "device")
    if not on_torch:
        pseudo_features = np.asarray(pseudo_features, dtype=np.float32)
    if isinstance(known_features, (np.ndarray, list, tuple)):
        known_features = np.asarray(known_features, dtype=np.float32)
    pseudo_z = np.asarray(pseudo_z, dtype=np.float64)
    known_z = np.asarray(known_z, dtype=np.float64)
    pseudo_opacity = np.asarray(pseudo_opacity)
    known_c2w = np.asarray(known_c2w, dtype=np.float64)
    check_shape("pseudo_features", pseudo_features.shape, (None, None, None))
    h, w, c = pseudo_features.shape
    check_shape("known_features", known_features.shape, (None, None, None, c))
    k = known_features.shape[0]
    for name, a, want in (("pseudo_z", pseudo_z, (h, w)), ("pseudo_opacity", pseudo_opacity, (h, w)),
                          ("known_z", known_z, tuple(known_features.shape[:3])), ("known_c2w", known_c2w, (k, 4, 4))):
        check_shape(name, a.shape, want)
    foreground = pseudo_opacity >= opacity_threshold
    per_view = np.full((k, h, w), NO_MATCH, dtype=np.float32)
    valid = np.zeros((k, h, w), dtype=bool)
    if k == 0:
        return ViewSimilarity(np.full((h, w), NO_MATCH, np.float32), per_view, valid, foreground)
    src_c2w = np.asarray(pseudo_c2w, dtype=np.float64)
    intr = list(known_intrinsics) if isinstance(known_intrinsics, (list, tuple)) else [known_intrinsics] * k
    if len(intr) != k:
        raise ValueError(f"expected {k} known-view intrinsics, got {len(intr)}")
    if len(set(intr)) > 1:  # per-view intrinsics: one warp call per view
        warps = [geometry.reproject(pseudo_z, pseudo_intrinsics, src_c2w, intr[j], known_c2w[j],
                                    z_depth_dst=known_z[j], rel_tol=rel_tol) for j in range(k)]
        uv_all = np.stack([u for u, _ in warps])
        ok_all = np.stack([o for _, o in warps])
    else:  # one shared intrinsics (given once, or k equal ones): one batched call
        uv_all, ok_all = geometry.reproject(pseudo_z, pseudo_intrinsics, src_c2w, intr[0], known_c2w,
                                            z_depth_dst=known_z, rel_tol=rel_tol)
    flat_src = pseudo_features.reshape(-1, c)
    for j in range(k):
        ok = np.asarray(ok_all[j], dtype=bool) & np.isfinite(pseudo_z) & (pseudo_z > 0)
        if foreground_only:
            ok &= foreground
        idx = np.flatnonzero(ok.reshape(-1))
        if idx.size == 0:
            continue
        uv_j = np.asarray(uv_all[j]).reshape(-1, 2)
        out_j = per_view[j].reshape(-1)
        out_j[idx] = _lookup_similarity(flat_src, idx, known_features[j], uv_j[idx])   # (H', W', C): built when lazy
        bad = ~np.isfinite(out_j)   # a NaN render or photo: no match there, so it cannot veto another view
        if bad.any():
            out_j[bad] = NO_MATCH
            ok = ok & ~bad.reshape(ok.shape)
        valid[j] = ok
    similarity = per_view.max(axis=0)
    return ViewSimilarity(similarity=similarity, per_view=per_view, valid=valid, foreground=foreground)


def adaptive_threshold(similarities: np.ndarray, alpha: float) -> float:
    """``tau`` = the ``(1 - alpha)`` quantile (linear interpolation) of ``similarities`` (any shape).

    Raises ValueError on an empty sample or ``alpha`` outside [0, 1].
    """
    s = np.asarray(similarities, dtype=np.float64).reshape(-1)
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    if s.size == 0:
        raise ValueError("no similarities to take a quantile of")
    return float(np.quantile(s, 1.0 - alpha))


def resolve_threshold(kind: str, similarities: np.ndarray, alpha: float = 0.15, tau: float = 0.6) -> float | None:
    """The hard threshold of ``kind`` for a scene: adaptive quantile, the fixed ``tau``, or None (unified).

    Args:
        similarities: (N,) foreground similarities of all pseudo views of the scene (adaptive only).
    """
    if kind == "adaptive":
        s = np.asarray(similarities).reshape(-1)
        s = s[s > NO_MATCH]  # pixels no known view sees carry no similarity
        return adaptive_threshold(s, alpha) if s.size else float("inf")
    if kind == "fixed":
        return float(tau)
    if kind == "unified":
        return None
    raise ValueError(f"unknown threshold kind {kind!r}; choose one of {THRESHOLD_KINDS}")


def threshold_weights(similarity: np.ndarray, foreground: np.ndarray, kind: str, tau: float | None = None,
                      beta: float = 16.0, center: float = 0.7) -> np.ndarray:
    """Reliability weight per pixel in [0, 1]: binary for 'adaptive'/'fixed', soft for 'unified'.

    Args:
        similarity: (H, W) (or any shape) per-pixel max similarity.
        foreground: same shape, bool; background pixels get weight 0.
        kind: 'adaptive' | 'fixed' (reliable iff ``similarity > tau``; 'adaptive' takes ``>= tau`` when the
            quantile fell on a tie and ``>`` would keep no foreground pixel) | 'unified'
            (``sigmoid(beta (similarity - center))``; a non-finite similarity weighs 0).
    Returns:
        float32 array of the same shape.
    """
    s = np.asarray(similarity, dtype=np.float64)
    fg = np.asarray(foreground, dtype=bool)
    check_shape("foreground", fg.shape, s.shape)
    if kind in ("adaptive", "fixed"):
        if tau is None:
            raise ValueError(f"threshold kind {kind!r} needs tau")
        w = (s > tau).astype(np.float64)
        if kind == "adaptive" and fg.any() and not (w.astype(bool) & fg).any():
            # the quantile fell on a tie (saturated similarities): the tied pixels are its top share
            w = (s >= tau).astype(np.float64)
    elif kind == "unified":
        with np.errstate(over="ignore", invalid="ignore"):
            w = np.nan_to_num(1.0 / (1.0 + np.exp(-beta * (s - center))), nan=0.0)
    else:
        raise ValueError(f"unknown threshold kind {kind!r}; choose one of {THRESHOLD_KINDS}")
    return np.where(fg, w, 0.0).astype(np.float32)


def gt_reliable_mask(teacher_rgb: np.ndarray, gt_rgb: np.ndarray, max_error: float = 0.1) -> np.ndarray:
    """Ground-truth reliability from colour: mean absolute RGB error ``< max_error``.

    Args:
        teacher_rgb, gt_rgb: (..., H, W, 3) in [0, 1].
    Returns:
        (..., H, W) bool.
    """
    a = np.asarray(teacher_rgb, dtype=np.float32)
    b = np.asarray(gt_rgb, dtype=np.float32)
    if a.shape != b.shape or a.shape[-1] != 3:
        raise ValueError(f"teacher_rgb {a.shape} and gt_rgb {b.shape} must match and end in 3")
    return np.abs(a - b).mean(axis=-1) < max_error


def mask_quality(predicted: np.ndarray, truth: np.ndarray, region: np.ndarray | None = None) -> dict:
    """Precision, recall and false-positive rate of a predicted reliable mask.

    Args:
        predicted: (...) bool, our reliable mask.
        truth: (...) bool, the ground-truth reliable mask.
        region: (...) bool, pixels to count (e.g. foreground); all when None.
    Returns:
        dict(precision, recall, fpr, tp, fp, fn, tn); a ratio with an empty denominator is NaN.
    """
    p = np.asarray(predicted, dtype=bool)
    t = np.asarray(truth, dtype=bool)
    check_shape("truth", t.shape, p.shape)
    r = np.ones_like(p) if region is None else np.asarray(region, dtype=bool)
    tp = int(np.sum(p & t & r))
    fp = int(np.sum(p & ~t & r))
    fn = int(np.sum(~p & t & r))
    tn = int(np.sum(~p & ~t & r))

    def ratio(a: int, b: int) -> float:
        return a / b if b else float("nan")

    return dict(precision=ratio(tp, tp + fp), recall=ratio(tp, tp + fn), fpr=ratio(fp, fp + tn),
                tp=tp, fp=fp, fn=fn, tn=tn)
