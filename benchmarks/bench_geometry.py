"""Benchmark of senerf.geometry on one core: project vs cv2.projectPoints vs the memory floor, and reproject.

Run: ``python benchmarks/bench_geometry.py``.  Single-threaded: BLAS thread counts are pinned to 1 before
NumPy is imported and ``cv2.setNumThreads(1)``.  Every figure is the median of several repeats.

Targets (issue #2): project >= 10x faster than cv2.projectPoints (no distortion) on 1 M points and within
3x of the memory floor (copying the same input and output bytes with NumPy); a 400 x 400 reprojection into
3 views with occlusion tests < 50 ms.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from senerf.geometry import Intrinsics, look_at, pixel_rays, project, reproject  # noqa: E402


def median_ms(fn, repeats: int = 9) -> tuple[float, float]:
    """Median wall-clock and median process-CPU milliseconds of ``fn()`` (after one warm-up call).

    CPU time is reported too because the machine is shared: with other jobs on both cores the wall clock
    includes time slices given to them, the CPU time of this single-threaded process does not.
    """
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))


def fmt(t: tuple[float, float]) -> str:
    return f"{t[0]:8.2f} ms wall {t[1]:8.2f} ms cpu"


def bench_project(n: int = 1_000_000) -> None:
    rng = np.random.default_rng(0)
    k = Intrinsics(500.0, 500.0, 256.0, 256.0, 512, 512)
    c2w = look_at([0.5, -4.0, 1.0], [0.0, 0.0, 0.0])
    pts = rng.normal(size=(n, 3))
    w2c = np.linalg.inv(c2w)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    tvec = w2c[:3, 3].copy()
    k_cv = k.K.copy()
    k_cv[:2, 2] -= 0.5
    uv, z, ok = project(pts, k, c2w)
    uv_cv = cv2.projectPoints(pts, rvec, tvec, k_cv, None)[0][:, 0] + 0.5
    err = np.abs(uv[ok] - uv_cv[ok]).max()

    t_ours = median_ms(lambda: project(pts, k, c2w))
    t_cv = median_ms(lambda: cv2.projectPoints(pts, rvec, tvec, k_cv, None), repeats=5)
    # Memory floor: read the input and write outputs of the same sizes (fresh arrays, as project returns).
    t_floor = median_ms(lambda: (pts.copy(), uv.copy(), z.copy(), ok.copy()))
    mb = (pts.nbytes + uv.nbytes + z.nbytes + ok.nbytes) / 1e6
    print(f"project, {n:,} points float64 ({mb:.0f} MB in+out), on one core (ratios: wall / cpu):")
    print(f"  senerf.geometry.project   {fmt(t_ours)}")
    print(f"  cv2.projectPoints         {fmt(t_cv)}   -> project is "
          f"{t_cv[0] / t_ours[0]:.1f}x / {t_cv[1] / t_ours[1]:.1f}x faster (target >= 10x)")
    print(f"  memory floor (np copies)  {fmt(t_floor)}   -> project takes "
          f"{t_ours[0] / t_floor[0]:.2f}x / {t_ours[1] / t_floor[1]:.2f}x the floor (target <= 3x)")
    print(f"  max |uv - cv2| on valid points: {err:.2e} px ({ok.mean():.1%} valid)")


def _scene_depth(k: Intrinsics, c2w: np.ndarray) -> np.ndarray:
    """z-depth of a ground plane z = 0 plus a box [-0.3, 0.3]^2 x [0, 0.8] (analytic ray casting)."""
    o, d, zpd = pixel_rays(k, c2w)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane = -o[..., 2] / d[..., 2]
        t_plane = np.where(t_plane > 0, t_plane, np.inf)
        lo, hi = np.array([-0.3, -0.3, 0.0]), np.array([0.3, 0.3, 0.8])
        t1, t2 = (lo - o) / d, (hi - o) / d
        t_near = np.nanmax(np.minimum(t1, t2), -1)
        t_far = np.nanmin(np.maximum(t1, t2), -1)
        t_box = np.where((t_near <= t_far) & (t_near > 0), t_near, np.inf)
    dist = np.minimum(t_plane, t_box)
    return np.where(np.isfinite(dist), dist * zpd, 0.0)


def bench_reproject(size: int = 400, dtype=np.float32) -> None:
    k = Intrinsics.from_fov(40.0, size, size)
    src = look_at([0.0, -3.0, 2.0], [0.0, 0.0, 0.2])
    dst = look_at(np.array([[1.0, -2.8, 2.0], [-1.0, -2.8, 2.0], [0.3, -3.2, 2.6]]), np.array([0.0, 0.0, 0.2]))
    z_src = _scene_depth(k, src).astype(dtype)
    z_dst = np.stack([_scene_depth(k, c) for c in dst]).astype(dtype)
    _, ok = reproject(z_src, k, src, k, dst, z_depth_dst=z_dst)
    _, ok_geo = reproject(z_src, k, src, k, dst)
    t_occ = median_ms(lambda: reproject(z_src, k, src, k, dst, z_depth_dst=z_dst))
    t_plain = median_ms(lambda: reproject(z_src, k, src, k, dst))
    t_fb = median_ms(lambda: reproject(z_src, k, src, k, dst, z_depth_dst=z_dst, forward_backward=True))
    print(f"reproject {size}x{size} {np.dtype(dtype).name} depth into 3 views, on one core:")
    print(f"  with occlusion z-test     {fmt(t_occ)}   (target < 50 ms)")
    print(f"  geometry only             {fmt(t_plain)}")
    print(f"  z-test + forward-backward {fmt(t_fb)}")
    print(f"  valid fraction: {ok_geo.mean():.1%} in view, {ok.mean():.1%} after the occlusion test")


def main() -> None:
    cv2.setNumThreads(1)
    print("threads: cv2.setNumThreads(1); OMP/OPENBLAS/MKL_NUM_THREADS=1 (NumPy ufuncs are single-threaded)")
    bench_project()
    bench_reproject(dtype=np.float32)
    bench_reproject(dtype=np.float64)


if __name__ == "__main__":
    main()
