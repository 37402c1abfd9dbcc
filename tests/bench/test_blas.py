"""Tests of the OpenBLAS binding behind the triad kernel (the real library from scipy-openblas32)."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from hdeem_watch.bench import blas


def _loaded() -> blas.Blas:
    loaded = blas.openblas()
    assert loaded is not None, "scipy-openblas32 is a dependency and must load"
    return loaded


def test_library_loads_single_threaded_and_privately() -> None:
    """The wheel's library loads once, reports its OpenBLAS build, runs one thread per call (the
    bench pins its own workers), and is not imported as a package (no RTLD_GLOBAL symbols)."""
    loaded = _loaded()
    assert blas.openblas() is loaded
    assert loaded.config.startswith("OpenBLAS ")
    same = ctypes.CDLL(loaded.path)  # dlopen of a loaded library returns the same handle
    assert same.scipy_openblas_get_num_threads() == 1
    assert "scipy_openblas32" not in sys.modules


@pytest.mark.parametrize(("incx", "incy", "n"), [(1, 1, 1), (8, 8, 1000), (3, 8, 777), (8, 1, 0)])
def test_axpby_on_strided_views(incx: int, incy: int, n: int) -> None:
    """``y = alpha x + beta y`` on every strided element and nowhere else (power-of-two factors, so
    each product is exact and the result bit-equal to numpy's)."""
    rng = np.random.default_rng(n)
    x_full = rng.standard_normal(max(1, n * incx + 5))
    y_full = rng.standard_normal(max(1, n * incy + 5))
    x, y = x_full[2:2 + n * incx:incx], y_full[1:1 + n * incy:incy]
    expected = y_full.copy()
    expected[1:1 + n * incy:incy] = 0.5 * x + 4.0 * y
    untouched_x = x_full.copy()
    _loaded().axpby(0.5, x, 4.0, y)
    assert y_full.tobytes() == expected.tobytes()
    assert x_full.tobytes() == untouched_x.tobytes()


def test_axpby_splits_views_longer_than_one_call(monkeypatch: pytest.MonkeyPatch) -> None:
    """A view longer than one call's ``int`` count goes in several calls, each from its own start."""
    monkeypatch.setattr(blas, "MAX_CALL_ELEMENTS", 7)
    a, b = np.arange(8 * 50, dtype=np.float64), np.full(8 * 50, 3.0)
    expected = a.copy()
    expected[::8] = b[::8] + 2.0 * a[::8]
    _loaded().axpby(1.0, b[::8], 2.0, a[::8])
    assert a.tobytes() == expected.tobytes()


@pytest.mark.parametrize(("x", "y", "message"), [
    (np.ones(4, dtype=np.float32), np.ones(4), "x: expected a 1-D float64 view"),
    (np.ones((2, 2)), np.ones(4), "x: expected a 1-D float64 view, got 2-D"),
    (np.ones(8)[::-2], np.ones(4), "x: stride -16 bytes; expected a positive multiple of 8"),
    (np.ones(4), np.ones(5), "x has 4 elements and y 5"),
])
def test_axpby_refuses_views_it_cannot_pass(x: np.ndarray, y: np.ndarray, message: str) -> None:
    """Views BLAS cannot take as they are (wrong type, 2-D, negative stride, unequal length) raise
    one clear error instead of being copied or misread."""
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        _loaded().axpby(1.0, x, 2.0, y)


def test_concurrent_calls_from_worker_threads() -> None:
    """Two threads calling at once (the bench's workers, GIL released by ctypes) each get their own
    range right."""
    loaded = _loaded()
    a, b = np.ones(8 * 200_000), np.full(8 * 200_000, 2.0)
    halves = [(0, 100_000), (100_000, 200_000)]

    def work(lo: int, hi: int) -> None:
        for _ in range(5):
            loaded.axpby(1.0, b[lo * 8:hi * 8:8], 2.0, a[lo * 8:hi * 8:8])

    threads = [threading.Thread(target=work, args=half) for half in halves]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    value = 1.0
    for _ in range(5):
        value = 2.0 + 2.0 * value
    assert (a[::8] == value).all() and (a.reshape(-1, 8)[:, 1:] == 1.0).all()


def test_missing_wheel_means_no_library(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without the wheel there is no library (the kernels then use numpy), and no error."""
    monkeypatch.setattr(blas.importlib.util, "find_spec", lambda name: None)
    assert blas.library_path() is None
    assert blas._load() is None  # the uncached loader


AMD_ZEN4 = "processor\t: 0\nvendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma avx512f\n\n" \
           "processor\t: 1\nvendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma avx512f\n"


@pytest.mark.parametrize(("cpuinfo", "expected"), [
    (AMD_ZEN4, "Zen"),
    ("vendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx\n", None),   # no AVX2: OpenBLAS's own pick
    ("vendor_id\t: GenuineIntel\nflags\t\t: fpu avx2 avx512f\n", None),
    ("", None),
])
def test_kernel_set_by_cpu(cpuinfo: str, expected: str | None) -> None:
    """AMD CPUs with AVX2 load OpenBLAS's Zen kernels (its SkylakeX pick on Zen 4 runs the strided
    daxpby slower); everything else keeps OpenBLAS's own choice."""
    assert blas.coretype_for(cpuinfo) == expected


def test_loaded_kernel_set_follows_the_cpu_and_leaves_no_variable() -> None:
    """The live load used the kernel set chosen for this CPU (Zen maps to OpenBLAS's Haswell
    kernels) and removed the variable it set."""
    loaded = _loaded()
    if blas.coretype_for(blas._read_cpuinfo()) == "Zen":
        assert " Haswell " in loaded.config
    assert "OPENBLAS_CORETYPE" not in os.environ and "OPENBLAS_NUM_THREADS" not in os.environ


def test_loading_starts_no_thread_pool() -> None:
    """Loading the library adds no threads to the process (OpenBLAS would otherwise start a pool
    sized to the CPUs, idle but spinning after load); checked in a fresh process."""
    code = ("import os, numpy; before = len(os.listdir('/proc/self/task'))\n"
            "from hdeem_watch.bench import blas; assert blas.openblas() is not None\n"
            "print(before, len(os.listdir('/proc/self/task')))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENBLAS")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    before, after = map(int, out.stdout.split())
    assert after == before


def test_users_coretype_wins() -> None:
    """A user's OPENBLAS_CORETYPE is respected, not replaced (checked in a fresh process, since a
    library loads its kernels once)."""
    code = "from hdeem_watch.bench import blas; print(blas.openblas().config)"
    env = {**os.environ, "OPENBLAS_CORETYPE": "SandyBridge"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert " sandybridge " in out.stdout.lower()
