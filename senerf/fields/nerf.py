"""Vanilla NeRF MLP with coarse-to-fine positional-encoding annealing (the paper's NeRF teacher)."""

from __future__ import annotations

import torch
from torch import nn

from .base import RadianceField, as_aabb, check_points, field_coords
from .encoding import anneal_weights, positional_encoding, sh_encoding
from .mlp import make_generator, seeded_linear

__all__ = ["NeRFField"]


class NeRFField(RadianceField):
    """MLP field on the positional encoding of (AABB-normalised) points.

    The encoding's bands are weighted by :func:`~senerf.fields.anneal_weights` of ``eta = n_freqs * step / N``
    (:meth:`set_progress`); before any call to :meth:`set_progress` every weight is 1.

    Args:
        aabb: ``(2, 3)`` box or ``None``; with a box, points are mapped to ``[-1, 1]^3`` and points outside
            have density 0; without, points are used as given.
        contract: all of space is the field's, contracted beyond ``aabb`` (:func:`~senerf.fields.field_coords`).
        n_freqs: positional-encoding octaves for points.
        hidden, n_layers: trunk width and depth (a skip connection re-injects the encoding at the middle).
        view_dependent: colour head sees the SH (degree 4) encoding of the direction.
        anneal_steps: N of the schedule (``None``: a quarter of ``total_steps`` of :meth:`set_progress`).
        generator: seeds the initial weights (``None`` = seed 0).
    """

    def __init__(self, aabb=None, n_freqs: int = 10, hidden: int = 128, n_layers: int = 4,
                 view_dependent: bool = True, anneal_steps: int | None = None,
                 generator: torch.Generator | None = None, contract: bool = False):
        super().__init__()
        gen = make_generator(generator)
        if contract and aabb is None:
            raise ValueError("contract: needs the aabb of the inner region")
        self.register_buffer("aabb", None if aabb is None else as_aabb(aabb))
        self.contract = bool(contract)
        self.n_freqs = int(n_freqs)
        self.anneal_steps = anneal_steps
        self.view_dependent = bool(view_dependent)
        self.register_buffer("band_weights", torch.ones(self.n_freqs))
        n_enc = 3 * (2 * self.n_freqs + 1)
        self.skip = n_layers // 2
        widths = [n_enc if i == 0 else hidden + (n_enc if i == self.skip else 0) for i in range(n_layers)]
        self.trunk = nn.ModuleList(seeded_linear(n_in, hidden, gen) for n_in in widths)
        self.sigma_head = seeded_linear(hidden, 1, gen)
        self.feat = seeded_linear(hidden, hidden, gen)
        c_in = hidden + (16 if self.view_dependent else 0)   # 16 SH coefficients (degree 4)
        self.color_head = nn.Sequential(seeded_linear(c_in, hidden // 2, gen), nn.ReLU(),
                                        seeded_linear(hidden // 2, 3, gen))

    def set_progress(self, step: int, total_steps: int | None = None) -> torch.Tensor:
        """Set the band weights for training ``step``; returns them ``(n_freqs,)``."""
        if self.anneal_steps is None and total_steps is None:
            raise ValueError("set_progress: give total_steps or construct with anneal_steps")
        n = self.anneal_steps if self.anneal_steps is not None else total_steps / 4.0
        eta = self.n_freqs * float(step) / max(float(n), 1e-12)
        self.band_weights.copy_(anneal_weights(eta, self.n_freqs))
        return self.band_weights.clone()

    def _trunk(self, xyz):
        check_points(xyz)
        if self.aabb is not None:
            u, inside = field_coords(xyz, self.aabb, self.contract)
        else:
            u, inside = xyz, torch.ones(xyz.shape[0], dtype=torch.bool, device=xyz.device)
        enc = positional_encoding(u, self.n_freqs, self.band_weights)
        h = enc
        for i, layer in enumerate(self.trunk):
            if i == self.skip and i > 0:
                h = torch.cat([h, enc], dim=-1)
            h = torch.relu(layer(h))
        sigma = nn.functional.softplus(self.sigma_head(h)[:, 0] - 1.0) * inside.to(h.dtype)
        return sigma, h

    def density(self, xyz: torch.Tensor) -> torch.Tensor:
        """Density ``(N,)`` at ``xyz (N, 3)`` (softplus of the raw output minus 1)."""
        return self._trunk(xyz)[0]

    def forward(self, xyz: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(sigma (N,), rgb (N, 3))``."""
        sigma, h = self._trunk(xyz)
        f = self.feat(h)
        if self.view_dependent:
            if dirs is None or dirs.shape != xyz.shape:
                raise ValueError(f"dirs: expected shape {tuple(xyz.shape)}")
            f = torch.cat([f, sh_encoding(dirs.to(f.dtype))], dim=-1)
        return sigma, torch.sigmoid(self.color_head(f))
