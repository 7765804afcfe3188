"""Scene loading, few-shot protocols and input validation (NumPy + Pillow + OpenCV; never imports torch).

Every problem with user input raises :class:`senerf.errors.InputError` naming the file and the field.  The
documented choices are in :mod:`senerf.data.load` (detection, downscaling), the loaders' modules,
:mod:`senerf.data.undistort` (lens models) and :mod:`senerf.data.fewshot` (protocols).
"""

from .blender import load_blender, load_ngp
from .colmap import load_colmap
from .fewshot import EXTREME_VIEWS, INFONERF4_VIEWS, PROTOCOLS, fewshot_split, spread_views
from .llff import load_llff
from .load import detect_format, load_scene, scene_root
from .scene import SCENE_KINDS, Scene, changed_files, scene_file_digests, view_names
from .undistort import (COVERAGE_WARN, Distortion, distort_pixels, photo_coverage, undistort_image,
                        undistorted_intrinsics, undistortion_maps)

__all__ = [
    "Scene", "SCENE_KINDS", "scene_file_digests", "changed_files", "view_names",
    "load_scene", "detect_format", "scene_root", "load_blender", "load_ngp", "load_llff", "load_colmap",
    "fewshot_split", "spread_views", "EXTREME_VIEWS", "INFONERF4_VIEWS", "PROTOCOLS",
    "Distortion", "distort_pixels", "undistorted_intrinsics", "undistortion_maps", "undistort_image",
    "photo_coverage", "COVERAGE_WARN",
]
