"""The STREAM-like kernels at stride 8 doubles, and a compute-only idle kernel.

Every kernel touches one double per 64-byte line (``x[k]`` for ``k = 0, 8, 16, ...``), so each
access is one line and one BL8 burst in the DRAM model (DESIGN.md §3). A pass visits every line of
the worker's index range exactly once per array:

=========  ======================  ==========  ==================  =============
kernel     operation               reads       writes (+ RFO)      arrays
=========  ======================  ==========  ==================  =============
read       ``sum += a[k]``         a           -                   a
assign     ``a[k] = 2``            -           a                   a
scale      ``b[k] = 2 a[k]``       a           b                   a, b
add        ``c[k] = a[k] + b[k]``  a, b        c                   a, b, c
triad      ``a[k] = b[k] + 2 a[k]``  b, a      a                   a, b
copy       ``b[k] = a[k]``         a           b                   a, b
selfscale  ``a[k] = 2 a[k]``       a           a                   a
stride2    ``sum += a[2k]``        a (½)       -                   a
stride4    ``sum += a[4k]``        a (¼)       -                   a
gups       ``sum += a[r(k)]``      a (random)  -                   a
chase      ``k = p[k]``            p (random)  -                   p
mix31      ``a = a + b + c``       a, b, c     a                   a, b, c
=========  ======================  ==========  ==================  =============

The last five are the hold-out kernels (:data:`~hdeem_watch.bench.schedule.HOLDOUT_KERNELS`): the
strides read every 2nd/4th line of the range; gups reads as many random lines of the whole array as
the range has (a fixed generator per pass); chase follows a random cycle through the range's lines
stored in ``p`` (each line holds the index of the next: one dependent miss at a time); mix31 runs
in chunks like add (``a += b``, then ``a += c`` with ``a``'s lines still cached).

Read, assign, copy and selfscale are one numpy call per pass on strided views with ``out=`` (no
temporaries). Triad is one call per pass of OpenBLAS's fused ``daxpby`` (``a = 1.0 b + 2.0 a``,
:mod:`hdeem_watch.bench.blas`): numpy has no single call for ``b + 2a``, and its two-call version
tops out well below the C loop's rate (docs/bench.md). Scale and add, and triad when OpenBLAS is
missing, run in chunks of :func:`chunk_lines` lines, two numpy calls per chunk, with the chunk's
destination lines still in cache for the second call (no extra DRAM traffic):

* scale: copy ``a`` into ``b`` (the int64 copy below), then ``b += b`` in place (``2 a``: exact);
* add: copy ``b`` into ``c``, then ``c = a + c`` (the same single rounding as ``a + b``);
* triad (fallback): ``a += a`` in place (``2 a``, exact, or inf exactly where ``2.0 * a``
  overflows), then ``a = b + a`` (one rounding: bit-exact with the C loop, as ``daxpby`` is).

Splitting scale and add this way measured 1.15-1.2x faster than the single ``multiply``/``add``
call on one core here: the first call streams one array through numpy's fastest strided loop and
the second streams the other (docs/bench.md). The chunk is sized so the chunk's lines of the two
arrays fit in half of the worker's share of the last-level cache; the scratch buffer of
:func:`scratch_size` only carries the chunk length. Larger chunks mean fewer numpy calls (16384
lines run ~30 % faster than 4096 here). numpy and ctypes release the GIL inside each loop, so
threads run these passes truly in parallel. The calls were chosen for speed on strided views:
``einsum`` sums faster than ``add.reduce``, and copies run as ``bitwise_or(a, 0)`` on int64 views of
the same memory (bit-exact, faster than ``copyto`` or ``positive``); see docs/bench.md.

The idle kernel evaluates ``sin`` over a 16 KiB scratch buffer (L1-resident): cores busy, DRAM idle.

Example:
    >>> import numpy as np
    >>> arrays = make_arrays("add", 64)
    >>> init_arrays(arrays, 0, 8)
    >>> run_pass("add", arrays, 0, 8, np.empty(scratch_size("add")))
    0.0
    >>> float(arrays["c"][8]), float(arrays["c"][9])
    (3.0, 0.0)
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hdeem_watch.bench import blas
from hdeem_watch.bench.schedule import IDLE_KERNEL, KERNELS, canonical_kernel

#: Doubles per 64-byte cache line: the access stride.
STRIDE = 8
#: Bytes per cache line / DRAM burst.
LINE_BYTES = 64
#: Kernels that run in chunks (two numpy calls per chunk, the destination's lines kept in cache);
#: triad only when OpenBLAS is missing.
CHUNKED_KERNELS = ("scale", "add", "triad", "mix31")
#: Default lines per chunk: 2 arrays x 4096 lines x 64 B = 512 KiB of lines, inside a 1 MiB L2 and
#: any LLC (used when the LLC size is unknown).
CHUNK_LINES = 4096
#: Bounds of the chunk chosen from the LLC.
CHUNK_RANGE = (1024, 32768)
#: Cache bytes budgeted per chunk line: a line of each of two arrays, 8 bytes of slack
#: (formerly triad's scratch double; kept so the chunk sizes stay as measured).
CHUNK_BYTES_PER_LINE = 2 * 64 + 8
#: Doubles in the idle kernel's scratch buffer (16 KiB: L1-resident).
IDLE_BUFFER = 2048

#: Initial values written at first touch, per array.
INIT_VALUES: dict[str, float] = {"a": 1.0, "b": 2.0, "c": 0.0}
#: The pointer chase's array: each line holds the index of the next line of a random cycle.
CHASE_ARRAY = "p"

#: Lines per iteration counted by STREAM's convention (McCalpin's STREAM: 2 words per element for
#: copy and scale, 3 for add and triad): each array read or written counted once, no write-allocate
#: read of the destination. A "word" here is the 64-byte line the stride-8 access moves; read,
#: assign and selfscale, which STREAM lacks, follow the same rule.
STREAM_LINES: dict[str, int] = {"read": 1, "assign": 1, "scale": 2, "add": 3, "triad": 3, "copy": 2,
                                "selfscale": 2, IDLE_KERNEL: 0, "stride2": 1, "stride4": 1, "gups": 1, "chase": 1,
                                "mix31": 4}

#: Arrays each kernel uses (allocated and first-touched).
KERNEL_ARRAYS: dict[str, tuple[str, ...]] = {
    "read": ("a",),
    "assign": ("a",),
    "scale": ("a", "b"),
    "add": ("a", "b", "c"),
    "triad": ("a", "b"),
    "copy": ("a", "b"),
    "selfscale": ("a",),
    IDLE_KERNEL: (),
    "stride2": ("a",),
    "stride4": ("a",),
    "gups": ("a",),
    "chase": ("p",),
    "mix31": ("a", "b", "c"),
}
#: Line step of the strided kernels.
LINE_STEP = {"stride2": 2, "stride4": 4}

#: Lines read and written per array line per pass, write-allocate (read for ownership) included.
#: ``(reads, writes)`` per line index; multiply by the number of lines for a pass.
_LINE_TRAFFIC: dict[str, tuple[int, int]] = {
    "read": (1, 0),
    "assign": (1, 1),      # RFO of a, write-back of a
    "scale": (2, 1),       # a, RFO of b; b
    "add": (3, 1),         # a, b, RFO of c; c
    "triad": (2, 1),       # b, a (destination already read); a
    "copy": (2, 1),        # a, RFO of b; b
    "selfscale": (1, 1),   # a (destination already read); a
    IDLE_KERNEL: (0, 0),
    "gups": (1, 0),
    "chase": (1, 0),
    "mix31": (3, 1),       # a, b, c; a
}


def lines_of(elements: int) -> int:
    """Return the number of 64-byte lines a stride-8 pass touches in an array of ``elements``."""
    return (int(elements) + STRIDE - 1) // STRIDE


def array_bytes(kernel: str, elements: int) -> int:
    """Return the bytes the kernel's arrays occupy (what the memory check must find free)."""
    return len(KERNEL_ARRAYS[canonical_kernel(kernel)]) * int(elements) * 8


def local_traffic(kernel: str, elements: int) -> tuple[int, int]:
    """Return ``(lines_read, lines_written)`` of one pass, counted from the kernel definitions.

    This is the bench's own count; :func:`hdeem_watch.bench.runner.pass_traffic` prefers the DRAM
    model's ``kernel_traffic`` when it is installed and the two are checked against each other in
    the tests.
    """
    name = canonical_kernel(kernel)
    if name in LINE_STEP:
        return -(-lines_of(elements) // LINE_STEP[name]), 0
    reads, writes = _LINE_TRAFFIC[name]
    n = lines_of(elements)
    return reads * n, writes * n


def make_arrays(kernel: str, elements: int) -> dict[str, np.ndarray]:
    """Allocate (but do not touch) the kernel's arrays of ``elements`` doubles each.

    ``np.empty`` of a large size maps fresh pages that the OS places on first touch, so the worker
    that later calls :func:`init_arrays` on its own range decides where its pages live. Large
    arrays start on a 2 MiB (huge-page) boundary, like the C baseline's ``posix_memalign``
    arrays: measured here, add went from 0.81 to 0.90 of C and the same C loop run on the arrays
    from 0.77 to 1.00 (numpy's own arrays start 16 bytes into a page).
    """
    return {name: _aligned_empty(int(elements)) for name in KERNEL_ARRAYS[canonical_kernel(kernel)]}


#: Array start alignment: a huge-page boundary, as the C baseline's ``posix_memalign`` uses.
ALIGN_BYTES = 2 << 20


def _aligned_empty(elements: int) -> np.ndarray:
    """An untouched float64 array whose data starts on a 2 MiB boundary (for large arrays)."""
    if elements * 8 < 4 * ALIGN_BYTES:
        return np.empty(elements, dtype=np.float64)
    raw = np.empty(elements + ALIGN_BYTES // 8, dtype=np.float64)
    start = (-raw.ctypes.data % ALIGN_BYTES) // 8
    return raw[start:start + elements]


def init_arrays(arrays: Mapping[str, np.ndarray], lo_line: int, hi_line: int) -> None:
    """First-touch every element of lines ``[lo_line, hi_line)`` with :data:`INIT_VALUES` (the chase's
    ``p``: a random cycle through the range's lines, each line holding the next one's index)."""
    for name, array in arrays.items():
        if name == CHASE_ARRAY:
            array[lo_line * STRIDE:hi_line * STRIDE] = 0.0
            order = lo_line + np.random.default_rng(lo_line).permutation(max(0, hi_line - lo_line))
            _view(array, lo_line, hi_line)[order - lo_line] = np.roll(order, -1).astype(np.float64)
            continue
        array[lo_line * STRIDE:hi_line * STRIDE] = INIT_VALUES[name]


def split_lines(lines: int, workers: int) -> list[tuple[int, int]]:
    """Split ``lines`` into ``workers`` contiguous ranges whose sizes differ by at most one.

    Example:
        >>> split_lines(10, 3)
        [(0, 4), (4, 7), (7, 10)]
    """
    base, extra = divmod(int(lines), int(workers))
    out: list[tuple[int, int]] = []
    lo = 0
    for w in range(int(workers)):
        hi = lo + base + (1 if w < extra else 0)
        out.append((lo, hi))
        lo = hi
    return out


def _view(array: np.ndarray, lo_line: int, hi_line: int) -> np.ndarray:
    return array[lo_line * STRIDE:hi_line * STRIDE:STRIDE]


def run_pass(kernel: str, arrays: Mapping[str, np.ndarray], lo_line: int, hi_line: int,
             scratch: np.ndarray) -> float:
    """Run one pass of ``kernel`` over lines ``[lo_line, hi_line)``; return the read sum (else 0).

    Args:
        kernel: canonical name (see :data:`KERNEL_ARRAYS`).
        arrays: the arrays from :func:`make_arrays`.
        lo_line: first line of this worker's range.
        hi_line: one past the last line.
        scratch: a per-worker float64 buffer from :func:`scratch_size`; for the
            :data:`CHUNKED_KERNELS` its length is the chunk in lines, for idle at least
            :data:`IDLE_BUFFER`.

    Returns:
        ``sum(a[k])`` for read, 0.0 for every other kernel (the idle kernel returns a checksum).
    """
    if kernel == "read":
        return float(np.einsum("i->", _view(arrays["a"], lo_line, hi_line)))
    if kernel == "assign":
        _view(arrays["a"], lo_line, hi_line).fill(2.0)
    elif kernel == "scale":
        _scale(arrays["a"], arrays["b"], lo_line, hi_line, scratch.size)
    elif kernel == "add":
        _add(arrays["a"], arrays["b"], arrays["c"], lo_line, hi_line, scratch.size)
    elif kernel == "copy":
        _copy(_view(arrays["a"], lo_line, hi_line), _view(arrays["b"], lo_line, hi_line))
    elif kernel == "selfscale":
        a = _view(arrays["a"], lo_line, hi_line)
        np.multiply(a, 2.0, out=a)
    elif kernel == "triad":
        _triad(arrays["a"], arrays["b"], lo_line, hi_line, scratch.size)
    elif kernel == IDLE_KERNEL:
        return _idle(hi_line - lo_line, scratch)
    elif kernel in LINE_STEP:
        return float(np.einsum("i->", arrays["a"][lo_line * STRIDE:hi_line * STRIDE:STRIDE * LINE_STEP[kernel]]))
    elif kernel == "gups":
        lines = lines_of(arrays["a"].size)
        picks = np.random.default_rng(lo_line).integers(0, lines, hi_line - lo_line) * STRIDE
        return float(np.take(arrays["a"], picks).sum())
    elif kernel == "chase":
        return _chase(arrays[CHASE_ARRAY], lo_line, hi_line)
    elif kernel == "mix31":
        _mix31(arrays["a"], arrays["b"], arrays["c"], lo_line, hi_line, scratch.size)
    else:  # pragma: no cover - canonical names are checked by the schedule
        raise ValueError(f"unknown kernel {kernel!r}; expected one of {KERNELS}")
    return 0.0


def prepare(kernel: str) -> None:
    """Load what ``kernel``'s passes call (OpenBLAS for triad: ~85 ms the first time), so that the
    load happens before a run's window opens, not inside it."""
    if canonical_kernel(kernel) == "triad":
        blas.openblas()


def chunk_lines(llc_bytes: int | None, workers: int) -> int:
    """Return the chunk (lines) whose two-array working set fits half a worker's share of the LLC.

    Example:
        >>> chunk_lines(30 << 20, 24), chunk_lines(32 << 20, 2), chunk_lines(None, 1)
        (4818, 32768, 4096)
    """
    if not llc_bytes:
        return CHUNK_LINES
    lo, hi = CHUNK_RANGE
    return max(lo, min(hi, int(llc_bytes) // max(1, int(workers)) // 2 // CHUNK_BYTES_PER_LINE))


def _copy(src: np.ndarray, dst: np.ndarray) -> None:
    """``dst = src`` bit for bit through the int64 loop, which runs faster on strided views than any
    float64 copy numpy has (positive, copyto, multiply by 1): measured 180 vs 137 Mlines/s."""
    np.bitwise_or(src.view(np.int64), 0, out=dst.view(np.int64))


def _scale(a_full: np.ndarray, b_full: np.ndarray, lo_line: int, hi_line: int, step: int) -> None:
    for lo in range(lo_line, hi_line, step):
        hi = min(lo + step, hi_line)
        b = _view(b_full, lo, hi)
        _copy(_view(a_full, lo, hi), b)
        np.add(b, b, out=b)  # 2a, exact (or inf, as 2.0 * a); b's lines are still cached


def _add(a_full: np.ndarray, b_full: np.ndarray, c_full: np.ndarray, lo_line: int, hi_line: int,
         step: int) -> None:
    for lo in range(lo_line, hi_line, step):
        hi = min(lo + step, hi_line)
        c = _view(c_full, lo, hi)
        _copy(_view(b_full, lo, hi), c)
        np.add(_view(a_full, lo, hi), c, out=c)  # a + b with c's lines still cached


def _triad(a_full: np.ndarray, b_full: np.ndarray, lo_line: int, hi_line: int, step: int) -> None:
    fused = blas.openblas()
    if fused is not None:  # one fused pass, both arrays streaming at once, as in the C loop
        fused.axpby(1.0, _view(b_full, lo_line, hi_line), 2.0, _view(a_full, lo_line, hi_line))
        return
    for lo in range(lo_line, hi_line, step):
        hi = min(lo + step, hi_line)
        a = _view(a_full, lo, hi)
        np.add(a, a, out=a)  # 2a in place: exact (or inf, as 2.0 * a); the lines stay cached
        np.add(_view(b_full, lo, hi), a, out=a)  # b + 2a, one rounding: bit-exact with C


def _chase(p: np.ndarray, lo_line: int, hi_line: int) -> float:
    """Follow the cycle from ``lo_line`` once around (one dependent load per line); the last index."""
    k = lo_line
    for _ in range(hi_line - lo_line):
        k = int(p[k * STRIDE])
    return float(k)


def _mix31(a_full: np.ndarray, b_full: np.ndarray, c_full: np.ndarray, lo_line: int, hi_line: int,
           step: int) -> None:
    for lo in range(lo_line, hi_line, step):
        hi = min(lo + step, hi_line)
        a = _view(a_full, lo, hi)
        np.add(a, _view(b_full, lo, hi), out=a)
        np.add(a, _view(c_full, lo, hi), out=a)  # a's lines still cached: 3 lines read, 1 written


def _idle(lines: int, scratch: np.ndarray) -> float:
    """Evaluate ``lines`` sines in an L1-resident buffer (one per 'line' of the range)."""
    buf = scratch[:IDLE_BUFFER]
    buf[:] = np.linspace(0.0, 1.0, IDLE_BUFFER)
    done = 0
    while done < lines:
        n = min(IDLE_BUFFER, lines - done)
        np.sin(buf[:n], out=buf[:n])
        done += n
    return float(buf[0])


def scratch_size(kernel: str, chunk: int = CHUNK_LINES) -> int:
    """Return the scratch elements a worker needs for ``kernel`` (a chunked kernel: its chunk in lines)."""
    if kernel in CHUNKED_KERNELS:
        return max(1, int(chunk))
    return IDLE_BUFFER if kernel == IDLE_KERNEL else 1
