"""The embedded default job: ``senerf-fit --demo``.

Builds the small procedural scene of :func:`senerf.procedural.make_demo_scene` (exact ground truth, no
data needed), fits it from 3 views on one side with the ``fast`` preset (baseline teacher, then SE-NeRF
self-training), and prints both test PSNRs and where the outputs are.

The scene is written once to ``OUT/demo_scene`` (built in a temporary folder beside it, then renamed, so an
interrupted build leaves nothing half-written); rerunning the same command reuses it and resumes the
fit.  ``OUT`` defaults to ``runs/demo``.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

from senerf.atomic import output_folder
from senerf.errors import InputError

__all__ = ["DEMO_PRESET", "DEMO_OPTIONS", "demo_iterations", "ensure_demo_scene", "refuse_ignored_options", "run_demo"]

DEMO_PRESET = "fast"
#: ``senerf-fit`` options the demo uses; any other one given with ``--demo`` is refused, not ignored.
DEMO_OPTIONS = frozenset({"demo", "out", "seed", "device", "threads", "quiet", "overwrite", "steps", "batch_rays"})
#: What the demo writes into its folder.
_DEMO_ENTRIES = frozenset({"demo_scene", "fit"})


def demo_iterations() -> int:
    """Self-training iterations of the demo: those of the ``fast`` preset."""
    from senerf.train import PRESETS

    return int(PRESETS[DEMO_PRESET]["iterations"])


def ensure_demo_scene(scene_dir: Path, seed: int = 0) -> Path:
    """Write the demo scene to ``scene_dir`` unless a finished one with this seed is already there."""
    from senerf.procedural import make_demo_scene

    marker = scene_dir / "procedural.json"
    if marker.is_file():
        try:
            meta = json.loads(marker.read_text())
        except (OSError, ValueError):
            meta = None  # damaged: rebuilt below
        if isinstance(meta, dict) and meta.get("camera_seed") == seed:  # JSON but no object: damaged too
            return scene_dir
        shutil.rmtree(scene_dir)
    scene_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".scene-", dir=scene_dir.parent))
    try:
        make_demo_scene(tmp / "scene", seed=seed)
        (tmp / "scene").rename(scene_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return scene_dir


def refuse_ignored_options(args, argv: list[str] | None = None) -> None:
    """:class:`InputError` naming the first option given with ``--demo`` that the demo does not use (the
    demo chooses its scene, views, preset and iterations).

    With ``argv`` (the command's arguments) every option given counts, also one given at its default value
    (``--preset balanced``); without it, only values that differ from the defaults can be seen.
    """
    import argparse

    from senerf.cli import build_parser

    parser = build_parser()
    defaults = vars(parser.parse_args([]))
    if argv is not None:  # parse again with no defaults: what is in the namespace was given
        for action in parser._actions:  # argparse's set_defaults would also store the marker as a value
            action.default = argparse.SUPPRESS
        args = parser.parse_args(argv)
    for name, value in vars(args).items():
        if name not in DEMO_OPTIONS and (argv is not None or value != defaults.get(name)):
            flag = "SCENE_DIR" if name == "scene" else "--" + name.replace("_", "-")
            raise InputError(f"--demo chooses its own scene, views, preset and iterations; drop {flag} or fit a "
                             "scene folder without --demo", field=flag)


def _check_demo_folder(out: Path, overwrite: bool) -> None:
    """Refuse an ``out`` holding other things than the demo's (unless ``overwrite``: the demo then goes
    beside them), and always one whose ``demo_scene`` the demo did not write."""
    if not out.is_dir():
        return
    names = {p.name for p in out.iterdir() if not p.name.startswith(".")}  # .scene-* temporaries, .DS_Store
    scene = out / "demo_scene"
    if scene.exists() and not (scene / "procedural.json").is_file():
        raise InputError("holds a demo_scene that senerf-fit --demo did not write; choose another --out", file=out)
    other = sorted(names - _DEMO_ENTRIES)
    if other and not overwrite:
        raise InputError(f"exists and is not a senerf-fit --demo output folder (it holds {other[0]}); use "
                         "--overwrite to put the demo beside, or another --out", file=out)


def _check_fit_seed(out: Path, seed: int, overwrite: bool) -> None:
    """Refuse (unless ``overwrite``) a folder whose demo was fitted with another seed: the demo's scene is drawn
    from the seed, so redrawing it would change the photos under the earlier fit before senerf-fit refused the run
    (its run.json would then see scene files differ, and senerf-render would render it against the new ones)."""
    marker, run_file = out / "demo_scene" / "procedural.json", out / "fit" / "run.json"
    if overwrite or not (marker.is_file() and run_file.is_file()):
        return
    try:
        drawn = json.loads(marker.read_text()).get("camera_seed")
    except (OSError, ValueError, AttributeError):
        return   # a damaged marker: the scene is rebuilt and senerf-fit compares the run
    if drawn is not None and drawn != seed:
        raise InputError(f"holds a different run (train.seed: {drawn} in the folder, {seed} now; the demo's scene is "
                         f"drawn from the seed too); use --overwrite or another --out", file=out / "fit")


def run_demo(args, argv: list[str] | None = None) -> int:
    """Run the demo for parsed ``senerf-fit`` arguments (``argv``: the arguments they were parsed from).

    Uses ``--out``, ``--seed``, ``--device``, ``--threads``, ``--quiet``, ``--overwrite``, and ``--steps`` /
    ``--batch-rays`` when given (they override the preset); everything else is the demo's own.
    """
    from senerf.cli import main
    from senerf.procedural import DEMO_FEWSHOT_VIEWS

    refuse_ignored_options(args, argv)
    out = output_folder(args.out if args.out is not None else Path("runs") / "demo", "--out")
    _check_demo_folder(out, args.overwrite)
    _check_fit_seed(out, args.seed, args.overwrite)   # before the scene is redrawn for another seed
    scene_dir = ensure_demo_scene(out / "demo_scene", seed=args.seed)
    fit_out = out / "fit"
    argv = [str(scene_dir), "--views", ",".join(map(str, DEMO_FEWSHOT_VIEWS)), "--preset", DEMO_PRESET,
            "--iterations", str(demo_iterations()), "--seed", str(args.seed), "--device", args.device,
            "--out", str(fit_out)]
    for flag, value in (("--steps", args.steps), ("--batch-rays", args.batch_rays), ("--threads", args.threads)):
        if value is not None:  # overrides of the preset (e.g. a quick smoke run), and the thread count
            argv += [flag, str(value)]
    if args.overwrite:
        argv.append("--overwrite")
    if args.quiet:
        argv.append("--quiet")
    print(f"senerf-fit --demo: procedural scene in {scene_dir}; fitting views {list(DEMO_FEWSHOT_VIEWS)} "
          f"with the '{DEMO_PRESET}' preset")
    status = main(argv)
    if status != 0:
        return status
    metrics = json.loads((fit_out / "metrics.json").read_text())
    iters = metrics["iterations"]
    base, final = iters[0], iters[-1]
    print(f"senerf-fit --demo: baseline (iteration 0) test PSNR {base['psnr']:.2f} dB; "
          f"SE-NeRF (iteration {final['iteration']}) test PSNR {final['psnr']:.2f} dB "
          f"({final['psnr'] - base['psnr']:+.2f} dB); {metrics['seconds_total']:.0f} s")
    print(f"senerf-fit --demo: outputs in {fit_out.resolve()} (summary.png, metrics.json, iter_*/test renders, "
          f"iter_*/pseudo reliability masks)")
    sys.stdout.flush()
    return 0
