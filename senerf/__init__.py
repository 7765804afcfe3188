"""senerf: Self-Evolving NeRF for few-shot novel view synthesis.

``senerf.fit(scene_dir, out, ...)`` fits a scene folder and writes its run folder (:mod:`senerf.pipeline`);
``senerf.load_run(out)`` loads it to render and query the field (:mod:`senerf.fitted`).
Importing :mod:`senerf` or :mod:`senerf.geometry` never imports torch; the torch parts live in
:mod:`senerf.fields`, :mod:`senerf.train` and :mod:`senerf.selftrain`.
"""

__version__ = "0.2.0"
__all__ = ["__version__", "fit", "FitResult", "load_run"]


def __getattr__(name: str):
    """``senerf.fit``, ``senerf.FitResult`` and ``senerf.load_run``, imported on first use (``import senerf``
    stays light)."""
    if name in ("fit", "FitResult"):
        from senerf import pipeline

        return getattr(pipeline, name)
    if name == "load_run":
        from senerf.fitted import load_run

        return load_run
    raise AttributeError(f"module 'senerf' has no attribute {name!r}")
