"""Lines of senerf.bench (and senerf.demo) that the rest of the suite never ran: each error names its file or flag,
each branch gives the value worked out by hand in a comment, and the accepted side of each boundary still passes.
No real fit runs here: where the harness would start ``senerf-fit``, the child or the driver is stubbed."""

from __future__ import annotations

import concurrent.futures as cf
import errno
import json
import runpy
import shlex
import signal
import subprocess
import sys
import types
import warnings
from importlib import metadata

import pytest

from senerf.bench import cli, execute, machine
from senerf.bench.cli import main
from senerf.errors import InputError

#: One finished baseline row of a results file (as in test_cli.py).
_FINISHED = {"run_key": "k", "status": "ok", "attempt": "a", "scene": "s", "protocol": "p", "method": "baseline",
             "preset": "fast", "seed": 0, "iterations": 0, "iteration": 0, "psnr": 20.0, "ssim": 0.5,
             "lpips": "unavailable", "avg": "unavailable", "seconds": 1.0, "seconds_cumulative": 1.0,
             "peak_memory_mib": 100.0}


def _run_args(scene, out, *extra):
    return ["run", "--scenes", str(scene), "--protocols", "synthetic-extreme3@100", "--methods", "baseline",
            "--out", str(out), "--fit-command", shlex.join([sys.executable, "-c", "raise SystemExit(9)"]), *extra]


def _error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err.strip()


# ---------------------------------------------------------------- machine.py: fake /proc, failing commands


def _fake_files(monkeypatch, files: dict):
    """machine's Path reads ``files[path]``; a path not there (or None) is missing (FileNotFoundError)."""
    class FakePath:
        def __init__(self, p):
            self.p = str(p)

        def read_text(self):
            if files.get(self.p) is None:
                raise FileNotFoundError(errno.ENOENT, "No such file or directory", self.p)
            return files[self.p]
    monkeypatch.setattr(machine, "Path", FakePath)


def _fake_run(monkeypatch, result):
    """machine's subprocess.run returns ``result`` (a stdout string) or raises it (an exception); calls recorded.
    ``CUDA_VISIBLE_DEVICES`` is cleared (GPU nodes set it; it selects which listed GPU is named)."""
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    calls = []

    def run(argv, **kw):
        calls.append(argv)
        if isinstance(result, BaseException):
            raise result
        return subprocess.CompletedProcess(argv, 0, stdout=result, stderr="")
    monkeypatch.setattr(machine.subprocess, "run", run)
    return calls


def test_memory_is_memtotal_in_gib_or_none(monkeypatch):
    # Catches: the OSError / ValueError fallback dropped (a missing /proc/meminfo or a malformed MemTotal
    # crashed), or the KiB -> GiB factor changed (1572864 KiB = 1.5 GiB).
    _fake_files(monkeypatch, {"/proc/meminfo": "MemFree: 1 kB\nMemTotal:        1572864 kB\n"})
    assert machine._memory_gib() == 1.5
    _fake_files(monkeypatch, {})
    assert machine._memory_gib() is None
    _fake_files(monkeypatch, {"/proc/meminfo": "MemTotal: lots kB\n"})
    assert machine._memory_gib() is None
    _fake_files(monkeypatch, {"/proc/meminfo": "MemFree: 1 kB\n"})
    assert machine._memory_gib() is None


def test_version_of_a_missing_package_is_none():
    # Catches: PackageNotFoundError not caught (a machine without torch crashed every run's outcome).
    assert machine._version("senerf-no-such-package-xyz") is None
    assert machine._version("numpy") == metadata.version("numpy")


@pytest.mark.parametrize("failure", [FileNotFoundError(errno.ENOENT, "No such file", "nvidia-smi"),
                                     subprocess.CalledProcessError(9, ["nvidia-smi"]),
                                     subprocess.TimeoutExpired(["nvidia-smi"], 30)],
                         ids=["no-nvidia-smi", "fails", "hangs"])
def test_gpu_name_falls_back_to_the_device_when_nvidia_smi_fails(monkeypatch, failure):
    # Catches: the OSError / SubprocessError fallback dropped (no nvidia-smi, or a failing one, crashed the run).
    calls = _fake_run(monkeypatch, failure)
    assert machine._gpu_name("cuda") == "cuda"
    assert calls == [["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"]]


def test_gpu_name_is_the_first_gpu_listed(monkeypatch):
    # Catches: the name not prefixed with the device, the last GPU taken, or an empty listing indexed (IndexError).
    _fake_run(monkeypatch, "\n  NVIDIA H100 80GB HBM3 \nNVIDIA A100\n")
    assert machine._gpu_name("cuda") == "cuda: NVIDIA H100 80GB HBM3"
    _fake_run(monkeypatch, " \n\n")
    assert machine._gpu_name("cuda") == "cuda"


@pytest.mark.parametrize("visible, device, expected", [
    (None, "cuda:1", "cuda:1: B"),                 # the device's own index
    ("2,0", "cuda", "cuda: C"),                    # cuda = the first visible GPU, physical 2
    ("2,0", "cuda:1", "cuda:1: A"),                # the second visible, physical 0
    ("GPU-1234", "cuda", "cuda"),                  # a UUID: which one cannot be told here
    ("0", "cuda:1", "cuda:1"),                     # beyond the visible list
    (None, "cuda:5", "cuda:5"),                    # beyond nvidia-smi's list
])
def test_gpu_name_is_the_gpu_the_device_selects(monkeypatch, visible, device, expected):
    # Catches: every GPU named after nvidia-smi's first whatever cuda:N or CUDA_VISIBLE_DEVICES select (so before
    # 2026-11-23), or an index beyond either list raising IndexError.
    _fake_run(monkeypatch, "A\nB\nC\n")   # (clears CUDA_VISIBLE_DEVICES)
    if visible is not None:
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", visible)
    assert machine._gpu_name(device) == expected


@pytest.mark.parametrize("meminfo", ["MemTotal:\n", "MemTotal:"])
def test_proc_lines_without_their_value_fall_back(monkeypatch, meminfo):
    # Catches: a "MemTotal:" line without a value raising IndexError.
    _fake_files(monkeypatch, {"/proc/meminfo": meminfo})
    assert machine._memory_gib() is None


def test_machine_info_asks_nvidia_smi_only_for_a_gpu_and_counts_usable_cores(monkeypatch):
    # Catches: a CPU run asking nvidia-smi (or naming a GPU), and cores_usable not falling back to the core count
    # where the platform has no sched_getaffinity.
    calls = _fake_run(monkeypatch, "Fake GPU\n")
    monkeypatch.setattr(machine.os, "cpu_count", lambda: 7)
    monkeypatch.setattr(machine.os, "sched_getaffinity", lambda pid: {0, 3})
    info = machine.machine_info("cpu")
    assert (info["device"], info["cores"], info["cores_usable"], calls) == ("cpu", 7, 2, [])
    assert machine.machine_info("cuda")["device"] == "cuda: Fake GPU" and len(calls) == 1
    monkeypatch.delattr(machine.os, "sched_getaffinity")
    assert machine.machine_info("cpu")["cores_usable"] == 7


def test_git_commit_is_unknown_when_git_fails_or_says_nothing(monkeypatch, tmp_path):
    # Catches: git's failure not caught (no git, or not a repository, crashed the benchmark), or an empty
    # description recorded as "" instead of "unknown".
    _fake_run(monkeypatch, FileNotFoundError(errno.ENOENT, "No such file", "git"))
    assert machine.git_commit(tmp_path) == "unknown"
    _fake_run(monkeypatch, subprocess.CalledProcessError(128, ["git"]))
    assert machine.git_commit(tmp_path) == "unknown"
    _fake_run(monkeypatch, "\n")
    assert machine.git_commit(tmp_path) == "unknown"
    calls = _fake_run(monkeypatch, "0123abcd-dirty\n")
    assert machine.git_commit(tmp_path) == "0123abcd-dirty"
    assert calls == [["git", "describe", "--always", "--dirty", "--abbrev=40"]]


# ---------------------------------------------------------------- executors.py: a fake Ray module


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


def test_make_executor_joins_a_ray_cluster_at_the_address(monkeypatch):
    # Catches: make_executor ignoring --ray-address (a local pool instead), the address not handed to ray.init,
    # or cpus_per_run not reserved per task.
    from senerf.bench.executors import LocalExecutor, RayExecutor, make_executor

    ray = _fake_ray(monkeypatch, initialized=False)
    ex = make_executor(workers=3, ray_address="ray://h:10001", cpus_per_run=2.5)
    assert isinstance(ex, RayExecutor)
    assert ray.log == [("init", {"address": "ray://h:10001", "log_to_driver": False})]
    assert ex.submit(divmod, 7, 2).result() == (3, 1)
    assert ray.log[-1] == ("options", {"num_cpus": 2.5, "max_retries": 1})
    ex.shutdown()
    assert ray.log[-1] == ("shutdown",)                # it started Ray, so it stops it
    local = make_executor(workers=3, ray_address="")
    assert isinstance(local, LocalExecutor) and local.workers == 3
    local.shutdown()


def test_a_running_ray_instance_is_joined_not_restarted_nor_stopped(monkeypatch):
    # Catches: ray.init called on an initialized Ray (an error in Ray), or shutdown stopping a Ray it did not start.
    from senerf.bench.executors import RayExecutor

    ray = _fake_ray(monkeypatch, initialized=True)
    ex = RayExecutor(address="auto")
    ex.shutdown()
    assert ray.log == []


def test_local_executor_needs_a_worker():
    # Catches: the workers >= 1 check dropped (ThreadPoolExecutor's own message names max_workers, not workers)
    # or made > 1.
    from senerf.bench.executors import LocalExecutor

    with pytest.raises(ValueError, match=r"^workers must be >= 1, got 0$"):
        LocalExecutor(0)
    one = LocalExecutor(1)
    assert one.submit(abs, -4).result() == 4
    one.shutdown()


def test_without_ray_installed_the_error_says_how_to_install_it(monkeypatch, blender_scene, tmp_path, capsys):
    # Catches: the ImportError re-raised without the install hint, or senerf-bench turning it into a traceback
    # (exit 1) instead of one line naming --ray-address.
    from senerf.bench.executors import RayExecutor

    monkeypatch.setitem(sys.modules, "ray", None)      # "import ray" raises ImportError
    with pytest.raises(ImportError, match=r"Ray is not installed: pip install 'senerf\[cluster\]' \(ray>=2\.9\)"):
        RayExecutor()
    assert main(_run_args(blender_scene, tmp_path / "b", "--ray-address", "auto")) == 2
    assert _error_line(capsys) == ("senerf-bench: error: --ray-address: Ray is not installed: pip install "
                                   "'senerf[cluster]' (ray>=2.9)")
    assert not list((tmp_path / "b" / "runs").iterdir())   # no fit started


# ---------------------------------------------------------------- execute.py


def test_default_fit_command_runs_senerf_fit_with_this_interpreter():
    # Catches: a fit command on another Python (PATH's), or one that does not reach senerf.cli.main.
    argv = execute.default_fit_command()
    assert argv[:2] == (sys.executable, "-c")
    done = subprocess.run([*argv, "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.startswith("usage: senerf-fit")


def test_execute_run_uses_the_default_fit_command_without_one(monkeypatch, tmp_path):
    # Catches: cfg.fit_command None not replaced by default_fit_command() (argv starting with the scene folder).
    from senerf.bench.execute import RunnerConfig, execute_run
    from senerf.bench.specs import RunSpec

    seen = []
    monkeypatch.setattr(execute, "_run_child", lambda argv, *a: seen.append(argv) or (0, 0.25))
    spec = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "baseline", "fast", 0, 0)
    outcome = execute_run(spec, RunnerConfig(str(tmp_path / "runs")))
    assert outcome["fit_command"][:4] == [*execute.default_fit_command(), "/d/lego"]
    assert seen[0][:3] == [sys.executable, "-S", "-c"] and seen[0][5:8] == outcome["fit_command"][:3]
    # no metrics.json was written by the stub: a failed outcome naming the file, no peak memory measured
    assert outcome["status"] == "failed" and "metrics.json: cannot read metrics" in outcome["error"]
    assert outcome["peak_memory_mib"] is None and outcome["run_seconds"] == 0.25


_IT = {"iteration": 0, "psnr": 20, "ssim": 0.5, "seconds": 1.5}


@pytest.mark.parametrize("doc, problem", [
    ("{", r"not valid JSON \(Expecting property name enclosed in double quotes at line 1\)"),
    ("{}", r"iterations: missing or empty"),
    ("[]", r"iterations: missing or empty"),                                    # JSON, but not an object
    (json.dumps({"iterations": []}), r"iterations: missing or empty"),
    (json.dumps({"iterations": {"0": _IT}}), r"iterations: missing or empty"),  # not a list
    (json.dumps({"iterations": [5]}), r"iterations\[0\]\.iteration: missing or not an integer"),
    (json.dumps({"iterations": [_IT, {**_IT, "iteration": "1"}]}), r"iterations\[1\]\.iteration: missing or not"),
    (json.dumps({"iterations": [{**_IT, "psnr": None}]}), r"iterations\[0\]\.psnr: missing or not a number"),
    (json.dumps({"iterations": [{**_IT, "ssim": True}]}), r"iterations\[0\]\.ssim: missing or not a number"),
    (json.dumps({"iterations": [{k: v for k, v in _IT.items() if k != "seconds"}]}),
     r"iterations\[0\]\.seconds: missing or not a number"),
], ids=["torn", "no-iterations", "a-list", "empty", "a-dict", "entry-not-object", "string-iteration", "null-psnr",
        "bool-ssim", "no-seconds"])
def test_parse_metrics_names_the_file_and_the_field(tmp_path, doc, problem):
    # Catches: any of parse_metrics' checks dropped (a malformed metrics.json then crashed result_lines with a
    # KeyError / TypeError in the driver, or filed a made-up number), or the message not naming the file.
    path = tmp_path / "metrics.json"
    path.write_text(doc)
    with pytest.raises(ValueError, match=f"^{path}: {problem}"):
        execute.parse_metrics(path)


def test_parse_metrics_checks_the_iterations_are_exactly_0_to_k(tmp_path):
    # Catches: the 0..K check dropped (a fit stopped after iteration 1 of 2 counted as finished) or off by one.
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps({"iterations": [_IT, {**_IT, "iteration": 1}]}))
    with pytest.raises(ValueError, match=rf"^{path}: iterations: expected 0\.\.2, found \[0, 1\]$"):
        execute.parse_metrics(path, expected_iterations=2)
    assert len(execute.parse_metrics(path, expected_iterations=1)["iterations"]) == 2   # ints are numbers too
    assert len(execute.parse_metrics(path)["iterations"]) == 2                         # no K: any iterations


def test_a_fit_program_that_cannot_start_is_status_127_with_the_reason_logged(tmp_path):
    # Catches: Popen's OSError escaping _run_child (a missing wrapper interpreter crashed the worker thread).
    log = tmp_path / "run.log"
    code, seconds = execute._run_child([str(tmp_path / "no-such-program")], log, {}, None, 0.01)
    assert code == 127 and 0 <= seconds < 5
    assert log.read_text().startswith(f"cannot start {tmp_path / 'no-such-program'}: [Errno 2]")


def test_killing_a_process_group_that_is_gone_is_not_an_error(monkeypatch):
    # Catches: ProcessLookupError not caught (a fit that ended just as its timeout fired crashed the driver), or
    # the group killed with a signal other than SIGKILL.
    calls = []

    def killpg(pid, sig):
        calls.append((pid, sig))
        raise ProcessLookupError(errno.ESRCH, "No such process")
    monkeypatch.setattr(execute.os, "killpg", killpg)
    assert execute._kill_group(12345) is None
    assert calls == [(12345, signal.SIGKILL)]


def test_tail_of_a_missing_log_is_empty_and_keeps_the_last_lines(tmp_path):
    # Catches: the OSError fallback dropped (a run whose log could not be read crashed the driver), or the tail
    # taken from the head.
    assert execute._tail(tmp_path / "missing.log") == ""
    log = tmp_path / "a.log"
    log.write_text("".join(f"line {i}\n" for i in range(30)))
    assert execute._tail(log, n_lines=3) == "line 27\nline 28\nline 29"
    assert execute._tail(log, n_lines=3, max_chars=9) == "8\nline 29"      # the last 9 characters


# ---------------------------------------------------------------- specs.py, protocols.py, runner.py


def test_a_steps_override_is_part_of_the_key_and_of_the_fit_flags():
    # Catches: steps left out of the key (a 20-step run would resume as the preset's finished run) or not passed
    # to senerf-fit.
    from senerf.bench.specs import RunSpec

    spec = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "senerf", "fast", 0, 3, "cpu", 20)
    assert spec.key() == "lego|synthetic-extreme3@100|senerf|fast|seed0|K3|cpu|steps20"
    assert spec.dirname() == "lego__synthetic-extreme3@100__senerf__fast__seed0__K3__cpu__steps20"
    assert spec.fit_args("/o")[-5:] == ["--steps", "20", "--out", "/o", "--overwrite"]
    plain = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "senerf", "fast", 0, 3)
    assert plain.key().endswith("|K3|cpu") and "--steps" not in plain.fit_args("/o")


def test_expand_specs_refuses_no_rounds_and_no_steps_and_accepts_one():
    # Catches: the iterations >= 1 or steps >= 1 check dropped or made > 1 (reachable from the library only:
    # senerf-bench's flags refuse 0 themselves).
    from senerf.bench.specs import expand_specs

    args = (["/nowhere/lego"], ["synthetic-extreme3@100"], ["senerf"], ["fast"], [0])
    with pytest.raises(InputError, match=r"^iterations: iterations must be >= 1 for self-training methods, got 0$"):
        expand_specs(*args, iterations=0, check_scenes=False)
    with pytest.raises(InputError, match=r"^steps: steps must be positive, got 0$"):
        expand_specs(*args, steps=0, check_scenes=False)
    (spec,) = expand_specs(*args, iterations=1, steps=1, check_scenes=False)
    assert (spec.iterations, spec.steps) == (1, 1)


def test_unchecked_scenes_get_the_nominal_factors_and_100_train_views():
    # Catches: check_scenes=False still reading the folder (a dry run on a machine without the data failed), or
    # other defaults than the 800x800 / 100-view NeRF Synthetic ones (800 / 100 = factor 8).
    from senerf.bench.specs import expand_specs

    (spec,) = expand_specs(["/nowhere/lego"], ["synthetic-extreme3@100"], ["baseline"], ["fast"], [0],
                           check_scenes=False)
    assert (spec.n_train, spec.downscale, spec.scene) == (100, None, "lego")
    args = spec.fit_args("/o")
    assert args[args.index("--downscale") + 1] == "8"


def test_random_views_needs_between_one_and_all_train_views():
    # Catches: the 0 < n_views <= n_train check dropped (numpy's "larger sample than population" instead) or made
    # strict at the top (all 8 of 8 views refused).
    from senerf.bench.protocols import random_views

    for n_train, n_views in ((5, 8), (8, 0)):
        with pytest.raises(ValueError, match=rf"^need 0 < n_views <= n_train, got {n_views}, {n_train}$"):
            random_views(n_train, n_views, 0)
    assert random_views(8, 8, 3) == tuple(range(8))


def _blender(root, frames_doc, image_side=None, name="lego"):
    d = root / name
    (d / "train").mkdir(parents=True)
    (d / "transforms_train.json").write_text(frames_doc if isinstance(frames_doc, str) else json.dumps(frames_doc))
    if image_side:
        from PIL import Image

        Image.new("RGB", (image_side, image_side)).save(d / "train" / "r_0.png")
    return d


@pytest.mark.parametrize("doc", ["{", "{}", json.dumps({"frames": 5}), "[]"], ids=["torn", "no-frames", "int", "list"])
def test_count_train_views_names_the_file(tmp_path, doc):
    # Catches: count_train_views' error handling dropped (a JSONDecodeError / KeyError / TypeError traceback).
    from senerf.bench.protocols import count_train_views

    d = _blender(tmp_path, doc)
    with pytest.raises(InputError, match=rf"^{d / 'transforms_train.json'}: frames: cannot count training frames"):
        count_train_views(d)


@pytest.mark.parametrize("doc", [json.dumps({"frames": []}), json.dumps({"frames": [{}]}), "{"],
                         ids=["no-frame", "no-file-path", "torn"])
def test_native_size_names_the_first_frame_field(tmp_path, doc):
    # Catches: the first-frame lookup's error handling dropped (IndexError / KeyError traceback).
    from senerf.bench.protocols import native_size

    d = _blender(tmp_path, doc)
    with pytest.raises(InputError, match=rf"^{d / 'transforms_train.json'}: frames\[0\]\.file_path: cannot find the "
                                         "first frame"):
        native_size(d)


def test_native_size_names_the_image_it_cannot_read(tmp_path):
    # Catches: the image's OSError not turned into an InputError, or ".png" appended to a path that has a
    # suffix (or not to one without).
    from senerf.bench.protocols import native_size

    d = _blender(tmp_path, {"frames": [{"file_path": "./train/r_0"}]})
    with pytest.raises(InputError, match=rf"^{d / 'train' / 'r_0.png'}: cannot read the image size"):
        native_size(d)
    e = _blender(tmp_path, {"frames": [{"file_path": "train/r_0.jpg"}]}, name="jpg")
    with pytest.raises(InputError, match=rf"^{e / 'train' / 'r_0.jpg'}: cannot read the image size"):
        native_size(e)
    f = _blender(tmp_path, {"frames": [{"file_path": "./train/r_0"}]}, image_side=40, name="ok")
    assert native_size(f) == (40, 40)


@pytest.mark.parametrize("content", [b"not a numpy file", None], ids=["garbage", "empty-array"])
def test_native_size_of_an_unreadable_poses_bounds_names_hwf(tmp_path, content):
    # Catches: poses_bounds.npy's read errors (pickled / garbage data, no rows) escaping as a traceback.
    import numpy as np

    from senerf.bench.protocols import native_size

    d = tmp_path / "fern"
    d.mkdir()
    path = d / "poses_bounds.npy"
    if content is None:
        np.save(path, np.zeros((0, 17)))
    else:
        path.write_bytes(content)
    with pytest.raises(InputError, match=rf"^{path}: hwf: cannot read the image size"):
        native_size(d)


def test_a_spec_given_twice_is_run_once():
    # Catches: the duplicate check dropped in pending_specs (the same run submitted twice, two ok lines).
    from senerf.bench.runner import pending_specs
    from senerf.bench.specs import RunSpec

    a = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "baseline", "fast", 0, 0)
    b = RunSpec("/d/lego", "lego", "synthetic-extreme3@100", "baseline", "fast", 1, 0)
    assert pending_specs([a, b, a, RunSpec(*a.__dict__.values())], "/nowhere/results.jsonl") == ([a, b], 0)


# ---------------------------------------------------------------- results.py, summary.py, ladder.py, plots.py


@pytest.mark.parametrize("line, name", [({"status": "failed", "error": "x"}, "run_key"),
                                        ({"run_key": "k", "error": "x"}, "status"),
                                        ({"run_key": "k", "status": "failed", "error": 5}, "error")])
def test_validate_line_names_a_failed_lines_missing_field(line, name):
    # Catches: a failed line's field check dropped (a line without its reason taken as valid).
    from senerf.bench.results import validate_line

    with pytest.raises(ValueError, match=rf"^failed line: {name}: missing or not a string$"):
        validate_line(line)
    validate_line({"run_key": "k", "status": "failed", "error": "x"})      # the accepted side


def test_appending_no_lines_writes_nothing(tmp_path):
    # Catches: the empty-list shortcut dropped (an empty run created the results folder and file, and locked it).
    from senerf.bench.results import append_lines

    path = tmp_path / "sub" / "r.jsonl"
    append_lines(path, [])
    assert not path.parent.exists()
    append_lines(path, [{"a": 1}])
    assert path.read_text() == '{"a": 1}\n'


def test_a_stat_of_no_number_prints_a_dash_and_a_gpu_run_is_its_own_preset():
    # Catches: Stat.text formatting a None mean (TypeError), or preset_label leaving the device out (a CUDA run's
    # seconds averaged with CPU runs').
    from senerf.bench.summary import Stat, preset_label

    assert Stat.of(["unavailable", None, float("nan"), True]) == Stat(None, None, 0)
    assert Stat.of(["unavailable"]).text() == "-"
    assert preset_label({"preset": "fast", "steps": 20, "device": "cuda"}) == "fast+steps20+cuda"
    assert preset_label({"preset": "fast", "device": "cpu"}) == "fast"


def test_teacher_dependence_row_without_a_slope_prints_dashes():
    # Catches: the slope-None branch dropped (a TypeError formatting None when every teacher scored the same).
    from senerf.bench.ladder import teacher_dependence, teacher_dependence_markdown

    lines = [dict(run_key=f"k{s}", status="ok", attempt="a", scene="lego", protocol="p", method="senerf",
                  preset="fast", seed=s, iterations=1, iteration=i, psnr=psnr)
             for s, final in enumerate((16.0, 17.0, 18.0)) for i, psnr in ((0, 15.0), (1, final))]
    (fit,) = teacher_dependence(lines)
    assert fit.slope is None and fit.gain_at(15.0) is None
    # teachers 15, 15, 15: 15.00 ± 0.00; gains 1, 2, 3: mean 2, sample std 1
    row = "| lego | fast K=1 | senerf | 3 | 15.00 ± 0.00 | 2.00 ± 1.00 | - | - | - | - |"
    assert teacher_dependence_markdown([fit])[-1] == row


def test_mask_quality_plot_of_no_records_is_refused(tmp_path):
    # Catches: the empty check dropped (an empty figure written, or numpy's error on no bars).
    from senerf.bench.plots import plot_mask_quality

    with pytest.raises(ValueError, match=r"^no mask-quality records to plot$"):
        plot_mask_quality([], tmp_path / "m.png")
    assert not (tmp_path / "m.png").exists()


# ---------------------------------------------------------------- cli.py


def test_an_interrupted_run_exits_130_at_once_naming_the_results_file(monkeypatch, blender_scene, tmp_path, capsys):
    # Catches: the KeyboardInterrupt handler dropped (the executor's shutdown then waited for every queued fit), or
    # its exit status or message changed.
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    exits = []

    def fake_exit(code):
        exits.append(code)
        raise SystemExit(code)
    monkeypatch.setattr(cli, "run_benchmark", interrupted)
    monkeypatch.setattr(cli.os, "_exit", fake_exit)
    out = tmp_path / "b"
    assert main(_run_args(blender_scene, out)) == 130
    assert exits == [130]
    assert _error_line(capsys) == (f"senerf-bench: interrupted; finished runs are in {out / 'results.jsonl'}, "
                                   "rerun to resume")


def test_a_file_where_the_runs_folder_goes_is_refused_before_any_fit(blender_scene, tmp_path, capsys):
    # Catches: the runs folder's OSError not caught (a FileExistsError traceback, exit 1) or not naming --out, or
    # naming OUT rather than the file in the way, OUT/runs (so before 2026-11-23).
    out = tmp_path / "b"
    out.mkdir()
    (out / "runs").write_text("mine")
    assert main(_run_args(blender_scene, out)) == 2
    assert _error_line(capsys) == (f"senerf-bench: error: {out / 'runs'}: cannot write there (File exists); "
                                   "choose another --out")
    assert (out / "runs").read_text() == "mine"


def test_only_torn_lines_skips_blank_lines():
    # Catches: a blank line read as someone else's text (a results file torn on its first append, with blank lines
    # around, refused as "not a senerf-bench results file").
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.jsonl"
        path.write_bytes(b"\n   \n{\"run_key\": \"x\", \"sta\n\n")
        assert cli._only_torn_lines(path) is True
        path.write_bytes(b"\n{\"a\": 1}\n")
        assert cli._only_torn_lines(path) is False


def test_a_results_file_that_cannot_be_read_is_one_line_naming_it(monkeypatch, blender_scene, tmp_path, capsys):
    # Catches: load_results' OSError escaping as a traceback, or the "choose another --results" hint lost (or
    # given where no flag chose the file).
    results = tmp_path / "r.jsonl"
    results.write_text(json.dumps(_FINISHED) + "\n")

    def unreadable(path, skipped=None):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))
    monkeypatch.setattr(cli, "load_results", unreadable)
    assert main(["summarize", str(results)]) == 2
    assert _error_line(capsys) == f"senerf-bench: error: {results}: cannot read (Permission denied)"
    assert main(_run_args(blender_scene, tmp_path / "b", "--results", str(results), "--dry-run")) == 2
    assert _error_line(capsys) == (f"senerf-bench: error: {results}: cannot read (Permission denied); "
                                   "choose another --results")


def test_a_scene_files_error_keeps_naming_the_file_not_a_flag(tmp_path, capsys):
    # Catches: _flags_named swallowing (or renaming to --protocols) an InputError that names a file.
    d = _blender(tmp_path, "{")
    assert main(["run", "--scenes", str(d), "--out", str(tmp_path / "b"), "--dry-run"]) == 2
    assert _error_line(capsys).startswith(f"senerf-bench: error: {d / 'transforms_train.json'}: frames: cannot "
                                          "count training frames (")


def test_an_input_that_cannot_be_compared_is_not_taken_for_the_output(monkeypatch, tmp_path):
    # Catches: samefile's OSError not caught (a traceback), or taken as "the same file" (a report refused).
    results = tmp_path / "r.jsonl"
    results.write_text("")
    out = tmp_path / "out.md"
    out.write_text("")
    with pytest.raises(InputError, match=rf"^{results}: is {results}, which this command reads; choose another --out$"):
        cli._not_an_input(results, "--out", [str(results)])

    def cannot_stat(a, b):
        raise OSError(errno.EIO, "Input/output error")
    monkeypatch.setattr(cli.os.path, "samefile", cannot_stat)
    assert cli._not_an_input(results, "--out", [str(out), str(results)]) is None


def test_a_masks_or_into_file_that_cannot_be_read_is_one_line_naming_it(tmp_path, capsys):
    # Catches: _read_text's OSError escaping (a FileNotFoundError traceback for a mistyped --into or --masks).
    results = tmp_path / "r.jsonl"
    results.write_text(json.dumps({**_FINISHED, "protocol": "synthetic-extreme3@100", "commit": "c", "machine": {},
                                   "timestamp": "2026-01-01T00:00", "bench_command": ["senerf-bench"]}) + "\n")
    missing = tmp_path / "missing.md"
    with pytest.raises(InputError, match=rf"^{missing}: cannot read \(No such file or directory\)$"):
        cli._read_text(missing)
    assert main(["report", str(results), "--into", str(missing), "--out", str(tmp_path / "rep.md")]) == 2
    assert _error_line(capsys) == f"senerf-bench: error: {missing}: cannot read (No such file or directory)"
    assert main(["report", str(results), "--masks", str(missing), "--out", str(tmp_path / "rep.md")]) == 2
    # (before 2026-11-23 it read "not JSON (... cannot read ...)": _read_text's InputError is a ValueError, and was
    # caught as bad JSON)
    assert _error_line(capsys) == f"senerf-bench: error: {missing}: cannot read (No such file or directory)"
    assert not (tmp_path / "rep.md").exists()


def test_plot_without_a_finished_run_is_refused_before_the_folder_is_made(tmp_path, capsys):
    # Catches: the no-finished-runs check dropped (an empty plots folder and exit 0 for a benchmark whose every run
    # failed).
    results = tmp_path / "r.jsonl"
    results.write_text(json.dumps({"run_key": "k", "status": "failed", "error": "x"}) + "\n")
    assert main(["plot", str(results), "--out-dir", str(tmp_path / "plots")]) == 2
    assert _error_line(capsys) == f"senerf-bench: error: {results}: no finished runs to plot"
    assert not (tmp_path / "plots").exists()


@pytest.mark.parametrize("module", ["senerf.bench", "senerf.bench.cli"])
def test_the_module_entry_points_exit_with_mains_status(module, monkeypatch, tmp_path, capsys):
    # Catches: `python -m senerf.bench` (or of the cli module) calling main without sys.exit (exit 0 on bad input).
    monkeypatch.setattr(sys, "argv", ["senerf-bench", "summarize", str(tmp_path / "none.jsonl")])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # runpy: the module is already imported
        with pytest.raises(SystemExit) as info:
            runpy.run_module(module, run_name="__main__")
    assert info.value.code == 2
    assert _error_line(capsys) == f"senerf-bench: error: {tmp_path / 'none.jsonl'}: results file not found"


# ---------------------------------------------------------------- demo.py


@pytest.mark.parametrize("marker", ["{", "[0]"], ids=["torn", "not-an-object"])
def test_a_damaged_demo_marker_is_not_taken_for_another_seed(tmp_path, marker):
    # Catches: the damaged-marker fallback dropped in _check_fit_seed (a JSONDecodeError / AttributeError
    # traceback where the scene is to be rebuilt and senerf-fit compares the run).
    from senerf.demo import _check_fit_seed

    (tmp_path / "demo_scene").mkdir()
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "run.json").write_text("{}")
    (tmp_path / "demo_scene" / "procedural.json").write_text(marker)
    assert _check_fit_seed(tmp_path, 1, False) is None
    (tmp_path / "demo_scene" / "procedural.json").write_text(json.dumps({"camera_seed": 0}))
    with pytest.raises(InputError, match=rf"^{tmp_path / 'fit'}: holds a different run \(train\.seed: 0 in the "):
        _check_fit_seed(tmp_path, 1, False)


# ---------------------------------------------------------------- defects the lines above turned up (2026-11-23)


def _full_line(**over) -> str:
    """A finished line with every field senerf-bench run writes."""
    from senerf.bench.results import REQUIRED_OK_FIELDS

    line = {**_FINISHED, "schema": 1, "timestamp": "2026-01-01T00:00", "protocol": "synthetic-extreme3@100",
            "resolution": [100, 100], "views": None, "n_views": None, "run_seconds": 1.0, "commit": "c",
            "machine": {}, "fit_command": ["senerf-fit"], "bench_command": ["senerf-bench"], **over}
    assert REQUIRED_OK_FIELDS.keys() <= line.keys()
    return json.dumps(line) + "\n"


def test_plot_draws_a_run_whose_memory_was_not_measured(tmp_path, capsys):
    # Catches: plot_frontier handing a None mean to errorbar (a TypeError traceback for a line the loader accepts
    # with peak_memory_mib null, "not measured"; so before 2026-11-23).
    results = tmp_path / "r.jsonl"
    results.write_text(_full_line(peak_memory_mib=None))
    assert main(["plot", str(results), "--out-dir", str(tmp_path / "p")]) == 0
    assert (tmp_path / "p" / "frontier_s_synthetic-extreme3_at_100.png").is_file()


def test_the_driver_logs_a_run_whose_memory_was_not_measured(tmp_path):
    # Catches: the driver formatting a None peak memory with :.0f (a TypeError that stopped the whole benchmark
    # after a run whose .maxrss file could not be read; so before 2026-11-23).
    from senerf.bench.executors import LocalExecutor
    from senerf.bench.runner import RunnerConfig, run_benchmark
    from senerf.bench.specs import RunSpec

    spec = RunSpec("/d/s", "s", "synthetic-extreme3@100", "baseline", "fast", 0, 0)
    row = {"iteration": 0, "psnr": 20.0, "ssim": 0.5, "lpips": "unavailable", "avg": "unavailable", "seconds": 1.0}
    metrics = {"resolution": [100, 100], "iterations": [row]}
    outcome = {"status": "ok", "metrics": metrics, "run_seconds": 1.0, "peak_memory_mib": None,
               "fit_command": ["senerf-fit"], "returncode": 0, "machine": {}, "error": None, "log": ""}
    lines: list[str] = []
    executor = LocalExecutor(1)
    try:
        run_benchmark([spec, spec], executor, tmp_path / "r.jsonl", RunnerConfig(str(tmp_path / "runs")), ["x"],
                      commit="c", log=lines.append, run_fn=lambda s, c: outcome)
    finally:
        executor.shutdown()
    assert any(line.endswith("PSNR 20.00  1 s  memory not measured") for line in lines), lines
    assert lines[0] == "1 runs: 0 already finished, 1 to run"   # the spec given twice counts once (was "2 runs")


def test_report_and_plot_name_a_finished_line_lacking_a_field_they_read(tmp_path, capsys):
    # Catches: report reading r['commit'] (and plot r's SSIM) of a line the loader accepts without them: a
    # KeyError / TypeError traceback (so before 2026-11-23); summarize still takes the line.
    results = tmp_path / "r.jsonl"
    line = json.loads(_full_line())
    del line["commit"]
    results.write_text(json.dumps(line) + "\n")
    assert main(["report", str(results)]) == 2
    assert _error_line(capsys) == (f"senerf-bench: error: {results}: run k: commit: missing (senerf-bench run "
                                   "writes it; this command reads it)")
    del line["ssim"]
    results.write_text(json.dumps(line) + "\n")
    assert main(["plot", str(results), "--out-dir", str(tmp_path / "p")]) == 2
    assert _error_line(capsys).endswith(f"{results}: run k: ssim: missing (senerf-bench run writes it; this "
                                        "command reads it)")
    assert not (tmp_path / "p").exists()
    assert main(["summarize", str(results)]) == 0 and "20.00" in capsys.readouterr().out


def test_report_names_the_file_and_run_of_an_unknown_protocol(tmp_path, capsys):
    # Catches: the unknown-protocol error of a results line naming neither the file nor the run (so before
    # 2026-11-23: "senerf-bench: error: protocol: unknown protocol 'p'; ...").
    results = tmp_path / "r.jsonl"
    results.write_text(_full_line(protocol="p", run_key="k7"))
    assert main(["report", str(results)]) == 2
    line = _error_line(capsys)
    assert line.startswith(f"senerf-bench: error: {results}: protocol: unknown protocol 'p'; choose from ")
    assert line.endswith(" (run k7)")
    # a failed run's line is not reported on, whatever its protocol: the report of the finished one goes on
    results.write_text(_full_line() + json.dumps({"run_key": "k8", "status": "failed", "error": "x",
                                                  "protocol": "p"}) + "\n")
    assert main(["report", str(results)]) == 0


def test_a_grid_with_duplicates_counts_each_run_once(blender_scene, tmp_path, capsys):
    # Catches: the count line using len(specs) (so before 2026-11-23: "# 8 runs: 0 already finished, 1 to run").
    assert main(["run", "--scenes", str(blender_scene), str(blender_scene), "--protocols", "synthetic-extreme3@100",
                 "--methods", "baseline", "baseline", "--presets", "fast", "--seeds", "0", "0", "--out",
                 str(tmp_path / "b"), "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "# 1 runs: 0 already finished, 1 to run"


def test_random8_on_a_train_split_of_fewer_views_is_refused_naming_the_scene(blender_factory, tmp_path, capsys):
    # Catches: expand_specs accepting a random8 protocol on a 5-frame scene, which then failed in fit_args with a
    # ValueError traceback (so before 2026-11-23); 8 frames are accepted.
    small = _blender(tmp_path, {"frames": [{"file_path": f"./train/r_{i}"} for i in range(5)]}, image_side=400,
                     name="small")
    args = ["run", "--scenes", str(small), "--protocols", "synthetic-random8@400", "--methods", "baseline",
            "--out", str(tmp_path / "b"), "--dry-run"]
    assert main(args) == 2
    assert _error_line(capsys) == (f"senerf-bench: error: {small}: --protocols: synthetic-random8@400 draws 8 "
                                   "training views; the train split has 5")
    eight = _blender(tmp_path, {"frames": [{"file_path": f"./train/r_{i}"} for i in range(8)]}, image_side=400,
                     name="eight")
    assert main([*args[:2], str(eight), *args[3:]]) == 0


def test_a_downscale_that_does_not_fit_names_the_scene(blender_factory, tmp_path, capsys):
    # Catches: the downscale error not saying which of the scenes cannot give the protocol's size (so before
    # 2026-11-23: "--protocols: images of 400x400 cannot be downscaled to 800x800").
    small = blender_factory(tmp_path, name="lego400", side=400)
    assert main(["run", "--scenes", str(small), "--protocols", "synthetic-extreme3@800", "--methods", "baseline",
                 "--out", str(tmp_path / "b"), "--dry-run"]) == 2
    assert _error_line(capsys) == (f"senerf-bench: error: {small}: --protocols: images of 400x400 cannot be "
                                   "downscaled to 800x800 (synthetic-extreme3@800)")


@pytest.mark.parametrize("height", [float("nan"), float("inf"), 0.0])
def test_a_poses_bounds_image_size_that_is_not_a_size_is_named(tmp_path, height):
    # Catches: int(round(hwf)) of a NaN / infinite size outside the try (a ValueError / OverflowError traceback;
    # so before 2026-11-23), or a zero size taken.
    import numpy as np

    from senerf.bench.protocols import native_size

    d = tmp_path / "fern"
    d.mkdir()
    pb = np.zeros((2, 17))
    pb[:, 4], pb[:, 9] = height, 4032
    np.save(d / "poses_bounds.npy", pb)
    with pytest.raises(InputError, match=rf"^{d / 'poses_bounds.npy'}: hwf: the image size must be finite and >= 1"):
        native_size(d)


def test_a_file_path_that_is_not_a_string_is_named(tmp_path):
    # Catches: Path(rel) of a number outside the try (a TypeError traceback; so before 2026-11-23).
    from senerf.bench.protocols import native_size

    d = _blender(tmp_path, {"frames": [{"file_path": 5}]})
    with pytest.raises(InputError, match=rf"^{d / 'transforms_train.json'}: frames\[0\]\.file_path: must be a "
                                         "string, got 5$"):
        native_size(d)


@pytest.mark.parametrize("name", ["synthetic-extreme3@²", "llff3@5０4x378", "llff3@504x³"])
def test_a_resolution_of_other_digits_is_refused_not_crashed_on(name):
    # Catches: str.isdigit() taking '²' (then int() raising a ValueError traceback; so before 2026-11-23).
    from senerf.bench.protocols import parse_protocol

    with pytest.raises(InputError, match="resolution must be"):
        parse_protocol(name)
    assert parse_protocol("llff3@504x378").size == (378, 504)   # the accepted side


def test_extreme_views_of_a_scene_without_them_are_refused_before_any_fit(blender_factory, tmp_path, capsys):
    # Catches: a grid whose Extreme protocol the scene has no views for listed by --dry-run and run, every fit then
    # failing with the reason only in its log (so before 2026-11-23); 'Lego' (any case) has them.
    mine = blender_factory(tmp_path, name="my_capture", side=400)
    args = ["run", "--scenes", str(mine), "--protocols", "synthetic-extreme3@100", "--methods", "baseline",
            "--out", str(tmp_path / "b"), "--dry-run"]
    assert main(args) == 2
    line = _error_line(capsys)
    assert line.startswith(f"senerf-bench: error: {mine}: --protocols: synthetic-extreme3@100 uses the published "
                           "Extreme views, known for chair, drums, ") and line.endswith("'my_capture' is none of them")
    lego = blender_factory(tmp_path, name="Lego", side=400)
    assert main([*args[:2], str(lego), *args[3:]]) == 0


@pytest.mark.parametrize("command, problem", [
    ('x "', "cannot be split into words (No closing quotation): 'x \"'"),
    ("", "is empty; leave it out to run senerf-fit"),
    ("  ", "is empty; leave it out to run senerf-fit")])
def test_a_fit_command_that_is_not_a_command_is_refused(blender_scene, tmp_path, capsys, command, problem):
    # Catches: shlex's ValueError on an unclosed quote escaping as a traceback, and an empty command silently
    # replaced by senerf-fit (so before 2026-11-23).
    assert main(["run", "--scenes", str(blender_scene), "--protocols", "synthetic-extreme3@100", "--methods",
                 "baseline", "--out", str(tmp_path / "b"), "--fit-command", command, "--dry-run"]) == 2
    assert _error_line(capsys) == f"senerf-bench: error: --fit-command: {problem}"
