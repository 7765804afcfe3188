"""This machine: its physical memory, for the up-front checks that refuse work which cannot fit, and its processor,
which a CPU fit's figures depend on (no torch)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

__all__ = ["physical_memory_bytes", "cpu_model"]


def physical_memory_bytes() -> int | None:
    """The machine's physical memory in bytes (``SC_PAGE_SIZE x SC_PHYS_PAGES``), or None where ``sysconf``
    cannot tell (not a POSIX system): the callers then skip their check."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def cpu_model(cpuinfo: str | Path = "/proc/cpuinfo") -> str:
    """The processor's model: the first processor's ``model name`` in ``cpuinfo`` (Linux), with its ``cpu family``
    and ``model`` numbers where given (a virtual machine's name can be as plain as "Intel(R) Xeon(R) Processor"),
    else ``platform.processor()``, else ``platform.machine()`` (``'unknown'`` when all are empty).

    Example:
        >>> isinstance(cpu_model(), str) and cpu_model() != ""
        True
    """
    fields = {}
    try:
        with open(cpuinfo, encoding="utf-8", errors="replace") as lines:
            for line in lines:
                if not line.strip() and fields:   # the end of the first processor's block
                    break
                key, _, value = line.partition(":")
                fields.setdefault(key.strip().lower(), " ".join(value.split()))
    except OSError:   # not Linux
        pass
    name = fields.get("model name")
    if not name:
        return platform.processor() or platform.machine() or "unknown"
    numbers = [f"{word} {fields[key]}" for key, word in (("cpu family", "family"), ("model", "model"))
               if fields.get(key)]
    return f"{name} ({', '.join(numbers)})" if numbers else name
