"""Self-training benchmarks on lego Extreme (views 0, 1, 51 of the train split) at 100 x 100.

``masks``: train a short baseline teacher, use held-out train-split poses (the ``--n-eval`` nearest in angle
to the known views) as pseudo views with ground truth, and report precision / recall / false-positive rate
of our reliable masks against masks from ground-truth colour (``mean |C_T - C_gt| < --max-error``), per
VGG-19 variant (layers normalised or plainly concatenated) and threshold kind (paper: precision 98.03 %, recall
92.25 %).

``e2e``: the whole self-training run (``--iterations``, default 3) and a baseline given the run's whole
wall-clock budget (``steps x run seconds / iteration-0 seconds`` steps); reports test PSNR per iteration,
gains and wall time
(target: final >= iteration 0 + 1.5 dB and >= long baseline + 1.0 dB, whole run <= 15 min on 2 cores).

``labelling``: the cost of labelling pseudo views, per phase (teacher render, features, similarity), on
``--n-pseudo`` pseudo views of iteration 1 from a ``--steps`` teacher, each fast path against its peer measured
in the same run on the same views: ``view_similarity(foreground_only=True)`` (what the labelling calls) against
scoring every pixel, and ``bilinear_sample`` against ``bilinear_sample_reference`` on the same lookups; both
pairs must agree exactly on what the labels use (checked, and printed).

``similarity``: the feature lookup of the reliability alone on synthetic fern-sized inputs (no data, no teacher):
known-view features ``--height x --width x --channels`` (378 x 504 x 960, 730 MB), ``--pixels`` pseudo pixels
warped by a nearby view's shift (coherent reads, as a real warp's), the compiled
``ckernel.fused_feature_similarity`` (on all threads, and on one) against the NumPy lookup it replaces
(``reliability._lookup_similarity_numpy``), best of ``--repeats``; their largest difference is printed (and must
stay below 1e-5).

Usage::

    python benchmarks/bench_selftrain.py masks --steps 600 --out /tmp/bench_st_masks
    python benchmarks/bench_selftrain.py e2e --steps 600 --iterations 3 --out /tmp/bench_st_e2e
    python benchmarks/bench_selftrain.py labelling --downscale 1 --steps 300 --n-pseudo 2 --out /tmp/bench_st_label
    python benchmarks/bench_selftrain.py similarity --pixels 190000 --out /tmp/bench_st_similarity

Results are printed and written to ``OUT/bench_<mode>.json`` (``masks`` also writes the markdown table
``OUT/bench_masks.md`` and ``OUT/mask_quality.png``).  ``masks-table --json FILE`` prints the table of an earlier
``masks`` result, e.g. ``python benchmarks/bench_selftrain.py masks-table --json benchmarks/results/mask-quality.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("SENERF_DATA", REPO.parent / "shared" / "data"))


def fewshot_test_views(scene) -> np.ndarray:
    """The Extreme protocol's test views (never used as pseudo views)."""
    from senerf.data import fewshot_split

    return fewshot_split(scene, "extreme")[1]


def _load(args):
    from senerf.data import fewshot_split, load_scene
    from senerf.config import PRESETS
    from senerf.train import choose_model

    scene = load_scene(DATA / "nerf_synthetic" / "lego", downscale=args.downscale)
    train_idx, test_idx = fewshot_split(scene, "extreme")
    test_idx = test_idx[:: args.test_stride]
    model = choose_model(scene, train_idx)
    over = {} if args.batch_rays is None else {"batch_rays": args.batch_rays}
    tcfg = PRESETS[args.preset].train_config(steps=args.steps, seed=args.seed, **over)
    return scene, train_idx, test_idx, model, tcfg


def _nearest_held_out(scene, train_idx, test_idx, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``n`` held-out views (neither known nor test) nearest in angle to a known view, and their angles
    (degrees): :func:`senerf.selftrain.dataset_pseudo_views`."""
    from senerf import geometry
    from senerf.selftrain import dataset_pseudo_views

    idx = dataset_pseudo_views(scene, train_idx, test_idx, 180.0, n)
    c2w = np.asarray(scene.c2w, dtype=np.float64)
    return idx, geometry.nearest_view_angles(c2w[train_idx], c2w[idx], center=None)


def bench_masks(args) -> dict:
    from senerf.config import SelfTrainConfig
    from senerf.selftrain import VGG19Features, reliability_mask_quality
    from senerf.selftrain import known_images
    from senerf.train import RayBatchSource, build_field, evaluate, render_views, train_field

    scene, train_idx, test_idx, model, tcfg = _load(args)
    out = Path(args.out)
    t0 = time.perf_counter()
    rays = RayBatchSource.from_scene(scene, train_idx, model, tcfg.device)
    res = train_field(build_field(model, seed=tcfg.seed, steps=tcfg.steps), rays, tcfg,
                      checkpoint=out / "teacher_train.pt", progress=False)
    teacher, occ = res.field, res.occupancy
    t_train = time.perf_counter() - t0
    ev = evaluate(teacher, scene, test_idx, None, model, occupancy=occ, progress=False)
    eval_idx, angles = _nearest_held_out(scene, train_idx, fewshot_test_views(scene), args.n_eval)
    t_r = time.perf_counter()
    per_view = scene.intrinsics_all
    renders = (render_views(teacher, model, [per_view[i] for i in train_idx], scene.c2w[train_idx], occupancy=occ),
               render_views(teacher, model, [per_view[i] for i in eval_idx], scene.c2w[eval_idx], occupancy=occ))
    t_render = time.perf_counter() - t_r
    print(f"teacher: {tcfg.steps} steps in {t_train:.0f} s, test PSNR {ev['psnr']:.2f} dB on {len(test_idx)} views; "
          f"{len(eval_idx)} held-out poses {angles.min():.1f} - {angles.max():.1f} deg from the nearest input, "
          f"rendered in {t_render:.0f} s")
    rows = []
    for normalize in (True, False):
        ext = VGG19Features(normalize_layers=normalize)
        label = "vgg19-norm" if normalize else "vgg19-concat"
        feats = ext(known_images(scene, train_idx, model))
        for kind in ("adaptive", "fixed", "unified"):
            cfg = SelfTrainConfig(threshold=kind, normalize_layers=normalize)
            t1 = time.perf_counter()
            q, labels = reliability_mask_quality(teacher, occ, model, scene, train_idx, eval_idx, ext, cfg,
                                                 cfg.alpha(1), max_error=args.max_error, known_features=feats,
                                                 renders=renders)
            row = dict(features=label, threshold=kind, tau=labels.tau, seconds=time.perf_counter() - t1,
                       **{k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in q.items()})
            rows.append(row)
            print(f"{label:13s} {kind:9s} tau={'soft' if labels.tau is None else f'{labels.tau:.3f}':>6s} "
                  f"precision {100 * q['precision']:.2f} % recall {100 * q['recall']:.2f} % "
                  f"FPR {100 * q['fpr']:.2f} %  predicted-reliable {100 * q['predicted_reliable_rate']:.1f} % "
                  f"(GT-reliable rate {100 * q['gt_reliable_rate']:.1f} %)")
    png = plot_mask_quality(rows, out / "mask_quality.png",
                            f"lego Extreme @100: reliable masks vs ground-truth colour masks "
                            f"({len(eval_idx)} held-out poses, teacher {ev['psnr']:.1f} dB)")
    print(f"wrote {png}")
    return dict(mode="masks", steps=tcfg.steps, batch_rays=tcfg.batch_rays, teacher_psnr=ev["psnr"],
                teacher_seconds=t_train,
                eval_views=[int(i) for i in eval_idx], eval_angles_deg=[float(a) for a in angles],
                max_error=args.max_error, rows=rows)


def plot_mask_quality(rows: list[dict], path: Path, title: str) -> Path:
    """Grouped bars of precision, recall and false-positive rate per (VGG-19 variant, threshold) row."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    x = np.arange(len(rows))
    fig = Figure(figsize=(max(5.0, 1.4 * len(rows)), 4.2))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for k, name in enumerate(("precision", "recall", "fpr")):
        ax.bar(x + (k - 1) * 0.27, [r[name] for r in rows], width=0.27, label=name)
    ax.set_xticks(x, [f"{r['features']}\n{r['threshold']}" for r in rows], fontsize=8)
    ax.set_ylim(0, 1)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    return path


def mask_quality_markdown(doc: dict, source: str) -> str:
    """Markdown table of a ``masks`` result (``bench_masks.json``, read from ``source``)."""
    angles = doc["eval_angles_deg"]
    pct = lambda v: f"{100 * v:.2f} %"  # noqa: E731
    machine = doc.get("machine") or {}
    head = [f"### Reliability masks vs ground-truth colour masks ({source})", "",
            f"- Made by: `python {' '.join(doc['argv'])}` at commit {doc.get('commit', 'unknown')}, "
            f"{doc.get('timestamp', 'time unknown')[:16]}, {machine.get('cpu', '?')}, "
            f"torch {machine.get('torch', '?')}",
            f"- Teacher: {doc['steps']} steps x {doc['batch_rays']} rays, {doc['teacher_psnr']:.2f} dB on the test "
            f"views; {len(angles)} held-out dataset poses {min(angles):.1f}-{max(angles):.1f} degrees from an input "
            f"view as pseudo views; ground truth: teacher colour within {doc['max_error']:g} (mean |dRGB|) of the "
            "photo.",
            "- Paper (800x800, its own teacher): precision 98.03 %, recall 92.25 %.", "",
            "| features | threshold | tau | precision | recall | false-positive rate | predicted reliable | "
            "ground-truth reliable |", "|" + "---|" * 8]
    return "\n".join(head + [
        f"| {r['features']} | {r['threshold']} | {'soft' if r.get('tau') is None else format(r['tau'], '.3f')} | "
        f"{pct(r['precision'])} | {pct(r['recall'])} | {pct(r['fpr'])} | {pct(r['predicted_reliable_rate'])} | "
        f"{pct(r['gt_reliable_rate'])} |" for r in doc["rows"]]) + "\n"


def bench_e2e(args) -> dict:
    from senerf.config import SelfTrainConfig
    from senerf.selftrain import run_selftraining
    from senerf.train import RayBatchSource, build_field, evaluate, train_field

    scene, train_idx, test_idx, model, tcfg = _load(args)
    out = Path(args.out)
    cfg = SelfTrainConfig(iterations=args.iterations, threshold=args.threshold, n_pseudo_per_input=args.n_pseudo,
                          seed=args.seed, batch_reliable=args.batch_reliable, batch_prior=args.batch_prior)
    t0 = time.perf_counter()
    metrics = run_selftraining(scene, train_idx, test_idx, model, tcfg, cfg, out / "selftrain",
                               command=sys.argv, progress=False)
    t_run = time.perf_counter() - t0
    psnrs = [it["psnr"] for it in metrics["iterations"]]
    print("self-training PSNR per iteration:", " ".join(f"{p:.2f}" for p in psnrs), f"({t_run:.0f} s)")
    # the baseline gets the whole run's wall time: steps scaled by (run seconds / iteration-0 seconds)
    t_iter0 = metrics["iterations"][0]["seconds"]
    long_cfg = dataclasses.replace(tcfg, steps=int(round(tcfg.steps * t_run / t_iter0)))
    t1 = time.perf_counter()
    rays = RayBatchSource.from_scene(scene, train_idx, model, tcfg.device)
    res = train_field(build_field(model, seed=tcfg.seed, steps=long_cfg.steps), rays, long_cfg,
                      checkpoint=out / "long_baseline.pt", progress=False)
    ev = evaluate(res.field, scene, test_idx, None, model, occupancy=res.occupancy, progress=False)
    t_long = time.perf_counter() - t1
    print(f"long baseline ({long_cfg.steps} steps): PSNR {ev['psnr']:.2f} ({t_long:.0f} s)")
    print(f"final - iteration 0: {psnrs[-1] - psnrs[0]:+.2f} dB; "
          f"final - long baseline: {psnrs[-1] - ev['psnr']:+.2f} dB")
    return dict(mode="e2e", steps=tcfg.steps, batch_rays=tcfg.batch_rays, iterations=args.iterations,
                batch_reliable=args.batch_reliable, batch_prior=args.batch_prior,
                psnr_per_iteration=psnrs,
                reliable_fraction=[it["reliable_fraction"] for it in metrics["iterations"]],
                run_seconds=t_run, long_baseline_steps=long_cfg.steps, long_baseline_psnr=ev["psnr"],
                long_baseline_seconds=t_long, n_test_views=len(test_idx))


def bench_labelling(args) -> dict:
    from senerf.config import SelfTrainConfig
    from senerf.selftrain import VGG19Features
    from senerf.selftrain import reliability as rel
    from senerf.selftrain import known_images, sample_pseudo_cameras
    from senerf.train import RayBatchSource, build_field, render_views, train_field

    scene, train_idx, _, model, tcfg = _load(args)
    rays = RayBatchSource.from_scene(scene, train_idx, model, tcfg.device)
    teacher = train_field(build_field(model, seed=tcfg.seed, steps=tcfg.steps), rays, tcfg, progress=False)
    field, occ = teacher.field.eval(), teacher.occupancy
    cfg = SelfTrainConfig()
    extractor = VGG19Features()
    known_intr = [scene.intrinsics_all[i] for i in train_idx]
    known_c2w = np.asarray(scene.c2w[train_idx], dtype=np.float64)
    t = time.perf_counter()
    known_feats = extractor(known_images(scene, train_idx, model))
    t_known = time.perf_counter() - t
    known = render_views(field, model, known_intr, known_c2w, occupancy=occ)
    known_z = np.where(known["acc"] >= cfg.opacity_threshold, known["z_depth"], np.inf)
    c2w, pseudo_k = sample_pseudo_cameras(scene, train_idx, cfg, 1)
    times = {k: 0.0 for k in ("render", "features", "similarity_all", "similarity_foreground",
                              "bilinear_reference", "bilinear")}
    lookups = 0
    fg_share = []
    for i in range(args.n_pseudo):
        t = time.perf_counter()
        view = render_views(field, model, pseudo_k[i], c2w[i], occupancy=occ)
        times["render"] += time.perf_counter() - t
        t = time.perf_counter()
        feats = extractor(np.clip(view["rgb"], 0.0, 1.0))[0]
        times["features"] += time.perf_counter() - t
        res = {}
        for key, only in (("similarity_all", False), ("similarity_foreground", True)):
            t = time.perf_counter()
            res[key] = rel.view_similarity(feats, view["z_depth"][0], view["acc"][0], pseudo_k[i], c2w[i],
                                           known_feats, known_z, known_intr, known_c2w,
                                           opacity_threshold=cfg.opacity_threshold, rel_tol=cfg.occlusion_rel_tol,
                                           foreground_only=only)
            times[key] += time.perf_counter() - t
        fg = res["similarity_all"].foreground
        fg_share.append(float(fg.mean()))
        if not np.array_equal(res["similarity_all"].similarity[fg], res["similarity_foreground"].similarity[fg]):
            raise AssertionError(f"pseudo view {i}: foreground similarities differ")
        uv = np.random.default_rng(i).uniform(0.0, known_feats.shape[2], size=(rel._SAMPLE_CHUNK, 2))
        for key, fn in (("bilinear_reference", rel.bilinear_sample_reference), ("bilinear", rel.bilinear_sample)):
            t = time.perf_counter()
            out = fn(known_feats[0], uv)
            times[key] += time.perf_counter() - t
            res[key] = out
        if not np.array_equal(res["bilinear"], res["bilinear_reference"]):
            raise AssertionError(f"pseudo view {i}: bilinear_sample differs from its reference")
        lookups += uv.shape[0]
    n = args.n_pseudo
    per_view = {k: v / n for k, v in times.items()}
    ratio_sim = times["similarity_foreground"] / times["similarity_all"]
    ratio_bil = times["bilinear"] / times["bilinear_reference"]
    h, w = scene.size
    print(f"lego {w}x{h}, vgg19, teacher {tcfg.steps} steps; {n} pseudo views, foreground "
          f"{100 * np.mean(fg_share):.1f} % of their pixels; known-view features {t_known:.1f} s")
    print("per pseudo view: " + ", ".join(f"{k} {v:.2f} s" for k, v in per_view.items()))
    print(f"view_similarity foreground only / every pixel: {ratio_sim:.3f} (same foreground values)")
    print(f"bilinear_sample / bilinear_sample_reference on {rel._SAMPLE_CHUNK} lookups: {ratio_bil:.3f} (identical)")
    return dict(mode="labelling", size=[h, w], steps=tcfg.steps, n_pseudo=n, features="vgg19",
                foreground_share=float(np.mean(fg_share)), known_features_seconds=t_known,
                seconds_per_view=per_view, ratio_similarity_foreground_vs_all=ratio_sim,
                ratio_bilinear_vs_reference=ratio_bil, bilinear_lookups=lookups)


def bench_similarity(args) -> dict:
    """The ``similarity`` mode (module docstring): the compiled lookup against the NumPy one on the same inputs."""
    from senerf.fields import ckernel
    from senerf.selftrain import reliability as rel

    h, w, c = args.height, args.width, args.channels
    if ckernel.load_kernel(torch.float32) is None:
        raise SystemExit(f"the compiled kernel is {ckernel.kernel_status()}: nothing to time")
    rng = np.random.default_rng(args.seed)
    known = rng.random((h, w, c), dtype=np.float32)    # VGG features are ReLU outputs: >= 0
    pseudo = rng.random((h * w, c), dtype=np.float32)
    idx = np.sort(rng.choice(h * w, size=min(args.pixels, h * w), replace=False))
    row, col = np.divmod(idx, w)
    jitter = 0.2 * rng.standard_normal((idx.size, 2))
    uv = np.stack([col + 0.5 + 6.3, row + 0.5 - 2.7], 1) + jitter
    threads = torch.get_num_threads()

    def best(fn) -> tuple[float, np.ndarray]:
        runs = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            out = fn()
            runs.append(time.perf_counter() - t)
        return min(runs), out

    t_numpy, ref = best(lambda: rel._lookup_similarity_numpy(pseudo, idx, known, uv))
    t_kernel, got = best(lambda: ckernel.fused_feature_similarity(pseudo, idx, known, uv))
    torch.set_num_threads(1)
    try:
        t_kernel1, got1 = best(lambda: ckernel.fused_feature_similarity(pseudo, idx, known, uv))
    finally:
        torch.set_num_threads(threads)
    diff = float(np.abs(got - ref).max())
    if diff > 1e-5 or not np.array_equal(got, got1):
        raise AssertionError(f"the kernel differs from the NumPy lookup by {diff:.2e}, or across thread counts")
    print(f"similarity lookup, known features {h}x{w}x{c} ({known.nbytes / 2**20:.0f} MB), {idx.size} pixels, "
          f"best of {args.repeats}: NumPy {t_numpy:.2f} s, kernel {t_kernel:.3f} s on {threads} threads "
          f"({t_numpy / t_kernel:.1f}x), {t_kernel1:.3f} s on 1 ({t_numpy / t_kernel1:.1f}x); "
          f"max |kernel - NumPy| {diff:.1e}")
    return {"mode": "similarity", "size": [h, w], "channels": c, "pixels": int(idx.size), "repeats": args.repeats,
            "numpy_seconds": t_numpy, "kernel_seconds": t_kernel, "kernel_seconds_1_thread": t_kernel1,
            "speedup": t_numpy / t_kernel, "speedup_1_thread": t_numpy / t_kernel1, "max_abs_difference": diff}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mode", choices=("masks", "e2e", "labelling", "similarity", "masks-table"))
    p.add_argument("--out", default="/tmp/bench_selftrain")
    p.add_argument("--steps", type=int, default=600)
    p.add_argument("--preset", default="fast")
    p.add_argument("--batch-rays", type=int, default=None, help="override the preset's rays per step")
    p.add_argument("--downscale", type=float, default=4.0, help="400 px files / 4 = 100 x 100")
    p.add_argument("--test-stride", type=int, default=8, help="evaluate every k-th test view")
    p.add_argument("--n-eval", type=int, default=12, help="masks: held-out poses used as pseudo views")
    p.add_argument("--max-error", type=float, default=0.1, help="masks: GT-reliable if mean |dRGB| below")
    p.add_argument("--iterations", type=int, default=3)
    p.add_argument("--n-pseudo", type=int, default=8,
                   help="e2e: pseudo views per input view; labelling: pseudo views timed")
    p.add_argument("--batch-reliable", type=int, default=512, help="e2e: reliable pseudo rays per step")
    p.add_argument("--batch-prior", type=int, default=128, help="e2e: prior pseudo rays per step")
    p.add_argument("--threshold", default="adaptive")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="masks-table: the bench_masks.json to tabulate")
    p.add_argument("--height", type=int, default=378, help="similarity: known features' rows (fern at 504x378)")
    p.add_argument("--width", type=int, default=504, help="similarity: known features' columns")
    p.add_argument("--channels", type=int, default=960, help="similarity: feature channels (VGG-19's 960)")
    p.add_argument("--pixels", type=int, default=190000, help="similarity: pseudo pixels looked up")
    p.add_argument("--repeats", type=int, default=1, help="similarity: timed runs (the best is kept)")
    args = p.parse_args(argv)
    if args.mode == "masks-table":
        print(mask_quality_markdown(json.loads(Path(args.json).read_text()), args.json), end="")
        return 0
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    Path(args.out).mkdir(parents=True, exist_ok=True)
    result = dict(masks=bench_masks, e2e=bench_e2e, labelling=bench_labelling,
                  similarity=bench_similarity)[args.mode](args)
    from datetime import datetime, timezone

    from senerf.bench.runner import git_commit
    from senerf.memory import cpu_model

    machine = dict(cpu=cpu_model(), threads=torch.get_num_threads(), torch=str(torch.__version__), device="cpu")
    result.update(argv=sys.argv, commit=git_commit(), machine=machine,
                  timestamp=datetime.now(timezone.utc).isoformat(timespec="seconds"))
    (Path(args.out) / f"bench_{args.mode}.json").write_text(json.dumps(result, indent=1))
    if args.mode == "masks":
        table = mask_quality_markdown(result, str(Path(args.out) / "bench_masks.json"))
        (Path(args.out) / "bench_masks.md").write_text(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
