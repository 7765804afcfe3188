"""Rendering cameras with a trained field, and the test-view evaluation (PSNR, SSIM, renders on disk)."""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np
import torch

from senerf.atomic import atomic_write_bytes
from senerf.config import ModelConfig

from .metrics import LPIPS_UNAVAILABLE, psnr, ssim
from .rays import camera_rays, per_view_intrinsics, ray_dist_to_z_depth

__all__ = ["render_views", "evaluate", "eval_images", "depth_to_color", "to_uint8", "write_png"]


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
    if lo is None or hi is None:
        fg = z_depth[(acc > 0.5) & np.isfinite(z_depth)]
        auto = np.percentile(fg, [1, 99]) if fg.size else (0.0, 1.0)
        lo, hi = auto[0] if lo is None else lo, auto[1] if hi is None else hi
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
             chunk: int = 8192, device: str | torch.device | None = None, progress: bool = True) -> dict:
    """Render the test views, score them against :func:`eval_images`, write ``rgb_XXX.png`` / ``depth_XXX.png``
    (``XXX``: the position in ``test_idx``, 000, 001, ...).

    Args:
        scene: the :class:`senerf.data.Scene`.
        test_idx: (m,) indices of the test images into the scene's arrays.
        out_dir: folder for the PNGs (created), or ``None`` to write nothing.
        model: the :class:`~senerf.config.ModelConfig` of the field.
        occupancy: the field's occupancy grid or ``None``.
        chunk, device, progress: see :func:`render_views`.

    Returns:
        dict ``psnr`` (mean), ``ssim`` (mean), ``lpips`` and ``avg`` (``"unavailable"``: no LPIPS weights
        offline), ``per_view`` ``{"psnr": [m], "ssim": [m]}``, ``seconds``.
    """
    t0 = time.perf_counter()
    test_idx = np.asarray(test_idx, dtype=np.int64).reshape(-1)
    if test_idx.size == 0:
        raise ValueError("no test views")
    gt = eval_images(scene, test_idx, model)
    out = None if out_dir is None else Path(out_dir)
    psnrs, ssims = [], []
    views = range(test_idx.size)
    if progress:
        from tqdm.auto import tqdm

        views = tqdm(views, desc="evaluate", unit="view", dynamic_ncols=True)
    for k in views:
        i = int(test_idx[k])
        img = render_views(field, model, scene.intrinsics_all[i], scene.c2w[i], occupancy=occupancy,
                           chunk=chunk, device=device)
        rgb = np.clip(img["rgb"][0], 0.0, 1.0)
        psnrs.append(float(psnr(rgb, gt[k])))
        ssims.append(float(ssim(rgb, gt[k])))
        if out is not None:
            write_png(out / f"rgb_{k:03d}.png", rgb)
            bg = 1.0 if model.eval_background == "white" else 0.0
            write_png(out / f"depth_{k:03d}.png", depth_to_color(img["z_depth"][0], img["acc"][0], background=bg))
    return dict(psnr=float(np.mean(psnrs)), ssim=float(np.mean(ssims)), lpips=LPIPS_UNAVAILABLE,
                avg=LPIPS_UNAVAILABLE, per_view=dict(psnr=psnrs, ssim=ssims), seconds=time.perf_counter() - t0)
