"""Every setting of a fit, as frozen dataclasses checked in one place (no torch import).

Each field declares its rule (:func:`_integer`, :func:`_real`, :func:`_choice`, :func:`_flag`) in its metadata;
:class:`_Checked` applies them when a config is made and raises :class:`~senerf.errors.InputError` naming the
field, so a bad value is one line wherever it came from (a flag, ``run.json``, Python).  Integers and reals are
stored as plain Python numbers (NumPy scalars are accepted and converted); sequences become tuples.

Example:
    >>> TrainConfig(steps=600, batch_rays=1024).lr
    0.02
    >>> try:
    ...     TrainConfig(lr=-1.0)
    ... except ValueError as exc:
    ...     print(exc)
    lr: must be a finite number > 0, got -1.0
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
from dataclasses import dataclass, field
from typing import Any, Callable

from senerf.errors import InputError

__all__ = ["TrainConfig", "ModelConfig", "SelfTrainConfig", "Preset", "PRESETS", "config_to_dict", "is_device_name",
           "THRESHOLD_KINDS", "BACKGROUNDS"]

THRESHOLD_KINDS = ("adaptive", "fixed", "unified")
BACKGROUNDS = ("random", "white", "black")


def is_device_name(name) -> bool:
    """Whether ``name`` is ``cpu``, ``cuda`` or ``cuda:N`` (whether that GPU exists is checked where it is used)."""
    return isinstance(name, str) and (name == "cpu" or re.fullmatch(r"cuda(:(0|[1-9][0-9]*))?", name) is not None)


def _integer(low: int = 0, high: int | None = None) -> Callable[[Any], int]:
    """Rule: an integer (not a bool) in ``[low, high]``."""
    def rule(value):
        if isinstance(value, numbers.Integral) and not isinstance(value, bool) \
                and value >= low and (high is None or value <= high):
            return int(value)
        raise ValueError(f"an integer >= {low}" + ("" if high is None else f" and <= {high}"))
    return rule


def _real(low: float | None = None, high: float | None = None, open_low: bool = False) -> Callable[[Any], float]:
    """Rule: a finite real number (not a bool) ``> low`` (``open_low``) or ``>= low``, and ``<= high``."""
    def rule(value):
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        try:
            ok = ok and math.isfinite(value)
        except OverflowError:   # an int beyond float's range
            ok = False
        if ok and (low is None or (value > low if open_low else value >= low)) and (high is None or value <= high):
            return float(value)
        bounds = ([] if low is None else [f"{'>' if open_low else '>='} {low:g}"]) + \
                 ([] if high is None else [f"<= {high:g}"])
        raise ValueError("a finite number" + (" " + " and ".join(bounds) if bounds else ""))
    return rule


def _choice(*options: str) -> Callable[[Any], str]:
    """Rule: one of ``options``."""
    def rule(value):
        if isinstance(value, str) and value in options:
            return value
        raise ValueError(f"one of {', '.join(options)}")
    return rule


def _flag(value):
    """Rule: True or False (a string such as "no" would count as true)."""
    if isinstance(value, bool):
        return value
    raise ValueError("True or False")


def _odd(value):
    """Rule: an odd integer >= 3 (a kernel size)."""
    if _integer(3)(value) % 2:
        return int(value)
    raise ValueError("an odd integer >= 3")


def _device(value):
    """Rule: a device name (:func:`is_device_name`)."""
    if is_device_name(value):
        return value
    raise ValueError("'cpu', 'cuda' or 'cuda:N'")


def _optional(rule: Callable[[Any], Any]) -> Callable[[Any], Any]:
    return lambda value: None if value is None else rule(value)


def _aabb(value):
    """Rule: ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` with every max above its min."""
    real = _real()
    try:
        rows = [[real(v) for v in row] for row in value]
    except (TypeError, ValueError):
        rows = []
    if len(rows) == 2 and all(len(r) == 3 for r in rows) and all(hi > lo for lo, hi in zip(*rows)):
        return tuple(tuple(r) for r in rows)
    raise ValueError("((xmin, ymin, zmin), (xmax, ymax, zmax)) with every max > min")


def _multires(value):
    """Rule: a non-empty sequence of integers >= 1 (the plane scales)."""
    try:
        scales = tuple(_integer(1)(m) for m in value)
    except (TypeError, ValueError):
        scales = ()
    if scales:
        return scales
    raise ValueError("a non-empty sequence of integers >= 1")


def _setting(default, rule: Callable[[Any], Any]):
    return field(default=default, metadata={"rule": rule})


class _Checked:
    """Base of the configs: applies every field's rule after ``__init__``, then :meth:`_relations`."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            try:
                object.__setattr__(self, f.name, f.metadata["rule"](value))
            except ValueError as exc:
                raise InputError(f"must be {exc}, got {value!r}", field=f.name) from None
        self._relations()

    def _relations(self) -> None:
        """Checks that involve several fields (none by default)."""


@dataclass(frozen=True)
class TrainConfig(_Checked):
    """Optimisation settings of one training (teacher or student).

    Attributes:
        steps: optimiser steps.
        batch_rays: rays per step.
        lr: peak Adam learning rate.
        warmup_steps: linear warm-up steps before the cosine decay.
        lr_final_factor: the cosine schedule ends at ``lr * lr_final_factor``.
        tv_weight: weight of ``field.regularizer()`` (plane total variation) in the loss.
        distortion_weight: weight of the distortion loss (:func:`senerf.fields.bin_distortion`) of a contracted
            (unbounded) field's rays; other fields have none.
        occupancy_every: steps between occupancy-grid updates (object scenes with a grid).
        occupancy_warmup: steps before the first grid update (the grid starts all-occupied).
        checkpoint_every: steps between atomic checkpoints (0: only at the end).
        seed: seed of the field's initialisation and of the training generator (ray batches, sample jitter,
            backgrounds).
        device: ``cpu``, ``cuda`` or ``cuda:N``.
    """

    steps: int = _setting(1000, _integer(0))
    batch_rays: int = _setting(4096, _integer(1))
    lr: float = _setting(0.02, _real(0, open_low=True))
    warmup_steps: int = _setting(50, _integer(0))
    lr_final_factor: float = _setting(0.05, _real(0, 1))
    tv_weight: float = _setting(0.1, _real(0))
    distortion_weight: float = _setting(0.01, _real(0))
    occupancy_every: int = _setting(8, _integer(0))
    occupancy_warmup: int = _setting(16, _integer(0))
    checkpoint_every: int = _setting(500, _integer(0))
    seed: int = _setting(0, _integer(0, 2**63 - 1))
    device: str = _setting("cpu", _device)


@dataclass(frozen=True)
class ModelConfig(_Checked):
    """What the field is and how its rays are rendered (chosen by :func:`senerf.train.choose_model`).

    Attributes:
        field: ``kplanes`` or ``nerf``.
        aabb: ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` of the field, in world units, or in NDC when ``ndc``.
            The fields, the occupancy grid and the rays work in the *model frame*, the world shifted by
            :attr:`frame_origin`, so float32 keeps its precision in scenes far from the world origin.
        ndc: a forward-facing scene rendered in normalised device coordinates (the LLFF convention).
        ndc_near: world-space near plane of the NDC warp (``ndc`` only).
        contract: an unbounded scene: ``aabb`` is the inner region, kept as it is, and all of space beyond it is
            contracted into the field (mip-NeRF 360's contraction in the L-infinity norm); the rays run from
            ``near`` to ``far`` with samples spaced evenly in contracted space.
        near, far: constant ray bounds, or None to clip every ray to ``aabb`` (ignored in NDC, where every ray
            spans ``t' in [0, 1]``; required with ``contract``).
        bound: with ``contract``, a world box the scene lies in (instant-ngp's ``aabb_scale``), or None: every
            ray is clipped to it as well.
        resolution: base plane resolution (K-Planes) per axis.
        multires: resolution multipliers of the plane scales.
        n_features: features per plane.
        density_shift: added to the raw density before the exponential (K-Planes only).
        view_dependent: colour depends on the view direction.
        hidden: width of the K-Planes density and colour MLPs (the paper's decoder: 64).
        n_samples: samples per ray (stratified, one per evenly spaced bin).
        occupancy_resolution: occupancy grid cells per axis (0: no grid).
        occupancy_threshold: density above which a grid cell is occupied.
        occupancy_decay: the grid's running maximum forgets by this factor per update.
        train_background: ``random`` (one colour per batch), ``white`` or ``black``.
        eval_background: ``white`` or ``black``.
    """

    field: str = _setting("kplanes", _choice("kplanes", "nerf"))
    aabb: tuple = _setting(((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5)), _aabb)
    ndc: bool = _setting(False, _flag)
    ndc_near: float = _setting(1.0, _real(0, open_low=True))
    contract: bool = _setting(False, _flag)
    bound: tuple | None = _setting(None, _optional(_aabb))
    near: float | None = _setting(None, _optional(_real(0)))
    far: float | None = _setting(None, _optional(_real(0)))
    resolution: int = _setting(64, _integer(1))
    multires: tuple = _setting((1, 2), _multires)
    n_features: int = _setting(16, _integer(1))
    density_shift: float = _setting(0.0, _real())
    view_dependent: bool = _setting(True, _flag)
    hidden: int = _setting(32, _integer(1))
    n_samples: int = _setting(48, _integer(1))
    occupancy_resolution: int = _setting(64, _integer(0))
    occupancy_threshold: float = _setting(0.1, _real(0))
    occupancy_decay: float = _setting(0.7, _real(0, 1))
    train_background: str = _setting("random", _choice(*BACKGROUNDS))
    eval_background: str = _setting("white", _choice("white", "black"))

    def _relations(self) -> None:
        if (self.near is None) != (self.far is None) or (self.near is not None and not self.near < self.far):
            raise InputError(f"give both near < far, or neither; got {self.near!r}, {self.far!r}", field="near/far")
        if self.contract and (self.ndc or self.near is None or not self.near > 0):
            raise InputError("a contracted (unbounded) field is rendered in world units from a near bound > 0 to a "
                             f"far bound; got ndc={self.ndc}, near={self.near!r}", field="contract")
        if self.bound is not None and not self.contract:
            raise InputError("bounds the rays of a contracted (unbounded) field only", field="bound")

    @property
    def frame_origin(self) -> tuple[float, float, float]:
        """The world point the model frame starts at: per axis, the box centre truncated to a whole number of
        box extents along that axis.  So ``(0, 0, 0)`` for every box that contains the world origin (the model
        frame is then the world frame, bit for bit), and within one extent of the box centre for a scene far
        from the origin, where float32 world points would be coarse.  ``(0, 0, 0)`` in NDC.  World points become
        model points by subtracting it, in float64, before any cast to float32.

        Example:
            >>> ModelConfig(aabb=((-1, -1, -1), (1, 1, 3))).frame_origin
            (0.0, 0.0, 0.0)
            >>> ModelConfig(aabb=((1e6 - 1, -1, 9.5), (1e6 + 1, 1, 11.5))).frame_origin
            (1000000.0, 0.0, 10.0)
        """
        if self.ndc:
            return (0.0, 0.0, 0.0)
        origin = []
        for lo, hi in zip(*self.aabb):
            extent = hi - lo
            origin.append(extent * math.trunc((lo + hi) / 2 / extent) + 0.0)   # + 0.0: no -0.0
        return tuple(origin)

    @property
    def field_aabb(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """``aabb`` in the model frame (``aabb - frame_origin``): what the fields and the grid are built with and
        what the rays are clipped to."""
        return self._in_model_frame(self.aabb)

    @property
    def field_bound(self) -> tuple | None:
        """``bound`` in the model frame, or None."""
        return None if self.bound is None else self._in_model_frame(self.bound)

    def _in_model_frame(self, box: tuple) -> tuple:
        origin = self.frame_origin
        return tuple(tuple(v - o for v, o in zip(row, origin)) for row in box)


@dataclass(frozen=True)
class SelfTrainConfig(_Checked):
    """The self-training loop, its reliability estimate and its distillation losses (the paper's Sections 3-4).

    Attributes:
        iterations: self-training iterations after the baseline teacher (0: the teacher only).
        n_pseudo_per_input: pseudo views per input view and iteration.
        pseudo_range_deg: the largest azimuth/elevation offset of iteration 1's pseudo views (paper: 10).
        pseudo_range_step_deg: its widening per later iteration.
        seed: seeds the pseudo-view sampling (the fields are initialised from ``TrainConfig.seed``).
        normalize_layers: L2-normalise each VGG-19 layer's features before concatenating them.
        threshold: ``adaptive`` (paper), ``fixed`` or ``unified`` (soft weights, the paper's ablations).
        alpha0, alpha_step: the adaptive threshold is the ``(1 - alpha)`` quantile of the similarities, with
            ``alpha = alpha0 + (K - 1) alpha_step`` in iteration K (paper: 0.15, 0.05).
        fixed_tau: the fixed threshold (a cosine similarity).
        beta: slope of the unified weighting's sigmoid.
        opacity_threshold: teacher opacity below which a pseudo pixel is background (no surface to label).
        occlusion_rel_tol: relative depth slack of the occlusion test of the warps.
        empty_opacity: pseudo pixels the teacher renders with opacity below this are reliable *empty* rays,
            distilled as empty space (0: off, the paper's letter; at most ``opacity_threshold``).  The paper
            defines reliability on surface pixels only; this is our addition (README, "Where we depart").
        batch_reliable: reliable pseudo rays per student step.
        batch_prior: unreliable (prior) pseudo rays per student step.
        lambda_color, lambda_geometry, lambda_prior: loss weights (paper: 1, 1, 0.005).  Each term is a mean over
            its own pool of rays.
        density_distill: the reliable geometry loss on (ablation switch).
        prior: the prior loss for unreliable rays on (ablation switch).
        kernel_size, kernel_std: the prior's Q x Q Gaussian kernel (paper: 3, 1 pixel), centre excluded.
    """

    iterations: int = _setting(3, _integer(0))
    n_pseudo_per_input: int = _setting(8, _integer(1))
    pseudo_range_deg: float = _setting(10.0, _real(0))
    pseudo_range_step_deg: float = _setting(5.0, _real(0))
    seed: int = _setting(0, _integer(0, 2**63 - 1))
    normalize_layers: bool = _setting(True, _flag)
    threshold: str = _setting("adaptive", _choice(*THRESHOLD_KINDS))
    alpha0: float = _setting(0.15, _real(0, 1))
    alpha_step: float = _setting(0.05, _real(0))
    fixed_tau: float = _setting(0.6, _real(-1, 1))
    beta: float = _setting(16.0, _real(0, open_low=True))
    opacity_threshold: float = _setting(0.5, _real(0, 1, open_low=True))
    occlusion_rel_tol: float = _setting(0.05, _real(0))
    empty_opacity: float = _setting(0.2, _real(0, 1))
    batch_reliable: int = _setting(512, _integer(1))
    batch_prior: int = _setting(128, _integer(1))
    lambda_color: float = _setting(1.0, _real(0))
    lambda_geometry: float = _setting(1.0, _real(0))
    lambda_prior: float = _setting(0.005, _real(0))
    density_distill: bool = _setting(True, _flag)
    prior: bool = _setting(True, _flag)
    kernel_size: int = _setting(3, _odd)
    kernel_std: float = _setting(1.0, _real(0, open_low=True))

    def _relations(self) -> None:
        if self.empty_opacity > self.opacity_threshold:
            raise InputError(f"must be <= opacity_threshold ({self.opacity_threshold:g}), got {self.empty_opacity:g}: "
                             "foreground pixels would be labelled empty space", field="empty_opacity")

    def alpha(self, iteration: int) -> float:
        """The adaptive threshold's alpha in iteration ``iteration >= 1`` (at most 1)."""
        return min(1.0, self.alpha0 + (iteration - 1) * self.alpha_step)

    def pseudo_range(self, iteration: int) -> float:
        """The largest angular offset (degrees) of iteration ``iteration``'s pseudo views (``>= 1``)."""
        return self.pseudo_range_deg + (iteration - 1) * self.pseudo_range_step_deg


@dataclass(frozen=True)
class Preset:
    """A named trade of time for accuracy: the training of every field and the number of iterations."""

    steps: int
    batch_rays: int
    iterations: int

    def train_config(self, **overrides: Any) -> TrainConfig:
        """The :class:`TrainConfig` of this preset, with ``overrides`` (TrainConfig fields)."""
        return TrainConfig(**{"steps": self.steps, "batch_rays": self.batch_rays, **overrides})


#: The presets (``--preset``), each on the measured speed/accuracy frontier of lego and mic Extreme at 100x100
#: (BENCHMARKS.md, "The preset ladder").
PRESETS = {"fast": Preset(steps=600, batch_rays=1024, iterations=1),
           "balanced": Preset(steps=3000, batch_rays=1024, iterations=1)}


def config_to_dict(cfg) -> dict:
    """A JSON-ready dict of a config (tuples become lists).

    Example:
        >>> config_to_dict(ModelConfig())["aabb"]
        [[-1.5, -1.5, -1.5], [1.5, 1.5, 1.5]]
    """
    def plain(value):
        return [plain(v) for v in value] if isinstance(value, (list, tuple)) else value
    return {k: plain(v) for k, v in dataclasses.asdict(cfg).items()}
