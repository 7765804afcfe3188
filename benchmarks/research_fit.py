"""``senerf-fit`` with settings its command line does not expose, for the research runs in BENCHMARKS.md.

Environment (each optional):

* ``SENERF_ST``: JSON object of :class:`senerf.config.SelfTrainConfig` fields, applied over what the command line
  sets (e.g. ``'{"lambda_prior": 0.05}'``);
* ``SENERF_TRAIN``: JSON object of :class:`senerf.config.TrainConfig` fields (teacher and students alike);
* ``SENERF_KEEP_KNOWN``: force the known views' features lazy, keeping this many views at full size (what
  :func:`senerf.selftrain.known_view_features` does when memory is short), for timing that path.

Usage::

    SENERF_ST='{"lambda_prior": 0.05}' python benchmarks/research_fit.py $LEGO --protocol extreme \\
        --downscale 4 --preset fast --seed 0 --out runs/prior05/s0

The overrides are part of the run's settings (``run.json``, ``metrics.json``'s ``config``), so a folder made with
one override is never resumed with another.  In Python, ``senerf.fit(..., selftrain={...}, train={...})`` does the
same.
"""

from __future__ import annotations

import json
import os
import sys

__all__ = ["overrides_from_env", "install", "main"]


def overrides_from_env(environ=os.environ) -> tuple[dict, dict, int | None]:
    """``(selftrain, train, keep_known)`` from the environment (see the module doc); ValueError on anything but
    JSON objects and a non-negative integer."""
    out = []
    for name in ("SENERF_ST", "SENERF_TRAIN"):
        value = json.loads(environ.get(name, "{}"))
        if not isinstance(value, dict):
            raise ValueError(f"{name} must be a JSON object, got {value!r}")
        out.append(value)
    keep = environ.get("SENERF_KEEP_KNOWN")
    if keep is not None and not keep.isdigit():
        raise ValueError(f"SENERF_KEEP_KNOWN must be an integer >= 0, got {keep!r}")
    return out[0], out[1], None if keep is None else int(keep)


def install(selftrain: dict, train: dict, keep_known: int | None) -> None:
    """Make ``senerf-fit`` (through :func:`senerf.pipeline.fit`) run with these overrides."""
    import senerf.pipeline as pipeline
    import senerf.selftrain.features as features
    import senerf.selftrain.loop as loop

    fit = pipeline.fit

    def fit_with_overrides(*args, **kwargs):
        kwargs["selftrain"] = {**(kwargs.get("selftrain") or {}), **selftrain}
        kwargs["train"] = {**(kwargs.get("train") or {}), **train}
        return fit(*args, **kwargs)

    pipeline.fit = fit_with_overrides
    if keep_known is not None:
        def forced(extractor, images, memory_bytes=None):
            view_bytes = 4 * images.shape[1] * images.shape[2] * extractor.channels
            memory = int((keep_known + 0.5) * view_bytes / features.EAGER_FEATURES_MEMORY_SHARE)
            return features.known_view_features(extractor, images, memory_bytes=memory)

        loop.known_view_features = forced


def main(argv: list[str] | None = None, environ=None) -> int:
    import senerf.cli as cli

    install(*overrides_from_env(os.environ if environ is None else environ))
    return cli.main(sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    sys.exit(main())
