"""Tests of the bench kernels: arithmetic, which lines they touch, and their DRAM traffic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdeem_watch.bench import blas
from hdeem_watch.bench import kernels as K
from hdeem_watch.bench.runner import pass_traffic, run_one
from hdeem_watch.bench.schedule import KERNELS, RunSpec
from hdeem_watch.dram.kernels import ARRAY_BASES, kernel_requests, kernel_traffic

#: Reference semantics per kernel, one line k at a time: new values of the destination (or the
#: sum contribution for read), written as plain Python.
REFERENCE = {
    "read": lambda v: {},
    "assign": lambda v: {"a": 2.0},
    "scale": lambda v: {"b": 2.0 * v["a"]},
    "add": lambda v: {"c": v["a"] + v["b"]},
    "triad": lambda v: {"a": v["b"] + 2.0 * v["a"]},
    "copy": lambda v: {"b": v["a"]},
    "selfscale": lambda v: {"a": 2.0 * v["a"]},
    "mix31": lambda v: {"a": (v["a"] + v["b"]) + v["c"]},
}


@pytest.fixture(params=["as-installed", "numpy"])
def triad_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Run a triad test as installed (OpenBLAS's fused ``daxpby`` with the ``bench`` extra, numpy
    without it) and again with the wheel made absent, so the numpy fallback is always tested."""
    if request.param == "numpy":
        monkeypatch.setattr(blas.importlib.util, "find_spec", lambda name: None)
        monkeypatch.setattr(blas, "_LOADED", [])  # forget a library loaded earlier in this process
        assert blas.openblas() is None
    else:
        assert (blas.openblas() is None) == (blas.library_path() is None)
    return str(request.param)


def _reference_run(kernel: str, arrays: dict[str, np.ndarray], repeat: int) -> float:
    """Run the kernel with a Python loop over k = 0, 8, 16, ...; return the last pass's sum."""
    total = 0.0
    n = len(next(iter(arrays.values())))
    for _ in range(repeat):
        total = 0.0
        for k in range(0, n, 8):
            values = {name: float(a[k]) for name, a in arrays.items()}
            total += values.get("a", 0.0)
            for name, value in REFERENCE[kernel](values).items():
                arrays[name][k] = value
    return total


def _filled(kernel: str, elements: int) -> dict[str, np.ndarray]:
    arrays = K.make_arrays(kernel, elements)
    K.init_arrays(arrays, 0, K.lines_of(elements))
    return arrays


@pytest.mark.slow
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("backend", ["thread", "process"])
def test_kernel_arithmetic_matches_reference(kernel: str, backend: str) -> None:
    """Each kernel computes its STREAM formula at every 8th double, over all workers' ranges."""
    elements, repeat = 8 * 1001 + 3, 3  # an odd line count, a partial last line, 2 workers
    threads = 2
    result = run_one(RunSpec(kernel, threads, elements, repeat), backend=backend, keep_arrays=True,
                     oversubscribe=True)
    expected = _filled(kernel, elements)
    expected_sum = _reference_run(kernel, expected, repeat)
    assert result.arrays is not None
    assert set(result.arrays) == set(expected)
    for name in expected:
        np.testing.assert_array_equal(result.arrays[name], expected[name], err_msg=f"{kernel}: array {name}")
    if kernel == "read":
        assert result.checksum == expected_sum == K.lines_of(elements) * K.INIT_VALUES["a"]
    else:
        assert math.isnan(result.checksum)


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["thread", "process"])
def test_triad_arithmetic_on_both_paths(triad_path: str, backend: str) -> None:
    """Triad computes ``b + 2a`` at every 8th double through OpenBLAS and through numpy alike."""
    elements, repeat = 8 * 1001 + 3, 3
    result = run_one(RunSpec("triad", 2, elements, repeat), backend=backend, keep_arrays=True,
                     oversubscribe=True)
    expected = _filled("triad", elements)
    _reference_run("triad", expected, repeat)
    assert result.arrays is not None
    for name in expected:
        np.testing.assert_array_equal(result.arrays[name], expected[name], err_msg=f"{triad_path}: {name}")


def _probe(kernel: str, elements: int) -> tuple[set[str], set[str]]:
    """Find which arrays a pass reads (NaN poisoning) and writes (changed values).

    Also checks that only stride-8 elements are read or written and each written line is written
    with the value of its own line's operands.
    """
    names = K.KERNEL_ARRAYS[kernel]
    lines = K.lines_of(elements)
    scratch = np.zeros(K.scratch_size(kernel))
    stride = np.zeros(elements, dtype=bool)
    stride[::8] = True

    def fresh(poison: str | None, poison_gaps: bool) -> dict[str, np.ndarray]:
        arrays = {}
        for i, name in enumerate(names):
            a = np.full(elements, np.nan if poison_gaps else -7.0)
            a[stride] = 3.0 + i + np.arange(lines) % 5  # distinct, non-fixed points of every kernel
            if name == poison:
                a[stride] = np.nan
            arrays[name] = a
        return arrays

    # Writes: stride elements that changed; gaps must be untouched (NaN gaps stay NaN).
    before = fresh(None, poison_gaps=True)
    after = {n: a.copy() for n, a in before.items()}
    checksum = K.run_pass(kernel, after, 0, lines, scratch)
    assert math.isfinite(checksum), f"{kernel} read a non-stride element"
    written = set()
    for name in names:
        changed = ~((after[name] == before[name]) | (np.isnan(after[name]) & np.isnan(before[name])))
        assert not (changed & ~stride).any(), f"{kernel} wrote a non-stride element of {name}"
        if changed[stride].any():
            assert changed[stride].all(), f"{kernel} wrote only some lines of {name}"
            assert np.isfinite(after[name][stride]).all(), f"{kernel} read a gap element into {name}"
            written.add(name)
    # Reads: an array is a source if poisoning its stride elements poisons the result.
    read = set()
    for name in names:
        arrays = fresh(name, poison_gaps=False)
        checksum = K.run_pass(kernel, arrays, 0, lines, scratch)
        outputs = [arrays[w][stride] for w in written]
        poisoned = math.isnan(checksum) if kernel == "read" else any(np.isnan(o).all() for o in outputs)
        partial = any(np.isnan(o).any() and not np.isnan(o).all() for o in outputs)
        assert not partial, f"{kernel}: only some lines depend on {name}"
        if poisoned:
            read.add(name)
    return read, written


@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_traffic_matches_dram_model_requests(kernel: str) -> None:
    """The arrays a kernel reads and writes, line by line, are those of the DRAM model's request
    stream, and the lines per pass (write-allocate included) equal kernel_traffic's count."""
    elements, threads = 8 * 257, 3
    read, written = _probe(kernel, elements)
    lines = K.lines_of(elements)

    addresses, is_write = kernel_requests(kernel, elements, threads)
    by_base = {base: name for name, base in ARRAY_BASES.items()}
    model_read: dict[str, np.ndarray] = {}
    model_written: dict[str, np.ndarray] = {}
    for name in ("a", "b", "c"):
        base = ARRAY_BASES[name]
        inside = (addresses >= base) & (addresses < base + (1 << 30))
        model_read[name] = (addresses[inside & ~is_write] - base) // 64
        model_written[name] = (addresses[inside & is_write] - base) // 64
    assert set(by_base.values()) >= set(model_read)
    # Every line of a written array is written exactly once, and read once (source or RFO).
    for name in ("a", "b", "c"):
        if name in written:
            np.testing.assert_array_equal(np.sort(model_written[name]), np.arange(lines))
            np.testing.assert_array_equal(np.sort(model_read[name]), np.arange(lines))
        else:
            assert model_written[name].size == 0, f"model writes {name}, the kernel does not"
        if name in read and name not in written:
            np.testing.assert_array_equal(np.sort(model_read[name]), np.arange(lines))
        if name not in read and name not in written:
            assert model_read[name].size == 0, f"model reads {name}, the kernel does not"
    # Counted traffic: sources + RFO of a destination that is not a source; one write-back each.
    ours = (lines * len(read | written), lines * len(written))
    traffic = kernel_traffic(kernel, elements)
    assert ours == (traffic.lines_read, traffic.lines_written) == (int((~is_write).sum()), int(is_write.sum()))
    assert K.local_traffic(kernel, elements) == ours
    reads, writes, origin = pass_traffic(kernel, elements)
    assert (reads, writes, origin) == (*ours, "dram-model")


def test_triad_fallback_touches_the_same_lines(triad_path: str) -> None:
    """Both triad paths read a and b and write a, at stride-8 elements only."""
    assert _probe("triad", 8 * 700) == ({"a", "b"}, {"a"})


def test_split_lines_covers_range_once() -> None:
    """Workers' line ranges are contiguous, disjoint and cover every line (OpenMP static split)."""
    for lines in (0, 1, 7, 1000, 1001):
        for workers in (1, 2, 3, 24):
            ranges = K.split_lines(lines, workers)
            assert len(ranges) == workers
            covered = [k for lo, hi in ranges for k in range(lo, hi)]
            assert covered == list(range(lines))
            sizes = [hi - lo for lo, hi in ranges]
            assert max(sizes) - min(sizes) <= 1


def test_chunk_fits_half_the_workers_llc_share() -> None:
    """A chunk's working set (lines of two arrays plus slack) fits half a worker's LLC share,
    within the chunk bounds; unknown LLC falls back to a chunk that fits a 1 MiB L2."""
    lo, hi = K.CHUNK_RANGE
    for llc in (2 << 20, 30 << 20, 32 << 20, 60 << 20):
        for workers in (1, 2, 12, 24, 48):
            chunk = K.chunk_lines(llc, workers)
            assert lo <= chunk <= hi
            if lo < chunk < hi:
                assert chunk * K.CHUNK_BYTES_PER_LINE <= llc / workers / 2
                assert (chunk + 1) * K.CHUNK_BYTES_PER_LINE > llc / workers / 2
    fallback = K.chunk_lines(None, 4)
    assert fallback * K.CHUNK_BYTES_PER_LINE <= 1 << 20


@pytest.mark.parametrize("kernel", K.CHUNKED_KERNELS)
@pytest.mark.parametrize("chunk", [1, 7, 64, 1000, 1001, 5000])
def test_chunk_boundaries(kernel: str, chunk: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """A chunked kernel gives the same result whatever the chunk (ranges not multiples of it included);
    triad's numpy fallback is the chunked one."""
    monkeypatch.setattr(blas, "openblas", lambda: None)
    elements = 8 * 1001
    arrays = _filled(kernel, elements)
    expected = {n: a.copy() for n, a in arrays.items()}
    _reference_run(kernel, expected, 2)
    scratch = np.zeros(K.scratch_size(kernel, chunk))
    for _ in range(2):
        K.run_pass(kernel, arrays, 0, 500, scratch)
        K.run_pass(kernel, arrays, 500, 1001, scratch)
    for name in arrays:
        np.testing.assert_array_equal(arrays[name], expected[name])


def test_idle_kernel_moves_no_dram_lines() -> None:
    """The idle kernel allocates no arrays, reports zero DRAM traffic, and still takes time."""
    result = run_one(RunSpec("idle", 1, 8 * 200_000, 2))
    assert K.array_bytes("idle", 10**9) == 0
    assert (result.lines_read_per_pass, result.lines_written_per_pass) == (0, 0)
    assert result.dram_bytes_per_s == 0.0 and result.lines_per_s == 0.0
    assert result.seconds > 0
    assert result.t_end_ns >= result.t_start_ns


def test_large_arrays_start_on_a_huge_page_boundary() -> None:
    """Large arrays start on a 2 MiB boundary and have exactly the requested length."""
    arrays = K.make_arrays("add", 1 << 20)  # 8 MiB each
    assert set(arrays) == {"a", "b", "c"}
    for array in arrays.values():
        assert array.size == 1 << 20 and array.dtype == np.float64
        assert array.ctypes.data % K.ALIGN_BYTES == 0
    small = K.make_arrays("copy", 1000)
    assert all(a.size == 1000 for a in small.values())


def test_triad_is_bit_exact_with_the_c_expression_on_awkward_values(triad_path: str) -> None:
    """Triad's chunked in-place steps give exactly ``b + 2.0 * a`` (the C loop's expression) at every
    stride-8 double, bit for bit (signed zeros, subnormals, overflow to inf, NaN, random values), over
    several chunks and a partial last chunk, and leave every other double untouched."""
    with np.errstate(over="ignore", invalid="ignore"):
        _check_triad_bits(np.random.default_rng(6))


def _check_triad_bits(rng: np.random.Generator) -> None:
    lines = 3 * 64 + 17
    special = np.array([0.0, -0.0, 5e-324, -5e-324, 1e308, -1e308, np.inf, -np.inf, np.nan, 1.5, -2.25])
    a = rng.normal(size=lines * 8) * 10.0 ** rng.integers(-300, 300, size=lines * 8)
    b = rng.normal(size=lines * 8) * 10.0 ** rng.integers(-300, 300, size=lines * 8)
    pairs = np.array([(x, y) for x in special for y in special])
    a[:len(pairs) * 8:8], b[:len(pairs) * 8:8] = pairs[:, 0], pairs[:, 1]
    arrays = {"a": a.copy(), "b": b.copy()}
    expected = a.copy()
    expected[::8] = b[::8] + 2.0 * a[::8]
    K.run_pass("triad", arrays, 0, lines, np.empty(K.scratch_size("triad", 64)))
    assert arrays["a"].view(np.int64).tolist() == expected.view(np.int64).tolist()
    assert arrays["b"].view(np.int64).tolist() == b.view(np.int64).tolist()


def test_triad_library_loads_before_the_window_opens(monkeypatch: pytest.MonkeyPatch) -> None:
    """OpenBLAS (~85 ms to load the first time) is loaded in the prepare phase, before ``on_start``
    opens the window, never inside a measured pass."""
    events: list[str] = []
    real = blas.openblas

    def recording() -> blas.Blas | None:
        events.append("load")
        return real()

    monkeypatch.setattr(blas, "openblas", recording)

    def on_start(spec: RunSpec) -> None:
        events.append("window")

    run_one(RunSpec("triad", 1, 8 * 1000, 2), on_start=on_start)
    assert events[0] == "load" and "window" in events
    assert events.index("window") > events.index("load")


# -- hold-out kernels (issue #32) ---------------------------------------------------------------------


def test_holdout_kernels_read_what_they_say_and_match_the_models_traffic() -> None:
    """Strides sum every 2nd/4th line, gups as many random lines as the range has, the chase walks
    the whole cycle back to its start; each pass's lines are the DRAM model's."""
    from hdeem_watch.bench.schedule import HOLDOUT_KERNELS, parse_kernels

    elements = 8 * 4096
    lines = elements // 8
    sums = {}
    for kernel in HOLDOUT_KERNELS:
        arrays = _filled(kernel, elements)
        sums[kernel] = K.run_pass(kernel, arrays, 0, lines, np.empty(K.scratch_size(kernel)))
        traffic = kernel_traffic(kernel, elements)
        assert K.local_traffic(kernel, elements) == (traffic.lines_read, traffic.lines_written), kernel
    assert sums["stride2"] == lines / 2 and sums["stride4"] == lines / 4 and sums["gups"] == lines
    assert sums["chase"] == 0.0  # once around the cycle: back at line 0
    chase = _filled("chase", elements)["p"][::8].astype(int)
    seen, k = set(), 0
    for _ in range(lines):
        seen.add(k)
        k = int(chase[k])
    assert len(seen) == lines  # one cycle through every line
    assert parse_kernels("holdout") == list(HOLDOUT_KERNELS)
