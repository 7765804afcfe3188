"""Camera geometry in NumPy: intrinsics, poses, spherical placement, camera paths, rays, projection and depth
warps, in the conventions of DESIGN.md.  Importing it never imports torch; ``project`` uses ``cv2.transform``.

Dtypes: the data argument (points, uv, depth, eye, azimuth, c2w for pose functions) decides the output
dtype: float32 stays float32, everything else becomes float64.  Poses are composed in float64 (the
``Convention:`` of :mod:`.projection` and :mod:`.warp`); lengths are exact at any finite scale (:mod:`._util`).
"""

from . import intrinsics, paths, poses, projection, rays, spherical, warp
from .intrinsics import *  # noqa: F403  (each module's __all__ names its public API once)
from .paths import *  # noqa: F403
from .poses import *  # noqa: F403
from .projection import *  # noqa: F403
from .rays import *  # noqa: F403
from .spherical import *  # noqa: F403
from .warp import *  # noqa: F403

__all__ = [name for module in (intrinsics, poses, spherical, paths, rays, projection, warp)
           for name in module.__all__]
