"""senerf: Self-Evolving NeRF for few-shot novel view synthesis.

Importing :mod:`senerf` or :mod:`senerf.geometry` never imports torch; the
torch parts live in :mod:`senerf.fields`, :mod:`senerf.train` and
:mod:`senerf.selftrain`.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
