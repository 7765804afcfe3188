"""The scene-driven model choice (:func:`choose_model`) and the fields it builds (:func:`build_field`)."""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any, Callable, Mapping

import numpy as np

from senerf.config import ModelConfig
from senerf.errors import InputError

__all__ = ["choose_model", "build_field", "camera_aabb", "nerf_description", "NDC_AABB", "NERF_FREQS", "NERF_HIDDEN",
           "NERF_LAYERS"]

# The NeRF field senerf builds (``--field nerf``): its MLP and positional encoding are fixed.
NERF_FREQS, NERF_HIDDEN, NERF_LAYERS = 10, 128, 4


def nerf_description() -> str:
    """One line saying what ``field='nerf'`` builds (:func:`build_field`)."""
    return (f"{NERF_LAYERS} layers x {NERF_HIDDEN}, {NERF_FREQS} frequency bands annealed over the first quarter "
            "of each training")


#: The box a forward-facing scene is fitted in, in NDC (x, y a little beyond the frustum's [-1, 1], z in [-1, 1]).
NDC_AABB = ((-1.5, -1.5, -1.0), (1.5, 1.5, 1.0))
#: Boxes wider than this (world units) get their densities and occupancy threshold scaled to it (``choose_model``).
DENSITY_PLATEAU_WIDTH = 4.0
#: The settings :func:`choose_model` reports, in this order (then any other override).
_REPORTED = ("field", "ndc", "contract", "aabb", "near", "bound", "resolution", "n_samples", "occupancy_resolution",
             "train_background", "view_dependent")


def camera_aabb(c2w: np.ndarray, fov_deg: float, margin: float = 1.05) -> tuple[np.ndarray, float, np.ndarray]:
    """A cube the cameras look at: centre = point nearest all optical axes, half size = what one camera
    sees across at the centre's distance.

    Args:
        c2w: (n, 4, 4) camera-to-world poses (OpenCV).
        fov_deg: the narrower field of view of the cameras, degrees.
        margin: multiplies the half size.

    Returns:
        (aabb (2, 3) float64, mean camera distance to the centre, centre (3,))
    """
    from senerf.geometry import closest_point_to_axes

    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
        raise ValueError(f"c2w must be (n, 4, 4), got {c2w.shape}")
    try:
        centre = np.asarray(closest_point_to_axes(c2w), dtype=np.float64)
    except ValueError:  # one camera or parallel axes: along the mean axis, as far as the origin is
        axis = c2w[:, :3, 2].mean(axis=0)
        axis /= max(np.linalg.norm(axis), 1e-12)
        origin = c2w[:, :3, 3].mean(axis=0)
        centre = origin + axis * max(np.linalg.norm(origin), 1.0)
    dist = float(np.mean(np.linalg.norm(c2w[:, :3, 3] - centre, axis=-1)))
    half = dist * math.tan(math.radians(fov_deg) / 2) * margin
    half = min(half, 0.95 * dist / math.sqrt(3))  # keep the cameras outside the box
    return np.stack([centre - half, centre + half]), dist, centre


def _check_parallax(c2w: np.ndarray, scene, train_idx) -> None:
    """:class:`InputError` when the cameras ``c2w (n, 4, 4)`` (n >= 2) all stand at one point: a pure
    rotation (a tripod pan) has no parallax, so no depth, and no box can be placed around what they see."""
    centres = np.asarray(c2w, dtype=np.float64)[:, :3, 3]
    if centres.shape[0] < 2 or not np.isfinite(centres).all():
        return
    spread = float(np.max(np.abs(centres - centres[0])))
    if spread <= 1e-9 * max(1.0, float(np.max(np.abs(centres)))):
        views = [int(i) for i in np.asarray(train_idx).reshape(-1)][:12]
        who = f"the training views {views}" if len(views) >= 2 else "the scene's cameras"
        raise InputError(f"{who} all stand at one camera centre (a pure rotation has no parallax, so no depth "
                         "to fit); use views taken from different places",
                         file=scene.root, field="camera positions")


def choose_model(scene, train_idx, overrides: Mapping[str, Any] | None = None,
                 echo: Callable[[str], None] = print) -> ModelConfig:
    """Pick every model setting for ``scene`` from its cameras and images (field kind, bounding box or NDC, plane
    resolution, samples, background policy, occupancy grid), printing one line per choice.

    Args:
        scene: a :class:`senerf.data.Scene`.
        train_idx: (n_train,) indices of the training images into the scene's arrays.
        overrides: ``{ModelConfig field: value}``; an overridden setting is printed as ``(override)``.
        echo: where the lines go (``print`` by default).

    Returns:
        the :class:`ModelConfig`.
    """
    overrides = dict(overrides or {})
    names = {f.name for f in fields(ModelConfig)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise InputError(f"unknown model setting(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}",
                         field="overrides")
    train_idx = np.asarray(train_idx, dtype=np.int64).reshape(-1)
    if train_idx.size == 0:
        raise InputError("no training views", field="train_idx")
    H, W = scene.rgb.shape[1:3]
    intr = scene.intrinsics
    fov_x = math.degrees(2 * math.atan(0.5 * W / intr.fx))
    fov_y = math.degrees(2 * math.atan(0.5 * H / intr.fy))
    chosen: dict[str, Any] = {}
    why: dict[str, str] = {}

    if scene.kind == "forward_facing":
        near = scene.near if scene.near is not None else 1.0
        chosen.update(ndc=True, ndc_near=float(0.75 * near), aabb=NDC_AABB, near=None, far=None,
                      occupancy_resolution=0)
        why["ndc"] = f"forward-facing scene: NDC with near plane {0.75 * near:.3g} (0.75 x dataset near)"
        why["aabb"] = "NDC cube " + " x ".join(f"[{lo:g}, {hi:g}]" for lo, hi in zip(*NDC_AABB))
        why["near"] = "NDC rays, t' in [0, 1]"
        why["occupancy_resolution"] = "no occupancy grid in NDC"
        extent_px = max(H, W)
        chosen["multires"] = (1, 2, 4)
    else:
        unbounded = scene.kind == "unbounded"
        cams = np.asarray(scene.c2w)[train_idx] if train_idx.size >= 2 else np.asarray(scene.c2w)
        _check_parallax(cams, scene, train_idx)
        with np.errstate(over="ignore", invalid="ignore"):  # huge coordinates are refused just below
            box, dist, centre = camera_aabb(cams, min(fov_x, fov_y))
        if not (np.isfinite(box).all() and dist > 0 and math.isfinite(dist)):
            raise InputError(f"the cameras' box cannot be computed (camera distance {dist:g} to the point "
                             f"they look at); are the poses in a sane unit?", file=scene.root,
                             field="camera positions")
        # 3 decimals at unit scale; more for small scenes (a 1e-4-scale scene would round to an empty box)
        half0 = float(box[1, 0] - box[0, 0]) / 2
        box = np.round(box, max(3, 3 - math.floor(math.log10(half0))) if half0 > 0 else 3)
        half = (box[1, 0] - box[0, 0]) / 2
        if not (half > 0 and math.isfinite(half)):   # a field of view so narrow that the box has no width
            raise InputError(f"the cameras see a box of half size {half:g} (field of view {min(fov_x, fov_y):.3g} "
                             f"degrees at distance {dist:.3g}); check the focal length", file=scene.root,
                             field="camera intrinsics")
        chosen.update(ndc=False, aabb=tuple(map(tuple, box)), near=None, far=None,
                      occupancy_resolution=64)
        why["aabb"] = (f"cube centre ({centre[0]:.4g}, {centre[1]:.4g}, {centre[2]:.4g}) half size {half:.4g} "
                       f"(camera distance {dist:.4g} x tan(fov/2) x 1.05)")
        why["near"] = "per-ray near/far from the ray-box intersection"
        why["occupancy_resolution"] = "64^3 occupancy grid skips empty space"
        extent_px = 2 * half / dist * intr.fx  # the box's width in pixels at the centre's distance
        chosen["multires"] = (1, 2)
        if unbounded:
            _unbounded(chosen, why, scene, dist)
    # base plane resolution: about the pixels the box covers in one image, /2, a multiple of 8 in [32, 128]
    # (contracted: the box fills the middle half of each plane, the outside the rest, so twice that)
    texels = extent_px * (2 if chosen.get("contract") else 1)
    res = int(min(128, max(32, int(round(texels / 2 / 8)) * 8)))
    chosen["resolution"] = res
    why["resolution"] = (f"base {res} (box ~{extent_px:.0f} px wide in {W}x{H} images"
                         f"{', the middle half of each plane' if chosen.get('contract') else ''}), "
                         f"scales {chosen['multires']}")
    chosen["n_samples"] = 48 if not chosen["ndc"] else 64
    why["n_samples"] = f"{chosen['n_samples']} samples per ray"
    if scene.alpha is not None and getattr(scene, "background", None) is not None:
        bg = tuple(float(v) for v in scene.background)
        name = {(1.0, 1.0, 1.0): "white", (0.0, 0.0, 0.0): "black"}.get(bg)
        if name is None:
            raise InputError(f"images were composited onto {bg} at load time; load them without a background "
                             "(or onto white/black)", field="background")
        chosen.update(train_background=name, eval_background=name)
        why["train_background"] = f"images composited onto {name} at load time: trained and evaluated on {name}"
    elif scene.alpha is not None:
        chosen.update(train_background="random", eval_background="white")
        why["train_background"] = "RGBA images: random background colour per batch, evaluated on white"
    else:
        chosen.update(train_background="black", eval_background="black")
        why["train_background"] = "RGB images: rendered over black"
        if chosen.get("contract"):
            why["train_background"] = "none: an unbounded scene's rays end in the scene"
    why["field"] = "K-Planes (the paper's main backbone)"   # (ModelConfig's defaults: K-Planes, view-dependent)

    if overrides.get("field") == "nerf":
        for key in ("resolution", "hidden"):
            if key in overrides:
                raise InputError(f"sets the K-Planes field; the NeRF field has no such setting (its MLP is fixed: "
                                 f"{nerf_description()})", field=key)
    cfg_values = {**chosen, **overrides}
    if not cfg_values.get("ndc"):   # the box fitted (chosen, or the overrides'), by its side along x
        try:
            width = float(cfg_values["aabb"][1][0]) - float(cfg_values["aabb"][0][0])
        except (TypeError, ValueError, IndexError, KeyError):   # a malformed aabb: ModelConfig names it below
            width = float("nan")
        _scale_densities(cfg_values, overrides, width, why)
    cfg = ModelConfig(**cfg_values)
    if cfg.field == "nerf":   # the plane resolution does not apply; say what the MLP is instead
        why["field"] = f"NeRF MLP, {nerf_description()}"
    for key in (*_REPORTED, *sorted(set(overrides) - set(_REPORTED))):
        if (key == "resolution" and cfg.field == "nerf") or (key in ("contract", "bound") and key not in overrides
                                                               and getattr(cfg, key) in (False, None)):
            continue
        if key == "field" and key in overrides and cfg.field == "nerf":
            echo(f"model: field = 'nerf' (override): {why['field']}")
        elif key in overrides:
            echo(f"model: {key} = {getattr(cfg, key)!r} (override)")
        elif key in why:
            echo(f"model: {key}: {why[key]}")
        else:
            echo(f"model: {key} = {getattr(cfg, key)!r}")
    if "density_scale" in why:
        echo(f"model: {why['density_scale']}")
    return cfg


#: An unbounded scene's rays run from this many camera distances (to what the cameras look at) to ...
UNBOUNDED_NEAR = 0.25
#: ... this many (contracted to within 0.1 % of the edge of the field's space)
UNBOUNDED_FAR = 1000.0
#: An unbounded field's initial density, ``exp(shift)`` per unit: the far bins are hundreds of units long, and from
#: ``exp(0)`` a dense fit of DTU scan24 collapses (8.6 dB against 19.0 at 600 steps)
UNBOUNDED_DENSITY_SHIFT = -1.5


def _unbounded(chosen: dict, why: dict, scene, dist: float) -> None:
    """The settings of an unbounded scene: the box the cameras look at is the inner region of a contracted field,
    rays run from ``UNBOUNDED_NEAR`` to ``UNBOUNDED_FAR`` camera distances, clipped to the scene's ``bound``.

    The near bound is a quarter of the distance to what the cameras look at: a capture walked around an object
    holds nothing much nearer, and the space right in front of each camera is seen by that camera alone, where
    a density that explains one photo (a floater) costs nothing."""
    near, far = float(f"{UNBOUNDED_NEAR * dist:.4g}"), float(f"{UNBOUNDED_FAR * dist:.4g}")
    chosen.update(contract=True, near=near, far=far, density_shift=UNBOUNDED_DENSITY_SHIFT)
    why["contract"] = ("unbounded scene: the box is kept as it is, all of space beyond it is contracted into the "
                       f"field; initial density exp({UNBOUNDED_DENSITY_SHIFT:g}) per unit")
    why["near"] = f"rays from {near:.4g} to {far:.4g} ({UNBOUNDED_NEAR:g} and {UNBOUNDED_FAR:g} camera distances)"
    why["occupancy_resolution"] = ("64^3 occupancy grid over the contracted space skips empty space and the cells "
                                   "no training ray crosses")
    if scene.bound is not None:
        chosen["bound"] = tuple(tuple(float(v) for v in row) for row in scene.bound)
        lo, hi = chosen["bound"]
        why["bound"] = ("rays end where they leave the scene's box " +
                        " x ".join(f"[{a:.4g}, {b:.4g}]" for a, b in zip(lo, hi)) + " (aabb_scale)")


def _scale_densities(values: dict, overrides: dict, width: float, why: dict) -> None:
    """Density is per world unit: a box ``width`` < 1 unit wide starts ``1/width`` times denser, and one wider
    than :data:`DENSITY_PLATEAU_WIDTH` starts ``width/4`` times more opaque while the grid's absolute threshold
    drops content it has learnt.  K-Planes' ``density_shift`` (the NeRF field has none) and, for wide boxes, the
    occupancy threshold are scaled back into 1-4 units; boxes 1-4 units wide are fitted as they are.  Values
    given in ``overrides`` are kept."""
    if not (width > 0 and math.isfinite(width)):
        return
    nerf = values.get("field") == "nerf"
    if width < 1.0:
        if "density_shift" not in overrides and not nerf:
            values["density_shift"] = values.get("density_shift", 0.0) - math.log(width)
            why["density_scale"] = f"initial densities scaled by 1/{width:.3g} for a box {width:.3g} units wide " \
                                   f"(density is per unit)"
        return
    if width <= DENSITY_PLATEAU_WIDTH:
        return
    scale = width / DENSITY_PLATEAU_WIDTH
    if "density_shift" not in overrides and not nerf:
        values["density_shift"] = values.get("density_shift", 0.0) - math.log(scale)
    if "occupancy_threshold" not in overrides:
        values["occupancy_threshold"] = ModelConfig.occupancy_threshold / scale
    what = "the occupancy threshold" if nerf else "initial densities and the occupancy threshold"
    why["density_scale"] = f"{what} scaled by 1/{scale:.3g} for a box {width:.3g} units wide (density is per unit)"


def build_field(model: ModelConfig, seed: int = 0, steps: int | None = None):
    """A freshly initialised field for ``model`` (weights drawn from a CPU generator seeded ``seed``).

    Args:
        steps: training steps; a NeRF field anneals its frequencies over the first quarter of them.

    Returns:
        a :class:`senerf.fields.KPlanesField` or :class:`senerf.fields.NeRFField` on the CPU.
    """
    import torch

    from senerf.fields import KPlanesField, NeRFField

    gen = torch.Generator()
    gen.manual_seed(int(seed))
    if model.field == "kplanes":
        return KPlanesField(model.field_aabb, resolution=model.resolution, n_features=model.n_features,
                            multires=model.multires, view_dependent=model.view_dependent,
                            hidden=model.hidden, density_shift=model.density_shift, generator=gen,
                            contract=model.contract)
    anneal = None if steps is None else max(1, int(steps) // 4)
    return NeRFField(aabb=model.field_aabb, n_freqs=NERF_FREQS, hidden=NERF_HIDDEN, n_layers=NERF_LAYERS,
                     view_dependent=model.view_dependent, anneal_steps=anneal, generator=gen,
                     contract=model.contract)
