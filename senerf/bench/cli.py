"""``senerf-bench``: run, summarize, report and plot benchmarks.

Examples::

    senerf-bench run --scenes data/nerf_synthetic/lego --protocols synthetic-extreme3@100 \\
        --methods baseline senerf --presets fast balanced --seeds 0 1 2 --workers 2 --out bench/
    senerf-bench run ... --ray-address auto          # same runs on an existing Ray cluster
    senerf-bench summarize bench/results.jsonl
    senerf-bench report bench/results.jsonl --out BENCHMARKS-section.md
    senerf-bench plot bench/results.jsonl --out-dir bench/plots
    senerf-bench angles bench/results.jsonl --scene data/nerf_synthetic/lego --protocol synthetic-extreme3@100

Exit status: 0 ok, 1 when some run failed (its line is in the results file; rerun to retry it), 2 bad input.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shlex
import sys
from pathlib import Path

import numpy as np

from senerf.atomic import atomic_write_text, output_file, output_folder
from senerf.cliargs import SEED_MAX, OneLineParser, check_device, float_flag, int_flag, run_command
from senerf.data.load import scene_root
from senerf.errors import InputError

from .execute import RunnerConfig
from .executors import make_executor
from .ladder import teacher_dependence
from .plots import line_view_angles, plot_frontier, plot_gain_vs_teacher, plot_iterations, plot_psnr_vs_angle
from .protocols import METHODS, parse_protocol
from .report import make_report, mask_quality_section
from .results import final_ok_lines, load_results
from .runner import dry_run_lines, run_benchmark
from .specs import PRESETS, expand_specs
from .summary import aggregate, final_iterations, format_table, preset_label

__all__ = ["main", "console", "build_parser"]


REPORT_BEGIN = "<!-- senerf-bench report: BEGIN (generated, do not edit by hand) -->"
REPORT_END = "<!-- senerf-bench report: END -->"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (subcommands ``run``, ``summarize``, ``report``, ``plot``, ``angles``).

    Errors raise :class:`InputError` (:class:`senerf.cliargs.OneLineParser`, inherited by the subcommands), so
    that :func:`main` prints them as one line; numeric flags are checked here, naming the flag."""
    parser = OneLineParser(prog="senerf-bench", description="Run, summarize, report and plot benchmarks; angles: "
                                                            "per-view PSNR against the angle to the nearest input.")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run the grid scenes x protocols x methods x presets x seeds (resumable)")
    run.add_argument("--scenes", nargs="+", required=True, help="scene folders (Blender or LLFF)")
    run.add_argument("--protocols", nargs="+", default=["synthetic-extreme3@100"],
                     help="FAMILY@RES, e.g. synthetic-extreme3@100 synthetic-infonerf4@200 "
                          "synthetic-random8@400 llff3@504x378")
    run.add_argument("--methods", nargs="+", default=["baseline", "senerf"], help=", ".join(METHODS))
    run.add_argument("--presets", nargs="+", default=["fast"], help=", ".join(PRESETS))
    run.add_argument("--seeds", nargs="+", type=int_flag("--seeds", allow_zero=True, maximum=SEED_MAX), default=[0])
    run.add_argument("--iterations", type=int_flag("--iterations"), default=3,
                     help="self-training rounds K (default 3 whatever the preset; senerf-fit's fast preset runs 1: "
                          "pass --iterations 1 to match it)")
    run.add_argument("--steps", type=int_flag("--steps"), default=None, help="override the preset's --steps")
    run.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    run.add_argument("--out", default="bench_out", help="output folder (results.jsonl, runs/)")
    run.add_argument("--results", default=None, help="results file (default OUT/results.jsonl)")
    run.add_argument("--workers", type=int_flag("--workers"), default=1, help="concurrent local runs (default 1)")
    run.add_argument("--threads", type=int_flag("--threads"), default=None,
                     help="torch/OpenMP threads per run (default: usable cores // workers; Ray: --cpus-per-run)")
    run.add_argument("--ray-address", default=None, help="run on this Ray cluster ('auto', 'ray://h:10001')")
    run.add_argument("--cpus-per-run", type=float_flag("--cpus-per-run", positive=True), default=1.0,
                     help="CPUs Ray reserves per run")
    run.add_argument("--timeout", type=float_flag("--timeout", positive=True), default=None,
                     help="seconds per run before it is killed")
    run.add_argument("--fit-command", default=None,
                     help="program replacing senerf-fit (shell-quoted string; for tests and wrappers)")
    run.add_argument("--dry-run", action="store_true", help="print the pending fit commands, run nothing")

    summ = sub.add_parser("summarize", help="print mean ± std over seeds")
    summ.add_argument("results")
    summ.add_argument("--final", action="store_true", help="only each run's last iteration")
    summ.add_argument("--markdown", action="store_true")

    rep = sub.add_parser("report", help="markdown section with the paper's numbers beside ours")
    rep.add_argument("results")
    rep.add_argument("--out", default=None, help="write here (default: stdout)")
    rep.add_argument("--title", default="Benchmarks")
    rep.add_argument("--masks", action="append", default=[],
                     help="also tabulate a `bench_selftrain.py masks` result (bench_masks.json); repeatable")
    rep.add_argument("--into", default=None,
                     help="replace the text between the report markers of this markdown file (e.g. "
                          f"BENCHMARKS.md: '{REPORT_BEGIN}' ... '{REPORT_END}'), atomically")

    plot = sub.add_parser("plot", help="PNG plots: frontier (PSNR vs seconds / memory) and per iteration")
    plot.add_argument("results")
    plot.add_argument("--out-dir", default="bench_plots")
    ang = sub.add_parser("angles", help="PNG: per-view PSNR vs angle to the nearest training view")
    ang.add_argument("results")
    ang.add_argument("--scene", required=True, help="the scene folder (poses are read from it)")
    ang.add_argument("--protocol", required=True, help="protocol of the lines to plot")
    ang.add_argument("--out", default="angles.png")
    ang.add_argument("--preset", default=None, help="only runs of this preset (default: all)")
    ang.add_argument("--methods", nargs="+", default=None, help="only these methods (default: all)")
    ang.add_argument("--iterations", type=int_flag("--iterations", allow_zero=True), default=None, metavar="K",
                     help="only self-training runs of K iterations (baselines are always drawn; default: all)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (0 ok, 2 bad input in one line, 130 interrupted by Ctrl-C or SIGTERM,
    1 internal error with the traceback), as senerf-fit's."""
    argv = list(sys.argv[1:] if argv is None else argv)
    return run_command("senerf-bench", lambda: _dispatch(build_parser().parse_args(argv), argv),
                       "finished runs are in the results file; rerun to resume")


def _dispatch(args: argparse.Namespace, argv: list[str]) -> int:
    if args.command == "run":
        return _cmd_run(args, argv)
    if args.command == "summarize":
        return _cmd_summarize(args)
    if args.command == "report":
        return _cmd_report(args, argv)
    if args.command == "angles":
        return _cmd_angles(args)
    return _cmd_plot(args)


def _cmd_run(args: argparse.Namespace, argv: list[str]) -> int:
    out = output_folder(args.out, "--out")
    results_flag = "--results" if args.results else "--out"
    results = output_file(args.results if args.results else out / "results.jsonl", results_flag)
    records, bad = _read_results(results, results_flag)   # readable (a missing file is a fresh benchmark)
    if bad and not records and not _only_torn_lines(results):
        # appending would mix our lines into someone's file (a README, a log); a torn first line of ours is fine
        raise InputError(f"not a senerf-bench results file ({bad} non-blank line(s), none a results line); "
                         f"choose another {results_flag}", file=results)
    args.scenes = [str(scene_root(s)) for s in args.scenes]   # a scene's marker file names its folder
    for s in args.scenes:
        if not args.dry_run and not Path(s).is_dir():
            raise InputError("scene folder not found", file=s)
    check = all(Path(s).is_dir() for s in args.scenes)
    with _flags_named({"method": "--methods", "preset": "--presets", "protocol": "--protocols"}):
        specs = expand_specs([str(Path(s).resolve()) if Path(s).is_dir() else s for s in args.scenes],
                             args.protocols, args.methods, args.presets, args.seeds, args.iterations, args.device,
                             args.steps, check_scenes=check)
    try:
        fit_command = None if args.fit_command is None else tuple(shlex.split(args.fit_command))
    except ValueError as exc:   # an unclosed quote
        raise InputError(f"cannot be split into words ({exc}): {args.fit_command!r}", field="--fit-command") from None
    if fit_command == ():
        raise InputError("is empty; leave it out to run senerf-fit", field="--fit-command")
    threads = args.threads
    if threads is None:   # one core per reserved CPU: concurrent fits must not oversubscribe a node
        threads = (max(1, int(args.cpus_per_run)) if args.ray_address
                   else max(1, len(os.sched_getaffinity(0)) // args.workers))
    cfg = RunnerConfig(runs_dir=str((out / "runs").resolve()), fit_command=fit_command,
                       timeout_s=args.timeout, threads=threads)
    if args.dry_run:
        print("\n".join(dry_run_lines(specs, results, cfg.runs_dir)))
        return 0
    if not specs:
        raise InputError("the grid of scenes, protocols, methods, presets and seeds holds no run (a protocol "
                         "that fits none of the scenes?)", field="--protocols")
    if args.device != "cpu" and not args.ray_address:   # the fits run here: every one would fail on it
        check_device(args.device)
    _prepare_run_outputs(out, results, results_flag)
    try:
        executor = make_executor(args.workers, args.ray_address, args.cpus_per_run)
    except ImportError as exc:
        raise InputError(str(exc), field="--ray-address") from None
    try:
        outcome = run_benchmark(specs, executor, results, cfg, ["senerf-bench", *argv])
    except KeyboardInterrupt:
        # Finished runs are already on disk; exiting at once makes each run's wrapper stop its fit.
        print(f"senerf-bench: interrupted; finished runs are in {results}, rerun to resume", file=sys.stderr)
        sys.stderr.flush()
        os._exit(130)
    executor.shutdown()
    print(f"done: {outcome.ok} ok, {outcome.failed} failed, {outcome.skipped} skipped -> {results}")
    return 1 if outcome.failed else 0


def _prepare_run_outputs(out: Path, results: Path, results_flag: str) -> None:
    """Create the runs folder and open the results file for appending before any fit starts, so that a
    place that cannot be written (a file in the way, ``/proc``) is refused now, not after the first run."""
    try:
        results.parent.mkdir(parents=True, exist_ok=True)
        with open(results, "a", encoding="utf-8"):
            pass
    except OSError as exc:
        raise InputError(f"cannot write there ({_os_reason(exc, results)}); choose another {results_flag}",
                         file=results) from None
    try:
        (out / "runs").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot write there ({_os_reason(exc, out / 'runs')}); choose another --out",
                         file=out / "runs") from None   # the runs' folder: the path in the way, when it is a file


def _os_reason(exc: OSError, path: Path | str) -> str:
    """``exc``'s reason, with the path it is about when that is a folder on the way to ``path``."""
    reason = exc.strerror or str(exc)
    if exc.filename is not None and Path(str(exc.filename)) in Path(path).parents:
        reason += f": {exc.filename}"
    return reason


def _only_torn_lines(path: Path) -> bool:
    """Whether every non-blank line of ``path`` is a torn results line: it starts like a JSON object (``{``)
    but does not parse (a killed writer).  A complete JSON line that is not a results line is someone else's
    (another tool's JSON-lines log), and so is any other text."""
    with open(path, "rb") as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            if not line.startswith(b"{"):
                return False
            try:
                json.loads(line.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                continue
            return False
    return True


def _read_results(path: Path | str, flag: str | None = None, skipped: list | None = None) -> tuple[list[dict], int]:
    """:func:`load_results`, with a file that cannot be read as an :class:`InputError`."""
    try:
        return load_results(path, skipped)
    except OSError as exc:
        hint = f"; choose another {flag}" if flag else ""
        raise InputError(f"cannot read ({exc.strerror or exc}){hint}", file=path) from None


def _load(path: str, needs: tuple = ()) -> list[dict]:
    """The records of a results file: unparseable lines skipped with a warning, an error when no line
    could be read (an empty file is an empty benchmark).  ``needs``: fields every finished line must carry for
    the command at hand (``senerf-bench run`` writes them all; a line written or cut by hand may lack some), the
    first line lacking one named."""
    if not Path(path).is_file():
        raise InputError("results file not found", file=path)
    skipped = []
    records, bad = _read_results(path, skipped=skipped)
    if bad and not records:
        raise InputError(f"no line could be read ({bad} unparseable line(s)); not a senerf-bench results file?",
                         file=path)
    if bad:
        (number, why), more = skipped[0], (f"; {bad - 1} more" if bad > 1 else "")
        print(f"senerf-bench: warning: skipped {bad} unparseable line(s) in {path} (line {number}: {why}{more})",
              file=sys.stderr)
    for r in records:
        missing = [name for name in needs if name not in r] if r.get("status") == "ok" else []
        if missing:
            raise InputError(f"run {r['run_key']}: {missing[0]}: missing (senerf-bench run writes it; this command "
                             "reads it)", file=path)
    return records


#: What ``plot`` reads of each finished line beyond the fields every one carries, and what ``report`` reads
_PLOT_NEEDS = ("ssim", "seconds_cumulative")
_REPORT_NEEDS = (*_PLOT_NEEDS, "commit", "timestamp", "bench_command")


def _cmd_summarize(args: argparse.Namespace) -> int:
    aggs = aggregate(_load(args.results))
    if args.final:
        aggs = final_iterations(aggs)
    print(format_table(aggs, markdown=args.markdown))
    return 0


@contextlib.contextmanager
def _flags_named(flags: dict):
    """Re-raise the library's InputError for a setting (``method``) as one for the flag that gave it
    (``--methods``): the same checks read results files, where the setting's name is the right one."""
    try:
        yield
    except InputError as exc:
        if exc.field in flags:   # the file, where there is one, is the scene folder the setting does not fit
            raise InputError(exc.problem, file=exc.file, field=flags[exc.field]) from None
        raise


def _not_an_input(target, flag: str, inputs) -> None:
    """Refuse writing ``target`` when it is one of the files read (the results file above all: a report written
    over it would lose every measured run)."""
    for name in inputs:
        try:
            same = Path(name).exists() and Path(target).exists() and os.path.samefile(target, name)
        except OSError:
            same = False
        if same:
            raise InputError(f"is {name}, which this command reads; choose another {flag}", file=target)


def _cmd_report(args: argparse.Namespace, argv: list[str]) -> int:
    out = output_file(args.out, "--out") if args.out else None
    into = output_file(args.into, "--into") if args.into else None
    for target, flag in ((out, "--out"), (into, "--into")):
        if target is not None:
            _not_an_input(target, flag, [args.results, *args.masks])
    try:
        text = make_report(_load(args.results, _REPORT_NEEDS), ["senerf-bench", *argv], title=args.title)
    except InputError as exc:   # a line of the results file
        raise (InputError(exc.problem, file=args.results, field=exc.field) if exc.file is None else exc) from None
    for name in args.masks:
        raw = _read_text(Path(name))   # its own InputError ("cannot read"), not taken for bad JSON below
        try:
            doc = json.loads(raw)
        except ValueError as exc:
            raise InputError(f"not JSON ({exc})", file=name) from None
        try:
            section = mask_quality_section(doc, name)
        except (ValueError, KeyError, TypeError, AttributeError):   # a row without a field, or of another shape
            raise InputError("not a `bench_selftrain.py masks` result", file=name) from None
        text = text.rstrip("\n") + "\n\n" + section
    spliced = splice_report(_read_text(into), text, into) if into is not None else None
    # the new file first: it is the likelier to fail, and then nothing has been written
    if out is not None:
        _write_text(out, text + "\n", "--out")
        print(f"wrote {out}")
    else:
        print(text)
    if into is not None:
        _write_text(into, spliced, "--into")
        print(f"updated the generated section of {into}")
    return 0


def _write_text(path: Path, text: str, flag: str) -> None:
    """:func:`atomic_write_text`, with a place that cannot be written as an :class:`InputError` naming
    ``flag``."""
    try:
        atomic_write_text(path, text)
    except OSError as exc:
        raise InputError(f"cannot write there ({_os_reason(exc, path)}); choose another {flag}", file=path) from None


def _read_text(path: Path) -> str:
    try:
        return path.read_text()
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", file=path) from None


def splice_report(document: str, report: str, path: Path | str = "document") -> str:
    """``document`` with the text between :data:`REPORT_BEGIN` and :data:`REPORT_END` replaced by ``report``.

    Raises:
        InputError: the markers are missing, repeated or out of order.
    """
    b, e = document.count(REPORT_BEGIN), document.count(REPORT_END)
    i, j = document.find(REPORT_BEGIN), document.find(REPORT_END)
    if b != 1 or e != 1 or j < i:
        raise InputError(f"needs exactly one '{REPORT_BEGIN}' line followed by one '{REPORT_END}' line",
                         file=path, field="report markers")
    head = document[:i + len(REPORT_BEGIN)]
    return head + "\n" + report.rstrip("\n") + "\n" + document[j:]


def _cmd_plot(args: argparse.Namespace) -> int:
    records = _load(args.results, _PLOT_NEEDS)
    aggs = aggregate(records)
    if not aggs:
        raise InputError("no finished runs to plot", file=args.results)
    out = output_folder(args.out_dir, "--out-dir")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot write there ({_os_reason(exc, out)}); choose another --out-dir",
                         file=out) from None
    fits = [f for f in teacher_dependence(records) if f.method == "senerf"]
    for scene, protocol in sorted({(a.scene, a.protocol) for a in aggs}):
        group = [a for a in aggs if a.scene == scene and a.protocol == protocol]
        stem = f"{scene}_{protocol.replace('@', '_at_')}"
        for path in (plot_frontier(group, out / f"frontier_{stem}.png", f"{scene} {protocol}: PSNR vs cost"),
                     plot_iterations(group, out / f"iterations_{stem}.png", f"{scene} {protocol}")):
            print(f"wrote {path}")
        mine = [f for f in fits if (f.scene, f.protocol) == (scene, protocol)]
        if mine:
            path = plot_gain_vs_teacher(mine, out / f"gain_vs_teacher_{stem}.png",
                                        f"{scene} {protocol}: SE-NeRF's gain over its teacher, per run")
            print(f"wrote {path}")
    return 0


def _cmd_angles(args: argparse.Namespace) -> int:
    from senerf.data import load_scene   # numpy + imageio only; imported here to keep start-up light

    output_file(args.out, "--out")
    _not_an_input(args.out, "--out", [args.results])
    with _flags_named({"protocol": "--protocol"}):
        proto = parse_protocol(args.protocol)
    scene = load_scene(args.scene, downscale=proto.downscale)
    name = scene.name
    # baselines at iteration 0, self-training runs at their last iteration (their iteration 0 is a baseline)
    lines = [r for r in final_ok_lines(_load(args.results)) if r["scene"] == name and r["protocol"] == proto.name
             and (args.preset is None or r.get("preset") == args.preset)
             and (args.methods is None or r.get("method") in args.methods)
             and (args.iterations is None or not r.get("iterations") or r["iterations"] == args.iterations)]
    if not lines:
        raise InputError(f"no finished runs of {name} under {proto.name}", file=args.results)
    center = (0.0, 0.0, 0.0) if proto.kind == "object" else None
    angles: dict[str, list] = {}
    psnr: dict[str, list] = {}
    for r in lines:
        try:
            a, p = line_view_angles(r, scene.c2w, center)
        except (ValueError, IndexError) as exc:   # a line whose views do not fit this scene (or lack per_view)
            raise InputError(f"run {r['run_key']}: {str(exc).splitlines()[0]}", file=args.results) from None
        label = f"{r['method']} {preset_label(r)}" + (f" iter {r['iteration']}" if r["iteration"] else "")
        angles.setdefault(label, []).extend(a.tolist())
        psnr.setdefault(label, []).extend(p.tolist())
    try:
        path = plot_psnr_vs_angle({k: np.asarray(v) for k, v in angles.items()},
                                  {k: np.asarray(v) for k, v in psnr.items()}, args.out,
                                  f"{name} {proto.name}: PSNR vs angle to the nearest training view (all seeds)")
    except OSError as exc:
        raise InputError(f"cannot write there ({_os_reason(exc, args.out)}); choose another --out",
                         file=args.out) from None
    print(f"wrote {path}")
    return 0


def console() -> None:
    """The ``senerf-bench`` console script: :func:`main`, exiting with its status
    (:func:`senerf.cliargs.console_entry`)."""
    from senerf.cliargs import console_entry

    console_entry(main)


if __name__ == "__main__":
    console()
