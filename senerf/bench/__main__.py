"""``python -m senerf.bench`` = ``senerf-bench``."""

from .cli import console

console()
