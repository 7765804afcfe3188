"""Blender-format (NeRF Synthetic) export of the procedural scene, and the small demo scene.

Folder layout written by :func:`export_blender_scene`::

    OUT/transforms_{train,val,test}.json   camera_angle_x (radians) + frames
                                          {"file_path": "./SPLIT/r_K", "rotation": 0.0,
                                           "transform_matrix": 4x4 camera-to-world, OpenGL/Blender convention}
    OUT/SPLIT/r_K.png                      RGBA 8-bit, straight colour, transparent background (alpha 0, rgb 0)
    OUT/SPLIT/r_K_depth.npy                (H, W) float32 exact z-depth (camera-frame z, scene units), 0 = miss
    OUT/procedural.json                    generator settings, seed, depth format, few-shot view indices

Convention: cameras are generated in OpenCV convention (``geometry.pose_from_spherical``, z-up world, looking
at the origin) and converted once with ``geometry.opencv_to_opengl`` when written.  Angles are in degrees
(``camera_angle_x``: radians).  Train and val views are :func:`hemisphere_poses`, test views :func:`ring_poses`.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from senerf.errors import InputError
from senerf.geometry import Intrinsics, opencv_to_opengl, pose_from_spherical

from .render import render
from .scene import SceneConfig, build_scene

__all__ = ["BLENDER_CAMERA_ANGLE_X", "DEMO_FEWSHOT_VIEWS", "hemisphere_poses", "ring_poses", "one_side_poses",
           "export_blender_scene", "make_demo_scene"]

BLENDER_CAMERA_ANGLE_X = 0.6911112070083618  # radians, NeRF Synthetic's value
DEMO_FEWSHOT_VIEWS = (0, 1, 2)  # indices into the demo's train split: three views on one side


def _check_count(n, name: str, minimum: int = 0) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {n!r}")
    return int(n)


def hemisphere_poses(n: int, rng: np.random.Generator, radius: float = 4.0,
                     elevation_range: tuple[float, float] = (10.0, 80.0)) -> np.ndarray:
    """(n, 4, 4) float64 OpenCV c2w on the upper hemisphere looking at the origin.

    Azimuth uniform in [0, 360) degrees, ``sin(elevation)`` uniform in ``sin(elevation_range)`` (uniform
    area on the spherical zone), drawn from ``rng``.
    """
    n = _check_count(n, "n")
    lo, hi = (math.radians(float(e)) for e in elevation_range)
    if not (-math.pi / 2 <= lo <= hi <= math.pi / 2):
        raise ValueError(f"elevation_range must be increasing within [-90, 90], got {elevation_range}")
    az = rng.uniform(0.0, 360.0, size=n)
    el = np.degrees(np.arcsin(rng.uniform(math.sin(lo), math.sin(hi), size=n)))
    return pose_from_spherical(az, el, float(radius)).reshape(n, 4, 4)


def ring_poses(n: int, radius: float = 4.0, elevation: float = 30.0) -> np.ndarray:
    """(n, 4, 4) float64 OpenCV c2w on a ring: azimuths ``360 k / n`` degrees, constant ``elevation``."""
    n = _check_count(n, "n")
    az = 360.0 * np.arange(n) / max(n, 1)
    return pose_from_spherical(az, np.full(n, float(elevation)), float(radius)).reshape(n, 4, 4)


def one_side_poses(n: int, rng: np.random.Generator, radius: float = 4.0) -> np.ndarray:
    """(n, 4, 4) float64 OpenCV c2w all on one side of the scene (few-shot 'extreme' views).

    Azimuths evenly spread over [0, 70] degrees (plus a seeded +-5 degree jitter), elevations seeded
    uniform in [15, 55] degrees.
    """
    n = _check_count(n, "n")
    az = np.linspace(5.0, 65.0, n) + rng.uniform(-5.0, 5.0, size=n)
    el = rng.uniform(15.0, 55.0, size=n)
    return pose_from_spherical(az, el, float(radius)).reshape(n, 4, 4)


def _remove_stale_views(folder: Path, n: int, pattern: str = r"r_(0|[1-9][0-9]*)(\.png|_depth\.npy)") -> None:
    """Delete the files of ``folder`` named ``pattern`` (group 1: the view index ``K``; default ``r_K.png`` /
    ``r_K_depth.npy``) with ``K >= n``: views an earlier, larger export wrote there (an overwrite must not leave
    images no transforms file lists); nothing else is touched."""
    for path in folder.iterdir():
        m = re.fullmatch(pattern, path.name)
        if m and int(m.group(1)) >= n and path.is_file():
            path.unlink()


def _scene_folder(out_dir, markers: tuple, overwrite: bool) -> Path:
    """``out_dir`` as a Path, refused (InputError) when it is a file, or holds one of the ``markers`` (file names)
    of a scene and ``overwrite`` is false; nothing is written."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", file=out)
    existing = [p for p in (out / m for m in markers) if p.exists()]
    if existing and not overwrite:
        raise InputError("already holds a scene (pass overwrite=True to replace it)", file=existing[0])
    return out


def _write_view(image: np.ndarray, z_depth: np.ndarray, png: Path, depth: Path) -> None:
    """Write ``image`` (H, W, C) in [0, 1] as an 8-bit PNG and ``z_depth`` (H, W) as a float32 .npy file."""
    iio.imwrite(png, np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
    np.save(depth, z_depth)


def export_blender_scene(out_dir, config: SceneConfig | None = None, n_train: int = 20, n_val: int = 8,
                         n_test: int = 16, width: int = 100, height: int = 100, seed: int = 0,
                         n_one_side: int = 0, camera_angle_x: float = BLENDER_CAMERA_ANGLE_X,
                         radius: float = 4.0, test_elevation: float = 30.0,
                         overwrite: bool = False) -> Path:
    """Render and write a Blender-format scene folder (layout in the module docstring); returns its path.

    Args:
        out_dir: folder to write (created if missing).
        config: scene parameters (default ``SceneConfig()``).
        n_train, n_val, n_test: views per split (n_train >= 1).
        width, height: image size in pixels; intrinsics ``Intrinsics.from_fov(deg(camera_angle_x), W, H)``.
        seed: camera layout seed (the scene's own seed is ``config.seed``).
        n_one_side: the first ``n_one_side`` train views are :func:`one_side_poses` (few-shot views on one
            side of the scene), the rest :func:`hemisphere_poses`.
        camera_angle_x: horizontal field of view in radians.
        radius: camera distance from the origin.
        test_elevation: elevation of the test ring, degrees.
        overwrite: replace an existing scene in ``out_dir``.
    """
    n_train = _check_count(n_train, "n_train", 1)
    n_val, n_test = _check_count(n_val, "n_val"), _check_count(n_test, "n_test")
    n_one_side = _check_count(n_one_side, "n_one_side")
    if n_one_side > n_train:
        raise ValueError(f"n_one_side ({n_one_side}) exceeds n_train ({n_train})")
    width, height = _check_count(width, "width", 1), _check_count(height, "height", 1)
    if not (0.0 < float(camera_angle_x) < math.pi):
        raise ValueError(f"camera_angle_x must be in (0, pi) radians, got {camera_angle_x}")
    if not (float(radius) > 2.7):
        raise ValueError(f"radius must exceed 2.7 (cameras outside the scene's bounds), got {radius}")
    out = _scene_folder(out_dir, tuple(f"transforms_{s}.json" for s in ("train", "val", "test")), overwrite)

    rng = np.random.default_rng(seed)
    train = np.concatenate([one_side_poses(n_one_side, rng, radius),
                            hemisphere_poses(n_train - n_one_side, rng, radius)])
    layout = {"train": train, "val": hemisphere_poses(n_val, rng, radius),
              "test": ring_poses(n_test, radius, test_elevation)}
    intr = Intrinsics.from_fov(math.degrees(float(camera_angle_x)), width, height)
    scene = build_scene(config)
    for split, poses in layout.items():
        (out / split).mkdir(parents=True, exist_ok=True)
        frames = []
        for k, c2w in enumerate(poses):
            view = render(scene, intr, c2w)
            rgba = np.concatenate([view.rgb, view.alpha[..., None]], axis=-1)
            _write_view(rgba, view.depth_or_zero(), out / split / f"r_{k}.png", out / split / f"r_{k}_depth.npy")
            frames.append({"file_path": f"./{split}/r_{k}", "rotation": 0.0,
                           "transform_matrix": opencv_to_opengl(c2w).tolist()})
        doc = {"camera_angle_x": float(camera_angle_x), "frames": frames}
        (out / f"transforms_{split}.json").write_text(json.dumps(doc, indent=2))
        if overwrite:
            _remove_stale_views(out / split, len(poses))
    meta = {
        "generator": "senerf.procedural",
        "scene_config": asdict(scene.config),
        "camera_seed": int(seed),
        "radius": float(radius),
        "test_elevation_deg": float(test_elevation),
        "one_side_train_views": list(range(n_one_side)),
        "depth": "SPLIT/r_K_depth.npy: (H, W) float32 camera-frame z-depth, 0 where the ray misses",
        "image": "SPLIT/r_K.png: RGBA 8-bit, straight colour, alpha 0 and rgb 0 on the background",
    }
    (out / "procedural.json").write_text(json.dumps(meta, indent=2))
    return out


def make_demo_scene(out_dir, seed: int = 0, overwrite: bool = False) -> Path:
    """Write the small demo scene: 100x100 images, 20 train / 8 val / 16 test views; returns its path.

    Train views ``DEMO_FEWSHOT_VIEWS`` lie on one side of the scene (:func:`one_side_poses`), the others as the
    module docstring says.  ``seed`` seeds both the scene (palettes, jitter) and the camera layout.
    """
    return export_blender_scene(out_dir, SceneConfig(seed=seed), n_train=20, n_val=8, n_test=16,
                                width=100, height=100, seed=seed, n_one_side=len(DEMO_FEWSHOT_VIEWS),
                                overwrite=overwrite)
