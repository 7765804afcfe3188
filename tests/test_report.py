"""senerf.report: the run summary figure (which views it picks, what it shows, its errors)."""

from __future__ import annotations

import imageio.v2 as imageio
import numpy as np
import pytest

from senerf.report import binned_means, pick_views, plot_run_summary


def test_pick_views_nearest_median_farthest_by_angle_else_best_median_worst_by_psnr():
    angles = np.array([30.0, 10.0, 50.0, 20.0, 40.0])
    assert pick_views(angles, np.zeros(5)) == [1, 0, 2]            # 10, 30, 50 degrees
    assert pick_views(None, np.array([1.0, 5.0, 3.0])) == [1, 2, 0]  # 5, 3, 1 dB
    assert pick_views(np.array([7.0]), np.zeros(1)) == [0]
    assert pick_views(np.array([9.0, 3.0]), np.zeros(2)) == [1, 0]
    assert pick_views(np.array([]), np.zeros(0)) == []
    assert pick_views(angles, np.zeros(5), k=5) == [1, 3, 0, 4, 2]


def _colour(iteration: int, position: int) -> tuple[int, int, int]:
    return (40 + 50 * iteration, 20 + 30 * position, 200 - 60 * iteration)


def _run(tmp_path, n=5, iterations=(0, 2)):
    rows = []
    for it in iterations:
        folder = tmp_path / f"iter_{it}" / "test"
        folder.mkdir(parents=True)
        for pos in range(n):
            imageio.imwrite(folder / f"rgb_{pos:03d}.png", np.full((12, 12, 3), _colour(it, pos), np.uint8))
        rows.append(dict(iteration=it, psnr=15.0 + it, ssim=0.6 + 0.01 * it,
                         reliable_fraction=None if it == 0 else 0.4,
                         per_view=dict(psnr=[15.0 + it + 0.1 * p for p in range(n)])))
    return dict(scene="toy", iterations=rows)


def _has_colour(image: np.ndarray, rgb) -> bool:
    return bool(np.all(image[..., :3] == np.asarray(rgb, np.uint8), axis=-1).sum() > 50)


def test_summary_shows_the_picked_views_of_the_first_and_last_iteration(tmp_path):
    metrics = _run(tmp_path)
    angles = np.array([30.0, 10.0, 50.0, 20.0, 40.0])
    gt_colour = {p: (255 - 20 * p, 255, 0) for p in range(5)}
    out = plot_run_summary(metrics, tmp_path, tmp_path / "summary.png", angles_deg=angles,
                           ground_truth=lambda p: np.full((12, 12, 3), gt_colour[p], np.float64) / 255.0)
    image = imageio.imread(out)
    assert image.shape[1] == 1200 and image.shape[0] > 900   # 12 in wide at 100 dpi, three rows of views
    for pos in range(5):
        shown = pos in (1, 0, 2)
        assert _has_colour(image, _colour(0, pos)) == shown, pos
        assert _has_colour(image, _colour(2, pos)) == shown, pos
        assert _has_colour(image, gt_colour[pos]) == shown, pos
    assert not list(tmp_path.glob("*.tmp*"))


def test_summary_of_a_baseline_only_run_and_missing_renders(tmp_path):
    metrics = _run(tmp_path, n=3, iterations=(0,))
    (tmp_path / "iter_0" / "test" / "rgb_001.png").unlink()   # a missing render is left blank
    out = plot_run_summary(metrics, tmp_path, tmp_path / "s.png")
    image = imageio.imread(out)
    # no angles: best, median, worst by iteration 0's PSNR (positions 2, 1, 0); no ground truth column
    assert _has_colour(image, _colour(0, 2)) and _has_colour(image, _colour(0, 0))
    assert not _has_colour(image, _colour(0, 1))


def test_summary_refuses_inconsistent_metrics(tmp_path):
    metrics = _run(tmp_path, n=3)
    with pytest.raises(ValueError, match="3 test views"):
        plot_run_summary(metrics, tmp_path, tmp_path / "s.png", angles_deg=np.zeros(4))
    metrics["iterations"][1]["per_view"]["psnr"] = [1.0]
    with pytest.raises(ValueError, match="row 1 lacks"):
        plot_run_summary(metrics, tmp_path, tmp_path / "s.png")
    del metrics["iterations"][0]["per_view"]
    with pytest.raises(ValueError, match="row 0 lacks"):
        plot_run_summary(metrics, tmp_path, tmp_path / "s.png")
    with pytest.raises(ValueError, match="no iteration rows"):
        plot_run_summary(dict(iterations=[]), tmp_path, tmp_path / "s.png")
    assert not (tmp_path / "s.png").exists()


def test_binned_means_by_hand():
    a = np.array([1.0, 14.0, 16.0, 44.0, 29.9, 0.0])
    p = np.array([1.0, 3.0, 10.0, 7.0, 20.0, 2.0])
    # bins [0, 15): 1, 14, 0 -> (1 + 3 + 2) / 3; [15, 30): 16, 29.9 -> 15; [30, 45): 44 -> 7
    assert binned_means(a, p, 15.0) == ([7.5, 22.5, 37.5], [2.0, 15.0, 7.0])
    assert binned_means(np.array([45.0]), np.array([3.0]), 15.0) == ([52.5], [3.0])   # an edge opens its bin
    assert binned_means(np.array([]), np.array([]), 15.0) == ([], [])


def test_summary_survives_a_perfect_render(tmp_path):
    """No angles: the histogram of per-view changes skips a perfect render's inf (numpy cannot bin it)."""
    metrics = _run(tmp_path, n=3)
    metrics["iterations"][1]["per_view"]["psnr"][0] = float("inf")
    metrics["test_views"] = [7, 11, 13]
    out = plot_run_summary(metrics, tmp_path, tmp_path / "s.png")
    assert imageio.imread(out).shape[1] == 1200


def test_huge_images_are_shown_strided(tmp_path):
    from senerf.report import _shrink

    rows, cols = np.meshgrid(np.arange(3024), np.arange(4032), indexing="ij")
    image = np.stack([rows % 251, cols % 251, (rows + cols) % 7], axis=-1).astype(np.uint8)
    small = _shrink(image)
    assert small.shape == (275, 367, 3)                      # stride ceil(4032 / 400) = 11: ceil(3024 / 11)
    assert small[1, 2].tolist() == image[11, 22].tolist()
    assert _shrink(image[:400, :300]).shape == (400, 300, 3)  # already small: unchanged


def test_rows_without_an_integer_iteration_are_a_value_error(tmp_path):
    metrics = _run(tmp_path, n=2)
    del metrics["iterations"][1]["iteration"]
    with pytest.raises(ValueError, match="row 1 lacks its iteration"):
        plot_run_summary(metrics, tmp_path, tmp_path / "s.png")


def _ground_truth_titles(tmp_path, monkeypatch, metrics, name: str) -> list[str]:
    """The ground-truth panels' titles of ``plot_run_summary`` on ``metrics`` (set_title recorded)."""
    import matplotlib.axes

    titles = []
    real = matplotlib.axes.Axes.set_title
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title", lambda ax, text, *a, **k: (titles.append(text),
                                                                                       real(ax, text, *a, **k))[1])
    plot_run_summary(metrics, tmp_path, tmp_path / name, ground_truth=lambda p: np.zeros((12, 12, 3)))
    monkeypatch.undo()
    return [t for t in titles if t.startswith("ground truth")]


def test_views_are_titled_with_their_photo_when_metrics_name_it(tmp_path, monkeypatch):
    # Catches: a view titled by its index among all the scene's views ("image 309") instead of its photo.
    metrics = _run(tmp_path)
    shown = _ground_truth_titles(tmp_path, monkeypatch, metrics, "a.png")
    assert sorted(shown) == [f"ground truth (test view {k})" for k in (0, 2, 4)]   # no file names: the position
    metrics["test_images"] = [f"test/r_{k}.png" for k in range(5)]
    shown = _ground_truth_titles(tmp_path, monkeypatch, metrics, "b.png")
    assert len(shown) == 3 and all(t in {f"ground truth (test/r_{k}.png)" for k in range(5)} for t in shown)
    # a long path keeps its last 29 characters
    metrics["test_images"] = [f"a/very/long/folder/name/for/the/photos/IMG_{k:04d}.JPG" for k in range(5)]
    shown = _ground_truth_titles(tmp_path, monkeypatch, metrics, "c.png")
    assert len(shown) == 3 and all(t.startswith("ground truth (...e/for/the/photos/IMG_000") for t in shown), shown


def test_a_32_character_name_is_whole_and_a_list_of_the_wrong_length_is_ignored(tmp_path, monkeypatch):
    metrics = _run(tmp_path)
    metrics["test_images"] = [f"photos/{k}/" + "x" * 15 + "_IMG.png" for k in range(5)]
    assert {len(n) for n in metrics["test_images"]} == {32}   # at the limit: shown whole
    shown = _ground_truth_titles(tmp_path, monkeypatch, metrics, "a.png")
    assert len(shown) == 3 and all(t[len("ground truth ("):-1] in metrics["test_images"] for t in shown), shown
    metrics["test_images"] = metrics["test_images"][:4]   # not one name per test view: the positions instead
    shown = _ground_truth_titles(tmp_path, monkeypatch, metrics, "b.png")
    assert len(shown) == 3 and all(t.startswith("ground truth (test view ") for t in shown), shown
