"""This machine's physical memory, for the up-front checks that refuse work which cannot fit (no torch)."""

from __future__ import annotations

import os

__all__ = ["physical_memory_bytes"]


def physical_memory_bytes() -> int | None:
    """The machine's physical memory in bytes (``SC_PAGE_SIZE x SC_PHYS_PAGES``), or None where ``sysconf``
    cannot tell (not a POSIX system): the callers then skip their check."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None
