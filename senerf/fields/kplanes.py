"""Hybrid static K-Planes field (REFERENCE section 4) in plain PyTorch, with the compiled kernel on CPU."""

from __future__ import annotations

import torch
from torch import nn

from .base import RadianceField, as_aabb, check_points, field_coords, trunc_exp
from .ckernel import fused_plane_features, kernel_status
from .encoding import sh_encoding
from .interp import PAIRS, plane_interp, plane_interp_reference, plane_layout, plane_tv
from .mlp import make_generator, relu_mlp, seeded_linear

__all__ = ["KPlanesField"]


class KPlanesField(RadianceField):
    """K-Planes (hybrid, static): three planes (xy, xz, yz) per scale, bilinear features multiplied (Hadamard)
    across the planes of a scale and concatenated across scales, then a density MLP (truncated-exp density and
    geometry features) and a colour MLP on ``[geometry features, SH encoding (degree 4) of the view direction]``.
    The paper's (Blender) configuration is ``resolution=128, multires=(1, 2, 4), n_features=32``; the defaults
    are smaller, for CPU training.

    Args:
        aabb: ``(2, 3)`` box ``[min, max]``; the planes cover it, points outside get density 0.
        contract: the planes cover all of space instead: ``aabb`` fills their middle half and the rest of space is
            contracted into the outer half (:func:`~senerf.fields.field_coords`; K-Planes' unbounded scenes).
        resolution: base plane resolution (texels per side).
        n_features: features per plane.
        multires: resolution multipliers, one scale each.
        view_dependent: colour MLP sees the SH encoding of the view direction; ``False`` drops it.
        hidden: width of both MLPs (density: 1 hidden layer; colour: 2); the paper uses 64.
        geo_features: geometry features passed from the density to the colour MLP (the paper: 15; 16 makes the
            colour MLP's input, with the 16 SH coefficients, 32 wide).
        density_shift: added to the raw density before ``trunc_exp``.
        generator: seeds every initial value (planes U(0.1, 0.5), MLP weights); ``None`` = seed 0.
        chunk: points per MLP pass; larger inputs are split (autograd still sees one batch), so the MLP
            temporaries stay at a few MB, which the allocator recycles instead of mapping fresh pages.
        backend: plane interpolation: ``'auto'`` (the compiled kernel of :mod:`senerf.fields.ckernel` where it
            can be used, else ``'gather'``), ``'fused'`` (the kernel, or raise), ``'gather'`` (pure PyTorch
            ``embedding_bag`` / ``index_add_``), ``'grid_sample'`` (reference).

    Attributes:
        table: ``(rows, n_features)`` parameter holding every plane (see :mod:`senerf.fields.interp`).
    """

    def __init__(self, aabb, resolution: int = 64, n_features: int = 16, multires=(1, 2, 4),
                 view_dependent: bool = True, hidden: int = 32, geo_features: int = 16, density_shift: float = 0.0,
                 generator: torch.Generator | None = None, backend: str = "auto", chunk: int = 32768,
                 contract: bool = False):
        super().__init__()
        gen = make_generator(generator)
        self.register_buffer("aabb", as_aabb(aabb))
        self.contract = bool(contract)
        self.resolutions = tuple(int(resolution * m) for m in multires)
        self.n_features = int(n_features)
        self.view_dependent = bool(view_dependent)
        self.geo_features = int(geo_features)
        self.density_shift = float(density_shift)
        if backend not in ("auto", "fused", "gather", "grid_sample"):
            raise ValueError(f"backend: expected auto, fused, gather or grid_sample, got {backend!r}")
        self.backend = backend
        if chunk < 1:
            raise ValueError(f"chunk: expected >= 1, got {chunk}")
        self.chunk = int(chunk)
        self.offsets, rows = plane_layout(self.resolutions, len(PAIRS))
        self.table = nn.Parameter(torch.rand(rows, self.n_features, generator=gen) * 0.4 + 0.1)
        n_in = len(self.resolutions) * self.n_features
        self.density_net = nn.Sequential(seeded_linear(n_in, hidden, gen), nn.ReLU(inplace=True),
                                         seeded_linear(hidden, 1 + self.geo_features, gen))
        c_in = self.geo_features + (16 if self.view_dependent else 0)   # 16 SH coefficients (degree 4)
        self.color_net = nn.Sequential(seeded_linear(c_in, hidden, gen), nn.ReLU(inplace=True),
                                       seeded_linear(hidden, hidden, gen), nn.ReLU(inplace=True),
                                       seeded_linear(hidden, 3, gen))

    def plane(self, scale: int, index: int) -> torch.Tensor:
        """View ``(r, r, F)`` (row b, column a, feature) of plane ``index`` (0 xy, 1 xz, 2 yz) of ``scale``."""
        r = self.resolutions[scale]
        o = self.offsets[scale * len(PAIRS) + index]
        return self.table[o:o + r * r].view(r, r, self.n_features)

    def features(self, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Plane features.

        Args:
            xyz: ``(N, 3)`` world points.
        Returns:
            ``(feat (N, S * F), inside (N,) bool)``.
        """
        check_points(xyz)
        u, inside = field_coords(xyz.to(self.table.dtype), self.aabb, self.contract)
        u = torch.nan_to_num(u, nan=0.0).clamp(-1.0, 1.0)   # NaN points: outside (density 0), safe lookups
        if self.backend in ("auto", "fused"):
            f = fused_plane_features(self.table, u, self.resolutions, self.offsets)
            if f is not None:
                return f, inside
            if self.backend == "fused":
                raise RuntimeError(f"fused kernel unusable here ({kernel_status()}; device "
                                   f"{self.table.device}, points need grad: {u.requires_grad})")
        if self.backend == "grid_sample":
            planes = [self.plane(s, p).permute(2, 0, 1) for s in range(len(self.resolutions))
                      for p in range(len(PAIRS))]
            f = plane_interp_reference(planes, u)
        else:
            f = plane_interp(self.table, u, self.resolutions, self.offsets)
        f = f[:, :, 0] * f[:, :, 1] * f[:, :, 2]                                 # (N, S, F)
        return f.reshape(xyz.shape[0], len(self.resolutions) * self.n_features), inside   # N = 0 is valid

    def _decode(self, xyz: torch.Tensor, dirs: torch.Tensor | None, with_rgb: bool):
        """Plane features for all points at once (one kernel call, one table-sized gradient buffer), then
        the MLPs in chunks of ``self.chunk`` points (``torch.split``: one concatenation in backward)."""
        feat, inside = self.features(xyz)   # checks xyz
        if with_rgb and self.view_dependent and (dirs is None or dirs.shape != xyz.shape):
            raise ValueError(f"dirs: expected shape {tuple(xyz.shape)}, got "
                             f"{None if dirs is None else tuple(dirs.shape)}")
        keep = inside.to(feat.dtype)
        sig, rgb = [], []
        dpieces = torch.split(dirs, self.chunk) if (with_rgb and self.view_dependent) else None
        for i, (f, k) in enumerate(zip(torch.split(feat, self.chunk), torch.split(keep, self.chunk))):
            raw, geo = torch.split(relu_mlp(f, self.density_net), [1, self.geo_features], dim=1)
            sig.append(trunc_exp(raw.squeeze(1) + self.density_shift) * k)
            if with_rgb:
                if dpieces is not None:
                    geo = torch.cat([geo, sh_encoding(dpieces[i].to(geo.dtype))], dim=-1)
                rgb.append(torch.sigmoid(relu_mlp(geo, self.color_net)))
        sigma = sig[0] if len(sig) == 1 else torch.cat(sig)
        if not with_rgb:
            return sigma, None
        return sigma, (rgb[0] if len(rgb) == 1 else torch.cat(rgb))

    def density(self, xyz: torch.Tensor) -> torch.Tensor:
        """Density ``(N,)`` at ``xyz (N, 3)``; 0 outside the AABB (unless :attr:`contract`)."""
        return self._decode(xyz, None, with_rgb=False)[0]

    def forward(self, xyz: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(sigma (N,), rgb (N, 3))`` at ``xyz (N, 3)`` seen along unit ``dirs (N, 3)``."""
        return self._decode(xyz, dirs, with_rgb=True)

    def regularizer(self) -> torch.Tensor:
        """Plane total variation ``mean(d_a^2) + mean(d_b^2)`` per plane, summed over planes, averaged over scales
        (:func:`~senerf.fields.interp.plane_tv`)."""
        return plane_tv(self.table, self.resolutions, self.offsets)
