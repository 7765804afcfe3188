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

from senerf.config import PRESETS

#: The training views senerf-fit picks per --protocol (random8: any 8 of the train split; "PROTOCOL SCENE": a
#: scene's own).
VIEWS = {"extreme": [0, 1, 51], "infonerf4": [26, 86, 2, 55], "random8": [3, 14, 15, 92, 65, 35, 89, 79],
         "dtu": [25, 22, 28, 40, 44, 48, 0, 8, 13], "extreme mic": [35, 65, 82]}
#: The full-size sides the fit's --downscale divides: LLFF (H, W), NeRF Synthetic, the DTU copies.
SIZES = {"llff": (3024, 4032), "dtu": (384, 384)}


def write_atomic(path: Path, data: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data))
    os.replace(tmp, path)


def main(argv):
    p = argparse.ArgumentParser()
    p.add_argument("scene")
    p.add_argument("--n-views", type=int, default=3)
    p.add_argument("--protocol", default="extreme")
    p.add_argument("--downscale", type=float, default=1)
    p.add_argument("--iterations", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    p.add_argument("--preset", choices=tuple(PRESETS), default="balanced")
    p.add_argument("--steps", type=int)
    a, _ = p.parse_known_args(argv)   # the methods' and presets' flags are accepted and ignored
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if os.environ.get("FAKE_FIT_PIDFILE"):
        Path(os.environ["FAKE_FIT_PIDFILE"]).write_text(str(os.getpid()))
    crash = {int(s) for s in os.environ.get("FAKE_FIT_CRASH_SEEDS", "").split(",") if s}
    views = list(range(1, 1 + a.n_views)) if a.protocol == "llff" else \
        VIEWS.get(f"{a.protocol} {Path(a.scene).name}", VIEWS[a.protocol])
    views = views[:a.n_views] if a.protocol == "dtu" else views
    size = [round(side / a.downscale) for side in SIZES.get(a.protocol, (800, 800))]
    metrics = {"senerf_version": "fake", "command": ["senerf-fit", *argv], "train_views": views,
               "config": {"train": {"steps": a.steps or PRESETS[a.preset].steps,
                                    "batch_rays": PRESETS[a.preset].batch_rays}},
               "test_views": [0, 1, 2], "resolution": size, "iterations": [], "seconds_total": 0.0}
    for k in range(a.iterations + 1):
        time.sleep(float(os.environ.get("FAKE_FIT_SLEEP", "0")))
        psnr = 20.0 + k + a.seed / 10.0
        metrics["iterations"].append({
            "iteration": k, "psnr": psnr, "ssim": 0.5 + 0.01 * k, "lpips": "unavailable", "avg": "unavailable",
            "reliable_fraction": None if k == 0 else 0.8, "seconds": float(os.environ.get("FAKE_FIT_SECONDS", "1.5")),
            "per_view": {"psnr": [psnr - 1, psnr, psnr + 1], "ssim": [0.5, 0.5, 0.5]},
            "host": {"device": "cpu", "threads": 1, "cpu": "Fake CPU", "torch": "0.0"}})
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
