"""The one exception type for bad user input (no torch import here).

Every loader and command raises :class:`InputError` for problems in what a user
gave us: a missing file, a malformed field, a non-rigid pose, an out-of-range
view index.  Its message is one line that names the file and the field, so the
command line can print it and exit with status 2 without a traceback.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["InputError"]


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
