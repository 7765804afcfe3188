"""Analytic radiance fields (no parameters) shared by the tests of senerf.fields."""

from __future__ import annotations

import torch

from senerf.fields import RadianceField


class BallField(RadianceField):
    """Density ``value`` inside a ball of ``radius`` at ``center``, 0 outside; colour = fixed ``rgb``."""

    def __init__(self, center=(0.0, 0.0, 0.0), radius=0.5, value=10.0, rgb=(0.2, 0.4, 0.6)):
        super().__init__()
        self.register_buffer("center", torch.tensor(center, dtype=torch.float32))
        self.register_buffer("rgb", torch.tensor(rgb, dtype=torch.float32))
        self.radius = radius
        self.value = value
        self.calls = 0

    def density(self, xyz):
        self.calls += xyz.shape[0]
        inside = (xyz - self.center).norm(dim=-1) <= self.radius
        return inside.to(xyz.dtype) * self.value

    def forward(self, xyz, dirs):
        return self.density(xyz), self.rgb.to(xyz.dtype).expand(xyz.shape[0], 3)


class ConstantField(RadianceField):
    """Density ``value`` and colour ``rgb`` everywhere."""

    def __init__(self, value=0.5, rgb=(0.2, 0.4, 0.6)):
        super().__init__()
        self.value = value
        self.colour = torch.tensor(rgb)

    def density(self, xyz):
        return torch.full((xyz.shape[0],), self.value, dtype=xyz.dtype)

    def forward(self, xyz, dirs):
        return self.density(xyz), self.colour.to(xyz.dtype).expand(xyz.shape[0], 3)
