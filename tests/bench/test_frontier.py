"""benchmarks/frontier.py through the harness with the fake fit: dry run, then a full (fake) run."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio

FRONTIER = Path(__file__).resolve().parents[2] / "benchmarks" / "frontier.py"


def test_frontier_dry_run_and_fake_run(blender_scene, fake_fit_command, tmp_path, capsys, load_script):
    frontier = load_script("frontier")
    out = tmp_path / "fr"
    base = ["--scene", str(blender_scene), "--out", str(out), "--iterations", "2"]
    assert frontier.main([*base, "--dry-run"]) == 0
    fits = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("senerf-fit ")]
    assert len(fits) == 2 * 2                              # baseline and SE-NeRF x 2 presets
    assert all("--protocol extreme --downscale 8" in f for f in fits)
    assert {f.split("--preset ")[1].split()[0] for f in fits} == {"fast", "balanced"}
    assert frontier.main([*base, "--fit-command", shlex.join(fake_fit_command), "--workers", "2"]) == 0
    text = (out / "frontier.md").read_text()
    assert "16.65 / 0.75 / 0.24" in text and "python benchmarks/frontier.py" in text
    assert iio.imread(out / "frontier.png").ndim == 3


def test_frontier_uses_each_presets_iterations_and_methods(blender_scene, tmp_path, capsys, load_script):
    from senerf.config import PRESETS

    frontier = load_script("frontier")
    assert frontier.main(["--scene", str(blender_scene), "--out", str(tmp_path / "fr"), "--dry-run",
                          "--methods", "senerf", "senerf-no-prior"]) == 0
    fits = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("senerf-fit ")]
    assert len(fits) == 2 * 2 and sum("--no-prior" in f for f in fits) == 2
    for f in fits:
        preset = f.split("--preset ")[1].split()[0]
        assert f"--iterations {PRESETS[preset].iterations} " in f


def test_frontier_reports_bad_input_in_one_line(blender_scene, tmp_path):
    proc = subprocess.run([sys.executable, str(FRONTIER), "--scene", str(blender_scene), "--out", str(tmp_path / "fr"),
                           "--methods", "nosuch"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.startswith("frontier: error: method: unknown method 'nosuch'")
