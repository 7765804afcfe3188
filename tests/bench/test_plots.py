"""The frontier PNG of aggregates."""

from __future__ import annotations

import imageio.v3 as iio

from senerf.bench.plots import plot_frontier
from senerf.bench.summary import aggregate


def test_frontier_draws_presets_iterations_and_runs_whose_memory_was_not_measured(tmp_path, ok_line):
    lines = [ok_line(run_key=f"s{s}{p}", method="senerf", preset=p, seed=s, iterations=2, iteration=i,
                     psnr=15.0 + i + s, seconds_cumulative=10.0 * (i + 1), peak_memory_mib=None if p == "fast" else 9.0)
             for p in ("fast", "balanced") for s in range(2) for i in range(3)]
    lines += [ok_line(run_key=f"b{s}", seed=s, psnr=15.0 + s) for s in range(2)]
    path = plot_frontier(aggregate(lines), tmp_path / "frontier.png", "lego")
    assert path == tmp_path / "frontier.png" and iio.imread(path).ndim == 3


def test_frontier_is_written_at_the_path_as_given_with_its_folder(tmp_path, ok_line):
    bare = plot_frontier(aggregate([ok_line()]), tmp_path / "new" / "no_suffix")
    assert bare == tmp_path / "new" / "no_suffix" and not (tmp_path / "new" / "no_suffix.png").exists()
    assert iio.imread(bare, extension=".png").shape[-1] in (3, 4)
