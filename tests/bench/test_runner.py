"""The driver: resume, retries, crash isolation, peak memory, timeouts, the fit's own figures checked; local and
Ray through one path."""

from __future__ import annotations

import concurrent.futures as cf
import json
import os
import signal
import subprocess
import sys
import time
import types

import pytest

from senerf.bench.results import load_results
from senerf.bench.runner import (RayExecutor, RunnerConfig, default_fit_command, estimate_lines, estimate_seconds,
                                 execute_run, git_commit, make_executor, pending_specs, read_metrics, run_benchmark)
from senerf.bench.protocols import RunSpec, expand_specs

LEGO = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "senerf", "fast", 0, 2)


def _specs(scene, seeds=(0, 1, 2)):
    return expand_specs([str(scene)], ["synthetic-extreme3@100"], ["baseline", "senerf"], ["fast"], list(seeds),
                        iterations=2)


def _run(specs, tmp_path, fit, workers=2):
    cfg = RunnerConfig(runs_dir=str(tmp_path / "runs"), fit_command=fit)
    with cf.ThreadPoolExecutor(workers) as ex:
        return run_benchmark(specs, ex, tmp_path / "results.jsonl", cfg, ["senerf-bench", "test"], commit="c0",
                             log=lambda s: None)


def _psnr_by_key(records):
    return {(r["run_key"], r["iteration"]): r["psnr"] for r in records if r["status"] == "ok"}


def test_a_crash_costs_only_its_run_and_the_next_invocation_retries_it(blender_scene, fake_fit_command, tmp_path,
                                                                        monkeypatch):
    specs = _specs(blender_scene)
    monkeypatch.setenv("FAKE_FIT_CRASH_SEEDS", "1")
    first = _run(specs, tmp_path, fake_fit_command)
    monkeypatch.delenv("FAKE_FIT_CRASH_SEEDS")
    assert (first.ok, first.failed, first.skipped) == (4, 2, 0)
    records, skipped = load_results(tmp_path / "results.jsonl")
    failed = [r for r in records if r["status"] == "failed"]
    assert skipped == [] and {r["seed"] for r in failed} == {1} and all("signal 9" in r["error"] for r in failed)
    kept = _psnr_by_key(records)
    assert kept[(specs[0].key(), 0)] == pytest.approx(20.0)   # fake fit: PSNR = 20 + iteration + seed / 10
    assert len(kept) == 2 * 1 + 2 * 3                          # baseline seeds 0, 2 (1 line) + senerf (3 lines)
    todo, done = pending_specs(specs + specs[:1], tmp_path / "results.jsonl")   # a spec given twice counts once
    assert done == 4 and {s.seed for s in todo} == {1} and len(todo) == 2
    second = _run(specs, tmp_path, fake_fit_command)
    assert (second.ok, second.failed, second.skipped) == (2, 0, 4)
    records2, _ = load_results(tmp_path / "results.jsonl")
    assert records2[:len(records)] == records and len(_psnr_by_key(records2)) == 3 * 1 + 3 * 3
    third = _run(specs, tmp_path, fake_fit_command)
    assert (third.ok, third.failed, third.skipped) == (0, 0, 6)


def test_peak_memory_and_time_are_measured(blender_scene, fake_fit_command, tmp_path, monkeypatch):
    spec = _specs(blender_scene, seeds=(0,))[0]
    base = execute_run(spec, RunnerConfig(str(tmp_path / "a"), fake_fit_command))
    monkeypatch.setenv("FAKE_FIT_ALLOC_MB", "200")
    big = execute_run(spec, RunnerConfig(str(tmp_path / "b"), fake_fit_command))
    monkeypatch.delenv("FAKE_FIT_ALLOC_MB")
    assert base["status"] == big["status"] == "ok"
    assert big["peak_memory_mib"] >= 200 > base["peak_memory_mib"] > 1
    assert big["peak_memory_mib"] - base["peak_memory_mib"] == pytest.approx(200, abs=30)
    monkeypatch.setenv("FAKE_FIT_SLEEP", "0.3")
    slow = execute_run(spec, RunnerConfig(str(tmp_path / "c"), fake_fit_command))
    assert slow["run_seconds"] >= 0.3 and slow["status"] == "ok"


def test_a_timeout_a_missing_program_and_missing_metrics_fail_cleanly(blender_scene, fake_fit_command, tmp_path,
                                                                      monkeypatch):
    spec = _specs(blender_scene, seeds=(0,))[1]            # senerf, 2 iterations
    monkeypatch.setenv("FAKE_FIT_SLEEP", "5")
    out = execute_run(spec, RunnerConfig(str(tmp_path / "t"), fake_fit_command, timeout_s=0.5))
    assert out["status"] == "failed" and out["error"] == "timed out after 0.5 s" and out["run_seconds"] < 4
    quiet = (sys.executable, "-c", "import sys; sys.exit(0)")  # exits 0 but writes no metrics.json
    out = execute_run(spec, RunnerConfig(str(tmp_path / "q"), quiet))
    assert out["status"] == "failed" and "metrics.json: not a metrics.json (FileNotFoundError" in out["error"]
    missing = execute_run(spec, RunnerConfig(str(tmp_path / "m"), ("/nonexistent/senerf-fit",)))
    assert missing["status"] == "failed" and missing["returncode"] == 127
    assert missing["log_tail"].startswith("cannot start /nonexistent/senerf-fit")


def test_every_attempt_starts_from_a_clean_folder(blender_scene, fake_fit_command, tmp_path):
    spec = _specs(blender_scene, seeds=(0,))[0]
    run_dir = tmp_path / "runs" / spec.dirname()
    run_dir.mkdir(parents=True)
    (run_dir / "checkpoint_from_last_attempt.pt").write_text("x")
    assert execute_run(spec, RunnerConfig(str(tmp_path / "runs"), fake_fit_command))["status"] == "ok"
    assert not (run_dir / "checkpoint_from_last_attempt.pt").exists() and (run_dir / "metrics.json").exists()


_ROW = {"iteration": 0, "psnr": 20.0, "ssim": 0.5, "seconds": 1.5}
_METRICS = {"resolution": [100, 100], "train_views": [51, 0, 1], "iterations": [_ROW, {**_ROW, "iteration": 1},
                                                                               {**_ROW, "iteration": 2}],
            "config": {"train": {"steps": 600, "batch_rays": 1024}}}


@pytest.mark.parametrize("change, problem", [
    ({"resolution": [200, 200]}, "resolution: [200, 200] is not [100, 100] of synthetic-extreme3@100"),
    ({"train_views": [0, 1]}, "train_views: [0, 1] are not the 3 views of synthetic-extreme3@100 [0, 1, 51]"),
    ({"train_views": [0, 1, 50]}, "train_views: [0, 1, 50] are not the 3 views"),
    ({"iterations": [_ROW, {**_ROW, "iteration": 1}]}, "iterations: expected 0..2, found [0, 1]"),
    ({"iterations": [{**_ROW, "psnr": None}]}, "iteration 0: psnr: None is not a measure"),
    ({"iterations": [{**_ROW, "ssim": True}]}, "iteration 0: ssim: True is not a measure"),
    ({"iterations": [{**_ROW, "seconds": -1.0}]}, "iteration 0: seconds: -1.0 is not a measure"),
    ({"iterations": [{**_ROW, "seconds": float("nan")}]}, "iteration 0: seconds: nan is not a measure"),
])
def test_metrics_that_do_not_describe_the_run_are_refused(tmp_path, change, problem):
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps(_METRICS))
    assert read_metrics(path, LEGO) == _METRICS
    path.write_text(json.dumps({**_METRICS, **change}))
    with pytest.raises(ValueError, match="^" + problem.replace("[", r"\[").replace(".", r"\.").join(
            [f"{path}: ".replace(".", r"\."), ""])):
        read_metrics(path, LEGO)
    for doc in ("{", "[]", json.dumps({"iterations": [5]})):
        path.write_text(doc)
        with pytest.raises(ValueError, match="not a metrics.json"):
            read_metrics(path, LEGO)
    fern = RunSpec("/d/fern", "fern", "llff3@504x378", "baseline", "fast", 0, 0)
    path.write_text(json.dumps({**_METRICS, "resolution": [378, 504], "iterations": [_ROW]}))
    assert read_metrics(path, fern)["train_views"] == [51, 0, 1]   # LLFF: any 3 views


def test_a_run_reporting_negative_seconds_fails_and_is_retried(blender_scene, fake_fit_command, tmp_path,
                                                                monkeypatch):
    specs = _specs(blender_scene, seeds=(0,))
    monkeypatch.setenv("FAKE_FIT_SECONDS", "-1")
    first = _run(specs, tmp_path, fake_fit_command)
    monkeypatch.delenv("FAKE_FIT_SECONDS")
    assert (first.ok, first.failed) == (0, 2)
    assert all("seconds: -1.0 is not a measure" in r["error"] for r in load_results(tmp_path / "results.jsonl")[0])
    second = _run(specs, tmp_path, fake_fit_command)
    assert (second.ok, second.failed, second.skipped) == (2, 0, 0)


def test_the_driver_logs_each_run_and_a_memory_it_could_not_measure(tmp_path):
    metrics = {**_METRICS, "iterations": [{**_ROW, "lpips": "unavailable", "avg": "unavailable"}]}
    outcome = {"status": "ok", "metrics": metrics, "run_seconds": 1.0, "peak_memory_mib": None}
    spec = RunSpec("/d/s", "s", "synthetic-extreme3@100", "baseline", "fast", 0, 0)
    lines: list[str] = []
    with cf.ThreadPoolExecutor(1) as ex:
        run_benchmark([spec, spec], ex, tmp_path / "r.jsonl", RunnerConfig(str(tmp_path / "runs")), ["x"],
                      commit="c", log=lines.append, run_fn=lambda s, c: outcome)
    assert lines == ["1 runs: 0 already finished, 1 to run",
                     f"[1/1] ok      {spec.key()}  PSNR 20.00  1 s  memory not measured"]


def test_the_fit_stops_when_its_driver_dies(blender_scene, fake_fit_command, tmp_path):
    pidfile = tmp_path / "fit.pid"
    code = ("from senerf.bench.runner import RunnerConfig, execute_run; from senerf.bench.protocols import RunSpec; "
            f"spec = RunSpec({str(blender_scene)!r}, 'lego', 'synthetic-extreme3@100', 'baseline', 'fast', 0, 0); "
            f"execute_run(spec, RunnerConfig({str(tmp_path / 'runs')!r}, {tuple(fake_fit_command)!r}))")
    env = {**os.environ, "FAKE_FIT_SLEEP": "60", "FAKE_FIT_PIDFILE": str(pidfile)}
    driver = subprocess.Popen([sys.executable, "-c", code], env=env)
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


def test_the_estimate_defaults_scale_with_iterations_preset_steps_and_pixels():
    spec = lambda protocol="synthetic-extreme3@100", **kw: RunSpec(**{   # noqa: E731
        "scene_dir": "/d/lego", "scene": "lego", "protocol": protocol, "method": "senerf", "preset": "fast", "seed": 0,
        "iterations": 1, **kw})
    one = estimate_seconds(spec())
    assert one == (pytest.approx(88.8), "default")                   # lego fast: 37.7 + 51.1 s measured
    assert estimate_seconds(spec(method="baseline", iterations=0))[0] == pytest.approx(37.7)
    assert estimate_seconds(spec("synthetic-extreme3@200"))[0] == pytest.approx(2 * one[0])   # sqrt of 4x pixels
    # steps and presets scale the training only (teacher 15.9 s, a student 24.0 s at fast), not evaluation or labels
    assert estimate_seconds(spec(steps=300))[0] == pytest.approx(88.8 - (15.9 + 24.0) / 2)
    assert estimate_seconds(spec(preset="balanced"))[0] == pytest.approx(   # 3000 x 1024: 5x fast's training
        5.0 * (15.9 + 24.0) + 21.8 + 15.1 + 4.0 * 3)                    # 248 s; measured 240 s (ladder, lego, c76190f)
    assert estimate_seconds(spec("llff6@504x378"))[0] == pytest.approx(106 + 19 + 173 + 11 + 82.0 * 6)
    assert estimate_seconds(spec("dtu3@96"))[0] == pytest.approx((33 + 12 + 50 + 6 + 15.0 * 3) / 2)


def test_the_estimate_uses_the_results_files_own_seconds_and_counts_only_pending_runs(ok_line, blender_scene,
                                                                                      llff_scene, tmp_path):
    specs = expand_specs([str(blender_scene), str(llff_scene)], ["synthetic-extreme3@100", "llff3@504x378"],
                         ["senerf"], ["fast"], [0, 1, 2])
    results = tmp_path / "results.jsonl"
    done = [ok_line(run_key=s.key(), method="senerf", seed=s.seed, iterations=1, iteration=1, run_seconds=secs)
            for s, secs in zip(specs[:2], (100.0, 120.0))]
    results.write_text("".join(json.dumps(line) + "\n" for line in done))
    measured = {("lego", "synthetic-extreme3@100", "senerf", "fast 600x1024", 1): [100.0, 120.0]}
    assert estimate_seconds(specs[2], measured) == (110.0, "measured")
    lines = estimate_lines(specs, results, workers=2)
    assert lines[0] == "# estimate: 4 runs to run (2 already finished)"
    assert lines[1] == "#   synthetic-extreme3@100 senerf fast K=1: 1 runs x ~110 s (measured) = 2 min"
    assert lines[2] == "#   llff3@504x378 senerf fast K=1: 3 runs x ~555 s (default) = 28 min"
    assert lines[3] == "# total ~30 min of fitting, ~15 min with 2 workers"


def test_the_default_fit_command_is_senerf_fit_on_this_interpreter():
    argv = default_fit_command()
    assert argv[:2] == (sys.executable, "-c")
    done = subprocess.run([*argv, "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("usage: senerf-fit")


def test_git_commit_is_the_checkouts_or_unknown(tmp_path):
    commit = git_commit()
    assert commit == "unknown" or len(commit.removesuffix("-dirty")) == 40
    assert git_commit(tmp_path) == "unknown"                     # not a repository


# ---------------------------------------------------------------- Ray: the same driver, another executor
def _dies_for_seed_1(spec, cfg):
    """A run function whose *worker process* dies for seed 1 (not just its fit child)."""
    if spec.seed == 1:
        os._exit(3)
    return execute_run(spec, cfg)


@pytest.fixture(scope="module")
def ray_executor():
    ray = pytest.importorskip("ray", reason="ray not installed (optional [cluster] extra): Ray executor untested")
    if ray.is_initialized():
        pytest.skip("a Ray instance is already running in this process")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ex = RayExecutor(address=None, num_cpus=2, cpus_per_run=1)
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
    assert _psnr_by_key(rec_local) == _psnr_by_key(rec_ray) and all(r["peak_memory_mib"] > 1 for r in rec_ray)


def test_a_lost_ray_worker_costs_only_its_run(ray_executor, blender_scene, fake_fit_command, tmp_path):
    specs = _specs(blender_scene, seeds=(0, 1))
    cfg = RunnerConfig(runs_dir=str(tmp_path / "runs"), fit_command=fake_fit_command)
    out = run_benchmark(specs, ray_executor, tmp_path / "results.jsonl", cfg, ["t"], commit="c0",
                        log=lambda s: None, run_fn=_dies_for_seed_1)
    assert (out.ok, out.failed) == (2, 2)
    records, _ = load_results(tmp_path / "results.jsonl")
    lost = [r for r in records if r["status"] == "failed"]
    assert {r["seed"] for r in lost} == {1} and all(r["error"].startswith("worker lost") for r in lost)
    assert {r["seed"] for r in records if r["status"] == "ok"} == {0}


def _fake_ray(monkeypatch, initialized: bool):
    ray = types.ModuleType("ray")
    ray.log = []
    ray.is_initialized = lambda: initialized
    ray.init = lambda **kw: ray.log.append(("init", kw))
    ray.shutdown = lambda: ray.log.append(("shutdown",))

    def remote(fn):
        def options(**opts):
            ray.log.append(("options", opts))

            def call(*args):
                fut = cf.Future()
                fut.set_result(fn(*args))
                return types.SimpleNamespace(future=lambda: fut)
            return types.SimpleNamespace(remote=call)
        return types.SimpleNamespace(options=options)
    ray.remote = remote
    monkeypatch.setitem(sys.modules, "ray", ray)
    return ray


def test_make_executor_joins_the_ray_cluster_at_the_address(monkeypatch):
    ray = _fake_ray(monkeypatch, initialized=False)
    ex = make_executor(workers=3, ray_address="ray://h:10001", cpus_per_run=2.5)
    assert isinstance(ex, RayExecutor) and ray.log == [("init", {"address": "ray://h:10001", "log_to_driver": False})]
    assert ex.submit(divmod, 7, 2).result() == (3, 1)
    assert ray.log[-1] == ("options", {"num_cpus": 2.5, "max_retries": 1})   # CPUs reserved per run
    ex.shutdown()
    assert ray.log[-1] == ("shutdown",)                # it started Ray, so it stops it
    joined = _fake_ray(monkeypatch, initialized=True)   # a running Ray is joined, neither restarted nor stopped
    RayExecutor(address="auto").shutdown()
    assert joined.log == []
    with make_executor(workers=3, ray_address="") as local:
        assert isinstance(local, cf.ThreadPoolExecutor) and local.submit(abs, -4).result() == 4
    monkeypatch.setitem(sys.modules, "ray", None)      # "import ray" raises ImportError
    with pytest.raises(ImportError, match=r"Ray is not installed: pip install 'senerf\[cluster\]'"):
        RayExecutor()
