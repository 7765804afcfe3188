"""senerf.memory: the physical memory the up-front checks compare against."""

import os


def test_physical_memory_is_the_pages_times_their_size_or_none(monkeypatch):
    # one reading for every up-front memory check (senerf-fit's planes and features, senerf-render's frames,
    # the known views' eager features), where each had its own copy
    from senerf.memory import physical_memory_bytes

    pages = {"SC_PAGE_SIZE": 4096, "SC_PHYS_PAGES": 2 ** 18}
    monkeypatch.setattr(os, "sysconf", lambda name: pages[name])
    assert physical_memory_bytes() == 2 ** 30

    def unknown(name):
        raise ValueError(name)
    monkeypatch.setattr(os, "sysconf", unknown)
    assert physical_memory_bytes() is None


def test_import_does_not_import_torch():
    import subprocess
    import sys

    code = "import senerf.memory; import sys; assert 'torch' not in sys.modules"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_the_processor_is_read_from_cpuinfo_with_a_fallback(tmp_path, monkeypatch):
    """Another processor takes other kernels (an Intel Xeon and an AMD EPYC gave lego balanced seed 0 teachers
    0.6 dB apart with the same command, threads and builds): metrics.json rows and the benchmark records name it."""
    import platform

    from senerf.memory import cpu_model

    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel\t\t: 207\n"
                    "model name\t: Intel(R) Xeon(R)  Processor\n\nprocessor\t: 1\nmodel name\t: Other\n")
    assert cpu_model(info) == "Intel(R) Xeon(R) Processor (family 6, model 207)"   # the first one, spaces folded
    info.write_text("model name\t: Fake CPU @ 2.00GHz: v2 \n")   # split at the first colon only, stripped
    assert cpu_model(info) == "Fake CPU @ 2.00GHz: v2"
    monkeypatch.setattr(platform, "processor", lambda: "x86_64-proc")
    monkeypatch.setattr(platform, "machine", lambda: "aarch64")
    assert cpu_model(tmp_path / "absent") == "x86_64-proc"   # no /proc/cpuinfo: the processor first
    for no_model in ("processor\t: 0\nBogoMIPS\t: 50.00\nCPU part\t: 0xd0c\n",   # an Arm machine names none
                     "model name\n", "model name  nocolon\n", "model name\t:\n"):   # lines without their value
        info.write_text(no_model)
        assert cpu_model(info) == "x86_64-proc", no_model
    monkeypatch.setattr(platform, "processor", lambda: "")
    assert cpu_model(tmp_path / "absent") == "aarch64"
    monkeypatch.setattr(platform, "machine", lambda: "")
    assert cpu_model(tmp_path / "absent") == "unknown"
