"""Occupancy grid for empty-space skipping (instant-NGP style, small enough to update on CPU)."""

from __future__ import annotations

import torch
from torch import nn

from .base import as_aabb, check_points, field_coords, uncontract_unit

__all__ = ["OccupancyGrid"]


class OccupancyGrid(nn.Module):
    """A ``res^3`` grid of density estimates over an AABB with a binary occupancy mask.

    :meth:`update` keeps a decaying maximum of ``field.density`` at the cell centres, as instant-NGP; a cell
    is occupied while its estimate, or that of a cell up to ``dilate`` cells away (3D max filter), exceeds
    ``threshold``: the dilation keeps cells that a surface crosses although their centre lies just outside
    it.  A fresh grid is fully occupied, so rendering with it equals rendering without it until the first
    update.  Points outside the AABB are never occupied.

    With ``contract`` the grid covers all of space in the field's contracted coordinates
    (:func:`~senerf.fields.field_coords`: the AABB is the middle half of every axis); a cell's estimate is then
    its density times its stretch, the world size of the cell over that of a cell inside the AABB, so that the
    threshold means the same optical thickness per cell near and far.

    :meth:`mark_seen` restricts the grid to the cells the training rays cross (as instant-NGP marks the cells no
    training camera sees): nothing constrains the density there, so a novel view that looks through such a
    cell (the space just in front of the camera, between the training cameras' frustums) would render
    whatever density it was initialised with.

    Args:
        aabb: ``(2, 3)`` box.
        resolution: cells per side.
        threshold: density above which a cell is occupied.
        decay: multiplier of the old estimate at each update (0 = forget, use only the newest density).
        dilate: cells of dilation of the binary mask (0 = none).
        contract: cover all of space, contracted beyond ``aabb``.
    """

    def __init__(self, aabb, resolution: int = 64, threshold: float = 0.01, decay: float = 0.95,
                 dilate: int = 1, contract: bool = False):
        super().__init__()
        if resolution < 1:
            raise ValueError(f"resolution: expected >= 1, got {resolution}")
        self.resolution = int(resolution)
        self.threshold = float(threshold)
        self.decay = float(decay)
        self.dilate = int(dilate)
        self.contract = bool(contract)
        self.register_buffer("aabb", as_aabb(aabb))
        n = self.resolution ** 3
        self.register_buffer("density_grid", torch.full((n,), float("inf")))
        self.register_buffer("mask", torch.ones(n, dtype=torch.bool))
        self.register_buffer("seen", torch.ones(n, dtype=torch.bool))

    def cell_centers(self) -> torch.Tensor:
        """``(res^3, 3)`` world centres of the cells, flat index ``(i * res + j) * res + k`` for x, y, z."""
        return self._centres_and_stretch()[0]

    def _centres_and_stretch(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(centres (res^3, 3), stretch (res^3,))``: the cells' world centres and the factor their density is
        scaled by (1 without ``contract``; ``1 / (2 - m)^2`` for a cell at contracted L-infinity radius ``m``
        of ``[0, 2)``, the derivative of the inverse contraction)."""
        r = self.resolution
        c = (torch.arange(r, dtype=torch.float32, device=self.aabb.device) + 0.5) / r
        g = torch.stack(torch.meshgrid(c, c, c, indexing="ij"), dim=-1).reshape(-1, 3)
        if not self.contract:
            return self.aabb[0] + g * (self.aabb[1] - self.aabb[0]), torch.ones_like(g[:, 0])
        unit = 2.0 * g - 1.0                                         # contracted coordinates in (-1, 1)
        m = (2.0 * unit).abs().amax(dim=-1).clamp(min=1.0)
        centre, half = (self.aabb[0] + self.aabb[1]) / 2, (self.aabb[1] - self.aabb[0]) / 2
        return centre + half * uncontract_unit(unit), 1.0 / (2.0 - m).square()

    @torch.no_grad()
    def update(self, field, chunk: int = 65536) -> float:
        """Set each cell's estimate to ``max(decay * estimate, density at its centre)``; returns the occupied
        fraction.

        Args:
            field: anything with ``density(xyz (N, 3)) -> (N,)``.
            chunk: points per ``density`` call.
        """
        pts, stretch = self._centres_and_stretch()
        new = torch.cat([field.density(pts[s:s + chunk]).float() for s in range(0, pts.shape[0], chunk)]) * stretch
        old = torch.where(torch.isinf(self.density_grid), torch.zeros_like(new), self.density_grid * self.decay)
        self.density_grid.copy_(torch.maximum(old, new))
        occ = (self.density_grid > self.threshold).float().view(1, 1, *(self.resolution,) * 3)
        if self.dilate > 0:
            k = 2 * self.dilate + 1
            occ = torch.nn.functional.max_pool3d(occ, k, stride=1, padding=self.dilate)
        self.mask.copy_((occ.reshape(-1) > 0.5) & self.seen)
        return self.occupied_fraction()

    @torch.no_grad()
    def mark_seen(self, origins: torch.Tensor, dirs: torch.Tensor, near: torch.Tensor, far: torch.Tensor,
                  n_points: int = 256, max_rays: int = 1 << 17, chunk: int = 4096) -> float:
        """Keep only the cells that the rays cross (dilated by one cell, which closes the gaps between
        neighbouring rays); returns the fraction of cells seen.

        Args:
            origins, dirs: ``(R, 3)`` rays; near, far: ``(R,)`` their bounds.
            n_points: points per ray, evenly spaced in the grid's (contracted) coordinates.
            max_rays: at most this many rays are traced, every ``ceil(R / max_rays)``-th one.
        """
        from .sampling import ray_bins

        stride = max(1, -(-origins.shape[0] // max_rays))
        o, d, n, f = (x[::stride] for x in (origins, dirs, near, far))
        r = self.resolution
        hit = torch.zeros(r ** 3, dtype=torch.bool, device=self.aabb.device)
        for k in range(0, o.shape[0], chunk):
            u = torch.full((min(chunk, o.shape[0] - k), n_points), 0.5, dtype=o.dtype, device=o.device)
            t = ray_bins(o[k:k + chunk], d[k:k + chunk], n[k:k + chunk], f[k:k + chunk], u,
                         self.aabb if self.contract else None)
            pts = (o[k:k + chunk, None, :] + t[..., None] * d[k:k + chunk, None, :]).reshape(-1, 3)
            c, inside = field_coords(pts, self.aabb, self.contract)
            ijk = ((c[inside] + 1.0) * (0.5 * r)).floor().long().clamp(0, r - 1)
            hit[(ijk[:, 0] * r + ijk[:, 1]) * r + ijk[:, 2]] = True
        grown = torch.nn.functional.max_pool3d(hit.float().view(1, 1, r, r, r), 3, stride=1, padding=1)
        self.seen.copy_(grown.reshape(-1) > 0.5)
        self.mask &= self.seen
        return float(self.seen.float().mean())

    def occupied_fraction(self) -> float:
        """Fraction of occupied cells."""
        return float(self.mask.float().mean())

    def is_occupied(self, xyz: torch.Tensor) -> torch.Tensor:
        """``(N,)`` bool: the cell containing each point of ``xyz (N, 3)`` is occupied (False outside)."""
        check_points(xyz)
        u, inside = field_coords(xyz, self.aabb, self.contract)
        r = self.resolution
        ijk = ((u + 1.0) * (0.5 * r)).floor().long().clamp(0, r - 1)
        flat = (ijk[:, 0] * r + ijk[:, 1]) * r + ijk[:, 2]
        return self.mask[flat] & inside
