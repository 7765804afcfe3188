"""Whole fits, phase by phase, against each phase's floor.

Run: ``python benchmarks/bench_fit.py [--scene lego|fern ...] [--out /tmp/bench_fit] [--threads 2] [--reuse]``

Scenes and settings (the figures of the fast-fits issue; seed 0):

- ``lego``: NeRF Synthetic Extreme at 100x100, the balanced preset of senerf 0.2 (1000 steps x 4096 rays,
  3 iterations), scored on 25 test views; target: the whole fit in 3 minutes;
- ``fern``: LLFF, 3 views at 504x378, the fast preset (600 steps x 1024 rays, 1 iteration); target 5 minutes.

Each fit runs as ``senerf-fit`` in a subprocess (wall time and peak RSS of the process); its ``metrics.json`` gives
the seconds of each phase.  The floors, measured in this process with the fit's own settings:

- training: the same field (``build_field`` of the run's ModelConfig) trained on the same samples per step
  (rays x samples, uniform along random rays through its box), forward, backward and fused Adam, nothing else:
  the field benchmark's samples per second (``bench_fields.py``'s step); target: a fit trains at >= 60 % of it;
- features: VGG-19 features of one pseudo view alone, times the pseudo views the fit labelled.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(os.environ.get("SENERF_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
FITS = {
    "lego": (DATA / "nerf_synthetic" / "lego", ["--protocol", "extreme", "--downscale", "4", "--steps", "1000",
                                                  "--batch-rays", "4096", "--iterations", "3", "--test-views", "25"],
             180.0),
    "fern": (DATA / "nerf_llff_data" / "fern", ["--protocol", "llff", "--n-views", "3", "--steps", "600",
                                                  "--batch-rays", "1024", "--iterations", "1"], 300.0),
}


def run_fit(scene: str, out: Path, threads: int, reuse: bool) -> tuple[float, float | None]:
    """Fit ``scene`` into ``out`` (``senerf-fit``, seed 0); ``(wall seconds, peak RSS MiB)`` (None when reused)."""
    folder, flags, _ = FITS[scene]
    if reuse and (out / "metrics.json").exists():
        return float("nan"), None
    cmd = [sys.executable, "-m", "senerf.cli", str(folder), *flags, "--seed", "0", "--threads", str(threads),
           "--out", str(out), "--overwrite", "--quiet"]
    print("$", " ".join(cmd), flush=True)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd)
    _, status, usage = os.wait4(proc.pid, 0)   # this child's own peak RSS (KiB on Linux)
    if status:
        raise SystemExit(f"senerf-fit failed (wait status {status})")
    return time.perf_counter() - t0, usage.ru_maxrss / 1024.0


def training_floor(run_dir: Path, steps: int = 6) -> float:
    """Samples per second of the run's field alone on its step's samples (median of ``steps`` after a warm-up)."""
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_fields import ray_points

    from senerf.config import ModelConfig, TrainConfig
    from senerf.train import build_field

    settings = json.loads((run_dir / "run.json").read_text())["settings"]
    model, train = ModelConfig(**settings["model"]), TrainConfig(**settings["train"])
    field = build_field(model, seed=0, steps=train.steps)
    opt = torch.optim.Adam(field.parameters(), lr=train.lr, eps=1e-15, fused=True)
    gen = torch.Generator().manual_seed(0)
    xyz, dirs = ray_points(torch.as_tensor(model.field_aabb, dtype=torch.float32), train.batch_rays,
                           model.n_samples, gen)
    target = torch.rand(xyz.shape[0], 3, generator=gen)
    times = []
    for k in range(steps + 1):
        t0 = time.perf_counter()
        sigma, rgb = field(xyz, dirs)
        loss = (rgb - target).square().mean() + 1e-3 * sigma.mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if k:
            times.append(time.perf_counter() - t0)
    return xyz.shape[0] / statistics.median(times)


def features_floor(run_dir: Path, n_views: int) -> float:
    """Seconds of VGG-19 features alone for ``n_views`` images of the run's size (median of 3, times n_views)."""
    import numpy as np

    from senerf.selftrain.features import VGG19Features

    h, w = json.loads((run_dir / "metrics.json").read_text())["resolution"]
    extractor = VGG19Features()
    image = np.random.default_rng(0).uniform(size=(1, h, w, 3)).astype(np.float32)
    extractor(image)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        extractor(image)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * n_views


def report(scene: str, run_dir: Path, wall: float, peak: float | None, threads: int) -> None:
    metrics = json.loads((run_dir / "metrics.json").read_text())
    rows = metrics["iterations"]
    total = {name: sum(r["phases"][name] for r in rows) for name in rows[0]["phases"]}
    samples = sum(r["train_samples_per_s"] * r["phases"]["train"] for r in rows)
    fit_rate, floor_rate = samples / total["train"], training_floor(run_dir)
    n_pseudo = len(list(run_dir.glob("iter_*/pseudo/rgb_*.png")))
    target = FITS[scene][2]
    print(f"[{scene}] {metrics['resolution'][1]}x{metrics['resolution'][0]}, {len(rows)} iteration(s), seed 0, "
          f"{threads} threads; process wall {wall:.1f} s, peak RSS {peak if peak is None else round(peak)} MiB; "
          f"fitting {metrics['seconds_total']:.1f} s (target {target:.0f} s: "
          f"{'met' if metrics['seconds_total'] <= target else 'NOT met'})")
    for name, seconds in total.items():
        print(f"  {name:14s} {seconds:7.1f} s")
    print(f"  training: {fit_rate / 1e6:.3f} M samples/s in the fit, {floor_rate / 1e6:.3f} M samples/s the field "
          f"alone: {fit_rate / floor_rate * 100:.0f} % (target >= 60 %)")
    if n_pseudo:
        floor = features_floor(run_dir, n_pseudo)
        print(f"  features: {total['features']:.1f} s for {n_pseudo} pseudo views, VGG-19 alone {floor:.1f} s "
              f"({total['features'] / floor:.2f}x; the known views' features are in the fit's figure too)")
    psnr = " -> ".join(f"{r['psnr']:.2f}" for r in rows)
    print(f"  PSNR per iteration: {psnr} dB", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=sorted(FITS), action="append")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_fit"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reuse", action="store_true", help="report an existing fit in --out/<scene> instead of fitting")
    args = ap.parse_args(argv)
    from senerf.cliargs import huge_page_tensors, short_openmp_waits

    short_openmp_waits()   # the floors measured as senerf-fit runs
    huge_page_tensors()
    import torch

    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {os.cpu_count()} cpus, load avg {os.getloadavg()[0]:.2f}")
    for scene in args.scene or ["lego", "fern"]:
        run_dir = args.out / scene
        wall, peak = run_fit(scene, run_dir, args.threads, args.reuse)
        report(scene, run_dir, wall, peak, args.threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
