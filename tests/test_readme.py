"""The README's examples run, and CI runs exactly the README's test command."""

from __future__ import annotations

import re

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]

README = (REPO_ROOT / "README.md").read_text()


def test_readme_python_examples_run():
    blocks = re.findall(r"```python\n(.*?)```", README, re.S)
    assert blocks, "README has no python example"
    for block in blocks:
        exec(compile(block, "README.md", "exec"), {})


def test_ci_runs_the_readme_test_command():
    test_lines = [line for line in README.splitlines() if "python -m pytest" in line and "pip install" in line]
    assert len(test_lines) == 1, test_lines
    readme_cmd = test_lines[0].strip()
    ci = (REPO_ROOT / ".ci" / "run").read_text()
    assert readme_cmd in ci, f"{readme_cmd!r} not in .ci/run"
