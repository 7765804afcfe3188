"""Tests of senerf/geometry/__init__.py: import hygiene and runnable docstring examples."""

import doctest
import importlib
import subprocess
import sys

import pytest

import senerf.geometry as geometry

MODULES = ["intrinsics", "poses", "spherical", "rays", "projection", "warp"]


def test_import_does_not_import_torch():
    code = "import senerf.geometry; import sys; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_all_names_exist():
    for name in geometry.__all__:
        assert hasattr(geometry, name), name


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    mod = importlib.import_module(f"senerf.geometry.{name}")
    result = doctest.testmod(mod, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0
