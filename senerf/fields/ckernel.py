"""The compiled fused K-Planes kernel (``_kplanes_kernel.c``): build, load, call.

The C source is compiled with the system C compiler on first use (about a second) into a cache folder
(``$SENERF_CACHE`` or ``~/.cache/senerf``, else the temp folder), keyed by a hash of source, flags, compiler
and the CPU's feature flags, and loaded with :mod:`ctypes`.  Work is split over ``torch.get_num_threads()`` Python threads
(ctypes releases the GIL), each on its own range of points; in the backward pass every thread accumulates
into its own gradient buffer, so there are no races and the result is deterministic.  Nothing here is
global state beyond a per-process cache of the loaded library.  When no compiler is available,
:func:`load_kernel` returns ``None`` and callers fall back to the pure-PyTorch gather path.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import torch

__all__ = ["load_kernel", "kernel_status", "cpu_planes_path", "cpu_planes_warning", "fused_plane_features",
           "fused_sh4", "MAX_FEATURES", "MAX_SCALES"]

MAX_FEATURES = 256
MAX_SCALES = 8
_SRC = Path(__file__).with_name("_kplanes_kernel.c")
_FLAGS = ["-O3", "-march=native", "-fno-math-errno", "-fPIC", "-shared", "-std=c99"]
_STATUS = {"status": "not loaded"}


def _cache_dir() -> Path:
    env = os.environ.get("SENERF_CACHE")
    cands = [Path(env)] if env else []
    cands += [Path.home() / ".cache" / "senerf", Path(tempfile.gettempdir()) / "senerf-cache"]
    for c in cands:
        try:
            c.mkdir(parents=True, exist_ok=True)
            if os.access(c, os.W_OK):
                return c
        except OSError:
            continue
    raise OSError("no writable cache folder for the compiled kernel")


def _cpu_flags() -> str:
    """The CPU feature flags (``-march=native`` code must not run on another CPU sharing the cache)."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith(("flags", "Features")):
                    return line
    except OSError:
        pass
    return platform.processor()


def _build(real: str, nf: int) -> Path:
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise OSError("no C compiler found")
    src = _SRC.read_bytes()
    key = hashlib.sha256(src + " ".join(_FLAGS + [real, str(nf), cc, platform.machine(), _cpu_flags()]).encode())
    out = _cache_dir() / f"kplanes_{real}_f{nf}_{key.hexdigest()[:16]}.so"
    if out.exists():
        return out
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=out.parent)
    os.close(fd)
    try:
        subprocess.run([cc, *_FLAGS, f"-DREAL={real}", f"-DNF={nf}", str(_SRC), "-o", tmp, "-lm"], check=True,
                       capture_output=True, timeout=120)
        os.replace(tmp, out)  # atomic: concurrent builders race harmlessly
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


@functools.lru_cache(maxsize=None)
def load_kernel(dtype: torch.dtype, n_features: int = 16):
    """The ctypes library for ``torch.float32`` / ``torch.float64`` and ``n_features`` per plane, or ``None``
    if it cannot be built."""
    real = {torch.float32: "float", torch.float64: "double"}.get(dtype)
    if real is None or not 1 <= n_features <= MAX_FEATURES:
        return None
    try:
        lib = ctypes.CDLL(str(_build(real, int(n_features))))
    except Exception as exc:  # no compiler, sandbox, ...: fall back to PyTorch
        _STATUS["status"] = f"unavailable: {type(exc).__name__}: {exc}"[:300]
        return None
    i64, ptr = ctypes.c_int64, ctypes.c_void_p
    for name, extra in (("kp_forward", [ptr]), ("kp_backward", [ptr, ptr])):
        fn = getattr(lib, name)
        fn.argtypes = [ptr, ptr, i64, i64, i64, ptr, ptr] + extra
        fn.restype = None
    lib.kp_sh4.argtypes = [ptr, i64, i64, ptr]
    lib.kp_sh4.restype = None
    if lib.kp_nf() != n_features:  # pragma: no cover - stale cache entry
        return None
    _STATUS["status"] = "loaded"
    return lib


def kernel_status() -> str:
    """``'loaded'``, ``'not loaded'`` or ``'unavailable: <reason>'``."""
    return _STATUS["status"]


def cpu_planes_path(n_features: int = 16) -> str:
    """Which code K-Planes fields of ``n_features`` per plane run on the CPU: ``'compiled'`` (this module's
    kernel, built or found in the cache now) or ``'pytorch'`` (the pure-PyTorch gather path of
    :mod:`senerf.fields.interp`, when the kernel cannot be built: :func:`kernel_status` says why).

    The two sum in other orders, so a fit's figures differ in their last bits between them, and the PyTorch path
    is slower (lego Extreme at 100x100, fast preset's teacher, 2 cores: 37 s against 23 s of fitting; BENCHMARKS.md,
    session 24).

    Example:
        >>> cpu_planes_path() in ("compiled", "pytorch")
        True
    """
    return "pytorch" if load_kernel(torch.float32, n_features) is None else "compiled"   # (None past MAX_FEATURES)


def cpu_planes_warning(n_features: int = 16) -> str | None:
    """The warning a command prints before it fits or renders K-Planes fields of ``n_features`` per plane on the
    CPU without the compiled kernel (:func:`cpu_planes_path` ``'pytorch'``), naming why; None with the kernel."""
    if cpu_planes_path(n_features) == "compiled":
        return None
    why = f"more than {MAX_FEATURES} features per plane" if n_features > MAX_FEATURES \
        else kernel_status().removeprefix("unavailable: ")
    return (f"the compiled K-Planes kernel cannot be used ({why}); the pure-PyTorch path runs instead: slower (1.6x "
            f"measured), and its figures differ in their last digits from the kernel's (a C compiler on PATH, or $CC, "
            f"gives the kernel)")


def _split(n: int, parts: int) -> list[tuple[int, int]]:
    if n == 0:
        return [(0, 0)]
    parts = max(1, min(parts, n // 2048 + 1))
    step = -(-n // parts)
    return [(s, min(n, s + step)) for s in range(0, n, step)]


def _run(calls, keep: tuple) -> None:
    """Run ``calls[1:]`` on worker threads and ``calls[0]`` here; return when all are done.

    The calls write through raw pointers into tensors; ``keep`` (those tensors) is held by every worker until
    its call returns.  An interrupt (Ctrl-C, or SIGTERM, which senerf's commands raise as KeyboardInterrupt)
    can leave this function while a worker still runs, and the caller then drops its tensors: without
    ``keep`` their memory was freed under the worker, and senerf-fit died of a segmentation fault instead of
    exiting 130.
    """
    if len(calls) == 1:
        calls[0]()
        return
    threads = [threading.Thread(target=_work, args=(call, keep)) for call in calls[1:]]
    for t in threads:
        t.start()
    calls[0]()
    for t in threads:
        t.join()


def _work(call, keep: tuple) -> None:
    """A worker's body: ``keep`` is referenced (by the thread's arguments) until ``call`` returns."""
    call()


class _Fused(torch.autograd.Function):
    @staticmethod
    def forward(ctx, table, u, res, offs, lib):
        n, nf = u.shape[0], table.shape[1]
        s = res.shape[0]
        out = table.new_empty(n, s * nf)
        args = (u.data_ptr(), table.data_ptr())
        tail = (s, res.data_ptr(), offs.data_ptr(), out.data_ptr())
        _run([functools.partial(lib.kp_forward, *args, a, b, *tail)
              for a, b in _split(n, torch.get_num_threads())], keep=(u, table, res, offs, out))
        ctx.save_for_backward(table, u, res, offs)
        ctx.lib = lib
        return out

    @staticmethod
    def backward(ctx, g):
        table, u, res, offs = ctx.saved_tensors
        g = g.contiguous()
        ranges = _split(u.shape[0], torch.get_num_threads())
        bufs = [torch.zeros_like(table) for _ in ranges]
        s = res.shape[0]
        _run([functools.partial(ctx.lib.kp_backward, u.data_ptr(), table.data_ptr(), a, b, s, res.data_ptr(),
                                offs.data_ptr(), g.data_ptr(), buf.data_ptr())
              for (a, b), buf in zip(ranges, bufs)], keep=(u, table, res, offs, g, *bufs))
        gt = bufs[0]
        for b in bufs[1:]:
            gt += b
        return gt, None, None, None, None


def fused_plane_features(table: torch.Tensor, u: torch.Tensor, resolutions: tuple[int, ...],
                         offsets: list[int]):
    """Hadamard-combined plane features by the compiled kernel, or ``None`` when it cannot be used.

    Args:
        table: ``(rows, F)`` contiguous CPU float32/float64 (layout of :mod:`senerf.fields.interp`).
        u: ``(N, 3)`` coordinates clamped to ``[-1, 1]`` (no gradient flows to ``u``).
    Returns:
        ``(N, S * F)`` (differentiable in ``table``) or ``None`` (``table`` or ``u`` not on the CPU, other
        dtype, ``u`` needs a gradient, F > MAX_FEATURES, or no compiler).  The C code reads raw pointers, so
        points on another device must never reach it (they would be read as host memory).
    """
    if (table.device.type != "cpu" or u.device.type != "cpu" or u.requires_grad or table.shape[1] > MAX_FEATURES
            or not table.is_contiguous() or len(resolutions) > MAX_SCALES):
        return None
    lib = load_kernel(table.dtype, table.shape[1])
    if lib is None:
        return None
    u = u.detach().to(table.dtype).contiguous()
    res = torch.tensor(resolutions, dtype=torch.int64)
    offs = torch.tensor(offsets, dtype=torch.int64)
    return _Fused.apply(table, u, res, offs, lib)


def fused_sh4(dirs: torch.Tensor):
    """Degree-4 real spherical harmonics by the compiled kernel, or ``None`` when it cannot be used.

    Args:
        dirs: ``(N, 3)`` unit directions, CPU float32/float64, no gradient.
    Returns:
        ``(N, 16)`` equal to :func:`senerf.fields.encoding.sh_encoding_reference` (to rounding), or ``None``
        (CUDA, other dtype, ``dirs`` needs a gradient, or no compiler).
    """
    if dirs.device.type != "cpu" or dirs.requires_grad or dirs.dtype not in (torch.float32, torch.float64):
        return None
    lib = load_kernel(dirs.dtype, 16)
    if lib is None:
        return None
    dirs = dirs.contiguous()
    out = dirs.new_empty(dirs.shape[0], 16)
    _run([functools.partial(lib.kp_sh4, dirs.data_ptr(), a, b, out.data_ptr())
          for a, b in _split(dirs.shape[0], torch.get_num_threads())], keep=(dirs, out))
    return out
