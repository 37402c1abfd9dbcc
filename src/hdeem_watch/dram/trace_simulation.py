"""Command statistics straight from a request-trace file: parsing is part of the chunk pipeline.

A Ramulator trace whose lines all have one length (what the writers and the kernel streams
produce) is memory-mapped and parsed chunk by chunk in the preparing stage of
:func:`hdeem_watch.dram.controller.simulate_requests` (the worker process, while the chunk before
is timed), so reading costs no wall time of its own. Any other trace (mixed line lengths, CPU
traces through the cache filter) is read whole by
:func:`hdeem_watch.dram.request_traces.read_request_trace` first. A malformed line raises the
same ``InputError`` (file and line number) either way (a block that does not parse sends the
whole file to the general reader).

Example:
    >>> import tempfile, numpy as np
    >>> from pathlib import Path
    >>> from hdeem_watch.dram.memspec import preset
    >>> from hdeem_watch.dram.kernels import kernel_requests
    >>> from hdeem_watch.dram.request_traces import write_requests
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = Path(tmp) / "read.trace"
    ...     _ = write_requests(path, *kernel_requests("read", 8 * 4096))
    ...     result, cpu_accesses = simulate_trace(preset("ddr4-2133-x8-4gb"), path, "ramulator")
    >>> result.reads, result.writes, cpu_accesses
    (4096, 0, 0)
"""

from __future__ import annotations

import mmap
from pathlib import Path
from typing import Any

import numpy as np

from hdeem_watch.dram.controller import ControllerResult, simulate, simulate_requests
from hdeem_watch.dram.request_traces import CacheConfig, read_request_trace
from hdeem_watch.dram.uniform_parser import UniformParser

_BLOCK = 1 << 16


def simulate_trace(spec: Any, path: str | Path, fmt: str, *, cache: CacheConfig | None = None,
                   **options: Any) -> tuple[ControllerResult, int]:
    """Simulate the requests of a trace file (see the module doc).

    Args:
        spec: memspec of the channel.
        path: the trace.
        fmt: one of :data:`hdeem_watch.dram.request_traces.FORMATS`.
        cache: the last-level cache of CPU traces (``pinatrace``, ``lackey``).
        options: :func:`hdeem_watch.dram.controller.simulate`'s keyword arguments.

    Returns:
        ``(result, cpu_accesses)``: the statistics, and the CPU accesses before the cache filter
        (0 for DRAM-level traces).

    Raises:
        InputError: ``file:line`` and what was wrong, for a malformed line; or a bad format or option.
    """
    if fmt in ("ramulator", "ramulator2") and Path(path).is_file():
        data = _map(path)
        width = data.find(b"\n") + 1
        if width > 1 and len(data) % width == 0 and data[width - 2] != 13:
            buf = np.frombuffer(data, dtype=np.uint8)
            count = buf.size // width
            text = np.lib.stride_tricks.as_strided(buf, shape=(count, width), strides=(width, 1))

            parsers: list[UniformParser] = []  # made where it is used (the worker): its own work arrays

            def requests(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
                if not parsers:
                    parsers.append(UniformParser(width - 1, fmt, _BLOCK))
                addresses = np.empty(hi - lo, dtype=np.uint64)
                writes = np.empty(hi - lo, dtype=bool)
                for first in range(lo, hi, _BLOCK):
                    last = min(first + _BLOCK, hi)
                    if not parsers[0].parse(text[first:last], addresses[first - lo:last - lo],
                                            writes[first - lo:last - lo]):
                        raise _NotUniform(first)
                return addresses, writes

            try:
                return simulate_requests(spec, count, requests, **options), 0
            except _NotUniform:
                pass  # mixed line lengths or a malformed line: the general reader names it
    trace = read_request_trace(path, fmt, cache=cache)
    return simulate(spec, trace.addresses, trace.is_write, **options), trace.cpu_accesses


class _NotUniform(Exception):
    """A block of the trace is not lines of one length in the format (raised in the pipeline)."""


def _map(path: str | Path) -> bytes | mmap.mmap:
    """The file's bytes, memory-mapped without pre-faulting (the worker touches its chunks)."""
    with open(path, "rb") as handle:
        try:
            return mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
        except (ValueError, OSError):  # empty or special file
            return handle.read()
