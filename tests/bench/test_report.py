"""The markdown report: our figures beside the published ones, with where they came from."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from senerf.bench.report import PAPER_NUMBERS, compare_to_paper, make_report, paper_rows, readme_markdown
from senerf.bench.results import load_results

REPO = Path(__file__).resolve().parents[2]
PAPER = REPO.parent / "shared" / "paper" / "se-nerf.tex"

#: REFERENCE.md section 6 ("Numbers to beat"), copied by hand: (family, scene, label) -> (PSNR, SSIM, LPIPS); None:
#: not in section 6 (the paper's tables may give it).
_REFERENCE_FIGURES = {
    ("synthetic-extreme3", "mean", "K-Planes (paper, 8 scenes)"): (15.45, 0.73, 0.28),
    ("synthetic-extreme3", "mean", "SE-NeRF K-Planes (paper, 8 scenes)"): (17.49, 0.78, 0.23),
    ("synthetic-extreme3", "mean", "SE-NeRF NeRF (paper, 8 scenes)"): (17.41, None, None),
    ("synthetic-extreme3", "lego", "K-Planes (paper)"): (14.67, 0.68, 0.31),
    ("synthetic-extreme3", "lego", "SE-NeRF K-Planes (paper)"): (16.65, 0.75, 0.24),
    ("synthetic-infonerf4", "mean", "K-Planes (paper)"): (17.99, None, None),
    ("synthetic-infonerf4", "mean", "SE-NeRF K-Planes (paper)"): (19.93, None, None),
    ("synthetic-infonerf4", "mean", "SE-NeRF NeRF (paper)"): (20.53, None, None),
    ("synthetic-random8", "mean", "FreeNeRF (DietNeRF views, not seeded-random)"): (24.26, None, None),
    ("synthetic-random8", "mean", "DropGaussian (DietNeRF views, not seeded-random)"): (25.42, None, None),
    ("llff3", "mean", "K-Planes (paper)"): (15.77, None, None),
    ("llff3", "mean", "SE-NeRF K-Planes (paper)"): (16.30, None, None),
    ("llff3", "mean", "SE-NeRF NeRF (paper)"): (18.10, None, None),
    ("llff3", "mean", "FreeNeRF"): (19.63, None, None),
    ("llff3", "mean", "DropGaussian"): (20.76, None, None),
    ("llff3", "fern", "K-Planes (paper)"): (18.22, None, None),
    ("llff3", "fern", "SE-NeRF K-Planes (paper)"): (18.83, None, None),
}


def _report(records):
    return make_report(records, ["senerf-bench", "report", "r.jsonl"])


def _final_table(text: str) -> list[str]:
    lines = text.splitlines()
    start = lines.index("Final iteration of each run:") + 4
    return lines[start:next(i for i in range(start, len(lines)) if not lines[i].startswith("|"))]


def test_paper_figures_are_reference_section_6():
    ours = {(r.family, r.scene, r.label): (r.psnr, r.ssim, r.lpips) for r in PAPER_NUMBERS}
    assert len(ours) == len(PAPER_NUMBERS)   # no figure twice
    for key, figures in _REFERENCE_FIGURES.items():
        assert all(f is None or f == o for f, o in zip(figures, ours[key])), key


def _tex_table(tex: str, label: str) -> list[list[str]]:
    """The cells of each row of the tabular holding ``\\label{label}`` (a row ends at ``\\\\``)."""
    start = tex.index(f"\\label{{{label}}}")
    body = tex[tex.index("\\hline", start):tex.index("\\end{tabular}", start)]
    return [[c.replace("\\hline", "").strip() for c in row.split("&")] for row in body.split("\\\\") if "&" in row]


def _figures(cells: list[str]) -> list[float]:
    """The numbers among ``cells``, LaTeX spacing and braces removed (``{20.13}  \\vspace{-2pt}`` is 20.13)."""
    bare = [re.sub(r"\\vspace\{[^}]*\}|[{}]", "", c).strip() for c in cells]
    return [float(c) for c in bare if re.fullmatch(r"[0-9]+\.[0-9]+", c)]


@pytest.mark.skipif(not PAPER.is_file(), reason=f"the paper's source is not at {PAPER}: nothing to check against")
def test_per_scene_paper_figures_are_the_papers_tables():
    tex = PAPER.read_text()
    scenes = ["chair", "drums", "ficus", "hotdog", "lego", "materials", "ship", "mic"]
    rows = _tex_table(tex, "tab:extreme")
    kplanes = next(_figures(r[1:]) for r in rows if r[0] == "$K$-Planes")
    senerf = next(_figures(r[1:]) for r in rows if r[0].endswith("{\\ours ($K$-Planes)}"))
    for method, values in (("baseline", kplanes), ("senerf", senerf)):
        assert len(values) == 8
        assert [paper_rows("synthetic-extreme3", s, method)[0].psnr for s in scenes] == values, method
    rows = [r for r in _tex_table(tex, "tab:llff_perscene") if len(_figures(r)) == 12]   # PSNR ... Average x 3
    assert len(rows) == 16   # 8 scenes of K-Planes, then 8 of SE-NeRF (K-Planes)
    for i, row in enumerate(rows):
        method, scene, values = ("baseline" if i < 8 else "senerf"), row[1], _figures(row[2:])
        for j, n in enumerate((3, 6, 9)):
            (published,) = paper_rows(f"llff{n}", scene, method)
            assert (published.psnr, published.ssim, published.lpips) == (values[j], values[3 + j], values[6 + j])
    means = {r[0]: _figures(r[1:]) for r in _tex_table(tex, "tab:llff369")}
    for method, key in (("baseline", "$K$-Planes"), ("senerf", "\\multirow{2}{*}{\\ours($K$-Planes)}")):
        for j, n in enumerate((3, 6, 9)):
            (published,) = [r for r in paper_rows(f"llff{n}", "mean", method) if "K-Planes" in r.label]
            assert (published.psnr, published.ssim, published.lpips) == tuple(means[key][j::3][:3]), (method, n)
    assert "DTU" not in tex and not paper_rows("dtu3")   # the paper publishes no DTU figures


def _suite_lines(ok_line, scenes=(("lego", 16.0), ("mic", 19.0)), seeds=(0, 1, 2), protocol="synthetic-extreme3@100"):
    """SE-NeRF runs (K=1) of each scene: teacher ``base + seed / 5``, SE-NeRF ``+ 0.5 + seed / 10`` above it."""
    return [ok_line(run_key=f"{scene}{seed}", scene=scene, protocol=protocol, method="senerf", seed=seed,
                    iterations=1, iteration=it, psnr=base + seed / 5 + it * (0.5 + seed / 10), ssim=0.5 + 0.01 * it)
            for scene, base in scenes for seed in seeds for it in (0, 1)]


def test_per_scene_rows_pair_each_senerf_run_with_its_own_teacher_and_end_with_the_mean(ok_line):
    (key, rows), = compare_to_paper(_suite_lines(ok_line)).items()
    assert key == ("synthetic-extreme3@100", "fast K=1") and [r.scene for r in rows] == ["lego", "mic", "mean"]
    lego, mic, mean = rows
    assert lego.baseline[0].mean == pytest.approx(16.2) and lego.senerf[0].mean == pytest.approx(16.8)
    assert lego.gain.seeds == (0, 1, 2) and lego.gain.diff.mean == pytest.approx(0.6)
    assert lego.gain.diff.std == pytest.approx(0.1) and lego.gain.p_value == pytest.approx(0.0091, abs=1e-4)
    assert mean.baseline[0].mean == pytest.approx(17.7) and mean.gain.diff.mean == pytest.approx(0.6)
    assert (lego.paper[0].psnr, lego.paper[1].psnr, mic.paper[1].psnr) == (14.67, 16.65, 20.13)
    assert (mean.paper[0].psnr, mean.paper[1].psnr) == (pytest.approx(17.205), pytest.approx(18.39))
    assert mean.paper[0].ssim is None   # mic's SSIM is not published
    # a seed only one scene has stays out of the mean; an unpublished scene has no paper figures
    more = _suite_lines(ok_line, scenes=(("lego", 16.0),), seeds=(3,)) + _suite_lines(
        ok_line, scenes=(("mine", 10.0),), seeds=(0,))
    rows = compare_to_paper(_suite_lines(ok_line) + more)[("synthetic-extreme3@100", "fast K=1")]
    assert [r.scene for r in rows] == ["lego", "mic", "mine", "mean"] and rows[0].gain.seeds == (0, 1, 2, 3)
    assert rows[-1].gain.seeds == (0,) and rows[2].paper == (None, None) and rows[-1].paper == (None, None)


def test_readme_table_has_a_row_per_scene_and_the_mean_with_the_papers_figures(ok_line):
    text = readme_markdown(_suite_lines(ok_line), ["senerf-bench", "report", "r.jsonl", "--readme"])
    rows = [line for line in text.splitlines() if line.startswith("| synthetic")]
    assert text.startswith("Generated by `senerf-bench report r.jsonl --readme`")
    assert rows[0].startswith("| synthetic-extreme3@100, fast K=1 | lego | 3 | 16.20 ± 0.20 | 16.80 ± 0.30 | "
                              "+0.60 ± 0.10 (0.009) | 14.67 -> 16.65 |")
    assert rows[1].split(" | ")[6] == "19.74 -> 20.13" and len(rows) == 3
    assert rows[2].split(" | ")[1:3] == ["**mean**", "3"] and rows[2].endswith("| 17.20 -> 18.39 | - |")
    assert readme_markdown([], ["x"]) == "No finished runs in the results file."


def test_a_baseline_run_stands_in_where_no_senerf_run_has_the_seed(ok_line):
    lines = _suite_lines(ok_line, scenes=(("lego", 16.0),), seeds=(0,)) + [
        ok_line(run_key="b0", psnr=99.0), ok_line(run_key="b1", seed=1, psnr=15.0)]
    (rows,) = compare_to_paper(lines).values()
    assert rows[0].baseline[0].n == 2 and rows[0].baseline[0].mean == pytest.approx((16.0 + 15.0) / 2)
    assert rows[0].gain.seeds == (0,)
    (rows,) = compare_to_paper([ok_line(run_key="b0"), ok_line(run_key="b1", seed=1)]).values()
    assert rows[0].config == "fast K=0" and rows[0].senerf[0].n == 0 and rows[0].baseline[0].n == 2


def test_report_writes_the_per_scene_tables_and_where_we_differ(ok_line):
    lines = _suite_lines(ok_line) + _suite_lines(ok_line, scenes=(("scan24", 9.0),), protocol="dtu3@192")
    text = _report(lines)
    assert ("| lego | 3 | 16.20 ± 0.20 | 16.80 ± 0.30 | +0.60 ± 0.10 (p 0.009) | 14.67 -> 16.65 (+1.98) | "
            "0.500 ± 0.000 | 0.510 ± 0.000 | 0.68 -> 0.75 | - | - | 0.31 -> 0.24 |") in text
    assert "| **mean** | 3 | 17.70 ± 0.20 | 18.30 ± 0.30 | +0.60 ± 0.10 (p 0.009) | 17.20 -> 18.39 (+1.19) |" in text
    assert "| scan24 | 3 | 9.20 ± 0.20 | 9.80 ± 0.30 | +0.60 ± 0.10 (p 0.009) | - |" in text
    assert "- **dtu3@192**: ours 192x192, the paper's (it publishes no figures for this protocol)." in text
    # lines from before the schedule was recorded name their preset's commit, never today's definition of it
    assert "- **Budget, fast**: each field the fast preset of commit(s) c0ffee, K = 1 self-training" in text
    assert "- **LPIPS**: not measured" in text and 'README.md, "Where we depart from the paper"' in text
    assert "Made by:" in text and "`senerf-bench run`" in text
    recorded = _report([{**line, "schedule": "3000x1024"} for line in lines])
    assert "- **Budget, fast 3000x1024**: each field 3000 steps x 1024 rays, K = 1 self-training" in recorded


def test_report_sets_the_papers_rows_beside_ours_and_says_where_ours_came_from(ok_line):
    line = ok_line(scene="fern", protocol="llff3@504x378", psnr=17.0, commit="abc",
                   host={"cpu": "Fake CPU", "threads": 2, "torch": "9.9", "device": "cpu"},
                   bench_command=["senerf-bench", "run", "--scenes", "fern"])
    text = _report([line])
    assert "K-Planes (paper): 18.22" in text and "FreeNeRF: 19.63" in text and "| 17.00 (n=1) |" in text
    assert "ours 504x378" in text and "paper 504x378." in text and "`senerf-bench report r.jsonl`" in text
    assert "`senerf-bench run --scenes fern`" in text and "Commit(s): abc" in text
    assert "Machine(s): Fake CPU, 2 threads, torch 9.9, cpu" in text
    assert "ours 100x100" in _report([ok_line()]) and "not directly comparable" in _report([ok_line()])
    assert "No finished runs" in _report([{"run_key": "k", "status": "failed", "error": "x"}])


def test_report_final_table_has_final_iterations_and_paper_rows_only_for_our_methods(ok_line):
    records = [ok_line(run_key=method, method=method, iterations=2, iteration=i, psnr=15.0 + i)
               for method in ("senerf", "senerf-no-empty") for i in range(3)]
    rows = _final_table(_report(records))
    assert [r.split(" | ")[5] for r in rows] == ["2", "2"]              # the iter column
    senerf, ablation = sorted(rows, key=lambda r: "no-empty" in r)
    assert senerf.endswith("| SE-NeRF K-Planes (paper): 16.65 / 0.75 / 0.24 |") and ablation.endswith("| - |")
    assert "Per self-training iteration" in _report(records)
    assert "Per self-training iteration" not in _report([ok_line()])


def test_report_of_the_committed_lego_results(ok_line):
    records, _ = load_results(REPO / "benchmarks" / "results" / "lego-extreme3@100.jsonl")
    text = _report(records)
    for needle in ("### synthetic-extreme3@100", "Does each slower preset buy PSNR?", "Ablations and analyses",
                   "K-Planes (paper): 14.67 / 0.68 / 0.31"):
        assert needle in text, needle


def test_report_sums_each_runs_phases_over_its_iterations_and_averages_the_runs(ok_line):
    phases = lambda train, render: dict(train=train, pseudo_render=render, features=0.0, reliability=0.0,   # noqa: E731
                                        evaluation=1.0)
    lines = [ok_line(run_key="s0", method="senerf", iterations=1, iteration=0, phases=phases(10.0, 0.0)),
             ok_line(run_key="s0", method="senerf", iterations=1, iteration=1, phases=phases(20.0, 4.0)),
             ok_line(run_key="s1", method="senerf", iterations=1, iteration=0, seed=1, phases=phases(12.0, 0.0)),
             ok_line(run_key="s1", method="senerf", iterations=1, iteration=1, seed=1, phases=phases(22.0, 6.0)),
             ok_line(run_key="old")]   # a line from before phases were recorded
    text = make_report(lines, ["senerf-bench", "report"])
    assert "| lego | senerf | fast | 2 | 32.0 | 5.0 | 0.0 | 0.0 | 2.0 |" in text
    assert "| lego | baseline |" not in text.split("Seconds per phase")[1]
