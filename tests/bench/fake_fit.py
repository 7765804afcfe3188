"""A stand-in for ``senerf-fit`` in the harness tests: parses the contract flags, writes metrics.json.

PSNR depends on seed and iteration (``20 + iteration + seed / 10``) so tests can check the values travel
through unchanged.  Environment knobs:
``FAKE_FIT_CRASH_SEEDS`` (comma list): SIGKILL itself for these seeds (simulated OOM kill) after writing a
partial metrics.json; ``FAKE_FIT_ALLOC_MB``: touch this many MiB before finishing (peak-memory check);
``FAKE_FIT_SLEEP``: seconds to sleep per iteration; ``FAKE_FIT_SECONDS``: the seconds it reports (1.5);
``FAKE_FIT_PIDFILE``: write the fit's pid there.
"""

import argparse
import json
import os
import signal
import sys
import time
from pathlib import Path


def write_atomic(path: Path, data: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data))
    os.replace(tmp, path)


def main(argv):
    p = argparse.ArgumentParser()
    p.add_argument("scene")
    p.add_argument("--views", default=None)
    p.add_argument("--n-views", type=int, default=None)
    p.add_argument("--protocol", default=None)
    p.add_argument("--downscale", type=int, default=1)
    p.add_argument("--iterations", type=int, default=3)
    p.add_argument("--features", default="vgg19")
    p.add_argument("--threshold", default="adaptive")
    p.add_argument("--no-density-distill", action="store_true")
    p.add_argument("--no-prior", action="store_true")
    p.add_argument("--preset", default="balanced")
    p.add_argument("--steps", type=int, default=None)
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    p.add_argument("--overwrite", action="store_true")
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if os.environ.get("FAKE_FIT_PIDFILE"):
        Path(os.environ["FAKE_FIT_PIDFILE"]).write_text(str(os.getpid()))
    crash = {int(s) for s in os.environ.get("FAKE_FIT_CRASH_SEEDS", "").split(",") if s}
    views = [int(v) for v in a.views.split(",")] if a.views else [0, 1, 51]
    side = 800 // a.downscale
    metrics = {"senerf_version": "fake", "command": ["senerf-fit", *argv], "config": {"preset": a.preset},
               "scene": Path(a.scene).name, "train_views": views, "test_views": [0, 1, 2],
               "resolution": [side, side], "iterations": [], "seconds_total": 0.0}
    for k in range(a.iterations + 1):
        time.sleep(float(os.environ.get("FAKE_FIT_SLEEP", "0")))
        psnr = 20.0 + k + a.seed / 10.0
        metrics["iterations"].append({
            "iteration": k, "psnr": psnr, "ssim": 0.5 + 0.01 * k, "lpips": "unavailable", "avg": "unavailable",
            "reliable_fraction": None if k == 0 else 0.8, "seconds": float(os.environ.get("FAKE_FIT_SECONDS", "1.5")),
            "per_view": {"psnr": [psnr - 1, psnr, psnr + 1], "ssim": [0.5, 0.5, 0.5]}})
        metrics["seconds_total"] += 1.5
        write_atomic(out / "metrics.json", metrics)
        if a.seed in crash:
            sys.stdout.flush()
            os.kill(os.getpid(), signal.SIGKILL)
    mb = int(os.environ.get("FAKE_FIT_ALLOC_MB", "0"))
    if mb:
        block = bytearray(mb * 2**20)
        block[:: 4096] = b"\x01" * len(block[:: 4096])
    print("fake fit done")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
