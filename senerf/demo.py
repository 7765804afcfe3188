"""The embedded default job: ``senerf-fit --demo`` (DESIGN.md, "Commands"): the procedural scene of
:func:`senerf.procedural.make_demo_scene` (exact ground truth, no data needed), fitted with the ``fast`` preset;
prints the teacher's and the SE-NeRF iteration's test PSNRs.  The scene is built in a temporary folder and renamed
into place, so an interrupted build leaves nothing half-written; the same command again reuses it and resumes the
fit.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from senerf.errors import InputError

__all__ = ["DEMO_PRESET", "DEMO_OPTIONS", "ensure_demo_scene", "run_demo"]

DEMO_PRESET = "fast"
#: ``senerf-fit`` options the demo uses; any other one given with ``--demo`` is refused, not ignored.
DEMO_OPTIONS = ("--demo", "--out", "--seed", "--device", "--threads", "--quiet", "--overwrite", "--steps",
                "--batch-rays")


def ensure_demo_scene(scene_dir: Path) -> Path:
    """Write the demo scene to ``scene_dir`` unless it is already there (its ``procedural.json`` marks it)."""
    from senerf.procedural import make_demo_scene

    if (scene_dir / "procedural.json").is_file():
        return scene_dir
    if scene_dir.exists() or scene_dir.is_symlink():
        raise InputError("holds something senerf-fit --demo did not write; choose another --out", file=scene_dir)
    scene_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".scene-", dir=scene_dir.parent))
    try:
        make_demo_scene(tmp / "scene", seed=0)
        (tmp / "scene").rename(scene_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return scene_dir


def run_demo(args, argv: list[str]) -> int:
    """Run the demo for parsed ``senerf-fit`` arguments ``args`` (parsed from ``argv``)."""
    from senerf.cliargs import check_device
    from senerf.pipeline import fit
    from senerf.procedural import DEMO_FEWSHOT_VIEWS

    other = [a.split("=")[0] for a in argv if a.startswith("-") and a.split("=")[0] not in DEMO_OPTIONS]
    if other or args.scene:
        flag = other[0] if other else "SCENE_DIR"
        raise InputError(f"--demo chooses its own scene, views, preset and iterations; drop {flag} or fit a scene "
                         "folder without --demo", field=flag)
    check_device(args.device)   # before the scene is written
    out = Path(args.out) if args.out is not None else Path("runs") / "demo"
    scene_dir = ensure_demo_scene(out / "demo_scene")
    print(f"senerf-fit --demo: procedural scene in {scene_dir}; fitting views {list(DEMO_FEWSHOT_VIEWS)} with the "
          f"'{DEMO_PRESET}' preset")
    train = {k: v for k, v in (("steps", args.steps), ("batch_rays", args.batch_rays)) if v is not None}
    result = fit(scene_dir, out / "fit", views=list(DEMO_FEWSHOT_VIEWS), preset=DEMO_PRESET, seed=args.seed,
                 device=args.device, train=train, overwrite=args.overwrite, progress=not args.quiet,
                 command=["senerf-fit", *argv])
    rows = result.metrics["iterations"]
    base, final = rows[0], rows[-1]
    print(f"senerf-fit --demo: baseline (iteration 0) test PSNR {base['psnr']:.2f} dB; SE-NeRF (iteration "
          f"{final['iteration']}) test PSNR {final['psnr']:.2f} dB ({final['psnr'] - base['psnr']:+.2f} dB); "
          f"{result.metrics['seconds_total']:.0f} s")
    print(f"senerf-fit --demo: outputs in {result.out.resolve()} (summary.png, metrics.json, iter_*/test renders, "
          "iter_*/pseudo reliability masks)")
    return 0
