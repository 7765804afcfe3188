"""The driver: resume, retries, crash isolation, peak memory, timeouts; local and Ray through one path."""

from __future__ import annotations

import os
import sys

import pytest

from senerf.bench.execute import RunnerConfig, execute_run
from senerf.bench.executors import LocalExecutor
from senerf.bench.results import load_results, validate_line
from senerf.bench.runner import pending_specs, run_benchmark
from senerf.bench.specs import expand_specs


def _specs(scene, seeds=(0, 1, 2)):
    return expand_specs([str(scene)], ["synthetic-extreme3@100"], ["baseline", "senerf"], ["fast"],
                        list(seeds), iterations=2)


def _run(specs, tmp_path, fit, workers=2, **cfg_kw):
    cfg = RunnerConfig(runs_dir=str(tmp_path / "runs"), fit_command=fit, **cfg_kw)
    ex = LocalExecutor(workers)
    try:
        return run_benchmark(specs, ex, tmp_path / "results.jsonl", cfg, ["senerf-bench", "test"], commit="c0",
                             log=lambda s: None)
    finally:
        ex.shutdown()


def _psnr_by_key(records):
    return {(r["run_key"], r["iteration"]): r["psnr"] for r in records if r["status"] == "ok"}


def test_crash_costs_only_its_run_then_resume_retries_it(blender_scene, fake_fit_command, tmp_path):
    specs = _specs(blender_scene)
    first = _run(specs, tmp_path, fake_fit_command, env=(("FAKE_FIT_CRASH_SEEDS", "1"),))
    assert (first.ok, first.failed, first.skipped) == (4, 2, 0)
    records, bad = load_results(tmp_path / "results.jsonl")
    assert bad == 0
    failed = [r for r in records if r["status"] == "failed"]
    assert {r["seed"] for r in failed} == {1} and all("signal 9" in r["error"] for r in failed)
    for r in records:
        validate_line(r)
    kept = _psnr_by_key(records)
    # fake fit: PSNR = 20 + iteration + seed / 10, unchanged through the harness
    assert kept[(specs[0].key(), 0)] == pytest.approx(20.0)
    assert len(kept) == 2 * 1 + 2 * 3                      # baseline seeds 0, 2 (1 line) + senerf (3 lines)

    todo, skipped = pending_specs(specs, tmp_path / "results.jsonl")
    assert skipped == 4 and {s.seed for s in todo} == {1}
    second = _run(specs, tmp_path, fake_fit_command)
    assert (second.ok, second.failed, second.skipped) == (2, 0, 4)
    records2, _ = load_results(tmp_path / "results.jsonl")
    assert records2[:len(records)] == records             # earlier lines untouched
    assert len(_psnr_by_key(records2)) == 3 * 1 + 3 * 3
    third = _run(specs, tmp_path, fake_fit_command)
    assert (third.ok, third.failed, third.skipped) == (0, 0, 6)


def test_peak_memory_and_timing_measured(blender_scene, fake_fit_command, tmp_path):
    (spec,) = _specs(blender_scene, seeds=(0,))[:1]
    base = execute_run(spec, RunnerConfig(str(tmp_path / "a"), fake_fit_command))
    big = execute_run(spec, RunnerConfig(str(tmp_path / "b"), fake_fit_command,
                                         env=(("FAKE_FIT_ALLOC_MB", "200"),)))
    assert base["status"] == big["status"] == "ok"
    assert big["peak_memory_mib"] >= 200 > base["peak_memory_mib"] > 1
    assert big["peak_memory_mib"] - base["peak_memory_mib"] == pytest.approx(200, abs=30)
    slow = execute_run(spec, RunnerConfig(str(tmp_path / "c"), fake_fit_command,
                                          env=(("FAKE_FIT_SLEEP", "0.3"),)))
    assert slow["run_seconds"] >= 0.3 and slow["status"] == "ok"


def test_timeout_and_bad_metrics_fail_cleanly(blender_scene, fake_fit_command, tmp_path):
    spec = _specs(blender_scene, seeds=(0,))[1]            # senerf, 3 iterations
    out = execute_run(spec, RunnerConfig(str(tmp_path / "t"), fake_fit_command, timeout_s=0.5,
                                         env=(("FAKE_FIT_SLEEP", "5"),)))
    assert out["status"] == "failed" and "timed out" in out["error"] and out["run_seconds"] < 4
    quiet = (sys.executable, "-c", "import sys; sys.exit(0)")  # exits 0 but writes no metrics.json
    out = execute_run(spec, RunnerConfig(str(tmp_path / "q"), quiet))
    assert out["status"] == "failed" and "metrics" in out["error"]
    missing = execute_run(spec, RunnerConfig(str(tmp_path / "m"), ("/nonexistent/senerf-fit",)))
    assert missing["status"] == "failed" and missing["returncode"] == 127


# ---------------------------------------------------------------- Ray: the same driver, another executor
def _dies_for_seed_1(spec, cfg):
    """A run function whose *worker process* dies for seed 1 (not just its fit child)."""
    if spec.seed == 1:
        os._exit(3)
    return execute_run(spec, cfg)


@pytest.fixture(scope="module")
def ray_executor():
    ray = pytest.importorskip("ray", reason="ray not installed (optional [cluster] extra): Ray executor untested")
    from senerf.bench.executors import RayExecutor
    if ray.is_initialized():
        pytest.skip("a Ray instance is already running in this process")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ex = RayExecutor(address=None, num_cpus=2, cpus_per_run=1, max_retries=0)
    yield ex
    ex.shutdown()


def test_ray_and_local_give_the_same_results(ray_executor, blender_scene, fake_fit_command, tmp_path):
    specs = _specs(blender_scene, seeds=(0, 1))
    local = _run(specs, tmp_path / "local", fake_fit_command)
    cfg = RunnerConfig(runs_dir=str(tmp_path / "ray" / "runs"), fit_command=fake_fit_command)
    remote = run_benchmark(specs, ray_executor, tmp_path / "ray" / "results.jsonl", cfg, ["t"], commit="c0",
                           log=lambda s: None)
    assert (local.ok, remote.ok, remote.failed) == (4, 4, 0)
    rec_local, _ = load_results(tmp_path / "local" / "results.jsonl")
    rec_ray, _ = load_results(tmp_path / "ray" / "results.jsonl")
    assert _psnr_by_key(rec_local) == _psnr_by_key(rec_ray)
    assert all(r["peak_memory_mib"] > 1 for r in rec_ray)


def test_ray_lost_worker_costs_only_its_run(ray_executor, blender_scene, fake_fit_command, tmp_path):
    specs = _specs(blender_scene, seeds=(0, 1))
    cfg = RunnerConfig(runs_dir=str(tmp_path / "runs"), fit_command=fake_fit_command)
    out = run_benchmark(specs, ray_executor, tmp_path / "results.jsonl", cfg, ["t"], commit="c0",
                        log=lambda s: None, run_fn=_dies_for_seed_1)
    assert (out.ok, out.failed) == (2, 2)
    records, _ = load_results(tmp_path / "results.jsonl")
    lost = [r for r in records if r["status"] == "failed"]
    assert {r["seed"] for r in lost} == {1} and all(r["error"].startswith("worker lost") for r in lost)
    assert {r["seed"] for r in records if r["status"] == "ok"} == {0}


def test_metrics_from_another_protocol_are_rejected():
    from senerf.bench.execute import check_protocol
    from senerf.bench.specs import RunSpec
    spec = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "senerf", "fast", 0, 2)
    check_protocol(spec, {"resolution": [100, 100], "train_views": [51, 0, 1]})
    for bad, word in (({"resolution": [200, 200], "train_views": [0, 1, 51]}, "resolution"),
                      ({"resolution": [100, 100], "train_views": [0, 1]}, "3 views"),
                      ({"resolution": [100, 100], "train_views": [0, 1, 50]}, "differ")):
        with pytest.raises(ValueError, match=word):
            check_protocol(spec, bad)
    llff = RunSpec("/d/fern", "fern", "llff3@504x378", "baseline", "fast", 0, 0)
    check_protocol(llff, {"resolution": [378, 504], "train_views": [1, 9, 17]})


def test_every_attempt_starts_from_a_clean_folder(blender_scene, fake_fit_command, tmp_path):
    spec = _specs(blender_scene, seeds=(0,))[0]
    cfg = RunnerConfig(str(tmp_path / "runs"), fake_fit_command)
    run_dir = tmp_path / "runs" / spec.dirname()
    run_dir.mkdir(parents=True)
    (run_dir / "checkpoint_from_last_attempt.pt").write_text("x")
    assert execute_run(spec, cfg)["status"] == "ok"
    assert not (run_dir / "checkpoint_from_last_attempt.pt").exists() and (run_dir / "metrics.json").exists()


def test_fit_stops_when_its_driver_dies(blender_scene, fake_fit_command, tmp_path):
    import signal
    import subprocess
    import time

    pidfile = tmp_path / "fit.pid"
    code = ("import sys; from senerf.bench.execute import RunnerConfig, execute_run; "
            "from senerf.bench.specs import RunSpec; "
            f"spec = RunSpec({str(blender_scene)!r}, 'lego', 'synthetic-extreme3@100', 'baseline', 'fast', 0, 0); "
            f"execute_run(spec, RunnerConfig({str(tmp_path / 'runs')!r}, {tuple(fake_fit_command)!r}, "
            f"env=(('FAKE_FIT_SLEEP', '60'), ('FAKE_FIT_PIDFILE', {str(pidfile)!r}))))")
    driver = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 30
        while not pidfile.exists() or not pidfile.read_text():
            assert time.monotonic() < deadline, "fake fit never started"
            time.sleep(0.1)
        fit_pid = int(pidfile.read_text())
        os.kill(fit_pid, 0)                                  # running
    finally:
        driver.send_signal(signal.SIGKILL)
        driver.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.kill(fit_pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    pytest.fail("the fit outlived its driver by more than 10 s")


def test_a_run_reporting_impossible_values_fails_and_the_file_stays_readable(blender_scene, fake_fit_command, tmp_path):
    # Before, a fit command's negative seconds were filed as an ok run, and every later command refused the
    # results file naming that line (so at 45ed16b).
    specs = _specs(blender_scene, seeds=(0,))
    first = _run(specs, tmp_path, fake_fit_command, env=(("FAKE_FIT_SECONDS", "-1"),))
    assert (first.ok, first.failed) == (0, 2)
    records, bad = load_results(tmp_path / "results.jsonl")
    assert bad == 0 and {r["status"] for r in records} == {"failed"}
    assert all(r["error"] == "metrics.json: iteration 0: seconds: -1.0 is not a finite number >= 0" for r in records)
    second = _run(specs, tmp_path, fake_fit_command)   # retried, and filed
    assert (second.ok, second.failed, second.skipped) == (2, 0, 0)


def test_a_driver_measured_value_no_run_can_have_is_named_as_the_runs():
    # Catches: the driver's own measures (run_seconds, peak_memory_mib) reported as coming from metrics.json.
    from senerf.bench.runner import _lines_of
    from senerf.bench.specs import RunSpec

    spec = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "baseline", "fast", 0, 0)
    metrics = {"iterations": [{"iteration": 0, "psnr": 20.0, "ssim": 0.5, "seconds": 1.0}], "train_views": [0, 1, 51],
               "test_views": [0], "resolution": [100, 100]}
    ok = {"status": "ok", "metrics": metrics, "run_seconds": 3.0, "peak_memory_mib": 100.0, "returncode": 0}
    outcome, lines = _lines_of(ok, spec, "c0", ["t"])
    assert outcome is ok and len(lines) == 1 and lines[0]["status"] == "ok"
    outcome, lines = _lines_of({**ok, "run_seconds": -1.0}, spec, "c0", ["t"])
    assert outcome["status"] == "failed" and [line["status"] for line in lines] == ["failed"]
    assert outcome["error"] == "the run's run_seconds: -1.0 is not a finite number >= 0"
    outcome, _ = _lines_of({**ok, "metrics": {**metrics, "iterations": [{**metrics["iterations"][0], "ssim": 2.0}]}},
                           spec, "c0", ["t"])
    assert outcome["error"] == "metrics.json: iteration 0: ssim: 2.0 is outside [-1, 1]"
