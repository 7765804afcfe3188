"""Textured procedural scene with exact ground truth (NumPy + trimesh + embreex; never imports torch).

Convention: OpenCV cameras, z-up world, scene inside ``[-1.5, 1.5]^3``; misses have alpha 0 and z-depth
inf in memory, 0 in exported depth files.
"""

from . import export, render as _render, scene
from .export import *  # noqa: F403  (each module's __all__ names its public API once)
from .render import *  # noqa: F403  (``render`` is the function; its module is ``_render``)
from .scene import *  # noqa: F403

__all__ = [*scene.__all__, *_render.__all__, *export.__all__]
