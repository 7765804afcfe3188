"""benchmarks/bench_fields.py's "fit" configuration is the field `senerf-fit` builds for lego at 100x100."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LEGO = ROOT.parent / "shared" / "data" / "nerf_synthetic" / "lego"


def _bench_configs():
    spec = importlib.util.spec_from_file_location("bench_fields", ROOT / "benchmarks" / "bench_fields.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.CONFIGS


@pytest.mark.skipif(not LEGO.is_dir(), reason=f"benchmark data not found at {LEGO}")
def test_fit_config_is_what_choose_model_picks_for_lego_at_100():
    from senerf.data import load_scene
    from senerf.data.fewshot import fewshot_split
    from senerf.fields import KPlanesField
    from senerf.train.model import choose_model

    scene = load_scene(LEGO, downscale=4)
    for protocol in ("extreme", "all"):
        model = choose_model(scene, fewshot_split(scene, protocol)[0], echo=lambda _: None)
        fit = _bench_configs()["fit"]
        assert (model.resolution, model.n_features, tuple(model.multires)) == \
            (fit["resolution"], fit["n_features"], tuple(fit["multires"]))
        # the bench builds KPlanesField with its constructor defaults for the decoder: same as the trainer
        import inspect
        assert inspect.signature(KPlanesField).parameters["hidden"].default == model.hidden
