"""The markdown report: our figures beside the published ones, with where they came from."""

from __future__ import annotations

from pathlib import Path

from senerf.bench.report import PAPER_NUMBERS, make_report
from senerf.bench.results import load_results

REPO = Path(__file__).resolve().parents[2]

#: REFERENCE.md section 6 ("Numbers to beat"), copied by hand: (family, scene, label) -> (PSNR, SSIM, LPIPS).
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
    assert {(r.family, r.scene, r.label): (r.psnr, r.ssim, r.lpips) for r in PAPER_NUMBERS} == _REFERENCE_FIGURES


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
