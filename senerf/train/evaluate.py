"""Rendering cameras with a trained field, and the test-view evaluation (PSNR, SSIM, renders on disk)."""

from __future__ import annotations

import hashlib
import io
import json
import time
from pathlib import Path

import numpy as np
import torch

from .checkpoint import atomic_write_bytes
from .config import ModelConfig, config_to_dict
from .metrics import LPIPS_UNAVAILABLE, psnr, ssim
from .rays import camera_rays, per_view_intrinsics, ray_dist_to_z_depth

__all__ = ["render_views", "evaluate", "evaluation_digest", "field_digest", "eval_images", "depth_to_color",
           "to_uint8", "write_png"]


def _background(name: str) -> tuple[float, float, float]:
    return (1.0, 1.0, 1.0) if name == "white" else (0.0, 0.0, 0.0)


def eval_images(scene, idx, model: ModelConfig) -> np.ndarray:
    """The real images ``idx (n,)`` as renders are scored against them: ``(n, H, W, 3)`` float32, RGBA
    composited onto ``model.eval_background`` (only these views are composited, not the whole scene)."""
    idx = np.asarray(idx, dtype=np.int64).reshape(-1)
    if scene.alpha is None:
        return np.asarray(scene.rgb[idx], dtype=np.float32)
    return np.asarray(scene.composite(_background(model.eval_background), idx), dtype=np.float32)


@torch.no_grad()
def render_views(field, model: ModelConfig, intrinsics, c2w, occupancy=None, background: str | None = None,
                 chunk: int = 8192, device: str | torch.device | None = None, progress: bool = False
                 ) -> dict[str, np.ndarray]:
    """Render whole images from cameras (deterministic bin centres, no gradients, chunked).

    Args:
        field: the trained :class:`senerf.fields.RadianceField`.
        model: the :class:`ModelConfig` it was trained with (NDC, box, samples).
        intrinsics: :class:`senerf.geometry.Intrinsics` shared by the cameras, or a sequence of ``n``, one
            per camera (all of one image size).
        c2w: (n, 4, 4) OpenCV camera-to-world poses.
        occupancy: the field's :class:`senerf.fields.OccupancyGrid` or ``None``.
        background: ``"white"``/``"black"``; ``None`` = ``model.eval_background``.
        chunk: rays per field call (bounds memory).
        device: where to render (default: the field's device).
        progress: tqdm bar over the views.

    Returns:
        dict of float32 NumPy arrays: ``rgb (n, H, W, 3)``, ``z_depth (n, H, W)`` (camera z; where the ray
        is empty it is the far bound's depth), ``acc (n, H, W)``.
    """
    from senerf.fields import render_image

    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.ndim == 2:
        c2w = c2w[None]
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
        raise ValueError(f"c2w must be (n, 4, 4), got {c2w.shape}")
    if device is None:
        p = next(field.parameters(), None)
        device = p.device if p is not None else torch.device("cpu")
    bg = torch.tensor(_background(background or model.eval_background), device=device)
    n = c2w.shape[0]
    per_view = per_view_intrinsics(intrinsics, n)
    H, W = per_view[0].size if per_view else getattr(intrinsics, "size", (0, 0))
    out = dict(rgb=np.empty((n, H, W, 3), np.float32), z_depth=np.empty((n, H, W), np.float32),
               acc=np.empty((n, H, W), np.float32))
    views = range(n)
    if progress:
        from tqdm.auto import tqdm

        views = tqdm(views, desc="render", unit="view", dynamic_ncols=True)
    was_training = field.training
    field.eval()
    for i in views:
        rays = camera_rays(per_view[i], c2w[i:i + 1], model, device)
        img = render_image(field, rays["origins"].view(H, W, 3), rays["dirs"].view(H, W, 3),
                           rays["near"].view(H, W), rays["far"].view(H, W), model.n_samples,
                           background=bg, occupancy=occupancy, chunk=chunk, randomized=False, device=device)
        dist = torch.as_tensor(img["ray_dist"].reshape(-1), device=device)
        out["rgb"][i] = img["rgb"]
        out["acc"][i] = img["acc"]
        out["z_depth"][i] = ray_dist_to_z_depth(dist, rays, model).view(H, W).cpu().numpy()
    field.train(was_training)
    return out


def depth_to_color(z_depth: np.ndarray, acc: np.ndarray, lo: float | None = None, hi: float | None = None,
                   background: float = 1.0) -> np.ndarray:
    """Colour-map a depth image (turbo; near = red, far = blue), fading to ``background`` where empty.

    Args:
        z_depth: (H, W) depth.
        acc: (H, W) accumulated opacity in [0, 1].
        lo, hi: depth range mapped to the colour map (default: 1st/99th percentile where ``acc > 0.5``).
        background: grey value of empty pixels.

    Returns:
        (H, W, 3) uint8.
    """
    from matplotlib import colormaps

    z_depth = np.asarray(z_depth, dtype=np.float64)
    acc = np.clip(np.asarray(acc, dtype=np.float64), 0.0, 1.0)
    if z_depth.ndim != 2 or acc.shape != z_depth.shape:
        raise ValueError(f"z_depth and acc must both be (H, W), got {z_depth.shape}, {acc.shape}")
    fg = z_depth[(acc > 0.5) & np.isfinite(z_depth)]
    if lo is None or hi is None:
        lo_, hi_ = (np.percentile(fg, [1, 99]) if fg.size else (0.0, 1.0))
        lo = lo_ if lo is None else lo
        hi = hi_ if hi is None else hi
    x = np.clip((z_depth - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    x = np.nan_to_num(x, nan=1.0)
    rgb = colormaps["turbo"](1.0 - x)[..., :3]
    rgb = rgb * acc[..., None] + background * (1.0 - acc[..., None])
    return np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)


def to_uint8(image: np.ndarray) -> np.ndarray:
    """``(...)`` float image in [0, 1] (or uint8, returned as is) as uint8: ``round(255 x)`` in float64, clipped.

    Example:
        >>> to_uint8(np.array([-0.1, 0.5, 0.999, 2.0])).tolist()
        [0, 128, 255, 255]
    """
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    return np.clip(np.round(np.asarray(image, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write an (H, W, 3) float image in [0, 1] or uint8 image as an 8-bit PNG, atomically."""
    import imageio.v2 as imageio

    image = to_uint8(image)
    buf = io.BytesIO()
    imageio.imwrite(buf, image, format="png")
    atomic_write_bytes(path, buf.getvalue())


def evaluate(field, scene, test_idx, out_dir: str | Path | None, model: ModelConfig, occupancy=None,
             chunk: int = 8192, device: str | torch.device | None = None, progress: bool = True,
             resume: str | Path | None = None) -> dict:
    """Render the test views, compare with the ground truth, write ``rgb_XXX.png`` / ``depth_XXX.png``.

    The ground truth of RGBA scenes is composited onto ``model.eval_background`` (white for NeRF
    Synthetic), which the renders use too.  ``XXX`` is the position in ``test_idx`` (000, 001, ...).

    Args:
        field: the trained field.
        scene: the :class:`senerf.data.Scene`.
        test_idx: (m,) indices of the test images into the scene's arrays.
        out_dir: folder for the PNGs (created), or ``None`` to write nothing.
        model: the :class:`ModelConfig` of the field.
        occupancy: the field's occupancy grid or ``None``.
        chunk, device, progress: see :func:`render_views`.
        resume: a JSON file recording each finished view's PSNR and SSIM (rewritten atomically after every
            view) under a digest of the field, its occupancy grid, the model and the test cameras.  A call
            that finds it with the same digest renders only the views it lacks (or whose PNGs are missing),
            and returns what one uninterrupted call returns, its ``seconds`` included.  The caller deletes
            it once the result is stored; one with another digest is replaced.

    Returns:
        dict ``psnr`` (mean), ``ssim`` (mean), ``lpips`` and ``avg`` (``"unavailable"``: no LPIPS weights
        offline), ``per_view`` ``{"psnr": [m], "ssim": [m]}``, ``seconds`` (this call's and those recorded
        in ``resume``), ``seconds_before`` (those recorded in ``resume``; 0 without one).
    """
    t0 = time.perf_counter()
    test_idx = np.asarray(test_idx, dtype=np.int64).reshape(-1)
    if test_idx.size == 0:
        raise ValueError("no test views")
    gt = eval_images(scene, test_idx, model)
    out = None if out_dir is None else Path(out_dir)
    resume = None if resume is None else Path(resume)
    digest = None if resume is None else evaluation_digest(field, occupancy, model, scene, test_idx)
    done, seconds_before = _finished_views(resume, digest, test_idx.size)
    psnrs: list = [None] * test_idx.size
    ssims: list = [None] * test_idx.size
    for k, (p, s) in done.items():
        if out is None or ((out / f"rgb_{k:03d}.png").is_file() and (out / f"depth_{k:03d}.png").is_file()):
            psnrs[k], ssims[k] = p, s
    views = [k for k in range(test_idx.size) if psnrs[k] is None]
    if progress:   # a resumed evaluation's bar starts at the views already scored, so its rate and ETA are its own
        from tqdm.auto import tqdm

        views = tqdm(views, desc="evaluate", unit="view", dynamic_ncols=True, total=test_idx.size,
                     initial=test_idx.size - len(views))
    for k in views:
        i = int(test_idx[k])
        img = render_views(field, model, scene.intrinsics_all[i], scene.c2w[i], occupancy=occupancy,
                           chunk=chunk, device=device)
        rgb = np.clip(img["rgb"][0], 0.0, 1.0)
        psnrs[k] = float(psnr(rgb, gt[k]))
        ssims[k] = float(ssim(rgb, gt[k]))
        if out is not None:
            write_png(out / f"rgb_{k:03d}.png", rgb)
            bg = 1.0 if model.eval_background == "white" else 0.0
            write_png(out / f"depth_{k:03d}.png", depth_to_color(img["z_depth"][0], img["acc"][0], background=bg))
        if resume is not None:
            record = dict(digest=digest, seconds=seconds_before + time.perf_counter() - t0,
                          views={str(j): [psnrs[j], ssims[j]] for j in range(test_idx.size) if psnrs[j] is not None})
            atomic_write_bytes(resume, json.dumps(record).encode())
    return dict(psnr=float(np.mean(psnrs)), ssim=float(np.mean(ssims)), lpips=LPIPS_UNAVAILABLE,
                avg=LPIPS_UNAVAILABLE, per_view=dict(psnr=[float(v) for v in psnrs], ssim=[float(v) for v in ssims]),
                seconds=seconds_before + time.perf_counter() - t0, seconds_before=seconds_before)


def _field_hash(field, occupancy, model: ModelConfig):
    """A SHA-256 hasher fed the field's and the occupancy grid's tensors and the model settings."""
    h = hashlib.sha256()
    for module in (field, occupancy):
        if module is None:
            h.update(b"none")
            continue
        for name, value in sorted(module.state_dict().items()):
            h.update(name.encode())
            h.update(str(tuple(value.shape)).encode() + str(value.dtype).encode())
            h.update(value.detach().cpu().contiguous().numpy().tobytes())
    h.update(json.dumps(config_to_dict(model), sort_keys=True, default=str).encode())
    return h


def field_digest(field, occupancy, model: ModelConfig) -> str:
    """SHA-256 naming a fitted field: its and its occupancy grid's tensors and the model settings (what a render
    from a given camera depends on, besides the device)."""
    return _field_hash(field, occupancy, model).hexdigest()


def evaluation_digest(field, occupancy, model: ModelConfig, scene, test_idx) -> str:
    """SHA-256 naming one evaluation: the field's and the occupancy grid's tensors, the model settings, the
    test views' indices, cameras (image size included) and photos (what :func:`evaluate`'s figures depend on)."""
    h = _field_hash(field, occupancy, model)
    idx = np.asarray(test_idx, dtype=np.int64)
    h.update(idx.tobytes())
    h.update(np.ascontiguousarray(np.asarray(scene.c2w)[idx], dtype=np.float64).tobytes())
    for i in idx:   # view by view: no copy of all the test photos
        h.update(repr(scene.intrinsics_all[int(i)]).encode())
        h.update(np.ascontiguousarray(scene.rgb[int(i)]).tobytes())
        if scene.alpha is not None:
            h.update(np.ascontiguousarray(scene.alpha[int(i)]).tobytes())
    return h.hexdigest()


def _finished_views(path: Path | None, digest: str | None, n_views: int) -> tuple[dict, float]:
    """``({view position: (psnr, ssim)}, seconds)`` recorded in ``path`` for ``digest``; empty for no file, a
    file of another evaluation or an unreadable one (it is rewritten after the next view)."""
    if path is None or not path.is_file():
        return {}, 0.0
    try:
        record = json.loads(path.read_text())
        if record.get("digest") != digest:
            return {}, 0.0
        views = {int(k): (float(v[0]), float(v[1])) for k, v in record["views"].items()}
        seconds = float(record.get("seconds", 0.0))
    except (OSError, ValueError, TypeError, KeyError, IndexError, AttributeError):
        return {}, 0.0
    return {k: v for k, v in views.items() if 0 <= k < n_views}, seconds
