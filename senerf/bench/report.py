"""Markdown report: our mean ± std over seeds beside the paper's figures (never mixed into our statistics)."""

from __future__ import annotations

import datetime as _dt
import shlex
from dataclasses import dataclass

from .ladder import method_contrasts, paired_markdown, preset_ladder
from .protocols import parse_protocol
from .results import latest_ok_lines
from .summary import Aggregate, aggregate, final_iterations, format_table

__all__ = ["PaperRow", "PAPER_NUMBERS", "paper_rows", "make_report"]


@dataclass(frozen=True)
class PaperRow:
    """One published figure: ``scene`` is a scene name or ``"mean"`` (mean over the protocol's scenes);
    ``method`` is ``"baseline"``, ``"senerf"`` or ``"peer"``; metrics are ``None`` where not published."""

    family: str
    scene: str
    method: str
    label: str
    psnr: float | None
    ssim: float | None = None
    lpips: float | None = None
    resolution: str = "800x800"


#: REFERENCE.md section 6 ("numbers to beat").
PAPER_NUMBERS: tuple[PaperRow, ...] = (
    PaperRow("synthetic-extreme3", "mean", "baseline", "K-Planes (paper, 8 scenes)", 15.45, 0.73, 0.28),
    PaperRow("synthetic-extreme3", "mean", "senerf", "SE-NeRF K-Planes (paper, 8 scenes)", 17.49, 0.78, 0.23),
    PaperRow("synthetic-extreme3", "mean", "senerf", "SE-NeRF NeRF (paper, 8 scenes)", 17.41),
    PaperRow("synthetic-extreme3", "lego", "baseline", "K-Planes (paper)", 14.67, 0.68, 0.31),
    PaperRow("synthetic-extreme3", "lego", "senerf", "SE-NeRF K-Planes (paper)", 16.65, 0.75, 0.24),
    PaperRow("synthetic-infonerf4", "mean", "baseline", "K-Planes (paper)", 17.99),
    PaperRow("synthetic-infonerf4", "mean", "senerf", "SE-NeRF K-Planes (paper)", 19.93),
    PaperRow("synthetic-infonerf4", "mean", "senerf", "SE-NeRF NeRF (paper)", 20.53),
    PaperRow("synthetic-random8", "mean", "peer", "FreeNeRF (DietNeRF views, not seeded-random)", 24.26,
             resolution="400x400"),
    PaperRow("synthetic-random8", "mean", "peer", "DropGaussian (DietNeRF views, not seeded-random)", 25.42,
             resolution="400x400"),
    PaperRow("llff3", "mean", "baseline", "K-Planes (paper)", 15.77, resolution="504x378"),
    PaperRow("llff3", "mean", "senerf", "SE-NeRF K-Planes (paper)", 16.30, resolution="504x378"),
    PaperRow("llff3", "mean", "senerf", "SE-NeRF NeRF (paper)", 18.10, resolution="504x378"),
    PaperRow("llff3", "mean", "peer", "FreeNeRF", 19.63, resolution="504x378"),
    PaperRow("llff3", "mean", "peer", "DropGaussian", 20.76, resolution="504x378"),
    PaperRow("llff3", "fern", "baseline", "K-Planes (paper)", 18.22, resolution="504x378"),
    PaperRow("llff3", "fern", "senerf", "SE-NeRF K-Planes (paper)", 18.83, resolution="504x378"),
)

def paper_rows(family: str, scene: str | None = None, method: str | None = None) -> list[PaperRow]:
    """Published rows of a protocol family, optionally for one scene (or ``"mean"``) and method."""
    return [r for r in PAPER_NUMBERS if r.family == family and (scene is None or r.scene == scene)
            and (method is None or r.method == method)]


def make_report(records: list[dict], report_command: list[str], title: str = "Benchmarks") -> str:
    """The markdown section: one block per protocol, our results beside the paper's, each block stating the
    resolutions (ours and the paper's), the commit(s), machine(s), run dates and the command(s) behind its rows.

    Args:
        records: results-file lines (:func:`senerf.bench.results.load_results`).
        report_command: argv of the command generating this report (stated in the header).
    """
    ok = latest_ok_lines(records)
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    out = [f"## {title}", "", f"Generated {now} by `{shlex.join(report_command)}`.",
           "Figures are mean ± sample standard deviation over seeds (never the best run); `n=1` marks a "
           "single seed. Paper figures are copied from the publications, not re-measured.", ""]
    if not ok:
        return "\n".join(out + ["No finished runs in the results file.", ""])
    aggs = aggregate(records)
    for protocol in sorted({r["protocol"] for r in ok}):
        out += _protocol_block(protocol, [r for r in ok if r["protocol"] == protocol],
                               [a for a in aggs if a.protocol == protocol])
    return "\n".join(out)


def _protocol_block(protocol: str, lines: list[dict], aggs: list[Aggregate]) -> list[str]:
    proto = parse_protocol(protocol)
    h, w = proto.size
    paper_res = {r.resolution for r in paper_rows(proto.family)} or {"none published"}
    out = [f"### {protocol}", "",
           f"- Resolution: ours {w}x{h} (checked against each metrics.json); paper {', '.join(sorted(paper_res))}"
           + ("." if f"{w}x{h}" in paper_res else " - a different resolution, so not directly comparable."),
           f"- Commit(s): {', '.join(sorted({r['commit'] for r in lines}))}",
           f"- Machine(s): {'; '.join(sorted({_machine_text(r) for r in lines}))}",
           f"- Run dates: {min(r['timestamp'] for r in lines)[:16]} to {max(r['timestamp'] for r in lines)[:16]}",
           "- Made by:"] + [f"  `{shlex.join(c)}`" for c in sorted({tuple(r['bench_command']) for r in lines})]
    finals = final_iterations(aggs)
    paper = ["; ".join(_paper_text(r) for r in paper_rows(proto.family, a.scene, a.method)) or "-"
             for a in finals]   # published rows are "baseline", "senerf" or "peer": ablations have none
    out += ["", "Final iteration of each run:", "", format_table(finals, True, ("paper (PSNR / SSIM / LPIPS)", paper))]
    out += paired_markdown(preset_ladder(lines)) + paired_markdown(method_contrasts(lines), ladder=False)
    selftrain = [a for a in aggs if a.iterations > 0]
    if selftrain:
        out += ["", "Per self-training iteration (0 = teacher; seconds cumulative):", "", format_table(selftrain, True)]
    out += _phase_table(lines)
    published = paper_rows(proto.family)
    if published:
        out += ["", "Published figures for this protocol:", ""]
        out += [f"- {r.scene}: {_paper_text(r)} at {r.resolution}" for r in published]
    return out + [""]


def _phase_table(lines: list[dict]) -> list[str]:
    """Markdown rows: each (scene, method, preset)'s seconds per phase of a whole run (summed over its iterations),
    mean over its runs; nothing when no line records its phases."""
    from senerf.train.record import PHASES

    runs: dict = {}
    for r in lines:
        if isinstance(r.get("phases"), dict):
            run = runs.setdefault((r["scene"], r["method"], r["preset"]), {}).setdefault(r["run_key"], {})
            for name in PHASES:
                run[name] = run.get(name, 0.0) + float(r["phases"].get(name, 0.0))
    if not runs:
        return []
    out = ["", "Seconds per phase of a whole run (mean over its runs):", "",
           "| scene | method | preset | runs | " + " | ".join(PHASES) + " |", "|" + "---|" * (4 + len(PHASES))]
    for (scene, method, preset), by_run in sorted(runs.items()):
        means = [sum(run[name] for run in by_run.values()) / len(by_run) for name in PHASES]
        out.append(f"| {scene} | {method} | {preset} | {len(by_run)} | " + " | ".join(f"{m:.1f}" for m in means) + " |")
    return out


def _paper_text(r: PaperRow) -> str:
    parts = [f"{v:.2f}" if v is not None else "-" for v in (r.psnr, r.ssim, r.lpips)]
    while parts[-1] == "-":
        parts.pop()
    return f"{r.label}: {' / '.join(parts)}"


def _machine_text(line: dict) -> str:
    """The processor, threads, torch and device (the GPU's name) a line's fit recorded (``host``; lines written
    before it was recorded carry the driver's ``machine``)."""
    host = line.get("host") or line.get("machine") or {}
    return (f"{host.get('cpu', '?')}, {host.get('threads', host.get('cores_usable', '?'))} threads, "
            f"torch {host.get('torch', '?')}, {host.get('device', '?')}")
