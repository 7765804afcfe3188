"""senerf.cliargs: the flag converters' bounds (inclusive at both ends), and one ``argument --flag: problem``
line through argparse."""

from __future__ import annotations

import errno
import subprocess
import sys

import pytest

from senerf.cliargs import SEED_MAX, OneLineParser, float_flag, int_flag
from senerf.errors import InputError


def _parse(type_, text: str):
    parser = OneLineParser(prog="prog")
    parser.add_argument("--x", type=type_)
    return parser.parse_args([f"--x={text}"]).x  # "--x=-inf": not taken for an option


@pytest.mark.parametrize("kwargs, accepted, refused, bound", [
    ({}, ["1", "7"], ["0", "-1"], ">= 1"),
    ({"allow_zero": True}, ["0", "1"], ["-1"], ">= 0"),
    ({"minimum": 2}, ["2", "3"], ["1"], ">= 2"),
    ({"allow_zero": True, "maximum": 5}, ["0", "5"], ["6", "-1"], ">= 0 and <= 5"),
    ({"allow_zero": True, "maximum": SEED_MAX}, ["9223372036854775807"], ["9223372036854775808"],
     ">= 0 and <= 9223372036854775807"),
])
def test_int_flag_bounds_are_inclusive(kwargs, accepted, refused, bound):
    for text in accepted:
        assert _parse(int_flag("--x", **kwargs), text) == int(text)
    for text in refused:
        with pytest.raises(InputError) as info:
            _parse(int_flag("--x", **kwargs), text)
        assert str(info.value) == f"argument --x: must be {bound}, got {int(text)}"


def test_int_flag_refuses_a_non_integer():
    for text in ("1.5", "x", ""):
        with pytest.raises(InputError) as info:
            _parse(int_flag("--x"), text)
        assert str(info.value) == f"argument --x: expected an integer, got {text!r}"


@pytest.mark.parametrize("kwargs, accepted, refused, bound", [
    ({}, ["-3.5", "0", "1e300"], [], ""),
    ({"minimum": 1.0}, ["1", "1.5"], ["0.999"], " >= 1"),
    ({"positive": True}, ["1e-300", "2"], ["0", "-0.0", "-1"], " > 0"),
    ({"minimum": 0.0, "maximum": 0.5}, ["0", "0.5"], ["-1e-9", "0.5000001"], " >= 0 and <= 0.5"),
    ({"maximum": 2.0}, ["2", "-7"], ["2.01"], " <= 2"),
    # both lower bounds named (the message said only "> 0" at 7c49076, though 0.2 was refused for minimum 0.5) ...
    ({"positive": True, "minimum": 0.5}, ["0.5", "3"], ["0.2", "0"], " > 0 and >= 0.5"),
    # ... and positive with a maximum, as before (its message was right at 7c49076 too)
    ({"positive": True, "maximum": 3.0}, ["3", "1e-9"], ["3.5", "0"], " > 0 and <= 3"),
])
def test_float_flag_bounds_are_inclusive_and_refuse_non_finite(kwargs, accepted, refused, bound):
    for text in accepted:
        assert _parse(float_flag("--x", **kwargs), text) == float(text)
    for text in [*refused, "nan", "inf", "-inf", "Infinity"]:
        with pytest.raises(InputError) as info:
            _parse(float_flag("--x", **kwargs), text)
        assert str(info.value) == f"argument --x: expected a finite number{bound}, got {text!r}"


def test_parser_errors_are_input_errors_not_exits():
    parser = OneLineParser(prog="prog")
    parser.add_argument("--x", type=int_flag("--x"), required=True)
    for argv, needle in ((["--x", "1", "--bogus"], "unrecognized arguments: --bogus"),
                         ([], "the following arguments are required: --x")):
        with pytest.raises(InputError, match=needle) as info:
            parser.parse_args(argv)
        assert "\n" not in str(info.value)


def test_run_command_maps_every_way_out_to_its_exit_status(capsys):
    from senerf.cliargs import run_command

    def raising(exc):
        def body():
            raise exc
        return body

    assert run_command("prog", lambda: 0, "x") == 0
    assert run_command("prog", raising(InputError("bad", field="--f")), "x") == 2
    assert capsys.readouterr().err == "prog: error: --f: bad\n"
    assert run_command("prog", raising(SystemExit(0)), "x") == 0     # --help
    assert run_command("prog", raising(SystemExit("usage")), "x") == 2
    assert run_command("prog", raising(KeyboardInterrupt()), "rerun it") == 130
    assert capsys.readouterr().err == "prog: interrupted (rerun it)\n"
    assert run_command("prog", raising(RuntimeError("boom")), "x") == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "RuntimeError: boom" in err
    assert err.endswith("prog: internal error (please report it with the traceback above)\n")
    # before: a full disk printed a traceback and asked for a bug report
    assert run_command("prog", raising(OSError(errno.ENOSPC, "No space left on device")), "rerun it") == 2
    assert capsys.readouterr().err == "prog: error: No space left on device; free some space (rerun it)\n"
    assert run_command("prog", raising(OSError(errno.EDQUOT, "Disk quota exceeded", "/o/c.pt")), "rerun it") == 2
    assert capsys.readouterr().err == "prog: error: /o/c.pt: Disk quota exceeded; free some space (rerun it)\n"

    def torch_save_on_a_full_disk():   # what torch.save raises when the disk fills (measured on a 3 MB tmpfs)
        try:
            raise OSError(errno.ENOSPC, "No space left on device")
        except OSError:
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 3010624 vs 3010536")
    assert run_command("prog", torch_save_on_a_full_disk, "rerun it") == 2
    assert capsys.readouterr().err == "prog: error: No space left on device; free some space (rerun it)\n"

    def interrupted_import():   # a Ctrl-C inside a lazy import, then a cleanup that imports it again (at 7c49076 a
        try:                    # fuzzed fit exited 1 with such an ImportError's traceback)
            raise KeyboardInterrupt
        finally:
            raise ImportError("cannot import name 'linalg' from partially initialized module 'numpy'")
    assert run_command("prog", interrupted_import, "rerun it") == 130
    assert capsys.readouterr().err.startswith("prog: interrupted (rerun it); while stopping: ImportError: ")
    looped = RuntimeError("a")   # a chain that loops ends the search
    looped.__context__ = ValueError("b")
    looped.__context__.__context__ = looped
    assert run_command("prog", raising(looped), "x") == 1
    assert "RuntimeError: a" in capsys.readouterr().err
    caused = RuntimeError("write failed")          # an explicit cause (raise ... from), with no context
    caused.__cause__ = OSError(errno.ENOSPC, "No space left on device", "/o/x.png")
    assert run_command("prog", raising(caused), "rerun it") == 2
    assert capsys.readouterr().err == "prog: error: /o/x.png: No space left on device; free some space (rerun it)\n"


def test_run_command_prints_warnings_as_one_line_each(capsys):
    import warnings

    from senerf.cliargs import run_command

    def body():
        warnings.warn("a warning\n   over two lines", UserWarning)
        return 0
    assert run_command("prog", body, "x") == 0
    assert capsys.readouterr().err == "prog: warning: a warning over two lines\n"
    assert warnings.showwarning.__name__ != "one_line"      # restored afterwards


def test_run_command_treats_sigterm_as_an_interrupt_and_restores_the_handler(capsys):
    import os
    import signal

    from senerf.cliargs import run_command

    before = signal.getsignal(signal.SIGTERM)
    cleaned = []

    def body():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            signal.pause() if hasattr(signal, "pause") else None   # pragma: no cover - the signal lands first
        finally:
            cleaned.append(True)                                    # a finally block runs (temp folders go)
        return 0
    assert run_command("prog", body, "rerun it") == 130
    assert capsys.readouterr().err == "prog: interrupted (rerun it)\n" and cleaned == [True]
    assert signal.getsignal(signal.SIGTERM) == before


@pytest.mark.parametrize("text", ["abc", "", "1,5", "0x10"])
def test_float_flag_names_the_flag_for_text_that_is_no_number(text):
    with pytest.raises(InputError) as info:
        _parse(float_flag("--x", minimum=0.0), text)
    assert str(info.value) == f"argument --x: expected a number, got {text!r}"


@pytest.mark.parametrize("device", ["cuda:x", "cuda:", "cuda:01", "cuda:-1", "cudafoo", "CUDA", "cpu:0", "tpu"])
def test_malformed_devices_are_refused_by_name(device, monkeypatch):
    import torch

    from senerf.cliargs import check_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)   # the name is wrong whatever the machine
    with pytest.raises(InputError, match=r"--device.*expected cpu, cuda or cuda:N"):
        check_device(device)


def test_a_gpu_the_machine_lacks_is_refused_by_name(monkeypatch):
    import torch

    from senerf.cliargs import check_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert check_device("cpu") == "cpu" and check_device("cuda") == "cuda" and check_device("cuda:1") == "cuda:1"
    with pytest.raises(InputError, match=r"--device: cuda:2 requested but torch sees 2 GPU\(s\)"):
        check_device("cuda:2")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="--device: CUDA requested but torch sees no GPU"):
        check_device("cuda")


def test_set_threads_sets_torchs_count_and_none_leaves_it():
    import torch

    from senerf.cliargs import THREADS_MAX, set_threads, threads_flag

    before = torch.get_num_threads()
    try:
        set_threads(1)
        assert torch.get_num_threads() == 1
        set_threads(None)
        assert torch.get_num_threads() == 1
        set_threads(2)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    assert _parse(threads_flag(), "1") == 1 and _parse(threads_flag(), str(THREADS_MAX)) == THREADS_MAX
    for bad in ("0", str(THREADS_MAX + 1), "two"):
        with pytest.raises(InputError, match=r"argument --x: (must be >= 1 and <= 1024|expected an integer)"):
            _parse(threads_flag(), bad)


def test_openmp_waits_are_short_by_default_and_the_users_choice_wins():
    from senerf.cliargs import OPENMP_SPINS, short_openmp_waits

    env: dict = {}
    short_openmp_waits(env)
    assert env == {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": str(OPENMP_SPINS)}
    env = {"OMP_WAIT_POLICY": "ACTIVE", "GOMP_SPINCOUNT": "0"}
    short_openmp_waits(env)
    assert env == {"OMP_WAIT_POLICY": "ACTIVE", "GOMP_SPINCOUNT": "0"}


_REFAULTS = """
import resource
import torch
a = torch.ones(25_000_000); del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(3):
    a = torch.ones(25_000_000); del a
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _huge_pages_offered() -> bool:
    try:
        return "[never]" not in open("/sys/kernel/mm/transparent_hugepage/enabled").read()
    except OSError:
        return False


@pytest.mark.skipif(not _huge_pages_offered(), reason="the kernel offers no transparent huge pages")
def test_large_tensors_fault_once_per_huge_page_and_the_users_choice_wins():
    """Three fresh 100 MB tensors written: ~73,000 page faults on 4 KiB pages, a few hundred on huge pages."""
    import os

    from senerf.cliargs import huge_page_tensors

    def refaults(environ: dict) -> int:
        env = {k: v for k, v in os.environ.items() if k != "THP_MEM_ALLOC_ENABLE"} | environ
        return int(subprocess.run([sys.executable, "-c", _REFAULTS], capture_output=True, text=True, check=True,
                                  env=env).stdout)

    env: dict = {}
    huge_page_tensors(env)
    assert env == {"THP_MEM_ALLOC_ENABLE": "1"}
    faults_huge, faults_default = refaults(env), refaults({})
    assert faults_huge < 5_000 and faults_default > 50_000, (faults_huge, faults_default)
    env = {"THP_MEM_ALLOC_ENABLE": "0"}
    huge_page_tensors(env)
    assert env == {"THP_MEM_ALLOC_ENABLE": "0"}


def test_both_commands_set_the_waits_and_huge_pages_before_torch_is_imported(tmp_path):
    """libgomp and torch read the settings when they load, so importing a command's module must not import torch,
    and its main must set them before anything imports torch: a finder records the environment at torch's
    first import (``--threads 1`` imports it, then the missing folder is refused)."""
    import subprocess
    import sys

    for module in ("senerf.cli", "senerf.flythrough"):
        code = (f"import os, sys, {module} as m\n"
                "os.environ.pop('GOMP_SPINCOUNT', None)\n"
                "os.environ.pop('THP_MEM_ALLOC_ENABLE', None)\n"
                "assert 'torch' not in sys.modules, 'imported torch'\n"
                "seen = []\n"
                "class Spy:\n"
                "    def find_spec(self, name, path=None, target=None):\n"
                "        if name == 'torch' and not seen:\n"
                "            seen.append((os.environ.get('GOMP_SPINCOUNT'), os.environ.get('THP_MEM_ALLOC_ENABLE')))\n"
                "        return None\n"
                "sys.meta_path.insert(0, Spy())\n"
                f"assert m.main([{str(tmp_path / 'nowhere')!r}, '--threads', '1']) == 2\n"
                "assert seen == [('1000', '1')], seen\n")
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert done.returncode == 0, (module, done.stderr)


def test_console_entry_exits_with_mains_status_and_ignores_ctrl_c_after_it():
    # Catches: a SIGINT during the interpreter's shutdown, once the command was done, printing an ignored
    # KeyboardInterrupt's traceback (5 of 5 sent 0-10 ms after senerf-fit's last line, at 496c5a9).
    import signal

    from senerf.cliargs import console_entry

    before = signal.getsignal(signal.SIGINT)
    try:
        with pytest.raises(SystemExit) as info:
            console_entry(lambda: 2)
        assert info.value.code == 2 and signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


def test_the_console_scripts_call_console_entry():
    # Catches: a console script (or python -m) left calling main directly, without the quiet exit.
    import tomllib
    from pathlib import Path

    scripts = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts == {"senerf-fit": "senerf.cli:console", "senerf-bench": "senerf.bench.cli:console",
                       "senerf-render": "senerf.flythrough:console", "senerf-view": "senerf.viewer:console",
                       "senerf-export": "senerf.export:console"}
    for module in ("senerf.cli", "senerf.flythrough", "senerf.viewer", "senerf.export"):   # python -m: the same exit
        proc = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 0 and proc.stdout.startswith(
            ("senerf-fit ", "senerf-render ", "senerf-view ", "senerf-export ")), proc.stderr
    proc = subprocess.run([sys.executable, "-m", "senerf.bench"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "the following arguments are required: command" in proc.stderr
