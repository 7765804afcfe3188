"""The compiled fused K-Planes kernel (``_kplanes_kernel.c``, package data: plane features, their gradient, the
planes' total variation and SH encoding; also the feature similarity of the self-training's reliability): build, load,
call.

On first use the source is compiled (``$CC``, else ``cc`` or ``gcc``; ``-march=native`` where the compiler knows it)
and loaded with :mod:`ctypes`; where it cannot be, :func:`load_kernel` returns ``None``, :func:`kernel_status` says
why, and callers take the pure-PyTorch gather path.  The library is cached per user, never beside the (maybe
read-only) source: in ``$SENERF_CACHE``, else ``$XDG_CACHE_HOME/senerf`` or ``~/.cache/senerf``, else a private
folder in the temp folder, under a name hashing the source, the flags, the compiler and the macros it predefines
(the instruction set), so no CPU is handed a library built for another.  ``-ffp-contract=off`` keeps the sums the
same with or without fused multiply-add.  Work is split over ``torch.get_num_threads()`` threads (ctypes releases
the GIL), each with its own points and gradient buffer: no races, deterministic results.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
import threading
import warnings
from pathlib import Path

import numpy as np
import torch

__all__ = ["load_kernel", "kernel_status", "cpu_planes_path", "cpu_planes_warning", "warn_without_kernel",
           "fused_plane_features", "fused_sh4", "fused_plane_tv", "fused_feature_similarity", "MAX_FEATURES",
           "MAX_SCALES"]

MAX_FEATURES = 256
MAX_SCALES = 8
_SRC = Path(__file__).with_name("_kplanes_kernel.c")
_FLAGS = ["-O3", "-fno-math-errno", "-ffp-contract=off", "-fPIC", "-shared", "-std=c99"]
_STATUS = {"status": "not loaded"}


class _Unavailable(OSError):
    """Why the kernel cannot be built or loaded here: one line, with the remedy where there is one."""


def _cache_dir() -> Path:
    """The first usable cache folder (module docstring); the one in the shared temp folder only when it is this
    user's and no one else may write to it (a library planted there would be loaded and run)."""
    cands = [Path(os.environ["SENERF_CACHE"])] if os.environ.get("SENERF_CACHE") else []
    try:
        xdg = os.environ.get("XDG_CACHE_HOME")
        cands.append(Path(xdg) / "senerf" if xdg else Path.home() / ".cache" / "senerf")
    except RuntimeError:   # no home folder
        pass
    uid = os.getuid() if hasattr(os, "getuid") else None
    shared = Path(tempfile.gettempdir()) / f"senerf-cache-{uid}"
    for folder in [*cands, shared]:
        try:
            folder.mkdir(mode=0o700, parents=True, exist_ok=True)
            st = folder.stat()
            if folder == shared and uid is not None and (st.st_uid != uid or st.st_mode & 0o022):
                continue
            if os.access(folder, os.W_OK):
                return folder
        except OSError:
            continue
    raise _Unavailable("no writable folder to cache it in: set $SENERF_CACHE to one")


def _compiler() -> list[str]:
    """The C compiler's command: ``$CC`` split as a shell would (``ccache gcc``), else ``cc`` or ``gcc``."""
    cmd = shlex.split(os.environ.get("CC", ""))
    if cmd:
        if shutil.which(cmd[0]) is None:
            raise _Unavailable(f"$CC names {cmd[0]}, which is no program on PATH")
        return cmd
    found = shutil.which("cc") or shutil.which("gcc")
    if found is None:
        raise _Unavailable("no C compiler found: install one (cc or gcc on PATH) or name it in $CC")
    return [found]


def _call(cmd: list[str], timeout: float) -> bytes:
    """``cmd``'s standard output, or :class:`_Unavailable` naming its first error line when it fails."""
    try:
        done = subprocess.run(cmd, input=b"", capture_output=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise _Unavailable(f"{cmd[0]} cannot be run: {exc}") from None
    if done.returncode != 0:
        lines = [line.strip() for line in done.stderr.decode(errors="replace").splitlines() if line.strip()]
        first = next((line for line in lines if "error" in line), lines[-1] if lines else "")
        raise _Unavailable(f"{cmd[0]} failed (exit status {done.returncode}): {first[:200]}")
    return done.stdout


@functools.lru_cache(maxsize=None)
def _target(cc: tuple[str, ...]) -> tuple[list[str], bytes]:
    """``(march, macros)``: ``['-march=native']`` where the compiler knows it, else ``[]`` (its default target),
    and the macros it predefines under that choice, which name the instruction set it builds for."""
    try:
        return ["-march=native"], _call([*cc, "-march=native", "-dM", "-E", "-x", "c", "-"], 60)
    except _Unavailable:
        return [], _call([*cc, "-dM", "-E", "-x", "c", "-"], 60)


def _build(real: str, nf: int) -> Path:
    """The library for ``REAL`` = ``real`` and ``NF`` = ``nf``: found in the cache, else compiled into it."""
    try:
        src = _SRC.read_bytes()
    except OSError:
        raise _Unavailable(f"its C source {_SRC} is missing from this installation: reinstall senerf") from None
    cc = _compiler()
    march, macros = _target(tuple(cc))
    flags = [*_FLAGS, *march, f"-DREAL={real}", f"-DNF={nf}"]
    key = hashlib.sha256(b"\0".join([src, " ".join(cc + flags).encode(), platform.machine().encode(), macros]))
    out = _cache_dir() / f"kplanes_{real}_f{nf}_{key.hexdigest()[:16]}.so"
    if out.exists():
        return out
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=out.parent)
    os.close(fd)
    try:
        _call([*cc, *flags, str(_SRC), "-o", tmp, "-lm"], 120)
        os.replace(tmp, out)  # atomic: concurrent builders race harmlessly
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


@functools.lru_cache(maxsize=None)
def load_kernel(dtype: torch.dtype, n_features: int = 16):
    """The ctypes library for ``torch.float32`` / ``torch.float64`` and ``n_features`` per plane, or ``None``
    if it cannot be built or loaded (:func:`kernel_status` says why)."""
    real = {torch.float32: "float", torch.float64: "double"}.get(dtype)
    if real is None or not 1 <= n_features <= MAX_FEATURES:
        return None
    try:
        path = _build(real, int(n_features))
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise _Unavailable(f"the compiled library {path} cannot be loaded: {exc}") from None
    except Exception as exc:  # sandbox, read-only disk, ...: fall back to PyTorch, saying why in one line
        why = str(exc) if isinstance(exc, _Unavailable) else f"{type(exc).__name__}: {exc}"
        _STATUS["status"] = "unavailable: " + " ".join(why.split())[:300]
        return None
    i64, ptr = ctypes.c_int64, ctypes.c_void_p
    planes = [ptr, ptr, i64, i64, i64, ptr, ptr]
    for name, argtypes in (("kp_forward", planes + [ptr]), ("kp_backward", planes + [ptr, ptr]),
                           ("kp_sh4", [ptr, i64, i64, ptr])):
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = argtypes, None
    real_t = ctypes.c_float if real == "float" else ctypes.c_double
    lib.kp_tv.argtypes, lib.kp_tv.restype = [ptr, i64, i64, i64, real_t, ptr], ctypes.c_double
    lib.kp_feature_cosine.argtypes = [ptr, ptr, ptr, i64, i64, i64, ptr, i64, i64, ctypes.c_double, ptr]
    lib.kp_feature_cosine.restype = None
    _STATUS["status"] = "loaded"
    return lib


def kernel_status() -> str:
    """``'loaded'``, ``'not loaded'`` or ``'unavailable: <reason>'`` (one line) after the latest load."""
    return _STATUS["status"]


def cpu_planes_path(n_features: int = 16) -> str:
    """Which code K-Planes fields of ``n_features`` per plane run on the CPU: ``'compiled'`` (this module's
    kernel, built or found in the cache now) or ``'pytorch'`` (the slower gather path of :mod:`senerf.fields.interp`,
    whose sums run in another order: a fit's figures differ in their last bits).

    Example:
        >>> cpu_planes_path() in ("compiled", "pytorch")
        True
    """
    return "pytorch" if load_kernel(torch.float32, n_features) is None else "compiled"   # (None past MAX_FEATURES)


def cpu_planes_warning(n_features: int = 16) -> str | None:
    """The one-line warning for K-Planes fields of ``n_features`` per plane on the CPU without the compiled kernel,
    naming why and, where there is one, the remedy; None with the kernel."""
    if cpu_planes_path(n_features) == "compiled":
        return None
    why = f"more than {MAX_FEATURES} features per plane" if n_features > MAX_FEATURES \
        else kernel_status().removeprefix("unavailable: ")
    return (f"the compiled K-Planes kernel cannot be used ({why}); the pure-PyTorch path runs instead: slower, and "
            f"its figures differ in their last digits from the kernel's")


def warn_without_kernel(model, device) -> None:
    """Warn (:func:`cpu_planes_warning`) before ``model`` (a :class:`senerf.config.ModelConfig`) fits or renders a
    K-Planes field on the CPU ``device`` without the compiled kernel."""
    if model.field == "kplanes" and str(device).split(":")[0] == "cpu":
        line = cpu_planes_warning(model.n_features)
        if line is not None:
            warnings.warn(line, stacklevel=2)


def _split(n: int, parts: int) -> list[tuple[int, int]]:
    if n == 0:
        return [(0, 0)]
    parts = max(1, min(parts, n // 2048 + 1))
    step = -(-n // parts)
    return [(s, min(n, s + step)) for s in range(0, n, step)]


def _run(calls, keep: tuple) -> None:
    """Run ``calls[1:]`` on worker threads and ``calls[0]`` here; return when all are done.

    Every worker holds ``keep`` (the tensors the calls write into through raw pointers) until its call returns:
    an interrupt can leave this function while a worker still runs, and those tensors must not be freed under it.
    """
    threads = [threading.Thread(target=_work, args=(call, keep)) for call in calls[1:]]
    for t in threads:
        t.start()
    calls[0]()
    for t in threads:
        t.join()


def _work(call, keep: tuple) -> None:
    call()


class _Fused(torch.autograd.Function):
    @staticmethod
    def forward(ctx, table, u, res, offs, lib):
        n, nf, s = u.shape[0], table.shape[1], res.shape[0]
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
        ``(N, S * F)`` (differentiable in ``table``), or ``None`` when either is off the CPU (the C code would
        read device pointers as host memory), of another dtype, ``u`` needs a gradient, F > MAX_FEATURES, or no
        kernel can be loaded.
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


def _tv_pass(lib, table: torch.Tensor, resolutions, offsets, c: float, grad: torch.Tensor | None) -> float:
    """One :c:func:`kp_tv` pass over every plane, its rows split over the threads: the sum of squared differences
    of each plane divided by its count of differences, summed (and ``grad`` written, scaled by ``c`` / count)."""
    nf, n_planes = table.shape[1], len(offsets) // len(resolutions)
    total, keep = 0.0, (table,) if grad is None else (table, grad)
    for k, o in enumerate(offsets):
        r = resolutions[k // n_planes]
        count = (r - 1) * r * nf   # differences along each axis
        ptr = table.data_ptr() + o * nf * table.element_size()
        out = 0 if grad is None else grad.data_ptr() + o * nf * grad.element_size()
        step = -(-r // max(1, min(torch.get_num_threads(), r * r // 2048 + 1)))
        rows = [(b, min(r, b + step)) for b in range(0, r, step)]   # whole texel rows, as _split sizes point ranges
        parts = [0.0] * len(rows)

        def call(i, b0, b1):
            parts[i] = lib.kp_tv(ptr, r, b0, b1, c / count, out)

        _run([functools.partial(call, i, b0, b1) for i, (b0, b1) in enumerate(rows)], keep=keep)
        total += sum(parts) / count
    return total


class _FusedTV(torch.autograd.Function):
    @staticmethod
    def forward(ctx, table, resolutions, offsets, lib):
        ctx.save_for_backward(table)
        ctx.layout = (resolutions, offsets, lib)
        return table.new_tensor(_tv_pass(lib, table, resolutions, offsets, 0.0, None) / len(resolutions))

    @staticmethod
    def backward(ctx, g):
        (table,) = ctx.saved_tensors
        resolutions, offsets, lib = ctx.layout
        grad = torch.empty_like(table)
        _tv_pass(lib, table, resolutions, offsets, 2.0 * float(g) / len(resolutions), grad)
        return grad, None, None, None


def fused_plane_tv(table: torch.Tensor, resolutions: tuple[int, ...], offsets: list[int]):
    """:func:`senerf.fields.interp.plane_tv_reference` by the compiled kernel, one pass over the planes for the value
    and one for the gradient, or ``None`` when it cannot be used (``table`` off the CPU, not contiguous, another
    dtype, more than :data:`MAX_FEATURES` features, or no kernel)."""
    if table.device.type != "cpu" or not table.is_contiguous() or table.shape[1] > MAX_FEATURES:
        return None
    lib = load_kernel(table.dtype, table.shape[1])
    if lib is None:
        return None
    return _FusedTV.apply(table, tuple(resolutions), list(offsets), lib)


def _host_float32(x) -> np.ndarray | None:
    """``x`` (an array or a tensor) as a C-contiguous float32 host array sharing its memory where it can (a copy
    only when it is strided), or ``None`` when it is a tensor off the CPU or either is not float32: no silent copy of
    a view's features, nor a read of device memory as host memory."""
    if isinstance(x, torch.Tensor):
        if x.device.type != "cpu" or x.dtype != torch.float32:
            return None
        x = x.detach().contiguous().numpy()
    x = np.asarray(x)
    return np.ascontiguousarray(x) if x.dtype == np.float32 else None


def fused_feature_similarity(src, rows: np.ndarray, features, uv: np.ndarray, eps: float = 1e-8):
    """The cosine similarity of pixel features with another view's features sampled bilinearly, by the compiled
    kernel in one pass over the feature rows, or ``None`` when it cannot be used.

    What :func:`senerf.selftrain.reliability.view_similarity` scores: ``cosine_similarity(src[rows],
    bilinear_sample(features, uv))`` without the sampled ``(N, C)`` array and the temporaries of the NumPy path
    (the lookup is memory bound: each temporary is as much traffic again).  The sample is the NumPy one to the
    bit (its corners, clamping, weights and float32 operations); the dot product and the norms are summed in
    double (float32 there), so the two agree to ~1e-6, and the result does not depend on the thread count.

    Args:
        src: ``(M, C)`` (or ``(H, W, C)``) float32 pixel features: an array or a CPU tensor.
        rows: ``(N,)`` integer rows of ``src`` (flat pixel indices), each in ``[0, M)``.
        features: ``(H', W', C)`` float32 features of the other view: an array or a CPU tensor.
        uv: ``(N, 2)`` pixel coordinates in that view (column, row; pixel centres at ``i + 0.5``; clamped to the
            image as :func:`senerf.selftrain.reliability.bilinear_sample` clamps them).
        eps: the similarity is ``dot / max(|a| |b|, eps)``: 0 for a zero vector.
    Returns:
        ``(N,)`` float32 array, or ``None`` when a tensor is off the CPU, either features are not float32, or no
        kernel can be loaded.  Raises ``ValueError`` on mismatched shapes and ``IndexError`` on a row out of range.
    """
    a, feat = _host_float32(src), _host_float32(features)
    if a is None or feat is None:
        return None
    a = a.reshape(-1, a.shape[-1])
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    n = rows.shape[0]
    if feat.ndim != 3 or feat.shape[2] != a.shape[1] or 0 in feat.shape[:2] or rows.ndim != 1 or uv.shape != (n, 2):
        raise ValueError(f"expected src (M, C), rows (N,), features (H, W, C) with H, W >= 1 and uv (N, 2), got "
                         f"{a.shape}, {rows.shape}, {feat.shape} and {uv.shape}")
    if n and (rows.min() < 0 or rows.max() >= a.shape[0]):
        raise IndexError(f"rows must lie in [0, {a.shape[0]}), got {rows.min()} .. {rows.max()}")
    lib = load_kernel(torch.float32)
    if lib is None:
        return None
    out = np.empty(n, dtype=np.float32)
    h, w, c = feat.shape
    if n == 0:
        return out
    _run([functools.partial(lib.kp_feature_cosine, a.ctypes.data, rows.ctypes.data, feat.ctypes.data, h, w, c,
                            uv.ctypes.data, n0, n1, float(eps), out.ctypes.data)
          for n0, n1 in _split(n, torch.get_num_threads())], keep=(a, rows, feat, uv, out))
    return out
