"""Textured procedural scenes with exact ground truth (NumPy + trimesh + embreex; never imports torch).

Convention: OpenCV cameras, z-up world.  The object scene (:mod:`.scene`) lies inside ``[-1.5, 1.5]^3``; its
misses have alpha 0 and z-depth inf in memory, 0 in exported depth files.  The room (:mod:`.room`) is closed:
every ray from inside hits a surface.
"""

from . import export, render as _render, room, scene
from .export import *  # noqa: F403  (each module's __all__ names its public API once)
from .render import *  # noqa: F403  (``render`` is the function; its module is ``_render``)
from .room import *  # noqa: F403
from .scene import *  # noqa: F403

__all__ = [*scene.__all__, *_render.__all__, *export.__all__, *room.__all__]
