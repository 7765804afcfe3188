"""``senerf-fit`` with settings its command line does not expose, for the research runs in BENCHMARKS.md.

Environment (each optional):

* ``SENERF_ST``: JSON object of :class:`senerf.selftrain.SelfTrainConfig` fields, applied over what the
  command line sets (e.g. ``'{"lambda_prior": 0.05}'``);
* ``SENERF_STUDENT``: JSON object of :class:`senerf.train.TrainConfig` fields for the students only (the
  teacher keeps the preset's), e.g. ``'{"steps": 1200}'``;
* ``SENERF_KEEP_KNOWN``: force the known views' features lazy, keeping this many views at full size (what
  :func:`senerf.selftrain.known_view_features` does when memory is short), for timing that path.

Usage::

    SENERF_ST='{"lambda_prior": 0.05}' python benchmarks/research_fit.py $LEGO --protocol extreme \\
        --downscale 4 --preset fast --seed 0 --out runs/prior05/s0

Every override is recorded in the run's ``metrics.json`` (``config.selftrain`` / ``config.student``), and the
resume check sees it, so a folder made with one override is never resumed with another.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys

__all__ = ["overrides_from_env", "install", "main"]


def overrides_from_env(environ=os.environ) -> tuple[dict, dict, int | None]:
    """``(selftrain, student, keep_known)`` from the environment (see the module doc); ValueError on
    anything but JSON objects and a non-negative integer."""
    out = []
    for name in ("SENERF_ST", "SENERF_STUDENT"):
        value = json.loads(environ.get(name, "{}"))
        if not isinstance(value, dict):
            raise ValueError(f"{name} must be a JSON object, got {value!r}")
        out.append(value)
    keep = environ.get("SENERF_KEEP_KNOWN")
    if keep is not None and (not keep.isdigit()):
        raise ValueError(f"SENERF_KEEP_KNOWN must be an integer >= 0, got {keep!r}")
    return out[0], out[1], None if keep is None else int(keep)


def install(selftrain: dict, student: dict, keep_known: int | None) -> None:
    """Make ``senerf.cli.main`` build its self-training run with these overrides."""
    import senerf.cli as cli
    import senerf.selftrain.controller as controller
    import senerf.selftrain.features as features
    from senerf.selftrain import SelfTrainConfig, run_selftraining

    def make_config(**kw):
        return SelfTrainConfig(**{**kw, **selftrain})

    def run(scene, train_idx, test_idx, model, train_cfg, cfg, out, **kw):
        student_cfg = dataclasses.replace(train_cfg, **student) if student else None
        return run_selftraining(scene, train_idx, test_idx, model, train_cfg, cfg, out, student_cfg=student_cfg, **kw)

    cli._selftrain_available = lambda: ((make_config, run), None)
    if keep_known is not None:
        def forced(extractor, images, memory_bytes=None):
            view_bytes = 4 * images.shape[1] * images.shape[2] * extractor.channels
            memory = int((keep_known + 0.5) * view_bytes / features.EAGER_FEATURES_MEMORY_SHARE)
            return features.known_view_features(extractor, images, memory_bytes=memory)

        controller.known_view_features = forced


def main(argv: list[str] | None = None, environ=None) -> int:
    import senerf.cli as cli

    install(*overrides_from_env(os.environ if environ is None else environ))
    return cli.main(sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    sys.exit(main())
