"""Benchmark harness for ``senerf-fit``: protocols, resumable runs (local or Ray), summaries, reports, plots.

Each run is one ``senerf-fit`` child process in its own output folder; its ``metrics.json`` (DESIGN.md
contract) becomes one JSON line per self-training iteration in a results file.  See ``senerf-bench --help``
and :mod:`senerf.bench.results` for the line schema.  No torch import.
"""

from .execute import RunnerConfig, check_protocol, default_fit_command, execute_run, parse_metrics
from .executors import Executor, LocalExecutor, RayExecutor, make_executor
from .machine import git_commit, machine_info
from .ladder import (Contrast, Rung, TeacherFit, contrasts_markdown, ladder_markdown, method_contrasts,
                     paired_gain_p_value, preset_ladder, teacher_dependence, teacher_dependence_markdown)
from .plots import (line_view_angles, nearest_view_angles, plot_frontier, plot_gain_vs_teacher, plot_iterations,
                    plot_mask_quality, plot_psnr_vs_angle)
from .protocols import METHODS, Method, Protocol, get_method, native_size, parse_protocol
from .report import PAPER_NUMBERS, PaperRow, make_report, paper_rows
from .results import append_lines, finished_keys, latest_ok_lines, load_results, result_lines, validate_line
from .runner import BenchOutcome, pending_specs, run_benchmark
from .specs import PRESETS, RunSpec, expand_specs
from .summary import Aggregate, Stat, aggregate, final_iterations, format_table, preset_label

__all__ = [
    "Protocol", "Method", "METHODS", "PRESETS", "parse_protocol", "get_method", "native_size",
    "RunSpec", "expand_specs",
    "RunnerConfig", "default_fit_command", "execute_run", "parse_metrics", "check_protocol",
    "Executor", "LocalExecutor", "RayExecutor", "make_executor",
    "BenchOutcome", "pending_specs", "run_benchmark",
    "result_lines", "validate_line", "append_lines", "load_results", "finished_keys", "latest_ok_lines",
    "Stat", "Aggregate", "aggregate", "final_iterations", "format_table", "preset_label",
    "PaperRow", "PAPER_NUMBERS", "paper_rows", "make_report",
    "plot_frontier", "plot_iterations", "nearest_view_angles", "line_view_angles", "plot_psnr_vs_angle",
    "plot_mask_quality", "Rung", "preset_ladder", "paired_gain_p_value", "ladder_markdown",
    "Contrast", "method_contrasts", "contrasts_markdown", "TeacherFit", "teacher_dependence",
    "teacher_dependence_markdown", "plot_gain_vs_teacher",
    "git_commit", "machine_info",
]
