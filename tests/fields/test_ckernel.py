"""The compiled K-Planes kernel's build, cache and fallback (senerf.fields.ckernel); its numbers against the
references are checked in test_kplanes.py, test_encoding.py and (the feature similarity)
selftrain/test_reliability.py."""

from __future__ import annotations

import os
import platform
import shutil
import stat
import sys

import pytest
import torch

import senerf.fields.ckernel as ck

HAVE_CC = bool(os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc"))
POSIX = sys.platform != "win32"


@pytest.fixture
def fresh(tmp_path, monkeypatch):
    """The loader with no library loaded yet and its cache in ``tmp_path / 'cache'``; afterwards the loader
    starts afresh again, so no other test gets a library (or a failure) made here."""
    monkeypatch.setenv("SENERF_CACHE", str(tmp_path / "cache"))
    monkeypatch.setitem(ck._STATUS, "status", ck._STATUS["status"])
    ck.load_kernel.cache_clear()
    ck._target.cache_clear()
    yield tmp_path / "cache"
    ck.load_kernel.cache_clear()
    ck._target.cache_clear()


def _fake_cc(folder, body: str) -> str:
    """A shell script standing in for the C compiler: ``body`` runs with the compiler's arguments in ``$@``."""
    path = folder / "fake-cc"
    path.write_text("#!/bin/sh\n" + body + "\n")
    path.chmod(0o755)
    return str(path)


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler on PATH or in $CC")
def test_the_kernel_is_compiled_once_into_the_cache_and_then_loaded_from_it(fresh, monkeypatch):
    lib = ck.load_kernel(torch.float64, 3)
    assert lib is not None and lib.kp_nf() == 3 and ck.kernel_status() == "loaded"
    built = sorted(p.name for p in fresh.iterdir())
    assert len(built) == 1 and built[0].startswith("kplanes_double_f3_") and built[0].endswith(".so")   # no temp file

    def no_compiler(*args, **kwargs):
        raise AssertionError("compiled again")
    ck.load_kernel.cache_clear()   # a new process: the probe of the compiler is remembered, the build must be found
    monkeypatch.setattr(ck.subprocess, "run", no_compiler)
    assert ck.load_kernel(torch.float64, 3).kp_nf() == 3
    assert sorted(p.name for p in fresh.iterdir()) == built


@pytest.mark.skipif(not (HAVE_CC and POSIX and platform.machine() in ("x86_64", "AMD64")),
                    reason="needs a C compiler on an x86-64 POSIX machine")
def test_a_cache_shared_with_another_cpu_never_hands_over_a_library_built_for_it(fresh, tmp_path, monkeypatch):
    # The same compiler command on a CPU with another instruction set (here: the compiler told to target
    # plain x86-64) must build its own library instead of loading the one built for this CPU.
    real = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    monkeypatch.setenv("CC", _fake_cc(tmp_path, f'exec {real} "$@" ${{FAKE_MARCH:+-march=$FAKE_MARCH}}'))
    assert ck.load_kernel(torch.float32, 2) is not None
    ck.load_kernel.cache_clear()
    ck._target.cache_clear()
    monkeypatch.setenv("FAKE_MARCH", "x86-64")
    assert ck.load_kernel(torch.float32, 2) is not None
    assert len(list(fresh.glob("kplanes_float_f2_*.so"))) == 2


@pytest.mark.skipif(not POSIX, reason="the stand-in compilers are shell scripts")
@pytest.mark.parametrize("case", ["no compiler", "no such $CC", "source missing", "compile error", "unloadable",
                                  "no cache folder"])
def test_the_warning_without_the_kernel_names_the_true_reason_in_one_line(case, fresh, tmp_path, monkeypatch):
    # Catches: a reason that advises a C compiler where one would not help (a missing source, an unusable cache
    # folder, a compiler that fails), or a multi-line compiler error reaching the one-line warning.
    if case == "no compiler":
        monkeypatch.delenv("CC", raising=False)
        monkeypatch.setattr(ck.shutil, "which", lambda name: None)
        expected = ["no C compiler found: install one", "$CC"]
    elif case == "no such $CC":
        monkeypatch.setenv("CC", str(tmp_path / "missing-cc"))
        expected = [f"$CC names {tmp_path / 'missing-cc'}, which is no program on PATH"]
    elif case == "source missing":
        monkeypatch.setattr(ck, "_SRC", tmp_path / "_kplanes_kernel.c")
        expected = [f"its C source {tmp_path / '_kplanes_kernel.c'} is missing from this installation",
                    "reinstall senerf"]
    elif case == "compile error":   # preprocessing works, compiling fails with a two-line diagnostic
        monkeypatch.setenv("CC", _fake_cc(tmp_path, 'case "$*" in *-E*) exit 0;; esac\n'
                                                    'echo "k.c: In function f:" >&2\n'
                                                    'echo "k.c:3:1: error: it broke" >&2\necho "second" >&2\nexit 1'))
        expected = ["fake-cc failed (exit status 1): k.c:3:1: error: it broke"]
    elif case == "unloadable":      # the compiler "succeeds" but writes no library
        monkeypatch.setenv("CC", _fake_cc(tmp_path, 'for a; do [ "$prev" = -o ] && echo junk > "$a"; prev=$a; done'))
        expected = ["the compiled library", "cannot be loaded"]
    else:
        blocker = tmp_path / "a-file"
        blocker.write_text("")
        monkeypatch.setenv("SENERF_CACHE", str(blocker / "cache"))
        monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
        monkeypatch.setattr(ck.tempfile, "gettempdir", lambda: str(blocker))
        expected = ["no writable folder to cache it in: set $SENERF_CACHE to one"]
    line = ck.cpu_planes_warning(16)
    assert ck.cpu_planes_path(16) == "pytorch" and line is not None and "\n" not in line
    why = line.removeprefix("the compiled K-Planes kernel cannot be used (").split("); the pure-PyTorch path")[0]
    assert all(part in why for part in expected), why
    assert ("compiler" in why) == (case == "no compiler"), why   # a compiler is advised only where it helps
    assert ck.kernel_status() == f"unavailable: {why}"


def test_the_warning_past_the_feature_limit_names_the_limit():
    assert ck.cpu_planes_path(ck.MAX_FEATURES + 1) == "pytorch"
    assert "(more than 256 features per plane)" in ck.cpu_planes_warning(ck.MAX_FEATURES + 1)


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler on PATH or in $CC")
def test_with_the_kernel_there_is_no_warning(fresh):
    assert ck.cpu_planes_path(16) == "compiled" and ck.cpu_planes_warning(16) is None


@pytest.mark.skipif(not hasattr(os, "getuid"), reason="no user ids here")
def test_the_cache_falls_back_to_a_private_temp_folder_and_refuses_one_others_may_write(tmp_path, monkeypatch):
    # Catches: an unusable $SENERF_CACHE stopping the kernel instead of falling back, or a temp-folder cache that
    # another user could have made (or may write to) being trusted: a library planted there would be run.
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("SENERF_CACHE", str(blocker / "cache"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert ck._cache_dir() == tmp_path / "xdg" / "senerf"
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    monkeypatch.setattr(ck.tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    private = ck._cache_dir()
    assert private == tmp_path / "tmp" / f"senerf-cache-{os.getuid()}"
    assert stat.S_IMODE(private.stat().st_mode) & 0o077 == 0
    private.chmod(0o777)
    with pytest.raises(OSError, match="no writable folder to cache it in"):
        ck._cache_dir()


def test_load_kernel_refuses_other_dtypes_and_feature_counts_and_falls_back_when_the_build_fails(monkeypatch):
    # Catches: load_kernel's dtype / 1 <= n_features <= MAX_FEATURES check deleted or off by one, or its
    # "except Exception" fallback deleted (a failed build raised instead of returning None for the PyTorch path).
    built = []

    def failing_build(real, nf):
        built.append((real, nf))
        raise OSError("boom")
    monkeypatch.setattr(ck, "_build", failing_build)
    monkeypatch.setitem(ck._STATUS, "status", ck._STATUS["status"])   # restored afterwards
    load = ck.load_kernel.__wrapped__   # past the per-process cache
    for dtype, nf in ((torch.float16, 16), (torch.int32, 16), (torch.float32, 0), (torch.float32, ck.MAX_FEATURES + 1)):
        assert load(dtype, nf) is None
    assert built == []                  # refused before any build
    assert load(torch.float32, 1) is None and load(torch.float64, ck.MAX_FEATURES) is None
    assert built == [("float", 1), ("double", 256)]
    assert ck.kernel_status() == "unavailable: OSError: boom"
