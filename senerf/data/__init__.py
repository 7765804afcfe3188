"""Scene loading, few-shot protocols and input validation (NumPy + imageio + OpenCV; never imports torch).

Public API::

    Scene                                   frozen dataclass (images, OpenCV c2w, intrinsics, splits, bounds)
    load_scene(path, downscale=1, background=None) -> Scene      auto-detects Blender / ngp / LLFF
    fewshot_split(scene, protocol, views=None, n_views=None, seed=0) -> (train_idx, test_idx)
    load_blender, load_ngp, load_llff, load_colmap   the per-format loaders (LLFF and COLMAP take bd_factor,
                                            recenter)
    detect_format(path) -> 'blender' | 'ngp' | 'llff' | 'colmap'
    Distortion, undistorted_intrinsics, undistortion_maps, undistort_image, distort_pixels, photo_coverage,
    COVERAGE_WARN
                                            lens undistortion, applied by the JSON loaders (OPENCV, OPENCV_FISHEYE)
    scene_file_digests(scene, views=None) -> {name: sha256}   what the scene's files held (resume checks)
    run_file_digests(scene, train_idx, test_idx, oracle=False, missing_ok=False)   those of the files a run reads
    changed_files(then, now) -> [line]      how two such records differ, one line per file
    view_names(scene, views) -> [name]      each view's image file, relative to the scene folder
    EXTREME_VIEWS, INFONERF4_VIEWS, PROTOCOLS

Every problem with user input raises :class:`senerf.errors.InputError` naming the file and the field.
See :mod:`senerf.data.load` (detection, downscaling), :mod:`senerf.data.blender`, :mod:`senerf.data.llff`
(normalisation) and :mod:`senerf.data.fewshot` (protocols) for the documented choices.
"""

from .blender import load_blender, load_ngp
from .colmap import load_colmap
from .fewshot import EXTREME_VIEWS, INFONERF4_VIEWS, PROTOCOLS, fewshot_split, spread_views
from .llff import load_llff, recenter_poses
from .load import detect_format, load_scene, scene_root
from .scene import Scene, changed_files, run_file_digests, scene_file_digests, view_names
from .undistort import (COVERAGE_WARN, Distortion, distort_pixels, photo_coverage, undistort_image,
                        undistorted_intrinsics, undistortion_maps)

__all__ = [
    "Scene",
    "scene_file_digests",
    "run_file_digests",
    "changed_files",
    "view_names",
    "load_scene",
    "detect_format",
    "scene_root",
    "load_blender",
    "load_ngp",
    "load_llff",
    "load_colmap",
    "recenter_poses",
    "fewshot_split",
    "spread_views",
    "EXTREME_VIEWS",
    "INFONERF4_VIEWS",
    "PROTOCOLS",
    "Distortion",
    "distort_pixels",
    "undistorted_intrinsics",
    "undistortion_maps",
    "undistort_image",
    "photo_coverage",
    "COVERAGE_WARN",
]
