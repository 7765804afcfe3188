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
