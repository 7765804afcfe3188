"""Reliability-based distillation from a teacher field to a student field (torch).

Per training step of the student (through the trainer's ``extra_loss(field, step, generator, occupancy)``
hook), :class:`DistillationLoss` draws a batch of pseudo-view rays, queries the teacher under ``torch.no_grad`` at
its own stratified points and renders the student at *its own* random point of the *same* evenly spaced bins
(``senerf.fields.stratified_bins``: bin ``k`` has the same bounds for both), so bin ``k`` pairs with bin
``k`` and the different positions inside a bin are the paper's student noise.  Nothing of size
rays x samples is kept between steps.

Losses (``lambda_c = 1``, ``lambda_g = 1``, ``lambda_p = 0.005`` by default):

* reliable colour ``L_c = mean_r  m_r ||C_T(r) - C_S(r)||^2`` over a batch of reliable rays (``m_r`` = 1
  for the hard thresholds, the soft weight for 'unified');
* reliable geometry ``L_g = mean_r  m_r  d(g_T(r), g_S(r))``: with ``geometry_target='weights'`` (default,
  the paper's Algorithm 2 "Weight(T, r)") ``g`` are the per-bin volume-rendering weights
  ``w_k = T_k alpha_k`` (bounded in [0, 1], summed over bins: ``d = sum_k (w_T,k - w_S,k)^2``); with
  ``'log_density'`` ``g = log1p(sigma)`` at the bin points, ``d`` = the mean over bins (raw densities span
  orders of magnitude, so we compress them);
* prior for unreliable rays ``L_p = mean_r  (1 - m_r)  d(g~_T(r), g_S(r))`` over unreliable foreground rays
  with at least one reliable neighbour, ``g~_T`` the Gaussian-weighted average (Q x Q, std 1 px, centre
  excluded, only reliable neighbours) of the teacher's per-bin values on the neighbours' rays, queried at
  the *same per-bin fractions* for the whole kernel.

Kernel: the paper's prose says "Q x Q kernel ... centre excluded" (8 neighbours for Q = 3) while its set
notation ``Omega_x x Omega_y`` taken literally leaves only the 4 diagonal pixels; we follow the prose.
For 'unified' the neighbour weights are ``max(s_xy - s_ij, 0) g(x, y)`` as in the paper's unified equation.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import is_number   # re-exported: this module named it first (see __all__)
from ..fields import render_rays, volume_render

__all__ = [
    "DistillConfig",
    "DistillConfigError",
    "gaussian_kernel",
    "neighbour_offsets",
    "prior_weights",
    "unified_prior_weights",
    "gaussian_prior",
    "PseudoRays",
    "DistillationLoss",
    "bins_with_fractions",
    "GEOMETRY_TARGETS",
    "STUDENT_GRIDS",
    "BACKGROUNDS",
    "is_number",
]

GEOMETRY_TARGETS = ("weights", "log_density")
STUDENT_GRIDS = ("teacher", "student", "none")
BACKGROUNDS = ("random", "white", "black")   # DistillationLoss's background policies


@dataclass(frozen=True)
class DistillConfig:
    """Settings of the distillation losses.

    Attributes:
        batch_reliable: reliable pseudo rays per step (foreground rays: most of their samples fall in
            occupied cells, so a pseudo ray costs more than an average real ray).  2048 instead of 512
            measured -0.08 ± 0.53 dB (see the end of this docstring for how).
        batch_prior: unreliable (prior) pseudo rays per step.
        batch_empty: 0: reliable *empty* rays (see ``SelfTrainConfig.empty_opacity``) share the reliable pool,
            so they make up most of each reliable batch (on lego Extreme at 100x100 ~95 % of the reliable
            pool is empty space: ~26 of 512 rays per step are reliable surface rays); > 0: the reliable
            batch is drawn from reliable *surface* rays only and this many empty rays are drawn on top,
            with the same colour and geometry losses (averaged over both).  Needs ``PseudoRays.empty``.
            Measured (lego Extreme 100x100, fast preset, seeds 0-2, paired; harness method
            ``senerf-batch-empty``: 512 + 512): -0.30 ± 0.04 dB (p = 0.007), and slower (120 ± 5 s a fit
            against 97 ± 8 s for ``senerf-student-grid`` in the same session): twenty times more surface
            distillation hurts, so 0 stays the default.
        lambda_color, lambda_geometry, lambda_prior: loss weights (paper: 1.0, 1.0, 0.005).  A ten times
            stronger prior (0.05) measured -0.40 ± 0.11 dB.  The colour loss sums the squared error over the
            three channels (the paper's squared L2 norm, averaged over rays) while the trainer's
            photometric loss averages them, so against the photometric loss ``lambda_color`` counts three
            times; 1/3 (the same per-channel scale) measured +0.07 ± 0.46 dB (17.07 / 17.65 / 17.88), so
            the paper's weight stays as written.  Each term is a mean over its own pool (reliable rays,
            prior rays), where the paper's equations sum over the pseudo rays, so here the prior's weight
            against the geometry term is ``lambda_prior / lambda_geometry`` whatever the pools' sizes.  With
            the empty rays in the reliable pool (~26 surface rays of 512, above) the prior weighs about 0.1 of
            the surface rays' geometry term per step; the paper's sums over lego's labels (prior on 11.5 %,
            reliable 14.9 % of the foreground, no empty rays) would give ~0.004.  ``lambda_prior`` 0.0002,
            which restores that ratio, measured +0.05 ± 0.13 dB over seeds 0-5 (p = 0.35), so the paper's
            0.005 stays.
        geometry_target: 'weights' (per-bin rendering weights, default) or 'log_density' (measured -0.39 ±
            0.27 dB).
        density_distill: enable the reliable geometry loss (ablation flag).
        prior: enable the prior loss for unreliable rays (ablation flag).
        kernel_size: Q (odd), kernel_std: Gaussian std in pixels (paper: 3, 1; Q = 5 with std 1.5 measured
            -0.15 ± 0.06 dB).
        student_grid: the occupancy grid the *student's* pseudo rays are marched through (samples in its
            empty cells are not evaluated and count as density 0): 'teacher' (the teacher's grid: about 5x
            cheaper on object scenes than no grid, but no distillation gradient reaches the student's density
            inside the teacher's empty cells, so floaters the student grows there go unpunished by the empty
            rays), 'student' (the student's own current grid, the one it renders with: what it would show is
            what is distilled; all-occupied until the trainer's first grid update) or 'none' (every sample).
            Measured (lego Extreme 100x100, paired with 'teacher' by seed): 'student' fast preset +0.13 ±
            0.39 dB over 6 seeds (p = 0.47), balanced +0.00 ± 0.07 over 3 (p = 0.94); 'none' fast +0.12 ±
            0.32 over 6 seeds (p = 0.41; 111 ± 9 s a fit against the student grid's 97 ± 8 s in the same session),
            balanced +0.12 ± 0.17 over 3 (p = 0.34).  No measurable gain, so 'teacher' stays.

    "Measured" without more: lego Extreme at 100x100, fast preset (one iteration), research runs over
    ``run_selftraining`` with that one setting changed, seeds 0-2, paired by seed with the defaults'
    17.44 / 17.10 / 17.85 dB (BENCHMARKS.md, session 5); mean ± std of the paired differences.

    Raises:
        DistillConfigError: a ``ValueError`` whose ``field`` (and first word) names the setting out of range:
            batch sizes integers (``>= 1``; ``batch_empty >= 0``), loss weights finite and ``>= 0``,
            ``kernel_size`` an odd integer ``>= 3``, ``kernel_std`` finite and ``> 0``.  NumPy integers are taken as
            plain ints.
    """

    batch_reliable: int = 512
    batch_prior: int = 128
    batch_empty: int = 0
    lambda_color: float = 1.0
    lambda_geometry: float = 1.0
    lambda_prior: float = 0.005
    geometry_target: str = "weights"
    density_distill: bool = True
    prior: bool = True
    kernel_size: int = 3
    kernel_std: float = 1.0
    student_grid: str = "teacher"

    def __post_init__(self) -> None:
        for name, least in (("batch_reliable", 1), ("batch_prior", 1), ("batch_empty", 0)):
            _integer(self, name, least)
        for name in ("lambda_color", "lambda_geometry", "lambda_prior"):
            value = getattr(self, name)
            if not (is_number(value) and value >= 0):
                raise DistillConfigError(name, f"must be a finite number >= 0, got {value!r}")
        if self.geometry_target not in GEOMETRY_TARGETS:
            raise DistillConfigError("geometry_target", f"must be one of {GEOMETRY_TARGETS}, got "
                                                         f"{self.geometry_target!r}")
        if self.student_grid not in STUDENT_GRIDS:
            raise DistillConfigError("student_grid", f"must be one of {STUDENT_GRIDS}, got {self.student_grid!r}")
        _integer(self, "kernel_size", 3)
        if self.kernel_size % 2 == 0:
            raise DistillConfigError("kernel_size", f"must be odd and >= 3, got {self.kernel_size!r}")
        if not (is_number(self.kernel_std) and self.kernel_std > 0):
            raise DistillConfigError("kernel_std", f"must be a finite number > 0, got {self.kernel_std!r}")


class DistillConfigError(ValueError):
    """A :class:`DistillConfig` field out of range: ``field`` names it, the message starts with it."""

    def __init__(self, field: str, message: str):
        super().__init__(field, message)   # both in args: the error pickles (a worker process hands it back)
        self.field, self.message = field, message

    def __str__(self) -> str:
        return f"{self.field} {self.message}"


def _integer(cfg, name: str, least: int) -> None:
    """``cfg.name`` as a plain int ``>= least`` (NumPy integers too, not bools); DistillConfigError otherwise."""
    value = getattr(cfg, name)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
        raise DistillConfigError(name, f"must be an integer >= {least}, got {value!r}")
    object.__setattr__(cfg, name, int(value))


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


def _normalise(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    total = raw.sum(axis=-1, keepdims=True)
    has = total[..., 0] > 0
    return np.where(total > 0, raw / np.where(total > 0, total, 1.0), 0.0).astype(np.float32), has


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
    g = gaussian_kernel(q, std)
    raw = np.stack([_shift(m, dy, dx, 0.0) * g[i] for i, (dy, dx) in enumerate(neighbour_offsets(q))], axis=-1)
    return _normalise(raw)


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
    if s.shape != fg.shape:
        raise ValueError(f"similarity {s.shape} and foreground {fg.shape} differ")
    g = gaussian_kernel(q, std)
    raw = []
    for i, (dy, dx) in enumerate(neighbour_offsets(q)):
        s_n = _shift(s, dy, dx, -np.inf)
        fg_n = _shift(fg, dy, dx, False)
        raw.append(np.where(fg_n, np.maximum(s_n - s, 0.0), 0.0) * g[i])
    return _normalise(np.stack(raw, axis=-1))


def gaussian_prior(reliable: np.ndarray, teacher: np.ndarray, q: int = 3, std: float = 1.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Dense reference of the prior target: Gaussian-weighted average of reliable neighbours' values.

    Args:
        reliable: (H, W) bool mask.
        teacher: (H, W, S) teacher per-bin values (densities or weights) of every pixel's ray.
    Returns:
        (target (H, W, S) float32, zero where no reliable neighbour; has_neighbour (H, W) bool).
    """
    teacher = np.asarray(teacher, dtype=np.float64)
    reliable = np.asarray(reliable)
    if reliable.ndim != 2 or teacher.ndim != 3 or teacher.shape[:2] != reliable.shape:
        raise ValueError(f"need reliable (H, W) and teacher (H, W, S), got {reliable.shape}, {teacher.shape}")
    wts, has = prior_weights(reliable, q, std)
    vals = np.moveaxis(teacher, -1, 0)  # (S, H, W)
    target = np.zeros_like(vals)
    for i, (dy, dx) in enumerate(neighbour_offsets(q)):
        target += wts[..., i] * _shift(vals, dy, dx, 0.0)
    return np.moveaxis(target, 0, -1).astype(np.float32), has


def bins_with_fractions(near: torch.Tensor, far: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Points ``near + (k + u_k) (far - near) / S`` of :func:`senerf.fields.stratified_bins`' bins.

    Args:
        near, far: (R,); u: (R, S) fractions in [0, 1).
    Returns:
        t (R, S).
    """
    s = u.shape[-1]
    k = torch.arange(s, dtype=u.dtype, device=u.device)
    return near[:, None] + (k + u) * ((far - near)[:, None] / s)


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
        empty: (N,) bool, or None: reliable rays that are empty space (a subset of ``reliable > 0``);
            lets :class:`DistillationLoss` draw surface and empty rays from separate pools.
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
    empty: torch.Tensor | None = None

    def __post_init__(self) -> None:
        n = int(np.prod(self.shape))
        if len(self.shape) != 3:
            raise ValueError(f"shape must be (P, H, W), got {self.shape}")
        for name, tail in (("origins", (3,)), ("dirs", (3,)), ("near", ()), ("far", ()), ("reliable", ()),
                           ("prior", ()), ("neighbour", (self.q * self.q - 1,))):
            t = getattr(self, name)
            if tuple(t.shape) != (n, *tail):
                raise ValueError(f"{name} must be {(n, *tail)}, got {tuple(t.shape)}")
        self._reliable_idx = torch.nonzero(self.reliable > 0).squeeze(1)
        if self.empty is not None:
            if tuple(self.empty.shape) != (n,) or self.empty.dtype != torch.bool:
                raise ValueError(f"empty must be a (n,) = {(n,)} bool tensor, got {tuple(self.empty.shape)} "
                                 f"{self.empty.dtype}")
            if bool((self.empty & ~(self.reliable > 0)).any()):
                raise ValueError("empty rays must be reliable (reliable > 0)")
            self._empty_idx = torch.nonzero(self.empty).squeeze(1)
            self._surface_idx = torch.nonzero((self.reliable > 0) & ~self.empty).squeeze(1)
        self._prior_idx = torch.nonzero(self.prior > 0).squeeze(1)
        self._offsets = torch.as_tensor(neighbour_offsets(self.q), device=self.origins.device)

    @property
    def n_reliable(self) -> int:
        return int(self._reliable_idx.numel())

    @property
    def n_prior(self) -> int:
        return int(self._prior_idx.numel())

    def sample_reliable(self, batch: int, generator: torch.Generator) -> torch.Tensor:
        """(batch,) int64 flat indices drawn uniformly (with replacement) among rays with ``reliable > 0``."""
        return self._draw(self._reliable_idx, batch, generator)

    def sample_surface(self, batch: int, generator: torch.Generator) -> torch.Tensor:
        """(batch,) flat indices drawn uniformly among reliable rays that are not empty (needs ``empty``)."""
        self._need_empty()
        return self._draw(self._surface_idx, batch, generator)

    def sample_empty(self, batch: int, generator: torch.Generator) -> torch.Tensor:
        """(batch,) flat indices drawn uniformly among the empty rays (needs ``empty``)."""
        self._need_empty()
        return self._draw(self._empty_idx, batch, generator)

    def _need_empty(self) -> None:
        if self.empty is None:
            raise ValueError("these PseudoRays have no 'empty' mask")

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


def _background(kind: str, generator: torch.Generator, device) -> torch.Tensor:
    if kind == "random":
        return torch.rand(3, generator=generator, device=device)
    if kind == "white":
        return torch.ones(3, device=device)
    if kind == "black":
        return torch.zeros(3, device=device)
    raise ValueError(f"background must be one of {BACKGROUNDS}, got {kind!r}")


class DistillationLoss:
    """The trainer's ``extra_loss(field, step, generator, occupancy) -> (loss, logs)`` for one self-training
    iteration (``occupancy``: the student's current grid, or None).

    Args:
        teacher: the teacher :class:`~senerf.fields.RadianceField` (frozen, queried under no_grad).
        pseudo: :class:`PseudoRays` of this iteration.
        cfg: :class:`DistillConfig`.
        n_samples: bins per ray (the model's ``n_samples``).
        background: 'random' (one colour per batch, shared by teacher and student), 'white' or 'black'.
        teacher_occupancy: the teacher's :class:`~senerf.fields.OccupancyGrid` (or None): the teacher is
            queried as it renders, with samples in its empty cells at density 0.
    """

    def __init__(self, teacher, pseudo: PseudoRays, cfg: DistillConfig, n_samples: int,
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

    def _geometry(self, out: dict) -> torch.Tensor:
        if self.cfg.geometry_target == "weights":
            return out["weights"]
        return torch.log1p(out["sigma"])

    def _distance(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        d = (a - b) ** 2
        return d.sum(dim=1) if self.cfg.geometry_target == "weights" else d.mean(dim=1)

    @torch.no_grad()
    def _prior_target(self, idx: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """Teacher target (B, S) for prior rays ``idx (B,)``: neighbours queried at shared bin fractions."""
        pr = self.pseudo
        nb_idx, nb_w = pr.neighbours(idx)                     # (B, K)
        u = torch.rand(idx.shape[0], self.n_samples, generator=generator, device=idx.device)
        rows, cols = torch.nonzero(nb_w > 0, as_tuple=True)   # only reliable neighbours are queried
        flat = nb_idx[rows, cols]
        near, far = pr.near[flat], pr.far[flat]
        t = bins_with_fractions(near, far, u[rows])           # the same fractions for the whole kernel
        pts = pr.origins[flat][:, None, :] + t[..., None] * pr.dirs[flat][:, None, :]
        flat_pts = pts.reshape(-1, 3)
        if self.teacher_occupancy is None:
            sigma = self.teacher.density(flat_pts)
        else:  # only occupied cells are evaluated, as the teacher renders
            keep = self.teacher_occupancy.is_occupied(flat_pts).nonzero().squeeze(1)
            sigma = flat_pts.new_zeros(flat_pts.shape[0])
            sigma.index_copy_(0, keep, self.teacher.density(flat_pts[keep]).to(sigma.dtype))
        sigma = sigma.reshape(t.shape)
        if self.cfg.geometry_target == "weights":
            val = volume_render(sigma, torch.zeros(*t.shape, 3, device=t.device), t, far)["weights"]
        else:
            val = torch.log1p(sigma)
        target = torch.zeros(idx.shape[0], self.n_samples, device=idx.device, dtype=val.dtype)
        target.index_add_(0, rows, nb_w[rows, cols][:, None] * val)
        return target

    def _student_grid(self, occupancy):
        kind = self.cfg.student_grid
        return self.teacher_occupancy if kind == "teacher" else occupancy if kind == "student" else None

    def __call__(self, field, step: int, generator: torch.Generator, occupancy=None):
        cfg, pr = self.cfg, self.pseudo
        dev = pr.origins.device
        bg = _background(self.background, generator, dev)
        if cfg.batch_empty > 0:
            rel = torch.cat([pr.sample_surface(cfg.batch_reliable, generator),
                             pr.sample_empty(cfg.batch_empty, generator)])
        else:
            rel = pr.sample_reliable(cfg.batch_reliable, generator)
        use_prior = cfg.prior and cfg.lambda_prior > 0
        pri = pr.sample_prior(cfg.batch_prior, generator) if use_prior else rel[:0]
        logs = {"n_reliable": float(rel.numel()), "n_prior": float(pri.numel())}
        total = torch.zeros((), device=dev)
        if rel.numel() + pri.numel() == 0:
            return total, logs
        idx = torch.cat([rel, pri])
        student = render_rays(field, pr.origins[idx], pr.dirs[idx], pr.near[idx], pr.far[idx],
                              self.n_samples, generator, bg,
                              occupancy=self._student_grid(occupancy))
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
                g_s = self._geometry({k: v[:nr] for k, v in student.items() if k in ("weights", "sigma")})
                l_g = (m * self._distance(self._geometry(teacher), g_s)).mean()
                total = total + cfg.lambda_geometry * l_g
                logs["distill_geometry"] = l_g.detach()
        if pri.numel():
            target = self._prior_target(pri, generator)
            g_s = self._geometry({k: v[nr:] for k, v in student.items() if k in ("weights", "sigma")})
            l_p = (pr.prior[pri] * self._distance(target, g_s)).mean()
            total = total + cfg.lambda_prior * l_p
            logs["distill_prior"] = l_p.detach()
        return total, logs
