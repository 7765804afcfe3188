"""Executors: where runs execute.  One tiny interface, two implementations.

``submit(fn, *args) -> concurrent.futures.Future`` and ``shutdown()``; the driver
(:func:`senerf.bench.runner.run_benchmark`) uses only these, so local and Ray runs share one code path.

* :class:`LocalExecutor`: a thread pool on this machine.  Each thread only starts a ``senerf-fit`` child
  process and waits for it, so a crash or out-of-memory kill of one fit never touches the pool (a
  ``ProcessPoolExecutor`` would mark itself broken and lose every queued run).
* :class:`RayExecutor`: tasks on a Ray cluster (optional ``[cluster]`` extra, ``ray>=2.9``).  Each task
  runs the same function on a worker, which starts its own ``senerf-fit`` child; the outcome travels back to
  the driver, which alone writes the results file.  Scene folders must exist at the same path on workers.
"""

from __future__ import annotations

import concurrent.futures as cf
from typing import Any, Callable, Protocol

__all__ = ["Executor", "LocalExecutor", "RayExecutor", "make_executor"]


class Executor(Protocol):
    """What the benchmark driver needs from an executor."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> cf.Future:
        """Schedule ``fn(*args)``; the future's result is ``fn``'s return value."""

    def shutdown(self) -> None:
        """Release workers (waits for submitted work)."""


class LocalExecutor:
    """``workers`` concurrent runs on this machine (threads that each wait on one child process)."""

    def __init__(self, workers: int = 1):
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = workers
        self._pool = cf.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="senerf-bench")

    def submit(self, fn: Callable[..., Any], *args: Any) -> cf.Future:
        return self._pool.submit(fn, *args)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=True)


class RayExecutor:
    """Runs tasks on Ray.

    Args:
        address: cluster address (``"auto"``, ``"ray://host:10001"``), or ``None`` to start a private local
            Ray instance (tests) with ``num_cpus`` CPUs and no dashboard.
        num_cpus: CPUs of the private local instance (ignored with an address).
        cpus_per_run: CPUs Ray reserves per run (limits concurrency per node).
        max_retries: how often Ray re-runs a task whose worker process died (the fit itself is a child of
            that worker, so a fit crash is a normal "failed" outcome, not a worker death).
    """

    def __init__(self, address: str | None = None, num_cpus: int | None = None, cpus_per_run: float = 1.0,
                 max_retries: int = 1):
        try:
            import ray
        except ImportError:
            raise ImportError("Ray is not installed: pip install 'senerf[cluster]' (ray>=2.9)") from None
        self._ray = ray
        self._started_here = not ray.is_initialized()
        if self._started_here:
            if address is None:
                ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False,
                         configure_logging=False)
            else:
                ray.init(address=address, log_to_driver=False)
        self._options = {"num_cpus": cpus_per_run, "max_retries": max_retries}
        self._remote: dict[Callable, Any] = {}

    def submit(self, fn: Callable[..., Any], *args: Any) -> cf.Future:
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._remote[fn] = self._ray.remote(fn).options(**self._options)
        return remote.remote(*args).future()

    def shutdown(self) -> None:
        if self._started_here:
            self._ray.shutdown()


def make_executor(workers: int = 1, ray_address: str | None = None, cpus_per_run: float = 1.0) -> Executor:
    """A :class:`RayExecutor` on ``ray_address`` when given, else a :class:`LocalExecutor`."""
    if ray_address:
        return RayExecutor(address=ray_address, cpus_per_run=cpus_per_run)
    return LocalExecutor(workers)
