"""Markdown report: our mean ± std over seeds beside the paper's figures (never mixed into our statistics), per
scene and protocol as the paper's tables are, with SE-NeRF's gain over its own teacher paired by seed."""

from __future__ import annotations

import datetime as _dt
import shlex
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from .ladder import Paired, frontier, frontier_markdown, method_contrasts, pair_runs, paired_markdown, preset_ladder
from .protocols import parse_protocol
from .results import latest_ok_lines
from .summary import Aggregate, Stat, aggregate, final_iterations, format_table, preset_label, preset_name

__all__ = ["PaperRow", "PAPER_NUMBERS", "paper_rows", "SceneComparison", "compare_to_paper", "comparison_markdown",
           "departures", "make_report", "readme_markdown"]


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


#: The paper's per-scene tables (``../shared/paper/se-nerf.tex``; tests/bench/test_report.py checks them against it).
#: tab:extreme, PSNR at 800x800: scene -> (K-Planes, SE-NeRF (K-Planes)).
_EXTREME = {"chair": (15.61, 20.54), "drums": (13.23, 13.38), "ficus": (18.29, 18.33), "hotdog": (12.45, 20.14),
            "lego": (14.67, 16.65), "materials": (16.30, 17.01), "ship": (13.35, 13.72), "mic": (19.74, 20.13)}
#: lego's SSIM / LPIPS (tab:distill_ablation): K-Planes, then K-Planes + reliable/unreliable (SE-NeRF).
_EXTREME_LEGO = ((0.68, 0.31), (0.75, 0.24))
#: tab:llff_perscene (504x378): scene -> (K-Planes, SE-NeRF (K-Planes)), each PSNR, SSIM, LPIPS at 3, 6, 9 views;
#: ``"mean"``: tab:llff369 (the mean of the 8 scenes).
_LLFF = {   # PSNR 3 / 6 / 9 views, SSIM 3 / 6 / 9, LPIPS 3 / 6 / 9
    "fern": ((18.22, 21.84, 22.59, .55, .71, .76, .39, .28, .23),
             (18.83, 22.82, 23.28, .59, .73, .77, .38, .28, .25)),
    "orchids": ((12.52, 16.41, 17.92, .19, .48, .56, .57, .36, .32),
                (13.79, 17.14, 18.67, .29, .52, .59, .50, .36, .32)),
    "horns": ((14.40, 18.37, 21.21, .35, .63, .74, .55, .35, .27),
              (14.90, 19.39, 21.82, .40, .67, .75, .54, .35, .28)),
    "leaves": ((14.44, 17.21, 18.51, .37, .57, .65, .47, .32, .27),
               (14.92, 17.59, 18.80, .40, .59, .65, .47, .34, .28)),
    "trex": ((15.04, 18.95, 21.57, .45, .69, .79, .49, .31, .23),
             (15.32, 20.05, 22.28, .50, .73, .80, .47, .29, .23)),
    "room": ((14.55, 20.73, 22.66, .55, .81, .87, .44, .23, .17),
             (14.83, 21.59, 23.27, .58, .84, .88, .40, .22, .18)),
    "fortress": ((19.74, 21.33, 26.71, .65, .76, .84, .30, .26, .17),
                 (19.99, 21.45, 26.87, .69, .77, .85, .31, .27, .18)),
    "flower": ((17.25, 21.81, 22.62, .41, .67, .70, .49, .29, .28),
               (17.84, 22.33, 23.51, .45, .70, .73, .49, .29, .27)),
    "mean": ((15.77, 19.58, 21.72, .44, .66, .73, .46, .30, .24),
             (16.30, 20.30, 22.31, .49, .69, .75, .44, .30, .25)),
}
_LABELS = {"baseline": "K-Planes (paper)", "senerf": "SE-NeRF K-Planes (paper)"}

#: REFERENCE.md section 6 ("numbers to beat"), then the per-scene tables above (no DTU figures: the paper has none).
PAPER_NUMBERS: tuple[PaperRow, ...] = (
    PaperRow("synthetic-extreme3", "mean", "baseline", "K-Planes (paper, 8 scenes)", 15.45, 0.73, 0.28),
    PaperRow("synthetic-extreme3", "mean", "senerf", "SE-NeRF K-Planes (paper, 8 scenes)", 17.49, 0.78, 0.23),
    PaperRow("synthetic-extreme3", "mean", "senerf", "SE-NeRF NeRF (paper, 8 scenes)", 17.41),
    PaperRow("synthetic-infonerf4", "mean", "baseline", "K-Planes (paper)", 17.99),
    PaperRow("synthetic-infonerf4", "mean", "senerf", "SE-NeRF K-Planes (paper)", 19.93),
    PaperRow("synthetic-infonerf4", "mean", "senerf", "SE-NeRF NeRF (paper)", 20.53),
    PaperRow("synthetic-random8", "mean", "peer", "FreeNeRF (DietNeRF views, not seeded-random)", 24.26,
             resolution="400x400"),
    PaperRow("synthetic-random8", "mean", "peer", "DropGaussian (DietNeRF views, not seeded-random)", 25.42,
             resolution="400x400"),
    PaperRow("llff3", "mean", "senerf", "SE-NeRF NeRF (paper)", 18.10, resolution="504x378"),
    PaperRow("llff3", "mean", "peer", "FreeNeRF", 19.63, resolution="504x378"),
    PaperRow("llff3", "mean", "peer", "DropGaussian", 20.76, resolution="504x378"),
    *(PaperRow("synthetic-extreme3", scene, method, _LABELS[method], psnr,
               *(_EXTREME_LEGO[i] if scene == "lego" else (None, None)))
      for scene, psnrs in _EXTREME.items() for i, (method, psnr) in enumerate(zip(_LABELS, psnrs))),
    *(PaperRow(f"llff{n}", scene, method, _LABELS[method], v[j], v[3 + j], v[6 + j], "504x378")
      for scene, both in _LLFF.items() for method, v in zip(_LABELS, both) for j, n in enumerate((3, 6, 9))),
)


def paper_rows(family: str, scene: str | None = None, method: str | None = None) -> list[PaperRow]:
    """Published rows of a protocol family, optionally for one scene (or ``"mean"``) and method."""
    return [r for r in PAPER_NUMBERS if r.family == family and (scene is None or r.scene == scene)
            and (method is None or r.method == method)]


@dataclass(frozen=True)
class SceneComparison:
    """One row of a per-scene table: one scene (or ``"mean"``, over the table's scenes) under one protocol and
    configuration (``"fast K=1"``).

    Attributes:
        scene, protocol, config: the row.
        baseline, senerf: (PSNR, SSIM, LPIPS) stats over seeds of the teachers (iteration 0) and of SE-NeRF's final
            iteration; the mean row's are over each seed's mean over the scenes (seeds every scene has).
        gain: SE-NeRF - baseline PSNR paired by seed (two-sided test; :func:`senerf.bench.ladder.pair_runs`).
        paper: the paper's (K-Planes, SE-NeRF (K-Planes)) rows, ``None`` where unpublished; the mean row's average
            the paper's figures over the same scenes (``None`` unless it publishes every one of them).
        seconds: seconds of fitting of the SE-NeRF runs (teacher, labelling and students; the mean row's: the sum
            over its scenes).
    """

    scene: str
    protocol: str
    config: str
    baseline: tuple[Stat, Stat, Stat]
    senerf: tuple[Stat, Stat, Stat]
    gain: Paired
    paper: tuple[PaperRow | None, PaperRow | None]
    seconds: Stat = Stat(None, None, 0)


def compare_to_paper(records: list[dict]) -> dict[tuple[str, str], list[SceneComparison]]:
    """(protocol, configuration) -> one :class:`SceneComparison` per scene (sorted), then a ``"mean"`` row when
    there are several scenes.

    The baseline of a seed is the teacher (iteration 0) of that seed's ``senerf`` run: the same fit, bit for bit,
    as ``senerf-fit --iterations 0`` with that seed and preset (what the ``baseline`` method runs), trained with the
    same budget as each SE-NeRF student, and the gain is over the teacher SE-NeRF itself started from.  A
    ``baseline`` run's line stands in where no ``senerf`` run has the seed.  SE-NeRF spends (K + 1) such trainings
    and the labelling: this is the paper's comparison, not a compute-matched one.
    """
    runs: dict[tuple, dict] = defaultdict(lambda: defaultdict(dict))   # (protocol, config, role) -> scene -> seed
    baselines: dict[tuple, dict] = defaultdict(lambda: defaultdict(dict))   # (protocol, preset label) -> ...
    for r in latest_ok_lines(records):
        label = preset_label(r)
        if r["method"] == "baseline" and r["iteration"] == r["iterations"]:
            baselines[(r["protocol"], label)][r["scene"]][r["seed"]] = r
        elif r["method"] == "senerf" and r["iteration"] in (0, r["iterations"]):
            config = (r["protocol"], f"{label} K={r['iterations']}")
            runs[config + ("final" if r["iteration"] else "teacher",)][r["scene"]][r["seed"]] = r
    configs = {k[:2] for k in runs} | {(protocol, f"{label} K=0") for protocol, label in baselines
                                       if not any(k[0] == protocol and k[1].startswith(label + " K=") for k in runs)}
    out = {}
    for protocol, config in sorted(configs):
        base = baselines[(protocol, config.rsplit(" K=", 1)[0])]
        teacher, final = runs[(protocol, config, "teacher")], runs[(protocol, config, "final")]
        scenes = sorted(set(base) | set(teacher) | set(final))
        pairs = {s: ({**base.get(s, {}), **teacher.get(s, {})}, final.get(s, {})) for s in scenes}
        rows = [_comparison(s, protocol, config, *pairs[s], _paper_pair(protocol, [s])) for s in scenes]
        if len(scenes) > 1:
            means = [_scene_means([pairs[s][i] for s in scenes]) for i in (0, 1)]
            rows.append(_comparison("mean", protocol, config, *means, _paper_pair(protocol, scenes)))
        out[(protocol, config)] = rows
    return out


def _comparison(scene: str, protocol: str, config: str, base: dict, final: dict, paper: tuple) -> SceneComparison:
    stats = [tuple(Stat.of([r.get(m) for r in lines.values()]) for m in ("psnr", "ssim", "lpips"))
             for lines in (base, final)]
    gain = pair_runs((scene, protocol), ("senerf", final), ("baseline", base), "two-sided")
    seconds = Stat.of([r.get("seconds_cumulative") for r in final.values()])
    return SceneComparison(scene, protocol, config, *stats, gain, paper, seconds)


def _scene_means(per_scene: list[dict]) -> dict[int, dict]:
    """seed -> a line of the means over the scenes (sum of their seconds), for the seeds every scene has."""
    seeds = set.intersection(*(set(lines) for lines in per_scene)) if per_scene else set()
    out = {}
    for seed in sorted(seeds):
        lines = [lines[seed] for lines in per_scene]
        out[seed] = {m: float(np.mean([r[m] for r in lines])) if all(Stat.of([r.get(m)]).n for r in lines)
                     else "unavailable" for m in ("psnr", "ssim", "lpips")}
        out[seed]["seconds_cumulative"] = sum(r["seconds_cumulative"] for r in lines)
    return out


def _paper_pair(protocol: str, scenes: list[str]) -> tuple[PaperRow | None, PaperRow | None]:
    """The paper's (K-Planes, SE-NeRF) figures of ``scenes`` (their mean for several), ``None`` unless each is
    published."""
    family = parse_protocol(protocol).family
    out = []
    for method, label in _LABELS.items():
        rows = [next((r for r in paper_rows(family, s, method) if r.label == label), None) for s in scenes]
        if any(r is None for r in rows):
            out.append(None)
        elif len(rows) == 1:
            out.append(rows[0])
        else:
            means = [None if any(getattr(r, m) is None for r in rows) else round(float(np.mean(
                [getattr(r, m) for r in rows])), 3) for m in ("psnr", "ssim", "lpips")]
            out.append(PaperRow(family, "mean", method, f"{label}, these {len(rows)} scenes", *means,
                                rows[0].resolution))
    return out[0], out[1]


def _gain_text(gain: Paired, p_label: str = "") -> str:
    """``"+0.60 ± 0.10 (p 0.009)"``, ``"+0.60 (n=1)"`` or ``"-"``: a paired gain and its test, as tables print it."""
    d = gain.diff
    if d.mean is None:
        return "-"
    return f"{d.mean:+.2f}" + (" (n=1)" if d.std is None else f" ± {d.std:.2f} ({p_label}{gain.p_value:.3f})")


def comparison_markdown(rows: list[SceneComparison]) -> list[str]:
    """Markdown lines of one per-scene table (:func:`compare_to_paper`'s rows of one protocol and configuration)."""
    out = [(f"Per scene, {rows[0].config} (baseline: each run's teacher; gain: SE-NeRF - baseline PSNR paired by "
            "seed, two-sided t-test; paper: K-Planes -> SE-NeRF (K-Planes)):"), "",
           ("| scene | seeds | PSNR baseline | PSNR SE-NeRF | gain (p) | paper PSNR | SSIM baseline | SSIM SE-NeRF | "
            "paper SSIM | LPIPS baseline | LPIPS SE-NeRF | paper LPIPS |"), "|" + "---|" * 12]
    for r in rows:
        gain = _gain_text(r.gain, "p ")
        paper = []
        for i, m in enumerate(("psnr", "ssim", "lpips")):
            values = [None if p is None else getattr(p, m) for p in r.paper]
            text = "-" if values == [None, None] else " -> ".join("-" if v is None else f"{v:.2f}" for v in values)
            paper.append(text + (f" ({values[1] - values[0]:+.2f})" if i == 0 and None not in values else ""))
        cells = [f"**{r.scene}**" if r.scene == "mean" else r.scene, str(len(r.gain.seeds)),
                 r.baseline[0].text(2), r.senerf[0].text(2), gain, paper[0], r.baseline[1].text(3),
                 r.senerf[1].text(3), paper[1], r.baseline[2].text(3), r.senerf[2].text(3), paper[2]]
        out.append("| " + " | ".join(cells) + " |")
    return out


def readme_markdown(records: list[dict], report_command: list[str]) -> str:
    """README's results: one PSNR table over every protocol, scene and configuration of :func:`compare_to_paper`
    (teacher, SE-NeRF, the paired gain, the paper's K-Planes -> SE-NeRF, seconds of a fit), under one line naming
    the command, commits and machines; the full provenance is :func:`make_report`'s."""
    ok = latest_ok_lines(records)
    if not ok:
        return "No finished runs in the results file."
    machines = "; ".join(sorted({_machine_text(r) for r in ok}))
    out = [f"Generated by `{shlex.join(report_command)}` from runs of commit(s) "
           f"{', '.join(sorted({r['commit'][:7] for r in ok}))} ({machines}). PSNR in dB, mean ± std over seeds; "
           "teacher = each run's iteration 0; gain paired by seed (two-sided t-test).", "",
           "| protocol | scene | seeds | teacher | SE-NeRF | gain (p) | paper: K-Planes -> SE-NeRF | a fit |",
           "|---|---|---|---|---|---|---|---|"]
    for (protocol, config), rows in compare_to_paper(records).items():
        for r in rows:
            gain = _gain_text(r.gain)
            paper = ("-" if None in r.paper or r.paper[0].psnr is None or r.paper[1].psnr is None else
                     f"{r.paper[0].psnr:.2f} -> {r.paper[1].psnr:.2f}")
            fit = "-" if r.scene == "mean" or r.seconds.mean is None else f"{r.seconds.mean:.0f} s"
            out.append(f"| {protocol}, {config} | {'**mean**' if r.scene == 'mean' else r.scene} | "
                       f"{max(len(r.gain.seeds), r.baseline[0].n, r.senerf[0].n)} | {r.baseline[0].text(2)} | "
                       f"{r.senerf[0].text(2)} | {gain} | {paper} | "
                       f"{fit} |")
    return "\n".join(out)


def departures(records: list[dict]) -> list[str]:
    """Markdown bullets: where the runs behind a report differ from the paper's experiments, from the records
    themselves (resolution, budget, seeds, metrics); the method's own departures are README.md's list, named once
    there and pointed to here."""
    ok = latest_ok_lines(records)
    out = ["Where these runs differ from the paper:", ""]
    for protocol in sorted({r["protocol"] for r in ok}):
        proto = parse_protocol(protocol)
        paper_res = sorted({r.resolution for r in paper_rows(proto.family)})
        out.append(f"- **{protocol}**: ours {proto.size[1]}x{proto.size[0]}, the paper's "
                   + (", ".join(paper_res) if paper_res else "(it publishes no figures for this protocol)") + ".")
    for label in sorted({preset_label(r) for r in ok}):
        runs = [r for r in ok if preset_label(r) == label]
        schedule = runs[0].get("schedule")   # lines written before it was recorded: the preset of their commit
        budget = (f"{schedule.replace('x', ' steps x ')} rays" if schedule else
                  f"the {preset_name(label)} preset of commit(s) {', '.join(sorted({r['commit'][:7] for r in runs}))}")
        ks = sorted({r["iterations"] for r in runs if r["method"] != "baseline"})
        out.append(f"- **Budget, {label}**: each field {budget}, "
                   f"K = {', '.join(map(str, ks)) or '0'} self-training iteration(s), on the machines named above; "
                   "the paper trains K-Planes 20 GPU-minutes an iteration (NeRF Synthetic; 60 on LLFF) on an RTX "
                   "3090, about 4 iterations.")
    seeds = sorted({r["seed"] for r in ok})
    out += [(f"- **Seeds**: ours mean ± std over seeds {', '.join(map(str, seeds))}; the paper gives one figure per "
             "scene, no spread."),
            ("- **Means**: ours over the scenes present; the paper column of a mean row averages its figures over the "
             "same scenes (its published means cover 8).")]
    if not any(Stat.of([r.get("lpips")]).n for r in ok):
        out.append("- **LPIPS**: not measured (no LPIPS weights offline); the paper's are listed.")
    out.append("- **The method**: the decoder, empty-space distillation and the choices the paper leaves open are "
               "listed once, in README.md, \"Where we depart from the paper\".")
    return out


def make_report(records: list[dict], report_command: list[str], title: str = "Benchmarks") -> str:
    """The markdown section: one block per protocol, our results beside the paper's, each block stating the
    resolutions (ours and the paper's), the commit(s), machine(s), run dates and the command(s) behind its rows;
    then :func:`departures`.

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
    tables = compare_to_paper(records)
    for protocol in sorted({r["protocol"] for r in ok}):
        out += _protocol_block(protocol, [r for r in ok if r["protocol"] == protocol],
                               [a for a in aggs if a.protocol == protocol],
                               [rows for (p, _), rows in tables.items() if p == protocol])
    return "\n".join(out + departures(records) + [""])


def _protocol_block(protocol: str, lines: list[dict], aggs: list[Aggregate], tables: list[list[SceneComparison]]
                    ) -> list[str]:
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
    for rows in tables:
        out += [""] + comparison_markdown(rows)
    finals = final_iterations(aggs)
    paper = ["; ".join(_paper_text(r) for r in paper_rows(proto.family, a.scene, a.method)) or "-"
             for a in finals]   # published rows are "baseline", "senerf" or "peer": ablations have none
    out += ["", "Final iteration of each run:", "", format_table(finals, True, ("paper (PSNR / SSIM / LPIPS)", paper))]
    ladder = preset_ladder(lines)   # more than one rung: the frontier too
    out += paired_markdown(ladder) + (frontier_markdown(frontier(lines)) if ladder else [])
    out += paired_markdown(method_contrasts(lines), ladder=False)
    selftrain = [a for a in aggs if a.iterations > 0]
    if selftrain:
        out += ["", "Per self-training iteration (0 = teacher; seconds cumulative):", "", format_table(selftrain, True)]
    out += _phase_table(lines)
    published = [r for r in paper_rows(proto.family) if r.scene == "mean"]   # the scenes': in the tables above
    if published:
        out += ["", "Published means for this protocol:", ""]
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
