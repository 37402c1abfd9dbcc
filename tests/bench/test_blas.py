"""Tests of the OpenBLAS binding behind the triad kernel.

The binding is tested against real C twice over: the ``scipy-openblas32`` wheel's library when the
optional ``bench`` extra is installed (CI installs it through ``[test]``), and always against a
stand-in library built here with gcc (``openblas_standin.c``: the same four symbols, and it reports
the load-time environment it saw). Without the wheel the kernels take the numpy path, which
tests/bench/test_kernels.py checks with the library made absent.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.bench import blas

#: The wheel's library, or None without the ``bench`` extra.
WHEEL = blas.library_path()
#: The libraries the binding is tested against.
LIBRARIES = ["wheel", "stand-in"] if WHEEL else ["stand-in"]
STANDIN_SOURCE = Path(__file__).resolve().parent / "openblas_standin.c"

AMD_ZEN4 = "processor\t: 0\nvendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma avx512f\n\n" \
           "processor\t: 1\nvendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma avx512f\n"
INTEL = "vendor_id\t: GenuineIntel\nflags\t\t: fpu avx2 avx512f\n"


@pytest.fixture(scope="session")
def standin_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The stand-in library, compiled once per session."""
    out = tmp_path_factory.mktemp("openblas-standin") / "libscipy_openblas_standin.so"
    subprocess.run(["gcc", "-O2", "-shared", "-fPIC", "-Wall", "-o", str(out), str(STANDIN_SOURCE)], check=True)
    return out


@pytest.fixture
def standin(standin_build: Path, tmp_path: Path) -> str:
    """A fresh copy of the stand-in: a new file name, so loading it runs its load-time code again."""
    copy = tmp_path / standin_build.name
    shutil.copy(standin_build, copy)
    return str(copy)


@pytest.fixture(params=LIBRARIES)
def library_file(request: pytest.FixtureRequest, standin: str) -> str:
    """The library file under test: the wheel's, or a fresh stand-in."""
    if request.param == "wheel":
        assert WHEEL is not None
        return WHEEL
    return standin


@pytest.fixture
def fused(library_file: str) -> blas.Blas:
    """The loaded library under test (the wheel through the process-wide :func:`blas.openblas`)."""
    loaded = blas.openblas() if library_file == WHEEL else blas.load_library(library_file)
    assert loaded is not None and loaded.path == library_file
    return loaded


def test_openblas_loads_once_exactly_when_the_wheel_is_installed() -> None:
    """``openblas()`` gives the wheel's library (the same object every call) when the wheel is
    installed, and ``None`` (the numpy path) when it is not."""
    first = blas.openblas()
    assert blas.openblas() is first
    assert (first is None) == (WHEEL is None)


@pytest.mark.slow
def test_library_loads_single_threaded_and_privately(fused: blas.Blas) -> None:
    """The library reports its OpenBLAS build, runs one thread per call (the bench pins its own
    workers), and is not imported as a package (no RTLD_GLOBAL symbols)."""
    assert fused.config.startswith("OpenBLAS ")
    same = ctypes.CDLL(fused.path)  # dlopen of a loaded library returns the same handle
    assert same.scipy_openblas_get_num_threads() == 1
    assert "scipy_openblas32" not in sys.modules


@pytest.mark.parametrize(("incx", "incy", "n"), [(1, 1, 1), (8, 8, 1000), (3, 8, 777), (8, 1, 0)])
def test_axpby_on_strided_views(fused: blas.Blas, incx: int, incy: int, n: int) -> None:
    """``y = alpha x + beta y`` on every strided element and nowhere else (power-of-two factors, so
    each product is exact and the result bit-equal to numpy's)."""
    rng = np.random.default_rng(n)
    x_full = rng.standard_normal(max(1, n * incx + 5))
    y_full = rng.standard_normal(max(1, n * incy + 5))
    x, y = x_full[2:2 + n * incx:incx], y_full[1:1 + n * incy:incy]
    expected = y_full.copy()
    expected[1:1 + n * incy:incy] = 0.5 * x + 4.0 * y
    untouched_x = x_full.copy()
    fused.axpby(0.5, x, 4.0, y)
    assert y_full.tobytes() == expected.tobytes()
    assert x_full.tobytes() == untouched_x.tobytes()


def test_axpby_splits_views_longer_than_one_call(fused: blas.Blas, monkeypatch: pytest.MonkeyPatch) -> None:
    """A view longer than one call's ``int`` count goes in several calls, each from its own start."""
    monkeypatch.setattr(blas, "MAX_CALL_ELEMENTS", 7)
    a, b = np.arange(8 * 50, dtype=np.float64), np.full(8 * 50, 3.0)
    expected = a.copy()
    expected[::8] = b[::8] + 2.0 * a[::8]
    fused.axpby(1.0, b[::8], 2.0, a[::8])
    assert a.tobytes() == expected.tobytes()


@pytest.mark.parametrize(("x", "y", "message"), [
    (np.ones(4, dtype=np.float32), np.ones(4), "x: expected a 1-D float64 view"),
    (np.ones((2, 2)), np.ones(4), "x: expected a 1-D float64 view, got 2-D"),
    (np.ones(8)[::-2], np.ones(4), "x: stride -16 bytes; expected a positive multiple of 8"),
    (np.ones(4), np.ones(5), "x has 4 elements and y 5"),
])
def test_axpby_refuses_views_it_cannot_pass(fused: blas.Blas, x: np.ndarray, y: np.ndarray, message: str) -> None:
    """Views BLAS cannot take as they are (wrong type, 2-D, negative stride, unequal length) raise
    one clear error instead of being copied or misread."""
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        fused.axpby(1.0, x, 2.0, y)


def test_concurrent_calls_from_worker_threads(fused: blas.Blas) -> None:
    """Two threads calling at once (the bench's workers, GIL released by ctypes) each get their own
    range right."""
    a, b = np.ones(8 * 200_000), np.full(8 * 200_000, 2.0)
    halves = [(0, 100_000), (100_000, 200_000)]

    def work(lo: int, hi: int) -> None:
        for _ in range(5):
            fused.axpby(1.0, b[lo * 8:hi * 8:8], 2.0, a[lo * 8:hi * 8:8])

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


def test_unloadable_file_means_no_library_and_leaves_the_environment(tmp_path: Path) -> None:
    """A file that is no library loads as ``None`` (numpy path), with the environment untouched."""
    junk = tmp_path / "libscipy_openblas.so"
    junk.write_text("not a shared object\n")
    before = dict(os.environ)
    assert blas.load_library(str(junk), cpuinfo=AMD_ZEN4) is None
    assert dict(os.environ) == before


@pytest.mark.parametrize(("cpuinfo", "expected"), [
    (AMD_ZEN4, "Zen"),
    ("vendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx\n", None),   # no AVX2: OpenBLAS's own pick
    (INTEL, None),
    ("", None),
])
def test_kernel_set_by_cpu(cpuinfo: str, expected: str | None) -> None:
    """AMD CPUs with AVX2 load OpenBLAS's Zen kernels (its SkylakeX pick on Zen 4 runs the strided
    daxpby slower); everything else keeps OpenBLAS's own choice."""
    assert blas.coretype_for(cpuinfo) == expected


@pytest.mark.parametrize("users_coretype", [None, "SandyBridge"])
@pytest.mark.parametrize("users_threads", [None, "4"])
@pytest.mark.parametrize(("cpuinfo", "chosen"), [(AMD_ZEN4, "Zen"), (INTEL, "-")])
def test_load_time_settings_exist_only_during_the_load(
        standin: str, monkeypatch: pytest.MonkeyPatch, users_coretype: str | None, users_threads: str | None,
        cpuinfo: str, chosen: str) -> None:
    """While the library loads it sees the kernel set chosen for the CPU and one thread, unless the
    user set either variable (then it sees the user's value); afterwards the environment is exactly
    what it was: a variable set for the load is gone, a user's value is still there, unchanged."""
    for name, value in (("OPENBLAS_CORETYPE", users_coretype), ("OPENBLAS_NUM_THREADS", users_threads)):
        if value is None:
            monkeypatch.delenv(name, raising=False)
        else:
            monkeypatch.setenv(name, value)
    before = dict(os.environ)
    loaded = blas.load_library(standin, cpuinfo=cpuinfo)
    assert loaded is not None
    assert loaded.config == (f"OpenBLAS stand-in coretype={users_coretype or chosen} "
                             f"threads={users_threads or '1'}")
    assert dict(os.environ) == before
    assert ctypes.CDLL(standin).scipy_openblas_get_num_threads() == 1  # the calls: one thread anyway


@pytest.mark.slow
@pytest.mark.parametrize("users_coretype", [None, "SandyBridge"])
def test_loaded_kernel_set_follows_the_cpu_and_restores_the_environment(
        library_file: str, users_coretype: str | None) -> None:
    """In a fresh process (a library picks its kernels once per process): the load used the user's
    ``OPENBLAS_CORETYPE`` when set, else the kernel set chosen for this CPU (Zen maps to OpenBLAS's
    Haswell kernels), and the environment after the load equals the one before, whether or not the
    user had set the variable (HPC module systems do)."""
    code = ("import json, os, sys\nfrom hdeem_watch.bench import blas\nbefore = dict(os.environ)\n"
            "loaded = blas.load_library(sys.argv[1])\n"
            "print(json.dumps([loaded.config, dict(os.environ) == before, os.environ.get('OPENBLAS_CORETYPE')]))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENBLAS")}
    if users_coretype is not None:
        env["OPENBLAS_CORETYPE"] = users_coretype
    out = subprocess.run([sys.executable, "-c", code, library_file], env=env, capture_output=True, text=True,
                         check=True)
    config, unchanged, coretype_after = json.loads(out.stdout)
    assert unchanged and coretype_after == users_coretype
    expected = users_coretype or blas.coretype_for(blas._read_cpuinfo())
    if library_file == WHEEL:
        if expected is not None:
            kernels = {"Zen": "Haswell"}.get(expected, expected)
            assert f" {kernels.lower()} " in config.lower()
    else:
        assert f"coretype={expected or '-'} " in config


@pytest.mark.slow
def test_loading_starts_no_thread_pool(library_file: str) -> None:
    """Loading the library adds no threads to the process (OpenBLAS would otherwise start a pool
    sized to the CPUs, idle but spinning after load); checked in a fresh process."""
    code = ("import os, sys, numpy; before = len(os.listdir('/proc/self/task'))\n"
            "from hdeem_watch.bench import blas; assert blas.load_library(sys.argv[1]) is not None\n"
            "print(before, len(os.listdir('/proc/self/task')))")
    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENBLAS")}
    out = subprocess.run([sys.executable, "-c", code, library_file], env=env, capture_output=True, text=True,
                         check=True)
    before, after = map(int, out.stdout.split())
    assert after == before
