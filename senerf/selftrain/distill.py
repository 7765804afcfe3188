"""Reliability-based distillation from a teacher field to a student field (torch), the paper's Algorithm 2.

Per student step, :class:`DistillationLoss` draws a batch of pseudo-view rays, queries the teacher under
``torch.no_grad`` at its own stratified points and renders the student at *its own* random point of the *same*
bins (``senerf.fields.ray_bins``), so bin ``k`` pairs with bin ``k`` and the different
positions inside a bin are the paper's student noise.  Nothing of size rays x samples is kept between steps.

Losses (``lambda_c = 1``, ``lambda_g = 1``, ``lambda_p = 0.005`` by default), on the per-bin volume-rendering
weights ``w_k = T_k alpha_k`` (the paper's "Weight(T, r)", in [0, 1]) with ``d(a, b) = sum_k (a_k - b_k)^2``:

* reliable colour ``L_c = mean_r  m_r ||C_T(r) - C_S(r)||^2`` over a batch of reliable rays (``m_r`` = 1
  for the hard thresholds, the soft weight for 'unified');
* reliable geometry ``L_g = mean_r  m_r  d(w_T(r), w_S(r))``;
* prior for unreliable rays ``L_p = mean_r  (1 - m_r)  d(w~_T(r), w_S(r))`` over unreliable foreground rays
  with at least one reliable neighbour, ``w~_T`` the average of the teacher's weights on the neighbours' rays
  with the weights of :func:`prior_weights` (or :func:`unified_prior_weights`), queried at the *same per-bin
  fractions* for the whole kernel.

Kernel: the paper's prose says "Q x Q kernel ... centre excluded" (8 neighbours for Q = 3) while its set
notation ``Omega_x x Omega_y`` taken literally leaves only the 4 diagonal pixels; we follow the prose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..config import BACKGROUNDS, SelfTrainConfig
from ..fields import contraction_box, ray_bins, render_rays, volume_render
from ..train import background_color
from .reliability import check_shape

__all__ = ["gaussian_kernel", "neighbour_offsets", "prior_weights", "unified_prior_weights", "PseudoRays",
           "DistillationLoss"]


def neighbour_offsets(q: int = 3) -> np.ndarray:
    """``(q*q - 1, 2)`` int64 offsets ``(dy, dx)`` of a q x q window, row-major, centre excluded."""
    if q < 3 or q % 2 == 0:
        raise ValueError(f"q must be odd and >= 3, got {q}")
    r = q // 2
    offs = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dy, dx) != (0, 0)]
    return np.asarray(offs, dtype=np.int64)


def gaussian_kernel(q: int = 3, std: float = 1.0) -> np.ndarray:
    """``(q*q - 1,)`` Gaussian weights ``exp(-(dx^2 + dy^2) / (2 std^2))`` at :func:`neighbour_offsets`,
    normalised to sum 1 over the window without its centre (the discrete pmf ``g``)."""
    offs = neighbour_offsets(q).astype(np.float64)
    g = np.exp(-(offs ** 2).sum(axis=1) / (2.0 * std ** 2))
    return g / g.sum()


def _shift(a: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    """``out[..., y, x] = a[..., y + dy, x + dx]`` (``fill`` outside the image)."""
    h, w = a.shape[-2:]
    out = np.full_like(a, fill)
    ys, ye = max(0, -dy), min(h, h - dy)
    xs, xe = max(0, -dx), min(w, w - dx)
    if ys < ye and xs < xe:
        out[..., ys:ye, xs:xe] = a[..., ys + dy:ye + dy, xs + dx:xe + dx]
    return out


def _neighbour_weights(raw, q: int, std: float) -> tuple[np.ndarray, np.ndarray]:
    """The neighbour weights of :func:`prior_weights` (same returns) from ``raw(dy, dx) -> (..., H, W)``, each
    pixel's unnormalised weight of its neighbour at ``(dy, dx)``: times :func:`gaussian_kernel`, normalised over
    the window, zero where they sum to zero."""
    g = gaussian_kernel(q, std)
    stacked = np.stack([raw(dy, dx) * g[i] for i, (dy, dx) in enumerate(neighbour_offsets(q))], axis=-1)
    total = stacked.sum(axis=-1, keepdims=True)
    has = total[..., 0] > 0
    return np.where(total > 0, stacked / np.where(total > 0, total, 1.0), 0.0).astype(np.float32), has


def prior_weights(reliable: np.ndarray, q: int = 3, std: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Normalised Gaussian weights of each pixel's reliable neighbours.

    Args:
        reliable: (..., H, W) reliability mask (bool, or weights in [0, 1] used as ``M``).
    Returns:
        (weights (..., H, W, q*q - 1) float32 in the order of :func:`neighbour_offsets`, summing to 1 where
        ``has_neighbour``; has_neighbour (..., H, W) bool: at least one reliable neighbour in the window).
        Out-of-image neighbours count as unreliable.
    """
    m = np.asarray(reliable, dtype=np.float64)
    if m.ndim < 2:
        raise ValueError(f"reliable must be (..., H, W), got {m.shape}")
    return _neighbour_weights(lambda dy, dx: _shift(m, dy, dx, 0.0), q, std)


def unified_prior_weights(similarity: np.ndarray, foreground: np.ndarray, q: int = 3, std: float = 1.0
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The paper's 'unified' neighbour weights ``max(s_xy - s_ij, 0) g`` over foreground neighbours.

    Args:
        similarity: (..., H, W); foreground: (..., H, W) bool.
    Returns:
        as :func:`prior_weights`.
    """
    s = np.asarray(similarity, dtype=np.float64)
    fg = np.asarray(foreground, dtype=bool)
    check_shape("foreground", fg.shape, s.shape)

    def gain(dy: int, dx: int) -> np.ndarray:   # how much more similar the foreground neighbour is, or 0
        return np.where(_shift(fg, dy, dx, False), np.maximum(_shift(s, dy, dx, -np.inf) - s, 0.0), 0.0)

    return _neighbour_weights(gain, q, std)


@dataclass(eq=False)
class PseudoRays:
    """Every pseudo-view ray of one iteration with its reliability (flattened over ``(P, H, W)``).

    Attributes:
        origins, dirs: (N, 3) float32 field-space rays, N = P*H*W.
        near, far: (N,) float32.
        shape: (P, H, W).
        reliable: (N,) float32 reliable weight ``m`` in [0, 1] (0: not reliable or background).
        prior: (N,) float32 prior weight ``1 - m`` for rays that get the prior (0 elsewhere).
        neighbour: (N, Q*Q - 1) float32 normalised neighbour weights (order of :func:`neighbour_offsets`).
        q: kernel size Q.
    """

    origins: torch.Tensor
    dirs: torch.Tensor
    near: torch.Tensor
    far: torch.Tensor
    shape: tuple
    reliable: torch.Tensor
    prior: torch.Tensor
    neighbour: torch.Tensor
    q: int = 3

    def __post_init__(self) -> None:
        n = int(np.prod(self.shape))
        if len(self.shape) != 3:
            raise ValueError(f"shape must be (P, H, W), got {self.shape}")
        for name, tail in (("origins", (3,)), ("dirs", (3,)), ("near", ()), ("far", ()), ("reliable", ()),
                           ("prior", ()), ("neighbour", (self.q * self.q - 1,))):
            check_shape(name, getattr(self, name).shape, (n, *tail))
        self._reliable_idx = torch.nonzero(self.reliable > 0).squeeze(1)
        self._prior_idx = torch.nonzero(self.prior > 0).squeeze(1)
        self._offsets = torch.as_tensor(neighbour_offsets(self.q), device=self.origins.device)

    def sample_reliable(self, batch: int, generator: torch.Generator) -> torch.Tensor:
        """(batch,) int64 flat indices drawn uniformly (with replacement) among rays with ``reliable > 0``."""
        return self._draw(self._reliable_idx, batch, generator)

    def sample_prior(self, batch: int, generator: torch.Generator) -> torch.Tensor:
        """(batch,) int64 flat indices drawn uniformly among rays with ``prior > 0``."""
        return self._draw(self._prior_idx, batch, generator)

    @staticmethod
    def _draw(pool: torch.Tensor, batch: int, generator: torch.Generator) -> torch.Tensor:
        if pool.numel() == 0:
            return pool
        pick = torch.randint(0, pool.numel(), (batch,), generator=generator, device=pool.device)
        return pool[pick]

    def neighbours(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat indices (B, Q*Q-1) of the window around rays ``idx (B,)`` (clamped at the image edge; those
        carry neighbour weight 0) and their normalised weights (B, Q*Q-1)."""
        p_, h, w = self.shape
        y = (idx // w) % h
        x = idx % w
        base = idx - y * w - x
        ny = (y[:, None] + self._offsets[:, 0]).clamp(0, h - 1)
        nx = (x[:, None] + self._offsets[:, 1]).clamp(0, w - 1)
        return base[:, None] + ny * w + nx, self.neighbour[idx]


class DistillationLoss:
    """The trainer's ``extra_loss(field, step, generator, occupancy) -> (loss, logs)`` for one self-training
    iteration.  The student's pseudo rays are marched through the teacher's grid, not through the trainer's
    ``occupancy`` (the student's current grid, or None), which is accepted and not used.

    Args:
        teacher: the teacher :class:`~senerf.fields.RadianceField` (frozen, queried under no_grad).
        pseudo: :class:`PseudoRays` of this iteration.
        cfg: the :class:`~senerf.config.SelfTrainConfig` (its batch sizes, loss weights and kernel).
        n_samples: bins per ray (the model's ``n_samples``).
        background: 'random' (one colour per batch, shared by teacher and student), 'white' or 'black'.
        teacher_occupancy: the teacher's :class:`~senerf.fields.OccupancyGrid` (or None): the teacher is
            queried as it renders, with samples in its empty cells at density 0, and the student's pseudo rays
            skip those cells too.
    """

    def __init__(self, teacher, pseudo: PseudoRays, cfg: SelfTrainConfig, n_samples: int,
                 background: str = "random", teacher_occupancy=None):
        if n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        if background not in BACKGROUNDS:   # here, not at the first step of a training
            raise ValueError(f"background must be one of {BACKGROUNDS}, got {background!r}")
        self.teacher = teacher
        self.pseudo = pseudo
        self.cfg = cfg
        self.n_samples = int(n_samples)
        self.background = background
        self.teacher_occupancy = teacher_occupancy
        for p in teacher.parameters():
            p.requires_grad_(False)
        teacher.eval()

    @torch.no_grad()
    def _prior_target(self, idx: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """Teacher target (B, S) for prior rays ``idx (B,)``: neighbours queried at shared bin fractions."""
        pr = self.pseudo
        nb_idx, nb_w = pr.neighbours(idx)                     # (B, K)
        u = torch.rand(idx.shape[0], self.n_samples, generator=generator, device=idx.device)
        rows, cols = torch.nonzero(nb_w > 0, as_tuple=True)   # only reliable neighbours are queried
        flat = nb_idx[rows, cols]
        near, far = pr.near[flat], pr.far[flat]
        t = ray_bins(pr.origins[flat], pr.dirs[flat], near, far, u[rows],   # the same fractions for the kernel
                     contraction_box(self.teacher))
        pts = pr.origins[flat][:, None, :] + t[..., None] * pr.dirs[flat][:, None, :]
        flat_pts = pts.reshape(-1, 3)
        if self.teacher_occupancy is None:
            sigma = self.teacher.density(flat_pts)
        else:  # only occupied cells are evaluated, as the teacher renders
            keep = self.teacher_occupancy.is_occupied(flat_pts).nonzero().squeeze(1)
            sigma = flat_pts.new_zeros(flat_pts.shape[0])
            sigma.index_copy_(0, keep, self.teacher.density(flat_pts[keep]).to(sigma.dtype))
        val = volume_render(sigma.reshape(t.shape), torch.zeros(*t.shape, 3, device=t.device), t, far)["weights"]
        target = torch.zeros(idx.shape[0], self.n_samples, device=idx.device, dtype=val.dtype)
        target.index_add_(0, rows, nb_w[rows, cols][:, None] * val)
        return target

    def __call__(self, field, step: int, generator: torch.Generator, occupancy=None):
        cfg, pr = self.cfg, self.pseudo
        dev = pr.origins.device
        bg = background_color(self.background, generator, dev)
        rel = pr.sample_reliable(cfg.batch_reliable, generator)
        use_prior = cfg.prior and cfg.lambda_prior > 0
        pri = pr.sample_prior(cfg.batch_prior, generator) if use_prior else rel[:0]
        logs = {"n_reliable": float(rel.numel()), "n_prior": float(pri.numel())}
        total = torch.zeros((), device=dev)
        if rel.numel() + pri.numel() == 0:
            return total, logs
        idx = torch.cat([rel, pri])
        student = render_rays(field, pr.origins[idx], pr.dirs[idx], pr.near[idx], pr.far[idx],
                              self.n_samples, generator, bg, occupancy=self.teacher_occupancy)
        nr = rel.numel()
        if nr:
            with torch.no_grad():
                teacher = render_rays(self.teacher, pr.origins[rel], pr.dirs[rel], pr.near[rel], pr.far[rel],
                                      self.n_samples, generator, bg, occupancy=self.teacher_occupancy)
            m = pr.reliable[rel]
            l_c = (m * ((teacher["rgb"] - student["rgb"][:nr]) ** 2).sum(dim=1)).mean()
            total = total + cfg.lambda_color * l_c
            logs["distill_color"] = l_c.detach()   # a float at log steps only (no GPU sync per step)
            if cfg.density_distill and cfg.lambda_geometry > 0:
                l_g = (m * ((teacher["weights"] - student["weights"][:nr]) ** 2).sum(dim=1)).mean()
                total = total + cfg.lambda_geometry * l_g
                logs["distill_geometry"] = l_g.detach()
        if pri.numel():
            target = self._prior_target(pri, generator)
            l_p = (pr.prior[pri] * ((target - student["weights"][nr:]) ** 2).sum(dim=1)).mean()
            total = total + cfg.lambda_prior * l_p
            logs["distill_prior"] = l_p.detach()
        return total, logs
