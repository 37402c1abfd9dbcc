"""DRAM request streams of the STREAM-like kernels, and their command statistics.

Each kernel touches one 64-byte line per access (stride 8 doubles, one BL8 burst) of arrays much
larger than the last-level cache. Per iteration ``k`` the stream holds a read of each source line
in operand order, then a read-for-ownership of the destination line unless it was just read as a
source (write-allocate), then the destination's write-back (``wb0``: right after the reads of the
same iteration). This is exactly how the Ramulator reference traces were built
(``reference/ramulator/README.md``); arrays ``a``, ``b``, ``c`` start at 1, 2 and 3 GiB.

Threads split the line range into contiguous chunks (OpenMP ``static``: the first ``lines % T``
threads get one line more); their streams interleave at the memory controller round-robin, one
iteration of each thread in turn.

Example:
    >>> kernel_traffic("copy", 16)
    Traffic(lines_read=4, lines_written=2)
    >>> addresses, is_write = kernel_requests("copy", 16, threads=1)
    >>> [hex(int(a)) for a in addresses[:3]], is_write[:3].tolist()
    (['0x40000000', '0x80000000', '0x80000000'], [False, False, True])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.dram.command_set import ControllerResult
    from hdeem_watch.dram.memspec import MemSpec
    from hdeem_watch.dram.stats import CommandStats

#: The kernels, in the order of the seed paper.
KERNELS = ("read", "assign", "scale", "add", "triad", "copy", "selfscale")
#: Workloads the calibration schedule does not run, kept to test a calibration on what it never saw:
#: random 64-byte reads over the array (GUPS-like, many misses in flight), a dependent pointer chase
#: (the same random reads, one miss in flight per thread), reads of every 2nd and 4th line, and a
#: 3:1 read/write mix (``a = f(a, b, c)``: three lines read, the first written back).
HOLDOUT_KERNELS = ("gups", "chase", "stride2", "stride4", "mix31")
#: Line step of the strided kernels (one line read per step).
LINE_STRIDES = {"stride2": 2, "stride4": 4}
#: Kernels whose line per iteration is random (uniform over the array, with replacement).
RANDOM_KERNELS = ("gups", "chase")
#: Accepted alternative names.
ALIASES = {"addition": "add", "sum": "read"}
#: Bytes per request (one cache line, one BL8 burst of a 64-bit channel).
LINE_BYTES = 64
#: Doubles per line: the stride of every kernel.
STRIDE_DOUBLES = 8
#: The longest prefix :func:`kernel_stats` simulates (whatever ``max_requests`` allows): the
#: statistics per request converge within 0.3 % of the full Ramulator-size runs (see the tests).
PREFIX_REQUESTS = 1 << 18
#: Physical base address of each array.
ARRAY_BASES = {"a": 1 << 30, "b": 2 << 30, "c": 3 << 30}

#: Sources (in operand order) and destination of each kernel.
_OPERANDS: dict[str, tuple[tuple[str, ...], str | None]] = {
    "read": (("a",), None),
    "assign": ((), "a"),
    "scale": (("a",), "b"),
    "add": (("a", "b"), "c"),
    "triad": (("b", "a"), "a"),
    "copy": (("a",), "b"),
    "selfscale": (("a",), "a"),
    "gups": (("a",), None),
    "chase": (("a",), None),
    "stride2": (("a",), None),
    "stride4": (("a",), None),
    "mix31": (("a", "b", "c"), "a"),
}


@dataclass(frozen=True)
class Traffic:
    """DRAM lines one pass of a kernel moves.

    Attributes:
        lines_read: 64-byte lines read, read-for-ownership included.
        lines_written: 64-byte lines written back.
    """

    lines_read: int
    lines_written: int


@dataclass(frozen=True)
class KernelModel:
    """Command statistics of a kernel run on one channel.

    Attributes:
        stats: per-rank statistics of one channel, all passes.
        reads: read requests on that channel.
        writes: write requests on that channel.
        cycles: DRAM clock cycles the channel needs.
        row_hits: requests that found their row open.
        row_misses: requests to a precharged bank.
        row_conflicts: requests that had to close another row first.
        scale: how much the simulated prefix was multiplied by.
    """

    stats: CommandStats
    reads: float
    writes: float
    cycles: float
    row_hits: float
    row_misses: float
    row_conflicts: float
    scale: float


def canonical_kernel(kernel: str) -> str:
    """The canonical name of ``kernel`` (aliases resolved, case-insensitive).

    Raises:
        InputError: for an unknown kernel.
    """
    name = str(kernel).strip().lower()
    name = ALIASES.get(name, name)
    if name not in _OPERANDS:
        raise InputError(f"kernel {kernel!r}: unknown; expected one of {', '.join(KERNELS + HOLDOUT_KERNELS)} "
                         "(or 'addition')")
    return name


def access_pattern(kernel: str) -> tuple[tuple[str, bool], ...]:
    """The per-iteration accesses of ``kernel`` as ``(array, is_write)`` in stream order."""
    sources, destination = _OPERANDS[canonical_kernel(kernel)]
    pattern = [(array, False) for array in sources]
    if destination is not None:
        if destination not in sources:
            pattern.append((destination, False))
        pattern.append((destination, True))
    return tuple(pattern)


def kernel_lines(elements: int) -> int:
    """Lines one array of ``elements`` doubles spans at stride 8 (``ceil(elements / 8)``)."""
    if isinstance(elements, bool) or int(elements) != elements or elements < 0:
        raise InputError(f"elements {elements!r}: expected a non-negative integer")
    return -(-int(elements) // STRIDE_DOUBLES)


def kernel_iterations(kernel: str, elements: int) -> int:
    """Iterations of one pass (one access of each operand each): the array's lines, every
    ``LINE_STRIDES``-th of them for a strided kernel."""
    return -(-kernel_lines(elements) // LINE_STRIDES.get(canonical_kernel(kernel), 1))


def _mix(values: np.ndarray, seed: int) -> np.ndarray:
    """A fixed pseudo-random 64-bit hash of each value (splitmix64's finaliser)."""
    with np.errstate(over="ignore"):
        z = values.astype(np.uint64) + np.uint64((0x9E3779B97F4A7C15 * (int(seed) + 1)) & (2 ** 64 - 1))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def iteration_lines(kernel: str, lines: int, iterations: np.ndarray, seed: int = 0) -> np.ndarray:
    """The array line each iteration touches: itself (streams), ``stride ×`` it (strided kernels),
    or a random line of the array's ``lines`` (random kernels; fixed by ``seed``).

    >>> iteration_lines("stride4", 100, np.arange(3, dtype=np.uint64)).tolist()
    [0, 4, 8]
    >>> bool((iteration_lines("gups", 100, np.arange(1000, dtype=np.uint64)) < 100).all())
    True
    """
    name = canonical_kernel(kernel)
    it = np.asarray(iterations, dtype=np.uint64)
    if name in RANDOM_KERNELS:
        return _mix(it, seed) % np.uint64(max(1, int(lines)))
    return it * np.uint64(LINE_STRIDES.get(name, 1))


def kernel_traffic(kernel: str, elements: int) -> Traffic:
    """Lines read and written by one pass of ``kernel`` over ``elements`` doubles per array.

    Pure counting: write-allocate reads are included, so a written line counts once as read and
    once as written unless it is also a source.
    """
    pattern = access_pattern(kernel)
    lines = kernel_iterations(kernel, elements)
    writes = sum(1 for _, is_write in pattern if is_write)
    return Traffic(lines_read=lines * (len(pattern) - writes), lines_written=lines * writes)


def thread_line_order(lines: int, threads: int, max_steps: int | None = None) -> np.ndarray:
    """Line indices in controller order: contiguous chunks per thread, interleaved round-robin.

    ``max_steps`` keeps only each thread's first iterations (a prefix of the same layout).

    Raises:
        InputError: if ``threads`` is not a positive integer.
    """
    if isinstance(threads, bool) or int(threads) != threads or threads < 1:
        raise InputError(f"threads {threads!r}: expected a positive integer")
    threads = int(threads)
    if threads == 1 or lines == 0:
        return np.arange(lines if max_steps is None else min(lines, max_steps), dtype=np.uint64)
    base, extra = divmod(lines, threads)
    sizes = np.full(threads, base, dtype=np.int64)
    sizes[:extra] += 1
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    if max_steps is not None:
        sizes = np.minimum(sizes, max_steps)
    steps = int(sizes.max())
    step = np.arange(steps, dtype=np.int64)[:, None]
    grid = starts[None, :] + step
    valid = step < sizes[None, :]
    return grid[valid].astype(np.uint64)


def kernel_requests(kernel: str, elements: int, threads: int = 1, *,
                    max_steps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The DRAM request stream of one pass of ``kernel``.

    Args:
        kernel: one of :data:`KERNELS` (or an alias).
        elements: doubles per array.
        threads: threads sharing the index range.
        max_steps: only each thread's first ``max_steps`` iterations (a prefix of the stream).

    Returns:
        ``(addresses, is_write)``: physical byte addresses (``uint64``) and write flags, in the
        order the controller receives them.
    """
    pattern = access_pattern(kernel)
    order = iteration_lines(kernel, kernel_lines(elements),
                            thread_line_order(kernel_iterations(kernel, elements), threads, max_steps)) * np.uint64(LINE_BYTES)
    width = len(pattern)
    addresses = np.empty((order.size, width), dtype=np.uint64)
    is_write = np.empty((order.size, width), dtype=bool)
    for column, (array, write) in enumerate(pattern):
        np.add(order, np.uint64(ARRAY_BASES[array]), out=addresses[:, column])
        is_write[:, column] = write
    return addresses.ravel(), is_write.ravel()


_CACHE: dict[tuple[Any, ...], ControllerResult] = {}


def _simulate_prefix(spec: MemSpec, name: str, lines: int, threads: int, steps: int, policy: str,
                     mapping: str, xor_bank: bool = False) -> ControllerResult:
    """Simulate each thread's first ``steps`` iterations over ``lines`` lines (cached: the daemon
    asks for the same runs again)."""
    from hdeem_watch.dram.controller import simulate

    try:
        key: tuple[Any, ...] | None = (
            getattr(spec, "memory_id", None), tuple(sorted(spec.timings.items())), spec.nbr_of_ranks,
            spec.nbr_of_banks, spec.nbr_of_bankgroups, spec.nbr_of_rows, spec.nbr_of_columns,
            spec.burst_length, spec.width, spec.nbr_of_devices, name, lines, threads, steps, policy, mapping, xor_bank)
    except (AttributeError, TypeError):
        key = None
    if key is not None and key in _CACHE:
        return _CACHE[key]
    addresses, is_write = kernel_requests(name, lines * STRIDE_DOUBLES, threads, max_steps=steps)
    result = simulate(spec, addresses, is_write, policy=policy, mapping=mapping, xor_bank=xor_bank)
    if key is not None:
        if len(_CACHE) > 256:
            _CACHE.clear()
        _CACHE[key] = result
    return result


def kernel_stats(
    spec: MemSpec,
    kernel: str,
    elements: int,
    threads: int,
    *,
    repeat: int = 1,
    channels: int = 1,
    mapping: str = "RoBaRaCoCh",
    max_requests: int = 2_000_000,
    policy: str = "open",
    xor_bank: bool = False,
) -> KernelModel:
    """Command statistics of ``repeat`` passes of ``kernel`` on ONE of ``channels`` channels.

    Each channel carries ``1/channels`` of the traffic (the lines are interleaved over the
    channels). A representative prefix of the stream (at most ``max_requests`` requests, whole
    iterations) is simulated and every figure is scaled linearly to the full run, so this is fast
    for any size.

    Args:
        spec: the memspec of one channel (:class:`hdeem_watch.dram.memspec.MemSpec`).
        kernel: kernel name.
        elements: doubles per array.
        threads: threads.
        repeat: passes over the arrays.
        channels: channels the traffic is spread over (1 = everything on this channel).
        mapping: address-mapping scheme of the channel.
        max_requests: the largest prefix simulated.
        policy: row-buffer policy, ``"open"`` or ``"closed"``.
        xor_bank: XOR bank hashing in the mapping.

    Raises:
        InputError: for a bad kernel, size, thread count, repeat, channel count or mapping.
    """
    name = canonical_kernel(kernel)
    for label, value, low in (("repeat", repeat, 0), ("channels", channels, 1), ("max_requests", max_requests, 1)):
        if isinstance(value, bool) or int(value) != value or value < low:
            raise InputError(f"{label} {value!r}: expected an integer >= {low}")
    width = len(access_pattern(name))
    total_lines = kernel_iterations(name, elements)
    lines_per_channel = total_lines / channels
    full_requests = lines_per_channel * width * repeat
    channel_lines = int(np.ceil(kernel_lines(elements) / channels))
    threads = int(threads)
    if isinstance(threads, bool) or threads < 1:
        raise InputError(f"threads {threads!r}: expected a positive integer")
    budget = max(1, min(max_requests, PREFIX_REQUESTS) // width)
    steps = max(1, budget // threads)
    if total_lines == 0 or repeat == 0:
        channel_lines = 0
    result = _simulate_prefix(spec, name, channel_lines, threads, steps, policy, mapping, xor_bank)
    factor = full_requests / result.requests if result.requests else 0.0
    return KernelModel(
        stats=result.stats.scaled(factor),
        reads=lines_per_channel * repeat * (width - sum(w for _, w in access_pattern(name))),
        writes=lines_per_channel * repeat * sum(w for _, w in access_pattern(name)),
        cycles=result.cycles * factor,
        row_hits=result.row_hits * factor,
        row_misses=result.row_misses * factor,
        row_conflicts=result.row_conflicts * factor,
        scale=factor,
    )
