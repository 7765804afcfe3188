"""senerf: Self-Evolving NeRF for few-shot novel view synthesis.

``senerf.fit(scene_dir, out, ...)`` fits a scene folder and writes its run folder (:mod:`senerf.pipeline`).
Importing :mod:`senerf` or :mod:`senerf.geometry` never imports torch; the torch parts live in
:mod:`senerf.fields`, :mod:`senerf.train` and :mod:`senerf.selftrain`.
"""

__version__ = "0.2.0"
__all__ = ["__version__", "fit", "FitResult"]


def __getattr__(name: str):
    """``senerf.fit`` and ``senerf.FitResult``, imported on first use (``import senerf`` stays light)."""
    if name in ("fit", "FitResult"):
        from senerf import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module 'senerf' has no attribute {name!r}")
