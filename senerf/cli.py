"""``senerf-fit``: fit a scene folder with SE-NeRF (:func:`senerf.fit`) and write its run folder.

The exit statuses are :func:`senerf.cliargs.run_command`'s; the flags' defaults are the configurations' own
(:mod:`senerf.config`).
"""

from __future__ import annotations

import shlex
from pathlib import Path

from senerf import __version__
from senerf.cliargs import (SEED_MAX, THREADS_HELP, OneLineParser, argument_type, command_main, console_entry,
                            float_flag, int_flag, set_threads, threads_flag)
from senerf.config import PRESETS, SelfTrainConfig
from senerf.errors import InputError

__all__ = ["main", "console", "build_parser", "parse_views"]

PROG = "senerf-fit"
_PROTOCOLS = ("extreme", "spread", "llff", "dtu", "all", "infonerf4", "random8")


def parse_views(text: str) -> list[int]:
    """``"0,1,51"`` -> ``[0, 1, 51]``; :class:`InputError` naming ``--views`` otherwise."""
    try:
        return [int(t) for t in str(text).split(",")]
    except ValueError:
        raise InputError(f"expected comma-separated integers like 0,1,51, got {text!r}", field="--views") from None


def build_parser() -> OneLineParser:
    """The ``senerf-fit`` argument parser (errors raise :class:`InputError`)."""
    st = SelfTrainConfig
    p = OneLineParser(prog=PROG, description="Few-shot NeRF with SE-NeRF self-training (K-Planes teacher/student).",
                      epilog="Writes into --out: summary.png, metrics.json, iter_K/test/ (test-view renders, K = 0 the "
                             "teacher), iter_K/pseudo/ (pseudo views, similarity maps, reliability masks), run.json "
                             "and checkpoints/. Run the same command again to resume. Exit status: 0 done, 2 bad "
                             "input, 130 interrupted, 1 internal error.")
    p.add_argument("scene", nargs="?", help="scene folder (NeRF Synthetic / instant-ngp / nerfstudio / LLFF / COLMAP)")
    g = p.add_argument_group("views")
    g.add_argument("--views", type=argument_type(parse_views),
                   help="training view indices, e.g. 0,1,51 (into the train split of a scene that has one)")
    g.add_argument("--n-views", type=int_flag("--n-views"),
                   help="number of training views (llff, dtu, spread, random8)")
    g.add_argument("--protocol", choices=_PROTOCOLS,
                   help="few-shot protocol (default: extreme for the NeRF Synthetic scenes; spread for other scenes "
                        "with a test split: 3 views spread over the train split; else llff: every 8th image tests; "
                        "dtu: DTU's few-shot views 25, 22, 28, ... and its 25 test views)")
    g.add_argument("--test-views", type=int_flag("--test-views"), metavar="N",
                   help="score on N of the test views, spread evenly (default: all, as published tables)")
    g.add_argument("--scene-kind", choices=("unbounded", "object", "forward-facing"),
                   help="fit as an unbounded scene (RGB photos with background), an object in a box (photos with "
                        "alpha) or a forward-facing (NDC) capture (LLFF, COLMAP); default: from the photos and "
                        "cameras")
    g.add_argument("--downscale", type=float_flag("--downscale", 1.0),
                   help="image downscale factor (default 1; LLFF: 8, relative to full resolution)")
    t = p.add_argument_group("training")
    t.add_argument("--preset", choices=tuple(PRESETS), default="balanced",
                   help="; ".join(f"{name}: {pr.steps} steps x {pr.batch_rays} rays, {pr.iterations} iteration(s)"
                                  for name, pr in PRESETS.items()) + " (default: %(default)s; BENCHMARKS.md)")
    t.add_argument("--steps", type=int_flag("--steps"), help="training steps per iteration (overrides the preset)")
    t.add_argument("--batch-rays", type=int_flag("--batch-rays"), help="rays per step (overrides the preset)")
    t.add_argument("--iterations", type=int_flag("--iterations", allow_zero=True),
                   help="self-training iterations after the teacher (0: the baseline only; default: the preset's)")
    t.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    t.add_argument("--threads", type=threads_flag(), metavar="N", help=THREADS_HELP)
    t.add_argument("--seed", type=int_flag("--seed", allow_zero=True, maximum=SEED_MAX), default=0)
    m = p.add_argument_group("model overrides (default: chosen from the scene and printed)")
    m.add_argument("--field", choices=("kplanes", "nerf"), help="kplanes, or nerf (an MLP with frequency annealing)")
    m.add_argument("--resolution", type=int_flag("--resolution", minimum=2), help="base plane resolution (K-Planes)")
    m.add_argument("--samples", type=int_flag("--samples"), help="samples per ray")
    m.add_argument("--hidden", type=int_flag("--hidden"), help="width of the K-Planes MLPs")
    m.add_argument("--aabb", type=float_flag("--aabb", positive=True),
                   help="half size of a cube around the world origin to fit in (object scenes)")
    m.add_argument("--background", choices=("random", "white", "black"), help="training background")
    m.add_argument("--no-view-dependence", action="store_true", help="colour ignores the view direction")
    m.add_argument("--no-occupancy", action="store_true", help="no occupancy grid")
    s = p.add_argument_group("self-training")
    s.add_argument("--threshold", choices=("adaptive", "fixed", "unified"), default=st.threshold)
    s.add_argument("--no-density-distill", action="store_true")
    s.add_argument("--no-prior", action="store_true")
    s.add_argument("--empty-opacity", type=float_flag("--empty-opacity", 0.0, maximum=st.opacity_threshold),
                   default=st.empty_opacity, help="pseudo pixels the teacher renders with opacity below this are "
                                                  "distilled as empty space (0: off; default %(default)g)")
    s.add_argument("--pseudo-range", type=float_flag("--pseudo-range", 0.0), default=st.pseudo_range_deg,
                   metavar="DEG", help="the first iteration's pseudo-view range around each input "
                                       "(default %(default)g)")
    s.add_argument("--pseudo-range-step", type=float_flag("--pseudo-range-step", 0.0), metavar="DEG",
                   default=st.pseudo_range_step_deg, help="its widening per later iteration (default %(default)g)")
    s.add_argument("--pseudo-views", type=int_flag("--pseudo-views"), default=st.n_pseudo_per_input, metavar="N",
                   help="pseudo views per input view and iteration (default %(default)d)")
    o = p.add_argument_group("output")
    o.add_argument("--out", type=Path, help="output folder (default runs/<scene>-<protocol>)")
    o.add_argument("--overwrite", action="store_true", help="replace a different run in --out")
    o.add_argument("--demo", action="store_true", help="build a small procedural scene and fit it")
    o.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return p


def _model_overrides(args) -> dict:
    pairs = (("field", args.field), ("resolution", args.resolution), ("n_samples", args.samples),
             ("hidden", args.hidden), ("train_background", args.background),
             ("aabb", None if args.aabb is None else ((-args.aabb,) * 3, (args.aabb,) * 3)),
             ("view_dependent", False if args.no_view_dependence else None),
             ("occupancy_resolution", 0 if args.no_occupancy else None))
    return {k: v for k, v in pairs if v is not None}


def _selftrain_settings(args) -> dict:
    return dict(threshold=args.threshold, density_distill=not args.no_density_distill, prior=not args.no_prior,
                empty_opacity=args.empty_opacity, pseudo_range_deg=args.pseudo_range,
                pseudo_range_step_deg=args.pseudo_range_step, n_pseudo_per_input=args.pseudo_views)


def _run(args, argv: list[str]) -> int:
    set_threads(args.threads)
    if args.demo:
        from senerf.demo import run_demo

        return run_demo(args, argv)
    if not args.scene:
        raise InputError("a SCENE_DIR is required (or --demo)", field="SCENE_DIR")
    from senerf.pipeline import fit

    train = {k: v for k, v in (("steps", args.steps), ("batch_rays", args.batch_rays)) if v is not None}
    result = fit(args.scene, args.out, protocol=args.protocol, views=args.views, n_views=args.n_views,
                 test_views=args.test_views, downscale=args.downscale,
                 scene_kind=None if args.scene_kind is None else args.scene_kind.replace("-", "_"),
                 preset=args.preset, iterations=args.iterations, seed=args.seed, device=args.device, train=train,
                 model=_model_overrides(args), selftrain=_selftrain_settings(args), overwrite=args.overwrite,
                 progress=not args.quiet, command=[PROG, *argv])
    for it in result.metrics["iterations"]:
        print(f"{PROG}: iteration {it['iteration']}: PSNR {it['psnr']:.2f} dB, SSIM {it['ssim']:.3f}, "
              f"LPIPS {it['lpips']}, {it['seconds']:.0f} s")
    print(f"{PROG}: metrics in {result.out / 'metrics.json'}")
    print(f"{PROG}: to fly around the fitted scene: senerf-render {shlex.quote(str(result.out))}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``senerf-fit``; returns the exit status (0 ok, 2 bad input, 130 interrupted, 1 internal)."""
    return command_main(PROG, lambda a: _run(build_parser().parse_args(a), a), argv, "rerun the same command to resume")


def console() -> None:
    """The ``senerf-fit`` console script."""
    console_entry(main)


if __name__ == "__main__":  # pragma: no cover
    console()
