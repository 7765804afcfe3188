"""Put two senerf-render outputs side by side in one labelled GIF (the README's teacher | SE-NeRF orbit).

    senerf-render RUN --iteration 0 --frames 48 --out A
    senerf-render RUN --frames 48 --out B
    python benchmarks/side_by_side_gif.py A B OUT.gif --labels "teacher (iteration 0)" "SE-NeRF (iteration 3)"
"""

from __future__ import annotations

import argparse
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from PIL import Image, ImageDraw


def side_by_side(left: Path, right: Path, labels: tuple[str, str], zoom: int = 2) -> np.ndarray:
    """``(n, H, W, 3)`` uint8 frames: the two folders' ``rgb_XXX.png`` beside each other under their labels."""
    names = sorted(p.name for p in left.glob("rgb_*.png"))
    if not names or names != sorted(p.name for p in right.glob("rgb_*.png")):
        raise SystemExit(f"{left} and {right} must hold the same rgb_XXX.png frames")
    frames = []
    for name in names:
        a, b = (np.kron(iio.imread(d / name)[..., :3], np.ones((zoom, zoom, 1), np.uint8)) for d in (left, right))
        gap = np.full((a.shape[0], 4, 3), 255, np.uint8)
        row = np.concatenate([a, gap, b], axis=1)
        img = Image.fromarray(np.concatenate([np.full((18, row.shape[1], 3), 255, np.uint8), row], axis=0))
        draw = ImageDraw.Draw(img)
        draw.text((4, 3), labels[0], fill=(0, 0, 0))
        draw.text((a.shape[1] + 8, 3), labels[1], fill=(0, 0, 0))
        frames.append(np.asarray(img))
    return np.stack(frames)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("left", type=Path)
    p.add_argument("right", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--labels", nargs=2, default=("left", "right"))
    p.add_argument("--zoom", type=int, default=2)
    p.add_argument("--ms", type=float, default=80.0, help="milliseconds per frame")
    args = p.parse_args()
    frames = side_by_side(args.left, args.right, tuple(args.labels), args.zoom)
    iio.imwrite(args.out, frames, extension=".gif", duration=args.ms, loop=0)
    print(f"{len(frames)} frames -> {args.out}")


if __name__ == "__main__":
    main()
