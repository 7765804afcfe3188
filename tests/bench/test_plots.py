"""Analysis helpers: angular distance to the training views, plot files."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest

from senerf.bench.plots import nearest_view_angles, plot_gain_vs_teacher, plot_mask_quality, plot_psnr_vs_angle


def _pose_at(center):
    c2w = np.eye(4)
    c2w[:3, 3] = center
    return c2w


def test_nearest_view_angles_known_geometry():
    train = np.stack([_pose_at([4, 0, 0]), _pose_at([0, 4, 0])])
    test = np.stack([_pose_at([2, 0, 0]), _pose_at([0, 0, 3]), _pose_at([1, 1, 0]), _pose_at([-5, 0, 0])])
    np.testing.assert_allclose(nearest_view_angles(train, test), [0.0, 90.0, 45.0, 90.0], atol=1e-9)
    shifted = nearest_view_angles(train + _pose_at([1, 1, 1]) - np.eye(4), test + _pose_at([1, 1, 1]) - np.eye(4),
                                  center=(1, 1, 1))
    np.testing.assert_allclose(shifted, [0.0, 90.0, 45.0, 90.0], atol=1e-9)
    with pytest.raises(ValueError):
        nearest_view_angles(np.eye(4), test)


def test_analysis_plots_write_pngs(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 90, 20)
    p1 = plot_psnr_vs_angle({"senerf": a}, {"senerf": 25 - 0.1 * a}, tmp_path / "angle.png")
    recs = [{"feature": f, "threshold": t, "precision": rng.random(), "recall": rng.random(),
             "fpr": rng.random()}
            for f in ("vgg19", "daisy") for t in ("adaptive", "fixed")]
    p2 = plot_mask_quality(recs, tmp_path / "mask.png")
    from senerf.bench.ladder import TeacherFit

    fits = [TeacherFit("lego", "p", "senerf", "fast K=1", (0, 1, 2), (15.0, 16.0, 17.0), (3.0, 2.0, 1.5),
                       -0.75, 85 / 6, -0.98, 0.12),
            TeacherFit("lego", "p", "senerf", "balanced K=3", (0, 1), (15.0, 15.0), (3.0, 3.2), None, None, None, None)]
    p3 = plot_gain_vs_teacher(fits, tmp_path / "gain.png")
    for p in (p1, p2, p3):
        assert iio.imread(p).shape[-1] in (3, 4)
    with pytest.raises(ValueError):
        plot_psnr_vs_angle({"x": a}, {"x": a[:3]}, tmp_path / "bad.png")
    # a PNG at the path as given, even without the suffix (matplotlib would otherwise add one)
    bare = plot_psnr_vs_angle({"senerf": a}, {"senerf": 25 - 0.1 * a}, tmp_path / "no_suffix")
    assert bare == tmp_path / "no_suffix" and bare.is_file() and not (tmp_path / "no_suffix.png").exists()
    assert iio.imread(bare, extension=".png").shape[-1] in (3, 4)


@pytest.mark.parametrize("n", [1, 10, 11, 20, 21, 40])
def test_angle_plot_colours_are_distinct(n):
    from matplotlib.colors import to_rgba

    from senerf.bench.plots import _distinct_colours

    rgba = [to_rgba(c) for c in _distinct_colours(n)]
    assert len(rgba) == n and len(set(rgba)) == n


def test_angles_command_on_lego(lego_dir, tmp_path, capsys):
    from senerf.bench.cli import main
    from senerf.bench.plots import line_view_angles
    from senerf.bench.results import append_lines
    from senerf.data import load_scene

    line = {"run_key": "k", "attempt": "a", "status": "ok", "scene": "lego", "protocol": "synthetic-extreme3@100",
            "method": "senerf", "preset": "fast", "seed": 0, "iterations": 1, "iteration": 1, "psnr": 18.0,
            "views": [0, 1, 51], "test_views": [0, 200, 250, 300], "per_view": {"psnr": [30.0, 15.0, 14.0, 13.0]}}
    c2w = load_scene(lego_dir, downscale=8).c2w
    angles, psnr = line_view_angles(line, c2w)
    assert angles.shape == (4,) and angles[0] == pytest.approx(0.0, abs=1e-6) and np.all(angles[1:] > 0)
    assert np.all(angles <= 180) and psnr.tolist() == [30.0, 15.0, 14.0, 13.0]
    append_lines(tmp_path / "r.jsonl", [line])
    out = tmp_path / "angles.png"
    assert main(["angles", str(tmp_path / "r.jsonl"), "--scene", str(lego_dir), "--protocol",
                 "synthetic-extreme3@100", "--out", str(out)]) == 0
    assert iio.imread(out).ndim == 3
    # --methods filters the lines: none left is a one-line error naming the results file
    assert main(["angles", str(tmp_path / "r.jsonl"), "--scene", str(lego_dir), "--protocol",
                 "synthetic-extreme3@100", "--out", str(tmp_path / "none.png"), "--methods", "baseline"]) == 2
    assert not (tmp_path / "none.png").exists()
    # a place the kernel refuses: one line naming --out, exit 2 (before: a traceback from savefig, exit 1)
    capsys.readouterr()
    assert main(["angles", str(tmp_path / "r.jsonl"), "--scene", str(lego_dir), "--protocol",
                 "synthetic-extreme3@100", "--out", "/proc/senerf-bench-test.png"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--out" in err and "Traceback" not in err


def test_angles_iterations_keeps_baselines_and_runs_of_k_iterations(lego_dir, tmp_path, monkeypatch):
    # the committed angles.png (one SE-NeRF iteration) could not be redrawn once 3-iteration runs of the same
    # method and preset were in the results file: their lines were drawn too
    import senerf.bench.cli as cli
    from senerf.bench.results import append_lines

    base = {"attempt": "a", "status": "ok", "scene": "lego", "protocol": "synthetic-extreme3@100", "preset": "fast",
            "seed": 0, "psnr": 18.0, "views": [0, 1, 51], "test_views": [0, 200], "per_view": {"psnr": [30.0, 15.0]}}
    lines = [{**base, "run_key": "b", "method": "baseline", "iterations": 0, "iteration": 0},
             {**base, "run_key": "s1", "method": "senerf", "iterations": 1, "iteration": 1},
             {**base, "run_key": "s3", "method": "senerf", "iterations": 3, "iteration": 3}]
    append_lines(tmp_path / "r.jsonl", lines)
    drawn = []
    monkeypatch.setattr(cli, "plot_psnr_vs_angle", lambda angles, psnr, out, title: drawn.append(sorted(angles)) or out)
    args = ["angles", str(tmp_path / "r.jsonl"), "--scene", str(lego_dir), "--protocol", "synthetic-extreme3@100",
            "--out", str(tmp_path / "a.png")]
    assert cli.main(args) == 0 and cli.main(args + ["--iterations", "1"]) == 0
    assert drawn == [["baseline fast", "senerf fast iter 1", "senerf fast iter 3"],
                     ["baseline fast", "senerf fast iter 1"]]
    assert cli.main(args + ["--iterations", "2", "--methods", "senerf"]) == 2     # nothing left: one line, exit 2
    assert cli.main(args + ["--iterations", "0"]) == 0 and drawn[-1] == ["baseline fast"]   # baselines alone


def test_angles_names_a_line_whose_views_do_not_fit_the_scene(lego_dir, tmp_path, capsys):
    # test_views past the scene's views, or a line without per_view, ended in an IndexError / ValueError
    # traceback (so at 79e672f)
    from senerf.bench.cli import main
    from senerf.bench.results import append_lines

    line = {"run_key": "k", "attempt": "a", "status": "ok", "scene": "lego", "protocol": "synthetic-extreme3@100",
            "method": "senerf", "preset": "fast", "seed": 0, "iterations": 1, "iteration": 1, "psnr": 18.0,
            "views": [0, 1, 51], "test_views": [0, 9999], "per_view": {"psnr": [30.0, 15.0]}}
    for name, edit in (("far", {}), ("noview", {"test_views": [0, 200], "per_view": None})):
        results = tmp_path / f"{name}.jsonl"
        append_lines(results, [{**line, **edit}])
        assert main(["angles", str(results), "--scene", str(lego_dir), "--protocol", "synthetic-extreme3@100",
                     "--out", str(tmp_path / f"{name}.png")]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"senerf-bench: error: {results}: run k: ") and "\n" not in err
        assert not (tmp_path / f"{name}.png").exists()
