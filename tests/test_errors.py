"""senerf.errors.InputError: one ``file: field: problem`` line, the parts given, whatever the problem text."""

from __future__ import annotations

from pathlib import Path

import pytest

from senerf.errors import InputError


@pytest.mark.parametrize("file, field, expected", [
    ("scene/transforms.json", "fl_x", "scene/transforms.json: fl_x: must be positive"),
    (Path("scene") / "transforms.json", None, "scene/transforms.json: must be positive"),
    (None, "--steps", "--steps: must be positive"),
    (None, None, "must be positive"),
])
def test_message_names_the_file_and_the_field_given(file, field, expected):
    exc = InputError("must be positive", file=file, field=field)
    assert str(exc) == expected
    assert exc.problem == "must be positive" and exc.field == field
    assert exc.file == (None if file is None else "scene/transforms.json")  # a Path is kept as its text


def test_a_multi_line_problem_becomes_one_line():
    # the command line prints str(exc) as its one error line: newlines, tabs and runs of spaces collapse
    exc = InputError("bad value\n  in\tthe\r\nmatrix  ", file="a.json", field="frames[0]")
    assert exc.problem == "bad value in the matrix"
    assert str(exc) == "a.json: frames[0]: bad value in the matrix"


def test_is_a_value_error():
    # library callers (and argparse for a type converter) catch bad input as ValueError
    with pytest.raises(ValueError, match=r"^x\.json: must be a list$"):
        raise InputError("must be a list", file="x.json")


def test_is_number_takes_finite_reals_python_or_numpy_and_nothing_else():
    import numpy as np

    from senerf.errors import is_number

    for value in (0, -3, 0.5, 1e308, np.float32(0.5), np.float64(-2.0), np.int64(7), np.uint8(3)):
        assert is_number(value) is True, value
    for value in (True, np.True_, "0.5", None, 1j, [0.5], float("nan"), float("inf"), np.float32("inf"), 10 ** 400):
        assert is_number(value) is False, value


def test_errors_import_neither_torch_nor_numpy():
    import subprocess
    import sys

    code = ("import sys, senerf.errors as e; assert e.is_number(0.5); "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'numpy')); assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)
