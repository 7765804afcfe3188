"""The interface every radiance field satisfies, and the helpers the fields share."""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["RadianceField", "trunc_exp", "check_points", "normalize_aabb", "as_aabb", "contract_unit",
           "uncontract_unit", "field_coords"]

#: ``|u|`` beyond which box coordinates are clamped before the contraction (finite in float32, contracts to 2)
_HUGE = 1e30


class RadianceField(nn.Module):
    """A field maps world (or NDC) points to a density ``>= 0`` and a colour in [0, 1].

    Subclasses implement :meth:`density` (self-training queries a teacher's at arbitrary points) and
    :meth:`forward` (the renderer's call); the trainer adds :meth:`regularizer`, 0 by default, to its loss.
    A field of an unbounded scene sets :attr:`contract` (:func:`field_coords`); the renderer then spaces its
    samples evenly in the contracted space (:func:`senerf.fields.ray_bins`).

    Attributes:
        aabb: ``(2, 3)`` box (a buffer of the subclass), or ``None``: the box mapped to ``[-1, 1]^3``, or with
            :attr:`contract` the inner region kept as it is while all of space beyond it is contracted.
        contract: the field covers all of space (:func:`contract_unit` beyond ``aabb``).
    """

    contract = False

    def density(self, xyz: torch.Tensor) -> torch.Tensor:
        """Density at points.

        Args:
            xyz: ``(N, 3)`` points.
        Returns:
            sigma ``(N,)``, non-negative, finite.
        """
        raise NotImplementedError

    def forward(self, xyz: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Density and colour.

        Args:
            xyz: ``(N, 3)`` points.
            dirs: ``(N, 3)`` unit view directions (ignored by view-independent fields).
        Returns:
            ``(sigma (N,), rgb (N, 3))``.
        """
        raise NotImplementedError

    def regularizer(self) -> torch.Tensor:
        """Scalar regulariser to add to the loss (0 when the field has none)."""
        p = next(self.parameters(), None)
        return torch.zeros((), device=None if p is None else p.device)


class _TruncExp(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x):
        ctx.save_for_backward(x)
        return torch.exp(x.clamp(max=15.0))

    @staticmethod
    def backward(ctx, g):
        (x,) = ctx.saved_tensors
        return g * torch.exp(x.clamp(-15.0, 15.0))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    """Truncated exponential density activation (K-Planes / instant-NGP): finite value and gradient.

    Args:
        x: any shape.
    Returns:
        ``exp(min(x, 15))``, same shape; its gradient is ``exp(clamp(x, -15, 15))``.
    """
    return _TruncExp.apply(x)


def as_aabb(aabb) -> torch.Tensor:
    """``aabb`` as a float32 ``(2, 3)`` tensor ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``; checks min < max."""
    box = torch.as_tensor(aabb, dtype=torch.float32).detach().clone()
    if box.shape != (2, 3):
        raise ValueError(f"aabb: expected shape (2, 3), got {tuple(box.shape)}")
    if not bool((box[1] > box[0]).all()):
        raise ValueError(f"aabb: every max must exceed its min, got {box.tolist()}")
    return box


def check_points(xyz: torch.Tensor, name: str = "xyz") -> None:
    """Raise ``ValueError`` unless ``xyz`` is a floating ``(N, 3)`` tensor."""
    if not isinstance(xyz, torch.Tensor) or xyz.ndim != 2 or xyz.shape[1] != 3:
        shape = tuple(xyz.shape) if isinstance(xyz, torch.Tensor) else type(xyz).__name__
        raise ValueError(f"{name}: expected a tensor of shape (N, 3), got {shape}")
    if not xyz.is_floating_point():
        raise ValueError(f"{name}: expected a floating tensor, got {xyz.dtype}")


def normalize_aabb(xyz: torch.Tensor, aabb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Map points of the box to ``[-1, 1]^3``.

    Args:
        xyz: ``(N, 3)`` points.
        aabb: ``(2, 3)`` box.
    Returns:
        ``(u (N, 3), inside (N,) bool)``; ``u`` is *not* clamped, ``inside`` means all ``|u| <= 1``.
    """
    lo, hi = aabb.to(xyz)
    u = (xyz - lo) * (2.0 / (hi - lo)) - 1.0
    inside = (u.abs() <= 1.0).all(dim=-1)
    return u, inside


def contract_unit(u: torch.Tensor) -> torch.Tensor:
    """The scene contraction of mip-NeRF 360 in the L-infinity norm (as nerfstudio and K-Planes), halved: box
    coordinates ``u`` with ``|u|_inf <= 1`` map to ``u / 2``, the rest to ``(2 - 1/|u|_inf) u / |u|_inf / 2``,
    so all of space lands in ``[-1, 1]^3`` and the inner box fills its middle half.

    Args:
        u: ``(..., 3)`` finite box coordinates (:func:`normalize_aabb`).
    Returns:
        ``(..., 3)`` in ``[-1, 1]``; continuous, with a continuous first derivative across the box's faces.

    Example:
        >>> contract_unit(torch.tensor([[0.5, 0.0, 0.0], [4.0, 2.0, 0.0]])).tolist()
        [[0.25, 0.0, 0.0], [0.875, 0.4375, 0.0]]
    """
    norm = u.abs().amax(dim=-1, keepdim=True).clamp(min=1.0)   # clamp before divide: 1 inside the box
    return u * ((2.0 - 1.0 / norm) / norm * 0.5)


def uncontract_unit(c: torch.Tensor) -> torch.Tensor:
    """The inverse of :func:`contract_unit`: ``c (..., 3)`` with ``|c|_inf < 1`` to box coordinates ``(..., 3)``
    (``|c|_inf -> 1`` goes to infinity; it is clamped to ``1 - 1e-6``)."""
    v = 2.0 * c
    norm = v.abs().amax(dim=-1, keepdim=True).clamp(min=1.0, max=2.0 - 2e-6)
    return v / (norm * (2.0 - norm))


def field_coords(xyz: torch.Tensor, aabb: torch.Tensor, contract: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Model-frame points as a field's ``[-1, 1]^3`` coordinates.

    Args:
        xyz: ``(N, 3)`` points.
        aabb: ``(2, 3)`` box.
        contract: contract all of space (:func:`contract_unit`) instead of keeping only the box.
    Returns:
        ``(u (N, 3), inside (N,) bool)``: without ``contract`` as :func:`normalize_aabb`; with it, ``u`` in
        ``[-1, 1]`` and ``inside`` every finite point (NaN coordinates are outside; infinite ones contract to 1).
    """
    u, inside = normalize_aabb(xyz, aabb)
    if not contract:
        return u, inside
    inside = ~torch.isnan(u).any(dim=-1)
    return contract_unit(torch.nan_to_num(u, nan=0.0).clamp(-_HUGE, _HUGE)), inside
