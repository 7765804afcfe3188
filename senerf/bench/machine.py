"""Where a result came from: the code's commit and the machine's description (no torch import)."""

from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

from senerf.memory import cpu_model

__all__ = ["git_commit", "machine_info"]


def git_commit(repo: str | Path | None = None) -> str:
    """``git describe --always --dirty --abbrev=40`` of ``repo`` (default: the senerf checkout).

    Returns the full commit hash, with ``-dirty`` appended when tracked files differ from it, or
    ``"unknown"`` when git or the repository is unavailable.
    """
    repo = Path(repo) if repo is not None else Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=40"], cwd=repo,
                             capture_output=True, text=True, timeout=30, check=True)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() or "unknown"


def machine_info(device: str = "cpu") -> dict:
    """Description of this machine, JSON-ready.

    Keys: ``hostname``, ``cpu`` (model name), ``cores`` (logical CPUs), ``cores_usable`` (CPU affinity of
    this process), ``memory_gib``, ``torch`` (installed version, read from package metadata without
    importing torch), ``python``, ``device`` (``"cpu"`` or the GPU's name for ``"cuda"``).
    """
    return {
        "hostname": platform.node(),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "memory_gib": _memory_gib(),
        "torch": _version("torch"),
        "python": platform.python_version(),
        "device": device if device == "cpu" else _gpu_name(device),
    }


def _memory_gib() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except (OSError, ValueError, IndexError):   # IndexError: a MemTotal line without its value
        pass
    return None


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def _gpu_name(device: str) -> str:
    """``"cuda:1: <name>"``: ``nvidia-smi``'s name of the GPU ``device`` selects (its index through
    ``CUDA_VISIBLE_DEVICES`` when that lists indices); ``device`` alone when that cannot be told (no nvidia-smi,
    UUIDs in ``CUDA_VISIBLE_DEVICES``, an index beyond the list).  nvidia-smi counts in PCI bus order, CUDA (without
    ``CUDA_DEVICE_ORDER=PCI_BUS_ID``) fastest first; each fit's own ``metrics.json`` ``host`` names the GPU torch
    used."""
    index = int(device.partition(":")[2] or 0)
    visible = [v.strip() for v in os.environ.get("CUDA_VISIBLE_DEVICES", "").split(",") if v.strip()]
    if visible:
        if index >= len(visible) or not visible[index].isdecimal():
            return device
        index = int(visible[index])
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=30, check=True)
    except (OSError, subprocess.SubprocessError):
        return device
    names = [n.strip() for n in out.stdout.splitlines() if n.strip()]
    return f"{device}: {names[index]}" if index < len(names) else device
