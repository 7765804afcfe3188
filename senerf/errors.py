"""The one exception type for bad user input, and what counts as a number in it (no torch or NumPy import here).

Every loader and command raises :class:`InputError` for problems in what a user gave us; the command line prints
its one line and exits with status 2 without a traceback.
"""

from __future__ import annotations

import math
import numbers
from pathlib import Path

__all__ = ["InputError", "is_number"]


class InputError(ValueError):
    """Bad user input, reported as ``"<file>: <field>: <problem>"``.

    Args:
        problem: what is wrong, one line.
        file: the file (or folder) the problem is in, or ``None``.
        field: the field inside that file (``"frames[3].transform_matrix"``), or ``None``.

    Example:
        >>> str(InputError("must be positive", file="scene/transforms.json", field="fl_x"))
        'scene/transforms.json: fl_x: must be positive'
    """

    def __init__(self, problem: str, file: str | Path | None = None, field: str | None = None):
        self.problem = " ".join(str(problem).split())
        self.file = None if file is None else str(file)
        self.field = field
        parts = [p for p in (self.file, self.field, self.problem) if p]
        super().__init__(": ".join(parts))


def is_number(value) -> bool:
    """A finite real number (Python or NumPy), not a bool: what a weight, a range or a threshold may be.

    Example:
        >>> [is_number(v) for v in (1, 0.5, -2.0)]
        [True, True, True]
        >>> [is_number(v) for v in (True, "1", float("nan"), float("inf"), None, 1j, 10 ** 400)]
        [False, False, False, False, False, False, False]
    """
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:   # an int beyond float's range: no setting can use it
        return False
