"""A small textured procedural scene (trimesh meshes + analytic 3D textures).

The scene is object-centric and bounded: a ground disc (optional) and four objects (box, icosphere,
standing cylinder, tilted torus) placed close together so they occlude each other, all inside the AABB
``[-1.5, 1.5]^3`` of a z-up world.  Every object's high-frequency texture (:func:`texture_color`) is evaluated
analytically at the exact 3D hit point, so a pixel's colour is the exact colour of the surface point its centre
ray hits: no texture maps, no filtering, no anti-aliasing.

Convention: world frame is z-up, units are the scene's (the ground's top face is at ``z = GROUND_TOP``);
object ids index the scene's ``object_names`` (here ``OBJECT_NAMES``; ``-1`` = no hit).  Shading
(:func:`~senerf.procedural.render.shade`) never depends on the viewing direction, so colours are multi-view
consistent.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

__all__ = ["SceneConfig", "ProceduralScene", "ObjectTexture", "build_scene", "OBJECT_NAMES", "GROUND_TOP",
           "texture_color"]

OBJECT_NAMES = ("ground", "box", "sphere", "cylinder", "torus")
GROUND_TOP = -0.65

# Colour palettes (linear values in [0, 1]); the seed picks which object gets which.
_PALETTES = (
    ((0.90, 0.15, 0.10), (0.98, 0.85, 0.20)),  # red / yellow
    ((0.10, 0.30, 0.85), (0.85, 0.90, 0.95)),  # blue / white
    ((0.10, 0.60, 0.20), (0.95, 0.55, 0.10)),  # green / orange
    ((0.55, 0.15, 0.65), (0.30, 0.85, 0.80)),  # purple / cyan
    ((0.15, 0.15, 0.15), (0.90, 0.90, 0.80)),  # black / ivory
)


@dataclass(frozen=True)
class SceneConfig:
    """Scene parameters.

    Attributes:
        seed: drives palette assignment, small position / rotation jitter and the noise lattice.
        with_ground: include the textured ground disc (object id 0).  Without it, only the four objects
            are hit (alpha = object silhouette).
        ground_radius: radius of the ground disc (its top face is at ``z = GROUND_TOP``).
        sphere_subdivisions: icosphere subdivision level (4 -> 5120 faces).
        texture_scale: multiplies every texture frequency (1.0 = default high-frequency textures).
        light_dir: direction *towards* the light, world frame (normalised internally).
        ambient: ambient fraction in [0, 1]; shade = ambient + (1 - ambient) * max(0, n . l).
        jitter: maximum seeded offset of object positions (scene units).
    """

    seed: int = 0
    with_ground: bool = True
    ground_radius: float = 1.3
    sphere_subdivisions: int = 4
    texture_scale: float = 1.0
    light_dir: tuple[float, float, float] = (0.45, -0.35, 0.82)
    ambient: float = 0.35
    jitter: float = 0.05

    def __post_init__(self) -> None:
        if not (0.3 <= float(self.ground_radius) <= 1.5):
            raise ValueError(f"ground_radius must be in [0.3, 1.5] (bounded scene), got {self.ground_radius}")
        if not (0 <= int(self.sphere_subdivisions) <= 6):
            raise ValueError(f"sphere_subdivisions must be in [0, 6], got {self.sphere_subdivisions}")
        if not (0.0 <= float(self.jitter) <= 0.1):
            raise ValueError(f"jitter must be in [0, 0.1], got {self.jitter}")
        _check_look(self)


def _check_look(cfg) -> None:
    """The checks of ``texture_scale``, ``ambient`` and ``light_dir`` that every scene configuration shares."""
    if not (float(cfg.texture_scale) > 0):
        raise ValueError(f"texture_scale must be positive, got {cfg.texture_scale}")
    if not (0.0 <= float(cfg.ambient) <= 1.0):
        raise ValueError(f"ambient must be in [0, 1], got {cfg.ambient}")
    light = np.asarray(cfg.light_dir, dtype=np.float64)
    if light.shape != (3,) or not np.all(np.isfinite(light)) or np.linalg.norm(light) == 0:
        raise ValueError(f"light_dir must be a finite non-zero 3-vector, got {cfg.light_dir}")


@dataclass(frozen=True, eq=False)
class ObjectTexture:
    """Procedural texture of one object, evaluated in the object's local frame.

    Attributes:
        kind: 'checker2d' (xy plane), 'checker3d', 'torus_checker', 'helix', 'noise', 'cells' (xy plane).
        freq: cells (or stripes, or lattice cells) per scene unit / per turn, see :func:`texture_color`.
        colors: (2, 3) float64 palette.
        params: extra scalars (torus major radius, noise lattice values (16**3,), cell values (16**2,)).
    """

    kind: str
    freq: float
    colors: np.ndarray
    params: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ProceduralScene:
    """A built scene: one merged mesh, per-face object ids, per-object frames and textures.

    Attributes:
        config: the :class:`SceneConfig` (or :class:`~senerf.procedural.room.RoomConfig`) it was built from;
            shading reads its ``ambient``.
        mesh: merged ``trimesh.Trimesh`` (world frame).
        face_object: (F,) int32 object id of every face of ``mesh``.
        world_to_local: (n_objects, 4, 4) float64 world -> object frame (texture frame).
        textures: one :class:`ObjectTexture` per object id.
        intersector: embreex ``RayMeshIntersector`` over ``mesh``.
        light: (3,) unit direction towards the light, world frame.
        object_names: the name of every object id.
    """

    config: SceneConfig
    mesh: trimesh.Trimesh
    face_object: np.ndarray
    world_to_local: np.ndarray
    textures: tuple
    intersector: RayMeshIntersector
    light: np.ndarray
    object_names: tuple = OBJECT_NAMES


def _rotation(axis: str, deg: float) -> np.ndarray:
    vec = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}[axis]
    return trimesh.transformations.rotation_matrix(np.deg2rad(deg), vec)


def _object_meshes(cfg: SceneConfig, rng: np.random.Generator):
    """(meshes in local frames, local->world transforms), index = object id."""
    jit = lambda: rng.uniform(-cfg.jitter, cfg.jitter, size=3) * np.array([1.0, 1.0, 0.0])  # noqa: E731
    ground_h = 0.1
    meshes = [
        trimesh.creation.cylinder(radius=cfg.ground_radius, height=ground_h, sections=96),
        trimesh.creation.box(extents=(0.8, 0.8, 0.8)),
        trimesh.creation.icosphere(subdivisions=int(cfg.sphere_subdivisions), radius=0.5),
        trimesh.creation.cylinder(radius=0.25, height=1.3, sections=64),
        trimesh.creation.torus(major_radius=0.42, minor_radius=0.14, major_sections=64, minor_sections=32),
    ]
    z0 = GROUND_TOP
    move = trimesh.transformations.translation_matrix
    transforms = [
        move((0.0, 0.0, z0 - ground_h / 2)),
        move(np.array((-0.45, -0.35, z0 + 0.4)) + jit()) @ _rotation("z", 30 + rng.uniform(-10, 10)),
        move(np.array((0.45, 0.30, z0 + 0.5)) + jit()) @ _rotation("z", rng.uniform(0, 360)),
        move(np.array((0.40, -0.62, z0 + 0.65)) + jit()),
        move(np.array((-0.35, 0.55, z0 + 0.56)) + jit())
        @ _rotation("z", -30 + rng.uniform(-10, 10))
        @ _rotation("x", 70),
    ]
    return meshes, transforms


def _textures(cfg: SceneConfig, rng: np.random.Generator) -> tuple:
    order = rng.permutation(len(_PALETTES))
    pal = [np.asarray(_PALETTES[k], dtype=np.float64) for k in order]
    s = float(cfg.texture_scale)
    noise = rng.uniform(0.0, 1.0, size=16**3)
    return (
        ObjectTexture("checker2d", 6.0 * s, pal[0]),
        ObjectTexture("checker3d", 7.5 * s, pal[1]),
        ObjectTexture("noise", 12.0 * s, pal[2], {"lattice": noise}),
        ObjectTexture("helix", 6.0 * s, pal[3]),
        ObjectTexture("torus_checker", 4.0 * s, pal[4], {"major_radius": 0.42}),
    )


def build_scene(config: SceneConfig | None = None) -> ProceduralScene:
    """Build the scene (meshes, textures, embreex intersector); deterministic given ``config.seed``."""
    cfg = SceneConfig() if config is None else config
    if not isinstance(cfg, SceneConfig):
        raise ValueError(f"config must be a SceneConfig, got {type(cfg).__name__}")
    rng = np.random.default_rng(cfg.seed)
    meshes, transforms = _object_meshes(cfg, rng)
    textures = _textures(cfg, rng)
    keep = [i for i in range(len(meshes)) if cfg.with_ground or i != 0]
    return _assemble(cfg, meshes, transforms, textures, keep, OBJECT_NAMES)


def _assemble(cfg, meshes, transforms, textures, keep, names) -> ProceduralScene:
    """The scene of the objects ``keep`` (ids) of ``meshes`` (local frames) placed by ``transforms`` (local ->
    world (4, 4)); every object id keeps its frame and texture, kept or not."""
    world = [meshes[i].copy().apply_transform(transforms[i]) for i in keep]   # apply_transform returns the mesh
    face_object = [np.full(len(m.faces), i, dtype=np.int32) for i, m in zip(keep, world)]
    mesh = trimesh.util.concatenate(world)
    w2l = np.stack([np.linalg.inv(t) for t in transforms])
    light = np.asarray(cfg.light_dir, dtype=np.float64)
    return ProceduralScene(
        config=cfg,
        mesh=mesh,
        face_object=np.concatenate(face_object),
        world_to_local=w2l,
        textures=textures,
        intersector=RayMeshIntersector(mesh),
        light=light / np.linalg.norm(light),
        object_names=tuple(names),
    )


def _checker(coords: np.ndarray) -> np.ndarray:
    """(N, k) cell coordinates -> (N,) parity in {0, 1}."""
    return (np.floor(coords).astype(np.int64).sum(axis=-1) % 2).astype(np.float64)


def _value_noise(p: np.ndarray, lattice: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1]: trilinear (smoothstep) blend of a periodic 16^3 lattice.  p (N, 3)."""
    base = np.floor(p)
    f = p - base
    w = f * f * (3.0 - 2.0 * f)
    b = base.astype(np.int64)
    out = np.zeros(len(p))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                idx = ((b[:, 0] + dx) % 16) * 256 + ((b[:, 1] + dy) % 16) * 16 + ((b[:, 2] + dz) % 16)
                wx = w[:, 0] if dx else 1 - w[:, 0]
                wy = w[:, 1] if dy else 1 - w[:, 1]
                wz = w[:, 2] if dz else 1 - w[:, 2]
                out += wx * wy * wz * lattice[idx]
    return out


def texture_color(texture: ObjectTexture, local: np.ndarray) -> np.ndarray:
    """Albedo of ``texture`` at object-frame points ``local`` (N, 3) float64 -> (N, 3) float64 in [0, 1].

    Convention: 'checker2d' uses local x, y (cells of ``1/freq`` units); 'checker3d' the three local
    coordinates; 'torus_checker' ``freq`` cells per quarter turn around the torus axis (local z) and per half
    turn around the tube; 'helix' ``freq`` stripes per unit of height shifted by 4 stripes per turn (a helix);
    'noise' value noise with lattice spacing ``1/freq`` mixed between the two palette colours with a sharp ramp;
    'cells' square cells of ``1/freq`` units in local x, y, each mixing 0.6 of the checker parity with 0.4 of its
    own value from the periodic 16 x 16 ``params['lattice']`` (index ``16 (i mod 16) + (j mod 16)``), so that
    neighbouring cells always differ (by at least 0.2) and no two stretches of 16 cells look alike.
    """
    local = np.asarray(local, dtype=np.float64)
    if local.ndim != 2 or local.shape[1] != 3:
        raise ValueError(f"local: expected shape (N, 3), got {local.shape}")
    f = texture.freq
    c0, c1 = texture.colors
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    if texture.kind == "checker2d":
        t = _checker(local[:, :2] * f)
        # a second, coarser modulation so neighbouring checker cells are not all identical
        t = 0.15 + 0.85 * t * (0.6 + 0.4 * _checker(local[:, :2] * (f / 3.0)))
    elif texture.kind == "checker3d":
        t = _checker(local * f + 0.5)
    elif texture.kind == "torus_checker":
        u = np.arctan2(y, x) / (np.pi / 2) * f
        v = np.arctan2(z, np.hypot(x, y) - texture.params["major_radius"]) / np.pi * f
        t = _checker(np.stack([u, v], axis=-1))
    elif texture.kind == "helix":
        turns = np.arctan2(y, x) / (2 * np.pi)
        t = (np.floor(z * f + 4.0 * turns) % 2).astype(np.float64)
    elif texture.kind == "noise":
        n = _value_noise(local * f + 8.0, texture.params["lattice"])
        t = np.clip((n - 0.5) * 4.0 + 0.5, 0.0, 1.0)
    elif texture.kind == "cells":
        cell = np.floor(local[:, :2] * f).astype(np.int64)
        value = texture.params["lattice"][(cell[:, 0] % 16) * 16 + cell[:, 1] % 16]
        t = 0.6 * (cell.sum(axis=-1) % 2) + 0.4 * value
    else:
        raise ValueError(f"unknown texture kind {texture.kind!r}")
    return (1.0 - t)[:, None] * c0[None] + t[:, None] * c1[None]
