"""Markdown report: our mean ± std over seeds beside the paper's numbers for the same protocol.

Every table states the date, commit(s), machine(s), the benchmark command(s) that produced its rows and
the resolution difference from the paper (NeRF Synthetic: paper 800x800, 8 views 400x400; LLFF 504x378).
Paper figures are copied from REFERENCE.md section 6 and are never mixed into our statistics.
"""

from __future__ import annotations

import datetime as _dt
import shlex
from dataclasses import dataclass

from ..errors import InputError
from .ladder import (contrasts_markdown, ladder_markdown, method_contrasts, preset_ladder, teacher_dependence,
                     teacher_dependence_markdown)
from .protocols import parse_protocol
from .results import latest_ok_lines
from .summary import Aggregate, aggregate, final_iterations

__all__ = ["PaperRow", "PAPER_NUMBERS", "paper_rows", "make_report", "mask_quality_section"]


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

#: scenes the paper averages over, per family (the "mean" rows are comparable only with all of them).
_PAPER_SCENES = {
    "synthetic-extreme3": ("chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship"),
    "synthetic-infonerf4": ("chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship"),
    "synthetic-random8": ("chair", "drums", "ficus", "hotdog", "lego", "materials", "mic", "ship"),
    "llff3": ("fern", "flower", "fortress", "horns", "leaves", "orchids", "room", "trex"),
}


def paper_rows(family: str, scene: str | None = None, method: str | None = None) -> list[PaperRow]:
    """Published rows of a protocol family, optionally for one scene (``"mean"`` included) and method."""
    return [r for r in PAPER_NUMBERS if r.family == family and (scene is None or r.scene == scene)
            and (method is None or r.method == method)]


def _split_off_size(records: list[dict]) -> tuple[list[dict], list[dict]]:
    """``(kept, off_size)``: the finished lines whose recorded ``resolution`` is not their protocol's ``[H, W]``
    (a line edited or merged by hand; the runner refuses such fits) split off, so a table never averages two
    resolutions under one protocol.  Lines without a resolution are kept."""
    kept, off = [], []
    for r in records:
        res = r.get("resolution")
        bad = r.get("status") == "ok" and res is not None and list(res) != list(parse_protocol(r["protocol"]).size)
        (off if bad else kept).append(r)
    return kept, off


def make_report(records: list[dict], report_command: list[str], title: str = "Benchmarks") -> str:
    """The markdown section: one block per protocol, our results beside the paper's.

    Args:
        records: results-file lines (:func:`senerf.bench.results.load_results`).
        report_command: argv of the command generating this report (stated in the header).
        title: section heading.
    """
    for r in records:   # a protocol name this version does not know: say which run, before any table
        if r.get("status") == "ok":
            try:
                parse_protocol(r["protocol"])
            except InputError as exc:
                raise InputError(f"{exc.problem} (run {r['run_key']})", field=exc.field) from None
    records, off_size = _split_off_size(records)
    ok = latest_ok_lines(records)
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    out = [f"## {title}", "", f"Generated {now} by `{shlex.join(report_command)}`.",
           "Figures are mean ± sample standard deviation over seeds (never the best run); `n=1` marks a "
           "single seed. Paper figures are copied from the publications, not re-measured.", ""]
    if off_size:
        keys = ", ".join(f"`{r['run_key']}`" for r in off_size[:3]) + (", ..." if len(off_size) > 3 else "")
        out += [f"Left out: {len(off_size)} finished line(s) whose resolution is not their protocol's ({keys}).", ""]
    if not ok:
        return "\n".join(out + ["No finished runs in the results file.", ""])
    aggs = aggregate(records)
    for protocol in sorted({a.protocol for a in aggs}):
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
           f"- Machine(s): {'; '.join(sorted({_machine_text(r.get('machine') or {}) for r in lines}))}",
           f"- Run dates: {min(r['timestamp'] for r in lines)[:16]} to {max(r['timestamp'] for r in lines)[:16]}",
           "- Made by:"] + [f"  `{shlex.join(c)}`" for c in sorted({tuple(r['bench_command']) for r in lines})]
    out += ["", "Final iteration of each run:", "",
            "| scene | method | preset | iter | seeds | PSNR | SSIM | LPIPS | Avg. | seconds | peak MiB | "
            "paper (PSNR / SSIM / LPIPS) |", "|" + "---|" * 12]
    for a in final_iterations(aggs):
        paper = "; ".join(_paper_text(r) for r in paper_rows(proto.family, a.scene, _paper_method(a.method)))
        out.append(f"| {a.scene} | {a.method} | {a.preset} | {a.iteration} | {len(a.seeds)} | "
                   f"{a.psnr.text(2)} | {a.ssim.text(3)} | {_na(a.lpips)} | {_na(a.avg)} | {a.seconds.text(0)} | "
                   f"{a.peak_memory_mib.text(0)} | {paper or '-'} |")
    out += _mean_rows(proto.family, aggs)
    out += ladder_markdown(preset_ladder(lines))
    out += contrasts_markdown(method_contrasts(lines))
    out += teacher_dependence_markdown(teacher_dependence(lines))
    selftrain = [a for a in aggs if a.iterations > 0]
    if selftrain:
        out += ["", "Per self-training iteration (0 = teacher):", "",
                "| scene | method | preset | K | iter | PSNR | SSIM | seconds (cumulative) |", "|" + "---|" * 8]
        out += [f"| {a.scene} | {a.method} | {a.preset} | {a.iterations} | {a.iteration} | {a.psnr.text(2)} | "
                f"{a.ssim.text(3)} | {a.seconds.text(0)} |" for a in selftrain]
    published = paper_rows(proto.family)
    if published:
        out += ["", "Published figures for this protocol:", ""]
        out += [f"- {r.scene}: {_paper_text(r)} at {r.resolution}" for r in published]
    return out + [""]


def _mean_rows(family: str, aggs: list[Aggregate]) -> list[str]:
    """A "mean over scenes" note per (method, preset) when all of the paper's scenes are present."""
    wanted = _PAPER_SCENES.get(family)
    finals = final_iterations(aggs)
    out = []
    for method, preset in sorted({(a.method, a.preset) for a in finals}):
        rows = {a.scene: a for a in finals if a.method == method and a.preset == preset}
        if not wanted or not set(wanted) <= set(rows):
            continue
        mean = sum(rows[s].psnr.mean for s in wanted) / len(wanted)
        paper = "; ".join(_paper_text(r) for r in paper_rows(family, "mean", _paper_method(method)))
        out.append(f"| mean of {len(wanted)} scenes | {method} | {preset} | - | - | {mean:.2f} | | | | | | "
                   f"{paper or '-'} |")
    return out


def _paper_method(method: str) -> str:
    """The paper's row kind for one of our methods; ablations and analyses have none ("-")."""
    return {"baseline": "baseline", "senerf": "senerf"}.get(method, "no published counterpart")


def _paper_text(r: PaperRow) -> str:
    parts = [f"{v:.2f}" if v is not None else "-" for v in (r.psnr, r.ssim, r.lpips)]
    while parts and parts[-1] == "-":
        parts.pop()
    return f"{r.label}: {' / '.join(parts)}"


def _na(stat) -> str:
    return "unavailable" if stat.mean is None else stat.text(3)


def _machine_text(m: dict) -> str:
    if not m:
        return "unknown"
    return (f"{m.get('cpu', '?')}, {m.get('cores_usable', m.get('cores', '?'))} cores, "
            f"torch {m.get('torch', '?')}, {m.get('device', '?')}")


def mask_quality_section(doc: dict, source: str) -> str:
    """Markdown table of a ``benchmarks/bench_selftrain.py masks`` result (its ``bench_masks.json``).

    Args:
        doc: the JSON document (``rows`` of features / threshold / precision / recall / fpr, ``argv``,
            ``commit``, ``machine``, ``timestamp``, ``teacher_psnr``, ``eval_angles_deg``, ``max_error``).
        source: the file it was read from (stated in the section).
    """
    try:
        rows = doc["rows"]
        angles = doc["eval_angles_deg"]
        head = [f"### Reliability masks vs ground-truth colour masks ({source})", "",
                f"- Made by: `python {shlex.join(doc['argv'])}` at commit {doc.get('commit', 'unknown')}, "
                f"{doc.get('timestamp', 'time unknown')[:16]}, {_machine_text(doc.get('machine') or {})}",
                f"- Teacher: {doc['steps']} steps x {doc['batch_rays']} rays, {doc['teacher_psnr']:.2f} dB on the "
                f"test views; {len(angles)} held-out dataset poses {min(angles):.1f}-{max(angles):.1f} degrees "
                f"from an input view as pseudo views; ground truth: teacher colour within {doc['max_error']:g} "
                f"(mean |dRGB|) of the photo.",
                "- Paper (800x800, its own teacher): precision 98.03 %, recall 92.25 %.", "",
                "| features | threshold | tau | precision | recall | false-positive rate | predicted reliable | "
                "ground-truth reliable |", "|" + "---|" * 8]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{source}: not a bench_selftrain masks result ({exc})") from None
    pct = lambda v: f"{100 * v:.2f} %"  # noqa: E731
    body = []
    for r in rows:
        tau = "soft" if r.get("tau") is None else f"{r['tau']:.3f}"
        body.append(f"| {r['features']} | {r['threshold']} | {tau} | {pct(r['precision'])} | {pct(r['recall'])} | "
                    f"{pct(r['fpr'])} | {pct(r['predicted_reliable_rate'])} | {pct(r['gt_reliable_rate'])} |")
    return "\n".join(head + body + [""])
