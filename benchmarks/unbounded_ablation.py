"""The unbounded-scene settings, one at a time, on a dense fit of a real capture (the teacher alone).

Trains on every view but every 8th (``llff`` protocol, all non-held-out views), scores the held-out ones, and
prints one line per variant: the mean test PSNR, per view, and the seconds of training; for a scene exported with
its exact depths (``depth/<image name>.npy``, as ``senerf.procedural.export_room_scene`` writes), also the median
relative error of the rendered z-depth.  A variant is a
``ModelConfig`` override dict and a ``TrainConfig`` override dict, on top of the settings ``senerf-fit`` would
choose for the scene (``choose_model``, and plane TV off as for every unbounded scene).

    python benchmarks/unbounded_ablation.py ../shared/data/dtu/scan24 --downscale 2 --steps 600 --batch-rays 2048 \\
        "{}" "{'near': 0.1363}" "{'aabb': ((-2.7, -2.7, -2.7), (2.7, 2.7, 2.7)), 'resolution': 256}" "{}, {'tv_weight': 0.1}"
"""

from __future__ import annotations

import argparse
import ast
import time
from pathlib import Path

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene")
    p.add_argument("variants", nargs="+", help="'{model overrides}' or '{model overrides}, {train overrides}'")
    p.add_argument("--downscale", type=float, default=1.0)
    p.add_argument("--steps", type=int, default=600)
    p.add_argument("--batch-rays", type=int, default=2048)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-seen-mask", action="store_true",
                   help="let the occupancy grid keep the cells no training ray crosses (the ablation of mark_seen)")
    args = p.parse_args()

    import torch

    from senerf.config import TrainConfig
    from senerf.data import fewshot_split, load_scene
    from senerf.pipeline import UNBOUNDED_TV_WEIGHT
    from senerf.train import build_field, choose_model, render_views
    from senerf.train.loop import train_field
    from senerf.train.rays import RayBatchSource

    torch.set_num_threads(2)
    if args.no_seen_mask:
        from senerf.fields import OccupancyGrid

        OccupancyGrid.mark_seen = lambda self, *a, **k: 1.0
    scene = load_scene(args.scene, downscale=args.downscale)
    train_idx, test_idx = fewshot_split(scene, "llff", n_views=scene.n_images - (scene.n_images + 7) // 8)
    print(f"{scene.name} ({scene.kind}), {len(train_idx)} training views, test views {test_idx.tolist()}")
    for text in args.variants:
        value = ast.literal_eval(text)
        model_over, train_over = value if isinstance(value, tuple) else (value, {})
        model = choose_model(scene, train_idx, model_over, echo=lambda line: None)
        tv = UNBOUNDED_TV_WEIGHT if scene.kind == "unbounded" else TrainConfig().tv_weight
        cfg = TrainConfig(**{"steps": args.steps, "batch_rays": args.batch_rays, "checkpoint_every": 0,
                             "seed": args.seed, "tv_weight": tv, **train_over})
        field = build_field(model, args.seed, args.steps)
        start = time.perf_counter()
        result = train_field(field, RayBatchSource.from_scene(scene, train_idx, model), cfg, progress=False,
                             log_every=args.steps)
        seconds = time.perf_counter() - start
        psnr, depth_err = [], []
        for v in test_idx:
            out = render_views(result.field, model, scene.intrinsics_all[v], scene.c2w[v:v + 1],
                               occupancy=result.occupancy)
            psnr.append(-10 * np.log10(np.mean((out["rgb"][0] - scene.rgb[v]) ** 2)))
            exact = scene.root / "depth" / (Path(scene.image_paths[v]).stem + ".npy")
            if exact.is_file():
                z = np.load(exact)
                depth_err.append(np.abs(out["z_depth"][0] - z) / z)
        depth = f", depth error median {100 * np.median(depth_err):.2f} %" if depth_err else ""
        print(f"{text}: test PSNR {np.mean(psnr):.2f} dB (per view {' '.join(f'{x:.1f}' for x in psnr)}){depth}, "
              f"{seconds:.0f} s training", flush=True)


if __name__ == "__main__":
    main()
