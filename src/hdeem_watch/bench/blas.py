"""OpenBLAS's fused strided loop ``y = alpha x + beta y`` (``daxpby``), for the triad kernel.

numpy has no call that computes ``b + 2a`` in one pass: its triad takes two calls per chunk (double
``a`` in place, then add ``b``), each streaming one array, and tops out at 448 Mlines/s per core
with the lines in cache, against 730 for the C loop (docs/bench.md). OpenBLAS's ``daxpby``
extension is that C loop, on strided views: 609 Mlines/s in cache, and 1.13x numpy's rate on
DRAM-sized arrays with one thread. The library comes from the ``scipy-openblas32`` wheel (the
OpenBLAS build that numpy and scipy are themselves built against; the optional ``bench`` extra,
``pip install 'hdeem-watch[bench]'``) and is called through ctypes, which releases the GIL for the
call, so the bench's worker threads run it in parallel.

OpenBLAS is told to use one thread: the bench runs one pinned worker per CPU, and each call must
stay on its worker's CPU. When the wheel or the symbol is missing, :func:`openblas` returns ``None``
and the kernels fall back to numpy (same results, bit for bit).

Example:
    >>> import numpy as np
    >>> blas = openblas()
    >>> a, b = np.ones(16), np.full(16, 2.0)
    >>> if blas is not None:
    ...     blas.axpby(1.0, b[::8], 2.0, a[::8])
    ... else:
    ...     a[::8] = b[::8] + 2.0 * a[::8]
    >>> a[:9].tolist()
    [4.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 4.0]
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import importlib.util
import os
import threading
from collections.abc import Iterator

import numpy as np

#: Largest element count one call takes (the LP64 library's ``int``); longer views are split.
MAX_CALL_ELEMENTS = 2**31 - 1


class Blas:
    """The loaded library's ``daxpby`` on numpy views.

    Attributes:
        path: the shared library loaded.
        config: OpenBLAS's build string (version, target, threading).
    """

    def __init__(self, library: ctypes.CDLL, path: str) -> None:
        self.path = path
        config = library.scipy_openblas_get_config
        config.restype = ctypes.c_char_p
        self.config = (config() or b"").decode(errors="replace")
        library.scipy_openblas_set_num_threads(ctypes.c_int(1))
        self._daxpby = library.scipy_cblas_daxpby
        self._daxpby.restype = None
        self._daxpby.argtypes = [ctypes.c_int, ctypes.c_double, ctypes.c_void_p, ctypes.c_int,
                                 ctypes.c_double, ctypes.c_void_p, ctypes.c_int]

    def axpby(self, alpha: float, x: np.ndarray, beta: float, y: np.ndarray) -> None:
        """Set ``y[i] = alpha * x[i] + beta * y[i]`` for every ``i``, in place, in one pass.

        Args:
            alpha: factor of ``x``.
            x: 1-D float64 view, any positive stride (in elements).
            beta: factor of ``y``.
            y: 1-D float64 view of the same length, any positive stride; overwritten. ``x`` and ``y``
                must not overlap unless they are the same view.

        Raises:
            ValueError: the views are not 1-D float64 of equal length with positive element strides.
        """
        for name, view in (("x", x), ("y", y)):
            if view.dtype != np.float64 or view.ndim != 1:
                raise ValueError(f"axpby {name}: expected a 1-D float64 view, got {view.ndim}-D {view.dtype}")
            if view.size > 1 and (view.strides[0] <= 0 or view.strides[0] % 8):
                raise ValueError(f"axpby {name}: stride {view.strides[0]} bytes; expected a positive "
                                 "multiple of 8")
        if x.size != y.size:
            raise ValueError(f"axpby: x has {x.size} elements and y {y.size}; expected equal lengths")
        incx, incy = max(1, x.strides[0] // 8), max(1, y.strides[0] // 8)
        px, py = x.ctypes.data, y.ctypes.data
        for start in range(0, x.size, MAX_CALL_ELEMENTS):
            n = min(MAX_CALL_ELEMENTS, x.size - start)
            self._daxpby(n, alpha, px + start * incx * 8, incx, beta, py + start * incy * 8, incy)


def library_path() -> str | None:
    """Return the ``scipy-openblas32`` wheel's shared library, or ``None`` when it is not installed.

    The package is located, not imported: importing it loads the library ``RTLD_GLOBAL``, which
    would hand its symbols (and the one-thread setting below) to scipy's own BLAS calls.
    """
    spec = importlib.util.find_spec("scipy_openblas32")
    if spec is None or not spec.submodule_search_locations:
        return None
    for package_dir in spec.submodule_search_locations:
        found = sorted(glob.glob(os.path.join(package_dir, "lib", "libscipy_openblas*.so*")))
        if found:
            return found[0]
    return None


#: The environment variables through which OpenBLAS picks its kernel set and its thread pool's size
#: at load time (set only while it loads, and only when the user has not set them; see
#: :func:`load_library`).
CORETYPE_VARIABLE = "OPENBLAS_CORETYPE"
THREADS_VARIABLE = "OPENBLAS_NUM_THREADS"
CPUINFO = "/proc/cpuinfo"


def coretype_for(cpuinfo: str) -> str | None:
    r"""Return the kernel set to load OpenBLAS with on this CPU, or ``None`` for OpenBLAS's own pick.

    On AMD CPUs with AVX2 this is ``"Zen"`` (which OpenBLAS maps to its Haswell kernels). OpenBLAS
    picks its SkylakeX kernels on Zen 4 for AVX-512, and there the strided ``daxpby`` runs slower:
    triad at 1 thread, 2**25 doubles, on the AMD EPYC development VM, median Mlines/s over five
    alternating processes of eight runs each: 168.7 with OpenBLAS's pick, 191.1 with ``Zen``.
    Intel CPUs keep OpenBLAS's pick (not measured here).

    Example:
        >>> coretype_for("vendor_id : AuthenticAMD\nflags : fpu sse2 avx avx2 fma\n")
        'Zen'
        >>> coretype_for("vendor_id : GenuineIntel\nflags : fpu avx2\n") is None
        True
    """
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() not in fields:
            fields[key.strip()] = value.strip()
    if fields.get("vendor_id") == "AuthenticAMD" and "avx2" in fields.get("flags", "").split():
        return "Zen"
    return None


def _read_cpuinfo(path: str = CPUINFO) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as handle:
            return handle.read(1 << 16)
    except OSError:
        return ""


_LOAD_LOCK = threading.Lock()
_LOADED: list[Blas | None] = []  # filled once, under the lock


def openblas() -> Blas | None:
    """The library, loaded on the first call (privately, ``RTLD_LOCAL``); ``None`` when it or
    ``daxpby`` is missing. Thread-safe: workers may call this at once, and it loads once."""
    if not _LOADED:
        with _LOAD_LOCK:
            if not _LOADED:
                _LOADED.append(_load())
    return _LOADED[0]


def _load() -> Blas | None:
    """Load the installed wheel's library (uncached); ``None`` when the wheel is not installed."""
    path = library_path()
    return None if path is None else load_library(path)


def load_library(path: str, cpuinfo: str | None = None) -> Blas | None:
    """Load the OpenBLAS library at ``path`` with the bench's load-time settings (uncached).

    OpenBLAS reads two variables once, while it loads: ``OPENBLAS_CORETYPE`` (its kernel set, chosen
    here by :func:`coretype_for`) and ``OPENBLAS_NUM_THREADS`` (its thread pool's size; ``1`` here,
    the calls being single-threaded either way). A variable the user has set is left as it is. A
    variable set here exists only for the duration of the load and is removed right after it, so
    the process environment afterwards is exactly what it was before (other threads could see it
    only during the load, a few tens of milliseconds, once per process).

    Args:
        path: the shared library file.
        cpuinfo: the text of ``/proc/cpuinfo`` (default: read it).

    Returns:
        The library, or ``None`` when the file does not load or lacks ``daxpby``.
    """
    settings = {THREADS_VARIABLE: "1"}  # no thread pool: each call runs on its worker's CPU
    coretype = coretype_for(_read_cpuinfo() if cpuinfo is None else cpuinfo)
    if coretype is not None:
        settings[CORETYPE_VARIABLE] = coretype
    with _unless_set(settings):
        try:
            return Blas(ctypes.CDLL(path), path)
        except (OSError, AttributeError):  # unloadable file or missing symbol
            return None


@contextlib.contextmanager
def _unless_set(settings: dict[str, str]) -> Iterator[None]:
    """Set each variable of ``settings`` the environment lacks; on exit, restore every one of them
    to exactly what it was before (absent, or its previous value)."""
    before = {name: os.environ.get(name) for name in settings}
    os.environ.update({name: value for name, value in settings.items() if before[name] is None})
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
