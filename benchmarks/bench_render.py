"""Benchmark of ``senerf-render``'s videos: a 60-frame mp4 orbit of a 100 x 100 fit (issue 37's target: under 30 s
on 2 CPU cores, and the file plays: ffprobe reads it).

Run: ``python benchmarks/bench_render.py [--run RUN] [--threads N]``.  Without ``--run`` it first fits lego
Extreme at 100 x 100 (``senerf-fit LEGO --protocol extreme --downscale 4 --preset fast --out /tmp/bench_lego_fast``,
reused when that folder already holds a finished run).

It times the whole ``senerf-render RUN --frames 60`` command as a user runs it (a fresh process: imports, loading
the run, rendering, encoding rgb.mp4 and depth.mp4, the atomic rename), then the two encodes alone
(:func:`senerf.flythrough.write_mp4` on the decoded frames), and checks both files with ffprobe (Debian's
``ffmpeg`` package) or, where there is none, with the ffmpeg imageio-ffmpeg bundles: H.264, yuv420p, an even size,
60 frames.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LEGO = Path("/work/shared/data/nerf_synthetic/lego")
TARGET_S = 30.0
FRAMES = 60


def _env() -> dict:
    """The environment of the subprocesses: this checkout's senerf first on the path."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))


def ensure_fit(run: Path) -> Path:
    """``run``, fitted (lego Extreme, 100 x 100, the fast preset) unless it already holds a finished run."""
    if not (run / "metrics.json").is_file():
        subprocess.run([sys.executable, "-m", "senerf.cli", str(LEGO), "--protocol", "extreme", "--downscale", "4",
                        "--preset", "fast", "--out", str(run), "--overwrite"], check=True, env=_env())
    return run


def probe(mp4: Path) -> dict:
    """Codec, pixel format, size and frame count of ``mp4``'s video stream, read by ffprobe (or, without it, by
    the bundled ffmpeg, decoding every frame)."""
    if shutil.which("ffprobe"):
        out = subprocess.run(["ffprobe", "-v", "error", "-select_streams", "v:0", "-count_frames", "-show_entries",
                              "stream=codec_name,pix_fmt,width,height,nb_read_frames,avg_frame_rate", "-of", "json",
                              str(mp4)], check=True, capture_output=True, text=True).stdout
        s = json.loads(out)["streams"][0]
        return dict(reader="ffprobe", codec=s["codec_name"], pix_fmt=s["pix_fmt"], size=(s["width"], s["height"]),
                    frames=int(s["nb_read_frames"]), fps=s["avg_frame_rate"])
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    return dict(reader="bundled ffmpeg", codec=meta["codec"], pix_fmt=meta["pix_fmt"].split("(")[0],
                size=tuple(meta["size"]), frames=sum(1 for _ in reader), fps=meta["fps"])


def decode(mp4: Path) -> np.ndarray:
    """``(n, H, W, 3)`` uint8 frames of ``mp4``."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(mp4))
    w, h = next(reader)["size"]
    return np.stack([np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in reader])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, default=None, help="a finished 100 x 100 senerf-fit run (default: fit lego)")
    p.add_argument("--threads", type=int, default=None, help="senerf-render --threads (default: torch's)")
    args = p.parse_args()
    run = args.run or ensure_fit(Path("/tmp/bench_lego_fast"))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "orbit"
        cmd = [sys.executable, "-m", "senerf.flythrough", str(run), "--frames", str(FRAMES), "--out", str(out),
               "--quiet", *(["--threads", str(args.threads)] if args.threads else [])]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, env=_env())
        total = time.perf_counter() - t0
        from senerf.flythrough import write_mp4

        frames = {name: decode(out / f"{name}.mp4") for name in ("rgb", "depth")}
        t0 = time.perf_counter()
        for name, stack in frames.items():
            write_mp4(Path(tmp) / f"again_{name}.mp4", stack, 20.0)
        encode = time.perf_counter() - t0
        probes = {name: probe(out / f"{name}.mp4") for name in ("rgb", "depth")}
        size = {name: (out / f"{name}.mp4").stat().st_size for name in probes}
    print(f"run: {run} ({os.cpu_count()} CPUs, torch threads {args.threads or 'default'})")
    print(f"senerf-render {FRAMES}-frame mp4 orbit: {total:.1f} s wall (target < {TARGET_S:.0f} s: "
          f"{'met' if total < TARGET_S else 'MISSED'}); of it encoding rgb.mp4 + depth.mp4: {encode:.2f} s")
    ok = True
    for name, info in probes.items():
        good = (info["codec"] == "h264" and info["pix_fmt"] == "yuv420p" and info["frames"] == FRAMES
                and all(v % 2 == 0 for v in info["size"]))
        ok &= good
        print(f"{name}.mp4 ({size[name] / 1024:.0f} KiB), {info['reader']}: {info['codec']} {info['pix_fmt']} "
              f"{info['size'][0]}x{info['size'][1]}, {info['frames']} frames at {info['fps']} fps: "
              f"{'plays' if good else 'NOT AS EXPECTED'}")
    return 0 if ok and total < TARGET_S else 1


if __name__ == "__main__":
    sys.exit(main())
