"""``senerf-bench``: run, summarize, report and plot benchmarks.

Examples::

    senerf-bench run --scenes data/nerf_synthetic/lego --protocols synthetic-extreme3@100 \\
        --methods baseline senerf --presets fast balanced --seeds 0 1 2 --workers 2 --out bench/
    senerf-bench run ... --ray-address auto          # same runs on an existing Ray cluster
    senerf-bench suite --data ../shared/data --out runs/suite [--full]   # every scene at hand, the paper's tables
    senerf-bench summarize bench/results.jsonl
    senerf-bench report bench/results.jsonl --out BENCHMARKS-section.md --figures bench/figures
    senerf-bench report runs/suite/results.jsonl --readme --into README.md   # README's marked results section
    senerf-bench plot bench/results.jsonl --out-dir bench/plots
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import sys
from pathlib import Path

from senerf.atomic import atomic_write_text
from senerf.cliargs import (SEED_MAX, OneLineParser, argument_type, check_device, console_entry, float_flag, int_flag,
                            run_command)
from senerf.data.load import scene_root
from senerf.errors import InputError

from .plots import plot_frontier, plot_paper_comparison
from .protocols import METHODS, PRESETS, SUITE, SUITE_FULL, discover_scenes, expand_specs, parse_protocol
from .report import compare_to_paper, make_report, readme_markdown
from .results import load_results
from .runner import RunnerConfig, dry_run_lines, estimate_lines, make_executor, run_benchmark
from .summary import aggregate, final_iterations, format_table

__all__ = ["main", "console", "build_parser", "splice_report", "REPORT_BEGIN", "REPORT_END"]

REPORT_BEGIN = "<!-- senerf-bench report: BEGIN (generated, do not edit by hand) -->"
REPORT_END = "<!-- senerf-bench report: END -->"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (subcommands ``run``, ``suite``, ``summarize``, ``report``, ``plot``); errors raise
    :class:`InputError` (:class:`senerf.cliargs.OneLineParser`), naming the flag."""
    parser = OneLineParser(prog="senerf-bench", description="Run, summarize, report and plot benchmarks.")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run the grid scenes x protocols x methods x presets x seeds (resumable)")
    run.add_argument("--scenes", nargs="+", required=True, help="scene folders (Blender or LLFF)")
    run.add_argument("--protocols", nargs="+", type=argument_type(lambda name: parse_protocol(name).name),
                     default=["synthetic-extreme3@100"],
                     help="FAMILY@RES, e.g. synthetic-extreme3@100 synthetic-infonerf4@200 "
                          "synthetic-random8@400 llff3@504x378")
    _run_options(run, ["baseline", "senerf"], [0], "bench_out")

    suite = sub.add_parser("suite", help="the paper's protocols on every scene of a data folder (resumable; prints "
                                         "its time estimate first; baselines: each SE-NeRF run's teacher)")
    suite.add_argument("--data", required=True, help="folder holding nerf_synthetic/, nerf_llff_data/ and/or dtu/")
    suite.add_argument("--full", action="store_true", help=f"also {' '.join(SUITE_FULL)}")
    _run_options(suite, ["senerf"], [0, 1, 2], "runs/suite")

    summ = sub.add_parser("summarize", help="print mean ± std over seeds")
    summ.add_argument("results")
    summ.add_argument("--final", action="store_true", help="only each run's last iteration")
    summ.add_argument("--markdown", action="store_true")

    rep = sub.add_parser("report", help="markdown section with the paper's numbers beside ours, per scene")
    rep.add_argument("results")
    rep.add_argument("--out", default=None, help="write here (default: stdout)")
    rep.add_argument("--title", default="Benchmarks")
    rep.add_argument("--into", default=None, help="replace the text between the report markers of this markdown "
                                                  f"file ('{REPORT_BEGIN}' ... '{REPORT_END}')")
    rep.add_argument("--readme", action="store_true", help="one PSNR table over every protocol and scene, ours and "
                                                           "the paper's, under one provenance line (README's form)")
    rep.add_argument("--figures", default=None, metavar="DIR",
                     help="also write a PNG per protocol and configuration: bars per scene, ours against the paper's")

    plot = sub.add_parser("plot", help="PNG frontier plots: PSNR vs seconds and vs peak memory")
    plot.add_argument("results")
    plot.add_argument("--out-dir", default="bench_plots")
    return parser


def _run_options(parser: argparse.ArgumentParser, methods: list[str], seeds: list[int], out: str) -> None:
    """The flags ``run`` and ``suite`` share, with their defaults for ``--methods``, ``--seeds`` and ``--out``."""
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=methods, metavar="METHOD",
                        help=", ".join(METHODS) + f" (default: {' '.join(methods)})")
    parser.add_argument("--presets", nargs="+", choices=PRESETS, default=["fast"])
    parser.add_argument("--seeds", nargs="+", type=int_flag("--seeds", allow_zero=True, maximum=SEED_MAX),
                        default=seeds)
    parser.add_argument("--iterations", type=int_flag("--iterations"), default=None,
                        help="self-training rounds K (default: each preset's own, as senerf-fit)")
    parser.add_argument("--steps", type=int_flag("--steps"), default=None, help="override the preset's --steps")
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--out", default=out, help=f"output folder (results.jsonl, runs/; default {out})")
    parser.add_argument("--results", default=None, help="results file (default OUT/results.jsonl)")
    parser.add_argument("--workers", type=int_flag("--workers"), default=1, help="concurrent local runs (default 1)")
    parser.add_argument("--threads", type=int_flag("--threads"), default=None,
                        help="torch/OpenMP threads per run (default: usable cores // workers; Ray: --cpus-per-run)")
    parser.add_argument("--ray-address", default=None, help="run on this Ray cluster ('auto', 'ray://h:10001')")
    parser.add_argument("--cpus-per-run", type=float_flag("--cpus-per-run", positive=True), default=1.0,
                        help="CPUs Ray reserves per run")
    parser.add_argument("--timeout", type=float_flag("--timeout", positive=True), default=None,
                        help="seconds per run before it is killed")
    parser.add_argument("--fit-command", type=shlex.split, default=None,
                        help="program replacing senerf-fit (shell-quoted string; for tests and wrappers)")
    parser.add_argument("--dry-run", action="store_true", help="print the pending fit commands, run nothing")


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (0 ok, 1 some run failed: rerun to retry it, 2 bad input in one line,
    130 interrupted: rerun to resume)."""
    argv = list(sys.argv[1:] if argv is None else argv)

    def body() -> int:
        args = build_parser().parse_args(argv)
        command = {"run": _cmd_run, "suite": _cmd_suite, "summarize": _cmd_summarize, "report": _cmd_report,
                   "plot": _cmd_plot}
        return command[args.command](args, ["senerf-bench", *argv])

    return run_command("senerf-bench", body, "finished runs are in the results file; rerun to resume")


@contextlib.contextmanager
def _os_errors(path, flag: str | None = None, doing: str = "write"):
    """An ``OSError`` inside as one :class:`InputError` line naming ``path`` (and the flag that chose it)."""
    try:
        yield
    except OSError as exc:
        hint = f"; choose another {flag}" if flag else ""
        raise InputError(f"cannot {doing} ({exc.strerror or exc}){hint}", file=path) from None


def _load(path, flag: str | None = None, must_exist: bool = True) -> list[dict]:
    """The results lines of ``path``, a warning naming the first line skipped; refused when it has lines but
    none is a results line (not a results file: reading it is a mistake, appending to it worse)."""
    if must_exist and not Path(path).is_file():
        raise InputError("results file not found", file=path)
    with _os_errors(path, flag, "read"):
        records, skipped = load_results(path)
    if skipped:
        number, why = skipped[0]
        if not records:
            raise InputError(f"not a senerf-bench results file ({len(skipped)} line(s), none a results line; line "
                             f"{number}: {why})" + (f"; choose another {flag}" if flag else ""), file=path)
        print(f"senerf-bench: warning: skipped {len(skipped)} line(s) that are not results lines in {path} (line "
              f"{number}: {why})", file=sys.stderr)
    return records


def _cmd_run(args: argparse.Namespace, command: list[str]) -> int:
    scenes = [scene_root(s) for s in args.scenes]   # a scene's marker file names its folder
    missing = [s for s in scenes if not s.is_dir()]
    if missing and not args.dry_run:
        raise InputError("scene folder not found", file=missing[0])
    return _run_grid(args, command, [str(s.resolve()) if s.is_dir() else str(s) for s in scenes], args.protocols,
                     check_scenes=not missing)


def _cmd_suite(args: argparse.Namespace, command: list[str]) -> int:
    """``run`` over :func:`discover_scenes`' scenes and :data:`SUITE`'s protocols (``--full``: and
    :data:`SUITE_FULL`'s), with the time estimate printed first.

    It runs ``senerf`` only unless ``--methods`` says otherwise: each run's iteration 0 is its teacher, bit for bit
    the fit the ``baseline`` method runs (``--iterations 0``, same seed, preset and steps; lego at 50x50: 7.485346 dB
    both), so a separate baseline would repeat it, and the report pairs SE-NeRF with the very teacher it started
    from.  That baseline has one field's budget, as in the paper's tables; SE-NeRF spends K + 1 such trainings and
    the labelling, which the estimate and the report's seconds show.  A compute-matched baseline is another
    experiment: ``run --methods baseline --steps N``.
    """
    scenes, notes = discover_scenes(args.data)
    for note in notes:
        print(f"senerf-bench: note: {note}", file=sys.stderr)
    protocols = [*SUITE, *(SUITE_FULL if args.full else ())]
    return _run_grid(args, command, [str(s.resolve()) for s in scenes], protocols, estimate=True)


def _run_grid(args: argparse.Namespace, command: list[str], scenes: list[str], protocols: list[str],
              check_scenes: bool = True, estimate: bool = False) -> int:
    """The grid of ``scenes`` x ``protocols`` x the flags' methods, presets and seeds, printed (``--dry-run``) or run
    resumably into the results file; ``estimate``: print :func:`estimate_lines` first."""
    out = Path(args.out)
    results, results_flag = (Path(args.results), "--results") if args.results else (out / "results.jsonl", "--out")
    _load(results, results_flag, must_exist=False)
    specs = expand_specs(scenes, protocols, args.methods, args.presets, args.seeds, args.iterations, args.device,
                         args.steps, check_scenes=check_scenes)
    if estimate:
        print("\n".join(estimate_lines(specs, results, 1 if args.ray_address else args.workers)), flush=True)
    threads = args.threads
    if threads is None:   # one core per reserved CPU: concurrent fits must not oversubscribe a node
        threads = (max(1, int(args.cpus_per_run)) if args.ray_address
                   else max(1, len(os.sched_getaffinity(0)) // args.workers))
    cfg = RunnerConfig(runs_dir=str((out / "runs").resolve()), fit_command=tuple(args.fit_command or ()) or None,
                       timeout_s=args.timeout, threads=threads)
    if args.dry_run:
        print("\n".join(dry_run_lines(specs, results, cfg.runs_dir)))
        return 0
    if args.device != "cpu" and not args.ray_address:   # the fits run here: every one would fail on it
        check_device(args.device)
    with _os_errors(results, results_flag):   # refused now, not after the first run
        results.parent.mkdir(parents=True, exist_ok=True)
        open(results, "a").close()
    with _os_errors(out / "runs", "--out"):
        (out / "runs").mkdir(parents=True, exist_ok=True)
    try:
        executor = make_executor(args.workers, args.ray_address, args.cpus_per_run)
    except ImportError as exc:
        raise InputError(str(exc), field="--ray-address") from None
    try:
        outcome = run_benchmark(specs, executor, results, cfg, command)
    except KeyboardInterrupt:
        # Finished runs are already on disk; exiting at once makes each run's wrapper stop its fit.
        print(f"senerf-bench: interrupted; finished runs are in {results}, rerun to resume", file=sys.stderr)
        sys.stderr.flush()
        os._exit(130)
    executor.shutdown()
    print(f"done: {outcome.ok} ok, {outcome.failed} failed, {outcome.skipped} skipped -> {results}")
    return 1 if outcome.failed else 0


def _cmd_summarize(args: argparse.Namespace, command: list[str]) -> int:
    aggs = aggregate(_load(args.results))
    print(format_table(final_iterations(aggs) if args.final else aggs, markdown=args.markdown))
    return 0


def _cmd_report(args: argparse.Namespace, command: list[str]) -> int:
    records = _load(args.results)
    if args.out and Path(args.out).exists() and os.path.samefile(args.out, args.results):
        raise InputError(f"is {args.results}, which this command reads; choose another --out", file=args.out)
    text = (readme_markdown(records, command) if args.readme
            else make_report(records, command, title=args.title))
    document = None
    if args.into:
        with _os_errors(args.into, "--into", "read"):
            document = splice_report(Path(args.into).read_text(), text, args.into)
    if args.out:   # the new file first: it is the likelier to fail, and then nothing has been written
        with _os_errors(args.out, "--out"):
            atomic_write_text(args.out, text + "\n")
        print(f"wrote {args.out}")
    elif not args.into:
        print(text)
    if document is not None:
        with _os_errors(args.into, "--into"):
            atomic_write_text(args.into, document)
        print(f"updated the generated section of {args.into}")
    if args.figures:
        with _os_errors(args.figures, "--figures"):
            for (protocol, config), rows in compare_to_paper(records).items():
                name = f"paper_{protocol}_{config}".replace("@", "_at_").replace("=", "").replace(" ", "_")
                print(f"wrote {plot_paper_comparison(rows, Path(args.figures) / (name + '.png'))}")
    return 0


def splice_report(document: str, report: str, path: str | Path = "document") -> str:
    """``document`` with the text between :data:`REPORT_BEGIN` and :data:`REPORT_END` replaced by ``report``.

    Raises:
        InputError: the markers are missing, repeated or out of order.
    """
    i, j = document.find(REPORT_BEGIN), document.find(REPORT_END)
    if document.count(REPORT_BEGIN) != 1 or document.count(REPORT_END) != 1 or j < i:
        raise InputError(f"needs exactly one '{REPORT_BEGIN}' line followed by one '{REPORT_END}' line",
                         file=path, field="report markers")
    return document[:i + len(REPORT_BEGIN)] + "\n" + report.rstrip("\n") + "\n" + document[j:]


def _cmd_plot(args: argparse.Namespace, command: list[str]) -> int:
    aggs = aggregate(_load(args.results))
    if not aggs:
        raise InputError("no finished runs to plot", file=args.results)
    out = Path(args.out_dir)
    with _os_errors(out, "--out-dir"):
        out.mkdir(parents=True, exist_ok=True)
        for scene, protocol in sorted({(a.scene, a.protocol) for a in aggs}):
            group = [a for a in aggs if (a.scene, a.protocol) == (scene, protocol)]
            path = out / f"frontier_{scene}_{protocol.replace('@', '_at_')}.png"
            print(f"wrote {plot_frontier(group, path, f'{scene} {protocol}: PSNR vs cost')}")
    return 0


def console() -> None:
    """The ``senerf-bench`` console script: :func:`main`, exiting with its status."""
    console_entry(main)
