"""The rays of whole images as the field sees them (:func:`camera_rays`), and the precomputed training rays with
their per-step random batches (:class:`RayBatchSource`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from senerf.config import ModelConfig
from senerf.errors import InputError

__all__ = ["RayBatchSource", "ray_aabb_bounds", "camera_rays", "per_view_intrinsics", "ray_dist_to_z_depth"]

_PARALLEL_T = 1e12   # the entry / exit distance ray_aabb_bounds gives an axis its ray runs parallel to


def ray_aabb_bounds(origins: torch.Tensor, dirs: torch.Tensor, aabb, min_near: float = 1e-3
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-ray ``[near, far]`` of the segment inside an axis-aligned box (slab test).

    Args:
        origins: (R, 3) ray origins.
        dirs: (R, 3) ray directions (any length; the bounds are in units of ``dirs``).
        aabb: (2, 3) box ``[min, max]`` (tensor or nested sequence).
        min_near: lower bound of ``near`` (a camera inside the box starts there).

    Returns:
        ``(near (R,), far (R,))``; a ray that misses the box gets ``far = near`` (an empty segment, so it
        renders as pure background).

    Convention: the box is closed.  A direction component below 1e-12 in magnitude counts as parallel to
    that axis's slab: the ray stays inside it for all ``t`` when its origin lies within ``[min, max]``,
    faces included (on either face alike), and misses the box otherwise (its empty segment then sits at
    ``near = far = 1e12``).  A zero direction has no segment worth the name (the bounds come out as
    ``[min_near, 1e12]`` inside the box).
    """
    if origins.ndim != 2 or origins.shape[1] != 3 or dirs.shape != origins.shape:
        raise ValueError(f"origins and dirs must both be (R, 3), got {tuple(origins.shape)}, {tuple(dirs.shape)}")
    box = torch.as_tensor(aabb, dtype=origins.dtype, device=origins.device)
    if box.shape != (2, 3):
        raise ValueError(f"aabb must be (2, 3), got {tuple(box.shape)}")
    parallel = dirs.abs() < 1e-12
    safe = torch.where(parallel, torch.ones_like(dirs), dirs)
    t0 = (box[0] - origins) / safe
    t1 = (box[1] - origins) / safe
    # a parallel axis bounds nothing when the origin is within its slab, and empties the segment otherwise;
    # +-1e12 (finite in float32) keeps a missed ray's empty segment finite
    in_slab = (origins >= box[0]) & (origins <= box[1])
    unbounded = torch.full_like(t0, _PARALLEL_T)
    entry = torch.where(parallel, torch.where(in_slab, -unbounded, unbounded), torch.minimum(t0, t1))
    leave = torch.where(parallel, torch.where(in_slab, unbounded, -unbounded), torch.maximum(t0, t1))
    near = entry.amax(dim=-1).clamp_min(min_near)
    far = leave.amin(dim=-1)
    far = torch.maximum(far, near)
    return near, far


def camera_rays(intrinsics, c2w: np.ndarray, model: ModelConfig, device: str | torch.device = "cpu"
                ) -> dict[str, torch.Tensor]:
    """The rays of whole images as the field sees them, with their bounds: in the model frame (the world
    shifted by ``model.frame_origin``, in float64 before the cast) or in NDC.

    In NDC (``model.ndc``) the NDC directions are normalised to unit length so the field sees unit view
    directions; the NDC parameter ``t' in [0, 1]`` becomes the distance ``t' * |d_ndc|``, hence
    ``near = 0`` and ``far = |d_ndc|`` per ray.

    Args:
        intrinsics: one :class:`senerf.geometry.Intrinsics` shared by the cameras, or a sequence of ``n``
            (one per camera, all of one image size).  NDC needs them all equal (the NDC warp is built from
            one focal length; :func:`senerf.data.load_llff` refuses scenes whose focals differ).
        c2w: (n, 4, 4) camera-to-world poses (OpenCV).
        model: gives ``ndc``/``ndc_near``, ``aabb``, constant ``near``/``far`` and ``bound``.

    Returns:
        dict of float32 tensors flattened over ``(n, H, W)``: ``origins (R, 3)``, ``dirs (R, 3)`` unit,
        ``near (R,)``, ``far (R,)``, and for :func:`ray_dist_to_z_depth`: ``z_per_dist (R,)``,
        ``world_oz (R,)``, ``world_dz (R,)`` (used in NDC, where they are the world's; outside NDC the origin's
        z is the model frame's), ``ndc_len (R,)`` (1 outside NDC).
    """
    from senerf.geometry import Intrinsics, pixel_rays

    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
        raise ValueError(f"c2w must be (n, 4, 4), got {c2w.shape}")
    if not isinstance(intrinsics, Intrinsics):
        per_view = per_view_intrinsics(intrinsics, c2w.shape[0])
        if any(k != per_view[0] for k in per_view):
            if model.ndc:
                raise ValueError("camera_rays: NDC rays need one shared Intrinsics (the NDC warp uses one focal)")
            parts = [camera_rays(k, c2w[i:i + 1], model, device) for i, k in enumerate(per_view)]
            return {key: torch.cat([p[key] for p in parts]) for key in parts[0]}
        intrinsics = per_view[0]
    o, d, zpd = pixel_rays(intrinsics, c2w)
    if not model.ndc:  # world -> model frame, in float64 (see ModelConfig.frame_origin)
        o = o - np.asarray(model.frame_origin, dtype=np.float64)

    def tensor(a, cols):
        a = np.ascontiguousarray(a.reshape((-1, cols) if cols > 1 else (-1,)))
        return torch.as_tensor(a, dtype=torch.float32, device=device)

    o, d, zpd = tensor(o, 3), tensor(d, 3), tensor(zpd, 1)
    out = dict(z_per_dist=zpd, world_oz=o[:, 2].clone(), world_dz=d[:, 2].clone(),
               ndc_len=torch.ones_like(zpd))
    if model.ndc:
        from senerf.fields import ndc_rays

        W, H = intrinsics.width, intrinsics.height
        o, d = ndc_rays(o, d, intrinsics.fx, intrinsics.fy, W, H, near=model.ndc_near)
        length = d.norm(dim=-1)
        d = d / length[:, None]
        near, far = torch.zeros_like(length), length
        out["ndc_len"] = length
    elif model.near is not None:
        near = torch.full_like(o[:, 0], model.near)
        far = torch.full_like(o[:, 0], model.far)
        if model.bound is not None:   # rays end where they leave the scene's box (or, missing it, are empty)
            enter, leave = ray_aabb_bounds(o, d, model.field_bound, min_near=model.near)
            near, far = enter.clamp(max=model.far), leave.clamp(max=model.far)
    else:
        # min_near 1e-3, or 1e-3 box sizes for a box under 1 unit (an absolute 1e-3 empties a tiny scene's rays)
        size = min(hi - lo for lo, hi in zip(*model.aabb))
        near, far = ray_aabb_bounds(o, d, model.field_aabb, min_near=min(1e-3, 1e-3 * size))
    out.update(origins=o, dirs=d, near=near, far=far)
    return out


def per_view_intrinsics(intrinsics, n: int) -> tuple:
    """``intrinsics`` (one ``Intrinsics`` or a sequence of ``n``) as a tuple of ``n``, all of one image size."""
    from senerf.geometry import Intrinsics

    seq = (intrinsics,) * n if isinstance(intrinsics, Intrinsics) else tuple(intrinsics)
    if len(seq) != n or not all(isinstance(k, Intrinsics) for k in seq):
        raise ValueError(f"intrinsics: expected one Intrinsics or a sequence of {n}, got {len(seq)} items")
    if any(k.size != seq[0].size for k in seq):
        raise ValueError(f"intrinsics: the cameras' image sizes differ ({sorted({k.size for k in seq})})")
    return seq


def ray_dist_to_z_depth(ray_dist: torch.Tensor, rays: dict[str, torch.Tensor], model: ModelConfig) -> torch.Tensor:
    """Camera z-depth ``(R,)`` of a rendered ``ray_dist (R,)`` for rays from :func:`camera_rays`.

    World rays: ``ray_dist * z_per_dist``.  NDC: ``t' = ray_dist / |d_ndc|`` is at world depth
    ``Z = ndc_near / (1 - t')`` along the scene's forward axis, reached after ``(Z - o_z) / d_z`` along
    the unit world ray.
    """
    if not model.ndc:
        return ray_dist * rays["z_per_dist"]
    from senerf.fields import ndc_t_to_depth

    z_fwd = ndc_t_to_depth(ray_dist / rays["ndc_len"], model.ndc_near)
    dist = (z_fwd - rays["world_oz"]) / rays["world_dz"].clamp_min(1e-9)
    return dist * rays["z_per_dist"]


@dataclass(eq=False)
class RayBatchSource:
    """All rays of the training images (computed once, float32 on the training device), sampled uniformly per step
    from a seeded ``torch.Generator`` on the same device, so a run is reproducible and resumable.

    Attributes:
        origins, dirs: (R, 3) float32 (NDC when ``model.ndc``).
        rgb: (R, 3) float32 straight colour (or already composited, see ``alpha``).
        alpha: (R,) float32 or ``None`` (no alpha: ``rgb`` is the target as is).
        near, far: (R,) float32 ray bounds.
        model: the :class:`ModelConfig` the rays were built for (render settings for the trainer).
    """

    origins: torch.Tensor
    dirs: torch.Tensor
    rgb: torch.Tensor
    alpha: torch.Tensor | None
    near: torch.Tensor
    far: torch.Tensor
    model: ModelConfig

    def __post_init__(self) -> None:
        n = self.origins.shape[0]
        for name, shape in (("origins", (n, 3)), ("dirs", (n, 3)), ("rgb", (n, 3)), ("alpha", (n,)), ("near", (n,)),
                            ("far", (n,))):
            t = getattr(self, name)
            if t is not None and (t.shape != shape or t.dtype != torch.float32):
                raise ValueError(f"{name} must be {shape} float32, got {tuple(t.shape)} {t.dtype}")
        if n == 0:
            raise ValueError("no rays")

    @classmethod
    def from_scene(cls, scene, idx, model: ModelConfig, device: str | torch.device = "cpu") -> "RayBatchSource":
        """Precompute the rays of images ``idx (n,)`` of ``scene`` on ``device``."""
        idx = np.asarray(idx, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            raise InputError("no training views", field="views")
        if idx.min() < 0 or idx.max() >= scene.n_images:
            raise InputError(f"view index out of range [0, {scene.n_images})", field="views")
        rays = camera_rays([scene.intrinsics_all[i] for i in idx], scene.c2w[idx], model, device)
        rgb = torch.as_tensor(scene.rgb[idx].reshape(-1, 3), dtype=torch.float32, device=device)
        alpha = None
        if scene.alpha is not None and scene.background is None:
            alpha = torch.as_tensor(scene.alpha[idx].reshape(-1), dtype=torch.float32, device=device)
        return cls(rays["origins"], rays["dirs"], rgb.contiguous(), alpha, rays["near"], rays["far"], model)

    def __len__(self) -> int:
        return int(self.origins.shape[0])

    @property
    def device(self) -> torch.device:
        return self.origins.device

    def sample(self, batch: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """A uniform random batch (with replacement).

        Args:
            generator: a ``torch.Generator`` on :attr:`device`.

        Returns:
            dict ``origins (B, 3)``, ``dirs (B, 3)``, ``rgb (B, 3)``, ``alpha (B,)`` or absent,
            ``near (B,)``, ``far (B,)``, ``index (B,)`` int64.
        """
        i = torch.randint(0, len(self), (batch,), generator=generator, device=self.device)
        out = dict(origins=self.origins[i], dirs=self.dirs[i], rgb=self.rgb[i], near=self.near[i],
                   far=self.far[i], index=i)
        if self.alpha is not None:
            out["alpha"] = self.alpha[i]
        return out
