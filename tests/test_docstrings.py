"""Every ``senerf`` module whose docstrings hold ``>>>`` examples runs them (doctest).

Modules are found by walking the package and reading each module's source, so a new module with examples
is picked up without touching this file (a few modules' own test files run their examples too; the
repetition costs about a second).  Examples that need the benchmark data run in their own test below.
"""

from __future__ import annotations

import doctest
import importlib
import importlib.util
import pkgutil
from pathlib import Path

import pytest

import senerf


#: module -> the test below that runs its examples (they are '+SKIP' in the module: they need the benchmark
#: data, so plain doctest attempts none)
NEEDS_DATA = {"senerf.data.load": "test_data_examples_hold_on_the_benchmark_data"}

FLAGS = doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS


def _source(name: str) -> str:
    spec = importlib.util.find_spec(name)
    return Path(spec.origin).read_text(encoding="utf-8") if spec and spec.origin else ""


def _modules_with_examples() -> list[str]:
    """Every module of the package whose source holds a ``>>>`` example (found without importing it)."""
    names = [senerf.__name__] + [m.name for m in pkgutil.walk_packages(senerf.__path__, senerf.__name__ + ".")]
    return sorted(name for name in names if ">>>" in _source(name))


WITH_EXAMPLES = _modules_with_examples()
HERE = [name for name in WITH_EXAMPLES if name not in NEEDS_DATA]


def test_discovery_finds_the_known_modules():
    assert {"senerf.geometry.warp", "senerf.config", "senerf.runfolder"} <= set(HERE)
    assert "senerf.errors" in HERE and set(NEEDS_DATA) <= set(WITH_EXAMPLES)
    assert all(callable(globals().get(test)) for test in NEEDS_DATA.values())


@pytest.mark.parametrize("name", HERE)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=FLAGS)
    assert result.attempted > 0, f"{name}: no example ran (all skipped?)"
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"


def test_data_examples_hold_on_the_benchmark_data(shared_data, monkeypatch):
    """``senerf.data.load``'s examples are skipped (they read ``data/nerf_synthetic/lego``, relative to the
    folder that holds the benchmark data): run them un-skipped there, so their printed values stay true."""
    import senerf.data.load as load

    monkeypatch.chdir(shared_data.parent)
    if not Path("data/nerf_synthetic/lego").is_dir():
        pytest.skip(f"no nerf_synthetic/lego in {shared_data}")
    tests = [t for t in doctest.DocTestFinder().find(load) if t.examples]
    assert tests
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in tests:
        for example in test.examples:
            example.options.pop(doctest.SKIP, None)
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.attempted > 0 and result.failed == 0
