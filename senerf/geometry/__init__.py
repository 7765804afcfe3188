"""Camera geometry in NumPy: intrinsics, poses, spherical placement, camera paths, rays, projection and depth
warps.

Importing this package never imports torch; it uses NumPy and OpenCV (``cv2.transform`` in ``project``).

Conventions (see DESIGN.md): OpenCV camera frame (x right, y down, z forward); poses are camera-to-world
``c2w (..., 4, 4)``; pixel ``(i, j)`` covers ``[i, i+1) x [j, j+1)`` with its centre at ``i + 0.5``;
``z_depth`` is camera-frame z, ``ray_dist`` the distance along a unit ray; public angles are degrees.
Dtypes: the data argument (points, uv, depth, eye, azimuth, c2w for pose functions) decides the output
dtype: float32 stays float32, everything else becomes float64.  Poses are composed in float64, and
``project`` applies them in float64 (float32 points far from the origin keep their precision).  Lengths
are taken after an exact power-of-two rescaling, so directions stay exact from 1e-300 to 1e300.
"""

from .intrinsics import Intrinsics
from .poses import (
    invert_rigid,
    is_rigid,
    look_at,
    opencv_to_opengl,
    opengl_to_opencv,
    orthonormalize,
    validate_rigid,
)
from .paths import orbit_path, spiral_focus_depth, spiral_path
from .projection import project, projection_matrix, unproject
from .rays import pixel_centers, pixel_rays, rays_from_pixels
from .spherical import (
    nearest_view_angles,
    closest_point_to_axes,
    default_up,
    pose_from_spherical,
    sample_pseudo_views,
    spherical_basis,
    spherical_from_pose,
)
from .warp import reproject

__all__ = [
    "Intrinsics",
    "opengl_to_opencv",
    "opencv_to_opengl",
    "is_rigid",
    "validate_rigid",
    "orthonormalize",
    "invert_rigid",
    "look_at",
    "pose_from_spherical",
    "spherical_from_pose",
    "spherical_basis",
    "nearest_view_angles",
    "closest_point_to_axes",
    "sample_pseudo_views",
    "orbit_path",
    "spiral_path",
    "spiral_focus_depth",
    "default_up",
    "pixel_centers",
    "pixel_rays",
    "rays_from_pixels",
    "project",
    "projection_matrix",
    "unproject",
    "reproject",
]
