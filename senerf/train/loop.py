"""The training loop: Adam with linear warm-up + cosine decay, plane TV, occupancy grid, checkpoints.

Convention: every random draw (ray batches, sample jitter, background colours, the ``extra_loss`` hook) comes from
one ``torch.Generator`` on the training device whose state is checkpointed, so on the CPU a resumed training ends
bit for bit as the uninterrupted one on the same host (each checkpoint records its
:func:`~senerf.train.record.host_record`).  On CUDA it continues the same random stream, but not to the bit; across
device types (CPU <-> CUDA) the ray batches continue from a new stream seeded from ``(seed, step)``, with a warning.
"""

from __future__ import annotations

import hashlib
import math
import time
import warnings
from dataclasses import dataclass, field as dc_field
from pathlib import Path
from typing import Callable

import torch

from senerf.config import TrainConfig
from senerf.errors import InputError

from .checkpoint import _FORMAT, _load_training_state, save_checkpoint
from .rays import RayBatchSource
from .record import host_record

__all__ = ["train_field", "TrainResult", "lr_factor", "make_occupancy", "background_color", "ExtraLoss"]

#: ``extra_loss(field, step, generator, occupancy) -> (scalar loss tensor, {name: float or 0-d tensor})``;
#: ``occupancy`` is the grid the step renders the real rays with (None before ``occupancy_warmup`` or without
#: a grid); the logged values are read (``float``) at log steps only
ExtraLoss = Callable[[torch.nn.Module, int, torch.Generator, object], "tuple[torch.Tensor, dict]"]


@dataclass
class TrainResult:
    """What :func:`train_field` hands back.

    Attributes:
        field: the trained field (the same module that was passed in, on ``cfg.device``).
        occupancy: the trained :class:`senerf.fields.OccupancyGrid`, or ``None``.
        steps: steps done in total (including those before a resume).
        resumed_from: step the run resumed from (0 for a fresh run).
        seconds: wall time of this call.
        history: ``[{step, loss, psnr, lr, ...extra logs}]`` every ``log_every`` steps.
        seconds_before: training seconds recorded in the checkpoint this call resumed from (0 for a fresh
            run): ``seconds + seconds_before`` is the training time of the steps done (redone steps count twice).
    """

    field: torch.nn.Module
    occupancy: object | None
    steps: int
    resumed_from: int
    seconds: float
    history: list = dc_field(default_factory=list)
    seconds_before: float = 0.0


def lr_factor(step: int, cfg: TrainConfig) -> float:
    """Learning-rate multiplier at ``step``: linear warm-up to 1, then cosine to ``lr_final_factor``."""
    if step < cfg.warmup_steps:
        return (step + 1) / cfg.warmup_steps
    span = max(cfg.steps - cfg.warmup_steps, 1)
    progress = min((step - cfg.warmup_steps) / span, 1.0)
    return cfg.lr_final_factor + (1.0 - cfg.lr_final_factor) * 0.5 * (1.0 + math.cos(math.pi * progress))


def make_occupancy(model, device):
    """The occupancy grid the model asks for (``None`` in NDC or when ``occupancy_resolution == 0``)."""
    if model.ndc or model.occupancy_resolution == 0:
        return None
    from senerf.fields import OccupancyGrid

    grid = OccupancyGrid(model.field_aabb, model.occupancy_resolution, threshold=model.occupancy_threshold,
                         decay=model.occupancy_decay, contract=model.contract)
    return grid.to(device)


def background_color(policy: str, generator: torch.Generator, device) -> torch.Tensor:
    """The background colour ``(3,)`` of a batch: white, black, or uniform random (one per batch)."""
    if policy == "white":
        return torch.ones(3, device=device)
    if policy == "black":
        return torch.zeros(3, device=device)
    if policy == "random":
        return torch.rand(3, generator=generator, device=device)
    raise ValueError(f"unknown background policy {policy!r}")


def _state(field, optimizer, generator, occupancy, step: int, seconds: float) -> dict:
    state = dict(format=_FORMAT, step=int(step),
                 field=field.state_dict(), optimizer=optimizer.state_dict(),
                 generator=generator.get_state(), generator_device=generator.device.type,
                 seconds=float(seconds), host=host_record(generator.device))
    if occupancy is not None:
        state["occupancy"] = occupancy.state_dict()
    return state


def _restore(path: Path, field, optimizer, generator, occupancy, seed: int) -> tuple[int, float]:
    """Load a training checkpoint into the objects; returns ``(step, training seconds recorded in it)``.  The batch
    generator of a checkpoint written on another device type is reseeded from ``(seed, step)`` (module Convention)."""
    # read on the host: load_state_dict copies into the device's tensors (the fused Adam's step counters go beside
    # the parameters, as in a fresh run)
    state = _load_training_state(path, field, occupancy, optimizer)
    saved_on = state.get("generator_device")
    try:
        step, seconds = int(state["step"]), float(state["seconds"])
        if saved_on == generator.device.type:
            generator.set_state(state["generator"].cpu())
    except (RuntimeError, KeyError, ValueError, TypeError, AttributeError) as exc:
        raise InputError(f"does not fit this training ({str(exc).splitlines()[0] or type(exc).__name__}); delete it "
                         "or use another output folder", file=path) from None
    if saved_on != generator.device.type:   # a CPU stream cannot continue as a CUDA one, or back
        generator.manual_seed(int(hashlib.sha256(f"senerf-resume:{int(seed)}:{step}".encode()).hexdigest()[:15], 16))
        warnings.warn(f"{path}: written on {saved_on}, resumed on {generator.device.type}: the random stream "
                      f"cannot move between devices, so steps {step}+ draw from a new one seeded from (seed, step) "
                      f"(reproducible, but not what an uninterrupted run gives)", stacklevel=3)
    return step, seconds


def train_field(field: torch.nn.Module, rays: RayBatchSource, cfg: TrainConfig,
                extra_loss: ExtraLoss | None = None, checkpoint: str | Path | None = None,
                progress: bool = True, log_every: int = 25) -> TrainResult:
    """Train ``field`` on ``rays`` with the photometric MSE (+ TV, + ``extra_loss``).

    Args:
        field: a :class:`senerf.fields.RadianceField`; moved to ``cfg.device``.
        rays: the training rays (on ``cfg.device``); ``rays.model`` gives the render settings
            (samples, background policy, occupancy grid).
        extra_loss: an :data:`ExtraLoss` added to the loss every step (self-training's distillation losses); it must
            draw randomness only from ``generator``.
        checkpoint: a ``.pt`` path: resumed from when it exists (module Convention), written atomically every
            ``cfg.checkpoint_every`` steps and at the end.  The caller keeps it with the settings and rays it
            belongs to (a run folder's ``run.json`` does); only the tensors' shapes and finiteness are checked here.
        progress: show a tqdm bar (steps, loss, PSNR).
        log_every: steps between history entries / progress updates.

    Returns:
        :class:`TrainResult`.
    """
    from senerf.fields import bin_distortion, render_rays

    if not isinstance(rays, RayBatchSource):
        raise ValueError(f"rays must be a RayBatchSource, got {type(rays).__name__}")
    device = torch.device(cfg.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError("CUDA was requested but torch sees no GPU", field="device")
    if rays.device.type != device.type:
        raise ValueError(f"rays are on {rays.device}, the config asks for {device}")
    model = rays.model
    field.to(device)
    field.train()
    generator = torch.Generator(device=device)
    generator.manual_seed(cfg.seed)
    # fused: one pass over each parameter per step instead of a dozen elementwise ones (5x faster on large planes)
    optimizer = torch.optim.Adam(field.parameters(), lr=cfg.lr, eps=1e-15, fused=True)
    occupancy = make_occupancy(model, device)
    if occupancy is not None and model.contract:   # an unbounded scene: render nothing where no ray has looked
        occupancy.mark_seen(rays.origins, rays.dirs, rays.near, rays.far)
    start, seconds_before = 0, 0.0
    ckpt = Path(checkpoint) if checkpoint is not None else None
    if ckpt is not None and ckpt.exists():
        start, seconds_before = _restore(ckpt, field, optimizer, generator, occupancy, cfg.seed)

    history: list[dict] = []
    t_start = time.perf_counter()
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=cfg.steps, initial=start, desc="train", unit="step", dynamic_ncols=True)
    for step in range(start, cfg.steps):
        for group in optimizer.param_groups:
            group["lr"] = cfg.lr * lr_factor(step, cfg)
        if hasattr(field, "set_progress"):
            field.set_progress(step, cfg.steps)   # a field built without anneal_steps anneals over steps / 4
        if occupancy is not None and step >= cfg.occupancy_warmup and cfg.occupancy_every \
                and (step - cfg.occupancy_warmup) % cfg.occupancy_every == 0:
            occupancy.update(field)
        use_grid = occupancy if (occupancy is not None and step >= cfg.occupancy_warmup) else None

        batch = rays.sample(cfg.batch_rays, generator)
        bg = background_color(model.train_background, generator, device)
        target = batch["rgb"]
        if "alpha" in batch:
            a = batch["alpha"][:, None]
            target = target * a + bg * (1.0 - a)
        out = render_rays(field, batch["origins"], batch["dirs"], batch["near"], batch["far"],
                          model.n_samples, generator, bg, occupancy=use_grid, randomized=True)
        photo = torch.mean((out["rgb"] - target) ** 2)
        loss = photo
        if cfg.tv_weight > 0:
            loss = loss + cfg.tv_weight * field.regularizer()
        if model.contract and cfg.distortion_weight > 0:
            loss = loss + cfg.distortion_weight * bin_distortion(out["weights"])
        logs: dict = {}
        if extra_loss is not None:
            extra, logs = extra_loss(field, step, generator, use_grid)
            loss = loss + extra
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

        done = step + 1
        if done % log_every == 0 or done == cfg.steps:
            loss_v, photo_v = float(loss.detach().cpu()), float(photo.detach().cpu())
            if not math.isfinite(loss_v):
                raise RuntimeError(f"loss became {loss_v} at step {done}; check the ray bounds and lr")
            entry = dict(step=done, loss=loss_v, psnr=-10.0 * math.log10(max(photo_v, 1e-12)),
                         lr=optimizer.param_groups[0]["lr"], **{k: float(v) for k, v in logs.items()})
            history.append(entry)
            if bar is not None:
                bar.set_postfix(loss=f"{loss_v:.4f}", psnr=f"{entry['psnr']:.2f}")
        if bar is not None:
            bar.update(1)
        if ckpt is not None and ((cfg.checkpoint_every and done % cfg.checkpoint_every == 0)
                                 or done == cfg.steps):
            save_checkpoint(ckpt, _state(field, optimizer, generator, occupancy, done,
                                         seconds_before + time.perf_counter() - t_start))
    if bar is not None:
        bar.close()
    field.eval()
    return TrainResult(field=field, occupancy=occupancy, steps=max(cfg.steps, start), resumed_from=start,
                       seconds=time.perf_counter() - t_start, seconds_before=seconds_before, history=history)
