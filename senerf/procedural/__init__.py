"""Textured procedural scene with exact ground truth (NumPy + trimesh + embreex; never imports torch).

- :mod:`.scene`: :class:`SceneConfig`, :func:`build_scene` (ground disc + box, icosphere, cylinder, torus,
  analytic high-frequency textures).
- :mod:`.render`: :func:`render` (RGB(A), exact z-depth, normals, object ids at any OpenCV pose, by ray
  casting the :func:`senerf.geometry.pixel_rays` rays with embreex), :func:`cast_rays`, :func:`shade`.
- :mod:`.export`: :func:`export_blender_scene` (NeRF-Synthetic-format folder that
  :func:`senerf.data.load_scene` reads) and :func:`make_demo_scene`.

Convention: OpenCV cameras, z-up world, scene inside ``[-1.5, 1.5]^3``; misses have alpha 0 and z-depth
inf in memory, 0 in exported depth files.
"""

from .export import (
    BLENDER_CAMERA_ANGLE_X,
    DEMO_FEWSHOT_VIEWS,
    export_blender_scene,
    hemisphere_poses,
    make_demo_scene,
    one_side_poses,
    ring_poses,
)
from .render import Render, RayHits, cast_rays, render, shade
from .scene import GROUND_TOP, OBJECT_NAMES, ObjectTexture, ProceduralScene, SceneConfig, build_scene, texture_color

__all__ = [
    "SceneConfig",
    "ProceduralScene",
    "ObjectTexture",
    "build_scene",
    "texture_color",
    "OBJECT_NAMES",
    "GROUND_TOP",
    "Render",
    "RayHits",
    "cast_rays",
    "shade",
    "render",
    "BLENDER_CAMERA_ANGLE_X",
    "DEMO_FEWSHOT_VIEWS",
    "hemisphere_poses",
    "ring_poses",
    "one_side_poses",
    "export_blender_scene",
    "make_demo_scene",
]
