"""A capture through a distorting lens, fitted with its distortion undone at load and with it ignored.

Builds three versions of the demo scene (:func:`senerf.procedural.make_demo_scene`, exact ground truth):

* ``pinhole``: the demo scene itself;
* ``distorted``: every view re-rendered exactly through a lens with OpenCV radial-tangential distortion
  (each photo pixel's ray is the undistorted direction of its centre, solved here by Newton's method and cast
  into the procedural scene), with the coefficients in ``transforms_*.json``: the loader undoes them;
* ``ignored``: the same photos with the coefficients left out of the JSON, which is what senerf did with
  distortion before it undid it (it warned and used the photos as pinhole images).

and fits each with ``senerf-fit`` (one fit at a time).  Each fit's own test PSNR is scored against its own
loader's view of the test photos (resampled for ``distorted``, raw for ``ignored``), which do not compare
across scenes; so every fit is also rendered at one common set of cameras, the test poses with the pinhole
camera the ``distorted`` loader derives, and scored against exact ray-cast renders of the scene there
(``common``, white background as ``senerf-fit`` evaluates).

Usage::

    python benchmarks/distorted_capture.py --out benchmarks/out/distorted [--k1 -0.3 --k2 0.1 ...]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from senerf.geometry import Intrinsics, opengl_to_opencv
from senerf.procedural import DEMO_FEWSHOT_VIEWS, build_scene, cast_rays, make_demo_scene, shade
from senerf.procedural.scene import SceneConfig

__all__ = ["undistort_normalised", "render_distorted", "build_scenes", "main"]

SPLITS = ("train", "val", "test")


def _distort(x, y, c):
    k1, k2, p1, p2, k3 = c
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def undistort_normalised(xd: np.ndarray, yd: np.ndarray, coeffs) -> tuple:
    """Normalised pinhole ``(x, y)`` whose distortion is ``(xd, yd)`` (Newton's method, residual < 1e-12)."""
    x, y, h = xd.copy(), yd.copy(), 1e-7
    for _ in range(50):
        fx, fy = _distort(x, y, coeffs)
        ax, ay = _distort(x + h, y, coeffs)
        bx, by = _distort(x, y + h, coeffs)
        j11, j21, j12, j22 = (ax - fx) / h, (ay - fy) / h, (bx - fx) / h, (by - fy) / h
        det = j11 * j22 - j12 * j21
        rx, ry = fx - xd, fy - yd
        x, y = x - (j22 * rx - j12 * ry) / det, y - (-j21 * rx + j11 * ry) / det
    fx, fy = _distort(x, y, coeffs)
    if max(np.abs(fx - xd).max(), np.abs(fy - yd).max()) > 1e-12:
        raise RuntimeError("the distortion could not be inverted over the image")
    return x, y


def render_distorted(scene, k: Intrinsics, c2w_cv: np.ndarray, coeffs) -> np.ndarray:
    """``(H, W, 4)`` uint8 RGBA of the procedural ``scene`` through a lens with OpenCV ``coeffs``."""
    u, v = np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5)
    x, y = undistort_normalised((u - k.cx) / k.fx, (v - k.cy) / k.fy, coeffs)
    dirs_cam = np.stack([x, y, np.ones_like(x)], -1).reshape(-1, 3)
    dirs = dirs_cam @ c2w_cv[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = cast_rays(scene, np.broadcast_to(c2w_cv[:3, 3], dirs.shape), dirs)
    rgba = np.concatenate([shade(scene, hits), hits.hit[:, None].astype(np.float64)], 1)
    return np.round(np.clip(rgba, 0, 1) * 255).astype(np.uint8).reshape(k.height, k.width, 4)


def build_scenes(out: Path, coeffs, seed: int = 0) -> dict:
    """Write ``out/{pinhole,distorted,ignored}`` (module docstring); returns their paths."""
    base = make_demo_scene(out / "pinhole", seed=seed, overwrite=True)
    scene = build_scene(SceneConfig(seed=seed))
    dist, ignored = out / "distorted", out / "ignored"
    for folder in (dist, ignored):
        shutil.rmtree(folder, ignore_errors=True)
    names = dict(zip(("k1", "k2", "p1", "p2", "k3"), coeffs))
    for split in SPLITS:
        meta = json.loads((base / f"transforms_{split}.json").read_text())
        k = Intrinsics.from_fov(np.degrees(meta["camera_angle_x"]), 100, 100)
        for folder in (dist, ignored):
            (folder / split).mkdir(parents=True, exist_ok=True)
        for frame in meta["frames"]:
            c2w = opengl_to_opencv(np.asarray(frame["transform_matrix"], np.float64))
            photo = render_distorted(scene, k, c2w, coeffs)
            rel = frame["file_path"].lstrip("./") + ".png"
            iio.imwrite(dist / rel, photo)
            iio.imwrite(ignored / rel, photo)
        (ignored / f"transforms_{split}.json").write_text(json.dumps(meta, indent=2))
        (dist / f"transforms_{split}.json").write_text(json.dumps(dict(meta, **names), indent=2))
    return {"pinhole": base, "distorted": dist, "ignored": ignored}


def common_psnr(fit_dir: Path, truth: dict, iteration: int) -> float:
    """Mean PSNR of a finished fit's ``iteration`` rendered at ``truth['c2w'] (n, 4, 4)`` with
    ``truth['intrinsics']``, against ``truth['rgb'] (n, H, W, 3)`` in [0, 1]."""
    from senerf.flythrough import load_run
    from senerf.train import render_views

    run = load_run(fit_dir, iteration=iteration)
    out = render_views(run.field, run.model, truth["intrinsics"], truth["c2w"], occupancy=run.occupancy,
                       progress=False)
    mse = ((np.clip(out["rgb"], 0, 1) - truth["rgb"]) ** 2).reshape(len(truth["rgb"]), -1).mean(1)
    return float(np.mean(-10.0 * np.log10(mse)))


def common_truth(scenes: dict, seed: int) -> dict:
    """Exact renders at the test poses through the ``distorted`` scene's pinhole camera, on white."""
    from senerf.data import load_scene
    from senerf.procedural import render

    loaded = load_scene(scenes["distorted"])
    k = loaded.intrinsics
    idx = loaded.splits["test"]
    c2w = loaded.c2w[idx]
    scene = build_scene(SceneConfig(seed=seed))
    rgb = []
    for pose in c2w:
        view = render(scene, k, pose)
        rgb.append(view.rgb * view.alpha[..., None] + (1.0 - view.alpha[..., None]))
    return {"intrinsics": k, "c2w": c2w, "rgb": np.stack(rgb).astype(np.float32)}


def _fit(scene_dir: Path, out: Path, views: str, iterations: int, seed: int) -> dict:
    cmd = ["senerf-fit", str(scene_dir), "--views", views, "--preset", "fast", "--iterations", str(iterations),
           "--seed", str(seed), "--out", str(out), "--overwrite", "--quiet"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    metrics = json.loads((out / "metrics.json").read_text())
    its = metrics["iterations"]
    return {"first": its[0]["psnr"], "last": its[-1]["psnr"], "wall_s": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--k1", type=float, default=-0.3)
    ap.add_argument("--k2", type=float, default=0.1)
    ap.add_argument("--p1", type=float, default=0.002)
    ap.add_argument("--p2", type=float, default=-0.001)
    ap.add_argument("--k3", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", nargs="+", default=["all20", "fewshot"], choices=["all20", "fewshot"],
                    help="all20: the baseline from all 20 train views; fewshot: the demo's 3 views + 1 SE-NeRF "
                         "iteration")
    args = ap.parse_args(argv)
    coeffs = (args.k1, args.k2, args.p1, args.p2, args.k3)
    scenes = build_scenes(args.out, coeffs, args.seed)
    truth = common_truth(scenes, args.seed)
    runs = {"all20": (",".join(map(str, range(20))), 0),
            "fewshot": (",".join(map(str, DEMO_FEWSHOT_VIEWS)), 1)}
    print(f"distortion (k1, k2, p1, p2, k3) = {coeffs}")
    for run in args.runs:
        views, iterations = runs[run]
        for name, path in scenes.items():
            fit_dir = args.out / "fits" / f"{run}_{name}"
            res = _fit(path, fit_dir, views, iterations, args.seed)
            common = [common_psnr(fit_dir, truth, k) for k in range(iterations + 1)]
            print(f"{run:8s} {name:10s} own test views: iteration 0 {res['first']:.3f} dB, iteration {iterations} "
                  f"{res['last']:.3f} dB; common: " + ", ".join(f"iteration {k} {c:.3f} dB" for k, c in
                                                                enumerate(common)) + f" ({res['wall_s']:.0f} s)",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
