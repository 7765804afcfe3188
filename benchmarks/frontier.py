"""Frontier run: lego, NeRF Synthetic Extreme (3 views) at 100x100, every preset, baseline and SE-NeRF.

Fits through the harness (:mod:`senerf.bench`), one ``senerf-fit`` process per run, resumable: rerunning
skips finished runs.  Writes ``OUT/results.jsonl``, ``OUT/frontier.md`` (tables with mean ± std over seeds,
the paper's numbers, commit, machine and the command) and ``OUT/frontier.png`` (PSNR vs seconds and vs peak memory).

    python benchmarks/frontier.py --dry-run                   # list the fits
    python benchmarks/frontier.py --seeds 0 1 2 --out benchmarks/out/frontier

Runs default to one at a time (``--workers 1``) so each fit has every core and its seconds are comparable.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from senerf.bench.plots import plot_frontier
from senerf.bench.report import make_report
from senerf.bench.results import load_results
from senerf.bench.runner import RunnerConfig, dry_run_lines, make_executor, run_benchmark
from senerf.bench.protocols import PRESETS, expand_specs
from senerf.bench.summary import aggregate, final_iterations, format_table
from senerf.cliargs import run_command

PROTOCOL = "synthetic-extreme3@100"
METHODS = ["baseline", "senerf"]
REPO = Path(__file__).resolve().parents[1]


def default_scene() -> Path:
    data = Path(os.environ["SENERF_DATA"]) if os.environ.get("SENERF_DATA") else REPO.parent / "shared" / "data"
    return data / "nerf_synthetic" / "lego"


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default=str(default_scene()), help="lego folder (default: $SENERF_DATA/...)")
    p.add_argument("--presets", nargs="+", default=list(PRESETS), choices=PRESETS)
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--iterations", type=int, default=None,
                   help="SE-NeRF self-training rounds (default: each preset's own count)")
    p.add_argument("--methods", nargs="+", default=METHODS,
                   help=f"harness methods (default: {' '.join(METHODS)}; e.g. senerf-no-prior senerf-no-empty)")
    p.add_argument("--out", default=str(REPO / "benchmarks" / "out" / "frontier"))
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--ray-address", default=None)
    p.add_argument("--timeout", type=float, default=None, help="seconds per fit")
    p.add_argument("--fit-command", default=None, help="replace senerf-fit (shell-quoted; for testing)")
    p.add_argument("--dry-run", action="store_true")
    args = p.parse_args(argv)

    out = Path(args.out)
    results = out / "results.jsonl"
    scene = Path(args.scene)
    specs = expand_specs([str(scene.resolve())], [PROTOCOL], args.methods, args.presets, args.seeds,
                         iterations=args.iterations, check_scenes=scene.is_dir())
    cfg_kw = {"fit_command": tuple(shlex.split(args.fit_command))} if args.fit_command else {}
    threads = 1 if args.ray_address else max(1, len(os.sched_getaffinity(0)) // args.workers)
    cfg = RunnerConfig(runs_dir=str((out / "runs").resolve()), timeout_s=args.timeout, threads=threads, **cfg_kw)
    command = ["python", "benchmarks/frontier.py", *argv]
    if args.dry_run:
        print("\n".join(dry_run_lines(specs, results, cfg.runs_dir)))
        return 0
    if not scene.is_dir():
        print(f"frontier: scene folder not found: {scene}", file=sys.stderr)
        return 2
    executor = make_executor(args.workers, args.ray_address)
    try:
        outcome = run_benchmark(specs, executor, results, cfg, command)
    finally:
        executor.shutdown()
    records = load_results(results)[0]
    aggs = [a for a in aggregate(records) if a.protocol == PROTOCOL and a.scene == scene.name]
    if not aggs:
        print("frontier: no finished fits to tabulate", file=sys.stderr)
        return 1
    (out / "frontier.md").write_text(make_report(records, command, title=f"Frontier: {scene.name} {PROTOCOL}") + "\n")
    plot_frontier(aggs, out / "frontier.png", f"{scene.name} {PROTOCOL}: PSNR vs cost per preset")
    print(format_table(final_iterations(aggs)))
    print(f"wrote {out / 'frontier.md'} and {out / 'frontier.png'}")
    return 1 if outcome.failed else 0


if __name__ == "__main__":   # bad input (a refused results line, say) as one line and exit 2, not a traceback
    sys.exit(run_command("frontier", main, "rerun the same command to resume"))
