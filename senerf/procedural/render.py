"""Exact rendering of a :class:`~senerf.procedural.scene.ProceduralScene` by ray casting (first hits only).

embreex finds the first triangle each ray hits; the hit distance is then recomputed in float64 as the
intersection of the ray with that triangle's plane, so ``origin + ray_dist * dir`` lies on the mesh to ~1e-12
(embree itself works in float32).

Convention: OpenCV cameras (``c2w`` (4, 4), x right, y down, z forward), pixel centres at ``i + 0.5``.
Misses are marked field by field (:class:`Render`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from senerf.geometry import Intrinsics, pixel_rays

from .scene import ProceduralScene, texture_color

__all__ = ["RayHits", "Render", "cast_rays", "shade", "render"]

_CHUNK = 1 << 20


@dataclass(frozen=True, eq=False)
class RayHits:
    """First hits of N rays (world frame).

    Attributes:
        hit: (N,) bool.
        ray_dist: (N,) float64 distance along the unit ray; inf for misses.
        points: (N, 3) float64 hit points; nan for misses.
        normals: (N, 3) float64 outward unit face normals; 0 for misses.
        object_id: (N,) int32; -1 for misses.
        face: (N,) int64 index into ``scene.mesh.faces``; -1 for misses.
    """

    hit: np.ndarray
    ray_dist: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    object_id: np.ndarray
    face: np.ndarray


@dataclass(frozen=True, eq=False)
class Render:
    """One rendered view, all arrays (H, W, ...) in image layout.

    Attributes:
        rgb: (H, W, 3) float32 straight colour in [0, 1]; 0 where ``alpha == 0``.
        alpha: (H, W) float32, 1 where the ray hits the scene, else 0 (binary: no anti-aliasing).
        z_depth: (H, W) float64 camera-frame z of the hit; inf for misses.
        ray_dist: (H, W) float64 distance along the unit pixel ray; inf for misses.
        normals: (H, W, 3) float32 world-frame outward face normals; 0 for misses.
        object_id: (H, W) int32 (see ``scene.object_names``); -1 for misses.
        points: (H, W, 3) float64 world hit points; nan for misses.
    """

    rgb: np.ndarray
    alpha: np.ndarray
    z_depth: np.ndarray
    ray_dist: np.ndarray
    normals: np.ndarray
    object_id: np.ndarray
    points: np.ndarray

    def composite(self, background=(1.0, 1.0, 1.0)) -> np.ndarray:
        """(H, W, 3) float32 ``rgb * alpha + (1 - alpha) * background``; background (3,) in [0, 1]."""
        bg = np.asarray(background, dtype=np.float32)
        if bg.shape != (3,):
            raise ValueError(f"background: expected shape (3,), got {bg.shape}")
        a = self.alpha[..., None]
        return (self.rgb * a + (1.0 - a) * bg).astype(np.float32)

    def depth_or_zero(self) -> np.ndarray:
        """(H, W) float32 z-depth with 0 for misses (the export format)."""
        return np.where(np.isfinite(self.z_depth), self.z_depth, 0.0).astype(np.float32)


def _check_rays(origins, dirs) -> tuple[np.ndarray, np.ndarray]:
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(dirs, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(f"origins, dirs: expected matching shapes (N, 3), got {o.shape} and {d.shape}")
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise ValueError("origins, dirs: must be finite")
    norms = np.linalg.norm(d, axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-6):
        raise ValueError("dirs: must be unit length (|norm - 1| <= 1e-6)")
    return o, d


def cast_rays(scene: ProceduralScene, origins, dirs) -> RayHits:
    """First hits of rays ``origins`` (N, 3), unit ``dirs`` (N, 3), world frame (float64, module docstring)."""
    o, d = _check_rays(origins, dirs)
    face = np.full(len(o), -1, dtype=np.int64)
    for start in range(0, len(o), _CHUNK):   # embreex in chunks of bounded size
        sl = slice(start, start + _CHUNK)
        tri, ray = scene.intersector.intersects_id(o[sl], d[sl], multiple_hits=False, return_locations=False)
        face[start + np.asarray(ray, dtype=np.int64)] = tri
    hit = face >= 0
    n = len(o)
    ray_dist = np.full(n, np.inf)
    points = np.full((n, 3), np.nan)
    normals = np.zeros((n, 3))
    object_id = np.full(n, -1, dtype=np.int32)
    if np.any(hit):
        f = face[hit]
        nrm = np.asarray(scene.mesh.face_normals, dtype=np.float64)[f]
        v0 = np.asarray(scene.mesh.triangles, dtype=np.float64)[f, 0]
        denom = np.einsum("ij,ij->i", nrm, d[hit])
        num = np.einsum("ij,ij->i", nrm, v0 - o[hit])
        safe = np.abs(denom) > 1e-12
        centroid = np.asarray(scene.mesh.triangles_center, dtype=np.float64)[f]
        t = np.where(safe, num / np.where(safe, denom, 1.0), np.einsum("ij,ij->i", centroid - o[hit], d[hit]))
        ray_dist[hit] = t
        points[hit] = o[hit] + t[:, None] * d[hit]
        normals[hit] = nrm
        object_id[hit] = scene.face_object[f]
    return RayHits(hit=hit, ray_dist=ray_dist, points=points, normals=normals, object_id=object_id, face=face)


def shade(scene: ProceduralScene, hits: RayHits) -> np.ndarray:
    """(N, 3) float64 view-independent colour of the hits (0 for misses).

    colour = albedo(point) * (ambient + (1 - ambient) * max(0, normal . light)).
    """
    rgb = np.zeros((len(hits.hit), 3))
    amb = float(scene.config.ambient)
    for oid in np.unique(hits.object_id[hits.hit]):
        sel = hits.object_id == oid
        p = hits.points[sel]
        w2l = scene.world_to_local[oid]
        local = p @ w2l[:3, :3].T + w2l[:3, 3]
        albedo = texture_color(scene.textures[oid], local)
        lam = np.clip(hits.normals[sel] @ scene.light, 0.0, None)
        rgb[sel] = albedo * (amb + (1.0 - amb) * lam)[:, None]
    return np.clip(rgb, 0.0, 1.0)


def render(scene: ProceduralScene, intrinsics: Intrinsics, c2w) -> Render:
    """One view as a :class:`Render`: ``intrinsics`` of an H x W image, ``c2w`` (4, 4) OpenCV camera-to-world."""
    pose = np.asarray(c2w, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"c2w: expected shape (4, 4), got {pose.shape}")
    origins, dirs, z_per_dist = pixel_rays(intrinsics, pose)
    h, w = origins.shape[:2]
    hits = cast_rays(scene, origins.reshape(-1, 3), dirs.reshape(-1, 3))
    rgb = shade(scene, hits)
    ray_dist = hits.ray_dist.reshape(h, w)
    return Render(
        rgb=rgb.reshape(h, w, 3).astype(np.float32),
        alpha=hits.hit.reshape(h, w).astype(np.float32),
        z_depth=ray_dist * np.asarray(z_per_dist, dtype=np.float64),
        ray_dist=ray_dist,
        normals=hits.normals.reshape(h, w, 3).astype(np.float32),
        object_id=hits.object_id.reshape(h, w),
        points=hits.points.reshape(h, w, 3),
    )
