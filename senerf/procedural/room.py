"""A closed, textured room around the procedural objects: exact ground truth for unbounded scenes.

The room is an axis-aligned box: floor at ``z = GROUND_TOP``, ceiling at ``z = GROUND_TOP + ceiling_height``,
walls at ``x = +-half_width`` and ``y = +-half_width``.  The box, sphere, cylinder and torus of
:func:`~senerf.procedural.scene.build_scene` (same seed: same places, same textures; no ground disc) stand in
the middle, within 1.3 units of the z axis.  Every ray from inside the room hits a surface, so the photos have
no alpha and every depth is finite.  The floor and ceiling show cells of 0.6 and 0.8 units, each wall its own
noise blobs of about 0.5 units (at ``texture_scale=1``): structure a feature matcher finds from across the room.

Folder layout written by :func:`export_room_scene` (instant-ngp / nerfstudio)::

    OUT/transforms.json         "camera_model": "OPENCV", fl_x, fl_y, cx, cy (pixels), w, h, aabb_scale (only
                                when given), frames {"file_path": "images/frame_K.png",
                                "transform_matrix": 4x4 camera-to-world, OpenGL convention}
    OUT/images/frame_K.png      RGB 8-bit, no alpha (K: the view index, 5 digits, from 0)
    OUT/depth/frame_K.npy       (H, W) float32 exact z-depth (camera-frame z, scene units), finite and > 0
    OUT/procedural.json         generator settings, seeds, camera ring, room bounds

Convention: z-up world, scene units; object ids index :data:`ROOM_OBJECT_NAMES`; every surface's normal points
into the room.  Cameras are made in OpenCV convention (:func:`senerf.geometry.look_at`) and converted once
with :func:`senerf.geometry.opencv_to_opengl` when written.  Angles in degrees.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import trimesh

from senerf.errors import is_number
from senerf.geometry import Intrinsics, look_at, opencv_to_opengl

from .export import _check_count, _remove_stale_views, _scene_folder, _write_view
from .render import render
from .scene import (GROUND_TOP, ObjectTexture, ProceduralScene, SceneConfig, _assemble, _check_look, _object_meshes,
                    _textures)

__all__ = ["RoomConfig", "ROOM_OBJECT_NAMES", "build_room_scene", "room_ring_poses", "export_room_scene"]

ROOM_OBJECT_NAMES = ("floor", "box", "sphere", "cylinder", "torus", "wall_px", "wall_nx", "wall_py", "wall_ny",
                     "ceiling")
_WALL_NORMALS = ((-1.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 1.0, 0.0))  # inward, in name order
_OVERLAP = 0.5   # each surface reaches this far past the room's edges: corners are closed without shared edges
_MARGIN = 0.1    # the least distance from a camera to the room's surfaces
_OBJECTS_RADIUS = 1.5   # cameras stay at least this far from the z axis (the objects stand within 1.3 of it)
_HEIGHT_JITTER = 0.05
_AABB_SCALES = (1, 2, 4, 8, 16, 32, 64, 128)   # instant-ngp's

_FLOOR_PALETTE = ((0.35, 0.22, 0.12), (0.88, 0.72, 0.50))  # dark wood / light wood
_CEILING_PALETTE = ((0.40, 0.42, 0.48), (0.96, 0.96, 0.94))  # grey / white
_WALL_PALETTES = (  # the seed picks which wall gets which
    ((0.18, 0.32, 0.55), (0.92, 0.90, 0.82)),  # blue / cream
    ((0.55, 0.18, 0.15), (0.96, 0.86, 0.74)),  # brick / beige
    ((0.16, 0.42, 0.26), (0.90, 0.94, 0.86)),  # green / white
    ((0.52, 0.40, 0.10), (0.94, 0.94, 0.98)),  # ochre / white
)


@dataclass(frozen=True)
class RoomConfig:
    """Room parameters.

    Attributes:
        seed: drives the objects as :class:`~senerf.procedural.scene.SceneConfig`'s seed does, the walls'
            palettes and the room's noise and cell values.
        half_width: the walls stand at ``x, y = +-half_width``; in ``(1.5, 50]`` (outside the objects).
        ceiling_height: height of the ceiling above the floor (``z = GROUND_TOP``); in ``(2.15, 50]``, so the
            ceiling is above the objects' bounds ``z <= 1.5``.
        texture_scale: multiplies every texture frequency, the objects' and the room's.
        light_dir: direction *towards* the light, world frame (normalised internally).
        ambient: ambient fraction in [0, 1]; shade = ambient + (1 - ambient) * max(0, n . l).
    """

    seed: int = 0
    half_width: float = 3.5
    ceiling_height: float = 2.5
    texture_scale: float = 1.0
    light_dir: tuple[float, float, float] = (0.45, -0.35, 0.82)
    ambient: float = 0.5

    def __post_init__(self) -> None:
        if not (1.5 < float(self.half_width) <= 50.0):
            raise ValueError(f"half_width must be in (1.5, 50], got {self.half_width}")
        if not (1.5 - GROUND_TOP < float(self.ceiling_height) <= 50.0):
            raise ValueError(f"ceiling_height must be in ({1.5 - GROUND_TOP:g}, 50], got {self.ceiling_height}")
        _check_look(self)

    @property
    def ceiling_z(self) -> float:
        """World z of the ceiling."""
        return GROUND_TOP + float(self.ceiling_height)


def _surface(normal, x_axis, centre, half_x: float, half_y: float) -> tuple:
    """``(quad mesh in its local xy plane, local -> world (4, 4))``: local z is the inward ``normal``, local x
    ``x_axis``, local y ``normal x x_axis``; the quad is ``[-half_x, half_x] x [-half_y, half_y]``."""
    n, x = np.asarray(normal, dtype=np.float64), np.asarray(x_axis, dtype=np.float64)
    frame = np.eye(4)
    frame[:3, :3] = np.column_stack([x, np.cross(n, x), n])
    frame[:3, 3] = centre
    verts = np.array([[-half_x, -half_y, 0.0], [half_x, -half_y, 0.0], [half_x, half_y, 0.0], [-half_x, half_y, 0.0]])
    return trimesh.Trimesh(verts, [[0, 1, 2], [0, 2, 3]], process=False), frame   # counter-clockwise: normal +z


def _room_surfaces(cfg: RoomConfig) -> list:
    """``(mesh, local -> world)`` of the floor, the walls in :data:`ROOM_OBJECT_NAMES` order and the ceiling."""
    w, h = float(cfg.half_width), float(cfg.ceiling_height)
    side, up = w + _OVERLAP, (0.0, 0.0, 1.0)
    walls = [_surface(n, np.cross(up, n), -w * np.asarray(n) + (0.0, 0.0, GROUND_TOP + h / 2), side, h / 2 + _OVERLAP)
             for n in _WALL_NORMALS]
    return [_surface(up, (1.0, 0.0, 0.0), (0.0, 0.0, GROUND_TOP), side, side), *walls,
            _surface((0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.0, 0.0, cfg.ceiling_z), side, side)]


def _room_textures(cfg: RoomConfig, rng: np.random.Generator) -> list:
    """Textures of the floor, the four walls and the ceiling (order of :func:`_room_surfaces`)."""
    s = float(cfg.texture_scale)
    order = rng.permutation(len(_WALL_PALETTES))
    floor = ObjectTexture("cells", s / 0.6, np.asarray(_FLOOR_PALETTE), {"lattice": rng.uniform(size=16**2)})
    walls = [ObjectTexture("noise", s / 0.5, np.asarray(_WALL_PALETTES[k]), {"lattice": rng.uniform(size=16**3)})
             for k in order]
    ceiling = ObjectTexture("cells", s / 0.8, np.asarray(_CEILING_PALETTE), {"lattice": rng.uniform(size=16**2)})
    return [floor, *walls, ceiling]


def build_room_scene(config: RoomConfig | None = None) -> ProceduralScene:
    """Build the room scene (module docstring); deterministic given ``config.seed``.

    The objects (ids 1-4) are those of ``build_scene(SceneConfig(seed=config.seed,
    texture_scale=config.texture_scale))``; the floor takes the ground's id 0, the walls and the ceiling ids 5-9.

    Example:
        >>> from senerf.geometry import Intrinsics
        >>> from senerf.procedural import render
        >>> scene = build_room_scene()
        >>> view = render(scene, Intrinsics.from_fov(60.0, 100, 100), room_ring_poses(48)[0])
        >>> bool(view.alpha.all()), [scene.object_names[i] for i in np.unique(view.object_id)]
        (True, ['floor', 'box', 'sphere', 'cylinder', 'wall_nx', 'ceiling'])
    """
    cfg = RoomConfig() if config is None else config
    if not isinstance(cfg, RoomConfig):
        raise ValueError(f"config must be a RoomConfig, got {type(cfg).__name__}")
    rng = np.random.default_rng(cfg.seed)
    objects = SceneConfig(seed=cfg.seed, texture_scale=cfg.texture_scale)
    meshes, transforms = _object_meshes(objects, rng)   # the draws of build_scene, in its order
    textures = list(_textures(objects, rng))
    (floor, *rest), (floor_texture, *rest_textures) = _room_surfaces(cfg), _room_textures(cfg, rng)
    meshes[0], transforms[0], textures[0] = floor[0], floor[1], floor_texture
    meshes += [m for m, _ in rest]
    transforms += [t for _, t in rest]
    return _assemble(cfg, meshes, transforms, tuple(textures + rest_textures), range(len(meshes)),
                     ROOM_OBJECT_NAMES)


def room_ring_poses(n: int, radius: float = 2.2, heights=(0.0, 0.4, 0.8), target=(0.0, 0.0, 0.0),
                    height_jitter: float = _HEIGHT_JITTER, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) float64 OpenCV c2w on a horizontal ring around the z axis, each looking at ``target``.

    View ``k`` sits at azimuth ``360 k / n`` degrees, ``radius`` from the z axis, at world height
    ``heights[k % len(heights)]`` plus a jitter drawn uniform in ``[-height_jitter, height_jitter]`` from
    ``seed``.  Neighbouring views differ in height; with three heights, every 8th view (the llff protocol's
    test views) lies between training views and the test views visit every height (3 and 8 are coprime).

    Example:
        >>> c2w = room_ring_poses(48, height_jitter=0.0)
        >>> c2w.shape, c2w[1, :3, 3].round(3).tolist(), c2w[2, :3, 3].round(3).tolist()
        ((48, 4, 4), [2.181, 0.287, 0.4], [2.125, 0.569, 0.8])
    """
    n = _check_count(n, "n")
    hs = np.asarray(heights, dtype=np.float64).reshape(-1)
    if hs.size == 0 or not np.all(np.isfinite(hs)):
        raise ValueError(f"heights must be a non-empty sequence of finite numbers, got {heights!r}")
    if not (is_number(radius) and radius > 0):
        raise ValueError(f"radius must be a positive number, got {radius!r}")
    if not (is_number(height_jitter) and height_jitter >= 0):
        raise ValueError(f"height_jitter must be a number >= 0, got {height_jitter!r}")
    az = np.deg2rad(360.0 * np.arange(n) / max(n, 1))
    z = hs[np.arange(n) % hs.size] + np.random.default_rng(seed).uniform(-height_jitter, height_jitter, size=n)
    eye = np.column_stack([radius * np.cos(az), radius * np.sin(az), z])
    return look_at(eye, np.broadcast_to(np.asarray(target, dtype=np.float64), eye.shape)).reshape(n, 4, 4)


def _check_cameras_inside(c2w: np.ndarray, cfg: RoomConfig) -> None:
    """Refuse camera centres closer than ``_MARGIN`` to a room surface or within ``_OBJECTS_RADIUS`` of the z
    axis (among the objects)."""
    t = c2w[:, :3, 3]
    w = float(cfg.half_width) - _MARGIN
    low, high = GROUND_TOP + _MARGIN, cfg.ceiling_z - _MARGIN
    inside = (np.abs(t[:, :2]).max(axis=1) < w) & (t[:, 2] > low) & (t[:, 2] < high)
    among_objects = np.hypot(t[:, 0], t[:, 1]) <= _OBJECTS_RADIUS
    for bad, what in ((~inside, f"is not inside the room (|x|, |y| < {w:g}, {low:g} < z < {high:g})"),
                      (among_objects, f"is within {_OBJECTS_RADIUS:g} of the z axis, among the objects")):
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"camera {k} at {np.round(t[k], 3).tolist()} {what}: check radius and heights")


def export_room_scene(out_dir, config: RoomConfig | None = None, n_views: int = 48, width: int = 100,
                      height: int = 100, fov_deg: float = 60.0, seed: int = 0, radius: float = 2.2,
                      heights=(0.0, 0.4, 0.8), aabb_scale=None, overwrite: bool = False) -> Path:
    """Render and write the room as an instant-ngp / nerfstudio folder (layout in the module docstring).

    Args:
        out_dir: folder to write (created if missing).
        config: room parameters (default ``RoomConfig()``).
        n_views: views on the ring (>= 1), in :func:`room_ring_poses` order (view ``K`` is ``frame_K``).
        width, height: image size in pixels; intrinsics ``Intrinsics.from_fov(fov_deg, width, height)``.
        fov_deg: horizontal field of view in degrees, in (0, 180).
        seed: camera height jitter seed (the room's own seed is ``config.seed``).
        radius, heights: the camera ring (:func:`room_ring_poses`); every camera must be inside the room, at
            least 0.1 from its surfaces and 1.5 from the z axis.
        aabb_scale: written as instant-ngp's ``aabb_scale`` when given: a power of two in [1, 128].
        overwrite: replace an existing scene in ``out_dir``.

    Returns:
        ``out_dir`` as a Path.
    """
    n_views = _check_count(n_views, "n_views", 1)
    width, height = _check_count(width, "width", 1), _check_count(height, "height", 1)
    if not (is_number(fov_deg) and 0.0 < fov_deg < 180.0):
        raise ValueError(f"fov_deg must be in (0, 180) degrees, got {fov_deg!r}")
    if aabb_scale is not None and not (is_number(aabb_scale) and aabb_scale in _AABB_SCALES):
        raise ValueError(f"aabb_scale must be a power of two in [1, 128] (instant-ngp's), got {aabb_scale!r}")
    cfg = RoomConfig() if config is None else config
    scene = build_room_scene(cfg)
    poses = room_ring_poses(n_views, radius, heights, seed=seed)
    _check_cameras_inside(poses, cfg)
    out = _scene_folder(out_dir, ("transforms.json",), overwrite)
    intr = Intrinsics.from_fov(float(fov_deg), width, height)
    for sub in ("images", "depth"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    frames = []
    for k, c2w in enumerate(poses):
        view = render(scene, intr, c2w)
        if not view.alpha.all():   # the room is closed: a miss is a bug, never a background
            raise RuntimeError(f"view {k}: {int((view.alpha == 0).sum())} rays left the room")
        _write_view(view.rgb, view.z_depth.astype(np.float32), out / "images" / f"frame_{k:05d}.png",
                    out / "depth" / f"frame_{k:05d}.npy")
        frames.append({"file_path": f"images/frame_{k:05d}.png", "transform_matrix": opencv_to_opengl(c2w).tolist()})
    doc = {"camera_model": "OPENCV", "fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx, "cy": intr.cy, "w": width,
           "h": height, **({} if aabb_scale is None else {"aabb_scale": int(aabb_scale)}), "frames": frames}
    (out / "transforms.json").write_text(json.dumps(doc, indent=2))
    if overwrite:
        _remove_stale_views(out / "images", n_views, r"frame_([0-9]+)\.png")
        _remove_stale_views(out / "depth", n_views, r"frame_([0-9]+)\.npy")
    meta = {
        "generator": "senerf.procedural.room",
        "room_config": asdict(cfg),
        "object_names": list(ROOM_OBJECT_NAMES),
        "room": {"floor_z": GROUND_TOP, "ceiling_z": cfg.ceiling_z, "half_width": float(cfg.half_width)},
        "camera_seed": int(seed),
        "camera_ring": {"radius": float(radius), "heights": [float(h) for h in np.ravel(heights)],
                        "height_jitter": _HEIGHT_JITTER, "target": [0.0, 0.0, 0.0], "fov_deg": float(fov_deg)},
        "depth": "depth/frame_K.npy: (H, W) float32 camera-frame z-depth, finite and > 0 (every ray hits the room)",
        "image": "images/frame_K.png: RGB 8-bit, no alpha",
    }
    (out / "procedural.json").write_text(json.dumps(meta, indent=2))
    return out
